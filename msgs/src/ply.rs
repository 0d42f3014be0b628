//! PLY point clouds and meshes (Turk 1994). Written binary little-endian: `x y z` as float and
//! `red green blue` as uchar per vertex, the layout MeshLab, CloudCompare and Open3D read.
//! Read in any of PLY's three encodings (through the `ply-rs-bw` crate): the vertices' `x y z`
//! of any numeric type and, where the file has faces, their `vertex_indices` (or
//! `vertex_index`) lists, polygons split into triangle fans.

use std::path::Path;

/// The geometry of a PLY file: vertex positions and triangles (none for a point cloud).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Geometry {
    pub vertices: Vec<[f64; 3]>,
    pub triangles: Vec<[u32; 3]>,
}

/// Reads a PLY file's vertices and faces; errors name the file and what was wrong.
pub fn read(path: &Path) -> Result<Geometry, String> {
    let bytes =
        std::fs::read(path).map_err(|e| format!("cannot read PLY file {}: {e}", path.display()))?;
    parse(&bytes).map_err(|e| format!("PLY file {}: {e}", path.display()))
}

/// A scalar property as a number.
fn number(p: &ply_rs_bw::ply::Property) -> Option<f64> {
    use ply_rs_bw::ply::Property as P;
    Some(match *p {
        P::Char(v) => v as f64,
        P::UChar(v) => v as f64,
        P::Short(v) => v as f64,
        P::UShort(v) => v as f64,
        P::Int(v) => v as f64,
        P::UInt(v) => v as f64,
        P::Float(v) => v as f64,
        P::Double(v) => v,
        _ => return None,
    })
}

/// A list property as indices (None: not an integer list, or a negative entry).
fn indices(p: &ply_rs_bw::ply::Property) -> Option<Vec<u32>> {
    use ply_rs_bw::ply::Property as P;
    fn all<T: Copy>(v: &[T], f: impl Fn(T) -> Option<u32>) -> Option<Vec<u32>> {
        v.iter().map(|x| f(*x)).collect()
    }
    match p {
        P::ListChar(v) => all(v, |x| u32::try_from(x).ok()),
        P::ListUChar(v) => all(v, |x| Some(x as u32)),
        P::ListShort(v) => all(v, |x| u32::try_from(x).ok()),
        P::ListUShort(v) => all(v, |x| Some(x as u32)),
        P::ListInt(v) => all(v, |x| u32::try_from(x).ok()),
        P::ListUInt(v) => all(v, Some),
        _ => None,
    }
}

/// Parses the bytes of a PLY file (see [`read`]).
pub fn parse(bytes: &[u8]) -> Result<Geometry, String> {
    use ply_rs_bw::parser::Parser;
    use ply_rs_bw::ply::DefaultElement;
    let ply = Parser::<DefaultElement>::new()
        .read_ply(&mut &bytes[..])
        .map_err(|e| format!("not a readable PLY file: {e}"))?;
    let vertices = ply
        .payload
        .get("vertex")
        .ok_or("the file has no `vertex` element")?;
    let mut out = Geometry {
        vertices: Vec::with_capacity(vertices.len()),
        triangles: Vec::new(),
    };
    for (i, v) in vertices.iter().enumerate() {
        let mut p = [0.0; 3];
        for (k, name) in ["x", "y", "z"].iter().enumerate() {
            p[k] = v
                .get(*name)
                .and_then(number)
                .ok_or_else(|| format!("vertex {i}: expected a numeric property `{name}`"))?;
            if !p[k].is_finite() {
                return Err(format!(
                    "vertex {i}: `{name}` is {}, expected a finite number",
                    p[k]
                ));
            }
        }
        out.vertices.push(p);
    }
    let n = out.vertices.len();
    for (i, f) in ply.payload.get("face").into_iter().flatten().enumerate() {
        let list = f
            .get("vertex_indices")
            .or_else(|| f.get("vertex_index"))
            .ok_or_else(|| format!("face {i}: expected a list property `vertex_indices`"))?;
        let idx = indices(list).ok_or_else(|| {
            format!("face {i}: `vertex_indices` must be a list of non-negative integers")
        })?;
        if let Some(bad) = idx.iter().find(|j| **j as usize >= n) {
            return Err(format!(
                "face {i}: vertex index {bad} is out of range (the file has {n} vertices)"
            ));
        }
        if idx.len() < 3 {
            return Err(format!(
                "face {i}: {} vertices, expected at least 3",
                idx.len()
            ));
        }
        for k in 1..idx.len() - 1 {
            out.triangles.push([idx[0], idx[k], idx[k + 1]]);
        }
    }
    Ok(out)
}

