//! Things that move, found in 2D laser scans without a model of what they look like: the
//! two moving-object detectors of the seeds.
//!
//! - [`MapDifference`] (seed 000 §2.6): a scan's points that the static map does not explain,
//!   because they lie in its free space more than `static_distance` (0.15 m) from any occupied
//!   cell. Seed 000 then runs optical flow on these to keep the moving ones; here the tracker
//!   does that part (a track is a person once it has walked).
//! - [`TemporalDifference`] (seed 004 §4): scans taken `interval` (0.25 s) apart are kept,
//!   `window` (3) of them besides the newest; the points of the scan before the newest, t−1,
//!   are differenced against all the others, t, t−2, …, t−n (seed 004's fix for walls showing
//!   up in a plain two-scan difference). A point of t−1 moves when no other scan has a point
//!   within `same_place` (0.1 m) of it **and** at least one other scan's beam passes through
//!   it by more than `same_place`. The second condition is this module's, not the paper's: a
//!   point that the other scans could not see (out of their field of view, or hidden behind
//!   something nearer) is then not taken for a moving one, which is how static walls show up
//!   in the plain difference. The result belongs to t−1, one interval late, as in the paper.
//!
//! Both group the points they flag, in beam order, into blobs of consecutive points no
//! further apart than `cluster_distance` (0.13 m, as the leg segmenter) with at least
//! `min_points` (3) points and no wider than `max_width` (0.5 m: a leg, or two legs side by
//! side; a wall or a door is wider). A blob's confidence is the number of points it holds:
//! neither detector has a better measure of how sure it is.

use crate::config::{ConfigError, check_counts, check_ranges};
use crate::geometry::grid::{OCCUPIED, obstacle_distance};
use crate::geometry::within;
use futago_msgs::grid::OccupancyGrid;
use futago_msgs::{LaserScan, Pose2, Time};
use serde::{Deserialize, Serialize};
use std::collections::{HashMap, VecDeque};

/// Settings of the moving-object detectors (`people.motion`).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct MotionConfig {
    /// A point this close to an occupied cell of the map is the map's, m.
    pub static_distance: f64,
    /// Two scans' points this close are the same place, m.
    pub same_place: f64,
    /// Scans kept for the temporal difference are at least this far apart in time, s.
    pub interval: f64,
    /// Scans the point of t−1 is differenced against (n of seed 004), besides the newest.
    pub window: usize,
    /// Flagged points further apart than this, in beam order, start a new blob, m.
    pub cluster_distance: f64,
    /// Blobs with fewer points are dropped.
    pub min_points: usize,
    /// Blobs wider than this (first to last point) are dropped, m.
    pub max_width: f64,
    /// Beams beyond this are ignored, m.
    pub max_range: f64,
}

impl Default for MotionConfig {
    fn default() -> Self {
        MotionConfig {
            static_distance: 0.15,
            same_place: 0.1,
            interval: 0.25,
            window: 3,
            cluster_distance: 0.13,
            min_points: 3,
            max_width: 0.5,
            max_range: 10.0,
        }
    }
}

impl MotionConfig {
    /// Checks every field; errors name `prefix.field`.
    pub fn validate(&self, prefix: &str) -> Result<(), ConfigError> {
        check_ranges(
            prefix,
            &[
                ("static_distance", self.static_distance, 0.0, 5.0),
                ("same_place", self.same_place, 0.001, 5.0),
                ("interval", self.interval, 0.0, 60.0),
                ("cluster_distance", self.cluster_distance, 0.01, 2.0),
                ("max_width", self.max_width, 0.01, 10.0),
                ("max_range", self.max_range, 0.1, 100.0),
            ],
        )?;
        check_counts(
            prefix,
            &[
                ("window", self.window, 1, 100),
                ("min_points", self.min_points, 1, 1000),
            ],
        )
    }
}

/// A group of flagged points: where (the frame the caller asked for) and how many points.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Blob {
    pub position: [f64; 2],
    pub points: usize,
}

/// A scan's valid beams as points in the laser's frame, by beam index.
fn beam_points(scan: &LaserScan, max_range: f64) -> Vec<Option<[f64; 2]>> {
    let max = max_range.min(scan.range_max);
    (0..scan.ranges.len())
        .map(|i| {
            let r = scan.ranges[i] as f64;
            (r.is_finite() && r >= scan.range_min && r <= max).then(|| {
                let a = scan.angle(i);
                [r * a.cos(), r * a.sin()]
            })
        })
        .collect()
}

