//! Trajectory metrics in the conventions of `evo` (Grupp, github.com/MichaelGrupp/evo), written
//! for futago: association by nearest timestamps, absolute trajectory error (evo's APE on the
//! translation part) with optional alignment, and relative pose error over a number of poses or
//! a travelled distance, with evo's statistics.

use futago_msgs::tum::Stamped;
use nalgebra::{Isometry3, Matrix3, Quaternion, Translation3, UnitQuaternion, Vector3};

/// evo's statistics of a set of errors.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Stats {
    pub rmse: f64,
    pub mean: f64,
    pub median: f64,
    /// Population standard deviation (numpy's default).
    pub std: f64,
    pub min: f64,
    pub max: f64,
    pub sse: f64,
    pub count: usize,
}

impl Stats {
    /// `None` for an empty set.
    pub fn of(errors: &[f64]) -> Option<Stats> {
        if errors.is_empty() {
            return None;
        }
        let n = errors.len() as f64;
        let sse: f64 = errors.iter().map(|e| e * e).sum();
        let mean = errors.iter().sum::<f64>() / n;
        let var = errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / n;
        let mut sorted = errors.to_vec();
        sorted.sort_by(f64::total_cmp);
        let m = sorted.len();
        let median = if m % 2 == 1 {
            sorted[m / 2]
        } else {
            0.5 * (sorted[m / 2 - 1] + sorted[m / 2])
        };
        Some(Stats {
            rmse: (sse / n).sqrt(),
            mean,
            median,
            std: var.sqrt(),
            min: sorted[0],
            max: sorted[m - 1],
            sse,
            count: m,
        })
    }

    /// The `p`-th percentile (0–100) by linear interpolation between order statistics
    /// (numpy's default).
    pub fn percentile(errors: &[f64], p: f64) -> Option<f64> {
        if errors.is_empty() {
            return None;
        }
        let mut s = errors.to_vec();
        s.sort_by(f64::total_cmp);
        let x = p / 100.0 * (s.len() - 1) as f64;
        let (lo, hi) = (x.floor() as usize, x.ceil() as usize);
        Some(s[lo] + (x - lo as f64) * (s[hi] - s[lo]))
    }
}

/// How the estimate is aligned to the reference before ATE.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize, serde::Serialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Alignment {
    /// None: in simulation the map frame is known (the default).
    #[default]
    None,
    /// A rotation about z and a translation in x–y (planar robots).
    Se2,
    /// Umeyama's least-squares rigid transform (evo's `--align`).
    Se3,
}

/// A stamp in seconds exactly as reading its TUM text gives it (the nearest double to the
/// decimal), so that pairing at the `max_diff` boundary agrees with evo's.
pub fn seconds(p: &Stamped) -> f64 {
    p.stamp.nanos() as f64 / 1e9
}

fn iso(p: &Stamped) -> Isometry3<f64> {
    let [x, y, z] = p.pose.translation;
    let [qx, qy, qz, qw] = p.pose.rotation;
    Isometry3::from_parts(
        Translation3::new(x, y, z),
        UnitQuaternion::from_quaternion(Quaternion::new(qw, qx, qy, qz)),
    )
}

/// Pairs poses of `reference` and `estimate` with the nearest stamp within `max_diff` s, as
/// evo's `associate_trajectories`: the trajectory with fewer poses (the estimate on a tie)
/// keeps each of its poses that finds a partner. Both must be sorted by time.
pub fn associate(
    reference: &[Stamped],
    estimate: &[Stamped],
    max_diff: f64,
) -> Vec<(Isometry3<f64>, Isometry3<f64>)> {
    associate_indices(reference, estimate, max_diff)
        .into_iter()
        .map(|(r, e)| (iso(&reference[r]), iso(&estimate[e])))
        .collect()
}

