//! The people of a scenario, from the simulator's truth: `people.txt` (every person's id,
//! pose and velocity at the ground-truth rate) and the robot's safety among them.
//!
//! Safety, scored at the ground-truth rate (`people.*`):
//! - `people.collisions`: contacts begun between the robot's body and a person's, counted by
//!   the physics;
//! - `people.min_clearance_m`: the smallest gap between the robot's body and a person's (centre
//!   distance less the robot's radius and the person's, `crowd.radius`);
//! - `people.time_within_0.45m_s`, `people.time_within_1.2m_s`: time with a person's body
//!   closer than Hall's intimate (0.45 m) and personal (1.2 m) distances to the robot's.
//!
//! Tracking, when the scenario has a laser: the robot stack's leg detector (the shipped
//! model, `models/legs.json`) and people tracker run on the first laser's scans. With a map
//! and a pose in it (localisation's, else SLAM's), they track in the map's frame and leave out
//! candidates off its free space (an occupied cell within 0.15 m: leg_tracker's free-space
//! test); without, in the odometry frame. They are scored by CLEAR-MOT as the leg_tracker benchmark scores a real
//! log: frame by frame (each scan), in the laser's frame, within 0.75 m. The true people of a
//! frame are those the scan sees: as many beams as a segment needs (3) end within 0.15 m of
//! their legs where they cross the laser's plane (`people.mota`, `people.motp_m`, `people.id_switches`,
//! `people.false_positives`, `people.misses`).
//!
//! Only scenarios with people (`[[person]]` or `[[flow]]`) run this node.

use super::{Bus, Node, Report, Streams, Truth};
use crate::ground_truth::Metrics;
use crate::ground_truth::mot::{Frame, clear_mot};
use crate::scenario::{Scenario, ScenarioSpec};
use anyhow::{Context, Result};
use futago_msgs::grid::OccupancyGrid;
use futago_msgs::{LaserScan, Pose2};
use futago_robot::geometry::grid::OCCUPIED;
use futago_robot::perception::legs::{AdaBoost, LegConfig, detect};
use futago_robot::tracking::people::{PeopleTracker, TrackerConfig};
use serde_json::json;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

/// Every person's true id, pose and velocity, one line per person per ground-truth tick.
pub const PEOPLE_FILE: &str = "people.txt";

/// The metric names of the people's scorer for a scenario.
pub fn metric_names(s: &ScenarioSpec) -> Vec<String> {
    if s.person.is_empty() && s.flow.is_empty() {
        return Vec::new();
    }
    [
        "people.collisions",
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
    .collect()
}

/// The people's node of a scenario: `None` without people.
pub fn node(s: &Scenario, out: Option<&Path>) -> Result<Option<PeopleNode>> {
    if s.movers.people.is_empty() && s.movers.flows.is_empty() {
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
            source: if s.spec.localization.is_some() {
                Some("localization")
            } else if s.slam.is_some() {
                Some("slam")
            } else {
                None
            },
            laser: l.name.clone(),
            mount: l.planar_mount(),
            height: l.xyz[2],
            model: crate::legs_train::default_model()?,
            legs: LegConfig::default(),
            tracker: PeopleTracker::new(TrackerConfig::default()),
            frames: Vec::new(),
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
        min_clearance: f64::INFINITY,
        within: [0.0; 2],
        seen: std::collections::BTreeSet::new(),
        line: String::new(),
    }))
}

/// The stack's people tracking on one laser, and its CLEAR-MOT frames.
struct Tracking {
    /// The module whose pose and map the tracker uses (`pose/NAME`, `map/NAME`), if any.
    source: Option<&'static str>,
    laser: String,
    mount: Pose2,
    height: f64,
    model: AdaBoost,
    legs: LegConfig,
    tracker: PeopleTracker,
    frames: Vec<Frame>,
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
    min_clearance: f64,
    /// Time within 0.45 m and 1.2 m, s.
    within: [f64; 2],
    /// Ids of everyone who was in the world.
    seen: std::collections::BTreeSet<u32>,
    line: String,
}

/// Hall's intimate and personal distances, m.
const ZONES: [f64; 2] = [0.45, 1.2];

/// A candidate counts only where no occupied cell of the map lies this close, m (a shin's
/// radius and a cell's diagonal at 5 cm).
const FREE_RADIUS: f64 = 0.15;

/// Whether no occupied cell of `m` lies within `r` of `q`; a point off the map is not free.
fn in_free_space(m: &OccupancyGrid, q: [f64; 2], r: f64) -> bool {
    let k = (r / m.resolution).ceil() as i64;
    let Some((ci, cj)) = m.cell_of(q[0], q[1]) else {
        return false;
    };
    for dj in -k..=k {
        for di in -k..=k {
            let (i, j) = (ci as i64 + di, cj as i64 + dj);
            if i < 0 || j < 0 || i >= m.width as i64 || j >= m.height as i64 {
                continue;
            }
            let c = m.cell_center(i as usize, j as usize);
            if (c[0] - q[0]).hypot(c[1] - q[1]) <= r + 0.5 * m.resolution
                && m.get(i as usize, j as usize) >= OCCUPIED
            {
                return false;
            }
        }
    }
    true
}

