//! `futago replay`: the robot stack's SLAM on a real robot's log, scored against ground-truth
//! relations when given; and, on a log with annotated people (`leg_tracker/Person`), its people
//! tracking scored by CLEAR-MOT as the leg_tracker benchmark scores it.

use crate::ground_truth::mot::MOT_GATE;
use crate::relations::{self, Metrics};
use crate::run::write_atomically;
use anyhow::{Context, Result, bail};
use futago_msgs::{Pose2, Pose3, Time, carmen, tum};
use futago_robot::mapping::slam::{Slam, SlamConfig, SlamMethod};
use serde_json::{Value, json};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Reads a log by its extension: CARMEN (`.clf`, `.log`, `.carmen`), ROS 1 bag (`.bag`), or
/// ROS 2 bag (a rosbag2 folder with its `metadata.yaml`, an `.mcap` file, or a `.db3` file in
/// its folder), with the reader's options: salvage of a damaged log unless `o.strict`, and the
/// bag's topics.
pub fn read_log_with(path: &Path, o: &carmen::ReadOptions) -> Result<carmen::Log> {
    if path.is_dir() {
        return futago_msgs::rosbag2::read_folder(path, o).map_err(anyhow::Error::msg);
    }
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    match ext.as_str() {
        "clf" | "log" | "carmen" => {
            let bytes =
                std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
            if o.scan_topic.is_some() || o.odom_topic.is_some() {
                bail!(
                    "{}: --scan-topic and --odom-topic choose a bag's topics; a CARMEN log has none",
                    path.display()
                );
            }
            let text = match String::from_utf8(bytes) {
                Ok(t) => t,
                // Salvaging, the lines with bad bytes fail to parse and are skipped.
                Err(e) if !o.strict => String::from_utf8_lossy(e.as_bytes()).into_owned(),
                Err(e) => bail!(
                    "{}: not a text CARMEN log (invalid UTF-8 at byte {})",
                    path.display(),
                    e.utf8_error().valid_up_to()
                ),
            };
            carmen::read_with(&text, o).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
        }
        "bag" => {
            let bytes =
                std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
            futago_msgs::rosbag::read_with(&bytes, o)
                .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
        }
        "mcap" | "db3" => futago_msgs::rosbag2::read_path(path, o).map_err(anyhow::Error::msg),
        _ => bail!(
            "{}: unknown log format `.{ext}`; expected a CARMEN log (.clf, .log, .carmen), a ROS 1 bag (.bag), or a ROS 2 bag (a rosbag2 folder, .mcap, .db3)",
            path.display()
        ),
    }
}

pub(crate) fn write_tum(path: &Path, header: &str, traj: &[(Time, Pose2)]) -> Result<()> {
    let mut text = format!("{header}\n# timestamp tx ty tz qx qy qz qw\n");
    for (t, p) in traj {
        tum::format_line(
            &mut text,
            &tum::Stamped {
                stamp: *t,
                pose: Pose3::from_pose2(p, 0.0),
            },
        );
    }
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}

fn metrics_json(m: &Metrics) -> Value {
    serde_json::to_value(m).unwrap_or(Value::Null)
}

fn method_name(m: SlamMethod) -> &'static str {
    match m {
        SlamMethod::Icp => "icp",
        SlamMethod::Graph => "graph",
    }
}

/// What `futago replay` is asked besides the log.
#[derive(Debug, Clone, Default)]
pub struct ReplayOptions {
    /// How the log is read (salvage or strict, the bag's topics).
    pub read: carmen::ReadOptions,
    /// Replace the output folder even when it holds files futago did not write.
    pub force: bool,
    /// The leg classifier that people tracking uses (a `futago train-legs` model file);
    /// `None`: the shipped `models/legs.json`. Scoring a model trained in simulation on a
    /// real annotated log is how its transfer is measured.
    pub legs_model: Option<PathBuf>,
}

/// What a log held and lost, for the summary: messages by topic, the stamps read, the damage.
fn read_summary(log: &carmen::Log) -> Value {
    let stamps = log.scans.iter().map(|s| s.logged.secs());
    json!({
        "messages": log.messages,
        "scan_topic": log.scan_topic,
        "odom_topic": log.odom_topic,
        "odometry": if log.odometry_absent { "absent: the robot's motion is the SLAM front end's scan matching" } else { "read" },
        "first_stamp_s": stamps.clone().reduce(f64::min),
        "last_stamp_s": stamps.reduce(f64::max),
        "damaged": !log.damage.is_empty(),
        "damage": log.damage,
    })
}

