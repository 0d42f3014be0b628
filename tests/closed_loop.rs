//! The closed loop in process, through the library: scenarios run by `futago::run::run` (as
//! the command does, without spawning it) and their outputs checked against the simulated
//! truth or a hand-computed case. The command's own behaviour (its arguments, exit statuses,
//! messages) is tested in `cli.rs`.

mod common;
use common::*;
use futago::run::{self, RunOptions};
use std::path::{Path, PathBuf};

/// Runs `scenario` into `out` (for `duration` simulated seconds if given) and returns its
/// summary. The run must end normally; its gates may fail, since a short run cannot meet
/// them (the command would exit with status 3).
fn run_for(scenario: &Path, out: &Path, duration: Option<&str>) -> serde_json::Value {
    let s = futago::stack::load(scenario).unwrap_or_else(|e| panic!("{e}"));
    let opts = RunOptions {
        seed: None,
        duration: duration.map(|d| d.parse().unwrap()),
        progress: false,
        report: true,
        force: false,
    };
    let (summary, _) = run::run(&s, &opts, out).unwrap_or_else(|e| panic!("{e:#}"));
    summary
}

/// [`run_for`] of a shipped scenario, for `duration` s.
fn short_run(scenario: &str, duration: &str, out: &Path) -> serde_json::Value {
    run_for(&root().join(scenario), out, Some(duration))
}

/// The pose of a robot that drives an odometry-perfect square (legs of `side`, in-place turns
/// of ±90° by odometry) with actual wheel radii `E_d` apart and actual wheel base `E_b` times
/// the nominal one: Borenstein's UMBmark error model in closed form.
fn umbmark_prediction(start: [f64; 3], side: f64, ccw: bool, ed: f64, eb: f64) -> [f64; 3] {
    let (r, b) = (0.036, 0.258);
    let (rl, rr) = (r * 2.0 / (ed + 1.0), r * 2.0 * ed / (ed + 1.0));
    let ba = b * eb;
    let mut pose = start;
    // Turns the left and right wheels by `phi_l`, `phi_r` (rad) in small equal steps.
    let mut roll = |phi_l: f64, phi_r: f64| {
        let n = 10_000;
        let (sl, sr) = (rl * phi_l / n as f64, rr * phi_r / n as f64);
        let (d, dth) = ((sl + sr) / 2.0, (sr - sl) / ba);
        for _ in 0..n {
            let [x, y, th] = pose;
            pose = [
                x + d * (th + dth / 2.0).cos(),
                y + d * (th + dth / 2.0).sin(),
                th + dth,
            ];
        }
    };
    let sign = if ccw { 1.0 } else { -1.0 };
    for leg in 0..4 {
        // Straight by the encoders: both wheels turn by side / r.
        roll(side / r, side / r);
        if leg < 3 {
            // In place by the encoders: ±90° = (s_r − s_l) / b with s_r = −s_l.
            let phi = std::f64::consts::FRAC_PI_2 * b / (2.0 * r);
            roll(-sign * phi, sign * phi);
        }
    }
    pose
}

