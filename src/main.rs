//! The `futago` command: runs scenarios, exports worlds' ground truth and measures speed.

use futago::{
    bench, calibrate, crowd, folds, fuzz, legs_train, overlay, replay, run, serve, stack, suite,
    tune, twin, world_cmd,
};

use anyhow::{Result, bail};
use clap::{Parser, Subcommand};
use std::path::PathBuf;

#[derive(Parser)]
#[command(
    name = "futago",
    version,
    about = "futago (双子, twin): a simulation-first digital twin of a small indoor robot",
    long_about = "futago simulates an iRobot Create with a laser range finder in a rapier physics world, runs a controller in closed loop on it, and writes the robot's sensor data beside the ground truth. Worlds and scenarios are TOML files (see worlds/ and scenarios/)."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a scenario and write its results: groundtruth.txt and odometry.txt (TUM), scans.clf
    /// (CARMEN log) and summary.json.
    Run(RunArgs),
    /// Serve a scenario over ROS 2 (DDS): publish the robot's sensors, tf and /clock, and
    /// take /cmd_vel from the user's own stack in lock-step (the simulation waits for the
    /// command of each control tick); then score the run as `futago run` does.
    Serve(ServeArgs),
    /// Write a finished run's folder as a ROS 2 bag: an MCAP file (scans, odometry, tf, ground
    /// truth, its map, /clock) with rosbag2's metadata.yaml, for ros2 bag play and Foxglove.
    Export {
        /// The folder `futago run` wrote.
        run: PathBuf,
        /// Where the bag goes [default: RUN.ros2 beside the run folder].
        #[arg(long)]
        out: Option<PathBuf>,
        /// Replace the output even when it holds files futago did not write (never `/`, the
        /// home folder, the current folder or its parents, or a folder with a `.git`).
        #[arg(long)]
        force: bool,
    },
    /// Run the robot stack's SLAM on a real robot's log (CARMEN, ROS 1 bag, or ROS 2 bag: a
    /// rosbag2 folder, .mcap or .db3) and score it against
    /// ground-truth relations (Kümmerle et al. 2009): writes trajectory.txt, odometry.txt (TUM),
    /// map.pgm/map.yaml and summary.json.
    Replay {
        /// The log (CARMEN: .clf, .log; ROS 1 bag: .bag).
        log: std::path::PathBuf,
        /// Ground-truth relations (`t1 t2 x y z roll pitch yaw` per line).
        #[arg(long)]
        relations: Option<std::path::PathBuf>,
        /// Output folder, created or replaced whole when futago wrote it [default:
        /// out/replay/<log name>].
        #[arg(long)]
        out: Option<std::path::PathBuf>,
        /// Replace the output even when it holds files futago did not write (never `/`, the
        /// home folder, the current folder or its parents, or a folder with a `.git`).
        #[arg(long)]
        force: bool,
        /// SLAM parameters: a TOML file of the `[slam]` table's keys (method,
        /// keyframe_distance, icp.max_distance_start, graph.loop_min_score, …).
        #[arg(long)]
        config: Option<std::path::PathBuf>,
        /// SLAM method, over the config file's: `graph` (loop closure; the default) or `icp`
        /// (seed 000's baseline).
        #[arg(long)]
        method: Option<String>,
        /// Refuse a damaged log (cut short, a chunk or line that does not parse) instead of
        /// replaying what it holds and saying what was lost.
        #[arg(long)]
        strict: bool,
        /// The bag's sensor_msgs/LaserScan topic, where it has several.
        #[arg(long, value_name = "TOPIC")]
        scan_topic: Option<String>,
        /// The bag's nav_msgs/Odometry topic, where it has several.
        #[arg(long, value_name = "TOPIC")]
        odom_topic: Option<String>,
        /// The leg classifier for people tracking on an annotated log (a model written by
        /// `futago train-legs`) [default: the shipped models/legs.json].
        #[arg(long, value_name = "MODEL")]
        legs_model: Option<std::path::PathBuf>,
    },
    /// Estimate a robot profile from a real robot's log (CARMEN or ROS 1 bag): its laser's and
    /// its odometry's error models against the stack's own SLAM of the log. Writes
    /// profile.toml, summary.json, the reference trajectory.txt and map.pgm/map.yaml.
    Calibrate(CalibrateArgs),
    /// Replay a real log's drive in simulation with a robot profile (from `calibrate`): the
    /// world from the log's SLAM map, the laser cast along the SLAM path at the log's scan
    /// times, odometry with the profile's errors; the same SLAM scored on both. Writes
    /// summary.json, twin.md (side by side), twin.clf and the world.
    Twin(TwinArgs),
    /// Choose SLAM defaults by leave-one-log-out: every value of every choice in the choice
    /// file runs on every log; for each log in turn a value is chosen on the others and scored
    /// on it. Writes folds.json, folds.md (the per-fold table) and chosen.toml (the values
    /// kept, as a [slam] file for `replay --config`).
    Folds {
        /// The choice file: [[choice]] tables of name, key (under [slam]), values, neutral.
        choices: PathBuf,
        /// A log (CARMEN or ROS 1 bag); give two or more, each followed by its --relations.
        #[arg(long = "log", value_name = "LOG", required = true)]
        logs: Vec<PathBuf>,
        /// The ground-truth relations of the log given before it.
        #[arg(long = "relations", value_name = "FILE", required = true)]
        relations: Vec<PathBuf>,
        /// The base SLAM configuration: a TOML file of [slam] keys over the defaults.
        #[arg(long)]
        config: Option<PathBuf>,
        /// Output folder [default: out/folds].
        #[arg(long)]
        out: Option<PathBuf>,
        /// Replace the output even when it holds files futago did not write.
        #[arg(long)]
        force: bool,
        /// Each configuration also runs with its keyframe spacing scaled by 1 ± this, and a
        /// log's error is the mean of the three (0: one run).
        #[arg(long, default_value_t = folds::PERTURBATION)]
        perturb: f64,
        /// Runs at a time [default: the CPU cores].
        #[arg(long)]
        jobs: Option<usize>,
    },
    /// Train the laser leg classifier on a scenario's simulated scans (its people give the
    /// labels): AdaBoost on every seed but the last, scored on the last. Writes the model
    /// (JSON) that people tracking reads.
    TrainLegs {
        /// Scenario file (TOML) with people and a laser.
        scenario: PathBuf,
        /// Seeds to run; the last is held out [default: the scenario's `seeds`].
        #[arg(long, value_delimiter = ',')]
        seeds: Vec<u64>,
        /// Boosting rounds (stumps).
        #[arg(long, default_value_t = 100)]
        rounds: usize,
        /// Where to write the model (an existing file is replaced only when it is a futago
        /// model).
        #[arg(long, default_value = "models/legs.json")]
        out: PathBuf,
        /// Replace the output even when it holds files futago did not write (never `/`, the
        /// home folder, the current folder or its parents, or a folder with a `.git`).
        #[arg(long)]
        force: bool,
        #[command(flatten)]
        overlays: OverlayArgs,
    },
    /// Run many scenarios in parallel and collect their gates: writes each run into
    /// OUT/<scenario file name>/, and OUT/suite.json and OUT/junit.xml (JUnit XML: a test case
    /// per run and per gate). Exits 3 when a gate fails, 1 when a run fails.
    Suite {
        /// Scenario files and folders of them (their *.toml files).
        #[arg(required = true)]
        paths: Vec<PathBuf>,
        /// Scenarios run at once, each job held to its own share of the cores (Linux)
        /// [default: the number of CPU cores].
        #[arg(long)]
        jobs: Option<usize>,
        /// Run only the K-th of N equal parts of the suite (1-based), for CI matrices, indexed
        /// Kubernetes Jobs or Slurm arrays.
        #[arg(long)]
        shard: Option<suite::Shard>,
        /// Output folder [default: out/suite].
        #[arg(long)]
        out: Option<PathBuf>,
        /// Replace the output even when it holds files futago did not write (never `/`, the
        /// home folder, the current folder or its parents, or a folder with a `.git`).
        #[arg(long)]
        force: bool,
        /// Run each scenario in a process of its own, so that a crash (a segfault in a GPU
        /// driver) is that run's error and every other result is kept. A suite whose last
        /// run in the same folder crashed does this by itself.
        #[arg(long)]
        isolate: bool,
        #[command(flatten)]
        overlays: OverlayArgs,
    },
    /// Search a scenario's parameters for the best value of one of its metrics (CMA-ES, or
    /// random search as the baseline), each candidate scored by the metric's mean over several
    /// seeds. Writes OUT/best.toml (an overlay: `futago run SCENARIO --overlay OUT/best.toml`),
    /// trials.csv, tune.json and report.html.
    Tune {
        /// Scenario file (TOML).
        scenario: PathBuf,
        #[command(flatten)]
        options: tune::TuneOptions,
        /// Output folder, created or replaced whole when futago wrote it [default:
        /// out/tune/<scenario name>].
        #[arg(long)]
        out: Option<PathBuf>,
        #[command(flatten)]
        overlays: OverlayArgs,
    },
    /// List the metrics a scenario's run produces (the names its gates, `than` and tuning
    /// objectives may use), one a line, as the stack's scorers declare them.
    Metrics {
        /// Scenario file (TOML).
        scenario: PathBuf,
        #[command(flatten)]
        overlays: OverlayArgs,
    },
    /// Fuzz every parser (scenario, overlay, world, glTF, CARMEN, ROS bag, MCAP, TUM, relations, landmark map) with
    /// mutated inputs from the project's own files; exits 1 if any input makes one panic, and
    /// writes those inputs to OUT/.
    Fuzz {
        /// Inputs in all, spread over the parsers.
        #[arg(long, default_value_t = 100_000)]
        inputs: u64,
        /// Worker threads.
        #[arg(long, default_value_t = 2)]
        jobs: usize,
        /// Seed of the mutations.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Where findings go [default: out/fuzz].
        #[arg(long)]
        out: Option<PathBuf>,
        /// Replace the output even when it holds files futago did not write (never `/`, the
        /// home folder, the current folder or its parents, or a folder with a `.git`).
        #[arg(long)]
        force: bool,
        /// The project folder whose scenarios/ and worlds/ give the seeds.
        #[arg(long, default_value = ".")]
        root: PathBuf,
    },
    /// Print the scenario as it would run: every key of every module with its value, defaults
    /// included (every parameter `--set` can reach, by its dotted path).
    Config {
        /// Scenario file (TOML).
        scenario: PathBuf,
        #[command(flatten)]
        overlays: OverlayArgs,
    },
    /// Join the results of a suite's shards (their --out folders) into one suite.json and
    /// junit.xml. Exits 3 when a gate failed, 1 when a run failed, as the suite would have.
    Merge {
        /// The shards' output folders.
        #[arg(required = true)]
        shards: Vec<PathBuf>,
        /// Output folder [default: out/suite].
        #[arg(long)]
        out: Option<PathBuf>,
        /// Replace the output even when it holds files futago did not write (never `/`, the
        /// home folder, the current folder or its parents, or a folder with a `.git`).
        #[arg(long)]
        force: bool,
    },
    /// Measure real crowds (ETH/UCY trajectory files: `frame person [label] x y`), calibrate
    /// the crowd model on them and compare simulated crowds with them statistic by statistic.
    Crowd {
        #[command(subcommand)]
        command: CrowdCommand,
    },
    /// Inspect worlds and export their ground truth.
    World {
        #[command(subcommand)]
        command: WorldCommand,
    },
    /// Measure speed: the simulator's real-time factor, camera images and laser rays per second.
    Bench {
        #[command(subcommand)]
        command: BenchCommand,
    },
}

