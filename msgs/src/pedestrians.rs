//! Pedestrian trajectories in the text format in which trajectory-prediction work
//! distributes the ETH (Pellegrini et al., ICCV 2009) and UCY (Lerner et al., Eurographics
//! 2007) data sets, as in Social GAN's split (Gupta et al., CVPR 2018): one line per person
//! and frame, `frame person x y`, separated by tabs or spaces, x and y in metres on the
//! ground plane. Some copies add a label column after the person (`frame person label x y`);
//! it is read and ignored. Frames are numbered in steps of a constant (10 in ETH/UCY), the
//! frame period apart (0.4 s there); the period is not in the file, so readers are told it.
//!
//! futago reads these files to measure real crowds and writes its simulated crowds in the
//! same format, so that any tool that reads one reads the other.

use std::fmt::Write as _;

/// One person's position in one frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    pub frame: i64,
    pub person: i64,
    /// Ground-plane position, m.
    pub position: [f64; 2],
}

/// A file's samples, sorted by frame and then person, and the step between frame numbers.
#[derive(Clone, Debug, PartialEq)]
pub struct Trajectories {
    pub samples: Vec<Sample>,
    /// The greatest common divisor of the gaps between successive frame numbers: one frame
    /// period in the file's numbering (1 where only one frame is present).
    pub frame_step: i64,
}

/// An error reading a trajectory file: the line (0 for the whole file) and what was wrong.
pub use crate::tum::ParseError;

/// The largest frame number or person id read, in magnitude: integers beyond it would lose
/// precision as the `f64` some copies write them as (`10.0`).
pub const MAX_INDEX: f64 = 1e12;

/// An integer written as a number (`40` or `40.0`), within ±[`MAX_INDEX`].
fn index(v: f64) -> Option<i64> {
    (v.is_finite() && v.fract() == 0.0 && v.abs() <= MAX_INDEX).then_some(v as i64)
}

/// Parses a trajectory file. Blank lines and `#` comments are skipped; every other line must
/// hold 4 or 5 numbers (`frame person [label] x y`) with integer frame and person, and a
/// person may appear once per frame.
pub fn parse(text: &str) -> Result<Trajectories, ParseError> {
    let mut samples = Vec::new();
    let mut lines = Vec::new();
    for (line_no, line) in crate::tum::data_lines(text) {
        let err = |message: String| ParseError {
            line: line_no,
            message,
        };
        let v = crate::tum::numbers(line_no, line)?;
        if v.len() != 4 && v.len() != 5 {
            return Err(err(format!(
                "expected 4 or 5 numbers (frame person [label] x y), found {}",
                v.len()
            )));
        }
        let frame = index(v[0]).ok_or_else(|| {
            err(format!(
                "frame `{}` is not an integer within ±{MAX_INDEX:e}",
                v[0]
            ))
        })?;
        let person = index(v[1]).ok_or_else(|| {
            err(format!(
                "person `{}` is not an integer within ±{MAX_INDEX:e}",
                v[1]
            ))
        })?;
        let (x, y) = (v[v.len() - 2], v[v.len() - 1]);
        if crate::bounded_coordinate(x).is_none() || crate::bounded_coordinate(y).is_none() {
            return Err(err(format!(
                "position ({x}, {y}) is not finite or is beyond ±{} m of the origin",
                crate::MAX_COORDINATE
            )));
        }
        samples.push(Sample {
            frame,
            person,
            position: [x, y],
        });
        lines.push(line_no);
    }
    if samples.is_empty() {
        return Err(ParseError {
            line: 0,
            message: "no samples: expected lines of `frame person [label] x y`".into(),
        });
    }
    let mut order: Vec<usize> = (0..samples.len()).collect();
    order.sort_by_key(|&k| (samples[k].frame, samples[k].person, lines[k]));
    for w in order.windows(2) {
        let (a, b) = (&samples[w[0]], &samples[w[1]]);
        if a.frame == b.frame && a.person == b.person {
            return Err(ParseError {
                line: lines[w[1]].max(lines[w[0]]),
                message: format!(
                    "person {} appears twice in frame {} (also on line {})",
                    a.person,
                    a.frame,
                    lines[w[1]].min(lines[w[0]])
                ),
            });
        }
    }
    let samples: Vec<Sample> = order.into_iter().map(|k| samples[k]).collect();
    let mut frame_step = 0i64;
    for w in samples.windows(2) {
        // Differences of frames within ±MAX_INDEX cannot overflow.
        let gap = w[1].frame - w[0].frame;
        if gap > 0 {
            frame_step = gcd(frame_step, gap);
        }
    }
    Ok(Trajectories {
        samples,
        frame_step: frame_step.max(1),
    })
}

fn gcd(a: i64, b: i64) -> i64 {
    if b == 0 { a } else { gcd(b, a % b) }
}

/// Writes samples as a trajectory file (`frame person x y`, tab-separated, positions in
/// millimetres' precision), one line each in the order given, after a `#` comment line.
pub fn format(comment: &str, samples: &[Sample]) -> String {
    let mut out = String::new();
    for line in comment.lines() {
        let _ = writeln!(out, "# {line}");
    }
    for s in samples {
        let _ = writeln!(
            out,
            "{}\t{}\t{:.3}\t{:.3}",
            s.frame, s.person, s.position[0], s.position[1]
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_four_and_five_columns_sorted_with_the_frame_step() {
        let t = parse("20.0\t2.0\t4\t1.5\t-2.0\n0\t1\t0.5\t0.25\n# c\n\n10 1 0.75 0.5\n").unwrap();
        assert_eq!(t.frame_step, 10);
        let keys: Vec<(i64, i64)> = t.samples.iter().map(|s| (s.frame, s.person)).collect();
        assert_eq!(keys, vec![(0, 1), (10, 1), (20, 2)]);
        assert_eq!(t.samples[2].position, [1.5, -2.0]);
    }

    #[test]
    fn the_frame_step_is_the_common_divisor_of_the_gaps() {
        let t = parse("0 1 0 0\n30 1 0 0\n50 1 0 0\n").unwrap();
        assert_eq!(t.frame_step, 10);
        assert_eq!(parse("7 1 0 0\n").unwrap().frame_step, 1);
    }

    #[test]
    fn what_is_wrong_is_said_with_its_line() {
        for (text, line, says) in [
            ("0 1 0\n", 1, "expected 4 or 5"),
            ("0 1 0 0\n1.5 1 0 0\n", 2, "frame `1.5`"),
            ("0 x 0 0\n", 1, "`x` is not a number"),
            ("0 1 nan 0\n", 1, "not finite"),
            ("0 1 0 1e300\n", 1, "beyond"),
            ("0 1e15 0 0\n", 1, "person"),
            (
                "0 1 0 0\n\n0 1 2 2\n",
                3,
                "appears twice in frame 0 (also on line 1)",
            ),
            ("# nothing\n", 0, "no samples"),
        ] {
            let e = parse(text).unwrap_err();
            assert_eq!(e.line, line, "{text:?}: {e}");
            assert!(e.to_string().contains(says), "{text:?}: {e}");
        }
    }

    #[test]
    fn what_is_written_reads_back() {
        let s = vec![
            Sample {
                frame: 0,
                person: 3,
                position: [1.25, -0.5],
            },
            Sample {
                frame: 10,
                person: 3,
                position: [1.5, -0.75],
            },
        ];
        let text = format("simulated\ncrowd", &s);
        assert!(text.starts_with("# simulated\n# crowd\n"));
        let t = parse(&text).unwrap();
        assert_eq!(t.samples, s);
        assert_eq!(t.frame_step, 10);
    }
}
