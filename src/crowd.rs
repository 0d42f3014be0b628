//! `futago crowd`: real crowds measured, the twin's crowd calibrated on them, and the two
//! compared statistic by statistic.
//!
//! Real crowds come as trajectory files of the ETH and UCY format
//! ([`futago_msgs::pedestrians`]). Both commands measure them with
//! [`crate::ground_truth::crowd::measure`]:
//! - `futago crowd calibrate FILE… --out crowd.toml` fits the crowd model's walking speed
//!   (mean and spread), the share of arrivals that come as pairs and the pairs' spacing, each
//!   sequence weighing the same. The speed is fitted in the loop: the model's people slow
//!   down as they meet others and keep pace with a companion, so the speed they want is
//!   scaled until the simulated crowds walk, over all sequences, as fast as the real ones.
//! - `futago crowd compare FILE… --profile crowd.toml --out DIR` simulates, for each real
//!   sequence, a crowd given only that sequence's density and walkable area: people cross an
//!   open square floor of that area between its sides (entering and leaving anywhere along
//!   them), arriving at the rate that holds the density. Only what happens on the square is
//!   measured, as a camera above it would. The report sets the real and simulated statistics
//!   side by side, with their ratios and whether each is within [`TOLERANCE`].
//!
//! The simulated crowd is the simulator's own ([`futago_sim::people::Crowd`]: the social
//! force model, the bodies' separation, the flows and pairs), stepped without physics or
//! sensors, so what is calibrated here is what scenarios run.

use crate::ground_truth::crowd::{CrowdOptions, CrowdStats, measure};
use crate::run::write_atomically;
use anyhow::{Context, Result, bail};
use futago_msgs::pedestrians::{self, Sample};
use futago_sim::people::{Crowd, CrowdConfig, FlowConfig, Surroundings};
use serde::{Deserialize, Serialize};
use serde_json::json;
use std::path::{Path, PathBuf};

/// How far a simulated statistic may be from the real one: ±15 % of it (issue 45's goal).
pub const TOLERANCE: f64 = 0.15;

/// What a crowd profile holds: the walking speed of the flows' people and the `[crowd]`
/// model (its pairs), as `futago crowd calibrate` writes them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CrowdProfile {
    pub walking: Walking,
    pub crowd: CrowdConfig,
}

/// The speed people want to walk at: drawn per person from N(speed, speed_std²), m/s; a
/// scenario's `[[flow]]` takes them as its `speed` and `speed_std`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Walking {
    pub speed: f64,
    pub speed_std: f64,
}

impl Default for CrowdProfile {
    /// The simulator's defaults: pedsim's N(1.2, 0.2²) and no pairs.
    fn default() -> Self {
        CrowdProfile {
            walking: Walking {
                speed: 1.2,
                speed_std: 0.2,
            },
            crowd: CrowdConfig::default(),
        }
    }
}

impl CrowdProfile {
    /// Reads and checks a profile file; errors name the file and the key.
    pub fn load(path: &Path) -> Result<CrowdProfile> {
        let text = futago_sim::config::read_text(path)?;
        let p: CrowdProfile = futago_sim::config::parse_toml(path, &text)?;
        p.crowd.validate(path)?;
        for (key, v, lo, hi) in [
            ("walking.speed", p.walking.speed, 0.1, 3.0),
            ("walking.speed_std", p.walking.speed_std, 0.0, 1.0),
        ] {
            if !(v.is_finite() && (lo..=hi).contains(&v)) {
                bail!("{}: {key} = {v}: expected {lo} to {hi} m/s", path.display());
            }
        }
        Ok(p)
    }
}

/// The most people per frame a sequence may hold: its crowd is simulated with every pair of
/// people interacting at every step.
pub const MAX_PEOPLE: f64 = 1000.0;

/// A real sequence: its file, name and samples.
pub struct Sequence {
    pub path: PathBuf,
    pub name: String,
    pub samples: Vec<Sample>,
    pub options: CrowdOptions,
}

