//! glTF 2.0 in and out: loading `.glb`/`.gltf` assets as static geometry, and writing a world as
//! one binary glTF with its materials and textures.
//!
//! glTF is +Y up; futago is +Z up (REP 103). Loading rotates +90° about x, `(x, y, z)_gltf →
//! (x, −z, y)`, and exporting applies the inverse on a root node, so a world written and read
//! back is unchanged. Where a glTF material has both a base-colour factor and a texture, the
//! factor is baked into the texture: a futago material is a colour *or* a texture.

use super::mesh::TriMesh;
use super::{Motion, World};
use futago_render::Texture;
use glam::{Mat3, Mat4, Quat, Vec2, Vec3};
use serde_json::{Value, json};
use std::path::Path;

/// A material read from a glTF file.
#[derive(Debug, Clone)]
pub struct LoadedMaterial {
    pub name: String,
    /// sRGB colour in [0, 1].
    pub color: [f64; 3],
    /// Index into [`Loaded::textures`].
    pub texture: Option<usize>,
}

/// One triangle list with one material.
#[derive(Debug, Clone)]
pub struct LoadedPart {
    /// Index into [`Loaded::materials`].
    pub material: usize,
    pub mesh: TriMesh,
}

/// The geometry of a glTF file, flattened into Z-up meshes in the file's root frame.
#[derive(Debug, Clone)]
pub struct Loaded {
    pub parts: Vec<LoadedPart>,
    pub materials: Vec<LoadedMaterial>,
    pub material_count: usize,
    pub textures: Vec<Texture>,
}

fn linear_to_srgb(c: f32) -> f64 {
    let c = c.clamp(0.0, 1.0) as f64;
    if c <= 0.0031308 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    }
}

fn srgb_to_linear(c: f64) -> f64 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// glTF (Y-up) to futago (Z-up).
fn y_up_to_z_up() -> Mat4 {
    Mat4::from_rotation_x(std::f32::consts::FRAC_PI_2)
}

fn to_rgba8(img: &gltf::image::Data) -> Result<Vec<u8>, String> {
    use gltf::image::Format::*;
    let px = &img.pixels;
    let n = (img.width * img.height) as usize;
    let out: Vec<u8> = match img.format {
        R8G8B8A8 => px.clone(),
        R8G8B8 => px
            .chunks_exact(3)
            .flat_map(|c| [c[0], c[1], c[2], 255])
            .collect(),
        R8G8 => px
            .chunks_exact(2)
            .flat_map(|c| [c[0], c[0], c[0], c[1]])
            .collect(),
        R8 => px.iter().flat_map(|&c| [c, c, c, 255]).collect(),
        other => {
            return Err(format!(
                "unsupported texture pixel format {other:?} (8-bit formats only)"
            ));
        }
    };
    if out.len() != n * 4 {
        return Err("texture pixel data does not match its size".into());
    }
    Ok(out)
}

