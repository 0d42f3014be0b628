//! Iso-lines of a scalar field sampled on a grid (marching squares; written for futago).
//!
//! The coverage planners follow the lines at fixed distances from walls: the iso-lines of a
//! distance transform. Samples lie at the cells' centres; outside the grid the field counts
//! as below every level, so every iso-line closes into a loop. Saddles are resolved by the
//! mean of the square's four samples, as is usual.

use std::collections::HashMap;

/// The closed iso-lines `field = level` of a row-major `w × h` field whose sample `(i, j)`
/// lies at `origin + (i, j) · step` (world units), as loops of points (the last point joins
/// the first; it is not repeated). Loops come in a fixed order: by the first square they
/// cross, in row-major order.
pub fn iso_loops(
    field: &[f64],
    w: usize,
    h: usize,
    origin: [f64; 2],
    step: f64,
    level: f64,
) -> Vec<Vec<[f64; 2]>> {
    // Samples of the padded field: one ring of "below" outside the grid.
    let value = |i: i64, j: i64| -> f64 {
        if i < 0 || j < 0 || i >= w as i64 || j >= h as i64 {
            f64::NEG_INFINITY
        } else {
            field[j as usize * w + i as usize]
        }
    };
    let inside = |i: i64, j: i64| value(i, j) >= level;
    // A crossing point on the edge from sample a to sample b (one in, one out).
    let point = |a: (i64, i64), b: (i64, i64)| -> [f64; 2] {
        let (va, vb) = (value(a.0, a.1), value(b.0, b.1));
        let t = if va.is_finite() && vb.is_finite() && (vb - va).abs() > 1e-12 {
            ((level - va) / (vb - va)).clamp(0.0, 1.0)
        } else {
            // Against the padding outside the grid: half way.
            0.5
        };
        [
            origin[0] + (a.0 as f64 + t * (b.0 - a.0) as f64) * step,
            origin[1] + (a.1 as f64 + t * (b.1 - a.1) as f64) * step,
        ]
    };
    // Edge keys: (i, j, 0) from (i, j) to (i+1, j); (i, j, 1) from (i, j) to (i, j+1).
    type Key = (i64, i64, u8);
    let mut segments: Vec<(Key, Key)> = Vec::new();
    for j in -1..h as i64 {
        for i in -1..w as i64 {
            let bl = inside(i, j);
            let br = inside(i + 1, j);
            let tr = inside(i + 1, j + 1);
            let tl = inside(i, j + 1);
            let case = bl as u8 | (br as u8) << 1 | (tr as u8) << 2 | (tl as u8) << 3;
            let bottom = (i, j, 0);
            let top = (i, j + 1, 0);
            let left = (i, j, 1);
            let right = (i + 1, j, 1);
            let mut push = |a: Key, b: Key| segments.push((a, b));
            match case {
                0 | 15 => {}
                1 | 14 => push(left, bottom),
                2 | 13 => push(bottom, right),
                3 | 12 => push(left, right),
                4 | 11 => push(right, top),
                6 | 9 => push(bottom, top),
                7 | 8 => push(left, top),
                5 | 10 => {
                    let centre = [(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)]
                        .iter()
                        .map(|&(a, b)| value(a, b).max(level - 1e6))
                        .sum::<f64>()
                        / 4.0;
                    // Case 5: bl and tr inside. A centre inside joins them.
                    let joined = centre >= level;
                    match (case, joined) {
                        (5, true) | (10, false) => {
                            push(left, top);
                            push(bottom, right);
                        }
                        _ => {
                            push(left, bottom);
                            push(right, top);
                        }
                    }
                }
                _ => unreachable!("a four-bit case"),
            }
        }
    }
    let mut at: HashMap<Key, Vec<usize>> = HashMap::new();
    for (k, (a, b)) in segments.iter().enumerate() {
        at.entry(*a).or_default().push(k);
        at.entry(*b).or_default().push(k);
    }
    let position = |key: Key| -> [f64; 2] {
        let (i, j, dir) = key;
        if dir == 0 {
            point((i, j), (i + 1, j))
        } else {
            point((i, j), (i, j + 1))
        }
    };
    let mut used = vec![false; segments.len()];
    let mut loops = Vec::new();
    for first in 0..segments.len() {
        if used[first] {
            continue;
        }
        used[first] = true;
        let (start, mut key) = segments[first];
        let mut line = vec![position(start)];
        while key != start {
            line.push(position(key));
            let next = at[&key].iter().copied().find(|&s| !used[s]);
            let Some(s) = next else { break };
            used[s] = true;
            let (a, b) = segments[s];
            key = if a == key { b } else { a };
        }
        loops.push(line);
    }
    loops
}