/// Reads a trajectory file; `period` is its frame period, s.
pub fn read(path: &Path, period: f64) -> Result<Sequence> {
    if !(period.is_finite() && period > 0.0 && period <= 60.0) {
        bail!("--period {period}: expected a frame period of 0 to 60 s");
    }
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let t = pedestrians::parse(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    let frames = t
        .samples
        .windows(2)
        .filter(|w| w[0].frame != w[1].frame)
        .count()
        + 1;
    let per_frame = t.samples.len() as f64 / frames as f64;
    if per_frame > MAX_PEOPLE {
        bail!(
            "{}: {per_frame:.0} people per frame on average; the simulated crowd holds at most {MAX_PEOPLE}",
            path.display()
        );
    }
    let name = path
        .file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_else(|| "sequence".into());
    Ok(Sequence {
        path: path.to_path_buf(),
        name,
        samples: t.samples,
        options: CrowdOptions {
            period,
            frame_step: t.frame_step,
            ..CrowdOptions::default()
        },
    })
}

/// How a simulated crowd is run: its length, the time it settles first, its step.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ArenaOptions {
    /// Measured time, s.
    pub duration: f64,
    /// Time before measuring, s.
    pub warm_up: f64,
    /// The crowd's step, s.
    pub dt: f64,
    /// How far outside the square people enter and leave, m.
    pub margin: f64,
}

impl Default for ArenaOptions {
    fn default() -> Self {
        ArenaOptions {
            duration: 600.0,
            warm_up: 60.0,
            dt: 0.02,
            margin: 1.0,
        }
    }
}

/// The mean length of a straight walk between uniform points of two different sides of the
/// unit square, the twelve ordered pairs of sides alike: (8·0.7652 + 4·1.0766) / 12 (adjacent
/// sides: E√(u² + v²); opposite: E√(1 + (u − v)²); u, v uniform on [0, 1]).
const MEAN_CROSSING: f64 = (8.0 * 0.765_196 + 4.0 * 1.076_635) / 12.0;

/// A crowd simulated on an open square of `area` m² at `density` people per m², with
/// `profile`'s people: its samples on the square every `o.period`, numbered as `o` numbers
/// frames. `rate_scale` multiplies the arrival rate first estimated from the density.
fn simulate(
    profile: &CrowdProfile,
    area: f64,
    density: f64,
    o: &CrowdOptions,
    a: &ArenaOptions,
    seed: u64,
    rate_scale: f64,
) -> Vec<Sample> {
    let side = area.sqrt();
    let m = a.margin;
    // The sides, outside the square by the margin, each from one corner to the next.
    let sides = [
        ([-m, 0.0], [-m, side]),
        ([side + m, 0.0], [side + m, side]),
        ([0.0, -m], [side, -m]),
        ([0.0, side + m], [side, side + m]),
    ];
    let people = density * area;
    // Mean time on the square: a crossing at the wanted speed, and the stops on the way.
    let c = &profile.crowd;
    let crossing =
        MEAN_CROSSING * side / profile.walking.speed.max(0.1) * (1.0 + c.stop_rate * c.stop_time);
    let per_minute = 60.0 * people / crossing * rate_scale;
    let mut flows = Vec::new();
    for (i, from) in sides.iter().enumerate() {
        for (j, to) in sides.iter().enumerate() {
            if i == j {
                continue;
            }
            flows.push(FlowConfig {
                name: format!("side{i}-side{j}"),
                from: from.0,
                to: to.0,
                via: Vec::new(),
                rate: (per_minute / 12.0).max(1e-6),
                spread: 0.0,
                from_end: Some(from.1),
                to_end: Some(to.1),
                start_time: 0.0,
                end_time: f64::INFINITY,
                max: (people / 12.0 * 6.0).ceil() as usize + 6,
                speed: profile.walking.speed,
                speed_std: profile.walking.speed_std,
            });
        }
    }
    let mut crowd = Crowd::new(&[], &flows, profile.crowd, seed);
    let open = |_: [f64; 2], _: f64| None;
    let around = Surroundings {
        robot: None,
        nearest_obstacle: &open,
    };
    let steps_per_frame = (o.period / a.dt).round().max(1.0) as u64;
    let dt = o.period / steps_per_frame as f64;
    let warm = (a.warm_up / o.period).round() as i64;
    let frames = (a.duration / o.period).round() as i64;
    let mut out = Vec::new();
    let mut t = 0.0;
    for frame in 0..warm + frames {
        if frame >= warm {
            for p in crowd.truth() {
                let q = [p.pose.x, p.pose.y];
                if (0.0..=side).contains(&q[0]) && (0.0..=side).contains(&q[1]) {
                    out.push(Sample {
                        frame: (frame - warm) * o.frame_step,
                        person: i64::from(p.id),
                        position: q,
                    });
                }
            }
        }
        for _ in 0..steps_per_frame {
            crowd.step(t, dt, &around);
            t += dt;
        }
    }
    out.sort_by_key(|s| (s.frame, s.person));
    out
}

