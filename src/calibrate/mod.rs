//! `futago calibrate LOG`: a robot profile (its laser's and its odometry's error models, see
//! [`futago_msgs::profile`]) estimated from a log of the real robot.
//!
//! The reference is the stack's own laser SLAM over the stretch of the log chosen (`--span`):
//! its trajectory stands for the truth, and an occupancy grid of the stretch's scans at those
//! poses stands for the world. The laser's model comes from each beam against the range cast
//! in that grid ([`laser`]); the odometry's from the reported motion against the trajectory
//! ([`odometry`]). Nothing in the procedure depends on which log it is: a user runs it on
//! their own robot's log as it is run on the shared ones.

pub mod laser;
pub mod odometry;

use crate::replay::{read_log_with, slam_over, write_tum};
use crate::run::write_atomically;
use anyhow::{Context, Result, bail};
use futago_msgs::profile::{Estimate, LaserProfile, OdometryProfile, RobotProfile, Source};
use futago_msgs::{Pose2, Time, carmen};
use futago_robot::mapping::occupancy::{OccupancyConfig, OccupancyMap};
use futago_robot::mapping::slam::SlamConfig;
use serde_json::{Value, json};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Beams whose readings are compared with the map, at most: scans are taken at an even stride
/// to stay under it (a few seconds of casting).
pub const MAX_BEAMS: usize = 400_000;

/// Fewest scans a profile is estimated from.
pub const MIN_SCANS: usize = 20;

/// How `futago calibrate` reads its log and what it writes.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrateOptions {
    pub read: carmen::ReadOptions,
    /// The stretch of the log, as fractions of its duration from its first scan.
    pub span: [f64; 2],
    /// The laser (its frame) to describe; none: the one with the most scans.
    pub laser: Option<String>,
    pub force: bool,
}

/// Parses a span `A:B` of fractions with 0 ≤ A < B ≤ 1.
pub fn parse_span(s: &str) -> Result<[f64; 2]> {
    let bad = || {
        anyhow::anyhow!(
            "--span `{s}`: expected FROM:TO, fractions of the log's duration with 0 ≤ FROM < TO ≤ 1 (e.g. 0:0.5)"
        )
    };
    let (a, b) = s.split_once(':').ok_or_else(bad)?;
    let (a, b): (f64, f64) = (
        a.trim().parse().map_err(|_| bad())?,
        b.trim().parse().map_err(|_| bad())?,
    );
    if !((0.0..1.0).contains(&a) && a < b && b <= 1.0) {
        return Err(bad());
    }
    Ok([a, b])
}

/// The default output folder: `out/calibrate/<log name>`.
pub fn default_out(log: &Path) -> PathBuf {
    let stem = log
        .file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_else(|| "log".into());
    PathBuf::from("out/calibrate").join(stem)
}

/// The scans of laser `name` (or of the laser with the most scans) within `span`.
pub(crate) fn chosen_scans(
    log: &carmen::Log,
    path: &Path,
    o: &CalibrateOptions,
) -> Result<carmen::Log> {
    let mut frames: std::collections::BTreeMap<&str, usize> = Default::default();
    for s in &log.scans {
        *frames.entry(s.scan.frame.as_str()).or_default() += 1;
    }
    let name = match &o.laser {
        Some(n) if frames.contains_key(n.as_str()) => n.clone(),
        Some(n) => bail!(
            "{}: no laser `{n}`; the log's lasers are {}",
            path.display(),
            frames
                .keys()
                .map(|k| format!("`{k}`"))
                .collect::<Vec<_>>()
                .join(", ")
        ),
        None => frames
            .iter()
            .max_by_key(|(_, n)| **n)
            .map(|(k, _)| k.to_string())
            .unwrap_or_default(),
    };
    let first = log.scans[0].scan.stamp;
    let last = log.scans[log.scans.len() - 1].scan.stamp;
    let duration = (last - first).secs();
    let at = |f: f64| Time(first.0 + Time::from_secs(f * duration).0);
    let (from, to) = (at(o.span[0]), at(o.span[1]));
    let mut chosen = within(log, from, to);
    chosen.scans.retain(|s| s.scan.frame == name);
    if chosen.scans.len() < MIN_SCANS {
        bail!(
            "{}: {} scans of laser `{name}` within the span {}–{} s; a profile needs {MIN_SCANS} at least",
            path.display(),
            chosen.scans.len(),
            (from - first).secs(),
            (to - first).secs()
        );
    }
    Ok(chosen)
}