/// One line on what a damaged log lost, or `None` for an intact one.
fn damage_line(log: &Value) -> Option<String> {
    let d = &log["damage"];
    if log["damaged"] != true {
        return None;
    }
    let gaps: Vec<String> = d["losses"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|l| {
            let (a, b) = (
                l["last_stamp_before_s"].as_f64(),
                l["first_stamp_after_s"].as_f64(),
            );
            match (a, b) {
                (Some(a), Some(b)) => Some(format!("{a:.3}–{b:.3} s")),
                (Some(a), None) => Some(format!("after {a:.3} s")),
                (None, Some(b)) => Some(format!("before {b:.3} s")),
                (None, None) => None,
            }
        })
        .collect();
    let read: Vec<String> = log["messages"]
        .as_object()
        .into_iter()
        .flatten()
        .map(|(topic, n)| format!("{n} {topic}"))
        .collect();
    Some(format!(
        "damaged log: read {}; {} bytes lost in {} part{}{}{}; read up to {:.3} s{}",
        read.join(", "),
        d["bytes_lost"],
        d["parts_skipped"],
        if d["parts_skipped"] == 1 { "" } else { "s" },
        if d["truncated"] == true {
            ", cut short"
        } else {
            ""
        },
        match d["messages_salvaged_from_cut_chunk"].as_u64() {
            Some(n) if n > 0 => format!(" ({n} messages recovered from the cut chunk)"),
            _ => String::new(),
        },
        log["last_stamp_s"].as_f64().unwrap_or(f64::NAN),
        if gaps.is_empty() {
            String::new()
        } else {
            format!("; gaps: {}", gaps.join(", "))
        }
    ))
}

/// Prints what a replay did: the scans and the speed, the topics read, a missing odometry, the
/// damage (on stderr), and the relations metrics of SLAM and odometry when scored.
pub fn print(s: &Value, log: &Path, out: &Path) {
    let line = |k: &str| -> String {
        let m = &s["relations"][k];
        let spans = s["relations"]["by_span"]
            .as_array()
            .map(|groups| {
                groups
                    .iter()
                    .filter(|g| g[k]["relations"].as_u64().unwrap_or(0) > 0)
                    .map(|g| {
                        format!(
                            "{} {:.4}",
                            g["span"].as_str().unwrap_or("?"),
                            g[k]["abs_trans_m"]["mean"].as_f64().unwrap_or(f64::NAN)
                        )
                    })
                    .collect::<Vec<_>>()
                    .join(", ")
            })
            .unwrap_or_default();
        format!(
            "{k:>9}: abs trans {:.4} ± {:.4} m, abs rot {:.3} ± {:.3}° over {} relations (by span: {spans} m)",
            m["abs_trans_m"]["mean"].as_f64().unwrap_or(f64::NAN),
            m["abs_trans_m"]["std"].as_f64().unwrap_or(f64::NAN),
            m["abs_rot_deg"]["mean"].as_f64().unwrap_or(f64::NAN),
            m["abs_rot_deg"]["std"].as_f64().unwrap_or(f64::NAN),
            m["relations"]
        )
    };
    println!(
        "{}: {} scans over {:.0} s in {:.2} s ({:.0}× real time); results in {}",
        log.display(),
        s["scans"],
        s["log_duration_s"].as_f64().unwrap_or(0.0),
        s["performance"]["wall_time_s"].as_f64().unwrap_or(0.0),
        s["performance"]["real_time_factor"].as_f64().unwrap_or(0.0),
        out.display()
    );
    let read = &s["read"];
    let topics: Vec<String> = [("scans", "scan_topic"), ("odometry", "odom_topic")]
        .iter()
        .filter_map(|(what, k)| read[k].as_str().map(|t| format!("{what} from {t}")))
        .collect();
    if !topics.is_empty() {
        println!("read {}", topics.join(", "));
    }
    if read["odometry"] != "read" {
        println!("no odometry in the log: the robot's motion is the SLAM's scan matching");
    }
    if let Some(line) = damage_line(read) {
        eprintln!("futago: {line}");
    }
    if s.get("relations").is_some() {
        println!("{}\n{}", line("slam"), line("odometry"));
        if let Ok(n) = serde_json::from_value::<relations::ReferenceNoise>(
            s["relations"]["reference_noise"].clone(),
        ) {
            println!("{}", relations::describe(&n));
        }
    }
    if let Some(p) = s.get("people") {
        let f = |v: &Value| v.as_f64().unwrap_or(f64::NAN);
        let part = |t: &Value, d: &Value| {
            format!(
                "MOTA {:.3}, MOTP {:.3} m, legs AP@0.5 {:.3} over {} scans",
                f(&t["mota"]),
                f(&t["motp_m"]),
                f(&d["legs"]["by_radius_m"]["0.5"]["ap"]),
                t["frames"]
            )
        };
        let h = &p["annotated_halves"];
        println!(
            "people, annotated scans: {}\n  first half: {}\n  second half: {}",
            part(&p["annotated_frames"], &p["detection_on_annotated_frames"]),
            part(&h["first"]["tracking"], &h["first"]["detection"]),
            part(&h["second"]["tracking"], &h["second"]["detection"])
        );
    }
    let p = &s["loop_closure_precision"];
    if let Some(n) = p["constraints"].as_u64().filter(|n| *n > 0) {
        println!(
            "loop closures: {n} in the final graph, {} held within {LOOP_TRUE_M} m and {LOOP_TRUE_DEG}° (precision {:.1} %; {} removed as outliers, {:.1} % of all found held)",
            p["held"],
            100.0 * p["precision"].as_f64().unwrap_or(f64::NAN),
            p["removed_as_outliers"],
            100.0 * p["precision_of_all_found"].as_f64().unwrap_or(f64::NAN)
        );
    }
}

