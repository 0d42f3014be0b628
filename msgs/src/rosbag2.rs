//! ROS 2 bags: MCAP files (Foxglove's `mcap` crate walks the records) and rosbag2's SQLite3
//! storage (`.db3` files, read with `rusqlite`), their messages in CDR (the OMG's Common Data
//! Representation, as ROS 2's middleware serialises them; decoded here for the few types futago
//! reads), read into the same [`Log`] a ROS 1 bag gives ([`crate::rosbag`]).
//!
//! A rosbag2 bag is a folder: `metadata.yaml` names its storage (`sqlite3` or `mcap`), its files
//! in order, and its compression (none, or zstd per file or per message). An MCAP file also
//! reads alone, being self-describing; a `.db3` does not (its compression is in the metadata).
//!
//! What differs from ROS 1: a ROS 2 header has no `seq`, so the late stamps that a ROS 1
//! bag's numbering repairs ([`crate::rosbag`]'s `acquisition_times`) are kept as stamped. Types
//! are named `pkg/msg/Type` (read as `pkg/Type`, so `--scan-topic` and the skipped counts
//! speak as for ROS 1). MCAP chunks compressed with lz4 are decoded by `lz4_flex`, zstd by
//! `ruzstd` (both pure Rust).

use crate::carmen::{Log, ReadOptions};
use crate::rosbag::{BagError, Raw, Transform, assemble, checked_position, frame_name, yaw_of};
use crate::{LaserScan, Pose2, Time};
use std::collections::HashMap;
use std::io::Read;
use std::path::{Path, PathBuf};

pub mod writer;

/// Reads a ROS 2 bag at `path`: a rosbag2 folder (with `metadata.yaml`), an MCAP file, or a
/// `.db3` file whose folder holds the metadata.
pub fn read_path(path: &Path, o: &ReadOptions) -> Result<Log, String> {
    if path.is_dir() {
        return read_folder(path, o);
    }
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    match ext.as_str() {
        "mcap" => {
            let bytes =
                std::fs::read(path).map_err(|e| format!("{}: reading: {e}", path.display()))?;
            read_mcap(&bytes, o).map_err(|e| format!("{}: {e}", path.display()))
        }
        "db3" => {
            let dir = path.parent().unwrap_or(Path::new("."));
            if !dir.join("metadata.yaml").is_file() {
                return Err(format!(
                    "{}: a rosbag2 SQLite3 file is read with its folder's metadata.yaml (its compression and file order), and {} has none",
                    path.display(),
                    dir.display()
                ));
            }
            read_folder(dir, o)
        }
        _ => Err(format!(
            "{}: not a ROS 2 bag (expected a rosbag2 folder, an .mcap or a .db3 file)",
            path.display()
        )),
    }
}

/// What `metadata.yaml` says of a rosbag2 bag (the fields futago needs).
#[derive(Debug, serde::Deserialize)]
struct Metadata {
    rosbag2_bagfile_information: BagInfo,
}

#[derive(Debug, serde::Deserialize)]
struct BagInfo {
    storage_identifier: String,
    relative_file_paths: Vec<String>,
    #[serde(default)]
    compression_format: String,
    #[serde(default)]
    compression_mode: String,
}

/// How a rosbag2 bag's data is compressed.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Compression {
    None,
    /// Each file is a zstd stream of the storage file.
    File,
    /// Each message's data is a zstd stream.
    Message,
}

/// Reads a rosbag2 folder: its `metadata.yaml`, then each of its files in order.
pub fn read_folder(dir: &Path, o: &ReadOptions) -> Result<Log, String> {
    let meta_path = dir.join("metadata.yaml");
    let text = std::fs::read_to_string(&meta_path).map_err(|e| {
        format!(
            "{}: reading: {e} (a rosbag2 bag is a folder with its metadata.yaml)",
            meta_path.display()
        )
    })?;
    let meta: Metadata = serde_yaml_ng::from_str(&text)
        .map_err(|e| format!("{}: not rosbag2 metadata: {e}", meta_path.display()))?;
    let info = meta.rosbag2_bagfile_information;
    let compression = match (
        info.compression_format.to_ascii_lowercase().as_str(),
        info.compression_mode.to_ascii_lowercase().as_str(),
    ) {
        ("", _) | (_, "") | (_, "none") => Compression::None,
        ("zstd", "file") => Compression::File,
        ("zstd", "message") => Compression::Message,
        (f, m) => {
            return Err(format!(
                "{}: compression_format `{f}` with compression_mode `{m}` is not supported (expected none, or zstd by file or message)",
                meta_path.display()
            ));
        }
    };
    if info.relative_file_paths.is_empty() {
        return Err(format!(
            "{}: relative_file_paths is empty: the bag has no files",
            meta_path.display()
        ));
    }
    let mut raw = Raw {
        salvage: !o.strict,
        ..Default::default()
    };
    for name in &info.relative_file_paths {
        let file = dir.join(name);
        if Path::new(name).is_absolute() || name.split(['/', '\\']).any(|c| c == "..") {
            return Err(format!(
                "{}: relative_file_paths entry `{name}` leaves the bag's folder",
                meta_path.display()
            ));
        }
        let mut bytes =
            std::fs::read(&file).map_err(|e| format!("{}: reading: {e}", file.display()))?;
        if compression == Compression::File {
            bytes = unzstd(&bytes, MAX_FILE).map_err(|e| format!("{}: {e}", file.display()))?;
        }
        match info.storage_identifier.as_str() {
            "mcap" => mcap_records(&bytes, &mut raw, compression == Compression::Message)
                .map_err(|e| format!("{}: {e}", file.display()))?,
            "sqlite3" => sqlite_records(&file, &bytes, &mut raw, compression)
                .map_err(|e| format!("{}: {e}", file.display()))?,
            other => {
                return Err(format!(
                    "{}: storage_identifier `{other}` is not supported (expected sqlite3 or mcap)",
                    meta_path.display()
                ));
            }
        }
    }
    assemble(raw, o).map_err(|e| format!("{}: {e}", dir.display()))
}

