//! Monte Carlo localisation on a known occupancy grid (written for futago; Thrun, Burgard & Fox,
//! *Probabilistic Robotics*, ch. 5–8): the odometry motion model with Gaussian noise
//! (`alpha1..4`, as ROS amcl's `diff` model), two measurement models (the beam model with hit,
//! short, max and random terms, and the likelihood field), low-variance resampling, KLD-sampling
//! of the particle count (Fox 2003) and augmented MCL's random particles for recovery from
//! kidnapping (`alpha_slow`, `alpha_fast`; `recovery_ratio` below 1 injects them only where
//! the fit falls further).
//!
//! Seed 000's configuration is the default: 500 particles, the beam model, one beam every 15°.

use crate::cores::map_on_cores_with;
use crate::geometry::floor_i64;
use crate::geometry::grid::{OCCUPIED, clear_distance, obstacle_distance};
use futago_msgs::grid::OccupancyGrid;
use futago_msgs::{LaserScan, Pose2, wrap_angle};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::Deserialize;

/// Measurement model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SensorModel {
    Beam,
    LikelihoodField,
}

/// MCL parameters (`mcl.*`).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct MclConfig {
    /// Particle count (the starting count, and the fixed count without KLD-sampling).
    pub particles: usize,
    pub model: SensorModel,
    /// Angle between the beams used, rad (seed 000: 15°).
    pub beam_step: f64,
    /// Readings beyond this are treated as max-range, m.
    pub max_range: f64,
    pub z_hit: f64,
    pub z_short: f64,
    pub z_max: f64,
    pub z_rand: f64,
    pub sigma_hit: f64,
    pub lambda_short: f64,
    /// Odometry noise (amcl's alpha1–4): rotation from rotation, rotation from translation,
    /// translation from translation, translation from rotation.
    pub alpha: [f64; 4],
    /// KLD-sampling: bound the particle count by the KL error `kld_err` at quantile `kld_z`
    /// over bins of `kld_bin` m and `kld_bin_angle` rad, between the two limits.
    pub kld: bool,
    pub kld_err: f64,
    pub kld_z: f64,
    pub kld_bin: f64,
    pub kld_bin_angle: f64,
    pub min_particles: usize,
    pub max_particles: usize,
    /// Augmented MCL: averages of the measurement likelihood; random particles are injected
    /// with probability max(0, 1 − w_fast / w_slow).
    pub alpha_slow: f64,
    pub alpha_fast: f64,
    /// Random particles are injected only while the fast average falls below this share of
    /// the slow one: with probability max(0, 1 − w_fast / (`recovery_ratio` · w_slow)). The
    /// default, 1, is the textbook rule (Thrun et al., *Probabilistic Robotics*, Table 8.3;
    /// ROS amcl), under which the ordinary rise and fall of how well the map explains a scan
    /// from place to place injects particles at every dip of the fit below its long average
    /// (w_fast was below w_slow in 39 % of `office-laps`' updates while the robot was tracked,
    /// by up to a fifth), and KLD-sampling, which counts each random particle in a bin of its
    /// own, grows the set towards `max_particles`. At 0.85 (the fifth percentile of
    /// w_fast / w_slow over `office-laps`' tracked run; a kidnapping drops it to 0.7 within a
    /// second) `office-coverage` held 684 particles on average instead of 2,216, at about
    /// the same accuracy, but the larger sets also track better where the map is wrong (see
    /// the README): a trade a user may make, not the default.
    pub recovery_ratio: f64,
    /// The filter takes a scan only once odometry has moved `update_min_d` m or turned
    /// `update_min_a` rad since the last scan it took (ROS amcl's rule). Scans of a robot
    /// that stands still repeat the same evidence: weighting and resampling on each of them
    /// as if independent, with no motion noise to spread the set, collapse it onto whichever
    /// pose the map's small errors favour (a leg the map rasterises wider than it is), and
    /// lower the likelihood averages that decide augmented MCL's random particles.
    pub update_min_d: f64,
    pub update_min_a: f64,
    /// Beam skipping (ROS amcl's `do_beamskip`), for the beam model: a beam that fewer than
    /// `beam_skip_threshold` of the particles find consistent with the map (its reading within
    /// `beam_skip_distance` m of the range the map gives) is left out of this scan's
    /// weighting, unless more than `beam_skip_error_threshold` of the beams would be (the
    /// filter is lost, not the map wrong). Not for the likelihood field: there amcl's test
    /// (the beam's end within the distance of any obstacle) holds for most beams of a wrong
    /// pose in a room, and a robot carried off kept its old pose on the beams that agreed
    /// with it. A map rasterises a chair's leg of a few centimetres into a block of 5 cm
    /// cells: beams that pass the true leg hit the block on the map, each costs the true pose
    /// the model's random floor (about 7 nats), and a few of them pull the set to a pose
    /// whose beams miss the cells; the office's boustrophedon run lost the robot for 107 s
    /// that way among the wide hall's chairs (issue 47).
    pub beam_skip: bool,
    pub beam_skip_distance: f64,
    pub beam_skip_threshold: f64,
    pub beam_skip_error_threshold: f64,
}

impl Default for MclConfig {
    fn default() -> Self {
        MclConfig {
            particles: 500,
            model: SensorModel::Beam,
            beam_step: 15f64.to_radians(),
            max_range: 30.0,
            z_hit: 0.8,
            z_short: 0.1,
            z_max: 0.05,
            z_rand: 0.05,
            sigma_hit: 0.2,
            lambda_short: 0.1,
            alpha: [0.2, 0.2, 0.2, 0.2],
            kld: true,
            kld_err: 0.01,
            kld_z: 0.99,
            kld_bin: 0.5,
            kld_bin_angle: 10f64.to_radians(),
            min_particles: 100,
            max_particles: 5000,
            alpha_slow: 0.001,
            alpha_fast: 0.1,
            recovery_ratio: 1.0,
            // One cell of seed 000's 50 mm map, and the turn that moves a beam's end at 1 m
            // by a cell.
            update_min_d: 0.05,
            update_min_a: 0.05,
            // amcl's values.
            beam_skip: true,
            beam_skip_distance: 0.5,
            beam_skip_threshold: 0.3,
            beam_skip_error_threshold: 0.9,
        }
    }
}

impl MclConfig {
    /// Checks values MCL cannot run with, naming `PREFIX.KEY` (e.g. `localization.mcl`).
    pub fn validate(&self, prefix: &str) -> Result<(), crate::config::ConfigError> {
        use std::f64::consts::PI;
        crate::config::check_counts(
            prefix,
            &[
                ("particles", self.particles, 1, 100_000),
                ("min_particles", self.min_particles, 1, 100_000),
                ("max_particles", self.max_particles, 1, 100_000),
            ],
        )?;
        if self.min_particles > self.max_particles {
            return Err((
                format!("{prefix}.min_particles"),
                format!(
                    "expected at most max_particles ({}), found {}",
                    self.max_particles, self.min_particles
                ),
            ));
        }
        crate::config::check_ranges(
            prefix,
            &[
                ("beam_step", self.beam_step, 1e-4, 2.0 * PI),
                ("max_range", self.max_range, 0.1, 1000.0),
                ("z_hit", self.z_hit, 0.0, 1.0),
                ("z_short", self.z_short, 0.0, 1.0),
                ("z_max", self.z_max, 0.0, 1.0),
                ("z_rand", self.z_rand, 0.0, 1.0),
                ("sigma_hit", self.sigma_hit, 1e-3, 10.0),
                ("lambda_short", self.lambda_short, 1e-3, 100.0),
                ("alpha[0]", self.alpha[0], 0.0, 10.0),
                ("alpha[1]", self.alpha[1], 0.0, 10.0),
                ("alpha[2]", self.alpha[2], 0.0, 10.0),
                ("alpha[3]", self.alpha[3], 0.0, 10.0),
                ("kld_err", self.kld_err, 1e-6, 1.0),
                ("kld_z", self.kld_z, 0.5, 0.999_999),
                ("kld_bin", self.kld_bin, 1e-3, 10.0),
                ("kld_bin_angle", self.kld_bin_angle, 1e-3, PI),
                ("alpha_slow", self.alpha_slow, 0.0, 1.0),
                ("alpha_fast", self.alpha_fast, 0.0, 1.0),
                ("recovery_ratio", self.recovery_ratio, 0.01, 1.0),
                ("update_min_d", self.update_min_d, 0.0, 100.0),
                ("update_min_a", self.update_min_a, 0.0, PI),
                ("beam_skip_distance", self.beam_skip_distance, 1e-3, 100.0),
                ("beam_skip_threshold", self.beam_skip_threshold, 0.0, 1.0),
                (
                    "beam_skip_error_threshold",
                    self.beam_skip_error_threshold,
                    0.0,
                    1.0,
                ),
            ],
        )?;
        if self.z_hit + self.z_short + self.z_max + self.z_rand <= 0.0 {
            return Err((
                format!("{prefix}.z_hit"),
                "expected z_hit + z_short + z_max + z_rand > 0".into(),
            ));
        }
        Ok(())
    }
}

