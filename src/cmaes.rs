//! CMA-ES, the covariance matrix adaptation evolution strategy (Hansen & Ostermeier 2001), as
//! the (μ/μ_w, λ) strategy of Hansen's tutorial (arXiv:1604.00772, 2016) with its default
//! parameters, on the unit box [0, 1]^n. Written here: the crates that implement it do not
//! offer an ask-and-tell interface with seeded sampling, which parallel, deterministic
//! parameter searches need.
//!
//! Candidates outside the box are drawn again (up to a limit, then clamped), which suits the
//! low-dimensional, box-bounded searches of scenario parameters.

use nalgebra::{DMatrix, DVector};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

/// Draws per candidate before one outside the box is clamped into it.
const MAX_REDRAWS: usize = 100;

/// The state of a CMA-ES search.
pub struct Cmaes {
    n: usize,
    lambda: usize,
    weights: Vec<f64>,
    mu_eff: f64,
    c_sigma: f64,
    d_sigma: f64,
    c_c: f64,
    c_1: f64,
    c_mu: f64,
    /// E‖N(0, I)‖.
    chi_n: f64,
    mean: DVector<f64>,
    sigma: f64,
    cov: DMatrix<f64>,
    /// Eigenvectors (columns) and square roots of the eigenvalues of `cov`.
    basis: DMatrix<f64>,
    scales: DVector<f64>,
    p_sigma: DVector<f64>,
    p_c: DVector<f64>,
    generation: usize,
    rng: ChaCha8Rng,
}

impl Cmaes {
    /// A search from `start` (in the unit box) with step size `sigma` (in box units; a third
    /// of the box is a good default), its random stream seeded by `seed`.
    pub fn new(start: &[f64], sigma: f64, seed: u64) -> Cmaes {
        let n = start.len().max(1);
        let nf = n as f64;
        let lambda = 4 + (3.0 * nf.ln()).floor() as usize;
        let mu = lambda / 2;
        let raw: Vec<f64> = (1..=mu)
            .map(|i| ((lambda as f64 + 1.0) / 2.0).ln() - (i as f64).ln())
            .collect();
        let sum: f64 = raw.iter().sum();
        let weights: Vec<f64> = raw.iter().map(|w| w / sum).collect();
        let mu_eff = 1.0 / weights.iter().map(|w| w * w).sum::<f64>();
        let c_sigma = (mu_eff + 2.0) / (nf + mu_eff + 5.0);
        let d_sigma = 1.0 + 2.0 * (((mu_eff - 1.0) / (nf + 1.0)).sqrt() - 1.0).max(0.0) + c_sigma;
        let c_c = (4.0 + mu_eff / nf) / (nf + 4.0 + 2.0 * mu_eff / nf);
        let c_1 = 2.0 / ((nf + 1.3).powi(2) + mu_eff);
        let c_mu =
            (1.0 - c_1).min(2.0 * (mu_eff - 2.0 + 1.0 / mu_eff) / ((nf + 2.0).powi(2) + mu_eff));
        let chi_n = nf.sqrt() * (1.0 - 1.0 / (4.0 * nf) + 1.0 / (21.0 * nf * nf));
        Cmaes {
            n,
            lambda,
            weights,
            mu_eff,
            c_sigma,
            d_sigma,
            c_c,
            c_1,
            c_mu,
            chi_n,
            mean: DVector::from_iterator(n, start.iter().map(|x| x.clamp(0.0, 1.0))),
            sigma,
            cov: DMatrix::identity(n, n),
            basis: DMatrix::identity(n, n),
            scales: DVector::from_element(n, 1.0),
            p_sigma: DVector::zeros(n),
            p_c: DVector::zeros(n),
            generation: 0,
            rng: ChaCha8Rng::seed_from_u64(seed),
        }
    }

    /// Candidates per generation, λ = 4 + ⌊3 ln n⌋.
    pub fn lambda(&self) -> usize {
        self.lambda
    }

    /// The current mean, in the unit box.
    pub fn mean(&self) -> Vec<f64> {
        self.mean.iter().copied().collect()
    }

