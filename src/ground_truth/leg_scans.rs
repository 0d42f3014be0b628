//! What a planar laser sees of people, measured the same way on real annotated scans and on
//! simulated ones, so that the twin's people can be held to real ones (issue 45, part 1).
//!
//! For each person of a scan (a real log's annotation, or a simulated person the scan sees),
//! the scan's segments ([`futago_robot::perception::legs::segments`], the leg detector's own)
//! whose centroid lies within [`NEAR`] of the person's centre are theirs. By range from the
//! laser, in bins of 2 m, it counts how many segments a person makes (none, one: legs merged
//! or one hidden; two: each leg its own; three or more: a leg cut by a gap), and the widths
//! (first to last point) and point counts of their segments. The same is counted again by how
//! the person moves, over every range: standing (slower than the crowd statistics' 0.2 m/s),
//! walking along the line of sight (within 45° of towards or away from the laser, where one
//! leg hides behind the other), or across it. These are what the leg classifier learns from;
//! a twin whose people give a different mix teaches it the wrong legs.

use super::trajectory::Stats;
use futago_robot::perception::legs::Segment;
use serde_json::{Value, json};

/// A segment whose centroid lies this close to a person's centre is theirs, m: half the
/// longest step (0.8 m), as far as a foot reaches from the centre.
pub const NEAR: f64 = 0.4;

/// The range bins' upper edges, m (the first starts at 0).
const BINS: [f64; 5] = [2.0, 4.0, 6.0, 8.0, 10.0];

/// The ways a person moves relative to the laser, in the summary's `by_motion` order.
pub const MOTIONS: [&str; 3] = ["standing", "along", "across"];

/// A person as one scan shows them: their centre in the laser's frame (m), and, where known,
/// their velocity over the ground in the laser's axes (m/s).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Seen {
    pub centre: [f64; 2],
    pub velocity: Option<[f64; 2]>,
}

/// Which of [`MOTIONS`] a person is in (see the module documentation).
fn motion(p: &Seen) -> Option<usize> {
    let v = p.velocity?;
    let speed = v[0].hypot(v[1]);
    if speed < super::crowd::CrowdOptions::default().standing_speed {
        return Some(0);
    }
    let range = p.centre[0].hypot(p.centre[1]);
    let along = (v[0] * p.centre[0] + v[1] * p.centre[1]).abs() / (speed * range.max(1e-9));
    Some(if along >= std::f64::consts::FRAC_1_SQRT_2 {
        1
    } else {
        2
    })
}

#[derive(Debug, Clone, Default)]
struct Bin {
    /// People by segments made: none, one, two, three or more.
    by_segments: [u64; 4],
    widths: Vec<f64>,
    points: Vec<f64>,
}

/// The people's segments, accumulated over scans by range bin (see the module documentation).
#[derive(Debug, Clone, Default)]
pub struct LegScans {
    bins: [Bin; BINS.len()],
    /// The same people by [`MOTIONS`], over every range (those with a velocity).
    motions: [Bin; MOTIONS.len()],
}

impl LegScans {
    /// Adds one scan: its segments (in the laser's frame) and its people. People beyond the
    /// last range bin are left out.
    pub fn add(&mut self, segments: &[Segment], people: &[Seen]) {
        let centroids: Vec<[f64; 2]> = segments.iter().map(Segment::centroid).collect();
        for p in people {
            let c = p.centre;
            let range = c[0].hypot(c[1]);
            let Some(b) = BINS.iter().position(|&hi| range < hi) else {
                continue;
            };
            let mut made = 0usize;
            let mut widths = Vec::new();
            let mut points = Vec::new();
            for (s, q) in segments.iter().zip(&centroids) {
                if (q[0] - c[0]).hypot(q[1] - c[1]) <= NEAR {
                    made += 1;
                    let (a, z) = (s.points[0], s.points[s.points.len() - 1]);
                    widths.push((a[0] - z[0]).hypot(a[1] - z[1]));
                    points.push(s.points.len() as f64);
                }
            }
            let mut bins = vec![&mut self.bins[b]];
            if let Some(m) = motion(p) {
                bins.push(&mut self.motions[m]);
            }
            for bin in bins {
                bin.by_segments[made.min(3)] += 1;
                bin.widths.extend_from_slice(&widths);
                bin.points.extend_from_slice(&points);
            }
        }
    }

    /// People counted in every bin.
    pub fn people(&self) -> u64 {
        self.bins.iter().flat_map(|b| b.by_segments).sum()
    }

    /// The share of people seen as exactly `n` segments (3: three or more) in range bin `b`,
    /// or NaN where the bin has nobody.
    pub fn share(&self, b: usize, n: usize) -> f64 {
        self.bins[b].share(n)
    }

