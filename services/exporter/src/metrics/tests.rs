use super::*;
use isochron_wire::{CameraId, LAYOUT_VERSION, MAGIC, STAGE_NAME_LEN, STATUS_DETAIL_LEN, to_fixed};
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
