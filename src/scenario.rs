//! Scenario files: which world, which robot and sensors, how long, which seed, which
//! controller, and what to write.
//!
//! Every table is a typed config of the module it configures (`[robot]` is the Create's
//! [`CreateConfig`], `[[lidar]]` a [`LidarConfig`], `[controller]` a scripted
//! [`ControllerConfig`]), so any parameter is reachable by its dotted path.

use crate::overlay::{Overlay, blame};
use futago_msgs::Pose2;
use futago_robot::control::PoseSource;
use futago_robot::control::script::{Script, SegmentsConfig, WaypointConfig};
use futago_robot::localization::mcl::MclConfig;
use futago_robot::mapping::rgbd_map::RgbdMapConfig;
use futago_robot::mapping::slam::SlamConfig;
use futago_robot::mapping::turntable::TurntableConfig;
use futago_robot::navigation::NavigationConfig;
use futago_robot::navigation::coverage::CoverageConfig;
use futago_robot::navigation::{CoverConfig, ExploreConfig, NavigateConfig, RouteConfig};
use futago_robot::tracking::PeopleConfig;
use futago_sim::agent::AgentConfig;
use futago_sim::config::{SpecError, check_name, check_range, load_toml};
use futago_sim::create::CreateConfig;
use futago_sim::joint::JointConfig;
use futago_sim::kinect::{KinectConfig, KinectSpec};
use futago_sim::lidar::{LidarConfig, LidarSpec};
use futago_sim::people::{CrowdConfig, FlowConfig, PersonConfig};
use futago_sim::{Movers, PhysicsConfig, World};
use serde::Deserialize;
use std::path::Path;

/// A scenario file as written.
#[derive(Debug, Clone, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct ScenarioSpec {
    pub name: String,
    #[serde(default)]
    pub description: String,
    /// World file, relative to the scenario file.
    pub world: String,
    /// Longest simulated time, s; the run ends earlier when the controller is done.
    pub duration: f64,
    #[serde(default)]
    pub seed: u64,
    /// Seeds that `futago suite` sweeps this scenario over (one run each, with the mean and
    /// spread of every metric); empty runs `seed` once.
    #[serde(default)]
    pub seeds: Vec<u64>,
    /// Where the robot starts: a spawn name of the world or `{ x, y, yaw_deg }`.
    pub start: StartSpec,
    #[serde(default)]
    pub physics: PhysicsConfig,
    #[serde(default)]
    pub robot: CreateConfig,
    #[serde(default)]
    pub lidar: Vec<LidarConfig>,
    /// RGB-D cameras (Kinect models); rendered only when something consumes their frames.
    #[serde(default)]
    pub camera: Vec<KinectConfig>,
    /// Joints on the robot's base that sensors ride on (turntables, tilt units).
    #[serde(default)]
    pub joint: Vec<JointConfig>,
    /// Bodies that walk the world besides the robot, seen by every sensor.
    #[serde(default)]
    pub agent: Vec<AgentConfig>,
    /// People walking routes or standing, on two legs, seen by every sensor.
    #[serde(default)]
    pub person: Vec<PersonConfig>,
    /// Streams of people arriving at a place and walking to another.
    #[serde(default)]
    pub flow: Vec<FlowConfig>,
    /// The people's motion model (social forces) and body.
    #[serde(default)]
    pub crowd: CrowdConfig,
    /// The stack's people detection and tracking (leg detector, moving-object detectors,
    /// tracker), run in scenarios with people.
    #[serde(default)]
    pub people: PeopleConfig,
    /// Monte Carlo localisation on the world's map, from its laser's scans.
    pub localization: Option<LocalizationSpec>,
    /// Monte Carlo localisation of a depth camera in the world's 3D model (seed 002).
    pub depth_localization: Option<DepthLocalizationSpec>,
    /// Laser SLAM in the loop, from its laser's scans; typed by [`slam_config`].
    pub slam: Option<toml::Table>,
    /// A 3D map from a camera's RGB-D keyframes, placed by a 2D pose and the floor; typed by
    /// [`rgbd_map_config`].
    pub rgbd_map: Option<toml::Table>,
    /// Seed 004's stop-and-scan 3D map from a laser on a turntable; typed by
    /// [`scan3d_config`].
    pub scan3d: Option<toml::Table>,
    /// Seed 001's visual landmark map from a trinocular camera.
    pub visual_map: Option<crate::stack::visual_map::VisualMapSpec>,
    /// Seed 001's monocular localisation in a landmark map.
    pub visual_localization: Option<crate::stack::visual_localization::VisualLocalizationSpec>,
    /// Navigation parameters, for the `navigate`, `explore` and `coverage` controllers.
    #[serde(default)]
    pub navigation: NavigationConfig,
    /// Coverage planning parameters, for the `coverage` controller.
    #[serde(default)]
    pub coverage: CoverageConfig,
    /// Things that happen to the robot at set times.
    #[serde(default)]
    pub event: Vec<EventSpec>,
    /// Accuracy gates: `futago run` exits with status 3 when one fails.
    #[serde(default)]
    pub gate: Vec<crate::gate::Gate>,
    /// Read as a table and typed by [`controller_config`], so that errors inside it carry
    /// their full key path.
    pub controller: toml::Table,
    #[serde(default)]
    pub output: OutputConfig,
}

impl ScenarioSpec {
    /// Whether the scenario puts people in the world (`[[person]]` or `[[flow]]`).
    pub fn has_people(&self) -> bool {
        !(self.person.is_empty() && self.flow.is_empty())
    }

    /// The names of the metrics a run of this scenario produces (for gates and tuning), as
    /// the stack's scorers declare them.
    pub fn metric_names(&self) -> Vec<String> {
        crate::stack::metric_names(self)
    }
}

/// An event: at `time`, the robot is picked up and put down at `teleport` (a kidnapping;
/// its odometry does not notice).
#[derive(Debug, Clone, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct EventSpec {
    /// Simulated time, s.
    pub time: f64,
    pub teleport: PoseSpec,
}

/// A pose as written: metres and degrees.
#[derive(Debug, Clone, Copy, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct PoseSpec {
    pub x: f64,
    pub y: f64,
    #[serde(default)]
    pub yaw_deg: f64,
}

impl PoseSpec {
    pub fn pose(&self) -> Pose2 {
        Pose2::new(self.x, self.y, self.yaw_deg.to_radians())
    }
}

/// The largest magnitude a gate's value may have.
pub const MAX_GATE_VALUE: f64 = 1e12;

