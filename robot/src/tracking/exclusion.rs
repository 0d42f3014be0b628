//! Keeping tracked people out of the maps and the localiser: the places the tracker's people
//! stand are cut out of the laser's scans (before MCL and SLAM) and of the RGB-D keyframes'
//! points (seed 000 §2.6 stops and pauses for people; seed 004 §5 pauses its 3D scans while
//! something moves; neither leaves a walking person in its map). A person is a vertical
//! cylinder of `radius` about their tracked position: the legs' stride (steps of 0.65–0.8 m
//! put a foot up to 0.4 m from the body's centre) and the shin (0.05 m) make 0.45 m, and the
//! tracker's error (its MOTP, about 0.15 m) is partly covered by the rest of the default 0.5 m.
//! A beam cut out becomes NaN (REP 117's "not a measurement"), which MCL, the occupancy grid
//! and the scan matcher all skip.

use crate::config::{ConfigError, check_ranges};
use futago_msgs::{LaserScan, Pose2};
use serde::{Deserialize, Serialize};

/// Settings of the exclusion (`people.exclusion`).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct ExclusionConfig {
    /// Whether tracked people are cut out of the scans and the RGB-D keyframes.
    pub enabled: bool,
    /// Radius of the cylinder cut out about a tracked person, m.
    pub radius: f64,
}

impl Default for ExclusionConfig {
    fn default() -> Self {
        ExclusionConfig {
            enabled: true,
            radius: 0.5,
        }
    }
}

impl ExclusionConfig {
    /// Checks every field; errors name `prefix.field`.
    pub fn validate(&self, prefix: &str) -> Result<(), ConfigError> {
        check_ranges(prefix, &[("radius", self.radius, 0.0, 3.0)])
    }
}

/// The places of tracked people, as vertical cylinders in one frame (the robot base's).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Exclusion {
    centres: Vec<[f64; 2]>,
    radius: f64,
}

impl Exclusion {
    /// People at `centres` (base frame), each a cylinder of the configured radius; nothing
    /// when the exclusion is disabled.
    pub fn new(config: &ExclusionConfig, centres: Vec<[f64; 2]>) -> Exclusion {
        Exclusion {
            centres: if config.enabled { centres } else { Vec::new() },
            radius: config.radius,
        }
    }

    /// Whether no one is cut out.
    pub fn is_empty(&self) -> bool {
        self.centres.is_empty() || self.radius <= 0.0
    }

    /// Whether the point `p` (x, y in the base frame) lies on a tracked person.
    pub fn contains(&self, p: [f64; 2]) -> bool {
        let r2 = self.radius * self.radius;
        self.centres
            .iter()
            .any(|c| (p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) <= r2)
    }

    /// Whether any person stands within the sector of bearings `[-half_fov, half_fov]` about
    /// the direction `view` (a pose in the base frame: a camera's place and heading), no
    /// further than `range` from it. A person whose cylinder reaches into the sector counts.
    pub fn in_view(&self, view: &Pose2, half_fov: f64, range: f64) -> bool {
        if self.is_empty() {
            return false;
        }
        let to_view = view.inverse();
        self.centres.iter().any(|c| {
            let [x, y] = to_view.transform_point(*c);
            let d = x.hypot(y);
            if d > range + self.radius {
                return false;
            }
            if d <= self.radius {
                return true;
            }
            // The cylinder's angular half-width, seen from the view point.
            let spread = (self.radius / d).asin();
            y.atan2(x).abs() <= half_fov + spread
        })
    }

    /// `scan` (taken by a laser at `mount` in the base frame) with every beam that ends on a
    /// tracked person set to NaN, and how many beams that was; `None` when no beam was cut.
    pub fn mask_scan(&self, scan: &LaserScan, mount: &Pose2) -> Option<(LaserScan, usize)> {
        if self.is_empty() {
            return None;
        }
        let mut out: Option<LaserScan> = None;
        let mut cut = 0;
        for (k, &r) in scan.ranges.iter().enumerate() {
            let r = r as f64;
            if !r.is_finite() {
                continue;
            }
            let a = scan.angle(k);
            if self.contains(mount.transform_point([r * a.cos(), r * a.sin()])) {
                out.get_or_insert_with(|| scan.clone()).ranges[k] = f32::NAN;
                cut += 1;
            }
        }
        out.map(|s| (s, cut))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use futago_msgs::Time;

    /// A scan of a circular room of radius 4 m about the laser, one beam a degree.
    fn room() -> LaserScan {
        LaserScan {
            frame: "laser".into(),
            stamp: Time::ZERO,
            angle_min: -std::f64::consts::PI,
            angle_increment: 1f64.to_radians(),
            time_increment: 0.0,
            range_min: 0.02,
            range_max: 30.0,
            ranges: vec![4.0; 360],
        }
    }

    #[test]
    fn beams_ending_on_a_person_are_cut_and_no_others() {
        let mut scan = room();
        // A person 2 m ahead of the base: the beams near bearing 0 end on their legs at
        // 1.9 m (the laser sits 0.1 m ahead of the base, so 1.8 m from the laser).
        for k in 175..=185 {
            scan.ranges[k] = 1.8;
        }
        scan.ranges[10] = f32::INFINITY;
        let mount = Pose2::new(0.1, 0.0, 0.0);
        let ex = Exclusion::new(&ExclusionConfig::default(), vec![[2.0, 0.0]]);
        let (masked, cut) = ex.mask_scan(&scan, &mount).expect("beams were cut");
        assert_eq!(cut, 11);
        for (k, r) in masked.ranges.iter().enumerate() {
            if (175..=185).contains(&k) {
                assert!(r.is_nan(), "beam {k} ends on the person");
            } else {
                assert!(!r.is_nan(), "beam {k} ends on the wall");
            }
        }
        // Disabled, or no one there: the scan is left alone.
        let off = ExclusionConfig {
            enabled: false,
            ..ExclusionConfig::default()
        };
        assert!(
            Exclusion::new(&off, vec![[2.0, 0.0]])
                .mask_scan(&scan, &mount)
                .is_none()
        );
        let far = Exclusion::new(&ExclusionConfig::default(), vec![[-1.0, 0.0]]);
        assert!(far.mask_scan(&scan, &mount).is_none());
    }

    #[test]
    fn a_person_is_in_view_when_the_cylinder_reaches_the_sector() {
        let ex = |c: [f64; 2]| Exclusion::new(&ExclusionConfig::default(), vec![c]);
        let camera = Pose2::new(0.1, 0.0, 0.0);
        let half = 28.5f64.to_radians();
        // Straight ahead, and at the edge: 3 m out at 35°, the cylinder spans ±asin(0.5/3)
        // = ±9.6°, so it reaches 25.4° < 28.5°.
        assert!(ex([3.0, 0.0]).in_view(&camera, half, 4.0));
        let edge = 35f64.to_radians();
        assert!(ex([0.1 + 3.0 * edge.cos(), 3.0 * edge.sin()]).in_view(&camera, half, 4.0));
        // Behind, too far, or well off to the side.
        assert!(!ex([-2.0, 0.0]).in_view(&camera, half, 4.0));
        assert!(!ex([5.0, 0.0]).in_view(&camera, half, 4.0));
        let side = 45f64.to_radians();
        assert!(!ex([0.1 + 3.0 * side.cos(), 3.0 * side.sin()]).in_view(&camera, half, 4.0));
        // A camera turned to look left sees that one.
        let left = Pose2::new(0.1, 0.0, side);
        assert!(ex([0.1 + 3.0 * side.cos(), 3.0 * side.sin()]).in_view(&left, half, 4.0));
    }
}
