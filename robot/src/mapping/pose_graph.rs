//! 2D pose-graph optimisation (written for futago): nodes are robot poses, edges are measured
//! relative poses with an information matrix, and Levenberg–Marquardt minimises the sum of
//! squared edge errors, with a Huber kernel on the edges that may be wrong (loop closures).
//!
//! The error of an edge from node i to node j measuring `z` is the tangent vector of
//! `z⁻¹ · (xᵢ⁻¹ · xⱼ)` (Grisetti et al., "A tutorial on graph-based SLAM", 2010, §IV). The
//! normal equations are block-sparse (one 3×3 block per node and per edge); they are solved by
//! a sparse Cholesky factorisation (the `faer` crate, fill-reducing AMD ordering, analysed
//! once per optimisation and refactored for each damping), which stays exact where conjugate
//! gradients stall: a building-size loop couples thousands of nodes, and CG needs about as
//! many iterations as the loop has nodes. Where the factorisation fails (a graph that does not
//! constrain some node), conjugate gradients preconditioned with the inverse diagonal blocks
//! take over. The first node is held fixed (gauge).

// 3×3 block algebra reads best with explicit indices.
#![allow(clippy::needless_range_loop)]

use faer::linalg::solvers::Solve;
use faer::sparse::linalg::solvers::{Llt, SymbolicLlt};
use faer::sparse::{SparseColMat, Triplet};
use faer::{Mat, Side};
use futago_msgs::{Pose2, wrap_angle};
use std::collections::HashMap;

/// A measured relative pose between two nodes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Edge {
    pub from: usize,
    pub to: usize,
    /// Pose of `to` in the frame of `from`.
    pub measurement: Pose2,
    /// Information (inverse covariance) of `(x, y, θ)` in the frame of `from`.
    pub information: [[f64; 3]; 3],
    /// Huber threshold on the whitened error (√(eᵀΩe)); `None` for a plain squared loss.
    pub huber: Option<f64>,
}

impl Edge {
    /// An edge with a diagonal information from standard deviations (m, m, rad).
    pub fn with_sigmas(from: usize, to: usize, measurement: Pose2, sigma: [f64; 3]) -> Edge {
        let mut information = [[0.0; 3]; 3];
        for (k, s) in sigma.iter().enumerate() {
            information[k][k] = 1.0 / (s * s);
        }
        Edge {
            from,
            to,
            measurement,
            information,
            huber: None,
        }
    }

    /// The edge's error for the node poses `a` (from) and `b` (to).
    pub fn error(&self, a: &Pose2, b: &Pose2) -> [f64; 3] {
        let d = self.measurement.between(&a.between(b));
        [d.x, d.y, d.theta]
    }

    /// Squared Mahalanobis norm of the error.
    pub fn chi2(&self, a: &Pose2, b: &Pose2) -> f64 {
        let e = self.error(a, b);
        quad(&self.information, &e)
    }
}

fn quad(m: &[[f64; 3]; 3], e: &[f64; 3]) -> f64 {
    (0..3)
        .map(|i| (0..3).map(|j| e[i] * m[i][j] * e[j]).sum::<f64>())
        .sum()
}

/// Optimiser settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OptimizeOptions {
    pub max_iterations: usize,
    /// Stop when an iteration lowers the cost by less than this share.
    pub relative_tolerance: f64,
    pub cg_max_iterations: usize,
    pub cg_tolerance: f64,
}

impl Default for OptimizeOptions {
    fn default() -> Self {
        OptimizeOptions {
            max_iterations: 20,
            relative_tolerance: 1e-5,
            cg_max_iterations: 1000,
            cg_tolerance: 1e-6,
        }
    }
}

/// What one optimisation did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OptimizeReport {
    pub initial_cost: f64,
    pub final_cost: f64,
    pub iterations: usize,
}

/// A pose graph.
#[derive(Debug, Clone, Default)]
pub struct PoseGraph {
    pub nodes: Vec<Pose2>,
    pub edges: Vec<Edge>,
}

type Block = [[f64; 3]; 3];

/// The linearised system: diagonal blocks, upper off-diagonal blocks keyed `(i, j)`, `i < j`,
/// and the gradient.
struct Normal {
    diag: Vec<Block>,
    off: Vec<((usize, usize), Block)>,
    b: Vec<[f64; 3]>,
}

