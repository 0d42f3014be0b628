//! A laser's error model from a log: each beam's reading against the range the map predicts
//! from the reference pose, and the beam model mixture fitted to them by expectation
//! maximisation (Thrun, Burgard and Fox, *Probabilistic Robotics*, 2005, §6.3, Table 6.2).
//!
//! The expected range is cast through an occupancy grid of the log's own scans at the
//! reference poses ([`cast`]): it is the middle of the beam's chord through the first occupied
//! cell, so the cell's extent adds the variance of a uniform error over that chord
//! (`chord²/12`), which is taken off the hit's spread. The map holds what the log saw, people
//! and doors included: the residuals are those of a map made from the same scans, as a
//! robot's own map is.

use crate::ground_truth::trajectory::Stats;
use futago_msgs::LaserScan;
use futago_msgs::Pose2;
use futago_msgs::profile::{Bin, Estimate, LaserProfile};
use futago_robot::mapping::occupancy::OccupancyMap;

/// Cells more likely occupied than this (log-odds of p = 0.65, map_server's threshold) stop a
/// cast.
const OCCUPIED: f32 = 0.619_039_2;

/// A cast that crosses more than this many unobserved cells in a row has no expected range.
const MAX_UNKNOWN_RUN: usize = 3;

/// Neighbours' expected ranges further apart than this (m) make a depth edge.
pub const EDGE_STEP: f64 = 0.5;

/// A reading at a depth edge counts as a mixed pixel when it lies between the near and the
/// far surface by more than this (m) from both.
pub const EDGE_MARGIN: f64 = 0.1;

/// Bin edges of the expected range (m) and of the incidence angle (degrees).
const RANGE_EDGES: [f64; 12] = [
    0.0, 0.5, 1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0, 24.0, 32.0,
];
const INCIDENCE_EDGES_DEG: [f64; 7] = [0.0, 15.0, 30.0, 45.0, 60.0, 75.0, 90.0];

/// Rounds of expectation maximisation.
const EM_ROUNDS: usize = 100;

/// What a cast from a pose finds along a beam.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Cast {
    /// An occupied cell: the middle of the beam's chord through it and the chord's length,
    /// m, and the cell.
    Hit {
        range: f64,
        chord: f64,
        cell: [i64; 2],
    },
    /// Free cells all the way to the range limit.
    Free,
    /// A run of unobserved cells first: the map cannot say.
    Unknown,
}

/// Casts a beam from `(x, y)` at bearing `a` through `map` (cells of side `res`) up to `max`,
/// visiting every cell the beam crosses (Amanatides and Woo's traversal); the cell it starts
/// in is skipped (the laser sits in it).
pub fn cast(map: &OccupancyMap, res: f64, x: f64, y: f64, a: f64, max: f64) -> Cast {
    let (c, s) = (a.cos(), a.sin());
    let mut cell = [(x / res).floor() as i64, (y / res).floor() as i64];
    let step = [if c >= 0.0 { 1 } else { -1 }, if s >= 0.0 { 1 } else { -1 }];
    let next_edge = |i: i64, dir: i64| (i + i64::from(dir > 0)) as f64 * res;
    let mut t_max = [
        if c.abs() < 1e-12 {
            f64::INFINITY
        } else {
            (next_edge(cell[0], step[0]) - x) / c
        },
        if s.abs() < 1e-12 {
            f64::INFINITY
        } else {
            (next_edge(cell[1], step[1]) - y) / s
        },
    ];
    let t_delta = [res / c.abs().max(1e-12), res / s.abs().max(1e-12)];
    let mut unknown = 0;
    loop {
        // Step into the next cell; `enter` is where the beam enters it.
        let axis = if t_max[0] < t_max[1] { 0 } else { 1 };
        let enter = t_max[axis];
        if enter > max {
            return Cast::Free;
        }
        cell[axis] += step[axis];
        t_max[axis] += t_delta[axis];
        let centre = [(cell[0] as f64 + 0.5) * res, (cell[1] as f64 + 0.5) * res];
        let l = map.logodds_at(centre[0], centre[1]);
        if l > OCCUPIED {
            let exit = t_max[0].min(t_max[1]);
            return Cast::Hit {
                range: 0.5 * (enter + exit),
                chord: exit - enter,
                cell,
            };
        }
        if l == 0.0 {
            unknown += 1;
            if unknown > MAX_UNKNOWN_RUN {
                return Cast::Unknown;
            }
        } else {
            unknown = 0;
        }
    }
}

