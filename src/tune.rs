//! `futago tune`: searches a scenario's parameters for the best value of one of its metrics.
//!
//! Each parameter is a dotted scenario path with a range (`localization.mcl.sigma_hit=0.05..0.5`,
//! `:log` for a log scale). The search runs in the unit box and maps each candidate onto the
//! ranges as an overlay; a candidate's cost is the metric's mean over the given seeds, so that
//! the search does not fit one noise draw. Candidates of a generation run in parallel, and the
//! search is deterministic for its `--search-seed`: results are taken in candidate order,
//! whatever order the runs finish in. The scenario as written is evaluated first, as the
//! baseline the result is compared with.
//!
//! Writes `best.toml` (an overlay for `futago run --overlay`), `trials.csv` (every candidate,
//! its parameters and per-seed values), `tune.json` and `report.html` (the trials plotted).

use crate::cmaes::{Cmaes, RandomSearch};
use crate::overlay::{Overlay, lookup};
use crate::parallel::parallel_map;
use crate::report::{Series, escape, line_chart_scaled};
use crate::run::{self, RunOptions};
use anyhow::{Context, Result, bail};
use serde_json::{Value, json};
use std::path::{Path, PathBuf};

/// A searched parameter: a scenario path and its range.
#[derive(Debug, Clone, PartialEq)]
pub struct Param {
    pub path: String,
    pub lo: f64,
    pub hi: f64,
    /// Searched on a log scale (both ends positive).
    pub log: bool,
    /// Written as a TOML integer (both ends were written as integers).
    pub integer: bool,
}

impl std::str::FromStr for Param {
    type Err = String;
    fn from_str(s: &str) -> Result<Param, String> {
        let bad = |why: &str| {
            format!(
                "`{s}`: {why}; expected PATH=LO..HI or PATH=LO..HI:log, e.g. localization.mcl.sigma_hit=0.05..0.5"
            )
        };
        let (path, range) = s.split_once('=').ok_or_else(|| bad("no `=`"))?;
        let path = path.trim();
        crate::overlay::split_path(path).map_err(|e| bad(&e))?;
        let (range, log) = match range.trim().strip_suffix(":log") {
            Some(r) => (r, true),
            None => (range.trim(), false),
        };
        let (lo, hi) = range
            .split_once("..")
            .ok_or_else(|| bad("no `..` in the range"))?;
        let integer = [lo, hi].iter().all(|v| v.trim().parse::<i64>().is_ok());
        let (lo, hi): (f64, f64) = (
            lo.trim().parse().map_err(|_| bad("LO is not a number"))?,
            hi.trim().parse().map_err(|_| bad("HI is not a number"))?,
        );
        if !(lo.is_finite() && hi.is_finite() && lo < hi) {
            return Err(bad("LO must be below HI, both finite"));
        }
        if log && lo <= 0.0 {
            return Err(bad("a log scale needs LO > 0"));
        }
        Ok(Param {
            path: path.to_string(),
            lo,
            hi,
            log,
            integer,
        })
    }
}

impl Param {
    /// The value at `u` in [0, 1] of the range.
    pub fn value(&self, u: f64) -> f64 {
        let u = u.clamp(0.0, 1.0);
        let v = if self.log {
            self.lo * (self.hi / self.lo).powf(u)
        } else {
            self.lo + u * (self.hi - self.lo)
        };
        if self.integer { v.round() } else { v }
    }

    /// Where `v` lies in the range, in [0, 1].
    pub fn unit(&self, v: f64) -> f64 {
        let u = if self.log {
            (v / self.lo).ln() / (self.hi / self.lo).ln()
        } else {
            (v - self.lo) / (self.hi - self.lo)
        };
        u.clamp(0.0, 1.0)
    }

    fn toml(&self, v: f64) -> toml::Value {
        if self.integer {
            toml::Value::Integer(v as i64)
        } else {
            toml::Value::Float(v)
        }
    }
}

