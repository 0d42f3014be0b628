//! Following what moves: optimal assignment ([`assignment`]), the people tracker
//! ([`people`]), which turns leg detections into tracks of people, and the cutting of tracked
//! people out of scans and keyframes ([`exclusion`]). [`PeopleConfig`] gathers the settings
//! of the whole people pipeline, detectors included.

pub mod assignment;
pub mod exclusion;
pub mod laser_people;
pub mod people;

use crate::config::ConfigError;
use crate::perception::depth_people::DepthPeopleConfig;
use crate::perception::free_space::FreeSpaceConfig;
use crate::perception::legs::LegConfig;
use crate::perception::motion::MotionConfig;
use exclusion::ExclusionConfig;
use people::TrackerConfig;
use serde::{Deserialize, Serialize};

/// Settings of people detection and tracking (`people`).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct PeopleConfig {
    /// The laser leg detector (`people.legs`).
    pub legs: LegConfig,
    /// The moving-object detectors (`people.motion`).
    pub motion: MotionConfig,
    /// The depth-image person detector (`people.depth`).
    pub depth: DepthPeopleConfig,
    /// The tracker (`people.tracker`).
    pub tracker: TrackerConfig,
    /// Cutting tracked people out of the scans and keyframes the maps and the localiser
    /// take (`people.exclusion`).
    pub exclusion: ExclusionConfig,
    /// Without a map, where the floor has been seen: leg candidates elsewhere start no track
    /// (`people.free_space`).
    pub free_space: FreeSpaceConfig,
    /// A map that grows (SLAM's) is taken for the map difference at most this often, s (0:
    /// at every change). Taking one computes its distance transform over the whole grid:
    /// at every SLAM update among walkers that was 264 of a 300 s run in the pillared hall,
    /// and a map a second old lacks only what the robot has seen in that second, which the
    /// map difference reads as unknown, not free, so it flags nothing there. (After a loop
    /// closure moves SLAM's map, the old one is read against the new pose for up to that
    /// long.)
    pub map_period: f64,
}

impl Default for PeopleConfig {
    fn default() -> Self {
        PeopleConfig {
            legs: LegConfig::default(),
            motion: MotionConfig::default(),
            depth: DepthPeopleConfig::default(),
            tracker: TrackerConfig::default(),
            exclusion: ExclusionConfig::default(),
            free_space: FreeSpaceConfig::default(),
            map_period: 1.0,
        }
    }
}

impl PeopleConfig {
    /// Checks every field; errors name the full key (`people.legs.threshold`).
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.legs.validate("people.legs")?;
        self.motion.validate("people.motion")?;
        self.depth.validate("people.depth")?;
        self.tracker.validate("people.tracker")?;
        self.exclusion.validate("people.exclusion")?;
        self.free_space.validate("people.free_space")?;
        crate::config::check_ranges("people", &[("map_period", self.map_period, 0.0, 3600.0)])
    }
}
