//! Registration of RGB-D keyframes over (x, y, yaw) (seed 000 §3.1.2, written for futago):
//! the extended RGBD-ICP, the variants of the thesis's Fig. 3.7, and a modern baseline.
//!
//! Every keyframe has been levelled by its floor ([`crate::perception::floor`]), so its height, pitch and
//! roll are fixed and its points are in the robot's base frame; a robot pose (x, y, yaw)
//! places them in the world. The methods differ in how they correct the robot's 2D pose:
//!
//! - [`Method::Pose`] (①): the robot's pose as it is.
//! - [`Method::Map`] (②): each keyframe alone, its laser-height points (M_s) against the 2D
//!   map, point to plane.
//! - [`Method::RgbdIcp`] (③, Henry et al.'s RGBD-ICP): image features point to point (A_f)
//!   and a quarter of the cloud point to plane (A_p) against the best of the last few
//!   registered keyframes; errors can accumulate.
//! - [`Method::Full`] (④, the thesis's method): all three terms,
//!   `e = α·mean|t(f_s) − f_t|² + β·mean((t(p_s) − p_t)·n)² + γ·mean((t(m_s) − m_t)·n)²`,
//!   α, β, γ = 0.3, 0.3, 0.4.
//! - [`Method::IcpGraph`] (a modern baseline, as in Open3D's reconstruction pipeline or
//!   Choi et al. 2015): point-to-plane ICP between consecutive keyframes and between keyframes
//!   that revisit a place, and a pose graph over these edges and the robot's poses (as priors),
//!   solved by [`crate::mapping::pose_graph`].
//!
//! Each ICP iteration matches (k-d trees from `kiddo`), then takes Levenberg–Marquardt steps
//! `x ← x − (JᵀJ + λI)⁻¹ Jᵀf` with the matches fixed, until the step is below `tolerance` or
//! `max_iterations` is reached. Every term is started from the robot's pose, as in the thesis.

use crate::geometry::plane::pca_normal;
use crate::mapping::pose_graph::{Edge, OptimizeOptions, PoseGraph};
use crate::perception::features::{Descriptor, FeatureConfig};
use futago_msgs::grid::OccupancyGrid;
use futago_msgs::{Pose2, wrap_angle};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::num::NonZero;

/// How keyframes are placed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// ① The robot's 2D pose, no registration.
    Pose,
    /// ② The 2D-map term only.
    Map,
    /// ③ RGBD-ICP without the map: features and cloud against recent keyframes.
    RgbdIcp,
    /// ④ The extended RGBD-ICP: features, cloud and map.
    Full,
    /// Baseline: point-to-plane ICP edges and the robot's poses in a pose graph.
    IcpGraph,
}

impl Method {
    pub const ALL: [Method; 5] = [
        Method::Pose,
        Method::Map,
        Method::RgbdIcp,
        Method::Full,
        Method::IcpGraph,
    ];

    /// The name used in scenario files and metric names.
    pub fn name(self) -> &'static str {
        match self {
            Method::Pose => "pose",
            Method::Map => "map",
            Method::RgbdIcp => "rgbd_icp",
            Method::Full => "full",
            Method::IcpGraph => "icp_graph",
        }
    }
}

/// Parameters of the registration. The thesis states α, β, γ and the quarter sample; the
/// rest it leaves open, and the values here are chosen for the Kinect at 0.5 m keyframes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RegistrationConfig {
    /// Weight of the feature term (α).
    pub alpha: f64,
    /// Weight of the cloud term (β).
    pub beta: f64,
    /// Weight of the 2D-map term (γ).
    pub gamma: f64,
    /// P_s takes every `cloud_step`-th point (4: "about a quarter, uniformly").
    pub cloud_step: usize,
    /// M_s: points within this of the laser's height, m.
    pub map_band: f64,
    /// Candidate target keyframes: this many before the input.
    pub target_frames: usize,
    /// Cloud pairs farther apart are refused, m.
    pub max_cloud_pair: f64,
    /// Map pairs farther apart are refused, m.
    pub max_map_pair: f64,
    /// Neighbours of a point for its PCA normal.
    pub normal_neighbours: usize,
    /// Image features.
    pub features: FeatureConfig,
    /// RANSAC over feature matches: hypotheses.
    pub feature_ransac_iterations: usize,
    /// RANSAC over feature matches: inlier distance, m.
    pub feature_inlier: f64,
    /// Fewer feature inliers than this and the feature term is left out.
    pub min_feature_inliers: usize,
    /// ICP iterations (match, then minimise) at most.
    pub max_iterations: usize,
    /// Stop when a step moves less than this (m, and rad per metre).
    pub tolerance: f64,
    /// Directions whose eigenvalue of JᵀJ is below this are not stepped in (0: all are).
    pub degenerate: f64,
    /// A registration that moves a keyframe farther than this from the robot's pose is taken
    /// for a failure (a slide along a corridor, a wrong match) and the robot's pose is kept, m.
    pub max_correction: f64,
    /// The same for the turn, rad.
    pub max_correction_turn: f64,
    /// Baseline: keyframes whose robot poses are this close are tried as a loop, m.
    pub loop_radius: f64,
    /// Baseline: an ICP edge is kept when at least this share of its sample found a pair.
    pub min_fitness: f64,
    /// Baseline: standard deviations of an ICP edge (x m, y m, yaw rad).
    pub icp_sigma: [f64; 3],
    /// Baseline: standard deviations of the robot's pose as a prior (x m, y m, yaw rad).
    pub prior_sigma: [f64; 3],
}

