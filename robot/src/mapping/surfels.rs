//! A 3D map's surfaces as planar patches, and point-to-plane registration of a new sweep
//! against them (written for futago; seed 004 places each sweep by its 2D localisation alone,
//! which drifted 0.1–0.4 m between views of the hall among walkers).
//!
//! The map gathers its points in cells of side `cell`, keeping for each only the moments of
//! its points (count, sum, sum of products), so that adding a sweep costs as much as its
//! points and the map's memory grows with the surfaces, not with the scans. A cell with
//! `min_points` points whose scatter is flat (its smallest eigenvalue at most `planarity`
//! times its middle one) is a surfel: a plane through the points' centroid, normal along the
//! smallest eigenvector.
//!
//! A sweep is registered over (x, y, yaw): the robot stands on a level floor, so height, roll
//! and pitch are the mount's. The sweep's own points are gathered into surfels the same way
//! (in the robot's frame), and each sweep surfel's centroid is paired with the nearest map
//! surfel whose normal agrees with its own within `max_angle` (a `kiddo` k-d tree over the
//! centroids), when it lies off that surfel's plane by less than a correspondence distance
//! that shrinks from `max_distance[0]` to `max_distance[1]` over the iterations, and within a
//! cell more than that of its centroid (two cells on one surface have centroids up to a cell
//! apart along it). The point-to-plane distances, weighted by Tukey's biweight at the
//! correspondence distance, are minimised by Levenberg–Marquardt steps with the pairs fixed
//! ([`crate::mapping::registration`]'s, which leave out a direction the surfaces do not
//! constrain, such as a corridor's length). Pairing surfels, each a patch of its surface
//! however many points measured it, keeps the nearest surfaces from outweighing the rest; the
//! normals' agreement keeps a floor point near a wall from pairing with the wall, and one face
//! of a pillar from pairing with the next. Surfels that face up or down (the floor, a table's
//! top) say nothing of x, y or yaw and are left out.

use crate::config::ConfigError;
use crate::mapping::registration::{Index, Pair, Term, minimise};
use futago_msgs::{Pose2, wrap_angle};
use rustc_hash::{FxHashMap, FxHashSet};
use serde::{Deserialize, Serialize};

/// Parameters of the sweep registration (`scan3d.registration.*`).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct SurfelConfig {
    /// Register each sweep against the map before it enters it (off: the sweep stays where
    /// the pose it was placed by put it, as the seed did).
    pub enabled: bool,
    /// Side of the cells the map's points are gathered in, m: large enough to hold a patch of
    /// wall many times wider than the LMS200's 1.5 cm noise, small enough that few cells
    /// straddle a corner.
    pub cell: f64,
    /// Points a cell needs before its plane is trusted.
    pub min_points: usize,
    /// Largest ratio of a cell's smallest to its middle eigenvalue for it to count as a plane.
    /// A flat 0.2 m patch with 1.5 cm noise gives 0.07; two faces meeting at a right angle
    /// in one cell give about 0.3 and more.
    pub planarity: f64,
    /// Most a sweep surfel's normal may differ from the map surfel it pairs with, degrees.
    pub max_angle: f64,
    /// Correspondence distance at the first and the last iteration, m.
    pub max_distance: [f64; 2],
    pub max_iterations: usize,
    /// Stop when an iteration moves the pose less than this (m plus rad).
    pub tolerance: f64,
    /// A sweep with fewer pairs than this keeps its pose (too little of it overlaps the map).
    pub min_pairs: usize,
    /// A correction larger than this is refused, m and rad: the registration found some other
    /// place that fits, not the drift since the last view.
    pub max_correction: [f64; 2],
    /// The error of a map plane at a pair at which the pair counts half, m: each pair counts
    /// `1 / (1 + v / plane_sigma²)`, with `v` the variance of the map surfel's plane where the
    /// sweep's surfel lies ([`Surfel::offset_variance`]) and of the sweep surfel's centroid.
    /// The LMS200's 1.5 cm range noise over a cell's eight points places its plane to 5 mm at
    /// the centroid, and a pair of two such surfels counts 0.64 (more points, more); a patch
    /// of two far scan lines, or one tilted by a corner it straddles, reached a cell away
    /// along it can be 2-5 cm off there, and its pair counts 0.2 to 0.04. Such patches made
    /// most of the error of sweeps registered from the truth on hall-scan3d (issue 47's
    /// note).
    pub plane_sigma: f64,
    /// Directions whose share of the normalised JᵀJ falls below this are left unchanged
    /// ([`crate::mapping::registration::RegistrationConfig::degenerate`]).
    pub degenerate: f64,
}

