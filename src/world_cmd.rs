//! `futago world`: checking a world file and exporting its ground truth.

use anyhow::{Context, Result, bail};
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

/// Writes `<name>.pgm`/`.yaml` (occupancy of the band) and the mesh files into the folder
/// `out`, created or replaced whole when futago wrote it (or with `force`); returns the paths
/// written.
pub fn export_world(
    world: &World,
    out: &Path,
    o: &ExportOptions,
    force: bool,
) -> Result<Vec<std::path::PathBuf>> {
    crate::output::check_folder(out, force)?;
    // The grid is made (or refused) before anything is written.
    let grid = if o.grid {
        Some(
            export::occupancy_grid(world, o.resolution, o.band.0, o.band.1, o.margin)
                .map_err(|e| anyhow::anyhow!("--resolution: {e}"))?,
        )
    } else {
        None
    };
    crate::run::write_atomically(out, force, "world export", |dir| {
        write_export(world, dir, grid, o)
    })
    .map(|names| names.into_iter().map(|n| out.join(n)).collect())
}

/// The export's files, written into `dir`; their names.
fn write_export(
    world: &World,
    dir: &Path,
    grid: Option<futago_msgs::grid::OccupancyGrid>,
    o: &ExportOptions,
) -> Result<Vec<String>> {
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
        written.extend([format!("{stem}.pgm"), format!("{stem}.yaml")]);
    }
    let poses: Vec<_> = world.objects.iter().map(|ob| ob.pose).collect();
    if matches!(o.mesh, MeshFormat::Ply | MeshFormat::Both) {
        let p = dir.join(format!("{stem}.ply"));
        write_atomic(&p, &export::to_ply(world))?;
        written.push(format!("{stem}.ply"));
    }
    if matches!(o.mesh, MeshFormat::Glb | MeshFormat::Both) {
        let p = dir.join(format!("{stem}.glb"));
        write_atomic(&p, &gltf_io::export_glb(world, &poses))?;
        written.push(format!("{stem}.glb"));
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

/// Settings of `futago world from-map`.
#[derive(Debug, Clone)]
pub struct FromMapOptions {
    /// The world's name (default: the output file's stem).
    pub name: Option<String>,
    /// Wall (and ceiling) height, m.
    pub height: f64,
    /// What the map's unknown cells become.
    pub unknown: futago_sim::world::floor_plan::UnknownCells,
    /// The start pose `[x, y, yaw_deg]` (default: the free cell farthest from any wall).
    pub spawn: Option<[f64; 3]>,
    /// Put a ceiling at the walls' height.
    pub ceiling: bool,
}

/// Clearance a spawn needs from walls and unknown cells, m: the Create's radius (0.17 m)
/// and a margin.
const SPAWN_CLEARANCE: f64 = 0.25;

/// The name of the world `from_map` writes: `--name`, or the world file's stem; letters,
/// digits, '-' and '_', for it names the world's files.
fn world_name(o: &FromMapOptions, out: &Path) -> Result<String> {
    let name = match &o.name {
        Some(n) => n.clone(),
        None => out
            .file_stem()
            .map(|s| s.to_string_lossy().to_string())
            .unwrap_or_default(),
    };
    if name.is_empty()
        || !name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
    {
        anyhow::bail!(
            "--name: `{name}`: expected letters, digits, '-' and '_' (the world's name names its files)"
        );
    }
    Ok(name)
}

/// Makes a world from a map_server map: writes the world file `out` and, beside it, the map
/// as `<name>.map.pgm`/`.yaml` (trinary), which the world's `[[map_walls]]` names, so that the
/// world is self-contained. The world is compiled before it is put in place; returns it.
pub fn from_map(map: &Path, out: &Path, o: &FromMapOptions, force: bool) -> Result<World> {
    use futago_sim::world::floor_plan::{UnknownCells, WallCells};
    if !(o.height.is_finite() && (0.1..=100.0).contains(&o.height)) {
        anyhow::bail!("--height: expected 0.1 to 100 m, found {}", o.height);
    }
    let grid = known_part(&futago_msgs::map_server::read(map)?)
        .with_context(|| format!("{}: every cell of the map is unknown", map.display()))?;
    let name = world_name(o, out)?;
    // Free cells, and how far each lies from the nearest wall or unknown cell.
    let walls = WallCells::new(&grid, o.unknown);
    let (w, h) = (walls.width, walls.height);
    let free: Vec<bool> = (0..w * h)
        .map(|k| {
            let (i, j) = (k % w, k / w);
            !walls.wall[k]
                && i > 0
                && j > 0
                && i < w - 1
                && j < h - 1
                && (0..futago_sim::world::floor_plan::WALL_VALUE).contains(&grid.get(i - 1, j - 1))
        })
        .collect();
    let blocked: Vec<bool> = free.iter().map(|f| !f).collect();
    let d2 = futago_robot::geometry::grid::squared_edt(&blocked, w, h);
    let clearance = |x: f64, y: f64| -> f64 {
        let i = ((x - walls.origin[0]) / walls.resolution).floor();
        let j = ((y - walls.origin[1]) / walls.resolution).floor();
        if i < 0.0 || j < 0.0 || i as usize >= w || j as usize >= h {
            return 0.0;
        }
        d2[j as usize * w + i as usize].sqrt() * walls.resolution
    };
    let spawn = match o.spawn {
        Some(s) => {
            let c = clearance(s[0], s[1]);
            if c < SPAWN_CLEARANCE {
                anyhow::bail!(
                    "--spawn: ({}, {}) is {c:.2} m from a wall or unknown cell of {}: expected a free cell at least {SPAWN_CLEARANCE} m clear",
                    s[0],
                    s[1],
                    map.display()
                );
            }
            s
        }
        None => {
            // The first cell (bottom row first) of greatest clearance.
            let best = (0..w * h)
                .filter(|&k| free[k])
                .max_by(|&a, &b| d2[a].total_cmp(&d2[b]).then(b.cmp(&a)))
                .with_context(|| format!("{}: the map has no free cell", map.display()))?;
            let c = d2[best].sqrt() * walls.resolution;
            if c < SPAWN_CLEARANCE {
                anyhow::bail!(
                    "{}: no free cell is {SPAWN_CLEARANCE} m clear of walls and unknown cells (the roomiest is {c:.2} m): no room for the Create",
                    map.display()
                );
            }
            [
                walls.origin[0] + ((best % w) as f64 + 0.5) * walls.resolution,
                walls.origin[1] + ((best / w) as f64 + 0.5) * walls.resolution,
                0.0,
            ]
        }
    };
    let dir = match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => std::path::PathBuf::from("."),
    };
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let stem = format!("{name}.map");
    let pgm = dir.join(format!("{stem}.pgm"));
    let yaml = dir.join(format!("{stem}.yaml"));
    // The world file and its map copy replace only what an earlier from-map wrote: a world
    // file with its header, and the map copy beside such a world file.
    let ours = std::fs::read(out).is_ok_and(|b| b.starts_with(FROM_MAP_HEADER.as_bytes()));
    crate::output::check_file(out, force, |_| ours)?;
    crate::output::check_file(&pgm, force, |_| ours)?;
    crate::output::check_file(&yaml, force, |_| ours)?;
    let unknown = match o.unknown {
        UnknownCells::Wall => "wall",
        UnknownCells::Free => "free",
    };
    let mut toml = format!(
        "{FROM_MAP_HEADER}{map}`: the occupied cells of that ROS map_server map\n\
         # ({w} × {h} cells of {res} m, copied beside this file as {stem}.pgm/.yaml) extruded into\n\
         # walls {height} m high. Unknown cells: {unknown} (wall: sealed where they touch free space,\n\
         # free space narrower than {min_free} m taken for unknown first; free: open floor).\n\
         name = \"{name}\"\n\
         description = \"Walls extruded from an occupancy map of {gw} × {gh} cells at {res} m\"\n\n\
         [[spawn]]\nname = \"start\"\nx = {x}\ny = {y}\nyaw_deg = {yaw}\n\n\
         [materials.plaster]\ncolor = [0.86, 0.84, 0.80]\n\
         texture = {{ pattern = \"noise\", color2 = [0.70, 0.68, 0.64], size = [1.5, 1.5], seed = 11 }}\n\n\
         [materials.floor]\ncolor = [0.55, 0.56, 0.58]\n\
         texture = {{ pattern = \"noise\", color2 = [0.47, 0.48, 0.50], size = [2.0, 2.0], seed = 5 }}\n\n\
         [materials.ceiling]\ncolor = [0.95, 0.95, 0.95]\n\n\
         [[map_walls]]\nmap = \"{stem}.yaml\"\nmaterial = \"plaster\"\nheight = {height}\nunknown = \"{unknown}\"\n\n\
         [floor]\nmaterial = \"floor\"\n",
        map = map.display(),
        min_free = futago_sim::world::floor_plan::MIN_FREE_WIDTH,
        w = grid.width,
        h = grid.height,
        gw = grid.width,
        gh = grid.height,
        res = grid.resolution,
        height = o.height,
        x = round_mm(spawn[0]),
        y = round_mm(spawn[1]),
        yaw = round_mm(spawn[2]),
    );
    if o.ceiling {
        toml += &format!(
            "\n[ceiling]\nmaterial = \"ceiling\"\nheight = {}\n",
            o.height
        );
    }
    // The map first, then the world file through a temporary name, compiled before it is
    // renamed into place.
    write_atomic(&pgm, &grid.to_pgm())?;
    write_atomic(&yaml, grid.to_yaml(&format!("{stem}.pgm")).as_bytes())?;
    let tmp = dir.join(format!("{name}.toml.partial"));
    std::fs::write(&tmp, &toml).with_context(|| format!("writing {}", tmp.display()))?;
    let world = match World::load(&tmp) {
        Ok(w) => w,
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            return Err(e.into());
        }
    };
    std::fs::rename(&tmp, out)
        .with_context(|| format!("renaming {} to {}", tmp.display(), out.display()))?;
    Ok(World {
        source: out.to_path_buf(),
        ..world
    })
}

