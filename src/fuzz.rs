//! A mutation fuzzer for every parser of the project, on the stable toolchain (written for
//! futago: cargo-fuzz needs nightly).
//!
//! Each target starts from seeds the project itself provides: the shipped scenarios and
//! worlds, the chair's GLB, and logs written by the project's own writers (a CARMEN log, a
//! TUM trajectory, a relations file, a map_server map, an example ROS bag uncompressed, bz2 and
//! lz4, the first landmarks of the lab's landmark map). An input is a
//! seed with 1 to 8 stacked mutations: bit flips, random bytes, insertions, deletions,
//! duplicated or spliced ranges, and, for text, numbers replaced by values at the edges of
//! their types (0, −1, ±10³⁰⁰, NaN, 2³², 2⁶⁴ …), lines dropped, doubled or swapped. Every
//! input is parsed under `catch_unwind`: an error is the right answer, a panic is a finding,
//! written to the output folder with its message. Inputs are drawn from seeded ChaCha
//! streams, one per worker, so a run is reproducible from its seed and worker count.

use crate::scenario::ScenarioSpec;
use anyhow::{Context, Result};
use futago_msgs::{Pose2, Time, carmen, rosbag, tum};
use futago_sim::World;
use futago_sim::config::{SpecError, parse_toml};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

/// Inputs are cut to this size: the parsers bound what they read, and a larger input only
/// slows the search.
const MAX_INPUT: usize = 1 << 18;

/// One starting input and the file it stands for (relative paths inside it resolve there).
#[derive(Clone)]
pub struct Seed {
    pub origin: PathBuf,
    pub bytes: Vec<u8>,
}

/// What a target feeds its input to.
type Parse = fn(&Seed, &mut Worlds);

/// A parser and its seeds.
pub struct Target {
    pub name: &'static str,
    /// Whether inputs are text (numbers and lines are mutated as such too).
    pub text: bool,
    pub seeds: Vec<Seed>,
    parse: Parse,
}

/// Compiled worlds, by path: the scenario targets mutate the scenario, not its world.
#[derive(Default)]
pub struct Worlds(HashMap<PathBuf, Result<World, String>>);

