//! futago-robot: the robot's own software, which sees only sensor messages
//! ([`futago_msgs`]) and emits drive commands. It never depends on the simulator, so the same
//! code runs in simulation and on logs of real robots.
//!
//! Grouped by concern, each group depending only on those listed before it:
//!
//! - [`config`]: range checks shared by every module's options;
//! - [`cores`]: work split over the machine's cores, its results in order;
//! - [`geometry`]: distance transforms and plane fits;
//! - [`perception`]: image features, floor levelling, legs in laser scans;
//! - [`tracking`]: optimal assignment and the people tracker;
//! - [`localization`]: odometry, Monte Carlo localisation;
//! - [`mapping`]: occupancy grids, scan matching, graph SLAM, the RGB-D 3D map;
//! - [`control`]: path following and scripted drive plans;
//! - [`navigation`]: planning, exploration and the navigator that drives by them.

pub mod config;
pub mod control;
pub mod cores;
pub mod geometry;
pub mod localization;
pub mod mapping;
pub mod navigation;
pub mod perception;
pub mod tracking;