/// The most a decompressed file may hold (a decompression bomb stops here).
const MAX_FILE: usize = 1 << 34;

/// The most a decompressed MCAP chunk or message may hold (rosbag2 writes chunks of about a
/// megabyte).
const MAX_CHUNK: usize = 1 << 30;

/// A zstd stream (one or more frames) decompressed, at most `limit` bytes.
fn unzstd(mut src: &[u8], limit: usize) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    while !src.is_empty() {
        let left = (limit - out.len()) as u64;
        let decoder =
            ruzstd::decoding::StreamingDecoder::new(&mut src).map_err(|e| format!("zstd: {e}"))?;
        decoder
            .take(left + 1)
            .read_to_end(&mut out)
            .map_err(|e| format!("zstd: {e}"))?;
        if out.len() > limit {
            return Err(format!("zstd: decompresses to more than {limit} bytes"));
        }
    }
    Ok(out)
}

/// A chunk's records decompressed to exactly its declared `size`.
fn inflate_chunk(compression: &str, data: &[u8], size: u64) -> Result<Vec<u8>, String> {
    let size = usize::try_from(size)
        .ok()
        .filter(|&s| s <= MAX_CHUNK)
        .ok_or_else(|| {
            format!("chunk declares {size} uncompressed bytes (at most {MAX_CHUNK} are read)")
        })?;
    let out = match compression {
        "" => data.to_vec(),
        "zstd" => unzstd(data, size)?,
        "lz4" => {
            let mut out = Vec::new();
            lz4_flex::frame::FrameDecoder::new(data)
                .take(size as u64 + 1)
                .read_to_end(&mut out)
                .map_err(|e| format!("lz4: {e}"))?;
            out
        }
        other => {
            return Err(format!(
                "chunk compression `{other}` is not supported (expected none, lz4 or zstd)"
            ));
        }
    };
    if out.len() != size {
        return Err(format!(
            "chunk decompresses to {} bytes, but its header says {size}",
            out.len()
        ));
    }
    Ok(out)
}

/// A ROS 2 type name as futago's ROS 1 reader knows it: `sensor_msgs/msg/LaserScan` →
/// `sensor_msgs/LaserScan`.
fn ros1_name(ty: &str) -> String {
    match ty.split('/').collect::<Vec<_>>()[..] {
        [pkg, "msg", name] => format!("{pkg}/{name}"),
        _ => ty.to_string(),
    }
}

/// The channels an MCAP walk has met: id → (topic, type in ROS 1 spelling, message encoding).
#[derive(Default)]
struct Channels {
    schemas: HashMap<u16, String>,
    channels: HashMap<u16, (String, String, String)>,
}

/// Reads an MCAP file's ROS 2 messages.
pub fn read_mcap(bytes: &[u8], o: &ReadOptions) -> Result<Log, BagError> {
    let mut raw = Raw {
        salvage: !o.strict,
        ..Default::default()
    };
    mcap_records(bytes, &mut raw, false).map_err(|message| BagError { offset: 0, message })?;
    assemble(raw, o)
}