/// Changes laid over scenarios before they are checked (see `futago run --help`).
#[derive(clap::Args)]
struct OverlayArgs {
    /// Overlay file laid over the scenario: a TOML table of the scenario keys it changes (as
    /// `futago tune` writes). Tables merge; other values replace. Repeatable; later ones win.
    #[arg(long = "overlay", value_name = "FILE")]
    files: Vec<PathBuf>,
    /// One scenario key changed: PATH=VALUE, VALUE in TOML (e.g.
    /// localization.mcl.particles=300, slam.method=icp). Repeatable; applied after --overlay.
    #[arg(long = "set", value_name = "PATH=VALUE")]
    sets: Vec<String>,
}

impl OverlayArgs {
    /// The arguments again, for a child `futago run`.
    fn args(&self) -> Vec<String> {
        let files = self
            .files
            .iter()
            .flat_map(|f| ["--overlay".to_string(), f.display().to_string()]);
        let sets = self
            .sets
            .iter()
            .flat_map(|s| ["--set".to_string(), s.clone()]);
        files.chain(sets).collect()
    }

    /// The overlays, read and checked: files first, then assignments, in the order given.
    fn load(&self) -> Result<Vec<overlay::Overlay>> {
        let mut out = Vec::new();
        for f in &self.files {
            out.push(overlay::Overlay::load(f)?);
        }
        for s in &self.sets {
            out.push(overlay::Overlay::parse_set(s)?);
        }
        Ok(out)
    }
}

