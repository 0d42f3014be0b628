//! Seed 000's data-collection route (Ozaki 2012, §3.3; written for futago from the digest).
//!
//! 1. **Distances** to the walls for every free cell (an exact Euclidean transform where the
//!    thesis used a k-d tree of the occupied pixels).
//! 2. **Bands**: the free space is cut where the distance to the walls is `wall_distance`
//!    (60 cm) and every `lane_spacing` (60 cm) further in; the cut lines are traced as closed
//!    loops (iso-lines) and nodes A are put on them every `node_spacing` (the thesis: where
//!    60 cm grid lines cross them).
//! 3. **Centre lines** of corridors narrower than `narrow_width` (1.2 m): cells nearly
//!    equidistant from two walls (ridges of the distance with a flat crest, which leaves out
//!    the bisectors of corners, as the thesis's test against the 10 nearest obstacle points
//!    does), traced into chains that carry nodes B.
//! 4. **Relations**: nodes next to each other on a loop or chain are *adjacent*; other nodes
//!    within `reach` (a square around the node) joined by a clear line `2 × clearance` thick
//!    are *reachable*.
//! 5. **Route** (§3.3.3): from the node nearest the robot, once round its loop; every node on
//!    the route with an unexplored reachable node is a candidate, and the nearest candidate's
//!    loop is inserted there as a sub-loop, until no candidate is left. A centre line is
//!    driven to its end and back (the thesis's excursion R″ into a dead end); a loop reached
//!    at its far end is inserted there by the same rule (R″ then R‴, then R″ back).
//! 6. The whole route again in **reverse**, to see what the first lap hid.
//!
//! Nodes C (where a centre line meets a band) are not made explicitly: the reachable relation
//! joins a centre line's end to the loop it meets, which is what they were for.

use super::{Field, NEIGHBOURS_8};
use crate::geometry::contour::{iso_loops, loop_length, resample};
use serde::{Deserialize, Serialize};

/// Seed 000's route parameters (`coverage.seed000.*`).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct Seed000Config {
    /// Distance of the first loop from the walls, m (seed 000: about 60 cm, set by trial).
    pub wall_distance: f64,
    /// Distance between further loops in wide areas, m (seed 000: 60 cm).
    pub lane_spacing: f64,
    /// Corridors up to this wide are driven along their centre line, m (seed 000: 120 cm).
    pub narrow_width: f64,
    /// Spacing of nodes along loops and centre lines, m (seed 000: 60 cm grid lines).
    pub node_spacing: f64,
    /// Half side of the square in which reachable nodes are looked for, m (seed 000: a
    /// rectangle, its size not stated).
    pub reach: f64,
    /// Loops shorter than this are dropped (slivers at a band's crest), m.
    pub min_loop: f64,
    /// A ridge cell's distance may change by at most this much per metre along the ridge
    /// (0 on a corridor's centre line, 0.5–0.7 on the bisector of a room's corner).
    pub ridge_slope: f64,
    /// Drive the whole route again in reverse (seed 000: yes).
    pub reverse_lap: bool,
}

impl Default for Seed000Config {
    fn default() -> Self {
        Seed000Config {
            wall_distance: 0.6,
            lane_spacing: 0.6,
            narrow_width: 1.2,
            node_spacing: 0.6,
            reach: 1.5,
            min_loop: 1.2,
            ridge_slope: 0.3,
            reverse_lap: true,
        }
    }
}

impl Seed000Config {
    pub fn validate(&self, key: &str, clearance: f64) -> Result<(), (String, String)> {
        crate::config::check_ranges(
            key,
            &[
                ("wall_distance", self.wall_distance, 0.05, 10.0),
                ("lane_spacing", self.lane_spacing, 0.05, 10.0),
                ("narrow_width", self.narrow_width, 0.1, 20.0),
                ("node_spacing", self.node_spacing, 0.05, 10.0),
                ("reach", self.reach, 0.05, 20.0),
                ("min_loop", self.min_loop, 0.0, 1000.0),
                ("ridge_slope", self.ridge_slope, 0.0, 1.0),
            ],
        )?;
        if self.wall_distance < clearance {
            return Err((
                format!("{key}.wall_distance"),
                format!("expected at least coverage.clearance ({clearance} m)"),
            ));
        }
        Ok(())
    }
}

/// A loop (closed) or a centre line (open) of nodes.
struct Chain {
    nodes: Vec<usize>,
    closed: bool,
}

