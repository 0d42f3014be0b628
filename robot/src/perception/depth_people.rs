//! People in depth images, after Munaro, Basso & Menegatti (IROS 2012, "Tracking people within
//! groups with RGB-D data") and Munaro & Menegatti (2014): the cloud is voxelised, the floor
//! found and removed, the rest clustered, and clusters that stand on the floor with a person's
//! size are people. Written for futago.
//!
//! Per frame, in the camera's body frame levelled by the floor ([`crate::perception::floor`]):
//! 1. every `stride`-th pixel with valid depth is back-projected and levelled; points lower
//!    than `floor_clearance` over the floor (the floor and what lies on it) are removed;
//! 2. the points fall into cubic voxels of `voxel` (0.06 m, Munaro's), and the occupied voxels
//!    are clustered by adjacency (26-neighbours: Euclidean clustering at one voxel's
//!    diagonal);
//! 3. a cluster is a person when it stands on the floor (its lowest voxel below
//!    `max_bottom`), its top is a person's height (`min_height` to `max_height`, Munaro's
//!    1.3–2.3 m), its horizontal extent both across and along the view is no more than
//!    `max_width`, it is not flat (the spread of its voxels about their best horizontal line is
//!    at least `min_thickness`: walls, doors and cabinets' fronts are planes, which the
//!    camera's range limit or a door's jambs can cut to a person's width), and it has
//!    `min_voxels` voxels. A camera low on a robot cuts people off at
//!    the top of its view (the Kinect at 0.42 m sees 1.7 m only beyond 3.3 m): a cluster that
//!    reaches the image's top row has its height unknown above the view, and passes when its
//!    visible top reaches `min_truncated` (above a person's hips, so that chairs and tables
//!    near the camera do not). Clusters cut by the image's left or right edge are left out:
//!    their centre is unknown;
//! 4. the person stands at the cluster's horizontal centroid, pushed away from the camera by
//!    `surface_to_centre` (the camera sees the front of a body 0.2–0.25 m deep). The
//!    confidence ranks clusters by size: voxels / (voxels + `min_voxels`).
//!
//! Munaro's HOG confidence on the colour image and his head-based sub-clustering of groups
//! are not done here: the first needs a trained colour classifier, the second heads, which
//! the low camera rarely sees. People side by side within a voxel of each other are one
//! cluster, and pass as one person only when no wider than `max_width`.

use super::floor::{FloorConfig, level, optical_to_body};
use crate::config::{ConfigError, check_counts, check_ranges};
use futago_msgs::Pose2;
use futago_msgs::camera::RgbdFrame;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rustc_hash::FxHashMap;
use serde::{Deserialize, Serialize};

/// Settings of the depth-image person detector (`people.depth`).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct DepthPeopleConfig {
    /// Whether the detector runs on the first camera of a scenario with people.
    pub enabled: bool,
    /// Frames it takes per second, Hz (each is rendered for it).
    pub rate: f64,
    /// Every `stride`-th pixel of every `stride`-th row is used.
    pub stride: u32,
    /// Depth beyond this is not used, m.
    pub max_depth: f64,
    /// Voxel edge, m (Munaro: 0.06).
    pub voxel: f64,
    /// The floor's search (RANSAC, as the RGB-D mapper's).
    pub floor: FloorConfig,
    /// Points lower than this over the floor are the floor, m.
    pub floor_clearance: f64,
    /// A person's lowest visible voxel is below this, m.
    pub max_bottom: f64,
    /// A person's top lies in [`min_height`, `max_height`], m (Munaro: 1.3, 2.3).
    pub min_height: f64,
    pub max_height: f64,
    /// A cluster cut off by the image's top row must reach this high, m.
    pub min_truncated: f64,
    /// Largest horizontal extent across and along the view, m (a walker's stride, 0.8 m,
    /// and the legs' width).
    pub max_width: f64,
    /// Least spread, m, of a person's voxels about their best horizontal line (the standard
    /// deviation across it): a body's front is curved (the twin's torso is an ellipse 0.24 m
    /// deep and 0.4 m wide, whose visible half deviates some 0.04 m from its chord, its legs
    /// stand behind or before it), a flat surface's spread is the depth noise, under 0.02 m
    /// within 3.5 m for a Kinect (Nguyen et al. 2012), less once voxels average it.
    pub min_thickness: f64,
    /// Fewest voxels in a person.
    pub min_voxels: usize,
    /// From the visible surface to the body's centre, m.
    pub surface_to_centre: f64,
}

