//! The stop-and-scan 3D mapper in the loop (seed 004): it asks the driver for the route to
//! each view (`path/scan3d`), turns the turntable (`joint/NAME`), hands the horizontal
//! laser's scans to the mover detector and the vertical laser's to the mapper, and at the end
//! writes the map and scores how it kept people out.
//!
//! Scoring uses what each beam truly hit (the simulator's labels, [`Node::on_scan_truth`]):
//! every point a sweep measured, dropped or kept, is static (the building, its furniture) or
//! dynamic (a person or an agent). Three ways of keeping the dynamic ones out are scored on
//! the same run:
//! - `pause`: the seed's, the kept scans as they are;
//! - `carving`: every scan a sweep took (as if the robot never paused), with the points whose
//!   voxels free-space carving found free removed (OctoMap's removal, the DynamicMap
//!   benchmark's baseline);
//! - `pause_carving`: the kept scans, carved.
//!
//! Each is scored by the DynamicMap benchmark's point measures (Zhang et al. 2023): static
//! accuracy SA (the share of static points kept), dynamic accuracy DA (the share of dynamic
//! points removed) and their geometric mean AA, matched voxel by voxel (see
//! [`removal_scores`]); and by ERASOR's voxel measures at 0.2 m (Lim
//! et al. 2021): preservation rate PR (static voxels still holding a static point), rejection
//! rate RR (dynamic voxels left with no dynamic point) and their F1. SA is also given for the
//! floor (points no higher than 0.1 m) and for the rest, so that removal that eats the floor
//! shows.
//!
//! With no views given, the node plans each next view (`scan3d.planning`,
//! [`futago_robot::navigation::views`]) on the grid compressed from the mapper's voxel map
//! and hands it over. The map is also scored against the world's geometry: the share of the
//! true surfaces it holds after each view, with the distance driven
//! ([`crate::ground_truth::completeness`]), and lengths measured in it against the same
//! lengths cast in the world's colliders (`[[scan3d.length]]`, the seed's L1 and L2).

use super::{Bus, Node, Report, Streams, TrueState, Truth};
use super::{Nodes, StackModule, boxed};
use crate::ground_truth::Metrics;
use crate::ground_truth::completeness::{Completeness, LengthProbe, length_along};
use crate::ground_truth::coverage::Surfaces;
use crate::scenario::{
    ModuleConfig, Resolving, Scenario, ScenarioSpec, Spec, take_name, typed_table,
};
use anyhow::{Context, Result};
use futago_msgs::{LaserScan, Odometry, Pose2, Time};
use futago_robot::control::PoseSource;
use futago_robot::mapping::line_icp::LineIcp;
use futago_robot::mapping::turntable::TurntableConfig;
use futago_robot::mapping::turntable::{Phase, PlacedScan, StopAndScan, TableMount};
use futago_robot::mapping::voxels::VoxelMap;
use futago_robot::navigation::views::{View, ViewPlanningConfig, next_view};
use futago_sim::config::SpecError;
use futago_sim::lidar::BeamHit;
use glam::{DAffine3, DQuat, DVec3};
use rand_chacha::ChaCha8Rng;
use rustc_hash::{FxHashMap, FxHashSet};
use serde::Deserialize;
use serde_json::json;
use std::any::Any;
use std::collections::VecDeque;
use std::path::Path;

/// The map as kept (binary PLY, world frame).
pub const SCAN3D_MAP_FILE: &str = "scan3d_map.ply";
/// Every point the sweeps measured, dropped scans too, coloured by what the beam hit
/// (grey static, red a person or an agent).
pub const SCAN3D_RAW_FILE: &str = "scan3d_raw.ply";
/// The kept map after free-space carving.
pub const SCAN3D_CARVED_FILE: &str = "scan3d_carved.ply";
/// The seed's 2D grid, compressed from the carved voxel map (`map_server` files).
pub const SCAN3D_GRID_STEM: &str = "scan3d_grid";
/// The voxels of ERASOR's measures, m.
const SCORE_VOXEL: f64 = 0.2;
/// The voxels the point measures match a removal's output to the measured cloud in, m: the
/// voxel maps' default side.
const MATCH_VOXEL: f64 = 0.1;
/// Points no higher than this are on the floor, m (the LMS200's 1.5 cm noise, twice, and
/// more).
const FLOOR_Z: f64 = 0.1;
/// A true surface counts as mapped when a map point lies this near, m: the voxel maps'
/// side, 2.5 times the LMS200's 4 cm largest error.
const COVERAGE_TOLERANCE: f64 = 0.1;
/// The share of the true surfaces the coverage curve is read at (the 95 %).
const COVERAGE_MARK: f64 = 0.95;
/// The cell of the world grid the area to map is flooded on, m.
const INTERIOR_CELL: f64 = 0.05;
/// A surface belongs to the area to map when it lies this near floor the robot's centre can
/// reach, m: the Create's radius and a margin, so that a wall's inner face (0.17 m from the
/// nearest centre) counts and its outer face (a wall's 0.2 m thickness farther) does not.
const INTERIOR_REACH: f64 = 0.3;
/// How a length's surfaces are found on its line: the points within 5 cm of it (keep lines
/// twice this far from surfaces parallel to them), or 2 cm per metre of their distance along
/// it where that is more, whose projections gather within 8 cm (the LMS200's ±4 cm), at
/// least three of them. A view's scans 0.8° apart with 0.5° beams put about 10 points in a
/// 5 cm disc on a wall 2.5 m away but one or two at 7 m, since the points thin out as the
/// square of the range; a reach that grows as the range beyond 2.5 m (0.05 m / 2.5 m) holds
/// about as many at any range (the distance along the line stands in for the range: the
/// survey's views stand near the lines). Three asks for a near view or two far ones, and
/// more than the odd stray point.
const LENGTH_PROBE: LengthProbe = LengthProbe {
    radius: 0.05,
    spread: 0.02,
    window: 0.08,
    min_points: 3,
};
/// Joint readings kept for interpolating the table's angle.
const JOINT_HISTORY: usize = 64;

