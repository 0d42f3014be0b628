//! People from one planar laser: every detector the stack has for a scan, and the tracker fed
//! by the fused one. The simulation's people node and the replay of real logs both run this,
//! so the twin and the logs score the same code.
//!
//! Per scan, in the laser's frame, as person candidates ([`Candidate`]):
//! - `legs`: the leg classifier's legs ([`crate::perception::legs`]), paired;
//! - `map_difference`: with a map, the blobs the map does not explain
//!   ([`MapDifference`]), paired as legs are (confidence: points);
//! - `fused`: with a map, the leg candidates in the map's free space, further than
//!   `motion.static_distance` from its obstacles (leg_tracker's free-space test), then the
//!   map-difference candidates no leg candidate backs, ranked below them ([`fuse`]);
//! - `temporal`: the temporal difference ([`TemporalDifference`], on odometry poses), which
//!   belongs to an earlier scan and comes with its time.
//!
//! The tracker also takes the people a depth camera finds ([`LaserPeople::update_depth`],
//! from [`crate::perception::depth_people`]) in the same frame: with a map, those in its
//! free space, which confirm a track by their shape alone (a person standing still is a
//! person); without one, as any candidate.
//!
//! The tracker takes the fused candidates at or above the leg detector's threshold (those the
//! legs back), in the map's frame, when there is a map and a pose in it; otherwise the leg
//! candidates in the odometry frame that lie where the scans so far have seen the floor
//! ([`FreeSpace`], leg_tracker's local grid; the grid takes each scan after its candidates are
//! judged). Map-difference candidates without legs were measured to
//! start too many false tracks to feed it (office-people seed 1: MOTA 0.12 → −1.44).

use super::PeopleConfig;
use super::people::{Candidate, PeopleTracker, TrackedPerson, pair_legs};
use crate::perception::free_space::FreeSpace;
use crate::perception::legs::{AdaBoost, detect};
use crate::perception::motion::{Blob, MapDifference, TemporalDifference};
use futago_msgs::grid::OccupancyGrid;
use futago_msgs::{LaserScan, Pose2, Time};

/// One scan's person candidates per detector (see the module documentation).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Detections {
    pub legs: Vec<Candidate>,
    /// `None` without a map.
    pub map_difference: Option<Vec<Candidate>>,
    /// `None` without a map.
    pub fused: Option<Vec<Candidate>>,
    /// The time of the scan they belong to, and the candidates in the odometry frame.
    pub temporal: Option<(Time, Vec<Candidate>)>,
}

/// A leg candidate and a map-difference candidate this close are one person, m (a person's
/// radius, 0.2 m, and a leg's offset from the pair's midpoint).
const AGREE: f64 = 0.3;

/// The fused candidates: each leg candidate in free space, and each map-difference candidate
/// that no such leg candidate lies near. The map-difference candidates alone rank below every
/// leg-backed one: their confidence, points/(points + 10), is halved.
fn fuse(
    legs: &[Candidate],
    moved: &[Candidate],
    free: impl Fn([f64; 2]) -> bool,
) -> Vec<Candidate> {
    let mut out: Vec<Candidate> = legs.iter().copied().filter(|q| free(q.position)).collect();
    let near = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).hypot(a[1] - b[1]) <= AGREE;
    let alone: Vec<Candidate> = moved
        .iter()
        .filter(|m| !out.iter().any(|l| near(l.position, m.position)))
        .map(|m| Candidate {
            position: m.position,
            confidence: 0.5 * m.confidence / (m.confidence + 10.0),
        })
        .collect();
    out.extend(alone);
    out
}

/// Detection and tracking of people on one laser (see the module documentation).
#[derive(Debug, Clone)]
pub struct LaserPeople {
    config: PeopleConfig,
    model: AdaBoost,
    map: Option<MapDifference>,
    temporal: TemporalDifference,
    /// Where the floor has been seen, in the odometry frame, for when there is no map.
    free_space: FreeSpace,
    tracker: PeopleTracker,
}

impl LaserPeople {
    pub fn new(config: PeopleConfig, model: AdaBoost) -> LaserPeople {
        LaserPeople {
            config,
            model,
            map: None,
            temporal: TemporalDifference::new(config.motion),
            free_space: FreeSpace::new(config.free_space),
            tracker: PeopleTracker::new(config.tracker),
        }
    }

    /// Takes a (new) static map; its distance transform is computed once here.
    pub fn set_map(&mut self, map: &OccupancyGrid) {
        self.map = Some(MapDifference::new(map, &self.config.motion));
    }