fn umbmark_scenario(dir: &Path, ccw: bool, ed: f64, eb: f64) -> PathBuf {
    let world = root().join("worlds/lab.toml");
    let (start, pts) = if ccw {
        (
            [4.5, 1.8],
            "[[8.5, 1.8], [8.5, 5.8], [4.5, 5.8], [4.5, 1.8]]",
        )
    } else {
        (
            [4.5, 5.8],
            "[[8.5, 5.8], [8.5, 1.8], [4.5, 1.8], [4.5, 5.8]]",
        )
    };
    let text = format!(
        "name = \"umbmark\"\nworld = {world:?}\nduration = 300.0\nstart = {{ x = {}, y = {}, yaw_deg = 0.0 }}\n[robot.odometry]\nwheel_diameter_ratio = {ed}\nwheel_base_ratio = {eb}\nquantize = false\n[controller]\ntype = \"waypoints\"\npose_source = \"odometry\"\nspeed = 0.2\nlookahead = 0.3\nturn_in_place_deg = 20.0\nturn_tolerance_deg = 0.05\nturn_speed = 0.08\ntolerance = 0.005\nwaypoints = {pts}\n",
        start[0], start[1]
    );
    let p = dir.join(format!(
        "umbmark-{}-{ed}-{eb}.toml",
        if ccw { "ccw" } else { "cw" }
    ));
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn umbmark_square_shows_the_configured_odometry_errors_and_none_without_them() {
    let tmp = tempfile::tempdir().unwrap();
    for (ed, eb) in [(1.0, 1.0), (1.0, 1.02), (1.006, 1.0), (1.004, 0.985)] {
        let mut errors = Vec::new();
        for ccw in [false, true] {
            let scenario = umbmark_scenario(tmp.path(), ccw, ed, eb);
            let out = tmp.path().join(format!("out-{ccw}-{ed}-{eb}"));
            run_for(&scenario, &out, None);
            let s = summary(&out);
            assert!(
                s["controller_finished"].as_bool().unwrap(),
                "the square was completed"
            );
            let fin: Vec<f64> = s["robot"]["final_pose"]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap())
                .collect();
            let start: Vec<f64> = s["robot"]["start"]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap())
                .collect();
            let predicted = umbmark_prediction([start[0], start[1], start[2]], 4.0, ccw, ed, eb);
            let (ex, ey) = (fin[0] - start[0], fin[1] - start[1]);
            let miss = (fin[0] - predicted[0]).hypot(fin[1] - predicted[1]);
            let expected = (predicted[0] - start[0]).hypot(predicted[1] - start[1]);
            errors.push((ex, ey));
            if ed == 1.0 && eb == 1.0 {
                assert!(
                    ex.hypot(ey) < 0.02,
                    "no error model: return error {ex:.4}, {ey:.4}"
                );
            } else {
                assert!(
                    expected > 0.15,
                    "the model predicts a visible error ({expected})"
                );
                assert!(
                    miss < 0.04 + 0.05 * expected,
                    "E_d {ed}, E_b {eb}, ccw {ccw}: ended {miss:.3} m from the UMBmark prediction (error {expected:.3} m)"
                );
            }
        }
        if ed == 1.0 && eb != 1.0 {
            // A wheel-base error alone: the clockwise and counter-clockwise return errors mirror
            // each other across the first leg's direction (x), Borenstein's type A pattern.
            let ((x1, y1), (x2, y2)) = (errors[0], errors[1]);
            assert!(
                (x1 - x2).abs() < 0.05 && (y1 + y2).abs() < 0.05,
                "{errors:?}"
            );
        }
    }
}

/// Exploration closes the loop from an unknown map: the robot maps both rooms through the
/// doorway on its graph SLAM without touching anything, SLAM's pose stays within 10 cm of the
/// truth, and the run ends by itself when no frontier is left.
#[test]
fn exploration_maps_both_rooms_on_slam_without_a_bump() {
    let tmp = tempfile::tempdir().unwrap();
    let world = write(tmp.path(), "two-rooms.toml", TWO_ROOMS);
    let scenario = write(
        tmp.path(),
        "explore.toml",
        format!(
            "name = \"explore\"\nworld = {world:?}\nduration = 300.0\nseed = 3\n\
             start = {{ x = 1.0, y = 1.0, yaw_deg = 0.0 }}\n\
             [robot.odometry]\nwheel_base_ratio = 1.01\nnoise = 0.002\n\
             [[lidar]]\nname = \"front\"\npreset = \"urg-04lx\"\nxyz = [0.08, 0.0, 0.2]\n\
             [slam]\nmethod = \"graph\"\n\
             [controller]\ntype = \"explore\"\n\
             [[gate]]\nmetric = \"slam.ate.rmse_m\"\nop = \"<\"\nvalue = 0.05\n\
             [[gate]]\nmetric = \"slam.map.f1_2cell\"\nop = \">=\"\nvalue = 0.8\n"
        ),
    );
    let out = tmp.path().join("out");
    run_for(&scenario, &out, None);
    let s = summary(&out);
    assert!(s["controller_finished"].as_bool().unwrap(), "{s}");
    assert_eq!(s["robot"]["bump_events"], 0, "{s}");
    let gates = s["gates"].as_array().unwrap();
    assert!(
        gates.len() == 2 && gates.iter().all(|g| g["passed"] == true),
        "{gates:?}"
    );
    let slam = &s["slam"];
    assert!(
        slam["online_max_position_error_m"].as_f64().unwrap() < 0.1,
        "{slam}"
    );
    // The scored metrics: SLAM's final trajectory beats odometry's against the ground truth.
    let m = &s["metrics"];
    let ate = |k: &str| m[format!("{k}.ate.rmse_m")].as_f64().unwrap();
    assert!(ate("slam") < 0.05 && ate("slam") < ate("odometry"), "{m}");
    assert!(m["slam.rpe_1m.trans.max_m"].as_f64().unwrap() < 0.1, "{m}");
    // The map against the world's own grid: walls where the world has them, and both rooms.
    let v = |k: &str| m[k].as_f64().unwrap();
    assert!(v("slam.map.precision_2cell") > 0.95, "{m}");
    assert!(v("slam.map.recall_2cell") > 0.9, "{m}");
    assert!(v("slam.map.free_iou") > 0.8, "{m}");
    // Both rooms (24 m² inside the walls) are known, in the map SLAM wrote.
    let area = slam["map_known_area_m2"].as_f64().unwrap();
    assert!(area > 0.9 * 24.0, "{area} m² known");
    let map = std::fs::read_to_string(out.join("slam_map.yaml")).unwrap();
    assert!(map.contains("slam_map.pgm"));
    // The robot went through the doorway and round the wall that hid the far side.
    let truth =
        futago_msgs::tum::parse(&std::fs::read_to_string(out.join("groundtruth.txt")).unwrap())
            .unwrap();
    assert!(truth.iter().any(|p| p.pose.translation[0] > 4.7));
}

