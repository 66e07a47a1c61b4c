//! The robots' route graph: a nav2_route GeoJSON graph, each edge a corridor on the
//! map grid, scored from the cost map and the long-term model, closed while people
//! block it, and planned over across departure times ([`crate::graph_plan`]).
//!
//! # The file
//!
//! Read as nav2_route's `GeoJsonGraphFileLoader` reads it (navigation2,
//! `nav2_route/src/plugins/graph_file_loaders/geojson_graph_file_loader.cpp`): a
//! FeatureCollection whose `Point` features are nodes (`properties.id`, optional
//! `properties.frame`, `geometry.coordinates` `[x, y]`) and whose `MultiLineString`
//! and `LineString` features are edges (`properties.id`, `startid`, `endid`,
//! optional `cost` and `overridable` (default true), `metadata` an object); other
//! features are ignored, as there. nav2_route never reads an edge's coordinates
//! (its route runs straight from node to node); isochron takes them, when given,
//! as the line the corridor follows, from the start node to the end node (one
//! drawn the other way round is reversed, and the nodes are added at the ends if
//! missing); an edge without coordinates runs straight between its nodes. An
//! edge's `metadata.width_m` overrides `costmap.route_edge_width_m`.
//!
//! isochron refuses, naming the file and the feature (its index in `features` and
//! its id), what nav2_route would take but cannot be used to tell the route server
//! about edges: a node or edge id used twice (nav2_route keeps the last node and
//! both edges, and `DynamicEdges` could not tell them apart), an id that is both a
//! node's and an edge's (nav2_route's README wants them unique among each other),
//! an id outside ROS `uint16` (0 to 65535: `nav2_msgs` carries node and edge ids
//! so), an edge naming an unknown node, a node in another frame than the cost
//! map's (`costmap.frame_id`; nav2_route would transform it with TF, isochron does
//! not; a node without `frame` is in `"map"`, nav2_route's default, and an empty
//! one in the route server's frame, taken to be the cost map's), an edge with
//! `overridable: false` and no `cost > 0` (nav2_route refuses to route through
//! it), malformed JSON, coordinates or fields, and a graph without nodes or edges.
//!
//! # The cost isochron gives an edge
//!
//! An edge is a path segment p of the paper, its cells those of its corridor. Its
//! cost is the edge's own Cost2 ([`crate::plan::SegmentCosts`], the term
//! [`crate::plan::plan_now`] sums per segment): `w1 · Cost(M_e(t*)) + w2 ·
//! Cost(M_e(now))`, with `Cost(M) = min(cap, 100 · M / cost_scale)`, `M_e(t*)` the
//! long-term mean activity of the corridor's blocks at the current t* and
//! `M_e(now)` the mean activity of its cells on the live cost map (a cell of cost
//! `c` has activity `c · cost_scale / 100`, exact below `cap`). So an edge costs 0
//! (quiet) to `(w1 + w2) · cap` (196 with the defaults), whatever its length,
//! and the sum the route server makes along a route is the route's Cost2.
//!
//! nav2_route adds the costs of its `edge_cost_functions` per edge. Its
//! `DistanceScorer` gives `weight · length` (metres; `weight` 1 by default), its
//! `TimeScorer` `weight · seconds`, its `PenaltyScorer` `weight · penalty`, while
//! its `DynamicEdgesScorer`, through which isochron sends its costs, has no weight:
//! the cost isochron sends is added as it is. Weigh the others against it: with
//! `DistanceScorer.weight = w`, a detour of `d` metres is taken to avoid an edge
//! whose isochron cost exceeds `w · d`; with the defaults (w = 1), avoiding a fully
//! busy edge is worth up to 196 m of detour, a half-busy one (Cost 49 on both
//! terms) 98 m. On a small site raise `DistanceScorer.weight` (e.g. 5 to 10), or
//! lower `w1` and `w2`. Closed edges (people standing across the corridor, see
//! [`dynamic`]) are not scored at all: the route server routes around them.

use std::collections::HashMap;
use std::fmt;
use std::path::{Path, PathBuf};

use isochron_config::LoadedConfig;
use serde_json::{Map, Value};

use crate::grid::Point;

pub mod corridor;
pub mod dynamic;
pub mod forecast;
mod geojson;
#[cfg(test)]
pub(crate) mod tests;

pub use corridor::{Corridors, EdgeScore, EdgeScorer, GridCell, seen_cells};
pub use dynamic::{
    ClosureGate, DynamicEdgesRequest, DynamicEdgesTracker, EdgeCost, TrackerSettings,
};
pub use forecast::{EdgeForecast, FnForecast, ModelForecast, NoForecast};

