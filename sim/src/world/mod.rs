//! Worlds: the TOML world format, compiled into one immutable [`World`] value.
//!
//! Like MuJoCo's `mjModel`, a [`World`] is what the files describe and never changes while a
//! simulation runs; the running state (body poses, velocities) lives in
//! [`crate::Simulation`]. A world is a list of [`Object`]s, each with a pose, a collider shape
//! and render meshes that describe the same surface: the physics, the laser, the camera and the
//! ground-truth exports all read this one description.

pub mod export;
pub mod floor_plan;
pub mod gltf_io;
pub mod spec;
pub mod texture;

use crate::config::{SpecError, check_name, check_positive, check_range, load_toml};
use futago_msgs::Pose2;
pub use futago_render::mesh;
pub use futago_render::{Material, MeshPart, Texture};
use glam::{Quat, Vec2, Vec3};
use mesh::{TriMesh, UvMap};
use rapier3d::math::Pose;
use rapier3d::prelude::SharedShape;
use spec::*;
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

/// How an object moves.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Motion {
    /// Fixed in the world.
    Static,
    /// A free rigid body with this mass, kg.
    Dynamic { mass: f64 },
}

/// One thing in the world: a pose, a collider and its render meshes.
#[derive(Debug, Clone)]
pub struct Object {
    pub name: String,
    /// Initial pose in the world frame.
    pub pose: Pose,
    /// Collision (and laser) shape in the object frame; `None` for visual-only meshes.
    pub shape: Option<SharedShape>,
    pub parts: Vec<MeshPart>,
    pub motion: Motion,
    pub friction: f64,
    /// The floor or ceiling slab. The planar robot body does not collide with slabs (its
    /// height is fixed), which keeps the contact solver idle while it drives.
    pub slab: bool,
}

impl Object {
    /// Whether the object is part of a wall: of a `[[walls]]` polyline or extruded from a
    /// floor plan's `[[map_walls]]` (the surface class "walls" of the coverage scores).
    pub fn is_wall(&self) -> bool {
        self.name.starts_with("walls[") || self.name.starts_with("map_walls[")
    }
}

/// A compiled world: immutable while a simulation runs.
#[derive(Debug, Clone)]
pub struct World {
    pub name: String,
    pub description: String,
    /// The world file it was compiled from.
    pub source: PathBuf,
    pub materials: Vec<Material>,
    pub textures: Vec<Texture>,
    pub objects: Vec<Object>,
    /// Named start poses.
    pub spawns: Vec<(String, Pose2)>,
}

/// Axis-aligned bounds `(min, max)`.
pub type Bounds = (Vec3, Vec3);

impl World {
    /// The render scene of every object, in [`World::objects`] order: static objects merged,
    /// dynamic ones movable. Bodies the world does not list (the robot) are added after them.
    pub fn scene(&self) -> futago_render::Scene {
        futago_render::Scene {
            materials: self.materials.clone(),
            textures: self.textures.clone(),
            bodies: self
                .objects
                .iter()
                .map(|o| futago_render::SceneBody {
                    name: o.name.clone(),
                    pose: o.pose,
                    movable: matches!(o.motion, Motion::Dynamic { .. }),
                    parts: o.parts.clone(),
                })
                .collect(),
        }
    }

    /// Loads and compiles a world file, with its meshes and textures. A bare glTF file
    /// (`.glb`, `.gltf`) is a world of that one static mesh, its triangles the collider.
    pub fn load(path: &Path) -> Result<World, SpecError> {
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase());
        if matches!(ext.as_deref(), Some("glb" | "gltf")) {
            let file = path
                .file_name()
                .map(|f| f.to_string_lossy().to_string())
                .unwrap_or_default();
            let name: String = path
                .file_stem()
                .map(|f| f.to_string_lossy().to_string())
                .unwrap_or_default()
                .chars()
                .map(|c| {
                    if c.is_ascii_alphanumeric() || c == '-' {
                        c
                    } else {
                        '_'
                    }
                })
                .collect();
            let mut t = toml::Table::new();
            t.insert("name".into(), toml::Value::String(name));
            let mut mesh = toml::Table::new();
            mesh.insert("file".into(), toml::Value::String(file));
            t.insert(
                "meshes".into(),
                toml::Value::Array(vec![toml::Value::Table(mesh)]),
            );
            let spec: WorldSpec = crate::config::parse_toml(path, &t.to_string())?;
            return compile(&spec, path);
        }
        let spec: WorldSpec = load_toml(path)?;
        compile(&spec, path)
    }

    /// A named spawn pose.
    pub fn spawn(&self, name: &str) -> Option<Pose2> {
        self.spawns.iter().find(|(n, _)| n == name).map(|(_, p)| *p)
    }

    /// Bounds of every object's render mesh at its initial pose.
    pub fn bounds(&self) -> Bounds {
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for o in &self.objects {
            for p in &o.parts {
                for &v in &p.mesh.positions {
                    let w = o.pose * v;
                    lo = lo.min(w);
                    hi = hi.max(w);
                }
            }
        }
        (lo, hi)
    }

    /// Total triangle count of all render meshes.
    pub fn triangle_count(&self) -> usize {
        self.objects
            .iter()
            .flat_map(|o| &o.parts)
            .map(|p| p.mesh.triangle_count())
            .sum()
    }
}

