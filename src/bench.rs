//! `futago bench`: the simulator's speed on a real scenario (`sim`), and the sensors' speed in
//! any world (`sensors`): camera images and laser rays per second.

use crate::run::{RunOptions, run_in_memory};
use crate::scenario::Scenario;
use crate::stack::rgbd_map::RgbdMapSpec;
use crate::stack::visual_localization::VisualLocalizationSpec;
use anyhow::{Context, Result, bail};
use futago_msgs::Pose2;
use futago_sim::create::CreateConfig;
use futago_sim::lidar::LidarPreset;
use futago_sim::render::{Intrinsics, Renderer};
use futago_sim::{Movers, PhysicsConfig, Simulation, World};
use glam::{Quat, Vec3};
use rand::{Rng, SeedableRng};
use rapier3d::math::Pose;
use serde_json::{Value, json};
use std::path::Path;
use std::time::Instant;

/// Measures (1) the real-time factor of the scenario (loaded from `path`) with its lasers
/// and stack (`lasers_read` false where no node of the stack reads a laser: scans are made
/// on demand, so that run cast none and timed no laser), (2) without them (physics, robot
/// and controller alone: the lasers, the stack's modules and the gates left out, the
/// controller driving on the true pose), and (3)
/// single-thread ray casts per second from random free poses of the scenario's world with
/// the URG-04LX's and a 30 m beam fan.
pub fn bench(path: &Path, s: &Scenario, duration: Option<f64>, rays: usize) -> Result<Value> {
    let opts = RunOptions {
        seed: None,
        duration,
        progress: false,
        report: false,
        force: false,
    };
    let full = run_in_memory(s, &opts)?;
    let (bare, drives) = physics_only(path, s, duration)?;
    let physics = run_in_memory(&bare, &opts)?;

    let mut sim = Simulation::new(
        &s.world,
        &s.spec.physics,
        &s.spec.robot,
        &[],
        &Movers::default(),
        s.start,
        0,
    );
    sim.step(None); // builds the query structure
    let origins: Vec<Vec3> = free_poses(&sim, &s.world, 256, 0.2)
        .iter()
        .map(|p| p.translation)
        .collect();
    let rates = laser_rates(&mut sim, &origins, rays);
    Ok(json!({
        "scenario": s.spec.name,
        "sim_time_s": full.sim_time,
        "with_lasers": { "wall_time_s": full.wall_time, "real_time_factor": full.sim_time / full.wall_time, "laser_rays": full.laser_rays, "lasers_read": full.laser_rays > 0, "steps": full.steps },
        "physics_only": {
            "wall_time_s": physics.wall_time,
            "real_time_factor": physics.sim_time / physics.wall_time,
            "controller": if drives { "the scenario's, on the true pose" } else { "standing still: the scenario's needs its stack" },
        },
        "ray_casting_one_core": rates,
    }))
}

/// The scenario without its lasers and its stack: only `[controller]` of the modules' tables,
/// on the true pose where it names a pose source (the localiser it would read is gone), and
/// no gates (their metrics are gone with the modules). A controller that cannot drive without
/// them (exploration on SLAM's map, a stop-and-scan survey on its laser) is replaced by a
/// script that stands still for the run's duration. With whether the scenario's own
/// controller drives.
fn physics_only(path: &Path, s: &Scenario, duration: Option<f64>) -> Result<(Scenario, bool)> {
    let mut spec = s.spec.clone();
    spec.lidar.clear();
    spec.gate.clear();
    spec.modules.retain(|k, _| k == "controller");
    if let Some(toml::Value::Table(c)) = spec.modules.get_mut("controller")
        && c.contains_key("pose_source")
    {
        c.insert("pose_source".into(), "ground_truth".into());
    }
    let world = |_: &Path| Ok(s.world.clone());
    if let Ok(bare) = crate::stack::from_spec_with(path, spec.clone(), &mut { world }) {
        return Ok((bare, true));
    }
    // Standing still for the whole run (an idle controller would end the run at once).
    let mut still = toml::Table::new();
    let length = duration.map_or(spec.duration, |d| d.max(spec.duration));
    still.insert("duration".into(), length.into());
    still.insert("velocity".into(), 0.0.into());
    let mut standing = toml::Table::new();
    standing.insert("type".into(), "segments".into());
    standing.insert(
        "segments".into(),
        toml::Value::Array(vec![toml::Value::Table(still)]),
    );
    spec.modules
        .insert("controller".into(), toml::Value::Table(standing));
    let bare = crate::stack::from_spec_with(path, spec, &mut { world }).map_err(|e| {
        anyhow::anyhow!("the scenario without its lasers and stack (physics only): {e}")
    })?;
    Ok((bare, false))
}

