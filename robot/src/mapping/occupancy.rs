//! Occupancy grid mapping with the log-odds inverse sensor model (Thrun, Burgard & Fox,
//! *Probabilistic Robotics*, ch. 9): each beam lowers the log-odds of the cells it crosses and
//! raises that of the cell it ends in. The grid grows to fit whatever is inserted.

use crate::geometry::floor_i64;
use futago_msgs::grid::OccupancyGrid;
use futago_msgs::{LaserScan, Pose2};
use serde::Deserialize;

/// Parameters of the grid (`mapping.grid.*` in a scenario).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct OccupancyConfig {
    /// Cell side, m (seed 000: 50 mm).
    pub resolution: f64,
    /// Log-odds added to the cell a beam ends in.
    pub hit: f32,
    /// Log-odds added to each cell a beam crosses (negative).
    pub miss: f32,
    /// Clamp of the log-odds, so that cells stay changeable.
    pub min: f32,
    pub max: f32,
    /// Beams are used up to this range, m; longer ones clear cells up to it only.
    pub max_range: f64,
}

impl Default for OccupancyConfig {
    fn default() -> Self {
        OccupancyConfig {
            resolution: 0.05,
            hit: 0.85,
            miss: -0.4,
            min: -2.0,
            max: 3.5,
            max_range: 30.0,
        }
    }
}

impl OccupancyConfig {
    /// Checks ranges; the error names the key below `key`.
    pub fn validate(&self, key: &str) -> Result<(), (String, String)> {
        crate::config::check_ranges(
            key,
            &[
                ("resolution", self.resolution, 0.001, 1.0),
                ("hit", self.hit as f64, 1e-3, 100.0),
                ("miss", self.miss as f64, -100.0, -1e-3),
                ("min", self.min as f64, -1000.0, -1e-3),
                ("max", self.max as f64, 1e-3, 1000.0),
                ("max_range", self.max_range, 0.01, 1000.0),
            ],
        )
    }
}

/// The most cells a grid may hold (2²⁸: 1 GiB of log-odds; 800 km² at 5 cm). A scan that
/// would grow the grid beyond it is refused and counted (see [`OccupancyMap::refused`]).
pub const MAX_CELLS: usize = 1 << 28;

/// A scan's laser cell, its beams' end cells, and the box of cells they span.
type BeamEnds = ([i64; 2], Vec<[i64; 2]>, [[i64; 2]; 2]);

/// Side of a tile of the grid, cells.
const TILE: i64 = 64;

/// A growing log-odds grid, stored in tiles of 64 × 64 cells that exist only where a beam
/// has passed: memory grows with the mapped area, not with its bounding box (a map that
/// drifted into an L spans a box many times its area). The bounding box is kept as a dense
/// grid would keep it (grown with a 64-cell margin), so the grid [`OccupancyMap::to_grid`]
/// gives has the same extent, and the [`MAX_CELLS`] cap applies to it.
#[derive(Debug, Clone)]
pub struct OccupancyMap {
    config: OccupancyConfig,
    /// Cell index (i, j) of the bounding box's first cell.
    offset: [i64; 2],
    width: usize,
    height: usize,
    /// The tiles' cells' log-odds, row-major, in the order they were made.
    tiles: Vec<Box<[f32]>>,
    /// Each tile's index (i, j) in tiles, in `tiles` order.
    keys: Vec<[i64; 2]>,
    /// Tile index (i, j) → position in `tiles`.
    index: rustc_hash::FxHashMap<[i64; 2], usize>,
    refused: usize,
}

impl OccupancyMap {
    pub fn new(config: OccupancyConfig) -> OccupancyMap {
        OccupancyMap {
            config,
            offset: [0, 0],
            width: 0,
            height: 0,
            tiles: Vec::new(),
            keys: Vec::new(),
            index: Default::default(),
            refused: 0,
        }
    }

    /// Scans refused because the grid would have grown beyond [`MAX_CELLS`].
    pub fn refused(&self) -> usize {
        self.refused
    }

