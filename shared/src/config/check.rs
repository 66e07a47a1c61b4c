//! Value checks the sections' `validate` share.

use super::{Invalid, Polygon};

/// Errors unless `lo <= v <= hi`.
pub fn check_range(key: &str, v: f64, lo: f64, hi: f64) -> Result<(), Invalid> {
    if v.is_finite() && v >= lo && v <= hi {
        Ok(())
    } else {
        Err(Invalid::new(
            key,
            format!("expected a number from {lo} to {hi}, found {v}"),
        ))
    }
}

/// Errors unless `v > 0`.
pub fn check_positive(key: &str, v: f64) -> Result<(), Invalid> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(Invalid::new(
            key,
            format!("expected a number > 0, found {v}"),
        ))
    }
}

/// Errors unless `poly` has at least 3 points, all finite.
pub(super) fn check_polygon(key: &str, poly: &Polygon) -> Result<(), Invalid> {
    if poly.len() < 3 {
        return Err(Invalid::new(
            key,
            format!(
                "expected a polygon of at least 3 [x, y] points, found {}",
                poly.len()
            ),
        ));
    }
    if poly.iter().flatten().any(|v| !v.is_finite()) {
        return Err(Invalid::new(key, "expected finite coordinates"));
    }
    Ok(())
}
