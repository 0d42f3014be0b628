//! Where the real logs that futago's accuracy tests replay are found, and what to do when
//! they are not there.
//!
//! The logs are public but large, so the repository does not carry them. They are looked up
//! in the folder named by the environment variable [`DATA_ENV`] (`FUTAGO_DATA`), laid out as
//! below, or else in `../shared/datasets` beside the repository where that exists. A test
//! that needs a log that is absent says so in one line (which file, where it looked, where
//! to get it and its SHA-256) and passes without checking anything, unless
//! [`REQUIRE_ENV`] (`FUTAGO_REQUIRE_DATA=1`) is set, as CI sets it: then the absence fails
//! the test.
//!
//! ```text
//! slam-benchmark/mit-csail.clf, mit-csail.orig.bag, mit-csail.relations,
//!                intel.orig.bag, intel.relations,
//!                fr-clinic_robotlaser.orig.bag, fr-clinic.relations
//! people/general_tracking_moving_1.bag
//! ```

use std::path::{Path, PathBuf};

/// The environment variable naming the data folder.
pub const DATA_ENV: &str = "FUTAGO_DATA";
/// The environment variable that makes a missing log a failure (`1`).
pub const REQUIRE_ENV: &str = "FUTAGO_REQUIRE_DATA";

/// A log the tests use: its path in the data folder, its SHA-256 and where it comes from.
#[derive(Debug, Clone, Copy)]
pub struct Dataset {
    pub path: &'static str,
    pub sha256: &'static str,
    pub source: &'static str,
}

const SLAM: &str = "the SLAM benchmark of Kümmerle et al., \"On measuring the accuracy of SLAM algorithms\" (Autonomous Robots 27(4), 2009), University of Freiburg; the bags are its CARMEN logs converted to ROS 1 bags with their original stamps";
const PEOPLE: &str = "the leg_tracker benchmark of Leigh, Pineau, Olmedo and Zhang, \"Person Tracking and Following with 2D Laser Scanners\" (ICRA 2015)";

/// The logs futago's tests replay.
pub const DATASETS: &[Dataset] = &[
    Dataset {
        path: "slam-benchmark/mit-csail.clf",
        sha256: "f40f31cf9e561cb2a0cb0ca2f4a809abb319543cd1b2875f6c8c6a0138559ca4",
        source: SLAM,
    },
    Dataset {
        path: "slam-benchmark/mit-csail.orig.bag",
        sha256: "d8fde828fa92b605769fac7521cf24111b8f14cdde51b983c8a0614671f76b93",
        source: SLAM,
    },
    Dataset {
        path: "slam-benchmark/mit-csail.relations",
        sha256: "ffd7ebe97fa1738913931e39ca643ee0a1b67de80499b0197a3d01abad0f589d",
        source: SLAM,
    },
    Dataset {
        path: "slam-benchmark/intel.orig.bag",
        sha256: "b37cdd3988b49893edb7afe353d55739327a6e68196f257e62e7fb287860fb5d",
        source: SLAM,
    },
    Dataset {
        path: "slam-benchmark/intel.relations",
        sha256: "330378f153eeae652d6756c1746f335801f66c3e097d90611548e6c4f593c359",
        source: SLAM,
    },
    Dataset {
        path: "slam-benchmark/fr-clinic_robotlaser.orig.bag",
        sha256: "0b5c3f5b24d277e2a0e38b385f6c09c6cf12e490f6ae7990978f0743bf1aebaf",
        source: SLAM,
    },
    Dataset {
        path: "slam-benchmark/fr-clinic.relations",
        sha256: "583b7bba8c1a3ef1f7ad41221c151534333e71b52f5fc267d5e343c79355300c",
        source: SLAM,
    },
    Dataset {
        path: "people/general_tracking_moving_1.bag",
        sha256: "69cadfdbfa4925cd9ec11e4d979fb4501da69a9799c4fe93deb91d01b5c831cb",
        source: PEOPLE,
    },
];

/// The data folder: `FUTAGO_DATA`, or `../shared/datasets` from `repo_root` where it
/// exists; `None` when neither is set or there.
pub fn folder(repo_root: &Path) -> Option<PathBuf> {
    match std::env::var_os(DATA_ENV) {
        Some(d) if !d.is_empty() => Some(PathBuf::from(d)),
        _ => Some(repo_root.join("../shared/datasets")).filter(|d| d.is_dir()),
    }
}

/// The files `paths` (relative to the data folder) for the test `test`, or `None` when one is
/// missing, after printing which test is skipped, what it needs and how to get it. With
/// `FUTAGO_REQUIRE_DATA=1` a missing file panics (the test fails) instead.
pub fn require(repo_root: &Path, test: &str, paths: &[&str]) -> Option<Vec<PathBuf>> {
    let dir = folder(repo_root);
    let found: Vec<PathBuf> = paths
        .iter()
        .filter_map(|p| dir.as_ref().map(|d| d.join(p)).filter(|f| f.is_file()))
        .collect();
    if found.len() == paths.len() {
        return Some(found);
    }
    let missing: Vec<String> = paths
        .iter()
        .filter(|p| !dir.as_ref().is_some_and(|d| d.join(p).is_file()))
        .map(|p| match DATASETS.iter().find(|d| d.path == *p) {
            Some(d) => format!("{p} (SHA-256 {}; from {})", d.sha256, d.source),
            None => p.to_string(),
        })
        .collect();
    let where_ = match &dir {
        Some(d) => format!("in {}", d.display()),
        None => format!(
            "({DATA_ENV} is not set and {} does not exist)",
            repo_root.join("../shared/datasets").display()
        ),
    };
    let line = format!(
        "skipped {test}: needs {} {where_}; put the files in a folder and set {DATA_ENV} to it",
        missing.join(", ")
    );
    if std::env::var(REQUIRE_ENV).is_ok_and(|v| v == "1") {
        panic!("{line} ({REQUIRE_ENV}=1 makes this a failure)");
    }
    // Straight to stderr: the test harness shows a passing test's printed output only when
    // asked (`--nocapture`), and the skip must be seen.
    use std::io::Write;
    let _ = writeln!(std::io::stderr(), "{line}");
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_dataset_has_a_digest_and_a_source() {
        for d in DATASETS {
            assert_eq!(d.sha256.len(), 64, "{}", d.path);
            assert!(
                d.sha256.chars().all(|c| c.is_ascii_hexdigit()),
                "{}",
                d.path
            );
            assert!(!d.source.is_empty());
        }
    }
}
