//! Every numeric key of every module's config, walked: each is set, one at a time, to values
//! no parameter of an indoor robot can take (NaN, ±10³⁰⁰, and for integers −1 and 2⁶²), and
//! the scenario must be refused with an error that names that key (or, for an element of a
//! list, the list). The keys are not listed by hand: they come from
//! [`Scenario::effective_config`], so a field added to any config is walked too.

use std::path::Path;

/// Scenarios that between them use every table: sensors on the base and on a joint, agents,
/// people and flows, localisation, SLAM, the RGB-D map, each controller, events, gates and outputs.
fn scenarios() -> Vec<String> {
    let world = Path::new(env!("CARGO_MANIFEST_DIR")).join("worlds/lab.toml");
    let common = format!(
        r#"name = "walk"
world = {world:?}
duration = 10.0
seed = 1
start = {{ x = 3.0, y = 6.0, yaw_deg = 10.0 }}

[physics]
rate = 200.0

[[lidar]]
name = "front"
preset = "urg-04lx"
xyz = [0.1, 0.0, 0.2]

[[lidar]]
name = "vertical"
preset = "utm-30lx"
xyz = [0.0, 0.0, 0.5]
rpy_deg = [90.0, 0.0, 0.0]
joint = "table"

[[joint]]
name = "table"
mode = "oscillate"
rate_deg = 30.0
min_deg = -20.0
max_deg = 20.0

[[agent]]
name = "walker"
path = [[2.0, 2.0], [4.0, 2.0]]
speed = 1.0

[[person]]
name = "ann"
route = [[2.0, 3.0], [4.0, 3.0]]
speed = 1.2
start_time = 1.0
heading_deg = 90.0

[[flow]]
name = "visitors"
from = [2.0, 4.0]
to = [5.0, 4.0]
via = [[3.0, 4.5]]
rate = 2.0
max = 3

[[event]]
time = 5.0
teleport = {{ x = 3.0, y = 5.0, yaw_deg = 0.0 }}

[[gate]]
metric = "odometry.ate.rmse_m"
op = "<"
value = 0.5

[output]
groundtruth_rate = 50.0
"#
    );
    let full = common.clone()
        + r#"
[[camera]]
name = "kinect"
preset = "seed000"

[localization]
laser = "front"

[depth_localization]
camera = "kinect"
size = [80, 60]

[slam]
laser = "front"

[rgbd_map]
camera = "kinect"
laser = "front"

[controller]
type = "navigate"
laser = "front"
goals = [[4.0, 6.0], [3.0, 3.0]]
"#;
    let segments = common.clone()
        + r#"
[controller]
type = "segments"
segments = [{ duration = 2.0, velocity = 0.1, radius = 0.5 }]
"#;
    let waypoints = common.clone()
        + r#"
[controller]
type = "waypoints"
waypoints = [[4.0, 6.0], [3.0, 3.0]]
"#;
    let explore = common
        + r#"
[slam]
laser = "front"
method = "icp"

[controller]
type = "explore"
laser = "front"
"#;
    vec![full, segments, waypoints, explore]
}

/// Numeric leaves of `t` as (dotted path with `[i]` for list elements, value).
fn leaves(t: &toml::Value, path: &str, out: &mut Vec<(String, toml::Value)>) {
    match t {
        toml::Value::Table(m) => {
            for (k, v) in m {
                let p = if path.is_empty() {
                    k.clone()
                } else {
                    format!("{path}.{k}")
                };
                leaves(v, &p, out);
            }
        }
        toml::Value::Array(a) => {
            for (i, v) in a.iter().enumerate() {
                leaves(v, &format!("{path}[{i}]"), out);
            }
        }
        toml::Value::Integer(_) | toml::Value::Float(_) => out.push((path.into(), t.clone())),
        _ => {}
    }
}

/// The value at `path` in `t`, for writing.
fn at<'a>(t: &'a mut toml::Value, path: &str) -> &'a mut toml::Value {
    let mut v = t;
    for part in path.split('.') {
        let (key, idx) = match part.find('[') {
            Some(i) => (&part[..i], &part[i..]),
            None => (part, ""),
        };
        v = &mut v[key];
        for i in idx.split(['[', ']']).filter(|s| !s.is_empty()) {
            v = &mut v[i.parse::<usize>().unwrap()];
        }
    }
    v
}

/// Whether an error at `key` names `leaf`: the same key, or the list that holds it.
fn names(key: &str, leaf: &str) -> bool {
    let mut l = leaf;
    loop {
        if key == l {
            return true;
        }
        match l
            .strip_suffix(']')
            .and_then(|s| s.rfind('[').map(|i| &s[..i]))
        {
            Some(shorter) => l = shorter,
            None => return false,
        }
    }
}

/// Keys that take any value of their type: seeds are arbitrary 64-bit numbers.
fn unbounded(leaf: &str) -> bool {
    leaf == "seed" || leaf.starts_with("seeds[")
}

#[test]
fn every_numeric_key_refuses_absurd_values_by_name() {
    let tmp = tempfile::tempdir().unwrap();
    let mut walked = std::collections::BTreeSet::new();
    let mut failures = Vec::new();
    for (n, text) in scenarios().iter().enumerate() {
        let file = tmp.path().join(format!("walk-{n}.toml"));
        std::fs::write(&file, text).unwrap();
        let s = crate::stack::load(&file).unwrap_or_else(|e| panic!("scenario {n}: {e}"));
        let effective = toml::Value::Table(s.effective_config());
        // The effective config is itself a scenario that loads.
        std::fs::write(&file, toml::to_string(&effective).unwrap()).unwrap();
        crate::stack::load(&file).unwrap_or_else(|e| panic!("effective config {n}: {e}"));
        let mut numeric = Vec::new();
        leaves(&effective, "", &mut numeric);
        for (leaf, value) in numeric {
            if unbounded(&leaf) || !walked.insert(leaf.clone()) {
                continue;
            }
            let bad: Vec<toml::Value> = match value {
                toml::Value::Integer(_) => vec![(-1).into(), (1i64 << 62).into()],
                _ => vec![f64::NAN.into(), 1e300.into(), (-1e300).into()],
            };
            for b in bad {
                let mut t = effective.clone();
                *at(&mut t, &leaf) = b.clone();
                std::fs::write(&file, toml::to_string(&t).unwrap()).unwrap();
                let shown = match b {
                    toml::Value::Float(f) if f.abs() == 1e300 => format!("{:e}", f),
                    _ => b.to_string(),
                };
                match crate::stack::load(&file) {
                    Ok(_) => failures.push(format!("{leaf} = {shown}: accepted")),
                    Err(e) if !names(&e.key, &leaf) => failures.push(format!(
                        "{leaf} = {shown}: refused at `{}`: {}",
                        e.key, e.message
                    )),
                    Err(_) => {}
                }
            }
        }
    }
    eprintln!("walked {} numeric keys", walked.len());
    assert!(walked.len() > 200, "walked only {} keys", walked.len());
    assert!(
        failures.is_empty(),
        "{} of the walk's cases were not refused by name:\n{}",
        failures.len(),
        failures.join("\n")
    );
}