#[derive(Subcommand)]
enum BenchCommand {
    /// Real-time factor of a scenario with and without its lasers, and laser rays per second.
    Sim {
        /// Scenario to measure.
        #[arg(default_value = "scenarios/bench-office.toml")]
        scenario: PathBuf,
        /// Simulated seconds (overrides the scenario's duration).
        #[arg(long)]
        duration: Option<f64>,
        /// Rays to cast in the ray-throughput measurement.
        #[arg(long, default_value_t = 2_000_000)]
        rays: usize,
    },
    /// Seed 004's 3D scan by parts: a full turn of the turntable simulated, its scans placed,
    /// the voxel maps updated, free-space carving, the next view planned.
    Scan3d {
        /// Scenario with a `[scan3d]`; the sweep is taken at its start.
        #[arg(default_value = "scenarios/hall-scan3d.toml")]
        scenario: PathBuf,
        /// Sweeps, each with the next seed; the median time is reported.
        #[arg(long, default_value_t = 3)]
        repeats: usize,
    },
    /// Seed 001's monocular localisation per frame: SIFT, and each localiser's selection,
    /// matching and pose search, on the scenario's own run.
    Visual {
        /// Scenario with a [visual_localization] to measure.
        #[arg(default_value = "scenarios/lab-visual-nav.toml")]
        scenario: PathBuf,
        /// Simulated seconds (overrides the scenario's duration).
        #[arg(long)]
        duration: Option<f64>,
    },
    /// Planning time of both coverage planners (and the second pass) on a scenario's map,
    /// region and annotations.
    Coverage {
        /// Scenario whose world, start and [coverage] to plan with.
        #[arg(default_value = "scenarios/office-coverage.toml")]
        scenario: PathBuf,
        /// Plans of each planner; the median time is reported.
        #[arg(long, default_value_t = 5)]
        repeats: usize,
    },
    /// Time per keyframe of the RGB-D map: keyframe making and each registration method.
    Rgbd {
        /// Scenario with an [rgbd_map] to measure.
        #[arg(default_value = "scenarios/office-rgbd-methods.toml")]
        scenario: PathBuf,
        /// Simulated seconds (overrides the scenario's duration).
        #[arg(long)]
        duration: Option<f64>,
    },
    /// Monte Carlo localisation update time on a world's own map (seed 000: 500 particles,
    /// one beam every 15°), for the beam and likelihood-field models.
    Mcl {
        #[arg(long, default_value = "worlds/office.toml")]
        world: PathBuf,
        /// Spawn to localise at.
        #[arg(long, default_value = "dock")]
        spawn: String,
        #[arg(long, default_value_t = 500)]
        particles: usize,
        #[arg(long, default_value_t = 200)]
        updates: usize,
    },
    /// Seed 002's depth-camera MCL: time per frame (one batched render of every particle,
    /// the likelihood, resampling) for each particle count and render size.
    DepthMcl {
        #[arg(long, default_value = "worlds/office.toml")]
        world: PathBuf,
        /// Spawn the camera stands over.
        #[arg(long, default_value = "dock")]
        spawn: String,
        /// Particle counts, comma-separated.
        #[arg(long, value_delimiter = ',', default_value = "50,200,500,2000")]
        particles: Vec<usize>,
        /// Render sizes WxH, comma-separated (the SR4000's 176x144 and smaller).
        #[arg(long, value_delimiter = ',', default_value = "176x144,88x72,44x36")]
        sizes: Vec<String>,
        /// Frames timed per combination.
        #[arg(long, default_value_t = 20)]
        frames: usize,
        /// Likelihoods timed, comma-separated: `field` (the 3D likelihood field, no render),
        /// `seed` (seed 002's render-and-compare) or `sensor` (the per-pixel sensor model on
        /// the render).
        #[arg(long, value_delimiter = ',', default_value = "field,seed")]
        likelihoods: Vec<String>,
    },
    /// People detection and tracking per scan (a URG-04LX before walking people) and the
    /// simulator's real-time factor among a crowd.
    People {
        #[arg(long, default_value = "worlds/hall.toml")]
        world: PathBuf,
        /// Spawn the robot stands at.
        #[arg(long, default_value = "hall")]
        spawn: String,
        /// People walking across the laser's view.
        #[arg(long, default_value_t = 10)]
        people: usize,
        /// Scans to collect and process.
        #[arg(long, default_value_t = 200)]
        scans: usize,
        /// People for the simulation's real-time factor.
        #[arg(long, default_value_t = 20)]
        crowd: usize,
    },
    /// Camera images per second (640×480 RGB + depth, depth alone, batches of small depth
    /// images) and laser rays per second, in any world.
    Sensors {
        /// World file (TOML, or a bare .glb/.gltf mesh).
        #[arg(long, default_value = "worlds/office.toml")]
        world: PathBuf,
        /// Camera poses, one `x,y,z,yaw` per line (m, rad) [default: 64 random free poses at
        /// the Kinect's 0.42 m].
        #[arg(long)]
        poses: Option<PathBuf>,
        /// Frames per single-image workload.
        #[arg(long, default_value_t = 300)]
        frames: usize,
        /// Views per batch (seed 002's particle count).
        #[arg(long, default_value_t = 200)]
        batch: usize,
        /// Batches to render.
        #[arg(long, default_value_t = 20)]
        batches: usize,
        /// Batch image size WIDTHxHEIGHT (seed 002's SR4000: 176x144).
        #[arg(long, default_value = "176x144")]
        batch_size: String,
        /// Rays per laser measurement.
        #[arg(long, default_value_t = 1_000_000)]
        rays: usize,
    },
}