/// Checks a pose written in a scenario: `x` and `y` inside the world's bounds and `yaw_deg`
/// within ±360°, each error naming `KEY.x`, `KEY.y` or `KEY.yaw_deg`.
fn check_pose(path: &Path, key: &str, p: &PoseSpec, world: &World) -> Result<Pose2, SpecError> {
    let (lo, hi) = world.bounds();
    let unit = "m, inside the world's bounds";
    check_range(
        path,
        &format!("{key}.x"),
        p.x,
        lo.x as f64,
        hi.x as f64,
        unit,
    )?;
    check_range(
        path,
        &format!("{key}.y"),
        p.y,
        lo.y as f64,
        hi.y as f64,
        unit,
    )?;
    check_range(
        path,
        &format!("{key}.yaw_deg"),
        p.yaw_deg,
        -360.0,
        360.0,
        "degrees",
    )?;
    Ok(p.pose())
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

/// The depth-camera localiser of a run (seed 002): MCL of one camera in the world's mesh,
/// handed to the stack as its 3D model.
#[derive(Debug, Clone, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct DepthLocalizationSpec {
    /// The camera it localises (by name; may be left out when the scenario has one).
    #[serde(default)]
    pub camera: Option<String>,
    /// Frames the filter takes per second (seed 002 took 125 ms a frame: 8 Hz).
    #[serde(default = "default_depth_localization_rate")]
    pub rate: f64,
    /// Render size [width, height], px: the particles' views and the measured depth
    /// re-projected to it; none: the camera's depth size.
    #[serde(default)]
    pub size: Option<[u32; 2]>,
    /// Carry the particles by the robot's odometry; false: seed 002's carrier without it
    /// (the random walk alone).
    #[serde(default)]
    pub odometry: bool,
    /// Start from anywhere in the model's free space (`mcl.max_particles` particles, any
    /// yaw) instead of the camera's true pose; scored by `depth_localization.convergence_s`.
    #[serde(default)]
    pub global: bool,
    #[serde(default)]
    pub mcl: futago_robot::localization::depth_mcl::DepthMclConfig,
    /// The model the filter renders: the world's mesh (exact or perturbed), or a mesh or
    /// point cloud file (`file`, relative to the scenario; resolved when the scenario loads).
    #[serde(default)]
    pub model: futago_robot::localization::model::ModelConfig,
}

fn default_depth_localization_rate() -> f64 {
    8.0
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

#[derive(Debug, Clone, Deserialize, serde::Serialize)]
#[serde(untagged)]
pub enum StartSpec {
    Spawn(String),
    Pose {
        x: f64,
        y: f64,
        #[serde(default)]
        yaw_deg: f64,
    },
}

/// What `futago run` writes.
#[derive(Debug, Clone, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputConfig {
    /// Rate of the ground-truth trajectory, Hz.
    pub groundtruth_rate: f64,
    /// Write the CARMEN log of laser scans and odometry.
    pub carmen: bool,
    /// Write each camera's stream as a TUM RGB-D sequence in a folder named after it.
    pub rgbd_dataset: bool,
}

impl Default for OutputConfig {
    fn default() -> Self {
        OutputConfig {
            groundtruth_rate: 50.0,
            carmen: true,
            rgbd_dataset: false,
        }
    }
}

/// A loaded, checked scenario with its world compiled.
#[derive(Debug, Clone)]
pub struct Scenario {
    pub controller: ControllerConfig,
    pub spec: ScenarioSpec,
    pub world: World,
    pub start: Pose2,
    /// Resolved laser parameters, in `spec.lidar` order.
    pub lidars: Vec<(LidarConfig, LidarSpec)>,
    /// Resolved camera models, in `spec.camera` order.
    pub cameras: Vec<KinectSpec>,
    /// The joints and agents, checked.
    pub movers: Movers,
    /// The scenario as run: the file's table with its overlays laid over it.
    pub config: toml::Table,
    /// The overlays laid over the file, in order.
    pub overlays: Vec<Overlay>,
    /// The `[rgbd_map]` table, typed, its camera and laser resolved.
    pub rgbd_map: Option<RgbdMapSpec>,
    /// The `[slam]` table, typed, its laser resolved.
    pub slam: Option<SlamSpec>,
    /// The `[scan3d]` table, typed, its lasers and joint resolved.
    pub scan3d: Option<Scan3dSpec>,
    /// The laser the navigator avoids obstacles with (`controller.laser`, or the only one).
    pub driver_laser: Option<String>,
}

/// `[slam]`: `laser` (the name of the laser it maps with) and SLAM's own keys.
#[derive(Debug, Clone, PartialEq)]
pub struct SlamSpec {
    pub laser: Option<String>,
    pub config: SlamConfig,
}

/// Types a module's table whose wiring keys (`wiring`: which sensor it reads, where its pose
/// comes from) have been taken out, naming `KEY.…` in errors.
fn typed_table<T: serde::de::DeserializeOwned>(
    path: &Path,
    key: &str,
    rest: toml::Table,
) -> Result<T, SpecError> {
    serde_path_to_error::deserialize(toml::Value::Table(rest)).map_err(|e| {
        let k = e.path().to_string();
        SpecError::new(
            path,
            if k == "." {
                key.to_string()
            } else {
                format!("{key}.{k}")
            },
            e.into_inner().message().to_string(),
        )
    })
}

/// Takes the string key `key` out of `table` (a sensor's name), naming `module.key` in errors.
fn take_name(
    path: &Path,
    module: &str,
    key: &str,
    table: &mut toml::Table,
) -> Result<Option<String>, SpecError> {
    match table.remove(key) {
        None => Ok(None),
        Some(toml::Value::String(s)) => Ok(Some(s)),
        Some(other) => Err(SpecError::new(
            path,
            format!("{module}.{key}"),
            format!("expected a sensor's name (a string), found {other}"),
        )),
    }
}

/// Types the `[slam]` table: `laser` and SLAM's keys ([`SlamConfig`]), naming `slam.KEY` in
/// errors.
pub fn slam_config(path: &Path, table: &toml::Table) -> Result<SlamSpec, SpecError> {
    let mut rest = table.clone();
    let laser = take_name(path, "slam", "laser", &mut rest)?;
    let config: SlamConfig = typed_table(path, "slam", rest)?;
    config
        .validate()
        .map_err(|(k, m)| SpecError::new(path, k, m))?;
    Ok(SlamSpec { laser, config })
}