/// The angle between a beam of bearing `a` and the normal of the occupied cells around
/// `cell` (their principal axes), rad in [0, π/2]; `None` where they do not form a line.
fn incidence(map: &OccupancyMap, res: f64, cell: [i64; 2], a: f64) -> Option<f64> {
    let mut pts = Vec::with_capacity(25);
    for dj in -2..=2 {
        for di in -2..=2 {
            let (i, j) = (cell[0] + di, cell[1] + dj);
            let (x, y) = ((i as f64 + 0.5) * res, (j as f64 + 0.5) * res);
            if map.logodds_at(x, y) > OCCUPIED {
                pts.push([x, y]);
            }
        }
    }
    if pts.len() < 3 {
        return None;
    }
    let n = pts.len() as f64;
    let (mx, my) = (
        pts.iter().map(|p| p[0]).sum::<f64>() / n,
        pts.iter().map(|p| p[1]).sum::<f64>() / n,
    );
    let (mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0);
    for p in &pts {
        let (dx, dy) = (p[0] - mx, p[1] - my);
        sxx += dx * dx;
        syy += dy * dy;
        sxy += dx * dy;
    }
    let tr = sxx + syy;
    let disc = ((sxx - syy).powi(2) + 4.0 * sxy * sxy).sqrt();
    let (big, small) = (0.5 * (tr + disc), 0.5 * (tr - disc));
    if big <= 0.0 || small > 0.1 * big {
        return None;
    }
    // The line's direction is the big axis; the normal is across it.
    let along = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    let normal = along + std::f64::consts::FRAC_PI_2;
    let cos = (normal - a).cos().abs();
    Some(cos.clamp(0.0, 1.0).acos())
}

/// A returned reading where the map predicts a surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reading {
    pub measured: f64,
    pub expected: f64,
    pub chord: f64,
}

/// Counts of what the beams did, before the mixture is fitted.
#[derive(Debug, Default, Clone)]
pub struct Tally {
    pub readings: Vec<Reading>,
    /// Beams expected to hit, by range bin and by incidence bin: (no return, all).
    pub by_range: Vec<(usize, usize)>,
    pub by_incidence: Vec<(usize, usize)>,
    pub no_return: (usize, usize),
    /// Depth edges: (with a reading between the surfaces, all).
    pub edges: (usize, usize),
    /// Beams where the map holds nothing within range: (returned, all).
    pub unmapped: (usize, usize),
    /// Range residuals of neighbouring beams on one surface, in pairs (see
    /// [`LaserProfile::neighbour_correlation`]).
    pub neighbours: Vec<(f64, f64)>,
}

fn bin_of(edges: &[f64], v: f64) -> Option<usize> {
    (v >= edges[0])
        .then(|| edges.partition_point(|e| *e <= v).saturating_sub(1))
        .filter(|&k| k + 1 < edges.len())
}

/// Whether a reading is a return within the laser's limits.
fn returned(r: f64, scan: &LaserScan) -> bool {
    r.is_finite() && r >= scan.range_min && r <= scan.range_max && r > 0.0
}

impl Tally {
    pub fn new() -> Tally {
        Tally {
            by_range: vec![(0, 0); RANGE_EDGES.len() - 1],
            by_incidence: vec![(0, 0); INCIDENCE_EDGES_DEG.len() - 1],
            ..Default::default()
        }
    }

