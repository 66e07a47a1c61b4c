//! isochron-link: a site of several base stations. Shared memory ends at a box's
//! edge; this service carries the small streams of the cameras a box exports —
//! `activity`, `events`, `detections` and the stages' status — to the boxes that
//! import them, over ROS 2 DDS (the engine the costmap bridge already speaks), and
//! never frames (docs/many-boxes.md). It is a site-wide stage (`StageKind::Link`)
//! that `isochron up` does not start: its own unit does.
//!
//! * [`msgs`]: `isochron_msgs/msg/Activity`, `Event`, `Detections` and `Status`
//!   (ros/isochron_msgs), the box id, the iceoryx2 header and the payload, field
//!   for field — the wire types themselves, so no second layout can drift (a unit
//!   test pins the CDR size);
//! * [`dds`]: the DDS participant and per camera one topic per stream: activity
//!   best effort, keep last 1; events and detections reliable, bounded by
//!   `link.queue_messages`; status one report per stage;
//! * [`stage`]: exported cameras' streams in, DDS out; imported cameras' DDS in,
//!   their streams into this box's iceoryx2 services out, with the remote header
//!   (sequence, capture and origin times) unchanged and every message validated
//!   first (`Message::validate`: box id, the header's bounded sizes, the camera's
//!   `KnownGrid`); a remote stage's status as this box saw it (report time = arrival
//!   time, pid = the link's).
//!
//! **Security.** With `link.security_dir` the participant runs DDS Security
//! (`isochron_dds::RosNode::start` with an enclave: RustDDS's built-in plugins
//! through `DomainParticipantBuilder::builtin_security`, the six files of
//! `isochron_dds::ENCLAVE_FILES`). Without one, `LinkStage::open` refuses (exit 78)
//! when DDS may use an interface other than loopback
//! (`LinkConfig::leaves_the_box`) unless `link.insecure`. The governance that
//! `isochron keystore` writes sets `data_protection_kind` NONE: the data is
//! encrypted inside the protected submessage, and RustDDS 0.15 encrypts each
//! fragment of a payload-protected sample on its own, which its own reader then
//! refuses (a fragment longer than the fragment size), so a fragmented activity
//! message never arrived. Each reader reassembles at most its topic's largest
//! message (`Message::max_cdr_len`, `Status::max_cdr_len`, through
//! `isochron_dds::bounded` and the patched RustDDS of `vendor/`).
//!
//! **Open files.** RustDDS makes each reader's poll and status channels from socket
//! pairs (four sockets per reader, two per writer; it panics when it cannot make
//! one), and the iceoryx2 side adds a port tag, a dynamic config and a data segment
//! per publisher (plus a notifier's port tag and event config) and 3 files per
//! remote stage's status publisher: 43 files per imported camera once every stream
//! has crossed, 38 per exported one (`FileBudget`, `stage/checks.rs`). The link checks,
//! before it joins DDS, that its open-file limit holds that budget, and otherwise
//! exits (78) with one line naming `LimitNOFILE=` and the value needed. Before, a
//! link past the limit died at its N-th first sample with iceoryx2's
//! `InternalFailure` (an `EMFILE` inside) — 1 152 imported cameras under a hard
//! limit of 20 000.

pub mod dds;
pub mod msgs;
pub mod stage;
