//! Laser SLAM. [`IcpSlam`] is seed 000's method (written for futago): each scan is matched by
//! ICP to the map built so far, starting from the odometry guess; a scan becomes a keyframe,
//! and enters the map, every `keyframe_distance` of travel (300 mm in seed 000) or
//! `keyframe_angle` of turn. There is no loop closure: this is the baseline that graph SLAM is
//! measured against.

use crate::icp::{IcpConfig, PointMap, align, scan_points};
use crate::occupancy::{OccupancyConfig, OccupancyMap};
use futago_msgs::{LaserScan, Pose2, Time, wrap_angle};
use serde::Deserialize;

/// Parameters of the ICP SLAM (`slam.*`).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IcpSlamConfig {
    /// Travel between keyframes, m.
    pub keyframe_distance: f64,
    /// Turn between keyframes, rad.
    pub keyframe_angle: f64,
    /// Readings beyond this are not used for matching, m.
    pub max_range: f64,
    /// A match that moves the pose further than this from the odometry guess (m, rad) is
    /// refused, and the scan dead-reckoned.
    pub max_correction: f64,
    pub max_correction_angle: f64,
    pub icp: IcpConfig,
    pub grid: OccupancyConfig,
}

impl Default for IcpSlamConfig {
    fn default() -> Self {
        IcpSlamConfig {
            keyframe_distance: 0.3,
            keyframe_angle: 0.35,
            max_range: 30.0,
            max_correction: 0.5,
            max_correction_angle: 0.6,
            icp: IcpConfig::default(),
            grid: OccupancyConfig::default(),
        }
    }
}

/// What SLAM did with one scan.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SlamUpdate {
    pub pose: Pose2,
    /// Whether ICP accepted a match (else the pose is the odometry guess).
    pub matched: bool,
    pub keyframe: bool,
}

/// Seed 000's ICP scan-to-map SLAM.
pub struct IcpSlam {
    config: IcpSlamConfig,
    map: PointMap,
    grid: OccupancyMap,
    pose: Pose2,
    last_odometry: Option<Pose2>,
    last_keyframe: Option<Pose2>,
    trajectory: Vec<(Time, Pose2)>,
    keyframes: usize,
    unmatched: usize,
}

impl IcpSlam {
    /// Starts at `start` (the map frame's origin is where the robot starts when identity).
    pub fn new(config: IcpSlamConfig, start: Pose2) -> IcpSlam {
        IcpSlam {
            map: PointMap::new(config.icp.voxel, config.icp.max_distance_start.max(0.05)),
            grid: OccupancyMap::new(config.grid),
            config,
            pose: start,
            last_odometry: None,
            last_keyframe: None,
            trajectory: Vec::new(),
            keyframes: 0,
            unmatched: 0,
        }
    }

    /// Processes one scan with the odometry pose of the robot at its time and the laser's
    /// mount on the robot.
    pub fn update(&mut self, scan: &LaserScan, odometry: &Pose2, mount: &Pose2) -> SlamUpdate {
        let guess = match self.last_odometry {
            Some(prev) => self.pose.compose(&prev.between(odometry)),
            None => self.pose,
        };
        self.last_odometry = Some(*odometry);
        let points = scan_points(scan, mount, self.config.max_range, &self.config.icp);
        let aligned = align(&self.map, &points, guess, &self.config.icp).filter(|a| {
            a.pose.distance(&guess) <= self.config.max_correction
                && wrap_angle(a.pose.theta - guess.theta).abs() <= self.config.max_correction_angle
        });
        let matched = aligned.is_some();
        if !matched && !self.map.is_empty() {
            self.unmatched += 1;
        }
        self.pose = aligned.map(|a| a.pose).unwrap_or(guess);
        let keyframe = match self.last_keyframe {
            None => true,
            Some(k) => {
                k.distance(&self.pose) >= self.config.keyframe_distance
                    || wrap_angle(k.theta - self.pose.theta).abs() >= self.config.keyframe_angle
            }
        };
        if keyframe {
            self.map.insert(&self.pose, &points);
            self.grid.insert(&self.pose.compose(mount), scan);
            self.last_keyframe = Some(self.pose);
            self.keyframes += 1;
        }
        self.trajectory.push((scan.stamp, self.pose));
        SlamUpdate {
            pose: self.pose,
            matched,
            keyframe,
        }
    }

    /// Estimated pose after every scan.
    pub fn trajectory(&self) -> &[(Time, Pose2)] {
        &self.trajectory
    }

    /// The occupancy grid of the keyframes.
    pub fn grid(&self) -> &OccupancyMap {
        &self.grid
    }

    pub fn keyframes(&self) -> usize {
        self.keyframes
    }

    /// Scans ICP could not match (their pose is dead-reckoned).
    pub fn unmatched(&self) -> usize {
        self.unmatched
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::icp::tests_support::room_scan;

    #[test]
    fn icp_slam_follows_a_drive_that_odometry_gets_wrong() {
        let mut slam = IcpSlam::new(IcpSlamConfig::default(), Pose2::IDENTITY);
        // The robot drives 1.5 m along x and turns 0.5 rad; odometry overestimates distance by
        // 5 % and turns by 10 %.
        let mut odo = Pose2::IDENTITY;
        let mut truth = Pose2::IDENTITY;
        for k in 0..=60 {
            if k > 0 {
                truth = truth.compose(&Pose2::new(0.025, 0.0, 0.5 / 60.0));
                odo = odo.compose(&Pose2::new(0.025 * 1.05, 0.0, 0.55 / 60.0));
            }
            let mut scan = room_scan(&truth);
            scan.stamp = Time::from_secs(k as f64 * 0.1);
            slam.update(&scan, &odo, &Pose2::IDENTITY);
        }
        let est = slam.trajectory().last().unwrap().1;
        assert!(
            odo.distance(&truth) > 0.07,
            "odometry error {}",
            odo.distance(&truth)
        );
        assert!(est.distance(&truth) < 0.01, "SLAM {est:?} vs {truth:?}");
        assert!(wrap_angle(est.theta - truth.theta).abs() < 0.5f64.to_radians());
        assert!(slam.keyframes() >= 5 && slam.keyframes() < 60);
        assert_eq!(slam.unmatched(), 0);
    }
}
