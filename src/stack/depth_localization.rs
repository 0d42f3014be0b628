//! The depth-camera localiser node (seed 002): Monte Carlo localisation of one camera in a 3D
//! model, every particle's depth rendered in one batch through the stack's own renderer.
//!
//! The model is the world's mesh handed to the stack as a model (the "laser-scanned model" of
//! seed 002, here exact); the filter never reads the simulator's state. At its rate the node
//! takes a frame of its camera, re-projects the measured depth to the render size, moves the
//! particles (by the robot's odometry carried to the camera where `odometry` is set, else the
//! seed's random walk alone), updates, and publishes the robot's pose under the camera
//! (`pose/depth_localization`). It writes `depth_localization.txt` (TUM, the base's planar
//! pose, scored like any trajectory), and scores the seed's own measure: each estimated
//! position's distance to the true path, its median, σ and share within 3σ.

use super::{Bus, CameraFrame, FrameTruth, Node, Report, Streams, Truth, tum_line};
use crate::ground_truth::Metrics;
use crate::scenario::{Scenario, ScenarioSpec};
use anyhow::{Context, Result};
use futago_msgs::camera::Intrinsics;
use futago_msgs::{Duration, Pose2, Time};
use futago_robot::localization::depth_mcl::{CameraState, DepthMcl, reproject};
use futago_sim::noise::stream;
use glam::{DQuat, DVec3};
use serde_json::json;
use std::path::Path;
use std::time::Instant;

/// The estimates of the robot's planar pose (TUM), one per frame.
pub const DEPTH_LOCALIZATION_FILE: &str = "depth_localization.txt";

/// Spacing of the true path's points, m (well below the seed's 0.07 m).
const PATH_STEP: f64 = 0.01;

/// The depth-camera localiser in the loop.
pub struct DepthLocalizationNode {
    mcl: DepthMcl,
    renderer: futago_render::Renderer,
    camera: String,
    /// The camera's depth intrinsics and those of the render.
    depth: Intrinsics,
    render: Intrinsics,
    /// The camera's range, m (the model is drawn a little past it).
    range: f64,
    /// The camera's body frame on the base, planar part.
    mount2: Pose2,
    odometry: bool,
    period: Duration,
    next: Time,
    last_odometry: Option<Pose2>,
    lines: String,
    /// Per frame: the estimated and true positions (x, y), and the filter's wall time, s.
    frames: Vec<([f64; 2], [f64; 2], f64)>,
    /// The true path, a point every [`PATH_STEP`] (for the seed's measure).
    path: Vec<[f64; 2]>,
    summary: Option<serde_json::Value>,
}

/// The camera body pose on a base at planar pose `base` on the floor.
fn camera_state(base: &Pose2, mount: &(DVec3, DQuat)) -> CameraState {
    let r = DQuat::from_rotation_z(base.theta);
    let p = DVec3::new(base.x, base.y, 0.0) + r * mount.0;
    let q = r * mount.1;
    CameraState::from_pose(&futago_msgs::Pose3 {
        translation: p.to_array(),
        rotation: [q.x, q.y, q.z, q.w],
    })
}

