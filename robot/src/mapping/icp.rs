//! 2D scan-to-map ICP (written for futago): point-to-line Gauss–Newton on SE(2) against a map
//! of points with normals, as seed 000 matches each scan to its map from the odometry guess.
//!
//! The map keeps at most one point per `voxel` cell in a hash grid, each with the normal of the
//! surface it was seen on (fitted to its neighbours in its own scan). Matching pairs each scan
//! point with the nearest map point within a correspondence distance that shrinks over the
//! iterations, and minimises the Huber-weighted point-to-line distances.

use crate::cores::map_on_cores;
use crate::geometry::{closer_than, floor_i64, least_squared_distance, squared_distance};
use futago_msgs::{LaserScan, Pose2, wrap_angle};
use rustc_hash::FxHashMap;
use serde::Deserialize;

/// Matcher parameters (`slam.icp.*`).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct IcpConfig {
    pub max_iterations: usize,
    /// Correspondence distance of the first and the last iterations, m.
    pub max_distance_start: f64,
    pub max_distance_end: f64,
    /// Huber threshold of the point-to-line residual, m.
    pub huber: f64,
    /// At least this share of the scan's points must find a partner.
    pub min_overlap: f64,
    /// Map point spacing, m.
    pub voxel: f64,
    /// Radius of the scan neighbourhood a point's normal is fitted to, m: several times the
    /// range noise, so that the fitted line is not noise.
    pub normal_radius: f64,
    /// Largest ratio of the fit's small to large spread for a point to count as on a line.
    pub planarity: f64,
    /// Weight of the odometry guess against the mean squared point-to-line residual, for
    /// translation (per m²) and rotation (per rad²), as Cartographer's scan matcher weighs
    /// its prior: it holds the pose where the scan alone does not (a corridor's length). The
    /// defaults were chosen on a simulated lab log and the MIT CSAIL log (see the closing note
    /// of issue 4's first part).
    pub translation_weight: f64,
    pub rotation_weight: f64,
    /// Points a scan needs for its fit to count fully against the prior. The point term is
    /// a mean, so without this a scan of 40 scattered points would pull as hard as one of
    /// 400 along clean walls; a scan with fewer points weighs the prior up in proportion
    /// (`translation_weight × prior_points / points`), as a sum of squares over its points
    /// would. A denser scan keeps the plain weights (0: off). 120 is the median of the
    /// Intel log's 180-beam scans after the line test: there the weights above were chosen.
    pub prior_points: f64,
    /// Half-width of the heading search before ICP, rad (0: none). Odometry headings can be
    /// off by more than ICP's basin of convergence after a fast turn; the search tries
    /// headings around the guess in `rotation_search_step` steps and starts ICP from the one
    /// whose points land closest to the map. The step is `rotation_search_step` at most, and
    /// finer where the scan's farthest point would move more than `max_distance_end` in one.
    pub rotation_search: f64,
    pub rotation_search_step: f64,
    /// Make the heading search's step finer for far points (see `rotation_search`); off, the
    /// step is `rotation_search_step` however far the points reach.
    pub heading_step_by_range: bool,
    /// A point's normal is fitted to its neighbours within `normal_radius`, or within this
    /// many beam spacings at its range where that is wider, so that a far wall, whose returns
    /// lie further apart than `normal_radius`, keeps its points (0: `normal_radius` alone).
    pub normal_spacings: f64,
    /// Scan points are thinned to one per cell of this size, m (0: all kept), as
    /// Cartographer's voxel filter: dense near returns add time, not information.
    pub scan_voxel: f64,
}

impl Default for IcpConfig {
    fn default() -> Self {
        IcpConfig {
            max_iterations: 30,
            max_distance_start: 0.5,
            max_distance_end: 0.1,
            huber: 0.03,
            min_overlap: 0.3,
            voxel: 0.03,
            normal_radius: 0.3,
            planarity: 0.1,
            translation_weight: 0.05,
            rotation_weight: 0.02,
            prior_points: 120.0,
            rotation_search: 0.35,
            rotation_search_step: 0.025,
            heading_step_by_range: true,
            normal_spacings: 3.0,
            scan_voxel: 0.0,
        }
    }
}

impl IcpConfig {
    /// Checks every field; the error names the key below `prefix`.
    pub fn validate(&self, prefix: &str) -> Result<(), crate::config::ConfigError> {
        use std::f64::consts::PI;
        crate::config::check_counts(
            prefix,
            &[("max_iterations", self.max_iterations, 1, 10_000)],
        )?;
        crate::config::check_ranges(
            prefix,
            &[
                ("max_distance_start", self.max_distance_start, 1e-3, 100.0),
                ("max_distance_end", self.max_distance_end, 1e-3, 100.0),
                ("huber", self.huber, 1e-4, 100.0),
                ("min_overlap", self.min_overlap, 0.0, 1.0),
                ("voxel", self.voxel, 1e-3, 10.0),
                ("normal_radius", self.normal_radius, 1e-3, 100.0),
                ("planarity", self.planarity, 0.0, 1.0),
                ("translation_weight", self.translation_weight, 0.0, 1e6),
                ("rotation_weight", self.rotation_weight, 0.0, 1e6),
                ("prior_points", self.prior_points, 0.0, 1e6),
                ("rotation_search", self.rotation_search, 0.0, PI),
                ("rotation_search_step", self.rotation_search_step, 1e-4, PI),
                ("scan_voxel", self.scan_voxel, 0.0, 10.0),
                ("normal_spacings", self.normal_spacings, 0.0, 100.0),
            ],
        )
    }
}