/// Seed 000's route from `start` over `field` (the points the robot drives through, from
/// `start`; segments are checked and repaired by the caller).
pub fn plan(field: &Field, c: &Seed000Config, start: [f64; 2]) -> Result<Vec<[f64; 2]>, String> {
    let mut nodes: Vec<[f64; 2]> = Vec::new();
    let mut chain_of: Vec<usize> = Vec::new();
    let mut chains: Vec<Chain> = Vec::new();
    let mut add_chain = |points: Vec<[f64; 2]>, closed: bool| {
        let id = chains.len();
        let first = nodes.len();
        for p in &points {
            nodes.push(*p);
            chain_of.push(id);
        }
        chains.push(Chain {
            nodes: (first..nodes.len()).collect(),
            closed,
        });
    };
    // Step 2: the bands' loops, at the wall distance and every lane spacing further in.
    let g = &field.grid;
    let origin = g.cell_center(0, 0);
    let max = field
        .distance
        .iter()
        .zip(&field.reachable)
        .filter(|(_, r)| **r)
        .map(|(d, _)| *d)
        .fold(0.0, f64::max);
    let mut level = c.wall_distance;
    while level <= max {
        for lp in iso_loops(
            &field.distance,
            g.width,
            g.height,
            origin,
            g.resolution,
            level,
        ) {
            if loop_length(&lp) < c.min_loop || !lp.iter().any(|p| field.reachable_at(*p)) {
                continue;
            }
            let points = resample(&lp, c.node_spacing, true);
            if points.len() >= 2 {
                add_chain(points, true);
            }
        }
        level += c.lane_spacing;
    }
    // Step 3: centre lines of narrow corridors.
    for line in centre_lines(field, c) {
        add_chain(resample(&line, c.node_spacing, false), false);
    }
    if nodes.is_empty() {
        return Err("the map has no free space wide enough for a coverage route".into());
    }
    // Step 4: the reachable relation (adjacency is the order within a chain).
    let reachable = reachable_pairs(field, &nodes, &chain_of, &chains, c.reach);
    // Step 5: the route.
    let first = (0..nodes.len())
        .filter(|&k| field.clear(start, nodes[k], super::ROBOT_RADIUS))
        .chain(0..nodes.len())
        .min_by(|&a, &b| dist(start, nodes[a]).total_cmp(&dist(start, nodes[b])))
        .unwrap_or(0);
    let mut explored = vec![false; chains.len()];
    let mut route = traverse(&chains[chain_of[first]], first);
    explored[chain_of[first]] = true;
    loop {
        // The nearest (route position, unexplored node) pair.
        let mut best: Option<(f64, usize, usize)> = None;
        for (i, &r) in route.iter().enumerate() {
            for &(m, d) in &reachable[r] {
                if explored[chain_of[m]] {
                    continue;
                }
                if best.is_none_or(|(bd, _, _)| d < bd) {
                    best = Some((d, i, m));
                }
            }
        }
        let Some((_, i, m)) = best else { break };
        explored[chain_of[m]] = true;
        let mut sub = traverse(&chains[chain_of[m]], m);
        // Back to where the route left off, unless the next route node is reachable from
        // the sub-loop's end directly.
        let back = route[i];
        let end = *sub.last().unwrap_or(&m);
        let next = route.get(i + 1).copied();
        let direct = next.is_some_and(|n| {
            n != end
                && reachable[end].iter().any(|&(k, _)| k == n)
                && field.clear(nodes[end], nodes[n], field.clearance)
        });
        if !direct {
            sub.push(back);
        }
        route.splice(i + 1..i + 1, sub);
    }
    route.dedup();
    // Step 6: the reverse lap.
    if c.reverse_lap {
        let back: Vec<usize> = route.iter().rev().skip(1).copied().collect();
        route.extend(back);
    }
    let mut points = vec![start];
    points.extend(route.iter().map(|&k| nodes[k]));
    Ok(points)
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (b[0] - a[0]).hypot(b[1] - a[1])
}

/// A chain's nodes in driving order from node `from`: a loop once round and back to it; a
/// line to one end, to the other, and back.
fn traverse(chain: &Chain, from: usize) -> Vec<usize> {
    let n = chain.nodes.len();
    let k = chain.nodes.iter().position(|&x| x == from).unwrap_or(0);
    let mut out = Vec::new();
    if chain.closed {
        out.extend((0..=n).map(|s| chain.nodes[(k + s) % n]));
    } else {
        // To the nearer end first.
        let (a, b): (Vec<usize>, Vec<usize>) = if k <= n - 1 - k {
            ((0..=k).rev().collect(), (1..n).collect())
        } else {
            ((k..n).collect(), (0..n - 1).rev().collect())
        };
        out.extend(a.iter().chain(&b).map(|&s| chain.nodes[s]));
        // Back to the entry node.
        let last = *b.last().unwrap_or(&k);
        if last < k {
            out.extend((last + 1..=k).map(|s| chain.nodes[s]));
        } else if last > k {
            out.extend((k..last).rev().map(|s| chain.nodes[s]));
        }
    }
    out.dedup();
    out
}