/// The mapper when the scenario has `[scan3d]`.
pub fn node(s: &Scenario, seed: u64) -> Result<Option<Scan3dNode>> {
    let Some(m) = s.module::<Scan3dSpec>() else {
        return Ok(None);
    };
    let laser = |n: &str| {
        s.lidars
            .iter()
            .find(|(c, _)| c.name == n)
            .map(|(c, _)| c)
            .with_context(|| format!("scan3d: no laser is named `{n}`"))
    };
    let horizontal = laser(&m.horizontal)?;
    let mount = node_mount(s, m)?;
    Ok(Some(Scan3dNode {
        icp: (m.pose_source == Scan3dPose::LineIcp)
            .then(|| LineIcp::new(m.config.line_icp, s.start, s.start)),
        mapper: StopAndScan::new(m.config.clone(), mount),
        planning: m.planning.clone(),
        plans: Vec::new(),
        rng: <ChaCha8Rng as rand::SeedableRng>::seed_from_u64(seed),
        completeness: surfaces_to_map(s, &m.planning.region)?,
        lengths: m
            .lengths
            .iter()
            .map(|l| {
                let back = l.direction.map(|c| -c);
                let cast = |d| futago_sim::world::export::cast_static(&s.world, l.from, d, 1e3);
                let truth = cast(l.direction).zip(cast(back)).map(|(a, b)| a + b);
                (l.clone(), truth)
            })
            .collect(),
        curve: Vec::new(),
        travel: 0.0,
        last_truth: None,
        ticked: false,
        view_truth: None,
        view_started: false,
        view_done: false,
        guess_errors: Vec::new(),
        views_scored: 0,
        coverage_from: 0,
        band: m.planning.band,
        vertical: m.laser.clone(),
        horizontal: m.horizontal.clone(),
        horizontal_mount: horizontal.planar_mount(),
        horizontal_height: horizontal.xyz[2],
        slice: Vec::new(),
        sliced: 0,
        joint: m.joint.clone(),
        source: m.pose_source,
        joint_history: VecDeque::new(),
        placed: Vec::new(),
        kept_moved: 0,
        last_placed: None,
        sweep_seconds: Vec::new(),
        sweep_started: None,
        view_errors: Vec::new(),
        scenario: s.spec.name.clone(),
        has_movers: !(s.movers.agents.is_empty()
            && s.movers.people.is_empty()
            && s.movers.flows.is_empty()),
    }))
}

/// The turntable's geometry: the joint's axis and origin, the vertical laser's mount.
fn node_mount(s: &Scenario, m: &Scan3dSpec) -> Result<TableMount> {
    let vertical = s
        .lidars
        .iter()
        .find(|(c, _)| c.name == m.laser)
        .map(|(c, _)| c)
        .with_context(|| format!("scan3d: no laser is named `{}`", m.laser))?;
    let joint = s
        .movers
        .joints
        .iter()
        .find(|j| j.name == m.joint)
        .with_context(|| format!("scan3d: no joint is named `{}`", m.joint))?;
    let mount = vertical.mount();
    Ok(TableMount {
        axis: DVec3::from_array(joint.axis),
        origin: DVec3::from_array(joint.origin),
        laser: DAffine3::from_rotation_translation(
            DQuat::from_xyzw(
                mount.rotation.x as f64,
                mount.rotation.y as f64,
                mount.rotation.z as f64,
                mount.rotation.w as f64,
            )
            .normalize(),
            DVec3::new(
                mount.translation.x as f64,
                mount.translation.y as f64,
                mount.translation.z as f64,
            ),
        ),
    })
}

/// A placed scan's points (map frame) with the index of the beam that measured each.
type BeamPoints = Vec<([f64; 3], usize)>;

/// A placed scan's points with what each beam hit.
struct Labelled {
    stamp: Time,
    points: Vec<([f64; 3], bool)>,
}

/// Seed 004's mapper in the loop.
pub struct Scan3dNode {
    mapper: StopAndScan,
    /// The seed's localiser, when it places the scans.
    icp: Option<LineIcp>,
    vertical: String,
    horizontal: String,
    horizontal_mount: Pose2,
    /// The horizontal laser's height above the floor, m, and the 3D map's slice about it (map
    /// frame) that the seed's localiser matches against after each view, gathered from the
    /// kept scans before `sliced`.
    horizontal_height: f64,
    slice: Vec<[f64; 2]>,
    sliced: usize,
    joint: String,
    source: Scan3dPose,
    /// The table's angle as its encoder reported it (time, rad).
    joint_history: VecDeque<(Time, f64)>,
    /// Every placed scan's points, each with whether a mover was hit (truth, for scoring);
    /// a kept scan's as it entered the map (see [`move_to_map`]).
    placed: Vec<Labelled>,
    /// Kept scans whose points `placed` holds as they entered the map.
    kept_moved: usize,
    /// The last vertical scan placed, waiting for its truth: its stamp and beam indices.
    last_placed: Option<(Time, BeamPoints)>,
    /// Simulated seconds each view's sweep took, pauses included.
    sweep_seconds: Vec<f64>,
    sweep_started: Option<Time>,
    /// Each view's placing pose against the truth: position (m) and heading (°) errors; and
    /// those of the pose the sweep was taken at, before registration.
    view_errors: Vec<(f64, f64)>,
    guess_errors: Vec<(f64, f64)>,
    scenario: String,
    /// Whether anything in the world moves (the dynamic measures exist only then).
    has_movers: bool,
    /// The map's completeness against the true surfaces of the area to map.
    completeness: Completeness,
    /// The lengths to measure, with their truth (`None`: the world has no surface there).
    lengths: Vec<(MapLength, Option<f64>)>,
    /// After each view: views, distance driven (m, true), coverage.
    curve: Vec<(usize, f64, f64)>,
    /// Distance driven so far (m, true) and the last true pose.
    travel: f64,
    last_truth: Option<Pose2>,
    /// A control tick happened, for the scorer to look at.
    ticked: bool,
    /// A view's sweep just began, or just entered the map, for the scorer to look at; the
    /// true pose when it began.
    view_started: bool,
    view_done: bool,
    view_truth: Option<Pose2>,
    /// Views whose points the coverage has taken.
    views_scored: usize,
    /// Placed scans before this one the coverage has taken.
    coverage_from: usize,
    /// The height band the 2D grid is compressed from, m.
    band: [f64; 2],
    /// View planning, when the views are not given; the views planned; the random
    /// planner's draws.
    planning: ViewPlanningConfig,
    plans: Vec<View>,
    rng: ChaCha8Rng,
}

/// Moves the points of the `placed` scans that entered the map as `kept` (matched by stamp)
/// to where they entered it. A sweep's scans are placed by the view's pose as they come;
/// registration then moves the whole sweep before it enters the map (the dropped scans of a
/// paused sweep entered the carving map as placed, and stay so). The coverage, the removal
/// scores and the raw map are of the map as built; scored at the pose before registration,
/// the coverage of a survey on its own poses measured a map it never held.
fn move_to_map(placed: &mut [Labelled], kept: &[PlacedScan]) {
    if kept.is_empty() {
        return;
    }
    let at: FxHashMap<i64, usize> = placed
        .iter()
        .enumerate()
        .map(|(k, s)| (s.stamp.0, k))
        .collect();
    for s in kept {
        let Some(l) = at.get(&s.stamp.0).map(|&k| &mut placed[k]) else {
            continue;
        };
        // The same beams in the same order (both are the scan's returns as placed).
        if l.points.len() == s.points.len() {
            for ((p, _), (q, _)) in l.points.iter_mut().zip(&s.points) {
                *p = *q;
            }
        }
    }
}

