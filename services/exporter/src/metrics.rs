//! The exporter's metric families, made at every scrape from the latest status of
//! each watched service (a `prometheus-client` [`Collector`]).
//!
//! Every family carries the labels `stage` and `camera` (empty for site-wide
//! stages). Counters are the services' own totals: they restart from 0 when a
//! service restarts, which Prometheus's `rate()` and `increase()` handle as a
//! counter reset. Stage-specific metrics are the stages' counters, named,
//! typed and described by their schemas in the stage table
//! (`isochron_runtime::counters`); a status written with other counters (another
//! build) gives none of them.
//!
//! `isochron_up` is 1 while the last report is younger than
//! `exporter.stale_after_s` and its pid exists (`kill(pid, 0)` ≠ ESRCH), so a
//! killed and reaped service is down at the next scrape, a hung one after the
//! stale time. `prometheus-client` writes OpenMetrics (counter families named
//! without `_total`); a client that does not ask for OpenMetrics in `Accept` gets
//! the classic 0.0.4 text (`_total` on counter families' `HELP`/`TYPE`, no
//! `# EOF`), which is what `promtool check metrics` lints.

use std::sync::Arc;
use std::time::Duration;

use isochron_config::clock::wall_now_ns;
use isochron_runtime::counters::CounterKind as Kind;
use isochron_runtime::health::status_counters;
use isochron_runtime::topology::{STAGES, StageKind};
use isochron_wire::StageStatus;
use parking_lot::{Mutex, MutexGuard};
use prometheus_client::collector::Collector;
use prometheus_client::encoding::{DescriptorEncoder, NoLabelSet};
use prometheus_client::metrics::MetricType;

/// One watched service: a stage of one camera, or of the site.
#[derive(Debug, Clone)]
pub struct Service {
    /// The stage.
    pub stage: StageKind,
    /// The camera ("" for site-wide stages).
    pub camera: String,
    /// Its latest status report, if one ever arrived.
    pub status: Option<StageStatus>,
}

/// The services the exporter watches and what each last reported, shared between
/// the stage (which updates it) and the collector (which reads it at a scrape).
#[derive(Debug)]
pub struct Table {
    services: Mutex<Vec<Service>>,
    stale_after: Duration,
}

impl Table {
    /// A table of `services` (no reports yet); a report older than `stale_after`
    /// means its service is down.
    pub fn new(services: Vec<Service>, stale_after: Duration) -> Arc<Self> {
        Arc::new(Table {
            services: Mutex::new(services),
            stale_after,
        })
    }

    /// Records `status` as the latest report of service `index`.
    pub fn update(&self, index: usize, status: StageStatus) {
        if let Some(s) = self.lock().get_mut(index) {
            s.status = Some(status);
        }
    }

    /// Copies of the services and their last reports.
    pub fn services(&self) -> Vec<Service> {
        self.lock().clone()
    }

    /// How many services are up at `now_ns` (wall clock), and how many are watched.
    pub fn count_up(&self, now_ns: i64) -> (usize, usize) {
        let services = self.lock();
        let up = services
            .iter()
            .filter(|s| is_up(s, now_ns, self.stale_after))
            .count();
        (up, services.len())
    }

    fn lock(&self) -> MutexGuard<'_, Vec<Service>> {
        self.services.lock()
    }
}

/// True when `service` reported within `stale_after` of `now_ns` and its process
/// still exists (a killed service is down at once, not only once its last report
/// is stale).
pub fn is_up(service: &Service, now_ns: i64, stale_after: Duration) -> bool {
    service.status.is_some_and(|s| {
        let age_ns = now_ns.saturating_sub(s.report_wall_ns);
        age_ns <= stale_after.as_nanos() as i64 && process_exists(s.pid)
    })
}

/// False only when no process `pid` exists (ESRCH); a process of another user
/// (EPERM) exists.
fn process_exists(pid: u32) -> bool {
    let Ok(pid) = i32::try_from(pid) else {
        return false;
    };
    if pid <= 0 {
        return false;
    }
    // SAFETY: signal 0 only checks that the process exists; nothing is sent.
    let r = unsafe { libc::kill(pid, 0) };
    r == 0 || std::io::Error::last_os_error().raw_os_error() != Some(libc::ESRCH)
}

/// A metric of every reporting service, from its [`StageStatus`].
struct StatusMetric {
    name: &'static str,
    help: &'static str,
    kind: Kind,
    value: fn(&StageStatus, i64) -> f64,
}

const STATUS_METRICS: &[StatusMetric] = &[
    StatusMetric {
        name: "isochron_received",
        help: "Samples the service received (capture: frames read).",
        kind: Kind::Counter,
        value: |s, _| s.received as f64,
    },
    StatusMetric {
        name: "isochron_sent",
        help: "Samples the service published.",
        kind: Kind::Counter,
        value: |s, _| s.sent as f64,
    },
    StatusMetric {
        name: "isochron_dropped",
        help: "Samples lost: gaps in the input's sequence numbers, and samples the service dropped.",
        kind: Kind::Counter,
        value: |s, _| s.dropped as f64,
    },
    StatusMetric {
        name: "isochron_rejected",
        help: "Malformed samples the service rejected.",
        kind: Kind::Counter,
        value: |s, _| s.rejected as f64,
    },
    StatusMetric {
        name: "isochron_stage_latency_seconds",
        help: "Median time from an input's arrival to the output it caused (recent outputs).",
        kind: Kind::Gauge,
        value: |s, _| f64::from(s.stage_latency_ms) / 1e3,
    },
    StatusMetric {
        name: "isochron_e2e_latency_p50_seconds",
        help: "Median time from capture to this service's output (recent outputs).",
        kind: Kind::Gauge,
        value: |s, _| f64::from(s.e2e_latency_p50_ms) / 1e3,
    },
    StatusMetric {
        name: "isochron_e2e_latency_p99_seconds",
        help: "99th percentile time from capture to this service's output (recent outputs).",
        kind: Kind::Gauge,
        value: |s, _| f64::from(s.e2e_latency_p99_ms) / 1e3,
    },
    StatusMetric {
        name: "isochron_start_time_seconds",
        help: "When the service's process started, Unix time.",
        kind: Kind::Gauge,
        value: |s, _| s.started_wall_ns as f64 / 1e9,
    },
    StatusMetric {
        name: "isochron_status_age_seconds",
        help: "Time since the service's last status report.",
        kind: Kind::Gauge,
        value: |s, now_ns| (now_ns - s.report_wall_ns).max(0) as f64 / 1e9,
    },
];

