//! `futago replay` reads what a damaged log holds and says what it lost; it replays a bag of
//! laser scans alone on scan matching; and it makes the user choose between several scan
//! topics. The logs are made here: a robot driving through a room, its scans cast by hand.

use futago_msgs::rosbag::writer::{
    BagWriter, laser_scan_message, odometry_message, person_message,
};
use futago_msgs::{LaserScan, Pose2, Time};
mod common;
use common::*;
use std::path::Path;

/// Scans of the robot in a 6 m × 4 m room with a box in one corner, 10 Hz, the robot driving
/// 3 cm and turning 0.002 rad a scan.
const SCANS: u32 = 100;

fn pose(k: u32) -> Pose2 {
    Pose2::new(-1.5 + 0.03 * k as f64, 0.0, 0.002 * k as f64)
}

fn scan(k: u32, frame: &str) -> LaserScan {
    let inc = std::f64::consts::PI / 180.0;
    LaserScan {
        frame: frame.into(),
        stamp: Time::from_secs(k as f64 / 10.0),
        angle_min: -std::f64::consts::FRAC_PI_2,
        angle_increment: inc,
        time_increment: 0.0,
        range_min: 0.02,
        range_max: 20.0,
        ranges: (0..181)
            .map(|b| room_cast(pose(k), -std::f64::consts::FRAC_PI_2 + b as f64 * inc))
            .collect(),
    }
}

/// The drive as a bag, `per_chunk` messages a chunk (bz2), with odometry or scans alone.
fn bag(odometry: bool, per_chunk: usize) -> Vec<u8> {
    let mut w = BagWriter::new("bz2", per_chunk);
    let sc = w.connection("/scan", "sensor_msgs/LaserScan");
    let od = w.connection("/odom", "nav_msgs/Odometry");
    for k in 1..=SCANS {
        let t = Time::from_secs(k as f64 / 10.0);
        if odometry {
            w.write(od, t, &odometry_message(k, t, "odom", "laser", pose(k)));
        }
        w.write(sc, t, &laser_scan_message(k, &scan(k, "laser")));
    }
    w.finish()
}

