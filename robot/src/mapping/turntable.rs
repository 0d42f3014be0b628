//! Seed 004's stop-and-scan 3D mapping (§2, §5): the robot drives to a view, stands, and
//! turns a laser that scans a vertical plane through a full turn on a turntable; each scan is
//! placed by the robot's pose at the view, the table's angle and the laser's mount. While the
//! horizontal laser's temporal difference ([`TemporalDifference`], seed 004 §4) sees something
//! move, the sweep pauses; the vertical scans taken since shortly before the detection are
//! dropped, and once nothing has moved for `clear` seconds the table turns back to where they
//! began and the sweep goes on. So the turn is measured again after the person has passed,
//! as the seed does, without starting it over (the seed does not say which it did).
//!
//! A sweep's scans enter the map only when the sweep is complete: the point cloud, and the
//! voxel map ([`VoxelMap`]) of occupied, free and unknown space that free-space carving
//! reads. Beside it a second voxel map takes every scan, dropped ones too, so that carving
//! can be scored on its own against the seed's pausing.
//!
//! The mapper decides; the run loop does the rest: it drives the route the mapper asks for
//! (`route`), turns the table to the angle it asks for (`table`) and hands it the scans.

use crate::config::ConfigError;
use crate::mapping::line_icp::LineIcpConfig;
use crate::mapping::surfels::{Registration, SurfelConfig, SurfelMap};
use crate::mapping::voxels::{VoxelConfig, VoxelMap};
use crate::perception::motion::{MotionConfig, TemporalDifference};
use futago_msgs::{LaserScan, Pose2, Time};
use glam::{DAffine3, DQuat, DVec3};
use serde::{Deserialize, Serialize};

/// Parameters of the stop-and-scan mapper (`scan3d.*`).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct TurntableConfig {
    /// The views, in order (map frame, m). Empty: the robot scans where it starts, and a
    /// planner hands it each next view ([`StopAndScan::plan_view`]), as the seed did.
    pub stops: Vec<[f64; 2]>,
    /// The table's turn per view, degrees (360: the seed's full surround).
    pub sweep_deg: f64,
    /// Standing time at a view before the sweep, s (the base settles, the detector fills its
    /// window).
    pub settle: f64,
    /// Pause the sweep while something moves (the seed's way of keeping people out).
    pub pause_for_movers: bool,
    /// Vertical scans up to this long before a detection are dropped, s. The detector
    /// reports scan t−1 one interval (0.25 s) late, and a person walks into the vertical
    /// plane before their legs move enough to show.
    pub guard: f64,
    /// Nothing may move for this long before the sweep goes on, s.
    pub clear: f64,
    /// A sweep paused this long goes on regardless, s (something that never stops, or a
    /// false detection, must not hold the robot for ever).
    pub max_wait: f64,
    /// The moving-object detector on the horizontal laser.
    pub motion: MotionConfig,
    /// The voxel maps.
    pub voxels: VoxelConfig,
    /// The seed's localisation, when the scans are placed by it.
    pub line_icp: LineIcpConfig,
    /// Each sweep registered against the map of the sweeps before it, from the pose it was
    /// placed by ([`SurfelMap::register`]).
    pub registration: SurfelConfig,
}

impl Default for TurntableConfig {
    fn default() -> Self {
        TurntableConfig {
            stops: Vec::new(),
            sweep_deg: 360.0,
            settle: 1.0,
            pause_for_movers: true,
            guard: 0.5,
            clear: 2.0,
            max_wait: 60.0,
            motion: MotionConfig::default(),
            voxels: VoxelConfig::default(),
            line_icp: LineIcpConfig::default(),
            registration: SurfelConfig::default(),
        }
    }
}

