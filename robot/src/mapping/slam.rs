//! Laser SLAM, two methods (written for futago) that share a front end.
//!
//! The front end is seed 000's: each scan is matched by ICP to a map of points, starting from
//! the odometry guess, and a scan becomes a keyframe (a node) every `keyframe_distance` of
//! travel (300 mm in seed 000) or `keyframe_angle` of turn.
//!
//! - `method = "icp"` is seed 000's SLAM: the map is every keyframe so far, and there is no
//!   loop closure. It is the baseline.
//! - `method = "graph"` matches each scan against a local map of the last `graph.local_nodes`
//!   keyframes only, and keeps the keyframes in a pose graph ([`crate::mapping::pose_graph`]) whose
//!   edges are the front end's relative poses. Every `graph.submap_nodes` keyframes form a
//!   submap, frozen in the frame of its first keyframe. Each new keyframe is searched for in
//!   the finished submaps near its estimate by branch and bound ([`crate::mapping::correlative`]) and
//!   the match refined by ICP; a match is a loop-closure edge with a Huber kernel, and the
//!   graph is re-optimised (Hess et al., ICRA 2016, with node-to-submap constraints expressed
//!   between keyframes).
//!
//! Both report every scan's pose relative to its keyframe, so the trajectory follows the
//! keyframes when the graph moves them.

use crate::config::{check_counts, check_ranges};
use crate::mapping::correlative::{LikelihoodGrid, SearchWindow, search};
use crate::mapping::icp::{IcpConfig, Oriented, PointMap, Sweep, align, fit_score, scan_points};
use crate::mapping::occupancy::{OccupancyConfig, OccupancyMap};
use crate::mapping::pose_graph::{Edge, OptimizeOptions, PoseGraph};
use futago_msgs::{LaserScan, Pose2, Time, wrap_angle};
use serde::Deserialize;

/// Which SLAM runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, serde::Serialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum SlamMethod {
    /// Seed 000: ICP to the map of all keyframes, no loop closure.
    Icp,
    /// Local ICP front end, submaps, branch-and-bound loop closure and a pose graph.
    #[default]
    Graph,
}

/// When the front end tries a constant-velocity guess beside the odometry's.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, serde::Serialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum VelocityGuess {
    /// At every scan.
    #[default]
    Always,
    /// Where the odometry stalled: it reported no motion at all since the last scan, or at the
    /// scan before (the one where it catches up). Wheel odometry that stalls reports exactly
    /// nothing; odometry that is merely noisy (Intel's) or right (the hospital's) is left
    /// alone, where a velocity guess that fitted a little better by chance did harm (see the
    /// README's "Choosing defaults by leave-one-log-out": on MIT CSAIL it recovers most of what `Always` gives,
    /// on Intel it does not cost the 3.6 % that `Always` does).
    Stalls,
    /// Never: the odometry guess alone.
    Never,
}

/// Parameters of the laser SLAM (`slam.*`).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct SlamConfig {
    pub method: SlamMethod,
    /// Travel between keyframes, m.
    pub keyframe_distance: f64,
    /// Turn between keyframes, rad.
    pub keyframe_angle: f64,
    /// Readings beyond this are not used for matching, m.
    pub max_range: f64,
    /// A match that moves the pose further than this from the odometry guess (m, rad) is
    /// refused, and the scan dead-reckoned.
    pub max_correction: f64,
    pub max_correction_angle: f64,
    /// Motion filter: a scan is matched only when odometry has moved `min_travel` (m) or
    /// turned `min_turn` (rad) since the last matched scan, or `max_interval` (s) has passed.
    /// Off by default (every scan is matched: best on logs whose odometry stalls, as MIT
    /// CSAIL's); fast lasers in simulation turn it on.
    pub min_travel: f64,
    pub min_turn: f64,
    pub max_interval: f64,
    /// When ICP also starts from a constant-velocity guess (the last scan's motion again),
    /// where it and the odometry guess disagree (see [`GUESS_DISAGREEMENT`]); the velocity
    /// guess's alignment wins when it fits `velocity_margin` times better (1 % keeps corridor
    /// ties with odometry). For odometry that stalls and then jumps.
    pub velocity_guess: VelocityGuess,
    pub velocity_margin: f64,
    /// Take each beam back to the robot's pose at the scan's stamp when the scan says its
    /// beams were cast one after another (`time_increment`), with the odometry's last motion
    /// as the velocity over the sweep.
    pub deskew: bool,
    pub icp: IcpConfig,
    pub grid: OccupancyConfig,
    pub graph: GraphConfig,
}

impl Default for SlamConfig {
    fn default() -> Self {
        SlamConfig {
            method: SlamMethod::default(),
            keyframe_distance: 0.3,
            keyframe_angle: 0.35,
            max_range: 30.0,
            max_correction: 0.5,
            max_correction_angle: 0.6,
            min_travel: 0.0,
            min_turn: 0.0,
            max_interval: 0.0,
            velocity_guess: VelocityGuess::default(),
            velocity_margin: 1.01,
            deskew: true,
            icp: IcpConfig::default(),
            grid: OccupancyConfig::default(),
            graph: GraphConfig::default(),
        }
    }
}

/// Parameters of the graph back end (`slam.graph.*`). The Huber threshold was chosen on the
/// MIT CSAIL log (issue 4's closing note has the sweep); the local map of 60 keyframes (18 m
/// of travel) on MIT CSAIL and Intel together, as the size whose result held when the keyframe
/// spacing was perturbed by ±7 % (issue 14's note). The loop windows' limits are
/// Cartographer's (7 m, 30°); the rest follow from the laser (cells of 5 cm) and the front
/// end's drift between revisits.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct GraphConfig {
    /// Keyframes in the front end's local map.
    pub local_nodes: usize,
    /// Keyframes per submap.
    pub submap_nodes: usize,
    /// A finished submap is searched when one of its keyframes lies within this of the new
    /// keyframe's estimate, m.
    pub loop_search_radius: f64,
    /// Keyframes this recent are the front end's business, not loop closure's.
    pub loop_min_age: usize,
    /// Half-widths of the branch-and-bound window, m and rad.
    pub loop_linear_window: f64,
    pub loop_angular_window: f64,
    /// Lowest mean likelihood of a loop-closure match.
    pub loop_min_score: f64,
    /// Lowest share of the scan's points that ICP pairs in the refinement.
    pub loop_min_overlap: f64,
    /// Readings used for loop closure reach at most this far, m.
    pub loop_max_range: f64,
    /// Cell of the submaps' likelihood grids and the Gaussian's standard deviation, m.
    pub loop_resolution: f64,
    pub loop_sigma: f64,
    /// Standard deviations of the front end's relative poses (m, rad).
    pub sequential_sigma: f64,
    pub sequential_sigma_angle: f64,
    /// Standard deviations of loop closures (m, rad), and their Huber threshold (in standard
    /// deviations).
    pub loop_sigma_xy: f64,
    pub loop_sigma_angle: f64,
    pub loop_huber: f64,
    /// Re-optimise after this many new loop closures.
    pub optimize_every: usize,
    /// Drift allowed for, per metre travelled since the last loop closure: the search radius
    /// and the linear window grow by this much (m/m) and the angular window by
    /// `loop_angular_growth` (rad/m), so that a loop is still found after a long stretch
    /// without one, up to `loop_max_window` (m) and `loop_max_angular_window` (rad). The same
    /// rates bound how far two submaps' relative estimate can be wrong, per metre travelled
    /// between them, when one keyframe's matches against both are compared.
    pub loop_growth: f64,
    pub loop_angular_growth: f64,
    pub loop_max_window: f64,
    pub loop_max_angular_window: f64,
    /// A loop closure enters the graph only when another one, found from a keyframe at most
    /// `loop_confirm_nodes` keyframes apart, agrees with it: the two place their keyframes
    /// relative to each other as the front end does, within `loop_agreement` (m) and
    /// `loop_agreement_angle` (rad). A single match can be chance; two that agree rarely are.
    pub loop_confirm_nodes: usize,
    pub loop_agreement: f64,
    pub loop_agreement_angle: f64,
    /// At the end of a log, search every keyframe against every finished submap near it
    /// (see [`Slam::finish`]).
    pub final_search: bool,
    /// At the end of a log, loop closures whose whitened error at the optimum exceeds this
    /// many standard deviations are removed as outliers (0: none). 5 σ is 0.25 m or 5.7° with
    /// the default loop deviations.
    pub outlier_sigmas: f64,
}