impl PoseGraph {
    /// Robust cost: Σ ρ(eᵀΩe) with ρ the Huber kernel where the edge has one.
    pub fn cost(&self) -> f64 {
        self.edges
            .iter()
            .map(|e| robust(e, e.chi2(&self.nodes[e.from], &self.nodes[e.to])).0)
            .sum()
    }

    /// Removes the robust edges (those with a Huber kernel: loop closures) whose whitened
    /// error √(eᵀΩe) at the current node poses exceeds `threshold`, and returns how many went.
    /// Called after an optimisation: an edge that far from what the other edges agree on is an
    /// outlier, and the Huber kernel only bounds its pull, it does not remove it (a 1 m wrong
    /// loop still bends a chain by 0.45 m in the test below).
    pub fn remove_outliers(&mut self, threshold: f64) -> usize {
        let before = self.edges.len();
        let nodes = &self.nodes;
        self.edges.retain(|e| {
            e.huber.is_none() || e.chi2(&nodes[e.from], &nodes[e.to]).sqrt() <= threshold
        });
        before - self.edges.len()
    }

    /// Minimises the cost over every node but the first; `Err` names a bad edge.
    pub fn optimize(&mut self, options: &OptimizeOptions) -> Result<OptimizeReport, String> {
        let n = self.nodes.len();
        for (k, e) in self.edges.iter().enumerate() {
            if e.from >= n || e.to >= n || e.from == e.to {
                return Err(format!(
                    "edge {k} joins nodes {} and {} of {n}",
                    e.from, e.to
                ));
            }
        }
        let initial_cost = self.cost();
        let mut cost = initial_cost;
        let mut lambda = 1e-4;
        let mut iterations = 0;
        if n < 2 {
            return Ok(OptimizeReport {
                initial_cost,
                final_cost: cost,
                iterations,
            });
        }
        // The sparsity pattern is the graph's: analysed once, on the first linearisation
        // (`Some(None)`: faer refused it, and conjugate gradients solve every step).
        let mut symbolic: Option<Option<SymbolicLlt<usize>>> = None;
        for _ in 0..options.max_iterations {
            iterations += 1;
            let normal = self.linearise();
            let symbolic = symbolic.get_or_insert_with(|| analyse(&normal));
            let mut accepted = false;
            for _ in 0..10 {
                let dx = symbolic
                    .as_ref()
                    .and_then(|sym| solve_direct(&normal, lambda, sym))
                    .unwrap_or_else(|| solve(&normal, lambda, options));
                let saved = self.nodes.clone();
                for (k, d) in dx.iter().enumerate().skip(1) {
                    let p = &mut self.nodes[k];
                    *p = Pose2::new(p.x + d[0], p.y + d[1], wrap_angle(p.theta + d[2]));
                }
                let new_cost = self.cost();
                if new_cost <= cost {
                    let gain = (cost - new_cost) / cost.max(1e-300);
                    cost = new_cost;
                    lambda = (lambda / 10.0).max(1e-9);
                    accepted = true;
                    if gain < options.relative_tolerance {
                        return Ok(OptimizeReport {
                            initial_cost,
                            final_cost: cost,
                            iterations,
                        });
                    }
                    break;
                }
                self.nodes = saved;
                lambda *= 10.0;
            }
            if !accepted {
                break;
            }
        }
        Ok(OptimizeReport {
            initial_cost,
            final_cost: cost,
            iterations,
        })
    }

