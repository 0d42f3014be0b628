//! CARMEN log lines, the text format of the classic 2D SLAM data sets (Intel, MIT CSAIL,
//! Freiburg) and of their relations files.
//!
//! The writer emits `PARAM`, `ODOM`, `ROBOTLASER1`/`ROBOTLASER2` and `TRUEPOS` messages in the
//! field order of CARMEN's logger. Every line ends with `timestamp hostname logger_timestamp`;
//! futago writes the simulation time for both timestamps and `futago` as the host name.

use crate::{LaserScan, Pose2};
use std::fmt::Write as _;

const HOST: &str = "futago";

/// `PARAM name value`.
pub fn param(out: &mut String, name: &str, value: &str) {
    let _ = writeln!(out, "PARAM {name} {value} 0.000000 {HOST} 0.000000");
}

/// `ODOM x y theta tv rv accel timestamp host logger_timestamp`.
pub fn odom(out: &mut String, t: f64, odom: &Pose2, tv: f64, rv: f64) {
    let _ = writeln!(
        out,
        "ODOM {:.6} {:.6} {:.6} {:.6} {:.6} 0.000000 {t:.6} {HOST} {t:.6}",
        odom.x, odom.y, odom.theta, tv, rv
    );
}

/// `TRUEPOS true_x true_y true_theta odom_x odom_y odom_theta timestamp host logger_timestamp`:
/// the simulator's ground truth beside odometry, as CARMEN's own simulator logs it.
pub fn truepos(out: &mut String, t: f64, truth: &Pose2, odom: &Pose2) {
    let _ = writeln!(
        out,
        "TRUEPOS {:.6} {:.6} {:.6} {:.6} {:.6} {:.6} {t:.6} {HOST} {t:.6}",
        truth.x, truth.y, truth.theta, odom.x, odom.y, odom.theta
    );
}

/// `ROBOTLASERn laser_type start_angle fov angular_resolution max_range accuracy
/// remission_mode num_readings ranges… num_remissions laser_pose(x y θ) robot_pose(x y θ)
/// tv rv forward_safety_dist side_safety_dist turn_axis timestamp host logger_timestamp`.
///
/// `channel` is 1 or 2. `robot_pose` is the odometry pose at the scan and `laser_pose` is that
/// pose composed with the laser's mounting. No-return beams (`+∞`) are written as the maximum
/// range, as real CARMEN logs do; returns closer than the minimum range are written as 0.
#[allow(clippy::too_many_arguments)]
pub fn robotlaser(
    out: &mut String,
    channel: u8,
    scan: &LaserScan,
    accuracy: f64,
    laser_pose: &Pose2,
    robot_pose: &Pose2,
    tv: f64,
    rv: f64,
) {
    let t = scan.stamp.secs();
    let fov = scan.angle_increment * (scan.ranges.len().saturating_sub(1)) as f64;
    let _ = write!(
        out,
        "ROBOTLASER{channel} 0 {:.6} {:.6} {:.6} {:.3} {:.3} 0 {}",
        scan.angle_min,
        fov,
        scan.angle_increment,
        scan.range_max,
        accuracy,
        scan.ranges.len()
    );
    for &r in &scan.ranges {
        let r = if r == f32::INFINITY {
            scan.range_max as f32
        } else if r == f32::NEG_INFINITY || r.is_nan() {
            0.0
        } else {
            r
        };
        let _ = write!(out, " {r:.3}");
    }
    let _ = writeln!(
        out,
        " 0 {:.6} {:.6} {:.6} {:.6} {:.6} {:.6} {tv:.6} {rv:.6} 0.000000 0.000000 0.000000 {t:.6} {HOST} {t:.6}",
        laser_pose.x, laser_pose.y, laser_pose.theta, robot_pose.x, robot_pose.y, robot_pose.theta
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Time;

    #[test]
    fn robotlaser_line_has_the_logger_field_layout() {
        let scan = LaserScan {
            frame: "front".into(),
            stamp: Time::from_secs(1.5),
            angle_min: -1.0,
            angle_increment: 0.5,
            time_increment: 0.0,
            range_min: 0.1,
            range_max: 5.0,
            ranges: vec![1.0, f32::INFINITY, f32::NEG_INFINITY, 2.5, 3.0],
        };
        let mut s = String::new();
        let p = Pose2::new(1.0, 2.0, 0.5);
        robotlaser(&mut s, 1, &scan, 0.01, &p, &p, 0.2, 0.0);
        let w: Vec<&str> = s.split_whitespace().collect();
        assert_eq!(w[0], "ROBOTLASER1");
        assert_eq!(w[8], "5");
        assert_eq!(&w[9..14], ["1.000", "5.000", "0.000", "2.500", "3.000"]);
        assert_eq!(w[14], "0"); // no remissions
        // 6 pose values, tv rv, 3 safety fields, then timestamp host logger_timestamp.
        assert_eq!(w.len(), 15 + 6 + 2 + 3 + 3);
        assert_eq!(w[w.len() - 2], "futago");
        assert_eq!(w[w.len() - 1], "1.500000");
        // The field of view spans first to last beam.
        assert_eq!(w[3], "2.000000");
    }
}
