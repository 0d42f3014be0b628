//! The run as a ROS 2 bag (`[output] mcap = true`): `ros2/ros2.mcap` with rosbag2's
//! `metadata.yaml`, written as the run goes, log time = simulation time, so `ros2 bag play`,
//! Foxglove and `rosbags` open the folder.
//!
//! Beyond what `futago export` recovers from a finished run's files, a live run has the
//! joints' angles, the cameras' images, the map frame and the people's truth:
//!
//! | topic | type | when |
//! |---|---|---|
//! | `/clock` | `rosgraph_msgs/Clock` | before each new log time |
//! | `/tf_static` | `tf2_msgs/TFMessage` | at the start: each laser's mount on `base_link` or on its joint's frame |
//! | `/tf` | `tf2_msgs/TFMessage` | each odometry report (15 ms): `odom → base_link`, each joint's frame from its encoder angle, `map → odom` from the stack's estimate; each camera frame: its optical frame on `base_link` (the robot's kinematics: mount, joint, sway), or on `world` for a camera an agent carries |
//! | `/odom` | `nav_msgs/Odometry` | each report, with the wheels' twist |
//! | `/scan`, `/scan_NAME` | `sensor_msgs/LaserScan` | each scan (the first laser, then the others by name), in the laser's frame |
//! | `/NAME/rgb/image_raw`, `/NAME/depth/image_raw` | `sensor_msgs/Image` | each frame the stack took (`rgb8`; `32FC1` metres, NaN without a reading) |
//! | `/NAME/rgb/camera_info`, `/NAME/depth/camera_info` | `sensor_msgs/CameraInfo` | with each image |
//! | `/map` | `nav_msgs/OccupancyGrid` (latched) | each map the stack publishes: localisation's if it runs, else SLAM's (its final map at the end) |
//! | `/localization/pose` | `geometry_msgs/PoseWithCovarianceStamped` | with `[localization]`: each estimate MCL publishes, with its covariance (as amcl's `/amcl_pose`), in `map` at the odometry report after it, the pose carried there by odometry |
//! | `/ground_truth/pose` | `geometry_msgs/PoseStamped` | the robot's true pose in `world`, at the ground-truth rate |
//! | `/ground_truth/people` | `visualization_msgs/MarkerArray` | every person as a cylinder in `world`, at the ground-truth rate |
//!
//! The recorder takes only the camera frames the stack renders for itself
//! ([`Node::passive_frames`]), so asking for the bag changes neither which frames are
//! rendered nor what the stack computes.

use super::{Bus, CameraFrame, FrameTruth, Node, Report, Streams, TrueState};
use crate::scenario::Scenario;
use anyhow::{Context, Result};
use futago_msgs::camera::Intrinsics;
use futago_msgs::ros2msg::{self, Marker, Pose};
use futago_msgs::rosbag2::writer::BagWriter;
use futago_msgs::{LaserScan, Odometry, Pose2, Time};
use futago_sim::joint::JointConfig;
use glam::{DQuat, DVec3, EulerRot};
use std::path::Path;

/// The bag's folder in the run's folder (and the stem of its MCAP file).
pub const BAG_DIR: &str = "ros2";

/// The robot's base frame, the odometry's and the map's.
const BASE: &str = "base_link";
const ODOM: &str = "odom";
const MAP: &str = "map";
/// The ground truth's frame.
const WORLD: &str = "world";

const TF: &str = "tf2_msgs/msg/TFMessage";
const IMAGE: &str = "sensor_msgs/msg/Image";
const CAMERA_INFO: &str = "sensor_msgs/msg/CameraInfo";

/// A person's stature from their hips' height: the greater trochanter stands at 0.530 of
/// the stature (Winter, *Biomechanics and Motor Control of Human Movement*, fig. 4.1).
const HIP_TO_STATURE: f64 = 1.0 / 0.530;
/// A person's marker's diameter, m (the shoulders' breadth, 0.259 of the stature, for a
/// 1.7 m person: Winter fig. 4.1, rounded).
const PERSON_DIAMETER: f64 = 0.45;