/// The node when the scenario has `[depth_localization]`.
pub fn node(s: &Scenario, seed: u64) -> Result<Option<DepthLocalizationNode>> {
    use rand::Rng;
    let Some(spec) = &s.spec.depth_localization else {
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
    let m = cam.mount;
    let mount = (
        DVec3::new(
            m.translation.x as f64,
            m.translation.y as f64,
            m.translation.z as f64,
        ),
        DQuat::from_xyzw(
            m.rotation.x as f64,
            m.rotation.y as f64,
            m.rotation.z as f64,
            m.rotation.w as f64,
        ),
    );
    let renderer = futago_render::Renderer::new(&s.world.scene())
        .context("depth_localization: rendering the model")?;
    let mcl = DepthMcl::new(
        spec.mcl,
        camera_state(&s.start, &mount),
        stream(seed, "depth_localization.mcl").random(),
    );
    Ok(Some(DepthLocalizationNode {
        mcl,
        renderer,
        camera: cam.name.clone(),
        depth: cam.depth,
        render,
        range: cam.range_max,
        mount2: super::camera_on_base(cam),
        odometry: spec.odometry,
        period: Duration::from_secs(1.0 / spec.rate),
        next: Time::ZERO,
        last_odometry: None,
        lines: String::new(),
        frames: Vec::new(),
        path: Vec::new(),
        summary: None,
    }))
}

/// The trajectory metrics under `depth_localization`, the seed's path measure and the time per
/// frame.
pub fn metric_names(s: &ScenarioSpec) -> Vec<String> {
    if s.depth_localization.is_none() {
        return Vec::new();
    }
    let mut names = crate::ground_truth::trajectory_metric_names("depth_localization");
    for k in ["median_m", "sigma_m", "within_3sigma"] {
        names.push(format!("depth_localization.path_error.{k}"));
    }
    names.push("depth_localization.frame_ms".into());
    names
}

/// Distance from `p` to the polyline `path`, m.
fn distance_to_path(p: [f64; 2], path: &[[f64; 2]]) -> f64 {
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
        Streams {
            consumes: vec![
                format!("camera/{}", self.camera),
                "odometry".into(),
                "truth".into(),
            ],
            publishes: vec!["pose/depth_localization".into()],
            ..Streams::default()
        }
    }

    fn on_truth(&mut self, bus: &Bus) -> Result<()> {
        // A point every centimetre of the path: a standing robot adds none, and the distances
        // at the end stay a pass over the path per frame.
        let p = [bus.truth.x, bus.truth.y];
        if self
            .path
            .last()
            .is_none_or(|l| (p[0] - l[0]).hypot(p[1] - l[1]) >= PATH_STEP)
        {
            self.path.push(p);
        }
        Ok(())
    }

    fn wants_frame(&self, camera: &str, bus: &Bus) -> bool {
        camera == self.camera && bus.now >= self.next
    }

    fn on_frame(
        &mut self,
        camera: &str,
        frame: &CameraFrame,
        _truth: &mut dyn FrameTruth,
        bus: &mut Bus,
    ) -> Result<()> {
        if camera != self.camera {
            return Ok(());
        }
        self.next = bus.now + self.period;
        let odo = bus.odometry;
        // The robot's odometry since the last frame, carried to the camera.
        let motion = match (self.odometry, self.last_odometry) {
            (true, Some(last)) => Some(
                self.mount2
                    .inverse()
                    .compose(&last.between(&odo))
                    .compose(&self.mount2),
            ),
            (true, None) => Some(Pose2::IDENTITY),
            (false, _) => None,
        };
        self.last_odometry = Some(odo);
        let measured = reproject(&frame.frame.depth, &self.depth, &self.render);
        let t0 = Instant::now();
        let est = self
            .mcl
            .update(
                &mut self.renderer,
                &self.render,
                &measured,
                self.range,
                motion.as_ref(),
            )
            .map_err(|e| anyhow::anyhow!("depth_localization: {e}"))?;
        let spent = t0.elapsed().as_secs_f64();
        // The base under the estimated camera (planar).
        let c = est.state;
        let yaw = c.rpy[2] - self.mount2.theta;
        let (s, co) = yaw.sin_cos();
        let base = Pose2::new(
            c.position[0] - (co * self.mount2.x - s * self.mount2.y),
            c.position[1] - (s * self.mount2.x + co * self.mount2.y),
            futago_msgs::wrap_angle(yaw),
        );
        bus.publish_pose("depth_localization", base, odo);
        tum_line(&mut self.lines, bus.now, &base);
        self.frames
            .push(([base.x, base.y], [bus.truth.x, bus.truth.y], spent));
        Ok(())
    }

    fn finish(&mut self, _bus: &mut Bus, out: Option<&Path>) -> Result<Report> {
        let mut report = Report::default();
        if let Some(dir) = out {
            std::fs::write(dir.join(DEPTH_LOCALIZATION_FILE), &self.lines)
                .with_context(|| format!("writing {DEPTH_LOCALIZATION_FILE}"))?;
            report.files.push(DEPTH_LOCALIZATION_FILE.to_string());
            report.trajectories.push((
                "depth_localization".to_string(),
                DEPTH_LOCALIZATION_FILE.to_string(),
            ));
        }
        let d: Vec<f64> = self
            .frames
            .iter()
            .map(|(e, _, _)| distance_to_path(*e, &self.path))
            .collect();
        let n = self.frames.len().max(1) as f64;
        let frame_ms = self.frames.iter().map(|f| f.2).sum::<f64>() / n * 1000.0;
        let (median, sigma, within) = path_error(&d).unwrap_or((f64::NAN, f64::NAN, f64::NAN));
        let v = json!({
            "frames": self.frames.len(),
            "render": [self.render.width, self.render.height],
            "frame_ms": frame_ms,
            "path_error": {
                "median_m": median,
                "sigma_m": sigma,
                "within_3sigma": within,
                "what": "each estimated position's distance to the true path (seed 002 §4)",
            },
        });
        self.summary = Some(v.clone());
        report.summary.push(("depth_localization".into(), v));
        Ok(report)
    }

    fn score(&self, truth: &Truth) -> Result<Metrics> {
        let mut m = crate::ground_truth::score_trajectory(
            truth,
            "depth_localization",
            DEPTH_LOCALIZATION_FILE,
        )?;
        if let Some(v) = &self.summary {
            for k in ["median_m", "sigma_m", "within_3sigma"] {
                if let Some(x) = v["path_error"][k].as_f64() {
                    m.insert(format!("depth_localization.path_error.{k}"), x);
                }
            }
            if let Some(x) = v["frame_ms"].as_f64() {
                m.insert("depth_localization.frame_ms".to_string(), x);
            }
        }
        Ok(m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
