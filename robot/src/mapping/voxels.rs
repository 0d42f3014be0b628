//! A 3D map of occupied, free and unknown space from range measurements: seed 004's cubic
//! lattice (§6: voxels holding measured points are obstacles, voxels a measurement showed
//! empty are free, the rest unmeasured), its compression along the height axis into a 2D grid
//! for view planning, and the removal of moving objects by free-space carving.
//!
//! Each voxel holds a clamped log-odds of occupancy, updated as OctoMap does (Hornung et al.,
//! Autonomous Robots 2013: a hit adds logit(0.7), a miss logit(0.4), clamped to logit(0.12) …
//! logit(0.97), occupied above logit(0.5) = 0). A beam's voxels are found by Amanatides and
//! Woo's traversal (Eurographics 1987). As in OctoMap's point-cloud insertion, one scan updates
//! a voxel once: a voxel that any of its beams ends in is a hit, and the others they cross
//! are misses. So beams of one scan never carve each other's surfaces.
//!
//! Removal: by default a point is kept when at least as many scans ended in its voxel as
//! passed through it ([`Carving::Majority`], a verdict that does not depend on the scans'
//! order); or, as OctoMap, when its voxel's log-odds ends occupied ([`Carving::LogOdds`]). A
//! person who walked through is seen through by other scans, so their points go (the
//! DynamicMap benchmark's OctoMap baseline, Zhang et al. 2023). Beams that graze the floor cross floor
//! voxels on their way to a farther floor hit and would carve the floor, the classic failure
//! of this method; the benchmark runs it with ground segmentation for that reason. Here no
//! miss is counted in a voxel that lies wholly under `floor_clearance` above the floor (z = 0
//! in the map frame, where the robot stands), so the floor is never carved; ERASOR (Lim et
//! al. 2021) likewise never removes ground.
//!
//! Written here: the maintained voxel crates either render (no log-odds or traversal) or wrap
//! C++ OctoMap.

use crate::config::ConfigError;
use crate::geometry::floor_i64;
use futago_msgs::grid::OccupancyGrid;
use rustc_hash::FxHashMap;
use serde::{Deserialize, Serialize};

/// Parameters of the voxel map (`…voxels.*`).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct VoxelConfig {
    /// Voxel side, m. ERASOR and the DynamicMap benchmark score at 0.2 m; seed 004 gives
    /// none. 0.1 m keeps a corridor's door recesses and a person's legs apart.
    pub voxel: f64,
    /// Probability a hit stands for (OctoMap: 0.7).
    pub p_hit: f64,
    /// Probability a miss stands for (OctoMap: 0.4).
    pub p_miss: f64,
    /// Clamping bounds on a voxel's probability (OctoMap: 0.12 and 0.97), so that a voxel
    /// seen often can still change when the world does.
    pub p_min: f64,
    pub p_max: f64,
    /// Voxels wholly below this height above the floor take no misses, m (the floor is
    /// never carved; see the module's notes).
    pub floor_clearance: f64,
    /// No miss is counted in a voxel whose centre lies within this of the end of a beam
    /// that hit something, m. A beam that meets a surface at a grazing angle θ runs within
    /// one voxel of it for `voxel / tan θ` before it ends, through voxels of that surface
    /// that other beams hit; 0.5 m spares surfaces seen at down to 11° with 0.1 m voxels.
    /// Without it, grazing beams down the corridor world carved a tenth of its walls' points
    /// (`corridor-scan3d`, seed 1: static accuracy off the floor 0.90, against 0.994 with
    /// 0.5 m; 0.2 m gave 0.955, 1 m 0.998 but removed 83 % of the people's points rather
    /// than 93 %). The cost: a person within the margin of a wall is not carved by the beams
    /// that end on that wall.
    pub miss_margin: f64,
    /// Which points carving keeps ([`Carving`]).
    pub carving: Carving,
}

/// The rule by which free-space carving keeps a point.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Carving {
    /// Its voxel has been hit by at least as many scans as have passed through it. The
    /// verdict does not depend on the order of the scans: a person hit by twenty scans of a
    /// slow sweep where twenty-one scans saw through, before or after, is removed.
    #[default]
    Majority,
    /// Its voxel's clamped log-odds ends occupied (OctoMap). Order matters: a voxel hit by
    /// many scans in a row sits at the upper clamp and needs nine misses to turn free, so
    /// what was measured last wins.
    LogOdds,
}

