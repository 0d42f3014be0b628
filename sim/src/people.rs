//! People: pedestrians that walk routes, stand, or stream between places, avoiding each other,
//! the walls and the robot by a social-force model, on two legs that swing with their gait.
//!
//! A scenario declares them:
//! - `[[person]]`: one person on a route of waypoints (`loop`, `back_and_forth` or `once`),
//!   or standing where a route of one point puts them;
//! - `[[flow]]`: people arriving at `rate` per minute (exponential gaps, a Poisson stream) at
//!   a place, walking to another and leaving there;
//! - `[crowd]`: the motion model, the body about which each person's is drawn, and how far
//!   bodies differ ([`CrowdConfig`]).
//!
//! **Motion.** Each person is a point of velocity **v** driven by three accelerations, as in
//! pedsim (Gloor's pedestrian simulator, whose default parameters these are):
//! - towards the next waypoint at the person's own speed v₀, relaxing with time τ:
//!   (v₀·**e** − **v**)/τ (Helbing & Molnár 1995);
//! - away from each other person and the robot, by the social force of Moussaïd, Helbing et
//!   al. (2009), fitted to people passing each other: it weighs the neighbour's direction and
//!   the two velocities' difference (λ = 2, γ = 0.35) and turns the walker aside (n = 2,
//!   n′ = 3). People see the robot as a walker of radius `robot_radius` (0.5 m, pedsim_ros's
//!   r_r): its distance counts as that much less the person's own radius. A person declared
//!   with `yields = false` ignores the robot (someone absorbed in a phone in a doorway);
//! - away from the nearest obstacle, exp(−d/σ) with d the gap to it and σ = 0.8 m.
//!
//! The sum is integrated at the physics step, the speed capped at 1.3·v₀. A person never
//! passes through a wall, another person or the robot: a step that would bring the body
//! closer than its radius to the nearest obstacle (two radii to another person, its radius
//! and the robot's to the robot) is pushed back out, and the velocity into it is dropped.
//!
//! **Body.** A person is three bodies that every laser, camera and the physics see: a torso
//! with a head, and two legs (capsules of a shin's radius, 5 cm, from hip to floor) hinged at
//! the hip. The legs swing in opposite phase: a stride (two steps) takes `stride_period` (1 s),
//! and a step is v·period/2 long, capped at `max_step` (0.8 m), so at 1.3 m/s the feet are up
//! to 0.65 m apart. At rest the legs hang straight from hips `hip_width` apart; walking, the
//! feet come in to `step_width` apart side to side, so that a walker seen from ahead or behind
//! can show one leg before the other. By default `step_width` is the hips' width (legs straight
//! below the hips), because the gait literature's narrower step trained a leg classifier that
//! did worse on the real annotated log (README, "People as real lasers see them").
//!
//! No two people are alike: each slot's body is drawn by the seed about the crowd's
//! ([`Body::drawn`]): stature (5 % spread: men's stature has a standard deviation of 6.7 cm
//! about 175.6 cm in the US Army's 1988 survey, and a crowd mixes men and women, who are
//! about a tenth shorter), which scales the legs, the shoulders, the height and the longest
//! step; the shin's radius (1 cm: calves and trousers of every girth); the hips' width (2 cm);
//! and the stride's period (0.07 s). The last three spreads are futago's choice, not fitted.
//! A flow's slot keeps its body for every arrival it holds, so a flow of `max` people shows
//! `max` bodies (the cameras draw each slot's meshes once).
//!
//! Everything is deterministic per seed: speeds not given and flow arrivals come from seeded
//! streams.

use crate::agent::PathMode;
use crate::config::{SpecError, check_name, check_range};
use crate::noise::stream;
use crate::world::MAX_EXTENT;
use futago_msgs::Pose2;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Exp, Normal};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// One person, as a scenario's `[[person]]` table declares them.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PersonConfig {
    pub name: String,
    /// Waypoints `[[x, y], …]` in the world frame, m. One point: the person stands there.
    pub route: Vec<[f64; 2]>,
    #[serde(default)]
    pub mode: PathMode,
    /// Walking speed, m/s; left out, drawn from N(1.2, 0.2²) (pedsim's crowd).
    #[serde(default)]
    pub speed: Option<f64>,
    /// Stands at the first waypoint until this time, s.
    #[serde(default)]
    pub start_time: f64,
    /// Which way a standing person faces, degrees from the world's x axis.
    #[serde(default)]
    pub heading_deg: f64,
    /// Whether they step aside for the robot (its social force); a flow's people do.
    #[serde(default = "yes")]
    pub yields: bool,
    /// sRGB colour of the clothes on the torso.
    #[serde(default = "shirt")]
    pub shirt: [f64; 3],
    /// sRGB colour of the legs.
    #[serde(default = "trousers")]
    pub trousers: [f64; 3],
}

/// People arriving at a place and walking to another, as a `[[flow]]` table declares them.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct FlowConfig {
    pub name: String,
    /// Where people appear, m; each within `spread` of it.
    pub from: [f64; 2],
    /// Where they go and leave, m; each to a point within `spread` of it.
    pub to: [f64; 2],
    /// Waypoints between, m.
    #[serde(default)]
    pub via: Vec<[f64; 2]>,
    /// Arrivals per minute, on average (a Poisson stream).
    pub rate: f64,
    /// Radius of the places, m.
    #[serde(default = "spread")]
    pub spread: f64,
    /// Where given, people appear anywhere along the segment from `from` to `from_end` (a
    /// doorway, the side of a square) rather than about one point, m; `spread` still applies.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub from_end: Option<[f64; 2]>,
    /// Where given, people leave anywhere along the segment from `to` to `to_end`, m.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub to_end: Option<[f64; 2]>,
    /// First and last time an arrival may come, s.
    #[serde(default)]
    pub start_time: f64,
    #[serde(default = "forever")]
    pub end_time: f64,
    /// At most this many of the flow's people in the world at once; an arrival beyond it
    /// does not come.
    #[serde(default = "max_people")]
    pub max: usize,
    /// Walking speed, m/s: mean and standard deviation.
    #[serde(default = "speed_mean")]
    pub speed: f64,
    #[serde(default = "speed_std")]
    pub speed_std: f64,
}

fn yes() -> bool {
    true
}
fn shirt() -> [f64; 3] {
    [0.2, 0.35, 0.6]
}
fn trousers() -> [f64; 3] {
    [0.15, 0.15, 0.2]
}
fn spread() -> f64 {
    0.5
}
fn forever() -> f64 {
    1e9
}
fn max_people() -> usize {
    10
}
fn speed_mean() -> f64 {
    1.2
}
fn speed_std() -> f64 {
    0.2
}

/// The motion model, the body about which each person's is drawn, and the spreads of the
/// draws (`[crowd]`).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct CrowdConfig {
    /// τ: how fast a person takes up the velocity they want, s (pedsim 0.5).
    pub relaxation_time: f64,
    /// Weight of the social force between people, m/s² (pedsim 2.1).
    pub social_force: f64,
    /// Weight of the obstacle force, m/s² (pedsim 1.0).
    pub obstacle_force: f64,
    /// Range of the obstacle force, m (pedsim 0.8).
    pub obstacle_sigma: f64,
    /// Moussaïd et al. 2009: weight of the velocity difference against the direction (λ),
    /// range per unit of interaction (γ), and the angular falloffs (n for turning aside, n′
    /// for slowing down).
    pub lambda: f64,
    pub gamma: f64,
    pub n: f64,
    pub n_prime: f64,
    /// The radius people see the robot as when they avoid it, m (pedsim_ros's r_r).
    pub robot_radius: f64,
    /// The probability that a flow's arrival is two people walking together (a pair), who
    /// share their speed and keep abreast `pair_spacing` apart. Real crowds walk largely in
    /// groups, mostly pairs (Moussaïd et al., PLoS ONE 2010); `futago crowd calibrate`
    /// measures it. Zero (the default) draws nothing, so crowds without it keep their bytes.
    pub pair_fraction: f64,
    /// The distance between a pair's walkers, side by side, m.
    pub pair_spacing: f64,
    /// How often a flow's walker stops and stands, per second walked (a Poisson stream over
    /// the time they walk): real people stop to talk, wait or look about (a quarter of the
    /// samples of the ETH hotel and UCY students sequences stand). A pair stops together.
    /// Zero (the default) draws nothing, so crowds without it keep their bytes; `futago crowd
    /// calibrate` measures it as standing spells per second of walking.
    pub stop_rate: f64,
    /// How long a stop lasts, s: drawn per stop from an exponential of this mean.
    pub stop_time: f64,
    /// How often the forces are evaluated, Hz (people move on at every physics step under
    /// the forces last evaluated).
    pub rate: f64,
    /// The speed is capped at this multiple of the person's own.
    pub max_speed_factor: f64,
    /// A waypoint counts as reached this close, m.
    pub waypoint_radius: f64,
    /// The body's radius for walls, m (pedsim 0.2).
    pub radius: f64,
    /// Shin radius, m.
    pub leg_radius: f64,
    /// Hip height: the legs' length, m.
    pub hip_height: f64,
    /// Distance between the hip joints, side to side, m: where the legs hang from, and the
    /// feet's spacing at rest.
    pub hip_width: f64,
    /// Distance between the feet's centres, side to side, while walking, m: the feet come in
    /// from `hip_width` to this as the step grows to half of `max_step`. Donelan, Kram and
    /// Kuo (Proc. R. Soc. B 268, 2001) measured a preferred step width of 0.13 of the leg
    /// length (0.11 m for legs of 0.85 m); the default is `hip_width`, legs straight below
    /// the hips, which transferred better to real scans (see the module documentation).
    pub step_width: f64,
    /// Time of a stride (two steps), s.
    pub stride_period: f64,
    /// The longest step, m.
    pub max_step: f64,
    /// Torso half-depth (x) and half-width (y), m; from the hips to `shoulder_height`.
    pub torso: [f64; 2],
    pub shoulder_height: f64,
    /// Head radius, m (its top is at `height`).
    pub head_radius: f64,
    pub height: f64,
    /// How people's bodies differ, drawn per person by the seed ([`Body::drawn`]): the
    /// standard deviation of stature as a share of it (the legs' length, the shoulders, the
    /// height and the longest step scale with it).
    pub stature_spread: f64,
    /// The standard deviation of the shin's radius, m (legs and trousers of every girth).
    pub leg_radius_spread: f64,
    /// The standard deviation of the hips' width, m (the walking step width moves with it).
    pub hip_width_spread: f64,
    /// The standard deviation of the stride's period, s (each person's own cadence).
    pub stride_period_spread: f64,
}

