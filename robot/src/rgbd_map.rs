//! A 3D map from RGB-D keyframes placed by the robot's 2D pose and the floor (seed 000 §3.1):
//! the first of the thesis's Fig. 3.7 variants, "robot pose only", on which the registration
//! variants build.
//!
//! A frame becomes a keyframe after the robot has travelled `keyframe_distance` or turned
//! `keyframe_turn` since the last one. Its depth pixels (every `stride`-th in each direction)
//! are back-projected in the camera's body frame, levelled by the floor found in them
//! ([`crate::floor`]: height, pitch, roll), turned by the robot's yaw plus the camera's
//! mounting yaw and moved to the camera's position on the robot. Frames without a floor and
//! pixels without valid depth are counted and skipped. Points are kept one per voxel (the
//! first point of a voxel keeps its colour; later ones add to its mean position).

use crate::floor::{FloorConfig, Level, level, optical_to_body};
use crate::polygons::{PolygonConfig, PolygonMap};
use futago_msgs::Pose2;
use futago_msgs::camera::RgbdFrame;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rustc_hash::FxHashMap;
use serde::{Deserialize, Serialize};

/// Parameters of the RGB-D map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RgbdMapConfig {
    /// Travel between keyframes, m (seed 000 logs frames at a fixed distance; its value is
    /// not stated, 0.5 m chosen here).
    pub keyframe_distance: f64,
    /// Turn between keyframes, rad.
    pub keyframe_turn: f64,
    /// Pixel step of the back-projection in each direction.
    pub stride: u32,
    /// Depths beyond this are left out, m.
    pub max_depth: f64,
    /// Voxel size of the map, m.
    pub voxel: f64,
    pub floor: FloorConfig,
    /// The polygon map built beside the points (seed 000 §3.2).
    pub polygons: PolygonConfig,
}

impl Default for RgbdMapConfig {
    fn default() -> Self {
        RgbdMapConfig {
            keyframe_distance: 0.5,
            keyframe_turn: 0.5,
            stride: 2,
            max_depth: 4.0,
            voxel: 0.01,
            floor: FloorConfig::default(),
            polygons: PolygonConfig::default(),
        }
    }
}

impl RgbdMapConfig {
    /// Checks ranges; `Err((key, message))`.
    pub fn validate(&self) -> Result<(), (String, String)> {
        let bad = |k: &str, m: String| Err((k.to_string(), m));
        if !(self.keyframe_distance.is_finite() && self.keyframe_distance >= 0.0) {
            return bad(
                "keyframe_distance",
                format!(
                    "expected a distance ≥ 0 m, found {}",
                    self.keyframe_distance
                ),
            );
        }
        if !(self.keyframe_turn.is_finite() && self.keyframe_turn >= 0.0) {
            return bad(
                "keyframe_turn",
                format!("expected an angle ≥ 0 rad, found {}", self.keyframe_turn),
            );
        }
        if self.stride == 0 {
            return bad("stride", "expected at least 1 pixel".into());
        }
        if !(self.max_depth.is_finite() && self.max_depth > 0.0) {
            return bad(
                "max_depth",
                format!("expected a positive depth, found {}", self.max_depth),
            );
        }
        if !(self.voxel.is_finite() && self.voxel >= 1e-4) {
            return bad(
                "voxel",
                format!("expected a voxel of at least 0.1 mm, found {}", self.voxel),
            );
        }
        Ok(())
    }
}

/// Where the camera sits on the robot, in the base frame: x, y and yaw; its height, pitch
/// and roll come from the floor in every frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraMount {
    pub x: f64,
    pub y: f64,
    pub yaw: f64,
}

/// Counts of what the mapper did with its input.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct RgbdMapCounts {
    pub frames: u64,
    pub keyframes: u64,
    /// Keyframe candidates without a floor, left out (the next frame is tried in their place,
    /// so a stretch without floor in view counts every frame of it).
    pub no_floor: u64,
    /// Sampled pixels without valid depth (0, NaN, infinite or beyond `max_depth`).
    pub invalid_pixels: u64,
    /// Points added to the map (before voxel merging).
    pub points: u64,
}

struct Voxel {
    sum: [f64; 3],
    n: u32,
    colour: [u8; 3],
}

/// The map and its keyframe logic.
pub struct RgbdMapper {
    config: RgbdMapConfig,
    mount: CameraMount,
    last: Option<Pose2>,
    voxels: FxHashMap<[i64; 3], Voxel>,
    /// Voxel keys in insertion order, so that the output is deterministic.
    order: Vec<[i64; 3]>,
    counts: RgbdMapCounts,
    rng: ChaCha8Rng,
    /// Each keyframe's robot pose and levelling.
    keyframes: Vec<(Pose2, Level)>,
    polygons: PolygonMap,
}

