//! A crash in one run of a suite costs only that run: with `--isolate` (or after a suite that
//! crashed in the same folder) each scenario runs in a process of its own, and a run that
//! aborts is that run's error in suite.json and JUnit, every other result kept.

mod common;
use common::root;
use std::path::Path;
use std::process::{Command, Output};

fn futago(args: &[&str], crash: Option<&str>) -> Output {
    futago_crashing_once(args, crash, None)
}

/// `futago ARGS`, with the run of scenario `crash` aborting: every time, or only the first
/// time when `once` names the flag file that records the crash.
fn futago_crashing_once(args: &[&str], crash: Option<&str>, once: Option<&Path>) -> Output {
    let mut c = Command::new(env!("CARGO_BIN_EXE_futago"));
    c.args(args).current_dir(env!("CARGO_MANIFEST_DIR"));
    if let Some(name) = crash {
        c.env("FUTAGO_CRASH_RUN", name);
    }
    if let Some(flag) = once {
        c.env("FUTAGO_CRASH_ONCE", flag);
    }
    c.output().expect("futago runs")
}

/// Three short scenarios in `dir`: a, b and c, two seconds each in the lab.
fn scenarios(dir: &Path) {
    std::fs::create_dir_all(dir).unwrap();
    let world = root().join("worlds/lab.toml");
    for name in ["a", "b", "c"] {
        std::fs::write(
            dir.join(format!("{name}.toml")),
            format!(
                "name = \"{name}\"\nworld = {world:?}\nduration = 2.0\nstart = \"centre\"\n\
                 [controller]\ntype = \"segments\"\nsegments = [{{ duration = 2.0, velocity = 0.2 }}]\n"
            ),
        )
        .unwrap();
    }
}

fn suite_json(out: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("suite.json")).unwrap()).unwrap()
}

#[test]
fn a_crashed_run_is_that_runs_error_and_the_others_are_kept() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("s");
    scenarios(&dir);
    let out = tmp.path().join("out");
    let args = [
        "suite",
        dir.to_str().unwrap(),
        "--jobs",
        "2",
        "--isolate",
        "--set",
        "duration=1.0",
        "--out",
        out.to_str().unwrap(),
    ];
    let o = futago(&args, Some("b"));
    assert_eq!(
        o.status.code(),
        Some(1),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let s = suite_json(&out);
    let by_name = |n: &str| {
        s["results"]
            .as_array()
            .unwrap()
            .iter()
            .find(|r| r["scenario"] == n)
            .unwrap()
            .clone()
    };
    let b = by_name("b");
    assert_eq!(b["status"], "error");
    assert!(
        b["error"]
            .as_str()
            .unwrap()
            .contains("crashed (signal 6, SIGABRT"),
        "{b}"
    );
    // It crashed on its try and on its retry (each after creating its temporary folder), and
    // neither left that folder behind.
    assert!(
        b["error"].as_str().unwrap().contains("on each of 2 tries"),
        "{b}"
    );
    assert_eq!(
        String::from_utf8_lossy(&o.stderr)
            .matches("run b crashed")
            .count(),
        1,
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let left: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
        .filter(|n| n.contains(".partial"))
        .collect();
    assert!(left.is_empty(), "{left:?}");
    for n in ["a", "c"] {
        let r = by_name(n);
        assert_eq!(r["status"], "passed", "{r}");
        // The overlay reached the child: one simulated second.
        assert!(
            (r["sim_time_s"].as_f64().unwrap() - 1.0).abs() < 0.05,
            "{r}"
        );
        assert!(out.join(n).join("summary.json").is_file());
    }
    assert!(!out.join("b").exists());
    let junit = std::fs::read_to_string(out.join("junit.xml")).unwrap();
    assert!(junit.contains("SIGABRT"), "{junit}");
    // The same suite in the same process: the crash would take every result with it, which
    // the folder's flag shows to the next suite, which then isolates by itself.
    let same = [
        "suite",
        dir.to_str().unwrap(),
        "--jobs",
        "2",
        "--set",
        "duration=1.0",
        "--out",
    ];
    let out2 = tmp.path().join("out2");
    let mut a = same.to_vec();
    a.push(out2.to_str().unwrap());
    let o = futago(&a, Some("b"));
    assert!(
        o.status.code().is_none(),
        "the crash did not take the suite down"
    );
    assert!(!out2.join("suite.json").exists());
    let o = futago(&a, Some("b"));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("ended without writing its results"), "{err}");
    assert_eq!(suite_json(&out2)["errors"], 1);
    assert_eq!(suite_json(&out2)["passed"], 2);
    assert!(!out2.join(".suite-running").exists());
}

#[test]
fn a_run_that_crashes_once_is_run_again_and_its_results_are_those_of_a_clean_run() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("s");
    scenarios(&dir);
    let run = |out: &Path, once: Option<&Path>| {
        futago_crashing_once(
            &[
                "suite",
                dir.to_str().unwrap(),
                "--jobs",
                "2",
                "--isolate",
                "--set",
                "duration=1.0",
                "--out",
                out.to_str().unwrap(),
            ],
            once.map(|_| "b"),
            once,
        )
    };
    let flag = tmp.path().join("crashed-once");
    let out = tmp.path().join("out");
    let o = run(&out, Some(&flag));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(0), "{err}");
    assert!(flag.exists(), "the first try did not crash: {err}");
    assert!(
        err.contains("run b crashed (signal 6, SIGABRT") && err.contains("running it again"),
        "{err}"
    );
    assert!(err.contains("run b completed on try 2"), "{err}");
    let s = suite_json(&out);
    assert_eq!(s["passed"], 3);
    let b = s["results"]
        .as_array()
        .unwrap()
        .iter()
        .find(|r| r["scenario"] == "b")
        .unwrap();
    let crashes = b["crashes"].as_array().unwrap();
    assert_eq!(crashes.len(), 1, "{b}");
    assert!(
        crashes[0]
            .as_str()
            .unwrap()
            .starts_with("signal 6, SIGABRT"),
        "{b}"
    );
    // The retry's files are byte for byte those of a suite in which nothing crashed.
    let clean = tmp.path().join("clean");
    let o = run(&clean, None);
    assert_eq!(o.status.code(), Some(0));
    for f in ["groundtruth.txt", "odometry.txt", "scans.clf"] {
        let a = std::fs::read(out.join("b").join(f)).unwrap();
        let c = std::fs::read(clean.join("b").join(f)).unwrap();
        assert!(a == c, "b/{f} differs after the retry");
    }
}
