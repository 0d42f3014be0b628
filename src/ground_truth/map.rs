//! 2D map metrics (written for futago): an estimated occupancy grid against the world's own
//! grid of the same height band.
//!
//! The map frame is the world frame: SLAM starts at the scenario's start pose, so no alignment
//! is searched for (a search would hide a map that is offset or turned). What is compared:
//!
//! - the true obstacles the robot could have seen: occupied cells next to free space reachable
//!   from the start (the wall faces; the inside of a wall and the far side of the building's
//!   shell cannot be mapped by a laser);
//! - the true free space: the cells reachable from the start.
//!
//! Precision: the share of the estimate's occupied cells within `k` cells of a true obstacle.
//! Recall: the share of true obstacles within `k` cells of an occupied estimated cell. Mean
//! distances each way are capped at [`DISTANCE_CAP`]. Free-space IoU is computed on the true
//! grid's cells. Distances are exact Euclidean distances between cell centres (Felzenszwalb
//! and Huttenlocher's transform).

use futago_msgs::grid::OccupancyGrid;
use futago_robot::geometry::grid::{OCCUPIED, squared_edt};

/// Distances beyond this count as this in the mean distances, m.
pub const DISTANCE_CAP: f64 = 1.0;

/// The scores of one map.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct MapScore {
    /// Precision, recall and F1 within 1 and 2 cells.
    pub precision: [f64; 2],
    pub recall: [f64; 2],
    pub f1: [f64; 2],
    /// Mean distance from the estimate's obstacles to the true ones, and back, m.
    pub mean_distance_to_truth: f64,
    pub mean_distance_from_truth: f64,
    pub free_iou: f64,
    pub true_obstacle_cells: usize,
    pub map_obstacle_cells: usize,
}

/// Distance (m) from world point `p` to the nearest site of a grid's transform; the cap
/// outside the grid.
fn distance_at(grid: &OccupancyGrid, sq: &[f64], p: [f64; 2]) -> f64 {
    match grid.cell_of(p[0], p[1]) {
        Some((i, j)) => (sq[j * grid.width + i].sqrt() * grid.resolution).min(DISTANCE_CAP),
        None => DISTANCE_CAP,
    }
}

/// Distances (m) of world points to the nearest true wall of a grid: to the nearest occupied
/// cell's square, exactly, capped at 1 m. For the laser-height slice of a 3D map, which seed
/// 000 judged against the 2D map. The transform finds the nearest cell centre; the squares
/// within a cell and a half beyond it are then measured exactly.
pub fn wall_distances(truth: &OccupancyGrid, points: &[[f64; 2]]) -> Vec<f64> {
    let sites: Vec<bool> = truth.cells.iter().map(|&c| c >= OCCUPIED).collect();
    let sq = squared_edt(&sites, truth.width, truth.height);
    let r = truth.resolution;
    points
        .iter()
        .map(|p| {
            let Some((i, j)) = truth.cell_of(p[0], p[1]) else {
                return DISTANCE_CAP;
            };
            let centre = sq[j * truth.width + i].sqrt();
            if centre * r > DISTANCE_CAP + 2.0 * r {
                return DISTANCE_CAP;
            }
            let reach = (centre + 1.5).ceil() as i64;
            let mut best = f64::INFINITY;
            for b in (j as i64 - reach).max(0)..=(j as i64 + reach).min(truth.height as i64 - 1) {
                for a in (i as i64 - reach).max(0)..=(i as i64 + reach).min(truth.width as i64 - 1)
                {
                    if !sites[b as usize * truth.width + a as usize] {
                        continue;
                    }
                    let c = truth.cell_center(a as usize, b as usize);
                    let dx = ((p[0] - c[0]).abs() - r / 2.0).max(0.0);
                    let dy = ((p[1] - c[1]).abs() - r / 2.0).max(0.0);
                    best = best.min(dx.hypot(dy));
                }
            }
            best.min(DISTANCE_CAP)
        })
        .collect()
}