/// The search method.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Method {
    /// CMA-ES (Hansen 2016).
    Cmaes,
    /// Uniform random search, the baseline.
    Random,
}

/// What `futago tune` was asked.
#[derive(clap::Args)]
pub struct TuneOptions {
    /// Replace the output folder even when it holds files futago did not write.
    #[arg(long)]
    pub force: bool,
    /// A parameter and its range: PATH=LO..HI, or PATH=LO..HI:log for a log scale;
    /// integer ends search integers. Repeatable.
    #[arg(long = "param", value_name = "PATH=LO..HI", required = true)]
    pub params: Vec<Param>,
    /// The metric to optimise, by its name in summary.json (e.g. localization.ate.rmse_m).
    #[arg(long)]
    pub objective: String,
    /// Maximise the objective instead of minimising it.
    #[arg(long)]
    pub maximize: bool,
    /// Candidates to evaluate, besides the scenario as written.
    #[arg(long, default_value_t = 40)]
    pub budget: usize,
    /// Search method.
    #[arg(long, value_enum, default_value = "cmaes")]
    pub method: Method,
    /// Seeds each candidate runs with; its score is the mean over them.
    #[arg(long, value_delimiter = ',', default_value = "1,2,3")]
    pub seeds: Vec<u64>,
    /// Runs at once [default: the number of CPU cores].
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Seed of the search's own random stream.
    #[arg(long, default_value_t = 0)]
    pub search_seed: u64,
}

/// One evaluated candidate.
struct Trial {
    /// 0 is the baseline (the scenario as written).
    index: usize,
    generation: usize,
    /// Parameter values (the scenario's own, where known, for the baseline).
    values: Vec<Option<f64>>,
    /// The objective per seed (`None`: the run failed or did not produce it).
    per_seed: Vec<Option<f64>>,
    /// The mean over seeds; `None` unless every seed produced it.
    objective: Option<f64>,
    error: Option<String>,
}

/// The overlay of a candidate.
fn overlay(params: &[Param], values: &[f64]) -> Result<Overlay> {
    let mut table = toml::Table::new();
    for (p, v) in params.iter().zip(values) {
        Overlay::assign(&p.path, p.toml(*v))?.apply(&mut table);
    }
    Ok(Overlay {
        origin: PathBuf::from("--param"),
        table,
    })
}

/// Checks the search's options against the scenario before any run: parameters named once,
/// a budget and seeds, an objective the scenario produces, and ranges whose ends both give a
/// valid scenario. Gives the scenario with the base overlays.
fn check_options(
    scenario: &Path,
    base: &[Overlay],
    o: &TuneOptions,
) -> Result<crate::scenario::Scenario> {
    if o.params.is_empty() {
        bail!(
            "--param: name at least one parameter to search, e.g. --param localization.mcl.sigma_hit=0.05..0.5"
        );
    }
    if o.budget == 0 {
        bail!("--budget: expected at least 1 candidate");
    }
    if o.seeds.is_empty() {
        bail!("--seeds: expected at least one seed");
    }
    for (i, p) in o.params.iter().enumerate() {
        if o.params[..i].iter().any(|q| q.path == p.path) {
            bail!("--param {}: named twice", p.path);
        }
    }
    let s = crate::stack::load_with(scenario, base)?;
    let names = s.metric_names();
    if !names.contains(&o.objective) {
        let close = crate::ground_truth::similar(&names, &o.objective);
        bail!(
            "--objective: {} produces no metric `{}`{}",
            scenario.display(),
            o.objective,
            if close.is_empty() {
                String::new()
            } else {
                format!("; similar: {close:?}")
            }
        );
    }
    // Every range's ends must make a valid scenario: this catches unknown paths, wrong types
    // and values the scenario refuses before any run.
    for end in [0.0, 1.0] {
        let values: Vec<f64> = o.params.iter().map(|p| p.value(end)).collect();
        let mut all = base.to_vec();
        all.push(overlay(&o.params, &values)?);
        crate::stack::load_with(scenario, &all).map_err(|e| {
            anyhow::anyhow!(
                "--param: the range's {} end does not give a valid scenario: {e}",
                if end == 0.0 { "low" } else { "high" }
            )
        })?;
    }
    Ok(s)
}

