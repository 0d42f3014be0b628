//! The `futago` library's modules form layers (listed in `src/lib.rs`): each module uses only
//! the modules listed before it here, so there are no cycles. The test reads every source
//! file's `crate::MODULE` paths (comments aside) and fails on a path that points up or
//! sideways, naming the file; `src/main.rs`, the command, is above them all.

use std::path::{Path, PathBuf};

/// The library's top-level modules in dependency order, by layer.
const LAYERS: &[(&str, &[&str])] = &[
    ("scenario schema", &["gate", "overlay", "scenario"]),
    ("scoring", &["relations", "ground_truth"]),
    ("formats", &["picture", "rgbd", "output", "dds"]),
    ("bus, nodes and modules", &["stack"]),
    ("reports", &["report"]),
    (
        "applications",
        &[
            "config_walk",
            "cmaes",
            "parallel",
            "run",
            "serve",
            "export",
            "world_cmd",
            "replay",
            "legs_train",
            "calibrate",
            "twin",
            "crowd",
            "suite",
            "folds",
            "tune",
            "bench",
            "fuzz",
        ],
    ),
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

/// The top-level module a file under `src` belongs to: its folder, or its name.
fn module_of(src: &Path, file: &Path) -> String {
    let rel = file.strip_prefix(src).unwrap();
    let first = rel.components().next().unwrap().as_os_str();
    first.to_string_lossy().trim_end_matches(".rs").to_string()
}

/// Every module in order, with its rank.
fn order() -> Vec<&'static str> {
    LAYERS.iter().flat_map(|(_, m)| m.iter().copied()).collect()
}

/// The `crate::NAME` paths of a file's code lines.
fn uses(text: &str) -> Vec<String> {
    let mut found = Vec::new();
    for line in text.lines() {
        let code = line.split("//").next().unwrap_or("");
        for (i, _) in code.match_indices("crate::") {
            let rest = &code[i + "crate::".len()..];
            let dep: String = rest
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                .collect();
            found.push(dep);
        }
    }
    found
}

#[test]
fn modules_use_only_modules_below_them() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    sources(&src, &mut files);
    files.sort();
    let order = order();
    let rank = |m: &str| order.iter().position(|l| *l == m);
    let mut bad = Vec::new();
    let mut seen = 0;
    for f in &files {
        let m = module_of(&src, f);
        if m == "lib" || m == "main" {
            continue;
        }
        let Some(own) = rank(&m) else {
            bad.push(format!("{}: module `{m}` is not in LAYERS", f.display()));
            continue;
        };
        for dep in uses(&std::fs::read_to_string(f).unwrap()) {
            seen += 1;
            match rank(&dep) {
                Some(r) if r <= own => {}
                _ => bad.push(format!("{}: `{m}` uses `crate::{dep}`", f.display())),
            }
        }
    }
    assert!(
        seen > 50,
        "only {seen} crate paths found: is the scan broken?"
    );
    assert!(
        bad.is_empty(),
        "uses against the layers:\n{}",
        bad.join("\n")
    );
}

/// `lib.rs` declares exactly the modules of LAYERS, so the two cannot drift.
#[test]
fn lib_declares_the_modules_of_the_layers() {
    let lib =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("src/lib.rs")).unwrap();
    let mut declared: Vec<String> = lib
        .lines()
        .filter_map(|l| {
            let l = l.trim();
            let l = l.strip_prefix("pub ").unwrap_or(l);
            l.strip_prefix("mod ")?
                .strip_suffix(';')
                .map(str::to_string)
        })
        .collect();
    declared.sort();
    let mut listed = order();
    listed.sort();
    assert_eq!(declared, listed);
}

/// The scan sees the uses it must judge: a path up the layers is caught, a comment is not.
#[test]
fn the_scan_finds_paths_and_skips_comments() {
    let text =
        "use crate::run::Outcome; // crate::fuzz\n// crate::tune\nlet x = crate::gate::similar;";
    assert_eq!(uses(text), ["run", "gate"]);
}
