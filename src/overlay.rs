//! Scenario overlays: changes laid over a scenario file before it is typed and checked, from an
//! overlay file (`--overlay best.toml`, a TOML table of the scenario's own keys, as `futago
//! tune` writes) or from one assignment (`--set slam.icp.max_distance_start=0.5`).
//!
//! Tables merge key by key, recursively; any other value, arrays included, replaces what the
//! scenario had. So an overlay names only what it changes, by the same dotted paths that
//! scenarios, sweeps and `futago tune` use. Errors in the merged scenario that come from an
//! overlay's key name the overlay, not the scenario file.

use futago_sim::config::{SpecError, read_text};
use std::path::{Path, PathBuf};

/// One set of changes to a scenario, and where it came from.
#[derive(Debug, Clone, PartialEq)]
pub struct Overlay {
    /// The overlay file, or `--set` for a command-line assignment.
    pub origin: PathBuf,
    pub table: toml::Table,
}

/// A dotted key path (`slam.icp.max_distance_start`) split into its keys, each checked to be a
/// bare TOML key: letters, digits, `_` and `-`.
pub fn split_path(path: &str) -> Result<Vec<&str>, String> {
    let keys: Vec<&str> = path.split('.').map(str::trim).collect();
    for k in &keys {
        if k.is_empty()
            || !k
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
        {
            let why = if k.contains('[') {
                "; arrays are replaced whole (e.g. controller.goals=[...]), not indexed"
            } else {
                ""
            };
            return Err(format!(
                "`{path}`: expected a dotted key path such as slam.icp.max_distance_start{why}"
            ));
        }
    }
    Ok(keys)
}

impl Overlay {
    /// Reads an overlay file: a TOML table of the scenario's keys.
    pub fn load(path: &Path) -> Result<Overlay, SpecError> {
        let text = read_text(path)?;
        let table: toml::Table = futago_sim::config::parse_toml(path, &text)?;
        if table.is_empty() {
            return Err(SpecError::new(
                path,
                "",
                "the overlay is empty: expected the scenario keys it changes, e.g. [slam] keyframe_distance = 0.2",
            ));
        }
        Ok(Overlay {
            origin: path.to_path_buf(),
            table,
        })
    }

    /// One value at a dotted key path.
    pub fn assign(path: &str, value: toml::Value) -> Result<Overlay, SpecError> {
        let set = || SpecError::new("--set", path, "");
        let keys = split_path(path).map_err(|m| SpecError {
            message: m,
            ..set()
        })?;
        let mut table = toml::Table::new();
        let (last, parents) = keys.split_last().expect("split gives one key at least");
        let mut at = &mut table;
        for k in parents {
            at = at
                .entry(k.to_string())
                .or_insert_with(|| toml::Value::Table(toml::Table::new()))
                .as_table_mut()
                .expect("a table was just inserted");
        }
        at.insert(last.to_string(), value);
        Ok(Overlay {
            origin: PathBuf::from("--set"),
            table,
        })
    }

    /// Parses `PATH=VALUE`, the value in TOML (`0.5`, `true`, `"icp"`, `[1, 2]`); a value that
    /// is not TOML is taken as a string, so that `slam.method=icp` works unquoted.
    pub fn parse_set(text: &str) -> Result<Overlay, SpecError> {
        let Some((path, value)) = text.split_once('=') else {
            return Err(SpecError::new(
                "--set",
                text,
                "expected PATH=VALUE, e.g. localization.mcl.particles=300",
            ));
        };
        let value = value.trim();
        if value.is_empty() {
            return Err(SpecError::new("--set", path.trim(), "the value is empty"));
        }
        let parsed = format!("v = {value}")
            .parse::<toml::Table>()
            .ok()
            .and_then(|mut t| t.remove("v"))
            .unwrap_or_else(|| toml::Value::String(value.to_string()));
        Overlay::assign(path.trim(), parsed)
    }

    /// Every leaf's dotted path, in the table's order.
    pub fn leaves(&self) -> Vec<String> {
        fn walk(t: &toml::Table, prefix: &str, out: &mut Vec<String>) {
            for (k, v) in t {
                let p = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                match v {
                    toml::Value::Table(inner) if !inner.is_empty() => walk(inner, &p, out),
                    _ => out.push(p),
                }
            }
        }
        let mut out = Vec::new();
        walk(&self.table, "", &mut out);
        out
    }

