//! Building a visual landmark map with a trinocular camera (seed 001 §2): each frame's
//! triangulated points are matched to the map's landmarks predicted in view (§2.5), the
//! camera's planar pose found by an exhaustive search for the least sum of 3D Mahalanobis
//! distances (eqs. 7–11), the matching done again at that pose, matched landmarks fused by a
//! Kalman filter and their direction's descriptor renewed, the counters m and l kept (§2.3),
//! and unmatched points added as new landmarks.
//!
//! The seed predicts no motion: the search is centred on the last pose. Here, where the wheels
//! report the frame's motion, it is centred on the last pose carried by it, and the cost adds
//! the prediction's Mahalanobis distance ([`OdometryNoise`]); the grid's best pose is then
//! refined by Gauss–Newton (`refine_iterations`). Neither is the seed's. Its eq. 9 leaves the
//! stereo covariance out of Q; it is added here (the digest's reading: "this observation
//! error is used"). Its outlier cut, δ ≥ 1, is read as a cap on each match's cost (a constant
//! for a false match) at the χ² of 3 degrees of freedom at 99 % (11.34), since a cut at 1
//! would drop four in five true matches of a 3D Gaussian.

use crate::localization::landmarks::{
    Camera, InView, Landmark, LandmarkMap, MonocularConfig, SearchConfig, View, direction_bin,
    grid_search_outward, in_view, optical_rotation,
};
use crate::perception::sift::{self, Keypoint};
use crate::perception::trinocular::{StereoPoint, passes_ratio};
use futago_msgs::Pose2;
use glam::{DMat3, DVec3};
use serde::{Deserialize, Serialize};

/// Parameters of the mapping pass.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MappingConfig {
    pub search: SearchConfig,
    /// Matching window about a landmark's predicted pixel, px (§2.5: 40 × 20 at 320 × 240).
    pub gate_u_px: f64,
    pub gate_v_px: f64,
    /// Predicted and measured disparities differ by at most this share of the measured one.
    pub disparity_ratio: f64,
    /// Ratio test (eq. 3: 0.7) and the largest descriptor distance (0.2).
    pub ratio: f64,
    pub max_distance: f64,
    /// Views within this many direction bins count as seen from here (±20°: 2).
    pub direction_reach: u8,
    /// Landmarks predicted nearer or farther than this are not candidates, m.
    pub min_depth: f64,
    pub max_depth: f64,
    /// Each match's 3D Mahalanobis distance counts at most this much (see the module).
    pub outlier: f64,
    /// Gauss–Newton iterations that refine the search's best grid pose on its inliers (0:
    /// the seed's grid pose, quantised to the search's steps). Not in the seed: its 1°
    /// heading step alone puts a landmark 8 m away up to 7 cm off.
    pub refine_iterations: usize,
    /// The wheels' error model, when the frame's motion is predicted by odometry.
    pub odometry: OdometryNoise,
}

/// How far the wheels' report of a frame's motion may be off (one σ): the search is centred
/// on the predicted pose and its cost adds the prediction's Mahalanobis distance. Not in the
/// seed, whose mecanum base had no usable encoders (§4.3.3); it notes that encoders would
/// narrow the search. Errors grow with the distance and the turn, as a differential drive's
/// systematic ones do (wheel diameters and track width off: Borenstein and Feng's UMBmark);
/// the defaults, 2 % of the distance and of the turn and 0.01 rad a metre, are of the order
/// of an uncalibrated drive's. A robot's own figures belong here.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OdometryNoise {
    /// Translation error per metre driven, along and across the motion (σ / m).
    pub translation: f64,
    /// Heading error per radian turned (σ / rad) and per metre driven (rad / m).
    pub rotation_per_rad: f64,
    pub rotation_per_m: f64,
    /// Floors of the σs, m and rad, so that a standing frame still lets the camera settle.
    pub min_translation: f64,
    pub min_rotation: f64,
}

impl Default for OdometryNoise {
    fn default() -> Self {
        OdometryNoise {
            translation: 0.02,
            rotation_per_rad: 0.02,
            rotation_per_m: 0.01,
            min_translation: 0.002,
            min_rotation: 0.1f64.to_radians(),
        }
    }
}

