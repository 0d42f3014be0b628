//! Writing ROS 1 bags (format 2.0) of laser scans, odometry, tf and annotated people: the
//! fixtures from which tests make cut, damaged and scan-only bags, and a way to rewrite a
//! log's streams (a scan-only copy of a bag, say). Written for futago from the ROS wiki's
//! "Bags/Format/2.0", as the reader is.
//!
//! Messages go into chunks of `messages_per_chunk`, each connection's record in the chunk of
//! its first message and again after the chunks, as `rosbag record` lays a bag out. No index
//! records are written: futago's reader (like `rosbag reindex`) walks the records themselves.

use super::{field, header_seq, record, ros_string};
use crate::{LaserScan, Pose2, Time};
use std::io::Read;

/// A bag being written in memory.
pub struct BagWriter {
    compression: String,
    messages_per_chunk: usize,
    /// Each connection's topic and type, by id.
    connections: Vec<(String, String)>,
    /// Whether each connection's record is in a chunk already.
    defined: Vec<bool>,
    /// The open chunk's records and message count.
    open: Vec<u8>,
    in_open: usize,
    /// The chunk records written so far.
    chunks: Vec<u8>,
}

impl BagWriter {
    /// A bag whose chunks are compressed by `compression` (`none`, `bz2` or `lz4`), each
    /// holding at most `messages_per_chunk` messages (at least 1).
    pub fn new(compression: &str, messages_per_chunk: usize) -> BagWriter {
        BagWriter {
            compression: compression.to_string(),
            messages_per_chunk: messages_per_chunk.max(1),
            connections: Vec::new(),
            defined: Vec::new(),
            open: Vec::new(),
            in_open: 0,
            chunks: Vec::new(),
        }
    }

    /// Adds a connection for `topic` of message type `ty` (`sensor_msgs/LaserScan`, …); its id.
    pub fn connection(&mut self, topic: &str, ty: &str) -> u32 {
        self.connections.push((topic.to_string(), ty.to_string()));
        self.defined.push(false);
        (self.connections.len() - 1) as u32
    }

    fn connection_record(&self, id: u32) -> Vec<u8> {
        let (topic, ty) = &self.connections[id as usize];
        record(
            &[
                field("op", &[0x07]),
                field("conn", &id.to_le_bytes()),
                field("topic", topic.as_bytes()),
            ],
            &[
                field("topic", topic.as_bytes()),
                field("type", ty.as_bytes()),
            ]
            .concat(),
        )
    }

    /// Writes the serialised message `body` on connection `conn`, recorded at `time`.
    pub fn write(&mut self, conn: u32, time: Time, body: &[u8]) {
        if !self.defined[conn as usize] {
            self.defined[conn as usize] = true;
            let r = self.connection_record(conn);
            self.open.extend(r);
        }
        let t = time.nanos().max(0);
        let stamp = [
            ((t / 1_000_000_000) as u32).to_le_bytes(),
            ((t % 1_000_000_000) as u32).to_le_bytes(),
        ]
        .concat();
        self.open.extend(record(
            &[
                field("op", &[0x02]),
                field("conn", &conn.to_le_bytes()),
                field("time", &stamp),
            ],
            body,
        ));
        self.in_open += 1;
        if self.in_open >= self.messages_per_chunk {
            self.close_chunk();
        }
    }

    fn close_chunk(&mut self) {
        if self.open.is_empty() {
            return;
        }
        let inner = std::mem::take(&mut self.open);
        self.in_open = 0;
        let data = compress(&self.compression, &inner);
        self.chunks.extend(record(
            &[
                field("op", &[0x05]),
                field("compression", self.compression.as_bytes()),
                field("size", &(inner.len() as u32).to_le_bytes()),
            ],
            &data,
        ));
    }

