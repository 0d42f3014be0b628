//! Coverage against the simulated world: how much of the floor the robot's footprint swept,
//! and how much of the true surfaces its camera saw.
//!
//! - **Footprint**: the floor the robot can sweep at all is every cell within the Create's
//!   radius of a cell its centre can reach (at least the planner's clearance from obstacles,
//!   connected to the start; the reachable floor of ipa_coverage_planning's evaluation). The
//!   score is the share of it that a disc of the Create's radius at the true poses swept.
//! - **Camera**: the world's triangles are sampled every [`SAMPLE_STEP`] into voxels of
//!   [`VOXEL`], each voxel carrying the area of each surface class in it: the floor's top,
//!   the walls' faces, the other static objects' upright faces (furniture). A voxel is seen
//!   when a noiseless depth pixel rendered at the camera's true pose, within the camera's
//!   valid range, lands in it. The score is the seen share of each class's area below the
//!   highest point the camera can see at all (its height plus its range times the tangent of
//!   half its vertical field of view): seed 000 painted a 2D fan onto the map, which it
//!   admits is not rigorous; this counts what the renders saw.

use futago_msgs::Pose2;
use futago_msgs::camera::{DepthImage, Intrinsics};
use futago_msgs::grid::OccupancyGrid;
use futago_sim::World;
use rustc_hash::FxHashMap;

/// Voxel side of the surface samples, m.
pub const VOXEL: f64 = 0.05;
/// Spacing of the samples on a triangle, m (half a voxel: every voxel a surface crosses
/// holds a sample).
pub const SAMPLE_STEP: f64 = 0.025;
/// The voxel grid's offset, m: away from the round coordinates where the worlds' axis-aligned
/// faces lie (the floor's top at z = 0), so that a face and the depth points on it fall in
/// the same voxels.
const OFFSET: [f64; 3] = [0.0137, 0.0219, 0.0271];

/// The surface classes scored.
pub const CLASSES: [&str; 3] = ["floor", "walls", "furniture"];

/// The true surfaces, voxelised, with each class's area per voxel, and per region of the
/// floor where the surfaces were labelled by region.
pub struct Surfaces {
    /// Each voxel's place in `area`.
    voxel: FxHashMap<[i32; 3], u32>,
    /// Each class's area per voxel.
    area: Vec<[f64; 3]>,
    total: [f64; 3],
    /// Each (voxel, region)'s place in `regional`.
    voxel_region: FxHashMap<([i32; 3], u32), u32>,
    /// Each class's area per (voxel, region): all of it, and the part the camera can see
    /// from some reachable pose ([`super::observable`]).
    regional: Vec<[[f64; 3]; 2]>,
    /// Each region's area of each class: all of it, and the observable part.
    region_total: Vec<[[f64; 3]; 2]>,
}

/// How far from a face, along its outward normal, its region is looked up, m: into the free
/// cell beside a wall's face rather than the wall's own.
const REGION_PROBE: f64 = 0.03;

#[inline]
fn key(p: [f64; 3]) -> [i32; 3] {
    let at = |k: usize| floor_i32((p[k] - OFFSET[k]) / VOXEL);
    [at(0), at(1), at(2)]
}

/// `x.floor() as i32` (saturating, NaN to 0) without the maths library's call that baseline
/// x86-64 makes for `floor`: truncation, one less where it rounded up. Every surface sample
/// of a world is keyed by it.
#[inline]
fn floor_i32(x: f64) -> i32 {
    let t = x as i64;
    let t = if (t as f64) > x {
        t.saturating_sub(1)
    } else {
        t
    };
    t.clamp(i32::MIN as i64, i32::MAX as i64) as i32
}

