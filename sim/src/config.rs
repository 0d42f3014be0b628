//! Loading typed configuration from TOML files with errors that name the file, the key and
//! what was expected.
//!
//! Every world and scenario file goes through [`load_toml`]: unknown keys are rejected by the
//! `deny_unknown_fields` of the target types, and [`SpecError`] carries the dotted key path
//! (`robot.odometry.noise`) found by `serde_path_to_error`.

use serde::de::DeserializeOwned;
use std::fmt;
use std::path::{Path, PathBuf};

/// A problem with an input file: which file, which key, what was expected.
#[derive(Debug, Clone, PartialEq)]
pub struct SpecError {
    pub file: PathBuf,
    /// Dotted key path, e.g. `lidar[0].range_max`; empty for the whole file.
    pub key: String,
    /// Line (1-based) when known.
    pub line: Option<usize>,
    pub message: String,
}

impl SpecError {
    /// An error about `key` in `file`.
    pub fn new(
        file: impl Into<PathBuf>,
        key: impl Into<String>,
        message: impl Into<String>,
    ) -> SpecError {
        SpecError {
            file: file.into(),
            key: key.into(),
            line: None,
            message: message.into(),
        }
    }
}

impl fmt::Display for SpecError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file.display())?;
        if let Some(l) = self.line {
            write!(f, ":{l}")?;
        }
        if !self.key.is_empty() {
            write!(f, ": key `{}`", self.key)?;
        }
        write!(f, ": {}", self.message)
    }
}

impl std::error::Error for SpecError {}

/// Reads `path` as UTF-8 text, naming the file in the error.
pub fn read_text(path: &Path) -> Result<String, SpecError> {
    std::fs::read_to_string(path)
        .map_err(|e| SpecError::new(path, "", format!("cannot read file: {e}")))
}

/// Parses TOML text into `T`, naming `path`, the key path and the line in errors.
pub fn parse_toml<T: DeserializeOwned>(path: &Path, text: &str) -> Result<T, SpecError> {
    let line_of = |offset: usize| text[..offset.min(text.len())].matches('\n').count() + 1;
    let de = toml::de::Deserializer::parse(text).map_err(|e| SpecError {
        file: path.to_path_buf(),
        key: String::new(),
        line: e.span().map(|s| line_of(s.start)),
        message: format!("TOML syntax error: {}", e.message()),
    })?;
    serde_path_to_error::deserialize(de).map_err(|e| {
        let key = e.path().to_string();
        let inner = e.into_inner();
        SpecError {
            file: path.to_path_buf(),
            key: if key == "." { String::new() } else { key },
            line: inner.span().map(|s| line_of(s.start)),
            message: inner.message().to_string(),
        }
    })
}

/// The line (1-based) of the dotted key `key` (`localization.mcl.particles`,
/// `lidar[0].name`) in the TOML text `text`: where its deepest part that the text holds is
/// written. For errors found after parsing, when checks of typed values name a key.
pub fn line_of_key(text: &str, key: &str) -> Option<usize> {
    use toml::de::{DeTable, DeValue};
    let root = DeTable::parse(text).ok()?;
    let line = |offset: usize| text[..offset.min(text.len())].matches('\n').count() + 1;
    let mut table = root.get_ref();
    let mut found = None;
    for part in key.split('.') {
        let (name, indices) = part.split_once('[').unwrap_or((part, ""));
        let Some((k, mut v)) = table.iter().find(|(k, _)| k.get_ref().as_ref() == name) else {
            return found;
        };
        found = Some(line(k.span().start));
        for index in indices.split('[').filter(|i| !i.is_empty()) {
            let item = index
                .trim_end_matches(']')
                .parse::<usize>()
                .ok()
                .and_then(|i| match v.get_ref() {
                    DeValue::Array(a) => a.get(i),
                    _ => None,
                });
            let Some(item) = item else {
                return found;
            };
            v = item;
            found = Some(line(v.span().start));
        }
        match v.get_ref() {
            DeValue::Table(t) => table = t,
            _ => return found,
        }
    }
    found
}

/// Reads and parses a TOML file into `T`.
pub fn load_toml<T: DeserializeOwned>(path: &Path) -> Result<T, SpecError> {
    let text = read_text(path)?;
    parse_toml(path, &text)
}

