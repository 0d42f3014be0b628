//! The RGB-D map node (seed 000 §3.1): keyframes of one named camera placed by a 2D pose
//! (the truth, odometry, or another node's `pose/…`) and the floor, each method's map built
//! after the run against the 2D map SLAM or the localiser had (`map/slam`, else
//! `map/localization`). It keeps the true surfaces its keyframes saw for scoring, writes the
//! map, its planes, its truth and its laser-height slice, and scores every method's map.
//!
//! People: while a person the stack tracks (`people/tracked`) is in the camera's view, the
//! mapper takes no keyframe (`rgbd_map.pause_for_people`, seed 000 §5.4); the points that
//! lie on tracked people are left out of the keyframes it takes (`people.exclusion`). The
//! true surfaces leave out the true people, and in a world with people the share of the map
//! that lies where they walked is scored (`rgbd_map.people_pollution`, see
//! `ground_truth::pollution`).

use super::localization::LocalizationSpec;
use super::slam::SlamSpec;
use super::{Bus, CameraFrame, FrameTruth, Node, Report, Streams, TrueState, Truth};
use super::{Nodes, StackModule, boxed};
use crate::ground_truth::Metrics;
use crate::ground_truth::pollution::{FLOOR, HEAD_ROOM, PATH_RADIUS, PeoplePaths};
use crate::scenario::{
    ModuleConfig, Resolving, Scenario, ScenarioSpec, Spec, take_name, typed_table,
};
use anyhow::{Context, Result};
use futago_msgs::camera::{DepthImage, Intrinsics};
use futago_msgs::grid::OccupancyGrid;
use futago_msgs::{Pose2, Pose3};
use futago_robot::control::PoseSource;
use futago_robot::mapping::registration::{EnvironmentMap, Method};
use futago_robot::mapping::rgbd_map::RgbdMapConfig;
use futago_robot::mapping::rgbd_map::{CameraMount, Completion, RgbdMap, RgbdMapper};
use futago_robot::tracking::exclusion::{Exclusion, ExclusionConfig};
use futago_sim::config::SpecError;
use serde::Deserialize;
use serde_json::json;
use std::any::Any;
use std::path::Path;
use std::time::Instant;

/// The RGB-D map (binary PLY, coloured points in the world frame).
pub const RGBD_MAP_FILE: &str = "rgbd_map.ply";
/// The polygon map (binary PLY mesh, a face per plane).
pub const RGBD_PLANES_FILE: &str = "rgbd_planes.ply";
/// The true surfaces its keyframes saw (binary PLY), against which it is scored.
pub const RGBD_TRUTH_FILE: &str = "rgbd_map_truth.ply";
/// The RGB-D map's laser-height slice (red) over the world's true 2D map, 1 cm a pixel.
pub const RGBD_SLICE_FILE: &str = "rgbd_slice.png";
/// Cell of the true 2D map under the slice picture, m (5 px of 1 cm each).
const SLICE_MAP_RESOLUTION: f64 = 0.05;
/// Half the height of the laser-height slice of a 3D map, m.
const SLICE_HALF_WIDTH: f64 = 0.05;
/// The slice's height without a laser, m.
const DEFAULT_SLICE_Z: f64 = 0.2;

/// The RGB-D mapper in the loop.
pub struct RgbdMapNode {
    mapper: RgbdMapper,
    camera: String,
    source: PoseSource,
    /// The methods that place the keyframes after the run, the first the run's map.
    methods: Vec<Method>,
    stride: u32,
    max_depth: f64,
    voxel: f64,
    /// Height of the laser-height slice (its laser's, if it has one).
    slice_z: f64,
    /// The world's walls at that height, at the 2D map's cell size (for scoring the slice)
    /// and at 5 cm (under the slice picture).
    walls: OccupancyGrid,
    picture: OccupancyGrid,
    truth: rustc_hash::FxHashMap<[i64; 3], [f64; 3]>,
    /// Truth voxels in the order first seen (deterministic output).
    order: Vec<[i64; 3]>,
    truth_poses: Vec<Pose2>,
    offer_seconds: f64,
    maps: Vec<RgbdMap>,
    scenario: String,
    exclusion: ExclusionConfig,
    pause_for_people: bool,
    /// The camera's place and heading in the base frame, its horizontal half field of view
    /// (rad) and its range (m): where a person is in view.
    view: (Pose2, f64, f64),
    /// Frames the mapper wanted but put off for a person in view.
    paused_frames: std::cell::Cell<u64>,
    /// Where the world's people walked (truth, for scoring); `None` in a world without.
    paths: Option<PeoplePaths>,
}