impl Surfaces {
    /// The world's static surfaces at or below `top` (m) where `keep(x, y)` holds (the area
    /// to cover): the floor slab's upper face, the walls' upright faces and the other static
    /// objects' upright faces. `region(x, y)` labels each piece with the region of the floor
    /// it faces (looked up a little way out along its normal), or none; `sees(p, normal)`
    /// tells whether the camera can see a labelled upright piece at all (the floor counts as
    /// observable). `bounds` (lower and upper corners, m), where given, holds every point
    /// `keep` takes: the rest of the world is not sampled.
    pub fn from_world(
        world: &World,
        top: f64,
        bounds: Option<[[f64; 2]; 2]>,
        keep: impl Fn([f64; 2]) -> bool,
        region: impl Fn([f64; 2]) -> Option<usize>,
        sees: impl Fn([f64; 3], [f64; 2]) -> bool,
    ) -> Surfaces {
        let mut s = Surfaces::empty();
        for o in &world.objects {
            if !matches!(o.motion, futago_sim::world::Motion::Static) || o.name == "ceiling" {
                continue;
            }
            let class_of = |n: glam::Vec3| -> Option<usize> {
                if o.name == "floor" {
                    (n.z > 0.9).then_some(0)
                } else if n.z.abs() < 0.2 {
                    Some(if o.is_wall() { 1 } else { 2 })
                } else {
                    None
                }
            };
            for part in &o.parts {
                let m = &part.mesh;
                for t in &m.indices {
                    let [a, b, c] = t.map(|i| o.pose * m.positions[i as usize]);
                    let n = (b - a).cross(c - a);
                    let area2 = n.length();
                    if area2 < 1e-9 {
                        continue;
                    }
                    let Some(class) = class_of(n / area2) else {
                        continue;
                    };
                    let [a, b, c] = [a, b, c].map(|v| [v.x as f64, v.y as f64, v.z as f64]);
                    let probe = [n.x as f64 / area2 as f64, n.y as f64 / area2 as f64]
                        .map(|u| u * REGION_PROBE);
                    let label = |p: [f64; 2]| region([p[0] + probe[0], p[1] + probe[1]]);
                    let normal = [n.x as f64, n.y as f64];
                    let observable = |p: [f64; 3]| class == 0 || sees(p, normal);
                    if let Some([lo, hi]) = bounds {
                        let outside = (0..2).any(|d| {
                            a[d].min(b[d]).min(c[d]) > hi[d] || a[d].max(b[d]).max(c[d]) < lo[d]
                        });
                        if outside {
                            continue;
                        }
                    }
                    let keep = |p: [f64; 2]| {
                        bounds.is_none_or(|[lo, hi]| {
                            (lo[0]..=hi[0]).contains(&p[0]) && (lo[1]..=hi[1]).contains(&p[1])
                        }) && keep(p)
                    };
                    s.add_triangle(a, b, c, class, top, &keep, &label, &observable);
                }
            }
        }
        s
    }

    /// Surfaces of the given triangles, each with its class (tests of the measures built on
    /// them).
    #[cfg(test)]
    pub(crate) fn from_triangles(triangles: &[([[f64; 3]; 3], usize)]) -> Surfaces {
        let mut s = Surfaces::empty();
        for ([a, b, c], class) in triangles {
            s.add_triangle(
                *a,
                *b,
                *c,
                *class,
                f64::INFINITY,
                &|_| true,
                &|_| None,
                &|_| true,
            );
        }
        s
    }

    fn empty() -> Surfaces {
        Surfaces {
            voxel: FxHashMap::default(),
            area: Vec::new(),
            total: [0.0; 3],
            voxel_region: FxHashMap::default(),
            regional: Vec::new(),
            region_total: Vec::new(),
        }
    }

