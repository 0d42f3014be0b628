//! A 3D distance field of a model's surfaces: the Euclidean distance from any point to the
//! nearest surface, on a voxel grid, looked up with trilinear interpolation.
//!
//! The surfaces (triangles) are sampled into the voxels they cross, at under half a voxel's
//! spacing, and the exact Euclidean distance transform of those voxels' centres is taken by
//! Felzenszwalb and Huttenlocher's lower envelope of parabolas ("Distance Transforms of Sampled
//! Functions", Theory of Computing 8, 2012), one axis after another. A point's distance is then
//! within half a voxel's diagonal of its distance to the true surface. This is the likelihood
//! field of Thrun et al. (Probabilistic Robotics §6.4) in three dimensions, for the depth
//! camera's Monte Carlo localisation (`depth_localization.mcl.likelihood = "field"`): a
//! measured point is weighed by how far it lies from the model, with no render.

/// Squared distances past this many voxels are not told apart (a voxel's distance is capped
/// here): 1.6 m at 5 cm voxels, where a likelihood kernel of centimetres is flat.
const CAP_VOXELS: f32 = 32.0;

/// The stored distances' resolution: 1/1024 of a voxel (0.05 mm at 5 cm), so that the cap of
/// 32 voxels fits two bytes.
const UNITS_PER_VOXEL: f64 = 1024.0;

/// Distances to a model's surfaces on a voxel grid.
#[derive(Debug, Clone)]
pub struct DistanceField {
    /// The grid's lower corner (the first voxel's corner), m.
    origin: [f64; 3],
    /// A voxel's side, m.
    cell: f64,
    inv_cell: f64,
    dims: [usize; 3],
    /// Index steps of a voxel along x, y and z, and to the next voxel centre that the
    /// interpolation reads along each (0 along an axis one voxel wide).
    strides: [usize; 3],
    steps: [usize; 3],
    /// Along each axis, the last voxel centre's coordinate (in voxels from the first) and
    /// the last voxel an interpolation starts from (the one before the last, or 0).
    top: [f64; 3],
    last: [u32; 3],
    /// Distance of each voxel's centre to the nearest surface voxel's centre, in `unit`s,
    /// x fastest: two bytes a voxel, so that more of the field stays in the caches.
    distance: Vec<u16>,
    /// The distances' unit, m: 1/1024 of a voxel.
    unit: f32,
}

/// Why a field could not be made.
#[derive(Debug, Clone, PartialEq)]
pub enum FieldError {
    /// No triangle with finite corners.
    Empty,
    /// The grid would exceed `max_voxels`.
    TooLarge { voxels: u64, max_voxels: u64 },
    /// The voxel size is not a positive distance.
    Cell(f64),
}

impl std::fmt::Display for FieldError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FieldError::Empty => write!(f, "the model has no triangle with finite corners"),
            FieldError::TooLarge { voxels, max_voxels } => write!(
                f,
                "the model's distance field would take {voxels} voxels, more than {max_voxels}: expected a larger voxel"
            ),
            FieldError::Cell(c) => write!(f, "voxel size {c} m: expected a positive distance"),
        }
    }
}

impl std::error::Error for FieldError {}