/// The mapper when the scenario has `[rgbd_map]`.
pub fn node(s: &Scenario, seed: u64) -> Result<Option<RgbdMapNode>> {
    let Some(m) = s.module::<RgbdMapSpec>() else {
        return Ok(None);
    };
    let cam = s
        .cameras
        .iter()
        .find(|c| c.name == m.camera)
        .with_context(|| format!("rgbd_map: no camera is named `{}`", m.camera))?;
    // The camera's place on the robot: x, y and yaw of its mount (height, pitch and roll come
    // from the floor in each frame).
    let mount = super::camera_on_base(cam);
    let slice_z = match &m.laser {
        Some(n) => s
            .lidars
            .iter()
            .find(|(c, _)| &c.name == n)
            .map_or(DEFAULT_SLICE_Z, |(c, _)| c.xyz[2]),
        None => DEFAULT_SLICE_Z,
    };
    // The true walls the slice is scored against, at the 2D map's cell size.
    let resolution = s
        .module::<SlamSpec>()
        .map_or(SLICE_MAP_RESOLUTION, |l| l.config.grid.resolution);
    let picture = super::world_map(s, SLICE_MAP_RESOLUTION, slice_z)?;
    let walls = if resolution == SLICE_MAP_RESOLUTION {
        picture.clone()
    } else {
        super::world_map(s, resolution, slice_z)?
    };
    Ok(Some(RgbdMapNode {
        mapper: RgbdMapper::new(
            m.config.clone(),
            CameraMount {
                x: mount.x,
                y: mount.y,
                yaw: mount.theta,
            },
            seed,
        ),
        camera: m.camera.clone(),
        source: m.pose_source,
        methods: m.config.methods.clone(),
        stride: m.config.stride,
        max_depth: m.config.max_depth,
        voxel: m.config.voxel,
        slice_z,
        walls,
        picture,
        truth: Default::default(),
        order: Vec::new(),
        truth_poses: Vec::new(),
        offer_seconds: 0.0,
        maps: Vec::new(),
        scenario: s.spec.name.clone(),
        exclusion: s.spec.people.exclusion,
        pause_for_people: m.config.pause_for_people,
        view: (
            mount,
            (cam.depth.width as f64 / (2.0 * cam.depth.fx)).atan(),
            m.config.max_depth.min(cam.range_max),
        ),
        paused_frames: std::cell::Cell::new(0),
        paths: s.spec.has_people().then(PeoplePaths::default),
    }))
}

/// The RGB-D map's metrics besides the cloud scores: distances to the true surfaces, the
/// laser-height slice against the true walls, the keyframes' placing against their true poses
/// and the planes against the true surfaces.
pub const RGBD_MAP_KEYS: [&str; 12] = [
    "mean_distance_m",
    "median_distance_m",
    "slice_rms_m",
    "slice_median_m",
    "slice_thickness_m",
    "keyframe_pose.rmse_m",
    "keyframe_pose.max_m",
    "keyframe_pose.rmse_deg",
    "planes.angle_mean_deg",
    "planes.offset_mean_m",
    "planes.faces",
    "planes.vertices",
];

