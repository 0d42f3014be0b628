//! `futago serve SCENARIO`: the twin as a ROS 2 participant over DDS, so that a user's own
//! ROS 2 stack drives the simulated robot in lock-step and is scored as the built-in one is.
//!
//! The scenario's `[controller]` is replaced by an `external` one: no driver node runs, and
//! the link node ([`Link`]) publishes what the robot senses and takes its commands:
//!
//! - published: `/clock` (`rosgraph_msgs/Clock`), `/odom` (`nav_msgs/Odometry`, with the
//!   wheels' twist), `/tf` (`odom → base_link`, each joint's frame from its encoder angle),
//!   `/tf_static` (each laser's mount; transient local), and each laser's scans on `/scan`
//!   (the first) or `/scan_NAME`, all as the bag of a run names them ([`crate::stack::bag`]);
//! - published, for each camera: `/NAME/{rgb,depth}/image_raw` (`rgb8`; `32FC1` metres, NaN
//!   without a reading) and `/NAME/{rgb,depth}/camera_info`, with the optical frame on `/tf`:
//!   the frames the scenario's own nodes render (the link never makes a camera render), at
//!   most `--camera-rate` a second;
//! - taken: `/cmd_vel`, `geometry_msgs/Twist` or, with `--stamped`, `TwistStamped`.
//!
//! **Lock-step.** At every control tick (each report of the Create's sensor stream, 15 ms of
//! simulated time) the link publishes that tick's sensor messages, then `/clock` = the tick's
//! time t_k, and waits for the controller's command for that tick before the simulation goes
//! on: a `TwistStamped` stamped t_k (older stamps are discarded), or the next `Twist` (one
//! per `/clock`, in order). So what the controller computes from what it received up to t_k
//! is applied at t_k, whatever the load of the machine, and a run is the same twice. If no
//! command comes within `--timeout` seconds of real time, the robot keeps its last command,
//! the run goes on, and its summary says it was not deterministic (`serve.late`). Before the
//! first tick the link waits (`--wait`) until the controller's `/cmd_vel` publisher and a
//! `/clock` subscriber have matched, and then a second more, for the controller's side of
//! the match.
//!
//! Every topic is reliable, so lock-step also covers what the link publishes: a write waits
//! for reliable subscribers to acknowledge (at most `--timeout`), so a slow subscriber slows
//! the run rather than miss messages, and one that acknowledges nothing for that long fails
//! it. Camera images are large: one 640×480 depth image is 1.2 MB, sent as about 900 UDP
//! datagrams. A subscriber whose UDP receive buffer cannot hold such a burst loses fragments;
//! ROS 2's DDS tuning guide has Linux's `net.core.rmem_max` raised on its machine (Cyclone DDS
//! asks for 1 MiB, and gets at most that limit, 208 KiB by default).
//!
//! DDS is `dust_dds` (pure Rust, RTPS over UDP): no ROS installation is needed, and ROS 2
//! nodes on Cyclone DDS or Fast DDS in the same domain (`--domain`, or `ROS_DOMAIN_ID`) see
//! the topics. Discovery is the standard one (SPDP by multicast).
//!
//! **The user's estimates.** With `--pose-topic` (or `--pose-from-tf`, the stack's
//! `map → odom` on `/tf`) and `--map-topic`, the link also takes what the stack estimates and
//! scores it as futago's SLAM is scored: the trajectory `external` and `external.map`.
//!
//! **A started stack.** A scenario whose `[controller]` is `external` with a `command` is run
//! by `futago run`, `suite` and `tune` through [`run_scenario`] and [`evaluate_scenario`],
//! which start the stack for the run on a DDS domain of its own and stop it after.

use crate::dds::{self, RosType};
use crate::ground_truth::Metrics;
use crate::run::Outcome;
use crate::run::{RunOptions, print_result, run_with};
use crate::scenario::Scenario;
use crate::stack::bag::{borrowed, laser_mounts, odometry_frames, optical_parent};
use crate::stack::driver::{ControllerConfig, EXTERNAL, ExternalConfig, StackCommand, controller};
use crate::stack::{Bus, CameraFrame, FrameTruth, Node, Report, Streams, Trajectory, Truth};
use anyhow::{Context, Result, bail};
use dust_dds::domain::domain_participant::DomainParticipant;
use dust_dds::domain::domain_participant_factory::DomainParticipantFactory;
use dust_dds::infrastructure::error::DdsError;
use dust_dds::infrastructure::listener::NO_LISTENER;
use dust_dds::infrastructure::qos::{DataReaderQos, DataWriterQos, QosKind};
use dust_dds::infrastructure::qos_policy::{
    DurabilityQosPolicy, DurabilityQosPolicyKind, HistoryQosPolicy, HistoryQosPolicyKind,
    ReliabilityQosPolicy, ReliabilityQosPolicyKind,
};
use dust_dds::infrastructure::sample_info::{ANY_INSTANCE_STATE, ANY_SAMPLE_STATE, ANY_VIEW_STATE};
use dust_dds::infrastructure::status::{NO_STATUS, StatusKind};
use dust_dds::infrastructure::time::{Duration as DdsDuration, DurationKind};
use dust_dds::publication::data_writer::DataWriter;
use dust_dds::publication::publisher::Publisher;
use dust_dds::rtps_udp_transport::udp_transport::RtpsUdpTransportParticipantFactory;
use dust_dds::subscription::data_reader::DataReader;
use dust_dds::topic_definition::topic::Topic;
use dust_dds::topic_definition::topic_description::TopicDescription;
use dust_dds::wait_set::{Condition, WaitSet};
use dust_dds::xtypes::type_support::TypeSupport;
use futago_msgs::camera::Intrinsics;
use futago_msgs::grid::OccupancyGrid;
use futago_msgs::ros2msg::Pose;
use futago_msgs::{DriveCommand, LaserScan, Odometry, Pose2, Time};
use futago_sim::joint::JointConfig;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// How long the link waits after matching before the first `/clock`, real time.
const SETTLE: Duration = Duration::from_secs(1);