/// The pairing of [`associate`], as (reference index, estimate index), in time order.
pub fn associate_indices(
    reference: &[Stamped],
    estimate: &[Stamped],
    max_diff: f64,
) -> Vec<(usize, usize)> {
    let estimate_longer = estimate.len() > reference.len();
    let (short, long) = if estimate_longer {
        (reference, estimate)
    } else {
        (estimate, reference)
    };
    let stamps: Vec<f64> = long.iter().map(seconds).collect();
    let mut pairs = Vec::new();
    if stamps.is_empty() {
        return pairs;
    }
    for (i, s) in short.iter().enumerate() {
        let t = seconds(s);
        if t < stamps[0] - max_diff || t > stamps[stamps.len() - 1] + max_diff {
            continue;
        }
        // numpy's searchsorted(side="right"), clamped.
        let mut k = stamps.partition_point(|&x| x <= t);
        if k >= stamps.len() {
            k = stamps.len() - 1;
        }
        let ub = stamps[k] - t;
        let lb = if k > 0 {
            t - stamps[k - 1]
        } else {
            f64::INFINITY
        };
        let best = if ub <= max_diff && ub < lb {
            k
        } else if lb <= max_diff && lb <= ub {
            k - 1
        } else {
            continue;
        };
        pairs.push(if estimate_longer {
            (i, best)
        } else {
            (best, i)
        });
    }
    pairs
}

/// The transform that best maps the estimate's positions onto the reference's.
pub fn align(pairs: &[(Isometry3<f64>, Isometry3<f64>)], how: Alignment) -> Isometry3<f64> {
    let n = pairs.len() as f64;
    if how == Alignment::None || pairs.len() < 2 {
        return Isometry3::identity();
    }
    let planar = how == Alignment::Se2;
    let pick = |v: Vector3<f64>| {
        if planar {
            Vector3::new(v.x, v.y, 0.0)
        } else {
            v
        }
    };
    let mu_r = pairs
        .iter()
        .map(|p| pick(p.0.translation.vector))
        .sum::<Vector3<f64>>()
        / n;
    let mu_e = pairs
        .iter()
        .map(|p| pick(p.1.translation.vector))
        .sum::<Vector3<f64>>()
        / n;
    let rotation = if planar {
        // Closed form of the planar Procrustes problem.
        let (mut s, mut c) = (0.0, 0.0);
        for (r, e) in pairs {
            let a = pick(e.translation.vector) - mu_e;
            let b = pick(r.translation.vector) - mu_r;
            c += a.x * b.x + a.y * b.y;
            s += a.x * b.y - a.y * b.x;
        }
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), s.atan2(c))
    } else {
        // Umeyama 1991: R = U S Vᵀ of the cross-covariance, with the reflection fixed.
        let mut sigma = Matrix3::zeros();
        for (r, e) in pairs {
            sigma += (r.translation.vector - mu_r) * (e.translation.vector - mu_e).transpose();
        }
        sigma /= n;
        let svd = sigma.svd(true, true);
        let (u, vt) = (svd.u.unwrap(), svd.v_t.unwrap());
        let mut s = Matrix3::identity();
        if u.determinant() * vt.determinant() < 0.0 {
            s[(2, 2)] = -1.0;
        }
        UnitQuaternion::from_matrix(&(u * s * vt))
    };
    let t = mu_r - rotation * mu_e;
    let mut out = Isometry3::from_parts(Translation3::from(t), rotation);
    if planar {
        // Keep z untouched.
        out.translation.vector.z = 0.0;
    }
    out
}

/// Absolute trajectory error: the distance between aligned estimated and reference positions.
pub fn ate(pairs: &[(Isometry3<f64>, Isometry3<f64>)], how: Alignment) -> Vec<f64> {
    let t = align(pairs, how);
    pairs
        .iter()
        .map(|(r, e)| ((t * e).translation.vector - r.translation.vector).norm())
        .collect()
}

/// What separates the two poses of a relative-error pair.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Delta {
    /// This much travel of the estimate (evo `--delta D --delta_unit m`, whose pairs come
    /// from the estimate's path unless `--pairs_from_reference`).
    Metres(f64),
}

