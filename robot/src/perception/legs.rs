//! People's legs in a 2D laser scan, after Arras, Martínez Mozos & Burgard (ICRA 2007): the
//! scan is cut into segments where consecutive points jump apart, each segment is described
//! by geometric features, and a boosted classifier (AdaBoost over decision stumps) says how
//! leg-like it is.
//!
//! - **Segments**: consecutive valid beams whose points lie within `cluster_distance` (0.13 m,
//!   leg_tracker's) of each other, with at least `min_points` (3) points, within `max_range`
//!   (10 m).
//! - **Features** ([`FEATURES`]): Arras et al.'s number of points, standard deviation, mean
//!   average deviation from the median, jump distances to the segments before and after,
//!   width, linearity, circularity, radius, boundary length and regularity, mean curvature
//!   and mean angular difference (their 14th, speed, needs tracking and is left out), and the
//!   segment's range (leg_tracker adds it: a leg far away has fewer points).
//! - **Classifier** ([`AdaBoost`]): discrete AdaBoost (Freund & Schapire) over decision stumps,
//!   trained on labelled segments ([`AdaBoost::train`]); its margin becomes a confidence in
//!   [0, 1] by the logistic link of Friedman, Hastie & Tibshirani (2000).

use crate::config::{ConfigError, check_counts, check_ranges};
use crate::geometry::within;
use futago_msgs::LaserScan;
use serde::{Deserialize, Serialize};

/// Segmentation and detection settings (`people.legs`).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct LegConfig {
    /// Consecutive points further apart than this start a new segment, m.
    pub cluster_distance: f64,
    /// Segments with fewer points are dropped.
    pub min_points: usize,
    /// Beams beyond this are ignored, m.
    pub max_range: f64,
    /// A segment with a confidence at least this is a leg.
    pub threshold: f64,
}

impl Default for LegConfig {
    fn default() -> Self {
        LegConfig {
            cluster_distance: 0.13,
            min_points: 3,
            max_range: 10.0,
            threshold: 0.5,
        }
    }
}

impl LegConfig {
    /// Checks every field; errors name `prefix.field`.
    pub fn validate(&self, prefix: &str) -> Result<(), ConfigError> {
        check_ranges(
            prefix,
            &[
                ("cluster_distance", self.cluster_distance, 0.01, 2.0),
                ("max_range", self.max_range, 0.1, 100.0),
                ("threshold", self.threshold, 0.0, 1.0),
            ],
        )?;
        check_counts(prefix, &[("min_points", self.min_points, 1, 1000)])
    }
}

/// A run of consecutive beams: its points in the laser's frame and the beams it spans.
#[derive(Debug, Clone, PartialEq)]
pub struct Segment {
    /// Index of the first beam.
    pub first: usize,
    pub points: Vec<[f64; 2]>,
    /// Distance from the first point to the last valid point before the segment, and from
    /// the last point to the first valid point after it, m (`max_range` at the scan's ends).
    pub jumps: [f64; 2],
}

impl Segment {
    /// Mean of the points.
    pub fn centroid(&self) -> [f64; 2] {
        let n = self.points.len().max(1) as f64;
        let (sx, sy) = self
            .points
            .iter()
            .fold((0.0, 0.0), |(x, y), p| (x + p[0], y + p[1]));
        [sx / n, sy / n]
    }
}