impl Default for VoxelConfig {
    fn default() -> Self {
        VoxelConfig {
            voxel: 0.1,
            p_hit: 0.7,
            p_miss: 0.4,
            p_min: 0.12,
            p_max: 0.97,
            floor_clearance: 0.1,
            miss_margin: 0.5,
            carving: Carving::Majority,
        }
    }
}

impl VoxelConfig {
    /// Checks values, naming `PREFIX.KEY`.
    pub fn validate(&self, prefix: &str) -> Result<(), ConfigError> {
        crate::config::check_ranges(
            prefix,
            &[
                ("voxel", self.voxel, 0.01, 10.0),
                ("p_hit", self.p_hit, 0.5, 0.999),
                ("p_miss", self.p_miss, 0.001, 0.5),
                ("p_min", self.p_min, 0.001, 0.5),
                ("p_max", self.p_max, 0.5, 0.999),
                ("floor_clearance", self.floor_clearance, 0.0, 1.0),
                ("miss_margin", self.miss_margin, 0.0, 10.0),
            ],
        )?;
        if self.p_hit == 0.5 && self.p_miss == 0.5 {
            return Err((
                crate::config::below(prefix, "p_hit"),
                "p_hit and p_miss are both 0.5, so measurements change nothing".into(),
            ));
        }
        Ok(())
    }
}

/// What a voxel is known to hold.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Voxel {
    Unknown,
    Free,
    Occupied,
}

fn logit(p: f64) -> f64 {
    (p / (1.0 - p)).ln()
}

/// Integer coordinates of a voxel.
pub type Key = [i64; 3];

/// A block of the map's store holds `2^BLOCK_BITS` voxels along each axis (4: 64 voxels).
const BLOCK_BITS: u32 = 2;
const BLOCK_MASK: i64 = (1 << BLOCK_BITS) - 1;
const BLOCK_CELLS: usize = 1 << (3 * BLOCK_BITS);

/// The block holding voxel `k` (its key shifted: the floor for negative keys too) and the
/// voxel's place in it.
fn split(k: Key) -> (Key, usize) {
    let b = k.map(|c| c >> BLOCK_BITS);
    let i = (k[0] & BLOCK_MASK)
        | ((k[1] & BLOCK_MASK) << BLOCK_BITS)
        | ((k[2] & BLOCK_MASK) << (2 * BLOCK_BITS));
    (b, i as usize)
}

/// The map: log-odds of the voxels measured so far.
///
/// The voxels are stored in blocks of 4×4×4, found by the block's key in a hash map, so that
/// the voxels one beam crosses share a few lookups and lie together in memory: a map keyed
/// by each voxel spent most of a turntable survey's insertion in its lookups' cache misses
/// (issue 48). The store only changes where a voxel lives, not what it holds: a voxel is
/// measured when a scan has hit or passed through it.
#[derive(Debug, Clone)]
pub struct VoxelMap {
    config: VoxelConfig,
    /// Each block's index in `blocks`, by its key.
    index: FxHashMap<Key, u32>,
    blocks: Vec<[Cell; BLOCK_CELLS]>,
    /// Voxels measured.
    measured: usize,
    /// The number of the scan being inserted (0 before the first): a voxel's `scan` says
    /// whether this scan has updated it already.
    scan: u32,
}

/// A voxel: its clamped log-odds, the scans that ended in it (hits) and that passed through
/// it (misses), and the last scan that updated it. Unmeasured while both counts are 0.
#[derive(Debug, Clone, Copy, Default)]
struct Cell {
    log_odds: f32,
    hits: u32,
    misses: u32,
    scan: u32,
}

impl Cell {
    fn measured(&self) -> bool {
        self.hits > 0 || self.misses > 0
    }
}

impl VoxelMap {
    pub fn new(config: VoxelConfig) -> VoxelMap {
        VoxelMap {
            config,
            index: FxHashMap::default(),
            blocks: Vec::new(),
            measured: 0,
            scan: 0,
        }
    }

    pub fn config(&self) -> &VoxelConfig {
        &self.config
    }

    /// The voxel holding `p`.
    pub fn key(&self, p: [f64; 3]) -> Key {
        p.map(|c| floor_i64(c / self.config.voxel))
    }