/// The topic of the scans of the laser at `index` (the scenario's order) named `name`:
/// `/scan` for the first, `/scan_NAME` for the others, as `futago export` names them.
pub fn scan_topic(index: usize, name: &str) -> String {
    if index == 0 {
        "/scan".into()
    } else {
        format!("/scan_{name}")
    }
}

/// A camera's topics and frame.
struct CameraTopics {
    name: String,
    frame: String,
    /// Topic indices: rgb image, rgb info, depth image, depth info.
    topics: [usize; 4],
}

/// The ROS 2 bag's recorder node.
pub struct BagRecorder {
    bag: Option<BagWriter>,
    /// Each laser's name and `/scan…` topic index.
    lasers: Vec<(String, usize)>,
    cameras: Vec<CameraTopics>,
    /// Each laser's mount: parent frame (`base_link` or its joint's), frame, pose.
    mounts: Vec<(String, String, Pose)>,
    joints: Vec<JointConfig>,
    wheel_base: f64,
    /// Whether the world has people (their markers are written, even when none is in it).
    people: bool,
    /// Topic indices.
    tf: usize,
    tf_static: usize,
    odom: usize,
    map: usize,
    truth: usize,
    markers: usize,
    /// `/localization/pose`, where the scenario localises, and the stamp of the last
    /// covariance written.
    estimate: Option<usize>,
    estimate_written: Option<Time>,
    /// The stamp of the last map written.
    map_written: Option<Time>,
}

impl BagRecorder {
    /// A recorder writing `dir/ros2/` for scenario `s`.
    pub fn new(s: &Scenario, dir: &Path) -> Result<BagRecorder> {
        let folder = dir.join(BAG_DIR);
        std::fs::create_dir_all(&folder).with_context(|| format!("creating {BAG_DIR}/"))?;
        let mut bag = BagWriter::create(&folder, BAG_DIR)?;
        let lasers = s
            .lidars
            .iter()
            .enumerate()
            .map(|(i, (c, _))| {
                let t = bag.topic(&scan_topic(i, &c.name), "sensor_msgs/msg/LaserScan", false);
                (c.name.clone(), t)
            })
            .collect();
        let mounts = laser_mounts(s);
        let cameras = s
            .cameras
            .iter()
            .map(|c| {
                let n = &c.name;
                CameraTopics {
                    name: n.clone(),
                    frame: format!("{n}_optical_frame"),
                    topics: [
                        bag.topic(&format!("/{n}/rgb/image_raw"), IMAGE, false),
                        bag.topic(&format!("/{n}/rgb/camera_info"), CAMERA_INFO, false),
                        bag.topic(&format!("/{n}/depth/image_raw"), IMAGE, false),
                        bag.topic(&format!("/{n}/depth/camera_info"), CAMERA_INFO, false),
                    ],
                }
            })
            .collect();
        Ok(BagRecorder {
            tf_static: bag.topic("/tf_static", TF, true),
            tf: bag.topic("/tf", TF, false),
            odom: bag.topic("/odom", "nav_msgs/msg/Odometry", false),
            map: bag.topic("/map", "nav_msgs/msg/OccupancyGrid", true),
            truth: bag.topic("/ground_truth/pose", "geometry_msgs/msg/PoseStamped", false),
            markers: bag.topic(
                "/ground_truth/people",
                "visualization_msgs/msg/MarkerArray",
                false,
            ),
            estimate: s
                .module::<super::localization::LocalizationSpec>()
                .map(|_| {
                    bag.topic(
                        "/localization/pose",
                        "geometry_msgs/msg/PoseWithCovarianceStamped",
                        false,
                    )
                }),
            estimate_written: None,
            bag: Some(bag),
            lasers,
            cameras,
            mounts,
            joints: s.movers.joints.clone(),
            wheel_base: s.spec.robot.wheel_base,
            people: !s.movers.people.is_empty() || !s.movers.flows.is_empty(),
            map_written: None,
        })
    }

    fn write(&mut self, topic: usize, t: Time, data: &[u8]) -> Result<()> {
        if let Some(b) = &mut self.bag {
            b.write(topic, t, data)?;
        }
        Ok(())
    }

