//! A run is scored in memory, and the truth reaches the robot's stack only through the oracle.
//! In process, through the library:
//!
//! - `run::evaluate` scores a run without writing anything, and gives the same metrics and
//!   gates as `run::run`, which writes the files after scoring and reads none back;
//! - the summary lists every file the run wrote, and only those, and times each node by
//!   callback (every scan handed to the localiser counted);
//! - the oracle node (`pose/ground_truth`) runs only where a module asks for the truth, and
//!   the summary then names it and its consumers.

use futago::run::{self, RunOptions};
use futago::stack;
use serde_json::Value;
use std::collections::BTreeSet;
use std::path::Path;

fn options(duration: f64) -> RunOptions {
    RunOptions {
        seed: None,
        duration: Some(duration),
        progress: false,
        report: false,
        force: false,
    }
}

fn scenario(name: &str) -> futago::scenario::Scenario {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenarios")
        .join(format!("{name}.toml"));
    stack::load(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Every file under `dir`, relative to it.
fn files_in(dir: &Path) -> BTreeSet<String> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeSet<String>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(root, &p, out);
            } else {
                let rel = p.strip_prefix(root).unwrap();
                out.insert(rel.to_string_lossy().replace('\\', "/"));
            }
        }
    }
    let mut out = BTreeSet::new();
    walk(dir, dir, &mut out);
    out
}

#[test]
fn a_run_scored_in_memory_matches_the_run_written_to_disk() {
    // Localisation on the laser: trajectories of odometry and MCL, scored against the truth.
    let s = scenario("office-mcl");
    let opts = options(20.0);
    let scored = run::evaluate(&s, &opts).unwrap();
    assert!(
        scored.metrics.0.contains_key("localization.ate.rmse_m")
            && scored.metrics.0.contains_key("odometry.ate.rmse_m"),
        "in-memory metrics: {:?}",
        scored.metrics.0.keys().collect::<Vec<_>>()
    );
    // The run's truth is the robot's true trajectory at the ground-truth rate: 20 s at the
    // scenario's rate, and the relations sampled from it.
    let rate = s.spec.output.groundtruth_rate;
    let expected = (20.0 * rate).round() as usize;
    assert!(
        scored.outcome.truth.len().abs_diff(expected) <= 1,
        "{} true poses for {expected}",
        scored.outcome.truth.len()
    );
    assert!(!scored.relations.is_empty());

    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let (summary, _) = run::run(&s, &opts, &out).unwrap();
    let written: serde_json::Map<String, Value> = summary["metrics"].as_object().unwrap().clone();
    let in_memory = serde_json::to_value(&scored.metrics).unwrap();
    assert_eq!(
        Value::Object(written),
        in_memory,
        "the written run's metrics are the in-memory ones"
    );
    assert_eq!(
        summary["gates"],
        serde_json::to_value(scored.gates(&s)).unwrap()
    );

    // The summary lists every file in the folder but itself, its marker and the report.
    let listed: BTreeSet<String> = summary["files"]
        .as_object()
        .unwrap()
        .keys()
        .cloned()
        .collect();
    let on_disk: BTreeSet<String> = files_in(&out)
        .into_iter()
        .filter(|f| f != run::SUMMARY_FILE && f != run::REPORT_FILE && f != futago::output::MARKER)
        .collect();
    assert_eq!(listed, on_disk);
    // No oracle: the driver steers on the localiser's estimate.
    assert!(summary.get("oracle").is_none());
    assert!(summary["performance"]["nodes"].get("oracle").is_none());

    // Each node's time by callback: the localiser was handed every scan of the laser once,
    // started and finished once, and its callbacks' times make up its wall time.
    let loc = &summary["performance"]["nodes"]["localization"];
    let calls = loc["callbacks"].as_object().unwrap();
    let laser = &summary["lidar"][0];
    let scans = &calls[&format!("scan/{}", laser["name"].as_str().unwrap())];
    assert_eq!(scans["calls"], laser["scans"], "{calls:?}");
    assert!(laser["scans"].as_u64().unwrap() > 100, "{laser}");
    assert_eq!(calls["start"]["calls"], 1);
    assert_eq!(calls["finish"]["calls"], 1);
    let mut summed = 0.0;
    for (what, c) in calls {
        let (n, mean, max) = (
            c["calls"].as_f64().unwrap(),
            c["mean_ms"].as_f64().unwrap(),
            c["max_ms"].as_f64().unwrap(),
        );
        assert!(n >= 1.0 && mean >= 0.0 && max >= mean, "{what}: {c}");
        summed += n * mean / 1e3;
    }
    let wall = loc["wall_s"].as_f64().unwrap();
    assert!(
        (summed - wall).abs() <= 1e-9 * wall.max(1.0),
        "callbacks {summed} s, node {wall} s"
    );
}

