//! CLEAR-MOT (Bernardin & Stiefelhagen 2008) for people tracks on the floor plane, as the
//! leg_tracker benchmark (Leigh et al. 2015) scores it: frame by frame, a true person and a
//! track that were matched before stay matched while within the gate (0.75 m there); the
//! rest are matched by least total distance within the gate (Kuhn–Munkres). A true person
//! left unmatched is a miss, a track left unmatched a false positive, and a match that
//! changes partner (a track now on another person, or a person now followed by another
//! track) an identity switch.
//!
//! MOTA = 1 − (misses + false positives + switches) / true people over all frames;
//! MOTP = mean distance of the matches, m.

/// The leg_tracker benchmark's match gate, m.
pub const MOT_GATE: f64 = 0.75;

use futago_robot::tracking::assignment::assign;
use std::collections::BTreeMap;

/// One frame: the true people and the tracks, each an id and a position (same frame), m.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Frame {
    pub truth: Vec<(u32, [f64; 2])>,
    pub tracks: Vec<(u32, [f64; 2])>,
}

/// The CLEAR-MOT counts over a sequence.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct Mot {
    pub frames: usize,
    /// True people summed over frames.
    pub objects: usize,
    pub matches: usize,
    pub misses: usize,
    pub false_positives: usize,
    pub id_switches: usize,
    /// Sum of the matches' distances, m.
    pub distance: f64,
}

impl Mot {
    /// 1 − (misses + false positives + switches) / objects; `None` without objects.
    pub fn mota(&self) -> Option<f64> {
        (self.objects > 0).then(|| {
            1.0 - (self.misses + self.false_positives + self.id_switches) as f64
                / self.objects as f64
        })
    }

    /// Mean distance of the matches, m; `None` without matches.
    pub fn motp(&self) -> Option<f64> {
        (self.matches > 0).then(|| self.distance / self.matches as f64)
    }

    /// The counts with MOTA and MOTP, for summaries.
    pub fn summary(self) -> serde_json::Value {
        serde_json::json!({
            "frames": self.frames,
            "objects": self.objects,
            "matches": self.matches,
            "misses": self.misses,
            "false_positives": self.false_positives,
            "id_switches": self.id_switches,
            "mota": self.mota(),
            "motp_m": self.motp(),
        })
    }
}

/// Scores `frames` in order with matches within `gate` (m).
pub fn clear_mot(frames: &[Frame], gate: f64) -> Mot {
    let mut m = Mot::default();
    // Track id → true id of its last match, and the reverse.
    let mut partner: BTreeMap<u32, u32> = BTreeMap::new();
    let dist = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).hypot(a[1] - b[1]);
    for f in frames {
        m.frames += 1;
        m.objects += f.truth.len();
        let mut matched: Vec<(usize, usize)> = Vec::new();
        // Matches kept from before, while within the gate.
        for (ti, (tid, tp)) in f.tracks.iter().enumerate() {
            if let Some(&gid) = partner.get(tid)
                && let Some(gi) = f.truth.iter().position(|g| g.0 == gid)
                && dist(*tp, f.truth[gi].1) < gate
            {
                matched.push((ti, gi));
            }
        }
        // The rest by least total distance.
        let free_t: Vec<usize> = (0..f.tracks.len())
            .filter(|ti| !matched.iter().any(|m| m.0 == *ti))
            .collect();
        let free_g: Vec<usize> = (0..f.truth.len())
            .filter(|gi| !matched.iter().any(|m| m.1 == *gi))
            .collect();
        let costs: Vec<Vec<f64>> = free_t
            .iter()
            .map(|&ti| {
                free_g
                    .iter()
                    .map(|&gi| dist(f.tracks[ti].1, f.truth[gi].1))
                    .collect()
            })
            .collect();
        for (r, c) in assign(&costs, gate) {
            if costs[r][c] < gate {
                matched.push((free_t[r], free_g[c]));
            }
        }
        m.matches += matched.len();
        m.misses += f.truth.len() - matched.len();
        m.false_positives += f.tracks.len() - matched.len();
        for &(ti, gi) in &matched {
            let (tid, gid) = (f.tracks[ti].0, f.truth[gi].0);
            m.distance += dist(f.tracks[ti].1, f.truth[gi].1);
            let was = partner.get(&tid).copied();
            let followed_by_other = partner.iter().any(|(t, g)| *g == gid && *t != tid);
            if was.is_some_and(|g| g != gid) || (was.is_none() && followed_by_other) {
                m.id_switches += 1;
            }
        }
        // Remember the new matches, dropping older pairs they replace.
        for &(ti, gi) in &matched {
            let (tid, gid) = (f.tracks[ti].0, f.truth[gi].0);
            partner.retain(|t, g| *t != tid && *g != gid);
            partner.insert(tid, gid);
        }
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_hand_counted_sequence_gives_its_counts() {
        let f = |truth: Vec<(u32, [f64; 2])>, tracks: Vec<(u32, [f64; 2])>| Frame { truth, tracks };
        let frames = vec![
            // Track 10 on person 1 (0.1 m off); person 2 missed.
            f(
                vec![(1, [0.0, 0.0]), (2, [5.0, 0.0])],
                vec![(10, [0.1, 0.0])],
            ),
            // Both matched (0.2 and 0.1 m); track 30 is far from anyone: a false positive.
            f(
                vec![(1, [0.0, 0.0]), (2, [5.0, 0.0])],
                vec![(10, [0.2, 0.0]), (20, [5.1, 0.0]), (30, [9.0, 9.0])],
            ),
            // Track 20 jumps to person 1 while track 10 is lost: a switch (person 1 had been
            // followed by 10); person 2 missed.
            f(
                vec![(1, [0.0, 0.0]), (2, [5.0, 0.0])],
                vec![(20, [0.3, 0.0])],
            ),
        ];
        let m = clear_mot(&frames, 0.75);
        assert_eq!(m.frames, 3);
        assert_eq!(m.objects, 6);
        assert_eq!(m.matches, 4);
        assert_eq!(m.misses, 2);
        assert_eq!(m.false_positives, 1);
        assert_eq!(m.id_switches, 1);
        assert!((m.distance - 0.7).abs() < 1e-12);
        assert!((m.mota().unwrap() - (1.0 - 4.0 / 6.0)).abs() < 1e-12);
        assert!((m.motp().unwrap() - 0.175).abs() < 1e-12);
    }

    #[test]
    fn a_kept_match_holds_against_a_nearer_newcomer() {
        // Track 1 follows person 7 at 0.5 m; track 2 appears right on the person. CLEAR-MOT
        // keeps the old pair (no switch) and counts the newcomer as a false positive.
        let frames = vec![
            Frame {
                truth: vec![(7, [0.0, 0.0])],
                tracks: vec![(1, [0.5, 0.0])],
            },
            Frame {
                truth: vec![(7, [0.0, 0.0])],
                tracks: vec![(1, [0.5, 0.0]), (2, [0.0, 0.0])],
            },
        ];
        let m = clear_mot(&frames, 0.75);
        assert_eq!((m.matches, m.false_positives, m.id_switches), (2, 1, 0));
        assert!((m.motp().unwrap() - 0.5).abs() < 1e-12);
    }
}