/// `n` random camera poses in the world's bounds at height `z`, each with free space around
/// it (no surface within 5 cm along x), any yaw. Deterministic.
fn free_poses(sim: &Simulation, world: &World, n: usize, z: f32) -> Vec<Pose> {
    let (lo, hi) = world.bounds();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let mut out = Vec::new();
    let mut tries = 0;
    while out.len() < n && tries < 100 * n {
        tries += 1;
        let p = Vec3::new(
            rng.random_range(lo.x..=hi.x),
            rng.random_range(lo.y..=hi.y),
            z,
        );
        let yaw: f32 = rng.random_range(-std::f32::consts::PI..std::f32::consts::PI);
        if [
            Vec3::X,
            Vec3::NEG_X,
            Vec3::Y,
            Vec3::NEG_Y,
            Vec3::Z,
            Vec3::NEG_Z,
        ]
        .iter()
        .all(|d| sim.cast_ray(p, *d, 0.05).is_none())
        {
            out.push(Pose::from_parts(p, Quat::from_rotation_z(yaw)));
        }
    }
    out
}

/// Single-thread ray casts per second with 682-beam fans (the URG-04LX's) from `origins`, at
/// the URG's 5.6 m and at 30 m: by the lasers' plan grid ([`Simulation::cast_beam`], what
/// every laser casts with) and by rapier's query pipeline ([`Simulation::cast_ray`]), with
/// each one's count of beams that hit (the same where both agree).
fn laser_rates(sim: &mut Simulation, origins: &[Vec3], rays: usize) -> Value {
    let mut rates = serde_json::Map::new();
    for (label, max) in [
        ("urg04lx_5.6m", LidarPreset::Urg04lx.spec().range_max as f32),
        ("30m", 30.0f32),
    ] {
        let beams = 682usize;
        let dirs: Vec<Vec3> = (0..beams)
            .map(|i| {
                let a = -2.09 + i as f32 * (4.18 / beams as f32);
                Vec3::new(a.cos(), a.sin(), 0.0)
            })
            .collect();
        let time = |cast: &mut dyn FnMut(Vec3, Vec3) -> bool| {
            let t = Instant::now();
            let (mut hits, mut n) = (0usize, 0usize);
            while n < rays && !origins.is_empty() {
                let o = origins[(n / beams) % origins.len()];
                hits += dirs.iter().filter(|d| cast(o, **d)).count();
                n += beams;
            }
            (n, hits, t.elapsed().as_secs_f64())
        };
        let (n, hits, secs) = time(&mut |o, d| sim.cast_beam(o, d, max).is_some());
        let (_, rapier_hits, rapier_secs) = time(&mut |o, d| sim.cast_ray(o, d, max).is_some());
        rates.insert(
            label.into(),
            json!({
                "rays": n, "hits": hits, "seconds": secs, "rays_per_second": n as f64 / secs.max(1e-9),
                "rapier_query_pipeline": { "hits": rapier_hits, "seconds": rapier_secs, "rays_per_second": n as f64 / rapier_secs.max(1e-9) },
            }),
        );
    }
    Value::Object(rates)
}

/// Reads camera poses: one `x,y,z,yaw` per line (metres, radians), `#` comments.
pub fn read_poses(path: &Path) -> Result<Vec<Pose>> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("reading poses from {}", path.display()))?;
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let v: Vec<f32> = line
            .split(',')
            .map(|w| w.trim().parse::<f32>().ok().filter(|x| x.is_finite()))
            .collect::<Option<_>>()
            .filter(|v: &Vec<f32>| v.len() == 4)
            .with_context(|| {
                format!(
                    "{} line {}: expected `x,y,z,yaw` (four finite numbers: metres and radians), found `{line}`",
                    path.display(),
                    i + 1
                )
            })?;
        out.push(Pose::from_parts(
            Vec3::new(v[0], v[1], v[2]),
            Quat::from_rotation_z(v[3]),
        ));
    }
    if out.is_empty() {
        bail!("{}: no poses (expected `x,y,z,yaw` lines)", path.display());
    }
    Ok(out)
}