impl Default for SurfelConfig {
    fn default() -> Self {
        SurfelConfig {
            enabled: true,
            cell: 0.2,
            min_points: 8,
            planarity: 0.15,
            max_angle: 30.0,
            max_distance: [0.3, 0.1],
            max_iterations: 30,
            tolerance: 1e-5,
            min_pairs: 100,
            max_correction: [0.5, 0.1],
            plane_sigma: 0.01,
            degenerate: 0.02,
        }
    }
}

impl SurfelConfig {
    /// Checks values, naming `PREFIX.KEY`.
    pub fn validate(&self, prefix: &str) -> Result<(), ConfigError> {
        crate::config::check_ranges(
            prefix,
            &[
                ("cell", self.cell, 0.01, 5.0),
                ("min_points", self.min_points as f64, 3.0, 1e6),
                ("planarity", self.planarity, 0.0, 1.0),
                ("max_angle", self.max_angle, 0.0, 90.0),
                ("max_distance", self.max_distance[0], 0.01, 10.0),
                ("max_distance", self.max_distance[1], 0.01, 10.0),
                ("max_iterations", self.max_iterations as f64, 1.0, 1e4),
                ("tolerance", self.tolerance, 0.0, 1.0),
                ("min_pairs", self.min_pairs as f64, 3.0, 1e9),
                ("max_correction", self.max_correction[0], 0.0, 100.0),
                ("max_correction", self.max_correction[1], 0.0, 3.2),
                ("plane_sigma", self.plane_sigma, 1e-4, 10.0),
                ("degenerate", self.degenerate, 0.0, 1e6),
            ],
        )?;
        if self.max_distance[1] > self.max_distance[0] {
            return Err((
                crate::config::below(prefix, "max_distance"),
                format!(
                    "expected [first, last] with the last no larger; found {:?}",
                    self.max_distance
                ),
            ));
        }
        Ok(())
    }
}

/// A cell's points by their moments.
#[derive(Debug, Clone, Copy, Default)]
struct Moments {
    n: u32,
    sum: [f64; 3],
    /// xx, xy, xz, yy, yz, zz.
    products: [f64; 6],
}

/// A planar patch: its centroid and unit normal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Surfel {
    pub centroid: [f64; 3],
    pub normal: [f64; 3],
    /// The patch's in-plane axes (unit) and its points' variance along each, m², and its
    /// points' variance off the plane and their count: what the plane's uncertainty is made
    /// of ([`Surfel::offset_variance`]).
    pub axes: [[f64; 3]; 2],
    pub spread: [f64; 2],
    pub thickness: f64,
    pub count: u32,
}

impl Surfel {
    /// The variance of the plane's offset at `at` (a point on or near it), m²: the least-squares
    /// plane through `count` points scattered `thickness` off it has its offset at the
    /// centroid uncertain by `thickness / count`, and its tilt about each in-plane axis by
    /// `thickness / (count · spread)`, so the offset grows with the distance from the centroid
    /// along the patch. A patch of few points seen from afar (two or three scan lines) is
    /// well placed where it was measured and poorly a cell away.
    pub fn offset_variance(&self, at: [f64; 3]) -> f64 {
        let d = [
            at[0] - self.centroid[0],
            at[1] - self.centroid[1],
            at[2] - self.centroid[2],
        ];
        let along = |a: [f64; 3]| d[0] * a[0] + d[1] * a[1] + d[2] * a[2];
        let (d1, d2) = (along(self.axes[0]), along(self.axes[1]));
        self.thickness / self.count as f64
            * (1.0 + d1 * d1 / self.spread[0] + d2 * d2 / self.spread[1])
    }
}

impl Moments {
    fn add(&mut self, p: [f64; 3]) {
        self.n += 1;
        for (s, v) in self.sum.iter_mut().zip(p) {
            *s += v;
        }
        let [x, y, z] = p;
        let q = [x * x, x * y, x * z, y * y, y * z, z * z];
        for (s, v) in self.products.iter_mut().zip(q) {
            *s += v;
        }
    }