/// The collector the exporter registers: every metric of every service.
#[derive(Debug)]
pub struct StatusCollector {
    table: Arc<Table>,
}

impl StatusCollector {
    /// A collector reading `table` at every scrape.
    pub fn new(table: Arc<Table>) -> Self {
        StatusCollector { table }
    }
}

fn metric_type(kind: Kind) -> MetricType {
    match kind {
        Kind::Counter => MetricType::Counter,
        Kind::Gauge => MetricType::Gauge,
    }
}

/// Writes one family: its descriptor, then one sample per `(labels, value)`.
fn family(
    encoder: &mut DescriptorEncoder,
    name: &str,
    help: &str,
    kind: Kind,
    samples: &[([(&'static str, String); 2], f64)],
) -> Result<(), std::fmt::Error> {
    let mut metric = encoder.encode_descriptor(name, help, None, metric_type(kind))?;
    for (labels, value) in samples {
        let mut sample = metric.encode_family(labels)?;
        match kind {
            Kind::Counter => sample.encode_counter::<NoLabelSet, _, f64>(value, None)?,
            Kind::Gauge => sample.encode_gauge(value)?,
        }
    }
    Ok(())
}

fn labels(s: &Service) -> [(&'static str, String); 2] {
    [
        ("stage", s.stage.name().to_string()),
        ("camera", s.camera.clone()),
    ]
}

impl Collector for StatusCollector {
    fn encode(&self, mut encoder: DescriptorEncoder) -> Result<(), std::fmt::Error> {
        let services = self.table.services();
        let now_ns = wall_now_ns();
        let up: Vec<_> = services
            .iter()
            .map(|s| {
                let up = is_up(s, now_ns, self.table.stale_after);
                (labels(s), if up { 1.0 } else { 0.0 })
            })
            .collect();
        family(
            &mut encoder,
            "isochron_up",
            "1 while the service reports its status, 0 when its reports stopped or it never reported.",
            Kind::Gauge,
            &up,
        )?;
        let reporting: Vec<(&Service, &StageStatus)> = services
            .iter()
            .filter_map(|s| s.status.as_ref().map(|st| (s, st)))
            .collect();
        for m in STATUS_METRICS {
            let samples: Vec<_> = reporting
                .iter()
                .map(|(s, st)| (labels(s), (m.value)(st, now_ns)))
                .collect();
            family(&mut encoder, m.name, m.help, m.kind, &samples)?;
        }
        for spec in &STAGES {
            let counters: Vec<_> = reporting
                .iter()
                .filter(|(s, _)| s.stage == spec.kind)
                .filter_map(|(s, st)| Some((labels(s), status_counters(st)?)))
                .collect();
            for (k, c) in spec.counters.iter().enumerate() {
                if c.metric.is_empty() {
                    continue;
                }
                let samples: Vec<_> = counters
                    .iter()
                    .map(|(l, values)| {
                        let v = values.iter().nth(k).map_or(0.0, |(_, v)| v);
                        (l.clone(), c.metric_value(v))
                    })
                    .collect();
                family(&mut encoder, c.metric, c.help, c.kind, &samples)?;
            }
        }
        Ok(())
    }
}

/// The Prometheus text format 0.0.4 of `openmetrics` (the OpenMetrics text
/// `prometheus-client` writes), for scrapers and tools that do not ask for
/// OpenMetrics (`promtool check metrics`, curl): a counter family is named with
/// its `_total` suffix in `# HELP` and `# TYPE`, and `# EOF` is left out. Only
/// what this exporter writes is handled (counters and gauges, no units, no
/// exemplars, no `_created`).
pub fn classic_text(openmetrics: &str) -> String {
    let counters: std::collections::HashSet<&str> = openmetrics
        .lines()
        .filter_map(|l| l.strip_prefix("# TYPE "))
        .filter_map(|rest| rest.strip_suffix(" counter"))
        .collect();
    let mut out = String::with_capacity(openmetrics.len() + 16 * counters.len());
    for line in openmetrics.lines() {
        if line == "# EOF" {
            continue;
        }
        let meta = ["# HELP ", "# TYPE "]
            .into_iter()
            .find_map(|p| line.strip_prefix(p).map(|rest| (p, rest)));
        match meta.and_then(|(p, rest)| Some((p, rest.split_once(' ')?))) {
            Some((p, (name, tail))) if counters.contains(name) => {
                out += &format!("{p}{name}_total {tail}");
            }
            _ => out += line,
        }
        out.push('\n');
    }
    out
}

#[cfg(test)]
mod tests;
