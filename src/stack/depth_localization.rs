//! The depth-camera localiser node (seed 002): Monte Carlo localisation of one camera in a 3D
//! model, every particle's depth rendered in one batch through the stack's own renderer.
//!
//! The model is handed to the stack as a mesh (`depth_localization.model`): by default the
//! world's mesh, exact (the "laser-scanned model" of seed 002); the world's mesh resampled and
//! displaced (a stand-in for a scanned model); or a file: a user's glTF or PLY mesh, or a map
//! futago's own mapper built (Fallon et al.'s setting, a map made by a robot: the RGB-D map's
//! point cloud, meshed as surfels, or its planar polygons). The filter never reads the
//! simulator's state. At its rate the node
//! takes a frame of its camera, re-projects the measured depth to the render size, moves the
//! particles (by the robot's odometry carried to the camera where `odometry` is set, else the
//! filter's motion model alone), updates, and, for a camera on the robot, publishes the
//! robot's pose under the camera (`pose/depth_localization`, and `depth_localization.txt`,
//! TUM, scored like any trajectory). The filter starts at the camera's true pose at the first
//! frame (seed 002 tracks from a known start).
//!
//! Whatever carries the camera (the robot, or an agent: a pushed wagon, a hand-held camera),
//! the camera's own pose is scored against its true pose at each frame:
//! - the seed's measure: each estimated position's distance to the true path in the plane,
//!   its median, σ and share within 3σ;
//! - the 3D position error and the rotation error (the angle of the rotation between the
//!   estimate and the truth), their median, 95th percentile and largest;
//! - the relative pose error over 1 s (TUM's RPE), RMSE of translation and rotation;
//! - the filter's wall time per frame.
//!
//! The estimated and true camera poses are written as 3D TUM files.

use super::{Bus, CameraFrame, FrameTruth, Node, Report, Streams, Trajectory, Truth};
use super::{Nodes, StackModule, boxed};
use crate::ground_truth::Metrics;
use crate::ground_truth::trajectory::{
    RECOVERED_HOLD_S, RECOVERED_M, recovery_times, worst_recovery,
};
use crate::scenario::{ModuleConfig, Resolving, Scenario, ScenarioSpec, Spec};
use anyhow::{Context, Result};
use futago_msgs::camera::Intrinsics;
use futago_msgs::tum::{Stamped, format_line};
use futago_msgs::{Duration, Pose2, Pose3, Time};
use futago_robot::geometry::distance_field::DistanceField;
use futago_robot::localization::depth_mcl::{
    CameraState, DepthMcl, DepthMclConfig, Likelihood, MeshModel, reproject,
};
use futago_robot::localization::model::{self, ModelConfig};
use futago_sim::config::{SpecError, check_range};
use futago_sim::noise::stream;
use glam::{DQuat, DVec3};
use serde::Deserialize;
use serde_json::json;
use std::any::Any;
use std::path::Path;
use std::time::Instant;

/// The estimates of the robot's planar pose (TUM), one per frame, for a camera on the robot.
pub const DEPTH_LOCALIZATION_FILE: &str = "depth_localization.txt";
/// The estimated camera body poses (TUM, 3D), one per frame.
pub const CAMERA_ESTIMATE_FILE: &str = "depth_camera.txt";
/// The true camera body poses at the same frames (TUM, 3D).
pub const CAMERA_TRUTH_FILE: &str = "depth_camera_truth.txt";

/// Spacing of the true path's points, m (well below the seed's 0.07 m).
const PATH_STEP: f64 = 0.01;

/// Interval of the relative pose error, s.
const RPE_INTERVAL: f64 = 1.0;

/// Cells of the free space particles are drawn in, m, and the band about the camera's height
/// that a surface must cross to take a cell, m.
const FREE_CELL: f64 = 0.25;
const FREE_BAND: f64 = 0.1;

/// One frame's estimate and truth.
struct FrameRecord {
    time: Time,
    estimate: CameraState,
    truth: CameraState,
    /// The filter's wall time, s.
    spent: f64,
    /// Particles after resampling, and hypotheses searched (recovery).
    particles: usize,
    searched: usize,
}

