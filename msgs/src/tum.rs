//! TUM trajectory format: one pose per line, `timestamp tx ty tz qx qy qz qw`, `#` comments.
//!
//! This is the format of the TUM RGB-D benchmark's `groundtruth.txt`, read by `evo` and most
//! SLAM evaluation tools.

use crate::{Pose3, Time};
use std::fmt::Write as _;

/// One trajectory sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stamped {
    pub stamp: Time,
    pub pose: Pose3,
}

/// Formats one TUM line (with trailing newline): time with 6 decimals (µs), translation
/// with 6 (µm), quaternion with 9.
pub fn format_line(out: &mut String, s: &Stamped) {
    let t = s.pose.translation;
    let q = s.pose.rotation;
    // The sign of a quaternion is arbitrary; keep w ≥ 0 so that equal poses print equally.
    let sign = if q[3] < 0.0 { -1.0 } else { 1.0 };
    let _ = writeln!(
        out,
        "{:.6} {:.6} {:.6} {:.6} {:.9} {:.9} {:.9} {:.9}",
        s.stamp.secs(),
        t[0],
        t[1],
        t[2],
        sign * q[0],
        sign * q[1],
        sign * q[2],
        sign * q[3]
    );
}

/// `s` as a TUM file holds it: each value rounded to the decimals [`format_line`] writes and
/// read back as [`parse`] reads it, the same `f64`s bit for bit. A trajectory kept in memory
/// this way scores as its file does under any tool that reads the file (evo).
pub fn as_written(s: &Stamped) -> Stamped {
    let mut text = String::new();
    let mut round = |x: f64, decimals: usize| {
        text.clear();
        let _ = write!(text, "{x:.decimals$}");
        text.parse::<f64>().unwrap_or(x)
    };
    let t = s.pose.translation;
    let q = s.pose.rotation;
    let sign = if q[3] < 0.0 { -1.0 } else { 1.0 };
    Stamped {
        stamp: Time::from_secs(round(s.stamp.secs(), 6)),
        pose: Pose3 {
            translation: [round(t[0], 6), round(t[1], 6), round(t[2], 6)],
            rotation: [
                round(sign * q[0], 9),
                round(sign * q[1], 9),
                round(sign * q[2], 9),
                round(sign * q[3], 9),
            ],
        },
    }
}

/// An error reading a text file of numbers (TUM, CARMEN, pedestrian trajectories): the line
/// number (1-based; 0 for the file as a whole) and what was wrong.
#[derive(Debug, Clone, PartialEq)]
pub struct ParseError {
    pub line: usize,
    pub message: String,
}

impl std::fmt::Display for ParseError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.line == 0 {
            write!(f, "{}", self.message)
        } else {
            write!(f, "line {}: {}", self.line, self.message)
        }
    }
}

impl std::error::Error for ParseError {}

/// The lines of a text file that hold data (1-based number, trimmed text): blank lines and
/// `#` comments are skipped.
pub(crate) fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
}

/// The whitespace-separated numbers of line `line_no`, or which word is not one.
pub(crate) fn numbers(line_no: usize, line: &str) -> Result<Vec<f64>, ParseError> {
    line.split_whitespace()
        .map(|w| {
            w.parse::<f64>().map_err(|_| ParseError {
                line: line_no,
                message: format!("`{w}` is not a number"),
            })
        })
        .collect()
}

/// Parses a TUM trajectory. Blank lines and `#` comments are skipped; anything else must be
/// eight finite numbers with a unit-norm (±1e-3) quaternion.
pub fn parse(text: &str) -> Result<Vec<Stamped>, ParseError> {
    let mut out = Vec::new();
    for (line_no, line) in data_lines(text) {
        let err = |message: String| ParseError {
            line: line_no,
            message,
        };
        let v = numbers(line_no, line)?;
        if v.len() != 8 {
            return Err(err(format!(
                "expected 8 numbers (t tx ty tz qx qy qz qw), found {}",
                v.len()
            )));
        }
        if v.iter().any(|x| !x.is_finite()) {
            return Err(err("non-finite value".into()));
        }
        if crate::bounded_stamp(v[0]).is_none() {
            return Err(err(format!(
                "timestamp {} is beyond ±{} s",
                v[0],
                crate::MAX_STAMP
            )));
        }
        if v[1..4]
            .iter()
            .any(|&x| crate::bounded_coordinate(x).is_none())
        {
            return Err(err(format!(
                "position ({}, {}, {}) is beyond ±{} m of the origin",
                v[1],
                v[2],
                v[3],
                crate::MAX_COORDINATE
            )));
        }
        let n = (v[4] * v[4] + v[5] * v[5] + v[6] * v[6] + v[7] * v[7]).sqrt();
        if (n - 1.0).abs() > 1e-3 {
            return Err(err(format!("quaternion norm is {n:.6}, expected 1")));
        }
        out.push(Stamped {
            stamp: Time::from_secs(v[0]),
            pose: Pose3 {
                translation: [v[1], v[2], v[3]],
                rotation: [v[4], v[5], v[6], v[7]],
            },
        });
    }
    Ok(out)
}

