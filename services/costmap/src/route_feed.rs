//! The route server fed live (with `costmap.route_graph` and ROS 2 on): every
//! `costmap.route_update_s` each edge of the graph is scored from the live cost
//! map and the long-term model ([`Planner::score_edges`]), closed and reopened by
//! its [`ClosureGate`](isochron_planning::route_graph::ClosureGate), and what
//! changed goes to the route server's `DynamicEdgesScorer` on every transport
//! ([`RouteLink`]). Each link has its own tracker, as each server has been told
//! its own. Edges that are not `overridable` and edges no camera sees are never
//! named.
//!
//! The corridors are laid on the cameras' footprints as the bridge has them
//! (one appears with a camera's first activity): when the footprints change, the
//! corridors and trackers are made anew and every server is told everything.

use std::time::{Duration, Instant};

use isochron_config::CostmapConfig;
use isochron_planning::grid::MapGrid;
use isochron_planning::plan::SegmentBlocks;
use isochron_planning::planner::Planner;
use isochron_planning::raster::Footprint;
use isochron_planning::route_graph::{
    Corridors, DynamicEdgesRequest, DynamicEdgesTracker, EdgeScore, RouteGraph, TrackerSettings,
    seen_cells,
};
use isochron_ros2::msgs::{DynamicEdges, EdgeCost};
use isochron_ros2::route_server::{Ready, RouteCounts, RouteLink};

/// The corridors on one set of footprints, and a tracker per link.
struct Laid {
    /// Per camera, the block grid and seen cells of its footprint.
    key: Vec<Option<(usize, usize)>>,
    corridors: Corridors,
    edges: Vec<SegmentBlocks>,
    trackers: Vec<DynamicEdgesTracker>,
}

/// Where the cameras see: the bridge's grid and each camera's footprint (none
/// before its first activity).
pub struct Sight<'a> {
    /// The bridge's grid.
    pub grid: &'a MapGrid,
    /// Per camera, its footprint on the grid.
    pub footprints: &'a [Option<&'a Footprint>],
}

/// Feeds the route server.
pub struct RouteFeed {
    graph: RouteGraph,
    width_m: f64,
    settings: TrackerSettings,
    every: Duration,
    next: Instant,
    started: Instant,
    laid: Option<Laid>,
    scores: Vec<EdgeScore>,
}

impl RouteFeed {
    /// The feed of `graph` as `c` configures it.
    pub fn new(graph: RouteGraph, c: &CostmapConfig, now: Instant) -> RouteFeed {
        RouteFeed {
            graph,
            width_m: c.route_edge_width_m,
            settings: TrackerSettings::from_config(c),
            every: isochron_config::clock::saturating_secs(c.route_update_s),
            next: now,
            started: now,
            laid: None,
            scores: Vec::new(),
        }
    }

    /// One pass of the bridge's loop: every link follows its server and takes
    /// its answers; when an update is due, the edges are scored from `live`
    /// (composed on demand: the cost map's cells) at `t_star` and each link
    /// that may send is told what changed (or everything). Returns a warning
    /// when the long-term store could not be read.
    pub fn tick(
        &mut self,
        links: &mut [RouteLink],
        sight: &Sight<'_>,
        planner: &mut Planner,
        live: impl FnOnce() -> Option<Vec<i8>>,
        t_star: u32,
        now: Instant,
    ) -> Option<String> {
        let ready: Vec<Ready> = links.iter_mut().map(|l| l.poll(now)).collect();
        let everything_now = ready.contains(&Ready::Everything);
        if now < self.next && !everything_now {
            return None;
        }
        if now >= self.next {
            self.next = now + self.every;
        }
        self.lay(sight, links);
        let laid = self.laid.as_mut()?;
        let cells = live().unwrap_or_default();
        let warning = planner
            .score_edges(
                &laid.corridors,
                &laid.edges,
                &cells,
                t_star,
                &mut self.scores,
            )
            .err()
            .map(|e| format!("route server: edges scored without the long-term model: {e}"));
        let now_s = now.duration_since(self.started).as_secs_f64();
        for ((link, ready), tracker) in links.iter_mut().zip(ready).zip(&mut laid.trackers) {
            let changes = tracker.update(&self.scores, now_s);
            let request = match ready {
                Ready::Everything => tracker.resend_all(),
                Ready::Changes => changes,
                Ready::No => {
                    if !changes.is_empty() {
                        link.missed();
                    }
                    continue;
                }
            };
            if !request.is_empty() {
                link.send(&message(&request), now);
            }
        }
        warning
    }

    /// Edges closed now (by the first link's tracker: the gates are the same in
    /// all).
    pub fn closed(&self) -> usize {
        self.laid
            .as_ref()
            .and_then(|l| l.trackers.first())
            .map_or(0, |t| t.closed().count())
    }

    /// Lays the corridors on `footprints` unless they are already laid there;
    /// anew, every link is told everything.
    fn lay(&mut self, sight: &Sight<'_>, links: &mut [RouteLink]) {
        let Sight { grid, footprints } = *sight;
        let key: Vec<Option<(usize, usize)>> = footprints
            .iter()
            .map(|f| f.map(|f| (f.blocks.len(), f.seen)))
            .collect();
        if self.laid.as_ref().is_some_and(|l| l.key == key) {
            return;
        }
        let seen = seen_cells(grid.len(), footprints);
        let corridors = Corridors::build(&self.graph, grid, self.width_m, &seen);
        let edges = (0..self.graph.edges().len())
            .map(|e| corridors.segment_blocks(&self.graph, e, footprints))
            .collect();
        let trackers = links
            .iter()
            .map(|_| DynamicEdgesTracker::new(&self.graph, &corridors, self.settings))
            .collect();
        for link in links.iter_mut() {
            link.missed();
        }
        self.laid = Some(Laid {
            key,
            corridors,
            edges,
            trackers,
        });
    }
}

/// `request` as `nav2_msgs/srv/DynamicEdges`.
fn message(request: &DynamicEdgesRequest) -> DynamicEdges {
    DynamicEdges {
        closed_edges: request.closed_edges.clone(),
        opened_edges: request.opened_edges.clone(),
        adjust_edges: request
            .adjust_edges
            .iter()
            .map(|e| EdgeCost {
                edgeid: e.edgeid,
                cost: e.cost,
            })
            .collect(),
    }
}

/// The links' counts together.
pub fn total(links: &[RouteLink]) -> RouteCounts {
    links.iter().fold(RouteCounts::default(), |sum, link| {
        let c = link.counts();
        RouteCounts {
            calls: sum.calls + c.calls,
            failures: sum.failures + c.failures,
            edges: sum.edges + c.edges,
            latency_ms: c.latency_ms.or(sum.latency_ms),
            up: sum.up || c.up,
        }
    })
}
