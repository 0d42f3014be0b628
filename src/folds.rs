//! `futago folds`: leave-one-log-out choice of SLAM defaults.
//!
//! A default chosen on the logs it is scored on can fit those logs and hurt the next one. So
//! each mechanism or parameter value is chosen as a user with several logs of their own would
//! check it: for every log in turn, the value is chosen on the other logs and scored on the one
//! left out. A choice file lists the choices: a `[slam]` key, the values to try and the
//! `neutral` one (the mechanism off, or the plain value it replaced):
//!
//! ```toml
//! [[choice]]
//! name = "constant-velocity guess"
//! key = "velocity_guess"
//! values = [true, false]
//! neutral = false
//! ```
//!
//! Every value of every choice runs on every log, the others held at the base configuration
//! (the defaults, or a `[slam]` file over them). A log's error is the relations metric's mean
//! absolute translational error over all its relations (Kümmerle et al. 2009), averaged over
//! three runs whose keyframe spacing is scaled by 1 − p, 1 and 1 + p (`p` = 7 % by default):
//! on a log whose result hangs on which scans happen to become keyframes (the Freiburg
//! hospital's relations over all its spans moved from 1.0 m to 4–7 m when the spacing moved by
//! 3 %), one run measures luck, and a choice made on luck does not carry over. On a set of logs
//! a value scores the mean, over the logs, of the logarithm of its error over the neutral
//! value's error: a value that halves one log's error and doubles another's is no gain. For
//! each fold the value with the lowest score on the training logs is chosen (the neutral one on
//! a tie) and its error on the held-out log compared with the neutral value's there. A value
//! fails when a fold chose it and its held-out log got worse than with the neutral value by
//! more than the tolerance (2 %) and by more than twice the standard error of that difference
//! (from the spread of the perturbed runs: a log whose result is chaotic cannot convict). The
//! value kept is the one with the lowest score on all the logs among the neutral one and those
//! that did not fail.

use crate::parallel::parallel_map;
use crate::relations::{self, Relation};
use crate::replay::{as_logged, read_log_with, slam_over};
use anyhow::{Context, Result, bail};
use futago_msgs::carmen;
use futago_robot::mapping::slam::SlamConfig;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The keyframe spacing's relative perturbation by default (issue 14 checked its local map's
/// size under ±7 %).
pub const PERTURBATION: f64 = 0.07;

/// How much worse than the neutral value a fold's held-out log may get under the value chosen
/// on the other logs (2 %).
pub const TOLERANCE: f64 = 0.02;

/// One choice of the choice file.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Choice {
    /// What the choice is, for the table.
    pub name: String,
    /// The dotted key under `[slam]` (`velocity_guess`, `icp.prior_points`).
    pub key: String,
    /// The values tried; the base configuration's value is tried too.
    pub values: Vec<toml::Value>,
    /// The value that stands for the mechanism off, or the plain value.
    pub neutral: toml::Value,
}

/// The choice file.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChoiceFile {
    #[serde(rename = "choice")]
    pub choices: Vec<Choice>,
}

/// A log and its ground-truth relations.
#[derive(Debug, Clone, PartialEq)]
pub struct LogSpec {
    pub log: PathBuf,
    pub relations: PathBuf,
}

/// One fold of one choice: the value chosen without the held-out log, and what it did there.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Fold {
    /// Index of the held-out log.
    pub held_out: usize,
    /// Index of the value chosen on the other logs.
    pub chosen: usize,
    /// The held-out log's error with the chosen value and with the neutral one, m.
    pub error: f64,
    pub neutral_error: f64,
    /// `error / neutral_error − 1`.
    pub change: f64,
    /// Twice the standard error of `error − neutral_error`, m (0 with one run a log).
    pub noise: f64,
    /// Whether the held-out log kept within [`TOLERANCE`] of the neutral value, or within
    /// `noise` of it.
    pub holds: bool,
}

/// The folds of one choice and the value kept.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Verdict {
    pub folds: Vec<Fold>,
    /// Index of the value with the lowest score on every log.
    pub best_on_all: usize,
    /// Index of the value kept (see the module documentation).
    pub kept: usize,
    /// Indices of the values that failed a fold.
    pub failed: Vec<usize>,
}

