//! Occupancy grids and their ROS `map_server` files (PGM image + YAML metadata).
//!
//! Cells hold `nav_msgs/OccupancyGrid` values: −1 unknown, 0 free … 100 occupied. Cell
//! `(i, j)` covers `[ox + i·r, ox + (i+1)·r) × [oy + j·r, oy + (j+1)·r)`; row `j = 0` is the
//! bottom of the map, which is the *last* row of the PGM image (map_server's convention).

use std::fmt::Write as _;
use std::io;
use std::path::Path;

/// A 2D occupancy grid.
#[derive(Debug, Clone, PartialEq)]
pub struct OccupancyGrid {
    /// Cell side, m.
    pub resolution: f64,
    /// World coordinates of the lower-left corner of cell (0, 0), m.
    pub origin: [f64; 2],
    pub width: usize,
    pub height: usize,
    /// Row-major from the bottom row: −1 unknown, 0 … 100 occupancy.
    pub cells: Vec<i8>,
}

impl OccupancyGrid {
    /// A grid of `width × height` unknown cells.
    pub fn new(resolution: f64, origin: [f64; 2], width: usize, height: usize) -> OccupancyGrid {
        OccupancyGrid {
            resolution,
            origin,
            width,
            height,
            cells: vec![-1; width * height],
        }
    }

    /// Value of cell `(i, j)`.
    pub fn get(&self, i: usize, j: usize) -> i8 {
        self.cells[j * self.width + i]
    }

    /// Sets cell `(i, j)`.
    pub fn set(&mut self, i: usize, j: usize, v: i8) {
        self.cells[j * self.width + i] = v;
    }

    /// The cell containing world point `(x, y)`, if inside the grid.
    pub fn cell_of(&self, x: f64, y: f64) -> Option<(usize, usize)> {
        let i = (x - self.origin[0]) / self.resolution;
        let j = (y - self.origin[1]) / self.resolution;
        // Below zero (or NaN) is off the grid; at or above it, truncation is the floor. (The
        // float `floor` is a call into the maths library on baseline x86-64, and this is the
        // innermost step of every ray cast on a grid.)
        if !(i >= 0.0 && j >= 0.0) {
            return None;
        }
        let (i, j) = (i as usize, j as usize);
        (i < self.width && j < self.height).then_some((i, j))
    }

    /// World coordinates of the centre of cell `(i, j)`.
    pub fn cell_center(&self, i: usize, j: usize) -> [f64; 2] {
        [
            self.origin[0] + (i as f64 + 0.5) * self.resolution,
            self.origin[1] + (j as f64 + 0.5) * self.resolution,
        ]
    }

    /// The trinary PGM (P5) image: occupied (≥ 65) black 0, free (≤ 19) white 254, other 205.
    pub fn to_pgm(&self) -> Vec<u8> {
        let mut out = Vec::new();
        // Writing to memory cannot fail.
        let _ = self.write_pgm(&mut out);
        out
    }

    /// Writes the image of [`OccupancyGrid::to_pgm`] row by row, so that a building-size map
    /// is not held twice in memory.
    pub fn write_pgm(&self, out: &mut impl io::Write) -> io::Result<()> {
        write!(
            out,
            "P5\n# futago occupancy grid, resolution {} m\n{} {}\n255\n",
            self.resolution, self.width, self.height
        )?;
        let mut row = vec![0u8; self.width];
        for j in (0..self.height).rev() {
            for (i, px) in row.iter_mut().enumerate() {
                *px = match self.get(i, j) {
                    v if v >= 65 => 0,
                    v if (0..=19).contains(&v) => 254,
                    _ => 205,
                };
            }
            out.write_all(&row)?;
        }
        Ok(())
    }

    /// The map_server YAML naming `image` (a path relative to the YAML file).
    pub fn to_yaml(&self, image: &str) -> String {
        let mut s = String::new();
        let _ = writeln!(s, "image: {image}");
        let _ = writeln!(s, "resolution: {}", self.resolution);
        let _ = writeln!(s, "origin: [{}, {}, 0.0]", self.origin[0], self.origin[1]);
        s.push_str("negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\nmode: trinary\n");
        s
    }

    /// Writes `stem.pgm` and `stem.yaml` into `dir`.
    pub fn write_map_server(&self, dir: &Path, stem: &str) -> io::Result<()> {
        let mut pgm = io::BufWriter::new(std::fs::File::create(dir.join(format!("{stem}.pgm")))?);
        self.write_pgm(&mut pgm)?;
        pgm.into_inner().map_err(io::IntoInnerError::into_error)?;
        std::fs::write(
            dir.join(format!("{stem}.yaml")),
            self.to_yaml(&format!("{stem}.pgm")),
        )
    }

    /// Number of cells with occupancy ≥ 65.
    pub fn occupied_count(&self) -> usize {
        self.cells.iter().filter(|&&v| v >= 65).count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pgm_rows_run_top_down_and_cells_map_to_points() {
        let mut g = OccupancyGrid::new(0.5, [-1.0, 2.0], 3, 2);
        g.cells.fill(0);
        g.set(0, 0, 100); // bottom-left
        let pgm = g.to_pgm();
        let header_end = pgm.len() - 6;
        // Bottom row is written last: its first pixel is black.
        assert_eq!(&pgm[header_end..], &[254, 254, 254, 0, 254, 254]);
        assert_eq!(g.cell_of(-0.9, 2.1), Some((0, 0)));
        assert_eq!(g.cell_of(0.49, 2.99), Some((2, 1)));
        assert_eq!(g.cell_of(0.51, 2.0), None);
        assert_eq!(g.cell_center(1, 1), [-0.25, 2.75]);
        assert!(g.to_yaml("m.pgm").contains("origin: [-1, 2, 0.0]"));
    }

    /// The cell of a point is that of the floor of its grid coordinates, edges, signed zeros,
    /// NaN and infinities included: points just below a cell's edge, on it, and off the grid
    /// on every side.
    #[test]
    fn cells_are_the_floor_of_grid_coordinates() {
        let g = OccupancyGrid::new(0.05, [-1.3, 2.7], 40, 30);
        let by_floor = |x: f64, y: f64| {
            let i = ((x - g.origin[0]) / g.resolution).floor();
            let j = ((y - g.origin[1]) / g.resolution).floor();
            (i >= 0.0 && j >= 0.0 && (i as usize) < g.width && (j as usize) < g.height)
                .then_some((i as usize, j as usize))
        };
        let mut values = vec![f64::NAN, f64::INFINITY, f64::NEG_INFINITY, -0.0, 0.0, 1e300];
        for k in -60..=60 {
            let edge = k as f64 * 0.05;
            values.extend([edge, edge + 1e-12, edge - 1e-12, edge + 0.025]);
        }
        let (mut inside, mut outside) = (0, 0);
        for &a in &values {
            for &b in &values {
                let (x, y) = (g.origin[0] + a, g.origin[1] + b);
                let got = g.cell_of(x, y);
                assert_eq!(got, by_floor(x, y), "({x}, {y})");
                if got.is_some() {
                    inside += 1;
                } else {
                    outside += 1;
                }
            }
        }
        assert!(inside > 1000 && outside > 1000, "{inside} {outside}");
    }
}
