//! The [`Bus`]: what the nodes of the loop share on the simulation clock.
//!
//! Messages that are events (scans, frames, odometry reports) are handed to nodes by the
//! loop; what a node publishes for others is kept here as latest values: pose estimates (each
//! with the odometry pose it was made at, so that a consumer carries it to now by odometry,
//! as tf's `map → odom → base` chain does), 2D maps with their stamps, and the drive command.

use futago_msgs::grid::OccupancyGrid;
use futago_msgs::{BumpsAndDrops, DriveCommand, Duration, Pose2, Time};
use futago_robot::control::PoseSource;
use std::collections::{BTreeMap, VecDeque};
use std::sync::Arc;

/// A published path: points in the map frame, m.
type Path = Arc<Vec<[f64; 2]>>;

/// Odometry poses kept for interpolation at scan stamps.
const HISTORY: usize = 256;

/// State shared by the nodes of one run.
pub struct Bus {
    /// Simulation time of the current phase.
    pub now: Time,
    /// The Create's wheel odometry integrated from the start pose (the `odom` frame).
    pub odometry: Pose2,
    /// The wheels' commanded speeds (left, right), m/s, as the Create reports them.
    pub wheel_speeds: (f64, f64),
    /// Bumper and wheel-drop state of this step's report (default without one).
    pub bumps: BumpsAndDrops,
    /// The drive command published at the last control tick, until the loop takes it.
    pub command: Option<DriveCommand>,
    /// `people/tracked`: the people the stack tracks, in the robot base's frame at the last
    /// scan (positions, m; velocities, m/s).
    pub people_tracked: Vec<futago_robot::tracking::people::TrackedPerson>,
    /// When `people/tracked` was published, and the odometry pose then (its base frame).
    pub people_tracked_at: (Time, Pose2),
    /// Each joint's angle, rad, as its encoder reports it with the Create's sensor stream.
    pub joints: Vec<(String, f64)>,
    /// Angles (rad) asked of `command` joints at the last control tick (`joint/NAME`), until
    /// the loop takes them.
    pub joint_commands: Vec<(String, f64)>,
    /// When the driver last finished driving a route (`navigation/route_done`).
    pub route_done: Option<Time>,
    history: VecDeque<(Time, Pose2)>,
    paths: BTreeMap<String, (Time, Path)>,
    estimates: BTreeMap<String, Option<(Pose2, Option<Pose2>)>>,
    /// The covariance of (x, y, θ) published with an estimate, by topic (ROS's
    /// `PoseWithCovariance`): m², m·rad, rad².
    covariances: BTreeMap<String, (Time, [[f64; 3]; 3])>,
    maps: BTreeMap<String, (Time, Arc<OccupancyGrid>)>,
    subscriptions: BTreeMap<String, Option<Duration>>,
}

impl Bus {
    /// A bus at time zero with the robot at `start`; `estimates` are the pose topics some
    /// node publishes, `subscriptions` the map topics consumed (with the period the
    /// consumer wants them at).
    pub fn new(
        start: Pose2,
        estimates: impl IntoIterator<Item = String>,
        subscriptions: impl IntoIterator<Item = (String, Option<Duration>)>,
    ) -> Bus {
        Bus {
            now: Time::ZERO,
            odometry: start,
            wheel_speeds: (0.0, 0.0),
            bumps: BumpsAndDrops::default(),
            command: None,
            people_tracked: Vec::new(),
            people_tracked_at: (Time::ZERO, start),
            joints: Vec::new(),
            joint_commands: Vec::new(),
            route_done: None,
            history: VecDeque::from([(Time::ZERO, start)]),
            paths: BTreeMap::new(),
            estimates: estimates.into_iter().map(|t| (t, None)).collect(),
            covariances: BTreeMap::new(),
            maps: BTreeMap::new(),
            subscriptions: subscriptions.into_iter().collect(),
        }
    }

    /// Records the odometry pose at `t` (the loop does this for every report).
    pub fn push_odometry(&mut self, t: Time, pose: Pose2) {
        self.odometry = pose;
        self.history.push_back((t, pose));
        while self.history.len() > HISTORY {
            self.history.pop_front();
        }
    }

    /// The odometry pose at `t`, interpolated in the recent history (the newest after it,
    /// the oldest kept before it).
    pub fn odometry_at(&self, t: Time) -> Pose2 {
        let Some(&(t_last, p_last)) = self.history.back() else {
            return Pose2::IDENTITY;
        };
        if t >= t_last {
            return p_last;
        }
        for (&(t0, p0), &(t1, p1)) in self.history.iter().zip(self.history.iter().skip(1)) {
            if t >= t0 && t <= t1 {
                let a = if t1 > t0 {
                    (t - t0).secs() / (t1 - t0).secs()
                } else {
                    0.0
                };
                return p0.lerp(&p1, a);
            }
        }
        self.history.front().map(|h| h.1).unwrap_or(p_last)
    }

    /// Publishes `people/tracked`: `people` in the base frame now.
    pub fn publish_people(&mut self, people: Vec<futago_robot::tracking::people::TrackedPerson>) {
        self.people_tracked = people;
        self.people_tracked_at = (self.now, self.odometry);
    }

