//! Path planning on occupancy grids (written for futago).
//!
//! - [`RoadMap`]: seed 000's node graph (Ozaki 2012, §2.5): nodes at fixed intervals along the
//!   boundary of the region within `wall_distance` of obstacles and along the boundary of the
//!   region beyond `open_distance`, every node joined to the nodes within `connect_radius`
//!   that it sees through a corridor as wide as the robot plus a margin (seed 000's "thick
//!   line" of about 40 cm), and A* with the Euclidean heuristic between the nodes nearest the
//!   start and the goal.
//! - [`grid_path`]: Dijkstra over free cells with enough clearance to the nearest cell that a
//!   predicate accepts, for goals that are regions (frontiers) rather than points.

use crate::geometry::grid::{OCCUPIED, obstacle_distance};
use futago_msgs::grid::OccupancyGrid;
use serde::Deserialize;
use std::cmp::Ordering;
use std::collections::BinaryHeap;

/// Road-map parameters (`navigation.planner.*`).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct PlannerConfig {
    /// Nodes line the boundary of the region this close to obstacles, m.
    pub wall_distance: f64,
    /// …and the boundary of the region this far from them, m.
    pub open_distance: f64,
    /// Spacing of nodes along a boundary, m.
    pub node_spacing: f64,
    /// Nodes closer than this are joined when the line between them is clear, m.
    pub connect_radius: f64,
    /// Half-width of the corridor a joining line must keep free, m: the Create's radius
    /// (0.17 m) plus a margin for localisation and tracking error (seed 000 drew a line about
    /// 40 cm thick; 60 cm here: the arc controller cuts corners, and SLAM maps walls thick).
    pub clearance: f64,
}

impl Default for PlannerConfig {
    fn default() -> Self {
        PlannerConfig {
            wall_distance: 0.4,
            open_distance: 0.8,
            node_spacing: 0.3,
            connect_radius: 1.0,
            clearance: 0.3,
        }
    }
}

impl PlannerConfig {
    /// Checks values the planner cannot work with; `(key, expectation)` on error.
    pub fn validate(&self, key: &str) -> Result<(), (String, String)> {
        crate::config::check_ranges(
            key,
            &[
                ("wall_distance", self.wall_distance, 1e-3, 100.0),
                ("open_distance", self.open_distance, 1e-3, 100.0),
                ("node_spacing", self.node_spacing, 1e-3, 100.0),
                ("connect_radius", self.connect_radius, 1e-3, 1000.0),
                ("clearance", self.clearance, 1e-3, 100.0),
            ],
        )?;
        if self.clearance > self.wall_distance || self.wall_distance >= self.open_distance {
            return Err((
                format!("{key}.wall_distance"),
                "expected clearance ≤ wall_distance < open_distance".into(),
            ));
        }
        Ok(())
    }
}

/// Seed 000's node graph over a known map.
#[derive(Debug, Clone)]
pub struct RoadMap {
    config: PlannerConfig,
    grid: OccupancyGrid,
    /// Distance to the nearest obstacle (unknown cells count as obstacles), m.
    distance: Vec<f32>,
    nodes: Vec<[f64; 2]>,
    /// Adjacency: neighbour index and edge length.
    edges: Vec<Vec<(usize, f64)>>,
}

impl RoadMap {
    /// Builds the graph over `grid`.
    pub fn new(grid: OccupancyGrid, config: PlannerConfig) -> RoadMap {
        let distance = obstacle_distance(&grid, |c| !(0..OCCUPIED).contains(&c), 10.0);
        let mut map = RoadMap {
            config,
            grid,
            distance,
            nodes: Vec::new(),
            edges: Vec::new(),
        };
        for band in [config.wall_distance, config.open_distance] {
            map.add_boundary_nodes(band);
        }
        map.connect();
        map
    }

    fn dist(&self, i: usize, j: usize) -> f64 {
        self.distance[j * self.grid.width + i] as f64
    }

