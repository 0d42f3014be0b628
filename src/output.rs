//! Output folders and files that are futago's own, so that no command deletes or overwrites
//! what a user keeps there.
//!
//! Every folder a command writes gets a marker, [`MARKER`], listing the files the command
//! wrote (paths relative to the folder). A command replaces an existing output folder only
//! when every file in it is listed by the marker of the folder or of a subfolder (a suite's
//! runs carry their own), when it is empty, or when it is a folder of an earlier futago that
//! wrote no marker but is recognised by its `summary.json`, `suite.json` or `tune.json`.
//! Anything else is refused before any work is done, naming the folder and what it holds;
//! `--force` overrides that, but never for `/`, the home folder, the current folder or one
//! of its parents, or a folder holding a `.git`: those are refused whatever is asked.
//!
//! Files written alone (a model, a world file) are replaced only when they are recognisably
//! futago's (their own header or schema), or with `--force`.

use anyhow::{Context, Result, bail};
use serde_json::{Value, json};
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// The marker file of an output folder: JSON naming the command that wrote the folder and
/// every file it wrote.
pub const MARKER: &str = ".futago-output.json";

/// Files of a foreign folder named in a refusal; the rest are counted.
const SHOWN: usize = 5;

/// Folders that no command writes into or replaces, `--force` or not: `/`, the home folder,
/// the current folder and its parents, and any folder holding a `.git`.
fn refuse_protected(out: &Path) -> Result<()> {
    let Ok(abs) = std::fs::canonicalize(out) else {
        // Not there yet (or unreadable, which the write will report): nothing to lose.
        return Ok(());
    };
    if abs.parent().is_none() {
        bail!(
            "{}: refusing to write into the file system's root; choose a new folder for --out",
            out.display()
        );
    }
    if let Some(home) = std::env::var_os("HOME").and_then(|h| std::fs::canonicalize(h).ok())
        && home == abs
    {
        bail!(
            "{}: refusing to write into the home folder, even with --force; choose a new folder for --out",
            out.display()
        );
    }
    if let Ok(cwd) = std::env::current_dir().and_then(std::fs::canonicalize)
        && cwd.ancestors().any(|a| a == abs)
    {
        bail!(
            "{}: refusing to write into the current folder or one of its parents, even with --force; choose a new folder for --out",
            out.display()
        );
    }
    if abs.is_dir() && std::fs::symlink_metadata(abs.join(".git")).is_ok() {
        bail!(
            "{}: holds a .git (a repository); refusing to write into it, even with --force; choose a new folder for --out",
            out.display()
        );
    }
    Ok(())
}

/// Checks, before any work, that a command may create or replace the folder `out`: it is
/// absent, empty or futago's own (see the module's doc), or `force` is given and it is not a
/// protected folder.
pub fn check_folder(out: &Path, force: bool) -> Result<()> {
    refuse_protected(out)?;
    let meta = match std::fs::symlink_metadata(out) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(e).with_context(|| format!("reading {}", out.display())),
        Ok(m) => m,
    };
    if force {
        return Ok(());
    }
    if !meta.is_dir() {
        bail!(
            "{}: is {}, not a folder futago wrote; choose another --out, or pass --force to replace it",
            out.display(),
            if meta.file_type().is_symlink() {
                "a symbolic link"
            } else {
                "a file"
            }
        );
    }
    let foreign = foreign_files(out)?;
    if foreign.is_empty() {
        return Ok(());
    }
    let more = foreign.len().saturating_sub(SHOWN);
    bail!(
        "{}: holds files futago did not write ({}{}); refusing to replace it. Choose another --out, or pass --force to replace the folder and everything in it",
        out.display(),
        foreign
            .iter()
            .take(SHOWN)
            .map(String::as_str)
            .collect::<Vec<_>>()
            .join(", "),
        if more > 0 {
            format!(" and {more} more")
        } else {
            String::new()
        }
    )
}