/// For each node, the nodes of other chains (and non-adjacent nodes of its own) within the
/// square of half side `reach` joined by a clear thick line, with their distances.
fn reachable_pairs(
    field: &Field,
    nodes: &[[f64; 2]],
    chain_of: &[usize],
    chains: &[Chain],
    reach: f64,
) -> Vec<Vec<(usize, f64)>> {
    let n = nodes.len();
    let mut out = vec![Vec::new(); n];
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| nodes[a][0].total_cmp(&nodes[b][0]).then(a.cmp(&b)));
    let mut position = vec![0; n];
    for chain in chains {
        for (k, &a) in chain.nodes.iter().enumerate() {
            position[a] = k;
        }
    }
    for (ka, &a) in order.iter().enumerate() {
        for &b in &order[ka + 1..] {
            let (p, q) = (nodes[a], nodes[b]);
            if q[0] - p[0] > reach {
                break;
            }
            if (q[1] - p[1]).abs() > reach {
                continue;
            }
            if chain_of[a] == chain_of[b] {
                // Same chain: neighbours along it are adjacent, not reachable.
                let len = chains[chain_of[a]].nodes.len();
                let gap = position[a].abs_diff(position[b]);
                let gap = if chains[chain_of[a]].closed {
                    gap.min(len - gap)
                } else {
                    gap
                };
                if gap <= 1 {
                    continue;
                }
            }
            if field.clear(p, q, field.clearance) {
                let d = dist(p, q);
                out[a].push((b, d));
                out[b].push((a, d));
            }
        }
    }
    out
}

/// The centre lines of the corridors narrower than `narrow_width`: chains of ridge cells,
/// the longest path through each connected set first, then what branches off it.
fn centre_lines(field: &Field, c: &Seed000Config) -> Vec<Vec<[f64; 2]>> {
    let g = &field.grid;
    let (w, h) = (g.width as i64, g.height as i64);
    let d = |i: i64, j: i64| -> f64 {
        if i < 0 || j < 0 || i >= w || j >= h {
            0.0
        } else {
            field.distance[(j * w + i) as usize]
        }
    };
    let res = g.resolution;
    let half = c.narrow_width / 2.0;
    let mut ridge = vec![false; (w * h) as usize];
    for j in 0..h {
        for i in 0..w {
            let k = (j * w + i) as usize;
            let v = field.distance[k];
            if !field.reachable[k] || v >= half {
                continue;
            }
            // A crest across one of four directions, and flat along the perpendicular one.
            for ((a, b), (pa, pb), step) in [
                ((1, 0), (0, 1), 1.0),
                ((0, 1), (1, 0), 1.0),
                ((1, 1), (1, -1), std::f64::consts::SQRT_2),
                ((1, -1), (1, 1), std::f64::consts::SQRT_2),
            ] {
                let (l, r) = (d(i - a, j - b), d(i + a, j + b));
                let crest = v >= l && v >= r && (v > l || v > r);
                if !crest {
                    continue;
                }
                let slope = (d(i + pa, j + pb) - d(i - pa, j - pb)).abs() / (2.0 * step * res);
                if slope <= c.ridge_slope {
                    ridge[k] = true;
                    break;
                }
            }
        }
    }
    let min_cells = (c.node_spacing / res).ceil() as usize;
    let mut lines = Vec::new();
    let neighbours = |k: usize| {
        let (i, j) = ((k as i64) % w, (k as i64) / w);
        NEIGHBOURS_8.iter().filter_map(move |(di, dj)| {
            let (a, b) = (i + di, j + dj);
            (a >= 0 && b >= 0 && a < w && b < h).then_some((b * w + a) as usize)
        })
    };
    // Breadth-first from `s` within the ridge: the farthest cell and the parents.
    let bfs = |ridge: &[bool], s: usize| {
        let mut parent = std::collections::HashMap::new();
        parent.insert(s, s);
        let mut queue = std::collections::VecDeque::from([s]);
        let mut last = s;
        while let Some(k) = queue.pop_front() {
            last = k;
            for m in neighbours(k) {
                if ridge[m] && !parent.contains_key(&m) {
                    parent.insert(m, k);
                    queue.push_back(m);
                }
            }
        }
        (last, parent)
    };
    for s in 0..ridge.len() {
        while ridge[s] {
            let (u, _) = bfs(&ridge, s);
            let (v, parent) = bfs(&ridge, u);
            let mut path = vec![v];
            let mut k = v;
            while k != u {
                k = parent[&k];
                path.push(k);
            }
            if path.len() >= min_cells {
                lines.push(
                    path.iter()
                        .map(|&k| g.cell_center(k % g.width, k / g.width))
                        .collect(),
                );
                // The path and its neighbours leave the ridge; branches stay.
                for &k in &path {
                    ridge[k] = false;
                    for m in neighbours(k) {
                        ridge[m] = false;
                    }
                }
            } else {
                // Too short: the whole connected set goes.
                for k in parent.keys() {
                    ridge[*k] = false;
                }
            }
        }
    }
    lines
}