    /// The tracked people's centres in the base frame now: each carried from when they were
    /// published by their velocity, and into the base's frame now by the odometry since.
    pub fn people_now(&self) -> Vec<[f64; 2]> {
        let (t, then) = self.people_tracked_at;
        let dt = (self.now - t).secs();
        let back = then.between(&self.odometry).inverse();
        self.people_tracked
            .iter()
            .map(|p| {
                back.transform_point([
                    p.position[0] + p.velocity[0] * dt,
                    p.position[1] + p.velocity[1] * dt,
                ])
            })
            .collect()
    }

    /// Publishes estimate `pose` on `pose/TOPIC`, made when odometry read `at`.
    pub fn publish_pose(&mut self, topic: &str, pose: Pose2, at: Pose2) {
        self.set_estimate(topic, Some((pose, Some(at))));
    }

    /// Publishes the covariance of the estimate just published on `pose/TOPIC` (its own
    /// uncertainty when it was made; odometry since adds to it), stamped now.
    pub fn publish_covariance(&mut self, topic: &str, covariance: [[f64; 3]; 3]) {
        let stamped = (self.now, covariance);
        match self.covariances.get_mut(topic) {
            Some(slot) => *slot = stamped,
            None => {
                self.covariances.insert(topic.to_string(), stamped);
            }
        }
    }

    /// The covariance last published with the estimate on `pose/TOPIC`, and its stamp, if
    /// its publisher gives one.
    pub fn covariance(&self, topic: &str) -> Option<(Time, [[f64; 3]; 3])> {
        self.covariances.get(topic).copied()
    }

    /// Publishes estimate `pose` on `pose/TOPIC` to be taken as it is until the next one,
    /// not carried by odometry: a localiser that runs without odometry (seed 001's camera
    /// alone).
    pub fn publish_pose_held(&mut self, topic: &str, pose: Pose2) {
        self.set_estimate(topic, Some((pose, None)));
    }

    /// Sets the estimate on `pose/TOPIC`, allocating its name only the first time (the oracle
    /// publishes at every physics step).
    fn set_estimate(&mut self, topic: &str, e: Option<(Pose2, Option<Pose2>)>) {
        match self.estimates.get_mut(topic) {
            Some(slot) => *slot = e,
            None => {
                self.estimates.insert(topic.to_string(), e);
            }
        }
    }

    /// The estimate on `pose/TOPIC` now, carried from when it was made by odometry (unless it
    /// was published held); odometry
    /// itself before the first estimate; `None` when no node publishes that topic.
    pub fn pose(&self, topic: &str) -> Option<Pose2> {
        self.estimates.get(topic).map(|e| match e {
            Some((est, Some(at))) => est.compose(&at.between(&self.odometry)),
            Some((est, None)) => *est,
            None => self.odometry,
        })
    }

    /// The pose `source` gives now: its odometry, or the estimate on the source's topic
    /// ([`pose_topic`]) carried to now by odometry, odometry until one is published. The
    /// ground-truth source is the oracle node's `pose/ground_truth` (see
    /// [`crate::stack::oracle`]), held as published at every physics step.
    pub fn pose_from(&self, source: PoseSource) -> Pose2 {
        match source {
            PoseSource::GroundTruth => self.pose(GROUND_TRUTH).unwrap_or(self.odometry),
            PoseSource::Odometry => self.odometry,
            PoseSource::Localization => self.pose("localization").unwrap_or(self.odometry),
            PoseSource::Slam => self.pose("slam").unwrap_or(self.odometry),
        }
    }

    /// Publishes a map on `map/TOPIC`, stamped now.
    pub fn publish_map(&mut self, topic: &str, map: OccupancyGrid) {
        self.maps
            .insert(topic.to_string(), (self.now, Arc::new(map)));
    }

    /// Publishes a path (a route to drive, map frame) on `path/TOPIC`, stamped now.
    pub fn publish_path(&mut self, topic: &str, points: Vec<[f64; 2]>) {
        self.paths
            .insert(topic.to_string(), (self.now, Arc::new(points)));
    }

    /// The latest path on `path/TOPIC` and its stamp.
    pub fn path(&self, topic: &str) -> Option<(Time, &Path)> {
        self.paths.get(topic).map(|(t, p)| (*t, p))
    }

    /// The latest map on `map/TOPIC` and its stamp.
    pub fn map(&self, topic: &str) -> Option<(Time, &Arc<OccupancyGrid>)> {
        self.maps.get(topic).map(|(t, m)| (*t, m))
    }

    /// Whether some node consumes `map/TOPIC`, and at which period (`Some(None)`: whenever
    /// it changes).
    pub fn subscription(&self, topic: &str) -> Option<Option<Duration>> {
        self.subscriptions.get(topic).copied()
    }
}

/// `navigation/route_done`: when the driver last finished a route ([`Bus::route_done`]).
pub const ROUTE_DONE: &str = "navigation/route_done";

/// The oracle's pose topic, `pose/ground_truth`: the robot's true pose, published only in
/// scenarios where a module asks for it.
pub const GROUND_TRUTH: &str = "ground_truth";

/// The topic a node that takes its pose from `source` consumes (`pose/slam`), if any.
pub fn pose_topic(source: PoseSource) -> Option<String> {
    match source {
        PoseSource::Localization => Some("pose/localization".into()),
        PoseSource::Slam => Some("pose/slam".into()),
        PoseSource::GroundTruth => Some(format!("pose/{GROUND_TRUTH}")),
        PoseSource::Odometry => None,
    }
}