    /// Adds one scan taken from `laser` (the laser's pose in the map frame).
    pub fn add(&mut self, map: &OccupancyMap, res: f64, laser: &Pose2, scan: &LaserScan) {
        let casts: Vec<Cast> = (0..scan.ranges.len())
            .map(|k| {
                cast(
                    map,
                    res,
                    laser.x,
                    laser.y,
                    laser.theta + scan.angle(k),
                    scan.range_max,
                )
            })
            .collect();
        for (k, (&r, cast)) in scan.ranges.iter().zip(&casts).enumerate() {
            let r = r as f64;
            // Readings below the minimum range are the laser's "too close", not a miss.
            if r == f64::NEG_INFINITY || (r.is_finite() && r < scan.range_min) {
                continue;
            }
            let back = returned(r, scan);
            match *cast {
                Cast::Unknown => {}
                Cast::Free => {
                    self.unmapped.1 += 1;
                    self.unmapped.0 += usize::from(back);
                }
                Cast::Hit { range, chord, cell } => {
                    if range > scan.range_max {
                        continue;
                    }
                    let miss = usize::from(!back);
                    self.no_return.0 += miss;
                    self.no_return.1 += 1;
                    if let Some(b) = bin_of(&RANGE_EDGES, range) {
                        self.by_range[b].0 += miss;
                        self.by_range[b].1 += 1;
                    }
                    let a = laser.theta + scan.angle(k);
                    if let Some(b) = incidence(map, res, cell, a)
                        .and_then(|i| bin_of(&INCIDENCE_EDGES_DEG, i.to_degrees()))
                    {
                        self.by_incidence[b].0 += miss;
                        self.by_incidence[b].1 += 1;
                    }
                    if back {
                        self.readings.push(Reading {
                            measured: r,
                            expected: range,
                            chord,
                        });
                    }
                }
            }
        }
        // Depth edges: neighbouring beams whose expected ranges jump.
        for k in 1..casts.len() {
            let (Cast::Hit { range: a, .. }, Cast::Hit { range: b, .. }) = (casts[k - 1], casts[k])
            else {
                continue;
            };
            if (a - b).abs() <= EDGE_STEP {
                continue;
            }
            let (near, far) = (a.min(b), a.max(b));
            let between = [k - 1, k].iter().any(|&i| {
                let r = scan.ranges[i] as f64;
                returned(r, scan) && r > near + EDGE_MARGIN && r < far - EDGE_MARGIN
            });
            self.edges.0 += usize::from(between);
            self.edges.1 += 1;
        }
        self.add_neighbours(&casts, scan);
    }

    /// The residual pairs of neighbouring beams that hit one surface.
    fn add_neighbours(&mut self, casts: &[Cast], scan: &LaserScan) {
        use futago_msgs::profile::{NEIGHBOUR_CORE_M, NEIGHBOUR_STEP_M};
        let residual = |k: usize, range: f64| {
            let r = scan.ranges[k] as f64;
            (returned(r, scan) && (r - range).abs() <= NEIGHBOUR_CORE_M).then_some(r - range)
        };
        for k in 1..casts.len() {
            let (Cast::Hit { range: a, .. }, Cast::Hit { range: b, .. }) = (casts[k - 1], casts[k])
            else {
                continue;
            };
            if (a - b).abs() > NEIGHBOUR_STEP_M {
                continue;
            }
            if let (Some(x), Some(y)) = (residual(k - 1, a), residual(k, b)) {
                self.neighbours.push((x, y));
            }
        }
    }
}

/// The correlation of residual pairs, with Fisher's standard error `(1 − ρ²)/√(n − 3)` (the
/// pairs taken as independent, which neighbours along a scan are not quite: a lower bound).
pub fn pair_correlation(pairs: &[(f64, f64)]) -> Estimate {
    let n = pairs.len();
    if n < 4 {
        return Estimate::new(0.0, 0.0, n);
    }
    let m = n as f64;
    let (mx, my) = pairs
        .iter()
        .fold((0.0, 0.0), |(a, b), (x, y)| (a + x / m, b + y / m));
    let (mut xy, mut xx, mut yy) = (0.0, 0.0, 0.0);
    for (x, y) in pairs {
        xy += (x - mx) * (y - my);
        xx += (x - mx).powi(2);
        yy += (y - my).powi(2);
    }
    let r = if xx > 0.0 && yy > 0.0 {
        xy / (xx * yy).sqrt()
    } else {
        0.0
    };
    Estimate::new(r, (1.0 - r * r) / (m - 3.0).sqrt(), n)
}