impl RgbdMapper {
    pub fn new(config: RgbdMapConfig, mount: CameraMount, seed: u64) -> RgbdMapper {
        RgbdMapper {
            config: config.clone(),
            mount,
            last: None,
            voxels: FxHashMap::default(),
            order: Vec::new(),
            counts: RgbdMapCounts::default(),
            rng: ChaCha8Rng::seed_from_u64(seed),
            keyframes: Vec::new(),
            polygons: PolygonMap::new(config.polygons),
        }
    }

    /// Whether a frame at `pose` would be a keyframe (so that callers can skip rendering).
    pub fn wants(&self, pose: &Pose2) -> bool {
        match &self.last {
            None => true,
            Some(l) => {
                l.distance(pose) >= self.config.keyframe_distance
                    || futago_msgs::wrap_angle(pose.theta - l.theta).abs()
                        >= self.config.keyframe_turn
            }
        }
    }

    /// Offers a frame taken with the robot at `pose` (its 2D estimate); returns whether it
    /// became a keyframe.
    pub fn offer(&mut self, frame: &RgbdFrame, pose: &Pose2) -> bool {
        self.counts.frames += 1;
        if !self.wants(pose) {
            return false;
        }
        let cfg = &self.config;
        let (k, d) = (&frame.depth_intrinsics, &frame.depth);
        let mut pts: Vec<([f64; 3], [u8; 3])> = Vec::new();
        for v in (0..d.height).step_by(cfg.stride as usize) {
            for u in (0..d.width).step_by(cfg.stride as usize) {
                let z = d.at(u, v) as f64;
                if !(z.is_finite() && z > 0.0 && z <= cfg.max_depth) {
                    self.counts.invalid_pixels += 1;
                    continue;
                }
                let colour = frame
                    .rgb
                    .as_ref()
                    .map(|rgb| {
                        // Registered images: the colour pixel under the same ray.
                        let cu = ((u as f64 + 0.5) * rgb.width as f64 / d.width as f64) as u32;
                        let cv = ((v as f64 + 0.5) * rgb.height as f64 / d.height as f64) as u32;
                        rgb.at(cu.min(rgb.width - 1), cv.min(rgb.height - 1))
                    })
                    .unwrap_or([200, 200, 200]);
                pts.push((
                    optical_to_body(k.back_project(u as f64, v as f64, z)),
                    colour,
                ));
            }
        }
        let body: Vec<[f64; 3]> = pts.iter().map(|p| p.0).collect();
        let Some(lv) = level(&body, &cfg.floor, &mut self.rng) else {
            self.counts.no_floor += 1;
            return false;
        };
        self.last = Some(*pose);
        self.counts.keyframes += 1;
        self.keyframes.push((*pose, lv));
        let cam = pose.compose(&Pose2::new(self.mount.x, self.mount.y, self.mount.yaw));
        let (s, c) = cam.theta.sin_cos();
        let size = cfg.voxel;
        let mut world = Vec::with_capacity(pts.len());
        for (p, colour) in pts {
            let q = lv.apply(p);
            let w = [
                cam.x + c * q[0] - s * q[1],
                cam.y + s * q[0] + c * q[1],
                q[2],
            ];
            let key = w.map(|x| (x / size).floor() as i64);
            world.push(w);
            self.counts.points += 1;
            match self.voxels.get_mut(&key) {
                Some(vx) => {
                    for (a, b) in vx.sum.iter_mut().zip(w) {
                        *a += b;
                    }
                    vx.n += 1;
                }
                None => {
                    self.voxels.insert(
                        key,
                        Voxel {
                            sum: w,
                            n: 1,
                            colour,
                        },
                    );
                    self.order.push(key);
                }
            }
        }
        self.polygons.add_frame(&world, &mut self.rng);
        true
    }

    /// The polygon map of the keyframes so far.
    pub fn polygons(&self) -> &PolygonMap {
        &self.polygons
    }

    /// The map's points (one per voxel, the mean of its points) and colours, in the order the
    /// voxels were first filled.
    pub fn points(&self) -> Vec<([f64; 3], [u8; 3])> {
        self.order
            .iter()
            .map(|k| {
                let v = &self.voxels[k];
                (v.sum.map(|s| s / v.n as f64), v.colour)
            })
            .collect()
    }

    pub fn counts(&self) -> RgbdMapCounts {
        self.counts
    }