impl Default for DepthPeopleConfig {
    fn default() -> Self {
        DepthPeopleConfig {
            enabled: true,
            rate: 5.0,
            stride: 2,
            max_depth: 6.0,
            voxel: 0.06,
            floor: FloorConfig::default(),
            floor_clearance: 0.1,
            max_bottom: 0.4,
            min_height: 1.3,
            max_height: 2.3,
            min_truncated: 1.0,
            max_width: 1.0,
            min_thickness: 0.03,
            min_voxels: 15,
            surface_to_centre: 0.1,
        }
    }
}

impl DepthPeopleConfig {
    /// Checks every field; errors name `prefix.field`.
    pub fn validate(&self, prefix: &str) -> Result<(), ConfigError> {
        self.floor
            .validate(&crate::config::below(prefix, "floor"))?;
        check_ranges(
            prefix,
            &[
                ("rate", self.rate, 0.01, 100.0),
                ("max_depth", self.max_depth, 0.1, 100.0),
                ("voxel", self.voxel, 0.005, 1.0),
                ("floor_clearance", self.floor_clearance, 0.0, 1.0),
                ("max_bottom", self.max_bottom, 0.0, 3.0),
                ("min_height", self.min_height, 0.0, 5.0),
                ("max_height", self.max_height, self.min_height, 5.0),
                ("min_truncated", self.min_truncated, 0.0, 5.0),
                ("max_width", self.max_width, 0.01, 10.0),
                ("min_thickness", self.min_thickness, 0.0, 1.0),
                ("surface_to_centre", self.surface_to_centre, 0.0, 1.0),
            ],
        )?;
        check_counts(
            prefix,
            &[
                ("stride", self.stride as usize, 1, 64),
                ("min_voxels", self.min_voxels, 1, 1_000_000),
            ],
        )
    }
}

/// A person found in a depth image: where they stand in the robot base's frame, m, and how
/// sure the detector is (0–1, for ranking).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthPerson {
    pub position: [f64; 2],
    pub confidence: f64,
}

/// What the detector did with one frame.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct DepthPeopleCounts {
    /// Points over the floor, voxels they filled, and clusters of them.
    pub points: usize,
    pub voxels: usize,
    pub clusters: usize,
}

/// The depth-image person detector of one camera (see the module documentation).
#[derive(Debug, Clone)]
pub struct DepthPeople {
    config: DepthPeopleConfig,
    /// The camera's place and heading in the base frame (its height, pitch and roll come
    /// from the floor in each frame).
    mount: Pose2,
    rng: ChaCha8Rng,
}

/// One occupied voxel: its points' sums, and the image rows and columns they came from.
#[derive(Debug, Clone, Copy)]
struct Voxel {
    sum: [f64; 3],
    n: u32,
    top_row: u32,
    columns: [u32; 2],
}

/// The connected components (26-neighbourhood) of the occupied voxels, each grown from the
/// first of its voxels in `order`.
fn clusters(order: &[[i64; 3]], voxels: &FxHashMap<[i64; 3], Voxel>) -> Vec<Vec<[i64; 3]>> {
    let mut label: FxHashMap<[i64; 3], usize> = FxHashMap::default();
    let mut clusters: Vec<Vec<[i64; 3]>> = Vec::new();
    for &seed in order {
        if label.contains_key(&seed) {
            continue;
        }
        let id = clusters.len();
        let mut members = vec![seed];
        label.insert(seed, id);
        let mut next = 0;
        while next < members.len() {
            let m = members[next];
            next += 1;
            for dx in -1..=1 {
                for dy in -1..=1 {
                    for dz in -1..=1 {
                        let n = [m[0] + dx, m[1] + dy, m[2] + dz];
                        if voxels.contains_key(&n) && !label.contains_key(&n) {
                            label.insert(n, id);
                            members.push(n);
                        }
                    }
                }
            }
        }
        clusters.push(members);
    }
    clusters
}

