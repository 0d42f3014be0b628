//! `futago run`: the closed loop of simulator and robot stack, and the files it writes.
//!
//! The loop steps the simulation and hands its messages to the stack's nodes
//! ([`crate::stack`]) in a fixed order on the simulation clock; it knows no module by name.
//! It is single-threaded, so a scenario and a seed always give the same bytes. Outputs go to
//! a temporary folder beside the destination and are renamed into place at the end: a
//! failed, interrupted or panicking run leaves no half-written results.

pub mod summary;

pub use summary::Summary;

use crate::scenario::Scenario;
use crate::stack::{self, Bus, CameraFrame, FrameTruth, Node, Report, TrueState};
use anyhow::{Context, Result, bail};
use futago_msgs::camera::{DepthImage, RgbImage};
use futago_msgs::grid::OccupancyGrid;
use futago_msgs::{Duration, Pose2, Time, tum};
use futago_robot::localization::odometry::OdometryIntegrator;
use futago_sim::Simulation;
use futago_sim::render::Renderer;
use futago_sim::rig::Cameras;
use futago_sim::sim::scene;
use serde_json::{Value, json};
use sha2::{Digest, Sha256};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Options of one run.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// Overrides the scenario's seed.
    pub seed: Option<u64>,
    /// Overrides the scenario's duration, s.
    pub duration: Option<f64>,
    /// Show a progress bar (on a terminal).
    pub progress: bool,
    /// Write `report.html` (parameter searches skip it).
    pub report: bool,
    /// Replace the output folder even when it holds files futago did not write (`--force`;
    /// see [`crate::output`]).
    pub force: bool,
}

/// What a run measured, for the summary and for callers (tests, benchmarks).
#[derive(Debug, Clone)]
pub struct Outcome {
    pub seed: u64,
    pub sim_time: f64,
    pub wall_time: f64,
    pub steps: u64,
    pub scans: Vec<u64>,
    /// Frames rendered per camera (0 where nothing consumed the camera).
    pub camera_frames: Vec<u64>,
    /// The adapter that rendered them, if any did.
    pub renderer: Option<String>,
    pub laser_rays: u64,
    pub bump_events: u64,
    pub wheel_drop_steps: u64,
    pub distance_travelled: f64,
    pub final_truth: Pose2,
    pub final_odometry: Pose2,
    /// Each joint's angle at the end, rad, in `movers.joints` order.
    pub final_joints: Vec<f64>,
    /// Each agent's pose at the end, in `movers.agents` order.
    pub final_agents: Vec<Pose2>,
    /// Each node's entries of the summary, in node order.
    pub entries: Vec<(String, Value)>,
    /// The files the nodes wrote (relative to the run's folder).
    pub files: Vec<String>,
    /// The stack's estimated 2D map, for the report.
    pub map: Option<OccupancyGrid>,
    /// The trajectories the nodes estimated, for the report.
    pub trajectories: Vec<stack::Trajectory>,
    /// The robot's true trajectory at the ground-truth rate, for the scorers.
    pub truth: Vec<tum::Stamped>,
    /// The pictures the nodes drew (file, PNG bytes), for the report.
    pub pictures: Vec<(String, Vec<u8>)>,
    /// The consumers that see a topic one callback late (a cycle of topics, see
    /// [`stack::schedule`]).
    pub lags: Vec<stack::schedule::Lag>,
    /// Where the wall time went: `simulation_s`, `rendering_s`, and per node (see
    /// [`performance`](Outcome::performance)).
    pub performance: Value,
}

/// The scorers' view of the frame just taken: the state, the true optical pose, and the true
/// depth rendered on demand (timed with the rendering); and the frame's colour, its own or
/// rendered on demand.
struct TrueDepth<'a> {
    state: &'a TrueState,
    optical: futago_msgs::Pose3,
    cameras: &'a mut Cameras,
    camera: usize,
    carrier: rapier3d::math::Pose,
    frame: &'a CameraFrame,
}

impl FrameTruth for TrueDepth<'_> {
    fn true_depth(&mut self) -> Result<DepthImage> {
        Ok(self.cameras.true_depth(self.camera, &self.carrier)?)
    }

    fn colour(&mut self) -> Result<RgbImage> {
        match &self.frame.frame.rgb {
            Some(rgb) => Ok(rgb.clone()),
            None => Ok(self.cameras.colour(self.camera, &self.carrier)?),
        }
    }

    fn full_depth(&mut self) -> Result<Option<DepthImage>> {
        Ok(self.cameras.full_depth(self.camera, &self.carrier)?)
    }

    fn optical(&self) -> futago_msgs::Pose3 {
        self.optical
    }

    fn state(&self) -> &TrueState {
        self.state
    }
}

/// Each node with the wall time spent in it, in all and by callback.
struct Scheduled {
    node: Box<dyn Node>,
    seconds: f64,
    /// By callback (`scan`, `frame`, `control`, …) and stream (a laser's or camera's name;
    /// empty for the others), in the order first called: a node has a few, so a scan looks
    /// its entry up without a map or a key built for it.
    callbacks: Vec<(&'static str, String, Calls)>,
}

/// The calls of one of a node's callbacks (one stream's messages, or its control ticks):
/// how many, their summed and their longest wall time. The longest is the latency a real
/// robot's computer would have to absorb within the stream's period, which a mean hides.
#[derive(Default)]
struct Calls {
    calls: u64,
    seconds: f64,
    longest_s: f64,
}

impl Scheduled {
    fn new(node: Box<dyn Node>) -> Scheduled {
        Scheduled {
            node,
            seconds: 0.0,
            callbacks: Vec::new(),
        }
    }