/// Cuts a scan into segments (see the module documentation).
pub fn segments(scan: &LaserScan, c: &LegConfig) -> Vec<Segment> {
    let max = c.max_range.min(scan.range_max);
    let point = |i: usize| -> Option<[f64; 2]> {
        let r = scan.ranges[i] as f64;
        (r.is_finite() && r >= scan.range_min && r <= max).then(|| {
            let a = scan.angle(i);
            [r * a.cos(), r * a.sin()]
        })
    };
    let dist = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).hypot(a[1] - b[1]);
    let within_of = |a: [f64; 2], b: [f64; 2], r: f64| within(a[0] - b[0], a[1] - b[1], r);
    // Runs of valid consecutive points.
    let mut runs: Vec<(usize, Vec<[f64; 2]>)> = Vec::new();
    let mut current: Option<(usize, Vec<[f64; 2]>)> = None;
    for i in 0..scan.ranges.len() {
        match (point(i), current.as_mut()) {
            (Some(p), Some((_, pts)))
                if within_of(
                    *pts.last().expect("runs are not empty"),
                    p,
                    c.cluster_distance,
                ) =>
            {
                pts.push(p)
            }
            (Some(p), _) => {
                if let Some(r) = current.take() {
                    runs.push(r);
                }
                current = Some((i, vec![p]));
            }
            (None, _) => {
                if let Some(r) = current.take() {
                    runs.push(r);
                }
            }
        }
    }
    runs.extend(current);
    let mut out = Vec::new();
    for (k, (first, points)) in runs.iter().enumerate() {
        if points.len() < c.min_points {
            continue;
        }
        let before = k
            .checked_sub(1)
            .map(|j| dist(*runs[j].1.last().expect("runs are not empty"), points[0]))
            .unwrap_or(max);
        let after = runs
            .get(k + 1)
            .map(|r| dist(*points.last().expect("runs are not empty"), r.1[0]))
            .unwrap_or(max);
        out.push(Segment {
            first: *first,
            points: points.clone(),
            jumps: [before, after],
        });
    }
    out
}

/// Number of features per segment.
pub const FEATURES: usize = 14;

/// The features' names, in order.
pub const FEATURE_NAMES: [&str; FEATURES] = [
    "points",
    "std",
    "mad_median",
    "jump_before",
    "jump_after",
    "width",
    "linearity",
    "circularity",
    "radius",
    "boundary_length",
    "boundary_regularity",
    "mean_curvature",
    "mean_angle_difference",
    "range",
];

/// A segment's features (see the module documentation), in [`FEATURE_NAMES`] order.
pub fn features(s: &Segment) -> [f64; FEATURES] {
    let p = &s.points;
    let n = p.len() as f64;
    let c = s.centroid();
    let d = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).hypot(a[1] - b[1]);
    let std = (p
        .iter()
        .map(|q| (q[0] - c[0]).powi(2) + (q[1] - c[1]).powi(2))
        .sum::<f64>()
        / (n - 1.0).max(1.0))
    .sqrt();
    // Median point: the component-wise median.
    let median = {
        let mut xs: Vec<f64> = p.iter().map(|q| q[0]).collect();
        let mut ys: Vec<f64> = p.iter().map(|q| q[1]).collect();
        xs.sort_by(f64::total_cmp);
        ys.sort_by(f64::total_cmp);
        [xs[xs.len() / 2], ys[ys.len() / 2]]
    };
    let mad = p.iter().map(|q| d(*q, median)).sum::<f64>() / n;
    let width = d(p[0], p[p.len() - 1]);
    // Linearity: squared residuals of the total-least-squares line (the scatter's smaller
    // eigenvalue times n).
    let (sxx, sxy, syy) = p.iter().fold((0.0, 0.0, 0.0), |(a, b, e), q| {
        let (x, y) = (q[0] - c[0], q[1] - c[1]);
        (a + x * x, b + x * y, e + y * y)
    });
    let tr = sxx + syy;
    let det = sxx * syy - sxy * sxy;
    let linearity = (tr / 2.0 - ((tr / 2.0).powi(2) - det).max(0.0).sqrt()).max(0.0);
    let (centre, radius) = fit_circle(p).unwrap_or((c, 0.0));
    let circularity = p
        .iter()
        .map(|q| (radius - d(*q, centre)).powi(2))
        .sum::<f64>();
    let gaps: Vec<f64> = p.windows(2).map(|w| d(w[0], w[1])).collect();
    let boundary = gaps.iter().sum::<f64>();
    let mean_gap = boundary / gaps.len().max(1) as f64;
    let regularity = (gaps.iter().map(|g| (g - mean_gap).powi(2)).sum::<f64>()
        / gaps.len().max(1) as f64)
        .sqrt();
    // Curvature of each triple (Menger: 4·area / product of sides) and the turn between its
    // two edges.
    let (mut curvature, mut turn, mut triples) = (0.0, 0.0, 0.0f64);
    for w in p.windows(3) {
        let (a, b, e) = (d(w[0], w[1]), d(w[1], w[2]), d(w[0], w[2]));
        let area2 = ((w[1][0] - w[0][0]) * (w[2][1] - w[0][1])
            - (w[2][0] - w[0][0]) * (w[1][1] - w[0][1]))
            .abs();
        if a * b * e > 1e-12 {
            curvature += 2.0 * area2 / (a * b * e);
        }
        let u = [w[1][0] - w[0][0], w[1][1] - w[0][1]];
        let v = [w[2][0] - w[1][0], w[2][1] - w[1][1]];
        turn += (u[0] * v[1] - u[1] * v[0])
            .atan2(u[0] * v[0] + u[1] * v[1])
            .abs();
        triples += 1.0;
    }
    let t = triples.max(1.0);
    [
        n,
        std,
        mad,
        s.jumps[0],
        s.jumps[1],
        width,
        linearity,
        circularity,
        radius,
        boundary,
        regularity,
        curvature / t,
        turn / t,
        c[0].hypot(c[1]),
    ]
}