/// What `futago bench sensors` measures.
#[derive(Debug, Clone)]
pub struct SensorBench {
    /// Frames per single-view workload.
    pub frames: usize,
    /// Views per batch and batches to render.
    pub batch: usize,
    pub batches: usize,
    pub batch_size: (u32, u32),
    /// Rays per laser measurement.
    pub rays: usize,
}

/// Camera and laser throughput in `world` from `poses` (or random free poses at 0.42 m, the
/// default Kinect mount height): 640×480 RGB + depth frames per second, depth alone at
/// 640×480 and 320×240, batched small depth images per second, and laser rays per second.
pub fn bench_sensors(world: &World, poses: Option<Vec<Pose>>, b: &SensorBench) -> Result<Value> {
    let mut sim = Simulation::new(
        world,
        &PhysicsConfig::default(),
        &CreateConfig::default(),
        &[],
        &Movers::default(),
        Pose2::new(1e4, 1e4, 0.0),
        0,
    );
    sim.step(None);
    let poses = match poses {
        Some(p) => p,
        None => free_poses(&sim, world, 64, 0.42),
    };
    if poses.is_empty() {
        bail!(
            "found no free camera pose at 0.42 m inside the bounds of world `{}`; give camera poses with --poses FILE (`x,y,z,yaw` per line)",
            world.name
        );
    }
    let started = Instant::now();
    let mut r = Renderer::new(&world.scene()).context("starting the renderer")?;
    let startup = started.elapsed().as_secs_f64();
    let fov = (57f64.to_radians(), 43f64.to_radians());
    let intr = |w, h| Intrinsics::from_fov(w, h, fov.0, fov.1).map_err(anyhow::Error::msg);
    let vga = intr(640, 480)?;
    let qvga = intr(320, 240)?;
    let small = intr(b.batch_size.0, b.batch_size.1)?;
    let mut out = serde_json::Map::new();
    out.insert("world".into(), json!(world.name));
    out.insert("triangles".into(), json!(world.triangle_count()));
    out.insert("adapter".into(), json!(r.adapter()));
    out.insert("startup_s".into(), json!(startup));
    out.insert("poses".into(), json!(poses.len()));
    let frames = b.frames.max(1);
    let mut valid = 0usize;
    let time = |label: &str,
                out: &mut serde_json::Map<String, Value>,
                f: &mut dyn FnMut(&Pose) -> Result<usize>|
     -> Result<()> {
        // Warm-up: pipelines, targets and driver caches.
        for p in poses.iter().take(3) {
            f(p)?;
        }
        let t = Instant::now();
        let mut n = 0;
        for i in 0..frames {
            n += f(&poses[i % poses.len()])?;
        }
        let secs = t.elapsed().as_secs_f64();
        out.insert(
            label.into(),
            json!({ "frames": frames, "seconds": secs, "frames_per_second": frames as f64 / secs, "valid_pixels": n }),
        );
        Ok(())
    };
    time("rgb_depth_640x480", &mut out, &mut |p| {
        let (_, d) = r.render(&vga, p)?;
        Ok(d.data.iter().filter(|&&z| z > 0.0).count())
    })?;
    time("depth_640x480", &mut out, &mut |p| {
        Ok(r.render_depth(&vga, p)?
            .data
            .iter()
            .filter(|&&z| z > 0.0)
            .count())
    })?;
    time("depth_320x240", &mut out, &mut |p| {
        Ok(r.render_depth(&qvga, p)?
            .data
            .iter()
            .filter(|&&z| z > 0.0)
            .count())
    })?;
    // Seed 000's camera (320×240 depth) with Nguyen et al.'s noise: the noise alone, on the
    // renders of the poses, as each coverage and people frame pays it.
    {
        use futago_sim::kinect::{KinectConfig, KinectPreset, NoiseModel};
        let mut cam = KinectConfig::preset(KinectPreset::Seed000);
        cam.noise.model = NoiseModel::Nguyen;
        let spec = cam
            .resolve(Path::new("bench"), "camera")
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        let clean = poses
            .iter()
            .map(|p| r.render_depth(&spec.depth, p))
            .collect::<Result<Vec<_>, _>>()?;
        // Every pixel, and every 2nd column and row (what the coverage scorer and the depth
        // people detector read: `Node::depth_stride`).
        for (stride, suffix) in [(1, ""), (2, "_grid2")] {
            let mut rng = futago_sim::noise::stream(1, "bench");
            let t = Instant::now();
            let mut n = 0;
            for i in 0..frames {
                let mut d = clean[i % clean.len()].clone();
                spec.apply_noise_on_grid(&mut d, &mut rng, stride);
                n += d.data.iter().filter(|&&z| z > 0.0).count();
            }
            let secs = t.elapsed().as_secs_f64();
            out.insert(
                format!(
                    "nguyen_noise_{}x{}{suffix}",
                    spec.depth.width, spec.depth.height
                ),
                json!({ "frames": frames, "seconds": secs, "frames_per_second": frames as f64 / secs, "ms_per_frame": secs * 1e3 / frames as f64, "valid_pixels": n }),
            );
        }
    }
    let views: Vec<Pose> = (0..b.batch.max(1))
        .map(|i| poses[i % poses.len()])
        .collect();
    let mut buf = Vec::new();
    r.render_depth_batch(&small, &views, futago_render::FAR_PLANE, &mut buf)?;
    let t = Instant::now();
    for _ in 0..b.batches.max(1) {
        r.render_depth_batch(&small, &views, futago_render::FAR_PLANE, &mut buf)?;
        valid += buf.iter().filter(|&&z| z > 0.0).count();
    }
    let secs = t.elapsed().as_secs_f64();
    let images = views.len() * b.batches.max(1);
    out.insert(
        format!("depth_batch_{}x{}", small.width, small.height),
        json!({ "batch": views.len(), "batches": b.batches.max(1), "seconds": secs, "images_per_second": images as f64 / secs, "ms_per_batch": secs * 1e3 / b.batches.max(1) as f64, "valid_pixels": valid }),
    );
    let origins: Vec<Vec3> = poses.iter().map(|p| p.translation).collect();
    out.insert(
        "laser_one_core".into(),
        laser_rates(&mut sim, &origins, b.rays),
    );
    Ok(Value::Object(out))
}

