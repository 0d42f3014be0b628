//! Depth-camera MCL on the stack's own renderer (wgpu; Mesa's rasterisers on CPU machines):
//! the renderer's depth from the filter's poses matches the room's geometry, and the seed's
//! filter tracks a camera moving down the room with every particle rendered in one batch.

use futago_msgs::camera::Intrinsics;
use futago_render::{Material, Pose, Renderer, Scene, TriMesh, mesh::UvMap};
use futago_robot::localization::depth_mcl::{CameraState, DepthMcl, DepthMclConfig, DepthModel};
use glam::Vec3;

/// A room 10 × 4 × 3 m (its inside from the origin), walls 0.1 m thick outside it, and square
/// pillars 0.4 m a side along both long walls.
fn room() -> Renderer {
    let mut scene = Scene::default();
    let slab = |lo: [f32; 3], hi: [f32; 3]| {
        let c = Vec3::from(lo).lerp(Vec3::from(hi), 0.5);
        let h = (Vec3::from(hi) - Vec3::from(lo)) * 0.5;
        TriMesh::cuboid(h, UvMap::Fit).transformed(glam::Quat::IDENTITY, c, 1.0)
    };
    let parts = [
        slab([-0.1, -0.1, -0.1], [10.1, 4.1, 0.0]),
        slab([-0.1, -0.1, 3.0], [10.1, 4.1, 3.1]),
        slab([-0.1, -0.1, 0.0], [0.0, 4.1, 3.0]),
        slab([10.0, -0.1, 0.0], [10.1, 4.1, 3.0]),
        slab([0.0, -0.1, 0.0], [10.0, 0.0, 3.0]),
        slab([0.0, 4.0, 0.0], [10.0, 4.1, 3.0]),
        slab([3.0, 0.0, 0.0], [3.4, 0.4, 3.0]),
        slab([5.5, 3.6, 0.0], [5.9, 4.0, 3.0]),
        slab([7.0, 0.0, 0.0], [7.4, 0.4, 3.0]),
        slab([9.0, 3.6, 0.0], [9.4, 4.0, 3.0]),
    ];
    let material = Material {
        name: "wall".into(),
        color: [0.7; 3],
        texture: None,
    };
    scene.add_body(
        "room",
        Pose::IDENTITY,
        parts.into_iter().map(|m| (material.clone(), m)).collect(),
    );
    Renderer::new(&scene).expect("a GPU adapter (Mesa's llvmpipe or lavapipe on CPU machines)")
}

fn intr() -> Intrinsics {
    Intrinsics::from_fov(44, 36, 43.6f64.to_radians(), 34.6f64.to_radians()).unwrap()
}

/// The centre pixel's depth from two camera poses, against the room's walls: facing +x from
/// (1, 2, 1) the far wall is 9 m ahead; turned 90° left, the wall at y = 4 is 2 m ahead.
#[test]
fn the_renderer_draws_the_filters_poses() {
    let mut r = room();
    // An even-sized image has no centre pixel: 45 × 37 has one.
    let k = Intrinsics::from_fov(45, 37, 0.8, 0.6).unwrap();
    let poses = [
        CameraState {
            position: [1.0, 2.0, 1.0],
            rpy: [0.0, 0.0, 0.0],
        },
        CameraState {
            position: [1.0, 2.0, 1.0],
            rpy: [0.0, 0.0, std::f64::consts::FRAC_PI_2],
        },
    ]
    .map(|s| s.pose());
    let mut out = Vec::new();
    DepthModel::render_batch(&mut r, &k, &poses, 20.0, &mut out).unwrap();
    let centre = (18 * 45 + 22) as usize;
    let px = 45 * 37;
    assert!((out[centre] - 9.0).abs() < 1e-3, "{}", out[centre]);
    assert!(
        (out[px + centre] - 2.0).abs() < 1e-3,
        "{}",
        out[px + centre]
    );
    // Drawn to 5 m, the end wall 9 m ahead is gone and the side wall 2 m away stays.
    DepthModel::render_batch(&mut r, &k, &poses, 5.0, &mut out).unwrap();
    assert_eq!(out[centre], 0.0);
    assert!((out[px + centre] - 2.0).abs() < 1e-3);
}

/// Seed 002's filter (200 particles, α 0.1, β 0.01, x, y and yaw) on the renderer: the camera
/// moves 5 cm a frame down the room, swaying 10 cm and 0.1 rad; the median error stays
/// within the seed's 7 cm.
#[test]
fn the_seeds_filter_tracks_on_the_renderer() {
    let mut r = room();
    let start = CameraState {
        position: [1.0, 2.0, 1.0],
        rpy: [0.0, 0.0, 0.2],
    };
    let mut mcl = DepthMcl::new(DepthMclConfig::default(), start, 1);
    let mut truth = start;
    let mut errors = Vec::new();
    let mut measured = Vec::new();
    for k in 0..40 {
        truth.position[0] += 0.05;
        truth.position[1] = 2.0 + 0.1 * (k as f64 * 0.2).sin();
        truth.rpy[2] = 0.2 + 0.1 * (k as f64 * 0.15).sin();
        DepthModel::render_batch(&mut r, &intr(), &[truth.pose()], 20.0, &mut measured).unwrap();
        let est = mcl.update(&mut r, &intr(), &measured, 20.0, None).unwrap();
        errors.push(
            (est.state.position[0] - truth.position[0])
                .hypot(est.state.position[1] - truth.position[1]),
        );
    }
    errors.sort_by(f64::total_cmp);
    let median = errors[errors.len() / 2];
    assert!(median < 0.07, "median {median}, all {errors:?}");
}
