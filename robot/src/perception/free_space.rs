//! Where the floor has been seen, without a map: an occupancy grid in the odometry frame built
//! from the scans themselves, in which a person candidate counts only where beams have passed
//! through before and nothing stood there since (Leigh et al., ICRA 2015: leg_tracker's local
//! occupancy grid and its `in_free_space_threshold`). Furniture that looks like a leg is hit
//! scan after scan and stays occupied; the floor where a person steps was seen empty.
//!
//! Each beam lowers the log-odds of the cells it crosses (`miss`) and raises its end cell's
//! (`hit`), clamped to ±`clamp`. The returns near the people the tracker holds are left out,
//! so that a person who stops does not become furniture. Cells are kept in tiles of 4 × 4,
//! found in a hash map by the tile's indices: only what the laser has seen takes memory, up to
//! `max_cells` cells. Each beam is traced at steps of a cell, a few to a tile, so most steps
//! find their tile without a lookup (a map keyed by each cell spent most of the grid's time in
//! its lookups, issue 48).

use futago_msgs::{LaserScan, Pose2, Time};
use rustc_hash::FxHashMap;
use serde::{Deserialize, Serialize};

use crate::config::{ConfigError, check_counts, check_ranges};
use crate::geometry::{floor_i64, within};

/// The free-space grid's settings (`people.free_space`).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct FreeSpaceConfig {
    /// Cell side, m.
    pub resolution: f64,
    /// Log-odds added to a beam's end cell, and to each cell it passes (negative).
    pub hit: f64,
    pub miss: f64,
    /// The log-odds stay within ±clamp, so that a cell can change its mind.
    pub clamp: f64,
    /// A place is free when its cell's occupancy probability is below this
    /// (leg_tracker's `in_free_space_threshold`, 0.06).
    pub threshold: f64,
    /// Returns within this distance of a held person are not counted as hits, m.
    pub person_radius: f64,
    /// Beams beyond this are not traced, m.
    pub max_range: f64,
    /// The grid takes a scan at most this often, s (0.9 of it is enough between two): a
    /// 75 Hz laser adds evidence as fast in time as a 10 Hz one, and traces an eighth of
    /// its scans.
    pub interval: f64,
    /// The grid keeps at most this many cells; past it, no new cells are made.
    pub max_cells: usize,
}

impl Default for FreeSpaceConfig {
    fn default() -> Self {
        FreeSpaceConfig {
            resolution: 0.1,
            hit: 0.85,
            miss: -0.4,
            clamp: 5.0,
            threshold: 0.06,
            person_radius: 0.3,
            max_range: 10.0,
            interval: 0.1,
            max_cells: 4_000_000,
        }
    }
}

impl FreeSpaceConfig {
    /// Checks every field; errors name `prefix.field`.
    pub fn validate(&self, prefix: &str) -> Result<(), ConfigError> {
        check_ranges(
            prefix,
            &[
                ("resolution", self.resolution, 0.01, 1.0),
                ("hit", self.hit, 0.0, 10.0),
                ("miss", self.miss, -10.0, 0.0),
                ("clamp", self.clamp, 0.1, 50.0),
                ("threshold", self.threshold, 0.0, 1.0),
                ("person_radius", self.person_radius, 0.0, 2.0),
                ("max_range", self.max_range, 0.1, 100.0),
                ("interval", self.interval, 0.0, 10.0),
            ],
        )?;
        check_counts(prefix, &[("max_cells", self.max_cells, 1, 100_000_000)])
    }
}

/// The grid (see the module documentation).
#[derive(Debug, Clone)]
pub struct FreeSpace {
    config: FreeSpaceConfig,
    /// Each tile's index in `tiles`, by the tile's indices (a cell's shifted).
    index: FxHashMap<(i64, i64), u32>,
    tiles: Vec<Tile>,
    /// Cells made.
    cells: usize,
    /// The stamp of the last scan taken.
    last: Option<Time>,
}

/// A tile holds `2^TILE_BITS` cells along each axis (4).
const TILE_BITS: u32 = 2;
const TILE_MASK: i64 = (1 << TILE_BITS) - 1;

/// Sixteen cells' log-odds, and which of them were made.
#[derive(Debug, Clone, Copy, Default)]
struct Tile {
    log_odds: [f32; 1 << (2 * TILE_BITS)],
    made: u16,
}

/// The tile of `cell` and the cell's place in it.
fn split(cell: (i64, i64)) -> ((i64, i64), usize) {
    (
        (cell.0 >> TILE_BITS, cell.1 >> TILE_BITS),
        (((cell.1 & TILE_MASK) << TILE_BITS) | (cell.0 & TILE_MASK)) as usize,
    )
}

impl FreeSpace {
    pub fn new(config: FreeSpaceConfig) -> FreeSpace {
        FreeSpace {
            config,
            index: FxHashMap::default(),
            tiles: Vec::new(),
            cells: 0,
            last: None,
        }
    }

