//! The camera renderer against parry ray casts, known planes and known colours.
//!
//! The backend comes from `FUTAGO_GPU_BACKEND` (auto, vulkan, gl); CI runs this file once per
//! backend.

mod common;

use common::*;
use futago_msgs::Pose2;
use futago_sim::World;
use futago_sim::create::CreateConfig;
use futago_sim::render::{DepthImage, Intrinsics, Renderer, optical_rotation};
use futago_sim::world::Material;
use futago_sim::world::mesh::{TriMesh, UvMap};
use glam::{Quat, Vec3};
use rapier3d::math::Pose;
use std::path::Path;

fn load(name: &str) -> World {
    World::load(
        &Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../worlds")
            .join(name),
    )
    .unwrap()
}

fn kinect(w: u32, h: u32) -> Intrinsics {
    Intrinsics::from_fov(w, h, 57f64.to_radians(), 43f64.to_radians()).unwrap()
}

/// A camera body pose from position, yaw and pitch (positive pitch looks down).
fn cam(x: f32, y: f32, z: f32, yaw: f32, pitch: f32) -> Pose {
    Pose::from_parts(
        Vec3::new(x, y, z),
        Quat::from_rotation_z(yaw) * Quat::from_rotation_y(pitch),
    )
}

/// Ray-cast depth (optical z) of every pixel centre; 0 where nothing is hit.
fn ray_cast_depth(sim: &futago_sim::Simulation, intr: &Intrinsics, pose: &Pose) -> DepthImage {
    let rot = pose.rotation * optical_rotation();
    let mut data = Vec::with_capacity((intr.width * intr.height) as usize);
    for v in 0..intr.height {
        for u in 0..intr.width {
            let [x, y, z] = intr.ray(u as f64, v as f64);
            let d = Vec3::new(x as f32, y as f32, z as f32);
            let len = d.length();
            let t = sim.cast_ray(pose.translation, rot * (d / len), 100.0);
            data.push(t.map(|t| t / len).unwrap_or(0.0));
        }
    }
    DepthImage {
        width: intr.width,
        height: intr.height,
        data,
    }
}

/// Fraction of pixels valid in either image that agree within 1 mm + 0.1 % of range.
fn agreement(rendered: &DepthImage, cast: &DepthImage) -> (f64, usize) {
    let mut valid = 0;
    let mut good = 0;
    for (&r, &c) in rendered.data.iter().zip(&cast.data) {
        if r == 0.0 && c == 0.0 {
            continue;
        }
        valid += 1;
        if r > 0.0 && c > 0.0 && (r - c).abs() <= 0.001 + 0.001 * c {
            good += 1;
        }
    }
    (good as f64 / valid.max(1) as f64, valid)
}

fn stepped_sim(world: &World, start: Pose2) -> futago_sim::Simulation {
    let mut s = sim(world, &CreateConfig::default(), &[], start, 1);
    s.step(None);
    s
}

fn check_world(file: &str, start: Pose2, poses: &[Pose]) {
    let world = load(file);
    let s = stepped_sim(&world, start);
    let mut r = Renderer::new(&world.scene()).unwrap();
    let intr = kinect(320, 240);
    for p in poses {
        let depth = r.render_depth(&intr, p).unwrap();
        let cast = ray_cast_depth(&s, &intr, p);
        let (frac, valid) = agreement(&depth, &cast);
        assert!(
            valid > 10_000,
            "{file} {p:?}: only {valid} valid pixels, the view is too empty to test"
        );
        assert!(
            frac >= 0.995,
            "{file} at {p:?} on {}: {:.3} % of {valid} pixels agree with the ray cast",
            r.adapter(),
            frac * 100.0
        );
        // The colour pass's registered depth is the same image (where surfaces meet at equal
        // depth, either may win).
        let (_, registered) = r.render(&intr, p).unwrap();
        let (same, _) = agreement(&registered, &depth);
        assert!(
            same >= 0.999,
            "{file} {p:?}: registered depth agrees at {:.3} %",
            same * 100.0
        );
    }
}

