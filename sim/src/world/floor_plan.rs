//! Walls from a floor plan: the occupied cells of a 2D occupancy grid (a ROS map_server map,
//! such as one `futago replay` built from a real robot's log) extruded into upright walls, so
//! that a map the robots already made becomes a world every scenario can run in.
//!
//! The occupied cells are merged into few axis-aligned rectangles (runs of a row, stacked
//! while the run above has the same extent), each a static box collider. Each box's render
//! mesh holds only the faces that border a cell which is not a wall, so that the camera, the
//! exports and the coverage scores see the surface a person would (no faces hidden inside a
//! thick wall), and the collider and the render agree wherever a surface can be seen.
//!
//! Unknown cells are, by default, sealed where they border free space: a SLAM map leaves
//! unknown what its laser never reached, and a twin should not let its robot drive out into
//! what no one measured. The grid is padded by one unknown cell so that free cells on the
//! map's edge are sealed too. Before sealing, free space narrower than [`MIN_FREE_WIDTH`]
//! (the trace of a laser ray into unmapped space) is taken for unknown.

use futago_msgs::grid::OccupancyGrid;
use futago_render::mesh::{TriMesh, UvMap};
use glam::Vec3;
use serde::Deserialize;

/// Cells at or above this value are walls; below it (and ≥ 0) free (futago's and map_server's
/// trinary image: occupancy ≥ 0.65).
pub const WALL_VALUE: i8 = 65;

/// What unknown cells of the map become.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum UnknownCells {
    /// Walls where they touch free space (8-neighbourhood), so the world is closed.
    #[default]
    Wall,
    /// Open floor.
    Free,
}

/// A rectangle of wall cells: columns `i0..=i1`, rows `j0..=j1` of the padded grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Rect {
    pub i0: usize,
    pub j0: usize,
    pub i1: usize,
    pub j1: usize,
}

/// The wall cells of a map, on a grid padded by one cell on every side.
#[derive(Debug, Clone)]
pub struct WallCells {
    pub resolution: f64,
    /// Lower-left corner of the padded grid's cell (0, 0), m.
    pub origin: [f64; 2],
    pub width: usize,
    pub height: usize,
    pub wall: Vec<bool>,
}

/// Free space narrower than this is taken for unknown before unknown cells are sealed, m:
/// a SLAM map's free cells include the traces of single laser rays through doors, glass and
/// gaps into space never mapped, a cell or two wide, which would otherwise become corridors
/// walled on both sides. 0.15 m is under half the Create's width.
pub const MIN_FREE_WIDTH: f64 = 0.15;

/// Free cells that lie in some `k × k` block of free cells (a morphological opening of the
/// free space by a square), on a `w × h` grid.
fn opened(free: &[bool], w: usize, h: usize, k: usize) -> Vec<bool> {
    // Prefix sums over (w + 1) × (h + 1).
    let sums = |m: &[bool]| {
        let mut s = vec![0u32; (w + 1) * (h + 1)];
        for j in 0..h {
            for i in 0..w {
                s[(j + 1) * (w + 1) + i + 1] =
                    m[j * w + i] as u32 + s[j * (w + 1) + i + 1] + s[(j + 1) * (w + 1) + i]
                        - s[j * (w + 1) + i];
            }
        }
        s
    };
    // Count of `s`'s cells in columns i0..i1, rows j0..j1 (half-open).
    let count = |s: &[u32], i0: usize, j0: usize, i1: usize, j1: usize| {
        s[j1 * (w + 1) + i1] + s[j0 * (w + 1) + i0] - s[j0 * (w + 1) + i1] - s[j1 * (w + 1) + i0]
    };
    let f = sums(free);
    // Blocks by their lower-left cell.
    let block: Vec<bool> = (0..w * h)
        .map(|c| {
            let (i, j) = (c % w, c / w);
            i + k <= w && j + k <= h && count(&f, i, j, i + k, j + k) == (k * k) as u32
        })
        .collect();
    let b = sums(&block);
    (0..w * h)
        .map(|c| {
            let (i, j) = (c % w, c / w);
            free[c]
                && count(
                    &b,
                    (i + 1).saturating_sub(k),
                    (j + 1).saturating_sub(k),
                    i + 1,
                    j + 1,
                ) > 0
        })
        .collect()
}

