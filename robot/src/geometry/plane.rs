//! Planes in point clouds: least-squares fits (a plane's Hesse form, and the normal of any
//! dimension's best-fit hyperplane by PCA) and RANSAC (Fischler & Bolles 1981), as seed 000
//! detects the floor (§3.1.1) and the planes it polygonises (§3.2.1).
//!
//! The thesis writes a plane as `a x + b y + c z = 1`, which cannot hold a plane through the
//! origin; here a plane is in Hesse normal form, `n · p + d = 0` with `|n| = 1`, which holds
//! every plane and gives point distances directly. The refit minimises the squared distances of
//! the inliers, solved by the eigendecomposition of their scatter matrix (the SVD of the
//! centred points, as the thesis does).

use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use rand::Rng;
use serde::{Deserialize, Serialize};

/// A plane `normal · p + offset = 0`, `normal` of unit length.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    pub normal: [f64; 3],
    pub offset: f64,
}

impl Plane {
    /// The plane through three points; `None` when they are (nearly) collinear.
    pub fn through(a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> Option<Plane> {
        let (a, b, c) = (Vector3::from(a), Vector3::from(b), Vector3::from(c));
        let n = (b - a).cross(&(c - a));
        let len = n.norm();
        if len < 1e-12 {
            return None;
        }
        let n = n / len;
        Some(Plane {
            normal: n.into(),
            offset: -n.dot(&a),
        })
    }

    /// Signed distance of `p` from the plane (positive on the normal's side).
    pub fn distance(&self, p: [f64; 3]) -> f64 {
        self.normal[0] * p[0] + self.normal[1] * p[1] + self.normal[2] * p[2] + self.offset
    }

    /// The same plane with its normal turned to the side of `towards` (a direction).
    pub fn facing(self, towards: [f64; 3]) -> Plane {
        let dot: f64 = (0..3).map(|k| self.normal[k] * towards[k]).sum();
        if dot < 0.0 {
            Plane {
                normal: self.normal.map(|v| -v),
                offset: -self.offset,
            }
        } else {
            self
        }
    }

    /// The least-squares plane of `points` (at least three, not all on a line): through their
    /// centroid, normal along the scatter's smallest eigenvector.
    pub fn fit(points: &[[f64; 3]]) -> Option<Plane> {
        if points.len() < 3 {
            return None;
        }
        let n = points.len() as f64;
        let c = points
            .iter()
            .fold(Vector3::zeros(), |s, p| s + Vector3::from(*p))
            / n;
        let mut scatter = Matrix3::zeros();
        for p in points {
            let d = Vector3::from(*p) - c;
            scatter += d * d.transpose();
        }
        let eig = SymmetricEigen::new(scatter);
        let (k, _) = eig
            .eigenvalues
            .iter()
            .enumerate()
            .min_by(|a, b| a.1.total_cmp(b.1))?;
        // Degenerate (collinear) sets have two zero eigenvalues.
        let mut sorted: Vec<f64> = eig.eigenvalues.iter().copied().collect();
        sorted.sort_by(f64::total_cmp);
        if sorted[1] <= 1e-12 * sorted[2].max(1e-300) {
            return None;
        }
        let normal = eig.eigenvectors.column(k).normalize();
        Some(Plane {
            normal: normal.into(),
            offset: -normal.dot(&c),
        })
    }
}

/// Parameters of a RANSAC plane search (seed 000 §3.1.1).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RansacConfig {
    /// Points drawn from the cloud to search in (seed 000: 1000).
    pub samples: usize,
    /// Hypotheses tried (seed 000: 1000).
    pub iterations: usize,
    /// Largest distance of an inlier, m (seed 000: 1 cm).
    pub inlier_distance: f64,
    /// Fewest inliers among the samples for a plane to count (the thesis: "very few" fails;
    /// unstated, chosen here).
    pub min_inliers: usize,
}

impl RansacConfig {
    /// Checks every field; the error names the key below `prefix`.
    pub fn validate(&self, prefix: &str) -> Result<(), crate::config::ConfigError> {
        crate::config::check_counts(
            prefix,
            &[
                ("samples", self.samples, 3, 1_000_000),
                ("iterations", self.iterations, 1, 1_000_000),
                ("min_inliers", self.min_inliers, 3, 1_000_000),
            ],
        )?;
        crate::config::check_ranges(
            prefix,
            &[("inlier_distance", self.inlier_distance, 1e-5, 10.0)],
        )
    }
}

impl Default for RansacConfig {
    fn default() -> Self {
        RansacConfig {
            samples: 1000,
            iterations: 1000,
            inlier_distance: 0.01,
            min_inliers: 100,
        }
    }
}

/// A plane found by RANSAC, refitted to its inliers, and the inliers' indices in the cloud.
#[derive(Debug, Clone, PartialEq)]
pub struct Found {
    pub plane: Plane,
    pub inliers: Vec<usize>,
}

