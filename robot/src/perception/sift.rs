//! SIFT keypoints and descriptors (Lowe 2004), as seed 001 uses them (§2.1, eqs. 1–2): extrema
//! of the difference of Gaussians D(x, y, σ) in scale space, each with its contrast |D| (which
//! the seed stores and ranks landmarks by), its octave (whose sampling interval d_s sets the
//! seed's stereo error, σ = 0.5 d_s px), its scale level (stereo matches must lie within one
//! level), its orientation and its 128-D descriptor of 4 × 4 cells of 8 gradient directions.
//!
//! Written here: the one SIFT crate (`sift-features` 0.1, a single release) is built on an
//! older `imageproc` and `ndarray`, and reports neither contrast nor level as the seed needs
//! them. The steps and constants follow Lowe 2004 and Rey-Otero & Delbracio's "Anatomy of the
//! SIFT method" (IPOL 2014): 3 scales an octave from σ = 1.6 (the input taken as blurred by
//! 0.5 px), sub-pixel refinement of each extremum, the edge test with r = 10, a 36-bin
//! orientation histogram whose peaks above 0.8 of the highest each give a keypoint, and
//! descriptors clamped at 0.2 and renormalised. The input is not doubled in size (the seed's
//! images are 320 × 240 and its first octave is at the image's own sampling).
//!
//! Descriptors are stored as bytes, 512 × the unit vector's components (as OpenCV stores
//! them); [`distance`] gives the Euclidean distance between the unit vectors, the measure of
//! the seed's 0.2 threshold and of Lowe's ratio test.

use image::GrayImage;
use serde::{Deserialize, Serialize};
use std::f32::consts::PI;

/// Length of a descriptor.
pub const DESCRIPTOR_LEN: usize = 128;

/// A SIFT descriptor: 512 × its unit vector, each component saturated at 255.
pub type Descriptor = [u8; DESCRIPTOR_LEN];

/// Parameters of the detector.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SiftConfig {
    /// Scales an octave (Lowe: 3).
    pub scales: usize,
    /// Blur of the first level, px (Lowe: 1.6).
    pub sigma: f64,
    /// Least |D| of a kept extremum, with grey levels in 0–1. The seed gives none; OpenCV
    /// takes 0.04 / 3 = 0.013 and VLFeat keeps every extremum (0). futago takes 0.006: at the
    /// seed's 320 × 240 the image is not doubled, and a threshold of 0.013 kept about 70
    /// keypoints in a view of the lab against about 235 at 0.006 (and 240 at 0.003).
    pub contrast: f64,
    /// Edge test: the ratio of principal curvatures kept below this (Lowe: 10).
    pub edge_ratio: f64,
    /// At most this many keypoints, the highest contrasts.
    pub max_features: usize,
}

impl Default for SiftConfig {
    fn default() -> Self {
        SiftConfig {
            scales: 3,
            sigma: 1.6,
            contrast: 0.006,
            edge_ratio: 10.0,
            max_features: 1500,
        }
    }
}

impl SiftConfig {
    /// Checks every field; the error names the key below `prefix`.
    pub fn validate(&self, prefix: &str) -> Result<(), crate::config::ConfigError> {
        crate::config::check_counts(
            prefix,
            &[
                ("scales", self.scales, 1, 8),
                ("max_features", self.max_features, 1, 100_000),
            ],
        )?;
        crate::config::check_ranges(
            prefix,
            &[
                ("sigma", self.sigma, 0.5, 10.0),
                ("contrast", self.contrast, 0.0, 1.0),
                ("edge_ratio", self.edge_ratio, 1.0, 1000.0),
            ],
        )
    }
}

