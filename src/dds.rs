//! ROS 2 messages as DDS types for `futago serve`'s live link (`dust_dds`, pure Rust): each
//! a struct with the official `.msg` file's fields in order and of its types, under the name
//! ROS 2's middleware gives the type on the wire (`sensor_msgs::msg::dds_::LaserScan_`), so
//! that a ROS 2 node on any DDS (Cyclone, Fast DDS) matches it. Encoded as plain CDR
//! (XCDR1), as ROS 2 exchanges them.

use dust_dds::infrastructure::type_support::DdsType;
use futago_msgs::camera::{DepthImage, Intrinsics, RgbImage};
use futago_msgs::ros2msg;

/// A type's name on the wire: `pkg::msg::dds_::Type_`.
pub trait RosType {
    /// The ROS 2 name, `pkg/msg/Type`.
    const ROS: &'static str;

    /// The DDS type name ROS 2's middleware registers for [`RosType::ROS`].
    fn dds_name() -> String {
        let mut parts = Self::ROS.split('/');
        let (pkg, kind, name) = (
            parts.next().unwrap_or(""),
            parts.next().unwrap_or("msg"),
            parts.next().unwrap_or(""),
        );
        format!("{pkg}::{kind}::dds_::{name}_")
    }
}

/// Whether `t` is an absolute ROS 2 topic name: `/` then tokens of letters, digits and `_`,
/// not starting with a digit, separated by single `/`.
pub fn is_topic(t: &str) -> bool {
    let Some(rest) = t.strip_prefix('/') else {
        return false;
    };
    !rest.is_empty()
        && rest.split('/').all(|token| {
            !token.is_empty()
                && !token.starts_with(|c: char| c.is_ascii_digit())
                && token.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
        })
}

/// `builtin_interfaces/Time`.
#[derive(Debug, Clone, Copy, Default, PartialEq, DdsType)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}

impl From<futago_msgs::Time> for Time {
    fn from(t: futago_msgs::Time) -> Time {
        let ns = t.nanos();
        Time {
            sec: ns.div_euclid(1_000_000_000) as i32,
            nanosec: ns.rem_euclid(1_000_000_000) as u32,
        }
    }
}

impl From<Time> for futago_msgs::Time {
    fn from(t: Time) -> futago_msgs::Time {
        futago_msgs::Time(i64::from(t.sec) * 1_000_000_000 + i64::from(t.nanosec))
    }
}

/// `std_msgs/Header`.
#[derive(Debug, Clone, Default, PartialEq, DdsType)]
pub struct Header {
    pub stamp: Time,
    pub frame_id: String,
}

impl Header {
    pub fn new(t: futago_msgs::Time, frame: &str) -> Header {
        Header {
            stamp: t.into(),
            frame_id: frame.to_string(),
        }
    }
}

/// `rosgraph_msgs/Clock`.
#[derive(Debug, Clone, Default, PartialEq, DdsType)]
pub struct Clock {
    pub clock: Time,
}

impl RosType for Clock {
    const ROS: &'static str = "rosgraph_msgs/msg/Clock";
}

/// `geometry_msgs/Vector3` (and `Point`, the same fields).
#[derive(Debug, Clone, Copy, Default, PartialEq, DdsType)]
pub struct Vector3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

/// `geometry_msgs/Quaternion`.
#[derive(Debug, Clone, Copy, Default, PartialEq, DdsType)]
pub struct Quaternion {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}

impl Quaternion {
    /// The yaw of this unit quaternion: the z-axis rotation of the body's x axis.
    pub fn yaw(&self) -> f64 {
        (2.0 * (self.w * self.z + self.x * self.y))
            .atan2(1.0 - 2.0 * (self.y * self.y + self.z * self.z))
    }
}

/// The planar pose at `position` turned by `orientation`'s yaw; `None` where it is not
/// finite (no pose).
pub fn planar(position: &Vector3, orientation: &Quaternion) -> Option<futago_msgs::Pose2> {
    let p = futago_msgs::Pose2::new(position.x, position.y, orientation.yaw());
    (p.x.is_finite() && p.y.is_finite() && p.theta.is_finite()).then_some(p)
}

