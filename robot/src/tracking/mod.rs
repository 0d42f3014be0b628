//! Following what moves: optimal assignment ([`assignment`]) and the people tracker
//! ([`people`]), which turns leg detections into tracks of people.

pub mod assignment;
pub mod people;