/// How far from the origin any part of a world may lie, m (in x, y and z). A building of
/// 4 km across fits; f32 coordinates keep millimetres out there.
pub const MAX_EXTENT: f32 = 2000.0;

/// Builds the world from its parsed spec; `path` resolves relative asset paths and names the
/// file in errors.
pub fn compile(spec: &WorldSpec, path: &Path) -> Result<World, SpecError> {
    let mut c = Compiler {
        path,
        dir: path.parent().unwrap_or(Path::new(".")),
        world: World {
            name: spec.name.clone(),
            description: spec.description.clone(),
            source: path.to_path_buf(),
            materials: Vec::new(),
            textures: Vec::new(),
            objects: Vec::new(),
            spawns: Vec::new(),
        },
        material_ids: HashMap::new(),
        gltf_cache: HashMap::new(),
        tiles: Vec::new(),
    };
    check_name(path, "name", &spec.name)?;
    c.materials(&spec.materials)?;
    for (i, s) in spec.spawn.iter().enumerate() {
        let key = format!("spawn[{i}]");
        if !(s.x.is_finite() && s.y.is_finite() && s.yaw_deg.is_finite()) {
            return Err(SpecError::new(
                path,
                key,
                "expected finite x, y and yaw_deg",
            ));
        }
        if c.world.spawns.iter().any(|(n, _)| *n == s.name) {
            return Err(SpecError::new(
                path,
                format!("{key}.name"),
                format!("spawn `{}` is defined twice", s.name),
            ));
        }
        c.world
            .spawns
            .push((s.name.clone(), Pose2::new(s.x, s.y, s.yaw_deg.to_radians())));
    }
    for (i, w) in spec.walls.iter().enumerate() {
        c.wall(w, &format!("walls[{i}]"))?;
    }
    for (i, m) in spec.map_walls.iter().enumerate() {
        c.map_walls(m, &format!("map_walls[{i}]"))?;
    }
    let root = Pose::IDENTITY;
    for (i, b) in spec.boxes.iter().enumerate() {
        c.cuboid(b, &root, &format!("boxes[{i}]"))?;
    }
    for (i, cy) in spec.cylinders.iter().enumerate() {
        c.cylinder(cy, &root, &format!("cylinders[{i}]"))?;
    }
    for (i, m) in spec.meshes.iter().enumerate() {
        c.mesh(m, &root, &format!("meshes[{i}]"))?;
    }
    for (i, inst) in spec.instances.iter().enumerate() {
        let key = format!("instances[{i}]");
        let prefab = spec.prefabs.get(&inst.prefab).ok_or_else(|| {
            SpecError::new(
                path,
                format!("{key}.prefab"),
                format!(
                    "unknown prefab `{}`; defined: {:?}",
                    inst.prefab,
                    spec.prefabs.keys().collect::<Vec<_>>()
                ),
            )
        })?;
        for (j, at) in inst.at.iter().enumerate() {
            if at.iter().any(|v| !v.is_finite()) {
                return Err(SpecError::new(
                    path,
                    format!("{key}.at[{j}]"),
                    "expected finite [x, y, yaw_deg]",
                ));
            }
            let frame = Pose::from_parts(
                Vec3::new(at[0] as f32, at[1] as f32, 0.0),
                Quat::from_rotation_z(at[2].to_radians() as f32),
            );
            let pk = format!("prefabs.{}", inst.prefab);
            for (k, b) in prefab.boxes.iter().enumerate() {
                c.cuboid(b, &frame, &format!("{pk}.boxes[{k}]"))?;
            }
            for (k, cy) in prefab.cylinders.iter().enumerate() {
                c.cylinder(cy, &frame, &format!("{pk}.cylinders[{k}]"))?;
            }
            for (k, m) in prefab.meshes.iter().enumerate() {
                c.mesh(m, &frame, &format!("{pk}.meshes[{k}]"))?;
            }
        }
    }
    // Floor and ceiling last: their default extent is that of everything else.
    c.slabs(spec)?;
    if c.world.objects.is_empty() {
        return Err(SpecError::new(
            path,
            "",
            "the world has no geometry: expected walls, boxes, cylinders, meshes or a floor",
        ));
    }
    // Coordinates far from the origin lose f32 precision and make grids of the world
    // unbounded in size: everything must lie within MAX_EXTENT of the origin.
    for o in &c.world.objects {
        let far = o.parts.iter().flat_map(|p| &p.mesh.positions).find(|&&v| {
            let w = o.pose * v;
            !(w.x.abs() <= MAX_EXTENT && w.y.abs() <= MAX_EXTENT && w.z.abs() <= MAX_EXTENT)
        });
        if let Some(&v) = far {
            let w = o.pose * v;
            return Err(SpecError::new(
                path,
                &o.name,
                format!(
                    "reaches ({}, {}, {}) m: expected every part of the world within {MAX_EXTENT} m of the origin",
                    w.x, w.y, w.z
                ),
            ));
        }
    }
    Ok(c.world)
}