/// The blobs of the flagged points, given in beam order as (beam, point).
fn blobs(flagged: &[(usize, [f64; 2])], c: &MotionConfig) -> Vec<Blob> {
    let dist = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).hypot(a[1] - b[1]);
    let mut out = Vec::new();
    let mut run: Vec<[f64; 2]> = Vec::new();
    let mut last_beam = 0usize;
    let mut flush = |run: &mut Vec<[f64; 2]>| {
        if run.len() >= c.min_points && dist(run[0], run[run.len() - 1]) <= c.max_width {
            let n = run.len() as f64;
            let (sx, sy) = run
                .iter()
                .fold((0.0, 0.0), |(x, y), p| (x + p[0], y + p[1]));
            out.push(Blob {
                position: [sx / n, sy / n],
                points: run.len(),
            });
        }
        run.clear();
    };
    for &(i, p) in flagged {
        let joins = run
            .last()
            .is_some_and(|q| i == last_beam + 1 && dist(*q, p) <= c.cluster_distance);
        if !joins {
            flush(&mut run);
        }
        run.push(p);
        last_beam = i;
    }
    flush(&mut run);
    out
}

/// Seed 000's scan-against-map difference on one map (see the module documentation).
#[derive(Debug, Clone)]
pub struct MapDifference {
    map: OccupancyGrid,
    /// Distance from each cell to the nearest occupied one, m.
    distance: Vec<f32>,
}

impl MapDifference {
    /// Prepares `map`: its distance transform, capped a little beyond `c.static_distance`.
    pub fn new(map: &OccupancyGrid, c: &MotionConfig) -> MapDifference {
        let cap = c.static_distance + 2.0 * map.resolution;
        MapDifference {
            distance: obstacle_distance(map, |v| v >= OCCUPIED, cap),
            map: map.clone(),
        }
    }

    /// Whether `q` (map frame) lies in the map's known free space, further than `clear`
    /// from its obstacles.
    pub fn is_free(&self, q: [f64; 2], clear: f64) -> bool {
        let Some((i, j)) = self.map.cell_of(q[0], q[1]) else {
            return false;
        };
        let v = self.map.get(i, j);
        (0..OCCUPIED).contains(&v)
            && self.distance[j * self.map.width + i] as f64 > clear + 0.5 * self.map.resolution
    }

    /// The blobs of `scan`'s points that the map does not explain, in the laser's frame;
    /// `laser` is the laser's pose in the map.
    pub fn detect(&self, scan: &LaserScan, laser: &Pose2, c: &MotionConfig) -> Vec<Blob> {
        let flagged: Vec<(usize, [f64; 2])> = beam_points(scan, c.max_range)
            .into_iter()
            .enumerate()
            .filter_map(|(i, p)| p.map(|p| (i, p)))
            .filter(|(_, p)| self.is_free(laser.transform_point(*p), c.static_distance))
            .collect();
        blobs(&flagged, c)
    }
}

/// One scan kept by [`TemporalDifference`]: its time, the laser's pose in the fixed frame,
/// its beams and their points in the fixed frame.
#[derive(Debug, Clone)]
struct Kept {
    stamp: Time,
    laser: Pose2,
    scan: LaserScan,
    world: Vec<Option<[f64; 2]>>,
}

/// Seed 004's temporal difference over a window of scans (see the module documentation).
#[derive(Debug, Clone)]
pub struct TemporalDifference {
    config: MotionConfig,
    kept: VecDeque<Kept>,
}

impl TemporalDifference {
    pub fn new(config: MotionConfig) -> TemporalDifference {
        TemporalDifference {
            config,
            kept: VecDeque::new(),
        }
    }

