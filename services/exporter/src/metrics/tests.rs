use super::*;
use isochron_runtime::counters::{Counters, gate};
use isochron_runtime::health::starting_status;
use isochron_runtime::topology::StageKind;
use isochron_wire::CameraId;
use prometheus_client::registry::Registry;

fn status(stage: StageKind, counters: &Counters, report_wall_ns: i64) -> StageStatus {
    StageStatus {
        started_wall_ns: 1_000_000_000,
        report_wall_ns,
        received: 10,
        sent: 9,
        dropped: 1,
        stage_latency_ms: 2.5,
        e2e_latency_p50_ms: 40.0,
        e2e_latency_p99_ms: 90.0,
        counters: counters.slots(),
        ..starting_status(CameraId::new("cam01").unwrap(), stage)
    }
}

fn none(stage: StageKind) -> Counters {
    Counters::new(stage.counters())
}

#[test]
fn a_status_of_other_counters_gives_no_counter_metrics() {
    let mut c = none(StageKind::Gate);
    c.set(gate::EVENTS, 4u64);
    let mut foreign = status(StageKind::Gate, &c, wall_now_ns());
    foreign.schema ^= 0xdead;
    let table = Table::new(
        vec![Service {
            stage: StageKind::Gate,
            camera: "cam01".into(),
            status: Some(foreign),
        }],
        Duration::from_secs(15),
    );
    let mut registry = Registry::default();
    registry.register_collector(Box::new(StatusCollector::new(table)));
    let mut text = String::new();
    prometheus_client::encoding::text::encode(&mut text, &registry).unwrap();
    assert!(text.contains("isochron_received_total{stage=\"gate\",camera=\"cam01\"} 10"));
    assert!(!text.contains("isochron_gate_events_total{"), "{text}");
}

#[test]
fn a_stale_or_dead_service_is_down() {
    let now = wall_now_ns();
    let stale = Duration::from_secs(15);
    let fresh = Service {
        stage: StageKind::Capture,
        camera: "cam01".into(),
        status: Some(status(
            StageKind::Capture,
            &none(StageKind::Capture),
            now - 1_000_000_000,
        )),
    };
    assert!(is_up(&fresh, now, stale));
    let old = Service {
        status: Some(status(
            StageKind::Capture,
            &none(StageKind::Capture),
            now - 20_000_000_000,
        )),
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
    let mut gate_counters = none(StageKind::Gate);
    gate_counters.set(gate::EVENTS, 4u64);
    gate_counters.set(gate::OPEN, 1u64);
    gate_counters.set(gate::DETECTOR_MS, 2500.0);
    gate_counters.set(gate::JOBS_DROPPED, 3u64);
    let table = Table::new(
        vec![
            Service {
                stage: StageKind::Gate,
                camera: "cam01".into(),
                status: Some(status(StageKind::Gate, &gate_counters, now)),
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
