//! A polygon map's planes against the true surfaces (issue 6 §7): for each polygon, the true
//! surface under it is the plane fitted to the true points near its plane (within 3 cm, or
//! [`BAND_M`] if too few are) and inside its outline, refitted twice to the points within 2 cm; its angle error is the angle between the two normals and its offset
//! error the distance of the polygon's centroid from the true plane. Means are weighted by the
//! polygons' areas, as large faces (walls, floor) matter more than small ones.

use futago_robot::geometry::plane::Plane;
use futago_robot::mapping::polygons::Polygon;

/// True points farther than this from a polygon's plane are not its surface, m.
pub const BAND_M: f64 = 0.10;
/// The first fit takes the true points within this of the polygon's plane (all within
/// [`BAND_M`] if too few are), m.
const START_M: f64 = 0.03;
/// Each refit takes the true points within this of the previous fit, m.
const REFIT_M: f64 = 0.02;
/// A polygon with fewer true points under it is not scored.
const MIN_POINTS: usize = 30;

/// Scores of a polygon map.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlaneScore {
    /// Area-weighted mean angle between map and true normals, degrees.
    pub angle_mean_deg: f64,
    /// Area-weighted mean distance of polygon centroids from the true planes, m.
    pub offset_mean_m: f64,
    /// Polygons scored, and polygons without enough true surface under them.
    pub scored: usize,
    pub unmatched: usize,
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Whether `p` (on or near the polygon's plane) projects inside its convex outline.
fn inside(poly: &Polygon, p: [f64; 3]) -> bool {
    let n = poly.plane.normal;
    let k = poly.outline.len();
    (0..k).all(|i| {
        let a = poly.outline[i];
        let b = poly.outline[(i + 1) % k];
        let e = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let d = [p[0] - a[0], p[1] - a[1], p[2] - a[2]];
        // Counter-clockwise about n: inside is to the left of every edge.
        let c = [
            e[1] * d[2] - e[2] * d[1],
            e[2] * d[0] - e[0] * d[2],
            e[0] * d[1] - e[1] * d[0],
        ];
        dot(c, n) >= 0.0
    })
}

/// Scores `polygons` against the true surface points `truth`; `None` when no polygon has
/// enough true surface under it.
pub fn score(polygons: &[Polygon], truth: &[[f64; 3]]) -> Option<PlaneScore> {
    let (mut angle, mut offset, mut weight) = (0.0, 0.0, 0.0);
    let (mut scored, mut unmatched) = (0, 0);
    for poly in polygons {
        if poly.outline.len() < 3 {
            unmatched += 1;
            continue;
        }
        let under: Vec<[f64; 3]> = truth
            .iter()
            .filter(|p| poly.plane.distance(**p).abs() <= BAND_M && inside(poly, **p))
            .copied()
            .collect();
        // Start near the polygon's own plane, so that a second surface inside the band (the
        // floor at a wall's foot, the other wall of a corner) does not pull the fit; then
        // refit twice to the points near the fit.
        let near = |plane: &Plane, within: f64| -> Vec<[f64; 3]> {
            under
                .iter()
                .filter(|p| plane.distance(**p).abs() <= within)
                .copied()
                .collect()
        };
        let mut start = near(&poly.plane, START_M);
        if start.len() < MIN_POINTS {
            start.clone_from(&under);
        }
        let mut fitted = Plane::fit(&start);
        for _ in 0..2 {
            fitted = fitted.and_then(|f| {
                let pts = near(&f, REFIT_M);
                (pts.len() >= MIN_POINTS)
                    .then(|| Plane::fit(&pts))
                    .flatten()
            });
        }
        let Some(t) = fitted.filter(|_| under.len() >= MIN_POINTS) else {
            unmatched += 1;
            continue;
        };
        let cos = dot(t.normal, poly.plane.normal).abs().min(1.0);
        angle += poly.area * cos.acos().to_degrees();
        offset += poly.area * t.distance(poly.centroid()).abs();
        weight += poly.area;
        scored += 1;
    }
    (scored > 0 && weight > 0.0).then(|| PlaneScore {
        angle_mean_deg: angle / weight,
        offset_mean_m: offset / weight,
        scored,
        unmatched,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A square polygon of side 1 m on the plane z = h, tilted by `tilt` rad about x.
    fn square(h: f64, tilt: f64) -> Polygon {
        let (s, c) = tilt.sin_cos();
        let corner = |x: f64, y: f64| [x, c * y, h + s * y];
        let outline = vec![
            corner(0.0, 0.0),
            corner(1.0, 0.0),
            corner(1.0, 1.0),
            corner(0.0, 1.0),
        ];
        let normal = [0.0, -s, c];
        Polygon {
            plane: Plane {
                normal,
                offset: -dot(normal, outline[0]),
            },
            outline,
            area: 1.0,
            frames: 1,
        }
    }

    #[test]
    fn angle_and_offset_of_a_hand_made_case() {
        // The true floor z = 0 sampled every 5 cm over 2 m × 2 m, and a wall x = 1.5 beside it.
        let mut truth = Vec::new();
        for i in 0..40 {
            for j in 0..40 {
                truth.push([i as f64 * 0.05, j as f64 * 0.05, 0.0]);
                truth.push([1.5, i as f64 * 0.05, j as f64 * 0.05]);
            }
        }
        // A polygon 3 cm above the floor and level: no angle, 3 cm offset.
        let s = score(&[square(0.03, 0.0)], &truth).unwrap();
        assert!(s.angle_mean_deg < 1e-9, "{s:?}");
        assert!((s.offset_mean_m - 0.03).abs() < 1e-9, "{s:?}");
        // Tilted by 2°: the angle is 2°; its centroid (0.5, ~0.5) is ~1.7 cm up.
        let s = score(&[square(0.0, 2f64.to_radians())], &truth).unwrap();
        assert!((s.angle_mean_deg - 2.0).abs() < 1e-6, "{s:?}");
        assert!(
            (s.offset_mean_m - 0.5 * 2f64.to_radians().sin()).abs() < 1e-3,
            "{s:?}"
        );
        // The area weights: a 1 m² level polygon and a 3 m² one 2 cm up.
        let mut big = square(0.02, 0.0);
        big.area = 3.0;
        let s = score(&[square(0.0, 0.0), big], &truth).unwrap();
        assert!((s.offset_mean_m - 0.015).abs() < 1e-9, "{s:?}");
        assert_eq!((s.scored, s.unmatched), (2, 0));
        // Under the polygon the camera saw only a 30 cm patch of floor, and a wall stands
        // across it (x = 0.5, every 2.5 cm along y, 5 cm steps up): the wall's foot, within
        // the band, outnumbers the floor and must not be taken for the surface.
        let mut walled: Vec<[f64; 3]> = (0..36)
            .map(|k| [(k % 6) as f64 * 0.05, (k / 6) as f64 * 0.05, 0.0])
            .collect();
        for i in 0..40 {
            for k in 1..20 {
                walled.push([0.5, i as f64 * 0.025, k as f64 * 0.05]);
            }
        }
        let s = score(&[square(0.0, 0.0)], &walled).unwrap();
        assert!(s.angle_mean_deg < 1e-6 && s.offset_mean_m < 1e-9, "{s:?}");
        // Nothing under a polygon in the air.
        assert!(score(&[square(1.0, 0.0)], &truth).is_none());
    }
}
