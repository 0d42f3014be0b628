//! The people of a scenario, from the simulator's truth: `people.txt` (every person's id,
//! pose and velocity at the ground-truth rate) and the robot's safety among them.
//!
//! Safety, scored at the ground-truth rate (`people.*`):
//! - `people.collisions`: contacts begun between the robot's body and a person's, counted by
//!   the physics;
//! - `people.collisions_driving`: those of them the robot drove into: begun while the robot
//!   itself closed on the nearest person at more than 0.05 m/s (its own velocity towards
//!   them, over the last ground-truth tick);
//! - `people.collisions_by_people`: the rest, people walking into a robot that stood, crept or
//!   drew back, which the stack cannot prevent and the crowd's walk-round should;
//! - `people.min_clearance_m`: the smallest gap between the robot's body and a person's (centre
//!   distance less the robot's radius and the person's, `crowd.radius`);
//! - `people.time_within_0.45m_s`, `people.time_within_1.2m_s`: time with a person's body
//!   closer than Hall's intimate (0.45 m) and personal (1.2 m) distances to the robot's.
//!
//! Tracking, when the scenario has a laser: the robot stack's people pipeline
//! (`futago_robot::tracking::laser_people`, with the shipped leg model `models/legs.json` and
//! the scenario's `[people]` settings) runs on the first laser's scans. With a map and a pose
//! in it (localisation's, else SLAM's), it tracks in the map's frame and leaves out candidates
//! off its free space (leg_tracker's free-space test); without, in the odometry frame. The
//! tracks are scored by CLEAR-MOT as the leg_tracker benchmark scores a real log: frame by
//! frame (each scan), in the laser's frame, within 0.75 m. The true people of a frame are
//! those the scan sees: as many beams as a segment needs (3) end within 0.15 m of their legs
//! where they cross the laser's plane (`people.mota`, `people.motp_m`, `people.id_switches`,
//! `people.false_positives`, `people.misses`). The tracks scored are those in view
//! (`PeopleTracker::people`); the driver is given every track held, hidden ones too.
//! What the scans show of those people, the segments near each by range
//! ([`crate::ground_truth::leg_scans`]), is in the summary's `leg_scans`, measured as
//! `futago replay` measures a real log's annotations.
//!
//! Detection, against the same true people: each detector's candidates (`legs`,
//! `map_difference` and `fused` with a map, `temporal`) are scored by DROW's average
//! precision within 0.5 m and 0.3 m (`people.legs.ap_0.5`, …), with precision and recall at
//! the operating point and AP against range in the summary. The temporal difference is scored
//! on the scans it kept, each against the people of its own time.
//!
//! People in depth images, when the scenario has a laser and a camera (the first, not on a
//! joint) and `people.depth.enabled`: the stack's depth detector
//! (`futago_robot::perception::depth_people`) takes a frame every 1/`people.depth.rate`
//! seconds and hands its people to the laser's tracker (in the map's free space, they confirm
//! a track by shape). Its detections are scored by AP like the laser's (`people.depth.ap_0.5`,
//! `people.depth.ap_0.3`) against the true people the frame sees: those whose body (within
//! 0.3 m of their centre, between 0.1 m and 2.3 m up) fills at least `people.depth.min_voxels`
//! of the detector's voxels among the frame's pixels, placed by the camera's true pose.
//!
//! Only scenarios with people (`[[person]]` or `[[flow]]`) run this node.

use super::{Bus, CameraFrame, FrameTruth, Node, Report, Streams, TrueState, Truth};
use crate::ground_truth::Metrics;
use crate::ground_truth::detection::{Detection, DetectionFrame, by_range, score};
use crate::ground_truth::leg_scans::{LegScans, Seen};
use crate::ground_truth::mot::{Frame, clear_mot};
use crate::scenario::{Scenario, ScenarioSpec};
use anyhow::{Context, Result};
use futago_msgs::{LaserScan, Pose2, Time};
use futago_robot::geometry::{closer_than, within};
use futago_robot::perception::depth_people::{DepthPeople, DepthPeopleConfig};
use futago_robot::perception::legs::{AdaBoost, LegConfig, Segment, segments};
use futago_robot::tracking::laser_people::{Detections, LaserPeople};
use futago_robot::tracking::people::{Candidate, TrackedPerson};
use futago_sim::people::PersonTruth;
use serde_json::{Value, json};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