/// The map as MCL reads it: occupancy for ray casting, distance to the nearest obstacle for
/// the likelihood field, and the free cells for drawing random particles.
pub struct MclMap {
    grid: OccupancyGrid,
    /// Distance to the nearest occupied cell, m (capped).
    distance: Vec<f32>,
    /// For the beam model's ray cast, one byte a cell: [`BLOCKED`] for an occupied cell,
    /// else how many points a ray may advance from any point in the cell (see
    /// [`MclMap::cast_each`] and [`advance_field`]). One load a step instead of the grid's
    /// and the distance field's, in a fifth of their memory: the casts' loads were their
    /// hottest instructions (10–20 % off an update).
    skip: Vec<u8>,
    free: Vec<(usize, usize)>,
}

/// The obstacle distance the likelihood field gives a point off the map, m: the distance
/// field's cap.
const OFF_GRID_DISTANCE: f64 = 5.0;

/// [`MclMap::skip`]'s value for an occupied cell.
const BLOCKED: u8 = u8::MAX;

impl MclMap {
    pub fn new(grid: OccupancyGrid) -> MclMap {
        let (w, h) = (grid.width, grid.height);
        let distance = obstacle_distance(&grid, |c| c >= OCCUPIED, OFF_GRID_DISTANCE);
        let free = (0..h)
            .flat_map(|j| (0..w).map(move |i| (i, j)))
            .filter(|&(i, j)| grid.get(i, j) == 0)
            .collect();
        let skip = advance_field(&grid);
        MclMap {
            grid,
            distance,
            skip,
            free,
        }
    }

    /// The likelihood field's log-likelihood term for each cell (a function of the cell's
    /// obstacle distance alone) and for a point off the grid, computed once: each beam then
    /// reads its cell's term instead of an exponential and a logarithm of the distance.
    fn field_terms(&self, term: impl Fn(f64) -> f64) -> (Vec<f64>, f64) {
        let cells = self.distance.iter().map(|&d| term(d as f64)).collect();
        (cells, term(OFF_GRID_DISTANCE))
    }

    fn occupied_or_outside(&self, x: f64, y: f64) -> bool {
        match self.grid.cell_of(x, y) {
            Some((i, j)) => self.grid.get(i, j) >= OCCUPIED,
            None => true,
        }
    }

    /// Ranges to the first occupied cell along the rays from (x, y) in each of the directions
    /// `dirs` (unit vectors, cosine and sine of the ray's angle), up to `max`, into `out`: for
    /// each ray, the first of the points one cell apart along it that lies in an occupied
    /// cell or off the grid.
    ///
    /// The points are not all visited: from a point, those nearer than every occupied cell
    /// and the grid's edge are skipped ([`advance_field`]), so a ray through open space costs
    /// a few steps instead of one per cell. The result is that of visiting every point.
    ///
    /// A ray's steps form a chain (a point, its cell, that cell's byte, the next point), each
    /// waiting on the last one's load. [`CAST_LANES`] rays advance side by side, a step of
    /// each in turn, so that their loads overlap, and a ray that ends hands its lane to the
    /// next: 1.32 → 0.95 ms an update with 500 particles (`futago bench mcl`, office). The
    /// lanes' steps are taken together without a branch, whether each ray ends decided
    /// after all of them, and a point's cell index goes through `i32`: 3.7–4.9 → 3.1–3.5 ms
    /// an update with 3,000 particles on one core, as coverage runs hold while augmented MCL
    /// injects particles (`taskset -c 0 futago bench mcl --particles 3000`, alternating).
    fn cast_each(&self, x: f64, y: f64, dirs: &[(f64, f64)], max: f64, out: &mut [f64]) {
        // A lane without a ray: its steps are taken and ignored.
        const IDLE: usize = usize::MAX;
        let g = &self.grid;
        let step = g.resolution;
        // Steps counted in f64, exact for whole numbers far past any grid's: the range is
        // the same product `k · step` as with an integer count.
        let n = (max / step) as usize as f64;
        // A point's cell index is taken through `i32` (fewer instructions than `usize`), so
        // a grid more than 2³¹ cells across (10⁵ km at 5 cm) is cast on as if it ended there.
        let side = |cells: usize| cells.min(i32::MAX as usize) as f64;
        let (width, height) = (side(g.width), side(g.height));
        let mut k = [1.0f64; CAST_LANES];
        let mut dir = [(0.0f64, 0.0f64); CAST_LANES];
        let mut beam = [IDLE; CAST_LANES];
        let mut next = 0;
        for l in 0..CAST_LANES {
            if next < dirs.len() {
                (beam[l], dir[l]) = (next, dirs[next]);
                next += 1;
            }
        }
        let mut live = beam.iter().filter(|&&b| b != IDLE).count();
        while live > 0 {
            // One step of every lane, without a branch: where each ray's point falls, its
            // cell's byte, and whether the ray ends there.
            let mut ends = [false; CAST_LANES];
            let mut advance = [0.0f64; CAST_LANES];
            for l in 0..CAST_LANES {
                let r = k[l] * step;
                let (c, s) = dir[l];
                // The grid's `cell_of`, its bounds checked on the coordinates: for one at or
                // above zero, truncation is below the width exactly when the coordinate is.
                let i = (x + r * c - g.origin[0]) / g.resolution;
                let j = (y + r * s - g.origin[1]) / g.resolution;
                let inside = i >= 0.0 && j >= 0.0 && i < width && j < height;
                let cell = if inside {
                    (j as i32 as usize) * g.width + i as i32 as usize
                } else {
                    0
                };
                // (An empty grid has no cell 0; its rays end off the grid all the same.)
                let byte = self.skip.get(cell).copied().unwrap_or(BLOCKED);
                ends[l] = k[l] > n || !inside || byte == BLOCKED;
                advance[l] = byte as f64;
            }
            for l in 0..CAST_LANES {
                if !ends[l] {
                    k[l] += advance[l];
                } else if beam[l] != IDLE {
                    out[beam[l]] = if k[l] > n { max } else { k[l] * step };
                    k[l] = 1.0;
                    if next < dirs.len() {
                        (beam[l], dir[l]) = (next, dirs[next]);
                        next += 1;
                    } else {
                        beam[l] = IDLE;
                        live -= 1;
                    }
                }
            }
        }
    }
}

/// For each cell of `grid`, how many points one cell apart a ray may advance from any point
/// in it without passing over a point in an occupied cell or off the grid: [`BLOCKED`] for
/// an occupied cell. The points passed over in advancing `n` lie within `n - 1` cells of
/// the point, so any `n` with `n - 1` less than the cell's [`clear_distance`] is safe; a
/// thousandth of a cell is kept in hand against the rounding of the points' coordinates.
fn advance_field(grid: &OccupancyGrid) -> Vec<u8> {
    let clear = clear_distance(grid, |c| c >= OCCUPIED, true);
    grid.cells
        .iter()
        .zip(clear)
        .map(|(&c, clear)| {
            if c >= OCCUPIED {
                return BLOCKED;
            }
            // The largest n with n - 1 at most the clear distance less the margin.
            ((clear - 1e-3).max(0.0).floor() + 1.0).min((BLOCKED - 1) as f64) as u8
        })
        .collect()
}

/// Rays [`MclMap::cast_each`] advances side by side (8 were no faster, and with the
/// branchless step slower: 3.4–3.6 → 5.0–5.2 ms an update with 3,000 particles).
const CAST_LANES: usize = 4;

/// A pose estimate: the weighted mean and the covariance of (x, y, θ).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    pub pose: Pose2,
    pub covariance: [[f64; 3]; 3],
    pub particles: usize,
}

/// The particle filter.
pub struct Mcl {
    config: MclConfig,
    map: MclMap,
    rng: ChaCha8Rng,
    particles: Vec<Pose2>,
    weights: Vec<f64>,
    last_odometry: Option<Pose2>,
    w_slow: f64,
    w_fast: f64,
    /// The odometry and the estimate at the last scan the filter took (`update_min_d`).
    last_update: Option<(Pose2, Estimate)>,
    /// The likelihood field's log-likelihood term of each cell of the map and off it
    /// ([`MclMap::field_terms`]); none for the beam model.
    field_terms: Vec<f64>,
    field_off_grid: f64,
}

/// A beam of a scan as the filter uses it: its reading, m, and the cosine and sine of its
/// angle from the laser's heading (the mount's yaw included).
#[derive(Debug, Clone, Copy)]
struct Beam {
    z: f64,
    cos: f64,
    sin: f64,
}

