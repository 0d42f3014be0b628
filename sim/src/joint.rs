//! Revolute joints on the robot's base that carry sensors: a turntable that spins a vertical
//! laser (seed 004's 3D scanner), a tilt unit that nods a laser or a camera, or a pan unit
//! turned on command.
//!
//! A joint is an axis through a point of the base frame. A sensor mounted on it is written at
//! the joint's zero angle (its `xyz` and `rpy_deg` as on the base); at angle θ its pose on the
//! base is `J(θ) · mount`, where `J(θ)` turns about the axis by θ (right-handed). The joint
//! moves in one of three ways:
//!
//! - `continuous`: at a constant rate, for ever (a turntable);
//! - `oscillate`: back and forth between two angles at a constant rate (a nodding tilt unit);
//! - `command`: towards the last angle the stack asked for, at most at its rate (a pan unit
//!   that stops to scan, as a next-best-view planner drives it).
//!
//! The first two are functions of time alone, so a joint's angle never drifts with the step
//! size; a commanded joint advances by at most `rate · dt` per physics step. The angle is
//! reported like an encoder would, with the robot's sensor stream.

use crate::config::{SpecError, check_name, check_range};
use futago_msgs::Time;
use glam::{Quat, Vec3};
use rapier3d::math::Pose;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// How a joint moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum JointMode {
    /// Turns at `rate_deg` for ever.
    #[default]
    Continuous,
    /// Sweeps between `min_deg` and `max_deg` and back at `rate_deg`.
    Oscillate,
    /// Moves towards the commanded angle at up to `rate_deg`.
    Command,
}

/// A joint as a scenario's `[[joint]]` table declares it.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct JointConfig {
    /// The joint's name, which sensors give as their `joint`.
    pub name: String,
    #[serde(default)]
    pub mode: JointMode,
    /// The rotation axis in the base frame (normalised when read); +z is a turntable turning
    /// counter-clockwise seen from above.
    #[serde(default = "up")]
    pub axis: [f64; 3],
    /// A point on the axis in the base frame, m.
    #[serde(default)]
    pub origin: [f64; 3],
    /// Angular speed, degrees per second (signed for `continuous`: negative turns clockwise).
    pub rate_deg: f64,
    /// The angle at time zero, degrees.
    #[serde(default)]
    pub start_deg: f64,
    /// The sweep's limits (`oscillate`), degrees.
    #[serde(default)]
    pub min_deg: f64,
    #[serde(default)]
    pub max_deg: f64,
}

fn up() -> [f64; 3] {
    [0.0, 0.0, 1.0]
}

impl JointConfig {
    /// Checks every field; errors name `KEY.field`.
    pub fn validate(&self, file: &Path, key: &str) -> Result<(), SpecError> {
        let k = |s: &str| format!("{key}.{s}");
        check_name(file, &k("name"), &self.name)?;
        for (i, v) in self.axis.iter().chain(&self.origin).enumerate() {
            let field = if i < 3 { "axis" } else { "origin" };
            check_range(
                file,
                &k(field),
                *v,
                -100.0,
                100.0,
                "(base-frame coordinates)",
            )?;
        }
        let norm = self.axis.iter().map(|v| v * v).sum::<f64>().sqrt();
        if norm < 1e-6 {
            return Err(SpecError::new(
                file,
                k("axis"),
                "expected a non-zero direction, e.g. [0, 0, 1] for a turntable",
            ));
        }
        let (lo, hi) = match self.mode {
            JointMode::Continuous => (-3600.0, 3600.0),
            _ => (1e-3, 3600.0),
        };
        check_range(
            file,
            &k("rate_deg"),
            self.rate_deg,
            lo,
            hi,
            "degrees per second",
        )?;
        check_range(
            file,
            &k("start_deg"),
            self.start_deg,
            -360.0,
            360.0,
            "degrees",
        )?;
        if self.mode == JointMode::Oscillate {
            check_range(file, &k("min_deg"), self.min_deg, -360.0, 360.0, "degrees")?;
            check_range(
                file,
                &k("max_deg"),
                self.max_deg,
                self.min_deg + 1e-3,
                self.min_deg + 720.0,
                "degrees, above min_deg",
            )?;
            check_range(
                file,
                &k("start_deg"),
                self.start_deg,
                self.min_deg,
                self.max_deg,
                "degrees, within [min_deg, max_deg]",
            )?;
        }
        Ok(())
    }

    /// The unit axis.
    fn unit_axis(&self) -> [f64; 3] {
        let n = self.axis.iter().map(|v| v * v).sum::<f64>().sqrt();
        self.axis.map(|v| v / n)
    }
}

/// A running joint.
#[derive(Debug, Clone)]
pub struct Joint {
    pub config: JointConfig,
    axis: Vec3,
    origin: Vec3,
    /// Current angle, rad.
    angle: f64,
    /// Commanded angle, rad (`command` mode).
    target: f64,
}

impl Joint {
    pub fn new(config: &JointConfig) -> Joint {
        let a = config.unit_axis();
        let o = config.origin;
        let start = config.start_deg.to_radians();
        Joint {
            config: config.clone(),
            axis: Vec3::new(a[0] as f32, a[1] as f32, a[2] as f32),
            origin: Vec3::new(o[0] as f32, o[1] as f32, o[2] as f32),
            angle: start,
            target: start,
        }
    }

    /// The angle, rad: for `continuous` wrapped to (−π, π].
    pub fn angle(&self) -> f64 {
        self.angle
    }

