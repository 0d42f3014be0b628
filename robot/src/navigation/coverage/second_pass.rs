//! The second pass (seed 000's future work, §5): after the route, find the walls the camera
//! has not seen and plan a route that takes the camera to them, and only to them.
//!
//! The robot keeps its own record of what its camera saw, [`WallSight`]: every depth pixel in
//! the camera's valid range, placed on the map by the robot's pose estimate, marks the wall
//! cell it lands on (or the wall cell beside it, for noise and pose error). A wall cell is
//! wanted when it faces free floor and lies within the camera's range of a cell the robot can
//! reach. Wanted cells not yet seen, grouped by adjacency, are the gaps; groups of fewer than
//! [`SecondPassConfig::min_gap`] metres of wall are left (a pillar's corner, a speck of noise).
//! For each gap a viewpoint is chosen among the reachable cells between
//! [`SecondPassConfig::view_min`] and [`SecondPassConfig::view_max`] from it, the one with a
//! clear line of sight to the most of its cells; viewpoints are visited nearest first, each
//! followed by a short step towards its gap, so that the robot ends its approach facing it.
//!
//! The same route sweeps the floor the first one promised and the robot's footprint missed
//! (issue 47's final pass over the driven footprint): the gaps of the robot's own record
//! ([`Swept`], placed by its pose estimate) of at least [`SecondPassConfig::min_floor_gap`]
//! get stops ([`super::swept::stops`]) that join the viewpoints in the nearest-first order.

use super::swept::{Swept, stops};
use super::{Field, NEIGHBOURS_8, ROBOT_RADIUS};
use crate::geometry::grid::OCCUPIED;
use futago_msgs::grid::OccupancyGrid;
use serde::{Deserialize, Serialize};

/// Second-pass parameters (`coverage.second_pass.*`).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct SecondPassConfig {
    /// Drive a second route to the walls the camera missed once the first is done.
    pub enabled: bool,
    /// Nearest distance of a viewpoint from its gap, m (the Kinect's depth is good from
    /// about 1.2 m on, seed 000's lower limit for keyframes).
    pub view_min: f64,
    /// Farthest distance of a viewpoint from its gap, m (within the 3.5 m seed 000 keeps).
    pub view_max: f64,
    /// Least length of wall a gap must have to be visited, m.
    pub min_gap: f64,
    /// The step towards the gap after each viewpoint, m.
    pub approach: f64,
    /// Also sweep the floor the first route promised and the footprint missed.
    pub floor: bool,
    /// Least area of a floor gap to be swept, m²: a 20 cm square. The slivers pose noise
    /// leaves between lanes are smaller; a lane driven a few centimetres off leaves a strip
    /// as long as the lane.
    pub min_floor_gap: f64,
    /// How much nearer than the robot's radius a stop's centre must be to the floor it is to
    /// sweep, m: the robot reaches a stop within the driver's tolerance and its estimate's
    /// error.
    pub floor_margin: f64,
}

impl Default for SecondPassConfig {
    fn default() -> Self {
        SecondPassConfig {
            enabled: false,
            view_min: 1.2,
            view_max: 2.5,
            min_gap: 0.3,
            approach: 0.15,
            floor: true,
            min_floor_gap: 0.04,
            floor_margin: 0.05,
        }
    }
}

impl SecondPassConfig {
    /// Checks the values; `(key, expectation)` on error.
    pub fn validate(&self, prefix: &str) -> Result<(), (String, String)> {
        crate::config::check_ranges(
            prefix,
            &[
                ("view_min", self.view_min, 0.3, 10.0),
                ("view_max", self.view_max, 0.3, 10.0),
                ("min_gap", self.min_gap, 0.0, 100.0),
                ("approach", self.approach, 0.0, 1.0),
                ("min_floor_gap", self.min_floor_gap, 0.0, 100.0),
                ("floor_margin", self.floor_margin, 0.0, ROBOT_RADIUS),
            ],
        )?;
        if self.view_max <= self.view_min {
            return Err((
                format!("{prefix}.view_max"),
                format!("expected more than view_min ({} m)", self.view_min),
            ));
        }
        Ok(())
    }
}