impl Beam {
    fn new(angle: f64, z: f64) -> Beam {
        let (sin, cos) = angle.sin_cos();
        Beam { z, cos, sin }
    }

    /// The beam's direction (cosine and sine) from a laser whose heading has sine `sin` and
    /// cosine `cos`: the beam's own direction rotated by the heading.
    fn direction(&self, sin: f64, cos: f64) -> (f64, f64) {
        (
            cos * self.cos - sin * self.sin,
            sin * self.cos + cos * self.sin,
        )
    }
}

/// The beam model's terms a thread has computed for one scan, by beam and expected range, to
/// be looked up rather than computed again (three exponentials and a logarithm each). The
/// expected ranges a cast gives are whole numbers of cells or the maximum range, and the
/// particles, most of them gathered round the robot, find the same few for a beam over and
/// over. Each slot holds a beam, the expected range's bits and its term; a range looks in
/// the slot of its number of cells and its beam, and computes (and keeps) the term where the
/// slot holds another: what it returns is always what the model gives for that beam and
/// range.
struct TermMemo {
    slots: Vec<Option<Kept>>,
    per_beam: usize,
    inverse_step: f64,
}

/// A term a [`TermMemo`] keeps: its beam, the expected range's bits, and the term.
#[derive(Clone, Copy)]
struct Kept {
    beam: u32,
    expected: u64,
    term: (f64, bool),
}

impl TermMemo {
    /// The most slots a thread allocates for a scan: beams × cells to the maximum range
    /// where that is fewer (seed 000's 17 beams to 30 m on 5 cm cells: 10,234), else slots
    /// shared by several (beam, range) pairs in turn.
    const MAX_SLOTS: usize = 16_384;

    fn new(beams: usize, max_range: f64, step: f64) -> TermMemo {
        TermMemo::with_slots(beams, max_range, step, Self::MAX_SLOTS)
    }

    fn with_slots(beams: usize, max_range: f64, step: f64, max_slots: usize) -> TermMemo {
        let per_beam = (max_range / step).clamp(0.0, 1e6) as usize + 2;
        TermMemo {
            slots: vec![None; beams.saturating_mul(per_beam).clamp(1, max_slots.max(1))],
            per_beam,
            inverse_step: 1.0 / step,
        }
    }

    /// Beam `beam`'s term at the expected range `expected`, by `term` where not kept.
    #[inline]
    fn term(
        &mut self,
        beam: usize,
        expected: f64,
        term: impl FnOnce() -> (f64, bool),
    ) -> (f64, bool) {
        let cells = ((expected * self.inverse_step + 0.5) as usize).min(self.per_beam - 1);
        let n = self.slots.len();
        let slot = &mut self.slots[(beam * self.per_beam + cells) % n];
        let (beam, expected) = (beam as u32, expected.to_bits());
        match slot {
            Some(k) if k.beam == beam && k.expected == expected => k.term,
            _ => {
                let term = term();
                *slot = Some(Kept {
                    beam,
                    expected,
                    term,
                });
                term
            }
        }
    }
}

/// A beam's log-likelihood from its likelihood `p` (floored, so a beam the map cannot explain
/// costs a bounded amount), with its consistency.
fn log_term(p: f64, consistent: bool) -> (f64, bool) {
    (p.max(1e-12).ln(), consistent)
}

fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    StandardNormal.sample(rng)
}

impl Mcl {
    /// A filter on `map`, its particles spread over the free cells (global localisation).
    pub fn new(config: MclConfig, map: MclMap, seed: u64) -> Mcl {
        let mut m = Mcl {
            config,
            map,
            rng: ChaCha8Rng::seed_from_u64(seed),
            particles: Vec::new(),
            weights: Vec::new(),
            last_odometry: None,
            w_slow: 0.0,
            w_fast: 0.0,
            last_update: None,
            field_terms: Vec::new(),
            field_off_grid: 0.0,
        };
        if config.model == SensorModel::LikelihoodField {
            let c = &m.config;
            (m.field_terms, m.field_off_grid) = m.map.field_terms(|d| {
                let p = c.z_hit * (-d * d / (2.0 * c.sigma_hit * c.sigma_hit)).exp()
                    + c.z_rand / c.max_range;
                log_term(p, true).0
            });
        }
        m.particles = (0..config.particles).map(|_| m.random_pose()).collect();
        m.weights = vec![1.0 / config.particles as f64; config.particles];
        m
    }

    /// Spreads the particles around `pose` with standard deviations (m, m, rad).
    pub fn set_pose(&mut self, pose: Pose2, sigma: [f64; 3]) {
        let n = self.config.particles;
        self.last_update = None;
        self.particles = (0..n)
            .map(|_| {
                Pose2::new(
                    pose.x + sigma[0] * gauss(&mut self.rng),
                    pose.y + sigma[1] * gauss(&mut self.rng),
                    wrap_angle(pose.theta + sigma[2] * gauss(&mut self.rng)),
                )
            })
            .collect();
        self.weights = vec![1.0 / n as f64; n];
    }

    fn random_pose(&mut self) -> Pose2 {
        let free = &self.map.free;
        if free.is_empty() {
            return Pose2::IDENTITY;
        }
        let (i, j) = free[self.rng.random_range(0..free.len())];
        let c = self.map.grid.cell_center(i, j);
        let r = self.map.grid.resolution;
        Pose2::new(
            c[0] + self.rng.random_range(-0.5..0.5) * r,
            c[1] + self.rng.random_range(-0.5..0.5) * r,
            self.rng
                .random_range(-std::f64::consts::PI..std::f64::consts::PI),
        )
    }

    /// Moves every particle by the odometry increment, with noise.
    fn predict(&mut self, odometry: &Pose2) {
        let Some(prev) = self.last_odometry.replace(*odometry) else {
            return;
        };
        let (dx, dy) = (odometry.x - prev.x, odometry.y - prev.y);
        let trans = dx.hypot(dy);
        let rot1 = if trans < 0.01 {
            0.0
        } else {
            wrap_angle(dy.atan2(dx) - prev.theta)
        };
        let rot2 = wrap_angle(odometry.theta - prev.theta - rot1);
        // The model's rotations are measured from the direction of travel, so a robot backing
        // straight up turns by π and back: its noise is that of the turn to or from the
        // nearer of forward and backward travel, as ROS amcl's diff model takes it. Charged
        // the full π, a 15 cm back-off scattered the headings by ±80° (σ = √α1·π at α1 = 0.2)
        // and lost the robot after bumps and blocked lanes (issue 47's coverage runs).
        let turn = |r: f64| r.abs().min(wrap_angle(r - std::f64::consts::PI).abs());
        let (n1, n2) = (turn(rot1), turn(rot2));
        let [a1, a2, a3, a4] = self.config.alpha;
        for p in &mut self.particles {
            let r1 = rot1 + (a1 * n1 * n1 + a2 * trans * trans).sqrt() * gauss(&mut self.rng);
            let t = trans
                + (a3 * trans * trans + a4 * (n1 * n1 + n2 * n2)).sqrt() * gauss(&mut self.rng);
            let r2 = rot2 + (a1 * n2 * n2 + a2 * trans * trans).sqrt() * gauss(&mut self.rng);
            let th = p.theta + r1;
            *p = Pose2::new(p.x + t * th.cos(), p.y + t * th.sin(), wrap_angle(th + r2));
        }
    }

    /// The used beams' log-likelihoods from the laser pose `laser`, and whether each beam is
    /// consistent with the map there (beam skipping's test, see [`MclConfig::beam_skip`];
    /// always for the likelihood field).
    ///
    /// A beam's direction is the laser's heading turned by the beam's angle, by a rotation
    /// of the beam's own direction (its cosine and sine, once a scan) rather than a cosine
    /// and a sine of the sum for each beam of each particle (a tenth of a coverage run's
    /// time). The two differ by a few units in the last place; a ray's points then fall in
    /// other cells only within about 10⁻¹⁴ m of a cell's edge.
    fn beam_terms(&self, laser: &Pose2, beams: &[Beam], memo: &mut TermMemo) -> Vec<(f64, bool)> {
        let c = &self.config;
        let (sin, cos) = laser.theta.sin_cos();
        let dir = |b: &Beam| b.direction(sin, cos);
        match c.model {
            SensorModel::LikelihoodField => beams
                .iter()
                .map(|b| {
                    let z = b.z;
                    if z >= c.max_range {
                        return log_term(1.0, true);
                    }
                    let (dx, dy) = dir(b);
                    let (x, y) = (laser.x + z * dx, laser.y + z * dy);
                    let term = match self.map.grid.cell_of(x, y) {
                        Some((i, j)) => self.field_terms[j * self.map.grid.width + i],
                        None => self.field_off_grid,
                    };
                    (term, true)
                })
                .collect(),
            SensorModel::Beam => {
                let dirs: Vec<(f64, f64)> = beams.iter().map(dir).collect();
                let mut expected = vec![0.0; beams.len()];
                self.map
                    .cast_each(laser.x, laser.y, &dirs, c.max_range, &mut expected);
                beams
                    .iter()
                    .zip(expected)
                    .enumerate()
                    .map(|(k, (b, expected))| {
                        memo.term(k, expected, || self.beam_model_term(b.z, expected))
                    })
                    .collect()
            }
        }
    }