/// The true surfaces of the area to map: the world's floor, walls and furniture faces near
/// floor the robot can reach from its start (within `region` when one is given).
fn surfaces_to_map(s: &Scenario, region: &[[f64; 2]]) -> Result<Completeness> {
    use futago_robot::navigation::coverage::{Field, ROBOT_RADIUS, inside_polygon};
    let mut grid = futago_sim::world::export::occupancy_grid(
        &s.world,
        INTERIOR_CELL,
        FLOOR_Z,
        2.0,
        INTERIOR_REACH,
    )
    .map_err(|e| anyhow::anyhow!("scan3d: {e}"))?;
    if !region.is_empty() {
        for j in 0..grid.height {
            for i in 0..grid.width {
                if !inside_polygon(region, grid.cell_center(i, j)) {
                    grid.set(i, j, 100);
                }
            }
        }
    }
    let start = [s.start.x, s.start.y];
    let field = Field::new(&grid, ROBOT_RADIUS, start)
        .map_err(|e| anyhow::anyhow!("scan3d: the area to map: {e}"))?;
    let reach =
        futago_robot::geometry::grid::squared_edt(&field.reachable, grid.width, grid.height);
    let near = |p: [f64; 2]| {
        grid.cell_of(p[0], p[1]).is_some_and(|(i, j)| {
            reach[j * grid.width + i].sqrt() * INTERIOR_CELL <= INTERIOR_REACH
        })
    };
    let surfaces = Surfaces::from_world(&s.world, f64::INFINITY, None, near, |_| None, |_, _| true);
    Ok(Completeness::new(&surfaces, COVERAGE_TOLERANCE))
}

impl Scan3dNode {
    fn pose(&self, bus: &Bus) -> Pose2 {
        match (self.source.node(), &self.icp) {
            (Some(source), _) => bus.pose_from(source),
            // The seed's own estimate, carried to now by odometry.
            (None, Some(icp)) => {
                let (pose, at) = icp.pose();
                pose.compose(&at.between(&bus.odometry))
            }
            (None, None) => bus.odometry,
        }
    }

    /// The table's angle at `t`, interpolated between encoder readings (the nearest at the
    /// ends).
    fn table_at(&self, t: Time) -> Option<f64> {
        let h = &self.joint_history;
        let k = h.iter().position(|(s, _)| *s >= t);
        match k {
            None => h.back().map(|x| x.1),
            Some(0) => h.front().map(|x| x.1),
            Some(k) => {
                let (t0, a0) = h[k - 1];
                let (t1, a1) = h[k];
                let f = (t - t0).secs() / (t1 - t0).secs().max(1e-12);
                Some(a0 + f * (a1 - a0))
            }
        }
    }

    /// A view's sweep has entered the map: the seed's localiser, if it places the scans,
    /// takes the registration's correction and matches from now on against the map's slice
    /// at its laser's height.
    fn relocalise(&mut self, bus: &mut Bus) {
        let Some(icp) = &mut self.icp else {
            return;
        };
        let (h, band) = (self.horizontal_height, icp.config().slice);
        let kept = self.mapper.kept();
        self.slice.extend(
            kept[self.sliced..]
                .iter()
                .flat_map(|s| s.points.iter())
                .filter(|(p, _)| (p[2] - h).abs() <= band)
                .map(|(p, _)| [p[0], p[1]]),
        );
        self.sliced = kept.len();
        let (est, at) = icp.pose();
        let mut now = est.compose(&at.between(&bus.odometry));
        if let Some(Some(r)) = self.mapper.registrations().last()
            && !r.refused
        {
            now = r.pose.compose(&r.guess.inverse()).compose(&now);
        }
        icp.reset(now, bus.odometry, &self.slice);
        bus.publish_pose("localization", now, bus.odometry);
    }

    fn table_now(&self, bus: &Bus) -> f64 {
        bus.joints
            .iter()
            .find(|(n, _)| *n == self.joint)
            .map_or(0.0, |(_, a)| *a)
    }
}

impl Scan3dNode {
    /// Plans the next view from the last one on the 2D grid compressed from the kept scans'
    /// voxel map, and hands it to the mapper; ends the survey at `max_views`, or when no view
    /// would measure enough that is new.
    fn plan_view(&mut self) {
        let views = self.mapper.views();
        let view = (views.len() < self.planning.max_views)
            .then(|| {
                let (carved_kept, _) = self.mapper.voxel_maps();
                let grid = carved_kept.project(self.band[0], self.band[1])?;
                let last = views.last()?;
                let visited: Vec<[f64; 2]> = views.iter().map(|v| [v.x, v.y]).collect();
                next_view(
                    &grid,
                    [last.x, last.y],
                    &visited,
                    &self.planning,
                    &mut self.rng,
                )
            })
            .flatten();
        self.mapper
            .plan_view(view.as_ref().map(|v| (v.position, v.route.clone())));
        self.plans.extend(view);
    }

    /// Adds the static points of the views completed since the last call to the coverage,
    /// and reads the curve.
    fn score_views(&mut self) {
        let views = self.mapper.stats().views;
        if views == self.views_scored {
            return;
        }
        let kept = self.mapper.kept();
        move_to_map(&mut self.placed, &kept[self.kept_moved..]);
        self.kept_moved = kept.len();
        let kept: FxHashSet<i64> = kept.iter().map(|s| s.stamp.0).collect();
        // The placed scans not yet taken, kept in the map, static points only.
        let from = self.coverage_from;
        let points = self.placed[from..]
            .iter()
            .filter(|s| kept.contains(&s.stamp.0))
            .flat_map(|s| s.points.iter().filter(|(_, m)| !m).map(|(p, _)| *p));
        self.completeness.add(points);
        self.coverage_from = self.placed.len();
        self.views_scored = views;
        self.curve
            .push((views, self.travel, self.completeness.share()));
    }

    /// The kept scans' points, and those of them carving keeps (the map as written).
    fn maps(&self) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
        let (carved_kept, _) = self.mapper.voxel_maps();
        let kept: Vec<[f64; 3]> = self
            .mapper
            .kept()
            .iter()
            .flat_map(|s| s.points.iter().map(|(p, _)| *p))
            .collect();
        let carved = carved_kept.keep_static(&kept);
        (kept, carved)
    }

    /// Each length's name, truth and measure in the carved map `carved` (m; `None` where
    /// there is no surface).
    fn measured_lengths(&self, carved: &[[f64; 3]]) -> Vec<(String, Option<f64>, Option<f64>)> {
        self.lengths
            .iter()
            .map(|(l, truth)| {
                let measured = length_along(carved, l.from, l.direction, LENGTH_PROBE);
                (l.name.clone(), *truth, measured)
            })
            .collect()
    }

    /// The views and the distance driven when the coverage first reached [`COVERAGE_MARK`].
    fn to_mark(&self) -> Option<(usize, f64)> {
        self.curve
            .iter()
            .find(|c| c.2 >= COVERAGE_MARK)
            .map(|c| (c.0, c.1))
    }
}