    /// Samples a triangle every [`SAMPLE_STEP`] and adds its area below `top` to `class`, and
    /// to the region `label` gives each sample (and to its observable part where
    /// `observable` holds).
    #[allow(clippy::too_many_arguments)]
    fn add_triangle(
        &mut self,
        a: [f64; 3],
        b: [f64; 3],
        c: [f64; 3],
        class: usize,
        top: f64,
        keep: &impl Fn([f64; 2]) -> bool,
        label: &impl Fn([f64; 2]) -> Option<usize>,
        observable: &impl Fn([f64; 3]) -> bool,
    ) {
        let e = |p: [f64; 3], q: [f64; 3]| {
            ((q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2) + (q[2] - p[2]).powi(2)).sqrt()
        };
        let longest = e(a, b).max(e(b, c)).max(e(c, a));
        let n = ((longest / SAMPLE_STEP).ceil() as usize).clamp(1, 20_000);
        let cross = {
            let (u, v) = (
                [b[0] - a[0], b[1] - a[1], b[2] - a[2]],
                [c[0] - a[0], c[1] - a[1], c[2] - a[2]],
            );
            [
                u[1] * v[2] - u[2] * v[1],
                u[2] * v[0] - u[0] * v[2],
                u[0] * v[1] - u[1] * v[0],
            ]
        };
        let area = 0.5 * (cross[0].powi(2) + cross[1].powi(2) + cross[2].powi(2)).sqrt();
        // Points at the centres of the n² small triangles of the subdivision, each of equal
        // area.
        let each = area / (n * n) as f64;
        let at = |s: f64, t: f64| -> [f64; 3] {
            [0, 1, 2].map(|k| a[k] + s * (b[k] - a[k]) + t * (c[k] - a[k]))
        };
        let nf = n as f64;
        // Neighbouring samples mostly share a voxel: the last one's places, looked up again
        // only when the voxel (or region) changes.
        let mut last_voxel: Option<([i32; 3], usize)> = None;
        let mut last_region: Option<(([i32; 3], u32), usize)> = None;
        for i in 0..n {
            for j in 0..n - i {
                // The upright small triangle's centre, and the inverted one's beside it where
                // there is one.
                let centres = [
                    at((i as f64 + 1.0 / 3.0) / nf, (j as f64 + 1.0 / 3.0) / nf),
                    at((i as f64 + 2.0 / 3.0) / nf, (j as f64 + 2.0 / 3.0) / nf),
                ];
                let count = if i + j + 1 < n { 2 } else { 1 };
                for p in centres.into_iter().take(count) {
                    if p[2] > top || !keep([p[0], p[1]]) {
                        continue;
                    }
                    let k = key(p);
                    let at = match last_voxel {
                        Some((l, at)) if l == k => at,
                        _ => {
                            let at = place(&mut self.voxel, &mut self.area, k, [0.0; 3]);
                            last_voxel = Some((k, at));
                            at
                        }
                    };
                    self.area[at][class] += each;
                    self.total[class] += each;
                    if let Some(r) = label([p[0], p[1]]) {
                        let parts = if observable(p) { 2 } else { 1 };
                        let kr = (k, r as u32);
                        let at = match last_region {
                            Some((l, at)) if l == kr => at,
                            _ => {
                                let at = place(
                                    &mut self.voxel_region,
                                    &mut self.regional,
                                    kr,
                                    [[0.0; 3]; 2],
                                );
                                last_region = Some((kr, at));
                                at
                            }
                        };
                        let entry = &mut self.regional[at];
                        if self.region_total.len() <= r {
                            self.region_total.resize(r + 1, [[0.0; 3]; 2]);
                        }
                        for (e, t) in entry.iter_mut().zip(&mut self.region_total[r]).take(parts) {
                            e[class] += each;
                            t[class] += each;
                        }
                    }
                }
            }
        }
    }

    /// Each class's area, m².
    pub fn total(&self) -> [f64; 3] {
        self.total
    }

    /// Each class's area in the voxels of `seen`, m².
    pub fn seen_area(&self, seen: &CameraCoverage) -> [f64; 3] {
        let mut out = [0.0; 3];
        for &at in seen.voxels.values() {
            if let Some(a) = self.area.get(at as usize) {
                for c in 0..3 {
                    out[c] += a[c];
                }
            }
        }
        out
    }

    /// The seen share of each class and of all of them (`None` for a class the world lacks).
    pub fn shares(&self, seen: &CameraCoverage) -> ([Option<f64>; 3], f64) {
        let got = self.seen_area(seen);
        let share = |c: usize| (self.total[c] > 0.0).then(|| got[c] / self.total[c]);
        let all = self.total.iter().sum::<f64>();
        (
            [share(0), share(1), share(2)],
            if all > 0.0 {
                got.iter().sum::<f64>() / all
            } else {
                0.0
            },
        )
    }

    /// Per region (by number, up to the highest labelled): each class's area, and the area
    /// of it in the voxels of `seen`, m². With `observable`, of the part of each class the
    /// camera can see at all.
    pub fn region_areas(
        &self,
        seen: &CameraCoverage,
        observable: bool,
    ) -> Vec<([f64; 3], [f64; 3])> {
        let part = usize::from(observable);
        let mut out: Vec<([f64; 3], [f64; 3])> = self
            .region_total
            .iter()
            .map(|t| (t[part], [0.0; 3]))
            .collect();
        for (&(k, r), &at) in &self.voxel_region {
            let a = &self.regional[at as usize];
            if seen.voxels.contains_key(&k) {
                for (o, x) in out[r as usize].1.iter_mut().zip(&a[part]) {
                    *o += x;
                }
            }
        }
        out
    }

