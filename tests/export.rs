//! `futago export`: a finished run as a ROS 2 bag (MCAP with rosbag2's metadata.yaml), read
//! back by futago's own ROS 2 reader and, where Python has them, by the independent readers
//! `mcap` with `mcap-ros2-support` (decoding every message by the schemas the file carries)
//! and `rosbags` (reading the folder as a rosbag2 bag and deserialising by its own definitions).

mod common;
use common::{futago, ok, python_with, run_cut_short};
use std::path::Path;

/// Runs `scenario` for `seconds` into `dir/run` and exports it to `dir/bag`.
fn run_and_export(dir: &Path, scenario: &str, seconds: &str) -> (std::path::PathBuf, String) {
    let run = dir.join("run");
    run_cut_short(scenario, seconds, &run, &[]);
    let bag = dir.join("bag");
    let o = futago(&[
        "export",
        run.to_str().unwrap(),
        "--out",
        bag.to_str().unwrap(),
    ]);
    ok(&o);
    (run, String::from_utf8_lossy(&o.stdout).to_string())
}

#[test]
fn an_exported_run_reads_back_as_the_run_it_was() {
    let tmp = tempfile::tempdir().unwrap();
    let (run, printed) = run_and_export(tmp.path(), "scenarios/hall-two-lasers.toml", "2");
    let bag = tmp.path().join("bag");
    assert!(bag.join("metadata.yaml").is_file());
    assert!(
        printed.contains("/scan ") && printed.contains("/scan_rear "),
        "{printed}"
    );
    let text = std::fs::read_to_string(run.join("scans.clf")).unwrap();
    let clf = futago_msgs::carmen::read(&text).unwrap();
    let back = futago::replay::read_log_with(
        &bag,
        &futago_msgs::carmen::ReadOptions {
            strict: true,
            scan_topic: Some("/scan".into()),
            ..Default::default()
        },
    )
    .unwrap();
    let front: Vec<_> = clf
        .scans
        .iter()
        .filter(|s| s.scan.frame == "front")
        .collect();
    assert_eq!(back.scans.len(), front.len());
    assert!(!front.is_empty());
    for (a, b) in front.iter().zip(&back.scans) {
        assert_eq!(a.scan.stamp, b.scan.stamp);
        assert_eq!(a.scan.frame, b.scan.frame);
        assert_eq!(a.scan.ranges.len(), b.scan.ranges.len());
        for (r, s) in a.scan.ranges.iter().zip(&b.scan.ranges) {
            assert!(r == s || (r.is_nan() && s.is_nan()), "{r} {s}");
        }
        // The mount on /tf_static, as the log gave it.
        assert!((a.mount.x - b.mount.x).abs() < 1e-9 && (a.mount.y - b.mount.y).abs() < 1e-9);
        assert!((a.mount.theta - b.mount.theta).abs() < 1e-9);
        // The odometry at the scan, interpolated from /odom as from the log's ODOM records,
        // which sample the same odometry.
        assert!(
            (a.odometry.x - b.odometry.x).abs() < 1e-3,
            "{:?} {:?}",
            a.odometry,
            b.odometry
        );
        assert!((a.odometry.y - b.odometry.y).abs() < 1e-3);
    }
    // Exported twice, the same bytes.
    let again = tmp.path().join("again");
    ok(&futago(&[
        "export",
        run.to_str().unwrap(),
        "--out",
        again.to_str().unwrap(),
    ]));
    assert!(
        std::fs::read(bag.join("bag.mcap")).unwrap()
            == std::fs::read(again.join("again.mcap")).unwrap()
    );
    // Not a run folder: an error that says so.
    let o = futago(&[
        "export",
        tmp.path().to_str().unwrap(),
        "--out",
        tmp.path().join("x").to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("not a run folder"));
}

/// Decodes every message of the bag with Python's `mcap` + `mcap-ros2-support` and with
/// `rosbags`; prints `topic count` lines from each.
const READERS: &str = r#"
import sys, collections
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
bag = sys.argv[1]
counts = collections.Counter()
with open(bag + "/" + bag.rstrip("/").split("/")[-1] + ".mcap", "rb") as f:
    reader = make_reader(f, decoder_factories=[DecoderFactory()])
    assert reader.get_header().profile == "ros2", reader.get_header().profile
    for schema, channel, message, ros in reader.iter_decoded_messages():
        counts[channel.topic] += 1
        if channel.topic == "/scan":
            assert ros.header.frame_id == "front" and len(ros.ranges) > 0
        if channel.topic == "/map":
            assert len(ros.data) == ros.info.width * ros.info.height > 0
for t, n in sorted(counts.items()):
    print("mcap", t, n)
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore
store = get_typestore(Stores.ROS2_HUMBLE)
counts = collections.Counter()
with Reader(bag) as reader:
    for conn, stamp, raw in reader.messages():
        msg = store.deserialize_cdr(raw, conn.msgtype)
        counts[conn.topic] += 1
        if conn.topic == "/tf_static":
            assert conn.ext.offered_qos_profiles[0].durability.value == 1, conn.ext
for t, n in sorted(counts.items()):
    print("rosbags", t, n)
"#;

#[test]
fn independent_readers_decode_every_message_of_an_export() {
    let test = "independent_readers_decode_every_message_of_an_export";
    let Some(python) = python_with(test, &["rosbags", "mcap", "mcap_ros2"]) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let (_, printed) = run_and_export(tmp.path(), "scenarios/office-explore.toml", "4");
    assert!(printed.contains("/map 1"), "{printed}");
    let o = std::process::Command::new(python)
        .args(["-c", READERS, tmp.path().join("bag").to_str().unwrap()])
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{out}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    // Both readers count what futago says it wrote, topic by topic.
    for item in printed.trim().split(": ").nth(1).unwrap().split(", ") {
        let (topic, n) = item.rsplit_once(' ').unwrap();
        for reader in ["mcap", "rosbags"] {
            assert!(
                out.contains(&format!("{reader} {topic} {n}\n")),
                "{reader} {topic} {n}: {out}"
            );
        }
    }
}

/// The same values serialised by `rosbags` (its ROS 2 Humble definitions, the official ones):
/// prints each type's CDR bytes in hex, one `TYPE HEX` line each.
const ROSBAGS_SERIALISES: &str = r#"
import numpy as np
from rosbags.typesys import Stores, get_typestore
ts = get_typestore(Stores.ROS2_HUMBLE)
T = ts.types
def time(ns): return T['builtin_interfaces/msg/Time'](sec=ns // 10**9, nanosec=ns % 10**9)
def header(ns, frame): return T['std_msgs/msg/Header'](stamp=time(ns), frame_id=frame)
def point(x, y, z): return T['geometry_msgs/msg/Point'](x=x, y=y, z=z)
def vec(x, y, z): return T['geometry_msgs/msg/Vector3'](x=x, y=y, z=z)
def quat(x, y, z, w): return T['geometry_msgs/msg/Quaternion'](x=x, y=y, z=z, w=w)
import math
def planar(x, y, yaw): return (x, y, 0.0, 0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
def pose(p): return T['geometry_msgs/msg/Pose'](position=point(*p[:3]), orientation=quat(*p[3:]))
t = 12_000_000_005
# x, y and the rotation about z in rows and columns 0, 1 and 5 of the 6 x 6, row-major.
cov6 = np.zeros(36)
for (r, c), v in {(0, 0): 0.01, (0, 1): 0.002, (0, 5): 0.0003, (1, 0): 0.002, (1, 1): 0.02,
                  (1, 5): -0.0004, (5, 0): 0.0003, (5, 1): -0.0004, (5, 5): 0.005}.items():
    cov6[6 * r + c] = v
msgs = {
  'rosgraph_msgs/msg/Clock': T['rosgraph_msgs/msg/Clock'](clock=time(t)),
  'sensor_msgs/msg/LaserScan': T['sensor_msgs/msg/LaserScan'](
      header=header(t, 'front'), angle_min=-0.5, angle_max=0.0, angle_increment=0.25,
      time_increment=0.001, scan_time=0.003, range_min=0.1, range_max=10.0,
      ranges=np.array([1.0, np.inf, 2.5], dtype=np.float32),
      intensities=np.array([], dtype=np.float32)),
  'nav_msgs/msg/Odometry': T['nav_msgs/msg/Odometry'](
      header=header(t, 'odom'), child_frame_id='base_link',
      pose=T['geometry_msgs/msg/PoseWithCovariance'](pose=pose(planar(1.0, 2.0, 0.3)),
          covariance=np.zeros(36)),
      twist=T['geometry_msgs/msg/TwistWithCovariance'](
          twist=T['geometry_msgs/msg/Twist'](linear=vec(0.25, 0, 0), angular=vec(0, 0, -0.5)),
          covariance=np.zeros(36))),
  'tf2_msgs/msg/TFMessage': T['tf2_msgs/msg/TFMessage'](transforms=[
      T['geometry_msgs/msg/TransformStamped'](header=header(t, p), child_frame_id=c,
          transform=T['geometry_msgs/msg/Transform'](translation=vec(*q[:3]), rotation=quat(*q[3:])))
      for p, c, q in [('base_link', 'front', planar(0.13, 0.0, 0.0)),
                      ('base_link', 'rear', planar(-0.1, 0.02, math.pi))]]),
  'geometry_msgs/msg/PoseStamped': T['geometry_msgs/msg/PoseStamped'](
      header=header(t, 'world'), pose=pose(planar(-3.5, 0.25, -1.0))),
  'geometry_msgs/msg/PoseWithCovarianceStamped': T['geometry_msgs/msg/PoseWithCovarianceStamped'](
      header=header(t, 'map'),
      pose=T['geometry_msgs/msg/PoseWithCovariance'](pose=pose(planar(2.0, -1.0, 0.5)),
          covariance=cov6)),
  'nav_msgs/msg/OccupancyGrid': T['nav_msgs/msg/OccupancyGrid'](
      header=header(t, 'map'),
      info=T['nav_msgs/msg/MapMetaData'](map_load_time=time(t), resolution=0.05, width=3,
          height=2, origin=pose(planar(-1.0, 2.0, 0.0))),
      data=np.array([-1, 0, 100, 50, 0, -1], dtype=np.int8)),
  'sensor_msgs/msg/Image rgb8': T['sensor_msgs/msg/Image'](
      header=header(t, 'kinect_optical_frame'), height=2, width=3, encoding='rgb8',
      is_bigendian=0, step=9, data=np.arange(18, dtype=np.uint8)),
  'sensor_msgs/msg/Image 32FC1': T['sensor_msgs/msg/Image'](
      header=header(t, 'kinect_optical_frame'), height=1, width=3, encoding='32FC1',
      is_bigendian=0, step=12,
      data=np.frombuffer(np.array([1.5, np.nan, 0.25], dtype='<f4').tobytes(), dtype=np.uint8)),
  'sensor_msgs/msg/CameraInfo': T['sensor_msgs/msg/CameraInfo'](
      header=header(t, 'kinect_optical_frame'), height=480, width=640,
      distortion_model='plumb_bob', d=np.zeros(5),
      k=np.array([525.0, 0, 319.5, 0, 526.0, 239.5, 0, 0, 1]),
      r=np.array([1.0, 0, 0, 0, 1, 0, 0, 0, 1]),
      p=np.array([525.0, 0, 319.5, 0, 0, 526.0, 239.5, 0, 0, 0, 1, 0]),
      binning_x=0, binning_y=0,
      roi=T['sensor_msgs/msg/RegionOfInterest'](x_offset=0, y_offset=0, height=0, width=0,
          do_rectify=False)),
  'visualization_msgs/msg/MarkerArray': T['visualization_msgs/msg/MarkerArray'](markers=[
      T['visualization_msgs/msg/Marker'](
          header=header(t, 'world'), ns='people', id=i, type=ty, action=action,
          pose=pose(p), scale=vec(*sc),
          color=T['std_msgs/msg/ColorRGBA'](r=c[0], g=c[1], b=c[2], a=c[3]),
          lifetime=T['builtin_interfaces/msg/Duration'](sec=0, nanosec=0),
          frame_locked=False, points=[], colors=[], texture_resource='',
          texture=T['sensor_msgs/msg/CompressedImage'](header=header(0, ''), format='',
              data=np.array([], dtype=np.uint8)),
          uv_coordinates=[], text='', mesh_resource='',
          mesh_file=T['visualization_msgs/msg/MeshFile'](filename='',
              data=np.array([], dtype=np.uint8)),
          mesh_use_embedded_materials=False)
      for i, ty, action, p, sc, c in [
          (0, 0, 3, planar(0, 0, 0), (0, 0, 0), (0, 0, 0, 0)),
          (7, 3, 0, (1.0, -2.0, 0.85, 0.0, 0.0, math.sin(0.35), math.cos(0.35)),
              (0.45, 0.45, 1.7), (1.0, 0.5, 0.0, 0.75))]]),
}
for name, m in msgs.items():
    print(name, bytes(ts.serialize_cdr(m, name.split()[0])).hex())
"#;

#[test]
fn every_message_type_futago_writes_serialises_as_rosbags_serialises_it() {
    use futago_msgs::camera::{DepthImage, Intrinsics, RgbImage};
    use futago_msgs::ros2msg::{self, Pose};
    use futago_msgs::{LaserScan, Time};
    let test = "every_message_type_futago_writes_serialises_as_rosbags_serialises_it";
    let Some(python) = python_with(test, &["rosbags", "numpy"]) else {
        return;
    };
    let t = Time(12_000_000_005);
    let scan = LaserScan {
        frame: "front".into(),
        stamp: t,
        angle_min: -0.5,
        angle_increment: 0.25,
        time_increment: 0.001,
        range_min: 0.1,
        range_max: 10.0,
        ranges: vec![1.0, f32::INFINITY, 2.5],
    };
    let mut grid = futago_msgs::grid::OccupancyGrid::new(0.05, [-1.0, 2.0], 3, 2);
    grid.cells = vec![-1, 0, 100, 50, 0, -1];
    let ours = [
        ("rosgraph_msgs/msg/Clock", ros2msg::clock(t)),
        ("sensor_msgs/msg/LaserScan", ros2msg::laser_scan(&scan)),
        (
            "nav_msgs/msg/Odometry",
            ros2msg::odometry(
                t,
                "odom",
                "base_link",
                &Pose::planar(1.0, 2.0, 0.3),
                [0.25, -0.5],
            ),
        ),
        (
            "tf2_msgs/msg/TFMessage",
            ros2msg::tf(
                t,
                &[
                    ("base_link", "front", Pose::planar(0.13, 0.0, 0.0)),
                    (
                        "base_link",
                        "rear",
                        Pose::planar(-0.1, 0.02, std::f64::consts::PI),
                    ),
                ],
            ),
        ),
        (
            "geometry_msgs/msg/PoseStamped",
            ros2msg::pose_stamped(t, "world", &Pose::planar(-3.5, 0.25, -1.0)),
        ),
        (
            "geometry_msgs/msg/PoseWithCovarianceStamped",
            ros2msg::pose_with_covariance_stamped(
                t,
                "map",
                &Pose::planar(2.0, -1.0, 0.5),
                &ros2msg::planar_covariance(&[
                    [0.01, 0.002, 0.0003],
                    [0.002, 0.02, -0.0004],
                    [0.0003, -0.0004, 0.005],
                ]),
            ),
        ),
        (
            "nav_msgs/msg/OccupancyGrid",
            ros2msg::occupancy_grid(t, "map", &grid),
        ),
        (
            "sensor_msgs/msg/Image rgb8",
            ros2msg::image_rgb8(
                t,
                "kinect_optical_frame",
                &RgbImage {
                    width: 3,
                    height: 2,
                    data: (0..18).collect(),
                },
            ),
        ),
        (
            // futago's "no reading" (0) is REP 118's NaN.
            "sensor_msgs/msg/Image 32FC1",
            ros2msg::image_depth(
                t,
                "kinect_optical_frame",
                &DepthImage {
                    width: 3,
                    height: 1,
                    data: vec![1.5, 0.0, 0.25],
                },
            ),
        ),
        (
            "sensor_msgs/msg/CameraInfo",
            ros2msg::camera_info(
                t,
                "kinect_optical_frame",
                &Intrinsics {
                    width: 640,
                    height: 480,
                    fx: 525.0,
                    fy: 526.0,
                    cx: 319.5,
                    cy: 239.5,
                },
            ),
        ),
        (
            "visualization_msgs/msg/MarkerArray",
            ros2msg::marker_array(
                t,
                "world",
                "people",
                &[ros2msg::Marker {
                    id: 7,
                    shape: ros2msg::CYLINDER,
                    pose: Pose {
                        position: [1.0, -2.0, 0.85],
                        orientation: [0.0, 0.0, 0.35f64.sin(), 0.35f64.cos()],
                    },
                    scale: [0.45, 0.45, 1.7],
                    color: [1.0, 0.5, 0.0, 0.75],
                }],
            ),
        ),
    ];
    let o = std::process::Command::new(python)
        .args(["-c", ROSBAGS_SERIALISES])
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for (ty, bytes) in ours {
        let hex: String = bytes.iter().map(|b| format!("{b:02x}")).collect();
        let theirs = out
            .lines()
            .find_map(|l| l.strip_prefix(&format!("{ty} ")))
            .unwrap_or_else(|| panic!("rosbags printed no {ty}: {out}"));
        assert_eq!(hex, theirs, "{ty}: futago's bytes, then rosbags'");
    }
}

/// Rewrites the MCAP file `argv[1]` as `argv[2]` with Python's `mcap` writer, its chunks lz4
/// compressed, message for message; prints the chunks' count and compressions.
const REWRITE_LZ4: &str = r#"
import sys
from mcap.reader import make_reader
from mcap.writer import Writer, CompressionType
src, dst = sys.argv[1], sys.argv[2]
with open(src, "rb") as f, open(dst, "wb") as g:
    w = Writer(g, compression=CompressionType.LZ4, chunk_size=16 * 1024)
    w.start(profile="ros2", library="futago test")
    schemas, channels = {}, {}
    for schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
        if schema.id not in schemas:
            schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
        if channel.id not in channels:
            channels[channel.id] = w.register_channel(
                channel.topic, channel.message_encoding, schemas[schema.id], channel.metadata)
        w.add_message(channels[channel.id], message.log_time, message.data,
                      message.publish_time, message.sequence)
    w.finish()
with open(dst, "rb") as g:
    s = make_reader(g).get_summary()
    print("chunks", len(s.chunk_indexes), " ".join(sorted({c.compression for c in s.chunk_indexes})))
"#;

#[test]
fn an_mcap_file_with_lz4_chunks_reads_as_the_same_file_uncompressed() {
    let test = "an_mcap_file_with_lz4_chunks_reads_as_the_same_file_uncompressed";
    let Some(python) = python_with(test, &["mcap", "lz4"]) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    run_and_export(tmp.path(), "scenarios/hall-two-lasers.toml", "2");
    let plain = tmp.path().join("bag").join("bag.mcap");
    let lz4 = tmp.path().join("lz4.mcap");
    let o = std::process::Command::new(python)
        .args([
            "-c",
            REWRITE_LZ4,
            plain.to_str().unwrap(),
            lz4.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    let printed = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // Several chunks, every one lz4.
    let (count, kinds) = printed
        .trim()
        .strip_prefix("chunks ")
        .and_then(|r| r.split_once(' '))
        .unwrap();
    assert!(
        count.parse::<usize>().unwrap() > 2 && kinds == "lz4",
        "{printed}"
    );
    let read = |p: &Path| {
        futago::replay::read_log_with(
            p,
            &futago_msgs::carmen::ReadOptions {
                strict: true,
                scan_topic: Some("/scan_rear".into()),
                ..Default::default()
            },
        )
        .unwrap()
    };
    let (a, b) = (read(&plain), read(&lz4));
    assert!(!a.scans.is_empty());
    assert_eq!(a.scans.len(), b.scans.len());
    for (x, y) in a.scans.iter().zip(&b.scans) {
        assert_eq!(x.scan.stamp, y.scan.stamp);
        assert_eq!(x.scan.frame, y.scan.frame);
        assert_eq!(x.odometry, y.odometry);
        assert_eq!(x.mount, y.mount);
        for (r, s) in x.scan.ranges.iter().zip(&y.scan.ranges) {
            assert!(r.to_bits() == s.to_bits(), "{r} {s}");
        }
    }
}