/// How `futago serve` links.
#[derive(Debug, Clone, Default)]
pub struct ServeOptions {
    /// The DDS domain; `None`: `ROS_DOMAIN_ID`, else 0.
    pub domain: Option<i32>,
    /// Real seconds to wait for a tick's command before going on without it, and for a
    /// reliable subscriber to acknowledge what the link published before it fails
    /// (`None`: 10).
    pub timeout: Option<f64>,
    /// Real seconds to wait for the controller to match before the first tick (`None`: 60).
    pub wait: Option<f64>,
    /// Take `geometry_msgs/TwistStamped` on `/cmd_vel` instead of `Twist`.
    pub stamped: bool,
    /// Simulated seconds between the ticks that wait for a command (`None`: every tick): the
    /// period of a controller that runs on its own timer, such as Nav2's controller server.
    pub period: Option<f64>,
    /// Most camera frames a second each camera publishes (`None`: every frame the stack
    /// renders).
    pub camera_rate: Option<f64>,
    /// Bin each camera's images `n × n` on the link (`None`: full size): a colour block's
    /// mean, a depth block's nearest reading, the intrinsics to match.
    pub camera_scale: Option<u32>,
    /// The topic of the user's pose estimate (`geometry_msgs/PoseWithCovarianceStamped`, as
    /// AMCL's `/amcl_pose`), scored as the trajectory `external`.
    pub pose_topic: Option<String>,
    /// Take the user's pose from its `map → odom` on `/tf` (as slam_toolbox, Cartographer
    /// and AMCL publish it) composed with the odometry at each tick, instead of a topic.
    pub pose_from_tf: bool,
    /// The topic of the user's map (`nav_msgs/OccupancyGrid`, as `/map`): its last one is
    /// scored as `external.map`.
    pub map_topic: Option<String>,
}

impl ServeOptions {
    /// These options (`futago serve`'s flags) over those of the scenario's external
    /// controller `e`: what is set here wins.
    pub fn over(&self, e: &ExternalConfig) -> ServeOptions {
        ServeOptions {
            domain: self.domain.or(e.domain),
            timeout: self.timeout.or(e.timeout),
            wait: self.wait.or(e.wait),
            stamped: self.stamped || e.stamped,
            period: self.period.or(e.period),
            camera_rate: self.camera_rate.or(e.camera_rate),
            camera_scale: self.camera_scale.or(e.camera_scale),
            pose_topic: self.pose_topic.clone().or_else(|| e.pose_topic.clone()),
            pose_from_tf: self.pose_from_tf || e.pose_from_tf,
            map_topic: self.map_topic.clone().or_else(|| e.map_topic.clone()),
        }
    }

    fn timeout(&self) -> Duration {
        Duration::from_secs_f64(self.timeout.unwrap_or(10.0))
    }

    fn wait(&self) -> f64 {
        self.wait.unwrap_or(60.0)
    }

    /// Whether the user's pose is taken, from a topic or from `/tf`.
    fn takes_pose(&self) -> bool {
        self.pose_topic.is_some() || self.pose_from_tf
    }

    /// Checks the numbers and topic names as a scenario's external controller's are
    /// checked ([`ExternalConfig::validate`]), naming the flag.
    fn check(&self) -> Result<()> {
        let as_keys = ExternalConfig {
            timeout: self.timeout,
            wait: self.wait,
            period: self.period,
            camera_rate: self.camera_rate,
            camera_scale: self.camera_scale,
            pose_topic: self.pose_topic.clone(),
            pose_from_tf: self.pose_from_tf,
            map_topic: self.map_topic.clone(),
            ..ExternalConfig::default()
        };
        as_keys.validate().map_err(|(key, expected)| {
            anyhow::anyhow!("--{}: expected {expected}", key.replace('_', "-"))
        })
    }
}

/// A DDS error as an error naming what was being done.
fn dds<T>(what: &str, r: dust_dds::infrastructure::error::DdsResult<T>) -> Result<T> {
    r.map_err(|e| anyhow::anyhow!("DDS: {what}: {e:?}"))
}

/// Reliable, keep last `depth`; transient local when `latched`. A write waits at most
/// `patience` for reliable subscribers to acknowledge the oldest of the `depth` samples kept
/// (`dust_dds` blocks there rather than overwrite it): lock-step, a slow subscriber slows the
/// run rather than lose messages.
fn writer_qos(depth: u32, latched: bool, patience: Duration) -> DataWriterQos {
    DataWriterQos {
        reliability: ReliabilityQosPolicy {
            kind: ReliabilityQosPolicyKind::Reliable,
            max_blocking_time: DurationKind::Finite(DdsDuration::new(
                patience.as_secs().min(i32::MAX as u64) as i32,
                patience.subsec_nanos(),
            )),
        },
        history: HistoryQosPolicy {
            kind: HistoryQosPolicyKind::KeepLast(depth),
        },
        durability: DurabilityQosPolicy {
            kind: if latched {
                DurabilityQosPolicyKind::TransientLocal
            } else {
                DurabilityQosPolicyKind::Volatile
            },
        },
        ..Default::default()
    }
}

/// The link's DDS entities.
struct Dds {
    participant: DomainParticipant,
    clock: DataWriter<dds::Clock>,
    tf: DataWriter<dds::TfMessage>,
    tf_static: DataWriter<dds::TfMessage>,
    odom: DataWriter<dds::Odometry>,
    /// Each laser's name and its scans' writer.
    scans: Vec<(String, DataWriter<dds::LaserScan>)>,
    cameras: Vec<CameraWriters>,
    command: CommandReader,
    waitset: WaitSet,
    /// The user's pose estimates and maps, where asked for.
    pose: Option<DataReader<dds::PoseEstimate>>,
    /// `/tf`, read for the user's `map → odom`.
    tf_in: Option<DataReader<dds::TfMessage>>,
    map: Option<DataReader<dds::OccupancyGrid>>,
}

/// A camera's writers: `/NAME/rgb/image_raw`, `/NAME/rgb/camera_info`,
/// `/NAME/depth/image_raw`, `/NAME/depth/camera_info`, as the bag names them.
struct CameraWriters {
    name: String,
    frame: String,
    rgb: DataWriter<dds::Image>,
    rgb_info: DataWriter<dds::CameraInfo>,
    depth: DataWriter<dds::Image>,
    depth_info: DataWriter<dds::CameraInfo>,
    /// When a frame was last published, and how many were.
    last: Option<Time>,
    published: u64,
}

/// `/cmd_vel`'s reader, of the type the controller publishes.
enum CommandReader {
    Twist(DataReader<dds::Twist>),
    Stamped(DataReader<dds::TwistStamped>),
}

/// ROS 2 topic `topic` (`/scan`) of type `T`, created as DDS topic `rt/scan`.
fn topic<T: TypeSupport + RosType + Send + 'static>(
    participant: &DomainParticipant,
    topic: &str,
) -> Result<Topic> {
    dds(
        &format!("creating topic {topic}"),
        participant.create_topic::<T>(
            &format!("rt{topic}"),
            &T::dds_name(),
            QosKind::Default,
            NO_LISTENER,
            NO_STATUS,
        ),
    )
}