/// Every person's true id, pose and velocity, one line per person per ground-truth tick.
pub const PEOPLE_FILE: &str = "people.txt";

/// The metric names of the people's scorer for a scenario.
pub fn metric_names(s: &ScenarioSpec) -> Vec<String> {
    if !s.has_people() {
        return Vec::new();
    }
    [
        "people.collisions",
        "people.collisions_driving",
        "people.collisions_by_people",
        "people.min_clearance_m",
        "people.time_within_0.45m_s",
        "people.time_within_1.2m_s",
    ]
    .map(String::from)
    .into_iter()
    .chain(
        (!s.lidar.is_empty())
            .then_some([
                "people.mota",
                "people.motp_m",
                "people.id_switches",
                "people.false_positives",
                "people.misses",
            ])
            .into_iter()
            .flatten()
            .map(String::from),
    )
    .chain(
        (!s.lidar.is_empty())
            .then(|| {
                let mapped = s.module("localization").is_some() || s.module("slam").is_some();
                DETECTORS
                    .iter()
                    .enumerate()
                    .filter(move |(k, _)| mapped || !NEEDS_MAP[*k])
                    .flat_map(|(_, d)| MATCH_RADII.map(|r| format!("people.{d}.ap_{r}")))
            })
            .into_iter()
            .flatten(),
    )
    .chain(
        depth_camera(s)
            .then(|| MATCH_RADII.map(|r| format!("people.depth.ap_{r}")))
            .into_iter()
            .flatten(),
    )
    .collect()
}

/// Whether the scenario's people are looked for in depth images: a laser to track with, a
/// camera off any joint, and the detector enabled.
fn depth_camera(s: &ScenarioSpec) -> bool {
    !s.lidar.is_empty()
        && s.camera.first().is_some_and(|c| c.joint.is_none())
        && s.people.depth.enabled
}

/// The laser's people detectors, in the order [`ScanFrame::found`] holds them (see
/// `futago_robot::tracking::laser_people`).
const DETECTORS: [&str; 4] = ["legs", "map_difference", "fused", "temporal"];
/// Which of them need a map.
const NEEDS_MAP: [bool; 4] = [false, true, true, false];
/// The DROW benchmark's association radii, m.
const MATCH_RADII: [f64; 2] = [0.5, 0.3];

/// Whether the scenario has people walking, for whom the people node runs.
fn has_people(s: &Scenario) -> bool {
    !s.movers.people.is_empty() || !s.movers.flows.is_empty()
}

/// Whether the stack tracks people from the laser and publishes `people/tracked`: the people
/// node runs with a laser to track from.
pub fn tracks_people(s: &Scenario) -> bool {
    has_people(s) && !s.lidars.is_empty()
}

/// The people's node of a scenario: `None` without people.
pub fn node(s: &Scenario, out: Option<&Path>) -> Result<Option<PeopleNode>> {
    if !has_people(s) {
        return Ok(None);
    }
    let file = match out {
        Some(dir) => Some(BufWriter::new(
            File::create(dir.join(PEOPLE_FILE))
                .with_context(|| format!("creating {PEOPLE_FILE}"))?,
        )),
        None => None,
    };
    let tracking = match s.lidars.first() {
        Some((l, _)) => Some(Tracking {
            source: if s.spec.module("localization").is_some() {
                Some("localization")
            } else if s.spec.module("slam").is_some() {
                Some("slam")
            } else {
                None
            },
            laser: l.name.clone(),
            mount: l.planar_mount(),
            height: l.xyz[2],
            min_points: s.spec.people.legs.min_points,
            legs: s.spec.people.legs,
            leg_scans: LegScans::default(),
            people: LaserPeople::new(s.spec.people, default_model()?),
            map_seen: None,
            maps_taken: 0,
            map_period: s.spec.people.map_period,
            frames: Vec::new(),
            scans: Vec::new(),
            unscored: None,
            depth: match s.cameras.first() {
                Some(cam) if depth_camera(&s.spec) => Some(DepthTracking {
                    camera: cam.name.clone(),
                    detector: DepthPeople::new(
                        s.spec.people.depth,
                        super::camera_on_base(cam),
                        s.spec.seed,
                    ),
                    config: s.spec.people.depth,
                    next: Time::ZERO,
                    frames: Vec::new(),
                    no_floor: 0,
                    taken: 0,
                    seconds: 0.0,
                }),
                _ => None,
            },
        }),
        None => None,
    };
    Ok(Some(PeopleNode {
        tracking,
        file,
        scenario: s.spec.name.clone(),
        robot_radius: s.spec.robot.radius,
        person_radius: s.movers.crowd.radius,
        period: 1.0 / s.spec.output.groundtruth_rate,
        collisions: 0,
        final_collisions: 0,
        collisions_driving: 0,
        last_pose: None,
        min_clearance: f64::INFINITY,
        within: [0.0; 2],
        seen: std::collections::BTreeSet::new(),
        line: String::new(),
    }))
}

