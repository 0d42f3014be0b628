//! The driver node: a scripted controller or the navigator, whichever the scenario's
//! `[controller]` names. It publishes the drive command at every control tick.

use super::bus::{GROUND_TRUTH, pose_topic};
use super::{Bus, Node, Report, Streams, Truth};
use crate::ground_truth::{Metrics, TrueState};
use crate::scenario::{ModuleConfig, Resolving, Scenario, ScenarioSpec, Spec};
use anyhow::{Context, Result};
use futago_msgs::{DriveCommand, Duration, LaserScan, Odometry, Pose2, Time};
use futago_robot::control::PoseSource;
use futago_robot::control::script::{ControlInput, ScriptedController};
use futago_robot::control::script::{Script, SegmentsConfig, WaypointConfig};
use futago_robot::localization::odometry::OdometryIntegrator;
use futago_robot::navigation::{CoverConfig, NavInput, Navigator, RouteConfig, Task};
use futago_robot::navigation::{ExploreConfig, NavigateConfig};
use futago_robot::tracking::people::TrackedPerson;
use futago_sim::config::SpecError;
use serde_json::{Value, json};
use std::any::Any;
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
    /// The scans it takes are `navigation.scan_rate`'s period apart: the next is the first
    /// stamped at or after `next_scan`.
    scan_period: Duration,
    next_scan: Time,
    last_scan: Option<LaserScan>,
    /// The navigator plans on SLAM's map, taken at this period.
    map_period: Option<Duration>,
    map_seen: Option<Time>,
    /// Odometry reports since the last tick.
    pending: Vec<Odometry>,
    /// Return-to-start errors per lap of a waypoint list (seed 000, Fig. 2.8).
    laps: Vec<Value>,
    /// The odometry and localisation poses at a lap's end, until the scorer sees the truth.
    lap_ended: Option<(Pose2, Option<Pose2>)>,
    localizes: bool,
    /// The pose source of a scripted waypoint list (none for other scripts).
    scripted_source: Option<PoseSource>,
    /// How many goals a navigator was given (none for other drivers and for exploration).
    goals: Option<usize>,
    /// A route driver (`coverage`, `route`): the topic its routes come on (`path/TOPIC`), the
    /// stamp of the last route taken, and whether it has been driven to its end.
    route: Option<(String, Option<Time>, bool)>,
}

