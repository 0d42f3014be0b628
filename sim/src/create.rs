//! The iRobot Create (first generation): its drive firmware, its wheels' grip on the floor and
//! its wheel-encoder odometry.
//!
//! Figures are those of `shared/reference/sensors-robot-metrics.md` §4.3: wheel base 0.258 m
//! (libcreate), wheel radius 36 mm and mass 3.5 kg (create_description), body radius 0.165 m,
//! ±0.5 m/s and ±2 m turning radius (Open Interface).
//!
//! **Wheels.** The firmware turns a Drive command into wheel speeds with its *nominal*
//! geometry and ramps them at `max_wheel_accel` (both wheels in proportion, keeping the radius). The wheels turn at those speeds (their servos
//! are stiff); the floor pushes the body through a friction-limited contact under each drive
//! wheel (a velocity-level Coulomb model, solved like a rigid-body friction constraint), so a
//! blocked robot spins its wheels and the encoders count travel that never happened.
//!
//! **Odometry errors** (Borenstein's UMBmark): the *actual* wheels differ from the nominal ones
//! by the diameter ratio `E_d = D_R/D_L` (mean diameter kept) and the actual wheel base is
//! `E_b` times the nominal one. The firmware integrates encoder ticks with the nominal figures,
//! so the robot believes it drove what it commanded. Random error is added per encoder
//! increment with variance `noise² · |Δs|`.

use crate::config::{SpecError, check_range};
use futago_msgs::{DriveCommand, Odometry, Radius, Time};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::Deserialize;
use std::path::Path;

/// Standard gravity, m/s².
pub const GRAVITY: f64 = 9.81;

/// Physical and firmware parameters of the Create.
#[derive(Debug, Clone, Deserialize, serde::Serialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct CreateConfig {
    /// Total mass, kg.
    pub mass: f64,
    /// Body radius, m.
    pub radius: f64,
    /// Height of the collision body including what it carries (laser, camera), m.
    pub height: f64,
    /// Gap between floor and body, m.
    pub clearance: f64,
    /// Nominal distance between the drive wheels' contact points, m.
    pub wheel_base: f64,
    /// Nominal wheel radius, m.
    pub wheel_radius: f64,
    /// Largest wheel speed the firmware commands, m/s.
    pub max_speed: f64,
    /// Wheel speed ramp of the firmware, m/s².
    pub max_wheel_accel: f64,
    /// Wheel–floor friction coefficient.
    pub wheel_friction: f64,
    /// Share of the weight on the two drive wheels (the rest is on the caster).
    pub drive_load_fraction: f64,
    /// How far a wheel can drop before its wheel-drop switch opens, m.
    pub wheel_drop_travel: f64,
    /// Period of the Create's sensor stream (odometry, bumpers, wheel drops), s. The OI
    /// streams every 15 ms.
    pub stream_period: f64,
    pub odometry: OdometryModel,
}

impl Default for CreateConfig {
    fn default() -> Self {
        CreateConfig {
            mass: 3.5,
            radius: 0.165,
            height: 0.35,
            clearance: 0.01,
            wheel_base: 0.258,
            wheel_radius: 0.036,
            max_speed: 0.5,
            max_wheel_accel: 1.8,
            wheel_friction: 0.8,
            drive_load_fraction: 0.85,
            wheel_drop_travel: 0.02,
            stream_period: 0.015,
            odometry: OdometryModel::default(),
        }
    }
}

/// The error model of the wheel odometry.
#[derive(Debug, Clone, Deserialize, serde::Serialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct OdometryModel {
    /// `E_d`: actual right wheel diameter over actual left wheel diameter.
    pub wheel_diameter_ratio: f64,
    /// `E_b`: actual wheel base over nominal wheel base.
    pub wheel_base_ratio: f64,
    /// Random encoder error: standard deviation of one wheel's travel per √m travelled.
    pub noise: f64,
    /// Report integer millimetres and degrees as the Create does (remainders carried over).
    pub quantize: bool,
}

