//! The robot stack in the loop, as a deterministic schedule of nodes (ROS's nodes and topics,
//! made deterministic).
//!
//! Each stack module (localiser, SLAM, RGB-D mapper, driver) and each recorder of the run's
//! files is a [`Node`]: it declares the named streams it consumes and publishes
//! ([`Streams`]), takes messages through the callbacks of its phases, and at the end writes
//! its files, its part of the summary and its scores ([`Node::finish`], [`Node::score`]).
//! The run loop (`crate::run`) only steps the simulation and hands each message to its
//! consumers on the simulation clock, in this fixed order within one physics step:
//!
//! 1. **truth**: at the ground-truth rate, before the step ([`Node::on_truth`]);
//! 2. the simulation steps;
//! 3. **truth/step**: the truth after every step, for the nodes that consume it (the oracle,
//!    [`oracle`]), and once before the first control tick;
//! 4. **odometry**: the Create's report, when one fell due ([`Node::on_odometry`]);
//! 5. **frames**: each camera that is due, in the scenario's order, is rendered only if some
//!    consumer wants a frame now ([`Node::wants_frame`]), then handed to those that do
//!    ([`Node::on_frame`]);
//! 6. **scans**: each completed scan, in the scenario's laser order ([`Node::on_scan`]);
//! 7. **control**: at the rate of the Create's reports ([`Node::on_control`]); the driver
//!    publishes the next drive command on the [`Bus`].
//!
//! Within a phase, nodes run in the order of what they consume and publish ([`schedule`]): a
//! node after the publishers of its inputs. Where topics form a cycle, the first node of it in
//! [`MODULES`] order goes first and sees the others' outputs one callback late; the run's
//! summary states each such lag (`schedule.lags`).
//!
//! The bus carries what the robot senses and what nodes publish, never the simulator's truth.
//! Recorders and scorers see the truth through their own view ([`TrueState`]): at the
//! ground-truth rate ([`Node::on_truth`]), after each of their callbacks ([`Node::observe`]),
//! and as what a scan's beams hit ([`Node::on_scan_truth`]) or a frame's true depth
//! ([`FrameTruth`]). A module that drives on the truth takes `pose/ground_truth` from the
//! oracle node, built only where some node consumes it.
//!
//! Nothing depends on threads or the wall
//! clock, so a scenario and a seed give the same bytes. A new module is a new file here with
//! its node and its `Module` ([`StackModule`], [`ModuleConfig`]: its table, nodes and metric
//! names), and one line in [`MODULES`]; the loader and the loop do not change.

pub mod bag;
pub mod bus;
pub mod coverage;
pub mod depth_localization;
pub mod driver;
pub mod localization;
pub mod oracle;
pub mod people;
pub mod record;
pub mod rgbd_map;
pub mod scan3d;
pub mod schedule;
pub mod slam;
pub mod visual_localization;
pub mod visual_map;

pub use crate::ground_truth::{TrueState, Truth, world_map};
pub use bus::Bus;

use crate::ground_truth::Metrics;
use crate::overlay::Overlay;
use crate::scenario::{ModuleConfig, Scenario, ScenarioSpec};
use anyhow::Result;
use futago_msgs::camera::{DepthImage, RgbImage, RgbdFrame};
use futago_msgs::grid::OccupancyGrid;
use futago_msgs::{LaserScan, Odometry, Pose2, Pose3, Time, tum};
use futago_sim::config::SpecError;
use serde_json::Value;
use std::path::Path;

/// The named streams a node consumes and publishes. Names follow ROS's habits:
/// `odometry`, `scan/NAME` (a laser's scans), `camera/NAME` (a camera's frames),
/// `pose/NAME` (a pose estimate), `map/NAME` (a 2D map), `cmd_vel` (drive commands),
/// `truth` (the simulator's ground truth, for recorders and scorers only).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Streams {
    pub consumes: Vec<String>,
    pub publishes: Vec<String>,
    /// Consumed topics wanted no more often than a period (a map for a planner).
    pub periods: Vec<(String, futago_msgs::Duration)>,
}

