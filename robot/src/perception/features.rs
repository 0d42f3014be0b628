//! Image features for the RGBD-ICP feature term (seed 000 §3.1.2, step 1): FAST-9 corners
//! and 256-bit BRIEF descriptors from `imageproc`, matched by Hamming distance.
//!
//! The thesis uses SURF, which no maintained Rust crate offers; FAST + BRIEF is the pairing
//! ORB is built on (Rublee et al. 2011). ORB's orientation step is left out: the camera is
//! levelled and only turns about the vertical, so the image hardly rotates in its plane and
//! unrotated BRIEF matches better. BRIEF's test pairs are drawn here from a seeded stream (the
//! crate's own draw is unseeded), so descriptors are the same on every run.

use image::GrayImage;
use imageproc::binary_descriptors::brief::{TestPair, brief};
use imageproc::corners::corners_fast9;
use imageproc::point::Point;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

/// Side of BRIEF's patch, pixels (imageproc's, as in Calonder et al.).
const PATCH: u32 = 31;
/// Corners closer than this to the image's edge have no full patch.
const MARGIN: u32 = PATCH / 2 + 2;
/// Descriptor length, bits.
const BITS: usize = 256;

/// Parameters of the feature detector and matcher.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FeatureConfig {
    /// FAST-9 intensity threshold, grey levels.
    pub fast_threshold: u8,
    /// At most this many corners per image, the strongest one per `cell` × `cell` pixels.
    pub max_features: usize,
    /// Cell of the corner grid, pixels (spreads corners over the image).
    pub cell: u32,
    /// Matches farther apart than this are refused, bits of 256.
    pub max_hamming: u32,
}

impl FeatureConfig {
    /// Checks every field; the error names the key below `prefix`.
    pub fn validate(&self, prefix: &str) -> Result<(), crate::config::ConfigError> {
        crate::config::check_counts(
            prefix,
            &[
                ("max_features", self.max_features, 1, 100_000),
                ("cell", self.cell as usize, 1, 4096),
                ("max_hamming", self.max_hamming as usize, 0, 256),
            ],
        )
    }
}

impl Default for FeatureConfig {
    fn default() -> Self {
        FeatureConfig {
            fast_threshold: 20,
            max_features: 400,
            cell: 8,
            max_hamming: 40,
        }
    }
}

/// A 256-bit descriptor.
pub type Descriptor = [u128; 2];

/// Hamming distance between two descriptors.
pub fn hamming(a: &Descriptor, b: &Descriptor) -> u32 {
    (a[0] ^ b[0]).count_ones() + (a[1] ^ b[1]).count_ones()
}

/// A detector with its fixed BRIEF pattern.
pub struct Detector {
    config: FeatureConfig,
    pairs: Vec<TestPair>,
}

impl Detector {
    /// `seed` draws BRIEF's test pairs: isotropic Gaussian about the patch centre with
    /// σ = 6.6 px (Calonder et al.'s G II, as imageproc draws them).
    pub fn new(config: FeatureConfig, seed: u64) -> Detector {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let g = Normal::new(PATCH as f64 / 2.0, 6.6).expect("σ > 0");
        let mut pairs = Vec::with_capacity(BITS);
        let coordinate = |rng: &mut ChaCha8Rng| loop {
            let v = g.sample(rng);
            if (0.0..PATCH as f64).contains(&v) {
                return v as u32;
            }
        };
        while pairs.len() < BITS {
            let (x0, y0, x1, y1) = (
                coordinate(&mut rng),
                coordinate(&mut rng),
                coordinate(&mut rng),
                coordinate(&mut rng),
            );
            pairs.push(TestPair {
                p0: Point::new(x0, y0),
                p1: Point::new(x1, y1),
            });
        }
        Detector { config, pairs }
    }

    /// Corners and their descriptors: `(u, v)` pixel and descriptor, strongest first.
    pub fn detect(&self, image: &GrayImage) -> Vec<([u32; 2], Descriptor)> {
        let (w, h) = image.dimensions();
        if w <= 2 * MARGIN || h <= 2 * MARGIN {
            return Vec::new();
        }
        let cell = self.config.cell.max(1);
        let cols = w.div_ceil(cell) as usize;
        let mut best: Vec<Option<(u32, u32, f32)>> = vec![None; cols * h.div_ceil(cell) as usize];
        for c in corners_fast9(image, self.config.fast_threshold) {
            if c.x < MARGIN || c.y < MARGIN || c.x + MARGIN >= w || c.y + MARGIN >= h {
                continue;
            }
            let k = (c.y / cell) as usize * cols + (c.x / cell) as usize;
            if best[k].is_none_or(|b| c.score > b.2) {
                best[k] = Some((c.x, c.y, c.score));
            }
        }
        let mut kept: Vec<(u32, u32, f32)> = best.into_iter().flatten().collect();
        // Strongest first; ties by position, so that the order never depends on the sort.
        kept.sort_by(|a, b| b.2.total_cmp(&a.2).then((a.1, a.0).cmp(&(b.1, b.0))));
        kept.truncate(self.config.max_features);
        let points: Vec<Point<u32>> = kept.iter().map(|c| Point::new(c.0, c.1)).collect();
        match brief(image, &points, BITS, Some(&self.pairs)) {
            Ok((descriptors, _)) => descriptors
                .into_iter()
                .map(|d| ([d.corner.x, d.corner.y], [d.bits[0], d.bits[1]]))
                .collect(),
            // Unreachable with the margin above; no features rather than a crash.
            Err(_) => Vec::new(),
        }
    }
}

