//! What a laser's readings suffer besides the hit's Gaussian noise: the other terms of the beam
//! model mixture (Thrun, Burgard and Fox, *Probabilistic Robotics*, 2005, §6.3) and mixed
//! pixels, as a robot profile (`futago calibrate`) measures them on a real laser.
//!
//! - **Short readings**: with probability `short_rate` a beam returns from something before the
//!   surface (a person, a chair leg, dust), at a range drawn from an exponential of rate
//!   `short_lambda` cut at the surface.
//! - **Random readings**: with probability `random_rate`, anywhere between the range limits
//!   (specular bounces, crosstalk); or, where `random_excess` is given, beyond the surface by
//!   a distance drawn from those quantiles (see-through, a bounce to the next wall), as a
//!   profile measures the real laser's long readings.
//! - **No return by range**: the probability that a beam whose surface lies in a range bin
//!   returns nothing, on top of the laser's constant `dropout` (dark or far surfaces).
//! - **Mixed pixels**: where neighbouring beams' surfaces lie more than `edge_step` apart, the
//!   far one reads, with probability `mixed_pixels`, between the two surfaces (a footprint
//!   that straddles the edge).
//! - **Quadrature**: the hit's σ grows as `√(sigma² + (sigma_rel·r)²)` instead of the larger
//!   of the two terms, as a profile fits it.
//!
//! All are off by default, and a term draws random numbers only when it is on, so that a
//! scenario without them keeps its bytes.

use crate::config::{SpecError, check_range};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// A no-return probability for surfaces between `lo` and `hi` m.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RangeProbability {
    pub lo: f64,
    pub hi: f64,
    pub p: f64,
}

/// A laser's beam errors beyond the hit's noise (see the module documentation).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct BeamErrors {
    pub quadrature: bool,
    pub short_rate: f64,
    /// 1/m.
    pub short_lambda: f64,
    pub random_rate: f64,
    /// Quantiles at 0, 1/N, …, 1 (N = length − 1) of how far beyond the surface a random
    /// reading lies, m (non-decreasing, at least two); empty: uniform over the range.
    pub random_excess: Vec<f64>,
    pub no_return_by_range: Vec<RangeProbability>,
    pub mixed_pixels: f64,
    /// m.
    pub edge_step: f64,
}

impl Default for BeamErrors {
    fn default() -> Self {
        BeamErrors {
            quadrature: false,
            short_rate: 0.0,
            short_lambda: 1.0,
            random_rate: 0.0,
            random_excess: Vec::new(),
            no_return_by_range: Vec::new(),
            mixed_pixels: 0.0,
            edge_step: 0.5,
        }
    }
}

/// What a reading became.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Reading {
    /// The surface, with the hit's noise (m), or nothing where no surface is within range.
    Surface(Option<f64>),
    /// A short or random reading: something that is not the surface, m.
    Phantom(f64),
    /// No return.
    Lost,
}

impl BeamErrors {
    /// Checks ranges; `key` locates this table in `file`.
    pub fn validate(&self, file: &Path, key: &str) -> Result<(), SpecError> {
        let k = |s: &str| format!("{key}.{s}");
        let p = "(a probability)";
        check_range(file, &k("short_rate"), self.short_rate, 0.0, 1.0, p)?;
        check_range(
            file,
            &k("short_lambda"),
            self.short_lambda,
            1e-3,
            1e3,
            "1/m",
        )?;
        check_range(file, &k("random_rate"), self.random_rate, 0.0, 1.0, p)?;
        if self.random_excess.len() == 1 {
            return Err(SpecError::new(
                file,
                k("random_excess"),
                "expected no quantiles or at least two (0 and 1), found one".to_string(),
            ));
        }
        for (i, q) in self.random_excess.iter().enumerate() {
            let below = if i == 0 {
                0.0
            } else {
                self.random_excess[i - 1]
            };
            check_range(
                file,
                &k(&format!("random_excess[{i}]")),
                *q,
                below,
                1e4,
                "m, non-decreasing",
            )?;
        }
        check_range(file, &k("mixed_pixels"), self.mixed_pixels, 0.0, 1.0, p)?;
        check_range(file, &k("edge_step"), self.edge_step, 0.01, 100.0, "m")?;
        if self.short_rate + self.random_rate > 1.0 {
            return Err(SpecError::new(
                file,
                k("random_rate"),
                format!(
                    "expected short_rate + random_rate ≤ 1, found {} + {}",
                    self.short_rate, self.random_rate
                ),
            ));
        }
        for (i, b) in self.no_return_by_range.iter().enumerate() {
            let kb = k(&format!("no_return_by_range[{i}]"));
            check_range(file, &format!("{kb}.p"), b.p, 0.0, 1.0, p)?;
            check_range(file, &format!("{kb}.lo"), b.lo, 0.0, 1e4, "m")?;
            check_range(file, &format!("{kb}.hi"), b.hi, b.lo, 1e4, "m (above lo)")?;
        }
        Ok(())
    }