/// The stack's people tracking on one laser, its CLEAR-MOT frames and its detections.
struct Tracking {
    /// The module whose pose and map the tracker uses (`pose/NAME`, `map/NAME`), if any.
    source: Option<&'static str>,
    laser: String,
    mount: Pose2,
    height: f64,
    /// Beams that must end on a person's legs for the scan to see them.
    min_points: usize,
    /// The leg detector's segmentation, to measure what the scans show of the people.
    legs: LegConfig,
    /// The segments of the people each scan sees ([`LegScans`]).
    leg_scans: LegScans,
    people: LaserPeople,
    /// The time of the map last given to `people`, and how many it was given.
    map_seen: Option<Time>,
    maps_taken: usize,
    /// Maps are wanted no more often than this ([`PeopleConfig::map_period`]).
    map_period: f64,
    frames: Vec<Frame>,
    scans: Vec<ScanFrame>,
    /// People in depth images, feeding the same tracker.
    depth: Option<DepthTracking>,
    /// The scan last tracked, until it is scored.
    unscored: Option<UnscoredScan>,
}

/// The depth-image person detector on one camera, and its scored frames.
struct DepthTracking {
    camera: String,
    detector: DepthPeople,
    config: DepthPeopleConfig,
    /// When the next frame is due.
    next: Time,
    /// Each frame's true people and detections, in the base's true and estimated frames.
    frames: Vec<DetectionFrame>,
    /// Frames without a floor to level by.
    no_floor: u64,
    /// Detections the tracker took.
    taken: u64,
    /// Wall time spent detecting, s (a cost, not a result).
    seconds: f64,
}

/// A person's body reaches this far from their centre, m (the torso's half-width, 0.2 m,
/// and a stride's leg).
const BODY_REACH: f64 = 0.3;
/// The floor's band and a person's greatest height for the depth truth, m (the detector's
/// defaults: a visible body is what it could cluster).
const BODY_FROM: f64 = 0.1;
const BODY_TO: f64 = 2.3;

impl DepthTracking {
    /// The true people `frame` sees, in the true base frame (see the module documentation).
    fn visible(&self, frame: &CameraFrame, view: &dyn FrameTruth) -> Vec<[f64; 2]> {
        let (truth, optical) = (view.state(), view.optical());
        let (k, d) = (&frame.frame.depth_intrinsics, &frame.frame.depth);
        let voxel = self.config.voxel;
        let mut cells: Vec<std::collections::BTreeSet<[i64; 3]>> =
            vec![Default::default(); truth.people.len()];
        let step = self.config.stride as usize;
        for v in (0..d.height).step_by(step) {
            for u in (0..d.width).step_by(step) {
                let z = d.at(u, v) as f64;
                if !(z.is_finite() && z > 0.0 && z <= self.config.max_depth) {
                    continue;
                }
                let w = optical.transform_point(k.back_project(u as f64, v as f64, z));
                if !(BODY_FROM..=BODY_TO).contains(&w[2]) {
                    continue;
                }
                for (p, set) in truth.people.iter().zip(cells.iter_mut()) {
                    if within(w[0] - p.pose.x, w[1] - p.pose.y, BODY_REACH) {
                        set.insert(w.map(|x| (x / voxel).floor() as i64));
                    }
                }
            }
        }
        let to_base = truth.robot.inverse();
        truth
            .people
            .iter()
            .zip(&cells)
            .filter(|(_, set)| set.len() >= self.config.min_voxels)
            .map(|(p, _)| to_base.transform_point([p.pose.x, p.pose.y]))
            .collect()
    }
}

