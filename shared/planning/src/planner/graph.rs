//! Planning over the route graph with the site's long-term stores: each edge's
//! corridor on the map grid, the blocks of the cameras it covers, and
//! [`plan_graph`] over the forecast they give; and each edge scored now
//! ([`Planner::score_edges`]), what the bridge tells the route server.

use isochron_store::Model;

use super::Planner;
use crate::graph_plan::{GraphPlan, GraphPlanError, GraphPlanParams, GraphPlanRequest, plan_graph};
use crate::grid::MapGrid;
use crate::plan::{PlanError, SegmentBlocks};
use crate::raster::Footprint;
use crate::route_graph::{Corridors, EdgeScore, EdgeScorer, ModelForecast, RouteGraph, seen_cells};

impl Planner {
    /// The plan of `request` over `graph`, each edge's activity forecast from the
    /// blocks its corridor on `grid` covers in the cameras' long-term stores.
    pub fn graph(
        &mut self,
        graph: &RouteGraph,
        grid: &MapGrid,
        request: &GraphPlanRequest,
    ) -> Result<GraphPlan, GraphPlanError> {
        self.refresh()
            .map_err(|e| GraphPlanError::NoData(e.to_string()))?;
        if self.models.iter().all(Option::is_none) {
            return Err(GraphPlanError::NoData(self.no_store().to_string()));
        }
        let footprints: Vec<Option<Footprint>> = self
            .cameras
            .iter()
            .map(|cam| {
                let (h, blocks) = (cam.homography.as_ref()?, cam.blocks?);
                Some(Footprint::build(grid, h, blocks, &cam.config.mask))
            })
            .collect();
        let footprints: Vec<Option<&Footprint>> = footprints.iter().map(Option::as_ref).collect();
        let seen = seen_cells(grid.len(), &footprints);
        let corridors = Corridors::build(graph, grid, self.config.route_edge_width_m, &seen);
        let edges: Vec<SegmentBlocks> = (0..graph.edges().len())
            .map(|e| corridors.segment_blocks(graph, e, &footprints))
            .collect();
        let models: Vec<Option<&Model>> = self.loaded_models();
        let forecast = ModelForecast::new(&edges, &models, self.cycle.bins());
        plan_graph(
            graph,
            &forecast,
            request,
            &GraphPlanParams::from_config(&self.config),
        )
    }

    /// Each edge's score now (`out[e]` for edge `e`): from the live cost map
    /// `live` and the long-term forecast at `t_star` of the blocks its corridor
    /// covers (`edges[e]`, [`Corridors::segment_blocks`]). A store that cannot be
    /// read leaves the long-term part out (the last model read stands in) and is
    /// returned after the scoring.
    pub fn score_edges(
        &mut self,
        corridors: &Corridors,
        edges: &[SegmentBlocks],
        live: &[i8],
        t_star: u32,
        out: &mut Vec<EdgeScore>,
    ) -> Result<(), PlanError> {
        let refreshed = self.refresh();
        let models: Vec<Option<&Model>> = self.loaded_models();
        let mut forecast = ModelForecast::new(edges, &models, self.cycle.bins());
        forecast.read([t_star]);
        EdgeScorer::from_config(&self.config).score(corridors, live, &forecast, t_star, out);
        refreshed
    }
}