/// A stack module or recorder in the loop. Every callback has a default that does nothing,
/// so a node implements only the phases of the streams it declares.
pub trait Node {
    /// The node's name, as in `summary.json`'s `performance.nodes` and in errors.
    fn name(&self) -> &'static str;

    /// The streams it consumes and publishes; the loop delivers only what is consumed.
    fn streams(&self) -> Streams;

    /// Before the first step, in node order: publish initial estimates, write headers.
    fn start(&mut self, _bus: &mut Bus) -> Result<()> {
        Ok(())
    }

    /// The truth, for the nodes that consume `truth` (at the ground-truth rate, before the
    /// step) or `truth/step` (after every step): recorders, scorers and the oracle.
    fn on_truth(&mut self, _truth: &TrueState, _bus: &mut Bus) -> Result<()> {
        Ok(())
    }

    /// The truth at the instant of each of this node's callbacks (odometry, frame, scan,
    /// control; not timed as its work) and once more before [`Node::finish`]: for the node's
    /// scorer to measure what it just published against; what it publishes never depends on
    /// it.
    fn observe(&mut self, _truth: &TrueState, _bus: &Bus) {}

    /// A report of the Create's sensor stream, already integrated into the bus's odometry.
    fn on_odometry(&mut self, _odometry: &Odometry, _bus: &mut Bus) -> Result<()> {
        Ok(())
    }

    /// Whether the node wants a frame of camera `camera` now (cameras render only then).
    fn wants_frame(&self, _camera: &str, _bus: &Bus) -> bool {
        false
    }

    /// Whether the frames the node wants of camera `camera` must hold the colour image. A
    /// camera renders colour only when a node that wants the frame says so: a depth-only frame
    /// costs a depth render and its noise, without the colour render (and its noise draws
    /// where `noise.rgb_sigma` is set, so that the camera's depth noise then depends on the
    /// form of the frames its nodes take, as it depends on which frames they take).
    fn wants_rgb(&self, _camera: &str) -> bool {
        true
    }

    /// Whether the node, wanting colour of camera `camera`, asks for it frame by frame
    /// ([`FrameTruth::colour`]) instead of having it with every frame: for a node that looks
    /// at a frame's depth first and needs the colour of few frames (the RGB-D map's keyframes
    /// are the frames in which it finds the floor). Where every node taking a frame that
    /// wants its colour takes it so, and the camera can render it afterwards
    /// ([`futago_sim::kinect::Kinect::colour_on_demand`]), the frame comes without colour.
    fn colour_on_demand(&self, _camera: &str) -> bool {
        false
    }

    /// Every how many columns and rows of `camera`'s measured depth the node reads, from
    /// pixel (0, 0). Where every node taking a frame reads a coarser grid, the camera noises
    /// the pixels of the grid they share alone and leaves the others 0: the same values on
    /// the grid and the same noise stream, for less work. 1 (the default): every pixel.
    fn depth_stride(&self, _camera: &str) -> u32 {
        1
    }

    /// Whether the node reads pixels of `camera`'s measured depth off its
    /// [`Node::depth_stride`] grid only through [`FrameTruth::full_depth`], frame by frame:
    /// for a node that looks at most frames on a grid and at few whole (the RGB-D map reads
    /// the features of its keyframes anywhere in the image). Where the camera cannot give the
    /// whole depth afterwards ([`futago_sim::kinect::Kinect::depth_on_demand`]), its frames
    /// are noised whole for the node.
    fn full_depth_on_demand(&self, _camera: &str) -> bool {
        false
    }

    /// Whether the node takes only the frames rendered for other nodes: a recorder that must
    /// change neither which frames are rendered, nor their form, nor (through the cameras'
    /// noise streams) what the other nodes see. Its wants alone render nothing.
    fn passive_frames(&self) -> bool {
        false
    }

    /// Whether the node takes camera frames for what they are (their pixels and true optical
    /// pose), so that a camera an agent carries, not the robot, suits it. Nodes that place
    /// frames by the robot's pose and the camera's mount on it do not.
    fn takes_carried_cameras(&self) -> bool {
        false
    }