    /// Nodes every `node_spacing` along the boundary of {distance ≥ band}: cells inside it
    /// with a 4-neighbour outside, thinned greedily in scan order.
    fn add_boundary_nodes(&mut self, band: f64) {
        let (w, h) = (self.grid.width, self.grid.height);
        let inside = |i: usize, j: usize| self.dist(i, j) >= band;
        let mut candidates = Vec::new();
        for j in 1..h.saturating_sub(1) {
            for i in 1..w.saturating_sub(1) {
                if inside(i, j)
                    && (!inside(i - 1, j)
                        || !inside(i + 1, j)
                        || !inside(i, j - 1)
                        || !inside(i, j + 1))
                {
                    candidates.push(self.grid.cell_center(i, j));
                }
            }
        }
        let spacing = self.config.node_spacing;
        let mut bins: std::collections::HashMap<(i64, i64), Vec<usize>> =
            std::collections::HashMap::new();
        let key = |p: &[f64; 2]| {
            (
                (p[0] / spacing).floor() as i64,
                (p[1] / spacing).floor() as i64,
            )
        };
        for p in candidates {
            let (bx, by) = key(&p);
            let close = (bx - 1..=bx + 1).any(|x| {
                (by - 1..=by + 1).any(|y| {
                    bins.get(&(x, y)).is_some_and(|v| {
                        v.iter().any(|&n| {
                            let q = self.nodes[n];
                            (q[0] - p[0]).hypot(q[1] - p[1]) < spacing
                        })
                    })
                })
            });
            if !close {
                bins.entry((bx, by)).or_default().push(self.nodes.len());
                self.nodes.push(p);
            }
        }
    }

    fn connect(&mut self) {
        let n = self.nodes.len();
        self.edges = vec![Vec::new(); n];
        let r = self.config.connect_radius;
        // Sort by x to limit the pairs tried.
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by(|&a, &b| self.nodes[a][0].total_cmp(&self.nodes[b][0]));
        for (ka, &a) in order.iter().enumerate() {
            for &b in &order[ka + 1..] {
                let (p, q) = (self.nodes[a], self.nodes[b]);
                if q[0] - p[0] > r {
                    break;
                }
                let d = (q[0] - p[0]).hypot(q[1] - p[1]);
                if d <= r && self.line_clear(p, q) {
                    self.edges[a].push((b, d));
                    self.edges[b].push((a, d));
                }
            }
        }
    }

    /// Whether every point of the segment keeps `clearance` from obstacles.
    pub fn line_clear(&self, p: [f64; 2], q: [f64; 2]) -> bool {
        line_clear(&self.grid, &self.distance, p, q, self.config.clearance)
    }

    /// As [`RoadMap::line_clear`], with the clearance lowered to what the robot has at `p`
    /// (down to [`START_CLEARANCE`]), so that a robot or goal close to a wall joins the graph.
    fn line_clear_from(&self, p: [f64; 2], q: [f64; 2]) -> bool {
        let at = distance_at(&self.grid, &self.distance, p);
        let c = self.config.clearance.min(at.max(START_CLEARANCE));
        line_clear(&self.grid, &self.distance, p, q, c)
    }

    /// The map the graph was built on.
    pub fn grid(&self) -> &OccupancyGrid {
        &self.grid
    }

    pub fn nodes(&self) -> &[[f64; 2]] {
        &self.nodes
    }

    pub fn edge_count(&self) -> usize {
        self.edges.iter().map(Vec::len).sum::<usize>() / 2
    }

    /// The node nearest `p` that `p` sees through a clear corridor.
    fn nearest_visible(&self, p: [f64; 2]) -> Option<usize> {
        let mut order: Vec<(f64, usize)> = self
            .nodes
            .iter()
            .enumerate()
            .map(|(k, q)| ((q[0] - p[0]).hypot(q[1] - p[1]), k))
            .collect();
        order.sort_by(|a, b| a.0.total_cmp(&b.0));
        order
            .into_iter()
            .take(50)
            .find(|&(_, k)| self.line_clear_from(p, self.nodes[k]))
            .map(|(_, k)| k)
    }

