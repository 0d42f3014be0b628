//! The Create's motion: kinematics, acceleration limit, walls, wheel drops, determinism.

mod common;

use common::*;
use futago_msgs::{DriveCommand, Pose2, Radius};
use futago_sim::create::CreateConfig;
use futago_sim::lidar::{LidarConfig, LidarPreset};

fn odometry_pose(start: Pose2, reports: &[futago_msgs::Odometry]) -> Pose2 {
    let mut p = start;
    for o in reports {
        let mid = p.theta + o.angle / 2.0;
        p = Pose2::new(
            p.x + o.distance * mid.cos(),
            p.y + o.distance * mid.sin(),
            p.theta + o.angle,
        );
    }
    p
}

#[test]
fn a_drive_arc_follows_its_circle_and_odometry_agrees() {
    let world = box_room(10.0, 10.0, "");
    let start = Pose2::new(5.0, 4.0, 0.0);
    let mut s = sim(&world, &CreateConfig::default(), &[], start, 0);
    s.step(Some(&DriveCommand::Drive {
        velocity: 0.2,
        radius: Radius::Arc(1.0),
    }));
    let mut reports = Vec::new();
    let mut max_dev: f64 = 0.0;
    let steps = (2.0 * std::f64::consts::PI / 0.2 / 0.005) as usize;
    for _ in 0..steps {
        let out = s.step(None);
        reports.extend(out.odometry);
        let p = s.robot_pose();
        // Centre of the commanded circle: 1 m to the left of the start.
        max_dev = max_dev.max(((p.x - 5.0).hypot(p.y - 5.0) - 1.0).abs());
    }
    assert!(max_dev < 0.01, "deviation from the 1 m circle: {max_dev}");
    let odo = odometry_pose(start, &reports);
    assert!(
        odo.distance(&s.robot_pose()) < 0.02,
        "odometry {odo:?} vs truth {:?}",
        s.robot_pose()
    );
}

#[test]
fn wheels_accelerate_at_the_firmware_limit() {
    let world = box_room(10.0, 10.0, "");
    let mut s = sim(
        &world,
        &CreateConfig::default(),
        &[],
        Pose2::new(2.0, 5.0, 0.0),
        0,
    );
    s.step(Some(&DriveCommand::Drive {
        velocity: 0.5,
        radius: Radius::Straight,
    }));
    for _ in 0..19 {
        s.step(None);
    }
    // 0.1 s at 1.8 m/s² (the traction can follow: μ·g·0.85 ≈ 6.7 m/s²).
    let v = s.robot_velocity().forward;
    assert!((v - 0.18).abs() < 0.01, "{v}");
}

#[test]
fn a_wall_stops_the_robot_presses_both_bumpers_and_the_wheels_slip() {
    let world = box_room(4.0, 4.0, "");
    let start = Pose2::new(2.0, 2.0, 0.0);
    let mut s = sim(&world, &CreateConfig::default(), &[], start, 0);
    s.step(Some(&DriveCommand::Drive {
        velocity: 0.3,
        radius: Radius::Straight,
    }));
    let mut reports = Vec::new();
    let mut bumps = (false, false);
    for _ in 0..(15.0 / 0.005) as usize {
        let out = s.step(None);
        reports.extend(out.odometry);
        if let Some(b) = out.bumps {
            bumps.0 |= b.bump_left;
            bumps.1 |= b.bump_right;
        }
    }
    let p = s.robot_pose();
    assert!(
        p.x < 4.0 - 0.165 + 0.02 && p.x > 4.0 - 0.165 - 0.05,
        "stopped against the wall at x = 4: {p:?}"
    );
    assert!((p.y - 2.0).abs() < 0.05 && p.theta.abs() < 0.05);
    assert_eq!(bumps, (true, true), "head-on: both bumpers");
    assert!(s.counters().bump_events >= 1);
    let odo: f64 = reports.iter().map(|o| o.distance).sum();
    let truth = p.x - start.x;
    assert!(
        odo > truth + 2.0,
        "spinning wheels count travel that did not happen: odometry {odo} vs {truth}"
    );
}