/// Node and edge ids travel as ROS `uint16`.
pub type GraphId = u16;

/// A node of the graph.
#[derive(Debug, Clone, PartialEq)]
pub struct GraphNode {
    /// `properties.id`.
    pub id: GraphId,
    /// Position in the map frame, metres.
    pub position: Point,
    /// Index of its feature in the file's `features`.
    pub feature: usize,
}

/// A directed edge of the graph.
#[derive(Debug, Clone, PartialEq)]
pub struct GraphEdge {
    /// `properties.id`.
    pub id: GraphId,
    /// Index of the start node in [`RouteGraph::nodes`].
    pub start: usize,
    /// Index of the end node in [`RouteGraph::nodes`].
    pub end: usize,
    /// The corridor's line, map frame, from the start node to the end node (at
    /// least two points).
    pub line: Vec<Point>,
    /// Length of `line`, metres.
    pub length_m: f64,
    /// `properties.cost`, if given: the route server uses it only for an edge that
    /// is not `overridable` (or without scorers).
    pub cost: Option<f64>,
    /// `properties.overridable` (default true): false means the route server
    /// ignores its scorers for this edge, so isochron never adjusts, closes or
    /// opens it.
    pub overridable: bool,
    /// `metadata.width_m`: this edge's corridor width, metres, if given.
    pub width_m: Option<f64>,
    /// `properties.metadata` (empty if absent).
    pub metadata: Map<String, Value>,
    /// Index of its feature in the file's `features`.
    pub feature: usize,
}

/// A route graph: its nodes and edges in file order, and their ids.
#[derive(Debug, Clone)]
pub struct RouteGraph {
    file: PathBuf,
    nodes: Vec<GraphNode>,
    edges: Vec<GraphEdge>,
    node_of: HashMap<GraphId, usize>,
    edge_of: HashMap<GraphId, usize>,
    /// Per node, the range of `out` holding its outgoing edges.
    out_start: Vec<u32>,
    out: Vec<u32>,
    ignored: usize,
}

/// Why a graph file was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Refusal {
    /// The file cannot be read.
    #[error("cannot read the route graph: {0}")]
    Read(String),
    /// Not JSON.
    #[error("not JSON: {0}")]
    Json(String),
    /// JSON, but no `features` array.
    #[error("expected a GeoJSON FeatureCollection with a \"features\" array")]
    NotFeatureCollection,
    /// No node or no edge (nav2_route refuses such a graph too).
    #[error("no {0}: a nav2_route graph needs Point nodes and MultiLineString or LineString edges")]
    Empty(&'static str),
    /// A field is missing or of the wrong kind.
    #[error("{field}: expected {expected}")]
    Field {
        /// Where, e.g. `properties.startid`.
        field: &'static str,
        /// What was expected (and found).
        expected: String,
    },
    /// An id beyond ROS `uint16`.
    #[error(
        "{field} {value} is out of range: nav2_route's node and edge ids travel as ROS uint16 (0 to 65535)"
    )]
    IdOutOfRange {
        /// `properties.id`, `startid` or `endid`.
        field: &'static str,
        /// The id found.
        value: String,
    },
    /// Two nodes with one id.
    #[error("node id {id} is used twice (first by feature {first})")]
    DuplicateNode {
        /// The id.
        id: GraphId,
        /// The feature that used it first.
        first: usize,
    },
    /// Two edges with one id.
    #[error(
        "edge id {id} is used twice (first by feature {first}): the route server could not tell them apart when closing or adjusting"
    )]
    DuplicateEdge {
        /// The id.
        id: GraphId,
        /// The feature that used it first.
        first: usize,
    },
    /// An edge whose id is also a node's.
    #[error(
        "edge id {id} is also the id of the node of feature {node}: nav2_route wants node and edge ids unique among each other"
    )]
    SharedId {
        /// The id.
        id: GraphId,
        /// The node's feature.
        node: usize,
    },
    /// An edge naming a node the graph does not have.
    #[error("{field} {id}: no node has this id")]
    UnknownNode {
        /// `properties.startid` or `properties.endid`.
        field: &'static str,
        /// The id.
        id: GraphId,
    },
    /// A node in another frame than the cost map's.
    #[error(
        "properties.frame \"{found}\" is not the cost map's frame \"{expected}\" (costmap.frame_id): give the graph in that frame (isochron does not transform graphs)"
    )]
    Frame {
        /// The node's frame.
        found: String,
        /// The grid's frame.
        expected: String,
    },
}

