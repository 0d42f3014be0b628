//! 2D laser range finders, simulated by casting one parry ray per beam into the rapier world.
//!
//! A scanner sweeps its beams in sequence: beam `i` of a scan is cast at the physics step that
//! contains its time `stamp + i·time_increment`, from where the laser was at that time (its pose
//! interpolated between the steps either side), so a moving robot's scans show the same motion
//! distortion as a real scanner's, and no more (switch it off with `sweep = false`: the whole
//! scan is then cast from where the laser was at the stamp). Casting from the step's pose
//! instead put each beam up to one step late: on a turntable at 30°/s with the physics at
//! 200 Hz, 0.15° of yaw, opposite for the two directions of turn. Ranges get Gaussian noise of
//! standard deviation `max(sigma, sigma_rel·r)`; a beam returns nothing beyond `range_max`,
//! below `range_min` (reported −∞), or with probability `dropout`.

use crate::beam::{BeamErrors, Reading};
use crate::config::{SpecError, check_mount, check_name, check_range, mount_pose};
use futago_msgs::{Duration, LaserScan, Time};
use glam::Vec3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rapier3d::math::Pose;
use serde::Deserialize;
use std::path::Path;

/// Known scanner models.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, serde::Serialize)]
pub enum LidarPreset {
    /// Hokuyo URG-04LX: 682 beams of 360°/1024 (239.8°), 0.02–5.6 m, 10 Hz (SCIP 2.0 spec;
    /// reference §4.1). Noise: ±10 mm below 1 m, ±1 % beyond, taken as 1σ.
    #[serde(rename = "urg-04lx")]
    Urg04lx,
    /// Hokuyo UTM-30LX: 1081 beams of 0.25° (270°), 0.1–30 m, 40 Hz (reference §4.2). Noise:
    /// ±30 mm taken as 1σ, growing to ±50 mm at 30 m.
    #[serde(rename = "utm-30lx")]
    Utm30lx,
    /// SICK LMS200: 361 beams of 0.5° (180°), 8 m (its millimetre mode), 37.5 Hz (two
    /// interlaced 75 Hz sweeps). Noise: the datasheet's typical ±15 mm as 1σ.
    #[serde(rename = "lms200")]
    Lms200,
    /// Seed 000's scanner: 240° and 30 m (seed-000 §2.2.2). Its model, resolution and rate are
    /// not stated; this preset takes the UTM-30LX's 0.25°, 40 Hz and noise, with which it
    /// shares the 30 m range: 961 beams.
    #[serde(rename = "seed000")]
    Seed000,
}

/// What a laser beam hit: the truth behind a range, for scorers (the stack never sees it).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BeamHit {
    /// Nothing within range, or no return (dropout, or noise past the range).
    Nothing,
    /// The world's fixed geometry or one of its objects.
    Static,
    /// An agent (a carrier on a scripted path), by its index in the scenario.
    Agent(u32),
    /// A person's body, by their slot in the crowd.
    Person(u32),
}

impl BeamHit {
    /// Whether the beam hit something that moves by itself (an agent or a person).
    pub fn is_mover(self) -> bool {
        matches!(self, BeamHit::Agent(_) | BeamHit::Person(_))
    }
}

/// Resolved scanner parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct LidarSpec {
    pub beams: usize,
    /// Angle between beams, rad.
    pub angle_increment: f64,
    pub range_min: f64,
    pub range_max: f64,
    /// Scans per second.
    pub rate: f64,
    /// Time between beams, s: the mirror's period over its steps per turn.
    pub time_increment: f64,
    pub sigma: f64,
    pub sigma_rel: f64,
}

