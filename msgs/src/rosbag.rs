//! ROS 1 bags (format 2.0; written for futago from the ROS wiki's "Bags/Format/2.0"): the
//! `sensor_msgs/LaserScan` and `nav_msgs/Odometry` messages of a bag, in chunks uncompressed,
//! bz2 or lz4 (the LZ4 frame format, ROS's default for large bags; decoded by `lz4_flex`), read
//! into the same [`Log`] a CARMEN log gives.
//!
//! A bag is the magic line `#ROSBAG V2.0\n` and records of `header_len, header, data_len, data`;
//! a header is `field_len, name=value` fields, with `op` giving the record type: 0x03 bag
//! header, 0x05 chunk (holding connection and message records, compressed), 0x07 connection,
//! 0x02 message data, 0x04 index data, 0x06 chunk info. Messages are read in file order; each
//! scan takes the odometry pose interpolated at its stamp (header stamps, not bag times). A
//! stamp that contradicts the header `seq` numbering of its stream (a message stamped late,
//! after messages published behind it) is replaced by one interpolated between its neighbours
//! by `seq` (`acquisition_times`); the scan keeps the stamp it was logged with as
//! [`LogScan::logged`], the name relation files know it by.
//!
//! The laser's mount on the robot comes from tf: the `tf2_msgs/TFMessage` (or `tf/tfMessage`)
//! transforms on `/tf` and `/tf_static` are chained from the scan's frame up to the odometry's
//! child frame (the base), each taken at its last value in the bag (mounts are static; the
//! base's own odometry transform is never on that chain). The chain is projected onto the
//! floor plane; a laser mounted upside down (roll π) has its scan mirrored back, and one tilted
//! otherwise is an error. Without a chain the laser is taken at the base, and the scans are
//! counted under `skipped` as `no tf from BASE to FRAME`.

use crate::carmen::{Damage, Log, LogScan, PersonMark, ReadOptions};
use crate::{LaserScan, Pose2, Time};
use std::collections::HashMap;
use std::io::Read;

pub mod writer;

/// An error reading a bag: the byte offset of the record and what was wrong.
#[derive(Debug, Clone, PartialEq)]
pub struct BagError {
    pub offset: usize,
    pub message: String,
}

impl std::fmt::Display for BagError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "byte {}: {}", self.offset, self.message)
    }
}

impl std::error::Error for BagError {}

/// Little-endian reads over a byte slice that fail with a message instead of panicking.
struct Cursor<'a> {
    data: &'a [u8],
    at: usize,
}

impl<'a> Cursor<'a> {
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], String> {
        if self.at + n > self.data.len() {
            return Err(format!(
                "{what}: needs {n} bytes, {} left (truncated or corrupt)",
                self.data.len() - self.at
            ));
        }
        let s = &self.data[self.at..self.at + n];
        self.at += n;
        Ok(s)
    }
    fn u32(&mut self, what: &str) -> Result<u32, String> {
        let b = self.take(4, what)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    fn f32(&mut self, what: &str) -> Result<f32, String> {
        Ok(f32::from_bits(self.u32(what)?))
    }
    fn f64(&mut self, what: &str) -> Result<f64, String> {
        let b = self.take(8, what)?;
        Ok(f64::from_le_bytes(b.try_into().expect("8 bytes")))
    }
    fn string(&mut self, what: &str) -> Result<String, String> {
        let n = self.u32(what)? as usize;
        Ok(String::from_utf8_lossy(self.take(n, what)?).into_owned())
    }
    fn time(&mut self, what: &str) -> Result<Time, String> {
        let s = self.u32(what)? as i64;
        let ns = self.u32(what)? as i64;
        Ok(Time(s * 1_000_000_000 + ns))
    }
}

/// Parses a record header's `name=value` fields.
fn fields(h: &[u8]) -> Result<HashMap<String, Vec<u8>>, String> {
    let mut c = Cursor { data: h, at: 0 };
    let mut out = HashMap::new();
    while c.at < h.len() {
        let n = c.u32("header field length")? as usize;
        let f = c.take(n, "header field")?;
        let eq = f
            .iter()
            .position(|&b| b == b'=')
            .ok_or("header field without `=`")?;
        out.insert(
            String::from_utf8_lossy(&f[..eq]).into_owned(),
            f[eq + 1..].to_vec(),
        );
    }
    Ok(out)
}

fn field_u32(f: &HashMap<String, Vec<u8>>, name: &str) -> Result<u32, String> {
    let v = f
        .get(name)
        .ok_or_else(|| format!("record header lacks `{name}`"))?;
    let b: [u8; 4] = v
        .get(..4)
        .and_then(|b| b.try_into().ok())
        .ok_or_else(|| format!("`{name}` is not 4 bytes"))?;
    Ok(u32::from_le_bytes(b))
}

/// What a bag holds of interest, before pairing scans with odometry.
#[derive(Default)]
pub(crate) struct Raw {
    /// Connection id → (topic, message type).
    pub(crate) conns: HashMap<u32, (String, String)>,
    /// Each scan with its connection and its header's `seq`.
    pub(crate) scans: Vec<(u32, u32, LaserScan)>,
    /// Annotated people: how many scans (of any topic) came before each in the file, its id
    /// and position.
    pub(crate) people: Vec<(usize, u32, [f64; 2])>,
    /// Each odometry message's connection, header `seq`, stamp, pose and child frame.
    pub(crate) odometry: Vec<(u32, u32, Time, Pose2, String)>,
    /// tf: child frame → (parent frame, transform), the last one seen.
    pub(crate) tf: HashMap<String, (String, Transform)>,
    pub(crate) skipped: std::collections::BTreeMap<String, usize>,
    /// Messages read, by topic.
    pub(crate) messages: std::collections::BTreeMap<String, usize>,
    /// Salvaging: what was lost, and the last stamp read (for the gaps).
    pub(crate) salvage: bool,
    pub(crate) damage: Damage,
    pub(crate) last_stamp: Option<Time>,
    /// Salvaging: messages on connections not (yet) defined, with their offset: the
    /// definition may come later (a bag repeats them after its chunks), or have been lost.
    pub(crate) pending: Vec<(usize, u32, Vec<u8>)>,
}

impl Raw {
    pub(crate) fn stamp(&mut self, t: Time) {
        self.last_stamp = Some(t);
        self.damage.stamp_read(t);
    }

    pub(crate) fn lose(&mut self, at: usize, what: String, bytes: usize) {
        self.damage.lose(
            at as u64,
            format!("byte {at}: {what}"),
            bytes as u64,
            self.last_stamp,
        );
    }

    /// Takes in the message `body` on connection `conn` of type `ty`.
    fn message(&mut self, conn: u32, ty: &str, body: &[u8]) -> Result<(), String> {
        match ty {
            "sensor_msgs/LaserScan" => {
                let (seq, scan) = laser_scan(body).map_err(|m| format!("LaserScan: {m}"))?;
                self.stamp(scan.stamp);
                self.scans.push((conn, seq, scan));
            }
            "leg_tracker/Person" => {
                let (id, p) = person(body).map_err(|m| format!("leg_tracker/Person: {m}"))?;
                self.people.push((self.scans.len(), id, p));
            }
            "nav_msgs/Odometry" => {
                let (seq, t, pose, child) = odometry(body).map_err(|m| format!("Odometry: {m}"))?;
                self.stamp(t);
                self.odometry.push((conn, seq, t, pose, child));
            }
            "tf2_msgs/TFMessage" | "tf/tfMessage" => {
                for (parent, child, t) in tf_message(body).map_err(|m| format!("TFMessage: {m}"))? {
                    self.tf.insert(child, (parent, t));
                }
            }
            other => {
                *self
                    .skipped
                    .entry(format!("message type {other}"))
                    .or_insert(0) += 1;
                return Ok(());
            }
        }
        let topic = self
            .conns
            .get(&conn)
            .map(|c| c.0.clone())
            .unwrap_or_default();
        *self.messages.entry(topic).or_insert(0) += 1;
        Ok(())
    }
}

