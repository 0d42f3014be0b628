//! The running simulation: rapier state, the robot, its sensors and the clock.
//!
//! [`Simulation`] is the mutable counterpart of the immutable [`World`] (MuJoCo's `mjData` to
//! its `mjModel`). [`Simulation::step`] advances one fixed physics step and returns whatever
//! sensor messages fell due in it; sensors run at their own rates on the simulation clock, so
//! a run depends only on the world, the configuration, the seed and the commands given.

use crate::agent::AgentConfig;
use crate::config::{SpecError, check_range};
use crate::create::{CreateConfig, CreateDrive, GRAVITY, PlanarVelocity, wheel_traction};
use crate::joint::{Joint, JointConfig};
use crate::lidar::{BeamHit, Lidar, LidarConfig};
use crate::noise::stream;
use crate::people::{
    Body, Crowd, CrowdConfig, FlowConfig, PARKED_Z, PersonConfig, PersonTruth, Surroundings,
};
use crate::ray_grid::RayGrid;
use crate::render::Scene;
use crate::world::mesh::{TriMesh, UvMap};
use crate::world::{Material, Motion, World};
use futago_msgs::{BumpsAndDrops, DriveCommand, Duration, LaserScan, Odometry, Pose2, Time};
use glam::{Quat, Vec3};
use rapier3d::math::Pose;
use rapier3d::prelude::*;
use serde::Deserialize;
use std::path::Path;

/// Physics settings.
#[derive(Debug, Clone, Deserialize, serde::Serialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct PhysicsConfig {
    /// Fixed physics rate, Hz (at least 200). The step is the nearest whole number of
    /// nanoseconds to its period, so that the clock never drifts.
    pub rate: f64,
}

impl Default for PhysicsConfig {
    fn default() -> Self {
        PhysicsConfig { rate: 200.0 }
    }
}

impl PhysicsConfig {
    pub fn validate(&self, file: &Path, key: &str) -> Result<(), SpecError> {
        check_range(
            file,
            &format!("{key}.rate"),
            self.rate,
            200.0,
            100_000.0,
            "Hz",
        )?;
        Ok(())
    }
}

/// What one step produced.
#[derive(Debug, Clone, Default)]
pub struct StepOutput {
    /// Completed laser scans, with the index of their laser.
    pub scans: Vec<(usize, LaserScan)>,
    /// What each beam of `scans[k]` hit: truth for scorers, never for the stack.
    pub hits: Vec<Vec<BeamHit>>,
    /// The Create's sensor stream, when a packet fell due.
    pub odometry: Option<Odometry>,
    pub bumps: Option<BumpsAndDrops>,
}

/// Counts of physical events over a run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counters {
    pub steps: u64,
    /// Steps that began a bumper press (either side).
    pub bump_events: u64,
    /// Steps with some wheel off the ground.
    pub wheel_drop_steps: u64,
    pub laser_rays: u64,
    /// Steps that began a contact between the robot and a person (a collision with a person).
    pub person_contact_events: u64,
    /// Steps with the robot touching a person.
    pub person_contact_steps: u64,
}

/// What moves besides the robot's wheels: joints on the robot's base that carry sensors, and
/// agents walking in the world. Sensors name their joint (`LidarConfig::joint`).
#[derive(Debug, Clone, Default)]
pub struct Movers {
    pub joints: Vec<JointConfig>,
    pub agents: Vec<AgentConfig>,
    /// People on routes or standing ([`crate::people`]).
    pub people: Vec<PersonConfig>,
    /// Streams of people between places.
    pub flows: Vec<FlowConfig>,
    /// The people's motion model and body.
    pub crowd: CrowdConfig,
}

/// The state of a simulation of one Create in a world.
pub struct Simulation {
    physics: PhysicsWorld,
    dt: Duration,
    time: Time,
    robot: RigidBodyHandle,
    robot_collider: ColliderHandle,
    drive: CreateDrive,
    yaw_inertia: f64,
    lidars: Vec<Lidar>,
    /// The frame each laser is fixed to: the base or a joint on it.
    lidar_frames: Vec<crate::rig::Parent>,
    joints: Vec<Joint>,
    /// Each agent and its kinematic body.
    agents: Vec<(AgentConfig, RigidBodyHandle)>,
    /// The people, and each slot's bodies: torso with head, left leg, right leg.
    crowd: Crowd,
    people_bodies: Vec<[RigidBodyHandle; 3]>,
    /// The lasers' ray casts: the world's colliders binned in plan.
    rays: RayGrid,
    /// Whether the robot touched a person in the last step.
    touching_person: bool,
    /// Rigid body of each world object (fixed bodies for static ones).
    object_bodies: Vec<RigidBodyHandle>,
    stream_period: Duration,
    next_stream: i64,
    bumps: BumpsAndDrops,
    counters: Counters,
}

/// Force that closes a bumper switch, N.
pub const BUMPER_FORCE: f64 = 0.5;