impl LidarPreset {
    /// The name scenario files use.
    pub fn name(self) -> &'static str {
        match self {
            LidarPreset::Urg04lx => "urg-04lx",
            LidarPreset::Utm30lx => "utm-30lx",
            LidarPreset::Lms200 => "lms200",
            LidarPreset::Seed000 => "seed000",
        }
    }

    /// The angle between the preset's beams as its data sheet gives it, degrees.
    fn increment_deg(self) -> f64 {
        match self {
            LidarPreset::Urg04lx => 360.0 / 1024.0,
            LidarPreset::Utm30lx | LidarPreset::Seed000 => 0.25,
            LidarPreset::Lms200 => 0.5,
        }
    }

    /// The preset's field of view (first beam to last), degrees, computed in degrees so that
    /// it prints as declared (240, not 239.99999999999997).
    pub fn fov_deg(self) -> f64 {
        self.increment_deg() * (self.spec().beams - 1) as f64
    }

    /// The preset's parameters.
    pub fn spec(self) -> LidarSpec {
        let deg = std::f64::consts::PI / 180.0;
        let angle_increment = self.increment_deg() * deg;
        match self {
            LidarPreset::Urg04lx => LidarSpec {
                beams: 682,
                angle_increment,
                range_min: 0.02,
                range_max: 5.6,
                rate: 10.0,
                time_increment: 0.1 / 1024.0,
                sigma: 0.01,
                sigma_rel: 0.01,
            },
            LidarPreset::Utm30lx => LidarSpec {
                beams: 1081,
                angle_increment,
                range_min: 0.1,
                range_max: 30.0,
                rate: 40.0,
                time_increment: 0.025 / 1440.0,
                sigma: 0.03,
                sigma_rel: 0.05 / 30.0,
            },
            LidarPreset::Lms200 => LidarSpec {
                beams: 361,
                angle_increment,
                range_min: 0.01,
                range_max: 8.0,
                rate: 37.5,
                time_increment: 1.0 / 75.0 / 720.0,
                sigma: 0.015,
                sigma_rel: 0.0,
            },
            LidarPreset::Seed000 => LidarSpec {
                beams: 961,
                angle_increment,
                range_min: 0.02,
                range_max: 30.0,
                rate: 40.0,
                time_increment: 0.025 / 1440.0,
                sigma: 0.03,
                sigma_rel: 0.05 / 30.0,
            },
        }
    }
}

/// A laser scanner as a scenario configures it: a preset, its mounting and overrides.
#[derive(Debug, Clone, Deserialize, serde::Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct LidarConfig {
    /// Name of the laser (its frame and output channel).
    #[serde(default = "default_name")]
    pub name: String,
    pub preset: LidarPreset,
    /// Mounting position on the robot base frame (x forward, y left, z up from the floor), m.
    #[serde(default = "default_mount")]
    pub xyz: [f64; 3],
    /// Mounting roll, pitch, yaw, degrees.
    #[serde(default)]
    pub rpy_deg: [f64; 3],
    pub beams: Option<usize>,
    /// Overrides the field of view (first to last beam), degrees; with `beams`, sets the
    /// angular step.
    pub fov_deg: Option<f64>,
    pub range_min: Option<f64>,
    pub range_max: Option<f64>,
    pub rate: Option<f64>,
    pub sigma: Option<f64>,
    pub sigma_rel: Option<f64>,
    /// Probability that a beam returns nothing.
    #[serde(default)]
    pub dropout: f64,
    /// Cast each beam at its own time (true) or the whole scan at once (false).
    #[serde(default = "yes")]
    pub sweep: bool,
    /// The joint (`[[joint]]` name) the laser rides on; none: fixed to the base. `xyz` and
    /// `rpy_deg` are then its mount at the joint's zero angle.
    #[serde(default)]
    pub joint: Option<String>,
    /// Short, random and lost readings and mixed pixels (see [`crate::beam`]); none by
    /// default.
    #[serde(default)]
    pub errors: BeamErrors,
}

fn default_name() -> String {
    "front".into()
}

fn default_mount() -> [f64; 3] {
    [0.0, 0.0, 0.2]
}

fn yes() -> bool {
    true
}

impl LidarConfig {
    /// The mount seen from above: x, y and yaw on the robot, as 2D scan matching and the
    /// CARMEN log take it.
    pub fn planar_mount(&self) -> futago_msgs::Pose2 {
        futago_msgs::Pose2::new(self.xyz[0], self.xyz[1], self.rpy_deg[2].to_radians())
    }