#[cfg(test)]
mod tests {
    use super::super::tests::floor;
    use super::super::{CoverageConfig, Field, PlannerKind, plan as plan_route};
    use super::*;

    fn near(points: &[[f64; 2]], p: [f64; 2], within: f64) -> bool {
        points.iter().any(|q| dist(*q, p) <= within)
    }

    /// On the test floor the route drives round the room at 0.6 m from the walls and again
    /// further in, round the desk, along the corridor's centre line into the second room and
    /// round it, into the dead end and back, then all of it in reverse; no segment comes
    /// closer than the Create's radius to an obstacle.
    #[test]
    fn the_route_follows_walls_lanes_and_corridors_and_comes_back_reversed() {
        let config = CoverageConfig::default();
        let start = [1.0, 1.0];
        let route = plan_route(&floor(), &config, start).expect("a route");
        assert_eq!(route.planner, PlannerKind::Seed000);
        let p = &route.points;
        let field = Field::new(&floor(), config.clearance, start).unwrap();
        for w in p.windows(2) {
            assert!(field.clear(w[0], w[1], super::super::ROBOT_RADIUS), "{w:?}");
        }
        // The room's first loop: 0.6 m off each wall (walls at 0.2 and 8.2, 0.2 and 6.2).
        for q in [[4.0, 0.8], [4.0, 5.6], [0.8, 3.0], [7.6, 1.5]] {
            assert!(near(p, q, 0.35), "no route point near {q:?}");
        }
        // A lane 0.6 m further in (west of the desk), and round the desk at 0.6 m.
        assert!(near(p, [1.4, 3.0], 0.35) && near(p, [4.0, 1.9], 0.35));
        // The corridor's centre line (y = 3.2), the second room's loop, the dead end.
        assert!(near(p, [9.3, 3.2], 0.2), "corridor centre");
        assert!(near(p, [12.0, 2.3], 0.35), "second room");
        assert!(near(p, [2.0, 8.5], 0.3), "dead end");
        // With the reverse lap the route ends where the first lap began.
        let n = p.len();
        assert!(dist(p[n - 1], p[1]) < 1e-9, "{:?} vs {:?}", p[n - 1], p[1]);
        assert!(route.stats.length_m > 2.0 * 60.0, "{:?}", route.stats);
    }

    #[test]
    fn without_the_reverse_lap_the_route_is_half_as_long() {
        let mut config = CoverageConfig::default();
        let full = plan_route(&floor(), &config, [1.0, 1.0]).unwrap();
        config.seed000.reverse_lap = false;
        let once = plan_route(&floor(), &config, [1.0, 1.0]).unwrap();
        let ratio = full.stats.length_m / once.stats.length_m;
        assert!((ratio - 2.0).abs() < 0.05, "{ratio}");
    }

    #[test]
    fn corner_bisectors_are_not_centre_lines() {
        let field = Field::new(&floor(), 0.2, [1.0, 1.0]).unwrap();
        let lines = centre_lines(&field, &Seed000Config::default());
        // The corridor (y = 3.2, x 8–10.6) and the dead end (x = 2, y 6–9.5) only.
        assert!(!lines.is_empty());
        for line in &lines {
            let mid = line[line.len() / 2];
            let corridor = (mid[1] - 3.2).abs() < 0.1 && mid[0] > 7.5 && mid[0] < 11.0;
            let dead_end = (mid[0] - 2.0).abs() < 0.1 && mid[1] > 5.8;
            assert!(corridor || dead_end, "a centre line at {mid:?}");
        }
    }
}
