//! Planning over the robots' route graph across departure times: for each
//! departure of a window, the cheapest way from one node to another when each
//! edge costs what the long-term model expects at the time the robot reaches it,
//! and the best departures; beside them, what the route server would do without
//! isochron (the shortest way, leaving now), costed the same way.
//!
//! # Cost
//!
//! An edge the robot enters at isochronal time t costs `distance_weight ·
//! length_m + Cost(M_e(t))`: the route server's `DistanceScorer` (weight 1 by
//! default) plus what isochron would send for it from the long-term model alone
//! (the paper's Cost1 term of the edge, [`CostParams::cost_of`]; see
//! [`crate::route_graph`] for the scale). An edge that is not `overridable` costs
//! its file `cost`, as in the route server. An edge without long-term data (no
//! camera, or the bin never learned) costs its distance term only, and is counted. Unlike
//! the segments of [`crate::plan`], an edge where people never walk (M'_p = 0) is
//! not infinite: the graph says where robots may drive, and the route server would
//! take it anyway. The robot leaves at the departure time and reaches each edge
//! after the travel time of the edges before it (their lengths over
//! `route_speed_mps`); t is that minute of the cycle (a weekly cycle passes from
//! one day to the next; the departures themselves keep to the window's day, as
//! off-line planning's [`DayRange`] does).
//!
//! # Algorithm
//!
//! One time-dependent Dijkstra search per departure (Dreyfus 1969; exact for
//! earliest arrival under FIFO travel times, Kaufman & Smith 1993): labels are
//! settled cheapest first, each carrying the time the robot reaches its node, and
//! an edge is costed at the time its label reaches it. Travel times are fixed per
//! edge, so FIFO holds (leaving later never arrives earlier). The criterion is
//! cost, not arrival time, and the robot does not wait at nodes: a node keeps its
//! cheapest label only, so a costlier label that reaches a later edge when it is
//! cheaper is dropped. That makes the search exact whenever competing labels meet
//! the same forecast on the edges after their node (the same minute bin, or an
//! unchanged forecast), and a heuristic otherwise; the cost reported for a
//! path is its exact cost. The sweep over departures is what finds the quiet time.
//! Each search stops when the goal is settled; searches reuse their buffers.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use isochron_config::CostmapConfig;
use isochron_config::clock::MINUTES_PER_DAY;

use crate::cost::CostParams;
use crate::plan::{CurvePoint, DayRange, Window, cheapest_windows};
use crate::route_graph::{EdgeForecast, GraphId, RouteGraph};

/// The weight of the route server's `DistanceScorer` by default.
pub const DEFAULT_DISTANCE_WEIGHT: f64 = 1.0;

/// The cost function and the robot's speed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GraphPlanParams {
    /// `Cost(M)`.
    pub cost: CostParams,
    /// The robot's speed along the graph, m/s.
    pub speed_mps: f64,
    /// Cost per metre: the route server's `DistanceScorer.weight`.
    pub distance_weight: f64,
}

impl GraphPlanParams {
    /// `[costmap]`'s cost function and `route_speed_mps`, with the
    /// `DistanceScorer`'s default weight.
    pub fn from_config(c: &CostmapConfig) -> GraphPlanParams {
        GraphPlanParams {
            cost: CostParams::from_config(c),
            speed_mps: c.route_speed_mps,
            distance_weight: DEFAULT_DISTANCE_WEIGHT,
        }
    }
}

/// What to plan.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GraphPlanRequest {
    /// Start node id.
    pub from: GraphId,
    /// Goal node id.
    pub to: GraphId,
    /// The departures: minutes of the day, step, and the day (`cycle_offset`).
    pub range: DayRange,
    /// The isochronal time now (minute of the cycle), for the baseline.
    pub now_t_star: u32,
}

/// A way through the graph at one departure time.
#[derive(Debug, Clone, PartialEq)]
pub struct GraphPath {
    /// Departure, minute of the cycle.
    pub t_star: u32,
    /// Departure, minute of the day.
    pub minute: u32,
    /// Node ids, from the start to the goal.
    pub nodes: Vec<GraphId>,
    /// Edge ids, in order.
    pub edges: Vec<GraphId>,
    /// Total cost: distance, activity and fixed costs.
    pub cost: f64,
    /// The activity part: Σ Cost(M_e(t_e)).
    pub activity_cost: f64,
    /// Length, metres.
    pub length_m: f64,
    /// Travel time, seconds.
    pub duration_s: f64,
    /// Edges without long-term data (their activity unknown, counted as 0).
    pub unknown_edges: usize,
}