impl Node for Scan3dNode {
    fn name(&self) -> &'static str {
        "scan3d"
    }

    fn streams(&self) -> Streams {
        let mut consumes = vec![
            "odometry".to_string(),
            format!("scan/{}", self.vertical),
            format!("scan/{}", self.horizontal),
            super::bus::ROUTE_DONE.to_string(),
        ];
        consumes.extend(self.source.node().and_then(super::bus::pose_topic));
        let mut publishes = vec!["path/scan3d".into(), format!("joint/{}", self.joint)];
        if self.icp.is_some() {
            publishes.push("pose/localization".into());
        }
        Streams {
            consumes,
            publishes,
            ..Streams::default()
        }
    }

    fn on_odometry(&mut self, _o: &Odometry, bus: &mut Bus) -> Result<()> {
        let a = self.table_now(bus);
        self.joint_history.push_back((bus.now, a));
        while self.joint_history.len() > JOINT_HISTORY {
            self.joint_history.pop_front();
        }
        Ok(())
    }

    fn on_scan(&mut self, laser: &str, scan: &LaserScan, bus: &mut Bus) -> Result<()> {
        if laser == self.horizontal {
            let at = bus.odometry.compose(&self.horizontal_mount);
            let movers = self.mapper.on_horizontal(scan, &at, bus.now);
            if let Some(icp) = &mut self.icp {
                if let Some((t, positions)) = movers {
                    icp.movers(t, &positions);
                }
                let pose = icp.update(scan, &self.horizontal_mount, bus.odometry);
                bus.publish_pose("localization", pose, bus.odometry);
            }
        } else if laser == self.vertical {
            // The table's angle halfway through the scan's sweep.
            let mid = scan.stamp
                + futago_msgs::Duration::from_secs(
                    scan.time_increment * scan.ranges.len() as f64 / 2.0,
                );
            let angle = self.table_at(mid).unwrap_or_else(|| self.table_now(bus));
            self.last_placed = self
                .mapper
                .on_vertical(scan, angle)
                .map(|p| (p.stamp, p.points.clone()));
        }
        Ok(())
    }

    fn on_scan_truth(&mut self, laser: &str, hits: &[BeamHit]) {
        if laser != self.vertical {
            return;
        }
        if let Some((stamp, points)) = self.last_placed.take() {
            self.placed.push(Labelled {
                stamp,
                points: points
                    .into_iter()
                    .map(|(p, i)| (p, hits.get(i).is_some_and(|h| h.is_mover())))
                    .collect(),
            });
        }
    }

    fn on_control(&mut self, bus: &mut Bus) -> Result<()> {
        self.ticked = true;
        let mut pose = self.pose(bus);
        let table = self.table_now(bus);
        let was_sweeping = self.sweep_started.is_some();
        let views = self.mapper.views().len();
        let mut r = self.mapper.control(bus.now, pose, bus.route_done, table);
        if self.mapper.views().len() > views {
            self.view_done = true;
            self.relocalise(bus);
            pose = self.pose(bus);
        }
        if matches!(self.mapper.phase(), Phase::Planning { .. }) {
            self.plan_view();
            r = self.mapper.control(bus.now, pose, bus.route_done, table);
        }
        if let Some(route) = r.route {
            bus.publish_path("scan3d", route);
        }
        if let Some(a) = r.table {
            bus.joint_commands.push((self.joint.clone(), a));
        }
        let sweeping = matches!(
            self.mapper.phase(),
            Phase::Sweeping { .. } | Phase::Paused { .. }
        );
        match (was_sweeping, sweeping) {
            (false, true) => {
                self.sweep_started = Some(bus.now);
                self.view_started = true;
            }
            (true, false) => {
                if let Some(t) = self.sweep_started.take() {
                    self.sweep_seconds.push((bus.now - t).secs());
                }
            }
            _ => {}
        }
        Ok(())
    }

    /// After a control tick: the distance truly driven, the error of a view's pose, and the
    /// map's completeness when a view was added.
    fn observe(&mut self, truth: &TrueState, _bus: &Bus) {
        if !std::mem::take(&mut self.ticked) {
            return;
        }
        let r = truth.robot;
        if let Some(p) = self.last_truth {
            self.travel += (r.x - p.x).hypot(r.y - p.y);
        }
        self.last_truth = Some(r);
        // The pose the view's scans are placed by, and the one its sweep was taken at,
        // against the truth when the sweep began (the robot stands through it).
        if std::mem::take(&mut self.view_started) {
            self.view_truth = Some(r);
        }
        if std::mem::take(&mut self.view_done)
            && let (Some(t), Some(placed)) = (self.view_truth.take(), self.mapper.views().last())
        {
            let guess = match self.mapper.registrations().last() {
                Some(Some(g)) => g.guess,
                _ => *placed,
            };
            let error = |p: &Pose2| {
                let e = p.between(&t);
                (e.x.hypot(e.y), e.theta.abs().to_degrees())
            };
            self.view_errors.push(error(placed));
            self.guess_errors.push(error(&guess));
        }
        self.score_views();
    }

    fn finished(&self) -> bool {
        self.mapper.finished()
    }

    fn finish(&mut self, _bus: &mut Bus, out: Option<&Path>) -> Result<Report> {
        let (carved_kept, _) = self.mapper.voxel_maps();
        let (kept, carved) = self.maps();
        let grid = carved_kept.project(self.band[0], self.band[1]);
        let stats = self.mapper.stats();
        let summary = json!({
            "views": stats.views,
            "pauses": stats.pauses,
            "pause_timeouts": stats.timeouts,
            "scans_kept": stats.scans_kept,
            "scans_dropped": stats.scans_dropped,
            "points": kept.len(),
            "points_carved": carved.len(),
            "sweep_s": self.sweep_seconds,
            "voxels_known": carved_kept.len(),
            "view_poses": self.mapper.views().iter().map(|p| [p.x, p.y, p.theta]).collect::<Vec<_>>(),
            "view_errors": self.view_errors.iter().map(|(p, h)| json!({ "position_m": p, "heading_deg": h })).collect::<Vec<_>>(),
            "view_errors_unregistered": self.guess_errors.iter().map(|(p, h)| json!({ "position_m": p, "heading_deg": h })).collect::<Vec<_>>(),
            "registrations": self.mapper.registrations().iter().map(|r| r.map(|r| {
                let d = r.guess.between(&r.pose);
                json!({
                    "sweep_surfels": r.sweep_surfels,
                    "map_surfels": r.map_surfels,
                    "pairs": r.pairs,
                    "iterations": r.iterations,
                    "refused": r.refused,
                    "degenerate": r.degenerate,
                    "correction": [d.x, d.y, d.theta],
                })
            })).collect::<Vec<_>>(),
            "points_left_out_for_movers": self.icp.as_ref().map(|i| i.left_out()),
            "planned_views": self.plans.iter().map(|v| json!({
                "position": v.position,
                "new_cells": v.new_cells,
                "v1": v.terms[0], "v2": v.terms[1], "v3": v.terms[2],
            })).collect::<Vec<_>>(),
            "travel_m": self.travel,
            "surface_area_m2": self.completeness.area(),
            "coverage_by_class": self.completeness.shares().into_iter().collect::<std::collections::BTreeMap<_, _>>(),
            "coverage_curve": self.curve.iter().map(|(v, t, c)| json!({ "views": v, "travel_m": t, "coverage": c })).collect::<Vec<_>>(),
            "views_to_95": self.to_mark().map(|m| m.0),
            "travel_to_95_m": self.to_mark().map(|m| m.1),
            "lengths": self.measured_lengths(&carved).into_iter().map(|(n, t, m)| json!({ "name": n, "truth_m": t, "measured_m": m })).collect::<Vec<_>>(),
        });
        let mut files = Vec::new();
        if let Some(dir) = out {
            let grey = |p: &[f64; 3]| (*p, [160, 160, 160]);
            let comment = format!("futago scan3d map of {}", self.scenario);
            let write = |name: &str, bytes: Vec<u8>| {
                std::fs::write(dir.join(name), bytes).with_context(|| format!("writing {name}"))
            };
            write(
                SCAN3D_MAP_FILE,
                futago_msgs::ply::points(&kept.iter().map(grey).collect::<Vec<_>>(), &comment),
            )?;
            write(
                SCAN3D_CARVED_FILE,
                futago_msgs::ply::points(&carved.iter().map(grey).collect::<Vec<_>>(), &comment),
            )?;
            let raw: Vec<([f64; 3], [u8; 3])> = self
                .placed
                .iter()
                .flat_map(|s| s.points.iter())
                .map(|(p, m)| (*p, if *m { [220, 40, 40] } else { [160, 160, 160] }))
                .collect();
            write(
                SCAN3D_RAW_FILE,
                futago_msgs::ply::points(
                    &raw,
                    &format!("{comment}: every sweep's points, red on movers"),
                ),
            )?;
            files.extend([
                SCAN3D_MAP_FILE.to_string(),
                SCAN3D_CARVED_FILE.to_string(),
                SCAN3D_RAW_FILE.to_string(),
            ]);
            if let Some(g) = &grid {
                g.write_map_server(dir, SCAN3D_GRID_STEM)
                    .with_context(|| format!("writing {SCAN3D_GRID_STEM}.pgm and .yaml"))?;
                files.extend([
                    format!("{SCAN3D_GRID_STEM}.pgm"),
                    format!("{SCAN3D_GRID_STEM}.yaml"),
                ]);
            }
        }
        Ok(Report {
            summary: vec![("scan3d".into(), summary)],
            files,
            map: grid,
            ..Report::default()
        })
    }

    fn score(&self, _truth: &Truth) -> Result<Metrics> {
        let mut m = Metrics::default();
        let stats = self.mapper.stats();
        m.insert("scan3d.views", stats.views as f64);
        m.insert("scan3d.pauses", stats.pauses as f64);
        m.insert("scan3d.coverage", self.completeness.share());
        m.insert("scan3d.travel_m", self.travel);
        let mark = self.to_mark();
        m.insert("scan3d.views_to_95", mark.map_or(f64::NAN, |x| x.0 as f64));
        m.insert("scan3d.travel_to_95_m", mark.map_or(f64::NAN, |x| x.1));
        // How far from the truth the views' scans were placed (none placed: not a number).
        let n = self.view_errors.len();
        let of = |f: fn(&(f64, f64)) -> f64, mean: bool| {
            let v = self.view_errors.iter().map(f);
            match (n, mean) {
                (0, _) => f64::NAN,
                (_, true) => v.sum::<f64>() / n as f64,
                (_, false) => v.fold(0.0, f64::max),
            }
        };
        m.insert("scan3d.view_error.position_max_m", of(|e| e.0, false));
        m.insert("scan3d.view_error.position_mean_m", of(|e| e.0, true));
        m.insert("scan3d.view_error.heading_max_deg", of(|e| e.1, false));
        let carved = if self.lengths.is_empty() {
            Vec::new()
        } else {
            self.maps().1
        };
        for (name, truth, measured) in self.measured_lengths(&carved) {
            let e = match (truth, measured) {
                (Some(t), Some(v)) => v - t,
                _ => f64::NAN,
            };
            m.insert(format!("scan3d.length.{name}.error_m"), e);
            m.insert(format!("scan3d.length.{name}.abs_error_m"), e.abs());
        }
        // The points of every placed scan, by stamp, and which were kept.
        let kept: FxHashSet<i64> = self.mapper.kept().iter().map(|s| s.stamp.0).collect();
        let (carved_kept, carved_all) = self.mapper.voxel_maps();
        let occupied = |map: &VoxelMap, p: &[f64; 3]| map.keeps(map.key(*p));
        for name in ["pause", "carving", "pause_carving"] {
            let score = removal_scores(&self.placed, |s, p| match name {
                "pause" => kept.contains(&s.stamp.0),
                "carving" => occupied(carved_all, p),
                _ => kept.contains(&s.stamp.0) && occupied(carved_kept, p),
            });
            m.insert(format!("scan3d.{name}.sa"), score.sa);
            m.insert(format!("scan3d.{name}.sa_floor"), score.sa_floor);
            m.insert(format!("scan3d.{name}.sa_structure"), score.sa_structure);
            m.insert(format!("scan3d.{name}.pr"), score.pr);
            if self.has_movers {
                m.insert(format!("scan3d.{name}.da"), score.da);
                m.insert(format!("scan3d.{name}.aa"), (score.sa * score.da).sqrt());
                m.insert(format!("scan3d.{name}.rr"), score.rr);
                let f1 = if score.pr + score.rr > 0.0 {
                    2.0 * score.pr * score.rr / (score.pr + score.rr)
                } else {
                    0.0
                };
                m.insert(format!("scan3d.{name}.f1"), f1);
            }
        }
        Ok(m)
    }
}