/// The depth-camera localiser in the loop.
pub struct DepthLocalizationNode {
    /// The filter, made at the first frame.
    mcl: Option<DepthMcl>,
    config: DepthMclConfig,
    seed: u64,
    /// The model: its renderer, and its distance field for the likelihood field.
    surfaces: MeshModel,
    /// The wall time the distance field took to build, s (not in the node's time).
    field_s: f64,
    camera: String,
    /// The camera's depth intrinsics and those of the render.
    depth: Intrinsics,
    render: Intrinsics,
    /// The camera's range, m (the model is drawn a little past it).
    range: f64,
    /// The camera's body frame on the base, planar part, when the robot carries it.
    mount2: Option<Pose2>,
    odometry: bool,
    period: Duration,
    next: Time,
    last_odometry: Option<Pose2>,
    track: Trajectory,
    frames: Vec<FrameRecord>,
    summary: Option<serde_json::Value>,
    /// What the model is (for the summary).
    model: serde_json::Value,
    /// The model's meshes in its frame, kept until the first frame when the filter draws
    /// particles anywhere (augmented MCL, a global start), to find the free space.
    meshes: Option<Vec<futago_render::TriMesh>>,
    global: bool,
    /// Kidnapping times, s (the scenario's events).
    events: Vec<f64>,
}

/// The body pose of a camera whose optical frame has pose `optical`.
fn body_of_optical(optical: &Pose3) -> CameraState {
    let r = futago_render::optical_rotation();
    let r = DQuat::from_xyzw(r.x as f64, r.y as f64, r.z as f64, r.w as f64);
    let [x, y, z, w] = optical.rotation;
    let q = (DQuat::from_xyzw(x, y, z, w) * r.inverse()).normalize();
    CameraState::from_pose(&Pose3 {
        translation: optical.translation,
        rotation: [q.x, q.y, q.z, q.w],
    })
}

/// Whether the scenario's localised camera rides on an agent rather than the robot.
fn carried(s: &ScenarioSpec, d: &DepthLocalizationSpec) -> bool {
    // Validation has named the camera by now.
    s.camera
        .iter()
        .find(|c| Some(&c.name) == d.camera.as_ref())
        .is_some_and(|c| c.carrier.is_some())
}

/// The node when the scenario has `[depth_localization]`.
pub fn node(s: &Scenario, seed: u64) -> Result<Option<DepthLocalizationNode>> {
    use rand::Rng;
    let Some(spec) = s.module::<DepthLocalizationSpec>() else {
        return Ok(None);
    };
    let name = spec.camera.clone().unwrap_or_default();
    let cam = s
        .cameras
        .iter()
        .find(|c| c.name == name)
        .with_context(|| format!("depth_localization.camera: no camera is named `{name}`"))?;
    let render = match spec.size {
        Some([w, h]) => cam.depth.scaled(w, h),
        None => cam.depth,
    };
    let draws_anywhere = spec.global || spec.mcl.alpha_slow > 0.0 || spec.mcl.alpha_fast > 0.0;
    let weighs_by_field = spec.mcl.likelihood == Likelihood::Field;
    let (scene, model, meshes) =
        model_scene(s, &spec.model, seed, draws_anywhere || weighs_by_field)?;
    let renderer =
        futago_render::Renderer::new(&scene).context("depth_localization: rendering the model")?;
    let t0 = Instant::now();
    let field = match &meshes {
        Some(meshes) if weighs_by_field => Some(surface_field(meshes, spec.mcl.field_cell)?),
        _ => None,
    };
    let field_s = t0.elapsed().as_secs_f64();
    let meshes = meshes.filter(|_| draws_anywhere);
    Ok(Some(DepthLocalizationNode {
        mcl: None,
        config: spec.mcl,
        seed: stream(seed, "depth_localization.mcl").random(),
        surfaces: MeshModel { renderer, field },
        field_s,
        camera: cam.name.clone(),
        depth: cam.depth,
        render,
        range: cam.range_max,
        mount2: cam.carrier.is_none().then(|| super::camera_on_base(cam)),
        odometry: spec.odometry,
        period: Duration::from_secs(1.0 / spec.rate),
        next: Time::ZERO,
        last_odometry: None,
        track: Trajectory::new("depth_localization"),
        frames: Vec::new(),
        summary: None,
        model,
        meshes,
        global: spec.global,
        events: s.spec.event.iter().map(|e| e.time).collect(),
    }))
}

/// Voxels a model's distance field may take (2 bytes each, 6 while it is built): the office's
/// world at 5 cm takes some 17 million.
const MAX_FIELD_VOXELS: u64 = 100_000_000;

/// The distance field of the model's surfaces (its meshes in the model's frame), for the
/// likelihood field (also `futago bench depth-mcl`'s).
pub fn surface_field(meshes: &[futago_render::TriMesh], cell: f64) -> Result<DistanceField> {
    let triangles: Vec<[[f64; 3]; 3]> = meshes
        .iter()
        .flat_map(|m| {
            m.indices.iter().filter_map(|t| {
                let corner = |i: u32| {
                    m.positions
                        .get(i as usize)
                        .map(|p| [p.x as f64, p.y as f64, p.z as f64])
                };
                Some([corner(t[0])?, corner(t[1])?, corner(t[2])?])
            })
        })
        .collect();
    // A point measured outside the grid is placed by its distance to the grid, so the
    // margin need only hold the surfaces' near side.
    DistanceField::new(&triangles, cell, 0.5, MAX_FIELD_VOXELS)
        .map_err(|e| anyhow::anyhow!("depth_localization.mcl.field_cell: {e}"))
}

