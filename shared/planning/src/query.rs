//! The plan query: the fixed-size `#[repr(C)]` request and response of the cost
//! map bridge's request-response service `<prefix>/plan` ([`PlanRequest`] →
//! [`PlanResponse`]), as both of its ends (see [`crate::plan_service`]) and any
//! foreign client read them.
//!
//! They share the magic and layout version of the stream headers
//! (`isochron_wire`), so a foreign or outdated peer is refused with the same
//! [`WireError`], and are pinned by `#[type_name]` for iceoryx2's type check.

use iceoryx2::prelude::ZeroCopySend;
use isochron_wire::u32_enum;
use isochron_wire::{LAYOUT_VERSION, MAGIC, WireError, check_layout, fixed_str, to_fixed};

/// Longest route or segment name in planning requests and responses, bytes (the
/// same limit the site config puts on route and segment names).
pub use isochron_wire::PLAN_NAME_LEN;
/// Most routes one planning request may name.
pub const PLAN_MAX_ROUTES: usize = 16;
/// Most points of an off-line cost curve (one per minute of the day).
pub const PLAN_CURVE_LEN: usize = 1440;
/// Most cheapest windows in an off-line answer.
pub const PLAN_MAX_WINDOWS: usize = 8;
/// Length of a planning response's text (an error, or where a snapshot went).
pub const PLAN_MESSAGE_LEN: usize = 256;
/// Most edges of a path in a graph answer ([`PlanGraphPath`]); a longer path is
/// answered with [`PlanStatus::Failed`].
pub const PLAN_GRAPH_MAX_EDGES: usize = 255;

u32_enum! {
    /// What a [`PlanRequest`] asks the cost map bridge for.
    pub enum PlanKind {
        /// Off-line: Cost1 of one route over the day, and its cheapest departure times.
        Offline = 1,
        /// Real-time: Cost2 of each named route now, ranked.
        Now = 2,
        /// Write a snapshot of the current cost map (PGM + YAML + PNG).
        Snapshot = 3,
        /// Over the route graph: for each departure of a window, the cheapest
        /// path from one node to another on the forecast, and the best departures.
        Graph = 4,
    }
}

u32_enum! {
    /// Outcome of a planning request.
    pub enum PlanStatus {
        /// Answered.
        Ok = 0,
        /// The request is malformed (kind, counts, minutes); see the message.
        BadRequest = 1,
        /// A route the site config does not have.
        UnknownRoute = 2,
        /// The data to answer is missing (no long-term store, no grid); see the message.
        NoData = 3,
        /// Something failed on the service's side; see the message.
        Failed = 4,
        /// Graph: a node id the route graph does not have.
        UnknownNode = 5,
        /// Graph: no path from the start node to the goal.
        NoPath = 6,
    }
}

/// A request to the cost map bridge's request-response service `<prefix>/plan`.
/// After sending it, a client may notify the event service of the same name to
/// be answered at once (otherwise within the bridge's loop period, ≤ 250 ms).
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("isochron::PlanRequest")]
#[repr(C)]
pub struct PlanRequest {
    /// Always [`MAGIC`].
    pub magic: u32,
    /// Always [`LAYOUT_VERSION`].
    pub layout_version: u16,
    /// Zero.
    pub reserved: u16,
    /// A [`PlanKind`] as `u32`.
    pub kind: u32,
    /// Number of valid entries in `routes`.
    pub route_count: u32,
    /// Route names, zero-padded (off-line: exactly one).
    pub routes: [[u8; PLAN_NAME_LEN]; PLAN_MAX_ROUTES],
    /// Off-line: first minute of the day considered (0..1440).
    pub start_minute: u32,
    /// Off-line: end minute, exclusive (1..=1440); below `start_minute` the range
    /// wraps past midnight.
    pub end_minute: u32,
    /// Off-line: minutes per curve point (1..=1440).
    pub step_min: u32,
    /// Off-line and graph, weekly stores: the day, 0 = Monday .. 6 = Sunday; 7 = today.
    pub weekday: u32,
    /// Graph: the start node's id (nav2_route, 0..=65535).
    pub from_node: u32,
    /// Graph: the goal node's id (nav2_route, 0..=65535).
    pub to_node: u32,
}

