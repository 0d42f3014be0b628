//! People tracked from leg detections: legs paired into people, a constant-velocity Kalman
//! filter per track, global nearest-neighbour association by Kuhn–Munkres, and births and
//! deaths, after leg_tracker (Leigh, Pineau, Olmedo & Zhang, ICRA 2015).
//!
//! Each scan's legs (in a fixed frame: odometry or map) are paired greedily, nearest first,
//! when no more than `pair_distance` (0.8 m, leg_tracker's `max_leg_pairing_dist`) apart; a
//! pair is a person at its midpoint, an unpaired leg a person at the leg (the other hidden).
//! Tracks are predicted to the scan's time and assigned to these candidates at least cost
//! (distance), within `gate`. An unassigned candidate further than `pair_distance` from every
//! track starts a tentative track. A track becomes a person once it has travelled
//! `confirm_distance` (0.5 m, leg_tracker's `dist_travelled_together_to_initiate_leg_pair`)
//! within `confirm_window` seconds (3 s), seen in at least `confirm_hits` scans: chair and
//! table legs never walk, and the window keeps the odometry's slow drift (a few centimetres
//! in seconds) from walking them.
//! A track is also a person once a shape detector (people in depth images,
//! [`crate::perception::depth_people`]) has seen it in `confirm_shape_hits` frames
//! ([`PeopleTracker::update_shapes`]): a body of a person's height and width standing on the
//! floor is a person whether it walks or not, which legs alone cannot tell.
//! A confirmed person who then stands still stays a person. A track not seen for `max_coast`
//! seconds, or whose position spreads beyond `max_std` (0.9 m, leg_tracker's), is dropped.
//! Until then it is remembered (a planner keeps clear of a person hidden behind another), but
//! reported as a person in view only while seen within `report_coast` (0.5 s): on the real
//! annotated log, two thirds of the false positives were tracks coasting without a detection.

use super::assignment::assign;
use crate::config::{ConfigError, check_counts, check_ranges};
use futago_msgs::Time;
use nalgebra::{Matrix2, Matrix2x4, Matrix4, Vector2, Vector4};
use serde::{Deserialize, Serialize};

/// Tracker settings (`people.tracker`).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrackerConfig {
    /// Two legs this close may be one person's, m.
    pub pair_distance: f64,
    /// A track takes a candidate no further than this from its prediction, m.
    pub gate: f64,
    /// White-noise acceleration of the constant-velocity model, m/s².
    pub acceleration_noise: f64,
    /// Standard deviation of a candidate's position, m.
    pub measurement_noise: f64,
    /// Distance a tentative track must travel to become a person, m.
    pub confirm_distance: f64,
    /// Scans a tentative track must be seen in to become a person.
    pub confirm_hits: usize,
    /// The travel must happen within this long, s.
    pub confirm_window: f64,
    /// Frames of a shape detector a track must be seen in to become a person, walking or
    /// not.
    pub confirm_shape_hits: usize,
    /// A track unseen this long is dropped, s.
    pub max_coast: f64,
    /// A confirmed track unseen longer than this is no longer reported as a person in view
    /// ([`PeopleTracker::people`]), s; it is still remembered
    /// ([`PeopleTracker::remembered`]) until `max_coast`.
    pub report_coast: f64,
    /// A track whose position's standard deviation exceeds this is dropped, m.
    pub max_std: f64,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        TrackerConfig {
            pair_distance: 0.8,
            gate: 0.6,
            acceleration_noise: 2.0,
            measurement_noise: 0.1,
            confirm_distance: 0.5,
            confirm_hits: 3,
            confirm_window: 3.0,
            confirm_shape_hits: 3,
            max_coast: 1.5,
            // A walker who turns at the model's 2 m/s² is ½·2·0.5² = 0.25 m off the
            // straight-line prediction after 0.5 s: still within half the 0.6 m gate.
            report_coast: 0.5,
            max_std: 0.9,
        }
    }
}

impl TrackerConfig {
    /// Checks every field; errors name `prefix.field`.
    pub fn validate(&self, prefix: &str) -> Result<(), ConfigError> {
        check_ranges(
            prefix,
            &[
                ("pair_distance", self.pair_distance, 0.0, 5.0),
                ("gate", self.gate, 0.01, 10.0),
                ("acceleration_noise", self.acceleration_noise, 0.01, 100.0),
                ("measurement_noise", self.measurement_noise, 0.001, 10.0),
                ("confirm_distance", self.confirm_distance, 0.0, 100.0),
                ("confirm_window", self.confirm_window, 0.01, 1000.0),
                ("max_coast", self.max_coast, 0.01, 100.0),
                ("report_coast", self.report_coast, 0.0, 100.0),
                ("max_std", self.max_std, 0.01, 100.0),
            ],
        )?;
        check_counts(
            prefix,
            &[
                ("confirm_hits", self.confirm_hits, 1, 1000),
                ("confirm_shape_hits", self.confirm_shape_hits, 1, 1000),
            ],
        )
    }
}

