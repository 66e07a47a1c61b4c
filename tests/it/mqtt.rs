//! `isochron-mqtt`: a real Mosquitto broker on a loopback port receives the zone
//! events and detections of the demo video, in order, through a broker restart
//! in the middle; every message the gate emitted is either received or counted
//! as dropped. An unreachable broker is one warning while the group runs on; a
//! malformed broker URL is one line and exit 78 while the group runs on.
//!
//! Over TLS (certificates made here with openssl, a Mosquitto password file, a
//! listener that requires client certificates): events arrive at Mosquitto's own
//! `mosquitto_sub`, nothing crosses in clear, a forged event that ends before it
//! starts is counted and never published, a missing client certificate is one
//! TLS error; a broker that stops accepting the sink's password is one clear,
//! counted error while the sink runs on, and its change of mind is logged.

use std::collections::{BTreeMap, HashSet};
use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;
use std::sync::mpsc::{Receiver, channel};
use std::time::{Duration, Instant};

use isochron_config::clock::wall_now_ns;
use isochron_runtime::ipc::Events;
use isochron_tests::{Proc, TestSite, bin, eventually, free_port, named_thread, vtest};
use isochron_wire::{ActivityKind, CameraId, EventHeader, EventPhase, Preamble, Stream, to_fixed};
use parking_lot::Mutex;
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
        Broker::start_with(
            dir,
            port,
            &format!("listener {port} 127.0.0.1\nallow_anonymous true\n"),
        )
    }

    /// A broker with the listeners and security settings `listeners`; `port` is
    /// the one to wait for.
    fn start_with(dir: &Path, port: u16, listeners: &str) -> Broker {
        let data = dir.join("mosquitto");
        std::fs::create_dir_all(&data).unwrap();
        let conf = dir.join("mosquitto.conf");
        std::fs::write(
            &conf,
            format!(
                "{listeners}\npersistence true\npersistence_location {}/\n# started as root (CI): stay root, the directory is ours\nuser root\n",
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

    /// Makes the broker read its configuration and password file again
    /// (SIGHUP); it disconnects clients its new settings no longer allow.
    fn reload(&self) {
        self.proc.as_ref().unwrap().signal(libc::SIGHUP);
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
        .set_keep_alive(Duration::from_secs(5))
        // Detections with keypoints outgrow rumqttc's default 10 KiB.
        .set_max_packet_size(1 << 20, 10 * 1024);
    let (client, mut connection) = Client::new(options, 16);
    named_thread("mqtt-connection", move || {
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
        // Paced (8 s for the 80 s clip), so that the replay is still running when
        // the broker is back: at full speed a fast machine ends it within a second
        // of the restart, before the sink's next reconnect attempt.
        "--speed".into(),
        "10".into(),
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

/// The certificates of one test, made with openssl in `dir`: a CA (`ca.pem`),
/// the broker's (`broker.pem`/`broker.key`, for 127.0.0.1 and localhost) and a
/// client's (`client.pem`/`client.key`), both signed by the CA.
fn make_certificates(dir: &Path) {
    let openssl = |args: &[&str]| {
        let out = Command::new("openssl")
            .args(args)
            .current_dir(dir)
            .output()
            .expect("openssl is installed (Debian package openssl; cargo xtask setup)");
        assert!(
            out.status.success(),
            "openssl {args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    };
    let ec = [
        "-newkey",
        "ec",
        "-pkeyopt",
        "ec_paramgen_curve:prime256v1",
        "-nodes",
    ];
    let mut ca = vec!["req", "-x509"];
    ca.extend(ec);
    ca.extend([
        "-keyout",
        "ca.key",
        "-out",
        "ca.pem",
        "-days",
        "2",
        "-subj",
        "/CN=isochron test CA",
    ]);
    openssl(&ca);
    for (name, ext) in [
        (
            "broker",
            "subjectAltName=IP:127.0.0.1,DNS:localhost\nextendedKeyUsage=serverAuth\n",
        ),
        ("client", "extendedKeyUsage=clientAuth\n"),
    ] {
        std::fs::write(dir.join(format!("{name}.ext")), ext).unwrap();
        let (key, csr, pem, ext) = (
            format!("{name}.key"),
            format!("{name}.csr"),
            format!("{name}.pem"),
            format!("{name}.ext"),
        );
        let subject = format!("/CN=isochron test {name}");
        let mut req = vec!["req"];
        req.extend(ec);
        req.extend(["-keyout", &key, "-out", &csr, "-subj", &subject]);
        openssl(&req);
        openssl(&[
            "x509",
            "-req",
            "-in",
            &csr,
            "-CA",
            "ca.pem",
            "-CAkey",
            "ca.key",
            "-CAcreateserial",
            "-out",
            &pem,
            "-days",
            "2",
            "-extfile",
            &ext,
        ]);
    }
}

/// Writes Mosquitto's password file `passwd` in `dir` with `users` (name,
/// password), through Mosquitto's own `mosquitto_passwd`.
fn write_passwords(dir: &Path, users: &[(&str, &str)]) {
    let file = dir.join("passwd");
    let _ = std::fs::remove_file(&file);
    for (k, (user, password)) in users.iter().enumerate() {
        let mut args = vec!["-b"];
        if k == 0 {
            args.push("-c");
        }
        let file = file.display().to_string();
        args.extend([file.as_str(), user, password]);
        let out = Command::new("mosquitto_passwd")
            .args(&args)
            .output()
            .expect("mosquitto_passwd (Debian package mosquitto)");
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
}

/// A TLS listener of Mosquitto on `port` with the test's certificates; with
/// `require_certificate` it asks every client for one (mutual TLS).
fn tls_listener(dir: &Path, port: u16, require_certificate: bool) -> String {
    format!(
        "listener {port} 127.0.0.1\ncafile {d}/ca.pem\ncertfile {d}/broker.pem\nkeyfile {d}/broker.key\nrequire_certificate {require_certificate}\n",
        d = dir.display()
    )
}

/// Mosquitto's settings for password-only access: no anonymous clients, the
/// password file `passwd` in `dir`.
fn password_access(dir: &Path) -> String {
    format!(
        "per_listener_settings false\nallow_anonymous false\npassword_file {}/passwd\n",
        dir.display()
    )
}

/// Mosquitto's own subscriber, `mosquitto_sub`, on the TLS listener `port` as
/// user "reader", printing `topic payload` lines.
fn mosquitto_sub(dir: &Path, port: u16) -> Proc {
    let sub = ["/usr/bin/mosquitto_sub", "/usr/local/bin/mosquitto_sub"]
        .into_iter()
        .map(PathBuf::from)
        .find(|p| p.is_file())
        .expect("mosquitto_sub is installed (Debian package mosquitto-clients; cargo xtask setup)");
    let ca = dir.join("ca.pem").display().to_string();
    let port = port.to_string();
    Proc::spawn(
        &sub,
        &[
            "-h",
            "127.0.0.1",
            "-p",
            &port,
            "--cafile",
            &ca,
            "-u",
            "reader",
            "-P",
            "reader-pw",
            "-i",
            "isochron-test-reader",
            "-q",
            "1",
            "-v",
            "-t",
            "isochron/test/#",
        ],
    )
}

/// A loopback TCP relay to `port`: what the clients send through it is
/// recorded, to check that nothing crosses in clear.
fn recording_relay(port: u16) -> (u16, Arc<Mutex<Vec<u8>>>) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let relay_port = listener.local_addr().unwrap().port();
    let recorded = Arc::new(Mutex::new(Vec::new()));
    let record = recorded.clone();
    named_thread("relay-accept", move || {
        for client in listener.incoming() {
            let Ok(mut client) = client else { return };
            let Ok(mut upstream) = TcpStream::connect(("127.0.0.1", port)) else {
                continue;
            };
            let (mut client_r, mut upstream_w) =
                (client.try_clone().unwrap(), upstream.try_clone().unwrap());
            let record = record.clone();
            named_thread("relay-to-broker", move || {
                let mut buf = [0u8; 16 << 10];
                while let Ok(n) = client_r.read(&mut buf) {
                    if n == 0 || upstream_w.write_all(&buf[..n]).is_err() {
                        break;
                    }
                    record.lock().extend_from_slice(&buf[..n]);
                }
                let _ = upstream_w.shutdown(std::net::Shutdown::Write);
            });
            named_thread("relay-to-client", move || {
                let _ = std::io::copy(&mut upstream, &mut client);
                let _ = client.shutdown(std::net::Shutdown::Write);
            });
        }
    });
    (relay_port, recorded)
}

/// An event record of cam01 as the gate writes it: a start, or an end after
/// `duration_s` (negative: forged).
fn event(sequence: u64, event_id: u64, end: bool, duration_s: f64) -> EventHeader {
    let camera = CameraId::new("cam01").unwrap();
    let start_ns = 1_772_434_800_000_000_000; // 2026-03-02T07:00:00Z
    let end_ns = start_ns + (duration_s * 1e9) as i64;
    let mut preamble = Preamble::new::<u32>(Stream::Events, camera, sequence, 1);
    preamble.capture_time_ns = if end { end_ns } else { start_ns };
    preamble.origin_wall_ns = wall_now_ns();
    EventHeader {
        preamble,
        event_id,
        zone: to_fixed("door"),
        kind: ActivityKind::Moving as u32,
        phase: if end {
            EventPhase::End
        } else {
            EventPhase::Start
        } as u32,
        start_ns,
        end_ns: if end { end_ns } else { 0 },
        start_frame: 100,
        end_frame: if end { 150 } else { 0 },
        peak: 0.6,
        threshold: 0.25,
    }
}

/// The value of `key=` in the sink's latest status report line in `stderr`.
fn reported(proc: &Proc, key: &str) -> Option<u64> {
    status_value(&proc.stderr(), key)?.parse().ok()
}

/// The sink under `RUST_LOG=debug`, so that a password in any log line shows.
fn spawn_sink_debug(site: &TestSite) -> Proc {
    let config = site.config_path().display().to_string();
    let sink = bin("isochron-mqtt").display().to_string();
    Proc::spawn(
        Path::new("/usr/bin/env"),
        &["RUST_LOG=debug", &sink, "--config", &config],
    )
}

fn camera_toml() -> &'static str {
    "[[camera]]\nid = \"cam01\"\nsource = \"unused.avi\"\n"
}

fn errors(stderr: &str) -> Vec<&str> {
    stderr.lines().filter(|l| l.contains("ERROR")).collect()
}

#[test]
fn events_cross_mutual_tls_with_a_password_and_a_forged_event_is_never_published() {
    let site = TestSite::new("mqtt-tls", camera_toml());
    let dir = site.dir.path();
    make_certificates(dir);
    write_passwords(
        dir,
        &[("isochron", "sink-pw-3141"), ("reader", "reader-pw")],
    );
    // One listener for password-only clients (the reader), one that also
    // requires a client certificate (the sink).
    let (plain_tls, mutual) = (free_port(), free_port());
    let broker = Broker::start_with(
        dir,
        mutual,
        &format!(
            "{}{}{}",
            password_access(dir),
            tls_listener(dir, plain_tls, false),
            tls_listener(dir, mutual, true)
        ),
    );
    std::fs::write(dir.join("sink-password"), "sink-pw-3141\n").unwrap();
    std::fs::set_permissions(
        dir.join("sink-password"),
        std::os::unix::fs::PermissionsExt::from_mode(0o600),
    )
    .unwrap();
    let mqtt = |port: u16, client_cert: bool| {
        let cert = if client_cert {
            "client_cert_file = \"client.pem\"\nclient_key_file = \"client.key\"\n"
        } else {
            ""
        };
        format!(
            "[mqtt]\nbroker = \"mqtts://127.0.0.1:{port}\"\nca_file = \"ca.pem\"\n{cert}username = \"isochron\"\npassword_file = \"sink-password\"\nreconnect_max_s = 1\n\n{}",
            camera_toml()
        )
    };

    // Without its client certificate the mutual-TLS listener refuses the
    // handshake: one error line naming TLS, counted, and the sink runs on.
    site.write_config(&mqtt(mutual, false));
    let mut no_cert = site.spawn("isochron-mqtt", &[]);
    let counted = eventually(Duration::from_secs(15), || {
        reported(&no_cert, "tls_failures").filter(|n| *n >= 1)
    });
    let stderr = no_cert.stderr();
    assert!(counted.is_some(), "no TLS failure counted: {stderr}");
    let errs = errors(&stderr);
    assert_eq!(errs.len(), 1, "{stderr}");
    assert!(
        errs[0].contains(&format!(
            "TLS with the MQTT broker mqtts://127.0.0.1:{mutual} failed"
        )),
        "{stderr}"
    );
    assert!(no_cert.wait(Duration::ZERO).is_none(), "{stderr}");
    no_cert.terminate(Duration::from_secs(10));

    // With it, through a relay that records what the sink sends.
    let (relay, recorded) = recording_relay(mutual);
    site.write_config(&mqtt(relay, true));
    let mut sink = spawn_sink_debug(&site);
    assert!(
        sink.wait_for_stderr(
            &format!("connected to the MQTT broker mqtts://127.0.0.1:{relay} as user \"isochron\" over TLS"),
            Duration::from_secs(20)
        ),
        "{}",
        sink.stderr()
    );
    let mut reader = mosquitto_sub(dir, plain_tls);
    reader
        .wait_for_line("isochron/test/status online", Duration::from_secs(20))
        .unwrap_or_else(|| panic!("mosquitto_sub got no status: {}", reader.stderr()));

    // The gate's events, and one forged record that ends 3 s before it starts.
    let ipc = site.ipc("mqtt-tls-gate");
    let gate = ipc.publisher::<Events>("cam01", 4).unwrap();
    eventually(Duration::from_secs(20), || {
        (gate.subscriber_count() > 0).then_some(())
    })
    .expect("the sink subscribes to cam01's events");
    for header in [
        event(0, 1, false, 0.0),
        event(1, 1, true, 2.5),
        event(2, 666, true, -3.0),
        event(3, 2, false, 0.0),
    ] {
        gate.send_copy(header, &[7]).unwrap();
    }
    let events_of = |out: &str| -> Vec<(u64, String, Value)> {
        out.lines()
            .filter_map(|l| l.strip_prefix("isochron/test/cam01/events "))
            .map(|payload| {
                let json: Value = serde_json::from_str(payload).unwrap();
                let phase = json["phase"].as_str().unwrap().to_string();
                (
                    json["event_id"].as_u64().unwrap(),
                    phase,
                    json["duration_s"].clone(),
                )
            })
            .collect()
    };
    eventually(Duration::from_secs(15), || {
        (events_of(&reader.stdout()).len() >= 3).then_some(())
    });
    // A late forged record would show by now.
    std::thread::sleep(Duration::from_secs(1));
    let out = reader.stdout();
    let got = events_of(&out);
    println!("mqtt over mutual TLS: mosquitto_sub got {got:?}");
    assert_eq!(
        got.iter()
            .map(|(id, phase, _)| (*id, phase.as_str()))
            .collect::<Vec<_>>(),
        vec![(1, "start"), (1, "end"), (2, "start")],
        "{out}\nsink: {}",
        sink.stderr()
    );
    assert_eq!(got[1].2, serde_json::json!(2.5));
    // Refused where it enters: the sample's header check (an end record that
    // ends before it starts), counted as rejected, one line saying why.
    let rejected = eventually(Duration::from_secs(10), || {
        reported(&sink, "rejected").filter(|n| *n >= 1)
    });
    let stderr = sink.stderr();
    assert_eq!(rejected, Some(1), "{stderr}");
    assert!(
        stderr.contains("rejected events sample") && stderr.contains("not before start_ns"),
        "{stderr}"
    );

    // Nothing in clear: the relay saw a TLS handshake, not MQTT.
    let bytes = recorded.lock().clone();
    let text = String::from_utf8_lossy(&bytes);
    println!(
        "relay: {} bytes from the sink, first {:02x?}",
        bytes.len(),
        &bytes[..bytes.len().min(3)]
    );
    assert!(
        bytes.len() > 500 && bytes.starts_with(&[0x16, 0x03]),
        "{:02x?}",
        &bytes[..bytes.len().min(16)]
    );
    for clear in ["MQTT", "isochron/test", "sink-pw-3141", "door", "event_id"] {
        assert!(!text.contains(clear), "{clear} crossed in clear");
    }
    assert!(
        !stderr.contains("sink-pw-3141"),
        "the password is logged: {stderr}"
    );
    assert!(errors(&stderr).is_empty(), "{stderr}");
    let done = sink.terminate(Duration::from_secs(15));
    assert!(done.success(), "{}", sink.stderr());
    drop(broker);
}

#[test]
fn a_broker_that_stops_taking_the_password_is_one_counted_error_and_the_sink_runs_on() {
    let site = TestSite::new("mqtt-auth", camera_toml());
    let dir = site.dir.path();
    make_certificates(dir);
    let port = free_port();

    // A TLS file that is not there: one line naming the key and the file, 78.
    site.write_config(&format!(
        "[mqtt]\nbroker = \"mqtts://127.0.0.1:{port}\"\nca_file = \"missing-ca.pem\"\n\n{}",
        camera_toml()
    ));
    let mut bad = site.spawn("isochron-mqtt", &[]);
    let status = bad.wait(Duration::from_secs(20)).expect("the sink exits");
    assert_eq!(status.code(), Some(78), "{}", bad.stderr());
    let stderr = bad.stderr();
    let errs = errors(&stderr);
    assert_eq!(errs.len(), 1, "{stderr}");
    let line = std::fs::read_to_string(site.config_path())
        .unwrap()
        .lines()
        .position(|l| l.starts_with("ca_file"))
        .unwrap()
        + 1;
    assert!(
        errs[0].contains(&format!("site.toml:{line}: key `mqtt.ca_file`"))
            && errs[0].contains("missing-ca.pem: No such file"),
        "{stderr}"
    );

    write_passwords(
        dir,
        &[("isochron", "right-pw-2718"), ("reader", "reader-pw")],
    );
    let broker = Broker::start_with(
        dir,
        port,
        &format!("{}{}", password_access(dir), tls_listener(dir, port, false)),
    );
    std::fs::write(dir.join("sink-password"), "right-pw-2718\n").unwrap();
    std::fs::set_permissions(
        dir.join("sink-password"),
        std::os::unix::fs::PermissionsExt::from_mode(0o600),
    )
    .unwrap();
    site.write_config(&format!(
        "[mqtt]\nbroker = \"mqtts://127.0.0.1:{port}\"\nca_file = \"ca.pem\"\nusername = \"isochron\"\npassword_file = \"sink-password\"\nreconnect_max_s = 1\n\n{}",
        camera_toml()
    ));
    let mut sink = spawn_sink_debug(&site);
    assert!(
        sink.wait_for_stderr("connected to the MQTT broker", Duration::from_secs(20)),
        "{}",
        sink.stderr()
    );

    // The broker's password file changes under the running sink: the broker
    // drops it at the reload and refuses it from then on.
    write_passwords(dir, &[("isochron", "changed-pw"), ("reader", "reader-pw")]);
    broker.reload();
    let changed = Instant::now();
    assert!(
        sink.wait_for_stderr("refused the sink", Duration::from_secs(20)),
        "{}",
        sink.stderr()
    );
    // Retrying for a while: still one error line, each refusal counted, with
    // backoff (reconnect_max_s = 1: at most about one attempt a second).
    std::thread::sleep(Duration::from_secs(6));
    let refused = eventually(Duration::from_secs(10), || {
        reported(&sink, "refused").filter(|n| *n >= 3)
    });
    let window = changed.elapsed().as_secs_f64();
    let stderr = sink.stderr();
    let errs = errors(&stderr);
    println!(
        "refused {refused:?} times in {window:.1} s after the change; error lines: {}",
        errs.len()
    );
    assert_eq!(errs.len(), 1, "{stderr}");
    let url = format!("mqtts://127.0.0.1:{port}");
    assert!(
        errs[0].contains(&format!(
            "the MQTT broker {url} refused the sink (user \"isochron\""
        )) && (errs[0].contains("not authorized") || errs[0].contains("bad user name or password"))
            && errs[0].contains("it accepted the sink before"),
        "{stderr}"
    );
    let refused = refused.unwrap_or_else(|| panic!("refusals not counted: {stderr}"));
    assert!(
        (refused as f64) <= window * 2.0 + 2.0,
        "{refused} attempts in {window:.1} s: no backoff"
    );
    assert!(
        sink.wait(Duration::ZERO).is_none(),
        "the sink exited: {stderr}"
    );

    // The password is accepted again: connected, and the log says after what.
    write_passwords(
        dir,
        &[("isochron", "right-pw-2718"), ("reader", "reader-pw")],
    );
    broker.reload();
    let line = eventually(Duration::from_secs(20), || {
        sink.stderr()
            .lines()
            .rev()
            .find(|l| {
                l.contains("connected to the MQTT broker")
                    && l.contains("refused or failed attempts")
            })
            .map(str::to_string)
    });
    let stderr = sink.stderr();
    assert!(line.is_some(), "{stderr}");
    assert!(
        !stderr.contains("right-pw-2718"),
        "the password is logged: {stderr}"
    );
    assert!(!stderr.contains("changed-pw"));
    let done = sink.terminate(Duration::from_secs(15));
    assert!(done.success(), "{}", sink.stderr());
}