    /// Runs callback `what` of the node (`scan`, `frame`, `control`, …) for `stream` (a
    /// laser's or a camera's name, or empty), timed.
    fn call<T>(
        &mut self,
        (what, stream): (&'static str, &str),
        f: impl FnOnce(&mut dyn Node) -> Result<T>,
    ) -> Result<T> {
        let t0 = Instant::now();
        let r = f(self.node.as_mut()).with_context(|| format!("node `{}`", self.node.name()));
        let dt = t0.elapsed().as_secs_f64();
        self.seconds += dt;
        let k = match self
            .callbacks
            .iter()
            .position(|(w, s, _)| *w == what && s == stream)
        {
            Some(k) => k,
            None => {
                self.callbacks
                    .push((what, stream.to_string(), Calls::default()));
                self.callbacks.len() - 1
            }
        };
        let c = &mut self.callbacks[k].2;
        c.calls += 1;
        c.seconds += dt;
        c.longest_s = c.longest_s.max(dt);
        r
    }

    /// The callbacks' calls for `performance`, each under `what/stream` (or `what`): how
    /// many, the mean and the longest in milliseconds.
    fn callbacks_json(&self) -> Value {
        let by: serde_json::Map<String, Value> = self
            .callbacks
            .iter()
            .map(|(what, stream, c)| {
                (
                    if stream.is_empty() {
                        what.to_string()
                    } else {
                        format!("{what}/{stream}")
                    },
                    json!({
                        "calls": c.calls,
                        "mean_ms": 1e3 * c.seconds / c.calls.max(1) as f64,
                        "max_ms": 1e3 * c.longest_s,
                    }),
                )
            })
            .collect();
        Value::Object(by)
    }

    /// A callback that takes the bus, then the node's look at the truth of the same instant
    /// ([`Node::observe`], its scorer's; not timed as the node's work).
    fn call_observed(
        &mut self,
        what: &'static str,
        truth: &TrueState,
        bus: &mut Bus,
        f: impl FnOnce(&mut dyn Node, &mut Bus) -> Result<()>,
    ) -> Result<()> {
        self.call((what, ""), |node| f(node, bus))?;
        self.node.observe(truth, bus);
        Ok(())
    }
}

/// Which nodes consume `topic`, in node order.
fn consumers(streams: &[stack::Streams], topic: &str) -> Vec<usize> {
    (0..streams.len())
        .filter(|&i| streams[i].consumes.iter().any(|t| t == topic))
        .collect()
}

/// Which nodes each stream of the loop goes to, in node order.
struct Routes {
    /// `truth`, at the ground-truth rate.
    truth: Vec<usize>,
    /// `truth/step`, after every step.
    step_truth: Vec<usize>,
    odometry: Vec<usize>,
    /// `scan/NAME`, per laser in the scenario's order.
    lasers: Vec<Vec<usize>>,
}

impl Routes {
    fn new(s: &Scenario, streams: &[stack::Streams]) -> Routes {
        Routes {
            truth: consumers(streams, "truth"),
            step_truth: consumers(streams, "truth/step"),
            odometry: consumers(streams, "odometry"),
            lasers: s
                .lidars
                .iter()
                .map(|(c, _)| consumers(streams, &format!("scan/{}", c.name)))
                .collect(),
        }
    }
}

/// Checks that some node drives the robot (publishes `cmd_vel`) and that every consumed
/// estimate or map has a publisher.
fn check_publishers(nodes: &[Scheduled], streams: &[stack::Streams]) -> Result<()> {
    if !streams
        .iter()
        .any(|s| s.publishes.iter().any(|t| t == "cmd_vel"))
    {
        bail!(
            "nothing drives the robot: the scenario's controller is `external`, whose commands \
             come over ROS 2; give it the `command` that starts your stack, or run it with \
             `futago serve` and start the stack yourself"
        );
    }
    for (n, st) in nodes.iter().zip(streams) {
        for t in &st.consumes {
            let derived = t.starts_with("pose/") || t.starts_with("map/");
            if derived && !streams.iter().any(|o| o.publishes.contains(t)) {
                bail!(
                    "node `{}` consumes `{t}`, which no node of this scenario publishes",
                    n.node.name()
                );
            }
        }
    }
    Ok(())
}

/// The names of the topics under `prefix` (`pose/`, `map/`) that nodes publish.
fn published(streams: &[stack::Streams], prefix: &str) -> Vec<String> {
    streams
        .iter()
        .flat_map(|st| st.publishes.iter())
        .filter_map(|t| t.strip_prefix(prefix).map(String::from))
        .collect()
}

/// The published maps some node consumes, each with the shortest period a consumer asks for
/// (none: every change).
fn map_subscriptions(streams: &[stack::Streams]) -> Vec<(String, Option<Duration>)> {
    published(streams, "map/")
        .into_iter()
        .filter_map(|m| {
            let topic = format!("map/{m}");
            let wanted: Vec<&stack::Streams> = streams
                .iter()
                .filter(|st| st.consumes.contains(&topic))
                .collect();
            (!wanted.is_empty()).then(|| {
                let period = wanted
                    .iter()
                    .map(|st| st.periods.iter().find(|(t, _)| *t == topic).map(|p| p.1))
                    .try_fold(None::<Duration>, |acc, p| {
                        p.map(|p| Some(acc.map_or(p, |a: Duration| Duration(a.0.min(p.0)))))
                    })
                    .flatten();
                (topic, period)
            })
        })
        .collect()
}

/// The run's cameras on the simulator's rig, with the nodes that consume each one's frames;
/// the renderer starts only when some node consumes frames (cameras render on demand).
struct CameraRig {
    cameras: Cameras,
    consumers: Vec<Vec<usize>>,
}

impl CameraRig {
    fn new(
        s: &Scenario,
        seed: u64,
        streams: &[stack::Streams],
        nodes: &[Scheduled],
    ) -> Result<CameraRig> {
        let consumers: Vec<Vec<usize>> = s
            .cameras
            .iter()
            .map(|c| consumers(streams, &format!("camera/{}", c.name)))
            .collect();
        // A camera an agent carries is not on the robot: only nodes that take its frames for
        // what they are may consume it.
        for (c, takers) in s.cameras.iter().zip(&consumers) {
            if let Some(agent) = &c.carrier {
                for &i in takers {
                    let n = nodes[i].node.name();
                    if !nodes[i].node.takes_carried_cameras() {
                        anyhow::bail!(
                            "camera `{}` is carried by agent `{agent}`, not the robot; the `{n}` node \
                             takes camera frames as the robot's",
                            c.name
                        );
                    }
                }
            }
        }
        let renderer = if consumers
            .iter()
            .flatten()
            .any(|&i| !nodes[i].node.passive_frames())
        {
            Some(
                Renderer::new(&scene(&s.world, &s.spec.robot, &s.movers, s.start, seed))
                    .context("starting the camera renderer")?,
            )
        } else {
            None
        };
        Ok(CameraRig {
            cameras: Cameras::new(&s.cameras, &s.movers, seed, renderer),
            consumers,
        })
    }