impl WallCells {
    /// The walls of `grid`, with unknown cells treated as `unknown` says.
    pub fn new(grid: &OccupancyGrid, unknown: UnknownCells) -> WallCells {
        let (w, h) = (grid.width + 2, grid.height + 2);
        // Padded values: −1 round the edge.
        let raw = |i: usize, j: usize| -> i8 {
            if i == 0 || j == 0 || i == w - 1 || j == h - 1 {
                -1
            } else {
                grid.get(i - 1, j - 1)
            }
        };
        // Where unknown cells are sealed, free space too thin to be a place is unknown.
        let kept = if unknown == UnknownCells::Wall {
            let free: Vec<bool> = (0..w * h)
                .map(|c| (0..WALL_VALUE).contains(&raw(c % w, c / w)))
                .collect();
            let k = (MIN_FREE_WIDTH / grid.resolution).ceil().max(1.0) as usize;
            Some(opened(&free, w, h, k))
        } else {
            None
        };
        let value = |i: usize, j: usize| -> i8 {
            let v = raw(i, j);
            match &kept {
                Some(kept) if (0..WALL_VALUE).contains(&v) && !kept[j * w + i] => -1,
                _ => v,
            }
        };
        let mut wall = vec![false; w * h];
        for j in 0..h {
            for i in 0..w {
                let v = value(i, j);
                wall[j * w + i] = if v >= WALL_VALUE {
                    true
                } else if v < 0 && unknown == UnknownCells::Wall {
                    // Sealed where any of the 8 neighbours is free.
                    (j.saturating_sub(1)..=(j + 1).min(h - 1)).any(|jj| {
                        (i.saturating_sub(1)..=(i + 1).min(w - 1)).any(|ii| {
                            let n = value(ii, jj);
                            (0..WALL_VALUE).contains(&n)
                        })
                    })
                } else {
                    false
                };
            }
        }
        WallCells {
            resolution: grid.resolution,
            origin: [
                grid.origin[0] - grid.resolution,
                grid.origin[1] - grid.resolution,
            ],
            width: w,
            height: h,
            wall,
        }
    }

    /// Whether cell `(i, j)` is a wall; cells outside the grid are not.
    pub fn is_wall(&self, i: isize, j: isize) -> bool {
        i >= 0
            && j >= 0
            && (i as usize) < self.width
            && (j as usize) < self.height
            && self.wall[j as usize * self.width + i as usize]
    }

    /// Number of wall cells.
    pub fn count(&self) -> usize {
        self.wall.iter().filter(|w| **w).count()
    }

    /// The wall cells as disjoint rectangles: each row's runs, a run extending the rectangle
    /// below it when that rectangle spans the same columns. Deterministic, bottom to top.
    pub fn rectangles(&self) -> Vec<Rect> {
        let mut done: Vec<Rect> = Vec::new();
        // Rectangles still growing, by their column span.
        let mut open: Vec<Rect> = Vec::new();
        for j in 0..self.height {
            let mut runs = Vec::new();
            let mut i = 0;
            while i < self.width {
                if self.wall[j * self.width + i] {
                    let i0 = i;
                    while i < self.width && self.wall[j * self.width + i] {
                        i += 1;
                    }
                    runs.push((i0, i - 1));
                } else {
                    i += 1;
                }
            }
            let mut next = Vec::with_capacity(runs.len());
            for (i0, i1) in runs {
                match open.iter().position(|r| r.i0 == i0 && r.i1 == i1) {
                    Some(k) => {
                        let mut r = open.swap_remove(k);
                        r.j1 = j;
                        next.push(r);
                    }
                    None => next.push(Rect {
                        i0,
                        j0: j,
                        i1,
                        j1: j,
                    }),
                }
            }
            done.append(&mut open);
            open = next;
        }
        done.append(&mut open);
        done.sort_by_key(|r| (r.j0, r.i0));
        done
    }

    /// The centre (x, y) and half extents (x, y) of a rectangle, m.
    pub fn extent(&self, r: &Rect) -> ([f64; 2], [f64; 2]) {
        let res = self.resolution;
        let x0 = self.origin[0] + r.i0 as f64 * res;
        let x1 = self.origin[0] + (r.i1 + 1) as f64 * res;
        let y0 = self.origin[1] + r.j0 as f64 * res;
        let y1 = self.origin[1] + (r.j1 + 1) as f64 * res;
        (
            [(x0 + x1) / 2.0, (y0 + y1) / 2.0],
            [(x1 - x0) / 2.0, (y1 - y0) / 2.0],
        )
    }