/// A point and the unit normal of its surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Oriented {
    pub p: [f64; 2],
    pub n: [f64; 2],
}

/// Most neighbours taken on each side of a beam.
const MAX_NEIGHBOURS: usize = 40;

/// The line fitted to `near` (`p` and its neighbours): `p` with the normal facing the sensor,
/// or `None` when too few points or not straight.
fn fit_normal(
    near: &[[f64; 2]],
    p: [f64; 2],
    mount: &Pose2,
    config: &IcpConfig,
) -> Option<Oriented> {
    if near.len() < 5 {
        return None;
    }
    let m = near.len() as f64;
    let c = near
        .iter()
        .fold([0.0, 0.0], |a, q| [a[0] + q[0] / m, a[1] + q[1] / m]);
    let (mut sxx, mut sxy, mut syy) = (0.0f64, 0.0f64, 0.0f64);
    for q in near {
        let (dx, dy) = (q[0] - c[0], q[1] - c[1]);
        sxx += dx * dx;
        sxy += dx * dy;
        syy += dy * dy;
    }
    // Keep points on straight surfaces only: at corners and edges the fitted normal is a
    // blend of two surfaces and would bias the match.
    let tr = sxx + syy;
    let disc = ((sxx - syy).powi(2) + 4.0 * sxy * sxy).sqrt();
    let (small, large) = ((tr - disc) / 2.0, (tr + disc) / 2.0);
    if large <= 0.0 || small > config.planarity * large {
        return None;
    }
    // Direction of least spread: the normal.
    let theta = 0.5 * (2.0 * sxy).atan2(sxx - syy) + std::f64::consts::FRAC_PI_2;
    let mut n = [theta.cos(), theta.sin()];
    // Face the sensor.
    let to_sensor = [mount.x - p[0], mount.y - p[1]];
    if n[0] * to_sensor[0] + n[1] * to_sensor[1] < 0.0 {
        n = [-n[0], -n[1]];
    }
    Some(Oriented { p, n })
}

/// The robot's motion while a scanner sweeps: a constant velocity, given as the displacement
/// `step` (in the robot's frame at the start) that it makes in `over` seconds. A scanner casts
/// its beams one after another (`LaserScan::time_increment` apart, from the scan's stamp, as
/// ROS has it), so a robot that turns at 1 rad/s while a 40 Hz scanner sweeps 240° bends the
/// scan by a degree; [`scan_points`] takes each beam back to the robot's pose at the stamp.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sweep {
    pub step: Pose2,
    pub over: f64,
}

impl Sweep {
    /// No motion: scans are taken as they are.
    pub const STILL: Sweep = Sweep {
        step: Pose2::IDENTITY,
        over: 0.0,
    };

    /// Where the robot is `t` seconds after the stamp, relative to its pose at the stamp.
    pub fn at(&self, t: f64) -> Pose2 {
        if self.over > 0.0 && t != 0.0 {
            Pose2::IDENTITY.lerp(&self.step, t / self.over)
        } else {
            Pose2::IDENTITY
        }
    }
}

/// Points of `scan` in the frame of the robot at the scan's stamp, whose laser sits at `mount`
/// and who moves as `sweep` says while the beams are cast, with normals; readings outside
/// `[range_min, max_range]` and points without close neighbours are dropped.
pub fn scan_points(
    scan: &LaserScan,
    mount: &Pose2,
    sweep: &Sweep,
    max_range: f64,
    config: &IcpConfig,
) -> Vec<Oriented> {
    let raw: Vec<Option<[f64; 2]>> = scan
        .ranges
        .iter()
        .enumerate()
        .map(|(k, &r)| {
            let r = r as f64;
            (r.is_finite() && r >= scan.range_min.max(0.01) && r <= max_range).then(|| {
                let a = scan.angle(k);
                let laser = sweep.at(k as f64 * scan.time_increment).compose(mount);
                laser.transform_point([r * a.cos(), r * a.sin()])
            })
        })
        .collect();
    let increment = scan.angle_increment.abs();
    let mut out = Vec::with_capacity(raw.len());
    for k in 0..raw.len() {
        let Some(p) = raw[k] else { continue };
        // Neighbours along the scan within a radius: fit a line through them (2×2 PCA). A
        // radius, not a beam count, so that range noise stays small against the extent; it
        // grows with range to span `normal_spacings` beam spacings (3 by default: two
        // neighbours on each side of a wall seen at up to 48° from square on, `2/cos φ < 3`),
        // so that a far wall, whose returns lie further apart than `normal_radius`, keeps
        // its points.
        let range = (p[0] - mount.x).hypot(p[1] - mount.y);
        let radius = config
            .normal_radius
            .max(config.normal_spacings * range * increment);
        let close = |j: usize| raw[j].filter(|q| closer_than(q[0] - p[0], q[1] - p[1], radius));
        let mut near = vec![p];
        for j in (k.saturating_sub(MAX_NEIGHBOURS)..k).rev() {
            match close(j) {
                Some(q) => near.push(q),
                None => break,
            }
        }
        for j in k + 1..(k + 1 + MAX_NEIGHBOURS).min(raw.len()) {
            match close(j) {
                Some(q) => near.push(q),
                None => break,
            }
        }
        if let Some(o) = fit_normal(&near, p, mount, config) {
            out.push(o);
        }
    }
    if config.scan_voxel > 0.0 {
        let mut seen = rustc_hash::FxHashSet::default();
        out.retain(|o| {
            seen.insert((
                (o.p[0] / config.scan_voxel).floor() as i64,
                (o.p[1] / config.scan_voxel).floor() as i64,
            ))
        });
    }
    out
}

