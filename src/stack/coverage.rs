//! The coverage node, for the `coverage` controller: it plans the route on the known map
//! ([`futago_robot::navigation::coverage`]) and publishes it on `path/coverage` for the
//! driver, and it scores the run against the world (`ground_truth::coverage`): the floor the
//! robot's footprint swept and the true surfaces its camera saw, over time.
//!
//! With `coverage.second_pass.enabled`, once the route is done the node plans a second one
//! to the walls the robot's camera did not see (by the robot's own record of its frames and
//! pose, [`second_pass`]), publishes it for the driver, and scores the camera coverage
//! before and after it and the extra distance driven.
//!
//! Files: `coverage_route.txt` (the planned route, `x y` per line, map frame, m),
//! `coverage_route_2.txt` (the second route, where there is one) and
//! `coverage.png` (the world's map painted: floor swept green, reachable floor not swept
//! orange, walls and furniture the camera saw blue and those it did not red; the planned
//! route dark blue, the second route magenta, the driven path black).

use super::bus::ROUTE_DONE;
use super::driver::{ControllerConfig, controller, controller_type};
use super::{Bus, CameraFrame, FrameTruth, Node, Report, Streams, TrueState, Truth};
use crate::ground_truth::Metrics;
use crate::ground_truth::coverage::{CLASSES, CameraCoverage, Footprint, Surfaces};
use crate::ground_truth::observable::{CameraReach, Observability};
use crate::ground_truth::regions::{CORRIDOR_WIDTH, Kind, MIN_AREA_FACTOR, Regions};
use crate::scenario::{Scenario, ScenarioSpec};
use anyhow::{Context, Result};
use futago_msgs::{Duration, Pose2, Time};
use futago_robot::control::PoseSource;
use futago_robot::geometry::grid::OCCUPIED;
use futago_robot::localization::covariance::position_sigma;
use futago_robot::navigation::coverage::second_pass::{self, SecondPassConfig, WallSight};
use futago_robot::navigation::coverage::swept::Swept;
use futago_robot::navigation::coverage::{self, Field, ROBOT_RADIUS, Route, RouteStats};
use futago_sim::kinect::KinectSpec;
use serde_json::{Value, json};
use std::path::Path;
use std::time::Instant;

/// The planned route.
pub const ROUTE_FILE: &str = "coverage_route.txt";
/// The second pass's route.
pub const SECOND_ROUTE_FILE: &str = "coverage_route_2.txt";
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
    /// What the route sweeps if driven exactly, to score the drive against.
    planned: Footprint,
    camera: Option<ScoredCamera>,
    surfaces: Option<Surfaces>,
    /// The floor's corridors and rooms, the share of each one's floor the robot's footprint
    /// can reach, and whether that makes it one the route is asked to cover.
    regions: Regions,
    reachable_share: Vec<f64>,
    scored_regions: Vec<bool>,
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
    /// When the driver finished the route (the second, where there is one).
    done_at: Option<Time>,
    published: bool,
    scenario: String,
    /// The second pass, when enabled and a camera is scored.
    second: Option<SecondPass>,
    /// The lanes replanned from the localisation's covariance, when asked for.
    lanes: Option<Lanes>,
}

/// The boustrophedon lanes replanned once the localisation has settled, spaced for its own
/// covariance (`coverage.boustrophedon.lanes_from_covariance`): the first route is planned
/// before the filter has made any estimate, from the configured spacing.
struct Lanes {
    /// The map and configuration the first route was planned on, and the start its promise
    /// is measured from.
    map: futago_msgs::grid::OccupancyGrid,
    config: coverage::CoverageConfig,
    start: [f64; 2],
    /// The topic whose covariance is read (the pose the driver steers by) and that pose.
    topic: String,
    pose_source: PoseSource,
    /// The position spread of each estimate taken, m, and the stamp of the last one.
    sigmas: Vec<f64>,
    last: Option<Time>,
    /// Once replanned (or given up): its figures.
    replanned: Option<Value>,
}

