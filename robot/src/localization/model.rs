//! The 3D model a depth-camera localiser renders (seed 002's "laser-scanned model"), and how
//! it is made from what the stack is given: a mesh (the world's, exported; a user's glTF or
//! PLY; the planar polygons of futago's own RGB-D map) or a point cloud (futago's RGB-D map; a
//! scan), which is meshed here as surfels.
//!
//! Two variants stand in for a model that is not the world itself:
//! - [`perturbed`]: the mesh resampled to edges of at most `spacing` and displaced by a smooth
//!   random field of RMS `noise` (seed 002's model came from a terrestrial laser scan; its
//!   registration to the corridor left about 10 mm, digest §5.1 and §6);
//! - [`surfels`]: a point cloud turned into small squares in the local tangent planes, the
//!   classic surfel map (Pfister et al., SIGGRAPH 2000; Weise et al. 2009 for RGB-D maps).
//!
//! Written here: no maintained crate meshes point clouds or perturbs meshes in this way.

use crate::geometry::plane::Plane;
use futago_render::mesh::UvMap;
use futago_render::{Material, MeshPart, Scene, SceneBody, TriMesh};
use glam::Vec3;
use rustc_hash::FxHashMap;
use serde::{Deserialize, Serialize};

/// Where the model comes from and how it is altered (`depth_localization.model.*`).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct ModelConfig {
    /// A mesh or point cloud file (PLY, glTF or GLB) in the world frame, relative to the
    /// scenario; none: the world's own mesh, exact.
    pub file: Option<String>,
    /// Side of the voxels a point cloud is averaged in, and so the surfels' spacing, m. The
    /// default, 0.1 m, tracked the office corridor on futago's own RGB-D map as well as 0.15
    /// m did and better than larger overlaps or neighbourhoods; 0.05 m costs four times the
    /// triangles.
    pub surfel: f64,
    /// Resample and displace the mesh (a stand-in for a scanned model); none: as it is.
    pub perturb: Option<PerturbConfig>,
    /// Merge the surfels of each plane into rectangles ([`planar_surfels`]): the same
    /// surfaces in far fewer triangles, so each frame renders faster. False: one square per
    /// voxel ([`surfels`]).
    pub merge_planes: bool,
}

/// A mesh resampled and displaced ([`perturbed`]).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PerturbConfig {
    /// Longest edge after resampling, and the displacement field's correlation length, m.
    pub spacing: f64,
    /// RMS of the displacement, m (seed 002: ≈ 0.01, its model's registration residual).
    pub noise: f64,
}

impl Default for ModelConfig {
    fn default() -> Self {
        ModelConfig {
            file: None,
            surfel: 0.1,
            perturb: None,
            merge_planes: true,
        }
    }
}

impl ModelConfig {
    /// Checks values, naming `PREFIX.KEY`.
    pub fn validate(&self, prefix: &str) -> Result<(), crate::config::ConfigError> {
        crate::config::check_ranges(prefix, &[("surfel", self.surfel, 0.005, 10.0)])?;
        if let Some(p) = &self.perturb {
            crate::config::check_ranges(
                &crate::config::below(prefix, "perturb"),
                &[
                    ("spacing", p.spacing, 0.01, 100.0),
                    ("noise", p.noise, 0.0, 1.0),
                ],
            )?;
        }
        Ok(())
    }
}

/// Squares larger than the voxels by this factor, so that neighbours overlap whatever the
/// offsets of their voxels' means and the surface's slant.
const SURFEL_OVERLAP: f32 = 1.5;

/// Voxel coordinates of `p` for voxels of side `size`.
fn voxel(p: [f64; 3], size: f64) -> [i64; 3] {
    p.map(|c| (c / size).floor() as i64)
}

/// One voxel's surfel: its key, its centre (the voxel's mean moved onto the local plane) and
/// the local plane's unit normal.
#[derive(Debug, Clone, Copy)]
struct Surfel {
    key: [i64; 3],
    centre: [f64; 3],
    normal: [f64; 3],
}

