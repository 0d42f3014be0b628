//! Odometry's error model from a log: reported motion against a reference trajectory (the
//! SLAM's), over stretches of about a metre or half a radian.
//!
//! The systematic terms are Borenstein's UMBmark errors written as what they do to the
//! reported motion (a translation scale, a rotation scale and a heading bias per metre), found
//! by robust Gauss–Newton: each stretch's reported steps are rescaled and composed, and the
//! result is compared with the reference's motion over the same stretch. The random terms are
//! a random walk: the squared residuals are regressed on the stretch's length and turn, with
//! an intercept that takes up the reference's own error (a scan match's, the same for a short
//! stretch as for a long one), so that the matcher's noise is not charged to the odometry.
//! Stretches missed by more than [`OUTLIER_SIGMAS`] deviations are outliers (stalls, slips):
//! they are left out of the fit and counted.

use futago_msgs::profile::{Estimate, OdometryProfile};
use futago_msgs::{Outside, Pose2, Time, pose_at, wrap_angle};
use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

/// A stretch ends when the reported path reaches this length (m) or its turns this sum (rad),
/// times one of [`SCALES`].
pub const STRETCH_M: f64 = 1.0;
pub const STRETCH_RAD: f64 = 0.5;

/// The stretches are cut at these multiples of [`STRETCH_M`] and [`STRETCH_RAD`], so that
/// their lengths differ: with one length only, a variance that grows with the distance could
/// not be told from the reference's own, which is the same for every stretch. Each scan
/// serves once per scale, so standard errors are widened by √(number of scales).
pub const SCALES: [f64; 4] = [0.5, 1.0, 2.0, 4.0];

/// A stretch is dropped where two scans are further apart in time than this many median
/// intervals: a gap in the log, over which nothing is known.
const GAP_INTERVALS: f64 = 10.0;

/// A stretch missed by more than this many deviations of the model is an outlier.
pub const OUTLIER_SIGMAS: f64 = 5.0;

/// Fewest stretches a fit is made on.
pub const MIN_STRETCHES: usize = 10;

/// Shifts searched for the odometry's latency, s, and their step.
const LATENCY_REACH_S: f64 = 0.5;
const LATENCY_STEP_S: f64 = 0.005;

/// Residuals beyond this (rad) count as this much in the latency search: a stall must not
/// decide the shift.
const LATENCY_TRUNCATION: f64 = 0.05;

/// One scan: its stamp, the odometry pose reported at it and the reference pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    pub stamp: Time,
    pub odometry: Pose2,
    pub reference: Pose2,
}

/// A stretch of consecutive scans: the reported steps and the reference's motion over it.
#[derive(Debug, Clone, PartialEq)]
struct Stretch {
    steps: Vec<Pose2>,
    reference: Pose2,
    length: f64,
    turn: f64,
    /// The sum of the steps' turns' magnitudes, rad.
    turned: f64,
}

/// The systematic parameters: translation scale, rotation scale, heading bias (rad/m).
type Params = [f64; 3];

/// The reported steps rescaled by `p` and composed.
fn predict(steps: &[Pose2], p: &Params) -> Pose2 {
    steps.iter().fold(Pose2::IDENTITY, |acc, s| {
        let d = s.x.hypot(s.y);
        acc.compose(&Pose2::new(
            p[0] * s.x,
            p[0] * s.y,
            p[1] * s.theta + p[2] * d,
        ))
    })
}