    /// Tiles allocated (each 64 × 64 cells).
    pub fn tiles(&self) -> usize {
        self.tiles.len()
    }

    fn cell(&self, x: f64, y: f64) -> [i64; 2] {
        let r = self.config.resolution;
        [floor_i64(x / r), floor_i64(y / r)]
    }

    /// Grows the bounding box to hold cells `lo..=hi` (with a margin); false when it would
    /// exceed [`MAX_CELLS`].
    fn reserve(&mut self, lo: [i64; 2], hi: [i64; 2]) -> bool {
        let have_lo = self.offset;
        let have_hi = [
            self.offset[0] + self.width as i64 - 1,
            self.offset[1] + self.height as i64 - 1,
        ];
        if self.width > 0
            && lo[0] >= have_lo[0]
            && lo[1] >= have_lo[1]
            && hi[0] <= have_hi[0]
            && hi[1] <= have_hi[1]
        {
            return true;
        }
        let margin = 64;
        let (nlo, nhi) = if self.width == 0 {
            (
                [lo[0].saturating_sub(margin), lo[1].saturating_sub(margin)],
                [hi[0].saturating_add(margin), hi[1].saturating_add(margin)],
            )
        } else {
            (
                [
                    lo[0].min(have_lo[0]).saturating_sub(margin),
                    lo[1].min(have_lo[1]).saturating_sub(margin),
                ],
                [
                    hi[0].max(have_hi[0]).saturating_add(margin),
                    hi[1].max(have_hi[1]).saturating_add(margin),
                ],
            )
        };
        let (w, h) = (
            nhi[0].saturating_sub(nlo[0]).saturating_add(1),
            nhi[1].saturating_sub(nlo[1]).saturating_add(1),
        );
        if w <= 0 || h <= 0 || w.saturating_mul(h) > MAX_CELLS as i64 {
            return false;
        }
        self.offset = nlo;
        self.width = w as usize;
        self.height = h as usize;
        true
    }

    /// The tile of cell `c` and the cell's index in it.
    fn tile_of(c: [i64; 2]) -> ([i64; 2], usize) {
        let (t, r) = (
            [c[0].div_euclid(TILE), c[1].div_euclid(TILE)],
            [c[0].rem_euclid(TILE), c[1].rem_euclid(TILE)],
        );
        (t, (r[1] * TILE + r[0]) as usize)
    }

    /// The position in `tiles` of tile `t`, made (zeroed) if it does not exist yet.
    fn tile_index(&mut self, t: [i64; 2]) -> usize {
        if let Some(&at) = self.index.get(&t) {
            return at;
        }
        self.tiles
            .push(vec![0f32; (TILE * TILE) as usize].into_boxed_slice());
        self.keys.push(t);
        self.index.insert(t, self.tiles.len() - 1);
        self.tiles.len() - 1
    }

    /// Adds `miss` to each cell of Bresenham's line from `a` to `b` (`a` included, `b` not), then
    /// `hit` to `b`, each clamped to the configured limits, in that order. The walk steps the
    /// cell's place within its tile and looks a tile up only on entering it: the log-odds are
    /// those of adding cell by cell, at about three quarters of the cost (25 % of
    /// `office-explore`'s profile before, 19 % after: `Slam::grid` rebuilds the grid from every
    /// keyframe after each optimisation).
    fn trace(&mut self, a: [i64; 2], b: [i64; 2], miss: f32, hit: f32) {
        let (min, max) = (self.config.min, self.config.max);
        let (dx, dy) = ((b[0] - a[0]).abs(), -(b[1] - a[1]).abs());
        let (sx, sy) = ((b[0] - a[0]).signum(), (b[1] - a[1]).signum());
        let mut err = dx + dy;
        let mut c = a;
        let (mut t, mut k) = Self::tile_of(c);
        let mut at = self.tile_index(t);
        // The cell's column and row within its tile.
        let (mut u, mut v) = (c[0] - t[0] * TILE, c[1] - t[1] * TILE);
        loop {
            let last = c == b;
            let cell = &mut self.tiles[at][k];
            *cell = (*cell + if last { hit } else { miss }).clamp(min, max);
            if last {
                return;
            }
            let e2 = 2 * err;
            if e2 >= dy {
                err += dy;
                c[0] += sx;
                u += sx;
            }
            if e2 <= dx {
                err += dx;
                c[1] += sy;
                v += sy;
            }
            if (0..TILE).contains(&u) && (0..TILE).contains(&v) {
                k = (v * TILE + u) as usize;
            } else {
                (t, k) = Self::tile_of(c);
                at = self.tile_index(t);
                (u, v) = (c[0] - t[0] * TILE, c[1] - t[1] * TILE);
            }
        }
    }