    /// Every voxel holding surface: its centre (m) and each class's area in it (m²), in no
    /// particular order.
    pub fn voxels(&self) -> impl Iterator<Item = ([f64; 3], [f64; 3])> + '_ {
        self.voxel.iter().map(|(k, &at)| {
            (
                [0, 1, 2].map(|d| OFFSET[d] + (k[d] as f64 + 0.5) * VOXEL),
                self.area[at as usize],
            )
        })
    }

    /// Per column of voxels (by [`column`]), which of the voxels at the heights `zs` (m, at
    /// most 64) hold surface of `class`: bit `b` for `zs[b]`. One pass over the voxels, for
    /// a picture that asks about every column of a map.
    pub fn levels_held(&self, zs: &[f64], class: usize) -> FxHashMap<[i32; 2], u64> {
        let held = self
            .voxel
            .iter()
            .filter(|&(_, &at)| self.area[at as usize][class] > 0.0);
        level_masks(held.map(|(k, _)| k), zs)
    }

    /// Whether voxel `k` holds surface of `class`.
    pub fn holds(&self, p: [f64; 3], class: usize) -> bool {
        self.voxel
            .get(&key(p))
            .is_some_and(|&at| self.area[at as usize][class] > 0.0)
    }
}

/// The column of voxels holding the point `(x, y)`.
pub fn column(p: [f64; 2]) -> [i32; 2] {
    let k = key([p[0], p[1], 0.0]);
    [k[0], k[1]]
}

/// Per column of the voxels `keys`, the bits of the heights of `zs` (at most 64) whose
/// voxel level is among them: bit `b` for `zs[b]`.
fn level_masks<'a>(
    keys: impl Iterator<Item = &'a [i32; 3]>,
    zs: &[f64],
) -> FxHashMap<[i32; 2], u64> {
    assert!(zs.len() <= 64, "at most 64 heights fit a mask");
    // Each voxel level's bits: the heights that fall in it.
    let mut bits = FxHashMap::default();
    for (b, &z) in zs.iter().enumerate() {
        *bits.entry(key([0.0, 0.0, z])[2]).or_insert(0u64) |= 1 << b;
    }
    let mut out = FxHashMap::default();
    for k in keys {
        if let Some(&b) = bits.get(&k[2]) {
            *out.entry([k[0], k[1]]).or_insert(0) |= b;
        }
    }
    out
}

/// The place of `key` in `values` by `index`, a new one holding `empty` where it had none.
fn place<K: std::hash::Hash + Eq, V>(
    index: &mut FxHashMap<K, u32>,
    values: &mut Vec<V>,
    key: K,
    empty: V,
) -> usize {
    let next = values.len() as u32;
    let at = *index.entry(key).or_insert(next);
    if at == next {
        values.push(empty);
    }
    at as usize
}

/// The voxels the camera saw.
#[derive(Default)]
pub struct CameraCoverage {
    /// Each voxel seen, with its place among the surfaces' areas (in [`Surfaces`]), or
    /// [`NO_SURFACE`]: found once, when the voxel is first seen, rather than each time the
    /// seen area is summed (every 10 s of a run, over every voxel seen). Iterated in the
    /// order a set of the same voxels would be: a table's layout does not depend on its
    /// values.
    voxels: FxHashMap<[i32; 3], u32>,
    /// The same voxels as bits, for the test of whether a pixel's voxel is new.
    bits: VoxelBits,
}

/// A seen voxel's place among the surfaces' areas where it holds none.
const NO_SURFACE: u32 = u32::MAX;

/// A set of voxels as bits in blocks of 8 × 8 × 8, the blocks looked up by key with the last
/// one at hand. A camera's pixels fall mostly in voxels it saw before, in the block of the
/// pixel before: the test of one bit, with a lookup in a table of blocks (up to 512 voxels a
/// key) when the block changes, where the voxel set's lookup (a hash table of every voxel
/// seen, some megabytes) missed the caches and took most of a frame's scoring.
#[derive(Default)]
struct VoxelBits {
    index: FxHashMap<[i32; 3], u32>,
    blocks: Vec<[u64; 8]>,
    last: Option<([i32; 3], u32)>,
}

impl VoxelBits {
    /// Sets voxel `k`'s bit; whether it was clear.
    fn insert(&mut self, k: [i32; 3]) -> bool {
        // The block's key is the voxel's, each coordinate divided by 8 rounding down (an
        // arithmetic shift), and its bit the remainders', z choosing the word.
        let block = [k[0] >> 3, k[1] >> 3, k[2] >> 3];
        let at = match self.last {
            Some((b, at)) if b == block => at,
            _ => {
                let at = place(&mut self.index, &mut self.blocks, block, [0; 8]) as u32;
                self.last = Some((block, at));
                at
            }
        };
        let word = &mut self.blocks[at as usize][(k[2] & 7) as usize];
        let bit = 1u64 << ((k[0] & 7) | (k[1] & 7) << 3);
        let clear = *word & bit == 0;
        *word |= bit;
        clear
    }
}

