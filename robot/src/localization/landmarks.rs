//! Monocular localisation in a map of visual landmarks (seed 001 §3): the map's landmarks are
//! projected into the camera's image at the last pose, matched to the frame's SIFT keypoints,
//! and the planar pose found by an exhaustive search for the least sum of image-plane
//! Mahalanobis distances (eqs. 14–19). [`Selection::Delegates`] projects and matches only the
//! seed's delegate landmarks (§3.2, eq. 23): the viewing frustum cut into image cells and depth
//! bins sized by the spread of the landmarks in view, at most one landmark a cell, ranked by
//! its success rate m/(m+l) and then by its contrast. [`pnp_ransac`] is a modern baseline on
//! the same matches, and [`LandmarkMap::summarised`] a modern map compression.
//!
//! Frames: the map is in the world frame (x forward, y left, z up). The camera is levelled,
//! at a known height, and its planar pose (x, y, yaw of its body frame) is the state, as the
//! seed's (X, Z, θ): the robot's pose follows from the camera's mount. Pixels follow
//! [`Intrinsics`] (OpenCV's optical frame: x right, y down, z forward).

use crate::perception::sift::{self, Descriptor, Keypoint};
use futago_msgs::Pose2;
use futago_msgs::camera::Intrinsics;
use futago_msgs::landmarks::{self as file, LandmarkFile, LandmarkRecord, ViewRecord};
use glam::{DMat2, DMat3, DVec2, DVec3};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Viewing-direction bins, 10° each (seed 001 §2.1).
pub const BINS: u8 = file::DIRECTION_BINS;

/// A landmark seen from one viewing direction.
#[derive(Debug, Clone, PartialEq)]
pub struct View {
    /// Direction bin: the azimuth of the ray from the camera to the landmark.
    pub bin: u8,
    /// SIFT contrast |D| from that direction.
    pub contrast: f32,
    pub descriptor: Descriptor,
}

/// A 3D landmark (seed 001 §2.1): position and covariance in the map, a descriptor and
/// contrast per viewing direction, and the counters m (predicted and seen) and l (predicted
/// and not seen).
#[derive(Debug, Clone, PartialEq)]
pub struct Landmark {
    pub position: DVec3,
    pub covariance: DMat3,
    pub observed: u32,
    pub missed: u32,
    pub views: Vec<View>,
}

impl Landmark {
    /// Success rate m / (m + l) (the seed prints m/(m+n); l is the counter it defines).
    pub fn success(&self) -> f64 {
        let n = self.observed + self.missed;
        if n == 0 {
            0.0
        } else {
            self.observed as f64 / n as f64
        }
    }

    /// The view from the bin nearest `bin`, within `reach` bins either side.
    pub fn view_near(&self, bin: u8, reach: u8) -> Option<&View> {
        self.views
            .iter()
            .map(|v| (bin_distance(v.bin, bin), v))
            .filter(|(d, _)| *d <= reach)
            .min_by_key(|(d, v)| (*d, v.bin))
            .map(|(_, v)| v)
    }
}

/// Bins between two directions, the short way round.
pub fn bin_distance(a: u8, b: u8) -> u8 {
    let d = (a as i16 - b as i16).rem_euclid(BINS as i16) as u8;
    d.min(BINS - d)
}

/// The direction bin of the ray from `from` to `to`: its azimuth in the xy plane.
pub fn direction_bin(from: DVec3, to: DVec3) -> u8 {
    let a = (to.y - from.y).atan2(to.x - from.x);
    (((a + PI) / (2.0 * PI) * BINS as f64).floor() as i64).rem_euclid(BINS as i64) as u8
}

/// A map of landmarks.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LandmarkMap {
    pub landmarks: Vec<Landmark>,
}

impl LandmarkMap {
    /// The map a file holds (already checked by [`LandmarkFile::read`]).
    pub fn from_file(f: &LandmarkFile) -> Result<LandmarkMap, String> {
        let mut landmarks = Vec::with_capacity(f.landmarks.len());
        for (i, r) in f.landmarks.iter().enumerate() {
            let c = r.covariance;
            let views = r
                .views
                .iter()
                .map(|v| {
                    Ok(View {
                        bin: v.bin,
                        contrast: v.contrast,
                        descriptor: file::from_hex(&v.descriptor)
                            .map_err(|e| format!("landmarks[{i}]: {e}"))?,
                    })
                })
                .collect::<Result<Vec<_>, String>>()?;
            landmarks.push(Landmark {
                position: DVec3::from_array(r.position),
                covariance: DMat3::from_cols_array(&[
                    c[0], c[1], c[2], c[1], c[3], c[4], c[2], c[4], c[5],
                ]),
                observed: r.observed,
                missed: r.missed,
                views,
            });
        }
        Ok(LandmarkMap { landmarks })
    }

    /// The map as a file.
    pub fn to_file(&self) -> LandmarkFile {
        LandmarkFile::new(
            self.landmarks
                .iter()
                .map(|l| {
                    let c = l.covariance;
                    LandmarkRecord {
                        position: l.position.to_array(),
                        covariance: [
                            c.x_axis.x, c.y_axis.x, c.z_axis.x, c.y_axis.y, c.z_axis.y, c.z_axis.z,
                        ],
                        observed: l.observed,
                        missed: l.missed,
                        views: l
                            .views
                            .iter()
                            .map(|v| ViewRecord {
                                bin: v.bin,
                                contrast: v.contrast,
                                descriptor: file::to_hex(&v.descriptor),
                            })
                            .collect(),
                    }
                })
                .collect(),
        )
    }

