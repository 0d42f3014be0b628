//! Scoring against the simulated world's ground truth, apart from the robot stack (as
//! Cartographer keeps its metrics in `ground_truth/`): each module computes one family of
//! metrics, and [`Metrics`] collects them under dotted names (`slam.ate.rmse_m`) so that
//! summaries, and later gates, address them by name. A new family is a new module and one
//! `insert` call where the run has its inputs.

pub mod map;
pub mod trajectory;

use std::collections::BTreeMap;
use trajectory::Stats;

/// Named scalar metrics of a run.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct Metrics(pub BTreeMap<String, f64>);

impl Metrics {
    pub fn insert(&mut self, name: impl Into<String>, value: f64) {
        self.0.insert(name.into(), value);
    }

    /// `prefix.precision_1cell`, … `prefix.free_iou` for a map.
    pub fn insert_map(&mut self, prefix: &str, m: &map::MapScore) {
        for k in 0..2 {
            let c = k + 1;
            self.insert(format!("{prefix}.precision_{c}cell"), m.precision[k]);
            self.insert(format!("{prefix}.recall_{c}cell"), m.recall[k]);
            self.insert(format!("{prefix}.f1_{c}cell"), m.f1[k]);
        }
        self.insert(
            format!("{prefix}.mean_distance_to_truth_m"),
            m.mean_distance_to_truth,
        );
        self.insert(
            format!("{prefix}.mean_distance_from_truth_m"),
            m.mean_distance_from_truth,
        );
        self.insert(format!("{prefix}.free_iou"), m.free_iou);
    }

    /// `prefix.rmse{unit}`, `prefix.mean{unit}`, … for a set of errors.
    pub fn insert_stats(&mut self, prefix: &str, unit: &str, s: &Stats) {
        for (k, v) in [
            ("rmse", s.rmse),
            ("mean", s.mean),
            ("median", s.median),
            ("std", s.std),
            ("min", s.min),
            ("max", s.max),
        ] {
            self.insert(format!("{prefix}.{k}{unit}"), v);
        }
    }
}

/// The trajectories a run may write, scored against its `groundtruth.txt`.
pub const SCORED_TRAJECTORIES: [(&str, &str); 3] = [
    ("odometry", "odometry.txt"),
    ("localization", "localization.txt"),
    ("slam", "slam_trajectory.txt"),
];

/// Largest time difference for pairing an estimate with a ground-truth pose, s (evo's
/// default; the ground truth's 50 Hz puts every stamp within 10 ms of one).
pub const MAX_TIME_DIFF: f64 = 0.01;

/// Travel between the poses of a relative-error pair, m.
pub const RPE_DELTA_M: f64 = 1.0;

/// Scores the trajectories in a run's folder against its ground truth: for each one written,
/// `NAME.ate.*_m` (no alignment: the map frame is the world frame in simulation),
/// `NAME.ate.p95_m`, and `NAME.rpe_1m.trans.*_m` / `NAME.rpe_1m.rot.*_deg`.
pub fn score_trajectories(dir: &std::path::Path) -> anyhow::Result<Metrics> {
    use anyhow::Context;
    let read = |name: &str| -> anyhow::Result<Vec<futago_msgs::tum::Stamped>> {
        let p = dir.join(name);
        let text =
            std::fs::read_to_string(&p).with_context(|| format!("reading {}", p.display()))?;
        futago_msgs::tum::parse(&text).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))
    };
    let truth = read("groundtruth.txt")?;
    let mut m = Metrics::default();
    for (name, file) in SCORED_TRAJECTORIES {
        if !dir.join(file).exists() {
            continue;
        }
        let est = read(file)?;
        let pairs = trajectory::associate(&truth, &est, MAX_TIME_DIFF);
        let ate = trajectory::ate(&pairs, trajectory::Alignment::None);
        if let Some(s) = Stats::of(&ate) {
            m.insert_stats(&format!("{name}.ate"), "_m", &s);
            if let Some(p) = Stats::percentile(&ate, 95.0) {
                m.insert(format!("{name}.ate.p95_m"), p);
            }
        }
        let (t, r) = trajectory::rpe(&pairs, trajectory::Delta::Metres(RPE_DELTA_M));
        if let Some(st) = Stats::of(&t) {
            m.insert_stats(&format!("{name}.rpe_1m.trans"), "_m", &st);
        }
        let deg: Vec<f64> = r.iter().map(|x| x.to_degrees()).collect();
        if let Some(sd) = Stats::of(&deg) {
            m.insert_stats(&format!("{name}.rpe_1m.rot"), "_deg", &sd);
        }
    }
    Ok(m)
}