fn writer<T: TypeSupport + RosType + Send + 'static>(
    participant: &DomainParticipant,
    publisher: &Publisher,
    name: &str,
    qos: DataWriterQos,
) -> Result<DataWriter<T>> {
    let t = topic::<T>(participant, name)?;
    let topic = name;
    dds(
        &format!("creating the writer of {topic}"),
        publisher.create_datawriter::<T>(&t, QosKind::Specific(qos), NO_LISTENER, NO_STATUS),
    )
}

fn reader<T: TypeSupport + RosType + Send + 'static>(
    participant: &DomainParticipant,
    name: &str,
    depth: u32,
) -> Result<DataReader<T>> {
    // A topic the link also writes (`/tf`) was created with its writer.
    let dds_name = format!("rt{name}");
    let found = participant.lookup_topicdescription(&dds_name);
    let created;
    let t: &dyn TopicDescription = match found {
        Ok(Some(ref t)) => t,
        _ => {
            created = topic::<T>(participant, name)?;
            &created
        }
    };
    let topic = name;
    let subscriber = dds(
        "creating a subscriber",
        participant.create_subscriber(QosKind::Default, NO_LISTENER, NO_STATUS),
    )?;
    let qos = DataReaderQos {
        reliability: ReliabilityQosPolicy {
            kind: ReliabilityQosPolicyKind::Reliable,
            max_blocking_time: DurationKind::Finite(DdsDuration::new(1, 0)),
        },
        history: HistoryQosPolicy {
            kind: HistoryQosPolicyKind::KeepLast(depth),
        },
        ..Default::default()
    };
    dds(
        &format!("creating the reader of {topic}"),
        subscriber.create_datareader::<T>(t, QosKind::Specific(qos), NO_LISTENER, NO_STATUS),
    )
}

/// What the link asks of its UDP sockets' receive buffers: room for a burst of fragments of
/// a large sample (a map, 0.2 MB at 5 cm for a 30 m × 18 m floor) from a peer. `dust_dds`
/// (0.16 as 0.15) cannot reassemble a sample whose lost fragments come again packed
/// otherwise (Cyclone DDS resends several in one submessage), so the link must not lose
/// them. Linux caps it at `net.core.rmem_max`.
const RECEIVE_BUFFER: usize = 8 << 20;

/// The DDS participant factory: `dust_dds`'s own, but for the UDP sockets' receive buffers
/// ([`RECEIVE_BUFFER`]).
fn participant_factory() -> &'static DomainParticipantFactory<RtpsUdpTransportParticipantFactory> {
    use dust_dds::dds_async::configuration::DustDdsConfigurationBuilder;
    use dust_dds::dds_async::domain_participant_factory::DomainParticipantFactoryAsync;
    use dust_dds::std_runtime::StdRuntime;
    use std::sync::OnceLock;
    static ASYNC: OnceLock<DomainParticipantFactoryAsync<RtpsUdpTransportParticipantFactory>> =
        OnceLock::new();
    static FACTORY: OnceLock<DomainParticipantFactory<RtpsUdpTransportParticipantFactory>> =
        OnceLock::new();
    let factory = ASYNC.get_or_init(|| {
        let mut transport = RtpsUdpTransportParticipantFactory::default();
        transport.set_udp_receive_buffer_size(Some(RECEIVE_BUFFER));
        // No XTypes type information in discovery: peers match by type name. With it (dust_dds
        // 0.16's default) Cyclone DDS matched none of the link's endpoints.
        let configuration = DustDdsConfigurationBuilder::new()
            .enable_type_information(false)
            .build()
            .unwrap_or_default();
        // As dust_dds names a participant: this host's address and the process.
        DomainParticipantFactoryAsync::new(
            StdRuntime::default(),
            std::process::id().to_ne_bytes(),
            host_id(),
            transport,
            configuration,
        )
    });
    FACTORY.get_or_init(|| DomainParticipantFactory::new(factory))
}

/// This host's IPv4 address that multicast leaves from (no packet is sent), for the
/// participants' GUIDs; 0.0.0.0 where there is none.
fn host_id() -> [u8; 4] {
    std::net::UdpSocket::bind(("0.0.0.0", 0))
        .and_then(|s| {
            s.connect(("239.255.0.1", 7400))?;
            s.local_addr()
        })
        .ok()
        .and_then(|a| match a.ip() {
            std::net::IpAddr::V4(v4) => Some(v4.octets()),
            std::net::IpAddr::V6(_) => None,
        })
        .unwrap_or([0; 4])
}