impl CameraCoverage {
    /// Adds what a noiseless depth image from `optical` (the optical frame's world pose) saw
    /// between `range` (min, max, m), every `stride`-th pixel, of `surfaces`.
    pub fn add(
        &mut self,
        surfaces: &Surfaces,
        depth: &DepthImage,
        k: &Intrinsics,
        optical: &futago_msgs::Pose3,
        range: (f64, f64),
        stride: u32,
    ) {
        // Most pixels land in a voxel seen before: its key is not looked up in the set again
        // (the set's probing was most of this loop), only its bit. Its room for one more is
        // still asked for, as inserting does first, so that the set grows when it did before
        // and is iterated, and its areas summed, in the same order.
        for v in (0..depth.height).step_by(stride.max(1) as usize) {
            for u in (0..depth.width).step_by(stride.max(1) as usize) {
                let z = depth.at(u, v) as f64;
                if !(z.is_finite() && z >= range.0 && z <= range.1) {
                    continue;
                }
                let w = key(optical.transform_point(k.back_project(u as f64, v as f64, z)));
                if self.bits.insert(w) {
                    self.see(surfaces, w);
                } else {
                    self.voxels.reserve(1);
                }
            }
        }
    }

    /// Marks voxel `k` of `surfaces` seen.
    fn see(&mut self, surfaces: &Surfaces, k: [i32; 3]) {
        let at = surfaces.voxel.get(&k).copied().unwrap_or(NO_SURFACE);
        self.voxels.insert(k, at);
    }

    /// Per column of voxels (by [`column`]), which of the voxels at the heights `zs` (m, at
    /// most 64) were seen: bit `b` for `zs[b]`.
    pub fn levels_seen(&self, zs: &[f64]) -> FxHashMap<[i32; 2], u64> {
        level_masks(self.voxels.keys(), zs)
    }

    /// Whether the voxel of `p` was seen.
    pub fn saw(&self, p: [f64; 3]) -> bool {
        self.voxels.contains_key(&key(p))
    }
}

/// The floor the robot's footprint can sweep and what it swept, on a grid of the world.
pub struct Footprint {
    grid: OccupancyGrid,
    radius: f64,
    reachable: Vec<bool>,
    swept: Vec<bool>,
    total: usize,
}

impl Footprint {
    /// On `grid` (the world's map), for a disc of `radius` whose centre keeps `clearance`
    /// from obstacles, starting at `start`.
    pub fn new(
        grid: &OccupancyGrid,
        radius: f64,
        clearance: f64,
        start: [f64; 2],
    ) -> Result<Footprint, String> {
        let field = futago_robot::navigation::coverage::Field::new(grid, clearance, start)?;
        let mut f = Footprint {
            grid: grid.clone(),
            radius,
            reachable: vec![false; grid.width * grid.height],
            swept: vec![false; grid.width * grid.height],
            total: 0,
        };
        let mut reach = vec![false; grid.width * grid.height];
        for (k, r) in field.reachable.iter().enumerate() {
            if *r {
                let c = grid.cell_center(k % grid.width, k / grid.width);
                f.disc(c, &mut reach);
            }
        }
        f.reachable = reach;
        f.total = f.reachable.iter().filter(|x| **x).count();
        Ok(f)
    }

    fn disc(&self, centre: [f64; 2], out: &mut [bool]) {
        let g = &self.grid;
        for (i, j) in futago_robot::geometry::grid::cells_within(g, centre, self.radius) {
            out[j * g.width + i] = true;
        }
    }

    /// Sweeps the footprint at `pose`.
    pub fn add(&mut self, pose: &Pose2) {
        let mut swept = std::mem::take(&mut self.swept);
        self.disc([pose.x, pose.y], &mut swept);
        self.swept = swept;
    }

    /// The swept share of the reachable floor.
    pub fn share(&self) -> f64 {
        if self.total == 0 {
            return 0.0;
        }
        let got = (0..self.swept.len())
            .filter(|&k| self.swept[k] && self.reachable[k])
            .count();
        got as f64 / self.total as f64
    }