/// Map points with normals in a hash grid, one per voxel.
#[derive(Debug, Clone, Default)]
pub struct PointMap {
    voxel: f64,
    /// Cell side of the lookup grid (the largest correspondence distance).
    bucket: f64,
    voxels: FxHashMap<(i64, i64), ()>,
    buckets: FxHashMap<(i64, i64), Bucket>,
    len: usize,
}

/// A lookup cell's points in the order added, with their positions again side by side:
/// [`PointMap::nearest`] reads positions alone, half the memory of the points.
#[derive(Debug, Clone, Default)]
struct Bucket {
    xy: Vec<[f64; 2]>,
    points: Vec<Oriented>,
}

impl Bucket {
    /// Makes this bucket's (at `key`) first point at its least distance from `q` the closest
    /// so far (`best`, at squared distance `bd`) where it is closer, or as close and this
    /// bucket comes first in (column, row) order: the nearest point's ties go to the first
    /// bucket in that order, then to the point added first.
    fn offer<'a>(
        &'a self,
        q: [f64; 2],
        key: (i64, i64),
        best: &mut Option<(&'a Oriented, (i64, i64))>,
        bd: &mut f64,
    ) {
        let m = least_squared_distance(&self.xy, &q);
        let better = m < *bd || (m == *bd && best.is_none_or(|(_, at)| key < at));
        if better && let Some(k) = self.xy.iter().position(|p| squared_distance(p, &q) == m) {
            *best = Some((&self.points[k], key));
            *bd = m;
        }
    }
}

impl PointMap {
    pub fn new(voxel: f64, bucket: f64) -> PointMap {
        PointMap {
            voxel,
            bucket,
            ..Default::default()
        }
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    fn key(x: f64, y: f64, s: f64) -> (i64, i64) {
        (floor_i64(x / s), floor_i64(y / s))
    }

    /// Adds points (robot frame) seen from `pose`; voxels already filled keep their point.
    pub fn insert(&mut self, pose: &Pose2, points: &[Oriented]) {
        let (s, c) = pose.theta.sin_cos();
        for o in points {
            let p = pose.transform_point(o.p);
            let v = Self::key(p[0], p[1], self.voxel);
            if self.voxels.insert(v, ()).is_some() {
                continue;
            }
            let n = [c * o.n[0] - s * o.n[1], s * o.n[0] + c * o.n[1]];
            let b = self
                .buckets
                .entry(Self::key(p[0], p[1], self.bucket))
                .or_default();
            b.xy.push(p);
            b.points.push(Oriented { p, n });
            self.len += 1;
        }
    }

    /// The nearest map point to `q` within `max` (≤ the bucket size): the closest, and of
    /// points at the same distance the one in the first bucket in (column, row) order, then
    /// the one added to it first.
    pub fn nearest(&self, q: [f64; 2], max: f64) -> Option<&Oriented> {
        let (bi, bj) = Self::key(q[0], q[1], self.bucket);
        // Only the buckets that the square round the disk of radius `max` reaches, widened by
        // a micrometre for the rounding of the distances below: no other holds a point within
        // `max`. Late iterations look 0.1 m round a point in 0.5 m buckets: one to four
        // buckets instead of nine (most of SLAM's time).
        let reach = max * (1.0 + 1e-9) + 1e-6;
        let (li, lj) = Self::key(q[0] - reach, q[1] - reach, self.bucket);
        let (hi, hj) = Self::key(q[0] + reach, q[1] + reach, self.bucket);
        // The closest so far, its bucket and its squared distance (`max²` while there is
        // none). Each bucket's least distance is found first (no branch on each point), and
        // only a bucket that holds a closer point than those before it, or one as close in a
        // bucket that comes first in (column, row) order, is searched again for the first
        // point at that distance (issue 48).
        let mut best: Option<(&Oriented, (i64, i64))> = None;
        let mut bd = max * max;
        // The query's own bucket first: its closest point is most often the nearest, and
        // then the buckets beside it lie farther than that and are passed over.
        if let Some(b) = self.buckets.get(&(bi, bj)) {
            b.offer(q, (bi, bj), &mut best, &mut bd);
        }
        let side = self.bucket;
        // How far `q` lies from the side of its own bucket that faces bucket `i` (0 for its
        // own), less a nanometre for the rounding of the keys: no point of bucket `i` lies
        // nearer along this axis.
        let gap = |i: i64, own: i64, x: f64| -> f64 {
            let g = match i.cmp(&own) {
                std::cmp::Ordering::Less => x - own as f64 * side,
                std::cmp::Ordering::Equal => 0.0,
                std::cmp::Ordering::Greater => (own + 1) as f64 * side - x,
            };
            (g - 1e-9).max(0.0)
        };
        for i in li.max(bi - 1)..=hi.min(bi + 1) {
            let gx = gap(i, bi, q[0]);
            for j in lj.max(bj - 1)..=hj.min(bj + 1) {
                if (i, j) == (bi, bj) {
                    continue;
                }
                let gy = gap(j, bj, q[1]);
                // Every point of the bucket lies farther than the closest so far: none is
                // the nearest, nor ties with it.
                if gx * gx + gy * gy > bd {
                    continue;
                }
                if let Some(b) = self.buckets.get(&(i, j)) {
                    b.offer(q, (i, j), &mut best, &mut bd);
                }
            }
        }
        best.map(|(o, _)| o)
    }

    /// Every point (for export and tests).
    pub fn points(&self) -> impl Iterator<Item = &Oriented> {
        self.buckets.values().flat_map(|b| &b.points)
    }
}

/// Iterations over which the correspondence distance shrinks to its final value.
const RAMP_ITERATIONS: f64 = 5.0;

/// Outcome of one alignment.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Alignment {
    pub pose: Pose2,
    /// Share of scan points with a partner in the last iteration.
    pub overlap: f64,
    /// RMS point-to-line residual of the partners, m.
    pub rms: f64,
    pub iterations: usize,
}

