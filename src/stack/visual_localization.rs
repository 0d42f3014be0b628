//! Seed 001's monocular localisation as a node: one camera localised in a landmark map that a
//! mapping pass wrote (`[visual_map]`'s `landmarks.json`), frame by frame from its last
//! estimate, with no odometry.
//!
//! Every frame's SIFT keypoints are localised by four localisers side by side, each from its
//! own last estimate:
//! - `all`: every landmark in view projected and matched, the seed's exhaustive search;
//! - `delegates`: the seed's delegate landmarks only (its contribution);
//! - `summary`: every landmark in view of a summary map that keeps the third of the
//!   landmarks seen most often (a modern map compression), the seed's search;
//! - `pnp`: the `all` matches, posed by RANSAC (the modern baseline).
//!
//! The estimate of `drive` (the delegates by default) is published on `pose/localization`,
//! held as it is between frames (not carried by odometry), for a controller to drive on.
//!
//! Scores per localiser, against the camera's true pose at each frame (the seed's Table 1):
//! the x and y errors (mm) and the heading error (°), mean and standard deviation; the share
//! of frames within 5 cm and 5°; landmarks in view, projected and matched per frame; the
//! descriptor comparisons of matching per frame. Wall times (matching, the whole frame) go to
//! `performance`: speed is a benchmark's figure, not a score; the speed-up the seed reports is
//! gated by the comparisons that matching makes, which are what its time is spent on.

use super::{Bus, CameraFrame, FrameTruth, Node, Report, Streams, Trajectory, Truth};
use super::{Nodes, StackModule, boxed};
use crate::ground_truth::Metrics;
use crate::scenario::{ModuleConfig, Resolving, Scenario, ScenarioSpec, Spec};
use anyhow::{Context, Result};
use futago_msgs::landmarks::LandmarkFile;
use futago_msgs::{Duration, Pose2, Time};
use futago_robot::localization::landmarks::{
    Camera, Estimate, Frame, LandmarkMap, MonocularConfig, Selection, Solver, localise,
};
use futago_robot::perception::features::grey;
use futago_robot::perception::sift::{self, SiftConfig};
use futago_sim::config::SpecError;
use serde::{Deserialize, Serialize};
use serde_json::json;
use std::any::Any;
use std::path::{Path, PathBuf};

/// The driven estimate of the robot's pose, one TUM line a frame.
pub const TRAJECTORY_FILE: &str = "visual_localization.txt";

/// The localisers run side by side.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Localiser {
    All,
    #[default]
    Delegates,
    Summary,
    Pnp,
}

const LOCALISERS: [Localiser; 4] = [
    Localiser::All,
    Localiser::Delegates,
    Localiser::Summary,
    Localiser::Pnp,
];

impl Localiser {
    fn name(self) -> &'static str {
        match self {
            Localiser::All => "all",
            Localiser::Delegates => "delegates",
            Localiser::Summary => "summary",
            Localiser::Pnp => "pnp",
        }
    }
}

/// `[visual_localization]`: seed 001's monocular localiser.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VisualLocalizationSpec {
    /// The camera it localises (by name; may be left out when the scenario has one).
    #[serde(default)]
    pub camera: Option<String>,
    /// The landmark map (a `landmarks.json`), relative to the scenario.
    pub map: PathBuf,
    /// Frames taken per second.
    #[serde(default = "default_rate")]
    pub rate: f64,
    /// Landmarks seen fewer times than this in the mapping pass are left out (the seed's map
    /// figure shows those seen twice or more).
    #[serde(default = "default_min_observations")]
    pub min_observations: u32,
    /// The share of landmarks the summary map keeps.
    #[serde(default = "default_keep")]
    pub summary_keep: f64,
    /// The localiser whose estimate is published for the controller.
    #[serde(default)]
    pub drive: Localiser,
    /// The route the mapping pass drove, `[[x, y], …]` (m): the robot's true path is scored
    /// against it (`path_error`), as the seed's online run followed the mapping route.
    #[serde(default)]
    pub route: Vec<[f64; 2]>,
    #[serde(default)]
    pub sift: SiftConfig,
    #[serde(default)]
    pub monocular: MonocularConfig,
}

fn default_rate() -> f64 {
    5.0
}
fn default_min_observations() -> u32 {
    2
}
fn default_keep() -> f64 {
    1.0 / 3.0
}