/// The least-squares circle through points (Kåsa's algebraic fit: x² + y² + a·x + b·y + c = 0
/// solved in the least-squares sense): centre and radius, or `None` when the points are too
/// few or collinear.
pub fn fit_circle(p: &[[f64; 2]]) -> Option<([f64; 2], f64)> {
    if p.len() < 3 {
        return None;
    }
    // Centred for conditioning.
    let n = p.len() as f64;
    let (mx, my) = p
        .iter()
        .fold((0.0, 0.0), |(x, y), q| (x + q[0] / n, y + q[1] / n));
    let mut m = nalgebra::Matrix3::<f64>::zeros();
    let mut r = nalgebra::Vector3::<f64>::zeros();
    for q in p {
        let (x, y) = (q[0] - mx, q[1] - my);
        let row = nalgebra::Vector3::new(x, y, 1.0);
        let z = -(x * x + y * y);
        m += row * row.transpose();
        r += row * z;
    }
    let sol = m.lu().solve(&r)?;
    let (a, b, c) = (sol[0], sol[1], sol[2]);
    let r2 = a * a / 4.0 + b * b / 4.0 - c;
    (r2.is_finite() && r2 > 0.0).then(|| ([mx - a / 2.0, my - b / 2.0], r2.sqrt()))
}

/// One weak classifier: `polarity · (x[feature] − threshold) > 0` votes leg, with weight
/// `alpha`.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
pub struct Stump {
    pub feature: usize,
    pub threshold: f64,
    pub polarity: f64,
    pub alpha: f64,
}

/// A boosted classifier of segments: legs against everything else.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
pub struct AdaBoost {
    pub stumps: Vec<Stump>,
}

impl AdaBoost {
    /// Trains `rounds` stumps on `samples` (features) with `labels` (true: leg) by discrete
    /// AdaBoost. Each round picks the feature, threshold and polarity of least weighted error
    /// (thresholds half way between consecutive sorted values), weighs it by
    /// ½·ln((1 − ε)/ε) and re-weighs the samples. Stops early when a stump is perfect or no
    /// better than chance.
    pub fn train(samples: &[[f64; FEATURES]], labels: &[bool], rounds: usize) -> AdaBoost {
        let n = samples.len();
        let mut stumps = Vec::new();
        if n == 0 || labels.len() != n {
            return AdaBoost { stumps };
        }
        let y: Vec<f64> = labels.iter().map(|&l| if l { 1.0 } else { -1.0 }).collect();
        // Uniform weights to start (discrete AdaBoost).
        let mut w = vec![1.0 / n as f64; n];
        // Samples sorted by each feature, once.
        let order: Vec<Vec<usize>> = (0..FEATURES)
            .map(|f| {
                let mut o: Vec<usize> = (0..n).collect();
                o.sort_by(|&a, &b| samples[a][f].total_cmp(&samples[b][f]).then(a.cmp(&b)));
                o
            })
            .collect();
        for _ in 0..rounds {
            let total: f64 = w.iter().sum();
            w.iter_mut().for_each(|x| *x /= total);
            // Weight of the positives and negatives at or below each threshold, swept.
            let (mut best_err, mut best) = (f64::INFINITY, None);
            let wpos: f64 = (0..n).filter(|&i| y[i] > 0.0).map(|i| w[i]).sum();
            let wneg = 1.0 - wpos;
            for (f, o) in order.iter().enumerate() {
                let (mut below_pos, mut below_neg) = (0.0, 0.0);
                for k in 0..n {
                    let i = o[k];
                    if y[i] > 0.0 {
                        below_pos += w[i];
                    } else {
                        below_neg += w[i];
                    }
                    let v = samples[i][f];
                    let next = o.get(k + 1).map(|&j| samples[j][f]);
                    if next == Some(v) {
                        continue;
                    }
                    let threshold = next.map_or(v + 1.0, |nv| 0.5 * (v + nv));
                    // Polarity +1: above the threshold is a leg; errors are the positives
                    // below and the negatives above.
                    let err_plus = below_pos + (wneg - below_neg);
                    let err_minus = below_neg + (wpos - below_pos);
                    for (err, polarity) in [(err_plus, 1.0), (err_minus, -1.0)] {
                        if err < best_err {
                            best_err = err;
                            best = Some((f, threshold, polarity));
                        }
                    }
                }
            }
            let Some((feature, threshold, polarity)) = best else {
                break;
            };
            if best_err >= 0.5 {
                break;
            }
            let e = best_err.max(1e-10);
            let alpha = 0.5 * ((1.0 - e) / e).ln();
            let stump = Stump {
                feature,
                threshold,
                polarity,
                alpha,
            };
            for i in 0..n {
                w[i] *= (-alpha * y[i] * stump.vote(&samples[i])).exp();
            }
            stumps.push(stump);
            if best_err < 1e-10 {
                break;
            }
        }
        AdaBoost { stumps }
    }