    /// Detects people in `scan` and updates the tracks. `in_map` is the laser's pose in the
    /// map (used only with a map), `in_odometry` its pose in the odometry frame.
    pub fn update(
        &mut self,
        scan: &LaserScan,
        in_map: Option<Pose2>,
        in_odometry: Pose2,
    ) -> Detections {
        let c = self.config;
        let pair = |blobs: &[Blob]| {
            let pts: Vec<([f64; 2], f64)> = blobs
                .iter()
                .map(|b| (b.position, b.points as f64))
                .collect();
            pair_legs(&pts, c.tracker.pair_distance)
        };
        let legs: Vec<([f64; 2], f64)> = detect(scan, &c.legs, &self.model)
            .iter()
            .map(|l| (l.position, l.confidence))
            .collect();
        let candidates = pair_legs(&legs, c.tracker.pair_distance);
        let mut out = Detections {
            legs: candidates.clone(),
            ..Detections::default()
        };
        let placed = self.map.as_ref().zip(in_map);
        if let Some((map, laser)) = placed {
            let moved = pair(&map.detect(scan, &laser, &c.motion));
            out.fused = Some(fuse(&candidates, &moved, |q| {
                map.is_free(laser.transform_point(q), c.motion.static_distance)
            }));
            out.map_difference = Some(moved);
        }
        out.temporal = self
            .temporal
            .update(scan, &in_odometry)
            .map(|(t, blobs)| (t, pair(&blobs)));
        // The tracker: fused candidates in the map, else leg candidates in odometry where the
        // floor has been seen. The free-space grid then takes the scan, less the returns of
        // the people the tracker holds (tentative ones included: a walker's leading leg would
        // otherwise mark the floor they step onto).
        match (placed, &out.fused) {
            (Some((_, laser)), Some(f)) => {
                let positions: Vec<[f64; 2]> = f
                    .iter()
                    .filter(|q| q.confidence >= c.legs.threshold)
                    .map(|q| laser.transform_point(q.position))
                    .collect();
                self.tracker.update_candidates(scan.stamp, &positions);
            }
            _ => {
                let positions: Vec<[f64; 2]> = out
                    .legs
                    .iter()
                    .filter(|q| q.confidence >= c.legs.threshold)
                    .map(|q| in_odometry.transform_point(q.position))
                    .filter(|p| self.free_space.is_free(*p))
                    .collect();
                self.tracker.update_candidates(scan.stamp, &positions);
                let held = self.tracker.positions();
                self.free_space.update(scan, &in_odometry, &held);
            }
        }
        out
    }

    /// Takes the people a depth camera found in a frame at `stamp` (`found`, positions in the
    /// robot base's frame, m); `in_map` is the base's pose in the map, `in_odometry` in the
    /// odometry frame. Returns how many the tracker took (with a map, those in its free space).
    pub fn update_depth(
        &mut self,
        stamp: Time,
        found: &[[f64; 2]],
        in_map: Option<Pose2>,
        in_odometry: Pose2,
    ) -> usize {
        let c = self.config;
        match self.map.as_ref().zip(in_map) {
            Some((map, base)) => {
                let free: Vec<[f64; 2]> = found
                    .iter()
                    .map(|q| base.transform_point(*q))
                    .filter(|&q| map.is_free(q, c.motion.static_distance))
                    .collect();
                self.tracker.update_shapes(stamp, &free);
                free.len()
            }
            None => {
                let placed: Vec<[f64; 2]> = found
                    .iter()
                    .map(|q| in_odometry.transform_point(*q))
                    .collect();
                self.tracker.update_candidates(stamp, &placed);
                placed.len()
            }
        }
    }

    /// The confirmed people in view, in the tracking frame (the map's with a map and a pose
    /// in it, else odometry's); see [`PeopleTracker::people`].
    pub fn people(&self) -> Vec<TrackedPerson> {
        self.tracker.people()
    }