/// How a world file that `futago world from-map` wrote begins.
const FROM_MAP_HEADER: &str = "# Made by `futago world from-map ";

/// `v` to three decimals, for a file a person reads.
fn round_mm(v: f64) -> f64 {
    (v * 1000.0).round() / 1000.0
}

/// The grid cut to the bounding box of its known cells (a SLAM map is mostly the unknown
/// space round the building); `None` when no cell is known.
pub(crate) fn known_part(
    g: &futago_msgs::grid::OccupancyGrid,
) -> Option<futago_msgs::grid::OccupancyGrid> {
    let (mut i0, mut j0, mut i1, mut j1) = (usize::MAX, usize::MAX, 0, 0);
    for j in 0..g.height {
        for i in 0..g.width {
            if g.get(i, j) >= 0 {
                (i0, j0, i1, j1) = (i0.min(i), j0.min(j), i1.max(i), j1.max(j));
            }
        }
    }
    if i0 == usize::MAX {
        return None;
    }
    let mut out = futago_msgs::grid::OccupancyGrid::new(
        g.resolution,
        // To the micrometre, so that the YAML does not carry the sum's rounding.
        [
            ((g.origin[0] + i0 as f64 * g.resolution) * 1e6).round() / 1e6,
            ((g.origin[1] + j0 as f64 * g.resolution) * 1e6).round() / 1e6,
        ],
        i1 - i0 + 1,
        j1 - j0 + 1,
    );
    for j in j0..=j1 {
        for i in i0..=i1 {
            out.set(i - i0, j - j0, g.get(i, j));
        }
    }
    Some(out)
}