impl OdometryNoise {
    /// Checks every field; the error names the key below `prefix`.
    pub fn validate(&self, prefix: &str) -> Result<(), crate::config::ConfigError> {
        crate::config::check_ranges(
            prefix,
            &[
                ("translation", self.translation, 0.0, 10.0),
                ("rotation_per_rad", self.rotation_per_rad, 0.0, 10.0),
                ("rotation_per_m", self.rotation_per_m, 0.0, 10.0),
                ("min_translation", self.min_translation, 1e-6, 10.0),
                ("min_rotation", self.min_rotation, 1e-6, 10.0),
            ],
        )
    }

    /// The information (inverse covariance) of a pose predicted by `motion` (in the frame it
    /// starts from), rows x, y, θ; isotropic in the plane, so the same in the world.
    pub fn information(&self, motion: &Pose2) -> DMat3 {
        let d = motion.x.hypot(motion.y);
        let st = (self.translation * d).max(self.min_translation);
        let sr = (self.rotation_per_rad * motion.theta.abs() + self.rotation_per_m * d)
            .max(self.min_rotation);
        DMat3::from_diagonal(DVec3::new(
            1.0 / (st * st),
            1.0 / (st * st),
            1.0 / (sr * sr),
        ))
    }
}

impl Default for MappingConfig {
    fn default() -> Self {
        MappingConfig {
            search: SearchConfig::default(),
            gate_u_px: 40.0,
            gate_v_px: 20.0,
            disparity_ratio: 0.2,
            ratio: 0.7,
            max_distance: 0.2,
            direction_reach: 2,
            min_depth: 0.2,
            max_depth: 12.0,
            outlier: 11.34,
            refine_iterations: 5,
            odometry: OdometryNoise::default(),
        }
    }
}

impl MappingConfig {
    /// Checks every field; the error names the key below `prefix`.
    pub fn validate(&self, prefix: &str) -> Result<(), crate::config::ConfigError> {
        self.search.validate(&format!("{prefix}.search"))?;
        self.odometry.validate(&format!("{prefix}.odometry"))?;
        crate::config::check_ranges(
            prefix,
            &[
                ("gate_u_px", self.gate_u_px, 1.0, 10_000.0),
                ("gate_v_px", self.gate_v_px, 1.0, 10_000.0),
                ("disparity_ratio", self.disparity_ratio, 0.0, 10.0),
                ("ratio", self.ratio, 0.0, 1.0),
                ("max_distance", self.max_distance, 0.0, 2.0),
                ("min_depth", self.min_depth, 0.0, 100.0),
                ("max_depth", self.max_depth, self.min_depth + 1e-3, 1000.0),
                ("outlier", self.outlier, 0.01, 1e6),
            ],
        )?;
        crate::config::check_counts(
            prefix,
            &[
                ("direction_reach", self.direction_reach as usize, 0, 18),
                ("refine_iterations", self.refine_iterations, 0, 100),
            ],
        )
    }

    /// The monocular localiser's view test with these depths and reach.
    fn view(&self) -> MonocularConfig {
        MonocularConfig {
            direction_reach: self.direction_reach,
            min_depth: self.min_depth,
            max_depth: self.max_depth,
            ..MonocularConfig::default()
        }
    }
}

/// What one frame did to the map.
#[derive(Debug, Clone, PartialEq)]
pub struct MappingStep {
    /// The camera's estimated planar pose.
    pub pose: Pose2,
    /// Triangulated points, landmarks predicted in view, points matched to them, new landmarks.
    pub points: usize,
    pub candidates: usize,
    pub matched: usize,
    pub added: usize,
    /// Matched points within the outlier cap at the pose.
    pub inliers: usize,
    /// The points that became new landmarks, in the order they were added.
    pub new_points: Vec<usize>,
}

/// The mapper: the map and the camera's last pose and its uncertainty.
pub struct LandmarkMapper {
    pub map: LandmarkMap,
    pub camera: Camera,
    pub config: MappingConfig,
    pose: Pose2,
    /// Σ_r: the pose's position uncertainty in the world, m² (eq. 12).
    pose_covariance: DMat3,
    /// Baseline × fx: disparity = this / depth.
    fb: f64,
}

