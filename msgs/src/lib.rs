//! Messages exchanged between a robot (simulated or real) and the futago robot stack.
//!
//! This crate is the only thing the simulator (`futago-sim`) and the autonomy stack
//! (`futago-robot`) have in common: the stack sees sensor messages and emits commands,
//! so the same stack runs on the simulator and on logs of real robots.
//!
//! Conventions (ROS REP 103): SI units, right-handed frames, x forward, y left, z up,
//! angles in radians. Time is simulation (or log) time in integer nanoseconds.

pub mod camera;
pub mod carmen;
pub mod datasets;
pub mod grid;
pub mod landmarks;
pub mod map_server;
pub mod pedestrians;
pub mod ply;
pub mod profile;
pub mod ros2msg;
pub mod rosbag;
pub mod rosbag2;
pub mod tum;

use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// A point in time, in integer nanoseconds since the start of a run (or the log's epoch).
///
/// Integer time keeps sensor schedules exact over long runs (no drift from summing
/// floating-point periods), which the determinism guarantee relies on.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize,
)]
pub struct Time(pub i64);

impl Time {
    /// Time zero.
    pub const ZERO: Time = Time(0);

    /// Time from seconds, rounded to the nearest nanosecond.
    pub fn from_secs(s: f64) -> Time {
        Time((s * 1e9).round() as i64)
    }

    /// Seconds as a float.
    pub fn secs(self) -> f64 {
        self.0 as f64 * 1e-9
    }

    /// Nanoseconds.
    pub fn nanos(self) -> i64 {
        self.0
    }
}

impl std::ops::Add<Duration> for Time {
    type Output = Time;
    fn add(self, d: Duration) -> Time {
        Time(self.0 + d.0)
    }
}

impl std::ops::Sub for Time {
    type Output = Duration;
    fn sub(self, o: Time) -> Duration {
        Duration(self.0 - o.0)
    }
}

/// A span of time in integer nanoseconds.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize,
)]
pub struct Duration(pub i64);

impl Duration {
    /// Duration from seconds, rounded to the nearest nanosecond.
    pub fn from_secs(s: f64) -> Duration {
        Duration((s * 1e9).round() as i64)
    }

    /// Seconds as a float.
    pub fn secs(self) -> f64 {
        self.0 as f64 * 1e-9
    }
}

/// The largest coordinate a log, trajectory or world may hold, m: 10 km from the origin
/// keeps f64 and f32 positions to the millimetre and every grid over them bounded.
pub const MAX_COORDINATE: f64 = 1e4;

/// The largest timestamp a log may hold, s (|t|; the year 2096 in Unix time): differences of
/// such stamps fit [`Time`]'s nanoseconds.
pub const MAX_STAMP: f64 = 4e9;

/// Checks a coordinate read from a file: `None` when it is not finite or beyond
/// [`MAX_COORDINATE`].
pub fn bounded_coordinate(v: f64) -> Option<f64> {
    (v.is_finite() && v.abs() <= MAX_COORDINATE).then_some(v)
}

/// Checks a timestamp read from a file: `None` when it is not finite or beyond
/// [`MAX_STAMP`].
pub fn bounded_stamp(v: f64) -> Option<f64> {
    (v.is_finite() && v.abs() <= MAX_STAMP).then_some(v)
}

/// A number as an error message shows it: plainly, or in scientific notation when it is huge
/// or tiny (`1e300`, not three hundred digits).
pub fn shown(v: f64) -> String {
    if v != 0.0 && v.is_finite() && !(1e-6..1e9).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

/// Wraps an angle to (-π, π].
pub fn wrap_angle(a: f64) -> f64 {
    let mut a = a % (2.0 * PI);
    if a > PI {
        a -= 2.0 * PI;
    } else if a <= -PI {
        a += 2.0 * PI;
    }
    a
}

/// A planar pose: position (m) and heading (rad, counter-clockwise from +x).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Pose2 {
    pub x: f64,
    pub y: f64,
    pub theta: f64,
}

/// A planar rigid transform with its rotation's cosine and sine at hand ([`Pose2::transform`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Transform2 {
    pub x: f64,
    pub y: f64,
    pub cos: f64,
    pub sin: f64,
}

