//! futago-sim: the simulated world of the futago digital twin.
//!
//! - [`world`]: the TOML world format compiled into an immutable [`World`], its meshes,
//!   textures, glTF import/export and ground-truth exports;
//! - [`sim`]: the running [`Simulation`] (rapier state, clock, sensors);
//! - [`create`]: the iRobot Create's drive, wheel traction and odometry;
//! - [`joint`]: turntables and tilt units on the base that carry sensors;
//! - [`agent`]: moving bodies besides the robot (carts, cylinders walking a path);
//! - [`sway`]: the wobble of a sensor's carrier (a pushed wagon, a hand-held camera);
//! - [`people`]: pedestrians on two legs, moved by a social-force model;
//! - [`kinect`]: the Kinect v1 RGB-D camera model and its depth noise;
//! - [`lidar`]: ray-cast laser range finders, and [`beam`]: their readings' errors beyond the
//!   hit's noise (short, random and lost readings, mixed pixels);
//! - [`noise`]: seeded random streams per noise source;
//! - [`ray_grid`]: the lasers' ray casts, over the world's colliders binned in plan;
//! - [`twin`]: a real log's drive replayed: its laser cast along a given path, its odometry made
//!   from the path with a robot profile's errors;
//! - [`render`]: the wgpu camera renderer (the `futago-render` crate, re-exported);
//! - [`config`]: TOML loading with errors that name file, key and expectation.
//!
//! The simulator knows nothing of the robot stack: it takes [`futago_msgs::DriveCommand`]s and
//! produces sensor messages.

pub mod agent;
pub mod beam;
pub mod config;
pub mod create;
pub mod joint;
pub mod kinect;
pub mod lidar;
pub mod noise;
pub mod people;
pub mod ray_grid;
pub mod rig;
pub mod sim;
pub mod sway;
pub mod twin;
pub mod world;

/// The camera renderer, its own crate ([`futago_render`]) so that the robot stack can draw
/// predicted views too; re-exported here under its old path.
pub use futago_render as render;

pub use config::SpecError;
pub use sim::{Movers, PhysicsConfig, Simulation, StepOutput};
pub use world::World;