/// The height of the band of the world's map that goal and route navigation plan on: the
/// navigator's laser's (0.2 m without one).
pub fn navigation_height(s: &Scenario) -> f64 {
    driver_laser(s)
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
        let driver = match controller(s) {
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
            driver_laser(s).and_then(|n| {
                s.lidars
                    .iter()
                    .find(|(c, _)| &c.name == n)
                    .map(|(c, _)| (n.clone(), c.planar_mount()))
            })
        } else {
            None
        };
        Ok(DriverNode {
            map_period: matches!(controller(s), ControllerConfig::Explore(_))
                .then(|| Duration::from_secs(spec.navigation.replan_period / 2.0)),
            driver,
            laser,
            // Among walking people the obstacle check reads every scan: a person walking at
            // 1.4 m/s towards the robot at 0.3 m/s closes 17 cm in the 0.1 s between scans
            // at 10 Hz, more than `stop_distance`. (At 10 Hz, corridor-scan3d's seed 3 was
            // off its survey's length by 2.8 m.)
            scan_period: if super::people::tracks_people(s) {
                Duration::from_secs(0.0)
            } else {
                Duration::from_secs(1.0 / spec.navigation.scan_rate)
            },
            next_scan: Time::ZERO,
            last_scan: None,
            map_seen: None,
            pending: Vec::new(),
            laps: Vec::new(),
            lap_ended: None,
            localizes: spec.module("localization").is_some()
                || spec.module("visual_localization").is_some(),
            scripted_source: match controller(s) {
                ControllerConfig::Waypoints(w) => Some(w.pose_source),
                _ => None,
            },
            goals: match controller(s) {
                ControllerConfig::Navigate(n) => match n.task() {
                    Task::Goals(g) => Some(g.len()),
                    Task::Explore | Task::Route(_) => None,
                },
                _ => None,
            },
            route: match controller(s) {
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
                pose_source: Some(source),
                ..
            } => consumes.extend(pose_topic(*source)),
            Driver::Scripted(_) => {
                if self.localizes {
                    consumes.push("pose/localization".into());
                }
                consumes.extend(
                    self.scripted_source
                        .filter(|s| *s != PoseSource::Localization)
                        .and_then(pose_topic),
                );
            }
        }
        let mut publishes = vec!["cmd_vel".to_string()];
        if self.route.is_some() {
            publishes.push(super::bus::ROUTE_DONE.into());
        }
        Streams {
            consumes,
            publishes,
            periods,
        }
    }

    fn on_odometry(&mut self, o: &Odometry, _bus: &mut Bus) -> Result<()> {
        self.pending.push(*o);
        Ok(())
    }

    /// The scans at `navigation.scan_rate`.
    fn wants_scan(&self, laser: &str, stamp: Time) -> bool {
        self.laser.as_ref().is_some_and(|(n, _)| n == laser) && stamp >= self.next_scan
    }

    /// Takes the scans it wants alone, not every scan made for another node: what it sees
    /// does not hang on whether a recorder is on.
    fn on_scan(&mut self, laser: &str, scan: &LaserScan, _bus: &mut Bus) -> Result<()> {
        if self.wants_scan(laser, scan.stamp) {
            self.next_scan = scan.stamp + self.scan_period;
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
            ground_truth: bus.pose(GROUND_TRUTH),
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
            // Scored against the truth when the scorer observes this tick.
            self.lap_ended = Some((bus.odometry, localization));
            self.laps.push(json!({
                "lap": self.laps.len() + 1,
                "time_s": bus.now.secs(),
            }));
        }
        Ok(())
    }

    fn observe(&mut self, truth: &TrueState, _bus: &Bus) {
        if let (Some((odometry, localization)), Some(lap)) =
            (self.lap_ended.take(), self.laps.last_mut())
        {
            lap["odometry_error_m"] = json!(odometry.distance(&truth.robot));
            lap["localization_error_m"] = json!(localization.map(|l| l.distance(&truth.robot)));
        }
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
    match controller_type(s) {
        Some("navigate") => vec!["navigation.goals_missed".into()],
        // The user's estimates the link scores, where the table names their topics.
        Some("external") => {
            let table = s.module("controller");
            let has = |k: &str| table.and_then(|t| t.get(k)).is_some();
            let mut names = Vec::new();
            let from_tf = table
                .and_then(|t| t.get("pose_from_tf"))
                .and_then(toml::Value::as_bool)
                .unwrap_or(false);
            if has("pose_topic") || from_tf {
                names.extend(crate::ground_truth::trajectory_metric_names(EXTERNAL));
            }
            if has("map_topic") {
                names.extend(crate::ground_truth::map_metric_names(&format!(
                    "{EXTERNAL}.map"
                )));
            }
            names
        }
        _ => Vec::new(),
    }
}

/// The name under which a user's stack's estimates are scored (`external.ate.mean_m`).
pub const EXTERNAL: &str = "external";

/// What drives the robot, as a scenario's `[controller]` table declares it, selected by its
/// `type` key: a scripted plan ([`Script`]) or the navigator.
#[derive(Debug, Clone, PartialEq)]
pub enum ControllerConfig {
    /// Stand still.
    Idle,
    Segments(SegmentsConfig),
    /// Follow waypoints.
    Waypoints(WaypointConfig),
    /// Navigate to goals on the known map ([`futago_robot::navigation`]).
    Navigate(NavigateConfig),
    /// Explore an unknown world with SLAM ([`futago_robot::navigation`]).
    Explore(ExploreConfig),
    /// Drive a coverage route planned on the known map
    /// ([`futago_robot::navigation::coverage`], parameters in `[coverage]`).
    Coverage(CoverConfig),
    /// Drive the routes a stack node publishes ([`futago_robot::navigation::RouteConfig`]).
    Route(RouteConfig),
    /// Commands from outside the stack: a user's ROS 2 stack over `futago serve`'s link
    /// ([`crate::serve`]); no driver node runs.
    External(ExternalConfig),
}

/// A command line: a string for `sh -c`, or the program and its arguments.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(untagged)]
pub enum StackCommand {
    Shell(String),
    Argv(Vec<String>),
}

/// `[controller] type = "external"`: a user's ROS 2 stack drives the robot over the link
/// (`crate::serve`). With `command`, `futago run`, `suite` and `tune` start that stack for
/// each run (in the scenario's folder, with `ROS_DOMAIN_ID` set to the run's domain) and stop
/// it after; without, only `futago serve` runs the scenario, and the user starts the stack.
/// The other keys are the link's options, as `futago serve`'s flags of the same names, which
/// override them.
#[derive(Debug, Clone, Default, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct ExternalConfig {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub command: Option<StackCommand>,
    /// The DDS domain; unset, a started stack gets a free one of 100 to 232.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub domain: Option<i32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub timeout: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wait: Option<f64>,
    #[serde(default)]
    pub stamped: bool,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub period: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_rate: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_scale: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pose_topic: Option<String>,
    #[serde(default)]
    pub pose_from_tf: bool,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub map_topic: Option<String>,
    /// The folder the command runs in: the scenario file's.
    #[serde(skip)]
    pub dir: std::path::PathBuf,
}