/// A crowd simulated at `real`'s density and area: the arrival rate is estimated from the
/// density, then scaled once by how far the first run's density fell from it.
pub fn simulate_like(
    profile: &CrowdProfile,
    real: &CrowdStats,
    o: &CrowdOptions,
    a: &ArenaOptions,
    seed: u64,
) -> Vec<Sample> {
    let first = simulate(profile, real.area_m2, real.density, o, a, seed, 1.0);
    let frames = (a.duration / o.period).round().max(1.0);
    let count = first.len() as f64 / frames;
    let scale = if count > 0.0 {
        (real.mean_count / count).clamp(0.25, 4.0)
    } else {
        1.0
    };
    simulate(profile, real.area_m2, real.density, o, a, seed, scale)
}

/// One real sequence against its simulations.
#[derive(Debug, Clone, Serialize)]
pub struct Comparison {
    pub name: String,
    pub file: String,
    pub real: CrowdStats,
    /// Each seed's statistics.
    pub sim: Vec<CrowdStats>,
    /// The compared statistics: name, real value, the median over seeds, their ratio and
    /// whether it is within the tolerance.
    pub rows: Vec<Row>,
}

#[derive(Debug, Clone, Serialize)]
pub struct Row {
    pub statistic: &'static str,
    pub real: f64,
    pub sim: f64,
    pub ratio: f64,
    pub within: bool,
    /// Whether the goal counts it (the others are shown for what they say of the model).
    pub gated: bool,
}