/// The files under `dir` (relative paths) that no marker lists, in sorted order; empty for a
/// folder of an earlier futago recognised by its summary.
pub fn foreign_files(dir: &Path) -> Result<Vec<String>> {
    let mut out = Vec::new();
    let own = read_marker(dir);
    if own.is_none() && written_by_earlier_futago(dir) {
        return Ok(out);
    }
    walk(dir, "", "", own.as_ref(), &mut out)?;
    out.sort();
    Ok(out)
}

/// Adds to `out` the files under `dir` that `listed` (the paths its marker's folder lists,
/// `inner` being `dir`'s path relative to that folder) does not name; `shown` is `dir`'s path
/// as reported.
fn walk(
    dir: &Path,
    shown: &str,
    inner: &str,
    listed: Option<&BTreeSet<String>>,
    out: &mut Vec<String>,
) -> Result<()> {
    let entries = std::fs::read_dir(dir).with_context(|| format!("listing {}", dir.display()))?;
    for e in entries {
        let e = e.with_context(|| format!("listing {}", dir.display()))?;
        let name = e.file_name().to_string_lossy().to_string();
        let (show, rel) = (format!("{shown}{name}"), format!("{inner}{name}"));
        if is_partial(&name) {
            // What a futago command was writing when it stopped (a crash, a kill).
            continue;
        }
        let ty = e
            .file_type()
            .with_context(|| format!("reading {}", e.path().display()))?;
        if ty.is_dir() {
            match read_marker(&e.path()) {
                // A folder of its own (a suite's run): its marker speaks for it.
                Some(own) => walk(&e.path(), &format!("{show}/"), "", Some(&own), out)?,
                // A run of an earlier futago inside a folder that futago wrote.
                None if listed.is_some() && written_by_earlier_futago(&e.path()) => {}
                None => walk(
                    &e.path(),
                    &format!("{show}/"),
                    &format!("{rel}/"),
                    listed,
                    out,
                )?,
            }
        } else if inner.is_empty() && name == MARKER {
            // The marker itself.
        } else if !listed.is_some_and(|l| l.contains(&rel)) {
            out.push(show);
        }
    }
    Ok(())
}

/// Whether `name` is a folder or file that a futago command writes before renaming it into
/// place (`.NAME.partial-PID`, `.NAME.partial`): left behind only by a command that crashed.
pub fn is_partial(name: &str) -> bool {
    name.starts_with('.') && (name.contains(".partial-") || name.ends_with(".partial"))
}

/// Removes what crashed commands left half-written in `dir` (see [`is_partial`]).
pub fn remove_partials(dir: &Path) {
    for e in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        if is_partial(&e.file_name().to_string_lossy()) {
            let p = e.path();
            let _ = if p.is_dir() {
                std::fs::remove_dir_all(&p)
            } else {
                std::fs::remove_file(&p)
            };
        }
    }
}

/// The files listed by `dir`'s marker, or `None` when it has none (or one that does not read).
fn read_marker(dir: &Path) -> Option<BTreeSet<String>> {
    let text = std::fs::read_to_string(dir.join(MARKER)).ok()?;
    let v: Value = serde_json::from_str(&text).ok()?;
    let files = v.get("files")?.as_array()?;
    Some(
        files
            .iter()
            .filter_map(|f| f.as_str().map(str::to_string))
            .collect(),
    )
}

/// A folder that futago wrote before markers existed: a run's `summary.json` (with the SHA-256
/// of its files), a replay's (its log and SLAM method), a suite's `suite.json` or a search's
/// `tune.json`.
fn written_by_earlier_futago(dir: &Path) -> bool {
    let read = |name: &str| -> Option<Value> {
        serde_json::from_str(&std::fs::read_to_string(dir.join(name)).ok()?).ok()
    };
    let summary = read("summary.json").is_some_and(|v| {
        let run = v.get("files").is_some_and(Value::is_object) && v.get("scenario").is_some();
        let replay = v.get("log").is_some_and(Value::is_string)
            && v.get("slam").is_some_and(Value::is_string);
        run || replay
    });
    let suite = read("suite.json").is_some_and(|v| {
        v.get("results").is_some_and(Value::is_array) && v.get("scenarios").is_some()
    });
    let tune = read("tune.json")
        .is_some_and(|v| v.get("objective").is_some() && v.get("trials").is_some());
    summary || suite || tune
}