/// `rgbd_map.*` for the first method and `rgbd_map.METHOD.*` for each.
fn metric_names(s: &ScenarioSpec, spec: &RgbdMapSpec) -> Vec<String> {
    let methods: Vec<&'static str> = spec.config.methods.iter().map(|m| m.name()).collect();
    let mut names = Vec::new();
    if s.has_people() {
        names.push("rgbd_map.people_pollution".into());
    }
    let prefixes = std::iter::once("rgbd_map".to_string())
        .chain(methods.iter().map(|m| format!("rgbd_map.{m}")));
    for prefix in prefixes {
        for t in crate::ground_truth::cloud::TOLERANCE_NAMES {
            for k in ["accuracy", "completeness", "f1"] {
                names.push(format!("{prefix}.{k}_{t}"));
            }
        }
        for k in RGBD_MAP_KEYS {
            names.push(format!("{prefix}.{k}"));
        }
    }
    names
}

impl RgbdMapNode {
    /// The 2D pose that places a keyframe now.
    fn map_pose(&self, bus: &Bus) -> Pose2 {
        bus.pose_from(self.source)
    }

    /// The tracked people now, as the exclusion cuts them out.
    fn people(&self, bus: &Bus) -> Exclusion {
        Exclusion::new(&self.exclusion, bus.people_now())
    }

    /// Whether a tracked person is in the camera's view now.
    fn person_in_view(&self, bus: &Bus) -> bool {
        let seen = ExclusionConfig {
            enabled: true,
            ..self.exclusion
        };
        let (camera, half_fov, range) = self.view;
        Exclusion::new(&seen, bus.people_now()).in_view(&camera, half_fov, range)
    }

    /// Adds a noiseless depth image taken from `optical` (the optical frame's world pose) to
    /// the true surfaces, less the people in the world (`people`, their true positions): the
    /// map is scored against the building.
    fn add_truth(
        &mut self,
        depth: &DepthImage,
        k: &Intrinsics,
        optical: &Pose3,
        people: &[[f64; 2]],
    ) {
        for v in (0..depth.height).step_by(self.stride as usize) {
            for u in (0..depth.width).step_by(self.stride as usize) {
                let z = depth.at(u, v) as f64;
                if !(z.is_finite() && z > 0.0 && z <= self.max_depth) {
                    continue;
                }
                let w = optical.transform_point(k.back_project(u as f64, v as f64, z));
                let on_person = w[2] > FLOOR
                    && w[2] <= HEAD_ROOM
                    && people
                        .iter()
                        .any(|p| (w[0] - p[0]).hypot(w[1] - p[1]) <= PATH_RADIUS);
                if on_person {
                    continue;
                }
                let key = w.map(|x| (x / self.voxel).floor() as i64);
                if let std::collections::hash_map::Entry::Vacant(e) = self.truth.entry(key) {
                    e.insert(w);
                    self.order.push(key);
                }
            }
        }
    }

    fn truth_points(&self) -> Vec<[f64; 3]> {
        self.order.iter().map(|k| self.truth[k]).collect()
    }
}

