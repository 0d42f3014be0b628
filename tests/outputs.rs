//! No futago command deletes or overwrites what it did not write: an output folder or file of
//! a user's is refused before any work, `--force` replaces it, and the current folder, its
//! parents and a repository are refused whatever is asked.

mod common;
use common::*;
use std::path::{Path, PathBuf};
use std::process::Output;

/// A folder of a user's: a thesis and a data file in a subfolder.
fn users_folder(d: &Path) -> PathBuf {
    let p = d.join("precious");
    std::fs::create_dir_all(p.join("sub")).unwrap();
    std::fs::write(p.join("thesis.txt"), "years of work").unwrap();
    std::fs::write(p.join("sub/data.csv"), "1,2,3").unwrap();
    p
}

fn intact(p: &Path) {
    assert_eq!(
        std::fs::read_to_string(p.join("thesis.txt")).unwrap(),
        "years of work"
    );
    assert_eq!(
        std::fs::read_to_string(p.join("sub/data.csv")).unwrap(),
        "1,2,3"
    );
}

fn refused(o: &Output, expect: &[&str]) {
    assert!(!o.status.success(), "not refused");
    let err = String::from_utf8_lossy(&o.stderr);
    for e in expect {
        assert!(err.contains(e), "expected `{e}` in: {err}");
    }
}

#[test]
fn no_command_replaces_a_folder_or_file_of_a_users() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let p = users_folder(d);
    let precious = p.to_str().unwrap();
    let r = root();
    let tour = r.join("scenarios/office-tour.toml");
    let tour = tour.to_str().unwrap();
    let office = r.join("worlds/office.toml");
    let office = office.to_str().unwrap();
    let log = d.join("log.clf");
    std::fs::write(&log, "FLASER 3 1.0 1.0 1.0 0 0 0 0 0 0 2.0 h 2.0\n").unwrap();
    let shard = d.join("shard");
    std::fs::create_dir(&shard).unwrap();
    std::fs::write(
        shard.join("suite.json"),
        r#"{"results": [], "scenarios": 0, "wall_time_s": 0}"#,
    )
    .unwrap();
    let folder_commands: Vec<Vec<&str>> = vec![
        vec!["run", tour, "--duration", "1", "-q"],
        vec!["suite", tour],
        vec![
            "tune",
            tour,
            "--param",
            "slam.keyframe_distance=0.2..0.4",
            "--objective",
            "slam.ate.rmse_m",
            "--budget",
            "1",
        ],
        vec!["replay", log.to_str().unwrap()],
        vec!["merge", shard.to_str().unwrap()],
        vec!["world", "export", office],
        vec!["fuzz", "--inputs", "10"],
    ];
    for args in &folder_commands {
        let mut a = args.clone();
        a.extend(["--out", precious]);
        let o = futago_in(d, &a);
        refused(&o, &["precious", "futago did not write", "--force"]);
        intact(&p);
    }
    // Files written alone: a model and a world file (and its map copy).
    let mine = p.join("thesis.txt");
    let o = futago_in(
        d,
        &[
            "train-legs",
            r.join("scenarios/train-legs.toml").to_str().unwrap(),
            "--out",
            mine.to_str().unwrap(),
        ],
    );
    refused(&o, &["thesis.txt", "not a file futago wrote"]);
    intact(&p);
    let export = d.join("export");
    let o = futago_in(
        d,
        &["world", "export", office, "--out", export.to_str().unwrap()],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let map = export.join("office.yaml");
    let o = futago_in(
        d,
        &[
            "world",
            "from-map",
            map.to_str().unwrap(),
            "--out",
            mine.to_str().unwrap(),
        ],
    );
    refused(&o, &["thesis.txt", "not a file futago wrote"]);
    intact(&p);
    // With --force the folder goes, and it is futago's from then on.
    let o = futago_in(
        d,
        &["world", "export", office, "--out", precious, "--force"],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(!p.join("thesis.txt").exists());
    assert!(p.join("office.glb").is_file() && p.join(".futago-output.json").is_file());
    let o = futago_in(d, &["world", "export", office, "--out", precious]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // Until a file of the user's goes into it.
    std::fs::write(p.join("notes.txt"), "mine").unwrap();
    let o = futago_in(d, &["world", "export", office, "--out", precious]);
    refused(&o, &["notes.txt"]);
    assert!(p.join("notes.txt").is_file());
}

#[test]
fn the_current_folder_its_parents_and_repositories_are_refused_even_with_force() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path().join("work");
    std::fs::create_dir_all(d.join("repo/.git")).unwrap();
    std::fs::write(d.join("keep.txt"), "keep").unwrap();
    let office = root().join("worlds/office.toml");
    let office = office.to_str().unwrap();
    for out in [".", "..", d.to_str().unwrap(), "repo"] {
        let o = futago_in(&d, &["world", "export", office, "--out", out, "--force"]);
        refused(&o, &["even with --force"]);
    }
    assert!(d.join("keep.txt").is_file() && d.join("repo/.git").is_dir());
    let o = futago_in(&d, &["world", "export", office, "--out", "/", "--force"]);
    refused(&o, &["root"]);
}
