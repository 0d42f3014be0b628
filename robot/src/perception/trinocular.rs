//! Trinocular stereo (seed 001 §2.2, after Se, Lowe & Little): SIFT keypoints of three
//! rectified cameras in an L matched and triangulated into 3D points with covariances.
//!
//! The rig: the right camera is the reference (its pixels and descriptors go into the map);
//! the left camera sits `baseline` to its left and the top camera `baseline` above it, all
//! with the same intrinsics and orientation. A point at depth Z then appears in the left
//! image fx·b/Z px to the right of its right-image pixel on the same row, and in the top image
//! fy·b/Z px lower in the same column.
//!
//! Matches (§2.3): on the epipolar line (within `epipolar_px` × the octave's sampling), at
//! most one scale level apart, descriptors within 0.2 and passing the ratio test at 0.7 among
//! the candidates, one to one. Both pairs must match and their disparities agree. The point
//! (eq. 4) uses the mean of the two disparities, each in units of its focal length; its
//! covariance (eqs. 5–6) propagates σ = 0.5 d_s px on x_l, x_r, y_r and y_t, d_s being each
//! keypoint's octave sampling (the digest's reading of the seed's "0.5 × d").

use super::sift::{self, Keypoint};
use futago_msgs::camera::Intrinsics;
use glam::{DMat3, DVec3};
use serde::{Deserialize, Serialize};

/// Parameters of trinocular matching.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StereoConfig {
    /// Off the epipolar line by at most this × the larger octave sampling, px.
    pub epipolar_px: f64,
    /// Scale levels apart at most (the seed: 1).
    pub max_level_gap: f32,
    /// Largest descriptor distance (the seed: 0.2).
    pub max_distance: f64,
    /// Ratio test (eq. 3: 0.7).
    pub ratio: f64,
    /// Horizontal and vertical disparities (in px at the focal length) agree within this ×
    /// the larger octave sampling, px.
    pub agreement_px: f64,
    /// Least disparity, px (farther points are not triangulated).
    pub min_disparity_px: f64,
    /// Keypoint position noise: this × the octave sampling, px (the seed: 0.5).
    pub pixel_sigma: f64,
}

impl Default for StereoConfig {
    fn default() -> Self {
        StereoConfig {
            epipolar_px: 1.0,
            max_level_gap: 1.0,
            max_distance: 0.2,
            ratio: 0.7,
            agreement_px: 1.5,
            min_disparity_px: 2.0,
            pixel_sigma: 0.5,
        }
    }
}

impl StereoConfig {
    /// Checks every field; the error names the key below `prefix`.
    pub fn validate(&self, prefix: &str) -> Result<(), crate::config::ConfigError> {
        crate::config::check_ranges(
            prefix,
            &[
                ("epipolar_px", self.epipolar_px, 0.0, 100.0),
                ("max_level_gap", self.max_level_gap as f64, 0.0, 100.0),
                ("max_distance", self.max_distance, 0.0, 2.0),
                ("ratio", self.ratio, 0.0, 1.0),
                ("agreement_px", self.agreement_px, 0.0, 100.0),
                ("min_disparity_px", self.min_disparity_px, 0.01, 1000.0),
                ("pixel_sigma", self.pixel_sigma, 1e-3, 100.0),
            ],
        )
    }
}

/// The L-shaped rig.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rig {
    /// Intrinsics shared by the three cameras.
    pub intrinsics: Intrinsics,
    /// Right–left and right–top baseline, m (Digiclops: 0.0996).
    pub baseline: f64,
}

/// A triangulated point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StereoPoint {
    /// Index of its keypoint in the right (reference) image.
    pub keypoint: usize,
    /// Position in the right camera's optical frame (x right, y down, z forward), m.
    pub position: DVec3,
    /// Its covariance in that frame (eq. 6), m².
    pub covariance: DMat3,
    /// The mean disparity, px at fx.
    pub disparity: f64,
}