#[test]
fn the_oracle_runs_only_where_a_module_asks_for_the_truth_and_the_summary_says_so() {
    // Laps of a square on the true pose (seed 000's return-to-start errors).
    let s = scenario("office-laps");
    let nodes = stack::build(&s, 0, None).unwrap();
    let oracle: Vec<_> = nodes.iter().filter(|n| n.name() == "oracle").collect();
    assert_eq!(oracle.len(), 1, "one oracle node");
    let streams = oracle[0].streams();
    assert_eq!(streams.publishes, ["pose/ground_truth"]);
    assert!(
        nodes.iter().any(|n| n.name() == "driver"
            && n.streams()
                .consumes
                .iter()
                .any(|t| t == "pose/ground_truth")),
        "the driver consumes the oracle's topic"
    );
    let scored = run::evaluate(&s, &options(5.0)).unwrap();
    let entry = scored
        .outcome
        .entries
        .iter()
        .find(|(k, _)| k == "oracle")
        .map(|(_, v)| v.clone())
        .expect("the summary names the oracle");
    assert_eq!(entry["publishes"], "pose/ground_truth");
    assert_eq!(entry["consumers"], serde_json::json!(["driver"]));

    // On odometry alone, no node consumes the truth and no oracle is built.
    let plain = scenario("umbmark-cw");
    assert!(
        stack::build(&plain, 0, None)
            .unwrap()
            .iter()
            .all(|n| n.name() != "oracle")
    );
}

/// The people node measures what its laser shows of the people it sees, as the replay of a
/// real annotated log does (`people.leg_scans`): every person the scan sees within 10 m is
/// counted once, in one range bin, and the segments near them measure a shin.
#[test]
fn the_people_a_scan_sees_are_measured_by_the_segments_near_them() {
    let s = scenario("train-legs");
    let tmp = tempfile::tempdir().unwrap();
    let (summary, _) = run::run(&s, &options(20.0), &tmp.path().join("run")).unwrap();
    let people = &summary["people"];
    let bins = people["leg_scans"]["by_range"].as_array().unwrap();
    assert!(!bins.is_empty(), "{people}");
    let mut counted = 0;
    for b in bins {
        counted += b["people"].as_u64().unwrap();
        let shares: f64 = ["none", "one", "two", "three_or_more"]
            .iter()
            .map(|k| b["share_by_segments"][k].as_f64().unwrap())
            .sum();
        assert!((shares - 1.0).abs() < 1e-9, "{b}");
        // A shin is 0.1 m across: its visible chord, or two legs merged, not a wall.
        let w = b["width_m"]["median"].as_f64().unwrap();
        assert!((0.05..=0.2).contains(&w), "{b}");
    }
    // The URG-04LX reaches 5.6 m: everyone the scan sees lies in a bin.
    assert_eq!(counted, people["tracking"]["objects"].as_u64().unwrap());
    // The twin knows every person's velocity: each is counted once more by how they move.
    let moving = &people["leg_scans"]["by_motion"];
    let by_motion: u64 = ["standing", "along", "across"]
        .iter()
        .map(|m| moving[m]["people"].as_u64().unwrap())
        .sum();
    assert_eq!(by_motion, counted);
}
