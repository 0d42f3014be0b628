//! ROS 2 messages as futago writes them: their `ros2msg` definitions (field types and names
//! in order, as the official `.msg` files of `builtin_interfaces`, `std_msgs`,
//! `geometry_msgs`, `sensor_msgs`, `nav_msgs`, `tf2_msgs`, `visualization_msgs` and
//! `rosgraph_msgs` of ROS 2 Humble give them, with their constants; the comments and default
//! values left out) with their dependencies, as an MCAP schema carries them, and their CDR
//! encodings ([`CdrWriter`]).

use crate::camera::{DepthImage, Intrinsics, RgbImage};
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
        "geometry_msgs/PoseWithCovarianceStamped",
        "std_msgs/Header header\ngeometry_msgs/PoseWithCovariance pose\n",
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
    (
        "sensor_msgs/Image",
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\n\
         uint32 step\nuint8[] data\n",
    ),
    (
        "sensor_msgs/RegionOfInterest",
        "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n",
    ),
    (
        "sensor_msgs/CameraInfo",
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\n\
         float64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\n\
         uint32 binning_y\nsensor_msgs/RegionOfInterest roi\n",
    ),
    (
        "sensor_msgs/CompressedImage",
        "std_msgs/Header header\nstring format\nuint8[] data\n",
    ),
    (
        "std_msgs/ColorRGBA",
        "float32 r\nfloat32 g\nfloat32 b\nfloat32 a\n",
    ),
    ("builtin_interfaces/Duration", "int32 sec\nuint32 nanosec\n"),
    ("visualization_msgs/UVCoordinate", "float32 u\nfloat32 v\n"),
    (
        "visualization_msgs/MeshFile",
        "string filename\nuint8[] data\n",
    ),
    (
        "visualization_msgs/Marker",
        "int32 ARROW=0\nint32 CUBE=1\nint32 SPHERE=2\nint32 CYLINDER=3\nint32 LINE_STRIP=4\n\
         int32 LINE_LIST=5\nint32 CUBE_LIST=6\nint32 SPHERE_LIST=7\nint32 POINTS=8\n\
         int32 TEXT_VIEW_FACING=9\nint32 MESH_RESOURCE=10\nint32 TRIANGLE_LIST=11\nint32 ADD=0\n\
         int32 MODIFY=0\nint32 DELETE=2\nint32 DELETEALL=3\n\
         std_msgs/Header header\nstring ns\nint32 id\nint32 type\nint32 action\n\
         geometry_msgs/Pose pose\ngeometry_msgs/Vector3 scale\nstd_msgs/ColorRGBA color\n\
         builtin_interfaces/Duration lifetime\nbool frame_locked\ngeometry_msgs/Point[] points\n\
         std_msgs/ColorRGBA[] colors\nstring texture_resource\n\
         sensor_msgs/CompressedImage texture\nvisualization_msgs/UVCoordinate[] uv_coordinates\n\
         string text\nstring mesh_resource\nvisualization_msgs/MeshFile mesh_file\n\
         bool mesh_use_embedded_materials\n",
    ),
    (
        "visualization_msgs/MarkerArray",
        "visualization_msgs/Marker[] markers\n",
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
    /// The pose, its quaternion normalised (one from single precision, or read from a file's
    /// decimals, is off unit length by more than tf2 and Foxglove expect of a rotation).
    fn from(p: &crate::Pose3) -> Pose {
        let n = p.rotation.iter().map(|v| v * v).sum::<f64>().sqrt();
        Pose {
            position: p.translation,
            orientation: if n > 0.0 {
                p.rotation.map(|v| v / n)
            } else {
                [0.0, 0.0, 0.0, 1.0]
            },
        }
    }
}

fn pose(w: &mut CdrWriter, p: &Pose) {
    for v in p.position.iter().chain(&p.orientation) {
        w.f64(*v);
    }
}