impl Default for RegistrationConfig {
    fn default() -> Self {
        RegistrationConfig {
            alpha: 0.3,
            beta: 0.3,
            gamma: 0.4,
            cloud_step: 4,
            map_band: 0.05,
            target_frames: 5,
            max_cloud_pair: 0.1,
            max_map_pair: 0.2,
            normal_neighbours: 10,
            features: FeatureConfig::default(),
            feature_ransac_iterations: 200,
            feature_inlier: 0.05,
            min_feature_inliers: 6,
            max_iterations: 30,
            tolerance: 1e-4,
            degenerate: 0.02,
            max_correction: 0.3,
            max_correction_turn: 0.1,
            loop_radius: 1.5,
            min_fitness: 0.3,
            icp_sigma: [0.01, 0.01, 0.005],
            prior_sigma: [0.05, 0.05, 0.02],
        }
    }
}

impl RegistrationConfig {
    /// Checks ranges; `Err((key, message))` with the key below `registration`.
    pub fn validate(&self) -> Result<(), (String, String)> {
        use crate::config::{check_counts, check_ranges};
        use std::f64::consts::PI;
        check_ranges(
            "",
            &[
                ("alpha", self.alpha, 0.0, 1000.0),
                ("beta", self.beta, 0.0, 1000.0),
                ("gamma", self.gamma, 0.0, 1000.0),
            ],
        )?;
        if self.alpha + self.beta + self.gamma <= 0.0 {
            return Err((
                "gamma".into(),
                "expected at least one weight above 0".into(),
            ));
        }
        check_counts(
            "",
            &[
                ("cloud_step", self.cloud_step, 1, 1_000_000),
                ("target_frames", self.target_frames, 1, 1000),
                ("normal_neighbours", self.normal_neighbours, 3, 1000),
                (
                    "feature_ransac_iterations",
                    self.feature_ransac_iterations,
                    1,
                    1_000_000,
                ),
                (
                    "min_feature_inliers",
                    self.min_feature_inliers,
                    0,
                    1_000_000,
                ),
                ("max_iterations", self.max_iterations, 1, 10_000),
            ],
        )?;
        self.features.validate("features")?;
        check_ranges(
            "",
            &[
                ("map_band", self.map_band, 1e-4, 10.0),
                ("max_cloud_pair", self.max_cloud_pair, 1e-4, 100.0),
                ("max_map_pair", self.max_map_pair, 1e-4, 100.0),
                ("feature_inlier", self.feature_inlier, 1e-5, 10.0),
                ("tolerance", self.tolerance, 1e-12, 1.0),
                ("degenerate", self.degenerate, 0.0, 1e6),
                ("max_correction", self.max_correction, 1e-4, 100.0),
                ("max_correction_turn", self.max_correction_turn, 1e-4, PI),
                ("loop_radius", self.loop_radius, 1e-3, 1000.0),
                ("min_fitness", self.min_fitness, 0.0, 1.0),
            ],
        )?;
        for (k, s) in [
            ("icp_sigma", self.icp_sigma),
            ("prior_sigma", self.prior_sigma),
        ] {
            for (i, v) in s.iter().enumerate() {
                check_ranges("", &[(&format!("{k}[{i}]"), *v, 1e-6, 10.0)])?;
            }
        }
        Ok(())
    }
}

/// A levelled keyframe: the robot's pose when it was taken and its points in the robot's base
/// frame (x forward, y left, z up from the floor).
#[derive(Debug, Clone, PartialEq)]
pub struct Keyframe {
    /// The robot's 2D pose estimate (the registration's initial value).
    pub pose: Pose2,
    pub points: Vec<[f64; 3]>,
    pub colours: Vec<[u8; 3]>,
    /// Whether a point lies on the edge of the depth data (a neighbouring pixel has none);
    /// pairs with such targets are refused.
    pub boundary: Vec<bool>,
    /// Image features with valid depth: base-frame point and descriptor.
    pub features: Vec<([f64; 3], Descriptor)>,
}

/// A point of the base frame placed by a robot pose.
pub fn place(pose: &Pose2, p: [f64; 3]) -> [f64; 3] {
    let (s, c) = pose.theta.sin_cos();
    [
        pose.x + c * p[0] - s * p[1],
        pose.y + s * p[0] + c * p[1],
        p[2],
    ]
}

/// Nearest-neighbour search over a fixed set of points (a `kiddo` k-d tree).
pub struct Index<const K: usize> {
    tree: Option<ImmutableKdTree<f64, K>>,
}

impl<const K: usize> Index<K> {
    pub fn new(points: &[[f64; K]]) -> Index<K> {
        Index {
            tree: if points.is_empty() {
                None
            } else {
                ImmutableKdTree::new_from_slice(points).ok()
            },
        }
    }

    /// The nearest point's index and squared distance.
    pub fn nearest(&self, p: &[f64; K]) -> Option<(usize, f64)> {
        let t = self.tree.as_ref()?;
        let r = t.query(p).nearest_one::<SquaredEuclidean<f64>>().execute();
        Some((r.item as usize, r.distance))
    }