/// A person as the tracker sees them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackedPerson {
    pub id: u32,
    pub position: [f64; 2],
    pub velocity: [f64; 2],
}

#[derive(Debug, Clone)]
struct Track {
    id: u32,
    /// x, y, vx, vy and its covariance.
    x: Vector4<f64>,
    p: Matrix4<f64>,
    /// Where and when the current confirmation window began.
    born_at: [f64; 2],
    born_time: Time,
    hits: usize,
    /// Frames of a shape detector it was seen in.
    shape_hits: usize,
    confirmed: bool,
    last_seen: Time,
}

/// The people tracker (see the module documentation).
#[derive(Debug, Clone)]
pub struct PeopleTracker {
    config: TrackerConfig,
    tracks: Vec<Track>,
    next_id: u32,
    last: Option<Time>,
}

impl PeopleTracker {
    pub fn new(config: TrackerConfig) -> PeopleTracker {
        PeopleTracker {
            config,
            tracks: Vec::new(),
            next_id: 0,
            last: None,
        }
    }

    /// Takes the legs of one scan at `t`, their positions in the tracking frame, m.
    pub fn update(&mut self, t: Time, legs: &[[f64; 2]]) {
        self.update_where(t, legs, &|_| true);
    }

    /// [`update`](Self::update) with the candidates where `free` says no (on a static
    /// map's obstacle) left out, leg_tracker's free-space test: furniture legs in the map
    /// neither start tracks nor hold a track that walked past them.
    pub fn update_where(&mut self, t: Time, legs: &[[f64; 2]], free: &dyn Fn([f64; 2]) -> bool) {
        let with_confidence: Vec<([f64; 2], f64)> = legs.iter().map(|l| (*l, 1.0)).collect();
        let candidates: Vec<[f64; 2]> = pair_legs(&with_confidence, self.config.pair_distance)
            .into_iter()
            .map(|q| q.position)
            .filter(|q| free(*q))
            .collect();
        self.update_candidates(t, &candidates);
    }

    /// Takes one scan's person candidates at `t` (legs already paired, see [`pair_legs`]), in
    /// the tracking frame, m.
    pub fn update_candidates(&mut self, t: Time, candidates: &[[f64; 2]]) {
        self.update_with(t, candidates, false);
    }

    /// Takes one frame's people from a shape detector (people in depth images) at `t`, in
    /// the tracking frame: as [`update_candidates`](Self::update_candidates), and a track
    /// seen in `confirm_shape_hits` such frames is a person without walking. Only a detector
    /// whose candidates are people by their shape, and have passed the static map's
    /// free-space test, should confirm this way.
    pub fn update_shapes(&mut self, t: Time, candidates: &[[f64; 2]]) {
        self.update_with(t, candidates, true);
    }