/// The people tracked in a replay: their scores in the summary's `people`, and their tracks
/// written as `people_tracks.txt` into `tmp`.
fn write_people(
    people: &PeopleReplay,
    log: &carmen::Log,
    log_path: &Path,
    summary: &mut Value,
    tmp: &Path,
) -> Result<()> {
    let PeopleReplay {
        mot,
        detection,
        halves,
        leg_scans,
        tracks,
    } = people;
    summary["people"] = json!({
        "annotations": log.people.len(),
        "gate_m": MOT_GATE,
        "all_frames": mot[0].summary(),
        "annotated_frames": mot[1].summary(),
        "detection_on_annotated_frames": detection,
        "annotated_halves": halves,
        "leg_scans": leg_scans,
    });
    let mut text = format!(
        "# people tracked by futago on {}: timestamp id x y ({} frame, m)\n",
        log_path.display(),
        if log.odometry_absent {
            "the SLAM map's"
        } else {
            "odometry"
        }
    );
    for (t, id, p) in tracks {
        text += &format!("{:.6} {id} {:.4} {:.4}\n", t.secs(), p[0], p[1]);
    }
    std::fs::write(tmp.join("people_tracks.txt"), text).context("writing people_tracks.txt")?;
    Ok(())
}

/// The SLAM over every scan of `log`, finished (the end-of-log search and optimisation done).
pub fn slam_over(log: &carmen::Log, config: SlamConfig) -> Slam {
    let mut slam = Slam::new(config, Pose2::IDENTITY);
    for s in &log.scans {
        slam.update(&s.scan, &s.odometry, &s.mount);
    }
    slam.finish();
    slam
}

/// The log's raw odometry at each scan, under the stamp the log gave the scan, relative to the
/// first scan's (the frame the SLAM starts in), in the order the scans were taken.
pub fn odometry_path(log: &carmen::Log) -> Vec<(Time, Pose2)> {
    let first = log.scans.first().map_or(Pose2::IDENTITY, |s| s.odometry);
    log.scans
        .iter()
        .map(|s| (s.logged, first.between(&s.odometry)))
        .collect()
}

/// A SLAM trajectory (a pose per scan, in the order the scans were taken) with each pose under
/// the stamp the log gave its scan, by which relations name it, sorted by that stamp.
pub fn as_logged(path: &[(Time, Pose2)], log: &carmen::Log) -> Vec<(Time, Pose2)> {
    let mut trajectory: Vec<(Time, Pose2)> = path
        .iter()
        .zip(&log.scans)
        .map(|((_, p), s)| (s.logged, *p))
        .collect();
    trajectory.sort_by_key(|p| p.0);
    trajectory
}