/// Searches `cloud` for the plane with the most inliers among `config.samples` points drawn
/// from it, trying only planes that `accept` (a constraint such as "roughly horizontal"), then
/// refits the plane to all its inliers in the whole cloud. `None` when no plane gathers
/// `min_inliers` of the samples.
pub fn ransac(
    cloud: &[[f64; 3]],
    config: &RansacConfig,
    accept: impl Fn(&Plane) -> bool,
    rng: &mut impl Rng,
) -> Option<Found> {
    if cloud.len() < 3 {
        return None;
    }
    let sample: Vec<[f64; 3]> = if cloud.len() <= config.samples {
        cloud.to_vec()
    } else {
        (0..config.samples)
            .map(|_| cloud[rng.random_range(0..cloud.len())])
            .collect()
    };
    let mut best: Option<(usize, Plane)> = None;
    for _ in 0..config.iterations {
        let pick = |rng: &mut _| sample[Rng::random_range(rng, 0..sample.len())];
        let Some(h) = Plane::through(pick(rng), pick(rng), pick(rng)) else {
            continue;
        };
        if !accept(&h) {
            continue;
        }
        let votes = sample
            .iter()
            .filter(|p| h.distance(**p).abs() <= config.inlier_distance)
            .count();
        if best.is_none_or(|(v, _)| votes > v) {
            best = Some((votes, h));
        }
    }
    let (votes, h) = best?;
    if votes < config.min_inliers.min(sample.len()) {
        return None;
    }
    // Refit to the hypothesis' inliers in the whole cloud, then gather the refit's inliers.
    let near: Vec<[f64; 3]> = cloud
        .iter()
        .copied()
        .filter(|p| h.distance(*p).abs() <= config.inlier_distance)
        .collect();
    let plane = Plane::fit(&near).unwrap_or(h);
    let plane = if accept(&plane) { plane } else { h };
    let inliers = (0..cloud.len())
        .filter(|&i| plane.distance(cloud[i]).abs() <= config.inlier_distance)
        .collect();
    Some(Found { plane, inliers })
}

/// Planes one after another (seed 000 §3.2.1): find the best plane, take its inliers out,
/// search again, until no plane is found or `max_planes` are.
pub fn ransac_all(
    cloud: &[[f64; 3]],
    config: &RansacConfig,
    max_planes: usize,
    rng: &mut impl Rng,
) -> Vec<Found> {
    let mut left: Vec<usize> = (0..cloud.len()).collect();
    let mut out = Vec::new();
    while out.len() < max_planes {
        let points: Vec<[f64; 3]> = left.iter().map(|&i| cloud[i]).collect();
        let Some(f) = ransac(&points, config, |_| true, rng) else {
            break;
        };
        let taken: Vec<usize> = f.inliers.iter().map(|&k| left[k]).collect();
        let mut is_taken = vec![false; points.len()];
        for &k in &f.inliers {
            is_taken[k] = true;
        }
        left = left
            .iter()
            .zip(&is_taken)
            .filter(|(_, t)| !**t)
            .map(|(i, _)| *i)
            .collect();
        out.push(Found {
            plane: f.plane,
            inliers: taken,
        });
    }
    out
}

