//! `futago suite`: many scenarios at once, in parallel, with their gates collected into
//! `suite.json` and a JUnit XML report (one test case per scenario run and per gate) that CI
//! services show natively.
//!
//! Every scenario is loaded and checked before the first one runs. Each run is deterministic for
//! its seed, and writes into its own folder, `OUT/<scenario file stem>/`. So the number of
//! parallel jobs changes the wall time only, never the results. `--shard K/N` keeps every N-th
//! scenario from the K-th (in sorted order), so that N machines split a suite between them.
//! A scenario file with a `[twin]` table is a twin scenario ([`crate::twin::scenario`]): the
//! calibration and twin of a real log, gated as a scenario is.

use crate::overlay::Overlay;
use crate::parallel::parallel_map;
use crate::report::escape;
use crate::run::{self, RunOptions};
use crate::scenario::Scenario;
use anyhow::{Context, Result, bail};
use serde_json::{Value, json};
use std::path::{Path, PathBuf};

/// Which part of a suite this machine runs: `k` of `n`, 1-based.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    pub k: usize,
    pub n: usize,
}

impl std::str::FromStr for Shard {
    type Err = String;
    fn from_str(s: &str) -> Result<Shard, String> {
        let bad = || format!("`{s}`: expected K/N with 1 ≤ K ≤ N, e.g. 2/4");
        let (k, n) = s.split_once('/').ok_or_else(bad)?;
        let (k, n): (usize, usize) = (
            k.trim().parse().map_err(|_| bad())?,
            n.trim().parse().map_err(|_| bad())?,
        );
        if k == 0 || n == 0 || k > n {
            return Err(bad());
        }
        Ok(Shard { k, n })
    }
}

