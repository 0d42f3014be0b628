//! RGB-D streams written as TUM RGB-D benchmark sequences.
//!
//! Layout of one sequence folder (Sturm et al., IROS 2012, and the benchmark's file formats):
//! - `rgb/<t>.png`: 8-bit RGB; `depth/<t>.png`: 16-bit depth, 5000 units per metre, 0 invalid;
//! - `rgb.txt`, `depth.txt`: `timestamp filename` per frame, three `#` header lines;
//! - `groundtruth.txt`: the optical centre of the camera (x right, y down, z forward) in the
//!   world, `timestamp tx ty tz qx qy qz qw`, one line per frame;
//! - `camera.yaml`: intrinsics of both images and the depth factor (not part of the benchmark,
//!   which lists intrinsics on its web pages; tools that run on it take them as parameters).

use anyhow::{Context, Result};
use futago_msgs::Pose3;
use futago_msgs::camera::{Intrinsics, RgbdFrame};
use futago_msgs::tum;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// Depth PNG units per metre (the TUM benchmark's factor).
pub const DEPTH_FACTOR: f64 = 5000.0;

/// Writes one camera's frames into a sequence folder.
pub struct TumRgbdWriter {
    dir: PathBuf,
    rgb: BufWriter<File>,
    depth: BufWriter<File>,
    groundtruth: BufWriter<File>,
    frames: u64,
    line: String,
}

fn header(w: &mut BufWriter<File>, what: &str, name: &str, sequence: &str) -> Result<()> {
    writeln!(
        w,
        "# {what} of {sequence} (futago camera `{name}`)\n# file: '{sequence}'\n# timestamp filename"
    )?;
    Ok(())
}

/// Converts metres to the PNG's 16-bit units (0 stays invalid; beyond 13.1 m saturates).
pub fn depth_units(z: f32) -> u16 {
    if z > 0.0 {
        (z as f64 * DEPTH_FACTOR)
            .round()
            .clamp(1.0, u16::MAX as f64) as u16
    } else {
        0
    }
}

impl TumRgbdWriter {
    /// Creates `dir` with its `rgb/` and `depth/` folders, list headers and `camera.yaml`.
    pub fn create(
        dir: &Path,
        camera: &str,
        sequence: &str,
        rgb: &Intrinsics,
        depth: &Intrinsics,
        range: (f64, f64),
    ) -> Result<TumRgbdWriter> {
        for d in [dir.to_path_buf(), dir.join("rgb"), dir.join("depth")] {
            std::fs::create_dir_all(&d).with_context(|| format!("creating {}", d.display()))?;
        }
        let open = |n: &str| -> Result<BufWriter<File>> {
            let p = dir.join(n);
            Ok(BufWriter::new(
                File::create(&p).with_context(|| format!("creating {}", p.display()))?,
            ))
        };
        let mut w = TumRgbdWriter {
            dir: dir.to_path_buf(),
            rgb: open("rgb.txt")?,
            depth: open("depth.txt")?,
            groundtruth: open("groundtruth.txt")?,
            frames: 0,
            line: String::new(),
        };
        header(&mut w.rgb, "color images", camera, sequence)?;
        header(&mut w.depth, "depth maps", camera, sequence)?;
        writeln!(
            w.groundtruth,
            "# ground truth of {sequence}: optical centre of camera `{camera}` (x right, y down, z forward) in the world\n# file: '{sequence}'\n# timestamp tx ty tz qx qy qz qw"
        )?;
        let intr = |i: &Intrinsics| {
            format!(
                "  width: {}\n  height: {}\n  fx: {}\n  fy: {}\n  cx: {}\n  cy: {}\n",
                i.width, i.height, i.fx, i.fy, i.cx, i.cy
            )
        };
        let yaml = format!(
            "# futago camera `{camera}`: pinhole, no distortion; depth is registered to rgb (same optical centre)\nrgb:\n{}depth:\n{}depth_factor: {DEPTH_FACTOR}\nrange_min: {}\nrange_max: {}\n",
            intr(rgb),
            intr(depth),
            range.0,
            range.1
        );
        std::fs::write(dir.join("camera.yaml"), yaml).context("writing camera.yaml")?;
        Ok(w)
    }

    /// Writes one frame and the optical frame's pose at its time.
    pub fn write(&mut self, frame: &RgbdFrame, optical: &Pose3) -> Result<()> {
        let stamp = format!("{:.6}", frame.stamp.secs());
        if let Some(rgb) = &frame.rgb {
            let name = format!("rgb/{stamp}.png");
            image::save_buffer_with_format(
                self.dir.join(&name),
                &rgb.data,
                rgb.width,
                rgb.height,
                image::ExtendedColorType::Rgb8,
                image::ImageFormat::Png,
            )
            .with_context(|| format!("writing {name}"))?;
            writeln!(self.rgb, "{stamp} {name}")?;
        }
        let name = format!("depth/{stamp}.png");
        let d = &frame.depth;
        let units: Vec<u16> = d.data.iter().map(|&z| depth_units(z)).collect();
        image::ImageBuffer::<image::Luma<u16>, _>::from_raw(d.width, d.height, units)
            .context("depth image size")?
            .save_with_format(self.dir.join(&name), image::ImageFormat::Png)
            .with_context(|| format!("writing {name}"))?;
        writeln!(self.depth, "{stamp} {name}")?;
        self.line.clear();
        tum::format_line(
            &mut self.line,
            &tum::Stamped {
                stamp: frame.stamp,
                pose: *optical,
            },
        );
        self.groundtruth.write_all(self.line.as_bytes())?;
        self.frames += 1;
        Ok(())
    }

    /// Flushes the lists; returns the number of frames.
    pub fn finish(mut self) -> Result<u64> {
        self.rgb.flush()?;
        self.depth.flush()?;
        self.groundtruth.flush()?;
        Ok(self.frames)
    }
}