impl Node for RgbdMapNode {
    fn name(&self) -> &'static str {
        "rgbd_map"
    }

    fn streams(&self) -> Streams {
        let mut consumes = vec![format!("camera/{}", self.camera)];
        consumes.extend(super::bus::pose_topic(self.source));
        if self.exclusion.enabled || self.pause_for_people {
            consumes.push("people/tracked".into());
        }
        if self.paths.is_some() {
            consumes.push("truth".into());
        }
        Streams {
            consumes,
            ..Streams::default()
        }
    }

    fn on_truth(&mut self, truth: &TrueState, _bus: &mut Bus) -> Result<()> {
        if let Some(p) = &mut self.paths {
            p.add(&truth.people);
        }
        Ok(())
    }

    fn colour_on_demand(&self, _camera: &str) -> bool {
        true
    }

    /// Finding the floor reads every `stride`-th pixel; a keyframe's features read anywhere,
    /// through [`FrameTruth::full_depth`].
    fn depth_stride(&self, camera: &str) -> u32 {
        if camera == self.camera {
            self.stride
        } else {
            1
        }
    }

    fn full_depth_on_demand(&self, camera: &str) -> bool {
        camera == self.camera
    }

    fn wants_frame(&self, camera: &str, bus: &Bus) -> bool {
        if camera != self.camera || !self.mapper.wants(&self.map_pose(bus)) {
            return false;
        }
        if self.pause_for_people && self.person_in_view(bus) {
            self.paused_frames.set(self.paused_frames.get() + 1);
            return false;
        }
        true
    }

    fn on_frame(
        &mut self,
        camera: &str,
        frame: &CameraFrame,
        truth: &mut dyn FrameTruth,
        bus: &mut Bus,
    ) -> Result<()> {
        if camera != self.camera {
            return Ok(());
        }
        let pose = self.map_pose(bus);
        let t0 = Instant::now();
        // The colour is rendered, and the depth noised whole, only for the frames that
        // become keyframes (their time is the rendering's, not the keyframe's).
        let (mut failed, mut rendering) = (None, 0.0);
        let complete = || {
            let t1 = Instant::now();
            // What the frame holds is not asked for again.
            let got = (|| -> Result<Completion> {
                Ok(Completion {
                    rgb: match frame.frame.rgb {
                        Some(_) => None,
                        None => Some(truth.colour()?),
                    },
                    depth: truth.full_depth()?,
                })
            })();
            rendering = t1.elapsed().as_secs_f64();
            got.map_err(|e| failed = Some(e)).unwrap_or_default()
        };
        let people = self.people(bus);
        let taken = self
            .mapper
            .offer_completing(&frame.frame, &pose, &people, complete);
        if let Some(e) = failed {
            return Err(e.context("completing a keyframe's colour and depth"));
        }
        self.offer_seconds += t0.elapsed().as_secs_f64() - rendering;
        if taken {
            let depth = truth.true_depth()?;
            let state = truth.state();
            let people: Vec<[f64; 2]> = state.people.iter().map(|p| [p.pose.x, p.pose.y]).collect();
            self.add_truth(
                &depth,
                &frame.frame.depth_intrinsics,
                &truth.optical(),
                &people,
            );
            self.truth_poses.push(state.robot);
        }
        Ok(())
    }

    fn finish(&mut self, bus: &mut Bus, out: Option<&Path>) -> Result<Report> {
        // The 2D map for the map term: SLAM's final map, else the map the localiser was given.
        let grid = bus
            .map("slam")
            .or_else(|| bus.map("localization"))
            .map(|(_, g)| g.clone());
        let env = grid
            .as_ref()
            .map(|g| EnvironmentMap::new(g, self.slice_z, futago_robot::geometry::grid::OCCUPIED));
        // Each method's map built on whichever core is free: each depends on the keyframes
        // and its method alone (34 s one after another in `office-rgbd-methods`).
        let built = futago_robot::cores::map_each_on_cores(&self.methods, |method| {
            let t0 = Instant::now();
            let map = self.mapper.build(*method, env.as_ref());
            (map, t0.elapsed().as_secs_f64())
        });
        let mut build_seconds = serde_json::Map::new();
        let mut maps: Vec<RgbdMap> = Vec::with_capacity(built.len());
        for (map, seconds) in built {
            build_seconds.insert(format!("build_{}_s", map.method.name()), json!(seconds));
            maps.push(map);
        }
        let mut counts = serde_json::to_value(self.mapper.counts()).unwrap_or_default();
        counts["environment_map_points"] = json!(env.as_ref().map_or(0, |e| e.len()));
        for map in &maps {
            let (faces, vertices) = map.polygons.size();
            let mut c = serde_json::to_value(map.registration).unwrap_or_default();
            c["planes_found"] = json!(map.polygons.found);
            c["plane_faces"] = json!(faces);
            c["plane_vertices"] = json!(vertices);
            c["map_points"] = json!(map.points.len());
            counts[map.method.name()] = c;
        }
        // The run's map (the first method's) at the top level too.
        if let Some(first) = maps.first() {
            for k in [
                "map_points",
                "planes_found",
                "plane_faces",
                "plane_vertices",
            ] {
                counts[k] = counts[first.method.name()][k].clone();
            }
        }
        let truth = self.truth_points();
        counts["truth_points"] = json!(truth.len());
        counts["paused_frames"] = json!(self.paused_frames.get());
        let (mut files, mut pictures) = (Vec::new(), Vec::new());
        if let (Some(dir), Some(first)) = (out, maps.first()) {
            let name = &self.scenario;
            let comment = format!(
                "futago RGB-D map of {name} placed by {} (world frame, m)",
                first.method.name()
            );
            std::fs::write(
                dir.join(RGBD_MAP_FILE),
                futago_msgs::ply::points(&first.points, &comment),
            )
            .with_context(|| format!("writing {RGBD_MAP_FILE}"))?;
            let coloured: Vec<([f64; 3], [u8; 3])> =
                truth.iter().map(|p| (*p, [26, 150, 65])).collect();
            let comment =
                format!("futago: the true surfaces the RGB-D map's keyframes saw, {name}");
            std::fs::write(
                dir.join(RGBD_TRUTH_FILE),
                futago_msgs::ply::points(&coloured, &comment),
            )
            .with_context(|| format!("writing {RGBD_TRUTH_FILE}"))?;
            let planes = first.polygons.to_ply(&format!(
                "futago polygon map of {name} placed by {} (world frame, m)",
                first.method.name()
            ));
            std::fs::write(dir.join(RGBD_PLANES_FILE), planes)
                .with_context(|| format!("writing {RGBD_PLANES_FILE}"))?;
            let slice: Vec<[f64; 2]> = first
                .points
                .iter()
                .filter(|p| (p.0[2] - self.slice_z).abs() <= SLICE_HALF_WIDTH)
                .map(|p| [p.0[0], p.0[1]])
                .collect();
            let png = crate::picture::points_over_map_png(&self.picture, &slice, 5);
            std::fs::write(dir.join(RGBD_SLICE_FILE), &png)
                .with_context(|| format!("writing {RGBD_SLICE_FILE}"))?;
            pictures.push((RGBD_SLICE_FILE.to_string(), png));
            files.extend(
                [
                    RGBD_MAP_FILE,
                    RGBD_TRUTH_FILE,
                    RGBD_PLANES_FILE,
                    RGBD_SLICE_FILE,
                ]
                .map(String::from),
            );
        }
        self.maps = maps;
        let mut performance = build_seconds;
        performance.insert("keyframe_s".into(), json!(self.offer_seconds));
        performance.insert("keyframes".into(), json!(self.truth_poses.len()));
        performance.insert("points".into(), counts["points"].clone());
        Ok(Report {
            summary: vec![("rgbd_map".into(), counts)],
            files,
            pictures,
            performance,
            ..Report::default()
        })
    }

    fn score(&self, truth: &Truth) -> Result<Metrics> {
        let mut metrics = Metrics::default();
        if let (Some(paths), Some(map)) = (&self.paths, self.maps.first()) {
            // Every static obstacle between the floor and the people's heads.
            let world = futago_sim::world::export::occupancy_grid(
                &truth.scenario.world,
                SLICE_MAP_RESOLUTION,
                FLOOR,
                HEAD_ROOM,
                0.5,
            )
            .map_err(|e| anyhow::anyhow!("{e}"))?;
            let points: Vec<[f64; 3]> = map.points.iter().map(|p| p.0).collect();
            metrics.insert(
                "rgbd_map.people_pollution",
                paths.cloud_share(&points, &world).unwrap_or(0.0),
            );
        }
        // The true surfaces indexed once for every method's map.
        let points = self.truth_points();
        let truth = crate::ground_truth::cloud::CloudIndex::new(&points);
        for (k, map) in self.maps.iter().enumerate() {
            let found = score_map(
                map,
                &points,
                &truth,
                &self.truth_poses,
                &self.walls,
                self.slice_z,
            );
            if k == 0 {
                for (name, v) in &found {
                    metrics.insert(format!("rgbd_map.{name}"), *v);
                }
            }
            for (name, v) in found {
                metrics.insert(format!("rgbd_map.{}.{name}", map.method.name()), v);
            }
        }
        Ok(metrics)
    }
}

