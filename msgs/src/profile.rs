//! Robot profiles: the error models of a robot's laser and odometry, as `futago calibrate`
//! estimates them from a log of the real robot, in a file a simulated robot can take.
//!
//! The laser's model is the beam model mixture of Thrun, Burgard and Fox (*Probabilistic
//! Robotics*, 2005, §6.3): a reading is a hit on the mapped surface with Gaussian noise, a
//! short reading (something the map does not hold) at an exponentially distributed range, a
//! random reading anywhere in the range, or no return at all. Here the hit's spread grows with
//! range (`σ(r)² = sigma² + (sigma_rel·r)²`), and the no-return probability is tabulated
//! against the expected range and the incidence angle instead of being one constant. Mixed
//! pixels (readings between the near and the far surface where a beam straddles a depth
//! edge) are counted on their own.
//!
//! The odometry's model is Borenstein's UMBmark systematic terms (a translation scale, a
//! rotation scale, a heading bias per metre driven: unequal wheel diameters and a wrong wheel
//! base) plus a random walk whose variance grows with the distance driven and the angle
//! turned, and the share of outliers (stalls, slips) the random walk does not explain.
//!
//! Every estimate carries its standard error and the number of samples behind it, so that a
//! user can see what the log could and could not tell.

use serde::{Deserialize, Serialize};

/// A reading this far (m) beyond the surface the map predicts is a long reading.
pub const LONG_READING_M: f64 = 1.0;

/// The quantiles [`LaserProfile::long_excess_m`] holds: 0, 1/N, …, 1.
pub const LONG_EXCESS_QUANTILES: usize = 20;

/// A quantity estimated from data: its value, its standard error (0 where it was set, not
/// estimated) and how many samples it rests on.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Estimate {
    pub value: f64,
    pub sd: f64,
    pub n: usize,
}

impl Estimate {
    pub fn new(value: f64, sd: f64, n: usize) -> Estimate {
        Estimate { value, sd, n }
    }

    /// A proportion `k` of `n` with its binomial standard error (0 of 0 is 0 ± 0).
    pub fn proportion(k: usize, n: usize) -> Estimate {
        if n == 0 {
            return Estimate::new(0.0, 0.0, 0);
        }
        let p = k as f64 / n as f64;
        Estimate::new(p, (p * (1.0 - p) / n as f64).sqrt(), n)
    }
}

/// Residuals further than this from the surface are not the hit's spread (m), and neighbouring
/// beams whose surfaces lie further apart than this are on different surfaces (m), for
/// [`LaserProfile::neighbour_correlation`].
pub const NEIGHBOUR_CORE_M: f64 = 0.2;
pub const NEIGHBOUR_STEP_M: f64 = 0.1;

/// A value tabulated over a bin `[lo, hi)` of some variable (range in m, or angle in rad).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Bin {
    pub lo: f64,
    pub hi: f64,
    pub value: f64,
    pub sd: f64,
    pub n: usize,
}

/// Where a profile comes from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Source {
    /// The log, as it was named to `futago calibrate`.
    pub log: String,
    /// The stretch of the log used, s from its first scan.
    pub from_s: f64,
    pub to_s: f64,
    /// Scans in that stretch.
    pub scans: usize,
    /// What estimated it and against what (the reference trajectory and map).
    pub procedure: String,
}

