//! Planning over the route graph with the site's long-term stores: each edge's
//! corridor on the map grid, the blocks of the cameras it covers, and
//! [`plan_graph`] over the forecast they give.

use isochron_store::Model;

use super::Planner;
use crate::graph_plan::{GraphPlan, GraphPlanError, GraphPlanParams, GraphPlanRequest, plan_graph};
use crate::grid::MapGrid;
use crate::plan::SegmentBlocks;
use crate::raster::Footprint;
use crate::route_graph::{Corridors, ModelForecast, RouteGraph, seen_cells};

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
}