/// Every body of a scene at its initial pose, as meshes in the world frame.
pub fn scene_meshes(scene: &futago_render::Scene) -> Vec<futago_render::TriMesh> {
    scene
        .bodies
        .iter()
        .flat_map(|b| {
            b.parts
                .iter()
                .map(|p| p.mesh.transformed(b.pose.rotation, b.pose.translation, 1.0))
        })
        .collect()
}

/// The model's scene, a description of it for the summary, and, when `keep`, its meshes in
/// the model's frame (for the free space).
fn model_scene(
    s: &Scenario,
    spec: &ModelConfig,
    seed: u64,
    keep: bool,
) -> Result<(
    futago_render::Scene,
    serde_json::Value,
    Option<Vec<futago_render::TriMesh>>,
)> {
    let key = "depth_localization.model.file";
    let (meshes, source) = match &spec.file {
        None if spec.perturb.is_none() => {
            let scene = s.world.scene();
            let meshes = scene_meshes(&scene);
            let triangles: usize = meshes.iter().map(|m| m.triangle_count()).sum();
            let v = json!({ "source": "world", "triangles": triangles });
            return Ok((scene, v, keep.then_some(meshes)));
        }
        None => (scene_meshes(&s.world.scene()), "world".to_string()),
        Some(file) => {
            let path = Path::new(file);
            let ext = path
                .extension()
                .and_then(|e| e.to_str())
                .map(str::to_ascii_lowercase);
            let meshes = if ext.as_deref() == Some("ply") {
                let g = futago_msgs::ply::read(path).map_err(|e| anyhow::anyhow!("{key}: {e}"))?;
                if g.triangles.is_empty() {
                    vec![if spec.merge_planes {
                        model::planar_surfels(&g.vertices, spec.surfel)
                    } else {
                        model::surfels(&g.vertices, spec.surfel)
                    }]
                } else {
                    vec![model::mesh_of(&g.vertices, &g.triangles)]
                }
            } else {
                futago_sim::world::gltf_io::load(path)
                    .map_err(|e| anyhow::anyhow!("{key}: {e}"))?
                    .parts
                    .into_iter()
                    .map(|p| p.mesh)
                    .collect()
            };
            (meshes, file.clone())
        }
    };
    let meshes: Vec<futago_render::TriMesh> = match &spec.perturb {
        Some(p) => {
            use rand::Rng;
            let field_seed: u64 = stream(seed, "depth_localization.model").random();
            meshes
                .iter()
                .map(|m| model::perturbed(m, p.spacing, p.noise, field_seed))
                .collect()
        }
        None => meshes,
    };
    let triangles: usize = meshes.iter().map(|m| m.triangle_count()).sum();
    if triangles == 0 {
        anyhow::bail!(
            "{key}: the model {source} has no surface to render (no faces, and no points that form a surface)"
        );
    }
    let v = json!({
        "source": source,
        "triangles": triangles,
        "perturb": spec.perturb.map(|p| json!({ "spacing_m": p.spacing, "noise_m": p.noise })),
    });
    let kept = keep.then(|| meshes.clone());
    Ok((model::scene(meshes), v, kept))
}

/// The metrics this node scores: the camera's (always) and, for a camera on the robot, the
/// trajectory metrics of the robot's pose under `depth_localization`.
fn metric_names(s: &ScenarioSpec, d: &DepthLocalizationSpec) -> Vec<String> {
    let mut names = if carried(s, d) {
        Vec::new()
    } else {
        crate::ground_truth::trajectory_metric_names("depth_localization")
    };
    for k in ["median_m", "sigma_m", "within_3sigma"] {
        names.push(format!("depth_localization.path_error.{k}"));
    }
    for k in ["median_m", "p95_m", "max_m"] {
        names.push(format!("depth_localization.camera.position.{k}"));
    }
    for k in ["median_deg", "p95_deg", "max_deg"] {
        names.push(format!("depth_localization.camera.rotation.{k}"));
    }
    for k in ["trans_rmse_m", "rot_rmse_deg"] {
        names.push(format!("depth_localization.camera.rpe_1s.{k}"));
    }
    names.push("depth_localization.frame_ms".into());
    if !s.event.is_empty() && !carried(s, d) {
        names.push("depth_localization.recovery_s".into());
    }
    if d.global {
        names.push("depth_localization.convergence_s".into());
    }
    names
}