/// For each of `a`, the nearest of `b` by Hamming distance if within `max_hamming` (the
/// thesis takes the closest descriptor, with no ratio test): `(index in a, index in b)`.
pub fn match_nearest(a: &[Descriptor], b: &[Descriptor], max_hamming: u32) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    for (i, da) in a.iter().enumerate() {
        let best = b
            .iter()
            .enumerate()
            .map(|(j, db)| (hamming(da, db), j))
            .min();
        if let Some((d, j)) = best
            && d <= max_hamming
        {
            out.push((i, j));
        }
    }
    out
}

/// An 8-bit grey image from RGB bytes (ITU-R BT.601 luma).
pub fn grey(width: u32, height: u32, rgb: &[u8]) -> GrayImage {
    let data = rgb
        .chunks_exact(3)
        .map(|p| ((299 * p[0] as u32 + 587 * p[1] as u32 + 114 * p[2] as u32) / 1000) as u8)
        .collect();
    GrayImage::from_raw(width, height, data).unwrap_or_else(|| GrayImage::new(width, height))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A textured test image: smooth-ish random blobs (a seeded value-noise pattern).
    fn texture(w: u32, h: u32, seed: u64) -> GrayImage {
        use rand::Rng;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let g = 8u32;
        let (gw, gh) = (w / g + 2, h / g + 2);
        let grid: Vec<f64> = (0..gw * gh).map(|_| rng.random_range(0.0..255.0)).collect();
        // Bilinear between the grid's values: smooth blobs, corners where they meet.
        GrayImage::from_fn(w, h, |x, y| {
            let (fx, fy) = (x as f64 / g as f64, y as f64 / g as f64);
            let (i, j) = (fx as usize, fy as usize);
            let (ax, ay) = (fx - i as f64, fy - j as f64);
            let at = |i: usize, j: usize| grid[j * gw as usize + i];
            let v = (1.0 - ay) * ((1.0 - ax) * at(i, j) + ax * at(i + 1, j))
                + ay * ((1.0 - ax) * at(i, j + 1) + ax * at(i + 1, j + 1));
            image::Luma([v as u8])
        })
    }

    #[test]
    fn corners_of_a_shifted_image_match_their_originals() {
        let d = Detector::new(FeatureConfig::default(), 7);
        let big = texture(200, 160, 3);
        // The same scene 5 px to the right and 3 px down.
        let a = image::imageops::crop_imm(&big, 10, 10, 160, 120).to_image();
        let b = image::imageops::crop_imm(&big, 5, 7, 160, 120).to_image();
        let fa = d.detect(&a);
        let fb = d.detect(&b);
        assert!(fa.len() > 50 && fb.len() > 50, "{} {}", fa.len(), fb.len());
        let da: Vec<Descriptor> = fa.iter().map(|f| f.1).collect();
        let db: Vec<Descriptor> = fb.iter().map(|f| f.1).collect();
        let max = FeatureConfig::default().max_hamming;
        let m = match_nearest(&da, &db, max);
        let right = m
            .iter()
            .filter(|(i, j)| {
                let (pa, pb) = (fa[*i].0, fb[*j].0);
                (pa[0] + 5).abs_diff(pb[0]) <= 1 && (pa[1] + 3).abs_diff(pb[1]) <= 1
            })
            .count();
        // Nearest descriptors without a ratio test leave outliers (corners whose partner was
        // out of view or not kept); RANSAC removes them downstream. The right ones are most.
        assert!(right > 40, "{right}");
        assert!(
            right as f64 > 0.55 * m.len() as f64,
            "{right} of {} matches right",
            m.len()
        );
        // Another texture matches little and wrongly.
        let c = texture(160, 120, 99);
        let dc: Vec<Descriptor> = d.detect(&c).iter().map(|f| f.1).collect();
        // Measured at 40 bits: 103 matches here against 22 to another texture.
        assert!(match_nearest(&da, &dc, max).len() < right / 2);
    }

    #[test]
    fn the_same_seed_gives_the_same_descriptors() {
        let img = texture(120, 100, 5);
        let a = Detector::new(FeatureConfig::default(), 1).detect(&img);
        let b = Detector::new(FeatureConfig::default(), 1).detect(&img);
        let c = Detector::new(FeatureConfig::default(), 2).detect(&img);
        assert_eq!(a, b);
        assert_eq!(a.len(), c.len());
        assert_ne!(a, c);
        // Too small for a patch: nothing, no panic.
        assert!(
            Detector::new(FeatureConfig::default(), 1)
                .detect(&GrayImage::new(20, 20))
                .is_empty()
        );
    }
}