impl Default for GraphConfig {
    fn default() -> Self {
        GraphConfig {
            local_nodes: 60,
            submap_nodes: 20,
            loop_search_radius: 3.0,
            loop_min_age: 40,
            loop_linear_window: 1.0,
            loop_angular_window: 0.35,
            loop_min_score: 0.55,
            loop_min_overlap: 0.5,
            loop_max_range: 8.0,
            loop_resolution: 0.05,
            loop_sigma: 0.05,
            sequential_sigma: 0.02,
            sequential_sigma_angle: 0.01,
            loop_sigma_xy: 0.05,
            loop_sigma_angle: 0.02,
            loop_huber: 1.0,
            optimize_every: 5,
            loop_growth: 0.05,
            loop_angular_growth: 0.005,
            loop_max_window: 7.0,
            loop_max_angular_window: 0.52,
            loop_confirm_nodes: 10,
            loop_agreement: 0.2,
            loop_agreement_angle: 0.035,
            final_search: true,
            outlier_sigmas: 5.0,
        }
    }
}

impl SlamConfig {
    /// Checks every field against the range SLAM can run with; returns `(key, expectation)`
    /// on error.
    pub fn validate(&self) -> Result<(), (String, String)> {
        use std::f64::consts::{PI, TAU};
        check_ranges(
            "slam",
            &[
                ("keyframe_distance", self.keyframe_distance, 1e-3, 100.0),
                ("keyframe_angle", self.keyframe_angle, 1e-3, TAU),
                ("max_range", self.max_range, 0.1, 1000.0),
                ("max_correction", self.max_correction, 1e-3, 100.0),
                ("max_correction_angle", self.max_correction_angle, 1e-3, TAU),
                ("min_travel", self.min_travel, 0.0, 100.0),
                ("min_turn", self.min_turn, 0.0, TAU),
                ("max_interval", self.max_interval, 0.0, 3600.0),
                ("velocity_margin", self.velocity_margin, 1.0, 10.0),
            ],
        )?;
        self.icp.validate("slam.icp")?;
        let g = &self.graph;
        check_counts(
            "slam.graph",
            &[
                ("local_nodes", g.local_nodes, 1, 10_000),
                ("submap_nodes", g.submap_nodes, 1, 10_000),
                ("loop_min_age", g.loop_min_age, 0, 1_000_000),
                ("optimize_every", g.optimize_every, 1, 1_000_000),
                ("loop_confirm_nodes", g.loop_confirm_nodes, 0, 1_000_000),
            ],
        )?;
        check_ranges(
            "slam.graph",
            &[
                ("loop_search_radius", g.loop_search_radius, 0.0, 1000.0),
                ("loop_linear_window", g.loop_linear_window, 0.0, 100.0),
                ("loop_angular_window", g.loop_angular_window, 0.0, PI),
                ("loop_min_score", g.loop_min_score, 0.0, 1.0),
                ("loop_min_overlap", g.loop_min_overlap, 0.0, 1.0),
                ("loop_max_range", g.loop_max_range, 0.1, 1000.0),
                ("loop_resolution", g.loop_resolution, 0.005, 1.0),
                ("loop_sigma", g.loop_sigma, 1e-4, 10.0),
                ("sequential_sigma", g.sequential_sigma, 1e-6, 10.0),
                ("sequential_sigma_angle", g.sequential_sigma_angle, 1e-6, PI),
                ("loop_sigma_xy", g.loop_sigma_xy, 1e-6, 10.0),
                ("loop_sigma_angle", g.loop_sigma_angle, 1e-6, PI),
                ("loop_huber", g.loop_huber, 1e-3, 1000.0),
                ("loop_growth", g.loop_growth, 0.0, 10.0),
                ("loop_angular_growth", g.loop_angular_growth, 0.0, 10.0),
                ("loop_max_window", g.loop_max_window, 0.0, 100.0),
                (
                    "loop_max_angular_window",
                    g.loop_max_angular_window,
                    0.0,
                    PI,
                ),
                ("loop_agreement", g.loop_agreement, 0.0, 1000.0),
                ("loop_agreement_angle", g.loop_agreement_angle, 0.0, PI),
                ("outlier_sigmas", g.outlier_sigmas, 0.0, 1000.0),
            ],
        )?;
        self.grid.validate("slam.grid")
    }
}

/// What SLAM did with one scan.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SlamUpdate {
    pub pose: Pose2,
    /// Whether ICP accepted a match (else the pose is the odometry guess).
    pub matched: bool,
    pub keyframe: bool,
    /// Whether the pose graph was re-optimised after this scan (the map moved).
    pub optimized: bool,
}

/// A loop closure and how far the optimised graph is from it (see [`Slam::loop_residuals`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopResidual {
    /// Stamps of the scans of the edge's two keyframes (the submap's first, the matched one).
    pub from: Time,
    pub to: Time,
    /// The edge's violation at the optimum, m and rad.
    pub translation: f64,
    pub rotation: f64,
}

/// Guesses closer than this (m, and rad) are one guess.
const GUESS_DISAGREEMENT: f64 = 0.05;

/// A keyframe with fewer points than this (within `loop_max_range`, thinned) is not searched
/// for loop closures: too few to tell a place.
const MIN_LOOP_POINTS: usize = 20;

/// A keyframe.
struct Node {
    points: Vec<Oriented>,
    scan: LaserScan,
    mount: Pose2,
}

/// A finished submap in the frame of its first keyframe.
struct Submap {
    first: usize,
    last: usize,
    grid: LikelihoodGrid,
    points: PointMap,
}