/// The surfels of a point cloud averaged in voxels of side `size`, in key order (see
/// [`surfels`]).
fn surfel_list(points: &[[f64; 3]], size: f64) -> Vec<Surfel> {
    let mut voxels: FxHashMap<[i64; 3], ([f64; 3], u32)> = FxHashMap::default();
    for p in points.iter().filter(|p| p.iter().all(|c| c.is_finite())) {
        let v = voxels.entry(voxel(*p, size)).or_insert(([0.0; 3], 0));
        for (sum, c) in v.0.iter_mut().zip(p) {
            *sum += c;
        }
        v.1 += 1;
    }
    let means: FxHashMap<[i64; 3], [f64; 3]> = voxels
        .into_iter()
        .map(|(k, (s, n))| (k, s.map(|c| c / n as f64)))
        .collect();
    let mut keys: Vec<[i64; 3]> = means.keys().copied().collect();
    keys.sort_unstable();
    let mut near = Vec::with_capacity(27);
    let mut out = Vec::with_capacity(keys.len());
    for key in keys {
        near.clear();
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    if let Some(m) = means.get(&[key[0] + dx, key[1] + dy, key[2] + dz]) {
                        near.push(*m);
                    }
                }
            }
        }
        let Some(plane) = Plane::fit(&near) else {
            continue;
        };
        // The voxel's mean moved onto the plane, so that neighbours lie in one surface:
        // left where they are, the noise of a map's points would stagger them, and a depth
        // render, which keeps the nearest surface, would see the wall nearer than it is.
        let m = means[&key];
        let off = plane.distance(m);
        out.push(Surfel {
            key,
            centre: [0, 1, 2].map(|k| m[k] - plane.normal[k] * off),
            normal: plane.normal,
        });
    }
    out
}

/// Unit vectors `u`, `v` spanning the plane of unit normal `n`, with `v = n × u`: for a wall,
/// `u` horizontal and `v` vertical; for a floor, along the axes of the plane.
fn plane_basis(n: Vec3) -> (Vec3, Vec3) {
    let reference = if n.z.abs() < 0.9 { Vec3::Z } else { Vec3::X };
    let u = reference.cross(n).normalize();
    (u, n.cross(u))
}

/// A surfel mesh of a point cloud: the points averaged per voxel of side `size`; through each
/// voxel's mean a square of side 1.5 `size`, in the least-squares plane of the means of its
/// 3×3×3 neighbourhood. A voxel whose neighbourhood holds fewer than three means, or only
/// means on a line, gets none (an isolated point is noise, not surface).
pub fn surfels(points: &[[f64; 3]], size: f64) -> TriMesh {
    let mut mesh = TriMesh::default();
    let side = size as f32 * SURFEL_OVERLAP;
    for s in surfel_list(points, size) {
        push_surfel(&mut mesh, &s, side);
    }
    mesh
}

/// Appends `s` as a square of side `side` about its centre, in its plane.
fn push_surfel(mesh: &mut TriMesh, s: &Surfel, side: f32) {
    let (u, v) = plane_basis(Vec3::from_array(s.normal.map(|c| c as f32)));
    let (u, v) = (u * side, v * side);
    let centre = Vec3::from_array(s.centre.map(|c| c as f32));
    mesh.push_quad(centre - 0.5 * (u + v), u, v, UvMap::Fit);
}

/// Most that neighbouring surfels' normals may differ, and still lie in one plane.
const PLANE_ANGLE_DEG: f64 = 15.0;
/// Farthest a surfel's centre may lie from a plane it joins, in voxel sides.
const PLANE_DISTANCE: f64 = 0.3;
/// Fewest surfels that make a plane worth merging; fewer stay surfels.
const PLANE_MIN_SURFELS: usize = 6;
/// Longest side of a merged rectangle, m: the renderer culls static triangles in 1 m cells
/// of the plane by the box that bounds each cell's triangles, and a longer rectangle would
/// widen its cell's box, so that views that cannot see the cell's small triangles draw them.
const PLANE_MAX_SIDE: f64 = 1.0;

