//! Seed 001's mapping pass as a node: a trinocular camera (three `[[camera]]`s in an L) driven
//! once along a route builds a map of SIFT landmarks, written as `landmarks.json`
//! ([`futago_msgs::landmarks`]).
//!
//! At its rate the node takes the three cameras' frames of one instant, finds SIFT keypoints
//! in each, matches and triangulates them (`perception::trinocular`), and hands the points
//! to the mapper (`mapping::landmark_map`), which places the frame by the seed's exhaustive
//! 3D search (`pose_source = "seed"`), centred on the wheels' prediction of the frame's
//! motion (`prediction = "odometry"`) or on the last pose (`"stationary"`, the seed's), or at
//! the right camera's true pose (`"ground_truth"`). The map file's `made_by` names the run
//! that remakes it, with the renderer backend it was forced to (`FUTAGO_GPU_BACKEND`).
//! The first frame is placed at the true pose: the seed's map frame is its first camera
//! frame, and this ties it to the world's, where the truth scores it.
//!
//! Scores, against the simulated truth:
//! - the stereo false-match rate (the seed: 0 %): a triangulated point is false when its depth
//!   is more than 3σ (its own eq. 6 σ) and 5 cm from the true depth at its pixel and every
//!   neighbour;
//! - each landmark's distance to the true point it was first seen at (the true depth at its
//!   first keypoint, back-projected from the true camera pose), for landmarks seen twice or
//!   more;
//! - the mapping pass's pose error per frame (the seed's own ground truth for localisation).

use super::{Bus, CameraFrame, FrameTruth, Node, Report, Streams, Truth};
use super::{Nodes, StackModule, boxed};
use crate::ground_truth::Metrics;
use crate::scenario::{ModuleConfig, Resolving, Scenario, ScenarioSpec, Spec};
use anyhow::{Context, Result};
use futago_msgs::{Duration, Pose2, Pose3, Time};
use futago_robot::localization::landmarks::Camera;
use futago_robot::mapping::landmark_map::{LandmarkMapper, MappingConfig, MappingStep};
use futago_robot::perception::features::grey;
use futago_robot::perception::sift::{self, Keypoint, SiftConfig};
use futago_robot::perception::trinocular::{self, Rig, StereoConfig};
use futago_sim::config::SpecError;
use glam::{DQuat, DVec3};
use image::GrayImage;
use serde::{Deserialize, Serialize};
use serde_json::json;
use std::any::Any;
use std::path::Path;

/// The map file a run writes.
pub const MAP_FILE: &str = "landmarks.json";

/// Where the mapping pass's frames are placed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MapPoseSource {
    /// The seed's exhaustive search of eqs. 7–11 from the last pose.
    #[default]
    Seed,
    /// The right camera's true pose (a map free of the pass's own drift).
    GroundTruth,
}

/// What each frame's search is centred on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MapPrediction {
    /// The last pose carried by the Create's wheel odometry since the last frame, its error
    /// weighed by `mapping.odometry` (not in the seed, whose base had no usable encoders).
    #[default]
    Odometry,
    /// The last pose (the seed: the robot is predicted to stand still).
    Stationary,
}

/// `[visual_map]`: seed 001's trinocular mapping pass.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VisualMapSpec {
    /// The rig's cameras by name: the right (reference) camera, the left one `b` to its left,
    /// the top one `b` above it; same intrinsics, orientation and rate.
    pub cameras: [String; 3],
    /// Frames taken per second.
    #[serde(default = "default_rate")]
    pub rate: f64,
    #[serde(default)]
    pub pose_source: MapPoseSource,
    #[serde(default)]
    pub prediction: MapPrediction,
    /// Landmarks seen fewer times than this are left out of the file (the seed's map figure
    /// shows those seen twice or more).
    #[serde(default = "default_min_observations")]
    pub min_observations: u32,
    #[serde(default)]
    pub sift: SiftConfig,
    #[serde(default)]
    pub stereo: StereoConfig,
    #[serde(default)]
    pub mapping: MappingConfig,
}

fn default_rate() -> f64 {
    5.0
}