/// Collision group of floor and ceiling slabs.
const SLAB_GROUP: Group = Group::GROUP_2;
/// Collision group of the robot body.
const ROBOT_GROUP: Group = Group::GROUP_3;
/// Collision group of people's bodies.
const PEOPLE_GROUP: Group = Group::GROUP_4;
/// What people steer around: everything but the floor and ceiling, the robot (which they
/// treat as a walker) and each other.
const PEOPLE_OBSTACLES: InteractionGroups = InteractionGroups::new(
    Group::GROUP_5,
    Group::ALL
        .difference(SLAB_GROUP)
        .difference(ROBOT_GROUP)
        .difference(PEOPLE_GROUP),
    InteractionTestMode::And,
);
/// The height at which people look for the nearest obstacle, m (between knee and hip: walls,
/// furniture and boxes, not a table top above).
const PEOPLE_OBSTACLE_HEIGHT: f32 = 0.5;

/// Robot body shape: a prism of this many sides (the render mesh uses the same vertices).
const ROBOT_SEGMENTS: u32 = 32;

/// Inserts the robot at `start`: a prism of its radius and height on its clearance, planar
/// (z, roll and pitch locked) and moved by its wheels, not by gravity. Gives its body, its
/// collider and its yaw inertia, kg m².
fn insert_robot(
    p: &mut PhysicsWorld,
    robot: &CreateConfig,
    start: Pose2,
) -> (RigidBodyHandle, ColliderHandle, f64) {
    let m = robot.mass as f32;
    let r = robot.radius as f32;
    let yaw_inertia = 0.5 * robot.mass * robot.radius * robot.radius;
    let body = RigidBodyBuilder::dynamic()
        .pose(Pose::from_parts(
            Vec3::new(start.x as f32, start.y as f32, 0.0),
            Quat::from_rotation_z(start.theta as f32),
        ))
        .gravity_scale(0.0)
        .locked_axes(
            LockedAxes::TRANSLATION_LOCKED_Z
                | LockedAxes::ROTATION_LOCKED_X
                | LockedAxes::ROTATION_LOCKED_Y,
        )
        .additional_mass_properties(MassProperties::new(
            Vec3::ZERO,
            m,
            Vec3::new(
                yaw_inertia as f32 / 2.0,
                yaw_inertia as f32 / 2.0,
                yaw_inertia as f32,
            ),
        ))
        .build();
    let robot_body = p.bodies.insert(body);
    let hh = (robot.height / 2.0) as f32;
    let hull = SharedShape::convex_hull(&TriMesh::prism_vertices(r, hh, ROBOT_SEGMENTS))
        .expect("a prism has a hull");
    let col = ColliderBuilder::new(hull)
        .density(0.0)
        .friction(0.3)
        .collision_groups(InteractionGroups::new(
            ROBOT_GROUP,
            Group::ALL.difference(SLAB_GROUP),
            InteractionTestMode::And,
        ))
        .translation(Vec3::new(0.0, 0.0, robot.clearance as f32 + hh))
        .build();
    let robot_collider = p
        .colliders
        .insert_with_parent(col, robot_body, &mut p.bodies);
    (robot_body, robot_collider, yaw_inertia)
}

