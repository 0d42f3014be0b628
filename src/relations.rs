//! The relations metric of Kümmerle et al. 2009 ("On measuring the accuracy of SLAM
//! algorithms", Autonomous Robots 27(4)), computed as Cartographer's
//! `compute_relations_metrics` does (`shared/reference/sensors-robot-metrics.md` §1.2).
//!
//! A relation is the true relative pose R from the robot at `t1` to the robot at `t2`. The
//! estimated poses P1, P2 at those times are interpolated in the estimated trajectory; the error
//! transform is E = (P1⁻¹ P2) R⁻¹, and each relation contributes ‖t(E)‖ and |angle(E)|. The
//! report is the mean and sample standard deviation (n − 1) of the absolute and squared
//! translational (m, m²) and rotational (deg, deg²) errors.
//!
//! This is scoring, not robot code: it lives beside the ground truth, apart from the stack.

use anyhow::{Result, bail};
use futago_msgs::{Duration, Pose2, Time, wrap_angle};
use serde::{Deserialize, Serialize};

/// One ground-truth relation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Relation {
    pub t1: Time,
    pub t2: Time,
    /// Pose of the robot at `t2` in its frame at `t1`.
    pub delta: Pose2,
}

/// Parses a relations file: `t1 t2 x y z roll pitch yaw` per line, `#` comments.
pub fn parse(text: &str, file: &str) -> Result<Vec<Relation>> {
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let v: Vec<f64> = line
            .split_whitespace()
            .map(|w| w.parse::<f64>().ok().filter(|x| x.is_finite()))
            .collect::<Option<_>>()
            .unwrap_or_default();
        if v.len() != 8 {
            bail!(
                "{file} line {}: expected `t1 t2 x y z roll pitch yaw` (8 numbers), found `{line}`",
                i + 1
            );
        }
        if futago_msgs::bounded_stamp(v[0]).is_none()
            || futago_msgs::bounded_stamp(v[1]).is_none()
            || v[2..5]
                .iter()
                .any(|&x| futago_msgs::bounded_coordinate(x).is_none())
        {
            bail!(
                "{file} line {}: stamps must lie within ±{} s and offsets within ±{} m, found `{line}`",
                i + 1,
                futago_msgs::MAX_STAMP,
                futago_msgs::MAX_COORDINATE
            );
        }
        out.push(Relation {
            t1: Time::from_secs(v[0]),
            t2: Time::from_secs(v[1]),
            delta: Pose2::new(v[2], v[3], v[7]),
        });
    }
    if out.is_empty() {
        bail!("{file}: no relations");
    }
    Ok(out)
}

/// Relations sampled from a ground-truth trajectory (sorted by time), for scoring simulated
/// runs as real logs are scored: from an anchor every `every_s` seconds to a time a uniform
/// 0 to `max_span_s` seconds later (seeded, so the same truth gives the same relations). The
/// spans mix short, scan-to-scan relations with ones across several metres of travel, as the
/// hand-made relation files of the real datasets do (intel's first relation spans 6.7 s).
pub fn sample(truth: &[(Time, Pose2)], every_s: f64, max_span_s: f64, seed: u64) -> Vec<Relation> {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let (Some(first), Some(last)) = (truth.first(), truth.last()) else {
        return Vec::new();
    };
    let mut out = Vec::new();
    let mut t1 = first.0;
    let step = Duration::from_secs(every_s);
    while t1 < last.0 {
        let span = Duration::from_secs(rng.random::<f64>() * max_span_s);
        let t2 = t1 + span;
        if let (Some(a), Some(b)) = (interpolate(truth, t1), interpolate(truth, t2))
            && t2 > t1
        {
            out.push(Relation {
                t1,
                t2,
                delta: a.between(&b),
            });
        }
        t1 = t1 + step;
    }
    out
}

/// Cycles of three relations fewer than which [`reference_noise`] measures nothing.
pub const MIN_CYCLES: usize = 10;

