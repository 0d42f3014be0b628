//! End-to-end tests of the `futago` command.

mod common;
use common::*;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Runs `scenario` quietly into `out` (for `duration` simulated seconds if given); must
/// succeed.
fn run_for(scenario: &Path, out: &Path, duration: Option<&str>) {
    let mut args = vec![
        "run",
        scenario.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "-q",
    ];
    if let Some(d) = duration {
        args.extend(["--duration", d]);
    }
    ok(&futago(&args));
}

/// Asserts the command's exit status, showing its output when it differs.
fn exits_with(o: &Output, code: i32) {
    assert_eq!(
        o.status.code(),
        Some(code),
        "stdout: {}\nstderr: {}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
}

/// Runs `args` with `--out fresh` and asserts that it fails (with status `code` when given;
/// clap's own refusals exit 2), says `expect`, and writes nothing.
fn refused_before_running(args: &[&str], fresh: &Path, expect: &str, code: Option<i32>) {
    let mut a = args.to_vec();
    a.extend(["--out", fresh.to_str().unwrap()]);
    let o = futago(&a);
    match code {
        Some(c) => exits_with(&o, c),
        None => assert!(!o.status.success(), "{a:?}"),
    }
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains(expect), "{a:?}: {err}");
    assert!(!fresh.exists(), "{a:?} ran something");
}

/// `text` with `from` replaced by `to`, written into `dir` and run: refused before anything
/// runs, with `expect` in the error.
fn edited_scenario_is_refused(dir: &Path, text: &str, from: &str, to: &str, expect: &str) {
    assert!(text.contains(from), "{from}");
    let path = dir.join("s.toml");
    std::fs::write(&path, text.replace(from, to)).unwrap();
    refused_before_running(
        &["run", path.to_str().unwrap()],
        &dir.join("fresh"),
        expect,
        None,
    );
}

#[test]
fn help_explains_every_command() {
    let o = futago(&["--help"]);
    ok(&o);
    let text = String::from_utf8_lossy(&o.stdout);
    for c in ["run", "world", "bench"] {
        assert!(text.contains(c), "{c} missing from --help:\n{text}");
    }
    let o = futago(&["world", "--help"]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("export") && text.contains("info"));
}

#[test]
fn a_run_writes_whole_results_byte_identical_for_its_seed() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b, c) = (
        tmp.path().join("a"),
        tmp.path().join("b"),
        tmp.path().join("c"),
    );
    for (dir, seed) in [(&a, "9"), (&b, "9"), (&c, "10")] {
        ok(&futago(&[
            "run",
            "scenarios/lab-push.toml",
            "--out",
            dir.to_str().unwrap(),
            "--seed",
            seed,
            "-q",
        ]));
    }
    for f in ["groundtruth.txt", "odometry.txt", "scans.clf"] {
        let (x, y) = (
            std::fs::read(a.join(f)).unwrap(),
            std::fs::read(b.join(f)).unwrap(),
        );
        assert!(!x.is_empty());
        assert_eq!(x, y, "{f} differs between two runs with the same seed");
    }
    let (mut sa, mut sb) = (summary(&a), summary(&b));
    sa.as_object_mut().unwrap().remove("performance");
    sb.as_object_mut().unwrap().remove("performance");
    assert_eq!(sa, sb);
    assert_ne!(
        std::fs::read(a.join("scans.clf")).unwrap(),
        std::fs::read(c.join("scans.clf")).unwrap(),
        "laser noise follows the seed"
    );

    // The summary agrees with the files.
    let scans = sa["lidar"][0]["scans"].as_u64().unwrap();
    let log = std::fs::read_to_string(a.join("scans.clf")).unwrap();
    assert_eq!(
        log.lines()
            .filter(|l| l.starts_with("ROBOTLASER1 "))
            .count() as u64,
        scans
    );
    assert!(scans >= 130, "10 Hz for 14 s: {scans}");
    let beams: usize = log
        .lines()
        .find(|l| l.starts_with("ROBOTLASER1 "))
        .unwrap()
        .split_whitespace()
        .nth(8)
        .unwrap()
        .parse()
        .unwrap();
    assert_eq!(beams, 682);
    let gt = std::fs::read_to_string(a.join("groundtruth.txt")).unwrap();
    let rows: Vec<Vec<f64>> = gt
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| l.split_whitespace().map(|w| w.parse().unwrap()).collect())
        .collect();
    assert!(rows.iter().all(|r| r.len() == 8));
    assert!(
        rows.windows(2).all(|w| w[1][0] > w[0][0]),
        "timestamps increase"
    );
    let sim_time = sa["sim_time_s"].as_f64().unwrap();
    assert!((rows.last().unwrap()[0] - sim_time).abs() < 0.021);
    // The robot met the box, pressed its bumpers and pushed it on (its wheels have the grip
    // to push a 1.5 kg box: 3 m forward, then back off 0.4 m).
    assert!(sa["robot"]["bump_events"].as_u64().unwrap() >= 1);
    let travelled = sa["robot"]["distance_travelled_m"].as_f64().unwrap();
    assert!((travelled - 3.4).abs() < 0.2, "{travelled}");
}

#[test]
// A table of bad inputs and the errors they must give; the 150-line limit is for library code.
#[allow(clippy::too_many_lines)]
fn bad_input_names_the_file_and_key_and_writes_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let world = root().join("worlds/lab.toml");
    let good = format!(
        "name = \"x\"\nworld = {world:?}\nduration = 1.0\nstart = \"centre\"\n[controller]\ntype = \"idle\"\n"
    );
    write(
        d,
        "bad.world.toml",
        "name = \"w\"\n[materials.m]\ncolor = [0.5, 0.5, 0.5]\n[[meshes]]\nfile = \"nowhere.glb\"\n",
    );
    let cases: Vec<(String, &str, &str)> = vec![
        (good.replace("duration = 1.0", "duration = "), "syntax", ""),
        (
            good.replace("duration = 1.0", "duration = 1.0\nspeed = 3"),
            "unknown field `speed`",
            "",
        ),
        (
            good.clone() + "[[lidar]]\npreset = \"urg-04lx\"\nrange_max = -2.0\n",
            "lidar[0].range_max",
            "expected",
        ),
        (
            good.clone() + "[[lidar]]\npreset = \"hokuyo-9000\"\n",
            "lidar[0].preset",
            "urg-04lx",
        ),
        (
            good.clone() + "[localization]\nrate = 4.0\n",
            "localization",
            "needs a [[lidar]]",
        ),
        (
            good.clone() + "[slam]\nmethod = \"graph\"\n",
            "slam",
            "needs a [[lidar]]",
        ),
        (
            good.clone() + "[[lidar]]\npreset = \"urg-04lx\"\n[slam.graph]\nloop_sigma = -0.1\n",
            "slam.graph.loop_sigma",
            "expected a value in [0.0001, 10], found -0.1",
        ),
        (
            good.clone() + "[[lidar]]\npreset = \"urg-04lx\"\n[slam]\nmethod = \"fastslam\"\n",
            "slam.method",
            "graph",
        ),
        (
            good.replace("type = \"idle\"", "type = \"explore\""),
            "controller.type",
            "needs a [slam] table",
        ),
        (
            good.replace(
                "type = \"idle\"",
                "type = \"navigate\"\ngoals = [[1.0, 1.0]]",
            ),
            "controller.pose_source",
            "[localization]",
        ),
        (
            good.clone() + "[[event]]\ntime = 5.0\nteleport = { x = 1.0, y = 1.0 }\n",
            "event[0].time",
            "expected a value in",
        ),
        (
            good.clone() + "[[gate]]\nmetric = \"slam.ate.rmse_m\"\nop = \"<\"\nvalue = 0.1\n",
            "gate[0].metric",
            "produces no metric `slam.ate.rmse_m`",
        ),
        (
            good.clone() + "[[gate]]\nmetric = \"odometry.ate.rmse\"\nop = \"<\"\nvalue = 0.1\n",
            "gate[0].metric",
            "odometry.ate.rmse_m",
        ),
        (
            good.clone()
                + "[[gate]]\nmetric = \"odometry.ate.rmse_m\"\nop = \"less\"\nvalue = 0.1\n",
            "gate[0].op",
            "",
        ),
        (
            good.clone() + "[navigation.planner]\nclearance = 0.5\n",
            "navigation.planner.wall_distance",
            "clearance",
        ),
        (
            good.clone()
                + "[[lidar]]\npreset = \"urg-04lx\"\n[localization.mcl]\nmodel = \"kalman\"\n",
            "localization.mcl.model",
            "beam",
        ),
        (
            good.replace("start = \"centre\"", "start = \"nowhere\""),
            "start",
            "spawn",
        ),
        (
            good.replace(
                &format!("{world:?}"),
                &format!("{:?}", d.join("bad.world.toml")),
            ),
            "meshes[0].file",
            "nowhere.glb",
        ),
        (
            good.replace(&format!("{world:?}"), "\"missing.toml\""),
            "world",
            "does not exist",
        ),
        (
            good.clone() + "[[lidar]]\npreset = \"urg-04lx\"\njoint = \"table\"\n",
            "lidar[0].joint",
            "no joint is named `table`",
        ),
        (
            good.clone()
                + "[[lidar]]\npreset = \"urg-04lx\"\njoint = \"table\"\n[[joint]]\nname = \"table\"\nrate_deg = 30.0\n[slam]\n",
            "slam.laser",
            "rides on joint `table`",
        ),
        (
            good.clone()
                + "[[joint]]\nname = \"tilt\"\nmode = \"oscillate\"\nrate_deg = 30.0\nmin_deg = 10.0\nmax_deg = 5.0\n",
            "joint[0].max_deg",
            "above min_deg",
        ),
        (
            good.clone()
                + "[[agent]]\nname = \"p\"\npath = [[1.0, 1.0], [1e6, 1.0]]\nspeed = 1.0\n",
            "agent[0].path[1]",
            "world",
        ),
        (
            good.clone()
                + "[[agent]]\nname = \"robot\"\npath = [[1.0, 1.0], [2.0, 1.0]]\nspeed = 1.0\n",
            "agent[0].name",
            "robot",
        ),
        (
            good.clone() + "[[person]]\nname = \"p\"\nroute = [[1.0, 1.0], [1.0, 1e6]]\n",
            "person[0].route[1]",
            "world",
        ),
        (
            good.clone()
                + "[[agent]]\nname = \"p\"\npath = [[1.0, 1.0], [2.0, 1.0]]\nspeed = 1.0\n[[person]]\nname = \"p\"\nroute = [[1.0, 1.0]]\n",
            "person[0].name",
            "taken",
        ),
        (
            good.clone()
                + "[[flow]]\nname = \"f\"\nfrom = [1.0, 1.0]\nto = [2.0, 1.0]\nrate = 1.0\nmax = 0\n",
            "flow[0].max",
            "expected 1 to 1000",
        ),
        (
            good.clone() + "[crowd]\nleg_radius = -0.05\n",
            "crowd.leg_radius",
            "expected",
        ),
        (
            good.clone() + "[robot]\nwheel_base = 2.0\n",
            "robot.wheel_base",
            "expected",
        ),
        (
            good.clone() + "[physics]\nrate = 50.0\n",
            "physics.rate",
            "expected",
        ),
        (
            good.replace(
                "type = \"idle\"",
                "type = \"segments\"\nsegments = [{ duration = -1.0 }]",
            ),
            "controller.segments[0].duration",
            "expected a value in [0.001, 1000000], found -1",
        ),
    ];
    for (i, (text, key, expect)) in cases.iter().enumerate() {
        let p = write(d, &format!("case{i}.toml"), text);
        let out = d.join(format!("out{i}"));
        let o = futago(&[
            "run",
            p.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "-q",
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "case {i} should fail");
        assert!(
            err.contains(key) && err.contains(expect),
            "case {i}: expected `{key}` and `{expect}` in: {err}"
        );
        assert!(err.contains(".toml"), "case {i}: names the file: {err}");
        assert!(!err.contains("panicked"), "case {i} panicked: {err}");
        assert!(!out.exists(), "case {i} left output behind");
    }
    // Nothing half-written beside the outputs either.
    let leftovers: Vec<_> = std::fs::read_dir(d)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().contains("partial"))
        .collect();
    assert!(leftovers.is_empty());
    let o = futago(&[
        "world",
        "export",
        "worlds/lab.toml",
        "--band",
        "0.3:0.1",
        "--out",
        d.join("w").to_str().unwrap(),
    ]);
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("--band"));
}