#[derive(Subcommand)]
enum CrowdCommand {
    /// Fit the crowd model (walking speed and its spread, pairs and their spacing) to real
    /// trajectories, each file weighing the same, and write it as a crowd profile.
    Calibrate {
        /// Trajectory files (ETH/UCY: `frame person [label] x y`, metres).
        files: Vec<PathBuf>,
        /// The profile to write (TOML).
        #[arg(long)]
        out: PathBuf,
        #[command(flatten)]
        arena: ArenaArgs,
        /// Replace the profile even when futago did not write it.
        #[arg(long)]
        force: bool,
    },
    /// Simulate a crowd at each file's density and walkable area and compare its statistics
    /// with the file's: writes crowd.json, crowd.md and each file's simulated trajectories.
    /// Exits with 3 when a gated statistic is more than 15 % from the real one.
    Compare {
        /// Trajectory files (ETH/UCY: `frame person [label] x y`, metres).
        files: Vec<PathBuf>,
        /// The crowd profile (`futago crowd calibrate`'s) [default: the simulator's defaults].
        #[arg(long)]
        profile: Option<PathBuf>,
        /// Simulated crowds per file, seeds 0 to N−1; the median is compared.
        #[arg(long, default_value_t = 5)]
        seeds: u64,
        /// Output folder [default: out/crowd].
        #[arg(long)]
        out: Option<PathBuf>,
        #[command(flatten)]
        arena: ArenaArgs,
        /// Replace the output even when it holds files futago did not write.
        #[arg(long)]
        force: bool,
    },
}

/// What the crowd commands share: the files' frame period and the simulation's length.
#[derive(clap::Args, Debug)]
struct ArenaArgs {
    /// Time between the files' frames, s (ETH and UCY: 0.4).
    #[arg(long, default_value_t = 0.4)]
    period: f64,
    /// Simulated seconds measured per crowd (after a minute to settle).
    #[arg(long, default_value_t = 600.0)]
    duration: f64,
    /// Crowds simulated at a time [default: the CPU cores].
    #[arg(long)]
    jobs: Option<usize>,
}

impl ArenaArgs {
    fn options(&self) -> Result<crowd::ArenaOptions> {
        if !(self.duration.is_finite() && (1.0..=1e5).contains(&self.duration)) {
            bail!("--duration {}: expected 1 to 100000 s", self.duration);
        }
        Ok(crowd::ArenaOptions {
            duration: self.duration,
            ..crowd::ArenaOptions::default()
        })
    }

    fn jobs(&self) -> Result<usize> {
        resolve_jobs(self.jobs)
    }
}

/// `futago crowd …`.
fn crowd_command(command: CrowdCommand) -> Result<i32> {
    let read = |files: &[PathBuf], period: f64| -> Result<Vec<crowd::Sequence>> {
        if files.is_empty() {
            bail!("no trajectory files given");
        }
        files.iter().map(|f| crowd::read(f, period)).collect()
    };
    match command {
        CrowdCommand::Calibrate {
            files,
            out,
            arena,
            force,
        } => {
            let seqs = read(&files, arena.period)?;
            let (p, real) = crowd::calibrate(
                &seqs,
                &crowd::CrowdProfile::default(),
                &arena.options()?,
                arena.jobs()?,
            )?;
            crowd::write_profile(&out, &p, &seqs, force)?;
            for (s, r) in seqs.iter().zip(&real) {
                println!(
                    "{}: speed {:.3} ± {:.3} m/s, nearest neighbour {:.2} m (p10 {:.2}), {:.0} % in groups {:.2} m apart, {:.0} % standing, {:.2} people on {:.0} m²",
                    s.name,
                    r.speed_mean,
                    r.speed_std,
                    r.nn_median_m,
                    r.nn_p10_m,
                    100.0 * r.grouped_fraction,
                    r.group_distance_m,
                    100.0 * r.standing_fraction,
                    r.mean_count,
                    r.area_m2
                );
            }
            println!(
                "profile: wanted speed {:.3} ± {:.3} m/s, pairs {:.0} % of arrivals {:.2} m apart, a stop per {:.0} s walked lasting {:.1} s → {}",
                p.walking.speed,
                p.walking.speed_std,
                100.0 * p.crowd.pair_fraction,
                p.crowd.pair_spacing,
                1.0 / p.crowd.stop_rate,
                p.crowd.stop_time,
                out.display()
            );
            Ok(0)
        }
        CrowdCommand::Compare {
            files,
            profile,
            seeds,
            out,
            arena,
            force,
        } => {
            if !(1..=1000).contains(&seeds) {
                bail!("--seeds {seeds}: expected 1 to 1000");
            }
            let seqs = read(&files, arena.period)?;
            let p = match &profile {
                Some(f) => crowd::CrowdProfile::load(f)?,
                None => crowd::CrowdProfile::default(),
            };
            let out = out.unwrap_or_else(|| PathBuf::from("out/crowd"));
            let cs = crowd::compare_all(
                &seqs,
                &p,
                &arena.options()?,
                seeds,
                arena.jobs()?,
                &out,
                force,
            )?;
            let outside = crowd::print(&cs);
            println!(
                "{} of the gated statistics outside ±15 %; report: {}",
                outside,
                out.join("crowd.md").display()
            );
            Ok(if outside > 0 { 3 } else { 0 })
        }
    }
}