/// Every file under `dir` (relative paths, sorted), but markers and the folders that carry
/// their own.
fn files_under(dir: &Path, prefix: &str, out: &mut Vec<String>) -> Result<()> {
    for e in std::fs::read_dir(dir).with_context(|| format!("listing {}", dir.display()))? {
        let e = e.with_context(|| format!("listing {}", dir.display()))?;
        let name = e.file_name().to_string_lossy().to_string();
        let rel = format!("{prefix}{name}");
        if is_partial(&name) {
            continue;
        }
        if e.file_type()?.is_dir() {
            if !e.path().join(MARKER).is_file() {
                files_under(&e.path(), &format!("{rel}/"), out)?;
            }
        } else if name != MARKER {
            out.push(rel);
        }
    }
    Ok(())
}

/// Writes `dir`'s marker: `command` wrote every file now in it (but the subfolders with
/// markers of their own).
pub fn mark(dir: &Path, command: &str) -> Result<()> {
    let mut files = Vec::new();
    files_under(dir, "", &mut files)?;
    files.sort();
    let v = json!({
        "what": "a folder written by futago, which may replace it whole; a file not listed here keeps it from doing so",
        "command": command,
        "files": files,
    });
    let path = dir.join(MARKER);
    let tmp = dir.join(format!("{MARKER}.partial"));
    std::fs::write(&tmp, serde_json::to_string_pretty(&v)? + "\n")
        .with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, &path).with_context(|| format!("writing {}", path.display()))
}

/// Checks, before any work, that a command may write the file `path`: it is absent, or
/// `is_ours` recognises its bytes as futago's, or `force` is given.
pub fn check_file(path: &Path, force: bool, is_ours: impl Fn(&[u8]) -> bool) -> Result<()> {
    let meta = match std::fs::symlink_metadata(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(e).with_context(|| format!("reading {}", path.display())),
        Ok(m) => m,
    };
    if meta.is_dir() {
        bail!(
            "{}: is a folder; expected the name of a file to write",
            path.display()
        );
    }
    if force {
        return Ok(());
    }
    let ours = meta.is_file() && std::fs::read(path).map(|b| is_ours(&b)).unwrap_or(false);
    if !ours {
        bail!(
            "{}: exists and is not a file futago wrote; refusing to overwrite it. Choose another name, or pass --force to replace it",
            path.display()
        );
    }
    Ok(())
}

