//! Autonomous navigation (written for futago): goals on a known map by seed 000's node graph
//! and A* ([`planner::RoadMap`]), or frontier exploration of the map SLAM is building
//! ([`exploration`]); either way the path is followed by seed 000's look-ahead arc
//! controller ([`crate::control::pursuit`]), with two safety behaviours:
//!
//! - an obstacle in the laser scan inside the strip the robot is about to sweep stops it, and
//!   it resumes when the strip is clear (seed 000 stops for people and resumes); after
//!   `blocked_timeout` it backs off and plans again;
//! - a bumper press backs it off `backup_distance`, turning away from the pressed side, and it
//!   plans again from where it ends up;
//! - a tracked person it would come too close to stops it until the risk has passed, and one
//!   who stays in the way is driven round ([`yielding`]).

pub mod coverage;
pub mod exploration;
pub mod planner;
pub mod views;
pub mod yielding;

use crate::control::PoseSource;
use crate::control::pursuit::{FollowParams, PathFollower};
use crate::tracking::people::TrackedPerson;
use exploration::path_to_frontier;
use futago_msgs::grid::OccupancyGrid;
use futago_msgs::{BumpsAndDrops, DriveCommand, LaserScan, Pose2, Radius, Time};
use planner::{PlannerConfig, RoadMap};
use serde::Deserialize;

/// Navigation parameters (`navigation.*`).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct NavigationConfig {
    pub planner: PlannerConfig,
    /// Cell size of the known map the road map is built on, m (seed 000: 50 mm).
    pub map_resolution: f64,
    /// Cruise speed, m/s.
    pub speed: f64,
    /// Look-ahead distance of the arc controller, m.
    pub lookahead: f64,
    /// A goal (or path point) counts as reached within this, m.
    pub goal_tolerance: f64,
    /// A route's points (a coverage route's lane ends) are driven to within this along the
    /// way to them, m: within `goal_tolerance`, a lane would end that much short and the
    /// robot cut the corner to the next, leaving a triangle of floor unswept at each end.
    pub route_pass: f64,
    /// …or until the laser finds a wall this close ahead of the middle of the bumper, m, when
    /// the point is within `goal_tolerance`: a pose estimate a few centimetres off would
    /// otherwise drive the bumper into the wall the lane ends against (the route keeps 3 cm
    /// from walls).
    pub route_wall_margin: f64,
    /// Turn in place when the aim is further off the heading than this, degrees.
    pub turn_in_place_deg: f64,
    pub turn_tolerance_deg: f64,
    /// Wheel speed in turns in place, m/s.
    pub turn_speed: f64,
    /// The Create's radius, m.
    pub robot_radius: f64,
    /// The laser's scans the navigator looks at, Hz (the newest at each control tick): at
    /// 10 Hz the robot at its 0.3 m/s moves 3 cm between them, a fifth of `stop_distance`.
    /// Nav2's local costmap takes the laser at 5 Hz. A laser scanning faster casts only the
    /// scans some node reads. A stack that tracks people reads every scan (the driver node):
    /// a walker closes faster than the robot drives.
    pub scan_rate: f64,
    /// Stop for laser returns this far ahead of the bumper, m…
    pub stop_distance: f64,
    /// …within the robot's width plus this margin each side, m.
    pub stop_margin: f64,
    /// Blocked this long, back off and plan again, s.
    pub blocked_timeout: f64,
    /// Back-off after a bump, m, at this speed, m/s.
    pub backup_distance: f64,
    pub backup_speed: f64,
    /// Plan again when the pose is further than this from the path being followed (a
    /// localisation jump, a kidnapping, a push), m.
    pub off_path_replan: f64,
    /// Exploration: plan to a new frontier at least this often, s.
    pub replan_period: f64,
    /// Exploration: frontiers shorter than this are ignored, m.
    pub frontier_min_length: f64,
    /// Exploration: a frontier reached that is still a frontier is given up within this, m.
    pub frontier_exclusion: f64,
    /// Stop for a tracked person who would come this close, centre to centre, m; 0 turns
    /// yielding off ([`yielding`]).
    pub people_clearance: f64,
    /// How far ahead a person's and the robot's motion are looked at, s.
    pub people_horizon: f64,
    /// Stopped for people this long, drive round them, s.
    pub people_patience: f64,
}

impl Default for NavigationConfig {
    fn default() -> Self {
        NavigationConfig {
            planner: PlannerConfig::default(),
            map_resolution: 0.05,
            speed: 0.3,
            lookahead: 0.35,
            goal_tolerance: 0.15,
            route_pass: 0.02,
            route_wall_margin: 0.03,
            turn_in_place_deg: 45.0,
            turn_tolerance_deg: 8.0,
            turn_speed: 0.12,
            robot_radius: 0.17,
            scan_rate: 10.0,
            stop_distance: 0.15,
            stop_margin: 0.03,
            blocked_timeout: 5.0,
            backup_distance: 0.15,
            backup_speed: 0.1,
            off_path_replan: 1.0,
            replan_period: 4.0,
            frontier_min_length: 0.4,
            frontier_exclusion: 0.6,
            people_clearance: 0.8,
            people_horizon: 2.0,
            people_patience: 5.0,
        }
    }
}

impl NavigationConfig {
    /// Checks values navigation cannot work with; `(key, expectation)` on error.
    pub fn validate(&self) -> Result<(), (String, String)> {
        self.planner.validate("navigation.planner")?;
        for (k, v, lo, hi) in [
            ("map_resolution", self.map_resolution, 0.01, 0.5),
            ("speed", self.speed, 0.01, 0.5),
            ("lookahead", self.lookahead, 0.05, 5.0),
            ("goal_tolerance", self.goal_tolerance, 0.01, 2.0),
            ("route_pass", self.route_pass, 0.001, 2.0),
            ("route_wall_margin", self.route_wall_margin, 0.0, 2.0),
            ("turn_in_place_deg", self.turn_in_place_deg, 1.0, 180.0),
            ("turn_tolerance_deg", self.turn_tolerance_deg, 0.1, 90.0),
            ("turn_speed", self.turn_speed, 0.01, 0.5),
            ("robot_radius", self.robot_radius, 0.01, 2.0),
            ("scan_rate", self.scan_rate, 0.1, 1000.0),
            ("stop_distance", self.stop_distance, 0.0, 5.0),
            ("stop_margin", self.stop_margin, 0.0, 1.0),
            ("blocked_timeout", self.blocked_timeout, 0.1, 600.0),
            ("backup_distance", self.backup_distance, 0.0, 2.0),
            ("backup_speed", self.backup_speed, 0.01, 0.5),
            ("off_path_replan", self.off_path_replan, 0.05, 100.0),
            ("replan_period", self.replan_period, 0.1, 600.0),
            ("frontier_min_length", self.frontier_min_length, 0.0, 100.0),
            ("frontier_exclusion", self.frontier_exclusion, 0.0, 100.0),
            ("people_clearance", self.people_clearance, 0.0, 10.0),
            ("people_horizon", self.people_horizon, 0.0, 60.0),
            ("people_patience", self.people_patience, 0.1, 600.0),
        ] {
            if !(v.is_finite() && v >= lo && v <= hi) {
                return Err((
                    format!("navigation.{k}"),
                    format!("expected a value in [{lo}, {hi}], found {v}"),
                ));
            }
        }
        Ok(())
    }

