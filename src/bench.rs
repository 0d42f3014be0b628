//! `futago bench`: the simulator's speed, measured on a real scenario.

use crate::run::{RunOptions, run_in_memory};
use crate::scenario::Scenario;
use anyhow::Result;
use futago_sim::Simulation;
use futago_sim::lidar::LidarPreset;
use glam::Vec3;
use rand::{Rng, SeedableRng};
use serde_json::{Value, json};
use std::time::Instant;

/// Measures (1) the real-time factor of the scenario with its lasers, (2) without them
/// (physics, robot and controller alone), and (3) single-thread ray casts per second from
/// random free poses of the scenario's world with the URG-04LX's and a 30 m beam fan.
pub fn bench(s: &Scenario, duration: Option<f64>, rays: usize) -> Result<Value> {
    let opts = RunOptions {
        seed: None,
        duration,
        progress: false,
    };
    let full = run_in_memory(s, &opts)?;
    let mut bare = s.clone();
    bare.lidars.clear();
    let physics = run_in_memory(&bare, &opts)?;

    let mut sim = Simulation::new(&s.world, &s.spec.physics, &s.spec.robot, &[], s.start, 0);
    sim.step(None); // builds the query structure
    let (lo, hi) = s.world.bounds();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let mut origins = Vec::new();
    while origins.len() < 256 {
        let p = Vec3::new(
            rng.random_range(lo.x..hi.x),
            rng.random_range(lo.y..hi.y),
            0.2,
        );
        // Keep origins that are not inside geometry: a ray straight up must reach the ceiling
        // region from outside any box (cheap proxy: the point must see some free space).
        if sim.cast_ray(p, Vec3::X, 0.05).is_none() {
            origins.push(p);
        }
    }
    let mut rates = serde_json::Map::new();
    for (label, max) in [
        ("urg04lx_5.6m", LidarPreset::Urg04lx.spec().range_max as f32),
        ("30m", 30.0f32),
    ] {
        let beams = 682usize;
        let dirs: Vec<Vec3> = (0..beams)
            .map(|i| {
                let a = -2.09 + i as f32 * (4.18 / beams as f32);
                Vec3::new(a.cos(), a.sin(), 0.0)
            })
            .collect();
        let t = Instant::now();
        let mut hits = 0usize;
        let mut n = 0usize;
        while n < rays {
            let o = origins[(n / beams) % origins.len()];
            for d in &dirs {
                if sim.cast_ray(o, *d, max).is_some() {
                    hits += 1;
                }
            }
            n += beams;
        }
        let secs = t.elapsed().as_secs_f64();
        rates.insert(
            label.into(),
            json!({ "rays": n, "hits": hits, "seconds": secs, "rays_per_second": n as f64 / secs }),
        );
    }
    Ok(json!({
        "scenario": s.spec.name,
        "sim_time_s": full.sim_time,
        "with_lasers": { "wall_time_s": full.wall_time, "real_time_factor": full.sim_time / full.wall_time, "laser_rays": full.laser_rays, "steps": full.steps },
        "physics_only": { "wall_time_s": physics.wall_time, "real_time_factor": physics.sim_time / physics.wall_time },
        "ray_casting_one_core": rates,
    }))
}
