//! `futago export RUN_FOLDER`: a finished run as a ROS 2 bag, an MCAP file (profile `ros2`,
//! `ros2msg` schemas, CDR payloads, log time = simulation time) with rosbag2's
//! `metadata.yaml` beside it, so `ros2 bag play`, Foxglove and `rosbags` open it.
//!
//! What a finished run holds, and so what an export has: the scans with the odometry at each
//! (`scans.clf`: `/scan` or `/scan_rear`, each laser in its own frame, with its mount on
//! `/tf_static`), the Create's odometry (`odometry.txt`: `/odom`, and `odom → base_link` on
//! `/tf`), the true pose (`groundtruth.txt`: `/ground_truth/pose` in frame `world`), the map
//! the run's SLAM built (`slam_map.yaml`, or a replay's `map.yaml`: `/map`, latched), and
//! `/clock` at every stamp. What only a live run has
//! (per-step tf of joints, the people's truth, camera images) is not in a run folder.

use crate::run::write_atomically;
use anyhow::{Context, Result, bail};
use futago_msgs::ros2msg::{self, Pose};
use futago_msgs::{Time, carmen, tum};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// One topic of the export.
struct Topic {
    name: &'static str,
    ty: &'static str,
    /// Latched (`/tf_static`, `/map`): durability transient local, so a late subscriber gets it.
    latched: bool,
}

const TOPICS: &[Topic] = &[
    Topic {
        name: "/clock",
        ty: "rosgraph_msgs/msg/Clock",
        latched: false,
    },
    Topic {
        name: "/tf_static",
        ty: "tf2_msgs/msg/TFMessage",
        latched: true,
    },
    Topic {
        name: "/tf",
        ty: "tf2_msgs/msg/TFMessage",
        latched: false,
    },
    Topic {
        name: "/odom",
        ty: "nav_msgs/msg/Odometry",
        latched: false,
    },
    Topic {
        name: "/scan",
        ty: "sensor_msgs/msg/LaserScan",
        latched: false,
    },
    Topic {
        name: "/scan_rear",
        ty: "sensor_msgs/msg/LaserScan",
        latched: false,
    },
    Topic {
        name: "/ground_truth/pose",
        ty: "geometry_msgs/msg/PoseStamped",
        latched: false,
    },
    Topic {
        name: "/map",
        ty: "nav_msgs/msg/OccupancyGrid",
        latched: true,
    },
];

/// rosbag2's QoS profile of a topic, as the YAML string it keeps in a channel's metadata and
/// in `metadata.yaml`: reliable, keep last; transient local when latched, else volatile.
fn qos(latched: bool) -> String {
    format!(
        "- history: 1\n  depth: {}\n  reliability: 1\n  durability: {}\n  deadline:\n    sec: 0\n    nsec: 0\n  lifespan:\n    sec: 0\n    nsec: 0\n  liveliness: 1\n  liveliness_lease_duration:\n    sec: 0\n    nsec: 0\n  avoid_ros_namespace_conventions: false\n",
        if latched { 1 } else { 10 },
        if latched { 1 } else { 2 }
    )
}

/// What an export wrote: messages by topic.
pub struct Exported {
    pub file: PathBuf,
    pub messages: BTreeMap<String, usize>,
}

/// The folder an export of `run` goes to by default: `RUN.ros2` beside it.
pub fn default_out(run: &Path) -> PathBuf {
    let name = run
        .file_name()
        .map(|n| n.to_string_lossy().to_string())
        .unwrap_or_else(|| "run".into());
    crate::output::parent_of(run).join(format!("{name}.ros2"))
}