/// A loop closure that the optimised graph violates by more than this (m, degrees) is false,
/// as Hess et al. 2016 count loop-closure precision (Table IV).
pub const LOOP_TRUE_M: f64 = 0.2;
pub const LOOP_TRUE_DEG: f64 = 1.0;

/// The loop closures in the final graph and the share of them that it violates by at most
/// [`LOOP_TRUE_M`] and [`LOOP_TRUE_DEG`] (Cartographer's Table IV convention).
pub fn loop_precision(slam: &Slam) -> Value {
    let loops = slam.loop_residuals();
    let held = loops
        .iter()
        .filter(|l| l.translation <= LOOP_TRUE_M && l.rotation.to_degrees() <= LOOP_TRUE_DEG)
        .count();
    let found = loops.len() + slam.outliers();
    json!({
        "constraints": loops.len(),
        "held": held,
        "precision": if loops.is_empty() { Value::Null } else { json!(held as f64 / loops.len() as f64) },
        // The loop closures removed as outliers at the end count as false too.
        "removed_as_outliers": slam.outliers(),
        "precision_of_all_found": if found == 0 { Value::Null } else { json!(held as f64 / found as f64) },
        "rule": format!("a loop closure violated by more than {LOOP_TRUE_M} m or {LOOP_TRUE_DEG}° after optimisation is false (Hess et al. 2016, Table IV)"),
    })
}

/// Runs the laser SLAM over `log`, writes `trajectory.txt`, `odometry.txt` (TUM),
/// `map.pgm`/`map.yaml` and `summary.json` into `out`, and scores SLAM and raw odometry
/// against `relations` when given. A damaged log gives the results of what it held (unless
/// `o.read.strict`); a log of scans alone is localised by the SLAM's scan matching.
pub fn replay(
    log_path: &Path,
    relations: Option<&Path>,
    config: SlamConfig,
    out: &Path,
    o: &ReplayOptions,
) -> Result<Value> {
    let force = o.force;
    crate::output::check_folder(out, force)?;
    let log = read_log_with(log_path, &o.read)?;
    if log.scans.is_empty() {
        match log.damage.losses.first() {
            Some(first) => bail!(
                "{}: {} ({} damaged parts, {} bytes lost): the log holds no laser scans that could be read",
                log_path.display(),
                first.what,
                log.damage.parts_skipped,
                log.damage.bytes_lost
            ),
            None => bail!("{}: the log holds no laser scans", log_path.display()),
        }
    }
    let rels = match relations {
        Some(p) => Some(relations::parse(
            &std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?,
            &p.display().to_string(),
        )?),
        None => None,
    };
    let started = Instant::now();
    let mut slam = slam_over(&log, config);
    let mut odometry = odometry_path(&log);
    // The trajectory as the map was built: a pose per scan, in the order the scans were taken.
    let path = slam.trajectory();
    let trajectory = as_logged(&path, &log);
    let drawn_odometry = odometry.clone();
    odometry.sort_by_key(|p| p.0);
    // Where the robot was at each scan: its odometry, or without any, the SLAM's estimate
    // (scan matching), a fixed frame all the same for tracking people.
    let robot: Vec<Pose2> = if log.odometry_absent {
        path.iter().map(|(_, p)| *p).collect()
    } else {
        log.scans.iter().map(|s| s.odometry).collect()
    };
    let people = if log.people.is_empty() {
        None
    } else {
        Some(track_people(&log, &robot, o.legs_model.as_deref())?)
    };
    let wall = started.elapsed().as_secs_f64();
    let span = (log.scans[log.scans.len() - 1].scan.stamp - log.scans[0].scan.stamp).secs();
    write_atomically(out, force, "replay", |tmp| {
        write_tum(
            &tmp.join("trajectory.txt"),
            &format!(
                "# futago {} SLAM on {}",
                method_name(config.method),
                log_path.display()
            ),
            &trajectory,
        )?;
        write_tum(
            &tmp.join("odometry.txt"),
            &format!("# odometry of {}, from its first scan", log_path.display()),
            &odometry,
        )?;
        let grid = slam.grid().to_grid();
        grid.write_map_server(tmp, "map")
            .context("writing map.pgm and map.yaml")?;
        let mut summary = json!({
            "log": log_path.display().to_string(),
            "slam": method_name(config.method),
            "loop_closures": slam.loop_closures(),
            "loop_closure_precision": loop_precision(&slam),
            "optimizations": slam.optimizations(),
            "scans": log.scans.len(),
            "odometry_records": log.odometry.len(),
            "skipped": log.skipped,
            "read": read_summary(&log),
            "log_duration_s": span,
            "keyframes": slam.keyframes(),
            "unmatched_scans": slam.unmatched(),
            "skipped_scans": slam.skipped(),
            "config": format!("{config:?}"),
        });
        if let Some(p) = &people {
            write_people(p, &log, log_path, &mut summary, tmp)?;
        }
        if let Some(rels) = &rels {
            let by_span: Vec<Value> = relations::by_span(rels)
                .into_iter()
                .map(|(label, group)| {
                    json!({
                        "span": label,
                        "slam": metrics_json(&relations::evaluate(&trajectory, &group)),
                        "odometry": metrics_json(&relations::evaluate(&odometry, &group)),
                    })
                })
                .collect();
            summary["relations"] = json!({
                "file": relations.map(|p| p.display().to_string()),
                "slam": metrics_json(&relations::evaluate(&trajectory, rels)),
                "odometry": metrics_json(&relations::evaluate(&odometry, rels)),
                "by_span": by_span,
                "reference_noise": relations::reference_noise(rels),
            });
        }
        summary["performance"] = json!({
            "wall_time_s": wall,
            "real_time_factor": if wall > 0.0 { span / wall } else { 0.0 },
        });
        std::fs::write(
            tmp.join("summary.json"),
            serde_json::to_string_pretty(&summary)? + "\n",
        )
        .context("writing summary.json")?;
        // Each relation's error, by the time of its first pose, and the worst placed on the map.
        let mut errors = Vec::new();
        let mut scored = Vec::new();
        for r in rels.iter().flatten() {
            if let Some((e, _)) = relations::error(&trajectory, r) {
                errors.push((r.t1.secs(), e));
                scored.push((r, e));
            }
        }
        scored.sort_by(|a, b| b.1.total_cmp(&a.1));
        let at = |t| relations::interpolate(&trajectory, t).map(|p| [p.x, p.y]);
        let worst: Vec<([f64; 2], [f64; 2], f64)> = scored
            .iter()
            .take(crate::report::WORST_RELATIONS)
            .filter_map(|(r, e)| Some((at(r.t1)?, at(r.t2)?, *e)))
            .collect();
        let html =
            crate::report::replay_report(&summary, &grid, &path, &drawn_odometry, &errors, &worst);
        std::fs::write(tmp.join("report.html"), html).context("writing report.html")?;
        Ok(summary)
    })
}

