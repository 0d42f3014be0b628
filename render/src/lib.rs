//! Camera rendering with wgpu: registered RGB and metric depth of a [`Scene`], headless.
//!
//! A [`Renderer`] uploads a scene once (static geometry merged per material, movable bodies
//! kept apart with a transform each) and then draws it from any camera pose:
//! [`Renderer::render`] gives an RGB image and the depth registered to it,
//! [`Renderer::render_depth`] depth alone, and [`Renderer::render_depth_batch`] many small depth
//! images from many poses in one GPU submission (a particle filter's predicted views).
//!
//! Depth is the distance along the optical axis (z in the camera's optical frame), as an RGB-D
//! camera reports it, in metres; 0 where no surface was drawn. It is computed per fragment from
//! the interpolated camera-frame position, not read from the z-buffer, so it carries no
//! projection non-linearity: noise-free renders agree with a ray cast to well under a
//! millimetre.
//!
//! Poses follow REP 103: a camera pose is the pose of a body frame (x forward, y left, z up)
//! in the world; [`optical_from_body`] gives the optical frame (x right, y down, z forward)
//! used for pixels and for TUM trajectories.

pub mod gpu;
pub mod mesh;
pub mod scene;

pub use futago_msgs::camera::{DepthImage, Intrinsics, RgbImage};

use glam::{Mat3, Mat4, Quat, Vec3};
pub use glamx::Pose3 as Pose;
use gpu::{BackendChoice, Gpu};
pub use mesh::TriMesh;
pub use scene::{Material, MeshPart, Texture};
use std::collections::HashMap;
use std::time::Duration as StdDuration;
use thiserror::Error;

/// Why a render could not be made.
#[derive(Debug, Error)]
pub enum RenderError {
    /// No Vulkan or GL adapter could be opened; says what to install.
    #[error("no GPU adapter for rendering: {0}")]
    NoAdapter(String),
    #[error("GPU device error: {0}")]
    Device(String),
    #[error("GPU device lost: {0}")]
    DeviceLost(String),
    /// Bad input: image size, field of view, scene content.
    #[error("{0}")]
    Config(String),
}

/// Perspective projection from the optical frame to wgpu clip space (y up, depth 0..1).
fn projection(intr: &Intrinsics, near: f32, far: f32) -> Mat4 {
    let (w, h) = (intr.width as f32, intr.height as f32);
    let (fx, fy) = (intr.fx as f32, intr.fy as f32);
    // The rasteriser samples pixel i at window coordinate i + 0.5.
    let (cx, cy) = (intr.cx as f32 + 0.5, intr.cy as f32 + 0.5);
    let a = far / (far - near);
    Mat4::from_cols_array(&[
        2.0 * fx / w,
        0.0,
        2.0 * cx / w - 1.0,
        0.0,
        0.0,
        -2.0 * fy / h,
        1.0 - 2.0 * cy / h,
        0.0,
        0.0,
        0.0,
        a,
        -a * near,
        0.0,
        0.0,
        1.0,
        0.0,
    ])
    .transpose()
}

/// Rotation from a body frame (x forward, y left, z up) to its optical frame (x right, y down,
/// z forward): the optical axes expressed in the body frame.
pub fn optical_rotation() -> Quat {
    Quat::from_mat3(&Mat3::from_cols(
        Vec3::new(0.0, -1.0, 0.0),
        Vec3::new(0.0, 0.0, -1.0),
        Vec3::new(1.0, 0.0, 0.0),
    ))
}

/// The optical frame of a camera whose body frame has pose `body` in the world.
pub fn optical_from_body(body: &Pose) -> Pose {
    Pose::from_parts(body.translation, body.rotation * optical_rotation())
}

/// One body of a scene: render meshes in the body frame and a pose.
#[derive(Debug, Clone)]
pub struct SceneBody {
    pub name: String,
    /// Initial pose; a movable body's pose is set with [`Renderer::set_poses`].
    pub pose: Pose,
    /// Whether the body moves (then drawn with its own transform).
    pub movable: bool,
    pub parts: Vec<MeshPart>,
}

/// What a renderer draws: materials, textures and bodies. The simulator builds one from its
/// world's objects in order and adds the bodies the world does not list (the robot) after them.
#[derive(Debug, Clone, Default)]
pub struct Scene {
    pub materials: Vec<Material>,
    pub textures: Vec<Texture>,
    pub bodies: Vec<SceneBody>,
}

impl Scene {
    /// Adds a movable body with its own untextured materials; returns its index.
    pub fn add_body(&mut self, name: &str, pose: Pose, parts: Vec<(Material, TriMesh)>) -> usize {
        let parts = parts
            .into_iter()
            .map(|(mut m, mesh)| {
                m.texture = None;
                self.materials.push(m);
                MeshPart {
                    material: self.materials.len() - 1,
                    mesh,
                    faces_out: false,
                }
            })
            .collect();
        self.bodies.push(SceneBody {
            name: name.to_string(),
            pose,
            movable: true,
            parts,
        });
        self.bodies.len() - 1
    }

    /// Checks indices, finiteness and texture sizes; errors name the body or texture.
    pub fn validate(&self) -> Result<(), String> {
        for (i, t) in self.textures.iter().enumerate() {
            if t.width == 0 || t.height == 0 || t.rgba.len() != (t.width * t.height * 4) as usize {
                return Err(format!(
                    "texture {i} ({}) is {}×{} with {} bytes: expected a non-empty RGBA8 image",
                    t.name,
                    t.width,
                    t.height,
                    t.rgba.len()
                ));
            }
        }
        for m in &self.materials {
            if let Some(t) = m.texture
                && t >= self.textures.len()
            {
                return Err(format!(
                    "material `{}` refers to texture {t}, but the scene has {}",
                    m.name,
                    self.textures.len()
                ));
            }
        }
        for b in &self.bodies {
            for (k, p) in b.parts.iter().enumerate() {
                let m = &p.mesh;
                let what = || format!("body `{}` mesh part {k}", b.name);
                if p.material >= self.materials.len() {
                    return Err(format!(
                        "{}: material {} does not exist",
                        what(),
                        p.material
                    ));
                }
                if m.normals.len() != m.positions.len() || m.uvs.len() != m.positions.len() {
                    return Err(format!(
                        "{}: {} positions but {} normals and {} texture coordinates",
                        what(),
                        m.positions.len(),
                        m.normals.len(),
                        m.uvs.len()
                    ));
                }
                if !m.positions.iter().all(|v| v.is_finite()) {
                    return Err(format!("{}: a vertex position is not finite", what()));
                }
                let n = m.positions.len() as u32;
                if let Some(t) = m.indices.iter().find(|t| t.iter().any(|&i| i >= n)) {
                    return Err(format!(
                        "{}: triangle {t:?} indexes past its {n} vertices",
                        what()
                    ));
                }
            }
        }
        Ok(())
    }
}