impl PlanRequest {
    /// A request of `kind` for `routes` (names longer than [`PLAN_NAME_LEN`] or
    /// beyond [`PLAN_MAX_ROUTES`] are cut; validate names first), over the whole day
    /// in steps of 5 minutes, today.
    pub fn new(kind: PlanKind, routes: &[&str]) -> PlanRequest {
        let mut names = [[0u8; PLAN_NAME_LEN]; PLAN_MAX_ROUTES];
        for (slot, name) in names.iter_mut().zip(routes) {
            *slot = to_fixed::<PLAN_NAME_LEN>(name);
        }
        PlanRequest {
            magic: MAGIC,
            layout_version: LAYOUT_VERSION,
            reserved: 0,
            kind: kind as u32,
            route_count: routes.len().min(PLAN_MAX_ROUTES) as u32,
            routes: names,
            start_minute: 0,
            end_minute: 1440,
            step_min: 5,
            weekday: 7,
            from_node: 0,
            to_node: 0,
        }
    }

    /// A graph request from node `from` to node `to`, over the whole day in
    /// steps of 5 minutes, today.
    pub fn graph(from: u16, to: u16) -> PlanRequest {
        let mut request = PlanRequest::new(PlanKind::Graph, &[]);
        request.from_node = from as u32;
        request.to_node = to as u32;
        request
    }

    /// Checks magic, version, kind, counts and minutes.
    pub fn validate(&self) -> Result<PlanKind, WireError> {
        check_layout(self.magic, self.layout_version)?;
        let kind = PlanKind::from_field(self.kind, "kind")?;
        let field = |field: &'static str, reason: String| Err(WireError::Field { field, reason });
        if self.route_count as usize > PLAN_MAX_ROUTES {
            return field(
                "route_count",
                format!("{} routes, at most {PLAN_MAX_ROUTES}", self.route_count),
            );
        }
        match kind {
            PlanKind::Offline if self.route_count != 1 => {
                return field(
                    "route_count",
                    format!("off-line plans take 1 route, found {}", self.route_count),
                );
            }
            PlanKind::Now if self.route_count == 0 => {
                return field("route_count", "name at least one route".into());
            }
            PlanKind::Graph if self.route_count != 0 => {
                return field(
                    "route_count",
                    format!(
                        "graph plans take nodes, not routes: found {} routes",
                        self.route_count
                    ),
                );
            }
            PlanKind::Graph
                if self.from_node > u16::MAX as u32 || self.to_node > u16::MAX as u32 =>
            {
                return field(
                    "from_node",
                    format!(
                        "nodes {} and {}: nav2_route ids are 0 to 65535",
                        self.from_node, self.to_node
                    ),
                );
            }
            _ => {}
        }
        if matches!(kind, PlanKind::Offline | PlanKind::Graph) {
            if self.start_minute >= 1440 || self.end_minute == 0 || self.end_minute > 1440 {
                return field(
                    "start_minute",
                    format!(
                        "minutes {}..{} are outside the day",
                        self.start_minute, self.end_minute
                    ),
                );
            }
            if self.step_min == 0 || self.step_min > 1440 {
                return field(
                    "step_min",
                    format!("{} is not 1 to 1440 minutes", self.step_min),
                );
            }
            if self.weekday > 7 {
                return field(
                    "weekday",
                    format!("{} is not 0 (Monday) to 7 (today)", self.weekday),
                );
            }
        }
        Ok(kind)
    }

    /// The valid route names.
    pub fn route_names(&self) -> Vec<String> {
        self.routes[..(self.route_count as usize).min(PLAN_MAX_ROUTES)]
            .iter()
            .map(|r| fixed_str(r))
            .collect()
    }
}

/// [`PlanRouteCost::flags`]: a segment of the route never saw activity (M'_p = 0),
/// so the route's cost is infinite.
pub const PLAN_FLAG_INFINITE: u32 = 1 << 0;
/// [`PlanRouteCost::flags`]: no live activity for some segment; its long-term
/// mean stood in for the short-term activity.
pub const PLAN_FLAG_ESTIMATED: u32 = 1 << 1;
/// [`PlanRouteCost::flags`]: the long-term model has no data at this t* for some
/// segment; the long-term cost is unknown (NaN).
pub const PLAN_FLAG_NO_LONG_TERM: u32 = 1 << 2;

