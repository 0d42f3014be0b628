//! `futago twin LOG --profile P --relations R`: the log's drive replayed in simulation with a
//! robot profile, and the same stack scored on both, side by side.
//!
//! 1. The stack's SLAM over the real log gives the path (the twin's truth) and the map; the
//!    map becomes a world (`world from-map`), written under `world/`.
//! 2. A twin with a perfect laser and odometry is measured as `futago calibrate` measures a
//!    log: that is the floor of the procedure (the map's cells, the SLAM's own error, beams
//!    that graze an edge). The simulated laser is the profile less that floor
//!    ([`laser_model`]): variances and rates subtract, so that the twin, measured the same way,
//!    reads as the real log does.
//! 3. For each seed, the laser is cast in the world along the path at the log's scan times
//!    with the log's layout and that model, and odometry is made from the path with the
//!    profile's errors ([`futago_sim::twin`]).
//! 4. The same SLAM runs on each twin log; the real log is scored against its relations, each
//!    twin against its truth at the same stamp pairs, over the span `--score-span` (by
//!    default the second half, so that a profile calibrated on the first half is judged on
//!    what it was not fitted to). The relations are a measurement with an error of their own,
//!    which their cycles show ([`relations::reference_noise`]); each seed's truth is scored
//!    with an error of that spread drawn in, so that like is compared with like, and its error
//!    against the exact truth is reported beside. Range residuals, odometry errors and
//!    relations errors go side by side with their ratios (twin over real, the median over the
//!    seeds).

use crate::calibrate::{self, Measured, laser::Tally};
use crate::relations::{self, Relation};
use crate::replay::{as_logged, read_log_with};
use crate::run::write_atomically;
use anyhow::{Context, Result, bail};
use futago_msgs::grid::OccupancyGrid;
use futago_msgs::profile::{LaserProfile, RobotProfile};
use futago_msgs::{Pose2, Time, carmen};
use futago_robot::mapping::slam::SlamConfig;
use futago_sim::beam::{BeamErrors, RangeProbability};
use futago_sim::noise::stream;
use futago_sim::twin::{TwinLaser, TwinOdometry};
use serde_json::{Value, json};
use std::path::{Path, PathBuf};

pub mod rank;
pub mod scenario;

/// Height of the simulated laser's beams above the floor, m: below the walls the map makes
/// and above the floor.
pub const LASER_HEIGHT: f64 = 0.3;

/// How `futago twin` runs.
#[derive(Debug, Clone, PartialEq)]
pub struct TwinOptions {
    pub read: carmen::ReadOptions,
    pub seeds: u64,
    /// The stretch scored, as fractions of the log's duration.
    pub score_span: [f64; 2],
    pub jobs: usize,
    pub force: bool,
    /// A file of SLAM configurations to rank in the twin and on the real log ([`rank`]).
    pub rank: Option<PathBuf>,
    /// The profile's path as the summary names it, where it is read from a folder that is
    /// moved into place after (a twin scenario's): none, the path it is read from.
    pub profile_as: Option<PathBuf>,
}

/// The simulated laser that, measured as the real log was, reads as `real` does: `real` less
/// the `floor` that the measurement finds on a perfect laser. Spreads subtract as variances;
/// shares of short and random readings subtract; no-return and mixed-pixel shares are taken
/// as independent of the floor's (`1 − (1 − real)/(1 − floor)`).
pub fn laser_model(real: &LaserProfile, floor: &LaserProfile) -> (f64, f64, BeamErrors) {
    let less = |a: f64, b: f64| (a * a - b * b).max(0.0).sqrt();
    let beyond = |a: f64, b: f64| {
        if b >= 1.0 {
            0.0
        } else {
            (1.0 - (1.0 - a) / (1.0 - b)).clamp(0.0, 1.0)
        }
    };
    let no_return_by_range = real
        .no_return_by_range
        .iter()
        .map(|r| {
            let f = floor
                .no_return_by_range
                .iter()
                .find(|f| f.lo == r.lo && f.hi == r.hi)
                .map_or(0.0, |f| f.value);
            RangeProbability {
                lo: r.lo,
                hi: r.hi,
                p: beyond(r.value, f),
            }
        })
        .collect();
    let short_rate = (real.short_rate.value - floor.short_rate.value).max(0.0);
    // Random readings are fitted on the long tail they make (readings far beyond the
    // surface), which is what the residuals' upper percentiles see: the mixture's random
    // share also takes up readings just behind the surface that the floor already has.
    let random_rate = (real.long_readings.value - floor.long_readings.value).max(0.0);
    let errors = BeamErrors {
        quadrature: true,
        short_rate,
        short_lambda: real.short_lambda.value.clamp(1e-3, 1e3),
        random_rate: random_rate.min(1.0 - short_rate),
        // ... and lie as far beyond their surface as the real ones do.
        random_excess: real.long_excess_m.clone(),
        no_return_by_range,
        mixed_pixels: beyond(real.mixed_pixels.value, floor.mixed_pixels.value),
        ..BeamErrors::default()
    };
    (
        less(real.sigma.value, floor.sigma.value),
        less(real.sigma_rel.value, floor.sigma_rel.value),
        errors,
    )
}