    /// A frame of camera `camera`, which the node asked for.
    fn on_frame(
        &mut self,
        _camera: &str,
        _frame: &CameraFrame,
        _truth: &mut dyn FrameTruth,
        _bus: &mut Bus,
    ) -> Result<()> {
        Ok(())
    }

    /// Whether the node reads the scan of laser `laser` stamped `stamp`, asked as the scan falls
    /// due, of the nodes that consume `scan/LASER`. A laser casts a scan only if one of them
    /// wants it, as a camera renders only for a node that wants the frame: a localiser that
    /// updates at 4 Hz need not have a 40 Hz laser's rays cast for it ten times a second,
    /// most of a laser-only loop's time. Every scan made goes to every consumer, wanted or
    /// not. A scan's readings do not depend on which other scans are made (a scan skipped
    /// still draws its noise), so a recorder that wants every scan changes nothing the
    /// others see.
    fn wants_scan(&self, _laser: &str, _stamp: Time) -> bool {
        true
    }

    /// A completed scan of laser `laser`.
    fn on_scan(&mut self, _laser: &str, _scan: &LaserScan, _bus: &mut Bus) -> Result<()> {
        Ok(())
    }

    /// What each beam of the scan of laser `laser` just handed to [`Node::on_scan`] hit:
    /// truth, for scorers only (a mapper that scores its map against the labels of what it
    /// measured); a stack module never acts on it.
    fn on_scan_truth(&mut self, _laser: &str, _hits: &[futago_sim::lidar::BeamHit]) {}

    /// A control tick (also one at time zero, before the first step).
    fn on_control(&mut self, _bus: &mut Bus) -> Result<()> {
        Ok(())
    }

    /// Whether the node is done (the run ends once every node is done and the robot stands).
    fn finished(&self) -> bool {
        true
    }

    /// After the last step, in node order: write files into `out` (when the run writes
    /// any), publish final outputs (a final map) for the nodes after it, and say what the
    /// summary and the scorers get.
    fn finish(&mut self, _bus: &mut Bus, _out: Option<&Path>) -> Result<Report> {
        Ok(Report::default())
    }

    /// The metrics this node's scorer produces, from what it kept in memory and the truth.
    fn score(&self, _truth: &Truth) -> Result<Metrics> {
        Ok(Metrics::default())
    }
}

/// A camera frame, as the robot has it: the images, and where the camera is on the robot.
/// Its true pose in the world is the scorer's ([`FrameTruth::optical`]).
pub struct CameraFrame {
    pub frame: RgbdFrame,
    /// The optical frame in the robot's floor frame (x forward, y left, z up from the floor
    /// under the base), as the robot's own kinematics give it: mount, joint and sway. `None`
    /// for a camera an agent carries.
    pub on_base: Option<Pose3>,
}

/// The scorer's and recorder's view of the frame just taken: the depth a perfect camera would
/// measure, the optical frame's true pose in the world, and the simulator's state at that
/// instant. A stack module acts on it only where it says so (a pose source of
/// `"ground_truth"`, an estimator started at the true pose).
pub trait FrameTruth {
    fn true_depth(&mut self) -> Result<DepthImage>;
    /// The frame's colour image, for a node that takes it on demand
    /// ([`Node::colour_on_demand`]): the frame's own, else rendered now for the frame's instant
    /// and pose, with the camera's colour noise, once for all the frame's nodes. Not truth,
    /// but the measurement the frame was taken without.
    fn colour(&mut self) -> Result<RgbImage>;
    /// The frame's whole measured depth, for a node that reads it on demand
    /// ([`Node::full_depth_on_demand`]): noised now for the rest of the image (the grid's
    /// pixels as the frame holds them), once for all the frame's nodes; `None` where the
    /// frame holds every pixel.
    fn full_depth(&mut self) -> Result<Option<DepthImage>>;
    fn optical(&self) -> Pose3;
    fn state(&self) -> &TrueState;
}

