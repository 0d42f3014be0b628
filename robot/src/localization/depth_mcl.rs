//! Monte Carlo localisation of a depth camera in a 3D model (seed 002, after Fallon et al.
//! 2012): every particle is a camera pose, the model's depth is rendered from all of them in
//! one batch, and each render is compared with the measured depth pixel by pixel.
//!
//! The filter follows seed 002 §3 (digest `shared/seeds/seed-002.md` §2):
//! - state: the camera body frame's pose (x forward, y left, z up) in the model's frame, as
//!   position and roll, pitch, yaw; a dimension whose random-walk σ is 0 stays at its start
//!   (the seed's experiment estimates x, y and yaw only);
//! - motion: the seed's additive Gaussian random walk, eq. (5), or, on a carrier with wheel
//!   odometry, the odometry increment carried to the camera plus that walk;
//! - measurement: the measured depth is re-projected through the particles' virtual camera
//!   (§3.3.2: a z-buffer of the measured points, so both images share one projection at any
//!   render size); per particle `l = Σ α / (α + |Δz|)` over the pixels valid in both
//!   (eq. 8), min–max normalised over the particles (eq. 9), weighted by
//!   `exp(−(l̃ − 1)² / β²)` (eq. 10);
//! - estimate: the weighted mean (eq. 12), angles by circular means;
//! - resampling: low-variance (systematic), every frame (the seed's scheme is not stated).
//!
//! Choices the seed leaves open, made here: a pixel where the measurement is invalid (0) is
//! left out for every particle; a pixel measured but where the model draws nothing scores 0
//! (as far off as can be); when every particle scores the same (l_max = l_min) the weights
//! are uniform.
//!
//! Rendering goes through [`DepthModel`]; the stack's own renderer (futago-render) implements
//! it, so the filter never sees the simulator's world, only the model it was given.

use crate::geometry::distance_field::DistanceField;
use futago_msgs::camera::{DepthImage, Intrinsics};
use futago_msgs::{Pose2, Pose3, wrap_angle};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::Deserialize;

/// Renders predicted depth images of a model: one per camera pose, in order, contiguous, each
/// `intr.width × intr.height`, depth along the optical axis in metres and 0 where nothing is
/// drawn within `far` m. Poses are camera body frames (REP 103) in the model's frame.
pub trait DepthModel {
    fn render_batch(
        &mut self,
        intr: &Intrinsics,
        poses: &[Pose3],
        far: f64,
        out: &mut Vec<f32>,
    ) -> Result<(), String>;

    /// The same images handed to `each` one at a time with their pose's index, in order (a
    /// buffer reused from one to the next). By default rendered as a batch and then split; a
    /// renderer that reads its images back one by one hands each over as it is read, so
    /// that a particle's score is taken while its image is in the cache.
    fn render_each(
        &mut self,
        intr: &Intrinsics,
        poses: &[Pose3],
        far: f64,
        each: &mut dyn FnMut(usize, &[f32]),
    ) -> Result<(), String> {
        let mut out = Vec::new();
        self.render_batch(intr, poses, far, &mut out)?;
        let pixels = intr.width as usize * intr.height as usize;
        if out.len() != pixels * poses.len() {
            return Err(format!(
                "the model rendered {} values for {} poses of {pixels} pixels",
                out.len(),
                poses.len()
            ));
        }
        for (k, image) in out.chunks_exact(pixels.max(1)).enumerate() {
            each(k, image);
        }
        Ok(())
    }

    /// The model's surfaces as a distance field, for [`Likelihood::Field`]; `None` (the
    /// default) where the model offers none.
    fn field(&self) -> Option<&DistanceField> {
        None
    }
}

/// A model drawn by a renderer (by default the stack's), with the distance field of the same
/// surfaces where the filter weighs by the likelihood field.
pub struct MeshModel<R = futago_render::Renderer> {
    pub renderer: R,
    pub field: Option<DistanceField>,
}

impl<R: DepthModel> DepthModel for MeshModel<R> {
    fn render_batch(
        &mut self,
        intr: &Intrinsics,
        poses: &[Pose3],
        far: f64,
        out: &mut Vec<f32>,
    ) -> Result<(), String> {
        self.renderer.render_batch(intr, poses, far, out)
    }

    fn render_each(
        &mut self,
        intr: &Intrinsics,
        poses: &[Pose3],
        far: f64,
        each: &mut dyn FnMut(usize, &[f32]),
    ) -> Result<(), String> {
        self.renderer.render_each(intr, poses, far, each)
    }

    fn field(&self) -> Option<&DistanceField> {
        self.field.as_ref()
    }
}

impl DepthModel for futago_render::Renderer {
    fn render_batch(
        &mut self,
        intr: &Intrinsics,
        poses: &[Pose3],
        far: f64,
        out: &mut Vec<f32>,
    ) -> Result<(), String> {
        let (cameras, far) = render_views(poses, far);
        self.render_depth_batch(intr, &cameras, far, out)
            .map_err(|e| e.to_string())
    }

    fn render_each(
        &mut self,
        intr: &Intrinsics,
        poses: &[Pose3],
        far: f64,
        each: &mut dyn FnMut(usize, &[f32]),
    ) -> Result<(), String> {
        let (cameras, far) = render_views(poses, far);
        self.render_depth_each(intr, &cameras, far, each)
            .map_err(|e| e.to_string())
    }
}

/// The renderer's camera poses for `poses`, and `far` within its far plane.
fn render_views(poses: &[Pose3], far: f64) -> (Vec<futago_render::Pose>, f32) {
    let cameras = poses.iter().map(render_pose).collect();
    (cameras, far.min(futago_render::FAR_PLANE as f64) as f32)
}

/// How far past the camera's range the model is drawn, in multiples of α: a pixel measured
/// within range where a particle's model lies beyond this would score at most
/// α/(α + 10α) ≈ 0.09 of a perfect match, and scores 0 instead.
const RANGE_MARGIN_ALPHAS: f64 = 10.0;

/// The depth to which the filter draws its model for a camera of range `range` (m) and the
/// likelihood kernel's `alpha`: the range plus 10 α.
pub fn model_far(range: f64, alpha: f64) -> f64 {
    range + RANGE_MARGIN_ALPHAS * alpha
}

/// A message pose as the renderer's (single-precision) pose.
pub fn render_pose(p: &Pose3) -> futago_render::Pose {
    let [x, y, z, w] = p.rotation;
    futago_render::Pose::from_parts(
        glam::Vec3::new(
            p.translation[0] as f32,
            p.translation[1] as f32,
            p.translation[2] as f32,
        ),
        glam::Quat::from_xyzw(x as f32, y as f32, z as f32, w as f32).normalize(),
    )
}

/// Depth-camera MCL parameters (`depth_localization.mcl.*`).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct DepthMclConfig {
    /// Particle count (seed 002: 200).
    pub particles: usize,
    /// Standard deviations of the random walk per frame: x, y, z (m), roll, pitch, yaw (rad).
    /// 0 freezes a dimension at its start. Seed 002 gives no values ("by trial and error");
    /// the walk must cover the camera's motion between frames.
    pub sigma: [f64; 6],
    /// The likelihood kernel's scale, m (seed 002: 0.1).
    pub alpha: f64,
    /// The weighting's sharpness on the normalised likelihood (seed 002: 0.01).
    pub beta: f64,
    /// How particles move between frames on a carrier without odometry.
    pub motion: MotionModel,
    /// How particles are weighed on the depth.
    pub likelihood: Likelihood,
    /// The sensor model's σ of a pixel's depth about the model's, m: the camera's noise
    /// (the SR4000's ±1 cm) and the model's own error (a surface scanned or mapped, a pose with
    /// fewer degrees of freedom than the camera's) together.
    pub pixel_sigma: f64,
    /// The sensor model's share of pixels that fit nothing (a person, an object the model
    /// lacks, a multipath return), spread evenly over the range.
    pub outlier: f64,
    /// The sensor model's count of independent measurements in an image: neighbouring pixels
    /// see the same surface and share the model's errors, so the summed log-likelihood is
    /// scaled to this many pixels, whatever the render size.
    pub independent_pixels: f64,
    /// The likelihood field's voxel, m: a measured point's distance to the model is known to
    /// within half its diagonal.
    pub field_cell: f64,
    /// The constant-velocity model's change of velocity per frame, standard deviations:
    /// forward and leftward (m per frame, per frame) and yaw rate (rad per frame, per frame).
    /// The defaults, 3 mm and 0.002 rad, are at 8 frames a second (σ / 0.125²) a change of
    /// speed of 0.19 m/s² and of turn rate of 0.13 rad/s²: a carrier pushed at a steady pace.
    /// A sharper velocity walk lets the seed's sharp weighting chase single frames and
    /// overshoot (10 mm a frame per frame does, in the unit tests' featureless room).
    pub velocity_sigma: [f64; 3],
    /// Recovery, after augmented MCL (Thrun et al., Probabilistic Robotics §8.3.5): slow and
    /// fast averages of how well the best particle fits (its mean per-pixel score, eq. 8 over
    /// the pixels measured, or for the sensor model the geometric mean of its pixels'
    /// likelihoods). While the fast average lies below the slow one, a share
    /// max(0, 1 − w_fast/w_slow) of `max_particles` (or `particles`) hypotheses is drawn
    /// anywhere in the model's free space, refined by `search_steps` rounds of a
    /// cross-entropy search on the frame, and added to the particles. Both 0 (the default, the
    /// seed's tracking filter): none.
    pub alpha_slow: f64,
    pub alpha_fast: f64,
    /// Rounds of the search that refines drawn hypotheses: each keeps the best quarter by
    /// score, draws the hypotheses again from them, and moves them by a step that halves each
    /// round (from 0.25 m, 0.05 m in height, 2° of roll and pitch and 15° of yaw, in the
    /// dimensions the filter estimates). A hypothesis drawn at random is almost never close
    /// enough to beat particles that have settled on a wrong place over many frames; refined,
    /// the ones drawn near the camera do.
    pub search_steps: usize,
    /// The share 1 − w_fast/w_slow below which no hypotheses are drawn. Augmented MCL draws at
    /// any share, but its particles are random ones that rarely fit; searched hypotheses fit
    /// well, and where the view is ambiguous (a plain wall filling it) one would win over the
    /// camera's own track. While a camera is tracked the share stays under about 1 % (the
    /// frame-to-frame spread of the fit); a kidnapping raises it to 5 % and more.
    pub search_share: f64,
    /// KLD-sampling (Fox 2003): the count between `particles` and this, bounded by the KL error
    /// `kld_err` at quantile `kld_z` over bins of `kld_bin` m and `kld_bin_angle` rad of yaw.
    /// None (the default): always `particles`. The default 0.05 asks no more than 200
    /// particles for a set in up to 8 bins (185; a tracked camera's spread over bin borders);
    /// the laser MCL's 0.01 would ask 330 for 2 bins.
    pub max_particles: Option<usize>,
    pub kld_err: f64,
    pub kld_z: f64,
    pub kld_bin: f64,
    pub kld_bin_angle: f64,
}

