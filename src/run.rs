//! `futago run`: the closed loop of simulator and controller, and the files it writes.
//!
//! The loop is single-threaded and steps on the simulation clock only, so a scenario and a seed
//! always give the same bytes. Outputs go to a temporary folder beside the destination and are
//! renamed into place at the end: a failed or interrupted run leaves no half-written results.

use crate::rgbd::TumRgbdWriter;
use crate::scenario::{MapPose, Scenario};
use anyhow::{Context, Result};
use futago_msgs::camera::Intrinsics;
use futago_msgs::grid::OccupancyGrid;
use futago_msgs::{DriveCommand, Duration, LaserScan, Pose2, Pose3, Time, carmen, tum};
use futago_robot::mcl::{Mcl, MclMap};
use futago_robot::navigation::{NavInput, Navigator, Task};
use futago_robot::odometry::OdometryIntegrator;
use futago_robot::registration::EnvironmentMap;
use futago_robot::rgbd_map::{CameraMount, RgbdMapper};
use futago_robot::script::{ControlInput, ControllerConfig, PoseSource, ScriptedController};
use futago_robot::slam::Slam;
use futago_sim::Simulation;
use futago_sim::kinect::Kinect;
use futago_sim::noise::stream;
use futago_sim::render::Renderer;
use futago_sim::sim::scene;
use serde_json::{Value, json};
use sha2::{Digest, Sha256};
use std::collections::VecDeque;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// The files a run writes, in the order they are listed in the summary.
pub const OUTPUT_FILES: [&str; 3] = ["groundtruth.txt", "odometry.txt", "scans.clf"];

/// The localiser's estimates (TUM), written when the scenario runs one.
pub const LOCALIZATION_FILE: &str = "localization.txt";

/// SLAM's trajectory (TUM, every scan of the first laser, as optimised at the end) and map
/// (`slam_map.pgm`/`.yaml`), written when the scenario runs SLAM.
pub const SLAM_TRAJECTORY_FILE: &str = "slam_trajectory.txt";
pub const SLAM_MAP_STEM: &str = "slam_map";

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
}

/// Text sinks of a run (benchmarks run with none).
struct Sinks {
    groundtruth: BufWriter<File>,
    odometry: BufWriter<File>,
    carmen: Option<BufWriter<File>>,
    /// One TUM RGB-D sequence per camera, when the scenario asks for the dataset.
    cameras: Vec<TumRgbdWriter>,
    /// The localiser's estimates, when one runs.
    localization: Option<BufWriter<File>>,
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
    pub controller_finished: bool,
    /// The localiser's accuracy against the ground truth, when one ran.
    pub localization: Option<Value>,
    /// SLAM's accuracy and counts, when it ran.
    pub slam: Option<Value>,
    /// The navigator's counts, when one drove.
    pub navigation: Option<Value>,
    /// Per lap of a waypoint list driven several times: the return-to-start error of odometry
    /// and of the localiser (their distance from the true pose as the robot reaches the first
    /// waypoint again; seed 000, Fig. 2.8).
    pub laps: Vec<Value>,
    /// SLAM's final trajectory and map, for the files.
    pub slam_result: Option<(Vec<(Time, Pose2)>, OccupancyGrid)>,
    /// The RGB-D map, the true surfaces its keyframes saw, and its counts.
    pub rgbd_map: Option<RgbdMapResult>,
}

/// What an RGB-D mapping run gives: one map per method, the first the run's.
#[derive(Debug, Clone)]
pub struct RgbdMapResult {
    pub maps: Vec<futago_robot::rgbd_map::RgbdMap>,
    /// The true surfaces the keyframes saw.
    pub truth: Vec<[f64; 3]>,
    /// The robot's true pose at each keyframe.
    pub truth_poses: Vec<Pose2>,
    pub counts: Value,
    /// Wall time of making keyframes (levelling, features), and of each method's build, s
    /// (for `futago bench rgbd`; not written to the run's files).
    pub keyframe_seconds: f64,
    pub build_seconds: Vec<f64>,
}

/// The RGB-D map in the loop, on the first camera, with the true surfaces of its keyframes.
struct RgbdRunner {
    mapper: RgbdMapper,
    source: MapPose,
    /// The methods that place the keyframes after the run, the first the run's map.
    methods: Vec<futago_robot::registration::Method>,
    stride: u32,
    max_depth: f64,
    voxel: f64,
    truth: rustc_hash::FxHashMap<[i64; 3], [f64; 3]>,
    /// Truth voxels in the order first seen (deterministic output).
    order: Vec<[i64; 3]>,
    truth_poses: Vec<Pose2>,
    offer_seconds: f64,
}

impl RgbdRunner {
    /// Adds a noiseless depth image taken from `optical` (the optical frame's world pose) to
    /// the true surfaces.
    fn add_truth(
        &mut self,
        depth: &futago_msgs::camera::DepthImage,
        k: &Intrinsics,
        optical: &Pose3,
    ) {
        let [qx, qy, qz, qw] = optical.rotation;
        let q =
            nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(qw, qx, qy, qz));
        let rotate = |v: [f64; 3]| -> [f64; 3] { (q * nalgebra::Vector3::from(v)).into() };
        for v in (0..depth.height).step_by(self.stride as usize) {
            for u in (0..depth.width).step_by(self.stride as usize) {
                let z = depth.at(u, v) as f64;
                if !(z.is_finite() && z > 0.0 && z <= self.max_depth) {
                    continue;
                }
                let r = rotate(k.back_project(u as f64, v as f64, z));
                let w = [
                    r[0] + optical.translation[0],
                    r[1] + optical.translation[1],
                    r[2] + optical.translation[2],
                ];
                let key = w.map(|x| (x / self.voxel).floor() as i64);
                if let std::collections::hash_map::Entry::Vacant(e) = self.truth.entry(key) {
                    e.insert(w);
                    self.order.push(key);
                }
            }
        }
    }
}

