//! The driver node: a scripted controller or the navigator, whichever the scenario's
//! `[controller]` names. It publishes the drive command at every control tick.

use super::{Bus, Node, Report, Streams, Truth};
use crate::ground_truth::Metrics;
use crate::scenario::ControllerConfig;
use crate::scenario::{Scenario, ScenarioSpec};
use anyhow::{Context, Result};
use futago_msgs::{DriveCommand, Duration, LaserScan, Odometry, Pose2, Time};
use futago_robot::control::PoseSource;
use futago_robot::control::script::{ControlInput, ScriptedController};
use futago_robot::localization::odometry::OdometryIntegrator;
use futago_robot::navigation::{CoverConfig, NavInput, Navigator, RouteConfig, Task};
use futago_robot::tracking::people::TrackedPerson;
use serde_json::{Value, json};
use std::path::Path;

enum Driver {
    Scripted(ScriptedController),
    Navigator {
        nav: Box<Navigator>,
        /// Where the navigator's pose comes from: `None` drives on SLAM's.
        pose_source: Option<PoseSource>,
        odometry: OdometryIntegrator,
        last: Option<DriveCommand>,
    },
}

/// Drives the robot.
pub struct DriverNode {
    driver: Driver,
    /// The navigator's laser for obstacles: its name and mount.
    laser: Option<(String, Pose2)>,
    last_scan: Option<LaserScan>,
    /// The navigator plans on SLAM's map, taken at this period.
    map_period: Option<Duration>,
    map_seen: Option<Time>,
    /// Odometry reports since the last tick.
    pending: Vec<Odometry>,
    /// Return-to-start errors per lap of a waypoint list (seed 000, Fig. 2.8).
    laps: Vec<Value>,
    localizes: bool,
    /// A scripted controller that drives on SLAM's pose.
    scripted_on_slam: bool,
    /// How many goals a navigator was given (none for other drivers and for exploration).
    goals: Option<usize>,
    /// A route driver (`coverage`, `route`): the topic its routes come on (`path/TOPIC`), the
    /// stamp of the last route taken, and whether it has been driven to its end.
    route: Option<(String, Option<Time>, bool)>,
}

/// The height of the band of the world's map that goal and route navigation plan on: the
/// navigator's laser's (0.2 m without one).
pub fn navigation_height(s: &Scenario) -> f64 {
    s.driver_laser
        .as_ref()
        .and_then(|n| s.lidars.iter().find(|(c, _)| &c.name == n))
        .map_or(0.2, |(c, _)| c.xyz[2])
}

impl DriverNode {
    pub fn new(s: &Scenario) -> Result<DriverNode> {
        let spec = &s.spec;
        let navigation_map = || {
            super::world_map(s, spec.navigation.map_resolution, navigation_height(s))
                .context("navigation.map_resolution")
        };
        let driver = match &s.controller {
            ControllerConfig::Navigate(n) => Driver::Navigator {
                nav: Box::new(Navigator::new(
                    spec.navigation,
                    n.task(),
                    Some(navigation_map()?),
                )),
                pose_source: Some(n.pose_source),
                odometry: OdometryIntegrator::new(s.start),
                last: None,
            },
            // The routes come on `path/coverage` or `path/TOPIC`.
            ControllerConfig::Coverage(CoverConfig { pose_source })
            | ControllerConfig::Route(RouteConfig { pose_source, .. }) => Driver::Navigator {
                nav: Box::new(Navigator::new(
                    spec.navigation,
                    Task::Route(Vec::new()),
                    Some(navigation_map()?),
                )),
                pose_source: Some(*pose_source),
                odometry: OdometryIntegrator::new(s.start),
                last: None,
            },
            ControllerConfig::Explore(_) => Driver::Navigator {
                nav: Box::new(Navigator::new(spec.navigation, Task::Explore, None)),
                pose_source: None,
                odometry: OdometryIntegrator::new(s.start),
                last: None,
            },
            other => Driver::Scripted(ScriptedController::new(
                other.script().context("a scripted controller")?,
                Time::ZERO,
                s.start,
            )),
        };
        let navigates = matches!(driver, Driver::Navigator { .. });
        let laser = if navigates {
            s.driver_laser.as_ref().and_then(|n| {
                s.lidars
                    .iter()
                    .find(|(c, _)| &c.name == n)
                    .map(|(c, _)| (n.clone(), c.planar_mount()))
            })
        } else {
            None
        };
        Ok(DriverNode {
            map_period: matches!(s.controller, ControllerConfig::Explore(_))
                .then(|| Duration::from_secs(spec.navigation.replan_period / 2.0)),
            driver,
            laser,
            last_scan: None,
            map_seen: None,
            pending: Vec::new(),
            laps: Vec::new(),
            localizes: spec.module("localization").is_some()
                || spec.module("visual_localization").is_some(),
            scripted_on_slam: matches!(&s.controller, ControllerConfig::Waypoints(w) if w.pose_source == PoseSource::Slam),
            goals: match &s.controller {
                ControllerConfig::Navigate(n) => match n.task() {
                    Task::Goals(g) => Some(g.len()),
                    Task::Explore | Task::Route(_) => None,
                },
                _ => None,
            },
            route: match &s.controller {
                ControllerConfig::Coverage(_) => Some(("coverage".into(), None, false)),
                ControllerConfig::Route(r) => Some((r.topic.clone(), None, false)),
                _ => None,
            },
        })
    }
}