    /// The step size, in box units.
    pub fn sigma(&self) -> f64 {
        self.sigma
    }

    /// Draws a generation of λ candidates in the unit box.
    pub fn ask(&mut self) -> Vec<Vec<f64>> {
        (0..self.lambda)
            .map(|_| {
                let mut x = self.draw();
                for _ in 0..MAX_REDRAWS {
                    if x.iter().all(|v| (0.0..=1.0).contains(v)) {
                        break;
                    }
                    x = self.draw();
                }
                x.iter().map(|v| v.clamp(0.0, 1.0)).collect()
            })
            .collect()
    }

    fn draw(&mut self) -> DVector<f64> {
        let z = DVector::from_iterator(
            self.n,
            (0..self.n).map(|_| self.rng.sample::<f64, _>(StandardNormal)),
        );
        &self.mean + self.sigma * (&self.basis * z.component_mul(&self.scales))
    }

    /// Updates the search with a generation's candidates and their costs (lower is better;
    /// non-finite costs rank last).
    pub fn tell(&mut self, xs: &[Vec<f64>], costs: &[f64]) {
        let n = self.n as f64;
        let mut order: Vec<usize> = (0..xs.len()).collect();
        order.sort_by(|&a, &b| {
            let key = |c: f64| if c.is_finite() { c } else { f64::INFINITY };
            key(costs[a]).total_cmp(&key(costs[b])).then(a.cmp(&b))
        });
        let ys: Vec<DVector<f64>> = order
            .iter()
            .take(self.weights.len())
            .map(|&k| (DVector::from_column_slice(&xs[k]) - &self.mean) / self.sigma)
            .collect();
        let mut y_w = DVector::zeros(self.n);
        for (w, y) in self.weights.iter().zip(&ys) {
            y_w += *w * y;
        }
        self.mean += self.sigma * &y_w;
        // C^(-1/2) y_w = B D^-1 Bᵀ y_w.
        let inv_sqrt = &self.basis
            * DMatrix::from_diagonal(&self.scales.map(|d| 1.0 / d.max(1e-300)))
            * self.basis.transpose();
        self.p_sigma = (1.0 - self.c_sigma) * &self.p_sigma
            + (self.c_sigma * (2.0 - self.c_sigma) * self.mu_eff).sqrt() * (&inv_sqrt * &y_w);
        self.generation += 1;
        let ps_norm = self.p_sigma.norm();
        let h_sigma = ps_norm
            / (1.0 - (1.0 - self.c_sigma).powi(2 * self.generation as i32)).sqrt()
            < (1.4 + 2.0 / (n + 1.0)) * self.chi_n;
        let h = if h_sigma { 1.0 } else { 0.0 };
        self.p_c = (1.0 - self.c_c) * &self.p_c
            + h * (self.c_c * (2.0 - self.c_c) * self.mu_eff).sqrt() * &y_w;
        let delta_h = (1.0 - h) * self.c_c * (2.0 - self.c_c);
        let mut rank_mu = DMatrix::zeros(self.n, self.n);
        for (w, y) in self.weights.iter().zip(&ys) {
            rank_mu += *w * y * y.transpose();
        }
        self.cov = (1.0 + self.c_1 * delta_h - self.c_1 - self.c_mu) * &self.cov
            + self.c_1 * &self.p_c * self.p_c.transpose()
            + self.c_mu * rank_mu;
        self.sigma *= ((self.c_sigma / self.d_sigma) * (ps_norm / self.chi_n - 1.0)).exp();
        // A step larger than the box is no use.
        self.sigma = self.sigma.min(1.0);
        let sym = (&self.cov + self.cov.transpose()) * 0.5;
        let eig = nalgebra::SymmetricEigen::new(sym.clone());
        self.cov = sym;
        self.basis = eig.eigenvectors;
        self.scales = eig.eigenvalues.map(|v| v.max(1e-20).sqrt());
    }
}

