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
//! Only scenarios with people (`[[person]]` or `[[flow]]`) run this node.

use super::{Bus, Node, Report, Streams, Truth};
use crate::ground_truth::Metrics;
use crate::scenario::{Scenario, ScenarioSpec};
use anyhow::{Context, Result};
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
    .to_vec()
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
    Ok(Some(PeopleNode {
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

/// Writes `people.txt` and scores the robot's safety among the people.
pub struct PeopleNode {
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

impl Node for PeopleNode {
    fn name(&self) -> &'static str {
        "people"
    }

    fn streams(&self) -> Streams {
        Streams {
            consumes: vec!["truth".into()],
            ..Streams::default()
        }
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
        Ok(Report {
            summary: vec![(
                "people".into(),
                json!({
                    "people": self.seen.len(),
                    "collisions": self.collisions,
                    "min_clearance_m": self.clearance(),
                    "time_within_0.45m_s": self.within[0],
                    "time_within_1.2m_s": self.within[1],
                }),
            )],
            files,
            ..Report::default()
        })
    }

    fn score(&self, _truth: &Truth) -> Result<Metrics> {
        let mut m = Metrics::default();
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