/// The trials of a batch of candidates (index, generation, values; none for the scenario's
/// own), from the `results` of their `runs` (candidate, seed): the objective is the mean over
/// the seeds, when every seed produced it.
fn trials_of(
    batch: &[(usize, usize, Option<Vec<f64>>)],
    runs: &[(usize, u64)],
    results: &[Result<f64, String>],
    start_values: &[Option<f64>],
) -> Vec<Trial> {
    batch
        .iter()
        .enumerate()
        .map(|(k, (index, generation, values))| {
            let mine: Vec<&Result<f64, String>> = runs
                .iter()
                .zip(results)
                .filter(|((kk, _), _)| *kk == k)
                .map(|(_, r)| r)
                .collect();
            let per_seed: Vec<Option<f64>> =
                mine.iter().map(|r| r.as_ref().ok().copied()).collect();
            let error = mine.iter().find_map(|r| r.as_ref().err().cloned());
            let objective = if per_seed.iter().all(|v| v.is_some()) {
                Some(per_seed.iter().flatten().sum::<f64>() / per_seed.len() as f64)
            } else {
                None
            };
            Trial {
                index: *index,
                generation: *generation,
                values: match values {
                    Some(v) => v.iter().map(|x| Some(*x)).collect(),
                    None => start_values.to_vec(),
                },
                per_seed,
                objective,
                error,
            }
        })
        .collect()
}

