//! Reading a nav2_route GeoJSON graph into nodes and edges, refusing what cannot
//! be used (see the module doc of [`crate::route_graph`]).

use std::collections::HashMap;

use serde_json::{Map, Value};

use super::{GraphEdge, GraphId, GraphNode, Refusal, WIDTH_RANGE_M};
use crate::grid::Point;

/// A refusal located at a feature (before the file is named).
pub(super) struct Located {
    pub feature: Option<usize>,
    pub id: Option<String>,
    pub refusal: Refusal,
}

impl Located {
    fn at(feature: usize, properties: &Map<String, Value>, refusal: Refusal) -> Located {
        Located {
            feature: Some(feature),
            id: properties.get("id").map(|v| v.to_string()),
            refusal,
        }
    }

    fn file(refusal: Refusal) -> Located {
        Located {
            feature: None,
            id: None,
            refusal,
        }
    }
}

/// The frame nav2_route gives a node without `frame`.
const DEFAULT_FRAME: &str = "map";

/// Nodes, edges and the number of features that are neither, from `text`.
pub(super) fn read(
    text: &str,
    frame_id: &str,
) -> Result<(Vec<GraphNode>, Vec<GraphEdge>, usize), Located> {
    let json: Value =
        serde_json::from_str(text).map_err(|e| Located::file(Refusal::Json(e.to_string())))?;
    let features = json
        .get("features")
        .and_then(Value::as_array)
        .ok_or_else(|| Located::file(Refusal::NotFeatureCollection))?;
    let empty = Map::new();
    let mut nodes: Vec<GraphNode> = Vec::new();
    let mut node_of: HashMap<GraphId, usize> = HashMap::new();
    let mut edge_features = Vec::new();
    let mut ignored = 0;
    for (k, feature) in features.iter().enumerate() {
        let properties = feature
            .get("properties")
            .and_then(Value::as_object)
            .unwrap_or(&empty);
        let geometry_type = feature
            .get("geometry")
            .and_then(|g| g.get("type"))
            .and_then(Value::as_str);
        match geometry_type {
            Some("Point") => {
                let node = read_node(feature, properties, k, frame_id)
                    .map_err(|r| Located::at(k, properties, r))?;
                if let Some(&first) = node_of.get(&node.id) {
                    let refusal = Refusal::DuplicateNode {
                        id: node.id,
                        first: nodes[first].feature,
                    };
                    return Err(Located::at(k, properties, refusal));
                }
                node_of.insert(node.id, nodes.len());
                nodes.push(node);
            }
            Some("MultiLineString" | "LineString") => edge_features.push((k, feature, properties)),
            _ => ignored += 1,
        }
    }
    if nodes.is_empty() {
        return Err(Located::file(Refusal::Empty("nodes")));
    }
    if edge_features.is_empty() {
        return Err(Located::file(Refusal::Empty("edges")));
    }
    let mut edges: Vec<GraphEdge> = Vec::with_capacity(edge_features.len());
    let mut edge_of: HashMap<GraphId, usize> = HashMap::new();
    for (k, feature, properties) in edge_features {
        let edge = read_edge(feature, properties, k, &nodes, &node_of)
            .map_err(|r| Located::at(k, properties, r))?;
        if let Some(&first) = edge_of.get(&edge.id) {
            let refusal = Refusal::DuplicateEdge {
                id: edge.id,
                first: edges[first].feature,
            };
            return Err(Located::at(k, properties, refusal));
        }
        if let Some(&node) = node_of.get(&edge.id) {
            let refusal = Refusal::SharedId {
                id: edge.id,
                node: nodes[node].feature,
            };
            return Err(Located::at(k, properties, refusal));
        }
        edge_of.insert(edge.id, edges.len());
        edges.push(edge);
    }
    Ok((nodes, edges, ignored))
}

/// An id field: an integer 0 to 65535.
fn id_field(properties: &Map<String, Value>, field: &'static str) -> Result<GraphId, Refusal> {
    let name = field.trim_start_matches("properties.");
    let value = properties.get(name).ok_or_else(|| Refusal::Field {
        field,
        expected: "an integer id (0 to 65535), found none".into(),
    })?;
    if let Some(n) = value.as_u64() {
        return GraphId::try_from(n).map_err(|_| Refusal::IdOutOfRange {
            field,
            value: n.to_string(),
        });
    }
    if value.as_i64().is_some() {
        return Err(Refusal::IdOutOfRange {
            field,
            value: value.to_string(),
        });
    }
    Err(Refusal::Field {
        field,
        expected: format!("an integer id (0 to 65535), found {value}"),
    })
}

/// A point `[x, y, ...]` of finite numbers.
fn point(value: &Value) -> Option<Point> {
    let a = value.as_array()?;
    let x = a.first()?.as_f64()?;
    let y = a.get(1)?.as_f64()?;
    (x.is_finite() && y.is_finite()).then_some([x, y])
}