/// Which 2D pose places the RGB-D keyframes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MapPose {
    GroundTruth,
    Odometry,
    Localization,
    Slam,
}

/// `[rgbd_map]`: `pose_source`, `camera` (its frames), `laser` (the height of its 2D-map
/// term and slice) and the mapper's own keys ([`RgbdMapConfig`]).
#[derive(Debug, Clone, PartialEq)]
pub struct RgbdMapSpec {
    pub pose_source: MapPose,
    /// The camera's name (resolved: the only camera when the table names none).
    pub camera: String,
    /// The laser's name, if any.
    pub laser: Option<String>,
    pub config: RgbdMapConfig,
}

/// Types the `[rgbd_map]` table: `pose_source` (default `slam`) and the mapper's keys, naming
/// `rgbd_map.KEY` in errors.
pub fn rgbd_map_config(path: &Path, table: &toml::Table) -> Result<RgbdMapSpec, SpecError> {
    let mut rest = table.clone();
    let camera = take_name(path, "rgbd_map", "camera", &mut rest)?.unwrap_or_default();
    let laser = take_name(path, "rgbd_map", "laser", &mut rest)?;
    let pose_source = match rest.remove("pose_source") {
        None => MapPose::Slam,
        Some(v) => MapPose::deserialize(v.clone()).map_err(|_| {
            SpecError::new(
                path,
                "rgbd_map.pose_source",
                format!(
                    "expected one of \"ground_truth\", \"odometry\", \"localization\", \"slam\"; found {v}"
                ),
            )
        })?,
    };
    let config: RgbdMapConfig = typed_table(path, "rgbd_map", rest)?;
    config
        .validate()
        .map_err(|(k, m)| SpecError::new(path, format!("rgbd_map.{k}"), m))?;
    Ok(RgbdMapSpec {
        pose_source,
        camera,
        laser,
        config,
    })
}

/// `[scan3d]`: `laser` (the vertical laser on the turntable), `horizontal` (the laser that
/// watches for movers and, by default, localises), `pose_source` (default `line_icp`, the
/// seed's) and the mapper's own keys ([`TurntableConfig`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Scan3dSpec {
    pub laser: String,
    pub horizontal: String,
    /// The joint the vertical laser rides on (resolved from the laser).
    pub joint: String,
    pub pose_source: Scan3dPose,
    pub config: TurntableConfig,
    /// Lengths to measure in the map against the world (`[[scan3d.length]]`; scoring).
    pub lengths: Vec<MapLength>,
    /// View planning, when no `stops` are given (`scan3d.planning.*`).
    pub planning: futago_robot::navigation::views::ViewPlanningConfig,
}

/// A length of the building to measure in the 3D map, like seed 004's L1 and L2: from a
/// point in free space (map frame, m) along a direction, the distance between the first
/// surfaces on either side. The truth is cast in the world's static colliders.
#[derive(Debug, Clone, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct MapLength {
    /// Names the metrics `scan3d.length.NAME.*`: letters, digits, `_` and `-`.
    pub name: String,
    pub from: [f64; 3],
    pub direction: [f64; 3],
}

/// Which pose places seed 004's scans: another node's or the truth, or the seed's own
/// localisation on the horizontal laser (`line_icp`: odometry, then point-to-line ICP by
/// Nelder–Mead, `scan3d.line_icp.*`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Scan3dPose {
    GroundTruth,
    Odometry,
    Localization,
    Slam,
    LineIcp,
}

/// Types the `[scan3d]` table, naming `scan3d.KEY` in errors (the lasers and the joint are
/// checked against the scenario's in [`Scenario::load`]).
pub fn scan3d_config(path: &Path, table: &toml::Table) -> Result<Scan3dSpec, SpecError> {
    let mut rest = table.clone();
    let laser = take_name(path, "scan3d", "laser", &mut rest)?.ok_or_else(|| {
        SpecError::new(
            path,
            "scan3d.laser",
            "expected the name of the laser on the turntable, e.g. laser = \"vertical\"",
        )
    })?;
    let horizontal = take_name(path, "scan3d", "horizontal", &mut rest)?.ok_or_else(|| {
        SpecError::new(
            path,
            "scan3d.horizontal",
            "expected the name of the horizontal laser that watches for movers",
        )
    })?;
    let pose_source = match rest.remove("pose_source") {
        None => Scan3dPose::LineIcp,
        Some(v) => Scan3dPose::deserialize(v.clone()).map_err(|_| {
            SpecError::new(
                path,
                "scan3d.pose_source",
                format!(
                    "expected one of \"line_icp\", \"ground_truth\", \"odometry\", \"localization\", \"slam\"; found {v}"
                ),
            )
        })?,
    };
    let lengths: Vec<MapLength> = match rest.remove("length") {
        None => Vec::new(),
        Some(v) => {
            let mut t = toml::Table::new();
            t.insert("length".into(), v);
            #[derive(Deserialize)]
            struct Lengths {
                length: Vec<MapLength>,
            }
            typed_table::<Lengths>(path, "scan3d", t)?.length
        }
    };
    for (i, l) in lengths.iter().enumerate() {
        let key = |k: &str| format!("scan3d.length[{i}].{k}");
        let ok_name = !l.name.is_empty()
            && l.name.len() <= 64
            && l.name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
        if !ok_name {
            return Err(SpecError::new(
                path,
                key("name"),
                format!(
                    "expected 1-64 letters, digits, `_` or `-`; found {:?}",
                    l.name
                ),
            ));
        }
        if lengths[..i].iter().any(|o| o.name == l.name) {
            return Err(SpecError::new(
                path,
                key("name"),
                format!("`{}` names two lengths", l.name),
            ));
        }
        if !l.from.iter().all(|c| c.is_finite() && c.abs() <= 1e6) {
            return Err(SpecError::new(
                path,
                key("from"),
                format!("expected a point in the map frame, m; found {:?}", l.from),
            ));
        }
        let n = l.direction.iter().map(|c| c * c).sum::<f64>().sqrt();
        if !(n.is_finite() && n > 1e-9) {
            return Err(SpecError::new(
                path,
                key("direction"),
                format!("expected a non-zero vector; found {:?}", l.direction),
            ));
        }
    }
    let planning = match rest.remove("planning") {
        None => Default::default(),
        Some(v) => {
            let mut t = toml::Table::new();
            t.insert("planning".into(), v);
            #[derive(Deserialize)]
            struct Planning {
                planning: futago_robot::navigation::views::ViewPlanningConfig,
            }
            typed_table::<Planning>(path, "scan3d", t)?.planning
        }
    };
    planning
        .validate("scan3d.planning")
        .map_err(|(k, m)| SpecError::new(path, k, m))?;
    let config: TurntableConfig = typed_table(path, "scan3d", rest)?;
    config
        .validate("scan3d")
        .map_err(|(k, m)| SpecError::new(path, k, m))?;
    Ok(Scan3dSpec {
        laser,
        horizontal,
        joint: String::new(),
        pose_source,
        config,
        lengths,
        planning,
    })
}

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
}