/// The folder beside which a temporary folder for `out` is made.
pub fn parent_of(out: &Path) -> PathBuf {
    match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn user_folder(root: &Path) -> PathBuf {
        let d = root.join("precious");
        std::fs::create_dir_all(d.join("sub")).unwrap();
        std::fs::write(d.join("thesis.txt"), "years of work").unwrap();
        std::fs::write(d.join("sub/data.csv"), "1,2,3").unwrap();
        d
    }

    #[test]
    fn a_users_folder_is_refused_and_named() {
        let tmp = tempfile::tempdir().unwrap();
        let d = user_folder(tmp.path());
        let e = format!("{:#}", check_folder(&d, false).unwrap_err());
        assert!(e.contains("precious"), "{e}");
        assert!(
            e.contains("sub/data.csv") && e.contains("thesis.txt"),
            "{e}"
        );
        assert!(e.contains("--force"), "{e}");
        check_folder(&d, true).unwrap();
        // Absent and empty folders are fine.
        check_folder(&tmp.path().join("new"), false).unwrap();
        std::fs::create_dir(tmp.path().join("empty")).unwrap();
        check_folder(&tmp.path().join("empty"), false).unwrap();
    }

    #[test]
    fn a_marked_folder_is_futagos_until_a_user_adds_a_file() {
        let tmp = tempfile::tempdir().unwrap();
        let d = tmp.path().join("run");
        std::fs::create_dir_all(d.join("kinect/rgb")).unwrap();
        std::fs::write(d.join("summary.json"), "{}").unwrap();
        std::fs::write(d.join("kinect/rgb/0.png"), "png").unwrap();
        mark(&d, "run").unwrap();
        check_folder(&d, false).unwrap();
        std::fs::write(d.join("kinect/notes.txt"), "mine").unwrap();
        let e = format!("{:#}", check_folder(&d, false).unwrap_err());
        assert!(e.contains("kinect/notes.txt"), "{e}");
        assert!(!e.contains("0.png"), "{e}");
    }

    #[test]
    fn a_suite_folder_is_judged_by_its_runs_markers() {
        let tmp = tempfile::tempdir().unwrap();
        let s = tmp.path().join("suite");
        std::fs::create_dir_all(s.join("a")).unwrap();
        std::fs::write(s.join("a/summary.json"), "{}").unwrap();
        mark(&s.join("a"), "run").unwrap();
        std::fs::write(s.join("suite.json"), "{}").unwrap();
        mark(&s, "suite").unwrap();
        let listed = read_marker(&s).unwrap();
        assert_eq!(listed.into_iter().collect::<Vec<_>>(), ["suite.json"]);
        check_folder(&s, false).unwrap();
        std::fs::write(s.join("a/mine.txt"), "x").unwrap();
        assert!(check_folder(&s, false).is_err());
    }

    #[test]
    fn protected_folders_are_refused_even_with_force() {
        let tmp = tempfile::tempdir().unwrap();
        let repo = tmp.path().join("repo");
        std::fs::create_dir_all(repo.join(".git")).unwrap();
        let e = format!("{:#}", check_folder(&repo, true).unwrap_err());
        assert!(e.contains(".git"), "{e}");
        let cwd = std::env::current_dir().unwrap();
        assert!(check_folder(&cwd, true).is_err());
        assert!(check_folder(Path::new("."), true).is_err());
        assert!(check_folder(Path::new("/"), true).is_err());
        if let Some(parent) = cwd.parent() {
            assert!(check_folder(parent, true).is_err());
        }
    }

    #[test]
    fn a_folder_of_an_earlier_futago_is_recognised_by_its_summary() {
        let tmp = tempfile::tempdir().unwrap();
        let d = tmp.path().join("old");
        std::fs::create_dir_all(&d).unwrap();
        std::fs::write(d.join("groundtruth.txt"), "").unwrap();
        std::fs::write(d.join("summary.json"), r#"{"files": {"a": "b"}}"#).unwrap();
        // Without the key a run's summary has, it is anyone's summary.json.
        assert!(check_folder(&d, false).is_err());
        std::fs::write(
            d.join("summary.json"),
            r#"{"scenario": "x", "files": {"a": "b"}}"#,
        )
        .unwrap();
        check_folder(&d, false).unwrap();
        // A replay's.
        std::fs::write(
            d.join("summary.json"),
            r#"{"log": "x.bag", "slam": "graph"}"#,
        )
        .unwrap();
        check_folder(&d, false).unwrap();
    }

    #[test]
    fn files_are_replaced_only_when_recognised() {
        let tmp = tempfile::tempdir().unwrap();
        let f = tmp.path().join("legs.json");
        let ours = |b: &[u8]| b.starts_with(b"futago");
        check_file(&f, false, ours).unwrap();
        std::fs::write(&f, "someone's").unwrap();
        let e = format!("{:#}", check_file(&f, false, ours).unwrap_err());
        assert!(e.contains("legs.json") && e.contains("--force"), "{e}");
        check_file(&f, true, ours).unwrap();
        std::fs::write(&f, "futago model").unwrap();
        check_file(&f, false, ours).unwrap();
        assert!(check_file(tmp.path(), true, ours).is_err());
    }
}
