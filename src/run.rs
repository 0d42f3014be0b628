//! `futago run`: the closed loop of simulator and controller, and the files it writes.
//!
//! The loop is single-threaded and steps on the simulation clock only, so a scenario and a seed
//! always give the same bytes. Outputs go to a temporary folder beside the destination and are
//! renamed into place at the end: a failed or interrupted run leaves no half-written results.

use crate::rgbd::TumRgbdWriter;
use crate::scenario::Scenario;
use anyhow::{Context, Result};
use futago_msgs::{Duration, Pose2, Pose3, Time, carmen, tum};
use futago_robot::mcl::{Mcl, MclMap};
use futago_robot::odometry::OdometryIntegrator;
use futago_robot::script::{ControlInput, ScriptedController};
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

/// Options of one run.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// Overrides the scenario's seed.
    pub seed: Option<u64>,
    /// Overrides the scenario's duration, s.
    pub duration: Option<f64>,
    /// Show a progress bar (on a terminal).
    pub progress: bool,
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
    errors: Vec<(f64, f64)>,
}

impl Localizer {
    fn new(s: &Scenario, spec: &crate::scenario::LocalizationSpec, seed: u64) -> Localizer {
        use rand::Rng;
        let (cfg, _) = &s.lidars[0];
        let z = cfg.xyz[2];
        let grid = futago_sim::world::export::occupancy_grid(
            &s.world,
            spec.map_resolution,
            z - 0.05,
            z + 0.05,
            0.5,
        );
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
            mount: Pose2::new(cfg.xyz[0], cfg.xyz[1], cfg.rpy_deg[2].to_radians()),
            estimate: None,
            updates: 0,
            errors: Vec::new(),
        }
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
    let consumers = sinks.as_deref().map(|k| k.cameras.len()).unwrap_or(0);
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
    let mut localizer = spec
        .localization
        .as_ref()
        .map(|l| Localizer::new(s, l, seed));
    let mut ctl = ScriptedController::new(s.controller.clone(), Time::ZERO, s.start);
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
    let mut cmd = ctl.update(&ControlInput {
        now: Time::ZERO,
        odometry: &[],
        bumps: sim.bumps(),
        ground_truth: Some(s.start),
        localization: None,
    });
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
        if now >= end || (ctl.finished() && sim.wheel_speeds() == (0.0, 0.0) && cmd.is_none()) {
            break;
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
        if let (Some(r), Some(k)) = (renderer.as_mut(), sinks.as_deref_mut())
            && kinects.iter().any(|c| c.due(now.nanos()))
        {
            // Pose the scene once for every camera due at this step.
            let poses = sim.scene_poses();
            r.set_poses(&poses)?;
            let base = poses[poses.len() - 1];
            for (i, cam) in kinects.iter_mut().enumerate() {
                if cam.due(now.nanos()) {
                    cam.take();
                    let frame = cam.capture(r, &base, now, true)?;
                    k.cameras[i].write(&frame, &cam.optical_pose(&base))?;
                    camera_frames[i] += 1;
                }
            }
        }
        for (i, scan) in out.scans {
            scans[i] += 1;
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
                let laser = robot.compose(&Pose2::new(
                    cfg.xyz[0],
                    cfg.xyz[1],
                    cfg.rpy_deg[2].to_radians(),
                ));
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
            cmd = ctl.update(&ControlInput {
                now,
                odometry: &pending,
                bumps: out.bumps.unwrap_or_default(),
                ground_truth: Some(truth),
                localization: localizer.as_ref().map(|l| l.current(&odo.pose)),
            });
            pending.clear();
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
    Ok(Outcome {
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
        controller_finished: ctl.finished(),
        localization: localizer.map(|l| {
            let n = l.errors.len().max(1) as f64;
            json!({
                "updates": l.updates,
                "mean_position_error_m": l.errors.iter().map(|e| e.0).sum::<f64>() / n,
                "max_position_error_m": l.errors.iter().map(|e| e.0).fold(0.0, f64::max),
                "final_position_error_m": l.errors.last().map(|e| e.0),
                "mean_heading_error_deg": l.errors.iter().map(|e| e.1).sum::<f64>() / n * 180.0 / std::f64::consts::PI,
            })
        }),
    })
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

/// The deterministic part of a run's summary (everything but `performance`).
pub fn summary(s: &Scenario, o: &Outcome, files: Value) -> Value {
    let err = o.final_truth.distance(&o.final_odometry);
    let herr = futago_msgs::wrap_angle(o.final_odometry.theta - o.final_truth.theta).to_degrees();
    json!({
        "scenario": s.spec.name,
        "description": s.spec.description,
        "world": s.world.name,
        "seed": o.seed,
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
        let mut files = serde_json::Map::new();
        for f in OUTPUT_FILES.iter().chain([&LOCALIZATION_FILE]) {
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
        sum["performance"] = json!({
            "renderer": outcome.renderer,
            "wall_time_s": outcome.wall_time,
            "real_time_factor": if outcome.wall_time > 0.0 { outcome.sim_time / outcome.wall_time } else { 0.0 },
        });
        let text = serde_json::to_string_pretty(&sum)? + "\n";
        std::fs::write(tmp.join("summary.json"), text).context("writing summary.json")?;
        Ok((sum, outcome))
    })
}
