//! Scoring against the simulated world's ground truth, apart from the robot stack (as
//! Cartographer keeps its metrics in `ground_truth/`): each module computes one family of
//! metrics, and [`Metrics`] collects them under dotted names (`slam.ate.rmse_m`) so that
//! summaries and gates address them by name. The stack's nodes (`crate::stack`) call these
//! scorers and declare the names they produce; a new family is a new module here.

pub mod cloud;
pub mod completeness;
pub mod coverage;
pub mod crowd;
pub mod detection;
pub mod leg_scans;
pub mod map;
pub mod mot;
pub mod observable;
pub mod planes;
pub mod pollution;
pub mod regions;
pub mod trajectory;

pub use crate::gate::{Comparison, Gate, similar};
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

/// Largest time difference for pairing an estimate with a ground-truth pose, s (evo's
/// default; the ground truth's 50 Hz puts every stamp within 10 ms of one).
pub const MAX_TIME_DIFF: f64 = 0.01;

/// Travel between the poses of a relative-error pair, m.
pub const RPE_DELTA_M: f64 = 1.0;

/// Anchors of the relations sampled from a run's ground truth, s.
pub const RELATION_EVERY_S: f64 = 1.0;
/// Longest span of a sampled relation, s.
pub const RELATION_MAX_SPAN_S: f64 = 10.0;
/// The relations metric's quantities (Kümmerle et al. 2009), as `NAME.relations.KEY`.
pub const RELATION_KEYS: [&str; 8] = [
    "abs_trans_mean_m",
    "abs_trans_std_m",
    "sqr_trans_mean_m2",
    "sqr_trans_std_m2",
    "abs_rot_mean_deg",
    "abs_rot_std_deg",
    "sqr_rot_mean_deg2",
    "sqr_rot_std_deg2",
];

/// The relations a run is scored on, sampled from its ground truth (see
/// [`crate::relations::sample`]; the seed is fixed, so the same truth gives the same relations).
pub fn sample_relations(truth: &[futago_msgs::tum::Stamped]) -> Vec<crate::relations::Relation> {
    let planar: Vec<(futago_msgs::Time, futago_msgs::Pose2)> =
        truth.iter().map(|s| (s.stamp, s.pose.to_pose2())).collect();
    crate::relations::sample(&planar, RELATION_EVERY_S, RELATION_MAX_SPAN_S, 0)
}

/// Scores the estimated trajectory `est` (in memory, as the node made it) against the run's
/// ground truth, as `NAME.ate.*_m` (no alignment: the map frame is the world frame in
/// simulation), `NAME.ate.p95_m`, `NAME.rpe_1m.trans.*_m` / `NAME.rpe_1m.rot.*_deg`, and the
/// relations metric as `NAME.relations.*` (see [`RELATION_KEYS`]). An empty trajectory scores
/// nothing. Each pose is taken as its TUM file holds it ([`futago_msgs::tum::as_written`]),
/// so the figures are those of the files under any tool that reads them (evo): the text's
/// rounding decides, for one, which true pose an estimate stamped halfway between two pairs
/// with.
pub fn score_trajectory(truth: &Truth, name: &str, est: &[futago_msgs::tum::Stamped]) -> Metrics {
    let mut m = Metrics::default();
    let est: Vec<futago_msgs::tum::Stamped> =
        est.iter().map(futago_msgs::tum::as_written).collect();
    let est = est.as_slice();
    let pairs = trajectory::associate(truth.poses, est, MAX_TIME_DIFF);
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
    let planar: Vec<(futago_msgs::Time, futago_msgs::Pose2)> =
        est.iter().map(|s| (s.stamp, s.pose.to_pose2())).collect();
    let rel = crate::relations::evaluate(&planar, truth.relations);
    if rel.relations > 0 && !est.is_empty() {
        let values = [
            rel.abs_trans_m.mean,
            rel.abs_trans_m.std,
            rel.sqr_trans_m2.mean,
            rel.sqr_trans_m2.std,
            rel.abs_rot_deg.mean,
            rel.abs_rot_deg.std,
            rel.sqr_rot_deg2.mean,
            rel.sqr_rot_deg2.std,
        ];
        for (k, v) in RELATION_KEYS.iter().zip(values) {
            m.insert(format!("{name}.relations.{k}"), v);
        }
    }
    m
}

const STATS: [&str; 6] = ["rmse", "mean", "median", "std", "min", "max"];

