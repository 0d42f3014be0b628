//! The laser against analytic distances, its noise and its view of moving bodies.

mod common;

use common::*;
use futago_msgs::{DriveCommand, LaserScan, Pose2, Radius};
use futago_sim::create::CreateConfig;
use futago_sim::lidar::LidarPreset;

/// Distance from (x, y) along bearing a to the inside of the rectangle [0, w] × [0, h].
fn analytic(x: f64, y: f64, a: f64, w: f64, h: f64) -> f64 {
    let (dx, dy) = (a.cos(), a.sin());
    let mut t = f64::INFINITY;
    if dx > 1e-12 {
        t = t.min((w - x) / dx);
    }
    if dx < -1e-12 {
        t = t.min(-x / dx);
    }
    if dy > 1e-12 {
        t = t.min((h - y) / dy);
    }
    if dy < -1e-12 {
        t = t.min(-y / dy);
    }
    t
}

fn first_scan(s: &mut futago_sim::Simulation) -> LaserScan {
    for _ in 0..1000 {
        let out = s.step(None);
        if let Some((_, scan)) = out.scans.into_iter().next() {
            return scan;
        }
    }
    panic!("no scan in 5 s");
}

#[test]
fn noise_free_ranges_equal_analytic_distances_in_a_box() {
    let (w, h) = (4.0, 6.0);
    let world = box_room(w, h, "");
    for (preset, start) in [
        (LidarPreset::Urg04lx, Pose2::new(1.3, 2.1, 0.4)),
        (LidarPreset::Utm30lx, Pose2::new(2.0, 3.0, -2.0)),
        (LidarPreset::Lms200, Pose2::new(3.1, 0.9, 1.2)),
        (LidarPreset::Seed000, Pose2::new(0.7, 5.0, 3.0)),
    ] {
        let spec = preset.spec();
        let mut s = sim(&world, &CreateConfig::default(), &[ideal(preset)], start, 1);
        let scan = first_scan(&mut s);
        assert_eq!(scan.ranges.len(), spec.beams);
        let mut compared = 0;
        for (i, &r) in scan.ranges.iter().enumerate() {
            let a = start.theta + scan.angle(i);
            let expected = analytic(start.x, start.y, a, w, h);
            if expected > spec.range_max {
                assert_eq!(
                    r,
                    f32::INFINITY,
                    "{preset:?} beam {i}: expected no return beyond range"
                );
            } else {
                assert!(
                    (r as f64 - expected).abs() < 1e-4,
                    "{preset:?} beam {i}: {r} vs analytic {expected}"
                );
                compared += 1;
            }
        }
        assert!(
            compared > spec.beams / 3,
            "{preset:?}: only {compared} beams in range"
        );
    }
}

#[test]
fn gaussian_noise_has_the_configured_spread_and_dropouts_their_rate() {
    let world = box_room(4.0, 6.0, "");
    let start = Pose2::new(2.0, 3.0, 0.0);
    let mut cfg = ideal(LidarPreset::Urg04lx);
    cfg.sigma = Some(0.02);
    cfg.dropout = 0.1;
    let mut s = sim(&world, &CreateConfig::default(), &[cfg], start, 42);
    let (mut errs, mut drops, mut n) = (Vec::new(), 0usize, 0usize);
    for _ in 0..20 {
        let scan = first_scan(&mut s);
        for (i, &r) in scan.ranges.iter().enumerate() {
            let e = analytic(2.0, 3.0, scan.angle(i), 4.0, 6.0);
            if e > 5.5 {
                continue;
            }
            n += 1;
            if r.is_infinite() {
                drops += 1;
            } else {
                errs.push(r as f64 - e);
            }
        }
    }
    let mean = errs.iter().sum::<f64>() / errs.len() as f64;
    let sd =
        (errs.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / (errs.len() - 1) as f64).sqrt();
    assert!(mean.abs() < 0.002, "mean {mean}");
    assert!((sd - 0.02).abs() < 0.001, "sd {sd}");
    let rate = drops as f64 / n as f64;
    assert!((rate - 0.1).abs() < 0.01, "dropout rate {rate}");
}

#[test]
fn the_robot_does_not_see_itself_and_a_moved_body_is_seen_where_it_is() {
    // A loose box ahead; the robot drives into it and pushes it: the laser keeps seeing the
    // box's near face just ahead of the robot, wherever the box has got to.
    let world = box_room(
        8.0,
        3.0,
        "[[boxes]]\nmaterial = \"m\"\ncenter = [2.0, 1.5]\nsize = [0.4, 0.6, 0.5]\ndynamic = true\nmass = 1.0\nfriction = 0.3\n",
    );
    let box_index = world
        .objects
        .iter()
        .position(|o| o.motion != futago_sim::world::Motion::Static)
        .unwrap();
    let mut laser = ideal(LidarPreset::Urg04lx);
    laser.xyz = [0.0, 0.0, 0.2];
    let mut s = sim(
        &world,
        &CreateConfig::default(),
        &[laser],
        Pose2::new(1.0, 1.5, 0.0),
        3,
    );
    let scan = first_scan(&mut s);
    let ahead = scan.ranges[scan.ranges.len() / 2] as f64;
    assert!(
        (ahead - 0.8).abs() < 1e-3,
        "box face at 1.8 m, robot at 1.0 m: {ahead}"
    );
    s.step(Some(&DriveCommand::Drive {
        velocity: 0.3,
        radius: Radius::Straight,
    }));
    let mut bumped = false;
    let mut last = None;
    for _ in 0..(8.0 / 0.005) as usize {
        let out = s.step(None);
        bumped |= s.bumps().bump_left && s.bumps().bump_right;
        if let Some((_, scan)) = out.scans.into_iter().next() {
            last = Some(scan);
        }
    }
    assert!(bumped, "a head-on push presses both bumpers");
    let box_x = s.object_poses()[box_index].translation.x as f64;
    assert!(box_x > 3.0, "the box was pushed from 2.0 m to {box_x}");
    let robot = s.robot_pose();
    let scan = last.unwrap();
    let ahead = scan.ranges[scan.ranges.len() / 2] as f64;
    let face = box_x - 0.2 - robot.x;
    assert!(
        (ahead - face).abs() < 0.03,
        "laser {ahead} vs box face {face} ahead"
    );
    // Never a return from the robot's own body: beams to the sides and back see the room.
    for (i, r) in scan.ranges.iter().enumerate() {
        if scan.angle(i).abs() > 1.7 {
            assert!(
                *r > 0.5,
                "beam {i} at {:.2} rad returned {r}",
                scan.angle(i)
            );
        }
    }
}