    /// The map of the map frame's source (localisation's, else SLAM's), if the stack
    /// publishes one, and the pose topic that places `map` on `odom`.
    fn map_source(bus: &Bus) -> Option<&'static str> {
        ["localization", "slam"]
            .into_iter()
            .find(|t| bus.pose(t).is_some())
    }

    /// Writes the localisation's estimate with its covariance if a new one was published.
    fn write_estimate(&mut self, bus: &Bus) -> Result<()> {
        let Some(topic) = self.estimate else {
            return Ok(());
        };
        let Some((stamp, covariance)) = bus.covariance("localization") else {
            return Ok(());
        };
        let Some(est) = bus.pose("localization") else {
            return Ok(());
        };
        if self.estimate_written.is_some_and(|t| t >= stamp) {
            return Ok(());
        }
        self.estimate_written = Some(stamp);
        let cov = ros2msg::planar_covariance(&covariance);
        let msg = ros2msg::pose_with_covariance_stamped(bus.now, MAP, &planar(&est), &cov);
        self.write(topic, bus.now, &msg)
    }

    /// Writes the map of the map frame's source if it is new.
    fn write_map(&mut self, bus: &Bus) -> Result<()> {
        let Some(source) = Self::map_source(bus) else {
            return Ok(());
        };
        let Some((stamp, grid)) = bus.map(source) else {
            return Ok(());
        };
        if self.map_written == Some(stamp) {
            return Ok(());
        }
        self.map_written = Some(stamp);
        let msg = ros2msg::occupancy_grid(stamp, MAP, grid);
        self.write(self.map, bus.now, &msg)
    }
}

/// A mount (`xyz`, m; roll, pitch, yaw, degrees, about fixed x, y, z) as a pose.
pub fn mount(xyz: [f64; 3], rpy_deg: [f64; 3]) -> Pose {
    let [r, p, y] = rpy_deg.map(f64::to_radians);
    let q = DQuat::from_euler(EulerRot::ZYX, y, p, r);
    Pose {
        position: xyz,
        orientation: [q.x, q.y, q.z, q.w],
    }
}

/// A joint's frame on the base at angle `angle` (rad): turned about its axis through its
/// origin, as [`futago_sim::joint::Joint::transform`] moves the sensors on it.
pub fn joint_pose(j: &JointConfig, angle: f64) -> Pose {
    let axis = DVec3::from(j.axis).normalize_or(DVec3::Z);
    let q = DQuat::from_axis_angle(axis, angle);
    let o = DVec3::from(j.origin);
    let t = o - q * o;
    Pose {
        position: t.to_array(),
        orientation: [q.x, q.y, q.z, q.w],
    }
}

/// Transforms for `/tf`: parent frame, child frame, the child's pose in the parent.
pub type Transforms<'a> = Vec<(&'a str, &'a str, Pose)>;

/// Each laser's mount, for `/tf_static`: its parent frame (`base_link`, or the frame of the
/// joint it rides), its frame (its name), and its pose there.
pub fn laser_mounts(s: &Scenario) -> Vec<(String, String, Pose)> {
    s.lidars
        .iter()
        .map(|(c, _)| {
            let parent = c.joint.clone().unwrap_or_else(|| BASE.into());
            (parent, c.name.clone(), mount(c.xyz, c.rpy_deg))
        })
        .collect()
}

/// Owned transforms, borrowed for a message.
pub fn borrowed(t: &[(String, String, Pose)]) -> Transforms<'_> {
    t.iter()
        .map(|(p, c, m)| (p.as_str(), c.as_str(), *m))
        .collect()
}

/// What the robot knows of itself at an odometry report, as ROS 2 publishes it: its
/// odometry pose (`odom → base_link`), the wheels' twist `[v, ω]` in `base_link`, and the
/// transforms for `/tf`: `odom → base_link` and each joint's frame on `base_link` from its
/// encoder angle.
pub fn odometry_frames<'a>(
    bus: &'a Bus,
    joints: &[JointConfig],
    wheel_base: f64,
) -> (Pose, [f64; 2], Transforms<'a>) {
    let odom = planar(&bus.odometry);
    let (l, r) = bus.wheel_speeds;
    let twist = [(l + r) / 2.0, (r - l) / wheel_base];
    let mut tf: Vec<(&str, &str, Pose)> = vec![(ODOM, BASE, odom)];
    for (name, angle) in &bus.joints {
        if let Some(j) = joints.iter().find(|j| &j.name == name) {
            tf.push((BASE, name.as_str(), joint_pose(j, *angle)));
        }
    }
    (odom, twist, tf)
}