/// `--band ZMIN:ZMAX` of `futago world export`, m.
pub fn parse_band(s: &str) -> Result<(f64, f64)> {
    let (a, b) = s
        .split_once(':')
        .with_context(|| format!("--band: expected ZMIN:ZMAX in metres, found `{s}`"))?;
    let (a, b): (f64, f64) = (
        a.trim()
            .parse()
            .with_context(|| format!("--band: `{a}` is not a number"))?,
        b.trim()
            .parse()
            .with_context(|| format!("--band: `{b}` is not a number"))?,
    );
    if !(a.is_finite() && b.is_finite() && b > a) {
        bail!("--band: expected ZMIN < ZMAX, found {a}:{b}");
    }
    Ok((a, b))
}

/// `--spawn X,Y,YAW_DEG` of `futago world from-map` (m, m, degrees).
pub fn parse_spawn(s: &str) -> Result<[f64; 3]> {
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .ok()
        .filter(|v: &Vec<f64>| v.len() == 3 && v.iter().all(|x| x.is_finite()))
        .with_context(|| format!("--spawn: `{s}`: expected X,Y,YAW_DEG (m, m, degrees)"))?;
    Ok([v[0], v[1], v[2]])
}

/// Checks the numbers of `futago world export`: a cell size in [0.001, 10] m and a
/// non-negative margin.
pub fn check_export_options(resolution: f64, margin: f64) -> Result<()> {
    if !(resolution.is_finite() && (0.001..=10.0).contains(&resolution)) {
        bail!("--resolution: expected a cell size in [0.001, 10] m, found {resolution}");
    }
    if !(margin.is_finite() && margin >= 0.0) {
        bail!("--margin: expected a non-negative number of metres, found {margin}");
    }
    Ok(())
}