    /// The hit's standard deviation at range `r` for a laser of `sigma` and `sigma_rel`.
    pub fn sigma(&self, sigma: f64, sigma_rel: f64, r: f64) -> f64 {
        if self.quadrature {
            sigma.hypot(sigma_rel * r)
        } else {
            sigma.max(sigma_rel * r)
        }
    }

    /// The no-return probability of a surface at `r` from the table (0 outside it).
    fn no_return(&self, r: f64) -> f64 {
        self.no_return_by_range
            .iter()
            .find(|b| r >= b.lo && r < b.hi)
            .map_or(0.0, |b| b.p)
    }

    /// The terms of one beam, after its hit noise: `surface` is the true range of the surface
    /// (none within `range_max`) and `noisy` the reading the hit's noise made of it. Draws from
    /// `rng` only for the terms that are on.
    pub fn apply(
        &self,
        surface: Option<f64>,
        noisy: Option<f64>,
        range_min: f64,
        range_max: f64,
        rng: &mut ChaCha8Rng,
    ) -> Reading {
        if !self.no_return_by_range.is_empty()
            && let Some(d) = surface
            && rng.random::<f64>() < self.no_return(d)
        {
            return Reading::Lost;
        }
        if self.short_rate > 0.0 || self.random_rate > 0.0 {
            let u: f64 = rng.random();
            if u < self.short_rate {
                // Exponential of rate λ cut at the surface (or the range limit), by inversion.
                let cut = surface.unwrap_or(range_max).max(range_min);
                let lambda = self.short_lambda;
                let q: f64 = rng.random();
                let span = 1.0 - (-lambda * (cut - range_min)).exp();
                return Reading::Phantom(range_min - (1.0 - q * span).ln() / lambda);
            }
            if u < self.short_rate + self.random_rate {
                return match (surface, self.random_excess.len()) {
                    (Some(d), 2..) => {
                        let r = d + quantile(&self.random_excess, rng.random());
                        if r <= range_max {
                            Reading::Phantom(r)
                        } else {
                            Reading::Lost
                        }
                    }
                    _ => Reading::Phantom(rng.random_range(range_min..=range_max)),
                };
            }
        }
        Reading::Surface(noisy)
    }

    /// Mixed pixels over a finished scan: `surfaces` are the beams' true ranges and `ranges`
    /// the readings, changed in place. Where two neighbours' surfaces lie more than
    /// `edge_step` apart, the beam on the far surface reads, with probability `mixed_pixels`,
    /// uniformly between the two. Draws only when `mixed_pixels` is on, one number per edge.
    pub fn mix_edges(&self, surfaces: &[Option<f64>], ranges: &mut [f32], rng: &mut ChaCha8Rng) {
        if self.mixed_pixels <= 0.0 {
            return;
        }
        for k in 1..surfaces.len().min(ranges.len()) {
            let (Some(a), Some(b)) = (surfaces[k - 1], surfaces[k]) else {
                continue;
            };
            if (a - b).abs() <= self.edge_step {
                continue;
            }
            let u: f64 = rng.random();
            if u < self.mixed_pixels {
                let (near, far) = (a.min(b), a.max(b));
                let f = u / self.mixed_pixels;
                let far_beam = if a > b { k - 1 } else { k };
                ranges[far_beam] = (near + f * (far - near)) as f32;
            }
        }
    }

    /// Whether every term is off (the laser is as it was without them).
    pub fn is_off(&self) -> bool {
        !self.quadrature
            && self.short_rate == 0.0
            && self.random_rate == 0.0
            && self.no_return_by_range.is_empty()
            && self.mixed_pixels == 0.0
    }
}