    /// The follower's parameters for a task: a route's points are passed (`route_pass`).
    fn follow_params(&self, task: &Task) -> FollowParams {
        FollowParams {
            speed: self.speed,
            lookahead: self.lookahead,
            tolerance: self.goal_tolerance,
            turn_in_place: self.turn_in_place_deg.to_radians(),
            turn_tolerance: self.turn_tolerance_deg.to_radians(),
            turn_speed: self.turn_speed,
            pass: matches!(task, Task::Route(_)).then_some(self.route_pass),
        }
    }
}

/// `[controller] type = "navigate"`: drive to goals on the known map, planning with the node
/// graph.
#[derive(Debug, Clone, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct NavigateConfig {
    /// `[[x, y], …]` in the map (world) frame, m.
    pub goals: Vec<[f64; 2]>,
    /// Visit the list this many times.
    #[serde(default = "one")]
    pub laps: u32,
    /// Where the pose comes from (normally the localiser).
    #[serde(default = "localization")]
    pub pose_source: PoseSource,
}

fn one() -> u32 {
    1
}

fn localization() -> PoseSource {
    PoseSource::Localization
}

impl NavigateConfig {
    /// The goals of every lap in order.
    pub fn task(&self) -> Task {
        Task::Goals(
            (0..self.laps)
                .flat_map(|_| self.goals.iter().copied())
                .collect(),
        )
    }
}

/// `[controller] type = "coverage"`: plan a coverage route on the known map (the
/// `coverage.*` parameters, [`coverage`]) and drive it.
#[derive(Debug, Clone, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct CoverConfig {
    /// Where the pose comes from (normally the localiser).
    #[serde(default = "localization")]
    pub pose_source: PoseSource,
}

/// `[controller] type = "route"`: drive each route a stack node publishes on `path/TOPIC`
/// (seed 004's stop-and-scan mapper publishes the way to its next view), planning on the
/// known map as the coverage controller does.
#[derive(Debug, Clone, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct RouteConfig {
    /// Where the pose comes from.
    #[serde(default = "localization")]
    pub pose_source: PoseSource,
    /// The topic the routes come on (`path/TOPIC`).
    pub topic: String,
}

/// `[controller] type = "explore"`: frontier exploration on the map SLAM builds, on SLAM's
/// pose (the scenario needs a `[slam]` table).
#[derive(Debug, Clone, PartialEq, Deserialize, serde::Serialize, Default)]
#[serde(deny_unknown_fields)]
pub struct ExploreConfig {}

impl NavigateConfig {
    /// Checks values the navigator cannot run with; returns `(key, expectation)` on error.
    pub fn validate(&self) -> Result<(), (String, String)> {
        crate::control::script::check_points("goals", &self.goals)?;
        if self.laps == 0 {
            return Err(("laps".into(), "expected at least one lap".into()));
        }
        Ok(())
    }
}

/// What the navigator is asked to do.
#[derive(Debug, Clone)]
pub enum Task {
    /// Visit these points of a known map in order.
    Goals(Vec<[f64; 2]>),
    /// Explore the map handed in by SLAM until no frontier is left.
    Explore,
    /// Drive along this polyline of a known map (a coverage route), from its first point;
    /// after a detour (an obstacle, a person, a push) it rejoins the route at the first
    /// point not yet passed.
    Route(Vec<[f64; 2]>),
}

/// What the navigator is told each control tick.
#[derive(Debug, Clone, Copy)]
pub struct NavInput<'a> {
    pub now: Time,
    /// The robot's pose estimate (localisation or SLAM) in the map frame.
    pub pose: Pose2,
    pub bumps: BumpsAndDrops,
    /// The newest laser scan and the laser's mount on the robot.
    pub scan: Option<(&'a LaserScan, Pose2)>,
    /// For exploration: a newer map than the last one given, when there is one.
    pub map: Option<&'a OccupancyGrid>,
    /// The people tracked now, in the map frame.
    pub people: &'a [TrackedPerson],
}

/// Counts of what happened, for the run's summary.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct NavStats {
    pub goals_reached: usize,
    pub goals_unreachable: usize,
    pub plans: usize,
    pub bumps: usize,
    pub obstacle_stops: usize,
    pub frontiers_exhausted: usize,
    /// Stops for people, and the time stopped for them, s.
    pub people_stops: usize,
    pub people_wait_s: f64,
    /// Paths planned round people who stayed in the way.
    pub people_detours: usize,
    /// Route points passed, and those given up as unreachable.
    pub route_points_passed: usize,
    pub route_points_skipped: usize,
    /// Plans of a route that found no path from the pose (the robot spun, and tried again).
    pub failed_plans: usize,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Mode {
    Driving,
    /// Stopped for an obstacle since then.
    Blocked(Time),
    /// Stopped for people since then; the last tick's time.
    Yielding(Time, Time),
    /// Backing off until then, then turning away in this direction (+1 left) until the
    /// second time.
    Backing(Time, f64, Time),
    Done,
}

/// The navigator.
pub struct Navigator {
    config: NavigationConfig,
    task: Task,
    roadmap: Option<RoadMap>,
    next_goal: usize,
    follower: Option<PathFollower>,
    mode: Mode,
    map: Option<OccupancyGrid>,
    last_plan: Option<Time>,
    /// When a route's plan last found no path: the robot spins, and plans again only
    /// [`SPIN_REPLAN_PERIOD`] later.
    route_failed: Option<Time>,
    exhausted: Vec<[f64; 2]>,
    /// Where bumpers found obstacles the map does not hold (low, thin, glass); exploration
    /// plans round them.
    bump_marks: Vec<[f64; 2]>,
    /// The people the path being followed goes round, and where they stood.
    detoured: Vec<(u32, [f64; 2])>,
    /// A route's first point not yet passed, and where it lies in the follower's path.
    route_next: usize,
    route_at: usize,
    /// Bumps since the route last passed a point.
    route_bumps: usize,
    /// The laser beams' directions, for the scans' checks at every control tick.
    beams: BeamDirections,
    stats: NavStats,
}

impl Navigator {
    /// A navigator for `task`; `map` is the known map for goals (the road map is built from
    /// it here), unused for exploration.
    pub fn new(config: NavigationConfig, task: Task, map: Option<OccupancyGrid>) -> Navigator {
        let roadmap = match (&task, map) {
            (Task::Goals(_) | Task::Route(_), Some(m)) => Some(RoadMap::new(m, config.planner)),
            _ => None,
        };
        Navigator {
            config,
            task,
            roadmap,
            next_goal: 0,
            follower: None,
            mode: Mode::Driving,
            map: None,
            last_plan: None,
            route_failed: None,
            exhausted: Vec::new(),
            bump_marks: Vec::new(),
            detoured: Vec::new(),
            route_next: 0,
            route_at: 1,
            route_bumps: 0,
            beams: BeamDirections::default(),
            stats: NavStats::default(),
        }
    }

    pub fn finished(&self) -> bool {
        self.mode == Mode::Done
    }

    /// Drives `route` from now on (a route task: a new coverage route replaces the one being
    /// driven, or starts again after it was done).
    pub fn set_route(&mut self, route: Vec<[f64; 2]>) {
        self.task = Task::Route(route);
        self.route_next = 0;
        self.route_at = 1;
        self.route_bumps = 0;
        self.follower = None;
        if self.mode == Mode::Done {
            self.mode = Mode::Driving;
        }
    }

    pub fn stats(&self) -> NavStats {
        self.stats
    }

    /// The road map's node count (goal navigation).
    pub fn roadmap_nodes(&self) -> usize {
        self.roadmap.as_ref().map(|r| r.nodes().len()).unwrap_or(0)
    }

