//! Geometry the stack's modules share: distance transforms of occupancy grids ([`grid`]), their
//! iso-lines ([`contour`]), distance fields of 3D surfaces ([`distance_field`]) and
//! plane fits in point clouds ([`plane`]), and a distance test without the maths library's
//! `hypot` ([`closer_than`]). Pose arithmetic and interpolation live with the pose
//! type itself, in [`futago_msgs`], where the command's metrics and the log readers use them too.

pub mod contour;
pub mod distance_field;
pub mod grid;
pub mod plane;

/// Whether (dx, dy) lies closer than `radius` to the origin: `dx.hypot(dy) < radius`, decided
/// by the squares where they clear the boundary by far more than either's rounding, and by
/// `hypot` itself only near it. (The maths library's `hypot` was a tenth of SLAM's time in
/// the scan normals' neighbour tests, and 4.5 % of `hall-crowd`'s samples in scoring which
/// people a scan saw.)
pub fn closer_than(dx: f64, dy: f64, radius: f64) -> bool {
    let (d2, r2) = (dx * dx + dy * dy, radius * radius);
    if d2 < r2 * (1.0 - 1e-9) {
        return true;
    }
    if d2 > r2 * (1.0 + 1e-9) {
        return false;
    }
    dx.hypot(dy) < radius
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The neighbour test by squares agrees with `hypot`: at random, on the boundary and a
    /// rounding either side of it, and for infinite and NaN offsets.
    #[test]
    fn closer_than_agrees_with_hypot() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        let mut near = 0;
        for _ in 0..200_000 {
            let r: f64 = rng.random_range(0.001..2.0);
            let a: f64 = rng.random_range(-3.2..3.2);
            // Half the offsets at the radius to a few roundings, half anywhere.
            let d = if rng.random_bool(0.5) {
                r * (1.0 + rng.random_range(-4i32..=4) as f64 * f64::EPSILON)
            } else {
                rng.random_range(0.0..3.0)
            };
            let (dx, dy) = (d * a.cos(), d * a.sin());
            assert_eq!(closer_than(dx, dy, r), dx.hypot(dy) < r, "{dx} {dy} {r}");
            near += usize::from((dx.hypot(dy) - r).abs() <= 4.0 * f64::EPSILON * r);
        }
        assert!(near > 10_000, "{near} on the boundary");
        for (dx, dy) in [
            (f64::INFINITY, 0.0),
            (f64::NAN, 0.1),
            (0.0, f64::NEG_INFINITY),
        ] {
            assert_eq!(closer_than(dx, dy, 0.1), dx.hypot(dy) < 0.1);
        }
    }
}