    /// Log-odds at a world point (0 outside the grid).
    pub fn logodds_at(&self, x: f64, y: f64) -> f32 {
        let c = self.cell(x, y);
        let (i, j) = (c[0] - self.offset[0], c[1] - self.offset[1]);
        if i < 0 || j < 0 || i >= self.width as i64 || j >= self.height as i64 {
            return 0.0;
        }
        let (t, k) = Self::tile_of(c);
        self.index.get(&t).map_or(0.0, |&at| self.tiles[at][k])
    }

    /// The cell of `laser` and those the scan's beams with a return end in (in the beams'
    /// order), and the corners of the box of cells they span.
    fn beam_ends(&self, laser: &Pose2, scan: &LaserScan) -> BeamEnds {
        let max = self.config.max_range.min(scan.range_max);
        let start = self.cell(laser.x, laser.y);
        let mut ends = Vec::with_capacity(scan.ranges.len());
        let (mut lo, mut hi) = (start, start);
        for (k, &r) in scan.ranges.iter().enumerate() {
            let r = r as f64;
            if r.is_nan() || r < scan.range_min || r == f64::NEG_INFINITY {
                continue;
            }
            let hit = r.is_finite() && r <= max;
            if !hit {
                // No return: nothing is known along the beam (glass, or out of range).
                continue;
            }
            let a = laser.theta + scan.angle(k);
            let e = self.cell(laser.x + r * a.cos(), laser.y + r * a.sin());
            lo = [lo[0].min(e[0]), lo[1].min(e[1])];
            hi = [hi[0].max(e[0]), hi[1].max(e[1])];
            ends.push(e);
        }
        (start, ends, [lo, hi])
    }

    /// Integrates one scan taken from `laser` (the laser's pose in the map frame): the cells
    /// each beam crosses become freer, the cell it ends in more occupied. Beams without a
    /// return (+∞ or beyond `max_range`) are skipped. A scan that would grow the grid beyond
    /// [`MAX_CELLS`] is refused and counted.
    pub fn insert(&mut self, laser: &Pose2, scan: &LaserScan) {
        let (start, ends, [lo, hi]) = self.beam_ends(laser, scan);
        if !self.reserve(lo, hi) {
            self.refused += 1;
            return;
        }
        let (hit, miss) = (self.config.hit, self.config.miss);
        for e in ends {
            self.trace(start, e, miss, hit);
        }
    }