    /// The beam model's log-likelihood of reading `z` where the map gives `expected`, and
    /// whether the two are consistent (within `beam_skip_distance`).
    fn beam_model_term(&self, z: f64, expected: f64) -> (f64, bool) {
        let c = &self.config;
        let hit = if z < c.max_range {
            (-(z - expected).powi(2) / (2.0 * c.sigma_hit * c.sigma_hit)).exp()
                / (c.sigma_hit * (2.0 * std::f64::consts::PI).sqrt())
        } else {
            0.0
        };
        let short = if z < expected {
            let eta = 1.0 / (1.0 - (-c.lambda_short * expected).exp());
            eta * c.lambda_short * (-c.lambda_short * z).exp()
        } else {
            0.0
        };
        let max = if z >= c.max_range { 1.0 } else { 0.0 };
        let rand = if z < c.max_range {
            1.0 / c.max_range
        } else {
            0.0
        };
        let p = c.z_hit * hit + c.z_short * short + c.z_max * max + c.z_rand * rand;
        log_term(p, (z - expected).abs() < c.beam_skip_distance)
    }

    /// Whether this filter skips beams: asked to, and on the beam model.
    fn skips_beams(&self) -> bool {
        self.config.beam_skip && self.config.model == SensorModel::Beam
    }

    /// Which beams to weight by: all, or with beam skipping those enough particles find
    /// consistent (`terms`: each particle's [`Mcl::beam_terms`], `None` inside a wall).
    fn beams_kept(&self, terms: &[Option<Vec<(f64, bool)>>], beams: usize) -> Vec<bool> {
        let c = &self.config;
        if !self.skips_beams() {
            return vec![true; beams];
        }
        let mut agree = vec![0usize; beams];
        let mut counted = 0usize;
        for t in terms.iter().flatten() {
            counted += 1;
            for (n, &(_, ok)) in agree.iter_mut().zip(t) {
                *n += usize::from(ok);
            }
        }
        let keep: Vec<bool> = agree
            .iter()
            .map(|&n| n as f64 >= c.beam_skip_threshold * counted as f64)
            .collect();
        let skipped = keep.iter().filter(|k| !**k).count();
        if skipped as f64 > c.beam_skip_error_threshold * beams as f64 {
            vec![true; beams]
        } else {
            keep
        }
    }

    /// One filter step: motion from `odometry` (the robot's odometry pose), then the scan
    /// (taken by the laser at `mount` on the robot), resampling, and the estimate.
    /// Where odometry has moved less than `update_min_d` and turned less than `update_min_a`
    /// since the last scan taken, the scan is not taken: the particles stay, and the
    /// estimate is the last one carried by odometry.
    pub fn update(&mut self, odometry: &Pose2, scan: &LaserScan, mount: &Pose2) -> Estimate {
        if let Some((at, last)) = &self.last_update {
            let moved = at.between(odometry);
            if moved.x.hypot(moved.y) < self.config.update_min_d
                && moved.theta.abs() < self.config.update_min_a
            {
                return Estimate {
                    pose: last.pose.compose(&moved),
                    ..*last
                };
            }
        }
        let estimate = self.take(odometry, scan, mount);
        self.last_update = Some((*odometry, estimate));
        estimate
    }

    /// Takes a scan: motion, weighting, resampling and the estimate.
    fn take(&mut self, odometry: &Pose2, scan: &LaserScan, mount: &Pose2) -> Estimate {
        self.predict(odometry);
        let c = self.config;
        // The beams used: one every `beam_step`.
        let every = ((c.beam_step / scan.angle_increment.abs().max(1e-9)).round() as usize).max(1);
        let beams: Vec<Beam> = scan
            .ranges
            .iter()
            .enumerate()
            .step_by(every)
            .filter(|(_, r)| !r.is_nan() && **r as f64 >= scan.range_min)
            .map(|(k, &r)| {
                let z = if r.is_finite() {
                    (r as f64).min(c.max_range)
                } else {
                    c.max_range
                };
                Beam::new(mount.theta + scan.angle(k), z)
            })
            .collect();
        let this = &*self;
        // The laser's position; beam angles already include the mount's yaw.
        let laser_of = |p: &Pose2| p.compose(&Pose2::new(mount.x, mount.y, 0.0));
        // The likelihood field keeps no terms.
        let memoised = if c.model == SensorModel::Beam {
            beams.len()
        } else {
            0
        };
        let memo = || TermMemo::new(memoised, c.max_range, self.map.grid.resolution);
        let (logs, used) = if self.skips_beams() {
            // Every beam's term kept for the choice of beams.
            let terms: Vec<Option<Vec<(f64, bool)>>> =
                map_on_cores_with(&self.particles, SERIAL_BELOW, memo, |memo, p| {
                    let laser = laser_of(p);
                    (!this.map.occupied_or_outside(p.x, p.y))
                        .then(|| this.beam_terms(&laser, &beams, memo))
                });
            let keep = self.beams_kept(&terms, beams.len());
            let logs: Vec<f64> = terms
                .iter()
                .map(|t| match t {
                    Some(t) => t
                        .iter()
                        .zip(&keep)
                        .filter(|(_, k)| **k)
                        .map(|((l, _), _)| l)
                        .sum(),
                    None => f64::NEG_INFINITY,
                })
                .collect();
            (logs, keep.iter().filter(|k| **k).count())
        } else {
            let logs = map_on_cores_with(&self.particles, SERIAL_BELOW, memo, |memo, p| {
                if this.map.occupied_or_outside(p.x, p.y) {
                    return f64::NEG_INFINITY;
                }
                let laser = laser_of(p);
                this.beam_terms(&laser, &beams, memo)
                    .iter()
                    .map(|t| t.0)
                    .sum()
            });
            (logs, beams.len())
        };
        let top = logs.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        if top == f64::NEG_INFINITY {
            // Every particle is inside a wall or off the map: start over.
            let n = self.particles.len();
            self.particles = (0..n).map(|_| self.random_pose()).collect();
            self.weights = vec![1.0 / n as f64; n];
            return self.estimate();
        }
        let mut sum = 0.0;
        for (w, l) in self.weights.iter_mut().zip(&logs) {
            *w *= (l - top).exp();
            sum += *w;
        }
        for w in &mut self.weights {
            *w /= sum;
        }
        // Average likelihood per beam weighted by (those kept), for augmented MCL's recovery.
        let avg = (top / used.max(1) as f64).exp()
            * (sum / self.particles.len() as f64)
                .max(1e-300)
                .powf(1.0 / used.max(1) as f64);
        if self.w_slow == 0.0 {
            self.w_slow = avg;
            self.w_fast = avg;
        } else {
            self.w_slow += c.alpha_slow * (avg - self.w_slow);
            self.w_fast += c.alpha_fast * (avg - self.w_fast);
        }
        // The estimate is the posterior this scan gives, before resampling: afterwards the
        // set also holds the uniform random particles augmented MCL injects, whose share
        // rises wherever the scan fits the map worse than usual, and whose mean would drag the
        // estimate across the map. Those injected last time are weighted by this scan here.
        let estimate = self.estimate();
        self.resample();
        estimate
    }

    /// Low-variance resampling to the KLD bound, with random particles at augmented MCL's rate.
    fn resample(&mut self) {
        let c = self.config;
        let p_random = if self.w_slow > 0.0 {
            (1.0 - self.w_fast / (c.recovery_ratio * self.w_slow)).max(0.0)
        } else {
            0.0
        };
        let mut out = Vec::with_capacity(self.particles.len());
        // Only the bins' number is read, so the hasher is the fast one (std's SipHash and
        // the maths library's `floor` were about 1 % of `office-coverage-bcd`'s samples).
        let mut bins = rustc_hash::FxHashSet::default();
        let z = normal_quantile(c.kld_z);
        let target = |k: usize| -> usize {
            if !c.kld || k <= 1 {
                return c.particles;
            }
            kld_bound(k, c.kld_err, z).clamp(c.min_particles, c.max_particles)
        };
        let n0 = self.particles.len();
        let step = 1.0 / n0 as f64;
        let mut r = self.rng.random_range(0.0..step);
        let mut cum = self.weights[0];
        let mut i = 0;
        loop {
            let limit = if c.kld {
                target(bins.len())
            } else {
                c.particles
            };
            if out.len() >= limit || out.len() >= c.max_particles {
                break;
            }
            let p = if self.rng.random::<f64>() < p_random {
                self.random_pose()
            } else {
                while r > cum && i + 1 < n0 {
                    i += 1;
                    cum += self.weights[i];
                }
                let p = self.particles[i];
                // Past the last particle (KLD asks more than there were) the wheel turns
                // again; the draw is taken first, or the wheel's last draw would be the first
                // particle whatever the weights.
                r += step;
                if r > 1.0 {
                    r -= 1.0;
                    i = 0;
                    cum = self.weights[0];
                }
                p
            };
            bins.insert((
                floor_i64(p.x / c.kld_bin),
                floor_i64(p.y / c.kld_bin),
                floor_i64(p.theta / c.kld_bin_angle),
            ));
            out.push(p);
        }
        let n = out.len();
        self.particles = out;
        self.weights = vec![1.0 / n as f64; n];
    }