/// Where a frame's optical frame is, for `/tf`: on `base_link` as the robot's kinematics place
/// it (mount, joint, sway), or on `world` for a camera an agent carries.
pub fn optical_parent(frame: &CameraFrame, truth: &dyn FrameTruth) -> (&'static str, Pose) {
    match &frame.on_base {
        Some(p) => (BASE, Pose::from(p)),
        None => (WORLD, Pose::from(&truth.optical())),
    }
}

fn planar(p: &Pose2) -> Pose {
    Pose::planar(p.x, p.y, p.theta)
}

impl Node for BagRecorder {
    fn name(&self) -> &'static str {
        "record.mcap"
    }

    fn streams(&self) -> Streams {
        let mut consumes = vec!["truth".to_string(), "odometry".to_string()];
        consumes.extend(self.lasers.iter().map(|(n, _)| format!("scan/{n}")));
        consumes.extend(self.cameras.iter().map(|c| format!("camera/{}", c.name)));
        Streams {
            consumes,
            ..Streams::default()
        }
    }

    fn start(&mut self, bus: &mut Bus) -> Result<()> {
        let statics = borrowed(&self.mounts);
        if !statics.is_empty() {
            let msg = ros2msg::tf(bus.now, &statics);
            self.write(self.tf_static, bus.now, &msg)?;
        }
        self.write_map(bus)
    }

    fn on_truth(&mut self, truth: &TrueState, bus: &mut Bus) -> Result<()> {
        let t = bus.now;
        let msg = ros2msg::pose_stamped(t, WORLD, &planar(&truth.robot));
        self.write(self.truth, t, &msg)?;
        if self.people {
            let markers: Vec<Marker> = truth
                .people
                .iter()
                .map(|p| {
                    let h = p.hip_height * HIP_TO_STATURE;
                    let mut pose = planar(&p.pose);
                    pose.position[2] = h / 2.0;
                    Marker {
                        id: p.id as i32,
                        shape: ros2msg::CYLINDER,
                        pose,
                        scale: [PERSON_DIAMETER, PERSON_DIAMETER, h],
                        color: [1.0, 0.5, 0.0, 0.8],
                    }
                })
                .collect();
            let msg = ros2msg::marker_array(t, WORLD, "people", &markers);
            self.write(self.markers, t, &msg)?;
        }
        Ok(())
    }

    fn on_odometry(&mut self, _o: &Odometry, bus: &mut Bus) -> Result<()> {
        let t = bus.now;
        let (odom, twist, mut tf) = odometry_frames(bus, &self.joints, self.wheel_base);
        let msg = ros2msg::odometry(t, ODOM, BASE, &odom, twist);
        self.write(self.odom, t, &msg)?;
        if let Some(est) = Self::map_source(bus).and_then(|s| bus.pose(s)) {
            tf.push((MAP, ODOM, planar(&est.compose(&bus.odometry.inverse()))));
        }
        let msg = ros2msg::tf(t, &tf);
        self.write(self.tf, t, &msg)?;
        self.write_estimate(bus)?;
        self.write_map(bus)
    }

    fn on_scan(&mut self, laser: &str, scan: &LaserScan, bus: &mut Bus) -> Result<()> {
        if let Some(&(_, topic)) = self.lasers.iter().find(|(n, _)| n == laser) {
            let msg = ros2msg::laser_scan(scan);
            self.write(topic, bus.now, &msg)?;
        }
        Ok(())
    }

    fn wants_frame(&self, camera: &str, _bus: &Bus) -> bool {
        self.cameras.iter().any(|c| c.name == camera)
    }

    fn passive_frames(&self) -> bool {
        true
    }

    fn takes_carried_cameras(&self) -> bool {
        true
    }

    fn on_frame(
        &mut self,
        camera: &str,
        frame: &CameraFrame,
        truth: &mut dyn FrameTruth,
        bus: &mut Bus,
    ) -> Result<()> {
        let Some(c) = self.cameras.iter().position(|c| c.name == camera) else {
            return Ok(());
        };
        let (now, f) = (bus.now, &frame.frame);
        let cam = &self.cameras[c];
        let (optical, [rgb, rgb_info, depth, depth_info]) = (cam.frame.clone(), cam.topics);
        let (parent, on) = optical_parent(frame, &*truth);
        let msg = ros2msg::tf(f.stamp, &[(parent, optical.as_str(), on)]);
        self.write(self.tf, now, &msg)?;
        let info = |k: &Intrinsics| ros2msg::camera_info(f.stamp, &optical, k);
        if let Some(image) = &f.rgb {
            let msg = ros2msg::image_rgb8(f.stamp, &optical, image);
            self.write(rgb, now, &msg)?;
            self.write(rgb_info, now, &info(&f.rgb_intrinsics))?;
        }
        let msg = ros2msg::image_depth(f.stamp, &optical, &f.depth);
        self.write(depth, now, &msg)?;
        self.write(depth_info, now, &info(&f.depth_intrinsics))
    }

    fn finish(&mut self, bus: &mut Bus, _out: Option<&Path>) -> Result<Report> {
        // The map nodes before this one published at their finish.
        self.write_map(bus)?;
        let counts = match self.bag.take() {
            Some(b) => b.finish()?,
            None => Vec::new(),
        };
        let messages: serde_json::Map<String, serde_json::Value> = counts
            .into_iter()
            .map(|(t, n)| (t, serde_json::json!(n)))
            .collect();
        Ok(Report {
            summary: vec![("mcap".into(), serde_json::json!({ "messages": messages }))],
            files: vec![format!("{BAG_DIR}/")],
            ..Report::default()
        })
    }
}