/// The second pass's state: the robot's own record of the walls its camera saw, and, once
/// the first route is done, the second route and the figures before it.
struct SecondPass {
    config: SecondPassConfig,
    field: Field,
    sight: WallSight,
    /// The robot's own record of the floor its footprint swept, placed by the pose it steers
    /// by, against what the first route promised.
    swept: Swept,
    /// Where the driver takes its pose from (the same pose places the camera's points).
    pose_source: PoseSource,
    time_model: coverage::TimeModel,
    /// When the first route was done, and the second route then planned with its figures.
    started: Option<(Time, Vec<[f64; 2]>, RouteStats)>,
    gaps: usize,
    views: usize,
    unseeable: usize,
    floor_gaps: usize,
    floor_stops: usize,
    /// The figures at the end of the first route.
    before: Option<Figures>,
    planning_s: f64,
}

/// The figures a second pass is judged against, taken at the end of the first route.
#[derive(Debug, Clone, Copy)]
struct Figures {
    driven_m: f64,
    /// The camera's seen share of the walls, and of every surface.
    walls: f64,
    all: f64,
    /// The camera's seen share of the scored regions' walls, and of the part of them it can
    /// see at all.
    regions_walls: f64,
    observable_walls: f64,
    /// The true footprint's share of what the first route promised.
    footprint: f64,
}

/// The world's surfaces the camera is scored on: those up to the highest it can see, in the
/// region to cover, labelled by region, with what it can see at all from the reachable cells
/// of `field` (the floor to cover).
fn camera_surfaces(
    s: &Scenario,
    c: &KinectSpec,
    field: &Field,
    regions: &Regions,
) -> Result<Surfaces> {
    let half_vfov = (c.depth.height as f64 / (2.0 * c.depth.fy)).atan();
    let half_hfov = (c.depth.width as f64 / (2.0 * c.depth.fx)).atan();
    let height = c.mount.translation.z as f64;
    let top = height + c.range_max * half_vfov.tan();
    let region = &s.spec.coverage.region;
    // What the camera can see at all: from the cells the robot's centre can reach on the
    // floor to cover, past what stands at the camera's height.
    let sight = super::world_map(s, s.spec.navigation.map_resolution, height)
        .context("navigation.map_resolution")?;
    let observability = Observability::new(
        sight,
        field.reachable.clone(),
        CameraReach {
            height,
            forward: c.mount.translation.x as f64,
            near: c.range_min,
            far: c.range_max,
            half_hfov,
            half_vfov,
        },
    )
    .map_err(|e| anyhow::anyhow!("coverage: {e}"))?;
    // The region's bounding box (none: the whole world).
    let bounds = (!region.is_empty()).then(|| {
        region.iter().fold(
            [[f64::INFINITY; 2], [f64::NEG_INFINITY; 2]],
            |[lo, hi], p| {
                [
                    [lo[0].min(p[0]), lo[1].min(p[1])],
                    [hi[0].max(p[0]), hi[1].max(p[1])],
                ]
            },
        )
    });
    Ok(Surfaces::from_world(
        &s.world,
        top,
        bounds,
        |p| region.is_empty() || coverage::inside_polygon(region, p),
        |p| regions.at(p),
        |p, n| observability.sees(p, n),
    ))
}

