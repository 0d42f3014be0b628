//! Reading ROS `map_server` maps: a YAML file of metadata naming an image (PGM or PNG), the
//! format that ROS 1's `map_server` and ROS 2's `nav2_map_server` load and save, and that
//! [`OccupancyGrid::write_map_server`] writes.
//!
//! The YAML keys are map_server's: `image` (a path relative to the YAML file), `resolution`
//! (m a cell), `origin` (`[x, y, yaw]`: the pose of the image's lower-left pixel), `negate`,
//! `occupied_thresh`, `free_thresh` and `mode` (`trinary`, `scale` or `raw`). A pixel's
//! occupancy is `p = (255 − v) / 255` (`v / 255` when negated, the mean of the colour
//! channels for colour images); in `trinary` mode `p > occupied_thresh` is occupied (100),
//! `p < free_thresh` free (0) and the rest unknown (−1); in `scale` mode the values between
//! are spread over 1–99; in `raw` mode the pixel value is the cell value (≥ 101 unknown).
//! An alpha channel below full opacity marks a cell unknown, as map_server does.
//! A rotated origin (yaw ≠ 0) is refused: map_server ignores it too.

use crate::grid::OccupancyGrid;
use serde::Deserialize;
use std::fmt;
use std::path::{Path, PathBuf};

/// The largest map read, cells (a 10 km² floor at 5 cm, or 20 × 20 km at 2.5 m): a larger
/// image header is refused before anything is allocated.
pub const MAX_CELLS: u64 = 1 << 26;

/// What went wrong reading a map, naming the file and the key or place.
#[derive(Debug, Clone, PartialEq)]
pub struct MapError {
    pub file: PathBuf,
    /// The YAML key, or what in the image (`header`, `pixels`); empty for the whole file.
    pub key: String,
    pub message: String,
}

impl fmt::Display for MapError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file.display())?;
        if !self.key.is_empty() {
            write!(f, ": `{}`", self.key)?;
        }
        write!(f, ": {}", self.message)
    }
}

impl std::error::Error for MapError {}

fn err(file: &Path, key: &str, message: impl Into<String>) -> MapError {
    MapError {
        file: file.to_path_buf(),
        key: key.to_string(),
        message: message.into(),
    }
}

/// How pixel values become occupancy (map_server's `mode`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    #[default]
    Trinary,
    Scale,
    Raw,
}

/// The YAML file of a map.
#[derive(Debug, Clone, Deserialize)]
pub struct MapMeta {
    pub image: String,
    pub resolution: f64,
    pub origin: Vec<f64>,
    #[serde(default)]
    pub negate: u8,
    #[serde(default = "default_occupied")]
    pub occupied_thresh: f64,
    #[serde(default = "default_free")]
    pub free_thresh: f64,
    #[serde(default)]
    pub mode: Mode,
}

fn default_occupied() -> f64 {
    0.65
}

fn default_free() -> f64 {
    0.196
}

/// Reads the map whose YAML file is `yaml`.
pub fn read(yaml: &Path) -> Result<OccupancyGrid, MapError> {
    let text = std::fs::read_to_string(yaml).map_err(|e| err(yaml, "", e.to_string()))?;
    parse(yaml, &text, |image| std::fs::read(image))
}

/// The map of YAML text `text` (read from `yaml`, which names it in errors and against which
/// the image's path resolves), its image's bytes got from `load`.
pub fn parse(
    yaml: &Path,
    text: &str,
    load: impl FnOnce(&Path) -> std::io::Result<Vec<u8>>,
) -> Result<OccupancyGrid, MapError> {
    let meta: MapMeta =
        serde_path_to_error::deserialize(serde_yaml_ng::Deserializer::from_str(text)).map_err(
            |e| {
                let key = e.path().to_string();
                let key = if key == "." { String::new() } else { key };
                err(
                    yaml,
                    &key,
                    format!(
                        "{}; expected map_server keys image, resolution, origin [x, y, yaw] and optionally negate, occupied_thresh, free_thresh, mode",
                        e.inner()
                    ),
                )
            },
        )?;
    check(yaml, &meta)?;
    let image = yaml.parent().unwrap_or(Path::new(".")).join(&meta.image);
    let bytes = load(&image).map_err(|e| {
        err(
            yaml,
            "image",
            format!("cannot read {}: {e}", image.display()),
        )
    })?;
    let pixels = decode(&image, &bytes)?;
    Ok(to_grid(&meta, &pixels))
}