    fn update_with(&mut self, t: Time, candidates: &[[f64; 2]], shape: bool) {
        let c = self.config;
        let dt = self.last.map_or(0.0, |l| (t - l).secs().max(0.0));
        self.last = Some(t);
        for tr in &mut self.tracks {
            predict(tr, dt, c.acceleration_noise);
        }
        let costs: Vec<Vec<f64>> = self
            .tracks
            .iter()
            .map(|tr| {
                candidates
                    .iter()
                    .map(|q| (tr.x[0] - q[0]).hypot(tr.x[1] - q[1]))
                    .collect()
            })
            .collect();
        let pairs = assign(&costs, c.gate);
        let mut used = vec![false; candidates.len()];
        for &(k, j) in &pairs {
            used[j] = true;
            let tr = &mut self.tracks[k];
            correct(tr, candidates[j], c.measurement_noise);
            tr.hits += 1;
            tr.shape_hits += usize::from(shape);
            tr.last_seen = t;
            let moved = (tr.x[0] - tr.born_at[0]).hypot(tr.x[1] - tr.born_at[1]);
            if tr.hits >= c.confirm_hits && moved >= c.confirm_distance
                || tr.shape_hits >= c.confirm_shape_hits
            {
                tr.confirmed = true;
            } else if !tr.confirmed && (t - tr.born_time).secs() > c.confirm_window {
                // Too slow: the window starts again from here.
                tr.born_at = [tr.x[0], tr.x[1]];
                tr.born_time = t;
            }
        }
        self.tracks.retain(|tr| {
            let spread = tr.p[(0, 0)].max(tr.p[(1, 1)]).sqrt();
            (t - tr.last_seen).secs() <= c.max_coast && spread <= c.max_std
        });
        for (j, q) in candidates.iter().enumerate() {
            let near_a_track = self
                .tracks
                .iter()
                .any(|tr| (tr.x[0] - q[0]).hypot(tr.x[1] - q[1]) <= c.pair_distance);
            if used[j] || near_a_track {
                continue;
            }
            let s2 = c.measurement_noise * c.measurement_noise;
            // A walker's speed is unknown at birth: 1.5 m/s either way.
            let v2 = 1.5 * 1.5;
            self.tracks.push(Track {
                id: self.next_id,
                x: Vector4::new(q[0], q[1], 0.0, 0.0),
                p: Matrix4::from_diagonal(&Vector4::new(s2, s2, v2, v2)),
                born_at: *q,
                born_time: t,
                hits: 1,
                shape_hits: usize::from(shape),
                confirmed: false,
                last_seen: t,
            });
            self.next_id += 1;
        }
    }

    /// The confirmed people in view now: those seen within `report_coast`. A track predicted
    /// longer without a detection has most likely left the scan (behind another person or
    /// out of range), and its straight-line prediction has drifted from where they are.
    pub fn people(&self) -> Vec<TrackedPerson> {
        let c = self.config.report_coast;
        self.confirmed(|tr| self.last.is_none_or(|t| (t - tr.last_seen).secs() <= c))
    }

    /// Every confirmed person the tracker holds, those unseen for up to `max_coast` included:
    /// what a planner should keep clear of, as a person hidden behind another is still there.
    pub fn remembered(&self) -> Vec<TrackedPerson> {
        self.confirmed(|_| true)
    }

    fn confirmed(&self, keep: impl Fn(&Track) -> bool) -> Vec<TrackedPerson> {
        self.tracks
            .iter()
            .filter(|tr| tr.confirmed && keep(tr))
            .map(|tr| TrackedPerson {
                id: tr.id,
                position: [tr.x[0], tr.x[1]],
                velocity: [tr.x[2], tr.x[3]],
            })
            .collect()
    }

    /// Tracks, tentative ones included.
    pub fn tracks(&self) -> usize {
        self.tracks.len()
    }

    /// Where every track is now, tentative ones included.
    pub fn positions(&self) -> Vec<[f64; 2]> {
        self.tracks.iter().map(|tr| [tr.x[0], tr.x[1]]).collect()
    }
}

/// A person candidate: where, and how sure (the mean confidence of the legs it rests on).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Candidate {
    pub position: [f64; 2],
    pub confidence: f64,
}

/// People candidates from legs with their confidences: legs paired nearest first within
/// `max`, each pair at its midpoint, each unpaired leg on its own (its partner hidden).
pub fn pair_legs(legs: &[([f64; 2], f64)], max: f64) -> Vec<Candidate> {
    let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
    for i in 0..legs.len() {
        for j in i + 1..legs.len() {
            let (a, b) = (legs[i].0, legs[j].0);
            let d = (a[0] - b[0]).hypot(a[1] - b[1]);
            if d <= max {
                pairs.push((d, i, j));
            }
        }
    }
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    let mut taken = vec![false; legs.len()];
    let mut out = Vec::new();
    for (_, i, j) in pairs {
        if taken[i] || taken[j] {
            continue;
        }
        taken[i] = true;
        taken[j] = true;
        let ((a, ca), (b, cb)) = (legs[i], legs[j]);
        out.push(Candidate {
            position: [0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1])],
            confidence: 0.5 * (ca + cb),
        });
    }
    out.extend(legs.iter().zip(&taken).filter(|(_, t)| !**t).map(
        |(&(position, confidence), _)| Candidate {
            position,
            confidence,
        },
    ));
    out
}

