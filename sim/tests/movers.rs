//! Joints that carry sensors and agents that walk the world, against hand-computed geometry:
//! a turntable turns the scan plane by its angle, a tilt unit points the laser at the floor,
//! and an agent is where its path says, blocks laser rays and pushes the robot.

mod common;

use common::*;
use futago_msgs::{LaserScan, Pose2, Time};
use futago_sim::agent::{AgentConfig, PathMode};
use futago_sim::create::CreateConfig;
use futago_sim::joint::{JointConfig, JointMode};
use futago_sim::lidar::{BeamHit, LidarConfig, LidarPreset};
use futago_sim::{Movers, Simulation, World};

fn with_movers(world: &World, lidars: &[LidarConfig], movers: &Movers, start: Pose2) -> Simulation {
    sim_with(world, &CreateConfig::default(), lidars, movers, start, 1)
}

fn joint(name: &str, mode: JointMode, axis: [f64; 3], rate: f64) -> JointConfig {
    JointConfig {
        name: name.into(),
        mode,
        axis,
        origin: [0.0, 0.0, 0.0],
        rate_deg: rate,
        start_deg: 0.0,
        min_deg: 0.0,
        max_deg: 0.0,
    }
}

/// Steps until a scan comes; returns it with the joints' angles at that step.
fn next_scan(s: &mut Simulation) -> (LaserScan, Vec<f64>) {
    let (scan, _, angles) = next_scan_and_hits(s);
    (scan, angles)
}

/// The next scan, what each of its beams hit, and the joints' angles.
fn next_scan_and_hits(s: &mut Simulation) -> (LaserScan, Vec<BeamHit>, Vec<f64>) {
    for _ in 0..2000 {
        let out = s.step(None);
        if let (Some((_, scan)), Some(hits)) = (out.scans.into_iter().next(), out.hits.first()) {
            return (
                scan,
                hits.clone(),
                s.joints().iter().map(|j| j.angle()).collect(),
            );
        }
    }
    panic!("no scan in 10 s");
}

/// Distance from (x, y) along bearing `a` to the inside of the rectangle [0, w] × [0, h].
fn to_walls(x: f64, y: f64, a: f64, w: f64, h: f64) -> f64 {
    let (dx, dy) = (a.cos(), a.sin());
    let mut t = f64::INFINITY;
    for (d, lo, hi, p) in [(dx, 0.0, w, x), (dy, 0.0, h, y)] {
        if d > 1e-12 {
            t = t.min((hi - p) / d);
        } else if d < -1e-12 {
            t = t.min((lo - p) / d);
        }
    }
    t
}

#[test]
fn a_turntable_turns_the_scan_plane_by_its_angle() {
    let (w, h) = (5.0, 4.0);
    let world = box_room(w, h, "");
    let mut laser = ideal(LidarPreset::Urg04lx);
    laser.joint = Some("table".into());
    let movers = Movers {
        joints: vec![joint("table", JointMode::Continuous, [0.0, 0.0, 1.0], 90.0)],
        agents: vec![],
        ..Default::default()
    };
    let start = Pose2::new(2.0, 1.5, 0.3);
    let mut s = with_movers(&world, &[laser], &movers, start);
    for _ in 0..6 {
        let (scan, angles) = next_scan(&mut s);
        // 90°/s from zero: the table's angle at the step that cast the scan.
        let want = futago_msgs::wrap_angle(90f64.to_radians() * s.time().secs());
        assert!((angles[0] - want).abs() < 1e-9, "{} vs {want}", angles[0]);
        let mut compared = 0;
        for (i, &r) in scan.ranges.iter().enumerate() {
            let a = start.theta + angles[0] + scan.angle(i);
            let want = to_walls(start.x, start.y, a, w, h);
            if r.is_finite() && want < 5.0 {
                assert!((r as f64 - want).abs() < 2e-3, "beam {i}: {r} vs {want}");
                compared += 1;
            }
        }
        assert!(compared > 500, "{compared}");
    }
}