/// The cost of one route in a [`PlanResponse`].
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("isochron::PlanRouteCost")]
#[repr(C)]
pub struct PlanRouteCost {
    /// Route name, zero-padded.
    pub name: [u8; PLAN_NAME_LEN],
    /// Now: `w1·cost1 + w2·short_term`. Off-line: the lowest Cost1 of the curve.
    pub cost2: f32,
    /// Cost1 at t* = now (off-line: at the cheapest time); infinite if a segment
    /// never saw activity.
    pub cost1: f32,
    /// Σ Cost(M_p(now)) over the route's segments.
    pub short_term: f32,
    /// `PLAN_FLAG_*` bits.
    pub flags: u32,
}

/// A run of curve points within a small margin of the cheapest cost.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("isochron::PlanWindow")]
#[repr(C)]
pub struct PlanWindow {
    /// First minute of the day.
    pub start_minute: u32,
    /// End minute, exclusive (may exceed 1440 past midnight).
    pub end_minute: u32,
    /// Mean Cost1 over the window.
    pub cost: f32,
    /// Zero.
    pub reserved: u32,
}

/// A path through the route graph in a [`PlanResponse`] to a graph request.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("isochron::PlanGraphPath")]
#[repr(C)]
pub struct PlanGraphPath {
    /// Departure, minute of the day.
    pub departure_minute: u32,
    /// Number of valid entries in `nodes` (0: no path; else `edge_count + 1`).
    pub node_count: u32,
    /// Number of valid entries in `edges`.
    pub edge_count: u32,
    /// Edges without long-term data (their activity counted as 0).
    pub unknown_edges: u32,
    /// Total cost: distance, forecast activity and fixed edge costs.
    pub cost: f32,
    /// The forecast activity part.
    pub activity_cost: f32,
    /// Length, metres.
    pub length_m: f32,
    /// Travel time, seconds.
    pub duration_s: f32,
    /// Node ids, from the start to the goal.
    pub nodes: [u16; PLAN_GRAPH_MAX_EDGES + 1],
    /// Edge ids, in order (the last entry is padding).
    pub edges: [u16; PLAN_GRAPH_MAX_EDGES + 1],
}

impl PlanGraphPath {
    /// No path.
    pub const EMPTY: PlanGraphPath = PlanGraphPath {
        departure_minute: 0,
        node_count: 0,
        edge_count: 0,
        unknown_edges: 0,
        cost: 0.0,
        activity_cost: 0.0,
        length_m: 0.0,
        duration_s: 0.0,
        nodes: [0; PLAN_GRAPH_MAX_EDGES + 1],
        edges: [0; PLAN_GRAPH_MAX_EDGES + 1],
    };

    /// The valid node ids.
    pub fn node_ids(&self) -> &[u16] {
        &self.nodes[..(self.node_count as usize).min(self.nodes.len())]
    }

    /// The valid edge ids.
    pub fn edge_ids(&self) -> &[u16] {
        &self.edges[..(self.edge_count as usize).min(PLAN_GRAPH_MAX_EDGES)]
    }
}

/// The answer of the cost map bridge to a [`PlanRequest`].
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("isochron::PlanResponse")]
#[repr(C)]
pub struct PlanResponse {
    /// Always [`MAGIC`].
    pub magic: u32,
    /// Always [`LAYOUT_VERSION`].
    pub layout_version: u16,
    /// Zero.
    pub reserved: u16,
    /// The request's [`PlanKind`] as `u32`.
    pub kind: u32,
    /// A [`PlanStatus`] as `u32`.
    pub status: u32,
    /// Why the request failed, or (snapshot) the files written; zero-padded.
    pub message: [u8; PLAN_MESSAGE_LEN],
    /// The t* the answer is for (now: the current minute of the cycle).
    pub t_star: u32,
    /// Number of valid entries in `routes`.
    pub route_count: u32,
    /// Now: the routes, cheapest first. Off-line: the route.
    pub routes: [PlanRouteCost; PLAN_MAX_ROUTES],
    /// Off-line: minute of the day of the first curve point.
    pub curve_start_minute: u32,
    /// Off-line: minutes between curve points.
    pub curve_step_min: u32,
    /// Off-line: number of valid curve points.
    pub curve_len: u32,
    /// Off-line: Cost1 per point (mean over its step); infinite if a segment never
    /// saw activity, NaN where the long-term model has no data.
    pub curve: [f32; PLAN_CURVE_LEN],
    /// Off-line: number of valid windows.
    pub window_count: u32,
    /// Off-line and graph: the cheapest windows, cheapest first.
    pub windows: [PlanWindow; PLAN_MAX_WINDOWS],
    /// Graph: the cheapest path of each window, as many as `window_count`.
    pub graph_windows: [PlanGraphPath; PLAN_MAX_WINDOWS],
    /// Graph: the cheapest departure of all.
    pub graph_best: PlanGraphPath,
    /// Graph: the shortest path leaving now (the route server's without
    /// isochron), costed the same way.
    pub graph_baseline: PlanGraphPath,
}

