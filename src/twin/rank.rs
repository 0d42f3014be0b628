//! Transfer of decisions: a set of SLAM configurations ranked by relations error in the twin
//! and on the real log (`futago twin --rank FILE`).
//!
//! A twin is worth tuning in only if the ordering it gives is the robot's. Each configuration
//! runs on the real log, scored against its relations, and on every seed's twin log, scored
//! against the twin's truth at the same stamp pairs. The two orderings are compared by
//! Spearman's rank correlation, and the configuration best in the twin by its real error over
//! the real log's best (the regret of choosing in the twin).
//!
//! A SLAM's result on a log hangs partly on which scans happen to become keyframes: on the
//! shared logs, the ranking of the committed set with its keyframes' spacing (in travel and in
//! turn) 7 % longer agreed with the ranking at the set's own spacing with ρ = 0.81 (MIT CSAIL),
//! 0.67 (Intel) and 0.55 (the hospital). A ranking on one run ranks that luck. So, as `futago folds` does, each
//! configuration's real error is the mean of three runs with the keyframe spacing scaled by
//! 1, 1 − p and 1 + p ([`PERTURBATION`]), and each twin seed runs at one of those spacings in
//! turn (seed 0 at the configuration's own), its error the median over the seeds.
//!
//! The real ordering rests on a finite set of relations: where the configurations' real errors
//! differ by less than their mean over the relations scatters, the relations cannot order
//! them. [`resampled_agreement`] says how far they resolve it: the agreement of the real
//! ranking with those of its relations resampled. (The relations' own error,
//! [`relations::reference_noise`], is common to every configuration and is not resampled away:
//! it favours a configuration whose errors happen to follow it, which this does not show.)
//!
//! The file lists the configurations, each a name and the keys it sets over the base
//! configuration (dotted, under `[slam]`):
//!
//! ```toml
//! [[config]]
//! name = "keyframes twice as sparse"
//! set = { keyframe_distance = 0.6, keyframe_angle = 0.7 }
//! ```

use crate::parallel::parallel_map;
use crate::relations::{self, Relation};
use crate::replay::{as_logged, slam_over};
use anyhow::{Result, anyhow, bail};
use futago_msgs::carmen;
use futago_robot::mapping::slam::SlamConfig;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The keyframe spacing's relative perturbation (`futago folds`'s, see there).
pub const PERTURBATION: f64 = 0.07;

/// The spacing factors of the real log's runs, and of twin seed `s` (`FACTORS[s % 3]`).
const FACTORS: [f64; 3] = [1.0, 1.0 - PERTURBATION, 1.0 + PERTURBATION];

/// A configuration to rank: its name and the whole SLAM configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct Candidate {
    pub name: String,
    pub config: SlamConfig,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct CandidateFile {
    #[serde(default)]
    config: Vec<Entry>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Entry {
    name: String,
    #[serde(default)]
    set: toml::Table,
}

/// Reads the configurations of the file at `path`, each laid over `base` and checked; the
/// error names the file, the configuration and the key.
pub fn load(path: &Path, base: SlamConfig) -> Result<Vec<Candidate>> {
    let file: CandidateFile = futago_sim::config::load_toml(path)?;
    let at = path.display();
    if file.config.len() < 2 {
        bail!(
            "{at}: `config`: expected at least two [[config]] to rank, found {}",
            file.config.len()
        );
    }
    let toml::Value::Table(base_table) = toml::Value::try_from(base)? else {
        bail!("the base SLAM configuration is not a table");
    };
    let mut candidates: Vec<Candidate> = Vec::new();
    for (k, e) in file.config.into_iter().enumerate() {
        if candidates.iter().any(|c| c.name == e.name) {
            bail!(
                "{at}: config[{k}].name = {:?}: expected a name no other configuration has",
                e.name
            );
        }
        let mut table = base_table.clone();
        for (key, value) in &e.set {
            crate::overlay::Overlay::assign(key, value.clone())
                .map_err(|m| anyhow!("{at}: config[{k}].set.`{key}`: {}", m.message))?
                .apply(&mut table);
        }
        let config: SlamConfig = toml::Value::Table(table)
            .try_into()
            .map_err(|m| anyhow!("{at}: config[{k}].set: not a SLAM setting ({m})"))?;
        config
            .validate()
            .map_err(|(key, why)| anyhow!("{at}: config[{k}].set: `{key}`: {why}"))?;
        candidates.push(Candidate {
            name: e.name,
            config,
        });
    }
    Ok(candidates)
}

/// One configuration's place in both orderings.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Row {
    pub name: String,
    /// Mean translational relations error on the real log, m: the mean of its runs, one at
    /// each spacing factor of [`FACTORS`].
    pub real_m: f64,
    pub real_runs_m: Vec<f64>,
    /// The same in the twin: the median over the seeds, and each seed's.
    pub twin_m: f64,
    pub twin_seeds_m: Vec<f64>,
    /// Ranks, 1 the best (ties share the mean of their ranks).
    pub real_rank: f64,
    pub twin_rank: f64,
}