impl ExternalConfig {
    /// Checks its values; returns `(key, expectation)` on error.
    pub fn validate(&self) -> Result<(), (String, String)> {
        match &self.command {
            Some(StackCommand::Shell(c)) if c.trim().is_empty() => {
                return Err(("command".into(), "a command line, not empty".into()));
            }
            Some(StackCommand::Argv(a)) if a.first().is_none_or(|p| p.is_empty()) => {
                return Err((
                    "command".into(),
                    "a program and its arguments, the program not empty".into(),
                ));
            }
            _ => {}
        }
        if let Some(d) = self.domain
            && !(0..=232).contains(&d)
        {
            return Err((
                "domain".into(),
                format!("a DDS domain id from 0 to 232, found {d}"),
            ));
        }
        for (k, v) in [
            ("timeout", self.timeout),
            ("wait", self.wait),
            ("period", self.period),
            ("camera_rate", self.camera_rate),
        ] {
            if let Some(v) = v
                && !(v.is_finite() && v > 0.0 && v <= 86_400.0)
            {
                return Err((
                    k.into(),
                    format!("a positive number up to 86400, found {v}"),
                ));
            }
        }
        if let Some(n) = self.camera_scale
            && !(1..=16).contains(&n)
        {
            return Err((
                "camera_scale".into(),
                format!("a binning factor from 1 to 16, found {n}"),
            ));
        }
        if self.pose_topic.is_some() && self.pose_from_tf {
            return Err((
                "pose_from_tf".into(),
                "no pose_topic with it: the pose comes from one or the other".into(),
            ));
        }
        for (k, t) in [
            ("pose_topic", &self.pose_topic),
            ("map_topic", &self.map_topic),
        ] {
            if let Some(t) = t
                && !crate::dds::is_topic(t)
            {
                return Err((
                    k.into(),
                    format!(
                        "an absolute ROS 2 topic name such as /amcl_pose (letters, digits, _ \
                         and /), found `{t}`"
                    ),
                ));
            }
        }
        Ok(())
    }
}

