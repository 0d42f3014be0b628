//! Moving bodies besides the robot: upright cylinders (people, carts) that walk a path.
//!
//! An agent is a kinematic rapier body: it follows its path whatever it touches, pushes the
//! robot and boxes it walks into (and so presses the robot's bumpers), and is seen by every
//! laser ray and every camera like any other body. Its pose is a function of time alone (the
//! distance walked is `speed · (t − start_time)` along the path), so its ground truth is exact
//! and independent of the step size.
//!
//! Path modes: `loop` walks the closed polygon of the points for ever, `back_and_forth`
//! walks the open polyline to its end and back, and `once` walks it once and stands at the
//! end. The agent faces where it walks.

use crate::config::{SpecError, check_name, check_range};
use crate::world::MAX_EXTENT;
use futago_msgs::{Pose2, Time};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// How an agent walks its path.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum PathMode {
    /// Round the closed polygon for ever.
    #[default]
    Loop,
    /// To the end and back, for ever.
    BackAndForth,
    /// To the end, then stand.
    Once,
}

/// An agent as a scenario's `[[agent]]` table declares it.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct AgentConfig {
    pub name: String,
    /// `[[x, y], …]` in the world frame, m; at least two distinct points.
    pub path: Vec<[f64; 2]>,
    /// Walking speed, m/s (people walk at about 1.2–1.4 m/s).
    pub speed: f64,
    #[serde(default)]
    pub mode: PathMode,
    /// Stands at the first point until this time, s.
    #[serde(default)]
    pub start_time: f64,
    /// The body's radius, m (an adult's shoulders: about 0.25).
    #[serde(default = "radius")]
    pub radius: f64,
    /// The body's height, m.
    #[serde(default = "height")]
    pub height: f64,
    /// sRGB colour in [0, 1].
    #[serde(default = "colour")]
    pub color: [f64; 3],
    /// Radius of the arcs that round the path's corners, m (0: turns on the spot). Where
    /// the legs are short the arc shrinks to end at their midpoints. The corner a loop closes
    /// on (its first point) stays sharp.
    #[serde(default)]
    pub turn_radius: f64,
}

fn radius() -> f64 {
    0.25
}
fn height() -> f64 {
    1.7
}
fn colour() -> [f64; 3] {
    [0.55, 0.35, 0.3]
}

impl AgentConfig {
    /// Checks every field; errors name `KEY.field`.
    pub fn validate(&self, file: &Path, key: &str) -> Result<(), SpecError> {
        let k = |s: &str| format!("{key}.{s}");
        check_name(file, &k("name"), &self.name)?;
        if self.path.len() < 2 || self.path.len() > 10_000 {
            return Err(SpecError::new(
                file,
                k("path"),
                format!(
                    "expected 2 to 10000 [x, y] points, found {}",
                    self.path.len()
                ),
            ));
        }
        for (i, p) in self.path.iter().enumerate() {
            for v in p {
                check_range(
                    file,
                    &format!("{key}.path[{i}]"),
                    *v,
                    -(MAX_EXTENT as f64),
                    MAX_EXTENT as f64,
                    "m, within the world's extent",
                )?;
            }
        }
        if self.length() < 1e-6 {
            return Err(SpecError::new(
                file,
                k("path"),
                "expected at least two distinct points",
            ));
        }
        check_range(file, &k("speed"), self.speed, 0.0, 10.0, "m/s")?;
        check_range(file, &k("start_time"), self.start_time, 0.0, 1e6, "s")?;
        check_range(file, &k("radius"), self.radius, 0.01, 5.0, "m")?;
        check_range(file, &k("height"), self.height, 0.01, 10.0, "m")?;
        check_range(file, &k("turn_radius"), self.turn_radius, 0.0, 100.0, "m")?;
        for c in self.color {
            check_range(file, &k("color"), c, 0.0, 1.0, "(sRGB in [0, 1])")?;
        }
        Ok(())
    }

    /// The points walked, in order, for one pass: closed for `loop`, the corners rounded.
    fn legs(&self) -> Vec<[f64; 2]> {
        let mut p = self.path.clone();
        if self.mode == PathMode::Loop {
            p.push(self.path[0]);
        }
        if self.turn_radius > 0.0 {
            p = round_corners(&p, self.turn_radius);
        }
        p
    }