/// Both orderings and how well they agree.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Ranking {
    pub rows: Vec<Row>,
    /// Spearman's rank correlation between the twin's and the real log's errors.
    pub spearman: f64,
    pub best_in_twin: String,
    pub best_on_real: String,
    /// The real error of the configuration best in the twin over the real log's best: 1 when
    /// the twin picks the real best.
    pub regret: f64,
    /// How well the relations resolve the real ranking: Spearman's ρ between the real ranking
    /// and the rankings of [`BOOTSTRAP`] resamplings of the scored relations (with
    /// replacement), their median and 10th percentile ([`resampled_agreement`]).
    pub real_resampled_spearman: [f64; 2],
}

/// Resamplings of the relations for [`Ranking::real_resampled_spearman`].
pub const BOOTSTRAP: usize = 200;

/// The agreement of the ranking by `errors` (per configuration, each relation's error: the
/// mean over its runs, none where a run left it unscored) with the rankings of [`BOOTSTRAP`]
/// resamplings of the relations, drawn with replacement from a fixed stream: Spearman's ρ's
/// median and 10th percentile. Where configurations differ by less than the scatter of the
/// mean over the relations, the relations cannot order them, and no twin can agree with an
/// ordering that its own data do not hold (Efron and Tibshirani, *An Introduction to the
/// Bootstrap*, 1993).
pub fn resampled_agreement(errors: &[Vec<Option<f64>>]) -> [f64; 2] {
    use rand::Rng;
    let n = errors.iter().map(Vec::len).min().unwrap_or(0);
    if n == 0 || errors.len() < 2 {
        return [f64::NAN; 2];
    }
    let mean_over = |e: &[Option<f64>], picks: &mut dyn Iterator<Item = usize>| {
        let (mut sum, mut k) = (0.0, 0usize);
        for i in picks {
            if let Some(x) = e[i] {
                sum += x;
                k += 1;
            }
        }
        if k == 0 { f64::NAN } else { sum / k as f64 }
    };
    let full: Vec<f64> = errors.iter().map(|e| mean_over(e, &mut (0..n))).collect();
    let full_rank = ranks(&full);
    let mut rng = futago_sim::noise::stream(0, "twin.rank.bootstrap");
    let mut rhos: Vec<f64> = (0..BOOTSTRAP)
        .map(|_| {
            let picks: Vec<usize> = (0..n).map(|_| rng.random_range(0..n)).collect();
            let means: Vec<f64> = errors
                .iter()
                .map(|e| mean_over(e, &mut picks.iter().copied()))
                .collect();
            pearson(&ranks(&means), &full_rank)
        })
        .collect();
    rhos.sort_by(f64::total_cmp);
    [rhos[BOOTSTRAP / 2], rhos[BOOTSTRAP / 10]]
}

