//! The coverage node, for the `coverage` controller: it plans the route on the known map
//! ([`futago_robot::navigation::coverage`]) and publishes it on `path/coverage` for the
//! driver, and it scores the run against the world (`ground_truth::coverage`): the floor the
//! robot's footprint swept and the true surfaces its camera saw, over time.
//!
//! Files: `coverage_route.txt` (the planned route, `x y` per line, map frame, m) and
//! `coverage.png` (the world's map painted: floor swept green, reachable floor not swept
//! orange, walls and furniture the camera saw blue and those it did not red; the planned
//! route dark blue, the driven path black).

use super::{Bus, CameraFrame, FrameTruth, Node, Report, Streams, Truth};
use crate::ground_truth::Metrics;
use crate::ground_truth::coverage::{CLASSES, CameraCoverage, Footprint, Surfaces};
use crate::scenario::{ControllerConfig, Scenario, ScenarioSpec};
use anyhow::{Context, Result};
use futago_msgs::{Duration, Pose2, Time};
use futago_robot::geometry::grid::OCCUPIED;
use futago_robot::navigation::coverage::{self, ROBOT_RADIUS, Route};
use serde_json::{Value, json};
use std::path::Path;
use std::time::Instant;

/// The planned route.
pub const ROUTE_FILE: &str = "coverage_route.txt";
/// The coverage picture.
pub const PICTURE_FILE: &str = "coverage.png";
/// Period of the camera frames scored, s: at the navigator's in-place turn (0.12 m/s a
/// wheel, 0.93 rad/s) the view turns 0.47 rad between frames, half the Kinect's 1.0 rad
/// field of view; at 0.3 m/s the robot moves 0.15 m.
pub const FRAME_PERIOD: f64 = 0.5;
/// Every how many pixels of a scored depth image are used (4 cm apart at 3.5 m on the
/// Kinect's 320-pixel depth image, within a 5 cm voxel).
const PIXEL_STRIDE: u32 = 2;
/// Period of the coverage-over-time series, s.
const SERIES_PERIOD: f64 = 10.0;

/// The camera whose frames are scored: its name, valid range and the height it can see up to.
struct ScoredCamera {
    name: String,
    range: (f64, f64),
}

/// The coverage planner and scorer.
pub struct CoverageNode {
    route: Route,
    planning_s: f64,
    /// The share of the floor the route sweeps if driven exactly.
    planned_footprint: f64,
    camera: Option<ScoredCamera>,
    surfaces: Option<Surfaces>,
    seen: CameraCoverage,
    footprint: Footprint,
    next_frame: Time,
    next_sample: Time,
    /// (time, footprint share, camera share of walls, of floor, of all).
    series: Vec<[f64; 5]>,
    last: Option<Pose2>,
    driven_m: f64,
    /// The true path, a point every 5 cm (for the picture).
    driven: Vec<[f64; 2]>,
    /// When the driver finished the route.
    done_at: Option<Time>,
    published: bool,
    scenario: String,
}

/// The node when the scenario's controller is `coverage`.
pub fn node(s: &Scenario) -> Result<Option<CoverageNode>> {
    if !matches!(s.controller, ControllerConfig::Coverage(_)) {
        return Ok(None);
    }
    let height = super::driver::navigation_height(s);
    let map = super::world_map(s, s.spec.navigation.map_resolution, height)
        .context("navigation.map_resolution")?;
    let start = [s.start.x, s.start.y];
    let t0 = Instant::now();
    let route = coverage::plan(&map, &s.spec.coverage, start)
        .map_err(|e| anyhow::anyhow!("coverage: {e}"))?;
    let planning_s = t0.elapsed().as_secs_f64();
    // The first camera off any joint is scored.
    let cam = s.cameras.iter().find(|c| c.joint.is_none());
    let camera = cam.map(|c| ScoredCamera {
        name: c.name.clone(),
        range: (c.range_min, c.range_max),
    });
    let surfaces = cam.map(|c| {
        let half_vfov = (c.depth.height as f64 / (2.0 * c.depth.fy)).atan();
        let top = c.mount.translation.z as f64 + c.range_max * half_vfov.tan();
        let region = &s.spec.coverage.region;
        Surfaces::from_world(&s.world, top, |p| {
            region.is_empty() || coverage::inside_polygon(region, p)
        })
    });
    // The floor to cover: the world's, less what the user left out (the region's outside and
    // the annotations).
    let floor = coverage::restricted(&map, &s.spec.coverage);
    let footprint = Footprint::new(&floor, ROBOT_RADIUS, s.spec.coverage.clearance, start)
        .map_err(|e| anyhow::anyhow!("coverage: {e}"))?;
    // What the route would sweep if driven exactly.
    let mut planned = Footprint::new(&floor, ROBOT_RADIUS, s.spec.coverage.clearance, start)
        .map_err(|e| anyhow::anyhow!("coverage: {e}"))?;
    for w in route.points.windows(2) {
        let n = ((w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]) / 0.02)
            .ceil()
            .max(1.0) as usize;
        for k in 0..=n {
            let t = k as f64 / n as f64;
            planned.add(&Pose2::new(
                w[0][0] + t * (w[1][0] - w[0][0]),
                w[0][1] + t * (w[1][1] - w[0][1]),
                0.0,
            ));
        }
    }
    let planned_footprint = planned.share();
    Ok(Some(CoverageNode {
        route,
        planning_s,
        planned_footprint,
        camera,
        surfaces,
        seen: CameraCoverage::default(),
        footprint,
        next_frame: Time::ZERO,
        next_sample: Time::ZERO,
        series: Vec::new(),
        last: None,
        driven_m: 0.0,
        driven: Vec::new(),
        done_at: None,
        published: false,
        scenario: s.spec.name.clone(),
    }))
}