/// `futago export RUN [--out DIR] [--force]`: exports and prints what was written.
pub fn command(run: &Path, out: Option<PathBuf>, force: bool) -> Result<i32> {
    let out = out.unwrap_or_else(|| default_out(run));
    let e = export(run, &out, force)?;
    println!(
        "wrote {}: {}",
        e.file.display(),
        e.messages
            .iter()
            .map(|(t, n)| format!("{t} {n}"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    Ok(0)
}

/// Writes the run folder `run` as a rosbag2 bag in `out` (`out/NAME.mcap` and
/// `out/metadata.yaml`), whole or not at all.
pub fn export(run: &Path, out: &Path, force: bool) -> Result<Exported> {
    let scans_path = run.join("scans.clf");
    if !scans_path.is_file() {
        bail!(
            "{}: not a run folder (no scans.clf); `futago export` takes the folder a `futago run` wrote",
            run.display()
        );
    }
    let text = std::fs::read_to_string(&scans_path)
        .with_context(|| format!("reading {}", scans_path.display()))?;
    let log = carmen::read(&text).map_err(|e| anyhow::anyhow!("{}: {e}", scans_path.display()))?;
    let trajectory = |name: &str| -> Result<Vec<tum::Stamped>> {
        let p = run.join(name);
        if !p.is_file() {
            return Ok(Vec::new());
        }
        let t = std::fs::read_to_string(&p).with_context(|| format!("reading {}", p.display()))?;
        tum::parse(&t).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))
    };
    let odometry = trajectory("odometry.txt")?;
    let truth = trajectory("groundtruth.txt")?;
    // A run's SLAM map, or a replay's.
    let map_path = ["slam_map.yaml", "map.yaml"]
        .iter()
        .map(|n| run.join(n))
        .find(|p| p.is_file())
        .unwrap_or_else(|| run.join("slam_map.yaml"));
    let map = if map_path.is_file() {
        Some(
            futago_msgs::map_server::read(&map_path)
                .map_err(|e| anyhow::anyhow!("{}: {e}", map_path.display()))?,
        )
    } else {
        None
    };

    // Every message, with its topic's index and its log time; sorted, then written.
    let mut messages: Vec<(Time, usize, Vec<u8>)> = Vec::new();
    let topic = |name: &str| TOPICS.iter().position(|t| t.name == name).expect("a topic");
    let start = log
        .scans
        .first()
        .map(|s| s.scan.stamp)
        .into_iter()
        .chain(odometry.first().map(|s| s.stamp))
        .chain(truth.first().map(|s| s.stamp))
        .min()
        .unwrap_or(Time::ZERO);
    // Each laser's mount, once, on /tf_static at the start.
    let mut mounts: BTreeMap<String, Pose> = BTreeMap::new();
    for s in &log.scans {
        mounts
            .entry(s.scan.frame.clone())
            .or_insert_with(|| Pose::planar(s.mount.x, s.mount.y, s.mount.theta));
        let name = if s.scan.frame == "rear" {
            "/scan_rear"
        } else {
            "/scan"
        };
        messages.push((s.scan.stamp, topic(name), ros2msg::laser_scan(&s.scan)));
    }
    let statics: Vec<(&str, &str, Pose)> = mounts
        .iter()
        .map(|(f, p)| ("base_link", f.as_str(), *p))
        .collect();
    messages.push((start, topic("/tf_static"), ros2msg::tf(start, &statics)));
    for o in &odometry {
        let p = Pose::from(&o.pose);
        messages.push((
            o.stamp,
            topic("/odom"),
            ros2msg::odometry(o.stamp, "odom", "base_link", &p),
        ));
        messages.push((
            o.stamp,
            topic("/tf"),
            ros2msg::tf(o.stamp, &[("odom", "base_link", p)]),
        ));
    }
    for g in &truth {
        let p = Pose::from(&g.pose);
        messages.push((
            g.stamp,
            topic("/ground_truth/pose"),
            ros2msg::pose_stamped(g.stamp, "world", &p),
        ));
    }
    if let Some(g) = &map {
        let end = messages.iter().map(|m| m.0).max().unwrap_or(start);
        messages.push((end, topic("/map"), ros2msg::occupancy_grid(end, "map", g)));
    }
    let stamps: std::collections::BTreeSet<Time> = messages.iter().map(|m| m.0).collect();
    for t in stamps {
        messages.push((t, topic("/clock"), ros2msg::clock(t)));
    }
    // By time, /clock first at each, then in the topics' order, then as made.
    messages.sort_by_key(|m| (m.0, m.1));

    let name = out
        .file_name()
        .map(|n| n.to_string_lossy().to_string())
        .unwrap_or_else(|| "run".into());
    let file_name = format!("{name}.mcap");
    let counts = write_atomically(out, force, "export", |tmp| {
        let path = tmp.join(&file_name);
        let counts = write_mcap(&path, &messages)?;
        let end = messages.last().map_or(start, |m| m.0);
        std::fs::write(
            tmp.join("metadata.yaml"),
            metadata(&file_name, start, end, &counts),
        )
        .context("writing metadata.yaml")?;
        Ok(counts)
    })?;
    Ok(Exported {
        file: out.join(&file_name),
        messages: TOPICS
            .iter()
            .zip(counts)
            .filter(|(_, n)| *n > 0)
            .map(|(t, n)| (t.name.to_string(), n))
            .collect(),
    })
}

/// Writes `messages` (log time, topic index, CDR payload; in order) to the MCAP file `path`:
/// each topic's schema and channel at its first message. Returns the count by topic.
fn write_mcap(path: &Path, messages: &[(Time, usize, Vec<u8>)]) -> Result<Vec<usize>> {
    let f = std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
    let mut w = mcap::WriteOptions::new()
        .profile("ros2")
        .create(std::io::BufWriter::new(f))
        .with_context(|| format!("writing {}", path.display()))?;
    let mut channels = vec![None; TOPICS.len()];
    let mut counts = vec![0usize; TOPICS.len()];
    for (t, k, data) in messages {
        let ch = match channels[*k] {
            Some(c) => c,
            None => {
                let tp = &TOPICS[*k];
                let schema = ros2msg::schema(tp.ty).expect("every topic's type is defined");
                let sid = w.add_schema(tp.ty, "ros2msg", schema.as_bytes())?;
                let meta = BTreeMap::from([("offered_qos_profiles".to_string(), qos(tp.latched))]);
                let c = w.add_channel(sid, tp.name, "cdr", &meta)?;
                channels[*k] = Some(c);
                c
            }
        };
        let ns = t.nanos().max(0) as u64;
        w.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id: ch,
                sequence: counts[*k] as u32,
                log_time: ns,
                publish_time: ns,
            },
            data,
        )?;
        counts[*k] += 1;
    }
    w.finish()?;
    Ok(counts)
}