    /// The cell's plane, if it has enough points and they lie flat.
    fn surfel(&self, c: &SurfelConfig) -> Option<Surfel> {
        if (self.n as usize) < c.min_points {
            return None;
        }
        let n = self.n as f64;
        let m = self.sum.map(|s| s / n);
        let p = self.products.map(|s| s / n);
        let cov = nalgebra::Matrix3::new(
            p[0] - m[0] * m[0],
            p[1] - m[0] * m[1],
            p[2] - m[0] * m[2],
            p[1] - m[0] * m[1],
            p[3] - m[1] * m[1],
            p[4] - m[1] * m[2],
            p[2] - m[0] * m[2],
            p[4] - m[1] * m[2],
            p[5] - m[2] * m[2],
        );
        let eig = cov.symmetric_eigen();
        let mut order = [0usize, 1, 2];
        order.sort_by(|a, b| eig.eigenvalues[*a].total_cmp(&eig.eigenvalues[*b]));
        let (small, middle) = (
            eig.eigenvalues[order[0]].max(0.0),
            eig.eigenvalues[order[1]],
        );
        if middle.is_nan() || middle <= 0.0 || small > c.planarity * middle {
            return None;
        }
        let unit = |k: usize| {
            let v = eig.eigenvectors.column(order[k]);
            let len = v.norm();
            (len > 0.0).then(|| [v[0] / len, v[1] / len, v[2] / len])
        };
        Some(Surfel {
            centroid: m,
            normal: unit(0)?,
            axes: [unit(1)?, unit(2)?],
            spread: [middle, eig.eigenvalues[order[2]]],
            thickness: small,
            count: self.n,
        })
    }
}

/// What registering a sweep did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Registration {
    /// The pose the sweep was placed by, and the pose it is placed by after registration (the
    /// same when it was refused).
    pub guess: Pose2,
    pub pose: Pose2,
    /// The sweep's surfels that could pair (not facing up or down), and the map's; pairs at
    /// the last iteration.
    pub sweep_surfels: usize,
    pub map_surfels: usize,
    pub pairs: usize,
    pub iterations: usize,
    /// Whether a direction was left unchanged as unconstrained.
    pub degenerate: bool,
    /// Whether the registration was refused (too few pairs, or a correction too large).
    pub refused: bool,
}

/// The map's surfaces as surfels (see the module's documentation).
#[derive(Debug, Clone)]
pub struct SurfelMap {
    config: SurfelConfig,
    cells: FxHashMap<[i64; 3], Moments>,
    /// Each cell's surfel, made again when points are added to it.
    surfels: FxHashMap<[i64; 3], Surfel>,
}

impl SurfelMap {
    pub fn new(config: SurfelConfig) -> SurfelMap {
        SurfelMap {
            config,
            cells: FxHashMap::default(),
            surfels: FxHashMap::default(),
        }
    }

    pub fn config(&self) -> &SurfelConfig {
        &self.config
    }

    fn key(&self, p: [f64; 3]) -> [i64; 3] {
        p.map(|c| (c / self.config.cell).floor() as i64)
    }

    /// Adds points (map frame) and makes the planes of the cells they fall in again.
    pub fn add(&mut self, points: impl IntoIterator<Item = [f64; 3]>) {
        let mut touched = FxHashSet::default();
        for p in points {
            if !p.iter().all(|c| c.is_finite()) {
                continue;
            }
            let k = self.key(p);
            self.cells.entry(k).or_default().add(p);
            touched.insert(k);
        }
        for k in touched {
            match self.cells[&k].surfel(&self.config) {
                Some(s) => self.surfels.insert(k, s),
                None => self.surfels.remove(&k),
            };
        }
    }

    /// The surfels, in no particular order.
    pub fn surfels(&self) -> impl Iterator<Item = &Surfel> {
        self.surfels.values()
    }

    pub fn is_empty(&self) -> bool {
        self.surfels.is_empty()
    }

    /// The surfels that constrain x, y or yaw (not facing up or down), in cell order, so that
    /// what is made of them does not depend on the hash map's order.
    fn sideways(&self) -> Vec<Surfel> {
        let mut keyed: Vec<(&[i64; 3], &Surfel)> = self
            .surfels
            .iter()
            .filter(|(_, s)| s.normal[2].abs() < VERTICAL_NORMAL)
            .collect();
        keyed.sort_unstable_by_key(|(k, _)| **k);
        keyed.into_iter().map(|(_, s)| *s).collect()
    }