/// MCL update time on a world's own map: the filter tracks the robot at `start` with
/// `particles` particles, one beam every 15°, for each measurement model. The scan is seed
/// 000's laser (240°, 961 beams) cast in the simulator.
pub fn bench_mcl(world: &World, start: Pose2, particles: usize, updates: usize) -> Result<Value> {
    use futago_robot::localization::mcl::{Mcl, MclConfig, MclMap, SensorModel};
    use futago_sim::lidar::{LidarConfig, LidarPreset};
    let grid = futago_sim::world::export::occupancy_grid(world, 0.05, 0.15, 0.25, 0.5)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let lidar = LidarConfig::preset(LidarPreset::Seed000);
    let spec = lidar
        .resolve(Path::new("bench"), "lidar")
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let mut sim = Simulation::new(
        world,
        &PhysicsConfig::default(),
        &CreateConfig::default(),
        &[(lidar.clone(), spec)],
        &Movers::default(),
        start,
        0,
    );
    let scan = loop {
        if let Some((_, s)) = sim.step(None).scans.into_iter().next() {
            break s;
        }
    };
    let mount = lidar.planar_mount();
    let mut out = serde_json::Map::new();
    out.insert("world".into(), json!(world.name));
    out.insert("map_cells".into(), json!(grid.width * grid.height));
    for model in [SensorModel::Beam, SensorModel::LikelihoodField] {
        // The robot stands while every update is timed: the filter must take each scan.
        let config = MclConfig {
            particles,
            model,
            kld: false,
            update_min_d: 0.0,
            update_min_a: 0.0,
            ..MclConfig::default()
        };
        let mut mcl = Mcl::new(config, MclMap::new(grid.clone()), 1);
        mcl.set_pose(start, [0.2, 0.2, 0.1]);
        let odometry = Pose2::IDENTITY;
        mcl.update(&odometry, &scan, &mount);
        let t = Instant::now();
        let mut est = mcl.estimate();
        for _ in 0..updates.max(1) {
            est = mcl.update(&odometry, &scan, &mount);
        }
        let secs = t.elapsed().as_secs_f64() / updates.max(1) as f64;
        out.insert(
            format!("{model:?}"),
            json!({
                "particles": particles,
                "beams_used": (240.0f64 / 15.0).floor() as usize + 1,
                "ms_per_update": secs * 1e3,
                "error_m": est.pose.distance(&start),
            }),
        );
    }
    Ok(Value::Object(out))
}

/// The scenario run in memory with its own seed, for `duration` simulated seconds (its own
/// when none), without progress or report: the nodes' timings are in its performance block.
fn run_quietly(s: &Scenario, duration: Option<f64>) -> Result<crate::run::Outcome> {
    let opts = RunOptions {
        seed: None,
        duration,
        progress: false,
        report: false,
        force: false,
    };
    run_in_memory(s, &opts)
}

