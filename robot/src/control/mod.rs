//! Turning a wish into wheel speeds: pure-pursuit path following ([`pursuit`]) and scripted
//! drive plans ([`script`]: timed segments, waypoints). Goal-directed driving on a map builds
//! on these in [`crate::navigation`]; nothing here depends on it.

pub mod pursuit;
pub mod script;

use serde::Deserialize;

/// Where the waypoint follower takes its pose from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, serde::Serialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum PoseSource {
    /// Dead reckoning from the robot's odometry reports, as a real robot without a localiser.
    #[default]
    Odometry,
    /// The simulator's true pose (an oracle for tests and for driving exact routes).
    GroundTruth,
    /// The localiser's estimate (Monte Carlo localisation on the map), carried forward by
    /// odometry between its updates.
    Localization,
    /// SLAM's estimate (`pose/slam`), carried forward by odometry between its updates: for a
    /// robot that maps as it goes.
    Slam,
}
