//! Scripted drive plans: timed velocity segments, and waypoints with a simple follower.
//!
//! These stand in for the autonomy stack in scenarios that only need the robot to move: a
//! controller is updated with what the robot knows (its odometry, and the true pose only when
//! a scenario asks for an oracle) and answers with Create drive commands.

use crate::control::PoseSource;
use crate::control::pursuit::{FollowParams, PathFollower};
use crate::localization::odometry::OdometryIntegrator;
use futago_msgs::{BumpsAndDrops, DriveCommand, Odometry, Pose2, Radius, Time};
use serde::Deserialize;

/// A turning radius as written in a scenario: metres, or `"straight"`, `"ccw"`, `"cw"`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RadiusSpec {
    Metres(f64),
    Named(NamedRadius),
}

/// The special radii of the OI Drive command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NamedRadius {
    Straight,
    Ccw,
    Cw,
}

impl<'de> Deserialize<'de> for RadiusSpec {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl serde::de::Visitor<'_> for V {
            type Value = RadiusSpec;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a radius in m, or \"straight\", \"ccw\" or \"cw\"")
            }
            fn visit_f64<E: serde::de::Error>(self, v: f64) -> Result<RadiusSpec, E> {
                Ok(RadiusSpec::Metres(v))
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<RadiusSpec, E> {
                Ok(RadiusSpec::Metres(v as f64))
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<RadiusSpec, E> {
                Ok(RadiusSpec::Metres(v as f64))
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<RadiusSpec, E> {
                match v {
                    "straight" => Ok(RadiusSpec::Named(NamedRadius::Straight)),
                    "ccw" => Ok(RadiusSpec::Named(NamedRadius::Ccw)),
                    "cw" => Ok(RadiusSpec::Named(NamedRadius::Cw)),
                    other => Err(E::invalid_value(serde::de::Unexpected::Str(other), &self)),
                }
            }
        }
        d.deserialize_any(V)
    }
}

impl serde::Serialize for RadiusSpec {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            RadiusSpec::Metres(m) => s.serialize_f64(*m),
            RadiusSpec::Named(NamedRadius::Straight) => s.serialize_str("straight"),
            RadiusSpec::Named(NamedRadius::Ccw) => s.serialize_str("ccw"),
            RadiusSpec::Named(NamedRadius::Cw) => s.serialize_str("cw"),
        }
    }
}

impl RadiusSpec {
    pub fn radius(self) -> Radius {
        match self {
            RadiusSpec::Metres(r) => Radius::Arc(r),
            RadiusSpec::Named(NamedRadius::Straight) => Radius::Straight,
            RadiusSpec::Named(NamedRadius::Ccw) => Radius::InPlaceCcw,
            RadiusSpec::Named(NamedRadius::Cw) => Radius::InPlaceCw,
        }
    }
}

/// One timed drive command.
#[derive(Debug, Clone, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct Segment {
    /// How long to hold it, s.
    pub duration: f64,
    /// OI Drive velocity, m/s (with `radius`).
    #[serde(default)]
    pub velocity: f64,
    #[serde(default = "straight")]
    pub radius: RadiusSpec,
    /// OI Drive Direct wheel velocities `[left, right]`, m/s, instead of velocity and radius.
    pub wheels: Option<[f64; 2]>,
}

fn straight() -> RadiusSpec {
    RadiusSpec::Named(NamedRadius::Straight)
}

impl Segment {
    fn command(&self) -> DriveCommand {
        match self.wheels {
            Some([left, right]) => DriveCommand::DriveDirect { left, right },
            None => DriveCommand::Drive {
                velocity: self.velocity,
                radius: self.radius.radius(),
            },
        }
    }
}

/// Follower settings.
#[derive(Debug, Clone, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct WaypointConfig {
    /// `[[x, y], …]` in the world frame, m.
    pub waypoints: Vec<[f64; 2]>,
    /// Cruise speed, m/s.
    #[serde(default = "default_speed")]
    pub speed: f64,
    /// Pure-pursuit look-ahead distance, m.
    #[serde(default = "default_lookahead")]
    pub lookahead: f64,
    /// A waypoint counts as reached within this distance, m.
    #[serde(default = "default_tolerance")]
    pub tolerance: f64,
    /// Turn in place when the heading error exceeds this, degrees.
    #[serde(default = "default_turn")]
    pub turn_in_place_deg: f64,
    /// In-place turns stop within this heading error, degrees.
    #[serde(default = "default_turn_tolerance")]
    pub turn_tolerance_deg: f64,
    /// Speed of each wheel in in-place turns, m/s.
    #[serde(default = "default_turn_speed")]
    pub turn_speed: f64,
    /// Drive the list this many times (the last point back to the first between laps).
    #[serde(default = "one")]
    pub laps: u32,
    #[serde(default)]
    pub pose_source: PoseSource,
}

