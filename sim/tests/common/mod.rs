//! Helpers shared by the simulator's integration tests.
#![allow(dead_code)]

use futago_msgs::Pose2;
use futago_sim::config::parse_toml;
use futago_sim::create::CreateConfig;
use futago_sim::lidar::{LidarConfig, LidarPreset};
use futago_sim::world::compile;
use futago_sim::{PhysicsConfig, Simulation, World};
use std::path::Path;

/// A world from TOML text (relative assets resolve against the crate's `worlds/` parent).
pub fn world(text: &str) -> World {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../worlds/test.toml");
    compile(&parse_toml(&p, text).unwrap(), &p).unwrap()
}

/// A closed rectangular room `[0, w] × [0, h]` (inner faces), walls 0.2 m thick, with a floor.
pub fn box_room(w: f64, h: f64, extra: &str) -> World {
    room(w, h, true, extra)
}

/// As [`box_room`], with or without the floor slab.
pub fn room(w: f64, h: f64, floor: bool, extra: &str) -> World {
    let t = 0.2;
    let floor = if floor {
        "[floor]\nmaterial = \"m\"\n"
    } else {
        ""
    };
    world(&format!(
        "name = \"box\"\n[materials.m]\ncolor = [0.5, 0.5, 0.5]\n{floor}[[walls]]\nmaterial = \"m\"\nthickness = {t}\nheight = 2.0\nclosed = true\npoints = [[{a}, {a}], [{b}, {a}], [{b}, {c}], [{a}, {c}]]\n{extra}",
        a = -t / 2.0,
        b = w + t / 2.0,
        c = h + t / 2.0
    ))
}

/// A simulation with the default Create and the given lasers.
pub fn sim(
    world: &World,
    robot: &CreateConfig,
    lidars: &[LidarConfig],
    start: Pose2,
    seed: u64,
) -> Simulation {
    sim_with(
        world,
        robot,
        lidars,
        &futago_sim::Movers::default(),
        start,
        seed,
    )
}

/// A simulation with the given lasers, joints and agents.
pub fn sim_with(
    world: &World,
    robot: &CreateConfig,
    lidars: &[LidarConfig],
    movers: &futago_sim::Movers,
    start: Pose2,
    seed: u64,
) -> Simulation {
    let resolved: Vec<_> = lidars
        .iter()
        .map(|l| (l.clone(), l.resolve(Path::new("test"), "lidar").unwrap()))
        .collect();
    Simulation::new(
        world,
        &PhysicsConfig::default(),
        robot,
        &resolved,
        movers,
        start,
        seed,
    )
}

/// A noise-free laser of `preset` at the robot's centre, 0.2 m up, taking scans at one instant.
pub fn ideal(preset: LidarPreset) -> LidarConfig {
    let mut l = LidarConfig::preset(preset);
    l.sigma = Some(0.0);
    l.sigma_rel = Some(0.0);
    l.sweep = false;
    l.xyz = [0.0, 0.0, 0.2];
    l
}