impl TurntableConfig {
    /// Checks values, naming `PREFIX.KEY`.
    pub fn validate(&self, prefix: &str) -> Result<(), ConfigError> {
        crate::config::check_ranges(
            prefix,
            &[
                ("sweep_deg", self.sweep_deg, 1.0, 720.0),
                ("settle", self.settle, 0.0, 60.0),
                ("guard", self.guard, 0.0, 10.0),
                ("clear", self.clear, 0.0, 60.0),
                ("max_wait", self.max_wait, 0.0, 3600.0),
            ],
        )?;
        for (i, p) in self.stops.iter().enumerate() {
            if !p.iter().all(|c| c.is_finite() && c.abs() <= 1e6) {
                return Err((
                    crate::config::below(prefix, &format!("stops[{i}]")),
                    format!("expected a point in the map frame, m; found {p:?}"),
                ));
            }
        }
        self.motion
            .validate(&crate::config::below(prefix, "motion"))?;
        self.line_icp
            .validate(&crate::config::below(prefix, "line_icp"))?;
        self.registration
            .validate(&crate::config::below(prefix, "registration"))?;
        self.voxels
            .validate(&crate::config::below(prefix, "voxels"))
    }
}

/// The turntable's geometry on the base: its axis through a point (base frame), and the
/// vertical laser's mount at the table's zero angle.
#[derive(Debug, Clone, Copy)]
pub struct TableMount {
    pub axis: DVec3,
    pub origin: DVec3,
    pub laser: DAffine3,
}

impl TableMount {
    /// The laser's pose on the base at table angle `angle` (rad).
    pub fn laser_at(&self, angle: f64) -> DAffine3 {
        let r = DQuat::from_axis_angle(self.axis.normalize(), angle);
        DAffine3::from_rotation_translation(r, self.origin - r * self.origin) * self.laser
    }
}

/// A vertical scan in the map frame: where the laser was, and each return's point with the
/// beam's index.
#[derive(Debug, Clone)]
pub struct PlacedScan {
    pub stamp: Time,
    /// The table's angle (rad).
    pub angle: f64,
    pub origin: [f64; 3],
    pub points: Vec<([f64; 3], usize)>,
    /// Beams with no return, as points at the range's end (free space to carve).
    pub misses: Vec<[f64; 3]>,
}

/// What the mapper is doing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Phase {
    /// Driving to view `stop`; the route was asked for at `asked` (none yet: not asked).
    Driving { stop: usize, asked: Option<Time> },
    /// Standing at the view since `since`.
    Settling { stop: usize, since: Time },
    /// Turning the table towards `to` (rad).
    Sweeping { stop: usize, to: f64 },
    /// Paused since `since`, the table sent back to `back` (rad); something last moved at
    /// `moved`.
    Paused {
        stop: usize,
        back: f64,
        to: f64,
        since: Time,
        moved: Time,
    },
    /// Waiting for the next view `stop` to be planned ([`StopAndScan::plan_view`]).
    Planning { stop: usize },
    /// Every view scanned.
    Done,
}

/// What the mapper asks of the robot at a control tick.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Requests {
    /// A route to drive (map frame), to the next view.
    pub route: Option<Vec<[f64; 2]>>,
    /// The angle to turn the table to, rad.
    pub table: Option<f64>,
}

/// Counts of a run's sweeps.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct SweepStats {
    /// Views scanned to the end.
    pub views: usize,
    /// Times a sweep paused for something moving.
    pub pauses: usize,
    /// Vertical scans dropped for being near a detection.
    pub scans_dropped: usize,
    /// Vertical scans kept in the map.
    pub scans_kept: usize,
    /// Pauses that ran out (`max_wait`) before the way was clear.
    pub timeouts: usize,
}

/// How close the table must come to an angle it was sent to, rad.
const TABLE_TOLERANCE: f64 = 1e-6;

/// The stop-and-scan mapper.
pub struct StopAndScan {
    config: TurntableConfig,
    mount: TableMount,
    detector: TemporalDifference,
    phase: Phase,
    /// The pose the scans of this view are placed by (taken when the sweep began).
    view_pose: Pose2,
    /// The current sweep's scans, kept until it completes.
    sweep: Vec<PlacedScan>,
    /// The map: every kept scan, in order.
    kept: Vec<PlacedScan>,
    /// Carving over the kept scans, and over every scan taken in a sweep (dropped too).
    carved_kept: VoxelMap,
    carved_all: VoxelMap,
    /// The views' poses as placed (after registration).
    views: Vec<Pose2>,
    /// The surfaces of the kept scans' points that carving keeps, that each sweep is
    /// registered against (made again as each sweep enters the map); what registering each
    /// view's sweep did (`None`: not registered, the first view or registration off).
    surfels: SurfelMap,
    registrations: Vec<Option<Registration>>,
    stats: SweepStats,
    /// Where each view is (given, or planned so far).
    targets: Vec<[f64; 2]>,
    /// The planned route to the next view, until it is asked for.
    route: Option<Vec<[f64; 2]>>,
}

