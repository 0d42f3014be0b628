//! `futago calibrate` against a simulated robot whose errors are known: the profile it
//! estimates from the simulated log must give them back.

mod common;
use common::*;
use futago_msgs::profile::{Estimate, RobotProfile};

/// The simulated Create's odometry errors and its laser's dropout (`sim/src/create.rs`: the
/// firmware integrates with the nominal wheel base and equal wheels).
const WHEEL_BASE_RATIO: f64 = 1.05;
const WHEEL_DIAMETER_RATIO: f64 = 1.01;
const NOMINAL_WHEEL_BASE: f64 = 0.258;
const DROPOUT: f64 = 0.05;

/// Asserts `e` is within `k` of its standard errors (plus `slack` for what the model leaves
/// out) of `truth`, and that the standard error is below `informative` (a wide one would pass
/// anything).
fn near(e: &Estimate, truth: f64, k: f64, slack: f64, informative: f64, what: &str) {
    assert!(
        e.sd > 0.0 && e.sd < informative,
        "{what}: standard error {} not in (0, {informative})",
        e.sd
    );
    assert!(
        (e.value - truth).abs() <= k * e.sd + slack,
        "{what}: {} ± {} against {truth}",
        e.value,
        e.sd
    );
}

#[test]
fn calibrate_gives_back_the_simulated_robots_errors() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    let cal = dir.path().join("cal");
    let lidar = format!(
        "lidar=[{{name=\"front\", preset=\"seed000\", xyz=[0.08, 0.0, 0.2], dropout={DROPOUT}, rate=10.0, beams=481}}]"
    );
    ok(&futago(&[
        "run",
        "scenarios/office-tour.toml",
        "--duration",
        "120",
        "--out",
        run.to_str().unwrap(),
        "-q",
        "--set",
        &format!("robot.odometry.wheel_base_ratio={WHEEL_BASE_RATIO}"),
        "--set",
        &format!("robot.odometry.wheel_diameter_ratio={WHEEL_DIAMETER_RATIO}"),
        "--set",
        &lidar,
    ]));
    let o = futago(&[
        "calibrate",
        run.join("scans.clf").to_str().unwrap(),
        "--out",
        cal.to_str().unwrap(),
    ]);
    ok(&o);
    let text = std::fs::read_to_string(cal.join("profile.toml")).unwrap();
    let p: RobotProfile = toml::from_str(&text).expect("the profile reads back");
    let odo = p.odometry.expect("the log has odometry");
    // The true turn is the reported one over E_b (the wheels are E_b times further apart
    // than the firmware believes).
    near(
        &odo.rotation_scale,
        1.0 / WHEEL_BASE_RATIO,
        4.0,
        0.005,
        0.03,
        "rotation scale",
    );
    // Unequal wheels with the mean diameter kept: driving straight by the firmware's
    // reckoning, the right wheel travels 2E_d/(E_d+1) of the distance and the left 2/(E_d+1),
    // so the robot turns 2(E_d−1)/((E_d+1)·E_b·b) rad per metre.
    let bias = 2.0 * (WHEEL_DIAMETER_RATIO - 1.0)
        / ((WHEEL_DIAMETER_RATIO + 1.0) * WHEEL_BASE_RATIO * NOMINAL_WHEEL_BASE);
    near(&odo.heading_bias, bias, 4.0, 0.002, 0.015, "heading bias");
    near(
        &odo.translation_scale,
        1.0,
        4.0,
        0.005,
        0.02,
        "translation scale",
    );
    // Dropout removes that share of the beams whatever they would have hit; the beams the
    // map says hit but that pass a gap in it add a little.
    near(
        &p.laser.no_return,
        DROPOUT,
        4.0,
        0.005,
        0.005,
        "no-return share",
    );
    assert_eq!(p.laser.beams, 481);
    assert!((p.laser.rate - 10.0).abs() < 0.05, "{}", p.laser.rate);
    // The default span is the whole log.
    assert_eq!(p.source.from_s, 0.0);
    assert!(p.source.to_s > 119.0, "{}", p.source.to_s);
}

