//! `futago serve`: the twin driven over DDS by a controller outside it, in lock-step.
//!
//! The first test's controller is a second DDS participant here (dust_dds, with futago's ROS 2
//! types) that drives the robot round a square by its odometry; the second's is Python's
//! `cyclonedds` (an independent DDS), which answers each `/clock` and counts the scans.

mod common;
use common::{multicast_with, python_with, root, udp_receive_buffer_with};
use dust_dds::dds_async::configuration::DustDdsConfigurationBuilder;
use dust_dds::domain::domain_participant_factory::DomainParticipantFactory;
use dust_dds::infrastructure::listener::NO_LISTENER;
use dust_dds::infrastructure::qos::{DataReaderQos, DataWriterQos, QosKind};
use dust_dds::infrastructure::qos_policy::{
    HistoryQosPolicy, HistoryQosPolicyKind, ReliabilityQosPolicy, ReliabilityQosPolicyKind,
};
use dust_dds::infrastructure::sample_info::{ANY_INSTANCE_STATE, ANY_SAMPLE_STATE, ANY_VIEW_STATE};
use dust_dds::infrastructure::status::NO_STATUS;
use dust_dds::infrastructure::time::{Duration as DdsDuration, DurationKind};
use futago::dds::{self, RosType};
use futago_msgs::Time;
use std::collections::{BTreeMap, VecDeque};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The start of a `nav_msgs/Odometry`, up to its pose: what the controller reads. (dust_dds
/// reads no fixed arrays of numbers, such as the covariances after it; CDR is read in order,
/// so the rest of the message is left unread.)
#[derive(Debug, Clone, Default, dust_dds::infrastructure::type_support::DdsType)]
struct OdometryStart {
    header: dds::Header,
    child_frame_id: String,
    pose: dds::Pose,
}

/// A DDS domain of this test process's own, so that tests run side by side do not meet:
/// below 100, where `futago run` leases domains for the stacks it starts.
fn domain(offset: i32) -> i32 {
    offset + (std::process::id() % 12) as i32
}

fn serve(scenario: &str, out: &Path, domain: i32, extra: &[&str]) -> Child {
    Command::new(env!("CARGO_BIN_EXE_futago"))
        .args([
            "serve",
            root().join(scenario).to_str().unwrap(),
            "-q",
            "--domain",
            &domain.to_string(),
            "--out",
            out.to_str().unwrap(),
            "--wait",
            "60",
            "--timeout",
            "30",
        ])
        .args(extra)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// DDS topic `name` of type `T`, named `ty` on the wire.
fn topic<T: dust_dds::xtypes::type_support::TypeSupport + Send + 'static>(
    p: &dust_dds::domain::domain_participant::DomainParticipant,
    name: &str,
    ty: &str,
) -> dust_dds::topic_definition::topic::Topic {
    p.create_topic::<T>(name, ty, QosKind::Default, NO_LISTENER, NO_STATUS)
        .unwrap()
}

/// What the finished `child` wrote on stderr.
fn stderr_of(child: &mut Child) -> String {
    use std::io::Read;
    let mut err = String::new();
    if let Some(mut e) = child.stderr.take() {
        e.read_to_string(&mut err).unwrap();
    }
    err
}

fn reliable() -> ReliabilityQosPolicy {
    ReliabilityQosPolicy {
        kind: ReliabilityQosPolicyKind::Reliable,
        max_blocking_time: DurationKind::Finite(DdsDuration::new(1, 0)),
    }
}

fn keep(n: u32) -> HistoryQosPolicy {
    HistoryQosPolicy {
        kind: HistoryQosPolicyKind::KeepLast(n),
    }
}

/// Side of the square, m; forward and turning speeds.
const SIDE: f64 = 0.5;
const SPEED: f64 = 0.2;
const TURN: f64 = 0.6;

/// The square's plan: drive a side, turn a quarter, four times, then stand.
struct Square {
    leg: usize,
    turning: bool,
    /// The odometry pose where the current leg began: x, y, yaw.
    from: Option<[f64; 3]>,
}

impl Square {
    /// The command `[v, ω]` at odometry pose `p`.
    fn command(&mut self, p: [f64; 3]) -> [f64; 2] {
        if self.leg == 4 {
            return [0.0, 0.0];
        }
        let from = *self.from.get_or_insert(p);
        if !self.turning {
            if (p[0] - from[0]).hypot(p[1] - from[1]) < SIDE {
                return [SPEED, 0.0];
            }
            self.turning = true;
            self.from = Some(p);
        }
        let turned = (p[2] - from[2] + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
            - std::f64::consts::PI;
        if turned < std::f64::consts::FRAC_PI_2 {
            return [0.0, TURN];
        }
        self.leg += 1;
        self.turning = false;
        self.from = Some(p);
        self.command(p)
    }
}

/// Drives the served robot round a square by its odometry until `child` exits: for each
/// `/clock` t_k, the command from the odometry stamped t_k (standing at t = 0),
/// published as a `TwistStamped` stamped t_k. Returns the child's status and stderr.
fn drive_square(domain: i32, mut child: Child) -> (std::process::ExitStatus, String) {
    let factory = DomainParticipantFactory::get_instance();
    // As futago serve's participants: no XTypes type information. This controller reads
    // `/odom` as `OdometryStart`, which is not the type written; dust_dds 0.16 with type
    // information on delivers it no sample.
    *factory.get_mut_configuration() = DustDdsConfigurationBuilder::new()
        .enable_type_information(false)
        .build()
        .unwrap();
    let p = factory
        .create_participant(domain, QosKind::Default, NO_LISTENER, NO_STATUS)
        .unwrap();
    let sub = p
        .create_subscriber(QosKind::Default, NO_LISTENER, NO_STATUS)
        .unwrap();
    let publ = p
        .create_publisher(QosKind::Default, NO_LISTENER, NO_STATUS)
        .unwrap();
    let rq = DataReaderQos {
        reliability: reliable(),
        history: keep(1000),
        ..Default::default()
    };
    let clock_t = topic::<dds::Clock>(&p, "rt/clock", &dds::Clock::dds_name());
    let odom_t = topic::<OdometryStart>(&p, "rt/odom", &dds::Odometry::dds_name());
    let cmd_t = topic::<dds::TwistStamped>(&p, "rt/cmd_vel", &dds::TwistStamped::dds_name());
    let clocks = sub
        .create_datareader::<dds::Clock>(
            &clock_t,
            QosKind::Specific(rq.clone()),
            NO_LISTENER,
            NO_STATUS,
        )
        .unwrap();
    let odoms = sub
        .create_datareader::<OdometryStart>(&odom_t, QosKind::Specific(rq), NO_LISTENER, NO_STATUS)
        .unwrap();
    let cmd = publ
        .create_datawriter::<dds::TwistStamped>(
            &cmd_t,
            QosKind::Specific(DataWriterQos {
                reliability: reliable(),
                history: keep(100),
                ..Default::default()
            }),
            NO_LISTENER,
            NO_STATUS,
        )
        .unwrap();
    let mut ticks: VecDeque<Time> = VecDeque::new();
    let mut poses: BTreeMap<Time, [f64; 3]> = BTreeMap::new();
    let mut square = Square {
        leg: 0,
        turning: false,
        from: None,
    };
    let started = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            return (status, stderr_of(&mut child));
        }
        assert!(
            started.elapsed() < Duration::from_secs(300),
            "the served run took too long"
        );
        if std::env::var("SERVE_DEBUG").is_ok() {
            eprintln!(
                "{:?} ticks {} poses {} leg {}",
                started.elapsed(),
                ticks.len(),
                poses.len(),
                square.leg
            );
        }
        for s in clocks
            .take(1000, ANY_SAMPLE_STATE, ANY_VIEW_STATE, ANY_INSTANCE_STATE)
            .unwrap_or_default()
        {
            if let Some(c) = s.data {
                ticks.push_back(c.clock.into());
            }
        }
        for s in odoms
            .take(1000, ANY_SAMPLE_STATE, ANY_VIEW_STATE, ANY_INSTANCE_STATE)
            .unwrap_or_default()
        {
            if let Some(o) = s.data {
                let q = &o.pose.orientation;
                let at = &o.pose.position;
                poses.insert(o.header.stamp.into(), [at.x, at.y, q.yaw()]);
            }
        }
        let mut acted = false;
        while let Some(&t) = ticks.front() {
            // The odometry of this tick, published before its /clock; none at t = 0, where
            // the robot stands still until its first report.
            let command = if t == Time::ZERO {
                [0.0; 2]
            } else if let Some(p) = poses.get(&t) {
                square.command(*p)
            } else {
                break;
            };
            ticks.pop_front();
            let [v, w] = command;
            let mut twist = dds::Twist::default();
            (twist.linear.x, twist.angular.z) = (v, w);
            let m = dds::TwistStamped {
                header: dds::Header::new(t, "base_link"),
                twist,
            };
            cmd.write(m, None).unwrap();
            acted = true;
        }
        if !acted {
            std::thread::sleep(Duration::from_micros(200));
        }
    }
}