/// How a particle's depth render is turned into its weight.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Likelihood {
    /// Seed 002 eqs. (8)–(10): `Σ α/(α + |Δz|)`, min–max normalised over the particles and
    /// weighted by `exp(−(l̃ − 1)²/β²)`. The normalisation stretches whatever spread the
    /// scores have to [0, 1], so where the depth says little (a stretch of plain corridor)
    /// the sharp β picks the particles whose noise happened to fit best.
    Seed,
    /// A per-pixel sensor model (Thrun et al., Probabilistic Robotics §6.3, for depth
    /// pixels): a Gaussian of `pixel_sigma` about the model's depth mixed with a uniform
    /// `outlier` share over the range; the log-likelihoods summed over the pixels measured
    /// and scaled to `independent_pixels`. A pixel where the model draws nothing is an
    /// outlier. Where the depth says little the weights stay flat, and the particles spread.
    Sensor,
    /// The likelihood field in 3D (Thrun et al. §6.4): each measured point, placed by the
    /// particle's pose, is weighed by its distance to the model's nearest surface under the
    /// sensor model's Gaussian and outlier share, looked up in a distance field of the model
    /// (voxels of `field_cell`); the log-likelihoods summed and scaled to
    /// `independent_pixels`. No render: the points are a grid of the measured image's pixels,
    /// about four for each independent one. Unlike the render, it does not see that a
    /// particle's view passes through a wall, nor that the model shows a surface the camera
    /// did not measure.
    Field,
}

/// The prediction step where no odometry is given.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MotionModel {
    /// Seed 002 eq. (5): each particle takes a Gaussian step of `sigma` about where it was.
    /// The seed's weighting keeps only the particles within a few per cent of the best, so
    /// the estimate follows the best of the particles drawn about the last one: a camera that
    /// moves a σ or more a frame pulls ahead in the directions the depth constrains least
    /// (along a corridor), and the estimate lags further and further behind.
    RandomWalk,
    /// Each particle also carries a planar velocity in its own frame (forward, leftward,
    /// yaw rate, per frame), which it keeps from frame to frame, changed by a Gaussian step
    /// of `velocity_sigma`; its pose moves by it, then takes the random walk. Resampling
    /// keeps the velocities that put particles where the depth fits, so a camera carried at
    /// a steady pace is followed along a corridor whose depth does not say where along it the
    /// camera is. Height, roll and pitch are left to the random walk: a carrier travels in the
    /// plane, and its camera's height and tilt sway about a mean.
    ConstantVelocity,
}

impl Default for DepthMclConfig {
    fn default() -> Self {
        DepthMclConfig {
            particles: 200,
            sigma: [0.05, 0.05, 0.0, 0.0, 0.0, 2f64.to_radians()],
            alpha: 0.1,
            beta: 0.01,
            motion: MotionModel::RandomWalk,
            velocity_sigma: [0.003, 0.003, 0.002],
            likelihood: Likelihood::Seed,
            pixel_sigma: 0.05,
            outlier: 0.1,
            independent_pixels: 400.0,
            field_cell: 0.05,
            alpha_slow: 0.0,
            alpha_fast: 0.0,
            search_steps: 4,
            search_share: 0.03,
            max_particles: None,
            kld_err: 0.05,
            kld_z: 0.99,
            kld_bin: 0.5,
            kld_bin_angle: 10f64.to_radians(),
        }
    }
}

impl DepthMclConfig {
    /// Checks values the filter cannot run with, naming `PREFIX.KEY`.
    pub fn validate(&self, prefix: &str) -> Result<(), crate::config::ConfigError> {
        crate::config::check_counts(prefix, &[("particles", self.particles, 1, 100_000)])?;
        crate::config::check_counts(prefix, &[("search_steps", self.search_steps, 0, 20)])?;
        if let Some(m) = self.max_particles {
            crate::config::check_counts(prefix, &[("max_particles", m, self.particles, 100_000)])?;
        }
        let s = &self.sigma;
        crate::config::check_ranges(
            prefix,
            &[
                ("sigma[0]", s[0], 0.0, 10.0),
                ("sigma[1]", s[1], 0.0, 10.0),
                ("sigma[2]", s[2], 0.0, 10.0),
                ("sigma[3]", s[3], 0.0, std::f64::consts::PI),
                ("sigma[4]", s[4], 0.0, std::f64::consts::PI),
                ("sigma[5]", s[5], 0.0, std::f64::consts::PI),
                ("alpha", self.alpha, 1e-6, 100.0),
                ("beta", self.beta, 1e-6, 100.0),
                ("pixel_sigma", self.pixel_sigma, 1e-4, 10.0),
                ("outlier", self.outlier, 1e-6, 1.0),
                ("independent_pixels", self.independent_pixels, 1.0, 1e8),
                ("field_cell", self.field_cell, 0.005, 1.0),
                ("alpha_slow", self.alpha_slow, 0.0, 1.0),
                ("search_share", self.search_share, 0.0, 1.0),
                ("alpha_fast", self.alpha_fast, 0.0, 1.0),
                ("kld_err", self.kld_err, 1e-6, 1.0),
                ("kld_z", self.kld_z, 0.5, 0.999_999),
                ("kld_bin", self.kld_bin, 1e-3, 10.0),
                (
                    "kld_bin_angle",
                    self.kld_bin_angle,
                    1e-3,
                    std::f64::consts::PI,
                ),
                ("velocity_sigma[0]", self.velocity_sigma[0], 0.0, 10.0),
                ("velocity_sigma[1]", self.velocity_sigma[1], 0.0, 10.0),
                (
                    "velocity_sigma[2]",
                    self.velocity_sigma[2],
                    0.0,
                    std::f64::consts::PI,
                ),
            ],
        )
    }
}

/// A camera pose as the filter's state: position (m) and roll, pitch, yaw (rad; the rotation
/// is yaw about z, then pitch about y, then roll about x).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraState {
    pub position: [f64; 3],
    pub rpy: [f64; 3],
}

impl CameraState {
    /// The state as a pose.
    pub fn pose(&self) -> Pose3 {
        let [r, p, y] = self.rpy;
        let (sr, cr) = (r * 0.5).sin_cos();
        let (sp, cp) = (p * 0.5).sin_cos();
        let (sy, cy) = (y * 0.5).sin_cos();
        Pose3 {
            translation: self.position,
            rotation: [
                sr * cp * cy - cr * sp * sy,
                cr * sp * cy + sr * cp * sy,
                cr * cp * sy - sr * sp * cy,
                cr * cp * cy + sr * sp * sy,
            ],
        }
    }

    /// The state of a pose (roll, pitch, yaw of its unit quaternion).
    pub fn from_pose(p: &Pose3) -> CameraState {
        let [x, y, z, w] = p.rotation;
        let roll = (2.0 * (w * x + y * z)).atan2(1.0 - 2.0 * (x * x + y * y));
        let pitch = (2.0 * (w * y - z * x)).clamp(-1.0, 1.0).asin();
        let yaw = (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z));
        CameraState {
            position: p.translation,
            rpy: [roll, pitch, yaw],
        }
    }
}

/// The filter's output for a frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthEstimate {
    pub state: CameraState,
    /// Weighted standard deviations of x, y, z (m) and roll, pitch, yaw (rad).
    pub sd: [f64; 6],
}

/// The particle filter.
pub struct DepthMcl {
    config: DepthMclConfig,
    rng: ChaCha8Rng,
    particles: Vec<CameraState>,
    weights: Vec<f64>,
    /// Each particle's planar velocity in its own frame (forward, left, yaw rate; per frame),
    /// for the constant-velocity model.
    velocities: Vec<[f64; 3]>,
    /// The sensor model's table, for the camera range it was made for.
    sensor: Option<(f64, SensorModel)>,
    /// Scratch: the particles' poses.
    poses: Vec<Pose3>,
    /// Where a camera may be: the centres of free cells of side `cell` in the plane, for
    /// drawing particles anywhere (augmented MCL, a global start).
    free: Vec<[f64; 2]>,
    cell: f64,
    /// Augmented MCL's averages of the best particle's fit (0: not yet set).
    w_slow: f64,
    w_fast: f64,
    /// Hypotheses drawn anywhere and searched at the last frame.
    searched: usize,
    /// Whether the next frame starts globally.
    global: bool,
}

fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    StandardNormal.sample(rng)
}

impl DepthMcl {
    /// A filter whose particles all start at `start` (seed 002 eq. 4: tracking from a known
    /// pose; the spread comes from the first propagation).
    pub fn new(config: DepthMclConfig, start: CameraState, seed: u64) -> DepthMcl {
        let n = config.particles.max(1);
        DepthMcl {
            config,
            rng: ChaCha8Rng::seed_from_u64(seed),
            particles: vec![start; n],
            weights: vec![1.0 / n as f64; n],
            velocities: vec![[0.0; 3]; n],
            sensor: None,
            poses: Vec::new(),
            free: Vec::new(),
            cell: 0.0,
            w_slow: 0.0,
            w_fast: 0.0,
            searched: 0,
            global: false,
        }
    }

    /// Gives the filter the places a camera may be (centres of free cells of side `cell`, m),
    /// where augmented MCL draws its particles.
    pub fn set_free_space(&mut self, free: Vec<[f64; 2]>, cell: f64) {
        self.free = free;
        self.cell = cell;
    }

    /// A global start: at the next frame the particles are replaced by `max_particles` (or
    /// `particles`) hypotheses drawn anywhere in the free space at any yaw, with height, roll
    /// and pitch from the start (a carrier's camera height and tilt are known), refined by the
    /// recovery's search. Without free space, nothing changes.
    pub fn start_global(&mut self) {
        self.global = !self.free.is_empty();
    }

    /// A state drawn uniformly over the free cells and yaw; the rest from `like`.
    fn random_state(&mut self, like: &CameraState) -> CameraState {
        let c = self.free[self.rng.random_range(0..self.free.len())];
        let h = 0.5 * self.cell;
        let mut s = *like;
        s.position[0] = c[0] + self.rng.random_range(-h..=h);
        s.position[1] = c[1] + self.rng.random_range(-h..=h);
        s.rpy[2] = self
            .rng
            .random_range(-std::f64::consts::PI..std::f64::consts::PI);
        s
    }

    /// Hypotheses drawn anywhere and searched at the last frame (recovery).
    pub fn searched(&self) -> usize {
        self.searched
    }

    /// Updates augmented MCL's averages with this frame's best fit.
    fn track_fit(&mut self, fit: f64) {
        let c = &self.config;
        let usable = fit > 0.0;
        if c.alpha_slow <= 0.0 && c.alpha_fast <= 0.0 || !usable {
            return;
        }
        if self.w_slow == 0.0 {
            self.w_slow = fit;
            self.w_fast = fit;
        } else {
            self.w_slow += c.alpha_slow * (fit - self.w_slow);
            self.w_fast += c.alpha_fast * (fit - self.w_fast);
        }
    }

    /// Spreads the particles around `start` with standard deviations per dimension (and
    /// forgets their velocities).
    pub fn spread(&mut self, start: CameraState, sd: [f64; 6]) {
        self.velocities.iter_mut().for_each(|v| *v = [0.0; 3]);
        for p in &mut self.particles {
            for k in 0..3 {
                p.position[k] = start.position[k] + sd[k] * gauss(&mut self.rng);
                p.rpy[k] = wrap_angle(start.rpy[k] + sd[k + 3] * gauss(&mut self.rng));
            }
        }
    }

    /// The particles (for display and tests).
    pub fn particles(&self) -> &[CameraState] {
        &self.particles
    }

    /// One frame: motion (the planar increment of the camera's body frame since the last
    /// frame, where the carrier has odometry), the random walk, the batched render, the
    /// likelihood of `measured` (a depth image of `intr`, e.g. from [`reproject`], from a
    /// camera that measures out to `range` m), the estimate and resampling. The model is
    /// drawn out to the range plus 10 α.
    pub fn update<M: DepthModel>(
        &mut self,
        model: &mut M,
        intr: &Intrinsics,
        measured: &[f32],
        range: f64,
        motion: Option<&Pose2>,
    ) -> Result<DepthEstimate, String> {
        if !(range > 0.0 && range.is_finite()) {
            return Err(format!(
                "camera range {range} m: expected a positive distance"
            ));
        }
        let pixels = (intr.width * intr.height) as usize;
        if measured.len() != pixels {
            return Err(format!(
                "measured depth has {} pixels, expected {}×{}",
                measured.len(),
                intr.width,
                intr.height
            ));
        }
        self.predict(motion);
        let mut raw = if self.global {
            self.global = false;
            let like = self.particles[0];
            let n = self.config.max_particles.unwrap_or(self.config.particles);
            let (found, scores) = self.search(model, intr, measured, range, n, &like)?;
            self.particles = found;
            self.velocities = vec![[0.0; 3]; n];
            scores
        } else {
            let states = std::mem::take(&mut self.particles);
            let raw = self.evaluate(model, intr, measured, range, &states);
            self.particles = states;
            raw?
        };
        let valid = measured.iter().filter(|m| **m > 0.0).count().max(1);
        let best = raw.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        let c = self.config;
        self.track_fit(match c.likelihood {
            Likelihood::Seed => best / valid as f64,
            Likelihood::Sensor | Likelihood::Field => (best / c.independent_pixels).exp(),
        });
        let share = if self.w_slow > 0.0 && !self.free.is_empty() {
            (1.0 - self.w_fast / self.w_slow).max(0.0)
        } else {
            0.0
        };
        let share = if share > c.search_share { share } else { 0.0 };
        self.searched = 0;
        if share > 0.0 {
            self.set_weights(&raw);
            let like = self.estimate().state;
            let n = c.max_particles.unwrap_or(c.particles) as f64 * share;
            let n = n.round() as usize;
            if n > 0 {
                let (found, scores) = self.search(model, intr, measured, range, n, &like)?;
                self.searched = n;
                self.particles.extend(found);
                self.velocities.resize(self.particles.len(), [0.0; 3]);
                raw.extend(scores);
            }
        }
        self.set_weights(&raw);
        let estimate = self.estimate();
        self.resample();
        Ok(estimate)
    }

    /// Each state's raw score on the frame: the seed's `Σ α/(α + |Δz|)`, or the sensor
    /// model's log-likelihood scaled to `independent_pixels`.
    fn evaluate<M: DepthModel>(
        &mut self,
        model: &mut M,
        intr: &Intrinsics,
        measured: &[f32],
        range: f64,
        states: &[CameraState],
    ) -> Result<Vec<f64>, String> {
        let pixels = (intr.width * intr.height) as usize;
        let c = self.config;
        if self.sensor.as_ref().is_none_or(|(r, _)| *r != range) {
            self.sensor = Some((range, SensorModel::new(c.pixel_sigma, c.outlier, range)));
        }
        if c.likelihood == Likelihood::Field {
            let field = model.field().ok_or(
                "the likelihood field needs the model's distance field, and the model has none",
            )?;
            let sensor = &self.sensor.as_ref().expect("made above").1;
            let points = field_points(intr, measured, c.independent_pixels);
            let scale = c.independent_pixels / points.len().max(1) as f64;
            return Ok(crate::cores::map_on_cores(
                states,
                FIELD_SERIAL_BELOW,
                |s| scale * field_log_likelihood(field, sensor, &s.pose(), &points),
            ));
        }
        self.poses.clear();
        self.poses.extend(states.iter().map(|p| p.pose()));
        let far = model_far(range, self.config.alpha);
        let sensor = &self.sensor.as_ref().expect("made above").1;
        let valid = measured.iter().filter(|m| **m > 0.0).count().max(1);
        let scale = c.independent_pixels / valid as f64;
        // Each particle's score as its image is read back; an image of the wrong size, out
        // of range or given twice is reported below, as is one never given.
        let mut scores = vec![f64::NAN; states.len()];
        let mut given = vec![false; states.len()];
        let mut wrong = None;
        model.render_each(intr, &self.poses, far, &mut |k, predicted| {
            if predicted.len() != pixels || given.get(k) != Some(&false) {
                wrong.get_or_insert((k, predicted.len()));
                return;
            }
            given[k] = true;
            scores[k] = match c.likelihood {
                Likelihood::Seed => score(measured, predicted, c.alpha),
                Likelihood::Sensor | Likelihood::Field => {
                    scale * sensor.log_likelihood(measured, predicted)
                }
            };
        })?;
        if let Some((k, len)) = wrong {
            return Err(format!(
                "the model gave image {k} ({len} values) for {} particles of {pixels} pixels: \
                 expected one image of each particle",
                states.len()
            ));
        }
        if let Some(k) = given.iter().position(|g| !g) {
            return Err(format!(
                "the model rendered no image for particle {k} of {}",
                states.len()
            ));
        }
        Ok(scores)
    }

    /// Weights from raw scores by the configured likelihood.
    fn set_weights(&mut self, raw: &[f64]) {
        match self.config.likelihood {
            Likelihood::Seed => self.weigh(raw),
            Likelihood::Sensor | Likelihood::Field => self.weigh_logs(raw),
        }
    }

