//! The 3D map reduced to planar polygons (seed 000 §3.2): planes found in each keyframe by
//! repeated RANSAC, each drawn as the convex hull of its inliers, and merged across keyframes
//! with planes of nearly the same orientation and position. The thesis turned 15 million points
//! into 34 faces and 767 vertices this way.
//!
//! Substitutions and choices (the thesis leaves them unstated): the hull is taken of the inliers
//! directly, without the thesis's morphological smoothing and contour step; two planes merge
//! when their normals are within `merge_angle`, the new plane's centroid lies within
//! `merge_distance` of the old plane, and their extents on the plane overlap or come within
//! `merge_gap` (so that coplanar walls of different rooms stay apart). A merged plane's normal
//! is the area-weighted mean of the two, as in the thesis, and its outline the hull of both.

use crate::geometry::plane::{Plane, RansacConfig, ransac_all};
use rand::Rng;
use serde::{Deserialize, Serialize};

/// Parameters of the polygon map.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PolygonConfig {
    /// Plane search per keyframe (seed 000: as the floor's, 1 cm inliers).
    pub ransac: RansacConfig,
    /// Most planes taken from one keyframe.
    pub max_planes: usize,
    /// Smallest polygon kept, m² ("planes of a certain size").
    pub min_area: f64,
    /// Largest angle between the normals of planes that merge, rad.
    pub merge_angle: f64,
    /// Largest distance of a new plane's centroid from the plane it merges with, m.
    pub merge_distance: f64,
    /// Largest gap between the extents of planes that merge, m.
    pub merge_gap: f64,
}

impl PolygonConfig {
    /// Checks every field; the error names the key below `prefix`.
    pub fn validate(&self, prefix: &str) -> Result<(), crate::config::ConfigError> {
        use crate::config::{below, check_counts, check_ranges};
        self.ransac.validate(&below(prefix, "ransac"))?;
        check_counts(prefix, &[("max_planes", self.max_planes, 1, 1000)])?;
        check_ranges(
            prefix,
            &[
                ("min_area", self.min_area, 0.0, 1e4),
                ("merge_angle", self.merge_angle, 0.0, std::f64::consts::PI),
                ("merge_distance", self.merge_distance, 0.0, 100.0),
                ("merge_gap", self.merge_gap, 0.0, 100.0),
            ],
        )
    }
}

impl Default for PolygonConfig {
    fn default() -> Self {
        PolygonConfig {
            ransac: RansacConfig {
                min_inliers: 80,
                ..RansacConfig::default()
            },
            max_planes: 6,
            min_area: 0.1,
            merge_angle: 10f64.to_radians(),
            merge_distance: 0.05,
            merge_gap: 0.3,
        }
    }
}

/// A planar polygon: its plane and its outline (counter-clockwise about the normal).
#[derive(Debug, Clone, PartialEq)]
pub struct Polygon {
    pub plane: Plane,
    pub outline: Vec<[f64; 3]>,
    pub area: f64,
    /// Keyframes merged into it.
    pub frames: u32,
}

