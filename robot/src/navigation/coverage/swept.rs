//! The floor the robot's footprint swept by its own pose estimate, and the gaps that left in
//! what its route promised (issue 47's final pass over the driven footprint).
//!
//! The route promises the floor a disc of [`ROBOT_RADIUS`] sweeps along it. The robot marks
//! the floor its disc swept at each pose it believes it had ([`Swept::add`], segments between
//! poses swept whole). What the route promised and the record lacks, grouped by
//! 8-adjacency, are the gaps; those of less than [`super::second_pass::SecondPassConfig::min_floor_gap`]
//! are left (the slivers between lanes that pose noise opens and closes). Each gap is then
//! covered by stops ([`stops`]): reachable cells chosen greedily, each taking the gap's cells
//! within a disc a little smaller than the robot's (so that a stop still sweeps them when the
//! robot arrives a few centimetres off), until every gap cell any stop can take is taken.

use super::{Field, ROBOT_RADIUS};
use crate::geometry::grid::cells_within;

/// The robot's record of the floor its footprint swept, on a coverage [`Field`]'s grid.
#[derive(Debug, Clone)]
pub struct Swept {
    /// Cells the route sweeps driven exactly.
    planned: Vec<bool>,
    /// Cells the footprint swept at the poses the robot believed.
    swept: Vec<bool>,
    last: Option<[f64; 2]>,
}

/// Spacing of the discs swept along a segment, m.
const STEP: f64 = 0.02;
/// A step of the estimate longer than this between two control ticks is a jump, m (the Create
/// drives at most 0.5 m/s; control ticks are 0.1 s or less apart).
pub const JUMP: f64 = 0.5;

/// Three lanes 0.3 m apart along y = 1.0, 1.3, 1.6 (x from 1 to 5 m), and the same driven
/// with the middle lane 12 cm low: between y = 1.35 and 1.43 no disc of the drive reaches.
#[cfg(test)]
pub(crate) fn lanes_driven_off() -> ([[f64; 2]; 6], [[f64; 2]; 6]) {
    let lanes = |middle: f64| {
        [
            [1.0, 1.0],
            [5.0, 1.0],
            [5.0, middle],
            [1.0, middle],
            [1.0, 1.6],
            [5.0, 1.6],
        ]
    };
    (lanes(1.3), lanes(1.18))
}

/// Drives `swept` along the polyline `points`, adding a position every 5 cm (as the control
/// ticks would).
#[cfg(test)]
pub(crate) fn drive(swept: &mut Swept, field: &Field, points: &[[f64; 2]]) {
    for w in points.windows(2) {
        let n = ((w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]) / 0.05)
            .ceil()
            .max(1.0) as usize;
        for k in 0..=n {
            let t = k as f64 / n as f64;
            swept.add(
                field,
                [
                    w[0][0] + t * (w[1][0] - w[0][0]),
                    w[0][1] + t * (w[1][1] - w[0][1]),
                ],
            );
        }
    }
}

impl Swept {
    /// Nothing swept yet; the promise is what `route` sweeps on `field`'s free cells.
    pub fn new(field: &Field, route: &[[f64; 2]]) -> Swept {
        let n = field.grid.width * field.grid.height;
        let mut s = Swept {
            planned: vec![false; n],
            swept: vec![false; n],
            last: None,
        };
        let mut planned = std::mem::take(&mut s.planned);
        for w in route.windows(2) {
            sweep_segment(field, w[0], w[1], &mut planned);
        }
        if let [only] = route {
            sweep_segment(field, *only, *only, &mut planned);
        }
        // Only floor: a disc that reaches past a wall's edge promises no wall.
        for (k, p) in planned.iter_mut().enumerate() {
            *p &= field.distance[k] > 0.0;
        }
        s.planned = planned;
        s
    }

    /// Replaces the promise with what `route` sweeps, keeping the record of what was swept
    /// (the lanes replanned once the localisation settled).
    pub fn promise(&mut self, field: &Field, route: &[[f64; 2]]) {
        self.planned = Swept::new(field, route).planned;
    }

    /// Sweeps the footprint from the last position added to `p` (map frame, m). It is called
    /// at the control rate, a few centimetres apart; a step of more than [`JUMP`] is the
    /// estimate jumping (a relocalisation), not a drive, and sweeps only `p`.
    pub fn add(&mut self, field: &Field, p: [f64; 2]) {
        let from = self.last.unwrap_or(p);
        // A jump (the estimate relocalised) is not a drive.
        let from = if (p[0] - from[0]).hypot(p[1] - from[1]) > JUMP {
            p
        } else {
            from
        };
        sweep_segment(field, from, p, &mut self.swept);
        self.last = Some(p);
    }

    /// The share of the promised floor swept by the robot's own record (1 with no promise).
    pub fn share(&self) -> f64 {
        let total = self.planned.iter().filter(|p| **p).count();
        if total == 0 {
            return 1.0;
        }
        let got = (0..self.planned.len())
            .filter(|&k| self.planned[k] && self.swept[k])
            .count();
        got as f64 / total as f64
    }

    /// The promised floor not swept, in 8-connected groups of at least `min_area` m².
    pub fn gaps(&self, field: &Field, min_area: f64) -> Vec<Vec<usize>> {
        let g = &field.grid;
        let (w, h) = (g.width, g.height);
        let missing: Vec<bool> = (0..w * h)
            .map(|k| self.planned[k] && !self.swept[k])
            .collect();
        let cell_area = g.resolution * g.resolution;
        super::groups_8(w, h, &missing)
            .into_iter()
            .filter(|cells| cells.len() as f64 * cell_area >= min_area)
            .collect()
    }
}