impl StopAndScan {
    /// The mapper with its views given (`config.stops`) or, with none, planned.
    pub fn new(config: TurntableConfig, mount: TableMount) -> StopAndScan {
        let phase = Phase::Driving {
            stop: 0,
            asked: None,
        };
        StopAndScan {
            targets: config.stops.clone(),
            route: None,
            detector: TemporalDifference::new(config.motion),
            carved_kept: VoxelMap::new(config.voxels),
            carved_all: VoxelMap::new(config.voxels),
            surfels: SurfelMap::new(config.registration),
            registrations: Vec::new(),
            config,
            mount,
            phase,
            view_pose: Pose2::IDENTITY,
            sweep: Vec::new(),
            kept: Vec::new(),
            views: Vec::new(),
            stats: SweepStats::default(),
        }
    }

    pub fn phase(&self) -> Phase {
        self.phase
    }

    pub fn finished(&self) -> bool {
        self.phase == Phase::Done
    }

    pub fn stats(&self) -> SweepStats {
        self.stats
    }

    /// The scans in the map, in order.
    pub fn kept(&self) -> &[PlacedScan] {
        &self.kept
    }

    /// The voxel map of the kept scans, and of every scan a sweep took (dropped ones too).
    pub fn voxel_maps(&self) -> (&VoxelMap, &VoxelMap) {
        (&self.carved_kept, &self.carved_all)
    }

    /// The views' poses, as their scans were placed.
    pub fn views(&self) -> &[Pose2] {
        &self.views
    }

    /// What registering each view's sweep did, by view (`None`: not registered).
    pub fn registrations(&self) -> &[Option<Registration>] {
        &self.registrations
    }

    /// The kept scans' surfaces.
    pub fn surfels(&self) -> &SurfelMap {
        &self.surfels
    }

    /// Whether the views are planned rather than given.
    pub fn planning(&self) -> bool {
        self.config.stops.is_empty()
    }

    /// A control tick at `now`: the robot's pose estimate (map frame), when the driver last
    /// finished a route, and the table's angle (rad).
    pub fn control(
        &mut self,
        now: Time,
        pose: Pose2,
        route_done: Option<Time>,
        table: f64,
    ) -> Requests {
        let mut out = Requests::default();
        match self.phase {
            Phase::Driving { stop, asked: None } => {
                // A planned survey scans first where the robot starts.
                if stop == 0 && self.planning() {
                    self.targets.push([pose.x, pose.y]);
                    self.phase = Phase::Settling { stop, since: now };
                    return out;
                }
                out.route = Some(
                    self.route
                        .take()
                        .unwrap_or_else(|| vec![[pose.x, pose.y], self.targets[stop]]),
                );
                self.phase = Phase::Driving {
                    stop,
                    asked: Some(now),
                };
            }
            Phase::Driving {
                stop,
                asked: Some(asked),
            } => {
                if route_done.is_some_and(|t| t > asked) {
                    self.phase = Phase::Settling { stop, since: now };
                }
            }
            Phase::Settling { stop, since } => {
                if (now - since).secs() >= self.config.settle {
                    self.view_pose = pose;
                    // Alternate the direction, so that the cable never winds up.
                    let sweep = self.config.sweep_deg.to_radians();
                    let to = if stop % 2 == 0 {
                        table + sweep
                    } else {
                        table - sweep
                    };
                    self.phase = Phase::Sweeping { stop, to };
                    out.table = Some(to);
                }
            }
            Phase::Sweeping { stop, to } => {
                out.table = Some(to);
                if (table - to).abs() < TABLE_TOLERANCE {
                    self.complete(stop);
                }
            }
            Phase::Paused {
                stop,
                back,
                to,
                since,
                moved,
            } => {
                let clear = (now - moved).secs() >= self.config.clear
                    && (table - back).abs() < TABLE_TOLERANCE;
                let timeout = (now - since).secs() >= self.config.max_wait;
                if clear || timeout {
                    if !clear {
                        self.stats.timeouts += 1;
                    }
                    self.phase = Phase::Sweeping { stop, to };
                    out.table = Some(to);
                } else {
                    out.table = Some(back);
                }
            }
            Phase::Planning { .. } | Phase::Done => {}
        }
        out
    }