/// Rounds of fitting the twin's laser and odometry through the measurement (after the floor).
pub const FIT_ROUNDS: usize = 3;

/// The share of a gap that one round of fitting closes.
const DAMPING: f64 = 0.5;

/// `v = a² + b²·r²` fitted to rows `(r, v, weight)` by weighted least squares, both terms
/// kept non-negative; `None` without rows.
fn variance_line(rows: &[(f64, f64, f64)]) -> Option<(f64, f64)> {
    if rows.is_empty() {
        return None;
    }
    let (mut s00, mut s01, mut s11, mut g0, mut g1) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for &(r, v, w) in rows {
        let x = r * r;
        s00 += w;
        s01 += w * x;
        s11 += w * x * x;
        g0 += w * v;
        g1 += w * x * v;
    }
    let det = s00 * s11 - s01 * s01;
    let (a2, b2) = if det.abs() > 1e-12 {
        ((s11 * g0 - s01 * g1) / det, (s00 * g1 - s01 * g0) / det)
    } else {
        (g0 / s00.max(1e-12), 0.0)
    };
    Some(if a2 < 0.0 {
        (0.0, (g1 / s11.max(1e-12)).max(0.0))
    } else if b2 < 0.0 {
        ((g0 / s00.max(1e-12)).max(0.0), 0.0)
    } else {
        (a2, b2)
    })
}

/// The twin's laser: the hit's spread and the other terms of the mixture.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LaserModel {
    pub sigma: f64,
    pub sigma_rel: f64,
    pub errors: BeamErrors,
}

/// One round of fitting the laser through the measurement (indirect inference): each term
/// moves by how far the twin's measured value is from the real one, in the term's own
/// algebra (spreads as variances, shares as shares, the short readings' rate by its ratio).
pub fn refit_laser(m: &mut LaserModel, real: &LaserProfile, twin: &LaserProfile) {
    // The spread: the model's variance at each range bin moves by the real bin's less the
    // twin's, and σ² = sigma² + (sigma_rel·r)² is refitted to the moved bins (weighted by the
    // twin's hit counts); the two terms alone trade off against each other from round to
    // round.
    let rows: Vec<(f64, f64, f64)> = real
        .spread_by_range
        .iter()
        .filter_map(|r| {
            let t = twin
                .spread_by_range
                .iter()
                .find(|t| t.lo == r.lo && t.hi == r.hi)?;
            let mid = 0.5 * (r.lo + r.hi);
            let now = m.sigma.powi(2) + (m.sigma_rel * mid).powi(2);
            let moved = (now + r.value.powi(2) - t.value.powi(2)).max(0.0);
            Some((mid, moved, t.n.min(r.n) as f64))
        })
        .collect();
    if let Some((a2, b2)) = variance_line(&rows) {
        m.sigma = a2.sqrt();
        m.sigma_rel = b2.sqrt();
    }
    let e = &mut m.errors;
    // Shares move by half their gap: the terms of the mixture pull on each other's measured
    // values, and a full step overshoots.
    e.short_rate =
        (e.short_rate + DAMPING * (real.short_rate.value - twin.short_rate.value)).clamp(0.0, 1.0);
    if real.short_lambda.value > 0.0 && twin.short_lambda.value > 0.0 && e.short_rate > 0.0 {
        e.short_lambda =
            (e.short_lambda * real.short_lambda.value / twin.short_lambda.value).clamp(1e-3, 1e3);
    }
    // Nearly every uniform reading over a long range lands far beyond the surface: the long
    // share moves one for one with the random rate.
    e.random_rate = (e.random_rate
        + DAMPING * (real.long_readings.value - twin.long_readings.value))
        .clamp(0.0, 1.0 - e.short_rate);
    for b in &mut e.no_return_by_range {
        let find = |bins: &[futago_msgs::profile::Bin]| {
            bins.iter()
                .find(|x| x.lo == b.lo && x.hi == b.hi)
                .map(|x| x.value)
        };
        if let (Some(r), Some(t)) = (
            find(&real.no_return_by_range),
            find(&twin.no_return_by_range),
        ) {
            b.p = (b.p + DAMPING * (r - t)).clamp(0.0, 1.0);
        }
    }
    e.mixed_pixels = (e.mixed_pixels
        + DAMPING * (real.mixed_pixels.value - twin.mixed_pixels.value))
        .clamp(0.0, 1.0);
}

/// The twin of `real` along `truth` (a pose per scan): `laser` and `odometry` none for a
/// perfect one. Scans keep their stamps, layout and mount.
fn twin_log(
    real: &carmen::Log,
    truth: &[Pose2],
    sim: &futago_sim::Simulation,
    laser: Option<TwinLaser>,
    mut odometry: Option<TwinOdometry>,
) -> carmen::Log {
    // A perfect laser: no spread and no other term.
    let mut laser = laser.unwrap_or_else(|| {
        TwinLaser::new(0.0, 0.0, BeamErrors::default(), stream(0, "twin.perfect"))
    });
    let cast = |x: f64, y: f64, a: f64, max: f64| {
        sim.cast_ray(
            glam::Vec3::new(x as f32, y as f32, LASER_HEIGHT as f32),
            glam::Vec3::new(a.cos() as f32, a.sin() as f32, 0.0),
            max as f32,
        )
        .map(f64::from)
    };
    let first = truth.first().copied().unwrap_or(Pose2::IDENTITY);
    let scans = real
        .scans
        .iter()
        .zip(truth)
        .map(|(s, t)| {
            let pose = t.compose(&s.mount);
            let scan = laser.scan(&s.scan, &pose, cast);
            let reported = match odometry.as_mut() {
                Some(o) => o.report(t),
                None => first.between(t),
            };
            carmen::LogScan {
                scan,
                logged: s.logged,
                odometry: reported,
                mount: s.mount,
            }
        })
        .collect();
    carmen::Log {
        scans,
        ..Default::default()
    }
}