#[derive(Subcommand)]
enum WorldCommand {
    /// Load a world and describe it (objects, triangles, bounds, spawns).
    Info { world: PathBuf },
    /// Write the occupancy grid of a height band (PGM + YAML, ROS map_server) and the world
    /// mesh (PLY and/or binary glTF) from the world's own colliders and meshes.
    Export {
        world: PathBuf,
        /// Output folder [default: out/worlds/<world name>].
        #[arg(long)]
        out: Option<PathBuf>,
        /// Grid cell size, m.
        #[arg(long, default_value_t = 0.05)]
        resolution: f64,
        /// Height band `ZMIN:ZMAX`, m (default: around a laser at 0.2 m).
        #[arg(long, default_value = "0.15:0.25")]
        band: String,
        /// Free margin around the world's bounds, m.
        #[arg(long, default_value_t = 0.5)]
        margin: f64,
        /// Mesh formats to write.
        #[arg(long, value_enum, default_value = "both")]
        mesh: world_cmd::MeshFormat,
        /// Skip the occupancy grid (write meshes only).
        #[arg(long)]
        no_grid: bool,
        /// Replace the output even when it holds files futago did not write (never `/`, the
        /// home folder, the current folder or its parents, or a folder with a `.git`).
        #[arg(long)]
        force: bool,
    },
    /// Make a world from a ROS map_server map (its YAML file; PGM or PNG image), such as the
    /// `map.yaml` that `futago replay` builds from a real log: occupied cells become walls.
    FromMap {
        map: PathBuf,
        /// The world file to write; the map is copied beside it [default:
        /// out/worlds/<map's stem>.toml].
        #[arg(long)]
        out: Option<PathBuf>,
        /// The world's name [default: the world file's stem].
        #[arg(long)]
        name: Option<String>,
        /// Height of the walls and of the ceiling, m.
        #[arg(long, default_value_t = 2.5)]
        height: f64,
        /// What unknown cells become: walls where they touch free space, or free floor.
        #[arg(long, value_enum, default_value = "wall")]
        unknown: UnknownArg,
        /// The start pose `X,Y,YAW_DEG` [default: the free cell farthest from any wall].
        #[arg(long)]
        spawn: Option<String>,
        /// Leave the ceiling out.
        #[arg(long)]
        no_ceiling: bool,
        /// Replace the output even when it holds files futago did not write (never `/`, the
        /// home folder, the current folder or its parents, or a folder with a `.git`).
        #[arg(long)]
        force: bool,
    },
}

/// `--unknown` of `futago world from-map`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum UnknownArg {
    Wall,
    Free,
}