/// The wall cells of a map the robot's camera has seen.
#[derive(Debug, Clone)]
pub struct WallSight {
    grid: OccupancyGrid,
    seen: Vec<bool>,
}

impl WallSight {
    /// Nothing seen yet on `map` (the map the route was planned on).
    pub fn new(map: &OccupancyGrid) -> WallSight {
        WallSight {
            seen: vec![false; map.width * map.height],
            grid: map.clone(),
        }
    }

    fn is_wall(&self, i: i64, j: i64) -> bool {
        i >= 0
            && j >= 0
            && (i as usize) < self.grid.width
            && (j as usize) < self.grid.height
            && self.grid.get(i as usize, j as usize) >= OCCUPIED
    }

    /// Marks the wall cell a point `[x, y]` of the map frame lands on, or the nearest wall
    /// cell among its 8 neighbours (depth noise and pose error of a few centimetres).
    pub fn add_point(&mut self, p: [f64; 2]) {
        let Some((i, j)) = self.grid.cell_of(p[0], p[1]) else {
            return;
        };
        let (i, j) = (i as i64, j as i64);
        let hit = if self.is_wall(i, j) {
            Some((i, j))
        } else {
            let g = &self.grid;
            let dist = |a: i64, b: i64| {
                let c = [
                    g.origin[0] + (a as f64 + 0.5) * g.resolution,
                    g.origin[1] + (b as f64 + 0.5) * g.resolution,
                ];
                (c[0] - p[0]).hypot(c[1] - p[1])
            };
            NEIGHBOURS_8
                .iter()
                .map(|(di, dj)| (i + di, j + dj))
                .filter(|&(a, b)| self.is_wall(a, b))
                .min_by(|x, y| dist(x.0, x.1).total_cmp(&dist(y.0, y.1)))
        };
        if let Some((a, b)) = hit {
            self.seen[b as usize * self.grid.width + a as usize] = true;
        }
    }
}

/// The wall cells to see: occupied cells with a free 4-neighbour, within `view_max` of a
/// reachable cell of `field`.
pub fn wanted_walls(field: &Field, view_max: f64) -> Vec<bool> {
    let g = &field.grid;
    let (w, h) = (g.width, g.height);
    let d2 = crate::geometry::grid::squared_edt(&field.reachable, w, h);
    let limit = (view_max / g.resolution).powi(2);
    (0..w * h)
        .map(|k| {
            let (i, j) = ((k % w) as i64, (k / w) as i64);
            g.cells[k] >= OCCUPIED
                && d2[k] <= limit
                && [(-1, 0), (1, 0), (0, -1), (0, 1)].iter().any(|(di, dj)| {
                    let (a, b) = (i + di, j + dj);
                    a >= 0
                        && b >= 0
                        && (a as usize) < w
                        && (b as usize) < h
                        && (0..OCCUPIED).contains(&g.get(a as usize, b as usize))
                })
        })
        .collect()
}

/// A gap: wanted wall cells not seen, connected.
#[derive(Debug, Clone)]
pub struct Gap {
    pub cells: Vec<usize>,
    /// Where the camera looks at each of its pieces from, and the point it looks at. A piece
    /// is the gap's cells within [`PIECE_RADIUS`] of its first cell.
    pub views: Vec<([f64; 2], [f64; 2])>,
    /// Pieces no reachable cell has in range and in sight.
    pub unseeable: usize,
}

/// Half the width of wall one view takes in, m: the Kinect's 57° field of view spans 2.2 m
/// at 2 m.
pub const PIECE_RADIUS: f64 = 1.0;

/// The second route and what it visits.
#[derive(Debug, Clone)]
pub struct SecondRoute {
    /// From the start, joined by grid paths, map frame, m.
    pub points: Vec<[f64; 2]>,
    /// The walls' gaps (with those no viewpoint was found for).
    pub gaps: Vec<Gap>,
    /// The floor's gaps (cells of the field's grid) and the stops that sweep them.
    pub floor_gaps: Vec<Vec<usize>>,
    pub floor_stops: usize,
}

