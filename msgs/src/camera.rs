//! Camera messages: pinhole intrinsics, depth and colour images, registered RGB-D frames.
//!
//! Pixel coordinates follow OpenCV and the TUM RGB-D benchmark: `u` right, `v` down, pixel
//! (0, 0)'s centre at (0, 0). Points are in the camera's optical frame (x right, y down,
//! z forward); depth is z, the distance along the optical axis, in metres.

use crate::Time;

/// Pinhole intrinsics of an image, in pixels; pixel (0, 0)'s centre is at (0, 0) (OpenCV and
/// TUM convention: `cx = (width - 1) / 2` for a centred axis).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intrinsics {
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

/// Largest image side the renderer accepts.
pub const MAX_IMAGE_SIDE: u32 = 8192;

impl Intrinsics {
    /// A centred camera with the given horizontal and vertical fields of view, radians.
    pub fn from_fov(width: u32, height: u32, fov_h: f64, fov_v: f64) -> Result<Self, String> {
        check_size(width, height)?;
        for (name, f) in [("horizontal", fov_h), ("vertical", fov_v)] {
            if !(f > 1f64.to_radians() && f < 170f64.to_radians()) {
                return Err(format!(
                    "{name} field of view {:.3}° is out of range: expected 1° to 170°",
                    f.to_degrees()
                ));
            }
        }
        Ok(Intrinsics {
            width,
            height,
            fx: width as f64 / 2.0 / (fov_h / 2.0).tan(),
            fy: height as f64 / 2.0 / (fov_v / 2.0).tan(),
            cx: (width as f64 - 1.0) / 2.0,
            cy: (height as f64 - 1.0) / 2.0,
        })
    }

    /// The same camera at another resolution (same field of view).
    pub fn scaled(&self, width: u32, height: u32) -> Intrinsics {
        let sx = width as f64 / self.width as f64;
        let sy = height as f64 / self.height as f64;
        Intrinsics {
            width,
            height,
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: (self.cx + 0.5) * sx - 0.5,
            cy: (self.cy + 0.5) * sy - 0.5,
        }
    }

    /// Checks size and focal lengths.
    pub fn validate(&self) -> Result<(), String> {
        check_size(self.width, self.height)?;
        if !(self.fx.is_finite() && self.fy.is_finite() && self.fx > 0.0 && self.fy > 0.0) {
            return Err(format!(
                "focal lengths fx {} and fy {} must be positive pixels",
                self.fx, self.fy
            ));
        }
        if !(self.cx.is_finite() && self.cy.is_finite()) {
            return Err("principal point must be finite".into());
        }
        Ok(())
    }

    /// Direction through pixel coordinates `(u, v)` in the optical frame, with z = 1.
    pub fn ray(&self, u: f64, v: f64) -> [f64; 3] {
        [(u - self.cx) / self.fx, (v - self.cy) / self.fy, 1.0]
    }

    /// Back-projects pixel `(u, v)` at depth `z` into the optical frame.
    pub fn back_project(&self, u: f64, v: f64, z: f64) -> [f64; 3] {
        [(u - self.cx) / self.fx * z, (v - self.cy) / self.fy * z, z]
    }
}

fn check_size(width: u32, height: u32) -> Result<(), String> {
    if width == 0 || height == 0 || width > MAX_IMAGE_SIDE || height > MAX_IMAGE_SIDE {
        return Err(format!(
            "image size {width}×{height} is out of range: expected 1 to {MAX_IMAGE_SIDE} pixels a side"
        ));
    }
    Ok(())
}

/// A depth image: optical-axis distance in metres, row-major from the top-left; 0 is invalid.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthImage {
    pub width: u32,
    pub height: u32,
    pub data: Vec<f32>,
}

impl DepthImage {
    pub fn at(&self, u: u32, v: u32) -> f32 {
        self.data[(v * self.width + u) as usize]
    }
}

/// An 8-bit sRGB image, row-major RGB from the top-left.
#[derive(Debug, Clone, PartialEq)]
pub struct RgbImage {
    pub width: u32,
    pub height: u32,
    pub data: Vec<u8>,
}

impl RgbImage {
    pub fn at(&self, u: u32, v: u32) -> [u8; 3] {
        let i = 3 * (v * self.width + u) as usize;
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }
}

/// One registered RGB-D frame: depth and colour from the same optical centre at one time.
#[derive(Debug, Clone, PartialEq)]
pub struct RgbdFrame {
    pub stamp: Time,
    /// Colour image, if the consumer asked for one.
    pub rgb: Option<RgbImage>,
    pub rgb_intrinsics: Intrinsics,
    pub depth: DepthImage,
    pub depth_intrinsics: Intrinsics,
}

impl RgbdFrame {
    /// A frame without colour: row-major depths `data` (m) of a `k.width × k.height` image.
    pub fn depth_only(stamp: Time, k: Intrinsics, data: Vec<f32>) -> RgbdFrame {
        RgbdFrame {
            stamp,
            rgb: None,
            rgb_intrinsics: k,
            depth: DepthImage {
                width: k.width,
                height: k.height,
                data,
            },
            depth_intrinsics: k,
        }
    }
}
