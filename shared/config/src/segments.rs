//! `[[costmap.segment]]` and `[[costmap.route]]`: the path segments and routes of
//! planning (the paper's segments p and routes), and their checks.

use serde::{Deserialize, Serialize};

use super::{CameraConfig, Invalid, check_polygon};

/// `[[costmap.segment]]`: a path segment p — a floor polygon, or a camera's zone.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SegmentConfig {
    /// Name (1 to 32 bytes), unique.
    pub name: String,
    /// Outline on the floor, `[[x, y], ...]`, metres in the map frame (at least 3
    /// points); its blocks are those of every camera whose centre lands inside.
    #[serde(default)]
    pub polygon_m: Option<Vec<[f64; 2]>>,
    /// Instead of `polygon_m`: a camera ...
    #[serde(default)]
    pub camera: Option<String>,
    /// ... and one of its zones (`"all"` for a camera without zones).
    #[serde(default)]
    pub zone: Option<String>,
}

/// `[[costmap.route]]`: a route, the ordered path segments a robot passes.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RouteConfig {
    /// Name (1 to 32 bytes), unique.
    pub name: String,
    /// Segment names, in the order the robot passes them (at least one).
    pub segments: Vec<String>,
}

/// Longest segment or route name, in bytes (the planning service's fixed width).
pub const PLAN_NAME_LEN: usize = isochron_wire::PLAN_NAME_LEN;

/// Each `[[costmap.segment]]`: a unique name, and a floor polygon (with cameras on
/// the floor) or a camera's zone.
pub(super) fn validate_segments(
    segments: &[SegmentConfig],
    cameras: &[CameraConfig],
) -> Result<(), Invalid> {
    let located = cameras.iter().any(|cam| !cam.floor_points.is_empty());
    for (i, seg) in segments.iter().enumerate() {
        let key = |k: &str| format!("costmap.segment[{i}].{k}");
        check_plan_name(
            &key("name"),
            "segment",
            &seg.name,
            segments[..i].iter().map(|s| s.name.as_str()),
        )?;
        match (&seg.polygon_m, &seg.camera, &seg.zone) {
            (Some(poly), None, None) => {
                check_polygon(&key("polygon_m"), poly)?;
                if !located {
                    return Err(Invalid::new(
                        key("polygon_m"),
                        "a floor polygon needs cameras on the floor: give at least one [[camera]] floor_points",
                    ));
                }
            }
            (None, Some(camera), Some(zone)) => {
                let Some(cam) = cameras.iter().find(|cam| &cam.id == camera) else {
                    return Err(Invalid::new(
                        key("camera"),
                        format!("no [[camera]] with id \"{camera}\""),
                    ));
                };
                let known = if cam.zones.is_empty() {
                    zone == "all"
                } else {
                    cam.zones.iter().any(|z| &z.name == zone)
                };
                if !known {
                    return Err(Invalid::new(
                        key("zone"),
                        format!("camera \"{camera}\" has no zone \"{zone}\""),
                    ));
                }
            }
            _ => {
                return Err(Invalid::new(
                    key("name"),
                    "expected either polygon_m, or camera and zone",
                ));
            }
        }
    }
    Ok(())
}

/// Each `[[costmap.route]]`: a unique name and known `segments`.
pub(super) fn validate_routes(
    routes: &[RouteConfig],
    segments: &[SegmentConfig],
) -> Result<(), Invalid> {
    for (i, route) in routes.iter().enumerate() {
        let key = |k: &str| format!("costmap.route[{i}].{k}");
        check_plan_name(
            &key("name"),
            "route",
            &route.name,
            routes[..i].iter().map(|r| r.name.as_str()),
        )?;
        if route.segments.is_empty() {
            return Err(Invalid::new(
                key("segments"),
                "expected at least one segment name",
            ));
        }
        for (j, name) in route.segments.iter().enumerate() {
            if !segments.iter().any(|s| &s.name == name) {
                return Err(Invalid::new(
                    format!("costmap.route[{i}].segments[{j}]"),
                    format!("no [[costmap.segment]] named \"{name}\""),
                ));
            }
        }
    }
    Ok(())
}

/// A segment or route name: 1 to [`PLAN_NAME_LEN`] bytes, no ',' (names are listed
/// with commas), and not one of the `earlier` names of its kind (`what`).
fn check_plan_name<'a>(
    key: &str,
    what: &str,
    name: &str,
    mut earlier: impl Iterator<Item = &'a str>,
) -> Result<(), Invalid> {
    if name.is_empty() || name.len() > PLAN_NAME_LEN || name.contains(',') {
        return Err(Invalid::new(
            key,
            "expected a name of 1 to 32 bytes without ','",
        ));
    }
    if earlier.any(|e| e == name) {
        return Err(Invalid::new(
            key,
            format!("{what} name \"{name}\" is used twice"),
        ));
    }
    Ok(())
}
