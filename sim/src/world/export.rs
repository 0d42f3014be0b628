//! Ground truth from the world's own geometry: the occupancy grid of a height band (what a
//! perfect 2D mapper would draw) and the world mesh as PLY.

use super::World;
use futago_msgs::grid::OccupancyGrid;
use glam::Vec3;
use rapier3d::math::Pose;
use rapier3d::parry::query::{Ray, intersection_test};
use rapier3d::parry::shape::Cuboid;

/// The most cells a ground-truth grid may have (2²⁸: 256 MiB; 4 km × 4 km at 25 cm).
pub const MAX_GRID_CELLS: usize = 1 << 28;

/// Rasterises the static colliders that intersect the height band `[z_min, z_max]` into an
/// occupancy grid (0 free, 100 occupied) covering the world's bounds plus `margin`.
///
/// A cell is occupied when its box `cell × [z_min, z_max]` intersects a collider (an exact
/// parry intersection test, not a sampling). Dynamic bodies are left out: they move. Cells
/// that intersect nothing are free, inside or outside the building alike.
pub fn occupancy_grid(
    world: &World,
    resolution: f64,
    z_min: f64,
    z_max: f64,
    margin: f64,
) -> Result<OccupancyGrid, String> {
    let (lo, hi) = world.bounds();
    let origin = [
        ((lo.x as f64 - margin) / resolution).floor() * resolution,
        ((lo.y as f64 - margin) / resolution).floor() * resolution,
    ];
    let width = (((hi.x as f64 + margin) - origin[0]) / resolution)
        .ceil()
        .max(1.0);
    let height = (((hi.y as f64 + margin) - origin[1]) / resolution)
        .ceil()
        .max(1.0);
    if !(resolution.is_finite() && resolution > 0.0 && width * height <= MAX_GRID_CELLS as f64) {
        return Err(format!(
            "a grid of world `{}` at {resolution} m a cell would have {width} × {height} cells; at most {MAX_GRID_CELLS}",
            world.name
        ));
    }
    let (width, height) = (width as usize, height as usize);
    let mut grid = OccupancyGrid::new(resolution, origin, width, height);
    grid.cells.fill(0);
    // Cells shrink by a hair so that a face lying exactly on a cell border (a wall's inner
    // face on a grid line) does not mark the free cell beside it.
    let half = resolution as f32 / 2.0 - 1e-5;
    let cell = Cuboid::new(Vec3::new(half, half, ((z_max - z_min) / 2.0) as f32));
    let zc = ((z_min + z_max) / 2.0) as f32;
    for o in world
        .objects
        .iter()
        .filter(|o| o.motion == super::Motion::Static)
    {
        let Some(shape) = &o.shape else { continue };
        let aabb = shape.compute_aabb(&o.pose);
        if aabb.maxs.z < z_min as f32 || aabb.mins.z > z_max as f32 {
            continue;
        }
        let i0 = ((aabb.mins.x as f64 - origin[0]) / resolution)
            .floor()
            .max(0.0) as usize;
        let j0 = ((aabb.mins.y as f64 - origin[1]) / resolution)
            .floor()
            .max(0.0) as usize;
        let i1 = (((aabb.maxs.x as f64 - origin[0]) / resolution).floor() as usize).min(width - 1);
        let j1 = (((aabb.maxs.y as f64 - origin[1]) / resolution).floor() as usize).min(height - 1);
        for j in j0..=j1 {
            for i in i0..=i1 {
                if grid.get(i, j) == 100 {
                    continue;
                }
                let c = grid.cell_center(i, j);
                let pos = Pose::from_translation(Vec3::new(c[0] as f32, c[1] as f32, zc));
                // Shapes without an intersection routine (none of ours) count as free.
                let hit = intersection_test(&pos, &cell, &o.pose, shape.as_ref())
                    .map(|r| r.intersecting)
                    .unwrap_or(false);
                if hit {
                    grid.set(i, j, 100);
                }
            }
        }
    }
    Ok(grid)
}

/// The distance from `origin` along `direction` (normalised here) to the first static
/// collider, m, up to `max`; `None` when nothing lies within `max` or `direction` is zero.
/// Dynamic bodies are left out: this measures the building (a corridor's width, a hall's
/// length), as [`occupancy_grid`] draws it.
pub fn cast_static(world: &World, origin: [f64; 3], direction: [f64; 3], max: f64) -> Option<f64> {
    let d = Vec3::new(
        direction[0] as f32,
        direction[1] as f32,
        direction[2] as f32,
    );
    if !(d.length().is_finite() && d.length() > 0.0) {
        return None;
    }
    let ray = Ray::new(
        Vec3::new(origin[0] as f32, origin[1] as f32, origin[2] as f32),
        d.normalize(),
    );
    world
        .objects
        .iter()
        .filter(|o| o.motion == super::Motion::Static)
        .filter_map(|o| o.shape.as_ref()?.cast_ray(&o.pose, &ray, max as f32, true))
        .min_by(f32::total_cmp)
        .map(|t| t as f64)
}

/// The world's render meshes at their initial poses as a binary little-endian PLY with
/// per-vertex normals and colours (a textured material gets its texture's mean colour).
pub fn to_ply(world: &World) -> Vec<u8> {
    let parts: Vec<_> = world
        .objects
        .iter()
        .flat_map(|o| o.parts.iter().map(move |p| (o.pose, p)))
        .collect();
    let nv: usize = parts.iter().map(|(_, p)| p.mesh.positions.len()).sum();
    let nf: usize = parts.iter().map(|(_, p)| p.mesh.indices.len()).sum();
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\ncomment futago world {}\nelement vertex {nv}\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nelement face {nf}\nproperty list uchar uint vertex_indices\nend_header\n",
        world.name
    )
    .into_bytes();
    let colors: Vec<[u8; 3]> = world
        .materials
        .iter()
        .map(|m| {
            let c = m
                .texture
                .map(|t| world.textures[t].mean_color())
                .unwrap_or(m.color);
            c.map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
        })
        .collect();
    for (pose, p) in &parts {
        let rgb = colors[p.material];
        for (v, n) in p.mesh.positions.iter().zip(&p.mesh.normals) {
            let (w, wn) = (*pose * *v, pose.rotation * *n);
            for f in [w.x, w.y, w.z, wn.x, wn.y, wn.z] {
                out.extend_from_slice(&f.to_le_bytes());
            }
            out.extend_from_slice(&rgb);
        }
    }
    let mut base = 0u32;
    for (_, p) in &parts {
        for t in &p.mesh.indices {
            out.push(3);
            for i in t {
                out.extend_from_slice(&(i + base).to_le_bytes());
            }
        }
        base += p.mesh.positions.len() as u32;
    }
    out
}