/// Monte Carlo localisation in the loop: updates at its rate from the first laser's scans, and
/// the estimate carried forward by odometry in between.
struct Localizer {
    mcl: Mcl,
    period: Duration,
    next: Time,
    mount: Pose2,
    /// Latest estimate and the odometry pose it was made at.
    estimate: Option<(Pose2, Pose2)>,
    updates: u64,
    /// (time s, position error m, heading error rad) at each update.
    errors: Vec<(f64, f64, f64)>,
}

/// A localiser has recovered from a kidnapping when its error is below this, m…
const RECOVERED_M: f64 = 0.3;
/// …and stays so for this long, s.
const RECOVERED_HOLD_S: f64 = 5.0;

/// The world's ground-truth occupancy grid at the first laser's height (the map a perfect
/// mapping run would give).
fn world_map(s: &Scenario, resolution: f64) -> OccupancyGrid {
    let z = s.lidars.first().map(|(c, _)| c.xyz[2]).unwrap_or(0.2);
    futago_sim::world::export::occupancy_grid(&s.world, resolution, z - 0.05, z + 0.05, 0.5)
}

/// Laser SLAM in the loop on the first laser.
struct SlamRunner {
    slam: Slam,
    mount: Pose2,
    /// Odometry pose at the last scan SLAM processed.
    at: Pose2,
    /// (estimate, truth) at each scan, for the accuracy summary.
    errors: Vec<(f64, f64)>,
    /// When the navigator last got a map.
    last_map: Option<Time>,
}

impl SlamRunner {
    /// SLAM's estimate now, carried from its last scan by odometry.
    fn current(&self, odometry: &Pose2) -> Pose2 {
        self.slam.pose().compose(&self.at.between(odometry))
    }
}

/// What drives the robot: a script or the navigator.
enum Driver {
    Scripted(ScriptedController),
    Navigator {
        nav: Box<Navigator>,
        pose_source: Option<PoseSource>,
        odometry: OdometryIntegrator,
        last: Option<DriveCommand>,
    },
}

impl Driver {
    fn finished(&self) -> bool {
        match self {
            Driver::Scripted(c) => c.finished(),
            Driver::Navigator { nav, .. } => nav.finished(),
        }
    }
}

impl Localizer {
    fn new(s: &Scenario, spec: &crate::scenario::LocalizationSpec, seed: u64) -> Localizer {
        use rand::Rng;
        let (cfg, _) = &s.lidars[0];
        let grid = world_map(s, spec.map_resolution);
        let mut mcl = Mcl::new(
            spec.mcl,
            MclMap::new(grid),
            stream(seed, "localization.mcl").random(),
        );
        if !spec.global {
            mcl.set_pose(s.start, spec.initial_sigma);
        }
        Localizer {
            mcl,
            period: Duration::from_secs(1.0 / spec.rate),
            next: Time::ZERO,
            mount: cfg.planar_mount(),
            estimate: None,
            updates: 0,
            errors: Vec::new(),
        }
    }

    /// Seconds from each event time until the error fell below `RECOVERED_M` and stayed there
    /// for `RECOVERED_HOLD_S` (`None`: never).
    fn recovery(&self, events: &[f64]) -> Vec<Option<f64>> {
        events
            .iter()
            .map(|&t0| {
                let after: Vec<&(f64, f64, f64)> =
                    self.errors.iter().filter(|e| e.0 >= t0).collect();
                (0..after.len())
                    .find(|&k| {
                        after[k].1 < RECOVERED_M
                            && after[k..]
                                .iter()
                                .take_while(|e| e.0 <= after[k].0 + RECOVERED_HOLD_S)
                                .all(|e| e.1 < RECOVERED_M)
                            && after
                                .last()
                                .is_some_and(|e| e.0 >= after[k].0 + RECOVERED_HOLD_S)
                    })
                    .map(|k| after[k].0 - t0)
            })
            .collect()
    }

    /// The estimate now, given the odometry pose now.
    fn current(&self, odometry: &Pose2) -> Pose2 {
        match self.estimate {
            Some((est, at)) => est.compose(&at.between(odometry)),
            None => *odometry,
        }
    }
}

/// The odometry pose at `t`, interpolated in the recent history.
fn pose_at(history: &VecDeque<(Time, Pose2)>, t: Time) -> Pose2 {
    let Some(&(t_last, p_last)) = history.back() else {
        return Pose2::IDENTITY;
    };
    if t >= t_last {
        return p_last;
    }
    for (&(t0, p0), &(t1, p1)) in history.iter().zip(history.iter().skip(1)) {
        if t >= t0 && t <= t1 {
            let a = if t1 > t0 {
                (t - t0).secs() / (t1 - t0).secs()
            } else {
                0.0
            };
            let dth = futago_msgs::wrap_angle(p1.theta - p0.theta);
            return Pose2::new(
                p0.x + a * (p1.x - p0.x),
                p0.y + a * (p1.y - p0.y),
                futago_msgs::wrap_angle(p0.theta + a * dth),
            );
        }
    }
    history.front().map(|h| h.1).unwrap_or(p_last)
}