/// `geometry_msgs/Pose`.
#[derive(Debug, Clone, Copy, Default, PartialEq, DdsType)]
pub struct Pose {
    pub position: Vector3,
    pub orientation: Quaternion,
}

impl From<&ros2msg::Pose> for Pose {
    fn from(p: &ros2msg::Pose) -> Pose {
        let [x, y, z] = p.position;
        let [qx, qy, qz, qw] = p.orientation;
        Pose {
            position: Vector3 { x, y, z },
            orientation: Quaternion {
                x: qx,
                y: qy,
                z: qz,
                w: qw,
            },
        }
    }
}

/// One element of a `float64[36]` covariance. `dust_dds` serialises fixed arrays of
/// structures but not of numbers; an array of one-number structures is the same bytes in CDR
/// (each element a `float64` aligned to 8, nothing between them).
#[derive(Debug, Clone, Copy, Default, PartialEq, DdsType)]
pub struct Float64 {
    pub value: f64,
}

/// A `float64[36]` of zeros: a covariance not known.
pub const UNKNOWN_COVARIANCE: [Float64; 36] = [Float64 { value: 0.0 }; 36];

/// `geometry_msgs/PoseWithCovariance`.
#[derive(Debug, Clone, PartialEq, DdsType)]
pub struct PoseWithCovariance {
    pub pose: Pose,
    pub covariance: [Float64; 36],
}

/// `geometry_msgs/PoseWithCovarianceStamped`: a pose estimate, as AMCL (`/amcl_pose`) and
/// slam_toolbox (`/pose`) publish theirs.
#[derive(Debug, Clone, PartialEq, DdsType)]
pub struct PoseWithCovarianceStamped {
    pub header: Header,
    pub pose: PoseWithCovariance,
}

impl RosType for PoseWithCovarianceStamped {
    const ROS: &'static str = "geometry_msgs/msg/PoseWithCovarianceStamped";
}

/// The start of a `geometry_msgs/PoseWithCovarianceStamped`, up to its pose: what the link
/// reads of a user's estimate. `dust_dds` reads no fixed arrays of numbers, such as the
/// covariance after it; CDR is read in order, so the rest is left unread.
#[derive(Debug, Clone, Default, PartialEq, DdsType)]
pub struct PoseEstimate {
    pub header: Header,
    pub pose: Pose,
}

impl RosType for PoseEstimate {
    const ROS: &'static str = PoseWithCovarianceStamped::ROS;
}

/// `nav_msgs/MapMetaData`.
#[derive(Debug, Clone, Default, PartialEq, DdsType)]
pub struct MapMetaData {
    pub map_load_time: Time,
    /// Cell side, m.
    pub resolution: f32,
    pub width: u32,
    pub height: u32,
    /// The pose of cell (0, 0)'s corner in the map's frame.
    pub origin: Pose,
}

/// `nav_msgs/OccupancyGrid`: row-major from the row at the origin, −1 unknown, 0 … 100
/// occupancy, as futago's own grids.
#[derive(Debug, Clone, Default, PartialEq, DdsType)]
pub struct OccupancyGrid {
    pub header: Header,
    pub info: MapMetaData,
    /// The cells, each an `int8` as its byte (two's complement, as CDR has it): `dust_dds`
    /// 0.16 reads a `sequence<int8>` as bytes and then cannot make them a `Vec<i8>`.
    pub data: Vec<u8>,
}

impl RosType for OccupancyGrid {
    const ROS: &'static str = "nav_msgs/msg/OccupancyGrid";
}

