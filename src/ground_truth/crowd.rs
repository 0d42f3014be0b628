//! Statistics of a crowd's motion, computed the same way from real trajectories (the ETH and
//! UCY sequences) and from the twin's simulated people, so that the two are compared
//! statistic by statistic:
//! - walking speed, mean and spread over the samples of moving people, a sample's speed
//!   being its displacement to the same person's next frame over the frame period;
//! - the share of samples standing (slower than `standing_speed`), and how people stand: how
//!   often a spell of standing begins per second walked, and how long one lasts on average;
//! - each person's distance to their nearest neighbour in each frame with two or more people:
//!   median and 10th percentile;
//! - the share of people who walk with someone (a group): two moving people closer than
//!   `group_distance` whose velocities differ by less than `group_speed`, in frames that add
//!   up to `group_time` or more; and the median distance between such companions;
//! - the density: people per frame over the walkable floor, the cells of side `cell` that
//!   anyone stood in.
//!
//! The thresholds are the usual ones of the crowd literature's measurements: people walking
//! together keep within about 1.5 m and match velocities (Moussaïd et al., "The walking
//! behaviour of pedestrian social groups", PLoS ONE 2010).

use super::trajectory::Stats;
use futago_msgs::pedestrians::Sample;
use std::collections::BTreeMap;

/// The thresholds of [`measure`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct CrowdOptions {
    /// Time between frames, s (ETH and UCY: 0.4 s).
    pub period: f64,
    /// The frame numbers' step per period (ETH and UCY: 10).
    pub frame_step: i64,
    /// Slower than this a person stands, m/s.
    pub standing_speed: f64,
    /// Companions keep within this distance, m.
    pub group_distance: f64,
    /// ... with velocities that differ by less than this, m/s ...
    pub group_speed: f64,
    /// ... for this long in all, s.
    pub group_time: f64,
    /// Side of the cells whose union is the walkable floor, m.
    pub cell: f64,
}

impl Default for CrowdOptions {
    fn default() -> Self {
        CrowdOptions {
            period: 0.4,
            frame_step: 10,
            standing_speed: 0.2,
            group_distance: 1.5,
            group_speed: 0.5,
            group_time: 3.2,
            cell: 1.0,
        }
    }
}

/// What [`measure`] finds.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct CrowdStats {
    pub frames: usize,
    pub people: usize,
    /// People per frame, on average.
    pub mean_count: f64,
    /// The walkable floor, m².
    pub area_m2: f64,
    /// `mean_count / area_m2`, people per m².
    pub density: f64,
    /// Speeds of moving samples: mean and (population) standard deviation, m/s, and how many.
    pub speed_mean: f64,
    pub speed_std: f64,
    pub speed_samples: usize,
    /// The share of samples with a speed that are standing.
    pub standing_fraction: f64,
    /// Spells of standing (a person's consecutive standing samples) begun per second of
    /// moving samples, and their mean length, s.
    pub stop_rate: f64,
    pub stop_time: f64,
    /// Nearest-neighbour distance, m: median and 10th percentile, and how many distances.
    pub nn_median_m: f64,
    pub nn_p10_m: f64,
    pub nn_samples: usize,
    /// The share of people who walk with a companion, and companions' median distance, m.
    pub grouped_fraction: f64,
    pub group_distance_m: f64,
}

