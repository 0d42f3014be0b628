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
    /// This camera's intrinsics for its image binned `n × n` ([`RgbImage::binned`]): whole
    /// blocks only, focal lengths over `n`, and the principal point where it falls in the
    /// blocks' pixel grid (a block's centre is its pixels' mean).
    pub fn binned(&self, n: u32) -> Intrinsics {
        let n = n.max(1);
        let f = n as f64;
        Intrinsics {
            width: self.width / n,
            height: self.height / n,
            fx: self.fx / f,
            fy: self.fy / f,
            cx: (self.cx + 0.5) / f - 0.5,
            cy: (self.cy + 0.5) / f - 0.5,
        }
    }

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

    /// The image binned `n × n` (whole blocks only): each block's nearest reading, 0 where
    /// it has none. The nearest, not the mean, so that a block across an edge holds a depth
    /// some surface has, and an obstacle is not thinned away.
    pub fn binned(&self, n: u32) -> DepthImage {
        let n = n.max(1);
        let (w, h) = (self.width / n, self.height / n);
        let mut data = Vec::with_capacity((w * h) as usize);
        for bv in 0..h {
            for bu in 0..w {
                let mut near = f32::INFINITY;
                for v in bv * n..(bv + 1) * n {
                    for u in bu * n..(bu + 1) * n {
                        let d = self.at(u, v);
                        if d > 0.0 && d < near {
                            near = d;
                        }
                    }
                }
                data.push(if near.is_finite() { near } else { 0.0 });
            }
        }
        DepthImage {
            width: w,
            height: h,
            data,
        }
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

    /// The image binned `n × n` (whole blocks only): each block's mean colour, rounded, as a
    /// camera's binning gives it.
    pub fn binned(&self, n: u32) -> RgbImage {
        let n = n.max(1);
        let (w, h) = (self.width / n, self.height / n);
        let count = n * n;
        let mut data = Vec::with_capacity((3 * w * h) as usize);
        for bv in 0..h {
            for bu in 0..w {
                let mut sum = [0u32; 3];
                for v in bv * n..(bv + 1) * n {
                    for u in bu * n..(bu + 1) * n {
                        for (s, c) in sum.iter_mut().zip(self.at(u, v)) {
                            *s += u32::from(c);
                        }
                    }
                }
                data.extend(sum.map(|s| ((s + count / 2) / count) as u8));
            }
        }
        RgbImage {
            width: w,
            height: h,
            data,
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn binning_averages_colours_keeps_the_nearest_depth_and_moves_the_principal_point() {
        // 5 × 2 pixels binned 2 × 2: two whole blocks, the last column dropped.
        let rgb = RgbImage {
            width: 5,
            height: 2,
            data: [
                [0, 10, 255],
                [2, 10, 255],
                [9, 0, 0],
                [9, 0, 0],
                [7, 7, 7],
                [4, 10, 255],
                [5, 11, 0],
                [9, 0, 0],
                [9, 0, 1],
                [7, 7, 7],
            ]
            .concat(),
        };
        let b = rgb.binned(2);
        assert_eq!((b.width, b.height), (2, 1));
        // (0+2+4+5)/4 = 2.75 → 3; (10+10+10+11)/4 = 10.25 → 10; (255·3)/4 = 191.25 → 191.
        assert_eq!(b.data, vec![3, 10, 191, 9, 0, 0]);
        let depth = DepthImage {
            width: 5,
            height: 2,
            data: vec![2.0, 0.0, 0.0, 0.0, 1.0, 1.5, 3.0, 0.0, 0.0, 1.0],
        };
        let d = depth.binned(2);
        assert_eq!(d.data, vec![1.5, 0.0]);
        // A pinhole binned 2: the principal point of a 640-wide image at 319.5 stays central.
        let k = Intrinsics {
            width: 640,
            height: 480,
            fx: 525.0,
            fy: 525.0,
            cx: 319.5,
            cy: 239.5,
        };
        let kb = k.binned(2);
        assert_eq!(
            (kb.width, kb.height, kb.fx, kb.cx, kb.cy),
            (320, 240, 262.5, 159.5, 119.5)
        );
        assert_eq!(k.binned(1), k);
    }
}
