//! The Kinect v1 RGB-D camera: presets, mounting, and its depth noise models.
//!
//! Specs from `shared/reference/sensors-robot-metrics.md` §3.1: 57° × 43° field of view, 30 Hz,
//! colour 640×480, depth 640×480 as OpenNI delivers it (320×240 in seed 000, after the retail
//! spec list), a valid range of 0.8–4.0 m by default and 1.2–3.5 m in the seed 000 preset.
//!
//! Noise models, applied on the CPU to the noise-free render with a seeded stream:
//! - [`NoiseModel::Nguyen`]: Nguyen, Izadi & Lovell 2012 (§3.3): axial σ_z = 0.0012 +
//!   0.0019 (z − 0.4)² m, plus 0.0001 θ² / (√z (π/2 − θ)²) above θ = π/3, and lateral
//!   σ_L = 0.8 + 0.035 θ / (π/2 − θ) px, θ the incidence angle (here from the depth image's own
//!   normals);
//! - [`NoiseModel::IclNuim`]: the ICL-NUIM / simkinect pipeline (§3.4): 0.5 px Gaussian lateral
//!   jitter with bilinear resampling, disparity f·b/z quantised to 1/8 px, a window consistency
//!   filter that drops pixels near depth edges, and Gaussian disparity noise of 1/6 step.
//!
//! Pixels outside the valid range, or dropped by a model, are invalid (0).

use crate::config::{SpecError, check_mount, check_range, mount_pose};
use crate::render::{RenderError, Renderer, optical_from_body};
use futago_msgs::camera::{DepthImage, Intrinsics, RgbImage, RgbdFrame};
use futago_msgs::{Pose3, Time};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;
use rapier3d::math::Pose;
use serde::Deserialize;
use std::path::Path;

/// Named parameter sets.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum KinectPreset {
    /// Kinect v1 as OpenNI drivers deliver it: 640×480 depth, 0.8–4.0 m.
    KinectV1,
    /// Seed 000's use: 320×240 depth, the retail 1.2–3.5 m play space.
    Seed000,
    /// MESA SR4000 time-of-flight camera (seed 002): 176×144, 43.6° × 34.6°, 0.1–5.0 m, the
    /// figures commonly quoted from MESA's datasheet (issue 17); its intensity image stands
    /// in for colour at the same size. Its ±1 cm is `noise = { model = "gaussian", sigma =
    /// 0.01 }`.
    Sr4000,
    /// One camera of seed 001's Point Grey Digiclops trinocular head: 320×240 at 28 Hz. The
    /// seed gives no focal length; futago takes 60° × 46.8° (square pixels). Depth, which the
    /// camera does not measure, is rendered only for scoring, over 0.1–30 m.
    Digiclops,
}

impl KinectPreset {
    /// The preset's horizontal and vertical fields of view as declared, degrees.
    pub fn fov_deg(self) -> [f64; 2] {
        match self {
            KinectPreset::KinectV1 | KinectPreset::Seed000 => [57.0, 43.0],
            KinectPreset::Sr4000 => [43.6, 34.6],
            KinectPreset::Digiclops => [60.0, 46.8],
        }
    }
}

/// Depth noise model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, serde::Serialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum NoiseModel {
    /// Exact depth (still cut to the valid range).
    #[default]
    None,
    /// Nguyen, Izadi & Lovell 2012 axial and lateral noise.
    Nguyen,
    /// ICL-NUIM's disparity-quantised model (simkinect).
    IclNuim,
    /// Independent Gaussian noise of `sigma` on every pixel's depth (a time-of-flight camera's
    /// datasheet accuracy taken as 1σ).
    Gaussian,
}

/// Noise parameters (the ICL-NUIM ones; Nguyen's are fixed by the paper).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct NoiseConfig {
    pub model: NoiseModel,
    /// Projector–camera baseline for disparity, m (simkinect: 0.075).
    pub baseline: f64,
    /// Disparity step, px (1/8 in the Kinect).
    pub disparity_step: f64,
    /// Lateral jitter of the ICL-NUIM model, px (0.5).
    pub jitter: f64,
    /// Drop pixels whose neighbourhood is inconsistent (ICL-NUIM's dot-pattern filter).
    pub edge_filter: bool,
    /// Standard deviation of the Gaussian model, m.
    pub sigma: f64,
    /// Independent Gaussian noise on every colour sample, 8-bit levels (0: exact renders).
    /// A camera's read and shot noise, for image features that would otherwise see
    /// noise-free pixels; independent of `model`.
    pub rgb_sigma: f64,
}

impl Default for NoiseConfig {
    fn default() -> Self {
        NoiseConfig {
            model: NoiseModel::None,
            baseline: 0.075,
            disparity_step: 0.125,
            jitter: 0.5,
            edge_filter: true,
            sigma: 0.01,
            rgb_sigma: 0.0,
        }
    }
}

/// A Kinect as a scenario configures it: `[[camera]]` tables.
#[derive(Debug, Clone, Deserialize, serde::Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct KinectConfig {
    #[serde(default = "default_name")]
    pub name: String,
    #[serde(default = "default_preset")]
    pub preset: KinectPreset,
    /// Mounting position of the camera body frame on the robot base frame, m.
    #[serde(default = "default_mount")]
    pub xyz: [f64; 3],
    /// Mounting roll, pitch (positive looks down), yaw, degrees.
    #[serde(default)]
    pub rpy_deg: [f64; 3],
    /// Colour image size [width, height].
    pub rgb_size: Option<[u32; 2]>,
    /// Depth image size [width, height].
    pub depth_size: Option<[u32; 2]>,
    /// Field of view [horizontal, vertical], degrees.
    pub fov_deg: Option<[f64; 2]>,
    pub range_min: Option<f64>,
    pub range_max: Option<f64>,
    /// Frame rate, Hz.
    pub rate: Option<f64>,
    #[serde(default)]
    pub noise: NoiseConfig,
    /// The joint (`[[joint]]` name) the camera rides on; none: fixed to the base. `xyz` and
    /// `rpy_deg` are then its mount at the joint's zero angle.
    #[serde(default)]
    pub joint: Option<String>,
    /// The agent (`[[agent]]` name) that carries the camera instead of the robot: a person
    /// with a hand-held camera or pushing a wagon. `xyz` and `rpy_deg` are then its mount on
    /// the agent's frame (on the floor, x where it walks). Such a camera has no odometry.
    #[serde(default)]
    pub carrier: Option<String>,
    /// The carrier's wobble, between its frame and the mount.
    #[serde(default)]
    pub sway: Option<crate::sway::SwayConfig>,
}

fn default_name() -> String {
    "kinect".into()
}
fn default_preset() -> KinectPreset {
    KinectPreset::KinectV1
}
/// On top of the Create's body (0.36 m), set back from its front edge so it sees none of it.
fn default_mount() -> [f64; 3] {
    [0.1, 0.0, 0.42]
}