/// A tf transform: translation and unit quaternion `[x, y, z, w]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Transform {
    pub(crate) t: [f64; 3],
    pub(crate) q: [f64; 4],
}

impl Transform {
    /// Roll, pitch and yaw (ZYX), rad.
    fn rpy(&self) -> [f64; 3] {
        let [x, y, z, w] = self.q;
        let roll = (2.0 * (w * x + y * z)).atan2(1.0 - 2.0 * (x * x + y * y));
        let pitch = (2.0 * (w * y - z * x)).clamp(-1.0, 1.0).asin();
        let yaw = (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z));
        [roll, pitch, yaw]
    }

    /// `self ∘ other` (other expressed in self's child frame).
    fn compose(&self, o: &Transform) -> Transform {
        let [ax, ay, az, aw] = self.q;
        let [bx, by, bz, bw] = o.q;
        let q = [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ];
        // Rotate o.t by self.q: v' = v + 2w(u×v) + 2u×(u×v).
        let u = [ax, ay, az];
        let v = o.t;
        let cross = |a: [f64; 3], b: [f64; 3]| {
            [
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ]
        };
        let uv = cross(u, v);
        let uuv = cross(u, uv);
        let t = [0, 1, 2].map(|i| self.t[i] + v[i] + 2.0 * (aw * uv[i] + uuv[i]));
        Transform { t, q }
    }
}

/// The transforms of a `tf2_msgs/TFMessage`: (parent, child, transform).
fn tf_message(data: &[u8]) -> Result<Vec<(String, String, Transform)>, String> {
    let mut c = Cursor { data, at: 0 };
    let n = c.u32("transforms length")? as usize;
    // Each transform takes at least 84 bytes: what the message holds bounds the count.
    if n > data.len() / 84 {
        return Err(format!("{n} transforms in a {}-byte message", data.len()));
    }
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        c.u32("header seq")?;
        c.time("header stamp")?;
        let parent = frame_name(c.string("header frame_id")?);
        let child = frame_name(c.string("child_frame_id")?);
        let mut v = [0.0; 7];
        for x in &mut v {
            *x = c.f64("transform")?;
        }
        let t = checked_transform(&parent, &child, v)?;
        out.push((parent, child, t));
    }
    Ok(out)
}

/// The transform `parent → child` of translation and quaternion `v`, checked: finite, within
/// the coordinate bound, and a unit quaternion.
pub(crate) fn checked_transform(
    parent: &str,
    child: &str,
    v: [f64; 7],
) -> Result<Transform, String> {
    let norm = (v[3] * v[3] + v[4] * v[4] + v[5] * v[5] + v[6] * v[6]).sqrt();
    if !(v.iter().all(|x| x.is_finite()) && (norm - 1.0).abs() < 1e-3)
        || v[..3].iter().any(|x| x.abs() > crate::MAX_COORDINATE)
    {
        return Err(format!(
            "transform {parent} → {child}: expected a finite translation within ±{} m and a unit quaternion, found {v:?}",
            crate::MAX_COORDINATE
        ));
    }
    Ok(Transform {
        t: [v[0], v[1], v[2]],
        q: [v[3], v[4], v[5], v[6]],
    })
}

/// A logged range as futago reads it: itself below `range_max`, NaN kept, anything else
/// (beyond range, infinite) no return.
pub(crate) fn range_as_read(r: f32, range_max: f64) -> f32 {
    if r.is_finite() && (r as f64) < range_max {
        r
    } else if r.is_nan() {
        f32::NAN
    } else {
        f32::INFINITY
    }
}

/// A frame's name as tf2 knows it: without the leading `/` that ROS 1 tf allowed
/// (`/base_link` and `base_link` are one frame).
pub(crate) fn frame_name(s: String) -> String {
    match s.strip_prefix('/') {
        Some(rest) => rest.to_string(),
        None => s,
    }
}

/// The transform from `base` to `frame` through the tf tree, if they are linked.
fn chain(tf: &HashMap<String, (String, Transform)>, base: &str, frame: &str) -> Option<Transform> {
    let mut at = frame;
    let mut t = Transform {
        t: [0.0; 3],
        q: [0.0, 0.0, 0.0, 1.0],
    };
    // A tree deeper than this is a loop.
    for _ in 0..64 {
        if at == base {
            return Some(t);
        }
        let (parent, p) = tf.get(at)?;
        t = p.compose(&t);
        at = parent;
    }
    None
}

fn laser_scan(data: &[u8]) -> Result<(u32, LaserScan), String> {
    let mut c = Cursor { data, at: 0 };
    let seq = c.u32("header seq")?;
    let stamp = c.time("header stamp")?;
    let frame = frame_name(c.string("header frame_id")?);
    let angle_min = c.f32("angle_min")? as f64;
    let _angle_max = c.f32("angle_max")?;
    let angle_increment = c.f32("angle_increment")? as f64;
    let time_increment = c.f32("time_increment")? as f64;
    let _scan_time = c.f32("scan_time")?;
    let range_min = c.f32("range_min")? as f64;
    let range_max = c.f32("range_max")? as f64;
    let n = c.u32("ranges length")? as usize;
    if n > 1_000_000 {
        return Err(format!("{n} ranges in one scan"));
    }
    let mut ranges = Vec::with_capacity(n);
    for _ in 0..n {
        let r = c.f32("range")?;
        ranges.push(range_as_read(r, range_max));
    }
    Ok((
        seq,
        LaserScan {
            frame,
            stamp,
            angle_min,
            angle_increment,
            time_increment,
            range_min,
            range_max,
            ranges,
        },
    ))
}

/// A `leg_tracker/Person`: a `geometry_msgs/Pose` and an id (no header).
fn person(data: &[u8]) -> Result<(u32, [f64; 2]), String> {
    let mut c = Cursor { data, at: 0 };
    let (x, y) = (c.f64("position x")?, c.f64("position y")?);
    for what in [
        "position z",
        "orientation x",
        "orientation y",
        "orientation z",
        "orientation w",
    ] {
        c.f64(what)?;
    }
    let id = c.u32("id")?;
    Ok((id, checked_position("position", x, y)?))
}

/// A logged planar position `(x, y)`, checked against the coordinate bound; `what` names it in
/// the error.
pub(crate) fn checked_position(what: &str, x: f64, y: f64) -> Result<[f64; 2], String> {
    if crate::bounded_coordinate(x).is_none() || crate::bounded_coordinate(y).is_none() {
        return Err(format!(
            "{what} ({x}, {y}) is beyond ±{} m of the origin",
            crate::MAX_COORDINATE
        ));
    }
    Ok([x, y])
}

/// The yaw of a general unit quaternion `[x, y, z, w]`: the z-axis rotation of the body's x
/// axis.
pub(crate) fn yaw_of(q: [f64; 4]) -> f64 {
    (2.0 * (q[3] * q[2] + q[0] * q[1])).atan2(1.0 - 2.0 * (q[1] * q[1] + q[2] * q[2]))
}

fn odometry(data: &[u8]) -> Result<(u32, Time, Pose2, String), String> {
    let mut c = Cursor { data, at: 0 };
    let seq = c.u32("header seq")?;
    let stamp = c.time("header stamp")?;
    c.string("header frame_id")?;
    let child = frame_name(c.string("child_frame_id")?);
    let (x, y) = (c.f64("position x")?, c.f64("position y")?);
    checked_position("odometry position", x, y)?;
    c.f64("position z")?;
    let q = [
        c.f64("orientation x")?,
        c.f64("orientation y")?,
        c.f64("orientation z")?,
        c.f64("orientation w")?,
    ];
    Ok((seq, stamp, Pose2::new(x, y, yaw_of(q)), child))
}