/// Checks the references that the gltf crate (1.4) follows without a bounds check, so that a
/// malformed file is an error naming it instead of a panic inside the crate (found by
/// `futago fuzz`): a primitive's accessor indices, which the crate's validation indexes
/// before checking, and an image in a buffer view without a MIME type, which its
/// `Image::source` unwraps.
fn precheck(name: &Path, bytes: &[u8]) -> Result<(), String> {
    let bad = |m: String| Err(format!("{}: {m}", name.display()));
    let glb;
    let json: &[u8] = if bytes.starts_with(b"glTF") {
        glb = gltf::Glb::from_slice(bytes)
            .map_err(|e| format!("cannot load glTF file {}: {e}", name.display()))?;
        &glb.json
    } else {
        bytes
    };
    // What does not parse here is left to the crate's own error.
    let Ok(root) = gltf::json::Root::from_slice(json) else {
        return Ok(());
    };
    let accessors = root.accessors.len();
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (k, p) in mesh.primitives.iter().enumerate() {
            let targets = p.targets.iter().flatten().flat_map(|t| {
                [t.positions, t.normals, t.tangents]
                    .into_iter()
                    .flatten()
                    .collect::<Vec<_>>()
            });
            let used = p
                .attributes
                .values()
                .copied()
                .chain(p.indices)
                .chain(targets);
            for a in used {
                if a.value() >= accessors {
                    return bad(format!(
                        "mesh {m} primitive {k} refers to accessor {}, but the file has {accessors}",
                        a.value()
                    ));
                }
            }
        }
    }
    for (i, v) in root.buffer_views.iter().enumerate() {
        let Some(b) = root.buffers.get(v.buffer.value()) else {
            return bad(format!("buffer view {i} refers to a missing buffer"));
        };
        let end = v
            .byte_offset
            .map_or(0, |o| o.0)
            .checked_add(v.byte_length.0);
        if end.is_none_or(|e| e > b.byte_length.0) {
            return bad(format!(
                "buffer view {i} reaches past the end of its buffer"
            ));
        }
    }
    // The attributes this loader reads, with the component types and shapes the crate's
    // readers take (any other reaches an `unreachable!` there).
    use gltf::json::accessor::{ComponentType as C, Type as T};
    use gltf::json::mesh::Semantic;
    use gltf::json::validation::Checked;
    let kind = |a: gltf::json::Index<gltf::json::Accessor>| {
        let acc = &root.accessors[a.value()];
        match (&acc.component_type, &acc.type_) {
            (Checked::Valid(c), Checked::Valid(t)) => Some((c.0, *t)),
            _ => None,
        }
    };
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (k, p) in mesh.primitives.iter().enumerate() {
            let what = |attr: &str| {
                format!("mesh {m} primitive {k}: {attr} has a type this loader does not read")
            };
            for (sem, a) in &p.attributes {
                let name = match sem {
                    Checked::Valid(Semantic::Positions) => "POSITION".to_string(),
                    Checked::Valid(Semantic::Normals) => "NORMAL".to_string(),
                    Checked::Valid(Semantic::TexCoords(n)) => format!("TEXCOORD_{n}"),
                    _ => "another attribute".to_string(),
                };
                let ok = match sem {
                    Checked::Valid(Semantic::Positions | Semantic::Normals) => {
                        kind(*a) == Some((C::F32, T::Vec3))
                    }
                    Checked::Valid(Semantic::TexCoords(_)) => {
                        matches!(kind(*a), Some((C::U8 | C::U16 | C::F32, T::Vec2)))
                    }
                    _ => true,
                };
                if !ok {
                    return bad(what(&format!("attribute {name}")));
                }
            }
            if let Some(a) = p.indices
                && !matches!(kind(a), Some((C::U8 | C::U16 | C::U32, T::Scalar)))
            {
                return bad(what("its index accessor"));
            }
        }
    }
    for (i, img) in root.images.iter().enumerate() {
        match (&img.buffer_view, &img.mime_type, &img.uri) {
            (Some(v), Some(_), _) if v.value() < root.buffer_views.len() => {}
            (Some(_), None, _) => {
                return bad(format!("image {i} is in a buffer view but has no mimeType"));
            }
            (Some(v), _, _) => {
                return bad(format!(
                    "image {i} refers to buffer view {}, but the file has {}",
                    v.value(),
                    root.buffer_views.len()
                ));
            }
            (None, _, None) => return bad(format!("image {i} has neither a uri nor a bufferView")),
            (None, _, Some(_)) => {}
        }
    }
    Ok(())
}

/// Loads every triangle primitive of the default (or first) scene of a glTF file.
pub fn load(path: &Path) -> Result<Loaded, String> {
    let bytes = std::fs::read(path)
        .map_err(|e| format!("cannot read glTF file {}: {e}", path.display()))?;
    precheck(path, &bytes)?;
    let (doc, buffers, images) =
        gltf::import(path).map_err(|e| format!("cannot load glTF file {}: {e}", path.display()))?;
    convert(path, doc, buffers, images)
}

/// As [`load`], from the bytes of a self-contained file (a GLB, or glTF with data URIs);
/// `name` stands for the file in errors.
pub fn load_slice(name: &Path, bytes: &[u8]) -> Result<Loaded, String> {
    precheck(name, bytes)?;
    let (doc, buffers, images) = gltf::import_slice(bytes)
        .map_err(|e| format!("cannot load glTF file {}: {e}", name.display()))?;
    convert(name, doc, buffers, images)
}

