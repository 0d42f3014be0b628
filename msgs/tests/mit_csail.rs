//! The two copies of the MIT CSAIL log in `shared/datasets/slam-benchmark/` (CARMEN and ROS 1
//! bag) read to the same scans, stamps and odometry.

use futago_msgs::{carmen, rosbag};
use std::path::PathBuf;

fn dataset(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/datasets/slam-benchmark")
        .join(name)
}

#[test]
fn carmen_log_and_bag_agree() {
    let clf = carmen::read(&std::fs::read_to_string(dataset("mit-csail.clf")).unwrap()).unwrap();
    let bag = rosbag::read(&std::fs::read(dataset("mit-csail.orig.bag")).unwrap()).unwrap();
    assert_eq!(clf.scans.len(), 1988);
    assert_eq!(bag.scans.len(), clf.scans.len());
    for (a, b) in clf.scans.iter().zip(&bag.scans) {
        assert!(
            (a.scan.stamp - b.scan.stamp).secs().abs() < 1e-5,
            "{:?} {:?}",
            a.scan.stamp,
            b.scan.stamp
        );
        assert_eq!(a.scan.ranges.len(), b.scan.ranges.len());
        assert!((a.scan.angle_min - b.scan.angle_min).abs() < 1e-6);
        assert!((a.scan.angle_increment - b.scan.angle_increment).abs() < 1e-6);
        // Same readings where both see a return (the bag keeps float32 of the 2-decimal text).
        for (x, y) in a.scan.ranges.iter().zip(&b.scan.ranges) {
            if x.is_finite() && y.is_finite() {
                assert!((x - y).abs() < 1e-3, "{x} vs {y}");
            }
        }
        assert!(
            a.odometry.distance(&b.odometry) < 1e-3,
            "{:?} vs {:?}",
            a.odometry,
            b.odometry
        );
    }
}