    /// The trinary map (map_server's thresholds: occupied above p = 0.65, free below 0.35,
    /// unknown between) over the bounding box.
    pub fn to_grid(&self) -> OccupancyGrid {
        let r = self.config.resolution;
        let (w, h) = (self.width.max(1), self.height.max(1));
        let mut g = OccupancyGrid::new(
            r,
            [self.offset[0] as f64 * r, self.offset[1] as f64 * r],
            w,
            h,
        );
        let (occ, free) = ((0.65f32 / 0.35).ln(), (0.35f32 / 0.65).ln());
        g.cells.iter_mut().for_each(|c| *c = -1);
        for (t, tile) in self.keys.iter().zip(&self.tiles) {
            for (k, &l) in tile.iter().enumerate() {
                let (ti, tj) = (k as i64 % TILE, k as i64 / TILE);
                let (i, j) = (
                    t[0] * TILE + ti - self.offset[0],
                    t[1] * TILE + tj - self.offset[1],
                );
                if i < 0 || j < 0 || i >= self.width as i64 || j >= self.height as i64 {
                    continue;
                }
                g.cells[j as usize * w + i as usize] = if l > occ {
                    100
                } else if l < free {
                    0
                } else {
                    -1
                };
            }
        }
        g
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use futago_msgs::Time;

    /// Bresenham's line from `a` towards `b`: `a` and every cell up to `b`, not `b`.
    fn line(a: [i64; 2], b: [i64; 2]) -> impl Iterator<Item = [i64; 2]> {
        let (dx, dy) = ((b[0] - a[0]).abs(), -(b[1] - a[1]).abs());
        let (sx, sy) = ((b[0] - a[0]).signum(), (b[1] - a[1]).signum());
        let mut err = dx + dy;
        let mut c = a;
        std::iter::from_fn(move || {
            if c == b {
                return None;
            }
            let out = c;
            let e2 = 2 * err;
            if e2 >= dy {
                err += dy;
                c[0] += sx;
            }
            if e2 <= dx {
                err += dx;
                c[1] += sy;
            }
            Some(out)
        })
    }

    /// Inserts `scan` as the cells of [`line`] one by one, each looked up afresh (the beams'
    /// ends found as `insert` finds them): the reference for [`OccupancyMap::insert`]'s walk.
    fn insert_cell_by_cell(m: &mut OccupancyMap, laser: &Pose2, scan: &LaserScan) {
        let (start, ends, [lo, hi]) = m.beam_ends(laser, scan);
        assert!(m.reserve(lo, hi));
        let (min, max) = (m.config.min, m.config.max);
        let add = |m: &mut OccupancyMap, c: [i64; 2], delta: f32| {
            let (t, k) = OccupancyMap::tile_of(c);
            let at = m.tile_index(t);
            let v = &mut m.tiles[at][k];
            *v = (*v + delta).clamp(min, max);
        };
        for e in ends {
            for c in line(start, e) {
                add(m, c, m.config.miss);
            }
            add(m, e, m.config.hit);
        }
    }

    /// The walk that steps within tiles gives the log-odds, to the bit, and the tiles, in
    /// order, of adding each cell of the beams' lines one at a time: scans from poses on both
    /// sides of the origin whose beams cross tile borders in every direction, repeated so that
    /// cells reach both clamps.
    #[test]
    fn insert_adds_along_each_beam_as_cell_by_cell() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(48);
        let (mut fast, mut slow) = (
            OccupancyMap::new(OccupancyConfig::default()),
            OccupancyMap::new(OccupancyConfig::default()),
        );
        for _ in 0..30 {
            let laser = Pose2::new(
                rng.random_range(-4.0..4.0),
                rng.random_range(-4.0..4.0),
                rng.random_range(-3.2..3.2),
            );
            let ranges: Vec<f32> = (0..181)
                .map(|_| match rng.random_range(0..10) {
                    0 => f32::INFINITY,
                    1 => 0.0,
                    2 => 3.21,
                    _ => rng.random_range(0.03..9.0),
                })
                .collect();
            let s = scan(ranges, -std::f64::consts::FRAC_PI_2, 1f64.to_radians());
            for _ in 0..5 {
                fast.insert(&laser, &s);
                insert_cell_by_cell(&mut slow, &laser, &s);
            }
        }
        assert_eq!(fast.keys, slow.keys);
        assert!(fast.tiles.len() > 20, "{} tiles", fast.tiles.len());
        let bits = |m: &OccupancyMap| -> Vec<u32> {
            m.tiles
                .iter()
                .flat_map(|t| t.iter().map(|v| v.to_bits()))
                .collect()
        };
        assert_eq!(bits(&fast), bits(&slow));
        let c = OccupancyConfig::default();
        let all: Vec<f32> = fast.tiles.iter().flat_map(|t| t.iter().copied()).collect();
        assert!(all.contains(&c.min) && all.contains(&c.max));
    }

