//! Geometry the stack's modules share: distance transforms of occupancy grids ([`grid`]), their
//! iso-lines ([`contour`]), distance fields of 3D surfaces ([`distance_field`]) and
//! plane fits in point clouds ([`plane`]), a distance test without the maths library's
//! `hypot` ([`closer_than`]) and the least distance from a point to a run of points
//! ([`least_squared_distance`]). Pose arithmetic and interpolation live with the pose
//! type itself, in [`futago_msgs`], where the command's metrics and the log readers use them too.

pub mod contour;
pub mod distance_field;
pub mod grid;
pub mod plane;

/// `x.floor() as i64` without the maths library's `floor` (a call on baseline x86-64, whose
/// SSE2 has no rounding instruction; 2-3 % of a SLAM or 3D-survey run's samples, where grids
/// find the cell of each point): the conversion truncates, and is one too high where it
/// rounded up (below zero). The same for every `x`: NaN gives 0 and values past `i64`'s
/// range saturate, as the cast does.
#[inline]
pub fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) > x {
        t.saturating_sub(1)
    } else {
        t
    }
}

/// The squared distance from `q` to `p`: the squares of the differences summed in axis order
/// (the value [`least_squared_distance`] compares, so a search can find the point it came
/// from by equality).
#[inline]
pub fn squared_distance<const K: usize>(p: &[f64; K], q: &[f64; K]) -> f64 {
    let mut d = (p[0] - q[0]).powi(2);
    for k in 1..K {
        d += (p[k] - q[k]).powi(2);
    }
    d
}

/// The least [`squared_distance`] from `q` to `points` (infinite for none), over four running
/// minima, one for each of four points in turn, that the compiler can keep in vector
/// registers: one running minimum made each comparison wait for the one before, and a minimum
/// is exact in any order. The inner loop of the matchers' nearest-point searches (the ICP's
/// point map, the 3D maps' scores), where a lookup cell holds tens to hundreds of points.
pub fn least_squared_distance<const K: usize>(points: &[[f64; K]], q: &[f64; K]) -> f64 {
    let mut m = [f64::INFINITY; 4];
    let quads = points.chunks_exact(4);
    for p in quads.remainder() {
        let d = squared_distance(p, q);
        m[0] = if d < m[0] { d } else { m[0] };
    }
    for quad in quads {
        for (m, p) in m.iter_mut().zip(quad) {
            let d = squared_distance(p, q);
            *m = if d < *m { d } else { *m };
        }
    }
    m[0].min(m[1]).min(m[2].min(m[3]))
}

/// Whether (dx, dy) lies closer than `radius` to the origin: `dx.hypot(dy) < radius`, decided
/// by the squares where they clear the boundary by far more than either's rounding, and by
/// `hypot` itself only near it. (The maths library's `hypot` was a tenth of SLAM's time in
/// the scan normals' neighbour tests, and 4.5 % of `hall-crowd`'s samples in scoring which
/// people a scan saw.)
pub fn closer_than(dx: f64, dy: f64, radius: f64) -> bool {
    match by_squares(dx, dy, radius) {
        Some(inside) => inside,
        None => dx.hypot(dy) < radius,
    }
}

/// Whether (dx, dy) lies within `radius` of the origin: `dx.hypot(dy) <= radius`, decided as
/// [`closer_than`] is.
pub fn within(dx: f64, dy: f64, radius: f64) -> bool {
    match by_squares(dx, dy, radius) {
        Some(inside) => inside,
        None => dx.hypot(dy) <= radius,
    }
}

/// Whether (dx, dy) lies inside the circle of `radius`, where the squares say so beyond any
/// rounding of theirs or of `hypot` (a relative 10⁻⁹, some ten million roundings); none near
/// the circle, for a radius whose square is not a normal number, and for NaN.
fn by_squares(dx: f64, dy: f64, radius: f64) -> Option<bool> {
    let (d2, r2) = (dx * dx + dy * dy, radius * radius);
    if r2.is_nan() || r2 <= 1e-290 {
        None
    } else if d2 < r2 * (1.0 - 1e-9) {
        Some(true)
    } else if d2 > r2 * (1.0 + 1e-9) {
        Some(false)
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `floor_i64` is the floor's cast: at random over many scales of both signs, at
    /// integers and a rounding either side of them, at zero's two signs, past `i64`'s range,
    /// and for the infinities and NaN.
    #[test]
    fn floor_i64_is_the_cast_of_the_floor() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let mut cases = vec![
            0.0,
            -0.0,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::MIN_POSITIVE,
            -f64::MIN_POSITIVE,
            i64::MAX as f64,
            (i64::MAX as f64).next_down(),
            i64::MIN as f64,
            (i64::MIN as f64).next_down(),
            -9.3e18,
            9.3e18,
            1e300,
            -1e300,
        ];
        for _ in 0..200_000 {
            let x = rng.random_range(-1.0..1.0) * 10f64.powi(rng.random_range(-12..20));
            let n = x.round();
            cases.extend([x, n, n.next_up(), n.next_down()]);
        }
        for x in cases {
            assert_eq!(floor_i64(x), x.floor() as i64, "{x:e}");
        }
    }

    /// The neighbour tests by squares agree with `hypot`: at random, on the boundary and a
    /// rounding either side of it, for tiny radii, and for infinite and NaN offsets.
    #[test]
    fn closer_than_and_within_agree_with_hypot() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        let mut near = 0;
        for k in 0..200_000 {
            let r: f64 = if k % 10 == 0 {
                1e-150 * rng.random_range(0.001..2.0)
            } else {
                rng.random_range(0.001..2.0)
            };
            let a: f64 = rng.random_range(-3.2..3.2);
            // Half the offsets at the radius to a few roundings, half anywhere.
            let d = if rng.random_bool(0.5) {
                r * (1.0 + rng.random_range(-4i32..=4) as f64 * f64::EPSILON)
            } else {
                r * rng.random_range(0.0..1.5)
            };
            let (dx, dy) = (d * a.cos(), d * a.sin());
            assert_eq!(closer_than(dx, dy, r), dx.hypot(dy) < r, "{dx} {dy} {r}");
            assert_eq!(within(dx, dy, r), dx.hypot(dy) <= r, "{dx} {dy} {r}");
            near += usize::from((dx.hypot(dy) - r).abs() <= 4.0 * f64::EPSILON * r);
        }
        assert!(near > 10_000, "{near} on the boundary");
        for (dx, dy) in [
            (f64::INFINITY, 0.0),
            (f64::NAN, 0.1),
            (0.0, f64::NEG_INFINITY),
            (0.1, 0.0),
        ] {
            assert_eq!(closer_than(dx, dy, 0.1), dx.hypot(dy) < 0.1);
            assert_eq!(within(dx, dy, 0.1), dx.hypot(dy) <= 0.1);
        }
    }
}