    /// Renders each camera that is due and wanted now, in the scenario's order, and hands the
    /// frame to the nodes that want it, each observing the truth after it.
    fn capture(
        &mut self,
        sim: &Simulation,
        nodes: &mut [Scheduled],
        (state, bus): (&TrueState, &mut Bus),
    ) -> Result<()> {
        let CameraRig { cameras, consumers } = self;
        for (c, takers) in consumers.iter().enumerate() {
            if !cameras.due(c, sim.time()) {
                continue;
            }
            let name = cameras.name(c).to_string();
            let wanting: Vec<usize> = takers
                .iter()
                .copied()
                .filter(|&i| nodes[i].node.wants_frame(&name, bus))
                .collect();
            // Only nodes that act on frames make the camera render, and choose its form.
            let active = |i: &&usize| !nodes[**i].node.passive_frames();
            if !wanting.iter().any(|i| active(&i)) {
                continue;
            }
            // Colour where an active node wants it, unless every node taking the frame that
            // wants colour asks for it frame by frame and the camera can render it then.
            let wants_rgb = |i: usize| nodes[i].node.wants_rgb(&name);
            let rgb = wanting.iter().filter(active).any(|&i| wants_rgb(i))
                && !(cameras.colour_on_demand(c)
                    && wanting
                        .iter()
                        .all(|&i| !wants_rgb(i) || nodes[i].node.colour_on_demand(&name)));
            // A node that reads the whole depth on demand reads its grid of the rest, where
            // the camera can give the whole afterwards.
            let later = cameras.depth_on_demand(c, rgb);
            // The grid every taker reads: the strides' greatest common divisor.
            let depth_stride = wanting
                .iter()
                .map(|&i| {
                    let node = &nodes[i].node;
                    match node.full_depth_on_demand(&name) && !later {
                        true => 1,
                        false => node.depth_stride(&name).max(1),
                    }
                })
                .reduce(gcd)
                .unwrap_or(1);
            let shot = cameras.capture(c, sim, rgb, depth_stride)?;
            let frame = CameraFrame {
                frame: shot.frame,
                on_base: shot.on_base,
            };
            for i in wanting {
                let mut truth = TrueDepth {
                    state,
                    optical: shot.optical,
                    cameras,
                    camera: c,
                    carrier: shot.carrier,
                    frame: &frame,
                };
                nodes[i].call(("frame", &name), |node| {
                    node.on_frame(&name, &frame, &mut truth, bus)
                })?;
                nodes[i].node.observe(state, bus);
            }
        }
        Ok(())
    }
}

/// The greatest common divisor of two positive integers.
fn gcd(a: u32, b: u32) -> u32 {
    if b == 0 { a } else { gcd(b, a % b) }
}

/// The live progress bar of a run of `duration` s, when shown.
fn progress_bar(show: bool, duration: f64, name: &str) -> Option<indicatif::ProgressBar> {
    show.then(|| {
        let b = indicatif::ProgressBar::new((duration * 1000.0) as u64);
        b.set_style(
            indicatif::ProgressStyle::with_template(
                "{spinner} {msg} [{bar:40}] {percent}% sim {pos}/{len} ms, eta {eta}",
            )
            .expect("valid template")
            .progress_chars("=> "),
        );
        b.set_message(name.to_string());
        b
    })
}

/// What the nodes leave at the end of a run, gathered in node order.
struct Finished {
    entries: Vec<(String, Value)>,
    files: Vec<String>,
    map: Option<OccupancyGrid>,
    trajectories: Vec<stack::Trajectory>,
    pictures: Vec<(String, Vec<u8>)>,
    per_node: serde_json::Map<String, Value>,
}

/// Shows every node the truth at the end, then finishes them in order (each writing into
/// `out` when the run writes files) and gathers their reports, with each node's wall time.
fn finish_nodes(
    nodes: &mut [Scheduled],
    (truth, bus): (&TrueState, &mut Bus),
    out: Option<&Path>,
) -> Result<Finished> {
    for n in nodes.iter_mut() {
        n.node.observe(truth, bus);
    }
    let mut f = Finished {
        entries: Vec::new(),
        files: Vec::new(),
        map: None,
        trajectories: Vec::new(),
        pictures: Vec::new(),
        per_node: serde_json::Map::new(),
    };
    for n in nodes.iter_mut() {
        let Report {
            summary,
            files: written,
            map: m,
            trajectories: t,
            pictures,
            performance,
        } = n.call(("finish", ""), |node| node.finish(bus, out))?;
        f.entries.extend(summary);
        f.files.extend(written);
        f.map = f.map.or(m);
        f.trajectories.extend(t);
        f.pictures.extend(pictures);
        let mut p = performance;
        p.insert("wall_s".into(), json!(n.seconds));
        p.insert("callbacks".into(), n.callbacks_json());
        f.per_node
            .insert(n.node.name().to_string(), Value::Object(p));
    }
    Ok(f)
}

/// The truth phase: the robot's, the agents' and the people's true poses into the scorers'
/// view and the robot's onto its true trajectory, then each node that consumes `truth`.
fn publish_truth(
    sim: &Simulation,
    (truth, track, bus): (&mut TrueState, &mut Vec<tum::Stamped>, &mut Bus),
    nodes: &mut [Scheduled],
    truth_nodes: &[usize],
    (has_agents, has_people): (bool, bool),
) -> Result<()> {
    truth.robot = sim.robot_pose();
    track.push(tum::Stamped {
        stamp: bus.now,
        pose: futago_msgs::Pose3::from_pose2(&truth.robot, 0.0),
    });
    if has_agents {
        truth.agents = sim
            .agent_poses()
            .into_iter()
            .map(|(n, p)| (n.to_string(), p))
            .collect();
    }
    if has_people {
        truth.people = sim.people();
        truth.person_collisions = sim.counters().person_contact_events;
    }
    deliver_truth(nodes, truth_nodes, truth, bus)
}

/// Hands the truth to the nodes `to` that consume it, in node order.
fn deliver_truth(
    nodes: &mut [Scheduled],
    to: &[usize],
    truth: &TrueState,
    bus: &mut Bus,
) -> Result<()> {
    for &i in to {
        nodes[i].call(("truth", ""), |node| node.on_truth(truth, bus))?;
    }
    Ok(())
}

/// Hands an odometry message to the nodes `to`, in node order, each observing the truth
/// after it.
fn deliver_odometry(
    nodes: &mut [Scheduled],
    to: &[usize],
    truth: &TrueState,
    bus: &mut Bus,
    odometry: &futago_msgs::Odometry,
) -> Result<()> {
    for &i in to {
        nodes[i].call_observed("odometry", truth, bus, |node, bus| {
            node.on_odometry(odometry, bus)
        })?;
    }
    Ok(())
}

/// The control phase: every node's control tick in order; gives the drive command published,
/// and hands the joints' commands to the simulation.
fn control(
    nodes: &mut [Scheduled],
    (truth, bus): (&TrueState, &mut Bus),
    sim: &mut Simulation,
) -> Result<Option<futago_msgs::DriveCommand>> {
    for n in nodes.iter_mut() {
        n.call_observed("control", truth, bus, |node, bus| node.on_control(bus))?;
    }
    let cmd = bus.command.take();
    for (name, angle) in bus.joint_commands.drain(..) {
        sim.command_joint(&name, angle)
            .map_err(|e| anyhow::anyhow!("a node's joint/{name} command: {e}"))?;
    }
    Ok(cmd)
}

/// The first control tick, from the start pose alone, then every node's start; gives the
/// first drive command.
fn begin(
    nodes: &mut [Scheduled],
    truth: &TrueState,
    bus: &mut Bus,
) -> Result<Option<futago_msgs::DriveCommand>> {
    for n in nodes.iter_mut() {
        n.call_observed("control", truth, bus, |node, bus| node.on_control(bus))?;
    }
    let cmd = bus.command.take();
    for n in nodes.iter_mut() {
        n.call(("start", ""), |node| node.start(bus))?;
    }
    Ok(cmd)
}

/// Hands a scan of laser `name` to the nodes `to` that consume it, then what its beams hit
/// (truth for scorers, not timed as the nodes' work).
fn deliver_scan(
    nodes: &mut [Scheduled],
    to: &[usize],
    (name, scan, hits): (&str, &futago_msgs::LaserScan, &[futago_sim::lidar::BeamHit]),
    truth: &TrueState,
    bus: &mut Bus,
) -> Result<()> {
    for &i in to {
        nodes[i].call(("scan", name), |node| node.on_scan(name, scan, bus))?;
        nodes[i].node.on_scan_truth(name, hits);
        nodes[i].node.observe(truth, bus);
    }
    Ok(())
}

/// The nodes in the order of what they consume and publish ([`stack::schedule`]), each with
/// its wall time, and the lags that order leaves.
fn schedule(
    nodes: impl Iterator<Item = Box<dyn Node>>,
) -> (Vec<Scheduled>, Vec<stack::schedule::Lag>) {
    let nodes: Vec<Box<dyn Node>> = nodes.collect();
    let names: Vec<&str> = nodes.iter().map(|n| n.name()).collect();
    let streams: Vec<stack::Streams> = nodes.iter().map(|n| n.streams()).collect();
    let sch = stack::schedule::schedule(&names, &streams);
    let mut slots: Vec<Option<Box<dyn Node>>> = nodes.into_iter().map(Some).collect();
    let ordered = sch
        .order
        .iter()
        .filter_map(|&i| slots[i].take())
        .map(Scheduled::new)
        .collect();
    (ordered, sch.lags)
}

/// The run's bus at time zero: the robot at its start, the estimates and maps the nodes
/// publish (maps with the period their consumers want), the joints at their start angles.
fn new_bus(s: &Scenario, streams: &[stack::Streams]) -> Bus {
    let mut bus = Bus::new(
        s.start,
        published(streams, "pose/"),
        map_subscriptions(streams),
    );
    bus.joints = s
        .movers
        .joints
        .iter()
        .map(|j| (j.name.clone(), j.start_deg.to_radians()))
        .collect();
    bus
}

/// The scheduled nodes, their lags, their streams and their bus ([`wire`]).
type Wired = (
    Vec<Scheduled>,
    Vec<stack::schedule::Lag>,
    Vec<stack::Streams>,
    Bus,
);

/// The stack's nodes, with `extra` after them, in their schedule; the streams each consumes
/// and publishes (every consumed stream checked for a publisher); and the bus they share.
fn wire(s: &Scenario, seed: u64, out: Option<&Path>, extra: Vec<Box<dyn Node>>) -> Result<Wired> {
    let (nodes, lags) = schedule(stack::build(s, seed, out)?.into_iter().chain(extra));
    let streams: Vec<stack::Streams> = nodes.iter().map(|n| n.node.streams()).collect();
    check_publishers(&nodes, &streams)?;
    let bus = new_bus(s, &streams);
    Ok((nodes, lags, streams, bus))
}

/// [`simulate`] with `extra` nodes after the stack's (a collector of training data, say).
pub fn simulate_with(
    s: &Scenario,
    opts: &RunOptions,
    out: Option<&Path>,
    extra: Vec<Box<dyn Node>>,
) -> Result<(Outcome, Vec<Box<dyn Node>>)> {
    let setup = Instant::now();
    let seed = opts.seed.unwrap_or(s.spec.seed);
    let duration = opts.duration.unwrap_or(s.spec.duration);
    let spec = &s.spec;
    let (mut nodes, lags, streams, mut bus) = wire(s, seed, out, extra)?;
    let (has_agents, has_joints) = (!s.movers.agents.is_empty(), !s.movers.joints.is_empty());
    let has_people = !s.movers.people.is_empty() || !s.movers.flows.is_empty();
    let movers = (has_agents, has_people);
    let to = Routes::new(s, &streams);
    let mut cameras = CameraRig::new(s, seed, &streams, &nodes)?;

    let mut sim = s.simulation(seed);
    let mut odo = OdometryIntegrator::new(s.start);
    let gt_period = Duration::from_secs(1.0 / spec.output.groundtruth_rate);
    let end = Time::from_secs(duration);
    let mut next_gt: i64 = 0;
    let mut next_event = 0usize;
    let mut scans = vec![0u64; s.lidars.len()];
    let mut distance = 0.0;
    let mut prev_truth = s.start;
    let mut sim_seconds = 0.0;
    let started = Instant::now();
    // Building the nodes (their maps and scorers), the cameras and the simulation: outside
    // the loop's wall time and real-time factor.
    let setup_s = (started - setup).as_secs_f64();
    let bar = progress_bar(opts.progress, duration, &spec.name);

    // The first command, from the start pose alone, before any node has started.
    bus.bumps = sim.bumps();
    let mut truth = TrueState {
        robot: sim.robot_pose(),
        ..TrueState::default()
    };
    let mut truth_track = Vec::new();
    deliver_truth(&mut nodes, &to.step_truth, &truth, &mut bus)?;
    let mut cmd = begin(&mut nodes, &truth, &mut bus)?;
    loop {
        let now = sim.time();
        bus.now = now;
        if now.nanos() >= next_gt * gt_period.0 {
            next_gt += 1;
            let view = (&mut truth, &mut truth_track, &mut bus);
            publish_truth(&sim, view, &mut nodes, &to.truth, movers)?;
        }
        let done = nodes.iter().all(|n| n.node.finished());
        if now >= end || (done && sim.wheel_speeds() == (0.0, 0.0) && cmd.is_none()) {
            break;
        }
        // Events that fell due: the robot is picked up and put down.
        while let Some(e) = spec.event.get(next_event).filter(|e| now.secs() >= e.time) {
            (prev_truth, next_event) = (e.teleport.pose(), next_event + 1);
            sim.teleport(prev_truth);
        }
        let t0 = Instant::now();
        let out = sim.step_taking(cmd.take().as_ref(), &mut |l, stamp| {
            let name = &s.lidars[l].0.name;
            to.lasers[l]
                .iter()
                .any(|&i| nodes[i].node.wants_scan(name, stamp))
        });
        sim_seconds += t0.elapsed().as_secs_f64();
        let now = sim.time();
        truth.robot = sim.robot_pose();
        distance += truth.robot.distance(&prev_truth);
        prev_truth = truth.robot;
        bus.now = now;
        deliver_truth(&mut nodes, &to.step_truth, &truth, &mut bus)?;
        bus.wheel_speeds = sim.wheel_speeds();
        bus.bumps = out.bumps.unwrap_or_default();
        if let Some(o) = out.odometry {
            if has_joints {
                for (slot, j) in bus.joints.iter_mut().zip(sim.joints()) {
                    slot.1 = j.angle();
                }
            }
            odo.integrate(&o);
            bus.push_odometry(now, odo.pose);
            deliver_odometry(&mut nodes, &to.odometry, &truth, &mut bus, &o)?;
        }
        cameras.capture(&sim, &mut nodes, (&truth, &mut bus))?;
        for ((l, scan), hits) in out.scans.into_iter().zip(&out.hits) {
            scans[l] += 1;
            deliver_scan(
                &mut nodes,
                &to.lasers[l],
                (&s.lidars[l].0.name, &scan, hits),
                &truth,
                &mut bus,
            )?;
        }
        // Control at the rate of the Create's sensor stream.
        if out.odometry.is_some() {
            cmd = control(&mut nodes, (&truth, &mut bus), &mut sim)?;
        }
        if let Some(b) = &bar
            && sim.counters().steps.is_multiple_of(200)
        {
            b.set_position((now.secs() * 1000.0) as u64);
        }
    }
    bar.iter()
        .for_each(indicatif::ProgressBar::finish_and_clear);
    bus.now = sim.time();
    truth.robot = sim.robot_pose();
    truth.person_collisions = sim.counters().person_contact_events;
    let finished = finish_nodes(&mut nodes, (&truth, &mut bus), out)?;
    let wall_time = started.elapsed().as_secs_f64();
    let c = sim.counters();
    let outcome = Outcome {
        seed,
        sim_time: sim.time().secs(),
        wall_time,
        steps: c.steps,
        scans,
        camera_frames: cameras.cameras.frames.clone(),
        renderer: cameras.cameras.adapter(),
        laser_rays: c.laser_rays,
        bump_events: c.bump_events,
        wheel_drop_steps: c.wheel_drop_steps,
        distance_travelled: distance,
        final_truth: sim.robot_pose(),
        final_odometry: odo.pose,
        final_joints: sim.joints().iter().map(|j| j.angle()).collect(),
        final_agents: sim.agent_poses().into_iter().map(|(_, p)| p).collect(),
        entries: finished.entries,
        files: finished.files,
        map: finished.map,
        trajectories: finished.trajectories,
        pictures: finished.pictures,
        truth: truth_track,
        lags,
        performance: json!({
            "setup_s": setup_s,
            "simulation_s": sim_seconds,
            "rendering_s": cameras.cameras.seconds,
            "nodes": finished.per_node,
        }),
    };
    Ok((outcome, nodes.into_iter().map(|n| n.node).collect()))
}

/// The run's summary (see [`Summary`]).
pub const SUMMARY_FILE: &str = "summary.json";

/// Cell size of the ground-truth map drawn in reports of runs without a 2D map, m.
const REPORT_MAP_RESOLUTION: f64 = 0.05;

/// The run's HTML report (see [`crate::report`]).
pub const REPORT_FILE: &str = "report.html";

/// The scenario as run, written beside its results: the file's table with any overlays laid over
/// it, headed by where each part came from.
pub const SCENARIO_FILE: &str = "scenario.toml";

/// The text of [`SCENARIO_FILE`].
pub fn scenario_text(s: &Scenario) -> String {
    let mut text = String::from("# The scenario as run");
    if s.overlays.is_empty() {
        text += ".\n";
    } else {
        text += ", with overlays laid over the file:\n";
        for o in &s.overlays {
            text += &format!("#   {}: {}\n", o.origin.display(), o.leaves().join(", "));
        }
    }
    text + &toml::to_string(&s.config).unwrap_or_default()
}

/// A run scored in memory: what happened, the relations its trajectories were scored on
/// (sampled from its ground truth), and every node's metrics.
pub struct Scored {
    pub outcome: Outcome,
    pub relations: Vec<crate::relations::Relation>,
    pub metrics: crate::ground_truth::Metrics,
}

impl Scored {
    /// The scenario's gates evaluated on the metrics (gates against other scenarios' runs are
    /// the suite's to check).
    pub fn gates(&self, s: &Scenario) -> Vec<crate::ground_truth::GateResult> {
        crate::ground_truth::evaluate(&s.spec.gate, &self.metrics)
    }
}

/// Runs a scenario and scores it from memory: the nodes' trajectories, maps and detections
/// against the simulator's truth; with `out`, the recorders and nodes also write their files
/// there (nothing is read back).
fn simulate_scored(
    s: &Scenario,
    opts: &RunOptions,
    out: Option<&Path>,
    extra: Vec<Box<dyn Node>>,
) -> Result<Scored> {
    let (outcome, nodes) = simulate_with(s, opts, out, extra)?;
    // The truth as groundtruth.txt holds it, as every trajectory is scored.
    let poses: Vec<tum::Stamped> = outcome.truth.iter().map(tum::as_written).collect();
    let relations = crate::ground_truth::sample_relations(&poses);
    let truth = stack::Truth {
        scenario: s,
        poses: &poses,
        relations: &relations,
    };
    let mut metrics = crate::ground_truth::Metrics::default();
    for n in &nodes {
        let m = n
            .score(&truth)
            .with_context(|| format!("scoring node `{}`", n.name()))?;
        metrics.0.extend(m.0);
    }
    Ok(Scored {
        outcome,
        relations,
        metrics,
    })
}

/// Runs a scenario and scores it without writing anything: for a search or a check that
/// needs a run's metrics and gates, not its files.
pub fn evaluate(s: &Scenario, opts: &RunOptions) -> Result<Scored> {
    evaluate_with(s, opts, Vec::new())
}

/// [`evaluate`] with `extra` nodes after the stack's (a ROS 2 link).
pub fn evaluate_with(s: &Scenario, opts: &RunOptions, extra: Vec<Box<dyn Node>>) -> Result<Scored> {
    simulate_scored(s, opts, None, extra)
}

/// Runs a scenario and writes its results into `out` (created or replaced whole).
pub fn run(s: &Scenario, opts: &RunOptions, out: &Path) -> Result<(Value, Outcome)> {
    run_with(s, opts, out, Vec::new())
}

/// [`run`] with `extra` nodes after the stack's (`futago serve`'s ROS 2 link).
pub fn run_with(
    s: &Scenario,
    opts: &RunOptions,
    out: &Path,
    extra: Vec<Box<dyn Node>>,
) -> Result<(Value, Outcome)> {
    write_atomically(out, opts.force, "run", |tmp| {
        // Injected here, the crash leaves a half-written folder behind, as a real one would.
        crash_if_asked(&s.spec.name);
        let scored = simulate_scored(s, opts, Some(tmp), extra)?;
        let relations = &scored.relations;
        let outcome = &scored.outcome;
        std::fs::write(
            tmp.join(RELATIONS_FILE),
            crate::relations::format(relations),
        )
        .with_context(|| format!("writing {RELATIONS_FILE}"))?;
        let config = scenario_text(s);
        std::fs::write(tmp.join(SCENARIO_FILE), &config)
            .with_context(|| format!("writing {SCENARIO_FILE}"))?;
        // Every file the run wrote, but the summary itself and the report (which holds the
        // wall times).
        let mut files = std::collections::BTreeMap::new();
        for f in outcome
            .files
            .iter()
            .map(String::as_str)
            .chain([RELATIONS_FILE, SCENARIO_FILE])
        {
            let digest = match f.strip_suffix('/') {
                Some(dir) => sha256_tree(&tmp.join(dir))?,
                None => sha256_file(&tmp.join(f))?,
            };
            files.insert(f.to_string(), summary::Digest { sha256: digest });
        }
        let typed = Summary::new(s, &scored, files).with_performance(outcome);
        std::fs::write(tmp.join(SUMMARY_FILE), typed.text())
            .with_context(|| format!("writing {SUMMARY_FILE}"))?;
        let sum = typed.to_value();
        if opts.report {
            let resolution = outcome
                .map
                .as_ref()
                .map_or(REPORT_MAP_RESOLUTION, |m| m.resolution);
            let world = stack::world_map(s, resolution, report_height(s))?;
            let html = crate::report::run_report(
                &outcome.truth,
                &sum,
                &config,
                &world,
                outcome.map.as_ref(),
                &outcome.trajectories,
                &outcome.pictures,
            );
            std::fs::write(tmp.join(REPORT_FILE), html)
                .with_context(|| format!("writing {REPORT_FILE}"))?;
        }
        Ok((sum, scored.outcome))
    })
}

/// The height of the world's map drawn in the report: the lowest laser's, or 0.2 m.
fn report_height(s: &Scenario) -> f64 {
    s.lidars
        .iter()
        .map(|(c, _)| c.xyz[2])
        .min_by(f64::total_cmp)
        .unwrap_or(0.2)
}

/// Exit status of a run whose results were written but a gate failed (errors exit with 1).
pub const GATE_FAILED: i32 = 3;

/// The environment variable that makes the run of the scenario it names abort, as a crash in
/// a driver would: fault injection for the tests of `futago suite --isolate`.
pub const CRASH_ENV: &str = "FUTAGO_CRASH_RUN";

/// With [`CRASH_ENV`], the file whose creation makes the crash happen once only: the first run
/// of the scenario creates it and aborts, later ones find it and go on (an intermittent crash,
/// for the tests of the suite's retry).
pub const CRASH_ONCE_ENV: &str = "FUTAGO_CRASH_ONCE";

fn crash_if_asked(name: &str) {
    if std::env::var_os(CRASH_ENV).is_some_and(|v| v == name) {
        if let Some(flag) = std::env::var_os(CRASH_ONCE_ENV) {
            // `create_new` fails when the file exists: the crash has happened already.
            if std::fs::File::create_new(&flag).is_err() {
                return;
            }
        }
        eprintln!("futago: {CRASH_ENV}={name}: aborting, as asked");
        std::process::abort();
    }
}

/// Runs without writing anything (for benchmarks).
pub fn run_in_memory(s: &Scenario, opts: &RunOptions) -> Result<Outcome> {
    simulate_with(s, opts, None, Vec::new()).map(|(o, _)| o)
}

/// Creates `out` whole or not at all: `fill` writes into a temporary folder beside it, which
/// replaces `out` when `fill` succeeds and is removed when it fails or panics (a panic comes
/// back as an error). An existing `out` is replaced only when it is futago's (checked before
/// `fill` runs and again before it goes, see [`crate::output`]) or `force` is given; the new
/// folder's marker names `command` as its writer.
pub fn write_atomically<T>(
    out: &Path,
    force: bool,
    command: &str,
    fill: impl FnOnce(&Path) -> Result<T>,
) -> Result<T> {
    crate::output::check_folder(out, force)?;
    let parent = crate::output::parent_of(out);
    std::fs::create_dir_all(&parent).with_context(|| format!("creating {}", parent.display()))?;
    let name = out
        .file_name()
        .with_context(|| format!("{} is not a folder name", out.display()))?
        .to_string_lossy()
        .to_string();
    let tmp = parent.join(format!(".{name}.partial-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    std::fs::create_dir(&tmp).with_context(|| format!("creating {}", tmp.display()))?;
    // A panic is this run's error, not the process's: the caller (a suite, a search) keeps
    // its other results, and the partial folder goes.
    let filled = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| fill(&tmp)))
        .unwrap_or_else(|panic| {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "no message".into());
            Err(anyhow::anyhow!(
                "internal error (a panic: {what}); nothing was written. Please report it with the input that caused it"
            ))
        })
        .and_then(|r| crate::output::mark(&tmp, command).map(|()| r));
    let r = match filled {
        Ok(r) => r,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&tmp);
            return Err(e);
        }
    };
    if let Ok(meta) = std::fs::symlink_metadata(out) {
        // Checked again: a file put there while the command ran is not deleted. The results
        // stay where they were written.
        crate::output::check_folder(out, force)
            .with_context(|| format!("the results are left in {}", tmp.display()))?;
        if meta.is_dir() {
            std::fs::remove_dir_all(out)
        } else {
            std::fs::remove_file(out)
        }
        .with_context(|| format!("replacing {}", out.display()))?;
    }
    std::fs::rename(&tmp, out).with_context(|| format!("moving results into {}", out.display()))?;
    Ok(r)
}