impl Transform2 {
    /// The point `p` of the child frame in the parent frame.
    pub fn apply(&self, p: [f64; 2]) -> [f64; 2] {
        [
            self.x + self.cos * p[0] - self.sin * p[1],
            self.y + self.sin * p[0] + self.cos * p[1],
        ]
    }
}

impl Pose2 {
    /// The identity pose.
    pub const IDENTITY: Pose2 = Pose2 {
        x: 0.0,
        y: 0.0,
        theta: 0.0,
    };

    pub fn new(x: f64, y: f64, theta: f64) -> Pose2 {
        Pose2 { x, y, theta }
    }

    /// `self ⊕ other`: `other` expressed in the frame of `self`, brought to the parent frame.
    pub fn compose(&self, other: &Pose2) -> Pose2 {
        let (s, c) = self.theta.sin_cos();
        Pose2 {
            x: self.x + c * other.x - s * other.y,
            y: self.y + s * other.x + c * other.y,
            theta: wrap_angle(self.theta + other.theta),
        }
    }

    /// The inverse transform.
    pub fn inverse(&self) -> Pose2 {
        let (s, c) = self.theta.sin_cos();
        Pose2 {
            x: -c * self.x - s * self.y,
            y: s * self.x - c * self.y,
            theta: wrap_angle(-self.theta),
        }
    }

    /// `self⁻¹ ⊕ other`: the pose of `other` relative to `self`.
    pub fn between(&self, other: &Pose2) -> Pose2 {
        self.inverse().compose(other)
    }

    /// Transforms a point from this pose's frame to the parent frame.
    pub fn transform_point(&self, p: [f64; 2]) -> [f64; 2] {
        self.transform().apply(p)
    }

    /// The transform from this pose's frame to the parent frame, its heading's sine and
    /// cosine taken once: for many points, the same values as
    /// [`transform_point`](Self::transform_point) on each.
    pub fn transform(&self) -> Transform2 {
        let (s, c) = self.theta.sin_cos();
        Transform2 {
            x: self.x,
            y: self.y,
            cos: c,
            sin: s,
        }
    }

    /// Turns a vector (a velocity, a direction) from this pose's frame to the parent frame:
    /// [`transform_point`](Self::transform_point) without the translation.
    pub fn rotate_vector(&self, v: [f64; 2]) -> [f64; 2] {
        let (s, c) = self.theta.sin_cos();
        [c * v[0] - s * v[1], s * v[0] + c * v[1]]
    }

    /// Euclidean distance between the positions of two poses.
    pub fn distance(&self, other: &Pose2) -> f64 {
        (self.x - other.x).hypot(self.y - other.y)
    }

    /// The pose a fraction `f` of the way from `self` to `other`: the position linearly, the
    /// heading along the shorter arc.
    pub fn lerp(&self, other: &Pose2, f: f64) -> Pose2 {
        Pose2::new(
            self.x + f * (other.x - self.x),
            self.y + f * (other.y - self.y),
            wrap_angle(self.theta + f * wrap_angle(other.theta - self.theta)),
        )
    }
}

/// How [`pose_at`] answers for a time outside a trajectory.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Outside {
    /// No pose: a metric must not invent one.
    None,
    /// The nearest end's pose: a sensor stamped just past the last odometry report.
    Clamp,
}

/// The pose at `t` in a trajectory sorted by time: a sample's own pose at its stamp, else
/// [`Pose2::lerp`] between the samples around `t`. The one pose interpolation of the project:
/// the relations metric, the log readers and the run loop's odometry history all use it.
pub fn pose_at(traj: &[(Time, Pose2)], t: Time, outside: Outside) -> Option<Pose2> {
    let k = traj.partition_point(|s| s.0 < t);
    if k < traj.len() && traj[k].0 == t {
        return Some(traj[k].1);
    }
    if k == 0 || k == traj.len() {
        return match outside {
            Outside::None => None,
            Outside::Clamp => traj.get(k.saturating_sub(1)).map(|s| s.1),
        };
    }
    let ((t0, a), (t1, b)) = (traj[k - 1], traj[k]);
    Some(a.lerp(&b, (t - t0).secs() / (t1 - t0).secs()))
}

/// A 3D pose: translation (m) and unit quaternion `[x, y, z, w]`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Pose3 {
    pub translation: [f64; 3],
    pub rotation: [f64; 4],
}