impl Worlds {
    fn load(&mut self, p: &Path) -> Result<World, SpecError> {
        self.0
            .entry(p.to_path_buf())
            .or_insert_with(|| World::load(p).map_err(|e| e.to_string()))
            .clone()
            .map_err(|m| SpecError::new(p, "", m))
    }
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

fn parse_scenario(s: &Seed, worlds: &mut Worlds) {
    let t = text(&s.bytes);
    if let Ok(spec) = parse_toml::<ScenarioSpec>(&s.origin, &t) {
        let s = crate::stack::from_spec_with(&s.origin, spec, &mut |p| worlds.load(p));
        if let Ok(s) = s {
            // What `futago config` prints must load again.
            let _ = toml::to_string(&s.effective_config());
        }
    }
}

fn parse_world(s: &Seed, _: &mut Worlds) {
    if let Ok(spec) = parse_toml(&s.origin, &text(&s.bytes)) {
        let _ = futago_sim::world::compile(&spec, &s.origin);
    }
}

fn parse_gltf(s: &Seed, _: &mut Worlds) {
    let _ = futago_sim::world::gltf_io::load_slice(&s.origin, &s.bytes);
}

fn parse_carmen(s: &Seed, _: &mut Worlds) {
    let t = text(&s.bytes);
    let _ = carmen::read(&t);
    // And salvaging, as `futago replay` reads by default.
    let _ = carmen::read_with(&t, &carmen::ReadOptions::default());
}

fn parse_bag(s: &Seed, _: &mut Worlds) {
    let _ = rosbag::read(&s.bytes);
    let _ = rosbag::read_with(&s.bytes, &carmen::ReadOptions::default());
}

/// An MCAP file of ROS 2 messages (its records, chunks and CDR payloads), strictly and
/// salvaging.
fn parse_mcap(s: &Seed, _: &mut Worlds) {
    let strict = carmen::ReadOptions {
        strict: true,
        ..Default::default()
    };
    let _ = futago_msgs::rosbag2::read_mcap(&s.bytes, &strict);
    let _ = futago_msgs::rosbag2::read_mcap(&s.bytes, &carmen::ReadOptions::default());
}

/// A rosbag2 SQLite3 file (SQLite's pages, the topics and messages tables, their CDR
/// payloads), strictly and salvaging.
fn parse_db3(s: &Seed, _: &mut Worlds) {
    let strict = carmen::ReadOptions {
        strict: true,
        ..Default::default()
    };
    let _ = futago_msgs::rosbag2::read_db3(&s.bytes, &strict);
    let _ = futago_msgs::rosbag2::read_db3(&s.bytes, &carmen::ReadOptions::default());
}

fn parse_tum(s: &Seed, _: &mut Worlds) {
    let t = text(&s.bytes);
    let _ = tum::parse(&t);
    let _ = tum::parse_image_list(&t);
}

/// A map_server YAML file over a small image of the project's own writing.
fn parse_map_yaml(s: &Seed, _: &mut Worlds) {
    let _ = futago_msgs::map_server::parse(&s.origin, &text(&s.bytes), |_| Ok(map_seed().to_pgm()));
}

/// A map image (PGM or PNG) under a fixed YAML file.
fn parse_map_image(s: &Seed, _: &mut Worlds) {
    let yaml = "image: m.pgm\nresolution: 0.05\norigin: [-1.0, 2.0, 0.0]\nmode: scale\n";
    let _ = futago_msgs::map_server::parse(&s.origin, yaml, |_| Ok(s.bytes.clone()));
}

/// A 12 × 9 map of free, occupied and unknown cells.
fn map_seed() -> futago_msgs::grid::OccupancyGrid {
    let mut g = futago_msgs::grid::OccupancyGrid::new(0.05, [-1.0, 2.0], 12, 9);
    for (k, c) in g.cells.iter_mut().enumerate() {
        *c = [0, 0, 100, -1, 0][k % 5];
    }
    g
}

/// A landmark map (seed 001), read and handed to the localiser's map.
fn parse_landmarks(s: &Seed, _: &mut Worlds) {
    if let Ok(f) = futago_msgs::landmarks::LandmarkFile::parse(&s.origin, &text(&s.bytes)) {
        let _ = futago_robot::localization::landmarks::LandmarkMap::from_file(&f);
    }
}

/// The first landmarks of the shipped lab map.
fn landmarks_seed(root: &Path) -> Result<Vec<u8>> {
    let path = root.join("worlds/maps/lab-landmarks.json");
    let mut f =
        futago_msgs::landmarks::LandmarkFile::read(&path).map_err(|e| anyhow::anyhow!("{e}"))?;
    f.landmarks.truncate(20);
    Ok(serde_json::to_vec(&f)?)
}

/// A pedestrian trajectory file (ETH/UCY), read and measured as `futago crowd` does.
fn parse_pedestrians(s: &Seed, _: &mut Worlds) {
    if let Ok(t) = futago_msgs::pedestrians::parse(&text(&s.bytes)) {
        let o = crate::ground_truth::crowd::CrowdOptions {
            frame_step: t.frame_step,
            ..Default::default()
        };
        let _ = crate::ground_truth::crowd::measure(&t.samples, &o);
    }
}

/// Three people over six frames, two of them abreast, in the ETH/UCY layout with its label
/// column.
fn pedestrians_seed() -> String {
    let mut s = String::new();
    for k in 0..6 {
        let x = 0.4 * k as f64;
        s += &format!("{}.0\t1.0\t4\t{x:.2}\t0.5\n", 10 * k);
        s += &format!("{}.0\t2.0\t4\t{x:.2}\t1.3\n", 10 * k);
        s += &format!("{}.0\t3.0\t1\t3.0\t{:.2}\n", 10 * k, 5.0 - x);
    }
    s
}

fn parse_relations(s: &Seed, _: &mut Worlds) {
    let _ = crate::relations::parse(&text(&s.bytes), "fuzz");
}

/// An overlay laid over the scenario the seed came from, as `--overlay` does, and each of
/// its lines as a `--set`.
fn parse_overlay(s: &Seed, worlds: &mut Worlds) {
    let t = text(&s.bytes);
    for line in t.lines() {
        let _ = crate::overlay::Overlay::parse_set(line);
    }
    let Ok(table) = parse_toml::<toml::Table>(&s.origin, &t) else {
        return;
    };
    let Ok(base) = std::fs::read_to_string(&s.origin) else {
        return;
    };
    let Ok(mut config) = base.parse::<toml::Table>() else {
        return;
    };
    crate::overlay::Overlay {
        origin: PathBuf::from("fuzz"),
        table,
    }
    .apply(&mut config);
    if let Ok(spec) =
        serde_path_to_error::deserialize::<_, ScenarioSpec>(toml::Value::Table(config))
    {
        let _ = crate::stack::from_spec_with(&s.origin, spec, &mut |p| worlds.load(p));
    }
}

fn files(dir: &Path, ext: &str) -> Result<Vec<Seed>> {
    let mut out = Vec::new();
    let entries =
        std::fs::read_dir(dir).with_context(|| format!("reading seeds in {}", dir.display()))?;
    let mut paths: Vec<PathBuf> = entries.filter_map(|e| e.ok().map(|e| e.path())).collect();
    paths.sort();
    for p in paths {
        if p.extension().is_some_and(|e| e == ext) {
            let bytes = std::fs::read(&p).with_context(|| format!("reading {}", p.display()))?;
            out.push(Seed { origin: p, bytes });
        }
    }
    Ok(out)
}

/// A CARMEN log written by the project's writer: parameters, odometry, a true pose and a
/// laser reading.
fn carmen_seed() -> String {
    let mut s = String::new();
    carmen::param(&mut s, "robot_front_laser_max", "30.0");
    let a = Pose2::new(1.0, 2.0, 0.3);
    carmen::odom(&mut s, 0.1, &a, 0.2, 0.05);
    carmen::truepos(&mut s, 0.1, &Pose2::new(1.01, 2.0, 0.31), &a);
    let scan = futago_msgs::LaserScan {
        frame: "front".into(),
        stamp: Time::from_secs(0.15),
        angle_min: -1.0,
        angle_increment: 0.5,
        time_increment: 0.0,
        range_min: 0.02,
        range_max: 30.0,
        ranges: vec![1.0, 2.5, f32::INFINITY, 3.0, 0.5],
    };
    let laser = a.compose(&Pose2::new(0.1, 0.0, 0.0));
    carmen::robotlaser(&mut s, 1, &scan, 0.01, &laser, &a, 0.2, 0.05);
    s.push('\n');
    carmen::odom(&mut s, 0.2, &Pose2::new(1.05, 2.01, 0.31), 0.2, 0.05);
    s
}

fn tum_seed() -> String {
    let mut s = "# timestamp tx ty tz qx qy qz qw\n".to_string();
    for k in 0..5 {
        tum::format_line(
            &mut s,
            &tum::Stamped {
                stamp: Time::from_secs(k as f64 * 0.1),
                pose: futago_msgs::Pose3::from_pose2(
                    &Pose2::new(k as f64, 0.5, 0.1 * k as f64),
                    0.0,
                ),
            },
        );
    }
    s
}

fn relations_seed() -> String {
    "# t1 t2 x y z roll pitch yaw\n0.0 1.0 0.5 0.0 0.0 0.0 0.0 0.1\n1.0 2.5 1.2 -0.3 0.0 0.0 0.0 -0.4\n"
        .to_string()
}

fn overlay_seeds(scenarios: &[Seed]) -> Vec<Seed> {
    let overlay = "duration = 5.0\n[robot.odometry]\nnoise = 0.01\n[localization.mcl]\nparticles = 300\n[slam]\nkeyframe_distance = 0.2\n[controller]\nspeed = 0.2\n";
    scenarios
        .iter()
        .map(|s| Seed {
            origin: s.origin.clone(),
            bytes: overlay.as_bytes().to_vec(),
        })
        .collect()
}

/// The targets, with seeds from the project at `root` (its `scenarios/` and `worlds/`).
pub fn targets(root: &Path) -> Result<Vec<Target>> {
    let scenarios = files(&root.join("scenarios"), "toml")?;
    let mut worlds = files(&root.join("worlds"), "toml")?;
    worlds.extend(files(&root.join("worlds/parts"), "toml")?);
    // Worlds that extrude a map's walls compile thousands of boxes for every input: the map
    // reader is fuzzed on its own (`map_yaml`, `map_image`), the rest of such a world's keys
    // in the other worlds.
    worlds.retain(|w| !text(&w.bytes).contains("[[map_walls]]"));
    let glb = files(&root.join("worlds/assets"), "glb")?;
    let made = |name: &str, bytes: Vec<u8>| Seed {
        origin: root.join(name),
        bytes,
    };
    Ok(vec![
        Target {
            name: "scenario",
            text: true,
            seeds: scenarios.clone(),
            parse: parse_scenario,
        },
        Target {
            name: "overlay",
            text: true,
            seeds: overlay_seeds(&scenarios),
            parse: parse_overlay,
        },
        Target {
            name: "world",
            text: true,
            seeds: worlds,
            parse: parse_world,
        },
        Target {
            name: "gltf",
            text: false,
            seeds: glb,
            parse: parse_gltf,
        },
        Target {
            name: "carmen",
            text: true,
            seeds: vec![made("fuzz.clf", carmen_seed().into_bytes())],
            parse: parse_carmen,
        },
        Target {
            name: "rosbag",
            text: false,
            seeds: vec![
                made("fuzz.bag", rosbag::example(true)),
                made("fuzz-none.bag", rosbag::example(false)),
                made(
                    "fuzz-lz4.bag",
                    rosbag::example_mounted("lz4", [0.0, 0.0, 0.0, 1.0]),
                ),
            ],
            parse: parse_bag,
        },
        Target {
            name: "mcap",
            text: false,
            seeds: vec![made("fuzz.mcap", futago_msgs::rosbag2::example_mcap())],
            parse: parse_mcap,
        },
        Target {
            name: "db3",
            text: false,
            seeds: vec![made("fuzz.db3", futago_msgs::rosbag2::example_db3())],
            parse: parse_db3,
        },
        Target {
            name: "map_yaml",
            text: true,
            seeds: vec![made("fuzz.yaml", map_seed().to_yaml("m.pgm").into_bytes())],
            parse: parse_map_yaml,
        },
        Target {
            name: "map_image",
            text: false,
            seeds: vec![made("fuzz.yaml", map_seed().to_pgm())],
            parse: parse_map_image,
        },
        Target {
            name: "tum",
            text: true,
            seeds: vec![made("fuzz.txt", tum_seed().into_bytes())],
            parse: parse_tum,
        },
        Target {
            name: "relations",
            text: true,
            seeds: vec![made("fuzz.relations", relations_seed().into_bytes())],
            parse: parse_relations,
        },
        Target {
            name: "pedestrians",
            text: true,
            seeds: vec![made(
                "fuzz-pedestrians.txt",
                pedestrians_seed().into_bytes(),
            )],
            parse: parse_pedestrians,
        },
        Target {
            name: "landmarks",
            text: true,
            seeds: vec![made("fuzz-landmarks.json", landmarks_seed(root)?)],
            parse: parse_landmarks,
        },
    ])
}

/// Values at the edges of numbers' types, for text mutations.
const EDGES: [&str; 16] = [
    "0",
    "-1",
    "1e300",
    "-1e300",
    "nan",
    "inf",
    "-inf",
    "1e-300",
    "4294967296",
    "-2147483649",
    "18446744073709551616",
    "9223372036854775807",
    "65535",
    "0.0",
    "-0.0",
    "1e20",
];

/// Applies 1 to 8 stacked mutations to `input`.
fn mutate(input: &mut Vec<u8>, text: bool, other: &[u8], rng: &mut ChaCha8Rng) {
    for _ in 0..rng.random_range(1..=8) {
        let n = input.len();
        match rng.random_range(0..if text { 10 } else { 7 }) {
            0 if n > 0 => {
                let i = rng.random_range(0..n);
                input[i] ^= 1 << rng.random_range(0..8);
            }
            1 if n > 0 => {
                let i = rng.random_range(0..n);
                input[i] = rng.random();
            }
            2 => {
                let i = rng.random_range(0..=n);
                let k = rng.random_range(1..=8);
                let bytes: Vec<u8> = (0..k).map(|_| rng.random()).collect();
                input.splice(i..i, bytes);
            }
            3 if n > 0 => {
                let a = rng.random_range(0..n);
                let b = (a + rng.random_range(1..=64)).min(n);
                input.drain(a..b);
            }
            4 if n > 0 => {
                let a = rng.random_range(0..n);
                let b = (a + rng.random_range(1..=256)).min(n);
                let chunk = input[a..b].to_vec();
                let at = rng.random_range(0..=n);
                input.splice(at..at, chunk);
            }
            5 if !other.is_empty() => {
                let a = rng.random_range(0..other.len());
                let b = (a + rng.random_range(1..=512)).min(other.len());
                let at = rng.random_range(0..=n);
                input.splice(at..at, other[a..b].iter().copied());
            }
            6 if n > 0 => {
                // Little-endian integers at the edges (sizes and counts in binary formats).
                let i = rng.random_range(0..n);
                let v: u32 = [0, 1, 0x7fff_ffff, 0xffff_ffff, 0x8000_0000, 0x0010_0000]
                    [rng.random_range(0..6)];
                for (k, b) in v.to_le_bytes().into_iter().enumerate() {
                    if i + k < n {
                        input[i + k] = b;
                    }
                }
            }
            7 => replace_number(input, rng),
            8 => {
                let lines: Vec<&[u8]> = input.split(|&c| c == b'\n').collect();
                if lines.len() > 1 {
                    let (a, b) = (
                        rng.random_range(0..lines.len()),
                        rng.random_range(0..lines.len()),
                    );
                    let mut l: Vec<Vec<u8>> = lines.iter().map(|l| l.to_vec()).collect();
                    match rng.random_range(0..3) {
                        0 => l.swap(a, b),
                        1 => {
                            let d = l[a].clone();
                            l.insert(b, d);
                        }
                        _ => {
                            l.remove(a);
                        }
                    }
                    *input = l.join(&b'\n');
                }
            }
            _ => {
                let cut = rng.random_range(0..=n);
                input.truncate(cut);
            }
        }
    }
    input.truncate(MAX_INPUT);
}

/// Replaces one number in a text with a value at an edge.
fn replace_number(input: &mut Vec<u8>, rng: &mut ChaCha8Rng) {
    let starts: Vec<usize> = (0..input.len())
        .filter(|&i| input[i].is_ascii_digit() && (i == 0 || !input[i - 1].is_ascii_alphanumeric()))
        .collect();
    if starts.is_empty() {
        return;
    }
    let a = starts[rng.random_range(0..starts.len())];
    let mut b = a;
    while b < input.len() && (input[b].is_ascii_digit() || b".eE+-_".contains(&input[b])) {
        b += 1;
    }
    let v = EDGES[rng.random_range(0..EDGES.len())];
    input.splice(a..b, v.bytes());
}

/// A panic found: the target, the input and the message.
pub struct Finding {
    pub target: &'static str,
    pub input: Vec<u8>,
    pub message: String,
}

/// What a run did.
pub struct Report {
    /// Inputs per target, in target order.
    pub counts: Vec<(&'static str, u64)>,
    pub findings: Vec<Finding>,
    pub seconds: f64,
}

thread_local! {
    /// Set on a fuzzing worker: its panics are recorded, not printed.
    static FUZZING: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
    static LAST_PANIC: std::cell::RefCell<Option<String>> = const { std::cell::RefCell::new(None) };
}

/// Installs, once per process, a panic hook that records a fuzzing worker's panic message and
/// leaves every other thread's panics to the hook that was there before.
fn install_hook() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if FUZZING.with(|f| f.get()) {
                let msg = match info.location() {
                    Some(l) => format!("{info} ({}:{})", l.file(), l.line()),
                    None => info.to_string(),
                };
                LAST_PANIC.with(|p| *p.borrow_mut() = Some(msg));
            } else {
                previous(info);
            }
        }));
    });
}