    /// A summary map (Mühlfellner et al., "Summary maps for lifelong visual localization",
    /// JFR 2016): the share `keep` of the landmarks seen most often, ties by contrast, a
    /// modern map compression beside the seed's per-frame selection.
    pub fn summarised(&self, keep: f64) -> LandmarkMap {
        let mut order: Vec<usize> = (0..self.landmarks.len()).collect();
        let best_contrast = |l: &Landmark| l.views.iter().map(|v| v.contrast).fold(0f32, f32::max);
        order.sort_by(|&a, &b| {
            let (la, lb) = (&self.landmarks[a], &self.landmarks[b]);
            lb.observed
                .cmp(&la.observed)
                .then(best_contrast(lb).total_cmp(&best_contrast(la)))
                .then(a.cmp(&b))
        });
        let n = ((self.landmarks.len() as f64) * keep.clamp(0.0, 1.0)).round() as usize;
        let mut kept: Vec<usize> = order.into_iter().take(n).collect();
        kept.sort_unstable();
        LandmarkMap {
            landmarks: kept.iter().map(|&i| self.landmarks[i].clone()).collect(),
        }
    }
}

/// A levelled camera at a fixed height, whose state is its planar pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    pub intrinsics: Intrinsics,
    /// Height of the optical centre above the floor, m.
    pub height: f64,
}

/// World → optical rotation for a camera of yaw `yaw`: body x forward, y left, z up becomes
/// optical x right (−y), y down (−z), z forward (x).
pub fn optical_rotation(yaw: f64) -> DMat3 {
    let (s, c) = yaw.sin_cos();
    // Rows: optical x = −body y, optical y = −body z, optical z = body x, with
    // body = Rz(−yaw) · world.
    DMat3::from_cols(
        DVec3::new(s, 0.0, c),
        DVec3::new(-c, 0.0, s),
        DVec3::new(0.0, -1.0, 0.0),
    )
}

impl Camera {
    /// The optical centre of a camera at planar pose `pose`.
    pub fn centre(&self, pose: &Pose2) -> DVec3 {
        DVec3::new(pose.x, pose.y, self.height)
    }

    /// A world point in the optical frame of the camera at `pose`.
    pub fn to_optical(&self, pose: &Pose2, p: DVec3) -> DVec3 {
        optical_rotation(pose.theta) * (p - self.centre(pose))
    }

    /// Pixel of an optical-frame point (eq. 15), or none behind the camera.
    pub fn pixel(&self, o: DVec3) -> Option<DVec2> {
        if o.z <= 1e-6 {
            return None;
        }
        let k = &self.intrinsics;
        Some(DVec2::new(k.fx * o.x / o.z + k.cx, k.fy * o.y / o.z + k.cy))
    }

    /// Whether a pixel lies in the image.
    pub fn inside(&self, p: DVec2) -> bool {
        let k = &self.intrinsics;
        p.x >= -0.5 && p.y >= -0.5 && p.x < k.width as f64 - 0.5 && p.y < k.height as f64 - 0.5
    }

    /// The image-plane covariance of a landmark of world covariance `cov` seen at optical
    /// point `o` from yaw `yaw` (eq. 18: J_P R Σ Rᵀ J_Pᵀ).
    pub fn pixel_covariance(&self, yaw: f64, o: DVec3, cov: &DMat3) -> DMat2 {
        let k = &self.intrinsics;
        let r = optical_rotation(yaw);
        let c = r * *cov * r.transpose();
        let iz = 1.0 / o.z;
        // J_P rows: [fx/z, 0, −fx x/z²], [0, fy/z, −fy y/z²].
        let j0 = DVec3::new(k.fx * iz, 0.0, -k.fx * o.x * iz * iz);
        let j1 = DVec3::new(0.0, k.fy * iz, -k.fy * o.y * iz * iz);
        let (c0, c1) = (c * j0, c * j1);
        DMat2::from_cols(
            DVec2::new(j0.dot(c0), j1.dot(c0)),
            DVec2::new(j0.dot(c1), j1.dot(c1)),
        )
    }
}

/// The exhaustive search's window and steps (seed 001 §4.1: ±100 mm, ±100 mm, ±10°, in steps
/// of 10 mm, 10 mm and 1°: 9,261 poses).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SearchConfig {
    /// Half-width of the position window, m.
    pub half_xy: f64,
    /// Position step, m.
    pub step_xy: f64,
    /// Half-width of the heading window, degrees.
    pub half_yaw_deg: f64,
    /// Heading step, degrees.
    pub step_yaw_deg: f64,
}

impl Default for SearchConfig {
    fn default() -> Self {
        SearchConfig {
            half_xy: 0.1,
            step_xy: 0.01,
            half_yaw_deg: 10.0,
            step_yaw_deg: 1.0,
        }
    }
}

impl SearchConfig {
    /// Checks every field; the error names the key below `prefix`.
    pub fn validate(&self, prefix: &str) -> Result<(), crate::config::ConfigError> {
        crate::config::check_ranges(
            prefix,
            &[
                ("half_xy", self.half_xy, 0.0, 5.0),
                ("step_xy", self.step_xy, 1e-4, 1.0),
                ("half_yaw_deg", self.half_yaw_deg, 0.0, 90.0),
                ("step_yaw_deg", self.step_yaw_deg, 0.01, 45.0),
            ],
        )?;
        let n = |h: f64, s: f64| 2 * (h / s).round() as usize + 1;
        let poses = n(self.half_xy, self.step_xy).pow(2) * n(self.half_yaw_deg, self.step_yaw_deg);
        crate::config::check_counts(prefix, &[("poses searched", poses, 1, 10_000_000)])
    }

    /// The offsets searched along one axis.
    fn steps(half: f64, step: f64) -> Vec<f64> {
        let n = (half / step).round() as i64;
        (-n..=n).map(|i| i as f64 * step).collect()
    }

    /// Every pose of the window about `prior` (offsets in the map frame), heading outermost.
    pub fn poses(&self, prior: &Pose2) -> impl Iterator<Item = Pose2> + '_ {
        let xy = Self::steps(self.half_xy, self.step_xy);
        let yaw = Self::steps(
            self.half_yaw_deg.to_radians(),
            self.step_yaw_deg.to_radians(),
        );
        let prior = *prior;
        yaw.into_iter().flat_map(move |t| {
            let xy = xy.clone();
            xy.clone().into_iter().flat_map(move |dx| {
                xy.clone()
                    .into_iter()
                    .map(move |dy| Pose2::new(prior.x + dx, prior.y + dy, prior.theta + t))
            })
        })
    }
}