/// Seed 004's 3D scan, timed by parts (`futago bench scan3d`): one full sweep of the
/// scenario's turntable at its start, simulated (physics, both lasers, the people) with the
/// robot standing; the sweep's scans placed; both voxel maps and the surfels updated (the map
/// update); free-space carving of the sweep's points (the removal); the next view planned on
/// the compressed grid; and the sweep registered against the surfels of its own map (what a
/// later view's registration costs). Wall seconds of each part, the median of `repeats`.
pub fn bench(s: &Scenario, repeats: usize) -> Result<serde_json::Value> {
    use futago_robot::mapping::turntable::Phase;
    use std::time::Instant;
    let m = s
        .module::<Scan3dSpec>()
        .context("the scenario has no [scan3d] to time")?;
    let vertical = s
        .lidars
        .iter()
        .position(|(c, _)| c.name == m.laser)
        .context("scan3d.laser")?;
    let joint = s
        .movers
        .joints
        .iter()
        .find(|j| j.name == m.joint)
        .context("scan3d: the table's joint")?;
    let median = |mut t: Vec<f64>| {
        t.sort_by(f64::total_cmp);
        t[t.len() / 2]
    };
    let (mut sim_s, mut place_s, mut update_s, mut removal_s, mut plan_s, mut register_s) = (
        Vec::new(),
        Vec::new(),
        Vec::new(),
        Vec::new(),
        Vec::new(),
        Vec::new(),
    );
    let (mut scans, mut points) = (0, 0);
    for k in 0..repeats.max(1) {
        let seed = s.spec.seed + k as u64;
        let mut node = node(s, seed)?.context("scan3d")?;
        // One view where the robot stands: no stops to drive to.
        let mut config = m.config.clone();
        config.stops = vec![[s.start.x, s.start.y]];
        node.mapper = StopAndScan::new(config.clone(), node_mount(s, m)?);
        let mut sim = s.simulation(seed);
        let t = Time::from_secs;
        let pose = s.start;
        // Asked for the route, driven it (standing there), settled: the sweep begins.
        node.mapper.control(t(0.0), pose, None, 0.0);
        node.mapper.control(t(0.1), pose, Some(t(0.1)), 0.0);
        let r = node
            .mapper
            .control(t(0.1 + config.settle), pose, Some(t(0.1)), 0.0);
        let to = r.table.context("the sweep did not begin")?;
        sim.command_joint(&m.joint, to)
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        let angle = |sim: &futago_sim::Simulation| {
            sim.joints()
                .iter()
                .find(|j| j.config.name == joint.name)
                .map_or(0.0, |j| j.angle())
        };
        // Simulate the sweep, keeping the vertical scans with the table's angle.
        let t0 = Instant::now();
        let mut taken = Vec::new();
        let limit = (config.sweep_deg / joint.rate_deg).abs() * 2.0 + 1.0;
        let mut now = 0.0;
        while (angle(&sim) - to).abs() > 1e-6 && now < limit {
            let out = sim.step(None);
            now += 1.0 / s.spec.physics.rate;
            for (i, scan) in out.scans {
                if i == vertical {
                    taken.push((scan, angle(&sim)));
                }
            }
        }
        sim_s.push(t0.elapsed().as_secs_f64());
        // Place them.
        let t0 = Instant::now();
        for (scan, a) in &taken {
            node.mapper.on_vertical(scan, *a);
        }
        place_s.push(t0.elapsed().as_secs_f64());
        // Complete the sweep: both voxel maps take its scans.
        let t0 = Instant::now();
        node.mapper.control(t(now), pose, None, to);
        update_s.push(t0.elapsed().as_secs_f64());
        if node.mapper.phase() != Phase::Done {
            anyhow::bail!("the sweep did not complete in {limit} s");
        }
        let kept: Vec<[f64; 3]> = node
            .mapper
            .kept()
            .iter()
            .flat_map(|s| s.points.iter().map(|(p, _)| *p))
            .collect();
        let (carved_kept, _) = node.mapper.voxel_maps();
        let t0 = Instant::now();
        let carved = carved_kept.keep_static(&kept);
        removal_s.push(t0.elapsed().as_secs_f64());
        let t0 = Instant::now();
        let band = m.planning.band;
        let grid = carved_kept.project(band[0], band[1]);
        let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(seed);
        let view = grid.as_ref().and_then(|g| {
            futago_robot::navigation::views::next_view(
                g,
                [pose.x, pose.y],
                &[[pose.x, pose.y]],
                &m.planning,
                &mut rng,
            )
        });
        plan_s.push(t0.elapsed().as_secs_f64());
        // Register the sweep against the surfels of the map it made: what each later view's
        // registration costs, pairing included.
        let back = pose.inverse();
        let local: Vec<[f64; 3]> = kept
            .iter()
            .map(|p| futago_robot::mapping::registration::place(&back, *p))
            .collect();
        let t0 = Instant::now();
        let registered = node.mapper.surfels().register(&local, pose);
        register_s.push(t0.elapsed().as_secs_f64());
        let _ = registered;
        scans = taken.len();
        points = kept.len();
        let _ = (carved, view);
    }
    Ok(json!({
        "scenario": s.spec.name,
        "repeats": repeats.max(1),
        "scans_per_sweep": scans,
        "points_per_sweep": points,
        "simulation_s": median(sim_s),
        "placing_s": median(place_s),
        "map_update_s": median(update_s),
        "removal_s": median(removal_s),
        "view_planning_s": median(plan_s),
        "registration_s": median(register_s),
    }))
}