/// The length of a closed loop.
pub fn loop_length(points: &[[f64; 2]]) -> f64 {
    let n = points.len();
    (0..n)
        .map(|k| {
            let (a, b) = (points[k], points[(k + 1) % n]);
            (b[0] - a[0]).hypot(b[1] - a[1])
        })
        .sum()
}

/// Points every `spacing` along a polyline (closed: back to its first point), starting at
/// its first point; at least one point.
pub fn resample(points: &[[f64; 2]], spacing: f64, closed: bool) -> Vec<[f64; 2]> {
    let Some(&first) = points.first() else {
        return Vec::new();
    };
    let mut out = vec![first];
    let mut carried = 0.0;
    let n = points.len();
    let edges = if closed { n } else { n.saturating_sub(1) };
    for k in 0..edges {
        let (a, b) = (points[k], points[(k + 1) % n]);
        let len = (b[0] - a[0]).hypot(b[1] - a[1]);
        let mut s = spacing - carried;
        while s <= len {
            let t = s / len;
            out.push([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]);
            s += spacing;
        }
        carried = len - (s - spacing);
    }
    if closed {
        // The last point too close to the first (the loop's join) goes.
        if out.len() > 1 {
            let (a, b) = (out[0], out[out.len() - 1]);
            if (b[0] - a[0]).hypot(b[1] - a[1]) < 0.5 * spacing {
                out.pop();
            }
        }
    } else if let Some(&last) = points.last() {
        let end = out[out.len() - 1];
        if (last[0] - end[0]).hypot(last[1] - end[1]) > 0.25 * spacing {
            out.push(last);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The iso-line at radius 1 of the distance from a point is a circle of length 2π; a
    /// field with two peaks gives two loops at a low level joined into one at a lower one.
    #[test]
    fn iso_lines_of_a_cone_are_circles() {
        let (w, h, step) = (100, 80, 0.05);
        let c = [2.5, 2.0];
        let field: Vec<f64> = (0..w * h)
            .map(|k| {
                let (i, j) = ((k % w) as f64 * step, (k / w) as f64 * step);
                2.0 - (i - c[0]).hypot(j - c[1])
            })
            .collect();
        let loops = iso_loops(&field, w, h, [0.0, 0.0], step, 1.0);
        assert_eq!(loops.len(), 1);
        let len = loop_length(&loops[0]);
        assert!((len - 2.0 * std::f64::consts::PI).abs() < 0.01, "{len}");
        for p in &loops[0] {
            let r = (p[0] - c[0]).hypot(p[1] - c[1]);
            assert!((r - 1.0).abs() < 0.005, "{p:?} at {r}");
        }
        // Resampled every 0.5 m: 12 or 13 points 0.5 m apart.
        let nodes = resample(&loops[0], 0.5, true);
        assert!((12..=13).contains(&nodes.len()), "{}", nodes.len());
        for w in nodes.windows(2) {
            let d = (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]);
            assert!(d > 0.45 && d <= 0.5 + 1e-9, "{d}");
        }
    }

    #[test]
    fn two_peaks_make_two_loops_then_one() {
        let (w, h, step) = (120, 60, 0.05);
        let field: Vec<f64> = (0..w * h)
            .map(|k| {
                let (x, y) = ((k % w) as f64 * step, (k / w) as f64 * step);
                let a = 1.5 - (x - 1.5).hypot(y - 1.5);
                let b = 1.5 - (x - 4.5).hypot(y - 1.5);
                a.max(b)
            })
            .collect();
        assert_eq!(iso_loops(&field, w, h, [0.0, 0.0], step, 0.5).len(), 2);
        // Below zero the two disks' outsides meet: one loop (with the grid's edge).
        assert_eq!(iso_loops(&field, w, h, [0.0, 0.0], step, -1.0).len(), 1);
    }
}