/// A keypoint with its descriptor.
#[derive(Debug, Clone, PartialEq)]
pub struct Keypoint {
    /// Position in the input image, px (pixel (0, 0)'s centre at (0, 0)).
    pub x: f32,
    pub y: f32,
    /// Scale: the blur σ at which it was found, in input pixels.
    pub sigma: f32,
    /// Octave: its sampling interval d_s is 2^octave input pixels.
    pub octave: u8,
    /// Scale level, continuous: octave × scales + level within the octave (refined).
    pub level: f32,
    /// Orientation of the gradient it was described along, rad (image axes: x right, y down).
    pub angle: f32,
    /// Contrast |D| at the refined extremum, grey levels 0–1.
    pub contrast: f32,
    pub descriptor: Descriptor,
}

impl Keypoint {
    /// The octave's sampling interval d_s, input pixels.
    pub fn sampling(&self) -> f32 {
        (1u32 << self.octave) as f32
    }
}

/// Euclidean distance between the unit descriptors that `a` and `b` store.
pub fn distance(a: &Descriptor, b: &Descriptor) -> f32 {
    let mut s = 0i32;
    for (x, y) in a.iter().zip(b) {
        let d = *x as i32 - *y as i32;
        s += d * d;
    }
    (s as f32).sqrt() / 512.0
}

/// A grey image of f32 levels.
#[derive(Clone)]
struct Plane {
    w: usize,
    h: usize,
    v: Vec<f32>,
}

impl Plane {
    fn at(&self, x: usize, y: usize) -> f32 {
        self.v[y * self.w + x]
    }

    /// Separable Gaussian blur of `sigma` px, edges extended.
    fn blur(&self, sigma: f64) -> Plane {
        let r = (3.0 * sigma).ceil().max(1.0) as isize;
        let mut k: Vec<f32> = (-r..=r)
            .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp() as f32)
            .collect();
        let sum: f32 = k.iter().sum();
        k.iter_mut().for_each(|x| *x /= sum);
        let (w, h) = (self.w as isize, self.h as isize);
        let mut tmp = vec![0f32; self.v.len()];
        // Each row extended by its edge pixels, so that the taps run over whole rows (which
        // the compiler vectorises) in the same order for every pixel: the sums are those of
        // taking each pixel's taps in turn.
        let ru = r as usize;
        let mut padded = vec![0f32; self.w + 2 * ru];
        for y in 0..h {
            let row = &self.v[(y * w) as usize..((y + 1) * w) as usize];
            padded[..ru].fill(row[0]);
            padded[ru..ru + self.w].copy_from_slice(row);
            padded[ru + self.w..].fill(row[self.w - 1]);
            let dst = &mut tmp[(y * w) as usize..((y + 1) * w) as usize];
            for (j, kj) in k.iter().enumerate() {
                for (d, s) in dst.iter_mut().zip(&padded[j..j + self.w]) {
                    *d += kj * s;
                }
            }
        }
        let mut out = vec![0f32; self.v.len()];
        for y in 0..h {
            for (j, kj) in k.iter().enumerate() {
                let yy = (y + j as isize - r).clamp(0, h - 1);
                let src = &tmp[(yy * w) as usize..((yy + 1) * w) as usize];
                let dst = &mut out[(y * w) as usize..((y + 1) * w) as usize];
                for (d, s) in dst.iter_mut().zip(src) {
                    *d += kj * s;
                }
            }
        }
        Plane {
            w: self.w,
            h: self.h,
            v: out,
        }
    }

    /// Every other pixel.
    fn halve(&self) -> Plane {
        let (w, h) = (self.w / 2, self.h / 2);
        let mut v = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                v.push(self.at(2 * x, 2 * y));
            }
        }
        Plane { w, h, v }
    }
}