impl Compiler<'_> {
    /// The floor and the ceiling (slabs), by default as wide as everything else plus their
    /// margin.
    fn slabs(&mut self, spec: &WorldSpec) -> Result<(), SpecError> {
        let path = self.path;
        let (lo, hi) = self.world.bounds();
        let have_extent = lo.x.is_finite();
        for (slab, is_ceiling, key) in [
            (&spec.floor, false, "floor"),
            (&spec.ceiling, true, "ceiling"),
        ] {
            let Some(s) = slab else { continue };
            let ext = match s.extent {
                Some(e) => e,
                None if have_extent => [
                    (lo.x - s.margin as f32) as f64,
                    (lo.y - s.margin as f32) as f64,
                    (hi.x + s.margin as f32) as f64,
                    (hi.y + s.margin as f32) as f64,
                ],
                None => {
                    return Err(SpecError::new(
                        path,
                        format!("{key}.extent"),
                        "expected an extent [xmin, ymin, xmax, ymax]: the world has no other geometry to take it from",
                    ));
                }
            };
            if !(ext.iter().all(|v| v.is_finite()) && ext[2] > ext[0] && ext[3] > ext[1]) {
                return Err(SpecError::new(
                    path,
                    format!("{key}.extent"),
                    "expected [xmin, ymin, xmax, ymax] with max > min",
                ));
            }
            check_positive(path, &format!("{key}.thickness"), s.thickness, "m")?;
            let z0 = if is_ceiling {
                let h = s.height.ok_or_else(|| {
                    SpecError::new(
                        path,
                        format!("{key}.height"),
                        "expected the height of the ceiling's underside, m",
                    )
                })?;
                check_range(path, &format!("{key}.height"), h, 0.1, 100.0, "m")?;
                h
            } else {
                if s.height.is_some() {
                    return Err(SpecError::new(
                        path,
                        format!("{key}.height"),
                        "the floor's top is z = 0 by definition; remove `height`",
                    ));
                }
                -s.thickness
            };
            let mat = self.material(&s.material, &format!("{key}.material"))?;
            let half = Vec3::new(
                ((ext[2] - ext[0]) / 2.0) as f32,
                ((ext[3] - ext[1]) / 2.0) as f32,
                (s.thickness / 2.0) as f32,
            );
            let centre = Vec3::new(
                ((ext[0] + ext[2]) / 2.0) as f32,
                ((ext[1] + ext[3]) / 2.0) as f32,
                (z0 + s.thickness / 2.0) as f32,
            );
            let uv = self.uv(mat);
            self.world.objects.push(Object {
                name: key.to_string(),
                pose: Pose::from_translation(centre),
                shape: Some(SharedShape::cuboid(half.x, half.y, half.z)),
                parts: vec![MeshPart {
                    material: mat,
                    mesh: TriMesh::cuboid(half, uv),
                    faces_out: false,
                }],
                motion: Motion::Static,
                friction: 0.8,
                slab: true,
            });
        }
        Ok(())
    }
}