/// A median cycle closure below which relations are taken as cut from one trajectory, m (a
/// file's six printed decimals round to 5e-7 m).
pub const CLOSED_M: f64 = 1e-5;

/// The relations' own error, as far as their cycles show it.
///
/// A relations file is a measurement too: Kümmerle et al. made each relation by matching two
/// scans and checking the match by eye, so a relation carries the error of that match. Where
/// three relations join stamps a→b, b→c and a→c, their composition `ab·bc·ac⁻¹` is the identity
/// up to that error; with independent errors of per-axis spread σ on each relation, the
/// closure's per-axis spread is √3·σ (its heading's too; the closure's translation also takes
/// the heading errors times the relations' lengths, neglected here, so σ is an upper estimate
/// where relations are long). σ comes from the closures' medians, robust to a bad relation:
/// the median of a 2D isotropic Gaussian's norm is σ·√(2 ln 2), of a 1D one's magnitude
/// 0.6745·σ. Relations cut from one trajectory close exactly (below [`CLOSED_M`]) and read 0:
/// their error, if any, is the trajectory's and no cycle shows it. Fewer than [`MIN_CYCLES`]
/// cycles measure nothing (σ 0).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ReferenceNoise {
    /// Cycles of three relations found.
    pub cycles: usize,
    /// The median closure's translation, m (0 with fewer than [`MIN_CYCLES`] cycles).
    pub closure_median_m: f64,
    /// One relation's per-axis translation spread, m.
    pub sigma_xy_m: f64,
    /// One relation's heading spread, rad.
    pub sigma_theta_rad: f64,
    /// The mean translational error σ implies for one relation, σ·√(π/2), m: what a relations
    /// error cannot go below on average for an estimate whose errors are independent of the
    /// reference's (E|s + n| grows with |s| for a zero-mean Gaussian n; an estimate that made
    /// the relations, or was tuned on them, can follow their errors).
    pub mean_error_m: f64,
}

/// The noise of `relations` measured on their cycles of three (see [`ReferenceNoise`]).
pub fn reference_noise(relations: &[Relation]) -> ReferenceNoise {
    use std::collections::{BTreeSet, HashMap};
    // Each relation both ways: (from, to) → (index, pose of `to` in the frame of `from`).
    let mut edges: HashMap<Time, Vec<(Time, usize, Pose2)>> = HashMap::new();
    for (i, r) in relations.iter().enumerate() {
        if r.t1 == r.t2 {
            continue;
        }
        edges.entry(r.t1).or_default().push((r.t2, i, r.delta));
        edges
            .entry(r.t2)
            .or_default()
            .push((r.t1, i, r.delta.inverse()));
    }
    let mut seen = BTreeSet::new();
    let (mut trans, mut heading) = (Vec::new(), Vec::new());
    for (i, r) in relations.iter().enumerate() {
        let Some(from_a) = edges.get(&r.t1) else {
            continue;
        };
        for &(b, j, ab) in from_a {
            if j == i || b == r.t2 {
                continue;
            }
            for &(c, k, bc) in edges.get(&b).map_or(&[][..], |v| v.as_slice()) {
                if c != r.t2 || k == i || k == j {
                    continue;
                }
                let mut key = [i, j, k];
                key.sort_unstable();
                if !seen.insert(key) {
                    continue;
                }
                let closure = ab.compose(&bc).compose(&r.delta.inverse());
                trans.push(closure.x.hypot(closure.y));
                heading.push(wrap_angle(closure.theta).abs());
            }
        }
    }
    let cycles = trans.len();
    if cycles < MIN_CYCLES {
        return ReferenceNoise {
            cycles,
            closure_median_m: 0.0,
            sigma_xy_m: 0.0,
            sigma_theta_rad: 0.0,
            mean_error_m: 0.0,
        };
    }
    // The middle value, or the mean of the two middle ones (selected, not sorted).
    let median = |mut v: Vec<f64>| {
        let n = v.len();
        let (below, mid, _) = v.select_nth_unstable_by(n / 2, f64::total_cmp);
        match below.iter().copied().max_by(f64::total_cmp) {
            Some(lower) if n.is_multiple_of(2) => 0.5 * (lower + *mid),
            _ => *mid,
        }
    };
    let closure_median_m = median(trans);
    if closure_median_m < CLOSED_M {
        return ReferenceNoise {
            cycles,
            closure_median_m,
            sigma_xy_m: 0.0,
            sigma_theta_rad: 0.0,
            mean_error_m: 0.0,
        };
    }
    let sqrt3 = 3f64.sqrt();
    let sigma_xy_m = closure_median_m / ((2.0 * std::f64::consts::LN_2).sqrt() * sqrt3);
    let sigma_theta_rad = median(heading) / (0.674_489_750_196_081_7 * sqrt3);
    ReferenceNoise {
        cycles,
        closure_median_m,
        sigma_xy_m,
        sigma_theta_rad,
        mean_error_m: sigma_xy_m * std::f64::consts::FRAC_PI_2.sqrt(),
    }
}