/// One person's body and gait: the crowd's ([`CrowdConfig::body`]), or drawn from it per
/// person ([`Body::drawn`]). The laser sees legs of this radius and spacing, the cameras
/// and the physics these heights.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Body {
    /// Shin radius, m.
    pub leg_radius: f64,
    /// The legs' length, m.
    pub hip_height: f64,
    /// Distance between the hip joints, m.
    pub hip_width: f64,
    /// Distance between the feet, side to side, while walking, m.
    pub step_width: f64,
    /// Time of a stride, s.
    pub stride_period: f64,
    /// The longest step, m.
    pub max_step: f64,
    /// Torso half-depth and half-width, m.
    pub torso: [f64; 2],
    pub shoulder_height: f64,
    pub head_radius: f64,
    pub height: f64,
}

/// A body's draws are kept within this many standard deviations of the crowd's body.
const BODY_SPREAD_LIMIT: f64 = 2.5;

impl Body {
    /// A body drawn about the crowd's: stature, shin radius, hip width and stride period each
    /// from a normal of `config`'s spread, cut at [`BODY_SPREAD_LIMIT`] standard deviations;
    /// the hips no wider than leaves the legs at rest [`FOOT_CLEARANCE`] inside `radius`.
    /// With every spread zero it is the crowd's body, and nothing is drawn from `rng`.
    pub fn drawn(config: &CrowdConfig, rng: &mut ChaCha8Rng) -> Body {
        let mean = config.body();
        let spreads = [
            config.stature_spread,
            config.leg_radius_spread,
            config.hip_width_spread,
            config.stride_period_spread,
        ];
        if spreads.iter().all(|s| *s == 0.0) {
            return mean;
        }
        let mut z = || {
            let d: f64 = rand_distr::StandardNormal.sample(&mut *rng);
            d.clamp(-BODY_SPREAD_LIMIT, BODY_SPREAD_LIMIT)
        };
        let stature = 1.0 + config.stature_spread * z();
        let leg_radius = (mean.leg_radius + config.leg_radius_spread * z()).max(0.01);
        // Legs hanging at rest stay within the body's radius, less the feet's clearance, so that
        // a person kept `radius` from the robot never touches it: a wide-hipped person has
        // no thicker legs than that leaves room for.
        let widest = 2.0 * (config.radius - FOOT_CLEARANCE - leg_radius);
        let hip_width =
            (mean.hip_width + config.hip_width_spread * z()).clamp(0.0, widest.max(0.0));
        let stride_period = (mean.stride_period + config.stride_period_spread * z()).max(0.2);
        Body {
            leg_radius,
            hip_height: mean.hip_height * stature,
            hip_width,
            step_width: (mean.step_width + hip_width - mean.hip_width).max(0.0),
            stride_period,
            max_step: mean.max_step * stature,
            shoulder_height: mean.shoulder_height * stature,
            height: (mean.height * stature)
                .max(mean.shoulder_height * stature + 2.0 * mean.head_radius),
            ..mean
        }
    }

    /// The longest step a person whose centre is `gap` from the robot's edge can take with
    /// both feet [`FOOT_CLEARANCE`] clear of it, wherever the robot lies: a foot swings half a
    /// step along the heading at most `hip_width / 2` (or `step_width / 2`, the wider) to the
    /// side, and is `leg_radius` thick. People shorten their steps beside an obstacle rather
    /// than kick it (a body kept `radius` from the robot still leaves room for steps of 0.2 m
    /// with the defaults).
    pub fn step_clear_of(&self, gap: f64) -> f64 {
        let reach = gap - self.leg_radius - FOOT_CLEARANCE;
        let hip = self.hip_width.max(self.step_width) / 2.0;
        if reach <= hip {
            return 0.0;
        }
        (2.0 * (reach * reach - hip * hip).sqrt()).min(self.max_step)
    }
}

/// How far a swinging foot stays from the robot's body, m: beyond the contact margins of the
/// physics, so that a person who walks up to a standing robot never touches it.
const FOOT_CLEARANCE: f64 = 0.02;

impl CrowdConfig {
    /// The crowd's own body, about which each person's is drawn.
    pub fn body(&self) -> Body {
        Body {
            leg_radius: self.leg_radius,
            hip_height: self.hip_height,
            hip_width: self.hip_width,
            step_width: self.step_width,
            stride_period: self.stride_period,
            max_step: self.max_step,
            torso: self.torso,
            shoulder_height: self.shoulder_height,
            head_radius: self.head_radius,
            height: self.height,
        }
    }
}

impl Default for CrowdConfig {
    fn default() -> Self {
        CrowdConfig {
            relaxation_time: 0.5,
            social_force: 2.1,
            obstacle_force: 1.0,
            obstacle_sigma: 0.8,
            lambda: 2.0,
            gamma: 0.35,
            n: 2.0,
            n_prime: 3.0,
            robot_radius: 0.5,
            pair_fraction: 0.0,
            pair_spacing: 0.75,
            stop_rate: 0.0,
            stop_time: 5.0,
            rate: 50.0,
            max_speed_factor: 1.3,
            waypoint_radius: 0.3,
            radius: 0.2,
            leg_radius: 0.05,
            hip_height: 0.85,
            hip_width: 0.2,
            step_width: 0.2,
            stride_period: 1.0,
            max_step: 0.8,
            torso: [0.12, 0.2],
            shoulder_height: 1.45,
            head_radius: 0.1,
            height: 1.72,
            stature_spread: 0.05,
            leg_radius_spread: 0.01,
            hip_width_spread: 0.02,
            stride_period_spread: 0.07,
        }
    }
}

fn check_point(file: &Path, key: &str, p: &[f64; 2]) -> Result<(), SpecError> {
    for v in p {
        check_range(
            file,
            key,
            *v,
            -(MAX_EXTENT as f64),
            MAX_EXTENT as f64,
            "m, within the world's extent",
        )?;
    }
    Ok(())
}

fn check_colour(file: &Path, key: &str, c: &[f64; 3]) -> Result<(), SpecError> {
    for v in c {
        check_range(file, key, *v, 0.0, 1.0, "(sRGB in [0, 1])")?;
    }
    Ok(())
}

impl PersonConfig {
    /// Checks every field; errors name `KEY.field`.
    pub fn validate(&self, file: &Path, key: &str) -> Result<(), SpecError> {
        let k = |s: &str| format!("{key}.{s}");
        check_name(file, &k("name"), &self.name)?;
        if self.route.is_empty() || self.route.len() > 10_000 {
            return Err(SpecError::new(
                file,
                k("route"),
                format!(
                    "expected 1 to 10000 [x, y] waypoints, found {}",
                    self.route.len()
                ),
            ));
        }
        for (i, p) in self.route.iter().enumerate() {
            check_point(file, &format!("{key}.route[{i}]"), p)?;
        }
        if let Some(s) = self.speed {
            check_range(file, &k("speed"), s, 0.0, 3.0, "m/s")?;
        }
        check_range(file, &k("start_time"), self.start_time, 0.0, 1e6, "s")?;
        check_range(
            file,
            &k("heading_deg"),
            self.heading_deg,
            -360.0,
            360.0,
            "°",
        )?;
        check_colour(file, &k("shirt"), &self.shirt)?;
        check_colour(file, &k("trousers"), &self.trousers)
    }
}

impl FlowConfig {
    /// Checks every field; errors name `KEY.field`.
    pub fn validate(&self, file: &Path, key: &str) -> Result<(), SpecError> {
        let k = |s: &str| format!("{key}.{s}");
        check_name(file, &k("name"), &self.name)?;
        check_point(file, &k("from"), &self.from)?;
        check_point(file, &k("to"), &self.to)?;
        if let Some(p) = &self.from_end {
            check_point(file, &k("from_end"), p)?;
        }
        if let Some(p) = &self.to_end {
            check_point(file, &k("to_end"), p)?;
        }
        if self.via.len() > 10_000 {
            return Err(SpecError::new(
                file,
                k("via"),
                "expected at most 10000 waypoints",
            ));
        }
        for (i, p) in self.via.iter().enumerate() {
            check_point(file, &format!("{key}.via[{i}]"), p)?;
        }
        check_range(
            file,
            &k("rate"),
            self.rate,
            1e-6,
            600.0,
            "arrivals per minute",
        )?;
        check_range(file, &k("spread"), self.spread, 0.0, 100.0, "m")?;
        check_range(file, &k("start_time"), self.start_time, 0.0, 1e9, "s")?;
        check_range(
            file,
            &k("end_time"),
            self.end_time,
            self.start_time,
            1e9,
            "s, no earlier than start_time",
        )?;
        if self.max == 0 || self.max > 1000 {
            return Err(SpecError::new(
                file,
                k("max"),
                format!("expected 1 to 1000 people, found {}", self.max),
            ));
        }
        check_range(file, &k("speed"), self.speed, 0.1, 3.0, "m/s")?;
        check_range(file, &k("speed_std"), self.speed_std, 0.0, 1.0, "m/s")
    }
}