    /// The whole bag: magic line, bag header, chunks, then every connection record again.
    pub fn finish(mut self) -> Vec<u8> {
        self.close_chunk();
        let mut out = b"#ROSBAG V2.0\n".to_vec();
        out.extend(record(&[field("op", &[0x03])], &[]));
        out.extend(&self.chunks);
        for id in 0..self.connections.len() as u32 {
            out.extend(self.connection_record(id));
        }
        out
    }
}

/// `inner` compressed as a chunk of `compression` (`bz2`, `lz4`; anything else is stored).
pub(super) fn compress(compression: &str, inner: &[u8]) -> Vec<u8> {
    match compression {
        "bz2" => {
            let mut z = Vec::new();
            bzip2::read::BzEncoder::new(inner, bzip2::Compression::default())
                .read_to_end(&mut z)
                .expect("bz2 compression in memory cannot fail");
            z
        }
        "lz4" => {
            use std::io::Write;
            let mut e = lz4_flex::frame::FrameEncoder::new(Vec::new());
            e.write_all(inner)
                .expect("lz4 compression in memory cannot fail");
            e.finish().expect("lz4 compression in memory cannot fail")
        }
        _ => inner.to_vec(),
    }
}

fn stamp_bytes(seq: u32, stamp: Time, frame: &str) -> Vec<u8> {
    let t = stamp.nanos().max(0);
    let mut m = header_seq(seq, (t / 1_000_000_000) as u32, frame);
    // header_seq writes whole seconds; put the nanoseconds in.
    let ns = ((t % 1_000_000_000) as u32).to_le_bytes();
    m[8..12].copy_from_slice(&ns);
    m
}

/// A `sensor_msgs/LaserScan`'s seven numbers after its header, as ROS 1 and ROS 2 both lay them
/// out: `angle_min`, `angle_max` (the last beam's angle), `angle_increment`, `time_increment`,
/// `scan_time` (one beam's time for each beam), `range_min` and `range_max`.
pub fn scan_fields(scan: &LaserScan) -> [f32; 7] {
    let n = scan.ranges.len();
    let angle_max = scan.angle_min + scan.angle_increment * n.saturating_sub(1) as f64;
    [
        scan.angle_min,
        angle_max,
        scan.angle_increment,
        scan.time_increment,
        scan.time_increment * n as f64,
        scan.range_min,
        scan.range_max,
    ]
    .map(|v| v as f32)
}

/// A `sensor_msgs/LaserScan` numbered `seq` (no intensities).
pub fn laser_scan_message(seq: u32, scan: &LaserScan) -> Vec<u8> {
    let mut m = stamp_bytes(seq, scan.stamp, &scan.frame);
    let n = scan.ranges.len();
    for v in scan_fields(scan) {
        m.extend(v.to_le_bytes());
    }
    m.extend((n as u32).to_le_bytes());
    for r in &scan.ranges {
        m.extend(r.to_le_bytes());
    }
    m.extend(0u32.to_le_bytes());
    m
}

/// A `nav_msgs/Odometry` numbered `seq`: `child` (the base) at `pose` in `frame`, no twist.
pub fn odometry_message(seq: u32, stamp: Time, frame: &str, child: &str, pose: Pose2) -> Vec<u8> {
    let mut m = stamp_bytes(seq, stamp, frame);
    m.extend(ros_string(child));
    let (s, c) = (pose.theta / 2.0).sin_cos();
    for v in [pose.x, pose.y, 0.0, 0.0, 0.0, s, c] {
        m.extend(v.to_le_bytes());
    }
    m.extend(vec![0u8; 36 * 8 + 6 * 8 + 36 * 8]);
    m
}

/// A `leg_tracker/Person`: `id` at `position` (m, in the laser's frame).
pub fn person_message(id: u32, position: [f64; 2]) -> Vec<u8> {
    let mut m = Vec::new();
    for v in [position[0], position[1], 0.0, 0.0, 0.0, 0.0, 1.0] {
        m.extend(v.to_le_bytes());
    }
    m.extend(id.to_le_bytes());
    m
}
