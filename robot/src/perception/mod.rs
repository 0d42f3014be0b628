//! What the sensors see: image features (FAST corners, BRIEF descriptors; [`features`]; SIFT
//! keypoints; [`sift`]) and trinocular stereo points ([`trinocular`]), the
//! floor plane that fixes the camera's height, pitch and roll ([`floor`]), and people's legs
//! in a laser scan ([`legs`]), things that move in it ([`motion`]), and people in depth images
//! ([`depth_people`]).

pub mod depth_people;
pub mod features;
pub mod floor;
pub mod free_space;
pub mod legs;
pub mod motion;
pub mod sift;
pub mod trinocular;