struct Compiler<'a> {
    path: &'a Path,
    dir: &'a Path,
    world: World,
    material_ids: HashMap<String, usize>,
    /// Loaded glTF files: parts (material indices already in this world) by canonical path.
    gltf_cache: HashMap<PathBuf, Vec<MeshPart>>,
    /// Texture tiling per material index.
    tiles: Vec<UvMap>,
}

impl Compiler<'_> {
    fn err(&self, key: impl Into<String>, msg: impl Into<String>) -> SpecError {
        SpecError::new(self.path, key, msg)
    }

    fn materials(&mut self, specs: &BTreeMap<String, MaterialSpec>) -> Result<(), SpecError> {
        for (name, m) in specs {
            let key = format!("materials.{name}");
            if m.color.iter().any(|c| !(0.0..=1.0).contains(c)) {
                return Err(self.err(
                    format!("{key}.color"),
                    format!("expected sRGB components in [0, 1], found {:?}", m.color),
                ));
            }
            let mut tile = UvMap::Tiled(Vec2::ONE);
            let texture = match &m.texture {
                None => None,
                Some(t) => {
                    let tk = format!("{key}.texture");
                    if t.size.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
                        return Err(self.err(
                            format!("{tk}.size"),
                            format!(
                                "expected a positive tile size [w, h] in m, found {:?}",
                                t.size
                            ),
                        ));
                    }
                    tile = if t.fit {
                        UvMap::Fit
                    } else {
                        UvMap::Tiled(Vec2::new(t.size[0] as f32, t.size[1] as f32))
                    };
                    let tex = match (&t.image, t.pattern) {
                        (Some(img), None) => {
                            let p = self.dir.join(img);
                            Texture::load_png(&p).map_err(|e| self.err(format!("{tk}.image"), e))?
                        }
                        (None, Some(pattern)) => {
                            if !(8..=4096).contains(&t.resolution) {
                                return Err(self.err(
                                    format!("{tk}.resolution"),
                                    format!("expected 8 to 4096 pixels, found {}", t.resolution),
                                ));
                            }
                            let c2 = t.color2.unwrap_or(m.color.map(|c| c * 0.6));
                            if c2.iter().any(|c| !(0.0..=1.0).contains(c)) {
                                return Err(self.err(
                                    format!("{tk}.color2"),
                                    "expected sRGB components in [0, 1]",
                                ));
                            }
                            texture::procedural(pattern, m.color, c2, t.seed, t.resolution)
                        }
                        _ => {
                            return Err(self.err(
                                tk,
                                "expected exactly one of `image` (a PNG file) or `pattern`",
                            ));
                        }
                    };
                    self.world.textures.push(tex);
                    Some(self.world.textures.len() - 1)
                }
            };
            self.material_ids
                .insert(name.clone(), self.world.materials.len());
            self.world.materials.push(Material {
                name: name.clone(),
                color: m.color,
                texture,
            });
            self.tiles.push(tile);
        }
        Ok(())
    }

    fn material(&self, name: &str, key: &str) -> Result<usize, SpecError> {
        self.material_ids.get(name).copied().ok_or_else(|| {
            self.err(
                key,
                format!(
                    "unknown material `{name}`; defined: {:?}",
                    self.world
                        .materials
                        .iter()
                        .map(|m| &m.name)
                        .collect::<Vec<_>>()
                ),
            )
        })
    }

    fn uv(&self, material: usize) -> UvMap {
        self.tiles[material]
    }

    fn body(&self, b: &BodySpec, key: &str) -> Result<(Motion, f64), SpecError> {
        let friction = b.friction.unwrap_or(0.6);
        check_range(
            self.path,
            &format!("{key}.friction"),
            friction,
            0.0,
            10.0,
            "",
        )?;
        let motion = if b.dynamic {
            let m = b.mass.ok_or_else(|| {
                self.err(format!("{key}.mass"), "a dynamic body needs its mass, kg")
            })?;
            check_range(self.path, &format!("{key}.mass"), m, 1e-3, 1e4, "kg")?;
            Motion::Dynamic { mass: m }
        } else {
            if b.mass.is_some() {
                return Err(self.err(
                    format!("{key}.mass"),
                    "mass applies to dynamic bodies only (set dynamic = true)",
                ));
            }
            Motion::Static
        };
        Ok((motion, friction))
    }

    fn wall(&mut self, w: &WallSpec, key: &str) -> Result<(), SpecError> {
        let mat = self.material(&w.material, &format!("{key}.material"))?;
        check_range(
            self.path,
            &format!("{key}.height"),
            w.height,
            0.01,
            100.0,
            "m",
        )?;
        check_range(
            self.path,
            &format!("{key}.thickness"),
            w.thickness,
            0.001,
            10.0,
            "m",
        )?;
        if w.points.len() < 2 || w.points.iter().flatten().any(|v| !v.is_finite()) {
            return Err(self.err(
                format!("{key}.points"),
                "expected at least two finite [x, y] points",
            ));
        }
        let mut pts: Vec<Vec2> = w
            .points
            .iter()
            .map(|p| Vec2::new(p[0] as f32, p[1] as f32))
            .collect();
        if w.closed {
            pts.push(pts[0]);
        }
        let nseg = pts.len() - 1;
        for i in 0..nseg {
            if (pts[i + 1] - pts[i]).length() < 1e-4 {
                return Err(self.err(
                    format!("{key}.points[{}]", i + 1),
                    "expected distinct consecutive points (segment of zero length)",
                ));
            }
        }
        // Cut the openings: per segment, intervals along it with (bottom, top) gaps.
        let mut cuts: Vec<Vec<(f32, f32, f32, f32)>> = vec![Vec::new(); nseg];
        for (k, o) in w.openings.iter().enumerate() {
            let ok = format!("{key}.openings[{k}]");
            check_range(self.path, &format!("{ok}.width"), o.width, 0.01, 100.0, "m")?;
            let top = o.top.unwrap_or(w.height);
            check_range(
                self.path,
                &format!("{ok}.top"),
                top,
                0.01,
                w.height,
                "m (at most the wall height)",
            )?;
            check_range(
                self.path,
                &format!("{ok}.sill"),
                o.sill,
                0.0,
                top - 0.01,
                "m (below the top)",
            )?;
            let at = Vec2::new(o.at[0] as f32, o.at[1] as f32);
            let (seg, s, d) = (0..nseg)
                .map(|i| {
                    let (a, b) = (pts[i], pts[i + 1]);
                    let len = (b - a).length();
                    let s = (at - a).dot((b - a) / len).clamp(0.0, len);
                    (i, s, (a + (b - a) / len * s - at).length())
                })
                .min_by(|x, y| x.2.total_cmp(&y.2))
                .expect("a wall has segments");
            if d > w.thickness as f32 {
                return Err(self.err(
                    format!("{ok}.at"),
                    format!(
                        "expected a point on the wall; the nearest wall point is {d:.3} m away"
                    ),
                ));
            }
            let half = o.width as f32 / 2.0;
            cuts[seg].push((s - half, s + half, o.sill as f32, top as f32));
        }
        let t = w.thickness as f32;
        let h = w.height as f32;
        let uv = self.uv(mat);
        for i in 0..nseg {
            let (a, b) = (pts[i], pts[i + 1]);
            let len = (b - a).length();
            let dir = (b - a) / len;
            let joint_start = i > 0 || w.closed;
            let joint_end = i + 1 < nseg || w.closed;
            let mut c = cuts[i].clone();
            c.sort_by(|x, y| x.0.total_cmp(&y.0));
            // Solid spans between openings, then lintels and sills over each opening.
            let mut pieces: Vec<(f32, f32, f32, f32)> = Vec::new();
            let mut s0 = if joint_start { -t / 2.0 } else { 0.0 };
            for &(o0, o1, sill, top) in &c {
                let (o0, o1) = (o0.max(0.0), o1.min(len));
                if o0 > s0 + 1e-4 {
                    pieces.push((s0, o0, 0.0, h));
                }
                if top < h - 1e-4 {
                    pieces.push((o0, o1, top, h));
                }
                if sill > 1e-4 {
                    pieces.push((o0, o1, 0.0, sill));
                }
                s0 = s0.max(o1);
            }
            let s_end = if joint_end { len + t / 2.0 } else { len };
            if s_end > s0 + 1e-4 {
                pieces.push((s0, s_end, 0.0, h));
            }
            for (k, (p0, p1, z0, z1)) in pieces.into_iter().enumerate() {
                let half = Vec3::new((p1 - p0) / 2.0, t / 2.0, (z1 - z0) / 2.0);
                let mid = a + dir * (p0 + p1) / 2.0;
                let pose = Pose::from_parts(
                    Vec3::new(mid.x, mid.y, (z0 + z1) / 2.0),
                    Quat::from_rotation_z(dir.y.atan2(dir.x)),
                );
                self.world.objects.push(Object {
                    name: format!("{key}.segment{i}.piece{k}"),
                    pose,
                    shape: Some(SharedShape::cuboid(half.x, half.y, half.z)),
                    parts: vec![MeshPart {
                        material: mat,
                        mesh: TriMesh::cuboid(half, uv),
                        faces_out: false,
                    }],
                    motion: Motion::Static,
                    friction: 0.6,
                    slab: false,
                });
            }
        }
        Ok(())
    }

    fn map_walls(&mut self, m: &MapWallsSpec, key: &str) -> Result<(), SpecError> {
        let mat = self.material(&m.material, &format!("{key}.material"))?;
        check_range(
            self.path,
            &format!("{key}.height"),
            m.height,
            0.01,
            100.0,
            "m",
        )?;
        let file = self.dir.join(&m.map);
        let grid = futago_msgs::map_server::read(&file)
            .map_err(|e| self.err(format!("{key}.map"), e.to_string()))?;
        let cells = floor_plan::WallCells::new(&grid, m.unknown);
        let uv = self.uv(mat);
        let h = m.height as f32;
        for (k, r) in cells.rectangles().iter().enumerate() {
            let (centre, half) = cells.extent(r);
            self.world.objects.push(Object {
                name: format!("{key}.rect{k}"),
                pose: Pose::from_translation(Vec3::new(
                    centre[0] as f32,
                    centre[1] as f32,
                    h / 2.0,
                )),
                shape: Some(SharedShape::cuboid(half[0] as f32, half[1] as f32, h / 2.0)),
                parts: vec![MeshPart {
                    material: mat,
                    mesh: cells.mesh(r, h, uv),
                    // The walls' union is solid: its faces all turn out, and a camera in
                    // the free cells sees none from behind.
                    faces_out: true,
                }],
                motion: Motion::Static,
                friction: 0.6,
                slab: false,
            });
        }
        Ok(())
    }

    fn cuboid(&mut self, b: &BoxSpec, frame: &Pose, key: &str) -> Result<(), SpecError> {
        let mat = self.material(&b.material, &format!("{key}.material"))?;
        for (k, s) in b.size.iter().enumerate() {
            check_range(
                self.path,
                &format!("{key}.size[{k}]"),
                *s,
                1e-4,
                1000.0,
                "m",
            )?;
        }
        if b.center
            .iter()
            .chain([&b.base, &b.yaw_deg])
            .any(|v| !v.is_finite())
        {
            return Err(self.err(key, "expected finite center, base and yaw_deg"));
        }
        let (motion, friction) = self.body(&b.body, key)?;
        let half = Vec3::new(b.size[0] as f32, b.size[1] as f32, b.size[2] as f32) / 2.0;
        let local = Pose::from_parts(
            Vec3::new(
                b.center[0] as f32,
                b.center[1] as f32,
                b.base as f32 + half.z,
            ),
            Quat::from_rotation_z(b.yaw_deg.to_radians() as f32),
        );
        self.world.objects.push(Object {
            name: b.name.clone().unwrap_or_else(|| key.to_string()),
            pose: *frame * local,
            shape: Some(SharedShape::cuboid(half.x, half.y, half.z)),
            parts: vec![MeshPart {
                material: mat,
                mesh: TriMesh::cuboid(half, self.uv(mat)),
                faces_out: false,
            }],
            motion,
            friction,
            slab: false,
        });
        Ok(())
    }

    fn cylinder(&mut self, cy: &CylinderSpec, frame: &Pose, key: &str) -> Result<(), SpecError> {
        let mat = self.material(&cy.material, &format!("{key}.material"))?;
        check_range(
            self.path,
            &format!("{key}.radius"),
            cy.radius,
            1e-4,
            1000.0,
            "m",
        )?;
        check_range(
            self.path,
            &format!("{key}.height"),
            cy.height,
            1e-4,
            1000.0,
            "m",
        )?;
        if !(3..=256).contains(&cy.segments) {
            return Err(self.err(
                format!("{key}.segments"),
                format!("expected 3 to 256 sides, found {}", cy.segments),
            ));
        }
        if cy.center.iter().chain([&cy.base]).any(|v| !v.is_finite()) {
            return Err(self.err(key, "expected finite center and base"));
        }
        let (motion, friction) = self.body(&cy.body, key)?;
        let (r, hh) = (cy.radius as f32, cy.height as f32 / 2.0);
        let shape = SharedShape::convex_hull(&TriMesh::prism_vertices(r, hh, cy.segments))
            .ok_or_else(|| self.err(key, "degenerate cylinder"))?;
        let local = Pose::from_translation(Vec3::new(
            cy.center[0] as f32,
            cy.center[1] as f32,
            cy.base as f32 + hh,
        ));
        self.world.objects.push(Object {
            name: cy.name.clone().unwrap_or_else(|| key.to_string()),
            pose: *frame * local,
            shape: Some(shape),
            parts: vec![MeshPart {
                material: mat,
                mesh: TriMesh::prism(r, hh, cy.segments, self.uv(mat)),
                faces_out: false,
            }],
            motion,
            friction,
            slab: false,
        });
        Ok(())
    }

    fn mesh(&mut self, m: &MeshSpec, frame: &Pose, key: &str) -> Result<(), SpecError> {
        check_range(self.path, &format!("{key}.scale"), m.scale, 1e-6, 1e6, "")?;
        if m.xyz.iter().chain(&m.rpy_deg).any(|v| !v.is_finite()) {
            return Err(self.err(key, "expected finite xyz and rpy_deg"));
        }
        let (motion, friction) = self.body(&m.body, key)?;
        if motion != Motion::Static && m.collider == MeshCollider::Trimesh {
            return Err(self.err(format!("{key}.collider"), "a dynamic mesh needs collider = \"convex_hull\" (triangle meshes are for static geometry)"));
        }
        let file = self.dir.join(&m.file);
        let canonical = file.canonicalize().map_err(|e| {
            self.err(
                format!("{key}.file"),
                format!("cannot open mesh file {}: {e}", file.display()),
            )
        })?;
        let parts = match self.gltf_cache.get(&canonical) {
            Some(p) => p.clone(),
            None => {
                let loaded =
                    gltf_io::load(&file).map_err(|e| self.err(format!("{key}.file"), e))?;
                let mut parts = Vec::new();
                let first_tex = self.world.textures.len();
                self.world.textures.extend(loaded.textures);
                for lm in loaded.materials {
                    self.world.materials.push(Material {
                        name: format!("{}#{}", m.file, lm.name),
                        color: lm.color,
                        texture: lm.texture.map(|t| t + first_tex),
                    });
                    self.tiles.push(UvMap::Fit);
                }
                let first_mat = self.world.materials.len() - loaded.material_count;
                for p in loaded.parts {
                    parts.push(MeshPart {
                        material: first_mat + p.material,
                        mesh: p.mesh,
                        faces_out: false,
                    });
                }
                self.gltf_cache.insert(canonical, parts.clone());
                parts
            }
        };
        let s = m.scale as f32;
        let parts: Vec<MeshPart> = parts
            .into_iter()
            .map(|p| MeshPart {
                material: p.material,
                mesh: p.mesh.transformed(Quat::IDENTITY, Vec3::ZERO, s),
                faces_out: false,
            })
            .collect();
        let shape = match m.collider {
            MeshCollider::None => None,
            MeshCollider::Trimesh => {
                let (v, i) = merged(&parts);
                Some(SharedShape::trimesh(v, i).map_err(|e| {
                    self.err(
                        format!("{key}.file"),
                        format!("cannot build a triangle-mesh collider: {e:?}"),
                    )
                })?)
            }
            MeshCollider::ConvexHull => {
                let (v, _) = merged(&parts);
                Some(SharedShape::convex_hull(&v).ok_or_else(|| {
                    self.err(
                        format!("{key}.collider"),
                        "the mesh's convex hull is degenerate (flat or empty)",
                    )
                })?)
            }
        };
        let [r, p, y] = m.rpy_deg.map(|a| a.to_radians() as f32);
        let local = Pose::from_parts(
            Vec3::new(m.xyz[0] as f32, m.xyz[1] as f32, m.xyz[2] as f32),
            Quat::from_euler(glam::EulerRot::ZYX, y, p, r),
        );
        self.world.objects.push(Object {
            name: m.name.clone().unwrap_or_else(|| key.to_string()),
            pose: *frame * local,
            shape,
            parts,
            motion,
            friction,
            slab: false,
        });
        Ok(())
    }
}

