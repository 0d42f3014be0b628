//! Next-view planning for a robot that maps by standing and scanning (seed 004 §6; written
//! for futago): where to stand for the next 3D scan, on the 2D grid compressed from the voxel
//! map built so far.
//!
//! Three planners, one interface ([`next_view`]):
//! - `seed`: the seed's evaluation, minimised over candidate positions,
//!   `V = α·v1 + β·v2 + γ·v3` with
//!   - `v1 = 1 / Σ f·h⁴`, over the unknown cells a 360° scan from the candidate would newly
//!     measure (`f = 1`), each weighted by `h(d)`, `d` its distance;
//!   - `v2 = 1 / min g·h²`, over the obstacle cells (`g = 1`): the inverse squared clearance;
//!   - `v3 = l²`, `l` the path length from the last view.
//!
//!   The seed prints `h` but defines only the distance `d`, and says nearer new cells weigh
//!   more, which `h = d` to the fourth power contradicts ([`DistanceWeight`] offers both
//!   readings and a third; the digest, §2.5, lists the inconsistency).
//! - `frontier`: the nearest frontier cell (Yamauchi 1997: a known free cell beside unknown
//!   space, in a frontier at least `frontier_min_length` long) the robot can stand on, the
//!   classic exploration baseline. Frontier cells within `frontier_reach` of a view already
//!   scanned are left out: they stayed frontiers though scanned from there (a pillar's
//!   shadow begins beside it), as exploration's exhausted frontiers are.
//! - `random`: a reachable candidate drawn at random, a floor for the others.
//!
//! All three stand only where a scan would measure at least `min_new` unknown cells, and stop
//! (return `None`) when no reachable candidate would: the same stopping rule, so that they
//! differ only in their choice. What a scan would measure is predicted on the 2D grid: rays
//! every `ray_step` through known free and unknown cells (unknown is assumed open, as
//! next-best-view planners commonly do) up to `range`, stopping at obstacles.

use crate::config::ConfigError;
use crate::cores::map_on_cores_with;
use crate::geometry::grid::{OCCUPIED, clear_distance, obstacle_distance};
use crate::navigation::coverage::inside_polygon;
use crate::navigation::exploration::frontiers;
use crate::navigation::planner::{grid_path, travel_costs};
use futago_msgs::grid::OccupancyGrid;
use rand::Rng;
use serde::{Deserialize, Serialize};

/// Which planner chooses the next view.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum ViewPlanner {
    /// The seed's evaluation `V = α·v1 + β·v2 + γ·v3`.
    #[default]
    Seed,
    /// The nearest candidate next to a frontier.
    Frontier,
    /// A candidate at random.
    Random,
}

/// The seed's undefined distance weight `h(d)` in `v1`, where `d` is a new cell's distance
/// from the candidate (m) and `R` the prediction range.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum DistanceWeight {
    /// `h = 1 − d/R`: nearer cells weigh more, as the seed's text says, and a cell at the
    /// range's end weighs nothing (the LMS200's points thin out with distance).
    #[default]
    Falloff,
    /// `h = 1/d` (`d` at least one cell): nearer cells weigh more, steeply.
    Inverse,
    /// `h = d`, as the formula is printed: farther cells weigh more.
    Distance,
}

