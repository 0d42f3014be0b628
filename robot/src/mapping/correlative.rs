//! Correlative scan matching by branch and bound (written for futago, after Hess et al., "Real-
//! time loop closure in 2D LIDAR SLAM", ICRA 2016, §V, and Olson, "Real-time correlative scan
//! matching", ICRA 2009).
//!
//! A scan is scored against a [`LikelihoodGrid`] (each cell holds how likely a laser return is
//! there: a Gaussian of the distance to the nearest map point) as the mean value under its
//! points. The search covers every heading in a window at a step small enough that the
//! farthest point moves less than a cell, and every translation in a window at one-cell steps;
//! branch and bound makes that exhaustive search cheap. Translations are grouped into squares
//! of 2ʰ cells whose score is bounded from above by grids that hold the maximum over each
//! square (precomputed once per grid), and only squares whose bound beats the best full-
//! resolution score so far are split.

use futago_msgs::Pose2;

/// A grid of return likelihoods in [0, 1] with the max-pooled grids branch and bound needs.
#[derive(Debug, Clone)]
pub struct LikelihoodGrid {
    resolution: f64,
    origin: [f64; 2],
    width: usize,
    height: usize,
    /// `levels[h]` holds, for cell (x, y), the maximum of the base grid over
    /// `[x, x + 2ʰ) × [y, y + 2ʰ)`; it extends `2ʰ − 1` cells below the base grid so that
    /// squares that start outside it are covered too. Values are stored in 1/255 steps, as
    /// Cartographer's precomputation grids are (a quarter of the memory of `f32`; a score
    /// moves by at most 1/510): a building-size log keeps hundreds of submaps.
    levels: Vec<Vec<u8>>,
}

impl LikelihoodGrid {
    /// Builds the grid over `points` (in the grid's frame) with a Gaussian of standard
    /// deviation `sigma` around each, and `depth` max-pooled levels above the base.
    pub fn new(points: &[[f64; 2]], resolution: f64, sigma: f64, depth: usize) -> LikelihoodGrid {
        let reach = (3.0 * sigma / resolution).ceil() as i64;
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for p in points {
            for k in 0..2 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        if points.is_empty() {
            lo = [0.0; 2];
            hi = [0.0; 2];
        }
        let margin = (reach + 1) as f64 * resolution;
        let origin = [lo[0] - margin, lo[1] - margin];
        let width = ((hi[0] + margin - origin[0]) / resolution).ceil() as usize + 1;
        let height = ((hi[1] + margin - origin[1]) / resolution).ceil() as usize + 1;
        let mut base = vec![0u8; width * height];
        let inv = 1.0 / (2.0 * sigma * sigma);
        for p in points {
            let cx = ((p[0] - origin[0]) / resolution).floor() as i64;
            let cy = ((p[1] - origin[1]) / resolution).floor() as i64;
            for y in cy - reach..=cy + reach {
                for x in cx - reach..=cx + reach {
                    // Every cell is within the grid: the margin exceeds the reach.
                    let (qx, qy) = (
                        origin[0] + (x as f64 + 0.5) * resolution,
                        origin[1] + (y as f64 + 0.5) * resolution,
                    );
                    let d2 = (qx - p[0]).powi(2) + (qy - p[1]).powi(2);
                    let v = quantise((-d2 * inv).exp());
                    let cell = &mut base[y as usize * width + x as usize];
                    *cell = (*cell).max(v);
                }
            }
        }
        let mut grid = LikelihoodGrid {
            resolution,
            origin,
            width,
            height,
            levels: vec![base],
        };
        for h in 1..=depth {
            let level = grid.pool(h);
            grid.levels.push(level);
        }
        grid
    }

    /// Level `h` from level `h − 1`: the max over a 2ʰ square is the max of four 2ʰ⁻¹ squares.
    fn pool(&self, h: usize) -> Vec<u8> {
        let half = 1i64 << (h - 1);
        let pad = (1i64 << h) - 1;
        let (w, hh) = (self.width as i64 + pad, self.height as i64 + pad);
        let mut out = vec![0u8; (w * hh) as usize];
        for y in 0..hh {
            for x in 0..w {
                let (gx, gy) = (x - pad, y - pad);
                let v = self
                    .raw(h - 1, gx, gy)
                    .max(self.raw(h - 1, gx + half, gy))
                    .max(self.raw(h - 1, gx, gy + half))
                    .max(self.raw(h - 1, gx + half, gy + half));
                out[(y * w + x) as usize] = v;
            }
        }
        out
    }

    /// Level `h` at base-grid cell (x, y) in 1/255 steps; 0 outside.
    #[inline]
    fn raw(&self, h: usize, x: i64, y: i64) -> u8 {
        let pad = (1i64 << h) - 1;
        let (w, hh) = (self.width as i64 + pad, self.height as i64 + pad);
        let (lx, ly) = (x + pad, y + pad);
        if lx < 0 || ly < 0 || lx >= w || ly >= hh {
            return 0;
        }
        self.levels[h][(ly * w + lx) as usize]
    }

    /// The base grid's value at a point in [0, 1] (0 outside).
    pub fn at(&self, p: [f64; 2]) -> f32 {
        let (x, y) = self.cell(p);
        f32::from(self.raw(0, x, y)) / 255.0
    }

    fn cell(&self, p: [f64; 2]) -> (i64, i64) {
        (
            ((p[0] - self.origin[0]) / self.resolution).floor() as i64,
            ((p[1] - self.origin[1]) / self.resolution).floor() as i64,
        )
    }

    pub fn resolution(&self) -> f64 {
        self.resolution
    }

    pub fn depth(&self) -> usize {
        self.levels.len() - 1
    }
}

/// A likelihood in [0, 1] in 1/255 steps. Rounding is monotone, so max-pooling the rounded
/// values gives the rounded maxima and the levels still bound the base grid.
fn quantise(v: f64) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// Search window and acceptance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SearchWindow {
    /// Half-width of the translation window, m.
    pub linear: f64,
    /// Half-width of the heading window, rad.
    pub angular: f64,
    /// Lowest mean likelihood a match may have.
    pub min_score: f64,
}