/// One RGB-D map's scores (metric names below `rgbd_map.`): the cloud against the true
/// surfaces (`truth`, and `index` of them), the laser-height slice against the true walls (seed 000 judged its methods by how
/// thin and true this trace was), the keyframes' poses against the truth and the planes
/// against the true surfaces.
fn score_map(
    map: &RgbdMap,
    truth: &[[f64; 3]],
    index: &crate::ground_truth::cloud::CloudIndex,
    truth_poses: &[Pose2],
    walls: &OccupancyGrid,
    z: f64,
) -> Vec<(String, f64)> {
    let mut out = Vec::new();
    let points: Vec<[f64; 3]> = map.points.iter().map(|p| p.0).collect();
    if let Some(score) = crate::ground_truth::cloud::score(&points, index) {
        out.extend(score.named());
    }
    let band: Vec<[f64; 3]> = points
        .iter()
        .filter(|p| (p[2] - z).abs() <= SLICE_HALF_WIDTH)
        .copied()
        .collect();
    if let Some(t) = crate::ground_truth::cloud::thickness(&band, index) {
        out.push(("slice_thickness_m".into(), t));
    }
    let slice: Vec<[f64; 2]> = band.iter().map(|p| [p[0], p[1]]).collect();
    if !slice.is_empty() {
        let mut d = crate::ground_truth::map::wall_distances(walls, &slice);
        let rms = (d.iter().map(|x| x * x).sum::<f64>() / d.len() as f64).sqrt();
        d.sort_by(f64::total_cmp);
        out.push(("slice_rms_m".into(), rms));
        out.push(("slice_median_m".into(), d[d.len() / 2]));
    }
    let errors: Vec<(f64, f64)> = map
        .poses
        .iter()
        .zip(truth_poses)
        .map(|(p, t)| {
            (
                p.distance(t),
                futago_msgs::wrap_angle(p.theta - t.theta).to_degrees(),
            )
        })
        .collect();
    if !errors.is_empty() {
        let n = errors.len() as f64;
        let rms = |f: fn(&(f64, f64)) -> f64| {
            (errors.iter().map(|e| f(e).powi(2)).sum::<f64>() / n).sqrt()
        };
        out.push(("keyframe_pose.rmse_m".into(), rms(|e| e.0)));
        out.push((
            "keyframe_pose.max_m".into(),
            errors.iter().map(|e| e.0).fold(0.0, f64::max),
        ));
        out.push(("keyframe_pose.rmse_deg".into(), rms(|e| e.1)));
    }
    if let Some(p) = crate::ground_truth::planes::score(&map.polygons.polygons, truth) {
        out.push(("planes.angle_mean_deg".into(), p.angle_mean_deg));
        out.push(("planes.offset_mean_m".into(), p.offset_mean_m));
    }
    let (faces, vertices) = map.polygons.size();
    out.push(("planes.faces".into(), faces as f64));
    out.push(("planes.vertices".into(), vertices as f64));
    out
}