/// Walks an MCAP file's records into `raw`; `zstd_messages`: each message's data is a zstd
/// stream (rosbag2's per-message compression). Salvaging, a record that does not parse ends
/// the walk and is recorded as lost, and a message that does not decode is lost alone.
fn mcap_records(bytes: &[u8], raw: &mut Raw, zstd_messages: bool) -> Result<(), String> {
    let reader = if raw.salvage {
        mcap::read::LinearReader::new_with_options(
            bytes,
            mcap::read::Options::IgnoreEndMagic.into(),
        )
    } else {
        mcap::read::LinearReader::new(bytes)
    }
    .map_err(|e| format!("not an MCAP file: {e}"))?;
    let mut seen = Channels::default();
    for (k, rec) in reader.enumerate() {
        let rec = match rec {
            Ok(r) => r,
            Err(e) if raw.salvage => {
                raw.damage.truncated = true;
                raw.lose(0, format!("record {k}: {e}"), 0);
                break;
            }
            Err(e) => return Err(format!("record {k}: {e}")),
        };
        match rec {
            mcap::records::Record::Chunk { header, data } => {
                let inner =
                    match inflate_chunk(&header.compression, &data, header.uncompressed_size) {
                        Ok(i) => i,
                        Err(e) if raw.salvage => {
                            raw.lose(0, format!("record {k}: {e}"), data.len());
                            continue;
                        }
                        Err(e) => return Err(format!("record {k}: {e}")),
                    };
                for (j, r) in mcap::read::LinearReader::sans_magic(&inner).enumerate() {
                    let step = match r {
                        Ok(mcap::records::Record::Chunk { .. }) => {
                            Err("a chunk inside a chunk".to_string())
                        }
                        Ok(r) => record(r, &mut seen, raw, zstd_messages),
                        Err(e) => Err(e.to_string()),
                    };
                    if let Err(e) = step {
                        let e = format!("record {k} (a chunk), its record {j}: {e}");
                        if !raw.salvage {
                            return Err(e);
                        }
                        let one_message = e_is_message_error(&e);
                        raw.lose(0, e, 0);
                        if !one_message {
                            break;
                        }
                    }
                }
            }
            r => {
                if let Err(e) = record(r, &mut seen, raw, zstd_messages) {
                    let e = format!("record {k}: {e}");
                    if !raw.salvage {
                        return Err(e);
                    }
                    raw.lose(0, e, 0);
                }
            }
        }
    }
    Ok(())
}

/// Whether a chunk's error concerns one message only (the walk of the chunk goes on).
fn e_is_message_error(e: &str) -> bool {
    e.contains(MESSAGE_ERROR)
}

/// The words that begin an error of one message's data.
const MESSAGE_ERROR: &str = "message on ";

/// Takes in one (unchunked) MCAP record.
fn record(
    r: mcap::records::Record,
    seen: &mut Channels,
    raw: &mut Raw,
    zstd_messages: bool,
) -> Result<(), String> {
    match r {
        mcap::records::Record::Schema { header, .. } => {
            seen.schemas.insert(header.id, header.name);
        }
        mcap::records::Record::Channel(c) => {
            let ty = ros1_name(seen.schemas.get(&c.schema_id).map_or("", String::as_str));
            raw.conns
                .insert(u32::from(c.id), (c.topic.clone(), ty.clone()));
            seen.channels
                .insert(c.id, (c.topic, ty, c.message_encoding));
        }
        mcap::records::Record::Message { header, data } => {
            let Some((topic, ty, encoding)) = seen.channels.get(&header.channel_id) else {
                return Err(format!(
                    "a message on channel {}, which no record defined",
                    header.channel_id
                ));
            };
            if encoding != "cdr" {
                *raw.skipped
                    .entry(format!("{topic}: message encoding `{encoding}`"))
                    .or_insert(0) += 1;
                return Ok(());
            }
            let body = if zstd_messages {
                std::borrow::Cow::Owned(
                    unzstd(&data, MAX_CHUNK).map_err(|e| format!("{MESSAGE_ERROR}{topic}: {e}"))?,
                )
            } else {
                data
            };
            message(raw, u32::from(header.channel_id), topic, ty, &body)
                .map_err(|e| format!("{MESSAGE_ERROR}{topic} ({ty}): {e}"))?;
        }
        _ => {}
    }
    Ok(())
}