impl Node for DriverNode {
    fn name(&self) -> &'static str {
        "driver"
    }

    fn streams(&self) -> Streams {
        let mut consumes = vec!["odometry".to_string()];
        consumes.extend(self.laser.iter().map(|(n, _)| format!("scan/{n}")));
        if matches!(self.driver, Driver::Navigator { .. }) {
            consumes.push("people/tracked".into());
        }
        if let Some((topic, ..)) = &self.route {
            consumes.push(format!("path/{topic}"));
        }
        let mut periods = Vec::new();
        match &self.driver {
            Driver::Navigator {
                pose_source: None, ..
            } => {
                consumes.push("pose/slam".into());
                consumes.push("map/slam".into());
                periods.extend(self.map_period.map(|p| ("map/slam".to_string(), p)));
            }
            Driver::Navigator {
                pose_source: Some(PoseSource::Localization),
                ..
            } => consumes.push("pose/localization".into()),
            Driver::Navigator {
                pose_source: Some(PoseSource::Slam),
                ..
            } => consumes.push("pose/slam".into()),
            Driver::Scripted(_) if self.localizes => consumes.push("pose/localization".into()),
            Driver::Scripted(_) if self.scripted_on_slam => consumes.push("pose/slam".into()),
            _ => {}
        }
        Streams {
            consumes,
            publishes: vec!["cmd_vel".into()],
            periods,
        }
    }

    fn on_odometry(&mut self, o: &Odometry, _bus: &mut Bus) -> Result<()> {
        self.pending.push(*o);
        Ok(())
    }

    fn on_scan(&mut self, laser: &str, scan: &LaserScan, _bus: &mut Bus) -> Result<()> {
        if self.laser.as_ref().is_some_and(|(n, _)| n == laser) {
            self.last_scan = Some(scan.clone());
        }
        Ok(())
    }

    fn on_control(&mut self, bus: &mut Bus) -> Result<()> {
        let localization = bus.pose("localization");
        let input = ControlInput {
            now: bus.now,
            odometry: &self.pending,
            bumps: bus.bumps,
            ground_truth: Some(bus.truth),
            localization,
            slam: bus.pose("slam"),
        };
        let cmd = match &mut self.driver {
            Driver::Scripted(c) => c.update(&input),
            Driver::Navigator {
                nav,
                pose_source,
                odometry,
                last,
            } => {
                for o in input.odometry {
                    odometry.integrate(o);
                }
                // A new route to drive.
                if let Some((topic, seen, done)) = &mut self.route
                    && let Some((t, points)) = bus.path(topic)
                    && seen.is_none_or(|s| t > s)
                {
                    *seen = Some(t);
                    *done = false;
                    nav.set_route(points.to_vec());
                }
                let pose = match pose_source {
                    Some(PoseSource::GroundTruth) => input.ground_truth,
                    Some(PoseSource::Localization) => input.localization,
                    Some(PoseSource::Odometry) => Some(odometry.pose),
                    Some(PoseSource::Slam) => input.slam,
                    None => bus.pose("slam"),
                }
                .unwrap_or(odometry.pose);
                // A newer map than the last one taken, when the explorer plans on one.
                let map = bus
                    .map("slam")
                    .filter(|(t, _)| self.map_seen.is_none_or(|seen| *t > seen));
                if let Some((t, _)) = map {
                    self.map_seen = Some(t);
                }
                // The tracked people, from the base's frame into the navigator's.
                let (c, s) = (pose.theta.cos(), pose.theta.sin());
                let people: Vec<TrackedPerson> = bus
                    .people_tracked
                    .iter()
                    .map(|p| TrackedPerson {
                        id: p.id,
                        position: pose.transform_point(p.position),
                        velocity: [
                            c * p.velocity[0] - s * p.velocity[1],
                            s * p.velocity[0] + c * p.velocity[1],
                        ],
                    })
                    .collect();
                let cmd = nav.update(&NavInput {
                    now: input.now,
                    pose,
                    bumps: input.bumps,
                    scan: self
                        .last_scan
                        .as_ref()
                        .zip(self.laser.as_ref().map(|l| l.1)),
                    map: map.map(|(_, m)| m.as_ref()),
                    people: &people,
                });
                (*last != Some(cmd)).then(|| {
                    *last = Some(cmd);
                    cmd
                })
            }
        };
        self.pending.clear();
        bus.command = cmd;
        if let (Some((_, _, done)), Driver::Navigator { nav, .. }) = (&mut self.route, &self.driver)
            && !*done
            && nav.finished()
        {
            *done = true;
            bus.route_done = Some(bus.now);
        }
        if let Driver::Scripted(c) = &self.driver
            && c.laps_completed() > self.laps.len()
        {
            self.laps.push(json!({
                "lap": self.laps.len() + 1,
                "time_s": bus.now.secs(),
                "odometry_error_m": bus.odometry.distance(&bus.truth),
                "localization_error_m": localization.map(|l| l.distance(&bus.truth)),
            }));
        }
        Ok(())
    }

    fn finished(&self) -> bool {
        match &self.driver {
            Driver::Scripted(c) => c.finished(),
            Driver::Navigator { nav, .. } => nav.finished(),
        }
    }

    fn finish(&mut self, _bus: &mut Bus, _out: Option<&Path>) -> Result<Report> {
        let mut summary = vec![
            ("controller_finished".to_string(), json!(self.finished())),
            ("laps".to_string(), json!(self.laps)),
        ];
        if let Driver::Navigator { nav, .. } = &self.driver {
            summary.push((
                "navigation".into(),
                json!({ "stats": nav.stats(), "roadmap_nodes": nav.roadmap_nodes() }),
            ));
        }
        Ok(Report {
            summary,
            ..Report::default()
        })
    }

    fn score(&self, _truth: &Truth) -> Result<Metrics> {
        let mut m = Metrics::default();
        if let (Some(goals), Driver::Navigator { nav, .. }) = (self.goals, &self.driver) {
            m.insert(
                "navigation.goals_missed",
                goals.saturating_sub(nav.stats().goals_reached) as f64,
            );
        }
        Ok(m)
    }
}

/// `navigation.goals_missed` (goals a navigator did not reach) where it is given goals.
pub fn metric_names(s: &ScenarioSpec) -> Vec<String> {
    if s.controller.get("type").and_then(|t| t.as_str()) == Some("navigate") {
        vec!["navigation.goals_missed".into()]
    } else {
        Vec::new()
    }
}

/// The driver: the controller that publishes the drive commands.
pub const MODULE: super::Plain = super::Plain {
    metric_names,
    build: |s, _, _| Ok(vec![Box::new(DriverNode::new(s)?) as Box<dyn Node>]),
};