/// A scan tracked, until it is scored against the truth of its instant.
struct UnscoredScan {
    stamp: Time,
    in_odometry: Pose2,
    /// The beams' ends in the laser frame.
    ends: Vec<[f64; 2]>,
    /// The scan's segments, as the leg detector cuts it.
    segments: Vec<Segment>,
    found: Detections,
    tracks: Vec<(u32, [f64; 2])>,
}

/// One scan's detections and the people it sees, in the laser's frame.
struct ScanFrame {
    stamp: Time,
    /// The laser's pose in the odometry frame, where the temporal difference works.
    in_odometry: Pose2,
    truth: Vec<[f64; 2]>,
    /// Per detector of [`DETECTORS`]; `None` where it gave nothing for this scan (no map, or
    /// a scan the temporal difference did not keep).
    found: [Option<Vec<Detection>>; 4],
}

fn as_points(c: &[Candidate]) -> Vec<Detection> {
    c.iter().map(|q| (q.position, q.confidence)).collect()
}

/// Writes `people.txt`, tracks people from the laser and scores the tracks and the robot's
/// safety among the people.
pub struct PeopleNode {
    tracking: Option<Tracking>,
    file: Option<BufWriter<File>>,
    scenario: String,
    robot_radius: f64,
    person_radius: f64,
    /// The ground-truth period, s: each tick counts for this long.
    period: f64,
    collisions: u64,
    /// The contacts counted at the scorer's last look (see `observe`).
    final_collisions: u64,
    /// Contacts begun while the robot drove at the person.
    collisions_driving: u64,
    /// The robot's true pose at the last tick.
    last_pose: Option<futago_msgs::Pose2>,
    min_clearance: f64,
    /// Time within 0.45 m and 1.2 m, s.
    within: [f64; 2],
    /// Ids of everyone who was in the world.
    seen: std::collections::BTreeSet<u32>,
    line: String,
}

/// A robot closing on a person faster than this drove into them, m/s (the Create's slowest
/// useful speed is about 0.05 m/s; standing, it reads 0 within odometry's noise).
const DRIVING_AT: f64 = 0.05;

/// Hall's intimate and personal distances, m.
const ZONES: [f64; 2] = [0.45, 1.2];

/// A person is in a scan when a beam ends this close to one of their legs' axes, m (a shin's
/// radius, 0.05 m, and the laser's noise).
const SEEN_WITHIN: f64 = 0.15;