    /// Each keyframe's robot pose and the levelling found in it.
    pub fn keyframes(&self) -> &[(Pose2, Level)] {
        &self.keyframes
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use futago_msgs::Time;
    use futago_msgs::camera::{DepthImage, Intrinsics};

    /// A level camera 0.4 m up, looking along its x axis at a wall `wall` m ahead over a flat
    /// floor: the depth image rendered by hand (ray-plane intersections).
    fn frame(wall: f64, pitch: f64) -> RgbdFrame {
        let k = Intrinsics::from_fov(160, 120, 57f64.to_radians(), 43f64.to_radians()).unwrap();
        let mut data = Vec::new();
        let (sp, cp) = pitch.sin_cos();
        for v in 0..k.height {
            for u in 0..k.width {
                let r = optical_to_body(k.ray(u as f64, v as f64));
                // Pitched nose down by `pitch`: world direction = Ry(pitch)·r.
                let w = [cp * r[0] + sp * r[2], r[1], -sp * r[0] + cp * r[2]];
                let t_wall = if w[0] > 1e-9 {
                    wall / w[0]
                } else {
                    f64::INFINITY
                };
                let t_floor = if w[2] < -1e-9 {
                    0.4 / -w[2]
                } else {
                    f64::INFINITY
                };
                let t = t_wall.min(t_floor);
                // Depth is the distance along the optical axis: the ray's body-x component.
                let z = t * r[0];
                // Every 17th pixel has no return.
                let bad = (u * 7 + v * 13) % 17 == 0;
                data.push(if bad {
                    0.0
                } else if u == 5 {
                    f32::NAN
                } else {
                    z as f32
                });
            }
        }
        RgbdFrame {
            stamp: Time::from_secs(0.0),
            rgb: None,
            rgb_intrinsics: k,
            depth: DepthImage {
                width: k.width,
                height: k.height,
                data,
            },
            depth_intrinsics: k,
        }
    }

    #[test]
    fn points_land_on_the_floor_and_the_wall_in_the_world() {
        let cfg = RgbdMapConfig {
            stride: 1,
            ..Default::default()
        };
        let mount = CameraMount {
            x: 0.1,
            y: 0.0,
            yaw: 0.0,
        };
        let mut m = RgbdMapper::new(cfg, mount, 1);
        // The robot at (2, 1) facing +y: the camera (0.1 m ahead) sees a wall 2 m ahead, at
        // world y = 1 + 0.1 + 2 = 3.1; a 3° nose-down pitch is levelled away.
        let pose = Pose2::new(2.0, 1.0, std::f64::consts::FRAC_PI_2);
        assert!(m.offer(&frame(2.0, 3f64.to_radians()), &pose));
        let pts = m.points();
        assert!(pts.len() > 3000, "{}", pts.len());
        let (mut floor, mut wall) = (0, 0);
        for (p, _) in &pts {
            if p[2].abs() < 0.005 {
                floor += 1;
            } else if (p[1] - 3.1).abs() < 0.005 {
                wall += 1;
                assert!(p[2] > -0.005 && p[2] < 3.0, "{p:?}");
            } else {
                panic!("a point off the floor and the wall: {p:?}");
            }
        }
        assert!(floor > 1000 && wall > 1000, "{floor} {wall}");
        let (_, lv) = m.keyframes()[0];
        // The wall's foot, within 1 cm of the floor, joins the floor's inliers and tilts the
        // refit a little (measured: 1.9 mm and 0.09°).
        assert!(
            (lv.height - 0.4).abs() < 3e-3 && (lv.pitch - 3f64.to_radians()).abs() < 3e-3,
            "{lv:?}"
        );
        let c = m.counts();
        assert!(c.invalid_pixels > 1000, "{c:?}");
        // The same pose again is no keyframe; half a metre on is.
        assert!(!m.offer(&frame(2.0, 0.0), &pose));
        assert!(m.offer(&frame(1.5, 0.0), &Pose2::new(2.0, 1.5, pose.theta)));
        assert_eq!(m.counts().keyframes, 2);
    }

    #[test]
    fn frames_without_floor_or_depth_are_counted_and_skipped() {
        let mut m = RgbdMapper::new(
            RgbdMapConfig::default(),
            CameraMount {
                x: 0.0,
                y: 0.0,
                yaw: 0.0,
            },
            2,
        );
        let mut f = frame(2.0, 0.0);
        f.depth.data.iter_mut().for_each(|d| *d = f32::NAN);
        assert!(!m.offer(&f, &Pose2::IDENTITY));
        // A wall filling the view: no floor.
        let mut f = frame(0.5, -0.3);
        f.depth.data.truncate(0);
        f.depth.data.resize((160 * 120) as usize, 0.5);
        assert!(!m.offer(&f, &Pose2::IDENTITY));
        let c = m.counts();
        assert_eq!((c.frames, c.keyframes, c.no_floor), (2, 0, 2));
        assert!(m.points().is_empty());
    }
}