/// View-planning parameters (`scan3d.planning.*`).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct ViewPlanningConfig {
    pub planner: ViewPlanner,
    /// Weight of `v1`, the inverse weighted count of new cells. The seed's weights were
    /// found by trial and error and are not given; these put the three terms on one scale:
    /// `v1` runs about 0.005 (a scan into a large unknown area) to 0.05 (a few square metres
    /// nearby), `v2` 0.25 to 4 (2 m to 0.5 m clearance), `v3` 0 to 100 (10 m away), so α
    /// = 1000 spreads `v1` over 5 to 50, as `β·v2` spreads over 0.25 to 4 and `γ·v3` over
    /// 0 to 10.
    pub alpha: f64,
    /// Weight of `v2`, the inverse squared clearance.
    pub beta: f64,
    /// Weight of `v3`, the squared path length from the last view.
    pub gamma: f64,
    /// The distance weight `h` of `v1`.
    pub weight: DistanceWeight,
    /// `h`'s exponent in `v1` (the seed's 4, found by trial and error).
    pub exponent: f64,
    /// How far a scan is predicted to measure, m (the seed's 6 m laser range).
    pub range: f64,
    /// Angle between prediction rays, degrees.
    pub ray_step_deg: f64,
    /// Spacing of the candidate positions, m.
    pub spacing: f64,
    /// Least clearance from obstacles of a candidate, and of the path to it, m.
    pub clearance: f64,
    /// Least new cells a view must be predicted to measure; the planning ends when no
    /// reachable candidate would.
    pub min_new: usize,
    /// Most views in all.
    pub max_views: usize,
    /// The area to map (a polygon, map frame, m; empty: everywhere the robot can reach).
    /// Cells outside it count as obstacles: the robot neither plans there nor counts them.
    pub region: Vec<[f64; 2]>,
    /// Least length of a frontier the `frontier` planner drives to, m.
    pub frontier_min_length: f64,
    /// Frontier cells this near a view already scanned are left out, m.
    pub frontier_reach: f64,
    /// The height band compressed into the 2D grid, m (above the floor, to above the
    /// people).
    pub band: [f64; 2],
}

impl Default for ViewPlanningConfig {
    fn default() -> Self {
        ViewPlanningConfig {
            planner: ViewPlanner::Seed,
            alpha: 1000.0,
            beta: 1.0,
            gamma: 0.1,
            weight: DistanceWeight::Falloff,
            exponent: 4.0,
            range: 6.0,
            ray_step_deg: 0.5,
            spacing: 0.5,
            clearance: 0.4,
            min_new: 100,
            max_views: 30,
            region: Vec::new(),
            frontier_min_length: 0.5,
            frontier_reach: 1.0,
            band: [0.1, 2.0],
        }
    }
}

impl ViewPlanningConfig {
    /// Checks values, naming `PREFIX.KEY`.
    pub fn validate(&self, prefix: &str) -> Result<(), ConfigError> {
        crate::config::check_ranges(
            prefix,
            &[
                ("alpha", self.alpha, 0.0, 1e12),
                ("beta", self.beta, 0.0, 1e12),
                ("gamma", self.gamma, 0.0, 1e12),
                ("exponent", self.exponent, 0.0, 16.0),
                ("range", self.range, 0.1, 100.0),
                ("ray_step_deg", self.ray_step_deg, 0.01, 45.0),
                ("spacing", self.spacing, 0.05, 100.0),
                ("clearance", self.clearance, 0.0, 10.0),
                ("min_new", self.min_new as f64, 1.0, 1e9),
                ("max_views", self.max_views as f64, 1.0, 10_000.0),
                ("frontier_min_length", self.frontier_min_length, 0.0, 100.0),
                ("frontier_reach", self.frontier_reach, 0.0, 100.0),
                ("band[0]", self.band[0], -10.0, 100.0),
                ("band[1]", self.band[1], -10.0, 100.0),
            ],
        )?;
        if self.band[1] <= self.band[0] {
            return Err((
                crate::config::below(prefix, "band"),
                format!(
                    "expected [low, high] with high above low, m; found {:?}",
                    self.band
                ),
            ));
        }
        if !self.region.is_empty() {
            let bad = self
                .region
                .iter()
                .any(|p| !p.iter().all(|c| c.is_finite() && c.abs() <= 1e6));
            if self.region.len() < 3 || bad {
                return Err((
                    crate::config::below(prefix, "region"),
                    format!(
                        "expected a polygon of at least 3 finite points, m; found {:?}",
                        self.region
                    ),
                ));
            }
        }
        Ok(())
    }
}

/// The chosen next view.
#[derive(Debug, Clone, PartialEq)]
pub struct View {
    /// Where to stand (map frame, m).
    pub position: [f64; 2],
    /// The path there from the robot, thinned to its corners.
    pub route: Vec<[f64; 2]>,
    /// Unknown cells a scan there is predicted to measure.
    pub new_cells: usize,
    /// The seed's terms `[v1, v2, v3]` there (whichever planner chose it).
    pub terms: [f64; 3],
}