#[test]
fn world_export_writes_map_server_grid_and_meshes() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("office");
    ok(&futago(&[
        "world",
        "export",
        "worlds/office.toml",
        "--out",
        out.to_str().unwrap(),
        "--resolution",
        "0.05",
    ]));
    let yaml = std::fs::read_to_string(out.join("office.yaml")).unwrap();
    assert!(
        yaml.contains("image: office.pgm")
            && yaml.contains("resolution: 0.05")
            && yaml.contains("mode: trinary")
    );
    let pgm = std::fs::read(out.join("office.pgm")).unwrap();
    let header: Vec<&str> = std::str::from_utf8(&pgm[..80])
        .unwrap_or_else(|e| std::str::from_utf8(&pgm[..e.valid_up_to()]).unwrap())
        .lines()
        .take(4)
        .collect();
    assert_eq!(header[0], "P5");
    let dims: Vec<usize> = header[2]
        .split_whitespace()
        .map(|v| v.parse().unwrap())
        .collect();
    // 30 m × 16 m floor plus walls and a 0.5 m margin, at 5 cm.
    assert!(
        (dims[0] as f64 * 0.05 - 31.75).abs() < 0.2 && (dims[1] as f64 * 0.05 - 17.75).abs() < 0.2,
        "{dims:?}"
    );
    let px = &pgm[pgm.len() - dims[0] * dims[1]..];
    let occupied = px.iter().filter(|&&v| v == 0).count() as f64 / px.len() as f64;
    assert!(
        occupied > 0.02 && occupied < 0.2,
        "occupied fraction {occupied}"
    );
    assert!(out.join("office.glb").exists() && out.join("office.ply").exists());
    let o = futago(&["world", "info", "worlds/office.toml"]);
    ok(&o);
    assert!(String::from_utf8_lossy(&o.stdout).contains("spawns: dock"));
}

/// Every shipped scenario runs, and its scorers produce exactly the metric names they declare
/// (`futago metrics`, which gates and tuning are checked against): none undeclared, none
/// declared but missing. Twelve seconds drive every robot over a metre, which the relative
/// pose error needs.
#[test]
fn every_shipped_scenario_loads_and_runs() {
    let tmp = tempfile::tempdir().unwrap();
    let mut n = 0;
    for e in std::fs::read_dir(root().join("scenarios")).unwrap() {
        let p = e.unwrap().path();
        if p.extension().and_then(|x| x.to_str()) != Some("toml") {
            continue;
        }
        n += 1;
        let out = tmp.path().join(p.file_stem().unwrap());
        // Gates judge the whole run; two seconds of it may fail them (status 3), but the run
        // itself must succeed and write everything.
        let o = futago(&[
            "run",
            p.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "-q",
            "--duration",
            "12",
        ]);
        assert!(
            matches!(o.status.code(), Some(0 | 3)),
            "{}: {}",
            p.display(),
            String::from_utf8_lossy(&o.stderr)
        );
        let s = summary(&out);
        assert!(
            (s["sim_time_s"].as_f64().unwrap() - 12.0).abs() < 1e-9
                || s["controller_finished"].as_bool().unwrap()
        );
        let listed = futago(&["metrics", p.to_str().unwrap()]);
        ok(&listed);
        let declared: std::collections::BTreeSet<String> = String::from_utf8_lossy(&listed.stdout)
            .lines()
            .map(String::from)
            .collect();
        let produced: std::collections::BTreeSet<String> =
            s["metrics"].as_object().unwrap().keys().cloned().collect();
        assert!(
            produced.is_subset(&declared),
            "{}: produced but not declared: {:?}",
            p.display(),
            produced.difference(&declared).collect::<Vec<_>>()
        );
        // The relative pose error is taken over 1 m of travel: a slow robot (seed 004's
        // 0.1 m/s) may not have driven that far in the 12 s, and then has none yet.
        let travelled = s["robot"]["distance_travelled_m"].as_f64().unwrap();
        let missing: Vec<&String> = declared
            .difference(&produced)
            .filter(|n| travelled >= 1.0 || !n.contains(".rpe_1m."))
            .collect();
        assert!(
            missing.is_empty(),
            "{}: declared but not produced: {missing:?}",
            p.display(),
        );
        // Every file the run wrote has its digest, but the summary and the report.
        let files = s["files"].as_object().unwrap();
        for e in std::fs::read_dir(&out).unwrap() {
            let name = e.unwrap().file_name().to_string_lossy().to_string();
            let key = if out.join(&name).is_dir() {
                format!("{name}/")
            } else {
                name.clone()
            };
            // The marker that says futago wrote the folder is written after the summary.
            if name != "summary.json" && name != "report.html" && name != ".futago-output.json" {
                assert!(
                    files.contains_key(&key),
                    "{}: no digest of {key}",
                    p.display()
                );
            }
        }
        assert_eq!(
            s["robot"]["wheel_drop_steps"].as_u64().unwrap(),
            0,
            "{}",
            p.display()
        );
    }
    assert!(n >= 5, "scenarios found: {n}");
}

/// A kidnapping: the robot, driven by the navigator on the node graph, is carried from the
/// west room to the east one; Monte Carlo localisation loses it and finds it again.
#[test]
fn mcl_recovers_from_a_kidnapping_between_rooms() {
    let tmp = tempfile::tempdir().unwrap();
    let world = write(tmp.path(), "two-rooms.toml", TWO_ROOMS);
    let scenario = write(
        tmp.path(),
        "kidnap.toml",
        format!(
            "name = \"kidnap\"\nworld = {world:?}\nduration = 60.0\nseed = 4\n\
             start = {{ x = 1.0, y = 1.0, yaw_deg = 0.0 }}\n\
             [[lidar]]\nname = \"front\"\npreset = \"urg-04lx\"\nxyz = [0.08, 0.0, 0.2]\n\
             [localization]\nrate = 4.0\n[localization.mcl]\nmodel = \"likelihood_field\"\n\
             [[event]]\ntime = 10.0\nteleport = {{ x = 5.2, y = 2.0, yaw_deg = 90.0 }}\n\
             [controller]\ntype = \"navigate\"\npose_source = \"ground_truth\"\n\
             goals = [[2.0, 3.0], [1.0, 1.0], [3.8, 3.5], [1.5, 2.0]]\n\
             [[gate]]\nmetric = \"localization.ate.median_m\"\nop = \"<\"\nvalue = 0.2\n\
             [[gate]]\nmetric = \"localization.ate.max_m\"\nop = \"<\"\nvalue = 1.0\n"
        ),
    );
    let out = tmp.path().join("out");
    // The kidnapping breaks the second gate: the run writes everything, says which gate failed
    // and by how much, and exits with status 3.
    let o = futago(&[
        "run",
        scenario.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "-q",
    ]);
    exits_with(&o, 3);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("gate failed: localization.ate.max_m = "),
        "{err}"
    );
    assert!(err.contains("not < 1 (margin -"), "{err}");
    assert!(!err.contains("median"), "{err}");
    let s = summary(&out);
    assert_eq!(s["gates"][0]["passed"], true);
    assert_eq!(s["gates"][1]["passed"], false);
    let l = &s["localization"];
    assert!(
        l["max_position_error_m"].as_f64().unwrap() > 2.0,
        "it was lost: {l}"
    );
    let k = &l["kidnappings"][0];
    assert_eq!(k["time_s"], 10.0);
    let after = k["recovered_after_s"].as_f64().expect("recovered");
    assert_eq!(
        s["metrics"]["localization.recovery_s"].as_f64(),
        Some(after)
    );
    assert!(after < 30.0, "{l}");
    assert!(l["final_position_error_m"].as_f64().unwrap() < 0.1, "{l}");
    assert_eq!(s["robot"]["bump_events"], 0, "{s}");
    assert!(
        s["navigation"]["stats"]["goals_reached"].as_u64().unwrap() >= 2,
        "{s}"
    );
}

