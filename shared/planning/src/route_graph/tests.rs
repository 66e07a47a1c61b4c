//! Loading graphs, corridors, scoring, closing and reopening, change tracking.

use std::path::{Path, PathBuf};

use serde_json::json;

use super::*;

/// A graph of `features` as nav2_route's files hold them.
fn collection(features: Vec<Value>) -> String {
    json!({ "type": "FeatureCollection", "features": features }).to_string()
}

fn node(id: Value, x: f64, y: f64) -> Value {
    json!({ "type": "Feature", "properties": { "id": id, "frame": "map" },
            "geometry": { "type": "Point", "coordinates": [x, y] } })
}

fn edge(id: Value, start: Value, end: Value) -> Value {
    json!({ "type": "Feature", "properties": { "id": id, "startid": start, "endid": end },
            "geometry": { "type": "MultiLineString", "coordinates": [] } })
}

fn parse(text: &str) -> Result<RouteGraph, GraphError> {
    RouteGraph::parse(text, Path::new("site.geojson"), "map")
}

/// Three nodes on a line and edges between them.
fn three() -> Vec<Value> {
    vec![
        node(json!(1), 0.0, 0.0),
        node(json!(2), 4.0, 0.0),
        node(json!(3), 4.0, 3.0),
        edge(json!(10), json!(1), json!(2)),
        edge(json!(11), json!(2), json!(3)),
    ]
}

#[test]
fn a_graph_loads_with_its_ids_lines_and_properties() {
    let mut features = three();
    // Drawn backwards, nested as a MultiLineString, through a bend.
    features.push(json!({ "type": "Feature",
        "properties": { "id": 12, "startid": 3, "endid": 1, "cost": 7.5, "overridable": false,
                        "metadata": { "width_m": 2.0, "speed_limit": 50 } },
        "geometry": { "type": "MultiLineString", "coordinates": [[[0.0, 0.0], [0.0, 3.0]], [[4.0, 3.0]]] } }));
    // A LineString whose coordinates are nested one level too deep (as in
    // nav2_route's aws_graph.geojson), and an edge without geometry coordinates.
    features.push(
        json!({ "type": "Feature", "properties": { "id": 13, "startid": 1, "endid": 3 },
        "geometry": { "type": "LineString", "coordinates": [[[0.0, 0.0], [4.0, 3.0]]] } }),
    );
    features.push(
        json!({ "type": "Feature", "properties": { "id": 14, "startid": 2, "endid": 1 },
        "geometry": { "type": "MultiLineString" } }),
    );
    features.push(
        json!({ "type": "Feature", "properties": { "name": "a room" },
        "geometry": { "type": "Polygon", "coordinates": [] } }),
    );
    let g = parse(&collection(features)).unwrap();
    let ids: Vec<u16> = g.nodes().iter().map(|n| n.id).collect();
    assert_eq!(ids, [1, 2, 3]);
    let ids: Vec<u16> = g.edges().iter().map(|e| e.id).collect();
    assert_eq!(ids, [10, 11, 12, 13, 14]);
    assert_eq!(g.ignored_features(), 1);
    assert_eq!(g.node_index(3), Some(2));
    assert_eq!(g.edge_index(12), Some(2));
    assert_eq!(g.edge_index(99), None);
    let e10 = &g.edges()[0];
    assert_eq!((e10.start, e10.end, e10.feature), (0, 1, 3));
    assert_eq!(e10.line, vec![[0.0, 0.0], [4.0, 0.0]]);
    assert!((e10.length_m - 4.0).abs() < 1e-12);
    assert!(e10.overridable && e10.cost.is_none() && e10.width_m.is_none());
    let e12 = &g.edges()[2];
    assert_eq!(e12.line, vec![[4.0, 3.0], [0.0, 3.0], [0.0, 0.0]]);
    assert!((e12.length_m - 7.0).abs() < 1e-12);
    assert_eq!(
        (e12.cost, e12.overridable, e12.width_m),
        (Some(7.5), false, Some(2.0))
    );
    assert_eq!(e12.metadata["speed_limit"], json!(50));
    assert_eq!(g.edges()[3].line, vec![[0.0, 0.0], [4.0, 3.0]]);
    assert_eq!(g.edges()[4].line, vec![[4.0, 0.0], [0.0, 0.0]]);
    // Out of node 1: edges 10 and 13 (indices 0 and 3).
    assert_eq!(g.out_edges(0), [0, 3]);
    assert_eq!(g.out_edges(2), [2]);
    assert!(g.out_edges(7).is_empty());
}

/// The error of [`three`] with feature `k` replaced by `v`, as shown.
fn refused_with(k: usize, v: Value) -> String {
    let mut f = three();
    f[k] = v;
    parse(&collection(f)).unwrap_err().to_string()
}

