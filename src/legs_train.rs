//! `futago train-legs`: the laser leg classifier trained on simulated scans, whose labels the
//! twin gives for free. Each scan of the scenario's laser is cut into segments
//! ([`futago_robot::perception::legs`]); a segment is a leg when its centroid lies within
//! `LABEL_RADIUS` of where a person's leg crosses the laser's plane (the simulator's truth).
//! AdaBoost is trained on every seed but the last, and scored on the last (held out).

use crate::run::{RunOptions, simulate_with};
use crate::scenario::Scenario;
use crate::stack::{Bus, Node, Streams, TrueState};
use anyhow::{Context, Result, bail};
use futago_msgs::{LaserScan, Pose2};
use futago_robot::perception::legs::{
    AdaBoost, FEATURE_NAMES, FEATURES, LegConfig, features, segments,
};
use serde_json::{Value, json};
use std::cell::RefCell;
use std::path::Path;
use std::rc::Rc;

/// A segment whose centroid lies this close to a leg's axis is a leg, m: a shin's radius
/// (0.05 m) and the centroid of its visible arc, plus the truth's age (up to one 20 ms
/// ground-truth tick at 1.3 m/s).
pub const LABEL_RADIUS: f64 = 0.12;

/// Labelled samples of one run.
#[derive(Default)]
struct Samples {
    features: Vec<[f64; FEATURES]>,
    labels: Vec<bool>,
}

/// Collects the scenario's laser's segments with their labels.
struct Collector {
    laser: String,
    mount: Pose2,
    height: f64,
    config: LegConfig,
    people: Vec<futago_sim::people::PersonTruth>,
    /// The scan just taken, until it is labelled.
    scan: Option<LaserScan>,
    out: Rc<RefCell<Samples>>,
}

impl Node for Collector {
    fn name(&self) -> &'static str {
        "legs.train"
    }

    fn streams(&self) -> Streams {
        Streams {
            consumes: vec!["truth".into(), format!("scan/{}", self.laser)],
            ..Streams::default()
        }
    }

    fn on_truth(&mut self, truth: &TrueState, _bus: &mut Bus) -> Result<()> {
        self.people.clone_from(&truth.people);
        Ok(())
    }

    fn on_scan(&mut self, _laser: &str, scan: &LaserScan, _bus: &mut Bus) -> Result<()> {
        self.scan = Some(scan.clone());
        Ok(())
    }

    /// Labels the scan just taken by the true legs around the true laser pose.
    fn observe(&mut self, truth: &TrueState, _bus: &Bus) {
        let Some(scan) = self.scan.take() else {
            return;
        };
        let scan = &scan;
        let laser = truth.robot.compose(&self.mount);
        let legs: Vec<[f64; 2]> = self
            .people
            .iter()
            .flat_map(|p| p.legs_at(self.height))
            .collect();
        let mut out = self.out.borrow_mut();
        for s in segments(scan, &self.config) {
            let c = laser.transform_point(s.centroid());
            let leg = legs
                .iter()
                .any(|l| (l[0] - c[0]).hypot(l[1] - c[1]) <= LABEL_RADIUS);
            out.features.push(features(&s));
            out.labels.push(leg);
        }
    }
}

/// Runs `scenario` over `seeds` collecting labelled segments, trains on all but the last seed
/// with `rounds` stumps, scores on the last, and writes the model to `out` (JSON). Returns the
/// summary that was printed.
pub fn train(
    scenario: &Scenario,
    seeds: &[u64],
    rounds: usize,
    out: &Path,
    force: bool,
) -> Result<Value> {
    crate::output::check_file(out, force, is_model)?;
    if seeds.len() < 2 {
        bail!("train-legs needs at least two seeds: the last is held out for the score");
    }
    if scenario.movers.people.is_empty() && scenario.movers.flows.is_empty() {
        bail!(
            "{}: the scenario has no people ([[person]] or [[flow]]) to learn legs from",
            scenario.spec.name
        );
    }
    let Some((lidar, _)) = scenario.lidars.first() else {
        bail!("{}: the scenario has no [[lidar]]", scenario.spec.name);
    };
    let mut runs = Vec::new();
    for &seed in seeds {
        let samples = Rc::new(RefCell::new(Samples::default()));
        let collector = Collector {
            laser: lidar.name.clone(),
            mount: lidar.planar_mount(),
            height: lidar.xyz[2],
            config: LegConfig::default(),
            people: Vec::new(),
            scan: None,
            out: samples.clone(),
        };
        let opts = RunOptions {
            seed: Some(seed),
            duration: None,
            progress: false,
            report: false,
            force: false,
        };
        simulate_with(scenario, &opts, None, vec![Box::new(collector)])
            .with_context(|| format!("running {} with seed {seed}", scenario.spec.name))?;
        runs.push(std::mem::take(&mut *samples.borrow_mut()));
    }
    let (test, train) = runs.split_last().expect("two seeds or more");
    let mut x = Vec::new();
    let mut y = Vec::new();
    for r in train {
        x.extend_from_slice(&r.features);
        y.extend_from_slice(&r.labels);
    }
    if !y.iter().any(|&l| l) || y.iter().all(|&l| l) {
        bail!(
            "{}: the training runs saw {} leg segments of {}; a classifier needs both kinds",
            scenario.spec.name,
            y.iter().filter(|&&l| l).count(),
            y.len()
        );
    }
    let model = AdaBoost::train(&x, &y, rounds);
    let config = LegConfig::default();
    let score = |r: &Samples| {
        let (mut tp, mut fp, mut fneg) = (0usize, 0usize, 0usize);
        for (f, &l) in r.features.iter().zip(&r.labels) {
            let said = model.confidence(f) >= config.threshold;
            match (said, l) {
                (true, true) => tp += 1,
                (true, false) => fp += 1,
                (false, true) => fneg += 1,
                _ => {}
            }
        }
        let precision = tp as f64 / (tp + fp).max(1) as f64;
        let recall = tp as f64 / (tp + fneg).max(1) as f64;
        json!({
            "segments": r.labels.len(),
            "legs": r.labels.iter().filter(|&&l| l).count(),
            "precision": precision,
            "recall": recall,
        })
    };
    let training = json!({
        "segments": y.len(),
        "legs": y.iter().filter(|&&l| l).count(),
    });
    let summary = json!({
        "scenario": scenario.spec.name,
        "laser": {
            "name": lidar.name,
            "preset": lidar.preset.name(),
            "height_m": lidar.xyz[2],
        },
        "seeds": {"train": &seeds[..seeds.len() - 1], "held_out": seeds[seeds.len() - 1]},
        "rounds": rounds,
        "stumps": model.stumps.len(),
        "training": training,
        "held_out": score(test),
    });
    let file = json!({
        "what": "futago laser leg classifier: AdaBoost over decision stumps (Arras et al. 2007 features)",
        "features": FEATURE_NAMES,
        "trained": summary,
        "model": model,
    });
    let text = serde_json::to_string_pretty(&file)? + "\n";
    let tmp = out.with_extension("json.tmp");
    std::fs::write(&tmp, text).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, out).with_context(|| format!("writing {}", out.display()))?;
    Ok(summary)
}