/// `[rgbd_map]`: `pose_source`, `camera` (its frames), `laser` (the height of its 2D-map
/// term and slice) and the mapper's own keys ([`RgbdMapConfig`]).
#[derive(Debug, Clone, PartialEq)]
pub struct RgbdMapSpec {
    pub pose_source: PoseSource,
    /// The camera's name (resolved: the only camera when the table names none).
    pub camera: String,
    /// The laser's name, if any.
    pub laser: Option<String>,
    pub config: RgbdMapConfig,
}

/// Types the `[rgbd_map]` table: `pose_source` (default `slam`) and the mapper's keys, naming
/// `rgbd_map.KEY` in errors.
pub fn rgbd_map_config(path: &Path, table: &toml::Table) -> Result<RgbdMapSpec, SpecError> {
    let mut rest = table.clone();
    let camera = take_name(path, "rgbd_map", "camera", &mut rest)?.unwrap_or_default();
    let laser = take_name(path, "rgbd_map", "laser", &mut rest)?;
    let pose_source = match rest.remove("pose_source") {
        None => PoseSource::Slam,
        Some(v) => PoseSource::deserialize(v.clone()).map_err(|_| {
            SpecError::new(
                path,
                "rgbd_map.pose_source",
                format!(
                    "expected one of \"ground_truth\", \"odometry\", \"localization\", \"slam\"; found {v}"
                ),
            )
        })?,
    };
    let config: RgbdMapConfig = typed_table(path, "rgbd_map", rest)?;
    config
        .validate()
        .map_err(|(k, m)| SpecError::new(path, format!("rgbd_map.{k}"), m))?;
    Ok(RgbdMapSpec {
        pose_source,
        camera,
        laser,
        config,
    })
}