/// rosbag2's `metadata.yaml` (version 5) for one MCAP file of `counts` messages by topic.
fn metadata(file: &str, start: Time, end: Time, counts: &[usize]) -> String {
    let total: usize = counts.iter().sum();
    let duration = (end.nanos() - start.nanos()).max(0);
    let mut topics = String::new();
    for (t, n) in TOPICS.iter().zip(counts) {
        if *n == 0 {
            continue;
        }
        let q = qos(t.latched).replace('\n', "\\n");
        topics += &format!(
            "    - topic_metadata:\n        name: {}\n        type: {}\n        serialization_format: cdr\n        offered_qos_profiles: \"{q}\"\n      message_count: {n}\n",
            t.name, t.ty
        );
    }
    format!(
        "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: mcap\n  duration:\n    nanoseconds: {duration}\n  starting_time:\n    nanoseconds_since_epoch: {}\n  message_count: {total}\n  topics_with_message_count:\n{topics}  compression_format: \"\"\n  compression_mode: \"\"\n  relative_file_paths:\n    - {file}\n  files:\n    - path: {file}\n      starting_time:\n        nanoseconds_since_epoch: {}\n      duration:\n        nanoseconds: {duration}\n      message_count: {total}\n",
        start.nanos(),
        start.nanos()
    )
}