    /// A bump: counts it, marks its contact point, gives up a route point bumped on again and
    /// again, and backs off turning away from the pressed side.
    fn on_bump(&mut self, input: &NavInput, now: Time) {
        self.stats.bumps += 1;
        // The contact point: the bumper's edge, on the pressed side.
        let side = match (input.bumps.bump_left, input.bumps.bump_right) {
            (true, false) => 0.6,
            (false, true) => -0.6,
            _ => 0.0,
        };
        let r = self.config.robot_radius + 0.02;
        self.bump_marks.push(
            input
                .pose
                .transform_point([r * f64::cos(side), r * f64::sin(side)]),
        );
        // A route point the robot bumps on its way to, again and again, lies past
        // something the map does not hold or the robot cannot pass (a gap as wide as its
        // clearance between jagged walls): it is given up for the next.
        if let Task::Route(route) = &self.task {
            self.route_bumps += 1;
            if self.route_bumps >= ROUTE_BUMP_LIMIT && self.route_next < route.len() {
                self.route_next += 1;
                self.stats.route_points_skipped += 1;
                self.route_bumps = 0;
            }
        }
        // Turn away from the pressed side (seed 000: right bumper, turn left).
        let away = if input.bumps.bump_right && !input.bumps.bump_left {
            1.0
        } else {
            -1.0
        };
        self.start_backing(now, away);
    }

    /// One control tick.
    pub fn update(&mut self, input: &NavInput) -> DriveCommand {
        if let Some(m) = input.map {
            self.map = Some(m.clone());
        }
        let now = input.now;
        if self.mode == Mode::Done {
            return DriveCommand::STOP;
        }
        // A bump interrupts everything but a back-off already under way.
        if input.bumps.bumped() && !matches!(self.mode, Mode::Backing(..)) {
            self.on_bump(input, now);
        }
        if let Mode::Backing(until, away, turn_until) = self.mode {
            let c = &self.config;
            if now < until
                && yielding::behind(
                    &input.pose,
                    input.people,
                    c.backup_distance,
                    c.people_clearance,
                )
            {
                // Someone walked up behind: stop backing, and try the way ahead again.
                self.mode = Mode::Blocked(now);
                self.follower = None;
                return DriveCommand::STOP;
            }
            if now < until {
                return DriveCommand::Drive {
                    velocity: -self.config.backup_speed,
                    radius: Radius::Straight,
                };
            }
            if now < turn_until {
                return DriveCommand::Drive {
                    velocity: self.config.turn_speed,
                    radius: if away > 0.0 {
                        Radius::InPlaceCcw
                    } else {
                        Radius::InPlaceCw
                    },
                };
            }
            self.mode = Mode::Driving;
            self.follower = None;
        }
        // Exploration re-plans as the map grows.
        if matches!(self.task, Task::Explore)
            && self
                .last_plan
                .is_some_and(|t| (now - t).secs() >= self.config.replan_period)
        {
            self.follower = None;
        }
        if self
            .follower
            .as_ref()
            .is_some_and(|f| f.distance_from_path(&input.pose) > self.config.off_path_replan)
        {
            self.follower = None;
        }
        if self.follower.is_none()
            && let Some(cmd) = self.plan_or_recover(now, &input.pose)
        {
            return cmd;
        }
        let route = matches!(self.task, Task::Route(_));
        let c = self.config;
        let Some(f) = self.follower.as_mut() else {
            return DriveCommand::STOP;
        };
        // The scan is looked at only near a route point, not at every tick.
        if route
            && let Some(&goal) = f.path().get(f.target())
            && (goal[0] - input.pose.x).hypot(goal[1] - input.pose.y) <= c.goal_tolerance
            && let Some((scan, mount)) = input.scan
            && wall_ends_lane(scan, self.beams.of(scan), &mount, &c)
        {
            f.advance();
        }
        let cmd = f.command(&input.pose);
        if let Task::Route(route) = &self.task {
            // Points of the route the follower has passed.
            let passed = f.target().saturating_sub(self.route_at);
            let next = (self.route_next + passed).min(route.len());
            if f.target() > self.route_at {
                self.stats.route_points_passed += next - self.route_next;
                if next > self.route_next {
                    self.route_bumps = 0;
                }
                self.route_next = next;
                self.route_at = f.target();
            }
        }
        if f.done() {
            self.follower = None;
            match self.task {
                Task::Goals(_) => {
                    self.stats.goals_reached += 1;
                    self.next_goal += 1;
                }
                Task::Explore => {
                    // The frontier should be seen by now; if it is still there next time,
                    // it cannot be resolved from here.
                    self.exhausted.push([input.pose.x, input.pose.y]);
                    self.stats.frontiers_exhausted += 1;
                }
                Task::Route(_) => self.mode = Mode::Done,
            }
            return DriveCommand::STOP;
        }
        // The obstacle check applies to motion forward (arcs and straight lines).
        let forward = match cmd {
            DriveCommand::Drive { velocity, radius } => {
                velocity > 0.0 && matches!(radius, Radius::Straight | Radius::Arc(_))
            }
            DriveCommand::DriveDirect { left, right } => left + right > 0.0,
        };
        if forward && self.yields(input) {
            return DriveCommand::STOP;
        }
        if forward && let Some((scan, mount)) = input.scan {
            self.beams.of(scan);
            if self.blocked(scan, self.beams.dirs(), &mount, &input.pose) {
                match self.mode {
                    Mode::Blocked(since) => {
                        let c = &self.config;
                        // Not back into someone: wait on while a person is behind.
                        if (now - since).secs() >= c.blocked_timeout
                            && !yielding::behind(
                                &input.pose,
                                input.people,
                                c.backup_distance,
                                c.people_clearance,
                            )
                        {
                            self.start_backing(now, 1.0);
                        }
                    }
                    _ => {
                        self.stats.obstacle_stops += 1;
                        self.mode = Mode::Blocked(now);
                    }
                }
                return DriveCommand::STOP;
            }
            self.mode = Mode::Driving;
        }
        cmd
    }

    /// Whether to stop for people now (see [`yielding`]); after `people_patience` stopped,
    /// plans a way round them to the goal.
    fn yields(&mut self, input: &NavInput) -> bool {
        let c = self.config;
        let now = input.now;
        // The people a detour goes round are no risk while they stand where they stood.
        let people: Vec<TrackedPerson> = input
            .people
            .iter()
            .filter(|p| {
                !self.detoured.iter().any(|(id, at)| {
                    *id == p.id
                        && (p.position[0] - at[0]).hypot(p.position[1] - at[1])
                            < yielding::STILL_WITHIN
                })
            })
            .copied()
            .collect();
        let risk = c.people_clearance > 0.0
            && yielding::at_risk(
                &input.pose,
                c.speed,
                &people,
                c.people_clearance,
                c.people_horizon,
            );
        if !risk {
            if matches!(self.mode, Mode::Yielding(..)) {
                self.mode = Mode::Driving;
            }
            return false;
        }
        let since = match self.mode {
            Mode::Yielding(since, last) => {
                self.stats.people_wait_s += (now - last).secs();
                since
            }
            _ => {
                self.stats.people_stops += 1;
                now
            }
        };
        self.mode = Mode::Yielding(since, now);
        let goal = match &self.task {
            Task::Goals(goals) => goals.get(self.next_goal).copied(),
            Task::Route(route) => route.get(self.route_next).copied(),
            Task::Explore => None,
        };
        if (now - since).secs() >= c.people_patience
            && let (Some(goal), Some(roadmap)) = (goal, &self.roadmap)
        {
            // Patience is spent either way: wait another spell before trying again.
            self.mode = Mode::Yielding(now, now);
            if let Some(path) = yielding::detour(
                roadmap.grid(),
                c.planner.clearance,
                input.people,
                c.people_clearance,
                [input.pose.x, input.pose.y],
                goal,
            ) {
                self.stats.people_detours += 1;
                self.follower = Some(PathFollower::new(c.follow_params(&self.task), path));
                self.detoured = input.people.iter().map(|p| (p.id, p.position)).collect();
                self.mode = Mode::Driving;
                // The new path is followed from the next tick.
            }
        }
        true
    }