/// The second route: from `start`, each wall gap's viewpoint with a step towards the gap, and
/// (with `swept` and [`SecondPassConfig::floor`]) the stops over the floor's gaps, nearest
/// first, joined by grid paths.
pub fn plan(
    field: &Field,
    sight: &WallSight,
    swept: Option<&Swept>,
    start: [f64; 2],
    config: &SecondPassConfig,
) -> Result<SecondRoute, String> {
    let g = &field.grid;
    let (w, h) = (g.width, g.height);
    let wanted = wanted_walls(field, config.view_max);
    let missing: Vec<bool> = (0..w * h).map(|k| wanted[k] && !sight.seen[k]).collect();
    // Gaps: 8-connected groups of missing cells, scanned bottom row first.
    let min_cells = (config.min_gap / g.resolution).ceil() as usize;
    let mut gaps: Vec<Gap> = super::groups_8(w, h, &missing)
        .into_iter()
        .map(|cells| Gap {
            cells,
            views: Vec::new(),
            unseeable: 0,
        })
        .collect();
    gaps.retain(|gap| gap.cells.len() >= min_cells.max(1));
    for gap in &mut gaps {
        // Pieces: the cells within PIECE_RADIUS of the first cell not yet taken.
        let mut taken = vec![false; gap.cells.len()];
        for a in 0..gap.cells.len() {
            if taken[a] {
                continue;
            }
            let ca = g.cell_center(gap.cells[a] % w, gap.cells[a] / w);
            let piece: Vec<usize> = (a..gap.cells.len())
                .filter(|&b| {
                    let cb = g.cell_center(gap.cells[b] % w, gap.cells[b] / w);
                    !taken[b] && (ca[0] - cb[0]).hypot(ca[1] - cb[1]) <= PIECE_RADIUS
                })
                .collect();
            for &b in &piece {
                taken[b] = true;
            }
            let cells: Vec<usize> = piece.iter().map(|&b| gap.cells[b]).collect();
            match viewpoint(field, &cells, config) {
                Some(v) => gap.views.push(v),
                None => gap.unseeable += 1,
            }
        }
    }
    // Stops over the floor's gaps: no step after them (`None` for a target).
    let floor_gaps = match swept {
        Some(swept) if config.floor => swept.gaps(field, config.min_floor_gap),
        _ => Vec::new(),
    };
    let floor: Vec<[f64; 2]> = floor_gaps
        .iter()
        .flat_map(|cells| stops(field, cells, config.floor_margin))
        .collect();
    let floor_stops = floor.len();
    // Nearest stop first (straight-line distance; the legs are joined by grid paths).
    let mut todo: Vec<([f64; 2], Option<[f64; 2]>)> = gaps
        .iter()
        .flat_map(|g| g.views.iter().map(|&(v, t)| (v, Some(t))))
        .chain(floor.into_iter().map(|v| (v, None)))
        .collect();
    let mut points = vec![start];
    let mut here = start;
    while !todo.is_empty() {
        let k = (0..todo.len())
            .min_by(|&a, &b| {
                let da = (todo[a].0[0] - here[0]).hypot(todo[a].0[1] - here[1]);
                let db = (todo[b].0[0] - here[0]).hypot(todo[b].0[1] - here[1]);
                da.total_cmp(&db)
            })
            .expect("todo is not empty");
        let (v, target) = todo.swap_remove(k);
        points.push(v);
        let Some(target) = target else {
            here = v;
            continue;
        };
        // A step towards the gap, where it keeps the robot's clearance.
        let (dx, dy) = (target[0] - v[0], target[1] - v[1]);
        let d = dx.hypot(dy).max(1e-9);
        let step = [
            v[0] + dx / d * config.approach,
            v[1] + dy / d * config.approach,
        ];
        if config.approach > 0.0 && field.clear(v, step, ROBOT_RADIUS) {
            points.push(step);
            here = step;
        } else {
            here = v;
        }
    }
    let points = field.repair(points)?;
    Ok(SecondRoute {
        points,
        gaps,
        floor_gaps,
        floor_stops,
    })
}