/// Width of the bins of the range residuals' histogram, m, and their number (the last holds
/// everything beyond): 1 cm bins out to 30 cm, past which the residuals are short, random or
/// mixed readings rather than the spread of hits.
pub const RESIDUAL_BIN_M: f64 = 0.01;
pub const RESIDUAL_BINS: usize = 31;

/// Shares of the tally's |range residual| per bin (see [`RESIDUAL_BIN_M`]).
fn residual_histogram(t: &Tally) -> Vec<f64> {
    let mut h = vec![0.0; RESIDUAL_BINS];
    for r in &t.readings {
        let k = ((r.measured - r.expected).abs() / RESIDUAL_BIN_M).floor();
        h[(k.max(0.0) as usize).min(RESIDUAL_BINS - 1)] += 1.0;
    }
    let n = t.readings.len().max(1) as f64;
    h.iter().map(|c| c / n).collect()
}

/// The histograms of the real log's range residuals and the twins' (the median over the
/// seeds, bin by bin), as an SVG chart.
fn residual_chart(real: &Figures, twins: &[Figures]) -> String {
    let centre = |k: usize| (k as f64 + 0.5) * RESIDUAL_BIN_M;
    let series = |name: &str, colour: &'static str, h: Vec<f64>| crate::report::Series {
        name: name.into(),
        colour,
        markers: false,
        // The last bin, everything beyond, is not a bin of the same width: left out.
        points: h[..RESIDUAL_BINS - 1]
            .iter()
            .enumerate()
            .map(|(k, v)| [centre(k), *v])
            .collect(),
    };
    let twin: Vec<f64> = (0..RESIDUAL_BINS)
        .map(|k| median(twins.iter().map(|t| t.residual_histogram[k]).collect()))
        .collect();
    crate::report::line_chart(
        &format!(
            "|range residual| (beyond {:.2} m: real {:.1} %, twin {:.1} %)",
            RESIDUAL_BIN_M * (RESIDUAL_BINS - 1) as f64,
            100.0 * real.residual_histogram[RESIDUAL_BINS - 1],
            100.0 * twin[RESIDUAL_BINS - 1]
        ),
        "|measured − cast| (m)",
        "share of readings per 1 cm",
        &[
            series("real log", "#d7191c", real.residual_histogram.clone()),
            series("twin (median of seeds)", "#2c7bb6", twin),
        ],
    )
}

/// The `q`-quantiles of the range residuals |measured − expected| of a tally, m.
fn residual_quantiles(t: &Tally, qs: &[f64]) -> Vec<f64> {
    let mut r: Vec<f64> = t
        .readings
        .iter()
        .map(|r| (r.measured - r.expected).abs())
        .collect();
    r.sort_by(f64::total_cmp);
    qs.iter()
        .map(|q| {
            r.get(((r.len() as f64 - 1.0) * q).round().max(0.0) as usize)
                .copied()
                .unwrap_or(f64::NAN)
        })
        .collect()
}

/// The figures compared between the real log and a twin.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Figures {
    /// Mean translational relations error, m: the SLAM's and raw odometry's, a twin's against
    /// its truth with the reference's error added ([`relations::with_noise`]), as the real log
    /// is scored against relations that carry it.
    pub slam_relations_m: f64,
    pub odometry_relations_m: f64,
    /// The SLAM's error against the relations as they are: a twin's against its exact truth
    /// (the real log's is `slam_relations_m`).
    pub slam_relations_exact_m: f64,
    /// Relations scored.
    pub relations: usize,
    /// Median and 95th percentile of |range residual|, m.
    pub residual_median_m: f64,
    pub residual_p95_m: f64,
    /// Shares of |range residual| in bins of [`RESIDUAL_BIN_M`] from 0, the last bin holding
    /// every residual beyond.
    pub residual_histogram: Vec<f64>,
    /// The correlation of neighbouring beams' residuals on one surface (see
    /// [`LaserProfile::neighbour_correlation`]).
    pub residual_neighbour_correlation: f64,
    /// The odometry's random walk as `calibrate` measures it: m²/m, rad²/rad, rad²/m.
    pub translation_variance: f64,
    pub heading_variance_per_rad: f64,
    pub heading_variance_per_m: f64,
}

/// The relations a log is scored on: as the reference measured them, and exact (a twin's
/// truth; the real log's are the same).
type Scored<'a> = (&'a [Relation], &'a [Relation]);