/// The surfel mesh of [`surfels`] with the surfels of each plane merged into rectangles.
///
/// Surfels are grown into planes over their 26-neighbourhoods (normals within 15°, centres
/// within 0.3 voxel sides of the plane fitted to the surfels already in it, refitted as it
/// doubles). A plane of at least six surfels is rasterised into cells of side `size` in its
/// own basis (each surfel marks the cell centred nearest its centre, so that a plane reaches
/// at most half a cell past its surfels' centres, about as far as a surfel; a cell between two marked
/// ones is filled), and the cells are covered by maximal rectangles
/// (greedy: the lowest cell first, grown along `u` and then along `v`) of at most 1 m a side.
/// Surfels in no plane (edges, corners, clutter) stay squares.
///
/// Why: a depth render's cost on a software rasteriser is mostly per triangle, and a
/// building's map is mostly walls and floor. futago's office map at 0.1 m has 57k surfels
/// (114k triangles); the planes' rectangles draw the same surfaces with a fraction of them.
pub fn planar_surfels(points: &[[f64; 3]], size: f64) -> TriMesh {
    let list = surfel_list(points, size);
    let index: FxHashMap<[i64; 3], usize> =
        list.iter().enumerate().map(|(i, s)| (s.key, i)).collect();
    let cos_max = PLANE_ANGLE_DEG.to_radians().cos();
    let mut region = vec![usize::MAX; list.len()];
    let mut regions: Vec<(Plane, Vec<usize>)> = Vec::new();
    for seed in 0..list.len() {
        if region[seed] != usize::MAX {
            continue;
        }
        let id = regions.len();
        let s = list[seed];
        let mut plane = Plane {
            normal: s.normal,
            offset: -(0..3).map(|k| s.normal[k] * s.centre[k]).sum::<f64>(),
        };
        let mut members = vec![seed];
        region[seed] = id;
        let mut refit_at = 8;
        let mut head = 0;
        while head < members.len() {
            let k = list[members[head]].key;
            head += 1;
            for dx in -1..=1 {
                for dy in -1..=1 {
                    for dz in -1..=1 {
                        let Some(&j) = index.get(&[k[0] + dx, k[1] + dy, k[2] + dz]) else {
                            continue;
                        };
                        if region[j] != usize::MAX {
                            continue;
                        }
                        let c = list[j];
                        let dot: f64 = (0..3).map(|i| c.normal[i] * plane.normal[i]).sum();
                        if dot.abs() < cos_max
                            || plane.distance(c.centre).abs() > PLANE_DISTANCE * size
                        {
                            continue;
                        }
                        region[j] = id;
                        members.push(j);
                    }
                }
            }
            if members.len() >= refit_at {
                let pts: Vec<[f64; 3]> = members.iter().map(|&i| list[i].centre).collect();
                if let Some(p) = Plane::fit(&pts) {
                    plane = p;
                }
                refit_at *= 2;
            }
        }
        regions.push((plane, members));
    }
    let mut mesh = TriMesh::default();
    let side = size as f32 * SURFEL_OVERLAP;
    for (plane, members) in &regions {
        if members.len() < PLANE_MIN_SURFELS {
            for &i in members {
                push_surfel(&mut mesh, &list[i], side);
            }
            continue;
        }
        let pts: Vec<[f64; 3]> = members.iter().map(|&i| list[i].centre).collect();
        let plane = Plane::fit(&pts).unwrap_or(*plane);
        let n = glam::DVec3::from_array(plane.normal);
        let (u, v) = {
            let (u, v) = plane_basis(n.as_vec3());
            (u.as_dvec3(), v.as_dvec3())
        };
        // The plane's origin: the point of it nearest the world origin.
        let origin = -n * plane.offset;
        let mut cells: std::collections::BTreeSet<(i64, i64)> = Default::default();
        for p in &pts {
            let d = glam::DVec3::from_array(*p) - origin;
            cells.insert((
                (d.dot(v) / size).round() as i64,
                (d.dot(u) / size).round() as i64,
            ));
        }
        // Close one-cell gaps (a slanted plane's voxels project unevenly onto its grid).
        let marked: Vec<(i64, i64)> = cells.iter().copied().collect();
        for &(b, a) in &marked {
            for (db, da) in [(0, 2), (2, 0)] {
                if cells.contains(&(b + db, a + da)) {
                    cells.insert((b + db / 2, a + da / 2));
                }
            }
        }
        let max_cells = ((PLANE_MAX_SIDE / size).floor() as i64).max(1);
        while let Some(&(b0, a0)) = cells.first() {
            let mut a1 = a0;
            while a1 - a0 + 1 < max_cells && cells.contains(&(b0, a1 + 1)) {
                a1 += 1;
            }
            let mut b1 = b0;
            while b1 - b0 + 1 < max_cells && (a0..=a1).all(|a| cells.contains(&(b1 + 1, a))) {
                b1 += 1;
            }
            for b in b0..=b1 {
                for a in a0..=a1 {
                    cells.remove(&(b, a));
                }
            }
            // Each rectangle reaches a hundredth of a cell past its cells, so that where
            // rectangles meet at a T-junction rounding leaves no pinholes between them.
            let m = 0.01 * size;
            let corner =
                origin + u * ((a0 as f64 - 0.5) * size - m) + v * ((b0 as f64 - 0.5) * size - m);
            let eu = u * ((a1 - a0 + 1) as f64 * size + 2.0 * m);
            let ev = v * ((b1 - b0 + 1) as f64 * size + 2.0 * m);
            mesh.push_quad(corner.as_vec3(), eu.as_vec3(), ev.as_vec3(), UvMap::Fit);
        }
    }
    mesh
}