/// The crowd statistics of `samples` (sorted by frame, then person, as
/// [`futago_msgs::pedestrians::parse`] returns them). Statistics without data (no moving
/// sample, no frame with two people, no group) are NaN.
pub fn measure(samples: &[Sample], o: &CrowdOptions) -> CrowdStats {
    let frames = by_frame(samples);
    let at: BTreeMap<(i64, i64), [f64; 2]> = samples
        .iter()
        .map(|s| ((s.person, s.frame), s.position))
        .collect();
    let velocity = |s: &Sample| {
        let next = at.get(&(s.person, s.frame.checked_add(o.frame_step)?))?;
        Some([
            (next[0] - s.position[0]) / o.period,
            (next[1] - s.position[1]) / o.period,
        ])
    };
    let mut moving = Vec::new();
    let mut standing = 0usize;
    let mut stood = std::collections::BTreeSet::new();
    let mut nn = Vec::new();
    let mut together: BTreeMap<(i64, i64), (usize, Vec<f64>)> = BTreeMap::new();
    for frame in frames.values() {
        let v: Vec<Option<[f64; 2]>> = frame.iter().map(&velocity).collect();
        for (a, s) in frame.iter().zip(&v) {
            let Some(s) = s else { continue };
            let speed = s[0].hypot(s[1]);
            if speed < o.standing_speed {
                standing += 1;
                stood.insert((a.person, a.frame));
            } else {
                moving.push(speed);
            }
        }
        if frame.len() < 2 {
            continue;
        }
        for (i, a) in frame.iter().enumerate() {
            let mut nearest = f64::INFINITY;
            for (j, b) in frame.iter().enumerate() {
                if i == j {
                    continue;
                }
                let d = distance(a.position, b.position);
                nearest = nearest.min(d);
                if j > i
                    && d < o.group_distance
                    && let (Some(va), Some(vb)) = (v[i], v[j])
                    && va[0].hypot(va[1]) >= o.standing_speed
                    && vb[0].hypot(vb[1]) >= o.standing_speed
                    && (va[0] - vb[0]).hypot(va[1] - vb[1]) < o.group_speed
                {
                    let e = together.entry((a.person, b.person)).or_default();
                    e.0 += 1;
                    e.1.push(d);
                }
            }
            nn.push(nearest);
        }
    }
    let need = (o.group_time / o.period - 1e-9).ceil().max(1.0) as usize;
    let mut grouped = std::collections::BTreeSet::new();
    let mut spacing = Vec::new();
    for ((a, b), (n, d)) in &together {
        if *n >= need {
            grouped.insert(*a);
            grouped.insert(*b);
            spacing.extend(d);
        }
    }
    let people: std::collections::BTreeSet<i64> = samples.iter().map(|s| s.person).collect();
    let cells: std::collections::BTreeSet<(i64, i64)> = samples
        .iter()
        .map(|s| {
            (
                (s.position[0] / o.cell).floor() as i64,
                (s.position[1] / o.cell).floor() as i64,
            )
        })
        .collect();
    let area = cells.len() as f64 * o.cell * o.cell;
    let mean_count = samples.len() as f64 / frames.len().max(1) as f64;
    let nan = f64::NAN;
    let (speed_mean, speed_std) = Stats::of(&moving).map_or((nan, nan), |s| (s.mean, s.std));
    let with_speed = moving.len() + standing;
    // A spell begins at a standing sample whose person did not stand the frame before.
    let spells = stood
        .iter()
        .filter(|&&(p, f)| {
            f.checked_sub(o.frame_step)
                .is_none_or(|before| !stood.contains(&(p, before)))
        })
        .count();
    let moving_time = moving.len() as f64 * o.period;
    CrowdStats {
        frames: frames.len(),
        people: people.len(),
        mean_count,
        area_m2: area,
        density: if area > 0.0 { mean_count / area } else { nan },
        speed_mean,
        speed_std,
        speed_samples: moving.len(),
        standing_fraction: if with_speed > 0 {
            standing as f64 / with_speed as f64
        } else {
            nan
        },
        stop_rate: if moving_time > 0.0 {
            spells as f64 / moving_time
        } else {
            nan
        },
        stop_time: if spells > 0 {
            standing as f64 * o.period / spells as f64
        } else {
            nan
        },
        nn_median_m: Stats::percentile(&nn, 50.0).unwrap_or(nan),
        nn_p10_m: Stats::percentile(&nn, 10.0).unwrap_or(nan),
        nn_samples: nn.len(),
        grouped_fraction: if people.is_empty() {
            nan
        } else {
            grouped.len() as f64 / people.len() as f64
        },
        group_distance_m: Stats::percentile(&spacing, 50.0).unwrap_or(nan),
    }
}

/// The samples of each frame, in frame order.
fn by_frame(samples: &[Sample]) -> BTreeMap<i64, Vec<Sample>> {
    let mut out: BTreeMap<i64, Vec<Sample>> = BTreeMap::new();
    for s in samples {
        out.entry(s.frame).or_default().push(*s);
    }
    out
}

