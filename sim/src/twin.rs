//! A real log's drive replayed in the simulator: the robot is placed along a given path (the
//! log's SLAM trajectory, which becomes the twin's truth) at the log's scan times, its laser is
//! cast in the world with the log's own layout, and its odometry is made from the path with a
//! robot profile's errors ([`futago_msgs::profile`]).
//!
//! The laser's readings are the hit's Gaussian noise (`σ(r)² = sigma² + (sigma_rel·r)²`) and
//! the [`BeamErrors`]; the odometry's are the profile's model run backwards: the reported step
//! is the true one with the scales and the heading bias undone, less a draw of the random walk.

use crate::beam::{BeamErrors, Reading};
use futago_msgs::profile::OdometryProfile;
use futago_msgs::{LaserScan, Pose2};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// A laser replayed along a path.
#[derive(Debug, Clone)]
pub struct TwinLaser {
    pub sigma: f64,
    pub sigma_rel: f64,
    pub errors: BeamErrors,
    rng: ChaCha8Rng,
}

impl TwinLaser {
    /// `errors.quadrature` is set: the profile's spread adds its terms as variances.
    pub fn new(sigma: f64, sigma_rel: f64, errors: BeamErrors, rng: ChaCha8Rng) -> TwinLaser {
        TwinLaser {
            sigma,
            sigma_rel,
            errors: BeamErrors {
                quadrature: true,
                ..errors
            },
            rng,
        }
    }

    /// The scan `template` (its stamp, frame, angles and range limits) taken from `laser` (the
    /// laser's pose in the world): `cast(x, y, bearing, max)` gives the range to the first
    /// surface along a beam, or `None` within `max`.
    pub fn scan(
        &mut self,
        template: &LaserScan,
        laser: &Pose2,
        mut cast: impl FnMut(f64, f64, f64, f64) -> Option<f64>,
    ) -> LaserScan {
        let (lo, hi) = (template.range_min, template.range_max);
        let surfaces: Vec<Option<f64>> = (0..template.ranges.len())
            .map(|k| cast(laser.x, laser.y, laser.theta + template.angle(k), hi))
            .collect();
        let mut ranges: Vec<f32> = surfaces
            .iter()
            .map(|s| {
                let n: f64 = StandardNormal.sample(&mut self.rng);
                let noisy = s.map(|d| d + n * self.errors.sigma(self.sigma, self.sigma_rel, d));
                match self.errors.apply(*s, noisy, lo, hi, &mut self.rng) {
                    Reading::Lost | Reading::Surface(None) => f32::INFINITY,
                    Reading::Surface(Some(v)) | Reading::Phantom(v) => {
                        if v > hi {
                            f32::INFINITY
                        } else if v < lo {
                            f32::NEG_INFINITY
                        } else {
                            v as f32
                        }
                    }
                }
            })
            .collect();
        self.errors.mix_edges(&surfaces, &mut ranges, &mut self.rng);
        LaserScan {
            ranges,
            ..template.clone()
        }
    }
}

/// Odometry made from a path with a profile's errors.
#[derive(Debug, Clone)]
pub struct TwinOdometry {
    profile: OdometryProfile,
    rng: ChaCha8Rng,
    reported: Pose2,
    last: Option<Pose2>,
}

impl TwinOdometry {
    /// Reports start at the identity.
    pub fn new(profile: OdometryProfile, rng: ChaCha8Rng) -> TwinOdometry {
        TwinOdometry {
            profile,
            rng,
            reported: Pose2::IDENTITY,
            last: None,
        }
    }

