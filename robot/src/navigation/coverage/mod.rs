//! Coverage routes over a known 2D map (written for futago): a route that takes the robot's
//! camera past every wall and the robot over the floor.
//!
//! Two planners share the map preparation, the route checks and the figures:
//!
//! - [`seed000`]: seed 000's data-collection route (Ozaki 2012, §3.3): loops at 60 cm from
//!   the walls and every 60 cm further in, the centre lines of corridors up to 1.2 m wide,
//!   sub-loops inserted where they are reachable, then the whole route again in reverse;
//! - [`boustrophedon`]: Choset's boustrophedon cellular decomposition, lanes spaced by a
//!   footprint, cells joined by obstacle-aware paths: the baseline coverage planners people
//!   use (Fields2Cover, Nav2's opennav_coverage, ipa_coverage_planning) are of this kind.
//!
//! Both plan on the map with the user's region limit (virtual walls) and obstacle annotations
//! (rectangles, ellipses) drawn in, as seed 000's §3.3.4 does; both report length, turns and
//! the execution time of ipa_coverage_planning's evaluation (length / v + rotation / ω).
//! No segment of a route comes closer to an obstacle than the Create's radius.

pub mod boustrophedon;
pub mod second_pass;
pub mod seed000;
pub mod swept;

use crate::geometry::grid::{OCCUPIED, squared_edt};
use futago_msgs::grid::OccupancyGrid;
use futago_msgs::wrap_angle;
use serde::{Deserialize, Serialize};

/// Which planner makes the route.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum PlannerKind {
    /// Seed 000's route ([`seed000`]).
    #[default]
    Seed000,
    /// Boustrophedon cellular decomposition ([`boustrophedon`]).
    Boustrophedon,
}

impl PlannerKind {
    pub fn name(self) -> &'static str {
        match self {
            PlannerKind::Seed000 => "seed000",
            PlannerKind::Boustrophedon => "boustrophedon",
        }
    }
}

/// A shape drawn onto the map for route planning only (seed 000 §3.3.4: desks and chairs the
/// 2D map does not show); localisation never sees it.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase", deny_unknown_fields)]
pub enum Annotation {
    /// `[xmin, ymin, xmax, ymax]`, m.
    Rect([f64; 4]),
    /// `[cx, cy, rx, ry]`: centre and semi-axes along x and y, m.
    Ellipse([f64; 4]),
}

/// The execution-time model of ipa_coverage_planning's evaluation (Bormann et al., ICRA
/// 2018): a route takes length / `speed` plus its total rotation / `turn_rate`.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct TimeModel {
    /// m/s (ipa_coverage_planning: 0.3).
    pub speed: f64,
    /// rad/s (ipa_coverage_planning: 0.52).
    pub turn_rate: f64,
}

impl Default for TimeModel {
    fn default() -> Self {
        TimeModel {
            speed: 0.3,
            turn_rate: 0.52,
        }
    }
}

/// Coverage parameters (`coverage.*`).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct CoverageConfig {
    pub planner: PlannerKind,
    /// Least distance from a route segment to an obstacle (the nearest edge of an obstacle
    /// cell), m: the Create's radius (0.17 m) and 3 cm (seed 000 drew a line about 40 cm
    /// thick).
    pub clearance: f64,
    pub seed000: seed000::Seed000Config,
    pub boustrophedon: boustrophedon::BoustrophedonConfig,
    /// A polygon `[[x, y], …]` around the area to cover: its edges are virtual walls and the
    /// route stays inside (seed 000 §3.3.4). Empty: the whole map.
    pub region: Vec<[f64; 2]>,
    /// Obstacles drawn onto the map for planning (seed 000 §3.3.4).
    pub obstacles: Vec<Annotation>,
    pub time_model: TimeModel,
    /// The second pass to the walls the camera missed (`coverage.second_pass.*`).
    pub second_pass: second_pass::SecondPassConfig,
}

impl Default for CoverageConfig {
    fn default() -> Self {
        CoverageConfig {
            planner: PlannerKind::Seed000,
            clearance: 0.2,
            seed000: seed000::Seed000Config::default(),
            boustrophedon: boustrophedon::BoustrophedonConfig::default(),
            region: Vec::new(),
            obstacles: Vec::new(),
            time_model: TimeModel::default(),
            second_pass: second_pass::SecondPassConfig::default(),
        }
    }
}