fn default_min_observations() -> u32 {
    2
}

/// A camera's planar body pose from its optical pose: position, and the yaw of its optical
/// axis (the camera is levelled).
pub fn planar_of_optical(o: &Pose3) -> Pose2 {
    let [x, y, z, w] = o.rotation;
    let forward = DQuat::from_xyzw(x, y, z, w) * DVec3::Z;
    Pose2::new(
        o.translation[0],
        o.translation[1],
        forward.y.atan2(forward.x),
    )
}

/// Checks the rig: three cameras of the scenario, on the robot, levelled, with the same
/// intrinsics and rate, the left one displaced only to the left and the top one only up, by
/// the same baseline. Returns the baseline, m.
pub fn check_rig(
    names: &[String],
    spec: &ScenarioSpec,
    cams: &[futago_sim::kinect::KinectSpec],
) -> Result<f64, String> {
    let find = |n: &str| {
        spec.camera
            .iter()
            .zip(cams)
            .find(|(c, _)| c.name == n)
            .ok_or_else(|| {
                let all: Vec<&str> = cams.iter().map(|c| c.name.as_str()).collect();
                format!("no camera is named `{n}`; the scenario's cameras are {all:?}")
            })
    };
    let mut found = Vec::new();
    for n in names {
        let (c, s) = find(n)?;
        if c.joint.is_some() || c.carrier.is_some() {
            return Err(format!("camera `{n}` must be fixed to the robot's base"));
        }
        if c.rpy_deg[0] != 0.0 || c.rpy_deg[1] != 0.0 {
            return Err(format!(
                "camera `{n}` must be levelled (roll and pitch 0): the state is planar"
            ));
        }
        found.push((c, s));
    }
    let (r, rs) = found[0];
    if rs.depth != rs.rgb {
        return Err(format!(
            "camera `{}` (right) must have its depth_size equal to its rgb_size: its true depth scores the stereo points pixel by pixel",
            r.name
        ));
    }
    for (c, s) in &found[1..] {
        if s.rgb != rs.rgb || s.rate != rs.rate || c.rpy_deg != r.rpy_deg {
            return Err(format!(
                "camera `{}` differs from `{}` in its colour intrinsics, rate or orientation",
                c.name, r.name
            ));
        }
    }
    let d =
        |c: &futago_sim::kinect::KinectConfig| DVec3::from_array(c.xyz) - DVec3::from_array(r.xyz);
    // In the cameras' own frame (their yaw on the base).
    let yaw = r.rpy_deg[2].to_radians();
    let unrotate = |v: DVec3| DQuat::from_rotation_z(-yaw) * v;
    let (l, t) = (unrotate(d(found[1].0)), unrotate(d(found[2].0)));
    let b = l.y;
    if !(b > 0.005 && l.x.abs() < 1e-3 && l.z.abs() < 1e-3) {
        return Err(String::from(
            "the second camera (left) must sit straight to the left of the first (right), at least 5 mm",
        ));
    }
    if !(t.x.abs() < 1e-3 && t.y.abs() < 1e-3 && (t.z - b).abs() < 1e-3) {
        return Err(format!(
            "the third camera (top) must sit straight above the first (right) by the same baseline, {b:.4} m"
        ));
    }
    Ok(b)
}

