//! The sensor rig: where each sensor is, composed on one small frame tree, and the cameras
//! that render from it.
//!
//! Every sensor hangs from a frame ([`Parent`]): the robot's base, a joint on the base, or an
//! agent on the floor; a carrier may sway between that frame and the sensor's mount:
//! `frame · sway(t) · mount`. [`Simulation::frame_pose`] poses the frames; lasers cast from
//! them in [`Simulation::step`], cameras render from them in [`Cameras::capture`]. A loop
//! running the simulation asks which camera is due, renders it when someone wants it, and
//! hands the frame on by the camera's index: a new kind of sensor is a new part of this rig
//! and of its consumers, not of the loop.

use crate::kinect::{Kinect, KinectSpec};
use crate::noise::stream;
use crate::render::{RenderError, Renderer};
use crate::sim::{Movers, Simulation};
use futago_msgs::camera::{DepthImage, RgbImage, RgbdFrame};
use futago_msgs::{Pose3, Time};
use rapier3d::math::Pose;
use std::time::Instant;

/// The frame a sensor's mount is fixed to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Parent {
    /// The robot's base.
    Base,
    /// A joint on the base (index into [`Movers::joints`]).
    Joint(usize),
    /// An agent walking the floor (index into [`Movers::agents`]).
    Agent(usize),
}

impl Parent {
    /// The frame of a sensor that names `joint` (on the base) or `carrier` (an agent): the
    /// joint if it names one of `movers`, else the carrier, else the base.
    pub fn of(joint: Option<&str>, carrier: Option<&str>, movers: &Movers) -> Parent {
        if let Some(j) = joint.and_then(|j| movers.joints.iter().position(|k| k.name == j)) {
            return Parent::Joint(j);
        }
        match carrier.and_then(|a| movers.agents.iter().position(|k| k.name == a)) {
            Some(a) => Parent::Agent(a),
            None => Parent::Base,
        }
    }
}

impl Simulation {
    /// The pose of frame `parent` now, in the world: the robot's base as physics has it, a
    /// joint's frame on it, or an agent's frame on the floor (its path pose, z = 0).
    pub fn frame_pose(&self, parent: Parent) -> Pose {
        match parent {
            Parent::Base => self.base_pose(),
            Parent::Joint(j) => self.base_pose() * self.joints()[j].transform(),
            Parent::Agent(a) => {
                let p = self.agent_poses()[a].1;
                Pose::from_parts(
                    glam::Vec3::new(p.x as f32, p.y as f32, 0.0),
                    glam::Quat::from_rotation_z(p.theta as f32),
                )
            }
        }
    }
}

/// The scenario's cameras on the rig, and the renderer they share.
pub struct Cameras {
    kinects: Vec<Kinect>,
    parents: Vec<Parent>,
    renderer: Option<Renderer>,
    /// When the scene was last posed in the renderer (once a step, for every camera).
    posed: Option<Time>,
    /// Frames rendered per camera.
    pub frames: Vec<u64>,
    /// Wall time spent rendering, s.
    pub seconds: f64,
}

/// A frame just rendered: the images, the optical frame's true pose in the world, the optical
/// frame on the robot's floor frame (x forward, y left, z up from the floor under the base;
/// `None` for a camera an agent carries), and the pose it was rendered from.
pub struct Shot {
    pub frame: RgbdFrame,
    pub optical: Pose3,
    pub on_base: Option<Pose3>,
    /// The carrier's pose the camera's mount applies to (for [`Cameras::true_depth`]).
    pub carrier: Pose,
}

impl Cameras {
    /// The cameras `specs`, placed on the frames of `movers` they name, each with its noise
    /// stream from `seed`; `renderer` renders them (none: nothing will be captured).
    pub fn new(
        specs: &[KinectSpec],
        movers: &Movers,
        seed: u64,
        renderer: Option<Renderer>,
    ) -> Cameras {
        Cameras {
            kinects: specs
                .iter()
                .map(|c| Kinect::new(c.clone(), stream(seed, &format!("camera.{}", c.name))))
                .collect(),
            parents: specs
                .iter()
                .map(|c| Parent::of(c.joint.as_deref(), c.carrier.as_deref(), movers))
                .collect(),
            renderer,
            posed: None,
            frames: vec![0; specs.len()],
            seconds: 0.0,
        }
    }

    /// Camera `c`'s name.
    pub fn name(&self, c: usize) -> &str {
        &self.kinects[c].spec.name
    }

    /// The adapter the cameras render on, if they render.
    pub fn adapter(&self) -> Option<String> {
        self.renderer.as_ref().map(Renderer::adapter)
    }

    /// Whether camera `c` has a frame due at `now` and a renderer to take it with.
    pub fn due(&self, c: usize, now: Time) -> bool {
        self.renderer.is_some() && self.kinects[c].due(now.nanos())
    }