fn read_node(
    feature: &Value,
    properties: &Map<String, Value>,
    k: usize,
    frame_id: &str,
) -> Result<GraphNode, Refusal> {
    let id = id_field(properties, "properties.id")?;
    let position = feature
        .get("geometry")
        .and_then(|g| g.get("coordinates"))
        .and_then(point)
        .ok_or_else(|| Refusal::Field {
            field: "geometry.coordinates",
            expected: "a node's position [x, y] (finite numbers)".into(),
        })?;
    match properties.get("frame") {
        None => check_frame(DEFAULT_FRAME, frame_id)?,
        Some(Value::String(f)) if f.is_empty() => {}
        Some(Value::String(f)) => check_frame(f, frame_id)?,
        Some(other) => {
            return Err(Refusal::Field {
                field: "properties.frame",
                expected: format!("a frame name, found {other}"),
            });
        }
    }
    Ok(GraphNode {
        id,
        position,
        feature: k,
    })
}

fn check_frame(found: &str, expected: &str) -> Result<(), Refusal> {
    if found.trim_start_matches('/') == expected.trim_start_matches('/') {
        Ok(())
    } else {
        Err(Refusal::Frame {
            found: found.into(),
            expected: expected.into(),
        })
    }
}

fn read_edge(
    feature: &Value,
    properties: &Map<String, Value>,
    k: usize,
    nodes: &[GraphNode],
    node_of: &HashMap<GraphId, usize>,
) -> Result<GraphEdge, Refusal> {
    let id = id_field(properties, "properties.id")?;
    let mut ends = [0usize; 2];
    for (slot, field) in ends
        .iter_mut()
        .zip(["properties.startid", "properties.endid"])
    {
        let node = id_field(properties, field)?;
        *slot = *node_of
            .get(&node)
            .ok_or(Refusal::UnknownNode { field, id: node })?;
    }
    let [start, end] = ends;
    let cost = match properties.get("cost") {
        None => None,
        Some(v) => Some(
            v.as_f64()
                .filter(|c| c.is_finite())
                .ok_or_else(|| Refusal::Field {
                    field: "properties.cost",
                    expected: format!("a number, found {v}"),
                })?,
        ),
    };
    let overridable = match properties.get("overridable") {
        None => true,
        Some(v) => v.as_bool().ok_or_else(|| Refusal::Field {
            field: "properties.overridable",
            expected: format!("true or false, found {v}"),
        })?,
    };
    if !overridable && cost.is_none_or(|c| c <= 0.0) {
        return Err(Refusal::Field {
            field: "properties.cost",
            expected: "a cost > 0 on an edge with overridable: false (nav2_route refuses to route through it otherwise)".into(),
        });
    }
    let metadata = match properties.get("metadata") {
        None => Map::new(),
        Some(Value::Object(m)) => m.clone(),
        Some(other) => {
            return Err(Refusal::Field {
                field: "properties.metadata",
                expected: format!("an object, found {other}"),
            });
        }
    };
    let width_m = metadata.get("width_m").map(width).transpose()?;
    let line = edge_line(feature, nodes[start].position, nodes[end].position)?;
    let length_m = line
        .windows(2)
        .map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]))
        .sum();
    Ok(GraphEdge {
        id,
        start,
        end,
        line,
        length_m,
        cost,
        overridable,
        width_m,
        metadata,
        feature: k,
    })
}

/// `metadata.width_m`: a number within [`WIDTH_RANGE_M`].
fn width(v: &Value) -> Result<f64, Refusal> {
    let (lo, hi) = WIDTH_RANGE_M;
    v.as_f64()
        .filter(|w| (lo..=hi).contains(w))
        .ok_or_else(|| Refusal::Field {
            field: "properties.metadata.width_m",
            expected: format!("a corridor width from {lo} to {hi} metres, found {v}"),
        })
}

/// The corridor's line: the edge's coordinates (points at any depth of nesting,
/// as `LineString` and `MultiLineString` hold them, in order), from `start` to
/// `end`; straight from `start` to `end` without coordinates.
fn edge_line(feature: &Value, start: Point, end: Point) -> Result<Vec<Point>, Refusal> {
    let mut points = Vec::new();
    if let Some(coordinates) = feature.get("geometry").and_then(|g| g.get("coordinates"))
        && !coordinates.is_null()
    {
        flatten(coordinates, &mut points, 0).ok_or_else(|| Refusal::Field {
            field: "geometry.coordinates",
            expected: "an edge's line: arrays of [x, y] points (finite numbers)".into(),
        })?;
    }
    let distance = |a: Point, b: Point| (a[0] - b[0]).hypot(a[1] - b[1]);
    if let (Some(&first), Some(&last)) = (points.first(), points.last())
        && distance(first, end) + distance(last, start)
            < distance(first, start) + distance(last, end)
    {
        points.reverse();
    }
    const SAME: f64 = 1e-6;
    if points.first().is_none_or(|&p| distance(p, start) > SAME) {
        points.insert(0, start);
    }
    if points.last().is_none_or(|&p| distance(p, end) > SAME) || points.len() < 2 {
        points.push(end);
    }
    Ok(points)
}

/// Appends the points of `value` (a point, or arrays of them at most 4 deep).
fn flatten(value: &Value, out: &mut Vec<Point>, depth: u32) -> Option<()> {
    let a = value.as_array()?;
    if a.first().is_some_and(Value::is_number) {
        out.push(point(value)?);
        return Some(());
    }
    if depth >= 4 {
        return None;
    }
    for v in a {
        flatten(v, out, depth + 1)?;
    }
    Some(())
}
