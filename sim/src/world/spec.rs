//! The TOML world format, as written by hand: every type here maps one table of a world file.
//!
//! Units: metres, kilograms; angles in files are degrees and say so in their key
//! (`yaw_deg`, `rpy_deg`). Colours are sRGB components in [0, 1]. Frames are ROS REP 103:
//! x forward/east, y left/north, z up, the floor's top surface at z = 0.

use serde::Deserialize;
use std::collections::BTreeMap;

/// A whole world file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorldSpec {
    /// Short name (used in file names and reports).
    pub name: String,
    #[serde(default)]
    pub description: String,
    /// Named start poses for robots.
    #[serde(default)]
    pub spawn: Vec<SpawnSpec>,
    /// Materials by name.
    #[serde(default)]
    pub materials: BTreeMap<String, MaterialSpec>,
    /// The floor slab; its top is z = 0.
    pub floor: Option<SlabSpec>,
    /// The ceiling slab; its underside is at `height`.
    pub ceiling: Option<SlabSpec>,
    #[serde(default)]
    pub walls: Vec<WallSpec>,
    /// Walls extruded from the occupied cells of map_server maps (floor plans).
    #[serde(default)]
    pub map_walls: Vec<MapWallsSpec>,
    #[serde(default)]
    pub boxes: Vec<BoxSpec>,
    #[serde(default)]
    pub cylinders: Vec<CylinderSpec>,
    #[serde(default)]
    pub meshes: Vec<MeshSpec>,
    /// Reusable groups of primitives (desks, chairs), placed by `instances`.
    #[serde(default)]
    pub prefabs: BTreeMap<String, PrefabSpec>,
    #[serde(default)]
    pub instances: Vec<InstanceSpec>,
}

/// A named start pose.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpawnSpec {
    pub name: String,
    pub x: f64,
    pub y: f64,
    #[serde(default)]
    pub yaw_deg: f64,
}

/// A surface material: a colour and an optional texture.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSpec {
    /// sRGB base colour, components in [0, 1].
    pub color: [f64; 3],
    pub texture: Option<TextureSpec>,
}

/// A texture: an image file (PNG) or one of the project's procedural patterns.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TextureSpec {
    /// Path of a PNG image, relative to the world file.
    pub image: Option<String>,
    /// A procedural pattern.
    pub pattern: Option<Pattern>,
    /// Second colour of a pattern (sRGB); defaults to a darker shade of the material colour.
    pub color2: Option<[f64; 3]>,
    /// Size of one texture tile on a surface, m (width, height).
    #[serde(default = "one_metre_tile")]
    pub size: [f64; 2],
    /// Stretch the texture once over each face instead of tiling it by `size`.
    #[serde(default)]
    pub fit: bool,
    /// Seed of the random patterns (`noise`, `poster`).
    #[serde(default)]
    pub seed: u64,
    /// Side of a procedural texture, pixels.
    #[serde(default = "default_texture_resolution")]
    pub resolution: u32,
}

fn one_metre_tile() -> [f64; 2] {
    [1.0, 1.0]
}

fn default_texture_resolution() -> u32 {
    256
}

/// The procedural texture patterns.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Pattern {
    Checker,
    Stripes,
    Bricks,
    Noise,
    Poster,
    Panel,
}

/// A floor or ceiling slab.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SlabSpec {
    pub material: String,
    /// `[xmin, ymin, xmax, ymax]`; defaults to the walls' extent plus `margin`.
    pub extent: Option<[f64; 4]>,
    #[serde(default = "default_margin")]
    pub margin: f64,
    /// Height of the ceiling's underside (ceilings only).
    pub height: Option<f64>,
    #[serde(default = "default_slab_thickness")]
    pub thickness: f64,
}

fn default_margin() -> f64 {
    0.5
}

fn default_slab_thickness() -> f64 {
    0.1
}