/// The unit normal of the least-squares plane through `points` (the scatter's eigenvector
/// of least eigenvalue), or `None` when they do not span a plane.
pub fn pca_normal<const K: usize>(points: &[[f64; K]]) -> Option<[f64; K]> {
    if points.len() < K {
        return None;
    }
    let n = points.len() as f64;
    let mut mean = [0.0; K];
    for p in points {
        for k in 0..K {
            mean[k] += p[k] / n;
        }
    }
    let mut m = nalgebra::DMatrix::<f64>::zeros(K, K);
    for p in points {
        for a in 0..K {
            for b in 0..K {
                m[(a, b)] += (p[a] - mean[a]) * (p[b] - mean[b]);
            }
        }
    }
    let e = m.symmetric_eigen();
    let (mut lo, mut hi) = (0, 0);
    for k in 1..K {
        if e.eigenvalues[k] < e.eigenvalues[lo] {
            lo = k;
        }
        if e.eigenvalues[k] > e.eigenvalues[hi] {
            hi = k;
        }
    }
    // A line or a blob: the smallest spread must be well below the others.
    if e.eigenvalues[hi].is_nan() || e.eigenvalues[hi] <= 0.0 {
        return None;
    }
    let mut out = [0.0; K];
    for (k, o) in out.iter_mut().enumerate() {
        *o = e.eigenvectors[(k, lo)];
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    /// Points on `z = 0.3 x - 0.1 y + 2` in a 2 m square, with Gaussian noise along z.
    fn tilted(n: usize, noise: f64, rng: &mut ChaCha8Rng) -> Vec<[f64; 3]> {
        let g = Normal::new(0.0, noise.max(1e-300)).unwrap();
        (0..n)
            .map(|_| {
                let (x, y) = (rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
                [x, y, 0.3 * x - 0.1 * y + 2.0 + g.sample(rng)]
            })
            .collect()
    }

    #[test]
    fn a_fit_recovers_a_plane_written_by_hand() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let p = Plane::fit(&tilted(500, 0.0, &mut rng))
            .unwrap()
            .facing([0.0, 0.0, 1.0]);
        // z = 0.3x − 0.1y + 2 ⇔ (−0.3, 0.1, 1)·p − 2 = 0, normalised by √1.1.
        let s = 1.1f64.sqrt();
        let want = [-0.3 / s, 0.1 / s, 1.0 / s];
        for (got, want) in p.normal.iter().zip(want) {
            assert!((got - want).abs() < 1e-9, "{p:?}");
        }
        assert!((p.offset + 2.0 / s).abs() < 1e-9);
        assert!(Plane::fit(&[[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]]).is_none());
        assert!(Plane::through([0.0; 3], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]).is_none());
    }

    #[test]
    fn ransac_finds_the_plane_among_outliers_and_obeys_its_constraint() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let mut cloud = tilted(3000, 0.003, &mut rng);
        let plane_points = cloud.len();
        // A vertical wall (x = 0.5) with more points than the tilted plane, and clutter.
        for _ in 0..4000 {
            cloud.push([0.5, rng.random_range(-1.0..1.0), rng.random_range(0.0..3.0)]);
        }
        for _ in 0..1000 {
            cloud.push([
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(0.0..4.0),
            ]);
        }
        let config = RansacConfig::default();
        // Unconstrained, the wall wins.
        let any = ransac(&cloud, &config, |_| true, &mut rng).unwrap();
        assert!(any.plane.normal[0].abs() > 0.999, "{:?}", any.plane);
        // Constrained to roughly horizontal planes (within 30° of z), the tilted plane wins.
        let up = |p: &Plane| p.normal[2].abs() > 30f64.to_radians().cos();
        let f = ransac(&cloud, &config, up, &mut rng).unwrap();
        let p = f.plane.facing([0.0, 0.0, 1.0]);
        let s = 1.1f64.sqrt();
        assert!((p.normal[2] - 1.0 / s).abs() < 2e-3, "{p:?}");
        assert!((p.offset + 2.0 / s).abs() < 5e-3, "{p:?}");
        // Nearly all the plane's points are inliers; few others are.
        let on_plane = f.inliers.iter().filter(|&&i| i < plane_points).count();
        assert!(on_plane as f64 > 0.95 * plane_points as f64, "{on_plane}");
        assert!(f.inliers.len() - on_plane < 200, "{}", f.inliers.len());
        // No plane in pure clutter.
        let clutter: Vec<[f64; 3]> = cloud[plane_points + 4000..].to_vec();
        assert!(ransac(&clutter, &config, |_| true, &mut rng).is_none());
    }

    #[test]
    fn planes_come_out_one_after_another() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut cloud = Vec::new();
        // Floor z = 0, wall x = 2, door y = 1.5, each 1500 points.
        for _ in 0..1500 {
            let (a, b) = (rng.random_range(0.0..2.0), rng.random_range(0.0..1.5));
            cloud.push([a, b, 0.0]);
            cloud.push([2.0, b, a]);
            cloud.push([a, 1.5, b + 0.2]);
        }
        let found = ransac_all(&cloud, &RansacConfig::default(), 10, &mut rng);
        assert_eq!(found.len(), 3, "{found:?}");
        let mut axes: Vec<usize> = found
            .iter()
            .map(|f| {
                (0..3)
                    .max_by(|&i, &j| f.plane.normal[i].abs().total_cmp(&f.plane.normal[j].abs()))
                    .unwrap()
            })
            .collect();
        axes.sort();
        assert_eq!(axes, vec![0, 1, 2]);
        let total: usize = found.iter().map(|f| f.inliers.len()).sum();
        assert!((4400..=4500).contains(&total), "{total}");
    }

    #[test]
    fn pca_normal_of_a_plane_and_of_a_line() {
        let pts: Vec<[f64; 3]> = (0..20)
            .map(|k| [k as f64 * 0.1, (k % 5) as f64 * 0.1, 0.5])
            .collect();
        let n = pca_normal(&pts).unwrap();
        assert!((n[2].abs() - 1.0).abs() < 1e-9, "{n:?}");
        let line: Vec<[f64; 2]> = (0..5).map(|k| [1.0, k as f64]).collect();
        let n = pca_normal(&line).unwrap();
        assert!((n[0].abs() - 1.0).abs() < 1e-9, "{n:?}");
        assert!(pca_normal(&[[0.0, 0.0, 0.0]; 2]).is_none());
    }
}