/// An edge feature from 1 to 2 with id 10 and `extra` properties.
fn edge_with(extra: Value) -> Value {
    let mut e = edge(json!(10), json!(1), json!(2));
    for (k, v) in extra.as_object().unwrap() {
        e["properties"][k] = v.clone();
    }
    e
}

fn expect(got: String, want: &str) {
    assert!(got.contains(want), "{got}\nwanted: {want}");
}

#[test]
fn a_file_that_is_no_graph_is_refused_with_its_name() {
    expect(
        parse("{ \"features\": [ ").unwrap_err().to_string(),
        "site.geojson: not JSON: EOF while parsing",
    );
    expect(
        parse("{\"type\": \"Feature\"}").unwrap_err().to_string(),
        "site.geojson: expected a GeoJSON FeatureCollection with a \"features\" array",
    );
    let edge_only = collection(vec![edge(json!(1), json!(1), json!(2))]);
    expect(
        parse(&edge_only).unwrap_err().to_string(),
        "site.geojson: no nodes: a nav2_route graph needs Point nodes",
    );
    let node_only = collection(vec![node(json!(1), 0.0, 0.0)]);
    expect(
        parse(&node_only).unwrap_err().to_string(),
        "site.geojson: no edges",
    );
    let err = RouteGraph::load(Path::new("/nonexistent/site.geojson"), "map").unwrap_err();
    assert!(matches!(err.refusal, Refusal::Read(_)), "{err}");
    expect(
        err.to_string(),
        "/nonexistent/site.geojson: cannot read the route graph",
    );
}

#[test]
fn bad_ids_are_refused_with_the_feature_and_its_id() {
    for (k, v, want) in [
        (
            1,
            node(json!(1), 5.0, 5.0),
            "site.geojson: feature 1 (id 1): node id 1 is used twice (first by feature 0)",
        ),
        (
            4,
            edge(json!(10), json!(2), json!(3)),
            "site.geojson: feature 4 (id 10): edge id 10 is used twice (first by feature 3)",
        ),
        (
            4,
            edge(json!(2), json!(2), json!(3)),
            "site.geojson: feature 4 (id 2): edge id 2 is also the id of the node of feature 1: nav2_route wants node and edge ids unique among each other",
        ),
        (
            4,
            edge(json!(70000), json!(2), json!(3)),
            "site.geojson: feature 4 (id 70000): properties.id 70000 is out of range: nav2_route's node and edge ids travel as ROS uint16 (0 to 65535)",
        ),
        (
            0,
            node(json!(-1), 0.0, 0.0),
            "site.geojson: feature 0 (id -1): properties.id -1 is out of range",
        ),
        (
            4,
            edge(json!(11), json!(2), json!(65536)),
            "site.geojson: feature 4 (id 11): properties.endid 65536 is out of range",
        ),
        (
            4,
            edge(json!(11), json!(2), json!(9)),
            "site.geojson: feature 4 (id 11): properties.endid 9: no node has this id",
        ),
        (
            3,
            edge(json!(10), json!(8), json!(2)),
            "site.geojson: feature 3 (id 10): properties.startid 8: no node has this id",
        ),
        (
            4,
            edge(json!("11"), json!(2), json!(3)),
            "site.geojson: feature 4 (id \"11\"): properties.id: expected an integer id (0 to 65535), found \"11\"",
        ),
        (
            4,
            json!({ "type": "Feature", "properties": { "startid": 2, "endid": 3 }, "geometry": { "type": "LineString" } }),
            "site.geojson: feature 4: properties.id: expected an integer id (0 to 65535), found none",
        ),
    ] {
        expect(refused_with(k, v), want);
    }
}