impl Simulation {
    /// Builds the rapier state from `world` and `movers`, places the robot at `start` and seeds
    /// every noise stream from `seed`. A laser whose `joint` names no joint of `movers` is
    /// fixed to the base (the scenario loader refuses that case with the file and key).
    pub fn new(
        world: &World,
        physics: &PhysicsConfig,
        robot: &CreateConfig,
        lidars: &[(LidarConfig, crate::lidar::LidarSpec)],
        movers: &Movers,
        start: Pose2,
        seed: u64,
    ) -> Simulation {
        let mut p = PhysicsWorld::new();
        p.gravity = Vec3::new(0.0, 0.0, -GRAVITY as f32);
        let dt = Duration((1e9 / physics.rate).round() as i64);
        p.integration_parameters.dt = dt.secs() as f32;
        let mut object_bodies = Vec::with_capacity(world.objects.len());
        for o in &world.objects {
            let body = match o.motion {
                Motion::Static => RigidBodyBuilder::fixed().pose(o.pose).build(),
                Motion::Dynamic { .. } => RigidBodyBuilder::dynamic().pose(o.pose).build(),
            };
            let h = p.bodies.insert(body);
            if let Some(shape) = &o.shape {
                let mut cb = ColliderBuilder::new(shape.clone()).friction(o.friction as f32);
                if o.slab {
                    cb = cb.collision_groups(InteractionGroups::new(
                        SLAB_GROUP,
                        Group::ALL,
                        InteractionTestMode::And,
                    ));
                }
                if let Motion::Dynamic { mass } = o.motion {
                    cb = cb.mass(mass as f32);
                }
                p.colliders.insert_with_parent(cb.build(), h, &mut p.bodies);
            }
            object_bodies.push(h);
        }
        // Agents: kinematic upright prisms, posed by their paths.
        let mut agents = Vec::with_capacity(movers.agents.len());
        for a in &movers.agents {
            let at = a.pose_at(Time::ZERO);
            let body = RigidBodyBuilder::kinematic_position_based()
                .pose(agent_pose(a, at))
                .build();
            let h = p.bodies.insert(body);
            let hh = (a.height / 2.0) as f32;
            let hull = SharedShape::convex_hull(&TriMesh::prism_vertices(
                a.radius as f32,
                hh,
                ROBOT_SEGMENTS,
            ))
            .expect("a prism has a hull");
            let col = ColliderBuilder::new(hull)
                .friction(0.3)
                .translation(Vec3::new(0.0, 0.0, hh))
                .build();
            p.colliders.insert_with_parent(col, h, &mut p.bodies);
            agents.push((a.clone(), h));
        }
        // People: three kinematic bodies per slot of the crowd, parked below the floor while
        // the slot is empty.
        let crowd = Crowd::new(&movers.people, &movers.flows, movers.crowd, seed);
        let mut people_bodies = Vec::with_capacity(crowd.slots());
        for i in 0..crowd.slots() {
            let poses = person_poses(&crowd, i);
            let mut handles = [RigidBodyHandle::invalid(); 3];
            for (k, (shape, offset)) in person_colliders(crowd.body_of(i)).into_iter().enumerate() {
                let body = RigidBodyBuilder::kinematic_position_based()
                    .pose(poses[k])
                    .build();
                let h = p.bodies.insert(body);
                for (s, o) in shape.into_iter().zip(offset) {
                    let col = ColliderBuilder::new(s)
                        .friction(0.3)
                        .translation(o)
                        .collision_groups(InteractionGroups::new(
                            PEOPLE_GROUP,
                            // Kinematic bodies get no contact forces: only the robot and
                            // the world's movable boxes need pairs with them. Leaving out
                            // the floor, the ceiling and each other spares the narrow phase.
                            Group::ALL.difference(SLAB_GROUP).difference(PEOPLE_GROUP),
                            InteractionTestMode::And,
                        ))
                        .build();
                    p.colliders.insert_with_parent(col, h, &mut p.bodies);
                }
                handles[k] = h;
            }
            people_bodies.push(handles);
        }
        // The robot: planar (z, roll and pitch locked), moved by its wheels, not by gravity.
        let (robot_body, robot_collider, yaw_inertia) = insert_robot(&mut p, robot, start);
        let drive = CreateDrive::new(
            robot.clone(),
            [
                stream(seed, "robot.encoder.left"),
                stream(seed, "robot.encoder.right"),
            ],
        );
        let joints: Vec<Joint> = movers.joints.iter().map(Joint::new).collect();
        let lidar_frames = lidars
            .iter()
            .map(|(c, _)| crate::rig::Parent::of(c.joint.as_deref(), None, movers))
            .collect();
        let lidars = lidars
            .iter()
            .map(|(c, s)| Lidar::new(c, s.clone(), stream(seed, &format!("lidar.{}", c.name))))
            .collect();
        // Note: rapier fills its broad phase (which ray casts use) in the first step; wheel
        // drops are therefore first sampled with the first sensor packet.
        let movers: std::collections::HashMap<RigidBodyHandle, BeamHit> = agents
            .iter()
            .enumerate()
            .map(|(i, (_, h))| (*h, BeamHit::Agent(i as u32)))
            .chain(
                people_bodies
                    .iter()
                    .enumerate()
                    .flat_map(|(i, hs)| hs.iter().map(move |h| (*h, BeamHit::Person(i as u32)))),
            )
            .collect();
        let rays = RayGrid::new(&p.bodies, &p.colliders, robot_body, &movers);
        Simulation {
            rays,
            physics: p,
            dt,
            time: Time::ZERO,
            robot: robot_body,
            robot_collider,
            drive,
            yaw_inertia,
            lidars,
            lidar_frames,
            joints,
            agents,
            crowd,
            people_bodies,
            touching_person: false,
            object_bodies,
            stream_period: Duration::from_secs(robot.stream_period),
            next_stream: 1,
            bumps: BumpsAndDrops::default(),
            counters: Counters::default(),
        }
    }

    /// Simulation time.
    pub fn time(&self) -> Time {
        self.time
    }

    /// The fixed step.
    pub fn dt(&self) -> Duration {
        self.dt
    }

    /// Event counts so far.
    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// The lasers, in configuration order.
    pub fn lidars(&self) -> &[Lidar] {
        &self.lidars
    }

    /// The robot base's pose as physics has it (the frame the rig's sensors hang from).
    pub fn base_pose(&self) -> Pose {
        *self.physics.bodies[self.robot].position()
    }

    /// Ground-truth pose of the robot's base frame (on the floor, between the drive wheels).
    pub fn robot_pose(&self) -> Pose2 {
        let b = &self.physics.bodies[self.robot];
        let t = b.translation();
        // Roll and pitch are locked, so the rotation is about z alone.
        let q = b.rotation();
        let yaw = 2.0 * (q.z as f64).atan2(q.w as f64);
        Pose2::new(t.x as f64, t.y as f64, futago_msgs::wrap_angle(yaw))
    }

