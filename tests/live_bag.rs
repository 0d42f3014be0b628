//! `[output] mcap = true`: a live run written as a ROS 2 bag (`ros2/`) as it goes. It must
//! not change what the run computes, and independent readers (Python's `mcap` with
//! `mcap-ros2-support`, and `rosbags`) must decode every message of it.

mod common;
use common::{python_with, run_cut_short};
use std::path::Path;

/// Runs `scenario` for `seconds` into `out`, with the bag when `mcap`.
fn run(scenario: &str, seconds: &str, out: &Path, mcap: bool) {
    let set = format!("output.mcap={mcap}");
    run_cut_short(scenario, seconds, out, &["--set", &set]);
}

fn summary(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap()
}

#[test]
fn the_bag_changes_nothing_the_run_computes_and_is_the_same_bytes_twice() {
    let tmp = tempfile::tempdir().unwrap();
    // A camera that renders only for the localiser's people check, a person, a map.
    let scenario = "scenarios/office-doorway.toml";
    let (without, with, again) = (
        tmp.path().join("without"),
        tmp.path().join("with"),
        tmp.path().join("again"),
    );
    run(scenario, "6", &without, false);
    run(scenario, "6", &with, true);
    run(scenario, "6", &again, true);
    let (a, b, c) = (summary(&without), summary(&with), summary(&again));
    // Every file the run wrote without the bag, byte for byte (but the scenario as run,
    // which says `mcap = true`), and everything else the summary says.
    let digests = a["files"].as_object().expect("files' digests");
    assert!(digests.contains_key("groundtruth.txt"), "{digests:?}");
    for (file, digest) in digests {
        if file != "scenario.toml" {
            assert_eq!(&b["files"][file], digest, "{file} changed with the bag");
        }
    }
    for (key, value) in a.as_object().unwrap() {
        if !["files", "performance", "overlays"].contains(&key.as_str()) {
            assert_eq!(&b[key], value, "{key} changed with the bag");
        }
    }
    assert!(a.get("mcap").is_none() && !without.join("ros2").exists());
    // The bag's digest, the same on a second run.
    let bag = &b["files"]["ros2/"]["sha256"];
    assert!(bag.is_string(), "{}", b["files"]);
    assert_eq!(bag, &c["files"]["ros2/"]["sha256"]);
    // It holds the camera's images and the map.
    let counts = &b["mcap"]["messages"];
    for topic in [
        "/kinect/depth/image_raw",
        "/map",
        "/ground_truth/people",
        "/scan",
        "/localization/pose",
    ] {
        assert!(counts[topic].as_u64().unwrap_or(0) > 0, "{topic}: {counts}");
    }
}

/// Decodes every message of the bag `argv[1]` with `mcap` + `mcap-ros2-support` and with
/// `rosbags`, checks what each type must hold, and prints `READER TOPIC COUNT` lines.
const READERS: &str = r#"
import sys, collections, math
import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
bag = sys.argv[1]
counts = collections.Counter()
tf_children = set()
with open(bag + "/ros2.mcap", "rb") as f:
    reader = make_reader(f, decoder_factories=[DecoderFactory()])
    assert reader.get_header().profile == "ros2"
    for schema, channel, message, ros in reader.iter_decoded_messages():
        counts[channel.topic] += 1
        t = channel.topic
        if t.endswith("image_raw"):
            px = {"rgb8": 3, "32FC1": 4}[ros.encoding]
            assert ros.step == px * ros.width and len(ros.data) == ros.step * ros.height > 0
            if ros.encoding == "32FC1":
                d = np.frombuffer(bytes(ros.data), dtype="<f4")
                ok = d[~np.isnan(d)]
                assert ok.size > 0 and (ok > 0).all() and (ok < 20).all(), ok
        if t.endswith("camera_info"):
            assert ros.k[0] > 0 and ros.k[8] == 1 and ros.p[10] == 1 and ros.width > 0
        if t == "/tf" or t == "/tf_static":
            for x in ros.transforms:
                q = x.transform.rotation
                assert abs(q.x**2 + q.y**2 + q.z**2 + q.w**2 - 1) < 1e-9
                tf_children.add(x.header.frame_id + ">" + x.child_frame_id)
        if t == "/ground_truth/people":
            assert ros.markers[0].action == 3
            assert all(m.type == 3 and m.scale.z > 1.2 for m in ros.markers[1:])
        if t == "/odom":
            assert ros.child_frame_id == "base_link"
        if t == "/map":
            assert len(ros.data) == ros.info.width * ros.info.height > 0
for t, n in sorted(counts.items()):
    print("mcap", t, n)
print("tf", " ".join(sorted(tf_children)))
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore
store = get_typestore(Stores.ROS2_HUMBLE)
counts = collections.Counter()
with Reader(bag) as reader:
    last = -1
    for conn, stamp, raw in reader.messages():
        store.deserialize_cdr(raw, conn.msgtype)
        counts[conn.topic] += 1
        assert stamp >= last
        last = stamp
for t, n in sorted(counts.items()):
    print("rosbags", t, n)
"#;

#[test]
fn independent_readers_decode_every_message_of_a_live_runs_bag() {
    let test = "independent_readers_decode_every_message_of_a_live_runs_bag";
    let Some(python) = python_with(test, &["rosbags", "mcap", "mcap_ros2", "numpy"]) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    // A camera, a person and a map; a turntable, two lasers and people.
    for (scenario, tf) in [
        (
            "scenarios/office-doorway.toml",
            &[
                "map>odom",
                "odom>base_link",
                "base_link>kinect_optical_frame",
            ][..],
        ),
        (
            "scenarios/hall-scan3d.toml",
            &["base_link>table", "table>vertical", "base_link>horizontal"][..],
        ),
    ] {
        let out = tmp.path().join(Path::new(scenario).file_stem().unwrap());
        run(scenario, "4", &out, true);
        let o = std::process::Command::new(&python)
            .args(["-c", READERS, out.join("ros2").to_str().unwrap()])
            .output()
            .unwrap();
        let printed = String::from_utf8_lossy(&o.stdout);
        assert!(
            o.status.success(),
            "{scenario}: {printed}\n{}",
            String::from_utf8_lossy(&o.stderr)
        );
        let counts = summary(&out)["mcap"]["messages"].clone();
        let counts = counts.as_object().unwrap();
        assert!(counts.len() >= 6, "{counts:?}");
        for (topic, n) in counts {
            for reader in ["mcap", "rosbags"] {
                assert!(
                    printed.contains(&format!("{reader} {topic} {n}\n")),
                    "{scenario}: {reader} {topic} {n}: {printed}"
                );
            }
        }
        let frames = printed.lines().find_map(|l| l.strip_prefix("tf ")).unwrap();
        for edge in tf {
            assert!(
                frames.split(' ').any(|f| f == *edge),
                "{scenario}: no {edge} in {frames}"
            );
        }
    }
}