/// Processing time per keyframe of the RGB-D map: making a keyframe (floor RANSAC, levelling,
/// features) and each method's registration with the building of its points and planes, on
/// the scenario's own run (one core).
pub fn bench_rgbd(s: &Scenario, duration: Option<f64>) -> Result<Value> {
    if s.module::<RgbdMapSpec>().is_none() {
        bail!("{}: the scenario has no [rgbd_map]", s.spec.name);
    }
    let out = run_quietly(s, duration)?;
    // The mapper's own timings, from its entry of the run's performance block.
    let m = &out.performance["nodes"]["rgbd_map"];
    let count = m["keyframes"]
        .as_u64()
        .context("the run made no RGB-D map")?;
    let keyframes = count.max(1) as f64;
    let methods: serde_json::Map<String, Value> = s
        .module::<RgbdMapSpec>()
        .into_iter()
        .flat_map(|r| r.config.methods.iter())
        .map(|method| {
            let t = m[format!("build_{}_s", method.name())]
                .as_f64()
                .unwrap_or(0.0);
            (
                method.name().to_string(),
                json!({ "seconds": t, "ms_per_keyframe": 1e3 * t / keyframes }),
            )
        })
        .collect();
    Ok(json!({
        "scenario": s.spec.name,
        "keyframes": count,
        "points_per_keyframe": m["points"].as_f64().unwrap_or(0.0) / keyframes,
        "keyframe_ms": 1e3 * m["keyframe_s"].as_f64().unwrap_or(0.0) / keyframes,
        "methods": methods,
    }))
}

/// Seed 001's monocular localisation per frame, on the scenario's own run: SIFT,
/// and for each localiser the selection, the matching (the seed's timed step) and the pose
/// search, their sum, and the delegates' matching speed-up over all landmarks.
pub fn bench_visual(s: &Scenario, duration: Option<f64>) -> Result<Value> {
    if s.module::<VisualLocalizationSpec>().is_none() {
        bail!("{}: the scenario has no [visual_localization]", s.spec.name);
    }
    let out = run_quietly(s, duration)?;
    let m = &out.performance["nodes"]["visual_localization"];
    let sift = m["sift_ms_per_frame"]
        .as_f64()
        .context("the run took no frame")?;
    let mut localisers = serde_json::Map::new();
    for name in ["all", "delegates", "summary", "pnp"] {
        let l = &m[name];
        let (sel, mat, sea) = (
            l["selection_ms"].as_f64().unwrap_or(f64::NAN),
            l["matching_ms"]["mean"].as_f64().unwrap_or(f64::NAN),
            l["search_ms"].as_f64().unwrap_or(f64::NAN),
        );
        localisers.insert(
            name.into(),
            json!({
                "selection_ms": sel,
                "matching_ms": mat,
                "search_ms": sea,
                "frame_ms": sift + sel + mat + sea,
            }),
        );
    }
    Ok(json!({
        "scenario": s.spec.name,
        "frames": m["frames"],
        "sift_ms": sift,
        "localisers": localisers,
        "matching_speedup": m["matching_speedup"],
    }))
}