/// The fixed light of the RGB image: direction towards it (world frame) and ambient share.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lighting {
    pub towards_light: Vec3,
    pub ambient: f32,
}

impl Default for Lighting {
    fn default() -> Self {
        Lighting {
            towards_light: Vec3::new(0.35, 0.25, 0.9).normalize(),
            ambient: 0.5,
        }
    }
}

impl Lighting {
    /// Shading factor (linear) of a surface with unit normal `n` (two-sided Lambert).
    pub fn shade(&self, n: Vec3) -> f32 {
        self.ambient + (1.0 - self.ambient) * n.dot(self.towards_light).abs()
    }

    /// The factor applied to sRGB-encoded colours: `shade^(1/2.2)`, which under the 2.2 power
    /// law equals encoding the linearly shaded albedo.
    pub fn encoded_shade(&self, n: Vec3) -> f32 {
        self.shade(n).powf(1.0 / 2.2)
    }
}

/// Nearest surface drawn; closer geometry is clipped.
pub const NEAR_PLANE: f32 = 0.02;
/// Farthest surface drawn, m: beyond any indoor depth camera's range.
pub const FAR_PLANE: f32 = 100.0;
/// How long a frame may take before the device is declared hung.
const FRAME_TIMEOUT: StdDuration = StdDuration::from_secs(60);

const COLOR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
const DEPTH_BITS_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Uint;
const ZBUFFER_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Vertex {
    position: [f32; 3],
    normal: [f32; 3],
    uv: [f32; 2],
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct CameraUniform {
    view_proj: [f32; 16],
    view: [f32; 16],
    light: [f32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct MaterialUniform {
    color: [f32; 4],
}

/// A run of indices drawn with one material and one transform slot.
#[derive(Debug, Clone)]
struct Draw {
    material: usize,
    /// Transform slot (0: identity, for static geometry baked into world coordinates).
    slot: u32,
    indices: std::ops::Range<u32>,
    /// Drawn from the front only: the triangles bound closed solids
    /// ([`TriMesh::is_closed_solid`]) or face out of solid matter ([`MeshPart::faces_out`]),
    /// so their faces turned away are always hidden.
    cull: bool,
}

/// Side of the square cells of the plane (m) by which static geometry is grouped for culling.
const CHUNK_SIZE: f32 = 1.0;

/// Static triangles whose centroids share a [`CHUNK_SIZE`] cell of the plane, with the box
/// that bounds them: a view draws only the chunks whose boxes meet its frustum. Vertex work
/// is most of a batched depth render on a software rasteriser (it runs on one thread), and
/// a narrow camera sees a small share of a building.
#[derive(Debug, Clone)]
struct Chunk {
    indices: std::ops::Range<u32>,
    min: Vec3,
    max: Vec3,
    /// As [`Draw::cull`].
    cull: bool,
}

/// The six planes `(n, d)` of a view-projection's frustum (wgpu clip space: |x|, |y| ≤ w,
/// 0 ≤ z ≤ w), each with the inside where `n·p + d ≥ 0`.
fn frustum_planes(view_proj: &Mat4) -> [glam::Vec4; 6] {
    let r = |i| view_proj.row(i);
    [
        r(3) + r(0),
        r(3) - r(0),
        r(3) + r(1),
        r(3) - r(1),
        r(2),
        r(3) - r(2),
    ]
}

/// Whether the box `min..max` lies wholly outside one of `planes` (then no part of it can be
/// drawn; a box that straddles planes is kept).
fn outside(planes: &[glam::Vec4; 6], min: Vec3, max: Vec3) -> bool {
    planes.iter().any(|p| {
        let far = Vec3::new(
            if p.x >= 0.0 { max.x } else { min.x },
            if p.y >= 0.0 { max.y } else { min.y },
            if p.z >= 0.0 { max.z } else { min.z },
        );
        p.truncate().dot(far) + p.w < 0.0
    })
}

/// Groups the triangles `tris` (indices into `vertices`, each with its [`Draw::cull`]) by
/// the cell of their centroids and whether they are culled, and appends them to `indices`,
/// cell by cell.
fn chunk_triangles(
    vertices: &[Vertex],
    indices: &mut Vec<u32>,
    tris: &[([u32; 3], bool)],
) -> Vec<Chunk> {
    let mut cells: std::collections::BTreeMap<(i64, i64, bool), Vec<[u32; 3]>> = Default::default();
    let at = |i: u32| Vec3::from_array(vertices[i as usize].position);
    for &(t, cull) in tris {
        let c = (at(t[0]) + at(t[1]) + at(t[2])) / 3.0;
        let key = (
            (c.y / CHUNK_SIZE).floor() as i64,
            (c.x / CHUNK_SIZE).floor() as i64,
            cull,
        );
        cells.entry(key).or_default().push(t);
    }
    cells
        .into_iter()
        .map(|((_, _, cull), tris)| {
            let start = indices.len() as u32;
            let (mut min, mut max) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
            for t in &tris {
                for &i in t {
                    min = min.min(at(i));
                    max = max.max(at(i));
                }
                indices.extend_from_slice(t);
            }
            Chunk {
                indices: start..indices.len() as u32,
                min,
                max,
                cull,
            }
        })
        .collect()
}

/// Appends `mesh` (moved by `pose` if given) to the geometry; returns its index range.
fn push_mesh(
    vertices: &mut Vec<Vertex>,
    indices: &mut Vec<u32>,
    mesh: &TriMesh,
    pose: Option<&Pose>,
) -> std::ops::Range<u32> {
    let base = vertices.len() as u32;
    for i in 0..mesh.positions.len() {
        let (p, n) = match pose {
            Some(t) => (*t * mesh.positions[i], t.rotation * mesh.normals[i]),
            None => (mesh.positions[i], mesh.normals[i]),
        };
        vertices.push(Vertex {
            position: p.to_array(),
            normal: n.to_array(),
            uv: mesh.uvs[i].to_array(),
        });
    }
    let start = indices.len() as u32;
    indices.extend(mesh.indices.iter().flatten().map(|&i| base + i));
    start..indices.len() as u32
}

/// Render targets and read-back buffers of one image size or atlas layout.
struct Targets {
    color: Option<(wgpu::Texture, wgpu::Buffer)>,
    depth: wgpu::Texture,
    depth_buffer: wgpu::Buffer,
    zbuffer: wgpu::Texture,
    width: u32,
    height: u32,
}

/// Bytes per row of a read-back buffer: 4-byte texels padded to wgpu's copy alignment.
fn padded_row(width: u32) -> u32 {
    let a = wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
    (width * 4).div_ceil(a) * a
}

/// Draws a [`Scene`] from camera poses. Owns its GPU device.
pub struct Renderer {
    gpu: Gpu,
    lighting: Lighting,
    /// Pipelines drawing both sides of each triangle (`[0]`) and the front alone (`[1]`).
    pipelines: [Pipelines; 2],
    frame_layout: wgpu::BindGroupLayout,
    frame_group: wgpu::BindGroup,
    camera_buffer: wgpu::Buffer,
    camera_capacity: u32,
    model_buffer: wgpu::Buffer,
    uniform_stride: u32,
    material_groups: Vec<wgpu::BindGroup>,
    vertices: wgpu::Buffer,
    indices: wgpu::Buffer,
    /// Colour draws: static runs per material, then movable parts.
    draws: Vec<Draw>,
    /// Depth-only geometry: static triangles by cell, culled per view, then one run per
    /// movable body.
    chunks: Vec<Chunk>,
    depth_draws: Vec<Draw>,
    /// Frustum planes of the cameras last written.
    frusta: Vec<[glam::Vec4; 6]>,
    /// Transform slot of each body (0 for static bodies).
    body_slots: Vec<u32>,
    targets: HashMap<(bool, u32, u32), Targets>,
}

/// The bind group layouts: per frame (the camera's and the body's uniforms, `cam_size` bytes
/// and a 4 × 4 matrix, at dynamic offsets) and per material (its colour, texture, sampler).
fn layouts(device: &wgpu::Device, cam_size: u64) -> (wgpu::BindGroupLayout, wgpu::BindGroupLayout) {
    let uniform_entry =
        |binding: u32, size: u64, vis: wgpu::ShaderStages| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: vis,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Uniform,
                has_dynamic_offset: true,
                min_binding_size: wgpu::BufferSize::new(size),
            },
            count: None,
        };
    let frame_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("frame"),
        entries: &[
            uniform_entry(0, cam_size, wgpu::ShaderStages::VERTEX),
            uniform_entry(1, 64, wgpu::ShaderStages::VERTEX),
        ],
    });
    let material_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("material"),
        entries: &[
            wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            },
            wgpu::BindGroupLayoutEntry {
                binding: 1,
                visibility: wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Texture {
                    sample_type: wgpu::TextureSampleType::Float { filterable: true },
                    view_dimension: wgpu::TextureViewDimension::D2,
                    multisampled: false,
                },
                count: None,
            },
            wgpu::BindGroupLayoutEntry {
                binding: 2,
                visibility: wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                count: None,
            },
        ],
    });
    (frame_layout, material_layout)
}