/// The names [`score_trajectory`] gives trajectory `name`.
pub fn trajectory_metric_names(name: &str) -> Vec<String> {
    let mut names = Vec::new();
    for s in STATS {
        names.push(format!("{name}.ate.{s}_m"));
        names.push(format!("{name}.rpe_1m.trans.{s}_m"));
        names.push(format!("{name}.rpe_1m.rot.{s}_deg"));
    }
    names.push(format!("{name}.ate.p95_m"));
    for k in RELATION_KEYS {
        names.push(format!("{name}.relations.{k}"));
    }
    names
}

/// The names [`Metrics::insert_map`] gives a map scored under `prefix`.
pub fn map_metric_names(prefix: &str) -> Vec<String> {
    let mut names = Vec::new();
    for c in [1, 2] {
        for k in ["precision", "recall", "f1"] {
            names.push(format!("{prefix}.{k}_{c}cell"));
        }
    }
    for k in [
        "mean_distance_to_truth_m",
        "mean_distance_from_truth_m",
        "free_iou",
    ] {
        names.push(format!("{prefix}.{k}"));
    }
    names
}

/// A gate's outcome.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct GateResult {
    pub metric: String,
    pub op: Comparison,
    pub threshold: f64,
    /// The metric's value (`None`: the run did not produce it).
    pub value: Option<f64>,
    pub passed: bool,
    /// What went wrong, for people: `slam.ate.rmse_m = 0.061, not < 0.05 (over by 0.011)`.
    pub message: String,
}

/// Checks `gates` against a run's metrics (the gates of a suite, with `scenario`, left out:
/// [`evaluate_versus`]).
pub fn evaluate(gates: &[Gate], metrics: &Metrics) -> Vec<GateResult> {
    gates
        .iter()
        .filter(|g| g.scenario.is_none())
        .map(|g| {
            let value = metrics.0.get(&g.metric).copied();
            let offset = g.value.unwrap_or(0.0);
            let threshold = match &g.than {
                None => Some(offset),
                Some(m) => metrics.0.get(m).map(|t| t + offset),
            };
            let passed = value.zip(threshold).is_some_and(|(v, t)| g.op.holds(v, t));
            let what = match &g.than {
                None => format!("{offset}"),
                Some(m) if offset == 0.0 => m.clone(),
                Some(m) => format!("{m} {offset:+}"),
            };
            let message = match (value, threshold) {
                (None, _) => format!("{} was not produced by the run", g.metric),
                (_, None) => format!(
                    "{} was not produced by the run",
                    g.than.as_deref().unwrap_or_default()
                ),
                (Some(v), Some(t)) => format!(
                    "{} = {v:.6}, {} {} {what}{} (margin {:+.6})",
                    g.metric,
                    if passed { "" } else { "not" },
                    g.op.symbol(),
                    if g.than.is_some() {
                        format!(" = {t:.6}")
                    } else {
                        String::new()
                    },
                    match g.op {
                        Comparison::Less | Comparison::LessOrEqual => t - v,
                        _ => v - t,
                    }
                )
                .replace(",  ", ", "),
            };
            GateResult {
                metric: g.metric.clone(),
                op: g.op,
                threshold: threshold.unwrap_or(f64::NAN),
                value,
                passed,
                message,
            }
        })
        .collect()
}

/// Checks a suite's gate (`scenario` set) against this run's metrics and those of the
/// scenario's run (`None`: it did not run, or failed): `metric op other's metric + value`.
pub fn evaluate_versus(g: &Gate, own: &Metrics, other: Option<&Metrics>) -> GateResult {
    let name = format!("{}:{}", g.scenario.as_deref().unwrap_or_default(), g.metric);
    let mut m = own.clone();
    if let Some(v) = other.and_then(|o| o.0.get(&g.metric)) {
        m.insert(name.clone(), *v);
    }
    let gate = Gate {
        than: Some(name),
        scenario: None,
        ..g.clone()
    };
    let mut r = evaluate(&[gate], &m);
    r.remove(0)
}

/// The simulator's state as the scorers and recorders see it, kept by the run loop apart from
/// the robot's [`Bus`](crate::stack::Bus): the robot's true pose (every physics step), each
/// agent's and every person's (at the ground-truth rate), and the contacts with people. A
/// stack module acts only on what the bus carries; this view reaches a node only through
/// `Node::on_truth` and `Node::observe`, for its recorder or its scorer.
#[derive(Debug, Clone, Default)]
pub struct TrueState {
    /// The robot base's true pose.
    pub robot: futago_msgs::Pose2,
    /// Each agent's true pose, in `movers.agents` order.
    pub agents: Vec<(String, futago_msgs::Pose2)>,
    /// Every person in the world.
    pub people: Vec<futago_sim::people::PersonTruth>,
    /// Contacts begun between the robot and a person so far (the physics' count).
    pub person_collisions: u64,
}