/// The node when the scenario's controller is `coverage`.
pub fn node(s: &Scenario) -> Result<Option<CoverageNode>> {
    let ControllerConfig::Coverage(control) = controller(s) else {
        return Ok(None);
    };
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
    // Corridors and rooms, on the whole map (the region to cover would narrow the space
    // where its edge cuts it).
    let regions = Regions::new(&map, CORRIDOR_WIDTH);
    // The floor to cover: the world's, less what the user left out (the region's outside and
    // the annotations).
    let floor = coverage::restricted(&map, &s.spec.coverage);
    // Where the robot's centre can go on it.
    let field = Field::new(&floor, s.spec.coverage.clearance, start)
        .map_err(|e| anyhow::anyhow!("coverage: {e}"))?;
    let surfaces = cam
        .map(|c| camera_surfaces(s, c, &field, &regions))
        .transpose()?;
    let footprint = Footprint::new(&floor, ROBOT_RADIUS, s.spec.coverage.clearance, start)
        .map_err(|e| anyhow::anyhow!("coverage: {e}"))?;
    // What the route would sweep if driven exactly.
    let planned = promised(&floor, s.spec.coverage.clearance, start, &route.points)?;
    let planned_footprint = planned.share();
    let mut reachable_m2 = vec![0.0; regions.regions().len()];
    let g = footprint.grid();
    for (k, state) in footprint.states().iter().enumerate() {
        if *state > 0
            && let Some(r) = regions.at(g.cell_center(k % g.width, k / g.width))
        {
            reachable_m2[r] += g.resolution * g.resolution;
        }
    }
    let reachable_share: Vec<f64> = regions
        .regions()
        .iter()
        .zip(&reachable_m2)
        .map(|(r, a)| {
            if r.area_m2 > 0.0 {
                (a / r.area_m2).min(1.0)
            } else {
                0.0
            }
        })
        .collect();
    let min_reachable_m2 = MIN_AREA_FACTOR * CORRIDOR_WIDTH * CORRIDOR_WIDTH;
    let scored_regions = reachable_share
        .iter()
        .zip(&reachable_m2)
        .map(|(&s, &a)| s >= MIN_REACHABLE_SHARE || a >= min_reachable_m2)
        .collect();
    let second = match (&camera, s.spec.coverage.second_pass.enabled) {
        (Some(_), true) => Some(SecondPass {
            config: s.spec.coverage.second_pass.clone(),
            swept: Swept::new(&field, &route.points),
            field,
            sight: WallSight::new(&floor),
            pose_source: control.pose_source,
            time_model: s.spec.coverage.time_model,
            started: None,
            gaps: 0,
            views: 0,
            unseeable: 0,
            floor_gaps: 0,
            floor_stops: 0,
            before: None,
            planning_s: 0.0,
        }),
        (None, true) => anyhow::bail!(
            "coverage.second_pass.enabled: the second pass needs a camera off any joint ([[camera]])"
        ),
        _ => None,
    };
    let lanes = (s.spec.coverage.planner == coverage::PlannerKind::Boustrophedon
        && s.spec.coverage.boustrophedon.lanes_from_covariance)
        .then(|| super::bus::pose_topic(control.pose_source))
        .flatten()
        .map(|topic| Lanes {
            map: map.clone(),
            config: s.spec.coverage.clone(),
            start,
            topic: topic.trim_start_matches("pose/").to_string(),
            pose_source: control.pose_source,
            sigmas: Vec::new(),
            last: None,
            replanned: None,
        });
    Ok(Some(CoverageNode {
        route,
        planning_s,
        planned_footprint,
        planned,
        camera,
        surfaces,
        regions,
        reachable_share,
        scored_regions,
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
        second,
        lanes,
    }))
}

