//! Where the robot is: dead reckoning from wheel odometry ([`odometry`]), Monte Carlo
//! localisation on a known map ([`mcl`]), of a depth camera in a 3D model ([`depth_mcl`]),
//! and of a single camera in a map of visual landmarks ([`landmarks`], seed 001); what an
//! estimate's covariance says about its position ([`covariance`]).

pub mod covariance;
pub mod depth_mcl;
pub mod landmarks;
pub mod mcl;
pub mod model;
pub mod odometry;
