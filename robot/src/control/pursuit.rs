//! Seed 000's look-ahead arc controller (written for futago): follows a polyline by aiming at
//! the point a look-ahead distance further along it and commanding the Create the circle
//! through the robot and that point tangent to its heading (pure pursuit, R = L² / 2y), and
//! turns in place where the aim lies too far off the heading (sharp corners, U-turns). A point
//! is reached within a tolerance of it or, for routes whose every point must be driven to
//! (a coverage route's lane ends, [`FollowParams::pass`]), once passed along its segment.

use futago_msgs::{DriveCommand, Pose2, Radius, wrap_angle};

/// The Create's nominal wheel base, m (libcreate), for turning arcs into wheel speeds.
pub const CREATE_WHEEL_BASE: f64 = 0.258;

/// Follower parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FollowParams {
    /// Cruise speed, m/s.
    pub speed: f64,
    /// Look-ahead distance along the path, m.
    pub lookahead: f64,
    /// A path point counts as reached within this distance, m.
    pub tolerance: f64,
    /// Turn in place when the aim's bearing exceeds this, rad.
    pub turn_in_place: f64,
    /// In-place turns stop within this bearing, rad.
    pub turn_tolerance: f64,
    /// Speed of each wheel in in-place turns, m/s.
    pub turn_speed: f64,
    /// Where every point must be driven to (a coverage route's lane ends): a point then also
    /// counts as reached once the robot, within `tolerance` of the segment leading to it, is
    /// no more than this short of it along the segment, m. Without it a point is reached
    /// anywhere within `tolerance` of it, which ends a lane `tolerance` short and cuts the
    /// corner to the next lane.
    pub pass: Option<f64>,
}

/// Follows one polyline.
#[derive(Debug, Clone)]
pub struct PathFollower {
    params: FollowParams,
    path: Vec<[f64; 2]>,
    /// Index of the path point being approached.
    target: usize,
    turning: bool,
}

impl PathFollower {
    /// Follows `path` from its first point (normally where the robot is).
    pub fn new(params: FollowParams, path: Vec<[f64; 2]>) -> PathFollower {
        PathFollower {
            params,
            path,
            target: 1,
            turning: false,
        }
    }

    /// Index of the path point being approached (0 before the first, `len` when done).
    pub fn target(&self) -> usize {
        self.target
    }

    pub fn path(&self) -> &[[f64; 2]] {
        &self.path
    }

    /// Distance from `pose` to the segment being followed, m.
    pub fn distance_from_path(&self, pose: &Pose2) -> f64 {
        if self.done() {
            return 0.0;
        }
        let (a, b) = (self.path[self.target - 1], self.path[self.target]);
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        let len2 = (dx * dx + dy * dy).max(1e-12);
        let t = (((pose.x - a[0]) * dx + (pose.y - a[1]) * dy) / len2).clamp(0.0, 1.0);
        (pose.x - a[0] - t * dx).hypot(pose.y - a[1] - t * dy)
    }

    /// Counts the point being approached as reached (a caller that knows better than the
    /// pose, such as a laser that finds the wall a route point lies against).
    pub fn advance(&mut self) {
        if !self.done() {
            self.target += 1;
            self.turning = true;
        }
    }

    /// True once the last point is reached.
    pub fn done(&self) -> bool {
        self.target >= self.path.len()
    }

    /// Whether the point being approached counts as reached from `pose` (see
    /// [`FollowParams::pass`]).
    fn reached(&self, pose: &Pose2) -> bool {
        let w = &self.params;
        let b = self.path[self.target];
        let dist = (b[0] - pose.x).hypot(b[1] - pose.y);
        let Some(pass) = w.pass else {
            return dist <= w.tolerance;
        };
        let a = self.path[self.target - 1];
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        let len = dx.hypot(dy);
        if len < 1e-9 {
            return dist <= w.tolerance;
        }
        let (px, py) = (pose.x - a[0], pose.y - a[1]);
        let short = len - (px * dx + py * dy) / len;
        let across = (px * dy - py * dx).abs() / len;
        dist <= pass || (short <= pass && across <= w.tolerance)
    }

