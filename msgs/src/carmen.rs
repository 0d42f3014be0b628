//! CARMEN log lines, the text format of the classic 2D SLAM data sets (Intel, MIT CSAIL,
//! Freiburg) and of their relations files.
//!
//! The writer emits `PARAM`, `ODOM`, `ROBOTLASER1`/`ROBOTLASER2` and `TRUEPOS` messages in the
//! field order of CARMEN's logger. Every line ends with `timestamp hostname logger_timestamp`;
//! futago writes the simulation time for both timestamps and `futago` as the host name.

use crate::{LaserScan, Pose2, Time};
use std::fmt::Write as _;

const HOST: &str = "futago";

/// `PARAM name value`.
pub fn param(out: &mut String, name: &str, value: &str) {
    let _ = writeln!(out, "PARAM {name} {value} 0.000000 {HOST} 0.000000");
}

/// `ODOM x y theta tv rv accel timestamp host logger_timestamp`.
pub fn odom(out: &mut String, t: f64, odom: &Pose2, tv: f64, rv: f64) {
    let _ = writeln!(
        out,
        "ODOM {:.6} {:.6} {:.6} {:.6} {:.6} 0.000000 {t:.6} {HOST} {t:.6}",
        odom.x, odom.y, odom.theta, tv, rv
    );
}

/// `TRUEPOS true_x true_y true_theta odom_x odom_y odom_theta timestamp host logger_timestamp`:
/// the simulator's ground truth beside odometry, as CARMEN's own simulator logs it.
pub fn truepos(out: &mut String, t: f64, truth: &Pose2, odom: &Pose2) {
    let _ = writeln!(
        out,
        "TRUEPOS {:.6} {:.6} {:.6} {:.6} {:.6} {:.6} {t:.6} {HOST} {t:.6}",
        truth.x, truth.y, truth.theta, odom.x, odom.y, odom.theta
    );
}

/// `ROBOTLASERn laser_type start_angle fov angular_resolution max_range accuracy
/// remission_mode num_readings ranges… num_remissions laser_pose(x y θ) robot_pose(x y θ)
/// tv rv forward_safety_dist side_safety_dist turn_axis timestamp host logger_timestamp`.
///
/// `channel` is 1 or 2. `robot_pose` is the odometry pose at the scan and `laser_pose` is that
/// pose composed with the laser's mounting. No-return beams (`+∞`) are written as the maximum
/// range, as real CARMEN logs do; returns closer than the minimum range are written as 0.
#[allow(clippy::too_many_arguments)]
pub fn robotlaser(
    out: &mut String,
    channel: u8,
    scan: &LaserScan,
    accuracy: f64,
    laser_pose: &Pose2,
    robot_pose: &Pose2,
    tv: f64,
    rv: f64,
) {
    let t = scan.stamp.secs();
    let fov = scan.angle_increment * (scan.ranges.len().saturating_sub(1)) as f64;
    let _ = write!(
        out,
        "ROBOTLASER{channel} 0 {:.6} {:.6} {:.6} {:.3} {:.3} 0 {}",
        scan.angle_min,
        fov,
        scan.angle_increment,
        scan.range_max,
        accuracy,
        scan.ranges.len()
    );
    for &r in &scan.ranges {
        let r = if r == f32::INFINITY {
            scan.range_max as f32
        } else if r == f32::NEG_INFINITY || r.is_nan() {
            0.0
        } else {
            r
        };
        out.push(' ');
        push_millis(out, r);
    }
    let _ = writeln!(
        out,
        " 0 {:.6} {:.6} {:.6} {:.6} {:.6} {:.6} {tv:.6} {rv:.6} 0.000000 0.000000 0.000000 {t:.6} {HOST} {t:.6}",
        laser_pose.x, laser_pose.y, laser_pose.theta, robot_pose.x, robot_pose.y, robot_pose.theta
    );
}

