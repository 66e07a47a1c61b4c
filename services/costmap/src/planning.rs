//! The planning side of the cost-map stage: requests answered with the site's
//! long-term planner and the live cost map, and snapshots written.

use std::path::PathBuf;
use std::time::Instant;

use isochron_config::LoadedConfig;
use isochron_config::clock::{Cycle, SiteClock, format_rfc3339, timestamp, wall_now_ns};
use isochron_planning::graph_plan::{GraphPlanError, GraphPlanRequest};
use isochron_planning::plan::{DayRange, PlanError};
use isochron_planning::plan_service::{answer_graph, answer_now, answer_offline};
use isochron_planning::planner::Planner;
use isochron_planning::query::{PlanKind, PlanRequest, PlanResponse, PlanStatus};
use isochron_planning::route_graph::RouteGraph;
use isochron_planning::snapshot::{self, FloorPlan, Snapshot, SnapshotError};

use crate::bridge::Bridge;

/// Why no snapshot was written.
#[derive(Debug, thiserror::Error)]
pub(crate) enum SnapshotFailure {
    /// No grid to take a picture of.
    #[error("no [costmap] grid is configured (map_yaml or width_cells/height_cells)")]
    NoGrid,
    /// The bridge composed no cells.
    #[error("no grid")]
    NoCells,
    /// Writing the files failed.
    #[error("{0}")]
    Write(#[from] SnapshotError),
}

/// What answers planning requests and writes snapshots: the site, its long-term
/// planner and clock, the floor plan, where snapshots go, the robots' route graph.
pub(crate) struct Planning {
    pub(crate) loaded: LoadedConfig,
    pub(crate) planner: Planner,
    pub(crate) clock: SiteClock,
    pub(crate) floor_plan: Option<FloorPlan>,
    pub(crate) snapshot_dir: PathBuf,
    /// `costmap.route_graph`, if configured.
    pub(crate) route_graph: Option<RouteGraph>,
}

impl Planning {
    /// Writes a snapshot of the cost map that `bridge` composes now; returns its YAML path.
    pub(crate) fn write_snapshot(
        &self,
        bridge: &Bridge,
        now: Instant,
    ) -> Result<String, SnapshotFailure> {
        let (loaded, dir, floor_plan) =
            (&self.loaded, &self.snapshot_dir, self.floor_plan.as_ref());
        let grid = bridge.grid.as_ref().ok_or(SnapshotFailure::NoGrid)?;
        let cells = bridge.compose(now).ok_or(SnapshotFailure::NoCells)?;
        let stamp_ns = bridge.newest(now).map_or_else(wall_now_ns, |(t, _)| t);
        let ts = timestamp(stamp_ns);
        let stem = format!(
            "activity-{}{:03}Z",
            ts.strftime("%Y%m%dT%H%M%S."),
            ts.subsec_millisecond()
        );
        let coverage = bridge.coverage();
        let polygons: Vec<&[[f64; 2]]> = loaded.config.costmap.segment_polygons();
        let stamp = format_rfc3339(stamp_ns);
        // As many as `coverage`: the cameras with a footprint.
        let camera_ids: Vec<&str> = bridge
            .cameras
            .iter()
            .filter(|c| c.footprint.is_some())
            .map(|c| c.id.as_str())
            .collect();
        let files = snapshot::write(
            dir,
            &stem,
            &Snapshot {
                grid,
                cells: &cells,
                floor_plan,
                coverage: &coverage,
                camera_ids: &camera_ids,
                segments: &polygons,
                zones: &snapshot::floor_zones(&loaded.config.cameras),
                caption: &format!("ACTIVITY COST {stamp}"),
                stamp: &stamp,
            },
        )?;
        snapshot::prune(dir, "activity-", loaded.config.costmap.snapshot_keep)?;
        Ok(files.yaml.display().to_string())
    }