/// The value at `q` ∈ [0, 1] of a distribution given by its quantiles at 0, 1/N, …, 1 (at
/// least two), linear between them.
fn quantile(qs: &[f64], q: f64) -> f64 {
    let at = q.clamp(0.0, 1.0) * (qs.len() - 1) as f64;
    let lo = (at.floor() as usize).min(qs.len() - 2);
    qs[lo] + (at - lo as f64) * (qs[lo + 1] - qs[lo])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::noise::stream;

    #[test]
    fn shares_of_short_random_and_lost_readings_follow_the_rates() {
        let e = BeamErrors {
            short_rate: 0.1,
            short_lambda: 2.0,
            random_rate: 0.05,
            no_return_by_range: vec![RangeProbability {
                lo: 4.0,
                hi: 6.0,
                p: 0.2,
            }],
            ..Default::default()
        };
        let mut rng = stream(1, "beam");
        let n = 100_000;
        let (mut short, mut random, mut lost) = (0, 0, 0);
        let mut short_sum = 0.0;
        for _ in 0..n {
            match e.apply(Some(5.0), Some(5.0), 0.1, 30.0, &mut rng) {
                Reading::Lost => lost += 1,
                Reading::Phantom(r) if r <= 5.0 => {
                    // Short readings lie before the surface; random ones anywhere.
                    short += 1;
                    short_sum += r;
                }
                Reading::Phantom(_) => random += 1,
                Reading::Surface(_) => {}
            }
        }
        let kept = (n - lost) as f64;
        // 20 % lost at 5 m; of the rest, 10 % short and 5 % random (a sixth of which also
        // falls before 5 m: 0.05 × 4.9/29.9 counts as short here).
        assert!((lost as f64 / n as f64 - 0.2).abs() < 0.005, "{lost}");
        let random_before = 0.05 * 4.9 / 29.9;
        assert!(
            (short as f64 / kept - (0.1 + random_before)).abs() < 0.005,
            "{short}"
        );
        assert!(
            (random as f64 / kept - (0.05 - random_before)).abs() < 0.005,
            "{random}"
        );
        // The mean of an exponential of rate 2 from 0.1 cut at 5 m is about 0.1 + 0.5.
        let mean = short_sum / short as f64;
        assert!(mean > 0.5 && mean < 1.2, "{mean}");
    }

    #[test]
    fn random_readings_with_an_excess_lie_beyond_the_surface_as_its_quantiles_say() {
        // Excess uniform over 1–3 m (quantiles every quarter), surface at 5 m, limit 7.5 m.
        let e = BeamErrors {
            random_rate: 1.0,
            random_excess: vec![1.0, 1.5, 2.0, 2.5, 3.0],
            ..Default::default()
        };
        let mut rng = stream(4, "beam");
        let mut beyond = Vec::new();
        let mut lost = 0;
        for _ in 0..20_000 {
            match e.apply(Some(5.0), Some(5.0), 0.1, 7.5, &mut rng) {
                Reading::Phantom(r) => beyond.push(r - 5.0),
                Reading::Lost => lost += 1,
                Reading::Surface(_) => panic!("every reading is random"),
            }
        }
        assert!(beyond.iter().all(|x| (1.0..=2.5).contains(x)));
        // Beyond the range limit (an excess over 2.5 m, a quarter) there is no return.
        assert!((lost as f64 / 20_000.0 - 0.25).abs() < 0.01, "{lost}");
        let mean = beyond.iter().sum::<f64>() / beyond.len() as f64;
        assert!((mean - 1.75).abs() < 0.01, "{mean}");
        // Without a surface the reading is anywhere in the range, as without quantiles.
        let anywhere: Vec<f64> = (0..2_000)
            .filter_map(|_| match e.apply(None, None, 0.1, 7.5, &mut rng) {
                Reading::Phantom(r) => Some(r),
                _ => None,
            })
            .collect();
        assert_eq!(anywhere.len(), 2_000);
        assert!(anywhere.iter().any(|r| *r < 1.0));
        let bad = BeamErrors {
            random_excess: vec![2.0, 1.0],
            ..Default::default()
        };
        let err = bad.validate(Path::new("w.toml"), "laser").unwrap_err();
        assert!(err.to_string().contains("laser.random_excess[1]"), "{err}");
    }

    #[test]
    fn off_terms_draw_nothing() {
        let e = BeamErrors::default();
        assert!(e.is_off());
        let mut a = stream(2, "beam");
        let b = a.clone();
        assert_eq!(
            e.apply(Some(3.0), Some(3.01), 0.1, 30.0, &mut a),
            Reading::Surface(Some(3.01))
        );
        let mut ranges = vec![1.0f32, 5.0];
        e.mix_edges(&[Some(1.0), Some(5.0)], &mut ranges, &mut a);
        assert_eq!(a, b, "the stream did not move");
        assert_eq!(ranges, vec![1.0, 5.0]);
    }

    #[test]
    fn mixed_pixels_fall_between_the_surfaces_on_the_far_beam() {
        let e = BeamErrors {
            mixed_pixels: 1.0,
            ..Default::default()
        };
        let mut rng = stream(3, "beam");
        let mut ranges = vec![1.0f32, 1.0, 4.0, 4.0];
        let surfaces = [Some(1.0), Some(1.0), Some(4.0), Some(4.0)];
        e.mix_edges(&surfaces, &mut ranges, &mut rng);
        assert_eq!(&ranges[..2], &[1.0, 1.0]);
        assert!(ranges[2] > 1.0 && ranges[2] < 4.0, "{ranges:?}");
        assert_eq!(ranges[3], 4.0);
    }

    #[test]
    fn quadrature_adds_the_terms_as_variances() {
        let q = BeamErrors {
            quadrature: true,
            ..Default::default()
        };
        assert!((q.sigma(0.03, 0.01, 4.0) - 0.05).abs() < 1e-12);
        assert!((BeamErrors::default().sigma(0.03, 0.01, 4.0) - 0.04).abs() < 1e-12);
    }
}