/// Feeds `inputs` mutated inputs (spread over the targets round-robin, the seeds themselves
/// first) to the targets on `jobs` threads, from `seed`. Stops early once `max_findings`
/// panics are found.
pub fn run(targets: &[Target], inputs: u64, jobs: usize, seed: u64, max_findings: usize) -> Report {
    let started = std::time::Instant::now();
    let counts: Vec<AtomicU64> = targets.iter().map(|_| AtomicU64::new(0)).collect();
    let next = AtomicU64::new(0);
    let findings = Arc::new(Mutex::new(Vec::new()));
    install_hook();
    std::thread::scope(|scope| {
        for worker in 0..jobs.max(1) {
            let (counts, next, findings) = (&counts, &next, findings.clone());
            scope.spawn(move || {
                let mut rng = ChaCha8Rng::seed_from_u64(seed);
                rng.set_stream(worker as u64);
                let mut worlds = Worlds::default();
                FUZZING.with(|f| f.set(true));
                loop {
                    let k = next.fetch_add(1, Ordering::Relaxed);
                    if k >= inputs || findings.lock().map(|f| f.len()).unwrap_or(0) >= max_findings
                    {
                        break;
                    }
                    let t = &targets[(k % targets.len() as u64) as usize];
                    if t.seeds.is_empty() {
                        continue;
                    }
                    let round = k / targets.len() as u64;
                    let base = &t.seeds[rng.random_range(0..t.seeds.len())];
                    let mut input = base.clone();
                    // Each seed goes in unchanged once.
                    if round >= t.seeds.len() as u64 {
                        let other = &t.seeds[rng.random_range(0..t.seeds.len())].bytes;
                        mutate(&mut input.bytes, t.text, other, &mut rng);
                    } else {
                        input = t.seeds[round as usize].clone();
                    }
                    counts[(k % targets.len() as u64) as usize].fetch_add(1, Ordering::Relaxed);
                    let parse = t.parse;
                    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                        parse(&input, &mut worlds)
                    }));
                    if result.is_err() {
                        let message = LAST_PANIC
                            .with(|p| p.borrow_mut().take())
                            .unwrap_or_else(|| "panic".into());
                        if let Ok(mut f) = findings.lock() {
                            f.push(Finding {
                                target: t.name,
                                input: input.bytes,
                                message,
                            });
                        }
                        // The cache may hold a half-built world; start it afresh.
                        worlds = Worlds::default();
                    }
                }
            });
        }
    });
    let findings = std::mem::take(&mut *findings.lock().unwrap_or_else(|e| e.into_inner()));
    Report {
        counts: targets
            .iter()
            .zip(&counts)
            .map(|(t, c)| (t.name, c.load(Ordering::Relaxed)))
            .collect(),
        findings,
        seconds: started.elapsed().as_secs_f64(),
    }
}

