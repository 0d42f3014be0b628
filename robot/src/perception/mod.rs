//! What the camera sees: image features (FAST corners, BRIEF descriptors; [`features`]) and
//! the floor plane that fixes the camera's height, pitch and roll ([`floor`]).

pub mod features;
pub mod floor;