#[test]
fn bad_fields_are_refused_with_the_feature_and_the_field() {
    let point = |properties: Value, coordinates: Value| json!({ "type": "Feature", "properties": properties, "geometry": { "type": "Point", "coordinates": coordinates } });
    let mut crooked = edge_with(json!({}));
    crooked["geometry"]["coordinates"] = json!([[0, 0], [1, "x"]]);
    for (k, v, want) in [
        (
            0,
            point(json!({ "id": 1 }), json!(["a", 0])),
            "site.geojson: feature 0 (id 1): geometry.coordinates: expected a node's position [x, y]",
        ),
        (
            3,
            crooked,
            "site.geojson: feature 3 (id 10): geometry.coordinates: expected an edge's line",
        ),
        (
            3,
            edge_with(json!({ "cost": "high" })),
            "feature 3 (id 10): properties.cost: expected a number, found \"high\"",
        ),
        (
            3,
            edge_with(json!({ "overridable": 1 })),
            "feature 3 (id 10): properties.overridable: expected true or false, found 1",
        ),
        (
            3,
            edge_with(json!({ "overridable": false })),
            "feature 3 (id 10): properties.cost: expected a cost > 0 on an edge with overridable: false",
        ),
        (
            3,
            edge_with(json!({ "metadata": [1] })),
            "feature 3 (id 10): properties.metadata: expected an object, found [1]",
        ),
        (
            3,
            edge_with(json!({ "metadata": { "width_m": 0 } })),
            "feature 3 (id 10): properties.metadata.width_m: expected a corridor width from 0.05 to 50 metres, found 0",
        ),
        (
            2,
            point(json!({ "id": 3, "frame": "odom" }), json!([4, 3])),
            "site.geojson: feature 2 (id 3): properties.frame \"odom\" is not the cost map's frame \"map\" (costmap.frame_id)",
        ),
        (
            2,
            point(json!({ "id": 3, "frame": 5 }), json!([4, 3])),
            "feature 2 (id 3): properties.frame: expected a frame name, found 5",
        ),
    ] {
        expect(refused_with(k, v), want);
    }
    // A node without a frame is in "map" (nav2_route's default); an empty frame is
    // the route server's, taken to be the grid's.
    let mut features = three();
    features[0] = point(json!({ "id": 1 }), json!([0, 0]));
    let text = collection(features.clone());
    assert!(parse(&text).is_ok());
    let err = RouteGraph::parse(&text, Path::new("g.geojson"), "odom").unwrap_err();
    assert_eq!((err.feature, err.id.as_deref()), (Some(0), Some("1")));
    expect(
        err.to_string(),
        "g.geojson: feature 0 (id 1): properties.frame \"map\" is not the cost map's frame \"odom\"",
    );
    for node in &mut features[..3] {
        node["properties"]["frame"] = json!("");
    }
    assert!(RouteGraph::parse(&collection(features), Path::new("g"), "odom").is_ok());
}

/// `tests/data/nav2_route/<name>`.
fn sample(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/data/nav2_route")
        .join(name)
}

/// Nodes and edges counted from the file independently: (node ids, edge ids).
fn count(path: &Path) -> (Vec<u64>, Vec<u64>) {
    let json: Value = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    let (mut nodes, mut edges) = (Vec::new(), Vec::new());
    for f in json["features"].as_array().unwrap() {
        let id = f["properties"]["id"].as_u64().unwrap();
        match f["geometry"]["type"].as_str().unwrap() {
            "Point" => nodes.push(id),
            "LineString" | "MultiLineString" => edges.push(id),
            other => panic!("{other}"),
        }
    }
    (nodes, edges)
}

#[test]
fn nav2_route_sample_graphs_load_with_their_ids() {
    // (file, nodes, edges, node ids, edge ids), counted from the files.
    for (name, n_nodes, n_edges, node_ids, edge_ids) in [
        ("aws_graph.geojson", 40, 84, 0..=39, 40..=123),
        ("sample_graph.geojson", 9, 24, 0..=8, 9..=32),
        ("turtlebot3_graph.geojson", 20, 65, 1..=20, 21..=85),
    ] {
        let path = sample(name);
        let g = RouteGraph::load(&path, "map").unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(
            (g.nodes().len(), g.edges().len()),
            (n_nodes, n_edges),
            "{name}"
        );
        let (nodes, edges) = count(&path);
        let ids: Vec<u64> = g.nodes().iter().map(|n| n.id as u64).collect();
        assert_eq!(ids, nodes, "{name}");
        let ids: Vec<u64> = g.edges().iter().map(|e| e.id as u64).collect();
        assert_eq!(ids, edges, "{name}");
        let mut sorted = ids.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, edge_ids.collect::<Vec<u64>>(), "{name}");
        let mut sorted: Vec<u64> = g.nodes().iter().map(|n| n.id as u64).collect();
        sorted.sort_unstable();
        assert_eq!(sorted, node_ids.collect::<Vec<u64>>(), "{name}");
        // Every edge's line runs from its start node to its end node.
        for e in g.edges() {
            assert_eq!(e.line.first(), Some(&g.nodes()[e.start].position), "{name}");
            assert_eq!(e.line.last(), Some(&g.nodes()[e.end].position), "{name}");
        }
    }
    let g = RouteGraph::load(&sample("sample_graph.geojson"), "map").unwrap();
    let e9 = &g.edges()[g.edge_index(9).unwrap()];
    assert_eq!((e9.cost, e9.overridable), (Some(10.0), false));
    assert_eq!(e9.metadata["aisle_number"], json!(14));
    // turtlebot4_graph gives edges 10006, 10007, 10012, 10013, 10020 and 10021 to
    // two edges each: refused at the first.
    let path = sample("turtlebot4_graph.geojson");
    let (nodes, edges) = count(&path);
    assert_eq!((nodes.len(), edges.len()), (34, 78));
    let err = RouteGraph::load(&path, "map").unwrap_err();
    assert!(
        matches!(err.refusal, Refusal::DuplicateEdge { id: 10006, .. }),
        "{err}"
    );
    assert!(
        err.to_string()
            .contains("(id 10006): edge id 10006 is used twice"),
        "{err}"
    );
}