impl VisualLocalizationSpec {
    /// Checks the values; errors name `visual_localization.KEY`.
    pub fn validate(&self) -> Result<(), (String, String)> {
        let k = |s: &str| format!("visual_localization.{s}");
        if !(self.rate > 0.01 && self.rate <= 100.0) {
            return Err((k("rate"), format!("{}: expected 0.01 to 100 Hz", self.rate)));
        }
        if !(self.summary_keep > 0.0 && self.summary_keep <= 1.0) {
            return Err((
                k("summary_keep"),
                format!("{}: expected a share in (0, 1]", self.summary_keep),
            ));
        }
        if self.route.len() == 1 || self.route.iter().flatten().any(|v| !v.is_finite()) {
            return Err((
                k("route"),
                "expected at least two finite points [x, y], m".into(),
            ));
        }
        self.sift.validate(&k("sift"))?;
        self.monocular.validate(&k("monocular"))
    }
}

/// The localiser node.
pub struct VisualLocalizationNode {
    spec: VisualLocalizationSpec,
    camera_name: String,
    camera: Camera,
    /// The camera's body frame on the base, planar.
    mount: Pose2,
    map: LandmarkMap,
    summary_map: LandmarkMap,
    period: Duration,
    next: Time,
    poses: Option<[Pose2; 4]>,
    truths: Vec<(Time, Pose2)>,
    /// The robot base's true position at each frame.
    bases: Vec<[f64; 2]>,
    /// The driven estimate of the robot's pose, TUM lines.
    track: Trajectory,
    /// Each frame's estimates, in [`LOCALISERS`] order.
    records: Vec<[Estimate; 4]>,
    sift_s: f64,
    /// The detector's memory, kept from frame to frame.
    sift_buffers: sift::SiftBuffers,
    bumps: u64,
    bumped: bool,
    summary: Option<serde_json::Value>,
}

/// The map file of a spec, resolved against the scenario's folder.
pub fn map_path(scenario: &Path, spec: &VisualLocalizationSpec) -> PathBuf {
    scenario.parent().unwrap_or(Path::new(".")).join(&spec.map)
}

/// The node when the scenario has `[visual_localization]`.
pub fn node(s: &Scenario) -> Result<Option<VisualLocalizationNode>> {
    let Some(spec) = s.module::<VisualLocalizationSpec>() else {
        return Ok(None);
    };
    let name = spec.camera.clone().unwrap_or_default();
    let cam = s
        .cameras
        .iter()
        .find(|c| c.name == name)
        .with_context(|| format!("visual_localization.camera: no camera `{name}`"))?;
    // Resolved at load (relative to the scenario).
    let file = LandmarkFile::read(&spec.map).map_err(|e| anyhow::anyhow!("{e}"))?;
    let mut map = LandmarkMap::from_file(&file)
        .map_err(|e| anyhow::anyhow!("{}: {e}", spec.map.display()))?;
    map.landmarks
        .retain(|l| l.observed >= spec.min_observations);
    let summary_map = map.summarised(spec.summary_keep);
    Ok(Some(VisualLocalizationNode {
        spec: spec.clone(),
        camera_name: name,
        camera: Camera {
            intrinsics: cam.rgb,
            height: cam.mount.translation.z as f64,
        },
        mount: super::camera_on_base(cam),
        map,
        summary_map,
        period: Duration::from_secs(1.0 / spec.rate),
        next: Time::ZERO,
        poses: None,
        truths: Vec::new(),
        bases: Vec::new(),
        track: Trajectory::new("visual localisation"),
        records: Vec::new(),
        sift_s: 0.0,
        sift_buffers: Default::default(),
        bumps: 0,
        bumped: false,
        summary: None,
    }))
}

fn mean_sd(v: &[f64]) -> (f64, f64) {
    if v.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    (
        m,
        (v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / n).sqrt(),
    )
}

