//! ROS 2 messages as futago writes them: their `ros2msg` definitions (field types and names
//! in order, as the official `.msg` files of `builtin_interfaces`, `std_msgs`,
//! `geometry_msgs`, `sensor_msgs`, `nav_msgs`, `tf2_msgs` and `rosgraph_msgs` give them; the
//! comments and default values left out) with their dependencies, as an MCAP schema carries
//! them, and their CDR encodings ([`CdrWriter`]).

use crate::grid::OccupancyGrid;
use crate::rosbag2::CdrWriter;
use crate::{LaserScan, Time};

/// Each message type futago writes, and the types it refers to.
const DEFINITIONS: &[(&str, &str)] = &[
    ("builtin_interfaces/Time", "int32 sec\nuint32 nanosec\n"),
    (
        "std_msgs/Header",
        "builtin_interfaces/Time stamp\nstring frame_id\n",
    ),
    ("rosgraph_msgs/Clock", "builtin_interfaces/Time clock\n"),
    (
        "sensor_msgs/LaserScan",
        "std_msgs/Header header\nfloat32 angle_min\nfloat32 angle_max\nfloat32 angle_increment\n\
         float32 time_increment\nfloat32 scan_time\nfloat32 range_min\nfloat32 range_max\n\
         float32[] ranges\nfloat32[] intensities\n",
    ),
    ("geometry_msgs/Point", "float64 x\nfloat64 y\nfloat64 z\n"),
    ("geometry_msgs/Vector3", "float64 x\nfloat64 y\nfloat64 z\n"),
    (
        "geometry_msgs/Quaternion",
        "float64 x\nfloat64 y\nfloat64 z\nfloat64 w\n",
    ),
    (
        "geometry_msgs/Pose",
        "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n",
    ),
    (
        "geometry_msgs/PoseWithCovariance",
        "geometry_msgs/Pose pose\nfloat64[36] covariance\n",
    ),
    (
        "geometry_msgs/Twist",
        "geometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular\n",
    ),
    (
        "geometry_msgs/TwistWithCovariance",
        "geometry_msgs/Twist twist\nfloat64[36] covariance\n",
    ),
    (
        "nav_msgs/Odometry",
        "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\n\
         geometry_msgs/TwistWithCovariance twist\n",
    ),
    (
        "geometry_msgs/Transform",
        "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n",
    ),
    (
        "geometry_msgs/TransformStamped",
        "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform\n",
    ),
    (
        "tf2_msgs/TFMessage",
        "geometry_msgs/TransformStamped[] transforms\n",
    ),
    (
        "geometry_msgs/PoseStamped",
        "std_msgs/Header header\ngeometry_msgs/Pose pose\n",
    ),
    (
        "nav_msgs/MapMetaData",
        "builtin_interfaces/Time map_load_time\nfloat32 resolution\nuint32 width\nuint32 height\n\
         geometry_msgs/Pose origin\n",
    ),
    (
        "nav_msgs/OccupancyGrid",
        "std_msgs/Header header\nnav_msgs/MapMetaData info\nint8[] data\n",
    ),
];

/// The definition of `ty` (`pkg/Type`), or `None` for a type futago does not write.
fn definition(ty: &str) -> Option<&'static str> {
    DEFINITIONS.iter().find(|(n, _)| *n == ty).map(|(_, d)| *d)
}

/// The types a definition's fields refer to (`pkg/Type`), in order.
fn references(def: &str) -> Vec<&str> {
    def.lines()
        .filter_map(|l| l.split_whitespace().next())
        .map(|t| t.split('[').next().unwrap_or(t))
        .filter(|t| t.contains('/'))
        .collect()
}

/// The MCAP schema (encoding `ros2msg`) of `ty` (`pkg/msg/Type` or `pkg/Type`): its definition,
/// then each type it depends on, depth first, once, after a line of 80 `=` and `MSG: pkg/Type`.
pub fn schema(ty: &str) -> Option<String> {
    let ty = ty.replace("/msg/", "/");
    let mut text = definition(&ty)?.to_string();
    let mut seen = vec![ty.clone()];
    let mut stack: Vec<&str> = references(definition(&ty)?).into_iter().rev().collect();
    while let Some(t) = stack.pop() {
        if seen.iter().any(|s| s == t) {
            continue;
        }
        seen.push(t.to_string());
        let d = definition(t)?;
        text += &format!("{}\nMSG: {t}\n{d}", "=".repeat(80));
        stack.extend(references(d).into_iter().rev());
    }
    Some(text)
}

/// A `rosgraph_msgs/msg/Clock`.
pub fn clock(t: Time) -> Vec<u8> {
    let mut w = CdrWriter::default();
    time(&mut w, t);
    w.into_bytes()
}

fn time(w: &mut CdrWriter, t: Time) {
    let ns = t.nanos();
    w.i32(ns.div_euclid(1_000_000_000) as i32)
        .u32(ns.rem_euclid(1_000_000_000) as u32);
}