/// Stretches of the samples at `scale` (see [`STRETCH_M`]); a stretch across a gap is
/// dropped.
fn stretches(samples: &[Sample], scale: f64) -> Vec<Stretch> {
    let mut intervals: Vec<f64> = samples
        .windows(2)
        .map(|w| (w[1].stamp - w[0].stamp).secs())
        .collect();
    if intervals.is_empty() {
        return Vec::new();
    }
    let mid = intervals.len() / 2;
    let median = *intervals.select_nth_unstable_by(mid, f64::total_cmp).1;
    let gap = GAP_INTERVALS * median.max(1e-6);
    let mut out = Vec::new();
    let mut start = 0;
    let (mut length, mut turn, mut turned) = (0.0, 0.0, 0.0);
    let mut steps = Vec::new();
    for k in 1..samples.len() {
        let (a, b) = (&samples[k - 1], &samples[k]);
        if (b.stamp - a.stamp).secs() > gap {
            start = k;
            (length, turn, turned) = (0.0, 0.0, 0.0);
            steps.clear();
            continue;
        }
        let s = a.odometry.between(&b.odometry);
        length += s.x.hypot(s.y);
        turn += s.theta;
        turned += s.theta.abs();
        steps.push(s);
        if length >= scale * STRETCH_M || turned >= scale * STRETCH_RAD {
            out.push(Stretch {
                steps: std::mem::take(&mut steps),
                reference: samples[start].reference.between(&b.reference),
                length,
                turn,
                turned,
            });
            start = k;
            (length, turn, turned) = (0.0, 0.0, 0.0);
        }
    }
    out
}

/// The residual of a stretch under `p`: along the predicted chord, across it (m) and in
/// heading (rad).
fn residual(s: &Stretch, p: &Params) -> [f64; 3] {
    let q = predict(&s.steps, p);
    let (ex, ey) = (s.reference.x - q.x, s.reference.y - q.y);
    let chord = q.x.hypot(q.y);
    let (along, across) = if chord > 1e-6 {
        let (ux, uy) = (q.x / chord, q.y / chord);
        (ex * ux + ey * uy, -ex * uy + ey * ux)
    } else {
        (ex, ey)
    };
    [along, across, wrap_angle(s.reference.theta - q.theta)]
}

/// The random-walk model's variances for a stretch: along the path and in heading.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Noise {
    /// Translation: per metre, and the reference's own (m²).
    translation: [f64; 2],
    /// Heading: per radian turned, per metre, and the reference's own (rad²).
    heading: [f64; 3],
}

impl Noise {
    fn variances(&self, s: &Stretch) -> (f64, f64) {
        let t = self.translation[0] * s.length + self.translation[1];
        let h = self.heading[0] * s.turn.abs() + self.heading[1] * s.length + self.heading[2];
        (t.max(1e-10), h.max(1e-12))
    }
}

/// Weighted Gauss–Newton for the systematic parameters over the inlier stretches, from `p`.
/// Returns the parameters and their covariance.
fn fit_systematic(
    all: &[Stretch],
    inlier: &[bool],
    noise: &Noise,
    mut p: Params,
) -> (Params, Matrix3<f64>) {
    let mut cov = Matrix3::zeros();
    for _ in 0..20 {
        let mut h = Matrix3::<f64>::zeros();
        let mut g = Vector3::<f64>::zeros();
        for (s, _) in all.iter().zip(inlier).filter(|(_, i)| **i) {
            let (vt, vh) = noise.variances(s);
            // Across the path, the heading's random walk adds up: a heading error growing
            // linearly in variance along a path of length L moves its end sideways by a
            // variance of L²·vh/3.
            let vc = vt + s.length * s.length * vh / 3.0;
            let w = [1.0 / vt, 1.0 / vc, 1.0 / vh];
            let r0 = residual(s, &p);
            let mut jac = [[0.0; 3]; 3];
            for (k, col) in [1e-6, 1e-6, 1e-7].into_iter().enumerate() {
                let mut q = p;
                q[k] += col;
                let r = residual(s, &q);
                for i in 0..3 {
                    // d(residual)/dp: the residual falls as the prediction rises.
                    jac[i][k] = (r[i] - r0[i]) / col;
                }
            }
            for i in 0..3 {
                let j = Vector3::new(jac[i][0], jac[i][1], jac[i][2]);
                h += w[i] * j * j.transpose();
                g += w[i] * j * r0[i];
            }
        }
        let Some(inv) = h.try_inverse() else {
            break;
        };
        let d = -inv * g;
        p = [p[0] + d[0], p[1] + d[1], p[2] + d[2]];
        cov = inv;
        if d.norm() < 1e-10 {
            break;
        }
    }
    (p, cov)
}