/// People detection and tracking per scan, and the simulator's speed among people. A robot
/// stands at `start` with a URG-04LX (682 beams) at 0.25 m while `people` walk back and forth
/// across its view, 0.6 m apart, from 1.5 m out; `scans` of its scans are collected, then the
/// leg detector (the shipped model) and the tracker run over them, timed alone. The
/// simulation's real-time factor is measured with the same robot, its laser and
/// `crowd` people walking the same way.
pub fn bench_people(
    world: &World,
    start: Pose2,
    people: usize,
    scans: usize,
    crowd: usize,
) -> Result<Value> {
    use futago_robot::tracking::PeopleConfig;
    use futago_robot::tracking::laser_people::LaserPeople;
    use futago_sim::lidar::LidarConfig;
    use futago_sim::people::PersonConfig;
    let mut lidar = LidarConfig::preset(LidarPreset::Urg04lx);
    lidar.xyz = [0.08, 0.0, 0.25];
    let spec = lidar
        .resolve(Path::new("bench"), "lidar")
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let walkers = |n: usize| Movers {
        people: (0..n)
            .map(|k| {
                let x = 1.5 + 0.6 * (k % 10) as f64;
                let lane = (k / 10) as f64 * 0.3;
                PersonConfig {
                    name: format!("p{k}"),
                    route: vec![
                        start.transform_point([x + lane, -3.0]),
                        start.transform_point([x + lane, 3.0]),
                    ],
                    mode: futago_sim::agent::PathMode::BackAndForth,
                    speed: None,
                    start_time: 0.0,
                    heading_deg: 0.0,
                    yields: true,
                    shirt: [0.3, 0.3, 0.5],
                    trousers: [0.1, 0.1, 0.1],
                }
            })
            .collect(),
        ..Movers::default()
    };
    let lidars = [(lidar.clone(), spec)];
    let mut sim = Simulation::new(
        world,
        &PhysicsConfig::default(),
        &CreateConfig::default(),
        &lidars,
        &walkers(people),
        start,
        1,
    );
    let mut taken = Vec::with_capacity(scans);
    let mut in_view = 0usize;
    while taken.len() < scans {
        for (_, scan) in sim.step(None).scans {
            if sim.time().secs() < 2.0 {
                continue;
            }
            in_view += sim
                .people()
                .iter()
                .filter(|p| {
                    let q = start.inverse().transform_point([p.pose.x, p.pose.y]);
                    q[0] > 0.0 && q[0].hypot(q[1]) < lidars[0].1.range_max
                })
                .count();
            taken.push(scan);
        }
    }
    let model = crate::stack::people::default_model()?;
    let mount = lidar.planar_mount();
    let laser = start.compose(&mount);
    let map = futago_sim::world::export::occupancy_grid(
        world,
        0.05,
        lidar.xyz[2] - 0.05,
        lidar.xyz[2] + 0.05,
        0.5,
    )
    .map_err(|e| anyhow::anyhow!("{e}"))?;
    let mut pipeline = LaserPeople::new(PeopleConfig::default(), model);
    // Taking a map (its distance transform), as the tracker does for each map SLAM
    // publishes, repeated until a quarter second has passed.
    let (mut maps, t) = (0usize, Instant::now());
    while maps == 0 || t.elapsed().as_secs_f64() < 0.25 {
        pipeline.set_map(&map);
        maps += 1;
    }
    let per_map = t.elapsed().as_secs_f64() / maps as f64;
    // The pipeline over the scans, repeated until a quarter second has passed.
    let (mut runs, mut found) = (0usize, 0usize);
    let t = Instant::now();
    while runs == 0 || t.elapsed().as_secs_f64() < 0.25 {
        let mut p = pipeline.clone();
        found = 0;
        for s in &taken {
            found += p.update(s, Some(laser), laser).legs.len();
        }
        runs += 1;
    }
    let per_scan = t.elapsed().as_secs_f64() / (runs * taken.len()) as f64;
    // The simulation among a crowd.
    let mut sim = Simulation::new(
        world,
        &PhysicsConfig::default(),
        &CreateConfig::default(),
        &lidars,
        &walkers(crowd),
        start,
        1,
    );
    let seconds = 20.0;
    let t = Instant::now();
    while sim.time().secs() < seconds {
        sim.step(None);
    }
    let rtf = seconds / t.elapsed().as_secs_f64();
    Ok(json!({
        "world": world.name,
        "laser": {"preset": lidar.preset.name(), "beams": taken.first().map(|s| s.ranges.len())},
        "scans": taken.len(),
        "people": people,
        "people_in_view_per_scan": in_view as f64 / taken.len().max(1) as f64,
        "person_candidates_per_scan": found as f64 / taken.len().max(1) as f64,
        "ms_per_scan_detect_and_track": per_scan * 1e3,
        "map_cells": map.cells.len(),
        "ms_per_map_taken": per_map * 1e3,
        "crowd": crowd,
        "simulation_real_time_factor": rtf,
    }))
}

