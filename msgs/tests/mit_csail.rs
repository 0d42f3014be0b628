//! The two copies of the MIT CSAIL log of the data folder (`futago_msgs::datasets`: CARMEN
//! and ROS 1 bag) read to the same scans, stamps and odometry. Skipped, saying so, where the
//! data is absent (a failure with `FUTAGO_REQUIRE_DATA=1`).

use futago_msgs::{carmen, datasets, rosbag};
use std::path::Path;

#[test]
fn carmen_log_and_bag_agree() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let Some(files) = datasets::require(
        &root,
        "carmen_log_and_bag_agree",
        &[
            "slam-benchmark/mit-csail.clf",
            "slam-benchmark/mit-csail.orig.bag",
        ],
    ) else {
        return;
    };
    let clf = carmen::read(&std::fs::read_to_string(&files[0]).unwrap()).unwrap();
    let bag = rosbag::read(&std::fs::read(&files[1]).unwrap()).unwrap();
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