#[test]
fn a_controller_over_dds_drives_a_square_by_odometry_and_the_run_is_the_same_twice() {
    if !multicast_with(
        "a_controller_over_dds_drives_a_square_by_odometry_and_the_run_is_the_same_twice",
    ) {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let d = domain(4);
    let mut files = Vec::new();
    // Twice waiting at every tick; then waiting every third tick (45 ms), as for a controller
    // on its own timer, which this one is not: it answers every /clock, and the link takes
    // the command stamped with the tick it waits at.
    for k in 0..3 {
        let out = tmp.path().join(format!("run{k}"));
        let mut args = vec!["--stamped", "--duration", "26"];
        if k == 2 {
            args.extend(["--period", "0.045"]);
        }
        let child = serve("scenarios/office-tour.toml", &out, d, &args);
        let (status, err) = drive_square(d, child);
        assert_eq!(status.code(), Some(0), "{err}");
        let summary: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap())
                .unwrap();
        assert_eq!(
            summary["serve"]["deterministic"], true,
            "{}",
            summary["serve"]
        );
        assert_eq!(summary["serve"]["late"], 0);
        // A tick at each of the Create's reports (every 15 ms) in 26 s, and one at time zero.
        let reports = (26.0f64 / 0.015).floor() as u64;
        assert_eq!(
            summary["serve"]["ticks"],
            1 + reports,
            "{}",
            summary["serve"]
        );
        let awaited = if k == 2 { 1 + reports / 3 } else { 1 + reports };
        assert_eq!(
            summary["serve"]["commands_awaited"], awaited,
            "{}",
            summary["serve"]
        );
        // The true path: a square of 0.5 m sides, back where it began.
        let text = std::fs::read_to_string(out.join("groundtruth.txt")).unwrap();
        let truth = futago_msgs::tum::parse(&text).unwrap();
        let start = truth[0].pose.translation;
        let end = truth.last().unwrap().pose.translation;
        let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
        for s in &truth {
            for i in 0..2 {
                lo[i] = lo[i].min(s.pose.translation[i]);
                hi[i] = hi[i].max(s.pose.translation[i]);
            }
        }
        for i in 0..2 {
            assert!(
                (hi[i] - lo[i] - SIDE).abs() < 0.1,
                "the path spans {:?} to {:?}",
                lo,
                hi
            );
        }
        let back = (end[0] - start[0]).hypot(end[1] - start[1]);
        assert!(
            back < 0.1,
            "ended {back} m from the start: {:?}",
            truth
                .iter()
                .step_by(50)
                .map(|s| (s.stamp.secs(), s.pose.translation[0], s.pose.translation[1]))
                .collect::<Vec<_>>()
        );
        files.push(
            ["groundtruth.txt", "odometry.txt", "scans.clf"]
                .map(|f| std::fs::read(out.join(f)).unwrap()),
        );
    }
    assert!(files[0] == files[1], "two runs over the link differ");
}