    /// A config of a preset with default mounting.
    pub fn preset(preset: LidarPreset) -> LidarConfig {
        LidarConfig {
            name: default_name(),
            preset,
            xyz: default_mount(),
            rpy_deg: [0.0; 3],
            beams: None,
            fov_deg: None,
            range_min: None,
            range_max: None,
            rate: None,
            sigma: None,
            sigma_rel: None,
            dropout: 0.0,
            sweep: true,
            joint: None,
            errors: BeamErrors::default(),
        }
    }

    /// The preset with the overrides applied, checked; `key` locates this table in `file`.
    pub fn resolve(&self, file: &Path, key: &str) -> Result<LidarSpec, SpecError> {
        let k = |s: &str| format!("{key}.{s}");
        let mut s = self.preset.spec();
        let fov = self
            .fov_deg
            .map(f64::to_radians)
            .unwrap_or(s.angle_increment * (s.beams - 1) as f64);
        if let Some(b) = self.beams {
            if !(2..=100_000).contains(&b) {
                return Err(SpecError::new(
                    file,
                    k("beams"),
                    format!("expected 2 to 100000 beams, found {b}"),
                ));
            }
            s.beams = b;
        }
        if let Some(f) = self.fov_deg {
            check_range(file, &k("fov_deg"), f, 0.1, 360.0, "degrees")?;
        }
        s.angle_increment = fov / (s.beams - 1) as f64;
        if let Some(v) = self.range_min {
            s.range_min = v;
        }
        if let Some(v) = self.range_max {
            s.range_max = v;
        }
        check_range(file, &k("range_min"), s.range_min, 0.0, 1000.0, "m")?;
        check_range(
            file,
            &k("range_max"),
            s.range_max,
            s.range_min.max(1e-3),
            1000.0,
            "m (above range_min)",
        )?;
        if let Some(v) = self.rate {
            check_range(file, &k("rate"), v, 0.1, 1000.0, "Hz")?;
            s.time_increment *= s.rate / v;
            s.rate = v;
        }
        if s.time_increment * s.beams as f64 > 1.0 / s.rate {
            s.time_increment = 1.0 / s.rate / s.beams as f64;
        }
        if let Some(v) = self.sigma {
            check_range(file, &k("sigma"), v, 0.0, 10.0, "m")?;
            s.sigma = v;
        }
        if let Some(v) = self.sigma_rel {
            check_range(file, &k("sigma_rel"), v, 0.0, 1.0, "")?;
            s.sigma_rel = v;
        }
        check_range(
            file,
            &k("dropout"),
            self.dropout,
            0.0,
            1.0,
            "(a probability)",
        )?;
        check_mount(file, key, self.xyz, self.rpy_deg)?;
        check_name(file, &k("name"), &self.name)?;
        self.errors.validate(file, &k("errors"))?;
        Ok(s)
    }

    /// Mounting pose in the robot base frame.
    pub fn mount(&self) -> Pose {
        mount_pose(self.xyz, self.rpy_deg)
    }
}

/// A running scanner: its schedule and the scan in progress.
#[derive(Debug, Clone)]
pub struct Lidar {
    pub name: String,
    pub spec: LidarSpec,
    pub mount: Pose,
    dropout: f64,
    errors: BeamErrors,
    sweep: bool,
    rng: ChaCha8Rng,
    /// Index of the next scan to start.
    next_scan: i64,
    scan: Option<LaserScan>,
    /// What each beam of the scan in progress hit.
    hits: Vec<BeamHit>,
    /// The true range of each beam's surface in the scan in progress, kept for mixed pixels
    /// only.
    surfaces: Vec<Option<f64>>,
    /// Unit beam directions in the laser frame.
    directions: Vec<Vec3>,
    /// The origin and direction of each beam due in this update (reused).
    rays: Vec<(Vec3, Vec3)>,
    /// The time and laser pose of the previous update, to interpolate each beam's pose from;
    /// none before the first and after a jump ([`Lidar::forget_motion`]).
    last: Option<(Time, Pose)>,
}