/// Laser SLAM (see the module documentation).
pub struct Slam {
    config: SlamConfig,
    /// The front end's map: all keyframes (ICP) or the last few (graph).
    map: PointMap,
    graph: PoseGraph,
    nodes: Vec<Node>,
    submaps: Vec<Submap>,
    /// The occupancy grid of the keyframes, kept up to date; rebuilt on demand after the
    /// graph moved (`grid_stale`).
    grid: OccupancyMap,
    grid_stale: bool,
    /// Odometry and stamp of the last scan that was matched (the motion filter's reference).
    last_matched: Option<(Time, Pose2)>,
    skipped: usize,
    pose: Pose2,
    last_odometry: Option<(Time, Pose2)>,
    /// The motion estimated between the last two scans.
    last_motion: Pose2,
    /// Whether the odometry reported no motion at the last scan.
    odometry_stalled: bool,
    /// Every scan: its stamp, its keyframe and its pose in that keyframe's frame.
    scans: Vec<(Time, usize, Pose2)>,
    unmatched: usize,
    loop_closures: usize,
    outliers: usize,
    pending_loops: usize,
    optimizations: usize,
    /// Distance travelled along the keyframes since the last loop closure, m.
    travel_since_loop: f64,
    /// Recent loop-closure matches, waiting for (or already given) a second that agrees.
    candidates: Vec<Candidate>,
}

/// A loop-closure match: keyframe `edge.to` seen from the anchor `edge.from` of a submap.
struct Candidate {
    edge: Edge,
    accepted: bool,
}

impl Slam {
    /// Starts at `start` (the map frame's origin is where the robot starts when identity).
    pub fn new(config: SlamConfig, start: Pose2) -> Slam {
        Slam {
            map: Self::empty_map(&config),
            graph: PoseGraph::default(),
            nodes: Vec::new(),
            submaps: Vec::new(),
            grid: OccupancyMap::new(config.grid),
            grid_stale: false,
            last_matched: None,
            skipped: 0,
            config,
            pose: start,
            last_odometry: None,
            last_motion: Pose2::IDENTITY,
            odometry_stalled: false,
            scans: Vec::new(),
            unmatched: 0,
            loop_closures: 0,
            outliers: 0,
            pending_loops: 0,
            optimizations: 0,
            travel_since_loop: 0.0,
            candidates: Vec::new(),
        }
    }

    fn empty_map(config: &SlamConfig) -> PointMap {
        PointMap::new(config.icp.voxel, config.icp.max_distance_start.max(0.05))
    }

    /// Processes one scan with the odometry pose of the robot at its time and the laser's
    /// mount on the robot.
    pub fn update(&mut self, scan: &LaserScan, odometry: &Pose2, mount: &Pose2) -> SlamUpdate {
        let guess = match self.last_odometry {
            Some((_, prev)) => self.pose.compose(&prev.between(odometry)),
            None => self.pose,
        };
        // The robot's motion during the sweep: the odometry's over the last interval, at the
        // same velocity.
        let sweep = match self.last_odometry {
            Some((t, prev)) if self.config.deskew => Sweep {
                step: prev.between(odometry),
                over: (scan.stamp - t).secs(),
            },
            _ => Sweep::STILL,
        };
        let stalled = self
            .last_odometry
            .is_some_and(|(_, prev)| prev == *odometry);
        let try_velocity = match self.config.velocity_guess {
            VelocityGuess::Always => true,
            VelocityGuess::Stalls => stalled || self.odometry_stalled,
            VelocityGuess::Never => false,
        };
        self.odometry_stalled = stalled;
        self.last_odometry = Some((scan.stamp, *odometry));
        // Motion filter: a scan taken where the last matched one was, and soon after it, adds
        // nothing but time (a 40 Hz laser on a robot at rest); it is dead-reckoned.
        if let Some((t, o)) = self.last_matched
            && !self.graph.nodes.is_empty()
            && o.distance(odometry) < self.config.min_travel
            && wrap_angle(o.theta - odometry.theta).abs() < self.config.min_turn
            && (scan.stamp - t).secs() < self.config.max_interval
        {
            self.skipped += 1;
            self.pose = guess;
            let node = self.graph.nodes.len() - 1;
            self.scans
                .push((scan.stamp, node, self.graph.nodes[node].between(&self.pose)));
            return SlamUpdate {
                pose: self.pose,
                matched: false,
                keyframe: false,
                optimized: false,
            };
        }
        self.last_matched = Some((scan.stamp, *odometry));
        let points = scan_points(scan, mount, &sweep, self.config.max_range, &self.config.icp);
        // Wheel odometry stalls and then catches up in one jump on real robots (the MIT CSAIL
        // log holds 1 s stalls in turns). Where the odometry guess and a constant-velocity
        // guess disagree, ICP starts from both and the better fit wins.
        let velocity_guess = self.pose.compose(&self.last_motion);
        let mut guesses = vec![guess];
        if try_velocity
            && (velocity_guess.distance(&guess) > GUESS_DISAGREEMENT
                || wrap_angle(velocity_guess.theta - guess.theta).abs() > GUESS_DISAGREEMENT)
        {
            guesses.push(velocity_guess);
        }
        let sigma = self.config.icp.max_distance_end;
        let alone = guesses.len() == 1;
        let aligned = guesses
            .iter()
            .filter_map(|g| {
                align(&self.map, &points, *g, &self.config.icp).filter(|a| {
                    a.pose.distance(g) <= self.config.max_correction
                        && wrap_angle(a.pose.theta - g.theta).abs()
                            <= self.config.max_correction_angle
                })
            })
            // A single guess has no rival to be scored against (its score went unread: 1 %
            // of hall-scan3d's time).
            .map(|a| {
                let score = if alone {
                    0.0
                } else {
                    fit_score(&self.map, &points, &a.pose, sigma)
                };
                (score, a)
            })
            // The odometry guess comes first and keeps ties: along a corridor both fit alike,
            // and a constant-velocity guess that won a tie would carry a wrong motion (an
            // odometry spike matched once) on from scan to scan.
            .reduce(|best, next| {
                if next.0 > best.0 * self.config.velocity_margin {
                    next
                } else {
                    best
                }
            })
            .map(|(_, a)| a);
        let matched = aligned.is_some();
        if !matched && !self.map.is_empty() {
            self.unmatched += 1;
        }
        let previous = self.pose;
        self.pose = aligned.map(|a| a.pose).unwrap_or(guess);
        self.last_motion = previous.between(&self.pose);
        let keyframe = match self.graph.nodes.last() {
            None => true,
            Some(k) => {
                k.distance(&self.pose) >= self.config.keyframe_distance
                    || wrap_angle(k.theta - self.pose.theta).abs() >= self.config.keyframe_angle
            }
        };
        let mut optimized = false;
        if keyframe {
            optimized = self.add_keyframe(scan, mount, points);
        }
        let node = self.graph.nodes.len() - 1;
        self.scans
            .push((scan.stamp, node, self.graph.nodes[node].between(&self.pose)));
        SlamUpdate {
            pose: self.pose,
            matched,
            keyframe,
            optimized,
        }
    }