/// A value's score on `logs`: the mean over them of `ln(error / neutral error)`; a value
/// without a finite positive error on one of them scores +∞.
fn score(errors: &[Vec<f64>], value: usize, neutral: usize, logs: &[usize]) -> f64 {
    let mut sum = 0.0;
    for &l in logs {
        let (e, n) = (errors[value][l], errors[neutral][l]);
        if !(e.is_finite() && e > 0.0 && n.is_finite() && n > 0.0) {
            return f64::INFINITY;
        }
        sum += (e / n).ln();
    }
    sum / logs.len().max(1) as f64
}

/// The value with the lowest score on `logs`; the neutral one on a tie, then the first.
fn choose(errors: &[Vec<f64>], neutral: usize, logs: &[usize]) -> usize {
    let mut best = (score(errors, neutral, neutral, logs), neutral);
    for v in 0..errors.len() {
        let s = score(errors, v, neutral, logs);
        if s < best.0 {
            best = (s, v);
        }
    }
    best.1
}

/// Leave-one-log-out over `errors[value][log]` (at least two logs) with the standard errors
/// of those means `spread[value][log]`, and `neutral` the index of the neutral value (see the
/// module documentation).
pub fn verdict(
    errors: &[Vec<f64>],
    spread: &[Vec<f64>],
    neutral: usize,
    tolerance: f64,
) -> Verdict {
    let logs = errors.first().map_or(0, Vec::len);
    let folds: Vec<Fold> = (0..logs)
        .map(|h| {
            let training: Vec<usize> = (0..logs).filter(|&l| l != h).collect();
            let chosen = choose(errors, neutral, &training);
            let (error, neutral_error) = (errors[chosen][h], errors[neutral][h]);
            let change = error / neutral_error - 1.0;
            let noise = 2.0 * spread[chosen][h].hypot(spread[neutral][h]);
            Fold {
                held_out: h,
                chosen,
                error,
                neutral_error,
                change,
                noise,
                holds: change <= tolerance || error - neutral_error <= noise,
            }
        })
        .collect();
    let mut failed: Vec<usize> = folds
        .iter()
        .filter(|f| !f.holds && f.chosen != neutral)
        .map(|f| f.chosen)
        .collect();
    failed.sort_unstable();
    failed.dedup();
    let all: Vec<usize> = (0..logs).collect();
    let best_on_all = choose(errors, neutral, &all);
    let standing: Vec<Vec<f64>> = errors
        .iter()
        .enumerate()
        .map(|(v, row)| {
            if failed.contains(&v) {
                vec![f64::NAN; row.len()]
            } else {
                row.clone()
            }
        })
        .collect();
    let kept = choose(&standing, neutral, &all);
    Verdict {
        folds,
        best_on_all,
        kept,
        failed,
    }
}

/// A log read and its relations parsed.
struct Loaded {
    log: carmen::Log,
    relations: Vec<Relation>,
}

/// What one SLAM configuration scored on one log: the means over its perturbed runs.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Score {
    /// Mean absolute translational error over all relations, m (the objective).
    pub all_m: f64,
    /// The same over the relations under 10 s apart (Cartographer's "local" figure on the
    /// hospital), m.
    pub local_m: f64,
    /// Mean absolute rotational error over all relations, degrees.
    pub rot_deg: f64,
    /// The standard error of `all_m` over the perturbed runs, m (0 for one run).
    pub all_se_m: f64,
}

/// The mean of the runs' scores.
fn mean_score(runs: &[Score]) -> Score {
    let n = runs.len().max(1) as f64;
    let all_m = runs.iter().map(|s| s.all_m).sum::<f64>() / n;
    let all_se_m = if runs.len() > 1 {
        let var = runs.iter().map(|s| (s.all_m - all_m).powi(2)).sum::<f64>() / (n - 1.0);
        (var / n).sqrt()
    } else {
        0.0
    };
    Score {
        all_m,
        local_m: runs.iter().map(|s| s.local_m).sum::<f64>() / n,
        rot_deg: runs.iter().map(|s| s.rot_deg).sum::<f64>() / n,
        all_se_m,
    }
}