/// The names this node scores where the controller is `coverage`.
pub fn metric_names(s: &ScenarioSpec) -> Vec<String> {
    if s.controller.get("type").and_then(|t| t.as_str()) != Some("coverage") {
        return Vec::new();
    }
    let mut names: Vec<String> = [
        "footprint",
        "route.length_m",
        "route.time_s",
        "route.turns",
        "route.footprint",
        "driven_m",
        "completed",
        "time_s",
    ]
    .iter()
    .map(|k| format!("coverage.{k}"))
    .collect();
    if s.camera.iter().any(|c| c.joint.is_none()) {
        names.extend(
            CLASSES
                .iter()
                .chain(&["all"])
                .map(|c| format!("coverage.camera.{c}")),
        );
    }
    names
}

impl CoverageNode {
    fn sample(&mut self, now: Time) {
        let (walls, floor, all) = match &self.surfaces {
            Some(s) => {
                let (by, all) = s.shares(&self.seen);
                (by[1].unwrap_or(0.0), by[0].unwrap_or(0.0), all)
            }
            None => (0.0, 0.0, 0.0),
        };
        self.series
            .push([now.secs(), self.footprint.share(), walls, floor, all]);
    }

    /// The picture: the map painted by footprint and camera coverage, the routes over it.
    fn picture(&self) -> Vec<u8> {
        let g = self.footprint.grid();
        let scale = 2u32;
        let (w, h) = (g.width as u32 * scale, g.height as u32 * scale);
        let mut img = image::RgbImage::from_pixel(w, h, image::Rgb([235, 235, 235]));
        let states = self.footprint.states();
        let column_seen = |p: [f64; 2], class: usize| -> Option<bool> {
            let s = self.surfaces.as_ref()?;
            let zs = (0..60).map(|k| k as f64 * 0.05);
            let mut held = false;
            for z in zs {
                let q = [p[0], p[1], z];
                if s.holds(q, class) {
                    held = true;
                    if self.seen.saw(q) {
                        return Some(true);
                    }
                }
            }
            held.then_some(false)
        };
        for j in 0..g.height {
            for i in 0..g.width {
                let k = j * g.width + i;
                let p = g.cell_center(i, j);
                let c = if g.cells[k] >= OCCUPIED {
                    match column_seen(p, 1).or_else(|| column_seen(p, 2)) {
                        Some(true) => [40, 90, 200],
                        Some(false) => [210, 40, 40],
                        None => [110, 110, 110],
                    }
                } else {
                    match states[k] {
                        2 => [150, 215, 150],
                        1 => [250, 190, 120],
                        _ if g.cells[k] >= 0 => [255, 255, 255],
                        _ => [220, 220, 220],
                    }
                };
                let top = (g.height - 1 - j) as u32 * scale;
                for dy in 0..scale {
                    for dx in 0..scale {
                        img.put_pixel(i as u32 * scale + dx, top + dy, image::Rgb(c));
                    }
                }
            }
        }
        let to_px = |p: [f64; 2]| -> (f32, f32) {
            let u = (p[0] - g.origin[0]) / g.resolution * scale as f64;
            let v = h as f64 - (p[1] - g.origin[1]) / g.resolution * scale as f64;
            (u as f32, v as f32)
        };
        for s in self.route.points.windows(2) {
            let (a, b) = (to_px(s[0]), to_px(s[1]));
            let n = ((b.0 - a.0).hypot(b.1 - a.1) * 2.0).ceil().max(1.0) as usize;
            for k in 0..=n {
                let t = k as f32 / n as f32;
                let (u, v) = (a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1));
                if u >= 0.0 && v >= 0.0 && (u as u32) < w && (v as u32) < h {
                    img.put_pixel(u as u32, v as u32, image::Rgb([20, 30, 120]));
                }
            }
        }
        for p in &self.driven {
            let (u, v) = to_px(*p);
            if u >= 0.0 && v >= 0.0 && (u as u32) < w && (v as u32) < h {
                img.put_pixel(u as u32, v as u32, image::Rgb([0, 0, 0]));
            }
        }
        crate::report::png(img)
    }
}