/// Ranks `candidates`: each runs the SLAM over `real` at each spacing of [`FACTORS`] (scored on
/// `real_rels`) and over the twin log of every seed `0..seeds` that `twin_log` makes (scored on
/// that seed's `twin_rels[seed]`, `seeds` of them), `jobs` at a time.
pub fn rank(
    candidates: &[Candidate],
    real: &carmen::Log,
    real_rels: &[Relation],
    twin_rels: &[Vec<Relation>],
    jobs: usize,
    twin_log: impl Fn(u64) -> carmen::Log + Sync,
) -> Ranking {
    let seeds = twin_rels.len() as u64;
    // (configuration, the spacing factor, the twin's seed: none for the real log)
    let runs: Vec<(usize, f64, Option<u64>)> = (0..candidates.len())
        .flat_map(|c| {
            let real = FACTORS.iter().map(move |&f| (c, f, None));
            let twins = (0..seeds).map(move |s| (c, FACTORS[s as usize % 3], Some(s)));
            real.chain(twins)
        })
        .collect();
    let per_relation = parallel_map(&runs, jobs, |_, &(c, f, seed)| {
        let mut config = candidates[c].config;
        config.keyframe_distance *= f;
        match seed {
            None => relations_errors(real, config, real_rels),
            Some(s) => relations_errors(&twin_log(s), config, &twin_rels[s as usize]),
        }
    });
    let mean = |e: &Vec<Option<f64>>| {
        let v: Vec<f64> = e.iter().flatten().copied().collect();
        if v.is_empty() {
            f64::NAN
        } else {
            v.iter().sum::<f64>() / v.len() as f64
        }
    };
    let errors: Vec<f64> = per_relation.iter().map(mean).collect();
    let per = FACTORS.len() + seeds as usize;
    // Each relation's real error per configuration, the mean over the spacings.
    let real_per_relation: Vec<Vec<Option<f64>>> = per_relation
        .chunks(per)
        .map(|runs| {
            let runs = &runs[..FACTORS.len()];
            (0..real_rels.len())
                .map(|i| {
                    let v: Option<Vec<f64>> = runs.iter().map(|r| r[i]).collect();
                    v.map(|v| v.iter().sum::<f64>() / v.len() as f64)
                })
                .collect()
        })
        .collect();
    let real_runs: Vec<Vec<f64>> = errors
        .chunks(per)
        .map(|e| e[..FACTORS.len()].to_vec())
        .collect();
    let twin_seeds: Vec<Vec<f64>> = errors
        .chunks(per)
        .map(|e| e[FACTORS.len()..].to_vec())
        .collect();
    let mut r = ranking(candidates, real_runs, twin_seeds);
    r.real_resampled_spearman = resampled_agreement(&real_per_relation);
    r
}

/// The orderings of errors already measured: each configuration's real runs (their mean
/// ranks it) and twin seeds (their median).
fn ranking(
    candidates: &[Candidate],
    real_runs: Vec<Vec<f64>>,
    twin_seeds: Vec<Vec<f64>>,
) -> Ranking {
    let real_m: Vec<f64> = real_runs
        .iter()
        .map(|r| r.iter().sum::<f64>() / r.len().max(1) as f64)
        .collect();
    let twin_m: Vec<f64> = twin_seeds
        .iter()
        .map(|e| super::median(e.clone()))
        .collect();
    let real_rank = ranks(&real_m);
    let twin_rank = ranks(&twin_m);
    let best = |r: &[f64]| {
        (0..r.len())
            .min_by(|&a, &b| r[a].total_cmp(&r[b]))
            .unwrap_or(0)
    };
    let (bt, br) = (best(&twin_rank), best(&real_rank));
    let rows = candidates
        .iter()
        .enumerate()
        .map(|(i, c)| Row {
            name: c.name.clone(),
            real_m: real_m[i],
            real_runs_m: real_runs[i].clone(),
            twin_m: twin_m[i],
            twin_seeds_m: twin_seeds[i].clone(),
            real_rank: real_rank[i],
            twin_rank: twin_rank[i],
        })
        .collect();
    Ranking {
        rows,
        spearman: pearson(&real_rank, &twin_rank),
        best_in_twin: candidates[bt].name.clone(),
        best_on_real: candidates[br].name.clone(),
        regret: real_m[bt] / real_m[br],
        real_resampled_spearman: [f64::NAN; 2],
    }
}