/// Reads a rosbag2 SQLite3 file (`bytes` is its content, decompressed when the bag compresses
/// by file): its `topics` and its `messages` in time order.
fn sqlite_records(
    file: &Path,
    bytes: &[u8],
    raw: &mut Raw,
    compression: Compression,
) -> Result<(), String> {
    // SQLite reads files: a decompressed one is written to a temporary file first.
    let tmp;
    let path: PathBuf = if compression == Compression::File {
        tmp = tempfile_for(bytes)?;
        tmp.path().to_path_buf()
    } else {
        file.to_path_buf()
    };
    let db = rusqlite::Connection::open_with_flags(
        &path,
        rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY | rusqlite::OpenFlags::SQLITE_OPEN_NO_MUTEX,
    )
    .map_err(|e| format!("not an SQLite3 database: {e}"))?;
    let sql = |e: rusqlite::Error| format!("not a rosbag2 database: {e}");
    let mut topics = db
        .prepare("SELECT id, name, type, serialization_format FROM topics")
        .map_err(sql)?;
    let mut by_id: HashMap<i64, (String, String, String)> = HashMap::new();
    let rows = topics
        .query_map([], |r| {
            Ok((
                r.get::<_, i64>(0)?,
                r.get::<_, String>(1)?,
                r.get::<_, String>(2)?,
                r.get::<_, String>(3)?,
            ))
        })
        .map_err(sql)?;
    for row in rows {
        let (id, name, ty, format) = row.map_err(sql)?;
        let conn = u32::try_from(id).map_err(|_| format!("topics: id {id} out of range"))?;
        raw.conns.insert(conn, (name.clone(), ros1_name(&ty)));
        by_id.insert(id, (name, ros1_name(&ty), format));
    }
    let mut messages = db
        .prepare("SELECT topic_id, data FROM messages ORDER BY timestamp, id")
        .map_err(sql)?;
    let mut rows = messages.query([]).map_err(sql)?;
    let mut k = 0usize;
    while let Some(row) = rows.next().map_err(sql)? {
        k += 1;
        let topic_id: i64 = row.get(0).map_err(sql)?;
        let data: Vec<u8> = row.get(1).map_err(sql)?;
        let Some((topic, ty, format)) = by_id.get(&topic_id) else {
            let e = format!("message {k} is on topic id {topic_id}, which the topics table lacks");
            if raw.salvage {
                raw.lose(0, e, data.len());
                continue;
            }
            return Err(e);
        };
        if format != "cdr" {
            *raw.skipped
                .entry(format!("{topic}: serialization format `{format}`"))
                .or_insert(0) += 1;
            continue;
        }
        let body = if compression == Compression::Message {
            unzstd(&data, MAX_CHUNK)
        } else {
            Ok(data)
        };
        let step = body.and_then(|b| message(raw, topic_id as u32, topic, ty, &b));
        if let Err(e) = step {
            let e = format!("message {k} on {topic} ({ty}): {e}");
            if !raw.salvage {
                return Err(e);
            }
            raw.lose(0, e, 0);
        }
    }
    Ok(())
}

/// `bytes` in a temporary file, removed when the handle drops.
fn tempfile_for(bytes: &[u8]) -> Result<TempFile, String> {
    let path = std::env::temp_dir().join(format!(
        "futago-rosbag2-{}-{}.db3",
        std::process::id(),
        TEMP_COUNTER.fetch_add(1, std::sync::atomic::Ordering::SeqCst)
    ));
    std::fs::write(&path, bytes).map_err(|e| format!("writing {}: {e}", path.display()))?;
    Ok(TempFile(path))
}

static TEMP_COUNTER: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

/// A file removed when dropped.
struct TempFile(PathBuf);

impl TempFile {
    fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// Takes in one CDR message of type `ty` (ROS 1 spelling) on connection `conn`.
fn message(raw: &mut Raw, conn: u32, topic: &str, ty: &str, body: &[u8]) -> Result<(), String> {
    match ty {
        "sensor_msgs/LaserScan" => {
            let scan = laser_scan(body)?;
            raw.stamp(scan.stamp);
            // No header seq in ROS 2: every message is numbered 0, and the stamps stand.
            raw.scans.push((conn, 0, scan));
        }
        "leg_tracker/Person" => {
            let (id, p) = person(body)?;
            raw.people.push((raw.scans.len(), id, p));
        }
        "nav_msgs/Odometry" => {
            let (t, pose, child) = odometry(body)?;
            raw.stamp(t);
            raw.odometry.push((conn, 0, t, pose, child));
        }
        "tf2_msgs/TFMessage" => {
            for (parent, child, t) in tf_message(body)? {
                raw.tf.insert(child, (parent, t));
            }
        }
        other => {
            *raw.skipped
                .entry(format!("message type {other}"))
                .or_insert(0) += 1;
            return Ok(());
        }
    }
    *raw.messages.entry(topic.to_string()).or_insert(0) += 1;
    Ok(())
}

/// Reads CDR (XCDR1, plain): a 4-byte encapsulation header, then fields at offsets aligned to
/// their size, counted from the end of that header.
pub(crate) struct Cdr<'a> {
    data: &'a [u8],
    at: usize,
    little: bool,
}