/// The document's materials and their textures, the colour factor baked into each texture
/// (see the module docs).
fn materials(
    path: &Path,
    doc: &gltf::Document,
    images: &[gltf::image::Data],
) -> Result<(Vec<Texture>, Vec<LoadedMaterial>), String> {
    let mut textures = Vec::new();
    let mut materials = Vec::new();
    for (i, m) in doc.materials().enumerate() {
        let pbr = m.pbr_metallic_roughness();
        let f = pbr.base_color_factor();
        let color = [
            linear_to_srgb(f[0]),
            linear_to_srgb(f[1]),
            linear_to_srgb(f[2]),
        ];
        let texture = match pbr.base_color_texture() {
            None => None,
            Some(info) => {
                if info.tex_coord() != 0 {
                    return Err(format!(
                        "{}: material {i} uses texture coordinate set {}; only set 0 is supported",
                        path.display(),
                        info.tex_coord()
                    ));
                }
                let img = &images[info.texture().source().index()];
                let mut rgba = to_rgba8(img)
                    .map_err(|e| format!("{}: texture of material {i}: {e}", path.display()))?;
                if f.iter().take(3).any(|&c| (c - 1.0).abs() > 1e-6) {
                    for px in rgba.chunks_exact_mut(4) {
                        for c in 0..3 {
                            let lin = srgb_to_linear(px[c] as f64 / 255.0) * f[c] as f64;
                            px[c] = (linear_to_srgb(lin as f32) * 255.0).round() as u8;
                        }
                    }
                }
                textures.push(Texture::from_rgba(
                    format!(
                        "{}#image{}",
                        path.display(),
                        info.texture().source().index()
                    ),
                    img.width,
                    img.height,
                    rgba,
                ));
                Some(textures.len() - 1)
            }
        };
        materials.push(LoadedMaterial {
            name: m
                .name()
                .map(str::to_string)
                .unwrap_or_else(|| format!("material{i}")),
            color,
            texture,
        });
    }
    Ok((textures, materials))
}

fn convert(
    path: &Path,
    doc: gltf::Document,
    buffers: Vec<gltf::buffer::Data>,
    images: Vec<gltf::image::Data>,
) -> Result<Loaded, String> {
    let (textures, mut materials) = materials(path, &doc, &images)?;
    let default_material = materials.len();
    materials.push(LoadedMaterial {
        name: "default".into(),
        color: [0.8, 0.8, 0.8],
        texture: None,
    });

    let scene = doc
        .default_scene()
        .or_else(|| doc.scenes().next())
        .ok_or_else(|| format!("{}: the glTF file has no scene", path.display()))?;
    let mut parts = Vec::new();
    let mut stack: Vec<(gltf::Node, Mat4)> = scene.nodes().map(|n| (n, y_up_to_z_up())).collect();
    while let Some((node, parent)) = stack.pop() {
        let m = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        for child in node.children() {
            stack.push((child, m));
        }
        let Some(mesh) = node.mesh() else { continue };
        let nmat = Mat3::from_mat4(m).inverse().transpose();
        for (pi, prim) in mesh.primitives().enumerate() {
            let what = format!("{}: mesh {} primitive {pi}", path.display(), mesh.index());
            if prim.mode() != gltf::mesh::Mode::Triangles {
                return Err(format!(
                    "{what}: mode {:?} is not supported (triangles only)",
                    prim.mode()
                ));
            }
            let reader = prim.reader(|b| Some(&buffers[b.index()]));
            let positions: Vec<Vec3> = reader
                .read_positions()
                .ok_or_else(|| format!("{what}: no POSITION attribute"))?
                .map(|p| m.transform_point3(Vec3::from(p)))
                .collect();
            if positions.iter().any(|p| !p.is_finite()) {
                return Err(format!("{what}: non-finite vertex positions"));
            }
            let n = positions.len();
            let indices: Vec<u32> = match reader.read_indices() {
                Some(i) => i.into_u32().collect(),
                None => (0..n as u32).collect(),
            };
            if !indices.len().is_multiple_of(3) {
                return Err(format!(
                    "{what}: {} indices is not a whole number of triangles",
                    indices.len()
                ));
            }
            if let Some(bad) = indices.iter().find(|&&i| i as usize >= n) {
                return Err(format!("{what}: index {bad} out of range ({n} vertices)"));
            }
            let uvs: Vec<Vec2> = match reader.read_tex_coords(0) {
                Some(t) => t.into_f32().map(Vec2::from).collect(),
                None => vec![Vec2::ZERO; n],
            };
            let mut tm = TriMesh {
                positions,
                normals: Vec::new(),
                uvs,
                indices: indices
                    .chunks_exact(3)
                    .map(|t| [t[0], t[1], t[2]])
                    .collect(),
            };
            match reader.read_normals() {
                Some(ns) => {
                    tm.normals = ns
                        .map(|v| (nmat * Vec3::from(v)).normalize_or(Vec3::Z))
                        .collect()
                }
                None => tm.compute_normals(),
            }
            if tm.normals.len() != n || tm.uvs.len() != n {
                return Err(format!(
                    "{what}: attribute counts differ from the vertex count"
                ));
            }
            tm.remove_degenerate();
            if tm.indices.is_empty() {
                continue;
            }
            parts.push(LoadedPart {
                material: prim.material().index().unwrap_or(default_material),
                mesh: tm,
            });
        }
    }
    if parts.is_empty() {
        return Err(format!(
            "{}: the glTF file has no non-degenerate triangles",
            path.display()
        ));
    }
    let material_count = materials.len();
    Ok(Loaded {
        parts,
        materials,
        material_count,
        textures,
    })
}