    /// The sweep of view `stop` is complete: it is registered against the map so far (when
    /// registration is on and there is a map), moved to where it fits, and its scans enter the
    /// map.
    fn complete(&mut self, stop: usize) {
        let registration = (self.config.registration.enabled && !self.surfels.is_empty())
            .then(|| self.register_sweep());
        if let Some(r) = registration.filter(|r| !r.refused) {
            // Each point moved from the view's pose to the registered one.
            let to = r.pose.compose(&self.view_pose.inverse());
            let moved = |p: [f64; 3]| crate::mapping::registration::place(&to, p);
            for s in &mut self.sweep {
                s.origin = moved(s.origin);
                for (p, _) in &mut s.points {
                    *p = moved(*p);
                }
                for p in &mut s.misses {
                    *p = moved(*p);
                }
            }
            self.view_pose = r.pose;
        }
        self.registrations.push(registration);
        for s in self.sweep.drain(..) {
            insert(&mut self.carved_kept, &s);
            insert(&mut self.carved_all, &s);
            self.kept.push(s);
            self.stats.scans_kept += 1;
        }
        if self.config.registration.enabled {
            // The surfels of what carving keeps: a person the sweeps saw through is not a
            // surface to register against.
            let points: Vec<[f64; 3]> = self
                .kept
                .iter()
                .flat_map(|s| s.points.iter().map(|(p, _)| *p))
                .collect();
            self.surfels = SurfelMap::new(self.config.registration);
            self.surfels.add(self.carved_kept.keep_static(&points));
        }
        self.views.push(self.view_pose);
        self.stats.views += 1;
        self.phase = if stop + 1 < self.targets.len() {
            Phase::Driving {
                stop: stop + 1,
                asked: None,
            }
        } else if self.planning() {
            Phase::Planning { stop: stop + 1 }
        } else {
            Phase::Done
        };
    }

    /// The current sweep registered against the surfels, from the view's pose.
    fn register_sweep(&self) -> Registration {
        let back = self.view_pose.inverse();
        let points: Vec<[f64; 3]> = self
            .sweep
            .iter()
            .flat_map(|s| s.points.iter())
            .map(|(p, _)| crate::mapping::registration::place(&back, *p))
            .collect();
        self.surfels.register(&points, self.view_pose)
    }

    /// The next view for a mapper that plans its views (in [`Phase::Planning`]): where to
    /// stand and the route there, or `None` to end the survey. Ignored in other phases.
    pub fn plan_view(&mut self, view: Option<([f64; 2], Vec<[f64; 2]>)>) {
        let Phase::Planning { stop } = self.phase else {
            return;
        };
        self.phase = match view {
            Some((at, route)) => {
                self.targets.push(at);
                self.route = Some(route);
                Phase::Driving { stop, asked: None }
            }
            None => Phase::Done,
        };
    }

    /// A scan of the horizontal laser, whose pose in the odometry frame is `laser` (the
    /// detector differences scans in one fixed frame), at `now`. Returns what moved, if
    /// anything: when (the scan the detector looked at) and where (the odometry frame).
    pub fn on_horizontal(
        &mut self,
        scan: &LaserScan,
        laser: &Pose2,
        now: Time,
    ) -> Option<(Time, Vec<[f64; 2]>)> {
        let (at, blobs) = self.detector.update(scan, laser)?;
        if blobs.is_empty() {
            return None;
        }
        if self.config.pause_for_movers {
            self.moved(at, now);
        }
        Some((at, blobs.iter().map(|b| b.position).collect()))
    }

    /// Something moved at `at`, reported at `now`: a sweep pauses (or stays paused).
    pub fn moved(&mut self, at: Time, now: Time) {
        match self.phase {
            Phase::Sweeping { stop, to } => {
                // Drop what the table measured since shortly before the detection, and send
                // it back to where that began.
                let cut = at.secs() - self.config.guard;
                let back = match self.sweep.iter().position(|s| s.stamp.secs() >= cut) {
                    Some(i) => {
                        let back = self.sweep[i].angle;
                        self.stats.scans_dropped += self.sweep.len() - i;
                        for s in self.sweep.drain(i..) {
                            insert(&mut self.carved_all, &s);
                        }
                        back
                    }
                    None => self.sweep.last().map_or(f64::NAN, |s| s.angle),
                };
                self.stats.pauses += 1;
                self.phase = Phase::Paused {
                    stop,
                    back: if back.is_finite() {
                        back
                    } else {
                        self.start_angle(to)
                    },
                    to,
                    since: now,
                    moved: now,
                };
            }
            Phase::Paused {
                stop,
                back,
                to,
                since,
                ..
            } => {
                self.phase = Phase::Paused {
                    stop,
                    back,
                    to,
                    since,
                    moved: now,
                };
            }
            _ => {}
        }
    }