    fn scan(ranges: Vec<f32>, angle_min: f64, inc: f64) -> LaserScan {
        LaserScan {
            frame: "front".into(),
            stamp: Time::ZERO,
            angle_min,
            angle_increment: inc,
            time_increment: 0.0,
            range_min: 0.02,
            range_max: 30.0,
            ranges,
        }
    }

    #[test]
    fn memory_grows_with_the_mapped_area_not_its_bounding_box() {
        let mut m = OccupancyMap::new(OccupancyConfig::default());
        // Two 4 m scans, 500 m apart: a 10 000 × 6 000-cell box (240 MB of dense log-odds).
        let s = scan(
            vec![4.0; 181],
            -std::f64::consts::FRAC_PI_2,
            1f64.to_radians(),
        );
        // Each twice: one pass of a beam leaves a cell unknown (−0.4 is above ln 0.35/0.65).
        for _ in 0..2 {
            m.insert(&Pose2::new(0.0, 0.0, 0.0), &s);
            m.insert(&Pose2::new(400.0, 300.0, 0.0), &s);
        }
        let g = m.to_grid();
        assert!(
            g.width >= 8000 && g.height >= 6000,
            "{}×{}",
            g.width,
            g.height
        );
        // Each scan sweeps a 4 m half-disc: a few 3.2 m tiles, not the box's 11 000.
        assert!(m.tiles() <= 20, "{} tiles", m.tiles());
        assert!(m.logodds_at(2.0, 0.0) < 0.0 && m.logodds_at(4.02, 0.0) > 0.0);
        assert!(m.logodds_at(402.0, 300.0) < 0.0 && m.logodds_at(404.02, 300.0) > 0.0);
        assert_eq!(m.logodds_at(200.0, 150.0), 0.0);
        // The trinary grid agrees with the log-odds where it was written.
        let at = |x: f64, y: f64| {
            let (i, j) = g.cell_of(x, y).unwrap();
            g.get(i, j)
        };
        assert_eq!(
            (at(2.0, 0.0), at(4.02, 0.0), at(200.0, 150.0)),
            (0, 100, -1)
        );
    }

    #[test]
    fn a_wall_seen_from_inside_a_room_is_occupied_with_free_space_before_it() {
        // A wall at x = 2.025 (mid-cell) seen from the origin by beams over ±30°.
        let n = 61;
        let inc = 1f64.to_radians();
        let ranges: Vec<f32> = (0..n)
            .map(|k| (2.025 / (-30f64.to_radians() + k as f64 * inc).cos()) as f32)
            .collect();
        let mut m = OccupancyMap::new(OccupancyConfig::default());
        for _ in 0..3 {
            m.insert(
                &Pose2::IDENTITY,
                &scan(ranges.clone(), -30f64.to_radians(), inc),
            );
        }
        let g = m.to_grid();
        let at = |x: f64, y: f64| {
            let (i, j) = g.cell_of(x, y).unwrap();
            g.get(i, j)
        };
        for y in [-1.0, -0.5, 0.0, 0.5, 1.0] {
            assert_eq!(at(2.025, y), 100, "wall at y {y}");
            assert_eq!(at(1.0, y * 0.5), 0, "free before the wall at y {y}");
            assert_eq!(at(2.5, y), -1, "unknown behind the wall at y {y}");
        }
        // The grid grew around what it saw and is a map_server grid with the right origin.
        assert!(g.origin[0] < 0.0 && g.origin[0] + g.width as f64 * 0.05 > 2.0);
    }

    #[test]
    fn bresenham_walks_every_cell_between_ends() {
        let cells: Vec<_> = line([0, 0], [5, 2]).collect();
        assert_eq!(cells.len(), 5);
        assert_eq!(cells[0], [0, 0]);
        for w in cells.windows(2) {
            assert!((w[1][0] - w[0][0]).abs() <= 1 && (w[1][1] - w[0][1]).abs() <= 1);
        }
        assert_eq!(line([3, 3], [3, 3]).count(), 0);
    }
}