    /// Length of one pass, m.
    fn length(&self) -> f64 {
        self.legs()
            .windows(2)
            .map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]))
            .sum()
    }

    /// The agent's pose at `t`: on its path, facing along it.
    pub fn pose_at(&self, t: Time) -> Pose2 {
        let legs = self.legs();
        let total = self.length();
        let walked = (self.speed * (t.secs() - self.start_time)).max(0.0);
        let (mut s, backwards) = match self.mode {
            PathMode::Loop => (walked % total, false),
            PathMode::Once => (walked.min(total), false),
            PathMode::BackAndForth => {
                let s = walked % (2.0 * total);
                if s <= total {
                    (s, false)
                } else {
                    (2.0 * total - s, true)
                }
            }
        };
        // The leg that holds arc length `s`; zero-length legs are skipped.
        let mut last = Pose2::new(legs[0][0], legs[0][1], 0.0);
        for w in legs.windows(2) {
            let (dx, dy) = (w[1][0] - w[0][0], w[1][1] - w[0][1]);
            let len = dx.hypot(dy);
            if len < 1e-12 {
                continue;
            }
            let heading = if backwards {
                dy.atan2(dx) + std::f64::consts::PI
            } else {
                dy.atan2(dx)
            };
            let heading = futago_msgs::wrap_angle(heading);
            if s <= len {
                let f = s / len;
                return Pose2::new(w[0][0] + f * dx, w[0][1] + f * dy, heading);
            }
            s -= len;
            last = Pose2::new(w[1][0], w[1][1], heading);
        }
        last
    }
}

/// Largest turn of one chord of a rounded corner, rad (2°).
const ARC_STEP: f64 = 0.035;