    /// The render mesh of rectangle `r` extruded to `height`, in the frame of its centre at
    /// half height: its top, and the parts of its four sides that face a cell which is not a
    /// wall (no bottom: it stands on the floor).
    pub fn mesh(&self, r: &Rect, height: f32, uv: UvMap) -> TriMesh {
        let (_, half) = self.extent(r);
        let (hx, hy, hz) = (half[0] as f32, half[1] as f32, height / 2.0);
        let res = self.resolution as f32;
        let mut m = TriMesh::default();
        let up = Vec3::new(0.0, 0.0, 2.0 * hz);
        // Runs along a side where the outer neighbour is open: (first, last) cell offsets.
        let open_runs = |n: usize, open: &dyn Fn(usize) -> bool| -> Vec<(usize, usize)> {
            let mut runs = Vec::new();
            let mut k = 0;
            while k < n {
                if open(k) {
                    let a = k;
                    while k < n && open(k) {
                        k += 1;
                    }
                    runs.push((a, k - 1));
                } else {
                    k += 1;
                }
            }
            runs
        };
        let (ni, nj) = (r.i1 - r.i0 + 1, r.j1 - r.j0 + 1);
        let (i0, j0, i1, j1) = (r.i0 as isize, r.j0 as isize, r.i1 as isize, r.j1 as isize);
        // −x side.
        for (a, b) in open_runs(nj, &|k| !self.is_wall(i0 - 1, j0 + k as isize)) {
            let (y0, y1) = (-hy + a as f32 * res, -hy + (b + 1) as f32 * res);
            m.push_quad(
                Vec3::new(-hx, y1, -hz),
                Vec3::new(0.0, y0 - y1, 0.0),
                up,
                uv,
            );
        }
        // +x side.
        for (a, b) in open_runs(nj, &|k| !self.is_wall(i1 + 1, j0 + k as isize)) {
            let (y0, y1) = (-hy + a as f32 * res, -hy + (b + 1) as f32 * res);
            m.push_quad(Vec3::new(hx, y0, -hz), Vec3::new(0.0, y1 - y0, 0.0), up, uv);
        }
        // −y side.
        for (a, b) in open_runs(ni, &|k| !self.is_wall(i0 + k as isize, j0 - 1)) {
            let (x0, x1) = (-hx + a as f32 * res, -hx + (b + 1) as f32 * res);
            m.push_quad(
                Vec3::new(x0, -hy, -hz),
                Vec3::new(x1 - x0, 0.0, 0.0),
                up,
                uv,
            );
        }
        // +y side.
        for (a, b) in open_runs(ni, &|k| !self.is_wall(i0 + k as isize, j1 + 1)) {
            let (x0, x1) = (-hx + a as f32 * res, -hx + (b + 1) as f32 * res);
            m.push_quad(Vec3::new(x1, hy, -hz), Vec3::new(x0 - x1, 0.0, 0.0), up, uv);
        }
        // Top.
        m.push_quad(
            Vec3::new(-hx, -hy, hz),
            Vec3::new(2.0 * hx, 0.0, 0.0),
            Vec3::new(0.0, 2.0 * hy, 0.0),
            uv,
        );
        m
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 6 × 5 map at 0.1 m: a ring of wall round a free 4 × 3 room, with one unknown cell
    /// outside it.
    fn room() -> OccupancyGrid {
        let mut g = OccupancyGrid::new(0.1, [1.0, 2.0], 6, 5);
        for j in 0..5 {
            for i in 0..6 {
                let ring = i == 0 || j == 0 || i == 5 || j == 4;
                g.set(i, j, if ring { 100 } else { 0 });
            }
        }
        g
    }

    /// The rectangles cover each wall cell exactly once.
    #[test]
    fn rectangles_tile_the_wall_cells() {
        let mut g = room();
        g.set(2, 2, 100);
        g.set(3, 2, 100);
        let w = WallCells::new(&g, UnknownCells::Free);
        let rects = w.rectangles();
        let mut hit = vec![0; w.width * w.height];
        for r in &rects {
            for j in r.j0..=r.j1 {
                for i in r.i0..=r.i1 {
                    hit[j * w.width + i] += 1;
                }
            }
        }
        for (k, n) in hit.iter().enumerate() {
            assert_eq!(*n, w.wall[k] as i32, "cell {k}");
        }
        // Bottom row, left and right columns (3 rows between), the two-cell island, top row.
        assert_eq!(rects.len(), 5, "{rects:?}");
        assert_eq!(w.count(), 18 + 2);
    }

    /// The visible wall area of the room is its inner and outer perimeter times the height:
    /// faces between wall cells are left out.
    #[test]
    fn only_faces_between_wall_and_open_cells_are_meshed() {
        let w = WallCells::new(&room(), UnknownCells::Free);
        let h = 2.0;
        let mut upright = 0.0;
        let mut top = 0.0;
        for r in w.rectangles() {
            let m = w.mesh(&r, h, UvMap::Fit);
            for t in &m.indices {
                let (a, b, c) = m.corners(t);
                let n = (b - a).cross(c - a);
                // Wound counter-clockwise seen from outside (the renderer draws these faces
                // from the front alone): the face turns away from the rectangle's centre,
                // the mesh's origin.
                assert!(n.dot((a + b + c) / 3.0) > 0.0, "a face wound inwards");
                if n.z.abs() < 1e-6 {
                    upright += 0.5 * n.length();
                } else {
                    assert!(n.z > 0.0, "a downward face");
                    top += 0.5 * n.length();
                }
            }
        }
        // Outer perimeter 2·(0.6 + 0.5) = 2.2 m, inner 2·(0.4 + 0.3) = 1.4 m.
        assert!((upright - (2.2 + 1.4) * 2.0).abs() < 1e-4, "{upright}");
        // Tops: 18 cells of 0.01 m².
        assert!((top - 0.18).abs() < 1e-4, "{top}");
        // Normals point out of the wall: the inner −x face of the right column faces −x.
        let right = w
            .rectangles()
            .into_iter()
            .find(|r| r.i0 == 6 && r.i1 == 6 && r.j1 > r.j0)
            .unwrap();
        let m = w.mesh(&right, h, UvMap::Fit);
        assert!(m.normals.iter().any(|n| n.x < -0.99));
        assert!(m.normals.iter().any(|n| n.x > 0.99));
    }

    /// Unknown cells touching free space become walls; the map's free edge is sealed by the
    /// padding; unknown cells away from free space stay open.
    #[test]
    fn unknown_cells_are_sealed_where_they_touch_free_space() {
        // Two rows at 0.1 m: a 2 × 2 free block (wide enough to be kept), then unknown.
        let mut g = OccupancyGrid::new(0.1, [0.0, 0.0], 5, 2);
        g.cells = vec![0, 0, -1, -1, -1, 0, 0, -1, -1, -1];
        let w = WallCells::new(&g, UnknownCells::Wall);
        // Padded row 1: pad, free, free, sealed, unknown, unknown, pad.
        let row: Vec<bool> = (0..7).map(|i| w.is_wall(i, 1)).collect();
        assert_eq!(row, [true, false, false, true, false, false, false]);
        // The padding below and above the free cells is sealed (diagonals too).
        assert!(w.is_wall(0, 0) && w.is_wall(3, 3) && !w.is_wall(4, 3));
        let open = WallCells::new(&g, UnknownCells::Free);
        assert_eq!(open.count(), 0);
        assert_eq!(open.origin, [-0.1, -0.1]);
    }

    /// A ray's trace, one cell wide, out of a room into unknown space is not walled in:
    /// its cells are unknown and only the room's side of it is sealed.
    #[test]
    fn a_ray_trace_into_unknown_space_is_not_walled_in() {
        // At 5 cm: a free 6 × 6 room (cells 0..6) and a one-cell trace from it along row 2
        // out to column 20; unknown elsewhere.
        let mut g = OccupancyGrid::new(0.05, [0.0, 0.0], 24, 8);
        for j in 0..6 {
            for i in 0..6 {
                g.set(i, j, 0);
            }
        }
        for i in 6..20 {
            g.set(i, 2, 0);
        }
        let w = WallCells::new(&g, UnknownCells::Wall);
        // Padded coordinates: +1. The trace's far cells and their sides stay open.
        for i in 9..21 {
            assert!(
                !w.is_wall(i, 3) && !w.is_wall(i, 2) && !w.is_wall(i, 4),
                "column {i}"
            );
        }
        // The room's east side is sealed, where the trace left it too.
        assert!(w.is_wall(7, 3) && w.is_wall(7, 1));
        // Kept free: the room.
        assert!(!w.is_wall(3, 3));
    }
}