/// What [`reference_noise`] found, in a sentence.
pub fn describe(n: &ReferenceNoise) -> String {
    if n.cycles < MIN_CYCLES {
        format!(
            "the relations hold {} cycles of three, fewer than {MIN_CYCLES}: their own error is not measured",
            n.cycles
        )
    } else if n.mean_error_m == 0.0 {
        format!(
            "the relations' {} cycles of three close to {:.1e} m (median): they were cut from one trajectory, whose own error no cycle shows",
            n.cycles, n.closure_median_m
        )
    } else {
        format!(
            "the relations' own error, from their {} cycles of three (median closure {:.4} m): σ {:.4} m per axis and {:.3}° in heading per relation, a mean error of {:.4} m that no estimate independent of the reference's goes below on average",
            n.cycles,
            n.closure_median_m,
            n.sigma_xy_m,
            n.sigma_theta_rad.to_degrees(),
            n.mean_error_m
        )
    }
}

/// `relations` as a reference with `noise` would have measured them: each relation composed
/// with an error of per-axis spread `noise.sigma_xy_m` and heading spread
/// `noise.sigma_theta_rad`, drawn from `rng` in order. A twin scored against these is scored as
/// the real log is, against relations that err as the real ones do.
pub fn with_noise(
    relations: &[Relation],
    noise: &ReferenceNoise,
    rng: &mut impl rand::Rng,
) -> Vec<Relation> {
    use rand_distr::{Distribution, StandardNormal};
    relations
        .iter()
        .map(|r| {
            let mut n = || -> f64 { StandardNormal.sample(rng) };
            let e = Pose2::new(
                noise.sigma_xy_m * n(),
                noise.sigma_xy_m * n(),
                noise.sigma_theta_rad * n(),
            );
            Relation {
                delta: r.delta.compose(&e),
                ..*r
            }
        })
        .collect()
}

/// Relations in the datasets' text format: `t1 t2 x y z roll pitch yaw` per line.
pub fn format(relations: &[Relation]) -> String {
    let mut text = String::from("# timestamp1 timestamp2 x y z roll pitch yaw\n");
    for r in relations {
        text += &format!(
            "{:.6} {:.6} {:.6} {:.6} 0.000000 0.000000 0.000000 {:.6}\n",
            r.t1.secs(),
            r.t2.secs(),
            r.delta.x,
            r.delta.y,
            r.delta.theta
        );
    }
    text
}

/// Mean and sample standard deviation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MeanStd {
    pub mean: f64,
    pub std: f64,
}

fn mean_std(v: &[f64]) -> MeanStd {
    let n = v.len() as f64;
    if v.is_empty() {
        return MeanStd {
            mean: f64::NAN,
            std: f64::NAN,
        };
    }
    let mean = v.iter().sum::<f64>() / n;
    let var = if v.len() > 1 {
        v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / (n - 1.0)
    } else {
        0.0
    };
    MeanStd {
        mean,
        std: var.sqrt(),
    }
}