/// The angle of the rotation between two states, rad.
fn rotation_error(a: &CameraState, b: &CameraState) -> f64 {
    let q = |s: &CameraState| {
        let [x, y, z, w] = s.pose().rotation;
        DQuat::from_xyzw(x, y, z, w)
    };
    let d = (q(a).inverse() * q(b)).normalize();
    2.0 * d.w.abs().min(1.0).acos()
}

fn position(s: &CameraState) -> DVec3 {
    DVec3::from_array(s.position)
}

/// TUM's relative pose error over `interval` s: for each frame, the frame at least
/// `interval` later; the error of the estimate's motion against the truth's, as (translation
/// RMSE m, rotation RMSE rad). None when the run is shorter than the interval.
fn relative_pose_error(frames: &[FrameRecord], interval: f64) -> Option<(f64, f64)> {
    let iso = |s: &CameraState| {
        let p = s.pose();
        let [x, y, z, w] = p.rotation;
        glam::DAffine3::from_rotation_translation(
            DQuat::from_xyzw(x, y, z, w),
            DVec3::from_array(p.translation),
        )
    };
    let (mut t2, mut r2, mut n) = (0.0, 0.0, 0usize);
    let mut j = 0;
    for i in 0..frames.len() {
        let due = frames[i].time.secs() + interval;
        while j < frames.len() && frames[j].time.secs() < due - 1e-9 {
            j += 1;
        }
        if j >= frames.len() {
            break;
        }
        let (a, b) = (&frames[i], &frames[j]);
        let truth = iso(&a.truth).inverse() * iso(&b.truth);
        let est = iso(&a.estimate).inverse() * iso(&b.estimate);
        let e = truth.inverse() * est;
        t2 += e.translation.length_squared();
        let q = DQuat::from_mat3(&e.matrix3);
        let angle = 2.0 * q.w.abs().min(1.0).acos();
        r2 += angle * angle;
        n += 1;
    }
    (n > 0).then(|| ((t2 / n as f64).sqrt(), (r2 / n as f64).sqrt()))
}