    /// Registers a sweep whose points are `points` in the robot's base frame (x forward,
    /// z up from the floor), placed by `guess` (map frame), against the surfels: the pose
    /// that places them best.
    pub fn register(&self, points: &[[f64; 3]], guess: Pose2) -> Registration {
        let c = &self.config;
        // The map's surfels in a k-d tree of their centroids.
        let surfels = self.sideways();
        let centroids: Vec<[f64; 3]> = surfels.iter().map(|s| s.centroid).collect();
        let index = Index::new(&centroids);
        // The sweep's own, in the robot's frame.
        let mut own = SurfelMap::new(*c);
        own.add(points.iter().copied());
        let sweep = own.sideways();
        let agree = c.max_angle.to_radians().cos();
        let plane2 = c.plane_sigma * c.plane_sigma;
        let refuse = |pairs, iterations| Registration {
            guess,
            pose: guess,
            sweep_surfels: sweep.len(),
            map_surfels: surfels.len(),
            pairs,
            iterations,
            degenerate: false,
            refused: true,
        };
        let mut pose = guess;
        let mut pairs = 0;
        let mut degenerate = false;
        let mut iterations = 0;
        for it in 0..c.max_iterations {
            iterations = it + 1;
            let f = if c.max_iterations > 1 {
                (it as f64 / (c.max_iterations - 1) as f64).min(1.0)
            } else {
                1.0
            };
            let max = c.max_distance[0] + f * (c.max_distance[1] - c.max_distance[0]);
            let (sin, cos) = pose.theta.sin_cos();
            // JᵀJ's eigenvalues are the shares of the pairs that constrain each direction,
            // each counted by its certainty (`degenerate`): a direction that only uncertain
            // planes constrain is left as the guess has it.
            let found: Vec<Pair> = sweep
                .iter()
                .filter_map(|own| {
                    let (p, n) = (own.centroid, own.normal);
                    let w = crate::mapping::registration::place(&pose, p);
                    let n = [cos * n[0] - sin * n[1], sin * n[0] + cos * n[1], n[2]];
                    let s = index
                        .nearest_n(&w, CANDIDATES)
                        .into_iter()
                        .map(|j| &surfels[j])
                        .find(|s| (0..3).map(|k| s.normal[k] * n[k]).sum::<f64>().abs() >= agree)?;
                    let d2 = (0..3).map(|k| (w[k] - s.centroid[k]).powi(2)).sum::<f64>();
                    let r = (0..3)
                        .map(|k| s.normal[k] * (w[k] - s.centroid[k]))
                        .sum::<f64>();
                    // The centroids of two cells on one surface lie up to a cell apart
                    // along it; the distance off the plane is what must be small.
                    let reach = max + c.cell;
                    // Tukey's biweight on the distance off the plane, as a scale of the
                    // residual and its derivatives: a pair far off its plane (a person,
                    // a surface the map has not got) pulls less as the distance shrinks.
                    let weight = (1.0 - (r / max).powi(2)).powi(2);
                    // Less for a pair whose map plane is poorly known where the
                    // sweep's surfel lies (a patch of few points, tilted by a corner it
                    // straddles, reached a cell away along it).
                    let v = s.offset_variance(w) + own.thickness / own.count as f64;
                    let weight = weight / (1.0 + v / plane2);
                    (d2 <= reach * reach && r.abs() <= max).then_some(Pair {
                        p,
                        q: s.centroid,
                        n: Some(s.normal.map(|v| v * weight.sqrt())),
                    })
                })
                .collect();
            let term = Term {
                weight: 1.0,
                pairs: found,
            };
            pairs = term.pairs.len();
            if pairs < c.min_pairs {
                return refuse(pairs, iterations);
            }
            let (next, flat) = minimise(pose, std::slice::from_ref(&term), 3, c.degenerate);
            degenerate |= flat;
            let step = (next.x - pose.x).hypot(next.y - pose.y)
                + wrap_angle(next.theta - pose.theta).abs();
            pose = next;
            if step < c.tolerance && f >= 1.0 {
                break;
            }
        }
        if pose.distance(&guess) > c.max_correction[0]
            || wrap_angle(pose.theta - guess.theta).abs() > c.max_correction[1]
        {
            return refuse(pairs, iterations);
        }
        Registration {
            guess,
            pose,
            sweep_surfels: sweep.len(),
            map_surfels: surfels.len(),
            pairs,
            iterations,
            degenerate,
            refused: false,
        }
    }
}