/// The four reported quantities, and how many relations were scored.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Metrics {
    pub relations: usize,
    /// Relations whose times fall outside the estimated trajectory.
    pub unmatched: usize,
    pub abs_trans_m: MeanStd,
    pub sqr_trans_m2: MeanStd,
    pub abs_rot_deg: MeanStd,
    pub sqr_rot_deg2: MeanStd,
}

/// The pose at `t`, interpolated between the samples around it; `None` outside the
/// trajectory, so that a relation is never scored against an invented pose.
pub fn interpolate(traj: &[(Time, Pose2)], t: Time) -> Option<Pose2> {
    futago_msgs::pose_at(traj, t, futago_msgs::Outside::None)
}

/// One relation's error: translational (m) and rotational (degrees), `None` when its times
/// fall outside the estimated trajectory.
pub fn error(traj: &[(Time, Pose2)], r: &Relation) -> Option<(f64, f64)> {
    let (p1, p2) = (interpolate(traj, r.t1)?, interpolate(traj, r.t2)?);
    let e = p1.between(&p2).compose(&r.delta.inverse());
    Some((e.x.hypot(e.y), wrap_angle(e.theta).abs().to_degrees()))
}

/// Scores an estimated trajectory (sorted by time) against relations.
pub fn evaluate(traj: &[(Time, Pose2)], relations: &[Relation]) -> Metrics {
    let (mut trans, mut rot) = (Vec::new(), Vec::new());
    let mut unmatched = 0;
    for r in relations {
        match error(traj, r) {
            Some((t, a)) => {
                trans.push(t);
                rot.push(a);
            }
            None => unmatched += 1,
        }
    }
    let sq = |v: &[f64]| v.iter().map(|x| x * x).collect::<Vec<_>>();
    Metrics {
        relations: trans.len(),
        unmatched,
        abs_trans_m: mean_std(&trans),
        sqr_trans_m2: mean_std(&sq(&trans)),
        abs_rot_deg: mean_std(&rot),
        sqr_rot_deg2: mean_std(&sq(&rot)),
    }
}

/// Upper ends of the time spans (s) relations are grouped by: relations between poses a few
/// seconds apart measure local accuracy (the hospital's "local" set, Kümmerle et al. 2009),
/// those spanning minutes measure the map's global consistency after a loop.
pub const SPAN_BOUNDS_S: [f64; 2] = [10.0, 100.0];