/// Checks that `value` is finite and within `[lo, hi]`; otherwise an error naming `key`.
pub fn check_range(
    file: &Path,
    key: &str,
    value: f64,
    lo: f64,
    hi: f64,
    unit: &str,
) -> Result<(), SpecError> {
    if value.is_finite() && value >= lo && value <= hi {
        Ok(())
    } else {
        Err(SpecError::new(
            file,
            key,
            format!(
                "expected a value in [{lo}, {hi}] {unit}, found {}",
                futago_msgs::shown(value)
            ),
        ))
    }
}

/// Checks that `value` is finite and strictly positive.
pub fn check_positive(file: &Path, key: &str, value: f64, unit: &str) -> Result<(), SpecError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(SpecError::new(
            file,
            key,
            format!("expected a positive number of {unit}, found {value}"),
        ))
    }
}

/// Checks a name used in file names and frames: non-empty ASCII letters, digits, `-`, `_`.
/// Checks a sensor's mounting table (`key.xyz`, `key.rpy_deg`): finite numbers.
pub fn check_mount(
    file: &Path,
    key: &str,
    xyz: [f64; 3],
    rpy_deg: [f64; 3],
) -> Result<(), SpecError> {
    for v in xyz {
        check_range(
            file,
            &format!("{key}.xyz"),
            v,
            -MAX_MOUNT,
            MAX_MOUNT,
            "m from the base frame",
        )?;
    }
    for v in rpy_deg {
        check_range(file, &format!("{key}.rpy_deg"), v, -360.0, 360.0, "degrees")?;
    }
    Ok(())
}

/// The farthest a sensor may sit from the robot's base frame, m: a small indoor robot's mast
/// is well inside it, and a mount beyond it is a typo.
pub const MAX_MOUNT: f64 = 10.0;

/// A sensor's mounting pose on the robot base frame from `xyz` (m) and `rpy_deg` (roll, pitch,
/// yaw in degrees; rotation = yaw · pitch · roll).
pub fn mount_pose(xyz: [f64; 3], rpy_deg: [f64; 3]) -> rapier3d::math::Pose {
    let [r, p, y] = rpy_deg.map(|a| a.to_radians() as f32);
    rapier3d::math::Pose::from_parts(
        glam::Vec3::new(xyz[0] as f32, xyz[1] as f32, xyz[2] as f32),
        glam::Quat::from_euler(glam::EulerRot::ZYX, y, p, r),
    )
}

pub fn check_name(file: &Path, key: &str, name: &str) -> Result<(), SpecError> {
    if !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
    {
        Ok(())
    } else {
        Err(SpecError::new(
            file,
            key,
            format!("expected a non-empty name of letters, digits, '-' and '_', found `{name}`"),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_are_found_on_their_lines() {
        let text = "name = \"a\"\n\n[localization]\nrate = 4.0\n\n[localization.mcl]\nparticles = 5\n\n[[lidar]]\nname = \"front\"\n\n[[lidar]]\nname = \"back\"\nxyz = [0.0, 0.0, 0.2]\n";
        assert_eq!(line_of_key(text, "name"), Some(1));
        assert_eq!(line_of_key(text, "localization.rate"), Some(4));
        assert_eq!(line_of_key(text, "localization.mcl.particles"), Some(7));
        assert_eq!(line_of_key(text, "lidar[1].name"), Some(13));
        // A key the text does not hold is placed at its deepest part that it does.
        assert_eq!(line_of_key(text, "localization.mcl.model"), Some(6));
        assert_eq!(line_of_key(text, "slam.method"), None);
        assert_eq!(line_of_key("x = [", "x"), None);
    }
    use serde::Deserialize;

    #[derive(Deserialize, serde::Serialize, Debug)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct Inner {
        range_max: f64,
    }

    #[derive(Deserialize, serde::Serialize, Debug)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct Outer {
        name: String,
        lidar: Vec<Inner>,
    }

    #[test]
    fn errors_name_key_path_and_line() {
        let p = Path::new("x.toml");
        let e =
            parse_toml::<Outer>(p, "name = \"a\"\n[[lidar]]\nrange_max = \"far\"\n").unwrap_err();
        assert_eq!(e.key, "lidar[0].range_max");
        assert_eq!(e.line, Some(3));
        assert!(
            e.to_string()
                .starts_with("x.toml:3: key `lidar[0].range_max`"),
            "{e}"
        );

        let e = parse_toml::<Outer>(p, "name = \"a\"\nlidar = []\nrange = 3\n").unwrap_err();
        assert!(e.message.contains("unknown field `range`"), "{e}");

        let e = parse_toml::<Outer>(p, "name = \n").unwrap_err();
        assert!(e.message.contains("syntax"), "{e}");
        assert_eq!(e.line, Some(1));
    }
}