    /// Adds a keyframe at the current pose; returns whether the graph was optimised.
    fn add_keyframe(&mut self, scan: &LaserScan, mount: &Pose2, points: Vec<Oriented>) -> bool {
        let id = self.graph.nodes.len();
        if let Some(prev) = self.graph.nodes.last() {
            self.travel_since_loop += prev.distance(&self.pose);
            let g = &self.config.graph;
            self.graph.edges.push(Edge::with_sigmas(
                id - 1,
                id,
                prev.between(&self.pose),
                [
                    g.sequential_sigma,
                    g.sequential_sigma,
                    g.sequential_sigma_angle,
                ],
            ));
        }
        self.graph.nodes.push(self.pose);
        if !self.grid_stale {
            self.grid.insert(&self.pose.compose(mount), scan);
        }
        self.nodes.push(Node {
            points,
            scan: scan.clone(),
            mount: *mount,
        });
        match self.config.method {
            SlamMethod::Icp => {
                self.map.insert(&self.pose, &self.nodes[id].points);
                false
            }
            SlamMethod::Graph => {
                if (id + 1).is_multiple_of(self.config.graph.submap_nodes) {
                    self.finish_submap(id + 1 - self.config.graph.submap_nodes, id);
                }
                // Loops found in a widened window correct a large drift: they are applied at
                // once, so that the next searches start from the corrected estimate.
                let widened = self.close_loops(id);
                let optimized = self.pending_loops >= self.config.graph.optimize_every || widened;
                if optimized {
                    self.optimize();
                }
                self.rebuild_local_map();
                optimized
            }
        }
    }

    fn rebuild_local_map(&mut self) {
        let n = self.graph.nodes.len();
        let mut map = Self::empty_map(&self.config);
        // Newest first, so that a voxel keeps the most recent view of it.
        for k in (n.saturating_sub(self.config.graph.local_nodes)..n).rev() {
            map.insert(&self.graph.nodes[k], &self.nodes[k].points);
        }
        self.map = map;
    }

    /// Freezes keyframes `first..=last` into a submap in the frame of `first`.
    fn finish_submap(&mut self, first: usize, last: usize) {
        let g = &self.config.graph;
        let anchor = self.graph.nodes[first].inverse();
        let mut points = Self::empty_map(&self.config);
        let mut cloud = Vec::new();
        for k in first..=last {
            let rel = anchor.compose(&self.graph.nodes[k]);
            points.insert(&rel, &self.nodes[k].points);
            for o in &self.nodes[k].points {
                if o.p[0].hypot(o.p[1]) <= g.loop_max_range {
                    cloud.push(rel.transform_point(o.p));
                }
            }
        }
        let window = (g.loop_linear_window / g.loop_resolution).ceil().max(1.0);
        let depth = (window.log2().ceil() as usize).clamp(1, 8);
        self.submaps.push(Submap {
            first,
            last,
            grid: LikelihoodGrid::new(&cloud, g.loop_resolution, g.loop_sigma, depth),
            points,
        });
    }

    /// The points of keyframe `id` for branch and bound: within `loop_max_range`, thinned to
    /// one per two cells.
    fn loop_cloud(&self, id: usize) -> Vec<[f64; 2]> {
        let g = &self.config.graph;
        let mut seen = std::collections::HashSet::new();
        self.nodes[id]
            .points
            .iter()
            .filter(|o| o.p[0].hypot(o.p[1]) <= g.loop_max_range)
            .filter(|o| {
                seen.insert((
                    (o.p[0] / (2.0 * g.loop_resolution)).floor() as i64,
                    (o.p[1] / (2.0 * g.loop_resolution)).floor() as i64,
                ))
            })
            .map(|o| o.p)
            .collect()
    }

    /// Branch and bound for keyframe `id` (its `cloud`) in submap `s` around the keyframe's
    /// estimate, refined by ICP to the submap's points; the loop-closure edge from the
    /// submap's first keyframe and the search's score, or `None`.
    fn match_submap(
        &self,
        s: &Submap,
        id: usize,
        cloud: &[[f64; 2]],
        window: &SearchWindow,
    ) -> Option<(Edge, f64)> {
        let g = &self.config.graph;
        let refine = IcpConfig {
            translation_weight: 0.0,
            rotation_weight: 0.0,
            rotation_search: 0.0,
            max_distance_start: 2.0 * g.loop_resolution,
            max_distance_end: g.loop_resolution,
            min_overlap: g.loop_min_overlap,
            ..self.config.icp
        };
        let guess = self.graph.nodes[s.first].between(&self.graph.nodes[id]);
        let m = search(&s.grid, cloud, guess, window)?;
        let refined = align(&s.points, &self.nodes[id].points, m.pose, &refine)?;
        // The refinement must stay in the cell the search found.
        if refined.pose.distance(&m.pose) > 2.0 * g.loop_resolution
            || wrap_angle(refined.pose.theta - m.pose.theta).abs() > 0.05
        {
            return None;
        }
        let mut edge = Edge::with_sigmas(
            s.first,
            id,
            refined.pose,
            [g.loop_sigma_xy, g.loop_sigma_xy, g.loop_sigma_angle],
        );
        edge.huber = Some(g.loop_huber);
        Some((edge, m.score))
    }

    /// Whether a keyframe of submap `s` lies within `radius` of keyframe `id`'s estimate.
    fn near(&self, s: &Submap, id: usize, radius: f64) -> bool {
        let pose = self.graph.nodes[id];
        (s.first..=s.last).any(|k| self.graph.nodes[k].distance(&pose) <= radius)
    }

    /// Searches the finished submaps near keyframe `id` and adds an edge for each confirmed
    /// match; returns whether any was found in a window wider than the base one.
    fn close_loops(&mut self, id: usize) -> bool {
        let g = self.config.graph;
        let cloud = self.loop_cloud(id);
        if cloud.len() < MIN_LOOP_POINTS {
            return false;
        }
        let linear = (g.loop_linear_window + g.loop_growth * self.travel_since_loop)
            .min(g.loop_max_window.max(g.loop_linear_window));
        let window = SearchWindow {
            linear,
            angular: (g.loop_angular_window + g.loop_angular_growth * self.travel_since_loop)
                .min(g.loop_max_angular_window.max(g.loop_angular_window)),
            min_score: g.loop_min_score,
        };
        let radius = g.loop_search_radius + (linear - g.loop_linear_window);
        let matches: Vec<(Edge, f64)> = self
            .submaps
            .iter()
            .filter(|s| s.last + g.loop_min_age <= id && self.near(s, id, radius))
            .filter_map(|s| self.match_submap(s, id, &cloud, &window))
            .collect();
        let new_edges = self.consistent(matches);
        let new_edges = self.confirm(id, new_edges);
        let found = !new_edges.is_empty();
        if found {
            self.travel_since_loop = 0.0;
        }
        self.loop_closures += new_edges.len();
        self.pending_loops += new_edges.len();
        self.graph.edges.extend(new_edges);
        found && linear > g.loop_linear_window
    }