/// office-mcl's scenario text, its world named by an absolute path (to be written elsewhere).
/// People tracked on a SLAM map take the growing map at `people.map_period` (1 s), not at
/// each of SLAM's updates: each map taken costs a distance transform of the whole grid.
/// Turning in place at 0.77 rad/s with SLAM updating every 0.02 rad (at most at the laser's
/// 40 Hz), 6 s give some 200 maps; the tracker takes one a second, and every one with the
/// period at 0.
#[test]
fn people_tracking_takes_a_growing_map_at_its_period() {
    let tmp = tempfile::tempdir().unwrap();
    let world = root().join("worlds/lab.toml");
    let taken = |name: &str, people: &str| {
        let scenario = write(
            tmp.path(),
            &format!("{name}.toml"),
            format!(
                "name = \"slam-people\"\nworld = {world:?}\nduration = 6.0\nstart = \"centre\"\n\
                 [[lidar]]\nname = \"front\"\npreset = \"utm-30lx\"\n\
                 [slam]\nlaser = \"front\"\nmin_travel = 0.02\nmin_turn = 0.02\n\
                 [controller]\ntype = \"segments\"\nsegments = [{{ duration = 6.0, wheels = [-0.1, 0.1] }}]\n\
                 [[person]]\nname = \"p\"\nroute = [[4.5, 2.5], [4.5, 4.5]]\nmode = \"back_and_forth\"\n{people}"
            ),
        );
        let summary = run_for(&scenario, &tmp.path().join(name), None);
        summary["people"]["tracking"]["maps_taken"]
            .as_u64()
            .unwrap()
    };
    let every = taken("every", "[people]\nmap_period = 0.0\n");
    let periodic = taken("periodic", "");
    assert!(every > 50, "{every} maps taken at every change");
    assert!((3..=7).contains(&periodic), "{periodic} maps taken at 1 s");
}

fn office_mcl() -> String {
    std::fs::read_to_string(root().join("scenarios/office-mcl.toml"))
        .unwrap()
        .replace(
            "../worlds/office.toml",
            root().join("worlds/office.toml").to_str().unwrap(),
        )
}