impl Node for PeopleNode {
    fn name(&self) -> &'static str {
        "people"
    }

    fn streams(&self) -> Streams {
        let mut consumes = vec!["truth".to_string()];
        let mut periods = Vec::new();
        if let Some(t) = &self.tracking {
            consumes.push(format!("scan/{}", t.laser));
            if let Some(d) = &t.depth {
                consumes.push(format!("camera/{}", d.camera));
            }
            if let Some(src) = t.source {
                consumes.push(format!("pose/{src}"));
                consumes.push(format!("map/{src}"));
                if t.map_period > 0.0 {
                    periods.push((
                        format!("map/{src}"),
                        futago_msgs::Duration::from_secs(t.map_period),
                    ));
                }
            }
        }
        Streams {
            periods,
            publishes: self
                .tracking
                .iter()
                .map(|_| "people/tracked".to_string())
                .collect(),
            consumes,
        }
    }

    fn wants_frame(&self, camera: &str, bus: &Bus) -> bool {
        self.tracking
            .as_ref()
            .and_then(|t| t.depth.as_ref())
            .is_some_and(|d| d.camera == camera && bus.now >= d.next)
    }

    /// It reads the depth image alone.
    fn wants_rgb(&self, _camera: &str) -> bool {
        false
    }

    /// The detector and the truth it is scored on read every `stride`-th pixel.
    fn depth_stride(&self, camera: &str) -> u32 {
        self.tracking
            .as_ref()
            .and_then(|t| t.depth.as_ref())
            .filter(|d| d.camera == camera)
            .map_or(1, |d| d.config.stride)
    }

    fn on_frame(
        &mut self,
        camera: &str,
        frame: &CameraFrame,
        truth: &mut dyn FrameTruth,
        bus: &mut Bus,
    ) -> Result<()> {
        let Some(t) = &mut self.tracking else {
            return Ok(());
        };
        let in_map = t.source.and_then(|src| bus.pose(src));
        let Some(d) = &mut t.depth else {
            return Ok(());
        };
        if d.camera != camera {
            return Ok(());
        }
        let period = futago_msgs::Duration::from_secs(1.0 / d.config.rate);
        while d.next <= bus.now {
            d.next = d.next + period;
        }
        let truth = d.visible(frame, truth);
        let t0 = std::time::Instant::now();
        let found = match d.detector.detect(&frame.frame) {
            Some((found, _)) => found,
            None => {
                d.no_floor += 1;
                Vec::new()
            }
        };
        d.seconds += t0.elapsed().as_secs_f64();
        d.taken += t.people.update_depth(
            frame.frame.stamp,
            &found.iter().map(|q| q.position).collect::<Vec<_>>(),
            in_map,
            bus.odometry,
        ) as u64;
        d.frames.push(DetectionFrame {
            truth,
            detections: found.iter().map(|q| (q.position, q.confidence)).collect(),
        });
        Ok(())
    }

    fn on_scan(&mut self, _laser: &str, scan: &LaserScan, bus: &mut Bus) -> Result<()> {
        let Some(t) = &mut self.tracking else {
            return Ok(());
        };
        // The stack's view: the laser placed by the map pose (with a map), and by odometry.
        if let Some((stamp, map)) = t.source.and_then(|src| bus.map(src))
            && t.map_seen != Some(stamp)
        {
            t.people.set_map(map);
            t.map_seen = Some(stamp);
            t.maps_taken += 1;
        }
        let in_map = t
            .source
            .and_then(|src| bus.pose(src))
            .map(|p| p.compose(&t.mount));
        let in_odometry = bus.odometry.compose(&t.mount);
        let found: Detections = t.people.update(scan, in_map, in_odometry);
        let laser = match (in_map, t.map_seen) {
            (Some(l), Some(_)) => l,
            _ => in_odometry,
        };
        let back = laser.inverse();
        // Scored: the people in view. Published: every person remembered, for the driver.
        let tracks = t
            .people
            .people()
            .iter()
            .map(|p| (p.id, back.transform_point(p.position)))
            .collect();
        let people = t.people.remembered();
        // Published in the base's frame, for the driver.
        let base = laser.compose(&t.mount.inverse());
        let to_base = base.inverse();
        bus.publish_people(
            people
                .iter()
                .map(|p| TrackedPerson {
                    id: p.id,
                    position: to_base.transform_point(p.position),
                    velocity: to_base.rotate_vector(p.velocity),
                })
                .collect(),
        );
        // Scored when the scorer sees the truth of this instant.
        let ends: Vec<[f64; 2]> = (0..scan.ranges.len())
            .filter_map(|i| {
                let r = scan.ranges[i] as f64;
                r.is_finite().then(|| {
                    let a = scan.angle(i);
                    [r * a.cos(), r * a.sin()]
                })
            })
            .collect();
        t.unscored = Some(UnscoredScan {
            stamp: scan.stamp,
            in_odometry,
            ends,
            segments: segments(scan, &t.legs),
            found,
            tracks,
        });
        Ok(())
    }

    fn start(&mut self, _bus: &mut Bus) -> Result<()> {
        if let Some(f) = &mut self.file {
            writeln!(
                f,
                "# futago ground truth of the people in {}: one line per person per tick, in the \
                 world frame\n# timestamp id x y yaw vx vy",
                self.scenario
            )?;
        }
        Ok(())
    }

    fn on_truth(&mut self, truth: &TrueState, bus: &mut Bus) -> Result<()> {
        use std::fmt::Write as _;
        let r = truth.robot;
        if truth.person_collisions > self.collisions {
            let last = self.last_pose.unwrap_or(r);
            if robot_drove_in(last, r, self.period, &truth.people) {
                self.collisions_driving += truth.person_collisions - self.collisions;
            }
        }
        self.collisions = truth.person_collisions;
        self.last_pose = Some(r);
        let mut nearest = f64::INFINITY;
        for p in &truth.people {
            self.seen.insert(p.id);
            let gap = p.pose.distance(&r) - self.robot_radius - self.person_radius;
            nearest = nearest.min(gap);
            if let Some(f) = &mut self.file {
                self.line.clear();
                let _ = writeln!(
                    self.line,
                    "{:.6} {} {:.6} {:.6} {:.6} {:.6} {:.6}",
                    bus.now.secs(),
                    p.id,
                    p.pose.x,
                    p.pose.y,
                    p.pose.theta,
                    p.velocity[0],
                    p.velocity[1]
                );
                f.write_all(self.line.as_bytes())?;
            }
        }
        self.min_clearance = self.min_clearance.min(nearest);
        for (t, zone) in self.within.iter_mut().zip(ZONES) {
            if nearest < zone {
                *t += self.period;
            }
        }
        Ok(())
    }

    fn observe(&mut self, truth: &TrueState, _bus: &Bus) {
        if let Some(t) = &mut self.tracking
            && let Some(u) = t.unscored.take()
        {
            t.score_scan(u, truth);
        }
        // The last look, before `finish`, counts the contacts of the run's last steps.
        self.final_collisions = truth.person_collisions;
    }

    fn finish(&mut self, _bus: &mut Bus, _out: Option<&Path>) -> Result<Report> {
        self.collisions = self.final_collisions;
        let mut files = Vec::new();
        if let Some(f) = &mut self.file {
            f.flush()
                .with_context(|| format!("writing {PEOPLE_FILE}"))?;
            files.push(PEOPLE_FILE.to_string());
        }
        let mut entry = json!({
            "people": self.seen.len(),
            "collisions": self.collisions,
            "collisions_driving": self.collisions_driving,
            "collisions_by_people": self.collisions_by_people(),
            "min_clearance_m": self.clearance(),
            "time_within_0.45m_s": self.within[0],
            "time_within_1.2m_s": self.within[1],
        });
        if let Some(t) = &self.tracking {
            let m = clear_mot(&t.frames, crate::ground_truth::mot::MOT_GATE);
            let mut tracking = m.summary();
            tracking["laser"] = json!(t.laser);
            tracking["maps_taken"] = json!(t.maps_taken);
            entry["tracking"] = tracking;
            entry["leg_scans"] = t.leg_scans.summary();
            let mut detection = serde_json::Map::new();
            for (k, name) in DETECTORS.iter().enumerate() {
                if let Some(frames) = t.detection_frames(k) {
                    let mut e = detection_entry(&frames);
                    e["scans"] = json!(frames.len());
                    detection.insert(name.to_string(), e);
                }
            }
            if let Some(d) = &t.depth {
                let mut e = detection_entry(&d.frames);
                e["frames"] = json!(d.frames.len());
                e["camera"] = json!(d.camera);
                e["frames_without_floor"] = json!(d.no_floor);
                e["taken_by_tracker"] = json!(d.taken);
                detection.insert("depth".to_string(), e);
            }
            entry["detection"] = serde_json::Value::Object(detection);
        }
        let mut performance = serde_json::Map::new();
        if let Some(d) = self.tracking.as_ref().and_then(|t| t.depth.as_ref()) {
            let n = d.frames.len().max(1) as f64;
            performance.insert("depth_frames".into(), json!(d.frames.len()));
            performance.insert(
                "depth_detect_ms_per_frame".into(),
                json!(1e3 * d.seconds / n),
            );
        }
        Ok(Report {
            summary: vec![("people".into(), entry)],
            files,
            performance,
            ..Report::default()
        })
    }

    fn score(&self, _truth: &Truth) -> Result<Metrics> {
        let mut m = Metrics::default();
        if let Some(t) = &self.tracking {
            let mot = clear_mot(&t.frames, crate::ground_truth::mot::MOT_GATE);
            // MOTA is undefined where nobody was seen; it is taken as 1 − false positives (as
            // if one person were there to find), so false tracks still count against such a
            // run.
            m.insert(
                "people.mota",
                mot.mota().unwrap_or(1.0 - mot.false_positives as f64),
            );
            m.insert("people.motp_m", mot.motp().unwrap_or(0.0));
            m.insert("people.id_switches", mot.id_switches as f64);
            m.insert("people.false_positives", mot.false_positives as f64);
            m.insert("people.misses", mot.misses as f64);
            for (k, name) in DETECTORS.iter().enumerate() {
                if let Some(frames) = t.detection_frames(k) {
                    insert_ap(&mut m, name, &frames);
                }
            }
            if let Some(d) = &t.depth {
                insert_ap(&mut m, "depth", &d.frames);
            }
        }
        m.insert("people.collisions", self.collisions as f64);
        m.insert("people.collisions_driving", self.collisions_driving as f64);
        m.insert(
            "people.collisions_by_people",
            self.collisions_by_people() as f64,
        );
        m.insert("people.min_clearance_m", self.clearance());
        m.insert("people.time_within_0.45m_s", self.within[0]);
        m.insert("people.time_within_1.2m_s", self.within[1]);
        Ok(m)
    }
}