impl PlanResponse {
    /// An empty answer to a request of `kind` with `status` and `message`.
    pub fn new(kind: u32, status: PlanStatus, message: &str) -> PlanResponse {
        PlanResponse {
            magic: MAGIC,
            layout_version: LAYOUT_VERSION,
            reserved: 0,
            kind,
            status: status as u32,
            message: to_fixed::<PLAN_MESSAGE_LEN>(message),
            t_star: 0,
            route_count: 0,
            routes: [PlanRouteCost::default(); PLAN_MAX_ROUTES],
            curve_start_minute: 0,
            curve_step_min: 0,
            curve_len: 0,
            curve: [0.0; PLAN_CURVE_LEN],
            window_count: 0,
            windows: [PlanWindow::default(); PLAN_MAX_WINDOWS],
            graph_windows: [PlanGraphPath::EMPTY; PLAN_MAX_WINDOWS],
            graph_best: PlanGraphPath::EMPTY,
            graph_baseline: PlanGraphPath::EMPTY,
        }
    }

    /// Checks magic, version, status and counts.
    pub fn validate(&self) -> Result<PlanStatus, WireError> {
        check_layout(self.magic, self.layout_version)?;
        let status = PlanStatus::from_field(self.status, "status")?;
        if self.route_count as usize > PLAN_MAX_ROUTES
            || self.curve_len as usize > PLAN_CURVE_LEN
            || self.window_count as usize > PLAN_MAX_WINDOWS
            || self.graph_paths().any(|p| {
                p.edge_count as usize > PLAN_GRAPH_MAX_EDGES
                    || p.node_count as usize > PLAN_GRAPH_MAX_EDGES + 1
            })
        {
            return Err(WireError::Field {
                field: "route_count",
                reason: "a count exceeds its array".into(),
            });
        }
        Ok(status)
    }

    /// The response's text.
    pub fn message(&self) -> String {
        fixed_str(&self.message)
    }

    /// Every graph path slot, valid or not.
    fn graph_paths(&self) -> impl Iterator<Item = &PlanGraphPath> {
        self.graph_windows
            .iter()
            .chain([&self.graph_best, &self.graph_baseline])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn malformed_requests_are_refused() {
        let mut req = PlanRequest::new(PlanKind::Offline, &["a", "b"]);
        assert!(req.validate().is_err(), "off-line takes one route");
        req = PlanRequest::new(PlanKind::Offline, &["a"]);
        assert_eq!(req.validate(), Ok(PlanKind::Offline));
        req.step_min = 0;
        assert!(req.validate().is_err());
        let mut req = PlanRequest::new(PlanKind::Now, &["a"]);
        req.kind = 99;
        assert!(req.validate().is_err());
        let mut req = PlanRequest::new(PlanKind::Now, &["a"]);
        req.magic = 0;
        assert!(req.validate().is_err());
        assert_eq!(
            PlanRequest::new(PlanKind::Now, &["x", "y"]).route_names(),
            ["x", "y"]
        );
        let mut req = PlanRequest::graph(1, 2);
        assert_eq!(req.validate(), Ok(PlanKind::Graph));
        req.to_node = 70_000;
        assert!(req.validate().is_err(), "ids are uint16");
        let mut req = PlanRequest::graph(1, 2);
        req.end_minute = 1441;
        assert!(req.validate().is_err());
        let mut req = PlanRequest::graph(1, 2);
        req.route_count = 1;
        assert!(req.validate().is_err(), "graph plans take no routes");
    }
}
