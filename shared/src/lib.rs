//! The common crate of isochron: everything the services and tools share.
//!
//! * [`wire`]: the headers and payload elements of every stream, and their checks;
//! * [`names`]: iceoryx2 service names, under a settable prefix;
//! * [`config`]: the site configuration, with errors located by file, line and key;
//! * [`clock`]: capture time and isochronal time t*;
//! * [`geometry`]: polygons and the block grid over a frame;
//! * [`store`]: the crash-safe long-term (isochronal) store, one SQLite file per camera;
//! * [`ipc`]: iceoryx2 node, publishers and subscribers, sized deliberately;
//! * [`health`]: exit codes, systemd notifications, periodic status;
//! * [`logging`]: `tracing` to journald or stderr;
//! * [`service`]: the start-up every service binary shares.

pub mod clock;
pub mod config;
pub mod geometry;
pub mod health;
pub mod ipc;
pub mod logging;
pub mod names;
pub mod service;
pub mod store;
pub mod wire;
