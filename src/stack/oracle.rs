//! The oracle: the one node that puts the simulator's truth on the robot's bus.
//!
//! A module told to steer or map by `pose_source = "ground_truth"` (tests, exact routes, a
//! map built on perfect poses to isolate another error) consumes `pose/ground_truth`. The
//! oracle publishes it, the robot's true pose held as it is, after every physics step and
//! once before the first control tick, so its consumers see the same pose the simulator has
//! at each of their callbacks. [`super::build_with`] adds the oracle only where some node
//! consumes the topic, and the run's summary then names it under `oracle`, so a result that
//! leaned on the truth says so.

use super::bus::GROUND_TRUTH;
use super::{Bus, Node, Report, Streams, TrueState};
use anyhow::Result;
use serde_json::json;
use std::path::Path;

/// Publishes the true pose on `pose/ground_truth`.
pub struct OracleNode {
    /// The nodes that consume it, for the summary.
    consumers: Vec<String>,
}

impl OracleNode {
    /// The oracle for the nodes named `consumers`.
    pub fn new(consumers: Vec<String>) -> OracleNode {
        OracleNode { consumers }
    }
}

impl Node for OracleNode {
    fn name(&self) -> &'static str {
        "oracle"
    }

    fn streams(&self) -> Streams {
        Streams {
            consumes: vec!["truth/step".into()],
            publishes: vec![format!("pose/{GROUND_TRUTH}")],
            ..Streams::default()
        }
    }

    fn on_truth(&mut self, truth: &TrueState, bus: &mut Bus) -> Result<()> {
        bus.publish_pose_held(GROUND_TRUTH, truth.robot);
        Ok(())
    }

    fn finish(&mut self, _bus: &mut Bus, _out: Option<&Path>) -> Result<Report> {
        Ok(Report {
            summary: vec![(
                "oracle".into(),
                json!({
                    "publishes": format!("pose/{GROUND_TRUTH}"),
                    "consumers": self.consumers,
                }),
            )],
            ..Report::default()
        })
    }
}
