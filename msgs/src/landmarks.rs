//! Visual landmark maps (seed 001 §2.1): the file a mapping pass writes and a localiser reads.
//!
//! A JSON document (`"format": "futago-landmarks"`, `"version": 1`) with one entry per
//! landmark:
//! - `position`: its 3D position in the map frame (x forward, y left, z up), m;
//! - `covariance`: the upper triangle of its 3 × 3 covariance, `[xx, xy, xz, yy, yz, zz]`, m²;
//! - `observed` and `missed`: the seed's counters m (predicted and seen) and l (predicted and
//!   not seen);
//! - `views`: for each viewing direction it was seen from, the direction's `bin` (0–35: the
//!   azimuth of the ray from the camera to the landmark in the map's xy plane, in 10° bins
//!   from −180°), the SIFT `contrast` |D| and the 128-byte `descriptor` in hex (512 × the unit
//!   vector, as OpenCV stores SIFT).
//!
//! Descriptors are hex rather than numbers to keep the file about a third the size.

use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::{Path, PathBuf};

/// The `format` value of a landmark file.
pub const FORMAT: &str = "futago-landmarks";
/// Viewing-direction bins (seed 001: 36 of 10°).
pub const DIRECTION_BINS: u8 = 36;
/// Bytes of a descriptor.
pub const DESCRIPTOR_BYTES: usize = 128;
/// The largest file read, bytes.
pub const MAX_BYTES: u64 = 1 << 30;

/// A landmark map as the file holds it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LandmarkFile {
    pub format: String,
    pub version: u32,
    /// How the map was made: the command that remakes it, written by the run that did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub made_by: Option<String>,
    pub landmarks: Vec<LandmarkRecord>,
}

/// One landmark.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LandmarkRecord {
    pub position: [f64; 3],
    pub covariance: [f64; 6],
    pub observed: u32,
    pub missed: u32,
    pub views: Vec<ViewRecord>,
}

/// The landmark seen from one direction.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ViewRecord {
    pub bin: u8,
    pub contrast: f32,
    pub descriptor: String,
}

/// What went wrong reading a landmark file, naming the file and the key.
#[derive(Debug, Clone, PartialEq)]
pub struct LandmarkError {
    pub file: PathBuf,
    pub key: String,
    pub message: String,
}

impl fmt::Display for LandmarkError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file.display())?;
        if !self.key.is_empty() {
            write!(f, ": `{}`", self.key)?;
        }
        write!(f, ": {}", self.message)
    }
}

impl std::error::Error for LandmarkError {}

/// A descriptor as hex.
pub fn to_hex(d: &[u8; DESCRIPTOR_BYTES]) -> String {
    d.iter().map(|b| format!("{b:02x}")).collect()
}

/// A descriptor from hex, or why not.
pub fn from_hex(s: &str) -> Result<[u8; DESCRIPTOR_BYTES], String> {
    let b = s.as_bytes();
    if b.len() != 2 * DESCRIPTOR_BYTES {
        return Err(format!(
            "expected {} hex digits, found {}",
            2 * DESCRIPTOR_BYTES,
            b.len()
        ));
    }
    let mut d = [0u8; DESCRIPTOR_BYTES];
    for (i, o) in d.iter_mut().enumerate() {
        let pair = std::str::from_utf8(&b[2 * i..2 * i + 2]).map_err(|_| "not hex".to_string())?;
        *o = u8::from_str_radix(pair, 16).map_err(|_| format!("`{pair}` is not hex"))?;
    }
    Ok(d)
}

impl LandmarkFile {
    /// A file of these landmarks.
    pub fn new(landmarks: Vec<LandmarkRecord>) -> LandmarkFile {
        LandmarkFile {
            format: FORMAT.into(),
            version: 1,
            made_by: None,
            landmarks,
        }
    }

    /// Reads and checks a landmark file.
    pub fn read(path: &Path) -> Result<LandmarkFile, LandmarkError> {
        let e = |key: &str, m: String| LandmarkError {
            file: path.to_path_buf(),
            key: key.into(),
            message: m,
        };
        let meta = std::fs::metadata(path).map_err(|x| e("", format!("cannot read: {x}")))?;
        if meta.len() > MAX_BYTES {
            return Err(e(
                "",
                format!("{} bytes: expected at most {MAX_BYTES}", meta.len()),
            ));
        }
        let text = std::fs::read_to_string(path).map_err(|x| e("", format!("cannot read: {x}")))?;
        Self::parse(path, &text)
    }