/// A compressed chunk's contents, decompressed no further than the header's `size` (a
/// decompression bomb stops there), into memory that grows only with what is read.
fn inflate(reader: impl Read, size: usize, what: &str) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    reader
        .take(size as u64 + 1)
        .read_to_end(&mut out)
        .map_err(|e| format!("{what} chunk: {e}"))?;
    if out.len() != size {
        return Err(format!(
            "{what} chunk decompresses to {}{} bytes, but its header says {size}",
            if out.len() > size { "more than " } else { "" },
            out.len().min(size)
        ));
    }
    Ok(out)
}

/// One record of a bag: its header's fields and its data.
struct Record<'a> {
    fields: HashMap<String, Vec<u8>>,
    op: u8,
    body: &'a [u8],
    /// Where the next record begins.
    end: usize,
    /// Bytes of the data that the file ends before (salvaging a cut file), else 0.
    missing: usize,
}

/// The record at `at` of `data`. Salvaging (`cut_ok`), a record whose data runs past the end
/// of `data` comes back with what there is of it and the count of what is missing.
fn parse_record(data: &[u8], at: usize, cut_ok: bool) -> Result<Record<'_>, String> {
    let mut c = Cursor { data, at };
    let hlen = c.u32("record header length")? as usize;
    let header = c.take(hlen, "record header")?;
    let dlen = c.u32("record data length")? as usize;
    let left = data.len() - c.at;
    let (body, missing) = if cut_ok && dlen > left {
        let b = &data[c.at..];
        c.at = data.len();
        (b, dlen - left)
    } else {
        (c.take(dlen, "record data")?, 0)
    };
    let fields = fields(header)?;
    let op = fields
        .get("op")
        .and_then(|v| v.first().copied())
        .ok_or("record without `op`")?;
    Ok(Record {
        fields,
        op,
        body,
        end: c.at,
        missing,
    })
}

/// The first place after `from` where a whole record of a known type parses: where reading
/// goes on after a damaged stretch, as `rosbag reindex` scans a bag record by record. Each
/// record's header holds the field `op=` (length 4), and begins a little before it.
fn resync(data: &[u8], from: usize) -> Option<usize> {
    const OP: &[u8] = b"\x04\x00\x00\x00op=";
    let mut p = from;
    while p + OP.len() <= data.len() {
        let k = data[p..].windows(OP.len()).position(|w| w == OP)?;
        let at_op = p + k;
        // The header starts at most this far before its op field.
        let lowest = at_op.saturating_sub(4 + 1024).max(from);
        for start in (lowest..=at_op.saturating_sub(4)).rev() {
            if let Ok(r) = parse_record(data, start, false)
                && (0x02..=0x07).contains(&r.op)
                && start + 4 <= at_op
            {
                return Some(start);
            }
        }
        p = at_op + 1;
    }
    None
}

/// A compressed chunk's contents as far as they decompress (a chunk cut by the end of the
/// file), at most `size` bytes.
fn inflate_partial(mut reader: impl Read, size: usize) -> Vec<u8> {
    let mut out = Vec::new();
    let mut buf = vec![0u8; 1 << 16];
    while out.len() < size {
        match reader.read(&mut buf) {
            Ok(0) | Err(_) => break,
            Ok(n) => out.extend_from_slice(&buf[..n.min(size - out.len())]),
        }
    }
    out
}

/// Walks the records of `data` (the file after its magic line, or a chunk's contents), `base`
/// being the offset of `data` in the file. Strict, the first damaged record is the error;
/// salvaging, a record that does not parse is recorded as lost and reading goes on at the next
/// record that does. `cut`: `data` is what decompressed of a chunk cut by the end of the file,
/// whose last record running past its end is part of that cut, not a loss of its own.
fn records(
    data: &[u8],
    base: usize,
    raw: &mut Raw,
    in_chunk: bool,
    cut: bool,
) -> Result<(), BagError> {
    let mut at = 0;
    while at < data.len() {
        let offset = base + at;
        let err = |message: String| BagError { offset, message };
        let rec = match parse_record(data, at, raw.salvage && !in_chunk) {
            Ok(r) => r,
            Err(m) if !raw.salvage => return Err(err(m)),
            Err(m) => {
                let next = resync(data, at + 1);
                if cut && next.is_none() {
                    break;
                }
                let lost = next.unwrap_or(data.len()) - at;
                if next.is_none() && m.contains("truncated") && !in_chunk {
                    raw.damage.truncated = true;
                }
                raw.lose(offset, m, lost);
                match next {
                    Some(n) => {
                        at = n;
                        continue;
                    }
                    None => break,
                }
            }
        };
        at = rec.end;
        let step = match rec.op {
            0x05 if in_chunk => {
                // The format puts messages and connections in chunks, never chunks: refusing
                // them bounds the recursion at one level.
                Err(err("a chunk inside a chunk".into()))
            }
            0x05 => chunk(&rec, offset, raw),
            0x07 => connection(&rec).map_err(err).map(|(conn, topic, ty)| {
                raw.conns.insert(conn, (topic, ty));
            }),
            0x02 => match field_u32(&rec.fields, "conn") {
                Err(m) => Err(err(m)),
                Ok(conn) => match raw.conns.get(&conn).map(|c| c.1.clone()) {
                    Some(ty) => raw.message(conn, &ty, rec.body).map_err(err),
                    None if raw.salvage => {
                        raw.pending.push((offset, conn, rec.body.to_vec()));
                        Ok(())
                    }
                    None => Err(err(format!(
                        "message on connection {conn}, which no record defined"
                    ))),
                },
            },
            0x03 | 0x04 | 0x06 => Ok(()),
            other => {
                *raw.skipped
                    .entry(format!("record op 0x{other:02x}"))
                    .or_insert(0) += 1;
                Ok(())
            }
        };
        match step {
            Ok(()) => {}
            Err(e) if !raw.salvage => return Err(e),
            Err(e) => raw.lose(e.offset, e.message, rec.body.len()),
        }
        if rec.missing > 0 {
            raw.damage.truncated = true;
            raw.lose(
                offset,
                format!(
                    "record cut short by the end of the file ({} of its {} bytes missing)",
                    rec.missing,
                    rec.missing + rec.body.len()
                ),
                rec.missing,
            );
        }
    }
    Ok(())
}

/// A connection record: its id, topic and message type.
fn connection(rec: &Record) -> Result<(u32, String, String), String> {
    let conn = field_u32(&rec.fields, "conn")?;
    let conn_header = fields(rec.body)?;
    let text = |f: &HashMap<String, Vec<u8>>, k: &str| {
        f.get(k)
            .map(|v| String::from_utf8_lossy(v).into_owned())
            .unwrap_or_default()
    };
    let mut topic = text(&conn_header, "topic");
    if topic.is_empty() {
        topic = text(&rec.fields, "topic");
    }
    Ok((conn, topic, text(&conn_header, "type")))
}