/// What `route` sweeps on `floor` if driven exactly (the floor reachable from `start` with
/// `clearance`).
fn promised(
    floor: &futago_msgs::grid::OccupancyGrid,
    clearance: f64,
    start: [f64; 2],
    route: &[[f64; 2]],
) -> Result<Footprint> {
    let mut planned = Footprint::new(floor, ROBOT_RADIUS, clearance, start)
        .map_err(|e| anyhow::anyhow!("coverage: {e}"))?;
    for w in route.windows(2) {
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
    Ok(planned)
}

/// The names this node scores where the controller is `coverage`.
pub fn metric_names(s: &ScenarioSpec) -> Vec<String> {
    if controller_type(s) != Some("coverage") {
        return Vec::new();
    }
    let mut names: Vec<String> = [
        "footprint",
        "route.length_m",
        "route.time_s",
        "route.turns",
        "route.footprint",
        "footprint_of_route",
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
        // By kind of region (where the world has that kind), over all the scored regions
        // together (`regions`: the walls and floor of the rooms and corridors the route is asked
        // to cover), and the worst region's walls.
        for kind in ["rooms", "corridors", "regions"] {
            for class in ["walls", "floor"] {
                names.push(format!("coverage.camera.{kind}.{class}"));
            }
        }
        names.push("coverage.camera.regions.walls_min".into());
        // The walls the camera can see at all from the floor the robot can reach (the
        // denominator, as the reachable floor is the footprint's), and their share of the walls.
        names.push("coverage.camera.regions.walls_observable".into());
        names.push("coverage.camera.regions.walls_observable_share".into());
        if s.coverage.second_pass.enabled {
            names.extend(
                [
                    "walls_before",
                    "all_before",
                    "regions_walls_before",
                    "walls_observable_before",
                    "walls_gain",
                    "extra_m",
                    "views",
                    "gaps",
                    "footprint_before",
                    "own_footprint",
                    "floor_gaps",
                    "floor_stops",
                ]
                .iter()
                .map(|k| format!("coverage.second_pass.{k}")),
            );
        }
    }
    names
}

/// Height above the floor from which a depth point counts as wall, m: points on the floor
/// beside a wall do not show the wall.
const WALL_POINT_MIN_Z: f64 = 0.1;

impl SecondPass {
    /// The pose the driver steers by.
    fn pose(&self, bus: &Bus) -> Pose2 {
        bus.pose_from(self.pose_source)
    }

    /// Marks the walls a camera frame (its measured depth) shows, placed by the robot's own
    /// pose: each point goes from the camera into the base's frame (the camera's mount, which
    /// the robot knows) and from there by the pose the driver steers by.
    fn see(&mut self, frame: &CameraFrame, range: (f64, f64), bus: &Bus) {
        let Some(on_base) = frame.on_base else {
            return;
        };
        let pose = self.pose(bus);
        let depth = &frame.frame.depth;
        let k = &frame.frame.depth_intrinsics;
        for v in (0..depth.height).step_by(PIXEL_STRIDE as usize) {
            for u in (0..depth.width).step_by(PIXEL_STRIDE as usize) {
                let z = depth.at(u, v) as f64;
                if !(z.is_finite() && z >= range.0 && z <= range.1) {
                    continue;
                }
                let b = on_base.transform_point(k.back_project(u as f64, v as f64, z));
                if b[2] < WALL_POINT_MIN_Z {
                    continue;
                }
                self.sight.add_point(pose.transform_point([b[0], b[1]]));
            }
        }
    }

    /// The second route from where the robot stands now, and its figures.
    fn plan(&mut self, bus: &Bus) -> Result<(Vec<[f64; 2]>, RouteStats)> {
        let t0 = Instant::now();
        let here = self.pose(bus);
        let second_pass::SecondRoute {
            points,
            gaps,
            floor_gaps,
            floor_stops,
        } = second_pass::plan(
            &self.field,
            &self.sight,
            Some(&self.swept),
            [here.x, here.y],
            &self.config,
        )
        .map_err(|e| anyhow::anyhow!("coverage.second_pass: {e}"))?;
        self.planning_s = t0.elapsed().as_secs_f64();
        self.gaps = gaps.len();
        self.views = gaps.iter().map(|g| g.views.len()).sum();
        self.unseeable = gaps.iter().map(|g| g.unseeable).sum();
        self.floor_gaps = floor_gaps.len();
        self.floor_stops = floor_stops;
        let stats = coverage::route_stats(&points, Some(here.theta), &self.time_model);
        Ok((points, stats))
    }
}

impl Lanes {
    /// What became of the lanes: replanned (with the spread and spacing), or why not.
    fn figures(&self) -> Value {
        if let Some(v) = &self.replanned {
            return v.clone();
        }
        let spacing = self.config.boustrophedon.spacing;
        let why = if self.sigmas.is_empty() {
            format!("pose/{} carries no covariance", self.topic)
        } else {
            format!(
                "{} of the {} estimates to settle on came before the run ended",
                self.sigmas.len(),
                self.config.boustrophedon.settle_estimates
            )
        };
        json!({"spacing_m": spacing, "configured": why})
    }
}

impl CoverageNode {
    /// Takes the localisation's newest covariance, and once enough are in, replans the
    /// lanes from the robot's pose with the spacing they call for
    /// ([`coverage::boustrophedon::spacing_from_sigma`]): the route and its promise are
    /// replaced, and the robot's own record of what it swept keeps what the first lanes did.
    fn replan_lanes(&mut self, bus: &mut Bus) -> Result<()> {
        let Some(lanes) = self.lanes.as_mut().filter(|l| l.replanned.is_none()) else {
            return Ok(());
        };
        // The first route is done, or the second pass is under way: nothing left to replan.
        if bus.route_done.is_some() {
            lanes.replanned = Some(json!({
                "spacing_m": lanes.config.boustrophedon.spacing,
                "configured": "the first route was done before the localisation settled",
            }));
            return Ok(());
        }
        let Some((t, covariance)) = bus
            .covariance(&lanes.topic)
            .filter(|(t, _)| lanes.last.is_none_or(|l| *t > l))
        else {
            return Ok(());
        };
        lanes.last = Some(t);
        lanes.sigmas.push(position_sigma(&covariance));
        let c = &lanes.config.boustrophedon;
        if lanes.sigmas.len() < c.settle_estimates {
            return Ok(());
        }
        let mut sorted = lanes.sigmas.clone();
        sorted.sort_by(f64::total_cmp);
        let sigma = sorted[sorted.len() / 2];
        let spacing =
            coverage::boustrophedon::spacing_from_sigma(sigma, 2.0 * ROBOT_RADIUS, c.miss);
        let mut config = lanes.config.clone();
        config.boustrophedon.spacing = spacing;
        let here = bus.pose_from(lanes.pose_source);
        let first = self.route.stats;
        let mut figures = json!({
            "at_s": bus.now.secs(),
            "estimates": lanes.sigmas.len(),
            "sigma_m": sigma,
            "spacing_m": spacing,
            "first_route": first,
        });
        let t0 = Instant::now();
        match coverage::plan(&lanes.map, &config, [here.x, here.y]) {
            Ok(route) => {
                let floor = coverage::restricted(&lanes.map, &lanes.config);
                let planned = promised(&floor, config.clearance, lanes.start, &route.points)?;
                self.planned_footprint = planned.share();
                self.planned = planned;
                if let Some(second) = &mut self.second {
                    second.swept.promise(&second.field, &route.points);
                }
                bus.publish_path("coverage", route.points.clone());
                self.route = route;
            }
            // Keep driving the first lanes where the robot's pose gives no route (off the
            // reachable floor).
            Err(e) => figures["error"] = json!(e),
        }
        figures["planning_s"] = json!(t0.elapsed().as_secs_f64());
        lanes.replanned = Some(figures);
        Ok(())
    }
}

/// A region's walls count towards the worst region's figure from this area on, m²: a nook
/// would make it noise.
const MIN_REGION_WALLS: f64 = 1.0;

/// A corridor or room is one the route is asked to cover, and is scored by region, when at
/// least this share of its floor lies within the footprint's reach, or at least as much floor
/// as the smallest region has (2.9 m², a 1.2 m corridor 2.4 m long). Regions are found on the
/// whole map (the edge of the region to cover would narrow the space it cuts); one that lies
/// mostly outside that edge, or behind an annotation, keeps only a sliver of floor and the far
/// faces of its walls inside, which no route over the covered floor can see. The footprint
/// reaches most of a room it can enter (all but a band of its clearance along the walls); in a
/// real map's clutter, a long corridor merged with rooms the robot cannot enter may keep less
/// than half, but many square metres.
const MIN_REACHABLE_SHARE: f64 = 0.5;

impl CoverageNode {
    /// The camera's coverage by region: per region its (walls, floor) area and seen area;
    /// per kind (rooms, corridors, and `None` for both together) the seen shares of walls and
    /// floor over the scored regions ([`MIN_REACHABLE_SHARE`]), 1 where there is none to see;
    /// and the lowest seen share of walls among the scored regions with at least
    /// [`MIN_REGION_WALLS`] of walls.
    #[allow(clippy::type_complexity)]
    fn by_region(
        &self,
    ) -> Option<(
        Vec<([f64; 3], [f64; 3])>,
        Vec<(Option<Kind>, [f64; 2])>,
        Option<f64>,
    )> {
        let s = self.surfaces.as_ref()?;
        let areas = s.region_areas(&self.seen, false);
        let mut kinds = Vec::new();
        for kind in [Some(Kind::Room), Some(Kind::Corridor), None] {
            let (mut total, mut got) = ([0.0; 2], [0.0; 2]);
            for (r, (t, g)) in areas.iter().enumerate() {
                if self.scored_regions[r]
                    && kind.is_none_or(|kind| self.regions.regions()[r].kind == kind)
                {
                    for (k, class) in [1, 0].into_iter().enumerate() {
                        total[k] += t[class];
                        got[k] += g[class];
                    }
                }
            }
            // Where the area holds no scored surface of a kind and class, nothing of it was
            // missed: the share is 1 (so the metric exists whatever the map, as declared).
            let share = |k: usize| {
                if total[k] > 0.0 {
                    got[k] / total[k]
                } else {
                    1.0
                }
            };
            kinds.push((kind, [share(0), share(1)]));
        }
        let worst = areas
            .iter()
            .enumerate()
            .filter(|(r, (t, _))| self.scored_regions[*r] && t[1] >= MIN_REGION_WALLS)
            .map(|(_, (t, g))| g[1] / t[1])
            .min_by(f64::total_cmp);
        Some((areas, kinds, worst))
    }

    /// The scored regions' walls the camera can see from some reachable pose: the seen share
    /// of them, and their share of all the scored regions' walls.
    fn observable_walls(&self) -> Option<(f64, f64)> {
        let s = self.surfaces.as_ref()?;
        let (mut all, mut observable, mut seen) = (0.0, 0.0, 0.0);
        let every = s.region_areas(&self.seen, false);
        for (r, (t, g)) in s.region_areas(&self.seen, true).iter().enumerate() {
            if self.scored_regions[r] {
                all += every[r].0[1];
                observable += t[1];
                seen += g[1];
            }
        }
        // As for the other shares: no such surface, nothing of it missed.
        Some(if observable > 0.0 {
            (seen / observable, observable / all)
        } else {
            (1.0, if all > 0.0 { 0.0 } else { 1.0 })
        })
    }

    /// The figures now: driven length, the camera's shares and the footprint's.
    fn figures(&self) -> Figures {
        let (walls, all) = match &self.surfaces {
            Some(s) => {
                let (by, all) = s.shares(&self.seen);
                (by[1].unwrap_or(0.0), all)
            }
            None => (0.0, 0.0),
        };
        let regions_walls = self
            .by_region()
            .and_then(|(_, kinds, _)| kinds.into_iter().find(|(k, _)| k.is_none()))
            .map_or(0.0, |(_, [walls, _])| walls);
        Figures {
            driven_m: self.driven_m,
            walls,
            all,
            regions_walls,
            observable_walls: self.observable_walls().map_or(0.0, |(seen, _)| seen),
            footprint: self.footprint.share_of(&self.planned),
        }
    }

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
        // A wall's or furniture's column: seen where some voxel of it up to 3 m that holds
        // the class was seen, missed where none was, none where it holds none.
        let zs: Vec<f64> = (0..60).map(|k| k as f64 * 0.05).collect();
        let held = self
            .surfaces
            .as_ref()
            .map(|s| [1, 2].map(|class| s.levels_held(&zs, class)));
        let seen = self.seen.levels_seen(&zs);
        let column_seen = |p: [f64; 2], class: usize| -> Option<bool> {
            let c = crate::ground_truth::coverage::column(p);
            let held = held.as_ref()?[class - 1].get(&c).copied().unwrap_or(0);
            (held != 0).then(|| held & seen.get(&c).copied().unwrap_or(0) != 0)
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
        let mut polyline = |points: &[[f64; 2]], colour: [u8; 3]| {
            for s in points.windows(2) {
                let (a, b) = (to_px(s[0]), to_px(s[1]));
                let n = ((b.0 - a.0).hypot(b.1 - a.1) * 2.0).ceil().max(1.0) as usize;
                for k in 0..=n {
                    let t = k as f32 / n as f32;
                    let (u, v) = (a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1));
                    if u >= 0.0 && v >= 0.0 && (u as u32) < w && (v as u32) < h {
                        img.put_pixel(u as u32, v as u32, image::Rgb(colour));
                    }
                }
            }
        };
        polyline(&self.route.points, [20, 30, 120]);
        if let Some((_, second, _)) = self.second.as_ref().and_then(|s| s.started.as_ref()) {
            polyline(second, [200, 0, 200]);
        }
        for p in &self.driven {
            let (u, v) = to_px(*p);
            if u >= 0.0 && v >= 0.0 && (u as u32) < w && (v as u32) < h {
                img.put_pixel(u as u32, v as u32, image::Rgb([0, 0, 0]));
            }
        }
        crate::picture::png(img)
    }
}

