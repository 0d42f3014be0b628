//! Twin scenarios: `futago calibrate` then `futago twin` on a real log, as one run of a
//! suite, gated on how close the twin comes to the robot.
//!
//! A twin scenario is a scenario file with a `[twin]` table instead of a world:
//!
//! ```toml
//! name = "twin-mit-csail"
//! [twin]
//! log = "slam-benchmark/mit-csail.clf"          # under the data folder
//! relations = "slam-benchmark/mit-csail.relations"
//! calibrate_span = [0.0, 0.5]                     # the profile is fitted here
//! score_span = [0.5, 1.0]                         # and judged here
//! seeds = 5
//! rank = "../../choices/slam-configs.toml"        # relative to this file; optional
//! [[gate]]
//! metric = "twin.slam_relations_m.ratio"
//! op = ">="
//! value = 0.67
//! ```
//!
//! Logs are looked up in the data folder (`FUTAGO_DATA`, or `../shared/datasets` beside the
//! repository holding the scenario, see [`futago_msgs::datasets`]). The run writes
//! `calibrate/` (the profile), `twin/` (the side-by-side) and `summary.json` with flat
//! `metrics` and the `gates`, whole or not at all.

use crate::gate::Gate;
use crate::ground_truth::{self, Metrics};
use anyhow::{Context, Result, bail};
use futago_robot::mapping::slam::SlamConfig;
use serde::Deserialize;
use serde_json::{Value, json};
use std::path::{Path, PathBuf};

/// A twin scenario as written.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct Spec {
    name: String,
    #[serde(default)]
    description: String,
    twin: TwinSpec,
    #[serde(default)]
    gate: Vec<Gate>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct TwinSpec {
    log: String,
    relations: String,
    #[serde(default = "first_half")]
    calibrate_span: [f64; 2],
    #[serde(default = "second_half")]
    score_span: [f64; 2],
    #[serde(default = "five")]
    seeds: u64,
    rank: Option<PathBuf>,
}

fn first_half() -> [f64; 2] {
    [0.0, 0.5]
}
fn second_half() -> [f64; 2] {
    [0.5, 1.0]
}
fn five() -> u64 {
    5
}

/// A checked twin scenario, its files found.
#[derive(Debug, Clone)]
pub struct TwinScenario {
    pub file: PathBuf,
    pub name: String,
    pub description: String,
    pub log: PathBuf,
    pub relations: PathBuf,
    pub calibrate_span: [f64; 2],
    pub score_span: [f64; 2],
    pub seeds: u64,
    pub rank: Option<PathBuf>,
    pub gates: Vec<Gate>,
}

/// Whether the scenario file at `path` is a twin scenario (it has a `[twin]` table). A file
/// that does not parse is not: the scenario loader reports its error.
pub fn is_twin_file(path: &Path) -> bool {
    std::fs::read_to_string(path)
        .ok()
        .and_then(|t| t.parse::<toml::Table>().ok())
        .is_some_and(|t| t.contains_key("twin"))
}

/// The metrics a twin scenario's run gives, for its gates.
pub fn metric_names() -> Vec<String> {
    let mut names = Vec::new();
    for (f, _) in super::COMPARED {
        for k in [
            "real",
            "twin",
            "ratio",
            "uncalibrated",
            "uncalibrated_ratio",
        ] {
            names.push(format!("twin.{f}.{k}"));
        }
    }
    names.push("twin.rank.spearman".into());
    names.push("twin.rank.regret".into());
    names.push("twin.rank.real_resampled_spearman".into());
    names.push("twin.reference.cycles".into());
    names.push("twin.reference.mean_error_m".into());
    names.push("twin.slam_relations_exact_m.twin".into());
    names.push("twin.simulation_real_time_factor".into());
    names
}