/// The beam model mixture fitted to the returned readings.
#[derive(Debug, Clone, PartialEq)]
pub struct Mixture {
    /// Shares of hit, short and random readings.
    pub weights: [f64; 3],
    pub bias: f64,
    pub short_lambda: f64,
    /// The hit's spread per range bin (raw: cells included) and the bin's hit count and mean
    /// squared chord.
    pub spread: Vec<(f64, f64, f64)>,
}

/// Expectation maximisation of the beam model over `readings` (Thrun et al. 2005, Table 6.2),
/// with the hit's spread per range bin; `range_max` bounds the random readings.
pub fn fit_mixture(readings: &[Reading], range_max: f64) -> Mixture {
    let bins = RANGE_EDGES.len() - 1;
    let bin: Vec<usize> = readings
        .iter()
        .map(|r| bin_of(&RANGE_EDGES, r.expected).unwrap_or(bins - 1))
        .collect();
    let mut m = Mixture {
        weights: [0.9, 0.05, 0.05],
        bias: 0.0,
        short_lambda: 1.0,
        spread: vec![(0.05, 0.0, 0.0); bins],
    };
    let uniform = 1.0 / range_max.max(1e-3);
    let mut resp = vec![[0.0f64; 3]; readings.len()];
    for _ in 0..EM_ROUNDS {
        for ((r, b), out) in readings.iter().zip(&bin).zip(resp.iter_mut()) {
            let sigma = m.spread[*b].0.max(1e-4);
            let e = r.measured - r.expected - m.bias;
            let hit =
                (-0.5 * (e / sigma).powi(2)).exp() / (sigma * (2.0 * std::f64::consts::PI).sqrt());
            let lambda = m.short_lambda;
            let short = if r.measured <= r.expected {
                lambda * (-lambda * r.measured).exp()
                    / (1.0 - (-lambda * r.expected).exp()).max(1e-12)
            } else {
                0.0
            };
            let p = [
                m.weights[0] * hit,
                m.weights[1] * short,
                m.weights[2] * uniform,
            ];
            let total = p[0] + p[1] + p[2];
            *out = if total > 0.0 {
                [p[0] / total, p[1] / total, p[2] / total]
            } else {
                [0.0, 0.0, 1.0]
            };
        }
        let n = readings.len().max(1) as f64;
        let sums = resp
            .iter()
            .fold([0.0; 3], |a, r| [a[0] + r[0], a[1] + r[1], a[2] + r[2]]);
        m.weights = [sums[0] / n, sums[1] / n, sums[2] / n];
        let hit_w = sums[0].max(1e-12);
        m.bias = readings
            .iter()
            .zip(&resp)
            .map(|(r, w)| w[0] * (r.measured - r.expected))
            .sum::<f64>()
            / hit_w;
        let short_z: f64 = readings
            .iter()
            .zip(&resp)
            .map(|(r, w)| w[1] * r.measured)
            .sum();
        if sums[1] > 1e-9 && short_z > 0.0 {
            m.short_lambda = (sums[1] / short_z).min(1e3);
        }
        let mut acc = vec![(0.0, 0.0, 0.0); bins];
        for ((r, b), w) in readings.iter().zip(&bin).zip(&resp) {
            let e = r.measured - r.expected - m.bias;
            acc[*b].0 += w[0] * e * e;
            acc[*b].1 += w[0];
            acc[*b].2 += w[0] * r.chord * r.chord;
        }
        for (s, a) in m.spread.iter_mut().zip(&acc) {
            if a.1 > 1.0 {
                *s = ((a.0 / a.1).sqrt(), a.1, a.2 / a.1);
            } else {
                *s = (s.0, a.1, 0.0);
            }
        }
    }
    m
}