    /// Moves the robot to `pose` at rest, without its odometry knowing: a kidnapping (the
    /// robot picked up and put down elsewhere), for testing localisation's recovery.
    pub fn teleport(&mut self, pose: Pose2) {
        let body = &mut self.physics.bodies[self.robot];
        let z = body.translation().z;
        body.set_position(
            Pose::from_parts(
                Vec3::new(pose.x as f32, pose.y as f32, z),
                Quat::from_rotation_z(pose.theta as f32),
            ),
            true,
        );
        body.set_linvel(Vec3::ZERO, true);
        body.set_angvel(Vec3::ZERO, true);
        // No beam is cast from somewhere between where the robot was and where it is put.
        for l in &mut self.lidars {
            l.forget_motion();
        }
    }

    /// Ground-truth velocity of the robot in its own frame.
    pub fn robot_velocity(&self) -> PlanarVelocity {
        let b = &self.physics.bodies[self.robot];
        let v = b.linvel();
        let th = self.robot_pose().theta;
        let (s, c) = th.sin_cos();
        PlanarVelocity {
            forward: c * v.x as f64 + s * v.y as f64,
            lateral: -s * v.x as f64 + c * v.y as f64,
            yaw_rate: b.angvel().z as f64,
        }
    }

    /// Current nominal wheel speeds (left, right), m/s: what the firmware believes.
    pub fn wheel_speeds(&self) -> (f64, f64) {
        self.drive.wheel_speed
    }

    /// Current pose of every world object, in [`World::objects`] order.
    pub fn object_poses(&self) -> Vec<Pose> {
        self.object_bodies
            .iter()
            .map(|&h| *self.physics.bodies[h].position())
            .collect()
    }

    /// Current pose of every body a camera sees, in [`scene`] order: the world's objects,
    /// the agents, then the robot.
    pub fn scene_poses(&self) -> Vec<Pose> {
        let mut poses = self.object_poses();
        poses.extend(
            self.agents
                .iter()
                .map(|(_, h)| *self.physics.bodies[*h].position()),
        );
        poses.extend(
            self.people_bodies
                .iter()
                .flatten()
                .map(|h| *self.physics.bodies[*h].position()),
        );
        poses.push(*self.physics.bodies[self.robot].position());
        poses
    }

    /// The joints, in [`Movers::joints`] order, at their current angles.
    pub fn joints(&self) -> &[Joint] {
        &self.joints
    }

    /// Asks joint `name` to turn to `angle` (rad). Errors when no joint has that name or the
    /// joint does not take commands.
    pub fn command_joint(&mut self, name: &str, angle: f64) -> Result<(), String> {
        let j = self
            .joints
            .iter_mut()
            .find(|j| j.config.name == name)
            .ok_or_else(|| format!("no joint named `{name}`"))?;
        if j.command(angle) {
            Ok(())
        } else {
            Err(format!(
                "joint `{name}` moves by itself ({:?}); only `command` joints take angles",
                j.config.mode
            ))
        }
    }

    /// Every agent's true pose, in [`Movers::agents`] order.
    pub fn agent_poses(&self) -> Vec<(&str, Pose2)> {
        self.agents
            .iter()
            .map(|(a, _)| (a.name.as_str(), a.pose_at(self.time)))
            .collect()
    }

    /// Every person in the world now: id, name, pose and velocity.
    pub fn people(&self) -> Vec<PersonTruth> {
        self.crowd.truth()
    }

    /// The crowd (slots, colours, flows' counts).
    pub fn crowd(&self) -> &Crowd {
        &self.crowd
    }

    /// Latest bumper and wheel-drop state.
    pub fn bumps(&self) -> BumpsAndDrops {
        self.bumps
    }

    /// Casts a ray against everything but the robot; distance to the first hit. Sees nothing
    /// before the first [`Simulation::step`], which builds rapier's query structure.
    pub fn cast_ray(&self, origin: Vec3, dir: Vec3, max: f32) -> Option<f32> {
        let qp = self
            .physics
            .query_pipeline_with_filter(QueryFilter::default().exclude_rigid_body(self.robot));
        qp.cast_ray(&Ray::new(origin, dir), max, true)
            .map(|(_, d)| d)
    }

    /// Casts a ray as the lasers do (the same distances as [`Simulation::cast_ray`], by the
    /// plan grid of [`RayGrid`]), against the colliders as they are now; distance to the first
    /// hit and what was hit. Unlike [`Simulation::cast_ray`], sees the world before the first
    /// step too.
    pub fn cast_beam(&mut self, origin: Vec3, dir: Vec3, max: f32) -> Option<(f32, BeamHit)> {
        self.rays.cast(
            &self.physics.colliders,
            self.counters.steps,
            origin,
            dir,
            max,
        )
    }