/// Scores a measured log: its SLAM path and odometry against `rels`, its range residuals
/// over the scans within `[from, to]`.
fn figures(log: &carmen::Log, m: &Measured, rels: Scored, from: Time, to: Time) -> Figures {
    let slam = as_logged(&m.path, log);
    let mut odometry = crate::replay::odometry_path(log);
    odometry.sort_by_key(|p| p.0);
    let s = relations::evaluate(&slam, rels.0);
    let o = relations::evaluate(&odometry, rels.0);
    let tally = calibrate::tally_within(log, m, from, to);
    let q = residual_quantiles(&tally, &[0.5, 0.95]);
    let odo = m.odometry.as_ref();
    let v = |f: &dyn Fn(&futago_msgs::profile::OdometryProfile) -> f64| odo.map_or(f64::NAN, f);
    Figures {
        slam_relations_m: s.abs_trans_m.mean,
        odometry_relations_m: o.abs_trans_m.mean,
        slam_relations_exact_m: relations::evaluate(&slam, rels.1).abs_trans_m.mean,
        relations: s.relations,
        residual_median_m: q[0],
        residual_p95_m: q[1],
        residual_histogram: residual_histogram(&tally),
        residual_neighbour_correlation: calibrate::laser::pair_correlation(&tally.neighbours).value,
        translation_variance: v(&|p| p.translation_variance.value),
        heading_variance_per_rad: v(&|p| p.heading_variance_per_rad.value),
        heading_variance_per_m: v(&|p| p.heading_variance_per_m.value),
    }
}

/// The median of `v`'s finite values (NaN when there are none).
fn median(mut v: Vec<f64>) -> f64 {
    v.retain(|x| x.is_finite());
    crate::ground_truth::trajectory::Stats::percentile(&v, 50.0).unwrap_or(f64::NAN)
}

/// The relations of `rels` within `[from, to]`, and the same stamp pairs measured on `truth`
/// (sorted by stamp) for the twin.
fn scored_relations(
    rels: &[Relation],
    truth: &[(Time, Pose2)],
    from: Time,
    to: Time,
) -> (Vec<Relation>, Vec<Relation>) {
    let real: Vec<Relation> = rels
        .iter()
        .filter(|r| r.t1 >= from && r.t2 <= to && r.t1 <= r.t2)
        .copied()
        .collect();
    let twin = real
        .iter()
        .filter_map(|r| {
            let a = relations::interpolate(truth, r.t1)?;
            let b = relations::interpolate(truth, r.t2)?;
            Some(Relation {
                t1: r.t1,
                t2: r.t2,
                delta: a.between(&b),
            })
        })
        .collect();
    (real, twin)
}