/// The node when the scenario has `[visual_map]`, for a run with `seed`.
pub fn node(s: &Scenario, seed: u64) -> Result<Option<VisualMapNode>> {
    let Some(spec) = s.module::<VisualMapSpec>() else {
        return Ok(None);
    };
    let baseline = check_rig(&spec.cameras, &s.spec, &s.cameras)
        .map_err(|e| anyhow::anyhow!("visual_map.cameras: {e}"))?;
    let right = s
        .cameras
        .iter()
        .find(|c| c.name == spec.cameras[0])
        .context("the rig's right camera")?;
    let camera = Camera {
        intrinsics: right.rgb,
        height: right.mount.translation.z as f64,
    };
    let mount = super::camera_on_base(right);
    let start = s.start.compose(&mount);
    Ok(Some(VisualMapNode {
        spec: spec.clone(),
        rig: Rig {
            intrinsics: right.rgb,
            baseline,
        },
        mapper: LandmarkMapper::new(camera, baseline, spec.mapping, start),
        mount,
        last_odometry: None,
        made_by: format!(
            "{}futago run scenarios/{}.toml --seed {} (the run's {MAP_FILE}; frames placed by {})",
            backend_prefix(),
            s.spec.name,
            seed,
            match (spec.pose_source, spec.prediction) {
                (MapPoseSource::GroundTruth, _) => "the truth",
                (MapPoseSource::Seed, MapPrediction::Odometry) =>
                    "the seed's search about the wheels' prediction",
                (MapPoseSource::Seed, MapPrediction::Stationary) => "the seed's search",
            }
        ),
        period: Duration::from_secs(1.0 / spec.rate),
        next: Time::ZERO,
        pending: [None, None, None],
        true_depth: None,
        frames: Vec::new(),
        first_truth: Vec::new(),
        sift_s: 0.0,
        sift_buffers: Default::default(),
        stereo_s: 0.0,
        mapping_s: 0.0,
        summary: None,
    }))
}

/// The renderer choice the run was forced to, as the shell prefix that repeats it (empty for
/// `auto`): the keypoints come from rasterised pixels, and lavapipe and llvmpipe do not
/// rasterise the same bits, so a map is remade byte for byte only on the backend that made it.
fn backend_prefix() -> String {
    use futago_render::gpu::{BACKEND_ENV, BackendChoice};
    match BackendChoice::from_env() {
        Ok(BackendChoice::Gl) => format!("{BACKEND_ENV}=gl "),
        Ok(BackendChoice::Vulkan) => format!("{BACKEND_ENV}=vulkan "),
        _ => String::new(),
    }
}

/// One mapping frame's record.
struct FrameRecord {
    time: Time,
    truth: Pose2,
    step: MappingStep,
    keypoints: [usize; 3],
    /// Triangulated points judged against the true depth, and the false ones.
    judged: usize,
    false_matches: usize,
}

/// The mapping pass in the loop.
pub struct VisualMapNode {
    spec: VisualMapSpec,
    rig: Rig,
    mapper: LandmarkMapper,
    /// The right camera's planar pose on the base.
    mount: Pose2,
    /// The odometry's base pose at the last frame placed.
    last_odometry: Option<Pose2>,
    /// The map file's `made_by`.
    made_by: String,
    period: Duration,
    next: Time,
    /// This instant's grey images of right, left and top (their keypoints found together,
    /// on the cores, once all three are in), and the right camera's true pose.
    pending: [Option<(Time, GrayImage)>; 3],
    true_depth: Option<(Time, Pose2, futago_msgs::camera::DepthImage)>,
    frames: Vec<FrameRecord>,
    /// Per landmark, the true point of its first keypoint (none where the truth had no depth).
    first_truth: Vec<Option<DVec3>>,
    sift_s: f64,
    /// The detector's memory for each camera, kept from frame to frame (each behind a lock
    /// its own image's thread takes alone).
    sift_buffers: [std::sync::Mutex<sift::SiftBuffers>; 3],
    stereo_s: f64,
    mapping_s: f64,
    summary: Option<serde_json::Value>,
}

/// Whether a triangulated depth `z` (σ `sz`) is false against the true depths about pixel
/// (u, v).
fn is_false(
    depth: &futago_msgs::camera::DepthImage,
    u: f32,
    v: f32,
    z: f64,
    sz: f64,
) -> Option<bool> {
    let (u, v) = (u.round() as i64, v.round() as i64);
    let tol = (3.0 * sz).max(0.05);
    let mut any = false;
    for dv in -1..=1 {
        for du in -1..=1 {
            let (x, y) = (u + du, v + dv);
            if x < 0 || y < 0 || x >= depth.width as i64 || y >= depth.height as i64 {
                continue;
            }
            let t = depth.at(x as u32, y as u32) as f64;
            if t <= 0.0 {
                continue;
            }
            any = true;
            if (t - z).abs() <= tol {
                return Some(false);
            }
        }
    }
    any.then_some(true)
}