    /// The shortest path from `start` to `goal` through the graph: `[start, nodes…, goal]`,
    /// or `None` when either end sees no node or the graph does not join them.
    pub fn plan(&self, start: [f64; 2], goal: [f64; 2]) -> Option<Vec<[f64; 2]>> {
        if self.line_clear_from(start, goal)
            && (goal[0] - start[0]).hypot(goal[1] - start[1]) <= self.config.connect_radius
        {
            return Some(vec![start, goal]);
        }
        let s = self.nearest_visible(start)?;
        let g = self.nearest_visible(goal)?;
        let nodes = astar(&self.nodes, &self.edges, s, g)?;
        let mut path = vec![start];
        path.extend(nodes.into_iter().map(|k| self.nodes[k]));
        path.push(goal);
        Some(self.shortcut(path))
    }

    /// Drops the points a clear straight line can skip (from each kept point, the farthest
    /// later point it sees), which removes the zig-zags between boundary nodes.
    fn shortcut(&self, path: Vec<[f64; 2]>) -> Vec<[f64; 2]> {
        let mut out = vec![path[0]];
        let mut k = 0;
        while k + 1 < path.len() {
            let next = (k + 1..path.len())
                .rev()
                .find(|&m| m == k + 1 || self.line_clear_from(path[k], path[m]))
                .unwrap_or(k + 1);
            out.push(path[next]);
            k = next;
        }
        out
    }
}

/// Whether the segment `p`–`q` keeps `clearance` from obstacles in `distance`.
fn line_clear(
    grid: &OccupancyGrid,
    distance: &[f32],
    p: [f64; 2],
    q: [f64; 2],
    clearance: f64,
) -> bool {
    let len = (q[0] - p[0]).hypot(q[1] - p[1]);
    let steps = (len / (grid.resolution * 0.5)).ceil().max(1.0) as usize;
    (0..=steps).all(|k| {
        let t = k as f64 / steps as f64;
        let x = p[0] + t * (q[0] - p[0]);
        let y = p[1] + t * (q[1] - p[1]);
        grid.cell_of(x, y)
            .is_some_and(|(i, j)| distance[j * grid.width + i] as f64 >= clearance)
    })
}

#[derive(PartialEq)]
struct Open(f64, usize);

impl Eq for Open {}