impl CrowdConfig {
    /// Checks every field; errors name `crowd.field`.
    pub fn validate(&self, file: &Path) -> Result<(), SpecError> {
        let k = |s: &str| format!("crowd.{s}");
        for (name, v, lo, hi, unit) in [
            ("relaxation_time", self.relaxation_time, 0.01, 10.0, "s"),
            ("social_force", self.social_force, 0.0, 100.0, "m/s²"),
            ("obstacle_force", self.obstacle_force, 0.0, 100.0, "m/s²"),
            ("obstacle_sigma", self.obstacle_sigma, 0.01, 10.0, "m"),
            ("lambda", self.lambda, 0.0, 100.0, ""),
            ("gamma", self.gamma, 0.01, 10.0, ""),
            ("n", self.n, 0.0, 100.0, ""),
            ("n_prime", self.n_prime, 0.0, 100.0, ""),
            ("robot_radius", self.robot_radius, 0.0, 5.0, "m"),
            ("pair_fraction", self.pair_fraction, 0.0, 1.0, ""),
            ("pair_spacing", self.pair_spacing, 0.0, 5.0, "m"),
            ("stop_rate", self.stop_rate, 0.0, 1.0, "per s"),
            ("stop_time", self.stop_time, 0.1, 3600.0, "s"),
            ("rate", self.rate, 1.0, 10_000.0, "Hz"),
            ("max_speed_factor", self.max_speed_factor, 1.0, 10.0, ""),
            ("waypoint_radius", self.waypoint_radius, 0.01, 10.0, "m"),
            ("radius", self.radius, 0.05, 1.0, "m"),
            ("leg_radius", self.leg_radius, 0.01, 0.2, "m"),
            ("hip_height", self.hip_height, 0.2, 1.5, "m"),
            ("hip_width", self.hip_width, 0.0, 0.6, "m"),
            ("step_width", self.step_width, 0.0, 0.6, "m"),
            ("stride_period", self.stride_period, 0.2, 5.0, "s"),
            ("max_step", self.max_step, 0.05, 2.0, "m"),
            ("torso[0]", self.torso[0], 0.02, 0.6, "m"),
            ("torso[1]", self.torso[1], 0.02, 0.6, "m"),
            ("head_radius", self.head_radius, 0.02, 0.3, "m"),
            (
                "stature_spread",
                self.stature_spread,
                0.0,
                0.1,
                "(a share of stature)",
            ),
            ("leg_radius_spread", self.leg_radius_spread, 0.0, 0.03, "m"),
            ("hip_width_spread", self.hip_width_spread, 0.0, 0.1, "m"),
            (
                "stride_period_spread",
                self.stride_period_spread,
                0.0,
                0.5,
                "s",
            ),
        ] {
            check_range(file, &k(name), v, lo, hi, unit)?;
        }
        check_range(
            file,
            &k("shoulder_height"),
            self.shoulder_height,
            self.hip_height + 0.05,
            3.0,
            "m, above the hips",
        )?;
        check_range(
            file,
            &k("height"),
            self.height,
            self.shoulder_height + 2.0 * self.head_radius,
            3.5,
            "m, room for the head above the shoulders",
        )
    }
}

/// What the people react to besides each other: the robot and the nearest obstacle.
pub struct Surroundings<'a> {
    /// The robot's position, velocity and body radius, m, m/s and m.
    pub robot: Option<([f64; 2], [f64; 2], f64)>,
    /// The nearest obstacle's point to a position, if one lies within the range asked (m).
    pub nearest_obstacle: &'a dyn Fn([f64; 2], f64) -> Option<[f64; 2]>,
}

/// One person's state. A slot of the pool holds a person while they are in the world.
#[derive(Debug, Clone, PartialEq)]
struct Walker {
    /// Unique over the run: declared people first, then flow arrivals in the order they came.
    id: u32,
    name: String,
    /// Which `[[person]]` or `[[flow]]` it comes from.
    source: Source,
    active: bool,
    yields: bool,
    p: [f64; 2],
    v: [f64; 2],
    heading: f64,
    speed: f64,
    route: Vec<[f64; 2]>,
    mode: PathMode,
    /// Index of the waypoint walked to, and the direction along the route (±1).
    target: usize,
    forward: bool,
    start_time: f64,
    /// Gait phase in strides, and the current step length.
    phase: f64,
    step: f64,
    /// The slot of the companion they walk with, if any (while both are in the world and
    /// name each other).
    partner: Option<usize>,
    /// Standing still until this time, s (a stop, `CrowdConfig::stop_rate`).
    stand_until: f64,
    /// Seconds still to walk before the next stop.
    walk_to_stop: f64,
    shirt: [f64; 3],
    trousers: [f64; 3],
    /// The body and gait, drawn for the slot by the seed.
    body: Body,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Source {
    Person,
    Flow(usize),
}

/// One person's ground truth.
#[derive(Debug, Clone, PartialEq)]
pub struct PersonTruth {
    pub id: u32,
    pub name: String,
    /// Position between the feet and heading (the way they face), world frame.
    pub pose: Pose2,
    /// Velocity, m/s, world frame.
    pub velocity: [f64; 2],
    /// Each leg's axis (left, right): the hip joint's position and the axis's horizontal
    /// run per metre down from it, world frame.
    pub legs: [([f64; 2], [f64; 2]); 2],
    /// The hips' height, m.
    pub hip_height: f64,
}

impl PersonTruth {
    /// Where each leg's axis crosses the height `z` (m, below the hips): what a laser at that
    /// height sees.
    pub fn legs_at(&self, z: f64) -> [[f64; 2]; 2] {
        let down = (self.hip_height - z).max(0.0);
        self.legs
            .map(|(hip, run)| [hip[0] + down * run[0], hip[1] + down * run[1]])
    }
}

/// A flow's arrivals: the next one's time and its random stream, and one who has arrived
/// but waits for room to step in (where they start, where they go, their speed).
#[derive(Debug, Clone)]
struct Arrivals {
    next: f64,
    rng: ChaCha8Rng,
    waiting: Option<Arrival>,
}

/// One arrival of a flow: where they start, where they go, their speed, and whether a
/// companion walks with them.
#[derive(Debug, Clone, Copy)]
struct Arrival {
    from: [f64; 2],
    to: [f64; 2],
    speed: f64,
    pair: bool,
}

/// The people of a run: the pool of slots (declared people, then each flow's `max`), their
/// states, and the flows' arrivals. The slots and their order never change, so that the
/// bodies built for them can be posed by index.
#[derive(Debug, Clone)]
pub struct Crowd {
    config: CrowdConfig,
    flows: Vec<FlowConfig>,
    walkers: Vec<Walker>,
    arrivals: Vec<Arrivals>,
    next_id: u32,
    /// Arrivals that found their flow full.
    turned_away: u64,
    /// Each slot's acceleration from the last evaluation of the forces.
    accel: Vec<[f64; 2]>,
    /// The stream of the flows' stops (`CrowdConfig::stop_rate`), drawn in slot order.
    stops: ChaCha8Rng,
}

/// Where an empty slot's bodies wait: far below the floor, out of every sensor's sight.
pub const PARKED_Z: f64 = -100.0;

impl Crowd {
    /// The crowd at time zero: declared people at their first waypoints, flows empty.
    pub fn new(
        people: &[PersonConfig],
        flows: &[FlowConfig],
        config: CrowdConfig,
        seed: u64,
    ) -> Crowd {
        let mut walkers = Vec::new();
        for (i, p) in people.iter().enumerate() {
            let speed = p.speed.unwrap_or_else(|| {
                draw_speed(
                    &mut stream(seed, &format!("people.{}.speed", p.name)),
                    1.2,
                    0.2,
                )
            });
            walkers.push(Walker {
                id: i as u32,
                name: p.name.clone(),
                source: Source::Person,
                active: true,
                yields: p.yields,
                p: p.route[0],
                v: [0.0; 2],
                heading: p.heading_deg.to_radians(),
                speed,
                route: p.route.clone(),
                mode: p.mode,
                target: usize::from(p.route.len() > 1),
                forward: true,
                start_time: p.start_time,
                phase: 0.0,
                step: 0.0,
                partner: None,
                stand_until: f64::NEG_INFINITY,
                walk_to_stop: f64::INFINITY,
                shirt: p.shirt,
                trousers: p.trousers,
                body: Body::drawn(
                    &config,
                    &mut stream(seed, &format!("people.{}.body", p.name)),
                ),
            });
        }
        let mut arrivals = Vec::new();
        for (f, flow) in flows.iter().enumerate() {
            for k in 0..flow.max {
                walkers.push(Walker {
                    id: u32::MAX,
                    name: format!("{}.{k}", flow.name),
                    source: Source::Flow(f),
                    active: false,
                    yields: true,
                    p: flow.from,
                    v: [0.0; 2],
                    heading: 0.0,
                    speed: flow.speed,
                    route: Vec::new(),
                    mode: PathMode::Once,
                    target: 0,
                    forward: true,
                    start_time: 0.0,
                    phase: 0.0,
                    step: 0.0,
                    partner: None,
                    stand_until: f64::NEG_INFINITY,
                    walk_to_stop: f64::INFINITY,
                    shirt: shirt_of(f, k),
                    trousers: trousers(),
                    body: Body::drawn(
                        &config,
                        &mut stream(seed, &format!("people.flow.{}.{k}.body", flow.name)),
                    ),
                });
            }
            let mut rng = stream(seed, &format!("people.flow.{}", flow.name));
            let gap = exp_draw(&mut rng, flow.rate / 60.0);
            arrivals.push(Arrivals {
                next: flow.start_time + gap,
                rng,
                waiting: None,
            });
        }
        Crowd {
            config,
            flows: flows.to_vec(),
            next_id: people.len() as u32,
            accel: vec![[0.0; 2]; walkers.len()],
            walkers,
            arrivals,
            turned_away: 0,
            stops: stream(seed, "people.stops"),
        }
    }

    /// The motion model and body.
    pub fn config(&self) -> &CrowdConfig {
        &self.config
    }

    /// Number of slots (people who can be in the world at once).
    pub fn slots(&self) -> usize {
        self.walkers.len()
    }

    /// Whether slot `i` holds a person now.
    pub fn active(&self, i: usize) -> bool {
        self.walkers[i].active
    }

    /// Slot `i`'s body and gait, drawn for it by the seed (every person a flow brings into
    /// the slot has it).
    pub fn body_of(&self, i: usize) -> &Body {
        &self.walkers[i].body
    }

    /// The colours of slot `i`'s clothes: torso, legs.
    pub fn colours(&self, i: usize) -> ([f64; 3], [f64; 3]) {
        (self.walkers[i].shirt, self.walkers[i].trousers)
    }

    /// Arrivals that found their flow full so far.
    pub fn turned_away(&self) -> u64 {
        self.turned_away
    }