/// A refused graph: the file, where in it, and why.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub struct GraphError {
    /// The graph file.
    pub file: PathBuf,
    /// Index of the feature in `features`, when one is at fault.
    pub feature: Option<usize>,
    /// That feature's `properties.id`, when it has a readable one.
    pub id: Option<String>,
    /// Why.
    pub refusal: Refusal,
}

impl fmt::Display for GraphError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file.display())?;
        match (self.feature, &self.id) {
            (Some(k), Some(id)) => write!(f, ": feature {k} (id {id})")?,
            (Some(k), None) => write!(f, ": feature {k}")?,
            _ => {}
        }
        write!(f, ": {}", self.refusal)
    }
}

/// Corridor widths isochron accepts, metres (`metadata.width_m`, and the range of
/// `costmap.route_edge_width_m`).
pub const WIDTH_RANGE_M: (f64, f64) = (0.05, 50.0);

impl RouteGraph {
    /// Loads the nav2_route GeoJSON graph at `path`, whose nodes must be in
    /// `frame_id` (the cost map's).
    pub fn load(path: &Path, frame_id: &str) -> Result<RouteGraph, GraphError> {
        let text = std::fs::read_to_string(path).map_err(|e| GraphError {
            file: path.to_path_buf(),
            feature: None,
            id: None,
            refusal: Refusal::Read(e.to_string()),
        })?;
        RouteGraph::parse(&text, path, frame_id)
    }

    /// Parses a nav2_route GeoJSON graph read from `file` (named in errors).
    pub fn parse(text: &str, file: &Path, frame_id: &str) -> Result<RouteGraph, GraphError> {
        let (nodes, edges, ignored) = geojson::read(text, frame_id).map_err(|e| GraphError {
            file: file.to_path_buf(),
            feature: e.feature,
            id: e.id,
            refusal: e.refusal,
        })?;
        let node_of = nodes.iter().enumerate().map(|(k, n)| (n.id, k)).collect();
        let edge_of = edges.iter().enumerate().map(|(k, e)| (e.id, k)).collect();
        let mut counts = vec![0u32; nodes.len() + 1];
        for e in &edges {
            counts[e.start + 1] += 1;
        }
        for k in 1..counts.len() {
            counts[k] += counts[k - 1];
        }
        let out_start = counts;
        let mut fill = out_start.clone();
        let mut out = vec![0u32; edges.len()];
        for (k, e) in edges.iter().enumerate() {
            out[fill[e.start] as usize] = k as u32;
            fill[e.start] += 1;
        }
        Ok(RouteGraph {
            file: file.to_path_buf(),
            nodes,
            edges,
            node_of,
            edge_of,
            out_start,
            out,
            ignored,
        })
    }

    /// The graph of `costmap.route_graph` (relative to the config file), in the
    /// frame of `costmap.frame_id`; `None` when none is configured.
    pub fn from_config(loaded: &LoadedConfig) -> Result<Option<RouteGraph>, GraphError> {
        let c = &loaded.config.costmap;
        let Some(path) = &c.route_graph else {
            return Ok(None);
        };
        let path = if path.is_absolute() {
            path.clone()
        } else {
            loaded.base_dir().join(path)
        };
        RouteGraph::load(&path, &c.frame_id).map(Some)
    }

    /// The file the graph was read from.
    pub fn file(&self) -> &Path {
        &self.file
    }

    /// The nodes, in file order.
    pub fn nodes(&self) -> &[GraphNode] {
        &self.nodes
    }

    /// The edges, in file order; an edge's index here is its index everywhere in
    /// this module and in [`crate::graph_plan`].
    pub fn edges(&self) -> &[GraphEdge] {
        &self.edges
    }

    /// Index of the node with `id`.
    pub fn node_index(&self, id: GraphId) -> Option<usize> {
        self.node_of.get(&id).copied()
    }

    /// Index of the edge with `id`.
    pub fn edge_index(&self, id: GraphId) -> Option<usize> {
        self.edge_of.get(&id).copied()
    }

    /// Indices of the edges leaving node `node` (an index), in file order.
    pub fn out_edges(&self, node: usize) -> &[u32] {
        match (self.out_start.get(node), self.out_start.get(node + 1)) {
            (Some(&a), Some(&b)) => &self.out[a as usize..b as usize],
            _ => &[],
        }
    }

    /// Features that are neither nodes nor edges (ignored, as nav2_route does).
    pub fn ignored_features(&self) -> usize {
        self.ignored
    }
}