#[test]
fn office_depth_equals_a_ray_cast() {
    check_world(
        "office.toml",
        Pose2::new(28.0, 2.0, 0.0),
        &[
            cam(1.5, 8.0, 0.5, 0.2, 0.0),
            cam(15.0, 8.0, 1.2, 1.57, 0.3),
            cam(19.0, 12.5, 0.4, -0.7, 0.1),
            cam(5.0, 8.0, 1.6, 2.5, 0.5),
        ],
    );
}

#[test]
fn lab_depth_equals_a_ray_cast() {
    check_world(
        "lab.toml",
        Pose2::new(1.0, 0.8, 0.0),
        &[
            cam(6.5, 3.5, 0.45, 0.0, 0.0),
            cam(2.0, 5.0, 1.0, -0.8, -0.2),
            cam(11.0, 1.5, 0.3, 2.8, 0.05),
        ],
    );
}

#[test]
fn back_projected_wall_fits_its_plane_and_material_renders_its_colour() {
    // Room interior [0, 4] × [0, 4], walls 2 m high; the far wall's inner face is x = 4.
    let world = box_room(4.0, 4.0, "");
    let mut r = Renderer::new(&world.scene()).unwrap();
    let intr = kinect(320, 240);
    let pose = cam(1.0, 2.0, 1.0, 0.3, 0.1);
    let (rgb, depth) = r.render(&intr, &pose).unwrap();
    let rot = pose.rotation * optical_rotation();
    // Points on the x = 4 wall, well inside it (away from the corners and the floor).
    let mut pts = Vec::new();
    for v in 0..intr.height {
        for u in 0..intr.width {
            let z = depth.at(u, v) as f64;
            if z == 0.0 {
                continue;
            }
            let p = intr.back_project(u as f64, v as f64, z);
            let w = pose.translation + rot * Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32);
            if w.x > 3.9 && w.y > 0.3 && w.y < 3.7 && w.z > 0.2 {
                pts.push(w.as_dvec3());
            }
        }
    }
    assert!(pts.len() > 5000, "{} wall points", pts.len());
    // Least-squares plane x = a + b y + c z.
    let n = pts.len() as f64;
    let (mut sy, mut sz, mut sx, mut syy, mut szz, mut syz, mut sxy, mut sxz) =
        (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for p in &pts {
        sy += p.y;
        sz += p.z;
        sx += p.x;
        syy += p.y * p.y;
        szz += p.z * p.z;
        syz += p.y * p.z;
        sxy += p.x * p.y;
        sxz += p.x * p.z;
    }
    let m = glam::DMat3::from_cols(
        glam::DVec3::new(n, sy, sz),
        glam::DVec3::new(sy, syy, syz),
        glam::DVec3::new(sz, syz, szz),
    );
    let abc = m.inverse() * glam::DVec3::new(sx, sxy, sxz);
    assert!((abc.x - 4.0).abs() < 1e-3, "plane offset {abc:?}");
    assert!(
        abc.y.abs() < 1e-4 && abc.z.abs() < 1e-4,
        "plane tilt {abc:?}"
    );
    let worst = pts
        .iter()
        .map(|p| (p.x - (abc.x + abc.y * p.y + abc.z * p.z)).abs())
        .fold(0.0, f64::max);
    assert!(worst < 1e-3, "worst residual {worst} m");

    // The wall's colour: sRGB 0.5 grey under the renderer's light on a normal of -x.
    let shade = r.lighting().encoded_shade(Vec3::NEG_X);
    let expect = (0.5 * shade * 255.0).round() as i32;
    // Find a pixel on the far wall (its centre column, above the floor line).
    let c = rgb.at(intr.width / 2, intr.height / 3);
    for ch in c {
        assert!(
            (ch as i32 - expect).abs() <= 2,
            "wall colour {c:?}, expected {expect} in each channel"
        );
    }
}