    /// The share of people moving as [`MOTIONS`]`[m]` seen as exactly `n` segments.
    pub fn share_moving(&self, m: usize, n: usize) -> f64 {
        self.motions[m].share(n)
    }

    /// The summary: per range bin (`by_range`, empty bins left out) and per motion
    /// (`by_motion`), the people, the shares seen as none, one, two and three or more
    /// segments, and their segments' width (10th, 50th and 90th percentiles, m) and median
    /// points.
    pub fn summary(&self) -> Value {
        let mut lo = 0.0;
        let mut by_range = Vec::new();
        for (&hi, bin) in BINS.iter().zip(&self.bins) {
            if bin.people() > 0 {
                let mut v = bin.summary();
                v["range_m"] = json!([lo, hi]);
                by_range.push(v);
            }
            lo = hi;
        }
        let by_motion: serde_json::Map<String, Value> = MOTIONS
            .iter()
            .zip(&self.motions)
            .map(|(m, bin)| (m.to_string(), bin.summary()))
            .collect();
        json!({"near_m": NEAR, "by_range": by_range, "by_motion": by_motion})
    }
}

impl Bin {
    fn people(&self) -> u64 {
        self.by_segments.iter().sum()
    }

    fn share(&self, n: usize) -> f64 {
        self.by_segments[n.min(3)] as f64 / self.people() as f64
    }

    fn summary(&self) -> Value {
        let q = |v: &[f64], p: f64| Stats::percentile(v, p).unwrap_or(f64::NAN);
        json!({
            "people": self.people(),
            "share_by_segments": {
                "none": self.share(0),
                "one": self.share(1),
                "two": self.share(2),
                "three_or_more": self.share(3),
            },
            "segments": self.widths.len(),
            "width_m": {
                "p10": q(&self.widths, 10.0),
                "median": q(&self.widths, 50.0),
                "p90": q(&self.widths, 90.0),
            },
            "points_median": q(&self.points, 50.0),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn segment(points: Vec<[f64; 2]>) -> Segment {
        Segment {
            first: 0,
            points,
            jumps: [1.0, 1.0],
        }
    }

    fn seen(centre: [f64; 2], velocity: Option<[f64; 2]>) -> Seen {
        Seen { centre, velocity }
    }

    /// A hand case: one person 1 m away walking at the laser and seen as two legs, one 3 m
    /// away walking across and seen as one merged segment with a wall segment beside them,
    /// one 5 m away standing and seen as nothing, one 12 m away out of every bin, and one
    /// 1.2 m away whose motion is not known.
    #[test]
    fn people_are_counted_by_the_segments_near_them_and_binned_by_range_and_motion() {
        let mut s = LegScans::default();
        let segments = vec![
            segment(vec![[1.0, 0.1], [0.98, 0.15], [1.0, 0.2]]),
            segment(vec![[1.0, -0.2], [0.98, -0.15], [1.0, -0.1]]),
            segment(vec![[3.0, -0.15], [2.95, 0.0], [3.0, 0.15]]),
            segment(vec![[3.0, 1.0], [3.0, 2.0], [3.0, 3.0]]),
        ];
        s.add(
            &segments,
            &[
                seen([1.0, 0.0], Some([-1.2, 0.3])),
                seen([3.0, 0.0], Some([0.2, 1.0])),
                seen([5.0, 0.0], Some([0.1, 0.1])),
                seen([12.0, 0.0], Some([1.0, 0.0])),
            ],
        );
        s.add(&segments, &[seen([1.2, 0.0], None)]);
        assert_eq!(s.people(), 4);
        assert_eq!(s.share(0, 2), 1.0);
        // standing, along, across: each one person.
        assert_eq!(s.share_moving(0, 0), 1.0);
        assert_eq!(s.share_moving(1, 2), 1.0);
        assert_eq!(s.share_moving(2, 1), 1.0);
        assert_eq!(s.share(1, 1), 1.0);
        assert_eq!(s.share(2, 0), 1.0);
        assert!(s.share(3, 0).is_nan());
        let v = s.summary();
        let bins = v["by_range"].as_array().unwrap();
        assert_eq!(bins.len(), 3);
        assert_eq!(bins[0]["people"], 2);
        assert_eq!(bins[0]["segments"], 4);
        assert_eq!(v["by_motion"]["along"]["segments"], 2);
        assert_eq!(v["by_motion"]["standing"]["people"], 1);
        assert!((bins[0]["width_m"]["median"].as_f64().unwrap() - 0.1).abs() < 1e-12);
        assert_eq!(bins[1]["range_m"], json!([2.0, 4.0]));
        assert!((bins[1]["width_m"]["median"].as_f64().unwrap() - 0.3).abs() < 1e-12);
        assert_eq!(bins[2]["share_by_segments"]["none"], 1.0);
    }
}
