//! futago (双子, "twin"): a simulation-first digital twin testbed for small indoor robots.
//!
//! The library under the `futago` command. Its modules form layers, each using only the
//! layers before it (`tests/layers.rs` checks this):
//!
//! 1. **scenario**: the schema of scenario files and its overlays (`scenario`, `overlay`, `gate`);
//! 2. **scoring**: metrics against the simulated truth, gates, relations and CLEAR-MOT
//!    (`relations`, `ground_truth`);
//! 3. **formats**: files the nodes write (`picture`: PNG images, `rgbd`: TUM RGB-D
//!    sequences) and whole-folder writes (`output`);
//! 4. **stack**: the bus, the node interface and every stack module's node and configuration
//!    (`stack`);
//! 5. **reports**: the HTML report (`report`);
//! 6. **applications**: the loop and what runs it (`parallel`, work spread over threads;
//!    `run`, `replay`, `legs_train`, `calibrate` (a robot profile from a real log), `twin`
//!    (the log's drive in simulation, side by side, its SLAM configurations ranked, and twin
//!    scenarios), `crowd` (real crowds measured, the crowd model calibrated on them and
//!    compared), `suite` (scenarios and twin scenarios), `folds` (SLAM defaults chosen by
//!    leave-one-log-out), `tune` with `cmaes`, `bench`, `fuzz`, `world_cmd`; and
//!    `config_walk`, a test that walks every scenario's parameters).
//!
//! The binary (`src/main.rs`) parses the command line and calls these.

pub mod gate;
pub mod overlay;
pub mod scenario;

pub mod ground_truth;
pub mod relations;

pub mod dds;
pub mod output;
pub mod parallel;
pub mod picture;
pub mod rgbd;

pub mod stack;

pub mod report;

pub mod bench;
pub mod calibrate;
pub mod cmaes;
#[cfg(test)]
mod config_walk;
pub mod crowd;
pub mod export;
pub mod folds;
pub mod fuzz;
pub mod legs_train;
pub mod replay;
pub mod run;
pub mod serve;
pub mod suite;
pub mod tune;
pub mod twin;
pub mod world_cmd;