impl VisualMapNode {
    fn process(&mut self, time: Time, odometry: Pose2) -> Result<()> {
        let [Some((_, right)), Some((_, left)), Some((_, top))] = std::mem::take(&mut self.pending)
        else {
            return Ok(());
        };
        // The three images' keypoints, each image on a core where there are several: each
        // image's keypoints are its own whichever thread finds them.
        let t0 = std::time::Instant::now();
        let sift = &self.spec.sift;
        let images = [
            (right, &self.sift_buffers[0]),
            (left, &self.sift_buffers[1]),
            (top, &self.sift_buffers[2]),
        ];
        let found = futago_robot::cores::map_on_cores(&images, 2, |(img, buffers)| {
            // A lock poisoned by a panic elsewhere still holds buffers `detect_with` may use.
            let mut buffers = buffers.lock().unwrap_or_else(|e| e.into_inner());
            sift::detect_with(img, sift, &mut buffers)
        });
        self.sift_s += t0.elapsed().as_secs_f64();
        let Ok([right, left, top]) = <[Vec<Keypoint>; 3]>::try_from(found) else {
            anyhow::bail!("visual map: not one set of keypoints for each of the three images");
        };
        let Some((_, truth, depth)) = self.true_depth.take() else {
            return Ok(());
        };
        let t0 = std::time::Instant::now();
        let points = trinocular::triangulate(&self.rig, &right, &left, &top, &self.spec.stereo);
        self.stereo_s += t0.elapsed().as_secs_f64();
        let (mut judged, mut false_matches) = (0, 0);
        for p in &points {
            let k = &right[p.keypoint];
            if let Some(f) = is_false(&depth, k.x, k.y, p.position.z, p.covariance.z_axis.z.sqrt())
            {
                judged += 1;
                false_matches += f as usize;
            }
        }
        let known = (self.spec.pose_source == MapPoseSource::GroundTruth || self.frames.is_empty())
            .then_some(truth);
        let camera = |o: &Pose2| o.compose(&self.mount);
        let motion = match (self.spec.prediction, self.last_odometry) {
            (MapPrediction::Odometry, Some(last)) => {
                Some(camera(&last).between(&camera(&odometry)))
            }
            _ => None,
        };
        self.last_odometry = Some(odometry);
        let t1 = std::time::Instant::now();
        let step = self.mapper.add_frame(&points, &right, known, motion);
        self.mapping_s += t1.elapsed().as_secs_f64();
        // The truth of each new landmark: its keypoint's true depth from the true pose.
        let cam = self.mapper.camera;
        let r = futago_robot::localization::landmarks::optical_rotation(truth.theta);
        for &i in &step.new_points {
            let k = &right[points[i].keypoint];
            let (u, v) = (k.x.round() as i64, k.y.round() as i64);
            let inside = u >= 0 && v >= 0 && u < depth.width as i64 && v < depth.height as i64;
            let z = if inside {
                depth.at(u as u32, v as u32) as f64
            } else {
                0.0
            };
            self.first_truth.push((z > 0.0).then(|| {
                let o = cam.intrinsics.back_project(k.x as f64, k.y as f64, z);
                r.transpose() * DVec3::from_array(o) + cam.centre(&truth)
            }));
        }
        self.frames.push(FrameRecord {
            time,
            truth,
            step,
            keypoints: [right.len(), left.len(), top.len()],
            judged,
            false_matches,
        });
        Ok(())
    }
}