/// `r` with three decimals, as `{r:.3}` writes it, without the general float formatter for
/// the ranges a laser gives (most of a log's bytes, and most of the time spent writing it):
/// an `f32` times 1000 is exact in an `f64` (24 + 10 bits), so below 2^31 m the rounding to
/// whole millimetres is decided exactly here; a tie (exactly half a millimetre), a negative
/// value or anything larger goes to the formatter, whose rounding of ties this leaves alone.
fn push_millis(out: &mut String, r: f32) {
    let x = r as f64 * 1000.0;
    if r.is_sign_positive() && x < 2_147_483_648.0 {
        let whole = x.floor();
        let frac = x - whole;
        if frac != 0.5 {
            let n = whole as u64 + u64::from(frac > 0.5);
            // The digits by hand, not by the formatter's machinery for two integers (issue
            // 48: hall-scan3d-random's recorder 3.5 -> 2.1 s alone).
            let mut digits = [0u8; 24];
            let mut k = digits.len();
            let mut rest = n;
            for place in 0.. {
                if place == 3 {
                    k -= 1;
                    digits[k] = b'.';
                }
                k -= 1;
                digits[k] = b'0' + (rest % 10) as u8;
                rest /= 10;
                if rest == 0 && place >= 3 {
                    break;
                }
            }
            out.push_str(std::str::from_utf8(&digits[k..]).unwrap_or_default());
            return;
        }
    }
    let _ = write!(out, "{r:.3}");
}

/// One laser scan of a log with the robot's odometry pose at that time.
#[derive(Debug, Clone, PartialEq)]
pub struct LogScan {
    /// The scan, stamped when it was taken (which [`crate::rosbag`] may have corrected).
    pub scan: LaserScan,
    /// The stamp the log gave the scan: the name by which benchmarks' relations refer to it.
    pub logged: Time,
    /// Odometry pose of the robot base when the scan was taken.
    pub odometry: Pose2,
    /// Pose of the laser on the robot base (ROBOTLASER gives it; FLASER means the origin).
    pub mount: Pose2,
}

/// What a CARMEN log holds, in file order, with what was skipped.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Log {
    pub scans: Vec<LogScan>,
    /// `ODOM` records: time and odometry pose.
    pub odometry: Vec<(Time, Pose2)>,
    /// Records not used, by reason (`unknown type PARAM`, `time went backwards`, …) and count.
    pub skipped: std::collections::BTreeMap<String, usize>,
    /// Annotated people (a bag's `leg_tracker/Person` messages), in file order.
    pub people: Vec<PersonMark>,
    /// Messages read, by topic (a bag's) or record type (a CARMEN log's).
    pub messages: std::collections::BTreeMap<String, usize>,
    /// What a damaged log lost, read with [`ReadOptions::strict`] off (nothing for an intact
    /// log).
    pub damage: Damage,
    /// The log has scans but no odometry (a bag of laser scans alone): each scan's
    /// `odometry` is the identity and the robot's motion must come from the scans.
    pub odometry_absent: bool,
    /// The topics read, where the log is a bag: the laser scans' and the odometry's.
    pub scan_topic: Option<String>,
    pub odom_topic: Option<String>,
}

/// How a log is read.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ReadOptions {
    /// Refuse a damaged log (a cut end, a chunk or line that does not parse) instead of
    /// reading what it holds and saying what was lost in [`Log::damage`].
    pub strict: bool,
    /// The `sensor_msgs/LaserScan` topic to read, where a bag has several.
    pub scan_topic: Option<String>,
    /// The `nav_msgs/Odometry` topic to read, where a bag has several.
    pub odom_topic: Option<String>,
}

/// What a damaged log lost: the parts skipped and the bytes they held.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct Damage {
    /// Bytes of the file that were not read: a cut end, skipped chunks and records.
    pub bytes_lost: u64,
    /// The file ends inside a record (cut short).
    pub truncated: bool,
    /// Parts skipped: a bag's chunks and records, a CARMEN log's lines.
    pub parts_skipped: usize,
    /// Messages read from the cut end of a truncated chunk.
    pub messages_salvaged_from_cut_chunk: usize,
    /// The first [`MAX_LOSSES`] losses, in file order.
    pub losses: Vec<Loss>,
}

/// Losses kept in [`Damage::losses`]; further ones are counted only.
pub const MAX_LOSSES: usize = 100;

/// One part of a log that could not be read.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Loss {
    /// Where: a bag's byte offset, a CARMEN log's 1-based line.
    pub at: u64,
    /// What was wrong.
    pub what: String,
    /// Bytes lost.
    pub bytes: u64,
    /// The last stamp read before the loss and the first after it, s: the gap in the data.
    pub last_stamp_before_s: Option<f64>,
    pub first_stamp_after_s: Option<f64>,
}

