//! `isochron-mqtt`: a real Mosquitto broker on a loopback port receives the zone
//! events and detections of the demo video, in order, through a broker restart
//! in the middle; every message the gate emitted is either received or counted
//! as dropped. An unreachable broker is one warning while the group runs on; a
//! malformed broker URL is one line and exit 78 while the group runs on.

use std::collections::{BTreeMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::mpsc::{Receiver, channel};
use std::time::{Duration, Instant};

use isochron_tests::{Proc, TestSite, bin, eventually, free_port, vtest};
use rumqttc::{Client, Event, Incoming, MqttOptions, QoS};
use serde_json::Value;

/// A Mosquitto broker on 127.0.0.1:`port` that keeps its sessions (and the
/// messages queued for them) across a restart.
struct Broker {
    conf: PathBuf,
    port: u16,
    proc: Option<Proc>,
}

impl Broker {
    fn start(dir: &Path, port: u16) -> Broker {
        let data = dir.join("mosquitto");
        std::fs::create_dir_all(&data).unwrap();
        let conf = dir.join("mosquitto.conf");
        std::fs::write(
            &conf,
            format!(
                "listener {port} 127.0.0.1\nallow_anonymous true\npersistence true\npersistence_location {}/\n# started as root (CI): stay root, the directory is ours\nuser root\n",
                data.display()
            ),
        )
        .unwrap();
        let mut broker = Broker {
            conf,
            port,
            proc: None,
        };
        broker.run();
        broker
    }

    fn run(&mut self) {
        let mosquitto = ["/usr/sbin/mosquitto", "/usr/bin/mosquitto"]
            .into_iter()
            .map(PathBuf::from)
            .find(|p| p.is_file())
            .expect("mosquitto is installed (Debian package mosquitto; cargo xtask setup)");
        let proc = Proc::spawn(&mosquitto, &["-c", &self.conf.display().to_string()]);
        let port = self.port;
        eventually(Duration::from_secs(10), || {
            std::net::TcpStream::connect(("127.0.0.1", port)).ok()
        })
        .unwrap_or_else(|| panic!("mosquitto does not listen on {port}: {}", proc.stderr()));
        self.proc = Some(proc);
    }

    /// Stops the broker (it saves its sessions) and starts it again after `down`.
    fn restart(&mut self, down: Duration) {
        if let Some(mut p) = self.proc.take() {
            let status = p.terminate(Duration::from_secs(10));
            assert!(status.success(), "mosquitto: {status:?} {}", p.stderr());
        }
        std::thread::sleep(down);
        self.run();
    }
}

/// A message the test's subscriber received.
struct Received {
    topic: String,
    payload: String,
}

/// A subscriber of `filter` with a persistent session (the broker keeps what
/// arrives while it is away), reconnecting on its own; it says when it first
/// subscribed.
fn subscribe(port: u16, filter: &str) -> Receiver<Option<Received>> {
    let (tx, rx) = channel();
    let filter = filter.to_string();
    let mut options = MqttOptions::new("isochron-test-subscriber", "127.0.0.1", port);
    options
        .set_clean_session(false)
        .set_keep_alive(Duration::from_secs(5));
    let (client, mut connection) = Client::new(options, 16);
    std::thread::spawn(move || {
        for event in connection.iter() {
            match event {
                Ok(Event::Incoming(Incoming::ConnAck(_))) => {
                    let _ = client.try_subscribe(&filter, QoS::AtLeastOnce);
                }
                Ok(Event::Incoming(Incoming::SubAck(_))) => {
                    if tx.send(None).is_err() {
                        return;
                    }
                }
                Ok(Event::Incoming(Incoming::Publish(p))) => {
                    let m = Received {
                        topic: p.topic.clone(),
                        payload: String::from_utf8_lossy(&p.payload).into_owned(),
                    };
                    if tx.send(Some(m)).is_err() {
                        return;
                    }
                }
                Ok(_) => {}
                Err(_) => std::thread::sleep(Duration::from_millis(100)),
            }
        }
    });
    rx
}

/// What the subscriber received: distinct messages (topic, sequence), their
/// order per topic, and the status payloads.
#[derive(Default)]
struct Arrived {
    seen: HashSet<(String, u64)>,
    order: BTreeMap<String, Vec<u64>>,
    statuses: Vec<String>,
}

impl Arrived {
    fn take(&mut self, m: Received) {
        if m.topic.ends_with("/status") {
            self.statuses.push(m.payload);
            return;
        }
        let v: Value = serde_json::from_str(&m.payload).expect("JSON");
        let sequence = v["sequence"].as_u64().unwrap();
        if self.seen.insert((m.topic.clone(), sequence)) {
            self.order.entry(m.topic).or_default().push(sequence);
        }
    }
}

/// The value of `key=` in the last status line of `log` that has it.
fn status_value(log: &str, key: &str) -> Option<String> {
    let needle = format!("{key}=");
    let line = log.lines().rev().find(|l| l.contains(&needle))?;
    let at = line.find(&needle)? + needle.len();
    Some(line[at..].split_whitespace().next()?.to_string())
}

fn mqtt_section(port: u16, extra: &str) -> String {
    format!("[mqtt]\nbroker = \"mqtt://127.0.0.1:{port}\"\nreconnect_max_s = 1\n{extra}\n")
}

#[test]
fn the_demo_video_reaches_the_broker_in_order_through_a_restart() {
    let port = free_port();
    let site = TestSite::with_source(
        "mqtt-replay",
        &format!(
            "{}\n[gate]\ndetect_every_s = 2.0",
            mqtt_section(port, "queue_len = 2")
        ),
        "replaced-by-replay",
    );
    let mut broker = Broker::start(site.dir.path(), port);
    let messages = subscribe(port, "isochron/test/#");
    messages
        .recv_timeout(Duration::from_secs(10))
        .expect("the subscriber subscribed");

    let out = site.path("out");
    let args = [
        "replay".to_string(),
        vtest().display().to_string(),
        "--out".into(),
        out.display().to_string(),
        "--config".into(),
        site.config_path().display().to_string(),
        "--start".into(),
        "2026-03-02T07:00:00Z".into(),
        "--speed".into(),
        "max".into(),
    ];
    let started = Instant::now();
    let mut replay = Proc::spawn(&bin("isochron"), &args);

    // The first event, then the broker goes away and comes back 1.5 s later:
    // longer than the 2 messages the sink may hold take to arrive.
    let mut got: Vec<Received> = Vec::new();
    while !got.iter().any(|m| m.topic.ends_with("/events")) {
        match messages.recv_timeout(Duration::from_secs(60)) {
            Ok(Some(m)) => got.push(m),
            Ok(None) => {}
            Err(_) => panic!("no event within 60 s; replay: {}", replay.stderr()),
        }
    }
    let first_event = started.elapsed();
    broker.restart(Duration::from_millis(1500));
    let restarted = started.elapsed();

    let done = replay.finish(Duration::from_secs(120));
    let replay_s = started.elapsed().as_secs_f64();
    assert!(done.status.success(), "replay: {}", done.stderr);
    let log = std::fs::read_to_string(out.join("logs/mqtt.log")).unwrap();
    let number = |key: &str| -> u64 {
        status_value(&log, key)
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("no {key}= in mqtt.log:\n{log}"))
    };
    let (queued, dropped, sent) = (number("messages"), number("queue_dropped"), number("out"));

    // What the gate emitted, from replay's own files: a start and an end record
    // per event, and the detections that found someone.
    let summary: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let events = summary["counts"]["events"].as_u64().unwrap();
    let with_people = std::fs::read_to_string(out.join("detections.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str::<Value>(l).unwrap())
        .filter(|d| d["detections"].as_array().is_some_and(|a| !a.is_empty()))
        .count() as u64;
    let emitted = 2 * events + with_people;
    assert!(events >= 1 && with_people >= 1, "{summary}");
    assert_eq!(
        queued, emitted,
        "the sink took every record of the gate\n{log}"
    );

    // Everything not dropped arrives (QoS 1, so some may arrive twice).
    let expected_distinct = (emitted - dropped) as usize;
    let mut got_all = Arrived::default();
    for m in got.drain(..) {
        got_all.take(m);
    }
    let deadline = Instant::now() + Duration::from_secs(10);
    while got_all.seen.len() < expected_distinct
        || got_all.statuses.last().map(String::as_str) != Some("offline")
    {
        let left = deadline.saturating_duration_since(Instant::now());
        match messages.recv_timeout(left) {
            Ok(Some(m)) => got_all.take(m),
            Ok(None) => {}
            Err(_) => break,
        }
    }
    let Arrived {
        seen,
        order,
        statuses,
    } = got_all;
    println!(
        "mqtt: {emitted} messages ({events} events × 2 records, {with_people} detections); \
         first event {:.1} s after start, broker restarted at {:.1} s, replay done at {replay_s:.1} s; \
         broker acked {sent}, queue dropped {dropped}, subscriber got {} distinct; \
         reconnects {}; sample received → PUBACK ms p50/p99 {}",
        first_event.as_secs_f64(),
        restarted.as_secs_f64(),
        seen.len(),
        number("reconnects"),
        status_value(&log, "ack_ms").unwrap_or_default(),
    );
    assert_eq!(
        seen.len(),
        expected_distinct,
        "received + dropped = emitted (none silently lost)\n{log}"
    );
    assert_eq!(sent + dropped, emitted, "acked + dropped = emitted\n{log}");
    assert!(number("reconnects") >= 1, "the restart was seen\n{log}");
    for (topic, sequences) in &order {
        assert!(
            sequences.windows(2).all(|w| w[0] < w[1]),
            "{topic} out of order: {sequences:?}"
        );
    }
    // Online at each connection, offline (retained) after the clean stop.
    assert!(
        statuses.iter().filter(|s| *s == "online").count() >= 2,
        "{statuses:?}"
    );
    assert_eq!(statuses.last().map(String::as_str), Some("offline"));
}

#[test]
fn a_bad_broker_url_or_an_unreachable_broker_stops_only_the_sink() {
    let port = free_port();
    let camera = format!(
        "[[camera]]\nid = \"cam01\"\nsource = \"{}\"\nspeed = 2\nloop = true\n",
        vtest().display()
    );
    let site = TestSite::new(
        "mqtt-bad",
        &format!("[mqtt]\nbroker = \"tcp://127.0.0.1:{port}\"\n\n{camera}"),
    );
    let mut capture = site.spawn("isochron-capture", &["--camera", "cam01"]);

    // Malformed: one line naming file, line, key and what was expected; exit 78.
    let mut sink = site.spawn("isochron-mqtt", &[]);
    let status = sink.wait(Duration::from_secs(20)).expect("the sink exits");
    assert_eq!(status.code(), Some(78), "{}", sink.stderr());
    let stderr = sink.stderr();
    let errors: Vec<&str> = stderr.lines().filter(|l| l.contains("ERROR")).collect();
    assert_eq!(errors.len(), 1, "{stderr}");
    assert!(
        errors[0].contains("site.toml:7: key `mqtt.broker`: expected a broker URL such as \"mqtt://127.0.0.1:1883\""),
        "{stderr}"
    );

    // Unreachable: one warning, and the sink keeps trying (backoff up to 1 s).
    site.write_config(&format!("{}\n{camera}", mqtt_section(port, "")));
    let sink = site.spawn("isochron-mqtt", &[]);
    assert!(
        sink.wait_for_stderr("cannot reach the MQTT broker", Duration::from_secs(20)),
        "{}",
        sink.stderr()
    );
    std::thread::sleep(Duration::from_secs(3));
    let stderr = sink.stderr();
    let warnings: Vec<&str> = stderr.lines().filter(|l| l.contains("WARN")).collect();
    assert_eq!(warnings.len(), 1, "{stderr}");
    assert!(
        warnings[0].contains(&format!("mqtt://127.0.0.1:{port}")),
        "{stderr}"
    );
    // The group runs on: capture is still there, and so is the sink.
    assert!(
        capture.wait(Duration::ZERO).is_none(),
        "{}",
        capture.stderr()
    );
    assert!(stderr.contains("connected=0"), "the sink reports: {stderr}");
}