impl Polygon {
    /// The outline's centroid (of its vertices).
    pub fn centroid(&self) -> [f64; 3] {
        let n = self.outline.len() as f64;
        let mut c = [0.0; 3];
        for p in &self.outline {
            for k in 0..3 {
                c[k] += p[k] / n;
            }
        }
        c
    }
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn normalize(a: [f64; 3]) -> [f64; 3] {
    let n = dot(a, a).sqrt();
    a.map(|x| x / n)
}

/// An orthonormal basis (u, v) of the plane with normal `n`, u × v = n.
fn basis(n: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let helper = if n[2].abs() < 0.9 {
        [0.0, 0.0, 1.0]
    } else {
        [1.0, 0.0, 0.0]
    };
    let u = normalize(cross(helper, n));
    (u, cross(n, u))
}

/// The convex hull of 2D points (Andrew's monotone chain), counter-clockwise, without
/// collinear points.
pub fn convex_hull(points: &[[f64; 2]]) -> Vec<[f64; 2]> {
    let mut p: Vec<[f64; 2]> = points.to_vec();
    p.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    p.dedup();
    if p.len() < 3 {
        return p;
    }
    let turn = |o: [f64; 2], a: [f64; 2], b: [f64; 2]| {
        (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
    };
    let mut hull: Vec<[f64; 2]> = Vec::new();
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &[f64; 2]>> = if pass == 0 {
            Box::new(p.iter())
        } else {
            Box::new(p.iter().rev())
        };
        for &q in iter {
            while hull.len() >= start + 2
                && turn(hull[hull.len() - 2], hull[hull.len() - 1], q) <= 0.0
            {
                hull.pop();
            }
            hull.push(q);
        }
        hull.pop();
    }
    hull
}

/// The area of a simple polygon (shoelace).
pub fn area(poly: &[[f64; 2]]) -> f64 {
    let n = poly.len();
    (0..n)
        .map(|i| {
            let (a, b) = (poly[i], poly[(i + 1) % n]);
            a[0] * b[1] - a[1] * b[0]
        })
        .sum::<f64>()
        .abs()
        / 2.0
}

/// A polygon on `plane` from points near it: their projections' convex hull.
pub fn polygon(plane: Plane, points: &[[f64; 3]]) -> Option<Polygon> {
    let n = plane.normal;
    let (u, v) = basis(n);
    let origin = n.map(|x| -x * plane.offset);
    let flat: Vec<[f64; 2]> = points
        .iter()
        .map(|p| {
            let d = [p[0] - origin[0], p[1] - origin[1], p[2] - origin[2]];
            [dot(d, u), dot(d, v)]
        })
        .collect();
    let hull = convex_hull(&flat);
    if hull.len() < 3 {
        return None;
    }
    let outline = hull
        .iter()
        .map(|q| {
            [
                origin[0] + q[0] * u[0] + q[1] * v[0],
                origin[1] + q[0] * u[1] + q[1] * v[1],
                origin[2] + q[0] * u[2] + q[1] * v[2],
            ]
        })
        .collect();
    Some(Polygon {
        plane,
        outline,
        area: area(&hull),
        frames: 1,
    })
}

/// The polygon map.
#[derive(Debug, Clone, Default)]
pub struct PolygonMap {
    pub config: PolygonConfig,
    pub polygons: Vec<Polygon>,
    /// Planes found in keyframes (before merging).
    pub found: u64,
}

impl PolygonMap {
    pub fn new(config: PolygonConfig) -> PolygonMap {
        PolygonMap {
            config,
            polygons: Vec::new(),
            found: 0,
        }
    }

    /// Finds the planes of a keyframe's points (world frame) and merges them into the map.
    pub fn add_frame(&mut self, points: &[[f64; 3]], rng: &mut impl Rng) {
        for f in ransac_all(points, &self.config.ransac, self.config.max_planes, rng) {
            let inliers: Vec<[f64; 3]> = f.inliers.iter().map(|&i| points[i]).collect();
            if let Some(p) = polygon(f.plane, &inliers)
                && p.area >= self.config.min_area
            {
                self.found += 1;
                self.insert(p);
            }
        }
    }

    /// Merges `p` into the first polygon it matches, or adds it.
    pub fn insert(&mut self, p: Polygon) {
        let c = self.config;
        let centre = p.centroid();
        let matched = self.polygons.iter().position(|q| {
            let aligned = dot(q.plane.normal, p.plane.normal).abs() >= c.merge_angle.cos();
            aligned
                && q.plane.distance(centre).abs() <= c.merge_distance
                && gap(q, &p) <= c.merge_gap
        });
        match matched {
            None => self.polygons.push(p),
            Some(k) => {
                let q = &self.polygons[k];
                let pn = if dot(q.plane.normal, p.plane.normal) < 0.0 {
                    p.plane.normal.map(|x| -x)
                } else {
                    p.plane.normal
                };
                let (wa, wb) = (q.area, p.area);
                let n = normalize([0, 1, 2].map(|i| wa * q.plane.normal[i] + wb * pn[i]));
                let (ca, cb) = (q.centroid(), centre);
                let c = [0, 1, 2].map(|i| (wa * ca[i] + wb * cb[i]) / (wa + wb));
                let plane = Plane {
                    normal: n,
                    offset: -dot(n, c),
                };
                let pts: Vec<[f64; 3]> = q.outline.iter().chain(&p.outline).copied().collect();
                let frames = q.frames + p.frames;
                if let Some(mut merged) = polygon(plane, &pts) {
                    merged.frames = frames;
                    self.polygons[k] = merged;
                }
            }
        }
    }

    /// Faces and vertices of the polygon mesh (each polygon one face).
    pub fn size(&self) -> (usize, usize) {
        (
            self.polygons.len(),
            self.polygons.iter().map(|p| p.outline.len()).sum(),
        )
    }

