//! Occupancy grid mapping with the log-odds inverse sensor model (Thrun, Burgard & Fox,
//! *Probabilistic Robotics*, ch. 9): each beam lowers the log-odds of the cells it crosses and
//! raises that of the cell it ends in. The grid grows to fit whatever is inserted.

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

/// A growing log-odds grid.
#[derive(Debug, Clone)]
pub struct OccupancyMap {
    config: OccupancyConfig,
    /// Cell index (i, j) of the first stored cell.
    offset: [i64; 2],
    width: usize,
    height: usize,
    logodds: Vec<f32>,
    refused: usize,
}

impl OccupancyMap {
    pub fn new(config: OccupancyConfig) -> OccupancyMap {
        OccupancyMap {
            config,
            offset: [0, 0],
            width: 0,
            height: 0,
            logodds: Vec::new(),
            refused: 0,
        }
    }

    /// Scans refused because the grid would have grown beyond [`MAX_CELLS`].
    pub fn refused(&self) -> usize {
        self.refused
    }

    fn cell(&self, x: f64, y: f64) -> [i64; 2] {
        let r = self.config.resolution;
        [(x / r).floor() as i64, (y / r).floor() as i64]
    }

    /// Grows the storage to hold cells `lo..=hi` (with a margin, to grow rarely); `false`
    /// when that would pass [`MAX_CELLS`].
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
        let (w, h) = (w as usize, h as usize);
        let mut grid = vec![0f32; w * h];
        for j in 0..self.height {
            let src = &self.logodds[j * self.width..(j + 1) * self.width];
            let dj = (self.offset[1] + j as i64 - nlo[1]) as usize;
            let di = (self.offset[0] - nlo[0]) as usize;
            grid[dj * w + di..dj * w + di + self.width].copy_from_slice(src);
        }
        self.offset = nlo;
        self.width = w;
        self.height = h;
        self.logodds = grid;
        true
    }

    fn add(&mut self, c: [i64; 2], delta: f32) {
        let i = (c[0] - self.offset[0]) as usize;
        let j = (c[1] - self.offset[1]) as usize;
        let v = &mut self.logodds[j * self.width + i];
        *v = (*v + delta).clamp(self.config.min, self.config.max);
    }

    /// Log-odds of the cell containing `(x, y)` (0 where never observed).
    pub fn logodds_at(&self, x: f64, y: f64) -> f32 {
        let c = self.cell(x, y);
        let (i, j) = (c[0] - self.offset[0], c[1] - self.offset[1]);
        if i < 0 || j < 0 || i >= self.width as i64 || j >= self.height as i64 {
            return 0.0;
        }
        self.logodds[j as usize * self.width + i as usize]
    }

    /// Inserts a scan taken by a laser at `laser` (world frame).
    pub fn insert(&mut self, laser: &Pose2, scan: &LaserScan) {
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
        if !self.reserve(lo, hi) {
            self.refused += 1;
            return;
        }
        let (hit, miss) = (self.config.hit, self.config.miss);
        for e in ends {
            for c in line(start, e) {
                self.add(c, miss);
            }
            self.add(e, hit);
        }
    }

    /// The map as occupancy values: occupied above p = 0.65, free below p = 0.35, else unknown.
    pub fn to_grid(&self) -> OccupancyGrid {
        let r = self.config.resolution;
        let mut g = OccupancyGrid::new(
            r,
            [self.offset[0] as f64 * r, self.offset[1] as f64 * r],
            self.width.max(1),
            self.height.max(1),
        );
        let (occ, free) = ((0.65f32 / 0.35).ln(), (0.35f32 / 0.65).ln());
        for (k, &l) in self.logodds.iter().enumerate() {
            g.cells[k] = if l > occ {
                100
            } else if l < free {
                0
            } else {
                -1
            };
        }
        g
    }
}

/// Cells from `a` towards `b`, excluding `b` (Bresenham).
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

#[cfg(test)]
mod tests {
    use super::*;
    use futago_msgs::Time;

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
