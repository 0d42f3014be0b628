//! `futago help` describes every command with its own text, and `futago config` prints the
//! presets' figures as they are declared.

use std::process::Command;

fn futago(args: &[&str]) -> String {
    let o = Command::new(env!("CARGO_BIN_EXE_futago"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("futago runs");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

#[test]
fn every_command_has_its_own_description() {
    let help = futago(&["help"]);
    let lines: Vec<&str> = help
        .lines()
        .skip_while(|l| !l.starts_with("Commands:"))
        .skip(1)
        .take_while(|l| !l.trim().is_empty())
        .collect();
    assert!(lines.len() >= 10, "{help}");
    let mut texts = std::collections::BTreeSet::new();
    for l in &lines {
        let (name, text) = l.trim().split_once(' ').unwrap_or((l.trim(), ""));
        assert!(!text.trim().is_empty(), "`{name}` has no description");
        assert!(texts.insert(text.trim()), "`{name}` shares its description");
    }
    let metrics = lines
        .iter()
        .find(|l| l.trim().starts_with("metrics"))
        .unwrap();
    assert!(!metrics.contains("shards"), "{metrics}");
    let merge = lines
        .iter()
        .find(|l| l.trim().starts_with("merge"))
        .unwrap();
    assert!(merge.contains("shards"), "{merge}");
}

#[test]
fn config_prints_the_presets_declared_figures() {
    // seed 000's laser: 960 steps of 0.25°; the URG-04LX: 681 of 360/1024°.
    let tour = futago(&["config", "scenarios/office-tour.toml"]);
    assert!(tour.contains("fov_deg = 240.0\n"), "{tour}");
    let kinect = futago(&["config", "scenarios/lab-kinect.toml"]);
    assert!(kinect.contains("fov_deg = [57.0, 43.0]\n"), "{kinect}");
}
