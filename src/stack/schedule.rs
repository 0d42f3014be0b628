//! The order of a run's nodes within each phase, derived from what they consume and publish.
//!
//! A node runs after the nodes that publish what it consumes, so that within a phase it sees
//! what they published at the same instant. Where the topics form a cycle (the people tracker
//! takes SLAM's pose, SLAM masks the tracked people), no order gives every node its inputs
//! fresh: the first node of the cycle in the module table's order runs first and sees the
//! others' outputs one callback late. Those lags are listed ([`Schedule::lags`]), and a run
//! states them in its summary (`schedule.lags`), so that they are a fact of the scenario, not
//! an accident of the table's order. Topics no node publishes (sensor streams, the truth)
//! constrain nothing.

use super::Streams;

/// A consumer that sees a topic one callback after its publisher's: both run in the same
/// phase, and the publisher runs later.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct Lag {
    pub consumer: String,
    pub topic: String,
    pub publisher: String,
}

/// The nodes' order (indices into the nodes as built) and the lags it leaves.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Schedule {
    pub order: Vec<usize>,
    pub lags: Vec<Lag>,
}

/// The schedule of nodes named `names` with `streams`, in the order they were built: each
/// node is placed as early as its inputs allow, ties (and cycles) broken by the built order.
pub fn schedule(names: &[&str], streams: &[Streams]) -> Schedule {
    let n = streams.len();
    // The publishers of each node's inputs, other than itself.
    let inputs: Vec<Vec<(usize, &str)>> = streams
        .iter()
        .enumerate()
        .map(|(i, st)| {
            st.consumes
                .iter()
                .flat_map(|t| {
                    streams
                        .iter()
                        .enumerate()
                        .filter(move |(j, o)| *j != i && o.publishes.contains(t))
                        .map(move |(j, _)| (j, t.as_str()))
                })
                .collect()
        })
        .collect();
    let mut placed = vec![false; n];
    let mut order = Vec::with_capacity(n);
    let mut lags = Vec::new();
    while order.len() < n {
        let ready = (0..n).find(|&i| !placed[i] && inputs[i].iter().all(|&(j, _)| placed[j]));
        // In a cycle, the first node left in the built order goes first and lags.
        let next = ready.unwrap_or_else(|| (0..n).find(|&i| !placed[i]).unwrap_or(0));
        if ready.is_none() {
            for &(j, topic) in &inputs[next] {
                if !placed[j] {
                    lags.push(Lag {
                        consumer: names[next].to_string(),
                        topic: topic.to_string(),
                        publisher: names[j].to_string(),
                    });
                }
            }
        }
        placed[next] = true;
        order.push(next);
    }
    Schedule { order, lags }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn streams(consumes: &[&str], publishes: &[&str]) -> Streams {
        Streams {
            consumes: consumes.iter().map(|s| s.to_string()).collect(),
            publishes: publishes.iter().map(|s| s.to_string()).collect(),
            periods: Vec::new(),
        }
    }

    /// A consumer built before its publisher runs after it; sensor topics and a node's own
    /// outputs constrain nothing; independent nodes keep the built order.
    #[test]
    fn consumers_run_after_their_publishers() {
        let s = [
            streams(&["odometry", "path/coverage"], &["cmd_vel"]),
            streams(&["scan/front"], &["pose/localization"]),
            streams(
                &["truth", "pose/localization"],
                &["path/coverage", "pose/x"],
            ),
            streams(&["pose/x"], &["pose/x"]),
        ];
        let names = ["driver", "localization", "coverage", "self"];
        let sch = schedule(&names, &s);
        assert_eq!(sch.order, [1, 2, 0, 3]);
        assert!(sch.lags.is_empty());
    }

    /// In a cycle the first node of the built order goes first and its lag is listed, once
    /// per topic it takes from a node after it.
    #[test]
    fn a_cycle_keeps_the_built_order_and_states_its_lag() {
        let s = [
            streams(&["pose/slam"], &["people/tracked"]),
            streams(
                &["people/tracked", "scan/front"],
                &["pose/slam", "map/slam"],
            ),
            streams(&["pose/slam", "people/tracked"], &["cmd_vel"]),
        ];
        let names = ["people", "slam", "driver"];
        let sch = schedule(&names, &s);
        assert_eq!(sch.order, [0, 1, 2]);
        assert_eq!(
            sch.lags,
            [Lag {
                consumer: "people".into(),
                topic: "pose/slam".into(),
                publisher: "slam".into(),
            }]
        );
    }
}