/// Aligns `scan` (robot frame) to `map` starting from `guess`; `None` when too few points
/// find partners.
pub fn align(map: &PointMap, scan: &[Oriented], guess: Pose2, c: &IcpConfig) -> Option<Alignment> {
    if scan.is_empty() || map.is_empty() {
        return None;
    }
    let mut pose = best_heading(map, scan, guess, c);
    // The prior's weight against the mean point term (see `IcpConfig::prior_points`).
    let scale = (c.prior_points / scan.len() as f64).max(1.0);
    let mut result = None;
    for it in 0..c.max_iterations {
        // The correspondence distance shrinks over the first iterations, then holds.
        let f = (it as f64 / RAMP_ITERATIONS).min(1.0);
        let dmax = c.max_distance_start + f * (c.max_distance_end - c.max_distance_start);
        let (s, co) = pose.theta.sin_cos();
        let mut h = [[0.0f64; 3]; 3];
        let mut g = [0.0f64; 3];
        let (mut pairs, mut sq) = (0usize, 0.0);
        for o in scan {
            let q = [
                pose.x + co * o.p[0] - s * o.p[1],
                pose.y + s * o.p[0] + co * o.p[1],
            ];
            let Some(m) = map.nearest(q, dmax) else {
                continue;
            };
            // Surfaces seen from opposite sides do not match.
            let n_scan = [co * o.n[0] - s * o.n[1], s * o.n[0] + co * o.n[1]];
            if n_scan[0] * m.n[0] + n_scan[1] * m.n[1] < 0.5 {
                continue;
            }
            let r = m.n[0] * (q[0] - m.p[0]) + m.n[1] * (q[1] - m.p[1]);
            let j = [
                m.n[0],
                m.n[1],
                m.n[0] * -(q[1] - pose.y) + m.n[1] * (q[0] - pose.x),
            ];
            let w = if r.abs() <= c.huber {
                1.0
            } else {
                c.huber / r.abs()
            };
            for a in 0..3 {
                g[a] += w * j[a] * r;
                for b in 0..3 {
                    h[a][b] += w * j[a] * j[b];
                }
            }
            pairs += 1;
            sq += r * r;
        }
        let overlap = pairs as f64 / scan.len() as f64;
        if overlap < c.min_overlap || pairs < 10 {
            return None;
        }
        // Mean point term plus the prior towards the guess.
        let inv = 1.0 / pairs as f64;
        for (ga, ha) in g.iter_mut().zip(h.iter_mut()) {
            *ga *= inv;
            ha.iter_mut().for_each(|x| *x *= inv);
        }
        let prior = [
            (scale * c.translation_weight, pose.x - guess.x),
            (scale * c.translation_weight, pose.y - guess.y),
            (
                scale * c.rotation_weight,
                wrap_angle(pose.theta - guess.theta),
            ),
        ];
        for (a, (w, d)) in prior.into_iter().enumerate() {
            h[a][a] += w;
            g[a] += w * d;
        }
        let d = solve3(h, [-g[0], -g[1], -g[2]])?;
        pose = Pose2::new(pose.x + d[0], pose.y + d[1], wrap_angle(pose.theta + d[2]));
        result = Some(Alignment {
            pose,
            overlap,
            rms: (sq / pairs as f64).sqrt(),
            iterations: it + 1,
        });
        if f >= 1.0 && d[0].hypot(d[1]) < 1e-5 && d[2].abs() < 1e-5 {
            break;
        }
    }
    result
}

/// How well `scan` (robot frame) at `pose` fits `map`: the mean over the scan's points of a
/// Gaussian (standard deviation `sigma`) of the distance to the nearest map point, in [0, 1].
/// Used to choose between alignments started from different guesses.
pub fn fit_score(map: &PointMap, scan: &[Oriented], pose: &Pose2, sigma: f64) -> f64 {
    if scan.is_empty() {
        return 0.0;
    }
    let reach = 2.0 * sigma;
    let sum: f64 = scan
        .iter()
        .filter_map(|o| {
            let q = pose.transform_point(o.p);
            map.nearest(q, reach).map(|m| {
                let d2 = (m.p[0] - q[0]).powi(2) + (m.p[1] - q[1]).powi(2);
                (-d2 / (2.0 * sigma * sigma)).exp()
            })
        })
        .sum();
    sum / scan.len() as f64
}

/// The heading within `rotation_search` of the guess whose points (every 4th) land closest to
/// map points (Gaussian score, σ = the final correspondence distance).
fn best_heading(map: &PointMap, scan: &[Oriented], guess: Pose2, c: &IcpConfig) -> Pose2 {
    heading_search(map, scan, guess, c, true)
}

