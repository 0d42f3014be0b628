//! Dead reckoning from the Create's odometry reports.

use futago_msgs::{Odometry, Pose2, wrap_angle};

/// Integrates (distance, angle) reports into a pose, assuming each report's motion is an arc
/// (heading at the report's midpoint), which is exact for constant wheel speeds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OdometryIntegrator {
    pub pose: Pose2,
}

impl OdometryIntegrator {
    /// Starts at `pose`.
    pub fn new(pose: Pose2) -> OdometryIntegrator {
        OdometryIntegrator { pose }
    }

    /// Adds one report and returns the new pose.
    pub fn integrate(&mut self, o: &Odometry) -> Pose2 {
        let mid = self.pose.theta + o.angle / 2.0;
        // Chord length of an arc of length d turning by a: d·sinc(a/2).
        let half = o.angle / 2.0;
        let chord = if half.abs() < 1e-9 {
            o.distance
        } else {
            o.distance * half.sin() / half
        };
        self.pose = Pose2::new(
            self.pose.x + chord * mid.cos(),
            self.pose.y + chord * mid.sin(),
            wrap_angle(self.pose.theta + o.angle),
        );
        self.pose
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use futago_msgs::Time;

    #[test]
    fn a_quarter_circle_in_many_reports_lands_on_the_circle() {
        // Radius 1 m, 90° left, in 100 reports.
        let mut o = OdometryIntegrator::new(Pose2::IDENTITY);
        let n = 100;
        for _ in 0..n {
            o.integrate(&Odometry {
                stamp: Time::ZERO,
                distance: std::f64::consts::FRAC_PI_2 / n as f64,
                angle: std::f64::consts::FRAC_PI_2 / n as f64,
            });
        }
        assert!(
            (o.pose.x - 1.0).abs() < 1e-12 && (o.pose.y - 1.0).abs() < 1e-12,
            "{:?}",
            o.pose
        );
        // One report of the whole arc gives the same, since the arc is exact.
        let mut one = OdometryIntegrator::new(Pose2::IDENTITY);
        one.integrate(&Odometry {
            stamp: Time::ZERO,
            distance: std::f64::consts::FRAC_PI_2,
            angle: std::f64::consts::FRAC_PI_2,
        });
        assert!(one.pose.distance(&o.pose) < 1e-12);
    }
}