fn check(yaml: &Path, m: &MapMeta) -> Result<(), MapError> {
    if !(m.resolution.is_finite() && m.resolution >= 1e-3 && m.resolution <= 100.0) {
        return Err(err(
            yaml,
            "resolution",
            format!(
                "expected a cell size from 0.001 to 100 m, found {}",
                m.resolution
            ),
        ));
    }
    if m.origin.len() != 3 || m.origin.iter().any(|v| !v.is_finite()) {
        return Err(err(
            yaml,
            "origin",
            format!(
                "expected three finite numbers [x, y, yaw], found {:?}",
                m.origin
            ),
        ));
    }
    if m.origin[2].abs() > 1e-9 {
        return Err(err(
            yaml,
            "origin",
            format!(
                "a rotated map (yaw {}) is not supported (map_server ignores the yaw too); expected 0",
                m.origin[2]
            ),
        ));
    }
    if m.negate > 1 {
        return Err(err(yaml, "negate", "expected 0 or 1"));
    }
    for (key, v) in [
        ("occupied_thresh", m.occupied_thresh),
        ("free_thresh", m.free_thresh),
    ] {
        if !(0.0..=1.0).contains(&v) {
            return Err(err(yaml, key, format!("expected 0 to 1, found {v}")));
        }
    }
    if m.free_thresh > m.occupied_thresh {
        return Err(err(
            yaml,
            "free_thresh",
            format!(
                "expected at most occupied_thresh ({}), found {}",
                m.occupied_thresh, m.free_thresh
            ),
        ));
    }
    Ok(())
}

/// A decoded image: grey values 0–255 (colour averaged), and whether each pixel is opaque;
/// rows top to bottom.
struct Pixels {
    width: usize,
    height: usize,
    grey: Vec<u8>,
    opaque: Vec<bool>,
}

fn decode(path: &Path, bytes: &[u8]) -> Result<Pixels, MapError> {
    if bytes.starts_with(b"P5") || bytes.starts_with(b"P2") {
        return decode_pgm(path, bytes);
    }
    if bytes.starts_with(b"\x89PNG") {
        return decode_png(path, bytes);
    }
    Err(err(
        path,
        "header",
        "expected a PGM (P2 or P5) or PNG image",
    ))
}

fn decode_png(path: &Path, bytes: &[u8]) -> Result<Pixels, MapError> {
    let reader =
        image::ImageReader::with_format(std::io::Cursor::new(bytes), image::ImageFormat::Png);
    let (w, h) = reader
        .into_dimensions()
        .map_err(|e| err(path, "header", e.to_string()))?;
    if w as u64 * h as u64 > MAX_CELLS || w == 0 || h == 0 {
        return Err(err(
            path,
            "header",
            format!("{w} × {h} pixels: expected 1 to {MAX_CELLS} pixels"),
        ));
    }
    let img = image::load_from_memory_with_format(bytes, image::ImageFormat::Png)
        .map_err(|e| err(path, "pixels", e.to_string()))?
        .to_rgba8();
    let mut grey = Vec::with_capacity((w * h) as usize);
    let mut opaque = Vec::with_capacity((w * h) as usize);
    for p in img.pixels() {
        grey.push(((p[0] as u32 + p[1] as u32 + p[2] as u32) / 3) as u8);
        opaque.push(p[3] == 255);
    }
    Ok(Pixels {
        width: w as usize,
        height: h as usize,
        grey,
        opaque,
    })
}