impl ControllerConfig {
    /// The `type` names, in declaration order.
    pub const TYPES: [&'static str; 8] = [
        "idle",
        "segments",
        "waypoints",
        "navigate",
        "explore",
        "coverage",
        "route",
        "external",
    ];

    /// Checks values a controller cannot run with; returns `(key, expectation)` on error.
    pub fn validate(&self) -> Result<(), (String, String)> {
        match self {
            ControllerConfig::Idle
            | ControllerConfig::Explore(_)
            | ControllerConfig::Coverage(_) => Ok(()),
            ControllerConfig::External(e) => e.validate(),
            ControllerConfig::Route(r) => {
                if r.topic.is_empty() || r.topic.contains(char::is_whitespace) {
                    Err((
                        "topic".into(),
                        "a topic name without spaces, e.g. \"scan3d\"".into(),
                    ))
                } else {
                    Ok(())
                }
            }
            ControllerConfig::Segments(s) => s.validate(),
            ControllerConfig::Waypoints(w) => w.validate(),
            ControllerConfig::Navigate(n) => n.validate(),
        }
    }

    /// The scripted plan, for the controllers that are one.
    pub fn script(&self) -> Option<Script> {
        match self {
            ControllerConfig::Idle => Some(Script::Idle),
            ControllerConfig::Segments(s) => Some(Script::Segments(s.clone())),
            ControllerConfig::Waypoints(w) => Some(Script::Waypoints(w.clone())),
            ControllerConfig::Navigate(_)
            | ControllerConfig::Explore(_)
            | ControllerConfig::Coverage(_)
            | ControllerConfig::Route(_)
            | ControllerConfig::External(_) => None,
        }
    }
}

/// Types the `[controller]` table by its `type` key, naming `controller.KEY` in errors.
pub fn controller_config(path: &Path, table: &toml::Table) -> Result<ControllerConfig, SpecError> {
    let mut rest = table.clone();
    let ty = match rest.remove("type") {
        Some(toml::Value::String(t)) => t,
        Some(other) => {
            return Err(SpecError::new(
                path,
                "controller.type",
                format!(
                    "expected a string, one of {:?}; found {other}",
                    ControllerConfig::TYPES
                ),
            ));
        }
        None => {
            return Err(SpecError::new(
                path,
                "controller.type",
                format!("missing; expected one of {:?}", ControllerConfig::TYPES),
            ));
        }
    };
    fn typed<T: serde::de::DeserializeOwned>(
        path: &Path,
        rest: toml::Table,
    ) -> Result<T, SpecError> {
        serde_path_to_error::deserialize(toml::Value::Table(rest)).map_err(|e| {
            let key = e.path().to_string();
            let key = if key == "." {
                "controller".to_string()
            } else {
                format!("controller.{key}")
            };
            SpecError::new(path, key, e.into_inner().message().to_string())
        })
    }
    match ty.as_str() {
        "idle" => match rest.keys().next() {
            None => Ok(ControllerConfig::Idle),
            Some(k) => Err(SpecError::new(
                path,
                format!("controller.{k}"),
                "unknown field: an idle controller takes no parameters",
            )),
        },
        "external" => Ok(ControllerConfig::External(typed(path, rest)?)),
        "segments" => Ok(ControllerConfig::Segments(typed(path, rest)?)),
        "waypoints" => Ok(ControllerConfig::Waypoints(typed(path, rest)?)),
        "navigate" => Ok(ControllerConfig::Navigate(typed(path, rest)?)),
        "explore" => Ok(ControllerConfig::Explore(typed(path, rest)?)),
        "coverage" => Ok(ControllerConfig::Coverage(typed(path, rest)?)),
        "route" => Ok(ControllerConfig::Route(typed(path, rest)?)),
        other => Err(SpecError::new(
            path,
            "controller.type",
            format!(
                "unknown controller `{other}`; expected one of {:?}",
                ControllerConfig::TYPES
            ),
        )),
    }
}