/// The polyline `p` with each interior corner replaced by a circular arc of radius `r`
/// (chords of at most [`ARC_STEP`] of turn), tangent to both legs; the arc shrinks where a
/// leg is shorter than twice its tangent length.
fn round_corners(p: &[[f64; 2]], r: f64) -> Vec<[f64; 2]> {
    let mut out = vec![p[0]];
    for i in 1..p.len().saturating_sub(1) {
        let (a, b, c) = (p[i - 1], p[i], p[i + 1]);
        let (l1, l2) = (
            (b[0] - a[0]).hypot(b[1] - a[1]),
            (c[0] - b[0]).hypot(c[1] - b[1]),
        );
        if l1 < 1e-9 || l2 < 1e-9 {
            out.push(b);
            continue;
        }
        let d1 = [(b[0] - a[0]) / l1, (b[1] - a[1]) / l1];
        let d2 = [(c[0] - b[0]) / l2, (c[1] - b[1]) / l2];
        let cross = d1[0] * d2[1] - d1[1] * d2[0];
        let turn = cross.atan2(d1[0] * d2[0] + d1[1] * d2[1]);
        if turn.abs() < 1e-6 || turn.abs() > std::f64::consts::PI - 1e-3 {
            out.push(b);
            continue;
        }
        let half = (turn.abs() / 2.0).tan();
        let t = (r * half).min(l1 / 2.0).min(l2 / 2.0);
        let radius = t / half;
        // The arc's centre is on the inside of the turn, `radius` from the first tangent point.
        let start = [b[0] - d1[0] * t, b[1] - d1[1] * t];
        let side = turn.signum();
        let centre = [
            start[0] - side * d1[1] * radius,
            start[1] + side * d1[0] * radius,
        ];
        let a0 = (start[1] - centre[1]).atan2(start[0] - centre[0]);
        let steps = (turn.abs() / ARC_STEP).ceil().max(1.0) as usize;
        for s in 0..=steps {
            let ang = a0 + turn * s as f64 / steps as f64;
            out.push([
                centre[0] + radius * ang.cos(),
                centre[1] + radius * ang.sin(),
            ]);
        }
    }
    out.push(p[p.len() - 1]);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn agent(mode: PathMode) -> AgentConfig {
        AgentConfig {
            name: "a".into(),
            path: vec![[0.0, 0.0], [4.0, 0.0], [4.0, 3.0]],
            speed: 1.0,
            mode,
            start_time: 1.0,
            radius: radius(),
            height: height(),
            color: colour(),
            turn_radius: 0.0,
        }
    }

    /// A right-angle corner rounded with a 1 m arc: the path leaves the first leg 1 m before
    /// the corner, stays 1 m from the arc's centre, turns its heading smoothly (no chord turns
    /// more than 2°), and is shorter than the sharp path by 2 − π/2 m.
    #[test]
    fn rounded_corners_are_arcs_tangent_to_both_legs() {
        let mut a = agent(PathMode::Once);
        a.start_time = 0.0;
        a.turn_radius = 1.0;
        a.validate(Path::new("s.toml"), "agent[0]").unwrap();
        let sharp = 7.0;
        assert!((a.length() - (sharp - 2.0 + std::f64::consts::FRAC_PI_2)).abs() < 1e-3);
        let t = Time::from_secs;
        let p = a.pose_at(t(2.9));
        assert!(
            (p.x - 2.9).abs() < 1e-9 && p.y == 0.0 && p.theta == 0.0,
            "{p:?}"
        );
        let mut last = a.pose_at(t(0.0));
        for i in 1..=700 {
            let p = a.pose_at(t(i as f64 * 0.01));
            if p.x > 3.0 && p.y < 1.0 {
                let r = (p.x - 3.0).hypot(p.y - 1.0);
                assert!((r - 1.0).abs() < 1e-3, "{p:?} is {r} m from the centre");
            }
            let turn = futago_msgs::wrap_angle(p.theta - last.theta).abs();
            assert!(turn <= ARC_STEP + 1e-9, "heading jumps {turn} at {p:?}");
            last = p;
        }
        // Legs shorter than twice the tangent length shrink the arc to their midpoints.
        a.path = vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]];
        let p = round_corners(&a.path, 5.0);
        assert!(
            (p[1][0] - 0.5).abs() < 1e-9 && p[1][1].abs() < 1e-9,
            "{:?}",
            p[1]
        );
        let end = p[p.len() - 2];
        assert!(
            (end[0] - 1.0).abs() < 1e-9 && (end[1] - 0.5).abs() < 1e-9,
            "{end:?}"
        );
    }

    #[test]
    fn agents_walk_their_paths_at_their_speed() {
        let t = Time::from_secs;
        let a = agent(PathMode::Loop);
        a.validate(Path::new("s.toml"), "agent[0]").unwrap();
        assert_eq!(a.pose_at(t(0.5)), Pose2::new(0.0, 0.0, 0.0), "waits");
        assert_eq!(a.pose_at(t(3.0)), Pose2::new(2.0, 0.0, 0.0));
        let p = a.pose_at(t(7.0)); // 6 m: 2 m up the second leg
        assert!(
            (p.x - 4.0).abs() < 1e-12 && (p.y - 2.0).abs() < 1e-12,
            "{p:?}"
        );
        assert!((p.theta - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        // The closing leg (5 m, from (4, 3) back to the start); the loop is 12 m.
        let p = a.pose_at(t(1.0 + 7.0 + 2.5));
        assert!(
            (p.x - 2.0).abs() < 1e-9 && (p.y - 1.5).abs() < 1e-9,
            "{p:?}"
        );
        assert_eq!(a.pose_at(t(13.0 + 3.0)), a.pose_at(t(1.0 + 3.0)));

        let b = agent(PathMode::BackAndForth);
        let p = b.pose_at(t(1.0 + 7.0 + 1.0)); // 8 m: 1 m back down the 7 m path
        assert!(
            (p.x - 4.0).abs() < 1e-12 && (p.y - 2.0).abs() < 1e-12,
            "{p:?}"
        );
        assert!(
            (p.theta + std::f64::consts::FRAC_PI_2).abs() < 1e-12,
            "faces back"
        );

        let o = agent(PathMode::Once);
        assert_eq!(o.pose_at(t(100.0)).x, 4.0);
        assert_eq!(o.pose_at(t(100.0)).y, 3.0);
    }

    #[test]
    fn bad_agents_are_refused_by_key() {
        let p = Path::new("s.toml");
        for (edit, key) in [
            (
                (|c: &mut AgentConfig| c.path.truncate(1)) as fn(&mut AgentConfig),
                "agent[0].path",
            ),
            (|c| c.path = vec![[1.0, 1.0]; 3], "agent[0].path"),
            (|c| c.path[1][0] = 1e300, "agent[0].path[1]"),
            (|c| c.speed = -1.0, "agent[0].speed"),
            (|c| c.radius = f64::NAN, "agent[0].radius"),
            (|c| c.color[2] = 2.0, "agent[0].color"),
        ] {
            let mut c = agent(PathMode::Loop);
            edit(&mut c);
            assert_eq!(c.validate(p, "agent[0]").unwrap_err().key, key);
        }
    }
}
