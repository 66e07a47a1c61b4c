//! The exporter's metric families, made at every scrape from the latest status of
//! each watched service (a `prometheus-client` [`Collector`]).
//!
//! Every family carries the labels `stage` and `camera` (empty for site-wide
//! stages). Counters are the services' own totals: they restart from 0 when a
//! service restarts, which Prometheus's `rate()` and `increase()` handle as a
//! counter reset. Stage-specific counters come from the status detail
//! (`key=value` words, see each stage's `detail`), named in [`DETAIL_METRICS`].
//!
//! `isochron_up` is 1 while the last report is younger than
//! `exporter.stale_after_s` and its pid exists (`kill(pid, 0)` ≠ ESRCH), so a
//! killed and reaped service is down at the next scrape, a hung one after the
//! stale time. `prometheus-client` writes OpenMetrics (counter families named
//! without `_total`); a client that does not ask for OpenMetrics in `Accept` gets
//! the classic 0.0.4 text (`_total` on counter families' `HELP`/`TYPE`, no
//! `# EOF`), which is what `promtool check metrics` lints.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use isochron_config::clock::wall_now_ns;
use isochron_runtime::health::detail_value;
use isochron_runtime::topology::StageKind;
use isochron_wire::{StageStatus, fixed_str};
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

    fn lock(&self) -> std::sync::MutexGuard<'_, Vec<Service>> {
        self.services.lock().unwrap_or_else(|e| e.into_inner())
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

/// Counter or gauge.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// A total that only grows (until its service restarts).
    Counter,
    /// A value that goes up and down.
    Gauge,
}

/// Which part of a detail value: `a` or `b` of `a/b` (`commit_ms=p50/p99`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Part {
    /// The whole value.
    Whole,
    /// Before the `/`.
    First,
    /// After the `/`.
    Second,
}

/// A metric read from a stage's status detail.
#[derive(Debug, Clone, Copy)]
pub struct DetailMetric {
    /// The stage whose detail has it.
    pub stage: StageKind,
    /// The detail key.
    pub key: &'static str,
    /// The metric's name (counters get `_total` when encoded).
    pub name: &'static str,
    /// Its help text.
    pub help: &'static str,
    /// Counter or gauge.
    pub kind: Kind,
    /// The part of the value.
    pub part: Part,
    /// Factor from the detail's unit to the metric's (ms → s: 1e-3).
    pub scale: f64,
    /// The key is left out of the detail while it is 0.
    pub absent_is_zero: bool,
}

const fn detail(
    stage: StageKind,
    key: &'static str,
    name: &'static str,
    help: &'static str,
    kind: Kind,
) -> DetailMetric {
    DetailMetric {
        stage,
        key,
        name,
        help,
        kind,
        part: Part::Whole,
        scale: 1.0,
        absent_is_zero: false,
    }
}