/// A detector's summary: its scores at each match radius and its AP against range.
fn detection_entry(frames: &[DetectionFrame]) -> serde_json::Value {
    let radii: serde_json::Map<String, serde_json::Value> = MATCH_RADII
        .iter()
        .map(|&r| (format!("{r}"), json!(score(frames, r))))
        .collect();
    let ranges: Vec<serde_json::Value> = by_range(frames, MATCH_RADII[0])
        .into_iter()
        .map(|(lo, hi, s)| json!({"from_m": lo, "to_m": hi, "score": s}))
        .collect();
    json!({"by_radius_m": radii, "by_range_at_0.5m": ranges})
}

/// `people.NAME.ap_R` for each match radius. AP is undefined where nobody was seen: 1
/// without detections, else 0 (every detection was false).
fn insert_ap(m: &mut Metrics, name: &str, frames: &[DetectionFrame]) {
    for r in MATCH_RADII {
        let s = score(frames, r);
        let ap = s.ap.unwrap_or(if s.detections == 0 { 1.0 } else { 0.0 });
        m.insert(format!("people.{name}.ap_{r}"), ap);
    }
}

impl Tracking {
    /// Scores the scan just tracked against the truth of its instant: the people it sees
    /// (enough beams end on their legs), in the true laser frame, against each detector's
    /// candidates and the tracks.
    fn score_scan(&mut self, u: UnscoredScan, state: &TrueState) {
        let UnscoredScan {
            stamp,
            in_odometry,
            ends,
            segments,
            found,
            tracks,
        } = u;
        let to_laser = state.robot.compose(&self.mount).inverse();
        let t = self;
        let mut seen = Vec::new();
        let truth = state
            .people
            .iter()
            .filter(|p| {
                let legs = p.legs_at(t.height).map(|l| to_laser.transform_point(l));
                let on_legs = ends
                    .iter()
                    .filter(|e| {
                        legs.iter()
                            .any(|q| closer_than(e[0] - q[0], e[1] - q[1], SEEN_WITHIN))
                    })
                    .count();
                on_legs >= t.min_points
            })
            .map(|p| {
                let centre = to_laser.transform_point([p.pose.x, p.pose.y]);
                seen.push(Seen {
                    centre,
                    velocity: Some(to_laser.rotate_vector(p.velocity)),
                });
                (p.id, centre)
            })
            .collect::<Vec<_>>();
        t.leg_scans.add(&segments, &seen);
        t.scans.push(ScanFrame {
            stamp,
            in_odometry,
            truth: truth.iter().map(|p| p.1).collect(),
            found: [
                Some(as_points(&found.legs)),
                found.map_difference.as_deref().map(as_points),
                found.fused.as_deref().map(as_points),
                None,
            ],
        });
        if let Some((when, c)) = &found.temporal
            && let Ok(k) = t.scans.binary_search_by_key(when, |f| f.stamp)
        {
            let back = t.scans[k].in_odometry.inverse();
            t.scans[k].found[3] = Some(
                c.iter()
                    .map(|q| (back.transform_point(q.position), q.confidence))
                    .collect(),
            );
        }
        t.frames.push(Frame { truth, tracks });
    }

