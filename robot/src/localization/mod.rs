//! Where the robot is: dead reckoning from wheel odometry ([`odometry`]) and Monte Carlo
//! localisation on a known map ([`mcl`]).

pub mod mcl;
pub mod odometry;
