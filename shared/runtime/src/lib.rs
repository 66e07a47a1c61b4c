//! isochron-runtime: what every isochron service runs on.
//!
//! * [`stage`]: the stage runtime, the one event loop every service runs;
//! * [`ipc`]: iceoryx2 node, publishers and subscribers, sized deliberately;
//! * [`names`]: iceoryx2 service names, under a settable prefix;
//! * [`topology`]: the stages, their binaries and the streams between them;
//! * [`health`]: systemd notifications, periodic status;
//! * [`logging`]: `tracing` to journald or stderr;
//! * [`service`]: the start-up every service binary shares.

pub mod counters;
pub mod health;
pub mod ipc;
pub mod logging;
pub mod names;
pub mod scheduling;
pub mod service;
pub mod stage;
pub mod topology;