    /// The scans detector `k` of [`DETECTORS`] gave detections for, as detection frames;
    /// `None` when it gave none at all (it needs a map and there was none).
    fn detection_frames(&self, k: usize) -> Option<Vec<DetectionFrame>> {
        let frames: Vec<DetectionFrame> = self
            .scans
            .iter()
            .filter_map(|f| {
                f.found[k].as_ref().map(|d| DetectionFrame {
                    truth: f.truth.clone(),
                    detections: d.clone(),
                })
            })
            .collect();
        (!frames.is_empty() || !NEEDS_MAP[k]).then_some(frames)
    }
}

impl PeopleNode {
    /// The contacts people began: those the robot did not drive into. (The last steps' contacts,
    /// counted only by `finish`, are never classed as driving.)
    fn collisions_by_people(&self) -> u64 {
        self.collisions.saturating_sub(self.collisions_driving)
    }

    /// The smallest gap seen; a run that never had anyone in the world reports 1000 m (a
    /// finite stand-in that any `min` gate passes and JSON can hold).
    fn clearance(&self) -> f64 {
        if self.min_clearance.is_finite() {
            self.min_clearance
        } else {
            1000.0
        }
    }
}

/// Reads a model file written by `futago train-legs` (`crate::legs_train::train`), checking it.
pub fn load_model(text: &str, name: &str) -> Result<AdaBoost> {
    let v: Value = serde_json::from_str(text).with_context(|| format!("{name}: not JSON"))?;
    let model: AdaBoost = serde_json::from_value(v["model"].clone())
        .with_context(|| format!("{name}: key `model`: expected {{\"stumps\": [...]}}"))?;
    model
        .validate()
        .map_err(|e| anyhow::anyhow!("{name}: key `model`: {e}"))?;
    Ok(model)
}