    fn start_backing(&mut self, now: Time, away: f64) {
        let back = self.config.backup_distance / self.config.backup_speed;
        // A quarter-turn's worth of turning away: 30° at the turn speed.
        let wheel_base = crate::control::pursuit::CREATE_WHEEL_BASE;
        let turn = 30f64.to_radians() * wheel_base / 2.0 / self.config.turn_speed;
        self.mode = Mode::Backing(
            now + futago_msgs::Duration::from_secs(back),
            away,
            now + futago_msgs::Duration::from_secs(back + turn),
        );
        self.follower = None;
    }

    /// Whether a laser return the map does not explain lies in the strip ahead the robot is
    /// about to sweep (seed 000 compares the scan with the map to find obstacles that are not
    /// in it; walls that are in it are the planner's business).
    /// `dirs`: the scan's beam directions ([`BeamDirections`]).
    fn blocked(&self, scan: &LaserScan, dirs: &[[f64; 2]], mount: &Pose2, pose: &Pose2) -> bool {
        debug_assert_eq!(
            dirs.len(),
            scan.ranges.len(),
            "the directions of another scan"
        );
        let c = &self.config;
        let mount = mount.transform();
        let ahead = c.robot_radius + c.stop_distance;
        let half = c.robot_radius + c.stop_margin;
        let map = self
            .roadmap
            .as_ref()
            .map(|r| r.grid())
            .or(self.map.as_ref());
        scan.ranges.iter().zip(dirs).any(|(&r, &[cos, sin])| {
            let r = r as f64;
            if !r.is_finite() || r < scan.range_min {
                return false;
            }
            let p = mount.apply([r * cos, r * sin]);
            if !(p[0] > 0.0 && p[0] < ahead && p[1].abs() < half) {
                return false;
            }
            let w = pose.transform_point(p);
            !map.is_some_and(|m| mapped_obstacle_near(m, w, MAP_MATCH_CELLS))
        })
    }

    /// Plans a path when the robot has none to follow; gives the command to give instead when
    /// there is no path. No path reaches the route's next points from the pose the robot
    /// believes it has (one inside a wall's margin): the estimate is likely off. Standing gives
    /// the localiser nothing new (MCL takes scans only as the robot moves), so the robot turns
    /// in place, as Nav2's spin recovery does, and plans again as it turns: every
    /// [`SPIN_REPLAN_PERIOD`], not at every control tick, since each failed plan searches the
    /// whole reachable grid for each of the next route points.
    fn plan_or_recover(&mut self, now: Time, pose: &Pose2) -> Option<DriveCommand> {
        let route = matches!(self.task, Task::Route(_));
        let spinning = route
            && self
                .route_failed
                .is_some_and(|t| (now - t).secs() < SPIN_REPLAN_PERIOD);
        if !spinning && self.plan(now, pose) {
            self.route_failed = None;
            return None;
        }
        if !route || matches!(self.mode, Mode::Done) {
            return Some(DriveCommand::STOP);
        }
        if !spinning {
            self.route_failed = Some(now);
            self.stats.failed_plans += 1;
        }
        Some(DriveCommand::Drive {
            velocity: self.config.turn_speed,
            radius: Radius::InPlaceCcw,
        })
    }

    /// Plans the next leg; false when there is nothing to do now (done, or no map yet).
    fn plan(&mut self, now: Time, pose: &Pose2) -> bool {
        let start = [pose.x, pose.y];
        self.last_plan = Some(now);
        self.detoured.clear();
        match &self.task {
            Task::Goals(goals) => {
                let Some(roadmap) = &self.roadmap else {
                    self.mode = Mode::Done;
                    return false;
                };
                while self.next_goal < goals.len() {
                    let goal = goals[self.next_goal];
                    // A start the road map does not join (a pose estimate close to a wall)
                    // is planned from on the grid.
                    let path = roadmap.plan(start, goal).or_else(|| {
                        planner::grid_route(
                            roadmap.grid(),
                            self.config.planner.clearance,
                            start,
                            goal,
                        )
                    });
                    if let Some(path) = path {
                        self.stats.plans += 1;
                        self.follower = Some(PathFollower::new(
                            self.config.follow_params(&self.task),
                            path,
                        ));
                        return true;
                    }
                    self.stats.goals_unreachable += 1;
                    self.next_goal += 1;
                }
                self.mode = Mode::Done;
                false
            }
            Task::Route(route) => {
                let Some(roadmap) = &self.roadmap else {
                    self.mode = Mode::Done;
                    return false;
                };
                // A point no path reaches is given up when a later one is reached; when none
                // of the next few is, the trouble is where the robot is (a localisation
                // error): it turns in place and tries again, and gives nothing up.
                for ahead in 0..ROUTE_LOOKAHEAD {
                    let k = self.route_next + ahead;
                    let Some(&goal) = route.get(k) else { break };
                    // Route points keep the coverage planner's clearance, less than the road
                    // map's: the grid fallback keeps the Create's radius and a centimetre.
                    let path = roadmap.plan(start, goal).or_else(|| {
                        planner::grid_route(
                            roadmap.grid(),
                            self.config.planner.clearance.min(ROUTE_CLEARANCE),
                            start,
                            goal,
                        )
                    });
                    if let Some(mut path) = path {
                        self.stats.plans += 1;
                        self.stats.route_points_skipped += ahead;
                        self.route_next = k;
                        self.route_at = path.len() - 1;
                        path.extend_from_slice(&route[k + 1..]);
                        self.follower = Some(PathFollower::new(
                            self.config.follow_params(&self.task),
                            path,
                        ));
                        return true;
                    }
                }
                if self.route_next >= route.len() {
                    self.mode = Mode::Done;
                }
                false
            }
            Task::Explore => {
                let Some(map) = &self.map else {
                    return false;
                };
                let mut map = map.clone();
                for m in &self.bump_marks {
                    if let Some((i, j)) = map.cell_of(m[0], m[1]) {
                        map.set(i, j, 100);
                    }
                }
                let c = &self.config;
                match path_to_frontier(
                    &map,
                    start,
                    c.frontier_min_length,
                    c.planner.clearance,
                    &self.exhausted,
                    c.frontier_exclusion,
                ) {
                    Some(path) => {
                        self.stats.plans += 1;
                        self.follower = Some(PathFollower::new(c.follow_params(&self.task), path));
                        true
                    }
                    None => {
                        self.mode = Mode::Done;
                        false
                    }
                }
            }
        }
    }
}