/// A `nav_msgs/msg/Odometry` of `child` in `frame` at `t`: the pose, the planar twist
/// `[v, ω]` in `child`'s frame (forward m/s, turn rad/s), and the covariances left zero
/// (unknown).
pub fn odometry(t: Time, frame: &str, child: &str, p: &Pose, twist: [f64; 2]) -> Vec<u8> {
    let mut w = CdrWriter::default();
    w.header(t, frame).string(child);
    pose(&mut w, p);
    for _ in 0..36 {
        w.f64(0.0);
    }
    for v in [twist[0], 0.0, 0.0, 0.0, 0.0, twist[1]] {
        w.f64(v);
    }
    for _ in 0..36 {
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

/// A `geometry_msgs/msg/PoseWithCovarianceStamped` (as ROS amcl's `/amcl_pose`): the pose
/// and its covariance of (x, y, z, rotation about x, y, z), row-major.
pub fn pose_with_covariance_stamped(
    t: Time,
    frame: &str,
    p: &Pose,
    covariance: &[f64; 36],
) -> Vec<u8> {
    let mut w = CdrWriter::default();
    w.header(t, frame);
    pose(&mut w, p);
    for v in covariance {
        w.f64(*v);
    }
    w.into_bytes()
}

/// The 6 × 6 covariance (x, y, z, rotation about x, y, z; row-major) of a planar estimate's
/// (x, y, θ) covariance: the planar terms in their places, the rest zero, as amcl fills it.
pub fn planar_covariance(c: &[[f64; 3]; 3]) -> [f64; 36] {
    let mut out = [0.0; 36];
    let index = [0, 1, 5];
    for (a, &i) in index.iter().enumerate() {
        for (b, &j) in index.iter().enumerate() {
            out[i * 6 + j] = c[a][b];
        }
    }
    out
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

/// A `sensor_msgs/msg/Image` of `image` (`rgb8`), stamped `t` in `frame`.
pub fn image_rgb8(t: Time, frame: &str, image: &RgbImage) -> Vec<u8> {
    let mut w = CdrWriter::with_capacity(64 + frame.len() + image.data.len());
    w.header(t, frame)
        .u32(image.height)
        .u32(image.width)
        .string("rgb8")
        .u8(0)
        .u32(3 * image.width)
        .u32(image.data.len() as u32)
        .bytes(&image.data);
    w.into_bytes()
}

/// A `sensor_msgs/msg/Image` of `depth` as REP 118 asks: `32FC1`, metres along the optical
/// axis, little-endian; pixels without a reading (0 in futago's images) are NaN.
pub fn image_depth(t: Time, frame: &str, depth: &DepthImage) -> Vec<u8> {
    let mut w = CdrWriter::with_capacity(64 + frame.len() + 4 * depth.data.len());
    w.header(t, frame)
        .u32(depth.height)
        .u32(depth.width)
        .string("32FC1")
        .u8(0)
        .u32(4 * depth.width)
        .u32(4 * depth.data.len() as u32);
    w.bytes(&depth_32fc1(depth));
    w.into_bytes()
}

/// A depth image's pixels as `32FC1` data: little-endian metres, NaN without a reading.
pub fn depth_32fc1(depth: &DepthImage) -> Vec<u8> {
    let mut bytes = Vec::with_capacity(4 * depth.data.len());
    for &d in &depth.data {
        let v = if d > 0.0 { d } else { f32::NAN };
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    bytes
}

/// A pinhole camera's `CameraInfo` matrices without distortion: `K`, `R` (the identity) and
/// `P = [K | 0]`, row-major.
pub fn pinhole(k: &Intrinsics) -> ([f64; 9], [f64; 9], [f64; 12]) {
    (
        [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0],
        [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        [
            k.fx, 0.0, k.cx, 0.0, 0.0, k.fy, k.cy, 0.0, 0.0, 0.0, 1.0, 0.0,
        ],
    )
}

/// A `sensor_msgs/msg/CameraInfo` of a pinhole camera without distortion (`plumb_bob`, all
/// five coefficients zero): `K` from `k`, `R` the identity, `P = [K | 0]`.
pub fn camera_info(t: Time, frame: &str, k: &Intrinsics) -> Vec<u8> {
    let mut w = CdrWriter::default();
    w.header(t, frame)
        .u32(k.height)
        .u32(k.width)
        .string("plumb_bob")
        .u32(5);
    let (km, r, p) = pinhole(k);
    for v in [0.0; 5].iter().chain(&km).chain(&r).chain(&p) {
        w.f64(*v);
    }
    // Binning, then a zero region of interest (the whole image).
    w.u32(0).u32(0).u32(0).u32(0).u32(0).u32(0).u8(0);
    w.into_bytes()
}

/// One `visualization_msgs/msg/Marker` of a [`marker_array`]: a shape at a pose.
#[derive(Debug, Clone, PartialEq)]
pub struct Marker {
    /// Its id within the array's namespace.
    pub id: i32,
    /// `Marker.CYLINDER` (3), `Marker.ARROW` (0), …
    pub shape: i32,
    pub pose: Pose,
    /// Size along its axes, m.
    pub scale: [f64; 3],
    /// Red, green, blue, alpha in [0, 1].
    pub color: [f32; 4],
}

/// `Marker.CYLINDER`.
pub const CYLINDER: i32 = 3;

/// A `visualization_msgs/msg/MarkerArray` in `frame` at `t`, in namespace `ns`: a
/// `DELETEALL` first (so a marker of something gone does not linger), then each of `markers`
/// added, for ever (lifetime zero).
pub fn marker_array(t: Time, frame: &str, ns: &str, markers: &[Marker]) -> Vec<u8> {
    const ADD: i32 = 0;
    const DELETEALL: i32 = 3;
    let mut w = CdrWriter::default();
    w.u32(markers.len() as u32 + 1);
    let clear = Marker {
        id: 0,
        shape: 0,
        pose: Pose::planar(0.0, 0.0, 0.0),
        scale: [0.0; 3],
        color: [0.0; 4],
    };
    for (m, action) in std::iter::once((&clear, DELETEALL)).chain(markers.iter().map(|m| (m, ADD)))
    {
        w.header(t, frame)
            .string(ns)
            .i32(m.id)
            .i32(m.shape)
            .i32(action);
        pose(&mut w, &m.pose);
        for v in m.scale {
            w.f64(v);
        }
        for c in m.color {
            w.f32(c);
        }
        // Lifetime zero, not frame-locked, no points, colours, texture or mesh.
        w.i32(0).u32(0).u8(0).u32(0).u32(0).string("");
        w.header(Time::ZERO, "").string("").u32(0);
        w.u32(0).string("").string("");
        w.string("").u32(0);
        w.u8(0);
    }
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