impl Lidar {
    pub fn new(config: &LidarConfig, spec: LidarSpec, rng: ChaCha8Rng) -> Lidar {
        let angle_min = -spec.angle_increment * (spec.beams - 1) as f64 / 2.0;
        let directions = (0..spec.beams)
            .map(|i| {
                let a = angle_min + i as f64 * spec.angle_increment;
                Vec3::new(a.cos() as f32, a.sin() as f32, 0.0)
            })
            .collect();
        Lidar {
            name: config.name.clone(),
            mount: config.mount(),
            dropout: config.dropout,
            errors: config.errors.clone(),
            sweep: config.sweep,
            rng,
            next_scan: 0,
            scan: None,
            hits: Vec::new(),
            surfaces: Vec::new(),
            directions,
            rays: Vec::new(),
            spec,
            last: None,
        }
    }

    /// The laser jumped (the robot was put down elsewhere): the next scans' beams are cast
    /// from the pose given, not from poses between the last one and it.
    pub fn forget_motion(&mut self) {
        self.last = None;
    }

    /// Start time of scan `k`.
    fn scan_time(&self, k: i64) -> Time {
        Time((k as f64 * 1e9 / self.spec.rate).round() as i64)
    }

    /// Called after every physics step at time `now` with the laser's world pose: casts the
    /// beams that fall due (with `cast(origin, direction, max_range)` returning the distance to
    /// the first hit and what was hit) and returns a scan when its last beam is done, with
    /// what each beam hit (truth for scorers: a beam that returned nothing, by dropout or
    /// noise past the range, hit [`BeamHit::Nothing`]).
    ///
    /// A scan falling due is made only if `wanted(stamp)` says so; one nobody wants is
    /// skipped whole, its rays never cast, but its noise is still drawn: the stream stays
    /// where every scan made would have left it, so which scans are made changes none of the
    /// readings of the others (a recorder that takes every scan leaves what a localiser that
    /// takes one in ten sees as it was, and a run's bytes do not hang on who reads the
    /// laser). A laser with beam errors on (`errors`) draws according to what each beam hits,
    /// so its scans are all made.
    ///
    /// `laser_pose` is where the laser is at `now`; a beam due earlier is cast from its pose
    /// interpolated between this and the previous call's (translation linearly, rotation by
    /// slerp), which is exact for a laser turning or moving at a steady rate within a step.
    pub fn update(
        &mut self,
        now: Time,
        laser_pose: &Pose,
        wanted: impl FnOnce(Time) -> bool,
        cast: impl FnMut(Vec3, Vec3, f32) -> Option<(f32, BeamHit)>,
    ) -> Option<(LaserScan, Vec<BeamHit>)> {
        let last = self.last.replace((now, *laser_pose));
        let from = last.filter(|(t, _)| *t < now);
        let pose_at = |t: Time| match from {
            Some((t0, p0)) if t < now => {
                let f = ((t - t0).secs() / (now - t0).secs()).clamp(0.0, 1.0);
                p0.lerp(laser_pose, f as f32)
            }
            _ => *laser_pose,
        };
        self.cast_due(now, pose_at, wanted, cast)
    }