    /// Every person in the world now, by slot.
    pub fn truth(&self) -> Vec<PersonTruth> {
        (0..self.walkers.len())
            .filter_map(|i| {
                let w = &self.walkers[i];
                let (body, feet) = self.body(i)?;
                let leg = |side: f64, foot: [f64; 2]| {
                    let hip = body.transform_point(self.hip(i, side));
                    // The axis runs `run / drop` per metre down.
                    let (run, down) = self.leg_run(i, side, foot);
                    let per_metre = [run[0] / down, run[1] / down];
                    let (s, co) = body.theta.sin_cos();
                    let world = [
                        co * per_metre[0] - s * per_metre[1],
                        s * per_metre[0] + co * per_metre[1],
                    ];
                    (hip, world)
                };
                Some(PersonTruth {
                    id: w.id,
                    name: w.name.clone(),
                    pose: body,
                    velocity: w.v,
                    legs: [leg(1.0, feet[0]), leg(-1.0, feet[1])],
                    hip_height: w.body.hip_height,
                })
            })
            .collect()
    }

    /// Slot `i`'s body frame (between the feet, facing its heading) and where its left and
    /// right feet are in it (forward, left), m; `None` for an empty slot.
    pub fn body(&self, i: usize) -> Option<(Pose2, [[f64; 2]; 2])> {
        let w = &self.walkers[i];
        if !w.active {
            return None;
        }
        let c = &w.body;
        let swing = 0.5 * w.step * (std::f64::consts::TAU * w.phase).sin();
        // The feet come in from the hips' spacing at rest to the step width as the step grows.
        let walking = (w.step / (0.5 * c.max_step)).min(1.0);
        let side = 0.5 * (c.hip_width + (c.step_width - c.hip_width) * walking);
        Some((
            Pose2::new(w.p[0], w.p[1], w.heading),
            [[swing, side], [-swing, -side]],
        ))
    }

    /// Slot `i`'s left (`side` = 1) or right (−1) hip joint's position in the body frame, at
    /// the hips' height.
    pub fn hip(&self, i: usize, side: f64) -> [f64; 2] {
        [0.0, side * self.walkers[i].body.hip_width / 2.0]
    }

    /// Slot `i`'s leg of length `hip_height` hung from the `side` hip towards `foot` (body
    /// frame, as [`body`](Self::body) gives it): its horizontal run from the hip and its drop,
    /// m. A foot out of reach is brought in until the leg lies no flatter than asin 0.99.
    pub fn leg_run(&self, i: usize, side: f64, foot: [f64; 2]) -> ([f64; 2], f64) {
        let l = self.walkers[i].body.hip_height;
        let h = self.hip(i, side);
        let run = [foot[0] - h[0], foot[1] - h[1]];
        let len = norm(run[0], run[1]);
        let k = if len > 0.99 * l { 0.99 * l / len } else { 1.0 };
        let down = (l * l - (len * k).powi(2)).sqrt();
        ([run[0] * k, run[1] * k], down)
    }

    /// Advances the crowd from `t` by `dt` seconds.
    pub fn step(&mut self, t: f64, dt: f64, around: &Surroundings) {
        self.plan(t, around);
        self.advance(t, dt, around);
    }

    /// Evaluates everyone's forces at `t` (from the state now; the order of the slots does
    /// not matter), held until the next call: the social forces change over tenths of a
    /// second, so they need not be evaluated at every physics step.
    pub fn plan(&mut self, t: f64, around: &Surroundings) {
        let n = self.walkers.len();
        self.accel = (0..n).map(|i| self.acceleration(i, t, around)).collect();
    }

    /// Moves everyone on from `t` by `dt` under the forces of the last [`plan`](Self::plan),
    /// keeping bodies out of walls, each other and the robot; lets arrivals in and moves
    /// targets on.
    pub fn advance(&mut self, t: f64, dt: f64, around: &Surroundings) {
        self.arrive(t + dt);
        let c = self.config;
        for (w, a) in self.walkers.iter_mut().zip(&self.accel) {
            if !w.active {
                continue;
            }
            let mut v = [w.v[0] + a[0] * dt, w.v[1] + a[1] * dt];
            let cap = c.max_speed_factor * w.speed;
            let s = norm(v[0], v[1]);
            if s > cap {
                v = [v[0] * cap / s, v[1] * cap / s];
            }
            w.v = v;
            w.p = [w.p[0] + v[0] * dt, w.p[1] + v[1] * dt];
        }
        self.separate();
        for w in self.walkers.iter_mut() {
            if !w.active {
                continue;
            }
            let (mut p, mut v) = (w.p, w.v);
            // Nor through the robot: a person who walks into it stops against it (their
            // swinging feet may still touch it) rather than shove it along.
            if let Some((rp, _, rr)) = around.robot {
                let (dx, dy) = (p[0] - rp[0], p[1] - rp[1]);
                let d = norm(dx, dy);
                let min = rr + c.radius;
                if d > 1e-9 && d < min {
                    let (nx, ny) = (dx / d, dy / d);
                    p = [rp[0] + nx * min, rp[1] + ny * min];
                    let into = v[0] * nx + v[1] * ny;
                    if into < 0.0 {
                        v = [v[0] - into * nx, v[1] - into * ny];
                    }
                }
            }
            // Never through a wall: back out to the radius, and no velocity into it.
            if let Some(q) = (around.nearest_obstacle)(p, c.radius) {
                let (dx, dy) = (p[0] - q[0], p[1] - q[1]);
                let d = norm(dx, dy);
                if d > 1e-9 && d < c.radius {
                    let (nx, ny) = (dx / d, dy / d);
                    p = [q[0] + nx * c.radius, q[1] + ny * c.radius];
                    let into = v[0] * nx + v[1] * ny;
                    if into < 0.0 {
                        v = [v[0] - into * nx, v[1] - into * ny];
                    }
                }
            }
            w.p = p;
            w.v = v;
            let speed = norm(v[0], v[1]);
            if speed > 0.1 {
                w.heading = v[1].atan2(v[0]);
            }
            // The gait: steps grow with speed up to max_step, and shorten beside the robot so
            // that no foot touches it; the phase advances a stride per two steps walked.
            let b = &w.body;
            let longest = match around.robot {
                Some((rp, _, rr)) => b.step_clear_of(norm(p[0] - rp[0], p[1] - rp[1]) - rr),
                None => b.max_step,
            };
            w.step = (speed * b.stride_period / 2.0).min(longest);
            if w.step > 1e-6 {
                w.phase = (w.phase + speed * dt / (2.0 * w.step)).fract();
            }
        }
        self.advance_routes(t + dt);
        self.advance_stops(t + dt, dt);
    }

    /// Person `i`'s acceleration at `t`: towards their waypoint, away from the others, the
    /// robot and the nearest obstacle; zero for an empty slot.
    fn acceleration(&self, i: usize, t: f64, around: &Surroundings) -> [f64; 2] {
        let c = self.config;
        let w = &self.walkers[i];
        if !w.active {
            return [0.0; 2];
        }
        let mut a = [0.0; 2];
        let mut want = self.desired_velocity(i, t);
        // A person who would walk into a wall, furniture or a robot within a step of touching
        // it walks along it instead, rather than press against it until the forces let go
        // (a lane that runs into a locker, a robot standing in the way).
        let obstacle = (around.nearest_obstacle)(w.p, c.radius + 5.0 * c.obstacle_sigma);
        if let Some(q) = obstacle {
            want = along_surface(want, w.v, [w.p[0] - q[0], w.p[1] - q[1]], c.radius);
        }
        if let Some((rp, _, rr)) = around.robot {
            want = along_surface(want, w.v, [w.p[0] - rp[0], w.p[1] - rp[1]], rr + c.radius);
        }
        a[0] += (want[0] - w.v[0]) / c.relaxation_time;
        a[1] += (want[1] - w.v[1]) / c.relaxation_time;
        let mut push = |pj: [f64; 2], vj: [f64; 2], nearer: f64| {
            let f = social_force(&c, w.p, w.v, pj, vj, nearer);
            a[0] += c.social_force * f[0];
            a[1] += c.social_force * f[1];
        };
        for (j, o) in self.walkers.iter().enumerate() {
            // Companions do not avoid each other: they keep abreast by their routes and
            // pace (see `desired_velocity`), their bodies apart by `separate`.
            if j != i && o.active && self.companion(i) != Some(j) {
                push(o.p, o.v, 0.0);
            }
        }
        if let Some((rp, rv, _)) = around.robot.filter(|_| w.yields) {
            push(rp, rv, (c.robot_radius - c.radius).max(0.0));
        }
        if let Some(q) = obstacle {
            let (dx, dy) = (w.p[0] - q[0], w.p[1] - q[1]);
            let d = norm(dx, dy);
            if d > 1e-9 {
                let f = c.obstacle_force * (-(d - c.radius).max(0.0) / c.obstacle_sigma).exp();
                a[0] += f * dx / d;
                a[1] += f * dy / d;
            }
        }
        a
    }

    /// Bodies do not pass through each other: two people closer than two radii are moved
    /// apart, each by half the overlap along the line between them, and lose the velocity
    /// with which they approach each other (one pass over the pairs, in slot order).
    fn separate(&mut self) {
        let min = 2.0 * self.config.radius;
        let n = self.walkers.len();
        for i in 0..n {
            if !self.walkers[i].active {
                continue;
            }
            for j in i + 1..n {
                if !self.walkers[j].active {
                    continue;
                }
                let (a, b) = (self.walkers[i].p, self.walkers[j].p);
                let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
                let d = norm(dx, dy);
                if d >= min || d < 1e-9 {
                    continue;
                }
                let (nx, ny) = (dx / d, dy / d);
                let push = 0.5 * (min - d);
                let (vi, vj) = (self.walkers[i].v, self.walkers[j].v);
                let closing = (vi[0] - vj[0]) * nx + (vi[1] - vj[1]) * ny;
                let wi = &mut self.walkers[i];
                wi.p = [a[0] - nx * push, a[1] - ny * push];
                if closing > 0.0 {
                    wi.v = [vi[0] - 0.5 * closing * nx, vi[1] - 0.5 * closing * ny];
                }
                let wj = &mut self.walkers[j];
                wj.p = [b[0] + nx * push, b[1] + ny * push];
                if closing > 0.0 {
                    wj.v = [vj[0] + 0.5 * closing * nx, vj[1] + 0.5 * closing * ny];
                }
            }
        }
    }

