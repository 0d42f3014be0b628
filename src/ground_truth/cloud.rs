//! 3D maps against the true surfaces the camera saw, in the Tanks and Temples / ETH3D
//! conventions (`shared/reference/sensors-robot-metrics.md` §7): accuracy (the share of map
//! points within τ of the truth), completeness (the share of true points within τ of the map)
//! and their F1, at τ = 1, 2, 5 and 10 cm; and the mean and median distance of map points to
//! the truth (ICL-NUIM's mean surface error), capped at [`CAP_M`].
//!
//! The truth is a dense cloud of the true surfaces: in a run, each keyframe's depth rendered
//! without noise at the camera's true pose, voxelised like the map. No alignment is searched
//! for: the map is in the world frame.

use futago_robot::geometry::least_squared_distance;
use rustc_hash::FxHashMap;

/// The tolerances, m.
pub const TOLERANCES: [f64; 4] = [0.01, 0.02, 0.05, 0.10];
/// Tolerance names in metric names.
pub const TOLERANCE_NAMES: [&str; 4] = ["1cm", "2cm", "5cm", "10cm"];
/// Distances beyond this count as this, m: a point that far from every seen surface is wrong
/// whatever its distance, and the cap keeps the nearest-point search local.
pub const CAP_M: f64 = 0.10;

/// Scores of a 3D map.
#[derive(Debug, Clone, PartialEq)]
pub struct CloudScore {
    pub accuracy: [f64; 4],
    pub completeness: [f64; 4],
    pub f1: [f64; 4],
    pub mean_distance: f64,
    pub median_distance: f64,
    pub map_points: usize,
    pub truth_points: usize,
}

/// Nearest-point queries within [`CAP_M`] over a hashed grid of cells of that size: a cloud
/// indexed once and queried by every map scored against it (each RGB-D method's map against
/// the same true surfaces).
pub struct CloudIndex {
    /// The cloud's points grouped by cell, each cell's side by side (a query reads its cells'
    /// points in a run, not scattered over the cloud).
    points: Vec<[f64; 3]>,
    /// Each cell's run of `points`.
    cells: FxHashMap<[i64; 3], (u32, u32)>,
}

/// Queries below this many stay on the calling thread.
const SERIAL_BELOW: usize = 4096;

impl CloudIndex {
    /// The index of `points` (at most 2³² − 1 of them: the runs are kept in 32 bits).
    pub fn new(points: &[[f64; 3]]) -> CloudIndex {
        let mut keyed: Vec<([i64; 3], u32)> = points
            .iter()
            .enumerate()
            .map(|(i, p)| (key(p), i as u32))
            .collect();
        keyed.sort_unstable();
        let mut cells: FxHashMap<[i64; 3], (u32, u32)> = FxHashMap::default();
        let mut sorted = Vec::with_capacity(points.len());
        for (k, i) in keyed {
            let at = sorted.len() as u32;
            cells.entry(k).or_insert((at, at)).1 = at + 1;
            sorted.push(points[i as usize]);
        }
        CloudIndex {
            points: sorted,
            cells,
        }
    }

    /// Whether the cloud has no points.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The distance of each of `points` to the nearest point of the cloud, or infinity
    /// beyond [`CAP_M`], in `points`' order; computed on the machine's cores (each distance
    /// its own, so the same whatever their number).
    fn nearest_each(&self, points: &[[f64; 3]]) -> Vec<f64> {
        futago_robot::cores::map_on_cores(points, SERIAL_BELOW, |p| self.nearest(p))
    }

    /// Distance to the nearest point if it is within [`CAP_M`], else infinity.
    ///
    /// Its own cell first, then each of the 26 around it unless the cell's nearest face lies
    /// farther than the nearest point found so far (or than the cap): none of its points could
    /// be nearer. A nanometre of margin covers the roundings of the keys and faces, so the
    /// nearest distance is the one all 27 cells give.
    fn nearest(&self, p: &[f64; 3]) -> f64 {
        let k = key(p);
        let mut best = f64::INFINITY;
        let scan = |cell: [i64; 3], best: &mut f64| {
            if let Some(&(from, to)) = self.cells.get(&cell) {
                // A wall's 10 cm cell holds some hundred points at the maps' voxels: reading
                // them was most of scoring a map (17 % of `office-rgbd-methods`' samples with
                // one running minimum).
                *best = best.min(least_squared_distance(
                    &self.points[from as usize..to as usize],
                    p,
                ));
            }
        };
        scan(k, &mut best);
        // Squared distance from p to the near face of the cell before, its own (0) and the
        // cell after, on each axis.
        let faces = [0, 1, 2].map(|d| {
            let below = p[d] - k[d] as f64 * CAP_M;
            let above = (k[d] + 1) as f64 * CAP_M - p[d];
            [below * below, 0.0, above * above]
        });
        for dx in 0..3 {
            for dy in 0..3 {
                for dz in 0..3 {
                    if (dx, dy, dz) == (1, 1, 1) {
                        continue;
                    }
                    let reach = best.min(CAP_M * CAP_M).sqrt() + 1e-9;
                    if faces[0][dx] + faces[1][dy] + faces[2][dz] > reach * reach {
                        continue;
                    }
                    let o = [dx, dy, dz].map(|o| o as i64 - 1);
                    scan([k[0] + o[0], k[1] + o[1], k[2] + o[2]], &mut best);
                }
            }
        }
        if best <= CAP_M * CAP_M {
            best.sqrt()
        } else {
            f64::INFINITY
        }
    }
}