/// A candidate position's prediction.
struct Candidate {
    cell: usize,
    position: [f64; 2],
    new_cells: usize,
    terms: [f64; 3],
}

/// The next view from `robot` (map frame, m) on `grid` (the 2D grid compressed from the
/// voxel map; −1 unknown, 0 free, 100 occupied), the views scanned so far being `visited`,
/// or `None` when no reachable candidate would measure `min_new` new cells. `rng` draws the
/// `random` planner's choice.
pub fn next_view(
    grid: &OccupancyGrid,
    robot: [f64; 2],
    visited: &[[f64; 2]],
    config: &ViewPlanningConfig,
    rng: &mut impl Rng,
) -> Option<View> {
    let grid = working_grid(grid, robot, config);
    let distance = obstacle_distance(&grid, |c| c >= OCCUPIED, config.range);
    let run = free_run(&grid, config);
    let travel = travel_costs(&grid, &distance, config.clearance, robot);
    if travel.is_empty() {
        return None;
    }
    let res = grid.resolution;
    let step = ((config.spacing / res).round() as usize).max(1);
    // The seed's terms of a candidate at cell `k`.
    let terms = |k: usize, position: [f64; 2], new_cells: usize, weighted: f64| {
        let clearance = (distance[k] as f64).max(res);
        Candidate {
            cell: k,
            position,
            new_cells,
            terms: [
                if weighted > 0.0 {
                    1.0 / weighted
                } else {
                    f64::INFINITY
                },
                1.0 / (clearance * clearance),
                travel[k] * travel[k],
            ],
        }
    };
    let frontier_choice;
    // The cells a candidate may stand on, one every `step`.
    let standing: Vec<(usize, usize)> = (0..grid.height)
        .step_by(step)
        .flat_map(|j| (0..grid.width).step_by(step).map(move |i| (i, j)))
        .filter(|&(i, j)| {
            let k = j * grid.width + i;
            (0..OCCUPIED).contains(&grid.cells[k])
                && (distance[k] as f64) >= config.clearance
                && travel[k].is_finite()
        })
        .collect();
    // Each one's prediction on the cores (most of the planning's time), each thread with its
    // own marks of the cells counted: a prediction is the same whichever thread makes it.
    let cells = grid.width * grid.height;
    let predicted = map_on_cores_with(
        &standing,
        PREDICT_SERIAL_BELOW,
        || (vec![0u32; cells], 0u32),
        |(seen, stamp), &(i, j)| {
            let position = grid.cell_center(i, j);
            *stamp += 1;
            (
                position,
                predict(&grid, &run, position, config, seen, *stamp),
            )
        },
    );
    let mut candidates = Vec::new();
    for (&(i, j), (position, (new_cells, weighted))) in standing.iter().zip(predicted) {
        if new_cells >= config.min_new {
            candidates.push(terms(j * grid.width + i, position, new_cells, weighted));
        }
    }
    let mut seen = vec![0u32; cells];
    let mut stamp = 0u32;
    if candidates.is_empty() {
        return None;
    }
    let chosen = match config.planner {
        ViewPlanner::Seed => {
            let v = |c: &Candidate| {
                config.alpha * c.terms[0] + config.beta * c.terms[1] + config.gamma * c.terms[2]
            };
            candidates
                .iter()
                .min_by(|a, b| v(a).total_cmp(&v(b)).then(a.cell.cmp(&b.cell)))?
        }
        ViewPlanner::Frontier => {
            let min_cells = (config.frontier_min_length / res).ceil().max(1.0) as usize;
            let (label, _) = frontiers(&grid, min_cells);
            // Frontier cells the robot may stand on, not beside a view already scanned,
            // nearest first.
            let mut cells: Vec<usize> = (0..label.len())
                .filter(|&k| {
                    let c = grid.cell_center(k % grid.width, k / grid.width);
                    label[k] != u32::MAX
                        && (distance[k] as f64) >= config.clearance
                        && travel[k].is_finite()
                        && !visited
                            .iter()
                            .any(|v| (v[0] - c[0]).hypot(v[1] - c[1]) <= config.frontier_reach)
                })
                .collect();
            cells.sort_by(|&a, &b| travel[a].total_cmp(&travel[b]).then(a.cmp(&b)));
            frontier_choice = cells.into_iter().find_map(|k| {
                let position = grid.cell_center(k % grid.width, k / grid.width);
                stamp += 1;
                let (new_cells, weighted) =
                    predict(&grid, &run, position, config, &mut seen, stamp);
                (new_cells >= config.min_new).then(|| terms(k, position, new_cells, weighted))
            });
            frontier_choice.as_ref()?
        }
        ViewPlanner::Random => &candidates[rng.random_range(0..candidates.len())],
    };
    let goal = chosen.cell;
    let mut route = grid_path(&grid, &distance, config.clearance, robot, |i, j| {
        j * grid.width + i == goal
    })?;
    if let Some(last) = route.last_mut() {
        *last = chosen.position;
    }
    Some(View {
        position: chosen.position,
        route,
        new_cells: chosen.new_cells,
        terms: chosen.terms,
    })
}

