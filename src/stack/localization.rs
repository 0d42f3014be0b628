//! The localiser node: Monte Carlo localisation on the world's occupancy grid at its laser's
//! height, updated at its rate from that laser's scans and carried by odometry in between.
//! Beams that end on a person the stack tracks (`people/tracked`) are left out
//! (`people.exclusion`). It publishes `pose/localization` and the map it was given
//! (`map/localization`), writes `localization.txt`, and scores its trajectory, its worst
//! recovery from a kidnapping and its convergence from a global start.

use super::{Bus, Node, Report, Streams, Trajectory, TrueState, Truth};
use super::{Nodes, StackModule, boxed};
use crate::ground_truth::Metrics;
use crate::scenario::{ModuleConfig, Resolving, Scenario, ScenarioSpec, Spec};
use anyhow::{Context, Result};
use futago_msgs::{Duration, LaserScan, Pose2, Time, wrap_angle};
use futago_robot::localization::covariance::{position_nees, position_sigma};
use futago_robot::localization::mcl::MclConfig;
use futago_robot::localization::mcl::{Mcl, MclMap};
use futago_robot::tracking::exclusion::{Exclusion, ExclusionConfig};
use futago_sim::config::{SpecError, check_range};
use futago_sim::noise::stream;
use serde::Deserialize;
use serde_json::{Value, json};
use std::any::Any;
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
    /// The estimate just published and its covariance, until the scorer measures it against
    /// the truth.
    unscored: Option<(Pose2, [[f64; 3]; 3])>,
    /// Per scored update: the filter's own position spread (the square root of the larger
    /// eigenvalue of its x, y covariance), m, and the normalised estimation error squared of
    /// its position (e' P⁻¹ e over x, y: 2 on average for a filter whose covariance is true).
    spread: Vec<(f64, Option<f64>)>,
    /// The estimates as TUM lines.
    track: Trajectory,
    /// Kidnapping times, s, and whether the filter starts globally.
    events: Vec<f64>,
    global: bool,
    map: Option<futago_msgs::grid::OccupancyGrid>,
    summary: Option<Value>,
    /// Cutting tracked people out of the scans (`people.exclusion`).
    exclusion: ExclusionConfig,
    /// Beams cut out so far.
    beams_excluded: u64,
    /// The particle set's size at each update: its sum and largest value (the filter's cost
    /// grows with it, and KLD-sampling decides it).
    particles_sum: u64,
    particles_max: usize,
}

/// The localiser when the scenario has `[localization]`.
pub fn node(s: &Scenario, seed: u64) -> Result<Option<LocalizationNode>> {
    use rand::Rng;
    let Some(spec) = s.module::<LocalizationSpec>() else {
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
        unscored: None,
        spread: Vec::new(),
        track: Trajectory::new("localization"),
        events: s.spec.event.iter().map(|e| e.time).collect(),
        global: spec.global,
        map: Some(grid),
        summary: None,
        exclusion: s.spec.people.exclusion,
        beams_excluded: 0,
        particles_sum: 0,
        particles_max: 0,
    }))
}

/// `localization.*` trajectory metrics, and its recovery and convergence times where the
/// scenario kidnaps the robot or starts globally.
fn metric_names(s: &ScenarioSpec, l: &LocalizationSpec) -> Vec<String> {
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

    /// The scans at its rate alone.
    fn wants_scan(&self, laser: &str, stamp: Time) -> bool {
        laser == self.laser && stamp >= self.next
    }

    fn on_scan(&mut self, laser: &str, scan: &LaserScan, bus: &mut Bus) -> Result<()> {
        if !self.wants_scan(laser, scan.stamp) {
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
        bus.publish_covariance("localization", est.covariance);
        self.updates += 1;
        self.particles_sum += est.particles as u64;
        self.particles_max = self.particles_max.max(est.particles);
        let now = bus.pose("localization").unwrap_or(est.pose);
        self.unscored = Some((now, est.covariance));
        self.track.push(bus.now, &now);
        Ok(())
    }

    fn observe(&mut self, truth: &TrueState, bus: &Bus) {
        if let Some((now, cov)) = self.unscored.take() {
            let e = [truth.robot.x - now.x, truth.robot.y - now.y];
            self.spread
                .push((position_sigma(&cov), position_nees(&cov, e)));
            self.errors.push((
                bus.now.secs(),
                now.distance(&truth.robot),
                wrap_angle(now.theta - truth.robot.theta).abs(),
            ));
        }
    }

    fn finish(&mut self, bus: &mut Bus, out: Option<&Path>) -> Result<Report> {
        let mut files = Vec::new();
        if let Some(dir) = out {
            self.track.write(dir, LOCALIZATION_FILE, "")?;
            files.push(LOCALIZATION_FILE.to_string());
        }
        let trajectories = vec![self.track.clone()];
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
            "mean_particles": self.particles_sum as f64 / self.updates.max(1) as f64,
            "max_particles": self.particles_max,
        });
        // The filter's own spread against its errors: how far a user may trust the
        // covariance it publishes (consumers size margins from it).
        if !self.spread.is_empty() {
            let k = self.spread.len() as f64;
            let nees: Vec<f64> = self.spread.iter().filter_map(|s| s.1).collect();
            let mut sorted = nees.clone();
            sorted.sort_by(f64::total_cmp);
            v["mean_sigma_m"] = json!(self.spread.iter().map(|s| s.0).sum::<f64>() / k);
            v["mean_position_nees"] = json!(nees.iter().sum::<f64>() / nees.len().max(1) as f64);
            v["median_position_nees"] = json!(sorted.get(sorted.len() / 2));
            // A position within two of its own standard deviations: 86 % of the time for
            // a Gaussian error in two dimensions whose covariance is the published one
            // (e' P⁻¹ e ≤ 4, χ² with 2 degrees of freedom).
            v["within_2_sigma"] =
                json!(nees.iter().filter(|n| **n <= 4.0).count() as f64 / nees.len().max(1) as f64);
        }
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
            crate::ground_truth::score_trajectory(truth, &self.track.name, &self.track.poses);
        for k in ["recovery_s", "convergence_s"] {
            if let Some(v) = self.summary.as_ref().and_then(|l| l[k].as_f64()) {
                m.insert(format!("localization.{k}"), v);
            }
        }
        Ok(m)
    }
}