    /// The angle a sweep towards `to` began at.
    fn start_angle(&self, to: f64) -> f64 {
        let sweep = self.config.sweep_deg.to_radians();
        match self.phase {
            Phase::Sweeping { stop, .. } | Phase::Paused { stop, .. } if stop % 2 == 1 => {
                to + sweep
            }
            _ => to - sweep,
        }
    }

    /// A scan of the vertical laser taken at table angle `angle` (rad). Only scans taken
    /// while the sweep turns are used; they are placed by the view's pose. Returns the scan
    /// as placed, if it was taken.
    pub fn on_vertical(&mut self, scan: &LaserScan, angle: f64) -> Option<&PlacedScan> {
        if !matches!(self.phase, Phase::Sweeping { .. }) {
            return None;
        }
        let base = DAffine3::from_rotation_translation(
            DQuat::from_rotation_z(self.view_pose.theta),
            DVec3::new(self.view_pose.x, self.view_pose.y, 0.0),
        );
        let laser = base * self.mount.laser_at(angle);
        let origin = laser.translation;
        let mut points = Vec::new();
        let mut misses = Vec::new();
        for (i, &r) in scan.ranges.iter().enumerate() {
            let a = scan.angle(i);
            let dir = DVec3::new(a.cos(), a.sin(), 0.0);
            if r.is_finite() && r > 0.0 {
                let p = laser.transform_point3(dir * r as f64);
                points.push((p.to_array(), i));
            } else if r == f32::INFINITY {
                misses.push(laser.transform_point3(dir * scan.range_max).to_array());
            }
        }
        self.sweep.push(PlacedScan {
            stamp: scan.stamp,
            angle,
            origin: origin.to_array(),
            points,
            misses,
        });
        self.sweep.last()
    }
}