impl Damage {
    /// Whether anything was lost.
    pub fn is_empty(&self) -> bool {
        self.parts_skipped == 0 && !self.truncated && self.bytes_lost == 0
    }

    /// Records a loss at `at` of `bytes`, after the stamp `before`.
    pub fn lose(&mut self, at: u64, what: String, bytes: u64, before: Option<Time>) {
        self.parts_skipped += 1;
        self.bytes_lost += bytes;
        if self.losses.len() < MAX_LOSSES {
            self.losses.push(Loss {
                at,
                what,
                bytes,
                last_stamp_before_s: before.map(Time::secs),
                first_stamp_after_s: None,
            });
        }
    }

    /// Closes the gaps still open with the first stamp read after them.
    pub fn stamp_read(&mut self, t: Time) {
        for l in self.losses.iter_mut().rev() {
            if l.first_stamp_after_s.is_some() {
                break;
            }
            l.first_stamp_after_s = Some(t.secs());
        }
    }
}

/// One annotated person: after which scan it came (an index into [`Log::scans`]), its id
/// and its position in that scan's laser frame, m (the leg_tracker benchmark's convention:
/// each annotation follows the scan it marks).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PersonMark {
    pub scan: usize,
    pub id: u32,
    pub position: [f64; 2],
}

/// An error reading a log: the 1-based line and what was wrong (the same as a TUM file's).
pub use crate::tum::ParseError as ReadError;

/// Readings at or beyond this are "no return" in FLASER records (the SICK's 81.91 m code).
pub const FLASER_NO_RETURN: f32 = 81.9;

/// Fields of one record, parsed on demand with errors that name the field.
struct Fields<'a> {
    words: Vec<&'a str>,
    at: usize,
    line: usize,
}

impl<'a> Fields<'a> {
    fn err(&self, message: String) -> ReadError {
        ReadError {
            line: self.line,
            message,
        }
    }

    fn word(&mut self, what: &str) -> Result<&'a str, ReadError> {
        let w = self.words.get(self.at).copied().ok_or_else(|| {
            self.err(format!(
                "{} record ends before its {what} (field {})",
                self.words[0], self.at
            ))
        })?;
        self.at += 1;
        Ok(w)
    }

    fn num(&mut self, what: &str) -> Result<f64, ReadError> {
        let w = self.word(what)?;
        w.parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| self.err(format!("{what} `{w}` is not a finite number")))
    }

    fn count(&mut self, what: &str) -> Result<usize, ReadError> {
        let w = self.word(what)?;
        w.parse::<usize>()
            .ok()
            .filter(|&n| n <= 100_000)
            .ok_or_else(|| self.err(format!("{what} `{w}` is not a count (0 to 100000)")))
    }

    fn coordinate(&mut self, what: &str) -> Result<f64, ReadError> {
        let v = self.num(what)?;
        crate::bounded_coordinate(v).ok_or_else(|| {
            self.err(format!(
                "{what} {v:e} is beyond ±{} m of the origin",
                crate::MAX_COORDINATE
            ))
        })
    }

    fn stamp(&mut self) -> Result<f64, ReadError> {
        let v = self.num("ipc_timestamp")?;
        crate::bounded_stamp(v).ok_or_else(|| {
            self.err(format!(
                "ipc_timestamp {v:e} is beyond ±{} s",
                crate::MAX_STAMP
            ))
        })
    }

    fn pose(&mut self, what: &str) -> Result<Pose2, ReadError> {
        Ok(Pose2::new(
            self.coordinate(&format!("{what} x"))?,
            self.coordinate(&format!("{what} y"))?,
            self.num(&format!("{what} theta"))?,
        ))
    }

    fn ranges(&mut self, n: usize, no_return: f32) -> Result<Vec<f32>, ReadError> {
        (0..n)
            .map(|_| {
                let r = self.num("range reading")? as f32;
                Ok(if r >= no_return || r < 0.0 {
                    f32::INFINITY
                } else {
                    r
                })
            })
            .collect()
    }
}

enum Record {
    Scan(f64, LogScan),
    Odom(f64, Pose2),
}