    /// Asks a `command` joint to move to `angle` (rad); other modes ignore it. Returns whether
    /// the joint takes commands.
    pub fn command(&mut self, angle: f64) -> bool {
        if self.config.mode == JointMode::Command && angle.is_finite() {
            self.target = angle;
            true
        } else {
            false
        }
    }

    /// Moves the joint to its state at `now`, `dt` after the previous call.
    pub fn advance(&mut self, now: Time, dt: f64) {
        let c = &self.config;
        let rate = c.rate_deg.to_radians();
        let start = c.start_deg.to_radians();
        let t = now.secs();
        self.angle = match c.mode {
            JointMode::Continuous => futago_msgs::wrap_angle(start + rate * t),
            JointMode::Oscillate => {
                let (lo, hi) = (c.min_deg.to_radians(), c.max_deg.to_radians());
                let span = hi - lo;
                // Distance travelled along the triangle wave, from `lo` going up.
                let s = ((start - lo) + rate * t).rem_euclid(2.0 * span);
                if s <= span { lo + s } else { hi - (s - span) }
            }
            JointMode::Command => {
                let step = rate * dt;
                let e = self.target - self.angle;
                if e.abs() <= step {
                    self.target
                } else {
                    self.angle + step * e.signum()
                }
            }
        };
    }

    /// `J(θ)`: the motion of the joint's frame on the base at the current angle.
    pub fn transform(&self) -> Pose {
        let r = Quat::from_axis_angle(self.axis, self.angle as f32);
        Pose::from_parts(self.origin - r * self.origin, r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn joint(mode: JointMode, rate: f64, start: f64, min: f64, max: f64) -> Joint {
        let c = JointConfig {
            name: "j".into(),
            mode,
            axis: [0.0, 0.0, 2.0],
            origin: [0.1, 0.0, 0.5],
            rate_deg: rate,
            start_deg: start,
            min_deg: min,
            max_deg: max,
        };
        c.validate(Path::new("s.toml"), "joint[0]").unwrap();
        Joint::new(&c)
    }

    #[test]
    fn a_turntable_turns_at_its_rate_about_its_axis() {
        let mut j = joint(JointMode::Continuous, 90.0, 10.0, 0.0, 0.0);
        j.advance(Time::from_secs(1.0), 1.0);
        assert!((j.angle().to_degrees() - 100.0).abs() < 1e-9);
        // A point 1 m ahead of the axis turns to 100° about (0.1, 0, ·), keeping its height.
        let p = j.transform().transform_point(Vec3::new(1.1, 0.0, 0.5));
        let (s, c) = 100f32.to_radians().sin_cos();
        assert!((p - Vec3::new(0.1 + c, s, 0.5)).length() < 1e-5, "{p}");
        // Points on the axis stay put.
        let q = j.transform().transform_point(Vec3::new(0.1, 0.0, 3.0));
        assert!((q - Vec3::new(0.1, 0.0, 3.0)).length() < 1e-5, "{q}");
        j.advance(Time::from_secs(3.0), 2.0);
        assert!((j.angle().to_degrees() - (-80.0)).abs() < 1e-9, "wrapped");
    }

    #[test]
    fn a_tilt_unit_sweeps_between_its_limits() {
        let mut j = joint(JointMode::Oscillate, 20.0, 0.0, -30.0, 30.0);
        for (t, want) in [
            (0.0, 0.0),
            (1.5, 30.0),
            (2.0, 20.0),
            (4.5, -30.0),
            (6.0, 0.0),
        ] {
            j.advance(Time::from_secs(t), 0.005);
            assert!((j.angle().to_degrees() - want).abs() < 1e-9, "t {t}");
        }
    }

    #[test]
    fn a_pan_unit_goes_where_it_is_told_no_faster_than_its_rate() {
        let mut j = joint(JointMode::Command, 45.0, 0.0, 0.0, 0.0);
        assert!(j.command(90f64.to_radians()));
        let dt = 0.01;
        let mut t = 0.0;
        for _ in 0..100 {
            t += dt;
            j.advance(Time::from_secs(t), dt);
        }
        assert!((j.angle().to_degrees() - 45.0).abs() < 1e-9);
        for _ in 0..200 {
            t += dt;
            j.advance(Time::from_secs(t), dt);
        }
        assert_eq!(j.angle(), 90f64.to_radians());
        let mut turntable = joint(JointMode::Continuous, 10.0, 0.0, 0.0, 0.0);
        assert!(!turntable.command(1.0));
    }

    #[test]
    fn bad_joints_are_refused_by_key() {
        let good = joint(JointMode::Oscillate, 20.0, 0.0, -30.0, 30.0).config;
        let p = Path::new("s.toml");
        for (edit, key) in [
            (
                (|c: &mut JointConfig| c.axis = [0.0; 3]) as fn(&mut JointConfig),
                "joint[0].axis",
            ),
            (|c| c.rate_deg = 0.0, "joint[0].rate_deg"),
            (|c| c.rate_deg = f64::NAN, "joint[0].rate_deg"),
            (|c| c.max_deg = c.min_deg, "joint[0].max_deg"),
            (|c| c.start_deg = 45.0, "joint[0].start_deg"),
            (|c| c.origin = [1e300, 0.0, 0.0], "joint[0].origin"),
            (|c| c.name = "a b".into(), "joint[0].name"),
        ] {
            let mut c = good.clone();
            edit(&mut c);
            assert_eq!(c.validate(p, "joint[0]").unwrap_err().key, key);
        }
    }
}
