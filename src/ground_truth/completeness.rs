//! How much of the world's true surfaces a point-cloud map holds: the completeness of 3D
//! reconstruction benchmarks (a true surface point counts when a map point lies within a
//! tolerance of it; ETH3D and Tanks and Temples score it so), weighted by area, per surface
//! class ([`Surfaces`]: floor, walls, furniture). Maps grow by adding points; the share can be
//! read after each addition, which gives coverage against scans and travel.

use super::coverage::{CLASSES, Surfaces};
use rustc_hash::FxHashMap;

/// The completeness of a growing map against a set of true surfaces.
pub struct Completeness {
    /// Each surface voxel's centre and area per class.
    voxels: Vec<([f64; 3], [f64; 3])>,
    covered: Vec<bool>,
    /// Surface voxels by cell of side `tolerance`.
    cells: FxHashMap<[i64; 3], Vec<u32>>,
    tolerance: f64,
    total: [f64; 3],
    got: [f64; 3],
}

impl Completeness {
    /// Scores against `surfaces`, a surface voxel counting once a point lies within
    /// `tolerance` (m) of its centre.
    pub fn new(surfaces: &Surfaces, tolerance: f64) -> Completeness {
        let mut voxels: Vec<([f64; 3], [f64; 3])> = surfaces.voxels().collect();
        // A fixed order, whatever the hash map's.
        voxels.sort_by(|a, b| {
            a.0.iter()
                .zip(&b.0)
                .map(|(x, y)| x.total_cmp(y))
                .find(|o| o.is_ne())
                .unwrap_or(std::cmp::Ordering::Equal)
        });
        let mut cells: FxHashMap<[i64; 3], Vec<u32>> = FxHashMap::default();
        for (i, (c, _)) in voxels.iter().enumerate() {
            cells
                .entry(c.map(|x| (x / tolerance).floor() as i64))
                .or_default()
                .push(i as u32);
        }
        let mut total = [0.0; 3];
        for (_, a) in &voxels {
            for (t, x) in total.iter_mut().zip(a) {
                *t += x;
            }
        }
        Completeness {
            covered: vec![false; voxels.len()],
            voxels,
            cells,
            tolerance,
            total,
            got: [0.0; 3],
        }
    }

    /// Adds map points (m, world frame).
    pub fn add(&mut self, points: impl IntoIterator<Item = [f64; 3]>) {
        let t = self.tolerance;
        for p in points {
            let c = p.map(|x| (x / t).floor() as i64);
            for dz in -1..=1 {
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let Some(list) = self.cells.get(&[c[0] + dx, c[1] + dy, c[2] + dz]) else {
                            continue;
                        };
                        for &i in list {
                            let i = i as usize;
                            if self.covered[i] {
                                continue;
                            }
                            let (v, a) = &self.voxels[i];
                            let d2 = (0..3).map(|k| (v[k] - p[k]).powi(2)).sum::<f64>();
                            if d2 <= t * t {
                                self.covered[i] = true;
                                for (g, x) in self.got.iter_mut().zip(a) {
                                    *g += x;
                                }
                            }
                        }
                    }
                }
            }
        }
    }

    /// The covered share of all the surfaces' area (0 when there is none).
    pub fn share(&self) -> f64 {
        let all: f64 = self.total.iter().sum();
        if all > 0.0 {
            self.got.iter().sum::<f64>() / all
        } else {
            0.0
        }
    }

    /// The covered share of each class's area, by [`CLASSES`] name (classes the world lacks
    /// left out).
    pub fn shares(&self) -> Vec<(&'static str, f64)> {
        (0..3)
            .filter(|&k| self.total[k] > 0.0)
            .map(|k| (CLASSES[k], self.got[k] / self.total[k]))
            .collect()
    }

    /// The surfaces' area, m².
    pub fn area(&self) -> f64 {
        self.total.iter().sum()
    }
}