fn distance(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(frame: i64, person: i64, x: f64, y: f64) -> Sample {
        Sample {
            frame,
            person,
            position: [x, y],
        }
    }

    /// Two companions walk abreast 0.8 m apart along x at 1 m/s for ten frames while a third
    /// stands 3 m away: every figure follows by hand.
    #[test]
    fn a_pair_and_a_stander_by_hand() {
        let o = CrowdOptions::default();
        let mut s = Vec::new();
        for k in 0..10 {
            let x = 0.4 * k as f64;
            s.push(sample(10 * k, 1, x, 0.0));
            s.push(sample(10 * k, 2, x, 0.8));
            s.push(sample(10 * k, 3, 0.0, 3.8));
        }
        s.sort_by_key(|s| (s.frame, s.person));
        let m = measure(&s, &o);
        assert_eq!((m.frames, m.people), (10, 3));
        assert_eq!(m.mean_count, 3.0);
        // Nine steps of 0.4 m in 0.4 s for each walker: 18 moving samples at 1 m/s; the
        // stander's 9 samples are standing.
        assert_eq!(m.speed_samples, 18);
        assert!((m.speed_mean - 1.0).abs() < 1e-9 && m.speed_std < 1e-9);
        assert!((m.standing_fraction - 9.0 / 27.0).abs() < 1e-12);
        // One spell of standing, 9 samples (3.6 s) long, over 18 moving samples (7.2 s).
        assert!((m.stop_rate - 1.0 / 7.2).abs() < 1e-12);
        assert!((m.stop_time - 3.6).abs() < 1e-12);
        // The walkers are each other's nearest at 0.8 m in every frame (20 of 30 distances);
        // the stander's nearest is 3 m or more away.
        assert_eq!(m.nn_samples, 30);
        assert!((m.nn_median_m - 0.8).abs() < 1e-9);
        assert!((m.nn_p10_m - 0.8).abs() < 1e-9);
        // Nine frames abreast with velocities (3.6 s ≥ 3.2 s): two of three people grouped.
        assert!((m.grouped_fraction - 2.0 / 3.0).abs() < 1e-12);
        assert!((m.group_distance_m - 0.8).abs() < 1e-9);
        // Cells of 1 m: x from 0 to 3.6 in rows y = 0 and 0.8 (both row 0): 4 cells, and the
        // stander's one: 5 m².
        assert_eq!(m.area_m2, 5.0);
        assert!((m.density - 0.6).abs() < 1e-12);
    }

    /// A walker who stops twice, for one and then three frames: two spells, four standing
    /// samples between them, over the frames they walk.
    #[test]
    fn spells_of_standing_are_counted_and_timed() {
        let o = CrowdOptions::default();
        // Positions frame by frame: walk, stand 1 frame, walk 2, stand 3, walk 1.
        let xs = [0.0, 0.4, 0.4, 0.8, 1.2, 1.2, 1.2, 1.2, 1.6];
        let s: Vec<Sample> = (xs.iter().enumerate())
            .map(|(k, &x)| sample(10 * k as i64, 1, x, 0.0))
            .collect();
        let m = measure(&s, &o);
        assert!((m.standing_fraction - 4.0 / 8.0).abs() < 1e-12);
        assert!((m.stop_rate - 2.0 / (4.0 * 0.4)).abs() < 1e-12);
        assert!((m.stop_time - 2.0 * 0.4).abs() < 1e-12);
    }

    #[test]
    fn companions_for_too_short_a_time_are_no_group() {
        let o = CrowdOptions::default();
        let mut s = Vec::new();
        // Eight frames: seven velocities, 2.8 s < 3.2 s.
        for k in 0..8 {
            let x = 0.4 * k as f64;
            s.push(sample(10 * k, 1, x, 0.0));
            s.push(sample(10 * k, 2, x, 0.8));
        }
        let m = measure(&s, &o);
        assert_eq!(m.grouped_fraction, 0.0);
        assert!(m.group_distance_m.is_nan());
        // Walking in opposite directions is no group either, however close.
        let mut s = Vec::new();
        for k in 0..20 {
            let x = 0.4 * k as f64;
            s.push(sample(10 * k, 1, x, 0.0));
            s.push(sample(10 * k, 2, 8.0 - x, 0.8));
        }
        s.sort_by_key(|s| (s.frame, s.person));
        assert_eq!(measure(&s, &o).grouped_fraction, 0.0);
    }

    #[test]
    fn a_gap_in_a_track_gives_no_speed_and_one_person_no_distance() {
        let o = CrowdOptions::default();
        let s = vec![sample(0, 1, 0.0, 0.0), sample(20, 1, 5.0, 0.0)];
        let m = measure(&s, &o);
        assert!(m.speed_mean.is_nan() && m.standing_fraction.is_nan());
        assert!(m.nn_median_m.is_nan() && m.nn_samples == 0);
    }
}