/// A scene's geometry in one vertex and index buffer: static bodies baked into world
/// coordinates and grouped by material (with their chunks for culling), then each movable
/// body in its own frame, in its own model slot.
struct Geometry {
    vertices: Vec<Vertex>,
    indices: Vec<u32>,
    draws: Vec<Draw>,
    chunks: Vec<Chunk>,
    depth_draws: Vec<Draw>,
    body_slots: Vec<u32>,
    /// Model slots used by movable bodies (slot 0 is the identity of static geometry).
    slots: u32,
}

/// The render pipelines: colour and depth after a z pre-pass, the z pre-pass itself, and
/// depth alone.
fn pipelines(
    device: &wgpu::Device,
    frame_layout: &wgpu::BindGroupLayout,
    material_layout: &wgpu::BindGroupLayout,
    cull: bool,
) -> Pipelines {
    let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("futago camera"),
        source: wgpu::ShaderSource::Wgsl(include_str!("shader.wgsl").into()),
    });
    let vertex_layout = wgpu::VertexBufferLayout {
        array_stride: std::mem::size_of::<Vertex>() as u64,
        step_mode: wgpu::VertexStepMode::Vertex,
        attributes: &wgpu::vertex_attr_array![0 => Float32x3, 1 => Float32x3, 2 => Float32x2],
    };
    let depth_stencil = wgpu::DepthStencilState {
        format: ZBUFFER_FORMAT,
        depth_write_enabled: Some(true),
        depth_compare: Some(wgpu::CompareFunction::Less),
        stencil: Default::default(),
        bias: Default::default(),
    };
    let primitive = wgpu::PrimitiveState {
        topology: wgpu::PrimitiveTopology::TriangleList,
        // wgpu's default front face (counter-clockwise) is a closed solid's outside: the
        // projection keeps the world's handedness on screen.
        cull_mode: cull.then_some(wgpu::Face::Back),
        ..Default::default()
    };
    let pipeline = |label: &str,
                    layouts: &[Option<&wgpu::BindGroupLayout>],
                    fs: &str,
                    targets: &[Option<wgpu::ColorTargetState>],
                    depth_stencil: wgpu::DepthStencilState| {
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some(label),
            bind_group_layouts: layouts,
            immediate_size: 0,
        });
        device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some(label),
            layout: Some(&layout),
            vertex: wgpu::VertexState {
                module: &shader,
                entry_point: Some("vs_main"),
                compilation_options: Default::default(),
                buffers: &[Some(vertex_layout.clone())],
            },
            primitive,
            depth_stencil: Some(depth_stencil),
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &shader,
                entry_point: Some(fs),
                compilation_options: Default::default(),
                targets,
            }),
            multiview_mask: None,
            cache: None,
        })
    };
    let color_pipeline = pipeline(
        "colour+depth",
        &[Some(frame_layout), Some(material_layout)],
        "fs_color",
        &[Some(COLOR_FORMAT.into()), Some(DEPTH_BITS_FORMAT.into())],
        // After the z pre-pass: shade only the visible surface of each pixel.
        wgpu::DepthStencilState {
            depth_write_enabled: Some(false),
            depth_compare: Some(wgpu::CompareFunction::LessEqual),
            ..depth_stencil.clone()
        },
    );
    let masked = |format: wgpu::TextureFormat| {
        Some(wgpu::ColorTargetState {
            format,
            blend: None,
            write_mask: wgpu::ColorWrites::empty(),
        })
    };
    let z_pipeline = pipeline(
        "z pre-pass",
        &[Some(frame_layout)],
        "fs_none",
        &[masked(COLOR_FORMAT), masked(DEPTH_BITS_FORMAT)],
        depth_stencil.clone(),
    );
    let depth_pipeline = pipeline(
        "depth",
        &[Some(frame_layout)],
        "fs_depth",
        &[Some(DEPTH_BITS_FORMAT.into())],
        depth_stencil.clone(),
    );
    Pipelines {
        color: color_pipeline,
        z: z_pipeline,
        depth: depth_pipeline,
    }
}

/// Which of a [`Pipelines`] a phase of a pass draws with.
type PickPipeline = fn(&Pipelines) -> &wgpu::RenderPipeline;