#[test]
fn batches_equal_single_renders_and_movable_bodies_follow_their_poses() {
    let world = box_room(6.0, 4.0, "");
    let mut scene = world.scene();
    let red = Material {
        name: "red".into(),
        color: [0.8, 0.1, 0.1],
        texture: None,
    };
    let cube = TriMesh::cuboid(Vec3::splat(0.25), UvMap::Fit);
    let body = scene.add_body(
        "cube",
        Pose::from_translation(Vec3::new(3.0, 2.0, 0.25)),
        vec![(red, cube)],
    );
    let mut r = Renderer::new(&scene).unwrap();
    let intr = kinect(176, 144);
    let eye = cam(0.5, 2.0, 0.25, 0.0, 0.0);
    let centre = |d: &DepthImage| d.at(d.width / 2, d.height / 2);
    // The cube's near face is at x = 2.75: 2.25 m in front of the camera.
    let before = r.render_depth(&intr, &eye).unwrap();
    assert!((centre(&before) - 2.25).abs() < 1e-3, "{}", centre(&before));
    let mut poses: Vec<Pose> = scene.bodies.iter().map(|b| b.pose).collect();
    poses[body] = Pose::from_translation(Vec3::new(4.0, 2.0, 0.25));
    r.set_poses(&poses).unwrap();
    let after = r.render_depth(&intr, &eye).unwrap();
    assert!((centre(&after) - 3.25).abs() < 1e-3, "{}", centre(&after));
    let (rgb, _) = r.render(&intr, &eye).unwrap();
    let px = rgb.at(intr.width / 2, intr.height / 2);
    assert!(
        px[0] > 150 && px[1] < 80 && px[2] < 80,
        "cube colour {px:?}"
    );

    let eyes: Vec<Pose> = (0..37)
        .map(|i| {
            cam(
                0.5 + 0.1 * i as f32,
                1.0 + 0.05 * i as f32,
                0.3,
                0.2 * i as f32,
                0.05,
            )
        })
        .collect();
    let mut batch = Vec::new();
    r.render_depth_batch(&intr, &eyes, futago_render::FAR_PLANE, &mut batch)
        .unwrap();
    let n = (intr.width * intr.height) as usize;
    assert_eq!(batch.len(), eyes.len() * n);
    for (i, e) in eyes.iter().enumerate() {
        let single = r.render_depth(&intr, e).unwrap();
        // The same triangles rasterised at another viewport offset: equal up to float
        // rounding of the interpolation, and every pixel covered alike.
        let mut worst = 0f32;
        for (a, b) in single.data.iter().zip(&batch[i * n..(i + 1) * n]) {
            assert_eq!(*a == 0.0, *b == 0.0, "view {i}: coverage differs");
            worst = worst.max((a - b).abs() / a.max(1e-6));
        }
        assert!(
            worst < 1e-4,
            "view {i} of the batch differs from its single render by {worst}"
        );
    }
    // Drawn to 2.5 m, each view is the full view less what lies beyond (the chunks culled
    // past the far plane took nothing nearer with them).
    let mut near = Vec::new();
    r.render_depth_batch(&intr, &eyes, 2.5, &mut near).unwrap();
    let mut cut = 0;
    for (a, b) in batch.iter().zip(&near) {
        if (a - 2.5).abs() < 1e-3 {
            continue;
        }
        if *a > 2.5 {
            assert_eq!(*b, 0.0, "a surface at {a} m drawn past the far plane");
            cut += 1;
        } else {
            assert!((a - b).abs() <= 1e-4 * a, "{a} drawn as {b}");
        }
    }
    assert!(cut > 1000, "only {cut} pixels lay beyond 2.5 m");
}