fn key(p: &[f64; 3]) -> [i64; 3] {
    p.map(|x| (x / CAP_M).floor() as i64)
}

impl CloudScore {
    /// The scores by metric name: `accuracy_1cm`, … `f1_10cm`, `mean_distance_m`,
    /// `median_distance_m`.
    pub fn named(&self) -> Vec<(String, f64)> {
        let mut out = Vec::new();
        for (k, t) in TOLERANCE_NAMES.iter().enumerate() {
            out.push((format!("accuracy_{t}"), self.accuracy[k]));
            out.push((format!("completeness_{t}"), self.completeness[k]));
            out.push((format!("f1_{t}"), self.f1[k]));
        }
        out.push(("mean_distance_m".into(), self.mean_distance));
        out.push(("median_distance_m".into(), self.median_distance));
        out
    }
}

/// The distance of each of `points` to the nearest point of `truth`, capped at [`CAP_M`].
pub fn distances(points: &[[f64; 3]], truth: &CloudIndex) -> Vec<f64> {
    let mut d = truth.nearest_each(points);
    for x in &mut d {
        *x = x.min(CAP_M);
    }
    d
}

/// The thickness of a trace of points along true surfaces: twice the 90th percentile of their
/// distances to the surfaces (the width of the band about the surface that holds 90 % of
/// them); `None` without points. A map whose keyframes disagree draws each wall twice, a few
/// centimetres apart, and its trace thickens (seed 000's Fig. 3.7, method ②).
pub fn thickness(points: &[[f64; 3]], truth: &CloudIndex) -> Option<f64> {
    let mut d = distances(points, truth);
    if d.is_empty() {
        return None;
    }
    d.sort_by(f64::total_cmp);
    let k = ((0.9 * d.len() as f64).ceil() as usize).clamp(1, d.len()) - 1;
    Some(2.0 * d[k])
}