    /// A binary PLY mesh of the polygons (one face per polygon, vertices in its outline's
    /// order), coloured by orientation: floors grey, walls by their heading.
    pub fn to_ply(&self, comment: &str) -> Vec<u8> {
        let mut vertices = Vec::new();
        let mut faces = Vec::new();
        for p in &self.polygons {
            let n = p.plane.normal;
            let colour = if n[2].abs() > 0.9 {
                [170, 170, 170]
            } else {
                let h = n[1].atan2(n[0]).abs() / std::f64::consts::PI;
                [(80.0 + 150.0 * h) as u8, 120, (230.0 - 150.0 * h) as u8]
            };
            let first = vertices.len() as u32;
            faces.push((first..first + p.outline.len() as u32).collect());
            vertices.extend(p.outline.iter().map(|v| (*v, colour)));
        }
        futago_msgs::ply::mesh(&vertices, &faces, comment)
    }
}

/// The gap between two polygons' extents, measured along the first one's plane axes (0 when
/// their bounding boxes overlap).
fn gap(a: &Polygon, b: &Polygon) -> f64 {
    let (u, v) = basis(a.plane.normal);
    let extent = |p: &Polygon| {
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for q in &p.outline {
            for (k, axis) in [u, v].iter().enumerate() {
                let x = dot(*q, *axis);
                lo[k] = lo[k].min(x);
                hi[k] = hi[k].max(x);
            }
        }
        (lo, hi)
    };
    let ((la, ha), (lb, hb)) = (extent(a), extent(b));
    let dx = (lb[0] - ha[0]).max(la[0] - hb[0]).max(0.0);
    let dy = (lb[1] - ha[1]).max(la[1] - hb[1]).max(0.0);
    dx.hypot(dy)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn hulls_and_areas_by_hand() {
        let pts = [
            [0.0, 0.0],
            [2.0, 0.0],
            [2.0, 1.0],
            [0.0, 1.0],
            [1.0, 0.5],
            [1.0, 0.0],
        ];
        let h = convex_hull(&pts);
        assert_eq!(h, vec![[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]]);
        assert_eq!(area(&h), 2.0);
        assert_eq!(
            area(&convex_hull(&[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])),
            0.5
        );
    }

    /// A wall x = x0 from y0 to y1, 0 to 1 m high, every 2 cm.
    fn wall(x0: f64, y0: f64, y1: f64) -> Vec<[f64; 3]> {
        let mut v = Vec::new();
        let mut y = y0;
        while y <= y1 + 1e-9 {
            for k in 0..=50 {
                v.push([x0, y, k as f64 * 0.02]);
            }
            y += 0.02;
        }
        v
    }

    #[test]
    fn overlapping_views_of_a_wall_merge_and_other_walls_do_not() {
        let mut m = PolygonMap::new(PolygonConfig::default());
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        // Two views of the wall x = 2 overlapping in y, the second 1 cm off.
        m.add_frame(&wall(2.0, 0.0, 1.5), &mut rng);
        m.add_frame(&wall(2.01, 1.0, 3.0), &mut rng);
        assert_eq!(m.polygons.len(), 1, "{:?}", m.polygons);
        let p = &m.polygons[0];
        assert_eq!(p.frames, 2);
        // One polygon from y = 0 to 3 and z = 0 to 1: 3 m² and 4 corners.
        assert!((p.area - 3.0).abs() < 0.05, "{}", p.area);
        assert_eq!(p.outline.len(), 4);
        // The merged plane lies between the two, weighted by area (1.5 and 2 m²).
        let x = -p.plane.offset / p.plane.normal[0];
        assert!((x - (2.0 * 1.5 + 2.01 * 2.0) / 3.5).abs() < 1e-3, "{x}");
        // A parallel wall 1 m away and a coplanar wall 2 m further along stay apart.
        m.add_frame(&wall(3.0, 0.0, 1.0), &mut rng);
        m.add_frame(&wall(2.0, 5.0, 6.0), &mut rng);
        assert_eq!(m.polygons.len(), 3);
        assert_eq!(m.size(), (3, 12));
        let ply = m.to_ply("t");
        let head = String::from_utf8_lossy(&ply[..400]).to_string();
        assert!(head.contains("element vertex 12\n") && head.contains("element face 3\n"));
        let end = head.find("end_header\n").unwrap() + "end_header\n".len();
        assert_eq!(ply.len() - end, 12 * 15 + 3 * (1 + 4 * 4));
    }

    #[test]
    fn a_keyframe_of_floor_and_wall_gives_two_polygons() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let mut pts = wall(2.0, 0.0, 2.0);
        for i in 0..100 {
            for j in 0..100 {
                pts.push([i as f64 * 0.02, j as f64 * 0.02, 0.0]);
            }
        }
        let mut m = PolygonMap::new(PolygonConfig::default());
        m.add_frame(&pts, &mut rng);
        assert_eq!(m.polygons.len(), 2, "{:?}", m.polygons);
        let floor = m
            .polygons
            .iter()
            .find(|p| p.plane.normal[2].abs() > 0.99)
            .unwrap();
        // The floor's points span 1.98 m × 1.98 m; the wall's foot (x = 2, y to 2 m) lies on
        // the floor plane too and widens the hull to 3.98 m².
        assert!((floor.area - 3.98).abs() < 0.01, "{}", floor.area);
        let wall = m
            .polygons
            .iter()
            .find(|p| p.plane.normal[0].abs() > 0.99)
            .unwrap();
        assert!(wall.area > 1.5, "{}", wall.area);
    }
}