/// A laser: its layout and timing as the log shows them, and its error model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LaserProfile {
    /// The laser's name (its frame in the log), so that a robot with several lasers knows
    /// which one this sets.
    pub name: String,
    pub beams: usize,
    /// First beam's bearing and the angle between beams, rad.
    pub angle_min: f64,
    pub angle_increment: f64,
    pub range_min: f64,
    pub range_max: f64,
    /// Scans per second (the median interval's inverse) and the interval's spread, s.
    pub rate: f64,
    pub period_spread_s: f64,
    /// Time between beams, s (0 where the log does not say).
    pub time_increment: f64,
    /// The hit's spread: `σ(r)² = sigma² + (sigma_rel·r)²`, m and m/m.
    pub sigma: Estimate,
    pub sigma_rel: Estimate,
    /// The hit's mean offset (measured minus expected), m: a range bias.
    pub bias: Estimate,
    /// Of the beams that return where the map holds a surface, the share that are short
    /// readings, and their exponential rate, 1/m.
    pub short_rate: Estimate,
    pub short_lambda: Estimate,
    /// Of the same, the share that are random readings (uniform over the range).
    pub random_rate: Estimate,
    /// Of the same, the share that read more than `LONG_READING_M` beyond the surface: the
    /// long tail (see-through, crosstalk), which sets the residuals' upper percentiles.
    pub long_readings: Estimate,
    /// How far beyond the surface the long readings lie, m: their quantiles at 0, 1/N, …, 1
    /// (N = [`LONG_EXCESS_QUANTILES`]); empty where the log has none. A simulated long reading
    /// lies this far beyond its surface, drawn from this distribution, instead of anywhere in
    /// the range (a profile without it draws over the range).
    #[serde(default)]
    pub long_excess_m: Vec<f64>,
    /// Of the beams that should hit a mapped surface, the share with no return, overall.
    pub no_return: Estimate,
    /// The same by expected range, m.
    pub no_return_by_range: Vec<Bin>,
    /// The same by incidence angle (between the beam and the surface's normal), rad.
    pub no_return_by_incidence: Vec<Bin>,
    /// Of the beams that straddle a depth edge (neighbours' expected ranges apart by more than
    /// the edge step), the share that read between the near and the far surface.
    pub mixed_pixels: Estimate,
    /// Of the beams where the map holds nothing within range, the share that return anyway
    /// (things the map does not hold: people, clutter).
    pub unmapped_returns: Estimate,
    /// The correlation of the range residuals of neighbouring beams on one surface (both hits
    /// within [`NEIGHBOUR_CORE_M`] of the surface, which lies within [`NEIGHBOUR_STEP_M`] at
    /// both): 0 where each beam errs on its own. Measured, not simulated: it says how far a
    /// model of independent beams is from the laser (a profile without it reads 0 ± 0).
    #[serde(default)]
    pub neighbour_correlation: Estimate,
    /// The hit's spread by expected range, net of the map's cells (what `sigma` and
    /// `sigma_rel` were fitted to), m.
    pub spread_by_range: Vec<Bin>,
}

/// Odometry's systematic and random errors, as the true motion relates to the reported.
///
/// Over a stretch of reported motion of length `L` (m) and turn `A` (rad, signed), the true
/// motion is the reported one with every step's translation times `translation_scale` and its
/// turn times `rotation_scale`, plus `heading_bias·L`; then a random walk of variance
/// `translation_variance·L` along the path and `heading_variance_per_rad·|A| +
/// heading_variance_per_m·L` in heading.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OdometryProfile {
    pub translation_scale: Estimate,
    pub rotation_scale: Estimate,
    /// rad/m, counter-clockwise positive.
    pub heading_bias: Estimate,
    /// m²/m.
    pub translation_variance: Estimate,
    /// rad²/rad.
    pub heading_variance_per_rad: Estimate,
    /// rad²/m.
    pub heading_variance_per_m: Estimate,
    /// Share of stretches the model misses by more than five of its deviations (a stall, a
    /// slip, a bump): the heavy tail.
    pub outlier_rate: Estimate,
    /// The outliers' root-mean-square error beyond the random walk: in position (m) and in
    /// heading (rad).
    pub outlier_translation: Estimate,
    pub outlier_heading: Estimate,
    /// The stretches the estimates rest on: their count, mean length (m) and mean turn
    /// (rad): the outlier rate is per such stretch.
    pub stretches: usize,
    pub stretch_length_m: f64,
    pub stretch_turn_rad: f64,
    /// The delay of the odometry's stamps behind the laser's, s: the shift that best lines
    /// up the odometry's turns with the scan matcher's (positive: odometry stamped late).
    pub latency: Estimate,
}

/// A robot profile: the file `futago calibrate` writes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotProfile {
    pub source: Source,
    pub laser: LaserProfile,
    /// None where the log has no odometry (a bag of scans alone) or too little motion.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub odometry: Option<OdometryProfile>,
}