impl CoverageConfig {
    /// Checks values the planners cannot work with; `(key, expectation)` on error.
    pub fn validate(&self) -> Result<(), (String, String)> {
        crate::config::check_ranges(
            "coverage",
            &[
                ("clearance", self.clearance, 0.05, 2.0),
                ("time_model.speed", self.time_model.speed, 0.01, 5.0),
                (
                    "time_model.turn_rate",
                    self.time_model.turn_rate,
                    0.01,
                    10.0,
                ),
            ],
        )?;
        self.seed000.validate("coverage.seed000", self.clearance)?;
        self.boustrophedon.validate("coverage.boustrophedon")?;
        self.second_pass.validate("coverage.second_pass")?;
        if !self.region.is_empty() && self.region.len() < 3 {
            return Err((
                "coverage.region".into(),
                format!(
                    "expected a polygon of at least 3 points, found {}",
                    self.region.len()
                ),
            ));
        }
        if !self.region.is_empty() {
            crate::control::script::check_points("coverage.region", &self.region)?;
        }
        for (k, a) in self.obstacles.iter().enumerate() {
            let (v, ok) = match a {
                Annotation::Rect(r) => (r, r[0] < r[2] && r[1] < r[3]),
                Annotation::Ellipse(e) => (e, e[2] > 0.0 && e[3] > 0.0),
            };
            if !(ok && v.iter().all(|x| x.is_finite() && x.abs() < 1e4)) {
                return Err((
                    format!("coverage.obstacles[{k}]"),
                    "expected rect = [xmin, ymin, xmax, ymax] with min < max, or ellipse = \
                     [cx, cy, rx, ry] with positive semi-axes, in metres"
                        .into(),
                ));
            }
        }
        Ok(())
    }
}

/// A coverage route and its figures.
#[derive(Debug, Clone, PartialEq)]
pub struct Route {
    pub planner: PlannerKind,
    /// From the start, in the map frame, m.
    pub points: Vec<[f64; 2]>,
    pub stats: RouteStats,
}

/// A route's figures under the time model.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct RouteStats {
    pub length_m: f64,
    /// Total heading change at the route's corners, rad.
    pub rotation_rad: f64,
    /// Corners that turn by more than [`TURN_THRESHOLD`].
    pub turns: usize,
    /// length / v + rotation / ω.
    pub time_s: f64,
    pub points: usize,
}

/// A heading change above this counts as a turn, rad (20°).
pub const TURN_THRESHOLD: f64 = 0.349;

/// The figures of a polyline that starts at heading `heading` (rad; `None`: the first leg's).
pub fn route_stats(points: &[[f64; 2]], heading: Option<f64>, model: &TimeModel) -> RouteStats {
    let mut length = 0.0;
    let mut rotation = 0.0;
    let mut turns = 0;
    let mut last = heading;
    for w in points.windows(2) {
        let (dx, dy) = (w[1][0] - w[0][0], w[1][1] - w[0][1]);
        let len = dx.hypot(dy);
        if len < 1e-9 {
            continue;
        }
        length += len;
        let h = dy.atan2(dx);
        if let Some(prev) = last {
            let turn = wrap_angle(h - prev).abs();
            rotation += turn;
            if turn > TURN_THRESHOLD {
                turns += 1;
            }
        }
        last = Some(h);
    }
    RouteStats {
        length_m: length,
        rotation_rad: rotation,
        turns,
        time_s: length / model.speed + rotation / model.turn_rate,
        points: points.len(),
    }
}

/// Plans a route over `grid` from `start` with the configured planner.
pub fn plan(
    grid: &OccupancyGrid,
    config: &CoverageConfig,
    start: [f64; 2],
) -> Result<Route, String> {
    let field = Field::new(&restricted(grid, config), config.clearance, start)?;
    let points = match config.planner {
        PlannerKind::Seed000 => seed000::plan(&field, &config.seed000, start)?,
        PlannerKind::Boustrophedon => boustrophedon::plan(&field, &config.boustrophedon, start)?,
    };
    let points = field.repair(points)?;
    Ok(Route {
        planner: config.planner,
        stats: route_stats(&points, None, &config.time_model),
        points,
    })
}