    /// The share of the reachable floor `planned` sweeps (the same grid) that this sweeps:
    /// how much of what a route promised a drive delivered. 0 when `planned` sweeps none.
    pub fn share_of(&self, planned: &Footprint) -> f64 {
        let promised: Vec<usize> = (0..planned.swept.len())
            .filter(|&k| planned.swept[k] && planned.reachable[k])
            .collect();
        if promised.is_empty() || planned.swept.len() != self.swept.len() {
            return 0.0;
        }
        let got = promised.iter().filter(|&&k| self.swept[k]).count();
        got as f64 / promised.len() as f64
    }

    /// Each cell: 0 not reachable floor, 1 reachable and not swept, 2 swept.
    pub fn states(&self) -> Vec<u8> {
        (0..self.swept.len())
            .map(|k| match (self.reachable[k], self.swept[k]) {
                (false, _) => 0,
                (true, false) => 1,
                (true, true) => 2,
            })
            .collect()
    }

    pub fn grid(&self) -> &OccupancyGrid {
        &self.grid
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rustc_hash::FxHashSet;

    /// The floor without the maths library is the maths library's, cast as it casts: on
    /// integers, halves, values a hair either side of an integer, negatives, zeros of both
    /// signs, values past `i32`'s range and past `i64`'s, infinities and NaN.
    #[test]
    fn floor_i32_equals_the_float_floor_cast() {
        let mut xs = vec![
            0.0,
            -0.0,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            3e9,
            -3e9,
            1e300,
            -1e300,
            -9.3e18,
            (i64::MIN as f64),
            4.5e15 + 0.5,
            -4.5e15 - 0.5,
        ];
        for k in -3000..3000 {
            let x = k as f64 * 0.25;
            xs.extend([x, x + 1e-9, x - 1e-9, k as f64 - f64::EPSILON]);
        }
        for x in xs {
            assert_eq!(floor_i32(x), x.floor() as i32, "{x}");
        }
    }

    /// A 2 × 1 m rectangle of floor: its area is found, and a camera that sees its left half
    /// covers half of it.
    #[test]
    fn a_triangle_pair_is_sampled_to_its_area_and_half_seen_is_half() {
        // Two regions: x < 0.5 m and beyond.
        let left_right = |p: [f64; 2]| Some(usize::from(p[0] >= 0.5));
        let mut s = Surfaces::empty();
        let (a, b, c, d) = (
            [0.0, 0.0, 0.0],
            [2.0, 0.0, 0.0],
            [2.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
        );
        // Observable: x < 1.5 m only.
        let observable = |p: [f64; 3]| p[0] < 1.5;
        s.add_triangle(a, b, c, 0, 1.0, &|_| true, &left_right, &observable);
        s.add_triangle(a, c, d, 0, 1.0, &|_| true, &left_right, &observable);
        assert!((s.total()[0] - 2.0).abs() < 1e-9, "{:?}", s.total());
        // Seen: every voxel whose centre has x < 1.
        let mut seen = CameraCoverage::default();
        for i in -2..50 {
            for j in -2..30 {
                let p = [
                    OFFSET[0] + (i as f64 + 0.5) * VOXEL,
                    OFFSET[1] + (j as f64 + 0.5) * VOXEL,
                    0.0,
                ];
                if p[0] < 1.0 {
                    seen.see(&s, key(p));
                }
            }
        }
        let got = s.seen_area(&seen)[0];
        // The voxel column straddling x = 1 (from 0.9637 to 1.0137) counts whole: up to
        // 0.0137 m × 1 m more.
        assert!((1.0 - 1e-9..=1.0 + 0.0137 + 1e-6).contains(&got), "{got}");
        // By region: the left 0.5 m (0.5 m²) all seen; of the rest (1.5 m²), the 0.5 m up to
        // x = 1 m (and the straddling column).
        let by = s.region_areas(&seen, false);
        assert_eq!(by.len(), 2);
        assert!(
            (by[0].0[0] - 0.5).abs() < 1e-9 && (by[0].1[0] - 0.5).abs() < 1e-9,
            "{by:?}"
        );
        assert!((by[1].0[0] - 1.5).abs() < 1e-9, "{by:?}");
        assert!(
            (0.5 - 1e-9..=0.5 + 0.0137 + 1e-6).contains(&by[1].1[0]),
            "{by:?}"
        );
        // Of the observable part, the right region holds 1 m² (x from 0.5 to 1.5 m), of which
        // the same 0.5 m² was seen; the left region is all observable.
        let ob = s.region_areas(&seen, true);
        assert!((ob[0].0[0] - 0.5).abs() < 1e-9, "{ob:?}");
        assert!((ob[1].0[0] - 1.0).abs() < 1e-6, "{ob:?}");
        assert!((ob[1].1[0] - by[1].1[0]).abs() < 1e-9, "{ob:?}");
        // A wall below `top` only: a 1 m high face cut at 0.5 m counts half.
        let mut w = Surfaces::empty();
        w.add_triangle(
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 0.0, 1.0],
            1,
            0.5,
            &|_| true,
            &|_| None,
            &|_| true,
        );
        w.add_triangle(
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 1.0],
            [0.0, 0.0, 1.0],
            1,
            0.5,
            &|_| true,
            &|_| None,
            &|_| true,
        );
        assert!((w.total()[1] - 0.5).abs() < 0.02, "{:?}", w.total());
    }

