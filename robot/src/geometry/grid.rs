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

/// The most by which [`obstacle_distance`]'s chamfer distance exceeds the Euclidean, as a
/// factor (1.0824 at 22.5°), rounded up: a distance divided by it is never more than the true
/// one (the clearances that let ray casts skip open space).
pub const CHAMFER_OVERESTIMATE: f64 = 1.09;

/// Distance from each cell's centre to the nearest cell for which `obstacle` holds, m
/// (two-pass chamfer transform with weights 1 and √2, within 8 % of Euclidean), capped at
/// `cap`. Row-major like the grid.
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

    #[test]
    fn edt_is_exact_on_a_knight_move() {
        let mut sites = vec![false; 25];
        sites[0] = true;
        let d = squared_edt(&sites, 5, 5);
        assert_eq!(d[5 + 2], 5.0); // cell (2, 1) of a 5-wide grid: 2² + 1²
        assert_eq!(d[4 * 5 + 4], 32.0);
    }
}