    /// The estimate: the weighted mean pose (circular mean for θ) and covariance of the
    /// heaviest cluster of particles, as ROS amcl takes it. Particles fall into the
    /// KLD-sampling bins (`kld_bin`, `kld_bin_angle`); bins that touch (in x, y and θ, θ
    /// wrapping round) form a cluster. Where the posterior has two modes, the mean of all the
    /// particles lies between them, in neither; the heaviest mode is the best single guess.
    pub fn estimate(&self) -> Estimate {
        let members = self.heaviest_cluster();
        let total: f64 = members.iter().map(|&k| self.weights[k]).sum();
        let norm = if total > 0.0 { total } else { 1.0 };
        let (mut x, mut y, mut s, mut co) = (0.0, 0.0, 0.0, 0.0);
        for &k in &members {
            let (p, w) = (&self.particles[k], self.weights[k] / norm);
            x += w * p.x;
            y += w * p.y;
            s += w * p.theta.sin();
            co += w * p.theta.cos();
        }
        let th = s.atan2(co);
        let mut cov = [[0.0; 3]; 3];
        for &k in &members {
            let (p, w) = (&self.particles[k], self.weights[k] / norm);
            let d = [p.x - x, p.y - y, wrap_angle(p.theta - th)];
            for a in 0..3 {
                for b in 0..3 {
                    cov[a][b] += w * d[a] * d[b];
                }
            }
        }
        Estimate {
            pose: Pose2::new(x, y, th),
            covariance: cov,
            particles: self.particles.len(),
        }
    }

    /// The indices of the particles in the heaviest cluster (ties to the cluster of the
    /// lowest particle index).
    fn heaviest_cluster(&self) -> Vec<usize> {
        let c = &self.config;
        let turns = (std::f64::consts::TAU / c.kld_bin_angle).ceil().max(1.0) as i64;
        let bin_of = |p: &Pose2| -> (i64, i64, i64) {
            (
                floor_i64(p.x / c.kld_bin),
                floor_i64(p.y / c.kld_bin),
                floor_i64((p.theta + std::f64::consts::PI) / c.kld_bin_angle).rem_euclid(turns),
            )
        };
        // Bins in the order their first particle comes, so the result does not hang on the
        // map's iteration order.
        let mut index = rustc_hash::FxHashMap::default();
        let mut bins = Vec::new();
        let particle_bin: Vec<usize> = self
            .particles
            .iter()
            .map(|p| {
                let b = bin_of(p);
                *index.entry(b).or_insert_with(|| {
                    bins.push(b);
                    bins.len() - 1
                })
            })
            .collect();
        // Union-find over touching bins.
        let mut parent: Vec<usize> = (0..bins.len()).collect();
        fn root(parent: &mut [usize], mut k: usize) -> usize {
            while parent[k] != k {
                parent[k] = parent[parent[k]];
                k = parent[k];
            }
            k
        }
        for (k, &(bx, by, bt)) in bins.iter().enumerate() {
            for dx in -1..=1 {
                for dy in -1..=1 {
                    for dt in -1..=1 {
                        let n = (bx + dx, by + dy, (bt + dt).rem_euclid(turns));
                        if let Some(&m) = index.get(&n) {
                            let (a, b) = (root(&mut parent, k), root(&mut parent, m));
                            if a != b {
                                parent[a.max(b)] = a.min(b);
                            }
                        }
                    }
                }
            }
        }
        let mut weight = vec![0.0; bins.len()];
        let cluster: Vec<usize> = particle_bin.iter().map(|&b| root(&mut parent, b)).collect();
        for (k, &r) in cluster.iter().enumerate() {
            weight[r] += self.weights[k];
        }
        let best = (0..bins.len())
            .filter(|&r| parent[r] == r)
            .fold(None::<usize>, |best, r| match best {
                Some(b) if weight[b] >= weight[r] => Some(b),
                _ => Some(r),
            });
        (0..self.particles.len())
            .filter(|&k| Some(cluster[k]) == best)
            .collect()
    }

    /// The particles (for display and tests).
    pub fn particles(&self) -> &[Pose2] {
        &self.particles
    }
}

/// Below this many particles the filter weighs them on one thread.
const SERIAL_BELOW: usize = 256;

/// Fox's KLD-sampling bound: particles needed so that, with the normal quantile `z`, the KL
/// divergence between the sample and the true posterior over `k` occupied bins stays below
/// `err` (Wilson–Hilferty approximation of the χ² quantile).
pub fn kld_bound(k: usize, err: f64, z: f64) -> usize {
    if k <= 1 {
        return 1;
    }
    let k1 = (k - 1) as f64;
    let a = 2.0 / (9.0 * k1);
    (k1 / (2.0 * err) * (1.0 - a + a.sqrt() * z).powi(3)).ceil() as usize
}