impl PartialOrd for Open {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Open {
    /// Smallest cost first, ties by index (deterministic).
    fn cmp(&self, other: &Self) -> Ordering {
        other
            .0
            .total_cmp(&self.0)
            .then_with(|| other.1.cmp(&self.1))
    }
}

/// A* over a graph with the Euclidean heuristic (admissible: edges are straight lines).
pub fn astar(
    nodes: &[[f64; 2]],
    edges: &[Vec<(usize, f64)>],
    start: usize,
    goal: usize,
) -> Option<Vec<usize>> {
    let h = |k: usize| (nodes[k][0] - nodes[goal][0]).hypot(nodes[k][1] - nodes[goal][1]);
    let mut cost = vec![f64::INFINITY; nodes.len()];
    let mut parent = vec![usize::MAX; nodes.len()];
    let mut open = BinaryHeap::new();
    cost[start] = 0.0;
    open.push(Open(h(start), start));
    while let Some(Open(_, k)) = open.pop() {
        if k == goal {
            let mut path = vec![goal];
            let mut c = goal;
            while c != start {
                c = parent[c];
                path.push(c);
            }
            path.reverse();
            return Some(path);
        }
        for &(m, d) in &edges[k] {
            let c = cost[k] + d;
            if c < cost[m] {
                cost[m] = c;
                parent[m] = k;
                open.push(Open(c + h(m), m));
            }
        }
    }
    None
}

/// Dijkstra over 8-connected cells of `grid` that are known free and at least `clearance`
/// from obstacles (`distance`, m), from the cell of `start` to the nearest cell for which
/// `is_goal` holds (goal cells must be passable too). Within `START_ESCAPE` of the start the
/// rules relax to any cell not occupied and `START_CLEARANCE` from obstacles, so that a
/// robot standing close to a wall, or on cells its laser has not seen, can leave. Returns the path as cell centres, thinned to the corners a straight line cannot
/// skip; `None` when no goal cell is reachable.
pub fn grid_path(
    grid: &OccupancyGrid,
    distance: &[f32],
    clearance: f64,
    start: [f64; 2],
    is_goal: impl Fn(usize, usize) -> bool,
) -> Option<Vec<[f64; 2]>> {
    let w = grid.width;
    let search = dijkstra(grid, distance, clearance, start, is_goal)?;
    let s = search.start;
    let parent = search.parent;
    let goal = search.goal?;
    let mut cells = vec![goal];
    let mut k = goal;
    while k != s {
        k = parent[k];
        cells.push(k);
    }
    cells.reverse();
    let mut points: Vec<[f64; 2]> = cells
        .iter()
        .map(|&k| grid.cell_center(k % w, k / w))
        .collect();
    points[0] = start;
    // Thin: keep a point only where the straight line from the last kept one to the next
    // would come closer to obstacles than the cells it replaces do.
    let mut out = vec![points[0]];
    let mut anchor = 0;
    let mut least = f64::INFINITY;
    for k in 1..points.len() {
        if k + 1 < points.len() {
            least = least.min(distance_at(grid, distance, points[k + 1]));
        }
        let keep = (clearance.max(least - grid.resolution))
            .min(PREFERRED_CLEARANCE)
            .min(distance_at(grid, distance, points[anchor]));
        if k + 1 < points.len() && line_clear(grid, distance, points[anchor], points[k + 1], keep) {
            continue;
        }
        least = f64::INFINITY;
        out.push(points[k]);
        anchor = k;
    }
    Some(out)
}

/// What [`dijkstra`] found: the cost of every cell it settled (path length in cells, each
/// step weighted by the clearance penalty; infinite where it did not reach), each cell's parent,
/// the start's cell and the goal cell it stopped at.
struct Search {
    cost: Vec<f64>,
    parent: Vec<usize>,
    start: usize,
    goal: Option<usize>,
}

/// Whether a path from `start` may pass cell (i, j): a free cell that keeps `clearance` from
/// obstacles, or near the start (within [`START_ESCAPE`]) any cell that is not occupied and
/// keeps [`START_CLEARANCE`].
fn passable(
    grid: &OccupancyGrid,
    distance: &[f32],
    clearance: f64,
    start: [f64; 2],
    i: usize,
    j: usize,
) -> bool {
    let k = j * grid.width + i;
    let c = grid.cells[k];
    let d = distance[k] as f64;
    if (0..OCCUPIED).contains(&c) && d >= clearance {
        return true;
    }
    let p = grid.cell_center(i, j);
    c < OCCUPIED && d >= START_CLEARANCE && (p[0] - start[0]).hypot(p[1] - start[1]) <= START_ESCAPE
}

/// Dijkstra over the cells [`grid_path`] may pass, from `start` until it settles a cell for
/// which `is_goal` holds (or everything it can reach); `None` when `start` is off the grid.
fn dijkstra(
    grid: &OccupancyGrid,
    distance: &[f32],
    clearance: f64,
    start: [f64; 2],
    is_goal: impl Fn(usize, usize) -> bool,
) -> Option<Search> {
    let (w, h) = (grid.width, grid.height);
    let (si, sj) = grid.cell_of(start[0], start[1])?;
    let passable = |i: usize, j: usize| passable(grid, distance, clearance, start, i, j);
    let mut cost = vec![f64::INFINITY; w * h];
    let mut parent = vec![usize::MAX; w * h];
    let mut open = BinaryHeap::new();
    let s = sj * w + si;
    cost[s] = 0.0;
    open.push(Open(0.0, s));
    let mut found = None;
    while let Some(Open(c, k)) = open.pop() {
        if c > cost[k] {
            continue;
        }
        let (i, j) = (k % w, k / w);
        if k != s && is_goal(i, j) {
            found = Some(k);
            break;
        }
        for (di, dj, step) in [
            (-1i64, 0i64, 1.0),
            (1, 0, 1.0),
            (0, -1, 1.0),
            (0, 1, 1.0),
            (-1, -1, std::f64::consts::SQRT_2),
            (1, -1, std::f64::consts::SQRT_2),
            (-1, 1, std::f64::consts::SQRT_2),
            (1, 1, std::f64::consts::SQRT_2),
        ] {
            let (ni, nj) = (i as i64 + di, j as i64 + dj);
            if ni < 0 || nj < 0 || ni >= w as i64 || nj >= h as i64 {
                continue;
            }
            let (ni, nj) = (ni as usize, nj as usize);
            let m = nj * w + ni;
            if !passable(ni, nj) {
                continue;
            }
            // Cells closer to obstacles than `PREFERRED_CLEARANCE` cost more (a costmap's
            // inflation): paths keep to the middle of corridors and doorways, which leaves room
            // for localisation and tracking errors.
            let d = distance[m] as f64;
            let penalty =
                CLEARANCE_PENALTY * ((PREFERRED_CLEARANCE - d) / PREFERRED_CLEARANCE).max(0.0);
            let nc = c + step * (1.0 + penalty);
            if nc < cost[m] {
                cost[m] = nc;
                parent[m] = k;
                open.push(Open(nc, m));
            }
        }
    }
    Some(Search {
        cost,
        parent,
        start: s,
        goal: found,
    })
}

/// The cost of the cheapest path from `start` to every cell of `grid` ([`grid_path`]'s
/// rules and costs: metres, each step weighted up to `1 + CLEARANCE_PENALTY` times near
/// obstacles), row-major; infinite where no path reaches. Empty when `start` is off the grid.
pub fn travel_costs(
    grid: &OccupancyGrid,
    distance: &[f32],
    clearance: f64,
    start: [f64; 2],
) -> Vec<f64> {
    dijkstra(grid, distance, clearance, start, |_, _| false)
        .map(|s| s.cost.into_iter().map(|c| c * grid.resolution).collect())
        .unwrap_or_default()
}

/// Clearance below which [`grid_path`] charges extra for a cell, m, and how much at most
/// (a cell touching an obstacle costs 1 + `CLEARANCE_PENALTY` times its length).
pub const PREFERRED_CLEARANCE: f64 = 0.6;
pub const CLEARANCE_PENALTY: f64 = 3.0;

/// Radius around the start where [`grid_path`] relaxes its rules, m.
pub const START_ESCAPE: f64 = 0.5;
/// Least clearance there, m (below the Create's 0.17 m radius, for localisation error).
pub const START_CLEARANCE: f64 = 0.12;

/// A path from `start` to `goal` over the cells of `grid` that keep `clearance` from its
/// obstacles ([`grid_path`], which lets a start near a wall escape), ending at `goal`; `None`
/// when there is none. Slower than the road map, for when the road map cannot be used: a
/// start it does not join, or obstacles it does not hold.
pub fn grid_route(
    grid: &OccupancyGrid,
    clearance: f64,
    start: [f64; 2],
    goal: [f64; 2],
) -> Option<Vec<[f64; 2]>> {
    let (gi, gj) = grid.cell_of(goal[0], goal[1])?;
    // A goal no path may end at is answered at once: the search would settle every cell it
    // can reach before giving up (a navigator's detour round people asked for a goal under
    // one of their discs every few seconds in `hall-scan3d-random`, 22 ms a time).
    if grid.get(gi, gj) >= OCCUPIED {
        return None;
    }
    let distance = obstacle_distance(grid, |v| v >= OCCUPIED, clearance + 1.0);
    if !passable(grid, &distance, clearance, start, gi, gj) {
        return None;
    }
    let mut path = grid_path(grid, &distance, clearance, start, |i, j| i == gi && j == gj)?;
    // The path ends at the goal cell's centre; the goal itself is where it should end.
    if let Some(last) = path.last_mut() {
        *last = goal;
    }
    Some(path)
}

fn distance_at(grid: &OccupancyGrid, distance: &[f32], p: [f64; 2]) -> f64 {
    grid.cell_of(p[0], p[1])
        .map(|(i, j)| distance[j * grid.width + i] as f64)
        .unwrap_or(0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::geometry::grid::room;

    #[test]
    fn roadmap_path_goes_round_the_wall_and_keeps_clear() {
        let map = RoadMap::new(room(), PlannerConfig::default());
        assert!(map.nodes().len() > 50 && map.edge_count() > map.nodes().len());
        let path = map.plan([2.0, 1.0], [8.0, 1.0]).expect("a path");
        // It must pass the wall's free end (y > 4.5) and every leg must keep clear.
        assert!(path.iter().any(|p| p[1] > 4.5), "{path:?}");
        for w in path.windows(2) {
            assert!(map.line_clear(w[0], w[1]), "{w:?}");
        }
        let len: f64 = path
            .windows(2)
            .map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]))
            .sum();
        // The shortest way round (through the gap's corner at (5, 4.5) plus clearance) is
        // about 2·√(3² + 3.7²) ≈ 9.5 m; the graph's shortcut path is a little longer.
        assert!(len > 9.4 && len < 10.5, "length {len}");
    }

    #[test]
    fn roadmap_refuses_a_goal_inside_a_wall() {
        let map = RoadMap::new(room(), PlannerConfig::default());
        assert!(map.plan([2.0, 1.0], [5.0, 2.0]).is_none());
    }

    #[test]
    fn astar_finds_the_shortest_of_two_routes() {
        let nodes = [[0.0, 0.0], [1.0, 1.0], [1.0, -0.2], [2.0, 0.0]];
        let d = |a: usize, b: usize| {
            let (p, q): ([f64; 2], [f64; 2]) = (nodes[a], nodes[b]);
            (q[0] - p[0]).hypot(q[1] - p[1])
        };
        let mut edges = vec![Vec::new(); 4];
        for (a, b) in [(0, 1), (1, 3), (0, 2), (2, 3)] {
            edges[a].push((b, d(a, b)));
            edges[b].push((a, d(a, b)));
        }
        assert_eq!(astar(&nodes, &edges, 0, 3), Some(vec![0, 2, 3]));
    }

    /// Answering at once for a goal no path may end at (inside a wall, too close to one)
    /// gives what the full search gives: for goals all over the room from a start in the
    /// open, and for every cell round a start beside a wall among unknown cells, where the
    /// start's relaxed rules let a path end closer to the wall and on unknown cells.
    #[test]
    fn grid_route_refuses_at_once_only_goals_the_search_cannot_reach() {
        let mut g = room();
        for j in 14..28 {
            for i in 1..6 {
                g.set(i, j, -1);
            }
        }
        let clearance = 0.18;
        let d = obstacle_distance(&g, |c| c >= OCCUPIED, clearance + 1.0);
        let everywhere = (0..g.height)
            .step_by(7)
            .flat_map(|j| (0..g.width).step_by(9).map(move |i| (i, j)));
        let round_the_start = (12..30).flat_map(|j| (0..10).map(move |i| (i, j)));
        let cases = everywhere
            .map(|c| ([2.0, 1.0], c))
            .chain(round_the_start.map(|c| ([0.14, 1.0], c)));
        let (mut found, mut refused) = (0, 0);
        for (start, (i, j)) in cases {
            let goal = g.cell_center(i, j);
            let full = grid_path(&g, &d, clearance, start, |a, b| a == i && b == j);
            let route = grid_route(&g, clearance, start, goal);
            assert_eq!(
                route.is_some(),
                full.is_some(),
                "from {start:?} to {goal:?}"
            );
            if route.is_some() {
                found += 1;
            } else {
                refused += 1;
            }
        }
        assert!(
            found > 100 && refused > 50,
            "{found} found, {refused} refused"
        );
    }

    #[test]
    fn grid_path_reaches_the_nearest_goal_cell_round_the_wall() {
        let g = room();
        let d = obstacle_distance(&g, |c| c >= OCCUPIED, 10.0);
        // Goal: any cell right of the wall with x > 8 m.
        let path = grid_path(&g, &d, 0.2, [2.0, 1.0], |i, _| i >= 160).expect("a path");
        let end = path.last().unwrap();
        assert!(end[0] >= 8.0 && end[0] < 8.1, "{end:?}");
        assert!(path.iter().any(|p| p[1] > 4.5));
        for w in path.windows(2) {
            assert!(line_clear(&g, &d, w[0], w[1], 0.19), "{w:?}");
        }
        // Nothing reachable: a goal inside the wall.
        assert!(grid_path(&g, &d, 0.2, [2.0, 1.0], |i, j| i == 100 && j == 10).is_none());
    }
}