#[test]
fn bad_sizes_fields_of_view_and_pose_counts_are_errors() {
    let e = Intrinsics::from_fov(0, 480, 1.0, 0.8).unwrap_err();
    assert!(e.contains("0×480"), "{e}");
    let e = Intrinsics::from_fov(640, 480, 3.2, 0.8).unwrap_err();
    assert!(e.contains("horizontal field of view"), "{e}");
    let world = box_room(2.0, 2.0, "");
    let mut r = Renderer::new(&world.scene()).unwrap();
    let mut bad = kinect(64, 48);
    bad.width = 0;
    let e = r.render_depth(&bad, &Pose::IDENTITY).unwrap_err();
    assert!(e.to_string().contains("image size"), "{e}");
    let e = r.set_poses(&[]).unwrap_err();
    assert!(e.to_string().contains("0 poses"), "{e}");
    // A mesh whose triangle indexes a missing vertex is refused by name.
    let mut scene = world.scene();
    let mut mesh = TriMesh::cuboid(Vec3::ONE, UvMap::Fit);
    mesh.indices.push([0, 1, 99]);
    scene.add_body(
        "broken",
        Pose::IDENTITY,
        vec![(
            Material {
                name: "m".into(),
                color: [1.0; 3],
                texture: None,
            },
            mesh,
        )],
    );
    let e = Renderer::new(&scene)
        .err()
        .expect("a broken mesh is refused");
    assert!(e.to_string().contains("body `broken`"), "{e}");
}

#[test]
fn missing_textures_and_empty_meshes_name_their_file_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let w = dir.path().join("w.toml");
    std::fs::write(
        &w,
        "name = \"w\"\n[materials.m]\ncolor = [0.5, 0.5, 0.5]\ntexture = { image = \"gone.png\" }\n[floor]\nmaterial = \"m\"\n",
    )
    .unwrap();
    let e = World::load(&w).unwrap_err().to_string();
    assert!(
        e.contains("w.toml") && e.contains("materials.m") && e.contains("gone.png"),
        "{e}"
    );
    // A glTF file whose only triangle has zero area.
    let mut flat = box_room(1.0, 1.0, "");
    for o in &mut flat.objects {
        for p in &mut o.parts {
            for v in &mut p.mesh.positions {
                *v = Vec3::ZERO;
            }
        }
    }
    let glb = dir.path().join("flat.glb");
    let poses: Vec<Pose> = flat.objects.iter().map(|o| o.pose).collect();
    std::fs::write(&glb, futago_sim::world::gltf_io::export_glb(&flat, &poses)).unwrap();
    let e = World::load(&glb).unwrap_err().to_string();
    assert!(e.contains("flat.glb") && e.contains("degenerate"), "{e}");
}