    /// Parses and checks the text of a landmark file; errors name `path`.
    pub fn parse(path: &Path, text: &str) -> Result<LandmarkFile, LandmarkError> {
        let e = |key: &str, m: String| LandmarkError {
            file: path.to_path_buf(),
            key: key.into(),
            message: m,
        };
        let de = &mut serde_json::Deserializer::from_str(text);
        let file: LandmarkFile = serde_path_to_error::deserialize(de)
            .map_err(|x| e(&x.path().to_string(), x.inner().to_string()))?;
        if file.format != FORMAT {
            return Err(e(
                "format",
                format!("`{}`: expected `{FORMAT}`", file.format),
            ));
        }
        if file.version != 1 {
            return Err(e("version", format!("{}: expected 1", file.version)));
        }
        for (i, l) in file.landmarks.iter().enumerate() {
            let k = |s: &str| format!("landmarks[{i}].{s}");
            if l.position.iter().any(|v| !v.is_finite() || v.abs() > 1e6) {
                return Err(e(&k("position"), "expected finite metres".into()));
            }
            let c = l.covariance;
            let (det2, det3) = (
                c[0] * c[3] - c[1] * c[1],
                c[0] * (c[3] * c[5] - c[4] * c[4]) - c[1] * (c[1] * c[5] - c[4] * c[2])
                    + c[2] * (c[1] * c[4] - c[3] * c[2]),
            );
            if c.iter().any(|v| !v.is_finite()) || c[0] <= 0.0 || det2 <= 0.0 || det3 <= 0.0 {
                return Err(e(
                    &k("covariance"),
                    "expected a positive definite covariance [xx, xy, xz, yy, yz, zz]".into(),
                ));
            }
            if l.views.is_empty() {
                return Err(e(&k("views"), "expected at least one view".into()));
            }
            for (j, v) in l.views.iter().enumerate() {
                if v.bin >= DIRECTION_BINS {
                    return Err(e(
                        &k(&format!("views[{j}].bin")),
                        format!("{}: expected 0 to {}", v.bin, DIRECTION_BINS - 1),
                    ));
                }
                if !(v.contrast.is_finite() && v.contrast >= 0.0) {
                    return Err(e(
                        &k(&format!("views[{j}].contrast")),
                        "expected a contrast ≥ 0".into(),
                    ));
                }
                from_hex(&v.descriptor).map_err(|m| e(&k(&format!("views[{j}].descriptor")), m))?;
            }
        }
        Ok(file)
    }

    /// Writes the file (to a temporary name, then renamed: never half-written).
    pub fn write(&self, path: &Path) -> std::io::Result<()> {
        let tmp = path.with_extension("json.partial");
        let text = serde_json::to_string(self).map_err(std::io::Error::other)?;
        std::fs::write(&tmp, text)?;
        std::fs::rename(&tmp, path)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record() -> LandmarkRecord {
        let mut d = [0u8; DESCRIPTOR_BYTES];
        d[3] = 200;
        d[127] = 7;
        LandmarkRecord {
            position: [1.0, 2.0, 1.5],
            covariance: [1e-4, 0.0, 0.0, 2e-4, 0.0, 3e-4],
            observed: 4,
            missed: 1,
            views: vec![ViewRecord {
                bin: 35,
                contrast: 0.05,
                descriptor: to_hex(&d),
            }],
        }
    }

    #[test]
    fn a_map_reads_back_and_bad_entries_name_their_key() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("m.json");
        let f = LandmarkFile::new(vec![record(), record()]);
        f.write(&p).unwrap();
        assert_eq!(LandmarkFile::read(&p).unwrap(), f);
        let d = from_hex(&f.landmarks[0].views[0].descriptor).unwrap();
        assert_eq!((d[3], d[127], d[0]), (200, 7, 0));

        let bad = |edit: &dyn Fn(&mut LandmarkRecord), key: &str| {
            let mut r = record();
            edit(&mut r);
            LandmarkFile::new(vec![record(), r]).write(&p).unwrap();
            let e = LandmarkFile::read(&p).unwrap_err().to_string();
            assert!(e.contains(key) && e.contains("m.json"), "{e}");
        };
        bad(&|r| r.views[0].bin = 36, "landmarks[1].views[0].bin");
        bad(
            &|r| r.views[0].descriptor.truncate(10),
            "landmarks[1].views[0].descriptor",
        );
        bad(&|r| r.covariance[0] = -1.0, "landmarks[1].covariance");
        bad(&|r| r.position[2] = f64::NAN, "landmarks[1].position");
        bad(&|r| r.views.clear(), "landmarks[1].views");
        std::fs::write(
            &p,
            r#"{"format": "futago-landmarks", "version": 1, "landmarks": [{"position": [1, 2]}]}"#,
        )
        .unwrap();
        let e = LandmarkFile::read(&p).unwrap_err().to_string();
        assert!(e.contains("landmarks[0].position"), "{e}");
        let e = LandmarkFile::read(&dir.path().join("none.json"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("none.json") && e.contains("cannot read"), "{e}");
    }
}
