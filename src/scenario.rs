//! Scenario files: which world, which robot and sensors, how long, which seed, which
//! controller, and what to write.
//!
//! Every table is a typed config of the module it configures (`[robot]` is the Create's
//! [`CreateConfig`], `[[lidar]]` a [`LidarConfig`]; a stack module's table, such as
//! `[controller]` or `[slam]`, is typed by the module, see [`ModuleConfig`]), so any
//! parameter is reachable by its dotted path.

use crate::overlay::{Overlay, blame};
use futago_msgs::Pose2;
use futago_robot::control::PoseSource;
use futago_robot::navigation::NavigationConfig;
use futago_robot::navigation::coverage::CoverageConfig;
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
use std::any::Any;
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;

/// A scenario file as written.
#[derive(Debug, Clone, Deserialize, serde::Serialize)]
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
    #[serde(default)]
    pub output: OutputConfig,
    /// The stack modules' tables as written (`[localization]`, `[slam]`, `[rgbd_map]`, …), by
    /// key: each is typed and checked by the module that owns it ([`ModuleConfig`]), and a
    /// key no module owns is refused when the scenario loads.
    #[serde(flatten)]
    pub modules: BTreeMap<String, toml::Value>,
}

impl ScenarioSpec {
    /// Whether the scenario puts people in the world (`[[person]]` or `[[flow]]`).
    pub fn has_people(&self) -> bool {
        !(self.person.is_empty() && self.flow.is_empty())
    }

    /// The table of stack module `key` as written, when the scenario has one.
    pub fn module(&self, key: &str) -> Option<&toml::Value> {
        self.modules.get(key)
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

/// A stack module's configuration: the table of scenario files it owns, typed, checked and
/// resolved against the scenario's sensors and the modules before it; its table as it runs;
/// and the metric names its scorer declares. Each module implements it beside its node (in
/// `crate::stack`), where one line registers it; the loader only loops over the modules.
pub trait ModuleConfig: Sync {
    /// The key of its table in scenario files (`slam`); none for a module without one.
    fn key(&self) -> Option<&'static str> {
        None
    }

    /// Whether every scenario must have its table (`[controller]`).
    fn required(&self) -> bool {
        false
    }

    /// Types and checks its table (present in the scenario), naming `KEY.…` in errors, and
    /// resolves the sensors and streams it names; gives its spec, which its node reads back
    /// by type ([`Scenario::module`]).
    fn resolve(&self, cx: &Resolving<'_>, _table: &toml::Value) -> Result<Spec, SpecError> {
        Err(cx.error(self.key().unwrap_or("?"), "this module takes no table"))
    }

    /// Its table as it runs, from its spec: every key, defaults and resolved names included.
    fn effective(&self, _spec: &(dyn Any + Send + Sync)) -> Option<toml::Table> {
        None
    }

    /// The pose topic (`pose/TOPIC`) its node publishes when the scenario holds `table` for
    /// it, read from the raw table (a module resolved earlier may ask before this one is
    /// resolved): pose sources are checked against these ([`Resolving::require_pose`]), and
    /// two modules may not publish the same one.
    fn pose_topic(&self, _table: &toml::Value) -> Option<&'static str> {
        None
    }

    /// The topic it can publish and how an error names the table that makes it do so
    /// (`[localization]`), for modules that can publish one.
    fn pose_table(&self) -> Option<(&'static str, &'static str)> {
        None
    }

    /// The metric names its scorer declares for `spec`, given its own resolved spec (none
    /// when the scenario has no table for it).
    fn metric_names(
        &self,
        _spec: &ScenarioSpec,
        _own: Option<&(dyn Any + Send + Sync)>,
    ) -> Vec<String> {
        Vec::new()
    }
}

/// A module's resolved spec.
pub type Spec = Box<dyn Any + Send + Sync>;

/// A resolved spec, shared by the clones of a scenario.
type SharedSpec = Arc<dyn Any + Send + Sync>;

/// The scenario's lasers (with their resolved specs) and cameras, in the file's order.
type Sensors = (Vec<(LidarConfig, LidarSpec)>, Vec<KinectSpec>);

/// The resolved specs of a scenario's stack modules, in the modules' order.
#[derive(Clone, Default)]
pub struct ModuleSpecs {
    entries: Vec<(&'static dyn ModuleConfig, Option<SharedSpec>)>,
}

impl ModuleSpecs {
    /// The spec of type `T`, when a module resolved one.
    pub fn get<T: Any>(&self) -> Option<&T> {
        self.entries
            .iter()
            .find_map(|(_, s)| s.as_ref()?.downcast_ref::<T>())
    }

