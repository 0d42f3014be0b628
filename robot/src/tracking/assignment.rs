//! Optimal one-to-one assignment with a gate: the pairs of rows and columns of least total
//! cost, where a row may stay unassigned at the price of the gate. Solved by Kuhn–Munkres (the
//! `pathfinding` crate) on costs scaled to integers.

/// The assignment of rows to columns that minimises the sum of `costs[r][c]` over assigned
/// pairs plus `gate` for every row left alone; only pairs of cost at most `gate` are assigned.
/// Costs are compared to 0.1 mm (they are scaled by 10⁴ to integers). Returns `(row, column)`
/// pairs in row order.
pub fn assign(costs: &[Vec<f64>], gate: f64) -> Vec<(usize, usize)> {
    let rows = costs.len();
    let cols = costs.first().map_or(0, Vec::len);
    if rows == 0 || cols == 0 || !(gate.is_finite() && gate >= 0.0) {
        return Vec::new();
    }
    const SCALE: f64 = 1e4;
    // Larger than any sum of admissible costs, so never chosen over a row's own dummy.
    let forbidden = ((gate * SCALE).round() as i64 + 1) * (rows as i64 + 1);
    // Columns: the real ones, then one dummy per row (its own "left alone" at the gate's price).
    let mut flat = Vec::with_capacity(rows * (cols + rows));
    for (r, row) in costs.iter().enumerate() {
        for c in 0..cols {
            let v = row.get(c).copied().unwrap_or(f64::INFINITY);
            flat.push(if v.is_finite() && v <= gate {
                (v * SCALE).round() as i64
            } else {
                forbidden
            });
        }
        for d in 0..rows {
            flat.push(if d == r {
                (gate * SCALE).round() as i64
            } else {
                forbidden
            });
        }
    }
    let m = pathfinding::matrix::Matrix::from_vec(rows, cols + rows, flat)
        .expect("the matrix has rows × (cols + rows) entries");
    let (_, by_row) = pathfinding::kuhn_munkres::kuhn_munkres_min(&m);
    by_row
        .into_iter()
        .enumerate()
        .filter(|&(r, c)| c < cols && costs[r][c] <= gate)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cheapest_total_wins_over_the_greedy_choice() {
        // Greedy would take (0, 0) at 1 and leave row 1 with 10; optimal pairs cross: 2 + 2.
        let costs = vec![vec![1.0, 2.0], vec![2.0, 10.0]];
        assert_eq!(assign(&costs, 20.0), vec![(0, 1), (1, 0)]);
    }

    #[test]
    fn pairs_beyond_the_gate_are_left_alone() {
        let costs = vec![vec![0.3, 5.0], vec![5.0, 0.9]];
        assert_eq!(assign(&costs, 0.75), vec![(0, 0)]);
        // More rows than columns, and none at all.
        let costs = vec![vec![0.2], vec![0.1], vec![0.5]];
        assert_eq!(assign(&costs, 1.0), vec![(1, 0)]);
        assert!(assign(&[], 1.0).is_empty());
        // Leaving a row alone costs the gate: both assigned (0.5 + 0.45 = 0.95) beats row 0
        // taking its cheaper column and row 1 left alone (0.45 + 0.6).
        let costs = vec![vec![0.45, 0.5], vec![0.45, 2.0]];
        assert_eq!(assign(&costs, 0.6), vec![(0, 1), (1, 0)]);
    }
}