    /// Which wheels (left, right, caster) have no floor within their drop travel.
    fn wheel_drops(&self, pose: &Pose2) -> BumpsAndDrops {
        let c = &self.drive.config;
        let b = c.actual_wheel_base() / 2.0;
        let qp = self
            .physics
            .query_pipeline_with_filter(QueryFilter::default().exclude_rigid_body(self.robot));
        let top = 0.05f32;
        let dropped = |x: f64, y: f64| {
            let p = pose.transform_point([x, y]);
            qp.cast_ray(
                &Ray::new(Vec3::new(p[0] as f32, p[1] as f32, top), -Vec3::Z),
                top + c.wheel_drop_travel as f32,
                true,
            )
            .is_none()
        };
        BumpsAndDrops {
            drop_left: dropped(0.0, b),
            drop_right: dropped(0.0, -b),
            drop_caster: dropped(0.13f64.min(c.radius * 0.8), 0.0),
            ..Default::default()
        }
    }

    /// Bumper state from the robot's contacts: a contact in the front half that pushes with at
    /// least [`BUMPER_FORCE`] presses the bumper on its side; one within ±15° of straight
    /// ahead presses both.
    fn bumpers(&self) -> (bool, bool) {
        let (mut left, mut right) = (false, false);
        // The switch closes under a push of at least this force, N.
        let min_impulse = (BUMPER_FORCE * self.dt.secs()) as f32;
        for pair in self
            .physics
            .narrow_phase
            .contact_pairs_with(self.robot_collider)
        {
            let robot_first = pair.collider1 == self.robot_collider;
            for m in pair.solver_manifolds() {
                for pt in &m.points {
                    if pt.data.impulse < min_impulse {
                        continue;
                    }
                    // Contact points are in each collider's frame; the robot's turns with its body.
                    let local = if robot_first {
                        pt.local_p1
                    } else {
                        pt.local_p2
                    };
                    let bearing = (local.y as f64).atan2(local.x as f64);
                    if bearing.abs() > std::f64::consts::FRAC_PI_2 {
                        continue;
                    }
                    let band = 15f64.to_radians();
                    if bearing > -band {
                        left = true;
                    }
                    if bearing < band {
                        right = true;
                    }
                }
            }
        }
        (left, right)
    }

    /// Moves the people on by `dt` (their social forces from the state now) and sets their
    /// bodies' next kinematic poses.
    fn step_people(&mut self, dt: f64) {
        let robot = {
            let b = &self.physics.bodies[self.robot];
            let (t, v) = (b.translation(), b.linvel());
            (
                [t.x as f64, t.y as f64],
                [v.x as f64, v.y as f64],
                self.drive.config.radius,
            )
        };
        let qp = self
            .physics
            .query_pipeline_with_filter(QueryFilter::default().groups(PEOPLE_OBSTACLES));
        let nearest = |p: [f64; 2], range: f64| -> Option<[f64; 2]> {
            let at = Vec3::new(p[0] as f32, p[1] as f32, PEOPLE_OBSTACLE_HEIGHT);
            qp.project_point(at, range as f32, true)
                .and_then(|(_, proj)| {
                    let q = proj.point;
                    // Only what stands beside the person at this height pushes them.
                    ((q.z - at.z).abs() < 0.05).then_some([q.x as f64, q.y as f64])
                })
        };
        let around = Surroundings {
            robot: Some(robot),
            nearest_obstacle: &nearest,
        };
        // The forces at the crowd's rate, the motion at every step.
        let every = (1.0 / (self.crowd.config().rate * dt)).round().max(1.0) as u64;
        let t = self.time.secs();
        if self.counters.steps.is_multiple_of(every) {
            self.crowd.plan(t, &around);
        }
        self.crowd.advance(t, dt, &around);
        for (i, handles) in self.people_bodies.iter().enumerate() {
            for (h, pose) in handles.iter().zip(person_poses(&self.crowd, i)) {
                self.physics.bodies[*h].set_next_kinematic_position(pose);
            }
        }
    }

    /// Whether the robot's collider touches any person's in the narrow phase now.
    fn touching_person(&self) -> bool {
        self.physics
            .narrow_phase
            .contact_pairs_with(self.robot_collider)
            .any(|pair| {
                let other = if pair.collider1 == self.robot_collider {
                    pair.collider2
                } else {
                    pair.collider1
                };
                pair.has_any_active_contact() && self.is_person(other)
            })
    }

    /// Whether `collider` is part of a person: one of the crowd's bodies carries it. (Not a
    /// test of its collision group: the world's and the agents' colliders keep rapier's
    /// default, every group, people's among them.)
    fn is_person(&self, collider: ColliderHandle) -> bool {
        self.physics
            .colliders
            .get(collider)
            .and_then(|c| c.parent())
            .is_some_and(|b| self.people_bodies.iter().any(|h| h.contains(&b)))
    }

    /// Advances one physics step. `command`, if given, replaces the drive command (it holds
    /// until the next one, as on the Create). Every laser makes every scan.
    pub fn step(&mut self, command: Option<&DriveCommand>) -> StepOutput {
        self.step_taking(command, &mut |_, _| true)
    }