#[test]
fn the_robot_drives_on_mcl_and_stays_localised_while_odometry_drifts() {
    let tmp = tempfile::tempdir().unwrap();
    let text = office_mcl();
    let scenario = write(tmp.path(), "mcl.toml", &text);
    let out = tmp.path().join("mcl");
    run_for(&scenario, &out, Some("60"));
    let s = summary(&out);
    let l = &s["localization"];
    assert!(l["updates"].as_u64().unwrap() >= 200, "{l}");
    assert!(l["mean_position_error_m"].as_f64().unwrap() < 0.1, "{l}");
    assert!(l["max_position_error_m"].as_f64().unwrap() < 0.3, "{l}");
    assert_eq!(
        s["robot"]["bump_events"], 0,
        "driving on the estimate hit something"
    );
    assert!(s["files"]["localization.txt"]["sha256"].is_string());
    let est =
        futago_msgs::tum::parse(&std::fs::read_to_string(out.join("localization.txt")).unwrap())
            .unwrap();
    assert!(est.len() >= 200);
}

#[test]
fn a_laser_casts_only_the_scans_read_and_a_recorder_changes_no_reading() {
    // office-mcl's localiser takes a scan at 4 Hz of the 40 Hz laser, and its driver none:
    // with the CARMEN recorder off, only those are cast; with it on, every scan is, and the
    // localiser's track is the same to the byte.
    let tmp = tempfile::tempdir().unwrap();
    let text = office_mcl();
    let quiet = write(
        tmp.path(),
        "quiet.toml",
        format!("{text}\n[output]\ncarmen = false\n"),
    );
    let recorded = write(tmp.path(), "recorded.toml", &text);
    let (a, b) = (tmp.path().join("quiet"), tmp.path().join("recorded"));
    run_for(&quiet, &a, Some("20"));
    run_for(&recorded, &b, Some("20"));
    let scans = |dir: &Path| summary(dir)["lidar"][0]["scans"].as_u64().unwrap();
    // 20 s at 40 Hz is 800 scans (801 with the one at 20 s); at 4 Hz, 80 (81).
    assert!((800..=801).contains(&scans(&b)), "{}", scans(&b));
    assert!((80..=81).contains(&scans(&a)), "{}", scans(&a));
    assert!(b.join("scans.clf").exists() && !a.join("scans.clf").exists());
    let track = |dir: &Path| std::fs::read(dir.join("localization.txt")).unwrap();
    assert!(track(&a).len() > 1000);
    assert_eq!(
        track(&a),
        track(&b),
        "the recorder changed what the localiser saw"
    );
}

#[test]
fn agents_leave_their_ground_truth_and_sensors_ride_joints() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let world = root().join("worlds/lab.toml");
    let scenario = write(
        d,
        "movers.toml",
        format!(
            "name = \"movers\"\nworld = {world:?}\nduration = 3.0\nstart = \"centre\"\n\
             [controller]\ntype = \"segments\"\nsegments = [{{ duration = 3.0, velocity = 0.0 }}]\n\
             [[lidar]]\nname = \"front\"\npreset = \"urg-04lx\"\n\
             [[lidar]]\nname = \"vertical\"\npreset = \"utm-30lx\"\nxyz = [0.0, 0.0, 0.5]\n\
             rpy_deg = [90.0, 0.0, 0.0]\njoint = \"table\"\n\
             [[joint]]\nname = \"table\"\nrate_deg = 36.0\n\
             [[agent]]\nname = \"walker\"\npath = [[2.0, 1.0], [4.0, 1.0]]\nspeed = 1.0\n\
             mode = \"back_and_forth\"\n"
        ),
    );
    let out = d.join("run");
    run_for(&scenario, &out, None);
    let text = std::fs::read_to_string(out.join("agents/walker.txt")).unwrap();
    let rows: Vec<Vec<f64>> = text
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| l.split(' ').map(|v| v.parse().unwrap()).collect())
        .collect();
    // 3 s at the 50 Hz ground-truth rate.
    assert!(rows.len() >= 150, "{}", rows.len());
    for r in &rows {
        // 1 m/s from x = 2 to 4 and back, on y = 1.
        let t = r[0];
        let s = t % 4.0;
        let x = if s <= 2.0 { 2.0 + s } else { 6.0 - s };
        assert!(
            (r[1] - x).abs() < 1e-6 && (r[2] - 1.0).abs() < 1e-9,
            "{r:?}"
        );
    }
    let sum = summary(&out);
    assert!(
        sum["files"]["agents/"]["sha256"].is_string(),
        "{}",
        sum["files"]
    );
    assert_eq!(sum["agents"][0]["name"], "walker");
    // 36°/s for 3 s.
    let angle = sum["joints"][0]["final_angle_deg"].as_f64().unwrap();
    assert!((angle - 108.0).abs() < 1e-6, "{angle}");
    // Both lasers scanned: the jointed one at the UTM-30LX's 40 Hz.
    let lidars = sum["lidar"].as_array().unwrap();
    assert_eq!(lidars.len(), 2);
    assert!(lidars[1]["scans"].as_u64().unwrap() >= 115, "{}", lidars[1]);
}