impl OccupancyGrid {
    /// As futago's grid; `Err` names what does not fit: cells that are not `width × height`,
    /// a resolution that is not positive, or an origin turned about z (futago's grids are
    /// aligned with the world's axes).
    pub fn to_grid(&self) -> Result<futago_msgs::grid::OccupancyGrid, String> {
        let i = &self.info;
        let (w, h) = (i.width as usize, i.height as usize);
        if w.checked_mul(h) != Some(self.data.len()) {
            return Err(format!("{} cells for a {w} × {h} map", self.data.len()));
        }
        let r = f64::from(i.resolution);
        if !(r.is_finite() && r > 0.0) {
            return Err(format!(
                "resolution {r}: expected a positive cell side in metres"
            ));
        }
        let yaw = i.origin.orientation.yaw();
        if !yaw.is_finite() || yaw.abs() > 1e-6 {
            return Err(format!(
                "origin turned by {yaw} rad about z: expected a map aligned with its frame"
            ));
        }
        let o = &i.origin.position;
        if !(o.x.is_finite() && o.y.is_finite()) {
            return Err("origin not finite".into());
        }
        Ok(futago_msgs::grid::OccupancyGrid {
            resolution: r,
            origin: [o.x, o.y],
            width: w,
            height: h,
            cells: self
                .data
                .iter()
                .map(|&b| {
                    let c = b as i8;
                    if (0..=100).contains(&c) { c } else { -1 }
                })
                .collect(),
        })
    }
}

/// `geometry_msgs/Twist`.
#[derive(Debug, Clone, Copy, Default, PartialEq, DdsType)]
pub struct Twist {
    pub linear: Vector3,
    pub angular: Vector3,
}

impl RosType for Twist {
    const ROS: &'static str = "geometry_msgs/msg/Twist";
}

/// `geometry_msgs/TwistStamped`.
#[derive(Debug, Clone, Default, PartialEq, DdsType)]
pub struct TwistStamped {
    pub header: Header,
    pub twist: Twist,
}

impl RosType for TwistStamped {
    const ROS: &'static str = "geometry_msgs/msg/TwistStamped";
}

/// `geometry_msgs/TwistWithCovariance`.
#[derive(Debug, Clone, PartialEq, DdsType)]
pub struct TwistWithCovariance {
    pub twist: Twist,
    pub covariance: [Float64; 36],
}

/// `nav_msgs/Odometry`.
#[derive(Debug, Clone, PartialEq, DdsType)]
pub struct Odometry {
    pub header: Header,
    pub child_frame_id: String,
    pub pose: PoseWithCovariance,
    pub twist: TwistWithCovariance,
}

impl RosType for Odometry {
    const ROS: &'static str = "nav_msgs/msg/Odometry";
}

impl Odometry {
    /// `child` in `frame` at `t`: the pose, the planar twist `[v, ω]` in `child`'s frame, the
    /// covariances zero (unknown), as the bag's odometry ([`ros2msg::odometry`]).
    pub fn new(
        t: futago_msgs::Time,
        frame: &str,
        child: &str,
        p: &ros2msg::Pose,
        twist: [f64; 2],
    ) -> Odometry {
        Odometry {
            header: Header::new(t, frame),
            child_frame_id: child.to_string(),
            pose: PoseWithCovariance {
                pose: p.into(),
                covariance: UNKNOWN_COVARIANCE,
            },
            twist: TwistWithCovariance {
                twist: Twist {
                    linear: Vector3 {
                        x: twist[0],
                        ..Vector3::default()
                    },
                    angular: Vector3 {
                        z: twist[1],
                        ..Vector3::default()
                    },
                },
                covariance: UNKNOWN_COVARIANCE,
            },
        }
    }
}

/// `geometry_msgs/Transform`.
#[derive(Debug, Clone, Copy, Default, PartialEq, DdsType)]
pub struct Transform {
    pub translation: Vector3,
    pub rotation: Quaternion,
}

/// `geometry_msgs/TransformStamped`.
#[derive(Debug, Clone, Default, PartialEq, DdsType)]
pub struct TransformStamped {
    pub header: Header,
    pub child_frame_id: String,
    pub transform: Transform,
}

/// `tf2_msgs/TFMessage`.
#[derive(Debug, Clone, Default, PartialEq, DdsType)]
pub struct TfMessage {
    pub transforms: Vec<TransformStamped>,
}

