//! isochron-link: a site of several base stations. Shared memory ends at a box's
//! edge; this service carries the small streams of the cameras a box exports to
//! the boxes that import them, over ROS 2 DDS (the engine the costmap bridge
//! already speaks), and never frames (docs/ARCHITECTURE.md, "Many base stations").
//!
//! * [`msgs`]: `isochron_msgs/msg/Activity` (ros/isochron_msgs), the header and
//!   blocks of an `activity` sample, field for field;
//! * [`dds`]: the DDS participant, one best-effort keep-last-1 topic per camera;
//! * [`stage`]: the service's stage: exported cameras' `activity` in, DDS out;
//!   imported cameras' DDS in, `activity` into this box's iceoryx2 services out,
//!   with the remote header (sequence, capture and origin times) unchanged.

pub mod dds;
pub mod msgs;
pub mod stage;