/// Seed 004's mapper in a short run: it drives to its first view, turns the table a full
/// turn, writes its maps and grid, and scores every removal against the beams' truth (the
/// shares lie in 0 … 1, and the kept map holds the sweep's points).
#[test]
fn the_turntable_mapper_scans_a_view_and_scores_its_removal() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    // The gates (six views) fail in 40 s; the run itself must not.
    let s = short_run("scenarios/corridor-scan3d.toml", "40", &out);
    assert!(
        s["scan3d"]["views"].as_u64().unwrap() >= 1,
        "{}",
        s["scan3d"]
    );
    // A 12 s turn of an LMS200 at 37.5 Hz: about 450 vertical scans of up to 361 points.
    let kept = s["scan3d"]["scans_kept"].as_u64().unwrap();
    assert!((400..=500).contains(&kept), "{kept} scans kept");
    assert!(s["scan3d"]["points"].as_u64().unwrap() > 100 * kept);
    for f in [
        "scan3d_map.ply",
        "scan3d_carved.ply",
        "scan3d_raw.ply",
        "scan3d_grid.pgm",
        "scan3d_grid.yaml",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let map = futago_msgs::ply::read(&out.join("scan3d_map.ply")).unwrap();
    assert_eq!(
        map.vertices.len() as u64,
        s["scan3d"]["points"].as_u64().unwrap()
    );
    for method in ["pause", "carving", "pause_carving"] {
        for k in ["sa", "sa_floor", "da", "aa", "pr", "rr", "f1"] {
            let v = s["metrics"][format!("scan3d.{method}.{k}")]
                .as_f64()
                .unwrap();
            assert!((0.0..=1.0).contains(&v), "scan3d.{method}.{k} = {v}");
        }
    }
}

/// With no views given, the mapper scans where it starts, then plans the next view on the 2D
/// grid of what it has mapped: a reachable place inside the region to map, clear of the
/// pillars, towards the unknown; the coverage of the hall's true surfaces grows from the
/// first view's, and the lengths are measured against the world's.
#[test]
fn the_turntable_mapper_plans_its_next_view_and_scores_its_coverage() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let s = short_run("scenarios/hall-scan3d.toml", "30", &out);
    let m = &s["scan3d"];
    assert_eq!(m["views"].as_u64(), Some(1), "{m}");
    let plans = m["planned_views"].as_array().unwrap();
    assert_eq!(plans.len(), 1, "{m}");
    let p = plans[0]["position"].as_array().unwrap();
    let (x, y) = (p[0].as_f64().unwrap(), p[1].as_f64().unwrap());
    // Inside the hall (the region), not where it stands, not on a pillar.
    assert!(
        (14.0..=34.0).contains(&x) && (-7.0..=7.0).contains(&y),
        "{x}, {y}"
    );
    assert!((x - 24.0).hypot(y) > 1.0, "{x}, {y}");
    for px in [18.0, 22.0, 26.0, 30.0] {
        for py in [-4.0, 0.5, 4.0] {
            assert!(
                (x - px).hypot(y - py) > 0.6,
                "{x}, {y} by the pillar at {px}, {py}"
            );
        }
    }
    assert!(plans[0]["new_cells"].as_u64().unwrap() >= 100);
    // One view's coverage: some, far from all, of 700 m² of surfaces.
    let c = s["metrics"]["scan3d.coverage"].as_f64().unwrap();
    assert!(c > 0.05 && c < 0.5, "{c}");
    let area = m["surface_area_m2"].as_f64().unwrap();
    // The floor alone is 20 × 14 m less the pillars and furniture.
    assert!(area > 280.0, "{area}");
    assert_eq!(m["coverage_curve"].as_array().unwrap().len(), 1);
    // The truth of each length is the world's: the hall's walls stand 14 m apart, 0.2 m
    // thick; its pillars 4 m apart, 0.6 m wide.
    let lengths = m["lengths"].as_array().unwrap();
    let truth = |n: &str| {
        lengths
            .iter()
            .find(|l| l["name"] == n)
            .and_then(|l| l["truth_m"].as_f64())
            .unwrap()
    };
    assert!((truth("width") - 13.8).abs() < 1e-4);
    assert!((truth("pillars") - 3.4).abs() < 1e-4);
    assert!((truth("length") - 19.8).abs() < 1e-4);
}

