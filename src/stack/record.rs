//! Recorders: nodes that write the run's sensor data and ground truth in the field's formats
//! (TUM trajectories, the CARMEN log, TUM RGB-D sequences). The odometry recorder's
//! trajectory is scored like the stack's estimates.

use super::tum_line;
use super::{Bus, CameraFrame, FrameTruth, Node, Report, Streams, Trajectory, TrueState, Truth};
use crate::ground_truth::Metrics;
use crate::rgbd::TumRgbdWriter;
use crate::scenario::{Scenario, ScenarioSpec};
use anyhow::{Context, Result};
use futago_msgs::{LaserScan, Odometry, Pose2, carmen};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

/// The true pose of the robot's base frame (TUM), at the ground-truth rate.
pub const GROUNDTRUTH_FILE: &str = "groundtruth.txt";
/// Wheel odometry integrated from the start pose (TUM), at every report.
pub const ODOMETRY_FILE: &str = "odometry.txt";
/// The CARMEN log of odometry, scans and true poses.
pub const CARMEN_FILE: &str = "scans.clf";
/// The folder of the agents' true trajectories (TUM), one `NAME.txt` each, at the
/// ground-truth rate.
pub const AGENTS_DIR: &str = "agents";

fn create(dir: &Path, name: &str) -> Result<BufWriter<File>> {
    Ok(BufWriter::new(
        File::create(dir.join(name)).with_context(|| format!("creating {name}"))?,
    ))
}

/// The recorders a run writes with, in their order; without a folder, the odometry's alone,
/// kept in memory for its scorer.
pub fn recorders(s: &Scenario, dir: Option<&Path>) -> Result<Vec<Box<dyn Node>>> {
    let odometry = TumRecorder {
        source: Source::Odometry,
        file: dir.map(|d| create(d, ODOMETRY_FILE)).transpose()?,
        name: s.spec.name.clone(),
        line: String::new(),
        track: Trajectory::new("odometry"),
    };
    let Some(dir) = dir else {
        return Ok(vec![Box::new(odometry)]);
    };
    let mut out: Vec<Box<dyn Node>> = vec![
        Box::new(TumRecorder {
            source: Source::Truth,
            file: Some(create(dir, GROUNDTRUTH_FILE)?),
            name: s.spec.name.clone(),
            line: String::new(),
            track: Trajectory::new("ground truth"),
        }),
        Box::new(odometry),
    ];
    if !s.movers.agents.is_empty() {
        std::fs::create_dir_all(dir.join(AGENTS_DIR))
            .with_context(|| format!("creating {AGENTS_DIR}/"))?;
        let files = s
            .movers
            .agents
            .iter()
            .map(|a| create(dir, &format!("{AGENTS_DIR}/{}.txt", a.name)))
            .collect::<Result<Vec<_>>>()?;
        out.push(Box::new(AgentRecorder {
            names: s.movers.agents.iter().map(|a| a.name.clone()).collect(),
            files,
            scenario: s.spec.name.clone(),
            line: String::new(),
        }));
    }
    if s.spec.output.carmen {
        out.push(Box::new(CarmenRecorder {
            file: create(dir, CARMEN_FILE)?,
            wheel_base: s.spec.robot.wheel_base,
            lasers: s
                .lidars
                .iter()
                .map(|(c, spec)| (c.name.clone(), c.clone(), spec.sigma))
                .collect(),
            line: String::new(),
        }));
    }
    if s.spec.output.rgbd_dataset {
        let writers = s
            .cameras
            .iter()
            .map(|c| {
                Ok((
                    c.name.clone(),
                    TumRgbdWriter::create(
                        &dir.join(&c.name),
                        &c.name,
                        &s.spec.name,
                        &c.rgb,
                        &c.depth,
                        (c.range_min, c.range_max),
                    )?,
                ))
            })
            .collect::<Result<Vec<_>>>()?;
        out.push(Box::new(RgbdDatasetRecorder {
            writers: writers.into_iter().map(|(n, w)| (n, Some(w))).collect(),
        }));
    }
    Ok(out)
}

/// The metrics of the recorded odometry trajectory. A robot whose controller is `idle` never
/// travels the metre the relative pose error is taken over, so it has none.
pub fn metric_names(s: &ScenarioSpec) -> Vec<String> {
    let names = crate::ground_truth::trajectory_metric_names("odometry");
    if super::driver::controller_type(s) == Some("idle") {
        names
            .into_iter()
            .filter(|n| !n.starts_with("odometry.rpe_1m."))
            .collect()
    } else {
        names
    }
}

/// What a TUM recorder writes: the true pose at the ground-truth rate, or the odometry
/// pose at every report.
#[derive(Clone, Copy, PartialEq)]
enum Source {
    Truth,
    Odometry,
}

/// `groundtruth.txt` or `odometry.txt` (the latter scored as the `odometry` trajectory).
struct TumRecorder {
    source: Source,
    /// Its file, when the run writes files.
    file: Option<BufWriter<File>>,
    name: String,
    line: String,
    /// The odometry's trajectory in memory (the truth's is the run's).
    track: Trajectory,
}

