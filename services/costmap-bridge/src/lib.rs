//! isochron-costmap: the cameras' block activity on the robots' map, published to
//! ROS 2 as a cost map, and path planning on it (DESIGN.md section 5; the paper's
//! sections "Off-line / Real-time Global Path Planning" and "Incorporation into
//! ROS").
//!
//! * [`homography`]: image → floor from a camera's `floor_points` (normalised DLT,
//!   least squares, degenerate sets refused);
//! * [`grid`]: the map grid (from `[costmap]` or a `map_server` YAML);
//! * [`raster`]: which block of a camera covers each grid cell;
//! * [`cost`]: weighted activity → cost 0..100, and the composed cost map;
//! * [`bridge`]: the service's state between samples (latest activity, confirmed
//!   people, staleness);
//! * [`delta`]: full grid or changed rectangle, each tick;
//! * [`msgs`], [`ros`]: `nav_msgs/OccupancyGrid` and `map_msgs/OccupancyGridUpdate`
//!   over DDS in pure Rust (feature `ros2`);
//! * [`snapshot`]: `map_server` PGM + YAML and a PNG picture;
//! * [`stage`]: the service's stage for the runtime (every camera's `activity` and
//!   `detections` in, the cost map out, planning requests answered);
//! * [`plan`], [`planner`]: `cost1`, `cost2`, segments, routes and the long-term
//!   store; [`plan_service`]: the same over iceoryx2 request-response.
//!
//! The binary `isochron-costmap` wires these to iceoryx2 and ROS 2; the `isochron`
//! CLI uses the library (without `ros2`) for `plan`, `costmap` and `plot --segment`.

pub mod bridge;
pub mod cost;
pub mod delta;
pub mod grid;
pub mod homography;
pub mod msgs;
pub mod plan;
pub mod plan_service;
pub mod planner;
pub mod raster;
#[cfg(feature = "ros2")]
pub mod ros;
pub mod snapshot;
#[cfg(feature = "ros2")]
pub mod stage;