/// The localiser of a run: MCL on the world's ground-truth occupancy grid at the first laser's
/// height (the map a perfect SLAM run would give).
#[derive(Debug, Clone, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct LocalizationSpec {
    /// The laser it localises with (by name; may be left out when the scenario has one).
    #[serde(default)]
    pub laser: Option<String>,
    /// Map cell size, m (seed 000: 50 mm).
    #[serde(default = "default_map_resolution")]
    pub map_resolution: f64,
    /// Filter updates per second (seed 000: 4).
    #[serde(default = "default_localization_rate")]
    pub rate: f64,
    /// Start knowing nothing (particles over the whole map) instead of near the start pose.
    #[serde(default)]
    pub global: bool,
    /// Spread of the initial particles around the start pose (m, m, rad).
    #[serde(default = "default_initial_sigma")]
    pub initial_sigma: [f64; 3],
    #[serde(default)]
    pub mcl: MclConfig,
}

fn default_map_resolution() -> f64 {
    0.05
}
fn default_localization_rate() -> f64 {
    4.0
}
fn default_initial_sigma() -> [f64; 3] {
    [0.2, 0.2, 0.1]
}

/// `[localization]`: Monte Carlo localisation on the world's map, from its laser's scans.
pub struct Module;

impl ModuleConfig for Module {
    fn key(&self) -> Option<&'static str> {
        Some("localization")
    }

    fn pose_topic(&self, _table: &toml::Value) -> Option<&'static str> {
        Some("localization")
    }

    fn pose_table(&self) -> Option<(&'static str, &'static str)> {
        Some(("localization", "[localization]"))
    }

    fn resolve(&self, cx: &Resolving<'_>, table: &toml::Value) -> Result<Spec, SpecError> {
        let mut l: LocalizationSpec = cx.typed("localization", cx.table("localization", table)?)?;
        if cx.lidars.is_empty() {
            return Err(cx.error(
                "localization",
                "Monte Carlo localisation needs a [[lidar]]; the scenario has none",
            ));
        }
        // The localiser reads its laser by the resolved name.
        l.laser = Some(cx.laser("localization", &l.laser)?);
        let path = cx.path;
        check_range(
            path,
            "localization.map_resolution",
            l.map_resolution,
            0.01,
            0.5,
            "m",
        )?;
        check_range(path, "localization.rate", l.rate, 0.1, 100.0, "Hz")?;
        for (k, v) in l.initial_sigma.iter().enumerate() {
            check_range(
                path,
                &format!("localization.initial_sigma[{k}]"),
                *v,
                0.0,
                100.0,
                "m or rad",
            )?;
        }
        l.mcl
            .validate("localization.mcl")
            .map_err(|(k, m)| cx.error(k, m))?;
        Ok(Box::new(l))
    }

    fn effective(&self, spec: &(dyn Any + Send + Sync)) -> Option<toml::Table> {
        toml::Table::try_from(spec.downcast_ref::<LocalizationSpec>()?).ok()
    }

    fn metric_names(
        &self,
        spec: &ScenarioSpec,
        own: Option<&(dyn Any + Send + Sync)>,
    ) -> Vec<String> {
        super::own::<LocalizationSpec>(own)
            .map(|l| metric_names(spec, l))
            .unwrap_or_default()
    }
}

impl StackModule for Module {
    fn build(&self, s: &Scenario, seed: u64, _out: Option<&Path>) -> Nodes {
        boxed(node(s, seed))
    }
}