impl TumRecorder {
    fn file_name(&self) -> &'static str {
        match self.source {
            Source::Truth => GROUNDTRUTH_FILE,
            Source::Odometry => ODOMETRY_FILE,
        }
    }

    /// Writes `pose` at the bus's time.
    fn write(&mut self, bus: &Bus, pose: Pose2) -> Result<()> {
        if self.source == Source::Odometry {
            self.track.push(bus.now, &pose);
        }
        if let Some(f) = &mut self.file {
            self.line.clear();
            tum_line(&mut self.line, bus.now, &pose);
            f.write_all(self.line.as_bytes())?;
        }
        Ok(())
    }
}

impl Node for TumRecorder {
    fn name(&self) -> &'static str {
        match self.source {
            Source::Truth => "record.groundtruth",
            Source::Odometry => "record.odometry",
        }
    }

    fn streams(&self) -> Streams {
        Streams {
            consumes: vec![match self.source {
                Source::Truth => "truth".into(),
                Source::Odometry => "odometry".into(),
            }],
            ..Streams::default()
        }
    }

    fn start(&mut self, bus: &mut Bus) -> Result<()> {
        let header = match self.source {
            Source::Truth => "ground truth of {}: robot base frame in the world frame",
            Source::Odometry => "wheel odometry of {}, integrated from the start pose",
        }
        .replace("{}", &self.name);
        if let Some(f) = &mut self.file {
            writeln!(f, "# futago {header}\n# timestamp tx ty tz qx qy qz qw")?;
        }
        // Odometry starts at the start pose; the truth's first line comes with its tick.
        if self.source == Source::Odometry {
            self.write(bus, bus.odometry)?;
        }
        Ok(())
    }

    fn on_truth(&mut self, truth: &TrueState, bus: &mut Bus) -> Result<()> {
        self.write(bus, truth.robot)
    }

    fn on_odometry(&mut self, _o: &Odometry, bus: &mut Bus) -> Result<()> {
        self.write(bus, bus.odometry)
    }

    fn finish(&mut self, _bus: &mut Bus, _out: Option<&Path>) -> Result<Report> {
        let file = self.file_name();
        let mut files = Vec::new();
        if let Some(f) = &mut self.file {
            f.flush().with_context(|| format!("writing {file}"))?;
            files.push(file.to_string());
        }
        Ok(Report {
            files,
            trajectories: (self.source == Source::Odometry)
                .then(|| self.track.clone())
                .into_iter()
                .collect(),
            ..Report::default()
        })
    }

    fn score(&self, truth: &Truth) -> Result<Metrics> {
        match self.source {
            Source::Odometry => Ok(crate::ground_truth::score_trajectory(
                truth,
                "odometry",
                &self.track.poses,
            )),
            Source::Truth => Ok(Metrics::default()),
        }
    }
}

/// `agents/NAME.txt`: each agent's true pose, with the robot's ground truth.
struct AgentRecorder {
    names: Vec<String>,
    /// One file per agent, in the bus's agent order.
    files: Vec<BufWriter<File>>,
    scenario: String,
    line: String,
}

impl Node for AgentRecorder {
    fn name(&self) -> &'static str {
        "record.agents"
    }

    fn streams(&self) -> Streams {
        Streams {
            consumes: vec!["truth".into()],
            ..Streams::default()
        }
    }

    fn start(&mut self, _bus: &mut Bus) -> Result<()> {
        for (f, name) in self.files.iter_mut().zip(&self.names) {
            writeln!(
                f,
                "# futago ground truth of agent `{name}` in {}: its body frame in the world \
                 frame\n# timestamp tx ty tz qx qy qz qw",
                self.scenario
            )?;
        }
        Ok(())
    }

    fn on_truth(&mut self, truth: &TrueState, bus: &mut Bus) -> Result<()> {
        for (f, (_, pose)) in self.files.iter_mut().zip(&truth.agents) {
            self.line.clear();
            tum_line(&mut self.line, bus.now, pose);
            f.write_all(self.line.as_bytes())?;
        }
        Ok(())
    }

    fn finish(&mut self, _bus: &mut Bus, _out: Option<&Path>) -> Result<Report> {
        for f in &mut self.files {
            f.flush()
                .with_context(|| format!("writing {AGENTS_DIR}/"))?;
        }
        Ok(Report {
            files: vec![format!("{AGENTS_DIR}/")],
            ..Report::default()
        })
    }
}

/// `scans.clf`: `PARAM`s, then `TRUEPOS`, `ODOM` and `ROBOTLASER1/2` as they come.
struct CarmenRecorder {
    file: BufWriter<File>,
    wheel_base: f64,
    /// Each laser's name, config and range noise, in the scenario's order (the log's
    /// channels 1 and 2).
    lasers: Vec<(String, futago_sim::lidar::LidarConfig, f64)>,
    line: String,
}