/// The relations split by `|t2 − t1|` at [`SPAN_BOUNDS_S`]: each group's label and members,
/// shortest first.
pub fn by_span(relations: &[Relation]) -> Vec<(String, Vec<Relation>)> {
    let [a, b] = SPAN_BOUNDS_S;
    let mut groups = vec![
        (format!("under_{a}s"), Vec::new()),
        (format!("{a}_to_{b}s"), Vec::new()),
        (format!("over_{b}s"), Vec::new()),
    ];
    for r in relations {
        let span = (r.t2 - r.t1).secs().abs();
        let k = SPAN_BOUNDS_S.iter().filter(|&&bound| span >= bound).count();
        groups[k].1.push(*r);
    }
    groups
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// A wandering path of `n` poses 0.3 m apart, one per second.
    fn path(n: usize) -> Vec<(Time, Pose2)> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut p = Pose2::IDENTITY;
        (0..n)
            .map(|i| {
                p = p.compose(&Pose2::new(0.3, 0.0, rng.random_range(-0.3..0.3)));
                (Time::from_secs(i as f64), p)
            })
            .collect()
    }

    /// Triangles i→i+1, i+1→i+2 and i→i+2 every second pose (neighbouring triangles share
    /// no relation), exact.
    fn triangles(truth: &[(Time, Pose2)]) -> Vec<Relation> {
        let rel = |a: usize, b: usize| Relation {
            t1: truth[a].0,
            t2: truth[b].0,
            delta: truth[a].1.between(&truth[b].1),
        };
        (0..truth.len() - 2)
            .step_by(2)
            .flat_map(|i| [rel(i, i + 1), rel(i + 1, i + 2), rel(i, i + 2)])
            .collect()
    }

    #[test]
    fn cycles_of_three_recover_the_spread_drawn_into_the_relations() {
        let truth = path(801);
        let exact = triangles(&truth);
        let drawn = ReferenceNoise {
            cycles: 0,
            closure_median_m: 0.0,
            sigma_xy_m: 0.02,
            sigma_theta_rad: 0.005,
            mean_error_m: 0.0,
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let noisy = with_noise(&exact, &drawn, &mut rng);
        let n = reference_noise(&noisy);
        assert_eq!(n.cycles, 400);
        // The median of 400 closures is within ~4 % (1σ) of its expectation; the heading
        // errors add about 0.3 m · 0.005 rad to the closure's translation, 1 % of it.
        assert!((n.sigma_xy_m / 0.02 - 1.0).abs() < 0.15, "{n:?}");
        assert!((n.sigma_theta_rad / 0.005 - 1.0).abs() < 0.15, "{n:?}");
        // The exact truth scored against the noisy relations errs by what the noise implies.
        let measured = evaluate(&truth, &noisy).abs_trans_m.mean;
        assert!(
            (measured / n.mean_error_m - 1.0).abs() < 0.15,
            "{measured} {n:?}"
        );
    }

    #[test]
    fn relations_cut_from_one_trajectory_close_and_too_few_cycles_measure_nothing() {
        let truth = path(101);
        let exact = triangles(&truth);
        let n = reference_noise(&exact);
        assert_eq!(n.cycles, 50);
        assert_eq!(
            (n.sigma_xy_m, n.sigma_theta_rad, n.mean_error_m),
            (0.0, 0.0, 0.0)
        );
        assert!(describe(&n).contains("cut from one trajectory"));
        // The same triangles listed backwards (t2 before t1) are the same cycles.
        let reversed: Vec<Relation> = exact
            .iter()
            .map(|r| Relation {
                t1: r.t2,
                t2: r.t1,
                delta: r.delta.inverse(),
            })
            .collect();
        assert_eq!(reference_noise(&reversed).cycles, 50);
        let few = reference_noise(&exact[..3 * (MIN_CYCLES - 1)]);
        assert_eq!(few.cycles, MIN_CYCLES - 1);
        assert_eq!((few.sigma_xy_m, few.mean_error_m), (0.0, 0.0));
        assert!(describe(&few).contains("not measured"));
        // A chain without cycles has none.
        let chain: Vec<Relation> = exact.iter().step_by(3).copied().collect();
        assert_eq!(reference_noise(&chain).cycles, 0);
    }

    #[test]
    fn relations_split_by_span_at_the_bounds_whichever_way_round() {
        let r = |t1: f64, t2: f64| Relation {
            t1: Time::from_secs(t1),
            t2: Time::from_secs(t2),
            delta: Pose2::IDENTITY,
        };
        let all = [
            r(0.0, 3.0),
            r(5.0, 0.0),
            r(0.0, 10.0),
            r(20.0, 119.9),
            r(0.0, 100.0),
            r(4000.0, 10.0),
        ];
        let groups = by_span(&all);
        let labels: Vec<&str> = groups.iter().map(|(l, _)| l.as_str()).collect();
        assert_eq!(labels, ["under_10s", "10_to_100s", "over_100s"]);
        let sizes: Vec<usize> = groups.iter().map(|(_, g)| g.len()).collect();
        assert_eq!(sizes, [2, 2, 2]);
        assert_eq!(groups[0].1, [all[0], all[1]]);
        assert_eq!(groups[2].1, [all[4], all[5]]);
    }

    #[test]
    fn a_perfect_trajectory_scores_zero_and_a_known_error_scores_by_hand() {
        // The robot drives 1 m along x per second, turning 0.1 rad per second.
        let truth: Vec<(Time, Pose2)> = (0..=10)
            .map(|i| {
                let t = i as f64;
                (Time::from_secs(t), Pose2::new(t, 0.0, 0.1 * t))
            })
            .collect();
        let rel = |a: usize, b: usize| Relation {
            t1: truth[a].0,
            t2: truth[b].0,
            delta: truth[a].1.between(&truth[b].1),
        };
        let rels = vec![rel(0, 1), rel(2, 5), rel(3, 4)];
        let m = evaluate(&truth, &rels);
        assert_eq!(m.relations, 3);
        assert!(m.abs_trans_m.mean < 1e-12 && m.abs_rot_deg.mean < 1e-9);

        // Shift one estimated pose 0.1 m along the world's y: relation (3, 4) then errs by
        // exactly that shift seen from pose 3, the others not at all.
        let mut est = truth.clone();
        est[4].1.y += 0.1;
        let m = evaluate(&est, &rels);
        let errs = [0.0, 0.0, 0.1];
        let mean = 0.1 / 3.0;
        let std = (errs.iter().map(|e| (e - mean) * (e - mean)).sum::<f64>() / 2.0).sqrt();
        assert!((m.abs_trans_m.mean - mean).abs() < 1e-9, "{m:?}");
        assert!((m.abs_trans_m.std - std).abs() < 1e-9);
        assert!((m.sqr_trans_m2.mean - 0.01 / 3.0).abs() < 1e-9);
        assert!(m.abs_rot_deg.mean < 1e-9);

        // A relation between times outside the trajectory is counted, not scored.
        let outside = Relation {
            t1: Time::from_secs(20.0),
            t2: Time::from_secs(21.0),
            delta: Pose2::IDENTITY,
        };
        assert_eq!(evaluate(&truth, &[outside]).unmatched, 1);
    }

    #[test]
    fn sampled_relations_are_exact_on_the_truth_and_round_trip_through_text() {
        let truth: Vec<(Time, Pose2)> = (0..=200)
            .map(|i| {
                let t = i as f64 * 0.1;
                (
                    Time::from_secs(t),
                    Pose2::new(t.cos() * 3.0, t.sin() * 3.0, t + 1.5),
                )
            })
            .collect();
        let rels = sample(&truth, 1.0, 5.0, 7);
        // Anchors at 0, 1, …, 19 s; those whose span runs past 20 s are dropped.
        assert!((12..=20).contains(&rels.len()), "{}", rels.len());
        assert!(
            rels.iter()
                .all(|r| r.t2 > r.t1 && (r.t2 - r.t1).secs() <= 5.0)
        );
        assert_eq!(rels, sample(&truth, 1.0, 5.0, 7));
        let m = evaluate(&truth, &rels);
        assert!(m.abs_trans_m.mean < 1e-3 && m.unmatched == 0, "{m:?}");
        let back = parse(&format(&rels), "r").unwrap();
        assert_eq!(back.len(), rels.len());
        assert!((back[3].delta.x - rels[3].delta.x).abs() < 1e-6);
    }

    #[test]
    fn interpolation_is_linear_and_takes_the_short_way_round() {
        let traj = vec![
            (Time::from_secs(0.0), Pose2::new(0.0, 0.0, 3.0)),
            (Time::from_secs(1.0), Pose2::new(2.0, 4.0, -3.0)),
        ];
        let p = interpolate(&traj, Time::from_secs(0.5)).unwrap();
        assert!((p.x - 1.0).abs() < 1e-12 && (p.y - 2.0).abs() < 1e-12);
        // From 3.0 to −3.0 through π, not through 0.
        assert!(p.theta.abs() > 3.0, "{}", p.theta);
        assert!(interpolate(&traj, Time::from_secs(1.5)).is_none());
    }

    #[test]
    fn relation_files_parse_and_bad_lines_are_named() {
        let r = parse(
            "1134864645.90321 1134864646.32420 0.31293 0.02935 0.00000  0.00000 0.00000 0.24198\n",
            "x.relations",
        )
        .unwrap();
        assert_eq!(r.len(), 1);
        assert!((r[0].delta.theta - 0.24198).abs() < 1e-12);
        let e = parse("1 2 3\n", "x.relations").unwrap_err().to_string();
        assert!(e.contains("x.relations line 1"), "{e}");
    }
}