/// How [`length_along`] finds a surface on its line.
#[derive(Debug, Clone, Copy)]
pub struct LengthProbe {
    /// Points within this of the line belong to it, m ...
    pub radius: f64,
    /// ... or within this much per metre of their distance along it from `from`, where that
    /// is more (a cylinder that opens into a cone): a laser's points on a surface thin out as
    /// the square of its range, so a fixed disc that holds a near wall's points holds one or
    /// two of a far wall's.
    pub spread: f64,
    /// The projections of one surface gather within this, m ...
    pub window: f64,
    /// ... at least this many of them.
    pub min_points: usize,
}

/// A length measured in a point cloud along a line: the distance between the first surfaces
/// the line meets on either side of `from` (the seed's L1 and L2, say a corridor's width).
///
/// On each side the points within `max(probe.radius, probe.spread * t)` of the line, `t`
/// their distance along it from `from`, are projected onto it; the surface is the first run of at
/// least `probe.min_points` projections within `probe.window` of each other, its place the
/// median of the points within the window of that run's median. `None` when a side has no
/// such run.
pub fn length_along(
    points: &[[f64; 3]],
    from: [f64; 3],
    direction: [f64; 3],
    probe: LengthProbe,
) -> Option<f64> {
    let n = direction.iter().map(|d| d * d).sum::<f64>().sqrt();
    if !(n.is_finite() && n > 0.0) {
        return None;
    }
    let u = direction.map(|d| d / n);
    let (mut ahead, mut behind) = (Vec::new(), Vec::new());
    for p in points {
        let v = [p[0] - from[0], p[1] - from[1], p[2] - from[2]];
        let t = v[0] * u[0] + v[1] * u[1] + v[2] * u[2];
        let off2 = v.iter().map(|c| c * c).sum::<f64>() - t * t;
        let reach = probe.radius.max(probe.spread * t.abs());
        if off2 <= reach * reach {
            if t >= 0.0 {
                ahead.push(t);
            } else {
                behind.push(-t);
            }
        }
    }
    let (w, k) = (probe.window, probe.min_points);
    Some(first_surface(ahead, w, k)? + first_surface(behind, w, k)?)
}

