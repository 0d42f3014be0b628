//! Worlds: the shipped worlds, ground-truth grids, and the glTF/PLY round trips.

mod common;

use common::*;
use futago_msgs::{DriveCommand, Pose2};
use futago_sim::World;
use futago_sim::create::CreateConfig;
use futago_sim::world::{export, gltf_io};
use glam::Vec3;
use std::path::Path;

fn shipped(name: &str) -> World {
    World::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../worlds/{name}.toml")))
        .unwrap()
}

#[test]
fn occupancy_grid_marks_exactly_what_crosses_the_band() {
    let desk = "[[boxes]]\nmaterial = \"m\"\ncenter = [2.0, 2.0]\nbase = 0.7\nsize = [1.0, 0.6, 0.03]\n[[boxes]]\nmaterial = \"m\"\ncenter = [1.6, 1.8]\nsize = [0.04, 0.04, 0.7]\n";
    let w = box_room(4.0, 3.0, desk);
    let g = export::occupancy_grid(&w, 0.05, 0.15, 0.25, 0.0).unwrap();
    let at = |x: f64, y: f64| {
        let (i, j) = g.cell_of(x, y).unwrap();
        g.get(i, j)
    };
    assert_eq!(at(-0.05, 1.5), 100, "inside the west wall");
    assert_eq!(at(4.05, 1.5), 100, "inside the east wall");
    assert_eq!(at(0.03, 1.5), 0, "just inside the room");
    assert_eq!(at(1.6, 1.8), 100, "the desk leg");
    assert_eq!(at(2.2, 2.1), 0, "under the desk top, at laser height");
    let top = export::occupancy_grid(&w, 0.05, 0.7, 0.72, 0.0).unwrap();
    let (i, j) = top.cell_of(2.2, 2.1).unwrap();
    assert_eq!(top.get(i, j), 100, "the desk top in its own band");
    // Walls 0.2 m thick and 3 m / 4 m long: occupied area close to their footprint.
    let walls = 2.0 * (4.4 * 0.2) + 2.0 * (3.0 * 0.2) + 0.05 * 0.05;
    let area = g.occupied_count() as f64 * 0.0025;
    assert!(
        (area - walls).abs() < 0.3,
        "occupied {area} m² vs walls {walls} m²"
    );
}

#[test]
fn glb_export_loads_back_with_the_same_geometry() {
    let w = shipped("lab");
    let poses: Vec<_> = w.objects.iter().map(|o| o.pose).collect();
    let bytes = gltf_io::export_glb(&w, &poses);
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("lab.glb");
    std::fs::write(&p, &bytes).unwrap();
    let back = gltf_io::load(&p).unwrap();
    let tris: usize = back.parts.iter().map(|p| p.mesh.triangle_count()).sum();
    assert_eq!(tris, w.triangle_count());
    let (lo, hi) = w.bounds();
    let (mut blo, mut bhi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for p in &back.parts {
        for v in &p.mesh.positions {
            blo = blo.min(*v);
            bhi = bhi.max(*v);
        }
    }
    assert!(
        (blo - lo).abs().max_element() < 1e-4 && (bhi - hi).abs().max_element() < 1e-4,
        "{blo} {bhi} vs {lo} {hi}"
    );
    // Textured materials keep their textures.
    assert_eq!(back.textures.len(), w.textures.len());
}

#[test]
fn ply_export_counts_every_vertex_and_face() {
    let w = shipped("hall");
    let ply = export::to_ply(&w);
    let text = String::from_utf8_lossy(&ply[..400]);
    let nv: usize = w
        .objects
        .iter()
        .flat_map(|o| &o.parts)
        .map(|p| p.mesh.positions.len())
        .sum();
    assert!(text.contains(&format!("element vertex {nv}\n")));
    assert!(text.contains(&format!("element face {}\n", w.triangle_count())));
    let header = text.find("end_header\n").unwrap() + "end_header\n".len();
    assert_eq!(ply.len(), header + nv * 27 + w.triangle_count() * 13);
}

/// Free span through `(x, y, z)` along ±`axis` (to the nearest surfaces both ways), by ray
/// casts in a stepped simulation.
fn span(w: &World, x: f64, y: f64, z: f32, axis: Vec3) -> f64 {
    let mut s = sim(w, &CreateConfig::default(), &[], Pose2::new(x, y, 0.0), 0);
    s.step(Some(&DriveCommand::STOP));
    let o = Vec3::new(x as f32, y as f32, z);
    (s.cast_ray(o, axis, 50.0).unwrap() + s.cast_ray(o, -axis, 50.0).unwrap()) as f64
}

#[test]
fn shipped_worlds_have_their_promised_features() {
    let office = shipped("office");
    let narrow = span(&office, 15.0, 11.0, 0.2, Vec3::X);
    assert!(narrow <= 1.2 && narrow > 0.8, "narrow corridor {narrow} m");
    let wide = span(&office, 5.0, 8.0, 0.2, Vec3::Y);
    assert!(wide > 1.2, "wide corridor {wide} m");
    assert!(office.spawn("dock").is_some());
    assert!(office.textures.len() >= 4, "posters, doors, plaster");
    assert!(
        office.objects.iter().any(|o| o.name.contains("meshes")),
        "chairs from the glTF asset"
    );

    let lab = shipped("lab");
    let (w, l) = (
        span(&lab, 6.5, 3.5, 2.0, Vec3::Y),
        span(&lab, 6.5, 3.5, 2.0, Vec3::X),
    );
    assert!(
        (w - 7.0).abs() < 0.01 && (l - 13.0).abs() < 0.01,
        "lab {l} × {w} m"
    );

    let hall = shipped("hall");
    assert!(
        hall.objects
            .iter()
            .filter(|o| o.name.starts_with("prefabs.pillar"))
            .count()
            >= 10
    );
    let corridor = span(&hall, 5.0, 0.0, 0.2, Vec3::Y);
    let open = span(&hall, 20.0, 2.2, 0.2, Vec3::Y);
    assert!(
        corridor < 2.5 && open > 6.0,
        "corridor {corridor} m opening to the hall"
    );
}

#[test]
fn loading_is_deterministic() {
    let a = shipped("office");
    let b = shipped("office");
    assert_eq!(a.triangle_count(), b.triangle_count());
    assert_eq!(a.textures, b.textures);
    assert_eq!(
        gltf_io::export_glb(&a, &a.objects.iter().map(|o| o.pose).collect::<Vec<_>>()),
        gltf_io::export_glb(&b, &b.objects.iter().map(|o| o.pose).collect::<Vec<_>>())
    );
}
