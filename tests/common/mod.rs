//! What the end-to-end tests share: running the command, and reading what it wrote.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// `futago ARGS` run in the repository's folder.
pub fn futago(args: &[&str]) -> Output {
    futago_in(Path::new(env!("CARGO_MANIFEST_DIR")), args)
}

/// `futago ARGS` run in `dir`.
pub fn futago_in(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_futago"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("futago runs")
}

/// The repository's folder.
pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Asserts that the command succeeded, showing its output when it did not.
pub fn ok(o: &Output) {
    assert!(
        o.status.success(),
        "futago failed:\nstdout: {}\nstderr: {}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
}

/// Writes `bytes` to `dir/name`; its path.
pub fn write(dir: &Path, name: &str, bytes: impl AsRef<[u8]>) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

pub fn json_file(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// The `summary.json` of the output folder `dir`.
pub fn summary(dir: &Path) -> serde_json::Value {
    json_file(&dir.join("summary.json"))
}
