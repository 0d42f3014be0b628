//! Yielding to people (seed 000 §2.6: the robot stops while a person is in its way and
//! resumes when the risk of collision is gone), and the way round one who does not move.
//!
//! **Risk.** Each tracked person is carried forward at their tracked velocity, and the robot
//! along its heading at cruise speed (what it would do if it drove on), over `people_horizon`
//! (2 s). A person who is ahead of the robot and comes within `people_clearance` (0.8 m between
//! centres: the Create's radius 0.17 m, a person's 0.2 m and Hall's intimate distance 0.45 m)
//! of it in that time is a risk. People behind the robot are left out: stopping does not help
//! against someone catching up.
//!
//! **Detour.** While stopped for `people_patience` (5 s), the risk has not passed: someone
//! stands in the way. The navigator then plans to its goal on the grid with every tracked
//! person drawn as an obstacle disc a little wider than `people_clearance`, and follows that
//! path, taking those people for no risk while they stay within 0.3 m of where they stood;
//! where there is no such path (a person in a doorway), it waits on.

use super::planner::{START_CLEARANCE, grid_route};
use crate::tracking::people::TrackedPerson;
use futago_msgs::Pose2;
use futago_msgs::grid::OccupancyGrid;

/// A person the detour goes round is taken to stand still while within this of where they
/// stood, m (a step).
pub const STILL_WITHIN: f64 = 0.3;

/// Time step of the risk's look-ahead, s.
const STEP: f64 = 0.1;

/// Whether any of `people` (map frame) puts the robot at `pose`, driving on along its
/// heading at `speed`, within `clearance` of them within `horizon` seconds, ahead of it.
pub fn at_risk(
    pose: &Pose2,
    speed: f64,
    people: &[TrackedPerson],
    clearance: f64,
    horizon: f64,
) -> bool {
    let (c, s) = (pose.theta.cos(), pose.theta.sin());
    people.iter().any(|p| {
        let rel = pose.inverse().transform_point(p.position);
        if rel[0] <= 0.0 {
            return false;
        }
        let steps = (horizon / STEP).ceil() as usize;
        (0..=steps).any(|k| {
            let t = k as f64 * STEP;
            let robot = [pose.x + c * speed * t, pose.y + s * speed * t];
            let q = [
                p.position[0] + p.velocity[0] * t,
                p.position[1] + p.velocity[1] * t,
            ];
            (robot[0] - q[0]).hypot(robot[1] - q[1]) < clearance
        })
    })
}

/// Whether any of `people` (map frame) stands in the way of the robot at `pose` backing
/// straight up by `distance`: behind it, within `clearance` of that stretch. The Create has no
/// eyes behind; the tracker, which sees people walk up before they get there, is its only
/// warning.
pub fn behind(pose: &Pose2, people: &[TrackedPerson], distance: f64, clearance: f64) -> bool {
    let back = pose.inverse();
    people.iter().any(|p| {
        let [x, y] = back.transform_point(p.position);
        let along = x.clamp(-distance, 0.0);
        x < 0.0 && (x - along).hypot(y) < clearance
    })
}

/// Where people stand, this much wider than the clearance, the detour does not go, m.
const DETOUR_MARGIN: f64 = 0.1;

