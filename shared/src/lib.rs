//! The common crate of isochron: everything the services and tools share.
//!
//! * [`wire`]: the headers and payload elements of every stream, and their checks;
//! * [`names`]: iceoryx2 service names, under a settable prefix;
//! * [`config`]: the site configuration, with errors located by file, line and key;
//! * [`clock`]: capture time and isochronal time t*;
//! * [`geometry`]: polygons and the block grid over a frame;
//! * [`store`]: the crash-safe long-term (isochronal) store, one SQLite file per camera;
//! * [`ipc`]: iceoryx2 node, publishers and subscribers, sized deliberately;
//! * [`exit`]: exit codes, and the one rule that maps a library error to one;
//! * [`health`]: systemd notifications, periodic status;
//! * [`stage`]: the stage runtime, the one event loop every service runs;
//! * [`topology`]: the stages, their binaries and the streams between them;
//! * [`logging`]: `tracing` to journald or stderr;
//! * [`service`]: the start-up every service binary shares.

pub mod clock;
pub mod config;
pub mod exit;
pub mod geometry;
pub mod health;
pub mod ipc;
pub mod logging;
pub mod names;
pub mod rng;
pub mod service;
pub mod stage;
pub mod store;
pub mod topology;
pub mod wire;