impl<'a> Cdr<'a> {
    /// The payload's encapsulation header: 0x0000 big-endian CDR, 0x0001 little-endian.
    pub(crate) fn new(payload: &'a [u8]) -> Result<Cdr<'a>, String> {
        let Some(h) = payload.get(..4) else {
            return Err(format!(
                "a CDR payload of {} bytes has no encapsulation header",
                payload.len()
            ));
        };
        let little = match [h[0], h[1]] {
            [0, 0] => false,
            [0, 1] => true,
            [a, b] => {
                return Err(format!(
                    "encapsulation 0x{a:02x}{b:02x} is not plain CDR (expected 0x0000 or 0x0001)"
                ));
            }
        };
        Ok(Cdr {
            data: &payload[4..],
            at: 0,
            little,
        })
    }

    fn align(&mut self, n: usize) {
        self.at = self.at.div_ceil(n) * n;
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], String> {
        match self.data.get(self.at..self.at.saturating_add(n)) {
            Some(s) if self.at.checked_add(n).is_some() => {
                self.at += n;
                Ok(s)
            }
            _ => Err(format!(
                "{what}: needs {n} bytes, {} left (truncated or corrupt)",
                self.data.len().saturating_sub(self.at)
            )),
        }
    }

    fn u32(&mut self, what: &str) -> Result<u32, String> {
        self.align(4);
        let b: [u8; 4] = self.take(4, what)?.try_into().expect("4 bytes");
        Ok(if self.little {
            u32::from_le_bytes(b)
        } else {
            u32::from_be_bytes(b)
        })
    }

    fn f32(&mut self, what: &str) -> Result<f32, String> {
        Ok(f32::from_bits(self.u32(what)?))
    }

    fn f64(&mut self, what: &str) -> Result<f64, String> {
        self.align(8);
        let b: [u8; 8] = self.take(8, what)?.try_into().expect("8 bytes");
        Ok(f64::from_bits(if self.little {
            u64::from_le_bytes(b)
        } else {
            u64::from_be_bytes(b)
        }))
    }

    /// A string: its length with the terminating NUL, its bytes, the NUL.
    fn string(&mut self, what: &str) -> Result<String, String> {
        let n = self.u32(what)? as usize;
        let b = self.take(n, what)?;
        let b = b.strip_suffix(&[0]).unwrap_or(b);
        Ok(String::from_utf8_lossy(b).into_owned())
    }

    /// A sequence's length, bounded by what is left at `each` bytes an element.
    fn count(&mut self, each: usize, what: &str) -> Result<usize, String> {
        let n = self.u32(what)? as usize;
        let left = self.data.len().saturating_sub(self.at);
        if n.saturating_mul(each) > left {
            return Err(format!(
                "{what}: {n} elements in {left} bytes (truncated or corrupt)"
            ));
        }
        Ok(n)
    }

    /// A `builtin_interfaces/Time`: seconds (int32) and nanoseconds (uint32).
    fn time(&mut self, what: &str) -> Result<Time, String> {
        let s = self.u32(what)? as i32 as i64;
        let ns = self.u32(what)?;
        if ns >= 1_000_000_000 {
            return Err(format!("{what}: {ns} nanoseconds is not below one second"));
        }
        Ok(Time(s * 1_000_000_000 + ns as i64))
    }

    /// A `std_msgs/Header`: stamp and frame.
    fn header(&mut self) -> Result<(Time, String), String> {
        let t = self.time("header stamp")?;
        Ok((t, frame_name(self.string("header frame_id")?)))
    }

    /// A `geometry_msgs/Pose` (or Transform: three then four doubles).
    fn doubles<const N: usize>(&mut self, what: &str) -> Result<[f64; N], String> {
        let mut v = [0.0; N];
        for x in &mut v {
            *x = self.f64(what)?;
        }
        Ok(v)
    }
}

/// A `sensor_msgs/msg/LaserScan`'s CDR payload decoded, ranges as futago reads them.
pub fn decode_laser_scan(body: &[u8]) -> Result<LaserScan, String> {
    laser_scan(body)
}

fn laser_scan(body: &[u8]) -> Result<LaserScan, String> {
    let mut c = Cdr::new(body)?;
    let (stamp, frame) = c.header()?;
    let angle_min = c.f32("angle_min")? as f64;
    let _angle_max = c.f32("angle_max")?;
    let angle_increment = c.f32("angle_increment")? as f64;
    let time_increment = c.f32("time_increment")? as f64;
    let _scan_time = c.f32("scan_time")?;
    let range_min = c.f32("range_min")? as f64;
    let range_max = c.f32("range_max")? as f64;
    let n = c.count(4, "ranges length")?;
    let mut ranges = Vec::with_capacity(n);
    for _ in 0..n {
        let r = c.f32("range")?;
        ranges.push(crate::rosbag::range_as_read(r, range_max));
    }
    let m = c.count(4, "intensities length")?;
    c.take(4 * m, "intensities")?;
    Ok(LaserScan {
        frame,
        stamp,
        angle_min,
        angle_increment,
        time_increment,
        range_min,
        range_max,
        ranges,
    })
}

fn odometry(body: &[u8]) -> Result<(Time, Pose2, String), String> {
    let mut c = Cdr::new(body)?;
    let (stamp, _) = c.header()?;
    let child = frame_name(c.string("child_frame_id")?);
    let [x, y, _z, qx, qy, qz, qw] = c.doubles::<7>("pose")?;
    checked_position("odometry position", x, y)?;
    Ok((stamp, Pose2::new(x, y, yaw_of([qx, qy, qz, qw])), child))
}

fn tf_message(body: &[u8]) -> Result<Vec<(String, String, Transform)>, String> {
    let mut c = Cdr::new(body)?;
    // Each transform takes at least 80 bytes.
    let n = c.count(80, "transforms length")?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let (_, parent) = c.header()?;
        let child = frame_name(c.string("child_frame_id")?);
        let v = c.doubles::<7>("transform")?;
        out.push((
            parent.clone(),
            child.clone(),
            crate::rosbag::checked_transform(&parent, &child, v)?,
        ));
    }
    Ok(out)
}