impl Node for CoverageNode {
    fn name(&self) -> &'static str {
        "coverage"
    }

    fn streams(&self) -> Streams {
        let mut consumes = vec!["truth".to_string(), ROUTE_DONE.to_string()];
        consumes.extend(self.camera.iter().map(|c| format!("camera/{}", c.name)));
        consumes.extend(
            self.second
                .as_ref()
                .and_then(|s| super::bus::pose_topic(s.pose_source)),
        );
        Streams {
            consumes,
            publishes: vec!["path/coverage".into()],
            ..Streams::default()
        }
    }

    fn on_truth(&mut self, truth: &TrueState, bus: &mut Bus) -> Result<()> {
        let pose = truth.robot;
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

    /// It reads the depth image alone.
    fn wants_rgb(&self, _camera: &str) -> bool {
        false
    }

    /// The second pass reads every `PIXEL_STRIDE`-th pixel of the measured depth (the scoring
    /// reads the true depth).
    fn depth_stride(&self, _camera: &str) -> u32 {
        PIXEL_STRIDE
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
        if let Some(second) = &mut self.second {
            second.see(frame, range, bus);
        }
        if let Some(surfaces) = &self.surfaces {
            let depth = truth.true_depth()?;
            self.seen.add(
                surfaces,
                &depth,
                &frame.frame.depth_intrinsics,
                &truth.optical(),
                range,
                PIXEL_STRIDE,
            );
        }
        Ok(())
    }

    fn on_control(&mut self, bus: &mut Bus) -> Result<()> {
        // The route goes out at the first control tick (before the driver's, which runs
        // after this node).
        if !self.published {
            bus.publish_path("coverage", self.route.points.clone());
            self.published = true;
        }
        self.replan_lanes(bus)?;
        if let Some(second) = &mut self.second {
            let p = second.pose(bus);
            second.swept.add(&second.field, [p.x, p.y]);
        }
        if self.done_at.is_none()
            && let Some(done) = bus.route_done
        {
            let figures = self
                .second
                .as_ref()
                .is_some_and(|s| s.started.is_none())
                .then(|| self.figures());
            match &mut self.second {
                None => self.done_at = Some(done),
                Some(second) => match &second.started {
                    None => {
                        second.before = figures;
                        let (points, stats) = second.plan(bus)?;
                        if points.len() < 2 {
                            self.done_at = Some(done);
                        } else {
                            bus.publish_path("coverage", points.clone());
                        }
                        second.started = Some((done, points, stats));
                    }
                    Some((first, ..)) if done > *first => self.done_at = Some(done),
                    Some(_) => {}
                },
            }
        }
        Ok(())
    }

    fn finish(&mut self, bus: &mut Bus, out: Option<&Path>) -> Result<Report> {
        self.sample(bus.now);
        let (mut files, mut pictures) = (Vec::new(), Vec::new());
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
            let png = self.picture();
            std::fs::write(dir.join(PICTURE_FILE), &png)
                .with_context(|| format!("writing {PICTURE_FILE}"))?;
            files.extend([ROUTE_FILE, PICTURE_FILE].map(String::from));
            pictures.push((PICTURE_FILE.to_string(), png));
        }
        let series: Vec<Value> = self
            .series
            .iter()
            .map(|s| {
                json!({"t": s[0], "footprint": s[1], "camera_walls": s[2], "camera_floor": s[3], "camera_all": s[4]})
            })
            .collect();
        let second = self.second.as_ref().map(|s| {
            json!({
                "route": s.started.as_ref().map(|(_, _, stats)| stats),
                "started_s": s.started.as_ref().map(|(t, ..)| t.secs()),
                "gaps": s.gaps,
                "views": s.views,
                "unseeable_pieces": s.unseeable,
                "planning_s": s.planning_s,
                "floor_gaps": s.floor_gaps,
                "floor_stops": s.floor_stops,
                "own_footprint": s.swept.share(),
                "before": s.before.map(|f| json!({
                    "driven_m": f.driven_m,
                    "camera_walls": f.walls,
                    "camera_all": f.all,
                    "camera_regions_walls": f.regions_walls,
                    "footprint_of_route": f.footprint,
                })),
            })
        });
        if let (Some(dir), Some((_, points, _))) =
            (out, self.second.as_ref().and_then(|s| s.started.as_ref()))
        {
            let mut text = format!(
                "# futago second coverage route of {}: x y, map frame, m\n",
                self.scenario
            );
            for p in points {
                text += &format!("{:.4} {:.4}\n", p[0], p[1]);
            }
            std::fs::write(dir.join(SECOND_ROUTE_FILE), text)
                .with_context(|| format!("writing {SECOND_ROUTE_FILE}"))?;
            files.push(SECOND_ROUTE_FILE.to_string());
        }
        let regions: Vec<Value> = match self.by_region() {
            Some((areas, ..)) => self
                .regions
                .regions()
                .iter()
                .enumerate()
                .filter_map(|(r, region)| {
                    let (t, g) = areas.get(r)?;
                    let share = |c: usize| (t[c] > 0.0).then(|| g[c] / t[c]);
                    Some(json!({
                        "kind": region.kind,
                        "area_m2": region.area_m2,
                        "centre": region.centre,
                        "reachable_share": self.reachable_share[r],
                        "scored": self.scored_regions[r],
                        "walls_m2": t[1],
                        "floor_m2": t[0],
                        "camera_walls": share(1),
                        "camera_floor": share(0),
                    }))
                })
                .collect(),
            None => Vec::new(),
        };
        let summary = json!({
            "planner": self.route.planner.name(),
            "regions": regions,
            "second_pass": second,
            "route": self.route.stats,
            "lanes": self.lanes.as_ref().map(Lanes::figures),
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
            pictures,
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
        m.insert(
            "coverage.footprint_of_route",
            self.footprint.share_of(&self.planned),
        );
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
            if let Some((_, kinds, worst)) = self.by_region() {
                for (kind, [walls, floor]) in kinds {
                    let name = match kind {
                        Some(Kind::Room) => "rooms",
                        Some(Kind::Corridor) => "corridors",
                        None => "regions",
                    };
                    m.insert(format!("coverage.camera.{name}.walls"), walls);
                    m.insert(format!("coverage.camera.{name}.floor"), floor);
                }
                if let Some(w) = worst {
                    m.insert("coverage.camera.regions.walls_min", w);
                }
            }
            if let Some((seen, observable)) = self.observable_walls() {
                m.insert("coverage.camera.regions.walls_observable", seen);
                m.insert("coverage.camera.regions.walls_observable_share", observable);
            }
            if let Some(second) = &self.second {
                // Without a second route (nothing missed, or the first never finished), the
                // figures before it are those at the end.
                let before = second.before.unwrap_or_else(|| self.figures());
                m.insert("coverage.second_pass.walls_before", before.walls);
                m.insert("coverage.second_pass.all_before", before.all);
                m.insert(
                    "coverage.second_pass.regions_walls_before",
                    before.regions_walls,
                );
                m.insert(
                    "coverage.second_pass.walls_observable_before",
                    before.observable_walls,
                );
                m.insert(
                    "coverage.second_pass.walls_gain",
                    by[1].unwrap_or(0.0) - before.walls,
                );
                m.insert(
                    "coverage.second_pass.extra_m",
                    self.driven_m - before.driven_m,
                );
                m.insert("coverage.second_pass.views", second.views as f64);
                m.insert("coverage.second_pass.gaps", second.gaps as f64);
                m.insert("coverage.second_pass.footprint_before", before.footprint);
                m.insert("coverage.second_pass.own_footprint", second.swept.share());
                m.insert("coverage.second_pass.floor_gaps", second.floor_gaps as f64);
                m.insert(
                    "coverage.second_pass.floor_stops",
                    second.floor_stops as f64,
                );
            }
        }
        Ok(m)
    }
}

/// The coverage planner and its scorer.
pub const MODULE: super::Plain = super::Plain {
    metric_names,
    build: |s, _, _| super::boxed(node(s)),
};