/// `grid` with the region's outside and the annotations marked occupied.
pub fn restricted(grid: &OccupancyGrid, config: &CoverageConfig) -> OccupancyGrid {
    let mut g = grid.clone();
    for j in 0..g.height {
        for i in 0..g.width {
            let p = g.cell_center(i, j);
            let outside = !config.region.is_empty() && !inside_polygon(&config.region, p);
            let marked = config.obstacles.iter().any(|a| match *a {
                Annotation::Rect(r) => p[0] >= r[0] && p[0] <= r[2] && p[1] >= r[1] && p[1] <= r[3],
                Annotation::Ellipse(e) => {
                    ((p[0] - e[0]) / e[2]).powi(2) + ((p[1] - e[1]) / e[3]).powi(2) <= 1.0
                }
            });
            if outside || marked {
                g.set(i, j, 100);
            }
        }
    }
    g
}

/// Whether `p` lies inside the polygon (even-odd rule).
pub fn inside_polygon(polygon: &[[f64; 2]], p: [f64; 2]) -> bool {
    let n = polygon.len();
    let mut inside = false;
    for k in 0..n {
        let (a, b) = (polygon[k], polygon[(k + 1) % n]);
        if (a[1] > p[1]) != (b[1] > p[1]) {
            let x = a[0] + (p[1] - a[1]) / (b[1] - a[1]) * (b[0] - a[0]);
            if p[0] < x {
                inside = !inside;
            }
        }
    }
    inside
}

/// The map as the planners see it: exact distances to the nearest obstacle (occupied or
/// unknown) cell and the cells the robot's centre can reach from the start.
pub struct Field {
    pub grid: OccupancyGrid,
    /// Distance from each cell's centre to the nearest obstacle cell's edge, m: the Euclidean
    /// distance between the centres less half a cell (0 on obstacle cells). Measured to the
    /// centres, a clearance would leave the robot half a cell less room than it says, and
    /// less on a coarser map: a route through a 0.35 m gap between two 5 cm specks kept
    /// "0.2 m" from both and left the 0.34 m Create 5 mm a side.
    pub distance: Vec<f64>,
    /// Cells at least `clearance` from obstacles, 8-connected to the start's.
    pub reachable: Vec<bool>,
    pub clearance: f64,
}

/// The least clearance a repaired segment keeps, m: the Create's radius.
pub const ROBOT_RADIUS: f64 = 0.17;

impl Field {
    /// The field of `grid` for a robot at `start` that keeps `clearance`.
    pub fn new(grid: &OccupancyGrid, clearance: f64, start: [f64; 2]) -> Result<Field, String> {
        let (w, h) = (grid.width, grid.height);
        let sites: Vec<bool> = grid
            .cells
            .iter()
            .map(|&c| !(0..OCCUPIED).contains(&c))
            .collect();
        let half = grid.resolution / 2.0;
        let distance: Vec<f64> = squared_edt(&sites, w, h)
            .into_iter()
            .map(|d2| (d2.sqrt() * grid.resolution - half).max(0.0))
            .collect();
        let mut field = Field {
            grid: grid.clone(),
            distance,
            reachable: vec![false; w * h],
            clearance,
        };
        // The reachable cell nearest the start seeds the flood (a start close to a wall).
        let seed = (0..w * h)
            .filter(|&k| field.distance[k] >= clearance)
            .map(|k| {
                let c = grid.cell_center(k % w, k / w);
                ((c[0] - start[0]).hypot(c[1] - start[1]), k)
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .filter(|(d, _)| *d <= 0.5)
            .map(|(_, k)| k)
            .ok_or_else(|| {
                format!(
                    "the start ({:.2}, {:.2}) is not within 0.5 m of a cell {clearance} m clear of \
                     obstacles on the map",
                    start[0], start[1]
                )
            })?;
        field.reachable[seed] = true;
        let (reachable, distance) = (&mut field.reachable, &field.distance);
        flood_8(w, h, seed, |m| {
            let take = !reachable[m] && distance[m] >= clearance;
            reachable[m] |= take;
            take
        });
        Ok(field)
    }

    /// The distance at world point `p` (0 off the map).
    pub fn distance_at(&self, p: [f64; 2]) -> f64 {
        self.grid
            .cell_of(p[0], p[1])
            .map_or(0.0, |(i, j)| self.distance[j * self.grid.width + i])
    }

    /// Whether the cell of `p` is reachable.
    pub fn reachable_at(&self, p: [f64; 2]) -> bool {
        self.grid
            .cell_of(p[0], p[1])
            .is_some_and(|(i, j)| self.reachable[j * self.grid.width + i])
    }

    /// Whether every point of the segment keeps `clearance`.
    pub fn clear(&self, p: [f64; 2], q: [f64; 2], clearance: f64) -> bool {
        let len = (q[0] - p[0]).hypot(q[1] - p[1]);
        let steps = (len / (self.grid.resolution * 0.5)).ceil().max(1.0) as usize;
        (0..=steps).all(|k| {
            let t = k as f64 / steps as f64;
            self.distance_at([p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])]) >= clearance
        })
    }