/// The pose of the window with the least `cost` (the first such in [`SearchConfig::poses`]'s
/// order), and that cost. `cost(pose, bound)` is handed the least cost so far: a cost that
/// is a sum of non-negative terms may stop adding once it reaches `bound` and return what it
/// has, since that pose can no longer be the least, and the search's result is the same.
/// The stack searches with [`grid_search_outward`], which finds the same pose with fewer
/// terms; this, the window in order, is its definition.
pub fn grid_search(
    config: &SearchConfig,
    prior: &Pose2,
    mut cost: impl FnMut(&Pose2, f64) -> f64,
) -> (Pose2, f64) {
    let mut best = (*prior, f64::INFINITY);
    for p in config.poses(prior) {
        let c = cost(&p, best.1);
        if c < best.1 {
            best = (p, c);
        }
    }
    best
}

/// [`grid_search`]'s pose and cost, the window's poses visited from the prior outwards
/// (in shells of growing steps from it, the largest of the three axes' counts) so that the
/// least cost so far, handed to `cost` as its bound, is small from the first poses on: the
/// pose of a frame's least cost lies near the last frame's, and the poses far from it then
/// stop after a few terms. `cost(pose, bound)` may stop adding once its sum exceeds `bound`
/// (not merely reaches it) and return what it has; among poses of equal least cost the one
/// first in [`SearchConfig::poses`]'s order is kept, so the result is [`grid_search`]'s.
pub fn grid_search_outward(
    config: &SearchConfig,
    prior: &Pose2,
    mut cost: impl FnMut(&Pose2, f64) -> f64,
) -> (Pose2, f64) {
    let xy = SearchConfig::steps(config.half_xy, config.step_xy);
    let yaw = SearchConfig::steps(
        config.half_yaw_deg.to_radians(),
        config.step_yaw_deg.to_radians(),
    );
    let (nxy, nyaw) = ((xy.len() / 2) as i64, (yaw.len() / 2) as i64);
    let mut best = (*prior, f64::INFINITY);
    let mut best_index: Option<usize> = None;
    let mut visit = |t: i64, x: i64, y: i64| {
        let (it, ix, iy) = ((t + nyaw) as usize, (x + nxy) as usize, (y + nxy) as usize);
        let p = Pose2::new(prior.x + xy[ix], prior.y + xy[iy], prior.theta + yaw[it]);
        let index = (it * xy.len() + ix) * xy.len() + iy;
        let c = cost(&p, best.1);
        if c < best.1 || (c == best.1 && best_index.is_some_and(|b| index < b)) {
            best = (p, c);
            best_index = Some(index);
        }
    };
    for r in 0..=nxy.max(nyaw) {
        let (rt, rxy) = (r.min(nyaw), r.min(nxy));
        for t in -rt..=rt {
            for x in -rxy..=rxy {
                if t.abs() == r || x.abs() == r {
                    for y in -rxy..=rxy {
                        visit(t, x, y);
                    }
                } else if r <= nxy {
                    // Only the shell's two faces across y.
                    visit(t, x, -r);
                    visit(t, x, r);
                }
            }
        }
    }
    best
}

/// The seed's delegate selection (§3.2, eq. 23).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SelectionConfig {
    /// Image cell width and height as multiples of the landmarks' spread in u and v (α, β).
    pub alpha: f64,
    pub beta: f64,
    /// Depth bin as a multiple of their spread in depth (γ); none: no depth division (γ = ∞).
    pub gamma: Option<f64>,
    /// Fewer landmarks in view than this: all are used (the seed's threshold of 20).
    pub min_landmarks: usize,
}

impl Default for SelectionConfig {
    fn default() -> Self {
        SelectionConfig {
            alpha: 0.2,
            beta: 0.2,
            gamma: Some(0.5),
            min_landmarks: 20,
        }
    }
}

/// Parameters of the monocular localiser.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MonocularConfig {
    pub search: SearchConfig,
    pub selection: SelectionConfig,
    /// Matching window about a landmark's predicted pixel, px either way (eqs. 16–17: 40 px
    /// at 320 × 240).
    pub gate_px: f64,
    /// Lowe's ratio test: nearest over second nearest at most this (eq. 3: 0.7).
    pub ratio: f64,
    /// Largest descriptor distance accepted (the seed's 0.2 for stereo; it gives none here).
    pub max_distance: f64,
    /// Views within this many direction bins count as seen from here (±20°: 2).
    pub direction_reach: u8,
    /// Landmarks nearer or farther than this along the optical axis are not projected, m.
    pub min_depth: f64,
    pub max_depth: f64,
    /// A match's Mahalanobis distance (eq. 19) counts at most this much: a false match costs
    /// a constant instead of pulling the pose (χ² of 2 degrees of freedom at 99 %: 9.21).
    pub outlier: f64,
    /// Image noise of a keypoint at octave sampling d_s: this × d_s px, added to eq. 18's
    /// covariance (the seed's stereo σ of 0.5 d_s px).
    pub pixel_sigma: f64,
    /// Refine the search's best pose by Gauss–Newton on eq. 19 over the matches within the
    /// cap there (kept only where it lowers the cost). The seed's grid alone quantises the
    /// heading to its 1° step, and with far landmarks a heading off by half a step is taken up
    /// by a sideways shift: 0.5° at 10 m is 9 cm.
    pub refine: bool,
}

impl Default for MonocularConfig {
    fn default() -> Self {
        MonocularConfig {
            search: SearchConfig::default(),
            selection: SelectionConfig::default(),
            gate_px: 40.0,
            ratio: 0.7,
            max_distance: 0.4,
            direction_reach: 2,
            min_depth: 0.2,
            max_depth: 12.0,
            outlier: 9.21,
            pixel_sigma: 0.5,
            refine: true,
        }
    }
}