#[test]
fn a_tilt_unit_points_the_laser_at_the_floor() {
    let world = box_room(8.0, 8.0, "");
    let mut laser = ideal(LidarPreset::Utm30lx);
    laser.joint = Some("tilt".into());
    laser.xyz = [0.0, 0.0, 0.5];
    // Positive about +y turns +x down; the axis passes through the laser.
    let mut tilt = joint("tilt", JointMode::Oscillate, [0.0, 1.0, 0.0], 20.0);
    tilt.origin = [0.0, 0.0, 0.5];
    tilt.min_deg = 10.0;
    tilt.max_deg = 40.0;
    tilt.start_deg = 10.0;
    let movers = Movers {
        joints: vec![tilt],
        agents: vec![],
        ..Default::default()
    };
    let mut s = with_movers(&world, &[laser], &movers, Pose2::new(1.0, 4.0, 0.0));
    for _ in 0..8 {
        let (scan, angles) = next_scan(&mut s);
        let pitch = angles[0];
        assert!((10.0..=40.0).contains(&pitch.to_degrees()), "{pitch}");
        // The centre beam (the scan has an even count: the two around 0) meets the floor
        // 0.5 / sin(pitch) away.
        let mid = scan.ranges.len() / 2;
        let want = 0.5 / pitch.sin();
        let got = (scan.ranges[mid - 1] + scan.ranges[mid]) as f64 / 2.0;
        assert!((got - want).abs() < 5e-3, "pitch {pitch}: {got} vs {want}");
    }
}

fn walker(path: Vec<[f64; 2]>, mode: PathMode) -> AgentConfig {
    AgentConfig {
        name: "walker".into(),
        path,
        speed: 1.0,
        mode,
        start_time: 0.0,
        radius: 0.25,
        height: 1.7,
        color: [0.5, 0.3, 0.3],
        turn_radius: 0.0,
    }
}

#[test]
fn an_agent_walks_its_path_and_blocks_the_laser() {
    let world = box_room(6.0, 6.0, "");
    let agent = walker(vec![[3.0, 0.5], [3.0, 5.5]], PathMode::BackAndForth);
    let movers = Movers {
        joints: vec![],
        agents: vec![agent.clone()],
        ..Default::default()
    };
    let start = Pose2::new(1.0, 3.0, 0.0);
    let mut s = with_movers(&world, &[ideal(LidarPreset::Urg04lx)], &movers, start);
    let mut crossed = false;
    for _ in 0..60 {
        let (scan, what, _) = next_scan_and_hits(&mut s);
        let (name, pose) = s.agent_poses()[0];
        assert_eq!(name, "walker");
        assert_eq!(pose, agent.pose_at(s.time()));
        // The body in the physics is where the truth says.
        let body = s.scene_poses()[world.objects.len()];
        assert!((body.translation.x as f64 - pose.x).abs() < 1e-5);
        assert!((body.translation.y as f64 - pose.y).abs() < 1e-5);
        // Straight ahead: the agent's near side when it is in the way, else the far wall.
        let mid = scan.ranges.len() / 2;
        let r = scan.ranges[mid] as f64;
        let bearing = scan.angle(mid);
        let y_hit = start.y + 2.0 * bearing.tan();
        let off = (pose.y - y_hit).abs();
        if off < 0.2 {
            crossed = true;
            // The near side of a 0.25 m circle about the agent's axis (the prism's faces lie
            // within 1.2 mm inside it).
            let want = (pose.x - start.x) - (0.25f64.powi(2) - off * off).sqrt();
            assert!(
                (r - want).abs() < 0.01,
                "agent at {pose:?}: range {r} vs {want}"
            );
            assert_eq!(what[mid], BeamHit::Agent(0), "the beam hit the agent");
        } else if (pose.y - y_hit).abs() > 0.35 {
            assert!((r - 5.0).abs() < 0.01, "agent at {pose:?}: range {r}");
            assert_eq!(what[mid], BeamHit::Static, "the beam hit the wall");
        }
    }
    assert!(crossed, "the agent never crossed the beam");
    assert!(s.time() > Time::from_secs(5.0));
}

#[test]
fn an_agent_pushes_the_robot_and_presses_its_bumper() {
    let world = box_room(8.0, 6.0, "");
    // Walks at the robot (at x = 3, facing it) from x = 6 and on to x = 1.
    let agent = walker(vec![[6.0, 3.0], [1.0, 3.0]], PathMode::Once);
    let movers = Movers {
        joints: vec![],
        agents: vec![agent],
        ..Default::default()
    };
    let start = Pose2::new(3.0, 3.0, 0.0);
    let mut s = with_movers(&world, &[], &movers, start);
    let mut bumped = false;
    for _ in 0..800 {
        s.step(None);
        bumped |= s.bumps().bumped();
    }
    assert!(bumped, "the bumper never closed");
    // The agent reached x = 1 + …; the robot (radius 0.17) was pushed ahead of it.
    let robot = s.robot_pose();
    assert!(robot.x < 3.0 - 1.0, "robot at {robot:?}");
}
