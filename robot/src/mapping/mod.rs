//! Building maps: 2D occupancy grids from laser scans ([`occupancy`]), scan matching
//! ([`icp`], [`correlative`]), graph SLAM ([`slam`], [`pose_graph`]), and seed 000's 3D map
//! from RGB-D keyframes ([`rgbd_map`], with [`registration`]'s RGBD-ICP and [`polygons`]);
//! seed 004's localisation by point-to-line ICP and Nelder–Mead ([`line_icp`]), its
//! stop-and-scan 3D mapping with a turntable laser ([`turntable`]), its sweeps registered
//! against the map's planar patches ([`surfels`]), and its voxel
//! map of occupied, free and unknown space with free-space carving ([`voxels`]); seed 001's
//! visual landmark map from a trinocular camera ([`landmark_map`]).

pub mod correlative;
pub mod icp;
pub mod landmark_map;
pub mod line_icp;
pub mod occupancy;
pub mod polygons;
pub mod pose_graph;
pub mod registration;
pub mod rgbd_map;
pub mod slam;
pub mod surfels;
pub mod turntable;
pub mod voxels;
