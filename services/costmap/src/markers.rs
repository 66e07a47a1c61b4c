//! What rviz2 / Foxglove draw of the site: each camera's footprint on the floor,
//! its zones, the path segments and the routes through them, as one
//! `visualization_msgs/MarkerArray` in the map frame (latched on the output's markers topic, `isochron_ros2::spec::MARKERS`).
//!
//! Namespaces: `cameras` (footprint outlines, with the camera id as a label),
//! `zones`, `segments` (outlines with names) and `routes` (a line through the
//! centres of a route's segments, in order). The first marker deletes what an
//! earlier array drew, so a republished array replaces the last one.

use isochron_config::{LoadedConfig, SegmentConfig};
use isochron_ros2::msgs::{ColorRGBA, Header, Marker, MarkerArray, Point, Pose, Vector3};

use crate::bridge::Bridge;

/// Points per image edge when a camera's frame border is mapped to the floor.
const EDGE_SAMPLES: usize = 16;
/// Line width, metres.
const LINE_M: f64 = 0.05;
/// Label height, metres.
const TEXT_M: f64 = 0.3;

/// The frame size of camera `k`: the config's `width`/`height`, else the size its
/// activity reports.
fn frame_size(loaded: &LoadedConfig, bridge: &Bridge, k: usize) -> Option<(u32, u32)> {
    let cam = loaded.config.cameras.get(k)?;
    if let (Some(w), Some(h)) = (cam.width, cam.height) {
        return Some((w, h));
    }
    let latest = bridge.cameras.get(k)?.latest.as_ref()?;
    (latest.header.frame_width > 0 && latest.header.frame_height > 0)
        .then_some((latest.header.frame_width, latest.header.frame_height))
}

/// The outline of an image polygon on the floor: its edges sampled and mapped,
/// leaving out points at or beyond the horizon; `None` if fewer than 3 remain.
fn on_floor(bridge: &Bridge, k: usize, polygon: &[[f64; 2]]) -> Option<Vec<[f64; 2]>> {
    let h = bridge.cameras.get(k)?.homography.as_ref()?;
    let n = polygon.len();
    let mut out = Vec::new();
    for i in 0..n {
        let (a, b) = (polygon[i], polygon[(i + 1) % n]);
        for s in 0..EDGE_SAMPLES {
            let t = s as f64 / EDGE_SAMPLES as f64;
            if let Some(p) = h.apply([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]) {
                out.push(p);
            }
        }
    }
    (out.len() >= 3).then_some(out)
}

/// The floor outline of a path segment (its polygon, or its camera zone mapped).
fn segment_outline(
    loaded: &LoadedConfig,
    bridge: &Bridge,
    seg: &SegmentConfig,
) -> Option<Vec<[f64; 2]>> {
    if let Some(poly) = &seg.polygon_m {
        return Some(poly.clone());
    }
    let (camera, zone) = (seg.camera.as_ref()?, seg.zone.as_ref()?);
    let k = loaded.config.cameras.iter().position(|c| &c.id == camera)?;
    let (w, h) = frame_size(loaded, bridge, k)?;
    let zones = loaded.config.cameras[k].zones_or_default(w, h);
    let z = zones.iter().find(|z| &z.name == zone)?;
    on_floor(bridge, k, &z.polygon)
}

fn centroid(poly: &[[f64; 2]]) -> [f64; 2] {
    let n = poly.len().max(1) as f64;
    let (x, y) = poly
        .iter()
        .fold((0.0, 0.0), |(x, y), p| (x + p[0], y + p[1]));
    [x / n, y / n]
}

fn point(p: [f64; 2]) -> Point {
    Point {
        x: p[0],
        y: p[1],
        z: 0.0,
    }
}

fn rgba(r: f32, g: f32, b: f32) -> ColorRGBA {
    ColorRGBA { r, g, b, a: 1.0 }
}

/// The markers of the site now (footprints and zones of cameras whose frame size
/// is not known yet are left out until it is).
pub fn site_markers(loaded: &LoadedConfig, bridge: &Bridge, header: &Header) -> MarkerArray {
    let mut markers = vec![Marker {
        header: header.clone(),
        action: Marker::DELETEALL,
        ..Default::default()
    }];
    let mut line = |ns: &str, color: ColorRGBA, closed: bool, pts: &[[f64; 2]]| {
        let mut points: Vec<Point> = pts.iter().copied().map(point).collect();
        if closed && let Some(&first) = points.first() {
            points.push(first);
        }
        let id = markers.iter().filter(|m| m.ns == ns).count() as i32;
        markers.push(Marker {
            header: header.clone(),
            ns: ns.into(),
            id,
            kind: Marker::LINE_STRIP,
            action: Marker::ADD,
            pose: Pose::default(),
            scale: Vector3 {
                x: LINE_M,
                ..Default::default()
            },
            color,
            points,
            ..Default::default()
        });
    };
    let mut labels = Vec::new();
    for (k, cam) in loaded.config.cameras.iter().enumerate() {
        let Some((w, h)) = frame_size(loaded, bridge, k) else {
            continue;
        };
        let (fw, fh) = (w as f64, h as f64);
        if let Some(outline) = on_floor(bridge, k, &[[0.0, 0.0], [fw, 0.0], [fw, fh], [0.0, fh]]) {
            line("cameras", rgba(0.2, 0.6, 1.0), true, &outline);
            labels.push(("cameras", cam.id.clone(), centroid(&outline)));
        }
        for z in &cam.zones {
            if let Some(outline) = on_floor(bridge, k, &z.polygon) {
                line("zones", rgba(1.0, 0.8, 0.0), true, &outline);
            }
        }
    }
    let c = &loaded.config.costmap;
    let mut centres = std::collections::HashMap::new();
    for seg in &c.segments {
        if let Some(outline) = segment_outline(loaded, bridge, seg) {
            line("segments", rgba(0.2, 0.9, 0.3), true, &outline);
            labels.push(("segments", seg.name.clone(), centroid(&outline)));
            centres.insert(seg.name.clone(), centroid(&outline));
        }
    }
    for route in &c.routes {
        let pts: Vec<[f64; 2]> = route
            .segments
            .iter()
            .filter_map(|s| centres.get(s).copied())
            .collect();
        if pts.len() == route.segments.len() && !pts.is_empty() {
            line("routes", rgba(1.0, 0.3, 0.3), false, &pts);
        }
    }
    for (ns, text, at) in labels {
        let id = markers
            .iter()
            .filter(|m| m.ns == format!("{ns}_labels"))
            .count() as i32;
        markers.push(Marker {
            header: header.clone(),
            ns: format!("{ns}_labels"),
            id,
            kind: Marker::TEXT_VIEW_FACING,
            action: Marker::ADD,
            pose: Pose {
                position: point(at),
                ..Default::default()
            },
            scale: Vector3 {
                z: TEXT_M,
                ..Default::default()
            },
            color: rgba(1.0, 1.0, 1.0),
            text,
            ..Default::default()
        });
    }
    MarkerArray { markers }
}

/// The frame sizes markers depend on, to republish when one becomes known.
pub fn marker_key(loaded: &LoadedConfig, bridge: &Bridge) -> Vec<Option<(u32, u32)>> {
    (0..loaded.config.cameras.len())
        .map(|k| frame_size(loaded, bridge, k))
        .collect()
}