/// Quantile of the standard normal distribution (Acklam's rational approximation, |error| <
/// 1.2e-9), for KLD-sampling's bound.
pub fn normal_quantile(p: f64) -> f64 {
    let a = [
        -3.969683028665376e1,
        2.209460984245205e2,
        -2.759285104469687e2,
        1.38357751867269e2,
        -3.066479806614716e1,
        2.506628277459239,
    ];
    let b = [
        -5.447609879822406e1,
        1.615858368580409e2,
        -1.556989798598866e2,
        6.680131188771972e1,
        -1.328068155288572e1,
    ];
    let c = [
        -7.784894002430293e-3,
        -3.223964580411365e-1,
        -2.400758277161838,
        -2.549732539343734,
        4.374664141464968,
        2.938163982698783,
    ];
    let d = [
        7.784695709041462e-3,
        3.224671290700398e-1,
        2.445134137142996,
        3.754408661907416,
    ];
    let p = p.clamp(1e-12, 1.0 - 1e-12);
    if p < 0.02425 {
        let q = (-2.0 * p.ln()).sqrt();
        (((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5])
            / ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1.0)
    } else if p <= 1.0 - 0.02425 {
        let q = p - 0.5;
        let r = q * q;
        (((((a[0] * r + a[1]) * r + a[2]) * r + a[3]) * r + a[4]) * r + a[5]) * q
            / (((((b[0] * r + b[1]) * r + b[2]) * r + b[3]) * r + b[4]) * r + 1.0)
    } else {
        -normal_quantile(1.0 - p)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use futago_msgs::Time;

    /// A 10 m × 6 m room with an inner wall stub and a pillar, so no pose is symmetric.
    fn room() -> OccupancyGrid {
        let r = 0.05;
        let (w, h) = (220, 140);
        let mut g = OccupancyGrid::new(r, [-0.5, -0.5], w, h);
        for j in 0..h {
            for i in 0..w {
                let [x, y] = g.cell_center(i, j);
                let wall = !(0.0..=10.0).contains(&x) || !(0.0..=6.0).contains(&y);
                let stub = (6.0..6.2).contains(&x) && y < 2.5;
                let pillar = (2.0..2.4).contains(&x) && (4.0..4.4).contains(&y);
                let outside = !(-0.3..=10.3).contains(&x) || !(-0.3..=6.3).contains(&y);
                g.set(
                    i,
                    j,
                    if outside {
                        -1
                    } else if wall || stub || pillar {
                        100
                    } else {
                        0
                    },
                );
            }
        }
        g
    }

    /// A filter of sensor model `model` on the room, and every `every`-th beam of the room's
    /// scan from `truth` as the filter takes them.
    fn filter_and_beams(model: SensorModel, truth: &Pose2, every: usize) -> (Mcl, Vec<Beam>) {
        let map = MclMap::new(room());
        let scan = scan(&map, truth);
        let c = MclConfig {
            model,
            ..MclConfig::default()
        };
        let beams = (0..scan.ranges.len())
            .step_by(every)
            .map(|k| Beam::new(scan.angle(k), (scan.ranges[k] as f64).min(c.max_range)))
            .collect();
        (Mcl::new(c, map, 5), beams)
    }

    /// The beam model's terms through a thread's memo are those computed afresh, for
    /// particles scattered over the room (wide and narrow of the scan's pose), with memos
    /// of every slot, of a few slots that many (beam, range) pairs share, and of one.
    #[test]
    fn kept_beam_terms_are_the_models_terms() {
        let truth = Pose2::new(3.0, 2.0, 0.4);
        let (mcl, beams) = filter_and_beams(SensorModel::Beam, &truth, 30);
        let c = mcl.config;
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let particles: Vec<Pose2> = (0..400)
            .map(|k| {
                let spread = if k % 2 == 0 { 0.1 } else { 3.0 };
                Pose2::new(
                    truth.x + spread * gauss(&mut rng),
                    truth.y + spread * gauss(&mut rng),
                    truth.theta + spread * gauss(&mut rng),
                )
            })
            .collect();
        let step = mcl.map.grid.resolution;
        for slots in [TermMemo::MAX_SLOTS, 7, 1] {
            let mut memo = TermMemo::with_slots(beams.len(), c.max_range, step, slots);
            let mut filled = 0;
            for p in &particles {
                let kept = mcl.beam_terms(p, &beams, &mut memo);
                let (sin, cos) = p.theta.sin_cos();
                let dirs: Vec<(f64, f64)> = beams.iter().map(|b| b.direction(sin, cos)).collect();
                let mut expected = vec![0.0; beams.len()];
                mcl.map
                    .cast_each(p.x, p.y, &dirs, c.max_range, &mut expected);
                for (b, (beam, e)) in beams.iter().zip(expected).enumerate() {
                    let fresh = mcl.beam_model_term(beam.z, e);
                    assert_eq!(kept[b].0.to_bits(), fresh.0.to_bits(), "{slots} slots");
                    assert_eq!(kept[b].1, fresh.1);
                }
                filled += memo.slots.iter().flatten().count();
            }
            assert!(filled > 0);
        }
    }

    /// The likelihood field's terms read from the cells' table are the model's formula at the
    /// beam end's obstacle distance, to the bit, on the map and off it (particles spread
    /// metres about a pose by the room's edge, so that some beams end off the grid).
    #[test]
    fn likelihood_field_terms_are_the_formula_at_the_cells_distance() {
        let truth = Pose2::new(1.0, 1.0, 2.5);
        let (mcl, beams) = filter_and_beams(SensorModel::LikelihoodField, &truth, 10);
        let c = mcl.config;
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut memo = TermMemo::with_slots(beams.len(), c.max_range, 0.05, 1);
        let (mut on, mut off) = (0, 0);
        for _ in 0..200 {
            let p = Pose2::new(
                truth.x + 2.0 * gauss(&mut rng),
                truth.y + 2.0 * gauss(&mut rng),
                truth.theta + 2.0 * gauss(&mut rng),
            );
            let terms = mcl.beam_terms(&p, &beams, &mut memo);
            let (sin, cos) = p.theta.sin_cos();
            for (b, t) in beams.iter().zip(terms) {
                let want = if b.z >= c.max_range {
                    0.0
                } else {
                    let (dx, dy) = b.direction(sin, cos);
                    let grid = &mcl.map.grid;
                    let d = match grid.cell_of(p.x + b.z * dx, p.y + b.z * dy) {
                        Some((i, j)) => {
                            on += 1;
                            mcl.map.distance[j * grid.width + i] as f64
                        }
                        None => {
                            off += 1;
                            5.0
                        }
                    };
                    let p = c.z_hit * (-d * d / (2.0 * c.sigma_hit * c.sigma_hit)).exp()
                        + c.z_rand / c.max_range;
                    p.max(1e-12).ln()
                };
                assert_eq!(t.0.to_bits(), want.to_bits(), "{p:?}");
                assert!(t.1);
            }
        }
        assert!(
            on > 100 && off > 100,
            "{on} beams end on the grid, {off} off it"
        );
    }

    /// A 240°, 0.5° scan of `grid` from `pose` (cast on the grid itself).
    fn scan(map: &MclMap, pose: &Pose2) -> LaserScan {
        let n = 481;
        let inc = 0.5f64.to_radians();
        let amin = -120f64.to_radians();
        LaserScan {
            frame: "front".into(),
            stamp: Time::ZERO,
            angle_min: amin,
            angle_increment: inc,
            time_increment: 0.0,
            range_min: 0.02,
            range_max: 30.0,
            ranges: (0..n)
                .map(|k| {
                    let mut range = [0.0];
                    let a = pose.theta + amin + k as f64 * inc;
                    map.cast_each(pose.x, pose.y, &[(a.cos(), a.sin())], 30.0, &mut range);
                    range[0] as f32
                })
                .collect(),
        }
    }

    /// Two clouds 3 m apart, one holding 60 % of the weight: the estimate is the heavier
    /// cloud's mean, not the point between them (where the robot cannot be).
    #[test]
    fn the_estimate_is_the_heaviest_cluster() {
        let mut mcl = Mcl::new(MclConfig::default(), MclMap::new(room()), 1);
        let (a, b) = (Pose2::new(2.0, 2.0, 3.1), Pose2::new(5.0, 2.0, -3.1));
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut jitter = |p: &Pose2| {
            Pose2::new(
                p.x + 0.05 * gauss(&mut rng),
                p.y + 0.05 * gauss(&mut rng),
                wrap_angle(p.theta + 0.02 * gauss(&mut rng)),
            )
        };
        mcl.particles = (0..400)
            .map(|k| if k % 2 == 0 { jitter(&a) } else { jitter(&b) })
            .collect();
        // Even particles (cloud a) weigh 1.5 times the odd ones: 60 % of the weight.
        let raw: Vec<f64> = (0..400)
            .map(|k| if k % 2 == 0 { 1.5 } else { 1.0 })
            .collect();
        let sum: f64 = raw.iter().sum();
        mcl.weights = raw.iter().map(|w| w / sum).collect();
        let e = mcl.estimate();
        assert!(e.pose.distance(&a) < 0.05, "{:?}", e.pose);
        // Its heading straddles ±π and is averaged as an angle.
        assert!(wrap_angle(e.pose.theta - 3.1).abs() < 0.02, "{:?}", e.pose);
        // Its covariance is the cloud's own (5 cm), not the spread between the clouds.
        assert!(e.covariance[0][0].sqrt() < 0.1, "{:?}", e.covariance);
        // The other way round, the other cloud.
        mcl.weights = raw.iter().map(|w| (2.5 - w) / sum).collect();
        assert!(mcl.estimate().pose.distance(&b) < 0.05);
    }

    /// The casts that skip open space, several rays side by side, find the same ranges as
    /// one that visits every point along each ray, from everywhere in the room and beyond
    /// its walls, in every direction, for fans of one ray to more than the lanes: in the
    /// plain room, and on an open floor without walls (rays leave the grid) cluttered with
    /// single cells and walls at every angle, where rays graze and pass close by corners.
    #[test]
    fn skipping_open_space_casts_the_same_ranges() {
        let mut cluttered = OccupancyGrid::new(0.05, [0.0, 0.0], 200, 120);
        cluttered.cells.fill(0);
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        for _ in 0..60 {
            let (i, j) = (rng.random_range(0..200), rng.random_range(0..120));
            cluttered.set(i, j, 100);
        }
        for _ in 0..6 {
            let (x, y) = (rng.random_range(0.0..10.0), rng.random_range(0.0..6.0));
            let a: f64 = rng.random_range(-std::f64::consts::PI..std::f64::consts::PI);
            for k in 0..60 {
                let r = k as f64 * 0.02;
                if let Some((i, j)) = cluttered.cell_of(x + r * a.cos(), y + r * a.sin()) {
                    cluttered.set(i, j, 100);
                }
            }
        }
        for grid in [room(), cluttered] {
            casts_match_visiting_every_point(&MclMap::new(grid));
        }
    }

    /// On a grid without cells every ray ends at its first point, off the grid (or at the
    /// maximum range where that comes first), as visiting the points says.
    #[test]
    fn rays_on_an_empty_grid_end_at_their_first_point() {
        let map = MclMap::new(OccupancyGrid::new(0.05, [0.0, 0.0], 0, 0));
        let dirs = [(1.0, 0.0), (0.0, 1.0), (-0.6, 0.8)];
        let mut out = [f64::NAN; 3];
        map.cast_each(0.01, 0.01, &dirs, 30.0, &mut out);
        assert_eq!(out, [0.05; 3]);
        map.cast_each(0.01, 0.01, &dirs, 0.04, &mut out);
        assert_eq!(out, [0.04; 3]);
    }

    fn casts_match_visiting_every_point(map: &MclMap) {
        let every = |x: f64, y: f64, a: f64, max: f64| -> f64 {
            let step = map.grid.resolution;
            for k in 1..=(max / step) as usize {
                let r = k as f64 * step;
                if map.occupied_or_outside(x + r * a.cos(), y + r * a.sin()) {
                    return r;
                }
            }
            max
        };
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let (mut long, mut rays) = (0, 0);
        for _ in 0..4_000 {
            let (x, y) = (rng.random_range(-1.0..11.0), rng.random_range(-1.0..7.0));
            let max = rng.random_range(0.5..30.0);
            let fan: Vec<f64> = (0..rng.random_range(1..=3 * CAST_LANES))
                .map(|_| rng.random_range(-std::f64::consts::PI..std::f64::consts::PI))
                .collect();
            let mut got = vec![f64::NAN; fan.len()];
            let dirs: Vec<(f64, f64)> = fan.iter().map(|a| (a.cos(), a.sin())).collect();
            map.cast_each(x, y, &dirs, max, &mut got);
            for (&a, &got) in fan.iter().zip(&got) {
                let want = every(x, y, a, max);
                assert_eq!(got, want, "from ({x}, {y}) at {a} up to {max}");
                long += usize::from(want > 2.0);
                rays += 1;
            }
        }
        // The rays were not all short ones.
        assert!(long > rays / 4, "{long} of {rays}");
    }

    /// Scans that fit the map worse than usual (every 7th beam blocked short by something
    /// the map does not hold) raise augmented MCL's share of random particles;
    /// the estimate stays on the robot, not dragged towards the middle of the room by them.
    #[test]
    fn random_particles_do_not_drag_the_estimate() {
        // The robot stands still; the filter takes every scan all the same.
        let config = MclConfig {
            model: SensorModel::LikelihoodField,
            update_min_d: 0.0,
            update_min_a: 0.0,
            ..MclConfig::default()
        };
        let reference = MclMap::new(room());
        let mut mcl = Mcl::new(config, MclMap::new(room()), 11);
        let truth = Pose2::new(8.5, 1.2, 2.0);
        mcl.set_pose(truth, [0.05, 0.05, 0.02]);
        let odo = Pose2::IDENTITY;
        for _ in 0..10 {
            mcl.update(&odo, &scan(&reference, &truth), &Pose2::IDENTITY);
        }
        let mut worst: f64 = 0.0;
        let mut spread: f64 = 0.0;
        const STEP: usize = 7;
        for _ in 0..30 {
            let mut z = scan(&reference, &truth);
            for r in z.ranges.iter_mut().step_by(STEP) {
                *r = (*r * 0.4).max(0.1);
            }
            let est = mcl.update(&odo, &z, &Pose2::IDENTITY);
            worst = worst.max(est.pose.distance(&truth));
            // How far the particle set's mean (random particles included) lies off.
            let n = mcl.particles().len() as f64;
            let (mx, my) = mcl
                .particles()
                .iter()
                .fold((0.0, 0.0), |(x, y), p| (x + p.x / n, y + p.y / n));
            spread = spread.max((mx - truth.x).hypot(my - truth.y));
        }
        // The injected particles are there (the set's mean moves), the estimate is not moved.
        assert!(spread > 0.3, "no random particles were injected: {spread}");
        assert!(worst < 0.1, "{worst}");
    }

    /// A dip of the fit as shallow as tracking brings (the fast average a tenth below the
    /// slow) injects no random particle with a `recovery_ratio` of 0.85; the textbook rule
    /// (1, the default) injects at any dip.
    #[test]
    fn a_shallow_dip_of_the_fit_injects_no_random_particles() {
        assert_eq!(MclConfig::default().recovery_ratio, 1.0);
        for (ratio, injects) in [(0.85, false), (1.0, true)] {
            let config = MclConfig {
                recovery_ratio: ratio,
                kld: false,
                ..MclConfig::default()
            };
            let mut mcl = Mcl::new(config, MclMap::new(room()), 5);
            let truth = Pose2::new(3.0, 2.0, 0.5);
            mcl.set_pose(truth, [0.05, 0.05, 0.02]);
            (mcl.w_slow, mcl.w_fast) = (1.0, 0.9);
            mcl.resample();
            let far = mcl
                .particles()
                .iter()
                .filter(|p| p.distance(&truth) > 0.5)
                .count();
            assert_eq!(far > 0, injects, "ratio {ratio}: {far} particles far off");
        }
    }

    /// Backing up is no noisier than driving forward: the same 15 cm straight back or ahead
    /// spreads the particles' headings alike (the noise of a turn of 0, not π).
    #[test]
    fn backing_up_spreads_the_set_as_driving_forward_does() {
        let start = Pose2::new(3.0, 2.0, 0.4);
        let spread_after = |step: f64| -> f64 {
            let config = MclConfig {
                kld: false,
                ..MclConfig::default()
            };
            let mut mcl = Mcl::new(config, MclMap::new(room()), 5);
            mcl.set_pose(start, [0.0, 0.0, 0.0]);
            mcl.predict(&Pose2::IDENTITY);
            mcl.predict(&Pose2::new(step, 0.0, 0.0));
            let th: Vec<f64> = mcl
                .particles()
                .iter()
                .map(|p| wrap_angle(p.theta - start.theta))
                .collect();
            let mean = th.iter().sum::<f64>() / th.len() as f64;
            (th.iter().map(|t| (t - mean).powi(2)).sum::<f64>() / th.len() as f64).sqrt()
        };
        let (ahead, back) = (spread_after(0.15), spread_after(-0.15));
        // Both: two rotations of σ = √α2 · 0.15 m = 0.067 rad each, about 0.095 rad together.
        let expected = (2.0 * 0.2 * 0.15f64.powi(2)).sqrt();
        for s in [ahead, back] {
            assert!(
                (s - expected).abs() < 0.2 * expected,
                "{ahead} {back} vs {expected}"
            );
        }
    }

    /// A robot that stands still: the filter takes its first scan and then no more until
    /// odometry moves, so the set keeps its spread; taking every scan of the standing robot
    /// collapses the set (resampling with no motion noise), which is what the rule prevents.
    #[test]
    fn a_standing_robot_does_not_collapse_the_set() {
        let reference = MclMap::new(room());
        let truth = Pose2::new(3.0, 2.0, 0.4);
        // Distinct particles in the set.
        let distinct = |mcl: &Mcl| -> usize {
            let mut d: Vec<(u64, u64, u64)> = mcl
                .particles()
                .iter()
                .map(|p| (p.x.to_bits(), p.y.to_bits(), p.theta.to_bits()))
                .collect();
            d.sort_unstable();
            d.dedup();
            d.len()
        };
        // Distinct particles after the first scan and after forty more of the standing robot.
        let spread = |update_min_d: f64, update_min_a: f64| -> (usize, usize, Estimate) {
            let config = MclConfig {
                update_min_d,
                update_min_a,
                kld: false,
                ..MclConfig::default()
            };
            let mut mcl = Mcl::new(config, MclMap::new(room()), 5);
            mcl.set_pose(truth, [0.05, 0.05, 0.02]);
            let odo = Pose2::new(1.0, -2.0, 0.3);
            let z = scan(&reference, &truth);
            let mut est = mcl.update(&odo, &z, &Pose2::IDENTITY);
            let first = distinct(&mcl);
            for _ in 0..40 {
                est = mcl.update(&odo, &z, &Pose2::IDENTITY);
            }
            (first, distinct(&mcl), est)
        };
        let (first, kept, est) = spread(0.05, 0.05);
        assert_eq!(first, kept);
        // Taking every scan: each resampling with no motion noise loses particles, and
        // forty of them leave a fraction of the first set.
        let (first, collapsed, _) = spread(0.0, 0.0);
        assert!(collapsed * 4 < first, "{collapsed} of {first}");
        assert!(est.pose.distance(&truth) < 0.1, "{est:?}");
        // Motion past the threshold makes the filter take the next scan and carry the estimate.
        let config = MclConfig::default();
        let mut mcl = Mcl::new(config, MclMap::new(room()), 5);
        mcl.set_pose(truth, [0.05, 0.05, 0.02]);
        let z = scan(&reference, &truth);
        let first = mcl.update(&Pose2::IDENTITY, &z, &Pose2::IDENTITY);
        let before = mcl.particles().to_vec();
        let small = Pose2::new(0.02, 0.0, 0.01);
        let carried = mcl.update(&small, &z, &Pose2::IDENTITY);
        assert_eq!(before, mcl.particles(), "a scan 2 cm on was taken");
        assert!(carried.pose.distance(&first.pose.compose(&small)) < 1e-12);
        let moved = truth.compose(&Pose2::new(0.3, 0.0, 0.0));
        mcl.update(
            &Pose2::new(0.3, 0.0, 0.0),
            &scan(&reference, &moved),
            &Pose2::IDENTITY,
        );
        assert_ne!(
            before,
            mcl.particles(),
            "the scan after moving 0.3 m was not taken"
        );
    }

    /// The rule on a hand-made set: ten particles in free space and one in a wall, three
    /// beams. A beam two of the ten find consistent is left out; three of ten (the 0.3
    /// threshold) and all ten keep theirs. When too many beams would go, all are kept.
    #[test]
    fn beam_skipping_leaves_out_the_beams_few_particles_find_consistent() {
        let mcl = Mcl::new(MclConfig::default(), MclMap::new(room()), 1);
        let mut terms: Vec<Option<Vec<(f64, bool)>>> = (0..10)
            .map(|k| Some(vec![(-1.0, k < 2), (-1.0, k < 3), (-1.0, true)]))
            .collect();
        // A particle inside a wall counts for no beam.
        terms.push(None);
        assert_eq!(mcl.beams_kept(&terms, 3), vec![false, true, true]);
        // Every beam inconsistent for nine particles in ten: the filter is lost, and skipping
        // them all would leave nothing to find it again by.
        let lost: Vec<Option<Vec<(f64, bool)>>> =
            (0..10).map(|k| Some(vec![(-1.0, k < 1); 3])).collect();
        assert_eq!(mcl.beams_kept(&lost, 3), vec![true; 3]);
        let off = Mcl::new(
            MclConfig {
                beam_skip: false,
                ..MclConfig::default()
            },
            MclMap::new(room()),
            1,
        );
        assert_eq!(off.beams_kept(&terms, 3), vec![true; 3]);
    }

    /// Two rows of chair legs 0.3 m apart along the rows, 0.45 and 0.85 m to the left of a
    /// robot that drives past them, turns in place 70° towards them and back, and drives on.
    /// Each leg is a 10 cm block on the map (a leg a few centimetres thick rasterised across
    /// cells of 5 cm) and absent from the world the scans are cast in, so the beams that pass
    /// between the true legs hit the map's blocks. The largest and the mean error of the estimate.
    fn past_the_legs(beam_skip: bool, seed: u64) -> (f64, f64) {
        let reference = MclMap::new(room());
        let mut legs = room();
        for k in 0..14 {
            let x = 2.0 + 0.3 * k as f64;
            for (dx, dy) in [(0.0, 0.0), (0.05, 0.0), (0.0, 0.05), (0.05, 0.05)] {
                for leg in [[x, 2.45], [x + 0.2, 2.85]] {
                    if let Some((i, j)) = legs.cell_of(leg[0] + dx, leg[1] + dy) {
                        legs.set(i, j, 100);
                    }
                }
            }
        }
        let config = MclConfig {
            beam_skip,
            ..MclConfig::default()
        };
        let mut mcl = Mcl::new(config, MclMap::new(legs), seed);
        let mut truth = Pose2::new(2.6, 2.0, 0.0);
        mcl.set_pose(truth, [0.03, 0.03, 0.02]);
        let mut odo = Pose2::IDENTITY;
        let (mut worst, mut sum): (f64, f64) = (0.0, 0.0);
        let n = 40;
        for k in 0..n {
            let step = match k {
                10..14 => Pose2::new(0.0, 0.0, 0.3),
                14..18 => Pose2::new(0.0, 0.0, -0.3),
                _ => Pose2::new(0.08, 0.0, 0.0),
            };
            truth = truth.compose(&step);
            odo = odo.compose(&step);
            let est = mcl.update(&odo, &scan(&reference, &truth), &Pose2::IDENTITY);
            worst = worst.max(est.pose.distance(&truth));
            sum += est.pose.distance(&truth);
        }
        (worst, sum / n as f64)
    }

    /// With beam skipping the filter tracks the robot past the legs on every seed (never
    /// 0.5 m off, 0.1 m on average); without it, the beams through the map's blocks pull the
    /// set off and it is lost by more than a metre.
    #[test]
    fn legs_the_map_draws_wider_than_they_are_do_not_pull_the_estimate() {
        let mut lost_without = 0;
        for seed in 1..=3 {
            let (worst, mean) = past_the_legs(true, seed);
            assert!(
                worst < 0.5 && mean < 0.1,
                "seed {seed}: largest error {worst:.3} m, mean {mean:.3} m with beam skipping"
            );
            let (worst, _) = past_the_legs(false, seed);
            lost_without += usize::from(worst > 1.0);
        }
        assert!(
            lost_without > 0,
            "no seed lost the robot without beam skipping"
        );
    }

    /// Drives a filter seeded `seed` round the room (from no knowledge of the pose where
    /// `global`, else from a rough start), then carries the robot off unseen and turns it in
    /// place. The estimate and the truth at the end of each part.
    fn drive(model: SensorModel, global: bool, seed: u64) -> [(Estimate, Pose2); 2] {
        let config = MclConfig {
            model,
            ..MclConfig::default()
        };
        let reference = MclMap::new(room());
        let mut mcl = Mcl::new(config, MclMap::new(room()), seed);
        // Drive a loop; odometry is exact here, the filter starts knowing nothing.
        let mut truth = Pose2::new(1.5, 1.5, 0.3);
        let mut odo = Pose2::new(0.0, 0.0, 0.0);
        if !global {
            mcl.set_pose(Pose2::new(1.8, 1.3, 0.5), [0.3, 0.3, 0.2]);
        }
        let mut est = mcl.estimate();
        for k in 0..60 {
            let step = if k % 15 < 12 {
                Pose2::new(0.15, 0.0, 0.0)
            } else {
                Pose2::new(0.0, 0.0, 0.5)
            };
            let next = truth.compose(&step);
            if reference.occupied_or_outside(
                next.x + 0.3 * next.theta.cos(),
                next.y + 0.3 * next.theta.sin(),
            ) {
                truth = truth.compose(&Pose2::new(0.0, 0.0, 0.6));
                odo = odo.compose(&Pose2::new(0.0, 0.0, 0.6));
            } else {
                truth = next;
                odo = odo.compose(&step);
            }
            est = mcl.update(&odo, &scan(&reference, &truth), &Pose2::IDENTITY);
        }
        let first = (est, truth);
        // Kidnap: carry the robot elsewhere without telling odometry.
        truth = Pose2::new(8.0, 4.5, -2.0);
        for _ in 0..80 {
            let step = Pose2::new(0.0, 0.0, 0.3);
            truth = truth.compose(&step);
            odo = odo.compose(&step);
            est = mcl.update(&odo, &scan(&reference, &truth), &Pose2::IDENTITY);
        }
        [first, (est, truth)]
    }

    /// Ten seeds of [`drive`]: at the end of each part, the estimate on the truth (0.1 m and
    /// 0.05 rad after the first, 0.15 m and 0.1 rad after the kidnapping) in at least three
    /// runs of ten. One seed is no test here: the room's bare rectangle fits a scan of 16
    /// beams at several poses all but as well as at the truth (its mirror images; only the
    /// stub and the pillar tell them apart), and which one the filter settles on changes from
    /// seed to seed. Over seeds 1–30 the beam model recovers from the kidnapping onto the
    /// truth in 20 runs, the likelihood field in 22; without random particles they recover in
    /// none and in one of seeds 1–10.
    fn localises(model: SensorModel, global: bool) {
        let mut on_truth = [0usize; 2];
        for seed in 1..=10 {
            for (part, (est, truth)) in drive(model, global, seed).into_iter().enumerate() {
                let (metres, radians) = [(0.1, 0.05), (0.15, 0.1)][part];
                on_truth[part] += usize::from(
                    est.pose.distance(&truth) < metres
                        && wrap_angle(est.pose.theta - truth.theta).abs() < radians,
                );
            }
        }
        assert!(
            on_truth.iter().all(|&n| n >= 3),
            "{model:?}: on the truth in {on_truth:?} of 10 runs"
        );
    }

    #[test]
    fn likelihood_field_mcl_localises_globally_and_recovers_from_kidnapping() {
        localises(SensorModel::LikelihoodField, true);
    }

    #[test]
    fn beam_model_mcl_tracks_from_a_rough_start_and_recovers_from_kidnapping() {
        localises(SensorModel::Beam, false);
    }

    #[test]
    fn kld_bound_matches_a_hand_computation() {
        // k = 10 bins, ε = 0.01, z = 2.326: 9/0.02 · (1 − 2/81 + √(2/81)·2.326)³ = 1084.7.
        assert_eq!(kld_bound(10, 0.01, 2.326), 1085);
        assert!(kld_bound(100, 0.01, 2.326) > kld_bound(10, 0.01, 2.326));
        assert_eq!(kld_bound(1, 0.01, 2.326), 1);
    }

    #[test]
    fn normal_quantiles_match_tables() {
        assert!((normal_quantile(0.99) - 2.326348).abs() < 1e-5);
        assert!((normal_quantile(0.5)).abs() < 1e-9);
        assert!((normal_quantile(0.01) + 2.326348).abs() < 1e-5);
    }
}
