//! isochron-exporter: every stage's status (the [`StageStatus`] each service
//! publishes over iceoryx2, the one `isochron status` shows) as Prometheus /
//! OpenMetrics metrics at `GET /metrics`.
//!
//! [`metrics`] turns the latest reports into metric families (a
//! `prometheus-client` collector, read at every scrape); [`http`] serves them
//! within bounds on connections, request size and time; [`stage`] is the
//! service: a stage on the shared runtime that reads the reports on its timer.
//!
//! [`StageStatus`]: isochron_wire::StageStatus

pub mod http;
pub mod metrics;
pub mod stage;
