//! Telling the route server about edges: each edge closes once people have blocked
//! it for a while and reopens once it has been clear as long ([`ClosureGate`]),
//! and only what changed since the last request is sent
//! ([`DynamicEdgesTracker`]), as a `nav2_msgs/srv/DynamicEdges` request
//! ([`DynamicEdgesRequest`]) to the route server's `DynamicEdgesScorer`.
//!
//! The scorer keeps what it is told (closed edges and each edge's cost) until told
//! otherwise, and forgets it all when the route server restarts: then
//! [`DynamicEdgesTracker::resend_all`] tells it everything again. Edges that are
//! not `overridable` (the route server ignores its scorers for them) and edges no
//! camera sees are never closed, opened nor adjusted.

use isochron_config::CostmapConfig;

use super::corridor::{Corridors, EdgeScore};
use super::{GraphId, RouteGraph};

/// `nav2_msgs/msg/EdgeCost`: an edge and the cost the scorer gives it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EdgeCost {
    /// The edge's id.
    pub edgeid: GraphId,
    /// Its cost (added to the other scorers' as it is).
    pub cost: f32,
}

/// The request of `nav2_msgs/srv/DynamicEdges` (`uint16[] closed_edges, uint16[]
/// opened_edges, EdgeCost[] adjust_edges`).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct DynamicEdgesRequest {
    /// Edges to close (the route server does not route through them).
    pub closed_edges: Vec<GraphId>,
    /// Edges to reopen.
    pub opened_edges: Vec<GraphId>,
    /// Edges whose cost changed.
    pub adjust_edges: Vec<EdgeCost>,
}

impl DynamicEdgesRequest {
    /// True if there is nothing to send.
    pub fn is_empty(&self) -> bool {
        self.closed_edges.is_empty() && self.opened_edges.is_empty() && self.adjust_edges.is_empty()
    }
}

/// Whether an edge is closed: it closes once it has been blocked for `after_s`
/// without a break, and reopens once it has been clear as long. Pure: the time
/// (seconds of any steady clock) is passed in.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ClosureGate {
    closed: bool,
    /// Since when the edge has been in the state opposite to `closed`.
    since: Option<f64>,
}

impl ClosureGate {
    /// The gate after seeing the edge `blocked` (or not) at `now_s`; true if closed.
    /// A time that is not finite changes nothing.
    pub fn update(&mut self, blocked: bool, now_s: f64, after_s: f64) -> bool {
        if !now_s.is_finite() {
            return self.closed;
        }
        if blocked == self.closed {
            self.since = None;
            return self.closed;
        }
        let since = *self.since.get_or_insert(now_s);
        if now_s - since >= after_s {
            self.closed = blocked;
            self.since = None;
        }
        self.closed
    }

    /// True if closed.
    pub fn is_closed(&self) -> bool {
        self.closed
    }
}

/// The tracker's settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackerSettings {
    /// How long an edge must be blocked to close (and clear to reopen), seconds.
    pub close_after_s: f64,
    /// A cost is sent again once it moved by at least this much (0: every time).
    pub epsilon: f64,
}

impl TrackerSettings {
    /// `costmap.route_close_after_s` and `costmap.route_cost_epsilon`.
    pub fn from_config(c: &CostmapConfig) -> TrackerSettings {
        TrackerSettings {
            close_after_s: c.route_close_after_s,
            epsilon: c.route_cost_epsilon,
        }
    }
}

/// One edge as the tracker knows it.
#[derive(Debug, Clone, Copy)]
struct Tracked {
    id: GraphId,
    /// Overridable and seen by a camera: the tracker may tell about it.
    managed: bool,
    gate: ClosureGate,
    /// The latest cost scored.
    cost: Option<f64>,
    /// What the route server was told: its cost, and whether it is closed
    /// (`None`: not told, or unknown).
    sent_cost: Option<f64>,
    sent_closed: Option<bool>,
}

/// What changed since the last request, per edge of a graph.
#[derive(Debug, Clone)]
pub struct DynamicEdgesTracker {
    settings: TrackerSettings,
    edges: Vec<Tracked>,
}

impl DynamicEdgesTracker {
    /// A tracker of `graph`'s edges (`corridors`: which a camera sees) that has told
    /// the route server nothing yet: its first request says every managed edge's
    /// state and cost (the scorer may hold what an earlier run sent).
    pub fn new(
        graph: &RouteGraph,
        corridors: &Corridors,
        settings: TrackerSettings,
    ) -> DynamicEdgesTracker {
        let edges = graph
            .edges()
            .iter()
            .enumerate()
            .map(|(e, edge)| Tracked {
                id: edge.id,
                managed: edge.overridable && corridors.is_seen(e),
                gate: ClosureGate::default(),
                cost: None,
                sent_cost: None,
                sent_closed: None,
            })
            .collect();
        DynamicEdgesTracker { settings, edges }
    }

    /// Takes the latest scores (`scores[e]` for edge `e`) seen at `now_s` and
    /// returns what changed since the last request: edges newly closed or opened,
    /// and costs that moved by at least the epsilon. The caller sends it (if not
    /// empty); the tracker takes it as told.
    pub fn update(&mut self, scores: &[EdgeScore], now_s: f64) -> DynamicEdgesRequest {
        let mut request = DynamicEdgesRequest::default();
        let TrackerSettings {
            close_after_s,
            epsilon,
        } = self.settings;
        for (edge, score) in self.edges.iter_mut().zip(scores) {
            if !edge.managed {
                continue;
            }
            let closed = edge.gate.update(score.blocked, now_s, close_after_s);
            if edge.sent_closed != Some(closed) {
                if closed {
                    request.closed_edges.push(edge.id);
                } else {
                    request.opened_edges.push(edge.id);
                }
                edge.sent_closed = Some(closed);
            }
            let Some(cost) = score.cost.filter(|c| c.is_finite()) else {
                continue;
            };
            edge.cost = Some(cost);
            if edge
                .sent_cost
                .is_none_or(|sent| (cost - sent).abs() >= epsilon)
            {
                request.adjust_edges.push(EdgeCost {
                    edgeid: edge.id,
                    cost: cost as f32,
                });
                edge.sent_cost = Some(cost);
            }
        }
        request
    }

    /// Everything the route server should know, for a route server that restarted
    /// (or a request that was lost): every managed edge closed or opened, and
    /// every cost scored; the tracker takes it as told.
    pub fn resend_all(&mut self) -> DynamicEdgesRequest {
        let mut request = DynamicEdgesRequest::default();
        for edge in self.edges.iter_mut().filter(|e| e.managed) {
            let closed = edge.gate.is_closed();
            if closed {
                request.closed_edges.push(edge.id);
            } else {
                request.opened_edges.push(edge.id);
            }
            edge.sent_closed = Some(closed);
            if let Some(cost) = edge.cost {
                request.adjust_edges.push(EdgeCost {
                    edgeid: edge.id,
                    cost: cost as f32,
                });
                edge.sent_cost = Some(cost);
            }
        }
        request
    }

    /// True if edge `edge` (an index) is closed.
    pub fn is_closed(&self, edge: usize) -> bool {
        self.edges.get(edge).is_some_and(|e| e.gate.is_closed())
    }

    /// The ids of the closed edges.
    pub fn closed(&self) -> impl Iterator<Item = GraphId> + '_ {
        self.edges
            .iter()
            .filter(|e| e.gate.is_closed())
            .map(|e| e.id)
    }
}
