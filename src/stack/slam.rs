//! The SLAM node: laser SLAM on one named laser's scans, less the beams that end on a person
//! the stack tracks (`people/tracked`, cut out by `people.exclusion`). It publishes
//! `pose/slam` (the start pose until its first scan), `map/slam` at the period a consumer
//! asks for and once more at the end, writes its trajectory and map, and scores both against
//! the truth; in a world with people, also the share of the map that is people
//! (`slam.map.people_pollution`, see `ground_truth::pollution`).

use super::{Bus, Node, Report, Streams, Trajectory, TrueState, Truth};
use super::{Nodes, StackModule, boxed};
use crate::ground_truth::Metrics;
use crate::ground_truth::pollution::PeoplePaths;
use crate::scenario::{ModuleConfig, Resolving, Scenario, ScenarioSpec, Spec};
use anyhow::{Context, Result};
use futago_msgs::grid::OccupancyGrid;
use futago_msgs::{LaserScan, Pose2, Time, wrap_angle};
use futago_robot::mapping::slam::Slam;
use futago_robot::mapping::slam::SlamConfig;
use futago_robot::tracking::exclusion::{Exclusion, ExclusionConfig};
use futago_sim::config::SpecError;
use serde_json::json;
use std::any::Any;
use std::path::Path;

/// SLAM's trajectory (TUM, every scan of its laser, as optimised at the end).
pub const SLAM_TRAJECTORY_FILE: &str = "slam_trajectory.txt";
/// SLAM's map (`slam_map.pgm` + `slam_map.yaml`).
pub const SLAM_MAP_STEM: &str = "slam_map";

/// Laser SLAM in the loop.
pub struct SlamNode {
    slam: Slam,
    laser: String,
    height: f64,
    mount: Pose2,
    /// Odometry pose at the last scan SLAM processed.
    at: Pose2,
    /// (position error m, heading error rad) at each scan.
    errors: Vec<(f64, f64)>,
    /// The pose of the update just made, until the scorer measures it against the truth.
    unscored: Option<Pose2>,
    /// The optimised trajectory, at the end.
    track: Trajectory,
    /// When a map was last published.
    last_map: Option<Time>,
    name: String,
    /// The final map, kept for scoring.
    map: Option<OccupancyGrid>,
    exclusion: ExclusionConfig,
    beams_excluded: u64,
    /// Where the world's people walked (truth, for scoring); `None` in a world without.
    paths: Option<PeoplePaths>,
}

/// SLAM when the scenario has `[slam]`.
pub fn node(s: &Scenario) -> Result<Option<SlamNode>> {
    let Some(spec) = s.module::<SlamSpec>() else {
        return Ok(None);
    };
    let (cfg, _) = super::laser(s, spec.laser.as_deref()).context("slam.laser")?;
    Ok(Some(SlamNode {
        slam: Slam::new(spec.config, s.start),
        laser: cfg.name.clone(),
        height: cfg.xyz[2],
        mount: cfg.planar_mount(),
        at: s.start,
        errors: Vec::new(),
        unscored: None,
        track: Trajectory::default(),
        last_map: None,
        name: s.spec.name.clone(),
        map: None,
        exclusion: s.spec.people.exclusion,
        beams_excluded: 0,
        paths: s.spec.has_people().then(PeoplePaths::default),
    }))
}

/// `slam.*` trajectory metrics and `slam.map.*` (the map against the world's grid).
fn metric_names(s: &ScenarioSpec) -> Vec<String> {
    let mut names = crate::ground_truth::trajectory_metric_names("slam");
    names.extend(crate::ground_truth::map_metric_names("slam.map"));
    if s.has_people() {
        names.push("slam.map.people_pollution".into());
    }
    names
}

/// Area of a grid's known cells, m².
fn known_area(g: &OccupancyGrid) -> f64 {
    g.cells.iter().filter(|&&c| c >= 0).count() as f64 * g.resolution * g.resolution
}