impl Node for VisualMapNode {
    fn name(&self) -> &'static str {
        "visual_map"
    }

    fn streams(&self) -> Streams {
        Streams {
            consumes: self
                .spec
                .cameras
                .iter()
                .map(|c| format!("camera/{c}"))
                .collect(),
            publishes: vec!["map/landmarks".into()],
            periods: Vec::new(),
        }
    }

    fn wants_frame(&self, camera: &str, bus: &Bus) -> bool {
        bus.now >= self.next && self.spec.cameras.iter().any(|c| c == camera)
    }

    fn on_frame(
        &mut self,
        camera: &str,
        frame: &CameraFrame,
        truth: &mut dyn FrameTruth,
        bus: &mut Bus,
    ) -> Result<()> {
        let Some(i) = self.spec.cameras.iter().position(|c| c == camera) else {
            return Ok(());
        };
        let Some(rgb) = &frame.frame.rgb else {
            return Ok(());
        };
        let img = grey(rgb.width, rgb.height, &rgb.data);
        if i == 0 {
            let depth = truth.true_depth()?;
            self.true_depth = Some((bus.now, planar_of_optical(&truth.optical()), depth));
        }
        self.pending[i] = Some((bus.now, img));
        if self
            .pending
            .iter()
            .all(|p| p.as_ref().is_some_and(|(t, _)| *t == bus.now))
        {
            self.process(bus.now, bus.odometry)?;
            self.next = bus.now + self.period;
        }
        Ok(())
    }

    fn finish(&mut self, _bus: &mut Bus, out: Option<&Path>) -> Result<Report> {
        let mut report = Report::default();
        if let Some(dir) = out {
            let path = dir.join(MAP_FILE);
            let mut file = futago_robot::localization::landmarks::LandmarkMap {
                landmarks: self
                    .mapper
                    .map
                    .landmarks
                    .iter()
                    .filter(|l| l.observed >= self.spec.min_observations)
                    .cloned()
                    .collect(),
            }
            .to_file();
            file.made_by = Some(self.made_by.clone());
            file.write(&path)
                .with_context(|| format!("writing {}", path.display()))?;
            report.files.push(MAP_FILE.into());
        }
        let map = &self.mapper.map;
        let seen_twice = map.landmarks.iter().filter(|l| l.observed >= 2).count();
        let mut errors: Vec<f64> = map
            .landmarks
            .iter()
            .zip(&self.first_truth)
            .filter(|(l, _)| l.observed >= 2)
            .filter_map(|(l, t)| t.map(|t| (l.position - t).length()))
            .collect();
        errors.sort_by(f64::total_cmp);
        let pct = |v: &[f64], q: f64| -> f64 {
            if v.is_empty() {
                f64::NAN
            } else {
                v[((v.len() - 1) as f64 * q).round() as usize]
            }
        };
        let (judged, false_matches) = self
            .frames
            .iter()
            .fold((0, 0), |(a, b), f| (a + f.judged, b + f.false_matches));
        let mut pos: Vec<f64> = self
            .frames
            .iter()
            .map(|f| f.step.pose.distance(&f.truth))
            .collect();
        let mut yaw: Vec<f64> = self
            .frames
            .iter()
            .map(|f| {
                futago_msgs::wrap_angle(f.step.pose.theta - f.truth.theta)
                    .abs()
                    .to_degrees()
            })
            .collect();
        pos.sort_by(f64::total_cmp);
        yaw.sort_by(f64::total_cmp);
        let n = self.frames.len().max(1) as f64;
        let mean =
            |f: &dyn Fn(&FrameRecord) -> usize| self.frames.iter().map(f).sum::<usize>() as f64 / n;
        let v = json!({
            "frames": self.frames.len(),
            "baseline_m": self.rig.baseline,
            "pose_source": self.spec.pose_source,
            "prediction": self.spec.prediction,
            "landmarks": map.landmarks.len(),
            "landmarks_seen_twice": seen_twice,
            "keypoints_per_frame": [mean(&|f| f.keypoints[0]), mean(&|f| f.keypoints[1]), mean(&|f| f.keypoints[2])],
            "points_per_frame": mean(&|f| f.step.points),
            "matched_per_frame": mean(&|f| f.step.matched),
            "added_per_frame": mean(&|f| f.step.added),
            "stereo": {
                "judged": judged,
                "false": false_matches,
                "false_rate": if judged > 0 { false_matches as f64 / judged as f64 } else { f64::NAN },
                "what": "a triangulated depth more than 3σ and 5 cm from the true depth at its pixel and every neighbour",
            },
            "landmark_error": {
                "median_m": pct(&errors, 0.5),
                "p95_m": pct(&errors, 0.95),
                "judged": errors.len(),
                "what": "landmarks seen twice or more: distance to the true point of their first keypoint",
            },
            "pose": {
                "position": { "median_m": pct(&pos, 0.5), "max_m": pct(&pos, 1.0) },
                "heading": { "median_deg": pct(&yaw, 0.5), "max_deg": pct(&yaw, 1.0) },
            },
            "last_frame_s": self.frames.last().map(|f| f.time.secs()),
        });
        report.summary.push(("visual_map".into(), v.clone()));
        self.summary = Some(v);
        report.performance.insert(
            "visual_map".into(),
            json!({
                "sift_ms_per_image": self.sift_s * 1000.0 / (3.0 * n),
                "stereo_ms_per_frame": self.stereo_s * 1000.0 / n,
                "mapping_ms_per_frame": self.mapping_s * 1000.0 / n,
            }),
        );
        Ok(report)
    }

    fn score(&self, _truth: &Truth) -> Result<Metrics> {
        let mut m = Metrics::default();
        let Some(v) = &self.summary else {
            return Ok(m);
        };
        let num = |x: &serde_json::Value| x.as_f64().unwrap_or(f64::NAN);
        m.insert("visual_map.landmarks", num(&v["landmarks"]));
        m.insert(
            "visual_map.stereo.false_rate",
            num(&v["stereo"]["false_rate"]),
        );
        m.insert(
            "visual_map.landmark_error.median_m",
            num(&v["landmark_error"]["median_m"]),
        );
        m.insert(
            "visual_map.pose.position.median_m",
            num(&v["pose"]["position"]["median_m"]),
        );
        m.insert(
            "visual_map.pose.position.max_m",
            num(&v["pose"]["position"]["max_m"]),
        );
        m.insert(
            "visual_map.pose.heading.max_deg",
            num(&v["pose"]["heading"]["max_deg"]),
        );
        Ok(m)
    }
}