/// The laser's layout and timing as its scans show them: the most common beam count and the
/// first such scan's angles and limits; the rate from the median interval between scans. The
/// error model's estimates are left at none (0 of 0).
fn layout(log: &carmen::Log) -> LaserProfile {
    let mut counts: std::collections::BTreeMap<usize, usize> = Default::default();
    for s in &log.scans {
        *counts.entry(s.scan.ranges.len()).or_default() += 1;
    }
    let beams = counts
        .iter()
        .max_by_key(|(_, n)| **n)
        .map_or(0, |(b, _)| *b);
    let first = log
        .scans
        .iter()
        .find(|s| s.scan.ranges.len() == beams)
        .map(|s| &s.scan)
        .unwrap_or(&log.scans[0].scan);
    let mut intervals: Vec<f64> = log
        .scans
        .windows(2)
        .map(|w| (w[1].scan.stamp - w[0].scan.stamp).secs())
        .collect();
    intervals.sort_by(f64::total_cmp);
    let median = intervals.get(intervals.len() / 2).copied().unwrap_or(0.0);
    let mut deviations: Vec<f64> = intervals.iter().map(|v| (v - median).abs()).collect();
    deviations.sort_by(f64::total_cmp);
    let mad = deviations.get(deviations.len() / 2).copied().unwrap_or(0.0);
    let none = Estimate::new(0.0, 0.0, 0);
    LaserProfile {
        name: first.frame.clone(),
        beams,
        angle_min: first.angle_min,
        angle_increment: first.angle_increment,
        range_min: first.range_min,
        range_max: first.range_max,
        rate: if median > 0.0 { 1.0 / median } else { 0.0 },
        period_spread_s: 1.4826 * mad,
        time_increment: first.time_increment,
        sigma: none,
        sigma_rel: none,
        bias: none,
        short_rate: none,
        short_lambda: none,
        random_rate: none,
        long_readings: none,
        long_excess_m: Vec::new(),
        no_return: none,
        no_return_by_range: Vec::new(),
        no_return_by_incidence: Vec::new(),
        mixed_pixels: none,
        unmapped_returns: none,
        neighbour_correlation: none,
        spread_by_range: Vec::new(),
    }
}

/// What the calibration measures on a log of one laser.
pub struct Measured {
    /// The SLAM's pose at every scan, in scan order.
    pub path: Vec<(Time, Pose2)>,
    /// The occupancy grid of the scans at those poses, and its cell side (m).
    pub map: OccupancyMap,
    pub resolution: f64,
    /// Every `stride`th scan's beams against the map.
    pub tally: laser::Tally,
    pub stride: usize,
    pub laser: LaserProfile,
    pub odometry: Option<OdometryProfile>,
    pub keyframes: usize,
    pub loop_closures: usize,
}