/// Surfels whose normal's vertical component is at least this face up or down.
const VERTICAL_NORMAL: f64 = 0.9;
/// The map surfels nearest a sweep surfel that are tried for one whose normal agrees.
const CANDIDATES: usize = 4;

#[cfg(test)]
mod tests {
    use super::*;

    /// Points on the walls, floor and a pillar of a room 8 m by 6 m, 2 m high, every 5 cm,
    /// in the map frame.
    fn room() -> Vec<[f64; 3]> {
        let mut out = Vec::new();
        let step = 0.05;
        let n = |l: f64| (l / step).round() as usize;
        for i in 0..=n(8.0) {
            for k in 0..=n(2.0) {
                let (x, z) = (i as f64 * step, k as f64 * step);
                out.push([x, 0.0, z]);
                out.push([x, 6.0, z]);
            }
        }
        for j in 0..=n(6.0) {
            for k in 0..=n(2.0) {
                let (y, z) = (j as f64 * step, k as f64 * step);
                out.push([0.0, y, z]);
                out.push([8.0, y, z]);
            }
        }
        // A pillar 0.4 m square at (5, 2)-(5.4, 2.4).
        for i in 0..=n(0.4) {
            for k in 0..=n(2.0) {
                let (a, z) = (i as f64 * step, k as f64 * step);
                out.extend([
                    [5.0 + a, 2.0, z],
                    [5.0 + a, 2.4, z],
                    [5.0, 2.0 + a, z],
                    [5.4, 2.0 + a, z],
                ]);
            }
        }
        for i in 0..=n(8.0) {
            for j in 0..=n(6.0) {
                out.push([i as f64 * step, j as f64 * step, 0.0]);
            }
        }
        out
    }

    /// The map frame's points as a robot at `pose` sees them (its base frame).
    fn seen_from(points: &[[f64; 3]], pose: &Pose2) -> Vec<[f64; 3]> {
        let back = pose.inverse();
        points
            .iter()
            .map(|p| crate::mapping::registration::place(&back, *p))
            .collect()
    }

    /// A flat cell is a surfel with the wall's normal through its points' centroid; a cell
    /// holding a corner, or too few points, is not.
    #[test]
    fn flat_cells_are_surfels_and_corners_are_not() {
        let mut map = SurfelMap::new(SurfelConfig::default());
        map.add(room());
        // The cell [0.2, 0.4) × [0, 0.2) × [1.0, 1.2) holds the wall y = 0.
        let k = map.key([0.3, 0.1, 1.1]);
        let s = map.surfels[&k];
        assert!(s.normal[1].abs() > 0.999, "{s:?}");
        assert!(s.centroid[1].abs() < 1e-9 && (s.centroid[0] - 0.3).abs() < 0.03);
        // The corner x = 0, y = 0 at the same height.
        assert!(!map.surfels.contains_key(&map.key([0.05, 0.05, 1.1])));
        let mut few = SurfelMap::new(SurfelConfig::default());
        few.add([[0.3, 0.0, 1.1], [0.35, 0.0, 1.1], [0.3, 0.0, 1.15]]);
        assert!(few.is_empty());
    }