    /// The end of a log's constraint search (Cartographer's final optimisation does the
    /// same): every keyframe is searched in every finished submap near its optimised estimate,
    /// those finished after it as well as before. During the run a keyframe meets only the
    /// submaps finished before it, so half the pairs that see the same walls were never
    /// tried. The graph is consistent by now, so the window is the agreement tolerance and a
    /// match is kept only where it agrees with the estimate (no second match needed); pairs
    /// that already have an edge are skipped. Returns the edges added.
    fn final_loops(&mut self) -> usize {
        let g = self.config.graph;
        let window = SearchWindow {
            linear: g.loop_agreement,
            angular: g.loop_agreement_angle,
            min_score: g.loop_min_score,
        };
        let joined: std::collections::HashSet<(usize, usize)> =
            self.graph.edges.iter().map(|e| (e.from, e.to)).collect();
        let mut found = Vec::new();
        for id in 0..self.nodes.len() {
            let cloud = self.loop_cloud(id);
            if cloud.len() < MIN_LOOP_POINTS {
                continue;
            }
            for s in &self.submaps {
                let apart = s.last + g.loop_min_age <= id || id + g.loop_min_age <= s.first;
                if !apart
                    || joined.contains(&(s.first, id))
                    || !self.near(s, id, g.loop_search_radius)
                {
                    continue;
                }
                let Some((edge, _)) = self.match_submap(s, id, &cloud, &window) else {
                    continue;
                };
                let estimate = self.graph.nodes[s.first].between(&self.graph.nodes[id]);
                if estimate.distance(&edge.measurement) <= g.loop_agreement
                    && wrap_angle(estimate.theta - edge.measurement.theta).abs()
                        <= g.loop_agreement_angle
                {
                    found.push(edge);
                }
            }
        }
        let n = found.len();
        self.loop_closures += n;
        self.pending_loops += n;
        self.graph.edges.extend(found);
        n
    }

    /// Of one keyframe's matches against several submaps, those that place it alike. The
    /// keyframe is in one place, so two matches that put it further apart than the submaps'
    /// relative estimate can be wrong cannot both be right: that error is at most the front
    /// end's drift over the travel between the submaps' first keyframes
    /// ([`GraphConfig::loop_growth`] and `loop_angular_growth` per metre) beyond
    /// `loop_agreement` and `loop_agreement_angle`. The match that agrees with the most others
    /// stands (the higher search score breaks a tie), with those that agree with it.
    /// Confirmation over time cannot catch this: a corridor's repeated doors fit one submap at
    /// a wrong place for keyframes in a row, which then agree with one another (office-explore,
    /// seed 1: one submap placed six keyframes in a row 1.0 m along the corridor while two
    /// others placed them within 0.05 m of their estimates).
    fn consistent(&self, matches: Vec<(Edge, f64)>) -> Vec<Edge> {
        let g = self.config.graph;
        let nodes = &self.graph.nodes;
        let travel = |a: usize, b: usize| -> f64 {
            (a.min(b)..a.max(b))
                .map(|k| nodes[k].distance(&nodes[k + 1]))
                .sum()
        };
        let agree = |a: &Edge, b: &Edge| {
            let apart = nodes[a.from]
                .compose(&a.measurement)
                .between(&nodes[b.from].compose(&b.measurement));
            let drift = travel(a.from, b.from);
            apart.x.hypot(apart.y) <= g.loop_agreement + g.loop_growth * drift
                && wrap_angle(apart.theta).abs()
                    <= g.loop_agreement_angle + g.loop_angular_growth * drift
        };
        let support: Vec<usize> = matches
            .iter()
            .map(|(a, _)| matches.iter().filter(|(b, _)| agree(a, b)).count())
            .collect();
        let Some(best) = (0..matches.len()).max_by(|&i, &j| {
            support[i]
                .cmp(&support[j])
                .then(matches[i].1.total_cmp(&matches[j].1))
        }) else {
            return Vec::new();
        };
        let standing = matches[best].0;
        matches
            .into_iter()
            .map(|(e, _)| e)
            .filter(|e| agree(&standing, e))
            .collect()
    }

    /// Of keyframe `id`'s loop-closure matches, those that agree with another recent match
    /// (see [`GraphConfig::loop_confirm_nodes`]), together with earlier matches they confirm
    /// for the first time; the rest wait as candidates.
    fn confirm(&mut self, id: usize, found: Vec<Edge>) -> Vec<Edge> {
        let g = self.config.graph;
        if g.loop_confirm_nodes == 0 {
            return found;
        }
        self.candidates
            .retain(|c| c.edge.to + g.loop_confirm_nodes >= id);
        let nodes = &self.graph.nodes;
        // Where a match puts its keyframe, given the anchor's current estimate.
        let placed = |e: &Edge| nodes[e.from].compose(&e.measurement);
        let agree = |a: &Edge, b: &Edge| {
            let by_front_end = nodes[a.to].between(&nodes[b.to]);
            let by_loops = placed(a).between(&placed(b));
            by_front_end.distance(&by_loops) <= g.loop_agreement
                && wrap_angle(by_front_end.theta - by_loops.theta).abs() <= g.loop_agreement_angle
        };
        let mut out = Vec::new();
        let mut fresh = Vec::new();
        for e in found {
            let mut confirmed = false;
            for c in self.candidates.iter_mut().chain(fresh.iter_mut()) {
                if c.edge.from == e.from && c.edge.to == e.to {
                    continue;
                }
                if agree(&c.edge, &e) {
                    confirmed = true;
                    if !c.accepted {
                        c.accepted = true;
                        out.push(c.edge);
                    }
                }
            }
            if confirmed {
                out.push(e);
            }
            fresh.push(Candidate {
                edge: e,
                accepted: confirmed,
            });
        }
        self.candidates.extend(fresh);
        out
    }

    /// Optimises the graph and carries the current pose along with the newest keyframe.
    fn optimize(&mut self) {
        let last = self.graph.nodes.len() - 1;
        let rel = self.graph.nodes[last].between(&self.pose);
        // The graph was checked as it was built, so optimisation cannot fail on its edges.
        if self.graph.optimize(&OptimizeOptions::default()).is_ok() {
            self.optimizations += 1;
        }
        self.pose = self.graph.nodes[last].compose(&rel);
        self.pending_loops = 0;
        self.grid_stale = true;
    }

    /// Call at the end of a log. Optimises once more if loop closures arrived since the last
    /// optimisation; then, for the graph method, removes the loop closures left further than
    /// [`GraphConfig::outlier_sigmas`] from the optimum, searches every keyframe against every
    /// submap ([`GraphConfig::final_search`]), optimises, and removes outliers again.
    pub fn finish(&mut self) {
        if self.pending_loops > 0 {
            self.optimize();
        }
        if self.config.method != SlamMethod::Graph {
            return;
        }
        // The final search keeps the matches that agree with the graph's estimate, so the
        // outliers go first: a graph bent by a wrong loop closure would have the search
        // confirm more of the same.
        self.remove_outliers();
        if self.config.graph.final_search && self.final_loops() > 0 {
            self.optimize();
            self.remove_outliers();
        }
    }