/// The scenario files named by `paths`: files as given, folders' `*.toml` files, sorted.
pub fn collect(paths: &[PathBuf]) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for p in paths {
        if p.is_dir() {
            let mut here: Vec<PathBuf> = std::fs::read_dir(p)
                .with_context(|| format!("reading {}", p.display()))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|f| f.extension().is_some_and(|x| x == "toml"))
                .collect();
            here.sort();
            files.extend(here);
        } else if p.is_file() {
            files.push(p.clone());
        } else {
            bail!("{}: no such scenario file or folder", p.display());
        }
    }
    if files.is_empty() {
        bail!(
            "the suite is empty: no scenario files (*.toml) in {}",
            paths
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    Ok(files)
}

/// One scenario run's outcome in a suite.
struct Entry {
    file: PathBuf,
    /// The run's name and folder under the suite's: the scenario file's stem, then
    /// `/seed-N` for the runs of a seed sweep.
    name: String,
    /// The scenario file's stem and the seed, for the runs of a sweep.
    sweep: Option<(String, u64)>,
    /// The run's summary, or the error that stopped it.
    result: Result<Value, String>,
    /// The crashes of its earlier tries, when it was isolated and retried (see
    /// [`CRASH_RETRIES`]).
    crashes: Vec<String>,
    /// The scenario's gates against other scenarios' runs (`[[gate]] scenario = …`).
    versus: Vec<crate::ground_truth::Gate>,
}

/// One run to do: a scenario, and the seed of a sweep.
struct Job {
    file: PathBuf,
    stem: String,
    work: Work,
    seed: Option<u64>,
}

/// What a suite's run is: a scenario in a simulated world, or the twin of a real log.
enum Work {
    Scenario(Box<Scenario>),
    Twin(crate::twin::scenario::TwinScenario),
}

impl Job {
    /// The simulated seconds the run may cover (a scenario's `duration`), as the suite's
    /// guess of its cost; a twin's length is not known before it runs.
    fn length(&self) -> f64 {
        match &self.work {
            Work::Scenario(s) => s.spec.duration,
            Work::Twin(_) => f64::INFINITY,
        }
    }

    fn name(&self) -> String {
        match self.seed {
            Some(s) => format!("{}/seed-{s}", self.stem),
            None => self.stem.clone(),
        }
    }
}

/// The runs of the scenario `files`, with `overlays` laid over each: one per seed of a sweep,
/// every file loaded and checked.
fn load_jobs(files: &[PathBuf], overlays: &[Overlay]) -> Result<Vec<Job>> {
    let mut runs = Vec::new();
    let mut stems = std::collections::BTreeSet::new();
    for f in files {
        let stem = f
            .file_stem()
            .map(|s| s.to_string_lossy().to_string())
            .unwrap_or_default();
        if !stems.insert(stem.clone()) {
            bail!(
                "{}: two scenario files are named `{stem}`; their results would share a folder",
                f.display()
            );
        }
        if crate::twin::scenario::is_twin_file(f) {
            if !overlays.is_empty() {
                bail!(
                    "{}: a twin scenario takes no --overlay or --set; run it in a suite of its own",
                    f.display()
                );
            }
            runs.push(Job {
                file: f.clone(),
                stem,
                work: Work::Twin(crate::twin::scenario::load(f)?),
                seed: None,
            });
            continue;
        }
        let s = crate::stack::load_with(f, overlays)?;
        let seeds: Vec<Option<u64>> = if s.spec.seeds.is_empty() {
            vec![None]
        } else {
            s.spec.seeds.iter().map(|&k| Some(k)).collect()
        };
        for seed in seeds {
            runs.push(Job {
                file: f.clone(),
                stem: stem.clone(),
                work: Work::Scenario(Box::new(s.clone())),
                seed,
            });
        }
    }
    Ok(runs)
}

/// Runs the suite, with `overlays` laid over every scenario, and writes `out/suite.json` and
/// `out/junit.xml` beside each run's folder; returns the suite summary. A scenario with
/// `seeds` is one run per seed; shards split the runs, so a sweep may span machines.
pub fn suite(
    paths: &[PathBuf],
    overlays: &[Overlay],
    jobs: usize,
    shard: Option<Shard>,
    out: &Path,
    force: bool,
    isolate: Option<&Isolation>,
) -> Result<Value> {
    crate::output::check_folder(out, force)?;
    let files = collect(paths)?;
    // Check everything before anything runs.
    let runs = load_jobs(&files, overlays)?;
    let runs: Vec<Job> = match shard {
        Some(s) => runs
            .into_iter()
            .enumerate()
            .filter(|(i, _)| i % s.n == s.k - 1)
            .map(|(_, r)| r)
            .collect(),
        None => runs,
    };
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    // A suite that left its flag behind ended without writing its results: a crash (or a
    // kill). This one runs each scenario in a process of its own, so that it cannot again.
    let flag = out.join(RUNNING_FLAG);
    let crashed_before = flag.exists();
    if crashed_before {
        crate::output::remove_partials(out);
    }
    let isolation = match (isolate, crashed_before) {
        (Some(i), _) => Some(i.clone()),
        (None, true) => {
            eprintln!(
                "futago: the last suite in {} ended without writing its results (a crash?): running each scenario in a process of its own, as --isolate does",
                out.display()
            );
            Some(Isolation::default())
        }
        (None, false) => None,
    };
    std::fs::write(&flag, format!("{}\n", std::process::id()))
        .with_context(|| format!("writing {}", flag.display()))?;
    crate::output::mark(out, "suite")?;
    let started = std::time::Instant::now();
    let bar = indicatif::ProgressBar::new(runs.len() as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{spinner} suite [{bar:40}] {pos}/{len} {msg}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    if !std::io::IsTerminal::is_terminal(&std::io::stderr()) {
        bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    // The longest runs start first (longest processing time first): in the files' order the
    // suite's two longest coverage runs started 17 and 27 minutes in and ran on alone at its
    // end. The order changes when each run starts, not what it computes; the entries keep
    // the files' order.
    let order = start_order(&runs.iter().map(Job::length).collect::<Vec<_>>());
    let started_first = parallel_map(&order, jobs, |_, &k| {
        let job = &runs[k];
        let opts = RunOptions {
            seed: job.seed,
            duration: None,
            progress: false,
            report: true,
            force,
        };
        let name = job.name();
        let mut crashes = Vec::new();
        let result = match (&isolation, &job.work) {
            (Some(i), _) => run_isolated(job, i, &out.join(&name), force, &name, &mut crashes),
            (None, Work::Scenario(s)) => crate::serve::run_scenario(s, &opts, &out.join(&name))
                .map(|(summary, _)| summary)
                .map_err(|e| format!("{e:#}")),
            // The suite's jobs already share the cores: a twin's seeds run one at a time.
            (None, Work::Twin(t)) => crate::twin::scenario::run(t, &out.join(&name), force, 1)
                .map_err(|e| format!("{e:#}")),
        };
        bar.inc(1);
        bar.set_message(name.clone());
        Entry {
            file: job.file.clone(),
            name,
            sweep: job.seed.map(|k| (job.stem.clone(), k)),
            result,
            crashes,
            versus: match &job.work {
                Work::Scenario(s) => s
                    .spec
                    .gate
                    .iter()
                    .filter(|g| g.scenario.is_some())
                    .cloned()
                    .collect(),
                Work::Twin(_) => Vec::new(),
            },
        }
    });
    let mut entries: Vec<Option<Entry>> = (0..runs.len()).map(|_| None).collect();
    for (k, e) in order.into_iter().zip(started_first) {
        entries[k] = Some(e);
    }
    let entries: Vec<Entry> = entries.into_iter().flatten().collect();
    bar.finish_and_clear();
    let wall = started.elapsed().as_secs_f64();
    let summary = summarise(&entries, shard, jobs, wall);
    let dirs: Vec<PathBuf> = entries.iter().map(|e| out.join(&e.name)).collect();
    write_reports(out, &summary, &dirs)?;
    let _ = std::fs::remove_file(&flag);
    crate::output::mark(out, "suite")?;
    Ok(summary)
}

/// The order in which to start runs of these lengths: longest first, equal lengths in their
/// given order.
fn start_order(lengths: &[f64]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..lengths.len()).collect();
    order.sort_by(|&a, &b| lengths[b].total_cmp(&lengths[a]));
    order
}

/// The file a suite keeps in its folder while it runs: found at the start of the next suite,
/// it says the last one crashed.
const RUNNING_FLAG: &str = ".suite-running";

/// Each run of a suite in a child `futago run`: a crash (a segfault in a driver, an abort)
/// is then that run's error, and the suite's other results are kept. The child is given the
/// suite's `--overlay` and `--set` arguments.
#[derive(Debug, Clone, Default)]
pub struct Isolation {
    pub overlay_args: Vec<String>,
}

/// How many times an isolated run that crashed (was killed by a signal) is run again. A run is
/// deterministic for its seed, so a retry that completes writes exactly what the first try
/// would have: the retry costs time, never correctness. Crashes seen so far came from the GPU
/// driver, intermittently (a SIGSEGV in one of 51 runs of CI's suite, not reproduced in a
/// local suite of the same build).
pub const CRASH_RETRIES: usize = 1;

/// Runs `job` in a child process ([`run_child`]); a crash is retried [`CRASH_RETRIES`] times,
/// each crash reported on stderr and pushed to `crashes`, and the last is the run's error.
fn run_isolated(
    job: &Job,
    iso: &Isolation,
    dir: &Path,
    force: bool,
    name: &str,
    seen: &mut Vec<String>,
) -> Result<Value, String> {
    let mut crashes = 0;
    loop {
        match run_child(job, iso, dir, force) {
            Child::Ended(r) => {
                if crashes > 0 && r.is_ok() {
                    eprintln!(
                        "futago: run {name} completed on try {} after crashing",
                        crashes + 1
                    );
                }
                return r;
            }
            Child::Crashed(what) => {
                crashes += 1;
                seen.push(what.clone());
                if crashes > CRASH_RETRIES {
                    return Err(format!(
                        "the run crashed ({what}){}; nothing of it was written, the suite's other runs are kept",
                        if crashes > 1 {
                            format!(", on each of {crashes} tries")
                        } else {
                            String::new()
                        }
                    ));
                }
                eprintln!("futago: run {name} crashed ({what}); running it again");
            }
        }
    }
}

/// How a child run ended: by itself (its summary or its error), or killed by a signal.
enum Child {
    Ended(Result<Value, String>),
    /// The signal, named (`signal 11, SIGSEGV, core dumped`).
    Crashed(String),
}

/// Runs `job` as a child `futago run` into `dir`: its summary, its error, or the signal that
/// killed it. What a killed child half wrote (its `.NAME.partial-PID` folder) is removed.
fn run_child(job: &Job, iso: &Isolation, dir: &Path, force: bool) -> Child {
    let exe = match std::env::current_exe() {
        Ok(e) => e,
        Err(e) => return Child::Ended(Err(format!("finding the futago program: {e}"))),
    };
    let mut cmd = std::process::Command::new(exe);
    cmd.arg("run")
        .arg(&job.file)
        .arg("--out")
        .arg(dir)
        .arg("-q")
        .args(&iso.overlay_args);
    if let Some(k) = job.seed {
        cmd.args(["--seed", &k.to_string()]);
    }
    if force {
        cmd.arg("--force");
    }
    let child = cmd
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn();
    let (pid, o) = match child {
        Ok(c) => (c.id(), c.wait_with_output()),
        Err(e) => return Child::Ended(Err(format!("starting a child futago: {e}"))),
    };
    let o = match o {
        Ok(o) => o,
        Err(e) => return Child::Ended(Err(format!("waiting for a child futago: {e}"))),
    };
    let stderr = String::from_utf8_lossy(&o.stderr);
    match o.status.code() {
        // 3: the run wrote its results and a gate failed, which the suite scores itself.
        Some(0) | Some(run::GATE_FAILED) => {
            let p = dir.join("summary.json");
            Child::Ended(
                std::fs::read_to_string(&p)
                    .map_err(|e| format!("reading {}: {e}", p.display()))
                    .and_then(|text| {
                        serde_json::from_str(&text)
                            .map_err(|e| format!("reading {}: {e}", p.display()))
                    }),
            )
        }
        Some(c) => Child::Ended(Err(stderr
            .lines()
            .filter_map(|l| l.strip_prefix("futago: error: "))
            .next_back()
            .map(str::to_string)
            .unwrap_or_else(|| {
                format!("the run exited with status {c}: {}", stderr.trim())
            }))),
        None => {
            use std::os::unix::process::ExitStatusExt;
            if let (Some(parent), Some(name)) = (dir.parent(), dir.file_name()) {
                let partial = parent.join(format!(".{}.partial-{pid}", name.to_string_lossy()));
                let _ = std::fs::remove_dir_all(partial);
            }
            let sig = o.status.signal().unwrap_or(0);
            let name = match sig {
                4 => "SIGILL",
                6 => "SIGABRT",
                7 => "SIGBUS",
                8 => "SIGFPE",
                9 => "SIGKILL",
                11 => "SIGSEGV",
                _ => "a signal",
            };
            Child::Crashed(format!(
                "signal {sig}, {name}{}",
                if o.status.core_dumped() {
                    ", core dumped"
                } else {
                    ""
                }
            ))
        }
    }
}

/// A run's gates, with its gates against other scenarios' runs of the suite: the run of
/// that scenario (its file's stem) with the same seed.
fn gates(e: &Entry, entries: &[Entry]) -> Vec<Value> {
    let Ok(s) = &e.result else {
        return Vec::new();
    };
    let mut out = s["gates"].as_array().cloned().unwrap_or_default();
    let metrics = |e: &Entry| -> Option<crate::ground_truth::Metrics> {
        let m = e.result.as_ref().ok()?["metrics"].as_object()?.clone();
        Some(crate::ground_truth::Metrics(
            m.into_iter()
                .filter_map(|(k, v)| Some((k, v.as_f64()?)))
                .collect(),
        ))
    };
    let stem = |e: &Entry| {
        e.file
            .file_stem()
            .map(|f| f.to_string_lossy().to_string())
            .unwrap_or_default()
    };
    let seed = |e: &Entry| e.sweep.as_ref().map(|(_, k)| *k);
    let own = metrics(e).unwrap_or_default();
    for g in &e.versus {
        let other = entries
            .iter()
            .find(|o| Some(stem(o)) == g.scenario && seed(o) == seed(e))
            .and_then(metrics);
        let r = crate::ground_truth::evaluate_versus(g, &own, other.as_ref());
        out.push(serde_json::to_value(r).unwrap_or_default());
    }
    out
}

fn summarise(entries: &[Entry], shard: Option<Shard>, jobs: usize, wall: f64) -> Value {
    let results: Vec<Value> = entries
        .iter()
        .map(|e| {
            let g = gates(e, entries);
            let failed = g.iter().filter(|r| r["passed"] == false).count();
            json!({
                "scenario": e.name,
                "file": e.file.display().to_string(),
                "sweep": e.sweep.as_ref().map(|(stem, _)| stem),
                "seed": e.sweep.as_ref().map(|(_, k)| k),
                "status": match (&e.result, failed) {
                    (Err(_), _) => "error",
                    (Ok(_), 0) => "passed",
                    _ => "failed",
                },
                "error": e.result.as_ref().err(),
                "crashes": e.crashes,
                "gates": g,
                "metrics": e.result.as_ref().ok().map(|s| s["metrics"].clone()),
                "sim_time_s": e.result.as_ref().ok().map(|s| s["sim_time_s"].clone()),
                "wall_time_s": e.result.as_ref().ok().map(|s| s["performance"]["wall_time_s"].clone()),
            })
        })
        .collect();
    totals(
        results,
        shard.map(|s| format!("{}/{}", s.k, s.n)),
        Some(jobs),
        wall,
    )
}

/// JUnit XML from a suite's results: a test suite per scenario, with a `run` case (an error
/// when the run failed) and a case per gate (a failure when it did not hold).
fn junit(results: &[Value], wall: f64) -> String {
    let mut cases_total = 0;
    let mut failures_total = 0;
    let mut errors_total = 0;
    let mut body = String::new();
    for r in results {
        let name = r["scenario"].as_str().unwrap_or("");
        let g = r["gates"].as_array().cloned().unwrap_or_default();
        let time = r["wall_time_s"].as_f64().unwrap_or(0.0);
        let failures = g.iter().filter(|r| r["passed"] == false).count();
        let error = r["error"].as_str();
        let errors = error.is_some() as usize;
        cases_total += 1 + g.len();
        failures_total += failures;
        errors_total += errors;
        body += &format!(
            "  <testsuite name=\"{}\" tests=\"{}\" failures=\"{failures}\" errors=\"{errors}\" time=\"{time:.3}\">\n",
            escape(name),
            1 + g.len()
        );
        body += &format!(
            "    <testcase classname=\"{0}\" name=\"run\" time=\"{time:.3}\">",
            escape(name)
        );
        if let Some(msg) = error {
            body += &format!(
                "\n      <error message=\"{}\">{}</error>\n    ",
                escape(msg.lines().next().unwrap_or("")),
                escape(msg)
            );
        }
        body += "</testcase>\n";
        for r in &g {
            let case = format!(
                "{} {} {}",
                r["metric"].as_str().unwrap_or(""),
                r["op"].as_str().unwrap_or(""),
                r["threshold"]
            );
            let msg = r["message"].as_str().unwrap_or("");
            body += &format!(
                "    <testcase classname=\"{}.gates\" name=\"{}\" time=\"0\">",
                escape(name),
                escape(&case)
            );
            if r["passed"] == false {
                body += &format!(
                    "\n      <failure message=\"{0}\" type=\"gate\">{0}</failure>\n    ",
                    escape(msg)
                );
            }
            body += "</testcase>\n";
        }
        body += "  </testsuite>\n";
    }
    format!(
        "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<testsuites name=\"futago\" tests=\"{cases_total}\" failures=\"{failures_total}\" errors=\"{errors_total}\" time=\"{wall:.3}\">\n{body}</testsuites>\n"
    )
}

/// `to` relative to the folder `from` (both made absolute), for links between reports.
fn relative(from: &Path, to: &Path) -> Option<String> {
    let abs = |p: &Path| -> Option<Vec<String>> {
        let p = std::path::absolute(p).ok()?;
        let mut parts: Vec<String> = Vec::new();
        for c in p.components() {
            match c {
                std::path::Component::ParentDir => {
                    parts.pop();
                }
                std::path::Component::CurDir => {}
                c => parts.push(c.as_os_str().to_string_lossy().to_string()),
            }
        }
        Some(parts)
    };
    let (f, t) = (abs(from)?, abs(to)?);
    let common = f.iter().zip(&t).take_while(|(a, b)| a == b).count();
    let mut parts = vec!["..".to_string(); f.len() - common];
    parts.extend(t[common..].iter().cloned());
    Some(parts.join("/"))
}

/// Writes `suite.json`, `junit.xml` and `report.html` into `out`, each whole (written beside,
/// then renamed). `run_dirs[k]` is the folder of result `k`, for the report's links.
fn write_reports(out: &Path, summary: &Value, run_dirs: &[PathBuf]) -> Result<()> {
    let results = summary["results"].as_array().cloned().unwrap_or_default();
    let wall = summary["wall_time_s"].as_f64().unwrap_or(0.0);
    let links: Vec<Option<String>> = run_dirs
        .iter()
        .map(|d| {
            let page = d.join(run::REPORT_FILE);
            page.is_file().then(|| relative(out, &page)).flatten()
        })
        .collect();
    for (name, text) in [
        ("suite.json", serde_json::to_string_pretty(summary)? + "\n"),
        ("junit.xml", junit(&results, wall)),
        ("report.html", crate::report::suite_report(summary, &links)),
    ] {
        let tmp = out.join(format!(".{name}.partial"));
        std::fs::write(&tmp, text).with_context(|| format!("writing {}", tmp.display()))?;
        std::fs::rename(&tmp, out.join(name))
            .with_context(|| format!("writing {}", out.join(name).display()))?;
    }
    Ok(())
}

/// Counts and throughput over a suite's results.
fn totals(results: Vec<Value>, shard: Option<String>, jobs: Option<usize>, wall: f64) -> Value {
    let count = |st: &str| results.iter().filter(|s| s["status"] == st).count();
    json!({
        "scenarios": results.len(),
        "passed": count("passed"),
        "failed": count("failed"),
        "errors": count("error"),
        "shard": shard,
        "jobs": jobs,
        "wall_time_s": wall,
        "scenarios_per_minute": if wall > 0.0 { results.len() as f64 * 60.0 / wall } else { 0.0 },
        "sweeps": sweeps(&results),
        "results": results,
    })
}

/// The mean and spread of every metric over the seeds of each swept scenario: for each, the
/// seeds that ran and, per metric, `mean`, `std` (sample standard deviation, n − 1), `min`,
/// `max` and `n` (the runs that produced it).
fn sweeps(results: &[Value]) -> Value {
    let mut groups: std::collections::BTreeMap<&str, Vec<&Value>> = Default::default();
    for r in results {
        if let Some(stem) = r["sweep"].as_str() {
            groups.entry(stem).or_default().push(r);
        }
    }
    let mut out = serde_json::Map::new();
    for (stem, runs) in groups {
        let mut values: std::collections::BTreeMap<String, Vec<f64>> = Default::default();
        for r in &runs {
            for (k, v) in r["metrics"].as_object().into_iter().flatten() {
                if let Some(v) = v.as_f64() {
                    values.entry(k.clone()).or_default().push(v);
                }
            }
        }
        let metrics: serde_json::Map<String, Value> =
            values.into_iter().map(|(k, v)| (k, spread(&v))).collect();
        out.insert(
            stem.to_string(),
            json!({
                "seeds": runs.iter().map(|r| r["seed"].clone()).collect::<Vec<_>>(),
                "passed": runs.iter().filter(|r| r["status"] == "passed").count(),
                "metrics": metrics,
            }),
        );
    }
    Value::Object(out)
}

/// Mean, sample standard deviation, min, max and count of some values.
pub fn spread(v: &[f64]) -> Value {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let std = if v.len() > 1 {
        (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
    } else {
        0.0
    };
    json!({
        "mean": mean,
        "std": std,
        "min": v.iter().copied().fold(f64::INFINITY, f64::min),
        "max": v.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        "n": v.len(),
    })
}

/// `futago merge`: joins the `suite.json` of several shards into one suite, with its JUnit
/// file; the wall time is the longest shard's (they ran side by side).
pub fn merge(shards: &[PathBuf], out: &Path, force: bool) -> Result<Value> {
    if shards.is_empty() {
        bail!("nothing to merge: name the output folders of the shards");
    }
    crate::output::check_folder(out, force)?;
    let mut results = Vec::new();
    let mut wall = 0.0f64;
    let mut seen = std::collections::BTreeSet::new();
    let mut dirs = std::collections::BTreeMap::new();
    for d in shards {
        let p = d.join("suite.json");
        let text =
            std::fs::read_to_string(&p).with_context(|| format!("reading {}", p.display()))?;
        let v: Value = serde_json::from_str(&text)
            .with_context(|| format!("{}: not a futago suite.json", p.display()))?;
        let Some(rs) = v["results"].as_array() else {
            bail!(
                "{}: key `results`: expected a list of scenario results",
                p.display()
            );
        };
        for r in rs {
            let name = r["scenario"].as_str().unwrap_or("").to_string();
            dirs.insert(name.clone(), d.join(&name));
            if !seen.insert(name.clone()) {
                bail!(
                    "{}: scenario `{name}` is in more than one shard",
                    p.display()
                );
            }
            results.push(r.clone());
        }
        wall = wall.max(v["wall_time_s"].as_f64().unwrap_or(0.0));
    }
    results.sort_by(|a, b| a["scenario"].as_str().cmp(&b["scenario"].as_str()));
    let run_dirs: Vec<PathBuf> = results
        .iter()
        .map(|r| dirs[r["scenario"].as_str().unwrap_or("")].clone())
        .collect();
    let summary = totals(results, None, None, wall);
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    write_reports(out, &summary, &run_dirs)?;
    crate::output::mark(out, "merge")?;
    Ok(summary)
}

/// Prints a suite's results (`suite.json`'s content) and gives the command's exit status: 1
/// when a run failed, [`run::GATE_FAILED`] when a gate did, else 0.
pub fn print(s: &Value, out: &Path) -> i32 {
    for r in s["results"].as_array().into_iter().flatten() {
        let status = r["status"].as_str().unwrap_or("");
        println!("{status:>6}  {}", r["scenario"].as_str().unwrap_or(""));
        for g in r["gates"].as_array().into_iter().flatten() {
            if g["passed"] == false {
                println!(
                    "        gate failed: {}",
                    g["message"].as_str().unwrap_or("")
                );
            }
        }
        if let Some(e) = r["error"].as_str() {
            println!("        error: {e}");
        }
    }
    for (stem, sw) in s["sweeps"].as_object().into_iter().flatten() {
        let seeds = sw["seeds"].as_array().map_or(0, |a| a.len());
        let mut line = format!("sweep  {stem}: {} of {seeds} seeds passed", sw["passed"]);
        let gated: std::collections::BTreeSet<&str> = s["results"]
            .as_array()
            .into_iter()
            .flatten()
            .filter(|r| r["sweep"].as_str() == Some(stem))
            .flat_map(|r| r["gates"].as_array().into_iter().flatten())
            .filter_map(|g| g["metric"].as_str())
            .collect();
        for m in gated {
            let v = &sw["metrics"][m];
            if let (Some(mean), Some(std)) = (v["mean"].as_f64(), v["std"].as_f64()) {
                line += &format!("; {m} {mean:.4} ± {std:.4}");
            }
        }
        println!("{line}");
    }
    println!(
        "suite: {} scenarios, {} passed, {} failed, {} errors in {:.1} s ({:.1} per minute{}); results in {}",
        s["scenarios"],
        s["passed"],
        s["failed"],
        s["errors"],
        s["wall_time_s"].as_f64().unwrap_or(0.0),
        s["scenarios_per_minute"].as_f64().unwrap_or(0.0),
        s["jobs"]
            .as_u64()
            .map(|j| format!(", {j} jobs"))
            .unwrap_or_default(),
        out.display()
    );
    if s["errors"].as_u64().unwrap_or(0) > 0 {
        1
    } else if s["failed"].as_u64().unwrap_or(0) > 0 {
        run::GATE_FAILED
    } else {
        0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sweeps_give_mean_and_sample_spread_per_metric() {
        let run = |seed: u64, ate: f64, status: &str| {
            json!({ "scenario": format!("a/seed-{seed}"), "sweep": "a", "seed": seed,
                    "status": status, "metrics": { "slam.ate.rmse_m": ate } })
        };
        let results = vec![
            run(1, 0.1, "passed"),
            run(2, 0.2, "failed"),
            run(3, 0.6, "passed"),
            json!({ "scenario": "b", "sweep": null, "status": "passed", "metrics": { "x": 1.0 } }),
        ];
        let s = sweeps(&results);
        let m = &s["a"]["metrics"]["slam.ate.rmse_m"];
        // mean 0.3; deviations -0.2, -0.1, 0.3: sum of squares 0.14 over n - 1 = 2.
        assert!((m["mean"].as_f64().unwrap() - 0.3).abs() < 1e-12);
        assert!((m["std"].as_f64().unwrap() - 0.07f64.sqrt()).abs() < 1e-12);
        assert_eq!(
            (m["min"].as_f64(), m["max"].as_f64()),
            (Some(0.1), Some(0.6))
        );
        assert_eq!(s["a"]["passed"], 2);
        assert_eq!(s["a"]["seeds"], json!([1, 2, 3]));
        assert!(s.get("b").is_none());
    }

    #[test]
    fn links_between_reports_are_relative() {
        assert_eq!(
            relative(
                Path::new("/a/out"),
                Path::new("/a/out/x/seed-1/report.html")
            )
            .as_deref(),
            Some("x/seed-1/report.html")
        );
        assert_eq!(
            relative(
                Path::new("/a/merged"),
                Path::new("/a/shard-1/x/report.html")
            )
            .as_deref(),
            Some("../shard-1/x/report.html")
        );
    }

    #[test]
    fn the_longest_runs_start_first_and_ties_keep_their_order() {
        assert_eq!(
            start_order(&[100.0, 5000.0, 300.0, 5000.0, f64::INFINITY, 20.0]),
            vec![4, 1, 3, 2, 0, 5]
        );
        assert!(start_order(&[]).is_empty());
    }

    #[test]
    fn shards_parse_and_refuse_nonsense() {
        assert_eq!("2/4".parse::<Shard>(), Ok(Shard { k: 2, n: 4 }));
        for bad in ["0/4", "5/4", "2", "a/b", "1/0"] {
            assert!(bad.parse::<Shard>().is_err(), "{bad}");
        }
    }

    /// A gate against another scenario reads that scenario's run with the same seed, and
    /// fails (without stopping the suite) when there is none.
    #[test]
    fn a_suite_gate_ranks_one_run_against_anothers_with_the_same_seed() {
        let run = |file: &str, seed: u64, views: f64, versus: bool| Entry {
            file: format!("{file}.toml").into(),
            name: format!("{file}/seed-{seed}"),
            sweep: Some((file.into(), seed)),
            result: Ok(json!({ "gates": [], "metrics": { "scan3d.views_to_95": views } })),
            crashes: Vec::new(),
            versus: if versus {
                vec![crate::ground_truth::Gate {
                    metric: "scan3d.views_to_95".into(),
                    op: crate::ground_truth::Comparison::Less,
                    value: None,
                    than: None,
                    scenario: Some("frontier".into()),
                }]
            } else {
                Vec::new()
            },
        };
        let entries = vec![
            run("seed", 1, 10.0, true),
            run("seed", 2, 12.0, true),
            run("seed", 3, 9.0, true),
            run("frontier", 1, 15.0, false),
            run("frontier", 2, 11.0, false),
        ];
        let s = summarise(&entries, None, 2, 1.0);
        let status: Vec<&str> = s["results"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| r["status"].as_str().unwrap())
            .collect();
        assert_eq!(status, ["passed", "failed", "failed", "passed", "passed"]);
        let g = &s["results"][0]["gates"][0];
        assert_eq!(g["threshold"].as_f64(), Some(15.0));
        assert!(
            s["results"][2]["gates"][0]["message"]
                .as_str()
                .unwrap()
                .contains("not produced")
        );
    }

    #[test]
    fn junit_counts_and_escapes() {
        let entries = vec![
            Entry {
                file: "a.toml".into(),
                name: "a".into(),
                sweep: None,
                result: Ok(json!({
                    "performance": { "wall_time_s": 1.5 },
                    "gates": [
                        { "metric": "slam.ate.rmse_m", "op": "<", "threshold": 0.05, "passed": false,
                          "message": "slam.ate.rmse_m = 0.061000, not < 0.05 (margin -0.011000)" },
                        { "metric": "slam.map.f1_2cell", "op": ">=", "threshold": 0.9, "passed": true,
                          "message": "ok" }
                    ]
                })),
                crashes: Vec::new(),
                versus: Vec::new(),
            },
            Entry {
                file: "b.toml".into(),
                name: "b".into(),
                sweep: None,
                result: Err("GPU <lost> & gone".into()),
                crashes: Vec::new(),
                versus: Vec::new(),
            },
        ];
        let s = summarise(&entries, None, 2, 3.0);
        let x = junit(s["results"].as_array().unwrap(), 3.0);
        assert!(x.contains("<testsuites name=\"futago\" tests=\"4\" failures=\"1\" errors=\"1\""));
        assert!(x.contains("name=\"slam.ate.rmse_m &lt; 0.05\""));
        assert!(x.contains("<failure message=\"slam.ate.rmse_m = 0.061000, not &lt; 0.05"));
        assert!(x.contains("<error message=\"GPU &lt;lost&gt; &amp; gone\""));
        assert_eq!(x.matches("<testcase ").count(), 4);
        let s = summarise(&entries, None, 2, 3.0);
        assert_eq!(
            (
                s["passed"].as_u64(),
                s["failed"].as_u64(),
                s["errors"].as_u64()
            ),
            (Some(0), Some(1), Some(1))
        );
    }
}