/// A `leg_tracker/msg/Person`: a `geometry_msgs/Pose` and an id.
fn person(body: &[u8]) -> Result<(u32, [f64; 2]), String> {
    let mut c = Cdr::new(body)?;
    let [x, y, ..] = c.doubles::<7>("pose")?;
    let id = c.u32("id")?;
    Ok((id, checked_position("position", x, y)?))
}

/// Writes CDR (XCDR1, little-endian): the encapsulation header `00 01 00 00`, then fields
/// aligned to their size from the header's end, as ROS 2's middleware lays them out.
#[derive(Debug, Clone)]
pub struct CdrWriter {
    buf: Vec<u8>,
}

impl Default for CdrWriter {
    fn default() -> Self {
        CdrWriter {
            buf: vec![0, 1, 0, 0],
        }
    }
}

impl CdrWriter {
    /// A writer with room for `n` bytes (an image's payload) before it grows.
    pub fn with_capacity(n: usize) -> CdrWriter {
        let mut buf = Vec::with_capacity(n + 4);
        buf.extend([0, 1, 0, 0]);
        CdrWriter { buf }
    }

    fn align(&mut self, n: usize) {
        while !(self.buf.len() - 4).is_multiple_of(n) {
            self.buf.push(0);
        }
    }

    pub fn u32(&mut self, v: u32) -> &mut Self {
        self.align(4);
        self.buf.extend(v.to_le_bytes());
        self
    }

    pub fn i32(&mut self, v: i32) -> &mut Self {
        self.u32(v as u32)
    }

    /// A `uint8`, `int8` or `bool` (one byte, no alignment).
    pub fn u8(&mut self, v: u8) -> &mut Self {
        self.buf.push(v);
        self
    }

    pub fn f32(&mut self, v: f32) -> &mut Self {
        self.u32(v.to_bits())
    }

    pub fn f64(&mut self, v: f64) -> &mut Self {
        self.align(8);
        self.buf.extend(v.to_le_bytes());
        self
    }

    /// A string: its length with the terminating NUL, its bytes, the NUL.
    pub fn string(&mut self, s: &str) -> &mut Self {
        self.u32(s.len() as u32 + 1);
        self.buf.extend(s.as_bytes());
        self.buf.push(0);
        self
    }

    /// An `int8[]`/`uint8[]` sequence's elements (its length written before).
    pub fn bytes(&mut self, b: &[u8]) -> &mut Self {
        self.buf.extend_from_slice(b);
        self
    }

    /// A `std_msgs/Header` at time `t` in `frame`.
    pub fn header(&mut self, t: Time, frame: &str) -> &mut Self {
        let ns = t.nanos();
        self.i32(ns.div_euclid(1_000_000_000) as i32)
            .u32(ns.rem_euclid(1_000_000_000) as u32)
            .string(frame)
    }

    pub fn into_bytes(self) -> Vec<u8> {
        self.buf
    }
}

/// The example bags' messages (topic, type, log time, CDR): the laser mounted 0.22 m ahead
/// of `base_link` on `/tf_static`, odometry at 1 s (x = 0) and 3 s (x = 1 m), a scan of three
/// beams at 2 s, and a message of a type the reader skips.
fn example_messages() -> Vec<(&'static str, &'static str, Time, Vec<u8>)> {
    let mut out = Vec::new();
    let mut m = CdrWriter::default();
    m.u32(1).header(Time(0), "base_link").string("laser");
    for v in [0.22, 0.0, 0.1, 0.0, 0.0, 0.0, 1.0] {
        m.f64(v);
    }
    out.push((
        "/tf_static",
        "tf2_msgs/msg/TFMessage",
        Time(0),
        m.into_bytes(),
    ));
    for (s, x) in [(1, 0.0), (3, 1.0)] {
        let t = Time(s * 1_000_000_000);
        let mut m = CdrWriter::default();
        m.header(t, "odom").string("base_link");
        for v in [x, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0] {
            m.f64(v);
        }
        for _ in 0..36 + 6 + 36 {
            m.f64(0.0);
        }
        out.push(("/odom", "nav_msgs/msg/Odometry", t, m.into_bytes()));
    }
    let t = Time(2_000_000_000);
    let mut m = CdrWriter::default();
    m.header(t, "laser");
    for v in [-0.5f32, 0.5, 0.5, 0.0, 0.1, 0.05, 20.0] {
        m.f32(v);
    }
    m.u32(3).f32(1.0).f32(2.0).f32(3.0).u32(0);
    out.push(("/scan", "sensor_msgs/msg/LaserScan", t, m.into_bytes()));
    let mut m = CdrWriter::default();
    m.string("hello");
    out.push(("/chatter", "std_msgs/msg/String", t, m.into_bytes()));
    out.sort_by_key(|m| m.2);
    out
}