    fn cell(&self, p: [f64; 2]) -> (i64, i64) {
        let r = self.config.resolution;
        (floor_i64(p[0] / r), floor_i64(p[1] / r))
    }

    /// Adds `v` to `cell`'s log-odds, clamped; a cell not made yet is made holding `v`
    /// (clamped), unless `max_cells` are made. `cached` remembers the last tile found, so that
    /// a beam's run of cells in one tile looks it up once.
    fn add(&mut self, cell: (i64, i64), v: f64, cached: &mut Option<((i64, i64), u32)>) {
        let clamp = self.config.clamp as f32;
        let full = self.cells >= self.config.max_cells;
        let (t, i) = split(cell);
        let at = match *cached {
            Some((key, at)) if key == t => at,
            _ => {
                let at = match self.index.get(&t) {
                    Some(&at) => at,
                    None if full => return,
                    None => {
                        self.tiles.push(Tile::default());
                        let at = (self.tiles.len() - 1) as u32;
                        self.index.insert(t, at);
                        at
                    }
                };
                *cached = Some((t, at));
                at
            }
        };
        let tile = &mut self.tiles[at as usize];
        let bit = 1u16 << i;
        if tile.made & bit != 0 {
            tile.log_odds[i] = (tile.log_odds[i] + v as f32).clamp(-clamp, clamp);
        } else if !full {
            tile.made |= bit;
            tile.log_odds[i] = (v as f32).clamp(-clamp, clamp);
            self.cells += 1;
        }
    }

    /// The log-odds of `cell`, if made.
    fn log_odds(&self, cell: (i64, i64)) -> Option<f32> {
        let (t, i) = split(cell);
        let tile = &self.tiles[*self.index.get(&t)? as usize];
        (tile.made & (1 << i) != 0).then_some(tile.log_odds[i])
    }

    /// Whether the place `p` (odometry frame) has been seen free: its cell's occupancy
    /// probability is below the threshold. A cell never seen is not free.
    pub fn is_free(&self, p: [f64; 2]) -> bool {
        self.log_odds(self.cell(p)).is_some_and(|l| {
            let odds = (l as f64).exp();
            odds / (1.0 + odds) < self.config.threshold
        })
    }