/// Reads a CARMEN log: `FLASER` (180° scans with odometry), `ROBOTLASER1`/`ROBOTLASER2` (scans
/// with their geometry, laser mount and odometry) and `ODOM`. Stamps are the `ipc_timestamp`
/// field, which relation files refer to.
///
/// Comments and other record types (`PARAM`, `SYNC`, `TRUEPOS`, …) are skipped and counted;
/// so are records whose time goes backwards against the previous record of their type, and a
/// last line cut short (a truncated file). A malformed record anywhere else is an error that
/// names its line.
pub fn read(text: &str) -> Result<Log, ReadError> {
    read_with(
        text,
        &ReadOptions {
            strict: true,
            ..Default::default()
        },
    )
}

/// The fields of a FLASER record after its name: a 180° scan and the odometry pose.
fn flaser(f: &mut Fields) -> Result<Record, ReadError> {
    let n = f.count("number of readings")?;
    let ranges = f.ranges(n, FLASER_NO_RETURN)?;
    let _corrected = f.pose("pose")?;
    let odometry = f.pose("odometry pose")?;
    let t = f.stamp()?;
    let inc = if n > 1 {
        std::f64::consts::PI / (n - 1) as f64
    } else {
        0.0
    };
    Ok(Record::Scan(
        t,
        LogScan {
            scan: LaserScan {
                frame: "front".into(),
                stamp: Time::from_secs(t),
                angle_min: -std::f64::consts::FRAC_PI_2,
                angle_increment: inc,
                time_increment: 0.0,
                range_min: 0.0,
                range_max: FLASER_NO_RETURN as f64,
                ranges,
            },
            logged: Time::from_secs(t),
            odometry,
            mount: Pose2::IDENTITY,
        },
    ))
}

/// The fields of a ROBOTLASER1 or ROBOTLASER2 record (`kind`) after its name: a scan with its
/// geometry, the laser's and the robot's poses.
fn robot_laser(f: &mut Fields, kind: &str) -> Result<Record, ReadError> {
    let _laser_type = f.num("laser type")?;
    let start = f.num("start angle")?;
    let _fov = f.num("field of view")?;
    let inc = f.num("angular resolution")?;
    let max = f.num("maximum range")?;
    let _accuracy = f.num("accuracy")?;
    let _remission_mode = f.num("remission mode")?;
    let n = f.count("number of readings")?;
    let ranges = f.ranges(n, max as f32)?;
    let m = f.count("number of remissions")?;
    for _ in 0..m {
        f.num("remission")?;
    }
    let laser = f.pose("laser pose")?;
    let robot = f.pose("robot pose")?;
    for what in [
        "tv",
        "rv",
        "forward safety distance",
        "side safety distance",
        "turn axis",
    ] {
        f.num(what)?;
    }
    let t = f.stamp()?;
    Ok(Record::Scan(
        t,
        LogScan {
            scan: LaserScan {
                frame: if kind == "ROBOTLASER1" {
                    "front"
                } else {
                    "rear"
                }
                .into(),
                stamp: Time::from_secs(t),
                angle_min: start,
                angle_increment: inc,
                time_increment: 0.0,
                range_min: 0.0,
                range_max: max,
                ranges,
            },
            logged: Time::from_secs(t),
            odometry: robot,
            mount: robot.between(&laser),
        },
    ))
}