impl MonocularConfig {
    /// Checks every field; the error names the key below `prefix`.
    pub fn validate(&self, prefix: &str) -> Result<(), crate::config::ConfigError> {
        self.search.validate(&format!("{prefix}.search"))?;
        let s = &self.selection;
        crate::config::check_ranges(
            &format!("{prefix}.selection"),
            &[
                ("alpha", s.alpha, 1e-3, 10.0),
                ("beta", s.beta, 1e-3, 10.0),
                ("gamma", s.gamma.unwrap_or(1.0), 1e-3, 10.0),
            ],
        )?;
        crate::config::check_counts(
            &format!("{prefix}.selection"),
            &[("min_landmarks", s.min_landmarks, 0, 1_000_000)],
        )?;
        crate::config::check_ranges(
            prefix,
            &[
                ("gate_px", self.gate_px, 1.0, 10_000.0),
                ("ratio", self.ratio, 0.0, 1.0),
                ("max_distance", self.max_distance, 0.0, 2.0),
                ("min_depth", self.min_depth, 0.0, 100.0),
                ("max_depth", self.max_depth, self.min_depth + 1e-3, 1000.0),
                ("outlier", self.outlier, 0.01, 1e6),
                ("pixel_sigma", self.pixel_sigma, 0.0, 100.0),
            ],
        )?;
        crate::config::check_counts(
            prefix,
            &[(
                "direction_reach",
                self.direction_reach as usize,
                0,
                BINS as usize / 2,
            )],
        )
    }
}

/// Which landmarks a frame projects and matches.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Selection {
    /// Every landmark in view (the seed's "all keypoints").
    All,
    /// The seed's delegates.
    Delegates,
}

/// A landmark in view at the prior pose.
#[derive(Debug, Clone, Copy)]
pub struct InView {
    pub index: usize,
    pub pixel: DVec2,
    pub depth: f64,
    /// Index of the view (direction) it is matched with.
    pub view: usize,
}

/// The landmarks in view of a camera at `pose`: in front within the depth range, inside the
/// image, and seen before from within `direction_reach` bins of this direction (§3.1).
pub fn in_view(
    map: &LandmarkMap,
    camera: &Camera,
    pose: &Pose2,
    config: &MonocularConfig,
) -> Vec<InView> {
    let centre = camera.centre(pose);
    let r = optical_rotation(pose.theta);
    let mut out = Vec::new();
    for (index, l) in map.landmarks.iter().enumerate() {
        let o = r * (l.position - centre);
        if o.z < config.min_depth || o.z > config.max_depth {
            continue;
        }
        let Some(pixel) = camera.pixel(o) else {
            continue;
        };
        if !camera.inside(pixel) {
            continue;
        }
        let bin = direction_bin(centre, l.position);
        let Some(v) = l.view_near(bin, config.direction_reach) else {
            continue;
        };
        let view = l.views.iter().position(|x| std::ptr::eq(x, v)).unwrap_or(0);
        out.push(InView {
            index,
            pixel,
            depth: o.z,
            view,
        });
    }
    out
}

fn spread(v: impl Iterator<Item = f64> + Clone) -> f64 {
    let n = v.clone().count().max(1) as f64;
    let m = v.clone().sum::<f64>() / n;
    (v.map(|x| (x - m) * (x - m)).sum::<f64>() / n).sqrt()
}

/// The seed's delegates among `view` (§3.2): cells of α σ_u × β σ_v pixels and γ σ_Z metres
/// of depth, at most one landmark a cell, the highest success rate m/(m+l), then the highest
/// contrast from this direction (then the lowest index). Fewer than `min_landmarks` in view:
/// all of them.
pub fn delegates(map: &LandmarkMap, view: &[InView], config: &SelectionConfig) -> Vec<InView> {
    if view.len() < config.min_landmarks.max(1) {
        return view.to_vec();
    }
    let su = spread(view.iter().map(|v| v.pixel.x));
    let sv = spread(view.iter().map(|v| v.pixel.y));
    let sz = spread(view.iter().map(|v| v.depth));
    let (wu, wv) = ((config.alpha * su).max(1.0), (config.beta * sv).max(1.0));
    let wz = config.gamma.map(|g| (g * sz).max(1e-3));
    let mut best: rustc_hash::FxHashMap<(i64, i64, i64), InView> = Default::default();
    let key = |v: &InView| {
        let l = &map.landmarks[v.index];
        (l.success(), l.views[v.view].contrast)
    };
    for v in view {
        let cell = (
            (v.pixel.x / wu).floor() as i64,
            (v.pixel.y / wv).floor() as i64,
            wz.map(|w| (v.depth / w).floor() as i64).unwrap_or(0),
        );
        match best.get(&cell) {
            Some(b) => {
                let (kb, kv) = (key(b), key(v));
                let better = kv.0 > kb.0
                    || (kv.0 == kb.0 && (kv.1 > kb.1 || (kv.1 == kb.1 && v.index < b.index)));
                if better {
                    best.insert(cell, *v);
                }
            }
            None => {
                best.insert(cell, *v);
            }
        }
    }
    let mut out: Vec<InView> = best.into_values().collect();
    out.sort_by_key(|v| v.index);
    out
}

/// A landmark matched to a keypoint.
#[derive(Debug, Clone, Copy)]
pub struct Match {
    pub landmark: usize,
    pub keypoint: usize,
}