/// The statistics compared: name, how to read it, whether it is one of the goal's four.
type Statistic = (&'static str, fn(&CrowdStats) -> f64, bool);
const STATISTICS: [Statistic; 10] = [
    ("speed_mean_mps", |s| s.speed_mean, true),
    ("speed_std_mps", |s| s.speed_std, true),
    ("nn_median_m", |s| s.nn_median_m, true),
    ("nn_p10_m", |s| s.nn_p10_m, true),
    ("people_per_frame", |s| s.mean_count, false),
    ("standing_fraction", |s| s.standing_fraction, false),
    ("stop_rate_per_s", |s| s.stop_rate, false),
    ("stop_time_s", |s| s.stop_time, false),
    ("grouped_fraction", |s| s.grouped_fraction, false),
    ("group_distance_m", |s| s.group_distance_m, false),
];

/// `real`'s sequence simulated with `seeds` seeds (0 to seeds − 1, `jobs` at a time) and
/// compared.
pub fn compare(
    seq: &Sequence,
    profile: &CrowdProfile,
    a: &ArenaOptions,
    seeds: u64,
    jobs: usize,
) -> (Comparison, Vec<Sample>) {
    let o = &seq.options;
    let real = measure(&seq.samples, o);
    let seed_list: Vec<u64> = (0..seeds).collect();
    let runs = crate::parallel::parallel_map(&seed_list, jobs, |_, &k| {
        let s = simulate_like(profile, &real, o, a, k);
        (measure(&s, o), s)
    });
    let sim: Vec<CrowdStats> = runs.iter().map(|r| r.0).collect();
    let first = runs.into_iter().next().map(|r| r.1).unwrap_or_default();
    let rows = STATISTICS
        .iter()
        .map(|(name, get, gated)| {
            let values: Vec<f64> = sim.iter().map(get).filter(|v| v.is_finite()).collect();
            let s = crate::ground_truth::trajectory::Stats::percentile(&values, 50.0)
                .unwrap_or(f64::NAN);
            let r = get(&real);
            let ratio = s / r;
            Row {
                statistic: name,
                real: r,
                sim: s,
                ratio,
                within: (ratio - 1.0).abs() <= TOLERANCE,
                gated: *gated,
            }
        })
        .collect();
    (
        Comparison {
            name: seq.name.clone(),
            file: seq.path.display().to_string(),
            real,
            sim,
            rows,
        },
        first,
    )
}

/// Fits a crowd profile to `sequences`, each weighing the same, starting from `start`'s
/// model: pairs from the share of people walking with a companion (a share `p` of arrivals
/// that are pairs puts 2p / (1 + p) of the people in pairs), their spacing from companions'
/// median distance, the speed's spread from the real one, and the wanted speed scaled twice
/// by the ratio of the real mean speed to the simulated one.
pub fn calibrate(
    sequences: &[Sequence],
    start: &CrowdProfile,
    a: &ArenaOptions,
    jobs: usize,
) -> Result<(CrowdProfile, Vec<CrowdStats>)> {
    if sequences.is_empty() {
        bail!("no trajectory files to calibrate on");
    }
    let real: Vec<CrowdStats> = sequences
        .iter()
        .map(|s| measure(&s.samples, &s.options))
        .collect();
    let mean = |f: fn(&CrowdStats) -> f64, what: &str| -> Result<f64> {
        let v: Vec<f64> = real.iter().map(f).filter(|x| x.is_finite()).collect();
        if v.is_empty() {
            bail!("no sequence gives the {what}: too few people or frames");
        }
        Ok(v.iter().sum::<f64>() / v.len() as f64)
    };
    let grouped = mean(|s| s.grouped_fraction, "share of people in groups")?;
    let mut p = start.clone();
    p.crowd.pair_fraction = (grouped / (2.0 - grouped)).clamp(0.0, 1.0);
    p.crowd.pair_spacing = mean(|s| s.group_distance_m, "companions' distance")
        .unwrap_or(start.crowd.pair_spacing)
        .clamp(2.0 * p.crowd.radius, 5.0);
    // Stops: as often per second walked as the real spells of standing, and as long once
    // the time to slow down and speed up is added back. A walker at v who wants to stand
    // reads as standing (below s) τ·ln(v/s) after the stop begins, and walks again
    // τ·ln(v/(v − s)) after it ends: the spell is τ·ln((v − s)/s) shorter than the stop.
    p.crowd.stop_rate = mean(|s| s.stop_rate, "rate of stops")
        .unwrap_or(0.0)
        .clamp(0.0, 1.0);
    let tau = p.crowd.relaxation_time;
    let stops: Vec<f64> = (sequences.iter().zip(&real))
        .filter_map(|(q, r)| {
            let s = q.options.standing_speed;
            let lag = if r.speed_mean > 2.0 * s {
                tau * ((r.speed_mean - s) / s).ln()
            } else {
                0.0
            };
            Some(r.stop_time + lag).filter(|t| t.is_finite())
        })
        .collect();
    p.crowd.stop_time = if stops.is_empty() {
        start.crowd.stop_time
    } else {
        (stops.iter().sum::<f64>() / stops.len() as f64).clamp(0.1, 3600.0)
    };
    let speed = mean(|s| s.speed_mean, "walking speed")?;
    p.walking.speed_std = mean(|s| s.speed_std, "walking speed's spread")?.clamp(0.0, 1.0);
    p.walking.speed = speed.clamp(0.1, 3.0);
    for _ in 0..2 {
        let sims = crate::parallel::parallel_map(sequences, jobs, |i, s| {
            measure(&simulate_like(&p, &real[i], &s.options, a, 0), &s.options).speed_mean
        });
        let v: Vec<f64> = sims.into_iter().filter(|x| x.is_finite()).collect();
        if v.is_empty() {
            break;
        }
        let simulated = v.iter().sum::<f64>() / v.len() as f64;
        p.walking.speed = (p.walking.speed * speed / simulated).clamp(0.1, 3.0);
    }
    Ok((p, real))
}

/// Writes `profile` to `path` whole or not at all, with a comment naming its sources.
pub fn write_profile(
    path: &Path,
    profile: &CrowdProfile,
    sources: &[Sequence],
    force: bool,
) -> Result<()> {
    crate::output::check_file(path, force, |b| b.starts_with(PROFILE_HEAD.as_bytes()))?;
    let names: Vec<String> = sources
        .iter()
        .map(|s| s.path.display().to_string())
        .collect();
    let text = format!(
        "{PROFILE_HEAD} from {}\n{}",
        names.join(", "),
        toml::to_string(profile).context("writing the crowd profile as TOML")?
    );
    let tmp = path.with_extension("toml.partial");
    std::fs::write(&tmp, text).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("writing {}", path.display()))
}

/// The first line of a profile `futago crowd calibrate` writes.
const PROFILE_HEAD: &str = "# futago crowd profile, written by `futago crowd calibrate`";