    /// [`Simulation::step`], where laser `i`'s scan stamped `stamp` that falls due in this
    /// step is made only if `wanted(i, stamp)`: its rays are cast for someone who reads it.
    /// What the scans made read does not depend on which others are (see [`Lidar::update`]).
    pub fn step_taking(
        &mut self,
        command: Option<&DriveCommand>,
        wanted: &mut dyn FnMut(usize, Time) -> bool,
    ) -> StepOutput {
        let mut out = StepOutput::default();
        if let Some(c) = command {
            self.drive.command(c);
        }
        let dt = self.dt.secs();
        let pose = self.robot_pose();
        // Wheel drops as sensed at the end of the previous step.
        let drops = self.bumps;
        let rims = self.drive.advance(dt, drops.dropped());
        // Wheel traction on the floor.
        let cfg = &self.drive.config;
        let w = cfg.mass * GRAVITY * cfg.drive_load_fraction / 2.0;
        let loads = (
            if drops.drop_left { 0.0 } else { w },
            if drops.drop_right { 0.0 } else { w },
        );
        let v = wheel_traction(
            self.robot_velocity(),
            cfg.mass,
            self.yaw_inertia,
            cfg.actual_wheel_base(),
            rims,
            loads,
            cfg.wheel_friction,
            dt,
        );
        let (s, c) = pose.theta.sin_cos();
        let body = &mut self.physics.bodies[self.robot];
        body.set_linvel(
            Vec3::new(
                (c * v.forward - s * v.lateral) as f32,
                (s * v.forward + c * v.lateral) as f32,
                0.0,
            ),
            true,
        );
        body.set_angvel(Vec3::new(0.0, 0.0, v.yaw_rate as f32), true);
        let next = self.time + self.dt;
        for (a, h) in &self.agents {
            self.physics.bodies[*h].set_next_kinematic_position(agent_pose(a, a.pose_at(next)));
        }
        if self.crowd.slots() > 0 {
            self.step_people(dt);
        }
        self.physics.step();
        self.time = next;
        self.counters.steps += 1;
        for j in &mut self.joints {
            j.advance(self.time, dt);
        }

        let touching = self.touching_person();
        if touching {
            self.counters.person_contact_steps += 1;
            if !self.touching_person {
                self.counters.person_contact_events += 1;
            }
        }
        self.touching_person = touching;
        let (bl, br) = self.bumpers();
        if (bl || br) && !self.bumps.bumped() {
            self.counters.bump_events += 1;
        }
        // The wheel-drop switches are sampled with the sensor stream (every 15 ms on the
        // Create); between samples the last state holds, for the firmware and the traction.
        let stream_due = self.time.nanos() >= self.next_stream * self.stream_period.0;
        let drops = if stream_due {
            self.wheel_drops(&self.robot_pose())
        } else {
            self.bumps
        };
        if drops.dropped() {
            self.counters.wheel_drop_steps += 1;
        }
        self.bumps = BumpsAndDrops {
            bump_left: bl,
            bump_right: br,
            ..drops
        };

        // Lasers, from their frames on the rig.
        let frames: Vec<Pose> = self
            .lidar_frames
            .iter()
            .map(|&f| self.frame_pose(f))
            .collect();
        let mut rays = 0u64;
        let step = self.counters.steps;
        for (i, l) in self.lidars.iter_mut().enumerate() {
            let laser_pose = frames[i] * l.mount;
            let grid = &mut self.rays;
            let colliders = &self.physics.colliders;
            let wanted = |stamp| wanted(i, stamp);
            if let Some((scan, hits)) = l.update(self.time, &laser_pose, wanted, |o, d, max| {
                rays += 1;
                grid.cast(colliders, step, o, d, max)
            }) {
                out.scans.push((i, scan));
                out.hits.push(hits);
            }
        }
        self.counters.laser_rays += rays;

        // The Create's sensor stream.
        if stream_due {
            self.next_stream += 1;
            out.odometry = Some(self.drive.report(self.time));
            out.bumps = Some(self.bumps);
        }
        out
    }
}

/// The robot's render meshes in its base frame: the body prism with the collider's vertices,
/// dark grey like the Create's bumper.
pub fn robot_parts(robot: &CreateConfig) -> Vec<(Material, TriMesh)> {
    let hh = (robot.height / 2.0) as f32;
    let body = TriMesh::prism(robot.radius as f32, hh, ROBOT_SEGMENTS, UvMap::Fit).transformed(
        Quat::IDENTITY,
        Vec3::new(0.0, 0.0, robot.clearance as f32 + hh),
        1.0,
    );
    vec![(
        Material {
            name: "robot".into(),
            color: [0.25, 0.25, 0.27],
            texture: None,
        },
        body,
    )]
}