/// Matches `projected` landmarks to `keypoints` (§3.1): keypoints within `gate_px` of the
/// predicted pixel, the nearest descriptor passing the ratio test and `max_distance`, one to
/// one (a keypoint claimed by two landmarks is dropped). Returns the matches and the number
/// of descriptor comparisons made.
pub fn match_landmarks(
    map: &LandmarkMap,
    projected: &[InView],
    keypoints: &[Keypoint],
    grid: &KeypointGrid,
    config: &MonocularConfig,
) -> (Vec<Match>, usize) {
    let mut comparisons = 0;
    let mut claims: rustc_hash::FxHashMap<usize, Option<usize>> = Default::default();
    for (pi, p) in projected.iter().enumerate() {
        let d = &map.landmarks[p.index].views[p.view].descriptor;
        let (mut best, mut second) = ((f32::INFINITY, usize::MAX), f32::INFINITY);
        for k in grid.near(p.pixel, config.gate_px) {
            let kp = &keypoints[k];
            if (kp.x as f64 - p.pixel.x).abs() > config.gate_px
                || (kp.y as f64 - p.pixel.y).abs() > config.gate_px
            {
                continue;
            }
            comparisons += 1;
            let dist = sift::distance(d, &kp.descriptor);
            if dist < best.0 {
                second = best.0;
                best = (dist, k);
            } else if dist < second {
                second = dist;
            }
        }
        if best.1 == usize::MAX
            || best.0 as f64 > config.max_distance
            || !crate::perception::trinocular::passes_ratio(best.0, second, config.ratio)
        {
            continue;
        }
        claims
            .entry(best.1)
            .and_modify(|c| *c = None)
            .or_insert(Some(pi));
    }
    let mut out: Vec<Match> = claims
        .into_iter()
        .filter_map(|(k, c)| {
            c.map(|pi| Match {
                landmark: projected[pi].index,
                keypoint: k,
            })
        })
        .collect();
    out.sort_by_key(|m| (m.landmark, m.keypoint));
    (out, comparisons)
}

/// A frame's keypoints, bucketed for the matching window.
pub struct Frame {
    pub keypoints: Vec<Keypoint>,
    pub grid: KeypointGrid,
}

impl Frame {
    /// Buckets of 20 px over a `width` × `height` image.
    pub fn new(keypoints: Vec<Keypoint>, width: u32, height: u32) -> Frame {
        let grid = KeypointGrid::new(&keypoints, width, height, 20.0);
        Frame { keypoints, grid }
    }
}

/// Keypoints bucketed by pixel, for the matching window.
pub struct KeypointGrid {
    cell: f64,
    cols: usize,
    rows: usize,
    cells: Vec<Vec<usize>>,
}

impl KeypointGrid {
    pub fn new(keypoints: &[Keypoint], width: u32, height: u32, cell: f64) -> KeypointGrid {
        let cols = (width as f64 / cell).ceil().max(1.0) as usize;
        let rows = (height as f64 / cell).ceil().max(1.0) as usize;
        let mut cells = vec![Vec::new(); cols * rows];
        for (i, k) in keypoints.iter().enumerate() {
            let c = ((k.x as f64 / cell).floor().max(0.0) as usize).min(cols - 1);
            let r = ((k.y as f64 / cell).floor().max(0.0) as usize).min(rows - 1);
            cells[r * cols + c].push(i);
        }
        KeypointGrid {
            cell,
            cols,
            rows,
            cells,
        }
    }

    /// Keypoints in the cells that the square of half-width `half` about `p` touches.
    pub fn near(&self, p: DVec2, half: f64) -> impl Iterator<Item = usize> + '_ {
        let lo = |v: f64, n: usize| ((v / self.cell).floor().max(0.0) as usize).min(n - 1);
        let (c0, c1) = (lo(p.x - half, self.cols), lo(p.x + half, self.cols));
        let (r0, r1) = (lo(p.y - half, self.rows), lo(p.y + half, self.rows));
        (r0..=r1).flat_map(move |r| {
            (c0..=c1).flat_map(move |c| self.cells[r * self.cols + c].iter().copied())
        })
    }
}

/// A match prepared for the pose search: the landmark's position, the keypoint's pixel and
/// the inverse of eq. 18's covariance (at the prior pose) plus the keypoint's noise.
#[derive(Debug, Clone, Copy)]
pub struct Prepared {
    pub position: DVec3,
    pub pixel: DVec2,
    pub information: DMat2,
}

/// Prepares matches at the prior pose.
pub fn prepare(
    map: &LandmarkMap,
    camera: &Camera,
    prior: &Pose2,
    matches: &[Match],
    keypoints: &[Keypoint],
    config: &MonocularConfig,
) -> Vec<Prepared> {
    matches
        .iter()
        .filter_map(|m| {
            let l = &map.landmarks[m.landmark];
            let k = &keypoints[m.keypoint];
            let o = camera.to_optical(prior, l.position);
            if o.z <= 1e-3 {
                return None;
            }
            let s = config.pixel_sigma * k.sampling() as f64;
            let cov = camera.pixel_covariance(prior.theta, o, &l.covariance)
                + DMat2::from_diagonal(DVec2::splat(s * s));
            (cov.determinant() > 0.0).then(|| Prepared {
                position: l.position,
                pixel: DVec2::new(k.x as f64, k.y as f64),
                information: cov.inverse(),
            })
        })
        .collect()
}

/// Eq. 19 at `pose`: the sum of the matches' image-plane Mahalanobis distances, each capped
/// at `outlier`.
pub fn reprojection_cost(camera: &Camera, pose: &Pose2, m: &[Prepared], outlier: f64) -> f64 {
    reprojection_cost_below(camera, pose, m, outlier, f64::INFINITY)
}

/// [`reprojection_cost`], which stops adding once the sum exceeds `bound` and returns the sum
/// so far: each term is a Mahalanobis distance (the information is positive definite, the
/// pixel noise's variance added to every covariance) or the cap, never negative, so the whole
/// sum would be more, and [`grid_search`] and [`grid_search_outward`] keep the same pose.
/// Most of the search's poses are far from the least cost, and stop after a few of the
/// matches.
pub fn reprojection_cost_below(
    camera: &Camera,
    pose: &Pose2,
    m: &[Prepared],
    outlier: f64,
    bound: f64,
) -> f64 {
    let r = optical_rotation(pose.theta);
    let c = camera.centre(pose);
    let k = &camera.intrinsics;
    let mut sum = 0.0;
    for p in m {
        let o = r * (p.position - c);
        let d = if o.z <= 1e-3 {
            outlier
        } else {
            let e = DVec2::new(
                k.fx * o.x / o.z + k.cx - p.pixel.x,
                k.fy * o.y / o.z + k.cy - p.pixel.y,
            );
            e.dot(p.information * e).min(outlier)
        };
        sum += d;
        if sum > bound {
            return sum;
        }
    }
    sum
}