    /// The column masks say, level by level, what `holds` and `saw` say voxel by voxel: on
    /// a wall (class 1) and a desk's side (class 2) in one column, half seen.
    #[test]
    fn the_columns_hold_and_saw_what_their_voxels_do() {
        let mut s = Surfaces::empty();
        let face = |s: &mut Surfaces, x: f64, z1: f64, class: usize| {
            let (a, b, c, d) = ([x, 0.0, 0.0], [x, 0.2, 0.0], [x, 0.2, z1], [x, 0.0, z1]);
            for (p, q, r) in [(a, b, c), (a, c, d)] {
                s.add_triangle(p, q, r, class, 2.0, &|_| true, &|_| None, &|_| true);
            }
        };
        face(&mut s, 0.3, 2.0, 1);
        face(&mut s, 1.1, 0.7, 2);
        let mut seen = CameraCoverage::default();
        for k in 0..=40 {
            seen.see(&s, key([0.3, 0.1, k as f64 * 0.025]));
        }
        let zs: Vec<f64> = (0..60).map(|k| k as f64 * 0.05).collect();
        let seen_levels = seen.levels_seen(&zs);
        for class in [1, 2] {
            let held = s.levels_held(&zs, class);
            for x in [0.3, 0.5, 1.1] {
                for y in [0.05, 0.1, 0.3] {
                    let c = column([x, y]);
                    let (h, v) = (
                        held.get(&c).copied().unwrap_or(0),
                        seen_levels.get(&c).copied().unwrap_or(0),
                    );
                    for (b, &z) in zs.iter().enumerate() {
                        let p = [x, y, z];
                        assert_eq!(h >> b & 1 == 1, s.holds(p, class), "{p:?} {class}");
                        assert_eq!(v >> b & 1 == 1, seen.saw(p), "{p:?}");
                    }
                }
            }
        }
        // The wall's column is held up to 2 m and seen up to 1 m; the desk's up to 0.7 m.
        let wall = s.levels_held(&zs, 1)[&column([0.3, 0.1])];
        assert_eq!(wall.count_ones(), 41, "{wall:b}");
        assert_eq!((wall & seen_levels[&column([0.3, 0.1])]).count_ones(), 21);
        assert_eq!(s.levels_held(&zs, 2)[&column([1.1, 0.1])].count_ones(), 15);
    }

    /// A `w` × `h` grid of 5 cm cells, free inside a one-cell wall.
    fn walled(w: usize, h: usize) -> OccupancyGrid {
        let mut g = OccupancyGrid::new(0.05, [0.0, 0.0], w, h);
        for j in 0..h {
            for i in 0..w {
                let wall = j == 0 || j == h - 1 || i == 0 || i == w - 1;
                g.set(i, j, if wall { 100 } else { 0 });
            }
        }
        g
    }

    /// A robot that drives along the middle of a 0.9 m wide corridor sweeps a 0.34 m strip of
    /// the floor its footprint can reach (its centre keeps 0.2 m from the walls' edges, at 0.05
    /// and 0.95 m: 0.25 m to 0.75 m across, and 0.17 m more each side).
    #[test]
    fn a_straight_drive_sweeps_its_strip() {
        let g = walled(100, 20);
        let mut f = Footprint::new(&g, 0.17, 0.2, [1.0, 0.5]).unwrap();
        for k in 0..=60 {
            f.add(&Pose2::new(1.0 + k as f64 * 0.05, 0.5, 0.0));
        }
        // In 5 cm cells: reachable centres are the cells 0.2 m from the wall cells' edges
        // (y from 0.275 to 0.725 m, x from 0.275 to 4.725 m); the floor they can sweep, the
        // cells within 0.17 m of those, is 16 × 96 cells. The drive sweeps the 6 rows whose
        // centres lie within 0.17 m of y = 0.5 m along 60 cells, and about 18 cells of each
        // end's half-disc.
        let share = f.share();
        let expected = (6.0 * 60.0 + 2.0 * 18.0) / (16.0 * 96.0);
        assert!((share - expected).abs() < 0.01, "{share} vs {expected}");
    }