impl Default for OdometryModel {
    fn default() -> Self {
        OdometryModel {
            wheel_diameter_ratio: 1.0,
            wheel_base_ratio: 1.0,
            noise: 0.0,
            quantize: true,
        }
    }
}

impl CreateConfig {
    /// Checks ranges; `key` is where this table sits in `file` (e.g. `robot`).
    pub fn validate(&self, file: &Path, key: &str) -> Result<(), SpecError> {
        let o = &self.odometry;
        let limits: [(&str, f64, f64, f64, &str); 15] = [
            ("mass", self.mass, 0.1, 1000.0, "kg"),
            ("radius", self.radius, 0.02, 5.0, "m"),
            ("height", self.height, 0.01, 5.0, "m"),
            ("clearance", self.clearance, 0.0, 0.5, "m"),
            (
                "wheel_base",
                self.wheel_base,
                0.01,
                2.0 * self.radius,
                "m (at most the body diameter)",
            ),
            ("wheel_radius", self.wheel_radius, 0.005, 1.0, "m"),
            ("max_speed", self.max_speed, 0.01, 10.0, "m/s"),
            ("max_wheel_accel", self.max_wheel_accel, 0.01, 100.0, "m/s²"),
            ("wheel_friction", self.wheel_friction, 0.01, 5.0, ""),
            (
                "drive_load_fraction",
                self.drive_load_fraction,
                0.05,
                1.0,
                "",
            ),
            ("wheel_drop_travel", self.wheel_drop_travel, 0.001, 0.5, "m"),
            ("stream_period", self.stream_period, 0.001, 10.0, "s"),
            (
                "odometry.wheel_diameter_ratio",
                o.wheel_diameter_ratio,
                0.5,
                2.0,
                "",
            ),
            (
                "odometry.wheel_base_ratio",
                o.wheel_base_ratio,
                0.5,
                2.0,
                "",
            ),
            ("odometry.noise", o.noise, 0.0, 1.0, "m/√m"),
        ];
        for (name, value, lo, hi, unit) in limits {
            check_range(file, &format!("{key}.{name}"), value, lo, hi, unit)?;
        }
        Ok(())
    }

    /// Actual (left, right) wheel radii from the nominal radius and `E_d`.
    pub fn actual_wheel_radii(&self) -> (f64, f64) {
        let ed = self.odometry.wheel_diameter_ratio;
        (
            self.wheel_radius * 2.0 / (ed + 1.0),
            self.wheel_radius * 2.0 * ed / (ed + 1.0),
        )
    }

    /// Actual wheel base.
    pub fn actual_wheel_base(&self) -> f64 {
        self.wheel_base * self.odometry.wheel_base_ratio
    }

    /// The firmware's (left, right) wheel speed targets for a command, m/s, in nominal terms.
    ///
    /// Drive: the centre moves at `velocity` on a circle of `radius`; if a wheel would exceed
    /// `max_speed`, both are scaled down keeping the radius. Turn in place: each wheel at
    /// `velocity`. Radii beyond ±2 m are clamped to ±2 m, as the OI's range is.
    pub fn wheel_targets(&self, cmd: &DriveCommand) -> (f64, f64) {
        let vmax = self.max_speed;
        let b = self.wheel_base;
        let (l, r) = match *cmd {
            DriveCommand::DriveDirect { left, right } => (left, right),
            DriveCommand::Drive { velocity, radius } => {
                let v = velocity.clamp(-vmax, vmax);
                match radius {
                    Radius::Straight => (v, v),
                    Radius::InPlaceCcw => (-v, v),
                    Radius::InPlaceCw => (v, -v),
                    Radius::Arc(rad) => {
                        let rad = if rad.abs() < 1e-3 {
                            1e-3f64.copysign(rad)
                        } else {
                            rad.clamp(-2.0, 2.0)
                        };
                        (v * (rad - b / 2.0) / rad, v * (rad + b / 2.0) / rad)
                    }
                }
            }
        };
        let (l, r) = (
            if l.is_finite() { l } else { 0.0 },
            if r.is_finite() { r } else { 0.0 },
        );
        let m = l.abs().max(r.abs());
        if m > vmax {
            (l * vmax / m, r * vmax / m)
        } else {
            (l, r)
        }
    }
}