impl RobotProfile {
    /// Checks that every value is one a simulator can use: shares in [0, 1], spreads,
    /// variances and rates finite and not negative, scales positive, a layout of beams. The
    /// error names the key and what was expected.
    pub fn validate(&self) -> Result<(), (String, String)> {
        let l = &self.laser;
        let mut checks: Vec<(String, f64, f64, f64)> = vec![
            ("laser.sigma.value".into(), l.sigma.value, 0.0, 10.0),
            ("laser.sigma_rel.value".into(), l.sigma_rel.value, 0.0, 1.0),
            (
                "laser.short_rate.value".into(),
                l.short_rate.value,
                0.0,
                1.0,
            ),
            (
                "laser.short_lambda.value".into(),
                l.short_lambda.value,
                0.0,
                1e3,
            ),
            (
                "laser.random_rate.value".into(),
                l.random_rate.value,
                0.0,
                1.0,
            ),
            (
                "laser.long_readings.value".into(),
                l.long_readings.value,
                0.0,
                1.0,
            ),
            ("laser.no_return.value".into(), l.no_return.value, 0.0, 1.0),
            (
                "laser.mixed_pixels.value".into(),
                l.mixed_pixels.value,
                0.0,
                1.0,
            ),
            ("laser.range_max".into(), l.range_max, 1e-3, 1e4),
            ("laser.range_min".into(), l.range_min, 0.0, l.range_max),
        ];
        for (i, q) in l.long_excess_m.iter().enumerate() {
            let below = if i == 0 { 0.0 } else { l.long_excess_m[i - 1] };
            checks.push((format!("laser.long_excess_m[{i}]"), *q, below, 1e4));
        }
        for (name, bins) in [
            ("no_return_by_range", &l.no_return_by_range),
            ("spread_by_range", &l.spread_by_range),
        ] {
            for (i, b) in bins.iter().enumerate() {
                let top = if name == "spread_by_range" { 10.0 } else { 1.0 };
                checks.push((format!("laser.{name}[{i}].value"), b.value, 0.0, top));
            }
        }
        if let Some(o) = &self.odometry {
            checks.extend([
                (
                    "odometry.translation_scale.value".into(),
                    o.translation_scale.value,
                    0.1,
                    10.0,
                ),
                (
                    "odometry.rotation_scale.value".into(),
                    o.rotation_scale.value,
                    0.1,
                    10.0,
                ),
                (
                    "odometry.heading_bias.value".into(),
                    o.heading_bias.value,
                    -10.0,
                    10.0,
                ),
                (
                    "odometry.translation_variance.value".into(),
                    o.translation_variance.value,
                    0.0,
                    100.0,
                ),
                (
                    "odometry.heading_variance_per_rad.value".into(),
                    o.heading_variance_per_rad.value,
                    0.0,
                    100.0,
                ),
                (
                    "odometry.heading_variance_per_m.value".into(),
                    o.heading_variance_per_m.value,
                    0.0,
                    100.0,
                ),
                (
                    "odometry.outlier_rate.value".into(),
                    o.outlier_rate.value,
                    0.0,
                    1.0,
                ),
                (
                    "odometry.outlier_translation.value".into(),
                    o.outlier_translation.value,
                    0.0,
                    100.0,
                ),
                (
                    "odometry.outlier_heading.value".into(),
                    o.outlier_heading.value,
                    0.0,
                    100.0,
                ),
                (
                    "odometry.stretch_length_m".into(),
                    o.stretch_length_m,
                    0.0,
                    1e4,
                ),
                (
                    "odometry.stretch_turn_rad".into(),
                    o.stretch_turn_rad,
                    0.0,
                    1e4,
                ),
            ]);
        }
        for (key, v, lo, hi) in checks {
            if !(v.is_finite() && v >= lo && v <= hi) {
                return Err((key, format!("expected a value in [{lo}, {hi}], found {v}")));
            }
        }
        if l.beams == 0 || !(l.angle_increment.is_finite() && l.angle_increment != 0.0) {
            return Err((
                "laser.beams".into(),
                "expected at least one beam and a finite, non-zero angle_increment".into(),
            ));
        }
        Ok(())
    }
}