/// The metrics a run with `[visual_map]` produces.
fn metric_names() -> Vec<String> {
    [
        "landmarks",
        "stereo.false_rate",
        "landmark_error.median_m",
        "pose.position.median_m",
        "pose.position.max_m",
        "pose.heading.max_deg",
    ]
    .iter()
    .map(|n| format!("visual_map.{n}"))
    .collect()
}

impl VisualMapSpec {
    /// Checks the values; errors name `visual_map.KEY`.
    pub fn validate(&self) -> Result<(), (String, String)> {
        if !(self.rate > 0.01 && self.rate <= 100.0) {
            return Err((
                "visual_map.rate".into(),
                format!("{}: expected 0.01 to 100 Hz", self.rate),
            ));
        }
        self.sift.validate("visual_map.sift")?;
        self.stereo.validate("visual_map.stereo")?;
        self.mapping.validate("visual_map.mapping")
    }
}

/// `[visual_map]`: seed 001's visual landmark map from a trinocular camera.
pub struct Module;

impl ModuleConfig for Module {
    fn key(&self) -> Option<&'static str> {
        Some("visual_map")
    }

    fn resolve(&self, cx: &Resolving<'_>, table: &toml::Value) -> Result<Spec, SpecError> {
        let key = "visual_map";
        let v: VisualMapSpec = cx.typed(key, cx.table(key, table)?)?;
        check_rig(&v.cameras, cx.spec, cx.cameras)
            .map_err(|m| cx.error("visual_map.cameras", m))?;
        v.validate().map_err(|(k, m)| cx.error(k, m))?;
        Ok(Box::new(v))
    }

    fn effective(&self, spec: &(dyn Any + Send + Sync)) -> Option<toml::Table> {
        toml::Table::try_from(spec.downcast_ref::<VisualMapSpec>()?).ok()
    }

    fn metric_names(
        &self,
        _spec: &ScenarioSpec,
        own: Option<&(dyn Any + Send + Sync)>,
    ) -> Vec<String> {
        if own.is_none() {
            return Vec::new();
        }
        metric_names()
    }
}

impl StackModule for Module {
    fn build(&self, s: &Scenario, seed: u64, _out: Option<&Path>) -> Nodes {
        boxed(node(s, seed))
    }
}