/// A chunk record: its contents decompressed and walked. A chunk cut by the end of the file
/// (salvaging) gives the messages of what decompresses.
fn chunk(rec: &Record, offset: usize, raw: &mut Raw) -> Result<(), BagError> {
    let err = |message: String| BagError { offset, message };
    let compression = rec
        .fields
        .get("compression")
        .map(|v| String::from_utf8_lossy(v).into_owned())
        .unwrap_or_default();
    let size = field_u32(&rec.fields, "size").map_err(err)? as usize;
    let body = rec.body;
    if rec.missing > 0 {
        let inner = match compression.as_str() {
            "none" => body[..body.len().min(size)].to_vec(),
            "bz2" => inflate_partial(bzip2::read::BzDecoder::new(body), size),
            "lz4" => inflate_partial(lz4_flex::frame::FrameDecoder::new(body), size),
            _ => Vec::new(),
        };
        let before = raw.messages.values().sum::<usize>();
        records(&inner, offset, raw, true, true)?;
        raw.damage.messages_salvaged_from_cut_chunk +=
            raw.messages.values().sum::<usize>() - before;
        return Ok(());
    }
    let inner = match compression.as_str() {
        "none" => body.to_vec(),
        "bz2" => inflate(bzip2::read::BzDecoder::new(body), size, "bz2").map_err(err)?,
        "lz4" => inflate(lz4_flex::frame::FrameDecoder::new(body), size, "lz4").map_err(err)?,
        other => {
            return Err(err(format!(
                "chunk compression `{other}` is not supported (expected none, bz2 or lz4)"
            )));
        }
    };
    records(&inner, offset, raw, true, false)
}

