//! What a pose estimate's covariance of (x, y, θ) says about its position: the spread along
//! its worst direction, and how an error measured against the truth compares with it.

/// The position's standard deviation along its worst direction, m: the square root of the
/// larger eigenvalue of the covariance's x, y block (0 for a degenerate one).
pub fn position_sigma(covariance: &[[f64; 3]; 3]) -> f64 {
    let (a, b, c) = (covariance[0][0], covariance[0][1], covariance[1][1]);
    let mid = 0.5 * (a + c);
    let half = (0.25 * (a - c) * (a - c) + b * b).sqrt();
    (mid + half).max(0.0).sqrt()
}

/// The normalised estimation error squared of a position error `e` (m) under the
/// covariance's x, y block: e' P⁻¹ e, which averages 2 (its degrees of freedom) when the
/// covariance is the error's true one, and more when the filter is overconfident
/// (Bar-Shalom, *Estimation with Applications to Tracking and Navigation*, §5.4). `None`
/// where the block is singular.
pub fn position_nees(covariance: &[[f64; 3]; 3], e: [f64; 2]) -> Option<f64> {
    let (a, b, c) = (covariance[0][0], covariance[0][1], covariance[1][1]);
    let det = a * c - b * b;
    if !(det > 1e-18 && a > 0.0 && c > 0.0) {
        return None;
    }
    Some((c * e[0] * e[0] - 2.0 * b * e[0] * e[1] + a * e[1] * e[1]) / det)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A covariance of the position alone.
    fn xy(a: f64, b: f64, c: f64) -> [[f64; 3]; 3] {
        [[a, b, 0.0], [b, c, 0.0], [0.0, 0.0, 0.01]]
    }

    #[test]
    fn sigma_is_the_worst_direction() {
        // Axis-aligned: the larger of the two.
        assert!((position_sigma(&xy(0.04, 0.0, 0.01)) - 0.2).abs() < 1e-12);
        // Rotated by 45°: eigenvalues 0.05 ± 0.03, so √0.08.
        let s = position_sigma(&xy(0.05, 0.03, 0.05));
        assert!((s - 0.08f64.sqrt()).abs() < 1e-12, "{s}");
        assert_eq!(position_sigma(&xy(0.0, 0.0, 0.0)), 0.0);
    }

    #[test]
    fn nees_weighs_the_error_by_the_covariance() {
        // σx = 0.1, σy = 0.2: an error of one σ along each axis scores 1 each.
        let p = xy(0.01, 0.0, 0.04);
        assert!((position_nees(&p, [0.1, 0.0]).unwrap() - 1.0).abs() < 1e-12);
        assert!((position_nees(&p, [0.0, 0.2]).unwrap() - 1.0).abs() < 1e-12);
        assert!((position_nees(&p, [0.1, 0.2]).unwrap() - 2.0).abs() < 1e-12);
        // Correlated: e = (1, 1) under [[2, 1], [1, 2]] is e' P⁻¹ e = (2 - 2 + 2) / 3.
        let q = xy(2.0, 1.0, 2.0);
        assert!((position_nees(&q, [1.0, 1.0]).unwrap() - 2.0 / 3.0).abs() < 1e-12);
        assert_eq!(position_nees(&xy(0.0, 0.0, 0.0), [0.1, 0.0]), None);
    }
}