fn run_one(loaded: &Loaded, config: SlamConfig) -> Score {
    let slam = slam_over(&loaded.log, config);
    let trajectory = as_logged(&slam.trajectory(), &loaded.log);
    let all = relations::evaluate(&trajectory, &loaded.relations);
    let local: Vec<Relation> = loaded
        .relations
        .iter()
        .filter(|r| (r.t2 - r.t1).secs().abs() < relations::SPAN_BOUNDS_S[0])
        .copied()
        .collect();
    let local_m = if local.is_empty() {
        f64::NAN
    } else {
        relations::evaluate(&trajectory, &local).abs_trans_m.mean
    };
    Score {
        all_m: all.abs_trans_m.mean,
        local_m,
        rot_deg: all.abs_rot_deg.mean,
        all_se_m: 0.0,
    }
}

/// The base configuration with `value` at `key` under `[slam]`, checked; the error names the
/// choice file and the key.
fn with_value(
    base: &toml::Table,
    key: &str,
    value: &toml::Value,
    file: &Path,
) -> Result<SlamConfig> {
    let mut table = base.clone();
    crate::overlay::Overlay::assign(key, value.clone())
        .map_err(|e| anyhow::anyhow!("{}: `{key}`: {}", file.display(), e.message))?
        .apply(&mut table);
    let config: SlamConfig = toml::Value::Table(table).try_into().map_err(|e| {
        anyhow::anyhow!(
            "{}: `{key}` = {value}: not a SLAM setting ({e})",
            file.display()
        )
    })?;
    config.validate().map_err(|(k, why)| {
        anyhow::anyhow!("{}: `{key}` = {value}: `{k}`: {why}", file.display())
    })?;
    Ok(config)
}

/// Reads and checks a choice file: at least one choice, each with a key, values, and a neutral
/// value among them.
pub fn load_choices(path: &Path) -> Result<Vec<Choice>> {
    let file: ChoiceFile = futago_sim::config::load_toml(path)?;
    if file.choices.is_empty() {
        bail!(
            "{}: `choice`: expected at least one [[choice]]",
            path.display()
        );
    }
    for (k, c) in file.choices.iter().enumerate() {
        crate::overlay::split_path(&c.key)
            .map_err(|e| anyhow::anyhow!("{}: choice[{k}].key: {e}", path.display()))?;
        if c.values.is_empty() {
            bail!(
                "{}: choice[{k}].values: expected at least one value",
                path.display()
            );
        }
        if !c.values.contains(&c.neutral) {
            bail!(
                "{}: choice[{k}].neutral = {}: expected one of its values",
                path.display(),
                c.neutral
            );
        }
    }
    Ok(file.choices)
}

/// Every choice's values, runs and verdict.
#[derive(Debug, Clone, Serialize)]
pub struct ChoiceResult {
    pub choice: Choice,
    /// The values tried: the choice's own, and the base configuration's where none of them
    /// gives the base configuration.
    pub values: Vec<toml::Value>,
    /// Index of the base configuration's value.
    pub base: usize,
    pub neutral: usize,
    /// Whether every value gave the same errors on every log: no evidence, and the base value
    /// is kept.
    pub inert: bool,
    /// `scores[value][log]`.
    pub scores: Vec<Vec<Score>>,
    pub verdict: Verdict,
}

/// What `futago folds` found.
#[derive(Debug, Clone, Serialize)]
pub struct Folds {
    pub logs: Vec<String>,
    pub tolerance: f64,
    /// The keyframe spacings each configuration ran with, as factors of its own.
    pub keyframe_spacing_factors: Vec<f64>,
    pub base: Vec<Score>,
    pub choices: Vec<ChoiceResult>,
}

