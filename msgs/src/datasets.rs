//! Where the real logs that futago's accuracy tests replay are found, and what to do when
//! they are not there.
//!
//! The logs are public but large, so the repository does not carry them. They are looked up
//! in the folder named by the environment variable [`DATA_ENV`] (`FUTAGO_DATA`), laid out as
//! the repository's [`LIST`] (`datasets.sha256`) names them, or else in `../shared/datasets`
//! beside the repository where that exists. A test that needs a log that is absent says so in
//! one line (which file, where it looked, where to get it and its SHA-256, from the list) and
//! passes without checking anything, unless [`REQUIRE_ENV`] (`FUTAGO_REQUIRE_DATA=1`) is set,
//! as CI sets it: then the absence fails the test.

use std::path::{Path, PathBuf};

/// The environment variable naming the data folder.
pub const DATA_ENV: &str = "FUTAGO_DATA";
/// The environment variable that makes a missing log a failure (`1`).
pub const REQUIRE_ENV: &str = "FUTAGO_REQUIRE_DATA";

/// The list of the logs, in the repository's folder: `sha256sum` lines, with comments
/// `# from FOLDER/: SOURCE` saying where each folder's files come from.
pub const LIST: &str = "datasets.sha256";

/// What `list` (the text of [`LIST`]) says of the file `path`: its SHA-256 and its source.
fn described(list: &str, path: &str) -> Option<(String, String)> {
    let sha = list.lines().find_map(|l| {
        let (sha, p) = l.split_once("  ")?;
        (p.trim() == path && !l.starts_with('#')).then(|| sha.to_string())
    })?;
    let source = list
        .lines()
        .filter_map(|l| l.strip_prefix("# from ")?.split_once(": "))
        .find(|(folder, _)| path.starts_with(folder))
        .map(|(_, s)| s.to_string())
        .unwrap_or_default();
    Some((sha, source))
}

/// The data folder: `FUTAGO_DATA`, or `../shared/datasets` from `repo_root` where it
/// exists; `None` when neither is set or there.
pub fn folder(repo_root: &Path) -> Option<PathBuf> {
    match std::env::var_os(DATA_ENV) {
        Some(d) if !d.is_empty() => Some(PathBuf::from(d)),
        _ => Some(repo_root.join("../shared/datasets")).filter(|d| d.is_dir()),
    }
}

/// The files `paths` (relative to the data folder) for the test `test`, or `None` when one is
/// missing, after printing which test is skipped, what it needs and how to get it. With
/// `FUTAGO_REQUIRE_DATA=1` a missing file panics (the test fails) instead.
pub fn require(repo_root: &Path, test: &str, paths: &[&str]) -> Option<Vec<PathBuf>> {
    let dir = folder(repo_root);
    let found: Vec<PathBuf> = paths
        .iter()
        .filter_map(|p| dir.as_ref().map(|d| d.join(p)).filter(|f| f.is_file()))
        .collect();
    if found.len() == paths.len() {
        return Some(found);
    }
    let list = std::fs::read_to_string(repo_root.join(LIST)).unwrap_or_default();
    let missing: Vec<String> = paths
        .iter()
        .filter(|p| !dir.as_ref().is_some_and(|d| d.join(p).is_file()))
        .map(|p| match described(&list, p) {
            Some((sha, source)) => format!("{p} (SHA-256 {sha}; from {source})"),
            None => p.to_string(),
        })
        .collect();
    let where_ = match &dir {
        Some(d) => format!("in {}", d.display()),
        None => format!(
            "({DATA_ENV} is not set and {} does not exist)",
            repo_root.join("../shared/datasets").display()
        ),
    };
    let line = format!(
        "skipped {test}: needs {} {where_}; put the files in a folder and set {DATA_ENV} to it",
        missing.join(", ")
    );
    if std::env::var(REQUIRE_ENV).is_ok_and(|v| v == "1") {
        panic!("{line} ({REQUIRE_ENV}=1 makes this a failure)");
    }
    // Straight to stderr: the test harness shows a passing test's printed output only when
    // asked (`--nocapture`), and the skip must be seen.
    use std::io::Write;
    let _ = writeln!(std::io::stderr(), "{line}");
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_list_gives_each_file_its_digest_and_source() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let list = std::fs::read_to_string(root.join(LIST)).unwrap();
        let files: Vec<&str> = list
            .lines()
            .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
            .collect();
        assert_eq!(files.len(), 8);
        for l in files {
            let (sha, path) = l.split_once("  ").unwrap();
            assert_eq!(sha.len(), 64, "{l}");
            assert!(sha.chars().all(|c| c.is_ascii_hexdigit()), "{l}");
            let (s, source) = described(&list, path).unwrap();
            assert_eq!(s, sha);
            assert!(source.contains("benchmark"), "{path}: {source}");
        }
        assert!(described(&list, "people/other.bag").is_none());
    }
}