impl CarmenRecorder {
    fn velocities(&self, bus: &Bus) -> (f64, f64) {
        let (l, r) = bus.wheel_speeds;
        ((l + r) / 2.0, (r - l) / self.wheel_base)
    }
}

impl Node for CarmenRecorder {
    fn name(&self) -> &'static str {
        "record.carmen"
    }

    fn streams(&self) -> Streams {
        let mut consumes = vec!["truth".to_string(), "odometry".to_string()];
        consumes.extend(self.lasers.iter().map(|l| format!("scan/{}", l.0)));
        Streams {
            consumes,
            ..Streams::default()
        }
    }

    fn start(&mut self, _bus: &mut Bus) -> Result<()> {
        let line = &mut self.line;
        line.clear();
        carmen::param(line, "robot_name", "create");
        carmen::param(line, "robot_wheel_base", &format!("{}", self.wheel_base));
        for (i, (_, cfg, _)) in self.lasers.iter().enumerate() {
            let prefix = if i == 0 {
                "robot_frontlaser"
            } else {
                "robot_rearlaser"
            };
            carmen::param(
                line,
                &format!("{prefix}_offset"),
                &format!("{}", cfg.xyz[0]),
            );
            carmen::param(
                line,
                &format!("{prefix}_side_offset"),
                &format!("{}", cfg.xyz[1]),
            );
            carmen::param(
                line,
                &format!("{prefix}_angular_offset"),
                &format!("{}", cfg.rpy_deg[2].to_radians()),
            );
        }
        self.file.write_all(self.line.as_bytes())?;
        Ok(())
    }

    fn on_truth(&mut self, truth: &TrueState, bus: &mut Bus) -> Result<()> {
        self.line.clear();
        carmen::truepos(&mut self.line, bus.now.secs(), &truth.robot, &bus.odometry);
        self.file.write_all(self.line.as_bytes())?;
        Ok(())
    }

    fn on_odometry(&mut self, _o: &Odometry, bus: &mut Bus) -> Result<()> {
        let (tv, rv) = self.velocities(bus);
        self.line.clear();
        carmen::odom(&mut self.line, bus.now.secs(), &bus.odometry, tv, rv);
        self.file.write_all(self.line.as_bytes())?;
        Ok(())
    }

    fn on_scan(&mut self, laser: &str, scan: &LaserScan, bus: &mut Bus) -> Result<()> {
        let Some(i) = self.lasers.iter().position(|l| l.0 == laser) else {
            return Ok(());
        };
        let robot = bus.odometry_at(scan.stamp);
        let (tv, rv) = self.velocities(bus);
        let (_, cfg, sigma) = &self.lasers[i];
        let at = robot.compose(&cfg.planar_mount());
        self.line.clear();
        carmen::robotlaser(
            &mut self.line,
            i as u8 + 1,
            scan,
            *sigma,
            &at,
            &robot,
            tv,
            rv,
        );
        self.file.write_all(self.line.as_bytes())?;
        Ok(())
    }

    fn finish(&mut self, _bus: &mut Bus, _out: Option<&Path>) -> Result<Report> {
        self.file
            .flush()
            .with_context(|| format!("writing {CARMEN_FILE}"))?;
        Ok(Report {
            files: vec![CARMEN_FILE.into()],
            ..Report::default()
        })
    }
}

/// Each camera's stream as a TUM RGB-D sequence in a folder named after the camera.
struct RgbdDatasetRecorder {
    writers: Vec<(String, Option<TumRgbdWriter>)>,
}

impl Node for RgbdDatasetRecorder {
    fn name(&self) -> &'static str {
        "record.rgbd_dataset"
    }

    /// It writes each frame with its true optical pose, whatever carries the camera.
    fn takes_carried_cameras(&self) -> bool {
        true
    }

    fn streams(&self) -> Streams {
        Streams {
            consumes: self
                .writers
                .iter()
                .map(|(n, _)| format!("camera/{n}"))
                .collect(),
            ..Streams::default()
        }
    }

    fn wants_frame(&self, camera: &str, _bus: &Bus) -> bool {
        self.writers.iter().any(|(n, _)| n == camera)
    }

    fn on_frame(
        &mut self,
        camera: &str,
        frame: &CameraFrame,
        truth: &mut dyn FrameTruth,
        _bus: &mut Bus,
    ) -> Result<()> {
        if let Some((_, Some(w))) = self.writers.iter_mut().find(|(n, _)| n == camera) {
            w.write(&frame.frame, &truth.optical())?;
        }
        Ok(())
    }

    fn finish(&mut self, _bus: &mut Bus, _out: Option<&Path>) -> Result<Report> {
        let mut files = Vec::new();
        for (name, w) in &mut self.writers {
            if let Some(w) = w.take() {
                w.finish()?;
            }
            files.push(format!("{name}/"));
        }
        Ok(Report {
            files,
            ..Report::default()
        })
    }
}

/// The recorders of a run's files (ground truth, odometry, the sensors' logs) and the odometry's scores.
pub const MODULE: super::Plain = super::Plain {
    metric_names,
    build: |s, _, out| recorders(s, out),
};