    /// Removes the loop closures left further than [`GraphConfig::outlier_sigmas`] from the
    /// optimum, re-optimising after each removal (twice at most: a removal can unmask one
    /// more).
    fn remove_outliers(&mut self) {
        let sigmas = self.config.graph.outlier_sigmas;
        if sigmas <= 0.0 {
            return;
        }
        for _ in 0..2 {
            let removed = self.graph.remove_outliers(sigmas);
            if removed == 0 {
                break;
            }
            self.outliers += removed;
            self.optimize();
        }
    }

    /// The current pose estimate.
    pub fn pose(&self) -> Pose2 {
        self.pose
    }

    /// Estimated pose at every scan, following the keyframes as they are now.
    pub fn trajectory(&self) -> Vec<(Time, Pose2)> {
        self.scans
            .iter()
            .map(|(t, k, rel)| (*t, self.graph.nodes[*k].compose(rel)))
            .collect()
    }

    /// The occupancy grid of the keyframes at their current poses.
    pub fn grid(&mut self) -> &OccupancyMap {
        if self.grid_stale {
            let mut grid = OccupancyMap::new(self.config.grid);
            for (n, p) in self.nodes.iter().zip(&self.graph.nodes) {
                grid.insert(&p.compose(&n.mount), &n.scan);
            }
            self.grid = grid;
            self.grid_stale = false;
        }
        &self.grid
    }

    /// Scans the motion filter passed over (dead-reckoned from the last matched one).
    pub fn skipped(&self) -> usize {
        self.skipped
    }

    pub fn keyframes(&self) -> usize {
        self.nodes.len()
    }

    /// Scans ICP could not match (their pose is dead-reckoned).
    pub fn unmatched(&self) -> usize {
        self.unmatched
    }

    /// Loop-closure edges added.
    pub fn loop_closures(&self) -> usize {
        self.loop_closures
    }

    /// Loop-closure edges removed by [`Slam::finish`] as outliers.
    pub fn outliers(&self) -> usize {
        self.outliers
    }

    /// Every loop-closure edge in the graph as it is now (outliers removed): the stamps of its
    /// two keyframes' scans and how far the optimised poses are from what it measured.
    pub fn loop_residuals(&self) -> Vec<LoopResidual> {
        let nodes = &self.graph.nodes;
        self.graph
            .edges
            .iter()
            .filter(|e| e.huber.is_some())
            .map(|e| {
                let d = e.measurement.between(&nodes[e.from].between(&nodes[e.to]));
                LoopResidual {
                    from: self.nodes[e.from].scan.stamp,
                    to: self.nodes[e.to].scan.stamp,
                    translation: d.x.hypot(d.y),
                    rotation: wrap_angle(d.theta).abs(),
                }
            })
            .collect()
    }

    pub fn optimizations(&self) -> usize {
        self.optimizations
    }