/// The Python both Cyclone scripts open with: Cyclone's imports and the ROS types every
/// message here stamps itself with (`builtin_interfaces/Time`, `rosgraph_msgs/Clock`,
/// `std_msgs/Header`).
macro_rules! cyclone_preamble {
    () => {
        r#"
import sys, time, os
from dataclasses import dataclass
from cyclonedds.domain import DomainParticipant
from cyclonedds.topic import Topic
from cyclonedds.sub import DataReader
from cyclonedds.pub import DataWriter
from cyclonedds.core import Qos, Policy
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import int8, int32, uint8, uint32, float32, float64, sequence, array

@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32
    nanosec: uint32
@dataclass
class Clock(IdlStruct, typename="rosgraph_msgs::msg::dds_::Clock_"):
    clock: Time
@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str
"#
    };
}

/// A controller on Cyclone DDS: answers each /clock with one `Twist` (0.1 m/s, 0.2 rad/s)
/// until the run has ended, and counts the scans and the depth images of camera `kinect`;
/// prints `clocks N scans N beams N frames F images N sizes WxH`.
const CYCLONE_CONTROLLER: &str = concat!(
    cyclone_preamble!(),
    r#"@dataclass
class LaserScan(IdlStruct, typename="sensor_msgs::msg::dds_::LaserScan_"):
    header: Header
    angle_min: float32
    angle_max: float32
    angle_increment: float32
    time_increment: float32
    scan_time: float32
    range_min: float32
    range_max: float32
    ranges: sequence[float32]
    intensities: sequence[float32]
@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64
    y: float64
    z: float64
@dataclass
class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3
    angular: Vector3
@dataclass
class Image(IdlStruct, typename="sensor_msgs::msg::dds_::Image_"):
    header: Header
    height: uint32
    width: uint32
    encoding: str
    is_bigendian: uint8
    step: uint32
    data: sequence[uint8]

dp = DomainParticipant(int(sys.argv[1]))
q = Qos(Policy.Reliability.Reliable(max_blocking_time=1000000000), Policy.History.KeepLast(100))
clock = DataReader(dp, Topic(dp, "rt/clock", Clock, qos=q), qos=q)
scan = DataReader(dp, Topic(dp, "rt/scan", LaserScan, qos=q), qos=q)
cmd = DataWriter(dp, Topic(dp, "rt/cmd_vel", Twist, qos=q), qos=q)
depth = DataReader(dp, Topic(dp, "rt/kinect/depth/image_raw", Image, qos=q), qos=q)
images = 0
sizes = set()
clocks = scans = beams = 0
frames = set()
deadline = time.time() + float(sys.argv[2])
last = None
# Until the run has ended: no /clock for 3 s after the first.
while time.time() < deadline and (last is None or time.time() - last < 3):
    got = clock.take(N=100)
    for c in got:
        clocks += 1
        last = time.time()
        cmd.write(Twist(linear=Vector3(0.1, 0.0, 0.0), angular=Vector3(0.0, 0.0, 0.2)))
    for s in scan.take(N=100):
        scans += 1
        beams = len(s.ranges)
        frames.add(s.header.frame_id)
    for i in depth.take(N=100):
        images += 1
        assert i.encoding == "32FC1" and len(i.data) == i.step * i.height == 4 * i.width * i.height
        sizes.add((i.width, i.height))
    if not got:
        time.sleep(0.0005)
print("clocks", clocks, "scans", scans, "beams", beams, "frames", ",".join(sorted(frames)),
      "images", images, "sizes", ",".join(f"{w}x{h}" for w, h in sorted(sizes)))
"#
);