/// Blur assumed of the input image, px (Lowe 2004).
const INPUT_BLUR: f64 = 0.5;
/// Pixels at an octave's edge not searched for extrema.
const BORDER: usize = 5;
/// Refinement steps before an extremum that keeps moving is dropped.
const REFINE_STEPS: usize = 5;
/// Orientation histogram: bins, window σ as a multiple of the scale, peak ratio.
const ORI_BINS: usize = 36;
const ORI_SIGMA: f32 = 1.5;
const ORI_PEAK: f32 = 0.8;
/// Descriptor: cells a side, direction bins, cell width as a multiple of the scale, clamp.
const CELLS: usize = 4;
const DIR_BINS: usize = 8;
const CELL_SCALE: f32 = 3.0;
const CLAMP: f32 = 0.2;

/// SIFT keypoints of `image`, highest contrast first (ties by position), at most
/// `config.max_features`.
pub fn detect(image: &GrayImage, config: &SiftConfig) -> Vec<Keypoint> {
    let (w, h) = (image.width() as usize, image.height() as usize);
    if w < 2 * BORDER + 3 || h < 2 * BORDER + 3 {
        return Vec::new();
    }
    let s = config.scales;
    let base = Plane {
        w,
        h,
        v: image.as_raw().iter().map(|&p| p as f32 / 255.0).collect(),
    };
    let sigma0 = config.sigma;
    let mut first = base.blur((sigma0 * sigma0 - INPUT_BLUR * INPUT_BLUR).max(0.01).sqrt());
    let mut out = Vec::new();
    let mut octave = 0usize;
    loop {
        // Gaussians at σ0·2^(i/s), i = 0..s+2, in this octave's pixels.
        let mut gauss = vec![first.clone()];
        for i in 1..s + 3 {
            let prev = sigma0 * 2f64.powf((i - 1) as f64 / s as f64);
            let next = sigma0 * 2f64.powf(i as f64 / s as f64);
            let g = gauss[i - 1].blur((next * next - prev * prev).sqrt());
            gauss.push(g);
        }
        let dog: Vec<Plane> = gauss
            .windows(2)
            .map(|p| Plane {
                w: p[0].w,
                h: p[0].h,
                v: p[1].v.iter().zip(&p[0].v).map(|(a, b)| a - b).collect(),
            })
            .collect();
        extrema(&dog, &gauss, octave, config, &mut out);
        let next = gauss[s].halve();
        octave += 1;
        if next.w < 2 * BORDER + 3 || next.h < 2 * BORDER + 3 || octave > 12 {
            break;
        }
        first = next;
    }
    out.sort_by(|a, b| {
        b.contrast
            .total_cmp(&a.contrast)
            .then(a.y.total_cmp(&b.y))
            .then(a.x.total_cmp(&b.x))
            .then(a.angle.total_cmp(&b.angle))
    });
    out.truncate(config.max_features);
    out
}

/// Finds, refines and describes the extrema of one octave's DoG stack.
fn extrema(
    dog: &[Plane],
    gauss: &[Plane],
    octave: usize,
    config: &SiftConfig,
    out: &mut Vec<Keypoint>,
) {
    let s = config.scales;
    let (w, h) = (dog[0].w, dog[0].h);
    let threshold = config.contrast as f32;
    let pre = 0.8 * threshold;
    let mut grads: Vec<Option<Gradients>> = gauss.iter().map(|_| None).collect();
    for level in 1..=s {
        for y in BORDER..h - BORDER {
            for x in BORDER..w - BORDER {
                let v = dog[level].at(x, y);
                if v.abs() <= pre || !is_extremum(dog, level, x, y, v) {
                    continue;
                }
                let Some((px, py, pl, off, contrast)) = refine(dog, level, x, y, config) else {
                    continue;
                };
                if contrast.abs() < threshold {
                    continue;
                }
                let scale_in_octave =
                    config.sigma as f32 * 2f32.powf((pl as f32 + off[2]) / s as f32);
                let d_s = (1u32 << octave) as f32;
                let g = grads[pl].get_or_insert_with(|| Gradients::new(&gauss[pl]));
                let fx = px as f32 + off[0];
                let fy = py as f32 + off[1];
                for angle in orientations(g, fx, fy, scale_in_octave) {
                    let descriptor = describe(g, fx, fy, scale_in_octave, angle);
                    out.push(Keypoint {
                        x: fx * d_s,
                        y: fy * d_s,
                        sigma: scale_in_octave * d_s,
                        octave: octave as u8,
                        level: (octave * s + pl) as f32 + off[2],
                        angle,
                        contrast: contrast.abs(),
                        descriptor,
                    });
                }
            }
        }
    }
}