    /// Answers one planning request (a snapshot written counts in `snapshots`).
    pub(crate) fn answer(
        &mut self,
        kind: PlanKind,
        request: &PlanRequest,
        bridge: &Bridge,
        snapshots: &mut u64,
    ) -> PlanResponse {
        let (planner, clock) = (&mut self.planner, &self.clock);
        let now = Instant::now();
        let failed =
            |status: PlanStatus, message: String| PlanResponse::new(kind as u32, status, &message);
        let status_of = |e: &PlanError| match e {
            PlanError::UnknownRoute(..) => PlanStatus::UnknownRoute,
            PlanError::NoData(_) | PlanError::EmptySegment(_) => PlanStatus::NoData,
            _ => PlanStatus::Failed,
        };
        // "Now" is the time of the newest activity (header time), else the wall clock.
        let now_ns = bridge.newest(now).map_or_else(wall_now_ns, |(t, _)| t);
        match kind {
            PlanKind::Offline => {
                let route = request.route_names().remove(0);
                let range = day_range(request, planner.cycle(), clock.t_star(now_ns));
                match planner.offline(&route, range) {
                    Ok(plan) => answer_offline(&plan),
                    Err(e) => failed(status_of(&e), e.to_string()),
                }
            }
            PlanKind::Now => {
                let t_star = bridge
                    .newest(now)
                    .map_or_else(|| clock.t_star(now_ns), |(_, t)| t);
                let live = bridge.live(now);
                match planner.now(&request.route_names(), &live, t_star) {
                    Ok(ranked) => answer_now(&ranked, t_star),
                    Err(e) => failed(status_of(&e), e.to_string()),
                }
            }
            PlanKind::Graph => {
                let t_star = bridge
                    .newest(now)
                    .map_or_else(|| clock.t_star(now_ns), |(_, t)| t);
                self.answer_graph(request, bridge, t_star)
            }
            PlanKind::Snapshot => match self.write_snapshot(bridge, now) {
                Ok(path) => {
                    *snapshots += 1;
                    tracing::info!("snapshot written: {path}");
                    PlanResponse::new(kind as u32, PlanStatus::Ok, &path)
                }
                Err(e) if bridge.grid.is_none() => failed(PlanStatus::NoData, e.to_string()),
                Err(e) => failed(PlanStatus::Failed, e.to_string()),
            },
        }
    }
}

impl Planning {
    /// Answers a graph request at isochronal time `now_t_star` (the baseline's
    /// departure).
    fn answer_graph(
        &mut self,
        request: &PlanRequest,
        bridge: &Bridge,
        now_t_star: u32,
    ) -> PlanResponse {
        let kind = PlanKind::Graph as u32;
        let no_data = |m: &str| PlanResponse::new(kind, PlanStatus::NoData, m);
        let Some(graph) = &self.route_graph else {
            return no_data("no route graph is configured (costmap.route_graph)");
        };
        let Some(grid) = &bridge.grid else {
            return no_data(
                "no [costmap] grid (map_yaml or width_cells/height_cells) to lay the route graph on",
            );
        };
        let graph_request = GraphPlanRequest {
            from: request.from_node as u16,
            to: request.to_node as u16,
            range: day_range(request, self.planner.cycle(), now_t_star),
            now_t_star,
        };
        match self.planner.graph(graph, grid, &graph_request) {
            Ok(plan) => answer_graph(&plan),
            Err(e) => {
                let status = match e {
                    GraphPlanError::UnknownNode(_) => PlanStatus::UnknownNode,
                    GraphPlanError::NoPath { .. } => PlanStatus::NoPath,
                    GraphPlanError::BadWindow(_) => PlanStatus::BadRequest,
                    GraphPlanError::NoData(_) => PlanStatus::NoData,
                    GraphPlanError::BadParams(_) => PlanStatus::Failed,
                };
                PlanResponse::new(kind, status, &e.to_string())
            }
        }
    }
}

/// The departures of an off-line or graph `request`: its minutes and step, on its
/// weekday of a weekly `cycle` (7: the day of `now_t_star`).
fn day_range(request: &PlanRequest, cycle: Cycle, now_t_star: u32) -> DayRange {
    let cycle_offset = match cycle {
        Cycle::Daily => 0,
        Cycle::Weekly | Cycle::DayTypes => {
            let day = if request.weekday == 7 {
                now_t_star / 1440
            } else {
                request.weekday
            };
            day * 1440
        }
    };
    DayRange {
        start: request.start_minute,
        end: request.end_minute,
        step: request.step_min,
        cycle_offset,
    }
}
