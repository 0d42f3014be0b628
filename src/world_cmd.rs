//! `futago world`: checking a world file and exporting its ground truth.

use anyhow::{Context, Result};
use futago_sim::World;
use futago_sim::world::{export, gltf_io};
use std::path::Path;

/// Writes `bytes` to `path` through a temporary file and a rename, so that `path` holds either
/// its old content or the whole new one.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = path.with_extension(format!(
        "{}.partial",
        path.extension().and_then(|e| e.to_str()).unwrap_or("")
    ));
    std::fs::write(&tmp, bytes).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path)
        .with_context(|| format!("renaming {} to {}", tmp.display(), path.display()))
}

/// Which mesh formats to write.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum MeshFormat {
    Ply,
    Glb,
    Both,
    None,
}

/// Export settings.
#[derive(Debug, Clone)]
pub struct ExportOptions {
    pub resolution: f64,
    pub band: (f64, f64),
    pub margin: f64,
    pub mesh: MeshFormat,
    /// Write the occupancy grid.
    pub grid: bool,
}

/// Writes `<name>.pgm`/`.yaml` (occupancy of the band) and the mesh files into `dir`; returns
/// the paths written.
pub fn export_world(
    world: &World,
    dir: &Path,
    o: &ExportOptions,
) -> Result<Vec<std::path::PathBuf>> {
    // The grid is made (or refused) before anything is written.
    let grid = if o.grid {
        Some(
            export::occupancy_grid(world, o.resolution, o.band.0, o.band.1, o.margin)
                .map_err(|e| anyhow::anyhow!("--resolution: {e}"))?,
        )
    } else {
        None
    };
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let mut written = Vec::new();
    let stem = &world.name;
    if let Some(grid) = grid {
        let pgm = dir.join(format!("{stem}.pgm"));
        write_atomic(&pgm, &grid.to_pgm())?;
        let yaml = dir.join(format!("{stem}.yaml"));
        let mut y = grid.to_yaml(&format!("{stem}.pgm"));
        y.push_str(&format!(
            "# futago: static colliders intersecting z in [{}, {}] m of world `{}`\n",
            o.band.0, o.band.1, world.name
        ));
        write_atomic(&yaml, y.as_bytes())?;
        written.extend([pgm, yaml]);
    }
    let poses: Vec<_> = world.objects.iter().map(|ob| ob.pose).collect();
    if matches!(o.mesh, MeshFormat::Ply | MeshFormat::Both) {
        let p = dir.join(format!("{stem}.ply"));
        write_atomic(&p, &export::to_ply(world))?;
        written.push(p);
    }
    if matches!(o.mesh, MeshFormat::Glb | MeshFormat::Both) {
        let p = dir.join(format!("{stem}.glb"));
        write_atomic(&p, &gltf_io::export_glb(world, &poses))?;
        written.push(p);
    }
    Ok(written)
}

/// A one-paragraph description of a world.
pub fn describe(world: &World) -> String {
    let (lo, hi) = world.bounds();
    let dynamic = world
        .objects
        .iter()
        .filter(|o| o.motion != futago_sim::world::Motion::Static)
        .count();
    format!(
        "world `{}` ({}): {} objects ({} dynamic), {} triangles, {} materials, {} textures\nbounds: x {:.2}..{:.2}, y {:.2}..{:.2}, z {:.2}..{:.2} m\nspawns: {}",
        world.name,
        world.source.display(),
        world.objects.len(),
        dynamic,
        world.triangle_count(),
        world.materials.len(),
        world.textures.len(),
        lo.x,
        hi.x,
        lo.y,
        hi.y,
        lo.z,
        hi.z,
        world
            .spawns
            .iter()
            .map(|(n, p)| format!("{n} ({:.2}, {:.2}, {:.0}°)", p.x, p.y, p.theta.to_degrees()))
            .collect::<Vec<_>>()
            .join(", ")
    )
}

/// Loads a world, naming the file on error.
pub fn load(path: &Path) -> Result<World> {
    Ok(World::load(path)?)
}