/// For each reference keypoint, its one-to-one match in `other` along the epipolar line:
/// `offset(r, o)` gives (disparity, distance off the line) in px.
fn match_pair(
    reference: &[Keypoint],
    other: &[Keypoint],
    config: &StereoConfig,
    offset: impl Fn(&Keypoint, &Keypoint) -> (f64, f64),
) -> Vec<Option<usize>> {
    let mut chosen = vec![None; reference.len()];
    let mut claims: Vec<u32> = vec![0; other.len()];
    for (i, r) in reference.iter().enumerate() {
        let (mut best, mut second) = ((f32::INFINITY, usize::MAX), f32::INFINITY);
        for (j, o) in other.iter().enumerate() {
            let (d, off) = offset(r, o);
            let ds = r.sampling().max(o.sampling()) as f64;
            if d < config.min_disparity_px
                || off.abs() > config.epipolar_px * ds
                || (r.level - o.level).abs() > config.max_level_gap
            {
                continue;
            }
            let dist = sift::distance(&r.descriptor, &o.descriptor);
            if dist as f64 > config.max_distance {
                continue;
            }
            if dist < best.0 {
                second = best.0;
                best = (dist, j);
            } else if dist < second {
                second = dist;
            }
        }
        if best.1 != usize::MAX && passes_ratio(best.0, second, config.ratio) {
            chosen[i] = Some(best.1);
            claims[best.1] += 1;
        }
    }
    // One to one: a keypoint of `other` claimed twice is no one's.
    for c in chosen.iter_mut() {
        if c.is_some_and(|j| claims[j] > 1) {
            *c = None;
        }
    }
    chosen
}

/// Lowe's ratio test: the nearest distance at most `ratio` of the second (and below it: two
/// equal descriptors are ambiguous), or no second candidate at all.
pub fn passes_ratio(best: f32, second: f32, ratio: f64) -> bool {
    !second.is_finite() || (best < second && best as f64 <= ratio * second as f64)
}

/// Matches the three images' keypoints and triangulates the points every pair agrees on.
pub fn triangulate(
    rig: &Rig,
    right: &[Keypoint],
    left: &[Keypoint],
    top: &[Keypoint],
    config: &StereoConfig,
) -> Vec<StereoPoint> {
    let k = &rig.intrinsics;
    let horizontal = match_pair(right, left, config, |r, o| {
        ((o.x - r.x) as f64, (o.y - r.y) as f64)
    });
    let vertical = match_pair(right, top, config, |r, o| {
        ((o.y - r.y) as f64, (o.x - r.x) as f64)
    });
    let mut out = Vec::new();
    for (i, r) in right.iter().enumerate() {
        let (Some(l), Some(t)) = (horizontal[i], vertical[i]) else {
            continue;
        };
        let (l, t) = (&left[l], &top[t]);
        let (dh, dv) = ((l.x - r.x) as f64, (t.y - r.y) as f64);
        let ds = r.sampling().max(l.sampling()).max(t.sampling()) as f64;
        // Compare at one focal length.
        if (dh - dv * k.fx / k.fy).abs() > config.agreement_px * ds {
            continue;
        }
        let sig = |kp: &Keypoint| config.pixel_sigma * kp.sampling() as f64;
        let (position, covariance) = point(
            rig,
            [l.x as f64, r.x as f64, r.y as f64, t.y as f64],
            [sig(l), sig(r), sig(r), sig(t)],
        );
        out.push(StereoPoint {
            keypoint: i,
            position,
            covariance,
            disparity: 0.5 * (dh + dv * k.fx / k.fy),
        });
    }
    out
}