/// A suite: scenarios run in parallel; a broken gate fails the suite with exit status 3 and a
/// JUnit failure naming it; shards split the files; an empty suite is refused.
#[test]
fn a_suite_runs_in_parallel_and_reports_gates_as_junit() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("suite");
    std::fs::create_dir(&dir).unwrap();
    let world = root().join("worlds/lab.toml");
    for (name, limit) in [("a", 1.0), ("b", -1.0), ("c", 1.0)] {
        write(
            &dir,
            &format!("{name}.toml"),
            format!(
                "name = \"{name}\"\nworld = {world:?}\nduration = 2.0\nstart = \"centre\"\n\
                 [controller]\ntype = \"segments\"\nsegments = [{{ duration = 2.0, velocity = 0.2 }}]\n\
                 [[gate]]\nmetric = \"odometry.ate.max_m\"\nop = \"<\"\nvalue = {limit}\n"
            ),
        );
    }
    let out = tmp.path().join("out");
    let o = futago(&[
        "suite",
        dir.to_str().unwrap(),
        "--jobs",
        "2",
        "--out",
        out.to_str().unwrap(),
    ]);
    exits_with(&o, 3);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        stdout.contains("gate failed: odometry.ate.max_m = "),
        "{stdout}"
    );
    let s: serde_json::Value = json_file(&out.join("suite.json"));
    assert_eq!(
        (s["passed"].as_u64(), s["failed"].as_u64()),
        (Some(2), Some(1))
    );
    let x = std::fs::read_to_string(out.join("junit.xml")).unwrap();
    assert!(x.contains("tests=\"6\" failures=\"1\" errors=\"0\""), "{x}");
    assert!(
        x.contains("<failure message=\"odometry.ate.max_m = "),
        "{x}"
    );
    for name in ["a", "b", "c"] {
        assert!(out.join(name).join("summary.json").exists());
    }
    // The same runs one at a time give the same metrics.
    let out1 = tmp.path().join("out1");
    futago(&[
        "suite",
        dir.to_str().unwrap(),
        "--jobs",
        "1",
        "--out",
        out1.to_str().unwrap(),
    ]);
    let s1: serde_json::Value = json_file(&out1.join("suite.json"));
    for (a, b) in s["results"]
        .as_array()
        .unwrap()
        .iter()
        .zip(s1["results"].as_array().unwrap())
    {
        assert_eq!(a["metrics"], b["metrics"]);
    }
    // Shard 2 of 2 is the second file only (b: its gate fails).
    let out2 = tmp.path().join("out2");
    let o = futago(&[
        "suite",
        dir.to_str().unwrap(),
        "--shard",
        "2/2",
        "--out",
        out2.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(3));
    let s2: serde_json::Value = json_file(&out2.join("suite.json"));
    assert_eq!(s2["scenarios"], 1);
    assert_eq!(s2["results"][0]["scenario"], "b");
    // Shard 1 of 2 (a and c) merged with shard 2 gives the whole suite back.
    let out3 = tmp.path().join("out3");
    futago(&[
        "suite",
        dir.to_str().unwrap(),
        "--shard",
        "1/2",
        "--out",
        out3.to_str().unwrap(),
    ]);
    let merged = tmp.path().join("merged");
    let o = futago(&[
        "merge",
        out3.to_str().unwrap(),
        out2.to_str().unwrap(),
        "--out",
        merged.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(3));
    let m: serde_json::Value = json_file(&merged.join("suite.json"));
    assert_eq!(
        (m["passed"].as_u64(), m["failed"].as_u64()),
        (Some(2), Some(1))
    );
    for (a, b) in m["results"]
        .as_array()
        .unwrap()
        .iter()
        .zip(s["results"].as_array().unwrap())
    {
        assert_eq!(
            (&a["scenario"], &a["metrics"]),
            (&b["scenario"], &b["metrics"])
        );
    }
    assert_eq!(
        std::fs::read_to_string(merged.join("junit.xml"))
            .unwrap()
            .matches("<testcase ")
            .count(),
        6
    );
    // Merging a shard twice is refused.
    let o = futago(&[
        "merge",
        out2.to_str().unwrap(),
        out2.to_str().unwrap(),
        "--out",
        merged.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("more than one shard"));
    // An empty suite is an error before anything runs.
    let empty = tmp.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    let o = futago(&["suite", empty.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("the suite is empty"));
}

#[test]
fn a_seed_sweep_reports_mean_and_spread_and_overlays_apply_to_every_run() {
    let tmp = tempfile::tempdir().unwrap();
    let world = root().join("worlds/lab.toml");
    let scenario = write(
        tmp.path(),
        "sweep.toml",
        format!(
            "name = \"sweep\"\nworld = {world:?}\nduration = 3.0\nstart = \"centre\"\nseeds = [1, 2, 3]\n\
             [robot.odometry]\nnoise = 0.05\n\
             [controller]\ntype = \"segments\"\nsegments = [{{ duration = 3.0, velocity = 0.2, radius = 0.5 }}]\n\
             [[gate]]\nmetric = \"odometry.ate.max_m\"\nop = \"<\"\nvalue = 1.0\n"
        ),
    );
    let out = tmp.path().join("out");
    let o = futago(&[
        "suite",
        scenario.to_str().unwrap(),
        "--jobs",
        "2",
        "--set",
        "duration=2.0",
        "--out",
        out.to_str().unwrap(),
    ]);
    ok(&o);
    assert!(
        String::from_utf8_lossy(&o.stdout)
            .contains("sweep  sweep: 3 of 3 seeds passed; odometry.ate.max_m "),
        "{}",
        String::from_utf8_lossy(&o.stdout)
    );
    let s = json_file(&out.join("suite.json"));
    assert_eq!(s["scenarios"], 3);
    let mut values = Vec::new();
    for seed in [1, 2, 3] {
        let run = summary(&out.join(format!("sweep/seed-{seed}")));
        assert_eq!(run["seed"], seed);
        // The overlay shortened every run, and the run records it.
        assert!(
            (run["sim_time_s"].as_f64().unwrap() - 2.0).abs() < 0.05,
            "{run}"
        );
        assert_eq!(run["overlays"], serde_json::json!(["--set"]));
        values.push(run["metrics"]["odometry.ate.max_m"].as_f64().unwrap());
    }
    assert!(values[0] != values[1], "seeds must differ: {values:?}");
    let mean = values.iter().sum::<f64>() / 3.0;
    let std = (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / 2.0).sqrt();
    let m = &s["sweeps"]["sweep"]["metrics"]["odometry.ate.max_m"];
    assert!((m["mean"].as_f64().unwrap() - mean).abs() < 1e-12, "{m}");
    assert!((m["std"].as_f64().unwrap() - std).abs() < 1e-12, "{m}");
    let text = std::fs::read_to_string(out.join("sweep/seed-2/scenario.toml")).unwrap();
    assert!(
        text.contains("duration = 2.0") && text.contains("#   --set: duration"),
        "{text}"
    );
    let page = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(page.contains("href=\"sweep/seed-3/report.html\""));
    assert!(page.contains("<table class=\"sweeps\">"));
    // A malformed overlay or a bad --set stops the suite before anything runs.
    let bad = write(tmp.path(), "bad.toml", "[robot\nx = 1\n");
    let empty_overlay = write(tmp.path(), "empty.toml", "# nothing\n");
    let unknown = write(
        tmp.path(),
        "unknown.toml",
        "[slam]\nmethod = \"icp\"\n[robot]\nwheel_bsae = 0.3\n",
    );
    for (args, expect) in [
        (
            vec!["--overlay", bad.to_str().unwrap()],
            "bad.toml:1: TOML syntax error",
        ),
        (
            vec!["--overlay", empty_overlay.to_str().unwrap()],
            "empty.toml: the overlay is empty",
        ),
        (
            vec!["--overlay", unknown.to_str().unwrap()],
            "unknown.toml: key `robot.wheel_bsae`: unknown field",
        ),
        (
            vec!["--set", "robot.odometry=3"],
            "--set: key `robot.odometry`: invalid type",
        ),
        (
            vec!["--set", "duration"],
            "--set: key `duration`: expected PATH=VALUE",
        ),
        (
            vec!["--overlay", "/nonexistent/o.toml"],
            "/nonexistent/o.toml: cannot read file",
        ),
    ] {
        let mut a = vec!["suite", scenario.to_str().unwrap()];
        a.extend(args);
        refused_before_running(&a, &tmp.path().join("fresh"), expect, Some(1));
    }
}

#[test]
fn tune_calibrates_a_wheel_base_error_found_by_hand_and_its_overlay_reproduces_the_best() {
    // Odometry that believes the wheel base 2.5 % too long, without noise: the error of the
    // odometry's path vanishes at a ratio of exactly 1, the answer the search must find.
    let tmp = tempfile::tempdir().unwrap();
    let world = root().join("worlds/lab.toml");
    let scenario = write(
        tmp.path(),
        "cal.toml",
        format!(
            "name = \"calibrate\"\nworld = {world:?}\nduration = 6.0\nstart = \"centre\"\n\
             [robot.odometry]\nwheel_base_ratio = 1.025\nnoise = 0.0\nquantize = false\n\
             [controller]\ntype = \"segments\"\nsegments = [{{ duration = 6.0, velocity = 0.3, radius = 0.6 }}]\n"
        ),
    );
    let sc = scenario.to_str().unwrap();
    let tune = |out: &Path, jobs: &str| {
        futago(&[
            "tune",
            sc,
            "--param",
            "robot.odometry.wheel_base_ratio=0.97..1.03",
            "--objective",
            "odometry.ate.max_m",
            "--budget",
            "16",
            "--seeds",
            "1,2",
            "--jobs",
            jobs,
            "--out",
            out.to_str().unwrap(),
        ])
    };
    let out = tmp.path().join("tune");
    ok(&tune(&out, "2"));
    let t = json_file(&out.join("tune.json"));
    let baseline = t["baseline"]["objective"].as_f64().unwrap();
    let best = t["best"]["objective"].as_f64().unwrap();
    let ratio = t["best"]["values"][0].as_f64().unwrap();
    assert!((ratio - 1.0).abs() < 0.003, "best wheel_base_ratio {ratio}");
    assert!(best < baseline / 5.0, "{baseline} -> {best}");
    assert_eq!(t["trials"].as_array().unwrap().len(), 17);
    let csv = std::fs::read_to_string(out.join("trials.csv")).unwrap();
    assert!(csv.starts_with("trial,generation,robot.odometry.wheel_base_ratio,odometry.ate.max_m,seed_1,seed_2,error\n0,0,1.025,"), "{csv}");
    assert_eq!(csv.lines().count(), 18);
    let page = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(page.contains("<table class=\"trials\">") && page.contains("<circle "));
    // The overlay it wrote gives the best trial's value again.
    let run = tmp.path().join("run");
    ok(&futago(&[
        "run",
        sc,
        "--overlay",
        out.join("best.toml").to_str().unwrap(),
        "--seed",
        "1",
        "--out",
        run.to_str().unwrap(),
        "-q",
    ]));
    assert_eq!(
        summary(&run)["metrics"]["odometry.ate.max_m"]
            .as_f64()
            .unwrap(),
        t["best"]["per_seed"][0].as_f64().unwrap()
    );
    // One job or two: the same search, to the byte.
    let out1 = tmp.path().join("tune1");
    ok(&tune(&out1, "1"));
    assert_eq!(
        csv,
        std::fs::read_to_string(out1.join("trials.csv")).unwrap()
    );
    // Bad requests are refused before anything runs.
    for (args, expect) in [
        (
            vec![
                "--param",
                "robot.odometry.wheel_bsae=0.9..1.1",
                "--objective",
                "odometry.ate.max_m",
            ],
            "unknown field `wheel_bsae`",
        ),
        (
            vec![
                "--param",
                "robot.odometry.wheel_base_ratio=0.9..1.1",
                "--objective",
                "slam.ate.rmse_m",
            ],
            "produces no metric `slam.ate.rmse_m`",
        ),
        (
            vec![
                "--param",
                "robot.odometry.wheel_base_ratio=-1..1.1",
                "--objective",
                "odometry.ate.max_m",
            ],
            "low end does not give a valid scenario",
        ),
        (
            vec![
                "--param",
                "robot.odometry.wheel_base_ratio=1.1..0.9",
                "--objective",
                "odometry.ate.max_m",
            ],
            "LO must be below HI",
        ),
        (
            vec![
                "--param",
                "robot.odometry.wheel_base_ratio=0.9..1.1",
                "--objective",
                "odometry.ate.max_m",
                "--budget",
                "0",
            ],
            "--budget",
        ),
    ] {
        let mut a = vec!["tune", sc];
        a.extend(args);
        refused_before_running(&a, &tmp.path().join("fresh"), expect, None);
    }
}

#[test]
fn an_rgbd_map_is_scored_against_the_surfaces_it_saw_and_a_worse_pose_scores_worse() {
    let tmp = tempfile::tempdir().unwrap();
    let world = root().join("worlds/lab.toml");
    let scenario = write(
        tmp.path(),
        "map.toml",
        format!(
            "name = \"map\"\nworld = {world:?}\nduration = 14.0\nseed = 1\nstart = \"centre\"\n\
             [robot.odometry]\nwheel_base_ratio = 1.03\n\
             [[camera]]\nname = \"kinect\"\npreset = \"seed000\"\nxyz = [0.1, 0.0, 0.42]\nnoise = {{ model = \"nguyen\" }}\n\
             [rgbd_map]\npose_source = \"ground_truth\"\nmethods = [\"pose\"]\n\
             [controller]\ntype = \"waypoints\"\nspeed = 0.3\npose_source = \"ground_truth\"\n\
             waypoints = [[9.5, 3.5], [9.5, 5.0], [6.0, 5.0]]\n"
        ),
    );
    let sc = scenario.to_str().unwrap();
    let truth = tmp.path().join("truth");
    run_for(&scenario, &truth, None);
    let odo = tmp.path().join("odo");
    ok(&futago(&[
        "run",
        sc,
        "--out",
        odo.to_str().unwrap(),
        "-q",
        "--set",
        "rgbd_map.pose_source=odometry",
    ]));
    let (a, b) = (summary(&truth), summary(&odo));
    let m =
        |s: &serde_json::Value, k: &str| s["metrics"][format!("rgbd_map.{k}")].as_f64().unwrap();
    // The same odometry run with a 2D map (the one a localiser would be given) registered by
    // the map term alone and by the full method, gated against the pose alone.
    let reg = tmp.path().join("reg");
    let gate = tmp.path().join("gate.toml");
    std::fs::write(
        &gate,
        "[[lidar]]\nname = \"front\"\npreset = \"seed000\"\nxyz = [0.08, 0.0, 0.2]\n\
         [localization]\nrate = 4.0\n[rgbd_map]\npose_source = \"odometry\"\n\
         methods = [\"pose\", \"map\", \"full\"]\n\
         [[gate]]\nmetric = \"rgbd_map.full.f1_5cm\"\nop = \">\"\nthan = \"rgbd_map.pose.f1_5cm\"\n\
         [[gate]]\nmetric = \"rgbd_map.pose.f1_5cm\"\nop = \">\"\nthan = \"rgbd_map.map.f1_5cm\"\n",
    )
    .unwrap();
    let out = futago(&[
        "run",
        sc,
        "--out",
        reg.to_str().unwrap(),
        "-q",
        "--overlay",
        gate.to_str().unwrap(),
    ]);
    let r = summary(&reg);
    // The first method's scores are also the unprefixed ones, and are the pose's.
    assert_eq!(m(&r, "f1_5cm"), m(&r, "pose.f1_5cm"));
    assert_eq!(m(&r, "pose.f1_5cm"), m(&b, "f1_5cm"));
    // Odometry's heading is off by about 1° here; the map term turns the keyframes back onto
    // the walls (measured F1 at 5 cm: pose 0.845, map 0.877, full 0.876).
    for method in ["map", "full"] {
        assert!(
            m(&r, &format!("{method}.f1_5cm")) > m(&r, "pose.f1_5cm") + 0.015,
            "{method}: {}",
            r["metrics"]
        );
    }
    // The slice picture (red points over the grid) and the report's table of the methods.
    let slice = image::open(reg.join("rgbd_slice.png")).unwrap().to_rgb8();
    let red = slice.pixels().filter(|p| p.0 == [220, 30, 30]).count();
    assert!(red > 500, "{red} slice pixels");
    let html = std::fs::read_to_string(reg.join("report.html")).unwrap();
    assert!(
        html.contains("<table class=\"rgbd-methods\">"),
        "no methods table"
    );
    for method in ["pose", "map", "full"] {
        assert!(html.contains(&format!("<td>{method}</td>")), "{method}");
    }
    assert!(html.contains("<img class=\"slice\" src=\"data:image/png;base64,"));
    // The relative gates: the first holds, the second (the pose ahead of the map) does not,
    // and the run says so.
    let gates = r["gates"].as_array().unwrap();
    assert_eq!(gates[0]["passed"], true, "{gates:?}");
    assert_eq!(gates[1]["passed"], false, "{gates:?}");
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("rgbd_map.pose.f1_5cm")
            || String::from_utf8_lossy(&out.stdout).contains("rgbd_map.pose.f1_5cm")
    );
    // Placed by the true pose, only the Kinect's noise is left: nearly all the map lies within
    // 5 cm of the true surfaces, and the mean distance is about a centimetre. Completeness is
    // lower (measured 0.82 to 0.83): the noise model drops pixels that the noiseless view
    // keeps. (F1 at 5 cm measured 0.900 on GL and a little more on Vulkan.)
    assert!(m(&a, "accuracy_5cm") > 0.97, "{a}");
    assert!(m(&a, "f1_5cm") > 0.85, "{a}");
    assert!(m(&a, "mean_distance_m") < 0.02, "{a}");
    assert!(
        m(&a, "accuracy_1cm") < m(&a, "accuracy_2cm")
            && m(&a, "accuracy_2cm") <= m(&a, "accuracy_5cm")
    );
    // Placed by odometry with a 3 % wheel-base error, it is worse on every count.
    for k in ["f1_2cm", "f1_5cm", "accuracy_5cm"] {
        assert!(
            m(&b, k) < m(&a, k) - 0.05,
            "{k}: {} vs {}",
            m(&b, k),
            m(&a, k)
        );
    }
    assert!(m(&b, "mean_distance_m") > m(&a, "mean_distance_m") + 0.005);
    // The laser-height slice lies on the true walls (5 cm cells) when placed by the true pose,
    // farther off when placed by odometry: by half a centimetre, as the mean distance above.
    // (Measured 0.012 m against 0.019 m; 0.023 m with the Kinect noise drawn before issue 48's
    // stop 89, the median moving with the noise's draws. The RMS is not tested here: the lab's
    // box, which the robot can push, is not among the static walls, and its points weigh on
    // the RMS.)
    let (sa, sb) = (m(&a, "slice_median_m"), m(&b, "slice_median_m"));
    assert!(sa < 0.04 && sb > sa + 0.005, "{sb} vs {sa}");
    // The map and the truth are PLY files with as many points as the summary says.
    let counts = &a["rgbd_map"];
    assert!(counts["keyframes"].as_u64().unwrap() >= 5, "{counts}");
    for (file, key) in [
        ("rgbd_map.ply", "map_points"),
        ("rgbd_map_truth.ply", "truth_points"),
    ] {
        let bytes = std::fs::read(truth.join(file)).unwrap();
        let head = String::from_utf8_lossy(&bytes[..300]).to_string();
        let n = counts[key].as_u64().unwrap();
        assert!(
            head.contains(&format!("element vertex {n}\n")),
            "{file}: {head}"
        );
        let end = head.find("end_header\n").unwrap() + "end_header\n".len();
        assert_eq!(bytes.len() - end, 15 * n as usize, "{file}");
    }
    // The polygon map: the lab's floor and walls, far fewer faces than planes found.
    let faces = counts["plane_faces"].as_u64().unwrap();
    assert!(
        faces >= 2 && faces < counts["planes_found"].as_u64().unwrap(),
        "{counts}"
    );
    let ply = std::fs::read(truth.join("rgbd_planes.ply")).unwrap();
    let head = String::from_utf8_lossy(&ply[..400]).to_string();
    assert!(head.contains(&format!("element face {faces}\n")), "{head}");
    assert!(
        head.contains(&format!("element vertex {}\n", counts["plane_vertices"])),
        "{head}"
    );
    // Bad tables are refused before anything runs.
    for (set, expect) in [
        (
            "rgbd_map.pose_source=slam",
            "this pose source needs a [slam] table",
        ),
        ("rgbd_map.pose_source=compass", "rgbd_map.pose_source"),
        (
            "rgbd_map.stride=0",
            "key `rgbd_map.stride`: expected a whole number in [1, 1000], found 0",
        ),
        ("camera=[]", "an RGB-D map needs a [[camera]]"),
    ] {
        refused_before_running(
            &["run", sc, "--set", set],
            &tmp.path().join("fresh"),
            expect,
            Some(1),
        );
    }
}

/// A headless browser, if this machine has one: `FUTAGO_CHROMIUM`, else Debian's `chromium`
/// or Google's `google-chrome`.
fn browser() -> Option<PathBuf> {
    if let Ok(p) = std::env::var("FUTAGO_CHROMIUM") {
        return Some(PathBuf::from(p));
    }
    ["chromium", "chromium-browser", "google-chrome"]
        .iter()
        .find(|b| {
            Command::new(b)
                .arg("--version")
                .output()
                .is_ok_and(|o| o.status.success())
        })
        .map(PathBuf::from)
}

/// Opens `page` in headless Chromium: returns the DOM it built and a screenshot of it.
fn render_page(chromium: &Path, page: &Path, profile: &Path) -> (String, image::RgbImage) {
    let shot = profile.join("shot.png");
    let common = [
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--hide-scrollbars",
        "--window-size=1200,2600",
    ];
    let url = format!("file://{}", page.display());
    let user = format!("--user-data-dir={}", profile.display());
    let o = Command::new(chromium)
        .args(common)
        .arg(&user)
        .arg("--dump-dom")
        .arg(&url)
        .output()
        .expect("chromium runs");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let dom = String::from_utf8_lossy(&o.stdout).to_string();
    let o = Command::new(chromium)
        .args(common)
        .arg(&user)
        .arg(format!("--screenshot={}", shot.display()))
        .arg(&url)
        .output()
        .expect("chromium runs");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    (dom, image::open(&shot).expect("a PNG screenshot").to_rgb8())
}

/// Pixels of the screenshot within `tol` of `rgb` on every channel.
fn pixels_like(img: &image::RgbImage, rgb: [u8; 3], tol: i32) -> usize {
    img.pixels()
        .filter(|p| (0..3).all(|c| (p[c] as i32 - rgb[c] as i32).abs() <= tol))
        .count()
}

#[test]
fn reports_render_their_figures_and_tables_in_headless_chromium() {
    let Some(chromium) = browser() else {
        assert!(
            std::env::var_os("FUTAGO_REQUIRE_BROWSER").is_none(),
            "FUTAGO_REQUIRE_BROWSER is set but no chromium was found"
        );
        eprintln!("skipped: no headless browser (install Debian's chromium)");
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    // A suite of one MCL run, with a gate that fails so that the pages show both states.
    let scenario = root().join("scenarios/office-mcl.toml");
    let o = futago(&[
        "suite",
        scenario.to_str().unwrap(),
        "--set",
        "duration=40.0",
        "--set",
        "gate=[{ metric = 'localization.ate.max_m', op = '<', value = 0.3 }, { metric = 'odometry.ate.max_m', op = '<', value = 0.001 }]",
        "--out",
        out.to_str().unwrap(),
    ]);
    exits_with(&o, 3);
    let run_page = out.join("office-mcl/report.html");
    let (dom, shot) = render_page(&chromium, &run_page, &tmp.path().join("p1"));
    // The browser built the figures and tables.
    assert!(dom.contains("<svg class=\"map\""), "no map figure");
    assert_eq!(
        dom.matches("<svg class=\"chart\"").count(),
        2,
        "error charts"
    );
    for series in ["ground truth", "odometry", "localization"] {
        assert!(dom.contains(&format!("data-name=\"{series}\"")), "{series}");
    }
    for t in ["gates", "metrics", "facts"] {
        assert!(dom.contains(&format!("<table class=\"{t}\">")), "{t} table");
    }
    assert!(dom.contains("localization.ate.rmse_m"));
    assert!(dom.contains("<pre class=\"config\">"));
    // And drew them: the map's walls (grey cells of the embedded PNG), the truth's green
    // line, the localiser's purple one and the error charts' red odometry line.
    for (what, rgb, at_least) in [
        ("walls", [120, 120, 120], 2000),
        ("ground truth", [0x1a, 0x96, 0x41], 150),
        ("localization", [0x7b, 0x32, 0x94], 150),
        ("odometry", [0xd7, 0x19, 0x1c], 150),
    ] {
        let n = pixels_like(&shot, rgb, 12);
        assert!(n >= at_least, "{what}: {n} pixels");
    }
    // The suite's page: its runs table with a link to the run's page, and the headroom of each
    // gate drawn as a bar, red for the one that failed.
    let (dom, shot) = render_page(&chromium, &out.join("report.html"), &tmp.path().join("p2"));
    assert!(dom.contains("<table class=\"runs\">"));
    assert!(dom.contains("href=\"office-mcl/report.html\""));
    assert!(dom.matches("<rect class=\"bar\"").count() >= 2);
    assert!(
        pixels_like(&shot, [0xd7, 0x19, 0x1c], 12) >= 50,
        "no red bar"
    );
}

/// Points of a depth PNG's row `v`, in the world, from `camera.yaml` and the frame's pose.
fn world_points(
    seq: &Path,
    depth_file: &str,
    pose: &futago_msgs::Pose3,
    v: u32,
) -> Vec<glam::DVec3> {
    let yaml = std::fs::read_to_string(seq.join("camera.yaml")).unwrap();
    let depth_part = &yaml[yaml.find("depth:").unwrap()..];
    let get = |k: &str| -> f64 {
        let line = depth_part
            .lines()
            .find(|l| l.trim_start().starts_with(&format!("{k}:")))
            .unwrap();
        line.split(':').nth(1).unwrap().trim().parse().unwrap()
    };
    let (fx, fy, cx, cy) = (get("fx"), get("fy"), get("cx"), get("cy"));
    let img = image::open(seq.join(depth_file)).unwrap().into_luma16();
    let q = glam::DQuat::from_xyzw(
        pose.rotation[0],
        pose.rotation[1],
        pose.rotation[2],
        pose.rotation[3],
    );
    let t = glam::DVec3::from_array(pose.translation);
    (0..img.width())
        .filter_map(|u| {
            let d = img.get_pixel(u, v)[0];
            (d > 0).then(|| {
                let z = d as f64 / 5000.0;
                t + q * glam::DVec3::new((u as f64 - cx) / fx * z, (v as f64 - cy) / fy * z, z)
            })
        })
        .collect()
}

#[test]
fn rgbd_dataset_is_a_tum_sequence_that_lands_on_the_floor_and_repeats() {
    let tmp = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(root().join("scenarios/lab-kinect.toml"))
        .unwrap()
        .replace(
            "../worlds/lab.toml",
            root().join("worlds/lab.toml").to_str().unwrap(),
        )
        .replace(
            "noise = { model = \"nguyen\" }",
            "noise = { model = \"none\" }",
        );
    let scenario = write(tmp.path(), "k.toml", &text);
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    for d in [&a, &b] {
        run_for(&scenario, d, Some("1"));
    }
    let (sa, sb) = (summary(&a), summary(&b));
    assert_eq!(sa["files"], sb["files"], "the dataset differs between runs");
    assert!(sa["files"]["kinect/"]["sha256"].is_string());
    assert!(sa["performance"]["renderer"].is_string());
    let seq = a.join("kinect");
    let rgb =
        futago_msgs::tum::parse_image_list(&std::fs::read_to_string(seq.join("rgb.txt")).unwrap())
            .unwrap();
    let depth = futago_msgs::tum::parse_image_list(
        &std::fs::read_to_string(seq.join("depth.txt")).unwrap(),
    )
    .unwrap();
    let gt =
        futago_msgs::tum::parse(&std::fs::read_to_string(seq.join("groundtruth.txt")).unwrap())
            .unwrap();
    // 30 Hz for 1 s.
    assert!((30..=31).contains(&rgb.len()), "{} frames", rgb.len());
    assert_eq!(
        sa["camera"][0]["frames"].as_u64().unwrap() as usize,
        rgb.len()
    );
    assert_eq!(rgb.len(), depth.len());
    assert_eq!(gt.len(), rgb.len());
    for ((r, d), g) in rgb.iter().zip(&depth).zip(&gt) {
        assert_eq!(r.0, d.0);
        assert_eq!(r.0, g.stamp);
        let c = image::open(seq.join(&r.1)).unwrap();
        assert_eq!(
            (c.width(), c.height(), c.color()),
            (640, 480, image::ColorType::Rgb8)
        );
        let z = image::open(seq.join(&d.1)).unwrap();
        assert_eq!(
            (z.width(), z.height(), z.color()),
            (640, 480, image::ColorType::L16)
        );
    }
    // The bottom row sees the floor 1.07 m ahead: intrinsics, depth factor and the optical
    // frame's pose must all be right for its points to land on z = 0.
    for (i, d) in depth.iter().enumerate().step_by(10) {
        let pts = world_points(&seq, &d.1, &gt[i].pose, 479);
        let on_floor = pts.iter().filter(|p| p.z.abs() < 0.002).count();
        assert!(
            on_floor * 2 > 640,
            "frame {i}: {on_floor} of {} bottom-row points on the floor",
            pts.len()
        );
    }

    // Without a consumer the camera is never rendered.
    let quiet = write(
        tmp.path(),
        "q.toml",
        text.replace("rgbd_dataset = true", "rgbd_dataset = false"),
    );
    let c = tmp.path().join("c");
    run_for(&quiet, &c, Some("1"));
    let sc = summary(&c);
    assert_eq!(sc["camera"][0]["frames"], 0);
    assert!(sc["performance"]["renderer"].is_null());
    assert!(!c.join("kinect").exists());
}

#[test]
fn a_missing_gpu_driver_is_a_clear_error() {
    let o = Command::new(env!("CARGO_BIN_EXE_futago"))
        .args([
            "bench",
            "sensors",
            "--frames",
            "1",
            "--batches",
            "1",
            "--rays",
            "1",
        ])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .env("FUTAGO_GPU_BACKEND", "vulkan")
        .env("VK_ICD_FILENAMES", "/nonexistent/icd.json")
        .env("VK_DRIVER_FILES", "/nonexistent/icd.json")
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("no GPU adapter") && err.contains("mesa-vulkan-drivers"),
        "{err}"
    );
    let o = Command::new(env!("CARGO_BIN_EXE_futago"))
        .args(["bench", "sensors", "--frames", "1"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .env("FUTAGO_GPU_BACKEND", "directx")
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("FUTAGO_GPU_BACKEND"));
}

/// `futago bench sim` measures scenarios whose stack reads the lasers: the physics-only run
/// leaves the stack out and drives the scenario's controller on the true pose (office-mcl,
/// which drives on its localiser), or stands still where the controller needs the stack
/// (exploration on SLAM's map); both runs simulate the asked time.
#[test]
fn the_simulator_bench_runs_scenarios_whose_stack_reads_the_lasers() {
    for (sc, drives) in [
        ("scenarios/office-mcl.toml", true),
        ("scenarios/office-explore.toml", false),
    ] {
        let o = futago(&["bench", "sim", sc, "--duration", "3", "--rays", "1000"]);
        ok(&o);
        let b: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        let sim = b["sim_time_s"].as_f64().unwrap();
        assert!((sim - 3.0).abs() < 0.05, "{sc}: {b}");
        assert_eq!(b["with_lasers"]["lasers_read"], true, "{sc}: {b}");
        assert!(
            b["with_lasers"]["laser_rays"].as_u64().unwrap() > 0,
            "{sc}: {b}"
        );
        let p = &b["physics_only"];
        let rtf = p["real_time_factor"].as_f64().unwrap();
        let wall = p["wall_time_s"].as_f64().unwrap();
        // The physics-only run simulated the same 3 s.
        assert!((rtf * wall - 3.0).abs() < 0.05, "{sc}: {p}");
        assert_eq!(
            p["controller"]
                .as_str()
                .unwrap()
                .starts_with("the scenario's"),
            drives,
            "{sc}: {p}"
        );
    }
    // A tour on the true pose reads none of its lasers: no scan is cast, and the bench says so.
    let o = futago(&[
        "bench",
        "sim",
        "scenarios/office-tour.toml",
        "--duration",
        "3",
        "--rays",
        "1000",
    ]);
    ok(&o);
    let b: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(b["with_lasers"]["laser_rays"], 0, "{b}");
    assert_eq!(b["with_lasers"]["lasers_read"], false, "{b}");
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("no node of its stack reads a laser"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

#[test]
fn sensor_bench_reads_poses_and_rejects_bad_ones() {
    let tmp = tempfile::tempdir().unwrap();
    let poses = write(
        tmp.path(),
        "p.csv",
        "# x,y,z,yaw\n6.5,3.5,0.42,0\n2.0,5.0,1.0,-0.8\n",
    );
    let bench = |poses: &Path, more: &[&str]| {
        let mut args = vec!["bench", "sensors", "--world", "worlds/lab.toml", "--poses"];
        args.push(poses.to_str().unwrap());
        args.extend(more);
        futago(&args)
    };
    let o = bench(
        &poses,
        &[
            "--frames",
            "2",
            "--batch",
            "5",
            "--batches",
            "1",
            "--rays",
            "682",
        ],
    );
    ok(&o);
    let r: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(r["poses"], 2);
    assert!(
        r["depth_batch_176x144"]["images_per_second"]
            .as_f64()
            .unwrap()
            > 0.0
    );
    assert!(r["rgb_depth_640x480"]["valid_pixels"].as_u64().unwrap() > 0);
    let bad = write(tmp.path(), "bad.csv", "1,2,3\n");
    let o = bench(&bad, &[]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("bad.csv line 1") && err.contains("x,y,z,yaw"),
        "{err}"
    );
}

/// Yaw of a TUM z-axis quaternion.
fn yaw(q: [f64; 4]) -> f64 {
    2.0 * q[2].atan2(q[3])
}

#[test]
fn replay_of_a_simulated_log_beats_its_odometry_on_ground_truth_relations() {
    let tmp = tempfile::tempdir().unwrap();
    let world = root().join("worlds/lab.toml");
    // A lap of the lab with a URG-04LX, the robot driven on the true pose while its odometry
    // carries a 2 % wheel-base error.
    let scenario = write(
        tmp.path(),
        "lap.toml",
        format!(
            "name = \"lap\"\nworld = {world:?}\nduration = 40.0\nseed = 2\nstart = \"centre\"\n\
             [robot.odometry]\nwheel_base_ratio = 1.02\nnoise = 0.002\n\
             [[lidar]]\nname = \"front\"\npreset = \"urg-04lx\"\nxyz = [0.08, 0.0, 0.2]\n\
             [controller]\ntype = \"waypoints\"\nspeed = 0.35\npose_source = \"ground_truth\"\n\
             waypoints = [[10.0, 3.5], [10.0, 5.5], [3.0, 5.5], [3.0, 2.0], [9.0, 1.8]]\n"
        ),
    );
    let sim = tmp.path().join("sim");
    run_for(&scenario, &sim, None);
    // Relations between scans 200 apart (20 s), from the simulator's ground truth.
    let truth =
        futago_msgs::tum::parse(&std::fs::read_to_string(sim.join("groundtruth.txt")).unwrap())
            .unwrap();
    let log = futago_msgs::carmen::read(&std::fs::read_to_string(sim.join("scans.clf")).unwrap())
        .unwrap();
    assert!(log.scans.len() > 300, "{} scans", log.scans.len());
    let at = |t: futago_msgs::Time| -> futago_msgs::Pose2 {
        let k = truth
            .partition_point(|s| s.stamp < t)
            .clamp(1, truth.len() - 1);
        let (a, b) = (&truth[k - 1], &truth[k]);
        let f = ((t - a.stamp).secs() / (b.stamp - a.stamp).secs()).clamp(0.0, 1.0);
        let (ya, yb) = (yaw(a.pose.rotation), yaw(b.pose.rotation));
        futago_msgs::Pose2::new(
            a.pose.translation[0] + f * (b.pose.translation[0] - a.pose.translation[0]),
            a.pose.translation[1] + f * (b.pose.translation[1] - a.pose.translation[1]),
            ya + f * futago_msgs::wrap_angle(yb - ya),
        )
    };
    let mut rel = String::new();
    for k in (0..log.scans.len() - 200).step_by(5) {
        let (t1, t2) = (log.scans[k].scan.stamp, log.scans[k + 200].scan.stamp);
        let d = at(t1).between(&at(t2));
        rel += &format!(
            "{:.6} {:.6} {:.6} {:.6} 0 0 0 {:.6}\n",
            t1.secs(),
            t2.secs(),
            d.x,
            d.y,
            d.theta
        );
    }
    let rel_file = write(tmp.path(), "lap.relations", &rel);
    let out = tmp.path().join("replay");
    let o = futago(&[
        "replay",
        sim.join("scans.clf").to_str().unwrap(),
        "--relations",
        rel_file.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    ok(&o);
    let s = summary(&out);
    let m = |who: &str, q: &str| s["relations"][who][q]["mean"].as_f64().unwrap();
    assert!(s["relations"]["slam"]["relations"].as_u64().unwrap() >= 40);
    // Over 20 s the odometry's heading error has grown; matching the scans holds it.
    let all = &s["relations"];
    assert!(m("slam", "abs_trans_m") < 0.05, "{all}");
    assert!(
        m("slam", "abs_trans_m") < m("odometry", "abs_trans_m"),
        "{all}"
    );
    assert!(
        m("slam", "abs_rot_deg") < 0.5 * m("odometry", "abs_rot_deg"),
        "{all}"
    );
    // The CARMEN log's TRUEPOS and PARAM records are counted as skipped, and a map is written.
    assert!(
        s["skipped"]["unknown record type TRUEPOS"]
            .as_u64()
            .unwrap()
            > 0
    );
    assert!(out.join("map.pgm").exists() && out.join("trajectory.txt").exists());
    // The report marks the ten worst relations on the map, worst first, the worst at least
    // as bad as the mean.
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(html.contains("Relations (Kümmerle"), "no relations table");
    let marked: Vec<f64> = html
        .split("<g class=\"worst\"><title>relation ")
        .skip(1)
        .map(|g| {
            let e = g.split(": ").nth(1).unwrap().split(" m<").next().unwrap();
            e.parse().unwrap()
        })
        .collect();
    assert_eq!(marked.len(), 10, "{marked:?}");
    assert!(marked.windows(2).all(|w| w[0] >= w[1]), "{marked:?}");
    assert!(marked[0] >= m("slam", "abs_trans_m"), "{marked:?}");
}

/// A world made from the map that graph SLAM built from the real Intel log
/// (`worlds/intel.map.yaml`): exported again at the map's resolution, its colliders give back
/// the map's walls cell for cell: each occupied cell, and each unknown cell touching free
/// space (sealed), is occupied; every other cell is free. Free cells in no 3 × 3 block of
/// free cells (15 cm at 5 cm: the traces of rays into unmapped space) count as unknown.
#[test]
fn world_from_a_real_logs_map_gives_back_its_walls() {
    use futago_msgs::map_server;
    let tmp = tempfile::tempdir().unwrap();
    let world = tmp.path().join("lab.toml");
    let o = futago(&[
        "world",
        "from-map",
        "worlds/intel.map.yaml",
        "--out",
        world.to_str().unwrap(),
    ]);
    ok(&o);
    assert!(String::from_utf8_lossy(&o.stdout).contains("spawns: start"));
    assert!(tmp.path().join("lab.map.yaml").exists());
    let export = tmp.path().join("export");
    ok(&futago(&[
        "world",
        "export",
        world.to_str().unwrap(),
        "--out",
        export.to_str().unwrap(),
        "--mesh",
        "none",
    ]));
    let map = map_server::read(&root().join("worlds/intel.map.yaml")).unwrap();
    let got = map_server::read(&export.join("lab.yaml")).unwrap();
    let raw = |i: isize, j: isize| -> i8 {
        if i < 0 || j < 0 || i >= map.width as isize || j >= map.height as isize {
            -1
        } else {
            map.get(i as usize, j as usize)
        }
    };
    let free = |i: isize, j: isize| (0..65).contains(&raw(i, j));
    let value = |i: isize, j: isize| -> i8 {
        let in_block = (-2..=0).any(|a| {
            (-2..=0).any(|b| (0..3).all(|di| (0..3).all(|dj| free(i + a + di, j + b + dj))))
        });
        if free(i, j) && !in_block {
            -1
        } else {
            raw(i, j)
        }
    };
    let (mut walls, mut sealed) = (0, 0);
    // The map and a one-cell ring round it.
    for j in -1..=map.height as isize {
        for i in -1..=map.width as isize {
            let v = value(i, j);
            let touches_free =
                (-1..=1).any(|dj| (-1..=1).any(|di| (0..65).contains(&value(i + di, j + dj))));
            let wall = v >= 65 || (v < 0 && touches_free);
            walls += wall as usize;
            sealed += (wall && v < 0) as usize;
            let c = [
                map.origin[0] + (i as f64 + 0.5) * map.resolution,
                map.origin[1] + (j as f64 + 0.5) * map.resolution,
            ];
            let (gi, gj) = got.cell_of(c[0], c[1]).expect("the export spans the map");
            assert_eq!(got.get(gi, gj) == 100, wall, "cell ({i}, {j}) at {c:?}");
        }
    }
    assert!(
        walls > 10_000 && sealed > 0,
        "{walls} walls, {sealed} sealed"
    );
}

/// Bad maps and options are refused with the file and key named, and nothing is written.
#[test]
fn world_from_map_refuses_bad_maps() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    std::fs::write(
        d.join("m.pgm"),
        b"P5\n3 3\n255\n\xfe\xfe\xfe\xfe\xfe\xfe\xfe\xfe\xfe",
    )
    .unwrap();
    std::fs::write(
        d.join("m.yaml"),
        "image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n",
    )
    .unwrap();
    std::fs::write(
        d.join("bad.yaml"),
        "image: m.pgm\nresolution: fine\norigin: [0, 0, 0]\n",
    )
    .unwrap();
    let out = d.join("w").join("w.toml");
    for (args, expect) in [
        (vec!["bad.yaml"], "resolution"),
        (vec!["missing.yaml"], "missing.yaml"),
        // A 15 cm room has no place for the Create.
        (vec!["m.yaml"], "no free cell"),
        (vec!["m.yaml", "--spawn", "1,2"], "--spawn"),
        (vec!["m.yaml", "--height", "0.01"], "--height"),
        (vec!["m.yaml", "--name", "a b"], "--name"),
    ] {
        let map = d.join(args[0]);
        let mut a = vec!["world", "from-map", map.to_str().unwrap()];
        a.extend(&args[1..]);
        a.extend(["--out", out.to_str().unwrap()]);
        let o = futago(&a);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            !o.status.success() && err.contains(expect),
            "{args:?}: {err}"
        );
        assert!(!out.exists(), "{args:?} wrote the world");
    }
}

/// The published benchmark: both SLAM methods on the MIT CSAIL log, scored with its
/// ground-truth relations. Graph SLAM must beat Cartographer's 0.0319 m (Hess et al. 2016,
/// Table II); the ICP baseline must beat pure scan matching's 0.106 m (Kümmerle et al. 2009).
#[test]
fn replay_of_mit_csail_beats_the_published_figures() {
    let Some(files) = futago_msgs::datasets::require(
        &root(),
        "replay_of_mit_csail_beats_the_published_figures",
        &[
            "slam-benchmark/mit-csail.clf",
            "slam-benchmark/mit-csail.relations",
        ],
    ) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    for (method, limit, loops) in [("graph", 0.0319, true), ("icp", 0.106, false)] {
        let out = tmp.path().join(method);
        let o = futago(&[
            "replay",
            files[0].to_str().unwrap(),
            "--relations",
            files[1].to_str().unwrap(),
            "--method",
            method,
            "--out",
            out.to_str().unwrap(),
        ]);
        ok(&o);
        let s = summary(&out);
        let trans = s["relations"]["slam"]["abs_trans_m"]["mean"]
            .as_f64()
            .unwrap();
        let rot = s["relations"]["slam"]["abs_rot_deg"]["mean"]
            .as_f64()
            .unwrap();
        assert_eq!(s["relations"]["slam"]["relations"], 1172);
        assert!(trans < limit, "{method}: {trans} m");
        assert!(rot < 0.5, "{method}: {rot}°");
        assert_eq!(s["loop_closures"].as_u64().unwrap() > 0, loops, "{method}");
    }
}

/// Replays a log of the SLAM benchmark with its relations and the default configuration for
/// the test `test`; returns the summary, or `None` (the skip printed) without the data.
fn replay_benchmark(test: &str, log: &str, relations: &str) -> Option<serde_json::Value> {
    let files = futago_msgs::datasets::require(
        &root(),
        test,
        &[
            &format!("slam-benchmark/{log}"),
            &format!("slam-benchmark/{relations}"),
        ],
    )?;
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("replay");
    ok(&futago(&[
        "replay",
        files[0].to_str().unwrap(),
        "--relations",
        files[1].to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]));
    Some(summary(&out))
}

/// The relations metric of a replay's summary: `group` is `None` for all relations, or a
/// time-span group (`under_10s`, …).
fn relation_mean(s: &serde_json::Value, group: Option<&str>, key: &str) -> f64 {
    let m = match group {
        None => &s["relations"]["slam"],
        Some(g) => s["relations"]["by_span"]
            .as_array()
            .unwrap()
            .iter()
            .find(|x| x["span"] == g)
            .map(|x| &x["slam"])
            .unwrap(),
    };
    m[key]["mean"].as_f64().unwrap()
}

/// The Intel lab log (bag, as recorded), with the same default configuration as MIT CSAIL:
/// graph SLAM must beat Cartographer's 0.0229 m and 0.453° (Hess et al. 2016, Table II). 787
/// of its scans are stamped out of their `seq` order; read by their stamps alone,
/// they are placed up to 0.3 m from where they were taken and the mean is 0.026 m.
#[test]
fn replay_of_intel_beats_cartographer() {
    let Some(s) = replay_benchmark(
        "replay_of_intel_beats_cartographer",
        "intel.orig.bag",
        "intel.relations",
    ) else {
        return;
    };
    assert_eq!(s["relations"]["slam"]["relations"], 2984);
    let trans = relation_mean(&s, None, "abs_trans_m");
    let rot = relation_mean(&s, None, "abs_rot_deg");
    assert!(trans < 0.0229, "{trans} m");
    assert!(rot < 0.453, "{rot}°");
    // The loops hold the map together: relations minutes apart are as good as the RBPF
    // (GMapping)'s 0.070 m over all (Kümmerle et al. 2009).
    let global = relation_mean(&s, Some("over_100s"), "abs_trans_m");
    assert!(global < 0.070, "{global} m over relations spanning minutes");
}

/// The Freiburg hospital log: its relations a few seconds apart (the "local" set) must beat
/// Cartographer's local 0.1078 m, and all its relations, the long ones across the building
/// included, Cartographer's "global" 5.2242 m (Hess et al. 2016, Table II).
#[test]
fn replay_of_the_hospital_beats_cartographer_locally_and_globally() {
    let Some(s) = replay_benchmark(
        "replay_of_the_hospital_beats_cartographer_locally_and_globally",
        "fr-clinic_robotlaser.orig.bag",
        "fr-clinic.relations",
    ) else {
        return;
    };
    let spans: Vec<&str> = s["relations"]["by_span"]
        .as_array()
        .unwrap()
        .iter()
        .map(|g| g["span"].as_str().unwrap())
        .collect();
    assert_eq!(spans, ["under_10s", "10_to_100s", "over_100s"]);
    let local = relation_mean(&s, Some("under_10s"), "abs_trans_m");
    assert!(local < 0.1078, "{local} m");
    let all = relation_mean(&s, None, "abs_trans_m");
    assert!(all < 5.2242, "{all} m");
}

/// The annotated people log (leg_tracker's benchmark): people are tracked from its `/scan`,
/// the laser placed by `/tf` and moved by `/odom`, and scored by CLEAR-MOT over every scan
/// against its 153 `leg_tracker/Person` annotations, in the laser's frame.
#[test]
fn replay_of_an_annotated_people_log_scores_its_tracks() {
    let Some(files) = futago_msgs::datasets::require(
        &root(),
        "replay_of_an_annotated_people_log_scores_its_tracks",
        &["people/general_tracking_moving_1.bag"],
    ) else {
        return;
    };
    let bag = &files[0];
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("replay");
    ok(&futago(&[
        "replay",
        bag.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]));
    let s = summary(&out);
    let p = &s["people"];
    assert_eq!(p["annotations"], 153);
    let all = &p["all_frames"];
    assert_eq!(all["frames"], 873);
    assert_eq!(all["objects"], 153);
    let n = |k: &str| all[k].as_u64().unwrap();
    // Every annotation is matched or missed, and MOTA counts what went wrong.
    assert_eq!(n("matches") + n("misses"), 153);
    let mota = 1.0 - (n("misses") + n("false_positives") + n("id_switches")) as f64 / 153.0;
    assert!((all["mota"].as_f64().unwrap() - mota).abs() < 1e-12);
    // The scored frames are the annotated ones in the second count.
    assert!(p["annotated_frames"]["frames"].as_u64().unwrap() < 873);
    let tracks = std::fs::read_to_string(out.join("people_tracks.txt")).unwrap();
    assert!(tracks.lines().count() > 1);
    // The leg detector is scored on every annotated scan against all 153 annotations; a
    // hit is counted once, so recall and precision follow from the counts.
    let legs = &p["detection_on_annotated_frames"]["legs"];
    assert_eq!(legs["scans"], p["annotated_frames"]["frames"]);
    for r in ["0.5", "0.3"] {
        let d = &legs["by_radius_m"][r];
        assert_eq!(d["truth"], 153);
        let tp = d["true_positives"].as_f64().unwrap();
        assert!((d["recall"].as_f64().unwrap() - tp / 153.0).abs() < 1e-12);
        let ap = d["ap"].as_f64().unwrap();
        assert!((0.0..=d["recall"].as_f64().unwrap()).contains(&ap), "{d}");
    }
    // A tighter radius never finds more.
    let tp = |r: &str| legs["by_radius_m"][r]["true_positives"].as_u64().unwrap();
    assert!(tp("0.3") <= tp("0.5"));
    // The annotated stretch cut in two in time: each half scored on its own scans and
    // people, the two adding up to the whole, and neither empty.
    let halves = &p["annotated_halves"];
    let count = |v: &serde_json::Value, k: &str| v[k].as_u64().unwrap();
    for k in ["frames", "objects"] {
        let (a, b) = (
            count(&halves["first"]["tracking"], k),
            count(&halves["second"]["tracking"], k),
        );
        assert_eq!(a + b, count(&p["annotated_frames"], k), "{k}");
        assert!(a > 0 && b > 0, "{k}: {a} and {b}");
    }
    assert_eq!(
        count(&halves["first"]["detection"]["legs"], "scans"),
        count(&halves["first"]["tracking"], "frames")
    );
    assert!(halves["split_after_first_annotation_s"].as_f64().unwrap() > 0.0);
    // What the scans show of the people: each of the 153 annotations (all within 8 m) is
    // counted in one range bin.
    let bins = p["leg_scans"]["by_range"].as_array().unwrap();
    let people: u64 = bins.iter().map(|b| b["people"].as_u64().unwrap()).sum();
    assert_eq!(people, 153);
    // Counted again by how they move, those whose marks give a velocity: the log has people
    // standing in a group and people walking at the robot.
    let moving = &p["leg_scans"]["by_motion"];
    let by = |m: &str| moving[m]["people"].as_u64().unwrap();
    assert!(by("standing") + by("along") + by("across") <= 153);
    assert!(by("standing") > 0 && by("along") > 0, "{moving}");
}

/// `replay --legs-model` scores a given leg classifier on a real annotated log (how a model
/// trained in simulation is measured on real scans): the shipped model given as a file scores
/// as the default does, a model whose every stump votes the other way scores otherwise, and a
/// file that is no model is refused with its name.
#[test]
fn replay_scores_the_leg_model_it_is_given() {
    let Some(files) = futago_msgs::datasets::require(
        &root(),
        "replay_scores_the_leg_model_it_is_given",
        &["people/general_tracking_moving_1.bag"],
    ) else {
        return;
    };
    let bag = files[0].to_str().unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let run = |name: &str, model: Option<&Path>| {
        let out = tmp.path().join(name);
        let mut args = vec!["replay", bag, "--out", out.to_str().unwrap()];
        if let Some(m) = model {
            args.extend(["--legs-model", m.to_str().unwrap()]);
        }
        ok(&futago(&args));
        summary(&out)["people"]["detection_on_annotated_frames"]["legs"].clone()
    };
    let shipped = std::fs::read_to_string(root().join("models/legs.json")).unwrap();
    let copy = tmp.path().join("copy.json");
    std::fs::write(&copy, &shipped).unwrap();
    let default = run("default", None);
    assert_eq!(run("copy", Some(&copy)), default);
    // Every stump's vote reversed: segments rank the other way round.
    let mut v: serde_json::Value = serde_json::from_str(&shipped).unwrap();
    for stump in v["model"]["stumps"].as_array_mut().unwrap() {
        let p = stump["polarity"].as_f64().unwrap();
        stump["polarity"] = serde_json::json!(-p);
    }
    let flipped = tmp.path().join("flipped.json");
    std::fs::write(&flipped, serde_json::to_string(&v).unwrap()).unwrap();
    let other = run("flipped", Some(&flipped));
    assert_ne!(
        other["by_radius_m"]["0.5"]["ap"], default["by_radius_m"]["0.5"]["ap"],
        "{other}"
    );
    let bad = tmp.path().join("bad.json");
    std::fs::write(&bad, "[").unwrap();
    let out = tmp.path().join("bad");
    let o = futago(&[
        "replay",
        bag,
        "--out",
        out.to_str().unwrap(),
        "--legs-model",
        bad.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("bad.json"), "{e}");
}

/// `futago bench people` times detection and tracking over scans of walking people and the
/// simulation among a crowd; it reports what it measured and refuses absurd sizes.
#[test]
fn bench_people_measures_and_refuses_absurd_sizes() {
    let o = futago(&[
        "bench", "people", "--scans", "20", "--people", "4", "--crowd", "2",
    ]);
    ok(&o);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["scans"], 20);
    assert_eq!(v["laser"]["beams"], 682);
    assert!(v["ms_per_scan_detect_and_track"].as_f64().unwrap() > 0.0);
    assert!(v["people_in_view_per_scan"].as_f64().unwrap() > 0.0);
    assert!(v["simulation_real_time_factor"].as_f64().unwrap() > 0.0);
    let o = futago(&["bench", "people", "--scans", "0"]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("1 to 100000 scans"));
}

/// The shipped leg classifier is what `futago train-legs` makes of its scenario, byte for
/// byte: training is deterministic, and a change to the simulator, the features or the
/// booster that moves the model fails here until the model is retrained.
#[test]
fn train_legs_reproduces_the_shipped_model() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("legs.json");
    ok(&futago(&[
        "train-legs",
        root().join("scenarios/train-legs.toml").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]));
    let made = std::fs::read_to_string(&out).unwrap();
    let shipped = std::fs::read_to_string(root().join("models/legs.json")).unwrap();
    assert!(made == shipped, "models/legs.json is stale: retrain it");
}

#[test]
fn replay_refuses_bad_logs_with_their_line() {
    let tmp = tempfile::tempdir().unwrap();
    let bad = write(
        tmp.path(),
        "bad.clf",
        "ODOM 1 2 3 0 0 0 1.0 h 1.0\nFLASER 3 1.0 oops 2.0 0 0 0 0 0 0 2.0 h 2.0\nODOM 1 2 3 0 0 0 3.0 h 3.0\n",
    );
    let o = futago(&[
        "replay",
        bad.to_str().unwrap(),
        "--out",
        tmp.path().join("o").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("bad.clf: line 2") && err.contains("oops"),
        "{err}"
    );
    assert!(!tmp.path().join("o").exists());
    let other = write(tmp.path(), "x.txt", "hello\n");
    let o = futago(&["replay", other.to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("unknown log format"));
}

/// Inputs that once crashed the program (a panic, an allocation abort, or a whole run before a
/// misleading error) are refused up front with the file, the key and what was expected.
#[test]
fn inputs_that_crashed_are_refused_by_name() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let fresh = d.join("out");
    refused_before_running(
        &[
            "run",
            "scenarios/office-mcl.toml",
            "--set",
            "localization.mcl.min_particles=6000",
        ],
        &fresh,
        "localization.mcl.min_particles`: expected at most max_particles (5000)",
        Some(1),
    );
    refused_before_running(
        &[
            "run",
            "scenarios/office-mcl.toml",
            "--set",
            "start={ x = 1e300, y = 0 }",
        ],
        &fresh,
        "key `start.x`: expected a value in [-0.375, 30.375] m, inside the world's bounds, found 1e300",
        Some(1),
    );
    // A world reaching 1e9 m would need an 800 GB grid.
    let far = write(
        d,
        "far.toml",
        "name = \"far\"\n[materials.wall]\ncolor = [0.9, 0.9, 0.9]\n[[boxes]]\ncenter = [1e9, 0]\nsize = [1, 1, 1]\nmaterial = \"wall\"\n",
    );
    refused_before_running(
        &["world", "export", far.to_str().unwrap()],
        &fresh,
        "far.toml: key `boxes[0]`: reaches (1000000000",
        Some(1),
    );
    // A world that fits but whose grid at 1 mm would not (5 × 10⁸ cells).
    refused_before_running(
        &[
            "world",
            "export",
            "worlds/office.toml",
            "--resolution",
            "0.001",
        ],
        &fresh,
        "--resolution: a grid of world `office`",
        Some(1),
    );
    // Odometry far beyond any building, in CARMEN and TUM files.
    for x in ["1e12", "1e300"] {
        let log = write(
            d,
            "far.clf",
            format!("ODOM {x} 0 0 0 0 0 1.0 host 1.0\nODOM {x} 0 0 0 0 0 2.0 host 2.0\n"),
        );
        refused_before_running(
            &["replay", log.to_str().unwrap()],
            &fresh,
            "far.clf: line 1: odometry pose x",
            Some(1),
        );
    }
    // Two lasers: a module must say which it reads.
    let two = write(
        d,
        "two.toml",
        format!(
            "name = \"two\"\nworld = {:?}\nduration = 1.0\nstart = \"corridor\"\n[[lidar]]\nname = \"front\"\npreset = \"utm-30lx\"\n[[lidar]]\nname = \"rear\"\npreset = \"lms200\"\n[slam]\n[controller]\ntype = \"segments\"\nsegments = [{{ duration = 1.0, velocity = 0.2 }}]\n",
            root().join("worlds/hall.toml")
        ),
    );
    refused_before_running(
        &["run", two.to_str().unwrap()],
        &fresh,
        "key `slam.laser`: the scenario has 2 lasers [\"front\", \"rear\"]: name the one it reads",
        Some(1),
    );
    refused_before_running(
        &["run", two.to_str().unwrap(), "--set", "slam.laser=\"side\""],
        &fresh,
        "no laser is named `side`",
        Some(1),
    );
    // Named, it runs on the rear laser.
    let o = futago(&[
        "run",
        two.to_str().unwrap(),
        "--set",
        "slam.laser=\"rear\"",
        "-q",
        "--out",
        fresh.to_str().unwrap(),
    ]);
    ok(&o);
    let s = summary(&fresh);
    assert!(s["slam"]["keyframes"].as_u64().unwrap() >= 1);
    assert!(
        std::fs::read_to_string(fresh.join("slam_trajectory.txt"))
            .unwrap()
            .contains("(laser `rear`)")
    );
}

/// Seed 002's depth-camera localiser in the loop: a few seconds of `office-depth-mcl` write a
/// filter estimate per frame at its rate, the seed's path error stays within its 7 cm against
/// the simulated truth, and bad tables are refused before anything runs.
#[test]
fn the_depth_camera_localiser_runs_in_the_loop() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let sc = "scenarios/office-depth-mcl.toml";
    let o = futago(&["run", sc, "--duration", "4", "--out", out.to_str().unwrap()]);
    ok(&o);
    let s = summary(&out);
    let d = &s["depth_localization"];
    // 8 Hz for 4 s.
    let frames = d["frames"].as_u64().unwrap();
    assert!((31..=33).contains(&frames), "{d}");
    let lines = std::fs::read_to_string(out.join("depth_localization.txt")).unwrap();
    assert_eq!(lines.lines().count() as u64, frames);
    let median = s["metrics"]["depth_localization.path_error.median_m"]
        .as_f64()
        .unwrap();
    assert!(median <= 0.07, "{d}");
    assert!(s["metrics"]["depth_localization.ate.mean_m"].is_number());
    for (set, expect) in [
        ("camera=[]", "depth-camera localisation needs a [[camera]]"),
        (
            "depth_localization.camera=\"nope\"",
            "no camera is named `nope`",
        ),
        (
            "depth_localization.size=[500, 10]",
            "depth_localization.size[0]",
        ),
        (
            "depth_localization.mcl.beta=0",
            "depth_localization.mcl.beta",
        ),
    ] {
        refused_before_running(
            &["run", sc, "--set", set],
            &tmp.path().join("fresh"),
            expect,
            Some(1),
        );
    }
}

/// The likelihood field in 3D in the loop: `office-depth-mcl-map` weighs its particles by
/// each measured point's distance to the robot-built map, with no render; the summary names
/// the field and its voxels, the seed's path error stays within its 7 cm against the
/// simulated truth, and a voxel so small that the field could not be held is refused, naming
/// the key, before anything runs.
#[test]
fn the_depth_localiser_weighs_by_a_distance_field_of_its_model() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let sc = "scenarios/office-depth-mcl-map.toml";
    ok(&futago(&[
        "run",
        sc,
        "--duration",
        "4",
        "--out",
        out.to_str().unwrap(),
        "-q",
    ]));
    let s = summary(&out);
    let d = &s["depth_localization"];
    assert_eq!(d["likelihood"], "field", "{d}");
    let voxels: u64 = d["field"]["voxels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap())
        .product();
    // The map spans the office's wing (some 30 × 16 × 3 m) at 5 cm.
    assert!(voxels > 1_000_000, "{d}");
    let median = s["metrics"]["depth_localization.path_error.median_m"]
        .as_f64()
        .unwrap();
    assert!(median <= 0.07, "{d}");
    refused_before_running(
        &[
            "run",
            sc,
            "--set",
            "depth_localization.mcl.field_cell=0.005",
        ],
        &tmp.path().join("fresh"),
        "depth_localization.mcl.field_cell",
        Some(1),
    );
}

/// Seed 002's wagon: a camera an agent carries, swaying, with no odometry. The camera's true
/// poses follow the agent's path 0.5 m ahead at the mount's 0.9 m, within the sway's 5 mm;
/// the robot, standing in its store room, is not what is scored; and a camera the robot does
/// not carry is refused to nodes that take frames as the robot's, and to odometry.
#[test]
fn a_camera_on_a_pushed_wagon_is_localised_and_scored_as_itself() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let sc = "scenarios/corridor-depth-mcl-6dof.toml";
    let o = futago(&["run", sc, "--duration", "4", "--out", out.to_str().unwrap()]);
    ok(&o);
    let s = summary(&out);
    let d = &s["depth_localization"];
    assert_eq!(d["carrier"], "agent", "{d}");
    assert!(!out.join("depth_localization.txt").exists());
    let truth = std::fs::read_to_string(out.join("depth_camera_truth.txt")).unwrap();
    let rows: Vec<Vec<f64>> = truth
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| l.split_whitespace().map(|v| v.parse().unwrap()).collect())
        .collect();
    assert!((31..=33).contains(&rows.len()), "{}", rows.len());
    for r in &rows {
        // The agent walks from (1, 0) east at 0.35 m/s; the camera is 0.5 m ahead of it and
        // 0.9 m up. The sway (5 mm in y and z; 0.5° of roll and pitch and 1° of yaw about the
        // agent's frame on the floor) moves it at most 0.9 sin 0.5° ≈ 7.9 mm in x,
        // 5 + 0.5 sin 1° + 0.9 sin 0.5° ≈ 21.6 mm in y and 5 + 0.5 sin 0.5° ≈ 9.4 mm in z.
        let x = 1.0 + 0.35 * r[0] + 0.5;
        assert!(
            (r[1] - x).abs() < 0.009,
            "x {} at t {}, expected {x}",
            r[1],
            r[0]
        );
        assert!(r[2].abs() < 0.022 && (r[3] - 0.9).abs() < 0.0105, "{r:?}");
    }
    // It does sway: more than a millimetre off the straight line somewhere.
    assert!(rows.iter().any(|r| r[2].abs() > 0.001), "no sway");
    let m = &s["metrics"];
    for k in [
        "depth_localization.camera.position.median_m",
        "depth_localization.camera.rotation.median_deg",
        "depth_localization.camera.rpe_1s.trans_rmse_m",
    ] {
        assert!(m[k].is_number(), "{k}: {m}");
    }
    assert!(m["depth_localization.ate.mean_m"].is_null());
    assert!(
        m["depth_localization.camera.position.median_m"]
            .as_f64()
            .unwrap()
            < 0.07
    );
    // The dataset writer takes a carried camera's frames with their true optical poses.
    let data = tmp.path().join("dataset");
    let o = futago(&[
        "run",
        sc,
        "--duration",
        "1",
        "--set",
        "output.rgbd_dataset=true",
        "--out",
        data.to_str().unwrap(),
    ]);
    ok(&o);
    let gt = std::fs::read_to_string(data.join("sr4000").join("groundtruth.txt")).unwrap();
    let first: Vec<f64> = gt
        .lines()
        .find(|l| !l.starts_with('#'))
        .unwrap()
        .split_whitespace()
        .map(|v| v.parse().unwrap())
        .collect();
    assert!(
        (first[1] - 1.5).abs() < 0.01 && (first[3] - 0.9).abs() < 0.0105,
        "{first:?}"
    );
    for (set, expect) in [
        ("depth_localization.odometry=true", "which has no odometry"),
        (
            "camera=[{name=\"sr4000\", preset=\"sr4000\", carrier=\"nobody\"}]",
            "no agent is named `nobody`",
        ),
        (
            "rgbd_map={camera=\"sr4000\", pose_source=\"ground_truth\"}",
            "takes camera frames as the robot's",
        ),
    ] {
        refused_before_running(
            &["run", sc, "--set", set],
            &tmp.path().join("fresh"),
            expect,
            Some(1),
        );
    }
}

/// The depth localiser's model from files (`depth_localization.model.file`): the corridor's
/// mesh exported by `futago world export` as PLY and as GLB, read back, tracks the wagon's
/// camera within the seed's 7 cm as the world's own mesh does, and so does the world's mesh
/// resampled and displaced by 1 cm (a scanned model's error). A missing file, a file of
/// another kind and a PLY with no surface are errors that name the key.
#[test]
fn the_depth_localiser_takes_its_model_from_files() {
    let tmp = tempfile::tempdir().unwrap();
    let export = tmp.path().join("export");
    ok(&futago(&[
        "world",
        "export",
        "worlds/corridor.toml",
        "--out",
        export.to_str().unwrap(),
    ]));
    let sc = "scenarios/corridor-depth-mcl-cv.toml";
    let ply = export.join("corridor.ply");
    let glb = export.join("corridor.glb");
    let ply_set = format!("depth_localization.model.file={:?}", ply.to_str().unwrap());
    let glb_set = format!("depth_localization.model.file={:?}", glb.to_str().unwrap());
    let perturb = "depth_localization.model.perturb={spacing=0.5,noise=0.01}".to_string();
    for (name, set) in [("ply", ply_set), ("glb", glb_set), ("perturb", perturb)] {
        let out = tmp.path().join(name);
        ok(&futago(&[
            "run",
            sc,
            "--duration",
            "4",
            "--set",
            &set,
            "--out",
            out.to_str().unwrap(),
            "-q",
        ]));
        let s = summary(&out);
        let model = &s["depth_localization"]["model"];
        assert!(
            model["triangles"].as_u64().unwrap() > 100,
            "{name}: {model}"
        );
        let median = s["metrics"]["depth_localization.camera.position.median_m"]
            .as_f64()
            .unwrap();
        assert!(median < 0.07, "{name}: median {median}");
    }
    // A point with no surface, a missing file, and a file that is neither PLY nor glTF.
    let lone = tmp.path().join("lone.ply");
    std::fs::write(
        &lone,
        "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n",
    )
    .unwrap();
    let txt = tmp.path().join("model.txt");
    std::fs::write(&txt, "x").unwrap();
    for (file, want) in [
        (lone.clone(), "no surface"),
        (tmp.path().join("missing.ply"), "does not exist"),
        (txt, "expected a .ply, .glb or .gltf file"),
    ] {
        let o = futago(&[
            "run",
            sc,
            "--duration",
            "1",
            "--set",
            &format!("depth_localization.model.file={:?}", file.to_str().unwrap()),
            "--out",
            tmp.path().join("bad").to_str().unwrap(),
            "-q",
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{file:?} was accepted");
        assert!(
            err.contains("depth_localization.model.file") && err.contains(want),
            "{file:?}: {err}"
        );
    }
}

/// A `[scan3d]` table whose lasers, joint or values are wrong is refused before anything
/// runs, naming the key.
#[test]
fn a_turntable_scan_names_its_bad_lasers_joint_and_values() {
    let tmp = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(root().join("scenarios/corridor-scan3d.toml"))
        .unwrap()
        .replace(
            "world = \"../worlds/corridor.toml\"",
            &format!(
                "world = \"{}\"",
                root().join("worlds/corridor.toml").display()
            ),
        );
    for (from, to, expect) in [
        (
            "range_max = 6.0\njoint = \"table\"",
            "range_max = 6.0",
            "scan3d.laser`: laser `vertical` rides on no joint",
        ),
        (
            "mode = \"command\"",
            "mode = \"continuous\"",
            "joint `table` must be mode = \"command\"",
        ),
        (
            "horizontal = \"horizontal\"",
            "horizontal = \"nope\"",
            "scan3d.horizontal`: no laser is named `nope`",
        ),
        (
            "stops = [[2.0, 0.0],",
            "voxels = { p_hit = 2.0 }\nstops = [[2.0, 0.0],",
            "scan3d.voxels.p_hit",
        ),
        (
            "stops = [[2.0, 0.0],",
            "stops = [[1e9, 0.0],",
            "scan3d.stops[0]",
        ),
        (
            "direction = [0.0, 1.0, 0.0]",
            "direction = [0.0, 0.0, 0.0]",
            "scan3d.length[0].direction",
        ),
        (
            "direction = [0.0, 1.0, 0.0]\n",
            "direction = [0.0, 1.0, 0.0]\n\n[[scan3d.length]]\nname = \"width\"\nfrom = [1.0, 0.0, 1.0]\ndirection = [1.0, 0.0, 0.0]\n",
            "scan3d.length[1].name`: `width` names two lengths",
        ),
        (
            "from = [4.0, 0.0, 1.5]",
            "from = [4.0, 0.0, 1e9]",
            "scan3d.length[0].from",
        ),
        (
            "stops = [[2.0, 0.0],",
            "planning = { region = [[0.0, 0.0], [1.0, 1.0]] }\nstops = [[2.0, 0.0],",
            "scan3d.planning.region",
        ),
        (
            "stops = [[2.0, 0.0],",
            "planning = { planner = \"nearest\" }\nstops = [[2.0, 0.0],",
            "scan3d.planning.planner",
        ),
        // Driving on `pose/localization` needs a localiser: the seed's line ICP is one, a
        // [scan3d] placing its scans by odometry is not.
        (
            "stops = [[2.0, 0.0],",
            "pose_source = \"odometry\"\nstops = [[2.0, 0.0],",
            "controller.pose_source`: driving on this pose needs a [localization] or [scan3d] (localising by its line ICP) or [visual_localization] table",
        ),
        // The seed's line ICP publishes `pose/localization`, as MCL does: one publisher a
        // topic, whichever module it is.
        (
            "[scan3d]",
            "[localization]\n\n[scan3d]",
            "`scan3d`: [scan3d] publishes `pose/localization`, as [localization] does, and a pose topic has one publisher",
        ),
        (
            "stops = [[2.0, 0.0],",
            "registration = { max_distance = [0.1, 0.3] }\nstops = [[2.0, 0.0],",
            "scan3d.registration.max_distance",
        ),
    ] {
        edited_scenario_is_refused(tmp.path(), &text, from, to, expect);
    }
}

/// The landmark maps seed 001's navigation localises in are made by `lab-visual-map`'s passes:
/// each file's `made_by` names the run, and that run writes the committed file byte for byte
/// (the own-pose map; the truth-placed ablation's command is checked to name its scenario).
#[test]
fn the_lab_landmark_maps_are_remade_by_the_command_in_their_header() {
    let made_by = |file: &str| -> String {
        let text = std::fs::read_to_string(root().join("worlds/maps").join(file)).unwrap();
        let v: serde_json::Value = serde_json::from_str(&text).unwrap();
        v["made_by"].as_str().unwrap_or_default().to_string()
    };
    // Keypoints come from rasterised pixels, and lavapipe and llvmpipe do not rasterise the
    // same bits: each map names the backend it was rendered on, and is remade on it.
    let prefix = "FUTAGO_GPU_BACKEND=gl futago run ";
    let truth = made_by("lab-landmarks-truth.json");
    assert!(
        truth.starts_with(&format!(
            "{prefix}scenarios/lab-visual-map-truth.toml --seed 1 "
        )) && truth.ends_with("placed by the truth)"),
        "{truth}"
    );
    let own = made_by("lab-landmarks.json");
    assert!(
        own.starts_with(prefix) && own.ends_with("about the wheels' prediction)"),
        "{own}"
    );
    // `futago run FILE --seed N`, then the run's landmarks.json.
    let args: Vec<&str> = own[prefix.len()..]
        .split(" (")
        .next()
        .unwrap()
        .split(' ')
        .collect();
    assert_eq!(args.len(), 3, "{own}");
    assert_eq!(args[0], "scenarios/lab-visual-map.toml");
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("map");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_futago"))
        .args(["run", args[0], args[1], args[2]])
        .args(["--out", out.to_str().unwrap(), "-q"])
        .current_dir(root())
        .env("FUTAGO_GPU_BACKEND", "gl")
        .output()
        .unwrap();
    ok(&o);
    let made = std::fs::read(out.join("landmarks.json")).unwrap();
    let committed = std::fs::read(root().join("worlds/maps/lab-landmarks.json")).unwrap();
    assert!(
        made == committed,
        "the run's landmarks.json ({} bytes) differs from worlds/maps/lab-landmarks.json ({} bytes): remake it with `{own}`",
        made.len(),
        committed.len()
    );
}

/// A trinocular rig that is not an L, a missing or corrupt landmark map, and bad values are
/// refused before anything runs, naming the key (and the file).
#[test]
fn seed_001_scenarios_name_their_bad_rigs_maps_and_values() {
    let tmp = tempfile::tempdir().unwrap();
    let abs = |text: String| {
        text.replace(
            "world = \"../worlds/lab.toml\"",
            &format!("world = \"{}\"", root().join("worlds/lab.toml").display()),
        )
        .replace(
            "map = \"../worlds/maps/lab-landmarks.json\"",
            &format!(
                "map = \"{}\"",
                root().join("worlds/maps/lab-landmarks.json").display()
            ),
        )
    };
    let mapping =
        abs(std::fs::read_to_string(root().join("scenarios/lab-visual-map.toml")).unwrap());
    let nav = abs(std::fs::read_to_string(root().join("scenarios/lab-visual-nav.toml")).unwrap());
    let corrupt = tmp.path().join("corrupt.json");
    std::fs::write(
        &corrupt,
        r#"{"format": "futago-landmarks", "version": 1, "landmarks": [{"position": [1, 2, 3], "covariance": [1, 0, 0, 1, 0, 1], "observed": 2, "missed": 0, "views": [{"bin": 40, "contrast": 0.1, "descriptor": "00"}]}]}"#,
    )
    .unwrap();
    let cases = [
        (
            &mapping,
            "xyz = [0.1, 0.0, 0.5496]",
            "xyz = [0.1, 0.0, 0.6]",
            "visual_map.cameras`: the third camera (top) must sit straight above",
        ),
        (
            &mapping,
            "cameras = [\"right\", \"left\", \"top\"]",
            "cameras = [\"right\", \"left\", \"nope\"]",
            "visual_map.cameras`: no camera is named `nope`",
        ),
        (
            &mapping,
            "rate = 5.0\n\n[controller]",
            "rate = 5.0\nstereo = { ratio = 2.0 }\n\n[controller]",
            "visual_map.stereo.ratio",
        ),
        (
            &nav,
            "lab-landmarks.json",
            "no-such-map.json",
            "visual_localization.map`",
        ),
        (
            &nav,
            &format!(
                "{}",
                root().join("worlds/maps/lab-landmarks.json").display()
            ),
            &format!("{}", corrupt.display()),
            "landmarks[0].views[0].bin",
        ),
        (
            &nav,
            "xyz = [0.1, 0.0996, 0.45]",
            "xyz = [0.1, 0.0996, 0.45]\nrpy_deg = [0.0, 10.0, 0.0]",
            "visual_localization.camera`: camera `mono` must be levelled",
        ),
        (
            &mapping,
            "name = \"right\"\npreset = \"digiclops\"",
            "name = \"right\"\npreset = \"digiclops\"\ndepth_size = [160, 120]",
            "must have its depth_size equal to its rgb_size",
        ),
        (
            &nav,
            "drive = \"delegates\"",
            "drive = \"delegates\"\nmonocular = { selection = { alpha = 0.0 } }",
            "visual_localization.monocular.selection.alpha",
        ),
        (
            &nav,
            "drive = \"delegates\"",
            "drive = \"delegates\"\nmonocular = { search = { step_xy = 1e-6 } }",
            "visual_localization.monocular.search",
        ),
    ];
    for (text, from, to, expect) in cases {
        edited_scenario_is_refused(tmp.path(), text, from, to, expect);
    }
}

/// `futago bench visual` times seed 001's localisers per frame on a short run of the scenario:
/// every part is measured, a frame costs at least its SIFT, and the speed-up is reported.
#[test]
fn bench_visual_times_the_localisers_by_parts() {
    let o = futago(&["bench", "visual", "--duration", "2"]);
    ok(&o);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(v["frames"].as_u64().unwrap() >= 19, "{v}");
    let sift = v["sift_ms"].as_f64().unwrap();
    assert!(sift > 0.0);
    for l in ["all", "delegates", "summary", "pnp"] {
        let f = &v["localisers"][l];
        for k in ["selection_ms", "matching_ms", "search_ms"] {
            assert!(f[k].as_f64().unwrap() > 0.0, "{l} {k}: {v}");
        }
        assert!(f["frame_ms"].as_f64().unwrap() > sift);
    }
    assert!(v["matching_speedup"].as_f64().unwrap() > 1.0, "{v}");
    let o = futago(&["bench", "visual", "scenarios/lab-visual-map.toml"]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("no [visual_localization]"));
}

/// `futago crowd`: a small sequence calibrated and compared end to end (the profile written
/// loads again, the report holds every statistic, the simulated crowd reads back in the
/// trajectory format), and bad files refused by name, line and key with nothing written.
#[test]
fn crowd_calibrates_compares_and_refuses_bad_files() {
    let tmp = tempfile::tempdir().unwrap();
    // Two companions abreast along x at 1 m/s, a third walking across them, 60 frames.
    let mut text = String::from("# frame person x y\n");
    for k in 0..60 {
        let t = 0.4 * k as f64;
        text += &format!("{}\t1\t{:.2}\t2.0\n", 10 * k, t % 12.0);
        text += &format!("{}\t2\t{:.2}\t2.8\n", 10 * k, t % 12.0);
        text += &format!("{}\t3\t4\t{:.2}\n", 10 * k, (1.3 * t) % 10.0);
    }
    let seq = write(tmp.path(), "square.txt", &text);
    let profile = tmp.path().join("crowd.toml");
    let o = futago(&[
        "crowd",
        "calibrate",
        seq.to_str().unwrap(),
        "--duration",
        "60",
        "--out",
        profile.to_str().unwrap(),
    ]);
    exits_with(&o, 0);
    let out = tmp.path().join("cmp");
    let o = futago(&[
        "crowd",
        "compare",
        seq.to_str().unwrap(),
        "--profile",
        profile.to_str().unwrap(),
        "--seeds",
        "2",
        "--duration",
        "60",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(matches!(o.status.code(), Some(0 | 3)), "{o:?}");
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("crowd.json")).unwrap()).unwrap();
    let s = &json["sequences"][0];
    let rows = s["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 10);
    // Nobody in the file stands, so the calibrated crowd never stops.
    assert_eq!(s["real"]["stop_rate"], 0.0);
    assert!(rows.iter().any(|r| r["statistic"] == "stop_time_s"));
    let profile_text = std::fs::read_to_string(&profile).unwrap();
    assert!(profile_text.contains("stop_rate = 0.0"), "{profile_text}");
    assert_eq!(s["sim"].as_array().unwrap().len(), 2);
    assert_eq!(s["real"]["people"], 3);
    let sim = std::fs::read_to_string(out.join("square.sim.txt")).unwrap();
    assert!(sim.starts_with("# futago's crowd"));
    assert!(sim.lines().filter(|l| !l.starts_with('#')).count() > 100);
    assert!(
        std::fs::read_to_string(out.join("crowd.md"))
            .unwrap()
            .contains("nn_median_m")
    );

    let bad = write(tmp.path(), "bad.txt", "0 1 0.0 0.0\n10 1 0.4\n");
    refused_before_running(
        &["crowd", "compare", bad.to_str().unwrap()],
        &tmp.path().join("fresh"),
        "bad.txt: line 2: expected 4 or 5 numbers",
        Some(1),
    );
    let crowded: String = (0..1001)
        .map(|k| format!("0 {k} {} 0\n", 0.5 * k as f64))
        .collect();
    let crowded = write(tmp.path(), "crowded.txt", crowded);
    refused_before_running(
        &["crowd", "calibrate", crowded.to_str().unwrap()],
        &tmp.path().join("fresh.toml"),
        "crowded.txt: 1001 people per frame",
        Some(1),
    );
    let bad_profile = write(
        tmp.path(),
        "p.toml",
        std::fs::read_to_string(&profile)
            .unwrap()
            .replace("pair_spacing =", "pair_spacing = 9.0\n#"),
    );
    refused_before_running(
        &[
            "crowd",
            "compare",
            seq.to_str().unwrap(),
            "--profile",
            bad_profile.to_str().unwrap(),
        ],
        &tmp.path().join("fresh"),
        "crowd.pair_spacing",
        Some(1),
    );
}
