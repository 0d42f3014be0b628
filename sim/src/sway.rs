//! The sway of a sensor's carrier: the small, smooth wobble of a pushed wagon or a hand-held
//! camera about the pose its carrier follows.
//!
//! Each of the six degrees of freedom (x, y, z in m; roll, pitch, yaw in degrees, in the
//! carrier's frame) moves as `A sin(2π t / T + φ)`, with its own amplitude `A` and period `T`
//! and a fixed phase `φ = k` rad for the k-th degree (so that they do not peak together).
//! Periods that are not multiples of one another give a motion that does not repeat within a
//! run. It is a function of time alone, like a joint's angle, so the true pose never drifts
//! with the step size. Its pose is applied between the carrier's frame and the sensor's mount:
//! `carrier · sway(t) · mount`.

use crate::config::{SpecError, check_range};
use futago_msgs::Time;
use glam::{EulerRot, Quat, Vec3};
use rapier3d::math::Pose;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// A `[camera.sway]` table.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SwayConfig {
    /// Amplitudes of x, y, z, m.
    #[serde(default)]
    pub xyz: [f64; 3],
    /// Amplitudes of roll, pitch, yaw, degrees.
    #[serde(default)]
    pub rpy_deg: [f64; 3],
    /// Periods of x, y, z, roll, pitch, yaw, s.
    pub period: [f64; 6],
}

impl SwayConfig {
    /// Checks every field; errors name `KEY.field`.
    pub fn validate(&self, file: &Path, key: &str) -> Result<(), SpecError> {
        for (i, a) in self.xyz.iter().enumerate() {
            check_range(file, &format!("{key}.xyz[{i}]"), *a, 0.0, 1.0, "m")?;
        }
        for (i, a) in self.rpy_deg.iter().enumerate() {
            check_range(
                file,
                &format!("{key}.rpy_deg[{i}]"),
                *a,
                0.0,
                45.0,
                "degrees",
            )?;
        }
        for (i, t) in self.period.iter().enumerate() {
            check_range(file, &format!("{key}.period[{i}]"), *t, 0.01, 1e4, "s")?;
        }
        Ok(())
    }

    /// The six offsets at `t`: x, y, z (m) and roll, pitch, yaw (rad).
    pub fn offsets(&self, t: Time) -> [f64; 6] {
        let s = t.secs();
        std::array::from_fn(|k| {
            let a = if k < 3 {
                self.xyz[k]
            } else {
                self.rpy_deg[k - 3].to_radians()
            };
            a * (std::f64::consts::TAU * s / self.period[k] + k as f64).sin()
        })
    }

    /// The sway's pose at `t` in the carrier's frame.
    pub fn pose(&self, t: Time) -> Pose {
        let o = self.offsets(t).map(|v| v as f32);
        Pose::from_parts(
            Vec3::new(o[0], o[1], o[2]),
            Quat::from_euler(EulerRot::ZYX, o[5], o[4], o[3]),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each degree follows its own sine: at a quarter period past its phase's zero it peaks
    /// at its amplitude, and a zero amplitude leaves the degree still.
    #[test]
    fn each_degree_swings_at_its_amplitude_and_period() {
        let s = SwayConfig {
            xyz: [0.0, 0.02, 0.0],
            rpy_deg: [1.0, 0.0, 2.0],
            period: [1.0, 2.0, 1.0, 0.5, 1.0, 4.0],
        };
        s.validate(Path::new("s.toml"), "camera[0].sway").unwrap();
        // y: phase 1 rad, so the peak is where 2π t / 2 + 1 = π/2.
        let t = (std::f64::consts::FRAC_PI_2 - 1.0) * 2.0 / std::f64::consts::TAU;
        let t = t + 2.0; // a period later
        let o = s.offsets(Time::from_secs(t));
        assert!((o[1] - 0.02).abs() < 1e-6, "{o:?}");
        assert_eq!(o[0], 0.0);
        assert_eq!(o[2], 0.0);
        assert_eq!(o[4], 0.0);
        for k in [3, 5] {
            let a = s.rpy_deg[k - 3].to_radians();
            let mut most = 0f64;
            for i in 0..4000 {
                most = most.max(s.offsets(Time::from_secs(i as f64 * 0.001))[k].abs());
            }
            assert!(most <= a + 1e-12 && most > 0.99 * a, "degree {k}: {most}");
        }
        let p = s.pose(Time::from_secs(t));
        assert!((p.translation.y - 0.02).abs() < 1e-6);
    }

    #[test]
    fn absurd_sways_name_their_key() {
        let s = SwayConfig {
            xyz: [0.0; 3],
            rpy_deg: [0.0, 90.0, 0.0],
            period: [1.0; 6],
        };
        let e = s
            .validate(Path::new("s.toml"), "camera[0].sway")
            .unwrap_err();
        assert!(e.to_string().contains("camera[0].sway.rpy_deg[1]"), "{e}");
        let s = SwayConfig {
            rpy_deg: [0.0; 3],
            period: [1.0, 1.0, 0.0, 1.0, 1.0, 1.0],
            ..s
        };
        let e = s.validate(Path::new("s.toml"), "c").unwrap_err();
        assert!(e.to_string().contains("c.period[2]"), "{e}");
    }
}
