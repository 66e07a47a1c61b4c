//! The costmap bridge's ROS 2 side, apart from its transports:
//!
//! * [`msgs`]: the message and service types, serde structs in CDR field order;
//! * [`fair`]: the per-client fair queue of the planning services.

pub mod fair;
pub mod msgs;