impl Node for CoverageNode {
    fn name(&self) -> &'static str {
        "coverage"
    }

    fn streams(&self) -> Streams {
        let mut consumes = vec!["truth".to_string()];
        consumes.extend(self.camera.iter().map(|c| format!("camera/{}", c.name)));
        Streams {
            consumes,
            publishes: vec!["path/coverage".into()],
            ..Streams::default()
        }
    }

    fn on_truth(&mut self, bus: &Bus) -> Result<()> {
        let pose = bus.truth;
        self.footprint.add(&pose);
        if let Some(last) = self.last {
            self.driven_m += last.distance(&pose);
        }
        if self
            .driven
            .last()
            .is_none_or(|p| (p[0] - pose.x).hypot(p[1] - pose.y) >= 0.05)
        {
            self.driven.push([pose.x, pose.y]);
        }
        self.last = Some(pose);
        if bus.now >= self.next_sample {
            self.sample(bus.now);
            self.next_sample = bus.now + Duration::from_secs(SERIES_PERIOD);
        }
        Ok(())
    }

    fn wants_frame(&self, camera: &str, bus: &Bus) -> bool {
        self.camera.as_ref().is_some_and(|c| c.name == camera) && bus.now >= self.next_frame
    }

    fn on_frame(
        &mut self,
        camera: &str,
        frame: &CameraFrame,
        truth: &mut dyn FrameTruth,
        bus: &mut Bus,
    ) -> Result<()> {
        let Some(c) = self.camera.as_ref().filter(|c| c.name == camera) else {
            return Ok(());
        };
        let range = c.range;
        self.next_frame = bus.now + Duration::from_secs(FRAME_PERIOD);
        let depth = truth.true_depth()?;
        self.seen.add(
            &depth,
            &frame.frame.depth_intrinsics,
            &frame.optical,
            range,
            PIXEL_STRIDE,
        );
        Ok(())
    }

    fn on_control(&mut self, bus: &mut Bus) -> Result<()> {
        // The route goes out at the first control tick (before the driver's, which runs
        // after this node).
        if !self.published {
            bus.publish_path("coverage", self.route.points.clone());
            self.published = true;
        }
        if self.done_at.is_none() && bus.route_done.is_some() {
            self.done_at = bus.route_done;
        }
        Ok(())
    }

    fn finish(&mut self, bus: &mut Bus, out: Option<&Path>) -> Result<Report> {
        self.sample(bus.now);
        let mut files = Vec::new();
        if let Some(dir) = out {
            let mut text = format!(
                "# futago coverage route of {} ({}): x y, map frame, m\n",
                self.scenario,
                self.route.planner.name()
            );
            for p in &self.route.points {
                text += &format!("{:.4} {:.4}\n", p[0], p[1]);
            }
            std::fs::write(dir.join(ROUTE_FILE), text)
                .with_context(|| format!("writing {ROUTE_FILE}"))?;
            std::fs::write(dir.join(PICTURE_FILE), self.picture())
                .with_context(|| format!("writing {PICTURE_FILE}"))?;
            files.extend([ROUTE_FILE, PICTURE_FILE].map(String::from));
        }
        let series: Vec<Value> = self
            .series
            .iter()
            .map(|s| {
                json!({"t": s[0], "footprint": s[1], "camera_walls": s[2], "camera_floor": s[3], "camera_all": s[4]})
            })
            .collect();
        let summary = json!({
            "planner": self.route.planner.name(),
            "route": self.route.stats,
            "route_done_s": self.done_at.map(|t| t.secs()),
            "driven_m": self.driven_m,
            "surface_area_m2": self.surfaces.as_ref().map(|s| {
                let t = s.total();
                json!({"floor": t[0], "walls": t[1], "furniture": t[2]})
            }),
            "series": series,
        });
        let mut performance = serde_json::Map::new();
        performance.insert("planning_s".into(), json!(self.planning_s));
        Ok(Report {
            summary: vec![("coverage".into(), summary)],
            files,
            performance,
            ..Report::default()
        })
    }

    fn score(&self, _truth: &Truth) -> Result<Metrics> {
        let mut m = Metrics::default();
        m.insert("coverage.footprint", self.footprint.share());
        m.insert("coverage.route.length_m", self.route.stats.length_m);
        m.insert("coverage.route.time_s", self.route.stats.time_s);
        m.insert("coverage.route.turns", self.route.stats.turns as f64);
        m.insert("coverage.route.footprint", self.planned_footprint);
        m.insert("coverage.driven_m", self.driven_m);
        m.insert(
            "coverage.completed",
            if self.done_at.is_some() { 1.0 } else { 0.0 },
        );
        let end = self.series.last().map_or(0.0, |s| s[0]);
        m.insert("coverage.time_s", self.done_at.map_or(end, |t| t.secs()));
        if let Some(s) = &self.surfaces {
            let (by, all) = s.shares(&self.seen);
            for (c, name) in CLASSES.iter().enumerate() {
                m.insert(format!("coverage.camera.{name}"), by[c].unwrap_or(0.0));
            }
            m.insert("coverage.camera.all", all);
        }
        Ok(m)
    }
}
