//! Triangle meshes for rendering and export, and the generators of the world's primitives.
//!
//! A primitive's render mesh and its collider describe the same surface: boxes are exact
//! cuboids, cylinders are prisms with the same vertices as their convex-hull collider, and a
//! capsule's vertices lie on the exact capsule, so a rendered depth image and a ray cast of
//! the colliders agree.

use glam::{Vec2, Vec3};

/// An indexed triangle mesh with per-vertex normals and texture coordinates.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TriMesh {
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    /// Texture coordinates, already scaled to texture space (1.0 = one tile).
    pub uvs: Vec<Vec2>,
    pub indices: Vec<[u32; 3]>,
}

/// How a primitive maps its texture onto its faces.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum UvMap {
    /// One tile per `size` metres (u, v), so patterns keep their physical size.
    Tiled(Vec2),
    /// The texture stretched once over each face.
    Fit,
}

impl TriMesh {
    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.indices.len()
    }

    /// The corners of triangle `t`.
    pub fn corners(&self, t: &[u32; 3]) -> (Vec3, Vec3, Vec3) {
        (
            self.positions[t[0] as usize],
            self.positions[t[1] as usize],
            self.positions[t[2] as usize],
        )
    }

    /// Appends a planar quad `o, o+u, o+u+v, o+v`, facing `u × v` (counter-clockwise seen
    /// from that side).
    pub fn push_quad(&mut self, o: Vec3, u: Vec3, v: Vec3, uv: UvMap) {
        let n = u.cross(v).normalize();
        let base = self.positions.len() as u32;
        let (su, sv) = match uv {
            UvMap::Tiled(size) => (u.length() / size.x, v.length() / size.y),
            UvMap::Fit => (1.0, 1.0),
        };
        for (p, t) in [
            (o, Vec2::new(0.0, sv)),
            (o + u, Vec2::new(su, sv)),
            (o + u + v, Vec2::new(su, 0.0)),
            (o + v, Vec2::new(0.0, 0.0)),
        ] {
            self.positions.push(p);
            self.normals.push(n);
            self.uvs.push(t);
        }
        self.indices.push([base, base + 1, base + 2]);
        self.indices.push([base, base + 2, base + 3]);
    }

    /// An axis-aligned box centred on the origin with half extents `h`.
    pub fn cuboid(h: Vec3, uv: UvMap) -> TriMesh {
        let mut m = TriMesh::default();
        let (x, y, z) = (Vec3::X * h.x, Vec3::Y * h.y, Vec3::Z * h.z);
        // Each face: origin at its lower-left corner seen from outside, u to the right, v up.
        m.push_quad(-x + y - z, -2.0 * y, 2.0 * z, uv); // -x face
        m.push_quad(x - y - z, 2.0 * y, 2.0 * z, uv); // +x face
        m.push_quad(-x - y - z, 2.0 * x, 2.0 * z, uv); // -y face
        m.push_quad(x + y - z, -2.0 * x, 2.0 * z, uv); // +y face
        m.push_quad(-x - y + z, 2.0 * x, 2.0 * y, uv); // top
        m.push_quad(-x + y - z, 2.0 * x, -2.0 * y, uv); // bottom
        m
    }

    /// The vertices of an upright prism of `segments` sides inscribed in a cylinder of
    /// `radius`, centred on the origin, `2·half_height` tall. Shared with the collider.
    pub fn prism_vertices(radius: f32, half_height: f32, segments: u32) -> Vec<Vec3> {
        let mut v = Vec::with_capacity(2 * segments as usize);
        for z in [-half_height, half_height] {
            for i in 0..segments {
                let a = i as f32 / segments as f32 * std::f32::consts::TAU;
                v.push(Vec3::new(radius * a.cos(), radius * a.sin(), z));
            }
        }
        v
    }

    /// An upright prism approximating a cylinder, with smooth side normals and flat caps.
    pub fn prism(radius: f32, half_height: f32, segments: u32, uv: UvMap) -> TriMesh {
        let mut m = TriMesh::default();
        let s = segments as usize;
        let verts = Self::prism_vertices(radius, half_height, segments);
        let circumference = std::f32::consts::TAU * radius;
        let (u_scale, v_side) = match uv {
            UvMap::Tiled(size) => (circumference / size.x, 2.0 * half_height / size.y),
            UvMap::Fit => (1.0, 1.0),
        };
        // Sides: duplicate the seam column so texture coordinates wrap cleanly.
        for i in 0..=s {
            let a = i as f32 / s as f32 * std::f32::consts::TAU;
            let n = Vec3::new(a.cos(), a.sin(), 0.0);
            let u = i as f32 / s as f32 * u_scale;
            m.positions.push(verts[i % s]);
            m.normals.push(n);
            m.uvs.push(Vec2::new(u, v_side));
            m.positions.push(verts[s + i % s]);
            m.normals.push(n);
            m.uvs.push(Vec2::new(u, 0.0));
        }
        for i in 0..s as u32 {
            let (b0, t0, b1, t1) = (2 * i, 2 * i + 1, 2 * i + 2, 2 * i + 3);
            m.indices.push([b0, b1, t1]);
            m.indices.push([b0, t1, t0]);
        }
        // Caps as fans.
        for (z, n) in [(-half_height, -Vec3::Z), (half_height, Vec3::Z)] {
            let centre = m.positions.len() as u32;
            let cap_uv = |p: Vec3| match uv {
                UvMap::Tiled(size) => Vec2::new(p.x / size.x, p.y / size.y),
                UvMap::Fit => Vec2::new(0.5 + 0.5 * p.x / radius, 0.5 - 0.5 * p.y / radius),
            };
            m.positions.push(Vec3::new(0.0, 0.0, z));
            m.normals.push(n);
            m.uvs.push(cap_uv(Vec3::ZERO));
            for v in &verts[..s] {
                let p = Vec3::new(v.x, v.y, z);
                m.positions.push(p);
                m.normals.push(n);
                m.uvs.push(cap_uv(p));
            }
            for i in 0..s as u32 {
                let a = centre + 1 + i;
                let b = centre + 1 + (i + 1) % s as u32;
                if n.z > 0.0 {
                    m.indices.push([centre, a, b]);
                } else {
                    m.indices.push([centre, b, a]);
                }
            }
        }
        m
    }

    /// A capsule along z centred at the origin: a cylinder of `radius` closed by two
    /// hemispheres, `2·half_height` long from tip to tip (at least `2·radius`). Its vertices
    /// lie on the capsule's surface: `segments` round the axis and `rings` latitudes per
    /// hemisphere, so the exact capsule a physics engine casts rays against (parry's
    /// `Capsule`) and this mesh agree at every vertex. The texture is stretched once round it
    /// and once from bottom to top.
    pub fn capsule(radius: f32, half_height: f32, segments: u32, rings: u32) -> TriMesh {
        let mut m = TriMesh::default();
        let (s, rings) = (segments.max(3) as usize, rings.max(1) as usize);
        let centre = (half_height - radius).max(0.0);
        // Latitudes from the bottom pole to the top one: the lower hemisphere's round its
        // centre at −centre, then the upper's round +centre (both equators, so the
        // cylinder between them is one band of quads; a ball has one equator, not a band of
        // zero height).
        let latitudes: Vec<(f32, f32)> = (0..=rings)
            .map(|j| {
                (
                    -std::f32::consts::FRAC_PI_2 * (1.0 - j as f32 / rings as f32),
                    -centre,
                )
            })
            .chain((usize::from(centre == 0.0)..=rings).map(|j| {
                (
                    std::f32::consts::FRAC_PI_2 * j as f32 / rings as f32,
                    centre,
                )
            }))
            .collect();
        let rows = latitudes.len();
        for (r, &(phi, z0)) in latitudes.iter().enumerate() {
            let (sp, cp) = phi.sin_cos();
            for i in 0..=s {
                let a = i as f32 / s as f32 * std::f32::consts::TAU;
                let n = Vec3::new(cp * a.cos(), cp * a.sin(), sp);
                m.positions.push(Vec3::new(0.0, 0.0, z0) + radius * n);
                m.normals.push(n);
                m.uvs.push(Vec2::new(
                    i as f32 / s as f32,
                    1.0 - r as f32 / (rows - 1) as f32,
                ));
            }
        }
        let at = |r: usize, i: usize| (r * (s + 1) + i) as u32;
        for r in 0..rows - 1 {
            for i in 0..s {
                let (b0, b1, t0, t1) = (at(r, i), at(r, i + 1), at(r + 1, i), at(r + 1, i + 1));
                // The poles' rows are one point: one triangle of each quad there.
                if r > 0 {
                    m.indices.push([b0, b1, t1]);
                }
                if r + 1 < rows - 1 {
                    m.indices.push([b0, t1, t0]);
                }
            }
        }
        m
    }

    /// Applies a rigid transform (and uniform scale) to positions and normals.
    pub fn transformed(&self, rotation: glam::Quat, translation: Vec3, scale: f32) -> TriMesh {
        TriMesh {
            positions: self
                .positions
                .iter()
                .map(|&p| rotation * (p * scale) + translation)
                .collect(),
            normals: self.normals.iter().map(|&n| rotation * n).collect(),
            uvs: self.uvs.clone(),
            indices: self.indices.clone(),
        }
    }

    /// Removes triangles with (near) zero area or out-of-range indices; returns how many.
    pub fn remove_degenerate(&mut self) -> usize {
        let before = self.indices.len();
        let n = self.positions.len() as u32;
        let pos = &self.positions;
        self.indices.retain(|t| {
            t.iter().all(|&i| i < n) && {
                let (a, b, c) = (pos[t[0] as usize], pos[t[1] as usize], pos[t[2] as usize]);
                (b - a).cross(c - a).length() > 1e-12
            }
        });
        before - self.indices.len()
    }

    /// Fills missing normals with area-weighted vertex normals.
    pub fn compute_normals(&mut self) {
        let mut normals = vec![Vec3::ZERO; self.positions.len()];
        for t in &self.indices {
            let (a, b, c) = self.corners(t);
            let n = (b - a).cross(c - a);
            for &i in t {
                normals[i as usize] += n;
            }
        }
        self.normals = normals
            .into_iter()
            .map(|n| n.normalize_or(Vec3::Z))
            .collect();
    }

    /// Whether the mesh bounds solids seen only from outside: every edge (vertices at the same
    /// place, to 10 µm, counted as one) borne by exactly two triangles that run it in
    /// opposite directions, and each connected piece winding counter-clockwise seen from
    /// outside (a positive enclosed volume). From a point outside such solids the first
    /// surface along any ray faces it, so the renderer may skip the triangles that face away
    /// (back-face culling): the same image for less work. Open surfaces (a lone wall quad, a
    /// reconstructed map) and inside-out pieces are false, and are drawn from both sides.
    pub fn is_closed_solid(&self) -> bool {
        use std::collections::HashMap;
        if self.indices.is_empty() {
            return false;
        }
        let n = self.positions.len();
        if self.indices.iter().flatten().any(|&i| i as usize >= n) {
            return false;
        }
        // Each vertex's place: the first vertex at the same rounded position.
        let mut places: HashMap<[i64; 3], u32> = HashMap::new();
        let mut place = Vec::with_capacity(n);
        for (i, p) in self.positions.iter().enumerate() {
            let key = p.to_array().map(|c| (c as f64 * 1e5).round() as i64);
            place.push(*places.entry(key).or_insert(i as u32));
        }
        let mut edges: HashMap<(u32, u32), u32> = HashMap::new();
        for t in &self.indices {
            let t = t.map(|i| place[i as usize]);
            for k in 0..3 {
                *edges.entry((t[k], t[(k + 1) % 3])).or_insert(0) += 1;
            }
        }
        let paired = edges
            .iter()
            .all(|(&(a, b), &count)| a != b && count == 1 && edges.get(&(b, a)) == Some(&1));
        if !paired {
            return false;
        }
        // Connected pieces (union-find over places), each one's signed volume: the sum of
        // its triangles' tetrahedra with the piece's first vertex.
        let mut parent: Vec<u32> = (0..n as u32).collect();
        fn root(parent: &mut [u32], mut i: u32) -> u32 {
            while parent[i as usize] != i {
                let up = parent[parent[i as usize] as usize];
                parent[i as usize] = up;
                i = up;
            }
            i
        }
        for t in &self.indices {
            let a = root(&mut parent, place[t[0] as usize]);
            for &i in &t[1..] {
                let b = root(&mut parent, place[i as usize]);
                parent[b as usize] = a;
            }
        }
        let mut volumes: HashMap<u32, (Vec3, f64)> = HashMap::new();
        for t in &self.indices {
            let r = root(&mut parent, place[t[0] as usize]);
            let (a, b, c) = self.corners(t);
            let entry = volumes.entry(r).or_insert((a, 0.0));
            let o = entry.0;
            entry.1 += ((a - o).dot((b - o).cross(c - o)) as f64) / 6.0;
        }
        volumes.values().all(|&(_, v)| v > 0.0)
    }

    /// Total surface area, m².
    pub fn area(&self) -> f32 {
        self.indices
            .iter()
            .map(|t| {
                let (a, b, c) = self.corners(t);
                0.5 * (b - a).cross(c - a).length()
            })
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn capsule_vertices_lie_on_the_capsule_and_its_faces_point_out() {
        // A shin, and a capsule as short as its radius allows: a ball.
        for (r, h) in [(0.05f32, 0.4f32), (0.1, 0.1)] {
            check_capsule(r, h);
        }
    }

    fn check_capsule(r: f32, h: f32) {
        let m = TriMesh::capsule(r, h, 16, 4);
        // Every vertex is `r` from the axis segment z ∈ [−(h − r), h − r], its normal the
        // unit vector from that segment to it.
        for (p, n) in m.positions.iter().zip(&m.normals) {
            let on_axis = Vec3::new(0.0, 0.0, p.z.clamp(-(h - r), h - r));
            assert!(((*p - on_axis).length() - r).abs() < 1e-6, "{p}");
            assert!((*n - (*p - on_axis) / r).length() < 1e-5, "{p} {n}");
        }
        let (lo, hi) = m
            .positions
            .iter()
            .fold((f32::MAX, f32::MIN), |(a, b), p| (a.min(p.z), b.max(p.z)));
        assert!((lo + h).abs() < 1e-6 && (hi - h).abs() < 1e-6, "{lo} {hi}");
        // No degenerate triangle, and each winds outwards (its normal along the vertices').
        for t in &m.indices {
            let (a, b, c) = m.corners(t);
            let face = (b - a).cross(c - a);
            assert!(face.length() > 1e-9, "{t:?}");
            let out =
                m.normals[t[0] as usize] + m.normals[t[1] as usize] + m.normals[t[2] as usize];
            assert!(face.dot(out) > 0.0, "{t:?}");
        }
        // Closed: every edge is shared by two triangles, once each way (the seam's duplicated
        // column and the poles' repeated points counted as one place).
        let key = |i: u32| {
            let p = m.positions[i as usize];
            (
                (p.x * 1e5).round() as i64,
                (p.y * 1e5).round() as i64,
                (p.z * 1e5).round() as i64,
            )
        };
        let mut edges = std::collections::HashMap::new();
        for t in &m.indices {
            for k in 0..3 {
                *edges.entry((key(t[k]), key(t[(k + 1) % 3]))).or_insert(0) += 1;
            }
        }
        for (&(a, b), &n) in &edges {
            assert_eq!(n, 1, "edge {a:?}→{b:?} used {n} times");
            assert_eq!(edges.get(&(b, a)), Some(&1), "edge {a:?}→{b:?} has no twin");
        }
        // Its area tends to the capsule's, 2πr·(2h − 2r) + 4πr², from below.
        let exact =
            std::f32::consts::TAU * r * (2.0 * h - 2.0 * r) + 4.0 * std::f32::consts::PI * r * r;
        assert!(
            m.area() < exact && m.area() > 0.95 * exact,
            "{} {exact}",
            m.area()
        );
    }

    #[test]
    fn closed_solids_are_told_from_open_and_inside_out_surfaces() {
        let q = glam::Quat::from_rotation_z(0.7) * glam::Quat::from_rotation_x(0.2);
        let closed =
            [
                TriMesh::cuboid(Vec3::new(1.0, 0.5, 0.25), UvMap::Fit),
                TriMesh::cuboid(Vec3::new(0.1, 2.0, 1.0), UvMap::Tiled(Vec2::splat(0.3)))
                    .transformed(q, Vec3::new(3.2, -1.7, 0.4), 1.5),
                TriMesh::prism(0.2, 0.5, 12, UvMap::Fit),
                TriMesh::capsule(0.05, 0.4, 16, 4),
            ];
        for m in &closed {
            assert!(m.is_closed_solid());
        }
        // Two solids apart are two closed pieces.
        let mut two = closed[0].clone();
        let other = closed[1].clone();
        let base = two.positions.len() as u32;
        two.positions.extend(&other.positions);
        two.normals.extend(&other.normals);
        two.uvs.extend(&other.uvs);
        two.indices
            .extend(other.indices.iter().map(|t| t.map(|i| i + base)));
        assert!(two.is_closed_solid());
        // A lone quad is open; so is a box without its top.
        let mut quad = TriMesh::default();
        quad.push_quad(Vec3::ZERO, Vec3::X, Vec3::Y, UvMap::Fit);
        assert!(!quad.is_closed_solid());
        let mut lidless = closed[0].clone();
        lidless.indices.drain(8..10);
        assert!(!lidless.is_closed_solid());
        // Inside out (a room's box seen from within), alone or beside a solid.
        let mut inverted = closed[0].clone();
        for t in &mut inverted.indices {
            t.swap(1, 2);
        }
        assert!(!inverted.is_closed_solid());
        let mut mixed = two.clone();
        for t in &mut mixed.indices[..12] {
            t.swap(1, 2);
        }
        assert!(!mixed.is_closed_solid());
        // An edge run the same way twice (one face's winding flipped) is not paired.
        let mut flipped_face = closed[0].clone();
        for t in &mut flipped_face.indices[..2] {
            t.swap(1, 2);
        }
        assert!(!flipped_face.is_closed_solid());
        assert!(!TriMesh::default().is_closed_solid());
    }

    #[test]
    fn cuboid_is_closed_with_outward_normals_and_right_area() {
        let m = TriMesh::cuboid(Vec3::new(1.0, 0.5, 0.25), UvMap::Fit);
        assert_eq!(m.triangle_count(), 12);
        let area = 2.0 * (2.0 * 1.0 + 2.0 * 0.5 + 1.0 * 0.5) * 4.0 / 4.0;
        assert!((m.area() - area).abs() < 1e-5, "{} vs {}", m.area(), area);
        for t in &m.indices {
            let (a, b, c) = m.corners(t);
            let n = (b - a).cross(c - a);
            let centroid = (a + b + c) / 3.0;
            assert!(n.dot(centroid) > 0.0, "triangle {t:?} winds inward");
            assert!(n.normalize().dot(m.normals[t[0] as usize]) > 0.999);
        }
    }

    #[test]
    fn prism_winds_outward_and_tiles_by_size() {
        let m = TriMesh::prism(0.5, 1.0, 16, UvMap::Tiled(Vec2::new(1.0, 1.0)));
        for t in &m.indices {
            let (a, b, c) = m.corners(t);
            let n = (b - a).cross(c - a);
            assert!(n.dot((a + b + c) / 3.0) > 0.0);
        }
        let umax = m.uvs.iter().map(|u| u.x).fold(0.0, f32::max);
        assert!((umax - std::f32::consts::TAU * 0.5).abs() < 1e-4);
    }

    #[test]
    fn degenerate_triangles_are_removed() {
        let mut m = TriMesh::cuboid(Vec3::ONE, UvMap::Fit);
        m.indices.push([0, 0, 1]);
        m.indices.push([0, 1, 999]);
        assert_eq!(m.remove_degenerate(), 2);
        assert_eq!(m.triangle_count(), 12);
    }
}