/// A resolved, checked camera model.
#[derive(Debug, Clone, PartialEq)]
pub struct KinectSpec {
    pub name: String,
    pub rgb: Intrinsics,
    pub depth: Intrinsics,
    pub range_min: f64,
    pub range_max: f64,
    pub rate: f64,
    pub noise: NoiseConfig,
    /// Camera body frame (x forward, y left, z up) in the robot base frame (on a joint: in
    /// the joint's frame, which is the base frame at the joint's zero angle).
    pub mount: Pose,
    /// The joint it rides on, if any.
    pub joint: Option<String>,
    /// The agent that carries it, if not the robot.
    pub carrier: Option<String>,
    pub sway: Option<crate::sway::SwayConfig>,
}

impl KinectConfig {
    /// A preset with default mounting.
    pub fn preset(preset: KinectPreset) -> KinectConfig {
        KinectConfig {
            name: default_name(),
            preset,
            xyz: default_mount(),
            rpy_deg: [0.0; 3],
            rgb_size: None,
            depth_size: None,
            fov_deg: None,
            range_min: None,
            range_max: None,
            rate: None,
            noise: NoiseConfig::default(),
            joint: None,
            carrier: None,
            sway: None,
        }
    }

    /// The preset with overrides applied, checked; `key` locates this table in `file`.
    pub fn resolve(&self, file: &Path, key: &str) -> Result<KinectSpec, SpecError> {
        let k = |s: &str| format!("{key}.{s}");
        crate::config::check_name(file, &k("name"), &self.name)?;
        let (depth_size, rgb_size, range) = match self.preset {
            KinectPreset::KinectV1 => ([640, 480], [640, 480], (0.8, 4.0)),
            KinectPreset::Seed000 => ([320, 240], [640, 480], (1.2, 3.5)),
            KinectPreset::Sr4000 => ([176, 144], [176, 144], (0.1, 5.0)),
            KinectPreset::Digiclops => ([320, 240], [320, 240], (0.1, 30.0)),
        };
        let fov = self.preset.fov_deg();
        let rgb_size = self.rgb_size.unwrap_or(rgb_size);
        let depth_size = self.depth_size.unwrap_or(depth_size);
        let [fh, fv] = self.fov_deg.unwrap_or(fov);
        check_range(file, &k("fov_deg[0]"), fh, 1.0, 170.0, "degrees")?;
        check_range(file, &k("fov_deg[1]"), fv, 1.0, 170.0, "degrees")?;
        let intr = |name: &str, [w, h]: [u32; 2]| {
            Intrinsics::from_fov(w, h, fh.to_radians(), fv.to_radians())
                .map_err(|e| SpecError::new(file, k(name), e))
        };
        let rgb = intr("rgb_size", rgb_size)?;
        let depth = intr("depth_size", depth_size)?;
        let range_min = self.range_min.unwrap_or(range.0);
        let range_max = self.range_max.unwrap_or(range.1);
        check_range(file, &k("range_min"), range_min, 0.02, 100.0, "m")?;
        check_range(
            file,
            &k("range_max"),
            range_max,
            range_min + 1e-3,
            100.0,
            "m (above range_min)",
        )?;
        let default_rate = if self.preset == KinectPreset::Digiclops {
            28.0
        } else {
            30.0
        };
        let rate = self.rate.unwrap_or(default_rate);
        check_range(file, &k("rate"), rate, 0.01, 1000.0, "Hz")?;
        let n = &self.noise;
        check_range(file, &k("noise.baseline"), n.baseline, 1e-3, 1.0, "m")?;
        check_range(
            file,
            &k("noise.disparity_step"),
            n.disparity_step,
            1e-4,
            4.0,
            "px",
        )?;
        check_range(file, &k("noise.jitter"), n.jitter, 0.0, 10.0, "px")?;
        check_range(file, &k("noise.sigma"), n.sigma, 0.0, 1.0, "m")?;
        check_range(
            file,
            &k("noise.rgb_sigma"),
            n.rgb_sigma,
            0.0,
            64.0,
            "8-bit levels",
        )?;
        check_mount(file, key, self.xyz, self.rpy_deg)?;
        if let Some(s) = &self.sway {
            s.validate(file, &k("sway"))?;
        }
        if self.carrier.is_some() && self.joint.is_some() {
            return Err(SpecError::new(
                file,
                k("carrier"),
                "a camera rides on a joint of the robot or on a carrier, not both",
            ));
        }
        let mount = mount_pose(self.xyz, self.rpy_deg);
        Ok(KinectSpec {
            name: self.name.clone(),
            rgb,
            depth,
            range_min,
            range_max,
            rate,
            noise: *n,
            mount,
            joint: self.joint.clone(),
            carrier: self.carrier.clone(),
            sway: self.sway,
        })
    }
}

impl KinectSpec {
    /// Adds the colour noise (`noise.rgb_sigma`) in place; draws nothing when it is 0.
    pub fn apply_rgb_noise(&self, rgb: &mut futago_msgs::camera::RgbImage, rng: &mut ChaCha8Rng) {
        let s = self.noise.rgb_sigma;
        if s <= 0.0 {
            return;
        }
        for v in rgb.data.iter_mut() {
            let n: f64 = StandardNormal.sample(rng);
            *v = round_to_i64(*v as f64 + s * n).clamp(0, 255) as u8;
        }
    }
}

/// simkinect's constant in its final noise step (disparity-like units of depth in cm).
const ICL_DISPARITY_CM: f64 = 35130.0;

impl KinectSpec {
    /// Applies the noise model and the valid range to a noise-free depth image in place.
    pub fn apply_noise(&self, depth: &mut DepthImage, rng: &mut ChaCha8Rng) {
        self.apply_noise_on_grid(depth, rng, 1);
    }

    /// As [`KinectSpec::apply_noise`], for a consumer that reads only the pixels of every
    /// `stride`-th column and row (from 0): those pixels get the very values `apply_noise`
    /// would give them, the noise stream advances as far, and every other pixel is left
    /// invalid (0). The Nguyen model's work per pixel (its draws, incidence, shifts and axial
    /// noise) is spent on the grid alone: its pixels draw from generators of their own; the
    /// other models noise every pixel, then clear those off the grid. A stride of 0 or 1 is
    /// every pixel.
    pub fn apply_noise_on_grid(&self, depth: &mut DepthImage, rng: &mut ChaCha8Rng, stride: u32) {
        self.noise_on_grid_keyed(depth, rng, stride);
    }

    /// [`KinectSpec::apply_noise_on_grid`], giving the Nguyen model's key of the frame (its
    /// one draw from the stream; see [`nguyen`]), with which [`KinectSpec::complete_noise`]
    /// noises the rest of the image afterwards.
    fn noise_on_grid_keyed(
        &self,
        depth: &mut DepthImage,
        rng: &mut ChaCha8Rng,
        stride: u32,
    ) -> Option<u64> {
        let stride = stride.max(1);
        let mut key = None;
        match self.noise.model {
            NoiseModel::None => {}
            NoiseModel::Nguyen => {
                let frame: u64 = rng.random();
                nguyen(depth, &self.depth, frame, stride);
                key = Some(frame);
            }
            NoiseModel::IclNuim => icl_nuim(depth, &self.depth, &self.noise, rng),
            NoiseModel::Gaussian => {
                for z in &mut depth.data {
                    if *z > 0.0 {
                        *z += (self.noise.sigma * normal(rng)) as f32;
                    }
                }
            }
        }
        let (lo, hi) = (self.range_min as f32, self.range_max as f32);
        let in_range = |z: &mut f32| {
            if !(*z >= lo && *z <= hi) {
                *z = 0.0;
            }
        };
        if stride == 1 {
            depth.data.iter_mut().for_each(in_range);
            return key;
        }
        let stride = stride as usize;
        for (v, row) in depth
            .data
            .chunks_mut(depth.width.max(1) as usize)
            .enumerate()
        {
            if !v.is_multiple_of(stride) {
                row.fill(0.0);
                continue;
            }
            for (u, z) in row.iter_mut().enumerate() {
                if u.is_multiple_of(stride) {
                    in_range(z);
                } else {
                    *z = 0.0;
                }
            }
        }
        key
    }