impl Node for SlamNode {
    fn name(&self) -> &'static str {
        "slam"
    }

    fn streams(&self) -> Streams {
        let mut consumes = vec![format!("scan/{}", self.laser), "odometry".into()];
        if self.exclusion.enabled {
            consumes.push("people/tracked".into());
        }
        if self.paths.is_some() {
            consumes.push("truth".into());
        }
        Streams {
            consumes,
            publishes: vec!["pose/slam".into(), "map/slam".into()],
            ..Streams::default()
        }
    }

    fn on_truth(&mut self, truth: &TrueState, _bus: &mut Bus) -> Result<()> {
        if let Some(p) = &mut self.paths {
            p.add(&truth.people);
        }
        Ok(())
    }

    fn start(&mut self, bus: &mut Bus) -> Result<()> {
        bus.publish_pose("slam", self.slam.pose(), self.at);
        Ok(())
    }

    fn observe(&mut self, truth: &TrueState, _bus: &Bus) {
        if let Some(pose) = self.unscored.take() {
            self.errors.push((
                pose.distance(&truth.robot),
                wrap_angle(pose.theta - truth.robot.theta).abs(),
            ));
        }
    }

    fn on_scan(&mut self, laser: &str, scan: &LaserScan, bus: &mut Bus) -> Result<()> {
        if laser != self.laser {
            return Ok(());
        }
        let at = bus.odometry_at(scan.stamp);
        let masked = Exclusion::new(&self.exclusion, bus.people_now()).mask_scan(scan, &self.mount);
        let scan = match &masked {
            Some((m, cut)) => {
                self.beams_excluded += *cut as u64;
                m
            }
            None => scan,
        };
        let u = self.slam.update(scan, &at, &self.mount);
        self.at = at;
        bus.publish_pose("slam", self.slam.pose(), at);
        self.unscored = Some(u.pose);
        // A planner that plans on the map gets a fresh copy at the period it asked for.
        if let Some(period) = bus.subscription("map/slam") {
            let due = match (self.last_map, period) {
                (None, _) | (_, None) => true,
                (Some(t), Some(p)) => bus.now - t >= p,
            };
            if due {
                self.last_map = Some(bus.now);
                bus.publish_map("slam", self.slam.grid().to_grid());
            }
        }
        Ok(())
    }

    fn finish(&mut self, bus: &mut Bus, out: Option<&Path>) -> Result<Report> {
        self.slam.finish();
        let e = &self.errors;
        let n = e.len().max(1) as f64;
        let grid = self.slam.grid().to_grid();
        let summary = json!({
            "method": format!("{:?}", self.slam.config().method).to_lowercase(),
            "keyframes": self.slam.keyframes(),
            "loop_closures": self.slam.loop_closures(),
            "optimizations": self.slam.optimizations(),
            "unmatched_scans": self.slam.unmatched(),
            "skipped_scans": self.slam.skipped(),
            "online_mean_position_error_m": e.iter().map(|e| e.0).sum::<f64>() / n,
            "online_max_position_error_m": e.iter().map(|e| e.0).fold(0.0, f64::max),
            "online_mean_heading_error_deg": e.iter().map(|e| e.1).sum::<f64>() / n * 180.0 / std::f64::consts::PI,
            "map_known_area_m2": known_area(&grid),
            "beams_excluded": self.beams_excluded,
        });
        let mut files = Vec::new();
        let mut track = Trajectory::new("slam");
        for (t, p) in self.slam.trajectory() {
            track.push(t, &p);
        }
        if let Some(dir) = out {
            let header = format!(
                "# futago SLAM of {} (laser `{}`), optimised at the end\n# timestamp tx ty tz qx qy qz qw\n",
                self.name, self.laser
            );
            track.write(dir, SLAM_TRAJECTORY_FILE, &header)?;
            grid.write_map_server(dir, SLAM_MAP_STEM)
                .with_context(|| format!("writing {SLAM_MAP_STEM}.pgm and .yaml"))?;
            files.extend([
                SLAM_TRAJECTORY_FILE.to_string(),
                format!("{SLAM_MAP_STEM}.pgm"),
                format!("{SLAM_MAP_STEM}.yaml"),
            ]);
        }
        bus.publish_map("slam", grid.clone());
        self.map = Some(grid.clone());
        self.track = track;
        Ok(Report {
            summary: vec![("slam".into(), summary)],
            files,
            map: Some(grid),
            trajectories: vec![self.track.clone()],
            ..Report::default()
        })
    }

    fn score(&self, truth: &Truth) -> Result<Metrics> {
        let mut m = crate::ground_truth::score_trajectory(truth, "slam", &self.track.poses);
        if let Some(map) = &self.map {
            let world = truth.world_map(map.resolution, self.height)?;
            let s = truth.scenario.start;
            let score = crate::ground_truth::map::score(map, &world, [s.x, s.y])
                .map_err(|e| anyhow::anyhow!("scoring the SLAM map: {e}"))?;
            m.insert_map("slam.map", &score);
            if let Some(p) = &self.paths {
                m.insert(
                    "slam.map.people_pollution",
                    p.grid_share(map, &world).unwrap_or(0.0),
                );
            }
        }
        Ok(m)
    }
}

/// `[slam]`: `laser` (the name of the laser it maps with) and SLAM's own keys.
#[derive(Debug, Clone, PartialEq)]
pub struct SlamSpec {
    pub laser: Option<String>,
    pub config: SlamConfig,
}

/// `[slam]`: laser SLAM in the loop, from its laser's scans.
pub struct Module;

impl ModuleConfig for Module {
    fn key(&self) -> Option<&'static str> {
        Some("slam")
    }

    fn pose_topic(&self, _table: &toml::Value) -> Option<&'static str> {
        Some("slam")
    }

    fn pose_table(&self) -> Option<(&'static str, &'static str)> {
        Some(("slam", "[slam]"))
    }

    /// `laser` and SLAM's keys ([`SlamConfig`]), naming `slam.KEY` in errors.
    fn resolve(&self, cx: &Resolving<'_>, table: &toml::Value) -> Result<Spec, SpecError> {
        let mut rest = cx.table("slam", table)?;
        let laser = cx.take_name("slam", "laser", &mut rest)?;
        let config: SlamConfig = cx.typed("slam", rest)?;
        config.validate().map_err(|(k, m)| cx.error(k, m))?;
        if cx.lidars.is_empty() {
            return Err(cx.error(
                "slam",
                "laser SLAM needs a [[lidar]]; the scenario has none",
            ));
        }
        let laser = Some(cx.laser("slam", &laser)?);
        Ok(Box::new(SlamSpec { laser, config }))
    }

    fn effective(&self, spec: &(dyn Any + Send + Sync)) -> Option<toml::Table> {
        let s = spec.downcast_ref::<SlamSpec>()?;
        let mut m = toml::Table::try_from(s.config).unwrap_or_default();
        m.extend(
            s.laser
                .clone()
                .map(|v| ("laser".to_string(), toml::Value::String(v))),
        );
        Some(m)
    }

    fn metric_names(
        &self,
        spec: &ScenarioSpec,
        own: Option<&(dyn Any + Send + Sync)>,
    ) -> Vec<String> {
        if own.is_none() {
            return Vec::new();
        }
        metric_names(spec)
    }
}

impl StackModule for Module {
    fn build(&self, s: &Scenario, _seed: u64, _out: Option<&Path>) -> Nodes {
        boxed(node(s))
    }
}
