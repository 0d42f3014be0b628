//! The robot crate's groups form layers: each depends only on groups listed before it in
//! `lib.rs` (and on itself), so there are no cycles between concerns. The test reads every
//! source file's `crate::GROUP` paths (doc comments aside) and fails on a path that points up
//! or sideways, naming the file.

use std::path::{Path, PathBuf};

/// The groups in dependency order, as `lib.rs` lists them.
const LAYERS: [&str; 9] = [
    "config",
    "cores",
    "geometry",
    "perception",
    "tracking",
    "localization",
    "mapping",
    "control",
    "navigation",
];

fn sources(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            sources(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The group a file under `src` belongs to: its folder, or its name for a top-level file.
fn group_of(src: &Path, file: &Path) -> String {
    let rel = file.strip_prefix(src).unwrap();
    let first = rel
        .components()
        .next()
        .unwrap()
        .as_os_str()
        .to_string_lossy();
    first.trim_end_matches(".rs").to_string()
}

#[test]
fn groups_depend_only_on_groups_below_them() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    sources(&src, &mut files);
    files.sort();
    let rank = |g: &str| LAYERS.iter().position(|l| *l == g);
    let mut bad = Vec::new();
    let mut seen = 0;
    for f in &files {
        let g = group_of(&src, f);
        if g == "lib" {
            continue;
        }
        let Some(own) = rank(&g) else {
            bad.push(format!("{}: group `{g}` is not in LAYERS", f.display()));
            continue;
        };
        for line in std::fs::read_to_string(f).unwrap().lines() {
            if line.trim_start().starts_with("//") {
                continue;
            }
            for (i, _) in line.match_indices("crate::") {
                let rest = &line[i + "crate::".len()..];
                let dep: String = rest
                    .chars()
                    .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                    .collect();
                seen += 1;
                match rank(&dep) {
                    Some(r) if r <= own => {}
                    _ => bad.push(format!("{}: `{g}` uses `crate::{dep}`", f.display())),
                }
            }
        }
    }
    assert!(
        seen > 20,
        "found only {seen} crate paths: is the scan broken?"
    );
    assert!(bad.is_empty(), "{}", bad.join("\n"));
}

#[test]
fn lib_lists_the_groups_in_layer_order() {
    let lib =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("src/lib.rs")).unwrap();
    let mut order: Vec<&str> = lib
        .lines()
        .filter_map(|l| l.strip_prefix("//! - [`"))
        .filter_map(|l| l.split('`').next())
        .collect();
    order.dedup();
    assert_eq!(order, LAYERS);
}