/// A removal's scores against the labels (shares in 0 … 1; a share of nothing is 1).
#[derive(Debug, Clone, Copy, PartialEq)]
struct RemovalScores {
    sa: f64,
    sa_floor: f64,
    sa_structure: f64,
    da: f64,
    pr: f64,
    rr: f64,
}

/// Scores a removal that keeps the point `p` of scan `s` when `keeps(s, p)`.
///
/// The removal's output is matched to the measured cloud voxel by voxel, class by class: a
/// static point is preserved when the output holds a static point in its voxel, and a
/// dynamic point is removed when the output holds no dynamic point in its voxel. For SA and
/// DA the voxels are the map's [`MATCH_VOXEL`]; for PR and RR they are ERASOR's 0.2 m, each
/// voxel counted once. So the seed's pausing is not charged for the static points of the
/// scans it dropped where it measured the same surface again, and carving, which keeps or
/// drops whole voxels, is scored as it works.
fn removal_scores(
    scans: &[Labelled],
    keeps: impl Fn(&Labelled, &[f64; 3]) -> bool,
) -> RemovalScores {
    let share = |k: usize, n: usize| if n == 0 { 1.0 } else { k as f64 / n as f64 };
    let key = |p: &[f64; 3], size: f64| p.map(|c| (c / size).floor() as i64);
    // The output's voxels, by class and voxel size.
    let mut out: [FxHashSet<[i64; 3]>; 4] = Default::default();
    for s in scans {
        for (p, mover) in &s.points {
            if keeps(s, p) {
                let m = *mover as usize;
                out[m].insert(key(p, MATCH_VOXEL));
                out[2 + m].insert(key(p, SCORE_VOXEL));
            }
        }
    }
    let (mut st, mut st_kept, mut fl, mut fl_kept, mut dy, mut dy_kept) = (0, 0, 0, 0, 0, 0);
    // ERASOR's voxels of each class: whether the output holds one of its class there.
    let mut static_voxels: FxHashMap<[i64; 3], bool> = FxHashMap::default();
    let mut dynamic_voxels: FxHashMap<[i64; 3], bool> = FxHashMap::default();
    for s in scans {
        for (p, mover) in &s.points {
            let (fine, coarse) = (key(p, MATCH_VOXEL), key(p, SCORE_VOXEL));
            if *mover {
                dy += 1;
                dy_kept += out[1].contains(&fine) as usize;
                dynamic_voxels.insert(coarse, out[3].contains(&coarse));
            } else {
                let kept = out[0].contains(&fine) as usize;
                st += 1;
                st_kept += kept;
                if p[2] <= FLOOR_Z {
                    fl += 1;
                    fl_kept += kept;
                }
                static_voxels.insert(coarse, out[2].contains(&coarse));
            }
        }
    }
    RemovalScores {
        sa: share(st_kept, st),
        sa_floor: share(fl_kept, fl),
        sa_structure: share(st_kept - fl_kept, st - fl),
        da: share(dy - dy_kept, dy),
        pr: share(
            static_voxels.values().filter(|k| **k).count(),
            static_voxels.len(),
        ),
        rr: share(
            dynamic_voxels.values().filter(|k| !**k).count(),
            dynamic_voxels.len(),
        ),
    }
}

