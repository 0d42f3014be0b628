//! `futago folds`: leave-one-log-out over logs made here, a robot driving round a room whose
//! odometry over-turns, with relations from the true drive.

use futago_msgs::{Pose2, wrap_angle};
mod common;
use common::*;
use std::path::{Path, PathBuf};

/// Scans a log, 10 Hz.
const SCANS: usize = 150;

/// The true pose at scan `k` of drive `d`: an ellipse round the room's centre, each drive
/// its own size and direction.
fn truth(d: usize, k: usize) -> Pose2 {
    let (a, b, dir) = [(1.6, 1.0, 1.0), (1.4, 0.9, -1.0), (1.8, 1.1, 1.0)][d];
    let u = dir * 2.0 * std::f64::consts::PI * k as f64 / SCANS as f64;
    let (x, y) = (a * u.cos(), b * u.sin());
    let (dx, dy) = (-a * u.sin() * dir, b * u.cos() * dir);
    Pose2::new(x, y, dy.atan2(dx))
}

/// Writes drive `d` as a CARMEN log whose odometry over-turns by `turn` and over-counts the
/// distance by `scale`, and its relations (each scan to the one 10 scans on) from the truth.
fn write_log(dir: &Path, d: usize, turn: f64, scale: f64) -> (PathBuf, PathBuf) {
    let mut log = String::new();
    let mut relations = String::new();
    let mut odo = Pose2::IDENTITY;
    for k in 0..SCANS {
        let p = truth(d, k);
        if k > 0 {
            let step = truth(d, k - 1).between(&p);
            odo = odo.compose(&Pose2::new(
                step.x * scale,
                step.y * scale,
                step.theta * turn,
            ));
        }
        let inc = std::f64::consts::PI / 180.0;
        let ranges: Vec<f32> = (0..181)
            .map(|b| room_cast(p, -std::f64::consts::FRAC_PI_2 + b as f64 * inc))
            .collect();
        let t = 1.0 + k as f64 / 10.0;
        log += &flaser_line(&ranges, odo, t);
        if k + 10 < SCANS {
            let r = p.between(&truth(d, k + 10));
            relations += &format!(
                "{t} {} {} {} 0 0 0 {}\n",
                t + 1.0,
                r.x,
                r.y,
                wrap_angle(r.theta)
            );
        }
    }
    (
        write(dir, &format!("drive{d}.clf"), log),
        write(dir, &format!("drive{d}.relations"), relations),
    )
}