/// Runs every value of every choice on every log (`jobs` at a time) and takes the folds.
pub fn folds(
    logs: &[LogSpec],
    choices: &[Choice],
    choice_file: &Path,
    base: &SlamConfig,
    perturbation: f64,
    jobs: usize,
) -> Result<Folds> {
    if !(0.0..0.5).contains(&perturbation) {
        bail!("--perturb {perturbation}: expected a share of the keyframe spacing in [0, 0.5)");
    }
    let factors: Vec<f64> = if perturbation > 0.0 {
        vec![1.0 - perturbation, 1.0, 1.0 + perturbation]
    } else {
        vec![1.0]
    };
    if logs.len() < 2 {
        bail!(
            "leave-one-log-out needs two logs at least, with their relations; got {}",
            logs.len()
        );
    }
    let loaded = logs
        .iter()
        .map(|l| {
            let log = read_log_with(&l.log, &carmen::ReadOptions::default())?;
            if log.scans.is_empty() {
                bail!("{}: the log holds no laser scans", l.log.display());
            }
            let text = std::fs::read_to_string(&l.relations)
                .with_context(|| format!("reading {}", l.relations.display()))?;
            let relations = relations::parse(&text, &l.relations.display().to_string())?;
            Ok(Loaded { log, relations })
        })
        .collect::<Result<Vec<_>>>()?;
    let base_table = match toml::Value::try_from(base)? {
        toml::Value::Table(t) => t,
        _ => bail!("the SLAM configuration is not a table"),
    };
    // Every configuration to run: the base first, then each choice's values but the base's.
    let mut configs = vec![*base];
    let mut plans = Vec::new();
    for c in choices {
        let base_value = crate::overlay::lookup(&base_table, &c.key)
            .cloned()
            .with_context(|| {
                format!("{}: `{}`: not a SLAM setting", choice_file.display(), c.key)
            })?;
        let mut values = c.values.clone();
        let mut at = Vec::new();
        for v in &values {
            let config = with_value(&base_table, &c.key, v, choice_file)?;
            if config == *base {
                at.push(0);
            } else {
                configs.push(config);
                at.push(configs.len() - 1);
            }
        }
        // The base configuration is always a candidate.
        if !at.contains(&0) {
            values.push(base_value);
            at.push(0);
        }
        let base_index = at.iter().position(|&c| c == 0).unwrap_or(0);
        let neutral = values.iter().position(|v| *v == c.neutral).unwrap_or(0);
        plans.push((c.clone(), values, at, base_index, neutral));
    }
    let draws = factors.len();
    let runs: Vec<(usize, usize, f64)> = (0..configs.len())
        .flat_map(|c| {
            let factors = &factors;
            (0..loaded.len()).flat_map(move |l| factors.iter().map(move |&f| (c, l, f)))
        })
        .collect();
    let scores = parallel_map(&runs, jobs, |_, &(c, l, f)| {
        let mut config = configs[c];
        config.keyframe_distance *= f;
        run_one(&loaded[l], config)
    });
    let score = |c: usize, l: usize| {
        let first = (c * loaded.len() + l) * draws;
        mean_score(&scores[first..first + draws])
    };
    let results = plans
        .into_iter()
        .map(|(choice, values, at, base, neutral)| {
            let table: Vec<Vec<Score>> = at
                .iter()
                .map(|&c| (0..loaded.len()).map(|l| score(c, l)).collect())
                .collect();
            let errors: Vec<Vec<f64>> = table
                .iter()
                .map(|row| row.iter().map(|s| s.all_m).collect())
                .collect();
            let spread: Vec<Vec<f64>> = table
                .iter()
                .map(|row| row.iter().map(|s| s.all_se_m).collect())
                .collect();
            // A choice that changes nothing on any of these logs has no evidence here either way
            // (a sensor model these logs do not exercise): its base value stays.
            let inert = errors.iter().all(|row| row == &errors[base]);
            let mut verdict = verdict(&errors, &spread, neutral, TOLERANCE);
            if inert {
                verdict.kept = base;
            }
            ChoiceResult {
                verdict,
                inert,
                choice,
                values,
                base,
                neutral,
                scores: table,
            }
        })
        .collect();
    Ok(Folds {
        logs: logs.iter().map(|l| l.log.display().to_string()).collect(),
        tolerance: TOLERANCE,
        keyframe_spacing_factors: factors.clone(),
        base: (0..loaded.len()).map(|l| score(0, l)).collect(),
        choices: results,
    })
}

/// The log's name for the table: its file name.
fn short(log: &str) -> String {
    Path::new(log)
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| log.to_string())
}