/// A model file written by `futago train-legs`; errors name the file.
pub fn read_model(path: &std::path::Path) -> Result<AdaBoost> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| anyhow::anyhow!("{}: cannot read the leg model: {e}", path.display()))?;
    load_model(&text, &path.display().to_string())
}

/// The model shipped with futago (`models/legs.json`), trained by `futago train-legs
/// scenarios/train-legs.toml`.
pub fn default_model() -> Result<AdaBoost> {
    load_model(include_str!("../../models/legs.json"), "models/legs.json")
}

/// People detection and tracking, and the people's truth and safety scores.
pub const MODULE: super::Plain = super::Plain {
    metric_names,
    build: |s, _, out| super::boxed(node(s, out)),
};

/// Whether the robot, at `last` one tick of `period` s ago and at `now`, drove into the
/// person nearest it: its own speed towards them exceeds [`DRIVING_AT`].
fn robot_drove_in(last: Pose2, now: Pose2, period: f64, people: &[PersonTruth]) -> bool {
    let v = [(now.x - last.x) / period, (now.y - last.y) / period];
    people
        .iter()
        .min_by(|a, b| a.pose.distance(&now).total_cmp(&b.pose.distance(&now)))
        .is_some_and(|p| {
            let d = p.pose.distance(&now).max(1e-9);
            (v[0] * (p.pose.x - now.x) + v[1] * (p.pose.y - now.y)) / d > DRIVING_AT
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(x: f64, y: f64) -> PersonTruth {
        PersonTruth {
            id: 0,
            name: "p".into(),
            pose: Pose2::new(x, y, 0.0),
            velocity: [0.0; 2],
            legs: [([x, y + 0.1], [0.0; 2]), ([x, y - 0.1], [0.0; 2])],
            hip_height: 0.85,
        }
    }

    #[test]
    fn a_contact_is_the_robots_when_it_closed_on_the_nearest_person() {
        let dt = 0.02;
        let people = [at(1.0, 0.0), at(-3.0, 0.0)];
        let from = Pose2::new(0.0, 0.0, 0.0);
        // The robot's velocity (m/s) over the tick, and who is in the world.
        let drove = |vx: f64, vy: f64, people: &[PersonTruth]| {
            robot_drove_in(from, Pose2::new(vx * dt, vy * dt, 0.0), dt, people)
        };
        // 0.3 m/s towards the nearest person (east): the robot drove in.
        assert!(drove(0.3, 0.0, &people));
        // Standing, backing away (towards the far person), or passing square to the near one
        // at 0.3 m/s: people began it.
        assert!(!drove(0.0, 0.0, &people));
        assert!(!drove(-0.3, 0.0, &people));
        assert!(!drove(0.0, 0.3, &people));
        // Creeping at 0.04 m/s, under the 0.05 m/s that counts as driving.
        assert!(!drove(0.04, 0.0, &people));
        // Nobody in the world.
        assert!(!drove(0.3, 0.0, &[]));
    }
}