fn sha256_file(p: &Path) -> Result<String> {
    let bytes = std::fs::read(p).with_context(|| format!("reading back {}", p.display()))?;
    Ok(Sha256::digest(&bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect())
}

/// One digest of a folder: each file's relative path and bytes, in sorted order.
fn sha256_tree(dir: &Path) -> Result<String> {
    fn walk(dir: &Path, root: &Path, out: &mut Vec<PathBuf>) -> Result<()> {
        for e in std::fs::read_dir(dir).with_context(|| format!("listing {}", dir.display()))? {
            let p = e?.path();
            if p.is_dir() {
                walk(&p, root, out)?;
            } else {
                out.push(p.strip_prefix(root)?.to_path_buf());
            }
        }
        Ok(())
    }
    let mut files = Vec::new();
    walk(dir, dir, &mut files)?;
    files.sort();
    let mut h = Sha256::new();
    for f in files {
        h.update(f.to_string_lossy().as_bytes());
        h.update([0]);
        h.update(
            std::fs::read(dir.join(&f)).with_context(|| format!("reading back {}", f.display()))?,
        );
    }
    Ok(h.finalize().iter().map(|b| format!("{b:02x}")).collect())
}

/// Relations sampled from the ground truth (the datasets' `t1 t2 x y z roll pitch yaw`), on
/// which the run's relations metrics are computed; other tools can score against it too.
pub const RELATIONS_FILE: &str = "groundtruth.relations";

/// `futago run`: loads `scenario` with its overlays, runs it into `out` (default
/// `out/<name>`), prints the one-line result and the failed gates, and gives the command's
/// exit status: 0, or [`GATE_FAILED`] when a gate failed.
pub fn command(
    scenario: &Path,
    overlays: &[crate::overlay::Overlay],
    out: Option<PathBuf>,
    opts: &RunOptions,
    runner: Runner,
) -> Result<i32> {
    if let Some(d) = opts.duration
        && !(d.is_finite() && d > 0.0)
    {
        bail!("--duration: expected a positive number of seconds, found {d}");
    }
    let s = crate::stack::load_with(scenario, overlays)?;
    let out = out.unwrap_or_else(|| PathBuf::from("out").join(&s.spec.name));
    let (summary, o) = runner(&s, opts, &out)?;
    Ok(print_result(&s, &summary, &o, &out))
}

/// What runs a loaded scenario into a folder: [`run`], or one that also starts what the
/// scenario needs outside futago (`crate::serve::run_scenario`, a user's ROS 2 stack).
pub type Runner = fn(&Scenario, &RunOptions, &Path) -> Result<(Value, Outcome)>;

/// Prints a run's one-line result and its failed gates; gives the exit status: 0, or
/// [`GATE_FAILED`] when a gate failed.
pub fn print_result(s: &Scenario, summary: &Value, o: &Outcome, out: &Path) -> i32 {
    let rtf = summary["performance"]["real_time_factor"]
        .as_f64()
        .unwrap_or(0.0);
    println!(
        "{}: {:.1} s simulated in {:.2} s ({rtf:.0}× real time), {:.2} m driven, odometry off by {:.3} m; results in {}",
        s.spec.name,
        o.sim_time,
        o.wall_time,
        o.distance_travelled,
        o.final_truth.distance(&o.final_odometry),
        out.display()
    );
    let failed: Vec<&Value> = summary["gates"]
        .as_array()
        .map(|g| g.iter().filter(|r| r["passed"] == false).collect())
        .unwrap_or_default();
    let total = summary["gates"].as_array().map_or(0, |g| g.len());
    if total > 0 {
        println!("gates: {} of {total} passed", total - failed.len());
    }
    for r in &failed {
        eprintln!(
            "futago: gate failed: {}",
            r["message"].as_str().unwrap_or("")
        );
    }
    if failed.is_empty() { 0 } else { GATE_FAILED }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_panic_while_writing_is_an_error_and_leaves_nothing() {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("run");
        let r: Result<()> = write_atomically(&out, false, "test", |dir| {
            std::fs::write(dir.join("half.txt"), "half").unwrap();
            panic!("boom at step 7");
        });
        let e = format!("{:#}", r.unwrap_err());
        assert!(e.contains("boom at step 7"), "{e}");
        assert!(!out.exists());
        assert_eq!(std::fs::read_dir(tmp.path()).unwrap().count(), 0);
        // And a run that succeeds replaces the folder whole.
        write_atomically(&out, false, "test", |dir| {
            Ok(std::fs::write(dir.join("a"), "a")?)
        })
        .unwrap();
        assert!(out.join("a").is_file());
    }
}