/// The run as a ROS 2 bag, when `[output] mcap` asks for it and the run writes files.
pub const MODULE: super::Plain = super::Plain {
    metric_names: |_| Vec::new(),
    build: |s, _, out| match out {
        Some(dir) if s.spec.output.mcap => Ok(vec![Box::new(BagRecorder::new(s, dir)?)]),
        _ => Ok(Vec::new()),
    },
};

#[cfg(test)]
mod tests {
    use super::*;

    fn moved(p: &Pose, point: [f64; 3]) -> DVec3 {
        DVec3::from(p.position) + DQuat::from_array(p.orientation) * DVec3::from(point)
    }

    #[test]
    fn a_joint_frame_moves_the_points_on_it_as_the_simulator_moves_them() {
        let c = JointConfig {
            name: "turntable".into(),
            mode: futago_sim::joint::JointMode::Continuous,
            axis: [0.3, -0.2, 2.0],
            origin: [0.1, 0.05, 0.5],
            rate_deg: 70.0,
            start_deg: 10.0,
            min_deg: 0.0,
            max_deg: 0.0,
        };
        let mut j = futago_sim::joint::Joint::new(&c);
        for t in [0.0, 1.0, 2.5, 4.0] {
            j.advance(Time::from_secs(t), 1.0);
            let p = joint_pose(&c, j.angle());
            for point in [[1.1, 0.0, 0.5], [0.0, -0.4, 1.0], [0.1, 0.05, 3.0]] {
                let sim = j
                    .transform()
                    .transform_point(glam::Vec3::from(point.map(|v| v as f32)));
                let ours = moved(&p, point);
                assert!(
                    (ours - sim.as_dvec3()).length() < 1e-5,
                    "at {t} s: {ours} against the simulator's {sim}"
                );
            }
        }
    }

    #[test]
    fn a_mount_is_the_simulators_mount_of_the_same_numbers() {
        for (xyz, rpy) in [
            ([0.0, 0.0, 0.3], [0.0, 90.0, 0.0]),
            ([0.1, -0.2, 0.4], [20.0, -35.0, 120.0]),
            ([-0.13, 0.0, 0.2], [180.0, 0.0, 180.0]),
        ] {
            let sim = futago_sim::config::mount_pose(xyz, rpy);
            let ours = mount(xyz, rpy);
            for point in [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.2, 0.3, -1.0]] {
                let s = sim.transform_point(glam::Vec3::from(point.map(|v| v as f32)));
                assert!(
                    (moved(&ours, point) - s.as_dvec3()).length() < 1e-5,
                    "{xyz:?} {rpy:?}"
                );
            }
        }
    }
}
