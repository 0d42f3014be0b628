//! What a planar laser sees of people, measured the same way on real annotated scans and on
//! simulated ones, so that the twin's people can be held to real ones (issue 45, part 1).
//!
//! For each person of a scan (a real log's annotation, or a simulated person the scan sees),
//! the scan's segments ([`futago_robot::perception::legs::segments`], the leg detector's own)
//! whose centroid lies within [`NEAR`] of the person's centre are theirs. By range from the
//! laser, in bins of 2 m, it counts how many segments a person makes (none, one: legs merged
//! or one hidden; two: each leg its own; three or more: a leg cut by a gap), and the widths
//! (first to last point) and point counts of their segments. These are what the leg
//! classifier learns from; a twin whose people give a different mix teaches it the wrong
//! legs.

use super::trajectory::Stats;
use futago_robot::perception::legs::Segment;
use serde_json::{Value, json};

/// A segment whose centroid lies this close to a person's centre is theirs, m: half the
/// longest step (0.8 m), as far as a foot reaches from the centre.
pub const NEAR: f64 = 0.4;

/// The range bins' upper edges, m (the first starts at 0).
const BINS: [f64; 5] = [2.0, 4.0, 6.0, 8.0, 10.0];

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
}

impl LegScans {
    /// Adds one scan: its segments and its people's centres, both in the laser's frame (m).
    /// People beyond the last bin are left out.
    pub fn add(&mut self, segments: &[Segment], people: &[[f64; 2]]) {
        let centroids: Vec<[f64; 2]> = segments.iter().map(Segment::centroid).collect();
        for p in people {
            let range = p[0].hypot(p[1]);
            let Some(b) = BINS.iter().position(|&hi| range < hi) else {
                continue;
            };
            let bin = &mut self.bins[b];
            let mut made = 0usize;
            for (s, c) in segments.iter().zip(&centroids) {
                if (c[0] - p[0]).hypot(c[1] - p[1]) <= NEAR {
                    made += 1;
                    let (a, z) = (s.points[0], s.points[s.points.len() - 1]);
                    bin.widths.push((a[0] - z[0]).hypot(a[1] - z[1]));
                    bin.points.push(s.points.len() as f64);
                }
            }
            bin.by_segments[made.min(3)] += 1;
        }
    }

    /// People counted in every bin.
    pub fn people(&self) -> u64 {
        self.bins.iter().flat_map(|b| b.by_segments).sum()
    }

    /// The share of people seen as exactly `n` segments (3: three or more) in bin `b`, or NaN
    /// where the bin has nobody.
    pub fn share(&self, b: usize, n: usize) -> f64 {
        let c = &self.bins[b].by_segments;
        let all: u64 = c.iter().sum();
        c[n.min(3)] as f64 / all as f64
    }

    /// The summary: per range bin, the people, the shares seen as none, one, two and three or
    /// more segments, and their segments' width (10th, 50th and 90th percentiles, m) and
    /// median points. Empty bins are left out.
    pub fn summary(&self) -> Value {
        let mut lo = 0.0;
        let mut out = Vec::new();
        for (b, (&hi, bin)) in BINS.iter().zip(&self.bins).enumerate() {
            let people: u64 = bin.by_segments.iter().sum();
            if people > 0 {
                let q = |v: &[f64], p: f64| Stats::percentile(v, p).unwrap_or(f64::NAN);
                out.push(json!({
                    "range_m": [lo, hi],
                    "people": people,
                    "share_by_segments": {
                        "none": self.share(b, 0),
                        "one": self.share(b, 1),
                        "two": self.share(b, 2),
                        "three_or_more": self.share(b, 3),
                    },
                    "segments": bin.widths.len(),
                    "width_m": {
                        "p10": q(&bin.widths, 10.0),
                        "median": q(&bin.widths, 50.0),
                        "p90": q(&bin.widths, 90.0),
                    },
                    "points_median": q(&bin.points, 50.0),
                }));
            }
            lo = hi;
        }
        json!({"near_m": NEAR, "by_range": out})
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

    /// A hand case: one person 1 m away seen as two legs, one 3 m away as one merged segment
    /// and a wall segment beside them, one 5 m away seen as nothing, one 12 m away out of
    /// every bin.
    #[test]
    fn people_are_counted_by_the_segments_near_them_and_binned_by_range() {
        let mut s = LegScans::default();
        let segments = vec![
            segment(vec![[1.0, 0.1], [0.98, 0.15], [1.0, 0.2]]),
            segment(vec![[1.0, -0.2], [0.98, -0.15], [1.0, -0.1]]),
            segment(vec![[3.0, -0.15], [2.95, 0.0], [3.0, 0.15]]),
            segment(vec![[3.0, 1.0], [3.0, 2.0], [3.0, 3.0]]),
        ];
        s.add(
            &segments,
            &[[1.0, 0.0], [3.0, 0.0], [5.0, 0.0], [12.0, 0.0]],
        );
        assert_eq!(s.people(), 3);
        assert_eq!(s.share(0, 2), 1.0);
        assert_eq!(s.share(1, 1), 1.0);
        assert_eq!(s.share(2, 0), 1.0);
        assert!(s.share(3, 0).is_nan());
        let v = s.summary();
        let bins = v["by_range"].as_array().unwrap();
        assert_eq!(bins.len(), 3);
        assert_eq!(bins[0]["segments"], 2);
        assert!((bins[0]["width_m"]["median"].as_f64().unwrap() - 0.1).abs() < 1e-12);
        assert_eq!(bins[1]["range_m"], json!([2.0, 4.0]));
        assert!((bins[1]["width_m"]["median"].as_f64().unwrap() - 0.3).abs() < 1e-12);
        assert_eq!(bins[2]["share_by_segments"]["none"], 1.0);
    }
}