/// Inserts a placed scan into a voxel map.
fn insert(map: &mut VoxelMap, s: &PlacedScan) {
    let beams: Vec<([f64; 3], bool)> = s
        .points
        .iter()
        .map(|(p, _)| (*p, true))
        .chain(s.misses.iter().map(|p| (*p, false)))
        .collect();
    map.insert_scan(s.origin, &beams);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The table turns about z through (0.1, 0, 0) on the base; the laser sits 0.2 m ahead
    /// of the axis and 0.5 m up, its scan plane vertical (rolled 90° about its x): beam
    /// bearing a points at (cos a, 0, sin a) in the base at table angle 0.
    fn mount() -> TableMount {
        TableMount {
            axis: DVec3::Z,
            origin: DVec3::new(0.1, 0.0, 0.0),
            laser: DAffine3::from_rotation_translation(
                DQuat::from_rotation_x(std::f64::consts::FRAC_PI_2),
                DVec3::new(0.3, 0.0, 0.5),
            ),
        }
    }

    /// A vertical scan of 3 beams (−10°, 0°, +10°), each `range` long; one more beam with
    /// no return.
    fn scan(stamp: f64, range: f32) -> LaserScan {
        LaserScan {
            frame: "v".into(),
            stamp: Time::from_secs(stamp),
            angle_min: -10f64.to_radians(),
            angle_increment: 10f64.to_radians(),
            time_increment: 0.0,
            range_min: 0.01,
            range_max: 6.0,
            ranges: vec![range, range, range, f32::INFINITY],
        }
    }

    fn config(stops: Vec<[f64; 2]>) -> TurntableConfig {
        TurntableConfig {
            stops,
            settle: 0.5,
            clear: 1.0,
            guard: 0.5,
            ..TurntableConfig::default()
        }
    }

    /// The mapper asks for the route to its view, stands once it is driven, turns the table
    /// a full turn, and places each scan by the view's pose, the table's angle and the mount:
    /// at the table's angle φ the level beam of range r ends at the axis plus (0.2 + r) along
    /// the heading turned by φ, 0.5 m up. Then it drives to the next view, turning back.
    #[test]
    fn a_view_is_driven_to_swept_and_placed() {
        let mut m = StopAndScan::new(config(vec![[2.0, 1.0], [4.0, 1.0]]), mount());
        let t = Time::from_secs;
        let start = Pose2::new(0.0, 0.0, 0.0);
        let r = m.control(t(0.0), start, None, 0.0);
        assert_eq!(r.route, Some(vec![[0.0, 0.0], [2.0, 1.0]]));
        assert!(
            m.control(t(1.0), start, None, 0.0).route.is_none(),
            "asked once"
        );
        // Arrived, facing +y.
        let view = Pose2::new(2.0, 1.0, std::f64::consts::FRAC_PI_2);
        m.control(t(10.0), view, Some(t(9.9)), 0.0);
        assert!(matches!(m.phase(), Phase::Settling { .. }));
        assert!(
            m.on_vertical(&scan(10.1, 1.0), 0.0).is_none(),
            "not yet sweeping"
        );
        let r = m.control(t(10.6), view, Some(t(9.9)), 0.0);
        assert_eq!(r.table, Some(std::f64::consts::TAU));
        for k in 0..8 {
            let phi = k as f64 * std::f64::consts::TAU / 8.0;
            let placed = m
                .on_vertical(&scan(11.0 + k as f64, 1.5), phi)
                .unwrap()
                .clone();
            assert_eq!(placed.points.len(), 3);
            assert_eq!(placed.misses.len(), 1);
            let (p, i) = placed.points[1];
            assert_eq!(i, 1);
            let heading = view.theta + phi;
            let axis = [2.0 + 0.1 * view.theta.cos(), 1.0 + 0.1 * view.theta.sin()];
            let want = [
                axis[0] + 1.7 * heading.cos(),
                axis[1] + 1.7 * heading.sin(),
                0.5,
            ];
            for d in 0..3 {
                assert!(
                    (p[d] - want[d]).abs() < 1e-9,
                    "φ = {phi}: {p:?} vs {want:?}"
                );
            }
            // The upper beam rises at 10°.
            let up = placed.points[2].0;
            assert!((up[2] - (0.5 + 1.5 * 10f64.to_radians().sin())).abs() < 1e-9);
        }
        m.control(t(20.0), view, Some(t(9.9)), std::f64::consts::TAU);
        assert_eq!(m.stats().views, 1);
        assert_eq!(m.kept().len(), 8);
        let r = m.control(t(20.1), view, Some(t(9.9)), std::f64::consts::TAU);
        assert_eq!(r.route, Some(vec![[2.0, 1.0], [4.0, 1.0]]));
        m.control(t(30.0), view, Some(t(29.0)), std::f64::consts::TAU);
        let r = m.control(t(31.0), view, Some(t(29.0)), std::f64::consts::TAU);
        assert_eq!(r.table, Some(0.0), "the second view turns back");
        m.control(t(40.0), view, Some(t(29.0)), 0.0);
        assert!(m.finished());
    }

    /// Something moves mid-sweep: the scans from `guard` before it on are dropped, the
    /// table goes back to the first dropped scan's angle, and the sweep goes on only once
    /// nothing has moved for `clear` and the table is back. The kept scans cover the turn
    /// without the dropped ones.
    #[test]
    fn a_mover_pauses_the_sweep_and_its_scans_are_taken_again() {
        let mut m = StopAndScan::new(config(vec![[0.0, 0.0]]), mount());
        let t = Time::from_secs;
        let p = Pose2::IDENTITY;
        m.control(t(0.0), p, None, 0.0);
        m.control(t(1.0), p, Some(t(0.5)), 0.0);
        m.control(t(2.0), p, Some(t(0.5)), 0.0);
        assert!(matches!(m.phase(), Phase::Sweeping { .. }));
        for k in 0..10 {
            m.on_vertical(&scan(2.0 + 0.1 * k as f64, 2.0), 0.1 * k as f64);
        }
        // A person seen at 2.75 s: the scans from 2.25 s on (angles 0.3 …) are dropped.
        m.moved(t(2.75), t(3.0));
        let Phase::Paused { back, .. } = m.phase() else {
            panic!("{:?}", m.phase());
        };
        assert!((back - 0.3).abs() < 1e-9, "{back}");
        assert_eq!(m.stats().scans_dropped, 7);
        assert!(m.on_vertical(&scan(3.1, 2.0), 0.9).is_none(), "paused");
        // Still moving at 3.5 s; the table is back at 3.6 s; clear at 4.5 s.
        m.moved(t(3.4), t(3.5));
        assert_eq!(m.control(t(3.6), p, Some(t(0.5)), back).table, Some(back));
        assert!(matches!(m.phase(), Phase::Paused { .. }));
        assert!(
            matches!(
                m.control(t(4.5), p, Some(t(0.5)), 0.5).table,
                Some(a) if a == back
            ),
            "clear, but the table is not back yet"
        );
        let r = m.control(t(4.5), p, Some(t(0.5)), back);
        assert_eq!(r.table, Some(std::f64::consts::TAU));
        assert!(matches!(m.phase(), Phase::Sweeping { .. }));
        for k in 3..10 {
            m.on_vertical(&scan(4.5 + 0.1 * k as f64, 2.0), 0.1 * k as f64);
        }
        m.control(t(9.0), p, Some(t(0.5)), std::f64::consts::TAU);
        assert!(m.finished());
        let angles: Vec<f64> = m.kept().iter().map(|s| s.angle).collect();
        let want: Vec<f64> = (0..10).map(|k| 0.1 * k as f64).collect();
        assert_eq!(angles, want);
        assert_eq!(m.stats().pauses, 1);
        assert_eq!(m.stats().timeouts, 0);
    }

    /// With no views given, the mapper scans where it stands, then waits for a planner: a
    /// planned view is driven to by the route given; no view ends the survey.
    #[test]
    fn a_planned_survey_scans_where_it_starts_and_waits_for_each_view() {
        let mut m = StopAndScan::new(config(Vec::new()), mount());
        let t = Time::from_secs;
        let p = Pose2::new(1.0, 2.0, 0.0);
        assert_eq!(m.control(t(0.0), p, None, 0.0).route, None);
        assert!(matches!(m.phase(), Phase::Settling { stop: 0, .. }));
        let to = m.control(t(1.0), p, None, 0.0).table.unwrap();
        m.on_vertical(&scan(1.1, 2.0), 0.5);
        m.control(t(13.0), p, None, to);
        assert_eq!(m.phase(), Phase::Planning { stop: 1 });
        assert_eq!(m.stats().views, 1);
        assert_eq!(m.views(), &[p]);
        // Nothing is asked for while the planner has not answered.
        assert_eq!(m.control(t(13.5), p, None, to), Requests::default());
        let route = vec![[1.0, 2.0], [3.0, 2.0], [3.0, 4.0]];
        m.plan_view(Some(([3.0, 4.0], route.clone())));
        assert_eq!(m.control(t(14.0), p, None, to).route, Some(route));
        m.control(t(40.0), p, Some(t(39.0)), to);
        let back = m.control(t(41.0), p, None, to).table.unwrap();
        m.control(t(54.0), p, None, back);
        assert_eq!(m.phase(), Phase::Planning { stop: 2 });
        m.plan_view(None);
        assert!(m.finished());
        assert_eq!(m.stats().views, 2);
    }

    /// A pause that never clears runs out after `max_wait`, and is counted.
    #[test]
    fn a_pause_that_never_clears_runs_out() {
        let mut m = StopAndScan::new(
            TurntableConfig {
                max_wait: 5.0,
                ..config(vec![[0.0, 0.0]])
            },
            mount(),
        );
        let t = Time::from_secs;
        let p = Pose2::IDENTITY;
        m.control(t(0.0), p, None, 0.0);
        m.control(t(1.0), p, Some(t(0.5)), 0.0);
        m.control(t(2.0), p, Some(t(0.5)), 0.0);
        m.moved(t(2.5), t(2.5));
        let mut resumed = None;
        for k in 0..40 {
            let now = 3.0 + 0.25 * k as f64;
            m.moved(t(now), t(now));
            m.control(t(now), p, Some(t(0.5)), 0.0);
            if matches!(m.phase(), Phase::Sweeping { .. }) {
                resumed = Some(now);
                break;
            }
        }
        assert_eq!(resumed, Some(7.5), "5 s after the pause began");
        assert_eq!(m.stats().timeouts, 1);
    }

    /// A vertical scan of 361 beams 0.5° apart taken at table angle `angle` by a robot truly at
    /// `truth`, in a room 8 m by 6 m, 3 m high: each range cast to the nearest face of the box.
    fn room_scan(stamp: f64, truth: &Pose2, angle: f64) -> LaserScan {
        let base = DAffine3::from_rotation_translation(
            DQuat::from_rotation_z(truth.theta),
            DVec3::new(truth.x, truth.y, 0.0),
        );
        let laser = base * mount().laser_at(angle);
        let far = [8.0, 6.0, 3.0];
        let ranges = (0..361)
            .map(|i| {
                let a = (i as f64 * 0.5 - 90.0).to_radians();
                let o = laser.translation;
                let d = laser.transform_vector3(DVec3::new(a.cos(), a.sin(), 0.0));
                (0..3)
                    .filter(|&k| d[k].abs() > 1e-12)
                    .map(|k| (if d[k] > 0.0 { far[k] } else { 0.0 } - o[k]) / d[k])
                    .fold(f64::INFINITY, f64::min) as f32
            })
            .collect();
        LaserScan {
            frame: "v".into(),
            stamp: Time::from_secs(stamp),
            angle_min: -std::f64::consts::FRAC_PI_2,
            angle_increment: 0.5f64.to_radians(),
            time_increment: 0.0,
            range_min: 0.01,
            range_max: 20.0,
            ranges,
        }
    }

    /// The second view's sweep, placed by a pose 11 cm and 1.1° off the truth, is registered
    /// against the first view's map before it enters the map: the view is placed at the truth
    /// to within a centimetre and a tenth of a degree, and its points lie on the room's walls.
    #[test]
    fn a_sweep_is_registered_against_the_map_before_it_enters_it() {
        const SCANS: usize = 720;
        let mut m = StopAndScan::new(config(vec![[3.0, 3.0], [3.5, 3.0]]), mount());
        let t = Time::from_secs;
        let truths = [Pose2::new(3.0, 3.0, 0.0), Pose2::new(3.5, 3.0, 0.0)];
        let guesses = [truths[0], Pose2::new(3.6, 2.95, 0.02)];
        let (mut clock, mut table) = (0.0, 0.0);
        for v in 0..2 {
            let g = guesses[v];
            assert!(m.control(t(clock), g, None, table).route.is_some());
            m.control(t(clock + 1.0), g, Some(t(clock + 0.5)), table);
            let to = m
                .control(t(clock + 2.0), g, None, table)
                .table
                .expect("the sweep begins");
            // A scan every 0.5° of the turn.
            for k in 0..=SCANS {
                let a = table + (to - table) * k as f64 / SCANS as f64;
                let at = clock + 2.0 + k as f64 * 0.01;
                m.on_vertical(&room_scan(at, &truths[v], a), a);
            }
            table = to;
            clock += 5.0;
            m.control(t(clock), g, None, table);
        }
        assert_eq!(m.views().len(), 2);
        assert!(
            m.registrations()[0].is_none(),
            "nothing to register the first against"
        );
        let r = m.registrations()[1].expect("registered");
        assert!(!r.refused && r.guess == guesses[1], "{r:?}");
        let placed = m.views()[1];
        assert!(placed.distance(&truths[1]) < 0.01, "{placed:?}");
        assert!((placed.theta - truths[1].theta).abs() < 0.1f64.to_radians());
        // The second sweep's points on the walls, floor or ceiling.
        let off_the_box = |p: &[f64; 3]| {
            [p[0], 8.0 - p[0], p[1], 6.0 - p[1], p[2], 3.0 - p[2]]
                .into_iter()
                .map(f64::abs)
                .fold(f64::INFINITY, f64::min)
        };
        let second = &m.kept()[SCANS + 1..];
        assert_eq!(second.len(), SCANS + 1);
        let worst = second
            .iter()
            .flat_map(|s| s.points.iter())
            .map(|(p, _)| off_the_box(p))
            .fold(0.0, f64::max);
        assert!(worst < 0.03, "a point {worst} m off the walls");
    }
}