    /// A path between two points over reachable cells (Dijkstra on the grid), `None` when
    /// there is none.
    pub fn path(&self, a: [f64; 2], b: [f64; 2]) -> Option<Vec<[f64; 2]>> {
        let d: Vec<f32> = self.distance.iter().map(|&x| x as f32).collect();
        let (gi, gj) = self.grid.cell_of(b[0], b[1])?;
        let clearance = self.clearance.min(self.distance_at(b)).max(ROBOT_RADIUS);
        let mut path =
            super::planner::grid_path(&self.grid, &d, clearance, a, |i, j| i == gi && j == gj)?;
        if let Some(last) = path.last_mut() {
            *last = b;
        }
        Some(path)
    }

    /// The route with every segment that comes closer than [`ROBOT_RADIUS`] to an obstacle
    /// replaced by a grid path; an error when some leg cannot be joined at all.
    pub fn repair(&self, points: Vec<[f64; 2]>) -> Result<Vec<[f64; 2]>, String> {
        let mut out: Vec<[f64; 2]> = Vec::with_capacity(points.len());
        for p in points {
            let Some(&last) = out.last() else {
                out.push(p);
                continue;
            };
            if (p[0] - last[0]).hypot(p[1] - last[1]) < 1e-9 {
                continue;
            }
            if self.clear(last, p, ROBOT_RADIUS) {
                out.push(p);
                continue;
            }
            let path = self.path(last, p).ok_or_else(|| {
                format!(
                    "no path from ({:.2}, {:.2}) to ({:.2}, {:.2}) keeps {ROBOT_RADIUS} m from \
                     obstacles",
                    last[0], last[1], p[0], p[1]
                )
            })?;
            out.extend(path.into_iter().skip(1));
        }
        Ok(out)
    }
}

/// The 8-connected groups of the cells of a `w × h` grid where `cells` holds, each in the
/// order [`flood_8`] finds it, groups in the order of their first cell (bottom row first).
pub fn groups_8(w: usize, h: usize, cells: &[bool]) -> Vec<Vec<usize>> {
    let mut taken = vec![false; w * h];
    let mut groups = Vec::new();
    for k0 in 0..w * h {
        if !cells[k0] || taken[k0] {
            continue;
        }
        taken[k0] = true;
        groups.push(flood_8(w, h, k0, |m| {
            let take = cells[m] && !taken[m];
            taken[m] |= take;
            take
        }));
    }
    groups
}

/// The cells 8-connected to `seed` (first) through cells that `take` accepts, in the order
/// found (breadth first). `take` is asked of each neighbour of each cell found and must
/// remember what it took, so that it refuses a cell the second time.
pub fn flood_8(w: usize, h: usize, seed: usize, mut take: impl FnMut(usize) -> bool) -> Vec<usize> {
    let mut cells = vec![seed];
    let mut next = 0;
    while next < cells.len() {
        let k = cells[next];
        next += 1;
        let (i, j) = ((k % w) as i64, (k / w) as i64);
        for (di, dj) in NEIGHBOURS_8 {
            let (a, b) = (i + di, j + dj);
            if a < 0 || b < 0 || a >= w as i64 || b >= h as i64 {
                continue;
            }
            let m = b as usize * w + a as usize;
            if take(m) {
                cells.push(m);
            }
        }
    }
    cells
}