/// The reachable cell from which the most of `cells` lie within range and in clear sight
/// (cells sampled every few along the gap); ties go to the cell nearest the range's middle,
/// then to the first in scan order.
fn viewpoint(
    field: &Field,
    cells: &[usize],
    config: &SecondPassConfig,
) -> Option<([f64; 2], [f64; 2])> {
    let g = &field.grid;
    let w = g.width;
    let centre = |k: usize| g.cell_center(k % w, k / w);
    // The gap's middle cell (the one nearest its centroid) is what the camera faces.
    let n = cells.len() as f64;
    let mean = cells.iter().fold([0.0, 0.0], |acc, &k| {
        let c = centre(k);
        [acc[0] + c[0] / n, acc[1] + c[1] / n]
    });
    let target = cells.iter().map(|&k| centre(k)).min_by(|a, b| {
        ((a[0] - mean[0]).hypot(a[1] - mean[1])).total_cmp(&(b[0] - mean[0]).hypot(b[1] - mean[1]))
    })?;
    let stride = (cells.len() / 16).max(1);
    let samples: Vec<[f64; 2]> = cells.iter().step_by(stride).map(|&k| centre(k)).collect();
    let r = (config.view_max / g.resolution).ceil() as i64;
    let (ti, tj) = g.cell_of(target[0], target[1])?;
    let mid = 0.5 * (config.view_min + config.view_max);
    let mut best: Option<(usize, f64, [f64; 2])> = None;
    // Candidates every other cell, to bound the work.
    for dj in (-r..=r).step_by(2) {
        for di in (-r..=r).step_by(2) {
            let (i, j) = (ti as i64 + di, tj as i64 + dj);
            if i < 0 || j < 0 || i >= w as i64 || j >= g.height as i64 {
                continue;
            }
            let k = j as usize * w + i as usize;
            if !field.reachable[k] {
                continue;
            }
            let p = centre(k);
            let d = (p[0] - target[0]).hypot(p[1] - target[1]);
            if d < config.view_min || d > config.view_max {
                continue;
            }
            let seen = samples
                .iter()
                .filter(|q| {
                    let dq = (q[0] - p[0]).hypot(q[1] - p[1]);
                    dq >= config.view_min && dq <= config.view_max && sight_line(g, p, **q)
                })
                .count();
            if seen == 0 {
                continue;
            }
            let off = (d - mid).abs();
            if best.is_none_or(|(s, o, _)| seen > s || (seen == s && off < o)) {
                best = Some((seen, off, p));
            }
        }
    }
    best.map(|(_, _, p)| (p, target))
}