/// CLEAR-MOT over every scan and over the annotated ones, the detectors' scores on the
/// annotated scans (legs and temporal difference, at each match radius), and every track at
/// every scan (logged stamp, id, position in the odometry frame).
struct PeopleReplay {
    mot: [crate::ground_truth::mot::Mot; 2],
    detection: Value,
    /// The annotated scans' two halves in time, each scored as the whole is.
    halves: Value,
    /// What the annotated scans show of the people ([`crate::ground_truth::leg_scans`]).
    leg_scans: Value,
    tracks: Vec<(Time, u32, [f64; 2])>,
}

/// Marks of one person this far apart in time give their velocity, s: the annotations'
/// jitter (about 5 cm) then moves it by under 0.1 m/s, half the speed below which a person
/// stands.
const MARK_SPAN: f64 = 0.4;

/// Each annotation's velocity over the ground (odometry frame, m/s), keyed by scan and id:
/// from the same person's marks at least [`MARK_SPAN`] before and after it (or on one side
/// only), within 2 s. Marks with no such neighbour have none. `lasers` is each scan's laser
/// pose in the odometry frame.
fn mark_velocities(
    log: &carmen::Log,
    lasers: &[Pose2],
) -> std::collections::HashMap<(usize, u32), [f64; 2]> {
    let mut by_id: std::collections::BTreeMap<u32, Vec<(f64, usize, [f64; 2])>> =
        Default::default();
    for m in &log.people {
        let t = log.scans[m.scan].scan.stamp.secs();
        let p = lasers[m.scan].transform_point(m.position);
        by_id.entry(m.id).or_default().push((t, m.scan, p));
    }
    let mut out = std::collections::HashMap::new();
    for (id, mut marks) in by_id {
        marks.sort_by(|a, b| a.0.total_cmp(&b.0));
        for &(t, scan, p) in &marks {
            let before = marks
                .iter()
                .rev()
                .find(|m| m.0 <= t - MARK_SPAN && m.0 >= t - 2.0);
            let after = marks
                .iter()
                .find(|m| m.0 >= t + MARK_SPAN && m.0 <= t + 2.0);
            let (a, b) = match (before, after) {
                (Some(a), Some(b)) => ((a.0, a.2), (b.0, b.2)),
                (Some(a), None) => ((a.0, a.2), (t, p)),
                (None, Some(b)) => ((t, p), (b.0, b.2)),
                (None, None) => continue,
            };
            let dt = b.0 - a.0;
            out.insert((scan, id), [(b.1[0] - a.1[0]) / dt, (b.1[1] - a.1[1]) / dt]);
        }
    }
    out
}