/// The folds as Markdown: per choice, each value's error on each log, each fold's choice and
/// held-out change, and the value kept.
pub fn markdown(f: &Folds) -> String {
    let names: Vec<String> = f.logs.iter().map(|l| short(l)).collect();
    let mut out = String::from("# Leave-one-log-out\n\n");
    out += &format!(
        "Error: mean absolute translational relations error over all relations, m (under 10 s in brackets), the mean of runs with the keyframe spacing scaled by {:?}. A value fails when a fold chose it on the other logs and the held-out log got more than {:.0} % worse than with the neutral value, and by more than the noise (twice the standard error of the difference, from the perturbed runs). The value kept is the best on all logs of the neutral one and those that did not fail.\n\n",
        f.keyframe_spacing_factors,
        100.0 * f.tolerance
    );
    out += "Base configuration: ";
    out += &names
        .iter()
        .zip(&f.base)
        .map(|(n, s)| format!("{n} {:.4} ({:.4})", s.all_m, s.local_m))
        .collect::<Vec<_>>()
        .join(", ");
    out += "\n";
    for c in &f.choices {
        out += &format!("\n## {} (`{}`)\n\n| value |", c.choice.name, c.choice.key);
        for n in &names {
            out += &format!(" {n} |");
        }
        out += "\n|---|";
        out += &"---|".repeat(names.len());
        out += "\n";
        for (index, (v, row)) in c.values.iter().zip(&c.scores).enumerate() {
            let mut tags = Vec::new();
            if index == c.base {
                tags.push("base");
            }
            if index == c.neutral {
                tags.push("neutral");
            }
            if index == c.verdict.kept {
                tags.push("kept");
            }
            let tag = if tags.is_empty() {
                String::new()
            } else {
                format!(" ({})", tags.join(", "))
            };
            out += &format!("| `{v}`{tag} |");
            for s in row {
                out += &format!(" {:.4} ({:.4}) |", s.all_m, s.local_m);
            }
            out += "\n";
        }
        out += "\n| held out | chosen on the others | held-out error | with neutral | change | noise (2 SE) | holds |\n|---|---|---|---|---|---|---|\n";
        for fold in &c.verdict.folds {
            out += &format!(
                "| {} | `{}` | {:.4} | {:.4} | {:+.1} % | {:.4} | {} |\n",
                names[fold.held_out],
                c.values[fold.chosen],
                fold.error,
                fold.neutral_error,
                100.0 * fold.change,
                fold.noise,
                if fold.holds { "yes" } else { "no" }
            );
        }
        out += &format!(
            "\nKept: `{}` (best on all logs: `{}`){}.\n",
            c.values[c.verdict.kept],
            c.values[c.verdict.best_on_all],
            if c.inert {
                "; no value changed anything on these logs, so the base value stays"
            } else {
                ""
            }
        );
    }
    out
}

/// The kept values that differ from the base configuration, as a `[slam]` TOML file for
/// `futago replay --config`.
pub fn chosen_toml(f: &Folds) -> String {
    let mut table = toml::Table::new();
    for c in &f.choices {
        if c.verdict.kept != c.base
            && let Ok(o) =
                crate::overlay::Overlay::assign(&c.choice.key, c.values[c.verdict.kept].clone())
        {
            o.apply(&mut table);
        }
    }
    let body = toml::to_string(&table).unwrap_or_default();
    format!(
        "# SLAM settings where leave-one-log-out keeps another value than the base configuration's\n# (futago folds over {}).\n{body}",
        f.logs
            .iter()
            .map(|l| short(l))
            .collect::<Vec<_>>()
            .join(", ")
    )
}