/// The median, 95th percentile and largest of `v`.
fn spread(v: &[f64]) -> Option<(f64, f64, f64)> {
    if v.is_empty() {
        return None;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let at = |q: f64| s[((s.len() - 1) as f64 * q).round() as usize];
    Some((at(0.5), at(0.95), s[s.len() - 1]))
}

fn tum3(out: &mut String, t: Time, s: &CameraState) {
    format_line(
        out,
        &Stamped {
            stamp: t,
            pose: s.pose(),
        },
    );
}

/// Distance from `p` to the polyline `path`, m.
pub(crate) fn distance_to_path(p: [f64; 2], path: &[[f64; 2]]) -> f64 {
    let seg = |a: [f64; 2], b: [f64; 2]| {
        let d = [b[0] - a[0], b[1] - a[1]];
        let l2 = d[0] * d[0] + d[1] * d[1];
        let t = if l2 > 0.0 {
            (((p[0] - a[0]) * d[0] + (p[1] - a[1]) * d[1]) / l2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        (p[0] - a[0] - t * d[0]).hypot(p[1] - a[1] - t * d[1])
    };
    match path {
        [] => f64::INFINITY,
        [only] => (p[0] - only[0]).hypot(p[1] - only[1]),
        _ => path
            .windows(2)
            .map(|w| seg(w[0], w[1]))
            .fold(f64::INFINITY, f64::min),
    }
}

/// Seed 002's measure: the median and σ of the distances, and the share within 3σ of zero.
fn path_error(d: &[f64]) -> Option<(f64, f64, f64)> {
    if d.is_empty() {
        return None;
    }
    let mut s = d.to_vec();
    s.sort_by(f64::total_cmp);
    let median = s[s.len() / 2];
    let n = s.len() as f64;
    let mean = s.iter().sum::<f64>() / n;
    let sigma = (s.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n).sqrt();
    let within = s.iter().filter(|x| **x <= 3.0 * sigma).count() as f64 / n;
    Some((median, sigma, within))
}

impl Node for DepthLocalizationNode {
    fn name(&self) -> &'static str {
        "depth_localization"
    }

    fn streams(&self) -> Streams {
        let mut consumes = vec![format!("camera/{}", self.camera)];
        if self.odometry {
            consumes.push("odometry".into());
        }
        Streams {
            consumes,
            publishes: if self.mount2.is_some() {
                vec!["pose/depth_localization".into()]
            } else {
                Vec::new()
            },
            ..Streams::default()
        }
    }

    /// A camera an agent carries moves whether the robot does or not: the run goes on to
    /// its duration.
    fn finished(&self) -> bool {
        self.mount2.is_some()
    }

    fn wants_frame(&self, camera: &str, bus: &Bus) -> bool {
        camera == self.camera && bus.now >= self.next
    }

    /// It scores the camera's own pose, whatever carries it.
    fn takes_carried_cameras(&self) -> bool {
        true
    }

    /// It reads the depth image alone.
    fn wants_rgb(&self, _camera: &str) -> bool {
        false
    }

    fn on_frame(
        &mut self,
        camera: &str,
        frame: &CameraFrame,
        view: &mut dyn FrameTruth,
        bus: &mut Bus,
    ) -> Result<()> {
        if camera != self.camera {
            return Ok(());
        }
        self.next = bus.now + self.period;
        // The truth, for the scorer; the filter starts at it (the seed's tracking runs).
        let truth = body_of_optical(&view.optical());
        let odo = bus.odometry;
        // The robot's odometry since the last frame, carried to the camera.
        let motion = match (self.odometry, self.mount2, self.last_odometry) {
            (true, Some(mount), Some(last)) => {
                Some(mount.inverse().compose(&last.between(&odo)).compose(&mount))
            }
            (true, _, _) => Some(Pose2::IDENTITY),
            (false, _, _) => None,
        };
        self.last_odometry = Some(odo);
        let measured = reproject(&frame.frame.depth, &self.depth, &self.render);
        let t0 = Instant::now();
        if self.mcl.is_none() {
            let mut mcl = DepthMcl::new(self.config, truth, self.seed);
            if let Some(meshes) = self.meshes.take() {
                let inside = [truth.position[0], truth.position[1]];
                let free = model::free_cells(
                    &meshes,
                    truth.position[2],
                    FREE_BAND,
                    FREE_CELL,
                    Some(inside),
                )
                .map_err(|e| anyhow::anyhow!("depth_localization: the model's free space: {e}"))?;
                mcl.set_free_space(free, FREE_CELL);
                if self.global {
                    mcl.start_global();
                }
            }
            self.mcl = Some(mcl);
        }
        let mcl = self.mcl.as_mut().expect("made above");
        let est = mcl
            .update(
                &mut self.surfaces,
                &self.render,
                &measured,
                self.range,
                motion.as_ref(),
            )
            .map_err(|e| anyhow::anyhow!("depth_localization: {e}"))?;
        let spent = t0.elapsed().as_secs_f64();
        let (particles, searched) = (mcl.particles().len(), mcl.searched());
        if let Some(mount) = self.mount2 {
            // The base under the estimated camera (planar).
            let c = est.state;
            let yaw = c.rpy[2] - mount.theta;
            let (s, co) = yaw.sin_cos();
            let base = Pose2::new(
                c.position[0] - (co * mount.x - s * mount.y),
                c.position[1] - (s * mount.x + co * mount.y),
                futago_msgs::wrap_angle(yaw),
            );
            bus.publish_pose("depth_localization", base, odo);
            self.track.push(bus.now, &base);
        }
        self.frames.push(FrameRecord {
            time: bus.now,
            estimate: est.state,
            truth,
            spent,
            particles,
            searched,
        });
        Ok(())
    }

    fn finish(&mut self, bus: &mut Bus, out: Option<&Path>) -> Result<Report> {
        let mut report = Report::default();
        if let Some(dir) = out {
            let (mut est, mut truth) = (String::new(), String::new());
            for f in &self.frames {
                tum3(&mut est, f.time, &f.estimate);
                tum3(&mut truth, f.time, &f.truth);
            }
            let files = [(CAMERA_ESTIMATE_FILE, &est), (CAMERA_TRUTH_FILE, &truth)];
            if self.mount2.is_some() {
                self.track.write(dir, DEPTH_LOCALIZATION_FILE, "")?;
                report.files.push(DEPTH_LOCALIZATION_FILE.to_string());
            }
            for (name, text) in files {
                std::fs::write(dir.join(name), text).with_context(|| format!("writing {name}"))?;
                report.files.push(name.to_string());
            }
        }
        if self.mount2.is_some() {
            report.trajectories.push(self.track.clone());
        }
        // The true path in the plane: the camera's true positions, a point every centimetre.
        let mut path: Vec<[f64; 2]> = Vec::new();
        for f in &self.frames {
            let p = [f.truth.position[0], f.truth.position[1]];
            if path
                .last()
                .is_none_or(|l| (p[0] - l[0]).hypot(p[1] - l[1]) >= PATH_STEP)
            {
                path.push(p);
            }
        }
        let d: Vec<f64> = self
            .frames
            .iter()
            .map(|f| distance_to_path([f.estimate.position[0], f.estimate.position[1]], &path))
            .collect();
        let position: Vec<f64> = self
            .frames
            .iter()
            .map(|f| (position(&f.estimate) - position(&f.truth)).length())
            .collect();
        let rotation: Vec<f64> = self
            .frames
            .iter()
            .map(|f| rotation_error(&f.estimate, &f.truth).to_degrees())
            .collect();
        let nan3 = (f64::NAN, f64::NAN, f64::NAN);
        let (p50, p95, pmax) = spread(&position).unwrap_or(nan3);
        let (r50, r95, rmax) = spread(&rotation).unwrap_or(nan3);
        let (rpe_t, rpe_r) =
            relative_pose_error(&self.frames, RPE_INTERVAL).unwrap_or((f64::NAN, f64::NAN));
        let n = self.frames.len().max(1) as f64;
        let frame_ms = self.frames.iter().map(|f| f.spent).sum::<f64>() / n * 1000.0;
        let (median, sigma, within) = path_error(&d).unwrap_or(nan3);
        let errors: Vec<(f64, f64)> = self
            .frames
            .iter()
            .zip(&position)
            .map(|(f, e)| (f.time.secs(), *e))
            .collect();
        let end = bus.now.secs();
        let counts: Vec<usize> = self.frames.iter().map(|f| f.particles).collect();
        let mut v = json!({
            "frames": self.frames.len(),
            "render": [self.render.width, self.render.height],
            "carrier": if self.mount2.is_some() { "robot" } else { "agent" },
            "model": self.model,
            "likelihood": self.config.likelihood,
            "field": self.surfaces.field.as_ref().map(|f| json!({
                "cell_m": f.cell(),
                "voxels": f.dims(),
                "build_s": self.field_s,
            })),
            "frame_ms": frame_ms,
            "path_error": {
                "median_m": median,
                "sigma_m": sigma,
                "within_3sigma": within,
                "what": "each estimated camera position's distance to the camera's true path in the plane (seed 002 §4)",
            },
            "camera": {
                "position": { "median_m": p50, "p95_m": p95, "max_m": pmax },
                "rotation": { "median_deg": r50, "p95_deg": r95, "max_deg": rmax },
                "rpe_1s": { "trans_rmse_m": rpe_t, "rot_rmse_deg": rpe_r.to_degrees() },
            },
            "particles": {
                "mean": counts.iter().sum::<usize>() as f64 / n,
                "max": counts.iter().max(),
                "frames_searching": self.frames.iter().filter(|f| f.searched > 0).count(),
                "searched_max": self.frames.iter().map(|f| f.searched).max(),
            },
        });
        // Kidnappings move the robot, so they are scored for a camera it carries.
        if !self.events.is_empty() && self.mount2.is_some() {
            v["kidnappings"] = json!(
                self.events
                    .iter()
                    .zip(recovery_times(&errors, &self.events))
                    .map(|(t, r)| json!({
                        "time_s": t,
                        "recovered_after_s": r,
                        "recovered_when": format!("camera position error < {RECOVERED_M} m for {RECOVERED_HOLD_S} s"),
                    }))
                    .collect::<Vec<_>>()
            );
            v["recovery_s"] = json!(worst_recovery(&errors, &self.events, end));
        }
        if self.global {
            v["convergence_s"] = json!(worst_recovery(&errors, &[0.0], end));
        }
        self.summary = Some(v.clone());
        report.summary.push(("depth_localization".into(), v));
        Ok(report)
    }

    fn score(&self, truth: &Truth) -> Result<Metrics> {
        let mut m = if self.mount2.is_some() {
            crate::ground_truth::score_trajectory(truth, &self.track.name, &self.track.poses)
        } else {
            Metrics::default()
        };
        if let Some(v) = &self.summary {
            for k in ["median_m", "sigma_m", "within_3sigma"] {
                if let Some(x) = v["path_error"][k].as_f64() {
                    m.insert(format!("depth_localization.path_error.{k}"), x);
                }
            }
            for (group, keys) in [
                ("position", &["median_m", "p95_m", "max_m"][..]),
                ("rotation", &["median_deg", "p95_deg", "max_deg"][..]),
                ("rpe_1s", &["trans_rmse_m", "rot_rmse_deg"][..]),
            ] {
                for k in keys {
                    if let Some(x) = v["camera"][group][k].as_f64() {
                        m.insert(format!("depth_localization.camera.{group}.{k}"), x);
                    }
                }
            }
            for k in ["frame_ms", "recovery_s", "convergence_s"] {
                if let Some(x) = v[k].as_f64() {
                    m.insert(format!("depth_localization.{k}"), x);
                }
            }
        }
        Ok(m)
    }
}

/// The depth-camera localiser of a run (seed 002): MCL of one camera in the world's mesh,
/// handed to the stack as its 3D model.
#[derive(Debug, Clone, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct DepthLocalizationSpec {
    /// The camera it localises (by name; may be left out when the scenario has one).
    #[serde(default)]
    pub camera: Option<String>,
    /// Frames the filter takes per second (seed 002 took 125 ms a frame: 8 Hz).
    #[serde(default = "default_depth_localization_rate")]
    pub rate: f64,
    /// Render size [width, height], px: the particles' views and the measured depth
    /// re-projected to it; none: the camera's depth size.
    #[serde(default)]
    pub size: Option<[u32; 2]>,
    /// Carry the particles by the robot's odometry; false: seed 002's carrier without it
    /// (the random walk alone).
    #[serde(default)]
    pub odometry: bool,
    /// Start from anywhere in the model's free space (`mcl.max_particles` particles, any
    /// yaw) instead of the camera's true pose; scored by `depth_localization.convergence_s`.
    #[serde(default)]
    pub global: bool,
    #[serde(default)]
    pub mcl: futago_robot::localization::depth_mcl::DepthMclConfig,
    /// The model the filter renders: the world's mesh (exact or perturbed), or a mesh or
    /// point cloud file (`file`, relative to the scenario; resolved when the scenario loads).
    #[serde(default)]
    pub model: futago_robot::localization::model::ModelConfig,
}

fn default_depth_localization_rate() -> f64 {
    8.0
}

/// `[depth_localization]`: Monte Carlo localisation of a depth camera in the world's 3D model
/// (seed 002).
pub struct Module;

impl ModuleConfig for Module {
    fn key(&self) -> Option<&'static str> {
        Some("depth_localization")
    }

    fn resolve(&self, cx: &Resolving<'_>, table: &toml::Value) -> Result<Spec, SpecError> {
        let key = "depth_localization";
        let mut d: DepthLocalizationSpec = cx.typed(key, cx.table(key, table)?)?;
        let path = cx.path;
        if cx.cameras.is_empty() {
            return Err(SpecError::new(
                path,
                "depth_localization",
                "depth-camera localisation needs a [[camera]]; the scenario has none",
            ));
        }
        let cam = cx.camera(key, d.camera.as_deref())?;
        let name = cam.name.clone();
        if cam.joint.is_some() {
            return Err(SpecError::new(
                path,
                "depth_localization.camera",
                format!(
                    "camera `{name}` rides on a joint; the localiser needs one fixed to the base"
                ),
            ));
        }
        if let (Some(a), true) = (&cam.carrier, d.odometry) {
            return Err(SpecError::new(
                path,
                "depth_localization.odometry",
                format!(
                    "camera `{name}` is carried by agent `{a}`, which has no odometry: set odometry = false"
                ),
            ));
        }
        check_range(path, "depth_localization.rate", d.rate, 0.1, 100.0, "Hz")?;
        if let Some([w, h]) = d.size {
            for (k, v, most) in [(0, w, cam.depth.width), (1, h, cam.depth.height)] {
                if v == 0 || v > most {
                    return Err(SpecError::new(
                        path,
                        format!("depth_localization.size[{k}]"),
                        format!("expected 1 to the camera's {most} px, found {v}"),
                    ));
                }
            }
        }
        d.mcl
            .validate("depth_localization.mcl")
            .map_err(|(k, m)| SpecError::new(path, k, m))?;
        d.model
            .validate("depth_localization.model")
            .map_err(|(k, m)| SpecError::new(path, k, m))?;
        if let Some(file) = &d.model.file {
            let resolved = path.parent().unwrap_or(Path::new(".")).join(file);
            let ext = resolved
                .extension()
                .and_then(|e| e.to_str())
                .map(str::to_ascii_lowercase);
            if !matches!(ext.as_deref(), Some("ply" | "glb" | "gltf")) {
                return Err(SpecError::new(
                    path,
                    "depth_localization.model.file",
                    format!("{file}: expected a .ply, .glb or .gltf file"),
                ));
            }
            if !resolved.is_file() {
                return Err(SpecError::new(
                    path,
                    "depth_localization.model.file",
                    format!("model file {} does not exist", resolved.display()),
                ));
            }
            // Absolute, so the spec reads the same wherever it is checked again.
            let resolved = std::fs::canonicalize(&resolved).unwrap_or(resolved);
            d.model.file = Some(resolved.to_string_lossy().into_owned());
        }
        d.camera = Some(name);
        Ok(Box::new(d))
    }

    fn effective(&self, spec: &(dyn Any + Send + Sync)) -> Option<toml::Table> {
        toml::Table::try_from(spec.downcast_ref::<DepthLocalizationSpec>()?).ok()
    }

    fn metric_names(
        &self,
        spec: &ScenarioSpec,
        own: Option<&(dyn Any + Send + Sync)>,
    ) -> Vec<String> {
        super::own::<DepthLocalizationSpec>(own)
            .map(|d| metric_names(spec, d))
            .unwrap_or_default()
    }
}