/// The metrics this node scores.
fn metric_names(s: &ScenarioSpec, spec: &Scan3dSpec) -> Vec<String> {
    let movers = !(s.agent.is_empty() && s.person.is_empty() && s.flow.is_empty());
    let mut names: Vec<String> = [
        "scan3d.views",
        "scan3d.pauses",
        "scan3d.coverage",
        "scan3d.travel_m",
        "scan3d.views_to_95",
        "scan3d.travel_to_95_m",
        "scan3d.view_error.position_max_m",
        "scan3d.view_error.position_mean_m",
        "scan3d.view_error.heading_max_deg",
    ]
    .map(String::from)
    .to_vec();
    for l in &spec.lengths {
        names.push(format!("scan3d.length.{}.error_m", l.name));
        names.push(format!("scan3d.length.{}.abs_error_m", l.name));
    }
    for method in ["pause", "carving", "pause_carving"] {
        let mut keys = vec!["sa", "sa_floor", "sa_structure", "pr"];
        if movers {
            keys.extend(["da", "aa", "rr", "f1"]);
        }
        names.extend(keys.iter().map(|k| format!("scan3d.{method}.{k}")));
    }
    names
}

/// `[scan3d]`: `laser` (the vertical laser on the turntable), `horizontal` (the laser that
/// watches for movers and, by default, localises), `pose_source` (default `line_icp`, the
/// seed's) and the mapper's own keys ([`TurntableConfig`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Scan3dSpec {
    pub laser: String,
    pub horizontal: String,
    /// The joint the vertical laser rides on (resolved from the laser).
    pub joint: String,
    pub pose_source: Scan3dPose,
    pub config: TurntableConfig,
    /// Lengths to measure in the map against the world (`[[scan3d.length]]`; scoring).
    pub lengths: Vec<MapLength>,
    /// View planning, when no `stops` are given (`scan3d.planning.*`).
    pub planning: futago_robot::navigation::views::ViewPlanningConfig,
}

/// A length of the building to measure in the 3D map, like seed 004's L1 and L2: from a
/// point in free space (map frame, m) along a direction, the distance between the first
/// surfaces on either side. The truth is cast in the world's static colliders.
#[derive(Debug, Clone, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct MapLength {
    /// Names the metrics `scan3d.length.NAME.*`: letters, digits, `_` and `-`.
    pub name: String,
    pub from: [f64; 3],
    pub direction: [f64; 3],
}

/// Which pose places seed 004's scans: another node's or the truth, or the seed's own
/// localisation on the horizontal laser (`line_icp`: odometry, then point-to-line ICP by
/// Nelder–Mead, `scan3d.line_icp.*`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Scan3dPose {
    GroundTruth,
    Odometry,
    Localization,
    Slam,
    #[default]
    LineIcp,
}

impl Scan3dPose {
    /// The node pose source it is, unless the seed's own `line_icp`.
    pub fn node(self) -> Option<PoseSource> {
        match self {
            Scan3dPose::GroundTruth => Some(PoseSource::GroundTruth),
            Scan3dPose::Odometry => Some(PoseSource::Odometry),
            Scan3dPose::Localization => Some(PoseSource::Localization),
            Scan3dPose::Slam => Some(PoseSource::Slam),
            Scan3dPose::LineIcp => None,
        }
    }
}

/// Types the `[scan3d]` table, naming `scan3d.KEY` in errors (the lasers and the joint are
/// checked against the scenario's in [`Scenario::load`]).
pub fn scan3d_config(path: &Path, table: &toml::Table) -> Result<Scan3dSpec, SpecError> {
    let mut rest = table.clone();
    let laser = take_name(path, "scan3d", "laser", &mut rest)?.ok_or_else(|| {
        SpecError::new(
            path,
            "scan3d.laser",
            "expected the name of the laser on the turntable, e.g. laser = \"vertical\"",
        )
    })?;
    let horizontal = take_name(path, "scan3d", "horizontal", &mut rest)?.ok_or_else(|| {
        SpecError::new(
            path,
            "scan3d.horizontal",
            "expected the name of the horizontal laser that watches for movers",
        )
    })?;
    let pose_source = match rest.remove("pose_source") {
        None => Scan3dPose::default(),
        Some(v) => Scan3dPose::deserialize(v.clone()).map_err(|_| {
            SpecError::new(
                path,
                "scan3d.pose_source",
                format!(
                    "expected one of \"line_icp\", \"ground_truth\", \"odometry\", \"localization\", \"slam\"; found {v}"
                ),
            )
        })?,
    };
    let lengths: Vec<MapLength> = match rest.remove("length") {
        None => Vec::new(),
        Some(v) => {
            let mut t = toml::Table::new();
            t.insert("length".into(), v);
            #[derive(Deserialize)]
            struct Lengths {
                length: Vec<MapLength>,
            }
            typed_table::<Lengths>(path, "scan3d", t)?.length
        }
    };
    for (i, l) in lengths.iter().enumerate() {
        let key = |k: &str| format!("scan3d.length[{i}].{k}");
        let ok_name = !l.name.is_empty()
            && l.name.len() <= 64
            && l.name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
        if !ok_name {
            return Err(SpecError::new(
                path,
                key("name"),
                format!(
                    "expected 1-64 letters, digits, `_` or `-`; found {:?}",
                    l.name
                ),
            ));
        }
        if lengths[..i].iter().any(|o| o.name == l.name) {
            return Err(SpecError::new(
                path,
                key("name"),
                format!("`{}` names two lengths", l.name),
            ));
        }
        if !l.from.iter().all(|c| c.is_finite() && c.abs() <= 1e6) {
            return Err(SpecError::new(
                path,
                key("from"),
                format!("expected a point in the map frame, m; found {:?}", l.from),
            ));
        }
        let n = l.direction.iter().map(|c| c * c).sum::<f64>().sqrt();
        if !(n.is_finite() && n > 1e-9) {
            return Err(SpecError::new(
                path,
                key("direction"),
                format!("expected a non-zero vector; found {:?}", l.direction),
            ));
        }
    }
    let planning = match rest.remove("planning") {
        None => Default::default(),
        Some(v) => {
            let mut t = toml::Table::new();
            t.insert("planning".into(), v);
            #[derive(Deserialize)]
            struct Planning {
                planning: futago_robot::navigation::views::ViewPlanningConfig,
            }
            typed_table::<Planning>(path, "scan3d", t)?.planning
        }
    };
    planning
        .validate("scan3d.planning")
        .map_err(|(k, m)| SpecError::new(path, k, m))?;
    let config: TurntableConfig = typed_table(path, "scan3d", rest)?;
    config
        .validate("scan3d")
        .map_err(|(k, m)| SpecError::new(path, k, m))?;
    Ok(Scan3dSpec {
        laser,
        horizontal,
        joint: String::new(),
        pose_source,
        config,
        lengths,
        planning,
    })
}

/// `[scan3d]`: seed 004's stop-and-scan 3D map from a laser on a turntable.
pub struct Module;