#[test]
fn seed000_kinect_gives_qvga_depth_registered_to_vga_colour_within_its_range() {
    use futago_sim::kinect::{Kinect, KinectConfig, KinectPreset};
    // Room interior [0, 6] × [0, 4]; the robot at (1, 2) facing +x, the camera 0.42 m up and
    // 0.1 m ahead of the base, so the far wall is 4.9 m away: beyond seed 000's 3.5 m.
    let world = box_room(6.0, 4.0, "");
    let robot = CreateConfig::default();
    let spec = KinectConfig::preset(KinectPreset::Seed000)
        .resolve(Path::new("t.toml"), "camera[0]")
        .unwrap();
    let mut r = Renderer::new(&futago_sim::sim::scene(
        &world,
        &robot,
        &futago_sim::Movers::default(),
        Pose2::new(1.0, 2.0, 0.0),
        1,
    ))
    .unwrap();
    let mut cam = Kinect::new(spec.clone(), futago_sim::noise::stream(1, "camera.kinect"));
    let base = Pose::from_translation(Vec3::new(1.0, 2.0, 0.0));
    let f = cam
        .capture(&mut r, &base, futago_msgs::Time::ZERO, true, 1)
        .unwrap();
    let rgb = f.rgb.as_ref().unwrap();
    assert_eq!((rgb.width, rgb.height), (640, 480));
    assert_eq!((f.depth.width, f.depth.height), (320, 240));
    // Centre row: the far wall, out of range.
    assert_eq!(f.depth.at(160, 119), 0.0);
    // The floor: z = 0.42 fy / (v − cy) in the depth image; valid only in 1.2–3.5 m.
    let fy = f.depth_intrinsics.fy;
    let cy = f.depth_intrinsics.cy;
    let mut seen = 0;
    for v in 125..240 {
        let expect = 0.42 * fy / (v as f64 - cy);
        let z = f.depth.at(160, v) as f64;
        if (1.2..=3.5).contains(&expect) {
            assert!(
                (z - expect).abs() < 1e-3 + 1e-3 * expect,
                "row {v}: {z} vs {expect}"
            );
            seen += 1;
        } else if !(1.19..=3.51).contains(&expect) {
            assert_eq!(z, 0.0, "row {v}: {expect} m is out of range");
        }
    }
    assert!(seen > 30, "{seen} floor rows in range");
    // The robot's own body stays out of view of the default mount.
    let body = Pose::from_translation(Vec3::new(1.0, 2.0, 0.0));
    let view = r.render_depth(&spec.depth, &(body * spec.mount)).unwrap();
    assert!(
        view.data.iter().all(|&z| z == 0.0 || z > 0.3),
        "the camera sees the robot"
    );
}

/// A renderer of `world` with the default Create standing at (1, 2), the scene's seed 1.
fn room_renderer(world: &World) -> Renderer {
    Renderer::new(&futago_sim::sim::scene(
        world,
        &CreateConfig::default(),
        &futago_sim::Movers::default(),
        Pose2::new(1.0, 2.0, 0.0),
        1,
    ))
    .unwrap()
}

/// A frame captured with colour and one of depth alone measure the same scene: the true depth
/// after either is the image a fresh depth render gives (the capture's own render before its
/// noise, not a stale one), a depth-only frame holds no colour, and a true depth asked at
/// another pose than the capture's is rendered from that pose.
#[test]
fn true_depth_after_a_capture_is_the_noiseless_render_of_that_view() {
    use futago_sim::kinect::{Kinect, KinectConfig, KinectPreset, NoiseModel};
    let world = box_room(6.0, 4.0, "");
    let mut config = KinectConfig::preset(KinectPreset::Seed000);
    config.noise.model = NoiseModel::Nguyen;
    let spec = config.resolve(Path::new("t.toml"), "camera[0]").unwrap();
    let mut r = room_renderer(&world);
    let mut cam = Kinect::new(spec.clone(), futago_sim::noise::stream(1, "camera.kinect"));
    // Facing the room's long diagonal, so the floor and walls lie within 1.2–3.5 m.
    let pose = |x: f32, yaw: f32| {
        Pose::from_parts(Vec3::new(x, 2.0, 0.0), glam::Quat::from_rotation_z(yaw))
    };
    let t = futago_msgs::Time::from_secs(1.0);
    for (rgb, base) in [(true, pose(1.0, 0.3)), (false, pose(1.5, -0.4))] {
        let f = cam.capture(&mut r, &base, t, rgb, 1).unwrap();
        assert_eq!(f.rgb.is_some(), rgb);
        let truth = cam.true_depth(&mut r, &base, t).unwrap();
        let fresh = r.render_depth(&spec.depth, &(base * spec.mount)).unwrap();
        assert_eq!(truth.data, fresh.data, "rgb {rgb}");
        // The noise changed the measured image, not the true one.
        assert_ne!(f.depth.data, truth.data, "rgb {rgb}");
        // Another pose: its own render.
        let other = pose(2.0, 1.0);
        let there = cam.true_depth(&mut r, &other, t).unwrap();
        let fresh = r.render_depth(&spec.depth, &(other * spec.mount)).unwrap();
        assert_eq!(there.data, fresh.data);
        assert_ne!(there.data, truth.data);
    }
}