    /// Renders the frame of camera `c` that is due now (poses the scene first, once a
    /// step), with its noise; counts it and times it. `rgb`: the colour image too (without
    /// it the frame holds depth alone, and is cheaper: a depth render and its noise).
    /// `depth_stride`: the measured depth is wanted on every `depth_stride`-th column and row
    /// alone, the other pixels left 0 ([`crate::kinect::KinectSpec::apply_noise_on_grid`]).
    pub fn capture(
        &mut self,
        c: usize,
        sim: &Simulation,
        rgb: bool,
        depth_stride: u32,
    ) -> Result<Shot, RenderError> {
        let Some(r) = self.renderer.as_mut() else {
            return Err(RenderError::Config(
                "no renderer: the cameras were built without one".into(),
            ));
        };
        let now = sim.time();
        let t0 = Instant::now();
        if self.posed != Some(now) {
            r.set_poses(&sim.scene_poses())?;
            self.posed = Some(now);
        }
        let cam = &mut self.kinects[c];
        let carrier = sim.frame_pose(self.parents[c]);
        let carrier = match &cam.spec.sway {
            Some(sway) => carrier * sway.pose(now),
            None => carrier,
        };
        // On the robot's floor frame: the base's planar pose taken back out.
        let on_base = (!matches!(self.parents[c], Parent::Agent(_))).then(|| {
            let b = sim.robot_pose();
            let planar = Pose::from_parts(
                glam::Vec3::new(b.x as f32, b.y as f32, 0.0),
                glam::Quat::from_rotation_z(b.theta as f32),
            );
            cam.optical_pose(&(planar.inverse() * carrier))
        });
        cam.take();
        let frame = cam.capture(r, &carrier, now, rgb, depth_stride)?;
        let optical = cam.optical_pose(&carrier);
        self.seconds += t0.elapsed().as_secs_f64();
        self.frames[c] += 1;
        Ok(Shot {
            frame,
            optical,
            on_base,
            carrier,
        })
    }

    /// `f` of camera `c`, the renderer and the stamp of the frame just captured, timed with
    /// the rendering: the work a node asks of the frame after its capture.
    fn after_capture<T>(
        &mut self,
        c: usize,
        f: impl FnOnce(&mut Kinect, &mut Renderer, Time) -> Result<T, RenderError>,
    ) -> Result<T, RenderError> {
        let Some(r) = self.renderer.as_mut() else {
            return Err(RenderError::Config(
                "no renderer: the cameras were built without one".into(),
            ));
        };
        let Some(stamp) = self.posed else {
            return Err(RenderError::Config(
                "no frame was captured: the scene is not posed".into(),
            ));
        };
        let t0 = Instant::now();
        let out = f(&mut self.kinects[c], r, stamp)?;
        self.seconds += t0.elapsed().as_secs_f64();
        Ok(out)
    }

    /// The depth camera `c` would measure without noise from `carrier` (a [`Shot`]'s, of the
    /// frame just captured), timed with the rendering.
    pub fn true_depth(&mut self, c: usize, carrier: &Pose) -> Result<DepthImage, RenderError> {
        self.after_capture(c, |k, r, stamp| k.true_depth(r, carrier, stamp))
    }

    /// Whether camera `c` can give a frame's whole depth after capturing it on a grid (with
    /// colour or not, `rgb`; [`crate::kinect::Kinect::depth_on_demand`]).
    pub fn depth_on_demand(&self, c: usize, rgb: bool) -> bool {
        self.kinects[c].depth_on_demand(rgb)
    }

    /// The whole measured depth of the frame of camera `c` just captured on a grid, from
    /// `carrier` (its [`Shot`]'s), timed with the rendering; `None` where the frame holds it
    /// ([`crate::kinect::Kinect::full_depth`]).
    pub fn full_depth(
        &mut self,
        c: usize,
        carrier: &Pose,
    ) -> Result<Option<DepthImage>, RenderError> {
        self.after_capture(c, |k, _, stamp| k.full_depth(carrier, stamp))
    }

    /// Whether camera `c` can render a frame's colour after capturing it without
    /// ([`crate::kinect::Kinect::colour_on_demand`]).
    pub fn colour_on_demand(&self, c: usize) -> bool {
        self.kinects[c].colour_on_demand()
    }

    /// The colour image of the frame of camera `c` just captured without it, from `carrier`
    /// (its [`Shot`]'s), timed with the rendering ([`crate::kinect::Kinect::colour`]).
    pub fn colour(&mut self, c: usize, carrier: &Pose) -> Result<RgbImage, RenderError> {
        self.after_capture(c, |k, r, stamp| k.colour(r, carrier, stamp))
    }
}