    /// Every metric name the modules' scorers declare, sorted, once each.
    pub fn metric_names(&self, spec: &ScenarioSpec) -> Vec<String> {
        let mut names: Vec<String> = self
            .entries
            .iter()
            .flat_map(|(m, own)| m.metric_names(spec, own.as_deref()))
            .collect();
        names.sort();
        names.dedup();
        names
    }
}

impl std::fmt::Debug for ModuleSpecs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_list()
            .entries(
                self.entries
                    .iter()
                    .filter(|(_, s)| s.is_some())
                    .filter_map(|(m, _)| m.key()),
            )
            .finish()
    }
}

/// What a module resolving its table sees: the scenario, its checked sensors, the specs of
/// the modules before it, and the shared resolvers of sensor names.
pub struct Resolving<'a> {
    pub path: &'a Path,
    pub spec: &'a ScenarioSpec,
    pub lidars: &'a [(LidarConfig, LidarSpec)],
    pub cameras: &'a [KinectSpec],
    pub earlier: &'a ModuleSpecs,
    /// Every module of the stack, to ask which publishes a pose topic.
    pub modules: &'a [&'static dyn ModuleConfig],
}

impl Resolving<'_> {
    /// An error at `key` of the scenario file.
    pub fn error(&self, key: impl Into<String>, message: impl Into<String>) -> SpecError {
        SpecError::new(self.path, key, message)
    }

    /// Types a module's table whose wiring keys have been taken out, naming `KEY.…` in
    /// errors.
    pub fn typed<T: serde::de::DeserializeOwned>(
        &self,
        key: &str,
        rest: toml::Table,
    ) -> Result<T, SpecError> {
        typed_table(self.path, key, rest)
    }

    /// The module's table `key` as a table, or an error naming it.
    pub fn table(&self, key: &str, value: &toml::Value) -> Result<toml::Table, SpecError> {
        match value {
            toml::Value::Table(t) => Ok(t.clone()),
            other => Err(self.error(key, format!("expected a table, found {other}"))),
        }
    }

    /// Takes the sensor name `name` out of the module `module`'s table.
    pub fn take_name(
        &self,
        module: &str,
        name: &str,
        table: &mut toml::Table,
    ) -> Result<Option<String>, SpecError> {
        take_name(self.path, module, name, table)
    }

    /// The laser module `key` reads: the one `name` names, or the only one; it must be fixed
    /// to the base.
    pub fn laser(&self, key: &str, name: &Option<String>) -> Result<String, SpecError> {
        resolve_laser(self.path, key, name, self.lidars)
    }

    /// The camera module `key` reads (its `KEY.camera`): the one `name` names, or the only
    /// one.
    pub fn camera(&self, key: &str, name: Option<&str>) -> Result<&KinectSpec, SpecError> {
        let names: Vec<&str> = self.cameras.iter().map(|c| c.name.as_str()).collect();
        let at = format!("{key}.camera");
        match name {
            Some(n) => self.cameras.iter().find(|c| c.name == n).ok_or_else(|| {
                self.error(
                    &at,
                    format!("no camera is named `{n}`; the scenario's cameras are {names:?}"),
                )
            }),
            None if names.len() == 1 => Ok(&self.cameras[0]),
            None => Err(self.error(
                &at,
                format!(
                    "the scenario has {} cameras {names:?}: name one, e.g. {key}.camera = \"{}\"",
                    names.len(),
                    names.first().copied().unwrap_or("kinect")
                ),
            )),
        }
    }

    /// Refuses pose source `source` at `key` unless the scenario runs the module that
    /// publishes it (see [`require_pose`]).
    pub fn require_pose(&self, key: &str, source: PoseSource, what: &str) -> Result<(), SpecError> {
        require_pose(self.path, self.spec, self.modules, key, source, what)
    }
}