/// The SLAM's translational error over `log` with `config` on each of `rels`, m (none where
/// the trajectory does not reach a relation's stamps).
fn relations_errors(log: &carmen::Log, config: SlamConfig, rels: &[Relation]) -> Vec<Option<f64>> {
    let slam = slam_over(log, config);
    let trajectory = as_logged(&slam.trajectory(), log);
    rels.iter()
        .map(|r| relations::error(&trajectory, r).map(|e| e.0))
        .collect()
}

/// Ranks of `v`, 1 the smallest; ties share the mean of their ranks, and a value that is not
/// finite (a run with nothing scored) ranks last.
pub fn ranks(v: &[f64]) -> Vec<f64> {
    let key = |x: f64| if x.is_finite() { x } else { f64::INFINITY };
    let mut order: Vec<usize> = (0..v.len()).collect();
    order.sort_by(|&a, &b| key(v[a]).total_cmp(&key(v[b])));
    let mut r = vec![0.0; v.len()];
    let mut i = 0;
    while i < order.len() {
        let mut j = i;
        while j + 1 < order.len() && key(v[order[j + 1]]) == key(v[order[i]]) {
            j += 1;
        }
        let mean = (i + j) as f64 / 2.0 + 1.0;
        for &k in &order[i..=j] {
            r[k] = mean;
        }
        i = j + 1;
    }
    r
}

/// Pearson's correlation of `a` and `b` (of ranks: Spearman's), NaN where either is constant.
fn pearson(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut ab, mut aa, mut bb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        ab += (x - ma) * (y - mb);
        aa += (x - ma).powi(2);
        bb += (y - mb).powi(2);
    }
    ab / (aa * bb).sqrt()
}

