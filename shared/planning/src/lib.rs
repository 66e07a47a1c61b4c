//! isochron-planning: where and when a robot should go around people, from the
//! cameras' block activity (the paper's sections "Off-line / Real-time Global Path
//! Planning"; docs/ARCHITECTURE.md, "Paper to code").
//!
//! A library without processes of its own: the cost map bridge (`isochron-costmap`)
//! uses it to draw activity on the robots' map and to answer plan queries, and the
//! `isochron` CLI uses it to plan off-line, to ask the bridge, and to check floor
//! mappings — neither depends on the other.
//!
//! * [`homography`]: image → floor from a camera's `floor_points` (normalised DLT,
//!   least squares, degenerate sets refused);
//! * [`calibration`]: per-point and leave-one-out residuals of that fit, and the
//!   point that stands out;
//! * [`grid`]: the map grid (from `[costmap]` or a `map_server` YAML);
//! * [`raster`]: which block of a camera covers each grid cell;
//! * [`cost`]: weighted activity → cost 0..100, and the composed cost map;
//! * [`profile`]: the long-term activity of a set of blocks over the cycle;
//! * [`plan`], [`planner`]: `cost1`, `cost2`, segments, routes and the long-term
//!   store;
//! * [`route_graph`]: the robots' nav2_route graph, each edge a corridor on the
//!   grid, scored from the cost map, closed while people block it, and the
//!   `DynamicEdges` requests that tell the route server;
//! * [`graph_plan`]: planning over that graph across departure times
//!   (time-dependent Dijkstra on the long-term forecast);
//! * [`query`]: the fixed-size plan request and response types;
//! * [`plan_service`]: both ends of the plan query over iceoryx2 request-response;
//! * [`snapshot`]: a cost map as `map_server` PGM + YAML and a PNG picture for
//!   people (the bridge's snapshots and `isochron costmap snapshot --at`).

#![warn(missing_docs)]

pub mod calibration;
pub mod cost;
mod font;
pub mod graph_plan;
pub mod grid;
pub mod homography;
pub mod plan;
pub mod plan_service;
pub mod planner;
pub mod profile;
pub mod query;
pub mod raster;
pub mod route_graph;
pub mod snapshot;