    fn linearise(&self) -> Normal {
        let n = self.nodes.len();
        let mut diag = vec![[[0.0; 3]; 3]; n];
        let mut b = vec![[0.0; 3]; n];
        let mut off: HashMap<(usize, usize), Block> = HashMap::new();
        for e in &self.edges {
            let (xi, xj) = (&self.nodes[e.from], &self.nodes[e.to]);
            let err = e.error(xi, xj);
            let (_, weight) = robust(e, quad(&e.information, &err));
            // e = [R_zᵀ(R_iᵀ(t_j − t_i) − t_z); θ_j − θ_i − θ_z]
            let (si, ci) = xi.theta.sin_cos();
            let (sz, cz) = e.measurement.theta.sin_cos();
            let dx = xj.x - xi.x;
            let dy = xj.y - xi.y;
            // R_zᵀ R_iᵀ
            let rt = [
                [cz * ci - sz * si, cz * si + sz * ci],
                [-sz * ci - cz * si, -sz * si + cz * ci],
            ];
            // ∂(R_iᵀ d)/∂θ_i = [-s c; -c -s] d
            let dri = [-si * dx + ci * dy, -ci * dx - si * dy];
            let drz = [cz * dri[0] + sz * dri[1], -sz * dri[0] + cz * dri[1]];
            let a: Block = [
                [-rt[0][0], -rt[0][1], drz[0]],
                [-rt[1][0], -rt[1][1], drz[1]],
                [0.0, 0.0, -1.0],
            ];
            let bj: Block = [
                [rt[0][0], rt[0][1], 0.0],
                [rt[1][0], rt[1][1], 0.0],
                [0.0, 0.0, 1.0],
            ];
            let mut om = e.information;
            om.iter_mut().flatten().for_each(|v| *v *= weight);
            let at_om = mul_t(&a, &om);
            let bt_om = mul_t(&bj, &om);
            add(&mut diag[e.from], &mul(&at_om, &a));
            add(&mut diag[e.to], &mul(&bt_om, &bj));
            let ab = mul(&at_om, &bj);
            let (key, block) = if e.from < e.to {
                ((e.from, e.to), ab)
            } else {
                ((e.to, e.from), transpose(&ab))
            };
            add(off.entry(key).or_insert([[0.0; 3]; 3]), &block);
            let ga = mat_vec(&at_om, &err);
            let gb = mat_vec(&bt_om, &err);
            for k in 0..3 {
                b[e.from][k] += ga[k];
                b[e.to][k] += gb[k];
            }
        }
        let mut off: Vec<_> = off.into_iter().collect();
        off.sort_by_key(|(k, _)| *k);
        Normal { diag, off, b }
    }
}

/// `(ρ(s), ρ'(s))` for the squared whitened error `s`.
fn robust(e: &Edge, s: f64) -> (f64, f64) {
    match e.huber {
        Some(k) if s > k * k => (2.0 * k * s.sqrt() - k * k, k / s.sqrt()),
        _ => (s, 1.0),
    }
}

/// The damped normal matrix over nodes 1.. (node 0 is the gauge) as lower-triangle triplets,
/// in an order that depends on the graph alone.
fn triplets(normal: &Normal, lambda: f64) -> Vec<Triplet<usize, usize, f64>> {
    let mut out = Vec::with_capacity(6 * normal.diag.len() + 9 * normal.off.len());
    for (k, d) in normal.diag.iter().enumerate().skip(1) {
        let at = 3 * (k - 1);
        for r in 0..3 {
            for c in 0..=r {
                let damp = if r == c {
                    lambda * d[r][r] + 1e-12
                } else {
                    0.0
                };
                out.push(Triplet::new(at + r, at + c, d[r][c] + damp));
            }
        }
    }
    // Block (i, j), i < j, lies above the diagonal; its transpose (j, i) below it.
    for ((i, j), m) in &normal.off {
        if *i == 0 {
            continue;
        }
        let (ai, aj) = (3 * (i - 1), 3 * (j - 1));
        for r in 0..3 {
            for c in 0..3 {
                out.push(Triplet::new(aj + r, ai + c, m[c][r]));
            }
        }
    }
    out
}

/// The symbolic factorisation of the normal matrix's pattern; `None` for a graph too small or
/// a pattern faer refuses.
fn analyse(normal: &Normal) -> Option<SymbolicLlt<usize>> {
    let dim = 3 * normal.diag.len().checked_sub(1)?;
    if dim == 0 {
        return None;
    }
    let mat = SparseColMat::try_new_from_triplets(dim, dim, &triplets(normal, 0.0)).ok()?;
    SymbolicLlt::try_new(mat.symbolic(), Side::Lower).ok()
}

/// Solves `(H + λ·diag(H)) dx = −b` with node 0 fixed by sparse Cholesky; `None` when the
/// matrix is not positive definite.
fn solve_direct(
    normal: &Normal,
    lambda: f64,
    symbolic: &SymbolicLlt<usize>,
) -> Option<Vec<[f64; 3]>> {
    let n = normal.diag.len();
    let dim = 3 * (n - 1);
    let mat = SparseColMat::try_new_from_triplets(dim, dim, &triplets(normal, lambda)).ok()?;
    let llt = Llt::try_new_with_symbolic(symbolic.clone(), mat.as_ref(), Side::Lower).ok()?;
    let mut rhs = Mat::<f64>::zeros(dim, 1);
    for k in 1..n {
        for c in 0..3 {
            rhs[(3 * (k - 1) + c, 0)] = -normal.b[k][c];
        }
    }
    llt.solve_in_place(rhs.as_mut());
    let mut x = vec![[0.0; 3]; n];
    for k in 1..n {
        for c in 0..3 {
            x[k][c] = rhs[(3 * (k - 1) + c, 0)];
        }
    }
    x.iter().flatten().all(|v| v.is_finite()).then_some(x)
}

