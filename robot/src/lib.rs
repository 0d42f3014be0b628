//! futago-robot: the robot's own software, which sees only sensor messages
//! ([`futago_msgs`]) and emits drive commands. It never depends on the simulator, so the same
//! code runs in simulation and on logs of real robots.
//!
//! So far: odometry integration ([`odometry`]) and scripted drive plans ([`script`]); the
//! mapping, localisation and navigation stack plugs in beside them.

pub mod config;
pub mod correlative;
pub mod exploration;
pub mod features;
pub mod floor;
pub mod icp;
pub mod mcl;
pub mod navigation;
pub mod occupancy;
pub mod odometry;
pub mod plane;
pub mod planner;
pub mod polygons;
pub mod pose_graph;
pub mod pursuit;
pub mod registration;
pub mod rgbd_map;
pub mod script;
pub mod slam;