    /// Whether a frame noised on a grid can be noised whole afterwards by
    /// [`KinectSpec::complete_noise`]: with no noise, or the Nguyen model's, whose pixels draw
    /// from generators of their own keyed by the frame (the other models draw every pixel
    /// from the camera's stream in turn).
    pub fn noise_completes(&self) -> bool {
        matches!(self.noise.model, NoiseModel::None | NoiseModel::Nguyen)
    }

    /// Noises the noise-free `depth` whole, as [`KinectSpec::apply_noise`] would, for the
    /// frame whose grid [`KinectSpec::noise_on_grid_keyed`] noised with `key`: every pixel of
    /// that grid gets the value it got then, and nothing is drawn from the stream. `None`
    /// where the model cannot ([`KinectSpec::noise_completes`]).
    fn complete_noise(&self, depth: &mut DepthImage, key: Option<u64>) -> Option<()> {
        match (self.noise.model, key) {
            (NoiseModel::None, _) => {}
            (NoiseModel::Nguyen, Some(frame)) => nguyen(depth, &self.depth, frame, 1),
            _ => return None,
        }
        let (lo, hi) = (self.range_min as f32, self.range_max as f32);
        for z in &mut depth.data {
            if !(*z >= lo && *z <= hi) {
                *z = 0.0;
            }
        }
        Some(())
    }
}

fn normal(rng: &mut ChaCha8Rng) -> f64 {
    StandardNormal.sample(rng)
}

/// The rays of a depth image's pixels: `(u − cx) / fx` for each column and `(v − cy) / fy`
/// for each row, so that back-projecting a pixel is two multiplications (the same values as
/// [`Intrinsics::back_project`], which divides for every pixel).
struct PixelRays {
    x: Vec<f64>,
    y: Vec<f64>,
}

impl PixelRays {
    fn new(d: &DepthImage, intr: &Intrinsics) -> PixelRays {
        PixelRays {
            x: (0..d.width)
                .map(|u| (u as f64 - intr.cx) / intr.fx)
                .collect(),
            y: (0..d.height)
                .map(|v| (v as f64 - intr.cy) / intr.fy)
                .collect(),
        }
    }

    fn back_project(&self, u: usize, v: usize, z: f64) -> [f64; 3] {
        [self.x[u] * z, self.y[v] * z, z]
    }
}

/// The cosine of the incidence angle at pixel (u, v), from the depth image's local surface
/// normal, in [0, 1]; none where the angle is taken as zero (no neighbour on the same surface
/// both ways, or a degenerate normal).
fn incidence_cos(d: &DepthImage, rays: &PixelRays, u: u32, v: u32) -> Option<f64> {
    let z = d.at(u, v) as f64;
    let p = rays.back_project(u as usize, v as usize, z);
    // Neighbours on the same surface: within 5 % in depth.
    let near = |uu: i64, vv: i64| -> Option<[f64; 3]> {
        if uu < 0 || vv < 0 || uu >= d.width as i64 || vv >= d.height as i64 {
            return None;
        }
        let zz = d.at(uu as u32, vv as u32) as f64;
        (zz > 0.0 && (zz - z).abs() < 0.05 * z)
            .then(|| rays.back_project(uu as usize, vv as usize, zz))
    };
    let (u, v) = (u as i64, v as i64);
    let du = near(u + 1, v)
        .map(|q| sub(q, p))
        .or_else(|| near(u - 1, v).map(|q| sub(p, q)));
    let dv = near(u, v + 1)
        .map(|q| sub(q, p))
        .or_else(|| near(u, v - 1).map(|q| sub(p, q)));
    let (Some(a), Some(b)) = (du, dv) else {
        return None;
    };
    let n = [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ];
    let nn = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    let pp = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
    if nn == 0.0 || pp == 0.0 {
        return None;
    }
    let c = (n[0] * p[0] + n[1] * p[1] + n[2] * p[2]).abs() / (nn * pp);
    Some(c.clamp(0.0, 1.0))
}

/// The Nguyen model's lateral shift of a pixel, `round(at + sigma * draw)` with `sigma` the
/// lateral deviation at incidence `theta` (clamped to [`MAX_INCIDENCE`]), where `theta` is
/// `acos(cos)` and `cos` is known to exceed `cos(π/3)` by far more than a rounding. The
/// arc cosine is a maths-library call a pixel; below π/3 the deviation lies between its
/// values at 0 and at π/3, and the rounded shift is monotonic in it, so where those two
/// bounds round alike the shift is theirs, exactly what the arc cosine would have given
/// (all but a few percent of pixels).
fn lateral_shift(at: f64, draw: f64, cos: f64, theta: &mut Option<f64>) -> i64 {
    let lo = round_to_i64(at + LATERAL_SIGMA_AT_0 * draw);
    let hi = round_to_i64(at + LATERAL_SIGMA_PAST_60 * draw);
    if lo == hi {
        return lo;
    }
    let theta = *theta.get_or_insert_with(|| cos.acos().min(MAX_INCIDENCE));
    round_to_i64(at + nguyen_lateral_sigma(theta) * draw)
}

/// The lateral deviation at normal incidence (0.8 px).
const LATERAL_SIGMA_AT_0: f64 = nguyen_lateral_sigma(0.0);

/// The lateral deviation just past π/3 (by 10⁻⁹ rad): no less than at any incidence up to π/3.
const LATERAL_SIGMA_PAST_60: f64 = nguyen_lateral_sigma(std::f64::consts::FRAC_PI_3 + 1e-9);