/// Serves `scenario` on `domain` with `args`, driven by [`CYCLONE_CONTROLLER`] in `python`;
/// both must succeed. Returns the run's summary and what the controller printed.
fn serve_to_cyclone(
    python: &Path,
    scenario: &str,
    domain: i32,
    args: &[&str],
) -> (serde_json::Value, String) {
    let tmp = tempfile::tempdir().unwrap();
    let (summary, printed, _) = serve_to_script(
        python,
        CYCLONE_CONTROLLER,
        &[],
        scenario,
        domain,
        args,
        tmp.path(),
    );
    (summary, printed)
}

/// Serves `scenario` on `domain` with `args` into `dir/run`, driven by `script` in `python`
/// (given the domain, a deadline in seconds and `script_args`); both must succeed. Returns
/// the run's summary, what the script printed and the run's folder.
fn serve_to_script(
    python: &Path,
    script: &str,
    script_args: &[&str],
    scenario: &str,
    domain: i32,
    args: &[&str],
    dir: &Path,
) -> (serde_json::Value, String, std::path::PathBuf) {
    let out = dir.join("run");
    let mut child = serve(scenario, &out, domain, args);
    let o = Command::new(python)
        .args(["-c", script, &domain.to_string(), "60"])
        .args(script_args)
        .output()
        .unwrap();
    let status = child.wait().unwrap();
    let err = stderr_of(&mut child);
    assert_eq!(
        status.code(),
        Some(0),
        "{err}\nthe script printed: {}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let summary =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    (
        summary,
        String::from_utf8_lossy(&o.stdout).into_owned(),
        out,
    )
}

#[test]
fn a_cyclone_dds_controller_receives_clock_and_scans_and_drives_the_twin() {
    let test = "a_cyclone_dds_controller_receives_clock_and_scans_and_drives_the_twin";
    let Some(python) = python_with(test, &["cyclonedds"]) else {
        return;
    };
    if !multicast_with(test) {
        return;
    }
    let (summary, printed) = serve_to_cyclone(
        &python,
        "scenarios/office-tour.toml",
        domain(16),
        &["--duration", "3"],
    );
    // Every tick's /clock and every scan, as the run counted them.
    let ticks = summary["serve"]["ticks"].as_u64().unwrap();
    let scans = summary["lidar"][0]["scans"].as_u64().unwrap();
    assert_eq!(summary["serve"]["late"], 0, "{printed}");
    assert!(
        printed.starts_with(&format!("clocks {ticks} scans {scans} ")),
        "{printed} against {ticks} ticks and {scans} scans"
    );
    assert!(printed.contains("frames front"), "{printed}");
    // It drove as commanded: 0.1 m/s for 3 s.
    let d = summary["robot"]["distance_travelled_m"]
        .as_f64()
        .unwrap_or(-1.0);
    assert!((d - 0.3).abs() < 0.02, "{d}: {summary}");
}

