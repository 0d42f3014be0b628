//! What a scene is drawn with: surface materials, their textures, and mesh parts.
//!
//! These are the render-side description of a surface, shared by the simulator's worlds (which
//! compile them from TOML and glTF) and by anything else that draws a model, such as a robot
//! stack that renders predicted views of a map.

use crate::mesh::TriMesh;
use std::path::Path;

/// A surface material.
#[derive(Debug, Clone, PartialEq)]
pub struct Material {
    pub name: String,
    /// sRGB base colour in [0, 1].
    pub color: [f64; 3],
    /// Index into the scene's (or world's) texture list.
    pub texture: Option<usize>,
}

/// A render mesh with one material, in its body's frame.
#[derive(Debug, Clone)]
pub struct MeshPart {
    /// Index into the scene's (or world's) material list.
    pub material: usize,
    pub mesh: TriMesh,
    /// Every triangle faces out of solid matter that no camera enters, though the mesh is
    /// not closed: a floor plan's walls, whose sides against other walls and bottoms on the
    /// floor are left out. Drawn from the front alone, as closed solids are
    /// ([`TriMesh::is_closed_solid`](crate::TriMesh::is_closed_solid)).
    pub faces_out: bool,
}

/// An sRGB RGBA8 image, row-major from the top-left.
#[derive(Debug, Clone, PartialEq)]
pub struct Texture {
    /// Where it came from (file path or pattern description).
    pub name: String,
    pub width: u32,
    pub height: u32,
    pub rgba: Vec<u8>,
}

impl Texture {
    /// Loads a PNG file; the error names the file.
    pub fn load_png(path: &Path) -> Result<Texture, String> {
        let img = image::open(path)
            .map_err(|e| format!("cannot load texture image {}: {e}", path.display()))?;
        let img = img.to_rgba8();
        if img.width() == 0 || img.height() == 0 {
            return Err(format!("texture image {} is empty", path.display()));
        }
        Ok(Texture {
            name: path.display().to_string(),
            width: img.width(),
            height: img.height(),
            rgba: img.into_raw(),
        })
    }

    /// Wraps decoded pixels (e.g. from a glTF file).
    pub fn from_rgba(name: String, width: u32, height: u32, rgba: Vec<u8>) -> Texture {
        Texture {
            name,
            width,
            height,
            rgba,
        }
    }

    /// Mean colour (sRGB, 0–1), used where a single colour stands for the texture (PLY export).
    pub fn mean_color(&self) -> [f64; 3] {
        let mut s = [0.0f64; 3];
        let n = (self.width * self.height) as f64;
        for px in self.rgba.chunks_exact(4) {
            for c in 0..3 {
                s[c] += px[c] as f64 / 255.0;
            }
        }
        s.map(|v| v / n)
    }

    /// Encodes as PNG (for glTF export).
    pub fn to_png(&self) -> Vec<u8> {
        let mut out = Vec::new();
        let img = image::RgbaImage::from_raw(self.width, self.height, self.rgba.clone())
            .expect("texture size matches its pixels");
        img.write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png)
            .expect("PNG encoding to memory cannot fail");
        out
    }
}