/// Eq. 4 and its covariance (eqs. 5–6) for I = [x_l, x_r, y_r, y_t] with independent σ.
pub fn point(rig: &Rig, i: [f64; 4], sigma: [f64; 4]) -> (DVec3, DMat3) {
    let k = &rig.intrinsics;
    let b = rig.baseline;
    let [xl, xr, yr, yt] = i;
    let u = (xr - k.cx) / k.fx;
    let v = (yr - k.cy) / k.fy;
    // Inverse depth ×b: the mean of the two disparities, each over its focal length.
    let rho = 0.5 * ((xl - xr) / k.fx + (yt - yr) / k.fy);
    let z = b / rho;
    let p = DVec3::new(u * z, v * z, z);
    // ∂Z/∂I = −b/ρ² ∂ρ/∂I.
    let drho = [0.5 / k.fx, -0.5 / k.fx, -0.5 / k.fy, 0.5 / k.fy];
    let dz: [f64; 4] = drho.map(|d| -b / (rho * rho) * d);
    let dx = [u * dz[0], u * dz[1] + z / k.fx, u * dz[2], u * dz[3]];
    let dy = [v * dz[0], v * dz[1], v * dz[2] + z / k.fy, v * dz[3]];
    let j = [dx, dy, dz];
    let mut c = [[0.0; 3]; 3];
    for (a, ja) in j.iter().enumerate() {
        for (bb, jb) in j.iter().enumerate() {
            c[a][bb] = (0..4).map(|n| ja[n] * jb[n] * sigma[n] * sigma[n]).sum();
        }
    }
    (
        p,
        DMat3::from_cols(
            DVec3::from_array(c[0]),
            DVec3::from_array(c[1]),
            DVec3::from_array(c[2]),
        ),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rig() -> Rig {
        Rig {
            intrinsics: Intrinsics::from_fov(320, 240, 60f64.to_radians(), 46.8f64.to_radians())
                .unwrap(),
            baseline: 0.0996,
        }
    }

    fn kp(x: f32, y: f32, desc: u8) -> Keypoint {
        let mut descriptor = [0u8; 128];
        descriptor[desc as usize] = 255;
        descriptor[(desc as usize + 64) % 128] = 255;
        Keypoint {
            x,
            y,
            sigma: 1.6,
            octave: 0,
            level: 1.0,
            angle: 0.0,
            contrast: 0.05,
            descriptor,
        }
    }

    /// Eq. 4 by hand, and eq. 6's depth variance against first-order theory:
    /// σ_Z = Z² / (f b) · σ_d, with σ_d = ½ √(4 · 0.25) px = 0.5 px for the mean disparity.
    #[test]
    fn a_point_and_its_covariance_by_hand() {
        let r = rig();
        let k = r.intrinsics;
        let truth = DVec3::new(0.4, -0.3, 2.5);
        let (xr, yr) = (
            k.fx * truth.x / truth.z + k.cx,
            k.fy * truth.y / truth.z + k.cy,
        );
        let xl = xr + k.fx * r.baseline / truth.z;
        let yt = yr + k.fy * r.baseline / truth.z;
        let (p, c) = point(&r, [xl, xr, yr, yt], [0.5; 4]);
        assert!((p - truth).length() < 1e-9, "{p}");
        let want = truth.z * truth.z / (k.fx * r.baseline) * 0.5;
        assert!(
            (c.z_axis.z.sqrt() / want - 1.0).abs() < 0.02,
            "{} vs {want}",
            c.z_axis.z.sqrt()
        );
        // Lateral spread grows with depth and is correlated with depth by the ray's slope.
        assert!(c.z_axis.x * truth.x > 0.0 && c.z_axis.y * truth.y > 0.0);
    }

    /// Three views of a few points: true matches are triangulated at their depths; a
    /// repeated descriptor (two keypoints alike on one row) is refused by the ratio test.
    #[test]
    fn matches_follow_the_epipolar_lines_and_refuse_ambiguity() {
        let r = rig();
        let k = r.intrinsics;
        let pts = [
            DVec3::new(0.2, 0.1, 2.0),
            DVec3::new(-0.5, -0.2, 3.0),
            DVec3::new(0.8, 0.4, 4.0),
        ];
        let (mut right, mut left, mut top) = (vec![], vec![], vec![]);
        for (i, p) in pts.iter().enumerate() {
            let (xr, yr) = (k.fx * p.x / p.z + k.cx, k.fy * p.y / p.z + k.cy);
            let d = k.fx * r.baseline / p.z;
            right.push(kp(xr as f32, yr as f32, i as u8));
            left.push(kp((xr + d) as f32, yr as f32, i as u8));
            top.push(kp(
                xr as f32,
                (yr + k.fy * r.baseline / p.z) as f32,
                i as u8,
            ));
        }
        // A look-alike of point 0 on its row in the left image.
        left.push(kp(right[0].x + 3.0, right[0].y, 0));
        let out = triangulate(&r, &right, &left, &top, &StereoConfig::default());
        let found: Vec<usize> = out.iter().map(|s| s.keypoint).collect();
        assert_eq!(found, vec![1, 2], "point 0 is ambiguous in the left image");
        for s in &out {
            assert!((s.position - pts[s.keypoint]).length() < 1e-4);
        }
        // Off the epipolar line by 3 px: no match.
        let mut off = top.clone();
        off[1].x += 3.0;
        let out = triangulate(&r, &right, &left, &off, &StereoConfig::default());
        assert!(out.iter().all(|s| s.keypoint != 1));
    }
}
