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
use futago_msgs::rosbag2::writer::BagWriter;
use futago_msgs::{Time, carmen, tum};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The export's topics in the order they are declared: name, type, latched.
const TOPICS: &[(&str, &str, bool)] = &[
    ("/tf_static", "tf2_msgs/msg/TFMessage", true),
    ("/tf", "tf2_msgs/msg/TFMessage", false),
    ("/odom", "nav_msgs/msg/Odometry", false),
    ("/scan", "sensor_msgs/msg/LaserScan", false),
    ("/scan_rear", "sensor_msgs/msg/LaserScan", false),
    ("/ground_truth/pose", "geometry_msgs/msg/PoseStamped", false),
    ("/map", "nav_msgs/msg/OccupancyGrid", true),
];

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
    let topic = |name: &str| TOPICS.iter().position(|t| t.0 == name).expect("a topic");
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
            ros2msg::odometry(o.stamp, "odom", "base_link", &p, [0.0; 2]),
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
    // By time, then in the topics' order, then as made.
    messages.sort_by_key(|m| (m.0, m.1));

    let name = out
        .file_name()
        .map(|n| n.to_string_lossy().to_string())
        .unwrap_or_else(|| "bag".into());
    let counts = write_atomically(out, force, "export", |tmp| {
        let mut bag = BagWriter::create(tmp, &name)?;
        let ids: Vec<usize> = TOPICS
            .iter()
            .map(|(name, ty, latched)| bag.topic(name, ty, *latched))
            .collect();
        for (t, k, data) in &messages {
            bag.write(ids[*k], *t, data)?;
        }
        Ok(bag.finish()?)
    })?;
    Ok(Exported {
        file: out.join(format!("{name}.mcap")),
        messages: counts.into_iter().collect(),
    })
}