/// Compares every sequence and writes `crowd.json`, `crowd.md` and each sequence's first
/// simulated crowd (`NAME.sim.txt`, the trajectory format) into `out`.
pub fn compare_all(
    sequences: &[Sequence],
    profile: &CrowdProfile,
    a: &ArenaOptions,
    seeds: u64,
    jobs: usize,
    out: &Path,
    force: bool,
) -> Result<Vec<Comparison>> {
    crate::output::check_folder(out, force)?;
    let results: Vec<(Comparison, Vec<Sample>)> = sequences
        .iter()
        .map(|s| compare(s, profile, a, seeds, jobs))
        .collect();
    write_atomically(out, force, "crowd", |tmp| {
        for (c, s) in &results {
            let text = pedestrians::format(
                &format!(
                    "futago's crowd at the density and area of {} (seed 0): frame person x y",
                    c.file
                ),
                s,
            );
            std::fs::write(tmp.join(format!("{}.sim.txt", c.name)), text)
                .with_context(|| format!("writing {}.sim.txt", c.name))?;
        }
        let comparisons: Vec<&Comparison> = results.iter().map(|r| &r.0).collect();
        let json = json!({
            "profile": profile,
            "arena": a,
            "seeds": seeds,
            "tolerance": TOLERANCE,
            "sequences": comparisons,
        });
        std::fs::write(
            tmp.join("crowd.json"),
            serde_json::to_string_pretty(&json)? + "\n",
        )
        .context("writing crowd.json")?;
        std::fs::write(tmp.join("crowd.md"), markdown(&comparisons, seeds))
            .context("writing crowd.md")
    })?;
    Ok(results.into_iter().map(|r| r.0).collect())
}

/// The comparison as a Markdown table per sequence.
pub fn markdown(cs: &[&Comparison], seeds: u64) -> String {
    use std::fmt::Write as _;
    let mut s = format!(
        "# Simulated crowds against real ones\n\nEach real sequence's crowd is simulated at its density on an open square of its walkable area ({seeds} seeds, the median shown); a gated statistic is within ±{:.0} % of the real one or not.\n",
        TOLERANCE * 100.0
    );
    for c in cs {
        let _ = writeln!(
            s,
            "\n## {}\n\n{} frames, {} people, {:.2} per frame on {:.0} m²\n\n| statistic | real | twin | twin/real | |\n|---|---|---|---|---|",
            c.name, c.real.frames, c.real.people, c.real.mean_count, c.real.area_m2
        );
        for r in &c.rows {
            let mark = match (r.gated, r.within) {
                (true, true) => "within",
                (true, false) => "**outside**",
                (false, _) => "(not gated)",
            };
            let _ = writeln!(
                s,
                "| {} | {:.3} | {:.3} | {:.2} | {mark} |",
                r.statistic, r.real, r.sim, r.ratio
            );
        }
    }
    s
}