    /// The `n` nearest points' indices, nearest first.
    pub fn nearest_n(&self, p: &[f64; K], n: usize) -> Vec<usize> {
        let (Some(t), Some(n)) = (self.tree.as_ref(), NonZero::new(n)) else {
            return Vec::new();
        };
        t.query(p)
            .nearest_n::<SquaredEuclidean<f64>>(n)
            .execute()
            .into_iter()
            .map(|r| r.item as usize)
            .collect()
    }
}

/// The 2D map as the map term sees it: occupied cells' centres at the laser's height, with
/// normals from PCA of their neighbours.
pub struct EnvironmentMap {
    points: Vec<[f64; 2]>,
    normals: Vec<[f64; 2]>,
    index: Index<2>,
    /// The laser's height, m (M_s is the band of the cloud around it).
    pub height: f64,
}

impl EnvironmentMap {
    /// Cells of at least `occupied` (0–100) are walls.
    pub fn new(grid: &OccupancyGrid, height: f64, occupied: i8) -> EnvironmentMap {
        let mut cells = Vec::new();
        for j in 0..grid.height {
            for i in 0..grid.width {
                if grid.get(i, j) >= occupied {
                    cells.push([
                        grid.origin[0] + (i as f64 + 0.5) * grid.resolution,
                        grid.origin[1] + (j as f64 + 0.5) * grid.resolution,
                    ]);
                }
            }
        }
        let all = Index::new(&cells);
        let mut points = Vec::new();
        let mut normals = Vec::new();
        for c in &cells {
            let near: Vec<[f64; 2]> = all
                .nearest_n(c, 9)
                .into_iter()
                .map(|k| cells[k])
                .filter(|q| (q[0] - c[0]).hypot(q[1] - c[1]) <= 2.5 * grid.resolution)
                .collect();
            if near.len() < 3 {
                continue;
            }
            if let Some(n) = pca_normal(&near) {
                points.push(*c);
                normals.push(n);
            }
        }
        EnvironmentMap {
            index: Index::new(&points),
            points,
            normals,
            height,
        }
    }

    /// Number of wall points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }
}

/// One residual: `p` in the input's base frame, `q` and the normal `n` (point to plane; `None`:
/// point to point in x, y) in the world.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Pair {
    pub(crate) p: [f64; 3],
    pub(crate) q: [f64; 3],
    pub(crate) n: Option<[f64; 3]>,
}

/// A term of the error: its weight and its pairs (the weight is shared by its pairs, as the
/// thesis's mean).
pub(crate) struct Term {
    pub(crate) weight: f64,
    pub(crate) pairs: Vec<Pair>,
}

/// Residuals and their derivatives by x, y, yaw at `pose`.
fn residuals(pose: &Pose2, terms: &[Term], mut visit: impl FnMut(f64, [f64; 3])) {
    for t in terms {
        if t.pairs.is_empty() {
            continue;
        }
        let s = (t.weight / t.pairs.len() as f64).sqrt();
        for pr in &t.pairs {
            let w = place(pose, pr.p);
            // ∂w/∂yaw
            let dw = [-(w[1] - pose.y), w[0] - pose.x];
            match pr.n {
                Some(n) => {
                    let r =
                        n[0] * (w[0] - pr.q[0]) + n[1] * (w[1] - pr.q[1]) + n[2] * (w[2] - pr.q[2]);
                    visit(
                        s * r,
                        [s * n[0], s * n[1], s * (n[0] * dw[0] + n[1] * dw[1])],
                    );
                }
                None => {
                    visit(s * (w[0] - pr.q[0]), [s, 0.0, s * dw[0]]);
                    visit(s * (w[1] - pr.q[1]), [0.0, s, s * dw[1]]);
                }
            }
        }
    }
}

fn cost(pose: &Pose2, terms: &[Term]) -> f64 {
    let mut c = 0.0;
    residuals(pose, terms, |r, _| c += 0.5 * r * r);
    c
}