/// A match of a stereo point to a landmark.
#[derive(Debug, Clone, Copy)]
struct PointMatch {
    point: usize,
    landmark: usize,
}

impl LandmarkMapper {
    /// A mapper whose camera starts at `start` (the map's frame is the world's).
    pub fn new(camera: Camera, baseline: f64, config: MappingConfig, start: Pose2) -> Self {
        LandmarkMapper {
            map: LandmarkMap::default(),
            camera,
            config,
            pose: start,
            pose_covariance: DMat3::ZERO,
            fb: baseline * camera.intrinsics.fx,
        }
    }

    /// The camera's last pose.
    pub fn pose(&self) -> Pose2 {
        self.pose
    }

    /// Matches points to the landmarks in view of `pose` (§2.5).
    fn associate(
        &self,
        pose: &Pose2,
        points: &[StereoPoint],
        keypoints: &[Keypoint],
    ) -> (Vec<InView>, Vec<PointMatch>) {
        let view = in_view(&self.map, &self.camera, pose, &self.config.view());
        let mut claims: rustc_hash::FxHashMap<usize, Option<usize>> = Default::default();
        for (pi, p) in points.iter().enumerate() {
            let k = &keypoints[p.keypoint];
            let (mut best, mut second) = ((f32::INFINITY, usize::MAX), f32::INFINITY);
            for (vi, v) in view.iter().enumerate() {
                if (v.pixel.x - k.x as f64).abs() >= self.config.gate_u_px
                    || (v.pixel.y - k.y as f64).abs() >= self.config.gate_v_px
                {
                    continue;
                }
                let predicted = self.fb / v.depth;
                if (predicted - p.disparity).abs() >= self.config.disparity_ratio * p.disparity {
                    continue;
                }
                let l = &self.map.landmarks[v.index];
                let d = sift::distance(&l.views[v.view].descriptor, &k.descriptor);
                if d as f64 > self.config.max_distance {
                    continue;
                }
                if d < best.0 {
                    second = best.0;
                    best = (d, vi);
                } else if d < second {
                    second = d;
                }
            }
            if best.1 != usize::MAX && passes_ratio(best.0, second, self.config.ratio) {
                claims
                    .entry(best.1)
                    .and_modify(|c| *c = None)
                    .or_insert(Some(pi));
            }
        }
        let mut matches: Vec<PointMatch> = claims
            .into_iter()
            .filter_map(|(vi, c)| {
                c.map(|pi| PointMatch {
                    point: pi,
                    landmark: view[vi].index,
                })
            })
            .collect();
        matches.sort_by_key(|m| (m.point, m.landmark));
        (view, matches)
    }