impl ControllerConfig {
    /// The `type` names, in declaration order.
    pub const TYPES: [&'static str; 7] = [
        "idle",
        "segments",
        "waypoints",
        "navigate",
        "explore",
        "coverage",
        "route",
    ];

    /// Checks values a controller cannot run with; returns `(key, expectation)` on error.
    pub fn validate(&self) -> Result<(), (String, String)> {
        match self {
            ControllerConfig::Idle
            | ControllerConfig::Explore(_)
            | ControllerConfig::Coverage(_) => Ok(()),
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
            | ControllerConfig::Route(_) => None,
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

/// The name of the laser module `key` reads: the one `name` names, or the only laser when it
/// names none. Errors name `KEY.laser` and the scenario's lasers.
fn resolve_laser(
    path: &Path,
    key: &str,
    name: &Option<String>,
    lidars: &[(LidarConfig, LidarSpec)],
) -> Result<String, SpecError> {
    let names: Vec<&str> = lidars.iter().map(|(c, _)| c.name.as_str()).collect();
    let planar = |n: &str| -> Result<String, SpecError> {
        match lidars
            .iter()
            .find(|(c, _)| c.name == n)
            .and_then(|(c, _)| c.joint.as_ref())
        {
            Some(j) => Err(SpecError::new(
                path,
                format!("{key}.laser"),
                format!(
                    "laser `{n}` rides on joint `{j}`, so its scans do not lie in one plane of the \
                     base; `{key}` needs a laser fixed to the base"
                ),
            )),
            None => Ok(n.to_string()),
        }
    };
    match name {
        Some(n) if names.contains(&n.as_str()) => planar(n),
        Some(n) => Err(SpecError::new(
            path,
            format!("{key}.laser"),
            format!("no laser is named `{n}`; the scenario's lasers are {names:?}"),
        )),
        None if names.len() == 1 => planar(names[0]),
        None => Err(SpecError::new(
            path,
            format!("{key}.laser"),
            format!(
                "the scenario has {} lasers {names:?}: name the one it reads, e.g. {key}.laser = \"{}\"",
                names.len(),
                names.first().copied().unwrap_or("front")
            ),
        )),
    }
}

/// The most lasers a CARMEN log has channels for (ROBOTLASER1, ROBOTLASER2).
pub const MAX_LIDARS: usize = 2;

impl ControllerConfig {
    /// The `[controller]` table with every key, defaults included.
    pub fn table(&self) -> toml::Table {
        let typed = match self {
            ControllerConfig::Idle => Ok(toml::Table::new()),
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
        };
        t.insert("type".into(), toml::Value::String(ty.into()));
        t
    }
}

impl Scenario {
    /// The scenario as it runs, with every key of every module, defaults included: what
    /// `futago config` prints, and the list of every parameter a `--set` can reach.
    pub fn effective_config(&self) -> toml::Table {
        let mut t = toml::Table::try_from(&self.spec).unwrap_or_default();
        // The sensors' optional overrides, filled with what their presets resolved to.
        let lidars: Vec<LidarConfig> = self
            .lidars
            .iter()
            .map(|(c, s)| LidarConfig {
                beams: Some(s.beams),
                // The preset's field of view as declared (the resolved increment times the
                // beams would print 239.99999999999997 for 240).
                fov_deg: Some(c.fov_deg.unwrap_or(c.preset.fov_deg())),
                range_min: Some(s.range_min),
                range_max: Some(s.range_max),
                rate: Some(s.rate),
                sigma: Some(s.sigma),
                sigma_rel: Some(s.sigma_rel),
                ..c.clone()
            })
            .collect();
        let cameras: Vec<KinectConfig> = self
            .spec
            .camera
            .iter()
            .zip(&self.cameras)
            .map(|(c, s)| KinectConfig {
                rgb_size: Some([s.rgb.width, s.rgb.height]),
                depth_size: Some([s.depth.width, s.depth.height]),
                // The preset's field of view as declared.
                fov_deg: Some(c.fov_deg.unwrap_or(c.preset.fov_deg())),
                range_min: Some(s.range_min),
                range_max: Some(s.range_max),
                rate: Some(s.rate),
                ..c.clone()
            })
            .collect();
        for (key, v) in [
            ("lidar", toml::Value::try_from(lidars)),
            ("camera", toml::Value::try_from(cameras)),
        ] {
            if let Ok(v) = v {
                t.insert(key.into(), v);
            }
        }
        let name = |n: &Option<String>| n.clone().map(toml::Value::String);
        if let Some(slam) = &self.slam {
            let mut m = toml::Table::try_from(slam.config).unwrap_or_default();
            m.extend(name(&slam.laser).map(|v| ("laser".to_string(), v)));
            t.insert("slam".into(), toml::Value::Table(m));
        }
        if let Some(r) = &self.rgbd_map {
            let mut m = toml::Table::try_from(&r.config).unwrap_or_default();
            m.extend(name(&r.laser).map(|v| ("laser".to_string(), v)));
            m.insert("camera".into(), toml::Value::String(r.camera.clone()));
            if let Ok(v) = toml::Value::try_from(r.pose_source) {
                m.insert("pose_source".into(), v);
            }
            t.insert("rgbd_map".into(), toml::Value::Table(m));
        }
        if let Some(r) = &self.scan3d {
            let mut m = toml::Table::try_from(&r.config).unwrap_or_default();
            m.insert("laser".into(), toml::Value::String(r.laser.clone()));
            m.insert(
                "horizontal".into(),
                toml::Value::String(r.horizontal.clone()),
            );
            if let Ok(v) = toml::Value::try_from(r.pose_source) {
                m.insert("pose_source".into(), v);
            }
            if let Ok(v) = toml::Value::try_from(&r.planning) {
                m.insert("planning".into(), v);
            }
            if !r.lengths.is_empty()
                && let Ok(v) = toml::Value::try_from(&r.lengths)
            {
                m.insert("length".into(), v);
            }
            t.insert("scan3d".into(), toml::Value::Table(m));
        }
        let mut controller = self.controller.table();
        if let Some(l) = &self.driver_laser {
            controller.insert("laser".into(), toml::Value::String(l.clone()));
        }
        t.insert("controller".into(), toml::Value::Table(controller));
        t
    }

    /// Loads and checks a scenario and the world it names. Nothing runs before this succeeds.
    pub fn load(path: &Path) -> Result<Scenario, SpecError> {
        Scenario::load_with(path, &[])
    }

    /// Loads a scenario with overlays laid over it (see [`crate::overlay`]). Errors at keys an
    /// overlay set name the overlay.
    pub fn load_with(path: &Path, overlays: &[Overlay]) -> Result<Scenario, SpecError> {
        let mut config: toml::Table = load_toml(path)?;
        for o in overlays {
            o.apply(&mut config);
        }
        let spec: ScenarioSpec = if overlays.is_empty() {
            // Parsed again from the text so that errors carry line numbers.
            load_toml(path)?
        } else {
            serde_path_to_error::deserialize(toml::Value::Table(config.clone())).map_err(|e| {
                let key = e.path().to_string();
                let err = SpecError::new(
                    path,
                    if key == "." { String::new() } else { key },
                    e.into_inner().message().to_string(),
                );
                blame(err, overlays)
            })?
        };
        let mut s = Scenario::from_spec(path, spec).map_err(|e| blame(e, overlays))?;
        s.config = config;
        s.overlays = overlays.to_vec();
        Ok(s)
    }

    /// Checks a parsed scenario and compiles its world.
    pub fn from_spec(path: &Path, spec: ScenarioSpec) -> Result<Scenario, SpecError> {
        Scenario::from_spec_with(path, spec, &mut World::load)
    }

    /// As [`Scenario::from_spec`], with the world compiled by `load_world` (which may reuse
    /// worlds it compiled before: the fuzzer does).
    pub fn from_spec_with(
        path: &Path,
        mut spec: ScenarioSpec,
        load_world: &mut dyn FnMut(&Path) -> Result<World, SpecError>,
    ) -> Result<Scenario, SpecError> {
        check_name(path, "name", &spec.name)?;
        if spec.seeds.len() > 1000 {
            return Err(SpecError::new(
                path,
                "seeds",
                format!("expected at most 1000 seeds, found {}", spec.seeds.len()),
            ));
        }
        for (i, s) in spec.seeds.iter().enumerate() {
            if spec.seeds[..i].contains(s) {
                return Err(SpecError::new(
                    path,
                    format!("seeds[{i}]"),
                    format!("seed {s} is listed twice; a sweep runs each seed once"),
                ));
            }
        }
        check_range(path, "duration", spec.duration, 1e-3, 1e7, "s")?;
        spec.physics.validate(path, "physics")?;
        spec.robot.validate(path, "robot")?;
        check_range(
            path,
            "output.groundtruth_rate",
            spec.output.groundtruth_rate,
            1e-3,
            spec.physics.rate,
            "Hz, at most the physics rate",
        )?;
        if spec.lidar.len() > MAX_LIDARS {
            return Err(SpecError::new(
                path,
                "lidar",
                format!(
                    "expected at most {MAX_LIDARS} lasers (the CARMEN log's ROBOTLASER1 and ROBOTLASER2), found {}",
                    spec.lidar.len()
                ),
            ));
        }
        let mut lidars = Vec::new();
        for (i, l) in spec.lidar.iter().enumerate() {
            let s = l.resolve(path, &format!("lidar[{i}]"))?;
            if spec.lidar[..i].iter().any(|o| o.name == l.name) {
                return Err(SpecError::new(
                    path,
                    format!("lidar[{i}].name"),
                    format!("laser name `{}` is used twice", l.name),
                ));
            }
            lidars.push((l.clone(), s));
        }
        let mut cameras: Vec<KinectSpec> = Vec::new();
        for (i, c) in spec.camera.iter().enumerate() {
            let s = c.resolve(path, &format!("camera[{i}]"))?;
            if cameras.iter().any(|o| o.name == s.name) || lidars.iter().any(|l| l.0.name == s.name)
            {
                return Err(SpecError::new(
                    path,
                    format!("camera[{i}].name"),
                    format!("sensor name `{}` is used twice", s.name),
                ));
            }
            cameras.push(s);
        }
        for (i, j) in spec.joint.iter().enumerate() {
            j.validate(path, &format!("joint[{i}]"))?;
            if spec.joint[..i].iter().any(|o| o.name == j.name) {
                return Err(SpecError::new(
                    path,
                    format!("joint[{i}].name"),
                    format!("joint name `{}` is used twice", j.name),
                ));
            }
        }
        let joint_names: Vec<&str> = spec.joint.iter().map(|j| j.name.as_str()).collect();
        let mounted = spec
            .lidar
            .iter()
            .enumerate()
            .map(|(i, l)| (format!("lidar[{i}].joint"), &l.joint))
            .chain(
                spec.camera
                    .iter()
                    .enumerate()
                    .map(|(i, c)| (format!("camera[{i}].joint"), &c.joint)),
            );
        for (key, j) in mounted {
            if let Some(j) = j
                && !joint_names.contains(&j.as_str())
            {
                return Err(SpecError::new(
                    path,
                    key,
                    format!("no joint is named `{j}`; the scenario's joints are {joint_names:?}"),
                ));
            }
        }
        for (i, a) in spec.agent.iter().enumerate() {
            a.validate(path, &format!("agent[{i}]"))?;
            if spec.agent[..i].iter().any(|o| o.name == a.name) || a.name == "robot" {
                return Err(SpecError::new(
                    path,
                    format!("agent[{i}].name"),
                    format!(
                        "agent name `{}` is used twice (or is `robot`, the robot's own)",
                        a.name
                    ),
                ));
            }
        }
        let agent_names: Vec<&str> = spec.agent.iter().map(|a| a.name.as_str()).collect();
        for (i, c) in spec.camera.iter().enumerate() {
            if let Some(a) = &c.carrier
                && !agent_names.contains(&a.as_str())
            {
                return Err(SpecError::new(
                    path,
                    format!("camera[{i}].carrier"),
                    format!("no agent is named `{a}`; the scenario's agents are {agent_names:?}"),
                ));
            }
        }
        spec.crowd.validate(path)?;
        let mut walker_names: Vec<&str> = spec.agent.iter().map(|a| a.name.as_str()).collect();
        walker_names.push("robot");
        for (i, p) in spec.person.iter().enumerate() {
            p.validate(path, &format!("person[{i}]"))?;
            if walker_names.contains(&p.name.as_str()) {
                return Err(SpecError::new(
                    path,
                    format!("person[{i}].name"),
                    format!(
                        "name `{}` is taken (by another person, an agent or the robot)",
                        p.name
                    ),
                ));
            }
            walker_names.push(&p.name);
        }
        for (i, f) in spec.flow.iter().enumerate() {
            f.validate(path, &format!("flow[{i}]"))?;
            if walker_names.contains(&f.name.as_str()) {
                return Err(SpecError::new(
                    path,
                    format!("flow[{i}].name"),
                    format!(
                        "name `{}` is taken (by another flow, a person, an agent or the robot)",
                        f.name
                    ),
                ));
            }
            walker_names.push(&f.name);
        }
        if spec.output.rgbd_dataset && cameras.is_empty() {
            return Err(SpecError::new(
                path,
                "output.rgbd_dataset",
                "an RGB-D dataset needs a [[camera]]; the scenario has none",
            ));
        }
        let mut localization_laser = None;
        if let Some(l) = &spec.localization {
            if lidars.is_empty() {
                return Err(SpecError::new(
                    path,
                    "localization",
                    "Monte Carlo localisation needs a [[lidar]]; the scenario has none",
                ));
            }
            localization_laser = Some(resolve_laser(path, "localization", &l.laser, &lidars)?);
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
                .map_err(|(k, m)| SpecError::new(path, k, m))?;
        }
        // The localiser reads its laser by the resolved name.
        if let Some(l) = spec.localization.as_mut() {
            l.laser = localization_laser.clone();
        }
        if let Some(v) = &spec.visual_map {
            crate::stack::visual_map::check_rig(&v.cameras, &spec, &cameras)
                .map_err(|m| SpecError::new(path, "visual_map.cameras", m))?;
            v.validate().map_err(|(k, m)| SpecError::new(path, k, m))?;
        }
        if spec.visual_localization.is_some() && spec.localization.is_some() {
            return Err(SpecError::new(
                path,
                "visual_localization",
                "a scenario runs one localiser on `pose/localization`: [localization] or [visual_localization]",
            ));
        }
        if let Some(v) = spec.visual_localization.as_mut() {
            let names: Vec<&str> = cameras.iter().map(|c| c.name.as_str()).collect();
            let name = match &v.camera {
                Some(n) if names.contains(&n.as_str()) => n.clone(),
                None if names.len() == 1 => names[0].to_string(),
                _ => {
                    return Err(SpecError::new(
                        path,
                        "visual_localization.camera",
                        format!("name one of the scenario's cameras {names:?}"),
                    ));
                }
            };
            let cam = cameras.iter().find(|c| c.name == name);
            if cam.is_some_and(|c| c.joint.is_some() || c.carrier.is_some()) {
                return Err(SpecError::new(
                    path,
                    "visual_localization.camera",
                    format!("camera `{name}` must be fixed to the robot's base"),
                ));
            }
            let levelled = spec
                .camera
                .iter()
                .find(|c| c.name == name)
                .is_some_and(|c| c.rpy_deg[0] == 0.0 && c.rpy_deg[1] == 0.0);
            if !levelled {
                return Err(SpecError::new(
                    path,
                    "visual_localization.camera",
                    format!(
                        "camera `{name}` must be levelled (roll and pitch 0): the state is planar"
                    ),
                ));
            }
            v.camera = Some(name);
            v.validate().map_err(|(k, m)| SpecError::new(path, k, m))?;
            let file = crate::stack::visual_localization::map_path(path, v);
            if !file.is_file() {
                return Err(SpecError::new(
                    path,
                    "visual_localization.map",
                    format!(
                        "{}: no such file (a `landmarks.json` a [visual_map] run wrote)",
                        file.display()
                    ),
                ));
            }
            // Read now, so that a bad map is refused before anything runs.
            futago_msgs::landmarks::LandmarkFile::read(&file)
                .map_err(|e| SpecError::new(path, "visual_localization.map", e.to_string()))?;
            v.map = file;
        }
        if let Some(d) = spec.depth_localization.as_mut() {
            if cameras.is_empty() {
                return Err(SpecError::new(
                    path,
                    "depth_localization",
                    "depth-camera localisation needs a [[camera]]; the scenario has none",
                ));
            }
            let names: Vec<&str> = cameras.iter().map(|c| c.name.as_str()).collect();
            let name = match &d.camera {
                Some(n) if names.contains(&n.as_str()) => n.clone(),
                Some(n) => {
                    return Err(SpecError::new(
                        path,
                        "depth_localization.camera",
                        format!("no camera is named `{n}`; the scenario's cameras are {names:?}"),
                    ));
                }
                None if names.len() == 1 => names[0].to_string(),
                None => {
                    return Err(SpecError::new(
                        path,
                        "depth_localization.camera",
                        format!(
                            "the scenario has {} cameras {names:?}: name one",
                            names.len()
                        ),
                    ));
                }
            };
            let cam = cameras.iter().find(|c| c.name == name).ok_or_else(|| {
                SpecError::new(path, "depth_localization.camera", "no such camera")
            })?;
            if cam.joint.is_some() {
                return Err(SpecError::new(
                    path,
                    "depth_localization.camera",
                    format!(
                        "camera `{name}` rides on a joint; the localiser needs one fixed to the base"
                    ),
                ));
            }
            if let (Some(a), true) = (&cam.carrier, d.odometry) {
                return Err(SpecError::new(
                    path,
                    "depth_localization.odometry",
                    format!(
                        "camera `{name}` is carried by agent `{a}`, which has no odometry: set odometry = false"
                    ),
                ));
            }
            check_range(path, "depth_localization.rate", d.rate, 0.1, 100.0, "Hz")?;
            if let Some([w, h]) = d.size {
                for (k, v, most) in [(0, w, cam.depth.width), (1, h, cam.depth.height)] {
                    if v == 0 || v > most {
                        return Err(SpecError::new(
                            path,
                            format!("depth_localization.size[{k}]"),
                            format!("expected 1 to the camera's {most} px, found {v}"),
                        ));
                    }
                }
            }
            d.mcl
                .validate("depth_localization.mcl")
                .map_err(|(k, m)| SpecError::new(path, k, m))?;
            d.model
                .validate("depth_localization.model")
                .map_err(|(k, m)| SpecError::new(path, k, m))?;
            if let Some(file) = &d.model.file {
                let resolved = path.parent().unwrap_or(Path::new(".")).join(file);
                let ext = resolved
                    .extension()
                    .and_then(|e| e.to_str())
                    .map(str::to_ascii_lowercase);
                if !matches!(ext.as_deref(), Some("ply" | "glb" | "gltf")) {
                    return Err(SpecError::new(
                        path,
                        "depth_localization.model.file",
                        format!("{file}: expected a .ply, .glb or .gltf file"),
                    ));
                }
                if !resolved.is_file() {
                    return Err(SpecError::new(
                        path,
                        "depth_localization.model.file",
                        format!("model file {} does not exist", resolved.display()),
                    ));
                }
                // Absolute, so the spec reads the same wherever it is checked again.
                let resolved = std::fs::canonicalize(&resolved).unwrap_or(resolved);
                d.model.file = Some(resolved.to_string_lossy().into_owned());
            }
            d.camera = Some(name);
        }
        let slam = match &spec.slam {
            None => None,
            Some(t) => {
                let mut slam = slam_config(path, t)?;
                if lidars.is_empty() {
                    return Err(SpecError::new(
                        path,
                        "slam",
                        "laser SLAM needs a [[lidar]]; the scenario has none",
                    ));
                }
                slam.laser = Some(resolve_laser(path, "slam", &slam.laser, &lidars)?);
                Some(slam)
            }
        };
        spec.navigation
            .validate()
            .map_err(|(k, m)| SpecError::new(path, k, m))?;
        spec.coverage
            .validate()
            .map_err(|(k, m)| SpecError::new(path, k, m))?;
        spec.people
            .validate()
            .map_err(|(k, m)| SpecError::new(path, k, m))?;
        for (i, e) in spec.event.iter().enumerate() {
            check_range(
                path,
                &format!("event[{i}].time"),
                e.time,
                0.0,
                spec.duration,
                "s",
            )?;
        }
        let names = spec.metric_names();
        for (i, g) in spec.gate.iter().enumerate() {
            if !names.contains(&g.metric) {
                let close = crate::gate::similar(&names, &g.metric);
                return Err(SpecError::new(
                    path,
                    format!("gate[{i}].metric"),
                    format!(
                        "this scenario produces no metric `{}`{}",
                        g.metric,
                        if close.is_empty() {
                            format!(
                                "; its metrics start with {:?}",
                                [
                                    "odometry.",
                                    "localization. (with [localization])",
                                    "slam. (with [slam])"
                                ]
                            )
                        } else {
                            format!("; similar: {close:?}")
                        }
                    ),
                ));
            }
            if let Some(other) = &g.scenario {
                let plain = !other.is_empty()
                    && other
                        .chars()
                        .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_' || c == '.');
                if !plain || g.than.is_some() {
                    return Err(SpecError::new(
                        path,
                        format!("gate[{i}].scenario"),
                        format!(
                            "expected the file stem of another scenario of the suite (its run's `{}` is the threshold; no `than`), found {other:?}",
                            g.metric
                        ),
                    ));
                }
            }
            match (&g.value, &g.than) {
                (None, None) if g.scenario.is_none() => {
                    return Err(SpecError::new(
                        path,
                        format!("gate[{i}].value"),
                        "expected a number (or `than`, a metric to compare with)",
                    ));
                }
                (Some(v), _) if !(v.is_finite() && v.abs() <= MAX_GATE_VALUE) => {
                    return Err(SpecError::new(
                        path,
                        format!("gate[{i}].value"),
                        format!(
                            "expected a number within ±{MAX_GATE_VALUE:e} (metrics are SI values of one run), found {v}"
                        ),
                    ));
                }
                _ => {}
            }
            if let Some(m) = g.than.as_ref().filter(|m| !names.contains(m)) {
                return Err(SpecError::new(
                    path,
                    format!("gate[{i}].than"),
                    format!(
                        "this scenario produces no metric `{m}`; similar: {:?}",
                        crate::gate::similar(&names, m)
                    ),
                ));
            }
        }
        let rgbd_map = match &spec.rgbd_map {
            None => None,
            Some(t) => {
                let mut m = rgbd_map_config(path, t)?;
                if cameras.is_empty() {
                    return Err(SpecError::new(
                        path,
                        "rgbd_map",
                        "an RGB-D map needs a [[camera]]; the scenario has none",
                    ));
                }
                let names: Vec<&str> = cameras.iter().map(|c| c.name.as_str()).collect();
                if m.camera.is_empty() {
                    if cameras.len() > 1 {
                        return Err(SpecError::new(
                            path,
                            "rgbd_map.camera",
                            format!(
                                "the scenario has {} cameras {names:?}: name one, e.g. rgbd_map.camera = \"{}\"",
                                names.len(),
                                names[0]
                            ),
                        ));
                    }
                    m.camera = cameras[0].name.clone();
                } else if !names.contains(&m.camera.as_str()) {
                    return Err(SpecError::new(
                        path,
                        "rgbd_map.camera",
                        format!(
                            "no camera is named `{}`; the scenario's cameras are {names:?}",
                            m.camera
                        ),
                    ));
                }
                // The laser of its slice and 2D-map term: the one named, else SLAM's, else the
                // localiser's, else the only one.
                m.laser = match &m.laser {
                    Some(_) => Some(resolve_laser(path, "rgbd_map", &m.laser, &lidars)?),
                    None => slam
                        .as_ref()
                        .and_then(|s| s.laser.clone())
                        .or_else(|| localization_laser.clone())
                        .or_else(|| (lidars.len() == 1).then(|| lidars[0].0.name.clone())),
                };
                let needs = match m.pose_source {
                    MapPose::Localization if spec.localization.is_none() => Some("[localization]"),
                    MapPose::Slam if spec.slam.is_none() => Some("[slam]"),
                    _ => None,
                };
                if let Some(table) = needs {
                    return Err(SpecError::new(
                        path,
                        "rgbd_map.pose_source",
                        format!("this pose source needs a {table} table"),
                    ));
                }
                Some(m)
            }
        };
        let mut controller_table = spec.controller.clone();
        let controller_laser = take_name(path, "controller", "laser", &mut controller_table)?;
        let controller = controller_config(path, &controller_table)?;
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
            (Some(_), true) => Some(resolve_laser(
                path,
                "controller",
                &controller_laser,
                &lidars,
            )?),
            (None, true) if !lidars.is_empty() => {
                Some(resolve_laser(path, "controller", &None, &lidars)?)
            }
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
        if pose_source == Some(PoseSource::Slam) && spec.slam.is_none() {
            return Err(SpecError::new(
                path,
                "controller.pose_source",
                "driving on SLAM's pose needs a [slam] table",
            ));
        }
        if pose_source == Some(PoseSource::Localization)
            && spec.localization.is_none()
            && spec.visual_localization.is_none()
        {
            return Err(SpecError::new(
                path,
                "controller.pose_source",
                "driving on the localiser's pose needs a [localization] or [visual_localization] table",
            ));
        }
        if matches!(controller, ControllerConfig::Explore(_)) && spec.slam.is_none() {
            return Err(SpecError::new(
                path,
                "controller.type",
                "exploration drives on SLAM's map and pose: it needs a [slam] table",
            ));
        }
        let world_path = path.parent().unwrap_or(Path::new(".")).join(&spec.world);
        if !world_path.is_file() {
            return Err(SpecError::new(
                path,
                "world",
                format!("world file {} does not exist", world_path.display()),
            ));
        }
        let world = load_world(&world_path)?;
        let start = match &spec.start {
            StartSpec::Spawn(name) => world.spawn(name).ok_or_else(|| {
                SpecError::new(
                    path,
                    "start",
                    format!(
                        "world `{}` has no spawn `{name}`; it has {:?}",
                        world.name,
                        world.spawns.iter().map(|(n, _)| n).collect::<Vec<_>>()
                    ),
                )
            })?,
            StartSpec::Pose { x, y, yaw_deg } => check_pose(
                path,
                "start",
                &PoseSpec {
                    x: *x,
                    y: *y,
                    yaw_deg: *yaw_deg,
                },
                &world,
            )?,
        };
        for (i, e) in spec.event.iter().enumerate() {
            check_pose(path, &format!("event[{i}].teleport"), &e.teleport, &world)?;
        }
        // The robot starts, and is put down, inside the world's bounds.
        let (lo, hi) = world.bounds();
        let inside = |p: &Pose2| {
            p.x >= lo.x as f64 && p.x <= hi.x as f64 && p.y >= lo.y as f64 && p.y <= hi.y as f64
        };
        let bounds = format!(
            "expected a pose inside the world's bounds x ∈ [{}, {}], y ∈ [{}, {}] m",
            lo.x, hi.x, lo.y, hi.y
        );
        let at = |p: &Pose2| format!("({:.6e}, {:.6e})", p.x, p.y).replace(".000000e0", "");
        if !inside(&start) {
            return Err(SpecError::new(
                path,
                "start",
                format!("{bounds}; found {}", at(&start)),
            ));
        }
        for (i, a) in spec.agent.iter().enumerate() {
            for (k, p) in a.path.iter().enumerate() {
                let p = Pose2::new(p[0], p[1], 0.0);
                if !inside(&p) {
                    return Err(SpecError::new(
                        path,
                        format!("agent[{i}].path[{k}]"),
                        format!("{bounds}; found {}", at(&p)),
                    ));
                }
            }
        }
        let mut places: Vec<(String, [f64; 2])> = Vec::new();
        for (i, p) in spec.person.iter().enumerate() {
            for (k, q) in p.route.iter().enumerate() {
                places.push((format!("person[{i}].route[{k}]"), *q));
            }
        }
        for (i, f) in spec.flow.iter().enumerate() {
            places.push((format!("flow[{i}].from"), f.from));
            places.push((format!("flow[{i}].to"), f.to));
            for (k, q) in f.via.iter().enumerate() {
                places.push((format!("flow[{i}].via[{k}]"), *q));
            }
        }
        for (key, q) in places {
            let p = Pose2::new(q[0], q[1], 0.0);
            if !inside(&p) {
                return Err(SpecError::new(
                    path,
                    key,
                    format!("{bounds}; found {}", at(&p)),
                ));
            }
        }
        let scan3d = match &spec.scan3d {
            None => None,
            Some(t) => {
                let mut m = scan3d_config(path, t)?;
                let names: Vec<&str> = lidars.iter().map(|(c, _)| c.name.as_str()).collect();
                let find = |key: &str, n: &str| {
                    lidars.iter().find(|(c, _)| c.name == n).ok_or_else(|| {
                        SpecError::new(
                            path,
                            format!("scan3d.{key}"),
                            format!("no laser is named `{n}`; the scenario's lasers are {names:?}"),
                        )
                    })
                };
                let (vertical, _) = find("laser", &m.laser)?;
                let (horizontal, _) = find("horizontal", &m.horizontal)?;
                let joint = vertical
                    .joint
                    .as_ref()
                    .and_then(|j| spec.joint.iter().find(|k| &k.name == j))
                    .ok_or_else(|| {
                        SpecError::new(
                            path,
                            "scan3d.laser",
                            format!(
                                "laser `{}` rides on no joint: the 3D scan turns it on a turntable ([[joint]] with mode = \"command\", and the laser's joint = NAME)",
                                m.laser
                            ),
                        )
                    })?;
                if joint.mode != futago_sim::joint::JointMode::Command {
                    return Err(SpecError::new(
                        path,
                        "scan3d.laser",
                        format!(
                            "joint `{}` must be mode = \"command\": the mapper turns the table itself, one sweep per view",
                            joint.name
                        ),
                    ));
                }
                if horizontal.joint.is_some() {
                    return Err(SpecError::new(
                        path,
                        "scan3d.horizontal",
                        format!(
                            "laser `{}` rides on a joint; the mover detector needs one fixed to the base",
                            m.horizontal
                        ),
                    ));
                }
                if m.pose_source == Scan3dPose::Slam && spec.slam.is_none() {
                    return Err(SpecError::new(
                        path,
                        "scan3d.pose_source",
                        "placing the scans by SLAM's pose needs a [slam] table",
                    ));
                }
                if m.pose_source == Scan3dPose::Localization && spec.localization.is_none() {
                    return Err(SpecError::new(
                        path,
                        "scan3d.pose_source",
                        "placing the scans by the localiser's pose needs a [localization] table",
                    ));
                }
                m.joint = joint.name.clone();
                Some(m)
            }
        };
        let movers = Movers {
            joints: spec.joint.clone(),
            agents: spec.agent.clone(),
            people: spec.person.clone(),
            flows: spec.flow.clone(),
            crowd: spec.crowd,
        };
        Ok(Scenario {
            controller,
            spec,
            world,
            start,
            lidars,
            cameras,
            movers,
            config: toml::Table::new(),
            overlays: Vec::new(),
            rgbd_map,
            slam,
            scan3d,
            driver_laser,
        })
    }
}