/// A small MCAP file of ROS 2 messages, written with the `mcap` crate: the laser mounted
/// 0.22 m ahead of `base_link` on `/tf_static`, odometry at 1 s (x = 0) and 3 s (x = 1 m), a
/// scan of three beams at 2 s, and a message of a type the reader skips. The fuzzer's seed,
/// and a reading test without Python.
pub fn example_mcap() -> Vec<u8> {
    let mut out = std::io::Cursor::new(Vec::new());
    {
        let mut w = mcap::Writer::new(&mut out).expect("an in-memory MCAP writer");
        let mut channels: HashMap<&str, u16> = HashMap::new();
        for (topic, ty, t, data) in example_messages() {
            let ch = match channels.get(topic) {
                Some(&c) => c,
                None => {
                    let schema = w.add_schema(ty, "ros2msg", b"").expect("schema");
                    let c = w
                        .add_channel(schema, topic, "cdr", &Default::default())
                        .expect("channel");
                    channels.insert(topic, c);
                    c
                }
            };
            let header = mcap::records::MessageHeader {
                channel_id: ch,
                sequence: 0,
                log_time: t.nanos() as u64,
                publish_time: t.nanos() as u64,
            };
            w.write_to_known_channel(&header, &data).expect("message");
        }
        w.finish().expect("finished");
    }
    out.into_inner()
}

/// The same messages as [`example_mcap`] in a rosbag2 SQLite3 database (its `topics` and
/// `messages` tables as rosbag2 creates them): the `db3` fuzzer's seed.
pub fn example_db3() -> Vec<u8> {
    let tmp = tempfile_for(&[]).expect("a temporary file");
    std::fs::remove_file(tmp.path()).expect("an empty name");
    {
        let db = rusqlite::Connection::open(tmp.path()).expect("a new database");
        db.execute_batch(
            "CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL, \
             serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);\
             CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL, \
             timestamp INTEGER NOT NULL, data BLOB NOT NULL);",
        )
        .expect("the tables");
        let mut ids: Vec<&str> = Vec::new();
        for (topic, ty, t, data) in example_messages() {
            let id = match ids.iter().position(|n| *n == topic) {
                Some(i) => i + 1,
                None => {
                    ids.push(topic);
                    db.execute(
                        "INSERT INTO topics VALUES (?1, ?2, ?3, 'cdr', '')",
                        rusqlite::params![ids.len() as i64, topic, ty],
                    )
                    .expect("a topic");
                    ids.len()
                }
            };
            db.execute(
                "INSERT INTO messages(topic_id, timestamp, data) VALUES (?1, ?2, ?3)",
                rusqlite::params![id as i64, t.nanos(), data],
            )
            .expect("a message");
        }
    }
    std::fs::read(tmp.path()).expect("the database's bytes")
}