/// A wall: a polyline extruded upwards with a thickness, with optional openings.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WallSpec {
    pub material: String,
    /// Centre line of the wall, `[[x, y], …]`.
    pub points: Vec<[f64; 2]>,
    /// Join the last point back to the first.
    #[serde(default)]
    pub closed: bool,
    #[serde(default = "default_wall_height")]
    pub height: f64,
    #[serde(default = "default_wall_thickness")]
    pub thickness: f64,
    /// Doorways and windows cut out of the wall.
    #[serde(default)]
    pub openings: Vec<OpeningSpec>,
}

fn default_wall_height() -> f64 {
    2.5
}

fn default_wall_thickness() -> f64 {
    0.1
}

/// Walls from a floor plan: the occupied cells of a ROS map_server map (its YAML file; a PGM
/// or PNG image) extruded upwards (see [`super::floor_plan`]).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MapWallsSpec {
    /// Path of the map's YAML file, relative to the world file.
    pub map: String,
    pub material: String,
    #[serde(default = "default_wall_height")]
    pub height: f64,
    /// What the map's unknown cells become: `wall` where they touch free space (the default),
    /// or `free`.
    #[serde(default)]
    pub unknown: super::floor_plan::UnknownCells,
}

/// An opening in a wall: centred on the wall point nearest `at`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OpeningSpec {
    pub at: [f64; 2],
    pub width: f64,
    /// Top of the opening; defaults to the wall's full height (no lintel).
    pub top: Option<f64>,
    /// Bottom of the opening (0 for a doorway, higher for a window).
    #[serde(default)]
    pub sill: f64,
}

/// How a primitive body moves.
#[derive(Debug, Clone, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct BodySpec {
    /// A free rigid body (pushable) instead of static geometry.
    #[serde(default)]
    pub dynamic: bool,
    /// Mass of a dynamic body, kg.
    pub mass: Option<f64>,
    /// Coulomb friction coefficient.
    pub friction: Option<f64>,
}

/// A box standing on `base`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoxSpec {
    pub material: String,
    /// Centre of the footprint, `[x, y]`.
    pub center: [f64; 2],
    /// Height of the bottom face.
    #[serde(default)]
    pub base: f64,
    /// `[length x, width y, height z]` before rotation.
    pub size: [f64; 3],
    #[serde(default)]
    pub yaw_deg: f64,
    #[serde(default)]
    pub name: Option<String>,
    #[serde(flatten)]
    pub body: BodySpec,
}

/// An upright cylinder (a prism of `segments` sides, which collider and renderer share).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CylinderSpec {
    pub material: String,
    pub center: [f64; 2],
    #[serde(default)]
    pub base: f64,
    pub radius: f64,
    pub height: f64,
    #[serde(default = "default_segments")]
    pub segments: u32,
    #[serde(default)]
    pub name: Option<String>,
    #[serde(flatten)]
    pub body: BodySpec,
}

fn default_segments() -> u32 {
    24
}

/// How a loaded mesh collides.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum MeshCollider {
    /// The exact triangles (static meshes only).
    #[default]
    Trimesh,
    /// The convex hull of the vertices.
    ConvexHull,
    /// Visible only (no collisions, no laser returns).
    None,
}

/// A glTF 2.0 file (`.glb` or `.gltf`) placed in the world.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshSpec {
    /// Path relative to the world file.
    pub file: String,
    #[serde(default)]
    pub xyz: [f64; 3],
    #[serde(default)]
    pub rpy_deg: [f64; 3],
    #[serde(default = "unit_scale")]
    pub scale: f64,
    #[serde(default)]
    pub collider: MeshCollider,
    #[serde(default)]
    pub name: Option<String>,
    #[serde(flatten)]
    pub body: BodySpec,
}

fn unit_scale() -> f64 {
    1.0
}

/// A reusable group of primitives in its own frame.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PrefabSpec {
    #[serde(default)]
    pub boxes: Vec<BoxSpec>,
    #[serde(default)]
    pub cylinders: Vec<CylinderSpec>,
    #[serde(default)]
    pub meshes: Vec<MeshSpec>,
}

/// Copies of a prefab at planar poses `[x, y, yaw_deg]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InstanceSpec {
    pub prefab: String,
    pub at: Vec<[f64; 3]>,
}
