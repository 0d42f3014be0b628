//! PLY point clouds (Turk 1994), binary little-endian: `x y z` as float and `red green blue`
//! as uchar per vertex, the layout MeshLab, CloudCompare and Open3D read.

/// A binary PLY file of coloured points.
pub fn points(points: &[([f64; 3], [u8; 3])], comment: &str) -> Vec<u8> {
    let comment = comment.replace(['\n', '\r'], " ");
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\ncomment {comment}\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n",
        points.len()
    )
    .into_bytes();
    out.reserve(points.len() * 15);
    for (p, c) in points {
        for v in p {
            out.extend_from_slice(&(*v as f32).to_le_bytes());
        }
        out.extend_from_slice(c);
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