/// Runs the twin of the log at `log_path` with the profile at `profile_path`, scores both on
/// the relations at `relations_path`, and writes `summary.json`, `twin.md`, the world under
/// `world/` and the first seed's log as `twin.clf` into `out`, whole or not at all.
pub fn twin(
    log_path: &Path,
    profile_path: &Path,
    relations_path: &Path,
    config: SlamConfig,
    out: &Path,
    o: &TwinOptions,
) -> Result<Value> {
    crate::output::check_folder(out, o.force)?;
    if o.seeds == 0 {
        bail!("--seeds: expected at least 1, found 0");
    }
    let profile: RobotProfile = futago_sim::config::load_toml(profile_path)?;
    if let Err((key, expected)) = profile.validate() {
        bail!("{}: `{key}`: {expected}", profile_path.display());
    }
    let rels = relations::parse(
        &std::fs::read_to_string(relations_path)
            .with_context(|| format!("reading {}", relations_path.display()))?,
        &relations_path.display().to_string(),
    )?;
    let candidates = match &o.rank {
        Some(p) => rank::load(p, config)?,
        None => Vec::new(),
    };
    let full = read_log_with(log_path, &o.read)?;
    if full.scans.is_empty() {
        bail!("{}: the log holds no laser scans", log_path.display());
    }
    let options = calibrate::CalibrateOptions {
        read: o.read.clone(),
        span: [0.0, 1.0],
        laser: Some(profile.laser.name.clone()),
        force: o.force,
    };
    let real = calibrate::chosen_scans(&full, log_path, &options)?;
    let started = std::time::Instant::now();
    let measured_real = calibrate::measure(&real, config)
        .map_err(|e| anyhow::anyhow!("{}: {e}", log_path.display()))?;
    let truth: Vec<Pose2> = measured_real.path.iter().map(|(_, p)| *p).collect();
    let truth_logged = as_logged(&measured_real.path, &real);
    let first = real.scans[0].logged;
    let last = real.scans[real.scans.len() - 1].logged;
    let at = |f: f64| Time(first.0 + Time::from_secs(f * (last - first).secs()).0);
    let (real_rels, twin_rels) = scored_relations(
        &rels,
        &truth_logged,
        at(o.score_span[0]),
        at(o.score_span[1]),
    );
    if real_rels.is_empty() {
        bail!(
            "{}: no relation falls within the scored span {:?} of the log",
            relations_path.display(),
            o.score_span
        );
    }
    // The scored stretch by the scans' own stamps, for the range residuals.
    let (s0, s1) = (
        real.scans[0].scan.stamp,
        real.scans[real.scans.len() - 1].scan.stamp,
    );
    let scan_at = |f: f64| Time(s0.0 + Time::from_secs(f * (s1 - s0).secs()).0);
    let (score_from, score_to) = (scan_at(o.score_span[0]), scan_at(o.score_span[1]));
    let real_figures = figures(
        &real,
        &measured_real,
        (&real_rels, &real_rels),
        score_from,
        score_to,
    );
    // The reference's own error, from every cycle of the file (it is the reference's, not the
    // robot's: no part of the log is fitted by it), and each seed's relations as a reference
    // with that error would have measured its truth.
    let reference = relations::reference_noise(&rels);
    let seed_rels: Vec<Vec<Relation>> = (0..o.seeds)
        .map(|seed| {
            relations::with_noise(&twin_rels, &reference, &mut stream(seed, "twin.reference"))
        })
        .collect();
    write_atomically(out, o.force, "twin", |tmp| {
        let sim = twin_world(&tmp.join("world"), &measured_real)?;
        let setup = Setup {
            real: &real,
            truth: &truth,
            sim: &sim,
            config,
        };
        let fitted = fit(&setup, &profile, (&twin_rels, score_from, score_to))?;
        let (twins, first_log, simulated) = run_seeds(
            &setup,
            &fitted,
            o,
            (&seed_rels, &twin_rels),
            (score_from, score_to),
        )?;
        let ranking = (!candidates.is_empty()).then(|| {
            rank::rank(&candidates, &real, &real_rels, &seed_rels, o.jobs, |seed| {
                seed_log(&setup, &fitted, seed)
            })
        });
        let duration = (last - first).secs();
        let wall = started.elapsed().as_secs_f64();
        let summary = json!({
            "log": log_path.display().to_string(),
            "profile": o.profile_as.as_deref().unwrap_or(profile_path).display().to_string(),
            "relations": relations_path.display().to_string(),
            "score_span": o.score_span,
            "seeds": o.seeds,
            "reference_noise": reference,
            // The twin's SLAM against its exact truth, the median over the seeds.
            "slam_relations_exact_m": median(twins.iter().map(|t| t.slam_relations_exact_m).collect()),
            "real": real_figures,
            "twins": twins,
            "uncalibrated": fitted.before,
            "compared": compared(&real_figures, &twins, &fitted.before),
            "laser_model": fitted.laser,
            "odometry_model": fitted.odometry,
            "floor": fitted.floor,
            "fit": fitted.rounds,
            "ranking": ranking,
            "performance": {
                "wall_time_s": wall,
                "log_duration_s": duration,
                // Casting the laser and making the odometry of one twin log, the stack's
                // runs apart: its speed against the log's duration.
                "simulation_s": simulated,
                "simulation_real_time_factor": duration / median(simulated.clone()).max(1e-9),
            },
        });
        write_report(
            tmp,
            &Report {
                summary: &summary,
                real: &real_figures,
                twins: &twins,
                ranking: ranking.as_ref(),
                rank_file: o.rank.as_deref(),
                first: first_log.as_ref(),
                real_map: &measured_real.map.to_grid(),
                truth: &truth,
            },
        )?;
        Ok(summary)
    })
}

/// What a twin writes beside its summary.
struct Report<'a> {
    summary: &'a Value,
    real: &'a Figures,
    twins: &'a [Figures],
    ranking: Option<&'a rank::Ranking>,
    rank_file: Option<&'a Path>,
    first: Option<&'a FirstSeed>,
    real_map: &'a OccupancyGrid,
    truth: &'a [Pose2],
}

/// Writes `summary.json`, `twin.md` (the side-by-side table, the pictures and the ranking),
/// `residuals.svg`, `maps.png` and the first seed's `twin.clf` into `tmp`.
fn write_report(tmp: &Path, r: &Report) -> Result<()> {
    std::fs::write(
        tmp.join("summary.json"),
        serde_json::to_string_pretty(r.summary)? + "\n",
    )
    .context("writing summary.json")?;
    std::fs::write(tmp.join("residuals.svg"), residual_chart(r.real, r.twins))
        .context("writing residuals.svg")?;
    let mut md = table(r.summary);
    md += "\n![The real log's SLAM map (red), the first twin's (blue), where both hold a wall (black)](maps.png)\n\n![Histograms of |range residual|, real and twin](residuals.svg)\n";
    if let Some(ranking) = r.ranking {
        md += &format!(
            "\n## SLAM configurations ranked ({})\n\n{}",
            r.rank_file
                .map_or(String::new(), |p| p.display().to_string()),
            rank::table(ranking)
        );
    }
    std::fs::write(tmp.join("twin.md"), md).context("writing twin.md")?;
    if let Some((log, map)) = r.first {
        std::fs::write(
            tmp.join("maps.png"),
            crate::picture::overlay_png(r.real_map, map, 1),
        )
        .context("writing maps.png")?;
        std::fs::write(tmp.join("twin.clf"), clf(log, r.truth)).context("writing twin.clf")?;
    }
    Ok(())
}

/// What every twin run shares: the real log, the twin's truth (a pose per scan), the world's
/// simulation and the SLAM's configuration.
struct Setup<'a> {
    real: &'a carmen::Log,
    truth: &'a [Pose2],
    sim: &'a futago_sim::Simulation,
    config: SlamConfig,
}

