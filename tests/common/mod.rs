//! What the end-to-end tests share: running the command, and reading what it wrote.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// `futago ARGS` run in the repository's folder.
pub fn futago(args: &[&str]) -> Output {
    futago_in(Path::new(env!("CARGO_MANIFEST_DIR")), args)
}

/// `futago ARGS` run in `dir`.
pub fn futago_in(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_futago"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("futago runs")
}

/// The repository's folder.
pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Asserts that the command succeeded, showing its output when it did not.
pub fn ok(o: &Output) {
    assert!(
        o.status.success(),
        "futago failed:\nstdout: {}\nstderr: {}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
}

/// Writes `bytes` to `dir/name`; its path.
pub fn write(dir: &Path, name: &str, bytes: impl AsRef<[u8]>) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

pub fn json_file(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// The `summary.json` of the output folder `dir`.
pub fn summary(dir: &Path) -> serde_json::Value {
    json_file(&dir.join("summary.json"))
}

/// The range along the beam at `a` (laser frame) from `p` in a 6 m × 4 m room centred on the
/// origin with a box at [1, 1.5] × [0.8, 1.3]: the room's walls, or the box.
pub fn room_cast(p: futago_msgs::Pose2, a: f64) -> f32 {
    let (s, c) = (p.theta + a).sin_cos();
    let mut t = f64::INFINITY;
    for (d, o, lo, hi) in [(c, p.x, -3.0, 3.0), (s, p.y, -2.0, 2.0)] {
        if d > 1e-12 {
            t = t.min((hi - o) / d);
        } else if d < -1e-12 {
            t = t.min((lo - o) / d);
        }
    }
    // The box [1, 1.5] × [0.8, 1.3] by slabs.
    let (mut near, mut far) = (0.0f64, f64::INFINITY);
    for (d, o, lo, hi) in [(c, p.x, 1.0, 1.5), (s, p.y, 0.8, 1.3)] {
        if d.abs() < 1e-12 {
            if o < lo || o > hi {
                far = -1.0;
            }
        } else {
            let (a, b) = ((lo - o) / d, (hi - o) / d);
            near = near.max(a.min(b));
            far = far.min(a.max(b));
        }
    }
    if near <= far && near > 0.0 {
        t = t.min(near);
    }
    t as f32
}

/// A CARMEN `FLASER` line: `ranges` (written to the millimetre), the robot at `pose` as both
/// the laser's and the odometry's pose, and the stamp `t` as both the IPC and the logger time.
pub fn flaser_line(ranges: &[f32], pose: futago_msgs::Pose2, t: f64) -> String {
    let ranges: Vec<String> = ranges.iter().map(|r| format!("{r:.3}")).collect();
    format!(
        "FLASER {} {} {x} {y} {th} {x} {y} {th} {t} host {t}\n",
        ranges.len(),
        ranges.join(" "),
        x = pose.x,
        y = pose.y,
        th = pose.theta
    )
}

/// Two 3 × 4 m rooms joined by a 0.9 m doorway; a wall across most of the east room hides its
/// far side from the doorway, and a cabinet there makes the two rooms look different.
pub const TWO_ROOMS: &str = r#"
name = "two-rooms"
[materials.plaster]
color = [0.8, 0.8, 0.8]
[floor]
material = "plaster"
[[walls]]
material = "plaster"
points = [[0, 0], [6, 0], [6, 4], [0, 4]]
closed = true
height = 1.0
thickness = 0.1
[[walls]]
material = "plaster"
points = [[3, 0], [3, 4]]
height = 1.0
thickness = 0.1
openings = [{ at = [3, 2.8], width = 0.9, top = 0.9 }]
[[walls]]
material = "plaster"
points = [[4.5, 0], [4.5, 3.0]]
height = 1.0
thickness = 0.1
[[boxes]]
material = "plaster"
center = [5.2, 0.8]
size = [0.8, 0.5, 0.6]
"#;

/// The environment variable naming the Python interpreter that has the independent ROS 2
/// tools (`rosbags`, `mcap`, `mcap-ros2-support`); `python3` when unset.
pub const PYTHON_ENV: &str = "FUTAGO_PYTHON";

/// With `FUTAGO_REQUIRE_PYTHON=1` a test whose Python tools are missing fails instead of
/// skipping (CI sets it, having installed them).
pub const REQUIRE_PYTHON_ENV: &str = "FUTAGO_REQUIRE_PYTHON";

/// The Python interpreter that imports every module of `modules`, or `None` (the skip printed)
/// when there is none, for the test `test`.
pub fn python_with(test: &str, modules: &[&str]) -> Option<PathBuf> {
    let python = std::env::var_os(PYTHON_ENV)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("python3"));
    let script = modules
        .iter()
        .map(|m| format!("import {m}"))
        .collect::<Vec<_>>()
        .join("; ");
    let found = Command::new(&python)
        .args(["-c", &script])
        .output()
        .is_ok_and(|o| o.status.success());
    if found {
        return Some(python);
    }
    let line = format!(
        "skipped {test}: needs {} importing {} (pip install {} in a virtual environment, and set {PYTHON_ENV} to its python)",
        python.display(),
        modules.join(", "),
        modules.join(" ")
    );
    if std::env::var(REQUIRE_PYTHON_ENV).is_ok_and(|v| v == "1") {
        panic!("{line} ({REQUIRE_PYTHON_ENV}=1 makes this a failure)");
    }
    println!("{line}");
    None
}

/// With `FUTAGO_REQUIRE_DDS=1` a test of the DDS link on a machine where UDP multicast does
/// not loop back fails instead of skipping.
pub const REQUIRE_DDS_ENV: &str = "FUTAGO_REQUIRE_DDS";

/// Whether this machine delivers UDP multicast back to itself, as DDS discovery (SPDP to
/// 239.255.0.1) needs between two participants on it; prints the skip for `test` when not.
pub fn multicast_with(test: &str) -> bool {
    use std::net::{Ipv4Addr, UdpSocket};
    let group = Ipv4Addr::new(239, 255, 0, 1);
    let loops = (|| -> std::io::Result<bool> {
        let rx = UdpSocket::bind((Ipv4Addr::UNSPECIFIED, 0))?;
        rx.join_multicast_v4(&group, &Ipv4Addr::UNSPECIFIED)?;
        rx.set_read_timeout(Some(std::time::Duration::from_secs(2)))?;
        let port = rx.local_addr()?.port();
        let tx = UdpSocket::bind((Ipv4Addr::UNSPECIFIED, 0))?;
        tx.set_multicast_loop_v4(true)?;
        tx.send_to(b"futago", (group, port))?;
        let mut buf = [0u8; 16];
        let (n, _) = rx.recv_from(&mut buf)?;
        Ok(&buf[..n] == b"futago")
    })()
    .unwrap_or(false);
    if loops {
        return true;
    }
    let line = format!(
        "skipped {test}: needs UDP multicast that loops back on this machine (DDS discovery sends \
         to 239.255.0.1)"
    );
    if std::env::var(REQUIRE_DDS_ENV).is_ok_and(|v| v == "1") {
        panic!("{line} ({REQUIRE_DDS_ENV}=1 makes this a failure)");
    }
    println!("{line}");
    false
}

/// Whether a UDP socket here may have a receive buffer of `bytes`: Linux caps what a program
/// asks for at `net.core.rmem_max`, 208 KiB by default, which loses the fragments of a large
/// DDS sample (a camera image) sent in one burst. ROS 2's DDS tuning guide raises it; `.ci/run`
/// does. Otherwise `test` is skipped, or fails under `FUTAGO_REQUIRE_DDS=1`.
pub fn udp_receive_buffer_with(test: &str, bytes: u64) -> bool {
    let Ok(max) = std::fs::read_to_string("/proc/sys/net/core/rmem_max") else {
        return true;
    };
    let max: u64 = max.trim().parse().unwrap_or(0);
    if max >= bytes {
        return true;
    }
    let line = format!(
        "skipped {test}: needs UDP receive buffers of {bytes} bytes, and net.core.rmem_max is \
         {max} (sysctl -w net.core.rmem_max={bytes})"
    );
    if std::env::var(REQUIRE_DDS_ENV).is_ok_and(|v| v == "1") {
        panic!("{line} ({REQUIRE_DDS_ENV}=1 makes this a failure)");
    }
    println!("{line}");
    false
}

/// Runs `scenario` (relative to the repository) for `seconds` into `out`, with `args` after
/// the usual ones. Cut short, a run may fail its gates (exit 3); its files are written all
/// the same, so that passes too.
pub fn run_cut_short(scenario: &str, seconds: &str, out: &Path, args: &[&str]) {
    let scenario = root().join(scenario);
    let mut all = vec![
        "run",
        scenario.to_str().unwrap(),
        "--duration",
        seconds,
        "-q",
        "--out",
        out.to_str().unwrap(),
    ];
    all.extend(args);
    let o = futago(&all);
    assert!(
        matches!(o.status.code(), Some(0) | Some(3)),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}