impl DepthPeople {
    pub fn new(config: DepthPeopleConfig, mount: Pose2, seed: u64) -> DepthPeople {
        DepthPeople {
            config,
            mount,
            rng: ChaCha8Rng::seed_from_u64(seed),
        }
    }

    /// The people in `frame`, in the robot base's frame (positions, m), or `None` when the
    /// frame shows no floor to level it by.
    pub fn detect(&mut self, frame: &RgbdFrame) -> Option<(Vec<DepthPerson>, DepthPeopleCounts)> {
        let c = self.config;
        let (k, d) = (&frame.depth_intrinsics, &frame.depth);
        let mut body = Vec::new();
        let mut pixels = Vec::new();
        for v in (0..d.height).step_by(c.stride as usize) {
            for u in (0..d.width).step_by(c.stride as usize) {
                let z = d.at(u, v) as f64;
                if z.is_finite() && z > 0.0 && z <= c.max_depth {
                    body.push(optical_to_body(k.back_project(u as f64, v as f64, z)));
                    pixels.push([u, v]);
                }
            }
        }
        let lv = level(&body, &c.floor, &mut self.rng)?;
        let mut counts = DepthPeopleCounts::default();
        // Voxels of the points over the floor, in the base frame.
        let mut voxels: FxHashMap<[i64; 3], Voxel> = FxHashMap::default();
        let mut order: Vec<[i64; 3]> = Vec::new();
        for (p, &[u, v]) in body.iter().zip(&pixels) {
            let l = lv.apply(*p);
            let [x, y] = self.mount.transform_point([l[0], l[1]]);
            let q = [x, y, l[2]];
            if q[2] < c.floor_clearance || q[2] > c.max_height + c.voxel {
                continue;
            }
            counts.points += 1;
            let key = q.map(|x| (x / c.voxel).floor() as i64);
            let e = voxels.entry(key).or_insert_with(|| {
                order.push(key);
                Voxel {
                    sum: [0.0; 3],
                    n: 0,
                    top_row: v,
                    columns: [u, u],
                }
            });
            for (s, x) in e.sum.iter_mut().zip(q) {
                *s += x;
            }
            e.n += 1;
            e.top_row = e.top_row.min(v);
            e.columns = [e.columns[0].min(u), e.columns[1].max(u)];
        }
        counts.voxels = order.len();
        // Clusters: connected components of the occupied voxels.
        let clusters = clusters(&order, &voxels);
        counts.clusters = clusters.len();
        let last_column = d.width.saturating_sub(1);
        let edge = c.stride.saturating_sub(1);
        let camera = [self.mount.x, self.mount.y];
        let people = clusters
            .iter()
            .filter_map(|members| {
                if members.len() < c.min_voxels {
                    return None;
                }
                let cells: Vec<&Voxel> = members.iter().map(|m| &voxels[m]).collect();
                let centre = |v: &Voxel| v.sum.map(|s| s / v.n as f64);
                let (mut bottom, mut top) = (f64::INFINITY, f64::NEG_INFINITY);
                let mut xy = [0.0; 2];
                let (mut top_row, mut left, mut right) = (u32::MAX, u32::MAX, 0);
                for v in &cells {
                    let p = centre(v);
                    bottom = bottom.min(p[2]);
                    top = top.max(p[2]);
                    xy[0] += p[0];
                    xy[1] += p[1];
                    top_row = top_row.min(v.top_row);
                    left = left.min(v.columns[0]);
                    right = right.max(v.columns[1]);
                }
                let n = cells.len() as f64;
                xy = [xy[0] / n, xy[1] / n];
                if left <= edge || right + c.stride > last_column || bottom > c.max_bottom {
                    return None;
                }
                let cut = top_row <= edge;
                let tall = if cut {
                    top >= c.min_truncated
                } else {
                    top >= c.min_height
                };
                if !tall || top > c.max_height {
                    return None;
                }
                // Extent across and along the ray from the camera to the centroid.
                let range = (xy[0] - camera[0]).hypot(xy[1] - camera[1]).max(1e-9);
                let along = [(xy[0] - camera[0]) / range, (xy[1] - camera[1]) / range];
                let (mut a, mut b) = ([f64::INFINITY, f64::NEG_INFINITY], [0.0f64; 2]);
                b[0] = f64::INFINITY;
                b[1] = f64::NEG_INFINITY;
                for v in &cells {
                    let p = centre(v);
                    let r = [p[0] - xy[0], p[1] - xy[1]];
                    let s = r[0] * along[0] + r[1] * along[1];
                    let t = -r[0] * along[1] + r[1] * along[0];
                    a = [a[0].min(s), a[1].max(s)];
                    b = [b[0].min(t), b[1].max(t)];
                }
                if a[1] - a[0] > c.max_width || b[1] - b[0] > c.max_width {
                    return None;
                }
                // Flatness: the smaller eigenvalue of the horizontal covariance.
                let mut m = [0.0f64; 3];
                for v in &cells {
                    let p = centre(v);
                    let r = [p[0] - xy[0], p[1] - xy[1]];
                    m = [m[0] + r[0] * r[0], m[1] + r[0] * r[1], m[2] + r[1] * r[1]];
                }
                let [sxx, sxy, syy] = m.map(|x| x / n);
                let half = 0.5 * (sxx + syy);
                let least = half - (0.25 * (sxx - syy).powi(2) + sxy * sxy).sqrt();
                if least.max(0.0).sqrt() < c.min_thickness {
                    return None;
                }
                let position = [
                    xy[0] + along[0] * c.surface_to_centre,
                    xy[1] + along[1] * c.surface_to_centre,
                ];
                Some(DepthPerson {
                    position,
                    confidence: n / (n + c.min_voxels as f64),
                })
            })
            .collect();
        Some((people, counts))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use futago_msgs::Time;
    use futago_msgs::camera::Intrinsics;

    /// An upright cylinder: centre x, y (camera body frame), radius, bottom and top, m.
    type Cylinder = ([f64; 2], f64, f64, f64);

    /// A level camera 0.42 m over a flat floor, its depth image rendered by hand (ray casts
    /// against the floor, a wall `wall` m ahead and upright cylinders), with the seed 000
    /// Kinect's 57° × 43° field of view at 160 × 120.
    fn frame(wall: f64, bodies: &[Cylinder]) -> RgbdFrame {
        const H: f64 = 0.42;
        let k = Intrinsics::from_fov(160, 120, 57f64.to_radians(), 43f64.to_radians()).unwrap();
        let mut data = Vec::new();
        for v in 0..k.height {
            for u in 0..k.width {
                let r = optical_to_body(k.ray(u as f64, v as f64));
                let mut t = if r[2] < -1e-9 {
                    H / -r[2]
                } else {
                    f64::INFINITY
                };
                if r[0] > 1e-9 {
                    t = t.min(wall / r[0]);
                }
                for &(c, radius, lo, hi) in bodies {
                    // |o + t r − c|² = radius² in x, y, the origin at the camera.
                    let (a, b) = (
                        r[0] * r[0] + r[1] * r[1],
                        -2.0 * (r[0] * c[0] + r[1] * c[1]),
                    );
                    let cc = c[0] * c[0] + c[1] * c[1] - radius * radius;
                    let disc = b * b - 4.0 * a * cc;
                    if a > 0.0 && disc >= 0.0 {
                        let s = (-b - disc.sqrt()) / (2.0 * a);
                        let z = H + s * r[2];
                        if s > 0.0 && z >= lo && z <= hi {
                            t = t.min(s);
                        }
                    }
                }
                let z = t * r[0];
                data.push(if z.is_finite() && z <= 3.5 {
                    z as f32
                } else {
                    0.0
                });
            }
        }
        RgbdFrame::depth_only(Time::ZERO, k, data)
    }

    /// A person of the twin's build at `x, y`: two shins 0.2 m apart and a torso with a head.
    fn person(x: f64, y: f64) -> [Cylinder; 3] {
        [
            ([x, y + 0.1], 0.05, 0.0, 0.85),
            ([x, y - 0.1], 0.05, 0.0, 0.85),
            ([x, y], 0.18, 0.85, 1.72),
        ]
    }

    fn detector() -> DepthPeople {
        let config = DepthPeopleConfig {
            stride: 1,
            ..Default::default()
        };
        // The camera 0.1 m ahead of the base's origin.
        DepthPeople::new(config, Pose2::new(0.1, 0.0, 0.0), 3)
    }

    #[test]
    fn a_person_in_view_is_found_at_their_centre() {
        // Two people, cut off at the top of the view (at 2.5 m it reaches 1.4 m), 1.2 m apart.
        let mut bodies = person(2.5, 0.6).to_vec();
        bodies.extend(person(2.8, -0.6));
        let (found, counts) = detector().detect(&frame(3.4, &bodies)).unwrap();
        assert_eq!(found.len(), 2, "{found:?} {counts:?}");
        for (x, y) in [(2.5, 0.6), (2.8, -0.6)] {
            // In the base frame the camera is 0.1 m ahead; within a voxel of the true centre.
            let near = found
                .iter()
                .any(|q| (q.position[0] - (x + 0.1)).hypot(q.position[1] - y) < 0.08);
            assert!(near, "({x}, {y}) not in {found:?}");
        }
    }

    #[test]
    fn low_narrow_wide_and_cut_off_clusters_are_not_people() {
        let bodies = [
            // A table-high box (0.7 m) 2.5 m ahead: too low.
            ([2.5, 0.5], 0.2, 0.0, 0.7),
            // A shelf floating from 0.6 m: not on the floor.
            ([2.6, -0.4], 0.2, 0.6, 1.8),
            // A round pillar 1.6 m wide.
            ([3.0, 0.0], 0.8, 0.0, 3.0),
        ];
        let (found, counts) = detector().detect(&frame(3.4, &bodies)).unwrap();
        assert!(counts.clusters >= 3, "{counts:?}");
        assert!(found.is_empty(), "{found:?}");
        // A door leaf or a cabinet's front, 0.8 m wide and 2 m tall, turned 30° from the view:
        // flat, though a person's width and height.
        let panel: Vec<Cylinder> = (0..=16)
            .map(|i| {
                let s = -0.4 + 0.05 * i as f64;
                let (c, n) = (30f64.to_radians().cos(), 30f64.to_radians().sin());
                ([2.6 + s * n, -0.2 + s * c], 0.03, 0.0, 2.0)
            })
            .collect();
        let (found, _) = detector().detect(&frame(3.4, &panel)).unwrap();
        assert!(found.is_empty(), "{found:?}");
        // Without the flatness test it would pass for one.
        let mut lax = detector();
        lax.config.min_thickness = 0.0;
        assert_eq!(lax.detect(&frame(3.4, &panel)).unwrap().0.len(), 1);
        // A person cut by the image's left edge (57° wide: the edge is at 28.5°).
        let edge = 2.5 * 28.5f64.to_radians().tan();
        let (found, _) = detector().detect(&frame(3.4, &person(2.5, edge))).unwrap();
        assert!(found.is_empty(), "{found:?}");
        // The same person in full view is found, so the refusals above are the filters'.
        let (found, _) = detector().detect(&frame(3.4, &person(2.5, 0.3))).unwrap();
        assert_eq!(found.len(), 1);
    }

    #[test]
    fn without_a_floor_there_is_no_answer() {
        // A wall 0.5 m ahead fills the view: nothing to level by.
        assert!(detector().detect(&frame(0.5, &[])).is_none());
    }

    #[test]
    fn settings_are_checked_by_key() {
        let mut c = DepthPeopleConfig::default();
        assert!(c.validate("people.depth").is_ok());
        c.max_height = 1.0;
        assert_eq!(
            c.validate("people.depth").unwrap_err().0,
            "people.depth.max_height"
        );
    }
}
