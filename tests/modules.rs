//! A stack module is its own code and one registration line. A toy module, registered beside
//! the stack's modules and nowhere else, types and checks its `[toy]` table, resolves the laser
//! it reads with the shared resolver, prints its effective configuration, declares a metric
//! that gates may name, and adds its node after the stack's: nothing in the loader, the
//! scenario schema or the loop knows of it. In process, through the library.

use futago::scenario::{ModuleConfig, Resolving, Scenario, ScenarioSpec, Spec};
use futago::stack::{self, MODULES, Node, Nodes, StackModule, Streams};
use futago_sim::config::SpecError;
use std::any::Any;
use std::path::{Path, PathBuf};

/// `[toy]`: a laser to read and a gain.
#[derive(Debug, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
struct ToySpec {
    #[serde(default)]
    laser: Option<String>,
    gain: f64,
}

struct Toy;

impl ModuleConfig for Toy {
    fn key(&self) -> Option<&'static str> {
        Some("toy")
    }

    fn resolve(&self, cx: &Resolving<'_>, table: &toml::Value) -> Result<Spec, SpecError> {
        let mut t: ToySpec = cx.typed("toy", cx.table("toy", table)?)?;
        t.laser = Some(cx.laser("toy", &t.laser)?);
        if !(t.gain.is_finite() && t.gain > 0.0) {
            return Err(cx.error("toy.gain", "expected a positive gain"));
        }
        Ok(Box::new(t))
    }

    fn effective(&self, spec: &(dyn Any + Send + Sync)) -> Option<toml::Table> {
        toml::Table::try_from(spec.downcast_ref::<ToySpec>()?).ok()
    }

    fn metric_names(
        &self,
        _spec: &ScenarioSpec,
        own: Option<&(dyn Any + Send + Sync)>,
    ) -> Vec<String> {
        own.map(|_| vec!["toy.scans".to_string()])
            .unwrap_or_default()
    }
}

struct ToyNode {
    laser: String,
}

impl Node for ToyNode {
    fn name(&self) -> &'static str {
        "toy"
    }

    fn streams(&self) -> Streams {
        Streams {
            consumes: vec![format!("scan/{}", self.laser)],
            ..Streams::default()
        }
    }
}

impl StackModule for Toy {
    fn build(&self, s: &Scenario, _seed: u64, _out: Option<&Path>) -> Nodes {
        Ok(s.module::<ToySpec>()
            .map(|t| {
                Box::new(ToyNode {
                    laser: t.laser.clone().unwrap_or_default(),
                }) as Box<dyn Node>
            })
            .into_iter()
            .collect())
    }
}

static TOY: Toy = Toy;

/// The stack's modules and the toy: its registration is this one push.
fn registry() -> Vec<&'static dyn StackModule> {
    let mut modules = MODULES.to_vec();
    modules.push(&TOY);
    modules
}

/// A scenario in a temporary folder with `extra` appended: the office, one laser, standing.
fn scenario(dir: &Path, extra: &str) -> PathBuf {
    scenario_with(dir, "", extra)
}

/// As [`scenario`], with `top` among the top-level keys.
fn scenario_with(dir: &Path, top: &str, extra: &str) -> PathBuf {
    let world = Path::new(env!("CARGO_MANIFEST_DIR")).join("worlds/office.toml");
    let text = format!(
        "name = \"toy\"\nworld = {:?}\nduration = 1.0\nstart = \"dock\"\n{top}\n[[lidar]]\nname = \"front\"\npreset = \"seed000\"\nxyz = [0.08, 0.0, 0.2]\n\n[controller]\ntype = \"idle\"\n\n{extra}",
        world.display().to_string()
    );
    let path = dir.join("toy.toml");
    std::fs::write(&path, text).unwrap();
    path
}

fn load(path: &Path) -> Result<Scenario, SpecError> {
    Scenario::load(path, &stack::configs(&registry()))
}

#[test]
fn a_registered_module_types_its_table_declares_metrics_and_adds_its_node() {
    let dir = tempfile::tempdir().unwrap();
    let path = scenario(
        dir.path(),
        "[toy]\ngain = 2.5\n\n[[gate]]\nmetric = \"toy.scans\"\nop = \">\"\nvalue = 0\n",
    );
    let s = load(&path).unwrap();
    let toy = s.module::<ToySpec>().expect("the toy's spec");
    // The shared resolver named the scenario's only laser.
    assert_eq!(toy.laser.as_deref(), Some("front"));
    assert_eq!(toy.gain, 2.5);
    assert!(s.metric_names().contains(&"toy.scans".to_string()));
    let effective = s.effective_config();
    assert_eq!(effective["toy"]["laser"].as_str(), Some("front"));
    assert_eq!(effective["toy"]["gain"].as_float(), Some(2.5));
    let nodes = stack::build_with(&registry(), &s, 0, None).unwrap();
    let names: Vec<&str> = nodes.iter().map(|n| n.name()).collect();
    assert_eq!(names.last(), Some(&"toy"), "{names:?}");
    assert_eq!(
        nodes.last().unwrap().streams().consumes,
        ["scan/front".to_string()]
    );
    // Without its table the module resolves nothing and adds no node.
    let plain = load(&scenario(dir.path(), "")).unwrap();
    assert!(plain.module::<ToySpec>().is_none());
    assert!(!plain.metric_names().contains(&"toy.scans".to_string()));
    let nodes = stack::build_with(&registry(), &plain, 0, None).unwrap();
    assert!(nodes.iter().all(|n| n.name() != "toy"));
}

#[test]
fn the_module_checks_its_table_with_the_dotted_key() {
    let dir = tempfile::tempdir().unwrap();
    let e = load(&scenario(dir.path(), "[toy]\ngain = -1.0\n")).unwrap_err();
    assert!(e.to_string().contains("toy.gain"), "{e}");
    let e = load(&scenario(dir.path(), "[toy]\ngian = 1.0\n")).unwrap_err();
    assert!(e.to_string().contains("gian"), "{e}");
    let e = load(&scenario(
        dir.path(),
        "[toy]\ngain = 1.0\nlaser = \"back\"\n",
    ))
    .unwrap_err();
    assert!(
        e.to_string().contains("toy.laser") && e.to_string().contains("front"),
        "{e}"
    );
}

#[test]
fn a_table_no_module_owns_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    // The stack alone does not know `[toy]`.
    let e = stack::load(&scenario(dir.path(), "[toy]\ngain = 1.0\n")).unwrap_err();
    let msg = e.to_string();
    assert!(msg.contains("toy") && msg.contains("slam"), "{msg}");
    // Nor a misspelt module's table, or a stray key.
    let e = stack::load(&scenario(dir.path(), "[slma]\nmethod = \"icp\"\n")).unwrap_err();
    assert!(e.to_string().contains("slma"), "{e}");
    let e = stack::load(&scenario_with(dir.path(), "durtion = 3.0\n", "")).unwrap_err();
    assert!(e.to_string().contains("durtion"), "{e}");
}
