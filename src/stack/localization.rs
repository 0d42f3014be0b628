//! The localiser node: Monte Carlo localisation on the world's occupancy grid at its laser's
//! height, updated at its rate from that laser's scans and carried by odometry in between.
//! Beams that end on a person the stack tracks (`people/tracked`) are left out
//! (`people.exclusion`). It publishes `pose/localization` and the map it was given
//! (`map/localization`), writes `localization.txt`, and scores its trajectory, its worst
//! recovery from a kidnapping and its convergence from a global start.

use super::{Bus, Node, Report, Streams, Truth, tum_line};
use crate::ground_truth::Metrics;
use crate::scenario::{Scenario, ScenarioSpec};
use anyhow::{Context, Result};
use futago_msgs::{Duration, LaserScan, Pose2, Time, wrap_angle};
use futago_robot::localization::mcl::{Mcl, MclMap};
use futago_robot::tracking::exclusion::{Exclusion, ExclusionConfig};
use futago_sim::noise::stream;
use serde_json::{Value, json};
use std::path::Path;

/// The localiser's estimates (TUM), at each update.
pub const LOCALIZATION_FILE: &str = "localization.txt";

use crate::ground_truth::trajectory::{
    RECOVERED_HOLD_S, RECOVERED_M, recovery_times, worst_recovery,
};

/// MCL in the loop.
pub struct LocalizationNode {
    mcl: Mcl,
    laser: String,
    mount: Pose2,
    period: Duration,
    next: Time,
    updates: u64,
    /// (time s, position error m, heading error rad) at each update.
    errors: Vec<(f64, f64, f64)>,
    /// The estimates as TUM lines.
    lines: String,
    /// Kidnapping times, s, and whether the filter starts globally.
    events: Vec<f64>,
    global: bool,
    map: Option<futago_msgs::grid::OccupancyGrid>,
    summary: Option<Value>,
    /// Cutting tracked people out of the scans (`people.exclusion`).
    exclusion: ExclusionConfig,
    /// Beams cut out so far.
    beams_excluded: u64,
}

/// The localiser when the scenario has `[localization]`.
pub fn node(s: &Scenario, seed: u64) -> Result<Option<LocalizationNode>> {
    use rand::Rng;
    let Some(spec) = &s.spec.localization else {
        return Ok(None);
    };
    let (cfg, _) = super::laser(s, spec.laser.as_deref()).context("localization.laser")?;
    let grid = super::world_map(s, spec.map_resolution, cfg.xyz[2])
        .context("localization.map_resolution")?;
    let mut mcl = Mcl::new(
        spec.mcl,
        MclMap::new(grid.clone()),
        stream(seed, "localization.mcl").random(),
    );
    if !spec.global {
        mcl.set_pose(s.start, spec.initial_sigma);
    }
    Ok(Some(LocalizationNode {
        mcl,
        laser: cfg.name.clone(),
        mount: cfg.planar_mount(),
        period: Duration::from_secs(1.0 / spec.rate),
        next: Time::ZERO,
        updates: 0,
        errors: Vec::new(),
        lines: String::new(),
        events: s.spec.event.iter().map(|e| e.time).collect(),
        global: spec.global,
        map: Some(grid),
        summary: None,
        exclusion: s.spec.people.exclusion,
        beams_excluded: 0,
    }))
}

/// `localization.*` trajectory metrics, and its recovery and convergence times where the
/// scenario kidnaps the robot or starts globally.
pub fn metric_names(s: &ScenarioSpec) -> Vec<String> {
    let Some(l) = &s.localization else {
        return Vec::new();
    };
    let mut names = crate::ground_truth::trajectory_metric_names("localization");
    if !s.event.is_empty() {
        names.push("localization.recovery_s".into());
    }
    if l.global {
        names.push("localization.convergence_s".into());
    }
    names
}

impl LocalizationNode {
    /// (time s, position error m) at each update.
    fn position_errors(&self) -> Vec<(f64, f64)> {
        self.errors.iter().map(|e| (e.0, e.1)).collect()
    }
}