impl Node for VisualLocalizationNode {
    fn name(&self) -> &'static str {
        "visual_localization"
    }

    fn streams(&self) -> Streams {
        Streams {
            consumes: vec![format!("camera/{}", self.camera_name)],
            publishes: vec!["pose/localization".into()],
            periods: Vec::new(),
        }
    }

    fn wants_frame(&self, camera: &str, bus: &Bus) -> bool {
        camera == self.camera_name && bus.now >= self.next
    }

    fn on_control(&mut self, bus: &mut Bus) -> Result<()> {
        let b = bus.bumps.bumped();
        if b && !self.bumped {
            self.bumps += 1;
        }
        self.bumped = b;
        Ok(())
    }

    fn on_frame(
        &mut self,
        _camera: &str,
        frame: &CameraFrame,
        truth_view: &mut dyn FrameTruth,
        bus: &mut Bus,
    ) -> Result<()> {
        let Some(rgb) = &frame.frame.rgb else {
            return Ok(());
        };
        self.next = bus.now + self.period;
        let truth = super::visual_map::planar_of_optical(&truth_view.optical());
        let t0 = std::time::Instant::now();
        let keypoints = sift::detect_with(
            &grey(rgb.width, rgb.height, &rgb.data),
            &self.spec.sift,
            &mut self.sift_buffers,
        );
        self.sift_s += t0.elapsed().as_secs_f64();
        let k = &self.camera.intrinsics;
        let f = Frame::new(keypoints, k.width, k.height);
        // The seed starts from a pose "roughly given": the true one at the first frame.
        let priors = *self.poses.get_or_insert([truth; 4]);
        let c = &self.spec.monocular;
        let run = |l: Localiser, prior: &Pose2| -> Estimate {
            match l {
                Localiser::All => localise(
                    &self.map,
                    &self.camera,
                    &f,
                    prior,
                    c,
                    Selection::All,
                    Solver::Search,
                ),
                Localiser::Delegates => localise(
                    &self.map,
                    &self.camera,
                    &f,
                    prior,
                    c,
                    Selection::Delegates,
                    Solver::Search,
                ),
                Localiser::Summary => localise(
                    &self.summary_map,
                    &self.camera,
                    &f,
                    prior,
                    c,
                    Selection::All,
                    Solver::Search,
                ),
                Localiser::Pnp => localise(
                    &self.map,
                    &self.camera,
                    &f,
                    prior,
                    c,
                    Selection::All,
                    Solver::PnpRansac {
                        seed: self.records.len() as u64,
                    },
                ),
            }
        };
        // The four localisers are independent: each on a core where there are several, each
        // estimate the same whichever thread makes it.
        let order: [usize; 4] = std::array::from_fn(|i| i);
        let made =
            futago_robot::cores::map_on_cores(&order, 2, |&i| run(LOCALISERS[i], &priors[i]));
        let Ok(estimates) = <[Estimate; 4]>::try_from(made) else {
            anyhow::bail!("visual localisation: not one estimate for each of the four localisers");
        };
        let poses = std::array::from_fn(|i| estimates[i].pose);
        self.poses = Some(poses);
        let drive = LOCALISERS
            .iter()
            .position(|l| *l == self.spec.drive)
            .unwrap_or(1);
        // The robot's pose under the camera.
        let robot = poses[drive].compose(&self.mount.inverse());
        bus.publish_pose_held("localization", robot);
        self.track.push(bus.now, &robot);
        self.truths.push((bus.now, truth));
        let robot = truth_view.state().robot;
        self.bases.push([robot.x, robot.y]);
        self.records.push(estimates);
        Ok(())
    }

    fn finish(&mut self, _bus: &mut Bus, out: Option<&Path>) -> Result<Report> {
        let mut report = Report::default();
        if let Some(dir) = out {
            self.track.write(dir, TRAJECTORY_FILE, "")?;
            report.files.push(TRAJECTORY_FILE.into());
        }
        report.trajectories.push(self.track.clone());
        let n = self.records.len().max(1) as f64;
        let mut v = json!({
            "frames": self.records.len(),
            "map": self.spec.map.display().to_string(),
            "landmarks": self.map.landmarks.len(),
            "summary_landmarks": self.summary_map.landmarks.len(),
            "drive": self.spec.drive,
            "bumps": self.bumps,
        });
        if self.spec.route.len() >= 2 {
            let d: Vec<f64> = self
                .bases
                .iter()
                .map(|p| super::depth_localization::distance_to_path(*p, &self.spec.route))
                .collect();
            let (mean, _) = mean_sd(&d);
            v["path_error"] = json!({
                "mean_m": mean,
                "max_m": d.iter().copied().fold(f64::NAN, f64::max),
                "what": "the robot's true position at each frame: its distance to the mapping route",
            });
        }
        let mut perf = serde_json::Map::new();
        perf.insert("frames".into(), json!(self.records.len()));
        perf.insert("sift_ms_per_frame".into(), json!(self.sift_s * 1000.0 / n));
        for (i, l) in LOCALISERS.iter().enumerate() {
            let mut ex = Vec::new();
            let mut ey = Vec::new();
            let mut eh = Vec::new();
            let mut within = 0usize;
            for (r, (_, t)) in self.records.iter().zip(&self.truths) {
                let p = r[i].pose;
                let (dx, dy) = ((p.x - t.x).abs(), (p.y - t.y).abs());
                let dh = futago_msgs::wrap_angle(p.theta - t.theta)
                    .abs()
                    .to_degrees();
                ex.push(dx * 1000.0);
                ey.push(dy * 1000.0);
                eh.push(dh);
                within += (dx.hypot(dy) <= 0.05 && dh <= 5.0) as usize;
            }
            let per = |f: &dyn Fn(&Estimate) -> f64| -> Vec<f64> {
                self.records.iter().map(|r| f(&r[i])).collect()
            };
            let (mx, sx) = mean_sd(&ex);
            let (my, sy) = mean_sd(&ey);
            let (mh, sh) = mean_sd(&eh);
            let (pm, ps) = mean_sd(&per(&|e| e.projected as f64));
            let (mm, ms) = mean_sd(&per(&|e| e.matched as f64));
            let (vm, _) = mean_sd(&per(&|e| e.in_view as f64));
            let (cm, cs) = mean_sd(&per(&|e| e.comparisons as f64));
            v[l.name()] = json!({
                "x_error_mm": { "mean": mx, "sd": sx },
                "y_error_mm": { "mean": my, "sd": sy },
                "heading_error_deg": { "mean": mh, "sd": sh },
                "within_5cm_5deg": within as f64 / n,
                "in_view": vm,
                "projected": { "mean": pm, "sd": ps },
                "matched": { "mean": mm, "sd": ms },
                "comparisons": { "mean": cm, "sd": cs },
            });
            let (tm, tsd) = mean_sd(&per(&|e| e.match_s * 1000.0));
            let (sm, _) = mean_sd(&per(&|e| e.select_s * 1000.0));
            let (qm, _) = mean_sd(&per(&|e| e.search_s * 1000.0));
            perf.insert(
                l.name().into(),
                json!({
                    "matching_ms": { "mean": tm, "sd": tsd },
                    "selection_ms": sm,
                    "search_ms": qm,
                }),
            );
        }
        let all = perf["all"]["matching_ms"]["mean"]
            .as_f64()
            .unwrap_or(f64::NAN);
        let del = perf["delegates"]["matching_ms"]["mean"]
            .as_f64()
            .unwrap_or(f64::NAN);
        perf.insert("matching_speedup".into(), json!(all / del));
        report
            .summary
            .push(("visual_localization".into(), v.clone()));
        report.performance = perf;
        self.summary = Some(v);
        Ok(report)
    }

    fn score(&self, _truth: &Truth) -> Result<Metrics> {
        let mut m = Metrics::default();
        let Some(v) = &self.summary else {
            return Ok(m);
        };
        let num = |x: &serde_json::Value| x.as_f64().unwrap_or(f64::NAN);
        for l in LOCALISERS {
            let s = &v[l.name()];
            let p = format!("visual_localization.{}", l.name());
            m.insert(format!("{p}.x_error_mm"), num(&s["x_error_mm"]["mean"]));
            m.insert(format!("{p}.y_error_mm"), num(&s["y_error_mm"]["mean"]));
            m.insert(
                format!("{p}.heading_error_deg"),
                num(&s["heading_error_deg"]["mean"]),
            );
            m.insert(format!("{p}.within_5cm_5deg"), num(&s["within_5cm_5deg"]));
            m.insert(format!("{p}.projected"), num(&s["projected"]["mean"]));
            m.insert(format!("{p}.comparisons"), num(&s["comparisons"]["mean"]));
        }
        let (a, d) = (&v["all"], &v["delegates"]);
        // The seed's comparisons, as ratios: delegates against all landmarks.
        m.insert(
            "visual_localization.delegates.matching_work_ratio",
            num(&a["comparisons"]["mean"]) / num(&d["comparisons"]["mean"]),
        );
        let ratio = |k: &str| num(&d[k]["mean"]) / num(&a[k]["mean"]);
        m.insert(
            "visual_localization.delegates.error_ratio",
            ratio("x_error_mm")
                .max(ratio("y_error_mm"))
                .max(ratio("heading_error_deg")),
        );
        m.insert("visual_localization.bumps", self.bumps as f64);
        if !self.spec.route.is_empty() {
            m.insert(
                "visual_localization.path_error.mean_m",
                num(&v["path_error"]["mean_m"]),
            );
            m.insert(
                "visual_localization.path_error.max_m",
                num(&v["path_error"]["max_m"]),
            );
        }
        Ok(m)
    }
}