/// The best pose found and its score.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Match {
    pub pose: Pose2,
    pub score: f64,
}

/// Finds the pose within `window` of `guess` whose points (robot frame) score highest on
/// `grid`, if any scores at least `window.min_score`. Exhaustive over the discretised window:
/// the answer is the same as scoring every candidate, only faster.
pub fn search(
    grid: &LikelihoodGrid,
    points: &[[f64; 2]],
    guess: Pose2,
    window: &SearchWindow,
) -> Option<Match> {
    if points.is_empty() {
        return None;
    }
    let r = grid.resolution;
    let far = points.iter().map(|p| p[0].hypot(p[1])).fold(r, f64::max);
    // The heading step that moves the farthest point by one cell (Hess et al., eq. 7).
    let step = (1.0 - r * r / (2.0 * far * far)).acos();
    let n_angles = (window.angular / step).ceil() as i64;
    let wx = (window.linear / r).ceil() as i64;
    let depth = grid.depth();
    let top = 1i64 << depth;
    // Cells of the points for each heading, with the translation of the guess.
    let headings: Vec<(f64, Vec<(i64, i64)>)> = (-n_angles..=n_angles)
        .map(|k| {
            let theta = guess.theta + k as f64 * step;
            let (s, c) = theta.sin_cos();
            let cells = points
                .iter()
                .map(|p| grid.cell([guess.x + c * p[0] - s * p[1], guess.y + s * p[0] + c * p[1]]))
                .collect();
            (theta, cells)
        })
        .collect();
    let scale = 1.0 / (255.0 * points.len() as f64);
    let score = |h: usize, cells: &[(i64, i64)], ox: i64, oy: i64| -> f64 {
        let sum: u64 = cells
            .iter()
            .map(|&(x, y)| u64::from(grid.raw(h, x + ox, y + oy)))
            .sum();
        sum as f64 * scale
    };
    // Candidates: (score, heading index, x offset, y offset, level).
    let mut stack: Vec<(f64, usize, i64, i64, usize)> = Vec::new();
    for (a, (_, cells)) in headings.iter().enumerate() {
        let mut oy = -wx;
        while oy <= wx {
            let mut ox = -wx;
            while ox <= wx {
                stack.push((score(depth, cells, ox, oy), a, ox, oy, depth));
                ox += top;
            }
            oy += top;
        }
    }
    // Depth first, best child last on the stack so that it is explored first.
    stack.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut best: Option<(f64, usize, i64, i64)> = None;
    let mut bound = window.min_score;
    while let Some((s, a, ox, oy, h)) = stack.pop() {
        if s < bound || (best.is_some() && s <= bound) {
            continue;
        }
        if h == 0 {
            best = Some((s, a, ox, oy));
            bound = s;
            continue;
        }
        let half = 1i64 << (h - 1);
        let mut children = Vec::with_capacity(4);
        for (dx, dy) in [(0, 0), (half, 0), (0, half), (half, half)] {
            let (cx, cy) = (ox + dx, oy + dy);
            if cx > wx || cy > wx {
                continue;
            }
            children.push((score(h - 1, &headings[a].1, cx, cy), a, cx, cy, h - 1));
        }
        children.sort_by(|a, b| a.0.total_cmp(&b.0));
        stack.extend(children);
    }
    best.map(|(s, a, ox, oy)| Match {
        pose: Pose2::new(
            guess.x + ox as f64 * r,
            guess.y + oy as f64 * r,
            headings[a].0,
        ),
        score: s,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points along the walls of an L-shaped room, in the room's frame.
    fn room() -> Vec<[f64; 2]> {
        let mut pts = Vec::new();
        let walls: [([f64; 2], [f64; 2]); 7] = [
            ([0.0, 0.0], [6.0, 0.0]),
            ([6.0, 0.0], [6.0, 3.0]),
            ([6.0, 3.0], [2.5, 3.0]),
            ([2.5, 3.0], [2.5, 5.0]),
            ([2.5, 5.0], [0.0, 5.0]),
            ([0.0, 5.0], [0.0, 0.0]),
            ([4.0, 1.0], [4.5, 1.5]),
        ];
        for (a, b) in walls {
            let len: f64 = (b[0] - a[0]).hypot(b[1] - a[1]);
            let n = (len / 0.02) as usize;
            for k in 0..=n {
                let t = k as f64 / n as f64;
                pts.push([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]);
            }
        }
        pts
    }

    #[test]
    fn max_pooled_levels_bound_the_base_grid() {
        let grid = LikelihoodGrid::new(&room(), 0.05, 0.05, 4);
        for h in 1..=4 {
            let size = 1i64 << h;
            for (x, y) in [(-3, -3), (10, 7), (40, 30), (100, 90), (125, 5)] {
                let mut m = 0u8;
                for dy in 0..size {
                    for dx in 0..size {
                        m = m.max(grid.raw(0, x + dx, y + dy));
                    }
                }
                assert_eq!(grid.raw(h, x, y), m, "level {h} at ({x}, {y})");
            }
        }
    }

    /// Branch and bound finds the same optimum as scoring every candidate.
    #[test]
    fn branch_and_bound_equals_exhaustive_search_and_recovers_the_pose() {
        let map = room();
        let grid = LikelihoodGrid::new(&map, 0.05, 0.05, 5);
        let truth = Pose2::new(1.3, 1.1, 0.3);
        // The scan: the map's points seen from `truth` within 4 m (robot frame), every 3rd.
        let inv = truth.inverse();
        let scan: Vec<[f64; 2]> = map
            .iter()
            .step_by(3)
            .map(|p| inv.transform_point(*p))
            .filter(|q| q[0].hypot(q[1]) < 4.0)
            .collect();
        let guess = Pose2::new(1.6, 0.8, 0.18);
        let window = SearchWindow {
            linear: 0.5,
            angular: 0.2,
            min_score: 0.1,
        };
        let m = search(&grid, &scan, guess, &window).unwrap();
        assert!(m.pose.distance(&truth) < 0.05, "{m:?}");
        assert!((m.pose.theta - truth.theta).abs() < 0.02, "{m:?}");
        // Exhaustive reference over the same discretisation.
        let far = scan.iter().map(|p| p[0].hypot(p[1])).fold(0.05, f64::max);
        let step = (1.0 - 0.05f64.powi(2) / (2.0 * far * far)).acos();
        let n = (0.2 / step).ceil() as i64;
        let mut best = 0.0f64;
        for k in -n..=n {
            let theta = guess.theta + k as f64 * step;
            for oy in -10..=10 {
                for ox in -10..=10 {
                    let p = Pose2::new(
                        guess.x + ox as f64 * 0.05,
                        guess.y + oy as f64 * 0.05,
                        theta,
                    );
                    let s = scan
                        .iter()
                        .map(|q| grid.at(p.transform_point(*q)) as f64)
                        .sum::<f64>()
                        / scan.len() as f64;
                    best = best.max(s);
                }
            }
        }
        assert!((m.score - best).abs() < 1e-6, "{} vs {best}", m.score);
    }

    #[test]
    fn a_score_below_the_threshold_is_no_match() {
        let grid = LikelihoodGrid::new(&room(), 0.05, 0.05, 3);
        // Points of a different shape, far from any wall.
        let scan: Vec<[f64; 2]> = (0..50).map(|k| [10.0 + k as f64 * 0.1, 10.0]).collect();
        let window = SearchWindow {
            linear: 0.3,
            angular: 0.1,
            min_score: 0.5,
        };
        assert!(search(&grid, &scan, Pose2::IDENTITY, &window).is_none());
    }
}