/// Relative pose error over consecutive pairs `delta` apart (evo's RPE without `--all_pairs`;
/// `Q` the reference, `P` the estimate):
/// per pair, the translation (m) and rotation angle (rad) of `(Qᵢ⁻¹Qⱼ)⁻¹(Pᵢ⁻¹Pⱼ)`.
pub fn rpe(pairs: &[(Isometry3<f64>, Isometry3<f64>)], delta: Delta) -> (Vec<f64>, Vec<f64>) {
    let ids: Vec<usize> = match delta {
        Delta::Metres(d) => {
            let mut ids = Vec::new();
            if !pairs.is_empty() {
                ids.push(0);
                let mut path = 0.0;
                for i in 1..pairs.len() {
                    path +=
                        (pairs[i].1.translation.vector - pairs[i - 1].1.translation.vector).norm();
                    if path >= d {
                        ids.push(i);
                        path = 0.0;
                    }
                }
            }
            ids
        }
    };
    let mut trans = Vec::new();
    let mut rot = Vec::new();
    for w in ids.windows(2) {
        let (i, j) = (w[0], w[1]);
        let q = pairs[i].0.inverse() * pairs[j].0;
        let p = pairs[i].1.inverse() * pairs[j].1;
        let e = q.inverse() * p;
        trans.push(e.translation.vector.norm());
        rot.push(e.rotation.angle());
    }
    (trans, rot)
}

/// A localiser has recovered from a kidnapping when its position error is below this, m…
pub const RECOVERED_M: f64 = 0.3;
/// …and stays so for this long, s.
pub const RECOVERED_HOLD_S: f64 = 5.0;

/// Seconds from each event time until the position error (`errors`: time s, error m, in time
/// order) fell below [`RECOVERED_M`] and stayed there for [`RECOVERED_HOLD_S`] (`None`: never,
/// or not for long enough before the run ended).
pub fn recovery_times(errors: &[(f64, f64)], events: &[f64]) -> Vec<Option<f64>> {
    events
        .iter()
        .map(|&t0| {
            let after: Vec<&(f64, f64)> = errors.iter().filter(|e| e.0 >= t0).collect();
            (0..after.len())
                .find(|&k| {
                    after[k].1 < RECOVERED_M
                        && after[k..]
                            .iter()
                            .take_while(|e| e.0 <= after[k].0 + RECOVERED_HOLD_S)
                            .all(|e| e.1 < RECOVERED_M)
                        && after
                            .last()
                            .is_some_and(|e| e.0 >= after[k].0 + RECOVERED_HOLD_S)
                })
                .map(|k| after[k].0 - t0)
        })
        .collect()
}