/// Runs the scenario's closed loop, writing into `sinks` when given.
fn simulate(s: &Scenario, opts: &RunOptions, mut sinks: Option<&mut Sinks>) -> Result<Outcome> {
    let seed = opts.seed.unwrap_or(s.spec.seed);
    let duration = opts.duration.unwrap_or(s.spec.duration);
    let spec = &s.spec;
    let mut sim = Simulation::new(
        &s.world,
        &spec.physics,
        &spec.robot,
        &s.lidars,
        s.start,
        seed,
    );
    // Cameras render on demand: only when some consumer takes their frames.
    let consumers =
        sinks.as_deref().map(|k| k.cameras.len()).unwrap_or(0) + s.rgbd_map.is_some() as usize;
    let mut kinects: Vec<Kinect> = s
        .cameras
        .iter()
        .map(|c| Kinect::new(c.clone(), stream(seed, &format!("camera.{}", c.name))))
        .collect();
    let mut renderer = if consumers > 0 {
        Some(
            Renderer::new(&scene(&s.world, &spec.robot, s.start))
                .context("starting the camera renderer")?,
        )
    } else {
        None
    };
    let mut camera_frames = vec![0u64; kinects.len()];
    let mut rgbd = s.rgbd_map.as_ref().map(|m| {
        // The camera's place on the robot: x, y and yaw of its mount (height, pitch and roll
        // come from the floor in each frame).
        let mount = s.cameras[0].mount;
        let forward = mount.rotation * glam::Vec3::X;
        let yaw = (forward.y as f64).atan2(forward.x as f64);
        RgbdRunner {
            mapper: RgbdMapper::new(
                m.config.clone(),
                CameraMount {
                    x: mount.translation.x as f64,
                    y: mount.translation.y as f64,
                    yaw,
                },
                seed,
            ),
            source: m.pose_source,
            methods: m.config.methods.clone(),
            stride: m.config.stride,
            max_depth: m.config.max_depth,
            voxel: m.config.voxel,
            truth: Default::default(),
            order: Vec::new(),
            truth_poses: Vec::new(),
            offer_seconds: 0.0,
        }
    });
    let mut localizer = spec
        .localization
        .as_ref()
        .map(|l| Localizer::new(s, l, seed));
    let mut driver = match &s.controller {
        ControllerConfig::Navigate(n) => Driver::Navigator {
            nav: Box::new(Navigator::new(
                spec.navigation,
                n.task(),
                Some(world_map(s, spec.navigation.map_resolution)),
            )),
            pose_source: Some(n.pose_source),
            odometry: OdometryIntegrator::new(s.start),
            last: None,
        },
        ControllerConfig::Explore(_) => Driver::Navigator {
            nav: Box::new(Navigator::new(spec.navigation, Task::Explore, None)),
            pose_source: None,
            odometry: OdometryIntegrator::new(s.start),
            last: None,
        },
        other => Driver::Scripted(ScriptedController::new(other.clone(), Time::ZERO, s.start)),
    };
    let mut slam = spec.slam.map(|c| {
        let (cfg, _) = &s.lidars[0];
        SlamRunner {
            slam: Slam::new(c, s.start),
            mount: cfg.planar_mount(),
            at: s.start,
            errors: Vec::new(),
            last_map: None,
        }
    });
    let mut last_scan: Option<(LaserScan, Pose2)> = None;
    let mut fresh_map: Option<OccupancyGrid> = None;
    let mut next_event = 0usize;
    let mut laps: Vec<Value> = Vec::new();
    let mut odo = OdometryIntegrator::new(s.start);
    let mut history: VecDeque<(Time, Pose2)> = VecDeque::from([(Time::ZERO, s.start)]);
    let gt_period = Duration::from_secs(1.0 / spec.output.groundtruth_rate);
    let end = Time::from_secs(duration);
    let mut next_gt: i64 = 0;
    let mut scans = vec![0u64; s.lidars.len()];
    let mut distance = 0.0;
    let mut prev_truth = s.start;
    let mut line = String::new();
    let started = std::time::Instant::now();
    let bar = if opts.progress {
        let b = indicatif::ProgressBar::new((duration * 1000.0) as u64);
        b.set_style(
            indicatif::ProgressStyle::with_template(
                "{spinner} {msg} [{bar:40}] {percent}% sim {pos}/{len} ms, eta {eta}",
            )
            .expect("valid template")
            .progress_chars("=> "),
        );
        b.set_message(spec.name.clone());
        Some(b)
    } else {
        None
    };

    if let Some(k) = sinks.as_deref_mut() {
        writeln!(
            k.groundtruth,
            "# futago ground truth of {}: robot base frame in the world frame\n# timestamp tx ty tz qx qy qz qw",
            spec.name
        )?;
        writeln!(
            k.odometry,
            "# futago wheel odometry of {}, integrated from the start pose\n# timestamp tx ty tz qx qy qz qw",
            spec.name
        )?;
        if let Some(c) = k.carmen.as_mut() {
            line.clear();
            carmen::param(&mut line, "robot_name", "create");
            carmen::param(
                &mut line,
                "robot_wheel_base",
                &format!("{}", spec.robot.wheel_base),
            );
            for (i, (cfg, _)) in s.lidars.iter().enumerate() {
                let prefix = if i == 0 {
                    "robot_frontlaser"
                } else {
                    "robot_rearlaser"
                };
                carmen::param(
                    &mut line,
                    &format!("{prefix}_offset"),
                    &format!("{}", cfg.xyz[0]),
                );
                carmen::param(
                    &mut line,
                    &format!("{prefix}_side_offset"),
                    &format!("{}", cfg.xyz[1]),
                );
                carmen::param(
                    &mut line,
                    &format!("{prefix}_angular_offset"),
                    &format!("{}", cfg.rpy_deg[2].to_radians()),
                );
            }
            c.write_all(line.as_bytes())?;
        }
    }
    let write_pose =
        |w: &mut BufWriter<File>, t: Time, p: &Pose2, line: &mut String| -> Result<()> {
            line.clear();
            tum::format_line(
                line,
                &tum::Stamped {
                    stamp: t,
                    pose: Pose3::from_pose2(p, 0.0),
                },
            );
            w.write_all(line.as_bytes())?;
            Ok(())
        };

    if let Some(k) = sinks.as_deref_mut() {
        write_pose(&mut k.odometry, Time::ZERO, &s.start, &mut line)?;
    }
    let mut pending = Vec::new();
    let mut cmd = drive(
        &mut driver,
        &ControlInput {
            now: Time::ZERO,
            odometry: &[],
            bumps: sim.bumps(),
            ground_truth: Some(s.start),
            localization: None,
        },
        None,
        None,
        None,
    );
    loop {
        let now = sim.time();
        if now.nanos() >= next_gt * gt_period.0 {
            next_gt += 1;
            let truth = sim.robot_pose();
            if let Some(k) = sinks.as_deref_mut() {
                write_pose(&mut k.groundtruth, now, &truth, &mut line)?;
                if let Some(c) = k.carmen.as_mut() {
                    line.clear();
                    carmen::truepos(&mut line, now.secs(), &truth, &odo.pose);
                    c.write_all(line.as_bytes())?;
                }
            }
        }
        if now >= end || (driver.finished() && sim.wheel_speeds() == (0.0, 0.0) && cmd.is_none()) {
            break;
        }
        while let Some(e) = spec.event.get(next_event)
            && now.secs() >= e.time
        {
            sim.teleport(e.teleport.pose());
            prev_truth = e.teleport.pose();
            next_event += 1;
        }
        let out = sim.step(cmd.take().as_ref());
        let now = sim.time();
        let truth = sim.robot_pose();
        distance += truth.distance(&prev_truth);
        prev_truth = truth;
        if let Some(o) = out.odometry {
            odo.integrate(&o);
            history.push_back((now, odo.pose));
            while history.len() > 256 {
                history.pop_front();
            }
            pending.push(o);
            if let Some(k) = sinks.as_deref_mut() {
                write_pose(&mut k.odometry, now, &odo.pose, &mut line)?;
                if let Some(c) = k.carmen.as_mut() {
                    let (l, r) = sim.wheel_speeds();
                    line.clear();
                    carmen::odom(
                        &mut line,
                        now.secs(),
                        &odo.pose,
                        (l + r) / 2.0,
                        (r - l) / spec.robot.wheel_base,
                    );
                    c.write_all(line.as_bytes())?;
                }
            }
        }
        if let Some(r) = renderer.as_mut()
            && kinects.iter().any(|c| c.due(now.nanos()))
        {
            let dataset = sinks.as_deref().is_some_and(|k| !k.cameras.is_empty());
            // The 2D pose that places a keyframe, and whether the mapper wants one here.
            let map_pose = rgbd.as_ref().map(|m| match m.source {
                MapPose::GroundTruth => truth,
                MapPose::Odometry => odo.pose,
                MapPose::Localization => localizer
                    .as_ref()
                    .map_or(odo.pose, |l| l.current(&odo.pose)),
                MapPose::Slam => slam.as_ref().map_or(odo.pose, |l| l.current(&odo.pose)),
            });
            let map_wants = match (&rgbd, &map_pose) {
                (Some(m), Some(p)) => m.mapper.wants(p) && kinects[0].due(now.nanos()),
                _ => false,
            };
            if dataset || map_wants {
                // Pose the scene once for every camera due at this step.
                let poses = sim.scene_poses();
                r.set_poses(&poses)?;
                let base = poses[poses.len() - 1];
                for (i, cam) in kinects.iter_mut().enumerate() {
                    let for_map = i == 0 && map_wants;
                    if !cam.due(now.nanos()) || !(dataset || for_map) {
                        continue;
                    }
                    cam.take();
                    let frame = cam.capture(r, &base, now, true)?;
                    if let Some(k) = sinks.as_deref_mut().filter(|_| dataset) {
                        k.cameras[i].write(&frame, &cam.optical_pose(&base))?;
                    }
                    camera_frames[i] += 1;
                    if for_map
                        && let (Some(m), Some(p)) = (rgbd.as_mut(), map_pose)
                        && {
                            let t0 = std::time::Instant::now();
                            let taken = m.mapper.offer(&frame, &p);
                            m.offer_seconds += t0.elapsed().as_secs_f64();
                            taken
                        }
                    {
                        let depth = cam.true_depth(r, &base)?;
                        m.add_truth(&depth, &frame.depth_intrinsics, &cam.optical_pose(&base));
                        m.truth_poses.push(truth);
                    }
                }
            }
        }
        for (i, scan) in out.scans {
            scans[i] += 1;
            if i == 0
                && let Some(r) = slam.as_mut()
            {
                let at = pose_at(&history, scan.stamp);
                let u = r.slam.update(&scan, &at, &r.mount);
                r.at = at;
                r.errors.push((
                    u.pose.distance(&truth),
                    futago_msgs::wrap_angle(u.pose.theta - truth.theta).abs(),
                ));
                // The explorer plans on SLAM's map: hand it a fresh copy twice per re-plan.
                let period = Duration::from_secs(spec.navigation.replan_period / 2.0);
                if matches!(s.controller, ControllerConfig::Explore(_))
                    && r.last_map.is_none_or(|t| now - t >= period)
                {
                    r.last_map = Some(now);
                    fresh_map = Some(r.slam.grid().to_grid());
                }
            }
            if i == 0 && matches!(driver, Driver::Navigator { .. }) {
                last_scan = Some((scan.clone(), s.lidars[0].0.planar_mount()));
            }
            if i == 0
                && let Some(l) = localizer.as_mut()
                && scan.stamp >= l.next
            {
                l.next = scan.stamp + l.period;
                let at = pose_at(&history, scan.stamp);
                let est = l.mcl.update(&at, &scan, &l.mount);
                l.estimate = Some((est.pose, at));
                l.updates += 1;
                let now_est = l.current(&odo.pose);
                l.errors.push((
                    now.secs(),
                    now_est.distance(&truth),
                    futago_msgs::wrap_angle(now_est.theta - truth.theta).abs(),
                ));
                if let Some(k) = sinks.as_deref_mut()
                    && let Some(w) = k.localization.as_mut()
                {
                    write_pose(w, now, &now_est, &mut line)?;
                }
            }
            if let Some(c) = sinks.as_deref_mut().and_then(|k| k.carmen.as_mut()) {
                let robot = pose_at(&history, scan.stamp);
                let cfg = &s.lidars[i].0;
                let laser = robot.compose(&cfg.planar_mount());
                let (l, r) = sim.wheel_speeds();
                line.clear();
                carmen::robotlaser(
                    &mut line,
                    i as u8 + 1,
                    &scan,
                    s.lidars[i].1.sigma,
                    &laser,
                    &robot,
                    (l + r) / 2.0,
                    (r - l) / spec.robot.wheel_base,
                );
                c.write_all(line.as_bytes())?;
            }
        }
        // Control at the rate of the Create's sensor stream.
        if out.odometry.is_some() {
            let localization = localizer.as_ref().map(|l| l.current(&odo.pose));
            cmd = drive(
                &mut driver,
                &ControlInput {
                    now,
                    odometry: &pending,
                    bumps: out.bumps.unwrap_or_default(),
                    ground_truth: Some(truth),
                    localization,
                },
                slam.as_ref().map(|r| r.current(&odo.pose)),
                last_scan.as_ref().map(|(scan, mount)| (scan, *mount)),
                fresh_map.take().as_ref(),
            );
            pending.clear();
            if let Driver::Scripted(c) = &driver
                && c.laps_completed() > laps.len()
            {
                laps.push(json!({
                    "lap": laps.len() + 1,
                    "time_s": now.secs(),
                    "odometry_error_m": odo.pose.distance(&truth),
                    "localization_error_m": localization.map(|l| l.distance(&truth)),
                }));
            }
        }
        if let Some(b) = &bar
            && sim.counters().steps.is_multiple_of(200)
        {
            b.set_position((now.secs() * 1000.0) as u64);
        }
    }
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    let c = sim.counters();
    let navigation = match &driver {
        Driver::Navigator { nav, .. } => Some(json!({
            "stats": nav.stats(),
            "roadmap_nodes": nav.roadmap_nodes(),
        })),
        Driver::Scripted(_) => None,
    };
    let (slam_summary, slam_result) = match slam {
        Some(mut r) => {
            r.slam.finish();
            let n = r.errors.len().max(1) as f64;
            let summary = json!({
                "method": format!("{:?}", r.slam.config().method).to_lowercase(),
                "keyframes": r.slam.keyframes(),
                "loop_closures": r.slam.loop_closures(),
                "optimizations": r.slam.optimizations(),
                "unmatched_scans": r.slam.unmatched(),
                "skipped_scans": r.slam.skipped(),
                "online_mean_position_error_m": r.errors.iter().map(|e| e.0).sum::<f64>() / n,
                "online_max_position_error_m": r.errors.iter().map(|e| e.0).fold(0.0, f64::max),
                "online_mean_heading_error_deg": r.errors.iter().map(|e| e.1).sum::<f64>() / n * 180.0 / std::f64::consts::PI,
                "map_known_area_m2": known_area(&r.slam.grid().to_grid()),
            });
            (
                Some(summary),
                Some((r.slam.trajectory(), r.slam.grid().to_grid())),
            )
        }
        None => (None, None),
    };
    let rgbd_map = rgbd.map(|m| {
        // The 2D map for the map term: SLAM's final map, else the map the localiser was
        // given, at the first laser's height.
        let height = s.lidars.first().map_or(DEFAULT_SLICE_Z, |(c, _)| c.xyz[2]);
        let grid = slam_result.as_ref().map(|(_, g)| g.clone()).or_else(|| {
            spec.localization
                .as_ref()
                .map(|l| world_map(s, l.map_resolution))
        });
        let env = grid
            .as_ref()
            .map(|g| EnvironmentMap::new(g, height, MAP_OCCUPIED));
        let mut build_seconds = Vec::new();
        let maps: Vec<_> = m
            .methods
            .iter()
            .map(|method| {
                let t0 = std::time::Instant::now();
                let map = m.mapper.build(*method, env.as_ref());
                build_seconds.push(t0.elapsed().as_secs_f64());
                map
            })
            .collect();
        let mut counts = serde_json::to_value(m.mapper.counts()).unwrap_or_default();
        counts["environment_map_points"] = json!(env.as_ref().map_or(0, |e| e.len()));
        for map in &maps {
            let (faces, vertices) = map.polygons.size();
            let mut c = serde_json::to_value(map.registration).unwrap_or_default();
            c["planes_found"] = json!(map.polygons.found);
            c["plane_faces"] = json!(faces);
            c["plane_vertices"] = json!(vertices);
            c["map_points"] = json!(map.points.len());
            counts[map.method.name()] = c;
        }
        // The run's map (the first method's) at the top level too.
        if let Some(first) = maps.first() {
            for k in [
                "map_points",
                "planes_found",
                "plane_faces",
                "plane_vertices",
            ] {
                counts[k] = counts[first.method.name()][k].clone();
            }
        }
        RgbdMapResult {
            maps,
            truth: m.order.iter().map(|k| m.truth[k]).collect(),
            truth_poses: m.truth_poses,
            counts,
            keyframe_seconds: m.offer_seconds,
            build_seconds,
        }
    });
    Ok(Outcome {
        rgbd_map,
        slam: slam_summary,
        slam_result,
        navigation,
        laps,
        seed,
        sim_time: sim.time().secs(),
        wall_time: started.elapsed().as_secs_f64(),
        steps: c.steps,
        scans,
        camera_frames,
        renderer: renderer.map(|r| r.adapter()),
        laser_rays: c.laser_rays,
        bump_events: c.bump_events,
        wheel_drop_steps: c.wheel_drop_steps,
        distance_travelled: distance,
        final_truth: sim.robot_pose(),
        final_odometry: odo.pose,
        controller_finished: driver.finished(),
        localization: localizer.map(|l| {
            let n = l.errors.len().max(1) as f64;
            let events: Vec<f64> = spec.event.iter().map(|e| e.time).collect();
            let mut v = json!({
                "updates": l.updates,
                "mean_position_error_m": l.errors.iter().map(|e| e.1).sum::<f64>() / n,
                "max_position_error_m": l.errors.iter().map(|e| e.1).fold(0.0, f64::max),
                "final_position_error_m": l.errors.last().map(|e| e.1),
                "mean_heading_error_deg": l.errors.iter().map(|e| e.2).sum::<f64>() / n * 180.0 / std::f64::consts::PI,
            });
            let end = sim.time().secs();
            // Not recovered by the end counts as the rest of the run (a lower bound).
            let worst = |ts: &[f64]| {
                ts.iter()
                    .zip(l.recovery(ts))
                    .map(|(t, r)| r.unwrap_or(end - t))
                    .fold(0.0, f64::max)
            };
            if !events.is_empty() {
                v["kidnappings"] = json!(events.iter().zip(l.recovery(&events)).map(|(t, r)| json!({
                    "time_s": t,
                    "recovered_after_s": r,
                    "recovered_when": format!("error < {RECOVERED_M} m for {RECOVERED_HOLD_S} s"),
                })).collect::<Vec<_>>());
                v["recovery_s"] = json!(worst(&events));
            }
            if spec.localization.as_ref().is_some_and(|l| l.global) {
                v["convergence_s"] = json!(worst(&[0.0]));
            }
            v
        }),
    })
}