    /// Eqs. 7–10 at `pose`: each match's 3D Mahalanobis distance, uncapped.
    fn distances<'a>(
        &'a self,
        pose: &Pose2,
        points: &'a [StereoPoint],
        m: &'a [(PointMatch, DMat3)],
    ) -> impl Iterator<Item = f64> + 'a {
        let r = optical_rotation(pose.theta);
        let c = self.camera.centre(pose);
        m.iter().map(move |(pm, info)| {
            let q = points[pm.point].position - r * (self.map.landmarks[pm.landmark].position - c);
            q.dot(*info * q)
        })
    }

    /// Eq. 11's sum at `pose`, each match's distance capped (see the module); or `Err` with
    /// the sum so far once it exceeds `bound`: every term is a Mahalanobis distance or the
    /// cap, never negative, and the search's prediction term is one too, so the pose's whole
    /// cost would be more, and [`grid_search_outward`] keeps the same pose.
    fn cost_below(
        &self,
        pose: &Pose2,
        points: &[StereoPoint],
        m: &[(PointMatch, DMat3)],
        bound: f64,
    ) -> Result<f64, f64> {
        // The empty sum, as `Iterator::sum` starts from it, so the additions are the same.
        let mut sum: f64 = std::iter::empty::<f64>().sum();
        for d in self.distances(pose, points, m) {
            sum += d.min(self.config.outlier);
            if sum > bound {
                return Err(sum);
            }
        }
        Ok(sum)
    }

    /// Gauss–Newton on eq. 11 from the grid's best pose `start`, over the matches within the
    /// outlier cap there, each weighted by its Q⁻¹ at `start`'s heading. Stops where a step
    /// does not lower the cost or would leave the search's window about `start`.
    fn refine(
        &self,
        start: Pose2,
        points: &[StereoPoint],
        m: &[(PointMatch, DMat3)],
        prediction: Option<&(Pose2, DMat3)>,
    ) -> Pose2 {
        let inliers: Vec<(PointMatch, DMat3)> = m
            .iter()
            .zip(self.distances(&start, points, m))
            .filter(|(_, d)| *d < self.config.outlier)
            .map(|(x, _)| *x)
            .collect();
        if inliers.len() < 3 {
            return start;
        }
        let sum = |p: &Pose2| -> f64 {
            self.distances(p, points, &inliers).sum::<f64>() + predicted_cost(p, prediction)
        };
        let mut pose = start;
        let mut cost = sum(&pose);
        for _ in 0..self.config.refine_iterations {
            let r = optical_rotation(pose.theta);
            let (s, co) = pose.theta.sin_cos();
            // ∂R/∂θ, column by column (see `optical_rotation`).
            let dr = DMat3::from_cols(DVec3::new(co, 0.0, -s), DVec3::new(s, 0.0, co), DVec3::ZERO);
            let c = self.camera.centre(&pose);
            let (mut h, mut g) = (DMat3::ZERO, DVec3::ZERO);
            for (pm, info) in &inliers {
                let d = self.map.landmarks[pm.landmark].position - c;
                let q = points[pm.point].position - r * d;
                // ∂q/∂(x, y, θ): moving the camera by +x moves the landmark by −x in it.
                let j = DMat3::from_cols(r * DVec3::X, r * DVec3::Y, -(dr * d));
                let jt_w = j.transpose() * *info;
                h += jt_w * j;
                g += jt_w * q;
            }
            if let Some((p, w)) = prediction {
                let e = pose_difference(&pose, p);
                h += *w;
                g += *w * e;
            }
            if h.determinant().abs() < 1e-12 {
                break;
            }
            let step = -(h.inverse() * g);
            let next = Pose2::new(pose.x + step.x, pose.y + step.y, pose.theta + step.z);
            let next_cost = sum(&next);
            let s = &self.config.search;
            let outside = (next.x - start.x).abs() > s.half_xy
                || (next.y - start.y).abs() > s.half_xy
                || futago_msgs::wrap_angle(next.theta - start.theta).abs()
                    > s.half_yaw_deg.to_radians();
            if next_cost.partial_cmp(&cost) != Some(std::cmp::Ordering::Less) || outside {
                break;
            }
            let done = step.length() < 1e-7;
            (pose, cost) = (next, next_cost);
            if done {
                break;
            }
        }
        pose
    }

    /// Adds one frame: its triangulated `points` (right camera) and the right image's
    /// `keypoints`. `known`: the camera's pose, when the pass is placed by another source
    /// (the truth); else the seed's search finds it, about the last pose carried by
    /// `motion` (the camera's planar motion since the last frame, in the last frame, as the
    /// wheels report it) when there is one, weighed by [`MappingConfig::odometry`].
    pub fn add_frame(
        &mut self,
        points: &[StereoPoint],
        keypoints: &[Keypoint],
        known: Option<Pose2>,
        motion: Option<Pose2>,
    ) -> MappingStep {
        let prediction =
            motion.map(|m| (self.pose.compose(&m), self.config.odometry.information(&m)));
        let prior = prediction.map_or(self.pose, |p| p.0);
        let (_, first) = self.associate(&prior, points, keypoints);
        let pose = match known {
            Some(p) => p,
            None if first.len() >= 3 => {
                // Q⁻¹ per match for each heading searched (eq. 9 plus the stereo covariance).
                let infos = |yaw: f64| -> Vec<(PointMatch, DMat3)> {
                    let r = optical_rotation(yaw);
                    first
                        .iter()
                        .map(|m| {
                            let l = &self.map.landmarks[m.landmark];
                            let q = r * (l.covariance + self.pose_covariance) * r.transpose()
                                + points[m.point].covariance;
                            (*m, q.inverse())
                        })
                        .collect()
                };
                // Each heading's, made the first time the search reaches it (it visits the
                // window from the prior outwards, the headings in turn).
                let mut cache: Vec<(i64, Vec<(PointMatch, DMat3)>)> = Vec::new();
                let grid = grid_search_outward(&self.config.search, &prior, |p, bound| {
                    let key = (p.theta * 1e6).round() as i64;
                    let slot = match cache.iter().position(|(k, _)| *k == key) {
                        Some(i) => i,
                        None => {
                            cache.push((key, infos(p.theta)));
                            cache.len() - 1
                        }
                    };
                    match self.cost_below(p, points, &cache[slot].1, bound) {
                        Ok(sum) => sum + predicted_cost(p, prediction.as_ref()),
                        Err(partial) => partial,
                    }
                })
                .0;
                self.refine(grid, points, &infos(grid.theta), prediction.as_ref())
            }
            None => prior,
        };
        // The second matching, at the estimate (§2.3).
        let (view, matches) = self.associate(&pose, points, keypoints);
        let r = optical_rotation(pose.theta);
        let centre = self.camera.centre(&pose);
        let mut inliers = 0;
        let mut information = DMat3::ZERO;
        let mut matched_landmark = vec![false; self.map.landmarks.len()];
        let mut matched_point = vec![false; points.len()];
        for m in &matches {
            let p = &points[m.point];
            let l = &self.map.landmarks[m.landmark];
            let q = p.position - r * (l.position - centre);
            let big_q = r * l.covariance * r.transpose() + p.covariance;
            if q.dot(big_q.inverse() * q) >= self.config.outlier {
                continue;
            }
            inliers += 1;
            matched_landmark[m.landmark] = true;
            matched_point[m.point] = true;
            // Eq. 12's sum, in the world.
            let obs = r.transpose() * p.covariance * r;
            information += (l.covariance + obs).inverse();
        }
        // Eq. 12–13: Σ_r from the landmarks used, plus the search's quantisation.
        let e = self.config.search.step_xy;
        let quantisation = DMat3::from_diagonal(DVec3::new(e * e, e * e, 0.0));
        self.pose_covariance = if inliers >= 3 && known.is_none() {
            information.inverse() + quantisation
        } else {
            DMat3::ZERO
        };
        // Kalman fusion of matched landmarks; m and l for every candidate.
        for v in &view {
            let l = &mut self.map.landmarks[v.index];
            if !matched_landmark[v.index] {
                l.missed += 1;
            }
        }
        let mut new_points = Vec::new();
        for m in &matches {
            if !matched_point[m.point] {
                continue;
            }
            let p = &points[m.point];
            let k = &keypoints[p.keypoint];
            let world = r.transpose() * p.position + centre;
            let obs = r.transpose() * p.covariance * r;
            let l = &mut self.map.landmarks[m.landmark];
            let prior_info = l.covariance.inverse();
            let obs_info = obs.inverse();
            let cov = (prior_info + obs_info).inverse();
            l.position = cov * (prior_info * l.position + obs_info * world);
            l.covariance = 0.5 * (cov + cov.transpose());
            l.observed += 1;
            let bin = direction_bin(centre, l.position);
            set_view(l, bin, k);
        }
        for (i, p) in points.iter().enumerate() {
            if matched_point[i] {
                continue;
            }
            // A point that matched a landmark but failed the check at the estimate is not
            // added again (it is most likely that landmark, badly placed).
            if matches.iter().any(|m| m.point == i) {
                continue;
            }
            let k = &keypoints[p.keypoint];
            let world = r.transpose() * p.position + centre;
            let cov = r.transpose() * p.covariance * r;
            let mut l = Landmark {
                position: world,
                covariance: 0.5 * (cov + cov.transpose()),
                observed: 1,
                missed: 0,
                views: Vec::new(),
            };
            set_view(&mut l, direction_bin(centre, world), k);
            self.map.landmarks.push(l);
            new_points.push(i);
        }
        self.pose = pose;
        MappingStep {
            pose,
            points: points.len(),
            candidates: view.len(),
            matched: matches.len(),
            added: new_points.len(),
            inliers,
            new_points,
        }
    }
}