/// Netpbm's grey map, binary (P5) or plain (P2), 8 or 16 bits (scaled to 0–255).
fn decode_pgm(path: &Path, bytes: &[u8]) -> Result<Pixels, MapError> {
    let binary = bytes.starts_with(b"P5");
    let mut pos = 2;
    let mut header = [0u64; 3];
    for (k, v) in header.iter_mut().enumerate() {
        // Whitespace and comments before each number.
        loop {
            match bytes.get(pos) {
                Some(b) if b.is_ascii_whitespace() => pos += 1,
                Some(b'#') => {
                    while bytes.get(pos).is_some_and(|&b| b != b'\n') {
                        pos += 1;
                    }
                }
                _ => break,
            }
        }
        let start = pos;
        while bytes.get(pos).is_some_and(u8::is_ascii_digit) && pos - start < 10 {
            pos += 1;
        }
        *v = std::str::from_utf8(&bytes[start..pos])
            .ok()
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| {
                err(
                    path,
                    "header",
                    format!(
                        "expected the {} as a number",
                        ["width", "height", "maximum value"][k]
                    ),
                )
            })?;
    }
    let [w, h, maxval] = header;
    if w == 0 || h == 0 || w * h > MAX_CELLS {
        return Err(err(
            path,
            "header",
            format!("{w} × {h} pixels: expected 1 to {MAX_CELLS} pixels"),
        ));
    }
    if !(1..=65535).contains(&maxval) {
        return Err(err(
            path,
            "header",
            format!("maximum value {maxval}: expected 1 to 65535"),
        ));
    }
    let n = (w * h) as usize;
    let scale = |v: u64| ((v.min(maxval) * 255 + maxval / 2) / maxval) as u8;
    let mut grey = Vec::with_capacity(n);
    if binary {
        // One whitespace byte after the maximum value, then the raster.
        pos += 1;
        let each = if maxval < 256 { 1 } else { 2 };
        let data = bytes.get(pos..).unwrap_or(&[]);
        if data.len() < n * each {
            return Err(err(
                path,
                "pixels",
                format!(
                    "the image is cut short: {w} × {h} pixels need {} bytes, found {}",
                    n * each,
                    data.len()
                ),
            ));
        }
        for k in 0..n {
            let v = if each == 1 {
                data[k] as u64
            } else {
                u16::from_be_bytes([data[2 * k], data[2 * k + 1]]) as u64
            };
            grey.push(scale(v));
        }
    } else {
        let text = std::str::from_utf8(&bytes[pos..])
            .map_err(|_| err(path, "pixels", "expected ASCII numbers in a P2 image"))?;
        for word in text
            .lines()
            .map(|l| l.split('#').next().unwrap_or(""))
            .flat_map(str::split_ascii_whitespace)
        {
            if grey.len() == n {
                break;
            }
            let v: u64 = word.parse().map_err(|_| {
                err(
                    path,
                    "pixels",
                    format!("pixel {}: expected a number, found `{word}`", grey.len()),
                )
            })?;
            grey.push(scale(v));
        }
        if grey.len() < n {
            return Err(err(
                path,
                "pixels",
                format!(
                    "the image is cut short: expected {n} pixels, found {}",
                    grey.len()
                ),
            ));
        }
    }
    Ok(Pixels {
        width: w as usize,
        height: h as usize,
        grey,
        opaque: vec![true; n],
    })
}

fn to_grid(m: &MapMeta, px: &Pixels) -> OccupancyGrid {
    let mut g = OccupancyGrid::new(
        m.resolution,
        [m.origin[0], m.origin[1]],
        px.width,
        px.height,
    );
    for row in 0..px.height {
        // The image's top row is the map's last.
        let j = px.height - 1 - row;
        for i in 0..px.width {
            let k = row * px.width + i;
            let v = px.grey[k];
            g.set(i, j, cell_value(m, v, px.opaque[k]));
        }
    }
    g
}