/// Solves `(H + λ·diag(H)) dx = −b` with node 0 fixed, by block-Jacobi preconditioned
/// conjugate gradients.
fn solve(normal: &Normal, lambda: f64, options: &OptimizeOptions) -> Vec<[f64; 3]> {
    let n = normal.diag.len();
    let mut diag = normal.diag.clone();
    for d in &mut diag {
        for k in 0..3 {
            d[k][k] += lambda * d[k][k] + 1e-12;
        }
    }
    let precond: Vec<Block> = diag
        .iter()
        .map(|d| invert(d).unwrap_or([[0.0; 3]; 3]))
        .collect();
    let apply = |x: &[[f64; 3]], y: &mut [[f64; 3]]| {
        for k in 0..n {
            y[k] = mat_vec(&diag[k], &x[k]);
        }
        for ((i, j), m) in &normal.off {
            let a = mat_vec(m, &x[*j]);
            let t = mat_vec(&transpose(m), &x[*i]);
            for k in 0..3 {
                y[*i][k] += a[k];
                y[*j][k] += t[k];
            }
        }
        y[0] = [0.0; 3];
    };
    let dot = |a: &[[f64; 3]], b: &[[f64; 3]]| -> f64 {
        a.iter()
            .zip(b)
            .map(|(u, v)| u[0] * v[0] + u[1] * v[1] + u[2] * v[2])
            .sum()
    };
    let mut x = vec![[0.0; 3]; n];
    let mut r: Vec<[f64; 3]> = normal.b.iter().map(|g| [-g[0], -g[1], -g[2]]).collect();
    r[0] = [0.0; 3];
    let mut z: Vec<[f64; 3]> = r.iter().zip(&precond).map(|(v, m)| mat_vec(m, v)).collect();
    z[0] = [0.0; 3];
    let mut p = z.clone();
    let mut rz = dot(&r, &z);
    let r0 = dot(&r, &r).sqrt();
    let mut ap = vec![[0.0; 3]; n];
    for _ in 0..options.cg_max_iterations {
        if rz.abs() < 1e-300 || dot(&r, &r).sqrt() <= options.cg_tolerance * r0.max(1e-300) {
            break;
        }
        apply(&p, &mut ap);
        let pap = dot(&p, &ap);
        if pap <= 0.0 {
            break;
        }
        let alpha = rz / pap;
        for k in 0..n {
            for c in 0..3 {
                x[k][c] += alpha * p[k][c];
                r[k][c] -= alpha * ap[k][c];
            }
        }
        for k in 1..n {
            z[k] = mat_vec(&precond[k], &r[k]);
        }
        let rz_new = dot(&r, &z);
        let beta = rz_new / rz;
        rz = rz_new;
        for k in 0..n {
            for c in 0..3 {
                p[k][c] = z[k][c] + beta * p[k][c];
            }
        }
    }
    x
}

fn mul(a: &Block, b: &Block) -> Block {
    let mut o = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            o[i][j] = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    o
}

/// aᵀ·b.
fn mul_t(a: &Block, b: &Block) -> Block {
    mul(&transpose(a), b)
}

fn transpose(a: &Block) -> Block {
    let mut o = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            o[i][j] = a[j][i];
        }
    }
    o
}

fn add(a: &mut Block, b: &Block) {
    for i in 0..3 {
        for j in 0..3 {
            a[i][j] += b[i][j];
        }
    }
}

fn mat_vec(a: &Block, v: &[f64; 3]) -> [f64; 3] {
    [
        a[0][0] * v[0] + a[0][1] * v[1] + a[0][2] * v[2],
        a[1][0] * v[0] + a[1][1] * v[1] + a[1][2] * v[2],
        a[2][0] * v[0] + a[2][1] * v[1] + a[2][2] * v[2],
    ]
}

