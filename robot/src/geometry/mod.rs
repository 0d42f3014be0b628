//! Geometry the stack's modules share: distance transforms of occupancy grids ([`grid`]), their
//! iso-lines ([`contour`]), distance fields of 3D surfaces ([`distance_field`]) and
//! plane fits in point clouds ([`plane`]). Pose arithmetic and interpolation live with the pose
//! type itself, in [`futago_msgs`], where the command's metrics and the log readers use them too.

pub mod contour;
pub mod distance_field;
pub mod grid;
pub mod plane;