    /// Lays this overlay over `base`: tables merge, everything else replaces.
    pub fn apply(&self, base: &mut toml::Table) {
        fn merge(base: &mut toml::Table, over: &toml::Table) {
            for (k, v) in over {
                match (base.get_mut(k), v) {
                    (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge(b, o),
                    _ => {
                        base.insert(k.clone(), v.clone());
                    }
                }
            }
        }
        merge(base, &self.table);
    }

    /// Whether an error at `key` (as serde names it: `slam.icp.max_distance_start`,
    /// `lidar[0].noise`) lies on one of this overlay's paths.
    pub fn touches(&self, key: &str) -> bool {
        let key = key.split('[').next().unwrap_or(key);
        self.leaves().iter().any(|leaf| {
            key == leaf
                || key.starts_with(&format!("{leaf}."))
                || leaf.starts_with(&format!("{key}."))
        })
    }
}

/// The value at a dotted path of a table, if there is one.
pub fn lookup<'a>(table: &'a toml::Table, path: &str) -> Option<&'a toml::Value> {
    let keys = split_path(path).ok()?;
    let (last, parents) = keys.split_last()?;
    let mut at = table;
    for k in parents {
        at = at.get(*k)?.as_table()?;
    }
    at.get(*last)
}

/// Attributes an error in a merged scenario to the last overlay that set its key, if any.
pub fn blame(mut e: SpecError, overlays: &[Overlay]) -> SpecError {
    if let Some(o) = overlays.iter().rev().find(|o| o.touches(&e.key)) {
        e.file = o.origin.clone();
        e.line = None;
    }
    e
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table(text: &str) -> toml::Table {
        text.parse().unwrap()
    }

    #[test]
    fn tables_merge_and_other_values_replace() {
        let mut base = table(
            "name = 'a'\n[slam]\nmethod = 'graph'\n[slam.icp]\nmax_distance_start = 1.0\nmax_iterations = 30\n[controller]\ngoals = [1, 2, 3]\n",
        );
        let over = Overlay {
            origin: "o.toml".into(),
            table: table("[slam.icp]\nmax_distance_start = 0.5\n[controller]\ngoals = [4]\n"),
        };
        over.apply(&mut base);
        assert_eq!(
            lookup(&base, "slam.icp.max_distance_start"),
            Some(&toml::Value::Float(0.5))
        );
        assert_eq!(
            lookup(&base, "slam.icp.max_iterations"),
            Some(&toml::Value::Integer(30))
        );
        assert_eq!(
            lookup(&base, "slam.method"),
            Some(&toml::Value::String("graph".into()))
        );
        assert_eq!(
            lookup(&base, "controller.goals"),
            Some(&toml::Value::Array(vec![toml::Value::Integer(4)]))
        );
        assert_eq!(
            over.leaves(),
            vec!["controller.goals", "slam.icp.max_distance_start"]
        );
    }

    #[test]
    fn assignments_parse_toml_values_and_bare_strings() {
        let o = Overlay::parse_set("localization.mcl.particles=300").unwrap();
        assert_eq!(
            lookup(&o.table, "localization.mcl.particles"),
            Some(&toml::Value::Integer(300))
        );
        let o = Overlay::parse_set("slam.method = icp").unwrap();
        assert_eq!(
            lookup(&o.table, "slam.method"),
            Some(&toml::Value::String("icp".into()))
        );
        let o = Overlay::parse_set("seed=[1, 2]").unwrap();
        assert!(matches!(lookup(&o.table, "seed"), Some(toml::Value::Array(a)) if a.len() == 2));
        for bad in ["slam.method", "slam..method=icp", "lidar[0].noise=1", "x="] {
            let e = Overlay::parse_set(bad).unwrap_err();
            assert_eq!(e.file, PathBuf::from("--set"), "{bad}");
            assert!(!e.message.is_empty(), "{bad}");
        }
    }

    #[test]
    fn errors_are_blamed_on_the_overlay_that_set_the_key() {
        let o = Overlay::parse_set("slam.icp.max_distance_start=-1").unwrap();
        let e = blame(
            SpecError::new("s.toml", "slam.icp.max_distance_start", "bad"),
            std::slice::from_ref(&o),
        );
        assert_eq!(e.file, PathBuf::from("--set"));
        let e = blame(SpecError::new("s.toml", "slam.method", "bad"), &[o]);
        assert_eq!(e.file, PathBuf::from("s.toml"));
    }
}