    /// The odometry pose reported when the robot is truly at `truth`.
    pub fn report(&mut self, truth: &Pose2) -> Pose2 {
        let Some(last) = self.last.replace(*truth) else {
            return self.reported;
        };
        let p = &self.profile;
        let step = last.between(truth);
        let kt = p.translation_scale.value.max(1e-3);
        let kr = p.rotation_scale.value.max(1e-3);
        // The profile's model forwards: true = (kt·x, kt·y, kr·θ + b·d) + noise, with d the
        // reported length. Backwards, the noise drawn for the reported step is taken off.
        let (x, y) = (step.x / kt, step.y / kt);
        let d = x.hypot(y);
        let theta = (step.theta - p.heading_bias.value * d) / kr;
        let along = (p.translation_variance.value.max(0.0) * d).sqrt();
        let turn = (p.heading_variance_per_rad.value.max(0.0) * theta.abs()
            + p.heading_variance_per_m.value.max(0.0) * d)
            .sqrt();
        let (n1, n2): (f64, f64) = (
            StandardNormal.sample(&mut self.rng),
            StandardNormal.sample(&mut self.rng),
        );
        let (ux, uy) = if d > 1e-9 { (x / d, y / d) } else { (1.0, 0.0) };
        let mut shrink = along * n1 / kt;
        let mut twist = turn * n2 / kr;
        // Outliers (stalls, slips): the profile counts them per stretch of its calibration
        // length; a step covers the share of a stretch that its length or its turn does.
        if p.outlier_rate.value > 0.0 && p.stretch_length_m > 0.0 {
            let share = (d / p.stretch_length_m)
                .max(theta.abs() / p.stretch_turn_rad.max(1e-3))
                .min(1.0);
            let u: f64 = rand::Rng::random(&mut self.rng);
            if u < p.outlier_rate.value * share {
                let (m1, m2): (f64, f64) = (
                    StandardNormal.sample(&mut self.rng),
                    StandardNormal.sample(&mut self.rng),
                );
                shrink += p.outlier_translation.value * m1 / kt;
                twist += p.outlier_heading.value * m2 / kr;
            }
        }
        let reported = Pose2::new(x - ux * shrink, y - uy * shrink, theta - twist);
        self.reported = self.reported.compose(&reported);
        self.reported
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::noise::stream;
    use futago_msgs::Time;
    use futago_msgs::profile::Estimate;

    fn profile(kt: f64, kr: f64, b: f64) -> OdometryProfile {
        let e = |v| Estimate::new(v, 0.0, 0);
        OdometryProfile {
            translation_scale: e(kt),
            rotation_scale: e(kr),
            heading_bias: e(b),
            translation_variance: e(0.0),
            heading_variance_per_rad: e(0.0),
            heading_variance_per_m: e(0.0),
            outlier_rate: e(0.0),
            outlier_translation: e(0.0),
            outlier_heading: e(0.0),
            stretches: 0,
            stretch_length_m: 0.0,
            stretch_turn_rad: 0.0,
            latency: e(0.0),
        }
    }

    #[test]
    fn noiseless_odometry_undoes_the_profiles_scales_and_bias() {
        // Driving 1 m straight in 100 steps with true scale 1.02, rotation scale 0.95 and a
        // bias of 0.05 rad/m: the odometry reports 1/1.02 m and turns −0.05·(1/1.02)/0.95 rad.
        let mut o = TwinOdometry::new(profile(1.02, 0.95, 0.05), stream(0, "odo"));
        let mut last = Pose2::IDENTITY;
        for k in 0..=100 {
            let truth = Pose2::new(k as f64 * 0.01, 0.0, 0.0);
            last = o.report(&truth);
        }
        let d = 1.0 / 1.02;
        assert!((last.x.hypot(last.y) - d).abs() < 1e-3, "{last:?}");
        assert!((last.theta + 0.05 * d / 0.95).abs() < 1e-9, "{last:?}");
    }

    #[test]
    fn a_replayed_scan_keeps_the_layout_and_reads_the_cast() {
        let template = LaserScan {
            frame: "laser".into(),
            stamp: Time::from_secs(12.5),
            angle_min: -1.0,
            angle_increment: 0.5,
            time_increment: 0.0,
            range_min: 0.1,
            range_max: 10.0,
            ranges: vec![0.0; 5],
        };
        let mut l = TwinLaser::new(0.0, 0.0, BeamErrors::default(), stream(0, "laser"));
        // A wall at x = 2 in front of a laser at the origin facing +x.
        let s = l.scan(&template, &Pose2::IDENTITY, |_, _, a, max| {
            let r = 2.0 / a.cos();
            (a.cos() > 0.0 && r <= max).then_some(r)
        });
        assert_eq!(
            (s.stamp, s.ranges.len(), s.angle_min),
            (template.stamp, 5, -1.0)
        );
        for (k, r) in s.ranges.iter().enumerate() {
            let a = -1.0 + 0.5 * k as f64;
            assert!((*r as f64 - 2.0 / a.cos()).abs() < 1e-5, "{k}: {r}");
        }
    }
}