/// `[rgbd_map]`: a 3D map from a camera's RGB-D keyframes, placed by a 2D pose and the floor.
pub struct Module;

impl ModuleConfig for Module {
    fn key(&self) -> Option<&'static str> {
        Some("rgbd_map")
    }

    fn resolve(&self, cx: &Resolving<'_>, table: &toml::Value) -> Result<Spec, SpecError> {
        let path = cx.path;
        let mut m = rgbd_map_config(path, &cx.table("rgbd_map", table)?)?;
        if cx.cameras.is_empty() {
            return Err(SpecError::new(
                path,
                "rgbd_map",
                "an RGB-D map needs a [[camera]]; the scenario has none",
            ));
        }
        let named = (!m.camera.is_empty()).then_some(m.camera.as_str());
        m.camera = cx.camera("rgbd_map", named)?.name.clone();
        // The laser of its slice and 2D-map term: the one named, else SLAM's, else the
        // localiser's, else the only one.
        m.laser = match &m.laser {
            Some(_) => Some(cx.laser("rgbd_map", &m.laser)?),
            None => cx
                .earlier
                .get::<SlamSpec>()
                .and_then(|s| s.laser.clone())
                .or_else(|| {
                    cx.earlier
                        .get::<LocalizationSpec>()
                        .and_then(|l| l.laser.clone())
                })
                .or_else(|| (cx.lidars.len() == 1).then(|| cx.lidars[0].0.name.clone())),
        };
        cx.require_pose("rgbd_map.pose_source", m.pose_source, "this pose source")?;

        Ok(Box::new(m))
    }

    fn effective(&self, spec: &(dyn Any + Send + Sync)) -> Option<toml::Table> {
        let r = spec.downcast_ref::<RgbdMapSpec>()?;
        let mut m = toml::Table::try_from(&r.config).unwrap_or_default();
        m.extend(
            r.laser
                .clone()
                .map(|v| ("laser".to_string(), toml::Value::String(v))),
        );
        m.insert("camera".into(), toml::Value::String(r.camera.clone()));
        if let Ok(v) = toml::Value::try_from(r.pose_source) {
            m.insert("pose_source".into(), v);
        }
        Some(m)
    }

    fn metric_names(
        &self,
        spec: &ScenarioSpec,
        own: Option<&(dyn Any + Send + Sync)>,
    ) -> Vec<String> {
        super::own::<RgbdMapSpec>(own)
            .map(|m| metric_names(spec, m))
            .unwrap_or_default()
    }
}

impl StackModule for Module {
    fn build(&self, s: &Scenario, seed: u64, _out: Option<&Path>) -> Nodes {
        boxed(node(s, seed))
    }
}