/// Area of a grid's known cells, m².
fn known_area(g: &OccupancyGrid) -> f64 {
    g.cells.iter().filter(|&&c| c >= 0).count() as f64 * g.resolution * g.resolution
}

/// One control tick of whichever drives the robot; returns a command when it changed.
fn drive(
    driver: &mut Driver,
    input: &ControlInput,
    slam_pose: Option<Pose2>,
    scan: Option<(&LaserScan, Pose2)>,
    map: Option<&OccupancyGrid>,
) -> Option<DriveCommand> {
    match driver {
        Driver::Scripted(c) => c.update(input),
        Driver::Navigator {
            nav,
            pose_source,
            odometry,
            last,
        } => {
            for o in input.odometry {
                odometry.integrate(o);
            }
            let pose = match pose_source {
                Some(PoseSource::GroundTruth) => input.ground_truth,
                Some(PoseSource::Localization) => input.localization,
                Some(PoseSource::Odometry) => Some(odometry.pose),
                None => slam_pose,
            }
            .unwrap_or(odometry.pose);
            let cmd = nav.update(&NavInput {
                now: input.now,
                pose,
                bumps: input.bumps,
                scan,
                map,
            });
            (*last != Some(cmd)).then(|| {
                *last = Some(cmd);
                cmd
            })
        }
    }
}