/// [`best_heading`], giving up the headings that cannot be chosen when `give_up` (always but
/// in the test that checks it changes nothing).
fn heading_search(
    map: &PointMap,
    scan: &[Oriented],
    guess: Pose2,
    c: &IcpConfig,
    give_up: bool,
) -> Pose2 {
    if c.rotation_search <= 0.0 || c.rotation_search_step <= 0.0 {
        return guess;
    }
    let sigma = c.max_distance_end.max(1e-3);
    let reach = 2.0 * sigma;
    // Every 4th point of a dense scan; all of a sparse one, whose few points would otherwise
    // let a chance alignment win.
    let stride = (scan.len() / HEADING_POINTS).clamp(1, 4);
    // A heading's score, the sum over its points of each one's term (at most 1); `None` as
    // soon as the terms still to come could not lift it above `floor`.
    let points = scan.len().div_ceil(stride);
    let score = |pose: &Pose2, floor: f64| -> Option<f64> {
        let mut sum = -0.0;
        for (k, o) in scan.iter().step_by(stride).enumerate() {
            let q = pose.transform_point(o.p);
            if let Some(m) = map.nearest(q, reach) {
                let d2 = (m.p[0] - q[0]).powi(2) + (m.p[1] - q[1]).powi(2);
                sum += (-d2 / (2.0 * sigma * sigma)).exp();
            }
            // A micrometre of margin over the sums' rounding (some 1e-12 here).
            if sum + (points - k - 1) as f64 + 1e-6 <= floor {
                return None;
            }
        }
        Some(sum)
    };
    // A step turns the farthest point by at most the final correspondence distance, so that
    // no heading between two steps is missed however far the points reach.
    let reach_m = scan
        .iter()
        .map(|o| o.p[0].hypot(o.p[1]))
        .fold(0.0, f64::max);
    let step = if c.heading_step_by_range {
        c.rotation_search_step
            .min(c.max_distance_end / reach_m.max(1e-3))
    } else {
        c.rotation_search_step
    };
    let steps = (c.rotation_search / step).round() as i64;
    // The guess, scored whole (no floor), then the other headings in turn, chosen in order.
    // A heading must score clearly better than the best so far to replace it (the guess is
    // preferred on ties), and the best so far is never below the guess: a heading whose score
    // cannot pass 1.05 times the guess's is never chosen, and is given up once its points
    // left cannot get it there.
    let Some(first) = score(&guess, f64::NEG_INFINITY) else {
        return guess;
    };
    let floor = if give_up {
        first * 1.05
    } else {
        f64::NEG_INFINITY
    };
    let poses: Vec<Pose2> = (-steps..=steps)
        .filter(|&k| k != 0)
        .map(|k| Pose2::new(guess.x, guess.y, wrap_angle(guess.theta + k as f64 * step)))
        .collect();
    let scores = map_on_cores(&poses, HEADINGS_SERIAL_BELOW, |p| score(p, floor));
    let mut best = (first, guess);
    for (sc, &p) in scores.into_iter().zip(&poses) {
        if let Some(sc) = sc
            && sc > best.0 * 1.05
        {
            best = (sc, p);
        }
    }
    best.1
}

/// Below this many headings the search scores them on one thread, where starting threads
/// would cost more than it saves.
const HEADINGS_SERIAL_BELOW: usize = 8;

/// Points scored per heading in the search, at least (where the scan has them).
const HEADING_POINTS: usize = 64;