/// Least squares of `y` on the columns of `x` with every coefficient kept non-negative (the
/// columns whose coefficient would be negative are dropped in turn); the coefficients and
/// their standard errors.
fn non_negative_fit(x: &DMatrix<f64>, y: &DVector<f64>) -> (Vec<f64>, Vec<f64>) {
    let cols = x.ncols();
    let mut active: Vec<usize> = (0..cols).collect();
    loop {
        let xa = DMatrix::from_fn(x.nrows(), active.len(), |r, c| x[(r, active[c])]);
        let xtx = xa.transpose() * &xa;
        let Some(inv) = xtx.try_inverse() else {
            return (vec![0.0; cols], vec![0.0; cols]);
        };
        let beta = &inv * xa.transpose() * y;
        if let Some(neg) = (0..active.len()).find(|&k| beta[k] < 0.0) {
            active.remove(neg);
            if active.is_empty() {
                return (vec![0.0; cols], vec![0.0; cols]);
            }
            continue;
        }
        let resid = y - &xa * &beta;
        let dof = (x.nrows() as f64 - active.len() as f64).max(1.0);
        let s2 = resid.norm_squared() / dof;
        let (mut b, mut se) = (vec![0.0; cols], vec![0.0; cols]);
        for (k, &c) in active.iter().enumerate() {
            b[c] = beta[k];
            se[c] = (s2 * inv[(k, k)]).max(0.0).sqrt();
        }
        return (b, se);
    }
}

/// Regresses the inliers' squared residuals on the random walk's terms.
fn fit_noise(all: &[Stretch], inlier: &[bool], p: &Params) -> (Noise, Noise) {
    let used: Vec<&Stretch> = all
        .iter()
        .zip(inlier)
        .filter(|(_, i)| **i)
        .map(|(s, _)| s)
        .collect();
    let n = used.len();
    let r: Vec<[f64; 3]> = used.iter().map(|s| residual(s, p)).collect();
    let xt = DMatrix::from_fn(n, 2, |i, c| if c == 0 { used[i].length } else { 1.0 });
    let yt = DVector::from_fn(n, |i, _| r[i][0] * r[i][0]);
    let xh = DMatrix::from_fn(n, 3, |i, c| match c {
        0 => used[i].turn.abs(),
        1 => used[i].length,
        _ => 1.0,
    });
    let yh = DVector::from_fn(n, |i, _| r[i][2] * r[i][2]);
    let (bt, st) = non_negative_fit(&xt, &yt);
    let (bh, sh) = non_negative_fit(&xh, &yh);
    (
        Noise {
            translation: [bt[0], bt[1]],
            heading: [bh[0], bh[1], bh[2]],
        },
        Noise {
            translation: [st[0], st[1]],
            heading: [sh[0], sh[1], sh[2]],
        },
    )
}

