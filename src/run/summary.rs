//! `summary.json`, typed: what a run did and how it scored.
//!
//! The file is this struct serialised through `serde_json::Value`, whose maps keep their
//! keys sorted, so the file's layout does not depend on the order of the fields here. Each
//! node adds its own entry (`slam`, `localization`, …), kept as the node wrote it.

use super::{Outcome, Scored};
use crate::ground_truth::{Gate, GateResult, Metrics};
use crate::scenario::Scenario;
use serde::Serialize;
use serde_json::Value;
use std::collections::BTreeMap;

/// The whole summary of a run.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    pub scenario: String,
    pub description: String,
    pub world: String,
    pub seed: u64,
    /// The overlays laid over the scenario file, in order.
    pub overlays: Vec<String>,
    pub sim_time_s: f64,
    pub physics_rate_hz: f64,
    pub steps: u64,
    pub robot: Robot,
    pub odometry: OdometryEnd,
    pub lidar: Vec<Lidar>,
    pub camera: Vec<Camera>,
    pub laser_rays: u64,
    /// Every file the run wrote (but the summary and the report) with its SHA-256; empty for
    /// a run scored without writing.
    pub files: BTreeMap<String, Digest>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub joints: Option<Vec<JointEnd>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub agents: Option<Vec<AgentEnd>>,
    pub gates: Vec<GateResult>,
    /// Gates against other scenarios' runs, for the suite to check.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub suite_gates: Option<Vec<Gate>>,
    pub metrics: Metrics,
    /// The order's lags, where topics form a cycle (see `stack::schedule`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub schedule: Option<Schedule>,
    /// Wall times and the renderer: the one part that is not the same for every run of a
    /// scenario and seed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub performance: Option<Value>,
    /// Each node's entry, by key.
    #[serde(flatten)]
    pub nodes: BTreeMap<String, Value>,
}

/// The robot's start and end, in the world frame (x, y, yaw in rad).
#[derive(Debug, Clone, Serialize)]
pub struct Robot {
    pub start: [f64; 3],
    pub final_pose: [f64; 3],
    pub distance_travelled_m: f64,
    pub bump_events: u64,
    pub wheel_drop_steps: u64,
}

/// Where wheel odometry ended, and how far from the truth.
#[derive(Debug, Clone, Serialize)]
pub struct OdometryEnd {
    pub final_pose: [f64; 3],
    pub final_position_error_m: f64,
    pub final_heading_error_deg: f64,
}

/// A laser and the scans it took.
#[derive(Debug, Clone, Serialize)]
pub struct Lidar {
    pub name: String,
    pub preset: String,
    pub scans: u64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub joint: Option<String>,
}

/// A camera and the frames it rendered.
#[derive(Debug, Clone, Serialize)]
pub struct Camera {
    pub name: String,
    pub rgb: [u32; 2],
    pub depth: [u32; 2],
    pub rate_hz: f64,
    pub frames: u64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub joint: Option<String>,
}

/// A joint's angle at the end.
#[derive(Debug, Clone, Serialize)]
pub struct JointEnd {
    pub name: String,
    pub mode: futago_sim::joint::JointMode,
    pub final_angle_deg: f64,
}

/// An agent's pose at the end.
#[derive(Debug, Clone, Serialize)]
pub struct AgentEnd {
    pub name: String,
    pub final_pose: [f64; 3],
}

/// What the order of the nodes leaves: consumers that see a topic one callback late.
#[derive(Debug, Clone, Serialize)]
pub struct Schedule {
    pub lags: Vec<crate::stack::schedule::Lag>,
}

/// A file's digest.
#[derive(Debug, Clone, Serialize)]
pub struct Digest {
    pub sha256: String,
}

impl Summary {
    /// The summary of run `scored` of `s`, listing `files`; without `performance`.
    pub fn new(s: &Scenario, scored: &Scored, files: BTreeMap<String, Digest>) -> Summary {
        let o: &Outcome = &scored.outcome;
        let (t, od) = (o.final_truth, o.final_odometry);
        let versus: Vec<Gate> = s
            .spec
            .gate
            .iter()
            .filter(|g| g.scenario.is_some())
            .cloned()
            .collect();
        Summary {
            scenario: s.spec.name.clone(),
            description: s.spec.description.clone(),
            world: s.world.name.clone(),
            seed: o.seed,
            overlays: s
                .overlays
                .iter()
                .map(|o| o.origin.display().to_string())
                .collect(),
            sim_time_s: o.sim_time,
            physics_rate_hz: s.spec.physics.rate,
            steps: o.steps,
            robot: Robot {
                start: [s.start.x, s.start.y, s.start.theta],
                final_pose: [t.x, t.y, t.theta],
                distance_travelled_m: o.distance_travelled,
                bump_events: o.bump_events,
                wheel_drop_steps: o.wheel_drop_steps,
            },
            odometry: OdometryEnd {
                final_pose: [od.x, od.y, od.theta],
                final_position_error_m: t.distance(&od),
                final_heading_error_deg: futago_msgs::wrap_angle(od.theta - t.theta).to_degrees(),
            },
            lidar: s
                .lidars
                .iter()
                .zip(&o.scans)
                .map(|((c, _), n)| Lidar {
                    name: c.name.clone(),
                    preset: c.preset.name().to_string(),
                    scans: *n,
                    joint: c.joint.clone(),
                })
                .collect(),
            camera: s
                .cameras
                .iter()
                .zip(&o.camera_frames)
                .map(|(c, n)| Camera {
                    name: c.name.clone(),
                    rgb: [c.rgb.width, c.rgb.height],
                    depth: [c.depth.width, c.depth.height],
                    rate_hz: c.rate,
                    frames: *n,
                    joint: c.joint.clone(),
                })
                .collect(),
            laser_rays: o.laser_rays,
            files,
            joints: (!s.movers.joints.is_empty()).then(|| {
                s.movers
                    .joints
                    .iter()
                    .zip(&o.final_joints)
                    .map(|(j, a)| JointEnd {
                        name: j.name.clone(),
                        mode: j.mode,
                        final_angle_deg: a.to_degrees(),
                    })
                    .collect()
            }),
            agents: (!s.movers.agents.is_empty()).then(|| {
                s.movers
                    .agents
                    .iter()
                    .zip(&o.final_agents)
                    .map(|(a, p)| AgentEnd {
                        name: a.name.clone(),
                        final_pose: [p.x, p.y, p.theta],
                    })
                    .collect()
            }),
            gates: scored.gates(s),
            suite_gates: (!versus.is_empty()).then_some(versus),
            metrics: scored.metrics.clone(),
            schedule: (!o.lags.is_empty()).then(|| Schedule {
                lags: o.lags.clone(),
            }),
            performance: None,
            nodes: o.entries.iter().cloned().collect(),
        }
    }

    /// Adds the run's wall times, renderer and real-time factor.
    pub fn with_performance(mut self, o: &Outcome) -> Summary {
        let mut p = o.performance.clone();
        p["renderer"] = serde_json::json!(o.renderer);
        p["wall_time_s"] = serde_json::json!(o.wall_time);
        p["real_time_factor"] = serde_json::json!(if o.wall_time > 0.0 {
            o.sim_time / o.wall_time
        } else {
            0.0
        });
        self.performance = Some(p);
        self
    }

    /// As JSON (sorted keys).
    pub fn to_value(&self) -> Value {
        serde_json::to_value(self).unwrap_or(Value::Null)
    }

    /// The text of `summary.json`.
    pub fn text(&self) -> String {
        serde_json::to_string_pretty(&self.to_value()).unwrap_or_default() + "\n"
    }
}