impl RosType for TfMessage {
    const ROS: &'static str = "tf2_msgs/msg/TFMessage";
}

impl TfMessage {
    /// `(parent, child, pose of child in parent)` at `t`, as [`ros2msg::tf`] writes them.
    pub fn new(t: futago_msgs::Time, transforms: &[(&str, &str, ros2msg::Pose)]) -> TfMessage {
        TfMessage {
            transforms: transforms
                .iter()
                .map(|(parent, child, p)| {
                    let p = Pose::from(p);
                    TransformStamped {
                        header: Header::new(t, parent),
                        child_frame_id: child.to_string(),
                        transform: Transform {
                            translation: p.position,
                            rotation: p.orientation,
                        },
                    }
                })
                .collect(),
        }
    }
}

/// `sensor_msgs/LaserScan`.
#[derive(Debug, Clone, Default, PartialEq, DdsType)]
pub struct LaserScan {
    pub header: Header,
    pub angle_min: f32,
    pub angle_max: f32,
    pub angle_increment: f32,
    pub time_increment: f32,
    pub scan_time: f32,
    pub range_min: f32,
    pub range_max: f32,
    pub ranges: Vec<f32>,
    pub intensities: Vec<f32>,
}

impl RosType for LaserScan {
    const ROS: &'static str = "sensor_msgs/msg/LaserScan";
}

impl From<&futago_msgs::LaserScan> for LaserScan {
    /// The same numbers as the bag's scans ([`ros2msg::laser_scan`]).
    fn from(s: &futago_msgs::LaserScan) -> LaserScan {
        let [
            angle_min,
            angle_max,
            angle_increment,
            time_increment,
            scan_time,
            range_min,
            range_max,
        ] = futago_msgs::rosbag::writer::scan_fields(s);
        LaserScan {
            header: Header::new(s.stamp, &s.frame),
            angle_min,
            angle_max,
            angle_increment,
            time_increment,
            scan_time,
            range_min,
            range_max,
            ranges: s.ranges.clone(),
            intensities: Vec::new(),
        }
    }
}

/// `sensor_msgs/Image`.
#[derive(Debug, Clone, Default, PartialEq, DdsType)]
pub struct Image {
    pub header: Header,
    pub height: u32,
    pub width: u32,
    pub encoding: String,
    pub is_bigendian: u8,
    pub step: u32,
    pub data: Vec<u8>,
}

impl RosType for Image {
    const ROS: &'static str = "sensor_msgs/msg/Image";
}

impl Image {
    /// A colour image, `rgb8`, as the bag writes it ([`ros2msg::image_rgb8`]).
    pub fn rgb8(t: futago_msgs::Time, frame: &str, image: &RgbImage) -> Image {
        Image {
            header: Header::new(t, frame),
            height: image.height,
            width: image.width,
            encoding: "rgb8".into(),
            is_bigendian: 0,
            step: 3 * image.width,
            data: image.data.clone(),
        }
    }

    /// A depth image, `32FC1` (REP 118), as the bag writes it ([`ros2msg::image_depth`]).
    pub fn depth(t: futago_msgs::Time, frame: &str, depth: &DepthImage) -> Image {
        Image {
            header: Header::new(t, frame),
            height: depth.height,
            width: depth.width,
            encoding: "32FC1".into(),
            is_bigendian: 0,
            step: 4 * depth.width,
            data: ros2msg::depth_32fc1(depth),
        }
    }
}

/// `sensor_msgs/RegionOfInterest`.
#[derive(Debug, Clone, Copy, Default, PartialEq, DdsType)]
pub struct RegionOfInterest {
    pub x_offset: u32,
    pub y_offset: u32,
    pub height: u32,
    pub width: u32,
    pub do_rectify: bool,
}

/// `sensor_msgs/CameraInfo`; its fixed arrays as [`Float64`] structures.
#[derive(Debug, Clone, PartialEq, DdsType)]
pub struct CameraInfo {
    pub header: Header,
    pub height: u32,
    pub width: u32,
    pub distortion_model: String,
    pub d: Vec<f64>,
    pub k: [Float64; 9],
    pub r: [Float64; 9],
    pub p: [Float64; 12],
    pub binning_x: u32,
    pub binning_y: u32,
    pub roi: RegionOfInterest,
}

