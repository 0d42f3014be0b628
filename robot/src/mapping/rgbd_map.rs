//! A 3D map from RGB-D keyframes (seed 000 §3.1): keyframes levelled by the floor, placed by
//! a registration method ([`crate::mapping::registration`]: the variants of the thesis's Fig. 3.7 and
//! a baseline) after the run, as the thesis does, and reduced to points and planes.
//!
//! A frame becomes a keyframe after the robot has travelled `keyframe_distance` or turned
//! `keyframe_turn` since the last one. Its depth pixels (every `stride`-th in each direction)
//! are back-projected in the camera's body frame, levelled by the floor found in them
//! ([`crate::perception::floor`]: height, pitch, roll), and moved to the robot's base frame by the
//! camera's mount; its colour image gives features ([`crate::perception::features`]). Frames without a
//! floor and pixels without valid depth are counted and skipped. [`RgbdMapper::build`] places
//! the keyframes and keeps one point per voxel (the first point of a voxel keeps its colour;
//! later ones add to its mean position).

use crate::mapping::polygons::{PolygonConfig, PolygonMap};
use crate::mapping::registration::{
    EnvironmentMap, Keyframe, Method, RegistrationConfig, RegistrationCounts, place, register,
};
use crate::perception::features::{Detector, grey};
use crate::perception::floor::{FloorConfig, Level, level, optical_to_body};
use crate::tracking::exclusion::Exclusion;
use futago_msgs::Pose2;
use futago_msgs::camera::{DepthImage, RgbImage, RgbdFrame};
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
    /// How keyframes are placed; every method listed builds its own map from the same
    /// keyframes, and the first is the run's map.
    pub methods: Vec<Method>,
    pub registration: RegistrationConfig,
    /// Put keyframes off while a tracked person is in view (seed 000 §5.4 pauses its data
    /// collection for people), taking the next frame without one.
    pub pause_for_people: bool,
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
            methods: vec![Method::Full],
            registration: RegistrationConfig::default(),
            pause_for_people: true,
        }
    }
}