/// Whether `scan` (from a laser at `mount`) finds the wall a route point lies against: the
/// nearest of its returns, once despeckled ([`despeckled`]), that lies ahead within the
/// bumper's middle half ([`ROUTE_WALL_BAND`]), within `route_wall_margin` of the bumper. The
/// raw nearest return read a wall ahead short by the laser's noise (the nearest of some 300
/// returns of σ = 3 cm on seed 000's laser, 8 cm short), ending lanes 5 cm before their
/// corners, and took a few noisy readings of a wall alongside for one ahead.
fn wall_ends_lane(
    scan: &LaserScan,
    dirs: &[[f64; 2]],
    mount: &Pose2,
    c: &NavigationConfig,
) -> bool {
    let half_width = c.robot_radius * ROUTE_WALL_BAND;
    let reach = c.robot_radius + c.route_wall_margin;
    // Windows whose median x is not ahead within `reach` (most of a scan, which lies farther
    // or behind) are passed over without taking their medians, a tenth of a coverage run's
    // time.
    despeckled(scan, dirs, mount, |xs| median_within(xs, 0.0, reach))
        .filter(|p| p[0] > 0.0 && p[1].abs() < half_width)
        .any(|p| p[0] <= reach)
}

/// The directions `[cos a, sin a]` of a scan's beams (`a` its k-th beam's angle), kept while
/// the scans' geometry (first angle, increment, count) stays: the navigator looks at the scan
/// at every control tick, and a sine and cosine a beam were a tenth of a coverage run's time.
#[derive(Debug, Default)]
struct BeamDirections {
    /// The geometry the directions are of: the first angle's and the increment's bits, and the
    /// beam count.
    geometry: Option<(u64, u64, usize)>,
    dirs: Vec<[f64; 2]>,
}

impl BeamDirections {
    /// The directions of `scan`'s beams, computed again only when its geometry differs from
    /// the last scan's.
    fn of(&mut self, scan: &LaserScan) -> &[[f64; 2]] {
        let geometry = (
            scan.angle_min.to_bits(),
            scan.angle_increment.to_bits(),
            scan.ranges.len(),
        );
        if self.geometry != Some(geometry) {
            self.dirs = beam_directions(scan);
            self.geometry = Some(geometry);
        }
        &self.dirs
    }

    /// The directions [`BeamDirections::of`] last gave.
    fn dirs(&self) -> &[[f64; 2]] {
        &self.dirs
    }
}

/// The directions `[cos a, sin a]` of `scan`'s beams.
fn beam_directions(scan: &LaserScan) -> Vec<[f64; 2]> {
    (0..scan.ranges.len())
        .map(|k| {
            let a = scan.angle(k);
            [a.cos(), a.sin()]
        })
        .collect()
}

/// Whether the median of `xs` (its element at index `len / 2` in order; finite values) lies in
/// (`lo`, `hi`], by counting rather than selecting: the median is at most `hi` where more than
/// half the values are, and above `lo` where at most `len / 2` of them are not.
fn median_within(xs: &[f64], lo: f64, hi: f64) -> bool {
    2 * xs.iter().filter(|&&x| x <= hi).count() > xs.len()
        && xs.iter().filter(|&&x| x <= lo).count() <= xs.len() / 2
}

/// Beams a laser return is despeckled over ([`despeckled`]).
const DESPECKLE_BEAMS: usize = 9;

/// A scan's returns in the robot's frame, each the component-wise median of the returns of
/// [`DESPECKLE_BEAMS`] neighbouring beams (at least half of them valid): a running median
/// along the scan, as ROS's laser_filters' median filter, which keeps an object that spans a
/// few beams and drops a reading that noise alone throws in. Windows whose valid returns'
/// x coordinates `wanted` rejects are left out unmedianed: a caller that needs only the
/// medians within some bound skips the selections that cannot meet it. `dirs`: the beams'
/// directions ([`BeamDirections`]).
fn despeckled<'a>(
    scan: &'a LaserScan,
    dirs: &[[f64; 2]],
    mount: &'a Pose2,
    wanted: impl Fn(&[f64]) -> bool + 'a,
) -> impl Iterator<Item = [f64; 2]> + 'a {
    let mount = mount.transform();
    let points: Vec<Option<[f64; 2]>> = scan
        .ranges
        .iter()
        .zip(dirs)
        .map(|(&r, &[cos, sin])| {
            let r = r as f64;
            (r.is_finite() && r >= scan.range_min && r <= scan.range_max)
                .then(|| mount.apply([r * cos, r * sin]))
        })
        .collect();
    let n = points.len();
    // Each window's coordinates in fixed arrays: no allocation per beam.
    (0..n.saturating_sub(DESPECKLE_BEAMS - 1)).filter_map(move |k| {
        let (mut xs, mut ys) = ([0.0; DESPECKLE_BEAMS], [0.0; DESPECKLE_BEAMS]);
        let mut m = 0;
        for p in points[k..k + DESPECKLE_BEAMS].iter().flatten() {
            (xs[m], ys[m]) = (p[0], p[1]);
            m += 1;
        }
        if 2 * m < DESPECKLE_BEAMS || !wanted(&xs[..m]) {
            return None;
        }
        let median = |v: &mut [f64]| *v.select_nth_unstable_by(v.len() / 2, f64::total_cmp).1;
        Some([median(&mut xs[..m]), median(&mut ys[..m])])
    })
}

/// How often a robot spinning because its route found no path plans again, s: a turn of about
/// 0.45 rad at the navigator's turning speed (0.93 rad/s), against every control tick
/// (15 ms) before, when a robot that could not get out spun out the run planning 67 times a
/// second (`hall-scan3d-random` seed 3 had not finished after 30 minutes; now 82 s).
const SPIN_REPLAN_PERIOD: f64 = 0.5;
/// Bumps on the way to one route point after which it is given up.
const ROUTE_BUMP_LIMIT: usize = 3;
/// How many route points ahead a route driver tries when the next cannot be reached.
const ROUTE_LOOKAHEAD: usize = 5;
/// The share of the robot's radius each side of its centre line in which a laser return
/// counts as the wall a route point lies against ([`NavigationConfig::route_wall_margin`]):
/// the middle half of the bumper. A wall the lane ends against crosses it, and so does the
/// corner of a pillar the point lies beside; a wall alongside, which the route passes at its
/// clearance (3 cm) less one map cell and the pose's error, lies nearer than the robot's
/// radius to its centre line and, counted across the whole bumper, ended lanes along walls up
/// to `goal_tolerance` short (`office-coverage-bcd-truth` seed 1: the robot turned 13 cm short
/// of the corner at (16.375, 15.675), the wall beside it).
const ROUTE_WALL_BAND: f64 = 0.5;
/// Least clearance of a grid path to a route point, m: the Create's radius and 1 cm.
const ROUTE_CLEARANCE: f64 = 0.18;

/// A return within this many cells of an occupied map cell is the map's obstacle.
const MAP_MATCH_CELLS: i64 = 2;