#[test]
fn calibrate_refuses_a_bad_span_and_an_unknown_laser_before_writing() {
    let dir = tempfile::tempdir().unwrap();
    let log = write(
        dir.path(),
        "room.clf",
        (0..40)
            .map(|k| {
                let pose = futago_msgs::Pose2::new(0.02 * k as f64, 0.0, 0.0);
                let ranges: Vec<f32> = (0..180)
                    .map(|b| room_cast(pose, (b as f64 - 90.0).to_radians()))
                    .collect();
                flaser_line(&ranges, pose, k as f64 * 0.1)
            })
            .collect::<String>(),
    );
    let out = dir.path().join("cal");
    for (args, says) in [
        (vec!["--span", "0.6:0.2"], "--span `0.6:0.2`"),
        (vec!["--span", "half"], "expected FROM:TO"),
        (vec!["--laser", "rear"], "no laser `rear`"),
    ] {
        let mut a = vec![
            "calibrate",
            log.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ];
        a.extend(args);
        refused(&a, says, &out);
    }
}

/// Asserts that `futago ARGS` fails, says `says`, and writes nothing at `out`.
fn refused(args: &[&str], says: &str, out: &std::path::Path) {
    let o = futago(args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains(says), "{args:?}: {err}");
    assert!(!out.exists(), "{args:?} wrote {}", out.display());
}

/// A twin scenario of a simulated robot's log, run as a suite: `calibrate` on the first half,
/// `twin` scored on the second, a ranking of three SLAM configurations, and the gates
/// on the SLAM's relations error and the median range residual.
#[test]
fn a_twin_of_a_simulated_robot_replays_its_drive_and_predicts_its_slam_and_ranges() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    ok(&futago(&[
        "run",
        "scenarios/office-tour.toml",
        "--duration",
        "90",
        "--out",
        run.to_str().unwrap(),
        "-q",
        "--set",
        &format!("robot.odometry.wheel_base_ratio={WHEEL_BASE_RATIO}"),
        "--set",
        "robot.odometry.noise=0.01",
        "--set",
        // A CARMEN log carries no beam timing, so the twin casts each scan at one instant:
        // the robot's laser does the same here, to be of the profile's own kind.
        "lidar=[{name=\"front\", preset=\"seed000\", xyz=[0.08, 0.0, 0.2], rate=10.0, beams=241, sweep=false}]",
    ]));
    write(
        dir.path(),
        "rank.toml",
        "[[config]]\nname = \"defaults\"\n[[config]]\nname = \"icp\"\nset = { method = \"icp\" }\n[[config]]\nname = \"sparse\"\nset = { keyframe_distance = 0.6 }\n",
    );
    let scenarios = dir.path().join("scenarios");
    std::fs::create_dir(&scenarios).unwrap();
    // The gates on the SLAM's relations error (a factor of 1.5) and the median range
    // residual (25 %), on a robot whose laser is of the profile's own kind. (Raw odometry's
    // error and the 95th percentile of the residuals are reported beside them; see the
    // README for how far they are.)
    let gate = |metric: &str, op: &str, value: f64| {
        format!("[[gate]]\nmetric = \"{metric}\"\nop = \"{op}\"\nvalue = {value}\n")
    };
    write(
        &scenarios,
        "twin-sim.toml",
        format!(
            "name = \"twin-sim\"\n[twin]\nlog = \"scans.clf\"\nrelations = \"groundtruth.relations\"\nseeds = 2\nrank = \"../rank.toml\"\n{}{}{}{}",
            gate("twin.slam_relations_m.ratio", ">=", 1.0 / 1.5),
            gate("twin.slam_relations_m.ratio", "<=", 1.5),
            gate("twin.residual_median_m.ratio", ">=", 0.75),
            gate("twin.residual_median_m.ratio", "<=", 1.25),
        ),
    );
    let suite = dir.path().join("suite");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_futago"))
        .args(["suite", scenarios.to_str().unwrap(), "--jobs", "2", "--out"])
        .arg(&suite)
        .env(futago_msgs::datasets::DATA_ENV, &run)
        .current_dir(root())
        .output()
        .unwrap();
    ok(&o);
    let result = &json_file(&suite.join("suite.json"))["results"][0];
    assert_eq!(result["status"], "passed", "{result}");
    assert_eq!(result["gates"].as_array().unwrap().len(), 4, "{result}");
    let twin = suite.join("twin-sim/twin");
    let s = summary(&twin);
    // The summary names the profile where it lies once the run is in place.
    let profile = suite.join("twin-sim/calibrate/profile.toml");
    assert!(profile.is_file());
    assert_eq!(s["profile"], profile.display().to_string());
    // Both are scored on the same stamp pairs of the second half.
    let scored = s["real"]["relations"].as_u64().unwrap();
    assert!(scored > 10, "{scored}");
    for t in s["twins"].as_array().unwrap() {
        assert_eq!(t["relations"].as_u64(), Some(scored));
    }
    // The ranking ran every configuration on the real log at three keyframe spacings and on
    // both twins (seed 0 at the configuration's own spacing): its default row's runs at the
    // defaults' spacing are the real log's and the first twin's own SLAM figures, run again.
    let rows = s["ranking"]["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 3);
    assert_eq!(rows[0]["twin_seeds_m"].as_array().unwrap().len(), 2);
    assert_eq!(
        rows[0]["twin_seeds_m"][0],
        s["twins"][0]["slam_relations_m"]
    );
    assert_eq!(rows[0]["real_runs_m"].as_array().unwrap().len(), 3);
    assert_eq!(rows[0]["real_runs_m"][0], s["real"]["slam_relations_m"]);
    let rho = s["ranking"]["spearman"].as_f64().unwrap();
    assert!((-1.0..=1.0).contains(&rho), "{rho}");
    assert!(
        std::fs::read_to_string(twin.join("twin.md"))
            .unwrap()
            .contains("Spearman")
    );
    // The twin's log is a CARMEN log of the real one's scans, which futago reads back.
    let back = futago(&[
        "replay",
        twin.join("twin.clf").to_str().unwrap(),
        "--out",
        dir.path().join("back").to_str().unwrap(),
    ]);
    ok(&back);
    let real_scans = summary(&suite.join("twin-sim/calibrate"))["profile"]["source"]["scans"]
        .as_u64()
        .unwrap();
    let twin_scans = summary(&dir.path().join("back"))["scans"].as_u64().unwrap();
    assert!(
        twin_scans >= 2 * real_scans - 2,
        "{twin_scans} scans against {real_scans} in the first half"
    );
}