/// Slot `i`'s three body poses: torso (on the floor, facing the heading), left and right leg
/// (hinged at the hip, swung by the gait); all parked below the floor for an empty slot.
fn person_poses(crowd: &Crowd, i: usize) -> [Pose; 3] {
    let c = crowd.body_of(i);
    let Some((body, feet)) = crowd.body(i) else {
        let parked = Pose::from_translation(Vec3::new(0.0, 0.0, PARKED_Z as f32));
        return [parked; 3];
    };
    let yaw = Quat::from_rotation_z(body.theta as f32);
    let torso = Pose::from_parts(Vec3::new(body.x as f32, body.y as f32, 0.0), yaw);
    let leg = |side: f64, foot: [f64; 2]| {
        let hip = body.transform_point(crowd.hip(i, side));
        // The leg hangs from the hip towards its foot: the prism's axis (−z) turned onto the
        // hip-to-foot direction in the body's frame.
        let (run, down) = crowd.leg_run(i, side, foot);
        let turn = if run[1] == 0.0 {
            // Straight below the hip side to side: turned about the body's y alone.
            Quat::from_rotation_y(-(run[0] / c.hip_height).clamp(-1.0, 1.0).asin() as f32)
        } else {
            let to = Vec3::new(run[0] as f32, run[1] as f32, -down as f32);
            Quat::from_rotation_arc(Vec3::NEG_Z, to.normalize())
        };
        Pose::from_parts(
            Vec3::new(hip[0] as f32, hip[1] as f32, c.hip_height as f32),
            yaw * turn,
        )
    };
    [torso, leg(1.0, feet[0]), leg(-1.0, feet[1])]
}

/// Sides of a person's prisms (torso, head).
const PERSON_SEGMENTS: u32 = 16;
/// Sides of a leg's render mesh, whose vertices lie on its capsule collider: a side's middle
/// lies r·(1 − cos(π/24)) = 0.9 % of the radius inside the capsule (0.6 mm for the widest
/// drawn shins, 7.5 cm), so that the cameras' depth agrees with the lasers' rays at the
/// legs' edges as well.
const LEG_SEGMENTS: u32 = 24;
/// Latitudes of each end of a leg's render mesh (a hemisphere of the leg's radius).
const LEG_RINGS: u32 = 4;

/// A prism's vertices stretched to an ellipse of half axes `a` (x) and `b` (y).
fn elliptic_prism_vertices(a: f32, b: f32, half_height: f32) -> Vec<Vec3> {
    TriMesh::prism_vertices(1.0, half_height, PERSON_SEGMENTS)
        .into_iter()
        .map(|v| Vec3::new(v.x * a, v.y * b, v.z))
        .collect()
}

/// The colliders of a person's three bodies, each as shapes and their offsets in the body's
/// frame: the torso (an elliptic prism from hips to shoulders) and the head on it, whose
/// render meshes ([`person_parts`]) share the vertices; each leg a capsule from the hip to
/// the floor, whose render mesh has its vertices on the capsule. A capsule's bounding box and
/// ray casts are exact formulas, where a prism's hull needs its 32 vertices and GJK: with 20
/// people, the legs as capsules make the simulation 1.3 times as fast (`futago bench people`).
fn person_colliders(c: &Body) -> [(Vec<SharedShape>, Vec<Vec3>); 3] {
    let hull = |v: Vec<Vec3>| SharedShape::convex_hull(&v).expect("a prism has a hull");
    let th = ((c.shoulder_height - c.hip_height) / 2.0) as f32;
    let torso = hull(elliptic_prism_vertices(
        c.torso[0] as f32,
        c.torso[1] as f32,
        th,
    ));
    let hr = c.head_radius as f32;
    let head = hull(TriMesh::prism_vertices(hr, hr, PERSON_SEGMENTS));
    let lh = (c.hip_height / 2.0) as f32;
    let r = c.leg_radius as f32;
    let leg = || {
        (
            vec![SharedShape::capsule_z((lh - r).max(0.0), r)],
            vec![Vec3::new(0.0, 0.0, -lh)],
        )
    };
    [
        (
            vec![torso, head],
            vec![
                Vec3::new(0.0, 0.0, c.hip_height as f32 + th),
                Vec3::new(0.0, 0.0, (c.height - c.head_radius) as f32),
            ],
        ),
        leg(),
        leg(),
    ]
}