/// Reads the bytes of an uncompressed rosbag2 SQLite3 file (as a lone `.db3` in a folder
/// whose `metadata.yaml` says storage `sqlite3`, no compression).
pub fn read_db3(bytes: &[u8], o: &ReadOptions) -> Result<Log, String> {
    let tmp = tempfile_for(bytes)?;
    let mut raw = Raw {
        salvage: !o.strict,
        ..Default::default()
    };
    sqlite_records(tmp.path(), bytes, &mut raw, Compression::None)?;
    assemble(raw, o).map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A little-endian CDR payload of `fields`, each aligned to its size from the header's end.
    fn cdr(fields: &[Field]) -> Vec<u8> {
        let mut out = vec![0, 1, 0, 0];
        let mut put = |bytes: &[u8], align: usize| {
            while (out.len() - 4) % align != 0 {
                out.push(0);
            }
            out.extend_from_slice(bytes);
        };
        for f in fields {
            match f {
                Field::U32(v) => put(&v.to_le_bytes(), 4),
                Field::F32(v) => put(&v.to_le_bytes(), 4),
                Field::F64(v) => put(&v.to_le_bytes(), 8),
                Field::Str(s) => {
                    put(&(s.len() as u32 + 1).to_le_bytes(), 4);
                    put(s.as_bytes(), 1);
                    put(&[0], 1);
                }
            }
        }
        out
    }

    enum Field {
        U32(u32),
        F32(f32),
        F64(f64),
        Str(&'static str),
    }
    use Field::*;

    #[test]
    fn a_laser_scan_reads_its_fields_at_their_cdr_alignments() {
        // Header (stamp 12 s + 5 ns, frame "/laser" of 6 chars: 4 + 7 bytes, so the floats
        // after it start at an offset padded to 4).
        let body = cdr(&[
            U32(12),
            U32(5),
            Str("/laser"),
            F32(-1.5),
            F32(1.5),
            F32(0.5),
            F32(0.001),
            F32(0.1),
            F32(0.1),
            F32(30.0),
            U32(3),
            F32(1.0),
            F32(f32::NAN),
            F32(40.0),
            U32(0),
        ]);
        let s = laser_scan(&body).unwrap();
        assert_eq!(s.stamp, Time(12_000_000_005));
        assert_eq!(s.frame, "laser");
        assert_eq!((s.angle_min, s.angle_increment), (-1.5, 0.5));
        assert_eq!(s.ranges[0], 1.0);
        assert!(s.ranges[1].is_nan());
        // Beyond range_max: no return.
        assert_eq!(s.ranges[2], f32::INFINITY);
        // Cut anywhere, it is an error, never a panic.
        for k in 0..body.len() {
            assert!(laser_scan(&body[..k]).is_err(), "cut at {k}");
        }
    }

    #[test]
    fn odometry_aligns_its_doubles_to_eight_bytes_after_the_strings() {
        // "odom" is 4 + 5 bytes, "base_link" 4 + 10: the doubles start padded to 8.
        let yaw: f64 = 0.3;
        let body = cdr(&[
            U32(1),
            U32(0),
            Str("odom"),
            Str("base_link"),
            F64(2.0),
            F64(-1.0),
            F64(0.0),
            F64(0.0),
            F64(0.0),
            F64((yaw / 2.0).sin()),
            F64((yaw / 2.0).cos()),
        ]);
        let (t, p, child) = odometry(&body).unwrap();
        assert_eq!(t, Time(1_000_000_000));
        assert_eq!(child, "base_link");
        assert!((p.x - 2.0).abs() < 1e-12 && (p.y + 1.0).abs() < 1e-12);
        assert!((p.theta - yaw).abs() < 1e-12);
    }

    #[test]
    fn big_endian_cdr_reads_too_and_other_encapsulations_are_refused() {
        let mut b = vec![0, 0, 0, 0];
        b.extend(7u32.to_be_bytes());
        let mut c = Cdr::new(&b).unwrap();
        assert_eq!(c.u32("x").unwrap(), 7);
        let e = Cdr::new(&[0, 7, 0, 0]).err().unwrap();
        assert!(e.contains("not plain CDR"), "{e}");
        assert!(Cdr::new(&[0, 1]).is_err());
    }

    #[test]
    fn a_sequence_longer_than_its_message_is_refused_before_allocating() {
        let body = cdr(&[U32(u32::MAX)]);
        let e = tf_message(&body).unwrap_err();
        assert!(e.contains("elements in"), "{e}");
    }

    #[test]
    fn the_example_db3_reads_as_the_example_mcap_and_damage_is_an_error() {
        let strict = ReadOptions {
            strict: true,
            ..Default::default()
        };
        let bytes = example_db3();
        let a = read_db3(&bytes, &strict).unwrap();
        let b = read_mcap(&example_mcap(), &strict).unwrap();
        assert_eq!(a.scans.len(), 1);
        assert_eq!(a.scans[0].scan.ranges, b.scans[0].scan.ranges);
        assert_eq!(a.scans[0].odometry, b.scans[0].odometry);
        assert_eq!(a.scans[0].mount, b.scans[0].mount);
        assert_eq!(a.skipped, b.skipped);
        // Cut short anywhere, or not SQLite at all: an error, never a panic.
        for k in (0..bytes.len()).step_by(bytes.len() / 16) {
            assert!(read_db3(&bytes[..k], &strict).is_err(), "cut at {k}");
        }
        let e = read_db3(b"not a database", &strict).unwrap_err();
        assert!(e.contains("SQLite") || e.contains("database"), "{e}");
    }

    #[test]
    fn the_example_mcap_reads_its_scan_placed_by_odometry_and_tf() {
        let bytes = example_mcap();
        let log = read_mcap(
            &bytes,
            &ReadOptions {
                strict: true,
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!(log.scans.len(), 1);
        let s = &log.scans[0];
        assert_eq!(s.scan.ranges, vec![1.0, 2.0, 3.0]);
        // Odometry halfway between x = 0 at 1 s and x = 1 at 3 s.
        assert!((s.odometry.x - 0.5).abs() < 1e-9, "{:?}", s.odometry);
        assert!((s.mount.x - 0.22).abs() < 1e-12, "{:?}", s.mount);
        assert_eq!(log.skipped.get("message type std_msgs/String"), Some(&1));
        assert_eq!(log.scan_topic.as_deref(), Some("/scan"));
        // Damaged anywhere, strictly it is an error and salvaging it is a log: never a panic.
        for k in (0..bytes.len()).step_by(7) {
            let mut b = bytes.clone();
            b[k] ^= 0x5a;
            let _ = read_mcap(&b, &ReadOptions::default());
            let _ = read_mcap(&bytes[..k], &ReadOptions::default());
            assert!(
                read_mcap(
                    &bytes[..k],
                    &ReadOptions {
                        strict: true,
                        ..Default::default()
                    }
                )
                .is_err()
                    || k == bytes.len()
            );
        }
    }

    #[test]
    fn ros2_type_names_read_as_ros1_names() {
        assert_eq!(
            ros1_name("sensor_msgs/msg/LaserScan"),
            "sensor_msgs/LaserScan"
        );
        assert_eq!(ros1_name("sensor_msgs/LaserScan"), "sensor_msgs/LaserScan");
    }
}