/// Whether the straight line from `p` reaches the wall cell of `q` without crossing another
/// occupied or unknown cell (sampled every half cell).
fn sight_line(g: &OccupancyGrid, p: [f64; 2], q: [f64; 2]) -> bool {
    let Some(end) = g.cell_of(q[0], q[1]) else {
        return false;
    };
    let len = (q[0] - p[0]).hypot(q[1] - p[1]);
    let steps = (len / (0.5 * g.resolution)).ceil().max(1.0) as usize;
    for k in 0..steps {
        let t = k as f64 / steps as f64;
        let Some((i, j)) = g.cell_of(p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])) else {
            return false;
        };
        if (i, j) == end {
            return true;
        }
        if !(0..OCCUPIED).contains(&g.get(i, j)) {
            // The cell next to the end (the line grazes the wall at the end's corner).
            return (i as i64 - end.0 as i64).abs() <= 1 && (j as i64 - end.1 as i64).abs() <= 1;
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 6 × 4 m room at 5 cm. The camera saw the whole south and west walls; the second
    /// route visits the rest, and the viewpoint of each gap lies within range, reachable and
    /// in sight of it.
    #[test]
    fn the_second_route_visits_every_unseen_wall_from_within_range() {
        let g = crate::geometry::grid::walled(120, 80);
        let field = Field::new(&g, 0.2, [1.0, 1.0]).unwrap();
        let mut sight = WallSight::new(&g);
        // Points a few centimetres in front of the south and west walls: each marks the wall
        // cell beside it.
        for i in 1..119 {
            sight.add_point([i as f64 * 0.05 + 0.025, 0.06]);
        }
        for j in 1..79 {
            sight.add_point([0.06, j as f64 * 0.05 + 0.025]);
        }
        let config = SecondPassConfig::default();
        let SecondRoute {
            points: route,
            gaps,
            ..
        } = plan(&field, &sight, None, [1.0, 1.0], &config).unwrap();
        // East and north walls form one gap (they meet at the north-east corner), 78 + 118
        // cells: each point marked the wall cell nearest it, not a corner's other wall.
        let sizes: Vec<usize> = gaps.iter().map(|g| g.cells.len()).collect();
        assert_eq!(sizes, [78 + 118]);
        // 10 m of wall in pieces of at most 2 m: at least 5 views, each in range, reachable
        // and passed by the route.
        assert!(
            gaps[0].views.len() >= 5 && gaps[0].unseeable == 0,
            "{:?}",
            gaps[0]
        );
        assert!(route.len() >= 2 && route[0] == [1.0, 1.0]);
        for (v, target) in &gaps[0].views {
            let d = (v[0] - target[0]).hypot(v[1] - target[1]);
            assert!((config.view_min..=config.view_max).contains(&d), "{d}");
            assert!(field.reachable_at(*v));
            assert!(
                route
                    .iter()
                    .any(|p| (p[0] - v[0]).hypot(p[1] - v[1]) < 1e-9)
            );
        }

        // With every wanted wall seen, there is nothing to visit.
        let wanted = wanted_walls(&field, config.view_max);
        let mut all = WallSight::new(&g);
        for (k, want) in wanted.iter().enumerate() {
            if *want {
                all.seen[k] = true;
            }
        }
        let SecondRoute {
            points: route,
            gaps,
            ..
        } = plan(&field, &all, None, [1.0, 1.0], &config).unwrap();
        assert!(gaps.is_empty() && route == vec![[1.0, 1.0]]);
        // The room's inner wall cells: 2·(118 + 78) less the 4 corners, which face no free
        // 4-neighbour.
        assert_eq!(wanted.iter().filter(|w| **w).count(), 2 * (118 + 78));
    }

    /// Every wall seen, but the first route's middle lane driven 12 cm off: the second route
    /// goes to the floor's gap alone, its stops in the order met from the start, and without
    /// `floor` it has nothing to do.
    #[test]
    fn the_second_route_sweeps_the_floor_the_footprint_missed() {
        let g = crate::geometry::grid::walled(120, 80);
        let field = Field::new(&g, 0.2, [1.0, 1.0]).unwrap();
        let config = SecondPassConfig::default();
        let mut sight = WallSight::new(&g);
        for (k, want) in wanted_walls(&field, config.view_max).iter().enumerate() {
            sight.seen[k] = *want;
        }
        let (route, off) = super::super::swept::lanes_driven_off();
        let mut swept = Swept::new(&field, &route);
        super::super::swept::drive(&mut swept, &field, &off);
        let second = plan(&field, &sight, Some(&swept), [5.0, 1.6], &config).unwrap();
        assert!(second.gaps.is_empty());
        assert_eq!(second.floor_gaps.len(), 1);
        assert!(second.floor_stops >= 2, "{}", second.floor_stops);
        // Driven, the second route sweeps the gap.
        let before = swept.clone();
        super::super::swept::drive(&mut swept, &field, &second.points);
        assert!(swept.gaps(&field, config.min_floor_gap).is_empty());
        // Nearest first from the east end: the stops run west, the route does not double back
        // more than a stop's spacing.
        let xs: Vec<f64> = second.points.iter().map(|p| p[0]).collect();
        assert!(xs.windows(2).all(|w| w[1] <= w[0] + 0.3), "{xs:?}");

        let walls_only = SecondPassConfig {
            floor: false,
            ..config
        };
        let second = plan(&field, &sight, Some(&before), [5.0, 1.6], &walls_only).unwrap();
        assert!(second.floor_gaps.is_empty() && second.points == vec![[5.0, 1.6]]);
    }

    /// A wall hidden behind another is not in sight; the wall itself is.
    #[test]
    fn a_sight_line_stops_at_the_first_wall() {
        let mut g = OccupancyGrid::new(0.1, [0.0, 0.0], 30, 5);
        g.cells.fill(0);
        for j in 0..5 {
            g.set(10, j, 100);
            g.set(20, j, 100);
        }
        assert!(sight_line(&g, [0.55, 0.25], [1.05, 0.25]));
        assert!(!sight_line(&g, [0.55, 0.25], [2.05, 0.25]));
    }
}