    /// The velocity person `i` wants: towards their waypoint at their speed, slowing within
    /// a metre of where they will stop.
    fn desired_velocity(&self, i: usize, t: f64) -> [f64; 2] {
        let w = &self.walkers[i];
        if t < w.start_time || t < w.stand_until || w.route.is_empty() {
            return [0.0; 2];
        }
        let goal = w.route[w.target];
        let (dx, dy) = (goal[0] - w.p[0], goal[1] - w.p[1]);
        let d = norm(dx, dy);
        if d < 1e-9 {
            return [0.0; 2];
        }
        let last = match w.mode {
            PathMode::Loop => w.route.len() == 1,
            PathMode::BackAndForth => w.route.len() == 1,
            PathMode::Once => w.target + 1 == w.route.len(),
        };
        let mut s = if last { w.speed * d.min(1.0) } else { w.speed };
        if let Some(j) = self.companion(i) {
            // Abreast of the companion: slower when ahead of them along the way, faster when
            // behind, by half the lead in units of the pair's spacing.
            let o = &self.walkers[j];
            let lead = ((w.p[0] - o.p[0]) * dx + (w.p[1] - o.p[1]) * dy) / d;
            let spacing = self.config.pair_spacing.max(2.0 * self.config.radius);
            s *= (1.0 - 0.5 * lead / spacing).clamp(0.5, self.config.max_speed_factor);
        }
        [s * dx / d, s * dy / d]
    }

    /// Starts and ends the flows' walkers' stops at `t`, after `dt` more seconds in the world:
    /// a walker's clock to the next stop runs while they walk; a pair's first slot keeps the
    /// clock and both stand.
    fn advance_stops(&mut self, t: f64, dt: f64) {
        let c = self.config;
        if c.stop_rate <= 0.0 {
            return;
        }
        for i in 0..self.walkers.len() {
            let w = &self.walkers[i];
            if !w.active || !matches!(w.source, Source::Flow(_)) || t < w.stand_until {
                continue;
            }
            if self.companion(i).is_some_and(|j| j < i) {
                continue;
            }
            let left = w.walk_to_stop - dt;
            if left > 0.0 {
                self.walkers[i].walk_to_stop = left;
                continue;
            }
            let until = t + exp_draw(&mut self.stops, 1.0 / c.stop_time);
            let next = exp_draw(&mut self.stops, c.stop_rate);
            let w = &mut self.walkers[i];
            w.stand_until = until;
            w.walk_to_stop = next;
            if let Some(j) = self.companion(i) {
                self.walkers[j].stand_until = until;
            }
        }
    }

    /// The slot of the companion walking with slot `i`, while both are in the world.
    fn companion(&self, i: usize) -> Option<usize> {
        let j = self.walkers[i].partner?;
        let o = self.walkers.get(j)?;
        (o.active && o.partner == Some(i)).then_some(j)
    }

    /// Moves each walker's target on when it is reached; a flow's people leave at the end.
    fn advance_routes(&mut self, t: f64) {
        let r = self.config.waypoint_radius;
        for w in self.walkers.iter_mut().filter(|w| w.active) {
            if w.route.len() < 2 || t < w.start_time {
                continue;
            }
            let g = w.route[w.target];
            if norm(g[0] - w.p[0], g[1] - w.p[1]) > r {
                continue;
            }
            let n = w.route.len();
            match (w.mode, w.source) {
                (_, Source::Flow(_)) if w.target + 1 == n => w.active = false,
                (PathMode::Once, _) => w.target = (w.target + 1).min(n - 1),
                (PathMode::Loop, _) => w.target = (w.target + 1) % n,
                (PathMode::BackAndForth, _) => {
                    if w.forward && w.target + 1 == n {
                        w.forward = false;
                    } else if !w.forward && w.target == 0 {
                        w.forward = true;
                    }
                    w.target = if w.forward {
                        w.target + 1
                    } else {
                        w.target - 1
                    };
                }
            }
        }
    }

    /// Lets in the arrivals due by `t`. An arrival steps in only where nobody stands within
    /// two body radii of their start (of both starts, for a pair); until then they wait, and
    /// the arrivals behind them too. A pair takes two of the flow's slots; with one free, the
    /// companion is turned away and the other walks alone.
    fn arrive(&mut self, t: f64) {
        let pairs = self.config.pair_fraction;
        for f in 0..self.flows.len() {
            loop {
                let flow = &self.flows[f];
                let a = &mut self.arrivals[f];
                if a.waiting.is_none() {
                    if a.next > t.min(flow.end_time) {
                        break;
                    }
                    let rng = &mut a.rng;
                    let from = place(rng, flow.from, flow.from_end, flow.spread);
                    let to = place(rng, flow.to, flow.to_end, flow.spread);
                    let speed = draw_speed(rng, flow.speed, flow.speed_std);
                    // Drawn only where pairs may come, so that other crowds keep their bytes.
                    let pair = pairs > 0.0 && rng.random::<f64>() < pairs;
                    a.next += exp_draw(rng, flow.rate / 60.0);
                    a.waiting = Some(Arrival {
                        from,
                        to,
                        speed,
                        pair,
                    });
                }
                let Some(arrival) = a.waiting else {
                    break;
                };
                let mut route = vec![arrival.from];
                route.extend(flow.via.iter().copied());
                route.push(arrival.to);
                let routes = if arrival.pair {
                    abreast(&route, self.config.pair_spacing)
                } else {
                    vec![route]
                };
                let room = 2.0 * self.config.radius;
                if routes.iter().any(|r| {
                    self.walkers
                        .iter()
                        .any(|w| w.active && norm(w.p[0] - r[0][0], w.p[1] - r[0][1]) < room)
                }) {
                    break;
                }
                self.arrivals[f].waiting = None;
                let mut slots = Vec::new();
                for route in routes {
                    let slot = self
                        .walkers
                        .iter()
                        .position(|w| w.source == Source::Flow(f) && !w.active);
                    let Some(slot) = slot else {
                        self.turned_away += 1;
                        continue;
                    };
                    self.enter(slot, route, arrival.speed);
                    slots.push(slot);
                }
                if let [a, b] = slots[..] {
                    self.walkers[a].partner = Some(b);
                    self.walkers[b].partner = Some(a);
                }
            }
        }
    }