/// A person is in a scan when a beam ends this close to one of their legs' axes, m (a shin's
/// radius, 0.05 m, and the laser's noise).
const SEEN_WITHIN: f64 = 0.15;

impl Node for PeopleNode {
    fn name(&self) -> &'static str {
        "people"
    }

    fn streams(&self) -> Streams {
        let mut consumes = vec!["truth".to_string()];
        if let Some(t) = &self.tracking {
            consumes.push(format!("scan/{}", t.laser));
            if let Some(src) = t.source {
                consumes.push(format!("pose/{src}"));
                consumes.push(format!("map/{src}"));
            }
        }
        Streams {
            consumes,
            ..Streams::default()
        }
    }

    fn on_scan(&mut self, _laser: &str, scan: &LaserScan, bus: &mut Bus) -> Result<()> {
        let Some(t) = &mut self.tracking else {
            return Ok(());
        };
        // The stack's view: the laser placed by the map pose, else by odometry.
        let robot = t
            .source
            .and_then(|src| bus.pose(src))
            .unwrap_or(bus.odometry);
        let laser = robot.compose(&t.mount);
        let seen: Vec<[f64; 2]> = detect(scan, &t.legs, &t.model)
            .iter()
            .map(|l| laser.transform_point(l.position))
            .collect();
        let map = t
            .source
            .and_then(|src| bus.map(src))
            .map(|(_, m)| m.clone());
        let free = |q: [f64; 2]| {
            map.as_ref()
                .is_none_or(|m| in_free_space(m, q, FREE_RADIUS))
        };
        t.tracker.update_where(scan.stamp, &seen, &free);
        let back = laser.inverse();
        let tracks = t
            .tracker
            .people()
            .iter()
            .map(|p| (p.id, back.transform_point(p.position)))
            .collect();
        // The truth: people the scan sees, in the true laser frame.
        let true_laser = bus.truth.compose(&t.mount);
        let to_laser = true_laser.inverse();
        let ends: Vec<[f64; 2]> = (0..scan.ranges.len())
            .filter_map(|i| {
                let r = scan.ranges[i] as f64;
                r.is_finite().then(|| {
                    let a = scan.angle(i);
                    [r * a.cos(), r * a.sin()]
                })
            })
            .collect();
        let truth = bus
            .people
            .iter()
            .filter(|p| {
                let legs = p.legs_at(t.height).map(|l| to_laser.transform_point(l));
                let on_legs = ends
                    .iter()
                    .filter(|e| {
                        legs.iter()
                            .any(|q| (e[0] - q[0]).hypot(e[1] - q[1]) < SEEN_WITHIN)
                    })
                    .count();
                on_legs >= t.legs.min_points
            })
            .map(|p| (p.id, to_laser.transform_point([p.pose.x, p.pose.y])))
            .collect();
        t.frames.push(Frame { truth, tracks });
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

    fn on_truth(&mut self, bus: &Bus) -> Result<()> {
        use std::fmt::Write as _;
        self.collisions = bus.person_collisions;
        let r = bus.truth;
        let mut nearest = f64::INFINITY;
        for p in &bus.people {
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

    fn finish(&mut self, bus: &mut Bus, _out: Option<&Path>) -> Result<Report> {
        self.collisions = bus.person_collisions;
        let mut files = Vec::new();
        if let Some(f) = &mut self.file {
            f.flush()
                .with_context(|| format!("writing {PEOPLE_FILE}"))?;
            files.push(PEOPLE_FILE.to_string());
        }
        let mut entry = json!({
            "people": self.seen.len(),
            "collisions": self.collisions,
            "min_clearance_m": self.clearance(),
            "time_within_0.45m_s": self.within[0],
            "time_within_1.2m_s": self.within[1],
        });
        if let Some(t) = &self.tracking {
            let m = clear_mot(&t.frames, crate::replay::MOT_GATE);
            let mut tracking = m.summary();
            tracking["laser"] = json!(t.laser);
            entry["tracking"] = tracking;
        }
        Ok(Report {
            summary: vec![("people".into(), entry)],
            files,
            ..Report::default()
        })
    }

    fn score(&self, _truth: &Truth) -> Result<Metrics> {
        let mut m = Metrics::default();
        if let Some(t) = &self.tracking {
            let mot = clear_mot(&t.frames, crate::replay::MOT_GATE);
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
        }
        m.insert("people.collisions", self.collisions as f64);
        m.insert("people.min_clearance_m", self.clearance());
        m.insert("people.time_within_0.45m_s", self.within[0]);
        m.insert("people.time_within_1.2m_s", self.within[1]);
        Ok(m)
    }
}

impl PeopleNode {
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