fn default_speed() -> f64 {
    0.3
}
fn default_lookahead() -> f64 {
    0.4
}
fn default_tolerance() -> f64 {
    0.05
}
fn default_turn() -> f64 {
    45.0
}
fn default_turn_tolerance() -> f64 {
    1.0
}
fn default_turn_speed() -> f64 {
    0.1
}
fn one() -> u32 {
    1
}

impl WaypointConfig {
    /// The follower's parameters.
    pub fn follow_params(&self) -> FollowParams {
        FollowParams {
            speed: self.speed,
            lookahead: self.lookahead,
            tolerance: self.tolerance,
            turn_in_place: self.turn_in_place_deg.to_radians(),
            turn_tolerance: self.turn_tolerance_deg.to_radians(),
            turn_speed: self.turn_speed,
            pass: None,
        }
    }
}

/// Timed commands, in order, `repeat` times.
#[derive(Debug, Clone, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct SegmentsConfig {
    pub segments: Vec<Segment>,
    #[serde(default = "one")]
    pub repeat: u32,
}

/// Checks a list of `[x, y]` points: at least one, each coordinate within
/// [`futago_msgs::MAX_COORDINATE`]; the error names `KEY[i]`.
pub fn check_points(key: &str, points: &[[f64; 2]]) -> Result<(), (String, String)> {
    if points.is_empty() {
        return Err((key.into(), "expected at least one [x, y] point".into()));
    }
    let m = futago_msgs::MAX_COORDINATE;
    for (i, p) in points.iter().enumerate() {
        for v in p {
            crate::config::check_ranges("", &[(&format!("{key}[{i}]"), *v, -m, m)])?;
        }
    }
    Ok(())
}

/// A scripted drive plan, as [`ScriptedController`] runs it.
#[derive(Debug, Clone, PartialEq)]
pub enum Script {
    /// Stand still.
    Idle,
    Segments(SegmentsConfig),
    /// Follow waypoints.
    Waypoints(WaypointConfig),
}

impl SegmentsConfig {
    /// Checks values the plan cannot run with; returns `(key, expectation)` on error. Speeds
    /// and radii are those the Create's Open Interface accepts: ±0.5 m/s, radii up to 2 m.
    pub fn validate(&self) -> Result<(), (String, String)> {
        use crate::config::{check_counts, check_ranges};
        let SegmentsConfig { segments, repeat } = self;
        if segments.is_empty() {
            return Err(("segments".into(), "expected at least one segment".into()));
        }
        check_counts("", &[("repeat", *repeat as usize, 1, 1_000_000)])?;
        for (i, s) in segments.iter().enumerate() {
            let k = format!("segments[{i}]");
            check_ranges(
                &k,
                &[
                    ("duration", s.duration, 1e-3, 1e6),
                    ("velocity", s.velocity, -0.5, 0.5),
                ],
            )?;
            for (j, w) in s.wheels.iter().flatten().enumerate() {
                check_ranges(&k, &[(&format!("wheels[{j}]"), *w, -0.5, 0.5)])?;
            }
            if let RadiusSpec::Metres(r) = s.radius
                && !(r.is_finite() && r != 0.0 && r.abs() <= 2.0)
            {
                return Err((
                    format!("{k}.radius"),
                    format!(
                        "expected a radius within ±2 m and not 0, or \"straight\", \"ccw\", \"cw\"; found {r}"
                    ),
                ));
            }
        }
        Ok(())
    }
}

impl WaypointConfig {
    /// Checks values the follower cannot run with; returns `(key, expectation)` on error.
    pub fn validate(&self) -> Result<(), (String, String)> {
        let w = self;
        check_points("waypoints", &w.waypoints)?;
        for (k, v, lo, hi) in [
            ("speed", w.speed, 0.01, 0.5),
            ("lookahead", w.lookahead, 0.01, 10.0),
            ("tolerance", w.tolerance, 0.001, 10.0),
            ("turn_in_place_deg", w.turn_in_place_deg, 1.0, 180.0),
            ("turn_tolerance_deg", w.turn_tolerance_deg, 0.01, 90.0),
            ("turn_speed", w.turn_speed, 0.01, 0.5),
        ] {
            if !(v.is_finite() && v >= lo && v <= hi) {
                return Err((
                    k.to_string(),
                    format!("expected a value in [{lo}, {hi}], found {v}"),
                ));
            }
        }
        if w.laps == 0 {
            return Err(("laps".into(), "expected at least one lap".into()));
        }
        Ok(())
    }
}