/// What a node leaves at the end.
#[derive(Default)]
pub struct Report {
    /// Top-level entries of `summary.json`.
    pub summary: Vec<(String, Value)>,
    /// Files (or folders, ending in `/`) it wrote into the run's folder, for their digests.
    pub files: Vec<String>,
    /// Its estimated 2D map, drawn in the report.
    pub map: Option<OccupancyGrid>,
    /// Trajectories it estimated, drawn in the report with their errors.
    pub trajectories: Vec<Trajectory>,
    /// Pictures it wrote (file name, PNG bytes), embedded in the report.
    pub pictures: Vec<(String, Vec<u8>)>,
    /// Its own measured costs beyond the wall time of its callbacks (`performance`).
    pub performance: serde_json::Map<String, Value>,
}

/// A camera's place and heading on the robot's base, as a 2D pose: x, y and the yaw of its
/// mount (its height, pitch and roll the stack takes from the floor in each frame).
pub fn camera_on_base(cam: &futago_sim::kinect::KinectSpec) -> Pose2 {
    let m = cam.mount;
    let forward = m.rotation * glam::Vec3::X;
    Pose2::new(
        m.translation.x as f64,
        m.translation.y as f64,
        (forward.y as f64).atan2(forward.x as f64),
    )
}

/// The laser named `name` (resolved when the scenario was loaded: named, or the only one).
pub fn laser<'a>(
    s: &'a Scenario,
    name: Option<&str>,
) -> Result<&'a (futago_sim::lidar::LidarConfig, futago_sim::lidar::LidarSpec)> {
    s.lidars
        .iter()
        .find(|(c, _)| Some(c.name.as_str()) == name)
        .ok_or_else(|| match name {
            Some(n) => anyhow::anyhow!("no laser is named `{n}`"),
            None => anyhow::anyhow!("no laser is named, and the scenario has none"),
        })
}

/// A scenario's nodes of one module, in their order.
pub type Nodes = Result<Vec<Box<dyn Node>>>;

/// A stack module: its configuration ([`ModuleConfig`]: its table, typed and resolved, and
/// its metric names) and the nodes it adds to a run of a scenario (none where the scenario
/// does not run it). Each module implements it beside its node, as a unit struct `Module`.
pub trait StackModule: ModuleConfig {
    /// Its nodes for scenario `s` run with `seed`, writing into `out` when the run writes
    /// files.
    fn build(&self, s: &Scenario, seed: u64, out: Option<&Path>) -> Nodes;
}

/// A module without a table of its own (it reads the scenario's sensors and shared tables):
/// its metric names and its nodes.
pub struct Plain {
    pub metric_names: fn(&ScenarioSpec) -> Vec<String>,
    pub build: fn(&Scenario, u64, Option<&Path>) -> Nodes,
}

impl ModuleConfig for Plain {
    fn metric_names(
        &self,
        spec: &ScenarioSpec,
        _own: Option<&(dyn std::any::Any + Send + Sync)>,
    ) -> Vec<String> {
        (self.metric_names)(spec)
    }
}

impl StackModule for Plain {
    fn build(&self, s: &Scenario, seed: u64, out: Option<&Path>) -> Nodes {
        (self.build)(s, seed, out)
    }
}

/// The resolved spec `own` of a module, as its type.
pub fn own<T: std::any::Any>(own: Option<&(dyn std::any::Any + Send + Sync)>) -> Option<&T> {
    own?.downcast_ref::<T>()
}

/// One node, or none.
pub(crate) fn boxed<N: Node + 'static>(n: Result<Option<N>>) -> Nodes {
    Ok(n?
        .map(|n| Box::new(n) as Box<dyn Node>)
        .into_iter()
        .collect())
}

/// The stack's modules, in the order their tables resolve and their nodes run in every
/// phase: the recorders of the run's files (when it writes them), the people's truth and
/// safety scores, the coverage planner and scorer, the driver, the localiser, the depth-camera
/// localiser, SLAM, the RGB-D mapper, the stop-and-scan 3D mapper, seed 001's visual landmark
/// mapper and monocular localiser; last, the run's ROS 2 bag (after the nodes whose final
/// maps it records). A new module is its own file and one line here; the
/// loader, the loop and the metric checks read this table.
pub static MODULES: &[&dyn StackModule] = &[
    &record::MODULE,
    &people::MODULE,
    &coverage::MODULE,
    &driver::Module,
    &localization::Module,
    &depth_localization::Module,
    &slam::Module,
    &rgbd_map::Module,
    &scan3d::Module,
    &visual_map::Module,
    &visual_localization::Module,
    &bag::MODULE,
];