impl RgbdMapConfig {
    /// Checks ranges; `Err((key, message))`.
    pub fn validate(&self) -> Result<(), (String, String)> {
        use crate::config::{check_counts, check_ranges};
        check_ranges(
            "",
            &[
                ("keyframe_distance", self.keyframe_distance, 0.0, 100.0),
                (
                    "keyframe_turn",
                    self.keyframe_turn,
                    0.0,
                    std::f64::consts::TAU,
                ),
                ("max_depth", self.max_depth, 0.01, 100.0),
                ("voxel", self.voxel, 1e-4, 10.0),
            ],
        )?;
        check_counts("", &[("stride", self.stride as usize, 1, 1000)])?;
        if self.methods.is_empty() {
            return Err(("methods".into(), "expected at least one method".into()));
        }
        for (i, m) in self.methods.iter().enumerate() {
            if self.methods[..i].contains(m) {
                return Err(("methods".into(), format!("{} is listed twice", m.name())));
            }
        }
        self.floor.validate("floor")?;
        self.polygons.validate("polygons")?;
        self.registration
            .validate()
            .map_err(|(k, m)| (format!("registration.{k}"), m))
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
    /// Image features with valid depth, over all keyframes.
    pub features: u64,
    /// Sampled points left out because they lay on a tracked person.
    pub excluded_points: u64,
}

struct Voxel {
    sum: [f64; 3],
    n: u32,
    colour: [u8; 3],
}

/// A map built by one method.
#[derive(Debug, Clone)]
pub struct RgbdMap {
    pub method: Method,
    /// Each keyframe's robot pose as placed.
    pub poses: Vec<Pose2>,
    /// One point per voxel (the mean of its points) and its colour, in the order the voxels
    /// were first filled.
    pub points: Vec<([f64; 3], [u8; 3])>,
    pub polygons: PolygonMap,
    pub registration: RegistrationCounts,
}

/// What a frame offered to [`RgbdMapper::offer_completing`] lacks for a keyframe: its colour
/// image where it was taken without, its whole depth where it holds the mapper's grid alone.
#[derive(Debug, Default)]
pub struct Completion {
    pub rgb: Option<RgbImage>,
    pub depth: Option<DepthImage>,
}

/// The keyframes and their logic.
pub struct RgbdMapper {
    config: RgbdMapConfig,
    mount: CameraMount,
    seed: u64,
    last: Option<Pose2>,
    counts: RgbdMapCounts,
    rng: ChaCha8Rng,
    detector: Detector,
    /// Each keyframe's levelling.
    levels: Vec<Level>,
    keyframes: Vec<Keyframe>,
}

impl RgbdMapper {
    pub fn new(config: RgbdMapConfig, mount: CameraMount, seed: u64) -> RgbdMapper {
        RgbdMapper {
            detector: Detector::new(config.registration.features, seed),
            config,
            mount,
            seed,
            last: None,
            counts: RgbdMapCounts::default(),
            rng: ChaCha8Rng::seed_from_u64(seed),
            levels: Vec::new(),
            keyframes: Vec::new(),
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
        self.offer_excluding(frame, pose, &Exclusion::default())
    }

    /// [`Self::offer`], leaving out the points (and features) that lie on the people of
    /// `people` (cylinders in the base frame at the frame's time).
    pub fn offer_excluding(&mut self, frame: &RgbdFrame, pose: &Pose2, people: &Exclusion) -> bool {
        self.offer_completing(frame, pose, people, Completion::default)
    }

    /// [`Self::offer_excluding`] for a frame that may have been taken without its colour
    /// image, or with its depth measured on the mapper's grid alone (every `stride`-th pixel
    /// of every `stride`-th row, what finding the floor reads): `complete` gives what the
    /// frame lacks, and is called only once the frame is to become a keyframe (its floor
    /// found), whose features are looked up anywhere in the depth. Most frames a mapper is
    /// offered are not taken: `office-rgbd`'s Kinect looked for the floor in 1,216 frames and
    /// found it in 177, each a 640 × 480 colour render and a 320 × 240 image's noise when the
    /// frames came whole.
    pub fn offer_completing(
        &mut self,
        frame: &RgbdFrame,
        pose: &Pose2,
        people: &Exclusion,
        complete: impl FnOnce() -> Completion,
    ) -> bool {
        self.counts.frames += 1;
        if !self.wants(pose) {
            return false;
        }
        let cfg = &self.config;
        let (k, d) = (&frame.depth_intrinsics, &frame.depth);
        let step = cfg.stride as usize;
        let (cols, rows) = (
            (d.width as usize).div_ceil(step),
            (d.height as usize).div_ceil(step),
        );
        // The sampled grid: each cell's point, if its depth is valid, and its pixel.
        let mut grid: Vec<Option<usize>> = vec![None; cols * rows];
        let mut sampled: Vec<([f64; 3], [u32; 2])> = Vec::new();
        for (r, v) in (0..d.height).step_by(step).enumerate() {
            for (c, u) in (0..d.width).step_by(step).enumerate() {
                let z = d.at(u, v) as f64;
                if !(z.is_finite() && z > 0.0 && z <= cfg.max_depth) {
                    self.counts.invalid_pixels += 1;
                    continue;
                }
                grid[r * cols + c] = Some(sampled.len());
                sampled.push((
                    optical_to_body(k.back_project(u as f64, v as f64, z)),
                    [u, v],
                ));
            }
        }
        let body: Vec<[f64; 3]> = sampled.iter().map(|p| p.0).collect();
        let Some(lv) = level(&body, &cfg.floor, &mut self.rng) else {
            self.counts.no_floor += 1;
            return false;
        };
        let completion = complete();
        let rgb = frame.rgb.as_ref().or(completion.rgb.as_ref());
        // The whole depth, for the features (the grid's pixels are the same in both).
        let whole = completion.depth.as_ref().unwrap_or(d);
        let pts: Vec<([f64; 3], [u8; 3])> = sampled
            .into_iter()
            .map(|(p, [u, v])| {
                let colour = rgb
                    .map(|rgb| {
                        // Registered images: the colour pixel under the same ray.
                        let cu = ((u as f64 + 0.5) * rgb.width as f64 / d.width as f64) as u32;
                        let cv = ((v as f64 + 0.5) * rgb.height as f64 / d.height as f64) as u32;
                        rgb.at(cu.min(rgb.width - 1), cv.min(rgb.height - 1))
                    })
                    .unwrap_or([200, 200, 200]);
                (p, colour)
            })
            .collect();
        let mount = Pose2::new(self.mount.x, self.mount.y, self.mount.yaw);
        let to_base = |p: [f64; 3]| place(&mount, lv.apply(p));
        // People are cut out: their cells lose their point (so the points beside them are on
        // the data's boundary, as beside any hole).
        let mut pts: Vec<([f64; 3], [u8; 3])> = pts.iter().map(|p| (to_base(p.0), p.1)).collect();
        if !people.is_empty() {
            let mut kept = Vec::with_capacity(pts.len());
            let mut index = vec![None; pts.len()];
            for (i, p) in pts.iter().enumerate() {
                if people.contains([p.0[0], p.0[1]]) {
                    self.counts.excluded_points += 1;
                } else {
                    index[i] = Some(kept.len());
                    kept.push(*p);
                }
            }
            for g in grid.iter_mut() {
                *g = g.and_then(|i| index[i]);
            }
            pts = kept;
        }
        // A point is on the data's boundary when a neighbouring cell has no depth.
        let mut boundary = vec![false; pts.len()];
        for r in 0..rows {
            for c in 0..cols {
                let Some(i) = grid[r * cols + c] else {
                    continue;
                };
                let has = |rr: isize, cc: isize| {
                    rr >= 0
                        && cc >= 0
                        && (rr as usize) < rows
                        && (cc as usize) < cols
                        && grid[rr as usize * cols + cc as usize].is_some()
                };
                let (ri, ci) = (r as isize, c as isize);
                boundary[i] =
                    !(has(ri - 1, ci) && has(ri + 1, ci) && has(ri, ci - 1) && has(ri, ci + 1));
            }
        }
        // Features: corners of the colour image with valid depth under them.
        let mut features = Vec::new();
        if let Some(rgb) = rgb {
            for ([cu, cv], desc) in self
                .detector
                .detect(&grey(rgb.width, rgb.height, &rgb.data))
            {
                let du = ((cu as f64 + 0.5) * d.width as f64 / rgb.width as f64) as u32;
                let dv = ((cv as f64 + 0.5) * d.height as f64 / rgb.height as f64) as u32;
                let z = whole.at(du.min(d.width - 1), dv.min(d.height - 1)) as f64;
                if z.is_finite() && z > 0.0 && z <= cfg.max_depth {
                    let base = to_base(optical_to_body(k.back_project(du as f64, dv as f64, z)));
                    if !people.contains([base[0], base[1]]) {
                        features.push((base, desc));
                    }
                }
            }
        }
        self.last = Some(*pose);
        self.counts.keyframes += 1;
        self.counts.points += pts.len() as u64;
        self.counts.features += features.len() as u64;
        self.levels.push(lv);
        self.keyframes.push(Keyframe {
            pose: *pose,
            points: pts.iter().map(|p| p.0).collect(),
            colours: pts.iter().map(|p| p.1).collect(),
            boundary,
            features,
        });
        true
    }

    /// Places the keyframes by `method` and builds the points and planes. `map`: the 2D map
    /// for the map term.
    pub fn build(&self, method: Method, map: Option<&EnvironmentMap>) -> RgbdMap {
        let (poses, registration) = register(
            &self.keyframes,
            method,
            map,
            &self.config.registration,
            self.seed,
        );
        let size = self.config.voxel;
        let mut voxels: FxHashMap<[i64; 3], Voxel> = FxHashMap::default();
        let mut order = Vec::new();
        let mut polygons = PolygonMap::new(self.config.polygons);
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        for (kf, pose) in self.keyframes.iter().zip(&poses) {
            let world: Vec<[f64; 3]> = kf.points.iter().map(|p| place(pose, *p)).collect();
            for (w, colour) in world.iter().zip(&kf.colours) {
                let key = w.map(|x| (x / size).floor() as i64);
                match voxels.get_mut(&key) {
                    Some(vx) => {
                        for (a, b) in vx.sum.iter_mut().zip(w) {
                            *a += b;
                        }
                        vx.n += 1;
                    }
                    None => {
                        voxels.insert(
                            key,
                            Voxel {
                                sum: *w,
                                n: 1,
                                colour: *colour,
                            },
                        );
                        order.push(key);
                    }
                }
            }
            polygons.add_frame(&world, &mut rng);
        }
        RgbdMap {
            method,
            poses,
            points: order
                .iter()
                .map(|k| {
                    let v = &voxels[k];
                    (v.sum.map(|s| s / v.n as f64), v.colour)
                })
                .collect(),
            polygons,
            registration,
        }
    }

    pub fn counts(&self) -> RgbdMapCounts {
        self.counts
    }

    /// The levelling found in each keyframe.
    pub fn levels(&self) -> &[Level] {
        &self.levels
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tracking::exclusion::ExclusionConfig;
    use futago_msgs::Time;
    use futago_msgs::camera::Intrinsics;

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
        RgbdFrame::depth_only(Time::ZERO, k, data)
    }

    /// A mapper's settings that use every pixel, and a camera 0.1 m ahead of the base.
    fn every_pixel() -> (RgbdMapConfig, CameraMount) {
        let cfg = RgbdMapConfig {
            stride: 1,
            ..Default::default()
        };
        let mount = CameraMount {
            x: 0.1,
            y: 0.0,
            yaw: 0.0,
        };
        (cfg, mount)
    }

    #[test]
    fn points_on_a_tracked_person_are_left_out() {
        let (cfg, mount) = every_pixel();
        let f = frame(2.0, 0.0);
        // The wall stands 2.1 m ahead of the base; a "person" 2.1 m ahead with a 0.5 m
        // cylinder covers the wall's middle metre and the floor within 0.5 m of its foot.
        let person = [2.1, 0.0];
        let cut = Exclusion::new(&ExclusionConfig::default(), vec![person]);
        let mut whole = RgbdMapper::new(cfg.clone(), mount, 1);
        let mut less = RgbdMapper::new(cfg, mount, 1);
        assert!(whole.offer(&f, &Pose2::IDENTITY));
        assert!(less.offer_excluding(&f, &Pose2::IDENTITY, &cut));
        let (all, kept) = (whole.counts().points, less.counts().points);
        assert_eq!(all, kept + less.counts().excluded_points);
        assert!(less.counts().excluded_points > 500, "{:?}", less.counts());
        for (p, _) in &less.build(Method::Pose, None).points {
            assert!((p[0] - person[0]).hypot(p[1] - person[1]) > 0.49, "{p:?}");
        }
    }

    #[test]
    fn points_land_on_the_floor_and_the_wall_in_the_world() {
        let (cfg, mount) = every_pixel();
        let mut m = RgbdMapper::new(cfg, mount, 1);
        // The robot at (2, 1) facing +y: the camera (0.1 m ahead) sees a wall 2 m ahead, at
        // world y = 1 + 0.1 + 2 = 3.1; a 3° nose-down pitch is levelled away.
        let pose = Pose2::new(2.0, 1.0, std::f64::consts::FRAC_PI_2);
        assert!(m.offer(&frame(2.0, 3f64.to_radians()), &pose));
        let pts = m.build(Method::Pose, None).points;
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
        let lv = m.levels()[0];
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

    /// A frame offered without its colour, or also with its depth on the mapper's grid alone,
    /// and completed on demand becomes the keyframe the whole frame becomes (the same points,
    /// colours and features; without the whole depth, features off the grid are lost), and a
    /// frame without a floor never asks for its completion.
    #[test]
    fn completion_on_demand_makes_the_keyframe_the_whole_frame_makes() {
        let (cfg, mount) = every_pixel();
        let depth_only = frame(2.0, 0.0);
        // A chequered colour image of twice the depth's size: corners for the features.
        let (w, h) = (320u32, 240u32);
        let data: Vec<u8> = (0..w * h)
            .flat_map(|i| {
                let (u, v) = (i % w, i / w);
                let c = if (u / 20 + v / 20) % 2 == 0 { 40 } else { 210 };
                [c, (u % 256) as u8, (v % 256) as u8]
            })
            .collect();
        let rgb = RgbImage {
            width: w,
            height: h,
            data,
        };
        let mut coloured = depth_only.clone();
        coloured.rgb = Some(rgb.clone());
        coloured.rgb_intrinsics =
            Intrinsics::from_fov(w, h, 57f64.to_radians(), 43f64.to_radians()).unwrap();
        let mut with = RgbdMapper::new(cfg.clone(), mount, 1);
        let mut on_demand = RgbdMapper::new(cfg, mount, 1);
        assert!(with.offer(&coloured, &Pose2::IDENTITY));
        // Offered on the mapper's grid alone (the other pixels 0, as a camera noising the
        // grid leaves them), given the whole depth and the colour on demand.
        let mut grid_only = depth_only.clone();
        for (i, z) in grid_only.depth.data.iter_mut().enumerate() {
            let (u, v) = (i % 160, i / 160);
            if u % 2 != 0 || v % 2 != 0 {
                *z = 0.0;
            }
        }
        let mut grid_mapper = RgbdMapper::new(
            RgbdMapConfig {
                stride: 2,
                ..RgbdMapConfig::default()
            },
            mount,
            1,
        );
        let mut whole_mapper = RgbdMapper::new(
            RgbdMapConfig {
                stride: 2,
                ..RgbdMapConfig::default()
            },
            mount,
            1,
        );
        assert!(whole_mapper.offer(&coloured, &Pose2::IDENTITY));
        let mut asked = 0;
        let none = Exclusion::default();
        assert!(
            grid_mapper.offer_completing(&grid_only, &Pose2::IDENTITY, &none, || {
                asked += 1;
                Completion {
                    rgb: Some(rgb.clone()),
                    depth: Some(depth_only.depth.clone()),
                }
            })
        );
        assert_eq!(asked, 1);
        let (a, b) = (&whole_mapper.keyframes[0], &grid_mapper.keyframes[0]);
        assert_eq!(a.points, b.points);
        assert_eq!(a.colours, b.colours);
        assert_eq!(a.features.len(), b.features.len());
        assert!(a.features.iter().zip(&b.features).all(|(x, y)| x.0 == y.0));
        // Without the whole depth, features on pixels off the grid find no depth.
        let mut short = RgbdMapper::new(
            RgbdMapConfig {
                stride: 2,
                ..RgbdMapConfig::default()
            },
            mount,
            1,
        );
        assert!(
            short.offer_completing(&grid_only, &Pose2::IDENTITY, &none, || Completion {
                rgb: Some(rgb.clone()),
                depth: None,
            })
        );
        assert!(short.keyframes[0].features.len() < a.features.len());
        // Colour alone on demand, every pixel's depth in the frame.
        let mut asked = 0;
        assert!(
            on_demand.offer_completing(&depth_only, &Pose2::IDENTITY, &none, || {
                asked += 1;
                Completion {
                    rgb: Some(rgb.clone()),
                    depth: None,
                }
            })
        );
        assert_eq!(asked, 1);
        let (a, b) = (&with.keyframes[0], &on_demand.keyframes[0]);
        assert_eq!(a.points, b.points);
        assert_eq!(a.colours, b.colours);
        assert!(a.colours.iter().any(|c| *c != [200, 200, 200]));
        assert!(!a.features.is_empty());
        assert_eq!(a.features.len(), b.features.len());
        // A wall filling the view has no floor: its colour is never asked for.
        let mut wall = frame(0.5, -0.3);
        wall.depth.data.iter_mut().for_each(|d| *d = 0.5);
        let far = Pose2::new(3.0, 0.0, 0.0);
        assert!(!on_demand.offer_completing(&wall, &far, &none, || panic!("completion asked")));
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
        assert!(m.build(Method::Full, None).points.is_empty());
    }
}