/// `grid` grown by the prediction range on every side (unknown there), so that unknown space
/// beyond what the map has reached is counted, with the cells outside the region made
/// obstacles. The robot's own cell is kept passable.
fn working_grid(
    grid: &OccupancyGrid,
    robot: [f64; 2],
    config: &ViewPlanningConfig,
) -> OccupancyGrid {
    let res = grid.resolution;
    let pad = (config.range / res).ceil() as usize + 1;
    // The robot may stand off the grid (nothing known around it yet).
    let (ri, rj) = (
        ((robot[0] - grid.origin[0]) / res).floor() as i64,
        ((robot[1] - grid.origin[1]) / res).floor() as i64,
    );
    let lo_i = (-(pad as i64)).min(ri - pad as i64);
    let lo_j = (-(pad as i64)).min(rj - pad as i64);
    let hi_i = (grid.width as i64 + pad as i64).max(ri + pad as i64);
    let hi_j = (grid.height as i64 + pad as i64).max(rj + pad as i64);
    let (w, h) = ((hi_i - lo_i) as usize, (hi_j - lo_j) as usize);
    let origin = [
        grid.origin[0] + lo_i as f64 * res,
        grid.origin[1] + lo_j as f64 * res,
    ];
    let mut out = OccupancyGrid::new(res, origin, w, h);
    out.cells.fill(-1);
    for j in 0..grid.height {
        for i in 0..grid.width {
            let (oi, oj) = ((i as i64 - lo_i) as usize, (j as i64 - lo_j) as usize);
            out.set(oi, oj, grid.get(i, j));
        }
    }
    if !config.region.is_empty() {
        for j in 0..h {
            for i in 0..w {
                if !inside_polygon(&config.region, out.cell_center(i, j)) {
                    out.set(i, j, 100);
                }
            }
        }
    }
    out
}

/// For each cell of `grid`, how many of [`predict`]'s half-cell steps a ray may advance from
/// any point in it: the points passed over all lie in known free cells, which count nothing
/// and stop nothing. Those points lie within `(n - 1) / 2` cells of the point, so any `n`
/// with that less than the cell's [`clear_distance`] to the unknown and occupied cells is
/// safe (a thousandth of a cell is kept in hand against rounding). A prediction's rays then
/// cross open floor in a few steps, and visit every point that matters, so it counts what
/// visiting every point does.
fn free_run(grid: &OccupancyGrid, config: &ViewPlanningConfig) -> Vec<f32> {
    let longest = (config.range / (0.5 * grid.resolution)).ceil() + 1.0;
    clear_distance(grid, |c| !(0..OCCUPIED).contains(&c), false)
        .into_iter()
        .map(|clear| ((2.0 * clear - 1e-3).max(0.0).floor() + 1.0).min(longest) as f32)
        .collect()
}

