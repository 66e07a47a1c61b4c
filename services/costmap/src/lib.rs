//! isochron-costmap: the cameras' block activity on the robots' map, published to
//! ROS 2 as a cost map, and the site's planning service (docs/robots.md; the
//! paper's section "Incorporation into ROS").
//!
//! The floor geometry, the costs and the planning itself are in `isochron-planning`,
//! the ROS 2 output (its messages, topics, transports and the planning services'
//! loop) in `isochron-ros2`; this crate is the service around them:
//!
//! * [`bridge`]: the service's state between samples (latest activity, confirmed
//!   people, staleness);
//! * [`delta`]: full grid or changed rectangle, each tick;
//! * [`markers`]: camera footprints, zones, segments and routes for rviz2;
//! * [`people`]: the confirmed people as poses at their feet and as markers
//!   (skeletons from keypoints, else cylinders, labelled with model and score);
//! * snapshots (`map_server` PGM + YAML and a PNG picture) are written with
//!   `isochron_planning::snapshot`, the writer the CLI shares;
//! * [`route_feed`]: the route server fed live: the graph's edges scored,
//!   closed and reopened, and what changed sent to its `DynamicEdgesScorer`;
//! * [`stage`]: the service's stage for the runtime (every camera's `activity` and
//!   `detections` in, the cost map out on `isochron_ros2::RosOutput`, planning
//!   requests answered), with what it publishes and counts (`publish`) and what
//!   it plans and snapshots (`planning`) in modules of their own.
//!
//! The binary `isochron-costmap` runs [`stage`] and answers `<prefix>/plan` with
//! `isochron_planning::plan_service::PlanServer`.

pub mod bridge;
pub mod delta;
pub mod markers;
pub mod people;
mod planning;
mod publish;
pub mod route_feed;
pub mod stage;