    /// A patch of two vertical scan lines 0.1 m apart, four points each 5 cm apart, 1 cm off
    /// the wall y = 2.1 in a pattern that is uncorrelated with x and z: its points' variances
    /// are 0.0025 m² along x, 0.003125 m² along z and 1e-4 m² off the plane, so the plane's
    /// offset is uncertain by 1e-4 / 8 m² at the centroid, and by 17 times that 0.2 m along x
    /// (1 + 0.2² / 0.0025).
    #[test]
    fn a_planes_offset_is_less_certain_away_from_its_points() {
        let mut points = Vec::new();
        for (x, signs) in [(0.0, [1.0, -1.0, -1.0, 1.0]), (0.1, [-1.0, 1.0, 1.0, -1.0])] {
            for (k, sign) in signs.into_iter().enumerate() {
                points.push([1.02 + x, 2.1 + 0.01 * sign, 1.02 + 0.05 * k as f64]);
            }
        }
        let mut map = SurfelMap::new(SurfelConfig::default());
        map.add(points);
        let s = *map.surfels().next().expect("a surfel");
        let c = s.centroid;
        assert!(
            (c[0] - 1.07).abs() < 1e-12 && (c[1] - 2.1).abs() < 1e-12,
            "{c:?}"
        );
        let at = |dx: f64, dz: f64| s.offset_variance([c[0] + dx, c[1], c[2] + dz]);
        let near = 1e-4 / 8.0;
        assert!((at(0.0, 0.0) - near).abs() < 1e-12, "{}", at(0.0, 0.0));
        assert!(
            (at(0.2, 0.0) - 17.0 * near).abs() < 1e-10,
            "{}",
            at(0.2, 0.0)
        );
        let up = 1.0 + 0.2 * 0.2 / 0.003125;
        assert!((at(0.0, 0.2) - up * near).abs() < 1e-10, "{}", at(0.0, 0.2));
        // Off the plane the offset's uncertainty is the same as on it.
        assert!((s.offset_variance([c[0], c[1] + 0.05, c[2]]) - near).abs() < 1e-12);
    }

    /// A sweep seen from a pose 0.25 m and 2° from where the guess puts it is moved back onto
    /// the map: the registered pose is the true one to within a few millimetres and a tenth
    /// of a degree (the points are exact; what is left is the surfels' own spread).
    #[test]
    fn a_displaced_sweep_is_registered_onto_the_map() {
        let mut map = SurfelMap::new(SurfelConfig::default());
        let points = room();
        map.add(points.iter().copied());
        let truth = Pose2::new(3.0, 3.5, 0.4);
        let guess = Pose2::new(3.2, 3.35, 0.4 + 2f64.to_radians());
        let r = map.register(&seen_from(&points, &truth), guess);
        assert!(!r.refused, "{r:?}");
        assert!(r.pose.distance(&truth) < 0.005, "{r:?}");
        assert!(wrap_angle(r.pose.theta - truth.theta).abs() < 0.1f64.to_radians());
        assert!(r.pairs >= 200);
    }

    /// Between two long walls alone nothing fixes the position along them: that direction
    /// keeps the guess while the other two are corrected.
    #[test]
    fn a_corridor_keeps_its_length_from_the_guess() {
        let mut walls = Vec::new();
        for i in 0..=400 {
            for k in 0..=40 {
                let (x, z) = (i as f64 * 0.05, k as f64 * 0.05);
                walls.push([x, 0.0, z]);
                walls.push([x, 2.0, z]);
            }
        }
        let mut map = SurfelMap::new(SurfelConfig::default());
        map.add(walls.iter().copied());
        let truth = Pose2::new(10.0, 1.0, 0.0);
        let guess = Pose2::new(10.3, 1.1, 0.02);
        let r = map.register(&seen_from(&walls, &truth), guess);
        assert!(!r.refused && r.degenerate, "{r:?}");
        assert!((r.pose.y - 1.0).abs() < 0.005, "{r:?}");
        assert!(r.pose.theta.abs() < 0.002, "{r:?}");
        assert!((r.pose.x - 10.3).abs() < 0.01, "x kept: {r:?}");
    }

    /// A sweep that does not overlap the map is refused and keeps its guess.
    #[test]
    fn a_sweep_elsewhere_is_refused() {
        let mut map = SurfelMap::new(SurfelConfig::default());
        map.add(room());
        let far: Vec<[f64; 3]> = room().iter().map(|p| [p[0], p[1], p[2] + 50.0]).collect();
        let guess = Pose2::new(3.0, 3.0, 0.0);
        let r = map.register(&far, guess);
        assert!(r.refused);
        assert_eq!(r.pose, guess);
    }

    #[test]
    fn bad_values_name_their_key() {
        let c = SurfelConfig {
            max_distance: [0.1, 0.5],
            ..SurfelConfig::default()
        };
        assert_eq!(
            c.validate("scan3d.registration").unwrap_err().0,
            "scan3d.registration.max_distance"
        );
        let c = SurfelConfig {
            cell: 0.0,
            ..SurfelConfig::default()
        };
        assert_eq!(
            c.validate("scan3d.registration").unwrap_err().0,
            "scan3d.registration.cell"
        );
    }
}