/// Levenberg–Marquardt steps with the pairs fixed; returns the new pose and whether a
/// direction was left out as degenerate.
///
/// Directions in which JᵀJ's eigenvalue is below `degenerate` (the weights sum to one, so a
/// translation's eigenvalue is about the share of weighted pairs that constrain it) get no
/// step: along a corridor the walls say nothing of x, and the few pairs that do (door frames,
/// a 5 cm map's steps) would slide the keyframe (Zhang, Kaess and Singh 2016's solution
/// remapping).
pub(crate) fn minimise(
    start: Pose2,
    terms: &[Term],
    steps: usize,
    degenerate: f64,
) -> (Pose2, bool) {
    let mut pose = start;
    let mut lambda = 1e-4;
    let mut current = cost(&pose, terms);
    let mut suppressed = false;
    for _ in 0..steps {
        let mut h = nalgebra::Matrix3::<f64>::zeros();
        let mut g = nalgebra::Vector3::<f64>::zeros();
        residuals(&pose, terms, |r, j| {
            let j = nalgebra::Vector3::from(j);
            h += j * j.transpose();
            g += j * r;
        });
        let eig = h.symmetric_eigen();
        let mut keep = nalgebra::Matrix3::<f64>::zeros();
        for k in 0..3 {
            if eig.eigenvalues[k] >= degenerate {
                let v = eig.eigenvectors.column(k);
                keep += v * v.transpose();
            } else {
                suppressed = true;
            }
        }
        let mut improved = false;
        for _ in 0..8 {
            let a = h + nalgebra::Matrix3::identity() * lambda;
            let Some(d) = a.cholesky().map(|c| keep * c.solve(&(-g))) else {
                lambda *= 10.0;
                continue;
            };
            let next = Pose2::new(pose.x + d[0], pose.y + d[1], wrap_angle(pose.theta + d[2]));
            let c = cost(&next, terms);
            if c <= current {
                pose = next;
                current = c;
                lambda = (lambda / 10.0).max(1e-9);
                improved = true;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    (pose, suppressed)
}

/// Per-keyframe search structures, normals made when first needed.
struct Frame<'a> {
    kf: &'a Keyframe,
    index: Index<3>,
    normals: Vec<Option<Option<[f64; 3]>>>,
    /// P_s.
    sample: Vec<usize>,
    /// M_s.
    band: Vec<usize>,
}

impl<'a> Frame<'a> {
    fn new(kf: &'a Keyframe, config: &RegistrationConfig, height: Option<f64>) -> Frame<'a> {
        Frame {
            kf,
            index: Index::new(&kf.points),
            normals: vec![None; kf.points.len()],
            sample: (0..kf.points.len()).step_by(config.cloud_step).collect(),
            band: height.map_or(Vec::new(), |h| {
                (0..kf.points.len())
                    .filter(|&k| (kf.points[k][2] - h).abs() <= config.map_band)
                    .collect()
            }),
        }
    }

    /// The PCA normal at point `k` (base frame).
    fn normal(&mut self, k: usize, neighbours: usize) -> Option<[f64; 3]> {
        if let Some(n) = self.normals[k] {
            return n;
        }
        let near: Vec<[f64; 3]> = self
            .index
            .nearest_n(&self.kf.points[k], neighbours)
            .into_iter()
            .map(|i| self.kf.points[i])
            .collect();
        let n = pca_normal(&near);
        self.normals[k] = Some(n);
        n
    }
}

/// Cloud pairs of `input`'s sample at `pose` against `target` placed at `at`: point to plane,
/// refusing far pairs, boundary targets and near-horizontal planes (after levelling the floor
/// and ceiling say nothing of x, y or yaw).
fn cloud_pairs(
    input: &Frame,
    pose: &Pose2,
    target: &mut Frame,
    at: &Pose2,
    config: &RegistrationConfig,
) -> Vec<Pair> {
    let back = at.inverse();
    let max2 = config.max_cloud_pair * config.max_cloud_pair;
    let mut out = Vec::new();
    for &k in &input.sample {
        let p = input.kf.points[k];
        let local = place(&back, place(pose, p));
        let Some((j, d2)) = target.index.nearest(&local) else {
            break;
        };
        if d2 > max2 || target.kf.boundary[j] {
            continue;
        }
        let Some(n) = target.normal(j, config.normal_neighbours) else {
            continue;
        };
        if n[2].abs() > 0.9 {
            continue;
        }
        let (s, c) = at.theta.sin_cos();
        out.push(Pair {
            p,
            q: place(at, target.kf.points[j]),
            n: Some([c * n[0] - s * n[1], s * n[0] + c * n[1], n[2]]),
        });
    }
    out
}

/// Map pairs of the input's laser-height band at `pose`.
fn map_pairs(input: &Frame, pose: &Pose2, map: &EnvironmentMap, max: f64) -> Vec<Pair> {
    let mut out = Vec::new();
    for &k in &input.band {
        let p = input.kf.points[k];
        let w = place(pose, p);
        let Some((j, d2)) = map.index.nearest(&[w[0], w[1]]) else {
            break;
        };
        if d2 > max * max {
            continue;
        }
        let (q, n) = (map.points[j], map.normals[j]);
        out.push(Pair {
            p,
            q: [q[0], q[1], w[2]],
            n: Some([n[0], n[1], 0.0]),
        });
    }
    out
}

/// Feature pairs of `input` against `target` placed at `at`: nearest descriptors, then
/// RANSAC over rigid (x, y, yaw) hypotheses from two matches; the inliers.
fn feature_pairs(
    input: &Keyframe,
    target: &Keyframe,
    at: &Pose2,
    config: &RegistrationConfig,
    rng: &mut ChaCha8Rng,
) -> Vec<Pair> {
    let da: Vec<Descriptor> = input.features.iter().map(|f| f.1).collect();
    let db: Vec<Descriptor> = target.features.iter().map(|f| f.1).collect();
    let pairs: Vec<Pair> =
        crate::perception::features::match_nearest(&da, &db, config.features.max_hamming)
            .into_iter()
            .map(|(i, j)| Pair {
                p: input.features[i].0,
                q: place(at, target.features[j].0),
                n: None,
            })
            .collect();
    if pairs.len() < 2 {
        return Vec::new();
    }
    let inliers = |pose: &Pose2| -> Vec<usize> {
        (0..pairs.len())
            .filter(|&k| {
                let w = place(pose, pairs[k].p);
                let q = pairs[k].q;
                ((w[0] - q[0]).powi(2) + (w[1] - q[1]).powi(2) + (w[2] - q[2]).powi(2)).sqrt()
                    <= config.feature_inlier
            })
            .collect()
    };
    let mut best: Vec<usize> = Vec::new();
    for _ in 0..config.feature_ransac_iterations {
        let a = rng.random_range(0..pairs.len());
        let b = rng.random_range(0..pairs.len());
        let (pa, pb, qa, qb) = (pairs[a].p, pairs[b].p, pairs[a].q, pairs[b].q);
        let (dp, dq) = (
            [pb[0] - pa[0], pb[1] - pa[1]],
            [qb[0] - qa[0], qb[1] - qa[1]],
        );
        let (lp, lq) = (dp[0].hypot(dp[1]), dq[0].hypot(dq[1]));
        if lp < 0.1 || (lp - lq).abs() > config.feature_inlier {
            continue;
        }
        let theta = dq[1].atan2(dq[0]) - dp[1].atan2(dp[0]);
        let (s, c) = theta.sin_cos();
        let pose = Pose2::new(
            qa[0] - (c * pa[0] - s * pa[1]),
            qa[1] - (s * pa[0] + c * pa[1]),
            wrap_angle(theta),
        );
        let found = inliers(&pose);
        if found.len() > best.len() {
            best = found;
        }
    }
    if best.len() < config.min_feature_inliers {
        return Vec::new();
    }
    best.into_iter().map(|k| pairs[k]).collect()
}

/// Counts of what the registration did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct RegistrationCounts {
    /// Keyframes with a feature term (enough RANSAC inliers against their target).
    pub with_features: u64,
    /// Mean feature inliers of those.
    pub feature_inliers_mean: f64,
    /// Mean cloud pairs per keyframe that had a cloud term.
    pub cloud_pairs_mean: f64,
    /// Mean map pairs per keyframe that had a map term.
    pub map_pairs_mean: f64,
    /// Mean ICP iterations.
    pub iterations_mean: f64,
    /// Keyframes whose registration moved them beyond `max_correction` and kept the robot's
    /// pose instead.
    pub rejected: u64,
    /// Keyframes with a direction left unchanged as degenerate (`degenerate`).
    pub degenerate: u64,
    /// Baseline: ICP edges between consecutive keyframes, and loop edges, kept.
    pub sequential_edges: u64,
    pub loop_edges: u64,
}

/// Registers `keyframes` (in the order taken) by `method`; the robot pose of each, and what was
/// done. `map`: the 2D map for the map term (without one, the map term is left out).
pub fn register(
    keyframes: &[Keyframe],
    method: Method,
    map: Option<&EnvironmentMap>,
    config: &RegistrationConfig,
    seed: u64,
) -> (Vec<Pose2>, RegistrationCounts) {
    let mut counts = RegistrationCounts::default();
    let initial: Vec<Pose2> = keyframes.iter().map(|k| k.pose).collect();
    if method == Method::Pose || keyframes.is_empty() {
        return (initial, counts);
    }
    let height = map.map(|m| m.height);
    let mut frames: Vec<Frame> = keyframes
        .iter()
        .map(|k| Frame::new(k, config, height))
        .collect();
    if method == Method::IcpGraph {
        return icp_graph(&mut frames, config, counts);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut poses: Vec<Pose2> = Vec::with_capacity(frames.len());
    let (mut feature_frames, mut cloud_frames, mut map_frames) = (0u64, 0u64, 0u64);
    let (mut feature_sum, mut cloud_sum, mut map_sum, mut iter_sum) = (0.0, 0.0, 0.0, 0.0);
    for (i, &init) in initial.iter().enumerate() {
        let (done, rest) = frames.split_at_mut(i);
        let input = &rest[0];
        let use_frames = method != Method::Map && i > 0;
        // Target: of the last few keyframes, the one with the most feature inliers; the
        // previous one when none has any.
        let mut target = i.saturating_sub(1);
        let mut features = Vec::new();
        if use_frames {
            for t in (i.saturating_sub(config.target_frames)..i).rev() {
                let f = feature_pairs(input.kf, done[t].kf, &poses[t], config, &mut rng);
                if f.len() > features.len() {
                    features = f;
                    target = t;
                }
            }
        }
        let mut pose = init;
        let mut iterations = 0;
        let mut degenerate = false;
        let (mut n_cloud, mut n_map) = (0, 0);
        for _ in 0..config.max_iterations {
            iterations += 1;
            let mut terms = Vec::new();
            if use_frames {
                terms.push(Term {
                    weight: config.alpha,
                    pairs: features.clone(),
                });
                let c = cloud_pairs(input, &pose, &mut done[target], &poses[target], config);
                n_cloud = c.len();
                terms.push(Term {
                    weight: config.beta,
                    pairs: c,
                });
            }
            if let Some(m) = map.filter(|_| method != Method::RgbdIcp) {
                let p = map_pairs(input, &pose, m, config.max_map_pair);
                n_map = p.len();
                terms.push(Term {
                    weight: config.gamma,
                    pairs: p,
                });
            }
            // Weights of the terms present, renormalised to sum to one.
            let total: f64 = terms
                .iter()
                .filter(|t| !t.pairs.is_empty())
                .map(|t| t.weight)
                .sum();
            if total <= 0.0 {
                break;
            }
            for t in &mut terms {
                t.weight /= total;
            }
            let (next, flat) = minimise(pose, &terms, 3, config.degenerate);
            degenerate |= flat;
            let step = (next.x - pose.x).hypot(next.y - pose.y)
                + wrap_angle(next.theta - pose.theta).abs();
            pose = next;
            if step < config.tolerance {
                break;
            }
        }
        if !features.is_empty() {
            feature_frames += 1;
            feature_sum += features.len() as f64;
        }
        if n_cloud > 0 {
            cloud_frames += 1;
            cloud_sum += n_cloud as f64;
        }
        if n_map > 0 {
            map_frames += 1;
            map_sum += n_map as f64;
        }
        iter_sum += iterations as f64;
        counts.degenerate += degenerate as u64;
        if pose.distance(&init) > config.max_correction
            || wrap_angle(pose.theta - init.theta).abs() > config.max_correction_turn
        {
            counts.rejected += 1;
            pose = init;
        }
        poses.push(pose);
    }
    let mean = |s: f64, n: u64| if n > 0 { s / n as f64 } else { 0.0 };
    counts.with_features = feature_frames;
    counts.feature_inliers_mean = mean(feature_sum, feature_frames);
    counts.cloud_pairs_mean = mean(cloud_sum, cloud_frames);
    counts.map_pairs_mean = mean(map_sum, map_frames);
    counts.iterations_mean = mean(iter_sum, frames.len() as u64);
    (poses, counts)
}

/// Point-to-plane ICP of `input` against `target` (placed at `at`), from `start`; the pose
/// and the share of the sample that found a pair.
fn pairwise(
    input: &Frame,
    target: &mut Frame,
    at: &Pose2,
    start: Pose2,
    config: &RegistrationConfig,
) -> (Pose2, f64) {
    let mut pose = start;
    let mut n = 0;
    for _ in 0..config.max_iterations {
        let pairs = cloud_pairs(input, &pose, target, at, config);
        n = pairs.len();
        if n < 10 {
            return (pose, 0.0);
        }
        let (next, _) = minimise(pose, &[Term { weight: 1.0, pairs }], 3, config.degenerate);
        let step =
            (next.x - pose.x).hypot(next.y - pose.y) + wrap_angle(next.theta - pose.theta).abs();
        pose = next;
        if step < config.tolerance {
            break;
        }
    }
    (pose, n as f64 / input.sample.len().max(1) as f64)
}

/// The baseline: ICP edges (consecutive keyframes, and revisits) and the robot's poses as
/// priors, in one pose graph whose node 0 is the world's origin.
fn icp_graph(
    frames: &mut [Frame],
    config: &RegistrationConfig,
    mut counts: RegistrationCounts,
) -> (Vec<Pose2>, RegistrationCounts) {
    let initial: Vec<Pose2> = frames.iter().map(|f| f.kf.pose).collect();
    let mut graph = PoseGraph {
        nodes: std::iter::once(Pose2::IDENTITY)
            .chain(initial.iter().copied())
            .collect(),
        edges: Vec::new(),
    };
    for (i, p) in initial.iter().enumerate() {
        graph
            .edges
            .push(Edge::with_sigmas(0, i + 1, *p, config.prior_sigma));
    }
    let mut iter_sum = 0.0;
    for i in 1..frames.len() {
        // Consecutive keyframes, then up to three earlier ones near the same place.
        let mut targets = vec![i - 1];
        let mut near: Vec<(f64, usize)> = (0..i.saturating_sub(config.target_frames))
            .filter_map(|j| {
                let d = initial[j].distance(&initial[i]);
                let turn = wrap_angle(initial[j].theta - initial[i].theta).abs();
                (d <= config.loop_radius && turn <= 0.8).then_some((d, j))
            })
            .collect();
        near.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        targets.extend(near.iter().take(3).map(|n| n.1));
        for (k, t) in targets.into_iter().enumerate() {
            let (done, rest) = frames.split_at_mut(i);
            let (pose, fitness) = pairwise(&rest[0], &mut done[t], &initial[t], initial[i], config);
            iter_sum += 1.0;
            if fitness < config.min_fitness {
                continue;
            }
            let mut e =
                Edge::with_sigmas(t + 1, i + 1, initial[t].between(&pose), config.icp_sigma);
            if k == 0 {
                counts.sequential_edges += 1;
            } else {
                e.huber = Some(2.0);
                counts.loop_edges += 1;
            }
            graph.edges.push(e);
        }
    }
    let _ = graph.optimize(&OptimizeOptions::default());
    counts.iterations_mean = iter_sum / frames.len().max(1) as f64;
    (graph.nodes[1..].to_vec(), counts)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A room's corner seen from the origin: two walls (x = 2 and y = 1.5) from the floor to
    /// 1 m, and a pillar, sampled every 2 cm, in the world.
    fn scene() -> Vec<[f64; 3]> {
        let mut pts = Vec::new();
        let mut z = 0.02;
        while z < 1.0 {
            let mut s = -1.0;
            while s < 1.5 {
                pts.push([2.0, s, z]);
                s += 0.02;
            }
            let mut s = 0.0;
            while s < 2.0 {
                pts.push([s, 1.5, z]);
                s += 0.02;
            }
            for k in 0..40 {
                let a = k as f64 * std::f64::consts::TAU / 40.0;
                pts.push([1.0 + 0.1 * a.cos(), -0.5 + 0.1 * a.sin(), z]);
            }
            z += 0.02;
        }
        pts
    }

    /// The scene as a keyframe taken at `truth` whose robot pose says `believed`.
    fn keyframe(truth: Pose2, believed: Pose2) -> Keyframe {
        let back = truth.inverse();
        let points: Vec<[f64; 3]> = scene().into_iter().map(|p| place(&back, p)).collect();
        Keyframe {
            pose: believed,
            colours: vec![[0, 0, 0]; points.len()],
            boundary: vec![false; points.len()],
            features: Vec::new(),
            points,
        }
    }

    fn grid_of_walls() -> OccupancyGrid {
        // 5 cm cells centred on multiples of 5 cm over [-2, 4] × [-2, 3]; the walls x = 2
        // and y = 1.5 and the pillar.
        let mut g = OccupancyGrid::new(0.05, [-2.025, -2.025], 120, 100);
        for (i, j) in (0..120).flat_map(|i| (0..100).map(move |j| (i, j))) {
            let x = -2.0 + i as f64 * 0.05;
            let y = -2.0 + j as f64 * 0.05;
            let wall = ((x - 2.0).abs() < 0.025 && y < 1.5)
                || ((y - 1.5).abs() < 0.025 && x < 2.0)
                || ((x - 1.0).hypot(y + 0.5) - 0.1).abs() < 0.025;
            g.cells[j * 120 + i] = if wall { 100 } else { 0 };
        }
        g
    }

    #[test]
    fn the_map_term_alone_pulls_a_keyframe_onto_the_walls() {
        let truth = Pose2::new(0.2, -0.1, 0.1);
        let off = Pose2::new(0.26, -0.14, 0.13);
        let kf = keyframe(truth, off);
        let map = EnvironmentMap::new(&grid_of_walls(), 0.2, 50);
        assert!(map.len() > 100);
        let cfg = RegistrationConfig::default();
        let (pose_only, _) = register(std::slice::from_ref(&kf), Method::Pose, Some(&map), &cfg, 1);
        assert_eq!(pose_only[0], off);
        let (p, c) = register(std::slice::from_ref(&kf), Method::Map, Some(&map), &cfg, 1);
        // The walls are cell centres, so within a few mm of the truth.
        assert!(p[0].distance(&truth) < 0.01, "{:?}", p[0]);
        assert!(
            wrap_angle(p[0].theta - truth.theta).abs() < 0.005,
            "{:?}",
            p[0]
        );
        assert!(c.map_pairs_mean > 100.0, "{c:?}");
        // Without a map the map term has nothing to do.
        let (p, _) = register(std::slice::from_ref(&kf), Method::Map, None, &cfg, 1);
        assert_eq!(p[0], off);
        // A robot pose that leaves the map: no pairs, the pose is kept, nothing breaks.
        let lost = keyframe(truth, Pose2::new(50.0, -40.0, 1.0));
        let (p, c) = register(
            std::slice::from_ref(&lost),
            Method::Full,
            Some(&map),
            &cfg,
            1,
        );
        assert_eq!(p[0], lost.pose);
        assert_eq!(c.map_pairs_mean, 0.0);
    }

    #[test]
    fn the_cloud_term_aligns_a_keyframe_to_the_one_before() {
        // The first keyframe is right; the second's robot pose is 6 cm and 2° off.
        let a = keyframe(Pose2::new(0.0, 0.0, 0.0), Pose2::new(0.0, 0.0, 0.0));
        let truth = Pose2::new(0.3, 0.1, 0.05);
        let b = keyframe(truth, Pose2::new(0.35, 0.07, 0.085));
        let cfg = RegistrationConfig::default();
        let (p, c) = register(&[a.clone(), b.clone()], Method::RgbdIcp, None, &cfg, 1);
        assert_eq!(p[0], a.pose);
        assert!(p[1].distance(&truth) < 0.002, "{:?}", p[1]);
        assert!(
            wrap_angle(p[1].theta - truth.theta).abs() < 0.001,
            "{:?}",
            p[1]
        );
        assert!(c.cloud_pairs_mean > 500.0, "{c:?}");
        // So does the baseline's graph, given loose priors.
        let cfg = RegistrationConfig {
            prior_sigma: [1.0, 1.0, 1.0],
            ..Default::default()
        };
        let (p, c) = register(&[a, b], Method::IcpGraph, None, &cfg, 1);
        assert_eq!(c.sequential_edges, 1);
        let rel = p[0].between(&p[1]);
        assert!(rel.distance(&truth) < 0.005, "{rel:?}");
    }

    #[test]
    fn feature_pairs_survive_ransac_and_outliers_do_not() {
        // Twenty features seen from two poses, five of them matched to the wrong point.
        let truth_a = Pose2::new(0.0, 0.0, 0.0);
        let truth_b = Pose2::new(0.4, 0.0, 0.2);
        let world: Vec<[f64; 3]> = (0..20)
            .map(|k| {
                let k = k as f64;
                [2.0 + 0.1 * (k * 1.3).sin(), -1.0 + 0.1 * k, 0.3 + 0.05 * k]
            })
            .collect();
        let desc = |k: usize| -> Descriptor { [(k as u128) * 0x1234_5678_9abc, !(k as u128)] };
        let mut a = keyframe(truth_a, truth_a);
        let mut b = keyframe(truth_b, Pose2::new(0.45, 0.03, 0.22));
        a.features = (0..20)
            .map(|k| (place(&truth_a.inverse(), world[k]), desc(k)))
            .collect();
        b.features = (0..20)
            .map(|k| {
                let from = if k < 5 { (k + 7) % 20 } else { k };
                (place(&truth_b.inverse(), world[from]), desc(k))
            })
            .collect();
        let cfg = RegistrationConfig::default();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let pairs = feature_pairs(&b, &a, &truth_a, &cfg, &mut rng);
        assert_eq!(pairs.len(), 15);
        // The feature term alone (no cloud to match: empty points) recovers the pose.
        b.points.clear();
        b.colours.clear();
        b.boundary.clear();
        let (p, c) = register(&[a, b], Method::RgbdIcp, None, &cfg, 1);
        assert_eq!(c.with_features, 1);
        assert!(p[1].distance(&truth_b) < 1e-6, "{:?}", p[1]);
    }

    #[test]
    fn the_full_method_weights_its_terms_and_ranks_ahead_of_the_pose() {
        // Three keyframes, all poses off by up to 6 cm; the full method brings each close.
        let truths = [
            Pose2::new(0.0, 0.0, 0.0),
            Pose2::new(0.3, 0.05, 0.05),
            Pose2::new(0.6, 0.1, 0.1),
        ];
        let offs = [
            Pose2::new(0.04, -0.03, 0.01),
            Pose2::new(0.34, 0.1, 0.08),
            Pose2::new(0.55, 0.16, 0.14),
        ];
        let kfs: Vec<Keyframe> = truths
            .iter()
            .zip(offs)
            .map(|(t, o)| keyframe(*t, o))
            .collect();
        let map = EnvironmentMap::new(&grid_of_walls(), 0.2, 50);
        let cfg = RegistrationConfig::default();
        let err = |p: &[Pose2]| -> f64 {
            p.iter()
                .zip(&truths)
                .map(|(a, b)| a.distance(b))
                .fold(0.0, f64::max)
        };
        let (pose, _) = register(&kfs, Method::Pose, Some(&map), &cfg, 1);
        let (full, c) = register(&kfs, Method::Full, Some(&map), &cfg, 1);
        assert!(err(&pose) > 0.05);
        assert!(err(&full) < 0.01, "{full:?}");
        assert!(c.map_pairs_mean > 0.0 && c.cloud_pairs_mean > 0.0, "{c:?}");
        // The same input gives the same bytes.
        assert_eq!(register(&kfs, Method::Full, Some(&map), &cfg, 1).0, full);
    }

    #[test]
    fn a_direction_few_pairs_constrain_is_left_alone() {
        // A corridor: 200 pairs on walls facing y, 2 cm off, and one pair on a door frame
        // facing x, 10 cm off.
        let mut pairs: Vec<Pair> = (0..200)
            .map(|k| Pair {
                p: [k as f64 * 0.02, if k % 2 == 0 { 1.0 } else { -1.0 }, 0.2],
                q: [k as f64 * 0.02, if k % 2 == 0 { 1.02 } else { -0.98 }, 0.2],
                n: Some([0.0, 1.0, 0.0]),
            })
            .collect();
        pairs.push(Pair {
            p: [3.0, 0.5, 0.2],
            q: [3.1, 0.5, 0.2],
            n: Some([1.0, 0.0, 0.0]),
        });
        let terms = [Term { weight: 1.0, pairs }];
        // x's eigenvalue is 1/201 of the weight: below 0.02, so x is not stepped; y is.
        let (p, flat) = minimise(Pose2::IDENTITY, &terms, 10, 0.02);
        assert!(flat);
        assert!(p.x.abs() < 1e-3 && (p.y - 0.02).abs() < 1e-3, "{p:?}");
        // Without the check the one pair moves the keyframe its 10 cm.
        let (p, flat) = minimise(Pose2::IDENTITY, &terms, 10, 0.0);
        assert!(!flat);
        assert!(
            (p.x - 0.1).abs() < 1e-4 && (p.y - 0.02).abs() < 1e-4,
            "{p:?}"
        );
    }

    #[test]
    fn bad_weights_and_distances_are_refused_by_name() {
        let mut c = RegistrationConfig {
            alpha: -1.0,
            ..Default::default()
        };
        assert_eq!(c.validate().unwrap_err().0, "alpha");
        c.alpha = 0.0;
        c.beta = 0.0;
        c.gamma = 0.0;
        assert_eq!(c.validate().unwrap_err().0, "gamma");
        let c = RegistrationConfig {
            max_cloud_pair: f64::NAN,
            ..Default::default()
        };
        assert_eq!(c.validate().unwrap_err().0, "max_cloud_pair");
        let c = RegistrationConfig {
            normal_neighbours: 2,
            ..Default::default()
        };
        assert_eq!(c.validate().unwrap_err().0, "normal_neighbours");
        assert!(RegistrationConfig::default().validate().is_ok());
    }
}