/// Slot `i`'s render meshes, body by body (torso with head, left leg, right leg), each named.
fn person_parts(crowd: &Crowd, i: usize) -> [(&'static str, Vec<(Material, TriMesh)>); 3] {
    let c = crowd.body_of(i);
    let (shirt, trousers) = crowd.colours(i);
    let material = |name: &str, color: [f64; 3]| Material {
        name: format!("person.{i}.{name}"),
        color,
        texture: None,
    };
    let th = ((c.shoulder_height - c.hip_height) / 2.0) as f32;
    let (a, b) = (c.torso[0] as f32, c.torso[1] as f32);
    let mut torso = TriMesh::prism(1.0, th, PERSON_SEGMENTS, UvMap::Fit);
    for p in &mut torso.positions {
        *p = Vec3::new(p.x * a, p.y * b, p.z + c.hip_height as f32 + th);
    }
    // An ellipse's normal at (a·cos t, b·sin t) is along (cos t / a, sin t / b).
    for n in &mut torso.normals {
        *n = Vec3::new(n.x / a, n.y / b, n.z).normalize_or(Vec3::Z);
    }
    let hr = c.head_radius as f32;
    let head = TriMesh::prism(hr, hr, PERSON_SEGMENTS, UvMap::Fit).transformed(
        Quat::IDENTITY,
        Vec3::new(0.0, 0.0, (c.height - c.head_radius) as f32),
        1.0,
    );
    let lh = (c.hip_height / 2.0) as f32;
    let leg = TriMesh::capsule(c.leg_radius as f32, lh, LEG_SEGMENTS, LEG_RINGS).transformed(
        Quat::IDENTITY,
        Vec3::new(0.0, 0.0, -lh),
        1.0,
    );
    [
        (
            "torso",
            vec![
                (material("shirt", shirt), torso),
                (material("skin", [0.85, 0.65, 0.5]), head),
            ],
        ),
        ("leg_l", vec![(material("leg_l", trousers), leg.clone())]),
        ("leg_r", vec![(material("leg_r", trousers), leg)]),
    ]
}

/// An agent's body pose from its planar pose: upright, on the floor.
fn agent_pose(_a: &AgentConfig, p: Pose2) -> Pose {
    Pose::from_parts(
        Vec3::new(p.x as f32, p.y as f32, 0.0),
        Quat::from_rotation_z(p.theta as f32),
    )
}

/// An agent's render mesh: the prism of its collider, in its colour.
pub fn agent_parts(a: &AgentConfig) -> Vec<(Material, TriMesh)> {
    let hh = (a.height / 2.0) as f32;
    let body = TriMesh::prism(a.radius as f32, hh, ROBOT_SEGMENTS, UvMap::Fit).transformed(
        Quat::IDENTITY,
        Vec3::new(0.0, 0.0, hh),
        1.0,
    );
    vec![(
        Material {
            name: format!("agent.{}", a.name),
            color: a.color,
            texture: None,
        },
        body,
    )]
}

/// What a camera sees: the world's objects in order, the agents, each person's three
/// bodies (drawn by `seed`, as the simulation of that seed draws them), then the robot
/// (posed by [`Simulation::scene_poses`]).
pub fn scene(
    world: &World,
    robot: &CreateConfig,
    movers: &Movers,
    start: Pose2,
    seed: u64,
) -> Scene {
    let mut scene = world.scene();
    for a in &movers.agents {
        scene.add_body(
            &a.name,
            agent_pose(a, a.pose_at(Time::ZERO)),
            agent_parts(a),
        );
    }
    // The crowd at time zero, as the simulation of this seed builds it: the seed draws each
    // slot's body, and where people stand at time zero does not depend on it.
    let crowd = Crowd::new(&movers.people, &movers.flows, movers.crowd, seed);
    for i in 0..crowd.slots() {
        let poses = person_poses(&crowd, i);
        for (k, (part, mesh)) in person_parts(&crowd, i).into_iter().enumerate() {
            scene.add_body(&format!("person.{i}.{part}"), poses[k], mesh);
        }
    }
    scene.add_body(
        "robot",
        Pose::from_parts(
            Vec3::new(start.x as f32, start.y as f32, 0.0),
            Quat::from_rotation_z(start.theta as f32),
        ),
        robot_parts(robot),
    );
    scene
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_legs_render_mesh_lies_on_its_collider() {
        // What a laser hits (the collider) and what a camera draws (the mesh) are one leg: every
        // vertex of the mesh, in the leg body's frame, is on the collider's surface, and the
        // leg reaches from the hip (the body's origin) down to the floor.
        let person = crate::people::tests::person("a", vec![[0.0, 0.0], [5.0, 0.0]], 1.2);
        let crowd = Crowd::new(&[person], &[], CrowdConfig::default(), 1);
        // The body the seed drew for this person, not the crowd's.
        let c = *crowd.body_of(0);
        assert_ne!(c, CrowdConfig::default().body());
        let colliders = person_colliders(&c);
        let parts = person_parts(&crowd, 0);
        for k in [1, 2] {
            let (shapes, offsets) = &colliders[k];
            assert_eq!(shapes.len(), 1);
            let at = Pose::from_translation(offsets[0]);
            let mesh = &parts[k].1[0].1;
            let (mut lo, mut hi) = (f32::MAX, f32::MIN);
            for p in &mesh.positions {
                let d = shapes[0].distance_to_point(&at, *p, false);
                assert!(d.abs() < 1e-5, "vertex {p} is {d} m off the leg's collider");
                lo = lo.min(p.z);
                hi = hi.max(p.z);
            }
            assert!(
                (lo + c.hip_height as f32).abs() < 1e-5 && hi.abs() < 1e-5,
                "{lo} {hi}"
            );
            // The laser's cross-section of a hanging leg is a circle of the leg's radius.
            let hit = shapes[0]
                .cast_ray(
                    &at,
                    &Ray::new(Vec3::new(-1.0, 0.0, -0.6), Vec3::X),
                    2.0,
                    true,
                )
                .expect("a ray through the leg hits it");
            assert!((hit - (1.0 - c.leg_radius as f32)).abs() < 1e-5, "{hit}");
        }
    }
}