/// The odometry's error model over `samples` (consecutive scans of one log, in order);
/// `odometry` is the log's timed odometry records, for the latency (none: not estimated).
/// `None` when the samples hold fewer than [`MIN_STRETCHES`] stretches.
pub fn calibrate(samples: &[Sample], odometry: &[(Time, Pose2)]) -> Option<OdometryProfile> {
    let all: Vec<Stretch> = SCALES.iter().flat_map(|&k| stretches(samples, k)).collect();
    if all.len() < MIN_STRETCHES {
        return None;
    }
    let n = all.len();
    let mut inlier = vec![true; n];
    // A start that charges everything to the random walk, at a scan matcher's precision.
    let mut noise = Noise {
        translation: [1e-3, 1e-4],
        heading: [1e-3, 1e-3, 1e-4],
    };
    let mut spread = noise;
    let mut p: Params = [1.0, 1.0, 0.0];
    let mut cov = Matrix3::zeros();
    for _ in 0..10 {
        (p, cov) = fit_systematic(&all, &inlier, &noise, [1.0, 1.0, 0.0]);
        (noise, spread) = fit_noise(&all, &inlier, &p);
        // Residuals in the model's deviations, and their robust spread (1.4826 × the median
        // absolute value): outliers inflate the model's variances, not the median, so the
        // test stays sharp while they are still in the fit.
        let z: Vec<[f64; 2]> = all
            .iter()
            .map(|s| {
                let r = residual(s, &p);
                let (vt, vh) = noise.variances(s);
                [r[0].abs() / vt.sqrt(), r[2].abs() / vh.sqrt()]
            })
            .collect();
        let robust = |k: usize| {
            let mut v: Vec<f64> = z.iter().map(|z| z[k]).collect();
            let mid = v.len() / 2;
            1.4826 * *v.select_nth_unstable_by(mid, f64::total_cmp).1
        };
        let (st, sh) = (robust(0), robust(1));
        let next: Vec<bool> = z
            .iter()
            .map(|z| z[0] <= OUTLIER_SIGMAS * st && z[1] <= OUTLIER_SIGMAS * sh)
            .collect();
        if next == inlier || next.iter().filter(|i| **i).count() < MIN_STRETCHES {
            break;
        }
        inlier = next;
    }
    let used = inlier.iter().filter(|i| **i).count();
    let outliers = n - used;
    // The Gauss–Newton covariance assumes the variances are right; scale it by how far the
    // weighted residuals are from that.
    let chi2: f64 = all
        .iter()
        .zip(&inlier)
        .filter(|(_, i)| **i)
        .map(|(s, _)| {
            let r = residual(s, &p);
            let (vt, vh) = noise.variances(s);
            let vc = vt + s.length * s.length * vh / 3.0;
            r[0] * r[0] / vt + r[1] * r[1] / vc + r[2] * r[2] / vh
        })
        .sum();
    let scale = (chi2 / (3.0 * used as f64 - 3.0).max(1.0)).max(1.0);
    let reuse = (SCALES.len() as f64).sqrt();
    let se = |k: usize| (cov[(k, k)] * scale).max(0.0).sqrt() * reuse;
    let latency = latency(samples, odometry, p[1]);
    // The outliers' own spread (root mean square of their residuals beyond the random walk's
    // share): what a stall or a slip does, for a simulator to draw from.
    let (mut sum_t, mut sum_h) = (0.0, 0.0);
    for (s, _) in all.iter().zip(&inlier).filter(|(_, i)| !**i) {
        let r = residual(s, &p);
        let (vt, vh) = noise.variances(s);
        sum_t += (r[0] * r[0] + r[1] * r[1] - vt).max(0.0);
        sum_h += (r[2] * r[2] - vh).max(0.0);
    }
    let spread_of = |sum: f64| {
        if outliers == 0 {
            Estimate::new(0.0, 0.0, 0)
        } else {
            let v = (sum / outliers as f64).sqrt();
            Estimate::new(v, v / (2.0 * outliers as f64).sqrt(), outliers)
        }
    };
    Some(OdometryProfile {
        translation_scale: Estimate::new(p[0], se(0), used),
        rotation_scale: Estimate::new(p[1], se(1), used),
        heading_bias: Estimate::new(p[2], se(2), used),
        translation_variance: Estimate::new(
            noise.translation[0],
            spread.translation[0] * reuse,
            used,
        ),
        heading_variance_per_rad: Estimate::new(noise.heading[0], spread.heading[0] * reuse, used),
        heading_variance_per_m: Estimate::new(noise.heading[1], spread.heading[1] * reuse, used),
        outlier_rate: Estimate::proportion(outliers, n),
        outlier_translation: spread_of(sum_t),
        outlier_heading: spread_of(sum_h),
        stretches: n,
        stretch_length_m: all.iter().map(|s| s.length).sum::<f64>() / n as f64,
        stretch_turn_rad: all.iter().map(|s| s.turned).sum::<f64>() / n as f64,
        latency,
    })
}