/// One frame's localisation.
#[derive(Debug, Clone)]
pub struct Estimate {
    /// The camera's planar pose.
    pub pose: Pose2,
    /// Landmarks in view at the prior pose.
    pub in_view: usize,
    /// Landmarks projected and matched against the keypoints.
    pub projected: usize,
    pub matched: usize,
    /// Matches within the outlier cap at the estimate.
    pub inliers: usize,
    /// Descriptor comparisons made in matching.
    pub comparisons: usize,
    /// Wall time of the parts, s: choosing the landmarks, matching them, searching the pose.
    pub select_s: f64,
    pub match_s: f64,
    pub search_s: f64,
}

/// How a frame's pose is found from its matches.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Solver {
    /// The seed's exhaustive search of eq. 19.
    Search,
    /// RANSAC over the matches, the modern baseline ([`pnp_ransac`]).
    PnpRansac { seed: u64 },
}

/// Localises one frame (§3.1): landmarks in view at `prior` (the last estimate; no motion
/// model, as the seed), `selection` of them projected and matched to `keypoints`, and the pose
/// by `solver`. With fewer than 3 matches the prior is kept.
pub fn localise(
    map: &LandmarkMap,
    camera: &Camera,
    frame: &Frame,
    prior: &Pose2,
    config: &MonocularConfig,
    selection: Selection,
    solver: Solver,
) -> Estimate {
    let (keypoints, grid) = (&frame.keypoints[..], &frame.grid);
    let t0 = std::time::Instant::now();
    let view = in_view(map, camera, prior, config);
    let projected = match selection {
        Selection::All => view.clone(),
        Selection::Delegates => delegates(map, &view, &config.selection),
    };
    let select_s = t0.elapsed().as_secs_f64();
    let t1 = std::time::Instant::now();
    let (matches, comparisons) = match_landmarks(map, &projected, keypoints, grid, config);
    let match_s = t1.elapsed().as_secs_f64();
    let t2 = std::time::Instant::now();
    let prepared = prepare(map, camera, prior, &matches, keypoints, config);
    let pose = if prepared.len() < 3 {
        *prior
    } else {
        match solver {
            Solver::Search => {
                let (best, cost) = grid_search_outward(&config.search, prior, |p, bound| {
                    reprojection_cost_below(camera, p, &prepared, config.outlier, bound)
                });
                if config.refine {
                    refine(camera, &best, cost, &prepared, config.outlier)
                } else {
                    best
                }
            }
            Solver::PnpRansac { seed } => pnp_ransac(camera, prior, &prepared, seed, config),
        }
    };
    let search_s = t2.elapsed().as_secs_f64();
    let inliers = inlier_count(camera, &pose, &prepared, config.outlier);
    Estimate {
        pose,
        in_view: view.len(),
        projected: projected.len(),
        matched: matches.len(),
        inliers,
        comparisons,
        select_s,
        match_s,
        search_s,
    }
}

/// Gauss–Newton from the search's `best` (of capped cost `cost`) over the matches within the
/// cap there; the refined pose where its capped cost is no higher.
fn refine(camera: &Camera, best: &Pose2, cost: f64, m: &[Prepared], outlier: f64) -> Pose2 {
    let inliers: Vec<&Prepared> = m
        .iter()
        .filter(|p| reprojection_cost(camera, best, std::slice::from_ref(p), outlier) < outlier)
        .collect();
    if inliers.len() < 3 {
        return *best;
    }
    let r = gauss_newton(camera, best, &inliers, 5);
    if r.distance(best).is_finite() && reprojection_cost(camera, &r, m, outlier) <= cost {
        r
    } else {
        *best
    }
}

fn inlier_count(camera: &Camera, pose: &Pose2, m: &[Prepared], outlier: f64) -> usize {
    m.iter()
        .filter(|p| reprojection_cost(camera, pose, std::slice::from_ref(p), outlier) < outlier)
        .count()
}

/// Residuals and their Jacobian in (x, y, yaw) of one match at `pose`, in pixels, whitened
/// by the match's information.
fn whitened(camera: &Camera, pose: &Pose2, p: &Prepared) -> Option<(DVec2, [DVec2; 3])> {
    let h = 1e-6;
    let r = |q: &Pose2| -> Option<DVec2> {
        let o = camera.to_optical(q, p.position);
        camera.pixel(o).map(|px| px - p.pixel)
    };
    let e = r(pose)?;
    let mut j = [DVec2::ZERO; 3];
    for (i, d) in [[h, 0.0, 0.0], [0.0, h, 0.0], [0.0, 0.0, h]]
        .iter()
        .enumerate()
    {
        let q = Pose2::new(pose.x + d[0], pose.y + d[1], pose.theta + d[2]);
        j[i] = (r(&q)? - e) / h;
    }
    // Whiten by the Cholesky factor of the information.
    let w = cholesky2(&p.information)?;
    Some((w * e, [w * j[0], w * j[1], w * j[2]]))
}

/// Upper factor U with UᵀU = m (so that |U e|² = eᵀ m e).
fn cholesky2(m: &DMat2) -> Option<DMat2> {
    let (a, b, d) = (m.x_axis.x, m.y_axis.x, m.y_axis.y);
    if a <= 0.0 {
        return None;
    }
    let l11 = a.sqrt();
    let l21 = b / l11;
    let l22 = (d - l21 * l21).max(0.0).sqrt();
    // L = [[l11, 0], [l21, l22]]; U = Lᵀ.
    Some(DMat2::from_cols(DVec2::new(l11, 0.0), DVec2::new(l21, l22)))
}