    /// Takes a scan and the laser's pose in a fixed frame (odometry's or a map's). When the
    /// scan is kept and the window is full, returns the time of scan t−1 and its moving
    /// blobs, in the fixed frame.
    pub fn update(&mut self, scan: &LaserScan, laser: &Pose2) -> Option<(Time, Vec<Blob>)> {
        let c = self.config;
        if self
            .kept
            .back()
            .is_some_and(|k| (scan.stamp - k.stamp).secs() < c.interval)
        {
            return None;
        }
        let world = beam_points(scan, c.max_range)
            .into_iter()
            .map(|p| p.map(|p| laser.transform_point(p)))
            .collect();
        self.kept.push_back(Kept {
            stamp: scan.stamp,
            laser: *laser,
            scan: scan.clone(),
            world,
        });
        while self.kept.len() > c.window + 1 {
            self.kept.pop_front();
        }
        if self.kept.len() < c.window + 1 {
            return None;
        }
        let focus = self.kept.len() - 2;
        Some((self.kept[focus].stamp, self.moving(focus)))
    }

    /// The moving blobs of kept scan `focus` against the others.
    fn moving(&self, focus: usize) -> Vec<Blob> {
        let c = self.config;
        let cell = c.same_place;
        let key = |p: [f64; 2]| ((p[0] / cell).floor() as i64, (p[1] / cell).floor() as i64);
        // The other scans' points, hashed into cells of `same_place`.
        let mut cells: HashMap<(i64, i64), Vec<[f64; 2]>> = HashMap::new();
        for (k, kept) in self.kept.iter().enumerate() {
            if k != focus {
                for p in kept.world.iter().flatten() {
                    cells.entry(key(*p)).or_default().push(*p);
                }
            }
        }
        // Any point within `same_place` lies in this cell or a neighbour.
        let near_other = |p: [f64; 2]| {
            let (i, j) = key(p);
            (-1..=1).any(|di| {
                (-1..=1).any(|dj| {
                    cells.get(&(i + di, j + dj)).is_some_and(|v| {
                        v.iter()
                            .any(|q| within(q[0] - p[0], q[1] - p[1], c.same_place))
                    })
                })
            })
        };
        let seen_through = |p: [f64; 2]| {
            self.kept.iter().enumerate().any(|(k, kept)| {
                if k == focus {
                    return false;
                }
                let q = kept.laser.inverse().transform_point(p);
                let r = q[0].hypot(q[1]);
                let a = q[1].atan2(q[0]);
                let s = &kept.scan;
                let i = ((a - s.angle_min) / s.angle_increment).round();
                if !(i >= 0.0 && (i as usize) < s.ranges.len()) {
                    return false;
                }
                let range = s.ranges[i as usize] as f64;
                // A beam with no echo saw nothing up to its maximum range.
                let reach = if range.is_finite() && range >= s.range_min {
                    range
                } else if range.is_infinite() || range > s.range_max {
                    s.range_max
                } else {
                    return false;
                };
                reach > r + c.same_place && r < s.range_max
            })
        };
        let kept = &self.kept[focus];
        let flagged: Vec<(usize, [f64; 2])> = kept
            .world
            .iter()
            .enumerate()
            .filter_map(|(i, p)| p.map(|p| (i, p)))
            .filter(|(_, p)| !near_other(*p) && seen_through(*p))
            .collect();
        blobs(&flagged, &c)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The leg tests' scan (0.5° beams over ±90°, circles before a wall at x = `wall`),
    /// taken at `t`.
    fn scan(t: f64, circles: &[([f64; 2], f64)], wall: f64) -> LaserScan {
        LaserScan {
            stamp: Time::from_secs(t),
            ..crate::perception::legs::tests::scan(circles, wall)
        }
    }

    /// A map of a room whose wall at x = 4 m is occupied and the rest free, at 5 cm.
    fn room() -> OccupancyGrid {
        let mut m = OccupancyGrid::new(0.05, [-1.0, -6.0], 120, 240);
        for j in 0..m.height {
            for i in 0..m.width {
                let c = m.cell_center(i, j);
                m.set(i, j, if (c[0] - 4.0).abs() < 0.05 { 100 } else { 0 });
            }
        }
        m
    }

    #[test]
    fn the_map_difference_finds_a_leg_and_not_the_wall() {
        let c = MotionConfig::default();
        let map = room();
        let d = MapDifference::new(&map, &c);
        let s = scan(0.0, &[([2.0, 0.5], 0.05)], 4.0);
        let found = d.detect(&s, &Pose2::default(), &c);
        assert_eq!(found.len(), 1, "{found:?}");
        let p = found[0].position;
        // The centroid of the lit arc lies between the leg's front (1.95 m) and its axis.
        assert!(
            (p[0] - 1.97).abs() < 0.03 && (p[1] - 0.5).abs() < 0.03,
            "{p:?}"
        );
        // With the laser placed 1 m further back, the wall's points land at x = 3 m, in free
        // space, but as runs metres wide they are no blob. The leg is still found, in the
        // laser's frame.
        let shifted = d.detect(&s, &Pose2::new(-1.0, 0.0, 0.0), &c);
        assert_eq!(shifted.len(), 1, "{shifted:?}");
        let p = shifted[0].position;
        assert!(
            (p[0] - 1.97).abs() < 0.03 && (p[1] - 0.5).abs() < 0.03,
            "{p:?}"
        );
    }

    #[test]
    fn the_temporal_difference_finds_a_walker_but_not_a_standing_leg_or_the_wall() {
        let c = MotionConfig::default();
        let mut td = TemporalDifference::new(c);
        let standing = ([2.5, -1.0], 0.05);
        let mut out = Vec::new();
        // A leg walks along y at 1.2 m/s; scans every 0.25 s, one skipped in between (it is
        // too soon, 0.1 s after a kept one, and must not count).
        for k in 0..6 {
            let t = 0.25 * k as f64;
            let walker = ([2.0, -0.5 + 1.2 * t], 0.05);
            let s = scan(t, &[walker, standing], 4.0);
            if let Some(r) = td.update(&s, &Pose2::default()) {
                out.push(r);
            }
            assert!(
                td.update(&scan(t + 0.1, &[], 4.0), &Pose2::default())
                    .is_none()
            );
        }
        // The window is full from the fourth kept scan on: three results, each for the scan
        // before the newest.
        assert_eq!(out.len(), 3);
        for (t, blobs) in &out {
            let y = -0.5 + 1.2 * t.secs();
            assert_eq!(blobs.len(), 1, "at {t:?}: {blobs:?}");
            let p = blobs[0].position;
            assert!(
                (p[0] - 1.97).abs() < 0.03 && (p[1] - y).abs() < 0.03,
                "{p:?} at y {y}"
            );
        }
    }

    #[test]
    fn the_temporal_difference_leaves_out_what_the_other_scans_could_not_see() {
        // A leg stands still; at t−1 (only) it is seen, because before and after another leg
        // stands in front of it. Nothing saw through its place: it is not moving.
        let c = MotionConfig::default();
        let mut td = TemporalDifference::new(c);
        let behind = ([3.0, 0.0], 0.05);
        let front = ([1.5, 0.0], 0.08);
        let mut last = None;
        for k in 0..4 {
            let t = 0.25 * k as f64;
            let circles: Vec<_> = if k == 2 {
                vec![behind]
            } else {
                vec![behind, front]
            };
            last = td.update(&scan(t, &circles, 4.0), &Pose2::default());
        }
        let (t, blobs) = last.expect("the window is full");
        assert_eq!(t, Time::from_secs(0.5));
        assert!(blobs.is_empty(), "{blobs:?}");
    }

    #[test]
    fn a_moving_robot_sees_the_wall_stand_still() {
        // The laser drives along x at 0.5 m/s facing a wall; the odometry poses are exact.
        let c = MotionConfig::default();
        let mut td = TemporalDifference::new(c);
        let mut results = 0;
        for k in 0..6 {
            let x = 0.125 * k as f64;
            let s = scan(0.25 * k as f64, &[], 4.0 - x);
            if let Some((_, b)) = td.update(&s, &Pose2::new(x, 0.0, 0.0)) {
                assert!(b.is_empty(), "{b:?}");
                results += 1;
            }
        }
        assert_eq!(results, 3);
    }

    #[test]
    fn bad_settings_are_named() {
        let c = MotionConfig {
            window: 0,
            ..MotionConfig::default()
        };
        assert_eq!(
            c.validate("people.motion").unwrap_err().0,
            "people.motion.window"
        );
        let c = MotionConfig {
            same_place: f64::NAN,
            ..MotionConfig::default()
        };
        assert_eq!(
            c.validate("people.motion").unwrap_err().0,
            "people.motion.same_place"
        );
    }
}