impl StackModule for Module {
    fn build(&self, s: &Scenario, seed: u64, _out: Option<&Path>) -> Nodes {
        boxed(node(s, seed))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state(x: f64, y: f64, yaw: f64) -> CameraState {
        CameraState {
            position: [x, y, 1.0],
            rpy: [0.0, 0.0, yaw],
        }
    }

    fn record(t: f64, estimate: CameraState, truth: CameraState) -> FrameRecord {
        FrameRecord {
            time: Time::from_secs(t),
            estimate,
            truth,
            spent: 0.0,
            particles: 1,
            searched: 0,
        }
    }

    /// The optical frame is the body frame turned (x right, y down, z forward): undoing the
    /// turn gives the body pose back.
    #[test]
    fn the_body_pose_is_recovered_from_the_optical_pose() {
        let body = CameraState {
            position: [1.0, -2.0, 0.9],
            rpy: [0.05, -0.1, 2.0],
        };
        let o = futago_render::optical_from_body(
            &futago_robot::localization::depth_mcl::render_pose(&body.pose()),
        );
        let optical = Pose3 {
            translation: [
                o.translation.x as f64,
                o.translation.y as f64,
                o.translation.z as f64,
            ],
            rotation: [
                o.rotation.x as f64,
                o.rotation.y as f64,
                o.rotation.z as f64,
                o.rotation.w as f64,
            ],
        };
        let back = body_of_optical(&optical);
        for k in 0..3 {
            assert!(
                (back.position[k] - body.position[k]).abs() < 1e-5,
                "{back:?}"
            );
            assert!((back.rpy[k] - body.rpy[k]).abs() < 1e-5, "{back:?}");
        }
    }

    /// Rotation errors by hand: 3° of yaw alone, and 4° of roll alone.
    #[test]
    fn rotation_errors_are_the_angle_between_the_rotations() {
        let a = state(0.0, 0.0, 0.5);
        let b = state(0.0, 0.0, 0.5 + 3f64.to_radians());
        assert!((rotation_error(&a, &b).to_degrees() - 3.0).abs() < 1e-9);
        let c = CameraState {
            position: [0.0; 3],
            rpy: [4f64.to_radians(), 0.0, 0.5],
        };
        assert!((rotation_error(&a, &c).to_degrees() - 4.0).abs() < 1e-9);
    }

    /// TUM's RPE: an estimate off by a constant pose has no relative error; one that moves
    /// 10 % too far has 10 % of the truth's 1 s motion; none when the run is shorter than 1 s.
    #[test]
    fn the_relative_pose_error_sees_drift_not_offsets() {
        let frames: Vec<FrameRecord> = (0..40)
            .map(|i| {
                let t = i as f64 * 0.125;
                record(t, state(0.4 * t + 0.3, 0.2, 0.1), state(0.4 * t, 0.0, 0.1))
            })
            .collect();
        let (tr, rot) = relative_pose_error(&frames, 1.0).unwrap();
        assert!(tr < 1e-9 && rot < 1e-9, "{tr} {rot}");
        let frames: Vec<FrameRecord> = (0..40)
            .map(|i| {
                let t = i as f64 * 0.125;
                record(t, state(0.44 * t, 0.0, 0.0), state(0.4 * t, 0.0, 0.0))
            })
            .collect();
        let (tr, _) = relative_pose_error(&frames, 1.0).unwrap();
        assert!((tr - 0.04).abs() < 1e-9, "{tr}");
        assert!(relative_pose_error(&frames[..8], 1.0).is_none());
    }

    /// The seed's measure by hand: distances to an L-shaped path, their median, σ and share
    /// within 3σ.
    #[test]
    fn the_path_error_is_the_distance_to_the_true_path() {
        let path = [[0.0, 0.0], [4.0, 0.0], [4.0, 3.0]];
        assert!((distance_to_path([2.0, 0.5], &path) - 0.5).abs() < 1e-12);
        assert!((distance_to_path([4.5, 2.0], &path) - 0.5).abs() < 1e-12);
        assert!((distance_to_path([-1.0, 0.0], &path) - 1.0).abs() < 1e-12);
        let mut d = vec![0.1; 9];
        d.push(2.0);
        let (median, sigma, within) = path_error(&d).unwrap();
        assert!((median - 0.1).abs() < 1e-12);
        // Mean 0.29; σ = √((9·0.19² + 1.71²)/10) = 0.57; 3σ = 1.71 < 2.
        assert!((sigma - 0.57).abs() < 1e-9, "{sigma}");
        assert!((within - 0.9).abs() < 1e-12);
    }
}