    /// The weighted vote Σ αₜ·hₜ(x), normalised by Σ αₜ: in [−1, 1], positive for a leg.
    pub fn margin(&self, x: &[f64; FEATURES]) -> f64 {
        let total: f64 = self.stumps.iter().map(|s| s.alpha).sum();
        if total <= 0.0 {
            return 0.0;
        }
        self.stumps.iter().map(|s| s.alpha * s.vote(x)).sum::<f64>() / total
    }

    /// The probability that `x` is a leg: the logistic link 1/(1 + e^(−2F)) of the
    /// unnormalised vote F (Friedman, Hastie & Tibshirani 2000).
    pub fn confidence(&self, x: &[f64; FEATURES]) -> f64 {
        let f: f64 = self.stumps.iter().map(|s| s.alpha * s.vote(x)).sum();
        1.0 / (1.0 + (-2.0 * f).exp())
    }

    /// Checks a model read from a file: features in range, finite numbers.
    pub fn validate(&self) -> Result<(), String> {
        if self.stumps.is_empty() {
            return Err("the model has no stumps".into());
        }
        for (k, s) in self.stumps.iter().enumerate() {
            if s.feature >= FEATURES
                || !(s.threshold.is_finite() && s.alpha.is_finite() && s.alpha >= 0.0)
                || s.polarity.abs() != 1.0
            {
                return Err(format!(
                    "stump {k}: expected a feature below {FEATURES}, a finite threshold, polarity ±1 and a finite weight ≥ 0, found {s:?}"
                ));
            }
        }
        Ok(())
    }
}

impl Stump {
    /// +1 (leg) or −1.
    pub fn vote(&self, x: &[f64; FEATURES]) -> f64 {
        if self.polarity * (x[self.feature] - self.threshold) > 0.0 {
            1.0
        } else {
            -1.0
        }
    }
}

/// A leg seen in a scan: where (laser frame) and how sure.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Leg {
    pub position: [f64; 2],
    pub confidence: f64,
}