    /// `n` hypotheses drawn anywhere in the free space (height, roll and pitch from `like`),
    /// refined by the cross-entropy search of `search_steps` rounds; with their raw scores.
    fn search<M: DepthModel>(
        &mut self,
        model: &mut M,
        intr: &Intrinsics,
        measured: &[f32],
        range: f64,
        n: usize,
        like: &CameraState,
    ) -> Result<(Vec<CameraState>, Vec<f64>), String> {
        /// The first round's steps: x, y, z (m), roll, pitch, yaw (rad).
        const FIRST: [f64; 6] = [0.25, 0.25, 0.05, 0.035, 0.035, 0.26];
        let mut found: Vec<CameraState> = (0..n).map(|_| self.random_state(like)).collect();
        let sigma = self.config.sigma;
        for round in 0..self.config.search_steps {
            let scores = self.evaluate(model, intr, measured, range, &found)?;
            let mut order: Vec<usize> = (0..found.len()).collect();
            order.sort_by(|a, b| scores[*b].total_cmp(&scores[*a]).then(a.cmp(b)));
            let elite: Vec<CameraState> = order[..found.len().div_ceil(4)]
                .iter()
                .map(|&k| found[k])
                .collect();
            let scale = 0.5f64.powi(round as i32);
            for (k, f) in found.iter_mut().enumerate() {
                let mut p = elite[k % elite.len()];
                for d in 0..3 {
                    if sigma[d] > 0.0 {
                        p.position[d] += FIRST[d] * scale * gauss(&mut self.rng);
                    }
                    if sigma[d + 3] > 0.0 {
                        p.rpy[d] =
                            wrap_angle(p.rpy[d] + FIRST[d + 3] * scale * gauss(&mut self.rng));
                    }
                }
                // The best of each round is kept as it is.
                *f = if k == 0 { elite[0] } else { p };
            }
        }
        let scores = self.evaluate(model, intr, measured, range, &found)?;
        Ok((found, scores))
    }

    /// Odometry carried to the camera (in its body frame's plane), or without it each
    /// particle's own velocity where the model is constant-velocity; then the random walk.
    fn predict(&mut self, motion: Option<&Pose2>) {
        let s = self.config.sigma;
        let vs = self.config.velocity_sigma;
        let own = motion.is_none() && self.config.motion == MotionModel::ConstantVelocity;
        for (p, v) in self.particles.iter_mut().zip(&mut self.velocities) {
            let step = match motion {
                Some(m) => Some(*m),
                None if own => {
                    for k in 0..3 {
                        if vs[k] > 0.0 {
                            v[k] += vs[k] * gauss(&mut self.rng);
                        }
                    }
                    Some(Pose2::new(v[0], v[1], v[2]))
                }
                None => None,
            };
            if let Some(m) = step {
                let yaw = p.rpy[2];
                let (sy, cy) = yaw.sin_cos();
                p.position[0] += cy * m.x - sy * m.y;
                p.position[1] += sy * m.x + cy * m.y;
                p.rpy[2] = wrap_angle(yaw + m.theta);
            }
            for k in 0..3 {
                if s[k] > 0.0 {
                    p.position[k] += s[k] * gauss(&mut self.rng);
                }
                if s[k + 3] > 0.0 {
                    p.rpy[k] = wrap_angle(p.rpy[k] + s[k + 3] * gauss(&mut self.rng));
                }
            }
        }
    }

    /// Weights from log-likelihoods (the largest is 1 before normalising, so none underflow
    /// all together).
    fn weigh_logs(&mut self, logs: &[f64]) {
        let top = logs.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        self.weights = logs.iter().map(|l| (l - top).exp()).collect();
        let sum: f64 = self.weights.iter().sum();
        for w in &mut self.weights {
            *w /= sum;
        }
    }

    /// Seed 002's weighting, eqs. (9)–(11).
    fn weigh(&mut self, scores: &[f64]) {
        let lo = scores.iter().cloned().fold(f64::INFINITY, f64::min);
        let hi = scores.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        let n = scores.len();
        if hi <= lo {
            self.weights = vec![1.0 / n as f64; n];
            return;
        }
        let b2 = self.config.beta * self.config.beta;
        self.weights = scores
            .iter()
            .map(|l| {
                let t = (l - lo) / (hi - lo) - 1.0;
                (-t * t / b2).exp()
            })
            .collect();
        // The best particle has weight 1, so the sum is at least 1.
        let sum: f64 = self.weights.iter().sum();
        for w in &mut self.weights {
            *w /= sum;
        }
    }

    /// The weighted mean (seed 002 eq. 12), angles by circular means, and the weighted
    /// standard deviations.
    pub fn estimate(&self) -> DepthEstimate {
        let mut pos = [0.0; 3];
        let mut sc = [[0.0; 2]; 3];
        for (p, w) in self.particles.iter().zip(&self.weights) {
            for k in 0..3 {
                pos[k] += w * p.position[k];
                sc[k][0] += w * p.rpy[k].sin();
                sc[k][1] += w * p.rpy[k].cos();
            }
        }
        let rpy = sc.map(|[s, c]| s.atan2(c));
        let mut var = [0.0; 6];
        for (p, w) in self.particles.iter().zip(&self.weights) {
            for k in 0..3 {
                var[k] += w * (p.position[k] - pos[k]).powi(2);
                var[k + 3] += w * wrap_angle(p.rpy[k] - rpy[k]).powi(2);
            }
        }
        DepthEstimate {
            state: CameraState { position: pos, rpy },
            sd: var.map(f64::sqrt),
        }
    }

    /// Low-variance resampling, to `particles` or, with KLD-sampling, to the bound for the
    /// bins (x, y, yaw) the new set occupies, between `particles` and `max_particles`.
    fn resample(&mut self) {
        let c = self.config;
        let n0 = self.particles.len();
        let (lo, hi) = match c.max_particles {
            Some(m) => (c.particles, m),
            None => (c.particles, c.particles),
        };
        let z = crate::localization::mcl::normal_quantile(c.kld_z);
        let mut bins = rustc_hash::FxHashSet::default();
        let step = 1.0 / n0 as f64;
        let mut r = self.rng.random_range(0.0..step);
        let mut cum = self.weights[0];
        let mut i = 0;
        let mut out = Vec::with_capacity(hi);
        let mut velocities = Vec::with_capacity(hi);
        loop {
            let target = if hi > lo {
                crate::localization::mcl::kld_bound(bins.len(), c.kld_err, z).clamp(lo, hi)
            } else {
                lo
            };
            if out.len() >= target {
                break;
            }
            while r > cum && i + 1 < n0 {
                i += 1;
                cum += self.weights[i];
            }
            let (p, v) = (self.particles[i], self.velocities[i]);
            // Past the last particle (KLD asks more than there were) the wheel turns again.
            r += step;
            if r > 1.0 {
                r -= 1.0;
                i = 0;
                cum = self.weights[0];
            }
            if hi > lo {
                bins.insert((
                    (p.position[0] / c.kld_bin).floor() as i64,
                    (p.position[1] / c.kld_bin).floor() as i64,
                    (p.rpy[2] / c.kld_bin_angle).floor() as i64,
                ));
            }
            out.push(p);
            velocities.push(v);
        }
        let n = out.len();
        self.particles = out;
        self.velocities = velocities;
        self.weights = vec![1.0 / n as f64; n];
    }
}

/// The per-pixel sensor model of [`Likelihood::Sensor`].
#[derive(Debug, Clone)]
pub struct SensorModel {
    /// ln((1 − ε)/(σ√(2π))), 1/(2σ²) and ln(ε/R).
    hit: f64,
    inv_2s2: f64,
    miss: f64,
    /// ln p by |Δz| in steps of [`SensorModel::STEP`] up to where it is `miss` to 1e-13.
    table: Vec<f32>,
}

impl SensorModel {
    /// The table's step, m: a hundredth of a centimetre-σ.
    const STEP: f64 = 1e-4;

    /// σ (m), the outlier share ε and the camera's range R (m).
    pub fn new(sigma: f64, outlier: f64, range: f64) -> SensorModel {
        let mut m = SensorModel {
            hit: ((1.0 - outlier) / (sigma * (2.0 * std::f64::consts::PI).sqrt())).ln(),
            inv_2s2: 1.0 / (2.0 * sigma * sigma),
            miss: (outlier / range).ln(),
            table: Vec::new(),
        };
        // Past this |Δz| the Gaussian lies 30 nats under the outlier term.
        let reach = ((m.hit - m.miss + 30.0).max(0.0) / m.inv_2s2).sqrt();
        let n = (reach / Self::STEP).ceil() as usize + 2;
        m.table = (0..n)
            .map(|i| m.exact(i as f64 * Self::STEP) as f32)
            .collect();
        m
    }

    /// ln p at a depth difference `d`, computed.
    fn exact(&self, d: f64) -> f64 {
        let g = self.hit - d * d * self.inv_2s2;
        // ln(eᵍ + eᵐ) without overflow; past 30 nats apart the smaller adds under 1e-13.
        let (a, b) = if g > self.miss {
            (g, self.miss)
        } else {
            (self.miss, g)
        };
        if a - b > 30.0 {
            a
        } else {
            a + (b - a).exp().ln_1p()
        }
    }

    /// ln p at `d` from the table, linearly interpolated.
    fn lookup(&self, d: f32) -> f32 {
        let x = d.abs() / Self::STEP as f32;
        let i = x as usize;
        if i + 1 >= self.table.len() {
            return self.miss as f32;
        }
        let f = x - i as f32;
        self.table[i] + f * (self.table[i + 1] - self.table[i])
    }

    /// ln p(z | ẑ) of one pixel measured at `z` where the model draws `z_hat` (0: nothing).
    pub fn pixel(&self, z: f32, z_hat: f32) -> f32 {
        if z_hat <= 0.0 {
            self.miss as f32
        } else {
            self.lookup(z - z_hat)
        }
    }