impl Node for LocalizationNode {
    fn name(&self) -> &'static str {
        "localization"
    }

    fn streams(&self) -> Streams {
        let mut consumes = vec![format!("scan/{}", self.laser), "odometry".into()];
        if self.exclusion.enabled {
            consumes.push("people/tracked".into());
        }
        Streams {
            consumes,
            publishes: vec!["pose/localization".into(), "map/localization".into()],
            ..Streams::default()
        }
    }

    fn start(&mut self, bus: &mut Bus) -> Result<()> {
        if let Some(map) = self.map.take() {
            bus.publish_map("localization", map);
        }
        Ok(())
    }

    fn on_scan(&mut self, laser: &str, scan: &LaserScan, bus: &mut Bus) -> Result<()> {
        if laser != self.laser || scan.stamp < self.next {
            return Ok(());
        }
        self.next = scan.stamp + self.period;
        let at = bus.odometry_at(scan.stamp);
        // The tracked people (published for this scan) are left out of the likelihood.
        let masked = Exclusion::new(&self.exclusion, bus.people_now()).mask_scan(scan, &self.mount);
        let scan = match &masked {
            Some((m, cut)) => {
                self.beams_excluded += *cut as u64;
                m
            }
            None => scan,
        };
        let est = self.mcl.update(&at, scan, &self.mount);
        bus.publish_pose("localization", est.pose, at);
        self.updates += 1;
        let now = bus.pose("localization").unwrap_or(est.pose);
        self.errors.push((
            bus.now.secs(),
            now.distance(&bus.truth),
            wrap_angle(now.theta - bus.truth.theta).abs(),
        ));
        tum_line(&mut self.lines, bus.now, &now);
        Ok(())
    }

    fn finish(&mut self, bus: &mut Bus, out: Option<&Path>) -> Result<Report> {
        let (mut files, mut trajectories) = (Vec::new(), Vec::new());
        if let Some(dir) = out {
            std::fs::write(dir.join(LOCALIZATION_FILE), &self.lines)
                .with_context(|| format!("writing {LOCALIZATION_FILE}"))?;
            files.push(LOCALIZATION_FILE.to_string());
            trajectories.push(("localization".to_string(), LOCALIZATION_FILE.to_string()));
        }
        let l = &self.errors;
        let n = l.len().max(1) as f64;
        let end = bus.now.secs();
        let mut v = json!({
            "updates": self.updates,
            "mean_position_error_m": l.iter().map(|e| e.1).sum::<f64>() / n,
            "max_position_error_m": l.iter().map(|e| e.1).fold(0.0, f64::max),
            "final_position_error_m": l.last().map(|e| e.1),
            "mean_heading_error_deg": l.iter().map(|e| e.2).sum::<f64>() / n * 180.0 / std::f64::consts::PI,
            "beams_excluded": self.beams_excluded,
        });
        if !self.events.is_empty() {
            v["kidnappings"] =
                json!(self.events.iter().zip(recovery_times(&self.position_errors(), &self.events)).map(|(t, r)| json!({
                "time_s": t,
                "recovered_after_s": r,
                "recovered_when": format!("error < {RECOVERED_M} m for {RECOVERED_HOLD_S} s"),
            })).collect::<Vec<_>>());
            v["recovery_s"] = json!(worst_recovery(&self.position_errors(), &self.events, end));
        }
        if self.global {
            v["convergence_s"] = json!(worst_recovery(&self.position_errors(), &[0.0], end));
        }
        self.summary = Some(v.clone());
        Ok(Report {
            summary: vec![("localization".into(), v)],
            files,
            trajectories,
            ..Report::default()
        })
    }

    fn score(&self, truth: &Truth) -> Result<Metrics> {
        let mut m =
            crate::ground_truth::score_trajectory(truth, "localization", LOCALIZATION_FILE)?;
        for k in ["recovery_s", "convergence_s"] {
            if let Some(v) = self.summary.as_ref().and_then(|l| l[k].as_f64()) {
                m.insert(format!("localization.{k}"), v);
            }
        }
        Ok(m)
    }
}