/// Runs without writing anything (for benchmarks).
pub fn run_in_memory(s: &Scenario, opts: &RunOptions) -> Result<Outcome> {
    simulate(s, opts, None)
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

/// The RGB-D map (binary PLY, coloured points in the world frame).
pub const RGBD_MAP_FILE: &str = "rgbd_map.ply";
/// Half the height of the laser-height slice of a 3D map, m.
const SLICE_HALF_WIDTH: f64 = 0.05;
/// The slice's height without a laser, m.
const DEFAULT_SLICE_Z: f64 = 0.2;
/// Cells of the 2D map at least this occupied (0–100) are walls for the map term.
const MAP_OCCUPIED: i8 = 50;

/// One RGB-D map's scores (metric names below `rgbd_map.`): the cloud against the true
/// surfaces, the laser-height slice against the true walls (seed 000 judged its methods by how
/// thin and true this trace was), the keyframes' poses against the truth and the planes
/// against the true surfaces.
fn score_rgbd_map(
    map: &futago_robot::rgbd_map::RgbdMap,
    run: &RgbdMapResult,
    walls: &OccupancyGrid,
    z: f64,
) -> Vec<(String, f64)> {
    let mut out = Vec::new();
    let points: Vec<[f64; 3]> = map.points.iter().map(|p| p.0).collect();
    if let Some(score) = crate::ground_truth::cloud::score(&points, &run.truth) {
        out.extend(score.named());
    }
    let band: Vec<[f64; 3]> = points
        .iter()
        .filter(|p| (p[2] - z).abs() <= SLICE_HALF_WIDTH)
        .copied()
        .collect();
    if let Some(t) = crate::ground_truth::cloud::thickness(&band, &run.truth) {
        out.push(("slice_thickness_m".into(), t));
    }
    let slice: Vec<[f64; 2]> = band.iter().map(|p| [p[0], p[1]]).collect();
    if !slice.is_empty() {
        let mut d = crate::ground_truth::map::wall_distances(walls, &slice);
        let rms = (d.iter().map(|x| x * x).sum::<f64>() / d.len() as f64).sqrt();
        d.sort_by(f64::total_cmp);
        out.push(("slice_rms_m".into(), rms));
        out.push(("slice_median_m".into(), d[d.len() / 2]));
    }
    let errors: Vec<(f64, f64)> = map
        .poses
        .iter()
        .zip(&run.truth_poses)
        .map(|(p, t)| {
            (
                p.distance(t),
                futago_msgs::wrap_angle(p.theta - t.theta).to_degrees(),
            )
        })
        .collect();
    if !errors.is_empty() {
        let n = errors.len() as f64;
        let rms = |f: fn(&(f64, f64)) -> f64| {
            (errors.iter().map(|e| f(e).powi(2)).sum::<f64>() / n).sqrt()
        };
        out.push(("keyframe_pose.rmse_m".into(), rms(|e| e.0)));
        out.push((
            "keyframe_pose.max_m".into(),
            errors.iter().map(|e| e.0).fold(0.0, f64::max),
        ));
        out.push(("keyframe_pose.rmse_deg".into(), rms(|e| e.1)));
    }
    if let Some(p) = crate::ground_truth::planes::score(&map.polygons.polygons, &run.truth) {
        out.push(("planes.angle_mean_deg".into(), p.angle_mean_deg));
        out.push(("planes.offset_mean_m".into(), p.offset_mean_m));
    }
    let (faces, vertices) = map.polygons.size();
    out.push(("planes.faces".into(), faces as f64));
    out.push(("planes.vertices".into(), vertices as f64));
    out
}

/// The polygon map (binary PLY mesh, a face per plane).
pub const RGBD_PLANES_FILE: &str = "rgbd_planes.ply";
/// The true surfaces its keyframes saw (binary PLY), against which it is scored.
pub const RGBD_TRUTH_FILE: &str = "rgbd_map_truth.ply";
/// The RGB-D map's laser-height slice (red) over the world's true 2D map, 1 cm a pixel.
pub const RGBD_SLICE_FILE: &str = "rgbd_slice.png";
/// Cell of the true 2D map under the slice picture, m (5 px of 1 cm each).
const SLICE_MAP_RESOLUTION: f64 = 0.05;

/// The run's HTML report (see [`crate::report`]).
pub const REPORT_FILE: &str = "report.html";

/// Cell size of the ground-truth map drawn in reports of runs without SLAM, m.
const REPORT_MAP_RESOLUTION: f64 = 0.05;

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

/// The deterministic part of a run's summary (everything but `performance`).
pub fn summary(s: &Scenario, o: &Outcome, files: Value) -> Value {
    let err = o.final_truth.distance(&o.final_odometry);
    let herr = futago_msgs::wrap_angle(o.final_odometry.theta - o.final_truth.theta).to_degrees();
    json!({
        "scenario": s.spec.name,
        "description": s.spec.description,
        "world": s.world.name,
        "seed": o.seed,
        "overlays": s.overlays.iter().map(|o| o.origin.display().to_string()).collect::<Vec<_>>(),
        "sim_time_s": o.sim_time,
        "physics_rate_hz": s.spec.physics.rate,
        "steps": o.steps,
        "controller_finished": o.controller_finished,
        "robot": {
            "start": [s.start.x, s.start.y, s.start.theta],
            "final_pose": [o.final_truth.x, o.final_truth.y, o.final_truth.theta],
            "distance_travelled_m": o.distance_travelled,
            "bump_events": o.bump_events,
            "wheel_drop_steps": o.wheel_drop_steps,
        },
        "odometry": {
            "final_pose": [o.final_odometry.x, o.final_odometry.y, o.final_odometry.theta],
            "final_position_error_m": err,
            "final_heading_error_deg": herr,
        },
        "lidar": s.lidars.iter().zip(&o.scans).map(|((c, _), n)| json!({ "name": c.name, "preset": c.preset.name(), "scans": n })).collect::<Vec<_>>(),
        "camera": s.cameras.iter().zip(&o.camera_frames).map(|(c, n)| json!({
            "name": c.name,
            "rgb": [c.rgb.width, c.rgb.height],
            "depth": [c.depth.width, c.depth.height],
            "rate_hz": c.rate,
            "frames": n,
        })).collect::<Vec<_>>(),
        "laser_rays": o.laser_rays,
        "localization": o.localization,
        "laps": o.laps,
        "slam": o.slam,
        "navigation": o.navigation,
        "files": files,
    })
}

/// Creates `out` whole or not at all: `fill` writes into a temporary folder beside it, which
/// replaces `out` when `fill` succeeds and is removed when it fails.
pub fn write_atomically<T>(out: &Path, fill: impl FnOnce(&Path) -> Result<T>) -> Result<T> {
    let parent = match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&parent).with_context(|| format!("creating {}", parent.display()))?;
    let name = out
        .file_name()
        .with_context(|| format!("{} is not a folder name", out.display()))?
        .to_string_lossy()
        .to_string();
    let tmp = parent.join(format!(".{name}.partial-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    std::fs::create_dir(&tmp).with_context(|| format!("creating {}", tmp.display()))?;
    match fill(&tmp) {
        Ok(r) => {
            if out.exists() {
                std::fs::remove_dir_all(out)
                    .with_context(|| format!("replacing {}", out.display()))?;
            }
            std::fs::rename(&tmp, out)
                .with_context(|| format!("moving results into {}", out.display()))?;
            Ok(r)
        }
        Err(e) => {
            let _ = std::fs::remove_dir_all(&tmp);
            Err(e)
        }
    }
}

/// Runs a scenario and writes its results into `out` (created or replaced whole).
pub fn run(s: &Scenario, opts: &RunOptions, out: &Path) -> Result<(Value, Outcome)> {
    write_atomically(out, |tmp| {
        let open = |n: &str| -> Result<BufWriter<File>> {
            Ok(BufWriter::new(
                File::create(tmp.join(n)).with_context(|| format!("creating {n}"))?,
            ))
        };
        let mut sinks = Sinks {
            groundtruth: open(OUTPUT_FILES[0])?,
            odometry: open(OUTPUT_FILES[1])?,
            carmen: if s.spec.output.carmen {
                Some(open(OUTPUT_FILES[2])?)
            } else {
                None
            },
            localization: if s.spec.localization.is_some() {
                Some(open(LOCALIZATION_FILE)?)
            } else {
                None
            },
            cameras: if s.spec.output.rgbd_dataset {
                s.cameras
                    .iter()
                    .map(|c| {
                        TumRgbdWriter::create(
                            &tmp.join(&c.name),
                            &c.name,
                            &s.spec.name,
                            &c.rgb,
                            &c.depth,
                            (c.range_min, c.range_max),
                        )
                    })
                    .collect::<Result<_>>()?
            } else {
                Vec::new()
            },
        };
        let outcome = simulate(s, opts, Some(&mut sinks))?;
        sinks.groundtruth.flush()?;
        sinks.odometry.flush()?;
        if let Some(c) = sinks.carmen.as_mut() {
            c.flush()?;
        }
        if let Some(c) = sinks.localization.as_mut() {
            c.flush()?;
        }
        for c in std::mem::take(&mut sinks.cameras) {
            c.finish()?;
        }
        drop(sinks);
        if let Some((trajectory, map)) = &outcome.slam_result {
            let mut text = format!(
                "# futago SLAM of {} (first laser), optimised at the end\n# timestamp tx ty tz qx qy qz qw\n",
                s.spec.name
            );
            for (t, p) in trajectory {
                tum::format_line(
                    &mut text,
                    &tum::Stamped {
                        stamp: *t,
                        pose: Pose3::from_pose2(p, 0.0),
                    },
                );
            }
            std::fs::write(tmp.join(SLAM_TRAJECTORY_FILE), text)
                .with_context(|| format!("writing {SLAM_TRAJECTORY_FILE}"))?;
            map.write_map_server(tmp, SLAM_MAP_STEM)
                .with_context(|| format!("writing {SLAM_MAP_STEM}.pgm and .yaml"))?;
        }
        if let Some(m) = &outcome.rgbd_map {
            let first = &m.maps[0];
            let comment = format!(
                "futago RGB-D map of {} placed by {} (world frame, m)",
                s.spec.name,
                first.method.name()
            );
            std::fs::write(
                tmp.join(RGBD_MAP_FILE),
                futago_msgs::ply::points(&first.points, &comment),
            )
            .with_context(|| format!("writing {RGBD_MAP_FILE}"))?;
            let truth: Vec<([f64; 3], [u8; 3])> =
                m.truth.iter().map(|p| (*p, [26, 150, 65])).collect();
            let comment = format!(
                "futago: the true surfaces the RGB-D map's keyframes saw, {}",
                s.spec.name
            );
            std::fs::write(
                tmp.join(RGBD_TRUTH_FILE),
                futago_msgs::ply::points(&truth, &comment),
            )
            .with_context(|| format!("writing {RGBD_TRUTH_FILE}"))?;
            let planes = first.polygons.to_ply(&format!(
                "futago polygon map of {} placed by {} (world frame, m)",
                s.spec.name,
                first.method.name()
            ));
            std::fs::write(tmp.join(RGBD_PLANES_FILE), planes)
                .with_context(|| format!("writing {RGBD_PLANES_FILE}"))?;
            let z = s.lidars.first().map_or(DEFAULT_SLICE_Z, |(c, _)| c.xyz[2]);
            let slice: Vec<[f64; 2]> = first
                .points
                .iter()
                .filter(|p| (p.0[2] - z).abs() <= SLICE_HALF_WIDTH)
                .map(|p| [p.0[0], p.0[1]])
                .collect();
            let grid = world_map(s, SLICE_MAP_RESOLUTION);
            std::fs::write(
                tmp.join(RGBD_SLICE_FILE),
                crate::report::points_over_map_png(&grid, &slice, 5),
            )
            .with_context(|| format!("writing {RGBD_SLICE_FILE}"))?;
        }
        let mut files = serde_json::Map::new();
        let slam_map = format!("{SLAM_MAP_STEM}.pgm");
        for f in OUTPUT_FILES.iter().chain([
            &LOCALIZATION_FILE,
            &SLAM_TRAJECTORY_FILE,
            &slam_map.as_str(),
            &RGBD_MAP_FILE,
            &RGBD_TRUTH_FILE,
            &RGBD_PLANES_FILE,
            &RGBD_SLICE_FILE,
        ]) {
            let p = tmp.join(f);
            if p.exists() {
                files.insert(f.to_string(), json!({ "sha256": sha256_file(&p)? }));
            }
        }
        if s.spec.output.rgbd_dataset {
            for c in &s.cameras {
                files.insert(
                    format!("{}/", c.name),
                    json!({ "sha256": sha256_tree(&tmp.join(&c.name))? }),
                );
            }
        }
        let mut sum = summary(s, &outcome, Value::Object(files));
        let truth_text = std::fs::read_to_string(tmp.join(OUTPUT_FILES[0]))
            .with_context(|| format!("reading back {}", OUTPUT_FILES[0]))?;
        let truth_poses = tum::parse(&truth_text)
            .map_err(|e| anyhow::anyhow!("reading back {}: {e}", OUTPUT_FILES[0]))?;
        let relations = crate::ground_truth::sample_relations(&truth_poses);
        std::fs::write(
            tmp.join(RELATIONS_FILE),
            crate::relations::format(&relations),
        )
        .with_context(|| format!("writing {RELATIONS_FILE}"))?;
        let mut metrics = crate::ground_truth::score_trajectories(tmp, &truth_poses, &relations)?;
        for k in ["recovery_s", "convergence_s"] {
            if let Some(v) = outcome.localization.as_ref().and_then(|l| l[k].as_f64()) {
                metrics.insert(format!("localization.{k}"), v);
            }
        }
        let truth = world_map(
            s,
            outcome
                .slam_result
                .as_ref()
                .map_or(REPORT_MAP_RESOLUTION, |(_, m)| m.resolution),
        );
        if let Some((_, map)) = &outcome.slam_result {
            let m = crate::ground_truth::map::score(map, &truth, [s.start.x, s.start.y])
                .map_err(|e| anyhow::anyhow!("scoring the SLAM map: {e}"))?;
            metrics.insert_map("slam.map", &m);
        }
        if let Some(m) = &outcome.rgbd_map {
            let mut counts = m.counts.clone();
            counts["truth_points"] = json!(m.truth.len());
            let z = s.lidars.first().map_or(DEFAULT_SLICE_Z, |(c, _)| c.xyz[2]);
            for (k, map) in m.maps.iter().enumerate() {
                let found = score_rgbd_map(map, m, &truth, z);
                if k == 0 {
                    for (name, v) in &found {
                        metrics.insert(format!("rgbd_map.{name}"), *v);
                    }
                }
                for (name, v) in found {
                    metrics.insert(format!("rgbd_map.{}.{name}", map.method.name()), v);
                }
            }
            sum["rgbd_map"] = counts;
        }
        sum["gates"] = serde_json::to_value(crate::ground_truth::evaluate(&s.spec.gate, &metrics))?;
        sum["metrics"] = serde_json::to_value(metrics)?;
        sum["performance"] = json!({
            "renderer": outcome.renderer,
            "wall_time_s": outcome.wall_time,
            "real_time_factor": if outcome.wall_time > 0.0 { outcome.sim_time / outcome.wall_time } else { 0.0 },
        });
        let text = serde_json::to_string_pretty(&sum)? + "\n";
        std::fs::write(tmp.join("summary.json"), text).context("writing summary.json")?;
        let config = scenario_text(s);
        std::fs::write(tmp.join(SCENARIO_FILE), &config)
            .with_context(|| format!("writing {SCENARIO_FILE}"))?;
        if opts.report {
            let html = crate::report::run_report(
                tmp,
                &sum,
                &config,
                &truth,
                outcome.slam_result.as_ref().map(|(_, m)| m),
            );
            std::fs::write(tmp.join(REPORT_FILE), html)
                .with_context(|| format!("writing {REPORT_FILE}"))?;
        }
        Ok((sum, outcome))
    })
}