/// Whether `v` at (x, y) of `level` is above or below all 26 neighbours.
fn is_extremum(dog: &[Plane], level: usize, x: usize, y: usize, v: f32) -> bool {
    let max = v > 0.0;
    for plane in &dog[level - 1..=level + 1] {
        for yy in y - 1..=y + 1 {
            for xx in x - 1..=x + 1 {
                let n = plane.at(xx, yy);
                if std::ptr::eq(plane, &dog[level]) && xx == x && yy == y {
                    continue;
                }
                if (max && n >= v) || (!max && n <= v) {
                    return false;
                }
            }
        }
    }
    true
}

/// Sub-pixel and sub-level refinement by a quadratic fit (Lowe 2004 §4), moving to the
/// neighbouring sample while the offset exceeds half a step, and the edge test; the refined
/// sample, offset (x, y, level) and D at the extremum.
#[allow(clippy::type_complexity)]
fn refine(
    dog: &[Plane],
    level: usize,
    x: usize,
    y: usize,
    config: &SiftConfig,
) -> Option<(usize, usize, usize, [f32; 3], f32)> {
    let (w, h) = (dog[0].w, dog[0].h);
    let (mut x, mut y, mut l) = (x, y, level);
    for _ in 0..REFINE_STEPS {
        let d = |dl: isize, dx: isize, dy: isize| {
            dog[(l as isize + dl) as usize]
                .at((x as isize + dx) as usize, (y as isize + dy) as usize)
        };
        let v = d(0, 0, 0);
        let g = [
            0.5 * (d(0, 1, 0) - d(0, -1, 0)),
            0.5 * (d(0, 0, 1) - d(0, 0, -1)),
            0.5 * (d(1, 0, 0) - d(-1, 0, 0)),
        ];
        let dxx = d(0, 1, 0) + d(0, -1, 0) - 2.0 * v;
        let dyy = d(0, 0, 1) + d(0, 0, -1) - 2.0 * v;
        let dss = d(1, 0, 0) + d(-1, 0, 0) - 2.0 * v;
        let dxy = 0.25 * (d(0, 1, 1) - d(0, -1, 1) - d(0, 1, -1) + d(0, -1, -1));
        let dxs = 0.25 * (d(1, 1, 0) - d(1, -1, 0) - d(-1, 1, 0) + d(-1, -1, 0));
        let dys = 0.25 * (d(1, 0, 1) - d(1, 0, -1) - d(-1, 0, 1) + d(-1, 0, -1));
        let hm = nalgebra::Matrix3::new(
            dxx as f64, dxy as f64, dxs as f64, dxy as f64, dyy as f64, dys as f64, dxs as f64,
            dys as f64, dss as f64,
        );
        let off = hm.lu().solve(&nalgebra::Vector3::new(
            -g[0] as f64,
            -g[1] as f64,
            -g[2] as f64,
        ))?;
        let off = [off[0] as f32, off[1] as f32, off[2] as f32];
        if off.iter().all(|o| o.abs() < 0.5) {
            let contrast = v + 0.5 * (g[0] * off[0] + g[1] * off[1] + g[2] * off[2]);
            // Edge test on the 2D Hessian: tr² / det < (r + 1)² / r.
            let (tr, det) = (dxx + dyy, dxx * dyy - dxy * dxy);
            let r = config.edge_ratio as f32;
            if det <= 0.0 || tr * tr * r >= (r + 1.0) * (r + 1.0) * det {
                return None;
            }
            return Some((x, y, l, off, contrast));
        }
        if off.iter().any(|o| !o.is_finite() || o.abs() > 3.0) {
            return None;
        }
        let nx = x as isize + off[0].round() as isize;
        let ny = y as isize + off[1].round() as isize;
        let nl = l as isize + off[2].round() as isize;
        if nl < 1
            || nl > config.scales as isize
            || nx < BORDER as isize
            || ny < BORDER as isize
            || nx >= (w - BORDER) as isize
            || ny >= (h - BORDER) as isize
        {
            return None;
        }
        (x, y, l) = (nx as usize, ny as usize, nl as usize);
    }
    None
}