#[test]
fn an_oblique_hit_presses_the_bumper_on_its_side() {
    let world = box_room(4.0, 4.0, "");
    // Heading 40° left of the +x wall's normal: the wall is met on the right side of the bumper.
    let mut s = sim(
        &world,
        &CreateConfig::default(),
        &[],
        Pose2::new(3.0, 1.0, 0.7),
        0,
    );
    s.step(Some(&DriveCommand::Drive {
        velocity: 0.2,
        radius: Radius::Straight,
    }));
    let mut first = None;
    for _ in 0..2000 {
        s.step(None);
        let b = s.bumps();
        if b.bumped() && first.is_none() {
            first = Some((b.bump_left, b.bump_right));
        }
    }
    assert_eq!(
        first,
        Some((false, true)),
        "first press is the right bumper"
    );
}

#[test]
fn a_hole_in_the_floor_trips_the_wheel_drop_and_stops_the_motors() {
    // No [floor]: two floor boxes with a gap at x 3..4.
    let world = room(
        7.0,
        3.0,
        false,
        "[[boxes]]\nmaterial = \"m\"\ncenter = [1.5, 1.5]\nbase = -0.1\nsize = [3.0, 3.2, 0.1]\n[[boxes]]\nmaterial = \"m\"\ncenter = [5.5, 1.5]\nbase = -0.1\nsize = [3.0, 3.2, 0.1]\n",
    );
    let mut s = sim(
        &world,
        &CreateConfig::default(),
        &[],
        Pose2::new(1.0, 1.5, 0.0),
        0,
    );
    s.step(Some(&DriveCommand::Drive {
        velocity: 0.2,
        radius: Radius::Straight,
    }));
    let mut dropped_at = None;
    for _ in 0..(20.0 / 0.005) as usize {
        let out = s.step(None);
        if let Some(b) = out.bumps
            && b.dropped()
            && dropped_at.is_none()
        {
            dropped_at = Some(s.robot_pose().x);
        }
    }
    let x = dropped_at.expect("a wheel drop was reported");
    // The caster, 0.13 m ahead of the axle, meets the edge at x = 3 first.
    assert!((x - (3.0 - 0.13)).abs() < 0.03, "dropped at {x}");
    let stop = s.robot_pose().x;
    assert!(
        stop - x < 0.05,
        "motors stop at once: dropped at {x}, stopped at {stop}"
    );
    assert_eq!(s.wheel_speeds(), (0.0, 0.0));
}

#[test]
fn same_seed_same_run_other_seed_other_noise() {
    let world = box_room(6.0, 6.0, "");
    let mut robot = CreateConfig::default();
    robot.odometry.noise = 0.01;
    let laser = LidarConfig::preset(LidarPreset::Urg04lx);
    let run = |seed| {
        let mut s = sim(
            &world,
            &robot,
            std::slice::from_ref(&laser),
            Pose2::new(1.0, 1.0, 0.5),
            seed,
        );
        s.step(Some(&DriveCommand::Drive {
            velocity: 0.3,
            radius: Radius::Arc(1.5),
        }));
        let mut scans = Vec::new();
        let mut odo = Vec::new();
        for _ in 0..2000 {
            let out = s.step(None);
            scans.extend(out.scans.into_iter().map(|(_, s)| s.ranges));
            odo.extend(out.odometry.map(|o| (o.distance, o.angle)));
        }
        (s.robot_pose(), scans, odo)
    };
    let (a, b, c) = (run(1), run(1), run(2));
    assert_eq!(a.0, b.0);
    assert_eq!(a.1, b.1);
    assert_eq!(a.2, b.2);
    assert_ne!(a.1, c.1, "laser noise depends on the seed");
    assert_ne!(a.2, c.2, "encoder noise depends on the seed");
    assert_eq!(
        a.0, c.0,
        "the true motion does not: noise is in the measurements"
    );
}