/// Runs the SLAM over `log` (scans of one laser) and measures its laser and odometry against
/// the result (see the module documentation); an error says what was too little.
pub fn measure(log: &carmen::Log, config: SlamConfig) -> Result<Measured, String> {
    if log.scans.len() < MIN_SCANS {
        return Err(format!(
            "{} scans to measure; a profile needs {MIN_SCANS} at least",
            log.scans.len()
        ));
    }
    let slam = slam_over(log, config);
    let path = slam.trajectory();
    // The map the beams are judged against: every scan at its SLAM pose.
    let range_max = log.scans[0].scan.range_max;
    let grid_config = OccupancyConfig {
        max_range: range_max.max(0.1),
        ..OccupancyConfig::default()
    };
    let mut map = OccupancyMap::new(grid_config);
    for (s, (_, p)) in log.scans.iter().zip(&path) {
        map.insert(&p.compose(&s.mount), &s.scan);
    }
    let beams: usize = log.scans.iter().map(|s| s.scan.ranges.len()).sum();
    let stride = beams.div_ceil(MAX_BEAMS).max(1);
    let mut tally = laser::Tally::new();
    for (s, (_, p)) in log.scans.iter().zip(&path).step_by(stride) {
        tally.add(&map, grid_config.resolution, &p.compose(&s.mount), &s.scan);
    }
    let Some(laser) = laser::error_model(&tally, layout(log)) else {
        return Err(format!(
            "too few beams ({}) fall where the map holds a surface to estimate the laser's errors",
            tally.readings.len()
        ));
    };
    let odometry = if log.odometry_absent {
        None
    } else {
        let samples: Vec<odometry::Sample> = log
            .scans
            .iter()
            .zip(&path)
            .map(|(s, (_, p))| odometry::Sample {
                stamp: s.scan.stamp,
                odometry: s.odometry,
                reference: *p,
            })
            .collect();
        odometry::calibrate(&samples, &log.odometry)
    };
    Ok(Measured {
        path,
        map,
        resolution: grid_config.resolution,
        tally,
        stride,
        laser,
        odometry,
        keyframes: slam.keyframes(),
        loop_closures: slam.loop_closures(),
    })
}

/// The beams of the scans of `log` stamped within `[from, to]` against the map of `m` (a
/// measurement of the same log) at its poses, every `m.stride`th scan.
pub fn tally_within(log: &carmen::Log, m: &Measured, from: Time, to: Time) -> laser::Tally {
    let mut tally = laser::Tally::new();
    for (s, (_, p)) in log
        .scans
        .iter()
        .zip(&m.path)
        .filter(|(s, _)| s.scan.stamp >= from && s.scan.stamp <= to)
        .step_by(m.stride)
    {
        tally.add(&m.map, m.resolution, &p.compose(&s.mount), &s.scan);
    }
    tally
}

/// The scans of `log` stamped within `[from, to]` (with the odometry records there).
pub fn within(log: &carmen::Log, from: Time, to: Time) -> carmen::Log {
    carmen::Log {
        scans: log
            .scans
            .iter()
            .filter(|s| s.scan.stamp >= from && s.scan.stamp <= to)
            .cloned()
            .collect(),
        odometry: log
            .odometry
            .iter()
            .filter(|(t, _)| *t >= from && *t <= to)
            .copied()
            .collect(),
        odometry_absent: log.odometry_absent,
        ..Default::default()
    }
}