/// Reads and checks the twin scenario at `path`; the error names the file and the key.
pub fn load(path: &Path) -> Result<TwinScenario> {
    let spec: Spec = futago_sim::config::load_toml(path)?;
    let at = path.display();
    let t = &spec.twin;
    for (key, s) in [
        ("calibrate_span", t.calibrate_span),
        ("score_span", t.score_span),
    ] {
        if !(s[0].is_finite() && s[1].is_finite() && 0.0 <= s[0] && s[0] < s[1] && s[1] <= 1.0) {
            bail!("{at}: `twin.{key}` = {s:?}: expected [A, B] with 0 ≤ A < B ≤ 1");
        }
    }
    if t.seeds == 0 || t.seeds > 100 {
        bail!("{at}: `twin.seeds` = {}: expected 1 to 100 seeds", t.seeds);
    }
    let names = metric_names();
    for (k, g) in spec.gate.iter().enumerate() {
        if g.scenario.is_some() {
            bail!("{at}: gate[{k}].scenario: a twin scenario's gates are on its own metrics");
        }
        for m in std::iter::once(&g.metric).chain(&g.than) {
            if !names.contains(m) {
                bail!(
                    "{at}: gate[{k}]: no metric `{m}`; a twin scenario gives: {}",
                    names.join(", ")
                );
            }
        }
        if g.value.is_none() && g.than.is_none() {
            bail!("{at}: gate[{k}]: expected a `value` or a `than` metric");
        }
    }
    let dir = path.parent().unwrap_or(Path::new("."));
    let data = data_folder(dir);
    let find = |key: &str, name: &str| -> Result<PathBuf> {
        let p = data.as_ref().map(|d| d.join(name));
        match p {
            Some(p) if p.is_file() => Ok(p),
            _ => bail!(
                "{at}: `twin.{key}` = {name:?}: not found in the data folder ({}); set {} to the folder of the logs that datasets.sha256 lists",
                data.as_ref()
                    .map_or("none found".into(), |d| d.display().to_string()),
                futago_msgs::datasets::DATA_ENV
            ),
        }
    };
    let log = find("log", &t.log)?;
    let relations = find("relations", &t.relations)?;
    let rank = match &t.rank {
        Some(r) => {
            let p = dir.join(r);
            // Checked now, not after the calibration and the twin have run.
            super::rank::load(&p, SlamConfig::default())
                .with_context(|| format!("{at}: `twin.rank`"))?;
            Some(p)
        }
        None => None,
    };
    Ok(TwinScenario {
        file: path.to_path_buf(),
        name: spec.name,
        description: spec.description,
        log,
        relations,
        calibrate_span: t.calibrate_span,
        score_span: t.score_span,
        seeds: t.seeds,
        rank,
        gates: spec.gate,
    })
}

/// The data folder for a scenario in `dir`: `FUTAGO_DATA`, or `../shared/datasets` beside the
/// nearest folder above `dir` that holds the list of the logs (the repository).
fn data_folder(dir: &Path) -> Option<PathBuf> {
    let dir = dir.canonicalize().unwrap_or_else(|_| dir.to_path_buf());
    let root = dir
        .ancestors()
        .find(|a| a.join(futago_msgs::datasets::LIST).is_file())
        .unwrap_or(&dir);
    futago_msgs::datasets::folder(root).map(|d| d.canonicalize().unwrap_or(d))
}

/// The flat metrics of a twin's summary.
fn metrics(summary: &Value) -> Metrics {
    let mut m = Metrics::default();
    for row in summary["compared"].as_array().into_iter().flatten() {
        let f = row["figure"].as_str().unwrap_or_default();
        for (k, key) in [
            ("real", "real"),
            ("twin", "twin_median"),
            ("ratio", "ratio_median"),
            ("uncalibrated", "uncalibrated"),
            ("uncalibrated_ratio", "uncalibrated_ratio"),
        ] {
            if let Some(v) = row[key].as_f64() {
                m.insert(format!("twin.{f}.{k}"), v);
            }
        }
    }
    let r = &summary["ranking"];
    for k in ["spearman", "regret"] {
        if let Some(v) = r[k].as_f64() {
            m.insert(format!("twin.rank.{k}"), v);
        }
    }
    if let Some(v) = r["real_resampled_spearman"][0].as_f64() {
        m.insert("twin.rank.real_resampled_spearman", v);
    }
    let n = &summary["reference_noise"];
    for k in ["cycles", "mean_error_m"] {
        if let Some(v) = n[k].as_f64() {
            m.insert(format!("twin.reference.{k}"), v);
        }
    }
    if let Some(v) = summary["slam_relations_exact_m"].as_f64() {
        m.insert("twin.slam_relations_exact_m.twin", v);
    }
    if let Some(v) = summary["performance"]["simulation_real_time_factor"].as_f64() {
        m.insert("twin.simulation_real_time_factor", v);
    }
    m
}

/// Runs the scenario into `out`: the calibration on `calibrate_span`, the twin with its
/// profile scored on `score_span`, and the gates; whole or not at all.
pub fn run(s: &TwinScenario, out: &Path, force: bool, jobs: usize) -> Result<Value> {
    let config = SlamConfig::default();
    crate::run::write_atomically(out, force, "run", |tmp| {
        let started = std::time::Instant::now();
        let cal = tmp.join("calibrate");
        let options = crate::calibrate::CalibrateOptions {
            read: Default::default(),
            span: s.calibrate_span,
            laser: None,
            force: false,
        };
        crate::calibrate::calibrate(&s.log, config, &cal, &options)?;
        let twin = super::twin(
            &s.log,
            &cal.join("profile.toml"),
            &s.relations,
            config,
            &tmp.join("twin"),
            &super::TwinOptions {
                read: Default::default(),
                seeds: s.seeds,
                score_span: s.score_span,
                jobs,
                force: false,
                rank: s.rank.clone(),
                profile_as: Some(out.join("calibrate/profile.toml")),
            },
        )?;
        let m = metrics(&twin);
        let gates = ground_truth::evaluate(&s.gates, &m);
        let summary = json!({
            "scenario": s.name,
            "description": s.description,
            "file": s.file.display().to_string(),
            "kind": "twin",
            "log": s.log.display().to_string(),
            "metrics": m.0,
            "gates": gates,
            "performance": { "wall_time_s": started.elapsed().as_secs_f64() },
        });
        std::fs::write(
            tmp.join("summary.json"),
            serde_json::to_string_pretty(&summary)? + "\n",
        )
        .context("writing summary.json")?;
        Ok(summary)
    })
}