/// Solves the 3×3 system `h x = g` (Cramer's rule); `None` if singular.
fn solve3(h: [[f64; 3]; 3], g: [f64; 3]) -> Option<[f64; 3]> {
    let det = |m: [[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(h);
    if d.abs() < 1e-12 {
        return None;
    }
    let mut x = [0.0; 3];
    for (k, xk) in x.iter_mut().enumerate() {
        let mut m = h;
        for r in 0..3 {
            m[r][k] = g[r];
        }
        *xk = det(m) / d;
    }
    Some(x)
}

/// Synthetic scans for the stack's tests.
#[cfg(test)]
pub(crate) mod tests_support {
    use futago_msgs::{LaserScan, Pose2, Time};

    /// A scan of an L-shaped room corner plus a pillar, from `pose`, ranges by ray casting
    /// against the walls x = 4, y = 3, y = −2 and a box around (2, 1).
    pub fn room_scan(pose: &Pose2) -> LaserScan {
        scan_of(&ROOM, pose)
    }

    /// Walls x = 4, y = 3, y = −2 and a 0.4 m box around (2, 1).
    pub const ROOM: [([f64; 2], [f64; 2]); 7] = [
        ([4.0, -2.0], [4.0, 3.0]),
        ([-1.0, 3.0], [4.0, 3.0]),
        ([-1.0, -2.0], [4.0, -2.0]),
        ([1.8, 0.8], [2.2, 0.8]),
        ([2.2, 0.8], [2.2, 1.2]),
        ([2.2, 1.2], [1.8, 1.2]),
        ([1.8, 1.2], [1.8, 0.8]),
    ];

    /// A 270°, 361-beam noise-free scan of wall segments from `pose`.
    pub fn scan_of(segs: &[([f64; 2], [f64; 2])], pose: &Pose2) -> LaserScan {
        swept_scan_of(segs, |_| *pose, 0.0)
    }

    /// As [`scan_of`], with beam `k` cast `k·time_increment` after the stamp from
    /// `pose_at(that time)`: the scan of a moving laser.
    pub fn swept_scan_of(
        segs: &[([f64; 2], [f64; 2])],
        pose_at: impl Fn(f64) -> Pose2,
        time_increment: f64,
    ) -> LaserScan {
        let n = 361;
        let inc = std::f64::consts::PI * 1.5 / (n - 1) as f64;
        let ranges = (0..n)
            .map(|k| {
                let pose = pose_at(k as f64 * time_increment);
                let a = pose.theta - 0.75 * std::f64::consts::PI + k as f64 * inc;
                cast(segs, [pose.x, pose.y], a) as f32
            })
            .collect();
        LaserScan {
            frame: "front".into(),
            stamp: Time::ZERO,
            angle_min: -0.75 * std::f64::consts::PI,
            angle_increment: inc,
            time_increment,
            range_min: 0.02,
            range_max: 30.0,
            ranges,
        }
    }

    /// Distance from `o` along bearing `a` to the nearest of the segments (∞ if none).
    pub fn cast(segs: &[([f64; 2], [f64; 2])], o: [f64; 2], a: f64) -> f64 {
        let (dx, dy) = (a.cos(), a.sin());
        let mut best = f64::INFINITY;
        for &(p, q) in segs {
            let (ex, ey) = (q[0] - p[0], q[1] - p[1]);
            let den = dx * ey - dy * ex;
            if den.abs() < 1e-12 {
                continue;
            }
            let (wx, wy) = (p[0] - o[0], p[1] - o[1]);
            let t = (wx * ey - wy * ex) / den;
            let u = (wx * dy - wy * dx) / den;
            if t > 0.0 && (0.0..=1.0).contains(&u) {
                best = best.min(t);
            }
        }
        best
    }

    /// Distance from `p` to the nearest of the segments.
    pub fn distance_to(segs: &[([f64; 2], [f64; 2])], p: [f64; 2]) -> f64 {
        segs.iter()
            .map(|&(a, b)| {
                let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
                let u = (((p[0] - a[0]) * ex + (p[1] - a[1]) * ey) / (ex * ex + ey * ey))
                    .clamp(0.0, 1.0);
                (a[0] + u * ex - p[0]).hypot(a[1] + u * ey - p[1])
            })
            .fold(f64::INFINITY, f64::min)
    }
}

#[cfg(test)]
mod tests {
    use super::tests_support::{ROOM, distance_to, room_scan, scan_of, swept_scan_of};

    /// The room's points seen from `pose` by a laser at the robot's centre.
    fn room_points(pose: &Pose2, c: &IcpConfig) -> Vec<Oriented> {
        scan_points(&room_scan(pose), &Pose2::IDENTITY, &Sweep::STILL, 30.0, c)
    }
    use super::*;

    #[test]
    fn icp_recovers_an_offset_pose_in_a_room() {
        // Pure ICP: no pull towards the guess.
        let c = IcpConfig {
            translation_weight: 0.0,
            rotation_weight: 0.0,
            ..IcpConfig::default()
        };
        let origin = Pose2::new(0.0, 0.0, 0.0);
        let mut map = PointMap::new(c.voxel, c.max_distance_start);
        map.insert(&origin, &room_points(&origin, &c));
        let truth = Pose2::new(0.3, -0.2, 0.1);
        let pts = room_points(&truth, &c);
        // Start 0.15 m and 3° off, as wheel odometry might be after a few scans.
        let guess = Pose2::new(0.42, -0.11, 0.15);
        let a = align(&map, &pts, guess, &c).expect("aligns");
        assert!(a.pose.distance(&truth) < 0.01, "{:?} vs {truth:?}", a.pose);
        assert!(wrap_angle(a.pose.theta - truth.theta).abs() < 0.2f64.to_radians());
        assert!(a.overlap > 0.8, "{a:?}");
    }

    #[test]
    fn the_heading_search_recovers_a_turn_that_odometry_misjudged() {
        let c = IcpConfig {
            translation_weight: 0.0,
            rotation_weight: 0.0,
            rotation_search: 40f64.to_radians(),
            ..IcpConfig::default()
        };
        let origin = Pose2::IDENTITY;
        let mut map = PointMap::new(c.voxel, c.max_distance_start);
        map.insert(&origin, &room_points(&origin, &c));
        let truth = Pose2::new(0.2, 0.1, 0.3);
        let pts = room_points(&truth, &c);
        // Odometry thinks the robot turned 35° less than it did.
        let guess = Pose2::new(0.2, 0.1, 0.3 - 35f64.to_radians());
        let with = align(&map, &pts, guess, &c).unwrap();
        assert!(with.pose.distance(&truth) < 0.01, "{with:?}");
        assert!(wrap_angle(with.pose.theta - truth.theta).abs() < 0.2f64.to_radians());
        let without = IcpConfig {
            rotation_search: 0.0,
            ..c
        };
        let plain = align(&map, &pts, guess, &without);
        assert!(
            plain.is_none_or(|a| a.pose.distance(&truth) > 0.05
                || wrap_angle(a.pose.theta - truth.theta).abs() > 1f64.to_radians()),
            "ICP alone should not reach the truth from 35° off: {plain:?}"
        );
    }

    /// Giving up the headings that cannot beat the guess chooses what scoring every heading
    /// whole chooses: from guesses up to 35° and 0.2 m off, where the search must move the
    /// heading, and near the truth, where it must keep the guess.
    #[test]
    fn giving_up_hopeless_headings_keeps_the_search_s_choice() {
        use rand::{Rng, SeedableRng};
        let c = IcpConfig {
            rotation_search: 40f64.to_radians(),
            ..IcpConfig::default()
        };
        let origin = Pose2::IDENTITY;
        let mut map = PointMap::new(c.voxel, c.max_distance_start);
        map.insert(&origin, &room_points(&origin, &c));
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let mut moved = 0;
        for _ in 0..40 {
            let truth = Pose2::new(
                rng.random_range(-0.5..0.5),
                rng.random_range(-0.5..0.5),
                rng.random_range(-0.5..0.5),
            );
            let pts = room_points(&truth, &c);
            let guess = Pose2::new(
                truth.x + rng.random_range(-0.2..0.2),
                truth.y + rng.random_range(-0.2..0.2),
                truth.theta + rng.random_range(-0.6..0.6),
            );
            let whole = heading_search(&map, &pts, guess, &c, false);
            assert_eq!(heading_search(&map, &pts, guess, &c, true), whole);
            moved += usize::from(whole != guess);
        }
        assert!(moved > 10 && moved < 40, "{moved} of 40 moved");
    }

    #[test]
    fn the_odometry_prior_holds_the_pose_along_a_featureless_corridor() {
        // Two long parallel walls: the scan fixes y and heading, not x.
        let corridor = [([-20.0, 1.0], [20.0, 1.0]), ([-20.0, -1.0], [20.0, -1.0])];
        let c = IcpConfig::default();
        let mut map = PointMap::new(c.voxel, c.max_distance_start);
        let at = |x: f64, y: f64, th: f64| Pose2::new(x, y, th);
        map.insert(
            &at(0.0, 0.0, 0.0),
            &scan_points(
                &scan_of(&corridor, &at(0.0, 0.0, 0.0)),
                &Pose2::IDENTITY,
                &Sweep::STILL,
                30.0,
                &c,
            ),
        );
        let truth = at(0.5, 0.1, 0.02);
        let pts = scan_points(
            &scan_of(&corridor, &truth),
            &Pose2::IDENTITY,
            &Sweep::STILL,
            30.0,
            &c,
        );
        let guess = at(0.45, 0.18, 0.05);
        let a = align(&map, &pts, guess, &c).unwrap();
        assert!((a.pose.y - truth.y).abs() < 0.005, "{a:?}");
        assert!((a.pose.theta - truth.theta).abs() < 0.002, "{a:?}");
        assert!(
            (a.pose.x - guess.x).abs() < 0.005,
            "x stays at the guess: {a:?}"
        );
    }

    #[test]
    fn a_scan_of_few_points_leans_on_the_prior_as_a_sum_over_points_would() {
        // One wall along y = 1 seen from the origin: the fit fixes y alone. With the mean
        // point term, a guess `d` off in y ends at y = w d / (1 + w), w the prior's weight:
        // the plain weight for a dense scan, `prior_points / n` times it for a scan of n.
        let wall = |n: usize| -> Vec<Oriented> {
            (0..n)
                .map(|k| Oriented {
                    p: [-1.65 + 3.3 * k as f64 / (n - 1) as f64, 1.0],
                    n: [0.0, -1.0],
                })
                .collect()
        };
        let c = IcpConfig {
            rotation_search: 0.0,
            ..IcpConfig::default()
        };
        let mut map = PointMap::new(c.voxel, c.max_distance_start);
        map.insert(&Pose2::IDENTITY, &wall(200));
        let d = 0.02;
        let guess = Pose2::new(0.0, d, 0.0);
        for (n, scale) in [(240, 1.0), (12, c.prior_points / 12.0)] {
            let w = scale * c.translation_weight;
            let a = align(&map, &wall(n), guess, &c).unwrap();
            let expected = w * d / (1.0 + w);
            assert!(
                (a.pose.y - expected).abs() < 1e-6,
                "{n} points: {a:?}, expected y {expected}"
            );
            assert!(a.pose.x.abs() < 1e-9 && a.pose.theta.abs() < 1e-9, "{a:?}");
        }
        // Off, every scan keeps the plain weight.
        let off = IcpConfig {
            prior_points: 0.0,
            ..c
        };
        let a = align(&map, &wall(12), guess, &off).unwrap();
        let w = off.translation_weight;
        assert!((a.pose.y - w * d / (1.0 + w)).abs() < 1e-6, "{a:?}");
    }

    /// A 181-beam scan from −90° to 90° in 1° steps, as the SICK LMS of the benchmark logs.
    fn one_degree_scan(ranges: Vec<f32>) -> LaserScan {
        LaserScan {
            frame: "laser".into(),
            stamp: futago_msgs::Time::ZERO,
            angle_min: -90f64.to_radians(),
            angle_increment: 1f64.to_radians(),
            time_increment: 0.0,
            range_min: 0.02,
            range_max: 80.0,
            ranges,
        }
    }

    #[test]
    fn normals_face_the_sensor_and_the_map_keeps_one_point_per_voxel() {
        let pts = scan_points(
            &room_scan(&Pose2::IDENTITY),
            &Pose2::IDENTITY,
            &Sweep::STILL,
            30.0,
            &IcpConfig::default(),
        );
        // Points on the x = 4 wall have normals pointing back along −x.
        let wall: Vec<_> = pts
            .iter()
            .filter(|o| (o.p[0] - 4.0).abs() < 1e-6 && o.p[1].abs() < 1.0)
            .collect();
        assert!(wall.len() > 20);
        for o in wall {
            assert!(o.n[0] < -0.99, "{o:?}");
        }
        let mut map = PointMap::new(0.05, 0.5);
        map.insert(&Pose2::IDENTITY, &pts);
        let n = map.len();
        map.insert(&Pose2::IDENTITY, &pts);
        assert_eq!(map.len(), n, "the same points twice add nothing");
        assert!(map.nearest([4.0, 0.0], 0.05).is_some());
        assert!(map.nearest([3.0, 0.0], 0.2).is_none());
    }

    /// The nearest point is the closest of all the map's points within the distance, found
    /// by reading every point: on a lattice (many at equal distances from lattice queries,
    /// each point tagged by the order it was added in its normal) and scattered points, added
    /// in several batches, queried at every correspondence distance ICP uses, at and across
    /// bucket borders, on both sides of the origin. A tie goes to the point of the first
    /// bucket in (column, row) order, then to the one added first.
    #[test]
    fn the_nearest_is_the_closest_of_all_points_ties_to_the_first() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(48);
        let mut map = PointMap::new(0.03, 0.5);
        let mut serial = 0.0;
        let mut tag = |p: [f64; 2]| {
            serial += 1.0;
            Oriented {
                p,
                n: [serial, 0.0],
            }
        };
        let lattice: Vec<Oriented> = (-30..30)
            .flat_map(|i| (-30..30).map(move |j| [i as f64 * 0.1, j as f64 * 0.1]))
            .filter(|_| rng.random::<f64>() < 0.7)
            .collect::<Vec<_>>()
            .into_iter()
            .map(&mut tag)
            .collect();
        for part in lattice.chunks(500) {
            map.insert(&Pose2::IDENTITY, part);
        }
        let scattered: Vec<Oriented> = (0..3000)
            .map(|_| [rng.random_range(-3.0..3.0), rng.random_range(-3.0..3.0)])
            .collect::<Vec<_>>()
            .into_iter()
            .map(&mut tag)
            .collect();
        for part in scattered.chunks(700) {
            map.insert(&Pose2::new(0.013, -0.021, 0.0), part);
        }
        let all: Vec<Oriented> = map.points().copied().collect();
        let (mut found, mut ties) = (0, 0);
        for k in 0..4000 {
            let q = if k % 2 == 0 {
                // Lattice points and midpoints: equal distances to two or four points.
                [
                    rng.random_range(-60..60) as f64 * 0.05,
                    rng.random_range(-60..60) as f64 * 0.05,
                ]
            } else {
                [rng.random_range(-3.2..3.2), rng.random_range(-3.2..3.2)]
            };
            for max in [0.5, 0.42, 0.2, 0.1, 0.05, 0.01] {
                let d = |o: &Oriented| (o.p[0] - q[0]).powi(2) + (o.p[1] - q[1]).powi(2);
                let within: Vec<&Oriented> = all.iter().filter(|o| d(o) <= max * max).collect();
                let want = within.iter().copied().min_by(|a, b| {
                    let key = |o: &Oriented| PointMap::key(o.p[0], o.p[1], 0.5);
                    d(a).total_cmp(&d(b))
                        .then(key(a).cmp(&key(b)))
                        .then(a.n[0].total_cmp(&b.n[0]))
                });
                assert_eq!(map.nearest(q, max), want, "{q:?} within {max}");
                found += usize::from(want.is_some());
                ties += usize::from(
                    want.is_some_and(|w| within.iter().filter(|o| d(o) == d(w)).count() > 1),
                );
            }
        }
        assert!(found > 10_000 && ties > 100, "{found} found, {ties} ties");
    }

    /// A laser with 1° beams (as the SICK LMS of the benchmark logs) sees a wall 15 m away:
    /// its returns lie 26 cm apart, so that a point's second neighbour is further than
    /// `normal_radius`; yet each keeps its point and a normal facing the sensor.
    #[test]
    fn a_far_wall_seen_by_a_sparse_laser_keeps_its_points() {
        let step = 1f64.to_radians();
        let ranges: Vec<f32> = (-90..=90)
            .map(|k| {
                let a = k as f64 * step;
                let r = 15.0 / a.cos();
                if (r * a.sin()).abs() <= 10.0 {
                    r as f32
                } else {
                    f32::INFINITY
                }
            })
            .collect();
        let scan = one_degree_scan(ranges);
        let c = IcpConfig::default();
        assert!(2.0 * 15.0 * step > c.normal_radius);
        let pts = scan_points(&scan, &Pose2::IDENTITY, &Sweep::STILL, 30.0, &c);
        // The wall spans atan(10/15) = ±33.7°: 67 beams, the two at each end with fewer
        // neighbours on one side.
        assert!(pts.len() >= 60, "{} points", pts.len());
        for o in &pts {
            assert!((o.p[0] - 15.0).abs() < 1e-4, "{o:?}");
            assert!(o.n[0] < -0.99, "{o:?}");
        }
    }

    #[test]
    fn a_scan_with_nothing_in_common_is_refused() {
        let c = IcpConfig::default();
        let mut map = PointMap::new(c.voxel, c.max_distance_start);
        map.insert(&Pose2::IDENTITY, &room_points(&Pose2::IDENTITY, &c));
        let far = Pose2::new(50.0, 50.0, 0.0);
        let pts = room_points(&Pose2::IDENTITY, &c);
        assert!(align(&map, &pts, far, &c).is_none());
    }

    /// A robot that drives an arc at 0.3 m/s and 1 rad/s while its scanner sweeps 270° in
    /// 18.75 ms (a 40 Hz UTM-30LX's pace) bends the room by up to 7 cm at 4 m. Taken back to
    /// the robot's pose at the stamp by the odometry's motion, every point lies on a wall
    /// again; taken as still, they do not.
    #[test]
    fn a_swept_scan_is_taken_back_to_the_pose_at_its_stamp() {
        let (v, w) = (0.3, 1.0);
        let arc = |t: f64| Pose2::new(v / w * (w * t).sin(), v / w * (1.0 - (w * t).cos()), w * t);
        let sweep_time = 0.01875;
        let scan = swept_scan_of(&ROOM, arc, sweep_time / 360.0);
        let c = IcpConfig::default();
        // The odometry's last interval (25 ms) at the same velocity.
        let sweep = Sweep {
            step: arc(0.025),
            over: 0.025,
        };
        let worst = |s: &Sweep| {
            scan_points(&scan, &Pose2::IDENTITY, s, 30.0, &c)
                .iter()
                .map(|o| distance_to(&ROOM, o.p))
                .fold(0.0, f64::max)
        };
        let deskewed = worst(&sweep);
        let still = worst(&Sweep::STILL);
        assert!(
            deskewed < 0.002,
            "deskewed points lie {deskewed} m off the walls"
        );
        assert!(still > 0.03, "raw points lie only {still} m off the walls");
    }
}
