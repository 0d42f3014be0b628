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
        let o = futago(&a);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains(says), "{a:?}: {err}");
        assert!(!out.exists(), "{a:?} wrote {}", out.display());
    }
}