/// (x, y, θ) of `a` less `b`, the angle wrapped.
fn pose_difference(a: &Pose2, b: &Pose2) -> DVec3 {
    DVec3::new(
        a.x - b.x,
        a.y - b.y,
        futago_msgs::wrap_angle(a.theta - b.theta),
    )
}

/// The Mahalanobis distance of `pose` from the odometry's prediction (0 without one).
fn predicted_cost(pose: &Pose2, prediction: Option<&(Pose2, DMat3)>) -> f64 {
    prediction.map_or(0.0, |(p, w)| {
        let e = pose_difference(pose, p);
        e.dot(*w * e)
    })
}

/// Renews (or adds) the landmark's view from `bin` with keypoint `k`'s descriptor and
/// contrast.
fn set_view(l: &mut Landmark, bin: u8, k: &Keypoint) {
    let v = View {
        bin,
        contrast: k.contrast,
        descriptor: k.descriptor,
    };
    match l.views.iter_mut().find(|x| x.bin == bin) {
        Some(x) => *x = v,
        None => {
            l.views.push(v);
            l.views.sort_by_key(|x| x.bin);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::perception::trinocular::{Rig, point};
    use futago_msgs::camera::Intrinsics;
    use rand::{Rng, SeedableRng};

    /// A world of random textured points on the walls of a 6 × 4 m room, each with its own
    /// descriptor.
    fn room() -> (Rig, Camera, Vec<(DVec3, [u8; 128])>) {
        let rig = Rig {
            intrinsics: Intrinsics::from_fov(320, 240, 60f64.to_radians(), 46.8f64.to_radians())
                .unwrap(),
            baseline: 0.0996,
        };
        let camera = Camera {
            intrinsics: rig.intrinsics,
            height: 0.5,
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut world = Vec::new();
        for i in 0..600 {
            let t = rng.random_range(0.0..1.0);
            let z = rng.random_range(0.1..2.5);
            let p = match i % 4 {
                0 => DVec3::new(-3.0 + 6.0 * t, 2.0, z),
                1 => DVec3::new(-3.0 + 6.0 * t, -2.0, z),
                2 => DVec3::new(3.0, -2.0 + 4.0 * t, z),
                _ => DVec3::new(-3.0, -2.0 + 4.0 * t, z),
            };
            let mut d = [0u8; 128];
            for v in d.iter_mut() {
                *v = rng.random_range(0..40);
            }
            world.push((p, d));
        }
        (rig, camera, world)
    }

    /// The visible points of `world` from `truth`, triangulated from exact pixels rounded to
    /// 0.1 px.
    fn frame(
        rig: &Rig,
        camera: &Camera,
        world: &[(DVec3, [u8; 128])],
        truth: &Pose2,
    ) -> (Vec<Keypoint>, Vec<StereoPoint>) {
        let (mut kps, mut pts) = (Vec::new(), Vec::new());
        for (p, d) in world {
            let o = camera.to_optical(truth, *p);
            let k = &rig.intrinsics;
            if o.z < 0.5 {
                continue;
            }
            let q = |v: f64| (v * 10.0).round() / 10.0;
            let (xr, yr) = (q(k.fx * o.x / o.z + k.cx), q(k.fy * o.y / o.z + k.cy));
            if !camera.inside(glam::DVec2::new(xr, yr)) {
                continue;
            }
            let disp = k.fx * rig.baseline / o.z;
            let (pos, cov) = point(rig, [q(xr + disp), xr, yr, q(yr + disp)], [0.5; 4]);
            kps.push(Keypoint {
                x: xr as f32,
                y: yr as f32,
                sigma: 1.6,
                octave: 0,
                level: 1.0,
                angle: 0.0,
                contrast: 0.05,
                descriptor: *d,
            });
            pts.push(StereoPoint {
                keypoint: kps.len() - 1,
                position: pos,
                covariance: cov,
                disparity: disp,
            });
        }
        (kps, pts)
    }

    /// The camera steps forward 3 cm and turns 2° a frame; the seed's search (no motion
    /// predicted) tracks it and the landmarks settle.
    #[test]
    fn the_seed_search_tracks_a_drive_and_landmarks_settle() {
        let (rig, camera, world) = room();
        let mut mapper = LandmarkMapper::new(
            camera,
            rig.baseline,
            MappingConfig::default(),
            Pose2::new(-1.0, 0.0, 0.0),
        );
        let mut worst: f64 = 0.0;
        for f in 0..40 {
            let truth = Pose2::new(-1.0 + 0.03 * f as f64, 0.0, (2.0 * f as f64).to_radians());
            let (kps, pts) = frame(&rig, &camera, &world, &truth);
            let known = (f == 0).then_some(truth);
            let step = mapper.add_frame(&pts, &kps, known, None);
            if f > 0 {
                assert!(step.inliers > 20, "frame {f}: {step:?}");
            }
            worst = worst.max(step.pose.distance(&truth));
            assert!(
                (step.pose.theta - truth.theta).abs() < 1.5f64.to_radians(),
                "{f}: {step:?}"
            );
        }
        assert!(worst < 0.03, "worst position error {worst}");
        // Landmarks seen in many frames were fused: their covariance shrank and they carry
        // their counters.
        let seen: Vec<&Landmark> = mapper
            .map
            .landmarks
            .iter()
            .filter(|l| l.observed >= 10)
            .collect();
        assert!(seen.len() > 50, "{}", seen.len());
        let mut near = 0;
        for l in &seen {
            let best = world
                .iter()
                .map(|(p, _)| (*p - l.position).length())
                .fold(f64::INFINITY, f64::min);
            near += (best < 0.05) as usize;
        }
        assert!(
            near as f64 > 0.9 * seen.len() as f64,
            "{near} of {}",
            seen.len()
        );
    }

    /// Steps off the search's grid (3.37 cm and 2.3° a frame): the Gauss–Newton refinement
    /// places frames well inside the grid's quantisation (±5 mm, ±0.5°), which the grid pose
    /// alone does not.
    #[test]
    fn refinement_places_frames_between_the_grid_steps() {
        let (rig, camera, world) = room();
        let worst = |iterations: usize| -> (f64, f64) {
            let config = MappingConfig {
                refine_iterations: iterations,
                ..MappingConfig::default()
            };
            let start = Pose2::new(-1.0, 0.0, 0.0);
            let mut mapper = LandmarkMapper::new(camera, rig.baseline, config, start);
            let (mut pos, mut yaw): (f64, f64) = (0.0, 0.0);
            for f in 0..30 {
                let truth =
                    Pose2::new(-1.0 + 0.0337 * f as f64, 0.0, (2.3 * f as f64).to_radians());
                let (kps, pts) = frame(&rig, &camera, &world, &truth);
                let step = mapper.add_frame(&pts, &kps, (f == 0).then_some(truth), None);
                pos = pos.max(step.pose.distance(&truth));
                yaw = yaw.max(futago_msgs::wrap_angle(step.pose.theta - truth.theta).abs());
            }
            (pos, yaw.to_degrees())
        };
        let (grid_pos, grid_yaw) = worst(0);
        let (pos, yaw) = worst(5);
        assert!(grid_yaw > 0.25, "the grid alone: {grid_pos} m, {grid_yaw}°");
        assert!(pos < 0.004 && yaw < 0.1, "refined: {pos} m, {yaw}°");
    }

    /// With no points at all (the camera blind), a frame is placed where the wheels' motion
    /// carries the last pose; without a prediction it stays at the last pose (the seed).
    #[test]
    fn a_blind_frame_follows_the_wheels_prediction() {
        let (rig, camera, _) = room();
        let start = Pose2::new(0.0, 0.0, 0.3);
        let motion = Pose2::new(0.05, 0.01, 0.1);
        let mut mapper = LandmarkMapper::new(camera, rig.baseline, MappingConfig::default(), start);
        let step = mapper.add_frame(&[], &[], None, Some(motion));
        let expected = start.compose(&motion);
        assert!(step.pose.distance(&expected) < 1e-12, "{:?}", step.pose);
        assert!((step.pose.theta - expected.theta).abs() < 1e-12);
        let step = mapper.add_frame(&[], &[], None, None);
        assert_eq!(step.pose, expected);
    }
}
