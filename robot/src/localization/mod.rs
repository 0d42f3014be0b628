//! Where the robot is: dead reckoning from wheel odometry ([`odometry`]), Monte Carlo
//! localisation on a known map ([`mcl`]), and of a depth camera in a 3D model
//! ([`depth_mcl`]).

pub mod depth_mcl;
pub mod landmarks;
pub mod mcl;
pub mod model;
pub mod odometry;