    /// Σ ln p over the pixels measured (`measured` > 0).
    pub fn log_likelihood(&self, measured: &[f32], predicted: &[f32]) -> f64 {
        measured
            .iter()
            .zip(predicted)
            .filter(|(m, _)| **m > 0.0)
            .map(|(&m, &p)| self.pixel(m, p) as f64)
            .sum()
    }
}

/// Measured points the likelihood field weighs per independent pixel (`independent_pixels`).
const FIELD_POINTS_PER_PIXEL: f64 = 4.0;

/// Below this many particles the likelihood field weighs them on one thread (a particle's
/// points take some 0.1 ms).
const FIELD_SERIAL_BELOW: usize = 16;

/// The measured points the likelihood field weighs, in the camera's body frame (x forward, y
/// left, z up): every valid pixel of a grid over the image (of intrinsics `intr`) whose step
/// leaves about four pixels for each of `independent` ones.
pub fn field_points(intr: &Intrinsics, measured: &[f32], independent: f64) -> Vec<[f64; 3]> {
    let (w, h) = (intr.width as usize, intr.height as usize);
    let step = ((w * h) as f64 / (FIELD_POINTS_PER_PIXEL * independent.max(1.0)))
        .sqrt()
        .floor()
        .max(1.0) as usize;
    let mut points = Vec::new();
    for v in (step / 2..h).step_by(step) {
        for u in (step / 2..w).step_by(step) {
            let z = measured.get(v * w + u).copied().unwrap_or(0.0) as f64;
            if !(z > 0.0 && z.is_finite()) {
                continue;
            }
            // The optical ray (x right, y down, z forward) in the body frame.
            let x = (u as f64 - intr.cx) / intr.fx * z;
            let y = (v as f64 - intr.cy) / intr.fy * z;
            points.push([z, -x, -y]);
        }
    }
    points
}

/// Σ ln p over `points` (camera body frame) placed by the camera pose `pose`, each weighed by
/// the sensor model at its distance to the model's surfaces.
fn field_log_likelihood(
    field: &DistanceField,
    sensor: &SensorModel,
    pose: &Pose3,
    points: &[[f64; 3]],
) -> f64 {
    let [x, y, z, w] = pose.rotation;
    // The rotation matrix of the unit quaternion.
    let r = [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - z * w),
            2.0 * (x * z + y * w),
        ],
        [
            2.0 * (x * y + z * w),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - x * w),
        ],
        [
            2.0 * (x * z - y * w),
            2.0 * (y * z + x * w),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ];
    let t = pose.translation;
    points
        .iter()
        .map(|p| {
            let q = [
                r[0][0] * p[0] + r[0][1] * p[1] + r[0][2] * p[2] + t[0],
                r[1][0] * p[0] + r[1][1] * p[1] + r[1][2] * p[2] + t[1],
                r[2][0] * p[0] + r[2][1] * p[1] + r[2][2] * p[2] + t[2],
            ];
            sensor.lookup(field.distance(q) as f32) as f64
        })
        .sum()
}

/// Seed 002 eq. (8): `Σ α / (α + |Δz|)` over the pixels measured; a pixel where the model
/// draws nothing scores 0. The sum is that of the terms in the pixels' order (see
/// [`score_in_order`]), computed in [`SCORE_LANES`] running sums where that gives the same
/// bits.
///
/// Each term is an `f32` in (0, 1]. Where the smallest is at least 2^(E − 30), with 2^E at
/// least the number of pixels, every term and every partial sum (at most 2^E) is a whole
/// multiple of 2^(E − 53): a number of at most 53 bits, which an `f64` holds exactly. Then
/// no addition rounds, the sum is exact in any order, and the running sums side by side
/// give the in-order sum's bits. A single running sum waits on the last addition at every
/// pixel; side by side, the terms' divisions and additions overlap (the frame less its
/// render, mostly this score, was 7–14 ms of a 43–54 ms corridor frame of 200 particles at
/// 176×144, and 2.5–3.3 ms after). Where a term is smaller than the bound (2^-15 at 176×144,
/// 2^-13 at 320×240: an `alpha` far below the depth differences), or not a number, the sum
/// is taken in order instead.
pub fn score(measured: &[f32], predicted: &[f32], alpha: f64) -> f64 {
    let a = alpha as f32;
    let n = measured.len().min(predicted.len());
    let (measured, predicted) = (&measured[..n], &predicted[..n]);
    // Zero where the pixel is not measured (as the in-order sum leaves it out) or not drawn;
    // computed for every pixel and then chosen, without branches, so that the lanes are
    // vector operations.
    let term = |m: f32, p: f32| {
        let t = a / (a + (m - p).abs());
        if (m > 0.0) & (p > 0.0) { t } else { 0.0 }
    };
    let mut sums = [0.0f64; SCORE_LANES];
    // The smallest positive term of each lane (a NaN term makes its lane's sum NaN).
    let mut least = [f32::INFINITY; SCORE_LANES];
    let mut add = |l: usize, t: f32| {
        sums[l] += t as f64;
        let positive = if t > 0.0 { t } else { f32::INFINITY };
        least[l] = if positive < least[l] {
            positive
        } else {
            least[l]
        };
    };
    let (m_rows, m_rest) = measured.as_chunks::<SCORE_LANES>();
    let (p_rows, p_rest) = predicted.as_chunks::<SCORE_LANES>();
    for (m, p) in m_rows.iter().zip(p_rows) {
        for l in 0..SCORE_LANES {
            add(l, term(m[l], p[l]));
        }
    }
    for (l, (&m, &p)) in m_rest.iter().zip(p_rest).enumerate() {
        add(l, term(m, p));
    }
    let least = least.iter().fold(f32::INFINITY, |x, &y| x.min(y));
    let total: f64 = sums.iter().fold(0.0, |x, &y| x + y);
    // 2^E at least the pixels; terms from 2^(E - 30) up are exact steps of 2^(E - 53).
    let e = n.max(1).next_power_of_two().trailing_zeros() as i32;
    let exact = a > 0.0 && (least as f64) >= 2f64.powi(e - 30) && total.is_finite();
    // A zero total may be the in-order sum's -0.0 (no pixel measured): taken in order too.
    if exact && total > 0.0 {
        total
    } else {
        score_in_order(measured, predicted, alpha)
    }
}

/// Running sums [`score`] keeps side by side.
const SCORE_LANES: usize = 8;

/// [`score`]'s definition: the terms of the measured pixels summed one after another in the
/// pixels' order.
pub fn score_in_order(measured: &[f32], predicted: &[f32], alpha: f64) -> f64 {
    let a = alpha as f32;
    measured
        .iter()
        .zip(predicted)
        .filter(|(m, _)| **m > 0.0)
        .map(|(&m, &p)| {
            if p > 0.0 {
                (a / (a + (m - p).abs())) as f64
            } else {
                0.0
            }
        })
        .sum()
}