/// The render pipelines of one way of drawing faces (both sides, or the front only).
struct Pipelines {
    color: wgpu::RenderPipeline,
    /// Depth-only pass before the colour pass, so that fragments are shaded once.
    z: wgpu::RenderPipeline,
    depth: wgpu::RenderPipeline,
}

/// Appends a draw of `indices`, or extends the last draw where it is alike and ends where
/// they start.
fn push_draw(
    draws: &mut Vec<Draw>,
    material: usize,
    slot: u32,
    indices: std::ops::Range<u32>,
    cull: bool,
) {
    if indices.is_empty() {
        return;
    }
    match draws.last_mut() {
        Some(d)
            if d.material == material
                && d.slot == slot
                && d.cull == cull
                && d.indices.end == indices.start =>
        {
            d.indices.end = indices.end
        }
        _ => draws.push(Draw {
            material,
            slot,
            indices,
            cull,
        }),
    }
}

/// Whether `part` is drawn from the front alone: its triangles face out of solid matter
/// ([`MeshPart::faces_out`], or a closed solid).
fn front_only(part: &MeshPart) -> bool {
    part.faces_out || part.mesh.is_closed_solid()
}

/// The [`Geometry`] of `scene`.
fn geometry(scene: &Scene) -> Geometry {
    let mut vertices: Vec<Vertex> = Vec::new();
    let mut indices: Vec<u32> = Vec::new();
    let mut draws = Vec::new();
    let mut static_parts: Vec<(usize, bool, &MeshPart, &Pose)> = Vec::new();
    for b in scene.bodies.iter().filter(|b| !b.movable) {
        for p in &b.parts {
            static_parts.push((p.material, front_only(p), p, &b.pose));
        }
    }
    static_parts.sort_by_key(|s| (s.0, s.1));
    let mut static_tris = Vec::new();
    for (material, cull, part, pose) in static_parts {
        let range = push_mesh(&mut vertices, &mut indices, &part.mesh, Some(pose));
        static_tris.extend(
            indices[range.start as usize..range.end as usize]
                .chunks_exact(3)
                .map(|t| ([t[0], t[1], t[2]], cull)),
        );
        push_draw(&mut draws, material, 0, range, cull);
    }
    let chunks = chunk_triangles(&vertices, &mut indices, &static_tris);
    let mut depth_draws = vec![];
    let mut body_slots = vec![0u32; scene.bodies.len()];
    let mut slot = 0;
    for (bi, b) in scene.bodies.iter().enumerate() {
        if !b.movable {
            continue;
        }
        slot += 1;
        body_slots[bi] = slot;
        for p in &b.parts {
            let range = push_mesh(&mut vertices, &mut indices, &p.mesh, None);
            let cull = front_only(p);
            draws.push(Draw {
                material: p.material,
                slot,
                indices: range.clone(),
                cull,
            });
            push_draw(&mut depth_draws, 0, slot, range, cull);
        }
    }
    Geometry {
        vertices,
        indices,
        draws,
        chunks,
        depth_draws,
        body_slots,
        slots: slot,
    }
}

/// A bind group per material of `scene`: its colour, its texture (sRGB, so sampling returns
/// linear values; a white texel for plain materials) and the sampler.
fn material_groups(
    gpu: &Gpu,
    scene: &Scene,
    material_layout: &wgpu::BindGroupLayout,
) -> Result<Vec<wgpu::BindGroup>, RenderError> {
    use wgpu::util::DeviceExt;
    let device = &gpu.device;
    let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
        label: Some("base colour"),
        address_mode_u: wgpu::AddressMode::Repeat,
        address_mode_v: wgpu::AddressMode::Repeat,
        mag_filter: wgpu::FilterMode::Linear,
        min_filter: wgpu::FilterMode::Linear,
        ..Default::default()
    });
    let max_tex = gpu.limits.max_texture_dimension_2d;
    let upload = |t: &Texture| -> Result<wgpu::TextureView, RenderError> {
        if t.width > max_tex || t.height > max_tex {
            return Err(RenderError::Config(format!(
                "texture {} is {}×{}, larger than this GPU's {max_tex}-texel limit",
                t.name, t.width, t.height
            )));
        }
        let tex = device.create_texture_with_data(
            &gpu.queue,
            &wgpu::TextureDescriptor {
                label: Some(&t.name),
                size: wgpu::Extent3d {
                    width: t.width,
                    height: t.height,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: wgpu::TextureFormat::Rgba8Unorm,
                usage: wgpu::TextureUsages::TEXTURE_BINDING,
                view_formats: &[],
            },
            wgpu::util::TextureDataOrder::LayerMajor,
            &t.rgba,
        );
        Ok(tex.create_view(&Default::default()))
    };
    let white = upload(&Texture::from_rgba(
        "white".into(),
        1,
        1,
        vec![255, 255, 255, 255],
    ))?;
    let views = scene
        .textures
        .iter()
        .map(upload)
        .collect::<Result<Vec<_>, _>>()?;
    let groups = scene
        .materials
        .iter()
        .map(|m| {
            let c = m.color.map(|c| c as f32);
            let u = MaterialUniform {
                color: [c[0], c[1], c[2], 1.0],
            };
            let buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(&m.name),
                contents: bytemuck::bytes_of(&u),
                usage: wgpu::BufferUsages::UNIFORM,
            });
            let view = m.texture.map(|t| &views[t]).unwrap_or(&white);
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some(&m.name),
                layout: material_layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: buffer.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: wgpu::BindingResource::TextureView(view),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: wgpu::BindingResource::Sampler(&sampler),
                    },
                ],
            })
        })
        .collect();
    Ok(groups)
}

impl Renderer {
    /// Opens a device (backend from [`gpu::BACKEND_ENV`]) and uploads `scene`.
    pub fn new(scene: &Scene) -> Result<Renderer, RenderError> {
        Renderer::with_backend(scene, BackendChoice::from_env()?)
    }

    /// Opens a device with the given backend choice and uploads `scene`.
    pub fn with_backend(scene: &Scene, choice: BackendChoice) -> Result<Renderer, RenderError> {
        scene.validate().map_err(RenderError::Config)?;
        let gpu = Gpu::open(choice)?;
        let r = Renderer::build(gpu, scene)?;
        r.gpu.check()?;
        Ok(r)
    }

    /// The adapter in use, in words.
    pub fn adapter(&self) -> String {
        self.gpu.describe()
    }

    /// The wgpu backend in use.
    pub fn backend(&self) -> wgpu::Backend {
        self.gpu.info.backend
    }

    /// The lighting of RGB images.
    pub fn lighting(&self) -> Lighting {
        self.lighting
    }