/// Planning time of each coverage planner on a scenario's map, its region and annotations
/// (the scenario's `[coverage]`), from its start: the median of `repeats` plans, with each
/// route's figures. With a camera, also the second pass's planning as if the camera had seen
/// nothing (every wanted wall a gap: its worst case).
pub fn bench_coverage(s: &Scenario, repeats: usize) -> Result<Value> {
    use futago_robot::navigation::coverage::swept::Swept;
    use futago_robot::navigation::coverage::{self, Field, PlannerKind, second_pass};
    let height = crate::stack::driver::navigation_height(s);
    let map = crate::stack::world_map(s, s.spec.navigation.map_resolution, height)
        .context("navigation.map_resolution")?;
    let start = [s.start.x, s.start.y];
    let repeats = repeats.max(1);
    let median = |mut t: Vec<f64>| {
        t.sort_by(f64::total_cmp);
        t[t.len() / 2]
    };
    let mut planners = serde_json::Map::new();
    for kind in [PlannerKind::Seed000, PlannerKind::Boustrophedon] {
        let config = coverage::CoverageConfig {
            planner: kind,
            ..s.spec.coverage.clone()
        };
        let mut times = Vec::with_capacity(repeats);
        let mut route = None;
        for _ in 0..repeats {
            let t0 = std::time::Instant::now();
            let r = coverage::plan(&map, &config, start)
                .map_err(|e| anyhow::anyhow!("coverage ({}): {e}", kind.name()))?;
            times.push(t0.elapsed().as_secs_f64());
            route = Some(r);
        }
        let stats = route.map(|r| r.stats);
        planners.insert(
            kind.name().into(),
            json!({ "planning_s": median(times), "route": stats }),
        );
    }
    let floor = coverage::restricted(&map, &s.spec.coverage);
    let field = Field::new(&floor, s.spec.coverage.clearance, start)
        .map_err(|e| anyhow::anyhow!("coverage: {e}"))?;
    let sight = second_pass::WallSight::new(&floor);
    // Nothing seen and nothing swept: every wall and the whole route's floor are gaps.
    let route = coverage::plan(&map, &s.spec.coverage, start)
        .map_err(|e| anyhow::anyhow!("coverage: {e}"))?;
    let swept = Swept::new(&field, &route.points);
    let mut times = Vec::with_capacity(repeats);
    let (mut views, mut floor_stops) = (0, 0);
    for _ in 0..repeats {
        let t0 = std::time::Instant::now();
        let second = second_pass::plan(
            &field,
            &sight,
            Some(&swept),
            start,
            &s.spec.coverage.second_pass,
        )
        .map_err(|e| anyhow::anyhow!("coverage.second_pass: {e}"))?;
        times.push(t0.elapsed().as_secs_f64());
        views = second.gaps.iter().map(|g| g.views.len()).sum::<usize>();
        floor_stops = second.floor_stops;
    }
    Ok(json!({
        "scenario": s.spec.name,
        "map_cells": [map.width, map.height],
        "repeats": repeats,
        "planners": planners,
        "second_pass_nothing_seen": { "planning_s": median(times), "views": views, "floor_stops": floor_stops },
    }))
}

/// The SR4000's range, m (MESA's datasheet, as the camera preset).
const SR4000_RANGE: f64 = 5.0;