/// Estimates a robot profile from the log at `log_path` and writes `profile.toml`,
/// `summary.json` (the profile with the run's counts), the reference `trajectory.txt` (TUM)
/// and `map.pgm`/`map.yaml` into `out`, whole or not at all.
pub fn calibrate(
    log_path: &Path,
    config: SlamConfig,
    out: &Path,
    o: &CalibrateOptions,
) -> Result<(RobotProfile, Value)> {
    crate::output::check_folder(out, o.force)?;
    let full = read_log_with(log_path, &o.read)?;
    if full.scans.is_empty() {
        bail!("{}: the log holds no laser scans", log_path.display());
    }
    let started = Instant::now();
    let log = chosen_scans(&full, log_path, o)?;
    let Measured {
        path,
        map,
        tally,
        laser,
        odometry,
        stride,
        resolution,
        keyframes,
        loop_closures,
    } = measure(&log, config).map_err(|e| anyhow::anyhow!("{}: {e}", log_path.display()))?;
    let first = full.scans[0].scan.stamp;
    let profile = RobotProfile {
        source: Source {
            log: log_path.display().to_string(),
            from_s: (log.scans[0].scan.stamp - first).secs(),
            to_s: (log.scans[log.scans.len() - 1].scan.stamp - first).secs(),
            scans: log.scans.len(),
            procedure: format!(
                "futago {} calibrate: reference = the stack's laser SLAM ({:?}) over the span; laser = beam model mixture (Thrun et al. 2005, §6.3) fitted by EM to the beams of one scan in {} against ranges cast in a {} m occupancy grid of the span's scans; odometry = UMBmark systematic terms and a random walk over stretches of {:?} × ({} m or {} rad)",
                env!("CARGO_PKG_VERSION"),
                config.method,
                stride,
                resolution,
                odometry::SCALES,
                odometry::STRETCH_M,
                odometry::STRETCH_RAD
            ),
        },
        laser,
        odometry,
    };
    let wall = started.elapsed().as_secs_f64();
    let text = format!(
        "# futago robot profile, written by `futago calibrate` (see its README section)\n{}",
        toml::to_string(&profile).context("writing the profile as TOML")?
    );
    let summary = write_atomically(out, o.force, "calibrate", |tmp| {
        std::fs::write(tmp.join("profile.toml"), &text).context("writing profile.toml")?;
        let trajectory = crate::replay::as_logged(&path, &log);
        write_tum(
            &tmp.join("trajectory.txt"),
            &format!(
                "# futago SLAM on {} (the calibration's reference)",
                log_path.display()
            ),
            &trajectory,
        )?;
        map.to_grid()
            .write_map_server(tmp, "map")
            .context("writing map.pgm and map.yaml")?;
        let summary = json!({
            "log": log_path.display().to_string(),
            "profile": profile,
            "beams_compared": tally.no_return.1,
            "scan_stride": stride,
            "keyframes": keyframes,
            "loop_closures": loop_closures,
            "performance": { "wall_time_s": wall },
        });
        std::fs::write(
            tmp.join("summary.json"),
            serde_json::to_string_pretty(&summary)? + "\n",
        )
        .context("writing summary.json")?;
        Ok(summary)
    })?;
    Ok((profile, summary))
}

/// Prints a profile's main figures.
pub fn print(p: &RobotProfile, out: &Path) {
    let l = &p.laser;
    println!(
        "laser `{}`: {} beams, {:.1} Hz; hit σ(r) = √({:.4}² + ({:.5}·r)²) m, bias {:+.4} m; short {:.2} % (λ {:.2}/m), random {:.2} %, no return {:.2} %, mixed pixels {:.1} % of {} edges; neighbours' residuals correlated {:.2} ± {:.2}",
        l.name,
        l.beams,
        l.rate,
        l.sigma.value,
        l.sigma_rel.value,
        l.bias.value,
        100.0 * l.short_rate.value,
        l.short_lambda.value,
        100.0 * l.random_rate.value,
        100.0 * l.no_return.value,
        100.0 * l.mixed_pixels.value,
        l.mixed_pixels.n,
        l.neighbour_correlation.value,
        l.neighbour_correlation.sd
    );
    match &p.odometry {
        Some(o) => println!(
            "odometry: translation ×{:.4} ± {:.4}, rotation ×{:.4} ± {:.4}, heading bias {:+.5} rad/m; random walk {:.2e} m²/m, {:.2e} rad²/rad, {:.2e} rad²/m; outliers {:.1} % of {} stretches; latency {:+.3} ± {:.3} s",
            o.translation_scale.value,
            o.translation_scale.sd,
            o.rotation_scale.value,
            o.rotation_scale.sd,
            o.heading_bias.value,
            o.translation_variance.value,
            o.heading_variance_per_rad.value,
            o.heading_variance_per_m.value,
            100.0 * o.outlier_rate.value,
            o.stretches,
            o.latency.value,
            o.latency.sd
        ),
        None => println!("odometry: none in the log (or too little motion to fit)"),
    }
    println!("→ {}", out.join("profile.toml").display());
}