/// The unknown cells a 360° scan from `at` would measure on `grid`, and their weighted sum
/// `Σ h(d)^exponent`. `seen` marks cells counted at `stamp` (one count per cell).
fn predict(
    grid: &OccupancyGrid,
    run: &[f32],
    at: [f64; 2],
    config: &ViewPlanningConfig,
    seen: &mut [u32],
    stamp: u32,
) -> (usize, f64) {
    let res = grid.resolution;
    let rays = (360.0 / config.ray_step_deg).round().max(1.0) as usize;
    let steps = (config.range / (0.5 * res)).ceil() as usize;
    let (mut count, mut sum) = (0usize, 0.0);
    // A ray's steps form a chain (a point, its cell, the cell's skip, the next point), each
    // waiting on the last one's division and loads. `RAY_LANES` rays advance side by side, a
    // step of each in turn, so that their chains overlap (issue 48), and note the unknown
    // cells they cross (the cell and the step it was met at); the notes are then counted ray
    // by ray in order, so that each cell is counted at the step of the first ray to meet it,
    // as one ray after another would count it.
    let mut notes: [Vec<(usize, usize)>; RAY_LANES] = Default::default();
    for first in (0..rays).step_by(RAY_LANES) {
        let mut lanes = [None; RAY_LANES];
        for (l, lane) in lanes.iter_mut().enumerate() {
            let r = first + l;
            if r < rays {
                let a = r as f64 * std::f64::consts::TAU / rays as f64;
                *lane = Some((a.cos() * 0.5 * res, a.sin() * 0.5 * res, 1usize));
            }
            notes[l].clear();
        }
        let mut live = lanes.iter().flatten().count();
        while live > 0 {
            for (lane, notes) in lanes.iter_mut().zip(notes.iter_mut()) {
                let Some((dx, dy, s)) = lane else {
                    continue;
                };
                let cell = if *s <= steps {
                    grid.cell_of(at[0] + *dx * *s as f64, at[1] + *dy * *s as f64)
                } else {
                    None
                };
                let Some((i, j)) = cell else {
                    *lane = None;
                    live -= 1;
                    continue;
                };
                let k = j * grid.width + i;
                let c = grid.cells[k];
                let here = *s;
                *s += (run[k] as usize).max(1);
                if c >= OCCUPIED {
                    *lane = None;
                    live -= 1;
                } else if c < 0 {
                    notes.push((k, here));
                }
            }
        }
        for &(k, here) in notes.iter().flatten() {
            if seen[k] != stamp {
                seen[k] = stamp;
                let d = (here as f64 * 0.5 * res).max(res);
                let h = match config.weight {
                    DistanceWeight::Falloff => (1.0 - d / config.range).max(0.0),
                    DistanceWeight::Inverse => 1.0 / d,
                    DistanceWeight::Distance => d,
                };
                count += 1;
                sum += h.powf(config.exponent);
            }
        }
    }
    (count, sum)
}

/// Rays [`predict`] advances side by side.
const RAY_LANES: usize = 4;