impl DistanceField {
    /// The field of `triangles` (corners in the model's frame, m) on voxels of `cell` m,
    /// over the triangles' bounds padded by `margin` m on every side; at most `max_voxels`.
    pub fn new(
        triangles: &[[[f64; 3]; 3]],
        cell: f64,
        margin: f64,
        max_voxels: u64,
    ) -> Result<DistanceField, FieldError> {
        if !(cell > 0.0 && cell.is_finite()) {
            return Err(FieldError::Cell(cell));
        }
        let finite = |t: &&[[f64; 3]; 3]| t.iter().flatten().all(|v| v.is_finite());
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for t in triangles.iter().filter(finite) {
            for p in t {
                for k in 0..3 {
                    lo[k] = lo[k].min(p[k]);
                    hi[k] = hi[k].max(p[k]);
                }
            }
        }
        if lo[0] > hi[0] {
            return Err(FieldError::Empty);
        }
        let margin = margin.max(0.0);
        let origin = [lo[0] - margin, lo[1] - margin, lo[2] - margin];
        let mut dims = [0usize; 3];
        let mut voxels: u64 = 1;
        for k in 0..3 {
            let n = ((hi[k] + margin - origin[k]) / cell).floor() + 1.0;
            // A span of more voxels than this is refused below in any case.
            let n = n.min(max_voxels as f64 + 1.0).max(1.0) as u64;
            voxels = voxels.saturating_mul(n);
            dims[k] = n as usize;
        }
        // A lookup indexes each axis in 32 bits.
        if voxels > max_voxels || dims.iter().any(|&n| n > u32::MAX as usize) {
            return Err(FieldError::TooLarge { voxels, max_voxels });
        }
        let strides = [1, dims[0], dims[0] * dims[1]];
        let steps = [0, 1, 2].map(|k| if dims[k] > 1 { strides[k] } else { 0 });
        let mut field = DistanceField {
            origin,
            cell,
            inv_cell: 1.0 / cell,
            dims,
            strides,
            steps,
            top: dims.map(|n| (n - 1) as f64),
            last: dims.map(|n| n.saturating_sub(2) as u32),
            distance: Vec::new(),
            unit: (cell / UNITS_PER_VOXEL) as f32,
        };
        // Squared distances in voxels: 0 on the surface, "far" elsewhere.
        let far = CAP_VOXELS * CAP_VOXELS;
        let mut sq = vec![far; voxels as usize];
        for t in triangles.iter().filter(finite) {
            field.mark(t, &mut sq);
        }
        for axis in 0..3 {
            field.transform_axis(&mut sq, axis);
        }
        field.distance = sq
            .iter()
            .map(|&d| (d.min(far).sqrt() * UNITS_PER_VOXEL as f32).round() as u16)
            .collect();
        Ok(field)
    }

    /// The voxel's side, m.
    pub fn cell(&self) -> f64 {
        self.cell
    }