/// A pixel's cell value under map_server's rules.
fn cell_value(m: &MapMeta, v: u8, opaque: bool) -> i8 {
    if m.mode == Mode::Raw {
        return if v <= 100 { v as i8 } else { -1 };
    }
    if !opaque {
        return -1;
    }
    let p = if m.negate == 1 {
        v as f64 / 255.0
    } else {
        (255.0 - v as f64) / 255.0
    };
    if p > m.occupied_thresh {
        100
    } else if p < m.free_thresh {
        0
    } else if m.mode == Mode::Scale {
        (1.0 + 98.0 * (p - m.free_thresh) / (m.occupied_thresh - m.free_thresh)).round() as i8
    } else {
        -1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir() -> tempfile::TempDir {
        tempfile::tempdir().unwrap()
    }

    /// What futago writes, map_server's reader reads back cell for cell.
    #[test]
    fn a_written_map_reads_back_the_same() {
        let tmp = dir();
        let d = tmp.path();
        let mut g = OccupancyGrid::new(0.05, [-1.25, 3.5], 7, 4);
        for (k, c) in g.cells.iter_mut().enumerate() {
            *c = [0, 100, -1][k % 3];
        }
        g.write_map_server(d, "m").unwrap();
        let back = read(&d.join("m.yaml")).unwrap();
        assert_eq!(back, g);
    }

    /// A plain (P2) 16-bit image with a comment, negated, in scale mode: each pixel's value by
    /// map_server's formula, the top row last.
    #[test]
    fn plain_pgm_scale_mode_and_negate_follow_map_server() {
        let tmp = dir();
        let d = tmp.path();
        std::fs::write(
            d.join("s.pgm"),
            "P2\n# a comment\n3 2\n65535\n0 65535 32768\n65535 0 13107\n",
        )
        .unwrap();
        std::fs::write(
            d.join("s.yaml"),
            "image: s.pgm\nresolution: 0.1\norigin: [0.0, 0.0, 0.0]\nnegate: 1\noccupied_thresh: 0.65\nfree_thresh: 0.196\nmode: scale\n",
        )
        .unwrap();
        let g = read(&d.join("s.yaml")).unwrap();
        // Negated: p = v/255. Bottom row (the image's second): 255 → 1.0 occupied, 0 → free,
        // 13107/65535·255 = 51 → p = 0.2: scale 1 + 98·(0.2 − 0.196)/(0.65 − 0.196) ≈ 1.86 → 2.
        assert_eq!(&g.cells[0..3], &[100, 0, 2]);
        // Top row: 0 → free, 255 → occupied, 128 → p = 0.502: 1 + 98·0.306/0.454 ≈ 67.
        assert_eq!(&g.cells[3..6], &[0, 100, 67]);
    }

    #[test]
    fn bad_maps_name_the_file_and_key() {
        let tmp = dir();
        let d = tmp.path();
        std::fs::write(d.join("b.pgm"), "P5\n4 4\n255\nab").unwrap();
        let cases = [
            (
                "image: b.pgm\nresolution: -1\norigin: [0, 0, 0]\n",
                "resolution",
            ),
            ("image: b.pgm\nresolution: 0.05\norigin: [0, 0]\n", "origin"),
            (
                "image: b.pgm\nresolution: 0.05\norigin: [0, 0, 0.5]\n",
                "origin",
            ),
            ("image: b.pgm\nresolution: 0.05\n", ""),
            (
                "image: b.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nmode: fancy\n",
                "mode",
            ),
            (
                "image: nope.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n",
                "image",
            ),
            (
                "image: b.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n",
                "pixels",
            ),
        ];
        for (yaml, key) in cases {
            std::fs::write(d.join("b.yaml"), yaml).unwrap();
            let e = read(&d.join("b.yaml")).unwrap_err();
            assert_eq!(e.key, key, "{yaml}: {e}");
            assert!(e.to_string().contains("b."), "{e}");
        }
        // A header that claims a huge image is refused before any allocation.
        std::fs::write(d.join("h.pgm"), "P5\n100000 100000\n255\n").unwrap();
        std::fs::write(
            d.join("h.yaml"),
            "image: h.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n",
        )
        .unwrap();
        let e = read(&d.join("h.yaml")).unwrap_err();
        assert_eq!(e.key, "header", "{e}");
    }
}