/// [`read`], or with `strict` off, a malformed record skipped and recorded in
/// [`Log::damage`] (its line, what was wrong, the stamps read around it) instead of an error.
pub fn read_with(text: &str, o: &ReadOptions) -> Result<Log, ReadError> {
    let mut log = Log::default();
    let mut last_stamp: Option<Time> = None;
    let lines: Vec<&str> = text.lines().collect();
    let truncated_last = !text.ends_with('\n');
    let mut last_scan: std::collections::HashMap<String, f64> = Default::default();
    let mut last_odom = f64::NEG_INFINITY;
    let skip = |log: &mut Log, why: String| *log.skipped.entry(why).or_insert(0) += 1;
    for (i, line) in lines.iter().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let mut f = Fields {
            words: line.split_whitespace().collect(),
            at: 1,
            line: i + 1,
        };
        let kind = f.words[0];
        let parsed: Result<Record, ReadError> = match kind {
            "FLASER" => flaser(&mut f),
            "ROBOTLASER1" | "ROBOTLASER2" => robot_laser(&mut f, kind),
            "ODOM" => (|| {
                let pose = f.pose("odometry pose")?;
                for what in ["tv", "rv", "accel"] {
                    f.num(what)?;
                }
                Ok(Record::Odom(f.stamp()?, pose))
            })(),
            other => {
                skip(&mut log, format!("unknown record type {other}"));
                continue;
            }
        };
        if parsed.is_ok() {
            *log.messages.entry(kind.to_string()).or_insert(0) += 1;
        }
        match parsed {
            Ok(Record::Scan(t, scan)) => {
                last_stamp = Some(Time::from_secs(t));
                log.damage.stamp_read(Time::from_secs(t));
                let prev = last_scan
                    .entry(scan.scan.frame.clone())
                    .or_insert(f64::NEG_INFINITY);
                if t < *prev {
                    skip(&mut log, format!("{kind}: time went backwards"));
                } else {
                    *prev = t;
                    log.scans.push(scan);
                }
            }
            Ok(Record::Odom(t, pose)) => {
                last_stamp = Some(Time::from_secs(t));
                log.damage.stamp_read(Time::from_secs(t));
                if t < last_odom {
                    skip(&mut log, "ODOM: time went backwards".into());
                } else {
                    last_odom = t;
                    log.odometry.push((Time::from_secs(t), pose));
                }
            }
            Err(e) if truncated_last && i + 1 == lines.len() => {
                skip(&mut log, "last line cut short (truncated file)".into());
                if !o.strict {
                    log.damage.truncated = true;
                    log.damage
                        .lose((i + 1) as u64, e.to_string(), line.len() as u64, last_stamp);
                }
            }
            Err(e) if o.strict => return Err(e),
            Err(e) => {
                log.damage.lose(
                    (i + 1) as u64,
                    e.to_string(),
                    line.len() as u64 + 1,
                    last_stamp,
                );
            }
        }
    }
    Ok(log)
}

#[cfg(test)]
mod tests {
    /// Ranges are written as `{:.3}` writes them: every f32 in the laser's range on a grid of
    /// steps that are not round, the exact halves of a millimetre, the ends and the odd ones.
    #[test]
    fn ranges_are_written_as_the_formatter_writes_them() {
        let mut values: Vec<f32> = (0..2_000_000).map(|k| k as f32 * 0.000_030_517_6).collect();
        values.extend((0..200_000).map(|k| (k as f32 + 0.5) / 1000.0));
        values.extend((0..100_000).map(|k| k as f32 * 0.0625));
        values.extend([
            0.0,
            -0.0,
            0.0005,
            0.0015,
            0.9995,
            29.9995,
            -1.25,
            1e9,
            3e9,
            f32::MAX,
        ]);
        values.extend([f32::MIN_POSITIVE, f32::EPSILON, 5.6, 30.0, 4.095, 0.0195]);
        for r in values {
            let mut fast = String::new();
            push_millis(&mut fast, r);
            assert_eq!(fast, format!("{r:.3}"), "{r:e}");
        }
    }

    use super::*;