/// A frame captured without colour and given it afterwards holds what a capture with colour
/// holds, and leaves the camera's noise stream where that capture leaves it: two cameras on
/// the same stream, one capturing with colour and one without and then asking for it, give
/// the same colour and depth, twice over (the second frames' noise follows the first's
/// colour noise), and a repeated ask gives the same image without drawing again. Colour is
/// refused for another frame than the last, for a frame captured with it, and for a camera
/// whose colour and depth have the same size.
#[test]
fn colour_on_demand_is_the_colour_a_capture_would_hold() {
    use futago_sim::kinect::{Kinect, KinectConfig, KinectPreset, NoiseModel};
    let world = box_room(6.0, 4.0, "");
    let mut config = KinectConfig::preset(KinectPreset::Seed000);
    config.noise.model = NoiseModel::Nguyen;
    config.noise.rgb_sigma = 2.0;
    let spec = config.resolve(Path::new("t.toml"), "camera[0]").unwrap();
    let mut r = room_renderer(&world);
    let stream = || futago_sim::noise::stream(1, "camera.kinect");
    let (mut eager, mut lazy) = (
        Kinect::new(spec.clone(), stream()),
        Kinect::new(spec, stream()),
    );
    assert!(lazy.colour_on_demand());
    let pose = |x: f32, yaw: f32| {
        Pose::from_parts(Vec3::new(x, 2.0, 0.0), glam::Quat::from_rotation_z(yaw))
    };
    for (k, base) in [pose(1.0, 0.3), pose(1.5, -0.4)].into_iter().enumerate() {
        let t = futago_msgs::Time::from_secs(k as f64);
        let want = eager.capture(&mut r, &base, t, true, 1).unwrap();
        let got = lazy.capture(&mut r, &base, t, false, 1).unwrap();
        assert!(got.rgb.is_none());
        assert_eq!(got.depth.data, want.depth.data, "frame {k}'s depth");
        let colour = lazy.colour(&mut r, &base, t).unwrap();
        assert_eq!(Some(&colour), want.rgb.as_ref(), "frame {k}'s colour");
        assert_eq!(
            lazy.colour(&mut r, &base, t).unwrap(),
            colour,
            "asked again"
        );
        let later = futago_msgs::Time::from_secs(k as f64 + 0.5);
        assert!(lazy.colour(&mut r, &base, later).is_err(), "another frame");
        assert!(
            eager.colour(&mut r, &base, t).is_err(),
            "captured with colour"
        );
    }
    let same = KinectConfig::preset(KinectPreset::Sr4000)
        .resolve(Path::new("t.toml"), "camera[0]")
        .unwrap();
    let mut sr = Kinect::new(same, stream());
    assert!(!sr.colour_on_demand());
    let t = futago_msgs::Time::ZERO;
    sr.capture(&mut r, &pose(1.0, 0.0), t, false, 1).unwrap();
    assert!(sr.colour(&mut r, &pose(1.0, 0.0), t).is_err());
}