/// Runs the folds and writes `folds.json`, `folds.md` and `chosen.toml` into `out` (all or
/// nothing); returns the Markdown table.
pub fn run(
    logs: &[LogSpec],
    choice_file: &Path,
    base: &SlamConfig,
    perturbation: f64,
    jobs: usize,
    out: &Path,
    force: bool,
) -> Result<String> {
    crate::output::check_folder(out, force)?;
    let choices = load_choices(choice_file)?;
    let f = folds(logs, &choices, choice_file, base, perturbation, jobs)?;
    let md = markdown(&f);
    crate::run::write_atomically(out, force, "folds", |tmp| {
        std::fs::write(
            tmp.join("folds.json"),
            serde_json::to_string_pretty(&f)? + "\n",
        )
        .context("writing folds.json")?;
        std::fs::write(tmp.join("folds.md"), &md).context("writing folds.md")?;
        std::fs::write(tmp.join("chosen.toml"), chosen_toml(&f)).context("writing chosen.toml")?;
        Ok(())
    })?;
    Ok(md)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// No spread: one run a log.
    fn exact(errors: &[Vec<f64>]) -> Vec<Vec<f64>> {
        errors.iter().map(|r| vec![0.0; r.len()]).collect()
    }

    /// Three logs; value 0 is neutral. Value 1 helps logs 0 and 1 by 10 % and hurts log 2 by
    /// 5 %: the fold that holds out log 2 chooses it and sees it 5 % worse, so it fails. Value
    /// 2 helps every log a little: the best that did not fail, it is kept.
    #[test]
    fn a_value_that_makes_a_held_out_log_worse_than_the_tolerance_fails() {
        let errors = vec![
            vec![1.0, 2.0, 4.0],
            vec![0.9, 1.8, 4.2],
            vec![0.95, 1.9, 3.96],
        ];
        let v = verdict(&errors, &exact(&errors), 0, TOLERANCE);
        // Holding out log 2: on logs 0 and 1, value 1 scores ln 0.9, value 2 ln 0.95.
        assert_eq!(v.folds[2].chosen, 1);
        assert!((v.folds[2].change - 0.05).abs() < 1e-12);
        assert!(!v.folds[2].holds);
        assert_eq!(v.failed, [1]);
        assert_eq!(v.best_on_all, 1);
        assert_eq!(v.kept, 2, "{v:?}");
        // Within the tolerance, value 1 stands and is the best.
        let v = verdict(&errors, &exact(&errors), 0, 0.06);
        assert!(v.failed.is_empty());
        assert_eq!(v.kept, 1);
    }

    /// The same 5 % harm on a log whose perturbed runs spread widely is not a conviction.
    #[test]
    fn harm_within_the_noise_of_a_chaotic_log_does_not_convict() {
        let errors = vec![vec![1.0, 2.0, 4.0], vec![0.9, 1.8, 4.2]];
        let mut spread = exact(&errors);
        spread[0][2] = 0.1;
        spread[1][2] = 0.1;
        // 2 √(0.1² + 0.1²) = 0.28 > 0.2.
        let v = verdict(&errors, &spread, 0, TOLERANCE);
        assert!(v.folds[2].holds && v.failed.is_empty(), "{v:?}");
        assert_eq!(v.kept, 1);
    }

    /// A value that only one log wants is chosen by no fold that holds that log out, and is
    /// not the best on all logs when the others lose by it: the neutral value is kept.
    #[test]
    fn what_only_one_log_wants_and_the_others_lose_by_is_not_a_default() {
        let errors = vec![vec![1.0, 1.0, 1.0], vec![1.3, 1.3, 0.95]];
        let v = verdict(&errors, &exact(&errors), 0, TOLERANCE);
        assert_eq!(v.folds[2].chosen, 0);
        assert_eq!(v.kept, 0);
    }

    /// A value that does nothing ties with the neutral one, and the neutral one is chosen.
    #[test]
    fn a_tie_goes_to_the_neutral_value() {
        let errors = vec![vec![1.0, 2.0], vec![1.0, 2.0]];
        let v = verdict(&errors, &exact(&errors), 1, TOLERANCE);
        assert!(v.folds.iter().all(|f| f.chosen == 1));
        assert_eq!(v.kept, 1);
    }

    /// A value whose run failed to score (no relation matched) is never chosen.
    #[test]
    fn a_value_without_a_score_is_never_chosen() {
        let errors = vec![vec![1.0, 1.0, 1.0], vec![f64::NAN, 0.5, 0.5]];
        let v = verdict(&errors, &exact(&errors), 0, TOLERANCE);
        assert_eq!(v.folds[1].chosen, 0);
        assert_eq!(v.best_on_all, 0);
        assert_eq!(v.kept, 0);
    }

    /// The mean of the perturbed runs and its standard error, by hand: runs 1, 2 and 6 have
    /// mean 3, sample variance 7, standard error √(7/3).
    #[test]
    fn a_log_scores_the_mean_of_its_runs_and_its_standard_error() {
        let run = |m: f64| Score {
            all_m: m,
            local_m: m / 10.0,
            rot_deg: 1.0,
            all_se_m: 0.0,
        };
        let s = mean_score(&[run(1.0), run(2.0), run(6.0)]);
        assert!((s.all_m - 3.0).abs() < 1e-12);
        assert!((s.local_m - 0.3).abs() < 1e-12);
        assert!((s.all_se_m - (7.0f64 / 3.0).sqrt()).abs() < 1e-12);
        assert_eq!(mean_score(&[run(2.0)]).all_se_m, 0.0);
    }
}