/// `futago replay LOG --out OUT`, which must succeed; its output and summary.
fn replayed(log: &Path, out: &Path) -> (std::process::Output, serde_json::Value) {
    let o = futago(&[
        "replay",
        log.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    ok(&o);
    (o, summary(out))
}

fn chunk_starts(b: &[u8]) -> Vec<usize> {
    b.windows(8)
        .enumerate()
        .filter(|(_, w)| *w == b"\x04\x00\x00\x00op=\x05")
        .map(|(k, _)| k)
        .collect()
}

#[test]
fn a_cut_or_corrupted_bag_is_replayed_for_what_it_holds() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let whole = bag(true, 10);
    let chunks = chunk_starts(&whole);
    assert_eq!(chunks.len(), 20);
    // Cut inside the 13th chunk, as a recorder killed mid-write leaves a bag.
    let cut = write(d, "cut.bag", &whole[..chunks[12] + 500]);
    let out = d.join("cut");
    let (o, s) = replayed(&cut, &out);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("damaged log") && err.contains("cut short"),
        "{err}"
    );
    // The twelve whole chunks' 60 scans (the cut one's bz2 block does not decompress).
    assert_eq!(s["scans"], 60);
    assert_eq!(s["read"]["damaged"], true);
    assert_eq!(s["read"]["damage"]["truncated"], true);
    assert!((s["read"]["last_stamp_s"].as_f64().unwrap() - 6.0).abs() < 1e-9);
    assert_eq!(s["read"]["messages"]["/scan"], 60);
    // --strict keeps the refusal, and writes nothing.
    let strict = d.join("strict");
    let o = futago(&[
        "replay",
        cut.to_str().unwrap(),
        "--strict",
        "--out",
        strict.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("truncated"));
    assert!(!strict.exists());
    // A chunk garbled in the middle costs its own five scans; the map is built on either side.
    let mut bad = whole.clone();
    for b in &mut bad[chunks[9] + 100..chunks[9] + 140] {
        *b ^= 0xa5;
    }
    let bad = write(d, "bad.bag", &bad);
    let out = d.join("bad");
    let (_, s) = replayed(&bad, &out);
    assert_eq!(s["scans"], 95);
    let loss = &s["read"]["damage"]["losses"][0];
    assert!(
        (loss["last_stamp_before_s"].as_f64().unwrap() - 4.5).abs() < 1e-9,
        "{loss}"
    );
    assert!(
        (loss["first_stamp_after_s"].as_f64().unwrap() - 5.1).abs() < 1e-9,
        "{loss}"
    );
    // The whole bag is not damaged, and says so.
    let good = write(d, "good.bag", &whole);
    let out = d.join("good");
    let (_, s) = replayed(&good, &out);
    assert_eq!(s["scans"], 100);
    assert_eq!(s["read"]["damaged"], false);
}

#[test]
fn a_carmen_log_with_a_bad_line_is_replayed_around_it() {
    let tmp = tempfile::tempdir().unwrap();
    let mut text = String::new();
    for k in 1..=SCANS {
        let p = pose(k);
        let s = scan(k, "front");
        let t = k as f64 / 10.0;
        if k == 50 {
            text += "FLASER 181 garbage\n";
            continue;
        }
        text += &flaser_line(&s.ranges, p, t);
    }
    let log = write(tmp.path(), "log.clf", text.as_bytes());
    let out = tmp.path().join("o");
    let (_, s) = replayed(&log, &out);
    assert_eq!(s["scans"], 99);
    assert_eq!(s["read"]["damage"]["losses"][0]["at"], 50);
    let o = futago(&["replay", log.to_str().unwrap(), "--strict"]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("log.clf: line 50"));
}

#[test]
fn a_bag_of_scans_alone_is_localised_by_scan_matching() {
    let tmp = tempfile::tempdir().unwrap();
    let b = write(tmp.path(), "scans.bag", bag(false, 50));
    let out = tmp.path().join("o");
    let (o, s) = replayed(&b, &out);
    assert!(String::from_utf8_lossy(&o.stdout).contains("no odometry in the log"));
    assert!(
        s["read"]["odometry"]
            .as_str()
            .unwrap()
            .starts_with("absent")
    );
    assert_eq!(s["read"]["odom_topic"], serde_json::Value::Null);
    // The motion comes from the scans: the last pose, relative to the first, is the drive's
    // (2.97 m and 0.198 rad) within 3 % of the distance.
    let traj =
        futago_msgs::tum::parse(&std::fs::read_to_string(out.join("trajectory.txt")).unwrap())
            .unwrap();
    let (first, last) = (
        traj[0].pose.to_pose2(),
        traj[traj.len() - 1].pose.to_pose2(),
    );
    let moved = first.between(&last);
    let truth = pose(1).between(&pose(SCANS));
    assert!(
        (moved.x - truth.x).hypot(moved.y - truth.y) < 0.03 * 2.97,
        "{moved:?} vs {truth:?}"
    );
    assert!((moved.theta - truth.theta).abs() < 0.02, "{moved:?}");
}

#[test]
fn several_scan_topics_are_an_error_until_one_is_chosen() {
    let tmp = tempfile::tempdir().unwrap();
    let mut w = BagWriter::new("lz4", 20);
    let front = w.connection("/front/scan", "sensor_msgs/LaserScan");
    let rear = w.connection("/rear/scan", "sensor_msgs/LaserScan");
    for k in 1..=SCANS {
        let t = Time::from_secs(k as f64 / 10.0);
        w.write(front, t, &laser_scan_message(k, &scan(k, "front")));
        w.write(rear, t, &laser_scan_message(k, &scan(k, "rear")));
    }
    let b = write(tmp.path(), "two.bag", w.finish());
    let out = tmp.path().join("o");
    let o = futago(&[
        "replay",
        b.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("/front/scan") && err.contains("/rear/scan") && err.contains("--scan-topic"),
        "{err}"
    );
    assert!(!out.exists());
    let o = futago(&[
        "replay",
        b.to_str().unwrap(),
        "--scan-topic",
        "/rear/scan",
        "--out",
        out.to_str().unwrap(),
    ]);
    ok(&o);
    assert!(String::from_utf8_lossy(&o.stdout).contains("scans from /rear/scan"));
    let s = summary(&out);
    assert_eq!(s["scans"], 100);
    assert_eq!(s["read"]["scan_topic"], "/rear/scan");
}

/// The annotated people log rewritten with its scans and annotations alone (no odometry, no
/// tf), as people-tracking logs are often recorded: people are still tracked, in the frame
/// that scan matching gives, about as well as with the robot's odometry.
#[test]
fn a_scan_only_copy_of_the_people_log_is_tracked() {
    let root = root();
    let Some(files) = futago_msgs::datasets::require(
        &root,
        "a_scan_only_copy_of_the_people_log_is_tracked",
        &["people/general_tracking_moving_1.bag"],
    ) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let log = futago_msgs::rosbag::read(&std::fs::read(&files[0]).unwrap()).unwrap();
    let mut w = BagWriter::new("lz4", 200);
    let sc = w.connection("/scan", "sensor_msgs/LaserScan");
    let pe = w.connection("/ground_truth_people_tracks", "leg_tracker/Person");
    let mut marks = vec![Vec::new(); log.scans.len()];
    for m in &log.people {
        marks[m.scan].push(m);
    }
    for (k, s) in log.scans.iter().enumerate() {
        let mut scan = s.scan.clone();
        scan.stamp = s.logged;
        w.write(sc, s.logged, &laser_scan_message(k as u32 + 1, &scan));
        for m in &marks[k] {
            w.write(pe, s.logged, &person_message(m.id, m.position));
        }
    }
    let scans_only = write(tmp.path(), "scans_only.bag", w.finish());
    let run = |bag: &Path, name: &str| {
        let out = tmp.path().join(name);
        ok(&futago(&[
            "replay",
            bag.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]));
        summary(&out)
    };
    let with = run(&files[0], "with");
    eprintln!("with odometry: {}", with["people"]["all_frames"]);
    let without = run(&scans_only, "without");
    eprintln!("scans alone: {}", without["people"]["all_frames"]);
    assert!(
        without["read"]["odometry"]
            .as_str()
            .unwrap()
            .starts_with("absent")
    );
    let p = &without["people"];
    assert_eq!(p["annotations"], 153);
    let matches = |s: &serde_json::Value| s["people"]["all_frames"]["matches"].as_u64().unwrap();
    // Tracked in a fixed frame: as many people matched as with odometry, give or take a few.
    assert!(
        matches(&without) as f64 >= 0.8 * matches(&with) as f64,
        "{} matched without odometry, {} with",
        matches(&without),
        matches(&with)
    );
}