/// The worst recovery over `events`; one not recovered by `end` counts the rest of the run (a
/// lower bound).
pub fn worst_recovery(errors: &[(f64, f64)], events: &[f64], end: f64) -> f64 {
    events
        .iter()
        .zip(recovery_times(errors, events))
        .map(|(t, r)| r.unwrap_or(end - t))
        .fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;
    use futago_msgs::{Pose2, Pose3, Time};

    fn st(t: f64, x: f64, y: f64, yaw: f64) -> Stamped {
        Stamped {
            stamp: Time::from_secs(t),
            pose: Pose3::from_pose2(&Pose2::new(x, y, yaw), 0.0),
        }
    }

    #[test]
    fn stats_match_a_hand_computation() {
        let s = Stats::of(&[1.0, 2.0, 3.0, 6.0]).unwrap();
        assert_eq!(
            (s.mean, s.median, s.min, s.max, s.sse),
            (3.0, 2.5, 1.0, 6.0, 50.0)
        );
        assert!((s.rmse - 12.5f64.sqrt()).abs() < 1e-12);
        assert!((s.std - 3.5f64.sqrt()).abs() < 1e-12); // (4+1+0+9)/4
        assert_eq!(Stats::percentile(&[1.0, 2.0, 3.0, 6.0], 50.0), Some(2.5));
        assert_eq!(Stats::percentile(&[0.0, 10.0], 95.0), Some(9.5));
        assert!(Stats::of(&[]).is_none());
    }

    #[test]
    fn association_keeps_the_sparser_trajectory_and_its_nearest_partners() {
        let reference: Vec<Stamped> = (0..10)
            .map(|k| st(k as f64 * 0.1, k as f64, 0.0, 0.0))
            .collect();
        // Estimate at 0.205, 0.5, 0.7995 and 5.0 s: the last has no partner within 10 ms, and
        // 0.205 is 5 ms from 0.2 (and 95 ms from 0.3).
        let estimate = vec![
            st(0.205, 0.0, 0.0, 0.0),
            st(0.5, 0.0, 0.0, 0.0),
            st(0.7995, 0.0, 0.0, 0.0),
            st(5.0, 0.0, 0.0, 0.0),
        ];
        let pairs = associate(&reference, &estimate, 0.01);
        let xs: Vec<f64> = pairs.iter().map(|p| p.0.translation.vector.x).collect();
        assert_eq!(xs, vec![2.0, 5.0, 8.0]);
    }

    #[test]
    fn ate_is_zero_after_aligning_a_rigidly_moved_copy_and_not_before() {
        let reference: Vec<Stamped> = (0..50)
            .map(|k| {
                let a = k as f64 * 0.1;
                st(a, 2.0 * a.cos(), a.sin(), a)
            })
            .collect();
        // The estimate: the reference moved by (1, -2) m and turned 0.3 rad about z.
        let m = Pose2::new(1.0, -2.0, 0.3);
        let estimate: Vec<Stamped> = reference
            .iter()
            .map(|s| {
                let yaw = 2.0 * s.pose.rotation[2].atan2(s.pose.rotation[3]);
                let p = m.compose(&Pose2::new(
                    s.pose.translation[0],
                    s.pose.translation[1],
                    yaw,
                ));
                st(s.stamp.secs(), p.x, p.y, p.theta)
            })
            .collect();
        let pairs = associate(&reference, &estimate, 0.01);
        assert_eq!(pairs.len(), 50);
        let raw = Stats::of(&ate(&pairs, Alignment::None)).unwrap();
        assert!(raw.mean > 1.0);
        for how in [Alignment::Se2, Alignment::Se3] {
            let s = Stats::of(&ate(&pairs, how)).unwrap();
            assert!(s.max < 1e-9, "{how:?}: {s:?}");
        }
        // Relative errors do not see a rigid motion at all.
        let (t, r) = rpe(&pairs, Delta::Metres(0.5));
        assert!(t.len() > 5);
        assert!(t.iter().chain(&r).all(|e| e.abs() < 1e-9));
    }

    #[test]
    fn rpe_by_distance_measures_a_scale_error_per_metre() {
        // The estimate drives 0.125 m per pose along x (exact in binary); the reference 10 %
        // less, so that each estimated metre is 0.1 m too long.
        let reference: Vec<Stamped> = (0..41)
            .map(|k| st(k as f64, 0.1125 * k as f64, 0.0, 0.0))
            .collect();
        let estimate: Vec<Stamped> = (0..41)
            .map(|k| st(k as f64, 0.125 * k as f64, 0.0, 0.0))
            .collect();
        let pairs = associate(&reference, &estimate, 0.01);
        // Pairs 1 m of the estimate's travel apart (evo's default): poses 0, 8, 16, 24, 32,
        // 40. Counted on the reference's path they would be 9 poses apart, and 4 pairs.
        let (t, r) = rpe(&pairs, Delta::Metres(1.0));
        assert_eq!(t.len(), 5);
        for e in &t {
            assert!((e - 0.1).abs() < 1e-12, "{e}");
        }
        assert!(r.iter().all(|e| e.abs() < 1e-12));
    }

    /// Recovery by hand: errors at 1 Hz, large until 13 s, below 0.3 m from 13 s on; an event
    /// at 10 s recovers after 3 s. A dip at 11 s that lasts under 5 s does not count. An event
    /// whose good stretch is cut short by the run's end has not recovered.
    #[test]
    fn recovery_is_the_first_lasting_return_below_the_threshold() {
        let errors: Vec<(f64, f64)> = (0..30)
            .map(|t| {
                let e = if t == 11 || t >= 13 { 0.1 } else { 2.0 };
                (t as f64, e)
            })
            .collect();
        assert_eq!(recovery_times(&errors, &[10.0]), vec![Some(3.0)]);
        assert_eq!(recovery_times(&errors[..16], &[10.0]), vec![None]);
        assert_eq!(worst_recovery(&errors[..16], &[10.0], 16.0), 6.0);
        assert_eq!(worst_recovery(&errors, &[0.0, 10.0], 30.0), 13.0);
    }
}