impl ControllerConfig {
    /// The `[controller]` table with every key, defaults included.
    pub fn table(&self) -> toml::Table {
        let typed = match self {
            ControllerConfig::Idle => Ok(toml::Table::new()),
            ControllerConfig::External(c) => toml::Table::try_from(c),
            ControllerConfig::Segments(c) => toml::Table::try_from(c),
            ControllerConfig::Waypoints(c) => toml::Table::try_from(c),
            ControllerConfig::Navigate(c) => toml::Table::try_from(c),
            ControllerConfig::Explore(c) => toml::Table::try_from(c),
            ControllerConfig::Coverage(c) => toml::Table::try_from(c),
            ControllerConfig::Route(c) => toml::Table::try_from(c),
        };
        let mut t = typed.unwrap_or_default();
        let names = ControllerConfig::TYPES;
        let ty = match self {
            ControllerConfig::Idle => names[0],
            ControllerConfig::Segments(_) => names[1],
            ControllerConfig::Waypoints(_) => names[2],
            ControllerConfig::Navigate(_) => names[3],
            ControllerConfig::Explore(_) => names[4],
            ControllerConfig::Coverage(_) => names[5],
            ControllerConfig::Route(_) => names[6],
            ControllerConfig::External(_) => names[7],
        };
        t.insert("type".into(), toml::Value::String(ty.into()));
        t
    }
}

/// `[controller]`'s spec: what drives the robot, and the laser the navigator avoids
/// obstacles with (`controller.laser`, or the only one).
#[derive(Debug, Clone, PartialEq)]
pub struct ControllerSpec {
    pub controller: ControllerConfig,
    pub laser: Option<String>,
}

/// What drives the robot in `s` (idle in a scenario not yet resolved, which cannot happen
/// after loading: `[controller]` is required).
pub fn controller(s: &Scenario) -> &ControllerConfig {
    static IDLE: ControllerConfig = ControllerConfig::Idle;
    s.module::<ControllerSpec>()
        .map_or(&IDLE, |c| &c.controller)
}

/// The laser the navigator avoids obstacles with, if any.
pub fn driver_laser(s: &Scenario) -> Option<&String> {
    s.module::<ControllerSpec>()?.laser.as_ref()
}

/// The type of a scenario's `[controller]` as written (`navigate`), for scorers that declare
/// their metrics before the table is typed.
pub fn controller_type(spec: &ScenarioSpec) -> Option<&str> {
    spec.module("controller")?.get("type")?.as_str()
}

/// `[controller]`: the driver, a scripted controller or the navigator. Every scenario has one.
pub struct Module;