impl Pose3 {
    /// Lifts a planar pose to 3D at height `z`.
    pub fn from_pose2(p: &Pose2, z: f64) -> Pose3 {
        let (s, c) = (p.theta * 0.5).sin_cos();
        Pose3 {
            translation: [p.x, p.y, z],
            rotation: [0.0, 0.0, s, c],
        }
    }

    /// A point of this pose's frame in the parent frame: rotated by the (unit) quaternion,
    /// then translated (`v + 2w(q×v) + 2q×(q×v)`, `q` the vector part).
    pub fn transform_point(&self, p: [f64; 3]) -> [f64; 3] {
        let [x, y, z, w] = self.rotation;
        let cross = |a: [f64; 3], b: [f64; 3]| {
            [
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ]
        };
        let q = [x, y, z];
        let t = cross(q, p).map(|c| 2.0 * c);
        let u = cross(q, t);
        std::array::from_fn(|i| p[i] + w * t[i] + u[i] + self.translation[i])
    }

    /// Projects onto the ground plane: x, y and the yaw (rotation about z) of the orientation.
    pub fn to_pose2(&self) -> Pose2 {
        let [x, y, z, w] = self.rotation;
        let yaw = (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z));
        Pose2::new(self.translation[0], self.translation[1], yaw)
    }
}

/// One laser scan, in the conventions of ROS `sensor_msgs/LaserScan`.
///
/// Beam `i` points at `angle_min + i·angle_increment` in the laser frame and was measured at
/// `stamp + i·time_increment`. A range of `+∞` is a beam with no return (beyond
/// `range_max`, or a dropout); `-∞` is a return closer than `range_min` (REP 117).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LaserScan {
    /// Name of the laser (its frame), e.g. `front`.
    pub frame: String,
    /// Time of the first beam.
    pub stamp: Time,
    pub angle_min: f64,
    pub angle_increment: f64,
    /// Time between two beams, s (0 for a scan taken at one instant).
    pub time_increment: f64,
    pub range_min: f64,
    pub range_max: f64,
    pub ranges: Vec<f32>,
}

impl LaserScan {
    /// Bearing of beam `i` in the laser frame.
    pub fn angle(&self, i: usize) -> f64 {
        self.angle_min + i as f64 * self.angle_increment
    }

    /// Angle of the last beam.
    pub fn angle_max(&self) -> f64 {
        self.angle(self.ranges.len().saturating_sub(1))
    }
}

/// Odometry as the iRobot Create reports it: distance and angle travelled since the last
/// request (Open Interface packets 19 and 20), computed inside the robot from its wheel
/// encoders.
///
/// The Create reports integer millimetres and degrees; `distance` and `angle` carry those
/// quantised values converted to metres and radians.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Odometry {
    pub stamp: Time,
    /// Distance travelled by the centre of the wheel axle since the last report, m.
    pub distance: f64,
    /// Heading change since the last report, rad, counter-clockwise positive.
    pub angle: f64,
}

/// The Create's bumper and wheel-drop bits (Open Interface packet 7).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct BumpsAndDrops {
    pub bump_left: bool,
    pub bump_right: bool,
    pub drop_left: bool,
    pub drop_right: bool,
    pub drop_caster: bool,
}

impl BumpsAndDrops {
    /// Any bumper pressed.
    pub fn bumped(&self) -> bool {
        self.bump_left || self.bump_right
    }

    /// Any wheel off the ground.
    pub fn dropped(&self) -> bool {
        self.drop_left || self.drop_right || self.drop_caster
    }
}

/// A turning radius for the Create's Drive command (Open Interface opcode 137).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum Radius {
    /// Drive straight (the OI's special radius 32767/32768).
    Straight,
    /// Turn in place counter-clockwise (radius 1).
    InPlaceCcw,
    /// Turn in place clockwise (radius −1).
    InPlaceCw,
    /// Arc of this radius, m; positive turns left (counter-clockwise). The OI accepts
    /// −2 … 2 m.
    Arc(f64),
}

/// A command to the Create's drive.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum DriveCommand {
    /// OI Drive (opcode 137): mean wheel velocity (m/s, ±0.5) and turning radius. For turns
    /// in place the velocity is the speed of each wheel.
    Drive { velocity: f64, radius: Radius },
    /// OI Drive Direct (opcode 145): right and left wheel velocities, m/s (±0.5).
    DriveDirect { left: f64, right: f64 },
}