/// One scan's laser pose in the odometry frame, and its leg and temporal-difference
/// detections in the laser's frame (the temporal ones where that detector kept the scan).
type ScanDetections = (
    Pose2,
    Vec<crate::ground_truth::detection::Detection>,
    Option<Vec<crate::ground_truth::detection::Detection>>,
);

/// Detects and tracks people in every scan of `log` (the leg classifier `legs_model`, or
/// the shipped one, and the default detectors and tracker, in the odometry frame: the log has
/// no map), and scores the tracks against the log's annotations frame by frame in each scan's
/// laser frame (CLEAR-MOT within [`MOT_GATE`]). The tracks are scored over every scan (the benchmark's protocol: a
/// track where nobody is annotated is a false positive) and over the annotated scans alone;
/// the detectors over the annotated scans (DROW's AP, as in simulation).
fn track_people(
    log: &carmen::Log,
    robot: &[Pose2],
    legs_model: Option<&Path>,
) -> Result<PeopleReplay> {
    use crate::ground_truth::leg_scans::Seen;
    use futago_robot::tracking::PeopleConfig;
    use futago_robot::tracking::laser_people::LaserPeople;
    let config = PeopleConfig::default();
    let model = match legs_model {
        Some(path) => crate::stack::people::read_model(path)?,
        None => crate::stack::people::default_model()?,
    };
    let mut people = LaserPeople::new(config, model);
    let mut frames = vec![crate::ground_truth::mot::Frame::default(); log.scans.len()];
    for m in &log.people {
        frames[m.scan].truth.push((m.id, m.position));
    }
    let mut tracks = Vec::new();
    let mut leg_scans = crate::ground_truth::leg_scans::LegScans::default();
    let mut found: Vec<ScanDetections> = Vec::with_capacity(log.scans.len());
    let stamps: Vec<Time> = log.scans.iter().map(|s| s.scan.stamp).collect();
    let lasers: Vec<Pose2> = log
        .scans
        .iter()
        .zip(robot)
        .map(|(s, base)| base.compose(&s.mount))
        .collect();
    let velocities = mark_velocities(log, &lasers);
    for (k, (s, frame)) in log.scans.iter().zip(frames.iter_mut()).enumerate() {
        let laser = lasers[k];
        let d = people.update(&s.scan, None, laser);
        if !frame.truth.is_empty() {
            let to_laser = laser.inverse();
            let marks: Vec<Seen> = frame
                .truth
                .iter()
                .map(|&(id, centre)| Seen {
                    centre,
                    // Over the ground, turned into the laser's axes.
                    velocity: velocities.get(&(k, id)).map(|&v| to_laser.rotate_vector(v)),
                })
                .collect();
            leg_scans.add(
                &futago_robot::perception::legs::segments(&s.scan, &config.legs),
                &marks,
            );
        }
        found.push((
            laser,
            d.legs.iter().map(|q| (q.position, q.confidence)).collect(),
            None,
        ));
        if let Some((when, c)) = d.temporal
            && let Ok(k) = stamps.binary_search(&when)
        {
            let back = found[k].0.inverse();
            found[k].2 = Some(
                c.iter()
                    .map(|q| (back.transform_point(q.position), q.confidence))
                    .collect(),
            );
        }
        let back = laser.inverse();
        for p in people.people() {
            frame.tracks.push((p.id, back.transform_point(p.position)));
            tracks.push((s.logged, p.id, p.position));
        }
    }
    let annotated: Vec<usize> = (0..frames.len())
        .filter(|&i| !frames[i].truth.is_empty())
        .collect();
    // The annotated stretch cut in two at its middle in time: the first half to develop on,
    // the second to report on (issue 45's protocol).
    let split = match (annotated.first(), annotated.last()) {
        (Some(&a), Some(&b)) => 0.5 * (stamps[a].secs() + stamps[b].secs()),
        _ => 0.0,
    };
    let part = |keep: &dyn Fn(usize) -> bool| -> (crate::ground_truth::mot::Mot, Value) {
        let kept: Vec<usize> = annotated.iter().copied().filter(|&i| keep(i)).collect();
        let scored: Vec<crate::ground_truth::mot::Frame> =
            kept.iter().map(|&i| frames[i].clone()).collect();
        let mot = crate::ground_truth::mot::clear_mot(&scored, MOT_GATE);
        (mot, detection_scores(&kept, &frames, &found))
    };
    let (whole, detection) = part(&|_| true);
    let halves = [
        part(&|i| stamps[i].secs() <= split),
        part(&|i| stamps[i].secs() > split),
    ];
    let first_annotated = annotated.first().map_or(0.0, |&i| stamps[i].secs());
    let halves = json!({
        "split_after_first_annotation_s": split - first_annotated,
        "first": {"tracking": halves[0].0.summary(), "detection": halves[0].1},
        "second": {"tracking": halves[1].0.summary(), "detection": halves[1].1},
    });
    Ok(PeopleReplay {
        mot: [
            crate::ground_truth::mot::clear_mot(&frames, MOT_GATE),
            whole,
        ],
        detection,
        halves,
        leg_scans: leg_scans.summary(),
        tracks,
    })
}

