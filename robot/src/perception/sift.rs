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
    // Sixteen running sums of whole numbers, so the order does not matter: each square of a
    // byte's difference fits 16 bits (255² < 2¹⁶), which the compiler multiplies eight to a
    // register.
    let mut sums = [0u32; 16];
    for (ca, cb) in a.chunks_exact(16).zip(b.chunks_exact(16)) {
        for ((s, x), y) in sums.iter_mut().zip(ca).zip(cb) {
            let d = x.abs_diff(*y) as u16;
            *s += (d * d) as u32;
        }
    }
    (sums.iter().sum::<u32>() as f32).sqrt() / 512.0
}

/// A grey image of f32 levels.
#[derive(Clone, Default)]
struct Plane {
    w: usize,
    h: usize,
    v: Vec<f32>,
}

impl Plane {
    fn at(&self, x: usize, y: usize) -> f32 {
        self.v[y * self.w + x]
    }

    /// Makes this a `w` × `h` plane, its levels to be written, keeping its memory.
    fn reshape(&mut self, w: usize, h: usize) {
        self.w = w;
        self.h = h;
        self.v.clear();
        self.v.resize(w * h, 0.0);
    }

    /// Separable Gaussian blur of `sigma` px, edges extended, into `out`; `tmp` and `padded`
    /// are working memory.
    fn blur_into(&self, sigma: f64, out: &mut Plane, tmp: &mut Vec<f32>, padded: &mut Vec<f32>) {
        let r = (3.0 * sigma).ceil().max(1.0) as isize;
        let mut k: Vec<f32> = (-r..=r)
            .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp() as f32)
            .collect();
        let sum: f32 = k.iter().sum();
        k.iter_mut().for_each(|x| *x /= sum);
        let (w, h) = (self.w, self.h);
        tmp.clear();
        tmp.resize(self.v.len(), 0.0);
        // Each row extended by its edge pixels, so that the taps run over whole rows in the
        // same order for every pixel. Pixels are summed a block at a time, the block's sums
        // held in registers over the taps (the compiler vectorises the block) instead of
        // stored and reloaded at each tap: each pixel's sum is still its taps added in turn
        // from zero, so the result is the same to the bit.
        let ru = r as usize;
        padded.clear();
        padded.resize(w + 2 * ru, 0.0);
        for y in 0..h {
            let row = &self.v[y * w..(y + 1) * w];
            padded[..ru].fill(row[0]);
            padded[ru..ru + w].copy_from_slice(row);
            padded[ru + w..].fill(row[w - 1]);
            let dst = &mut tmp[y * w..(y + 1) * w];
            convolve_row(dst, &k, |j, x0, n| &padded[j + x0..j + x0 + n]);
        }
        out.reshape(w, h);
        for y in 0..h {
            let dst = &mut out.v[y * w..(y + 1) * w];
            convolve_row(dst, &k, |j, x0, n| {
                let yy = (y as isize + j as isize - r).clamp(0, h as isize - 1) as usize;
                &tmp[yy * w + x0..yy * w + x0 + n]
            });
        }
    }

    /// Every other pixel, into `out`.
    fn halve_into(&self, out: &mut Plane) {
        let (w, h) = (self.w / 2, self.h / 2);
        out.reshape(w, h);
        for y in 0..h {
            for x in 0..w {
                out.v[y * w + x] = self.at(2 * x, 2 * y);
            }
        }
    }
}

/// Pixels summed together in [`convolve_row`]: four SSE registers' worth.
const BLOCK: usize = 16;