    #[test]
    fn logs_read_back_what_the_writers_wrote_and_count_what_they_skip() {
        let scan = LaserScan {
            frame: "front".into(),
            stamp: Time::from_secs(2.0),
            angle_min: -1.0,
            angle_increment: 0.5,
            time_increment: 0.0,
            range_min: 0.0,
            range_max: 5.0,
            ranges: vec![1.0, f32::INFINITY, 2.5, 3.0, 4.0],
        };
        let robot = Pose2::new(1.0, 2.0, 0.5);
        let laser = robot.compose(&Pose2::new(0.1, 0.0, 0.0));
        let mut s = String::from("# a comment\n");
        param(&mut s, "robot_name", "create");
        odom(&mut s, 1.0, &robot, 0.2, 0.0);
        robotlaser(&mut s, 1, &scan, 0.01, &laser, &robot, 0.2, 0.0);
        odom(&mut s, 0.5, &robot, 0.2, 0.0);
        s.push_str("FLASER 3 1.0 81.91 2.0 0 0 0 0.5 0.25 0.1 3.0 host 3.0\n");
        let log = read(&s).unwrap();
        assert_eq!(log.odometry.len(), 1);
        assert_eq!(log.scans.len(), 2);
        let r = &log.scans[0];
        assert_eq!(r.scan.ranges[1], f32::INFINITY);
        assert_eq!(r.scan.ranges[2], 2.5);
        assert!((r.mount.x - 0.1).abs() < 1e-6 && r.mount.y.abs() < 1e-6);
        assert_eq!(r.scan.stamp, Time::from_secs(2.0));
        let f = &log.scans[1];
        assert_eq!(f.scan.ranges, vec![1.0, f32::INFINITY, 2.0]);
        assert!((f.scan.angle_increment - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert_eq!(f.odometry, Pose2::new(0.5, 0.25, 0.1));
        assert_eq!(log.skipped["unknown record type PARAM"], 1);
        assert_eq!(log.skipped["ODOM: time went backwards"], 1);
    }

    #[test]
    fn corrupt_records_name_their_line_and_a_cut_last_line_is_skipped() {
        let e = read("ODOM 1 2 3 0 0 0 1.0 h 1.0\nFLASER 3 1.0 x 2.0 0 0 0 0 0 0 2.0 h 2.0\nODOM 1 2 3 0 0 0 3.0 h 3.0\n")
            .unwrap_err();
        assert_eq!(e.line, 2);
        assert!(e.message.contains("range reading `x`"), "{e}");
        let e = read("FLASER 5 1.0 2.0\nODOM 1 2 3 0 0 0 3.0 h 3.0\n").unwrap_err();
        assert!(e.message.contains("ends before"), "{e}");
        let log = read("ODOM 1 2 3 0 0 0 1.0 h 1.0\nFLASER 361 1.0 1.0").unwrap();
        assert_eq!(log.odometry.len(), 1);
        assert_eq!(log.skipped["last line cut short (truncated file)"], 1);
    }

    #[test]
    fn robotlaser_line_has_the_logger_field_layout() {
        let scan = LaserScan {
            frame: "front".into(),
            stamp: Time::from_secs(1.5),
            angle_min: -1.0,
            angle_increment: 0.5,
            time_increment: 0.0,
            range_min: 0.1,
            range_max: 5.0,
            ranges: vec![1.0, f32::INFINITY, f32::NEG_INFINITY, 2.5, 3.0],
        };
        let mut s = String::new();
        let p = Pose2::new(1.0, 2.0, 0.5);
        robotlaser(&mut s, 1, &scan, 0.01, &p, &p, 0.2, 0.0);
        let w: Vec<&str> = s.split_whitespace().collect();
        assert_eq!(w[0], "ROBOTLASER1");
        assert_eq!(w[8], "5");
        assert_eq!(&w[9..14], ["1.000", "5.000", "0.000", "2.500", "3.000"]);
        assert_eq!(w[14], "0"); // no remissions
        // 6 pose values, tv rv, 3 safety fields, then timestamp host logger_timestamp.
        assert_eq!(w.len(), 15 + 6 + 2 + 3 + 3);
        assert_eq!(w[w.len() - 2], "futago");
        assert_eq!(w[w.len() - 1], "1.500000");
        // The field of view spans first to last beam.
        assert_eq!(w[3], "2.000000");
    }

    #[test]
    fn a_bad_line_is_skipped_and_recorded_when_salvaging() {
        let text = "ODOM 0 0 0 0 0 0 1.0 h 1.0\n\
                    FLASER 3 1.0 1.0 1.0 0 0 0 0 0 0 2.0 h 2.0\n\
                    FLASER 3 1.0 oops 2.0 0 0 0 0 0 0 3.0 h 3.0\n\
                    FLASER 3 1.0 1.0 1.0 0 0 0 0 0 0 4.0 h 4.0\n\
                    ODOM 0 0 0 0 0 0 5.0 h 5.0\n";
        let e = read(text).unwrap_err();
        assert_eq!(e.line, 3);
        let log = read_with(text, &ReadOptions::default()).unwrap();
        assert_eq!(log.scans.len(), 2);
        assert_eq!(log.messages["FLASER"], 2);
        assert_eq!(log.damage.parts_skipped, 1);
        let l = &log.damage.losses[0];
        assert_eq!(l.at, 3);
        assert!(l.what.contains("oops"), "{l:?}");
        assert_eq!(l.last_stamp_before_s, Some(2.0));
        assert_eq!(l.first_stamp_after_s, Some(4.0));
        // A last line cut short is a cut file.
        let cut = &text[..text.len() - 16];
        let log = read_with(cut, &ReadOptions::default()).unwrap();
        assert!(log.damage.truncated);
    }
}