impl RosType for CameraInfo {
    const ROS: &'static str = "sensor_msgs/msg/CameraInfo";
}

impl CameraInfo {
    /// A pinhole camera without distortion, as the bag writes it ([`ros2msg::camera_info`]).
    pub fn pinhole(t: futago_msgs::Time, frame: &str, k: &Intrinsics) -> CameraInfo {
        let (km, r, p) = ros2msg::pinhole(k);
        let wrap = |v: f64| Float64 { value: v };
        CameraInfo {
            header: Header::new(t, frame),
            height: k.height,
            width: k.width,
            distortion_model: "plumb_bob".into(),
            d: vec![0.0; 5],
            k: km.map(wrap),
            r: r.map(wrap),
            p: p.map(wrap),
            binning_x: 0,
            binning_y: 0,
            roi: RegionOfInterest::default(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_type_is_named_as_ros_2_names_it_on_the_wire() {
        assert_eq!(LaserScan::dds_name(), "sensor_msgs::msg::dds_::LaserScan_");
        assert_eq!(Clock::dds_name(), "rosgraph_msgs::msg::dds_::Clock_");
        assert_eq!(TfMessage::dds_name(), "tf2_msgs::msg::dds_::TFMessage_");
    }

    #[test]
    fn a_topic_is_an_absolute_ros_2_name() {
        for t in ["/amcl_pose", "/map", "/robot_1/pose"] {
            assert!(is_topic(t), "{t}");
        }
        for t in [
            "amcl_pose",
            "/",
            "/map/",
            "//map",
            "/1map",
            "/a-b",
            "/a b",
            "",
        ] {
            assert!(!is_topic(t), "{t}");
        }
    }

    #[test]
    fn a_ros_map_becomes_futagos_grid_and_one_that_does_not_fit_says_why() {
        let mut m = OccupancyGrid {
            info: MapMetaData {
                resolution: 0.5,
                width: 3,
                height: 2,
                origin: Pose {
                    position: Vector3 {
                        x: -1.0,
                        y: 2.0,
                        z: 0.0,
                    },
                    orientation: Quaternion {
                        w: 1.0,
                        ..Quaternion::default()
                    },
                },
                ..MapMetaData::default()
            },
            data: [0i8, 100, -1, 50, 0, 101].map(|c| c as u8).to_vec(),
            ..OccupancyGrid::default()
        };
        let g = m.to_grid().unwrap();
        assert_eq!(
            (g.width, g.height, g.resolution, g.origin),
            (3, 2, 0.5, [-1.0, 2.0])
        );
        // Rows from the origin's, as ROS has them; a value beyond 100 is unknown.
        assert_eq!(g.cells, vec![0, 100, -1, 50, 0, -1]);
        assert_eq!(g.get(1, 0), 100);
        m.data.pop();
        assert!(m.to_grid().unwrap_err().contains("5 cells for a 3 × 2 map"));
        m.data.push(0);
        m.info.origin.orientation = Quaternion {
            z: (0.25f64).sin(),
            w: (0.25f64).cos(),
            ..Quaternion::default()
        };
        assert!(m.to_grid().unwrap_err().contains("turned by 0.5"));
        m.info.origin.orientation.z = 0.0;
        m.info.origin.orientation.w = 1.0;
        m.info.resolution = 0.0;
        assert!(m.to_grid().unwrap_err().contains("resolution 0"));
    }

    #[test]
    fn a_time_goes_to_seconds_and_nanoseconds_and_back() {
        for ns in [0, 1, 999_999_999, 1_000_000_000, 12_000_000_005, -1] {
            let t = futago_msgs::Time(ns);
            let d = Time::from(t);
            assert!(d.nanosec < 1_000_000_000);
            assert_eq!(futago_msgs::Time::from(d), t);
        }
    }
}
