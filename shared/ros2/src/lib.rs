//! The costmap bridge's ROS 2 side: one output on every transport that is on —
//! DDS always (`ros2-client` on RustDDS, pure Rust: no ROS install), Zenoh in
//! rmw_zenoh's format when `[costmap.zenoh]` says so.
//!
//! * [`spec`]: each topic and service declared once — the config key that names
//!   it, its type (DDS name, rmw_zenoh's type hash) and its QoS — and
//!   [`spec::Names`], the names a config gives them;
//! * [`output`]: [`RosOutput`], the node with a [`Publisher`] per topic
//!   ([`publisher`]: each sample out on DDS and on Zenoh) and the planning
//!   services of every transport;
//! * [`plan`]: the planning services' one loop (fair queue, round robin,
//!   counts, warnings, malformed requests answered with status 1) over an
//!   [`plan::Endpoint`] per transport: [`dds::DdsService`] (the request layouts
//!   of rmw_cyclonedds and rmw_fastrtps) and [`zenoh::ZenohService`]
//!   (rmw_zenoh's);
//! * [`msgs`]: the message and service types, serde structs in CDR field order;
//! * [`fair`]: the per-client fair queue of the planning services;
//! * [`route_server`]: the bridge as the route server's client, telling its
//!   `DynamicEdgesScorer` which edges are closed and what they cost, over a
//!   [`route_server::Caller`] per transport ([`dds::DdsCaller`]).
//!
//! The transports' own crates are `isochron-dds` (the participant and node,
//! shared with the link) and `isochron-zenoh` (the session, key expressions and
//! byte layouts of rmw_zenoh).

pub mod dds;
pub mod error;
pub mod fair;
pub mod msgs;
pub mod output;
pub mod plan;
pub mod publisher;
pub mod route_server;
pub mod spec;
pub mod zenoh;

pub use error::{PublishError, RosError, topic_name};
pub use output::{RosOutput, RosSettings, interfaces};
pub use plan::PlanCounts;
pub use publisher::Publisher;