    fn build(gpu: Gpu, scene: &Scene) -> Result<Renderer, RenderError> {
        let device = &gpu.device;
        let lighting = Lighting::default();
        let uniform_stride = gpu.limits.min_uniform_buffer_offset_alignment.max(256);
        let cam_size = std::mem::size_of::<CameraUniform>() as u64;
        let (frame_layout, material_layout) = layouts(device, cam_size);
        let pipelines =
            [false, true].map(|cull| pipelines(device, &frame_layout, &material_layout, cull));

        let Geometry {
            mut vertices,
            mut indices,
            draws,
            chunks,
            depth_draws,
            body_slots,
            slots: slot,
        } = geometry(scene);
        let max_buffer = gpu.limits.max_buffer_size;
        let vbytes = (vertices.len() * std::mem::size_of::<Vertex>()) as u64;
        if vbytes > max_buffer {
            return Err(RenderError::Config(format!(
                "scene has {} vertices ({vbytes} bytes), more than this GPU's buffer limit of {max_buffer} bytes",
                vertices.len()
            )));
        }
        // wgpu rejects empty buffers: keep one dummy vertex and triangle.
        if vertices.is_empty() {
            vertices.push(Vertex {
                position: [0.0; 3],
                normal: [0.0, 0.0, 1.0],
                uv: [0.0; 2],
            });
        }
        if indices.is_empty() {
            indices.extend([0, 0, 0]);
        }
        use wgpu::util::DeviceExt;
        let vertex_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("vertices"),
            contents: bytemuck::cast_slice(&vertices),
            usage: wgpu::BufferUsages::VERTEX,
        });
        let index_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("indices"),
            contents: bytemuck::cast_slice(&indices),
            usage: wgpu::BufferUsages::INDEX,
        });

        let material_groups = material_groups(&gpu, scene, &material_layout)?;

        let model_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("models"),
            size: uniform_stride as u64 * (slot as u64 + 1),
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let camera_capacity = 1;
        let camera_buffer = Self::camera_buffer(device, uniform_stride, camera_capacity);
        let frame_group = Self::frame_group(
            device,
            &frame_layout,
            &camera_buffer,
            &model_buffer,
            cam_size,
        );
        let mut r = Renderer {
            gpu,
            lighting,
            pipelines,
            frame_layout,
            frame_group,
            camera_buffer,
            camera_capacity,
            model_buffer,
            uniform_stride,
            material_groups,
            vertices: vertex_buffer,
            indices: index_buffer,
            draws,
            chunks,
            depth_draws,
            frusta: Vec::new(),
            body_slots,
            targets: HashMap::new(),
        };
        let poses: Vec<Pose> = scene.bodies.iter().map(|b| b.pose).collect();
        r.write_models(&poses);
        Ok(r)
    }

    fn camera_buffer(device: &wgpu::Device, stride: u32, capacity: u32) -> wgpu::Buffer {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("cameras"),
            size: stride as u64 * capacity as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    fn frame_group(
        device: &wgpu::Device,
        layout: &wgpu::BindGroupLayout,
        cameras: &wgpu::Buffer,
        models: &wgpu::Buffer,
        cam_size: u64,
    ) -> wgpu::BindGroup {
        device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("frame"),
            layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                        buffer: cameras,
                        offset: 0,
                        size: wgpu::BufferSize::new(cam_size),
                    }),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                        buffer: models,
                        offset: 0,
                        size: wgpu::BufferSize::new(64),
                    }),
                },
            ],
        })
    }

    fn write_models(&mut self, poses: &[Pose]) {
        let stride = self.uniform_stride as usize;
        let slots = self.body_slots.iter().copied().max().unwrap_or(0) as usize + 1;
        let mut data = vec![0u8; stride * slots];
        data[..64].copy_from_slice(bytemuck::bytes_of(&Mat4::IDENTITY.to_cols_array()));
        for (b, &slot) in self.body_slots.iter().enumerate() {
            if slot > 0 {
                let m = poses[b].to_mat4().to_cols_array();
                let o = slot as usize * stride;
                data[o..o + 64].copy_from_slice(bytemuck::bytes_of(&m));
            }
        }
        self.gpu.queue.write_buffer(&self.model_buffer, 0, &data);
    }

    /// Sets the pose of every body, in [`Scene::bodies`] order (static bodies' poses are
    /// ignored: they are baked into the geometry).
    pub fn set_poses(&mut self, poses: &[Pose]) -> Result<(), RenderError> {
        if poses.len() != self.body_slots.len() {
            return Err(RenderError::Config(format!(
                "{} poses given for a scene of {} bodies",
                poses.len(),
                self.body_slots.len()
            )));
        }
        self.write_models(poses);
        Ok(())
    }

    /// Uploads one camera uniform per pose, growing the buffer as needed.
    fn write_cameras(&mut self, intr: &Intrinsics, cameras: &[Pose], far: f32) {
        let n = cameras.len() as u32;
        if n > self.camera_capacity {
            self.camera_capacity = n.next_power_of_two();
            self.camera_buffer =
                Self::camera_buffer(&self.gpu.device, self.uniform_stride, self.camera_capacity);
            self.frame_group = Self::frame_group(
                &self.gpu.device,
                &self.frame_layout,
                &self.camera_buffer,
                &self.model_buffer,
                std::mem::size_of::<CameraUniform>() as u64,
            );
        }
        let proj = projection(intr, NEAR_PLANE, far);
        let stride = self.uniform_stride as usize;
        let mut data = vec![0u8; stride * cameras.len()];
        self.frusta.clear();
        for (i, c) in cameras.iter().enumerate() {
            let view = optical_from_body(c).inverse().to_mat4();
            let l = self.lighting;
            let view_proj = proj * view;
            self.frusta.push(frustum_planes(&view_proj));
            let u = CameraUniform {
                view_proj: view_proj.to_cols_array(),
                view: view.to_cols_array(),
                light: [
                    l.towards_light.x,
                    l.towards_light.y,
                    l.towards_light.z,
                    l.ambient,
                ],
            };
            data[i * stride..i * stride + std::mem::size_of::<CameraUniform>()]
                .copy_from_slice(bytemuck::bytes_of(&u));
        }
        self.gpu.queue.write_buffer(&self.camera_buffer, 0, &data);
    }

    fn targets(&mut self, color: bool, width: u32, height: u32) -> &Targets {
        let device = &self.gpu.device;
        self.targets
            .entry((color, width, height))
            .or_insert_with(|| {
                let size = wgpu::Extent3d {
                    width,
                    height,
                    depth_or_array_layers: 1,
                };
                let texture = |label: &str, format: wgpu::TextureFormat, copy: bool| {
                    let mut usage = wgpu::TextureUsages::RENDER_ATTACHMENT;
                    if copy {
                        usage |= wgpu::TextureUsages::COPY_SRC;
                    }
                    device.create_texture(&wgpu::TextureDescriptor {
                        label: Some(label),
                        size,
                        mip_level_count: 1,
                        sample_count: 1,
                        dimension: wgpu::TextureDimension::D2,
                        format,
                        usage,
                        view_formats: &[],
                    })
                };
                let buffer = |label: &str| {
                    device.create_buffer(&wgpu::BufferDescriptor {
                        label: Some(label),
                        size: padded_row(width) as u64 * height as u64,
                        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                        mapped_at_creation: false,
                    })
                };
                Targets {
                    color: color.then(|| {
                        (
                            texture("colour", COLOR_FORMAT, true),
                            buffer("colour read-back"),
                        )
                    }),
                    depth: texture("depth bits", DEPTH_BITS_FORMAT, true),
                    depth_buffer: buffer("depth read-back"),
                    zbuffer: texture("z-buffer", ZBUFFER_FORMAT, false),
                    width,
                    height,
                }
            })
    }

    /// Records one render pass drawing `views` (tile origin and camera slot) into `t`.
    fn encode_pass(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        t: &Targets,
        tile: (u32, u32),
        views: &[((u32, u32), u32)],
    ) {
        let depth_view = t.depth.create_view(&Default::default());
        let color_view = t
            .color
            .as_ref()
            .map(|c| c.0.create_view(&Default::default()));
        let z_view = t.zbuffer.create_view(&Default::default());
        let attachment = |view| {
            Some(wgpu::RenderPassColorAttachment {
                view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                    store: wgpu::StoreOp::Store,
                },
            })
        };
        let attachments = match &color_view {
            Some(cv) => vec![attachment(cv), attachment(&depth_view)],
            None => vec![attachment(&depth_view)],
        };
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("camera"),
            color_attachments: &attachments,
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &z_view,
                depth_ops: Some(wgpu::Operations {
                    load: wgpu::LoadOp::Clear(1.0),
                    store: wgpu::StoreOp::Discard,
                }),
                stencil_ops: None,
            }),
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        let color = t.color.is_some();
        pass.set_vertex_buffer(0, self.vertices.slice(..));
        pass.set_index_buffer(self.indices.slice(..), wgpu::IndexFormat::Uint32);
        let stride = self.uniform_stride;
        let mut depth_draws: Vec<Draw> = Vec::new();
        for &((x, y), cam) in views {
            pass.set_viewport(x as f32, y as f32, tile.0 as f32, tile.1 as f32, 0.0, 1.0);
            pass.set_scissor_rect(x, y, tile.0, tile.1);
            // The static chunks this view can see, neighbouring runs merged, then the movable
            // bodies.
            depth_draws.clear();
            let planes = &self.frusta[cam as usize];
            for c in self
                .chunks
                .iter()
                .filter(|c| !outside(planes, c.min, c.max))
            {
                push_draw(&mut depth_draws, 0, 0, c.indices.clone(), c.cull);
            }
            depth_draws.extend(self.depth_draws.iter().cloned());
            let phases: &[(PickPipeline, &[Draw])] = if color {
                &[(|p| &p.z, &depth_draws), (|p| &p.color, &self.draws)]
            } else {
                &[(|p| &p.depth, &depth_draws)]
            };
            for (k, &(pipeline, draws)) in phases.iter().enumerate() {
                let shaded = color && k == 1;
                let mut bound = (u32::MAX, usize::MAX);
                let mut culling = None;
                for d in draws {
                    if culling != Some(d.cull) {
                        pass.set_pipeline(pipeline(&self.pipelines[d.cull as usize]));
                        culling = Some(d.cull);
                    }
                    if bound.0 != d.slot {
                        pass.set_bind_group(0, &self.frame_group, &[cam * stride, d.slot * stride]);
                        bound.0 = d.slot;
                    }
                    if shaded && bound.1 != d.material {
                        pass.set_bind_group(1, &self.material_groups[d.material], &[]);
                        bound.1 = d.material;
                    }
                    pass.draw_indexed(d.indices.clone(), 0, 0..1);
                }
            }
        }
    }

    fn copy_out(encoder: &mut wgpu::CommandEncoder, t: &Targets) {
        let copy = |tex: &wgpu::Texture, buf: &wgpu::Buffer, encoder: &mut wgpu::CommandEncoder| {
            encoder.copy_texture_to_buffer(
                wgpu::TexelCopyTextureInfo {
                    texture: tex,
                    mip_level: 0,
                    origin: wgpu::Origin3d::ZERO,
                    aspect: wgpu::TextureAspect::All,
                },
                wgpu::TexelCopyBufferInfo {
                    buffer: buf,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(padded_row(t.width)),
                        rows_per_image: Some(t.height),
                    },
                },
                wgpu::Extent3d {
                    width: t.width,
                    height: t.height,
                    depth_or_array_layers: 1,
                },
            )
        };
        if let Some((tex, buf)) = &t.color {
            copy(tex, buf, encoder);
        }
        copy(&t.depth, &t.depth_buffer, encoder);
    }

    /// Renders, submits and maps the targets of `key`; calls `read` with the mapped bytes of
    /// (colour, depth) and unmaps.
    fn run<R>(
        &mut self,
        key: (bool, u32, u32),
        tile: (u32, u32),
        views: &[((u32, u32), u32)],
        read: impl FnOnce(Option<&[u8]>, &[u8], u32) -> R,
    ) -> Result<R, RenderError> {
        self.gpu.check()?;
        self.targets(key.0, key.1, key.2);
        let t = &self.targets[&key];
        let mut encoder = self
            .gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("camera"),
            });
        self.encode_pass(&mut encoder, t, tile, views);
        Self::copy_out(&mut encoder, t);
        let index = self.gpu.queue.submit([encoder.finish()]);
        let mut buffers = vec![&t.depth_buffer];
        if let Some((_, b)) = &t.color {
            buffers.push(b);
        }
        self.gpu.map_read(&buffers, index, FRAME_TIMEOUT)?;
        let mapped = |b: &wgpu::Buffer| {
            b.get_mapped_range(..)
                .map_err(|e| RenderError::Device(format!("read-back: {e}")))
        };
        let out = {
            let depth = mapped(&t.depth_buffer)?;
            let color = match &t.color {
                Some((_, b)) => Some(mapped(b)?),
                None => None,
            };
            read(color.as_deref(), &depth, padded_row(t.width))
        };
        t.depth_buffer.unmap();
        if let Some((_, b)) = &t.color {
            b.unmap();
        }
        Ok(out)
    }

    /// Renders RGB and registered depth from a camera whose body frame has pose `camera`.
    pub fn render(
        &mut self,
        intr: &Intrinsics,
        camera: &Pose,
    ) -> Result<(RgbImage, DepthImage), RenderError> {
        intr.validate().map_err(RenderError::Config)?;
        self.write_cameras(intr, std::slice::from_ref(camera), FAR_PLANE);
        let (w, h) = (intr.width, intr.height);
        self.run((true, w, h), (w, h), &[((0, 0), 0)], |color, depth, row| {
            let color = color.expect("colour target requested");
            let mut rgb = Vec::with_capacity((w * h * 3) as usize);
            let mut z = Vec::with_capacity((w * h) as usize);
            for v in 0..h as usize {
                let r = &color[v * row as usize..][..w as usize * 4];
                for px in r.chunks_exact(4) {
                    rgb.extend_from_slice(&px[..3]);
                }
                extend_f32_le(&mut z, &depth[v * row as usize..][..w as usize * 4]);
            }
            (
                RgbImage {
                    width: w,
                    height: h,
                    data: rgb,
                },
                DepthImage {
                    width: w,
                    height: h,
                    data: z,
                },
            )
        })
    }

    /// Renders depth alone from a camera whose body frame has pose `camera`.
    pub fn render_depth(
        &mut self,
        intr: &Intrinsics,
        camera: &Pose,
    ) -> Result<DepthImage, RenderError> {
        let mut data = Vec::new();
        self.render_depth_batch(intr, std::slice::from_ref(camera), FAR_PLANE, &mut data)?;
        Ok(DepthImage {
            width: intr.width,
            height: intr.height,
            data,
        })
    }

    /// Renders one depth image per camera pose into `out` (replaced): `cameras.len()` images of
    /// `width × height` in order, contiguous; as [`Renderer::render_depth_each`]. On an error
    /// `out` is left empty.
    pub fn render_depth_batch(
        &mut self,
        intr: &Intrinsics,
        cameras: &[Pose],
        far: f32,
        out: &mut Vec<f32>,
    ) -> Result<(), RenderError> {
        out.clear();
        let drawn = self.render_depth_each(intr, cameras, far, |k, image| {
            // Sized once the image is known to be valid, not from the unchecked intrinsics.
            if k == 0 {
                out.reserve(cameras.len() * image.len());
            }
            out.extend_from_slice(image)
        });
        if drawn.is_err() {
            out.clear();
        }
        drawn
    }

    /// Renders one depth image per camera pose and hands each to `each` with its pose's
    /// index, in order, as it is read back (`width × height` values, row by row, in a buffer
    /// reused for the next): a consumer that reduces each image (a particle's score) reads it
    /// while it is still in the cache, and no batch-sized copy is made. Surfaces farther than
    /// `far` (m, along the optical axis; at most [`FAR_PLANE`]) are not drawn (0), and geometry
    /// beyond it costs nothing: give a depth camera's range, and a batch of views from inside
    /// a building draws only what lies within it. The views are tiled into atlases as large
    /// as the GPU allows and drawn in one submission each.
    pub fn render_depth_each(
        &mut self,
        intr: &Intrinsics,
        cameras: &[Pose],
        far: f32,
        mut each: impl FnMut(usize, &[f32]),
    ) -> Result<(), RenderError> {
        intr.validate().map_err(RenderError::Config)?;
        if !(far > NEAR_PLANE * 2.0 && far <= FAR_PLANE) {
            return Err(RenderError::Config(format!(
                "far plane {far} m is out of range: expected {} to {FAR_PLANE} m",
                NEAR_PLANE * 2.0
            )));
        }
        if cameras.is_empty() {
            return Ok(());
        }
        let (w, h) = (intr.width, intr.height);
        let max = self.gpu.limits.max_texture_dimension_2d.min(4096);
        if w > max || h > max {
            return Err(RenderError::Config(format!(
                "image size {w}×{h} exceeds this GPU's {max}-pixel texture limit"
            )));
        }
        self.write_cameras(intr, cameras, far);
        let n = cameras.len() as u32;
        let cols = (max / w).min(n).max(1);
        let rows = n.div_ceil(cols).min(max / h).max(1);
        let per_atlas = cols * rows;
        let key = (false, cols * w, rows * h);
        let mut image = Vec::with_capacity((w * h) as usize);
        let mut first = 0u32;
        while first < n {
            let count = per_atlas.min(n - first);
            let views: Vec<((u32, u32), u32)> = (0..count)
                .map(|i| (((i % cols) * w, (i / cols) * h), first + i))
                .collect();
            self.run(key, (w, h), &views, |_, depth, row| {
                for i in 0..count as usize {
                    let (tx, ty) = (
                        i % cols as usize * w as usize,
                        i / cols as usize * h as usize,
                    );
                    image.clear();
                    for v in 0..h as usize {
                        let src = &depth[(ty + v) * row as usize + tx * 4..][..w as usize * 4];
                        extend_f32_le(&mut image, src);
                    }
                    each(first as usize + i, &image);
                }
            })?;
            first += count;
        }
        Ok(())
    }
}