#[test]
fn twin_refuses_a_profile_it_cannot_read_and_zero_seeds() {
    let dir = tempfile::tempdir().unwrap();
    let bad = write(dir.path(), "bad.toml", "[source]\nlog = 1\n");
    let rel = write(dir.path(), "r.relations", "0 1 0 0 0 0 0 0\n");
    // A profile (calibrated on a simulated log) that reads but says a share is 1.4.
    let mut absurd: toml::Value =
        toml::from_str(&std::fs::read_to_string(root().join("tests/data/profile.toml")).unwrap())
            .unwrap();
    absurd["laser"]["short_rate"]["value"] = toml::Value::Float(1.4);
    let absurd = write(dir.path(), "absurd.toml", toml::to_string(&absurd).unwrap());
    let log = write(dir.path(), "x.clf", "");
    let out = dir.path().join("twin");
    for (args, says) in [
        (vec!["--profile", bad.to_str().unwrap()], "bad.toml"),
        (
            vec!["--profile", absurd.to_str().unwrap()],
            "`laser.short_rate.value`: expected a value in [0, 1], found 1.4",
        ),
        (
            vec!["--profile", bad.to_str().unwrap(), "--seeds", "0"],
            "--seeds",
        ),
        (
            vec!["--profile", bad.to_str().unwrap(), "--score-span", "1:0"],
            "--score-span",
        ),
    ] {
        let mut a = vec![
            "twin",
            log.to_str().unwrap(),
            "--relations",
            rel.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ];
        a.extend(args);
        refused(&a, says, &out);
    }
}