/// A frame captured on a depth grid and given its whole depth afterwards holds what a
/// capture of every pixel holds: two cameras on the same stream, one capturing every pixel
/// and one every second pixel of every second row, give the same grid, then the same whole
/// image, twice over (nothing is drawn for the whole image); a frame captured whole has
/// nothing to complete. Refused for another frame than the last, and for a noise model that
/// draws every pixel from the stream.
#[test]
fn full_depth_on_demand_is_the_depth_a_whole_capture_measures() {
    use futago_sim::kinect::{Kinect, KinectConfig, KinectPreset, NoiseModel};
    let world = box_room(6.0, 4.0, "");
    let mut r = room_renderer(&world);
    let spec = |model| {
        let mut config = KinectConfig::preset(KinectPreset::Seed000);
        config.noise.model = model;
        config.resolve(Path::new("t.toml"), "camera[0]").unwrap()
    };
    let stream = || futago_sim::noise::stream(1, "camera.kinect");
    let (mut whole, mut grid) = (
        Kinect::new(spec(NoiseModel::Nguyen), stream()),
        Kinect::new(spec(NoiseModel::Nguyen), stream()),
    );
    assert!(grid.depth_on_demand(false) && grid.depth_on_demand(true));
    let pose = |x: f32, yaw: f32| {
        Pose::from_parts(Vec3::new(x, 2.0, 0.0), glam::Quat::from_rotation_z(yaw))
    };
    for (k, base) in [pose(1.0, 0.3), pose(1.5, -0.4)].into_iter().enumerate() {
        let t = futago_msgs::Time::from_secs(k as f64);
        let want = whole.capture(&mut r, &base, t, false, 1).unwrap();
        let got = grid.capture(&mut r, &base, t, false, 2).unwrap();
        let w = want.depth.width as usize;
        let mut on_grid = 0;
        for (i, (a, b)) in want.depth.data.iter().zip(&got.depth.data).enumerate() {
            if (i % w).is_multiple_of(2) && (i / w).is_multiple_of(2) {
                assert_eq!(a, b, "frame {k}, pixel {i} on the grid");
                on_grid += usize::from(*a > 0.0);
            } else {
                assert_eq!(*b, 0.0, "frame {k}, pixel {i} off the grid");
            }
        }
        assert!(on_grid > 1000, "{on_grid} measured pixels on the grid");
        let full = grid.full_depth(&base, t).unwrap().unwrap();
        assert_eq!(full.data, want.depth.data, "frame {k}'s whole depth");
        assert_eq!(
            grid.full_depth(&base, t).unwrap().unwrap(),
            full,
            "asked again"
        );
        assert_eq!(whole.full_depth(&base, t).unwrap(), None, "captured whole");
        let later = futago_msgs::Time::from_secs(k as f64 + 0.5);
        assert!(grid.full_depth(&base, later).is_err(), "another frame");
    }
    let mut icl = Kinect::new(spec(NoiseModel::IclNuim), stream());
    assert!(!icl.depth_on_demand(false));
    let t = futago_msgs::Time::ZERO;
    icl.capture(&mut r, &pose(1.0, 0.3), t, false, 2).unwrap();
    assert!(icl.full_depth(&pose(1.0, 0.3), t).is_err());
}

/// Steps a robot standing at (1, 3) in an 8 m × 6 m room among `movers` three times by
/// `steps`, renders the depth seen from `p` and checks it against ray casts of the colliders
/// (99.5 % within 1 mm + 0.1 %), and that at least `min` pixels lie nearer than `near` m.
fn cameras_see_movers(movers: &futago_sim::Movers, p: Pose, steps: usize, near: f32, min: usize) {
    let world = box_room(8.0, 6.0, "");
    let start = Pose2::new(1.0, 3.0, 0.0);
    let mut s = futago_sim::Simulation::new(
        &world,
        &futago_sim::PhysicsConfig::default(),
        &CreateConfig::default(),
        &[],
        movers,
        start,
        1,
    );
    let mut r = Renderer::new(&futago_sim::sim::scene(
        &world,
        &CreateConfig::default(),
        movers,
        start,
        // The simulation's seed: each person's body is drawn by it.
        1,
    ))
    .unwrap();
    let intr = kinect(160, 120);
    for _ in 0..3 {
        for _ in 0..steps {
            s.step(None);
        }
        r.set_poses(&s.scene_poses()).unwrap();
        let depth = r.render_depth(&intr, &p).unwrap();
        let cast = ray_cast_depth(&s, &intr, &p);
        let (frac, valid) = agreement(&depth, &cast);
        assert!(frac >= 0.995, "{:.3} % of {valid} agree", frac * 100.0);
        let n = depth.data.iter().filter(|&&d| d > 0.0 && d < near).count();
        assert!(n > min, "the movers cover only {n} pixels");
    }
}