/// The 8 neighbours of a cell.
pub const NEIGHBOURS_8: [(i64, i64); 8] = [
    (-1, 0),
    (1, 0),
    (0, -1),
    (0, 1),
    (-1, -1),
    (1, -1),
    (-1, 1),
    (1, 1),
];

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// An 8 × 6 m room with a 2 m desk in it, a 1 m wide corridor leaving its east wall to a
    /// 3 × 3 m second room, and a 1 m wide dead-end corridor going north: every case of seed
    /// 000's route (loops, lanes, narrow corridors to a room and to a dead end).
    pub fn floor() -> OccupancyGrid {
        let res = 0.05;
        let (w, h) = (280, 200); // 14 × 10 m
        let mut g = OccupancyGrid::new(res, [0.0, 0.0], w, h);
        let free = |x: f64, y: f64| {
            let room = (0.2..8.2).contains(&x) && (0.2..6.2).contains(&y);
            let desk = (3.0..5.0).contains(&x) && (2.5..3.5).contains(&y);
            let corridor = (8.0..10.6).contains(&x) && (2.7..3.7).contains(&y);
            let room2 = (10.5..13.5).contains(&x) && (1.7..4.7).contains(&y);
            let dead_end = (1.5..2.5).contains(&x) && (6.0..9.5).contains(&y);
            (room && !desk) || corridor || room2 || dead_end
        };
        for j in 0..h {
            for i in 0..w {
                let c = g.cell_center(i, j);
                g.set(i, j, if free(c[0], c[1]) { 0 } else { 100 });
            }
        }
        g
    }

    #[test]
    fn the_time_model_adds_length_over_speed_and_rotation_over_turn_rate() {
        // A 2 × 1 m rectangle driven from its corner, facing along the first side: three
        // quarter turns, 6 m.
        let points = [[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0], [0.0, 0.0]];
        let s = route_stats(&points, Some(0.0), &TimeModel::default());
        assert!((s.length_m - 6.0).abs() < 1e-12);
        assert!((s.rotation_rad - 3.0 * std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert_eq!(s.turns, 3);
        let expected = 6.0 / 0.3 + 3.0 * std::f64::consts::FRAC_PI_2 / 0.52;
        assert!((s.time_s - expected).abs() < 1e-9, "{}", s.time_s);
    }

    #[test]
    fn the_region_and_annotations_become_obstacles() {
        let config = CoverageConfig {
            region: vec![[0.0, 0.0], [5.0, 0.0], [5.0, 6.5], [0.0, 6.5]],
            obstacles: vec![Annotation::Ellipse([2.0, 1.5, 0.5, 0.3])],
            ..CoverageConfig::default()
        };
        let g = restricted(&floor(), &config);
        let at = |x: f64, y: f64| {
            let (i, j) = g.cell_of(x, y).unwrap();
            g.get(i, j)
        };
        assert_eq!(at(6.0, 1.0), 100, "outside the region");
        assert_eq!(at(4.0, 1.0), 0, "inside the region, free");
        assert_eq!(at(2.0, 1.5), 100, "in the ellipse");
        assert_eq!(at(2.0, 1.9), 0, "above the ellipse");
    }

    #[test]
    fn clearance_is_kept_from_the_edges_of_obstacle_cells() {
        // Two one-cell specks in open floor whose facing edges are 0.35 m apart (cells of
        // 5 cm: x in [2.0, 2.05) and [2.4, 2.45)), as in the Intel lab's clutter.
        let mut g = crate::geometry::grid::walled(100, 100);
        g.set(40, 50, 100);
        g.set(48, 50, 100);
        let field = Field::new(&g, 0.2, [1.0, 1.0]).expect("field");
        // Beside a speck: its edge is half a cell from the neighbouring cell's centre.
        assert!((field.distance_at([1.975, 2.525]) - 0.025).abs() < 1e-12);
        // The gap's middle (x = 2.225) is 0.175 m from either edge: a Create (0.17 m) passes
        // with 5 mm a side, so a route keeping 0.2 m may not go there; measured between
        // centres the middle was 0.2 m clear.
        assert!((field.distance_at([2.225, 2.525]) - 0.175).abs() < 1e-12);
        assert!(!field.reachable_at([2.225, 2.525]));
        // Round the specks the floor is reachable.
        assert!(field.reachable_at([2.225, 2.9]));
    }

    #[test]
    fn a_start_far_from_free_space_is_refused() {
        let err = Field::new(&floor(), 0.2, [3.5, 3.0])
            .err()
            .expect("refused");
        assert!(err.contains("start"), "{err}");
    }
}