/// Marks the cells of a disc of [`ROBOT_RADIUS`] swept from `a` to `b`.
fn sweep_segment(field: &Field, a: [f64; 2], b: [f64; 2], out: &mut [bool]) {
    let g = &field.grid;
    let n = ((b[0] - a[0]).hypot(b[1] - a[1]) / STEP).ceil().max(1.0) as usize;
    for k in 0..=n {
        let t = k as f64 / n as f64;
        let c = [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])];
        for (i, j) in cells_within(g, c, ROBOT_RADIUS) {
            out[j * g.width + i] = true;
        }
    }
}

/// Stops that sweep a gap's `cells`: reachable cells, each the one that takes the most of the
/// cells not yet taken within `ROBOT_RADIUS − margin` (ties to the first in scan order), until
/// no reachable cell takes any. Gap cells no reachable cell comes near are left.
///
/// Greedy set cover, with each candidate's count of cells left kept up to date as cells are
/// taken, so a room-sized gap costs its cells times the cells of a disc, not their square.
pub fn stops(field: &Field, cells: &[usize], margin: f64) -> Vec<[f64; 2]> {
    let g = &field.grid;
    let w = g.width;
    let reach = (ROBOT_RADIUS - margin).max(g.resolution);
    let centre = |k: usize| g.cell_center(k % w, k / w);
    // Which gap cells each candidate (a reachable cell within reach of one) takes, and which
    // candidates take each gap cell (the disc is symmetric).
    let mut takes: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
    for (n, &k) in cells.iter().enumerate() {
        for (i, j) in cells_within(g, centre(k), reach) {
            let c = j * w + i;
            if field.reachable[c] {
                takes.entry(c).or_default().push(n);
            }
        }
    }
    let candidates: Vec<(usize, Vec<usize>)> = takes.into_iter().collect();
    let mut taken_by: Vec<Vec<usize>> = vec![Vec::new(); cells.len()];
    for (a, (_, gap)) in candidates.iter().enumerate() {
        for &n in gap {
            taken_by[n].push(a);
        }
    }
    let mut count: Vec<usize> = candidates.iter().map(|(_, gap)| gap.len()).collect();
    let mut taken = vec![false; cells.len()];
    let mut out = Vec::new();
    // The first candidate with the most cells left, while one takes any.
    let first_best = |count: &[usize]| {
        (0..count.len())
            .filter(|&a| count[a] > 0)
            .fold(None, |best: Option<usize>, a| match best {
                Some(b) if count[b] >= count[a] => best,
                _ => Some(a),
            })
    };
    while let Some(best) = first_best(&count) {
        for &n in &candidates[best].1 {
            if !taken[n] {
                taken[n] = true;
                for &a in &taken_by[n] {
                    count[a] -= 1;
                }
            }
        }
        out.push(centre(candidates[best].0));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 6 × 4 m room at 5 cm. Lanes 0.3 m apart along y = 1.0, 1.3, 1.6 promise a band of
    /// floor 0.94 m wide; driven with the middle lane 12 cm off towards the first, they leave
    /// a strip along the third lane's near edge unswept, which is found as one gap, and the
    /// stops that cover it lie on reachable cells and sweep it whole.
    #[test]
    fn a_lane_driven_off_leaves_a_gap_that_the_stops_sweep() {
        let g = crate::geometry::grid::walled(120, 80);
        let field = Field::new(&g, 0.2, [1.0, 1.0]).unwrap();
        let (route, off) = lanes_driven_off();
        let mut swept = Swept::new(&field, &route);
        // Driven exactly, the record keeps the promise.
        let mut exact = swept.clone();
        drive(&mut exact, &field, &route);
        assert_eq!(exact.share(), 1.0);
        assert!(exact.gaps(&field, 0.0).is_empty());
        // The middle lane 12 cm low: between y = 1.35 and 1.43 no disc reaches.
        drive(&mut swept, &field, &off);
        assert!(swept.share() < 1.0);
        let gaps = swept.gaps(&field, 0.04);
        assert_eq!(
            gaps.len(),
            1,
            "{:?}",
            gaps.iter().map(|g| g.len()).collect::<Vec<_>>()
        );
        // Less than the whole promise: an area of the order of the strip (4 m × 5–10 cm).
        let area = gaps[0].len() as f64 * 0.05 * 0.05;
        assert!((0.15..0.5).contains(&area), "{area}");
        let stops = stops(&field, &gaps[0], 0.03);
        assert!(!stops.is_empty());
        for s in &stops {
            assert!(field.reachable_at(*s));
        }
        // Sweeping from each stop takes the whole gap.
        let w = field.grid.width;
        for &k in &gaps[0] {
            let c = field.grid.cell_center(k % w, k / w);
            assert!(
                stops
                    .iter()
                    .any(|s| (s[0] - c[0]).hypot(s[1] - c[1]) <= ROBOT_RADIUS),
                "{c:?}"
            );
        }
        // A gap smaller than the least area asked for is left.
        assert!(swept.gaps(&field, area + 0.01).is_empty());
    }

    /// A jump of the estimate (a relocalisation) sweeps nothing between the two poses.
    #[test]
    fn a_jump_of_the_estimate_is_not_swept() {
        let g = crate::geometry::grid::walled(120, 80);
        let field = Field::new(&g, 0.2, [1.0, 1.0]).unwrap();
        let mut swept = Swept::new(&field, &[[1.0, 1.0], [5.0, 1.0]]);
        swept.add(&field, [1.0, 1.0]);
        swept.add(&field, [5.0, 1.0]);
        // Only the two discs at the ends: far from the whole lane.
        assert!(swept.share() < 0.3, "{}", swept.share());
    }
}
