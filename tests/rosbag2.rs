//! ROS 2 bags read as their ROS 1 originals: the shared ROS 1 bags converted by `rosbags`
//! (an independent, maintained converter) into MCAP and SQLite3 rosbag2 bags, then read scan
//! for scan against the original.

mod common;
use common::{python_with, root};
use futago_msgs::carmen::{Log, ReadOptions};
use std::path::Path;

/// `src` (a ROS 1 bag) converted by `rosbags-convert` into a rosbag2 folder `dst` of storage
/// `storage` (`mcap` or `sqlite3`), with `compress` (`none`, `zstd`) by `mode`.
fn convert(python: &Path, src: &Path, dst: &Path, storage: &str, compress: Option<(&str, &str)>) {
    let mut args = vec![
        "-m".to_string(),
        "rosbags.convert".into(),
        "--src".into(),
        src.display().to_string(),
        "--dst".into(),
        dst.display().to_string(),
        "--dst-storage".into(),
        storage.into(),
    ];
    if let Some((c, mode)) = compress {
        args.extend([
            "--compress".into(),
            c.into(),
            "--compress-mode".into(),
            mode.into(),
        ]);
    }
    let o = std::process::Command::new(python)
        .args(&args)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "rosbags-convert failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

fn read(path: &Path) -> Log {
    futago::replay::read_log_with(
        path,
        &ReadOptions {
            strict: true,
            ..Default::default()
        },
    )
    .unwrap_or_else(|e| panic!("{e:#}"))
}

/// The ROS 2 log `b` holds the ROS 1 log `a`'s scans, odometry, mounts and people; stamps
/// equal the ROS 1 bag's logged stamps (ROS 2 has no `seq` to repair late ones by). Returns
/// how many scans the ROS 1 reader restamped.
fn same_as_ros1(a: &Log, b: &Log, what: &str) -> usize {
    assert_eq!(a.scans.len(), b.scans.len(), "{what}: scans");
    assert!(!a.scans.is_empty());
    let mut restamped = 0;
    // The ROS 1 log in the order of its logged stamps (ROS 2 keeps those, so orders them so).
    let mut order: Vec<usize> = (0..a.scans.len()).collect();
    order.sort_by_key(|&i| (a.scans[i].logged, i));
    for (k, &i) in order.iter().enumerate() {
        let (x, y) = (&a.scans[i], &b.scans[k]);
        assert_eq!(x.logged, y.scan.stamp, "{what}: scan {k}'s stamp");
        if x.scan.stamp != x.logged {
            restamped += 1;
        }
        assert_eq!(x.scan.frame, y.scan.frame, "{what}: scan {k}");
        assert_eq!(x.scan.angle_min, y.scan.angle_min, "{what}: scan {k}");
        assert_eq!(x.scan.angle_increment, y.scan.angle_increment);
        assert_eq!(x.scan.range_max, y.scan.range_max);
        assert_eq!(x.mount, y.mount, "{what}: scan {k}'s mount");
        assert_eq!(x.scan.ranges.len(), y.scan.ranges.len());
        for (r, s) in x.scan.ranges.iter().zip(&y.scan.ranges) {
            assert!(
                r.to_bits() == s.to_bits() || (r.is_nan() && s.is_nan()),
                "{what}: scan {k}"
            );
        }
    }
    assert_eq!(a.odometry.len(), b.odometry.len(), "{what}: odometry");
    assert_eq!(a.people.len(), b.people.len(), "{what}: people");
    for (p, q) in a.people.iter().zip(&b.people) {
        assert_eq!((p.id, p.position), (q.id, q.position), "{what}: people");
        if restamped == 0 {
            // The scan each annotation follows.
            assert_eq!(p.scan, q.scan, "{what}: people");
        }
    }
    assert_eq!(a.scan_topic, b.scan_topic);
    assert_eq!(a.odom_topic, b.odom_topic);
    restamped
}

#[test]
fn ros2_bags_converted_from_the_shared_ros1_bags_read_scan_for_scan_as_the_originals() {
    let test = "ros2_bags_converted_from_the_shared_ros1_bags_read_scan_for_scan_as_the_originals";
    let Some(python) = python_with(test, &["rosbags"]) else {
        return;
    };
    let Some(files) = futago_msgs::datasets::require(
        &root(),
        test,
        &[
            "slam-benchmark/intel.orig.bag",
            "slam-benchmark/mit-csail.orig.bag",
            // Annotated people (a custom type, `leg_tracker/Person`, converted with the
            // definition the bag carries).
            "people/general_tracking_moving_1.bag",
        ],
    ) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    for src in &files {
        let ros1 = read(src);
        let stem = src.file_stem().unwrap().to_string_lossy().to_string();
        for (storage, compress) in [
            ("mcap", None),
            ("sqlite3", None),
            ("mcap", Some(("zstd", "message"))),
            // zstd inside the MCAP file's chunks (the metadata says none).
            ("mcap", Some(("zstd", "storage"))),
            ("sqlite3", Some(("zstd", "file"))),
        ] {
            let dst = tmp.path().join(format!(
                "{stem}-{storage}-{}",
                compress.map_or("none".to_string(), |(c, m)| format!("{c}-{m}"))
            ));
            convert(&python, src, &dst, storage, compress);
            let what = format!("{} as {storage} {compress:?}", src.display());
            let restamped = same_as_ros1(&ros1, &read(&dst), &what);
            println!(
                "{what}: {} scans, {} people marks, {restamped} scans restamped by ROS 1's seq",
                ros1.scans.len(),
                ros1.people.len()
            );
            // The file alone reads too (an MCAP describes itself; a .db3 finds its folder's
            // metadata).
            if compress.is_none() {
                let ext = if storage == "mcap" { "mcap" } else { "db3" };
                let file = std::fs::read_dir(&dst)
                    .unwrap()
                    .map(|e| e.unwrap().path())
                    .find(|p| p.extension().is_some_and(|x| x == ext))
                    .unwrap();
                same_as_ros1(&ros1, &read(&file), &what);
            }
        }
    }
}