/// A model file that [`train`] wrote (its `what`), which a new training may replace.
fn is_model(bytes: &[u8]) -> bool {
    serde_json::from_slice::<Value>(bytes).is_ok_and(|v| {
        v["what"]
            .as_str()
            .is_some_and(|w| w.starts_with("futago laser leg classifier"))
    })
}

/// `futago train-legs`: trains on `seeds` (default: the scenario's `seeds`; the last held
/// out) with `rounds` stumps, writes the model to `out` and prints its summary.
pub fn command(s: &Scenario, seeds: &[u64], rounds: usize, out: &Path, force: bool) -> Result<()> {
    let seeds = if seeds.is_empty() {
        s.spec.seeds.clone()
    } else {
        seeds.to_vec()
    };
    if !(1..=100_000).contains(&rounds) {
        bail!("--rounds {rounds}: expected 1 to 100000");
    }
    let summary = train(s, &seeds, rounds, out, force)?;
    println!("{}", serde_json::to_string_pretty(&summary)?);
    println!("model written to {}", out.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use crate::stack::people::{default_model, load_model};
    use futago_msgs::{LaserScan, Time};
    use futago_robot::perception::legs::{LegConfig, detect};

    /// A 0.35° scan over ±90° of one circle (a leg: radius `r` at `at`) before a wall at 4 m.
    fn scan(at: [f64; 2], r: f64) -> LaserScan {
        let inc = 0.35f64.to_radians();
        let n = (std::f64::consts::PI / inc) as usize;
        let ranges = (0..n)
            .map(|i| {
                let a = -std::f64::consts::FRAC_PI_2 + i as f64 * inc;
                let (dx, dy) = (a.cos(), a.sin());
                let wall = if dx > 0.2 { 4.0 / dx } else { f64::INFINITY };
                let b = -(at[0] * dx + at[1] * dy);
                let disc = b * b - (at[0] * at[0] + at[1] * at[1] - r * r);
                let leg = if disc >= 0.0 {
                    -b - disc.sqrt()
                } else {
                    f64::INFINITY
                };
                wall.min(leg) as f32
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
    fn the_shipped_model_tells_a_shin_from_a_wall() {
        let model = default_model().unwrap();
        // A 5 cm shin 2 m ahead, before a wall 4 m away: one leg, where the shin is.
        let legs = detect(&scan([2.0, 0.3], 0.05), &LegConfig::default(), &model);
        assert_eq!(legs.len(), 1, "{legs:?}");
        let p = legs[0].position;
        assert!(
            (p[0] - 1.97).abs() < 0.05 && (p[1] - 0.3).abs() < 0.05,
            "{p:?}"
        );
        // A pillar of 0.4 m radius is no leg.
        assert!(detect(&scan([2.0, 0.3], 0.4), &LegConfig::default(), &model).is_empty());
    }

    #[test]
    fn a_model_file_that_is_not_one_is_refused_by_key() {
        let e = load_model("{\"model\": {\"stumps\": []}}", "m.json").unwrap_err();
        assert!(e.to_string().contains("m.json: key `model`"), "{e}");
        let e = load_model("[", "m.json").unwrap_err();
        assert!(e.to_string().contains("not JSON"), "{e}");
        let bad = "{\"model\": {\"stumps\": [{\"feature\": 99, \"threshold\": 0.1, \"polarity\": 1.0, \"alpha\": 1.0}]}}";
        assert!(load_model(bad, "m.json").is_err());
    }
}