/// What a controller is told at each control tick.
#[derive(Debug, Clone, Copy)]
pub struct ControlInput<'a> {
    pub now: Time,
    /// Odometry reports received since the last tick.
    pub odometry: &'a [Odometry],
    pub bumps: BumpsAndDrops,
    /// The true pose, when the scenario grants an oracle.
    pub ground_truth: Option<Pose2>,
    /// The localiser's current pose, when a localiser runs.
    pub localization: Option<Pose2>,
    /// SLAM's current pose, when SLAM runs.
    pub slam: Option<Pose2>,
}

/// A running scripted controller.
#[derive(Debug, Clone)]
pub struct ScriptedController {
    config: Script,
    start: Time,
    odometry: OdometryIntegrator,
    /// Waypoint follower over the expanded route.
    follower: Option<PathFollower>,
    /// Route points per lap (waypoint follower).
    lap_len: usize,
    last: Option<DriveCommand>,
    done: bool,
}

impl ScriptedController {
    /// A controller starting at time `start` from `initial` (the pose dead reckoning starts from).
    pub fn new(config: Script, start: Time, initial: Pose2) -> ScriptedController {
        let follower = match &config {
            Script::Waypoints(w) => {
                // The start is the first point of the route, so that the follower tracks the
                // line to the first waypoint as it does the later ones.
                let mut r = vec![[initial.x, initial.y]];
                for _ in 0..w.laps {
                    r.extend_from_slice(&w.waypoints);
                }
                if w.laps > 1 {
                    r.push(w.waypoints[0]);
                }
                Some(PathFollower::new(w.follow_params(), r))
            }
            _ => None,
        };
        let lap_len = match &config {
            Script::Waypoints(w) => w.waypoints.len(),
            _ => 0,
        };
        ScriptedController {
            config,
            start,
            odometry: OdometryIntegrator::new(initial),
            follower,
            lap_len,
            last: None,
            done: false,
        }
    }

    /// True once the plan is complete (the robot has been told to stop).
    pub fn finished(&self) -> bool {
        self.done
    }

    /// The dead-reckoned pose.
    pub fn odometry_pose(&self) -> Pose2 {
        self.odometry.pose
    }

    /// Index of the waypoint being approached (waypoint follower).
    pub fn progress(&self) -> usize {
        self.follower
            .as_ref()
            .map(|f| f.target().saturating_sub(1))
            .unwrap_or(0)
    }

    /// Laps of the waypoint list completed: the robot has come back to the first waypoint
    /// this many times after leaving it.
    pub fn laps_completed(&self) -> usize {
        match &self.follower {
            // Route index 1 + k·n is the first waypoint of lap k + 1 (the last lap's end is
            // the first waypoint again).
            Some(f) if self.lap_len > 0 => f.target().saturating_sub(2) / self.lap_len,
            _ => 0,
        }
    }

