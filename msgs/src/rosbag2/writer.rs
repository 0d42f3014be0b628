//! Writing a rosbag2 bag: one MCAP file (profile `ros2`, `ros2msg` schemas with their
//! dependencies, CDR payloads, log time = the simulation's time) and rosbag2's
//! `metadata.yaml` (version 5) beside it, so `ros2 bag play`, Foxglove and `rosbags` open the
//! folder. MCAP's own chunk compression is left off: its codecs are C libraries in the `mcap`
//! crate, and futago's messages are mostly floats, which compress poorly.

use crate::Time;
use crate::ros2msg;
use std::collections::BTreeMap;
use std::fs::File;
use std::io::{self, BufWriter};
use std::path::{Path, PathBuf};

/// `/clock`'s type.
const CLOCK_TYPE: &str = "rosgraph_msgs/msg/Clock";

/// A topic of a bag: its name, its type (`pkg/msg/Type`), and whether it is latched.
#[derive(Debug, Clone)]
struct Topic {
    name: String,
    ty: &'static str,
    /// Latched (`/tf_static`, `/map`): durability transient local, so a late subscriber gets
    /// the last message.
    latched: bool,
    channel: Option<u16>,
    count: usize,
}

/// rosbag2's QoS profile of a topic, as the YAML string it keeps in a channel's metadata and
/// in `metadata.yaml`: reliable, keep last; transient local when latched, else volatile.
pub fn qos(latched: bool) -> String {
    format!(
        "- history: 1\n  depth: {}\n  reliability: 1\n  durability: {}\n  deadline:\n    sec: 0\n    nsec: 0\n  lifespan:\n    sec: 0\n    nsec: 0\n  liveliness: 1\n  liveliness_lease_duration:\n    sec: 0\n    nsec: 0\n  avoid_ros_namespace_conventions: false\n",
        if latched { 1 } else { 10 },
        if latched { 1 } else { 2 }
    )
}

/// A bag being written into a folder: `DIR/NAME.mcap` (NAME the bag folder's name, as `ros2
/// bag record` names it) and, at [`BagWriter::finish`], `DIR/metadata.yaml`. Topics are declared
/// with [`BagWriter::topic`]; a topic's schema and channel are written with its first
/// message, so a topic without messages is in neither file. `/clock` is written before the
/// first message of each new log time.
pub struct BagWriter {
    mcap: mcap::Writer<BufWriter<File>>,
    dir: PathBuf,
    file_name: String,
    topics: Vec<Topic>,
    clock: usize,
    start: Option<Time>,
    last: Time,
}

fn other(path: &Path, e: impl std::fmt::Display) -> io::Error {
    io::Error::other(format!("{}: {e}", path.display()))
}

impl BagWriter {
    /// Starts the bag `name` in the existing folder `dir` (where the bag folder is being made
    /// under another name, to be renamed to `name` when whole).
    pub fn create(dir: &Path, name: &str) -> io::Result<BagWriter> {
        let file_name = format!("{name}.mcap");
        let path = dir.join(&file_name);
        let f = File::create(&path).map_err(|e| other(&path, e))?;
        let mcap = mcap::WriteOptions::new()
            .profile("ros2")
            .compression(None)
            .create(BufWriter::new(f))
            .map_err(|e| other(&path, e))?;
        let mut w = BagWriter {
            mcap,
            dir: dir.to_path_buf(),
            file_name,
            topics: Vec::new(),
            clock: 0,
            start: None,
            last: Time::ZERO,
        };
        w.clock = w.topic("/clock", CLOCK_TYPE, false);
        Ok(w)
    }

    /// The index of topic `name` of type `ty` (`pkg/msg/Type`, one that
    /// [`ros2msg::schema`] defines), declared now if it is new.
    pub fn topic(&mut self, name: &str, ty: &'static str, latched: bool) -> usize {
        if let Some(i) = self.topics.iter().position(|t| t.name == name) {
            return i;
        }
        self.topics.push(Topic {
            name: name.to_string(),
            ty,
            latched,
            channel: None,
            count: 0,
        });
        self.topics.len() - 1
    }