/// Velocity of a planar body in its own frame: forward, left, yaw rate.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PlanarVelocity {
    pub forward: f64,
    pub lateral: f64,
    pub yaw_rate: f64,
}

/// Friction-limited wheel–floor contact, solved at velocity level over one time step.
///
/// Each drive wheel touches the floor at `(0, ±base/2)`. Its contact point should move at the
/// wheel's rim speed along the wheel and not at all sideways; the floor can push it with at
/// most `μ·N` (impulse `μ·N·dt`), split between the two directions inside the friction disc.
/// Projected Gauss–Seidel over the four rows with accumulated, clamped impulses — the scheme of
/// rigid-body friction solvers. Returns the body velocity after the wheels have acted; the
/// caster is a free swivel and takes no load sideways.
#[allow(clippy::too_many_arguments)]
pub fn wheel_traction(
    v: PlanarVelocity,
    mass: f64,
    yaw_inertia: f64,
    base: f64,
    rim: (f64, f64),
    loads: (f64, f64),
    mu: f64,
    dt: f64,
) -> PlanarVelocity {
    let mut v = v;
    let ys = [base / 2.0, -base / 2.0];
    let rims = [rim.0, rim.1];
    let limits = [mu * loads.0 * dt, mu * loads.1 * dt];
    let mut acc = [[0.0f64; 2]; 2]; // [wheel][long, lat]
    let k_long: Vec<f64> = ys
        .iter()
        .map(|y| 1.0 / (1.0 / mass + y * y / yaw_inertia))
        .collect();
    for _ in 0..12 {
        for w in 0..2 {
            if limits[w] <= 0.0 {
                continue;
            }
            let y = ys[w];
            // Longitudinal row: contact point speed along the wheel is forward − ω·y.
            let err_long = rims[w] - (v.forward - v.yaw_rate * y);
            let err_lat = -v.lateral;
            let want = [acc[w][0] + err_long * k_long[w], acc[w][1] + err_lat * mass];
            let n = (want[0] * want[0] + want[1] * want[1]).sqrt();
            let clamped = if n > limits[w] {
                [want[0] * limits[w] / n, want[1] * limits[w] / n]
            } else {
                want
            };
            let d = [clamped[0] - acc[w][0], clamped[1] - acc[w][1]];
            acc[w] = clamped;
            v.forward += d[0] / mass;
            v.yaw_rate += -y * d[0] / yaw_inertia;
            v.lateral += d[1] / mass;
        }
    }
    v
}

/// The Create's wheels, firmware and encoders: everything of the robot but its rigid body.
#[derive(Debug, Clone)]
pub struct CreateDrive {
    pub config: CreateConfig,
    /// Current nominal wheel speeds (left, right), m/s, after the ramp.
    pub wheel_speed: (f64, f64),
    target: (f64, f64),
    /// Travel accumulated since the last odometry report (distance m, angle rad), unquantised.
    pending: (f64, f64),
    encoder_rng: [ChaCha8Rng; 2],
}

impl CreateDrive {
    /// A stopped drive; `encoder_rng` are the left and right encoder noise streams.
    pub fn new(config: CreateConfig, encoder_rng: [ChaCha8Rng; 2]) -> CreateDrive {
        CreateDrive {
            config,
            wheel_speed: (0.0, 0.0),
            target: (0.0, 0.0),
            pending: (0.0, 0.0),
            encoder_rng,
        }
    }