    /// Slot `slot` takes in a flow's arrival on `route` at `speed`.
    fn enter(&mut self, slot: usize, route: Vec<[f64; 2]>, speed: f64) {
        let w = &mut self.walkers[slot];
        w.id = self.next_id;
        self.next_id += 1;
        w.active = true;
        w.p = route[0];
        w.v = [0.0; 2];
        let (dx, dy) = (route[1][0] - route[0][0], route[1][1] - route[0][1]);
        w.heading = dy.atan2(dx);
        w.speed = speed;
        w.route = route;
        w.target = 1;
        w.start_time = 0.0;
        w.phase = 0.0;
        w.step = 0.0;
        w.partner = None;
        w.stand_until = f64::NEG_INFINITY;
        w.walk_to_stop = if self.config.stop_rate > 0.0 {
            exp_draw(&mut self.stops, self.config.stop_rate)
        } else {
            f64::INFINITY
        };
    }
}

/// A draw from the exponential of `rate` (mean 1 / rate); infinite for no rate.
fn exp_draw(rng: &mut ChaCha8Rng, rate: f64) -> f64 {
    Exp::new(rate)
        .map(|e| e.sample(rng))
        .unwrap_or(f64::INFINITY)
}

/// A pair's two routes: `route` moved `spacing / 2` to its left and to its right, square to
/// the way from its first point to its second.
fn abreast(route: &[[f64; 2]], spacing: f64) -> Vec<Vec<[f64; 2]>> {
    let (dx, dy) = (route[1][0] - route[0][0], route[1][1] - route[0][1]);
    let d = norm(dx, dy);
    let (lx, ly) = if d > 1e-9 {
        (-dy / d, dx / d)
    } else {
        (0.0, 1.0)
    };
    [0.5, -0.5]
        .iter()
        .map(|side| {
            route
                .iter()
                .map(|p| [p[0] + side * spacing * lx, p[1] + side * spacing * ly])
                .collect()
        })
        .collect()
}

/// Where a flow's arrival starts or ends: about `at`, or anywhere along the segment from `at`
/// to `end` where one is given, then within `spread` of that.
fn place(rng: &mut ChaCha8Rng, at: [f64; 2], end: Option<[f64; 2]>, spread: f64) -> [f64; 2] {
    let c = match end {
        Some(b) => {
            let u = rng.random::<f64>();
            [at[0] + u * (b[0] - at[0]), at[1] + u * (b[1] - at[1])]
        }
        None => at,
    };
    in_disc(rng, c, spread)
}

/// The length of (x, y). Coordinates here are bounded by the world's extent, so the plain
/// square root is safe, and several times faster than `hypot`'s overflow-proof one (the
/// crowd's forces take it for every pair of people at every physics step).
fn norm(x: f64, y: f64) -> f64 {
    (x * x + y * y).sqrt()
}

/// A walking speed from N(mean, std²), kept within [0.3, 2.5] m/s.
fn draw_speed(rng: &mut ChaCha8Rng, mean: f64, std: f64) -> f64 {
    let s = Normal::new(mean, std.max(0.0))
        .map(|n| n.sample(rng))
        .unwrap_or(mean);
    s.clamp(0.3, 2.5)
}

/// A point uniformly within `r` of `c`.
fn in_disc(rng: &mut ChaCha8Rng, c: [f64; 2], r: f64) -> [f64; 2] {
    let rho = r * rng.random::<f64>().sqrt();
    let a = std::f64::consts::TAU * rng.random::<f64>();
    [c[0] + rho * a.cos(), c[1] + rho * a.sin()]
}

/// A shirt colour per flow and person, so that a camera tells them apart.
fn shirt_of(flow: usize, k: usize) -> [f64; 3] {
    const PALETTE: [[f64; 3]; 6] = [
        [0.6, 0.15, 0.15],
        [0.15, 0.45, 0.2],
        [0.2, 0.3, 0.6],
        [0.7, 0.55, 0.1],
        [0.45, 0.2, 0.5],
        [0.8, 0.8, 0.78],
    ];
    PALETTE[(flow * 3 + k) % PALETTE.len()]
}

/// How near touching a surface a person begins to walk along it rather than into it, m.
const SLIDE_REACH: f64 = 0.1;
/// The speed along a surface, m/s, from which a person keeps to the side they move to.
const SLIDING: f64 = 0.05;

/// A wanted velocity that presses into a surface, turned along it at the same speed: `away`
/// runs from the surface (its nearest point, or a round body's centre) to the person, who
/// touches it at `contact` from there. Only within [`SLIDE_REACH`] of touching, and only the
/// velocity into it, so that nobody stands pressed against a wall or a robot that they could
/// walk round. The person keeps to the side they already move along it (else their wish
/// would flip from side to side about the point square to their goal, and hold them there);
/// from rest, to the side their wish leans to, and to their right when it is square on (as
/// people keep right).
fn along_surface(want: [f64; 2], v: [f64; 2], away: [f64; 2], contact: f64) -> [f64; 2] {
    let d = norm(away[0], away[1]);
    if d < 1e-9 || d > contact + SLIDE_REACH {
        return want;
    }
    let n = [away[0] / d, away[1] / d];
    if want[0] * n[0] + want[1] * n[1] >= 0.0 {
        return want;
    }
    let speed = norm(want[0], want[1]);
    // The surface's tangent to the right of someone walking square into it.
    let right = [-n[1], n[0]];
    let moving = v[0] * right[0] + v[1] * right[1];
    let lean = if moving.abs() > SLIDING {
        moving
    } else {
        want[0] * right[0] + want[1] * right[1]
    };
    let side = if lean >= 0.0 { 1.0 } else { -1.0 };
    [side * speed * right[0], side * speed * right[1]]
}

/// The social force on a person at `pi` moving at `vi` from one at `pj` moving at `vj`, whose
/// distance counts as `nearer` metres less than it is (a walker bigger than a person)
/// (Moussaïd, Helbing, Garnier, Johansson, Combe & Theraulaz 2009, as pedsim uses it): an
/// acceleration of at most 1 in units of the force's weight. It slows the person down along
/// the interaction direction (velocity difference weighted by λ, plus the direction to the
/// other) and turns them aside, both falling off with distance over B = γ·|interaction| and
/// with the angle θ between the interaction and the direction to the other. Head on (θ = 0)
/// the person turns right, so two people meeting pass on their right.
pub fn social_force(
    c: &CrowdConfig,
    pi: [f64; 2],
    vi: [f64; 2],
    pj: [f64; 2],
    vj: [f64; 2],
    nearer: f64,
) -> [f64; 2] {
    let d = [pj[0] - pi[0], pj[1] - pi[1]];
    let centres = norm(d[0], d[1]);
    if centres < 1e-9 {
        return [0.0; 2];
    }
    let e = [d[0] / centres, d[1] / centres];
    let dist = (centres - nearer).max(0.0);
    let iv = [
        c.lambda * (vi[0] - vj[0]) + e[0],
        c.lambda * (vi[1] - vj[1]) + e[1],
    ];
    let il = norm(iv[0], iv[1]);
    if il < 1e-9 {
        return [0.0; 2];
    }
    let t = [iv[0] / il, iv[1] / il];
    // Signed angle from the interaction direction to the direction to the other.
    let theta = (t[0] * e[1] - t[1] * e[0]).atan2(t[0] * e[0] + t[1] * e[1]);
    let b = c.gamma * il;
    let slow = -(-dist / b - (c.n_prime * b * theta).powi(2)).exp();
    let sign = if theta < 0.0 { -1.0 } else { 1.0 };
    let aside = -sign * (-dist / b - (c.n * b * theta).powi(2)).exp();
    // The interaction direction's left normal.
    let left = [-t[1], t[0]];
    [slow * t[0] + aside * left[0], slow * t[1] + aside * left[1]]
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    fn open(_: [f64; 2], _: f64) -> Option<[f64; 2]> {
        None
    }

    /// A person who walks `route` once at `speed`, for tests.
    pub(crate) fn person(name: &str, route: Vec<[f64; 2]>, speed: f64) -> PersonConfig {
        PersonConfig {
            name: name.into(),
            route,
            mode: PathMode::Once,
            speed: Some(speed),
            start_time: 0.0,
            heading_deg: 0.0,
            yields: true,
            shirt: shirt(),
            trousers: trousers(),
        }
    }

    fn run(crowd: &mut Crowd, seconds: f64, around: &Surroundings, mut each: impl FnMut(&Crowd)) {
        let dt = 0.005;
        let steps = (seconds / dt).round() as usize;
        for k in 0..steps {
            crowd.step(k as f64 * dt, dt, around);
            each(crowd);
        }
    }

    #[test]
    fn a_person_alone_takes_up_their_speed_with_the_relaxation_time() {
        let mut c = Crowd::new(
            &[person("a", vec![[0.0, 0.0], [100.0, 0.0]], 1.2)],
            &[],
            CrowdConfig::default(),
            1,
        );
        let around = Surroundings {
            robot: None,
            nearest_obstacle: &open,
        };
        // dv/dt = (v0 − v)/τ from rest: v(τ) = v0·(1 − 1/e) (to the step's Euler error).
        run(&mut c, 0.5, &around, |_| {});
        let v = c.truth()[0].velocity[0];
        let want = 1.2 * (1.0 - (-1.0f64).exp());
        assert!((v - want).abs() < 0.005, "{v} vs {want}");
        run(&mut c, 5.0, &around, |_| {});
        let v = c.truth()[0].velocity;
        assert!((v[0] - 1.2).abs() < 1e-3 && v[1].abs() < 1e-9, "{v:?}");
    }

    #[test]
    fn two_people_meeting_head_on_pass_each_other_on_their_right() {
        let mut c = Crowd::new(
            &[
                person("a", vec![[0.0, 0.0], [10.0, 0.0]], 1.3),
                person("b", vec![[10.0, 0.0], [0.0, 0.0]], 1.3),
            ],
            &[],
            CrowdConfig::default(),
            1,
        );
        let around = Surroundings {
            robot: None,
            nearest_obstacle: &open,
        };
        let mut closest = f64::INFINITY;
        let mut side_a = 0.0;
        run(&mut c, 12.0, &around, |c| {
            let t = c.truth();
            let d = t[0].pose.distance(&t[1].pose);
            if d < closest {
                closest = d;
                side_a = t[0].pose.y;
            }
        });
        // Shoulders (0.2 m each side) never touch, and a walking east steps to its right (−y).
        assert!(closest > 2.0 * 0.2, "closest {closest} m");
        assert!(side_a < -0.05, "a passed at y = {side_a}");
        let t = c.truth();
        assert!(t[0].pose.x > 9.5 && t[1].pose.x < 0.5, "{t:?}");
    }

    #[test]
    fn a_wall_keeps_its_distance_and_is_never_crossed() {
        // A wall along y = 0.5; the person walks a route that hugs it.
        let wall = |p: [f64; 2], range: f64| -> Option<[f64; 2]> {
            (0.5 - p[1] <= range).then_some([p[0], 0.5])
        };
        let mut c = Crowd::new(
            &[person("a", vec![[0.0, 0.3], [10.0, 0.6]], 1.2)],
            &[],
            CrowdConfig::default(),
            1,
        );
        let around = Surroundings {
            robot: None,
            nearest_obstacle: &wall,
        };
        let mut highest = f64::NEG_INFINITY;
        run(&mut c, 12.0, &around, |c| {
            highest = highest.max(c.truth()[0].pose.y)
        });
        // The body's edge (0.2 m) stays off the wall.
        assert!(highest <= 0.5 - 0.2 + 1e-9, "reached y = {highest}");
    }

    #[test]
    fn bodies_are_drawn_per_person_by_the_seed() {
        let flow = FlowConfig {
            name: "f".into(),
            from: [0.0, 0.0],
            to: [10.0, 0.0],
            via: vec![],
            rate: 10.0,
            spread: 0.5,
            from_end: None,
            to_end: None,
            start_time: 0.0,
            end_time: 100.0,
            max: 6,
            speed: 1.2,
            speed_std: 0.2,
        };
        let people = [
            person("a", vec![[0.0, 0.0]], 1.0),
            person("b", vec![[0.0, 2.0]], 1.0),
        ];
        let c = CrowdConfig::default();
        let bodies = |seed: u64, c: CrowdConfig| {
            let crowd = Crowd::new(&people, std::slice::from_ref(&flow), c, seed);
            (0..crowd.slots())
                .map(|i| *crowd.body_of(i))
                .collect::<Vec<Body>>()
        };
        let one = bodies(1, c);
        assert_eq!(one.len(), 8);
        // The same seed draws the same bodies; another seed others; every slot its own.
        assert_eq!(one, bodies(1, c));
        assert!(one.iter().zip(bodies(2, c)).all(|(a, b)| *a != b));
        for (i, a) in one.iter().enumerate() {
            assert!(one[i + 1..].iter().all(|b| a != b), "slot {i}");
            // Stature scales the legs, the shoulders, the height and the step together;
            // each draw stays within 2.5 standard deviations.
            let s = a.hip_height / c.hip_height;
            assert!((s - 1.0).abs() <= 2.5 * c.stature_spread + 1e-12, "{s}");
            for (v, mean) in [
                (a.shoulder_height, c.shoulder_height),
                (a.height, c.height),
                (a.max_step, c.max_step),
            ] {
                assert!((v / mean - s).abs() < 1e-12);
            }
            assert!((a.leg_radius - c.leg_radius).abs() <= 2.5 * c.leg_radius_spread + 1e-12);
            assert!((a.hip_width - c.hip_width).abs() <= 2.5 * c.hip_width_spread + 1e-12);
            // Legs at rest within the body's radius, less the feet's clearance.
            assert!(a.hip_width / 2.0 + a.leg_radius <= c.radius - FOOT_CLEARANCE + 1e-12);
            // With the default step width (the hips'), the legs stay straight below the hips.
            assert!((a.step_width - a.hip_width).abs() < 1e-12);
            let p = a.stride_period - c.stride_period;
            assert!(p.abs() <= 2.5 * c.stride_period_spread + 1e-12);
            assert_eq!((a.torso, a.head_radius), (c.torso, c.head_radius));
        }
        // No spread: everyone has the crowd's body.
        let same = CrowdConfig {
            stature_spread: 0.0,
            leg_radius_spread: 0.0,
            hip_width_spread: 0.0,
            stride_period_spread: 0.0,
            ..c
        };
        assert!(bodies(1, same).iter().all(|b| *b == c.body()));
    }

    #[test]
    fn a_bodys_draws_have_the_spreads_asked_for() {
        // A normal cut at 2.5 standard deviations keeps 0.986 of its spread; 4,000 draws
        // estimate a standard deviation within 2.2 % (1/√(2n)) at one sigma, so 6 % is about
        // three sigma. A wide body radius keeps the hips' bound out of the way here.
        let c = CrowdConfig {
            radius: 0.3,
            ..CrowdConfig::default()
        };
        let mut rng = stream(7, "test.bodies");
        let draws: Vec<Body> = (0..4000).map(|_| Body::drawn(&c, &mut rng)).collect();
        // With the default radius, the widest hips and thickest legs meet the bound (about
        // one body in 60 would reach past it), and none goes beyond.
        let d = CrowdConfig::default();
        let edge = d.radius - FOOT_CLEARANCE;
        let reach: Vec<f64> = (0..4000)
            .map(|_| {
                let b = Body::drawn(&d, &mut rng);
                b.hip_width / 2.0 + b.leg_radius
            })
            .collect();
        assert!(reach.iter().all(|r| *r <= edge + 1e-12));
        let bound = reach.iter().filter(|r| (*r - edge).abs() < 1e-12).count();
        assert!((20..=120).contains(&bound), "{bound} bodies at the bound");
        let spread = |f: &dyn Fn(&Body) -> f64| {
            let n = draws.len() as f64;
            let m = draws.iter().map(f).sum::<f64>() / n;
            let v = draws.iter().map(|b| (f(b) - m).powi(2)).sum::<f64>() / (n - 1.0);
            (m, v.sqrt())
        };
        for (name, (mean, sd), want_mean, want_sd) in [
            (
                "stature",
                spread(&|b| b.hip_height / c.hip_height),
                1.0,
                c.stature_spread,
            ),
            (
                "leg radius",
                spread(&|b| b.leg_radius),
                c.leg_radius,
                c.leg_radius_spread,
            ),
            (
                "hip width",
                spread(&|b| b.hip_width),
                c.hip_width,
                c.hip_width_spread,
            ),
            (
                "stride period",
                spread(&|b| b.stride_period),
                c.stride_period,
                c.stride_period_spread,
            ),
        ] {
            assert!(
                (sd / (0.986 * want_sd) - 1.0).abs() < 0.06,
                "{name}: sd {sd}"
            );
            // The mean within four standard errors.
            let se = want_sd / (draws.len() as f64).sqrt();
            assert!((mean - want_mean).abs() < 4.0 * se, "{name}: mean {mean}");
        }
    }

    #[test]
    fn steps_shorten_beside_the_robot_so_that_no_foot_reaches_it() {
        let c = CrowdConfig::default().body();
        // Far off, the longest step; at the body's radius (0.2 m from the robot's edge) a
        // foot may swing s with √(s² + 0.1²) + 0.05 + 0.02 ≤ 0.2: s = 0.0831, a step twice it.
        assert_eq!(c.step_clear_of(5.0), c.max_step);
        let s = (0.13f64 * 0.13 - 0.1 * 0.1).sqrt();
        assert!((c.step_clear_of(0.2) - 2.0 * s).abs() < 1e-12);
        // Closer than a hip and a shin from it: no step at all.
        assert_eq!(c.step_clear_of(0.17), 0.0);
        assert_eq!(c.step_clear_of(-1.0), 0.0);
        // Shorter the nearer, and never longer than max_step.
        let steps: Vec<f64> = (0..60)
            .map(|k| c.step_clear_of(0.15 + 0.01 * k as f64))
            .collect();
        assert!(steps.windows(2).all(|w| w[0] <= w[1]), "{steps:?}");
        assert!(steps.iter().all(|s| *s <= c.max_step));
    }

    #[test]
    fn a_person_walks_round_a_robot_standing_square_in_their_way() {
        // The robot stands on the route of someone who does not look out for it (no social
        // force from it): they neither stop against it nor touch it with a foot, and get to
        // the end.
        let mut walker = person("a", vec![[0.0, 0.0], [10.0, 0.0]], 1.3);
        walker.yields = false;
        let mut c = Crowd::new(&[walker], &[], CrowdConfig::default(), 1);
        let cfg = *c.config();
        let (rp, rr) = ([5.0, 0.0], 0.17);
        let around = Surroundings {
            robot: Some((rp, [0.0, 0.0], rr)),
            nearest_obstacle: &open,
        };
        let (mut body, mut foot) = (f64::INFINITY, f64::INFINITY);
        run(&mut c, 12.0, &around, |c| {
            let (pose, feet) = c.body(0).expect("walking");
            body = body.min(norm(pose.x - rp[0], pose.y - rp[1]));
            for f in feet {
                let at = pose.transform_point(f);
                foot = foot.min(norm(at[0] - rp[0], at[1] - rp[1]) - cfg.leg_radius);
            }
        });
        assert!(
            body >= rr + cfg.radius - 1e-9,
            "the body came {body} m from its centre"
        );
        assert!(
            foot >= rr + 0.01,
            "a foot came {foot} m from the robot's centre"
        );
        let end = c.truth()[0].pose;
        assert!(end.x > 9.5 && end.y.abs() < 0.3, "ended at {end:?}");
    }

    #[test]
    fn a_person_whose_lane_runs_into_a_box_walks_along_it_and_on() {
        // A box from x = 5 to 7 and y = 0 to 1 (a row of lockers) faces the way at x = 5; the lane
        // runs at y = 0.6 into it and on beyond. Pressed square on, a person would stand
        // against it; they walk along it, round its corner at y = 0, and on.
        let face = |p: [f64; 2], range: f64| -> Option<[f64; 2]> {
            let q = [p[0].clamp(5.0, 7.0), p[1].clamp(0.0, 1.0)];
            (norm(p[0] - q[0], p[1] - q[1]) <= range).then_some(q)
        };
        let box_of = |p: [f64; 2]| (5.0..=7.0).contains(&p[0]) && (0.0..=1.0).contains(&p[1]);
        let mut c = Crowd::new(
            &[person("a", vec![[0.0, 0.6], [12.0, 0.6]], 1.2)],
            &[],
            CrowdConfig::default(),
            1,
        );
        let around = Surroundings {
            robot: None,
            nearest_obstacle: &face,
        };
        run(&mut c, 20.0, &around, |c| {
            let p = c.truth()[0].pose;
            assert!(!box_of([p.x, p.y]), "walked into the box at {p:?}");
        });
        let end = c.truth()[0].pose;
        assert!(end.x > 11.5, "ended at {end:?}");
    }

    #[test]
    fn legs_swing_a_step_apart_at_a_stride_a_second() {
        let cfg = CrowdConfig {
            step_width: 0.11,
            ..CrowdConfig::default()
        };
        let mut c = Crowd::new(
            &[person("a", vec![[0.0, 0.0], [1000.0, 0.0]], 1.3)],
            &[],
            cfg,
            1,
        );
        let around = Surroundings {
            robot: None,
            nearest_obstacle: &open,
        };
        run(&mut c, 10.0, &around, |_| {});
        // At 1.3 m/s a step is 1.3 · T / 2 for the person's own stride period T (the crowd's
        // 1 s, drawn per person: 0.65 m at 1 s): the feet are up to that far apart, and a full
        // stride (one swing period) takes T.
        let b = *c.body_of(0);
        assert_ne!(b.stride_period, cfg.stride_period);
        let mut widest: f64 = 0.0;
        let mut crossings = 0;
        let mut last = c.body(0).unwrap().1[0][0];
        let mut sideways: Vec<f64> = Vec::new();
        run(&mut c, 4.0, &around, |c| {
            let f = c.body(0).unwrap().1;
            widest = widest.max(f[0][0] - f[1][0]);
            sideways.push(f[0][1] - f[1][1]);
            if last < 0.0 && f[0][0] >= 0.0 {
                crossings += 1;
            }
            last = f[0][0];
        });
        assert!(
            (widest - 1.3 * b.stride_period / 2.0).abs() < 0.01,
            "{widest}"
        );
        let strides = 4.0 / b.stride_period;
        assert!(
            (crossings as f64 - strides).abs() <= 1.0,
            "{crossings} crossings, {strides} strides in 4 s"
        );
        // Walking, the feet are the step width apart side to side (the left on the left),
        // not the hips' width.
        assert!((b.step_width - b.hip_width - (cfg.step_width - cfg.hip_width)).abs() < 1e-12);
        assert!(
            sideways.iter().all(|w| (w - b.step_width).abs() < 1e-9),
            "{sideways:?}"
        );
    }

    #[test]
    fn the_legs_run_from_the_hips_to_the_feet_which_come_in_when_walking() {
        let mut c = Crowd::new(
            &[
                person("walker", vec![[0.0, 0.0], [1000.0, 0.0]], 1.3),
                person("stander", vec![[0.0, 5.0]], 0.0),
            ],
            &[],
            CrowdConfig {
                step_width: 0.11,
                ..CrowdConfig::default()
            },
            1,
        );
        let around = Surroundings {
            robot: None,
            nearest_obstacle: &open,
        };
        run(&mut c, 3.3, &around, |_| {});
        for (i, truth) in c.truth().iter().enumerate() {
            let cfg = *c.body_of(i);
            let (pose, feet) = c.body(i).expect("in the world");
            // The truth's leg axes run from the hips at hip height to the feet, which a leg of
            // hip_height swung out lifts off the floor by hip_height − its drop.
            for (k, leg) in truth.legs.iter().enumerate() {
                let side = [1.0, -1.0][k];
                let hip = pose.transform_point(c.hip(i, side));
                assert!(norm(leg.0[0] - hip[0], leg.0[1] - hip[1]) < 1e-12);
                let (_, down) = c.leg_run(i, side, feet[k]);
                let at_foot = truth.legs_at(cfg.hip_height - down)[k];
                let foot = pose.transform_point(feet[k]);
                assert!(
                    norm(at_foot[0] - foot[0], at_foot[1] - foot[1]) < 1e-9,
                    "{} leg {k}: {at_foot:?} against {foot:?}",
                    truth.name
                );
                let at_hips = truth.legs_at(cfg.hip_height)[k];
                assert!(norm(at_hips[0] - hip[0], at_hips[1] - hip[1]) < 1e-12);
            }
            let apart = feet[0][1] - feet[1][1];
            let want = if truth.name == "walker" {
                cfg.step_width
            } else {
                cfg.hip_width
            };
            assert!((apart - want).abs() < 1e-9, "{}: {apart}", truth.name);
        }
    }

    #[test]
    fn a_flow_lets_people_in_at_its_rate_and_they_leave_at_the_end() {
        let flow = FlowConfig {
            name: "f".into(),
            from: [0.0, 0.0],
            to: [8.0, 0.0],
            via: vec![],
            rate: 30.0,
            spread: 0.5,
            from_end: None,
            to_end: None,
            start_time: 0.0,
            end_time: 200.0,
            max: 40,
            speed: 1.2,
            speed_std: 0.2,
        };
        let mut c = Crowd::new(&[], std::slice::from_ref(&flow), CrowdConfig::default(), 3);
        let around = Surroundings {
            robot: None,
            nearest_obstacle: &open,
        };
        let mut most = 0;
        let mut ids = std::collections::BTreeSet::new();
        run(&mut c, 230.0, &around, |c| {
            let t = c.truth();
            most = most.max(t.len());
            ids.extend(t.iter().map(|p| p.id));
        });
        // 30 a minute for 200 s: 100 expected, Poisson: ±3σ = ±30.
        assert!((70..=130).contains(&ids.len()), "{} arrivals", ids.len());
        // 8 m at ~1.2 m/s: about 7 s each, so about 3.5 at a time; never beyond max.
        assert!((3..=40).contains(&most), "{most}");
        assert_eq!(c.turned_away(), 0);
        // Long after the last arrival, all have left.
        assert!(c.truth().is_empty(), "{:?}", c.truth());
        // The same seed, the same arrivals.
        let mut again = Crowd::new(&[], &[flow], CrowdConfig::default(), 3);
        let mut ids2 = std::collections::BTreeSet::new();
        run(&mut again, 230.0, &around, |c| {
            ids2.extend(c.truth().iter().map(|p| p.id))
        });
        assert_eq!(ids, ids2);
    }

    /// A flow between two segments, all its arrivals pairs: each pair starts on the entry
    /// segment, walks abreast at the pair's spacing (neither avoiding the other), at one
    /// speed, and leaves on the exit segment.
    #[test]
    fn pairs_walk_abreast_from_segment_to_segment() {
        let flow = FlowConfig {
            name: "f".into(),
            from: [0.0, -3.0],
            to: [12.0, -3.0],
            via: vec![],
            rate: 12.0,
            spread: 0.0,
            from_end: Some([0.0, 3.0]),
            to_end: Some([12.0, 3.0]),
            start_time: 0.0,
            end_time: 60.0,
            max: 40,
            speed: 1.2,
            speed_std: 0.2,
        };
        let config = CrowdConfig {
            pair_fraction: 1.0,
            pair_spacing: 0.8,
            ..CrowdConfig::default()
        };
        let mut c = Crowd::new(&[], &[flow], config, 5);
        let around = Surroundings {
            robot: None,
            nearest_obstacle: &open,
        };
        let (mut starts, mut gaps, mut seen) = (Vec::new(), Vec::new(), 0usize);
        run(&mut c, 90.0, &around, |c| {
            for i in 0..c.slots() {
                let Some(j) = c.companion(i) else { continue };
                let (a, b) = (&c.walkers[i], &c.walkers[j]);
                if a.id > b.id {
                    continue;
                }
                seen = seen.max(b.id as usize + 1);
                assert_eq!(a.speed, b.speed, "a pair shares its speed");
                if a.p[0] < 0.05 {
                    starts.push(a.p);
                }
                if (3.0..9.0).contains(&a.p[0]) {
                    gaps.push(norm(a.p[0] - b.p[0], a.p[1] - b.p[1]));
                }
            }
        });
        // 12 arrivals a minute for 60 s: about 12 pairs (Poisson: ±3σ = ±10.4), every one a
        // pair, so 24 people seen in pairs.
        assert!((4..=46).contains(&seen) && seen % 2 == 0, "{seen} people");
        assert!(starts.iter().all(|p| p[1].abs() <= 3.0 + 0.4 + 1e-9));
        let ys: Vec<f64> = starts.iter().map(|p| p[1]).collect();
        let spread = ys.iter().cloned().fold(f64::MIN, f64::max)
            - ys.iter().cloned().fold(f64::MAX, f64::min);
        assert!(
            spread > 2.0,
            "starts along the segment, not at a point: {ys:?}"
        );
        gaps.sort_by(f64::total_cmp);
        let median = gaps[gaps.len() / 2];
        assert!(
            (median - 0.8).abs() < 0.1,
            "abreast at 0.8 m: median {median}"
        );
        assert!(
            gaps[gaps.len() * 9 / 10] < 1.2,
            "kept together: {:?}",
            &gaps[gaps.len() * 9 / 10..]
        );
        assert!(c.truth().is_empty(), "all left at the exit segment");
    }

    /// One arrival (a pair when `pair_fraction` is 1) down a 2 km lane, stopping once per
    /// 10 s walked for 5 s on average.
    fn stopping_flow(pair_fraction: f64) -> (Crowd, Surroundings<'static>) {
        let flow = FlowConfig {
            name: "f".into(),
            from: [0.0, 0.0],
            to: [2000.0, 0.0],
            via: vec![],
            rate: 1e-3,
            spread: 0.0,
            from_end: None,
            to_end: None,
            start_time: 0.0,
            end_time: 1.0,
            max: 2,
            speed: 1.2,
            speed_std: 0.0,
        };
        let config = CrowdConfig {
            stop_rate: 0.1,
            stop_time: 5.0,
            pair_fraction,
            ..CrowdConfig::default()
        };
        let mut c = Crowd::new(&[], &[flow], config, 7);
        // The one arrival, due in the first second, brought in now.
        c.arrivals[0].next = 0.0;
        let around = Surroundings {
            robot: None,
            nearest_obstacle: &open,
        };
        (c, around)
    }

    /// A walker standing a share of their time that follows from the stops' rate and length:
    /// a stop of mean T = 5 s per 1/λ = 10 s walked. With τ = 0.5 s, the speed falls below
    /// 0.2 m/s τ·ln(1.2/0.2) = 0.90 s into a stop and rises past it τ·ln(1.2/1.0) = 0.09 s
    /// after, so (T − 0.81) / (1/λ + T) = 0.279 of the time reads as standing.
    #[test]
    fn a_flow_walker_stops_as_often_and_as_long_as_asked() {
        let (mut c, around) = stopping_flow(0.0);
        let (mut standing, mut samples, mut spells, mut was) = (0usize, 0usize, 0usize, false);
        run(&mut c, 1200.0, &around, |c| {
            let Some(w) = c.walkers.iter().find(|w| w.active) else {
                return;
            };
            samples += 1;
            let now = norm(w.v[0], w.v[1]) < 0.2;
            standing += usize::from(now);
            spells += usize::from(now && !was);
            was = now;
        });
        let share = standing as f64 / samples as f64;
        // About 80 stops in 1,200 s: the share's spread from the stops' exponential lengths
        // and Poisson count is about 0.03; 0.1 is more than three of it.
        assert!((share - 0.279).abs() < 0.1, "standing {share}");
        assert!((50..=120).contains(&spells), "{spells} stops");
    }

    #[test]
    fn a_pair_stops_and_walks_on_together() {
        let (mut c, around) = stopping_flow(1.0);
        let (mut both, mut one) = (0usize, 0usize);
        run(&mut c, 600.0, &around, |c| {
            let w: Vec<&Walker> = c.walkers.iter().filter(|w| w.active).collect();
            if let [a, b] = w[..] {
                let (sa, sb) = (a.stand_until, b.stand_until);
                assert_eq!(sa, sb, "the companions' stops end together");
                let standing = |w: &Walker| norm(w.v[0], w.v[1]) < 0.2;
                both += usize::from(standing(a) && standing(b));
                one += usize::from(standing(a) != standing(b));
            }
        });
        assert!(both > 1000, "the pair stood together {both} steps");
        assert!(
            one * 20 < both,
            "one stood while the other walked {one} steps"
        );
    }

    #[test]
    fn bad_people_and_flows_are_refused_by_key() {
        let p = Path::new("s.toml");
        let mut a = person("a", vec![[0.0, 0.0]], 1.0);
        a.validate(p, "person[0]").unwrap();
        a.route.clear();
        assert_eq!(
            a.validate(p, "person[0]").unwrap_err().key,
            "person[0].route"
        );
        let mut a = person("a", vec![[0.0, 1e300]], 1.0);
        assert_eq!(
            a.validate(p, "person[0]").unwrap_err().key,
            "person[0].route[0]"
        );
        a.route[0][1] = 0.0;
        a.speed = Some(f64::NAN);
        assert_eq!(
            a.validate(p, "person[0]").unwrap_err().key,
            "person[0].speed"
        );
        let f = FlowConfig {
            name: "f".into(),
            from: [0.0, 0.0],
            to: [1.0, 0.0],
            via: vec![],
            rate: 0.0,
            spread: 0.5,
            from_end: None,
            to_end: None,
            start_time: 0.0,
            end_time: 1.0,
            max: 1,
            speed: 1.2,
            speed_std: 0.2,
        };
        assert_eq!(f.validate(p, "flow[0]").unwrap_err().key, "flow[0].rate");
        let mut c = CrowdConfig::default();
        c.validate(p).unwrap();
        c.height = 1.0;
        assert_eq!(c.validate(p).unwrap_err().key, "crowd.height");
    }
}