/// `σ(r)² = a² + (b·r)²` fitted to the bins' spreads net of their cells (weighted by their
/// hit counts, both terms kept non-negative): `a`, `b` and their standard errors, and the
/// net spread per bin.
fn fit_spread(m: &Mixture) -> ([Estimate; 2], Vec<Bin>) {
    let mut bins = Vec::new();
    let mut rows = Vec::new();
    for (k, &(s, n, chord2)) in m.spread.iter().enumerate() {
        if n < 10.0 {
            continue;
        }
        let net2 = (s * s - chord2 / 12.0).max(0.0);
        let (lo, hi) = (RANGE_EDGES[k], RANGE_EDGES[k + 1]);
        let sd = net2.sqrt() / (2.0 * n).sqrt();
        bins.push(Bin {
            lo,
            hi,
            value: net2.sqrt(),
            sd,
            n: n as usize,
        });
        rows.push((0.5 * (lo + hi), net2, n));
    }
    let total: usize = bins.iter().map(|b| b.n).sum();
    if rows.is_empty() {
        return (
            [Estimate::new(0.0, 0.0, 0), Estimate::new(0.0, 0.0, 0)],
            bins,
        );
    }
    // Weighted least squares of σ² on [1, r²], with the slope dropped if it comes out
    // negative (and the intercept if that does).
    let solve = |cols: &[usize]| -> Option<Vec<f64>> {
        let f = |r: f64, c: usize| if c == 0 { 1.0 } else { r * r };
        let k = cols.len();
        let mut a = nalgebra::DMatrix::<f64>::zeros(k, k);
        let mut g = nalgebra::DVector::<f64>::zeros(k);
        for &(r, y, w) in &rows {
            for i in 0..k {
                g[i] += w * f(r, cols[i]) * y;
                for j in 0..k {
                    a[(i, j)] += w * f(r, cols[i]) * f(r, cols[j]);
                }
            }
        }
        let x = a.try_inverse()? * g;
        Some(x.iter().copied().collect())
    };
    let (a2, b2) = match solve(&[0, 1]) {
        Some(x) if x[0] >= 0.0 && x[1] >= 0.0 => (x[0], x[1]),
        Some(x) if x[1] < 0.0 => (solve(&[0]).map_or(0.0, |v| v[0].max(0.0)), 0.0),
        _ => (0.0, solve(&[1]).map_or(0.0, |v| v[0].max(0.0))),
    };
    let a = a2.sqrt();
    let b = b2.sqrt();
    // Standard errors: from the bins' spread errors, nearest and farthest bins for a and b.
    let near = bins.first().map_or(0.0, |x| x.sd);
    let far = bins
        .last()
        .map_or(0.0, |x| x.sd / (0.5 * (x.lo + x.hi)).max(1e-3));
    (
        [Estimate::new(a, near, total), Estimate::new(b, far, total)],
        bins,
    )
}

fn bins_of(edges: &[f64], counts: &[(usize, usize)], scale: f64) -> Vec<Bin> {
    counts
        .iter()
        .enumerate()
        .filter(|(_, c)| c.1 > 0)
        .map(|(k, &(miss, all))| {
            let e = Estimate::proportion(miss, all);
            Bin {
                lo: edges[k] * scale,
                hi: edges[k + 1] * scale,
                value: e.value,
                sd: e.sd,
                n: all,
            }
        })
        .collect()
}

/// How far beyond their surface the long readings lie (more than
/// [`futago_msgs::profile::LONG_READING_M`]), m: quantiles 0, 1/N, …, 1 by linear interpolation
/// between order statistics (N = [`futago_msgs::profile::LONG_EXCESS_QUANTILES`]); empty with
/// fewer than N long readings, too few to say.
pub fn long_excess(readings: &[Reading]) -> Vec<f64> {
    use futago_msgs::profile::{LONG_EXCESS_QUANTILES as N, LONG_READING_M};
    let excess: Vec<f64> = readings
        .iter()
        .map(|r| r.measured - r.expected)
        .filter(|e| *e > LONG_READING_M)
        .collect();
    if excess.len() < N {
        return Vec::new();
    }
    (0..=N)
        .filter_map(|i| Stats::percentile(&excess, 100.0 * i as f64 / N as f64))
        .collect()
}