/// `dst[x] = Σ_j k[j] · src(j)[x]`, the taps added in order from zero, where `src(j, x0, n)`
/// gives tap `j`'s inputs for pixels `x0..x0 + n`.
fn convolve_row<'a>(dst: &mut [f32], k: &[f32], src: impl Fn(usize, usize, usize) -> &'a [f32]) {
    let w = dst.len();
    let mut x0 = 0;
    while x0 + BLOCK <= w {
        let mut acc = [0f32; BLOCK];
        for (j, kj) in k.iter().enumerate() {
            let s = &src(j, x0, BLOCK)[..BLOCK];
            for (a, v) in acc.iter_mut().zip(s) {
                *a += kj * v;
            }
        }
        dst[x0..x0 + BLOCK].copy_from_slice(&acc);
        x0 += BLOCK;
    }
    if x0 < w {
        let n = w - x0;
        let tail = &mut dst[x0..];
        tail.fill(0.0);
        for (j, kj) in k.iter().enumerate() {
            for (a, v) in tail.iter_mut().zip(src(j, x0, n)) {
                *a += kj * v;
            }
        }
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

/// Found extrema fewer than this are described on this thread: each takes some tens of
/// microseconds, about what starting a thread costs.
const DESCRIBE_SERIAL_BELOW: usize = 32;

/// SIFT keypoints of `image`, highest contrast first (ties by position), at most
/// `config.max_features`.
///
/// The extrema of every octave are found first and then described (their orientations and
/// descriptors, most of the detector's time) on the machine's cores, in their order, so
/// the keypoints are the same whatever the number of threads.
pub fn detect(image: &GrayImage, config: &SiftConfig) -> Vec<Keypoint> {
    detect_with(image, config, &mut SiftBuffers::default())
}

/// The memory of the detector's scale space (its Gaussian levels, their differences and the
/// blur's working rows), kept from one image to the next by [`detect_with`]. Made afresh
/// for each image, its megabytes came new from the system each time: `lab-visual-map` took
/// 1.1 million page faults and 2.7–3.1 s of system time, against 0.34 million and 1.3 s
/// with the memory kept.
#[derive(Default)]
pub struct SiftBuffers {
    base: Plane,
    /// Per octave, its Gaussian levels.
    pyramid: Vec<Vec<Plane>>,
    dog: Vec<Plane>,
    tmp: Vec<f32>,
    padded: Vec<f32>,
}

/// [`detect`] in `buffers`' memory: the same keypoints, whatever the buffers held before.
pub fn detect_with(
    image: &GrayImage,
    config: &SiftConfig,
    buffers: &mut SiftBuffers,
) -> Vec<Keypoint> {
    let Some(found) = extrema_of(image, config, buffers) else {
        return Vec::new();
    };
    let pyramid = &buffers.pyramid[..];
    let described = crate::cores::map_on_cores_with(
        &found,
        DESCRIBE_SERIAL_BELOW,
        // Each thread's own gradients of each Gaussian level, computed as its keypoints'
        // windows read them: a pixel's gradient is the same whichever thread computes it.
        || no_gradients(pyramid),
        |grads, e| describe_extremum(grads, pyramid, e, config.scales),
    );
    ranked(described.into_iter().flatten().collect(), config)
}

/// The refined extrema of the differences of Gaussians of every octave, in order of octave,
/// level, row and column, with the octaves' Gaussian levels left in `b.pyramid` (one entry
/// an octave); none for an image too small to search.
fn extrema_of(
    image: &GrayImage,
    config: &SiftConfig,
    b: &mut SiftBuffers,
) -> Option<Vec<Extremum>> {
    let (w, h) = (image.width() as usize, image.height() as usize);
    if w < 2 * BORDER + 3 || h < 2 * BORDER + 3 {
        return None;
    }
    let s = config.scales;
    let levels = s + 3;
    b.base.reshape(w, h);
    for (d, &p) in b.base.v.iter_mut().zip(image.as_raw()) {
        *d = p as f32 / 255.0;
    }
    let sigma0 = config.sigma;
    let level_planes = |pyramid: &mut Vec<Vec<Plane>>, octave: usize| {
        if pyramid.len() <= octave {
            pyramid.push(Vec::new());
        }
        pyramid[octave].resize_with(levels, Plane::default);
    };
    level_planes(&mut b.pyramid, 0);
    b.base.blur_into(
        (sigma0 * sigma0 - INPUT_BLUR * INPUT_BLUR).max(0.01).sqrt(),
        &mut b.pyramid[0][0],
        &mut b.tmp,
        &mut b.padded,
    );
    let mut found = Vec::new();
    let mut octaves = 0;
    loop {
        let octave = octaves;
        // Gaussians at σ0·2^(i/s), i = 0..s+2, in this octave's pixels.
        let gauss = &mut b.pyramid[octave];
        for i in 1..levels {
            let prev = sigma0 * 2f64.powf((i - 1) as f64 / s as f64);
            let next = sigma0 * 2f64.powf(i as f64 / s as f64);
            let (done, rest) = gauss.split_at_mut(i);
            done[i - 1].blur_into(
                (next * next - prev * prev).sqrt(),
                &mut rest[0],
                &mut b.tmp,
                &mut b.padded,
            );
        }
        b.dog.resize_with(levels - 1, Plane::default);
        for (d, p) in b.dog.iter_mut().zip(gauss.windows(2)) {
            d.reshape(p[0].w, p[0].h);
            for ((o, a), c) in d.v.iter_mut().zip(&p[1].v).zip(&p[0].v) {
                *o = a - c;
            }
        }
        extrema(&b.dog, octave, config, &mut found);
        octaves += 1;
        let (nw, nh) = (gauss[s].w / 2, gauss[s].h / 2);
        if nw < 2 * BORDER + 3 || nh < 2 * BORDER + 3 || octaves > 12 {
            break;
        }
        level_planes(&mut b.pyramid, octaves);
        let (this, next) = b.pyramid.split_at_mut(octaves);
        this[octave][s].halve_into(&mut next[0][0]);
    }
    b.pyramid.truncate(octaves);
    Some(found)
}

/// A cache of gradients for each Gaussian level of `pyramid`, none computed yet.
fn no_gradients(pyramid: &[Vec<Plane>]) -> Vec<Vec<Option<Gradients<'_>>>> {
    pyramid
        .iter()
        .map(|g| g.iter().map(|_| None).collect())
        .collect()
}

/// The keypoints of extremum `e`: one for each of its dominant orientations, described.
fn describe_extremum<'a>(
    grads: &mut [Vec<Option<Gradients<'a>>>],
    pyramid: &'a [Vec<Plane>],
    e: &Extremum,
    scales: usize,
) -> Vec<Keypoint> {
    let g =
        grads[e.octave][e.level].get_or_insert_with(|| Gradients::new(&pyramid[e.octave][e.level]));
    let d_s = (1u32 << e.octave) as f32;
    orientations(g, e.x, e.y, e.scale)
        .into_iter()
        .map(|angle| Keypoint {
            x: e.x * d_s,
            y: e.y * d_s,
            sigma: e.scale * d_s,
            octave: e.octave as u8,
            level: (e.octave * scales + e.level) as f32 + e.offset,
            angle,
            contrast: e.contrast,
            descriptor: describe(g, e.x, e.y, e.scale, angle),
        })
        .collect()
}

/// Keypoints highest contrast first (ties by position and angle), at most
/// `config.max_features`.
fn ranked(mut out: Vec<Keypoint>, config: &SiftConfig) -> Vec<Keypoint> {
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

/// A refined extremum of the difference of Gaussians, to be described.
struct Extremum {
    octave: usize,
    /// The Gaussian level it lies nearest, and its offset from it in levels.
    level: usize,
    offset: f32,
    /// Position, octave pixels.
    x: f32,
    y: f32,
    /// Scale σ, octave pixels.
    scale: f32,
    /// |D| at the extremum.
    contrast: f32,
}

/// Finds and refines the extrema of one octave's DoG stack, in order of level, row and
/// column.
fn extrema(dog: &[Plane], octave: usize, config: &SiftConfig, out: &mut Vec<Extremum>) {
    let s = config.scales;
    let (w, h) = (dog[0].w, dog[0].h);
    let threshold = config.contrast as f32;
    let pre = 0.8 * threshold;
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
                out.push(Extremum {
                    octave,
                    level: pl,
                    offset: off[2],
                    x: px as f32 + off[0],
                    y: py as f32 + off[1],
                    scale: config.sigma as f32 * 2f32.powf((pl as f32 + off[2]) / s as f32),
                    contrast: contrast.abs(),
                });
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

/// A pixel's gradient: magnitude and angle (rad).
type Gradient = (f32, f32);

/// The gradients (magnitude, angle) of one Gaussian level, each computed the first time a
/// keypoint's window reads it: the windows of neighbouring keypoints overlap, and the angle's
/// arc tangent was a third of the detector's time when every window computed its own. Rows
/// are made as the windows reach them: a cache of the whole level at once (0.6 MB at 320 ×
/// 240) came fresh from the system for each level of each image (`lab-visual-map`: 1.5
/// million page faults, 1.1 million with rows).
struct Gradients<'a> {
    g: &'a Plane,
    /// Per row, (magnitude, angle) per pixel, NaN magnitude where not computed yet; none
    /// where no pixel of the row has been.
    rows: Vec<Option<Box<[Gradient]>>>,
}

impl<'a> Gradients<'a> {
    fn new(g: &'a Plane) -> Gradients<'a> {
        Gradients {
            g,
            rows: vec![None; g.h],
        }
    }

    /// The gradient (magnitude, angle) at integer (x, y), or none at the edge.
    fn at(&mut self, x: isize, y: isize) -> Option<(f32, f32)> {
        let g = self.g;
        if x < 1 || y < 1 || x >= g.w as isize - 1 || y >= g.h as isize - 1 {
            return None;
        }
        let (x, y) = (x as usize, y as usize);
        let row = self.rows[y].get_or_insert_with(|| vec![(f32::NAN, 0.0); g.w].into());
        let slot = &mut row[x];
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

/// The columns `dx` (offsets from `cx`, within ±`radius`) of image row `row` where the
/// square of half-width `reach` cells about (x, y), turned by the angle whose cosine and sine
/// are `c` and `s`, may lie: the interval where both rotated coordinates lie within `reach`,
/// worked in `f64` and widened by a pixel at each end, so that it holds every pixel the
/// descriptor's own test in `f32` accepts. Empty where `from > to`.
#[allow(clippy::too_many_arguments)]
fn square_columns(
    x: f32,
    y: f32,
    cx: isize,
    row: isize,
    cell: f32,
    c: f32,
    s: f32,
    reach: f32,
    radius: isize,
) -> (isize, isize) {
    let (c, s) = (c as f64, s as f64);
    let fy = row as f64 - y as f64;
    let r = reach as f64 * cell as f64;
    let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
    // −r < c·fx + s·fy < r and −r < −s·fx + c·fy < r, each an interval of fx where its
    // factor is not near zero (there the window's own bound is the only one kept).
    for (a, b) in [(c, s * fy), (-s, c * fy)] {
        if a.abs() > 1e-6 {
            let (p, q) = ((-r - b) / a, (r - b) / a);
            lo = lo.max(p.min(q));
            hi = hi.min(p.max(q));
        }
    }
    let shift = x as f64 - cx as f64;
    let from = if lo.is_finite() {
        ((lo + shift).floor() as isize - 1).max(-radius)
    } else {
        -radius
    };
    let to = if hi.is_finite() {
        ((hi + shift).ceil() as isize + 1).min(radius)
    } else {
        radius
    };
    (from, to)
}

/// The 4 × 4 × 8 descriptor at (x, y), scale `sigma`, orientation `angle` (octave pixels),
/// with trilinear interpolation, a Gaussian window of half the descriptor's width, and the
/// clamp at 0.2.
fn describe(g: &mut Gradients, x: f32, y: f32, sigma: f32, angle: f32) -> Descriptor {
    describe_scanning(g, x, y, sigma, angle, true)
}

/// [`describe`], scanning each row of the window only over the columns the rotated square
/// may cover (`narrow`) or over the whole row. The square's pixels are found by the same
/// test either way, so the two give the same descriptor: the narrow scan skips the half of
/// the window outside the square, whose rotations were a third of the time.
fn describe_scanning(
    g: &mut Gradients,
    x: f32,
    y: f32,
    sigma: f32,
    angle: f32,
    narrow: bool,
) -> Descriptor {
    let cell = CELL_SCALE * sigma;
    let radius = (cell * std::f32::consts::SQRT_2 * (CELLS as f32 + 1.0) * 0.5).round() as isize;
    let (c, s) = (angle.cos(), angle.sin());
    let (cx, cy) = (x.round() as isize, y.round() as isize);
    let mut hist = [0f32; CELLS * CELLS * DIR_BINS];
    let half = CELLS as f32 / 2.0;
    let bins_per_rad = DIR_BINS as f32 / (2.0 * PI);
    for dy in -radius..=radius {
        let (from, to) = if narrow {
            square_columns(x, y, cx, cy + dy, cell, c, s, half + 0.5, radius)
        } else {
            (-radius, radius)
        };
        for dx in from..=to {
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
            let mut o = turn_remainder(a - angle) * bins_per_rad;
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

/// `v.rem_euclid(2π)` (f32), without the maths library's `fmodf` for the usual case of a
/// gradient's direction less the keypoint's: for `v` in (−2π, 2π), `fmod` returns `v`
/// itself, which `rem_euclid` then takes as it is or adds 2π to, as here; other values go
/// to `rem_euclid`. The same bits either way (a tested property); `fmodf` took 1.25 % of
/// `futago bench visual`'s samples beside the descriptors' own 17.6 %.
#[inline(always)]
fn turn_remainder(v: f32) -> f32 {
    const TURN: f32 = 2.0 * PI;
    if v > -TURN && v < TURN {
        if v < 0.0 { v + TURN } else { v }
    } else {
        v.rem_euclid(TURN)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// [`turn_remainder`] gives `rem_euclid`'s bits for every difference of two directions,
    /// the bounds ±2π and the floats either side of them, zeros and values turns away.
    #[test]
    fn turn_remainder_is_rem_euclid() {
        let turn = 2.0 * PI;
        let mut values = vec![
            0.0f32,
            -0.0,
            turn,
            -turn,
            3.0 * turn,
            -5.5 * turn,
            f32::MIN_POSITIVE,
        ];
        for b in [turn, -turn, PI, -PI, 0.0] {
            let (mut up, mut down) = (b, b);
            for _ in 0..4 {
                up = f32::from_bits(up.to_bits().wrapping_add(1));
                down = f32::from_bits(down.to_bits().wrapping_sub(1));
                values.extend([up, down, -up, -down]);
            }
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        values
            .extend((0..100_000).map(|_| rng.random_range(-PI..=PI) - rng.random_range(-PI..turn)));
        for v in values.into_iter().filter(|v| v.is_finite()) {
            assert_eq!(
                turn_remainder(v).to_bits(),
                v.rem_euclid(turn).to_bits(),
                "{v:e}"
            );
        }
    }

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

    /// The distance is the Euclidean distance of the stored bytes over 512, as the plain sum
    /// gives it, for random descriptors and the extremes (every byte 0 against every byte
    /// 255, whose squares are the largest).
    #[test]
    fn distance_is_that_of_the_stored_bytes() {
        let plain = |a: &Descriptor, b: &Descriptor| {
            let s: i64 = a
                .iter()
                .zip(b)
                .map(|(x, y)| (*x as i64 - *y as i64).pow(2))
                .sum();
            (s as f32).sqrt() / 512.0
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let mut pairs = vec![([0u8; 128], [255u8; 128]), ([255u8; 128], [0u8; 128])];
        for _ in 0..200 {
            let mut a = [0u8; 128];
            let mut b = [0u8; 128];
            rng.fill(&mut a[..]);
            rng.fill(&mut b[..]);
            pairs.push((a, b));
        }
        for (a, b) in &pairs {
            assert_eq!(distance(a, b), plain(a, b));
        }
        assert_eq!(
            distance(&pairs[0].0, &pairs[0].1),
            255.0 * 128f32.sqrt() / 512.0
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

    /// Buffers kept from image to image, of other sizes (more octaves, then fewer, then an
    /// image too small to search) and other contents, give each image the keypoints that
    /// fresh ones give.
    #[test]
    fn kept_buffers_give_each_image_its_own_keypoints() {
        let config = SiftConfig::default();
        let mut buffers = SiftBuffers::default();
        for (w, h, seed) in [
            (320, 240, 1),
            (160, 200, 2),
            (8, 8, 3),
            (240, 180, 4),
            (320, 240, 1),
        ] {
            let img = draw(w, h, &blobs(w, h, (w * h / 600) as usize, seed), 0.2, 1.0);
            let fresh = detect(&img, &config);
            assert_eq!(detect_with(&img, &config, &mut buffers), fresh, "{w} × {h}");
            assert_eq!(fresh.is_empty(), w < 20, "{w} × {h}");
        }
    }

    /// Scanning each row of a descriptor's window only where the turned square may lie gives
    /// the descriptor of the whole window, at every angle (the axes, the diagonals and
    /// between) and at sub-pixel positions and scales of several octaves' sizes.
    #[test]
    fn the_narrow_scan_gives_the_whole_window_s_descriptor() {
        let (w, h) = (120usize, 100usize);
        let plane = Plane {
            w,
            h,
            v: (0..w * h)
                .map(|k| (((k % w) as f32 * 0.37).sin() + ((k / w) as f32 * 0.23).cos()) * 0.5)
                .collect(),
        };
        let mut g = Gradients::new(&plane);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut angles: Vec<f32> = (-8..=8).map(|i| i as f32 * PI / 8.0).collect();
        angles.extend((0..40).map(|_| rng.random_range(-PI..PI)));
        for (i, angle) in angles.into_iter().enumerate() {
            let x = 60.0 + rng.random_range(-0.5f32..0.5);
            let y = 50.0 + rng.random_range(-0.5f32..0.5);
            let sigma = [1.6f32, 2.3, 3.9][i % 3];
            assert_eq!(
                describe_scanning(&mut g, x, y, sigma, angle, true),
                describe_scanning(&mut g, x, y, sigma, angle, false),
                "angle {angle}, ({x}, {y}), σ {sigma}"
            );
        }
    }

    /// The keypoints do not depend on how the extrema are shared among threads, each with its
    /// own gradients: describing every extremum with none computed before gives the same
    /// keypoints, bit for bit, as `detect`, whose threads share theirs over many extrema.
    #[test]
    fn keypoints_are_the_same_however_the_extrema_are_split() {
        let img = draw(320, 240, &blobs(320, 240, 300, 5), 0.3, 1.0);
        let config = SiftConfig::default();
        let mut buffers = SiftBuffers::default();
        let Some(found) = extrema_of(&img, &config, &mut buffers) else {
            panic!("an image of 320 × 240 is searched");
        };
        let pyramid = &buffers.pyramid[..];
        // Enough to be described on several threads where the machine has them.
        assert!(
            found.len() > 4 * DESCRIBE_SERIAL_BELOW,
            "{} extrema",
            found.len()
        );
        let alone: Vec<Keypoint> = found
            .iter()
            .flat_map(|e| describe_extremum(&mut no_gradients(pyramid), pyramid, e, 3))
            .collect();
        assert_eq!(detect(&img, &config), ranked(alone, &config));
    }
}
