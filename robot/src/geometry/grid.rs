//! Distance transforms of occupancy grids: how far each cell is from the nearest obstacle.
//!
//! Two transforms, for two needs. [`obstacle_distance`] is the two-pass chamfer transform
//! (weights 1 and √2, within 8 % of Euclidean, in f32 and capped), cheap enough to recompute
//! whenever SLAM's map grows; planning and Monte Carlo localisation's likelihood field read it.
//! [`squared_edt`] is exact (Felzenszwalb and Huttenlocher's lower envelope of parabolas), for
//! the map scores, where an 8 % error would be a bias in a published figure.

use futago_msgs::grid::OccupancyGrid;

/// Occupancy at or above which a cell is an obstacle (map_server's 0.65 trinary threshold
/// lies above it; SLAM's and the ground truth's grids are trinary 0/100/−1).
pub const OCCUPIED: i8 = 50;

/// Distance from each cell's centre to the nearest cell for which `obstacle` holds, m
/// (two-pass chamfer transform with weights 1 and √2, within 8 % of Euclidean), capped at
/// `cap`. Row-major like the grid.
///
/// Each pass takes a row in two sweeps: first every cell against the three neighbours in the
/// row already done (cells independent of each other, whose work the processor overlaps),
/// then along the row against the cell before. A minimum is exact whatever order its terms
/// are taken in, so the values are those of the textbook's one sweep per row
/// (`chamfer_reference` in the tests), while the chain of dependent operations per cell is
/// one addition and one minimum instead of four minima behind a store (issue 48: the people
/// tracker recomputes it for each map SLAM publishes; the build's code for the first sweep is
/// scalar, not vectorised).
pub fn obstacle_distance(
    grid: &OccupancyGrid,
    obstacle: impl Fn(i8) -> bool,
    cap: f64,
) -> Vec<f32> {
    let (w, h) = (grid.width, grid.height);
    let big = 1e9f32;
    let mut d: Vec<f32> = grid
        .cells
        .iter()
        .map(|&c| if obstacle(c) { 0.0 } else { big })
        .collect();
    if w > 0 && h > 0 {
        along_row(&mut d[..w]);
        for j in 1..h {
            let (done, rest) = d.split_at_mut(j * w);
            chamfer_row(&mut rest[..w], &done[(j - 1) * w..]);
        }
        along_row_back(&mut d[(h - 1) * w..]);
        for j in (0..h - 1).rev() {
            let (rest, done) = d.split_at_mut((j + 1) * w);
            chamfer_row_back(&mut rest[j * w..], &done[..w]);
        }
    }
    let r = grid.resolution as f32;
    d.into_iter().map(|c| (c * r).min(cap as f32)).collect()
}

/// The smaller of two distances: [`f32::min`] for the transform's values (never NaN), as one
/// instruction.
#[inline(always)]
fn lesser(x: f32, y: f32) -> f32 {
    if y < x { y } else { x }
}

/// The chamfer transform's weights: a step along a row or column, and a diagonal step.
const STRAIGHT: f32 = 1.0;
const DIAGONAL: f32 = std::f32::consts::SQRT_2;

/// One row of the forward pass: `row` against the row above it (`up`, done), then along
/// itself from the left.
fn chamfer_row(row: &mut [f32], up: &[f32]) {
    let w = row.len();
    for i in 0..w {
        let mut v = lesser(row[i], up[i] + STRAIGHT);
        if i > 0 {
            v = lesser(v, up[i - 1] + DIAGONAL);
        }
        if i + 1 < w {
            v = lesser(v, up[i + 1] + DIAGONAL);
        }
        row[i] = v;
    }
    along_row(row);
}

/// One row of the backward pass: `row` against the row below it (`down`, done), then along
/// itself from the right.
fn chamfer_row_back(row: &mut [f32], down: &[f32]) {
    let w = row.len();
    for i in 0..w {
        let mut v = lesser(row[i], down[i] + STRAIGHT);
        if i + 1 < w {
            v = lesser(v, down[i + 1] + DIAGONAL);
        }
        if i > 0 {
            v = lesser(v, down[i - 1] + DIAGONAL);
        }
        row[i] = v;
    }
    along_row_back(row);
}

