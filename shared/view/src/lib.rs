//! isochron-view: what the group sees, for people — live in Foxglove over its
//! WebSocket protocol (`isochron view`), and in MCAP recordings (`isochron record`,
//! `isochron replay --record`) that open in Foxglove the same way.
//!
//! * [`channels`]: the topics, their Foxglove well-known schemas, and how samples
//!   become messages — one module for both sinks; [`annotations`]: the
//!   detections drawn on a camera's image (boxes, skeletons, model and score);
//! * [`follow`]: one more subscriber of the cameras' streams that never slows a
//!   producer, and the services' status readers;
//! * [`stage`]: the view and the recorder as a stage on the stage runtime
//!   (`StageKind::View`: its own status, the runtime's drop counting);
//! * [`record`]: the MCAP file, closed cleanly also when the disk runs low;
//! * [`live`]: the WebSocket server, on loopback unless the site says otherwise,
//!   for every name of the protocol, each client held to a byte budget and all of
//!   them to one ([`outbox`]), at most `view.max_clients` at once;
//! * [`session`]: one client's side of the protocol, a sink of the channels'
//!   context inside the view's process;
//! * [`jpeg`]: camera frames as small JPEGs (only with `view.frames = true`).
//!
//! The `foxglove` crate (and with it tokio) lives here only, so that the services
//! and the rest of the CLI build without it.

#![warn(missing_docs)]

pub mod annotations;
pub mod channels;
pub mod follow;
pub mod jpeg;
pub mod live;
pub mod outbox;
pub mod record;
pub mod session;
pub mod stage;

pub use foxglove::Context;