/// The twin's models as fitted, with the floor and each round's figures.
struct Fitted {
    laser: LaserModel,
    odometry: Option<futago_msgs::profile::OdometryProfile>,
    floor: LaserProfile,
    /// The figures of the twin before calibration: a perfect laser and odometry.
    before: Figures,
    rounds: Vec<Value>,
}

/// The world of the twin, written into `dir`: the real log's SLAM map made a world
/// (`world from-map`, unknown cells free, no ceiling), ready for ray casts.
fn twin_world(dir: &Path, measured: &Measured) -> Result<futago_sim::Simulation> {
    std::fs::create_dir(dir).context("creating world/")?;
    let grid = crate::world_cmd::known_part(&measured.map.to_grid())
        .context("the SLAM map of the log holds no known cell")?;
    grid.write_map_server(dir, "slam")
        .context("writing the SLAM map")?;
    let world = crate::world_cmd::from_map(
        &dir.join("slam.yaml"),
        &dir.join("twin.toml"),
        &crate::world_cmd::FromMapOptions {
            name: Some("twin".into()),
            height: 2.5,
            unknown: futago_sim::world::floor_plan::UnknownCells::Free,
            spawn: None,
            ceiling: false,
        },
        false,
    )?;
    let mut sim = futago_sim::Simulation::new(
        &world,
        &futago_sim::PhysicsConfig::default(),
        &futago_sim::create::CreateConfig::default(),
        &[],
        &futago_sim::Movers::default(),
        world.spawns.first().map_or(Pose2::IDENTITY, |s| s.1),
        0,
    );
    // rapier builds the structure ray casts use in the first step.
    sim.step(None);
    Ok(sim)
}

/// The floor (whose figures over the scored relations are the uncalibrated twin's), then
/// [`FIT_ROUNDS`] of fitting the laser through the measurement on the profile's own stretch
/// of the log.
fn fit(
    setup: &Setup,
    profile: &RobotProfile,
    (rels, score_from, score_to): (&[Relation], Time, Time),
) -> Result<Fitted> {
    let floor_log = twin_log(setup.real, setup.truth, setup.sim, None, None);
    let floor = calibrate::measure(&floor_log, setup.config)
        .map_err(|e| anyhow::anyhow!("the perfect twin: {e}"))?;
    let (sigma, sigma_rel, errors) = laser_model(&profile.laser, &floor.laser);
    let mut laser = LaserModel {
        sigma,
        sigma_rel,
        errors,
    };
    // The odometry's estimates already leave the reference's own error out (the regression's
    // intercept): they are used as they are. Fitting them through the measurement as the
    // laser is fitted diverged on short logs, where the random walk's terms are least
    // certain.
    let odometry = profile.odometry.clone();
    // Like is compared with like: the profile's own stretch, and one stream for every round
    // (common random numbers).
    let start = setup.real.scans[0].scan.stamp;
    let from = Time(start.0 + Time::from_secs(profile.source.from_s).0);
    let to = Time(start.0 + Time::from_secs(profile.source.to_s).0);
    let mut rounds = Vec::new();
    for round in 0..FIT_ROUNDS {
        let twin_laser = TwinLaser::new(
            laser.sigma,
            laser.sigma_rel,
            laser.errors.clone(),
            stream(u64::MAX, "twin.fit.laser"),
        );
        let twin_odometry = odometry
            .clone()
            .map(|p| TwinOdometry::new(p, stream(u64::MAX, "twin.fit.odometry")));
        let log = twin_log(
            setup.real,
            setup.truth,
            setup.sim,
            Some(twin_laser),
            twin_odometry,
        );
        let m = calibrate::measure(&calibrate::within(&log, from, to), setup.config)
            .map_err(|e| anyhow::anyhow!("fitting the twin, round {round}: {e}"))?;
        rounds.push(json!({ "round": round, "model": laser, "measured": m.laser }));
        refit_laser(&mut laser, &profile.laser, &m.laser);
    }
    Ok(Fitted {
        laser,
        odometry,
        // A simulator's presets score against the exact truth: they model no reference.
        before: figures(&floor_log, &floor, (rels, rels), score_from, score_to),
        floor: floor.laser,
        rounds,
    })
}

/// The twin log of `seed` with the fitted models.
fn seed_log(setup: &Setup, fitted: &Fitted, seed: u64) -> carmen::Log {
    let laser = TwinLaser::new(
        fitted.laser.sigma,
        fitted.laser.sigma_rel,
        fitted.laser.errors.clone(),
        stream(seed, "twin.laser"),
    );
    let odometry = fitted
        .odometry
        .clone()
        .map(|p| TwinOdometry::new(p, stream(seed, "twin.odometry")));
    twin_log(setup.real, setup.truth, setup.sim, Some(laser), odometry)
}

/// A seed's twin log and the map its SLAM made.
type FirstSeed = (carmen::Log, OccupancyGrid);
/// A seed's figures, log, map and the wall time its log took to simulate, s.
type SeedRun = (Figures, carmen::Log, OccupancyGrid, f64);

