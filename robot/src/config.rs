//! Checks shared by the stack's typed options structs: each module's `validate` refuses a
//! value it cannot run with, naming the dotted key and what was expected.

/// A `(key, expectation)` error of an options struct.
pub type ConfigError = (String, String);

/// `key` below `prefix`, or `key` alone when the prefix is empty.
pub fn below(prefix: &str, key: &str) -> String {
    if prefix.is_empty() {
        key.to_string()
    } else {
        format!("{prefix}.{key}")
    }
}

/// Checks that each `(key, value, lo, hi)` is finite and within `[lo, hi]`; keys are named
/// below `prefix` (`localization.mcl` gives `localization.mcl.z_hit`).
pub fn check_ranges(prefix: &str, checks: &[(&str, f64, f64, f64)]) -> Result<(), ConfigError> {
    for &(k, v, lo, hi) in checks {
        if !(v.is_finite() && v >= lo && v <= hi) {
            return Err((
                below(prefix, k),
                format!(
                    "expected a value in [{lo}, {hi}], found {}",
                    futago_msgs::shown(v)
                ),
            ));
        }
    }
    Ok(())
}

/// Checks that each `(key, count, lo, hi)` lies within `[lo, hi]`.
pub fn check_counts(
    prefix: &str,
    checks: &[(&str, usize, usize, usize)],
) -> Result<(), ConfigError> {
    for &(k, v, lo, hi) in checks {
        if !(lo..=hi).contains(&v) {
            return Err((
                below(prefix, k),
                format!("expected a whole number in [{lo}, {hi}], found {v}"),
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_name_the_key() {
        assert!(check_ranges("a", &[("x", 1.0, 0.0, 2.0)]).is_ok());
        let e = check_ranges("a.b", &[("x", 1.0, 0.0, 2.0), ("y", f64::NAN, 0.0, 1.0)]);
        assert_eq!(e.unwrap_err().0, "a.b.y");
        let e = check_counts("m", &[("n", 0, 1, 10)]).unwrap_err();
        assert_eq!(e.0, "m.n");
        assert!(e.1.contains("[1, 10]"));
    }
}