    /// The command for the robot at `pose`; `STOP` once the path is done.
    pub fn command(&mut self, pose: &Pose2) -> DriveCommand {
        let w = self.params;
        // Advance past reached points.
        while self.target < self.path.len() && self.reached(pose) {
            self.target += 1;
            self.turning = true;
        }
        if self.done() {
            return DriveCommand::STOP;
        }
        let goal = self.path[self.target];
        let dist = (goal[0] - pose.x).hypot(goal[1] - pose.y);
        // Aim point: the goal, or a point `lookahead` along the segment from the previous one.
        let aim = if dist <= w.lookahead {
            goal
        } else {
            let prev = self.path[self.target - 1];
            let (dx, dy) = (goal[0] - prev[0], goal[1] - prev[1]);
            let len = dx.hypot(dy).max(1e-9);
            let s = (((pose.x - prev[0]) * dx + (pose.y - prev[1]) * dy) / len).clamp(0.0, len);
            let s = (s + w.lookahead).min(len);
            [prev[0] + dx / len * s, prev[1] + dy / len * s]
        };
        let local = pose.inverse().transform_point(aim);
        let err = wrap_angle(local[1].atan2(local[0]));
        if self.turning || err.abs() > w.turn_in_place {
            self.turning = err.abs() > w.turn_tolerance;
            if self.turning {
                // Slow down near the end of the turn so as not to overshoot.
                let v = w.turn_speed.min(0.02 + err.abs() * 0.2);
                let radius = if err > 0.0 {
                    Radius::InPlaceCcw
                } else {
                    Radius::InPlaceCw
                };
                return DriveCommand::Drive {
                    velocity: (v * 1000.0).round() / 1000.0,
                    radius,
                };
            }
        }
        let speed = w.speed.min(0.05 + dist); // ease in to the last point
        arc_command(speed, local)
    }
}

/// Pure pursuit: the Create command for the circle through the robot and `aim` (robot
/// frame), tangent to its heading, at `speed`.
pub fn arc_command(speed: f64, aim: [f64; 2]) -> DriveCommand {
    let l2 = aim[0] * aim[0] + aim[1] * aim[1];
    let speed = (speed * 1000.0).round() / 1000.0;
    let curvature = 2.0 * aim[1] / l2.max(1e-12);
    if curvature.abs() < 1e-4 {
        return DriveCommand::Drive {
            velocity: speed,
            radius: Radius::Straight,
        };
    }
    // The OI's Drive takes radii up to 2 m; gentler arcs go out as Drive Direct wheel speeds.
    // Both are quantised to whole millimetres, as the OI's integer fields are.
    let r = 1.0 / curvature;
    if r.abs() <= 2.0 {
        DriveCommand::Drive {
            velocity: speed,
            radius: Radius::Arc((r * 1000.0).round() / 1000.0),
        }
    } else {
        let half = curvature * CREATE_WHEEL_BASE / 2.0;
        let q = |v: f64| (v * 1000.0).round() / 1000.0;
        DriveCommand::DriveDirect {
            left: q(speed * (1.0 - half)),
            right: q(speed * (1.0 + half)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use futago_msgs::Radius;

    fn params(pass: Option<f64>) -> FollowParams {
        FollowParams {
            speed: 0.3,
            lookahead: 0.35,
            tolerance: 0.15,
            turn_in_place: 45f64.to_radians(),
            turn_tolerance: 8f64.to_radians(),
            turn_speed: 0.12,
            pass,
        }
    }

    /// Drives a unicycle on the follower's commands (their wheel speeds, exactly) along a 2 m
    /// lane and returns where it was when the follower counted the lane's end as reached.
    fn pose_at_corner(pass: Option<f64>) -> Pose2 {
        // A lane 2 m along x, then a side step of 0.3 m to the next lane.
        let path = vec![[0.0, 0.0], [2.0, 0.0], [2.0, 0.3], [0.0, 0.3]];
        let mut f = PathFollower::new(params(pass), path);
        let mut pose = Pose2::new(0.0, 0.0, 0.0);
        let dt = 0.015;
        for _ in 0..20_000 {
            let cmd = f.command(&pose);
            if f.target() == 2 {
                return pose;
            }
            let (l, r) = match cmd {
                DriveCommand::Drive { velocity, radius } => match radius {
                    Radius::Straight => (velocity, velocity),
                    Radius::InPlaceCcw => (-velocity, velocity),
                    Radius::InPlaceCw => (velocity, -velocity),
                    Radius::Arc(rad) => {
                        let h = CREATE_WHEEL_BASE / 2.0;
                        (velocity * (rad - h) / rad, velocity * (rad + h) / rad)
                    }
                },
                DriveCommand::DriveDirect { left, right } => (left, right),
            };
            let v = (l + r) / 2.0;
            let w = (r - l) / CREATE_WHEEL_BASE;
            pose = Pose2::new(
                pose.x + v * pose.theta.cos() * dt,
                pose.y + v * pose.theta.sin() * dt,
                pose.theta + w * dt,
            );
        }
        panic!("the corner was never reached");
    }

    #[test]
    fn a_lane_is_driven_to_its_end_when_points_must_be_passed() {
        // Reached by distance, the lane ends a tolerance (0.15 m) short of its end...
        let loose = pose_at_corner(None);
        assert!((2.0 - loose.x - 0.15).abs() < 0.01, "{loose:?}");
        // ...passed along the segment, within 2 cm of it.
        let tight = pose_at_corner(Some(0.02));
        assert!(2.0 - tight.x <= 0.02 + 1e-9, "{tight:?}");
        assert!(tight.y.abs() < 0.01, "{tight:?}");
    }
}