/// A run of departures near the cheapest, and the cheapest way within it.
#[derive(Debug, Clone, PartialEq)]
pub struct GraphWindow {
    /// Minutes of the day and mean cost.
    pub window: Window,
    /// The cheapest departure in the window.
    pub path: GraphPath,
}

/// A plan over departure times.
#[derive(Debug, Clone, PartialEq)]
pub struct GraphPlan {
    /// The departures looked at.
    pub range: DayRange,
    /// The cheapest cost per departure.
    pub curve: Vec<CurvePoint>,
    /// Runs of departures within [`crate::plan::WINDOW_MARGIN`] of the cheapest,
    /// cheapest first.
    pub windows: Vec<GraphWindow>,
    /// The cheapest departures (at most 5), cheapest first.
    pub best: Vec<GraphPath>,
    /// The shortest way (the route server's without isochron: `distance_weight ·
    /// length`, fixed costs), leaving now, costed as the others.
    pub baseline: GraphPath,
}

/// A plan's outcome, as a service status.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum GraphPlanStatus {
    /// Answered.
    Ok = 0,
    /// A node id the graph does not have.
    UnknownNode = 1,
    /// No way from the start to the goal.
    NoPath = 2,
    /// The window (minutes, step, day) or the time now is out of range.
    BadWindow = 3,
    /// The speed or the distance weight is out of range.
    BadParams = 4,
    /// No long-term store to forecast from.
    NoData = 5,
}

/// Why a plan cannot be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GraphPlanError {
    /// A node id the graph does not have.
    #[error("the route graph has no node {0}")]
    UnknownNode(GraphId),
    /// No way from the start to the goal.
    #[error("no way from node {from} to node {to} in the route graph")]
    NoPath {
        /// Start node id.
        from: GraphId,
        /// Goal node id.
        to: GraphId,
    },
    /// The window or the time now is out of range.
    #[error("{0}")]
    BadWindow(String),
    /// A parameter is out of range.
    #[error("{0}")]
    BadParams(String),
    /// The data to forecast from is missing (no long-term store, no grid).
    #[error("{0}")]
    NoData(String),
}

impl GraphPlanError {
    /// The status to answer with.
    pub fn status(&self) -> GraphPlanStatus {
        match self {
            GraphPlanError::UnknownNode(_) => GraphPlanStatus::UnknownNode,
            GraphPlanError::NoPath { .. } => GraphPlanStatus::NoPath,
            GraphPlanError::BadWindow(_) => GraphPlanStatus::BadWindow,
            GraphPlanError::BadParams(_) => GraphPlanStatus::BadParams,
            GraphPlanError::NoData(_) => GraphPlanStatus::NoData,
        }
    }
}