/// Appends the little-endian `f32`s in `bytes` to `out`: copied as they are where the bytes
/// are aligned for `f32` on a little-endian machine (a mapped read-back buffer's are), else
/// one by one.
fn extend_f32_le(out: &mut Vec<f32>, bytes: &[u8]) {
    if cfg!(target_endian = "little")
        && let Ok(values) = bytemuck::try_cast_slice::<u8, f32>(bytes)
    {
        out.extend_from_slice(values);
        return;
    }
    out.extend(
        bytes
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::UvMap;

    /// A camera at the origin looking down +x with a 90° × 90° view drawn to 5 m: boxes
    /// behind it, off to a side, or past the far plane are culled; boxes in view or
    /// straddling a plane are kept.
    #[test]
    fn frusta_cull_only_boxes_wholly_outside() {
        let intr = Intrinsics::from_fov(64, 64, 90f64.to_radians(), 90f64.to_radians()).unwrap();
        let view = optical_from_body(&Pose::IDENTITY).inverse().to_mat4();
        let planes = frustum_planes(&(projection(&intr, NEAR_PLANE, 5.0) * view));
        let at = |c: Vec3, h: f32| outside(&planes, c - Vec3::splat(h), c + Vec3::splat(h));
        assert!(!at(Vec3::new(3.0, 0.0, 0.0), 0.2), "ahead");
        assert!(at(Vec3::new(-3.0, 0.0, 0.0), 0.2), "behind");
        assert!(at(Vec3::new(2.0, 3.0, 0.0), 0.2), "left of the 45° edge");
        assert!(at(Vec3::new(2.0, 0.0, -3.0), 0.2), "below");
        assert!(at(Vec3::new(6.0, 0.0, 0.0), 0.5), "past the far plane");
        assert!(
            !at(Vec3::new(5.2, 0.0, 0.0), 0.5),
            "straddling the far plane"
        );
        assert!(
            !at(Vec3::new(2.0, 2.1, 0.0), 0.2),
            "straddling the left edge"
        );
        assert!(!at(Vec3::ZERO, 10.0), "around the camera");
    }

    /// A scene of two 1 m boxes, a static one ahead at (2, 0, 0) and a movable one at
    /// (2, 1.5, 0), before a wall quad 5 m ahead: each box one closed part, or six open
    /// parts (a face each).
    fn boxes(closed: bool) -> Scene {
        let material = Material {
            name: "m".into(),
            color: [0.5; 3],
            texture: None,
        };
        let cube = TriMesh::cuboid(Vec3::splat(0.5), UvMap::Fit);
        let parts = |m: &TriMesh| -> Vec<TriMesh> {
            if closed {
                return vec![m.clone()];
            }
            m.indices
                .chunks(2)
                .map(|face| TriMesh {
                    indices: face.to_vec(),
                    ..m.clone()
                })
                .collect()
        };
        let mut wall = TriMesh::default();
        wall.push_quad(
            Vec3::new(5.0, 4.0, -3.0),
            Vec3::new(0.0, -8.0, 0.0),
            Vec3::new(0.0, 0.0, 6.0),
            UvMap::Fit,
        );
        let mut scene = Scene {
            materials: vec![material.clone()],
            ..Default::default()
        };
        for (name, mesh, x) in [("box", &cube, 2.0), ("wall", &wall, 0.0)] {
            scene.bodies.push(SceneBody {
                name: name.into(),
                pose: Pose::from_translation(Vec3::new(x, 0.0, 0.0)),
                movable: false,
                parts: parts(mesh)
                    .into_iter()
                    .map(|mesh| MeshPart {
                        material: 0,
                        mesh,
                        faces_out: false,
                    })
                    .collect(),
            });
        }
        let movable = parts(&cube)
            .into_iter()
            .map(|m| (material.clone(), m))
            .collect();
        scene.add_body(
            "moved",
            Pose::from_translation(Vec3::new(2.0, 1.5, 0.0)),
            movable,
        );
        scene
    }

    /// Closed solids are drawn from the front alone: seen from outside, the same depth as
    /// the same faces drawn from both sides (to float rounding where a face turned away
    /// ties with the one in front at an edge); from inside one, its faces are not there.
    #[test]
    fn closed_solids_are_drawn_from_outside_alone() {
        let mut closed = Renderer::new(&boxes(true)).unwrap();
        let mut open = Renderer::new(&boxes(false)).unwrap();
        // The static box's chunks are culled, the wall's (at x = 5 m) not; nothing of the
        // open faces is.
        assert!(closed.chunks.iter().all(|c| c.cull == (c.max.x < 3.0)));
        assert!(closed.chunks.iter().any(|c| c.cull) && open.chunks.iter().all(|c| !c.cull));
        assert!(closed.depth_draws.iter().all(|d| d.cull));
        assert!(open.depth_draws.iter().all(|d| !d.cull));
        let intr = Intrinsics::from_fov(96, 72, 1.4, 1.1).unwrap();
        let views: Vec<Pose> = (0..12)
            .map(|k| {
                let yaw = -0.6 + 0.1 * k as f32;
                let at = Vec3::new(
                    -0.5 + 0.1 * k as f32,
                    0.8 - 0.15 * k as f32,
                    0.3 - 0.05 * k as f32,
                );
                Pose::from_parts(
                    at,
                    glam::Quat::from_rotation_z(yaw) * glam::Quat::from_rotation_y(0.2),
                )
            })
            .collect();
        let (mut a, mut b) = (Vec::new(), Vec::new());
        closed
            .render_depth_batch(&intr, &views, FAR_PLANE, &mut a)
            .unwrap();
        open.render_depth_batch(&intr, &views, FAR_PLANE, &mut b)
            .unwrap();
        let differ = a.iter().zip(&b).filter(|(x, y)| x != y).count();
        let worst = |x: &[f32], y: &[f32]| {
            x.iter()
                .zip(y)
                .map(|(p, q)| (p - q).abs())
                .fold(0.0f32, f32::max)
        };
        assert!(worst(&a, &b) < 1e-4, "{} m apart", worst(&a, &b));
        assert!(
            differ * 100 < a.len(),
            "{differ} of {} pixels differ",
            a.len()
        );
        // The boxes are in view: the images are not all wall.
        assert!(a.iter().any(|&z| z > 0.0 && z < 4.0));
        // From the static box's centre, looking down +x: its far face 0.5 m ahead when
        // drawn from both sides, the wall 3 m ahead when the box is a closed solid.
        let inside = Pose::from_translation(Vec3::new(2.0, 0.0, 0.0));
        let centre = |r: &mut Renderer| {
            let d = r.render_depth(&intr, &inside).unwrap();
            d.at(48, 36)
        };
        assert!((centre(&mut open) - 0.5).abs() < 1e-4);
        assert!((centre(&mut closed) - 3.0).abs() < 1e-4);
        // Open parts declared to face out of solid matter are drawn from the front alone too.
        let mut declared = boxes(false);
        for p in &mut declared.bodies[0].parts {
            p.faces_out = true;
        }
        let mut declared = Renderer::new(&declared).unwrap();
        assert!((centre(&mut declared) - 3.0).abs() < 1e-4);
        let mut c = Vec::new();
        declared
            .render_depth_batch(&intr, &views, FAR_PLANE, &mut c)
            .unwrap();
        assert!(worst(&c, &b) < 1e-4, "{} m apart", worst(&c, &b));
    }

    #[test]
    fn a_lost_device_is_reported_not_hung_on() {
        let mut scene = Scene::default();
        scene.add_body(
            "cube",
            Pose::from_translation(Vec3::new(2.0, 0.0, 0.0)),
            vec![(
                Material {
                    name: "m".into(),
                    color: [0.5; 3],
                    texture: None,
                },
                TriMesh::cuboid(Vec3::splat(0.5), UvMap::Fit),
            )],
        );
        let mut r = Renderer::new(&scene).unwrap();
        let intr = Intrinsics::from_fov(64, 48, 1.0, 0.8).unwrap();
        let d = r.render_depth(&intr, &Pose::IDENTITY).unwrap();
        // The cube's near face is 1.5 m ahead.
        assert!((d.at(32, 24) - 1.5).abs() < 1e-4, "{}", d.at(32, 24));
        r.gpu.device.destroy();
        let e = r.render_depth(&intr, &Pose::IDENTITY).unwrap_err();
        assert!(
            matches!(e, RenderError::DeviceLost(_) | RenderError::Device(_)),
            "{e}"
        );
    }
}