    /// Writes the CDR message `data` on topic `topic` (an index from [`BagWriter::topic`]),
    /// logged at `t`; `/clock` reads `t` first if it is later than every log time so far.
    pub fn write(&mut self, topic: usize, t: Time, data: &[u8]) -> io::Result<()> {
        if self.start.is_none() || t > self.last {
            self.start.get_or_insert(t);
            self.last = t;
            if topic != self.clock {
                self.put(self.clock, t, &ros2msg::clock(t))?;
            }
        }
        self.put(topic, t, data)
    }

    fn put(&mut self, topic: usize, t: Time, data: &[u8]) -> io::Result<()> {
        let path = self.dir.join(&self.file_name);
        let tp = &mut self.topics[topic];
        let channel = match tp.channel {
            Some(c) => c,
            None => {
                let schema = ros2msg::schema(tp.ty)
                    .ok_or_else(|| other(&path, format!("no definition of {}", tp.ty)))?;
                let sid = self
                    .mcap
                    .add_schema(tp.ty, "ros2msg", schema.as_bytes())
                    .map_err(|e| other(&path, e))?;
                let meta = BTreeMap::from([("offered_qos_profiles".to_string(), qos(tp.latched))]);
                let c = self
                    .mcap
                    .add_channel(sid, &tp.name, "cdr", &meta)
                    .map_err(|e| other(&path, e))?;
                tp.channel = Some(c);
                c
            }
        };
        let ns = t.nanos().max(0) as u64;
        self.mcap
            .write_to_known_channel(
                &mcap::records::MessageHeader {
                    channel_id: channel,
                    sequence: tp.count as u32,
                    log_time: ns,
                    publish_time: ns,
                },
                data,
            )
            .map_err(|e| other(&path, e))?;
        tp.count += 1;
        Ok(())
    }

    /// Ends the MCAP file (its summary and index) and writes `metadata.yaml`. Returns the
    /// count of messages by topic, for the topics that have any, in the order declared.
    pub fn finish(mut self) -> io::Result<Vec<(String, usize)>> {
        let path = self.dir.join(&self.file_name);
        self.mcap.finish().map_err(|e| other(&path, e))?;
        let meta = self.dir.join("metadata.yaml");
        std::fs::write(&meta, self.metadata()).map_err(|e| other(&meta, e))?;
        Ok(self
            .topics
            .iter()
            .filter(|t| t.count > 0)
            .map(|t| (t.name.clone(), t.count))
            .collect())
    }

    /// rosbag2's `metadata.yaml` (version 5) for the one MCAP file.
    fn metadata(&self) -> String {
        let total: usize = self.topics.iter().map(|t| t.count).sum();
        let start = self.start.unwrap_or(Time::ZERO);
        let duration = (self.last.nanos() - start.nanos()).max(0);
        let mut topics = String::new();
        for t in self.topics.iter().filter(|t| t.count > 0) {
            let q = qos(t.latched).replace('\n', "\\n");
            topics += &format!(
                "    - topic_metadata:\n        name: {}\n        type: {}\n        serialization_format: cdr\n        offered_qos_profiles: \"{q}\"\n      message_count: {}\n",
                t.name, t.ty, t.count
            );
        }
        let file = &self.file_name;
        format!(
            "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: mcap\n  duration:\n    nanoseconds: {duration}\n  starting_time:\n    nanoseconds_since_epoch: {}\n  message_count: {total}\n  topics_with_message_count:\n{topics}  compression_format: \"\"\n  compression_mode: \"\"\n  relative_file_paths:\n    - {file}\n  files:\n    - path: {file}\n      starting_time:\n        nanoseconds_since_epoch: {}\n      duration:\n        nanoseconds: {duration}\n      message_count: {total}\n",
            start.nanos(),
            start.nanos()
        )
    }
}