    /// Voxel `k`, if measured.
    fn cell(&self, k: Key) -> Option<&Cell> {
        let (b, i) = split(k);
        self.index
            .get(&b)
            .map(|&n| &self.blocks[n as usize][i])
            .filter(|c| c.measured())
    }

    /// The index of block `b`, made (unmeasured) if new. `last` caches the last block asked
    /// for: a beam's voxels come a few to a block.
    fn block(&mut self, b: Key, last: &mut Option<(Key, u32)>) -> usize {
        if let Some((key, n)) = *last
            && key == b
        {
            return n as usize;
        }
        let next = self.blocks.len() as u32;
        let n = *self.index.entry(b).or_insert(next);
        if n == next {
            self.blocks.push([Cell::default(); BLOCK_CELLS]);
        }
        *last = Some((b, n));
        n as usize
    }

    /// Every measured voxel with its key, block by block (in the index's order).
    fn measured_cells(&self) -> impl Iterator<Item = (Key, &Cell)> {
        self.index
            .iter()
            .map(|(b, &n)| (b, &self.blocks[n as usize]))
            .flat_map(|(b, cells)| {
                cells.iter().enumerate().map(move |(i, c)| {
                    let i = i as i64;
                    let k = [
                        (b[0] << BLOCK_BITS) | (i & BLOCK_MASK),
                        (b[1] << BLOCK_BITS) | ((i >> BLOCK_BITS) & BLOCK_MASK),
                        (b[2] << BLOCK_BITS) | (i >> (2 * BLOCK_BITS)),
                    ];
                    (k, c)
                })
            })
            .filter(|(_, c)| c.measured())
    }

    /// What voxel `k` holds.
    pub fn state(&self, k: Key) -> Voxel {
        match self.cell(k) {
            None => Voxel::Unknown,
            Some(c) if c.log_odds > 0.0 => Voxel::Occupied,
            Some(_) => Voxel::Free,
        }
    }

    /// How many scans ended in voxel `k` (hits) and passed through it (misses).
    pub fn counts(&self, k: Key) -> (u32, u32) {
        self.cell(k).map_or((0, 0), |c| (c.hits, c.misses))
    }

    /// Voxels measured (free or occupied).
    pub fn len(&self) -> usize {
        self.measured
    }

    pub fn is_empty(&self) -> bool {
        self.measured == 0
    }

    /// The occupied voxels, in key order.
    pub fn occupied(&self) -> Vec<Key> {
        let mut v: Vec<Key> = self
            .measured_cells()
            .filter(|(_, c)| c.log_odds > 0.0)
            .map(|(k, _)| k)
            .collect();
        v.sort_unstable();
        v
    }