/// The constant-velocity prediction over `dt` with white-noise acceleration `q` (m/s²).
fn predict(tr: &mut Track, dt: f64, q: f64) {
    if dt <= 0.0 {
        return;
    }
    let mut f = Matrix4::identity();
    f[(0, 2)] = dt;
    f[(1, 3)] = dt;
    let (a, b, e) = (dt.powi(4) / 4.0, dt.powi(3) / 2.0, dt * dt);
    let q2 = q * q;
    #[rustfmt::skip]
    let qm = Matrix4::new(
        a, 0.0, b, 0.0,
        0.0, a, 0.0, b,
        b, 0.0, e, 0.0,
        0.0, b, 0.0, e,
    ) * q2;
    tr.x = f * tr.x;
    tr.p = f * tr.p * f.transpose() + qm;
}

/// The Kalman update with a position measured at `z` with standard deviation `sigma`.
fn correct(tr: &mut Track, z: [f64; 2], sigma: f64) {
    #[rustfmt::skip]
    let h = Matrix2x4::new(
        1.0, 0.0, 0.0, 0.0,
        0.0, 1.0, 0.0, 0.0,
    );
    let r = Matrix2::identity() * (sigma * sigma);
    let s = h * tr.p * h.transpose() + r;
    let Some(si) = s.try_inverse() else {
        return;
    };
    let k = tr.p * h.transpose() * si;
    let y = Vector2::new(z[0], z[1]) - h * tr.x;
    tr.x += k * y;
    tr.p = (Matrix4::identity() - k * h) * tr.p;
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t(s: f64) -> Time {
        Time::from_secs(s)
    }

    #[test]
    fn a_walker_is_confirmed_once_moved_and_followed_with_its_velocity() {
        let mut tr = PeopleTracker::new(TrackerConfig::default());
        // Legs 0.2 m apart across the walk, walking +x at 1.2 m/s, scanned at 10 Hz; a chair's
        // legs stand at (5, 5).
        let mut first_seen = None;
        for k in 0..40 {
            let s = 0.1 * k as f64;
            let x = 1.2 * s;
            let legs = [[x, 0.1], [x, -0.1], [5.0, 5.0], [5.0, 5.4]];
            tr.update(t(s), &legs);
            if first_seen.is_none() && !tr.people().is_empty() {
                first_seen = Some(s);
            }
        }
        let people = tr.people();
        assert_eq!(people.len(), 1, "{people:?}");
        let p = people[0];
        // Confirmed after 0.5 m: the fifth scan at 1.2 m/s (0.48 m at 0.4 s, 0.6 m at 0.5 s).
        assert_eq!(first_seen, Some(0.5));
        assert!((p.position[0] - 1.2 * 3.9).abs() < 0.05, "{p:?}");
        assert!(p.position[1].abs() < 0.02);
        assert!((p.velocity[0] - 1.2).abs() < 0.05, "{p:?}");
        // The chair stays a tentative track, never a person.
        assert_eq!(tr.tracks(), 2);
    }

    #[test]
    fn a_chair_that_drifts_with_the_odometry_never_walks() {
        let mut tr = PeopleTracker::new(TrackerConfig::default());
        // Odometry drifting 5 cm/s makes a chair's legs creep 1.5 m in 30 s: under 0.5 m in
        // any 3 s window.
        for k in 0..300 {
            let s = 0.1 * k as f64;
            tr.update(t(s), &[[2.0 + 0.05 * s, 1.0]]);
        }
        assert!(tr.people().is_empty(), "{:?}", tr.people());
        assert_eq!(tr.tracks(), 1);
    }

    #[test]
    fn a_standing_person_the_depth_detector_sees_is_confirmed_by_shape() {
        // Someone stands at (2, 1): their legs are seen at 10 Hz, which never confirms them.
        let mut tr = PeopleTracker::new(TrackerConfig::default());
        for k in 0..30 {
            tr.update(t(0.1 * k as f64), &[[2.0, 1.1], [2.0, 0.9]]);
        }
        assert!(tr.people().is_empty());
        // A depth frame at 5 Hz sees a body there: after the third, they are a person.
        let mut confirmed_at = None;
        for k in 30..50 {
            let s = 0.1 * k as f64;
            tr.update(t(s), &[[2.0, 1.1], [2.0, 0.9]]);
            if k % 2 == 0 {
                tr.update_shapes(t(s), &[[2.02, 1.0]]);
            }
            if confirmed_at.is_none() && !tr.people().is_empty() {
                confirmed_at = Some(k);
            }
        }
        assert_eq!(confirmed_at, Some(34));
        assert_eq!(tr.tracks(), 1);
    }

    #[test]
    fn no_track_starts_or_holds_where_the_map_is_not_free() {
        let mut tr = PeopleTracker::new(TrackerConfig::default());
        // A walker crossing x = 0 … 3 at 1 m/s; the map is occupied for x < 1: the track
        // starts once the walker is in free space, and is confirmed 0.5 m later.
        let mut first = None;
        for k in 0..30 {
            let s = 0.1 * k as f64;
            tr.update_where(t(s), &[[s, 0.0]], &|q| q[0] >= 1.0);
            if first.is_none() && !tr.people().is_empty() {
                first = Some(s);
            }
        }
        // 0.5 m after x = 1 (at 1.5 s), and the filter, starting at rest, lags by a scan.
        let first = first.unwrap();
        assert!((1.5..=1.6 + 1e-9).contains(&first), "{first}");
        // The walker vanishes by a table (occupied for x > 3.5): the table's legs, seen from
        // then on, do not hold the track, which is dropped after 1.5 s.
        for k in 30..80 {
            let s = 0.1 * k as f64;
            tr.update_where(t(s), &[[3.8, 0.2]], &|q| (1.0..=3.5).contains(&q[0]));
        }
        assert!(tr.people().is_empty(), "{:?}", tr.people());
    }

    #[test]
    fn a_person_who_stops_stays_and_one_who_leaves_is_dropped() {
        let mut tr = PeopleTracker::new(TrackerConfig::default());
        for k in 0..60 {
            let s = 0.1 * k as f64;
            // Walks 1 m in the first second, then stands.
            let x = (1.0 * s).min(1.0);
            tr.update(t(s), &[[x, 0.0]]);
        }
        assert_eq!(tr.people().len(), 1);
        let id = tr.people()[0].id;
        assert!((tr.people()[0].position[0] - 1.0).abs() < 0.02);
        // Gone from view (last seen at 5.9 s): reported in view for report_coast (0.5 s),
        // remembered for max_coast (1.5 s), then dropped.
        for k in 60..64 {
            tr.update(t(0.1 * k as f64), &[]);
        }
        assert_eq!(tr.people().len(), 1, "0.4 s unseen is still in view");
        for k in 64..74 {
            tr.update(t(0.1 * k as f64), &[]);
        }
        assert!(tr.people().is_empty(), "1.4 s unseen is out of view");
        assert_eq!(tr.remembered().len(), 1);
        assert_eq!(tr.remembered()[0].id, id);
        for k in 74..80 {
            tr.update(t(0.1 * k as f64), &[]);
        }
        assert!(tr.remembered().is_empty());
    }

    #[test]
    fn a_person_hidden_a_while_is_out_of_view_then_back_under_the_same_id() {
        let mut tr = PeopleTracker::new(TrackerConfig::default());
        // Walks along x at 1 m/s, seen every 0.1 s but between 3 s and 4 s.
        let mut hidden = Vec::new();
        let mut ids = std::collections::BTreeSet::new();
        for k in 0..60 {
            let s = 0.1 * k as f64;
            let seen = !(30..40).contains(&k);
            let legs: Vec<[f64; 2]> = if seen { vec![[s, 0.0]] } else { vec![] };
            tr.update(t(s), &legs);
            ids.extend(tr.people().iter().map(|p| p.id));
            if !seen {
                hidden.push((s, tr.people().len(), tr.remembered().len()));
            }
        }
        // Last seen at 2.9 s: in view to 3.4 s, remembered throughout.
        for (s, in_view, held) in hidden {
            assert_eq!(in_view, usize::from(s <= 3.4 + 1e-9), "at {s} s");
            assert_eq!(held, 1, "at {s} s");
        }
        assert_eq!(tr.people().len(), 1);
        assert_eq!(ids.len(), 1, "one id throughout: {ids:?}");
    }

    #[test]
    fn two_people_crossing_keep_their_ids() {
        let mut tr = PeopleTracker::new(TrackerConfig::default());
        let mut ids = None;
        for k in 0..60 {
            let s = 0.1 * k as f64;
            // One walks +x along y = 1, the other −x along y = −1: they pass 2 m apart.
            let a = [-3.0 + 1.0 * s, 1.0];
            let b = [3.0 - 1.0 * s, -1.0];
            tr.update(t(s), &[a, b]);
            let mut p = tr.people();
            p.sort_by(|u, v| u.position[1].total_cmp(&v.position[1]));
            if p.len() == 2 {
                let now = (p[0].id, p[1].id);
                assert_eq!(*ids.get_or_insert(now), now, "ids swapped at {s} s");
            }
        }
        assert!(ids.is_some());
    }
}