/// One twin per seed, `o.jobs` at a time: each seed's figures, the first seed's log and SLAM map, and the
/// wall time each took to simulate its log (the stack's runs apart), s.
fn run_seeds(
    setup: &Setup,
    fitted: &Fitted,
    o: &TwinOptions,
    (seed_rels, exact): (&[Vec<Relation>], &[Relation]),
    (from, to): (Time, Time),
) -> Result<(Vec<Figures>, Option<FirstSeed>, Vec<f64>)> {
    let run_seed = |seed: u64| -> Result<SeedRun> {
        let clock = std::time::Instant::now();
        let log = seed_log(setup, fitted, seed);
        let simulated = clock.elapsed().as_secs_f64();
        let m = calibrate::measure(&log, setup.config)
            .map_err(|e| anyhow::anyhow!("the twin of seed {seed}: {e}"))?;
        let f = figures(&log, &m, (&seed_rels[seed as usize], exact), from, to);
        Ok((f, log, m.map.to_grid(), simulated))
    };
    let seeds: Vec<u64> = (0..o.seeds).collect();
    let per = seeds.len().div_ceil(o.jobs.max(1));
    let mut results: Vec<Option<Result<SeedRun>>> = (0..seeds.len()).map(|_| None).collect();
    std::thread::scope(|scope| {
        for (chunk, slots) in seeds.chunks(per).zip(results.chunks_mut(per)) {
            let run_seed = &run_seed;
            scope.spawn(move || {
                for (s, slot) in chunk.iter().zip(slots) {
                    *slot = Some(run_seed(*s));
                }
            });
        }
    });
    let mut twins = Vec::new();
    let mut first = None;
    let mut simulated = Vec::new();
    for r in results {
        let (f, log, map, s) = r.expect("every seed ran")?;
        twins.push(f);
        simulated.push(s);
        if first.is_none() {
            first = Some((log, map));
        }
    }
    Ok((twins, first, simulated))
}