/// Prints the comparison's table; returns how many gated statistics are outside.
pub fn print(cs: &[Comparison]) -> usize {
    let mut outside = 0;
    for c in cs {
        println!(
            "{}: {:.2} people on {:.0} m² ({:.3}/m²)",
            c.name, c.real.mean_count, c.real.area_m2, c.real.density
        );
        for r in &c.rows {
            if r.gated && !r.within {
                outside += 1;
            }
            println!(
                "  {:<18} real {:>7.3}  twin {:>7.3}  ratio {:>5.2}{}",
                r.statistic,
                r.real,
                r.sim,
                r.ratio,
                match (r.gated, r.within) {
                    (true, true) => "",
                    (true, false) => "  outside",
                    (false, _) => "  (not gated)",
                }
            );
        }
    }
    outside
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The crossing's mean length, by a fine grid over the two sides' points.
    #[test]
    fn the_mean_crossing_is_the_squares_mean_chord_between_sides() {
        let n = 400;
        let (mut adjacent, mut opposite) = (0.0, 0.0);
        for i in 0..n {
            for j in 0..n {
                let u = (i as f64 + 0.5) / n as f64;
                let v = (j as f64 + 0.5) / n as f64;
                adjacent += u.hypot(v);
                opposite += 1f64.hypot(u - v);
            }
        }
        let (adjacent, opposite) = (adjacent / (n * n) as f64, opposite / (n * n) as f64);
        assert!((adjacent - 0.765_196).abs() < 1e-4, "{adjacent}");
        assert!((opposite - 1.076_635).abs() < 1e-4, "{opposite}");
        assert!((MEAN_CROSSING - (8.0 * adjacent + 4.0 * opposite) / 12.0).abs() < 1e-4);
    }

    /// Calibration recovers the model that made a crowd: a crowd simulated with known pairs
    /// and speeds, measured as a real sequence would be, gives back its share of pairs, their
    /// spacing and the wanted speed and its spread.
    #[test]
    fn calibration_recovers_the_model_that_made_the_crowd() {
        let o = CrowdOptions::default();
        let a = ArenaOptions {
            duration: 400.0,
            ..ArenaOptions::default()
        };
        let truth = CrowdProfile {
            walking: Walking {
                speed: 1.0,
                speed_std: 0.25,
            },
            crowd: CrowdConfig {
                pair_fraction: 0.5,
                pair_spacing: 0.9,
                stop_rate: 0.05,
                stop_time: 6.0,
                ..CrowdConfig::default()
            },
        };
        let like = CrowdStats {
            mean_count: 10.0,
            area_m2: 150.0,
            density: 10.0 / 150.0,
            ..measure(&[], &o)
        };
        let seq = Sequence {
            path: PathBuf::from("made.txt"),
            name: "made".into(),
            samples: simulate_like(&truth, &like, &o, &a, 11),
            options: o,
        };
        let (p, real) =
            calibrate(std::slice::from_ref(&seq), &CrowdProfile::default(), &a, 2).unwrap();
        // Pairs: a share p of arrivals puts 2p/(1+p) = 2/3 of the people in pairs; the
        // measure's thresholds find most of them.
        assert!(
            (real[0].grouped_fraction - 2.0 / 3.0).abs() < 0.2,
            "{real:?}"
        );
        assert!(
            (p.crowd.pair_fraction - 0.5).abs() < 0.2,
            "{}",
            p.crowd.pair_fraction
        );
        assert!(
            (p.crowd.pair_spacing - 0.9).abs() < 0.1,
            "{}",
            p.crowd.pair_spacing
        );
        assert!((p.walking.speed - 1.0).abs() < 0.1, "{}", p.walking.speed);
        // Stops: about 10 people × 400 s / (20 s + 6 s) ≈ 150 of them, so the rate and the
        // mean length are each known to about a tenth (an exponential's spread is its mean).
        assert!(
            (p.crowd.stop_rate - 0.05).abs() < 0.015,
            "{}",
            p.crowd.stop_rate
        );
        assert!(
            (p.crowd.stop_time - 6.0).abs() < 1.5,
            "{}",
            p.crowd.stop_time
        );
        assert!(
            (p.walking.speed_std - 0.25).abs() < 0.1,
            "{}",
            p.walking.speed_std
        );
    }

    /// The shipped profile loads and is a calibrated one (pairs, a speed's spread), and a
    /// profile with a value out of range is refused by its key.
    #[test]
    fn the_shipped_profile_loads_and_bad_ones_are_refused_by_key() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let p = CrowdProfile::load(&root.join("models/crowd.toml")).unwrap();
        assert!(
            p.crowd.pair_fraction > 0.0 && p.walking.speed_std > 0.2,
            "{p:?}"
        );
        let dir = tempfile::tempdir().unwrap();
        let bad = dir.path().join("p.toml");
        let text = toml::to_string(&p).unwrap();
        std::fs::write(&bad, text.replace("speed_std = ", "speed_std = 7.0\n# ")).unwrap();
        let e = CrowdProfile::load(&bad).unwrap_err().to_string();
        assert!(
            e.contains("walking.speed_std") && e.contains("p.toml"),
            "{e}"
        );
    }

    /// The simulated crowd holds the density asked, within a tenth, and the same seed gives
    /// the same crowd.
    #[test]
    fn the_arena_holds_the_density_and_is_deterministic() {
        let o = CrowdOptions::default();
        let a = ArenaOptions {
            duration: 200.0,
            ..ArenaOptions::default()
        };
        let real = CrowdStats {
            mean_count: 8.0,
            area_m2: 100.0,
            density: 0.08,
            ..measure(&[], &o)
        };
        let p = CrowdProfile::default();
        let s = simulate_like(&p, &real, &o, &a, 3);
        let count = s.len() as f64 / 500.0;
        assert!((count - 8.0).abs() < 0.8, "{count} people on the square");
        assert!(s.iter().all(|q| (0.0..=10.0).contains(&q.position[0])));
        assert_eq!(s, simulate_like(&p, &real, &o, &a, 3));
        let m = measure(&s, &o);
        // Alone or nearly, people walk at about the speed they want (1.2 m/s).
        assert!((m.speed_mean - 1.2).abs() < 0.15, "{}", m.speed_mean);
    }
}
