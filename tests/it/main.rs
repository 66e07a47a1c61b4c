//! The multi-process integration tests, one module per area, in one test binary
//! (linking OpenCV and the services' crates once instead of once per area).
//!
//! Every test gets its own site (directory, config, iceoryx2 prefix, DDS domain),
//! so the tests of all areas run in parallel in this one process. Run one area
//! with a filter, e.g. `cargo test -p isochron-tests --test it -- capture::`.

// The tests' helpers fail their test when they unwrap, as the tests themselves may
// (clippy's allow-unwrap-in-tests covers only #[test] functions); a test reads as one
// scenario from start to end, however long.
#![allow(
    clippy::unwrap_used,
    reason = "helpers of tests: a failure panics the test"
)]
#![allow(
    clippy::too_many_lines,
    reason = "a test is one scenario, read top to bottom"
)]

mod capture;
mod cascade;
mod conventions;
mod costmap;
mod doctor;
mod exporter;
mod gate;
mod hostile;
mod inputs;
mod launcher;
mod link;
mod motion;
mod mqtt;
mod nav2;
mod operations;
mod package;
mod pipeline;
mod presence;
mod reliability;
mod scale;
mod systemd;
mod view;