/// Plans `request` over `graph` with the long-term `forecast`.
pub fn plan_graph<F: EdgeForecast + ?Sized>(
    graph: &RouteGraph,
    forecast: &F,
    request: &GraphPlanRequest,
    params: &GraphPlanParams,
) -> Result<GraphPlan, GraphPlanError> {
    check(forecast.cycle_minutes(), request, params)?;
    let node = |id| graph.node_index(id).ok_or(GraphPlanError::UnknownNode(id));
    let (from, to) = (node(request.from)?, node(request.to)?);
    let costing = Costing {
        graph,
        forecast,
        params,
    };
    let mut search = Search::new(graph.nodes().len());
    // The route server's way: time plays no part.
    let fixed = |e: usize, _: f64| costing.fixed(e);
    let no_path = GraphPlanError::NoPath {
        from: request.from,
        to: request.to,
    };
    let shortest = search
        .run(graph, from, to, fixed, params.speed_mps)
        .ok_or_else(|| no_path.clone())?;
    let baseline = costing.path(&shortest, from, request.now_t_star);
    let range = request.range;
    let total = range.minutes();
    let step = range.step;
    let mut paths = Vec::new();
    let mut offset = 0;
    while offset < total {
        let minute = (range.start + offset) % MINUTES_PER_DAY;
        let t_star = range.cycle_offset + minute;
        let cost = |e: usize, elapsed_s: f64| costing.at(e, t_star, elapsed_s).0;
        // Reachable, as the baseline found, unless a cost overflowed to infinity.
        let edges = search
            .run(graph, from, to, cost, params.speed_mps)
            .ok_or_else(|| no_path.clone())?;
        paths.push(costing.path(&edges, from, t_star));
        offset += step;
    }
    let curve: Vec<CurvePoint> = paths
        .iter()
        .map(|p| CurvePoint {
            minute: p.minute,
            cost: p.cost,
        })
        .collect();
    let (windows, best) = cheapest_windows(&curve, total, step);
    let path_at = |minute: u32| {
        paths
            .iter()
            .find(|p| p.minute == minute)
            .cloned()
            .expect("every curve point is a departure")
    };
    let windows = windows
        .into_iter()
        .map(|window| {
            let first = (window.start + MINUTES_PER_DAY - range.start) % MINUTES_PER_DAY;
            let inside = |p: &&GraphPath| {
                let off = (p.minute + MINUTES_PER_DAY - range.start) % MINUTES_PER_DAY;
                off >= first && off < first + (window.end - window.start)
            };
            let path = paths
                .iter()
                .filter(inside)
                .min_by(|a, b| a.cost.total_cmp(&b.cost))
                .cloned()
                .unwrap_or_else(|| path_at(window.start));
            GraphWindow { window, path }
        })
        .collect();
    Ok(GraphPlan {
        range,
        curve,
        windows,
        best: best.iter().map(|p| path_at(p.minute)).collect(),
        baseline,
    })
}

/// The window, the time now and the parameters, checked.
fn check(
    cycle_minutes: u32,
    request: &GraphPlanRequest,
    params: &GraphPlanParams,
) -> Result<(), GraphPlanError> {
    let r = request.range;
    let bad = |m: String| Err(GraphPlanError::BadWindow(m));
    if r.start >= MINUTES_PER_DAY || r.end == 0 || r.end > MINUTES_PER_DAY {
        return bad(format!(
            "minutes {}..{} are outside the day (0..1440)",
            r.start, r.end
        ));
    }
    if r.step == 0 || r.step > MINUTES_PER_DAY {
        return bad(format!("a step of {} is not 1 to 1440 minutes", r.step));
    }
    if !r.cycle_offset.is_multiple_of(MINUTES_PER_DAY) || r.cycle_offset >= cycle_minutes {
        return bad(format!(
            "the day starting at minute {} is not a day of the {cycle_minutes}-minute cycle",
            r.cycle_offset
        ));
    }
    if request.now_t_star >= cycle_minutes {
        return bad(format!(
            "now (minute {}) is outside the {cycle_minutes}-minute cycle",
            request.now_t_star
        ));
    }
    let speed = params.speed_mps;
    if !(speed.is_finite() && speed > 0.0) {
        return Err(GraphPlanError::BadParams(format!(
            "the robot's speed must be > 0 m/s, found {speed}"
        )));
    }
    let w = params.distance_weight;
    if !(w.is_finite() && w > 0.0) {
        return Err(GraphPlanError::BadParams(format!(
            "the distance weight must be > 0, found {w}"
        )));
    }
    Ok(())
}

/// How edges cost.
struct Costing<'a, F: ?Sized> {
    graph: &'a RouteGraph,
    forecast: &'a F,
    params: &'a GraphPlanParams,
}