/// Each cell against the one before it, left to right.
fn along_row(row: &mut [f32]) {
    let Some(&first) = row.first() else {
        return;
    };
    let mut last = first;
    for x in &mut row[1..] {
        last = lesser(*x, last + STRAIGHT);
        *x = last;
    }
}

/// Each cell against the one after it, right to left.
fn along_row_back(row: &mut [f32]) {
    let Some(&first) = row.last() else {
        return;
    };
    let mut last = first;
    let n = row.len();
    for x in row[..n - 1].iter_mut().rev() {
        last = lesser(*x, last + STRAIGHT);
        *x = last;
    }
}

/// The cells of `grid` whose centres lie within `radius` of `centre` (a disc: a person's
/// keep-out, the robot's footprint), in row-major order; none when `centre` is off the grid.
pub fn cells_within(grid: &OccupancyGrid, centre: [f64; 2], radius: f64) -> Vec<(usize, usize)> {
    let Some((ci, cj)) = grid.cell_of(centre[0], centre[1]) else {
        return Vec::new();
    };
    let k = (radius / grid.resolution).ceil() as i64;
    let mut out = Vec::new();
    for dj in -k..=k {
        for di in -k..=k {
            let (i, j) = (ci as i64 + di, cj as i64 + dj);
            if i < 0 || j < 0 || i >= grid.width as i64 || j >= grid.height as i64 {
                continue;
            }
            let c = grid.cell_center(i as usize, j as usize);
            if (c[0] - centre[0]).hypot(c[1] - centre[1]) <= radius {
                out.push((i as usize, j as usize));
            }
        }
    }
    out
}

/// For each cell of `grid`, the least distance in cells from any point in its square to any
/// point in the square of a cell whose value `site` holds, and with `rim` to any point off
/// the grid: what a ray cast may skip from anywhere in the cell.
///
/// The squares of two cells `(dx, dy)` cells apart are `hypot((|dx| - 1)⁺, (|dy| - 1)⁺)`
/// apart: the distance between their centres less up to a cell along each axis, which is the
/// centre distance to the nearest cell of the sites grown by one cell in each of the eight
/// directions (which brings the squares just off the grid onto its rim). An exact distance
/// transform of those gives it. (The chamfer distance less a cell's diagonal, which the casts
/// took before, is 1.34 cells for a cell three cells off a wall, where this is 2.)
pub fn clear_distance(grid: &OccupancyGrid, site: impl Fn(i8) -> bool, rim: bool) -> Vec<f64> {
    let (w, h) = (grid.width, grid.height);
    let mut grown = vec![false; w * h];
    for j in 0..h {
        for i in 0..w {
            if rim && (i == 0 || j == 0 || i + 1 == w || j + 1 == h) {
                grown[j * w + i] = true;
            }
            if site(grid.get(i, j)) {
                for row in grown.chunks_mut(w).take(j + 2).skip(j.saturating_sub(1)) {
                    row[i.saturating_sub(1)..(i + 2).min(w)].fill(true);
                }
            }
        }
    }
    squared_edt(&grown, w, h)
        .into_iter()
        .map(f64::sqrt)
        .collect()
}