/// The configurations of `modules`, for the loader.
pub fn configs(modules: &[&'static dyn StackModule]) -> Vec<&'static dyn ModuleConfig> {
    modules
        .iter()
        .map(|&m| m as &'static dyn ModuleConfig)
        .collect()
}

/// Loads and checks a scenario with the stack's modules ([`MODULES`]).
pub fn load(path: &Path) -> Result<Scenario, SpecError> {
    Scenario::load(path, &configs(MODULES))
}

/// Loads a scenario with overlays laid over it, with the stack's modules.
pub fn load_with(path: &Path, overlays: &[Overlay]) -> Result<Scenario, SpecError> {
    Scenario::load_with(path, overlays, &configs(MODULES))
}

/// Checks a parsed scenario with the stack's modules, its world compiled by `load_world`.
pub fn from_spec_with(
    path: &Path,
    spec: ScenarioSpec,
    load_world: &mut dyn FnMut(&Path) -> Result<futago_sim::World, SpecError>,
) -> Result<Scenario, SpecError> {
    Scenario::from_spec_with(path, spec, &configs(MODULES), load_world)
}

/// The stack of a scenario: every module's nodes, in [`MODULES`] order.
pub fn build(s: &Scenario, seed: u64, out: Option<&Path>) -> Result<Vec<Box<dyn Node>>> {
    build_with(MODULES, s, seed, out)
}

/// The nodes of `modules` for a scenario, in their order.
pub fn build_with(
    modules: &[&'static dyn StackModule],
    s: &Scenario,
    seed: u64,
    out: Option<&Path>,
) -> Result<Vec<Box<dyn Node>>> {
    let mut nodes = Vec::new();
    for m in modules {
        nodes.extend(m.build(s, seed, out)?);
    }
    // The oracle, only where a node drives or maps on the truth.
    let topic = format!("pose/{}", bus::GROUND_TRUTH);
    let consumers: Vec<String> = nodes
        .iter()
        .filter(|n| n.streams().consumes.contains(&topic))
        .map(|n| n.name().to_string())
        .collect();
    if !consumers.is_empty() {
        nodes.push(Box::new(oracle::OracleNode::new(consumers)));
    }
    Ok(nodes)
}

/// A trajectory a node estimates, kept in memory as it is made: its scorer and the report
/// read it there, and the run writes it as a TUM file only to hand it to the user. It is
/// scored as the file holds it ([`crate::ground_truth::score_trajectory`]), so that what futago
/// scores is what a user's tools score on the file.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Trajectory {
    /// Its name in metrics and in the report (`localization`, `slam`).
    pub name: String,
    pub poses: Vec<tum::Stamped>,
}

impl Trajectory {
    /// An empty trajectory named `name`.
    pub fn new(name: &str) -> Trajectory {
        Trajectory {
            name: name.to_string(),
            ..Trajectory::default()
        }
    }

    /// Adds the planar pose `p` at `t` (on the floor, z = 0).
    pub fn push(&mut self, t: Time, p: &Pose2) {
        self.poses.push(tum::Stamped {
            stamp: t,
            pose: Pose3::from_pose2(p, 0.0),
        });
    }

    /// Writes it as `file` in `dir`, under `header` (comment lines, each ending in a newline).
    pub fn write(&self, dir: &Path, file: &str, header: &str) -> Result<()> {
        use anyhow::Context;
        let mut text = header.to_string();
        for s in &self.poses {
            tum::format_line(&mut text, s);
        }
        std::fs::write(dir.join(file), text).with_context(|| format!("writing {file}"))?;
        Ok(())
    }
}

/// Writes a pose as a TUM line.
pub fn tum_line(line: &mut String, t: Time, p: &Pose2) {
    tum::format_line(
        line,
        &tum::Stamped {
            stamp: t,
            pose: Pose3::from_pose2(p, 0.0),
        },
    );
}