    /// The grid's size in voxels (x, y, z).
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// Marks the voxels triangle `t` crosses: its points on a barycentric lattice whose steps
    /// along the two edges from the first corner are under half a voxel.
    fn mark(&self, t: &[[f64; 3]; 3], sq: &mut [f32]) {
        let e1 = [t[1][0] - t[0][0], t[1][1] - t[0][1], t[1][2] - t[0][2]];
        let e2 = [t[2][0] - t[0][0], t[2][1] - t[0][1], t[2][2] - t[0][2]];
        let len = |e: &[f64; 3]| (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt();
        // Points i/n along e1 and j/n along e2 with i + j ≤ n: neighbours lie at most
        // max(|e1|, |e2|, |e2 − e1|)/n apart.
        let e3 = [e2[0] - e1[0], e2[1] - e1[1], e2[2] - e1[2]];
        let longest = len(&e1).max(len(&e2)).max(len(&e3));
        let n = ((longest / (0.5 * self.cell)).ceil() as usize).max(1);
        for i in 0..=n {
            for j in 0..=(n - i) {
                let (a, b) = (i as f64 / n as f64, j as f64 / n as f64);
                let p = [
                    t[0][0] + a * e1[0] + b * e2[0],
                    t[0][1] + a * e1[1] + b * e2[1],
                    t[0][2] + a * e1[2] + b * e2[2],
                ];
                if let Some(k) = self.index_of(p) {
                    sq[k] = 0.0;
                }
            }
        }
    }

    /// The index of the voxel holding `p`, if inside the grid.
    fn index_of(&self, p: [f64; 3]) -> Option<usize> {
        let mut ijk = [0usize; 3];
        for k in 0..3 {
            let c = ((p[k] - self.origin[k]) / self.cell).floor();
            if !(c >= 0.0 && c < self.dims[k] as f64) {
                return None;
            }
            ijk[k] = c as usize;
        }
        Some(ijk[0] + self.dims[0] * (ijk[1] + self.dims[1] * ijk[2]))
    }

    /// The exact 1D squared distance transform along `axis`, every line of the grid.
    fn transform_axis(&self, sq: &mut [f32], axis: usize) {
        let [nx, ny, nz] = self.dims;
        let n = self.dims[axis];
        let stride = match axis {
            0 => 1,
            1 => nx,
            _ => nx * ny,
        };
        let (mut f, mut d) = (vec![0f32; n], vec![0f32; n]);
        let (mut v, mut z) = (vec![0usize; n], vec![0f32; n + 1]);
        let starts: Vec<usize> = match axis {
            0 => (0..ny * nz).map(|l| l * nx).collect(),
            1 => (0..nz)
                .flat_map(|k| (0..nx).map(move |i| i + nx * ny * k))
                .collect(),
            _ => (0..nx * ny).collect(),
        };
        for s in starts {
            for (q, fq) in f.iter_mut().enumerate() {
                *fq = sq[s + q * stride];
            }
            lower_envelope(&f, &mut d, &mut v, &mut z);
            for (q, dq) in d.iter().enumerate() {
                sq[s + q * stride] = *dq;
            }
        }
    }

    /// The distance from `p` (model frame, m) to the nearest surface, trilinearly
    /// interpolated between voxel centres; outside the grid, the distance to the grid plus
    /// the nearest border voxel's.
    #[inline]
    pub fn distance(&self, p: [f64; 3]) -> f64 {
        let mut index = 0usize;
        let mut frac = [0f32; 3];
        let mut outside = 0.0f64;
        for k in 0..3 {
            // The continuous voxel-centre coordinate, clamped to the grid (NaN to its start).
            let x = (p[k] - self.origin[k]) * self.inv_cell - 0.5;
            let c = if x >= 0.0 { x.min(self.top[k]) } else { 0.0 };
            let d = x - c;
            if d.is_finite() {
                outside += d * d;
            }
            // 0 ≤ c < 2^32: truncation to 32 bits is the floor (with no call to the maths
            // library, and fewer instructions than to 64 unsigned bits).
            let i = (c as u32).min(self.last[k]);
            index += i as usize * self.strides[k];
            frac[k] = (c - i as f64) as f32;
        }
        let [sx, sy, sz] = self.steps;
        let at = |o: usize| self.distance[index + o] as f32;
        let [fx, fy, fz] = frac;
        let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
        let c00 = lerp(at(0), at(sx), fx);
        let c10 = lerp(at(sy), at(sy + sx), fx);
        let c01 = lerp(at(sz), at(sz + sx), fx);
        let c11 = lerp(at(sz + sy), at(sz + sy + sx), fx);
        let inside = lerp(lerp(c00, c10, fy), lerp(c01, c11, fy), fz);
        (inside * self.unit) as f64 + outside.sqrt() * self.cell
    }
}

/// Felzenszwalb and Huttenlocher's 1D squared distance transform: `d[q] = min_p (q − p)² +
/// f[p]`, by the lower envelope of the parabolas rooted at each `p` (`v` its roots' indices,
/// `z` the boundaries between them; both scratch of `f`'s length and one more).
fn lower_envelope(f: &[f32], d: &mut [f32], v: &mut [usize], z: &mut [f32]) {
    let n = f.len();
    if n == 0 {
        return;
    }
    let mut k = 0usize;
    v[0] = 0;
    z[0] = f32::NEG_INFINITY;
    z[1] = f32::INFINITY;
    let inter = |q: usize, p: usize| -> f32 {
        let (qf, pf) = (q as f32, p as f32);
        ((f[q] + qf * qf) - (f[p] + pf * pf)) / (2.0 * (qf - pf))
    };
    for q in 1..n {
        // z[0] is −∞ and the values are finite, so the search stops at k = 0 at the latest.
        let mut s = inter(q, v[k]);
        while s <= z[k] {
            k -= 1;
            s = inter(q, v[k]);
        }
        k += 1;
        v[k] = q;
        z[k] = s;
        z[k + 1] = f32::INFINITY;
    }
    let mut k = 0usize;
    for (q, dq) in d.iter_mut().enumerate() {
        while z[k + 1] < q as f32 {
            k += 1;
        }
        let r = q as f32 - v[k] as f32;
        *dq = r * r + f[v[k]];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The floor z = 0 over 0..4 × 0..3 m, as two triangles.
    fn floor() -> Vec<[[f64; 3]; 3]> {
        vec![
            [[0.0, 0.0, 0.0], [4.0, 0.0, 0.0], [4.0, 3.0, 0.0]],
            [[0.0, 0.0, 0.0], [4.0, 3.0, 0.0], [0.0, 3.0, 0.0]],
        ]
    }

    /// Above a plane the distance is the height, within half a voxel's diagonal (the surface
    /// voxel's centre lies up to half a voxel from the plane); beside the grid, the distance
    /// to it is added.
    #[test]
    fn distance_above_a_plane_is_the_height() {
        let cell = 0.05;
        let f = DistanceField::new(&floor(), cell, 1.0, 10_000_000).unwrap();
        let tol = 0.5 * cell * 3f64.sqrt();
        for (x, y, z) in [
            (1.0, 1.0, 0.3),
            (2.5, 0.7, 0.02),
            (3.3, 2.2, 0.77),
            (1.2, 2.9, -0.4),
        ] {
            let d = f.distance([x, y, z]);
            assert!((d - z.abs()).abs() <= tol, "({x}, {y}, {z}): {d}");
        }
        // 2 m above the floor is outside the 1 m margin: the grid's top is about 1 m up.
        let d = f.distance([2.0, 1.5, 2.0]);
        assert!((d - 2.0).abs() <= tol + 1e-9, "{d}");
    }

    /// Off the plane's edge the distance is to the edge, not to the plane's extension: the
    /// transform is Euclidean in all three axes, checked against the hand distance.
    #[test]
    fn distance_beyond_an_edge_is_to_the_edge() {
        let cell = 0.05;
        let f = DistanceField::new(&floor(), cell, 1.0, 10_000_000).unwrap();
        let tol = 0.5 * cell * 3f64.sqrt();
        // 0.3 m past x = 4 and 0.4 m up: 0.5 m from the edge.
        let d = f.distance([4.3, 1.5, 0.4]);
        assert!((d - 0.5).abs() <= tol, "{d}");
        // Past the corner (4, 3, 0) by (0.2, 0.2, 0.1): 0.3 m.
        let d = f.distance([4.2, 3.2, 0.1]);
        assert!((d - 0.3).abs() <= tol, "{d}");
    }

    /// The 1D transform against brute force on a line with several seeds.
    #[test]
    fn the_lower_envelope_is_the_brute_force_minimum() {
        let f: Vec<f32> = vec![9.0, 0.0, 9.0, 9.0, 4.0, 9.0, 9.0, 9.0, 0.0, 9.0, 1.0];
        let n = f.len();
        let (mut d, mut v, mut z) = (vec![0f32; n], vec![0usize; n], vec![0f32; n + 1]);
        lower_envelope(&f, &mut d, &mut v, &mut z);
        for (q, got) in d.iter().enumerate() {
            let want = f
                .iter()
                .enumerate()
                .map(|(p, fp)| (q as f32 - p as f32).powi(2) + fp)
                .fold(f32::INFINITY, f32::min);
            assert_eq!(*got, want, "at {q}");
        }
    }

    /// Bad input is refused with a reason, never a panic or an allocation abort.
    #[test]
    fn empty_huge_or_degenerate_input_is_refused() {
        assert_eq!(
            DistanceField::new(&[], 0.05, 0.5, 1000).unwrap_err(),
            FieldError::Empty
        );
        let nan = [[[f64::NAN, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]];
        assert_eq!(
            DistanceField::new(&nan, 0.05, 0.5, 1000).unwrap_err(),
            FieldError::Empty
        );
        assert!(matches!(
            DistanceField::new(&floor(), 0.05, 0.5, 1000).unwrap_err(),
            FieldError::TooLarge { .. }
        ));
        let far = [[[0.0, 0.0, 0.0], [1e300, 0.0, 0.0], [0.0, 1e300, 0.0]]];
        assert!(matches!(
            DistanceField::new(&far, 0.05, 0.5, 1_000_000).unwrap_err(),
            FieldError::TooLarge { .. }
        ));
        assert!(matches!(
            DistanceField::new(&floor(), 0.0, 0.5, 1000).unwrap_err(),
            FieldError::Cell(_)
        ));
        // A sliver wider than a lookup's 32-bit index along x, within any voxel budget: refused
        // before its grid is allocated.
        let sliver = [[[0.0, 0.0, 0.0], [5e9, 0.0, 0.0], [0.0, 0.5, 0.0]]];
        assert!(matches!(
            DistanceField::new(&sliver, 1.0, 0.0, u64::MAX).unwrap_err(),
            FieldError::TooLarge { .. }
        ));
    }
}