/// The leg and temporal-difference detectors' scores (DROW's AP at each match radius) over
/// the scans `kept` (indices into `frames` and `found`, every one annotated).
fn detection_scores(
    kept: &[usize],
    frames: &[crate::ground_truth::mot::Frame],
    found: &[ScanDetections],
) -> Value {
    use crate::ground_truth::detection::{DetectionFrame, score};
    let mut detection = serde_json::Map::new();
    for (name, which) in [("legs", 0), ("temporal", 1)] {
        let cut: Vec<DetectionFrame> = kept
            .iter()
            .filter_map(|&i| {
                let (_, legs, temporal) = &found[i];
                let d = if which == 0 {
                    Some(legs)
                } else {
                    temporal.as_ref()
                };
                d.map(|d| DetectionFrame {
                    truth: frames[i].truth.iter().map(|t| t.1).collect(),
                    detections: d.clone(),
                })
            })
            .collect();
        let radii: serde_json::Map<String, Value> = [0.5, 0.3]
            .iter()
            .map(|&r| (format!("{r}"), json!(score(&cut, r))))
            .collect();
        detection.insert(
            name.into(),
            json!({"scans": cut.len(), "by_radius_m": radii}),
        );
    }
    Value::Object(detection)
}

/// The SLAM configuration of `futago replay`: the `[slam]` keys of `config` (a TOML file; the
/// defaults without one), with `method` (`graph` or `icp`) over it, checked.
pub fn slam_config(config: Option<&Path>, method: Option<&str>) -> Result<SlamConfig> {
    let mut slam: SlamConfig = match config {
        Some(p) => futago_sim::config::load_toml(p)?,
        None => Default::default(),
    };
    if let Some(m) = method {
        slam.method = match m {
            "graph" => futago_robot::mapping::slam::SlamMethod::Graph,
            "icp" => futago_robot::mapping::slam::SlamMethod::Icp,
            other => anyhow::bail!("--method {other}: expected `graph` or `icp`"),
        };
    }
    if let Err((key, expected)) = slam.validate() {
        let file = config
            .map(|p| p.display().to_string())
            .unwrap_or_else(|| "default SLAM configuration".into());
        anyhow::bail!("{file}: `{key}`: {expected}");
    }
    Ok(slam)
}

/// Where `futago replay` writes without `--out`: `out/replay/<the log's stem>`.
pub fn default_out(log: &Path) -> PathBuf {
    Path::new("out/replay").join(
        log.file_stem()
            .map(|s| s.to_string_lossy().to_string())
            .unwrap_or_else(|| "log".into()),
    )
}