/// The nearest surface among distances along a ray (see [`length_along`]).
fn first_surface(mut t: Vec<f64>, window: f64, min_points: usize) -> Option<f64> {
    t.sort_by(f64::total_cmp);
    let median = |s: &[f64]| s[s.len() / 2];
    let start = (0..t.len()).find(|&i| {
        let end = t.partition_point(|x| *x <= t[i] + window);
        end - i >= min_points.max(1)
    })?;
    let end = t.partition_point(|x| *x <= t[start] + window);
    let m = median(&t[start..end]);
    let (a, b) = (
        t.partition_point(|x| *x < m - window / 2.0),
        t.partition_point(|x| *x <= m + window / 2.0),
    );
    Some(median(&t[a..b]))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 2 × 1 m floor and a 2 × 1 m wall; points every 2 cm on the floor's half x < 1 m
    /// cover its voxels whose centres lie within 0.1 m of them: x up to 1.1 m, 55 % of the
    /// floor, none of the wall (which stands 0.5 m off). Adding the same points again
    /// changes nothing.
    #[test]
    fn completeness_counts_the_area_within_tolerance_of_a_point() {
        let floor = [
            ([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [2.0, 1.0, 0.0]], 0),
            ([[0.0, 0.0, 0.0], [2.0, 1.0, 0.0], [0.0, 1.0, 0.0]], 0),
        ];
        let wall = [
            ([[0.0, 1.5, 0.0], [2.0, 1.5, 0.0], [2.0, 1.5, 1.0]], 1),
            ([[0.0, 1.5, 0.0], [2.0, 1.5, 1.0], [0.0, 1.5, 1.0]], 1),
        ];
        let s = Surfaces::from_triangles(&[floor[0], floor[1], wall[0], wall[1]]);
        let mut c = Completeness::new(&s, 0.1);
        assert!((c.area() - 4.0).abs() < 1e-6, "{}", c.area());
        assert_eq!(c.share(), 0.0);
        let points: Vec<[f64; 3]> = (0..50)
            .flat_map(|i| (0..50).map(move |j| [i as f64 * 0.02, j as f64 * 0.02, 0.0]))
            .collect();
        c.add(points.iter().copied());
        let by = c.shares();
        let floor_share = by.iter().find(|(n, _)| *n == "floor").unwrap().1;
        let wall_share = by.iter().find(|(n, _)| *n == "walls").unwrap().1;
        assert!((floor_share - 0.55).abs() < 0.02, "{floor_share}");
        assert_eq!(wall_share, 0.0);
        assert!((c.share() - floor_share / 2.0).abs() < 1e-9);
        let before = c.share();
        c.add(points);
        assert_eq!(c.share(), before);
    }

    /// Two walls 2.12 m apart (y = ±1.06) sampled with ±1 cm of noise, stray points nearer
    /// (a person's leg at y = 0.5, three points) and farther (behind the wall): the length
    /// is the walls' distance within the noise; the stray points are too few to be a
    /// surface.
    #[test]
    fn a_length_is_measured_between_the_first_surfaces() {
        let mut pts = Vec::new();
        for k in 0..400 {
            let x = -0.2 + 0.001 * k as f64;
            let z = 0.5 + 0.002 * k as f64;
            let noise = 0.01 * ((k * 7919 % 21) as f64 / 10.0 - 1.0);
            pts.push([x, 1.06 + noise, z]);
            pts.push([x, -1.06 - noise, z]);
            pts.push([x, 3.0, z]);
        }
        pts.extend([[0.0, 0.5, 1.0], [0.01, 0.5, 1.0], [0.0, 0.51, 1.01]]);
        let probe = LengthProbe {
            radius: 0.15,
            spread: 0.0,
            window: 0.08,
            min_points: 10,
        };
        let l = length_along(&pts, [0.0, 0.0, 1.0], [0.0, 2.0, 0.0], probe).unwrap();
        assert!((l - 2.12).abs() < 0.005, "{l}");
        // Nothing on one side: no length.
        let half: Vec<[f64; 3]> = pts.iter().filter(|p| p[1] > 0.0).copied().collect();
        assert!(length_along(&half, [0.0, 0.0, 1.0], [0.0, 1.0, 0.0], probe).is_none());
        assert!(length_along(&pts, [0.0; 3], [0.0; 3], probe).is_none());
    }

    /// A wall 1 m to the left sampled every 1 cm and one 7 m to the right sampled as a
    /// turntable laser leaves it there, a point per 10 cm across and 6 cm up, none on the
    /// line: a 5 cm cylinder holds two of the far wall's points, too few for a surface, and
    /// the length goes unmeasured; a reach of 2 cm a metre beyond 2.5 m (14 cm at 7 m) holds
    /// about ten and measures the 8 m between the walls.
    #[test]
    fn a_far_walls_sparse_points_are_found_by_a_reach_that_spreads() {
        let mut pts = Vec::new();
        for i in -30..30 {
            for j in -10..10 {
                let (x, z) = (0.03 + 0.1 * i as f64, 1.53 + 0.06 * j as f64);
                pts.push([x, -7.0, z]);
            }
        }
        for i in -100..100 {
            for j in -100..100 {
                pts.push([0.01 * i as f64, 1.0, 1.5 + 0.01 * j as f64]);
            }
        }
        let cylinder = LengthProbe {
            radius: 0.05,
            spread: 0.0,
            window: 0.08,
            min_points: 3,
        };
        let (from, along) = ([0.0, 0.0, 1.5], [0.0, 1.0, 0.0]);
        assert!(length_along(&pts, from, along, cylinder).is_none());
        let cone = LengthProbe {
            spread: 0.02,
            ..cylinder
        };
        let l = length_along(&pts, from, along, cone).unwrap();
        assert!((l - 8.0).abs() < 1e-9, "{l}");
    }
}