/// The stage-specific metrics, from the status details.
pub const DETAIL_METRICS: &[DetailMetric] = &[
    detail(
        StageKind::Capture,
        "reconnects",
        "isochron_capture_reconnects",
        "Times capture reopened its camera or file after a failure.",
        Kind::Counter,
    ),
    detail(
        StageKind::Motion,
        "restarts",
        "isochron_motion_restarts",
        "Times motion restarted its detector (a new frame size or stream).",
        Kind::Counter,
    ),
    detail(
        StageKind::Gate,
        "events",
        "isochron_gate_events",
        "Zone events the gate started.",
        Kind::Counter,
    ),
    detail(
        StageKind::Gate,
        "open",
        "isochron_gate_open_events",
        "Zone events open now.",
        Kind::Gauge,
    ),
    detail(
        StageKind::Gate,
        "detected",
        "isochron_detector_frames",
        "Frames the detector finished.",
        Kind::Counter,
    ),
    DetailMetric {
        scale: 1e-3,
        ..detail(
            StageKind::Gate,
            "detector_ms",
            "isochron_detector_busy_seconds",
            "Time the detector spent detecting.",
            Kind::Counter,
        )
    },
    detail(
        StageKind::Gate,
        "jobs_dropped",
        "isochron_detector_jobs_dropped",
        "Detection jobs dropped because the detector was busy.",
        Kind::Counter,
    ),
    detail(
        StageKind::Cascade,
        "commits",
        "isochron_store_commits",
        "Commits to the long-term store.",
        Kind::Counter,
    ),
    DetailMetric {
        part: Part::First,
        scale: 1e-3,
        ..detail(
            StageKind::Cascade,
            "commit_ms",
            "isochron_store_commit_latency_p50_seconds",
            "Median time of a store commit (recent commits).",
            Kind::Gauge,
        )
    },
    DetailMetric {
        part: Part::Second,
        scale: 1e-3,
        ..detail(
            StageKind::Cascade,
            "commit_ms",
            "isochron_store_commit_latency_p99_seconds",
            "99th percentile time of a store commit (recent commits).",
            Kind::Gauge,
        )
    },
    DetailMetric {
        absent_is_zero: true,
        ..detail(
            StageKind::Cascade,
            "store_failures",
            "isochron_store_failures",
            "Store commits that failed.",
            Kind::Counter,
        )
    },
    detail(
        StageKind::Costmap,
        "ros_subscribers",
        "isochron_ros_subscribers",
        "ROS 2 subscribers of the cost map topic.",
        Kind::Gauge,
    ),
    detail(
        StageKind::Costmap,
        "publish_errors",
        "isochron_ros_publish_errors",
        "Cost map publications to ROS 2 that failed.",
        Kind::Counter,
    ),
    detail(
        StageKind::Costmap,
        "updates",
        "isochron_costmap_updates",
        "Cost map updates published.",
        Kind::Counter,
    ),
    DetailMetric {
        part: Part::First,
        ..detail(
            StageKind::Costmap,
            "cameras_live",
            "isochron_costmap_cameras_live",
            "Cameras whose activity reached the cost map recently.",
            Kind::Gauge,
        )
    },
    detail(
        StageKind::Mqtt,
        "connected",
        "isochron_mqtt_connected",
        "1 while the MQTT sink is connected to its broker.",
        Kind::Gauge,
    ),
    detail(
        StageKind::Mqtt,
        "messages",
        "isochron_mqtt_messages",
        "Messages (zone events, detections) the MQTT sink queued for the broker.",
        Kind::Counter,
    ),
    detail(
        StageKind::Mqtt,
        "queued",
        "isochron_mqtt_queued",
        "Messages waiting for the broker.",
        Kind::Gauge,
    ),
    detail(
        StageKind::Mqtt,
        "queue_dropped",
        "isochron_mqtt_queue_dropped",
        "Messages dropped because the queue to the broker was full.",
        Kind::Counter,
    ),
    detail(
        StageKind::Mqtt,
        "reconnects",
        "isochron_mqtt_reconnects",
        "Times the MQTT sink connected to its broker again.",
        Kind::Counter,
    ),
    detail(
        StageKind::Mqtt,
        "refused",
        "isochron_mqtt_refused",
        "Connection attempts the MQTT broker refused (bad user name or password, not authorized).",
        Kind::Counter,
    ),
    detail(
        StageKind::Mqtt,
        "tls_failures",
        "isochron_mqtt_tls_failures",
        "Connection attempts to the MQTT broker whose TLS handshake failed.",
        Kind::Counter,
    ),
    detail(
        StageKind::Mqtt,
        "events_rejected",
        "isochron_mqtt_events_rejected",
        "Zone event records the MQTT sink rejected as impossible (ending before they start) and did not publish.",
        Kind::Counter,
    ),
    DetailMetric {
        part: Part::First,
        scale: 1e-3,
        ..detail(
            StageKind::Mqtt,
            "ack_ms",
            "isochron_mqtt_ack_latency_p50_seconds",
            "Median time from the sink receiving a gate's sample to the broker's acknowledgement (recent messages).",
            Kind::Gauge,
        )
    },
    DetailMetric {
        part: Part::Second,
        scale: 1e-3,
        ..detail(
            StageKind::Mqtt,
            "ack_ms",
            "isochron_mqtt_ack_latency_p99_seconds",
            "99th percentile time from the sink receiving a gate's sample to the broker's acknowledgement (recent messages).",
            Kind::Gauge,
        )
    },
];