/// The segments of `scan` that `model` takes for legs, at their centroids.
pub fn detect(scan: &LaserScan, c: &LegConfig, model: &AdaBoost) -> Vec<Leg> {
    segments(scan, c)
        .iter()
        .filter_map(|s| {
            let confidence = model.confidence(&features(s));
            (confidence >= c.threshold).then(|| Leg {
                position: s.centroid(),
                confidence,
            })
        })
        .collect()
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use futago_msgs::Time;

    /// A scan of 0.5° beams over ±90° that sees circles and a wall (a line at x = `wall`).
    pub(crate) fn scan(circles: &[([f64; 2], f64)], wall: f64) -> LaserScan {
        let inc = 0.5f64.to_radians();
        let n = 361;
        let ranges = (0..n)
            .map(|i| {
                let a = -std::f64::consts::FRAC_PI_2 + i as f64 * inc;
                let (dx, dy) = (a.cos(), a.sin());
                let mut r = if dx > 1e-9 { wall / dx } else { f64::INFINITY };
                for (c, rad) in circles {
                    let b = -(c[0] * dx + c[1] * dy);
                    let disc = b * b - (c[0] * c[0] + c[1] * c[1] - rad * rad);
                    if disc >= 0.0 {
                        let t = -b - disc.sqrt();
                        if t > 0.0 {
                            r = r.min(t);
                        }
                    }
                }
                r as f32
            })
            .collect();
        LaserScan {
            frame: "laser".into(),
            stamp: Time::ZERO,
            angle_min: -std::f64::consts::FRAC_PI_2,
            angle_increment: inc,
            time_increment: 0.0,
            range_min: 0.02,
            range_max: 30.0,
            ranges,
        }
    }

    #[test]
    fn a_circle_fit_recovers_a_legs_centre_and_radius() {
        let p: Vec<[f64; 2]> = (0..7)
            .map(|k| {
                let a = 2.5 + 0.2 * k as f64;
                [1.5 + 0.06 * a.cos(), -0.4 + 0.06 * a.sin()]
            })
            .collect();
        let (c, r) = fit_circle(&p).unwrap();
        assert!(
            (c[0] - 1.5).abs() < 1e-9 && (c[1] + 0.4).abs() < 1e-9,
            "{c:?}"
        );
        assert!((r - 0.06).abs() < 1e-9, "{r}");
        assert!(fit_circle(&[[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]]).is_none());
    }

    #[test]
    fn two_legs_before_a_wall_are_segments_of_their_own_with_their_geometry() {
        // Legs of 6 cm radius at 2 m, 0.2 m apart, before a wall at 4 m.
        let s = scan(&[([2.0, 0.1], 0.06), ([2.0, -0.1], 0.06)], 4.0);
        let segs = segments(&s, &LegConfig::default());
        // The wall (within the 10 m range) is split by the legs' shadows into three runs,
        // one between them; with the two legs, five.
        assert_eq!(segs.len(), 5, "{segs:?}");
        let legs: Vec<&Segment> = segs.iter().filter(|g| g.centroid()[0] < 3.0).collect();
        assert_eq!(legs.len(), 2);
        for g in legs {
            let f = features(g);
            let (c, r) = fit_circle(&g.points).unwrap();
            // Points on a 6 cm circle: the fit finds it, and the features say so.
            assert!((r - 0.06).abs() < 1e-6, "{r}");
            assert!((f[8] - r).abs() < 1e-12);
            assert!(f[7] < 1e-9, "circularity {}", f[7]);
            assert!((c[0] - 2.0).abs() < 1e-6);
            // Seen from 2 m, a 6 cm leg shows about its front third: a width under 0.12 m,
            // and it stands 2 m before a wall 4 m away: jumps of about 2 m.
            assert!(f[5] > 0.03 && f[5] < 0.12, "width {}", f[5]);
            assert!(f[3] > 1.5 && f[4] > 1.5, "jumps {:?}", &f[3..5]);
            assert!((f[13] - 2.0).abs() < 0.1, "range {}", f[13]);
        }
    }

    #[test]
    fn adaboost_learns_a_threshold_and_votes_by_it() {
        // A single informative feature (width): legs are narrower than 0.2 m.
        let mut samples = Vec::new();
        let mut labels = Vec::new();
        for k in 0..200 {
            let mut x = [0.0; FEATURES];
            x[5] = k as f64 * 0.005; // 0 … 1 m
            x[0] = (k % 7) as f64; // noise
            samples.push(x);
            labels.push(x[5] < 0.2);
        }
        let model = AdaBoost::train(&samples, &labels, 10);
        model.validate().unwrap();
        // One stump separates them: it sits between 0.195 and 0.2.
        assert_eq!(model.stumps.len(), 1, "{model:?}");
        let s = model.stumps[0];
        assert_eq!(s.feature, 5);
        assert!(s.threshold > 0.195 && s.threshold < 0.2, "{s:?}");
        let mut leg = [0.0; FEATURES];
        leg[5] = 0.1;
        let mut wall = [0.0; FEATURES];
        wall[5] = 0.8;
        assert!(model.confidence(&leg) > 0.99 && model.confidence(&wall) < 0.01);
        assert_eq!(model.margin(&leg), 1.0);
    }
}