/// Runs the search; writes its files into `out` (created or replaced whole).
pub fn tune(scenario: &Path, base: &[Overlay], o: &TuneOptions, out: &Path) -> Result<Value> {
    crate::output::check_folder(out, o.force)?;
    let s = check_options(scenario, base, o)?;
    let start_values: Vec<Option<f64>> = o
        .params
        .iter()
        .map(|p| {
            lookup(&s.config, &p.path)
                .and_then(|v| v.as_float().or(v.as_integer().map(|i| i as f64)))
        })
        .collect();
    let sign = if o.maximize { -1.0 } else { 1.0 };

    run::write_atomically(out, o.force, "tune", |tmp| {
        let trials_dir = tmp.join("trials");
        let evaluate = |batch: &[(usize, usize, Option<Vec<f64>>)]| -> Vec<Trial> {
            // One run per candidate and seed, all in parallel.
            let runs: Vec<(usize, u64)> = (0..batch.len())
                .flat_map(|k| o.seeds.iter().map(move |&seed| (k, seed)))
                .collect();
            let results = parallel_map(&runs, o.jobs.unwrap_or(1), |_, &(k, seed)| {
                let (index, _, values) = &batch[k];
                let dir = trials_dir
                    .join(format!("{index:04}"))
                    .join(format!("seed-{seed}"));
                evaluate_one(
                    scenario,
                    base,
                    &o.params,
                    values.as_deref(),
                    seed,
                    &o.objective,
                    &dir,
                )
            });
            trials_of(batch, &runs, &results, &start_values)
        };
        let mut trials = evaluate(&[(0, 0, None)]);
        report_progress(&trials, o, 0);
        let start: Vec<f64> = o
            .params
            .iter()
            .zip(&start_values)
            .map(|(p, v)| v.map_or(0.5, |v| p.unit(v)))
            .collect();
        let mut cma = Cmaes::new(&start, 0.3, o.search_seed);
        let mut random = RandomSearch::new(o.params.len(), cma.lambda(), o.search_seed);
        let mut generation = 0;
        while trials.len() - 1 < o.budget {
            generation += 1;
            let left = o.budget - (trials.len() - 1);
            let units = match o.method {
                Method::Cmaes => cma.ask(),
                Method::Random => random.ask(),
            };
            let take = units.len().min(left);
            let batch: Vec<(usize, usize, Option<Vec<f64>>)> = units[..take]
                .iter()
                .enumerate()
                .map(|(k, u)| {
                    let values = o.params.iter().zip(u).map(|(p, x)| p.value(*x)).collect();
                    (trials.len() + k, generation, Some(values))
                })
                .collect();
            let done = evaluate(&batch);
            if o.method == Method::Cmaes && take == units.len() {
                let costs: Vec<f64> = done
                    .iter()
                    .map(|t| t.objective.map_or(f64::NAN, |v| sign * v))
                    .collect();
                cma.tell(&units, &costs);
            }
            trials.extend(done);
            report_progress(&trials, o, generation);
        }
        let best = trials
            .iter()
            .filter(|t| t.objective.is_some())
            .min_by(|a, b| {
                (sign * a.objective.unwrap_or(0.0))
                    .total_cmp(&(sign * b.objective.unwrap_or(0.0)))
                    .then(a.index.cmp(&b.index))
            })
            .context("no candidate produced the objective on every seed; see trials.csv")?;
        let baseline = trials[0].objective;
        let summary = json!({
            "scenario": s.spec.name,
            "file": scenario.display().to_string(),
            "objective": o.objective,
            "direction": if o.maximize { "maximize" } else { "minimize" },
            "method": match o.method { Method::Cmaes => "cmaes", Method::Random => "random" },
            "budget": o.budget,
            "seeds": o.seeds,
            "search_seed": o.search_seed,
            "params": o.params.iter().map(|p| json!({
                "path": p.path, "lo": p.lo, "hi": p.hi, "log": p.log, "integer": p.integer,
            })).collect::<Vec<_>>(),
            "baseline": { "objective": baseline, "values": trials[0].values },
            "search": match o.method {
                Method::Cmaes => json!({
                    "generations": generation,
                    "final_mean": o.params.iter().zip(cma.mean()).map(|(p, u)| p.value(u)).collect::<Vec<_>>(),
                    "final_sigma": cma.sigma(),
                }),
                Method::Random => json!({ "generations": generation }),
            },
            "best": { "trial": best.index, "objective": best.objective, "values": best.values, "per_seed": best.per_seed },
            "trials": trials.iter().map(|t| json!({
                "trial": t.index, "generation": t.generation, "values": t.values,
                "objective": t.objective, "per_seed": t.per_seed, "error": t.error,
            })).collect::<Vec<_>>(),
        });
        let best_values: Vec<f64> = best
            .values
            .iter()
            .zip(&o.params)
            .map(|(v, p)| v.unwrap_or(p.value(0.5)))
            .collect();
        let mut text = format!(
            "# futago tune of {}: {} {} over seeds {:?} by {}, {} candidates.\n# baseline {} -> best {} (trial {}).\n",
            scenario.display(),
            if o.maximize { "maximize" } else { "minimize" },
            o.objective,
            o.seeds,
            summary["method"].as_str().unwrap_or(""),
            o.budget,
            fmt_opt(baseline),
            fmt_opt(best.objective),
            best.index
        );
        text += &toml::to_string(&overlay(&o.params, &best_values)?.table)?;
        std::fs::write(tmp.join("best.toml"), text).context("writing best.toml")?;
        std::fs::write(tmp.join("trials.csv"), csv(&trials, o)).context("writing trials.csv")?;
        std::fs::write(
            tmp.join("tune.json"),
            serde_json::to_string_pretty(&summary)? + "\n",
        )
        .context("writing tune.json")?;
        std::fs::write(tmp.join("report.html"), html(&trials, o, &summary))
            .context("writing report.html")?;
        Ok(summary)
    })
}

fn fmt_opt(v: Option<f64>) -> String {
    v.map_or("none".into(), |v| format!("{v:.6}"))
}