/// `x.round() as i64` (half away from zero) without the maths library's call, which baseline
/// x86-64 makes for `round`: truncation, then the fraction (exact below 2^52) decides, added
/// as the comparisons' 0 or 1 rather than branched on: a noise draw's fraction is as likely
/// above a half as below, and a mispredicted branch a pixel cost more than the rest of the
/// rounding.
fn round_to_i64(x: f64) -> i64 {
    if x.is_nan() || x.abs() >= 4.5e15 {
        return x.round() as i64;
    }
    let t = x as i64;
    let f = x - t as f64;
    t + i64::from(f >= 0.5) - i64::from(f <= -0.5)
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// Nguyen et al. 2012 axial standard deviation, m, at depth `z` and incidence `theta`.
pub fn nguyen_axial_sigma(z: f64, theta: f64) -> f64 {
    let mut s = 0.0012 + 0.0019 * (z - 0.4) * (z - 0.4);
    let half_pi = std::f64::consts::FRAC_PI_2;
    if theta > std::f64::consts::FRAC_PI_3 {
        s += 0.0001 * theta * theta / (z.sqrt() * (half_pi - theta).powi(2));
    }
    s
}

/// Nguyen et al. 2012 lateral standard deviation, pixels.
pub const fn nguyen_lateral_sigma(theta: f64) -> f64 {
    0.8 + 0.035 * theta / (std::f64::consts::FRAC_PI_2 - theta)
}

/// Largest incidence angle the Nguyen model is evaluated at (its terms diverge at π/2).
const MAX_INCIDENCE: f64 = 1.48;

/// The Nguyen model's noise on the pixels of every `stride`-th column and row (the others
/// are left for the caller to clear), in the frame keyed by `frame`.
fn nguyen(depth: &mut DepthImage, intr: &Intrinsics, frame: u64, stride: u32) {
    let src = depth.clone();
    let rays = PixelRays::new(&src, intr);
    let (w, h) = (src.width as i64, src.height as i64);
    // One draw from the camera's stream keys the frame (the caller's); each pixel's three
    // draws come from a generator of its own keyed by the frame and the pixel's index
    // ([`pixel_draws`]). A pixel's noise is then the same whichever others are noised: a
    // consumer of the grid's pixels draws for them alone (a quarter of the image at the
    // coverage scorer's stride of 2), the rest can be noised later with the same key, and a
    // pixel that one GPU draws and another misses by a rounding changes that pixel only.
    let stride = stride as usize;
    let width = src.width as usize;
    // The grid's draws first, on this thread: drawn on the cores with the rest, they kept both
    // busy for the whole of the noise, and a DDS subscriber on the same two cores (the serve
    // test's, taking 640×480 depth images) then lost fragments and stalled the link.
    // The grid's pixels row by row, `grid_width` to a row.
    let grid_width = width.div_ceil(stride);
    let draws: Vec<[f64; 3]> = (0..src.height as usize)
        .step_by(stride)
        .flat_map(|v| (0..width).step_by(stride).map(move |u| v * width + u))
        .map(|i| {
            if src.data[i] > 0.0 {
                pixel_draws(frame, i)
            } else {
                [0.0; 3]
            }
        })
        .collect();
    rows_on_cores(&mut depth.data, width, |v, row| {
        if !v.is_multiple_of(stride) {
            return;
        }
        // The row's draws: its place on the grid, then each pixel's (`gu`, u / stride).
        let row_draws = &draws[v / stride * grid_width..];
        for (gu, (u, out)) in row.iter_mut().enumerate().step_by(stride).enumerate() {
            let i = v * width + u;
            if src.data[i] <= 0.0 {
                continue;
            }
            let n = row_draws[gu];
            let cos = incidence_cos(&src, &rays, u as u32, v as u32);
            // Below π/3 (by a margin far beyond the arc cosine's rounding) only the lateral
            // shifts depend on the angle, and most of them only on its being below π/3; the
            // axial deviation is the same for every angle there (0 stands for them all).
            let (theta, su, sv) = match cos {
                Some(c) if c > 0.5 + 1e-9 => {
                    let mut theta = None;
                    let su = lateral_shift(u as f64, n[0], c, &mut theta);
                    let sv = lateral_shift(v as f64, n[1], c, &mut theta);
                    (0.0, su, sv)
                }
                _ => {
                    let theta = cos.map_or(0.0, f64::acos).min(MAX_INCIDENCE);
                    let sl = nguyen_lateral_sigma(theta);
                    let su = round_to_i64(u as f64 + sl * n[0]);
                    let sv = round_to_i64(v as f64 + sl * n[1]);
                    (theta, su, sv)
                }
            };
            let z = if su >= 0 && sv >= 0 && su < w && sv < h {
                src.at(su as u32, sv as u32) as f64
            } else {
                0.0
            };
            *out = if z > 0.0 {
                (z + nguyen_axial_sigma(z, theta) * n[2]) as f32
            } else {
                0.0
            };
        }
    });
}

/// The three standard normal draws of pixel `index` (row-major) in the frame keyed by
/// `frame`: the lateral shifts' along u and v, and the axial noise's, from a xoshiro256++
/// generator seeded (through SplitMix64) by the two together. Xoshiro's seeding spreads keys
/// a bit apart over the whole state, so neighbouring pixels' draws are independent.
fn pixel_draws(frame: u64, index: usize) -> [f64; 3] {
    let mut g = Xoshiro256PlusPlus::seed_from_u64(frame ^ index as u64);
    [
        StandardNormal.sample(&mut g),
        StandardNormal.sample(&mut g),
        StandardNormal.sample(&mut g),
    ]
}

/// `f(v, row)` for each row `v` of an image `width` pixels wide, the rows split into
/// contiguous blocks over the machine's cores. Each row's result depends on its own inputs
/// alone, so the image is the same whatever the number of threads. (The Nguyen noise of a
/// 320×240 image is some 7 ms on one core, a seventh of a coverage run's time at two frames a
/// second.)
fn rows_on_cores(data: &mut [f32], width: usize, f: impl Fn(usize, &mut [f32]) + Sync) {
    let rows = data.len() / width.max(1);
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    if threads < 2 || rows < 2 * threads {
        for (v, row) in data.chunks_mut(width.max(1)).enumerate() {
            f(v, row);
        }
        return;
    }
    let per = rows.div_ceil(threads);
    let f = &f;
    std::thread::scope(|scope| {
        for (k, block) in data.chunks_mut(per * width).enumerate() {
            scope.spawn(move || {
                for (j, row) in block.chunks_mut(width).enumerate() {
                    f(k * per + j, row);
                }
            });
        }
    });
}

/// Bilinear sample of valid depths; falls back to the nearest pixel next to invalid ones.
fn bilinear(d: &DepthImage, x: f64, y: f64) -> f32 {
    let (w, h) = (d.width as i64, d.height as i64);
    let (x0, y0) = (x.floor() as i64, y.floor() as i64);
    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
    let get = |xx: i64, yy: i64| -> f32 {
        if xx < 0 || yy < 0 || xx >= w || yy >= h {
            0.0
        } else {
            d.at(xx as u32, yy as u32)
        }
    };
    let c = [
        get(x0, y0),
        get(x0 + 1, y0),
        get(x0, y0 + 1),
        get(x0 + 1, y0 + 1),
    ];
    if c.iter().all(|&z| z > 0.0) {
        let top = c[0] as f64 * (1.0 - fx) + c[1] as f64 * fx;
        let bottom = c[2] as f64 * (1.0 - fx) + c[3] as f64 * fx;
        (top * (1.0 - fy) + bottom * fy) as f32
    } else {
        get(x.round() as i64, y.round() as i64)
    }
}

fn icl_nuim(depth: &mut DepthImage, intr: &Intrinsics, n: &NoiseConfig, rng: &mut ChaCha8Rng) {
    let (w, h) = (depth.width, depth.height);
    let fb = intr.fx * n.baseline;
    // 1. Lateral jitter with bilinear resampling.
    let mut jittered = depth.clone();
    for v in 0..h {
        for u in 0..w {
            let x = u as f64 + n.jitter * normal(rng);
            let y = v as f64 + n.jitter * normal(rng);
            jittered.data[(v * w + u) as usize] = bilinear(depth, x, y);
        }
    }
    // 2. Disparity, quantised to the sub-pixel step.
    let step = n.disparity_step;
    let disp: Vec<f64> = jittered
        .data
        .iter()
        .map(|&z| {
            if z > 0.0 {
                (fb / z as f64 / step).round() * step
            } else {
                0.0
            }
        })
        .collect();
    // 3. Window consistency (after simkinect's dot-pattern filter): a 9×9 window sampled every
    //    2 px must be mostly valid, and mostly within 0.1 px of its distance-weighted mean.
    let keep = |u: i64, v: i64| -> bool {
        let mut samples = 0usize;
        let mut valid = Vec::with_capacity(25);
        for dv in (-4..=4).step_by(2) {
            for du in (-4..=4).step_by(2) {
                samples += 1;
                let (x, y) = (u + du, v + dv);
                if x < 0 || y < 0 || x >= w as i64 || y >= h as i64 {
                    continue;
                }
                let d = disp[(y * w as i64 + x) as usize];
                if d > 0.0 {
                    valid.push((d, 1.0 / (1.0 + 1.44 * (du * du + dv * dv) as f64)));
                }
            }
        }
        let need = samples as f64 / 1.2;
        if (valid.len() as f64) <= need {
            return false;
        }
        let wsum: f64 = valid.iter().map(|s| s.1).sum();
        let mean = valid.iter().map(|s| s.0 * s.1).sum::<f64>() / wsum;
        let inliers = valid.iter().filter(|s| (s.0 - mean).abs() < 0.1).count();
        inliers as f64 > need
    };
    for v in 0..h {
        for u in 0..w {
            let i = (v * w + u) as usize;
            let d = disp[i];
            // One draw for every pixel (see `nguyen`).
            let noise = normal(rng);
            depth.data[i] = if d <= 0.0 || (n.edge_filter && !keep(u as i64, v as i64)) {
                0.0
            } else {
                // 4–5. Back to depth, then simkinect's Gaussian disparity noise (depth in cm).
                let z_cm = (fb / d * 100.0).round();
                if z_cm <= 0.0 {
                    0.0
                } else {
                    let noisy = (ICL_DISPARITY_CM / z_cm + noise / 6.0 + 0.5).round();
                    if noisy <= 0.0 {
                        0.0
                    } else {
                        (ICL_DISPARITY_CM / noisy / 100.0) as f32
                    }
                }
            };
        }
    }
}

/// A mounted camera in a running simulation: its model, noise stream and frame clock.
pub struct Kinect {
    pub spec: KinectSpec,
    rng: ChaCha8Rng,
    frames: u64,
    /// The last capture's depth image before noise, with the stamp and base pose it was
    /// rendered at, when it was rendered alone (the render [`Kinect::true_depth`] makes).
    noiseless: Option<(Time, Pose, DepthImage)>,
    /// The last capture's stamp and base pose where it was taken without its colour image,
    /// and that image once [`Kinect::colour`] has rendered it.
    uncoloured: Option<(Time, Pose, Option<RgbImage>)>,
    /// The last capture's depth grid, for [`Kinect::full_depth`].
    grid: Option<DepthGrid>,
}

/// How a capture's depth was noised: on which grid, with which key, and the whole image once
/// [`Kinect::full_depth`] has noised it.
struct DepthGrid {
    stamp: Time,
    base: Pose,
    stride: u32,
    key: Option<u64>,
    whole: Option<DepthImage>,
}

impl Kinect {
    pub fn new(spec: KinectSpec, rng: ChaCha8Rng) -> Kinect {
        Kinect {
            spec,
            rng,
            frames: 0,
            noiseless: None,
            uncoloured: None,
            grid: None,
        }
    }

    /// Whether a frame falls due at simulation time `t_ns` (the k-th frame at k / rate).
    pub fn due(&self, t_ns: i64) -> bool {
        t_ns as f64 >= self.frames as f64 * 1e9 / self.spec.rate - 0.5
    }

    /// Counts the frame that fell due as taken.
    pub fn take(&mut self) {
        self.frames += 1;
    }

    /// Renders a frame from the camera on a robot whose base frame has pose `base`, with the
    /// scene's bodies already posed in `renderer`; adds noise. `rgb`: also render colour.
    /// `depth_stride`: the measured depth is wanted on every `depth_stride`-th column and row
    /// alone (see [`KinectSpec::apply_noise_on_grid`]); 1 is every pixel.
    pub fn capture(
        &mut self,
        renderer: &mut Renderer,
        base: &Pose,
        stamp: Time,
        rgb: bool,
        depth_stride: u32,
    ) -> Result<RgbdFrame, RenderError> {
        let camera = *base * self.spec.mount;
        self.noiseless = None;
        self.uncoloured = (!rgb).then_some((stamp, *base, None));
        let (rgb, mut depth) = if rgb && self.spec.depth == self.spec.rgb {
            let (c, d) = renderer.render(&self.spec.rgb, &camera)?;
            (Some(c), d)
        } else {
            let c = match rgb {
                true => Some(renderer.render(&self.spec.rgb, &camera)?.0),
                false => None,
            };
            let d = renderer.render_depth(&self.spec.depth, &camera)?;
            self.noiseless = Some((stamp, *base, d.clone()));
            (c, d)
        };
        let key = self
            .spec
            .noise_on_grid_keyed(&mut depth, &mut self.rng, depth_stride);
        self.grid = Some(DepthGrid {
            stamp,
            base: *base,
            stride: depth_stride.max(1),
            key,
            whole: None,
        });
        let mut rgb = rgb;
        if let Some(c) = rgb.as_mut() {
            self.spec.apply_rgb_noise(c, &mut self.rng);
        }
        Ok(RgbdFrame {
            stamp,
            rgb,
            rgb_intrinsics: self.spec.rgb,
            depth,
            depth_intrinsics: self.spec.depth,
        })
    }

    /// Whether a frame captured on a depth grid (with or without colour, `rgb`) can have its
    /// whole depth afterwards from [`Kinect::full_depth`], as a capture of every pixel would
    /// have measured it: where the noise model completes ([`KinectSpec::noise_completes`])
    /// and the depth is rendered alone (a frame whose colour comes with it from one render
    /// keeps no noise-free depth).
    pub fn depth_on_demand(&self, rgb: bool) -> bool {
        self.spec.noise_completes() && !(rgb && self.spec.depth == self.spec.rgb)
    }

    /// The whole measured depth of the last capture, from `base` at `stamp` (that capture's),
    /// where it was noised on a grid: every pixel as a capture of every pixel would have
    /// measured it (the grid's as the frame holds them), nothing drawn from the stream, and
    /// kept for the next call. `None` where the frame holds its whole depth already. For nodes
    /// that read a grid of most frames and the whole of a few. An error for another frame
    /// than the last, or one [`Kinect::depth_on_demand`] did not allow.
    pub fn full_depth(
        &mut self,
        base: &Pose,
        stamp: Time,
    ) -> Result<Option<DepthImage>, RenderError> {
        let Some(g) = self
            .grid
            .as_mut()
            .filter(|g| g.stamp == stamp && g.base == *base)
        else {
            return Err(RenderError::Config(format!(
                "the whole depth asked for the frame at {stamp:?}, which was not the last captured"
            )));
        };
        if g.stride == 1 {
            return Ok(None);
        }
        if let Some(d) = &g.whole {
            return Ok(Some(d.clone()));
        }
        let mut d = match &self.noiseless {
            Some((t, b, d)) if *t == stamp && b == base => d.clone(),
            _ => {
                return Err(RenderError::Config(
                    "the whole depth of a frame whose depth came with its colour".into(),
                ));
            }
        };
        self.spec.complete_noise(&mut d, g.key).ok_or_else(|| {
            RenderError::Config(format!(
                "the {:?} noise model cannot noise a frame's depth after its grid",
                self.spec.noise.model
            ))
        })?;
        g.whole = Some(d.clone());
        Ok(Some(d))
    }

    /// Whether a frame captured without colour can have it rendered afterwards by
    /// [`Kinect::colour`] with the pixels a capture with colour would have given: where the
    /// colour image has a size of its own, a capture renders it apart from the depth either
    /// way (of the same size, the two come from one render, whose depth may differ from a
    /// depth render's where two surfaces meet).
    pub fn colour_on_demand(&self) -> bool {
        self.spec.depth != self.spec.rgb
    }

    /// The colour image of the last capture, taken without it, from `base` at `stamp` (that
    /// capture's), with the scene's bodies still posed for `stamp` in `renderer`: rendered
    /// and noised now (its noise draws follow the depth's, as in a capture with colour), and
    /// kept for the next call. For nodes that need a frame's colour only after looking at
    /// its depth. An error where the last capture was another or held its colour, or where
    /// [`Kinect::colour_on_demand`] does not hold.
    pub fn colour(
        &mut self,
        renderer: &mut Renderer,
        base: &Pose,
        stamp: Time,
    ) -> Result<RgbImage, RenderError> {
        if !self.colour_on_demand() {
            return Err(RenderError::Config(
                "a camera whose colour and depth images have the same size renders colour \
                 with the frame or not at all"
                    .into(),
            ));
        }
        let Some((t, b, kept)) = &mut self.uncoloured else {
            return Err(RenderError::Config(
                "the last frame was captured with its colour image, or none was".into(),
            ));
        };
        if *t != stamp || *b != *base {
            return Err(RenderError::Config(format!(
                "colour asked for the frame at {stamp:?}, but the last one was captured at {t:?}"
            )));
        }
        if let Some(c) = kept {
            return Ok(c.clone());
        }
        let mut c = renderer
            .render(&self.spec.rgb, &(*base * self.spec.mount))?
            .0;
        self.spec.apply_rgb_noise(&mut c, &mut self.rng);
        *kept = Some(c.clone());
        Ok(c)
    }

    /// The depth image this camera would measure without noise (every pixel's true distance
    /// along the optical axis) from `base` at `stamp`, with the scene's bodies posed for
    /// `stamp` in `renderer`, for scoring maps against the surfaces it saw. Draws nothing
    /// from the noise stream, so it leaves the camera's measurements as they were. Where the
    /// last capture rendered this very image (the same stamp and pose, depth alone) before
    /// adding noise, that image is returned instead of rendering it again: the same pixels.
    pub fn true_depth(
        &self,
        renderer: &mut Renderer,
        base: &Pose,
        stamp: Time,
    ) -> Result<DepthImage, RenderError> {
        if let Some((t, b, d)) = &self.noiseless
            && *t == stamp
            && b == base
        {
            return Ok(d.clone());
        }
        renderer.render_depth(&self.spec.depth, &(*base * self.spec.mount))
    }

    /// The optical frame's pose in the world for a robot base pose (TUM ground truth).
    pub fn optical_pose(&self, base: &Pose) -> Pose3 {
        let o = optical_from_body(&(*base * self.spec.mount));
        let (t, q) = (o.translation, o.rotation);
        Pose3 {
            translation: [t.x as f64, t.y as f64, t.z as f64],
            rotation: [q.x as f64, q.y as f64, q.z as f64, q.w as f64],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::noise::stream;
    use rand::Rng;

    fn plane(z: f32, w: u32, h: u32) -> DepthImage {
        DepthImage {
            width: w,
            height: h,
            data: vec![z; (w * h) as usize],
        }
    }

    fn spec(model: NoiseModel) -> KinectSpec {
        let mut c = KinectConfig::preset(KinectPreset::KinectV1);
        c.noise.model = model;
        c.depth_size = Some([160, 120]);
        c.resolve(Path::new("t.toml"), "camera[0]").unwrap()
    }

    fn stats(d: &DepthImage) -> (f64, f64, usize) {
        let v: Vec<f64> = d
            .data
            .iter()
            .filter(|&&z| z > 0.0)
            .map(|&z| z as f64)
            .collect();
        let m = v.iter().sum::<f64>() / v.len() as f64;
        let s = (v.iter().map(|z| (z - m) * (z - m)).sum::<f64>() / v.len() as f64).sqrt();
        (m, s, v.len())
    }

    /// The noise model's shortcuts give what they stand for, bit for bit: each pixel's ray
    /// times a depth is the intrinsics' back-projection, and the rounding is `f64::round`'s
    /// (half away from zero) on halves, near-halves, negatives and huge values.
    #[test]
    fn pixel_rays_and_rounding_equal_their_definitions() {
        let s = spec(NoiseModel::Nguyen);
        let d = plane(1.0, s.depth.width, s.depth.height);
        let rays = PixelRays::new(&d, &s.depth);
        for v in 0..d.height {
            for u in 0..d.width {
                for z in [0.5, 1.37, 3.9] {
                    assert_eq!(
                        rays.back_project(u as usize, v as usize, z),
                        s.depth.back_project(u as f64, v as f64, z),
                        "({u}, {v}) at {z}"
                    );
                }
            }
        }
        let mut xs = vec![
            0.0,
            -0.0,
            1e17,
            -1e17,
            f64::NAN,
            f64::INFINITY,
            4.4e15 + 0.5,
        ];
        for k in -2000..2000 {
            let x = k as f64 * 0.25;
            xs.extend([x, x + 1e-9, x - 1e-9, 0.49999999999999994 + k as f64]);
        }
        for x in xs {
            assert_eq!(round_to_i64(x), x.round() as i64, "{x}");
        }
    }

    /// Every row is handed to `f` once, with its own index, however the rows are split.
    #[test]
    fn rows_on_the_cores_are_each_rows_own() {
        for (width, height) in [(7, 1), (5, 3), (320, 240), (3, 97)] {
            let mut data = vec![0.0f32; width * height];
            rows_on_cores(&mut data, width, |v, row| {
                for (u, x) in row.iter_mut().enumerate() {
                    *x += (v * 1000 + u) as f32;
                }
            });
            for (i, x) in data.iter().enumerate() {
                assert_eq!(
                    *x,
                    ((i / width) * 1000 + i % width) as f32,
                    "{width}×{height}"
                );
            }
        }
    }

    /// The lateral shift decided by the deviation's bounds is the one the arc cosine gives,
    /// at random and where the shift is about to change.
    #[test]
    fn lateral_shifts_below_sixty_degrees_are_those_of_the_angle() {
        let mut rng = stream(5, "test");
        let mut decided = 0;
        for k in 0..500_000 {
            let cos: f64 = if k % 50 == 0 {
                0.5 + 1e-9 + 1e-12 * rng.random::<f64>()
            } else {
                rng.random_range(0.5 + 1e-9..=1.0)
            };
            let at = rng.random_range(0..640) as f64;
            let mut draw = normal(&mut rng);
            if k % 3 == 0 {
                // On the edge of a change of shift at this angle.
                let sl = nguyen_lateral_sigma(cos.acos());
                draw = (draw.round() + 0.5) / sl;
            }
            let want =
                round_to_i64(at + nguyen_lateral_sigma(cos.acos().min(MAX_INCIDENCE)) * draw);
            let mut theta = None;
            assert_eq!(
                lateral_shift(at, draw, cos, &mut theta),
                want,
                "{at} {draw} {cos}"
            );
            decided += usize::from(theta.is_none());
        }
        assert!(
            (300_000..500_000).contains(&decided),
            "{decided} decided by the bounds"
        );
    }

    #[test]
    fn nguyen_noise_on_a_frontal_plane_has_the_papers_sigma() {
        let s = spec(NoiseModel::Nguyen);
        for z in [1.0f32, 2.5] {
            let mut d = plane(z, 160, 120);
            s.apply_noise(&mut d, &mut stream(3, "kinect"));
            let (m, sd, n) = stats(&d);
            let want = nguyen_axial_sigma(z as f64, 0.0);
            assert!(n > 18_000, "{n} valid");
            assert!(
                (m - z as f64).abs() < 3.0 * want / (n as f64).sqrt() + 1e-4,
                "mean {m}"
            );
            assert!((sd / want - 1.0).abs() < 0.05, "σ {sd} vs {want} at {z} m");
        }
        // 9.6 mm at 2.5 m and 1.5 mm at 0.8 m, as the reference gives.
        assert!((nguyen_axial_sigma(2.5, 0.0) - 0.00958).abs() < 1e-4);
        assert!((nguyen_axial_sigma(0.8, 0.0) - 0.0015).abs() < 1e-4);
    }

    /// Each pixel draws from a generator of its own: on a frontal plane (where a lateral
    /// shift lands on the same depth, so a pixel's error is its own axial draw) the errors of
    /// neighbouring pixels, and of one pixel in two frames, are uncorrelated (|r| below 0.05,
    /// some seven standard errors of r over 19 000 pairs).
    #[test]
    fn nguyen_noise_is_independent_across_pixels_and_frames() {
        let s = spec(NoiseModel::Nguyen);
        let mut rng = stream(3, "kinect");
        let (mut a, mut b) = (plane(2.5, 160, 120), plane(2.5, 160, 120));
        s.apply_noise(&mut a, &mut rng);
        s.apply_noise(&mut b, &mut rng);
        let corr = |pairs: &[(f64, f64)]| {
            let n = pairs.len() as f64;
            let (mx, my) = (
                pairs.iter().map(|p| p.0).sum::<f64>() / n,
                pairs.iter().map(|p| p.1).sum::<f64>() / n,
            );
            let cov: f64 = pairs.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
            let vx: f64 = pairs.iter().map(|p| (p.0 - mx).powi(2)).sum();
            let vy: f64 = pairs.iter().map(|p| (p.1 - my).powi(2)).sum();
            cov / (vx * vy).sqrt()
        };
        let valid = |x: f32, y: f32| x > 0.0 && y > 0.0;
        let across: Vec<(f64, f64)> = a
            .data
            .chunks(160)
            .flat_map(|row| row.windows(2).map(|w| (w[0], w[1])))
            .filter(|&(x, y)| valid(x, y))
            .map(|(x, y)| (x as f64, y as f64))
            .collect();
        let frames: Vec<(f64, f64)> = a
            .data
            .iter()
            .zip(&b.data)
            .filter(|&(&x, &y)| valid(x, y))
            .map(|(&x, &y)| (x as f64, y as f64))
            .collect();
        assert!(across.len() > 18_000 && frames.len() > 18_000);
        let (r_across, r_frames) = (corr(&across), corr(&frames));
        assert!(r_across.abs() < 0.05, "neighbours: r = {r_across}");
        assert!(r_frames.abs() < 0.05, "frames: r = {r_frames}");
        assert_ne!(a.data, b.data);
    }

    #[test]
    fn icl_nuim_depths_are_quantised_disparities_and_range_cuts() {
        let mut s = spec(NoiseModel::IclNuim);
        s.noise.jitter = 0.0;
        let mut d = plane(3.0, 160, 120);
        s.apply_noise(&mut d, &mut stream(3, "kinect"));
        let (m, sd, n) = stats(&d);
        // Interior pixels survive the window filter; the border (4 px) may not.
        assert!(n >= 152 * 112, "{n} valid");
        // Biased by at most one disparity step (coarse here: 160 px wide) and the cm rounding.
        let step_m = 9.0 * s.noise.disparity_step / (s.depth.fx * s.noise.baseline);
        assert!(
            (m - 3.0).abs() < step_m + 0.01,
            "mean {m}, one step {step_m} m"
        );
        // Disparity noise of 1/6 step in simkinect's units: a few mm at 3 m.
        assert!(sd > 0.001 && sd < 0.03, "σ {sd}");
        // Every value is 35130 / k / 100 for an integer k.
        for &z in d.data.iter().filter(|&&z| z > 0.0).take(500) {
            let k = ICL_DISPARITY_CM / (z as f64 * 100.0);
            assert!((k - k.round()).abs() < 1e-3, "{z} is not quantised ({k})");
        }
        // Out of the valid range: all invalid.
        let mut far = plane(4.5, 160, 120);
        s.apply_noise(&mut far, &mut stream(3, "kinect"));
        assert!(far.data.iter().all(|&z| z == 0.0));
    }

    #[test]
    fn icl_nuim_filter_drops_depth_edges() {
        let s = spec(NoiseModel::IclNuim);
        let mut d = plane(1.5, 160, 120);
        for v in 0..120 {
            for u in 80..160 {
                d.data[v * 160 + u] = 3.0;
            }
        }
        s.apply_noise(&mut d, &mut stream(3, "kinect"));
        let row = 60 * 160;
        assert!(d.data[row + 40] > 0.0 && d.data[row + 120] > 0.0);
        assert!(
            d.data[row + 79] == 0.0 && d.data[row + 80] == 0.0,
            "edge kept"
        );
    }

    #[test]
    fn one_pixel_more_or_less_changes_only_its_neighbourhood() {
        for model in [NoiseModel::Nguyen, NoiseModel::IclNuim] {
            let s = spec(model);
            let a0 = plane(2.0, 160, 120);
            let mut b0 = a0.clone();
            b0.data[10 * 160 + 10] = 0.0;
            let (mut a, mut b) = (a0.clone(), b0.clone());
            s.apply_noise(&mut a, &mut stream(5, "kinect"));
            s.apply_noise(&mut b, &mut stream(5, "kinect"));
            let differ = a.data.iter().zip(&b.data).filter(|(x, y)| x != y).count();
            assert!(differ <= 100, "{model:?}: {differ} pixels changed");
        }
    }

    /// Noised on a grid, a depth image holds on the grid's pixels exactly what noising every
    /// pixel gives them (their shifted neighbours off the grid included), 0 elsewhere, and
    /// the noise stream ends where it would have: the next frame's noise is the same too.
    #[test]
    fn noise_on_a_grid_is_the_full_noise_on_its_pixels() {
        // A slanted floor and a nearer box, so that incidences, shifts and edges vary.
        let (w, h) = (160u32, 120u32);
        let mut scene = plane(2.0, w, h);
        for v in 0..h {
            for u in 0..w {
                let z = if (50..90).contains(&u) && (30..70).contains(&v) {
                    1.2
                } else {
                    1.0 + 3.0 * v as f32 / h as f32
                };
                scene.data[(v * w + u) as usize] = if (u + 3 * v) % 97 == 0 { 0.0 } else { z };
            }
        }
        for model in [
            NoiseModel::Nguyen,
            NoiseModel::IclNuim,
            NoiseModel::Gaussian,
        ] {
            let s = spec(model);
            let mut full = scene.clone();
            let mut rng_full = stream(7, "kinect");
            s.apply_noise(&mut full, &mut rng_full);
            for stride in [2u32, 3, 5] {
                let mut grid = scene.clone();
                let mut rng_grid = stream(7, "kinect");
                s.apply_noise_on_grid(&mut grid, &mut rng_grid, stride);
                for v in 0..h {
                    for u in 0..w {
                        let i = (v * w + u) as usize;
                        let want = if u % stride == 0 && v % stride == 0 {
                            full.data[i]
                        } else {
                            0.0
                        };
                        assert_eq!(grid.data[i], want, "{model:?}, stride {stride}, ({u}, {v})");
                    }
                }
                let valid = grid.data.iter().filter(|&&z| z > 0.0).count();
                assert!(
                    valid > (w * h / (stride * stride) / 8) as usize,
                    "{model:?}, stride {stride}: {valid} valid"
                );
                assert_eq!(
                    rng_grid.random::<u64>(),
                    rng_full.clone().random::<u64>(),
                    "{model:?}: the stream moved on differently"
                );
            }
            // Strides 0 and 1 are every pixel.
            for stride in [0, 1] {
                let mut all = scene.clone();
                s.apply_noise_on_grid(&mut all, &mut stream(7, "kinect"), stride);
                assert_eq!(all.data, full.data, "{model:?}, stride {stride}");
            }
        }
    }

    #[test]
    fn bad_camera_tables_name_the_key() {
        let mut c = KinectConfig::preset(KinectPreset::Seed000);
        c.depth_size = Some([0, 240]);
        let e = c.resolve(Path::new("s.toml"), "camera[0]").unwrap_err();
        assert!(e.to_string().contains("camera[0].depth_size"), "{e}");
        let mut c = KinectConfig::preset(KinectPreset::Seed000);
        c.fov_deg = Some([200.0, 43.0]);
        let e = c.resolve(Path::new("s.toml"), "camera[0]").unwrap_err();
        assert!(e.to_string().contains("camera[0].fov_deg[0]"), "{e}");
        let s = KinectConfig::preset(KinectPreset::Seed000)
            .resolve(Path::new("s.toml"), "camera[0]")
            .unwrap();
        assert_eq!((s.depth.width, s.depth.height), (320, 240));
        assert_eq!((s.range_min, s.range_max), (1.2, 3.5));
    }

    /// The SR4000 preset: seed 002's 176×144 at the datasheet's 43.6° × 34.6° and 0.1–5 m;
    /// its Gaussian noise has the configured σ and cuts to the range.
    #[test]
    fn the_sr4000_preset_and_its_gaussian_noise() {
        let mut c = KinectConfig::preset(KinectPreset::Sr4000);
        c.noise.model = NoiseModel::Gaussian;
        c.noise.sigma = 0.01;
        let s = c.resolve(Path::new("s.toml"), "camera[0]").unwrap();
        assert_eq!((s.depth.width, s.depth.height), (176, 144));
        assert_eq!((s.rgb.width, s.rgb.height), (176, 144));
        assert_eq!((s.range_min, s.range_max), (0.1, 5.0));
        let fov = 2.0 * (176.0 / 2.0 / s.depth.fx).atan();
        assert!(
            (fov.to_degrees() - 43.6).abs() < 1e-9,
            "{}",
            fov.to_degrees()
        );
        let mut d = plane(2.0, 176, 144);
        s.apply_noise(&mut d, &mut stream(3, "camera"));
        let n = d.data.len() as f64;
        let mean = d.data.iter().map(|z| *z as f64).sum::<f64>() / n;
        let sd = (d
            .data
            .iter()
            .map(|z| (*z as f64 - mean).powi(2))
            .sum::<f64>()
            / n)
            .sqrt();
        assert!(
            (mean - 2.0).abs() < 0.001 && (sd - 0.01).abs() < 0.001,
            "{mean} {sd}"
        );
        let mut far = plane(6.0, 176, 144);
        s.apply_noise(&mut far, &mut stream(3, "camera"));
        assert!(far.data.iter().all(|z| *z == 0.0));
        c.noise.sigma = -1.0;
        let e = c.resolve(Path::new("s.toml"), "camera[0]").unwrap_err();
        assert!(e.to_string().contains("camera[0].noise.sigma"), "{e}");
    }

    /// Colour noise has its σ and no bias on a flat image, and σ = 0 draws nothing.
    #[test]
    fn colour_noise_has_its_sigma_and_zero_draws_nothing() {
        let mut c = KinectConfig::preset(KinectPreset::Digiclops);
        c.noise.rgb_sigma = 2.0;
        let s = c.resolve(Path::new("s.toml"), "camera[0]").unwrap();
        assert_eq!((s.rgb.width, s.rgb.height, s.rate), (320, 240, 28.0));
        let flat = futago_msgs::camera::RgbImage {
            width: 320,
            height: 240,
            data: vec![100; 320 * 240 * 3],
        };
        let mut img = flat.clone();
        s.apply_rgb_noise(&mut img, &mut stream(4, "camera"));
        let n = img.data.len() as f64;
        let mean = img.data.iter().map(|v| *v as f64).sum::<f64>() / n;
        let sd = (img
            .data
            .iter()
            .map(|v| (*v as f64 - mean).powi(2))
            .sum::<f64>()
            / n)
            .sqrt();
        // Rounding to levels adds 1/12 level² of variance.
        let want = (4.0f64 + 1.0 / 12.0).sqrt();
        assert!(
            (mean - 100.0).abs() < 0.02 && (sd / want - 1.0).abs() < 0.02,
            "{mean} {sd}"
        );
        c.noise.rgb_sigma = 0.0;
        let s0 = c.resolve(Path::new("s.toml"), "camera[0]").unwrap();
        let (mut a, mut r) = (flat.clone(), stream(4, "camera"));
        s0.apply_rgb_noise(&mut a, &mut r);
        assert_eq!(a, flat);
        use rand::RngCore;
        assert_eq!(r.next_u64(), stream(4, "camera").next_u64());
        c.noise.rgb_sigma = -1.0;
        let e = c.resolve(Path::new("s.toml"), "camera[0]").unwrap_err();
        assert!(e.to_string().contains("camera[0].noise.rgb_sigma"), "{e}");
    }
}