/// Squared Euclidean distance transform of a `w × h` grid of sites, in cells².
pub fn squared_edt(sites: &[bool], w: usize, h: usize) -> Vec<f64> {
    const INF: f64 = 1e20;
    let mut f: Vec<f64> = sites.iter().map(|&s| if s { 0.0 } else { INF }).collect();
    // One dimension: the lower envelope of parabolas.
    fn pass(f: &[f64]) -> Vec<f64> {
        let n = f.len();
        let mut d = vec![0.0; n];
        let mut v = vec![0usize; n];
        let mut z = vec![0.0f64; n + 1];
        let mut k = 0usize;
        z[0] = f64::NEG_INFINITY;
        z[1] = f64::INFINITY;
        for q in 1..n {
            loop {
                let p = v[k];
                let s = ((f[q] + (q * q) as f64) - (f[p] + (p * p) as f64))
                    / (2.0 * (q as f64 - p as f64));
                if s <= z[k] && k > 0 {
                    k -= 1;
                    continue;
                }
                if s <= z[k] {
                    // k == 0: replace the first parabola.
                    v[0] = q;
                    z[1] = f64::INFINITY;
                    break;
                }
                k += 1;
                v[k] = q;
                z[k] = s;
                z[k + 1] = f64::INFINITY;
                break;
            }
        }
        k = 0;
        for (q, dq) in d.iter_mut().enumerate() {
            while z[k + 1] < q as f64 {
                k += 1;
            }
            let p = v[k];
            *dq = (q as f64 - p as f64).powi(2) + f[p];
        }
        d
    }
    for y in 0..h {
        let row = pass(&f[y * w..(y + 1) * w]);
        f[y * w..(y + 1) * w].copy_from_slice(&row);
    }
    for x in 0..w {
        let col: Vec<f64> = (0..h).map(|y| f[y * w + x]).collect();
        let out = pass(&col);
        for y in 0..h {
            f[y * w + x] = out[y];
        }
    }
    f
}

/// A 10 × 6 m room (5 cm cells) with a wall across the middle from y = 0 to 4.5, so that
/// the way from the left half to the right half goes round its end: the grid the transforms'
/// and the planners' tests share.
#[cfg(test)]
pub(crate) fn room() -> OccupancyGrid {
    let mut g = walled(200, 120);
    for j in 0..90 {
        for i in 99..=101 {
            g.set(i, j, 100);
        }
    }
    g
}