/// Refuses pose source `source` at `key` unless the scenario runs a module that publishes
/// it, as that module declares ([`ModuleConfig::pose_topic`]): `slam` needs `pose/slam`,
/// `localization` needs `pose/localization`. `what` opens the error, which names the tables
/// that can publish it.
fn require_pose(
    path: &Path,
    spec: &ScenarioSpec,
    modules: &[&'static dyn ModuleConfig],
    key: &str,
    source: PoseSource,
    what: &str,
) -> Result<(), SpecError> {
    let topic = match source {
        PoseSource::Slam => "slam",
        PoseSource::Localization => "localization",
        PoseSource::GroundTruth | PoseSource::Odometry => return Ok(()),
    };
    let published = modules.iter().any(|m| {
        m.key()
            .and_then(|key| spec.module(key))
            .is_some_and(|table| m.pose_topic(table) == Some(topic))
    });
    if published {
        return Ok(());
    }
    let named: Vec<&str> = modules
        .iter()
        .filter_map(|m| m.pose_table())
        .filter(|(t, _)| *t == topic)
        .map(|(_, table)| table)
        .collect();
    Err(SpecError::new(
        path,
        key,
        format!("{what} needs a {} table", named.join(" or ")),
    ))
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
    /// Write the run as a ROS 2 bag in `ros2/` (MCAP; see [`crate::stack::bag`]).
    pub mcap: bool,
}

impl Default for OutputConfig {
    fn default() -> Self {
        OutputConfig {
            groundtruth_rate: 50.0,
            carmen: true,
            rgbd_dataset: false,
            mcap: false,
        }
    }
}

/// A loaded, checked scenario with its world compiled.
#[derive(Debug, Clone)]
pub struct Scenario {
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
    /// The stack modules' specs, typed and resolved, in the modules' order.
    pub modules: ModuleSpecs,
}

/// Types a module's table whose wiring keys (`wiring`: which sensor it reads, where its pose
/// comes from) have been taken out, naming `KEY.…` in errors.
pub fn typed_table<T: serde::de::DeserializeOwned>(
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
pub fn take_name(
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

/// The name of the laser module `key` reads: the one `name` names, or the only laser when it
/// names none. Errors name `KEY.laser` and the scenario's lasers.
pub fn resolve_laser(
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

impl Scenario {
    /// The scenario's world, robot, lasers and movers in a simulation seeded with `seed`, the
    /// robot at its start.
    pub fn simulation(&self, seed: u64) -> futago_sim::Simulation {
        futago_sim::Simulation::new(
            &self.world,
            &self.spec.physics,
            &self.spec.robot,
            &self.lidars,
            &self.movers,
            self.start,
            seed,
        )
    }

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
        for (m, own) in &self.modules.entries {
            if let (Some(key), Some(own)) = (m.key(), own)
                && let Some(table) = m.effective(own.as_ref())
            {
                t.insert(key.into(), toml::Value::Table(table));
            }
        }
        t
    }

    /// The resolved spec of the stack module whose spec is a `T` (see [`ModuleConfig`]), when
    /// the scenario runs it.
    pub fn module<T: Any>(&self) -> Option<&T> {
        self.modules.get::<T>()
    }

    /// Every metric name a run of the scenario produces: each module's scorer declares its
    /// own.
    pub fn metric_names(&self) -> Vec<String> {
        self.modules.metric_names(&self.spec)
    }

    /// Loads and checks a scenario and the world it names, with the stack's `modules`
    /// typing their tables. Nothing runs before this succeeds.
    pub fn load(path: &Path, modules: &[&'static dyn ModuleConfig]) -> Result<Scenario, SpecError> {
        Scenario::load_with(path, &[], modules)
    }

    /// Loads a scenario with overlays laid over it (see [`crate::overlay`]). Errors at keys an
    /// overlay set name the overlay.
    pub fn load_with(
        path: &Path,
        overlays: &[Overlay],
        modules: &[&'static dyn ModuleConfig],
    ) -> Result<Scenario, SpecError> {
        Scenario::load_replacing(path, overlays, &toml::Table::new(), modules)
    }

    /// [`Scenario::load_with`], with the top-level tables of `replaced` put in place of the
    /// scenario's own after the overlays (which merge key by key): `futago serve` replaces
    /// `[controller]` whole by an external one.
    pub fn load_replacing(
        path: &Path,
        overlays: &[Overlay],
        replaced: &toml::Table,
        modules: &[&'static dyn ModuleConfig],
    ) -> Result<Scenario, SpecError> {
        let mut config: toml::Table = load_toml(path)?;
        for o in overlays {
            o.apply(&mut config);
        }
        config.extend(replaced.clone());
        let spec: ScenarioSpec = if overlays.is_empty() && replaced.is_empty() {
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
        // The modules type their tables after parsing: their errors are placed on the
        // file's lines here.
        let tables: Vec<String> = spec.modules.keys().cloned().collect();
        let mut s =
            Scenario::from_spec_with(path, spec, modules, &mut World::load).map_err(|mut e| {
                let table = e.key.split(['.', '[']).next().unwrap_or("");
                if e.line.is_none() && overlays.is_empty() && tables.iter().any(|t| t == table) {
                    e.line = std::fs::read_to_string(path)
                        .ok()
                        .and_then(|text| futago_sim::config::line_of_key(&text, &e.key));
                }
                blame(e, overlays)
            })?;
        s.config = config;
        s.overlays = overlays.to_vec();
        Ok(s)
    }

    /// Checks a parsed scenario and compiles its world (by `load_world`, which may reuse
    /// worlds it compiled before: the fuzzer does). The scenario's own tables are checked
    /// here; each of the stack's `modules` types and checks its table, in their order.
    pub fn from_spec_with(
        path: &Path,
        spec: ScenarioSpec,
        modules: &[&'static dyn ModuleConfig],
        load_world: &mut dyn FnMut(&Path) -> Result<World, SpecError>,
    ) -> Result<Scenario, SpecError> {
        let (lidars, cameras) = check_sensors(path, &spec)?;
        check_movers(path, &spec)?;
        let resolved = resolve_modules(path, &spec, &lidars, &cameras, modules)?;
        check_tables(path, &spec)?;
        check_gates(path, &spec, &resolved.metric_names(&spec))?;
        let (world, start) = place(path, &spec, load_world)?;
        let movers = Movers {
            joints: spec.joint.clone(),
            agents: spec.agent.clone(),
            people: spec.person.clone(),
            flows: spec.flow.clone(),
            crowd: spec.crowd,
        };
        Ok(Scenario {
            spec,
            world,
            start,
            lidars,
            cameras,
            movers,
            config: toml::Table::new(),
            overlays: Vec::new(),
            modules: resolved,
        })
    }
}

/// The scenario's header, physics, robot and sensors: checks them and resolves the lasers'
/// and cameras' presets, in the file's order.
fn check_sensors(path: &Path, spec: &ScenarioSpec) -> Result<Sensors, SpecError> {
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
        if cameras.iter().any(|o| o.name == s.name) || lidars.iter().any(|l| l.0.name == s.name) {
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
    Ok((lidars, cameras))
}

/// The joints' carriers, agents, people and flows: each checked, with names unique among the
/// things that walk.
fn check_movers(path: &Path, spec: &ScenarioSpec) -> Result<(), SpecError> {
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
    if spec.output.rgbd_dataset && spec.camera.is_empty() {
        return Err(SpecError::new(
            path,
            "output.rgbd_dataset",
            "an RGB-D dataset needs a [[camera]]; the scenario has none",
        ));
    }
    Ok(())
}

/// Each of `modules` in order types and checks its table, given the scenario's sensors and
/// the specs of the modules before it; a table no module owns is refused.
fn resolve_modules(
    path: &Path,
    spec: &ScenarioSpec,
    lidars: &[(LidarConfig, LidarSpec)],
    cameras: &[KinectSpec],
    modules: &[&'static dyn ModuleConfig],
) -> Result<ModuleSpecs, SpecError> {
    if let Some(key) = spec
        .modules
        .keys()
        .find(|k| !modules.iter().any(|m| m.key() == Some(k.as_str())))
    {
        let tables: Vec<&str> = modules.iter().filter_map(|m| m.key()).collect();
        return Err(SpecError::new(
            path,
            key.clone(),
            format!(
                "unknown field `{key}`; expected a scenario key or a stack module's table, one of {tables:?}"
            ),
        ));
    }
    // A pose topic has one publisher: two localisers would overwrite each other's estimates.
    let mut publishers: Vec<(&str, &str)> = Vec::new();
    for &m in modules {
        let Some((key, table)) = m.key().and_then(|k| Some((k, spec.modules.get(k)?))) else {
            continue;
        };
        if let Some(topic) = m.pose_topic(table) {
            if let Some((_, first)) = publishers.iter().find(|(t, _)| *t == topic) {
                return Err(SpecError::new(
                    path,
                    key,
                    format!(
                        "[{key}] publishes `pose/{topic}`, as [{first}] does, and a pose topic has one publisher: drop one of them"
                    ),
                ));
            }
            publishers.push((topic, key));
        }
    }
    let mut resolved = ModuleSpecs::default();
    for &m in modules {
        let own = match m.key().and_then(|k| spec.modules.get(k)) {
            None if m.required() => {
                let key = m.key().unwrap_or_default();
                return Err(SpecError::new(path, "", format!("missing field `{key}`")));
            }
            None => None,
            Some(table) => {
                let cx = Resolving {
                    path,
                    spec,
                    lidars,
                    cameras,
                    earlier: &resolved,
                    modules,
                };
                Some(Arc::from(m.resolve(&cx, table)?))
            }
        };
        resolved.entries.push((m, own));
    }
    Ok(resolved)
}

/// The navigation, coverage and people tables, and the events' times.
fn check_tables(path: &Path, spec: &ScenarioSpec) -> Result<(), SpecError> {
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
    Ok(())
}

/// The gates: each names a metric of `names` (and `than` another), with a value in range.
fn check_gates(path: &Path, spec: &ScenarioSpec, names: &[String]) -> Result<(), SpecError> {
    for (i, g) in spec.gate.iter().enumerate() {
        if !names.contains(&g.metric) {
            let close = crate::gate::similar(names, &g.metric);
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
                    crate::gate::similar(names, m)
                ),
            ));
        }
    }
    Ok(())
}

/// Compiles the world and checks the poses in it: the start (a spawn or a pose), the events'
/// teleports, the agents' paths and the people's routes, all inside its bounds.
fn place(
    path: &Path,
    spec: &ScenarioSpec,
    load_world: &mut dyn FnMut(&Path) -> Result<World, SpecError>,
) -> Result<(World, Pose2), SpecError> {
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
    Ok((world, start))
}
