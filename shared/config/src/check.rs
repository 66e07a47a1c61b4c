//! Value checks the sections' `validate` share.

use super::Invalid;

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

/// Checks a section's DDS settings: `<section>.ros_domain_id` 0 to 232, and
/// `<section>.dds_interfaces` IP addresses (`example` shows one in the message).
pub(super) fn check_dds(
    section: &str,
    ros_domain_id: Option<u16>,
    dds_interfaces: &[String],
    example: &str,
) -> Result<(), Invalid> {
    if let Some(d) = ros_domain_id {
        check_range(&format!("{section}.ros_domain_id"), d as f64, 0.0, 232.0)?;
    }
    for (i, addr) in dds_interfaces.iter().enumerate() {
        if addr.parse::<std::net::IpAddr>().is_err() {
            return Err(Invalid::new(
                format!("{section}.dds_interfaces[{i}]"),
                format!(
                    "expected the IP address of a network interface such as \"{example}\", found \"{addr}\""
                ),
            ));
        }
    }
    Ok(())
}

/// Errors unless there are at least `min` of the `found` items; `expected` says
/// what is expected, e.g. "a polygon of at least 3 [x, y] points".
pub(super) fn check_at_least(
    key: &str,
    found: usize,
    min: usize,
    expected: &str,
) -> Result<(), Invalid> {
    if found < min {
        return Err(Invalid::new(
            key,
            format!("expected {expected}, found {found}"),
        ));
    }
    Ok(())
}

/// Errors unless `poly` has at least 3 points, all finite, and is simple: no two
/// edges that are not neighbours cross or touch (a bow tie or figure eight has no
/// well-defined inside).
pub(super) fn check_polygon(key: &str, poly: &[[f64; 2]]) -> Result<(), Invalid> {
    check_at_least(key, poly.len(), 3, "a polygon of at least 3 [x, y] points")?;
    if poly.iter().flatten().any(|v| !v.is_finite()) {
        return Err(Invalid::new(key, "expected finite coordinates"));
    }
    if let Some((a, b)) = crossing_edges(poly) {
        let n = poly.len();
        let edge = |i: usize| format!("{:?}–{:?}", poly[i], poly[(i + 1) % n]);
        return Err(Invalid::new(
            key,
            format!(
                "expected a simple polygon (no crossing edges), found edge {} crossing edge {}",
                edge(a),
                edge(b)
            ),
        ));
    }
    Ok(())
}

/// The first two non-neighbouring edges of `poly` (closed, edge `i` from point `i`
/// to point `i + 1`) that cross or touch, by their first points' indices. Repeated
/// consecutive points (and a closing point equal to the first) are zero-length
/// edges and are skipped.
fn crossing_edges(poly: &[[f64; 2]]) -> Option<(usize, usize)> {
    let n = poly.len();
    // Edges of positive length, by the index of their first point.
    let edges: Vec<usize> = (0..n).filter(|&i| poly[i] != poly[(i + 1) % n]).collect();
    let m = edges.len();
    if m < 4 {
        return None; // a triangle (or less) cannot cross itself
    }
    let seg = |k: usize| (poly[edges[k]], poly[(edges[k] + 1) % n]);
    for a in 0..m {
        // Edge a's neighbours are a - 1 and a + 1 (wrapping): they share a point.
        for b in a + 2..m {
            if a == 0 && b == m - 1 {
                continue;
            }
            let (p, q) = seg(a);
            let (r, s) = seg(b);
            if segments_meet(p, q, r, s) {
                return Some((edges[a], edges[b]));
            }
        }
    }
    None
}

/// True when segments `pq` and `rs` share at least one point.
fn segments_meet(p: [f64; 2], q: [f64; 2], r: [f64; 2], s: [f64; 2]) -> bool {
    let orient = |a: [f64; 2], b: [f64; 2], c: [f64; 2]| {
        let v = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
        if v > 0.0 {
            1
        } else if v < 0.0 {
            -1
        } else {
            0
        }
    };
    // c on segment ab, given a, b, c collinear.
    let on = |a: [f64; 2], b: [f64; 2], c: [f64; 2]| {
        c[0] >= a[0].min(b[0])
            && c[0] <= a[0].max(b[0])
            && c[1] >= a[1].min(b[1])
            && c[1] <= a[1].max(b[1])
    };
    let (o1, o2, o3, o4) = (
        orient(p, q, r),
        orient(p, q, s),
        orient(r, s, p),
        orient(r, s, q),
    );
    // A proper crossing, or an end point of one on the other.
    (o1 * o2 < 0 && o3 * o4 < 0)
        || (o1 == 0 && on(p, q, r))
        || (o2 == 0 && on(p, q, s))
        || (o3 == 0 && on(r, s, p))
        || (o4 == 0 && on(r, s, q))
}

/// True if `topic` is a ROS 2 topic name this bridge can publish on: `/`-separated
/// tokens of letters, digits and `_`, each starting with a letter or `_`.
pub fn is_valid_ros_topic(topic: &str) -> bool {
    let rest = topic.strip_prefix('/').unwrap_or(topic);
    !rest.is_empty()
        && rest.split('/').all(|tok| {
            !tok.is_empty()
                && !tok.contains("__")
                && tok.starts_with(|c: char| c.is_ascii_alphabetic() || c == '_')
                && tok.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn simple_polygons_pass_and_crossing_ones_name_the_edges() {
        let square = vec![[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]];
        assert!(check_polygon("k", &square).is_ok());
        // Concave, explicitly closed, with a repeated point: still simple.
        let concave = vec![
            [0.0, 0.0],
            [10.0, 0.0],
            [10.0, 10.0],
            [10.0, 10.0],
            [5.0, 3.0],
            [0.0, 10.0],
            [0.0, 0.0],
        ];
        assert!(check_polygon("k", &concave).is_ok());
        let triangle = vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]];
        assert!(check_polygon("k", &triangle).is_ok());

        let bow_tie = vec![[0.0, 0.0], [10.0, 10.0], [10.0, 0.0], [0.0, 10.0]];
        let err = check_polygon("camera[0].mask[0]", &bow_tie).unwrap_err();
        assert_eq!(err.key, "camera[0].mask[0]");
        assert!(
            err.message
                .starts_with("expected a simple polygon (no crossing edges)"),
            "{}",
            err.message
        );
        assert!(
            err.message.contains("[0.0, 0.0]–[10.0, 10.0]"),
            "{}",
            err.message
        );

        // A vertex touching a non-neighbouring edge (a pinched figure eight).
        let pinched = vec![
            [0.0, 0.0],
            [4.0, 0.0],
            [2.0, 2.0],
            [4.0, 4.0],
            [0.0, 4.0],
            [2.0, 2.0],
        ];
        assert!(check_polygon("k", &pinched).is_err());
        // An edge folding back over another (collinear overlap).
        let folded = vec![[0.0, 0.0], [10.0, 0.0], [5.0, 0.0], [5.0, 5.0]];
        assert!(check_polygon("k", &folded).is_err());
    }
}