/// A `width` × `height` grid of 5 cm cells at the origin, free inside a one-cell wall: the
/// plain room of the navigation and coverage tests.
#[cfg(test)]
pub(crate) fn walled(width: usize, height: usize) -> OccupancyGrid {
    let mut g = OccupancyGrid::new(0.05, [0.0, 0.0], width, height);
    for j in 0..height {
        for i in 0..width {
            let border = i == 0 || j == 0 || i == width - 1 || j == height - 1;
            g.set(i, j, if border { 100 } else { 0 });
        }
    }
    g
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distance_transform_is_close_to_euclidean() {
        let g = room();
        let d = obstacle_distance(&g, |c| c >= OCCUPIED, 10.0);
        // Cell (50, 60): centre (2.525, 3.025); nearest obstacle cell edge… the left wall's
        // cell 0 centre is at 0.025: 2.5 m, the middle wall's cell 99 at 4.975: 2.45 m.
        let v = d[60 * 200 + 50] as f64;
        assert!((v - 2.45).abs() < 0.01, "{v}");
        // Diagonal case: within the chamfer's 8 % of the Euclidean distance.
        let v = d[20 * 200 + 20] as f64; // 1 m from both the left and the bottom border
        assert!((v - 1.0).abs() < 0.08, "{v}");
    }

    /// The clear distance is the least distance between the cell's square and the sites'
    /// squares (and the squares just off the grid, with the rim), found by comparing every
    /// pair of squares on a small grid of scattered sites.
    #[test]
    fn clear_distance_is_the_gap_between_squares() {
        let (w, h) = (23, 17);
        let mut g = OccupancyGrid::new(1.0, [0.0, 0.0], w, h);
        for (k, c) in g.cells.iter_mut().enumerate() {
            *c = if (k * 7919) % 61 == 0 { 100 } else { 0 };
        }
        let gap = |a: i64, b: i64| ((a - b).abs() - 1).max(0) as f64;
        for rim in [false, true] {
            let got = clear_distance(&g, |c| c >= OCCUPIED, rim);
            for j in 0..h as i64 {
                for i in 0..w as i64 {
                    let mut want = f64::INFINITY;
                    for jj in -1..=h as i64 {
                        for ii in -1..=w as i64 {
                            let off = ii < 0 || jj < 0 || ii >= w as i64 || jj >= h as i64;
                            let site = if off {
                                rim
                            } else {
                                g.get(ii as usize, jj as usize) >= OCCUPIED
                            };
                            if site {
                                want = want.min(gap(i, ii).hypot(gap(j, jj)));
                            }
                        }
                    }
                    let k = j as usize * w + i as usize;
                    assert!(
                        (got[k] - want).abs() < 1e-9,
                        "({i}, {j}) rim {rim}: {} {want}",
                        got[k]
                    );
                }
            }
        }
    }

    /// The textbook's two passes, one sweep per row with the four neighbours taken in turn:
    /// the definition [`obstacle_distance`] must reproduce to the bit.
    fn chamfer_reference(
        grid: &OccupancyGrid,
        obstacle: impl Fn(i8) -> bool,
        cap: f64,
    ) -> Vec<f32> {
        let (w, h) = (grid.width, grid.height);
        let mut d: Vec<f32> = grid
            .cells
            .iter()
            .map(|&c| if obstacle(c) { 0.0 } else { 1e9 })
            .collect();
        let (a, b) = (1.0f32, std::f32::consts::SQRT_2);
        for j in 0..h {
            for i in 0..w {
                let k = j * w + i;
                let mut v = d[k];
                if i > 0 {
                    v = v.min(d[k - 1] + a);
                }
                if j > 0 {
                    v = v.min(d[k - w] + a);
                    if i > 0 {
                        v = v.min(d[k - w - 1] + b);
                    }
                    if i + 1 < w {
                        v = v.min(d[k - w + 1] + b);
                    }
                }
                d[k] = v;
            }
        }
        for j in (0..h).rev() {
            for i in (0..w).rev() {
                let k = j * w + i;
                let mut v = d[k];
                if i + 1 < w {
                    v = v.min(d[k + 1] + a);
                }
                if j + 1 < h {
                    v = v.min(d[k + w] + a);
                    if i + 1 < w {
                        v = v.min(d[k + w + 1] + b);
                    }
                    if i > 0 {
                        v = v.min(d[k + w - 1] + b);
                    }
                }
                d[k] = v;
            }
        }
        let r = grid.resolution as f32;
        d.into_iter().map(|c| (c * r).min(cap as f32)).collect()
    }

    /// The row-split transform gives the reference's values bit for bit: on grids of one row,
    /// one column and many, sparse and dense obstacles, no obstacle at all, and caps below
    /// and above the largest distance.
    #[test]
    fn row_split_transform_is_the_reference_to_the_bit() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(48);
        for (w, h) in [(1, 1), (1, 9), (9, 1), (2, 2), (37, 23), (200, 120)] {
            for density in [0.0, 0.002, 0.05, 0.5] {
                let mut g = OccupancyGrid::new(0.05, [0.0, 0.0], w, h);
                for c in g.cells.iter_mut() {
                    *c = if rng.random::<f64>() < density {
                        100
                    } else if rng.random::<f64>() < 0.3 {
                        -1
                    } else {
                        0
                    };
                }
                for cap in [0.3, 2.0, 100.0] {
                    let want = chamfer_reference(&g, |c| c >= OCCUPIED, cap);
                    let got = obstacle_distance(&g, |c| c >= OCCUPIED, cap);
                    let same = want
                        .iter()
                        .zip(&got)
                        .all(|(a, b)| a.to_bits() == b.to_bits());
                    assert!(
                        same && want.len() == got.len(),
                        "{w}×{h}, {density}, cap {cap}"
                    );
                }
            }
        }
        // The room's walls: the same too, with a predicate that counts unknown as an obstacle.
        let g = room();
        let want = chamfer_reference(&g, |c| !(0..OCCUPIED).contains(&c), 10.0);
        assert_eq!(
            obstacle_distance(&g, |c| !(0..OCCUPIED).contains(&c), 10.0),
            want
        );
    }

    #[test]
    fn edt_is_exact_on_a_knight_move() {
        let mut sites = vec![false; 25];
        sites[0] = true;
        let d = squared_edt(&sites, 5, 5);
        assert_eq!(d[5 + 2], 5.0); // cell (2, 1) of a 5-wide grid: 2² + 1²
        assert_eq!(d[4 * 5 + 4], 32.0);
    }
}