/// Gauss–Newton on the whitened reprojection error of `m` from `start`.
fn gauss_newton(camera: &Camera, start: &Pose2, m: &[&Prepared], steps: usize) -> Pose2 {
    let mut pose = *start;
    for _ in 0..steps {
        let mut a = nalgebra::Matrix3::<f64>::zeros();
        let mut g = nalgebra::Vector3::<f64>::zeros();
        for p in m {
            let Some((e, j)) = whitened(camera, &pose, p) else {
                continue;
            };
            for row in 0..2 {
                let jr = nalgebra::Vector3::new(j[0][row], j[1][row], j[2][row]);
                a += jr * jr.transpose();
                g += jr * e[row];
            }
        }
        let Some(dx) = (a + nalgebra::Matrix3::identity() * 1e-9).lu().solve(&(-g)) else {
            break;
        };
        pose = Pose2::new(pose.x + dx[0], pose.y + dx[1], pose.theta + dx[2]);
        if dx.norm() < 1e-7 {
            break;
        }
    }
    pose
}

/// Iterations of RANSAC.
const RANSAC_ITERATIONS: usize = 100;

/// The modern baseline: PnP with RANSAC (Fischler & Bolles 1981) on the same matches, in the
/// plane: minimal sets of two matches (four equations for three unknowns), each solved by
/// Gauss–Newton from the prior; the set with the most matches within the outlier cap wins
/// (ties: the lower summed cost), and the pose is refined on its inliers. OpenCV's
/// `solvePnPRansac` does the same in six degrees of freedom with P3P; the camera here is
/// levelled at a known height, so three suffice.
pub fn pnp_ransac(
    camera: &Camera,
    prior: &Pose2,
    m: &[Prepared],
    seed: u64,
    config: &MonocularConfig,
) -> Pose2 {
    use rand::{Rng, SeedableRng};
    if m.len() < 2 {
        return *prior;
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut best: Option<(usize, f64, Pose2)> = None;
    for _ in 0..RANSAC_ITERATIONS {
        let a = rng.random_range(0..m.len());
        let mut b = rng.random_range(0..m.len() - 1);
        if b >= a {
            b += 1;
        }
        let pose = gauss_newton(camera, prior, &[&m[a], &m[b]], 8);
        if !(pose.x - prior.x).is_finite() || pose.distance(prior) > 1.0 {
            continue;
        }
        let n = inlier_count(camera, &pose, m, config.outlier);
        let c = reprojection_cost(camera, &pose, m, config.outlier);
        if best.is_none_or(|(bn, bc, _)| n > bn || (n == bn && c < bc)) {
            best = Some((n, c, pose));
        }
    }
    let Some((_, _, pose)) = best else {
        return *prior;
    };
    let inliers: Vec<&Prepared> = m
        .iter()
        .filter(|p| {
            reprojection_cost(camera, &pose, std::slice::from_ref(p), config.outlier)
                < config.outlier
        })
        .collect();
    if inliers.len() < 2 {
        return pose;
    }
    gauss_newton(camera, &pose, &inliers, 10)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> Camera {
        Camera {
            intrinsics: Intrinsics::from_fov(320, 240, 60f64.to_radians(), 46.8f64.to_radians())
                .unwrap(),
            height: 0.5,
        }
    }

    #[test]
    fn projection_follows_the_optical_convention() {
        let c = camera();
        let pose = Pose2::new(1.0, 2.0, PI / 2.0);
        // Straight ahead (along +y in the world), above the camera: centre column, upper half.
        let o = c.to_optical(&pose, DVec3::new(1.0, 5.0, 1.0));
        assert!((o - DVec3::new(0.0, -0.5, 3.0)).length() < 1e-12, "{o}");
        // To the camera's left (−x in the world when facing +y): the image's left half.
        let px = c
            .pixel(c.to_optical(&pose, DVec3::new(0.0, 5.0, 0.5)))
            .unwrap();
        assert!(px.x < c.intrinsics.cx && (px.y - c.intrinsics.cy).abs() < 1e-9);
        assert_eq!(direction_bin(DVec3::ZERO, DVec3::new(1.0, 0.0, 0.0)), 18);
        assert_eq!(direction_bin(DVec3::ZERO, DVec3::new(-1.0, -1e-9, 0.0)), 0);
        assert_eq!(bin_distance(35, 1), 2);
    }

    /// Eq. 18 by hand: a point straight ahead at 2 m with 1 cm² isotropic variance spreads
    /// f / z · 0.01 m = fx / 200 px in u.
    #[test]
    fn pixel_covariance_by_hand() {
        let c = camera();
        let o = DVec3::new(0.0, 0.0, 2.0);
        let s = c.pixel_covariance(0.3, o, &DMat3::from_diagonal(DVec3::splat(1e-4)));
        let want = (c.intrinsics.fx * 0.01 / 2.0).powi(2);
        assert!((s.x_axis.x - want).abs() < 1e-9 * want, "{s}");
        assert!(s.y_axis.x.abs() < 1e-12);
    }

    /// A synthetic map around a camera: the exhaustive search and RANSAC both find the true
    /// pose from the prior 6 cm and 4° off, with a fifth of the matches false.
    #[test]
    fn search_and_ransac_recover_a_known_pose() {
        use rand::{Rng, SeedableRng};
        let c = camera();
        let truth = Pose2::new(2.0, 1.0, 0.3);
        let prior = Pose2::new(2.05, 0.97, 0.3 + 4f64.to_radians());
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let mut m = Vec::new();
        while m.len() < 40 {
            let p = DVec3::new(
                rng.random_range(3.0..8.0),
                rng.random_range(-1.0..4.0),
                rng.random_range(0.0..2.7),
            );
            let Some(px) = c.pixel(c.to_optical(&truth, p)) else {
                continue;
            };
            if !c.inside(px) {
                continue;
            }
            let false_match = m.len() % 5 == 0;
            let shift = if false_match {
                DVec2::new(rng.random_range(-30.0..30.0), rng.random_range(-30.0..30.0))
            } else {
                DVec2::new(rng.random_range(-0.3..0.3), rng.random_range(-0.3..0.3))
            };
            m.push(Prepared {
                position: p,
                pixel: px + shift,
                information: DMat2::from_diagonal(DVec2::splat(1.0 / 0.25)),
            });
        }
        let cfg = MonocularConfig::default();
        let (best, _) = grid_search(&cfg.search, &prior, |p, _| {
            reprojection_cost(&c, p, &m, cfg.outlier)
        });
        // Stopping each sum at the least so far finds the same pose and cost.
        let bounded = grid_search(&cfg.search, &prior, |p, bound| {
            reprojection_cost_below(&c, p, &m, cfg.outlier, bound)
        });
        assert_eq!(bounded.0, best);
        assert!(best.distance(&truth) < 0.011, "{best:?}");
        assert!((best.theta - truth.theta).abs() < 0.6f64.to_radians());
        let r = pnp_ransac(&c, &prior, &m, 7, &cfg);
        assert!(r.distance(&truth) < 0.01, "{r:?}");
        assert!((r.theta - truth.theta).abs() < 0.2f64.to_radians());
        // The search visits 21³ poses, each once.
        assert_eq!(cfg.search.poses(&prior).count(), 9261);
    }

    /// Searching from the prior outwards visits every pose of the window once and keeps
    /// [`grid_search`]'s pose and cost, ties included (the first in the window's order),
    /// with windows whose heading and position counts differ either way, and with costs
    /// that stop early at the bound.
    #[test]
    fn the_outward_search_keeps_the_window_s_first_least_cost() {
        use rand::{Rng, SeedableRng};
        let prior = Pose2::new(1.0, -2.0, 0.4);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        for config in [
            SearchConfig::default(),
            SearchConfig {
                half_yaw_deg: 3.0,
                ..Default::default()
            },
            SearchConfig {
                half_xy: 0.02,
                ..Default::default()
            },
            SearchConfig {
                half_xy: 0.0,
                half_yaw_deg: 0.0,
                ..Default::default()
            },
        ] {
            let n = config.poses(&prior).count();
            // Costs of a few levels, so that many poses tie, as terms summed up to the bound.
            let table: Vec<Vec<f64>> = (0..n)
                .map(|_| (0..3).map(|_| rng.random_range(0..4) as f64).collect())
                .collect();
            let index = |p: &Pose2| {
                config
                    .poses(&prior)
                    .position(|q| q == *p)
                    .unwrap_or_else(|| panic!("{p:?} is not in the window"))
            };
            let full = |p: &Pose2, _: f64| table[index(p)].iter().sum::<f64>();
            let mut seen = vec![0u32; n];
            let outward = grid_search_outward(&config, &prior, |p, bound| {
                let i = index(p);
                seen[i] += 1;
                let mut sum = 0.0;
                for t in &table[i] {
                    sum += t;
                    if sum > bound {
                        break;
                    }
                }
                sum
            });
            assert!(seen.iter().all(|&k| k == 1), "{config:?}: each pose once");
            assert_eq!(outward, grid_search(&config, &prior, full), "{config:?}");
        }
    }

    fn landmark(observed: u32, missed: u32, contrast: f32) -> Landmark {
        Landmark {
            position: DVec3::ZERO,
            covariance: DMat3::IDENTITY * 1e-4,
            observed,
            missed,
            views: vec![View {
                bin: 0,
                contrast,
                descriptor: [0; 128],
            }],
        }
    }

    /// Eq. 23 by hand: landmarks on a 10 × 10 pixel lattice in one depth; cells of α σ_u
    /// keep one each, the best success rate first, then contrast.
    #[test]
    fn delegates_keep_one_landmark_a_cell_by_rate_then_contrast() {
        let mut map = LandmarkMap::default();
        let mut view = Vec::new();
        for i in 0..100 {
            let (u, v) = ((i % 10) as f64 * 30.0 + 5.0, (i / 10) as f64 * 20.0 + 5.0);
            map.landmarks
                .push(landmark(i as u32 % 3, 1, (i % 7) as f32));
            view.push(InView {
                index: i,
                pixel: DVec2::new(u, v),
                depth: 2.0,
                view: 0,
            });
        }
        // σ_u of 0, 30, …, 270 is 86.2 px: α = 0.35 gives cells of 30.2 px, one column each;
        // β = 0.7 with σ_v = 57.4 gives cells of 40.2 px: two rows each.
        let cfg = SelectionConfig {
            alpha: 0.35,
            beta: 0.7,
            gamma: None,
            min_landmarks: 20,
        };
        let d = delegates(&map, &view, &cfg);
        assert_eq!(d.len(), 50);
        for s in &d {
            let col = s.index % 10;
            let row = s.index / 10;
            let other = if row % 2 == 0 {
                s.index + 10
            } else {
                s.index - 10
            };
            let (a, b) = (&map.landmarks[s.index], &map.landmarks[other]);
            assert!(
                (a.success(), a.views[0].contrast) >= (b.success(), b.views[0].contrast),
                "column {col} row {row}"
            );
        }
        // Fewer in view than the threshold: all of them.
        assert_eq!(delegates(&map, &view[..19], &cfg).len(), 19);
        // Depth bins split a cell's landmarks by their distance.
        let mut deep = view.clone();
        for (i, v) in deep.iter_mut().enumerate() {
            v.depth = if i % 20 < 10 { 1.0 } else { 5.0 };
        }
        let cfg = SelectionConfig {
            gamma: Some(0.5),
            ..cfg
        };
        assert_eq!(delegates(&map, &deep, &cfg).len(), 100);
    }

    #[test]
    fn summary_maps_keep_the_most_observed() {
        let map = LandmarkMap {
            landmarks: (0..9).map(|i| landmark(i, 0, 1.0)).collect(),
        };
        let s = map.summarised(1.0 / 3.0);
        let kept: Vec<u32> = s.landmarks.iter().map(|l| l.observed).collect();
        assert_eq!(kept, vec![6, 7, 8]);
        let f = map.to_file();
        assert_eq!(LandmarkMap::from_file(&f).unwrap(), map);
    }
}