impl<F: EdgeForecast + ?Sized> Costing<'_, F> {
    /// Edge `e`'s cost to the route server without isochron.
    fn fixed(&self, e: usize) -> f64 {
        let edge = &self.graph.edges()[e];
        if edge.overridable {
            self.params.distance_weight * edge.length_m
        } else {
            edge.cost.unwrap_or(0.0)
        }
    }

    /// Edge `e`'s cost entered `elapsed_s` after leaving at `t_star`, its activity
    /// part, and whether its activity is unknown.
    fn at(&self, e: usize, t_star: u32, elapsed_s: f64) -> (f64, f64, bool) {
        let edge = &self.graph.edges()[e];
        if !edge.overridable {
            return (edge.cost.unwrap_or(0.0), 0.0, false);
        }
        let cycle = self.forecast.cycle_minutes().max(1) as u64;
        let minutes = (elapsed_s.max(0.0) / 60.0) as u64;
        let t = ((t_star as u64 + minutes) % cycle) as u32;
        let activity = self.forecast.activity(e, t);
        let part = activity.map_or(0.0, |m| self.params.cost.cost_of(m));
        (
            self.params.distance_weight * edge.length_m + part,
            part,
            activity.is_none(),
        )
    }

    /// The path of `edges` from node `from` leaving at `t_star`, costed.
    fn path(&self, edges: &[u32], from: usize, t_star: u32) -> GraphPath {
        let graph = self.graph;
        let mut path = GraphPath {
            t_star,
            minute: t_star % MINUTES_PER_DAY,
            nodes: vec![graph.nodes()[from].id],
            edges: Vec::with_capacity(edges.len()),
            cost: 0.0,
            activity_cost: 0.0,
            length_m: 0.0,
            duration_s: 0.0,
            unknown_edges: 0,
        };
        for &e in edges {
            let edge = &graph.edges()[e as usize];
            let (cost, part, unknown) = self.at(e as usize, t_star, path.duration_s);
            path.cost += cost;
            path.activity_cost += part;
            path.unknown_edges += unknown as usize;
            path.length_m += edge.length_m;
            path.duration_s += edge.length_m / self.params.speed_mps;
            path.edges.push(edge.id);
            path.nodes.push(graph.nodes()[edge.end].id);
        }
        path
    }
}

/// A label of the search: a node reached at a cost (cheapest first out of the heap).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Label {
    cost: f64,
    node: u32,
}

impl Eq for Label {}

impl Ord for Label {
    fn cmp(&self, other: &Self) -> Ordering {
        other
            .cost
            .total_cmp(&self.cost)
            .then_with(|| other.node.cmp(&self.node))
    }
}

impl PartialOrd for Label {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

/// A time-dependent Dijkstra search's buffers, reused between searches.
struct Search {
    cost: Vec<f64>,
    elapsed: Vec<f64>,
    parent: Vec<u32>,
    done: Vec<bool>,
    heap: BinaryHeap<Label>,
}

/// No parent edge.
const NONE: u32 = u32::MAX;

impl Search {
    fn new(nodes: usize) -> Search {
        Search {
            cost: vec![f64::INFINITY; nodes],
            elapsed: vec![0.0; nodes],
            parent: vec![NONE; nodes],
            done: vec![false; nodes],
            heap: BinaryHeap::new(),
        }
    }

    /// The edges (indices) of the cheapest way from `from` to `to`, an edge `e`
    /// entered `s` seconds after leaving costing `edge_cost(e, s)`; `None` if `to`
    /// cannot be reached.
    fn run(
        &mut self,
        graph: &RouteGraph,
        from: usize,
        to: usize,
        edge_cost: impl Fn(usize, f64) -> f64,
        speed_mps: f64,
    ) -> Option<Vec<u32>> {
        self.cost.fill(f64::INFINITY);
        self.parent.fill(NONE);
        self.done.fill(false);
        self.heap.clear();
        self.cost[from] = 0.0;
        self.elapsed[from] = 0.0;
        self.heap.push(Label {
            cost: 0.0,
            node: from as u32,
        });
        while let Some(Label { cost, node }) = self.heap.pop() {
            let u = node as usize;
            if self.done[u] {
                continue;
            }
            self.done[u] = true;
            if u == to {
                break;
            }
            let elapsed = self.elapsed[u];
            for &e in graph.out_edges(u) {
                let edge = &graph.edges()[e as usize];
                let v = edge.end;
                if self.done[v] {
                    continue;
                }
                let c = cost + edge_cost(e as usize, elapsed).max(0.0);
                if c < self.cost[v] {
                    self.cost[v] = c;
                    self.elapsed[v] = elapsed + edge.length_m / speed_mps;
                    self.parent[v] = e;
                    self.heap.push(Label {
                        cost: c,
                        node: v as u32,
                    });
                }
            }
        }
        if !self.done[to] {
            return None;
        }
        let mut edges = Vec::new();
        let mut v = to;
        while v != from && edges.len() < graph.nodes().len() {
            let e = self.parent[v];
            edges.push(e);
            v = graph.edges().get(e as usize)?.start;
        }
        edges.reverse();
        Some(edges)
    }
}

#[cfg(test)]
mod tests;
