//! The order of the stack's nodes follows from what they consume and publish, and where the
//! topics form a cycle the lag it leaves is stated. In process, on shipped scenarios.

use futago::stack::{self, schedule};
use std::path::Path;

/// The schedule of a shipped scenario's stack: node names in order, and the lags.
fn schedule_of(name: &str) -> (Vec<String>, Vec<schedule::Lag>) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenarios")
        .join(format!("{name}.toml"));
    let s = stack::load(&path).unwrap_or_else(|e| panic!("{e}"));
    let nodes = stack::build(&s, 0, None).unwrap();
    let names: Vec<&str> = nodes.iter().map(|n| n.name()).collect();
    let streams: Vec<stack::Streams> = nodes.iter().map(|n| n.streams()).collect();
    let sch = schedule::schedule(&names, &streams);
    (
        sch.order.iter().map(|&i| names[i].to_string()).collect(),
        sch.lags,
    )
}

fn before(order: &[String], a: &str, b: &str) -> bool {
    let at = |n: &str| order.iter().position(|x| x == n).unwrap();
    at(a) < at(b)
}

fn lag(consumer: &str, topic: &str, publisher: &str) -> schedule::Lag {
    schedule::Lag {
        consumer: consumer.into(),
        topic: topic.into(),
        publisher: publisher.into(),
    }
}

#[test]
fn publishers_run_before_their_consumers_and_cycles_state_their_lag() {
    // The driver steers on the localiser's pose: the localiser runs first, though the module
    // table lists the driver first.
    let (order, lags) = schedule_of("office-mcl");
    assert!(before(&order, "localization", "driver"), "{order:?}");
    assert!(lags.is_empty(), "{lags:?}");

    // The turntable mapper hands the driver its views and waits for the driver to finish
    // them: a cycle, kept in the table's order, the driver taking a view a tick late.
    let (order, lags) = schedule_of("corridor-scan3d-truth");
    assert!(before(&order, "driver", "scan3d"), "{order:?}");
    assert!(before(&order, "oracle", "driver"), "{order:?}");
    assert_eq!(lags, [lag("driver", "path/scan3d", "scan3d")]);

    // Coverage publishes the route first and hears that it was driven a tick late.
    let (order, lags) = schedule_of("office-coverage");
    assert!(before(&order, "coverage", "driver"), "{order:?}");
    assert_eq!(lags, [lag("coverage", "navigation/route_done", "driver")]);

    // The people tracker places its scans by the localiser's pose and map; the localiser
    // masks the tracked people: the tracker sees the localiser's outputs a scan late.
    let (_, lags) = schedule_of("office-doorway");
    assert_eq!(
        lags,
        [
            lag("people", "pose/localization", "localization"),
            lag("people", "map/localization", "localization"),
        ]
    );
}