/// Uniform random search on the unit box: the baseline any optimiser must beat.
pub struct RandomSearch {
    n: usize,
    batch: usize,
    rng: ChaCha8Rng,
}

impl RandomSearch {
    pub fn new(n: usize, batch: usize, seed: u64) -> RandomSearch {
        RandomSearch {
            n,
            batch: batch.max(1),
            rng: ChaCha8Rng::seed_from_u64(seed),
        }
    }

    pub fn ask(&mut self) -> Vec<Vec<f64>> {
        (0..self.batch)
            .map(|_| (0..self.n).map(|_| self.rng.random::<f64>()).collect())
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Best cost found within `budget` evaluations of `f`.
    fn minimise(f: impl Fn(&[f64]) -> f64, n: usize, budget: usize, seed: u64, cma: bool) -> f64 {
        let mut es = Cmaes::new(&vec![0.5; n], 0.3, seed);
        let mut rs = RandomSearch::new(n, es.lambda(), seed);
        let mut best = f64::INFINITY;
        let mut used = 0;
        while used < budget {
            let xs = if cma { es.ask() } else { rs.ask() };
            let costs: Vec<f64> = xs.iter().map(|x| f(x)).collect();
            used += xs.len();
            best = costs.iter().copied().fold(best, f64::min);
            if cma {
                es.tell(&xs, &costs);
            }
        }
        best
    }

    /// Rosenbrock's valley on [-2, 2]², mapped onto the box: minimum 0 at (0.75, 0.75).
    fn rosenbrock(x: &[f64]) -> f64 {
        let (a, b) = (4.0 * x[0] - 2.0, 4.0 * x[1] - 2.0);
        (1.0 - a).powi(2) + 100.0 * (b - a * a).powi(2)
    }

    #[test]
    fn cma_es_finds_the_bottom_of_an_ill_conditioned_valley() {
        for seed in 0..5 {
            let best = minimise(rosenbrock, 2, 600, seed, true);
            assert!(best < 1e-4, "seed {seed}: {best}");
            // Random search with the same budget stays far up the valley.
            let random = minimise(rosenbrock, 2, 600, seed, false);
            assert!(
                random > 100.0 * best,
                "seed {seed}: {random} against {best}"
            );
        }
    }

    #[test]
    fn cma_es_beats_random_search_on_a_shifted_ellipsoid() {
        let f = |x: &[f64]| -> f64 {
            x.iter()
                .enumerate()
                .map(|(i, v)| 10f64.powi(i as i32) * (v - 0.3).powi(2))
                .sum()
        };
        let mut wins = 0;
        for seed in 0..10 {
            let cma = minimise(f, 4, 300, seed, true);
            let random = minimise(f, 4, 300, seed, false);
            wins += (cma < random) as usize;
        }
        assert!(wins >= 9, "CMA-ES won {wins} of 10");
    }

    #[test]
    fn the_same_seed_gives_the_same_search() {
        let run = |seed| {
            let mut es = Cmaes::new(&[0.2, 0.8], 0.3, seed);
            for _ in 0..5 {
                let xs = es.ask();
                let costs: Vec<f64> = xs.iter().map(|x| rosenbrock(x)).collect();
                es.tell(&xs, &costs);
            }
            (es.mean(), es.sigma())
        };
        assert_eq!(run(7), run(7));
        assert_ne!(run(7), run(8));
    }

    #[test]
    fn candidates_stay_in_the_box_and_failures_rank_last() {
        let mut es = Cmaes::new(&[0.0, 1.0], 0.9, 1);
        for _ in 0..10 {
            let xs = es.ask();
            assert!(xs.iter().flatten().all(|v| (0.0..=1.0).contains(v)));
            // The first candidate "fails" each time; the search must not follow it.
            let mut costs: Vec<f64> = xs.iter().map(|x| (x[0] - 0.5).powi(2)).collect();
            costs[0] = f64::NAN;
            es.tell(&xs, &costs);
        }
        assert!((es.mean()[0] - 0.5).abs() < 0.1, "{:?}", es.mean());
    }
}