/// A figure of [`Figures`], by name.
type Figure = (&'static str, fn(&Figures) -> f64);

/// The figures compared, in the table's order.
const COMPARED: [Figure; 8] = [
    ("slam_relations_m", |f| f.slam_relations_m),
    ("odometry_relations_m", |f| f.odometry_relations_m),
    ("residual_median_m", |f| f.residual_median_m),
    ("residual_p95_m", |f| f.residual_p95_m),
    ("residual_neighbour_correlation", |f| {
        f.residual_neighbour_correlation
    }),
    ("translation_variance", |f| f.translation_variance),
    ("heading_variance_per_rad", |f| f.heading_variance_per_rad),
    ("heading_variance_per_m", |f| f.heading_variance_per_m),
];

/// Real beside twin (the median over the seeds) and their ratio (the median of the seeds'
/// ratios), and beside the uncalibrated twin `before`, for each compared figure.
fn compared(real: &Figures, twins: &[Figures], before: &Figures) -> Vec<Value> {
    COMPARED
        .iter()
        .map(|(name, f)| {
            json!({
                "figure": name,
                "real": f(real),
                "twin_median": median(twins.iter().map(f).collect()),
                "ratio_median": median(twins.iter().map(|t| f(t) / f(real)).collect()),
                "uncalibrated": f(before),
                "uncalibrated_ratio": f(before) / f(real),
            })
        })
        .collect()
}

/// The side-by-side table of a twin's summary, Markdown.
pub fn table(summary: &Value) -> String {
    let mut s = format!(
        "# Twin of {}\n\nProfile {}; relations {} within {}–{} of the log's duration; {} seeds (the twin column is their median). Uncalibrated: the twin with a perfect laser and odometry, as a simulator's presets come close to.\n\n| figure | real | twin | twin / real | uncalibrated | uncalibrated / real |\n|---|---|---|---|---|---|\n",
        summary["log"].as_str().unwrap_or(""),
        summary["profile"].as_str().unwrap_or(""),
        summary["relations"].as_str().unwrap_or(""),
        summary["score_span"][0],
        summary["score_span"][1],
        summary["seeds"]
    );
    for row in summary["compared"].as_array().into_iter().flatten() {
        let f = |k: &str| row[k].as_f64().map_or("–".into(), |v| format!("{v:.4}"));
        s += &format!(
            "| {} | {} | {} | {} | {} | {} |\n",
            row["figure"].as_str().unwrap_or(""),
            f("real"),
            f("twin_median"),
            f("ratio_median"),
            f("uncalibrated"),
            f("uncalibrated_ratio")
        );
    }
    if let Ok(n) =
        serde_json::from_value::<relations::ReferenceNoise>(summary["reference_noise"].clone())
    {
        let exact = summary["slam_relations_exact_m"]
            .as_f64()
            .unwrap_or(f64::NAN);
        let mut line = relations::describe(&n);
        line[..1].make_ascii_uppercase();
        s += &if n.mean_error_m > 0.0 {
            format!(
                "\n{line}. Each twin seed is scored against its truth with that error drawn in; against the exact truth its SLAM's error is {exact:.4} m (the median over the seeds).\n"
            )
        } else {
            format!("\n{line}; the twin is scored against its exact truth.\n")
        };
    }
    s
}

/// A twin log as CARMEN: `ROBOTLASER1` with the odometry at each scan, and `TRUEPOS`, the
/// twin's truth beside it.
fn clf(log: &carmen::Log, truth: &[Pose2]) -> String {
    let mut out = String::new();
    carmen::param(&mut out, "robot_frontlaser_offset", "0.0");
    for (s, t) in log.scans.iter().zip(truth) {
        let laser = s.odometry.compose(&s.mount);
        carmen::robotlaser(&mut out, 1, &s.scan, 0.01, &laser, &s.odometry, 0.0, 0.0);
        carmen::truepos(&mut out, s.scan.stamp.secs(), t, &s.odometry);
    }
    out
}

/// Prints the side-by-side table.
pub fn print(summary: &Value, out: &Path) {
    print!("{}", table(summary));
    println!("→ {}", out.display());
}

#[cfg(test)]
mod tests {
    use super::*;
    use futago_msgs::profile::{Bin, Estimate};

    fn laser(sigma: f64, short: f64, mixed: f64, no_return: &[(f64, f64, f64)]) -> LaserProfile {
        let e = |v| Estimate::new(v, 0.0, 1000);
        LaserProfile {
            name: "laser".into(),
            beams: 180,
            angle_min: -1.5,
            angle_increment: 0.017,
            range_min: 0.0,
            range_max: 30.0,
            rate: 5.0,
            period_spread_s: 0.0,
            time_increment: 0.0,
            sigma: e(sigma),
            sigma_rel: e(0.0),
            bias: e(0.0),
            short_rate: e(short),
            short_lambda: e(1.0),
            random_rate: e(0.0),
            long_readings: e(0.0),
            no_return: e(0.0),
            no_return_by_range: no_return
                .iter()
                .map(|&(lo, hi, value)| Bin {
                    lo,
                    hi,
                    value,
                    sd: 0.0,
                    n: 1000,
                })
                .collect(),
            no_return_by_incidence: Vec::new(),
            long_excess_m: Vec::new(),
            mixed_pixels: e(mixed),
            unmapped_returns: e(0.0),
            neighbour_correlation: e(0.0),
            spread_by_range: [(1.0, 2.0), (4.0, 6.0)]
                .iter()
                .map(|&(lo, hi)| Bin {
                    lo,
                    hi,
                    value: sigma,
                    sd: 0.0,
                    n: 1000,
                })
                .collect(),
        }
    }

    #[test]
    fn the_floor_comes_off_as_variances_and_independent_shares() {
        // Real 5 cm over a floor of 3 cm leaves 4 cm; a 20 % no-return over a floor of 10 %
        // leaves 1 − 0.8/0.9 = 1/9; short readings subtract.
        let real = laser(0.05, 0.10, 0.40, &[(2.0, 3.0, 0.2)]);
        let floor = laser(0.03, 0.02, 0.25, &[(2.0, 3.0, 0.1)]);
        let (sigma, _, e) = laser_model(&real, &floor);
        assert!((sigma - 0.04).abs() < 1e-12, "{sigma}");
        assert!((e.short_rate - 0.08).abs() < 1e-12);
        assert!((e.no_return_by_range[0].p - 1.0 / 9.0).abs() < 1e-12);
        assert!((e.mixed_pixels - 0.2).abs() < 1e-12);
        assert!(e.quadrature);
    }

    #[test]
    fn a_refit_round_moves_each_term_towards_the_real_log() {
        let real = laser(0.05, 0.10, 0.30, &[(2.0, 3.0, 0.2)]);
        let twin = laser(0.03, 0.20, 0.10, &[(2.0, 3.0, 0.1)]);
        let mut m = LaserModel {
            sigma: 0.02,
            sigma_rel: 0.0,
            errors: BeamErrors {
                short_rate: 0.1,
                mixed_pixels: 0.1,
                no_return_by_range: vec![RangeProbability {
                    lo: 2.0,
                    hi: 3.0,
                    p: 0.1,
                }],
                ..BeamErrors::default()
            },
        };
        refit_laser(&mut m, &real, &twin);
        // Each bin's variance moves from 0.02² by 0.05² − 0.03², and so does the fit.
        assert!(
            (m.sigma - (0.0004f64 + 0.0025 - 0.0009).sqrt()).abs() < 1e-9,
            "{m:?}"
        );
        assert!(
            (m.errors.short_rate - 0.05).abs() < 1e-12,
            "half of −0.1: {m:?}"
        );
        assert!((m.errors.mixed_pixels - 0.2).abs() < 1e-12, "{m:?}");
        assert!(
            (m.errors.no_return_by_range[0].p - 0.15).abs() < 1e-12,
            "{m:?}"
        );
    }

    #[test]
    fn a_variance_line_recovers_its_terms() {
        let rows: Vec<(f64, f64, f64)> = [1.0, 3.0, 5.0, 10.0]
            .iter()
            .map(|&r| (r, 0.02f64.powi(2) + (0.004f64 * r).powi(2), 100.0))
            .collect();
        let (a2, b2) = variance_line(&rows).unwrap();
        assert!((a2.sqrt() - 0.02).abs() < 1e-9 && (b2.sqrt() - 0.004).abs() < 1e-9);
    }
}