/// Scores `map` against the cloud `truth`; `None` when either is empty.
pub fn score(map: &[[f64; 3]], truth: &CloudIndex) -> Option<CloudScore> {
    if map.is_empty() || truth.is_empty() {
        return None;
    }
    let to_map = CloudIndex::new(map);
    let mut d_map: Vec<f64> = truth.nearest_each(map);
    // Completeness counts the true points near the map, in any order: the index's.
    let d_truth: Vec<f64> = to_map.nearest_each(&truth.points);
    let share = |d: &[f64], t: f64| d.iter().filter(|&&x| x <= t).count() as f64 / d.len() as f64;
    let accuracy = TOLERANCES.map(|t| share(&d_map, t));
    let completeness = TOLERANCES.map(|t| share(&d_truth, t));
    let mut f1 = [0.0; 4];
    for k in 0..4 {
        let (p, r) = (accuracy[k], completeness[k]);
        f1[k] = if p + r > 0.0 {
            2.0 * p * r / (p + r)
        } else {
            0.0
        };
    }
    for d in &mut d_map {
        *d = d.min(CAP_M);
    }
    let mean_distance = d_map.iter().sum::<f64>() / d_map.len() as f64;
    d_map.sort_by(f64::total_cmp);
    let n = d_map.len();
    let median_distance = if n % 2 == 1 {
        d_map[n / 2]
    } else {
        (d_map[n / 2 - 1] + d_map[n / 2]) / 2.0
    };
    Some(CloudScore {
        accuracy,
        completeness,
        f1,
        mean_distance,
        median_distance,
        map_points: map.len(),
        truth_points: truth.points.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The nearest distance read from the cells that may hold a nearer point is the one read
    /// from every point of the cloud: for clouds voxelised finely and coarsely, with points on
    /// the cells' faces and a rounding either side of them, far from the origin too, and with
    /// queries beyond the cap; and the queries on the cores give each query's own.
    #[test]
    fn skipping_cells_beyond_the_nearest_keeps_the_nearest() {
        use rand::{Rng, SeedableRng};
        let every = |cloud: &[[f64; 3]], p: &[f64; 3]| {
            let best = cloud
                .iter()
                .map(|q| (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2))
                .fold(f64::INFINITY, f64::min);
            if best <= CAP_M * CAP_M {
                best.sqrt()
            } else {
                f64::INFINITY
            }
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let coordinate = |rng: &mut rand_chacha::ChaCha8Rng, origin: f64| {
            if rng.random_bool(0.3) {
                // On a face, or an ulp or two off it.
                let face = origin + rng.random_range(-5i32..5) as f64 * CAP_M;
                face + rng.random_range(-2i32..=2) as f64 * f64::EPSILON * face.abs().max(1.0)
            } else {
                origin + rng.random_range(-0.5..0.5)
            }
        };
        let mut beyond = 0;
        for (origin, n) in [(0.0, 300), (0.0, 3000), (1234.5, 2000)] {
            let points: Vec<[f64; 3]> = (0..n)
                .map(|_| [0; 3].map(|_| coordinate(&mut rng, origin)))
                .collect();
            let g = CloudIndex::new(&points);
            let queries: Vec<[f64; 3]> = (0..3000)
                .map(|_| [0; 3].map(|_| coordinate(&mut rng, origin)))
                .collect();
            let each = g.nearest_each(&queries);
            for (p, fast) in queries.iter().zip(each) {
                let slow = every(&points, p);
                assert_eq!(
                    fast.to_bits(),
                    slow.to_bits(),
                    "{p:?}: {fast} against {slow}"
                );
                beyond += usize::from(slow.is_infinite());
            }
        }
        assert!(beyond > 100, "only {beyond} queries beyond the cap");
    }

    #[test]
    fn a_wall_drawn_twice_has_a_thick_trace() {
        // The true wall x = 0; one map draws it on it, another also 3 cm in front.
        let truth = wall(0.0, 20);
        let once = wall(0.002, 20);
        let mut twice = once.clone();
        twice.extend(wall(0.03, 20));
        let truth = CloudIndex::new(&truth);
        let t1 = thickness(&once, &truth).unwrap();
        let t2 = thickness(&twice, &truth).unwrap();
        assert!((t1 - 0.004).abs() < 1e-9, "{t1}");
        assert!((t2 - 0.06).abs() < 1e-9, "{t2}");
        assert_eq!(distances(&[[0.5, 0.5, 0.05]], &truth), vec![CAP_M]);
        assert!(thickness(&[], &truth).is_none());
    }

    /// A 1 m × 1 m wall at x = 0 sampled every 5 mm.
    fn wall(x: f64, rows: usize) -> Vec<[f64; 3]> {
        let mut v = Vec::new();
        for i in 0..rows {
            for j in 0..200 {
                v.push([x, j as f64 * 0.005, i as f64 * 0.005]);
            }
        }
        v
    }

    #[test]
    fn scores_of_hand_made_clouds() {
        let points = wall(0.0, 200);
        let truth = CloudIndex::new(&points);
        // The same wall: perfect.
        let s = score(&points, &truth).unwrap();
        assert_eq!(
            (s.accuracy, s.completeness, s.f1),
            ([1.0; 4], [1.0; 4], [1.0; 4])
        );
        assert_eq!(s.mean_distance, 0.0);
        // Shifted 2.5 cm off, and only its lower half: every map point is 2.5 cm away (fails
        // 1 and 2 cm, passes 5 and 10); completeness is the truth's lower half plus the rows
        // within τ above it.
        let map = wall(0.025, 100);
        let s = score(&map, &truth).unwrap();
        assert_eq!(s.accuracy, [0.0, 0.0, 1.0, 1.0]);
        assert!((s.mean_distance - 0.025).abs() < 1e-12);
        assert!((s.median_distance - 0.025).abs() < 1e-12);
        assert_eq!(s.completeness[0], 0.0);
        // Within 5 cm: rows 0..=99 plus those h above row 99 with 2.5² + h² ≤ 5², h ≤ 4.33 cm:
        // 8 more rows of 5 mm, 108 of 200.
        assert!((s.completeness[2] - 108.0 / 200.0).abs() < 1e-12, "{s:?}");
        let f = 2.0 * 1.0 * 0.54 / 1.54;
        assert!((s.f1[2] - f).abs() < 1e-12);
        // Points far away count as the cap.
        let s = score(&[[10.0, 0.0, 0.0]], &truth).unwrap();
        assert_eq!(s.mean_distance, CAP_M);
        assert_eq!((s.accuracy, s.completeness), ([0.0; 4], [0.0; 4]));
        // 9.9 cm off passes at 10 cm only; 10.1 cm passes nothing.
        let s = score(&wall(0.099, 200), &truth).unwrap();
        assert_eq!(s.accuracy, [0.0, 0.0, 0.0, 1.0]);
        let s = score(&wall(0.101, 200), &truth).unwrap();
        assert_eq!(s.accuracy, [0.0; 4]);
        assert!(score(&[], &truth).is_none());
    }
}