    /// Every confirmed person held, those out of view for a while included, in the tracking
    /// frame; see [`PeopleTracker::remembered`].
    pub fn remembered(&self) -> Vec<TrackedPerson> {
        self.tracker.remembered()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn c(x: f64, y: f64, confidence: f64) -> Candidate {
        Candidate {
            position: [x, y],
            confidence,
        }
    }

    #[test]
    fn fusion_keeps_free_legs_and_adds_unbacked_motion_below_them() {
        // Legs at (1, 0) (free) and (2, 0) (on the map); motion at (1.2, 0) (backed by the
        // first leg candidate), (2, 0.1) (not backed: that leg is off free space) and (5, 5).
        let legs = [c(1.0, 0.0, 0.7), c(2.0, 0.0, 0.9)];
        let moved = [c(1.2, 0.0, 6.0), c(2.0, 0.1, 10.0), c(5.0, 5.0, 30.0)];
        let f = fuse(&legs, &moved, |q| q[0] < 1.5 || q[0] > 1.9 && q[1] > 0.05);
        assert_eq!(
            f,
            vec![c(1.0, 0.0, 0.7), c(2.0, 0.1, 0.25), c(5.0, 5.0, 0.375)]
        );
        // Every motion-only candidate ranks below every leg candidate.
        assert!(f[1..].iter().all(|q| q.confidence < 0.5));
    }

    /// The scan at `stamp` of a wall at x = 6 m and, where given, a person's two shins (radius
    /// 6 cm, 0.15 m apart side to side) centred at `person`: the leg detector's test scene.
    fn scene(stamp: f64, person: Option<[f64; 2]>) -> LaserScan {
        let shins: Vec<([f64; 2], f64)> = person
            .iter()
            .flat_map(|p| [-0.075, 0.075].map(|side| ([p[0], p[1] + side], 0.06)))
            .collect();
        let mut s = crate::perception::legs::tests::scan(&shins, 6.0);
        s.stamp = Time::from_secs(stamp);
        s
    }

    #[test]
    fn without_a_map_people_are_tracked_only_where_the_floor_was_seen() {
        // Legs are what is narrower than 0.35 m (a person's two shins together); the wall is
        // not.
        let model = AdaBoost {
            stumps: vec![crate::perception::legs::Stump {
                feature: 5,
                threshold: 0.35,
                polarity: -1.0,
                alpha: 1.0,
            }],
        };
        // Someone walks 0.8 m across the view at x = 3 m in 0.8 s (10 Hz), enough to be
        // confirmed as a person (0.5 m within 3 s).
        let walk = |p: &mut LaserPeople, t0: f64| {
            for k in 0..=8 {
                let t = t0 + 0.1 * k as f64;
                let y = -0.4 + 0.1 * k as f64;
                p.update(&scene(t, Some([3.0, y])), None, Pose2::default());
            }
            p.remembered().len()
        };
        // The robot has seen the floor for a second first: the walker is tracked.
        let mut seen = LaserPeople::new(PeopleConfig::default(), model.clone());
        for k in 0..10 {
            seen.update(&scene(0.1 * k as f64, None), None, Pose2::default());
        }
        assert_eq!(walk(&mut seen, 1.0), 1);
        // The same walk as the robot's first scans: nowhere has been seen free long enough,
        // so no track starts (without the free-space test one would).
        let mut fresh = LaserPeople::new(PeopleConfig::default(), model.clone());
        assert_eq!(walk(&mut fresh, 0.0), 0);
        let mut config = PeopleConfig::default();
        config.free_space.threshold = 1.0;
        let mut anywhere = LaserPeople::new(config, model);
        assert_eq!(walk(&mut anywhere, 0.0), 1, "every seen place free");
    }

    #[test]
    fn without_a_map_only_the_map_free_detectors_report() {
        let model = AdaBoost { stumps: Vec::new() };
        let mut p = LaserPeople::new(PeopleConfig::default(), model.clone());
        let scan = LaserScan {
            frame: "laser".into(),
            stamp: Time::ZERO,
            angle_min: -1.0,
            angle_increment: 0.01,
            time_increment: 0.0,
            range_min: 0.02,
            range_max: 30.0,
            ranges: vec![3.0; 201],
        };
        let d = p.update(&scan, Some(Pose2::default()), Pose2::default());
        assert!(d.map_difference.is_none() && d.fused.is_none());
        // With a map of free space all around, the wall 3 m away is off the map's obstacles
        // but far wider than a person: no blob. Map-based detectors now report.
        let mut grid = OccupancyGrid::new(0.05, [-5.0, -5.0], 200, 200);
        grid.cells.iter_mut().for_each(|v| *v = 0);
        p.set_map(&grid);
        let d = p.update(&scan, Some(Pose2::default()), Pose2::default());
        assert_eq!(d.map_difference, Some(Vec::new()));
        assert!(d.fused.is_some());
    }
}