/// Seed 001's mapping pass in a short run: the trinocular rig's SIFT points become landmarks
/// written as a map that reads back, each seen at least twice, with (almost) no false stereo
/// matches against the true depth, and the seed's search keeping the pass within its window.
#[test]
fn the_trinocular_pass_writes_a_landmark_map() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let s = short_run("scenarios/lab-visual-map.toml", "6", &out);
    let v = &s["visual_map"];
    assert!(v["frames"].as_u64().unwrap() >= 29, "{v}");
    assert!((v["baseline_m"].as_f64().unwrap() - 0.0996).abs() < 1e-9);
    let file = futago_msgs::landmarks::LandmarkFile::read(&out.join("landmarks.json")).unwrap();
    assert!(file.landmarks.len() > 100, "{}", file.landmarks.len());
    assert_eq!(
        file.landmarks.len() as u64,
        v["landmarks_seen_twice"].as_u64().unwrap()
    );
    assert!(file.landmarks.iter().all(|l| l.observed >= 2));
    // Inside the lab (x 0–13, y 0–7, z 0–2.7) give or take their depth error.
    let inside = file
        .landmarks
        .iter()
        .filter(|l| {
            let [x, y, z] = l.position;
            (-0.5..13.5).contains(&x) && (-0.5..7.5).contains(&y) && (-0.3..3.0).contains(&z)
        })
        .count();
    assert!(
        inside as f64 > 0.9 * file.landmarks.len() as f64,
        "{inside}"
    );
    assert!(v["stereo"]["judged"].as_u64().unwrap() > 500, "{v}");
    assert!(v["stereo"]["false_rate"].as_f64().unwrap() <= 0.01, "{v}");
    // A pass that holds stays within one search window (±100 mm, ±10°) of the truth.
    assert!(
        v["pose"]["position"]["max_m"].as_f64().unwrap() < 0.1,
        "{v}"
    );
    assert!(
        v["pose"]["heading"]["max_deg"].as_f64().unwrap() < 10.0,
        "{v}"
    );
}

/// Seed 001's localisers in a short closed loop: the robot drives on the delegates' pose; every
/// localiser stays within 5 cm and 5° of the truth on most frames, the delegates are fewer
/// than the landmarks in view and match with fewer descriptor comparisons, and nothing is
/// bumped.
#[test]
fn the_monocular_localisers_track_the_camera_in_the_landmark_map() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let s = short_run("scenarios/lab-visual-nav.toml", "12", &out);
    let v = &s["visual_localization"];
    assert!(v["frames"].as_u64().unwrap() >= 119, "{v}");
    for l in ["all", "delegates", "summary", "pnp"] {
        let share = v[l]["within_5cm_5deg"].as_f64().unwrap();
        assert!(share >= 0.9, "{l}: {share}");
        assert!(v[l]["matched"]["mean"].as_f64().unwrap() >= 10.0, "{l}");
    }
    let (all, del) = (&v["all"], &v["delegates"]);
    assert!(
        del["projected"]["mean"].as_f64().unwrap()
            < 0.6 * all["projected"]["mean"].as_f64().unwrap(),
        "{v}"
    );
    assert!(
        del["comparisons"]["mean"].as_f64().unwrap()
            < 0.6 * all["comparisons"]["mean"].as_f64().unwrap()
    );
    // The summary map keeps a third of the landmarks.
    let (n, k) = (
        v["landmarks"].as_f64().unwrap(),
        v["summary_landmarks"].as_f64().unwrap(),
    );
    assert!((k / n - 1.0 / 3.0).abs() < 0.01, "{k} of {n}");
    assert_eq!(v["bumps"].as_u64(), Some(0));
    assert!(
        s["robot"]["distance_travelled_m"].as_f64().unwrap() > 1.5,
        "{}",
        s["robot"]
    );
    let m = &s["metrics"];
    assert!(
        m["visual_localization.delegates.matching_work_ratio"]
            .as_f64()
            .unwrap()
            > 1.5
    );
    // The driven estimate is written as a trajectory (TUM), one line a frame.
    let tum = std::fs::read_to_string(out.join("visual_localization.txt")).unwrap();
    assert_eq!(tum.lines().count() as u64, v["frames"].as_u64().unwrap());
}