    /// Takes a scan from the laser pose `laser` (odometry frame); returns within
    /// `person_radius` of any of `people` (odometry frame) are traced but not counted as hits.
    /// Scans within 0.9 `interval` of the last one taken are skipped.
    pub fn update(&mut self, scan: &LaserScan, laser: &Pose2, people: &[[f64; 2]]) {
        let c = self.config;
        if self
            .last
            .is_some_and(|t| (scan.stamp - t).secs() < 0.9 * c.interval)
        {
            return;
        }
        self.last = Some(scan.stamp);
        let origin = [laser.x, laser.y];
        let mut cached = None;
        for i in 0..scan.ranges.len() {
            let r = scan.ranges[i] as f64;
            if !r.is_finite() || r < scan.range_min {
                continue;
            }
            // A beam with no return (at or past its range limit) still saw its way clear.
            let hit = r < scan.range_max && r <= c.max_range;
            let reach = r.min(c.max_range).min(scan.range_max);
            let a = laser.theta + scan.angle(i);
            let (s, co) = a.sin_cos();
            let end = [origin[0] + reach * co, origin[1] + reach * s];
            let end_cell = self.cell(end);
            // The cells the beam crosses before its end, by steps of a cell (a corner it
            // clips may be missed: the beams beside it cross it).
            let step = c.resolution;
            let n = (reach / step).floor() as usize;
            let mut last = None;
            for k in 0..n {
                let d = k as f64 * step;
                let cell = self.cell([origin[0] + d * co, origin[1] + d * s]);
                if cell == end_cell {
                    break;
                }
                if last != Some(cell) {
                    self.add(cell, c.miss, &mut cached);
                    last = Some(cell);
                }
            }
            // (Asked only of a hit.)
            let by_person = || {
                people
                    .iter()
                    .any(|q| within(q[0] - end[0], q[1] - end[1], c.person_radius))
            };
            if hit && !by_person() {
                self.add(end_cell, c.hit, &mut cached);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The scan at `stamp` of a wall at x = 4 m and, where `post`, a post of radius 5 cm at
    /// (2, 0.5): the leg detector's test scene (0.5° beams over ±90° from the origin).
    fn scan(post: bool, stamp: f64) -> LaserScan {
        let circles: &[([f64; 2], f64)] = if post { &[([2.0, 0.5], 0.05)] } else { &[] };
        let mut s = crate::perception::legs::tests::scan(circles, 4.0);
        s.stamp = Time::from_secs(stamp);
        s
    }

    #[test]
    fn the_floor_seen_through_is_free_and_a_post_hit_every_scan_is_not() {
        let mut f = FreeSpace::new(FreeSpaceConfig::default());
        let laser = Pose2::new(0.0, 0.0, 0.0);
        // Nothing seen yet: nowhere is free.
        assert!(!f.is_free([2.0, 0.5]));
        for k in 0..10 {
            f.update(&scan(true, 0.1 * k as f64), &laser, &[]);
        }
        // The floor in front of the post and beside it was seen through ten times.
        assert!(f.is_free([1.0, 0.25]));
        assert!(f.is_free([2.0, -0.5]));
        // The post's front (where its returns are) and the wall were hit every time; behind
        // the wall was never seen.
        assert!(!f.is_free([1.96, 0.5]));
        assert!(!f.is_free([4.02, 0.0]));
        assert!(!f.is_free([6.0, 0.0]));
        // The post taken away: the floor where it stood is seen through and becomes free.
        for k in 10..30 {
            f.update(&scan(false, 0.1 * k as f64), &laser, &[]);
        }
        assert!(f.is_free([1.96, 0.5]));
    }

    #[test]
    fn a_held_person_does_not_become_furniture() {
        let mut f = FreeSpace::new(FreeSpaceConfig::default());
        let laser = Pose2::new(0.0, 0.0, 0.0);
        for k in 0..10 {
            f.update(&scan(false, 0.1 * k as f64), &laser, &[]);
        }
        // Someone (the "post") stands there while the tracker holds them.
        for k in 10..60 {
            f.update(&scan(true, 0.1 * k as f64), &laser, &[[2.0, 0.5]]);
        }
        assert!(f.is_free([1.96, 0.5]));
    }

    /// Every made cell and its log-odds, in the cells' order.
    fn made(f: &FreeSpace) -> Vec<((i64, i64), f32)> {
        let mut v = Vec::new();
        for (&t, &at) in &f.index {
            let tile = &f.tiles[at as usize];
            for i in 0..1i64 << (2 * TILE_BITS) {
                if tile.made & (1 << i) != 0 {
                    let c = (
                        (t.0 << TILE_BITS) | (i & TILE_MASK),
                        (t.1 << TILE_BITS) | (i >> TILE_BITS),
                    );
                    v.push((c, tile.log_odds[i as usize]));
                }
            }
        }
        v.sort_by_key(|(c, _)| *c);
        v
    }

    /// The tiles hold what a map keyed by each cell holds: runs of cells about zero (negative
    /// indices too), walked as beams walk them with the last tile remembered, added to until
    /// the cap on cells stops new ones, against the rule written out with a hash map.
    #[test]
    fn the_tiles_hold_what_a_map_of_each_cell_holds() {
        let config = FreeSpaceConfig {
            max_cells: 700,
            ..FreeSpaceConfig::default()
        };
        let mut f = FreeSpace::new(config);
        let mut reference: std::collections::HashMap<(i64, i64), f32> = Default::default();
        let clamp = config.clamp as f32;
        let mut state = 7u64;
        let mut r = move |n: i64| {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 33) % n as u64) as i64
        };
        for _ in 0..400 {
            let mut cached = None;
            let (mut c, d) = ((r(60) - 30, r(60) - 30), (r(3) - 1, r(3) - 1));
            for _ in 0..r(25) {
                let v = if r(4) == 0 { config.hit } else { config.miss };
                f.add(c, v, &mut cached);
                let full = reference.len() >= config.max_cells;
                match reference.get_mut(&c) {
                    Some(l) => *l = (*l + v as f32).clamp(-clamp, clamp),
                    None if !full => {
                        reference.insert(c, (v as f32).clamp(-clamp, clamp));
                    }
                    None => {}
                }
                c = (c.0 + d.0, c.1 + d.1);
            }
        }
        assert_eq!(f.cells, config.max_cells, "the cap was reached");
        let mut want: Vec<((i64, i64), f32)> = reference.into_iter().collect();
        want.sort_by_key(|(c, _)| *c);
        assert!(want.iter().any(|((i, j), _)| *i < 0 && *j < 0));
        assert_eq!(made(&f), want);
        for ((i, j), l) in &want {
            let p = [(*i as f64 + 0.5) * 0.1, (*j as f64 + 0.5) * 0.1];
            let odds = (*l as f64).exp();
            assert_eq!(f.is_free(p), odds / (1.0 + odds) < config.threshold);
        }
    }

    #[test]
    fn scans_closer_than_the_interval_add_nothing() {
        let laser = Pose2::new(0.0, 0.0, 0.0);
        // Ten scans at 200 Hz are one scan's evidence, where ten at 10 Hz are ten.
        let mut fast = FreeSpace::new(FreeSpaceConfig::default());
        let mut slow = FreeSpace::new(FreeSpaceConfig::default());
        let mut once = FreeSpace::new(FreeSpaceConfig::default());
        once.update(&scan(false, 0.0), &laser, &[]);
        for k in 0..10 {
            fast.update(&scan(false, 0.005 * k as f64), &laser, &[]);
            slow.update(&scan(false, 0.1 * k as f64), &laser, &[]);
        }
        assert_eq!(made(&fast), made(&once));
        assert!(slow.is_free([3.0, 0.0]) && !fast.is_free([3.0, 0.0]));
    }
}