fn report_progress(trials: &[Trial], o: &TuneOptions, generation: usize) {
    let sign = if o.maximize { -1.0 } else { 1.0 };
    let best = trials
        .iter()
        .filter_map(|t| t.objective.map(|v| (v, t.index)))
        .min_by(|a, b| (sign * a.0).total_cmp(&(sign * b.0)));
    eprintln!(
        "tune: generation {generation}, {} of {} candidates, best {} = {}",
        trials.len() - 1,
        o.budget,
        o.objective,
        best.map_or("none".into(), |(v, i)| format!("{v:.6} (trial {i})"))
    );
}

/// Runs one candidate on one seed, scored in memory, and gives its objective; writes only the
/// run's summary and scenario into `dir`, so that long searches do not fill the disk.
fn evaluate_one(
    scenario: &Path,
    base: &[Overlay],
    params: &[Param],
    values: Option<&[f64]>,
    seed: u64,
    objective: &str,
    dir: &Path,
) -> Result<f64, String> {
    let mut all = base.to_vec();
    if let Some(v) = values {
        all.push(overlay(params, v).map_err(|e| format!("{e:#}"))?);
    }
    // The CARMEN log is not scored; a search does not need it.
    all.push(Overlay::parse_set("output.carmen=false").map_err(|e| e.to_string())?);
    let s = crate::stack::load_with(scenario, &all).map_err(|e| e.to_string())?;
    let opts = RunOptions {
        seed: Some(seed),
        duration: None,
        progress: false,
        report: false,
        force: false,
    };
    // Scored in memory; the trial keeps its summary (no files listed: none were written)
    // and the scenario as run, to rerun it.
    let scored = crate::serve::evaluate_scenario(&s, &opts).map_err(|e| format!("{e:#}"))?;
    let summary =
        run::Summary::new(&s, &scored, Default::default()).with_performance(&scored.outcome);
    std::fs::create_dir_all(dir)
        .and_then(|()| std::fs::write(dir.join(run::SUMMARY_FILE), summary.text()))
        .and_then(|()| std::fs::write(dir.join(run::SCENARIO_FILE), run::scenario_text(&s)))
        .map_err(|e| format!("writing {}: {e}", dir.display()))?;
    scored
        .metrics
        .0
        .get(objective)
        .copied()
        .ok_or_else(|| format!("the run produced no {objective}"))
}

fn csv(trials: &[Trial], o: &TuneOptions) -> String {
    let mut text = String::from("trial,generation");
    for p in &o.params {
        text += &format!(",{}", p.path);
    }
    text += &format!(",{}", o.objective);
    for s in &o.seeds {
        text += &format!(",seed_{s}");
    }
    text += ",error\n";
    let cell = |v: &Option<f64>| v.map_or(String::new(), |v| format!("{v}"));
    for t in trials {
        text += &format!("{},{}", t.index, t.generation);
        for v in &t.values {
            text += &format!(",{}", cell(v));
        }
        text += &format!(",{}", cell(&t.objective));
        for v in &t.per_seed {
            text += &format!(",{}", cell(v));
        }
        let err = t.error.as_deref().unwrap_or("").replace('"', "'");
        text += &format!(",\"{}\"\n", err.lines().next().unwrap_or(""));
    }
    text
}