    /// A drive that stops halfway along a planned straight delivers about half of what the
    /// plan swept, whatever else it sweeps beside it.
    #[test]
    fn a_drive_is_scored_against_the_route_it_was_promised() {
        let g = walled(100, 40);
        let mut planned = Footprint::new(&g, 0.17, 0.2, [1.0, 0.5]).unwrap();
        let mut driven = Footprint::new(&g, 0.17, 0.2, [1.0, 0.5]).unwrap();
        for k in 0..=60 {
            planned.add(&Pose2::new(1.0 + k as f64 * 0.05, 0.5, 0.0));
        }
        for k in 0..=30 {
            driven.add(&Pose2::new(1.0 + k as f64 * 0.05, 0.5, 0.0));
            driven.add(&Pose2::new(1.0 + k as f64 * 0.05, 1.5, 0.0));
        }
        // 6 rows × 60 cells and the two ends' 18-cell half-discs promised; 6 × 30 and two
        // half-discs delivered (the first drive's start, and its end's, which lies inside the
        // promised strip); the second drive, off the route, counts for nothing.
        let got = driven.share_of(&planned);
        let expected = (6.0 * 30.0 + 2.0 * 18.0) / (6.0 * 60.0 + 2.0 * 18.0);
        assert!((got - expected).abs() < 0.03, "{got} vs {expected}");
        assert_eq!(planned.share_of(&planned), 1.0);
    }

    /// The blocks of bits hold what a set of keys holds: on random keys about the origin
    /// (negative ones, block borders) and repeats, each insertion says whether the key is new.
    #[test]
    fn voxel_bits_are_a_set() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        let mut bits = VoxelBits::default();
        let mut set = FxHashSet::default();
        for _ in 0..20_000 {
            let k = [
                rng.random_range(-20..20),
                rng.random_range(-20..20),
                rng.random_range(-9..9),
            ];
            assert_eq!(bits.insert(k), set.insert(k), "{k:?}");
        }
        assert!(set.len() > 5_000 && set.len() < 14_400, "{}", set.len());
    }

    /// A depth image's voxels go into the set as inserting every pixel's voxel in turn would
    /// put them: the same voxels, iterated (and so summed) in the same order, frame after
    /// frame, whatever the bits skip.
    #[test]
    fn frames_fill_the_set_as_inserting_every_pixel_does() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let k = Intrinsics {
            width: 64,
            height: 48,
            fx: 57.5,
            fy: 57.5,
            cx: 31.5,
            cy: 23.5,
        };
        let mut seen = CameraCoverage::default();
        let mut every = FxHashSet::default();
        for frame in 0..40 {
            let depth = DepthImage {
                width: k.width,
                height: k.height,
                data: (0..k.width * k.height)
                    .map(|_| match rng.random_range(0..20) {
                        0 => 0.0,
                        _ => rng.random_range(0.8f32..3.5),
                    })
                    .collect(),
            };
            let optical = futago_msgs::Pose3::from_pose2(
                &Pose2::new(0.1 * frame as f64, -0.05 * frame as f64, 0.3 * frame as f64),
                0.4,
            );
            let (range, stride) = ((1.0, 3.0), 1 + frame % 3);
            seen.add(&Surfaces::empty(), &depth, &k, &optical, range, stride);
            for v in (0..k.height).step_by(stride as usize) {
                for u in (0..k.width).step_by(stride as usize) {
                    let z = depth.at(u, v) as f64;
                    if z >= range.0 && z <= range.1 {
                        every.insert(key(
                            optical.transform_point(k.back_project(u as f64, v as f64, z))
                        ));
                    }
                }
            }
            let got: Vec<_> = seen.voxels.keys().collect();
            let want: Vec<_> = every.iter().collect();
            assert_eq!(got, want, "frame {frame}");
        }
        assert!(every.len() > 10_000, "{}", every.len());
    }
}