    /// Inserts one scan's beams from `origin` (the sensor's position, map frame): each beam
    /// as its end point and whether it hit something there (false: nothing within range, the
    /// end being the range's limit along the beam). Non-finite beams are skipped.
    ///
    /// The voxels the beams end in take a hit, then the others they cross a miss, each voxel
    /// once: a voxel's `scan` marks it updated by this scan.
    pub fn insert_scan(&mut self, origin: [f64; 3], beams: &[([f64; 3], bool)]) {
        if !origin.iter().all(|c| c.is_finite()) {
            return;
        }
        self.scan = self.scan.wrapping_add(1);
        if self.scan == 0 {
            // After 2³² scans: no voxel may keep a mark that a new scan's number repeats.
            for c in self.blocks.iter_mut().flatten() {
                c.scan = 0;
            }
            self.scan = 1;
        }
        let (l_hit, l_miss) = (
            logit(self.config.p_hit) as f32,
            logit(self.config.p_miss) as f32,
        );
        let (lo, hi) = (
            logit(self.config.p_min) as f32,
            logit(self.config.p_max) as f32,
        );
        let finite = |end: &[f64; 3]| end.iter().all(|c| c.is_finite());
        // A hit or a miss in voxel `k`, unless this scan has updated it already.
        let mut cached = None;
        let mut update = |map: &mut VoxelMap, k: Key, hit: bool| {
            let (b, i) = split(k);
            let n = map.block(b, &mut cached);
            let c = &mut map.blocks[n][i];
            if c.scan != map.scan {
                map.measured += usize::from(!c.measured());
                c.scan = map.scan;
                c.log_odds = (c.log_odds + if hit { l_hit } else { l_miss }).clamp(lo, hi);
                if hit {
                    c.hits += 1;
                } else {
                    c.misses += 1;
                }
            }
        };
        for (end, _) in beams.iter().filter(|(end, hit)| *hit && finite(end)) {
            let k = self.key(*end);
            update(self, k, true);
        }
        let floor_top = (self.config.floor_clearance / self.config.voxel).floor() as i64;
        let (margin, v) = (self.config.miss_margin, self.config.voxel);
        for (end, hit) in beams.iter().filter(|(end, _)| finite(end)) {
            let last = self.key(*end);
            traverse_each(origin, *end, v, |k| {
                if k == last {
                    return false;
                }
                if *hit && margin > 0.0 {
                    let c = [0, 1, 2].map(|i| (k[i] as f64 + 0.5) * v - end[i]);
                    if (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt() < margin {
                        return true;
                    }
                }
                // A voxel whose top is under the clearance lies wholly below it.
                if k[2] + 1 > floor_top {
                    update(self, k, false);
                }
                true
            });
            if !*hit && last[2] + 1 > floor_top {
                update(self, last, false);
            }
        }
    }

    /// Whether carving keeps a point in voxel `k` (by the configured [`Carving`] rule).
    pub fn keeps(&self, k: Key) -> bool {
        match self.config.carving {
            Carving::Majority => self
                .cell(k)
                .is_some_and(|c| c.hits >= c.misses && c.hits > 0),
            Carving::LogOdds => self.state(k) == Voxel::Occupied,
        }
    }

    /// The points of `cloud` carving keeps: the cloud with what moved through it removed.
    pub fn keep_static(&self, cloud: &[[f64; 3]]) -> Vec<[f64; 3]> {
        cloud
            .iter()
            .filter(|p| self.keeps(self.key(**p)))
            .copied()
            .collect()
    }

    /// Seed 004's 2D grid (§6): the voxels from `z_min` up to `z_max` compressed along the
    /// height axis into cells of the voxels' side. A cell is occupied (100) when any of its
    /// voxels in the band is, free (0) when none is and one is free or the floor just below
    /// the band was measured there, and unknown (−1) otherwise; chairs and desks at different
    /// heights become obstacles in one plane, as the seed says. Measured floor counts as
    /// free because rays are not carved within `miss_margin` of their hits: the band over
    /// floor near walls and near the robot is rarely carved, though the floor's points show
    /// it open. The grid spans the measured voxels; `None` when none lies in the band.
    pub fn project(&self, z_min: f64, z_max: f64) -> Option<OccupancyGrid> {
        let v = self.config.voxel;
        let (k0, k1) = ((z_min / v).floor() as i64, (z_max / v).ceil() as i64 - 1);
        let band: Vec<(Key, f32)> = self
            .measured_cells()
            .filter(|(k, _)| k[2] >= k0 && k[2] <= k1)
            .map(|(k, c)| (k, c.log_odds))
            .collect();
        // The floor: occupied voxels up to two below the band.
        let floor: Vec<Key> = self
            .measured_cells()
            .filter(|(k, c)| k[2] < k0 && k[2] >= k0 - 2 && c.log_odds > 0.0)
            .map(|(k, _)| k)
            .collect();
        let (mut lo, mut hi) = ([i64::MAX; 2], [i64::MIN; 2]);
        for k in band.iter().map(|(k, _)| k).chain(&floor) {
            for d in 0..2 {
                lo[d] = lo[d].min(k[d]);
                hi[d] = hi[d].max(k[d]);
            }
        }
        if band.is_empty() {
            return None;
        }
        let (w, h) = ((hi[0] - lo[0] + 1) as usize, (hi[1] - lo[1] + 1) as usize);
        let mut grid = OccupancyGrid::new(v, [lo[0] as f64 * v, lo[1] as f64 * v], w, h);
        for (k, l) in band {
            let (i, j) = ((k[0] - lo[0]) as usize, (k[1] - lo[1]) as usize);
            if l > 0.0 {
                grid.set(i, j, 100);
            } else if grid.get(i, j) < 0 {
                grid.set(i, j, 0);
            }
        }
        for k in floor {
            let (i, j) = ((k[0] - lo[0]) as usize, (k[1] - lo[1]) as usize);
            if grid.get(i, j) < 0 {
                grid.set(i, j, 0);
            }
        }
        Some(grid)
    }
}

/// The voxels of side `size` the segment from `a` to `b` passes through, in order from `a`'s
/// to `b`'s (Amanatides and Woo's traversal). Consecutive voxels share a face. A segment
/// longer than a million voxels is cut there (a corrupt point, not a measurement).
pub fn traverse(a: [f64; 3], b: [f64; 3], size: f64) -> Vec<Key> {
    let mut out = Vec::new();
    traverse_each(a, b, size, |k| {
        out.push(k);
        true
    });
    out
}

/// [`traverse`]'s voxels handed to `visit` in order, with no list made; `visit` returning
/// false stops the walk.
pub fn traverse_each(a: [f64; 3], b: [f64; 3], size: f64, mut visit: impl FnMut(Key) -> bool) {
    const MAX_STEPS: usize = 1_000_000;
    let key = |p: [f64; 3]| p.map(|c| floor_i64(c / size));
    let (mut k, last) = (key(a), key(b));
    let d = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
    let mut step = [0i64; 3];
    let mut t_max = [f64::INFINITY; 3];
    let mut t_delta = [f64::INFINITY; 3];
    for i in 0..3 {
        if d[i] > 0.0 {
            step[i] = 1;
            t_max[i] = ((k[i] + 1) as f64 * size - a[i]) / d[i];
            t_delta[i] = size / d[i];
        } else if d[i] < 0.0 {
            step[i] = -1;
            t_max[i] = (k[i] as f64 * size - a[i]) / d[i];
            t_delta[i] = -size / d[i];
        }
    }
    if !visit(k) {
        return;
    }
    let mut visited = 1;
    // Each axis's next face apart, and each step's axis as a constant index: with an index
    // only known at run time, the three were kept in memory, and each step waited on the
    // store and load of the last (a third of a scan's insertion).
    let [mut tx, mut ty, mut tz] = t_max;
    while k != last && visited < MAX_STEPS {
        let (i, t) = if tx <= ty && tx <= tz {
            (0, tx)
        } else if ty <= tz {
            (1, ty)
        } else {
            (2, tz)
        };
        if t > 1.0 {
            // Rounding: the end's voxel was missed by a hair; it is the next one.
            visit(last);
            return;
        }
        match i {
            0 => {
                k[0] += step[0];
                tx += t_delta[0];
            }
            1 => {
                k[1] += step[1];
                ty += t_delta[1];
            }
            _ => {
                k[2] += step[2];
                tz += t_delta[2];
            }
        }
        visited += 1;
        if !visit(k) {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Whether the segment a–b meets the voxel `k` of side `s` (slab test, with a hair's
    /// tolerance for segments along a face).
    fn meets(a: [f64; 3], b: [f64; 3], k: Key, s: f64) -> bool {
        let (mut t0, mut t1) = (0.0f64, 1.0f64);
        for i in 0..3 {
            let (lo, hi) = (k[i] as f64 * s - 1e-9, (k[i] + 1) as f64 * s + 1e-9);
            let d = b[i] - a[i];
            if d.abs() < 1e-15 {
                if a[i] < lo || a[i] > hi {
                    return false;
                }
            } else {
                let (u, v) = ((lo - a[i]) / d, (hi - a[i]) / d);
                t0 = t0.max(u.min(v));
                t1 = t1.min(u.max(v));
            }
        }
        t0 <= t1
    }

    /// Along an axis the traversal is every voxel from the start's to the end's; askew it is
    /// a face-connected chain from the start's voxel to the end's whose every voxel the
    /// segment meets.
    #[test]
    fn the_traversal_visits_the_voxels_a_segment_crosses() {
        let ks = traverse([0.05, 0.05, 0.05], [1.05, 0.05, 0.05], 0.1);
        assert_eq!(ks.len(), 11);
        for (i, k) in ks.iter().enumerate() {
            assert_eq!(*k, [i as i64, 0, 0]);
        }
        let mut state = 12345u64;
        let mut r = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64 * 6.0 - 3.0
        };
        for _ in 0..200 {
            let (a, b) = ([r(), r(), r()], [r(), r(), r()]);
            let ks = traverse(a, b, 0.1);
            assert_eq!(ks[0], a.map(|c| (c / 0.1).floor() as i64));
            assert_eq!(*ks.last().unwrap(), b.map(|c| (c / 0.1).floor() as i64));
            for w in ks.windows(2) {
                let d: i64 = (0..3).map(|i| (w[1][i] - w[0][i]).abs()).sum();
                assert_eq!(d, 1, "{:?} → {:?} do not share a face", w[0], w[1]);
            }
            for k in &ks {
                assert!(meets(a, b, *k, 0.1), "{k:?} is off the segment {a:?}–{b:?}");
            }
            // And no voxel is skipped: the count is the faces crossed plus one.
            let crossed: i64 = (0..3)
                .map(|i| ((b[i] / 0.1).floor() as i64 - (a[i] / 0.1).floor() as i64).abs())
                .sum();
            assert_eq!(ks.len() as i64, crossed + 1);
        }
    }

    /// The store in blocks holds what a map keyed by each voxel holds: random scans from
    /// origins on both sides of zero (blocks of negative keys), with and without the margin
    /// and the floor's clearance, against the rule written out with sets, voxel by voxel
    /// over the whole volume, and the occupied list, the count and the projected grid.
    #[test]
    fn the_blocks_hold_what_a_map_of_each_voxel_holds() {
        let mut state = 99u64;
        let mut r = move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for config in [
            VoxelConfig::default(),
            VoxelConfig {
                miss_margin: 0.0,
                floor_clearance: 0.0,
                voxel: 0.13,
                ..VoxelConfig::default()
            },
        ] {
            let mut m = VoxelMap::new(config);
            // The reference: log-odds, hits, misses by voxel.
            let mut reference: std::collections::HashMap<Key, (f32, u32, u32)> = Default::default();
            let v = config.voxel;
            let (l_hit, l_miss) = (logit(config.p_hit) as f32, logit(config.p_miss) as f32);
            let (lo, hi) = (logit(config.p_min) as f32, logit(config.p_max) as f32);
            let floor_top = (config.floor_clearance / v).floor() as i64;
            for _ in 0..60 {
                let origin = [r() * 4.0 - 2.0, r() * 4.0 - 2.0, r() * 1.5];
                let beams: Vec<([f64; 3], bool)> = (0..40)
                    .map(|_| {
                        let end = [r() * 8.0 - 4.0, r() * 8.0 - 4.0, r() * 2.5 - 0.2];
                        (end, r() < 0.8)
                    })
                    .collect();
                m.insert_scan(origin, &beams);
                let (mut hits, mut misses) = (
                    std::collections::HashSet::new(),
                    std::collections::HashSet::new(),
                );
                for (end, hit) in &beams {
                    let last = m.key(*end);
                    for k in traverse(origin, *end, v) {
                        if k == last {
                            break;
                        }
                        let c = [0, 1, 2].map(|i| (k[i] as f64 + 0.5) * v - end[i]);
                        let near =
                            (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt() < config.miss_margin;
                        if !(*hit && config.miss_margin > 0.0 && near) && k[2] + 1 > floor_top {
                            misses.insert(k);
                        }
                    }
                    if *hit {
                        hits.insert(last);
                    } else if last[2] + 1 > floor_top {
                        misses.insert(last);
                    }
                }
                for k in &hits {
                    let c = reference.entry(*k).or_default();
                    c.0 = (c.0 + l_hit).clamp(lo, hi);
                    c.1 += 1;
                }
                for k in misses.difference(&hits) {
                    let c = reference.entry(*k).or_default();
                    c.0 = (c.0 + l_miss).clamp(lo, hi);
                    c.2 += 1;
                }
            }
            assert_eq!(m.len(), reference.len());
            let n = (4.5 / v).ceil() as i64;
            for i in -n..=n {
                for j in -n..=n {
                    for k in -3..=(3.0 / v) as i64 {
                        let key = [i, j, k];
                        let want = reference.get(&key);
                        assert_eq!(
                            m.counts(key),
                            want.map_or((0, 0), |c| (c.1, c.2)),
                            "{key:?}"
                        );
                        let state = match want {
                            None => Voxel::Unknown,
                            Some(c) if c.0 > 0.0 => Voxel::Occupied,
                            Some(_) => Voxel::Free,
                        };
                        assert_eq!(m.state(key), state, "{key:?}");
                    }
                }
            }
            let mut occupied: Vec<Key> = reference
                .iter()
                .filter(|(_, c)| c.0 > 0.0)
                .map(|(k, _)| *k)
                .collect();
            occupied.sort_unstable();
            assert!(occupied.iter().any(|k| k[0] < 0 && k[1] < 0));
            assert_eq!(m.occupied(), occupied);
            let g = m.project(0.1, 1.0).unwrap();
            for (k, c) in &reference {
                if k[2] >= (0.1 / v).floor() as i64 && k[2] < (1.0 / v).ceil() as i64 && c.0 > 0.0 {
                    let (x, y) = ((k[0] as f64 + 0.5) * v, (k[1] as f64 + 0.5) * v);
                    let (ci, cj) = g.cell_of(x, y).unwrap();
                    assert_eq!(g.get(ci, cj), 100, "{k:?}");
                }
            }
        }
    }

    /// A beam's voxels before its end are free and its end occupied; a beam that hit nothing
    /// leaves its whole length free; what no beam crossed is unknown. With the default
    /// margin, the voxels within 0.5 m before a hit take no miss.
    #[test]
    fn a_beam_frees_what_it_crosses_and_fills_where_it_ends() {
        let beams = [([1.05, 0.05, 1.05], true), ([0.05, 2.05, 1.05], false)];
        let mut m = VoxelMap::new(VoxelConfig {
            miss_margin: 0.0,
            ..VoxelConfig::default()
        });
        m.insert_scan([0.05, 0.05, 1.05], &beams);
        for i in 0..10 {
            assert_eq!(m.state([i, 0, 10]), Voxel::Free, "x voxel {i}");
        }
        assert_eq!(m.state([10, 0, 10]), Voxel::Occupied);
        for j in 1..=20 {
            assert_eq!(m.state([0, j, 10]), Voxel::Free, "y voxel {j}");
        }
        assert_eq!(m.state([5, 5, 10]), Voxel::Unknown);
        assert_eq!(m.occupied(), vec![[10, 0, 10]]);
        // Voxel 5's centre is 0.5 m from the hit: free; 6 … 9 are nearer.
        let mut m = VoxelMap::new(VoxelConfig::default());
        m.insert_scan([0.05, 0.05, 1.05], &beams);
        for i in 1..=5 {
            assert_eq!(m.state([i, 0, 10]), Voxel::Free, "x voxel {i}");
        }
        for i in 6..10 {
            assert_eq!(m.state([i, 0, 10]), Voxel::Unknown, "x voxel {i}");
        }
        assert_eq!(
            m.state([0, 20, 10]),
            Voxel::Free,
            "a beam with no return is not shortened"
        );
    }

    /// A person stands 1.5 m before a wall for one scan, then walks off; later scans see the
    /// wall through where they stood. Their points go and the wall's stay. Without the later
    /// scans the person would stay: removal needs the space seen empty.
    #[test]
    fn what_moved_away_is_carved_and_the_wall_stays() {
        let origin = [0.05, 0.05, 1.0];
        // A segment of beams ending at x across y0 … y0 + 0.05 (n − 1).
        let beams = |x: f64, y0: f64, n: usize| -> Vec<([f64; 3], bool)> {
            (0..n)
                .map(|i| ([x, y0 + i as f64 * 0.05, 1.0], true))
                .collect()
        };
        // The person spans the wall's bearings from the sensor, so the wall's beams pass
        // through all of them.
        let person: Vec<[f64; 3]> = beams(1.55, -0.45, 20).iter().map(|b| b.0).collect();
        let wall_beams = beams(3.05, -1.0, 43);
        let wall: Vec<[f64; 3]> = wall_beams.iter().map(|b| b.0).collect();
        let mut m = VoxelMap::new(VoxelConfig::default());
        m.insert_scan(origin, &beams(1.55, -0.45, 20));
        let cloud: Vec<[f64; 3]> = person.iter().chain(&wall).copied().collect();
        assert_eq!(
            m.keep_static(&cloud),
            person,
            "the person alone is seen so far"
        );
        for _ in 0..3 {
            m.insert_scan(origin, &wall_beams);
        }
        assert_eq!(m.keep_static(&cloud), wall);
    }

    /// Twenty-one scans see the wall through a place, and a person then stands there for
    /// twenty scans of a slow sweep (or the other way round): the majority rule removes them
    /// in either order, while OctoMap's log-odds keeps whoever came last.
    #[test]
    fn the_majority_rule_does_not_depend_on_the_scans_order() {
        let origin = [0.05, 0.05, 1.05];
        let person = [([1.55, 0.05, 1.05], true)];
        let wall = [([3.05, 0.05, 1.05], true)];
        let run = |carving: Carving, person_last: bool| {
            let mut m = VoxelMap::new(VoxelConfig {
                carving,
                ..VoxelConfig::default()
            });
            let (first, n_first, second, n_second) = if person_last {
                (&wall, 21, &person, 20)
            } else {
                (&person, 20, &wall, 21)
            };
            for _ in 0..n_first {
                m.insert_scan(origin, first);
            }
            for _ in 0..n_second {
                m.insert_scan(origin, second);
            }
            let k = m.key(person[0].0);
            assert_eq!(m.counts(k), (20, 21));
            m.keeps(k)
        };
        assert!(!run(Carving::Majority, true));
        assert!(!run(Carving::Majority, false));
        assert!(run(Carving::LogOdds, true), "the person came last");
        assert!(!run(Carving::LogOdds, false));
    }

    /// A sensor 0.4 m up sees the floor 3–5 m ahead in one scan, then only farther floor, 5.5–8
    /// m ahead, in the next ones: those beams graze the nearer floor on their way (a beam to
    /// 8 m is under 0.1 m high from 6 m on). The floor voxels of the first scan stay occupied;
    /// with no clearance the later scans carve them.
    #[test]
    fn grazing_beams_do_not_carve_the_floor() {
        let origin = [0.0, 0.05, 0.4];
        let floor = |from: f64, to: f64| -> Vec<([f64; 3], bool)> {
            let n = ((to - from) / 0.05).round() as usize;
            (0..=n)
                .map(|i| ([from + 0.05 * i as f64, 0.05, 0.0], true))
                .collect()
        };
        let (near, far) = (floor(3.0, 5.0), floor(5.5, 8.0));
        let carved = |config: VoxelConfig| {
            let mut m = VoxelMap::new(config);
            m.insert_scan(origin, &near);
            for _ in 0..5 {
                m.insert_scan(origin, &far);
            }
            near.iter()
                .filter(|(p, _)| m.state(m.key(*p)) != Voxel::Occupied)
                .count()
        };
        assert_eq!(carved(VoxelConfig::default()), 0);
        let bare = carved(VoxelConfig {
            floor_clearance: 0.0,
            ..VoxelConfig::default()
        });
        assert!(bare > 5, "{bare} floor points carved without clearance");
    }

    /// The height band compresses into one plane: a table top at 0.7 m and a chair leg at
    /// 0.2 m are both obstacles below 1 m, the ceiling is not, and a cell seen only empty is
    /// free.
    #[test]
    fn the_band_compresses_into_a_grid() {
        let mut m = VoxelMap::new(VoxelConfig::default());
        m.insert_scan(
            [0.05, 0.05, 0.45],
            &[
                ([1.05, 0.05, 0.75], true),
                ([0.05, 1.05, 0.25], true),
                ([1.05, 1.05, 2.55], true),
                ([-0.95, 0.05, 0.45], false),
            ],
        );
        let g = m.project(0.1, 1.0).unwrap();
        let at = |x: f64, y: f64| {
            let (i, j) = (
                ((x - g.origin[0]) / g.resolution).floor() as usize,
                ((y - g.origin[1]) / g.resolution).floor() as usize,
            );
            g.get(i, j)
        };
        assert_eq!(at(1.05, 0.05), 100, "table top");
        assert_eq!(at(0.05, 1.05), 100, "chair leg");
        assert_eq!(at(-0.55, 0.05), 0, "seen empty");
        assert!(at(1.05, 1.05) <= 0, "the ceiling is above the band");
        assert!(m.project(5.0, 6.0).is_none());
        // Floor measured where no ray carved the band (the beam's last 0.5 m is not
        // carved): free.
        m.insert_scan([0.05, 0.05, 0.45], &[([0.55, -0.45, 0.02], true)]);
        let g = m.project(0.1, 1.0).unwrap();
        let (i, j) = (
            ((0.55 - g.origin[0]) / g.resolution).floor() as usize,
            ((-0.45 - g.origin[1]) / g.resolution).floor() as usize,
        );
        assert_eq!(g.get(i, j), 0, "the floor seen there");
    }
}