/// A binary PLY file of coloured points.
pub fn points(points: &[([f64; 3], [u8; 3])], comment: &str) -> Vec<u8> {
    mesh(points, &[], comment)
}

/// A binary PLY mesh: coloured vertices and polygonal faces (vertex indices, at most 255 a
/// face); without faces, a point cloud (no face element).
pub fn mesh(vertices: &[([f64; 3], [u8; 3])], faces: &[Vec<u32>], comment: &str) -> Vec<u8> {
    let comment = comment.replace(['\n', '\r'], " ");
    let face_element = if faces.is_empty() {
        String::new()
    } else {
        format!(
            "element face {}\nproperty list uchar uint vertex_indices\n",
            faces.len()
        )
    };
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\ncomment {comment}\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n{face_element}end_header\n",
        vertices.len()
    )
    .into_bytes();
    out.reserve(vertices.len() * 15);
    for (p, c) in vertices {
        for v in p {
            out.extend_from_slice(&(*v as f32).to_le_bytes());
        }
        out.extend_from_slice(c);
    }
    for f in faces {
        let f = &f[..f.len().min(255)];
        out.push(f.len() as u8);
        for i in f {
            out.extend_from_slice(&i.to_le_bytes());
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A mesh written here reads back: its vertices (to f32) and its quad as two triangles.
    #[test]
    fn a_written_mesh_reads_back_with_polygons_as_fans() {
        let v = [
            ([0.0, 0.0, 0.0], [1, 2, 3]),
            ([1.0, 0.0, 0.0], [0; 3]),
            ([1.0, 1.0, 0.5], [0; 3]),
            ([0.0, 1.0, 0.25], [0; 3]),
        ];
        let g = parse(&mesh(&v, &[vec![0, 1, 2, 3]], "quad")).unwrap();
        assert_eq!(g.vertices.len(), 4);
        assert_eq!(g.vertices[2], [1.0, 1.0, 0.5]);
        assert_eq!(g.triangles, vec![[0, 1, 2], [0, 2, 3]]);
        let cloud = parse(&points(&v, "cloud")).unwrap();
        assert_eq!(cloud.vertices.len(), 4);
        assert!(cloud.triangles.is_empty());
    }

    /// ASCII PLY with double coordinates and int indices reads as well.
    #[test]
    fn ascii_files_read() {
        let text = "ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\nproperty double z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n2 0 0\n0 3 1.5\n3 0 1 2\n";
        let g = parse(text.as_bytes()).unwrap();
        assert_eq!(g.vertices[2], [0.0, 3.0, 1.5]);
        assert_eq!(g.triangles, vec![[0, 1, 2]]);
    }

    /// Malformed files are errors that say what is wrong, never panics or huge allocations.
    #[test]
    fn malformed_files_are_clear_errors() {
        let head = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n";
        let cases = [
            (format!("{head}0 0 0\n1 0 0\n3 0 1 7\n"), "out of range"),
            (format!("{head}0 0 0\n1 0 0\n2 0 1\n"), "at least 3"),
            (format!("{head}0 0 0\n1 0 0\n3 0 -1 1\n"), "non-negative"),
            ("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n0 0\n".to_string(), "`z`"),
            ("ply\nformat ascii 1.0\nelement point 1\nproperty float x\nend_header\n0\n".to_string(), "no `vertex`"),
            ("not a ply".to_string(), "not a readable PLY"),
            // Four billion vertices declared, none given.
            ("ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n".to_string(), "not a readable PLY"),
        ];
        for (text, want) in cases {
            let e = parse(text.as_bytes()).unwrap_err();
            assert!(e.contains(want), "{e:?} should say {want:?}");
        }
        let e = read(Path::new("/nonexistent/model.ply")).unwrap_err();
        assert!(e.contains("/nonexistent/model.ply"), "{e}");
    }

    #[test]
    fn a_point_cloud_has_its_header_and_15_bytes_a_point() {
        let b = points(&[([1.0, -2.0, 0.5], [255, 0, 7])], "two\nlines");
        let text = String::from_utf8_lossy(&b);
        let end = text.find("end_header\n").unwrap() + "end_header\n".len();
        assert!(text.starts_with("ply\nformat binary_little_endian 1.0\ncomment two lines\n"));
        assert!(text.contains("element vertex 1\n"));
        let body = &b[end..];
        assert_eq!(body.len(), 15);
        assert_eq!(f32::from_le_bytes(body[4..8].try_into().unwrap()), -2.0);
        assert_eq!(&body[12..], &[255, 0, 7]);
    }
}