/// Scores `estimate` against `truth` for a robot that started at `start` (world frame);
/// `Err` when the start is not in the truth's free space.
pub fn score(
    estimate: &OccupancyGrid,
    truth: &OccupancyGrid,
    start: [f64; 2],
) -> Result<MapScore, String> {
    let (w, h) = (truth.width, truth.height);
    let free = |c: i8| (0..OCCUPIED).contains(&c);
    let (si, sj) = truth
        .cell_of(start[0], start[1])
        .filter(|&(i, j)| free(truth.get(i, j)))
        .ok_or_else(|| {
            format!(
                "the start ({:.2}, {:.2}) is not in the true map's free space",
                start[0], start[1]
            )
        })?;
    // Reachable free space (4-connected flood fill).
    let mut reach = vec![false; w * h];
    let mut stack = vec![(si, sj)];
    reach[sj * w + si] = true;
    while let Some((i, j)) = stack.pop() {
        for (di, dj) in [(-1i64, 0i64), (1, 0), (0, -1), (0, 1)] {
            let (a, b) = (i as i64 + di, j as i64 + dj);
            if a < 0 || b < 0 || a >= w as i64 || b >= h as i64 {
                continue;
            }
            let (a, b) = (a as usize, b as usize);
            if !reach[b * w + a] && free(truth.get(a, b)) {
                reach[b * w + a] = true;
                stack.push((a, b));
            }
        }
    }
    // Wall faces: occupied cells with a reachable 4-neighbour.
    let mut faces = vec![false; w * h];
    for j in 0..h {
        for i in 0..w {
            if truth.get(i, j) < OCCUPIED {
                continue;
            }
            faces[j * w + i] = [(-1i64, 0i64), (1, 0), (0, -1), (0, 1)]
                .iter()
                .any(|(di, dj)| {
                    let (a, b) = (i as i64 + di, j as i64 + dj);
                    a >= 0
                        && b >= 0
                        && a < w as i64
                        && b < h as i64
                        && reach[b as usize * w + a as usize]
                });
        }
    }
    let est_occ: Vec<bool> = estimate.cells.iter().map(|&c| c >= OCCUPIED).collect();
    let truth_sq = squared_edt(&faces, w, h);
    let est_sq = squared_edt(&est_occ, estimate.width, estimate.height);
    let cells = |g: &OccupancyGrid, mask: &[bool]| -> Vec<[f64; 2]> {
        (0..g.height)
            .flat_map(|j| (0..g.width).map(move |i| (i, j)))
            .filter(|&(i, j)| mask[j * g.width + i])
            .map(|(i, j)| g.cell_center(i, j))
            .collect()
    };
    let est_points = cells(estimate, &est_occ);
    let face_points = cells(truth, &faces);
    let to_truth: Vec<f64> = est_points
        .iter()
        .map(|p| distance_at(truth, &truth_sq, *p))
        .collect();
    let from_truth: Vec<f64> = face_points
        .iter()
        .map(|p| distance_at(estimate, &est_sq, *p))
        .collect();
    let share = |d: &[f64], lim: f64| {
        if d.is_empty() {
            0.0
        } else {
            d.iter().filter(|&&x| x <= lim + 1e-9).count() as f64 / d.len() as f64
        }
    };
    let mean = |d: &[f64]| {
        if d.is_empty() {
            DISTANCE_CAP
        } else {
            d.iter().sum::<f64>() / d.len() as f64
        }
    };
    let mut precision = [0.0; 2];
    let mut recall = [0.0; 2];
    let mut f1 = [0.0; 2];
    for k in 0..2 {
        let lim = (k + 1) as f64 * truth.resolution;
        precision[k] = share(&to_truth, lim);
        recall[k] = share(&from_truth, lim);
        f1[k] = if precision[k] + recall[k] > 0.0 {
            2.0 * precision[k] * recall[k] / (precision[k] + recall[k])
        } else {
            0.0
        };
    }
    // Free space on the truth's cells.
    let (mut both, mut either) = (0usize, 0usize);
    for j in 0..h {
        for i in 0..w {
            let c = truth.cell_center(i, j);
            let e = estimate
                .cell_of(c[0], c[1])
                .is_some_and(|(a, b)| free(estimate.get(a, b)));
            let t = reach[j * w + i];
            both += (e && t) as usize;
            either += (e || t) as usize;
        }
    }
    Ok(MapScore {
        precision,
        recall,
        f1,
        mean_distance_to_truth: mean(&to_truth),
        mean_distance_from_truth: mean(&from_truth),
        free_iou: if either > 0 {
            both as f64 / either as f64
        } else {
            0.0
        },
        true_obstacle_cells: face_points.len(),
        map_obstacle_cells: est_points.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 10 × 10-cell room (0.1 m cells): walls on the border, free inside.
    fn room() -> OccupancyGrid {
        let mut g = OccupancyGrid::new(0.1, [0.0, 0.0], 10, 10);
        for j in 0..10 {
            for i in 0..10 {
                let wall = i == 0 || j == 0 || i == 9 || j == 9;
                g.set(i, j, if wall { 100 } else { 0 });
            }
        }
        g
    }

    #[test]
    fn a_perfect_map_scores_one_and_a_shifted_one_by_hand() {
        let truth = room();
        let s = score(&truth, &truth, [0.5, 0.5]).unwrap();
        assert_eq!(s.precision, [1.0, 1.0]);
        assert_eq!(s.recall, [1.0, 1.0]);
        assert_eq!(s.free_iou, 1.0);
        assert_eq!(s.mean_distance_from_truth, 0.0);
        // The four corner cells are walls but no face: 0.1 m from the nearest face each.
        assert!((s.mean_distance_to_truth - 4.0 * 0.1 / 36.0).abs() < 1e-12);
        // Faces: the 36 border cells minus the 4 corners (their neighbours are walls).
        assert_eq!(s.true_obstacle_cells, 32);
        // The same map one cell (0.1 m) to the right, with an unknown column on the left.
        let mut shifted = OccupancyGrid::new(0.1, [0.1, 0.0], 10, 10);
        shifted.cells = truth.cells.clone();
        let s = score(&shifted, &truth, [0.5, 0.5]).unwrap();
        // Within one cell all but the right wall (now beyond the true grid, 10 of 36 cells)
        // is matched…
        assert!(
            (s.precision[0] - 26.0 / 36.0).abs() < 1e-12,
            "{:?}",
            s.precision
        );
        // …but on the truth's cells the free space moved: inside x 0.2–0.9 and y 0.1–0.8 the
        // estimate is free (7 × 8 = 56 cells); the truth's 64 free cells and the estimate's
        // 8 cells at x = 0.9 make the union 64 + 8 = 72.
        assert!((s.free_iou - 56.0 / 72.0).abs() < 1e-12, "{}", s.free_iou);
        // Mean distance to the truth over the estimate's 36 wall cells, by hand: the left
        // wall (x = 0.15) lies 0.1 m from the true left faces for its 8 middle cells and on
        // the true bottom and top faces for its end cells; the right wall (x = 1.05) is
        // outside the truth's grid (capped at 1 m, 10 cells); the bottom and top rows sit on
        // true faces except their cells at x = 0.95, true corners 0.1 m from a face.
        let expected = (8.0 * 0.1 + 10.0 * 1.0 + 2.0 * 0.1) / 36.0;
        assert!(
            (s.mean_distance_to_truth - expected).abs() < 1e-9,
            "{} vs {expected}",
            s.mean_distance_to_truth
        );
    }

    #[test]
    fn wall_distances_are_measured_to_the_cells_edge() {
        let g = room();
        // Walls are the border cells of a 1 m room of 0.1 m cells: the free space is
        // [0.1, 0.9]². Inside a wall, 3 cm from the left wall's face, at the centre, and near
        // a corner (3 cm from the left face, 4 cm from the bottom one: the nearer counts).
        let d = wall_distances(&g, &[[0.05, 0.5], [0.13, 0.5], [0.5, 0.5], [0.13, 0.14]]);
        assert_eq!(d[0], 0.0);
        assert!((d[1] - 0.03).abs() < 1e-9, "{d:?}");
        assert!((d[2] - 0.4).abs() < 1e-9, "{d:?}");
        assert!((d[3] - 0.03).abs() < 1e-9, "{d:?}");
    }

    #[test]
    fn a_start_in_a_wall_is_an_error() {
        assert!(score(&room(), &room(), [0.05, 0.05]).is_err());
    }
}