#[test]
fn cameras_see_walking_agents_where_the_lasers_do() {
    use futago_sim::agent::{AgentConfig, PathMode};
    let movers = futago_sim::Movers {
        agents: vec![AgentConfig {
            name: "walker".into(),
            path: vec![[5.0, 1.0], [5.0, 5.0]],
            speed: 1.2,
            mode: PathMode::BackAndForth,
            start_time: 0.0,
            radius: 0.25,
            height: 1.7,
            color: [0.6, 0.3, 0.3],
            turn_radius: 0.0,
        }],
        ..Default::default()
    };
    // The agent is in view: some pixels are nearer than the far wall (6.5 m ahead).
    cameras_see_movers(&movers, cam(1.5, 3.0, 0.8, 0.0, 0.0), 200, 4.0, 100);
}

#[test]
fn cameras_see_people_where_the_lasers_do() {
    use futago_sim::agent::PathMode;
    use futago_sim::people::PersonConfig;
    // One walks across the view, legs swinging; one stands nearer, turned sideways.
    let person = |name: &str, route: Vec<[f64; 2]>, heading_deg: f64| PersonConfig {
        name: name.into(),
        route,
        mode: PathMode::BackAndForth,
        speed: Some(1.3),
        start_time: 0.0,
        heading_deg,
        yields: false,
        shirt: [0.2, 0.3, 0.6],
        trousers: [0.1, 0.1, 0.15],
    };
    let movers = futago_sim::Movers {
        people: vec![
            person("walker", vec![[5.0, 1.0], [5.0, 5.0]], 0.0),
            person("stander", vec![[3.5, 3.6]], 90.0),
        ],
        ..Default::default()
    };
    // Low enough to see the legs and the torsos.
    cameras_see_movers(&movers, cam(1.2, 3.0, 0.6, 0.0, 0.0), 150, 4.2, 200);
}

/// The cameras' scene draws each person with the body the simulation of the same seed drew
/// for them: a leg's mesh has that leg's radius, and another seed gives another leg.
#[test]
fn the_scene_draws_the_bodies_its_seed_draws() {
    let world = box_room(6.0, 4.0, "");
    let movers = futago_sim::Movers {
        people: vec![futago_sim::people::PersonConfig {
            name: "ann".into(),
            route: vec![[3.0, 2.0]],
            mode: futago_sim::agent::PathMode::Once,
            speed: None,
            start_time: 0.0,
            heading_deg: 0.0,
            yields: true,
            shirt: [0.2, 0.3, 0.6],
            trousers: [0.1, 0.1, 0.15],
        }],
        ..Default::default()
    };
    let start = Pose2::new(1.0, 2.0, 0.0);
    // The leg mesh's radius: its vertices' largest distance from the leg's axis (z).
    let leg_radius = |seed: u64| {
        let scene = futago_sim::sim::scene(&world, &CreateConfig::default(), &movers, start, seed);
        let leg = scene
            .bodies
            .iter()
            .find(|b| b.name == "person.0.leg_l")
            .expect("the person's left leg is in the scene");
        leg.parts[0]
            .mesh
            .positions
            .iter()
            .map(|p| p.x.hypot(p.y) as f64)
            .fold(0.0, f64::max)
    };
    for seed in [7, 8] {
        let s = futago_sim::Simulation::new(
            &world,
            &futago_sim::PhysicsConfig::default(),
            &CreateConfig::default(),
            &[],
            &movers,
            start,
            seed,
        );
        let want = s.crowd().body_of(0).leg_radius;
        let got = leg_radius(seed);
        assert!(
            (got - want).abs() < 1e-6,
            "seed {seed}: {got} against {want}"
        );
    }
    assert!((leg_radius(7) - leg_radius(8)).abs() > 1e-4);
}