/// `futago run` of a twin scenario: runs it into `out` (by default `out/<name>`), prints its
/// gates, and gives the exit status: 0, or [`crate::run::GATE_FAILED`] when a gate failed.
/// `options`: the command line gave a scenario run's options (an overlay, a seed or a
/// duration), which a twin scenario refuses.
pub fn command(
    path: &Path,
    options: bool,
    out: Option<PathBuf>,
    force: bool,
    jobs: usize,
) -> Result<i32> {
    if options {
        bail!(
            "{}: a twin scenario takes no --overlay, --set, --seed or --duration (its seeds are `twin.seeds`)",
            path.display()
        );
    }
    let s = load(path)?;
    let out = out.unwrap_or_else(|| PathBuf::from("out").join(&s.name));
    let summary = run(&s, out.as_path(), force, jobs)?;
    print!(
        "{}",
        std::fs::read_to_string(out.join("twin/twin.md")).unwrap_or_default()
    );
    let gates = summary["gates"].as_array().cloned().unwrap_or_default();
    let failed = gates.iter().filter(|g| g["passed"] == false).count();
    for g in &gates {
        let mark = if g["passed"] == true { "pass" } else { "FAIL" };
        println!("{mark}: {}", g["message"].as_str().unwrap_or_default());
    }
    println!(
        "{}: {} of {} gates passed; results in {}",
        s.name,
        gates.len() - failed,
        gates.len(),
        out.display()
    );
    Ok(if failed == 0 {
        0
    } else {
        crate::run::GATE_FAILED
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_twin_scenarios_are_refused_by_key() {
        let dir = std::env::temp_dir().join(format!("futago-twin-scn-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let bad = |body: &str, expected: &str| {
            let p = dir.join("t.toml");
            std::fs::write(&p, body).unwrap();
            assert!(is_twin_file(&p));
            let e = format!("{:#}", load(&p).unwrap_err());
            assert!(e.contains(expected), "{e} lacks {expected}");
        };
        let head =
            "name = \"t\"\n[twin]\nlog = \"no/such.clf\"\nrelations = \"no/such.relations\"\n";
        bad(
            &format!("{head}score_span = [0.5, 0.2]\n"),
            "`twin.score_span`",
        );
        bad(&format!("{head}seeds = 0\n"), "`twin.seeds`");
        bad(
            &format!("{head}[[gate]]\nmetric = \"twin.nothing\"\nop = \"<\"\nvalue = 1.0\n"),
            "no metric `twin.nothing`",
        );
        bad(head, "`twin.log` = \"no/such.clf\": not found");
        bad(&format!("{head}speed = 1\n"), "speed");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn a_twins_summary_becomes_gated_metrics() {
        let summary = json!({
            "compared": [{ "figure": "slam_relations_m", "real": 0.03, "twin_median": 0.006, "ratio_median": 0.2 }],
            "ranking": { "spearman": 0.9, "regret": 1.05 },
            "performance": { "simulation_real_time_factor": 1000.0 },
            "reference_noise": { "cycles": 54, "mean_error_m": 0.028 },
            "slam_relations_exact_m": 0.007,
        });
        let m = metrics(&summary);
        assert_eq!(m.0["twin.slam_relations_m.ratio"], 0.2);
        assert_eq!(m.0["twin.reference.mean_error_m"], 0.028);
        assert_eq!(m.0["twin.slam_relations_exact_m.twin"], 0.007);
        assert_eq!(m.0["twin.rank.spearman"], 0.9);
        let gate = |metric: &str, op: &str, value: f64| -> Gate {
            toml::from_str(&format!(
                "metric = \"{metric}\"\nop = \"{op}\"\nvalue = {value}"
            ))
            .unwrap()
        };
        let r = ground_truth::evaluate(
            &[
                gate("twin.slam_relations_m.ratio", ">=", 0.67),
                gate("twin.rank.spearman", ">=", 0.8),
            ],
            &m,
        );
        assert!(!r[0].passed, "a twin five times too accurate fails");
        assert!(r[1].passed);
        for name in m.0.keys() {
            assert!(metric_names().contains(name), "{name} is listed");
        }
    }
}