/// What the scorers are given: the scenario and the simulated truth, in memory.
pub struct Truth<'a> {
    pub scenario: &'a crate::scenario::Scenario,
    /// The robot's true trajectory at the ground-truth rate, as `groundtruth.txt` holds it.
    pub poses: &'a [futago_msgs::tum::Stamped],
    pub relations: &'a [crate::relations::Relation],
}

impl Truth<'_> {
    /// The world's occupancy grid of the 10 cm band at `height`, at `resolution`.
    pub fn world_map(
        &self,
        resolution: f64,
        height: f64,
    ) -> anyhow::Result<futago_msgs::grid::OccupancyGrid> {
        world_map(self.scenario, resolution, height)
    }
}

/// The world's ground-truth occupancy grid of the 10 cm band around `height` (the map a
/// perfect mapping run at that laser height would give).
pub fn world_map(
    s: &crate::scenario::Scenario,
    resolution: f64,
    height: f64,
) -> anyhow::Result<futago_msgs::grid::OccupancyGrid> {
    futago_sim::world::export::occupancy_grid(
        &s.world,
        resolution,
        height - 0.05,
        height + 0.05,
        0.5,
    )
    .map_err(|e| anyhow::anyhow!("{e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A suite's gate ranks a metric against the same metric of another scenario's run,
    /// fails when that run produced none, and is left out of a run's own gates.
    #[test]
    fn a_suite_gate_ranks_against_another_run() {
        let mut own = Metrics::default();
        own.insert("scan3d.views_to_95", 10.0);
        let mut other = Metrics::default();
        other.insert("scan3d.views_to_95", 15.0);
        let g = Gate {
            metric: "scan3d.views_to_95".into(),
            op: Comparison::Less,
            value: None,
            than: None,
            scenario: Some("hall-frontier".into()),
        };
        let r = evaluate_versus(&g, &own, Some(&other));
        assert!(r.passed, "{}", r.message);
        assert_eq!(r.threshold, 15.0);
        assert!(
            r.message.contains("hall-frontier:scan3d.views_to_95"),
            "{}",
            r.message
        );
        let worse = Gate {
            value: Some(-6.0),
            ..g.clone()
        };
        assert!(!evaluate_versus(&worse, &own, Some(&other)).passed);
        let r = evaluate_versus(&g, &own, None);
        assert!(!r.passed);
        assert!(r.message.contains("not produced"), "{}", r.message);
        assert!(evaluate(&[g], &own).is_empty());
    }

    #[test]
    fn gates_pass_fail_and_say_by_how_much() {
        let mut m = Metrics::default();
        m.insert("slam.ate.rmse_m", 0.061);
        m.insert("slam.map.f1_2cell", 0.95);
        let gates = [
            Gate {
                metric: "slam.ate.rmse_m".into(),
                op: Comparison::Less,
                value: Some(0.05),
                than: None,
                scenario: None,
            },
            Gate {
                metric: "slam.map.f1_2cell".into(),
                op: Comparison::GreaterOrEqual,
                value: Some(0.9),
                than: None,
                scenario: None,
            },
            Gate {
                metric: "localization.ate.max_m".into(),
                op: Comparison::Less,
                value: Some(1.0),
                than: None,
                scenario: None,
            },
            Gate {
                metric: "slam.ate.rmse_m".into(),
                op: Comparison::Less,
                value: None,
                than: Some("odometry.ate.rmse_m".into()),
                scenario: None,
            },
            Gate {
                metric: "slam.ate.rmse_m".into(),
                op: Comparison::Less,
                value: Some(-0.05),
                than: Some("odometry.ate.rmse_m".into()),
                scenario: None,
            },
        ];
        m.insert("odometry.ate.rmse_m", 0.1);
        let r = evaluate(&gates, &m);
        assert_eq!(
            r.iter().map(|g| g.passed).collect::<Vec<_>>(),
            [false, true, false, true, false]
        );
        assert_eq!(
            r[3].message,
            "slam.ate.rmse_m = 0.061000, < odometry.ate.rmse_m = 0.100000 (margin +0.039000)"
        );
        assert_eq!(r[4].threshold, 0.05);
        assert_eq!(
            r[0].message,
            "slam.ate.rmse_m = 0.061000, not < 0.05 (margin -0.011000)"
        );
        assert_eq!(
            r[1].message,
            "slam.map.f1_2cell = 0.950000, >= 0.9 (margin +0.050000)"
        );
        assert!(r[2].message.contains("not produced"));
    }
}