impl DriveCommand {
    /// Stop both wheels.
    pub const STOP: DriveCommand = DriveCommand::DriveDirect {
        left: 0.0,
        right: 0.0,
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_at_interpolates_inside_and_answers_outside_as_asked() {
        let t = Time::from_secs;
        // Heading from 170° to −170°: the short way is through 180°, 20° in all.
        let a = Pose2::new(0.0, 0.0, 170f64.to_radians());
        let b = Pose2::new(2.0, -4.0, -170f64.to_radians());
        let traj = [(t(1.0), a), (t(3.0), b)];
        let p = pose_at(&traj, t(1.5), Outside::None).unwrap();
        assert!(
            (p.x - 0.5).abs() < 1e-12 && (p.y + 1.0).abs() < 1e-12,
            "{p:?}"
        );
        assert!((p.theta - 175f64.to_radians()).abs() < 1e-12, "{p:?}");
        // A sample's own stamp gives its own pose, bit for bit.
        assert_eq!(pose_at(&traj, t(3.0), Outside::None), Some(b));
        assert_eq!(pose_at(&traj, t(0.5), Outside::None), None);
        assert_eq!(pose_at(&traj, t(4.0), Outside::None), None);
        assert_eq!(pose_at(&traj, t(0.5), Outside::Clamp), Some(a));
        assert_eq!(pose_at(&traj, t(4.0), Outside::Clamp), Some(b));
        assert_eq!(pose_at(&[], t(4.0), Outside::Clamp), None);
    }

    #[test]
    fn a_vector_turns_with_the_pose_and_ignores_its_position() {
        let p = Pose2::new(5.0, -3.0, std::f64::consts::FRAC_PI_2);
        let v = p.rotate_vector([1.0, 2.0]);
        assert!(
            (v[0] + 2.0).abs() < 1e-12 && (v[1] - 1.0).abs() < 1e-12,
            "{v:?}"
        );
        // Turning there and back is the identity.
        let w = p.inverse().rotate_vector(v);
        assert!(
            (w[0] - 1.0).abs() < 1e-12 && (w[1] - 2.0).abs() < 1e-12,
            "{w:?}"
        );
    }

    #[test]
    fn planar_poses_survive_the_trip_through_3d() {
        for theta in [-3.0, -1.2, 0.0, 0.7, 3.1] {
            let p = Pose2::new(1.5, -2.0, theta);
            let q = Pose3::from_pose2(&p, 0.3).to_pose2();
            assert!((q.x - 1.5).abs() < 1e-12 && (q.y + 2.0).abs() < 1e-12);
            assert!(wrap_angle(q.theta - theta).abs() < 1e-12, "{theta}");
        }
        // A quarter turn about z written by hand: (0, 0, sin 45°, cos 45°).
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let q = Pose3 {
            translation: [0.0; 3],
            rotation: [0.0, 0.0, h, h],
        };
        assert!((q.to_pose2().theta - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
    }

    #[test]
    fn a_3d_pose_moves_points_as_its_rotation_and_translation_say() {
        let close = |a: [f64; 3], b: [f64; 3]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-12);
        // A planar pose lifted: as the 2D transform, at its height.
        let p = Pose2::new(1.0, 2.0, 0.5);
        let [x, y] = p.transform_point([0.3, -0.4]);
        let q = Pose3::from_pose2(&p, 0.25).transform_point([0.3, -0.4, 1.0]);
        assert!(close(q, [x, y, 1.25]), "{q:?}");
        // The optical frame (x right, y down, z forward) of a level camera, by hand: a
        // rotation of 120° about (1, −1, 1)/√3 turns z onto body x, x onto −y, y onto −z.
        let optical = Pose3 {
            translation: [0.0, 0.0, 0.4],
            rotation: [0.5, -0.5, 0.5, -0.5],
        };
        assert!(close(
            optical.transform_point([0.0, 0.0, 2.0]),
            [2.0, 0.0, 0.4]
        ));
        assert!(close(
            optical.transform_point([1.0, 0.0, 0.0]),
            [0.0, -1.0, 0.4]
        ));
        assert!(close(
            optical.transform_point([0.0, 1.0, 0.0]),
            [0.0, 0.0, -0.6]
        ));
    }
}