/// The odometry's latency behind the scans: the shift `d` (within ±[`LATENCY_REACH_S`]) for
/// which the odometry read at each scan's stamp plus `d` turns, scan to scan, as the
/// reference does (times `rotation_scale`), in a truncated least-squares sense; refined by a
/// parabola through the best shift and its neighbours, with the standard error that the
/// cost's curvature gives. Not estimated (0 of 0) without timed odometry.
fn latency(samples: &[Sample], odometry: &[(Time, Pose2)], rotation_scale: f64) -> Estimate {
    if odometry.len() < 2 || samples.len() < 3 {
        return Estimate::new(0.0, 0.0, 0);
    }
    let cost = |d: f64| -> (f64, usize) {
        let shift = Time::from_secs(d);
        let mut prev: Option<(Pose2, Pose2)> = None;
        let (mut sum, mut n) = (0.0, 0);
        for s in samples {
            let Some(o) = pose_at(odometry, Time(s.stamp.0 + shift.0), Outside::None) else {
                prev = None;
                continue;
            };
            if let Some((po, pr)) = prev {
                let turn_o = wrap_angle(o.theta - po.theta) * rotation_scale;
                let turn_r = wrap_angle(s.reference.theta - pr.theta);
                let e = wrap_angle(turn_r - turn_o).abs().min(LATENCY_TRUNCATION);
                sum += e * e;
                n += 1;
            }
            prev = Some((o, s.reference));
        }
        (sum, n)
    };
    let steps = (LATENCY_REACH_S / LATENCY_STEP_S).round() as i64;
    let costs: Vec<(f64, f64, usize)> = (-steps..=steps)
        .map(|k| {
            let d = k as f64 * LATENCY_STEP_S;
            let (c, n) = cost(d);
            (d, c, n)
        })
        .collect();
    let Some(best) = (0..costs.len())
        .filter(|&k| costs[k].2 > 0)
        .min_by(|&a, &b| costs[a].1.total_cmp(&costs[b].1))
    else {
        return Estimate::new(0.0, 0.0, 0);
    };
    let (d, c, n) = costs[best];
    if best == 0 || best + 1 == costs.len() {
        return Estimate::new(d, LATENCY_REACH_S, n);
    }
    let (cl, cr) = (costs[best - 1].1, costs[best + 1].1);
    let curvature = (cl - 2.0 * c + cr) / (LATENCY_STEP_S * LATENCY_STEP_S);
    if curvature <= 0.0 {
        return Estimate::new(d, LATENCY_STEP_S, n);
    }
    let offset = (0.5 * (cl - cr) / (cl - 2.0 * c + cr) * LATENCY_STEP_S)
        .clamp(-LATENCY_STEP_S, LATENCY_STEP_S);
    // The cost is a sum of squares of residuals with variance c / n: its curvature at the
    // minimum is 2/var(d) times that variance.
    let variance = 2.0 * (c / n.max(1) as f64) / curvature;
    Estimate::new(d + offset, variance.sqrt().max(1e-4), n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    /// A drive of `n` scans, 0.1 s apart, over gentle arcs and turns on the spot; the truth's
    /// steps are the reported ones with the errors of `p` and random walks of variances
    /// `q_t` (m²/m) and `q_r` (rad²/rad), and the reference is the truth plus a scan
    /// matcher's error of `matcher` (m and rad).
    fn drive(n: usize, p: Params, q_t: f64, q_r: f64, matcher: f64, seed: u64) -> Vec<Sample> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let unit = Normal::new(0.0, 1.0).unwrap();
        let (mut odo, mut truth) = (Pose2::IDENTITY, Pose2::IDENTITY);
        let mut out = Vec::new();
        for k in 0..n {
            let phase = (k / 150) % 3;
            let (v, w) = match phase {
                0 => (0.05, 0.02),
                1 => (0.03, -0.08),
                _ => (0.0, 0.15),
            };
            let step = Pose2::new(v, 0.0, w);
            let d = step.x.abs();
            let true_step = Pose2::new(
                p[0] * step.x + (q_t * d).sqrt() * unit.sample(&mut rng),
                0.0,
                p[1] * step.theta
                    + p[2] * d
                    + (q_r * step.theta.abs()).sqrt() * unit.sample(&mut rng),
            );
            odo = odo.compose(&step);
            truth = truth.compose(&true_step);
            let reference = truth.compose(&Pose2::new(
                matcher * unit.sample(&mut rng),
                matcher * unit.sample(&mut rng),
                matcher * unit.sample(&mut rng),
            ));
            out.push(Sample {
                stamp: Time::from_secs(k as f64 * 0.1),
                odometry: odo,
                reference,
            });
        }
        out
    }

    #[test]
    fn systematic_errors_are_recovered_within_their_standard_errors() {
        let truth = [1.03, 0.95, 0.02];
        let samples = drive(6000, truth, 1e-4, 4e-4, 0.002, 1);
        let p = calibrate(&samples, &[]).expect("enough stretches");
        for (e, t, name) in [
            (p.translation_scale, truth[0], "translation scale"),
            (p.rotation_scale, truth[1], "rotation scale"),
            (p.heading_bias, truth[2], "heading bias"),
        ] {
            assert!(e.sd > 0.0 && e.sd < 0.01, "{name}: {e:?}");
            assert!((e.value - t).abs() < 4.0 * e.sd, "{name}: {e:?}, truth {t}");
        }
        assert_eq!(p.latency.n, 0, "no timed odometry: no latency");
    }

    #[test]
    fn the_random_walk_is_told_apart_from_the_matchers_error() {
        // Heading variance 4e-4 rad²/rad on the turns; the matcher's 2 mrad per pose adds
        // 8e-6 rad² to every stretch whatever its turn, which the intercept must take.
        let samples = drive(20000, [1.0, 1.0, 0.0], 1e-4, 4e-4, 0.002, 2);
        let p = calibrate(&samples, &[]).expect("enough stretches");
        let h = p.heading_variance_per_rad;
        assert!((h.value - 4e-4).abs() < 4.0 * h.sd.max(2e-5), "{h:?}");
        let t = p.translation_variance;
        assert!((t.value - 1e-4).abs() < 4.0 * t.sd.max(1e-5), "{t:?}");
        assert!(p.outlier_rate.value < 0.01, "{:?}", p.outlier_rate);
    }

    #[test]
    fn stalls_are_outliers_not_noise() {
        let mut samples = drive(6000, [1.0, 1.0, 0.0], 1e-5, 1e-5, 0.001, 3);
        // Every 200th scan, the odometry jumps 0.3 rad (a wheel that slipped, a stall caught
        // up wrongly) where the reference did not turn.
        for k in (100..samples.len()).step_by(200) {
            let jump = Pose2::new(0.0, 0.0, 0.3);
            for s in &mut samples[k..] {
                s.odometry = jump.compose(&s.odometry);
            }
        }
        let p = calibrate(&samples, &[]).expect("enough stretches");
        assert!(p.outlier_rate.value > 0.02, "{:?}", p.outlier_rate);
        assert!(
            (p.rotation_scale.value - 1.0).abs() < 0.01,
            "the stalls must not bend the scale: {:?}",
            p.rotation_scale
        );
    }

    #[test]
    fn a_late_odometry_stamp_is_found() {
        let samples = drive(3000, [1.0, 1.0, 0.0], 0.0, 0.0, 0.0005, 4);
        // The odometry as a 50 Hz stream stamped 0.12 s late.
        let late = 0.12;
        let timed: Vec<(Time, Pose2)> = (0..15000)
            .map(|k| {
                let t = Time::from_secs(k as f64 * 0.02);
                let at = pose_at(
                    &samples
                        .iter()
                        .map(|s| (s.stamp, s.odometry))
                        .collect::<Vec<_>>(),
                    t,
                    Outside::Clamp,
                )
                .unwrap();
                (Time::from_secs(k as f64 * 0.02 + late), at)
            })
            .collect();
        let p = calibrate(&samples, &timed).expect("enough stretches");
        assert!(
            (p.latency.value - late).abs() < 0.01,
            "{:?}, truth {late}",
            p.latency
        );
    }
}