/// The ranking as a Markdown table, with its agreement.
pub fn table(r: &Ranking) -> String {
    let mut s = String::from(
        "| configuration | real, m | rank | twin, m | rank |\n|---|---|---|---|---|\n",
    );
    for row in &r.rows {
        s += &format!(
            "| {} | {:.4} | {} | {:.4} | {} |\n",
            row.name, row.real_m, row.real_rank, row.twin_m, row.twin_rank
        );
    }
    s += &format!(
        "\nSpearman's ρ {:.3}. Best in the twin: {}; on the real log: {}; the twin's choice on the real log over the real best: {:.3}. The relations resolve the real ranking to ρ {:.3} (the median over {BOOTSTRAP} resamplings of them; 10th percentile {:.3}).\n",
        r.spearman,
        r.best_in_twin,
        r.best_on_real,
        r.regret,
        r.real_resampled_spearman[0],
        r.real_resampled_spearman[1]
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One run per configuration.
    fn runs(v: &[f64]) -> Vec<Vec<f64>> {
        v.iter().map(|x| vec![*x]).collect()
    }

    fn candidates(n: usize) -> Vec<Candidate> {
        (0..n)
            .map(|i| Candidate {
                name: format!("c{i}"),
                config: SlamConfig::default(),
            })
            .collect()
    }

    #[test]
    fn resampling_tells_separated_configurations_from_ones_within_the_scatter() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        // Six configurations over 300 relations, each relation's error scattered by 0.02 m.
        let errors = |gap: f64, rng: &mut rand_chacha::ChaCha8Rng| -> Vec<Vec<Option<f64>>> {
            let shared: Vec<f64> = (0..300).map(|_| rng.random_range(0.0..0.04)).collect();
            (0..6)
                .map(|c| {
                    shared
                        .iter()
                        .map(|x| Some(x + c as f64 * gap + rng.random_range(0.0..0.04)))
                        .collect()
                })
                .collect()
        };
        // Means 0.01 m apart, their standard error about 0.0007 m: the order holds.
        let apart = resampled_agreement(&errors(0.01, &mut rng));
        assert!(apart[1] > 0.99, "{apart:?}");
        // No difference at all: resampling reshuffles them.
        let same = resampled_agreement(&errors(0.0, &mut rng));
        assert!(same[0] < 0.8, "{same:?}");
        // A relation left unscored by a run is left out of that configuration's mean.
        let mut holes = errors(0.01, &mut rng);
        holes[2][7] = None;
        assert!(resampled_agreement(&holes)[0] > 0.99);
        assert!(resampled_agreement(&holes[..1])[0].is_nan());
    }

    #[test]
    fn ties_share_their_mean_rank_and_a_failed_run_ranks_last() {
        assert_eq!(
            ranks(&[0.3, 0.1, 0.3, f64::NAN, 0.2]),
            vec![3.5, 1.0, 3.5, 5.0, 2.0]
        );
    }

    #[test]
    fn spearman_is_one_for_the_same_order_and_minus_one_reversed() {
        let real = runs(&[0.1, 0.2, 0.3, 0.4]);
        // A twin three times more accurate, in the same order: a perfect ranking.
        let same = ranking(&candidates(4), real.clone(), runs(&[0.03, 0.07, 0.1, 0.13]));
        assert!((same.spearman - 1.0).abs() < 1e-12);
        assert_eq!(same.regret, 1.0);
        let reversed = ranking(&candidates(4), real, runs(&[0.4, 0.3, 0.2, 0.1]));
        assert!((reversed.spearman + 1.0).abs() < 1e-12);
        assert_eq!(reversed.best_in_twin, "c3");
        assert_eq!(reversed.best_on_real, "c0");
        assert!((reversed.regret - 4.0).abs() < 1e-12);
    }

    #[test]
    fn one_swap_of_neighbours_in_four_gives_the_textbook_rho() {
        // ρ = 1 − 6 Σd² / (n(n² − 1)) = 1 − 6·2/60 = 0.8.
        let r = ranking(
            &candidates(4),
            runs(&[0.1, 0.2, 0.3, 0.4]),
            runs(&[0.1, 0.3, 0.2, 0.4]),
        );
        assert!((r.spearman - 0.8).abs() < 1e-12);
    }

    #[test]
    fn the_real_runs_rank_by_their_mean_and_the_seeds_by_their_median() {
        // Configuration 0 won one real run by luck; its mean loses. The twin's outlying seed
        // of configuration 1 does not move its median.
        let r = ranking(
            &candidates(2),
            vec![vec![0.10, 0.30, 0.30], vec![0.20, 0.20, 0.20]],
            vec![vec![0.3, 0.3, 0.3], vec![0.1, 0.1, 9.0]],
        );
        assert!((r.rows[0].real_m - 0.7 / 3.0).abs() < 1e-12);
        assert_eq!(r.best_on_real, "c1");
        assert_eq!(r.rows[1].twin_m, 0.1);
        assert_eq!(r.best_in_twin, "c1");
        assert!((r.spearman - 1.0).abs() < 1e-12);
    }

    #[test]
    fn the_committed_set_loads_and_bad_sets_are_refused_by_key() {
        let dir = std::env::temp_dir().join(format!("futago-rank-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let set = Path::new(env!("CARGO_MANIFEST_DIR")).join("choices/slam-configs.toml");
        let loaded = load(&set, SlamConfig::default()).unwrap();
        assert!(loaded.len() >= 8, "issue 44 asks for at least 8");
        assert_eq!(loaded[0].config, SlamConfig::default());
        assert!(
            loaded
                .iter()
                .skip(1)
                .all(|c| c.config != SlamConfig::default())
        );
        let bad = |body: &str, expected: &str| {
            let p = dir.join("set.toml");
            std::fs::write(&p, body).unwrap();
            let e = format!("{:#}", load(&p, SlamConfig::default()).unwrap_err());
            assert!(e.contains(expected), "{e} lacks {expected}");
        };
        bad("[[config]]\nname = \"a\"\n", "at least two");
        bad(
            "[[config]]\nname = \"a\"\n[[config]]\nname = \"a\"\n",
            "config[1].name",
        );
        bad(
            "[[config]]\nname = \"a\"\n[[config]]\nname = \"b\"\nset = { keyframe_distance = -1.0 }\n",
            "keyframe_distance",
        );
        bad(
            "[[config]]\nname = \"a\"\n[[config]]\nname = \"b\"\nset = { \"icp.no_such_key\" = 1 }\n",
            "config[1].set",
        );
        std::fs::remove_dir_all(&dir).ok();
    }
}