    /// Takes a new command (it holds until the next one, as on the real robot).
    pub fn command(&mut self, cmd: &DriveCommand) {
        self.target = self.config.wheel_targets(cmd);
    }

    /// Advances the firmware by `dt`: ramps the wheels (stops them at once if a wheel dropped,
    /// as the Create does), integrates the encoders. Returns the *actual* rim speeds
    /// (left, right) of the wheels for the traction model.
    pub fn advance(&mut self, dt: f64, wheel_dropped: bool) -> (f64, f64) {
        if wheel_dropped {
            self.target = (0.0, 0.0);
            self.wheel_speed = (0.0, 0.0);
        }
        // Both wheels ramp together, the one with further to go at the limit, so that the
        // turning radius holds while speeding up or slowing down.
        let a = self.config.max_wheel_accel * dt;
        let (dl, dr) = (
            self.target.0 - self.wheel_speed.0,
            self.target.1 - self.wheel_speed.1,
        );
        let m = dl.abs().max(dr.abs());
        let k = if m > a { a / m } else { 1.0 };
        self.wheel_speed = (self.wheel_speed.0 + dl * k, self.wheel_speed.1 + dr * k);
        // Encoders: wheel angle × nominal radius, plus random error.
        let sigma = self.config.odometry.noise;
        let mut travel = [self.wheel_speed.0 * dt, self.wheel_speed.1 * dt];
        if sigma > 0.0 {
            for (s, rng) in travel.iter_mut().zip(self.encoder_rng.iter_mut()) {
                let sd = sigma * s.abs().sqrt();
                if sd > 0.0 {
                    *s += Normal::new(0.0, sd)
                        .expect("finite positive sd")
                        .sample(rng);
                }
            }
        } else {
            // Keep the streams' positions independent of whether noise is on.
            let _ = self.encoder_rng[0].random::<u32>();
            let _ = self.encoder_rng[1].random::<u32>();
        }
        self.pending.0 += (travel[0] + travel[1]) / 2.0;
        self.pending.1 += (travel[1] - travel[0]) / self.config.wheel_base;
        let (rl, rr) = self.config.actual_wheel_radii();
        let r = self.config.wheel_radius;
        (self.wheel_speed.0 / r * rl, self.wheel_speed.1 / r * rr)
    }