impl ModuleConfig for Module {
    fn key(&self) -> Option<&'static str> {
        Some("scan3d")
    }

    /// `pose/localization` when it localises by the seed's line ICP (its `pose_source`, the
    /// default); a value that does not parse publishes nothing (resolving names the error).
    fn pose_topic(&self, table: &toml::Value) -> Option<&'static str> {
        let source = match table.get("pose_source") {
            None => Scan3dPose::default(),
            Some(v) => Scan3dPose::deserialize(v.clone()).ok()?,
        };
        (source == Scan3dPose::LineIcp).then_some("localization")
    }

    fn pose_table(&self) -> Option<(&'static str, &'static str)> {
        Some(("localization", "[scan3d] (localising by its line ICP)"))
    }

    fn resolve(&self, cx: &Resolving<'_>, table: &toml::Value) -> Result<Spec, SpecError> {
        let path = cx.path;
        let mut m = scan3d_config(path, &cx.table("scan3d", table)?)?;
        let names: Vec<&str> = cx.lidars.iter().map(|(c, _)| c.name.as_str()).collect();
        let find = |key: &str, n: &str| {
            cx.lidars.iter().find(|(c, _)| c.name == n).ok_or_else(|| {
                SpecError::new(
                    path,
                    format!("scan3d.{key}"),
                    format!("no laser is named `{n}`; the scenario's lasers are {names:?}"),
                )
            })
        };
        let (vertical, _) = find("laser", &m.laser)?;
        let (horizontal, _) = find("horizontal", &m.horizontal)?;
        let joint = vertical
                    .joint
                    .as_ref()
                    .and_then(|j| cx.spec.joint.iter().find(|k| &k.name == j))
                    .ok_or_else(|| {
                        SpecError::new(
                            path,
                            "scan3d.laser",
                            format!(
                                "laser `{}` rides on no joint: the 3D scan turns it on a turntable ([[joint]] with mode = \"command\", and the laser's joint = NAME)",
                                m.laser
                            ),
                        )
                    })?;
        if joint.mode != futago_sim::joint::JointMode::Command {
            return Err(SpecError::new(
                path,
                "scan3d.laser",
                format!(
                    "joint `{}` must be mode = \"command\": the mapper turns the table itself, one sweep per view",
                    joint.name
                ),
            ));
        }
        if horizontal.joint.is_some() {
            return Err(SpecError::new(
                path,
                "scan3d.horizontal",
                format!(
                    "laser `{}` rides on a joint; the mover detector needs one fixed to the base",
                    m.horizontal
                ),
            ));
        }
        if let Some(source) = m.pose_source.node() {
            cx.require_pose(
                "scan3d.pose_source",
                source,
                "placing the scans by this pose",
            )?;
        }
        m.joint = joint.name.clone();
        Ok(Box::new(m))
    }

    fn effective(&self, spec: &(dyn Any + Send + Sync)) -> Option<toml::Table> {
        let r = spec.downcast_ref::<Scan3dSpec>()?;
        let mut m = toml::Table::try_from(&r.config).unwrap_or_default();
        m.insert("laser".into(), toml::Value::String(r.laser.clone()));
        m.insert(
            "horizontal".into(),
            toml::Value::String(r.horizontal.clone()),
        );
        if let Ok(v) = toml::Value::try_from(r.pose_source) {
            m.insert("pose_source".into(), v);
        }
        if let Ok(v) = toml::Value::try_from(&r.planning) {
            m.insert("planning".into(), v);
        }
        if !r.lengths.is_empty()
            && let Ok(v) = toml::Value::try_from(&r.lengths)
        {
            m.insert("length".into(), v);
        }
        Some(m)
    }

    fn metric_names(
        &self,
        spec: &ScenarioSpec,
        own: Option<&(dyn Any + Send + Sync)>,
    ) -> Vec<String> {
        super::own::<Scan3dSpec>(own)
            .map(|m| metric_names(spec, m))
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

    /// A kept scan moved by registration moves its labelled points with it, labels kept; a
    /// scan not kept (dropped in a pause) stays where it was placed.
    #[test]
    fn kept_scans_are_scored_where_they_entered_the_map() {
        let labelled = |t: f64, x: f64| Labelled {
            stamp: Time::from_secs(t),
            points: vec![([x, 0.0, 1.0], false), ([x, 1.0, 1.0], true)],
        };
        let mut placed = vec![labelled(1.0, 2.0), labelled(2.0, 2.0)];
        let registered = PlacedScan {
            stamp: Time::from_secs(2.0),
            angle: 0.0,
            origin: [0.0, 0.0, 0.5],
            points: vec![([2.1, 0.02, 1.0], 0), ([2.1, 1.02, 1.0], 1)],
            misses: Vec::new(),
        };
        move_to_map(&mut placed, &[registered]);
        assert_eq!(placed[0].points, labelled(1.0, 2.0).points);
        assert_eq!(
            placed[1].points,
            vec![([2.1, 0.02, 1.0], false), ([2.1, 1.02, 1.0], true)]
        );
    }

    /// Hand-counted: 4 static points (one on the floor) and 2 dynamic ones in two scans, in
    /// voxels of their own; the removal keeps 3 static (the floor's among them) and 1
    /// dynamic point. A third scan measures the dropped static point's voxel again: that
    /// point then counts as preserved.
    #[test]
    fn removal_scores_count_by_hand() {
        let mut scans = vec![
            Labelled {
                stamp: Time::from_secs(1.0),
                points: vec![
                    ([0.05, 0.05, 0.0], false),
                    ([1.05, 0.05, 1.0], false),
                    ([2.05, 0.05, 1.0], true),
                ],
            },
            Labelled {
                stamp: Time::from_secs(2.0),
                points: vec![
                    ([3.05, 0.05, 1.0], false),
                    ([4.05, 0.05, 1.0], false),
                    ([5.05, 0.05, 1.0], true),
                ],
            },
        ];
        // Drops the static point at x = 4.05 and the dynamic one at x = 2.05.
        let drop = |_: &Labelled, p: &[f64; 3]| p[0] != 4.05 && p[0] != 2.05;
        let s = removal_scores(&scans, drop);
        assert_eq!(s.sa, 0.75);
        assert_eq!(s.sa_floor, 1.0);
        assert!((s.sa_structure - 2.0 / 3.0).abs() < 1e-12);
        assert_eq!(s.da, 0.5);
        // One voxel per point at 0.2 m too.
        assert_eq!(s.pr, 0.75);
        assert_eq!(s.rr, 0.5);
        // Keeping everything: static all kept, nothing removed.
        let all = removal_scores(&scans, |_, _| true);
        assert_eq!((all.sa, all.da, all.pr, all.rr), (1.0, 0.0, 1.0, 0.0));
        // The dropped static point's voxel measured again and kept.
        scans.push(Labelled {
            stamp: Time::from_secs(3.0),
            points: vec![([4.02, 0.08, 1.03], false)],
        });
        let again = removal_scores(&scans, |_, p| p[0] != 4.05 && p[0] != 2.05);
        assert_eq!(again.sa, 1.0);
        assert_eq!(again.pr, 1.0);
        assert_eq!(again.da, 0.5);
    }
}
