//! isochron-exporter: every stage's status (the [`StageStatus`] each service
//! publishes over iceoryx2, the one `isochron status` shows) as Prometheus /
//! OpenMetrics metrics at `GET /metrics`.
//!
//! [`metrics`] turns the latest reports into metric families (a
//! `prometheus-client` collector, read at every scrape); [`stage`] is the service:
//! a stage on the shared runtime that reads the reports on its timer and answers
//! the HTTP requests waiting then.
//!
//! [`StageStatus`]: isochron_shared::wire::StageStatus

pub mod metrics;
pub mod stage;