impl Dds {
    /// The participant on `domain` and its topics for scenario `s`; `/cmd_vel` as
    /// `TwistStamped` when `stamped`.
    fn new(s: &Scenario, domain: i32, serve: &ServeOptions, patience: Duration) -> Result<Dds> {
        let stamped = serve.stamped;
        let factory = participant_factory();
        let participant = dds(
            "creating the participant",
            factory.create_participant(domain, QosKind::Default, NO_LISTENER, NO_STATUS),
        )?;
        let publisher = dds(
            "creating a publisher",
            participant.create_publisher(QosKind::Default, NO_LISTENER, NO_STATUS),
        )?;
        let p = &participant;
        let scans = s
            .lidars
            .iter()
            .enumerate()
            .map(|(i, (c, _))| {
                let topic = crate::stack::bag::scan_topic(i, &c.name);
                Ok((
                    c.name.clone(),
                    writer(p, &publisher, &topic, writer_qos(10, false, patience))?,
                ))
            })
            .collect::<Result<Vec<_>>>()?;
        let cameras = s
            .cameras
            .iter()
            .map(|c| {
                let n = &c.name;
                let q = || writer_qos(2, false, patience);
                Ok(CameraWriters {
                    name: n.clone(),
                    frame: format!("{n}_optical_frame"),
                    rgb: writer(p, &publisher, &format!("/{n}/rgb/image_raw"), q())?,
                    rgb_info: writer(p, &publisher, &format!("/{n}/rgb/camera_info"), q())?,
                    depth: writer(p, &publisher, &format!("/{n}/depth/image_raw"), q())?,
                    depth_info: writer(p, &publisher, &format!("/{n}/depth/camera_info"), q())?,
                    last: None,
                    published: 0,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let command = if stamped {
            CommandReader::Stamped(reader(p, "/cmd_vel", 100)?)
        } else {
            CommandReader::Twist(reader(p, "/cmd_vel", 100)?)
        };
        let condition = match &command {
            CommandReader::Twist(r) => r.get_statuscondition(),
            CommandReader::Stamped(r) => r.get_statuscondition(),
        };
        dds(
            "watching /cmd_vel",
            condition.set_enabled_statuses(&[StatusKind::DataAvailable]),
        )?;
        let mut waitset = WaitSet::new();
        dds(
            "watching /cmd_vel",
            waitset.attach_condition(Condition::StatusCondition(condition)),
        )?;
        Ok(Dds {
            clock: writer(p, &publisher, "/clock", writer_qos(10, false, patience))?,
            tf: writer(p, &publisher, "/tf", writer_qos(100, false, patience))?,
            tf_static: writer(p, &publisher, "/tf_static", writer_qos(1, true, patience))?,
            odom: writer(p, &publisher, "/odom", writer_qos(10, false, patience))?,
            scans,
            cameras,
            command,
            waitset,
            pose: match &serve.pose_topic {
                Some(t) => Some(reader(p, t, 1000)?),
                None => None,
            },
            tf_in: if serve.pose_from_tf {
                Some(reader(p, "/tf", 1000)?)
            } else {
                None
            },
            map: match &serve.map_topic {
                Some(t) => Some(reader(p, t, 1)?),
                None => None,
            },
            participant,
        })
    }

    /// Waits until the controller's `/cmd_vel` publisher and a `/clock` subscriber have
    /// matched, at most `wait` real seconds.
    fn wait_for_controller(&self, wait: f64, mut stack: Option<&mut StackProcess>) -> Result<f64> {
        let start = Instant::now();
        loop {
            if let Some(p) = stack.as_deref_mut()
                && let Some(status) = p.exited()
            {
                bail!("the stack exited ({status}) before it matched");
            }
            let commands = match &self.command {
                CommandReader::Twist(r) => r.get_subscription_matched_status(),
                CommandReader::Stamped(r) => r.get_subscription_matched_status(),
            }
            .map(|m| m.current_count)
            .unwrap_or(0);
            let clocks = self
                .clock
                .get_publication_matched_status()
                .map(|m| m.current_count)
                .unwrap_or(0);
            if commands > 0 && clocks > 0 {
                // Matching is seen here when this side has matched; the controller's side
                // completes its half of the same exchange within milliseconds. Until it has,
                // a /clock would be lost to it.
                std::thread::sleep(SETTLE);
                return Ok(start.elapsed().as_secs_f64());
            }
            if start.elapsed().as_secs_f64() > wait {
                bail!(
                    "no controller matched within {wait} s: {} /cmd_vel publisher(s), {} /clock \
                     subscriber(s) (DDS domain {}); start the stack that drives the robot, on the \
                     same domain",
                    commands,
                    clocks,
                    self.participant.get_domain_id()
                );
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Waits, at most `patience` in all, until reliable subscribers have acknowledged all
    /// that every writer published: a write returns once its sample is queued, so the last
    /// ones (or the fragments of an image lost on the way and asked for again) may still be
    /// under way when the run ends. Returns the topics still unacknowledged.
    fn flush(&self, patience: Duration) -> Vec<String> {
        fn wait<T>(w: &DataWriter<T>, deadline: Instant) -> bool {
            let left = deadline.saturating_duration_since(Instant::now());
            w.wait_for_acknowledgments(DdsDuration::new(
                left.as_secs().min(i32::MAX as u64) as i32,
                left.subsec_nanos(),
            ))
            .is_ok()
        }
        let deadline = Instant::now() + patience;
        let mut acked = vec![
            ("/clock".to_string(), wait(&self.clock, deadline)),
            ("/tf".to_string(), wait(&self.tf, deadline)),
            ("/tf_static".to_string(), wait(&self.tf_static, deadline)),
            ("/odom".to_string(), wait(&self.odom, deadline)),
        ];
        for (name, w) in &self.scans {
            acked.push((format!("{name}'s scans"), wait(w, deadline)));
        }
        for c in &self.cameras {
            let n = &c.name;
            acked.extend([
                (format!("/{n}/rgb/image_raw"), wait(&c.rgb, deadline)),
                (format!("/{n}/rgb/camera_info"), wait(&c.rgb_info, deadline)),
                (format!("/{n}/depth/image_raw"), wait(&c.depth, deadline)),
                (
                    format!("/{n}/depth/camera_info"),
                    wait(&c.depth_info, deadline),
                ),
            ]);
        }
        acked
            .into_iter()
            .filter(|(_, ok)| !ok)
            .map(|(topic, _)| topic)
            .collect()
    }

    /// The pose estimates that arrived on the user's pose topic, as `(stamp, pose)`.
    fn take_poses(&self) -> Vec<(Time, Pose2)> {
        let Some(r) = &self.pose else {
            return Vec::new();
        };
        r.take(1000, ANY_SAMPLE_STATE, ANY_VIEW_STATE, ANY_INSTANCE_STATE)
            .unwrap_or_default()
            .into_iter()
            .filter_map(|s| s.data)
            .filter_map(|e| {
                dds::planar(&e.pose.position, &e.pose.orientation)
                    .map(|pose| (Time::from(e.header.stamp), pose))
            })
            .collect()
    }

    /// The newest `map → odom` that arrived on `/tf`, if any (frames named as ROS 2 does,
    /// without a leading `/`).
    fn take_map_odom(&self) -> Option<Pose2> {
        let frame = |f: &str| f.trim_start_matches('/').to_string();
        self.tf_in
            .as_ref()?
            .take(1000, ANY_SAMPLE_STATE, ANY_VIEW_STATE, ANY_INSTANCE_STATE)
            .unwrap_or_default()
            .into_iter()
            .filter_map(|s| s.data)
            .flat_map(|m| m.transforms)
            .filter(|t| frame(&t.header.frame_id) == "map" && frame(&t.child_frame_id) == "odom")
            .filter_map(|t| dds::planar(&t.transform.translation, &t.transform.rotation))
            .next_back()
    }

    /// The newest map that arrived on the user's map topic, if any.
    fn take_map(&self) -> Option<dds::OccupancyGrid> {
        self.map
            .as_ref()?
            .take(1, ANY_SAMPLE_STATE, ANY_VIEW_STATE, ANY_INSTANCE_STATE)
            .unwrap_or_default()
            .into_iter()
            .filter_map(|s| s.data)
            .next_back()
    }

    /// The commands that arrived, oldest first, as `(stamp, linear x, angular z)`; the stamp
    /// is `None` for a plain `Twist`.
    fn take_commands(&self) -> Vec<(Option<Time>, f64, f64)> {
        match &self.command {
            CommandReader::Twist(r) => r
                .take(100, ANY_SAMPLE_STATE, ANY_VIEW_STATE, ANY_INSTANCE_STATE)
                .unwrap_or_default()
                .into_iter()
                .filter_map(|s| s.data)
                .map(|t| (None, t.linear.x, t.angular.z))
                .collect(),
            CommandReader::Stamped(r) => r
                .take(100, ANY_SAMPLE_STATE, ANY_VIEW_STATE, ANY_INSTANCE_STATE)
                .unwrap_or_default()
                .into_iter()
                .filter_map(|s| s.data)
                .map(|t| {
                    (
                        Some(Time::from(t.header.stamp)),
                        t.twist.linear.x,
                        t.twist.angular.z,
                    )
                })
                .collect(),
        }
    }
}

/// The link node: publishes the robot's sensors and the clock, and takes the controller's
/// command at every control tick (see the module's notes).
pub struct Link {
    dds: Dds,
    timeout: Duration,
    wheel_base: f64,
    joints: Vec<JointConfig>,
    /// Each laser's mount: parent frame, frame, pose.
    mounts: Vec<(String, String, Pose)>,
    /// Commands taken and not yet applied: stamp (`TwistStamped`), forward speed, turn rate.
    queued: std::collections::VecDeque<(Option<Time>, f64, f64)>,
    /// Simulated time between the ticks that wait for a command (`None`: every tick).
    period: Option<futago_msgs::Duration>,
    /// Least simulated time between two published frames of a camera.
    camera_gap: Option<futago_msgs::Duration>,
    /// The binning of the cameras' images on the link (1: none).
    camera_scale: u32,
    /// The next tick that waits for a command.
    next_due: Time,
    last: Option<DriveCommand>,
    ticks: u64,
    /// Ticks that waited for a command, and those whose command came too late.
    waits: u64,
    late: u64,
    discarded: u64,
    matched_after: f64,
    estimates: Estimates,
}

/// What the user's stack estimated, taken from its topics as the run goes: its poses (the
/// trajectory `external`) and its newest map, scored as futago's own SLAM's are.
struct Estimates {
    pose_topic: Option<String>,
    /// Whether the pose is the user's `map → odom` (the newest, `map_odom`) composed with the
    /// odometry at each tick.
    from_tf: bool,
    map_odom: Option<Pose2>,
    map_topic: Option<String>,
    /// Poses by stamp; a later one of the same stamp replaces it.
    poses: std::collections::BTreeMap<Time, Pose2>,
    track: Trajectory,
    map: Option<OccupancyGrid>,
    maps: u64,
    /// The height of the band of the world the map is scored against: the first laser's.
    height: f64,
}

/// The metrics of the user's trajectory (`external.*`), declared so that gates may name them.
struct ExternalTrajectory;

impl crate::scenario::ModuleConfig for ExternalTrajectory {
    fn metric_names(
        &self,
        _spec: &crate::scenario::ScenarioSpec,
        _own: Option<&(dyn std::any::Any + Send + Sync)>,
    ) -> Vec<String> {
        crate::ground_truth::trajectory_metric_names("external")
    }
}

/// The metrics of the user's map (`external.map.*`), declared so that gates may name them.
struct ExternalMap;

impl crate::scenario::ModuleConfig for ExternalMap {
    fn metric_names(
        &self,
        _spec: &crate::scenario::ScenarioSpec,
        _own: Option<&(dyn std::any::Any + Send + Sync)>,
    ) -> Vec<String> {
        crate::ground_truth::map_metric_names("external.map")
    }
}

/// The files the user's estimates are written to in the run's folder (TUM; map_server).
const EXTERNAL_TRAJECTORY_FILE: &str = "external.txt";
const EXTERNAL_MAP_STEM: &str = "external_map";

impl Link {
    /// Takes what the user's stack published on its pose and map topics since the last call.
    fn take_estimates(&mut self) -> Result<()> {
        for (t, p) in self.dds.take_poses() {
            self.estimates.poses.insert(t, p);
        }
        if let Some(m) = self.dds.take_map_odom() {
            self.estimates.map_odom = Some(m);
        }
        if let Some(m) = self.dds.take_map() {
            let topic = self.estimates.map_topic.as_deref().unwrap_or_default();
            let grid = m
                .to_grid()
                .map_err(|e| anyhow::anyhow!("the map on {topic}: {e}"))?;
            self.estimates.map = Some(grid);
            self.estimates.maps += 1;
        }
        Ok(())
    }

    fn write<T: TypeSupport + Send + 'static>(w: &DataWriter<T>, what: &str, m: T) -> Result<()> {
        match w.write(m, None) {
            Err(DdsError::Timeout) => {
                bail!(
                    "DDS: publishing {what}: a reliable subscriber acknowledged nothing \
                     within --timeout. It stopped taking messages, or it loses them: large \
                     ones (camera images) are lost to a small UDP receive buffer on its machine; \
                     raise net.core.rmem_max there (ROS 2's DDS tuning guide), or lower \
                     --camera-rate"
                )
            }
            r => dds(&format!("publishing {what}"), r),
        }
    }

    /// The command for the tick at `now`, waiting for it at most the timeout: the next plain
    /// `Twist`, or the `TwistStamped` stamped `now` (older ones are discarded; later ones kept
    /// for their tick). A controller on its own timer of the link's `--period` stamps its
    /// command with the `/clock` that fired it, which is the tick the link waits at.
    fn command_for(&mut self, now: Time) -> Option<(f64, f64)> {
        let deadline = Instant::now() + self.timeout;
        loop {
            self.queued.extend(self.dds.take_commands());
            let before = self.queued.len();
            self.queued
                .retain(|(stamp, ..)| stamp.is_none_or(|t| t >= now));
            self.discarded += (before - self.queued.len()) as u64;
            if let Some(i) = self
                .queued
                .iter()
                .position(|(stamp, ..)| stamp.is_none_or(|t| t == now))
            {
                let (_, v, w) = self.queued.remove(i).expect("an index found");
                return Some((v, w));
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return None;
            }
            let step = left.min(Duration::from_millis(100));
            let _ = self
                .dds
                .waitset
                .wait(DdsDuration::new(step.as_secs() as i32, step.subsec_nanos()));
        }
    }
}

impl Node for Link {
    fn name(&self) -> &'static str {
        "serve.link"
    }

    fn streams(&self) -> Streams {
        let mut consumes = vec!["odometry".to_string()];
        consumes.extend(self.dds.scans.iter().map(|(n, _)| format!("scan/{n}")));
        consumes.extend(
            self.dds
                .cameras
                .iter()
                .map(|c| format!("camera/{}", c.name)),
        );
        Streams {
            consumes,
            publishes: vec!["cmd_vel".into()],
            ..Streams::default()
        }
    }

    fn start(&mut self, bus: &mut Bus) -> Result<()> {
        let statics = borrowed(&self.mounts);
        Self::write(
            &self.dds.tf_static,
            "/tf_static",
            dds::TfMessage::new(bus.now, &statics),
        )
    }

    fn on_odometry(&mut self, _o: &Odometry, bus: &mut Bus) -> Result<()> {
        let (odom, twist, tf) = odometry_frames(bus, &self.joints, self.wheel_base);
        Self::write(
            &self.dds.odom,
            "/odom",
            dds::Odometry::new(bus.now, "odom", "base_link", &odom, twist),
        )?;
        Self::write(&self.dds.tf, "/tf", dds::TfMessage::new(bus.now, &tf))
    }

    fn on_scan(&mut self, laser: &str, scan: &LaserScan, _bus: &mut Bus) -> Result<()> {
        if let Some((_, w)) = self.dds.scans.iter().find(|(n, _)| n == laser) {
            Self::write(w, laser, dds::LaserScan::from(scan))?;
        }
        Ok(())
    }

    fn wants_frame(&self, camera: &str, _bus: &Bus) -> bool {
        self.dds.cameras.iter().any(|c| c.name == camera)
    }

    /// The link publishes the frames the stack renders for itself, and never makes a camera
    /// render (as the bag, [`crate::stack::bag`]).
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
        _bus: &mut Bus,
    ) -> Result<()> {
        let gap = self.camera_gap;
        let Some(c) = self.dds.cameras.iter_mut().find(|c| c.name == camera) else {
            return Ok(());
        };
        let f = &frame.frame;
        if let (Some(last), Some(gap)) = (c.last, gap)
            && f.stamp - last < gap
        {
            return Ok(());
        }
        c.last = Some(f.stamp);
        c.published += 1;
        let (parent, on) = optical_parent(frame, &*truth);
        let tf = dds::TfMessage::new(f.stamp, &[(parent, c.frame.as_str(), on)]);
        Self::write(&self.dds.tf, "/tf", tf)?;
        let n = self.camera_scale;
        let info = |k: &Intrinsics| dds::CameraInfo::pinhole(f.stamp, &c.frame, &k.binned(n));
        if let Some(image) = &f.rgb {
            let image = if n > 1 {
                dds::Image::rgb8(f.stamp, &c.frame, &image.binned(n))
            } else {
                dds::Image::rgb8(f.stamp, &c.frame, image)
            };
            Self::write(&c.rgb, camera, image)?;
            Self::write(&c.rgb_info, camera, info(&f.rgb_intrinsics))?;
        }
        let depth = if n > 1 {
            dds::Image::depth(f.stamp, &c.frame, &f.depth.binned(n))
        } else {
            dds::Image::depth(f.stamp, &c.frame, &f.depth)
        };
        Self::write(&c.depth, camera, depth)?;
        Self::write(&c.depth_info, camera, info(&f.depth_intrinsics))
    }

    fn on_control(&mut self, bus: &mut Bus) -> Result<()> {
        let now = bus.now;
        Self::write(&self.dds.clock, "/clock", dds::Clock { clock: now.into() })?;
        self.ticks += 1;
        self.take_estimates()?;
        if let Some(m) = self.estimates.map_odom {
            // The pose in the map as tf gives it at this tick: map → odom ∘ odom → base_link.
            self.estimates.poses.insert(now, m.compose(&bus.odometry));
        }
        if now < self.next_due {
            return Ok(());
        }
        self.next_due = match self.period {
            Some(p) => self.next_due + p,
            None => now,
        };
        let command = self.command_for(now);
        self.waits += 1;
        let Some((v, w)) = command else {
            self.late += 1;
            return Ok(());
        };
        let half = w * self.wheel_base / 2.0;
        let cmd = DriveCommand::DriveDirect {
            left: v - half,
            right: v + half,
        };
        if self.last != Some(cmd) {
            self.last = Some(cmd);
            bus.command = Some(cmd);
        }
        Ok(())
    }

    /// The link drives to the scenario's end.
    fn finished(&self) -> bool {
        false
    }

    fn finish(&mut self, _bus: &mut Bus, out: Option<&Path>) -> Result<Report> {
        // What was published reaches the subscribers before the participant goes. A
        // subscriber gone by now cannot acknowledge; that changes no result, so it is said
        // and the run goes on.
        let late = self.dds.flush(self.timeout);
        if !late.is_empty() {
            eprintln!(
                "futago serve: warning: not acknowledged within --timeout at the end of the \
                 run: {}",
                late.join(", ")
            );
        }
        let e = &self.estimates;
        if e.pose_topic.is_some() || e.from_tf || e.map_topic.is_some() {
            // What the stack published in answer to the last /clock.
            std::thread::sleep(SETTLE);
            self.take_estimates()?;
        }
        let e = &mut self.estimates;
        let mut track = Trajectory::new(EXTERNAL);
        for (t, p) in &e.poses {
            track.push(*t, p);
        }
        let mut files = Vec::new();
        if let Some(dir) = out {
            if e.pose_topic.is_some() || e.from_tf {
                let from = match &e.pose_topic {
                    Some(topic) => topic.clone(),
                    None => "its map → odom on /tf and the odometry".into(),
                };
                let header = format!(
                    "# the pose estimates of the stack futago serve linked to, from {from}\n# timestamp tx ty tz qx qy qz qw\n"
                );
                track.write(dir, EXTERNAL_TRAJECTORY_FILE, &header)?;
                files.push(EXTERNAL_TRAJECTORY_FILE.to_string());
            }
            if let Some(map) = &e.map {
                map.write_map_server(dir, EXTERNAL_MAP_STEM)
                    .with_context(|| format!("writing {EXTERNAL_MAP_STEM}.pgm and .yaml"))?;
                files.extend([
                    format!("{EXTERNAL_MAP_STEM}.pgm"),
                    format!("{EXTERNAL_MAP_STEM}.yaml"),
                ]);
            }
        }
        e.track = track;
        let mut performance = serde_json::Map::new();
        performance.insert(
            "matched_after_s".into(),
            serde_json::json!(self.matched_after),
        );
        Ok(Report {
            summary: vec![(
                "serve".into(),
                serde_json::json!({
                    "ticks": self.ticks,
                    "commands_awaited": self.waits,
                    "late": self.late,
                    "discarded": self.discarded,
                    "deterministic": self.late == 0,
                    "camera_frames": self
                        .dds
                        .cameras
                        .iter()
                        .map(|c| (c.name.clone(), serde_json::json!(c.published)))
                        .collect::<serde_json::Map<_, _>>(),
                    "poses": (e.pose_topic.is_some() || e.from_tf).then_some(e.track.poses.len()),
                    "maps": e.map_topic.as_ref().map(|_| e.maps),
                }),
            )],
            files,
            map: e.map.clone(),
            trajectories: if e.track.poses.is_empty() {
                Vec::new()
            } else {
                vec![e.track.clone()]
            },
            performance,
            ..Report::default()
        })
    }

    /// The user's trajectory and map against the truth, as futago's SLAM is scored:
    /// `external.ate.*`, `external.rpe_1m.*`, `external.map.*`.
    fn score(&self, truth: &Truth) -> Result<Metrics> {
        let e = &self.estimates;
        let mut m = if e.track.poses.is_empty() {
            Metrics::default()
        } else {
            crate::ground_truth::score_trajectory(truth, EXTERNAL, &e.track.poses)
        };
        if let Some(map) = &e.map {
            let world = truth.world_map(map.resolution, e.height)?;
            let s = truth.scenario.start;
            let score = crate::ground_truth::map::score(map, &world, [s.x, s.y])
                .map_err(|e| anyhow::anyhow!("scoring the map from the linked stack: {e}"))?;
            m.insert_map("external.map", &score);
        }
        Ok(m)
    }
}

/// The link for scenario `s` on `domain`, with its DDS entities matched with the
/// controller's (waiting at most `o`'s `wait`; failing sooner if `stack`, the stack started
/// for the run, exits).
fn connect(
    s: &Scenario,
    domain: i32,
    o: &ServeOptions,
    stack: Option<&mut StackProcess>,
) -> Result<Link> {
    let height = match (s.lidars.first(), &o.map_topic) {
        (Some((c, _)), _) => c.xyz[2],
        (None, Some(_)) => bail!(
            "--map-topic: a map is scored against the world's band at its laser's height, and \
             {} has no laser",
            s.spec.name
        ),
        (None, None) => 0.0,
    };
    let patience = o.timeout();
    let link = Dds::new(s, domain, o, patience).context("starting the ROS 2 link")?;
    let matched_after = link.wait_for_controller(o.wait(), stack)?;
    Ok(Link {
        dds: link,
        timeout: patience,
        wheel_base: s.spec.robot.wheel_base,
        joints: s.movers.joints.clone(),
        mounts: laser_mounts(s),
        queued: Default::default(),
        period: o.period.map(futago_msgs::Duration::from_secs),
        camera_gap: o
            .camera_rate
            .map(|r| futago_msgs::Duration::from_secs(1.0 / r)),
        camera_scale: o.camera_scale.unwrap_or(1),
        next_due: Time::ZERO,
        waits: 0,
        last: None,
        ticks: 0,
        late: 0,
        discarded: 0,
        matched_after,
        estimates: Estimates {
            pose_topic: o.pose_topic.clone(),
            from_tf: o.pose_from_tf,
            map_odom: None,
            map_topic: o.map_topic.clone(),
            poses: Default::default(),
            track: Trajectory::new(EXTERNAL),
            map: None,
            maps: 0,
            height,
        },
    })
}

/// Runs `s` into `out` as `futago run` does. A scenario whose controller is `external` with
/// a `command` has that stack started for the run, linked over DDS and stopped after
/// ([`with_stack`]); `futago run`, `suite` and `tune` all run scenarios through here.
pub fn run_scenario(s: &Scenario, opts: &RunOptions, out: &Path) -> Result<(Value, Outcome)> {
    match started_stack(s) {
        None => crate::run::run(s, opts, out),
        Some(e) => with_stack(s, e, |link| run_with(s, opts, out, vec![link])),
    }
}

/// [`crate::run::evaluate`], starting the scenario's stack as [`run_scenario`] does.
pub fn evaluate_scenario(s: &Scenario, opts: &RunOptions) -> Result<crate::run::Scored> {
    match started_stack(s) {
        None => crate::run::evaluate(s, opts),
        Some(e) => with_stack(s, e, |link| crate::run::evaluate_with(s, opts, vec![link])),
    }
}

/// The scenario's external controller, when it names the command that starts its stack.
fn started_stack(s: &Scenario) -> Option<&ExternalConfig> {
    match controller(s) {
        ControllerConfig::External(e) if e.command.is_some() => Some(e),
        _ => None,
    }
}

/// Starts the stack `e` names on a DDS domain of its own, links `s` to it, gives the link
/// to `f` (which runs the scenario), and stops the stack, whatever `f` gave. An error carries
/// the stack's last output.
fn with_stack<T>(
    s: &Scenario,
    e: &ExternalConfig,
    f: impl FnOnce(Box<dyn Node>) -> Result<T>,
) -> Result<T> {
    let o = ServeOptions::default().over(e);
    let lease = DomainLease::take(o.domain)?;
    let mut stack = StackProcess::start(e, lease.domain)?;
    let r = connect(s, lease.domain, &o, Some(&mut stack)).and_then(|link| f(Box::new(link)));
    stack.stop();
    r.with_context(|| {
        format!(
            "the stack `{}` on DDS domain {}; its last output:\n{}",
            stack.what,
            lease.domain,
            stack.tail(20)
        )
    })
}

/// A DDS domain held for one run. Given, it is used as it is; else the first of 100 to 232
/// that no other futago run on this machine holds: each held domain is a lock on a file in
/// the temporary folder, released when the lease is dropped or the process ends. (Domain ids
/// below 100 are left to what the user runs outside futago, `ROS_DOMAIN_ID` 0 above all.)
struct DomainLease {
    domain: i32,
    _lock: Option<std::fs::File>,
}

impl DomainLease {
    fn take(domain: Option<i32>) -> Result<DomainLease> {
        if let Some(domain) = domain {
            return Ok(DomainLease {
                domain,
                _lock: None,
            });
        }
        let dir = std::env::temp_dir();
        for domain in 100..=232 {
            let path = dir.join(format!("futago-dds-domain-{domain}.lock"));
            let file = std::fs::OpenOptions::new()
                .create(true)
                .truncate(false)
                .write(true)
                .open(&path)
                .with_context(|| format!("opening {}", path.display()))?;
            if file.try_lock().is_ok() {
                return Ok(DomainLease {
                    domain,
                    _lock: Some(file),
                });
            }
        }
        bail!(
            "every DDS domain from 100 to 232 is held by another futago run on this machine \
             (locks in {})",
            dir.display()
        )
    }
}

/// A user's stack started for a run, in a process group of its own, its output in a log
/// file; stopped (SIGINT to the group, as Ctrl-C stops `ros2 launch`; SIGKILL after 5 s) by
/// [`StackProcess::stop`] or when dropped.
struct StackProcess {
    child: std::process::Child,
    log: PathBuf,
    /// The command line, for errors.
    what: String,
}

impl StackProcess {
    fn start(e: &ExternalConfig, domain: i32) -> Result<StackProcess> {
        use std::os::unix::process::CommandExt;
        let (mut command, what) = match &e.command {
            Some(StackCommand::Shell(line)) => {
                let mut c = std::process::Command::new("sh");
                c.arg("-c").arg(line);
                (c, line.clone())
            }
            Some(StackCommand::Argv(argv)) if !argv.is_empty() => {
                let mut c = std::process::Command::new(&argv[0]);
                c.args(&argv[1..]);
                (c, argv.join(" "))
            }
            _ => bail!("controller.command: expected the command that starts the stack"),
        };
        let log =
            std::env::temp_dir().join(format!("futago-stack-{}-{domain}.log", std::process::id()));
        let out = std::fs::File::create(&log)
            .with_context(|| format!("creating the stack's log {}", log.display()))?;
        let err = out.try_clone()?;
        let child = command
            .current_dir(&e.dir)
            .env("ROS_DOMAIN_ID", domain.to_string())
            .stdin(std::process::Stdio::null())
            .stdout(out)
            .stderr(err)
            .process_group(0)
            .spawn()
            .with_context(|| {
                format!(
                    "controller.command: starting `{what}` in {}",
                    e.dir.display()
                )
            })?;
        Ok(StackProcess { child, log, what })
    }

    /// How it ended, once it has.
    fn exited(&mut self) -> Option<std::process::ExitStatus> {
        self.child.try_wait().ok().flatten()
    }

    /// The last `n` lines it wrote.
    fn tail(&self, n: usize) -> String {
        let text = std::fs::read_to_string(&self.log).unwrap_or_default();
        let lines: Vec<&str> = text.lines().collect();
        lines[lines.len().saturating_sub(n)..].join("\n")
    }

    /// Stops its whole process group and reaps it.
    fn stop(&mut self) {
        let group = format!("-{}", self.child.id());
        let signal = |sig: &str| {
            let _ = std::process::Command::new("kill")
                .args([sig, "--", &group])
                .stderr(std::process::Stdio::null())
                .status();
        };
        if self.exited().is_none() {
            signal("-INT");
            let until = Instant::now() + Duration::from_secs(5);
            while self.exited().is_none() && Instant::now() < until {
                std::thread::sleep(Duration::from_millis(20));
            }
        }
        // What it left behind in its group, and itself if it ignored SIGINT.
        signal("-KILL");
        let _ = self.child.wait();
    }
}

impl Drop for StackProcess {
    fn drop(&mut self) {
        self.stop();
        let _ = std::fs::remove_file(&self.log);
    }
}

/// `futago serve`: loads the scenario with an external controller, links, waits for the
/// controller, runs in lock-step and scores as `futago run` does.
pub fn command(
    scenario: &Path,
    overlays: &[crate::overlay::Overlay],
    out: Option<PathBuf>,
    opts: &RunOptions,
    serve: &ServeOptions,
) -> Result<i32> {
    // A scenario whose controller is already external keeps its table: its link options
    // are the flags' defaults.
    let written = futago_sim::config::load_toml::<toml::Table>(scenario).ok();
    let is_external = written
        .as_ref()
        .and_then(|t| {
            t.get("controller")?
                .get("type")?
                .as_str()
                .map(|t| t == "external")
        })
        .unwrap_or(false);
    let replaced = if is_external {
        toml::Table::new()
    } else {
        toml::Table::from_iter([(
            "controller".to_string(),
            toml::Value::Table(toml::Table::from_iter([(
                "type".to_string(),
                toml::Value::String("external".into()),
            )])),
        )])
    };
    serve.check()?;
    // The user's estimates' metrics, for the scenario's gates to name.
    let mut modules = crate::stack::configs(crate::stack::MODULES);
    if serve.takes_pose() {
        modules.push(&ExternalTrajectory);
    }
    if serve.map_topic.is_some() {
        modules.push(&ExternalMap);
    }
    let s = Scenario::load_replacing(scenario, overlays, &replaced, &modules)?;
    let serve = match controller(&s) {
        ControllerConfig::External(e) => serve.over(e),
        _ => serve.clone(),
    };
    let domain = match serve.domain {
        Some(d) => d,
        None => match std::env::var("ROS_DOMAIN_ID") {
            Ok(v) => v.trim().parse().map_err(|_| {
                anyhow::anyhow!("ROS_DOMAIN_ID: expected a domain id from 0 to 232, found `{v}`")
            })?,
            Err(_) => 0,
        },
    };
    if !(0..=232).contains(&domain) {
        bail!(
            "--domain (or ROS_DOMAIN_ID): expected a DDS domain id from 0 to 232, found {domain}"
        );
    }
    let out = out.unwrap_or_else(|| PathBuf::from("out").join(&s.spec.name));
    eprintln!(
        "futago serve: {} on DDS domain {domain}; waiting for a controller (/cmd_vel {}, /clock)",
        s.spec.name,
        if serve.stamped {
            "TwistStamped"
        } else {
            "Twist"
        }
    );
    let node = connect(&s, domain, &serve, None)?;
    let (summary, o) = run_with(&s, opts, &out, vec![Box::new(node)])?;
    if summary["serve"]["deterministic"] == false {
        eprintln!(
            "futago serve: {} of {} commands came later than --timeout: this run is not deterministic",
            summary["serve"]["late"], summary["serve"]["ticks"]
        );
    }
    Ok(print_result(&s, &summary, &o, &out))
}