fn main() -> std::process::ExitCode {
    match real_main() {
        Ok(0) => std::process::ExitCode::SUCCESS,
        Ok(status) => std::process::ExitCode::from(status),
        Err(e) => {
            eprintln!("futago: error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

/// `--jobs`, or the number of CPU cores when not given; at least 1.
fn resolve_jobs(jobs: Option<usize>) -> Result<usize> {
    let jobs = jobs.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    if jobs == 0 {
        bail!("--jobs: expected at least 1");
    }
    Ok(jobs)
}

/// Runs the command line's command; gives the exit status (1: a run failed; 3: a gate did).
/// A scenario run's arguments (`futago run`, `futago serve`).
#[derive(clap::Args)]
struct RunArgs {
    /// Scenario file (TOML).
    scenario: PathBuf,
    /// Output folder, created or replaced whole when futago wrote it [default:
    /// out/<scenario name>].
    #[arg(long)]
    out: Option<PathBuf>,
    /// Replace the output even when it holds files futago did not write (never `/`, the
    /// home folder, the current folder or its parents, or a folder with a `.git`).
    #[arg(long)]
    force: bool,
    /// Seed of every noise source (overrides the scenario's).
    #[arg(long)]
    seed: Option<u64>,
    /// Simulated seconds (overrides the scenario's duration).
    #[arg(long)]
    duration: Option<f64>,
    #[command(flatten)]
    overlays: OverlayArgs,
    /// No progress bar.
    #[arg(long, short)]
    quiet: bool,
}

impl RunArgs {
    fn options(&self) -> run::RunOptions {
        run::RunOptions {
            seed: self.seed,
            duration: self.duration,
            progress: !self.quiet,
            report: true,
            force: self.force,
        }
    }
}

/// `futago serve`'s arguments: a run's (its scenario's `[controller]` replaced by the link),
/// and the link's.
#[derive(clap::Args)]
struct ServeArgs {
    #[command(flatten)]
    run: RunArgs,
    /// DDS domain id [default: ROS_DOMAIN_ID, else 0].
    #[arg(long)]
    domain: Option<i32>,
    /// Real seconds to wait for each tick's command before going on without it (the run is
    /// then marked as not deterministic), and for subscribers to acknowledge what the link
    /// publishes before failing [default: the scenario's external controller's, else 10].
    #[arg(long)]
    timeout: Option<f64>,
    /// Real seconds to wait for the controller to match before the first tick [default: the
    /// scenario's, else 60].
    #[arg(long)]
    wait: Option<f64>,
    /// Take geometry_msgs/TwistStamped on /cmd_vel (stamped with the tick's /clock) instead of
    /// Twist.
    #[arg(long)]
    stamped: bool,
    /// Simulated seconds between the ticks that wait for a command [default: every tick,
    /// 15 ms]; for a controller on its own timer (Nav2's controller_frequency 20 Hz: 0.05).
    #[arg(long)]
    period: Option<f64>,
    /// Most frames a second each camera publishes [default: every frame the scenario's stack
    /// renders; cameras render only for it].
    #[arg(long)]
    camera_rate: Option<f64>,
    /// Bin each camera's images N × N on the link: a colour block's mean, a depth block's
    /// nearest reading, CameraInfo to match [default: full size].
    #[arg(long)]
    camera_scale: Option<u32>,
    /// The topic of your stack's pose estimate (geometry_msgs/PoseWithCovarianceStamped in the
    /// map frame, as AMCL's /amcl_pose), scored against the truth as `external.*`.
    #[arg(long)]
    pose_topic: Option<String>,
    /// Take your stack's pose from its map → odom on /tf (slam_toolbox, Cartographer and AMCL
    /// publish it) composed with the odometry at each tick, instead of a pose topic.
    #[arg(long)]
    pose_from_tf: bool,
    /// The topic of your stack's map (nav_msgs/OccupancyGrid, as /map): its newest is scored
    /// as `external.map.*`.
    #[arg(long)]
    map_topic: Option<String>,
}

/// `futago serve`: its options, then [`serve::command`].
fn serve_main(a: ServeArgs) -> Result<i32> {
    let opts = a.run.options();
    let serve = serve::ServeOptions {
        domain: a.domain,
        timeout: a.timeout,
        wait: a.wait,
        stamped: a.stamped,
        period: a.period,
        camera_rate: a.camera_rate,
        camera_scale: a.camera_scale,
        pose_topic: a.pose_topic,
        pose_from_tf: a.pose_from_tf,
        map_topic: a.map_topic,
    };
    let r = a.run;
    serve::command(&r.scenario, &r.overlays.load()?, r.out, &opts, &serve)
}

fn real_main() -> Result<u8> {
    let status = match Cli::parse().command {
        Command::Run(a) => {
            if twin::scenario::is_twin_file(&a.scenario) {
                let options =
                    !a.overlays.args().is_empty() || a.seed.is_some() || a.duration.is_some();
                twin::scenario::command(&a.scenario, options, a.out, a.force, resolve_jobs(None)?)?
            } else {
                run::command(
                    &a.scenario,
                    &a.overlays.load()?,
                    a.out.clone(),
                    &a.options(),
                    serve::run_scenario,
                )?
            }
        }
        Command::Serve(a) => serve_main(a)?,
        Command::Suite {
            paths,
            jobs,
            shard,
            out,
            force,
            isolate,
            overlays,
        } => {
            let jobs = resolve_jobs(jobs)?;
            let out = out.unwrap_or_else(|| PathBuf::from("out/suite"));
            let isolation = isolate.then(|| suite::Isolation {
                overlay_args: overlays.args(),
            });
            let o = overlays.load()?;
            let s = suite::suite(&paths, &o, jobs, shard, &out, force, isolation.as_ref())?;
            suite::print(&s, &out)
        }
        Command::Tune {
            scenario,
            mut options,
            out,
            overlays,
        } => {
            options.jobs = Some(resolve_jobs(options.jobs)?);
            let base = overlays.load()?;
            let name = stack::load_with(&scenario, &base)?.spec.name;
            let out = out.unwrap_or_else(|| PathBuf::from("out/tune").join(name));
            tune::print(&tune::tune(&scenario, &base, &options, &out)?, &out);
            0
        }
        Command::TrainLegs {
            scenario,
            seeds,
            rounds,
            out,
            force,
            overlays,
        } => {
            let s = stack::load_with(&scenario, &overlays.load()?)?;
            legs_train::command(&s, &seeds, rounds, &out, force)?;
            0
        }
        Command::Metrics { scenario, overlays } => {
            let s = stack::load_with(&scenario, &overlays.load()?)?;
            for name in s.metric_names() {
                println!("{name}");
            }
            0
        }
        Command::Fuzz {
            inputs,
            jobs,
            seed,
            out,
            force,
            root,
        } => fuzz::command(&root, inputs, jobs, seed, out, force)?,
        Command::Config { scenario, overlays } => {
            let s = stack::load_with(&scenario, &overlays.load()?)?;
            print!("{}", toml::to_string(&s.effective_config())?);
            0
        }
        Command::Merge { shards, out, force } => {
            let out = out.unwrap_or_else(|| PathBuf::from("out/suite"));
            suite::print(&suite::merge(&shards, &out, force)?, &out)
        }
        Command::Export { run, out, force } => futago::export::command(&run, out, force)?,
        Command::Replay {
            log,
            relations,
            out,
            force,
            config,
            method,
            strict,
            scan_topic,
            odom_topic,
            legs_model,
        } => {
            let slam = replay::slam_config(config.as_deref(), method.as_deref())?;
            let out = out.unwrap_or_else(|| replay::default_out(&log));
            let options = replay::ReplayOptions {
                read: futago_msgs::carmen::ReadOptions {
                    strict,
                    scan_topic,
                    odom_topic,
                },
                force,
                legs_model,
            };
            let s = replay::replay(&log, relations.as_deref(), slam, &out, &options)?;
            replay::print(&s, &log, &out);
            0
        }
        Command::Calibrate(args) => calibrate_command(args)?,
        Command::Twin(args) => twin_command(args)?,
        Command::Folds {
            choices,
            logs,
            relations,
            config,
            out,
            force,
            perturb,
            jobs,
        } => folds_command(
            &choices,
            logs,
            relations,
            config.as_deref(),
            out,
            force,
            perturb,
            jobs,
        )?,
        Command::Crowd { command } => crowd_command(command)?,
        Command::World { command } => world(command)?,
        Command::Bench { command } => bench(command)?,
    };
    Ok(u8::try_from(status).unwrap_or(1))
}

/// `futago calibrate`'s arguments.
#[derive(clap::Args, Debug)]
struct CalibrateArgs {
    /// The log (CARMEN: .clf, .log; ROS 1 bag: .bag).
    log: PathBuf,
    /// The stretch of the log to use, as fractions of its duration (e.g. 0:0.5, the first
    /// half).
    #[arg(long, default_value = "0:1")]
    span: String,
    /// The laser (its frame) to describe, where the log has several [default: the one
    /// with the most scans].
    #[arg(long)]
    laser: Option<String>,
    /// Refuse a damaged log instead of using what it holds.
    #[arg(long)]
    strict: bool,
    #[command(flatten)]
    common: LogRunArgs,
}

/// What `calibrate` and `twin` share: the SLAM's parameters, the output and a bag's topics.
#[derive(clap::Args, Debug)]
struct LogRunArgs {
    /// SLAM parameters: a TOML file of the `[slam]` table's keys.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Output folder [default: out/calibrate/<log name> or out/twin/<log name>].
    #[arg(long)]
    out: Option<PathBuf>,
    /// Replace the output even when it holds files futago did not write.
    #[arg(long)]
    force: bool,
    /// The bag's sensor_msgs/LaserScan topic, where it has several.
    #[arg(long, value_name = "TOPIC")]
    scan_topic: Option<String>,
    /// The bag's nav_msgs/Odometry topic, where it has several.
    #[arg(long, value_name = "TOPIC")]
    odom_topic: Option<String>,
}

/// `futago calibrate …`: estimates the profile and prints its main figures.
fn calibrate_command(a: CalibrateArgs) -> Result<i32> {
    let c = a.common;
    let slam = replay::slam_config(c.config.as_deref(), None)?;
    let out = c.out.unwrap_or_else(|| calibrate::default_out(&a.log));
    let options = calibrate::CalibrateOptions {
        read: futago_msgs::carmen::ReadOptions {
            strict: a.strict,
            scan_topic: c.scan_topic,
            odom_topic: c.odom_topic,
        },
        span: calibrate::parse_span(&a.span)?,
        laser: a.laser,
        force: c.force,
    };
    let (profile, _) = calibrate::calibrate(&a.log, slam, &out, &options)?;
    calibrate::print(&profile, &out);
    Ok(0)
}

/// `futago twin`'s arguments.
#[derive(clap::Args, Debug)]
struct TwinArgs {
    /// The real log (CARMEN: .clf, .log; ROS 1 bag: .bag).
    log: PathBuf,
    /// The robot profile (`futago calibrate`'s profile.toml).
    #[arg(long)]
    profile: PathBuf,
    /// The real log's ground-truth relations: their stamp pairs score both logs.
    #[arg(long)]
    relations: PathBuf,
    /// Twin runs, each with its own noise (seeds 0 to N−1).
    #[arg(long, default_value_t = 5)]
    seeds: u64,
    /// The stretch scored, as fractions of the log's duration [default: the second half].
    #[arg(long, default_value = "0.5:1")]
    score_span: String,
    /// Seeds run at a time [default: the CPU cores].
    #[arg(long)]
    jobs: Option<usize>,
    /// Also rank the SLAM configurations of this file by relations error in the twin and on
    /// the real log (e.g. choices/slam-configs.toml).
    #[arg(long, value_name = "FILE")]
    rank: Option<PathBuf>,
    #[command(flatten)]
    common: LogRunArgs,
}

/// `futago twin …`: runs the twin and prints the side-by-side table.
fn twin_command(a: TwinArgs) -> Result<i32> {
    let c = a.common;
    let slam = replay::slam_config(c.config.as_deref(), None)?;
    let out = c.out.unwrap_or_else(|| {
        let stem = a
            .log
            .file_stem()
            .map_or_else(|| "log".into(), |s| s.to_string_lossy().to_string());
        PathBuf::from("out/twin").join(stem)
    });
    let options = twin::TwinOptions {
        read: futago_msgs::carmen::ReadOptions {
            strict: false,
            scan_topic: c.scan_topic,
            odom_topic: c.odom_topic,
        },
        seeds: a.seeds,
        score_span: calibrate::parse_span(&a.score_span)
            .map_err(|e| anyhow::anyhow!("{}", e.to_string().replace("--span", "--score-span")))?,
        jobs: a.jobs.unwrap_or_else(|| {
            std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get)
        }),
        force: c.force,
        rank: a.rank,
        profile_as: None,
    };
    let s = twin::twin(&a.log, &a.profile, &a.relations, slam, &out, &options)?;
    twin::print(&s, &out);
    Ok(0)
}

/// `futago folds …`: pairs each log with its relations and runs the folds.
#[allow(clippy::too_many_arguments)]
fn folds_command(
    choices: &std::path::Path,
    logs: Vec<PathBuf>,
    relations: Vec<PathBuf>,
    config: Option<&std::path::Path>,
    out: Option<PathBuf>,
    force: bool,
    perturb: f64,
    jobs: Option<usize>,
) -> Result<i32> {
    if logs.len() != relations.len() {
        bail!(
            "{} --log and {} --relations: expected one relations file after each log",
            logs.len(),
            relations.len()
        );
    }
    let logs: Vec<folds::LogSpec> = logs
        .into_iter()
        .zip(relations)
        .map(|(log, relations)| folds::LogSpec { log, relations })
        .collect();
    let base = replay::slam_config(config, None)?;
    let out = out.unwrap_or_else(|| PathBuf::from("out/folds"));
    let md = folds::run(
        &logs,
        choices,
        &base,
        perturb,
        resolve_jobs(jobs)?,
        &out,
        force,
    )?;
    print!("{md}");
    println!("\nresults in {}", out.display());
    Ok(0)
}

/// `futago world …`.
fn world(command: WorldCommand) -> Result<i32> {
    match command {
        WorldCommand::Info { world } => {
            let w = world_cmd::load(&world)?;
            println!("{}", world_cmd::describe(&w));
        }
        WorldCommand::Export {
            world,
            out,
            resolution,
            band,
            margin,
            mesh,
            no_grid,
            force,
        } => {
            world_cmd::check_export_options(resolution, margin)?;
            let band = world_cmd::parse_band(&band)?;
            let w = world_cmd::load(&world)?;
            let dir = out.unwrap_or_else(|| PathBuf::from("out/worlds").join(&w.name));
            let options = world_cmd::ExportOptions {
                resolution,
                band,
                margin,
                mesh,
                grid: !no_grid,
            };
            for p in world_cmd::export_world(&w, &dir, &options, force)? {
                println!("wrote {}", p.display());
            }
        }
        WorldCommand::FromMap {
            map,
            out,
            name,
            height,
            unknown,
            spawn,
            no_ceiling,
            force,
        } => {
            let spawn = spawn.map(|s| world_cmd::parse_spawn(&s)).transpose()?;
            let out = out.unwrap_or_else(|| {
                let stem = map
                    .file_stem()
                    .map(|s| s.to_string_lossy().to_string())
                    .unwrap_or_else(|| "map".into());
                PathBuf::from("out/worlds").join(format!("{stem}.toml"))
            });
            let options = world_cmd::FromMapOptions {
                name,
                height,
                unknown: match unknown {
                    UnknownArg::Wall => futago_sim::world::floor_plan::UnknownCells::Wall,
                    UnknownArg::Free => futago_sim::world::floor_plan::UnknownCells::Free,
                },
                spawn,
                ceiling: !no_ceiling,
            };
            let w = world_cmd::from_map(&map, &out, &options, force)?;
            println!("wrote {}", out.display());
            println!("{}", world_cmd::describe(&w));
        }
    }
    Ok(0)
}

/// `futago bench …`: prints the bench's figures as JSON.
fn bench(command: BenchCommand) -> Result<i32> {
    let load = stack::load;
    let r = match command {
        BenchCommand::Sim {
            scenario,
            duration,
            rays,
        } => {
            let r = bench::bench(&scenario, &load(&scenario)?, duration, rays.max(682))?;
            if r["with_lasers"]["lasers_read"] == false {
                eprintln!(
                    "futago: warning: {}: no node of its stack reads a laser, so the run \
                     \"with_lasers\" cast no scan; bench a scenario whose stack reads them",
                    scenario.display()
                );
            }
            r
        }
        BenchCommand::Scan3d { scenario, repeats } => {
            stack::scan3d::bench(&load(&scenario)?, repeats)?
        }
        BenchCommand::Coverage { scenario, repeats } => {
            bench::bench_coverage(&load(&scenario)?, repeats)?
        }
        BenchCommand::Visual { scenario, duration } => {
            bench::bench_visual(&load(&scenario)?, duration)?
        }
        BenchCommand::Rgbd { scenario, duration } => {
            bench::bench_rgbd(&load(&scenario)?, duration)?
        }
        BenchCommand::People {
            world,
            spawn,
            people,
            scans,
            crowd,
        } => {
            let (w, start) = bench::world_at_spawn(&world, &spawn)?;
            if people > 1000 || crowd > 1000 || !(1..=100_000).contains(&scans) {
                bail!("expected at most 1000 people and crowd, and 1 to 100000 scans");
            }
            bench::bench_people(&w, start, people, scans, crowd)?
        }
        BenchCommand::Mcl {
            world,
            spawn,
            particles,
            updates,
        } => {
            let (w, start) = bench::world_at_spawn(&world, &spawn)?;
            bench::bench_mcl(&w, start, particles.max(1), updates)?
        }
        BenchCommand::DepthMcl {
            world,
            spawn,
            particles,
            sizes,
            frames,
            likelihoods,
        } => {
            let (w, start) = bench::world_at_spawn(&world, &spawn)?;
            let sizes = bench::parse_depth_sizes(&sizes)?;
            let likelihoods = bench::parse_likelihoods(&likelihoods)?;
            if particles.iter().any(|n| !(1..=100_000).contains(n))
                || !(1..=100_000).contains(&frames)
            {
                bail!("expected 1 to 100000 particles and frames");
            }
            bench::bench_depth_mcl(&w, start, &particles, &sizes, &likelihoods, frames)?
        }
        BenchCommand::Sensors {
            world,
            poses,
            frames,
            batch,
            batches,
            batch_size,
            rays,
        } => {
            let w = world_cmd::load(&world)?;
            let poses = poses.map(|p| bench::read_poses(&p)).transpose()?;
            let options = bench::SensorBench {
                frames,
                batch,
                batches,
                batch_size: bench::parse_size("--batch-size", &batch_size)?,
                rays: rays.max(682),
            };
            bench::bench_sensors(&w, poses, &options)?
        }
    };
    println!("{}", serde_json::to_string_pretty(&r)?);
    Ok(0)
}