/// All parts' triangles as one vertex and index list.
fn merged(parts: &[MeshPart]) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let mut v = Vec::new();
    let mut idx = Vec::new();
    for p in parts {
        let base = v.len() as u32;
        v.extend_from_slice(&p.mesh.positions);
        idx.extend(p.mesh.indices.iter().map(|t| t.map(|i| i + base)));
    }
    (v, idx)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::parse_toml;

    fn world(text: &str) -> Result<World, SpecError> {
        let p = Path::new("test.toml");
        compile(&parse_toml(p, text)?, p)
    }

    const MATS: &str = "[materials.w]\ncolor = [0.8, 0.8, 0.8]\n";

    #[test]
    fn wall_with_doorway_leaves_a_gap_and_a_lintel() {
        let w = world(&format!("name = \"t\"\n{MATS}[[walls]]\nmaterial = \"w\"\npoints = [[0, 0], [4, 0]]\nheight = 2.5\nopenings = [{{ at = [2, 0], width = 1.0, top = 2.0 }}]\n")).unwrap();
        // Left span, lintel, right span.
        assert_eq!(w.objects.len(), 3);
        let spans: Vec<(f32, f32)> = w
            .objects
            .iter()
            .map(|o| {
                let c = o.shape.as_ref().unwrap().as_cuboid().unwrap().half_extents;
                (o.pose.translation.x - c.x, o.pose.translation.x + c.x)
            })
            .collect();
        assert!(
            spans
                .iter()
                .any(|&(a, b)| a.abs() < 1e-5 && (b - 1.5).abs() < 1e-5),
            "{spans:?}"
        );
        assert!(
            spans
                .iter()
                .any(|&(a, b)| (a - 2.5).abs() < 1e-5 && (b - 4.0).abs() < 1e-5)
        );
        let lintel = w
            .objects
            .iter()
            .find(|o| o.pose.translation.z > 2.0)
            .unwrap();
        assert!((lintel.pose.translation.z - 2.25).abs() < 1e-5);
    }

    #[test]
    fn closed_walls_overlap_at_corners() {
        let w = world(&format!("name = \"t\"\n{MATS}[[walls]]\nmaterial = \"w\"\npoints = [[0, 0], [4, 0], [4, 3], [0, 3]]\nclosed = true\nthickness = 0.2\n")).unwrap();
        assert_eq!(w.objects.len(), 4);
        let first = &w.objects[0];
        let half = first
            .shape
            .as_ref()
            .unwrap()
            .as_cuboid()
            .unwrap()
            .half_extents;
        assert!(
            (half.x - 2.1).abs() < 1e-5,
            "segments extend by half the thickness at joints"
        );
    }

    #[test]
    fn errors_name_the_key() {
        let e = world(&format!("name = \"t\"\n{MATS}[[boxes]]\nmaterial = \"nope\"\ncenter = [0, 0]\nsize = [1, 1, 1]\n")).unwrap_err();
        assert_eq!(e.key, "boxes[0].material");
        let e = world(&format!(
            "name = \"t\"\n{MATS}[[boxes]]\nmaterial = \"w\"\ncenter = [0, 0]\nsize = [1, -1, 1]\n"
        ))
        .unwrap_err();
        assert_eq!(e.key, "boxes[0].size[1]");
        let e = world(&format!("name = \"t\"\n{MATS}[[walls]]\nmaterial = \"w\"\npoints = [[0, 0], [4, 0]]\nopenings = [{{ at = [2, 3], width = 1.0 }}]\n")).unwrap_err();
        assert_eq!(e.key, "walls[0].openings[0].at");
        let e = world(&format!(
            "name = \"t\"\n{MATS}[[meshes]]\nfile = \"missing.glb\"\n"
        ))
        .unwrap_err();
        assert_eq!(e.key, "meshes[0].file");
        let e = world(&format!("name = \"t\"\n{MATS}[materials.x]\ncolor = [1, 1, 1]\ntexture = {{ image = \"nothere.png\" }}\n")).unwrap_err();
        assert_eq!(e.key, "materials.x.texture.image");
        let e = world(&format!("name = \"t\"\n{MATS}[[boxes]]\nmaterial = \"w\"\ncenter = [0, 0]\nsize = [1, 1, 1]\nmass = 3\n")).unwrap_err();
        assert_eq!(e.key, "boxes[0].mass");
    }

    #[test]
    fn prefab_instances_are_placed_and_rotated() {
        let w = world(&format!(
            "name = \"t\"\n{MATS}[prefabs.leg]\nboxes = [{{ material = \"w\", center = [1, 0], size = [0.1, 0.1, 0.5] }}]\n[[instances]]\nprefab = \"leg\"\nat = [[10, 0, 90], [0, 0, 0]]\n"
        ))
        .unwrap();
        assert_eq!(w.objects.len(), 2);
        let p = w.objects[0].pose.translation;
        assert!(
            (p.x - 10.0).abs() < 1e-5 && (p.y - 1.0).abs() < 1e-5 && (p.z - 0.25).abs() < 1e-5,
            "{p:?}"
        );
    }
}