fn html(trials: &[Trial], o: &TuneOptions, summary: &Value) -> String {
    let sign = if o.maximize { -1.0 } else { 1.0 };
    let points: Vec<[f64; 2]> = trials
        .iter()
        .filter_map(|t| t.objective.map(|v| [t.index as f64, v]))
        .collect();
    let mut best_so_far = Vec::new();
    let mut best = f64::INFINITY;
    for p in &points {
        if sign * p[1] < best {
            best = sign * p[1];
        }
        best_so_far.push([p[0], sign * best]);
    }
    let mut body = format!(
        "<h1>futago tune: {}</h1>\n<p>{} <code>{}</code> over seeds {:?} by {}; baseline {} → best {} (trial {}).</p>\n<figure>\n",
        escape(summary["scenario"].as_str().unwrap_or("")),
        if o.maximize { "Maximise" } else { "Minimise" },
        escape(&o.objective),
        o.seeds,
        summary["method"].as_str().unwrap_or(""),
        fmt_opt(summary["baseline"]["objective"].as_f64()),
        fmt_opt(summary["best"]["objective"].as_f64()),
        summary["best"]["trial"]
    );
    // A log scale where the scores are positive and spread over more than a decade, so that
    // failed candidates do not flatten the good ones.
    let (lo, hi) = points
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p[1]), b.max(p[1])));
    let log_y = lo > 0.0 && hi / lo > 20.0;
    body += &line_chart_scaled(
        "Objective of every trial",
        "trial",
        &o.objective,
        &[
            Series {
                name: "trial".into(),
                colour: "#2c7bb6",
                points: points.clone(),
                markers: true,
            },
            Series {
                name: "best so far".into(),
                colour: "#d7191c",
                points: best_so_far,
                markers: false,
            },
        ],
        [false, log_y],
    );
    for (k, p) in o.params.iter().enumerate() {
        let pts: Vec<[f64; 2]> = trials
            .iter()
            .filter_map(|t| Some([t.values[k]?, t.objective?]))
            .collect();
        body += &line_chart_scaled(
            &format!("Objective against {}", p.path),
            &p.path,
            &o.objective,
            &[Series {
                name: "trial".into(),
                colour: "#7b3294",
                points: pts,
                markers: true,
            }],
            [p.log, log_y],
        );
    }
    body += "</figure>\n<h2>Trials</h2>\n<table class=\"trials\"><thead><tr><th>trial</th><th>generation</th>";
    for p in &o.params {
        body += &format!("<th>{}</th>", escape(&p.path));
    }
    body += &format!(
        "<th>{}</th><th>error</th></tr></thead><tbody>\n",
        escape(&o.objective)
    );
    for t in trials {
        body += &format!("<tr><td>{}</td><td>{}</td>", t.index, t.generation);
        for v in &t.values {
            body += &format!("<td>{}</td>", v.map_or("—".into(), |v| format!("{v:.6}")));
        }
        body += &format!(
            "<td>{}</td><td>{}</td></tr>\n",
            fmt_opt(t.objective),
            escape(t.error.as_deref().unwrap_or(""))
        );
    }
    body += "</tbody></table>\n";
    crate::report::page("futago tune", &body)
}

/// Prints the one-line result of `futago tune` (`tune.json`'s content).
pub fn print(s: &Value, out: &Path) {
    println!(
        "tune: {} {}: baseline {} -> best {} (trial {} of {}); best parameters in {}",
        s["direction"].as_str().unwrap_or(""),
        s["objective"].as_str().unwrap_or(""),
        s["baseline"]["objective"],
        s["best"]["objective"],
        s["best"]["trial"],
        s["budget"],
        out.join("best.toml").display()
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn params_parse_ranges_scales_and_integers() {
        let p: Param = "localization.mcl.sigma_hit=0.05..0.5".parse().unwrap();
        assert_eq!((p.lo, p.hi, p.log, p.integer), (0.05, 0.5, false, false));
        assert!((p.value(0.5) - 0.275).abs() < 1e-12);
        assert!((p.unit(0.275) - 0.5).abs() < 1e-12);
        let q: Param = "localization.mcl.particles=100..10000:log".parse().unwrap();
        assert!(q.log && q.integer);
        assert_eq!(q.value(0.5), 1000.0);
        assert!((q.unit(1000.0) - 0.5).abs() < 1e-12);
        for bad in [
            "x",
            "a.b=1",
            "a.b=2..1",
            "a.b=0..1:log",
            "a[0].b=0..1",
            "a.b=x..1",
        ] {
            assert!(bad.parse::<Param>().is_err(), "{bad}");
        }
    }
}