#[test]
fn a_cyclone_dds_subscriber_receives_the_depth_images_the_stack_renders_at_the_rate_asked() {
    let test =
        "a_cyclone_dds_subscriber_receives_the_depth_images_the_stack_renders_at_the_rate_asked";
    let Some(python) = python_with(test, &["cyclonedds"]) else {
        return;
    };
    // Cyclone DDS asks for a 1 MiB receive buffer (its default), to take the bursts of
    // fragments a 1.2 MB depth image is sent in.
    if !multicast_with(test) || !udp_receive_buffer_with(test, 1 << 20) {
        return;
    }
    // lab-kinect's dataset recorder takes every frame at 30 Hz; the link sends 10 a second.
    let (summary, printed) = serve_to_cyclone(
        &python,
        "scenarios/lab-kinect.toml",
        domain(28),
        &["--duration", "1.5", "--camera-rate", "10"],
    );
    let sent = summary["serve"]["camera_frames"]["kinect"]
        .as_u64()
        .unwrap();
    let rendered = summary["camera"][0]["frames"].as_u64().unwrap();
    // 1.5 s at 10 a second, of the 30 a second rendered.
    assert!(
        (14..=16).contains(&sent),
        "{sent} sent of {rendered} rendered"
    );
    assert!(
        rendered >= 3 * sent - 3,
        "{sent} sent of {rendered} rendered"
    );
    let depth = &summary["camera"][0]["depth"];
    let received: u64 = printed
        .split_once("images ")
        .and_then(|(_, rest)| rest.split(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or(0);
    // Every image, or all but the run's first: a first image whose burst overflows the
    // subscriber's buffer (on a loaded machine) is lost to it, as Cyclone DDS takes up a
    // writer from the first heartbeat it hears when it has no sample of it yet; every later
    // one is resent until acknowledged.
    assert!(
        (sent - 1..=sent).contains(&received)
            && printed.contains(&format!(
                " sizes {}x{}",
                depth[0].as_u64().unwrap(),
                depth[1].as_u64().unwrap()
            )),
        "{printed} against {sent} sent: {}",
        summary["camera"]
    );
}

#[test]
fn a_cyclone_dds_subscriber_receives_the_images_binned_as_asked() {
    let test = "a_cyclone_dds_subscriber_receives_the_images_binned_as_asked";
    let Some(python) = python_with(test, &["cyclonedds"]) else {
        return;
    };
    if !multicast_with(test) || !udp_receive_buffer_with(test, 1 << 20) {
        return;
    }
    let (summary, printed) = serve_to_cyclone(
        &python,
        "scenarios/lab-kinect.toml",
        domain(64),
        &[
            "--duration",
            "0.5",
            "--camera-rate",
            "10",
            "--camera-scale",
            "4",
        ],
    );
    // Every image sent, a quarter of the camera's size each way (whole blocks).
    let sent = summary["serve"]["camera_frames"]["kinect"]
        .as_u64()
        .unwrap();
    let depth = &summary["camera"][0]["depth"];
    assert!(sent >= 4, "{sent} sent");
    assert!(
        printed.contains(&format!(
            "images {sent} sizes {}x{}",
            depth[0].as_u64().unwrap() / 4,
            depth[1].as_u64().unwrap() / 4
        )),
        "{printed} against {sent} sent: {}",
        summary["camera"]
    );
}

/// Writes the office world's map at the laser's height (0.2 m), as map_server has it, into
/// `dir` (`office.pgm`, `office.yaml`): the truth's own rasterisation, as a stack's map.
fn export_office_map(dir: &Path) {
    let o = Command::new(env!("CARGO_BIN_EXE_futago"))
        .args(["world", "export"])
        .arg(root().join("worlds/office.toml"))
        .args([
            "--resolution",
            "0.05",
            "--band",
            "0.15:0.25",
            "--mesh",
            "none",
            "--out",
        ])
        .arg(dir)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// Python with `cyclonedds`, where a map can be sent to the link: multicast loops back, and
/// the link's socket may hold a map's burst of fragments (lost ones come again packed
/// otherwise, which dust_dds cannot reassemble). `None`: `test` is skipped.
fn cyclone_taking_maps(test: &str) -> Option<std::path::PathBuf> {
    let python = python_with(test, &["cyclonedds"])?;
    (multicast_with(test) && udp_receive_buffer_with(test, 1 << 20)).then_some(python)
}

/// Asserts that the linked stack's trajectory, the odometry moved `dx` along x, is off the
/// truth by `dx` within the odometry's own error: |e + d| lies in [d − |e|, d + |e|] (and
/// TUM's rounding). Gives its mean error.
fn assert_error_is_the_shift(summary: &serde_json::Value, dx: f64) -> f64 {
    let m = &summary["metrics"];
    let ate = m["external.ate.mean_m"].as_f64().unwrap();
    let odometry = m["odometry.ate.max_m"].as_f64().unwrap();
    assert!(
        (ate - dx).abs() <= odometry + 1e-3,
        "external ATE {ate} m against {dx} m, odometry off by up to {odometry} m"
    );
    ate
}

/// A stack on Cyclone DDS that drives as [`CYCLONE_CONTROLLER`] does, publishes as its pose
/// estimate (`/amcl_pose`, `PoseWithCovarianceStamped`) each `/odom` pose moved `DX` metres
/// along the world's x, with the odometry's stamp, and as its map (`/map`,
/// `OccupancyGrid`) the map_server map given (PGM + YAML, turned into ROS's rows from the
/// bottom), every 50 clocks; prints `poses N maps N`. Arguments: domain, deadline, DX, the
/// map's YAML file, and `tf` to publish instead, at each clock, `map → odom` on `/tf` as a
/// shift of DX along x.
const CYCLONE_STACK: &str = concat!(
    cyclone_preamble!(),
    r##"@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64
    y: float64
    z: float64
@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: float64
    y: float64
    z: float64
@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64
    y: float64
    z: float64
    w: float64
@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point
    orientation: Quaternion
@dataclass
class PoseWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    pose: Pose
    covariance: array[float64, 36]
@dataclass
class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3
    angular: Vector3
@dataclass
class TwistWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::TwistWithCovariance_"):
    twist: Twist
    covariance: array[float64, 36]
@dataclass
class Odometry(IdlStruct, typename="nav_msgs::msg::dds_::Odometry_"):
    header: Header
    child_frame_id: str
    pose: PoseWithCovariance
    twist: TwistWithCovariance
@dataclass
class PoseWithCovarianceStamped(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovarianceStamped_"):
    header: Header
    pose: PoseWithCovariance
@dataclass
class Transform(IdlStruct, typename="geometry_msgs::msg::dds_::Transform_"):
    translation: Vector3
    rotation: Quaternion
@dataclass
class TransformStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TransformStamped_"):
    header: Header
    child_frame_id: str
    transform: Transform
@dataclass
class TFMessage(IdlStruct, typename="tf2_msgs::msg::dds_::TFMessage_"):
    transforms: sequence[TransformStamped]
@dataclass
class MapMetaData(IdlStruct, typename="nav_msgs::msg::dds_::MapMetaData_"):
    map_load_time: Time
    resolution: float32
    width: uint32
    height: uint32
    origin: Pose
@dataclass
class OccupancyGrid(IdlStruct, typename="nav_msgs::msg::dds_::OccupancyGrid_"):
    header: Header
    info: MapMetaData
    data: sequence[int8]

def read_map(yaml_path):
    meta = {}
    for line in open(yaml_path):
        if ":" in line and not line.startswith("#"):
            k, v = line.split(":", 1)
            meta[k.strip()] = v.strip()
    raw = open(os.path.join(os.path.dirname(yaml_path), meta["image"]), "rb").read()
    fields, i = [], 0
    while len(fields) < 4:
        while raw[i:i + 1].isspace() or raw[i:i + 1] == b"#":
            if raw[i:i + 1] == b"#":
                i = raw.index(b"\n", i)
            i += 1
        j = i
        while not raw[j:j + 1].isspace():
            j += 1
        fields.append(raw[i:j])
        i = j
    assert fields[0] == b"P5" and fields[3] == b"255"
    w, h = int(fields[1]), int(fields[2])
    pixels = raw[i + 1:i + 1 + w * h]
    occ, free = float(meta["occupied_thresh"]), float(meta["free_thresh"])
    cells = []
    for row in range(h - 1, -1, -1):
        for v in pixels[row * w:(row + 1) * w]:
            p = (255 - v) / 255.0
            cells.append(100 if p > occ else 0 if p < free else -1)
    ox, oy = [float(x) for x in meta["origin"].strip("[]").split(",")[:2]]
    origin = Pose(Point(ox, oy, 0.0), Quaternion(0.0, 0.0, 0.0, 1.0))
    return MapMetaData(Time(0, 0), float(meta["resolution"]), w, h, origin), cells

dp = DomainParticipant(int(sys.argv[1]))
dx = float(sys.argv[3])
info, cells = read_map(sys.argv[4])
q = Qos(Policy.Reliability.Reliable(max_blocking_time=1000000000), Policy.History.KeepLast(100))
clock = DataReader(dp, Topic(dp, "rt/clock", Clock, qos=q), qos=q)
odom = DataReader(dp, Topic(dp, "rt/odom", Odometry, qos=q), qos=q)
cmd = DataWriter(dp, Topic(dp, "rt/cmd_vel", Twist, qos=q), qos=q)
pose = DataWriter(dp, Topic(dp, "rt/amcl_pose", PoseWithCovarianceStamped, qos=q), qos=q)
grid = DataWriter(dp, Topic(dp, "rt/map", OccupancyGrid, qos=q), qos=q)
tf_mode = len(sys.argv) > 5 and sys.argv[5] == "tf"
tf = DataWriter(dp, Topic(dp, "rt/tf", TFMessage, qos=q), qos=q)
deadline = time.time() + float(sys.argv[2])
last = None
clocks = poses = maps = 0
while time.time() < deadline and (last is None or time.time() - last < 3):
    got = clock.take(N=100)
    for c in got:
        clocks += 1
        last = time.time()
        if clocks % 50 == 1:
            grid.write(OccupancyGrid(Header(c.clock, "map"), info, cells))
            maps += 1
        if tf_mode:
            shift = Transform(Vector3(dx, 0.0, 0.0), Quaternion(0.0, 0.0, 0.0, 1.0))
            tf.write(TFMessage([TransformStamped(Header(c.clock, "map"), "odom", shift)]))
        cmd.write(Twist(linear=Vector3(0.1, 0.0, 0.0), angular=Vector3(0.0, 0.0, 0.2)))
    for o in odom.take(N=100):
        if tf_mode:
            continue
        p = o.pose.pose
        moved = Pose(Point(p.position.x + dx, p.position.y, p.position.z), p.orientation)
        pose.write(PoseWithCovarianceStamped(Header(o.header.stamp, "map"),
                                             PoseWithCovariance(moved, [0.0] * 36)))
        poses += 1
    if not got:
        time.sleep(0.0005)
print("poses", poses, "maps", maps)
"##
);

#[test]
fn a_stacks_pose_estimates_and_map_over_dds_are_scored_against_the_truth() {
    let test = "a_stacks_pose_estimates_and_map_over_dds_are_scored_against_the_truth";
    let Some(python) = cyclone_taking_maps(test) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    // The truth's own map of the world at the laser's height (0.2 m), as map_server has it.
    let maps = tmp.path().join("map");
    export_office_map(&maps);
    const DX: f64 = 0.1;
    // Gates may name the user's metrics, as any scenario's.
    let gate = tmp.path().join("gate.toml");
    std::fs::write(
        &gate,
        "[[gate]]\nmetric = \"external.ate.mean_m\"\nop = \"<\"\nvalue = 0.2\n",
    )
    .unwrap();
    let (summary, printed, out) = serve_to_script(
        &python,
        CYCLONE_STACK,
        &[&DX.to_string(), maps.join("office.yaml").to_str().unwrap()],
        "scenarios/office-tour.toml",
        domain(40),
        &[
            "--duration",
            "4",
            "--pose-topic",
            "/amcl_pose",
            "--map-topic",
            "/map",
            "--overlay",
            gate.to_str().unwrap(),
        ],
        tmp.path(),
    );
    // Every pose the stack published was taken, and written as the trajectory `external`.
    let poses = summary["serve"]["poses"].as_u64().unwrap();
    assert!(poses > 200, "{printed}: {}", summary["serve"]);
    assert!(
        printed.starts_with(&format!("poses {poses} ")),
        "{printed}: {poses} taken"
    );
    let lines = std::fs::read_to_string(out.join("external.txt")).unwrap();
    assert_eq!(
        lines.lines().filter(|l| !l.starts_with('#')).count() as u64,
        poses
    );
    let ate = assert_error_is_the_shift(&summary, DX);
    assert_eq!(summary["gates"][0]["metric"], "external.ate.mean_m");
    assert_eq!(summary["gates"][0]["value"].as_f64(), Some(ate));
    let m = &summary["metrics"];
    // The map is a rasterisation of the world's own colliders in the laser's band, as the
    // scorer's truth is: every true wall face is in it, at no distance (a flipped or shifted
    // map would miss them). Its precision is not 1: the truth counts only the faces the robot
    // can reach, and the map holds the walls' insides and closed rooms too.
    assert!(
        summary["serve"]["maps"].as_u64().unwrap() >= 1,
        "{}",
        summary["serve"]
    );
    let recall = m["external.map.recall_1cell"].as_f64().unwrap();
    assert!(recall >= 0.99, "external.map.recall_1cell = {recall}");
    let from_truth = m["external.map.mean_distance_from_truth_m"]
        .as_f64()
        .unwrap();
    assert!(
        from_truth < 0.025,
        "{from_truth} m from the true walls to the map's"
    );
    assert!(out.join("external_map.pgm").exists() && out.join("external_map.yaml").exists());
}

/// A scenario whose controller is the user's stack, started by its `command`: `futago suite`
/// starts it for the run (in the scenario's folder, with `ROS_DOMAIN_ID` set to a domain of
/// the run's own), scores and gates what it estimates, and stops it.
#[test]
fn a_suite_starts_the_stack_a_scenario_names_and_gates_its_estimates() {
    let test = "a_suite_starts_the_stack_a_scenario_names_and_gates_its_estimates";
    let Some(python) = cyclone_taking_maps(test) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("scenarios");
    std::fs::create_dir(&dir).unwrap();
    export_office_map(&dir.join("map"));
    std::fs::write(dir.join("stack.py"), CYCLONE_STACK).unwrap();
    // The office tour, driven by the stack: the shell form of `command`, paths relative to
    // the scenario's folder, the domain from the environment.
    let tour = std::fs::read_to_string(root().join("scenarios/office-tour.toml")).unwrap();
    let head = &tour[..tour.find("[controller]").unwrap()];
    let scenario = format!(
        "{}\n[controller]\ntype = \"external\"\ncommand = \"exec '{}' stack.py $ROS_DOMAIN_ID 60 0.1 map/office.yaml\"\npose_topic = \"/amcl_pose\"\nmap_topic = \"/map\"\n\n[[gate]]\nmetric = \"external.ate.mean_m\"\nop = \"<\"\nvalue = 0.2\n\n[[gate]]\nmetric = \"external.map.recall_1cell\"\nop = \">=\"\nvalue = 0.99\n",
        head.replace(
            "../worlds/office.toml",
            root().join("worlds/office.toml").to_str().unwrap()
        ),
        python.display()
    );
    std::fs::write(dir.join("stack-tour.toml"), scenario).unwrap();
    let out = tmp.path().join("suite");
    let o = Command::new(env!("CARGO_BIN_EXE_futago"))
        .args(["suite"])
        .arg(&dir)
        .args(["--set", "duration=3", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let printed = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    let summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.join("stack-tour/summary.json")).unwrap_or_default(),
    )
    .unwrap_or_default();
    assert!(o.status.success(), "{printed}\n{summary}");
    // It drove (0.1 m/s for 3 s) and every gate on its estimates was evaluated and passed.
    let d = summary["robot"]["distance_travelled_m"].as_f64().unwrap();
    assert!((d - 0.3).abs() < 0.02, "{d}");
    let gates = summary["gates"].as_array().unwrap();
    assert_eq!(gates.len(), 2, "{}", summary["gates"]);
    assert!(
        gates.iter().all(|g| g["passed"] == true),
        "{}",
        summary["gates"]
    );
    assert!(summary["serve"]["poses"].as_u64().unwrap() > 150);
    assert_eq!(summary["serve"]["late"], 0);
}

#[test]
fn a_stacks_map_to_odom_on_tf_composed_with_the_odometry_is_its_pose() {
    let test = "a_stacks_map_to_odom_on_tf_composed_with_the_odometry_is_its_pose";
    let Some(python) = python_with(test, &["cyclonedds"]) else {
        return;
    };
    if !multicast_with(test) {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let maps = tmp.path().join("map");
    export_office_map(&maps);
    const DX: f64 = 0.1;
    let (summary, printed, out) = serve_to_script(
        &python,
        CYCLONE_STACK,
        &[
            &DX.to_string(),
            maps.join("office.yaml").to_str().unwrap(),
            "tf",
        ],
        "scenarios/office-tour.toml",
        domain(52),
        &["--duration", "3", "--pose-from-tf"],
        tmp.path(),
    );
    // A pose at every tick from the first map → odom on, each the odometry shifted DX along
    // the map's x (map → odom is a shift, and odom is the world's frame at the start).
    let poses = summary["serve"]["poses"].as_u64().unwrap();
    let ticks = summary["serve"]["ticks"].as_u64().unwrap();
    assert!(
        poses + 10 >= ticks && poses <= ticks,
        "{poses} poses of {ticks} ticks: {printed}"
    );
    assert_error_is_the_shift(&summary, DX);
    assert!(out.join("external.txt").exists());
}
