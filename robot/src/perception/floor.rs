//! Floor detection and camera levelling (seed 000 §3.1.1): the robot's 2D pose gives x, y and
//! yaw only, so each RGB-D frame finds the floor by RANSAC and takes the camera's height,
//! pitch and roll from it, so that the floor becomes horizontal.
//!
//! Points are in the camera's body frame (REP 103: x forward, y left, z up, origin at the
//! camera), with the camera nominally level; [`optical_to_body`] converts from the optical
//! frame of depth images. The thesis builds the levelling rotation from three point
//! correspondences; here it is computed in closed form from the floor's normal, which gives the
//! same rotation (the one with no yaw that turns the normal onto z).

use crate::geometry::plane::{Plane, RansacConfig, ransac};
use rand::Rng;
use serde::{Deserialize, Serialize};

/// A point of the optical frame (x right, y down, z forward) in the body frame (x forward,
/// y left, z up).
pub fn optical_to_body(p: [f64; 3]) -> [f64; 3] {
    [p[2], -p[0], -p[1]]
}

/// Parameters of the floor search.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FloorConfig {
    /// RANSAC on 1000 sampled points, 1000 hypotheses, 1 cm inliers (seed 000).
    pub ransac: RansacConfig,
    /// Largest angle between a floor hypothesis' normal and the camera's up axis, rad (the
    /// thesis's "roughly horizontal" test, threshold unstated; 20° chosen here).
    pub max_tilt: f64,
    /// Hypotheses above the camera are not the floor: the camera must be at least this high
    /// over the plane, m.
    pub min_height: f64,
}

impl FloorConfig {
    /// Checks every field; the error names the key below `prefix`.
    pub fn validate(&self, prefix: &str) -> Result<(), crate::config::ConfigError> {
        use crate::config::{below, check_ranges};
        self.ransac.validate(&below(prefix, "ransac"))?;
        check_ranges(
            prefix,
            &[
                ("max_tilt", self.max_tilt, 0.0, std::f64::consts::FRAC_PI_2),
                ("min_height", self.min_height, 0.0, 10.0),
            ],
        )
    }
}

impl Default for FloorConfig {
    fn default() -> Self {
        FloorConfig {
            ransac: RansacConfig::default(),
            max_tilt: 20f64.to_radians(),
            min_height: 0.05,
        }
    }
}

/// The camera's attitude and height from the floor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Level {
    /// Height of the camera over the floor, m.
    pub height: f64,
    /// Rotation about the body's y axis, rad (positive: nose down, REP 103).
    pub pitch: f64,
    /// Rotation about the body's x axis, rad.
    pub roll: f64,
    /// The floor, in the camera's body frame, its normal up.
    pub floor: Plane,
    /// Floor inliers among the frame's points.
    pub inliers: usize,
}

impl Level {
    /// The levelled frame of a body-frame point: `Ry(pitch) · Rx(roll) · p`, then lifted by
    /// the camera's height, so that the floor lies at z = 0.
    pub fn apply(&self, p: [f64; 3]) -> [f64; 3] {
        let (sr, cr) = self.roll.sin_cos();
        let (sp, cp) = self.pitch.sin_cos();
        // Rx(roll)
        let q = [p[0], cr * p[1] - sr * p[2], sr * p[1] + cr * p[2]];
        // Ry(pitch)
        [
            cp * q[0] + sp * q[2],
            q[1],
            -sp * q[0] + cp * q[2] + self.height,
        ]
    }
}

/// Finds the floor in a frame's points (body frame) and the camera's height, pitch and roll;
/// `None` when no roughly horizontal plane below the camera gathers enough points (the frame
/// is then left out, as in the thesis).
pub fn level(points: &[[f64; 3]], config: &FloorConfig, rng: &mut impl Rng) -> Option<Level> {
    let cos_max = config.max_tilt.cos();
    let below = |p: &Plane| {
        let up = p.facing([0.0, 0.0, 1.0]);
        // The camera (the origin) lies on the normal's side, at least min_height away.
        up.normal[2] >= cos_max && up.offset >= config.min_height
    };
    let found = ransac(points, &config.ransac, below, rng)?;
    let floor = found.plane.facing([0.0, 0.0, 1.0]);
    let [nx, ny, nz] = floor.normal;
    // Rx(roll) turns n into the x–z plane; Ry(pitch) then onto z.
    let roll = ny.atan2(nz);
    let pitch = (-nx).atan2(ny.hypot(nz));
    Some(Level {
        height: floor.offset,
        pitch,
        roll,
        floor,
        inliers: found.inliers.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    /// A camera 0.42 m over the floor, pitched and rolled by hand: the floor points it sees,
    /// and a wall 2 m ahead, in its body frame.
    fn view(pitch: f64, roll: f64, rng: &mut ChaCha8Rng) -> Vec<[f64; 3]> {
        // World points relative to the camera, then into the tilted body frame by the inverse
        // of Ry(pitch)·Rx(roll).
        let (sr, cr) = roll.sin_cos();
        let (sp, cp) = pitch.sin_cos();
        let to_body = |w: [f64; 3]| {
            // Ry(-pitch)
            let q = [cp * w[0] - sp * w[2], w[1], sp * w[0] + cp * w[2]];
            // Rx(-roll)
            [q[0], cr * q[1] + sr * q[2], -sr * q[1] + cr * q[2]]
        };
        let mut pts = Vec::new();
        for _ in 0..3000 {
            pts.push(to_body([
                rng.random_range(0.8..3.0),
                rng.random_range(-1.0..1.0),
                -0.42,
            ]));
        }
        for _ in 0..3000 {
            pts.push(to_body([
                2.0,
                rng.random_range(-1.0..1.0),
                rng.random_range(-0.42..1.5),
            ]));
        }
        pts
    }

    #[test]
    fn levelling_recovers_height_pitch_and_roll() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for (pitch, roll) in [(0.0, 0.0), (0.08, 0.0), (0.0, -0.05), (-0.06, 0.04)] {
            let pts = view(pitch, roll, &mut rng);
            let l = level(&pts, &FloorConfig::default(), &mut rng).unwrap();
            // Wall points within 1 cm of the floor join its inliers and bias the refit a
            // little (measured: 1e-5).
            assert!((l.height - 0.42).abs() < 1e-4, "{l:?}");
            assert!((l.pitch - pitch).abs() < 1e-4, "{pitch}: {l:?}");
            assert!((l.roll - roll).abs() < 1e-4, "{roll}: {l:?}");
            // Levelled, the floor is at z = 0 and the wall stands at x = 2.
            let floor = l.apply(pts[0]);
            assert!(floor[2].abs() < 1e-3, "{floor:?}");
            let wall = l.apply(pts[3000]);
            assert!((wall[0] - 2.0).abs() < 1e-3, "{wall:?}");
        }
    }

    #[test]
    fn frames_without_a_floor_are_refused() {
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        let pts = view(0.0, 0.0, &mut rng);
        // The wall alone: no horizontal plane.
        assert!(level(&pts[3000..], &FloorConfig::default(), &mut rng).is_none());
        // A ceiling above the camera is not a floor.
        let ceiling: Vec<[f64; 3]> = pts[..3000].iter().map(|p| [p[0], p[1], 2.0]).collect();
        assert!(level(&ceiling, &FloorConfig::default(), &mut rng).is_none());
        assert_eq!(optical_to_body([1.0, 2.0, 3.0]), [3.0, -1.0, -2.0]);
    }
}