/// The boustrophedon lanes are replanned once MCL has settled, spaced for the covariance it
/// publishes with its estimate: the new route starts where the robot is, its spacing is the
/// one the filter's spread calls for, and that spread is centimetres, as its errors are. The
/// truth-driven ablation, whose pose comes with no covariance, keeps the configured lanes.
#[test]
fn coverage_lanes_are_replanned_for_the_localisations_covariance() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let s = short_run("scenarios/office-coverage-bcd.toml", "16", &out);
    let lanes = &s["coverage"]["lanes"];
    let v = |k: &str| lanes[k].as_f64().unwrap_or_else(|| panic!("{k}: {lanes}"));
    // 40 estimates at MCL's 4 Hz: about 10 s in.
    let at = v("at_s");
    assert!((9.0..16.0).contains(&at), "{lanes}");
    let sigma = v("sigma_m");
    assert!((0.005..0.08).contains(&sigma), "{lanes}");
    let spacing = v("spacing_m");
    let expected =
        futago_robot::navigation::coverage::boustrophedon::spacing_from_sigma(sigma, 0.34, 0.01);
    assert!((spacing - expected).abs() < 1e-12, "{lanes}");
    assert!(spacing < 0.34 && spacing > 0.17, "{lanes}");
    // The route driven is the new one: it starts where the robot was then (on its estimate,
    // centimetres from the truth), not at the scenario's start.
    let route = std::fs::read_to_string(out.join("coverage_route.txt")).unwrap();
    let first: Vec<f64> = route
        .lines()
        .find(|l| !l.starts_with('#'))
        .unwrap()
        .split_whitespace()
        .map(|x| x.parse().unwrap())
        .collect();
    let truth =
        futago_msgs::tum::parse(&std::fs::read_to_string(out.join("groundtruth.txt")).unwrap())
            .unwrap();
    let then = truth
        .iter()
        .min_by(|a, b| {
            (a.stamp.secs() - at)
                .abs()
                .total_cmp(&(b.stamp.secs() - at).abs())
        })
        .unwrap();
    let [tx, ty, _] = then.pose.translation;
    assert!(
        (first[0] - tx).hypot(first[1] - ty) < 0.15,
        "{first:?} vs ({tx}, {ty})"
    );
    let start = &truth[0].pose.translation;
    assert!(
        (tx - start[0]).hypot(ty - start[1]) > 0.3,
        "the robot had not moved by {at} s"
    );
    assert_ne!(s["coverage"]["route"], lanes["first_route"], "{lanes}");
    // The time spent building the nodes (the coverage scorer's surfaces among them) is
    // reported apart from the loop's.
    let setup = s["performance"]["setup_s"].as_f64().unwrap_or(-1.0);
    assert!(setup > 0.0, "{}", s["performance"]);
    // The filter's account of its own spread, beside its errors.
    let l = &s["localization"];
    assert!(l["mean_sigma_m"].as_f64().unwrap() > 0.0, "{l}");
    let within = l["within_2_sigma"].as_f64().unwrap();
    assert!((0.0..=1.0).contains(&within), "{l}");

    let out = tmp.path().join("truth");
    let s = short_run("scenarios/office-coverage-bcd-truth.toml", "2", &out);
    let lanes = &s["coverage"]["lanes"];
    assert_eq!(lanes["spacing_m"].as_f64(), Some(0.3), "{lanes}");
    assert!(
        lanes["configured"]
            .as_str()
            .is_some_and(|w| w.contains("no covariance")),
        "{lanes}"
    );
}
