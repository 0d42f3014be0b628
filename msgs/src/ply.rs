//! PLY point clouds (Turk 1994), binary little-endian: `x y z` as float and `red green blue`
//! as uchar per vertex, the layout MeshLab, CloudCompare and Open3D read.

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