/// A splitmix64 step: a well-mixed 64-bit hash of `x`.
fn mix(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    x = (x ^ (x >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    x ^ (x >> 31)
}

/// A standard normal value fixed by (`seed`, lattice node, component): Box–Muller on two
/// hashed uniforms.
fn node_gauss(seed: u64, node: [i64; 3], component: u64) -> f64 {
    let mut h = mix(seed ^ component.wrapping_mul(0x51_7cc1_b727_220a));
    for c in node {
        h = mix(h ^ c as u64);
    }
    let u1 = ((h >> 11) as f64 + 0.5) / (1u64 << 53) as f64;
    let u2 = ((mix(h) >> 11) as f64) / (1u64 << 53) as f64;
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// A smooth random displacement field: independent Gaussian values on a cubic lattice of
/// spacing `spacing`, interpolated trilinearly, one field per component. Trilinear
/// interpolation of unit values has variance `Π((1−f)² + f²)` at fractional offsets f, whose
/// mean over the cell is (2/3)³; the node values are scaled by `noise / √((2/3)³)` so the
/// field's RMS over space is `noise`.
pub struct Displacement {
    seed: u64,
    spacing: f64,
    scale: f64,
}

impl Displacement {
    pub fn new(seed: u64, spacing: f64, noise: f64) -> Displacement {
        Displacement {
            seed,
            spacing,
            scale: noise / (8.0f64 / 27.0).sqrt(),
        }
    }

    /// The displacement at `p`, m.
    pub fn at(&self, p: [f64; 3]) -> [f64; 3] {
        let g = p.map(|c| c / self.spacing);
        let base = g.map(|c| c.floor() as i64);
        let f = [0, 1, 2].map(|k| g[k] - base[k] as f64);
        let mut out = [0.0; 3];
        for corner in 0..8 {
            let d = [corner & 1, (corner >> 1) & 1, (corner >> 2) & 1];
            let w: f64 = (0..3)
                .map(|k| if d[k] == 1 { f[k] } else { 1.0 - f[k] })
                .product();
            if w == 0.0 {
                continue;
            }
            let node = [0, 1, 2].map(|k| base[k] + d[k] as i64);
            for (c, o) in out.iter_mut().enumerate() {
                *o += w * node_gauss(self.seed, node, c as u64);
            }
        }
        out.map(|o| o * self.scale)
    }
}

/// The mesh resampled so that no edge is longer than `spacing` (each triangle bisected
/// across its longest edge until none is longer) and every vertex displaced by a smooth random
/// field of RMS `noise` ([`Displacement`]). The field is continuous, so where neighbouring
/// triangles are cut differently (a T-junction) they still meet to within the field's change
/// from linear over one cut, far under `noise`: no cracks to see through.
pub fn perturbed(mesh: &TriMesh, spacing: f64, noise: f64, seed: u64) -> TriMesh {
    let field = Displacement::new(seed, spacing, noise);
    let limit = spacing as f32;
    let mut out = TriMesh::default();
    let mut stack = Vec::new();
    for t in &mesh.indices {
        let (a, b, c) = mesh.corners(t);
        stack.push([a, b, c]);
        while let Some([a, b, c]) = stack.pop() {
            let lengths = [(b - a).length(), (c - b).length(), (a - c).length()];
            let (k, longest) = lengths
                .iter()
                .enumerate()
                .fold((0, 0.0f32), |m, (k, &l)| if l > m.1 { (k, l) } else { m });
            // Bisection halves the longest edge; a sliver's other edges shrink with it.
            if longest > limit && !(longest.is_nan()) {
                let [p, q, r] = match k {
                    0 => [a, b, c],
                    1 => [b, c, a],
                    _ => [c, a, b],
                };
                let m = 0.5 * (p + q);
                stack.push([p, m, r]);
                stack.push([m, q, r]);
                continue;
            }
            let base = out.positions.len() as u32;
            for p in [a, b, c] {
                let d = field.at([p.x as f64, p.y as f64, p.z as f64]);
                out.positions
                    .push(p + Vec3::new(d[0] as f32, d[1] as f32, d[2] as f32));
            }
            out.indices.push([base, base + 1, base + 2]);
        }
    }
    out.uvs = vec![glam::Vec2::ZERO; out.positions.len()];
    out.compute_normals();
    out
}

/// A scene of one static body holding `meshes` in the model's frame (static, so the renderer
/// culls them per view).
pub fn scene(meshes: Vec<TriMesh>) -> Scene {
    let mut s = Scene::default();
    s.materials.push(Material {
        name: "model".into(),
        color: [0.7, 0.7, 0.7],
        texture: None,
    });
    s.bodies.push(SceneBody {
        name: "model".into(),
        pose: futago_render::Pose::IDENTITY,
        movable: false,
        parts: meshes
            .into_iter()
            .filter(|m| !m.indices.is_empty())
            .map(|mesh| MeshPart {
                material: 0,
                mesh,
                faces_out: false,
            })
            .collect(),
    });
    s
}

/// A mesh of the triangles of a file's geometry (PLY vertex positions and faces).
pub fn mesh_of(vertices: &[[f64; 3]], triangles: &[[u32; 3]]) -> TriMesh {
    let mut m = TriMesh {
        positions: vertices
            .iter()
            .map(|p| Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32))
            .collect(),
        normals: Vec::new(),
        uvs: vec![glam::Vec2::ZERO; vertices.len()],
        indices: triangles.to_vec(),
    };
    m.remove_degenerate();
    m.compute_normals();
    m
}

/// Most cells [`free_cells`] lays over a model (a 1 km square at 0.5 m).
const MAX_CELLS: usize = 4_000_000;

/// Where a camera at height `height` (m) may be: the centres of the cells of side `cell` over
/// the model's extent in the plane that no triangle of the model crosses within `band` of that
/// height (each triangle marks the cells under its bounding box in the plane, so the free
/// space errs on the small side near slanted surfaces), and, given `inside`, only those joined
/// to its cell by free cells (4-connected): the floor a carrier can reach from where it is,
/// not the space between a building's outer walls and its model's bounding box. Errors when
/// the model is empty or its extent needs more than 4 million cells.
pub fn free_cells(
    meshes: &[TriMesh],
    height: f64,
    band: f64,
    cell: f64,
    inside: Option<[f64; 2]>,
) -> Result<Vec<[f64; 2]>, String> {
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in meshes.iter().flat_map(|m| &m.positions) {
        for k in 0..2 {
            lo[k] = lo[k].min(p[k] as f64);
            hi[k] = hi[k].max(p[k] as f64);
        }
    }
    if !(lo[0].is_finite() && hi[0].is_finite() && lo[1].is_finite() && hi[1].is_finite()) {
        return Err("the model has no vertices".into());
    }
    let nx = ((hi[0] - lo[0]) / cell).ceil().max(1.0);
    let ny = ((hi[1] - lo[1]) / cell).ceil().max(1.0);
    if nx * ny > MAX_CELLS as f64 {
        return Err(format!(
            "the model spans {:.0} m × {:.0} m: more than {MAX_CELLS} cells of {cell} m",
            hi[0] - lo[0],
            hi[1] - lo[1]
        ));
    }
    let (nx, ny) = (nx as usize, ny as usize);
    let mut occupied = vec![false; nx * ny];
    let index =
        |v: f64, k: usize, n: usize| (((v - lo[k]) / cell).floor().max(0.0) as usize).min(n - 1);
    for m in meshes {
        for t in &m.indices {
            let (a, b, c) = m.corners(t);
            let zmin = a.z.min(b.z).min(c.z) as f64;
            let zmax = a.z.max(b.z).max(c.z) as f64;
            if zmax < height - band || zmin > height + band {
                continue;
            }
            let (x0, x1) = (a.x.min(b.x).min(c.x) as f64, a.x.max(b.x).max(c.x) as f64);
            let (y0, y1) = (a.y.min(b.y).min(c.y) as f64, a.y.max(b.y).max(c.y) as f64);
            for j in index(y0, 1, ny)..=index(y1, 1, ny) {
                for i in index(x0, 0, nx)..=index(x1, 0, nx) {
                    occupied[j * nx + i] = true;
                }
            }
        }
    }
    // Flood from `inside`: every cell not reached counts as occupied.
    if let Some(p) = inside {
        let start = index(p[1], 1, ny) * nx + index(p[0], 0, nx);
        let mut reached = vec![false; nx * ny];
        let mut stack = Vec::new();
        if !occupied[start] {
            reached[start] = true;
            stack.push(start);
        }
        while let Some(k) = stack.pop() {
            let (i, j) = (k % nx, k / nx);
            let mut near = Vec::with_capacity(4);
            if i > 0 {
                near.push(k - 1);
            }
            if i + 1 < nx {
                near.push(k + 1);
            }
            if j > 0 {
                near.push(k - nx);
            }
            if j + 1 < ny {
                near.push(k + nx);
            }
            for n in near {
                if !occupied[n] && !reached[n] {
                    reached[n] = true;
                    stack.push(n);
                }
            }
        }
        for (o, r) in occupied.iter_mut().zip(&reached) {
            *o |= !r;
        }
    }
    Ok((0..nx * ny)
        .filter(|k| !occupied[*k])
        .map(|k| {
            let (i, j) = (k % nx, k / nx);
            [
                lo[0] + (i as f64 + 0.5) * cell,
                lo[1] + (j as f64 + 0.5) * cell,
            ]
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points on the plane z = 0.3 over 2 m × 2 m: every surfel lies in the plane, faces ±z,
    /// and together they cover the square (every point of a 5 cm grid inside it lies under
    /// some surfel).
    #[test]
    fn surfels_of_a_plane_lie_in_it_and_cover_it() {
        let mut pts = Vec::new();
        for i in 0..200 {
            for j in 0..200 {
                pts.push([i as f64 * 0.01, j as f64 * 0.01, 0.3]);
            }
        }
        let m = surfels(&pts, 0.1);
        assert_eq!(m.indices.len(), 2 * 400, "one square per occupied voxel");
        for p in &m.positions {
            assert!((p.z - 0.3).abs() < 1e-4, "{p}");
        }
        for n in &m.normals {
            assert!(n.z.abs() > 0.999, "{n}");
        }
        let covered = |x: f32, y: f32| {
            m.indices.iter().any(|t| {
                let (a, b, c) = m.corners(t);
                let s = |p: Vec3, q: Vec3| (q.x - p.x) * (y - p.y) - (q.y - p.y) * (x - p.x);
                let (d1, d2, d3) = (s(a, b), s(b, c), s(c, a));
                !((d1 < 0.0 || d2 < 0.0 || d3 < 0.0) && (d1 > 0.0 || d2 > 0.0 || d3 > 0.0))
            })
        };
        for i in 0..40 {
            for j in 0..40 {
                let (x, y) = (i as f32 * 0.05, j as f32 * 0.05);
                assert!(covered(x, y), "({x}, {y}) not covered");
            }
        }
    }

    /// A lone point and points on one line make no surfel.
    #[test]
    fn isolated_and_collinear_points_make_no_surfels() {
        assert!(surfels(&[[0.0, 0.0, 0.0]], 0.1).indices.is_empty());
        let line: Vec<[f64; 3]> = (0..30).map(|i| [i as f64 * 0.1, 0.0, 0.0]).collect();
        assert!(surfels(&line, 0.1).indices.is_empty());
    }

    /// Distance along the ray from `o` in the unit direction `d` to the nearest triangle of
    /// `m` it hits (Möller–Trumbore), if any.
    fn ray_hit(m: &TriMesh, o: Vec3, d: Vec3) -> Option<f32> {
        m.indices
            .iter()
            .filter_map(|t| {
                let (a, b, c) = m.corners(t);
                let (e1, e2) = (b - a, c - a);
                let p = d.cross(e2);
                let det = e1.dot(p);
                if det.abs() < 1e-9 {
                    return None;
                }
                let s = o - a;
                let u = s.dot(p) / det;
                let q = s.cross(e1);
                let v = d.dot(q) / det;
                let t = e2.dot(q) / det;
                (u >= 0.0 && v >= 0.0 && u + v <= 1.0 && t > 0.0).then_some(t)
            })
            .min_by(f32::total_cmp)
    }

    /// A deterministic offset in ±`amp` for point `i` (a map's noise, without a generator).
    fn jitter(i: u64, amp: f64) -> f64 {
        (mix(i) >> 11) as f64 / (1u64 << 53) as f64 * 2.0 * amp - amp
    }

    /// A floor (z = 0, 3 m × 2 m) meeting a wall (x = 0, 2 m × 1.5 m), points 1 cm apart with
    /// ±5 mm of noise off their surface: merged, they take under a fifth of the surfels'
    /// triangles, every triangle lies on one of the two surfaces or at their edge, no rectangle is longer than
    /// 1 m, and both surfaces are covered where they were sampled, 15 cm clear of their edge
    /// (a ray onto them at every 5 cm meets the model at the surface).
    #[test]
    fn the_surfels_of_a_floor_and_a_wall_merge_into_rectangles_that_cover_them() {
        let mut pts = Vec::new();
        let mut k = 0u64;
        for i in 0..300 {
            for j in 0..200 {
                k += 1;
                pts.push([i as f64 * 0.01, j as f64 * 0.01, jitter(k, 0.005)]);
            }
        }
        for j in 0..200 {
            for h in 1..150 {
                k += 1;
                pts.push([jitter(k, 0.005), j as f64 * 0.01, h as f64 * 0.01]);
            }
        }
        let plain = surfels(&pts, 0.1);
        let m = planar_surfels(&pts, 0.1);
        assert!(
            m.triangle_count() * 5 < plain.triangle_count(),
            "{} merged triangles against {} surfels' triangles",
            m.triangle_count(),
            plain.triangle_count()
        );
        for t in &m.indices {
            let (a, b, c) = m.corners(t);
            let centroid = (a + b + c) / 3.0;
            // Surfels where the surfaces meet fit neither plane and stay squares there.
            assert!(
                centroid.z.abs() < 0.02
                    || centroid.x.abs() < 0.02
                    || (centroid.x < 0.15 && centroid.z < 0.15),
                "a triangle off both surfaces and their edge at {centroid}"
            );
            for (p, q) in [(a, b), (b, c), (c, a)] {
                assert!((p - q).length() < 2f32.sqrt() + 0.01, "{p} – {q}");
            }
        }
        // Clear of the edge, where the squares of the surfels that fit neither plane lean.
        for i in 3..60 {
            for j in 1..40 {
                let (x, y) = (i as f32 * 0.05, j as f32 * 0.05);
                let hit = ray_hit(&m, Vec3::new(x, y, 1.0), -Vec3::Z);
                assert!(
                    hit.is_some_and(|t| (t - 1.0).abs() < 0.02),
                    "floor at ({x}, {y}): {hit:?}"
                );
            }
        }
        for j in 1..40 {
            for h in 3..30 {
                let (y, z) = (j as f32 * 0.05, h as f32 * 0.05);
                let hit = ray_hit(&m, Vec3::new(1.0, y, z), -Vec3::X);
                assert!(
                    hit.is_some_and(|t| (t - 1.0).abs() < 0.02),
                    "wall at ({y}, {z}): {hit:?}"
                );
            }
        }
    }

    /// A plane slanted 30° across the voxel grid, whose voxels project unevenly onto the
    /// plane's own cells, is merged without holes.
    #[test]
    fn a_slanted_plane_merges_without_holes() {
        let (c, s) = (30f64.to_radians().cos(), 30f64.to_radians().sin());
        let mut pts = Vec::new();
        for i in 0..250 {
            for j in 0..200 {
                let (a, b) = (i as f64 * 0.01, j as f64 * 0.01);
                pts.push([a * c, b, a * s + 0.05]);
            }
        }
        let m = planar_surfels(&pts, 0.1);
        assert!(m.triangle_count() < surfels(&pts, 0.1).triangle_count() / 5);
        let n = Vec3::new(-(s as f32), 0.0, c as f32);
        for i in 1..50 {
            for j in 1..40 {
                let (a, b) = (i as f32 * 0.05, j as f32 * 0.05);
                let on = Vec3::new(a * c as f32, b, a * s as f32 + 0.05);
                let hit = ray_hit(&m, on + n, -n);
                assert!(
                    hit.is_some_and(|t| (t - 1.0).abs() < 0.01),
                    "({a}, {b}) along the slope: {hit:?}"
                );
            }
        }
    }

    /// The field: its RMS over many points is the asked `noise` (to sampling error), it is
    /// continuous (points 1 mm apart differ by far less than the noise), and a seed fixes it.
    #[test]
    fn the_displacement_field_has_its_rms_and_is_smooth() {
        let f = Displacement::new(7, 0.25, 0.01);
        let mut s2 = 0.0;
        let n = 20_000;
        for i in 0..n {
            // Offsets spread over the cell in all three axes (the golden ratio's multiples).
            let g = i as f64 * 0.618_033_988_75;
            let p = [
                i as f64 * 0.0131,
                (i * 7 % 101) as f64 * 0.037,
                g.fract() * 5.0,
            ];
            let d = f.at(p);
            s2 += d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        }
        let rms = (s2 / (3 * n) as f64).sqrt();
        assert!((rms - 0.01).abs() < 0.001, "rms {rms}");
        let (a, b) = (f.at([1.0, 2.0, 0.5]), f.at([1.001, 2.0, 0.5]));
        let step = (0..3).map(|k| (a[k] - b[k]).abs()).fold(0.0, f64::max);
        assert!(step < 0.001, "{step}");
        assert_eq!(a, Displacement::new(7, 0.25, 0.01).at([1.0, 2.0, 0.5]));
        assert_ne!(a, Displacement::new(8, 0.25, 0.01).at([1.0, 2.0, 0.5]));
    }

    /// A 2 m square cut to edges of at most 0.25 m: each bisection of a right isosceles
    /// triangle halves it into two whose edges are 1/√2 as long, so each half of the square
    /// (hypotenuse 2√2 m) takes 7 rounds, 2⁷ = 128 pieces of hypotenuse 2√2/√2⁷ = 0.25 m; with no noise the surface is unchanged (same
    /// area, flat), with 1 cm it stays within a few cm of the plane.
    #[test]
    fn a_perturbed_mesh_is_finer_and_stays_near_the_surface() {
        let mut sq = TriMesh::default();
        sq.push_quad(Vec3::ZERO, Vec3::X * 2.0, Vec3::Y * 2.0, UvMap::Fit);
        let flat = perturbed(&sq, 0.25, 0.0, 1);
        assert_eq!(flat.indices.len(), 2 * 128);
        assert!((flat.area() - 4.0).abs() < 1e-4);
        for t in &flat.indices {
            let (a, b, c) = flat.corners(t);
            for l in [(b - a).length(), (c - b).length(), (a - c).length()] {
                assert!(l <= 0.25 + 1e-5, "{l}");
            }
        }
        let rough = perturbed(&sq, 0.25, 0.01, 1);
        let z: Vec<f32> = rough.positions.iter().map(|p| p.z).collect();
        let rms = (z.iter().map(|z| z * z).sum::<f32>() / z.len() as f32).sqrt();
        assert!(rms > 0.004 && rms < 0.02, "rms {rms}");
        assert!(z.iter().all(|z| z.abs() < 0.06));
    }

    /// A 4 m × 2 m room (floor at 0, walls 2 m high) with a 1 m box at (1, 1): at 0.5 m the
    /// camera's height crosses the walls (the border cells) and the box, not the floor.
    #[test]
    fn free_cells_leave_out_walls_and_furniture_at_the_cameras_height() {
        let mut room = TriMesh::default();
        room.push_quad(Vec3::ZERO, Vec3::X * 4.0, Vec3::Y * 2.0, UvMap::Fit);
        room.push_quad(Vec3::ZERO, Vec3::X * 4.0, Vec3::Z * 2.0, UvMap::Fit);
        room.push_quad(Vec3::Y * 2.0, Vec3::X * 4.0, Vec3::Z * 2.0, UvMap::Fit);
        let mut boxy = TriMesh::default();
        boxy.push_quad(
            Vec3::new(0.75, 0.75, 0.0),
            Vec3::X * 0.5,
            Vec3::Z * 1.0,
            UvMap::Fit,
        );
        let free = free_cells(&[room.clone(), boxy.clone()], 0.5, 0.1, 0.5, None).unwrap();
        // 8 × 4 cells; the rows y ∈ [0, 0.5) and [1.5, 2] hold the walls; the box's face at
        // y = 0.75 from x 0.75 to 1.25 takes cells x ∈ [0.5, 1.0) and [1.0, 1.5) of row 1.
        assert_eq!(free.len(), 8 * 2 - 2);
        assert!(free.iter().all(|c| c[1] > 0.5 && c[1] < 1.5));
        assert!(!free.contains(&[0.75, 0.75]) && free.contains(&[0.25, 0.75]));
        // At a height the walls do not reach (3 m) everything is free.
        assert_eq!(
            free_cells(&[room.clone()], 3.0, 0.1, 0.5, None)
                .unwrap()
                .len(),
            32
        );
        assert!(free_cells(&[], 0.5, 0.1, 0.5, None).is_err());
        // A wall across the room at x = 2 parts it; it takes the column x ∈ [2, 2.5) (a cell
        // boundary goes to the cell above it), so from (3, 1) only the 3 × 2 cells east of it.
        let mut parted = room;
        parted.push_quad(
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::Y * 2.0,
            Vec3::Z * 2.0,
            UvMap::Fit,
        );
        let east = free_cells(&[parted], 0.5, 0.1, 0.5, Some([3.0, 1.0])).unwrap();
        assert!(east.iter().all(|c| c[0] > 2.5), "{east:?}");
        assert_eq!(east.len(), 6);
    }
}