    /// [`Lidar::update`]'s work, with each beam's pose given by its time.
    fn cast_due(
        &mut self,
        now: Time,
        pose_at: impl Fn(Time) -> Pose,
        wanted: impl FnOnce(Time) -> bool,
        mut cast: impl FnMut(Vec3, Vec3, f32) -> Option<(f32, BeamHit)>,
    ) -> Option<(LaserScan, Vec<BeamHit>)> {
        if self.scan.is_none() {
            let start = self.scan_time(self.next_scan);
            if now < start {
                return None;
            }
            self.next_scan += 1;
            if !wanted(start) && self.errors.is_off() {
                // The draws each beam makes below, whatever it hits.
                for _ in 0..self.spec.beams {
                    let _: f64 = StandardNormal.sample(&mut self.rng);
                    let _: f64 = self.rng.random();
                }
                return None;
            }
            let angle_min = -self.spec.angle_increment * (self.spec.beams - 1) as f64 / 2.0;
            self.scan = Some(LaserScan {
                frame: self.name.clone(),
                stamp: start,
                angle_min,
                angle_increment: self.spec.angle_increment,
                time_increment: if self.sweep {
                    self.spec.time_increment
                } else {
                    0.0
                },
                range_min: self.spec.range_min,
                range_max: self.spec.range_max,
                ranges: Vec::with_capacity(self.spec.beams),
            });
        }
        let scan = self.scan.as_mut().expect("a scan is in progress");
        let elapsed = (now - scan.stamp).secs();
        let due = if self.sweep && self.spec.time_increment > 0.0 {
            ((elapsed / self.spec.time_increment).floor() as usize + 1).min(self.spec.beams)
        } else {
            self.spec.beams
        };
        let max = self.spec.range_max as f32;
        // Where each beam due starts and points, all before any is cast: each beam's
        // interpolation is a chain of a division, a square root and another division that
        // the processor overlaps with the next beam's only when no ray cast stands between
        // them (`Lidar::update` was 18 % of `office-tour`, mostly waiting on that chain;
        // its simulation time 1.82 → 1.70 s).
        let first = scan.ranges.len();
        self.rays.clear();
        self.rays.extend((first..due).map(|i| {
            let at = scan.stamp + Duration::from_secs(i as f64 * scan.time_increment);
            let pose = pose_at(at);
            (pose.translation, pose.rotation * self.directions[i])
        }));
        for k in 0..self.rays.len() {
            let (origin, dir) = self.rays[k];
            let hit = cast(origin, dir, max);
            // Draw the same random numbers whatever the beam hits, so streams stay aligned.
            let n: f64 = StandardNormal.sample(&mut self.rng);
            let drop = self.rng.random::<f64>() < self.dropout;
            let what = match hit {
                Some((_, w)) if !drop => w,
                _ => BeamHit::Nothing,
            };
            let surface = hit.map(|h| h.0 as f64);
            if self.errors.mixed_pixels > 0.0 {
                self.surfaces.push(surface);
            }
            let reading = if drop {
                Reading::Lost
            } else {
                let noisy = surface
                    .map(|d| d + n * self.errors.sigma(self.spec.sigma, self.spec.sigma_rel, d));
                if self.errors.is_off() {
                    Reading::Surface(noisy)
                } else {
                    self.errors.apply(
                        surface,
                        noisy,
                        self.spec.range_min,
                        self.spec.range_max,
                        &mut self.rng,
                    )
                }
            };
            let r = match reading {
                Reading::Lost | Reading::Surface(None) => f32::INFINITY,
                Reading::Surface(Some(v)) | Reading::Phantom(v) => {
                    if v > self.spec.range_max {
                        f32::INFINITY
                    } else if v < self.spec.range_min {
                        f32::NEG_INFINITY
                    } else {
                        v as f32
                    }
                }
            };
            scan.ranges.push(r);
            // A phantom reading (short or random) hit nothing the world holds.
            let phantom = matches!(reading, Reading::Phantom(_));
            self.hits.push(if r.is_finite() && !phantom {
                what
            } else {
                BeamHit::Nothing
            });
        }
        if scan.ranges.len() == self.spec.beams {
            let surfaces = std::mem::take(&mut self.surfaces);
            self.errors
                .mix_edges(&surfaces, &mut scan.ranges, &mut self.rng);
            let hits = std::mem::replace(&mut self.hits, Vec::with_capacity(self.spec.beams));
            self.scan.take().map(|s| (s, hits))
        } else {
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::noise::stream;
    use glam::Quat;

    #[test]
    fn presets_match_their_datasheets() {
        let u = LidarPreset::Urg04lx.spec();
        let fov = u.angle_increment * (u.beams - 1) as f64;
        assert!(
            (fov.to_degrees() - 239.4).abs() < 0.1,
            "{}",
            fov.to_degrees()
        );
        let t = LidarPreset::Utm30lx.spec();
        assert!(((t.angle_increment * 1080.0).to_degrees() - 270.0).abs() < 1e-9);
        let s = LidarPreset::Seed000.spec();
        assert!(((s.angle_increment * 960.0).to_degrees() - 240.0).abs() < 1e-9);
        assert_eq!(s.range_max, 30.0);
        for p in [
            LidarPreset::Urg04lx,
            LidarPreset::Utm30lx,
            LidarPreset::Lms200,
            LidarPreset::Seed000,
        ] {
            let s = p.spec();
            assert!(
                s.time_increment * s.beams as f64 <= 1.0 / s.rate,
                "{p:?} sweep fits its period"
            );
        }
    }

    #[test]
    fn overrides_are_checked() {
        let mut c = LidarConfig::preset(LidarPreset::Urg04lx);
        c.range_max = Some(-1.0);
        let e = c.resolve(Path::new("s.toml"), "lidar[0]").unwrap_err();
        assert_eq!(e.key, "lidar[0].range_max");
        c.range_max = None;
        c.beams = Some(181);
        c.fov_deg = Some(180.0);
        let s = c.resolve(Path::new("s.toml"), "lidar[0]").unwrap();
        assert!((s.angle_increment.to_degrees() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn sweep_casts_beams_as_they_fall_due() {
        let cfg = LidarConfig::preset(LidarPreset::Urg04lx);
        let spec = cfg.resolve(Path::new("x"), "l").unwrap();
        let mut l = Lidar::new(&cfg, spec.clone(), stream(0, "x"));
        let pose = Pose::IDENTITY;
        let casts = std::cell::Cell::new(0);
        let cast = |_: Vec3, _: Vec3, _: f32| {
            casts.set(casts.get() + 1);
            Some((1.0, BeamHit::Static))
        };
        assert!(
            l.update(Time::from_secs(0.0), &pose, |_| true, cast)
                .is_none()
        );
        let mut t = 0.0;
        let scan = loop {
            t += 0.005;
            if let Some((s, hits)) = l.update(Time::from_secs(t), &pose, |_| true, cast) {
                assert_eq!(hits.len(), s.ranges.len());
                assert!(hits.iter().all(|h| *h == BeamHit::Static));
                break s;
            }
        };
        // 682 beams at 97.7 µs take 66.6 ms: the scan completes at the 5 ms step after that.
        assert!((t - 0.07).abs() < 1e-9, "{t}");
        assert_eq!(scan.ranges.len(), 682);
        assert_eq!(casts.get(), 682);
        assert!(scan.ranges.iter().all(|r| (r - 1.0).abs() < 0.06));
        assert_eq!(scan.stamp, Time::ZERO);
        // The next scan starts at 0.1 s.
        assert!(
            l.update(Time::from_secs(0.095), &pose, |_| true, cast)
                .is_none()
        );
    }

    /// A laser turning about z at 30°/s, updated at 200 Hz: every beam is cast in the direction
    /// the laser faced at the beam's own time (stamp + i·time_increment), not at the step that
    /// cast it (up to 5 ms, 0.15°, later); after a jump the first beams are cast from where
    /// the laser now is.
    #[test]
    fn beams_are_cast_from_where_the_laser_was_at_their_time() {
        let cfg = LidarConfig::preset(LidarPreset::Lms200);
        let spec = cfg.resolve(Path::new("x"), "l").unwrap();
        let mut l = Lidar::new(&cfg, spec.clone(), stream(0, "x"));
        let rate = 30f64.to_radians();
        // Between two unit vectors, precise when small (f32's acos is not).
        let angle = |a: Vec3, b: Vec3| (a.cross(b).length() as f64).atan2(a.dot(b) as f64);
        let facing =
            |t: f64| Pose::from_parts(Vec3::ZERO, Quat::from_rotation_z((rate * t) as f32));
        let cast_dirs = std::cell::RefCell::new(Vec::new());
        let cast = |_: Vec3, d: Vec3, _: f32| {
            cast_dirs.borrow_mut().push(d);
            Some((1.0, BeamHit::Static))
        };
        // From the second scan on (stamp 1/37.5 s = 26.7 ms, between two steps).
        let mut t = 0.0;
        let scan = loop {
            if let Some((s, _)) = l.update(Time::from_secs(t), &facing(t), |_| true, cast)
                && s.stamp > Time::ZERO
            {
                break s;
            }
            t += 0.005;
        };
        let dirs = cast_dirs.borrow();
        let first = dirs.len() - spec.beams;
        let worst = (0..spec.beams)
            .map(|i| {
                let at = scan.stamp.secs() + i as f64 * scan.time_increment;
                let want = facing(at).rotation * l.directions[i];
                angle(want, dirs[first + i])
            })
            .fold(0.0, f64::max);
        assert!(worst < 1e-3f64.to_radians(), "{}°", worst.to_degrees());
        // Put down elsewhere, half a turn round: no beam between the two.
        drop(dirs);
        l.forget_motion();
        cast_dirs.borrow_mut().clear();
        let turned = Pose::from_parts(Vec3::ZERO, Quat::from_rotation_z(std::f32::consts::PI));
        let next = scan.stamp.secs() + 1.0 / spec.rate;
        l.update(Time::from_secs(next + 0.004), &turned, |_| true, cast);
        let dirs = cast_dirs.borrow();
        assert!(!dirs.is_empty());
        for (i, d) in dirs.iter().enumerate() {
            let want = turned.rotation * l.directions[i];
            assert!(angle(want, *d) < 1e-5, "beam {i}");
        }
    }

    #[test]
    fn beam_errors_reach_the_scans_and_their_truth() {
        // Every beam's surface lies at 1 m, in a bin where nothing returns, but for mixed
        // pixels and phantoms, which are off: every reading is lost and hit nothing.
        let mut cfg = LidarConfig::preset(LidarPreset::Urg04lx);
        cfg.sweep = false;
        cfg.errors.no_return_by_range = vec![crate::beam::RangeProbability {
            lo: 0.5,
            hi: 2.0,
            p: 1.0,
        }];
        let spec = cfg.resolve(Path::new("x"), "l").unwrap();
        let mut l = Lidar::new(&cfg, spec, stream(0, "x"));
        let (scan, hits) = l
            .update(
                Time::ZERO,
                &Pose::IDENTITY,
                |_| true,
                |_, _, _| Some((1.0, BeamHit::Static)),
            )
            .expect("an instant scan");
        assert!(scan.ranges.iter().all(|r| *r == f32::INFINITY));
        assert!(hits.iter().all(|h| *h == BeamHit::Nothing));
        // Random readings alone: finite, anywhere in range, and hitting nothing the world
        // holds.
        cfg.errors.no_return_by_range.clear();
        cfg.errors.random_rate = 1.0;
        let spec = cfg.resolve(Path::new("x"), "l").unwrap();
        let mut l = Lidar::new(&cfg, spec.clone(), stream(0, "x"));
        let (scan, hits) = l
            .update(
                Time::ZERO,
                &Pose::IDENTITY,
                |_| true,
                |_, _, _| Some((1.0, BeamHit::Static)),
            )
            .expect("an instant scan");
        assert!(scan.ranges.iter().all(|r| r.is_finite()));
        let far = scan.ranges.iter().filter(|r| **r > 1.5).count();
        assert!(
            far > scan.ranges.len() / 2,
            "{far} of {}",
            scan.ranges.len()
        );
        assert!(hits.iter().all(|h| *h == BeamHit::Nothing));
    }

    #[test]
    fn a_scan_is_the_same_whichever_other_scans_are_made() {
        let mut cfg = LidarConfig::preset(LidarPreset::Urg04lx);
        cfg.sweep = false;
        let spec = cfg.resolve(Path::new("x"), "l").unwrap();
        let casts = std::cell::Cell::new(0);
        let cast = |_: Vec3, _: Vec3, _: f32| {
            casts.set(casts.get() + 1);
            Some((2.0, BeamHit::Static))
        };
        // Scans at 10 Hz for 1 s: every one, then every third.
        let run = |every: i64| {
            let mut l = Lidar::new(&cfg, spec.clone(), stream(4, "front"));
            let mut made = Vec::new();
            for k in 0..10 {
                let t = Time::from_secs(k as f64 * 0.1);
                let want = |stamp: Time| {
                    assert_eq!(stamp, t);
                    k % every == 0
                };
                if let Some((s, _)) = l.update(t, &Pose::IDENTITY, want, cast) {
                    made.push((k, s.ranges));
                }
            }
            made
        };
        let all = run(1);
        casts.set(0);
        let some = run(3);
        // The scans not wanted cast no ray.
        assert_eq!(casts.get(), 4 * spec.beams);
        assert_eq!(some.len(), 4);
        for (k, ranges) in &some {
            assert_eq!(&all[*k as usize].1, ranges, "scan {k}");
        }
        // And the scans differ from one another (the stream moves on from scan to scan).
        assert_ne!(all[0].1, all[1].1);
    }
}