    pub fn config(&self) -> &SlamConfig {
        &self.config
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mapping::icp::tests_support::{room_scan, scan_of};

    #[test]
    fn icp_slam_follows_a_drive_that_odometry_gets_wrong() {
        let mut slam = Slam::new(
            SlamConfig {
                method: SlamMethod::Icp,
                ..SlamConfig::default()
            },
            Pose2::IDENTITY,
        );
        // The robot drives 1.5 m along x and turns 0.5 rad; odometry overestimates distance by
        // 5 % and turns by 10 %.
        let mut odo = Pose2::IDENTITY;
        let mut truth = Pose2::IDENTITY;
        for k in 0..=60 {
            if k > 0 {
                truth = truth.compose(&Pose2::new(0.025, 0.0, 0.5 / 60.0));
                odo = odo.compose(&Pose2::new(0.025 * 1.05, 0.0, 0.55 / 60.0));
            }
            let mut scan = room_scan(&truth);
            scan.stamp = Time::from_secs(k as f64 * 0.1);
            slam.update(&scan, &odo, &Pose2::IDENTITY);
        }
        let est = slam.trajectory().last().unwrap().1;
        assert_eq!(
            slam.loop_closures(),
            0,
            "the ICP method has no loop closure"
        );
        assert!(
            odo.distance(&truth) > 0.07,
            "odometry error {}",
            odo.distance(&truth)
        );
        assert!(est.distance(&truth) < 0.01, "SLAM {est:?} vs {truth:?}");
        assert!(wrap_angle(est.theta - truth.theta).abs() < 0.5f64.to_radians());
        assert!(slam.keyframes() >= 5 && slam.keyframes() < 60);
        assert_eq!(slam.unmatched(), 0);
    }

    /// Odometry that stalls for half a second in a turn and then catches up in one jump (as
    /// in the MIT CSAIL log): the constant-velocity guess keeps the heading.
    #[test]
    fn a_stall_and_jump_of_odometry_does_not_double_count_the_turn() {
        // Tried at every scan or only where the odometry stalled, the velocity guess keeps the
        // heading; never tried, the turn made during the stall is lost.
        for (mode, holds) in [
            (VelocityGuess::Always, true),
            (VelocityGuess::Stalls, true),
            (VelocityGuess::Never, false),
        ] {
            let config = SlamConfig {
                method: SlamMethod::Icp,
                velocity_guess: mode,
                ..SlamConfig::default()
            };
            let mut slam = Slam::new(config, Pose2::IDENTITY);
            let (mut truth, mut odo) = (Pose2::IDENTITY, Pose2::IDENTITY);
            for k in 0..=20 {
                if k > 0 {
                    truth = truth.compose(&Pose2::new(0.01, 0.0, 0.15));
                }
                // Odometry holds still at scans 5–9 and reports the whole motion at scan 10.
                if !(5..10).contains(&k) {
                    odo = truth;
                }
                let mut scan = room_scan(&truth);
                scan.stamp = Time::from_secs(k as f64 * 0.1);
                slam.update(&scan, &odo, &Pose2::IDENTITY);
            }
            let est = slam.pose();
            let right =
                wrap_angle(est.theta - truth.theta).abs() < 0.01 && est.distance(&truth) < 0.02;
            assert_eq!(right, holds, "{mode:?}: {est:?} vs {truth:?}");
        }
    }

    /// In a corridor longer than the laser's reach the scan cannot tell positions along it, so
    /// SLAM takes them from its guesses. Odometry that spikes 0.3 m back for one scan (as
    /// Intel's does) moves that scan; the next odometry reading is right again, and SLAM must
    /// follow it rather than a constant-velocity guess that carries the spike's motion on.
    #[test]
    fn an_odometry_spike_in_a_corridor_is_not_carried_on() {
        let walls = [
            ([-100.0, 1.0], [100.0, 1.0]),
            ([-100.0, -1.0], [100.0, -1.0]),
        ];
        let config = SlamConfig {
            method: SlamMethod::Icp,
            ..SlamConfig::default()
        };
        let mut slam = Slam::new(config, Pose2::IDENTITY);
        let mut truth = Pose2::IDENTITY;
        for k in 0..=30 {
            truth = Pose2::new(0.05 * k as f64, 0.0, 0.0);
            let odo = if k == 15 {
                Pose2::new(truth.x - 0.3, 0.0, 0.0)
            } else {
                truth
            };
            let mut scan = scan_of(&walls, &truth);
            scan.stamp = Time::from_secs(k as f64 * 0.1);
            slam.update(&scan, &odo, &Pose2::IDENTITY);
        }
        let est = slam.pose();
        assert!(est.distance(&truth) < 0.02, "{est:?} vs {truth:?}");
    }

    /// A SLAM with the default configuration whose graph holds `n` keyframes on a gently
    /// curving line, 0.3 m apart, for tests of what it makes of loop-closure matches.
    fn slam_on_a_line(n: usize) -> Slam {
        let mut slam = Slam::new(SlamConfig::default(), Pose2::IDENTITY);
        slam.graph.nodes = (0..n)
            .map(|k| Pose2::new(0.3 * k as f64, 0.01 * k as f64, 0.002 * k as f64))
            .collect();
        slam
    }

    /// A loop-closure match enters the graph only once a second, from a keyframe nearby,
    /// places the two keyframes as the front end does; one that contradicts them, or comes
    /// after the window, waits.
    #[test]
    fn a_loop_closure_waits_for_a_second_that_agrees() {
        let mut slam = slam_on_a_line(40);
        let g = slam.config.graph;
        // The truth is the estimate moved by a drift correction (the loop's).
        let nodes = slam.graph.nodes.clone();
        let seen = |from: usize, to: usize, drift: Pose2| {
            let truth = drift.compose(&nodes[to]);
            Edge::with_sigmas(from, to, nodes[from].between(&truth), [0.05, 0.05, 0.02])
        };
        let drift = Pose2::new(0.8, -0.4, 0.1);
        assert!(slam.confirm(20, vec![seen(0, 20, drift)]).is_empty());
        let both = slam.confirm(24, vec![seen(3, 24, drift)]);
        assert_eq!(
            both.iter().map(|e| (e.from, e.to)).collect::<Vec<_>>(),
            [(0, 20), (3, 24)]
        );
        // A match of the next keyframe to another place contradicts both and waits.
        let elsewhere = Pose2::new(0.8 + 3.0 * g.loop_agreement, -0.4, 0.1);
        assert!(slam.confirm(25, vec![seen(0, 25, elsewhere)]).is_empty());
        // One that agrees is taken at once, since the place was confirmed.
        assert_eq!(slam.confirm(26, vec![seen(0, 26, drift)]).len(), 1);
        // Past the window the earlier matches are forgotten.
        let late = 26 + g.loop_confirm_nodes + 1;
        assert!(slam.confirm(late, vec![seen(0, late, drift)]).is_empty());
    }

    /// A keyframe is in one place: of its matches against several submaps, those placing it
    /// where most of them do stand, however well the odd one scored; a lone pair that
    /// disagrees keeps the better score; and a disagreement that the front end's drift over
    /// the travel between the two submaps explains is no contradiction.
    #[test]
    fn a_keyframe_matched_to_two_places_keeps_the_one_most_matches_agree_on() {
        // Keyframes 0.3 m apart: 20 of them are 6 m of travel.
        let slam = slam_on_a_line(100);
        let g = slam.config.graph;
        let nodes = slam.graph.nodes.clone();
        let seen = |from: usize, drift: Pose2, score: f64| {
            let truth = drift.compose(&nodes[90]);
            let e = Edge::with_sigmas(from, 90, nodes[from].between(&truth), [0.05; 3]);
            (e, score)
        };
        let pairs = |edges: Vec<Edge>| edges.iter().map(|e| (e.from, e.to)).collect::<Vec<_>>();
        let right = Pose2::new(0.1, 0.05, 0.01);
        // 1 m along, beyond 0.2 m + 5 % of the 12 m between submaps 40 and 80.
        let along = Pose2::new(1.1, 0.05, 0.01);
        assert!(1.0 > g.loop_agreement + g.loop_growth * 12.1);
        let three = vec![
            seen(40, right, 0.7),
            seen(60, right, 0.8),
            seen(80, along, 0.95),
        ];
        assert_eq!(pairs(slam.consistent(three)), [(40, 90), (60, 90)]);
        let two = vec![seen(40, right, 0.7), seen(60, along, 0.9)];
        assert_eq!(pairs(slam.consistent(two)), [(60, 90)]);
        // Submaps 0 and 80 are 24 m apart: 1 m of disagreement is drift the loop may fix.
        assert!(1.0 < g.loop_agreement + g.loop_growth * 24.0);
        let far = vec![seen(0, right, 0.7), seen(80, along, 0.9)];
        assert_eq!(pairs(slam.consistent(far)), [(0, 90), (80, 90)]);
    }

    /// A corridor ring: outer walls 10 × 6 m, an inner block, and a few boxes on the walls so
    /// that places differ.
    fn ring() -> Vec<([f64; 2], [f64; 2])> {
        let mut segs = vec![
            ([-1.0, -1.0], [9.0, -1.0]),
            ([9.0, -1.0], [9.0, 5.0]),
            ([9.0, 5.0], [-1.0, 5.0]),
            ([-1.0, 5.0], [-1.0, -1.0]),
            ([1.0, 1.0], [7.0, 1.0]),
            ([7.0, 1.0], [7.0, 3.0]),
            ([7.0, 3.0], [1.0, 3.0]),
            ([1.0, 3.0], [1.0, 1.0]),
        ];
        for (cx, cy, w) in [
            (2.0, -0.9, 0.3),
            (5.5, -0.85, 0.5),
            (8.85, 2.5, 0.4),
            (4.0, 4.9, 0.2),
            (-0.9, 1.5, 0.6),
            (3.0, 1.1, 0.3),
        ] {
            let h = w / 2.0;
            let c = [
                [cx - h, cy - h],
                [cx + h, cy - h],
                [cx + h, cy + h],
                [cx - h, cy + h],
            ];
            for k in 0..4 {
                segs.push((c[k], c[(k + 1) % 4]));
            }
        }
        segs
    }

    /// Graph SLAM on dead reckoning alone (the front end's matches refused): odometry that
    /// over-turns by 4 % drifts round the ring, and loop closures pull the trajectory back.
    #[test]
    fn graph_slam_closes_a_loop_that_odometry_drifts_around() {
        let (r, _) = ring_drive(SlamConfig::default(), 1.04);
        assert!(r.odometry_worst > 0.5, "{r:?}");
        assert!(r.loop_closures > 0 && r.optimizations > 0, "{r:?}");
        // One loop spreads the heading error round the ring; what is left mid-ring is a tenth
        // of dead reckoning's.
        assert!(r.worst < 0.15 && r.worst < 0.15 * r.odometry_worst, "{r:?}");
        assert!(r.end_heading_error < 0.02, "{r:?}");
    }

    /// Odometry that over-turns by 8 % is 29° and metres off when the ring closes: beyond the
    /// base windows (1 m, 20°), within the windows grown by the travel since the last loop.
    #[test]
    fn the_loop_search_widens_with_the_travel_since_the_last_loop() {
        let (grown, _) = ring_drive(SlamConfig::default(), 1.08);
        assert!(grown.loop_closures > 0, "{grown:?}");
        assert!(grown.worst < 0.15 * grown.odometry_worst, "{grown:?}");
        assert!(grown.end_heading_error < 0.02, "{grown:?}");
        // Without the growth (and without the end-of-log search, which looks again from the
        // estimates as they are and would find part of the overlap) no loop is found.
        let mut fixed = SlamConfig::default();
        fixed.graph.loop_growth = 0.0;
        fixed.graph.loop_angular_growth = 0.0;
        fixed.graph.final_search = false;
        let (fixed, _) = ring_drive(fixed, 1.08);
        assert_eq!(fixed.loop_closures, 0, "{fixed:?}");
        assert!(fixed.end_heading_error > 0.3, "{fixed:?}");
    }

    /// A wrong loop closure that entered the graph online (a keyframe placed 1 m from where
    /// its place is, as keyframes in a row that see one place alike can confirm) bends the
    /// graph; the end of the log removes it as an outlier, and the trajectory ends as good as
    /// without it. (On this ring the final search finds no wrong match on the bent graph
    /// either, so the test holds whichever comes first; office-explore's seed 1, with the
    /// beams cast at their own times, is where the order mattered: issue 47's note.)
    #[test]
    fn a_wrong_loop_closure_is_gone_by_the_end_of_the_log() {
        let (clean, _) = ring_drive(SlamConfig::default(), 1.04);
        let (bent, slam) = ring_drive_then(SlamConfig::default(), 1.04, |slam| {
            let g = slam.config.graph;
            let (from, to) = (0, slam.graph.nodes.len() / 2);
            let wrong = slam.graph.nodes[from]
                .between(&slam.graph.nodes[to])
                .compose(&Pose2::new(1.0, 0.0, 0.0));
            let mut edge = Edge::with_sigmas(
                from,
                to,
                wrong,
                [g.loop_sigma_xy, g.loop_sigma_xy, g.loop_sigma_angle],
            );
            edge.huber = Some(g.loop_huber);
            slam.graph.edges.push(edge);
            slam.loop_closures += 1;
            slam.optimize();
        });
        assert!(slam.outliers() >= 1, "{bent:?}");
        assert!(
            bent.worst < clean.worst + 0.02,
            "{bent:?} against {clean:?}"
        );
        assert!(bent.end_heading_error < 0.02, "{bent:?}");
    }

    /// What [`ring_drive`] measured.
    #[derive(Debug)]
    struct RingResult {
        odometry_worst: f64,
        worst: f64,
        end_heading_error: f64,
        loop_closures: usize,
        optimizations: usize,
    }

    /// Graph SLAM on dead reckoning alone (the front end's matches refused) round [`ring`],
    /// with odometry that over-turns by the factor `turn_scale`.
    fn ring_drive(config: SlamConfig, turn_scale: f64) -> (RingResult, Slam) {
        ring_drive_then(config, turn_scale, |_| {})
    }

    /// [`ring_drive`], with `before_finish` done to the SLAM before the end of the log.
    fn ring_drive_then(
        config: SlamConfig,
        turn_scale: f64,
        before_finish: impl FnOnce(&mut Slam),
    ) -> (RingResult, Slam) {
        let config = SlamConfig {
            method: SlamMethod::Graph,
            max_correction: 0.0,
            max_correction_angle: 0.0,
            ..config
        };
        let mut slam = Slam::new(config, Pose2::IDENTITY);
        let segs = ring();
        // The drive: the corridor's centre line, once round and 4 m on, turning in place.
        let mut steps = Vec::new();
        for len in [8.0, 4.0, 8.0, 4.0] {
            steps.extend(std::iter::repeat_n(
                Pose2::new(0.1, 0.0, 0.0),
                (len / 0.1) as usize,
            ));
            steps.extend(std::iter::repeat_n(
                Pose2::new(0.0, 0.0, std::f64::consts::FRAC_PI_2 / 16.0),
                16,
            ));
        }
        steps.extend(std::iter::repeat_n(Pose2::new(0.1, 0.0, 0.0), 40));
        let (mut truth, mut odo) = (Pose2::IDENTITY, Pose2::IDENTITY);
        let (mut truths, mut odometry_worst) = (Vec::new(), 0.0f64);
        for (k, step) in std::iter::once(Pose2::IDENTITY).chain(steps).enumerate() {
            truth = truth.compose(&step);
            odo = odo.compose(&Pose2::new(step.x, step.y, step.theta * turn_scale));
            let mut scan = scan_of(&segs, &truth);
            scan.stamp = Time::from_secs(k as f64 * 0.1);
            slam.update(&scan, &odo, &Pose2::IDENTITY);
            truths.push(truth);
            odometry_worst = odometry_worst.max(odo.distance(&truth));
        }
        before_finish(&mut slam);
        slam.finish();
        let traj = slam.trajectory();
        let worst = traj
            .iter()
            .zip(&truths)
            .map(|((_, e), t)| e.distance(t))
            .fold(0.0, f64::max);
        let end = traj.last().unwrap().1;
        let r = RingResult {
            odometry_worst,
            worst,
            end_heading_error: wrap_angle(end.theta - truth.theta).abs(),
            loop_closures: slam.loop_closures(),
            optimizations: slam.optimizations(),
        };
        (r, slam)
    }

    /// The loop closures of a ring closed right agree with the optimised graph to centimetres
    /// and within Cartographer's 1° (all held: precision 1); one that says a keyframe lies 0.3 m and 2° from where the others put it is reported
    /// violated by that much (Cartographer's precision counts it false).
    #[test]
    fn loop_residuals_measure_how_far_the_graph_is_from_each_loop() {
        let (r, mut slam) = ring_drive(SlamConfig::default(), 1.04);
        let held = slam.loop_residuals();
        assert_eq!(held.len(), r.loop_closures - slam.outliers());
        assert!(
            held.iter()
                .all(|l| l.translation < 0.05 && l.rotation < 1f64.to_radians()),
            "{held:?}"
        );
        let (a, b) = (0, slam.graph.nodes.len() - 1);
        let truth = slam.graph.nodes[a].between(&slam.graph.nodes[b]);
        let off = truth.compose(&Pose2::new(0.3, 0.0, 2f64.to_radians()));
        let mut wrong = Edge::with_sigmas(a, b, off, [0.05, 0.05, 0.02]);
        wrong.huber = Some(1.0);
        slam.graph.edges.push(wrong);
        let last = *slam.loop_residuals().last().unwrap();
        assert!((last.translation - 0.3).abs() < 1e-9, "{last:?}");
        assert!((last.rotation - 2f64.to_radians()).abs() < 1e-9, "{last:?}");
        assert_eq!(last.from, slam.nodes[a].scan.stamp);
        assert_eq!(last.to, slam.nodes[b].scan.stamp);
    }
}