    /// One control tick: returns a command when it differs from the last one sent.
    pub fn update(&mut self, input: &ControlInput) -> Option<DriveCommand> {
        for o in input.odometry {
            self.odometry.integrate(o);
        }
        let cmd = match &self.config {
            // The navigator drives these; as a script they stand still.
            Script::Idle => {
                self.done = true;
                DriveCommand::STOP
            }
            Script::Segments(SegmentsConfig { segments, repeat }) => {
                let mut t = (input.now - self.start).secs();
                let period: f64 = segments.iter().map(|s| s.duration).sum();
                if t >= period * *repeat as f64 {
                    self.done = true;
                    DriveCommand::STOP
                } else {
                    t %= period;
                    let mut cmd = DriveCommand::STOP;
                    for s in segments {
                        if t < s.duration {
                            cmd = s.command();
                            break;
                        }
                        t -= s.duration;
                    }
                    cmd
                }
            }
            Script::Waypoints(w) => {
                let pose = match w.pose_source {
                    PoseSource::Odometry => self.odometry.pose,
                    PoseSource::GroundTruth => input.ground_truth.unwrap_or(self.odometry.pose),
                    PoseSource::Localization => input.localization.unwrap_or(self.odometry.pose),
                    PoseSource::Slam => input.slam.unwrap_or(self.odometry.pose),
                };
                match self.follower.as_mut() {
                    Some(f) => {
                        let cmd = f.command(&pose);
                        self.done = f.done();
                        cmd
                    }
                    None => DriveCommand::STOP,
                }
            }
        };
        if self.last != Some(cmd) {
            self.last = Some(cmd);
            Some(cmd)
        } else {
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tick(c: &mut ScriptedController, t: f64, truth: Pose2) -> Option<DriveCommand> {
        c.update(&ControlInput {
            now: Time::from_secs(t),
            odometry: &[],
            bumps: BumpsAndDrops::default(),
            ground_truth: Some(truth),
            slam: None,
            localization: None,
        })
    }

    #[test]
    fn segments_play_in_order_then_stop() {
        let cfg = Script::Segments(SegmentsConfig {
            segments: vec![
                Segment {
                    duration: 1.0,
                    velocity: 0.2,
                    radius: straight(),
                    wheels: None,
                },
                Segment {
                    duration: 2.0,
                    velocity: 0.1,
                    radius: RadiusSpec::Named(NamedRadius::Ccw),
                    wheels: None,
                },
            ],
            repeat: 1,
        });
        let mut c = ScriptedController::new(cfg, Time::ZERO, Pose2::IDENTITY);
        assert_eq!(
            tick(&mut c, 0.5, Pose2::IDENTITY),
            Some(DriveCommand::Drive {
                velocity: 0.2,
                radius: Radius::Straight
            })
        );
        assert_eq!(
            tick(&mut c, 0.6, Pose2::IDENTITY),
            None,
            "unchanged commands are not resent"
        );
        assert_eq!(
            tick(&mut c, 1.5, Pose2::IDENTITY),
            Some(DriveCommand::Drive {
                velocity: 0.1,
                radius: Radius::InPlaceCcw
            })
        );
        assert!(!c.finished());
        assert_eq!(tick(&mut c, 3.0, Pose2::IDENTITY), Some(DriveCommand::STOP));
        assert!(c.finished());
    }

    #[test]
    fn follower_turns_in_place_toward_a_waypoint_behind_and_arcs_to_one_ahead() {
        let w = WaypointConfig {
            waypoints: vec![[-1.0, 0.0]],
            speed: 0.3,
            lookahead: 0.4,
            tolerance: 0.05,
            turn_in_place_deg: 45.0,
            turn_tolerance_deg: 1.0,
            turn_speed: 0.1,
            laps: 1,
            pose_source: PoseSource::GroundTruth,
        };
        let mut c =
            ScriptedController::new(Script::Waypoints(w.clone()), Time::ZERO, Pose2::IDENTITY);
        match tick(&mut c, 0.0, Pose2::new(0.0, 0.0, 0.1)) {
            Some(DriveCommand::Drive {
                radius: Radius::InPlaceCcw,
                ..
            }) => {}
            other => panic!("expected a left turn in place, got {other:?}"),
        }
        let mut w2 = w.clone();
        w2.waypoints = vec![[1.0, 0.5]];
        let mut c = ScriptedController::new(Script::Waypoints(w2), Time::ZERO, Pose2::IDENTITY);
        match tick(&mut c, 0.0, Pose2::IDENTITY) {
            // The aim point is 0.4 m along the line to (1, 0.5), at bearing φ = atan(0.5); the
            // circle through it tangent to +x has R = 0.4 / (2 sin φ).
            Some(DriveCommand::Drive {
                velocity,
                radius: Radius::Arc(r),
            }) => {
                assert!(velocity > 0.0);
                let expected = 0.4 / (2.0 * 0.5f64.atan().sin());
                assert!((r - expected).abs() < 1e-3, "{r} vs {expected}");
            }
            other => panic!("expected an arc, got {other:?}"),
        }
        // Gentler than the OI's 2 m limit: wheel speeds, the right one faster for a left arc.
        let mut w3 = w.clone();
        w3.waypoints = vec![[3.0, 0.1]];
        let mut c3 = ScriptedController::new(Script::Waypoints(w3), Time::ZERO, Pose2::IDENTITY);
        match tick(&mut c3, 0.0, Pose2::new(0.0, -0.005, 0.0)) {
            Some(DriveCommand::DriveDirect { left, right }) => {
                assert!(right > left && left > 0.0, "{left} {right}")
            }
            other => panic!("expected wheel speeds, got {other:?}"),
        }
        // Reached: stop and finish.
        assert_eq!(
            tick(&mut c, 1.0, Pose2::new(1.0, 0.5, 0.0)),
            Some(DriveCommand::STOP)
        );
        assert!(c.finished());
    }
}