/// Scan matching beats odometry that over-turns on every log, so leave-one-log-out keeps it
/// whichever value is called neutral; and each log's error under the base configuration is
/// the one `futago replay` reports for it.
#[test]
fn leave_one_log_out_keeps_what_every_fold_wants_and_scores_as_replay_does() {
    let tmp = tempfile::tempdir().unwrap();
    let logs: Vec<(PathBuf, PathBuf)> = [(1.06, 1.02), (1.08, 0.98), (0.93, 1.03)]
        .iter()
        .enumerate()
        .map(|(d, (turn, scale))| write_log(tmp.path(), d, *turn, *scale))
        .collect();
    // The base configuration's matches may correct 0.5 m; 1 mm refuses nearly all of them.
    let choices = write(
        tmp.path(),
        "choices.toml",
        r#"
[[choice]]
name = "scan matching, called off when neutral"
key = "max_correction"
values = [0.001, 0.5]
neutral = 0.001

[[choice]]
name = "scan matching, neutral"
key = "max_correction"
values = [0.5, 0.001]
neutral = 0.5
"#,
    );
    let out = tmp.path().join("folds");
    let mut args = vec![
        "folds".to_string(),
        choices.display().to_string(),
        "--out".into(),
        out.display().to_string(),
        "--jobs".into(),
        "2".into(),
        // One run per configuration and log, so that its error is replay's.
        "--perturb".into(),
        "0".into(),
    ];
    for (log, rel) in &logs {
        args.extend([
            "--log".into(),
            log.display().to_string(),
            "--relations".into(),
            rel.display().to_string(),
        ]);
    }
    let o = futago(&args.iter().map(String::as_str).collect::<Vec<_>>());
    ok(&o);
    let f = json_file(&out.join("folds.json"));
    assert_eq!(f["keyframe_spacing_factors"], serde_json::json!([1.0]));
    let kept = |c: usize| {
        let c = &f["choices"][c];
        c["values"][c["verdict"]["kept"].as_u64().unwrap() as usize].as_f64()
    };
    assert_eq!(kept(0), Some(0.5), "{}", f["choices"][0]);
    assert_eq!(kept(1), Some(0.5), "{}", f["choices"][1]);
    for fold in f["choices"][0]["verdict"]["folds"].as_array().unwrap() {
        assert_eq!(fold["holds"], true, "{fold}");
        assert!(fold["change"].as_f64().unwrap() < -0.5, "{fold}");
    }
    // Called neutral, scan matching is what every fold chooses: refusing it is never chosen.
    for fold in f["choices"][1]["verdict"]["folds"].as_array().unwrap() {
        assert_eq!(fold["chosen"], 0, "{fold}");
    }
    // Nothing differs from the base configuration.
    let chosen = std::fs::read_to_string(out.join("chosen.toml")).unwrap();
    assert!(!chosen.contains("max_correction"), "{chosen}");
    assert!(String::from_utf8_lossy(&o.stdout).contains("| held out |"));
    for (l, (log, rel)) in logs.iter().enumerate() {
        let dir = tmp.path().join(format!("replay{l}"));
        ok(&futago(&[
            "replay",
            log.to_str().unwrap(),
            "--relations",
            rel.to_str().unwrap(),
            "--out",
            dir.to_str().unwrap(),
        ]));
        let s = summary(&dir);
        // Replay also reports how many loop closures the final graph holds to within 20 cm
        // and 1°; the drive is one lap, so every held closure counts.
        let p = &s["loop_closure_precision"];
        assert!(
            p["held"].as_u64().unwrap() <= p["constraints"].as_u64().unwrap(),
            "{p}"
        );
        assert_eq!(p["precision"].is_null(), p["constraints"] == 0, "{p}");
        assert_eq!(
            f["base"][l]["all_m"].as_f64(),
            s["relations"]["slam"]["abs_trans_m"]["mean"].as_f64(),
            "log {l}"
        );
    }
}

/// A choice file's mistakes and a log without its relations are errors that name them, before
/// anything runs.
#[test]
fn a_bad_choice_file_or_a_log_without_relations_is_named() {
    let tmp = tempfile::tempdir().unwrap();
    let (log, rel) = write_log(tmp.path(), 0, 1.0, 1.0);
    let (log2, rel2) = write_log(tmp.path(), 1, 1.0, 1.0);
    let run = |choices: &str, pairs: &[(&Path, Option<&Path>)]| {
        let file = write(tmp.path(), "c.toml", choices);
        let mut args = vec!["folds".to_string(), file.display().to_string()];
        args.extend(["--out".into(), tmp.path().join("o").display().to_string()]);
        for (l, r) in pairs {
            args.extend(["--log".into(), l.display().to_string()]);
            if let Some(r) = r {
                args.extend(["--relations".into(), r.display().to_string()]);
            }
        }
        let o = futago(&args.iter().map(String::as_str).collect::<Vec<_>>());
        assert!(!o.status.success());
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    let good =
        "[[choice]]\nname = \"m\"\nkey = \"max_correction\"\nvalues = [0.1, 0.5]\nneutral = 0.1\n";
    let both = [
        (log.as_path(), Some(rel.as_path())),
        (log2.as_path(), Some(rel2.as_path())),
    ];
    let e = run(&good.replace("neutral = 0.1", "neutral = 0.2"), &both);
    assert!(
        e.contains("c.toml") && e.contains("choice[0].neutral"),
        "{e}"
    );
    let e = run(&good.replace("max_correction", "no_such_key"), &both);
    assert!(e.contains("c.toml") && e.contains("no_such_key"), "{e}");
    let e = run(&good.replace("[0.1, 0.5]", "[0.1, -3.0]"), &both);
    assert!(e.contains("c.toml") && e.contains("max_correction"), "{e}");
    let e = run(
        good,
        &[(log.as_path(), Some(rel.as_path())), (log2.as_path(), None)],
    );
    assert!(e.contains("--relations"), "{e}");
    let e = run(good, &[(log.as_path(), Some(rel.as_path()))]);
    assert!(e.contains("two logs"), "{e}");
    assert!(!tmp.path().join("o").exists());
}