impl DetailMetric {
    /// The value in `detail`, if it has one.
    pub fn value(&self, detail: &str) -> Option<f64> {
        let Some(raw) = detail_value(detail, self.key) else {
            return self.absent_is_zero.then_some(0.0);
        };
        let part = match (self.part, raw.split_once('/')) {
            (Part::Whole, _) => raw,
            (Part::First, Some((a, _))) => a,
            (Part::Second, Some((_, b))) => b,
            (_, None) => return None,
        };
        let v: f64 = part.parse().ok()?;
        v.is_finite().then_some(v * self.scale)
    }
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
        for m in DETAIL_METRICS {
            let samples: Vec<_> = reporting
                .iter()
                .filter(|(s, _)| s.stage == m.stage)
                .filter_map(|(s, st)| Some((labels(s), m.value(&fixed_str(&st.detail))?)))
                .collect();
            family(&mut encoder, m.name, m.help, m.kind, &samples)?;
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
mod tests {
    use super::*;
    use isochron_wire::{
        CameraId, LAYOUT_VERSION, MAGIC, STAGE_NAME_LEN, STATUS_DETAIL_LEN, to_fixed,
    };
    use prometheus_client::registry::Registry;

    fn status(stage: StageKind, detail: &str, report_wall_ns: i64) -> StageStatus {
        StageStatus {
            magic: MAGIC,
            layout_version: LAYOUT_VERSION,
            reserved: 0,
            camera: CameraId::new("cam01").unwrap(),
            stage: to_fixed::<STAGE_NAME_LEN>(stage.name()),
            pid: std::process::id(),
            rate_in: 0.0,
            started_wall_ns: 1_000_000_000,
            report_wall_ns,
            received: 10,
            sent: 9,
            dropped: 1,
            rejected: 0,
            rate_out: 0.0,
            stage_latency_ms: 2.5,
            e2e_latency_p50_ms: 40.0,
            e2e_latency_p99_ms: 90.0,
            detail: to_fixed::<STATUS_DETAIL_LEN>(detail),
        }
    }

    #[test]
    fn detail_values_are_parsed_scaled_and_split() {
        let d = "seconds=3 commits=7 commit_ms=1.50/9.00";
        let by_name = |n: &str| DETAIL_METRICS.iter().find(|m| m.name == n).unwrap();
        assert_eq!(by_name("isochron_store_commits").value(d), Some(7.0));
        let p50 = by_name("isochron_store_commit_latency_p50_seconds").value(d);
        assert!((p50.unwrap() - 0.0015).abs() < 1e-12);
        let p99 = by_name("isochron_store_commit_latency_p99_seconds").value(d);
        assert!((p99.unwrap() - 0.009).abs() < 1e-12);
        assert_eq!(by_name("isochron_store_failures").value(d), Some(0.0));
        assert_eq!(by_name("isochron_gate_events").value(d), None);
        assert_eq!(by_name("isochron_store_commits").value("commits=x"), None);
        let mqtt = "connected=1 messages=9 queued=0 queue_dropped=2 reconnects=1 refused=3 tls_failures=0 events_rejected=4 ack_ms=1.5/4.0 broker=mqtts://127.0.0.1:8883";
        assert_eq!(
            by_name("isochron_mqtt_queue_dropped").value(mqtt),
            Some(2.0)
        );
        assert_eq!(by_name("isochron_mqtt_connected").value(mqtt), Some(1.0));
        assert_eq!(by_name("isochron_mqtt_refused").value(mqtt), Some(3.0));
        assert_eq!(
            by_name("isochron_mqtt_events_rejected").value(mqtt),
            Some(4.0)
        );
        let p99 = by_name("isochron_mqtt_ack_latency_p99_seconds").value(mqtt);
        assert!((p99.unwrap() - 0.004).abs() < 1e-12);
    }

    #[test]
    fn a_stale_or_dead_service_is_down() {
        let now = wall_now_ns();
        let stale = Duration::from_secs(15);
        let fresh = Service {
            stage: StageKind::Capture,
            camera: "cam01".into(),
            status: Some(status(StageKind::Capture, "", now - 1_000_000_000)),
        };
        assert!(is_up(&fresh, now, stale));
        let old = Service {
            status: Some(status(StageKind::Capture, "", now - 20_000_000_000)),
            ..fresh.clone()
        };
        assert!(!is_up(&old, now, stale));
        let mut dead = fresh.clone();
        dead.status.as_mut().unwrap().pid = i32::MAX as u32; // above pid_max
        assert!(!is_up(&dead, now, stale));
        let never = Service {
            status: None,
            ..fresh
        };
        assert!(!is_up(&never, now, stale));
    }

    #[test]
    fn the_scrape_has_every_family_with_stage_and_camera_labels() {
        let now = wall_now_ns();
        let table = Table::new(
            vec![
                Service {
                    stage: StageKind::Gate,
                    camera: "cam01".into(),
                    status: Some(status(
                        StageKind::Gate,
                        "detector=hog events=4 open=1 frames_seen=90 detected=12 detector_ms=2500 jobs_dropped=3",
                        now,
                    )),
                },
                Service {
                    stage: StageKind::Costmap,
                    camera: String::new(),
                    status: None,
                },
            ],
            Duration::from_secs(15),
        );
        let mut registry = Registry::default();
        registry.register_collector(Box::new(StatusCollector::new(table)));
        let mut text = String::new();
        prometheus_client::encoding::text::encode(&mut text, &registry).unwrap();
        for line in [
            "isochron_up{stage=\"gate\",camera=\"cam01\"} 1",
            "isochron_up{stage=\"costmap\",camera=\"\"} 0",
            "isochron_received_total{stage=\"gate\",camera=\"cam01\"} 10.0",
            "isochron_detector_busy_seconds_total{stage=\"gate\",camera=\"cam01\"} 2.5",
            "isochron_detector_jobs_dropped_total{stage=\"gate\",camera=\"cam01\"} 3",
            "isochron_gate_open_events{stage=\"gate\",camera=\"cam01\"} 1",
            "isochron_e2e_latency_p99_seconds{stage=\"gate\",camera=\"cam01\"} 0.09",
        ] {
            assert!(
                text.lines().any(|l| l.starts_with(line)),
                "no {line} in\n{text}"
            );
        }
        assert!(!text.contains("isochron_received_total{stage=\"costmap\""));
        assert!(text.ends_with("# EOF\n"));

        let classic = classic_text(&text);
        for line in [
            "# HELP isochron_received_total Samples the service received (capture: frames read).",
            "# TYPE isochron_received_total counter",
            "isochron_received_total{stage=\"gate\",camera=\"cam01\"} 10.0",
            "# TYPE isochron_up gauge",
        ] {
            assert!(
                classic.lines().any(|l| l == line),
                "no {line} in\n{classic}"
            );
        }
        assert!(!classic.contains("# EOF"));
        assert!(!classic.contains("# TYPE isochron_received counter"));
    }
}
