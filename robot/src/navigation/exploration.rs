//! Frontier exploration (written for futago, after Yamauchi, "A frontier-based approach for
//! autonomous exploration", CIRA 1997): a frontier is a free cell of the map being built that
//! borders unknown space; connected frontier cells form a frontier, and the robot drives to the
//! nearest cell of one long enough to matter, until none is left that it can reach.

use crate::geometry::grid::{OCCUPIED, obstacle_distance};
use crate::navigation::planner::grid_path;
use futago_msgs::grid::OccupancyGrid;

/// The frontiers of `grid`: groups of 8-connected free cells with an unknown 4-neighbour,
/// at least `min_cells` strong. Returns a per-cell frontier id (`u32::MAX`: none) and the
/// number of frontiers.
pub fn frontiers(grid: &OccupancyGrid, min_cells: usize) -> (Vec<u32>, usize) {
    let (w, h) = (grid.width, grid.height);
    let free = |i: usize, j: usize| {
        let c = grid.get(i, j);
        (0..OCCUPIED).contains(&c)
    };
    let unknown = |i: i64, j: i64| {
        i >= 0
            && j >= 0
            && (i as usize) < w
            && (j as usize) < h
            && grid.get(i as usize, j as usize) < 0
    };
    let is_frontier = |i: usize, j: usize| {
        let (a, b) = (i as i64, j as i64);
        free(i, j)
            && (unknown(a - 1, b) || unknown(a + 1, b) || unknown(a, b - 1) || unknown(a, b + 1))
    };
    let mut label = vec![u32::MAX; w * h];
    let mut seen = vec![false; w * h];
    let mut count = 0u32;
    for j in 0..h {
        for i in 0..w {
            if seen[j * w + i] || !is_frontier(i, j) {
                continue;
            }
            // Flood fill this frontier.
            let mut members = vec![(i, j)];
            seen[j * w + i] = true;
            let mut k = 0;
            while k < members.len() {
                let (ci, cj) = members[k];
                k += 1;
                for dj in -1i64..=1 {
                    for di in -1i64..=1 {
                        let (ni, nj) = (ci as i64 + di, cj as i64 + dj);
                        if ni < 0 || nj < 0 || ni >= w as i64 || nj >= h as i64 {
                            continue;
                        }
                        let (ni, nj) = (ni as usize, nj as usize);
                        if !seen[nj * w + ni] && is_frontier(ni, nj) {
                            seen[nj * w + ni] = true;
                            members.push((ni, nj));
                        }
                    }
                }
            }
            if members.len() >= min_cells {
                for (a, b) in members {
                    label[b * w + a] = count;
                }
                count += 1;
            }
        }
    }
    (label, count as usize)
}

/// The path from `start` to the nearest reachable cell of a frontier at least `min_length`
/// long (m), keeping `clearance` from obstacles, and avoiding cells within `exclusion` of the
/// points in `exhausted` (frontiers already driven to that stayed frontiers). `None` when no
/// frontier is left within reach: the exploration is over.
pub fn path_to_frontier(
    grid: &OccupancyGrid,
    start: [f64; 2],
    min_length: f64,
    clearance: f64,
    exhausted: &[[f64; 2]],
    exclusion: f64,
) -> Option<Vec<[f64; 2]>> {
    let min_cells = (min_length / grid.resolution).ceil().max(1.0) as usize;
    let (label, n) = frontiers(grid, min_cells);
    if n == 0 {
        return None;
    }
    let distance = obstacle_distance(grid, |c| c >= OCCUPIED, 5.0);
    let w = grid.width;
    grid_path(grid, &distance, clearance, start, |i, j| {
        label[j * w + i] != u32::MAX && {
            let p = grid.cell_center(i, j);
            exhausted
                .iter()
                .all(|q| (q[0] - p[0]).hypot(q[1] - p[1]) > exclusion)
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Known: a free 4 × 2 m strip with walls along its long sides; unknown beyond both ends
    /// (x < 0.5 and x > 4.5), plus a single unknown cell inside (too small to count).
    fn strip() -> OccupancyGrid {
        let mut g = OccupancyGrid::new(0.05, [0.0, 0.0], 100, 40);
        for j in 0..40 {
            for i in 10..90 {
                let wall = j == 0 || j == 39;
                g.set(i, j, if wall { 100 } else { 0 });
            }
        }
        g.set(50, 20, -1);
        g
    }

    #[test]
    fn frontiers_are_the_two_open_ends() {
        let g = strip();
        let (label, n) = frontiers(&g, 5);
        assert_eq!(n, 2, "the lone unknown cell's four neighbours are too few");
        // Both ends are frontiers of 38 free cells each (the wall rows are not free).
        for i in [10, 89] {
            let ids: std::collections::BTreeSet<u32> =
                (1..39).map(|j| label[j * 100 + i]).collect();
            assert_eq!(ids.len(), 1);
            assert!(!ids.contains(&u32::MAX));
        }
        assert_eq!(label.iter().filter(|&&l| l != u32::MAX).count(), 76);
        // With a lower threshold the cell's neighbours count too.
        assert_eq!(frontiers(&g, 1).1, 3);
    }

    #[test]
    fn the_nearest_frontier_wins_and_exhausted_ones_are_skipped() {
        let g = strip();
        let path = path_to_frontier(&g, [3.5, 1.0], 0.5, 0.2, &[], 0.5).unwrap();
        let end = *path.last().unwrap();
        assert!(
            (end[0] - 4.475).abs() < 0.01,
            "nearest is the right end: {end:?}"
        );
        let path = path_to_frontier(&g, [3.5, 1.0], 0.5, 0.2, &[[4.5, 1.0]], 1.5).unwrap();
        let end = *path.last().unwrap();
        assert!(
            (end[0] - 0.525).abs() < 0.01,
            "the right end is exhausted: {end:?}"
        );
        assert!(
            path_to_frontier(&g, [3.5, 1.0], 0.5, 0.2, &[[4.5, 1.0], [0.5, 1.0]], 1.5).is_none()
        );
    }
}