/// Re-projects a measured depth image (of intrinsics `from`) through a virtual camera at the
/// same pose with intrinsics `to` (seed 002 §3.3.2): every valid pixel is back-projected to
/// its point and projected again, the nearest point per target pixel kept; target pixels no
/// point falls in are invalid (0). With `to` a scaled copy of `from`, this is the measured
/// image at the render size.
pub fn reproject(measured: &DepthImage, from: &Intrinsics, to: &Intrinsics) -> Vec<f32> {
    let mut out = vec![0.0f32; (to.width * to.height) as usize];
    if measured.width != from.width || measured.height != from.height {
        return out;
    }
    for v in 0..measured.height {
        for u in 0..measured.width {
            let z = measured.at(u, v);
            if !(z > 0.0 && z.is_finite()) {
                continue;
            }
            let p = from.back_project(u as f64, v as f64, z as f64);
            let tu = (to.fx * p[0] / p[2] + to.cx).round();
            let tv = (to.fy * p[1] / p[2] + to.cy).round();
            if tu < 0.0 || tv < 0.0 || tu >= to.width as f64 || tv >= to.height as f64 {
                continue;
            }
            let k = tv as usize * to.width as usize + tu as usize;
            if out[k] == 0.0 || z < out[k] {
                out[k] = z;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A model that renders a room by ray casting, standing in for the GPU in unit tests: a
    /// box (x in 0..10, y in 0..4, z in 0..3) with square pillars along both walls (as a
    /// corridor has door recesses and columns: without them only the end wall tells where
    /// along the room the camera is).
    struct BoxRoom {
        pillars: bool,
    }

    const PILLARS: [([f64; 3], [f64; 3]); 4] = [
        ([3.0, 0.0, 0.0], [3.4, 0.4, 3.0]),
        ([5.5, 3.6, 0.0], [5.9, 4.0, 3.0]),
        ([7.0, 0.0, 0.0], [7.4, 0.4, 3.0]),
        ([9.0, 3.6, 0.0], [9.4, 4.0, 3.0]),
    ];

    /// Where the ray `o + t d` enters the box `lo..hi`, for t > 0.
    fn enter(o: [f64; 3], d: [f64; 3], lo: [f64; 3], hi: [f64; 3]) -> Option<f64> {
        let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
        for k in 0..3 {
            if d[k].abs() < 1e-12 {
                if o[k] < lo[k] || o[k] > hi[k] {
                    return None;
                }
                continue;
            }
            let (a, b) = ((lo[k] - o[k]) / d[k], (hi[k] - o[k]) / d[k]);
            t0 = t0.max(a.min(b));
            t1 = t1.min(a.max(b));
        }
        (t0 <= t1 && t0 > 0.0).then_some(t0)
    }

    impl BoxRoom {
        fn depth(&self, pose: &Pose3, intr: &Intrinsics, u: u32, v: u32) -> f32 {
            // The optical ray in the body frame: optical x right = −y, y down = −z, z fwd = x.
            let r = intr.ray(u as f64, v as f64);
            let body = [r[2], -r[0], -r[1]];
            let o = pose.translation;
            let e = pose.transform_point(body);
            let d = [e[0] - o[0], e[1] - o[1], e[2] - o[2]];
            let lo = [0.0, 0.0, 0.0];
            let hi = [10.0, 4.0, 3.0];
            let mut t = f64::INFINITY;
            for k in 0..3 {
                if d[k] > 1e-12 {
                    t = t.min((hi[k] - o[k]) / d[k]);
                } else if d[k] < -1e-12 {
                    t = t.min((lo[k] - o[k]) / d[k]);
                }
            }
            for (a, b) in PILLARS.into_iter().filter(|_| self.pillars) {
                if let Some(p) = enter(o, d, a, b) {
                    t = t.min(p);
                }
            }
            // z along the optical axis equals t (the ray has unit forward component).
            t as f32
        }
    }

    impl DepthModel for BoxRoom {
        fn render_batch(
            &mut self,
            intr: &Intrinsics,
            poses: &[Pose3],
            far: f64,
            out: &mut Vec<f32>,
        ) -> Result<(), String> {
            out.clear();
            for p in poses {
                for v in 0..intr.height {
                    for u in 0..intr.width {
                        let z = self.depth(p, intr, u, v);
                        out.push(if z as f64 <= far { z } else { 0.0 });
                    }
                }
            }
            Ok(())
        }
    }

    /// The range of the cameras in the tests, m: longer than the room.
    const RANGE: f64 = 20.0;

    fn intr() -> Intrinsics {
        Intrinsics::from_fov(44, 36, 43.6f64.to_radians(), 34.6f64.to_radians()).unwrap()
    }

    fn render(room: &BoxRoom, pose: &CameraState) -> Vec<f32> {
        let mut out = Vec::new();
        BoxRoom {
            pillars: room.pillars,
        }
        .render_batch(&intr(), &[pose.pose()], RANGE, &mut out)
        .unwrap();
        out
    }

    #[test]
    fn states_and_poses_convert_both_ways() {
        let s = CameraState {
            position: [1.0, 2.0, 3.0],
            rpy: [0.1, -0.2, 2.5],
        };
        let back = CameraState::from_pose(&s.pose());
        for k in 0..3 {
            assert!((back.rpy[k] - s.rpy[k]).abs() < 1e-12, "{back:?}");
        }
        // Yaw alone turns x forward to (cos, sin).
        let y = CameraState {
            position: [0.0; 3],
            rpy: [0.0, 0.0, 0.5],
        }
        .pose()
        .transform_point([1.0, 0.0, 0.0]);
        assert!((y[0] - 0.5f64.cos()).abs() < 1e-12 && (y[1] - 0.5f64.sin()).abs() < 1e-12);
    }

    /// The sensor model by hand: σ 0.05 m, ε 0.1, R 5 m. A pixel on the model scores
    /// ln(0.9/(0.05√(2π)) + 0.02); one 2σ off, ln(0.9 e⁻²/(0.05√(2π)) + 0.02); one far off or where
    /// the model draws nothing, ln 0.02.
    #[test]
    fn the_sensor_model_is_a_gaussian_with_outliers() {
        let m = SensorModel::new(0.05, 0.1, 5.0);
        let peak = 0.9 / (0.05 * (2.0 * std::f64::consts::PI).sqrt());
        let near = (peak + 0.02).ln();
        let two = (peak * (-2.0f64).exp() + 0.02).ln();
        assert!((m.pixel(2.0, 2.0) as f64 - near).abs() < 1e-5);
        assert!(
            (m.pixel(2.1, 2.0) as f64 - two).abs() < 1e-4,
            "{}",
            m.pixel(2.1, 2.0)
        );
        assert!((m.pixel(1.9, 2.0) as f64 - two).abs() < 1e-4);
        assert!((m.pixel(4.0, 2.0) as f64 - 0.02f64.ln()).abs() < 1e-6);
        assert!((m.pixel(2.0, 0.0) as f64 - 0.02f64.ln()).abs() < 1e-6);
        let l = m.log_likelihood(&[2.0, 2.0, 0.0], &[2.0, 0.0, 2.0]);
        assert!((l - (near + 0.02f64.ln())).abs() < 1e-5);
    }

    /// Eq. (8) by hand: α/(α + |Δz|) for Δz = 0, 0.1 and no model surface, one pixel not
    /// measured.
    #[test]
    fn the_score_is_the_seeds_kernel() {
        let l = score(&[2.0, 2.0, 2.0, 0.0], &[2.0, 2.1, 0.0, 5.0], 0.1);
        assert!((l - (1.0 + 0.5 + 0.0)).abs() < 1e-6, "{l}");
    }

    /// The score's running sums give the in-order sum's bits: on renders of the sizes the
    /// filter uses and odd sizes, with depth differences of every size, pixels not measured
    /// or not drawn, and where the exactness test fails (tiny terms, NaN, nothing measured)
    /// and the sum is taken in order.
    #[test]
    fn the_score_is_the_in_order_sum_to_the_bit() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        // All but the last may take the running sums (a score that took them where the bound
        // does not hold, at α = 1e-9, differed from the in-order sum in its last bits).
        for (n, alpha) in [
            (176 * 144, 0.1),
            (88 * 72, 0.1),
            (44 * 36, 0.05),
            (1, 0.1),
            (7, 0.1),
            (1001, 0.3),
            (320 * 240, 0.1),
            (176 * 144, 1e-9),
        ] {
            for _ in 0..4 {
                let measured: Vec<f32> = (0..n)
                    .map(|_| match rng.random_range(0..10) {
                        0 => 0.0,
                        _ => rng.random_range(0.3f32..8.0),
                    })
                    .collect();
                let predicted: Vec<f32> = measured
                    .iter()
                    .map(|&m| match rng.random_range(0..10) {
                        0 => 0.0,
                        1 => rng.random_range(0.3f32..11.0),
                        _ => m + rng.random_range(-0.3f32..0.3) * rng.random::<f32>().powi(3),
                    })
                    .collect();
                let want = score_in_order(&measured, &predicted, alpha);
                let got = score(&measured, &predicted, alpha);
                assert_eq!(
                    got.to_bits(),
                    want.to_bits(),
                    "{n} pixels, α {alpha}: {got} {want}"
                );
                // Shorter predictions are cut as the in-order zip cuts them.
                let cut = &predicted[..n / 2];
                let want = score_in_order(&measured, cut, alpha);
                assert_eq!(score(&measured, cut, alpha).to_bits(), want.to_bits());
            }
        }
        // Nothing measured: the in-order sum's zero, sign and all.
        let none = score(&[0.0; 9], &[1.0; 9], 0.1);
        assert_eq!(
            none.to_bits(),
            score_in_order(&[0.0; 9], &[1.0; 9], 0.1).to_bits()
        );
        // A NaN term makes the sum NaN either way.
        assert!(score(&[f32::INFINITY; 9], &[f32::INFINITY; 9], 0.1).is_nan());
    }

    /// Reprojection to the same camera gives the image back; to a quarter-size camera, each
    /// target pixel holds the nearest of the 16 points that fall in it.
    #[test]
    fn reprojection_keeps_depth_and_takes_the_nearest() {
        let big = Intrinsics::from_fov(176, 144, 0.76, 0.6).unwrap();
        let pose = CameraState {
            position: [2.0, 2.0, 1.0],
            rpy: [0.0, 0.0, 0.3],
        };
        let mut d = Vec::new();
        BoxRoom { pillars: true }
            .render_batch(&big, &[pose.pose()], RANGE, &mut d)
            .unwrap();
        let img = DepthImage {
            width: 176,
            height: 144,
            data: d.clone(),
        };
        let same = reproject(&img, &big, &big);
        assert_eq!(same, d);
        let small = big.scaled(44, 36);
        let r = reproject(&img, &big, &small);
        // Scaled by 4, a target pixel's points are those of one 4 × 4 block.
        for tv in 0..36u32 {
            for tu in 0..44u32 {
                let nearest = (0..16)
                    .map(|k| img.at(4 * tu + k % 4, 4 * tv + k / 4))
                    .fold(f32::INFINITY, f32::min);
                assert_eq!(r[(tv * 44 + tu) as usize], nearest, "({tu}, {tv})");
            }
        }
    }

    /// The median and largest planar position error, m, and the largest yaw error, rad, of
    /// tracking from a known start as the camera moves `step` m a frame down the room with no
    /// odometry, swaying 10 cm in y and 0.1 rad in yaw like a pushed wagon.
    fn track(pillars: bool, motion: MotionModel, step: f64) -> (f64, f64, f64) {
        let config = DepthMclConfig {
            motion,
            ..DepthMclConfig::default()
        };
        track_with(pillars, config, step)
    }

    /// The twelve triangles of the box `lo..hi`.
    fn box_triangles(lo: [f64; 3], hi: [f64; 3]) -> Vec<[[f64; 3]; 3]> {
        let corner = |k: usize| {
            [
                if k & 1 == 0 { lo[0] } else { hi[0] },
                if k & 2 == 0 { lo[1] } else { hi[1] },
                if k & 4 == 0 { lo[2] } else { hi[2] },
            ]
        };
        // Each face by its four corners (bit patterns), split along a diagonal.
        let faces = [
            [0, 1, 3, 2],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 3, 7, 6],
            [0, 2, 6, 4],
            [1, 3, 7, 5],
        ];
        faces
            .iter()
            .flat_map(|f| {
                [
                    [corner(f[0]), corner(f[1]), corner(f[2])],
                    [corner(f[0]), corner(f[2]), corner(f[3])],
                ]
            })
            .collect()
    }

    /// The room's surfaces as triangles: its walls, floor and ceiling, and its pillars.
    fn room_triangles(pillars: bool) -> Vec<[[f64; 3]; 3]> {
        let mut t = box_triangles([0.0; 3], [10.0, 4.0, 3.0]);
        for (a, b) in PILLARS.into_iter().filter(|_| pillars) {
            t.extend(box_triangles(a, b));
        }
        t
    }

    fn track_with(pillars: bool, config: DepthMclConfig, step: f64) -> (f64, f64, f64) {
        let field = (config.likelihood == Likelihood::Field).then(|| {
            DistanceField::new(&room_triangles(pillars), config.field_cell, 0.5, 10_000_000)
                .unwrap()
        });
        let mut room = MeshModel {
            renderer: BoxRoom { pillars },
            field,
        };
        let start = CameraState {
            position: [1.0, 2.0, 1.0],
            rpy: [0.0, 0.0, 0.2],
        };
        let mut mcl = DepthMcl::new(config, start, 3);
        let mut truth = start;
        let (mut errors, mut yaw) = (Vec::new(), 0.0f64);
        for k in 0..60 {
            truth.position[0] += step;
            truth.position[1] = 2.0 + 0.1 * (k as f64 * 0.2).sin();
            truth.rpy[2] = 0.2 + 0.1 * (k as f64 * 0.15).sin();
            let z = render(&room.renderer, &truth);
            let est = mcl.update(&mut room, &intr(), &z, RANGE, None).unwrap();
            errors.push(
                (est.state.position[0] - truth.position[0])
                    .hypot(est.state.position[1] - truth.position[1]),
            );
            yaw = yaw.max(wrap_angle(est.state.rpy[2] - truth.rpy[2]).abs());
        }
        errors.sort_by(f64::total_cmp);
        (errors[errors.len() / 2], errors[errors.len() - 1], yaw)
    }

    /// A model that hands over its images wrongly: one short, or one twice.
    struct Faulty {
        room: BoxRoom,
        twice: bool,
    }

    impl DepthModel for Faulty {
        fn render_batch(
            &mut self,
            intr: &Intrinsics,
            poses: &[Pose3],
            far: f64,
            out: &mut Vec<f32>,
        ) -> Result<(), String> {
            self.room.render_batch(intr, &poses[1..], far, out)
        }

        fn render_each(
            &mut self,
            intr: &Intrinsics,
            poses: &[Pose3],
            far: f64,
            each: &mut dyn FnMut(usize, &[f32]),
        ) -> Result<(), String> {
            if !self.twice {
                return self.room.render_each(intr, &poses[1..], far, each);
            }
            self.room.render_each(intr, poses, far, &mut |k, image| {
                each(k.min(poses.len() - 2), image)
            })
        }
    }

    /// Images missing or given twice are errors naming what was expected, not scores.
    #[test]
    fn a_model_that_misses_or_repeats_an_image_is_an_error() {
        let start = CameraState {
            position: [1.0, 2.0, 1.0],
            rpy: [0.0, 0.0, 0.2],
        };
        let z = render(&BoxRoom { pillars: false }, &start);
        for twice in [false, true] {
            let mut model = Faulty {
                room: BoxRoom { pillars: false },
                twice,
            };
            let mut mcl = DepthMcl::new(DepthMclConfig::default(), start, 3);
            let e = mcl
                .update(&mut model, &intr(), &z, RANGE, None)
                .unwrap_err();
            let expected = if twice {
                "expected one image of each"
            } else {
                "rendered no image for particle"
            };
            assert!(e.contains(expected), "{e}");
        }
    }

    /// Among pillars, both models follow a camera moving 5 cm a frame (a σ of the walk) within
    /// the seed's 7 cm. In a featureless box the seed's random walk falls behind along the
    /// room, where the depth constrains it least, and the lag grows; particles that carry
    /// their own velocity keep up.
    #[test]
    fn the_filter_tracks_a_moving_camera_without_odometry() {
        for m in [MotionModel::RandomWalk, MotionModel::ConstantVelocity] {
            let (median, worst, yaw) = track(true, m, 0.05);
            assert!(
                median < 0.07 && worst < 0.15,
                "{m:?}: median {median}, worst {worst}"
            );
            assert!(yaw < 3f64.to_radians(), "{m:?}: {yaw}");
        }
        let (median, ..) = track(false, MotionModel::RandomWalk, 0.05);
        assert!(median > 0.3, "the random walk kept up: median {median}");
        let (median, ..) = track(false, MotionModel::ConstantVelocity, 0.05);
        assert!(median < 0.07, "median {median}");
    }

    /// Weighing by `likelihood`, the filter follows the camera moving 5 cm a frame among
    /// pillars within the seed's 7 cm (median; 15 cm at worst, 3° of yaw), with either motion
    /// model.
    fn tracks_among_pillars(likelihood: Likelihood) {
        for motion in [MotionModel::RandomWalk, MotionModel::ConstantVelocity] {
            let config = DepthMclConfig {
                motion,
                likelihood,
                ..DepthMclConfig::default()
            };
            let (median, worst, yaw) = track_with(true, config, 0.05);
            assert!(
                median < 0.07 && worst < 0.15 && yaw < 3f64.to_radians(),
                "{likelihood:?}, {motion:?}: median {median}, worst {worst}, yaw {yaw}"
            );
        }
    }

    /// The per-pixel sensor model in place of the seed's weighting also tracks the camera
    /// within the seed's 7 cm, with either motion model, among pillars.
    #[test]
    fn the_sensor_model_tracks_a_moving_camera() {
        tracks_among_pillars(Likelihood::Sensor);
    }

    /// The likelihood field in 3D, with no render, also tracks the camera within the seed's
    /// 7 cm, with either motion model, among pillars; asked of a model without a field, the
    /// filter says so.
    #[test]
    fn the_likelihood_field_tracks_a_moving_camera() {
        tracks_among_pillars(Likelihood::Field);
        let config = DepthMclConfig {
            likelihood: Likelihood::Field,
            ..DepthMclConfig::default()
        };
        let start = CameraState {
            position: [1.0, 2.0, 1.0],
            rpy: [0.0; 3],
        };
        let mut room = BoxRoom { pillars: true };
        let z = render(&room, &start);
        let e = DepthMcl::new(config, start, 1)
            .update(&mut room, &intr(), &z, RANGE, None)
            .unwrap_err();
        assert!(e.contains("distance field"), "{e}");
    }

    /// The field's points are the measured pixels' points in the body frame: a pixel on the
    /// optical axis lies straight ahead, one right of and below the centre lies to the right
    /// (−y) and below (−z); invalid pixels give none.
    #[test]
    fn field_points_are_back_projected_into_the_body_frame() {
        let i = Intrinsics::from_fov(8, 6, 1.0, 0.8).unwrap();
        let mut d = vec![0.0f32; 48];
        // With 2 independent pixels the grid's step is floor(√(48/8)) = 2, from pixel 1.
        d[3 * 8 + 3] = 2.0;
        d[5 * 8 + 7] = 3.0;
        d[9] = f32::NAN; // pixel (1, 1)
        let p = field_points(&i, &d, 2.0);
        assert_eq!(p.len(), 2, "{p:?}");
        let want = |u: f64, v: f64, z: f64| [z, -(u - i.cx) / i.fx * z, -(v - i.cy) / i.fy * z];
        for (got, w) in p.iter().zip([want(3.0, 3.0, 2.0), want(7.0, 5.0, 3.0)]) {
            for k in 0..3 {
                assert!((got[k] - w[k]).abs() < 1e-12, "{got:?} vs {w:?}");
            }
        }
        assert!(
            p[1][1] < 0.0 && p[1][2] < 0.0,
            "right and below: {:?}",
            p[1]
        );
    }

    /// A pose's log-likelihood on the field is the sum over the points placed by the pose's
    /// own transform: a point on a wall scores near the Gaussian's peak, one 10 cm off it near
    /// the Gaussian there.
    #[test]
    fn the_field_log_likelihood_sums_the_points_placed_by_the_pose() {
        let field = DistanceField::new(&room_triangles(true), 0.05, 0.5, 10_000_000).unwrap();
        let sensor = SensorModel::new(0.05, 0.1, RANGE);
        // Points ahead of the camera, near and far, up and down, left and right.
        let points: Vec<[f64; 3]> = (0..40)
            .map(|k| {
                let k = k as f64;
                [0.5 + 0.2 * k, (k * 0.7).sin(), 0.8 * (k * 1.3).cos()]
            })
            .collect();
        let poses: Vec<Pose3> = (0..9)
            .map(|k| {
                let k = k as f64;
                CameraState {
                    position: [1.0 + 0.3 * k, 2.0 - 0.1 * k, 1.0 + 0.05 * k],
                    rpy: [0.02 * k, -0.03 * k, 0.4 * k],
                }
                .pose()
            })
            .collect();
        for (k, pose) in poses.iter().enumerate() {
            let got = field_log_likelihood(&field, &sensor, pose, &points);
            let want: f64 = points
                .iter()
                .map(|p| sensor.lookup(field.distance(pose.transform_point(*p)) as f32) as f64)
                .sum();
            assert!(
                (got - want).abs() < 1e-6 * want.abs(),
                "pose {k}: {got} vs {want}"
            );
        }
        // The camera 1 m from the west wall (x = 0), looking at it: a point 1 m ahead is on
        // it, one 0.9 m ahead 10 cm off it, each within half a voxel's diagonal (the field's
        // error) of that distance. Placed by a wrong transform (behind the camera, say) they
        // would lie metres from any surface and score the outlier's floor.
        let facing = CameraState {
            position: [1.0, 2.0, 1.5],
            rpy: [0.0, 0.0, std::f64::consts::PI],
        }
        .pose();
        let l = field_log_likelihood(
            &field,
            &sensor,
            &facing,
            &[[1.0, 0.0, 0.0], [0.9, 0.0, 0.0]],
        );
        let h = 0.05 * 3f64.sqrt() / 2.0;
        let lo = sensor.exact(h) + sensor.exact(0.1 + h);
        let hi = sensor.exact(0.0) + sensor.exact(0.1 - h);
        assert!(lo <= l && l <= hi, "{l} outside [{lo}, {hi}]");
    }

    /// In six degrees of freedom the filter (the seed's random walk, 400 particles) also
    /// follows the camera's height, roll and pitch (a hand-held camera's sway) within the
    /// seed's 7 cm and 2° (medians after the first eight frames).
    #[test]
    fn the_filter_tracks_six_degrees_of_freedom() {
        let motion = MotionModel::RandomWalk;
        let start = CameraState {
            position: [1.0, 2.0, 1.2],
            rpy: [0.0, 0.0, 0.0],
        };
        let config = DepthMclConfig {
            sigma: [
                0.03,
                0.03,
                0.02,
                1f64.to_radians(),
                1f64.to_radians(),
                1.5f64.to_radians(),
            ],
            particles: 400,
            motion,
            ..DepthMclConfig::default()
        };
        let mut mcl = DepthMcl::new(config, start, 9);
        let mut room = BoxRoom { pillars: true };
        let mut truth = start;
        let mut errors = Vec::new();
        for k in 0..60 {
            let t = k as f64;
            truth.position[0] += 0.04;
            truth.position[2] = 1.2 + 0.05 * (t * 0.3).sin();
            truth.rpy = [
                3f64.to_radians() * (t * 0.25).sin(),
                4f64.to_radians() * (t * 0.2).cos() - 4f64.to_radians(),
                0.1 * (t * 0.1).sin(),
            ];
            let z = render(&room, &truth);
            let est = mcl.update(&mut room, &intr(), &z, RANGE, None).unwrap();
            let d: f64 = (0..3)
                .map(|i| (est.state.position[i] - truth.position[i]).powi(2))
                .sum::<f64>()
                .sqrt();
            let a = (0..3)
                .map(|i| wrap_angle(est.state.rpy[i] - truth.rpy[i]).abs())
                .fold(0.0, f64::max);
            errors.push((d, a));
        }
        // After the first second (settling), within the seed's 7 cm and 2°.
        let mut d: Vec<f64> = errors[8..].iter().map(|e| e.0).collect();
        let mut a: Vec<f64> = errors[8..].iter().map(|e| e.1).collect();
        d.sort_by(f64::total_cmp);
        a.sort_by(f64::total_cmp);
        assert!(
            d[d.len() / 2] < 0.07,
            "{motion:?}: median {}",
            d[d.len() / 2]
        );
        assert!(
            a[a.len() / 2] < 2f64.to_radians(),
            "{motion:?}: median {}°",
            a[a.len() / 2].to_degrees()
        );
    }

    /// With every particle at one pose the scores tie: the weights stay uniform instead of
    /// dividing by zero.
    #[test]
    fn tied_scores_give_uniform_weights() {
        let start = CameraState {
            position: [1.0, 2.0, 1.0],
            rpy: [0.0; 3],
        };
        let config = DepthMclConfig {
            sigma: [0.0; 6],
            particles: 10,
            ..DepthMclConfig::default()
        };
        let mut mcl = DepthMcl::new(config, start, 1);
        let mut room = BoxRoom { pillars: true };
        let z = render(&room, &start);
        let est = mcl.update(&mut room, &intr(), &z, RANGE, None).unwrap();
        for k in 0..3 {
            assert!((est.state.position[k] - start.position[k]).abs() < 1e-12);
        }
        assert!(est.sd.iter().all(|s| *s < 1e-6), "{:?}", est.sd);
        let e = mcl
            .update(&mut room, &intr(), &[1.0; 3], RANGE, None)
            .unwrap_err();
        assert!(e.contains("expected 44×36"), "{e}");
    }

    /// The SR4000's field of view at 22×18 px, for the tests that render many hypotheses.
    fn small_intr() -> Intrinsics {
        Intrinsics::from_fov(22, 18, 43.6f64.to_radians(), 34.6f64.to_radians()).unwrap()
    }

    /// The box room's cells of 0.25 m whose centres lie 0.3 m inside the walls.
    fn room_free_cells() -> Vec<[f64; 2]> {
        let mut free = Vec::new();
        for i in 0..40 {
            for j in 0..16 {
                let c = [0.125 + 0.25 * i as f64, 0.125 + 0.25 * j as f64];
                if c[0] > 0.3 && c[0] < 9.7 && c[1] > 0.3 && c[1] < 3.7 {
                    free.push(c);
                }
            }
        }
        free
    }

    /// A kidnapping: a camera tracked at rest near one end of the room (odometry: no motion)
    /// is carried 6.7 m to the other end and turned round. With recovery (hypotheses drawn in
    /// the room's free cells as the fit drops, refined by the search), the filter finds it
    /// again within 5 frames; the seed's tracking filter alone stays lost.
    #[test]
    fn augmented_mcl_recovers_from_a_kidnapping() {
        let small = small_intr();
        let start = CameraState {
            position: [1.5, 2.0, 1.0],
            rpy: [0.0, 0.0, 0.1],
        };
        let kidnapped = CameraState {
            position: [8.2, 1.8, 1.0],
            rpy: [0.0, 0.0, std::f64::consts::PI - 0.2],
        };
        let free = room_free_cells();
        let run = |recover: bool| {
            let config = DepthMclConfig {
                particles: 200,
                alpha_slow: if recover { 0.001 } else { 0.0 },
                alpha_fast: if recover { 0.1 } else { 0.0 },
                max_particles: Some(1000),
                ..DepthMclConfig::default()
            };
            let mut mcl = DepthMcl::new(config, start, 5);
            mcl.set_free_space(free.clone(), 0.25);
            let mut room = BoxRoom { pillars: true };
            let mut out = Vec::new();
            let mut counts = Vec::new();
            for k in 0..60 {
                let truth = if k < 15 { start } else { kidnapped };
                let mut z = Vec::new();
                room.render_batch(&small, &[truth.pose()], RANGE, &mut z)
                    .unwrap();
                let est = mcl
                    .update(&mut room, &small, &z, RANGE, Some(&Pose2::IDENTITY))
                    .unwrap();
                out.push(
                    (est.state.position[0] - truth.position[0])
                        .hypot(est.state.position[1] - truth.position[1]),
                );
                counts.push(mcl.searched());
            }
            (out, counts)
        };
        let (errors, counts) = run(true);
        assert!(errors[..15].iter().all(|e| *e < 0.07), "{errors:?}");
        assert!(
            errors[20..].iter().all(|e| *e < 0.1),
            "not recovered within 5 frames: {errors:?}"
        );
        // The fit's drop set off a search of many hypotheses.
        assert!(counts[15] > 20, "{counts:?}");
        let (lost, _) = run(false);
        assert!(lost[55..].iter().all(|e| *e > 1.0), "{lost:?}");
    }

    /// A global start: 1,000 hypotheses drawn over the room's free cells at any yaw and
    /// refined by the search put the filter within half a metre of a camera at rest, with no
    /// hint of where it is, and the random walk closes in within 8 frames (1 s at 8 Hz).
    #[test]
    fn a_global_start_finds_the_camera() {
        let small = small_intr();
        let truth = CameraState {
            position: [6.4, 1.2, 1.0],
            rpy: [0.0, 0.0, 2.5],
        };
        let free = room_free_cells();
        let config = DepthMclConfig {
            alpha_slow: 0.001,
            alpha_fast: 0.1,
            max_particles: Some(1000),
            ..DepthMclConfig::default()
        };
        // The filter is told only the camera's height (and level roll and pitch).
        let told = CameraState {
            position: [0.0, 0.0, 1.0],
            rpy: [0.0; 3],
        };
        let mut mcl = DepthMcl::new(config, told, 11);
        mcl.set_free_space(free, 0.25);
        mcl.start_global();
        let mut room = BoxRoom { pillars: true };
        let mut z = Vec::new();
        room.render_batch(&small, &[truth.pose()], RANGE, &mut z)
            .unwrap();
        let mut errors = Vec::new();
        for _ in 0..12 {
            let est = mcl
                .update(&mut room, &small, &z, RANGE, Some(&Pose2::IDENTITY))
                .unwrap();
            errors.push((
                (est.state.position[0] - truth.position[0])
                    .hypot(est.state.position[1] - truth.position[1]),
                wrap_angle(est.state.rpy[2] - truth.rpy[2]).abs(),
            ));
        }
        assert!(
            errors[0].0 < 0.5
                && errors[8..]
                    .iter()
                    .all(|e| e.0 < 0.1 && e.1 < 3f64.to_radians()),
            "{errors:?}"
        );
    }
}