/// The gradients (magnitude, angle) of one Gaussian level, each computed the first time a
/// keypoint's window reads it: the windows of neighbouring keypoints overlap, and the angle's
/// arc tangent was a third of the detector's time when every window computed its own.
struct Gradients<'a> {
    g: &'a Plane,
    /// (magnitude, angle) per pixel; NaN magnitude: not computed yet.
    cache: Vec<(f32, f32)>,
}

impl<'a> Gradients<'a> {
    fn new(g: &'a Plane) -> Gradients<'a> {
        Gradients {
            g,
            cache: vec![(f32::NAN, 0.0); g.w * g.h],
        }
    }

    /// The gradient (magnitude, angle) at integer (x, y), or none at the edge.
    fn at(&mut self, x: isize, y: isize) -> Option<(f32, f32)> {
        let g = self.g;
        if x < 1 || y < 1 || x >= g.w as isize - 1 || y >= g.h as isize - 1 {
            return None;
        }
        let (x, y) = (x as usize, y as usize);
        let slot = &mut self.cache[y * g.w + x];
        if slot.0.is_nan() {
            let dx = g.at(x + 1, y) - g.at(x - 1, y);
            let dy = g.at(x, y + 1) - g.at(x, y - 1);
            *slot = ((dx * dx + dy * dy).sqrt(), dy.atan2(dx));
        }
        Some(*slot)
    }
}

/// Dominant orientations at (x, y) of scale `sigma` (octave pixels): the peaks of a 36-bin,
/// Gaussian-weighted histogram of gradient directions, smoothed, above 0.8 of the highest,
/// each refined by a parabola through its neighbours.
fn orientations(g: &mut Gradients, x: f32, y: f32, sigma: f32) -> Vec<f32> {
    let ws = ORI_SIGMA * sigma;
    let r = (3.0 * ws).round() as isize;
    let (cx, cy) = (x.round() as isize, y.round() as isize);
    let mut hist = [0f32; ORI_BINS];
    for dy in -r..=r {
        for dx in -r..=r {
            let Some((m, a)) = g.at(cx + dx, cy + dy) else {
                continue;
            };
            let (fx, fy) = ((cx + dx) as f32 - x, (cy + dy) as f32 - y);
            let wgt = (-(fx * fx + fy * fy) / (2.0 * ws * ws)).exp();
            // Not negative (a ≥ −π), so truncation is the floor.
            let b = ((a + PI) / (2.0 * PI) * ORI_BINS as f32) as isize;
            hist[b.rem_euclid(ORI_BINS as isize) as usize] += wgt * m;
        }
    }
    // Six passes of a [1 1 1] / 3 box (Rey-Otero 2014).
    for _ in 0..6 {
        let prev = hist;
        for i in 0..ORI_BINS {
            hist[i] =
                (prev[(i + ORI_BINS - 1) % ORI_BINS] + prev[i] + prev[(i + 1) % ORI_BINS]) / 3.0;
        }
    }
    let max = hist.iter().copied().fold(0f32, f32::max);
    if max <= 0.0 {
        return Vec::new();
    }
    let mut out = Vec::new();
    for i in 0..ORI_BINS {
        let (l, c, rr) = (
            hist[(i + ORI_BINS - 1) % ORI_BINS],
            hist[i],
            hist[(i + 1) % ORI_BINS],
        );
        if c > l && c > rr && c >= ORI_PEAK * max {
            let off = 0.5 * (l - rr) / (l - 2.0 * c + rr);
            let bin = i as f32 + 0.5 + off;
            let a = bin / ORI_BINS as f32 * 2.0 * PI - PI;
            out.push(a);
        }
    }
    out
}

/// ⌊x⌋ for |x| < 2³¹ without the maths library's call (which baseline x86-64 makes for
/// `floor` and `trunc`): the integer conversion truncates, one less where that rounded up
/// (below zero).
fn floor_small(x: f32) -> f32 {
    let t = x as i32 as f32;
    if t > x { t - 1.0 } else { t }
}

/// The 4 × 4 × 8 descriptor at (x, y), scale `sigma`, orientation `angle` (octave pixels),
/// with trilinear interpolation, a Gaussian window of half the descriptor's width, and the
/// clamp at 0.2.
fn describe(g: &mut Gradients, x: f32, y: f32, sigma: f32, angle: f32) -> Descriptor {
    let cell = CELL_SCALE * sigma;
    let radius = (cell * std::f32::consts::SQRT_2 * (CELLS as f32 + 1.0) * 0.5).round() as isize;
    let (c, s) = (angle.cos(), angle.sin());
    let (cx, cy) = (x.round() as isize, y.round() as isize);
    let mut hist = [0f32; CELLS * CELLS * DIR_BINS];
    let half = CELLS as f32 / 2.0;
    let bins_per_rad = DIR_BINS as f32 / (2.0 * PI);
    for dy in -radius..=radius {
        for dx in -radius..=radius {
            let (fx, fy) = ((cx + dx) as f32 - x, (cy + dy) as f32 - y);
            // Rotated into the keypoint's frame, in cells.
            let rx = (c * fx + s * fy) / cell;
            let ry = (-s * fx + c * fy) / cell;
            let (bx, by) = (rx + half - 0.5, ry + half - 0.5);
            if bx <= -1.0 || bx >= CELLS as f32 || by <= -1.0 || by >= CELLS as f32 {
                continue;
            }
            let Some((m, a)) = g.at(cx + dx, cy + dy) else {
                continue;
            };
            let wgt = (-(rx * rx + ry * ry) / (2.0 * half * half)).exp() * m;
            let mut o = (a - angle).rem_euclid(2.0 * PI) * bins_per_rad;
            if o >= DIR_BINS as f32 {
                o -= DIR_BINS as f32;
            }
            // o ≥ 0, so truncation is its floor; bx and by lie in (−1, CELLS).
            let (x0, y0, o0) = (floor_small(bx), floor_small(by), o as i32 as f32);
            let (ax, ay, ao) = (bx - x0, by - y0, o - o0);
            for (iy, wy) in [(y0 as isize, 1.0 - ay), (y0 as isize + 1, ay)] {
                if iy < 0 || iy >= CELLS as isize {
                    continue;
                }
                for (ix, wx) in [(x0 as isize, 1.0 - ax), (x0 as isize + 1, ax)] {
                    if ix < 0 || ix >= CELLS as isize {
                        continue;
                    }
                    for (io, wo) in [(o0 as usize, 1.0 - ao), (o0 as usize + 1, ao)] {
                        let k = ((iy as usize * CELLS) + ix as usize) * DIR_BINS + io % DIR_BINS;
                        hist[k] += wgt * wy * wx * wo;
                    }
                }
            }
        }
    }
    let norm = |h: &mut [f32]| {
        let n = h.iter().map(|v| v * v).sum::<f32>().sqrt();
        if n > 0.0 {
            h.iter_mut().for_each(|v| *v /= n);
        }
    };
    norm(&mut hist);
    hist.iter_mut().for_each(|v| *v = v.min(CLAMP));
    norm(&mut hist);
    let mut d = [0u8; DESCRIPTOR_LEN];
    for (o, v) in d.iter_mut().zip(hist) {
        *o = (v * 512.0).round().min(255.0) as u8;
    }
    d
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Random Gaussian blobs, light and dark, on grey.
    fn blobs(w: u32, h: u32, n: usize, seed: u64) -> Vec<(f32, f32, f32, f32)> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|_| {
                (
                    rng.random_range(0.0..w as f32),
                    rng.random_range(0.0..h as f32),
                    rng.random_range(2.0..7.0f32),
                    rng.random_range(-0.5..0.5f32),
                )
            })
            .collect()
    }

    /// The blobs drawn through a similarity: pixel (u, v) shows the pattern at
    /// R(−angle)·((u, v) − centre) / scale + centre.
    fn draw(w: u32, h: u32, b: &[(f32, f32, f32, f32)], angle: f32, scale: f32) -> GrayImage {
        let (cx, cy) = (w as f32 / 2.0, h as f32 / 2.0);
        let (c, s) = (angle.cos(), angle.sin());
        GrayImage::from_fn(w, h, |u, v| {
            let (du, dv) = ((u as f32 - cx) / scale, (v as f32 - cy) / scale);
            let (px, py) = (c * du + s * dv + cx, -s * du + c * dv + cy);
            let mut val = 0.5f32;
            for &(bx, by, bs, a) in b {
                let d2 = (px - bx).powi(2) + (py - by).powi(2);
                if d2 < 16.0 * bs * bs {
                    val += a * (-d2 / (2.0 * bs * bs)).exp();
                }
            }
            image::Luma([(val.clamp(0.0, 1.0) * 255.0).round() as u8])
        })
    }

    /// Hand case: a lone Gaussian blob of σ 4 px is found at its centre at about its own
    /// scale (the scale-normalised Laplacian of a Gaussian blob of σ_b peaks at σ = σ_b), as a
    /// bright blob's minimum of D (D = G(kσ) − G(σ) is negative on a bright peak).
    /// The floor without the maths library is the floor, across zero and at integers.
    #[test]
    fn floor_small_is_the_floor() {
        for k in -4000..4000 {
            let x = k as f32 * 0.0037;
            assert_eq!(floor_small(x), x.floor(), "{x}");
        }
        for x in [-1.0f32, -0.0, 0.0, 1.0, 3.0, -0.999_999_94, 3.999_999_8] {
            assert_eq!(floor_small(x), x.floor(), "{x}");
        }
    }

    /// A gradient read through the cache is the one computed from the level's pixels, on
    /// the first read and the second, and none at the edge.
    #[test]
    fn cached_gradients_are_the_level_s_own() {
        let (w, h) = (9usize, 7usize);
        let plane = Plane {
            w,
            h,
            v: (0..w * h).map(|k| ((k * 37 % 11) as f32).sin()).collect(),
        };
        let mut g = Gradients::new(&plane);
        for _ in 0..2 {
            for y in 1..h - 1 {
                for x in 1..w - 1 {
                    let dx = plane.at(x + 1, y) - plane.at(x - 1, y);
                    let dy = plane.at(x, y + 1) - plane.at(x, y - 1);
                    let want = ((dx * dx + dy * dy).sqrt(), dy.atan2(dx));
                    assert_eq!(g.at(x as isize, y as isize), Some(want), "({x}, {y})");
                }
            }
        }
        for (x, y) in [
            (0, 3),
            (3, 0),
            (w as isize - 1, 3),
            (3, h as isize - 1),
            (-2, 1),
        ] {
            assert_eq!(g.at(x, y), None, "({x}, {y})");
        }
    }

    #[test]
    fn a_gaussian_blob_is_found_at_its_centre_and_scale() {
        let b = [(120.3, 90.6, 4.0, 0.4)];
        let img = draw(240, 180, &b, 0.0, 1.0);
        let k = detect(&img, &SiftConfig::default());
        let best = &k[0];
        assert!(
            (best.x - 120.3).abs() < 0.5 && (best.y - 90.6).abs() < 0.5,
            "{best:?}"
        );
        assert!(
            best.sigma > 3.0 && best.sigma < 5.3,
            "scale {} for a blob of σ 4",
            best.sigma
        );
        // Its level agrees with its scale: σ = 1.6 · 2^(level / 3).
        let from_level = 1.6 * 2f32.powf(best.level / 3.0);
        assert!((from_level / best.sigma - 1.0).abs() < 1e-3, "{best:?}");
        assert!((best.sampling() - (1u32 << best.octave) as f32).abs() < 1e-6);
        assert!(best.contrast > 0.006);
    }

    /// Rotated by 30° and scaled by 0.8, the same scene's keypoints match their originals:
    /// nearest descriptors passing Lowe's ratio test land where the similarity puts them.
    #[test]
    fn keypoints_match_across_rotation_and_scale() {
        let (w, h) = (320, 240);
        let b = blobs(w, h, 160, 4);
        let a = detect(&draw(w, h, &b, 0.0, 1.0), &SiftConfig::default());
        let (angle, scale) = (30f32.to_radians(), 0.8f32);
        let t = detect(&draw(w, h, &b, angle, scale), &SiftConfig::default());
        assert!(a.len() > 100 && t.len() > 60, "{} and {}", a.len(), t.len());
        let (cx, cy) = (w as f32 / 2.0, h as f32 / 2.0);
        let (c, s) = (angle.cos(), angle.sin());
        let (mut matched, mut right) = (0, 0);
        for k in &t {
            let mut d = a
                .iter()
                .map(|o| (distance(&k.descriptor, &o.descriptor), o))
                .collect::<Vec<_>>();
            d.sort_by(|x, y| x.0.total_cmp(&y.0));
            if d[0].0 > 0.7 * d[1].0 {
                continue;
            }
            matched += 1;
            let o = d[0].1;
            // Where the original point appears in the transformed image.
            let (du, dv) = (o.x - cx, o.y - cy);
            let (u, v) = (
                scale * (c * du - s * dv) + cx,
                scale * (s * du + c * dv) + cy,
            );
            if (u - k.x).hypot(v - k.y) < 2.0 {
                right += 1;
                // The scale follows the image's.
                assert!(
                    (k.sigma / o.sigma / scale - 1.0).abs() < 0.3,
                    "{} vs {}",
                    k.sigma,
                    o.sigma
                );
            }
        }
        assert!(matched >= 40, "{matched} ratio-test matches");
        assert!(
            right as f32 >= 0.85 * matched as f32,
            "{right} of {matched} in place"
        );
    }

    #[test]
    fn distances_are_between_unit_vectors_and_detection_repeats() {
        let img = draw(200, 150, &blobs(200, 150, 60, 9), 0.0, 1.0);
        let a = detect(&img, &SiftConfig::default());
        let b = detect(&img, &SiftConfig::default());
        assert_eq!(a, b);
        for k in a.iter().take(20) {
            assert_eq!(distance(&k.descriptor, &k.descriptor), 0.0);
            let n: f32 = k
                .descriptor
                .iter()
                .map(|v| (*v as f32 / 512.0).powi(2))
                .sum();
            assert!((n.sqrt() - 1.0).abs() < 0.02, "norm {}", n.sqrt());
        }
        // Two different keypoints' descriptors are apart (unit vectors: at most √2).
        let d = distance(&a[0].descriptor, &a[1].descriptor);
        assert!(d > 0.05 && d <= 1.42, "{d}");
        // Too small an image has none, without a panic.
        assert!(detect(&GrayImage::new(8, 8), &SiftConfig::default()).is_empty());
    }
}