/// The metrics a run with `[visual_localization]` produces.
fn metric_names(v: &VisualLocalizationSpec) -> Vec<String> {
    let mut out = Vec::new();
    for l in LOCALISERS {
        for k in [
            "x_error_mm",
            "y_error_mm",
            "heading_error_deg",
            "within_5cm_5deg",
            "projected",
            "comparisons",
        ] {
            out.push(format!("visual_localization.{}.{k}", l.name()));
        }
    }
    out.push("visual_localization.delegates.matching_work_ratio".into());
    out.push("visual_localization.delegates.error_ratio".into());
    out.push("visual_localization.bumps".into());
    if !v.route.is_empty() {
        out.push("visual_localization.path_error.mean_m".into());
        out.push("visual_localization.path_error.max_m".into());
    }
    out
}

/// `[visual_localization]`: seed 001's monocular localisation in a landmark map.
pub struct Module;

impl ModuleConfig for Module {
    fn key(&self) -> Option<&'static str> {
        Some("visual_localization")
    }

    fn pose_topic(&self, _table: &toml::Value) -> Option<&'static str> {
        Some("localization")
    }

    fn pose_table(&self) -> Option<(&'static str, &'static str)> {
        Some(("localization", "[visual_localization]"))
    }

    fn resolve(&self, cx: &Resolving<'_>, table: &toml::Value) -> Result<Spec, SpecError> {
        let key = "visual_localization";
        let mut v: VisualLocalizationSpec = cx.typed(key, cx.table(key, table)?)?;
        let path = cx.path;
        let cam = cx.camera(key, v.camera.as_deref())?;
        let name = cam.name.clone();
        if cam.joint.is_some() || cam.carrier.is_some() {
            return Err(SpecError::new(
                path,
                "visual_localization.camera",
                format!("camera `{name}` must be fixed to the robot's base"),
            ));
        }
        let levelled = cx
            .spec
            .camera
            .iter()
            .find(|c| c.name == name)
            .is_some_and(|c| c.rpy_deg[0] == 0.0 && c.rpy_deg[1] == 0.0);
        if !levelled {
            return Err(SpecError::new(
                path,
                "visual_localization.camera",
                format!("camera `{name}` must be levelled (roll and pitch 0): the state is planar"),
            ));
        }
        v.camera = Some(name);
        v.validate().map_err(|(k, m)| SpecError::new(path, k, m))?;
        let file = map_path(path, &v);
        if !file.is_file() {
            return Err(SpecError::new(
                path,
                "visual_localization.map",
                format!(
                    "{}: no such file (a `landmarks.json` a [visual_map] run wrote)",
                    file.display()
                ),
            ));
        }
        // Read now, so that a bad map is refused before anything runs.
        futago_msgs::landmarks::LandmarkFile::read(&file)
            .map_err(|e| SpecError::new(path, "visual_localization.map", e.to_string()))?;
        v.map = file;
        Ok(Box::new(v))
    }

    fn effective(&self, spec: &(dyn Any + Send + Sync)) -> Option<toml::Table> {
        toml::Table::try_from(spec.downcast_ref::<VisualLocalizationSpec>()?).ok()
    }

    fn metric_names(
        &self,
        _spec: &ScenarioSpec,
        own: Option<&(dyn Any + Send + Sync)>,
    ) -> Vec<String> {
        super::own::<VisualLocalizationSpec>(own)
            .map(metric_names)
            .unwrap_or_default()
    }
}

impl StackModule for Module {
    fn build(&self, s: &Scenario, _seed: u64, _out: Option<&Path>) -> Nodes {
        boxed(node(s))
    }
}