impl ModuleConfig for Module {
    fn key(&self) -> Option<&'static str> {
        Some("controller")
    }

    fn required(&self) -> bool {
        true
    }

    /// The table typed by its `type`, its laser resolved, and the pose its driver steers by
    /// published by a module of the scenario.
    fn resolve(&self, cx: &Resolving<'_>, table: &toml::Value) -> Result<Spec, SpecError> {
        let path = cx.path;
        let mut controller_table = cx.table("controller", table)?;
        let controller_laser = cx.take_name("controller", "laser", &mut controller_table)?;
        let mut controller = controller_config(path, &controller_table)?;
        if let ControllerConfig::External(e) = &mut controller {
            e.dir = match path.parent() {
                Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
                _ => ".".into(),
            };
        }
        let navigates = matches!(
            controller,
            ControllerConfig::Navigate(_)
                | ControllerConfig::Explore(_)
                | ControllerConfig::Coverage(_)
                | ControllerConfig::Route(_)
        );
        let driver_laser = match (&controller_laser, navigates) {
            (Some(_), false) => {
                return Err(SpecError::new(
                    path,
                    "controller.laser",
                    "only the navigate and explore controllers read a laser",
                ));
            }
            (Some(_), true) => Some(cx.laser("controller", &controller_laser)?),
            (None, true) if !cx.lidars.is_empty() => Some(cx.laser("controller", &None)?),
            _ => None,
        };
        controller
            .validate()
            .map_err(|(k, m)| SpecError::new(path, format!("controller.{k}"), m))?;
        let pose_source = match &controller {
            ControllerConfig::Waypoints(w) => Some(w.pose_source),
            ControllerConfig::Navigate(n) => Some(n.pose_source),
            ControllerConfig::Coverage(c) => Some(c.pose_source),
            ControllerConfig::Route(r) => Some(r.pose_source),
            _ => None,
        };
        if let Some(source) = pose_source {
            cx.require_pose("controller.pose_source", source, "driving on this pose")?;
        }
        if matches!(controller, ControllerConfig::Explore(_)) && cx.spec.module("slam").is_none() {
            return Err(SpecError::new(
                path,
                "controller.type",
                "exploration drives on SLAM's map and pose: it needs a [slam] table",
            ));
        }
        Ok(Box::new(ControllerSpec {
            controller,
            laser: driver_laser,
        }))
    }

    fn effective(&self, spec: &(dyn Any + Send + Sync)) -> Option<toml::Table> {
        let c = spec.downcast_ref::<ControllerSpec>()?;
        let mut t = c.controller.table();
        if let Some(l) = &c.laser {
            t.insert("laser".into(), toml::Value::String(l.clone()));
        }
        Some(t)
    }

    fn metric_names(
        &self,
        spec: &ScenarioSpec,
        _own: Option<&(dyn Any + Send + Sync)>,
    ) -> Vec<String> {
        metric_names(spec)
    }
}

impl super::StackModule for Module {
    /// The driver, but for an `external` controller, whose commands a node from outside the
    /// stack publishes (`futago serve`'s link).
    fn build(&self, s: &Scenario, _seed: u64, _out: Option<&Path>) -> super::Nodes {
        if matches!(controller(s), ControllerConfig::External(_)) {
            return Ok(Vec::new());
        }
        Ok(vec![Box::new(DriverNode::new(s)?) as Box<dyn Node>])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn external(text: &str) -> Result<ControllerConfig, SpecError> {
        let table: toml::Table = toml::from_str(text).unwrap();
        let c = controller_config(Path::new("s.toml"), &table)?;
        c.validate()
            .map_err(|(k, m)| SpecError::new(Path::new("s.toml"), format!("controller.{k}"), m))?;
        Ok(c)
    }

    #[test]
    fn an_external_controller_takes_its_stacks_command_and_the_links_options() {
        let c = external(
            "type = \"external\"\ncommand = [\"ros2\", \"launch\", \"x.py\"]\npose_topic = \"/amcl_pose\"\ntimeout = 30.0\n",
        )
        .unwrap();
        let ControllerConfig::External(e) = &c else {
            panic!("{c:?}");
        };
        assert_eq!(
            e.command,
            Some(StackCommand::Argv(vec![
                "ros2".into(),
                "launch".into(),
                "x.py".into()
            ]))
        );
        assert_eq!(e.timeout, Some(30.0));
        // Its table as run lists what was set, and reads back the same.
        let again = controller_config(Path::new("s.toml"), &c.table()).unwrap();
        assert_eq!(again, c);
        for (text, key) in [
            ("command = \"  \"", "controller.command"),
            ("command = []", "controller.command"),
            ("pose_topic = \"amcl_pose\"", "controller.pose_topic"),
            ("domain = 300", "controller.domain"),
            ("wait = -1.0", "controller.wait"),
            (
                "pose_topic = \"/pose\"\npose_from_tf = true",
                "controller.pose_from_tf",
            ),
            ("laser_topic = \"/scan\"", "controller.laser_topic"),
        ] {
            let e = external(&format!("type = \"external\"\n{text}\n")).unwrap_err();
            assert_eq!(e.key, key, "{text}: {e}");
        }
    }
}