/// Appends `bytes` to the binary chunk as a buffer view, 4-byte aligned; returns its index.
fn push_view(
    bin: &mut Vec<u8>,
    views: &mut Vec<Value>,
    bytes: &[u8],
    target: Option<u32>,
) -> usize {
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let mut v = json!({ "buffer": 0, "byteOffset": bin.len(), "byteLength": bytes.len() });
    if let Some(t) = target {
        v["target"] = json!(t);
    }
    bin.extend_from_slice(bytes);
    views.push(v);
    views.len() - 1
}

fn f32_bytes(v: impl IntoIterator<Item = f32>) -> Vec<u8> {
    v.into_iter().flat_map(f32::to_le_bytes).collect()
}

/// Writes the world's objects at `poses` (one per object) as a binary glTF: a node per object,
/// a mesh per object with one primitive per material, the materials with their textures as
/// embedded PNG, under a root node that turns Z-up into glTF's Y-up.
pub fn export_glb(world: &World, poses: &[rapier3d::math::Pose]) -> Vec<u8> {
    let mut bin = Vec::new();
    let (mut views, mut accessors, mut meshes, mut nodes) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut images = Vec::new();
    let mut textures = Vec::new();
    let mut texture_of = vec![None; world.textures.len()];
    let materials: Vec<Value> = world
        .materials
        .iter()
        .map(|m| {
            let mut pbr = json!({ "metallicFactor": 0.0, "roughnessFactor": 0.9 });
            match m.texture {
                Some(t) => {
                    let ti = *texture_of[t].get_or_insert_with(|| {
                        let view =
                            push_view(&mut bin, &mut views, &world.textures[t].to_png(), None);
                        images.push(json!({ "bufferView": view, "mimeType": "image/png" }));
                        textures.push(json!({ "source": images.len() - 1, "sampler": 0 }));
                        textures.len() - 1
                    });
                    pbr["baseColorTexture"] = json!({ "index": ti });
                }
                None => {
                    let c = m.color.map(srgb_to_linear);
                    pbr["baseColorFactor"] = json!([c[0], c[1], c[2], 1.0]);
                }
            }
            json!({ "name": m.name, "pbrMetallicRoughness": pbr })
        })
        .collect();
    for (oi, (o, pose)) in world.objects.iter().zip(poses).enumerate() {
        let mut prims = Vec::new();
        for p in &o.parts {
            let m = &p.mesh;
            if m.indices.is_empty() {
                continue;
            }
            let (lo, hi) = m.positions.iter().fold(
                (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
                |(lo, hi), &v| (lo.min(v), hi.max(v)),
            );
            let pv = push_view(
                &mut bin,
                &mut views,
                &f32_bytes(m.positions.iter().flat_map(|v| v.to_array())),
                Some(34962),
            );
            accessors.push(json!({ "bufferView": pv, "componentType": 5126, "count": m.positions.len(), "type": "VEC3", "min": lo.to_array(), "max": hi.to_array() }));
            let nv = push_view(
                &mut bin,
                &mut views,
                &f32_bytes(m.normals.iter().flat_map(|v| v.to_array())),
                Some(34962),
            );
            accessors.push(json!({ "bufferView": nv, "componentType": 5126, "count": m.normals.len(), "type": "VEC3" }));
            let tv = push_view(
                &mut bin,
                &mut views,
                &f32_bytes(m.uvs.iter().flat_map(|v| v.to_array())),
                Some(34962),
            );
            accessors.push(json!({ "bufferView": tv, "componentType": 5126, "count": m.uvs.len(), "type": "VEC2" }));
            let idx: Vec<u8> = m
                .indices
                .iter()
                .flatten()
                .flat_map(|i| i.to_le_bytes())
                .collect();
            let iv = push_view(&mut bin, &mut views, &idx, Some(34963));
            accessors.push(json!({ "bufferView": iv, "componentType": 5125, "count": m.indices.len() * 3, "type": "SCALAR" }));
            let a = accessors.len();
            prims.push(json!({ "attributes": { "POSITION": a - 4, "NORMAL": a - 3, "TEXCOORD_0": a - 2 }, "indices": a - 1, "material": p.material }));
        }
        if prims.is_empty() {
            continue;
        }
        meshes.push(json!({ "name": o.name, "primitives": prims }));
        let q = pose.rotation;
        let t = pose.translation;
        let mut node = json!({ "name": o.name, "mesh": meshes.len() - 1, "translation": [t.x, t.y, t.z], "rotation": [q.x, q.y, q.z, q.w] });
        if let Motion::Dynamic { mass } = o.motion {
            node["extras"] = json!({ "dynamic": true, "mass": mass, "object": oi });
        }
        nodes.push(node);
    }
    let children: Vec<usize> = (0..nodes.len()).collect();
    let root = Quat::from_rotation_x(-std::f32::consts::FRAC_PI_2);
    nodes.push(json!({ "name": world.name, "rotation": [root.x, root.y, root.z, root.w], "children": children }));
    while bin.len() % 4 != 0 {
        bin.push(0);
    }
    let mut doc = json!({
        "asset": { "version": "2.0", "generator": "futago" },
        "scene": 0,
        "scenes": [{ "name": world.name, "nodes": [nodes.len() - 1] }],
        "nodes": nodes,
        "meshes": meshes,
        "materials": materials,
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{ "byteLength": bin.len() }],
        "samplers": [{ "magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497 }],
    });
    if !images.is_empty() {
        doc["images"] = json!(images);
        doc["textures"] = json!(textures);
    }
    let mut json_bytes =
        serde_json::to_vec(&doc).expect("JSON serialisation of plain values cannot fail");
    while !json_bytes.len().is_multiple_of(4) {
        json_bytes.push(b' ');
    }
    let glb = gltf::binary::Glb {
        header: gltf::binary::Header {
            magic: *b"glTF",
            version: 2,
            length: 0,
        },
        json: json_bytes.into(),
        bin: Some(bin.into()),
    };
    glb.to_vec().expect("writing a GLB to memory cannot fail")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A one-triangle glTF (JSON, no binary: the buffer is never read because every check
    /// below fails before it is) with `edit` applied to its JSON text.
    fn gltf(edit: impl Fn(String) -> String) -> Vec<u8> {
        let json = r#"{"asset":{"version":"2.0"},
"buffers":[{"byteLength":42}],
"bufferViews":[{"buffer":0,"byteLength":36},{"buffer":0,"byteOffset":36,"byteLength":6}],
"accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]},
{"bufferView":1,"componentType":5123,"count":3,"type":"SCALAR"}],
"meshes":[{"primitives":[{"attributes":{"POSITION":0},"indices":1}]}],
"images":[]}"#;
        edit(json.to_string()).into_bytes()
    }

    #[test]
    fn references_the_gltf_crate_would_panic_on_are_errors() {
        let name = Path::new("bad.gltf");
        assert!(precheck(name, &gltf(|j| j)).is_ok());
        for (edit, expect) in [
            (
                (|j: String| j.replace(r#""POSITION":0"#, r#""POSITION":7"#))
                    as fn(String) -> String,
                "refers to accessor 7, but the file has 2",
            ),
            (
                |j| j.replace(r#""byteOffset":36"#, r#""byteOffset":40"#),
                "buffer view 1 reaches past the end of its buffer",
            ),
            (
                |j| j.replace(r#""componentType":5123"#, r#""componentType":5126"#),
                "its index accessor has a type this loader does not read",
            ),
            (
                |j| j.replace(r#""images":[]"#, r#""images":[{"bufferView":0}]"#),
                "image 0 is in a buffer view but has no mimeType",
            ),
        ] {
            let e = precheck(name, &gltf(edit)).unwrap_err();
            assert!(e.contains(expect) && e.contains("bad.gltf"), "{e}");
        }
    }
}