/// Seed 002's depth-camera MCL: milliseconds per frame (the batched render of every
/// particle's depth, the re-projection of the measured image, the likelihood, weighting and
/// resampling) for each particle count and render size, on the SR4000's 43.6° × 34.6°
/// camera at the Kinect's 0.42 m over `start`, the measured image rendered at the truth:
/// weighed by each of `likelihoods` (the likelihood field in 3D, with no render; the seed's
/// render-and-compare and the per-pixel sensor model, with the render's own time), and the
/// field's build time.
pub fn bench_depth_mcl(
    world: &World,
    start: Pose2,
    particles: &[usize],
    sizes: &[[u32; 2]],
    likelihoods: &[futago_robot::localization::depth_mcl::Likelihood],
    frames: usize,
) -> Result<Value> {
    use crate::stack::depth_localization::{scene_meshes, surface_field};
    use futago_msgs::camera::Intrinsics;
    use futago_robot::localization::depth_mcl::{
        CameraState, DepthMcl, DepthMclConfig, DepthModel, Likelihood, MeshModel, model_far,
        reproject,
    };
    let scene = world.scene();
    let renderer = futago_render::Renderer::new(&scene).context("starting the renderer")?;
    let t = Instant::now();
    let field = surface_field(&scene_meshes(&scene), DepthMclConfig::default().field_cell)?;
    let field_build_s = t.elapsed().as_secs_f64();
    let field_voxels = field.dims();
    let mut model = MeshModel {
        renderer,
        field: Some(field),
    };
    let camera = Intrinsics::from_fov(176, 144, 43.6f64.to_radians(), 34.6f64.to_radians())
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let truth = CameraState {
        position: [
            start.x + 0.1 * start.theta.cos(),
            start.y + 0.1 * start.theta.sin(),
            0.42,
        ],
        rpy: [0.0, 0.0, start.theta],
    };
    let mut measured = Vec::new();
    model
        .render_batch(&camera, &[truth.pose()], SR4000_RANGE, &mut measured)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let image = futago_msgs::camera::DepthImage {
        width: camera.width,
        height: camera.height,
        data: measured,
    };
    let mut rows = Vec::new();
    for &likelihood in likelihoods {
        for &n in particles {
            for &[w, h] in sizes {
                let k = camera.scaled(w, h);
                let config = DepthMclConfig {
                    particles: n,
                    likelihood,
                    ..DepthMclConfig::default()
                };
                let mut mcl = DepthMcl::new(config, truth, 1);
                let z = reproject(&image, &camera, &k);
                mcl.update(&mut model, &k, &z, SR4000_RANGE, None)
                    .map_err(|e| anyhow::anyhow!("{e}"))?;
                let t = Instant::now();
                for _ in 0..frames.max(1) {
                    // The measured image is re-projected every frame, as the node does.
                    let z = reproject(&image, &camera, &k);
                    mcl.update(&mut model, &k, &z, SR4000_RANGE, None)
                        .map_err(|e| anyhow::anyhow!("{e}"))?;
                }
                let ms = t.elapsed().as_secs_f64() * 1e3 / frames.max(1) as f64;
                let mut row = json!({
                    "likelihood": likelihood,
                    "particles": n,
                    "size": [w, h],
                    "ms_per_frame": ms,
                });
                if likelihood != Likelihood::Field {
                    // The render alone, of the particles as the last frame left them.
                    let poses: Vec<_> = mcl.particles().iter().map(|p| p.pose()).collect();
                    let far = model_far(SR4000_RANGE, config.alpha);
                    let mut out = Vec::new();
                    let t = Instant::now();
                    for _ in 0..frames.max(1) {
                        model
                            .render_batch(&k, &poses, far, &mut out)
                            .map_err(|e| anyhow::anyhow!("{e}"))?;
                    }
                    row["render_ms"] =
                        json!(t.elapsed().as_secs_f64() * 1e3 / frames.max(1) as f64);
                }
                rows.push(row);
            }
        }
    }
    let triangles: usize = scene
        .bodies
        .iter()
        .flat_map(|b| &b.parts)
        .map(|p| p.mesh.triangle_count())
        .sum();
    Ok(json!({
        "world": world.name,
        "triangles": triangles,
        "frames": frames,
        "field": { "build_s": field_build_s, "voxels": field_voxels },
        "rows": rows,
    }))
}

/// `--likelihoods` of `futago bench depth-mcl`: each a depth MCL likelihood's name.
pub fn parse_likelihoods(
    names: &[String],
) -> Result<Vec<futago_robot::localization::depth_mcl::Likelihood>> {
    names
        .iter()
        .map(|n| {
            serde_json::from_value(json!(n.trim())).map_err(|_| {
                anyhow::anyhow!("--likelihoods: `{n}`: expected field, seed or sensor")
            })
        })
        .collect()
}

/// A bench's world and the pose of its spawn `spawn`.
pub fn world_at_spawn(
    world: &std::path::Path,
    spawn: &str,
) -> Result<(futago_sim::world::World, futago_msgs::Pose2)> {
    let w = crate::world_cmd::load(world)?;
    let start = w
        .spawn(spawn)
        .with_context(|| format!("world `{}` has no spawn `{spawn}`", w.name))?;
    Ok((w, start))
}

/// `WIDTHxHEIGHT` of option `flag`.
pub fn parse_size(flag: &str, s: &str) -> Result<(u32, u32)> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .with_context(|| format!("{flag}: expected WIDTHxHEIGHT, found `{s}`"))?;
    let w: u32 = w
        .trim()
        .parse()
        .with_context(|| format!("{flag}: `{w}` is not a pixel count"))?;
    let h: u32 = h
        .trim()
        .parse()
        .with_context(|| format!("{flag}: `{h}` is not a pixel count"))?;
    Ok((w, h))
}

/// `--sizes` of `futago bench depth-mcl`: `WIDTHxHEIGHT` each, at most the Kinect's 176 × 144
/// depth-model size.
pub fn parse_depth_sizes(sizes: &[String]) -> Result<Vec<[u32; 2]>> {
    sizes
        .iter()
        .map(|s| match parse_size("--sizes", s)? {
            (w, h) if (1..=176).contains(&w) && (1..=144).contains(&h) => Ok([w, h]),
            _ => Err(anyhow::anyhow!(
                "--sizes: expected at most 176x144, found `{s}`"
            )),
        })
        .collect()
}