/// Writes each finding's input and message to `dir` (`TARGET-N.input`, `TARGET-N.txt`).
pub fn write_findings(findings: &[Finding], out: &Path, force: bool) -> Result<()> {
    crate::run::write_atomically(out, force, "fuzz", |dir| {
        for (i, f) in findings.iter().enumerate() {
            let stem = dir.join(format!("{}-{i}", f.target));
            std::fs::write(stem.with_extension("input"), &f.input)?;
            std::fs::write(stem.with_extension("txt"), &f.message)?;
        }
        Ok(())
    })
}

/// `futago fuzz`: fuzzes every parser of the files under `root` with `inputs` mutated inputs
/// on `jobs` threads, prints the counts, and writes the inputs that panicked into `out`
/// (default `out/fuzz`, checked before any work). Gives the exit status: 1 when one did.
pub fn command(
    root: &Path,
    inputs: u64,
    jobs: usize,
    seed: u64,
    out: Option<PathBuf>,
    force: bool,
) -> Result<i32> {
    let out = out.unwrap_or_else(|| PathBuf::from("out/fuzz"));
    crate::output::check_folder(&out, force)?;
    let targets = targets(root)?;
    let r = run(&targets, inputs, jobs, seed, 100);
    for (name, n) in &r.counts {
        println!("{name:>10}: {n} inputs");
    }
    let total: u64 = r.counts.iter().map(|c| c.1).sum();
    println!(
        "fuzz: {total} inputs in {:.1} s ({:.0} per second, {jobs} jobs, seed {seed}), {} panics",
        r.seconds,
        total as f64 / r.seconds.max(1e-9),
        r.findings.len()
    );
    if r.findings.is_empty() {
        return Ok(0);
    }
    write_findings(&r.findings, &out, force)?;
    for f in &r.findings {
        eprintln!("{}: {}", f.target, f.message);
    }
    eprintln!("inputs written to {}", out.display());
    Ok(1)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn root() -> PathBuf {
        PathBuf::from(env!("CARGO_MANIFEST_DIR"))
    }

    #[test]
    fn every_target_has_seeds_that_parse() {
        let targets = targets(&root()).unwrap();
        assert_eq!(targets.len(), 14);
        for t in &targets {
            assert!(!t.seeds.is_empty(), "{}", t.name);
        }
        // The seeds are valid inputs: the writers' outputs read back.
        assert_eq!(carmen::read(&carmen_seed()).unwrap().scans.len(), 1);
        let yaml = map_seed().to_yaml("m.pgm");
        let map =
            futago_msgs::map_server::parse(Path::new("m.yaml"), &yaml, |_| Ok(map_seed().to_pgm()));
        assert_eq!(map.unwrap(), map_seed());
        assert_eq!(tum::parse(&tum_seed()).unwrap().len(), 5);
        let p = futago_msgs::pedestrians::parse(&pedestrians_seed()).unwrap();
        assert_eq!((p.samples.len(), p.frame_step), (18, 10));
        assert_eq!(
            crate::relations::parse(&relations_seed(), "x")
                .unwrap()
                .len(),
            2
        );
        for c in ["none", "bz2", "lz4"] {
            let bag = rosbag::example_mounted(c, [0.0, 0.0, 0.0, 1.0]);
            assert_eq!(rosbag::read(&bag).unwrap().scans.len(), 1);
        }
        let mcap = futago_msgs::rosbag2::example_mcap();
        let strict = carmen::ReadOptions {
            strict: true,
            ..Default::default()
        };
        assert_eq!(
            futago_msgs::rosbag2::read_mcap(&mcap, &strict)
                .unwrap()
                .scans
                .len(),
            1
        );
        let db3 = futago_msgs::rosbag2::example_db3();
        let log = futago_msgs::rosbag2::read_db3(&db3, &strict).unwrap();
        assert_eq!(log.scans.len(), 1);
        let text = String::from_utf8(landmarks_seed(&root()).unwrap()).unwrap();
        let f = futago_msgs::landmarks::LandmarkFile::parse(Path::new("l.json"), &text).unwrap();
        assert_eq!(f.landmarks.len(), 20);
        assert!(futago_robot::localization::landmarks::LandmarkMap::from_file(&f).is_ok());
    }

    #[test]
    fn a_planted_panic_is_found_and_the_run_is_reproducible() {
        fn planted(s: &Seed, _: &mut Worlds) {
            // Panics on inputs the mutations make often: a byte 0xFF.
            assert!(!s.bytes.contains(&0xff), "planted");
        }
        let t = vec![Target {
            name: "planted",
            text: false,
            seeds: vec![Seed {
                origin: PathBuf::from("x"),
                bytes: b"hello".to_vec(),
            }],
            parse: planted,
        }];
        let r = run(&t, 2000, 1, 7, 3);
        assert_eq!(r.findings.len(), 3);
        assert!(
            r.findings[0].message.contains("planted"),
            "{}",
            r.findings[0].message
        );
        let again = run(&t, 2000, 1, 7, 3);
        assert_eq!(r.findings[0].input, again.findings[0].input);
    }

    #[test]
    fn a_short_run_over_every_parser_finds_no_panic() {
        let targets = targets(&root()).unwrap();
        let r = run(&targets, 4000, 2, 1, 10);
        let found: Vec<String> = r
            .findings
            .iter()
            .map(|f| format!("{}: {}", f.target, f.message))
            .collect();
        assert!(found.is_empty(), "{}", found.join("\n"));
        assert_eq!(r.counts.iter().map(|c| c.1).sum::<u64>(), 4000);
    }
}