/// The laser profile of a tally: the mixture fitted to it over `layout` (a profile whose
/// layout and timing are set); `None` with fewer than 100 readings where the map predicts a
/// surface.
pub fn error_model(t: &Tally, layout: LaserProfile) -> Option<LaserProfile> {
    if t.readings.len() < 100 {
        return None;
    }
    let m = fit_mixture(&t.readings, layout.range_max);
    let n = t.readings.len();
    let share = |w: f64| Estimate::new(w, (w * (1.0 - w) / n as f64).sqrt(), n);
    let hits = (m.weights[0] * n as f64).max(1.0);
    let shorts = m.weights[1] * n as f64;
    let hit_sd: f64 = m.spread.iter().map(|s| s.0).fold(0.0, f64::max);
    let ([sigma, sigma_rel], spread_by_range) = fit_spread(&m);
    Some(LaserProfile {
        sigma,
        sigma_rel,
        bias: Estimate::new(m.bias, hit_sd / hits.sqrt(), hits as usize),
        short_rate: share(m.weights[1]),
        short_lambda: Estimate::new(
            m.short_lambda,
            m.short_lambda / shorts.max(1.0).sqrt(),
            shorts as usize,
        ),
        random_rate: share(m.weights[2]),
        long_readings: Estimate::proportion(
            t.readings
                .iter()
                .filter(|r| r.measured - r.expected > futago_msgs::profile::LONG_READING_M)
                .count(),
            n,
        ),
        no_return: Estimate::proportion(t.no_return.0, t.no_return.1),
        no_return_by_range: bins_of(&RANGE_EDGES, &t.by_range, 1.0),
        no_return_by_incidence: bins_of(
            &INCIDENCE_EDGES_DEG,
            &t.by_incidence,
            std::f64::consts::PI / 180.0,
        ),
        long_excess_m: long_excess(&t.readings),
        mixed_pixels: Estimate::proportion(t.edges.0, t.edges.1),
        unmapped_returns: Estimate::proportion(t.unmapped.0, t.unmapped.1),
        neighbour_correlation: pair_correlation(&t.neighbours),
        spread_by_range,
        ..layout
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use futago_robot::mapping::occupancy::OccupancyConfig;
    use rand::{Rng, SeedableRng};

    #[test]
    fn neighbour_correlation_is_one_for_a_shared_error_and_near_zero_for_independent_ones() {
        let shared: Vec<(f64, f64)> = (0..50)
            .map(|k| (k as f64 * 0.001, k as f64 * 0.002))
            .collect();
        assert!((pair_correlation(&shared).value - 1.0).abs() < 1e-12);
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        let independent: Vec<(f64, f64)> = (0..10_000)
            .map(|_| (rng.random::<f64>() - 0.5, rng.random::<f64>() - 0.5))
            .collect();
        let e = pair_correlation(&independent);
        // Fisher's standard error of ρ = 0 over 10,000 pairs: 1/√9997 = 0.01.
        assert!((e.sd - 0.01).abs() < 1e-4, "{e:?}");
        assert!(e.value.abs() < 4.0 * e.sd, "{e:?}");
    }
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    const WALL: f64 = 2.02;

    /// A map of one wall along x = 2.02 m (inside a cell's width), built from scans of it from
    /// the origin.
    fn wall_map() -> OccupancyMap {
        let mut map = OccupancyMap::new(OccupancyConfig::default());
        let scan = wall_scan(&[]);
        for _ in 0..5 {
            map.insert(&Pose2::IDENTITY, &scan);
        }
        map
    }

    /// 91 beams over ±45° at the wall x = 2.02 from the origin; `ranges` overrides them.
    fn wall_scan(ranges: &[f32]) -> LaserScan {
        let angle_min = -std::f64::consts::FRAC_PI_4;
        let inc = std::f64::consts::FRAC_PI_2 / 90.0;
        LaserScan {
            frame: "front".into(),
            stamp: futago_msgs::Time::ZERO,
            angle_min,
            angle_increment: inc,
            time_increment: 0.0,
            range_min: 0.05,
            range_max: 10.0,
            ranges: if ranges.is_empty() {
                (0..91)
                    .map(|k| (WALL / (angle_min + k as f64 * inc).cos()) as f32)
                    .collect()
            } else {
                ranges.to_vec()
            },
        }
    }

    #[test]
    fn a_cast_ends_within_a_cell_of_the_wall() {
        let map = wall_map();
        for a in [-0.6f64, -0.2, 0.0, 0.3, 0.7] {
            let truth = WALL / a.cos();
            let Cast::Hit { range, chord, .. } = cast(&map, 0.05, 0.0, 0.0, a, 10.0) else {
                panic!("bearing {a}: no hit");
            };
            // The first occupied cell along the beam holds the wall ([2.0, 2.05) in x), but the
            // beam may clip its corner and cross the wall in the next one: the chord's middle
            // is within a cell's diagonal of the crossing.
            assert!(chord > 0.0 && chord <= 0.05 * 2f64.sqrt() + 1e-9, "{chord}");
            assert!(
                (range - truth).abs() <= 0.05 * 2f64.sqrt(),
                "{a}: {range} vs {truth}"
            );
        }
        assert_eq!(
            cast(&map, 0.05, 0.0, 0.0, std::f64::consts::PI, 10.0),
            Cast::Unknown
        );
    }

    #[test]
    fn long_excess_quantiles_follow_the_long_readings_alone() {
        let reading = |measured: f64| Reading {
            measured,
            expected: 2.0,
            chord: 0.05,
        };
        // Hits and short readings, then long readings 1.5 to 3.5 m beyond the surface.
        let mut readings: Vec<Reading> = (0..500)
            .map(|i| reading(1.9 + 0.2 * (i % 2) as f64))
            .collect();
        readings.extend((0..=200).map(|i| reading(2.0 + 1.5 + 2.0 * i as f64 / 200.0)));
        let q = long_excess(&readings);
        assert_eq!(q.len(), futago_msgs::profile::LONG_EXCESS_QUANTILES + 1);
        assert!((q[0] - 1.5).abs() < 1e-9 && (q[q.len() - 1] - 3.5).abs() < 1e-9);
        assert!((q[q.len() / 2] - 2.5).abs() < 1e-9, "{q:?}");
        assert!(q.windows(2).all(|w| w[0] <= w[1]));
        // Too few long readings to say.
        assert!(long_excess(&readings[..510]).is_empty());
    }

    #[test]
    fn the_mixture_recovers_its_shares_and_spread() {
        // 20,000 readings at 1–9 m: 85 % hits with σ = 2 cm, 10 % short (λ = 1.5: people
        // and clutter near the laser), 5 % random over 10 m.
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let hit = Normal::new(0.0, 0.02).unwrap();
        let readings: Vec<Reading> = (0..20000)
            .map(|_| {
                let expected: f64 = rng.random_range(1.0..9.0);
                let u: f64 = rng.random();
                let measured = if u < 0.85 {
                    expected + hit.sample(&mut rng)
                } else if u < 0.95 {
                    // Exponential truncated at the expected range, by inversion.
                    let q: f64 = rng.random();
                    -(1.0 - q * (1.0 - (-1.5 * expected).exp())).ln() / 1.5
                } else {
                    rng.random_range(0.0..10.0)
                };
                Reading {
                    measured,
                    expected,
                    chord: 0.0,
                }
            })
            .collect();
        let m = fit_mixture(&readings, 10.0);
        assert!((m.weights[0] - 0.85).abs() < 0.02, "{m:?}");
        assert!((m.weights[1] - 0.10).abs() < 0.02, "{m:?}");
        assert!((m.weights[2] - 0.05).abs() < 0.02, "{m:?}");
        assert!((m.short_lambda - 1.5).abs() < 0.15, "{m:?}");
        for &(s, n, _) in &m.spread {
            if n > 500.0 {
                assert!((s - 0.02).abs() < 0.003, "{m:?}");
            }
        }
        let ([a, b], _) = fit_spread(&m);
        assert!(
            (a.value - 0.02).abs() < 0.003 && b.value < 0.002,
            "{a:?} {b:?}"
        );
    }

    #[test]
    fn a_tally_counts_misses_short_readings_and_mixed_pixels() {
        let map = wall_map();
        let mut ranges = wall_scan(&[]).ranges;
        // Beam 10: no return; beam 20: a reading 1 m short.
        ranges[10] = f32::INFINITY;
        ranges[20] -= 1.0;
        let mut t = Tally::new();
        t.add(&map, 0.05, &Pose2::IDENTITY, &wall_scan(&ranges));
        assert_eq!(t.no_return, (1, 91));
        assert_eq!(t.readings.len(), 90);
        let short = t
            .readings
            .iter()
            .filter(|r| r.measured < r.expected - 0.5)
            .count();
        assert_eq!(short, 1);
        assert_eq!(t.edges, (0, 0), "one wall has no depth edge");
    }
}