/// Parses a TUM RGB-D image list (`rgb.txt`, `depth.txt`): `timestamp filename` per line,
/// `#` comments. Filenames are relative to the sequence folder.
pub fn parse_image_list(text: &str) -> Result<Vec<(Time, String)>, ParseError> {
    let mut out = Vec::new();
    for (line_no, line) in data_lines(text) {
        let err = |message: String| ParseError {
            line: line_no,
            message,
        };
        let mut words = line.split_whitespace();
        let (Some(t), Some(name), None) = (words.next(), words.next(), words.next()) else {
            return Err(err("expected `timestamp filename`".into()));
        };
        let t: f64 = t
            .parse()
            .ok()
            .filter(|t: &f64| t.is_finite())
            .ok_or_else(|| err(format!("`{t}` is not a timestamp")))?;
        out.push((Time::from_secs(t), name.to_string()));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Pose2;

    /// What `as_written` keeps is what the file gives back, bit for bit, for poses that
    /// round up and down, negative ones and quaternions with w < 0.
    #[test]
    fn as_written_is_the_file_read_back() {
        let mut x = 0.123_456_789_f64;
        for i in 0..500 {
            x = (x * 7.3 + 0.618_033_988_7).fract();
            let theta = (x - 0.5) * 7.0;
            let s = Stamped {
                stamp: Time(i * 15_000_000 + (x * 1e6) as i64),
                pose: Pose3 {
                    translation: [x * 40.0 - 20.0, 13.0 * x - 3.0, x * 1e-6],
                    rotation: [0.0, 0.0, (theta / 2.0).sin(), (theta / 2.0).cos()],
                },
            };
            let mut line = String::new();
            format_line(&mut line, &s);
            let read = parse(&line).unwrap()[0];
            let kept = as_written(&s);
            assert_eq!(kept.stamp, read.stamp, "{line}");
            for k in 0..3 {
                assert_eq!(
                    kept.pose.translation[k].to_bits(),
                    read.pose.translation[k].to_bits()
                );
            }
            for k in 0..4 {
                assert_eq!(
                    kept.pose.rotation[k].to_bits(),
                    read.pose.rotation[k].to_bits()
                );
            }
        }
    }

    #[test]
    fn round_trip_keeps_pose_to_format_precision() {
        let p = Pose2::new(1.25, -3.5, 2.0);
        let s = Stamped {
            stamp: Time::from_secs(12.5),
            pose: Pose3::from_pose2(&p, 0.0),
        };
        let mut text = String::from("# t x y z qx qy qz qw\n");
        format_line(&mut text, &s);
        let back = parse(&text).unwrap();
        assert_eq!(back.len(), 1);
        assert_eq!(back[0].stamp, Time::from_secs(12.5));
        let q = back[0].pose.rotation;
        let yaw = 2.0 * q[2].atan2(q[3]);
        assert!((yaw - 2.0).abs() < 1e-8);
        assert!((back[0].pose.translation[0] - 1.25).abs() < 1e-9);
    }

    #[test]
    fn image_lists_parse_and_reject_junk() {
        let l = parse_image_list("# color images\n1.500000 rgb/1.500000.png\n\n2.0 rgb/2.png\n")
            .unwrap();
        assert_eq!(l.len(), 2);
        assert_eq!(l[0], (Time::from_secs(1.5), "rgb/1.500000.png".to_string()));
        let e = parse_image_list("1.0 a.png\nx b.png\n").unwrap_err();
        assert_eq!(e.line, 2);
        assert!(parse_image_list("1.0 a.png extra\n").is_err());
    }

    #[test]
    fn rejects_short_lines_and_bad_quaternions() {
        assert_eq!(parse("1 2 3\n").unwrap_err().line, 1);
        let e = parse("# c\n0 0 0 0 0 0 0 2\n").unwrap_err();
        assert_eq!(e.line, 2);
        assert!(e.message.contains("norm"));
    }
}