    /// The odometry report for a request at `stamp`: travel since the last one, quantised to
    /// whole millimetres and degrees (truncated toward zero) if configured; what is cut off
    /// stays for the next report.
    pub fn report(&mut self, stamp: Time) -> Odometry {
        let (d, a) = self.pending;
        let (qd, qa) = if self.config.odometry.quantize {
            (
                (d * 1000.0).trunc() / 1000.0,
                (a.to_degrees().trunc()).to_radians(),
            )
        } else {
            (d, a)
        };
        self.pending = (d - qd, a - qa);
        Odometry {
            stamp,
            distance: qd,
            angle: qa,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::noise::stream;

    fn drive(cfg: CreateConfig) -> CreateDrive {
        CreateDrive::new(cfg, [stream(0, "l"), stream(0, "r")])
    }

    #[test]
    fn drive_command_maps_to_wheel_speeds() {
        let c = CreateConfig::default();
        let (l, r) = c.wheel_targets(&DriveCommand::Drive {
            velocity: 0.2,
            radius: Radius::Arc(0.5),
        });
        assert!(((l + r) / 2.0 - 0.2).abs() < 1e-12);
        // ω = v/R = (r − l)/b.
        assert!(((r - l) / c.wheel_base - 0.4).abs() < 1e-12);
        let (l, r) = c.wheel_targets(&DriveCommand::Drive {
            velocity: 0.3,
            radius: Radius::InPlaceCw,
        });
        assert_eq!((l, r), (0.3, -0.3));
        // Over-speed is scaled down with the radius kept.
        let (l, r) = c.wheel_targets(&DriveCommand::Drive {
            velocity: 0.5,
            radius: Radius::Arc(0.2),
        });
        assert!((r - 0.5).abs() < 1e-12 && l > 0.0);
        assert!(((r - l) / c.wheel_base / ((l + r) / 2.0) - 1.0 / 0.2).abs() < 1e-9);
        let (l, r) = c.wheel_targets(&DriveCommand::DriveDirect {
            left: -3.0,
            right: 0.1,
        });
        assert_eq!((l, r), (-0.5, 0.5 * 0.1 / 3.0));
    }

    #[test]
    fn wheels_ramp_at_the_acceleration_limit() {
        let mut d = drive(CreateConfig::default());
        d.command(&DriveCommand::Drive {
            velocity: 0.5,
            radius: Radius::Straight,
        });
        let dt = 0.005;
        let mut t = 0.0;
        while d.wheel_speed.0 < 0.5 - 1e-12 {
            d.advance(dt, false);
            t += dt;
        }
        assert!((t - 0.5 / 1.8).abs() < dt + 1e-9, "{t}");
        d.advance(dt, true);
        assert_eq!(d.wheel_speed, (0.0, 0.0));
    }

    #[test]
    fn odometry_is_quantised_with_remainders_carried() {
        let run = |quantize: bool| {
            let mut cfg = CreateConfig::default();
            cfg.odometry.quantize = quantize;
            let mut d = drive(cfg);
            d.command(&DriveCommand::Drive {
                velocity: 0.03,
                radius: Radius::InPlaceCcw,
            });
            let mut reports = Vec::new();
            for k in 0..600 {
                d.advance(0.005, false);
                if k % 3 == 2 {
                    reports.push(d.report(Time::ZERO).angle);
                }
            }
            reports
        };
        let q = run(true);
        let exact: f64 = run(false).iter().sum();
        // Each report is a whole number of degrees, most of them 0 at this rate (< 0.5° per
        // report), yet the carried remainders keep the sum within 1° of the truth.
        assert!(
            q.iter()
                .all(|a| (a.to_degrees() - a.to_degrees().round()).abs() < 1e-9)
        );
        assert!(q.iter().filter(|a| **a == 0.0).count() > q.len() / 2);
        let sum: f64 = q.iter().sum();
        assert!(exact > 10f64.to_radians());
        assert!((sum - exact).abs() < 1f64.to_radians(), "{sum} vs {exact}");
    }

    #[test]
    fn traction_reaches_rim_speeds_when_grip_suffices_and_slips_when_not() {
        let m = 3.5;
        let i = 0.5 * m * 0.165 * 0.165;
        let loads = (m * GRAVITY * 0.425, m * GRAVITY * 0.425);
        let v = wheel_traction(
            PlanarVelocity::default(),
            m,
            i,
            0.258,
            (0.001, 0.003),
            loads,
            0.8,
            0.005,
        );
        assert!((v.forward - 0.002).abs() < 1e-6, "{v:?}");
        assert!((v.yaw_rate - 0.002 / 0.258).abs() < 1e-5);
        // A large step in rim speed cannot be met in one step: Δv ≤ μ·g·dt per unit mass.
        let v = wheel_traction(
            PlanarVelocity::default(),
            m,
            i,
            0.258,
            (0.5, 0.5),
            loads,
            0.8,
            0.005,
        );
        let dv_max = 0.8 * GRAVITY * 0.85 * 0.005;
        assert!(
            (v.forward - dv_max).abs() < 1e-6,
            "{} vs {dv_max}",
            v.forward
        );
        // Sideways motion is resisted.
        let v = wheel_traction(
            PlanarVelocity {
                lateral: 0.001,
                ..Default::default()
            },
            m,
            i,
            0.258,
            (0.0, 0.0),
            loads,
            0.8,
            0.005,
        );
        assert!(v.lateral.abs() < 1e-9);
    }
}