/// A `sensor_msgs/msg/LaserScan` of `scan` in its frame, stamped `scan.stamp`; beams with no
/// return (infinite) are written as +∞, as REP 117 asks.
pub fn laser_scan(scan: &LaserScan) -> Vec<u8> {
    let mut w = CdrWriter::default();
    w.header(scan.stamp, &scan.frame);
    let n = scan.ranges.len();
    for v in crate::rosbag::writer::scan_fields(scan) {
        w.f32(v);
    }
    w.u32(n as u32);
    for r in &scan.ranges {
        w.f32(*r);
    }
    w.u32(0);
    w.into_bytes()
}

/// A planar pose as a 3D one: position `[x, y, z]` and yaw.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    pub position: [f64; 3],
    /// Unit quaternion `[x, y, z, w]`.
    pub orientation: [f64; 4],
}

impl Pose {
    /// The pose at `(x, y, 0)` turned by `yaw` about z.
    pub fn planar(x: f64, y: f64, yaw: f64) -> Pose {
        let (s, c) = (yaw / 2.0).sin_cos();
        Pose {
            position: [x, y, 0.0],
            orientation: [0.0, 0.0, s, c],
        }
    }
}

impl From<&crate::Pose3> for Pose {
    fn from(p: &crate::Pose3) -> Pose {
        Pose {
            position: p.translation,
            orientation: p.rotation,
        }
    }
}

fn pose(w: &mut CdrWriter, p: &Pose) {
    for v in p.position.iter().chain(&p.orientation) {
        w.f64(*v);
    }
}

/// A `nav_msgs/msg/Odometry` of `child` in `frame` at `t`: the pose, zero twist, and the
/// covariances left zero (unknown).
pub fn odometry(t: Time, frame: &str, child: &str, p: &Pose) -> Vec<u8> {
    let mut w = CdrWriter::default();
    w.header(t, frame).string(child);
    pose(&mut w, p);
    for _ in 0..36 + 6 + 36 {
        w.f64(0.0);
    }
    w.into_bytes()
}

/// A `tf2_msgs/msg/TFMessage` of `(parent, child, pose of child in parent)` at `t`.
pub fn tf(t: Time, transforms: &[(&str, &str, Pose)]) -> Vec<u8> {
    let mut w = CdrWriter::default();
    w.u32(transforms.len() as u32);
    for (parent, child, p) in transforms {
        w.header(t, parent).string(child);
        pose(&mut w, p);
    }
    w.into_bytes()
}

/// A `geometry_msgs/msg/PoseStamped`.
pub fn pose_stamped(t: Time, frame: &str, p: &Pose) -> Vec<u8> {
    let mut w = CdrWriter::default();
    w.header(t, frame);
    pose(&mut w, p);
    w.into_bytes()
}

/// A `nav_msgs/msg/OccupancyGrid` of `g` in `frame` at `t` (cells −1 unknown, 0–100).
pub fn occupancy_grid(t: Time, frame: &str, g: &OccupancyGrid) -> Vec<u8> {
    let mut w = CdrWriter::default();
    w.header(t, frame);
    time(&mut w, t);
    w.f32(g.resolution as f32)
        .u32(g.width as u32)
        .u32(g.height as u32);
    pose(&mut w, &Pose::planar(g.origin[0], g.origin[1], 0.0));
    w.u32(g.cells.len() as u32);
    w.bytes(&g.cells.iter().map(|&c| c as u8).collect::<Vec<_>>());
    w.into_bytes()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_schema_holds_each_dependency_once_after_its_separator() {
        let s = schema("nav_msgs/msg/Odometry").unwrap();
        assert!(s.starts_with("std_msgs/Header header\n"), "{s}");
        for dep in [
            "std_msgs/Header",
            "builtin_interfaces/Time",
            "geometry_msgs/PoseWithCovariance",
            "geometry_msgs/Pose",
            "geometry_msgs/Point",
            "geometry_msgs/Quaternion",
            "geometry_msgs/TwistWithCovariance",
            "geometry_msgs/Twist",
            "geometry_msgs/Vector3",
        ] {
            assert_eq!(
                s.matches(&format!("\nMSG: {dep}\n")).count(),
                1,
                "{dep}: {s}"
            );
        }
        assert!(schema("std_msgs/msg/String").is_none());
    }

    #[test]
    fn every_definition_refers_only_to_defined_types() {
        for (name, def) in DEFINITIONS {
            for r in references(def) {
                assert!(definition(r).is_some(), "{name} refers to {r}");
            }
            assert!(schema(name).is_some(), "{name}");
        }
    }

    #[test]
    fn a_scan_written_reads_back_through_the_ros2_reader() {
        let scan = LaserScan {
            frame: "front".into(),
            stamp: Time(1_500_000_000),
            angle_min: -0.5,
            angle_increment: 0.25,
            time_increment: 0.0,
            range_min: 0.1,
            range_max: 10.0,
            ranges: vec![1.0, f32::INFINITY, 2.5, f32::NAN, 3.0],
        };
        let back = crate::rosbag2::decode_laser_scan(&laser_scan(&scan)).unwrap();
        assert_eq!(back.stamp, scan.stamp);
        assert_eq!(back.frame, "front");
        assert_eq!(back.ranges[..3], scan.ranges[..3]);
        assert!(back.ranges[3].is_nan());
    }
}