/// Whether an occupied or unknown cell of `map` lies within `cells` cells of world point `p`
/// (a return in unknown space is not a contradiction of the map: the map has not caught up).
fn mapped_obstacle_near(map: &OccupancyGrid, p: [f64; 2], cells: i64) -> bool {
    let i = ((p[0] - map.origin[0]) / map.resolution).floor() as i64;
    let j = ((p[1] - map.origin[1]) / map.resolution).floor() as i64;
    (j - cells..=j + cells).any(|b| {
        (i - cells..=i + cells).any(|a| {
            a >= 0 && b >= 0 && (a as usize) < map.width && (b as usize) < map.height && {
                let c = map.get(a as usize, b as usize);
                !(0..crate::geometry::grid::OCCUPIED).contains(&c)
            }
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 6 × 4 m room, free inside, 5 cm cells.
    fn room() -> OccupancyGrid {
        crate::geometry::grid::walled(120, 80)
    }

    /// A navigator driving `route` in [`room`], the robot at (1, 1) facing east, and the
    /// tests' control period, s.
    fn route_in_room(route: &[[f64; 2]]) -> (Navigator, Pose2, f64) {
        let nav = Navigator::new(
            NavigationConfig::default(),
            Task::Route(route.to_vec()),
            Some(room()),
        );
        (nav, Pose2::new(1.0, 1.0, 0.0), 0.05)
    }

    /// The navigator's input at tick `k` of `dt` s with only a pose: no bump, scan, map or
    /// people.
    fn plain_input(k: usize, dt: f64, pose: Pose2) -> NavInput<'static> {
        NavInput {
            now: Time::from_secs(k as f64 * dt),
            pose,
            bumps: BumpsAndDrops::default(),
            scan: None,
            map: None,
            people: &[],
        }
    }

    fn scan_with_return_at(distance: f64) -> LaserScan {
        LaserScan {
            frame: "front".into(),
            stamp: Time::ZERO,
            angle_min: -0.5,
            angle_increment: 0.5,
            time_increment: 0.0,
            range_min: 0.02,
            range_max: 30.0,
            ranges: vec![f32::INFINITY, distance as f32, f32::INFINITY],
        }
    }

    /// A wall square across the way `distance` ahead, as a laser at the robot's centre sees
    /// it with 1° beams over the front half.
    fn wall_ahead_scan(distance: f64) -> LaserScan {
        LaserScan {
            angle_min: -std::f64::consts::FRAC_PI_2,
            angle_increment: 1f64.to_radians(),
            ranges: (0..181)
                .map(|k| {
                    let c = (k as f64 - 90.0).to_radians().cos();
                    if c > 0.05 {
                        (distance / c) as f32
                    } else {
                        f32::INFINITY
                    }
                })
                .collect(),
            ..scan_with_return_at(1.0)
        }
    }

    /// Drives a unicycle on the commands: the navigator reaches both goals, in order.
    #[test]
    fn navigator_drives_to_goals_on_a_known_map() {
        let mut nav = Navigator::new(
            NavigationConfig::default(),
            Task::Goals(vec![[5.0, 3.0], [1.0, 1.0]]),
            Some(room()),
        );
        let mut pose = Pose2::new(1.0, 1.0, 0.0);
        let dt = 0.05;
        let mut visited = Vec::new();
        for k in 0..4000 {
            let cmd = nav.update(&plain_input(k, dt, pose));
            let (v, w) = unicycle(&cmd);
            pose = pose.compose(&Pose2::new(v * dt, 0.0, w * dt));
            if (pose.x - 5.0).hypot(pose.y - 3.0) < 0.2 {
                visited.push(k);
            }
            if nav.finished() {
                break;
            }
        }
        assert!(nav.finished());
        assert_eq!(nav.stats().goals_reached, 2);
        assert!(!visited.is_empty());
        assert!((pose.x - 1.0).hypot(pose.y - 1.0) < 0.2, "{pose:?}");
    }

    #[test]
    fn an_obstacle_ahead_stops_the_robot_and_a_bump_backs_it_off() {
        let mut nav = Navigator::new(
            NavigationConfig::default(),
            Task::Goals(vec![[5.0, 1.0]]),
            Some(room()),
        );
        fn input(t: f64, scan: Option<(&LaserScan, Pose2)>, bumps: BumpsAndDrops) -> NavInput<'_> {
            NavInput {
                now: Time::from_secs(t),
                pose: Pose2::new(1.0, 1.0, 0.0),
                bumps,
                scan,
                map: None,
                people: &[],
            }
        }
        let clear = scan_with_return_at(2.0);
        let close = scan_with_return_at(0.25);
        let mount = Pose2::IDENTITY;
        let (v, _) = unicycle(&nav.update(&input(0.0, Some((&clear, mount)), Default::default())));
        assert!(v > 0.0);
        assert_eq!(
            nav.update(&input(0.1, Some((&close, mount)), Default::default())),
            DriveCommand::STOP
        );
        assert_eq!(nav.stats().obstacle_stops, 1);
        let (v, _) = unicycle(&nav.update(&input(0.2, Some((&clear, mount)), Default::default())));
        assert!(v > 0.0, "resumes when clear");
        let right = BumpsAndDrops {
            bump_right: true,
            ..Default::default()
        };
        let (v, _) = unicycle(&nav.update(&input(0.3, None, right)));
        assert!(v < 0.0, "backs off");
        // After the back-off it turns away from the right bumper: left.
        let (v, w) = unicycle(&nav.update(&input(1.85, None, Default::default())));
        assert!(v == 0.0 && w > 0.0, "{v} {w}");
        assert_eq!(nav.stats().bumps, 1);
    }

    /// A route is driven through every point to its end; pushed 1.5 m off it half way, the
    /// robot plans back to the first point it had not passed and goes on from there.
    #[test]
    fn a_route_is_driven_to_its_end_and_rejoined_after_a_push() {
        // Up and down the room's left half in 1 m lanes.
        let route: Vec<[f64; 2]> = vec![
            [1.0, 1.0],
            [4.0, 1.0],
            [4.0, 2.0],
            [1.0, 2.0],
            [1.0, 3.0],
            [4.0, 3.0],
        ];
        let (mut nav, mut pose, dt) = route_in_room(&route);
        let mut pushed = false;
        let mut near = vec![false; route.len()];
        for k in 0..8000 {
            let cmd = nav.update(&plain_input(k, dt, pose));
            let (v, w) = unicycle(&cmd);
            pose = pose.compose(&Pose2::new(v * dt, 0.0, w * dt));
            for (n, p) in route.iter().enumerate() {
                near[n] |= (pose.x - p[0]).hypot(pose.y - p[1]) < 0.2;
            }
            if !pushed && nav.stats().route_points_passed == 3 {
                // Just past [4, 2]: pushed 1.5 m east, beyond the wall at x = 5 m.
                pose = Pose2::new(pose.x + 1.5, pose.y, pose.theta);
                pushed = true;
            }
            if nav.finished() {
                break;
            }
        }
        assert!(nav.finished() && pushed);
        assert_eq!(nav.stats().route_points_passed, route.len());
        assert_eq!(nav.stats().route_points_skipped, 0);
        assert!(near.iter().all(|n| *n), "{near:?}");
        assert!((pose.x - 4.0).hypot(pose.y - 3.0) < 0.2, "{pose:?}");
        // A new route starts it again.
        nav.set_route(vec![[4.0, 3.0], [4.0, 4.0]]);
        assert!(!nav.finished());
    }

    /// A route's last point lies 0.2 m from a wall (the Create's radius and 3 cm), and the
    /// pose estimate lags the robot by 5 cm: the lane ends where the laser finds the wall
    /// 3 cm ahead of the bumper, short of contact, and not where the estimate reaches the point
    /// (the true bumper would be in the wall by then).
    #[test]
    fn a_lane_against_a_wall_ends_where_the_laser_finds_the_wall() {
        let wall_x = 5.95;
        let route: Vec<[f64; 2]> = vec![[1.0, 1.0], [wall_x - 0.2, 1.0]];
        let (mut nav, mut truth, dt) = route_in_room(&route);
        let lag = 0.05;
        for k in 0..4000 {
            let estimate = Pose2::new(truth.x - lag, truth.y, truth.theta);
            let scan = wall_ahead_scan(wall_x - truth.x);
            let input = NavInput {
                scan: Some((&scan, Pose2::IDENTITY)),
                ..plain_input(k, dt, estimate)
            };
            let (v, w) = unicycle(&nav.update(&input));
            truth = truth.compose(&Pose2::new(v * dt, 0.0, w * dt));
            assert!(
                wall_x - truth.x > 0.17,
                "the bumper met the wall: {truth:?}"
            );
            if nav.finished() {
                break;
            }
        }
        assert!(nav.finished());
        assert_eq!(nav.stats().route_points_passed, route.len());
        // Stopped within a few millimetres (a tick's travel) of the wall margin.
        assert!((wall_x - truth.x - 0.2).abs() < 0.02, "{truth:?}");
    }

    /// The wall a lane ends against, and a wall alongside the lane 16 cm from the robot's
    /// centre (the route's 3 cm clearance less a map cell's quantisation and the pose's
    /// error): only the first ends the lane. Counted across the whole bumper, the wall
    /// alongside ended lanes up to `goal_tolerance` (15 cm) short of their corners, leaving
    /// their floor unswept (`office-coverage-bcd-truth` lost 2.8 % of its promise). Through
    /// seed 000's laser noise (σ = 3 cm, 0.25° beams) the wall ahead is read near its
    /// distance, not at the nearest of its noisy returns, and a pillar's corner in the way
    /// still counts.
    #[test]
    fn only_a_wall_ahead_ends_a_lane_not_one_alongside() {
        use rand::SeedableRng;
        use rand_distr::Distribution;
        let c = NavigationConfig::default();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let noise = rand_distr::Normal::new(0.0, 0.03).unwrap();
        // A straight wall through `a` along direction `dir` (robot frame), as a laser at the
        // centre sees it over the front half, with readings of standard deviation `sigma`.
        let mut scan_of_wall = |a: [f64; 2], dir: [f64; 2], sigma: f64| {
            let step = 0.25f64;
            let n = (180.0 / step) as usize + 1;
            let ranges = (0..n)
                .map(|k| {
                    let t = (k as f64 * step - 90.0).to_radians();
                    let (u, v) = (t.cos(), t.sin());
                    // Solve s·(u, v) = a + q·dir for s.
                    let det = u * -dir[1] - v * -dir[0];
                    let s = (a[0] * -dir[1] - a[1] * -dir[0]) / det;
                    let e = sigma * noise.sample(&mut rng);
                    if det.abs() > 1e-9 && s > 0.0 && s < 30.0 {
                        (s + e).max(0.03) as f32
                    } else {
                        f32::INFINITY
                    }
                })
                .collect();
            LaserScan {
                angle_min: -std::f64::consts::FRAC_PI_2,
                angle_increment: step.to_radians(),
                ranges,
                ..scan_with_return_at(1.0)
            }
        };
        let mount = Pose2::IDENTITY;
        for sigma in [0.0, 1.0] {
            let alongside = scan_of_wall([0.0, 0.16], [1.0, 0.0], sigma);
            assert!(
                !wall_ends_lane(&alongside, &beam_directions(&alongside), &mount, &c),
                "σ × {sigma}"
            );
            // The same wall, the robot 5° off the lane towards it.
            let (s5, c5) = 5f64.to_radians().sin_cos();
            let angled = scan_of_wall([0.0, 0.19 / c5], [c5, -s5], sigma);
            assert!(
                !wall_ends_lane(&angled, &beam_directions(&angled), &mount, &c),
                "σ × {sigma}"
            );
            // The wall the lane ends against, 3 cm ahead of the bumper less 1 cm, square or
            // 20° off.
            let ahead = scan_of_wall([0.19, 0.0], [0.0, 1.0], sigma);
            assert!(
                wall_ends_lane(&ahead, &beam_directions(&ahead), &mount, &c),
                "σ × {sigma}"
            );
            let (s20, c20) = 20f64.to_radians().sin_cos();
            let skew = scan_of_wall([0.19, 0.0], [s20, c20], sigma);
            assert!(
                wall_ends_lane(&skew, &beam_directions(&skew), &mount, &c),
                "σ × {sigma}"
            );
            // 5 cm further (the planned lane end may lie up to a map cell short of the true
            // wall) it does not yet.
            let far = scan_of_wall([0.25, 0.0], [0.0, 1.0], sigma);
            assert!(
                !wall_ends_lane(&far, &beam_directions(&far), &mount, &c),
                "σ × {sigma}"
            );
            // A pillar's face ahead of the bumper's right, its corner 5 cm right of the centre
            // line: the robot would bump it (`hall-scan3d-frontier` seed 1, at (30.35, 0.96)
            // beside the pillar at (30, 0.5)).
            let mut corner = scan_of_wall([0.19, 0.0], [0.0, 1.0], sigma);
            for (k, r) in corner.ranges.iter_mut().enumerate() {
                let a = corner.angle_min + k as f64 * corner.angle_increment;
                if (*r as f64 * a.sin()) > -0.05 {
                    *r = f32::INFINITY;
                }
            }
            assert!(
                wall_ends_lane(&corner, &beam_directions(&corner), &mount, &c),
                "σ × {sigma}"
            );
        }
    }

    /// Counting finds the median's interval as selecting it does: on windows of every length
    /// a despeckled window can have, with values on, about and between the interval's ends.
    #[test]
    fn counting_places_the_median_as_selecting_it_does() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let (lo, hi) = (0.0, 0.2);
        let values = [-0.1, -0.0, 0.0, 0.05, 0.2, 0.3];
        let mut inside = 0;
        for _ in 0..20_000 {
            let n = rng.random_range(DESPECKLE_BEAMS.div_ceil(2)..=DESPECKLE_BEAMS);
            let mut xs: Vec<f64> = (0..n)
                .map(|_| match rng.random_range(0..2) {
                    0 => values[rng.random_range(0..values.len())],
                    _ => rng.random_range(-0.3..0.5),
                })
                .collect();
            let got = median_within(&xs, lo, hi);
            let m = *xs.select_nth_unstable_by(n / 2, f64::total_cmp).1;
            assert_eq!(got, m > lo && m <= hi, "{xs:?}");
            inside += usize::from(got);
        }
        assert!((4_000..16_000).contains(&inside), "{inside}");
    }

    /// Passing over the windows whose median cannot come within reach gives the answer that
    /// taking every window's median does: on scans of walls at random distances and angles,
    /// with seed 000's noise and gaps, about half of which end the lane.
    #[test]
    fn the_windows_passed_over_could_not_end_the_lane() {
        use rand::{Rng, SeedableRng};
        let c = NavigationConfig::default();
        let reach = c.robot_radius + c.route_wall_margin;
        let half_width = c.robot_radius * ROUTE_WALL_BAND;
        let every = |scan: &LaserScan, mount: &Pose2| {
            despeckled(scan, &beam_directions(scan), mount, |_| true)
                .filter(|p| p[0] > 0.0 && p[1].abs() < half_width)
                .any(|p| p[0] <= reach)
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let mut ended = 0;
        for _ in 0..400 {
            let d = rng.random_range(0.1..0.4);
            let tilt: f64 = rng.random_range(-0.6..0.6);
            let step = 0.25f64.to_radians();
            // A URG-04LX's 240°: the beams that miss the wall ahead see one behind.
            let (first, behind) = (-120f64.to_radians(), rng.random_range(0.05..0.5));
            let ranges = (0..961)
                .map(|k| {
                    let t = first + k as f64 * step;
                    let ahead = d / (t - tilt).cos();
                    let s = if ahead > 0.0 {
                        ahead
                    } else {
                        behind / (t - std::f64::consts::PI).cos()
                    };
                    let r = s + rng.random_range(-0.05..0.05);
                    if !(0.0..30.0).contains(&s) || rng.random_bool(0.2) {
                        f32::INFINITY
                    } else {
                        r.max(0.02) as f32
                    }
                })
                .collect();
            let scan = LaserScan {
                angle_min: first,
                angle_increment: step,
                ranges,
                ..scan_with_return_at(1.0)
            };
            let mount = Pose2::new(rng.random_range(-0.1..0.1), 0.0, 0.0);
            let got = wall_ends_lane(&scan, &beam_directions(&scan), &mount, &c);
            assert_eq!(got, every(&scan, &mount), "{d} {tilt}");
            ended += usize::from(got);
        }
        assert!((100..300).contains(&ended), "{ended} of 400 ended");
    }

    /// A pose estimate inside a wall's margin, from which no path reaches the route: the
    /// robot turns in place (giving the localiser new views) instead of standing, gives no
    /// route point up, and drives the route once the estimate is back on the free floor.
    #[test]
    fn a_route_unreachable_from_the_estimate_turns_the_robot_in_place() {
        let route: Vec<[f64; 2]> = vec![[1.0, 1.0], [4.0, 1.0]];
        let (mut nav, _, dt) = route_in_room(&route);
        let lost = Pose2::new(0.06, 2.0, 0.0);
        for k in 0..40 {
            let cmd = nav.update(&plain_input(k, dt, lost));
            let (v, w) = unicycle(&cmd);
            assert!(v.abs() < 1e-9 && w > 0.0, "{cmd:?}");
        }
        assert_eq!(nav.stats().route_points_skipped, 0);
        // Spinning for 2 s, it planned again every 0.5 s (at 0, 0.5, 1 and 1.5 s), not at
        // every tick.
        assert_eq!(nav.stats().failed_plans, 4);
        let mut pose = Pose2::new(1.0, 1.2, 0.0);
        for k in 40..4000 {
            let (v, w) = unicycle(&nav.update(&plain_input(k, dt, pose)));
            pose = pose.compose(&Pose2::new(v * dt, 0.0, w * dt));
            if nav.finished() {
                break;
            }
        }
        assert!(nav.finished(), "{:?}", nav.stats());
        assert!((pose.x - 4.0).hypot(pose.y - 1.0) < 0.2, "{pose:?}");
    }

    /// A wall the map does not hold across the way to a route point (x = 2.5 m, below
    /// y = 1.5 m): after three bumps on the way to it the point is given up, and the robot
    /// drives on to the next (back west) instead of bumping for ever.
    #[test]
    fn a_route_point_bumped_short_of_again_and_again_is_given_up() {
        let route: Vec<[f64; 2]> = vec![[1.0, 1.0], [4.0, 1.0], [1.0, 3.0]];
        let (mut nav, mut pose, dt) = route_in_room(&route);
        for k in 0..12000 {
            let blocked = pose.x >= 2.5 - 0.17 && pose.y < 1.5;
            let cmd = nav.update(&NavInput {
                now: Time::from_secs(k as f64 * dt),
                pose,
                bumps: BumpsAndDrops {
                    bump_left: blocked,
                    bump_right: blocked,
                    ..Default::default()
                },
                scan: None,
                map: None,
                people: &[],
            });
            let (v, w) = unicycle(&cmd);
            let next = pose.compose(&Pose2::new(v * dt, 0.0, w * dt));
            // The hidden wall stops the body at it.
            pose = if next.y < 1.5 && next.x > 2.5 - 0.17 {
                Pose2::new(2.5 - 0.17, next.y, next.theta)
            } else {
                next
            };
            if nav.finished() {
                break;
            }
        }
        let st = nav.stats();
        assert!(nav.finished(), "{st:?}");
        assert_eq!(st.route_points_skipped, 1, "{st:?}");
        assert!((3..10).contains(&st.bumps), "{st:?}");
        assert!((pose.x - 1.0).hypot(pose.y - 3.0) < 0.2, "{pose:?}");
    }

    /// (v, ω) of a Create command.
    /// A person standing on the straight way to the goal stops the robot short of them;
    /// after `people_patience` it drives round them, never within the clearance, and reaches
    /// the goal. A person who walks out of the way lets it go on without a detour.
    #[test]
    fn a_person_in_the_way_is_waited_for_then_driven_round() {
        let run = |walks: bool| {
            let c = NavigationConfig::default();
            let mut nav = Navigator::new(c, Task::Goals(vec![[5.0, 2.0]]), Some(room()));
            let mut pose = Pose2::new(1.0, 2.0, 0.0);
            let dt = 0.05;
            let mut nearest = f64::INFINITY;
            let mut first_stop = None;
            for k in 0..4000 {
                let t = k as f64 * dt;
                // Standing at (3, 2); the walker leaves up the room at 1 m/s from t = 3 s.
                let vy = if walks && t >= 3.0 { 1.0 } else { 0.0 };
                let y = 2.0 + vy * (t - 3.0).max(0.0);
                let people = [TrackedPerson {
                    id: 7,
                    position: [3.0, y.min(3.8)],
                    velocity: [0.0, if y < 3.8 { vy } else { 0.0 }],
                }];
                let cmd = nav.update(&NavInput {
                    now: Time::from_secs(t),
                    pose,
                    bumps: BumpsAndDrops::default(),
                    scan: None,
                    map: None,
                    people: &people,
                });
                if first_stop.is_none() && nav.stats().people_stops > 0 {
                    first_stop = Some(pose);
                }
                let (v, w) = unicycle(&cmd);
                pose = pose.compose(&Pose2::new(v * dt, 0.0, w * dt));
                nearest = nearest.min((pose.x - 3.0).hypot(pose.y - people[0].position[1]));
                if nav.finished() {
                    break;
                }
            }
            (nav.stats(), nearest, first_stop, pose)
        };
        let (stats, nearest, stop, pose) = run(false);
        assert_eq!(stats.goals_reached, 1, "{stats:?}");
        assert_eq!(stats.people_detours, 1, "{stats:?}");
        assert!(stats.people_wait_s >= 5.0 - 0.1, "{stats:?}");
        // It stopped where driving on would have come within 0.8 m in 2 s at 0.3 m/s.
        let stop = stop.expect("it stopped");
        assert!(
            stop.x > 3.0 - 0.8 - 0.6 - 0.1 && stop.x < 3.0 - 0.8,
            "{stop:?}"
        );
        assert!(nearest > 0.8, "came {nearest} m from the person");
        assert!((pose.x - 5.0).hypot(pose.y - 2.0) < 0.2, "{pose:?}");
        let (stats, _, _, pose) = run(true);
        assert_eq!(
            (stats.goals_reached, stats.people_detours),
            (1, 0),
            "{stats:?}"
        );
        assert!(stats.people_wait_s < 5.0, "{stats:?}");
        assert!((pose.x - 5.0).hypot(pose.y - 2.0) < 0.2, "{pose:?}");
    }

    fn unicycle(cmd: &DriveCommand) -> (f64, f64) {
        let b = crate::control::pursuit::CREATE_WHEEL_BASE;
        match *cmd {
            DriveCommand::Drive { velocity, radius } => match radius {
                Radius::Straight => (velocity, 0.0),
                Radius::InPlaceCcw => (0.0, 2.0 * velocity / b),
                Radius::InPlaceCw => (0.0, -2.0 * velocity / b),
                Radius::Arc(r) => (velocity, velocity / r),
            },
            DriveCommand::DriveDirect { left, right } => ((left + right) / 2.0, (right - left) / b),
        }
    }
}