/// The topic of each stream of type `ty`: the one `chosen`, or the only one with messages;
/// several without a choice are an error naming them (`flag` makes the choice).
fn choose_topic(
    raw: &Raw,
    ty: &str,
    used: &std::collections::BTreeSet<String>,
    chosen: &Option<String>,
    flag: &str,
) -> Result<Option<String>, BagError> {
    let err = |message: String| BagError { offset: 0, message };
    let defined: std::collections::BTreeSet<&String> = raw
        .conns
        .values()
        .filter(|c| c.1 == ty)
        .map(|c| &c.0)
        .collect();
    match chosen {
        Some(c) if defined.contains(c) => Ok(Some(c.clone())),
        Some(c) => Err(err(format!(
            "{flag} {c}: the bag has no {ty} topic `{c}`; its {ty} topics: {}",
            if defined.is_empty() {
                "none".to_string()
            } else {
                defined
                    .iter()
                    .map(|s| s.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            }
        ))),
        None if used.len() > 1 => Err(err(format!(
            "the bag has {} {ty} topics ({}): choose one with {flag}",
            used.len(),
            used.iter()
                .map(String::as_str)
                .collect::<Vec<_>>()
                .join(", ")
        ))),
        None => Ok(used.iter().next().cloned()),
    }
}

/// Reads a ROS 1 bag's laser scans and odometry, refusing a damaged bag (see [`read_with`]).
pub fn read(bytes: &[u8]) -> Result<Log, BagError> {
    read_with(
        bytes,
        &ReadOptions {
            strict: true,
            ..Default::default()
        },
    )
}

impl Raw {
    /// Reads the messages kept until their connection's definition came, and loses those
    /// whose definition never came.
    fn settle_pending(&mut self) {
        for (offset, conn, body) in std::mem::take(&mut self.pending) {
            match self.conns.get(&conn).map(|c| c.1.clone()) {
                Some(ty) => {
                    if let Err(m) = self.message(conn, &ty, &body) {
                        self.lose(offset, m, body.len());
                    }
                }
                None => self.lose(
                    offset,
                    format!("message on connection {conn}, whose definition was lost"),
                    body.len(),
                ),
            }
        }
    }
}

/// Where laser frame `frame` sits on `base`, by the bag's tf, as a planar pose and whether it
/// is mounted upside down; none without a tf chain. A laser tilted more than 0.1 rad is an
/// error: futago reads lasers that scan parallel to the floor.
fn laser_mount(
    tf: &HashMap<String, (String, Transform)>,
    base: &str,
    frame: &str,
) -> Result<Option<(Pose2, bool)>, BagError> {
    match chain(tf, base, frame) {
        None => Ok(None),
        Some(t) => {
            let [roll, pitch, yaw] = t.rpy();
            let flipped = roll.abs() > std::f64::consts::FRAC_PI_2;
            let tilt = if flipped {
                std::f64::consts::PI - roll.abs()
            } else {
                roll.abs()
            };
            if tilt > 0.1 || pitch.abs() > 0.1 {
                return Err(BagError {
                    offset: 0,
                    message: format!(
                        "laser frame `{}` is tilted on `{base}` (roll {roll:.3}, pitch {pitch:.3} rad): futago reads lasers that scan parallel to the floor",
                        frame
                    ),
                });
            }
            // Upside down, its yaw is measured about the flipped z axis.
            Ok(Some((Pose2::new(t.t[0], t.t[1], yaw), flipped)))
        }
    }
}

/// The chosen odometry (header `seq`, stamp, pose) in the order it was published, restamped
/// where its stamps contradict that order.
fn odometry_in_order(chosen: &[(u32, Time, Pose2)]) -> Vec<(Time, Pose2)> {
    let times = acquisition_times(&chosen.iter().map(|o| (o.0, o.1)).collect::<Vec<_>>());
    let mut o: Vec<(Time, u32, Pose2)> = chosen
        .iter()
        .zip(times)
        .map(|(&(seq, _, pose), t)| (t, seq, pose))
        .collect();
    o.sort_by_key(|o| (o.0, o.1));
    o.into_iter().map(|(t, _, p)| (t, p)).collect::<Vec<_>>()
}

/// The chosen scans (header `seq`, scan) in the order they were taken, restamped where their
/// stamps contradict it, each with its place in the file (for the annotations after it).
fn scans_in_order(chosen: Vec<(u32, LaserScan)>) -> Vec<(Time, u32, usize, LaserScan)> {
    let times = acquisition_times(&chosen.iter().map(|s| (s.0, s.1.stamp)).collect::<Vec<_>>());
    // With each scan's place in the file, for the annotations that follow it.
    let mut s: Vec<(Time, u32, usize, LaserScan)> = chosen
        .into_iter()
        .zip(times)
        .enumerate()
        .map(|(k, ((seq, scan), t))| (t, seq, k, scan))
        .collect();
    s.sort_by_key(|s| (s.0, s.1, s.2));
    s
}

/// Reads a ROS 1 bag's laser scans and odometry; other message types are counted as skipped.
///
/// A bag with several `sensor_msgs/LaserScan` (or `nav_msgs/Odometry`) topics is an error
/// naming them unless `o` chooses one. A bag of laser scans without odometry is read with
/// [`Log::odometry_absent`] set. With `o.strict` off, a damaged bag (cut short, a chunk that
/// does not decompress or parse, a garbled stretch) gives what can be read: every intact
/// record and chunk, the messages of a cut chunk as far as it decompresses, and in
/// [`Log::damage`] what was lost.
pub fn read_with(bytes: &[u8], o: &ReadOptions) -> Result<Log, BagError> {
    const MAGIC: &[u8] = b"#ROSBAG V2.0\n";
    if !bytes.starts_with(MAGIC) {
        return Err(BagError {
            offset: 0,
            message: "not a ROS bag of format 2.0 (no `#ROSBAG V2.0` line)".into(),
        });
    }
    let mut raw = Raw {
        salvage: !o.strict,
        ..Default::default()
    };
    records(&bytes[MAGIC.len()..], MAGIC.len(), &mut raw, false, false)?;
    // Messages whose connection was defined after them (or never, its record lost).
    raw.settle_pending();
    assemble(raw, o)
}

/// The log of what a bag held (`raw`, ROS 1 or ROS 2): the chosen scan and odometry streams in
/// the order they were taken, each scan with the odometry at its stamp and its laser's mount.
pub(crate) fn assemble(mut raw: Raw, o: &ReadOptions) -> Result<Log, BagError> {
    let topic_of = |conn: u32| {
        raw.conns
            .get(&conn)
            .map(|c| c.0.clone())
            .unwrap_or_default()
    };
    let scan_topic = choose_topic(
        &raw,
        "sensor_msgs/LaserScan",
        &raw.scans.iter().map(|s| topic_of(s.0)).collect(),
        &o.scan_topic,
        "--scan-topic",
    )?;
    let odom_topic = choose_topic(
        &raw,
        "nav_msgs/Odometry",
        &raw.odometry.iter().map(|s| topic_of(s.0)).collect(),
        &o.odom_topic,
        "--odom-topic",
    )?;
    // The chosen streams; each annotation keeps its place after the chosen scans.
    let mut kept_before = Vec::with_capacity(raw.scans.len() + 1);
    kept_before.push(0usize);
    let mut chosen_scans = Vec::new();
    for (conn, seq, scan) in std::mem::take(&mut raw.scans) {
        let keep = scan_topic.as_deref() == Some(topic_of(conn).as_str());
        if keep {
            chosen_scans.push((seq, scan));
        } else {
            *raw.skipped
                .entry(format!("LaserScan on {} (not chosen)", topic_of(conn)))
                .or_insert(0) += 1;
        }
        kept_before.push(chosen_scans.len());
    }
    let mut chosen_odometry = Vec::new();
    let mut base = None;
    for (conn, seq, t, pose, child) in std::mem::take(&mut raw.odometry) {
        if odom_topic.as_deref() == Some(topic_of(conn).as_str()) {
            base.get_or_insert(child);
            chosen_odometry.push((seq, t, pose));
        } else {
            *raw.skipped
                .entry(format!("Odometry on {} (not chosen)", topic_of(conn)))
                .or_insert(0) += 1;
        }
    }
    // Each stream in the order it was published, restamped where its stamps contradict it.
    let odometry = odometry_in_order(&chosen_odometry);
    let scans = scans_in_order(chosen_scans);
    let mut sorted_of_file = vec![0usize; scans.len()];
    for (i, s) in scans.iter().enumerate() {
        sorted_of_file[s.2] = i;
    }
    let odometry_absent = !scans.is_empty() && odometry.is_empty();
    let mut log = Log {
        skipped: std::mem::take(&mut raw.skipped),
        messages: std::mem::take(&mut raw.messages),
        damage: std::mem::take(&mut raw.damage),
        odometry_absent,
        scan_topic,
        odom_topic,
        ..Default::default()
    };
    for &(before, id, position) in &raw.people {
        let before = kept_before[before.min(kept_before.len() - 1)];
        match before.checked_sub(1) {
            Some(k) => log.people.push(PersonMark {
                scan: sorted_of_file[k],
                id,
                position,
            }),
            None => {
                *log.skipped
                    .entry("leg_tracker/Person before any scan".into())
                    .or_insert(0) += 1
            }
        }
    }
    let base = base.unwrap_or_else(|| "base_link".into());
    // Each frame's mount, found once.
    let mut mounts: HashMap<String, Option<(Pose2, bool)>> = HashMap::new();
    for (taken, _, _, mut scan) in scans {
        let logged = scan.stamp;
        scan.stamp = taken;
        let pose =
            crate::pose_at(&odometry, taken, crate::Outside::Clamp).unwrap_or(Pose2::IDENTITY);
        if odometry_absent {
            // No base to place the laser on: the laser's frame is the robot's.
            log.scans.push(LogScan {
                scan,
                logged,
                odometry: Pose2::IDENTITY,
                mount: Pose2::IDENTITY,
            });
            continue;
        }
        let mount = match mounts.get(&scan.frame) {
            Some(m) => *m,
            None => {
                let m = laser_mount(&raw.tf, &base, &scan.frame)?;
                mounts.insert(scan.frame.clone(), m);
                m
            }
        };
        let mount = match mount {
            Some((m, flipped)) => {
                if flipped {
                    // Upside down, a beam at angle a in the laser frame lies at −a.
                    let n = scan.ranges.len().saturating_sub(1) as f64;
                    scan.angle_min = -(scan.angle_min + n * scan.angle_increment);
                    scan.ranges.reverse();
                }
                m
            }
            None => {
                *log.skipped
                    .entry(format!("no tf from {base} to {}", scan.frame))
                    .or_insert(0) += 1;
                Pose2::IDENTITY
            }
        };
        log.scans.push(LogScan {
            scan,
            logged,
            odometry: pose,
            mount,
        });
    }
    log.odometry = odometry;
    Ok(log)
}

/// When each message of one stream was taken, given its header `seq` and stamp.
///
/// A publisher numbers its messages in order, but a stamp can be wrong: the Intel Research Lab
/// log, as converted to a bag, holds scans and odometry stamped up to 0.9 s late, out of
/// order with the messages numbered around them (scan 1131 stamped after scans 1132–1135),
/// while the scan itself was taken between its neighbours by number (the benchmark's relations
/// place it there). The stamps that agree with the numbering are the longest run of them that
/// never goes back in time, taken in `seq` order; each other message is given the time
/// interpolated by `seq` between the nearest of those before and after it. A stream whose
/// `seq`s are not all distinct (a recorder that leaves them 0) keeps its stamps.
fn acquisition_times(stream: &[(u32, Time)]) -> Vec<Time> {
    let mut order: Vec<usize> = (0..stream.len()).collect();
    order.sort_by_key(|&i| stream[i].0);
    if order.windows(2).any(|w| stream[w[0]].0 == stream[w[1]].0) {
        return stream.iter().map(|s| s.1).collect();
    }
    // The longest non-decreasing run of stamps in seq order (patience sorting): `tails[k]` is
    // the position in `order` ending the best run of length k + 1 found so far.
    let stamp = |k: usize| stream[order[k]].1;
    let mut tails: Vec<usize> = Vec::new();
    // The run's element before each one, for walking the best run back from its end.
    let before: Vec<Option<usize>> = (0..order.len())
        .map(|k| {
            let at = tails.partition_point(|&j| stamp(j) <= stamp(k));
            let b = at.checked_sub(1).map(|a| tails[a]);
            if at == tails.len() {
                tails.push(k);
            } else {
                tails[at] = k;
            }
            b
        })
        .collect();
    let mut anchor = vec![false; order.len()];
    let mut k = tails.last().copied();
    while let Some(j) = k {
        anchor[j] = true;
        k = before[j];
    }
    let mut times = vec![Time::ZERO; stream.len()];
    let mut last: Option<usize> = None;
    for k in (0..order.len()).filter(|&k| anchor[k]) {
        // The messages between two anchors, interpolated by seq.
        let from = last.map_or(0, |l| l + 1);
        for m in from..k {
            times[order[m]] = match last {
                None => stamp(k),
                Some(l) => {
                    let (sa, sb, s) = (
                        stream[order[l]].0 as f64,
                        stream[order[k]].0 as f64,
                        stream[order[m]].0 as f64,
                    );
                    let (ta, tb) = (stamp(l).nanos(), stamp(k).nanos());
                    Time(ta + ((tb - ta) as f64 * (s - sa) / (sb - sa)).round() as i64)
                }
            };
        }
        times[order[k]] = stamp(k);
        last = Some(k);
    }
    // Messages after the last anchor (stamped before it) take its time.
    if let Some(l) = last {
        for m in l + 1..order.len() {
            times[order[m]] = stamp(l);
        }
    }
    times
}

fn field(name: &str, value: &[u8]) -> Vec<u8> {
    let mut f = name.as_bytes().to_vec();
    f.push(b'=');
    f.extend_from_slice(value);
    let mut out = (f.len() as u32).to_le_bytes().to_vec();
    out.extend(f);
    out
}

fn record(header: &[Vec<u8>], data: &[u8]) -> Vec<u8> {
    let h: Vec<u8> = header.concat();
    let mut out = (h.len() as u32).to_le_bytes().to_vec();
    out.extend(&h);
    out.extend((data.len() as u32).to_le_bytes());
    out.extend(data);
    out
}

fn header_msg(stamp: u32, frame: &str) -> Vec<u8> {
    header_seq(7, stamp, frame)
}

/// A `std_msgs/Header`: `seq`, a stamp of whole seconds and a frame.
fn header_seq(seq: u32, stamp: u32, frame: &str) -> Vec<u8> {
    let mut m = seq.to_le_bytes().to_vec();
    m.extend(stamp.to_le_bytes());
    m.extend(0u32.to_le_bytes());
    m.extend((frame.len() as u32).to_le_bytes());
    m.extend(frame.as_bytes());
    m
}

fn ros_string(s: &str) -> Vec<u8> {
    let mut m = (s.len() as u32).to_le_bytes().to_vec();
    m.extend(s.as_bytes());
    m
}

/// A `tf2_msgs/TFMessage` of one transform `parent → child`: translation and quaternion.
fn tf_bytes(parent: &str, child: &str, t: [f64; 3], q: [f64; 4]) -> Vec<u8> {
    let mut m = 1u32.to_le_bytes().to_vec();
    m.extend(header_msg(0, parent));
    m.extend(ros_string(child));
    for v in t.iter().chain(&q) {
        m.extend(v.to_le_bytes());
    }
    m
}

/// A small valid bag: one connection per type (a laser scan, odometry, tf, and a type the
/// reader skips), a scan at t = 2 s in frame `laser`, odometry of `base_link` at 1 s and 3 s,
/// and the laser mounted 0.22 m ahead of the base on `/tf_static` (`laser_q` its rotation),
/// the messages inside one chunk, bz2-compressed or not. A fixture for tests and a seed for
/// the fuzzer.
pub fn example(bz2: bool) -> Vec<u8> {
    example_mounted(if bz2 { "bz2" } else { "none" }, [0.0, 0.0, 0.0, 1.0])
}

/// [`example`] with its chunk compressed by `compression` (`none`, `bz2` or `lz4`) and the
/// laser turned by the quaternion `laser_q` on the base.
pub fn example_mounted(compression: &str, laser_q: [f64; 4]) -> Vec<u8> {
    use writer::{BagWriter, laser_scan_message, odometry_message};
    let mut w = BagWriter::new(compression, 100);
    let scan = w.connection("/scan", "sensor_msgs/LaserScan");
    let odom = w.connection("/odom", "nav_msgs/Odometry");
    let tf = w.connection("/tf_static", "tf2_msgs/TFMessage");
    let imu = w.connection("/imu", "sensor_msgs/Imu");
    let t = Time::from_secs;
    w.write(
        tf,
        t(0.0),
        &tf_bytes("base_link", "laser", [0.22, 0.0, 0.3], laser_q),
    );
    let odo = |seq: u32, x: f64| {
        odometry_message(
            seq,
            t(seq as f64),
            "odom",
            "base_link",
            Pose2::new(x, 0.0, 0.0),
        )
    };
    w.write(odom, t(1.0), &odo(1, 0.0));
    let s = LaserScan {
        frame: "laser".into(),
        stamp: t(2.0),
        angle_min: -1.0,
        angle_increment: 0.5,
        time_increment: 0.0,
        range_min: 0.02,
        range_max: 10.0,
        ranges: vec![1.0, 2.0, f32::INFINITY, 12.0, 3.0],
    };
    w.write(scan, t(2.0), &laser_scan_message(7, &s));
    w.write(odom, t(3.0), &odo(3, 1.0));
    w.write(imu, t(3.0), b"xx");
    w.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 3-beam `sensor_msgs/LaserScan` in `frame`, numbered `seq`, stamped `stamp` s.
    fn scan_message(frame: &str, seq: u32, stamp: u32) -> Vec<u8> {
        let mut m = header_seq(seq, stamp, frame);
        for v in [-1.0f32, 1.0, 1.0, 0.0, 0.0, 0.02, 10.0] {
            m.extend(v.to_bits().to_le_bytes());
        }
        m.extend(3u32.to_le_bytes());
        for r in [1.0f32, 2.0, 3.0] {
            m.extend(r.to_bits().to_le_bytes());
        }
        m.extend(0u32.to_le_bytes());
        m
    }

    /// A `nav_msgs/Odometry` of `child` at x = `x` m, numbered `seq`, stamped `stamp` s.
    fn odometry_message(child: &str, seq: u32, stamp: u32, x: f64) -> Vec<u8> {
        let mut m = header_seq(seq, stamp, "odom");
        m.extend(ros_string(child));
        for v in [x, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0] {
            m.extend(v.to_le_bytes());
        }
        m.extend(vec![0u8; 36 * 8 + 6 * 8 + 36 * 8]);
        m
    }

    /// A connection record of message type `ty`, outside any chunk.
    fn bare_connection(id: u32, ty: &str) -> Vec<u8> {
        record(
            &[field("op", &[0x07]), field("conn", &id.to_le_bytes())],
            &field("type", ty.as_bytes()),
        )
    }

    /// A message record on connection `id`, outside any chunk.
    fn bare_message(id: u32, body: Vec<u8>) -> Vec<u8> {
        record(
            &[field("op", &[0x02]), field("conn", &id.to_le_bytes())],
            &body,
        )
    }

    #[test]
    fn scans_and_odometry_come_out_of_a_bz2_chunk() {
        let log = read(&example(true)).unwrap();
        assert_eq!(log.scans.len(), 1);
        let s = &log.scans[0];
        assert_eq!(s.scan.stamp, Time::from_secs(2.0));
        assert_eq!(
            s.scan.ranges,
            vec![1.0, 2.0, f32::INFINITY, f32::INFINITY, 3.0]
        );
        assert_eq!(s.scan.frame, "laser");
        // Odometry interpolated half way between x = 0 at 1 s and x = 1 at 3 s.
        assert!((s.odometry.x - 0.5).abs() < 1e-12);
        assert_eq!(log.odometry.len(), 2);
        assert_eq!(log.skipped["message type sensor_msgs/Imu"], 1);
        // The mount from /tf_static, on the floor plane.
        assert_eq!(s.mount, Pose2::new(0.22, 0.0, 0.0));
        assert_eq!(read(&example(false)).unwrap(), log);
        assert_eq!(
            read(&example_mounted("lz4", [0.0, 0.0, 0.0, 1.0])).unwrap(),
            log
        );
    }

    #[test]
    fn the_laser_is_placed_by_tf_turned_or_upside_down() {
        let h = std::f64::consts::FRAC_1_SQRT_2;
        // Turned 90° left about z: (0, 0, sin 45°, cos 45°).
        let log = read(&example_mounted("bz2", [0.0, 0.0, h, h])).unwrap();
        let m = log.scans[0].mount;
        assert!((m.x - 0.22).abs() < 1e-12 && m.y.abs() < 1e-12, "{m:?}");
        assert!(
            (m.theta - std::f64::consts::FRAC_PI_2).abs() < 1e-9,
            "{m:?}"
        );
        assert_eq!(log.scans[0].scan.angle_min, -1.0);
        // Upside down (roll π: (1, 0, 0, 0)): the scan is mirrored, beam order and angles.
        let log = read(&example_mounted("bz2", [1.0, 0.0, 0.0, 0.0])).unwrap();
        let s = &log.scans[0];
        assert!(s.mount.theta.abs() < 1e-9, "{:?}", s.mount);
        // Five beams from −1 rad by 0.5: mirrored, from −1 again, in reverse order.
        assert!(
            (s.scan.angle_min + 1.0).abs() < 1e-6,
            "{}",
            s.scan.angle_min
        );
        assert_eq!(
            s.scan.ranges,
            vec![3.0, f32::INFINITY, f32::INFINITY, 2.0, 1.0]
        );
        // Tilted 30° about y: refused.
        let (sn, cs) = (15f64.to_radians().sin(), 15f64.to_radians().cos());
        let e = read(&example_mounted("bz2", [0.0, sn, 0.0, cs])).unwrap_err();
        assert!(e.message.contains("tilted"), "{e}");
    }

    #[test]
    fn a_message_stamped_out_of_its_seq_order_is_restamped_between_its_neighbours() {
        let t = |s: &[(u32, f64)]| -> Vec<f64> {
            let stream: Vec<(u32, Time)> =
                s.iter().map(|&(q, x)| (q, Time::from_secs(x))).collect();
            acquisition_times(&stream)
                .into_iter()
                .map(Time::secs)
                .collect()
        };
        // In order: kept.
        assert_eq!(t(&[(0, 1.0), (1, 2.0), (2, 2.0)]), [1.0, 2.0, 2.0]);
        // Seq 12 stamped late (after 13 and 14), given in file order: half way from 11 to 13.
        assert_eq!(
            t(&[(10, 1.0), (11, 2.0), (13, 3.0), (14, 4.0), (12, 4.5)]),
            [1.0, 2.0, 3.0, 4.0, 2.5]
        );
        // Stamped early: the rest keep theirs; the seq gap from 1 to 5 weighs the
        // interpolation (a quarter of the way).
        assert_eq!(
            t(&[(0, 1.0), (1, 2.0), (2, 0.1), (5, 5.0), (6, 6.0)]),
            [1.0, 2.0, 2.75, 5.0, 6.0]
        );
        // Seqs that number nothing (all 0): stamps kept, out of order as they are.
        assert_eq!(t(&[(0, 2.0), (0, 1.0)]), [2.0, 1.0]);
    }

    #[test]
    fn a_scan_logged_late_takes_the_odometry_of_its_place_in_the_sequence() {
        let mut bag = b"#ROSBAG V2.0\n".to_vec();
        for r in [
            record(&[field("op", &[0x03])], &[]),
            bare_connection(0, "sensor_msgs/LaserScan"),
            bare_connection(1, "nav_msgs/Odometry"),
            bare_message(1, odometry_message("base_link", 0, 1, 0.0)),
            bare_message(1, odometry_message("base_link", 1, 2, 1.0)),
            bare_message(0, scan_message("laser", 0, 1)),
            bare_message(1, odometry_message("base_link", 3, 4, 3.0)),
            bare_message(0, scan_message("laser", 2, 3)),
            bare_message(1, odometry_message("base_link", 4, 5, 4.0)),
            bare_message(0, scan_message("laser", 3, 4)),
            // Scan 1 and odometry 2 arrive last, stamped after everything else.
            bare_message(0, scan_message("laser", 1, 5)),
            bare_message(1, odometry_message("base_link", 2, 6, 2.5)),
        ] {
            bag.extend(r);
        }
        let log = read(&bag).unwrap();
        let got: Vec<(f64, f64, f64)> = log
            .scans
            .iter()
            .map(|s| (s.scan.stamp.secs(), s.logged.secs(), s.odometry.x))
            .collect();
        // Scan 1 was taken between scans 0 and 2 (at 2 s, where odometry read 1 m); scan 2
        // at 3 s, where odometry 2 (its stamp 6 s put right) read 2.5 m.
        assert_eq!(
            got,
            [
                (1.0, 1.0, 0.0),
                (2.0, 5.0, 1.0),
                (3.0, 3.0, 2.5),
                (4.0, 4.0, 3.0)
            ]
        );
    }

    #[test]
    fn annotated_people_follow_their_scan_and_slashed_frames_are_one() {
        let person = |id: u32, x: f64, y: f64| {
            let mut m = Vec::new();
            for v in [x, y, 0.0, 0.0, 0.0, 0.0, 1.0] {
                m.extend(v.to_le_bytes());
            }
            m.extend(id.to_le_bytes());
            m
        };
        let mut bag = b"#ROSBAG V2.0\n".to_vec();
        for r in [
            record(&[field("op", &[0x03])], &[]),
            bare_connection(0, "sensor_msgs/LaserScan"),
            bare_connection(1, "nav_msgs/Odometry"),
            bare_connection(2, "leg_tracker/Person"),
            bare_connection(3, "tf2_msgs/TFMessage"),
            bare_message(
                3,
                tf_bytes("base_link", "laser", [0.3, 0.0, 0.2], [0.0, 0.0, 0.0, 1.0]),
            ),
            bare_message(2, person(9, 0.0, 0.0)),
            bare_message(1, odometry_message("/base_link", 0, 1, 0.0)),
            bare_message(0, scan_message("/laser", 0, 1)),
            bare_message(2, person(1, 2.0, -0.5)),
            bare_message(2, person(2, 3.0, 0.5)),
            bare_message(0, scan_message("/laser", 1, 2)),
            bare_message(1, odometry_message("/base_link", 1, 3, 0.0)),
            bare_message(0, scan_message("/laser", 2, 3)),
            bare_message(2, person(1, 1.5, -0.4)),
        ] {
            bag.extend(r);
        }
        let log = read(&bag).unwrap();
        let marks: Vec<(usize, u32, [f64; 2])> = log
            .people
            .iter()
            .map(|m| (m.scan, m.id, m.position))
            .collect();
        assert_eq!(
            marks,
            [(0, 1, [2.0, -0.5]), (0, 2, [3.0, 0.5]), (2, 1, [1.5, -0.4])]
        );
        assert_eq!(log.skipped["leg_tracker/Person before any scan"], 1);
        // `/laser` and `/base_link` are tf's `laser` and `base_link`: the mount is found.
        assert_eq!(log.scans[0].mount, Pose2::new(0.3, 0.0, 0.0));
        assert_eq!(log.scans[0].scan.frame, "laser");
    }

    #[test]
    fn truncated_and_foreign_files_are_errors_not_panics() {
        let b = example(true);
        for cut in [20, b.len() / 2, b.len() - 3] {
            let e = read(&b[..cut]).unwrap_err();
            assert!(
                e.message.contains("truncated") || e.message.contains("bz2"),
                "{e}"
            );
        }
        assert!(
            read(b"hello")
                .unwrap_err()
                .message
                .contains("not a ROS bag")
        );
    }

    #[test]
    fn a_chunk_bigger_than_its_header_or_inside_a_chunk_is_an_error() {
        // The header promises 10 bytes fewer than the chunk holds.
        for compression in ["bz2", "lz4"] {
            let mut b = example_mounted(compression, [0.0, 0.0, 0.0, 1.0]);
            let at = b.windows(5).position(|w| w == b"size=").unwrap() + 5;
            let size = u32::from_le_bytes(b[at..at + 4].try_into().unwrap());
            b[at..at + 4].copy_from_slice(&(size - 10).to_le_bytes());
            let e = read(&b).unwrap_err();
            assert!(e.message.contains("decompresses to more than"), "{e}");
            assert!(e.message.contains(compression), "{e}");
        }
        // A chunk whose content is another chunk.
        let inner = record(
            &[
                field("op", &[0x05]),
                field("compression", b"none"),
                field("size", &0u32.to_le_bytes()),
            ],
            &[],
        );
        let mut nested = b"#ROSBAG V2.0\n".to_vec();
        nested.extend(record(
            &[
                field("op", &[0x05]),
                field("compression", b"none"),
                field("size", &(inner.len() as u32).to_le_bytes()),
            ],
            &inner,
        ));
        let e = read(&nested).unwrap_err();
        assert!(e.message.contains("a chunk inside a chunk"), "{e}");
    }

    /// A bag of `n` scans (10 Hz, in frame `laser`), each after an odometry message of the
    /// robot driving along x at 0.5 m/s, `per_chunk` messages a chunk; with `odometry` off,
    /// scans alone. Scans are numbered from 1, stamped `seq` / 10 s.
    fn fixture(n: u32, per_chunk: usize, compression: &str, odometry: bool) -> Vec<u8> {
        use writer::{BagWriter, laser_scan_message, odometry_message};
        let mut w = BagWriter::new(compression, per_chunk);
        let scan_conn = w.connection("/scan", "sensor_msgs/LaserScan");
        let odom_conn = w.connection("/odom", "nav_msgs/Odometry");
        for k in 1..=n {
            let t = Time::from_secs(k as f64 / 10.0);
            if odometry {
                let pose = Pose2::new(0.05 * k as f64, 0.0, 0.0);
                w.write(
                    odom_conn,
                    t,
                    &odometry_message(k, t, "odom", "base_link", pose),
                );
            }
            let scan = LaserScan {
                frame: "laser".into(),
                stamp: t,
                angle_min: -1.0,
                angle_increment: 0.01,
                time_increment: 0.0,
                range_min: 0.02,
                range_max: 10.0,
                ranges: (0..201)
                    .map(|b| 2.0 + (b as f32 + k as f32) * 0.001)
                    .collect(),
            };
            w.write(scan_conn, t, &laser_scan_message(k, &scan));
        }
        w.finish()
    }

    fn salvaging() -> ReadOptions {
        ReadOptions::default()
    }

    fn seqs(log: &Log) -> Vec<u32> {
        log.scans
            .iter()
            .map(|s| (s.scan.stamp.secs() * 10.0).round() as u32)
            .collect()
    }

    #[test]
    fn the_writer_s_bags_read_back_whole() {
        for c in ["none", "bz2", "lz4"] {
            let log = read(&fixture(40, 10, c, true)).unwrap();
            assert_eq!(seqs(&log), (1..=40).collect::<Vec<_>>(), "{c}");
            assert!((log.scans[39].odometry.x - 2.0).abs() < 1e-9);
            assert!(log.damage.is_empty());
            assert_eq!(log.messages["/scan"], 40);
            assert_eq!(log.scan_topic.as_deref(), Some("/scan"));
            assert!(!log.odometry_absent);
        }
    }

    #[test]
    fn a_cut_bag_gives_every_scan_before_the_cut() {
        for c in ["none", "bz2", "lz4"] {
            let bag = fixture(100, 10, c, true);
            // Cut inside the sixth chunk (each holds five scans and five odometry messages).
            let chunk_starts: Vec<usize> = bag
                .windows(8)
                .enumerate()
                .filter(|(_, w)| *w == b"\x04\x00\x00\x00op=\x05")
                .map(|(k, _)| k)
                .collect();
            let cut = chunk_starts[5] + 300;
            let e = read(&bag[..cut]).unwrap_err();
            assert!(e.message.contains("truncated"), "{e}");
            let log = read_with(&bag[..cut], &salvaging()).unwrap();
            let got = seqs(&log);
            // The five whole chunks' 25 scans; an uncompressed cut chunk gives more.
            assert!(got.len() >= 25, "{c}: {got:?}");
            assert_eq!(got, (1..=got.len() as u32).collect::<Vec<_>>(), "{c}");
            assert!(got.len() < 50, "{c}");
            assert!(log.damage.truncated, "{c}");
            assert!(log.damage.bytes_lost > 0, "{c}");
            let last = log.damage.losses.last().unwrap();
            assert!(last.last_stamp_before_s.is_some() && last.first_stamp_after_s.is_none());
        }
    }

    #[test]
    fn a_corrupt_chunk_in_the_middle_costs_only_its_own_scans() {
        let bag = fixture(100, 10, "bz2", true);
        let chunk_starts: Vec<usize> = bag
            .windows(8)
            .enumerate()
            .filter(|(_, w)| *w == b"\x04\x00\x00\x00op=\x05")
            .map(|(k, _)| k)
            .collect();
        assert_eq!(chunk_starts.len(), 20);
        // Garble the compressed data of the fourth chunk (scans 16-20).
        let mut bad = bag.clone();
        for b in &mut bad[chunk_starts[3] + 200..chunk_starts[3] + 260] {
            *b ^= 0x5a;
        }
        assert!(read(&bad).is_err());
        let log = read_with(&bad, &salvaging()).unwrap();
        let want: Vec<u32> = (1..=15).chain(21..=100).collect();
        assert_eq!(seqs(&log), want);
        assert_eq!(log.damage.parts_skipped, 1);
        let loss = &log.damage.losses[0];
        assert!(
            (loss.last_stamp_before_s.unwrap() - 1.5).abs() < 1e-9,
            "{loss:?}"
        );
        assert!(
            (loss.first_stamp_after_s.unwrap() - 2.1).abs() < 1e-9,
            "{loss:?}"
        );
        assert!(!log.damage.truncated);
        // A garbled record header: reading goes on at the next record that parses.
        let mut bad = bag.clone();
        for b in &mut bad[chunk_starts[7]..chunk_starts[7] + 40] {
            *b = 0xff;
        }
        let log = read_with(&bad, &salvaging()).unwrap();
        let want: Vec<u32> = (1..=35).chain(41..=100).collect();
        assert_eq!(seqs(&log), want);
    }

    #[test]
    fn a_bag_of_scans_alone_is_read_without_odometry() {
        let log = read(&fixture(20, 10, "lz4", false)).unwrap();
        assert_eq!(log.scans.len(), 20);
        assert!(log.odometry_absent);
        assert!(log.odometry.is_empty());
        assert!(log.scans.iter().all(|s| s.odometry == Pose2::IDENTITY));
        assert_eq!(log.odom_topic, None);
    }

    #[test]
    fn several_scan_topics_must_be_chosen_between() {
        use writer::{BagWriter, laser_scan_message};
        let mut w = BagWriter::new("none", 4);
        let front = w.connection("/front/scan", "sensor_msgs/LaserScan");
        let rear = w.connection("/rear/scan", "sensor_msgs/LaserScan");
        for k in 1..=6u32 {
            let t = Time::from_secs(k as f64);
            let scan = |frame: &str, n: usize| LaserScan {
                frame: frame.into(),
                stamp: t,
                angle_min: 0.0,
                angle_increment: 0.1,
                time_increment: 0.0,
                range_min: 0.0,
                range_max: 5.0,
                ranges: vec![1.0; n],
            };
            w.write(front, t, &laser_scan_message(k, &scan("front", 3)));
            w.write(rear, t, &laser_scan_message(k, &scan("rear", 5)));
        }
        let bag = w.finish();
        let e = read(&bag).unwrap_err();
        assert!(
            e.message.contains("/front/scan")
                && e.message.contains("/rear/scan")
                && e.message.contains("--scan-topic"),
            "{e}"
        );
        let o = ReadOptions {
            scan_topic: Some("/rear/scan".into()),
            ..ReadOptions::default()
        };
        let log = read_with(&bag, &o).unwrap();
        assert_eq!(log.scans.len(), 6);
        assert!(log.scans.iter().all(|s| s.scan.ranges.len() == 5));
        assert_eq!(log.skipped["LaserScan on /front/scan (not chosen)"], 6);
        let o = ReadOptions {
            scan_topic: Some("/scan".into()),
            ..ReadOptions::default()
        };
        let e = read_with(&bag, &o).unwrap_err();
        assert!(
            e.message.contains("no sensor_msgs/LaserScan topic `/scan`"),
            "{e}"
        );
    }
}
