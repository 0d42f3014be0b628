//! `futago suite`: many scenarios at once, in parallel, with their gates collected into
//! `suite.json` and a JUnit XML report (one test case per scenario run and per gate) that CI
//! services show natively.
//!
//! Every scenario is loaded and checked before the first one runs. Each run is deterministic for
//! its seed, and writes into its own folder, `OUT/<scenario file stem>/`. So the number of
//! parallel jobs changes the wall time only, never the results. `--shard K/N` keeps every N-th
//! scenario from the K-th (in sorted order), so that N machines split a suite between them.

use crate::run::{self, RunOptions};
use crate::scenario::Scenario;
use anyhow::{Context, Result, bail};
use serde_json::{Value, json};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

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

/// One scenario's outcome in a suite.
struct Entry {
    file: PathBuf,
    name: String,
    /// The run's summary, or the error that stopped it.
    result: Result<Value, String>,
}

/// Runs the suite and writes `out/suite.json` and `out/junit.xml` beside each scenario's
/// folder; returns the suite summary.
pub fn suite(paths: &[PathBuf], jobs: usize, shard: Option<Shard>, out: &Path) -> Result<Value> {
    let files = collect(paths)?;
    let files: Vec<PathBuf> = match shard {
        Some(s) => files
            .into_iter()
            .enumerate()
            .filter(|(i, _)| i % s.n == s.k - 1)
            .map(|(_, f)| f)
            .collect(),
        None => files,
    };
    // Check everything before anything runs.
    let mut scenarios = Vec::new();
    let mut stems = std::collections::BTreeSet::new();
    for f in &files {
        let s = Scenario::load(f)?;
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
        scenarios.push((f.clone(), stem, s));
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let started = std::time::Instant::now();
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Option<Entry>>> =
        Mutex::new((0..scenarios.len()).map(|_| None).collect());
    let bar = indicatif::ProgressBar::new(scenarios.len() as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{spinner} suite [{bar:40}] {pos}/{len} {msg}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    if !std::io::IsTerminal::is_terminal(&std::io::stderr()) {
        bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    std::thread::scope(|scope| {
        for _ in 0..jobs.max(1).min(scenarios.len()) {
            scope.spawn(|| {
                loop {
                    let i = next.fetch_add(1, Ordering::SeqCst);
                    let Some((file, stem, s)) = scenarios.get(i) else {
                        break;
                    };
                    let opts = RunOptions {
                        seed: None,
                        duration: None,
                        progress: false,
                    };
                    let result = run::run(s, &opts, &out.join(stem))
                        .map(|(summary, _)| summary)
                        .map_err(|e| format!("{e:#}"));
                    bar.inc(1);
                    bar.set_message(stem.clone());
                    results.lock().expect("no worker panicked")[i] = Some(Entry {
                        file: file.clone(),
                        name: stem.clone(),
                        result,
                    });
                }
            });
        }
    });
    bar.finish_and_clear();
    let wall = started.elapsed().as_secs_f64();
    let entries: Vec<Entry> = results
        .into_inner()
        .expect("no worker panicked")
        .into_iter()
        .map(|e| e.expect("every scenario ran"))
        .collect();
    let summary = summarise(&entries, shard, jobs, wall);
    write_reports(out, &summary)?;
    Ok(summary)
}

fn gates(e: &Entry) -> Vec<Value> {
    match &e.result {
        Ok(s) => s["gates"].as_array().cloned().unwrap_or_default(),
        Err(_) => Vec::new(),
    }
}

fn summarise(entries: &[Entry], shard: Option<Shard>, jobs: usize, wall: f64) -> Value {
    let results: Vec<Value> = entries
        .iter()
        .map(|e| {
            let g = gates(e);
            let failed = g.iter().filter(|r| r["passed"] == false).count();
            json!({
                "scenario": e.name,
                "file": e.file.display().to_string(),
                "status": match (&e.result, failed) {
                    (Err(_), _) => "error",
                    (Ok(_), 0) => "passed",
                    _ => "failed",
                },
                "error": e.result.as_ref().err(),
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

/// XML text with `& < > " '` escaped.
fn xml(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
        .replace('\'', "&apos;")
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
            xml(name),
            1 + g.len()
        );
        body += &format!(
            "    <testcase classname=\"{0}\" name=\"run\" time=\"{time:.3}\">",
            xml(name)
        );
        if let Some(msg) = error {
            body += &format!(
                "\n      <error message=\"{}\">{}</error>\n    ",
                xml(msg.lines().next().unwrap_or("")),
                xml(msg)
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
                xml(name),
                xml(&case)
            );
            if r["passed"] == false {
                body += &format!(
                    "\n      <failure message=\"{0}\" type=\"gate\">{0}</failure>\n    ",
                    xml(msg)
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

/// Writes `suite.json` and `junit.xml` into `out`, each whole (written beside, then renamed).
fn write_reports(out: &Path, summary: &Value) -> Result<()> {
    let results = summary["results"].as_array().cloned().unwrap_or_default();
    let wall = summary["wall_time_s"].as_f64().unwrap_or(0.0);
    for (name, text) in [
        ("suite.json", serde_json::to_string_pretty(summary)? + "\n"),
        ("junit.xml", junit(&results, wall)),
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
        "results": results,
    })
}

/// `futago merge`: joins the `suite.json` of several shards into one suite, with its JUnit
/// file; the wall time is the longest shard's (they ran side by side).
pub fn merge(shards: &[PathBuf], out: &Path) -> Result<Value> {
    if shards.is_empty() {
        bail!("nothing to merge: name the output folders of the shards");
    }
    let mut results = Vec::new();
    let mut wall = 0.0f64;
    let mut seen = std::collections::BTreeSet::new();
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
    let summary = totals(results, None, None, wall);
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    write_reports(out, &summary)?;
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_parse_and_refuse_nonsense() {
        assert_eq!("2/4".parse::<Shard>(), Ok(Shard { k: 2, n: 4 }));
        for bad in ["0/4", "5/4", "2", "a/b", "1/0"] {
            assert!(bad.parse::<Shard>().is_err(), "{bad}");
        }
    }

    #[test]
    fn junit_counts_and_escapes() {
        let entries = vec![
            Entry {
                file: "a.toml".into(),
                name: "a".into(),
                result: Ok(json!({
                    "performance": { "wall_time_s": 1.5 },
                    "gates": [
                        { "metric": "slam.ate.rmse_m", "op": "<", "threshold": 0.05, "passed": false,
                          "message": "slam.ate.rmse_m = 0.061000, not < 0.05 (margin -0.011000)" },
                        { "metric": "slam.map.f1_2cell", "op": ">=", "threshold": 0.9, "passed": true,
                          "message": "ok" }
                    ]
                })),
            },
            Entry {
                file: "b.toml".into(),
                name: "b".into(),
                result: Err("GPU <lost> & gone".into()),
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