/// Candidates fewer than this are predicted on this thread: a prediction casts a ray every
/// `ray_step_deg` (720 by default), and a handful of them is not worth starting a thread
/// (all of a plan's, on the cores, took `futago bench scan3d`'s view planning from
/// 0.21–0.26 s to 0.14–0.15 s).
const PREDICT_SERIAL_BELOW: usize = 8;

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    /// A 20 × 6 m room at 0.1 m, walls all round, everything unknown but a 4 m free bay at
    /// its west end where the robot has scanned, with a 0.6 m pillar in the bay's east half.
    fn room() -> OccupancyGrid {
        let mut g = OccupancyGrid::new(0.1, [0.0, 0.0], 200, 60);
        g.cells.fill(-1);
        for j in 0..60 {
            for i in 0..200 {
                let wall = i == 0 || j == 0 || i == 199 || j == 59;
                if wall && i < 40 {
                    g.set(i, j, 100);
                } else if i < 40 {
                    g.set(i, j, 0);
                }
            }
        }
        g
    }

    fn config(planner: ViewPlanner) -> ViewPlanningConfig {
        ViewPlanningConfig {
            planner,
            ..ViewPlanningConfig::default()
        }
    }

    /// A 160 × 120 grid of free floor at 5 cm with 40 random square blobs of unknown,
    /// occupied and in-between cells.
    fn blob_grid(rng: &mut rand_chacha::ChaCha8Rng) -> OccupancyGrid {
        let mut g = OccupancyGrid::new(0.05, [-1.0, 0.5], 160, 120);
        g.cells.fill(0);
        for _ in 0..40 {
            let (ci, cj, r) = (
                rng.random_range(0..160i64),
                rng.random_range(0..120i64),
                rng.random_range(1..8i64),
            );
            let v = [-1i8, 100, 60, 30][rng.random_range(0..4)];
            for j in (cj - r).max(0)..(cj + r).min(120) {
                for i in (ci - r).max(0)..(ci + r).min(160) {
                    g.set(i as usize, j as usize, v);
                }
            }
        }
        g
    }

    /// One ray after another, each to its end: the definition [`predict`]'s rays side by
    /// side must reproduce to the bit.
    fn predict_one_ray_at_a_time(
        grid: &OccupancyGrid,
        run: &[f32],
        at: [f64; 2],
        config: &ViewPlanningConfig,
        seen: &mut [u32],
        stamp: u32,
    ) -> (usize, f64) {
        let res = grid.resolution;
        let rays = (360.0 / config.ray_step_deg).round().max(1.0) as usize;
        let steps = (config.range / (0.5 * res)).ceil() as usize;
        let (mut count, mut sum) = (0usize, 0.0);
        for r in 0..rays {
            let a = r as f64 * std::f64::consts::TAU / rays as f64;
            let (dx, dy) = (a.cos() * 0.5 * res, a.sin() * 0.5 * res);
            let mut s = 1;
            while s <= steps {
                let (x, y) = (at[0] + dx * s as f64, at[1] + dy * s as f64);
                let Some((i, j)) = grid.cell_of(x, y) else {
                    break;
                };
                let k = j * grid.width + i;
                let c = grid.cells[k];
                let here = s;
                s += (run[k] as usize).max(1);
                if c >= OCCUPIED {
                    break;
                }
                if c < 0 && seen[k] != stamp {
                    seen[k] = stamp;
                    let d = (here as f64 * 0.5 * res).max(res);
                    let h = match config.weight {
                        DistanceWeight::Falloff => (1.0 - d / config.range).max(0.0),
                        DistanceWeight::Inverse => 1.0 / d,
                        DistanceWeight::Distance => d,
                    };
                    count += 1;
                    sum += h.powf(config.exponent);
                }
            }
        }
        (count, sum)
    }

    /// Rays side by side count the cells and sum the weights one ray at a time does, to the
    /// bit: on grids of random blobs, from every free cell of a coarse lattice, with and
    /// without skipping, for ray counts that do and do not fill the last group of lanes.
    #[test]
    fn rays_side_by_side_predict_what_one_at_a_time_does() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(48);
        for step in [1.0, 7.0, 45.0, 360.0] {
            let c = ViewPlanningConfig {
                ray_step_deg: step,
                ..config(ViewPlanner::Seed)
            };
            let g = blob_grid(&mut rng);
            let run = free_run(&g, &c);
            let none = vec![0f32; run.len()];
            let (mut a, mut b) = (vec![0; g.width * g.height], vec![0; g.width * g.height]);
            let mut stamp = 0;
            let mut counted = 0;
            for j in (0..120).step_by(11) {
                for i in (0..160).step_by(11) {
                    if g.get(i, j) != 0 {
                        continue;
                    }
                    let at = g.cell_center(i, j);
                    for r in [&run, &none] {
                        stamp += 1;
                        let lanes = predict(&g, r, at, &c, &mut a, stamp);
                        let one = predict_one_ray_at_a_time(&g, r, at, &c, &mut b, stamp);
                        assert_eq!(lanes.0, one.0, "from {at:?}, {step}°");
                        assert_eq!(lanes.1.to_bits(), one.1.to_bits(), "from {at:?}, {step}°");
                        counted += lanes.0;
                    }
                }
            }
            assert!(counted > 0, "{step}°: nothing unknown counted");
        }
    }

    /// Skipping open floor counts what visiting every point counts: on grids of random
    /// blobs of free, unknown and occupied cells, from anywhere in every free cell of a
    /// coarse lattice.
    #[test]
    fn skipping_open_floor_predicts_the_same() {
        let c = config(ViewPlanner::Seed);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for _ in 0..4 {
            let g = blob_grid(&mut rng);
            let run = free_run(&g, &c);
            assert!(run.iter().any(|&r| r >= 4.0), "nothing to skip");
            let none = vec![0f32; run.len()];
            let mut seen = vec![0; g.width * g.height];
            let mut stamp = 0;
            for j in (0..120).step_by(7) {
                for i in (0..160).step_by(7) {
                    if g.get(i, j) != 0 {
                        continue;
                    }
                    // Anywhere in the cell: the field holds for every point in it.
                    let centre = g.cell_center(i, j);
                    let at = [
                        centre[0] + rng.random_range(-0.5..0.5) * g.resolution,
                        centre[1] + rng.random_range(-0.5..0.5) * g.resolution,
                    ];
                    stamp += 2;
                    let fast = predict(&g, &run, at, &c, &mut seen, stamp);
                    let slow = predict(&g, &none, at, &c, &mut seen, stamp + 1);
                    assert_eq!(fast, slow, "from {at:?}");
                }
            }
        }
    }

    #[test]
    fn a_scan_is_predicted_to_measure_the_unknown_it_can_see() {
        let g = room();
        let c = config(ViewPlanner::Seed);
        let mut seen = vec![0; g.width * g.height];
        // From the bay's middle, 2 m from the unknown's edge: rays through the free bay reach
        // the unknown at x ≥ 4 m up to 6 m away; the walls at y = 0 and 6 m stop them. Each
        // unknown cell is counted once.
        let (n, w) = predict(&g, &free_run(&g, &c), [2.0, 3.0], &c, &mut seen, 1);
        // The unknown within range: x from 4 to 8 m, y over the grid's 6 m, cut by the 6 m
        // circle, about 21.5 m² (2,150 cells); the grid's edge stops the rays.
        assert!(n > 1900 && n < 2400, "{n} cells");
        assert!(w > 0.0);
        // A candidate with nothing unknown in range measures nothing.
        let mut small = room();
        for j in 0..60 {
            for i in 40..200 {
                small.set(i, j, if i == 40 { 100 } else { 0 });
            }
        }
        let (n0, w0) = predict(&small, &free_run(&small, &c), [2.0, 3.0], &c, &mut seen, 2);
        assert_eq!((n0, w0), (0, 0.0));
        // Nearer weighs more under the falloff and the inverse, less under the literal
        // reading.
        let near = predict(&g, &free_run(&g, &c), [3.5, 3.0], &c, &mut seen, 3);
        let far = predict(&g, &free_run(&g, &c), [0.8, 3.0], &c, &mut seen, 4);
        assert!(near.1 > far.1);
        let lit = ViewPlanningConfig {
            weight: DistanceWeight::Distance,
            ..c.clone()
        };
        let near_l = predict(&g, &free_run(&g, &lit), [3.5, 3.0], &lit, &mut seen, 5);
        let far_l = predict(&g, &free_run(&g, &lit), [0.8, 3.0], &lit, &mut seen, 6);
        assert!(near_l.0 > far_l.0, "nearer sees more cells");
        let mean_h4 = |x: (usize, f64)| x.1 / x.0 as f64;
        assert!(mean_h4(near) > mean_h4(far));
        assert!(mean_h4(near_l) < mean_h4(far_l));
    }

    #[test]
    fn the_seed_planner_moves_towards_the_unknown_and_keeps_clear_of_walls() {
        let g = room();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let v = next_view(&g, [1.0, 3.0], &[], &config(ViewPlanner::Seed), &mut rng).unwrap();
        // Towards the unknown east, inside the known bay (candidates stand on known free
        // cells), clear of the walls.
        assert!(v.position[0] > 2.5, "{v:?}");
        assert!(v.position[0] < 4.0);
        assert!(v.position[1] > 0.5 && v.position[1] < 5.5, "{v:?}");
        assert!(v.new_cells >= 100);
        assert_eq!(v.route.first(), Some(&[1.0, 3.0]));
        assert_eq!(v.route.last(), Some(&v.position));
        // With only clearance weighed, it stands in the middle of the bay's width.
        let clear = ViewPlanningConfig {
            alpha: 0.0,
            gamma: 0.0,
            ..config(ViewPlanner::Seed)
        };
        let v = next_view(&g, [1.0, 3.0], &[], &clear, &mut rng).unwrap();
        assert!((v.position[1] - 3.0).abs() < 0.3, "{v:?}");
        // With only travel weighed, it stays as near as a candidate allows.
        let lazy = ViewPlanningConfig {
            alpha: 0.0,
            beta: 0.0,
            ..config(ViewPlanner::Seed)
        };
        let v = next_view(&g, [1.0, 3.0], &[], &lazy, &mut rng).unwrap();
        assert!(
            (v.position[0] - 1.0).hypot(v.position[1] - 3.0) < 0.5,
            "{v:?}"
        );
    }

    #[test]
    fn the_frontier_planner_goes_to_the_nearest_frontier() {
        let g = room();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let v = next_view(
            &g,
            [1.0, 3.0],
            &[],
            &config(ViewPlanner::Frontier),
            &mut rng,
        )
        .unwrap();
        // The bay's east edge (x = 3.95 m, the last free column) is the only frontier; the
        // robot stands on it, straight ahead.
        assert!(v.position[0] >= 2.9 && v.position[0] < 4.0, "{v:?}");
        assert!((v.position[1] - 3.0).abs() < 1.0, "{v:?}");
        // Scanned from (4, 3) already, the frontier within 1 m of it is left out: the view
        // moves along the edge to what is left.
        let again = next_view(
            &g,
            [1.0, 3.0],
            &[[4.0, 3.0]],
            &config(ViewPlanner::Frontier),
            &mut rng,
        )
        .unwrap();
        assert!((again.position[1] - 3.0).abs() >= 0.5, "{again:?}");
    }

    #[test]
    fn planning_ends_when_nothing_new_can_be_seen_and_the_region_bounds_it() {
        let mut g = room();
        for j in 0..60 {
            for i in 40..200 {
                g.set(
                    i,
                    j,
                    if i == 199 || j == 0 || j == 59 {
                        100
                    } else {
                        0
                    },
                );
            }
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        for p in [
            ViewPlanner::Seed,
            ViewPlanner::Frontier,
            ViewPlanner::Random,
        ] {
            assert!(next_view(&g, [1.0, 3.0], &[], &config(p), &mut rng).is_none());
        }
        // The unknown east of x = 4 m lies outside the region: nothing to plan for.
        let bay = ViewPlanningConfig {
            region: vec![[0.0, 0.0], [4.0, 0.0], [4.0, 6.0], [0.0, 6.0]],
            ..config(ViewPlanner::Seed)
        };
        assert!(next_view(&room(), [1.0, 3.0], &[], &bay, &mut rng).is_none());
    }

    #[test]
    fn the_random_planner_is_repeatable_by_seed() {
        let g = room();
        let pick = |seed| {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            next_view(&g, [1.0, 3.0], &[], &config(ViewPlanner::Random), &mut rng)
                .unwrap()
                .position
        };
        assert_eq!(pick(7), pick(7));
        let distinct: std::collections::BTreeSet<[i64; 2]> = (0..8)
            .map(|s| pick(s).map(|c| (c * 10.0).round() as i64))
            .collect();
        assert!(distinct.len() > 2);
    }
}