/// A path from `start` to `goal` on `grid` that keeps `clearance` from the grid's obstacles
/// and passes every person further than `people_clearance` + 0.1 m from their centre (less
/// for one the robot already stands closer to); `None` when there is no such path.
pub fn detour(
    grid: &OccupancyGrid,
    clearance: f64,
    people: &[TrackedPerson],
    people_clearance: f64,
    start: [f64; 2],
    goal: [f64; 2],
) -> Option<Vec<[f64; 2]>> {
    let mut g = grid.clone();
    // A disc of occupied cells round each person, so that the planner's clearance adds to it:
    // the disc's radius plus `clearance` is the distance kept from the person's centre.
    let wide = (people_clearance + DETOUR_MARGIN - clearance).max(0.0);
    for p in people {
        // The robot often stopped closer than that to someone who came near: their disc
        // stops short of its start (by the least clearance the start may escape with, and a
        // cell), so that the way leads off from them rather than nowhere.
        let near = (p.position[0] - start[0]).hypot(p.position[1] - start[1])
            - START_CLEARANCE
            - 1.5 * g.resolution;
        let radius = wide.min(near).max(0.0);
        for (i, j) in crate::geometry::grid::cells_within(&g, p.position, radius) {
            g.set(i, j, 100);
        }
    }
    grid_route(&g, clearance, start, goal)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn person(x: f64, y: f64, vx: f64, vy: f64) -> TrackedPerson {
        TrackedPerson {
            id: 0,
            position: [x, y],
            velocity: [vx, vy],
        }
    }

    #[test]
    fn risk_is_who_the_robot_would_meet_ahead() {
        let robot = Pose2::new(0.0, 0.0, 0.0);
        let at = |p: TrackedPerson| at_risk(&robot, 0.3, &[p], 0.8, 2.0);
        // Standing 1.2 m ahead on the path: the robot reaches 0.6 m within 2 s.
        assert!(at(person(1.2, 0.0, 0.0, 0.0)));
        // Standing 1.2 m ahead but 0.9 m to the side: never within 0.8 m.
        assert!(!at(person(1.2, 0.9, 0.0, 0.0)));
        // Crossing: 2 m ahead, 2 m to the left, walking right at 1 m/s. Their distance falls
        // until after the horizon; at t = 2 s the robot is at (0.6, 0) and the person at
        // (2, 0), 1.4 m apart: no risk.
        assert!(!at(person(2.0, 2.0, 0.0, -1.0)));
        // The same person 1 m ahead: at t = 2 s, (0.6, 0) and (1, 0): 0.4 m.
        assert!(at(person(1.0, 2.0, 0.0, -1.0)));
        // Coming from behind fast: not the robot's to yield to.
        assert!(!at(person(-0.5, 0.0, 1.5, 0.0)));
        // The robot facing the other way sees the standing person behind it.
        let back = Pose2::new(0.0, 0.0, std::f64::consts::PI);
        assert!(!at_risk(
            &back,
            0.3,
            &[person(1.2, 0.0, 0.0, 0.0)],
            0.8,
            2.0
        ));
    }

    /// A 10 m × 4 m free room at 5 cm with walls round it.
    fn room() -> OccupancyGrid {
        crate::geometry::grid::walled(200, 80)
    }

    #[test]
    fn the_detour_keeps_clear_of_a_standing_person_or_is_not_there() {
        let g = room();
        let p = [person(5.0, 2.0, 0.0, 0.0)];
        let path = detour(&g, 0.3, &p, 0.8, [1.0, 2.0], [9.0, 2.0]).expect("a way round");
        assert_eq!(*path.last().unwrap(), [9.0, 2.0]);
        // Every point and every segment of the path stays 0.8 m from the person.
        for w in path.windows(2) {
            for k in 0..=20 {
                let f = k as f64 / 20.0;
                let q = [
                    w[0][0] + f * (w[1][0] - w[0][0]),
                    w[0][1] + f * (w[1][1] - w[0][1]),
                ];
                assert!((q[0] - 5.0).hypot(q[1] - 2.0) > 0.8, "{q:?} in {path:?}");
            }
        }
        // A corridor 1.6 m wide with a person in its middle: no way round.
        let mut narrow = room();
        for j in 0..narrow.height {
            for i in 0..narrow.width {
                let y = narrow.cell_center(i, j)[1];
                if !(1.2..=2.8).contains(&y) {
                    narrow.set(i, j, 100);
                }
            }
        }
        assert!(detour(&narrow, 0.3, &p, 0.8, [1.0, 2.0], [9.0, 2.0]).is_none());
    }

    #[test]
    fn someone_behind_is_in_the_way_of_backing_up() {
        let robot = Pose2::new(2.0, 1.0, std::f64::consts::FRAC_PI_2);
        let at = |x: f64, y: f64| behind(&robot, &[person(x, y, 0.0, 0.0)], 0.3, 0.8);
        // Facing +y: 0.9 m behind is within 0.3 + 0.8; 1.2 m behind is not.
        assert!(at(2.0, 0.1));
        assert!(!at(2.0, -0.2));
        // Beside the robot, a little behind, 0.7 m to its right: in the way; ahead: not.
        assert!(at(2.7, 0.9));
        assert!(!at(2.0, 1.5));
    }

    #[test]
    fn a_robot_stopped_close_to_a_person_still_finds_the_way_round() {
        // 0.59 m from the person, well inside the 0.9 m the detour keeps: the way must start
        // off from them, and never come closer than the escape's least clearance allows.
        let p = [person(5.0, 2.0, 0.0, 0.0)];
        let start = [4.45, 2.2];
        let path = detour(&room(), 0.3, &p, 0.8, start, [9.0, 2.0]).expect("a way round");
        assert_eq!(*path.last().unwrap(), [9.0, 2.0]);
        for q in &path {
            assert!((q[0] - 5.0).hypot(q[1] - 2.0) > 0.5, "{q:?} in {path:?}");
        }
    }
}