fn invert(m: &Block) -> Option<Block> {
    let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    if det.abs() < 1e-300 {
        return None;
    }
    let mut o = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            let (a, b) = ((j + 1) % 3, (j + 2) % 3);
            let (c, d) = ((i + 1) % 3, (i + 2) % 3);
            o[i][j] = (m[a][c] * m[b][d] - m[a][d] * m[b][c]) / det;
        }
    }
    Some(o)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_of_a_block_is_its_inverse() {
        let m = [[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]];
        let p = mul(&m, &invert(&m).unwrap());
        for (i, row) in p.iter().enumerate() {
            for (j, v) in row.iter().enumerate() {
                assert!((v - if i == j { 1.0 } else { 0.0 }).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn jacobians_match_finite_differences() {
        let e = Edge::with_sigmas(0, 1, Pose2::new(0.7, -0.2, 0.4), [1.0; 3]);
        let mut g = PoseGraph {
            nodes: vec![Pose2::new(0.3, 0.1, 0.5), Pose2::new(1.0, 0.9, 1.2)],
            edges: vec![e],
        };
        let normal = g.linearise();
        // b = Aᵀe + ... with Ω = I: compare to the gradient of ½|e|² by central differences.
        let h = 1e-6;
        for node in 0..2 {
            for k in 0..3 {
                let base = g.nodes[node];
                let mut plus = base;
                let mut minus = base;
                match k {
                    0 => (plus.x, minus.x) = (base.x + h, base.x - h),
                    1 => (plus.y, minus.y) = (base.y + h, base.y - h),
                    _ => (plus.theta, minus.theta) = (base.theta + h, base.theta - h),
                }
                g.nodes[node] = plus;
                let cp = 0.5 * g.cost();
                g.nodes[node] = minus;
                let cm = 0.5 * g.cost();
                g.nodes[node] = base;
                let numeric = (cp - cm) / (2.0 * h);
                assert!(
                    (numeric - normal.b[node][k]).abs() < 1e-6,
                    "node {node} coordinate {k}: {numeric} vs {}",
                    normal.b[node][k]
                );
            }
        }
    }

    /// A square loop of four odometry edges that each overestimate the turn, closed by a loop
    /// edge: optimisation spreads the error and the loop closes.
    #[test]
    fn a_loop_with_drifting_odometry_closes() {
        let truth: Vec<Pose2> = (0..8)
            .map(|k| {
                let a = k as f64 * std::f64::consts::FRAC_PI_4;
                Pose2::new(
                    2.0 * a.cos(),
                    2.0 * a.sin(),
                    a + std::f64::consts::FRAC_PI_2,
                )
            })
            .collect();
        let mut g = PoseGraph::default();
        let sigma = [0.05, 0.05, 0.02];
        let mut est = truth[0];
        g.nodes.push(est);
        for k in 1..8 {
            let mut z = truth[k - 1].between(&truth[k]);
            z.theta += 0.05;
            z.x *= 1.04;
            est = est.compose(&z);
            g.nodes.push(est);
            g.edges.push(Edge::with_sigmas(k - 1, k, z, sigma));
        }
        // The loop: node 7 back to node 0, measured exactly.
        g.edges.push(Edge::with_sigmas(
            7,
            0,
            truth[7].between(&truth[0]),
            [0.01, 0.01, 0.005],
        ));
        let before = g.nodes[7].distance(&truth[7]);
        let report = g.optimize(&OptimizeOptions::default()).unwrap();
        let after = g.nodes[7].distance(&truth[7]);
        assert!(report.final_cost < report.initial_cost * 0.1, "{report:?}");
        assert!(before > 0.5, "drift {before}");
        assert!(after < 0.1, "after {after}");
        assert_eq!(g.nodes[0], truth[0], "the first node is the gauge");
        // The loop edge is now nearly satisfied.
        let loop_edge = g.edges.last().unwrap();
        let e = loop_edge.error(&g.nodes[7], &g.nodes[0]);
        assert!(e[0].hypot(e[1]) < 0.05 && e[2].abs() < 0.02, "{e:?}");
    }

    /// A corridor of 3,000 one-metre steps whose far end is measured 3 m further than the
    /// steps add up to: with equal weights the 3 m spread evenly over the cycle's 3,000 edges
    /// (the problem is linear, so one exact step solves it). Conjugate gradients with the
    /// default 1,000 iterations stop far from this on a chain this long.
    #[test]
    fn a_building_size_loop_is_solved_exactly() {
        let n = 3000;
        let mut g = PoseGraph::default();
        for k in 0..n {
            g.nodes.push(Pose2::new(k as f64, 0.0, 0.0));
        }
        for k in 1..n {
            g.edges.push(Edge::with_sigmas(
                k - 1,
                k,
                Pose2::new(1.0, 0.0, 0.0),
                [0.1, 0.1, 0.01],
            ));
        }
        let stretch = 3.0;
        g.edges.push(Edge::with_sigmas(
            0,
            n - 1,
            Pose2::new((n - 1) as f64 + stretch, 0.0, 0.0),
            [0.1, 0.1, 0.01],
        ));
        g.optimize(&OptimizeOptions::default()).unwrap();
        let per_edge = stretch / n as f64;
        for k in [1, n / 2, n - 1] {
            let want = k as f64 * (1.0 + per_edge);
            let p = g.nodes[k];
            assert!(
                (p.x - want).abs() < 1e-4 && p.y.abs() < 1e-9 && p.theta.abs() < 1e-9,
                "node {k} at {p:?}, want x = {want}"
            );
        }
    }

    /// Ten nodes 1 m apart along x, joined by exact edges (σ 5 cm, 0.01 rad).
    fn straight_chain() -> PoseGraph {
        let mut g = PoseGraph::default();
        for k in 0..10 {
            g.nodes.push(Pose2::new(k as f64, 0.0, 0.0));
            if k > 0 {
                g.edges.push(Edge::with_sigmas(
                    k - 1,
                    k,
                    Pose2::new(1.0, 0.0, 0.0),
                    [0.05, 0.05, 0.01],
                ));
            }
        }
        g
    }

    #[test]
    fn a_huber_kernel_limits_a_wrong_loop_edge() {
        // A straight chain with exact odometry and one loop edge that is 1 m wrong.
        let mut g = straight_chain();
        let mut wrong = Edge::with_sigmas(0, 9, Pose2::new(8.0, 0.0, 0.0), [0.05, 0.05, 0.01]);
        let mut plain = g.clone();
        plain.edges.push(wrong);
        plain.optimize(&OptimizeOptions::default()).unwrap();
        wrong.huber = Some(1.0);
        g.edges.push(wrong);
        g.optimize(&OptimizeOptions::default()).unwrap();
        // By hand: nine chain edges in series against one loop edge. Squared loss: the chain
        // gives way 9/10 of the 1 m. Huber: the loop's pull is capped at 2k/σ, which the chain
        // (cost d²/(9σ²)) balances at d = 9kσ = 0.45 m.
        let plain_err = 9.0 - plain.nodes[9].x;
        let robust_err = 9.0 - g.nodes[9].x;
        assert!(
            (plain_err - 0.9).abs() < 0.01,
            "squared loss pulled by {plain_err}"
        );
        assert!(
            (robust_err - 0.45).abs() < 0.01,
            "Huber loss pulled by {robust_err}"
        );
    }

    #[test]
    fn an_outlier_loop_edge_is_removed_and_the_chain_straightens() {
        // The chain above with a right loop edge (0 → 5) beside the 1 m wrong one (0 → 9).
        let mut g = straight_chain();
        let sigma = [0.05, 0.05, 0.01];
        for (to, x) in [(5, 5.0), (9, 8.0)] {
            let mut e = Edge::with_sigmas(0, to, Pose2::new(x, 0.0, 0.0), sigma);
            e.huber = Some(1.0);
            g.edges.push(e);
        }
        g.optimize(&OptimizeOptions::default()).unwrap();
        // The wrong edge is left ~0.5 m (10 σ) from its measurement; the right one is within a
        // few σ (the bent chain strains it), so 5 σ tells them apart.
        assert_eq!(g.remove_outliers(5.0), 1);
        assert!(g.edges.iter().all(|e| !(e.from == 0 && e.to == 9)));
        g.optimize(&OptimizeOptions::default()).unwrap();
        let p = g.nodes[9];
        assert!(
            (p.x - 9.0).abs() < 1e-6 && p.y.abs() < 1e-9,
            "node 9 at {p:?} once the outlier is gone"
        );
        assert_eq!(g.remove_outliers(5.0), 0);
    }
}
