//! `isochron-exporter`: scraped during a replay, its output passes Prometheus's
//! own `promtool check metrics` and its counters move; a killed service turns
//! its `isochron_up` to 0; a taken port is one clear line and exit 78. Hostile
//! clients (huge request heads, thousands of idle connections, slowloris) get
//! 431 or are closed while its memory and threads stay bounded and a normal
//! scrape still passes promtool. The shipped alert rules pass `promtool check
//! rules` and their unit tests, and the dashboard asks only for metrics the
//! exporter serves.

use std::io::{ErrorKind, Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use isochron_runtime::service::raise_open_file_limit;
use isochron_tests::{Proc, TestSite, bin, eventually, free_port, named_thread, repo_root, vtest};

/// `GET path` on 127.0.0.1:`port` with `accept`: the response's head and body.
fn get(port: u16, path: &str, accept: &str) -> Option<(String, String)> {
    let mut s = TcpStream::connect(("127.0.0.1", port)).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(5))).ok()?;
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: localhost\r\nAccept: {accept}\r\nConnection: close\r\n\r\n"
    )
    .ok()?;
    let mut text = String::new();
    s.read_to_string(&mut text).ok()?;
    let (head, body) = text.split_once("\r\n\r\n")?;
    Some((head.to_string(), body.to_string()))
}

/// The metrics in the Prometheus text format (what promtool reads).
fn scrape(port: u16) -> Option<String> {
    let (head, body) = get(port, "/metrics", "text/plain")?;
    assert!(head.starts_with("HTTP/1.1 200"), "{head}");
    assert!(head.contains("text/plain; version=0.0.4"), "{head}");
    Some(body)
}

/// The value of the sample `name{labels}` in `text`, e.g.
/// `value(t, "isochron_up", "stage=\"capture\",camera=\"cam01\"")`.
pub(crate) fn value(text: &str, name: &str, labels: &str) -> Option<f64> {
    let prefix = format!("{name}{{{labels}}} ");
    text.lines()
        .find_map(|l| l.strip_prefix(&prefix))
        .and_then(|v| v.trim().parse().ok())
}

/// Runs `promtool args` with `stdin`: success and what it printed.
pub(crate) fn promtool(args: &[&str], stdin: &str, dir: &Path) -> (bool, String) {
    let mut child = Command::new("promtool")
        .args(args)
        .current_dir(dir)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("promtool is installed (Debian package prometheus; cargo xtask setup)");
    child
        .stdin
        .take()
        .unwrap()
        .write_all(stdin.as_bytes())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    let text =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    (out.status.success(), text)
}

fn exporter_section(port: u16) -> String {
    format!("[exporter]\nlisten = \"127.0.0.1:{port}\"\nstale_after_s = 8\n\n")
}

/// A free port and a site whose exporter listens there, with the config `rest`.
fn exporter_site(name: &str, rest: &str) -> (u16, TestSite) {
    let port = free_port();
    let site = TestSite::new(name, &format!("{}{rest}", exporter_section(port)));
    (port, site)
}

#[test]
fn a_replay_scraped_twice_passes_promtool_and_its_counters_move() {
    let (port, site) = exporter_site(
        "exporter-replay",
        "[[camera]]\nid = \"cam01\"\nsource = \"unused.avi\"\nstart = \"2009-03-02T11:00:00Z\"\n",
    );
    let out = site.path("out");
    // Four times real time: about 20 s of video, several 5 s status reports.
    let config = site.config_path().display().to_string();
    let video = vtest().display().to_string();
    let out_arg = out.display().to_string();
    let mut replay = Proc::spawn(
        &bin("isochron"),
        &[
            "replay", &video, "--out", &out_arg, "--config", &config, "--speed", "4",
        ],
    );
    let frames = |text: &str| {
        value(
            text,
            "isochron_received_total",
            "stage=\"capture\",camera=\"cam01\"",
        )
        .filter(|v| *v > 0.0)
    };
    let first = eventually(Duration::from_secs(60), || {
        scrape(port).filter(|t| frames(t).is_some())
    })
    .unwrap_or_else(|| panic!("no capture counts at :{port}; replay: {}", replay.stderr()));
    let started = Instant::now();
    let second = eventually(Duration::from_secs(30), || {
        scrape(port).filter(|t| frames(t) > frames(&first))
    })
    .expect("the frame counter moves between scrapes");
    println!(
        "capture frames {} → {} in {:.1} s",
        frames(&first).unwrap(),
        frames(&second).unwrap(),
        started.elapsed().as_secs_f64()
    );
    for text in [&first, &second] {
        let (ok, lint) = promtool(&["check", "metrics"], text, site.dir.path());
        assert!(ok && lint.trim().is_empty(), "promtool: {lint}\n{text}");
    }
    for stage in ["capture", "motion", "cascade", "gate"] {
        let labels = format!("stage=\"{stage}\",camera=\"cam01\"");
        assert_eq!(
            value(&second, "isochron_up", &labels),
            Some(1.0),
            "{stage}\n{second}"
        );
        assert!(
            value(&second, "isochron_sent_total", &labels).is_some(),
            "{stage}\n{second}"
        );
    }
    assert!(
        value(
            &second,
            "isochron_store_failures_total",
            "stage=\"cascade\",camera=\"cam01\""
        ) == Some(0.0)
    );
    // Prometheus asks for OpenMetrics, and gets it.
    let (head, body) = get(
        port,
        "/metrics",
        "application/openmetrics-text;version=1.0.0",
    )
    .unwrap();
    assert!(
        head.contains("application/openmetrics-text; version=1.0.0"),
        "{head}"
    );
    assert!(body.ends_with("# EOF\n"));
    assert!(
        get(port, "/nope", "*/*")
            .unwrap()
            .0
            .starts_with("HTTP/1.1 404")
    );

    let done = replay.finish(Duration::from_secs(300));
    assert!(done.status.success(), "replay: {}", done.stderr);
    assert!(out.join("logs/exporter.log").is_file());
}

#[test]
fn a_killed_service_goes_down_and_a_taken_port_is_one_line() {
    let (port, site) = exporter_site(
        "exporter-up",
        &format!(
            "[[camera]]\nid = \"cam01\"\nsource = \"{}\"\nspeed = 2\nloop = true\n",
            vtest().display()
        ),
    );
    let mut capture = site.spawn("isochron-capture", &["--camera", "cam01"]);
    let _exporter = site.spawn("isochron-exporter", &[]);
    let capture_up = |text: &str| value(text, "isochron_up", "stage=\"capture\",camera=\"cam01\"");
    let up = eventually(Duration::from_secs(60), || {
        scrape(port).filter(|t| capture_up(t) == Some(1.0))
    })
    .expect("capture is up");
    // Never started: down.
    assert_eq!(
        value(&up, "isochron_up", "stage=\"motion\",camera=\"cam01\""),
        Some(0.0)
    );
    assert_eq!(
        value(&up, "isochron_up", "stage=\"costmap\",camera=\"\""),
        Some(0.0)
    );
    // `isochron status` shows the exporter's own row (the config has [exporter]).
    let exporter_row = site.status_row("exporter");
    assert_eq!(exporter_row["state"], "running", "{exporter_row}");

    // Killed and reaped (as systemd or `up` would): down at the next scrape,
    // well before its last report goes stale (8 s).
    capture.signal(libc::SIGKILL);
    let killed = Instant::now();
    capture.wait(Duration::from_secs(10)).expect("capture dies");
    eventually(Duration::from_secs(20), || {
        scrape(port).filter(|t| capture_up(t) == Some(0.0))
    })
    .expect("a killed capture goes down");
    let after = killed.elapsed();
    println!(
        "isochron_up went to 0 {:.2} s after the kill",
        after.as_secs_f64()
    );
    assert!(
        after < Duration::from_secs(5),
        "{after:?}: not before staleness"
    );

    // A second exporter on the same port: one line, a config error, no restart.
    let mut second = site.spawn("isochron-exporter", &[]);
    let status = second
        .wait(Duration::from_secs(20))
        .expect("the second exporter exits");
    assert_eq!(status.code(), Some(78), "{}", second.stderr());
    let stderr = second.stderr();
    let errors: Vec<&str> = stderr.lines().filter(|l| l.contains("ERROR")).collect();
    assert_eq!(errors.len(), 1, "{stderr}");
    assert!(
        errors[0].contains("exporter.listen")
            && errors[0].contains(&format!("127.0.0.1:{port}"))
            && errors[0].contains("another process listens there"),
        "{stderr}"
    );
    // The first one still serves.
    assert!(scrape(port).is_some());
}

#[test]
fn the_alert_rules_pass_promtool_and_their_unit_tests() {
    let dir = repo_root().join("deploy/prometheus");
    let (ok, text) = promtool(&["check", "rules", "isochron-alerts.yml"], "", &dir);
    assert!(ok, "{text}");
    let (ok, text) = promtool(&["test", "rules", "isochron-alerts.test.yml"], "", &dir);
    assert!(ok, "{text}");
}

#[test]
fn the_dashboard_and_rules_ask_only_for_served_metrics() {
    // Every family the exporter serves, from its own unit of truth: a scrape of
    // an exporter whose services never ran still lists every family.
    let port = free_port();
    let site = TestSite::with_source("exporter-names", &exporter_section(port), "unused.avi");
    let _exporter = site.spawn("isochron-exporter", &[]);
    let text = eventually(Duration::from_secs(30), || scrape(port)).expect("a scrape");
    let served: Vec<&str> = text
        .lines()
        .filter_map(|l| l.strip_prefix("# TYPE "))
        .filter_map(|l| l.split_whitespace().next())
        .collect();
    for file in [
        "deploy/grafana/isochron-dashboard.json",
        "deploy/prometheus/isochron-alerts.yml",
    ] {
        let body = std::fs::read_to_string(repo_root().join(file)).unwrap();
        if file.ends_with(".json") {
            serde_json::from_str::<serde_json::Value>(&body).expect("valid JSON");
        }
        let mut rest = body.as_str();
        let mut asked = 0;
        while let Some(at) = rest.find("isochron_") {
            let name: String = rest[at..]
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                .collect();
            rest = &rest[at + name.len()..];
            asked += 1;
            assert!(
                served.contains(&name.as_str()),
                "{file} asks for {name}, not served"
            );
        }
        assert!(asked > 5, "{file}");
    }
}

/// `VmRSS` (KiB) and `Threads` of process `pid`, from `/proc/<pid>/status`.
fn rss_and_threads(pid: u32) -> Option<(u64, u64)> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let field = |name: &str| -> Option<u64> {
        let line = status.lines().find(|l| l.starts_with(name))?;
        line[name.len()..].split_whitespace().next()?.parse().ok()
    };
    Some((field("VmRSS:")?, field("Threads:")?))
}

/// The highest `VmRSS` (KiB) and `Threads` of a process, sampled every 20 ms
/// until [`Peaks::stop`].
struct Peaks {
    stop: Arc<AtomicBool>,
    sampler: JoinHandle<(u64, u64)>,
}

impl Peaks {
    fn watch(pid: u32) -> Peaks {
        let stop = Arc::new(AtomicBool::new(false));
        let stopped = stop.clone();
        let sampler = named_thread("sampler", move || {
            let mut peak = (0, 0);
            while !stopped.load(Ordering::Relaxed) {
                if let Some((rss, threads)) = rss_and_threads(pid) {
                    peak = (peak.0.max(rss), peak.1.max(threads));
                }
                std::thread::sleep(Duration::from_millis(20));
            }
            peak
        });
        Peaks { stop, sampler }
    }

    fn stop(self) -> (u64, u64) {
        self.stop.store(true, Ordering::Relaxed);
        self.sampler.join().unwrap()
    }
}

/// One client sending a request head of up to `limit` bytes (1 KiB header lines)
/// for at most `patience`: the bytes the exporter took before it closed the
/// connection, and the start of what it answered.
fn huge_head(port: u16, limit: u64, patience: Duration) -> (u64, String) {
    let mut s = TcpStream::connect(("127.0.0.1", port)).unwrap();
    s.set_write_timeout(Some(Duration::from_secs(5))).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
    let line = format!("X-Pad: {}\r\n", "a".repeat(1016));
    let chunk = line.repeat(64);
    let end = Instant::now() + patience;
    let mut sent = s
        .write(b"GET /metrics HTTP/1.1\r\nHost: localhost\r\n")
        .unwrap() as u64;
    while sent < limit && Instant::now() < end {
        match s.write(chunk.as_bytes()) {
            Ok(n) => sent += n as u64,
            Err(_) => break,
        }
    }
    let mut answer = vec![0; 256];
    let n = s.read(&mut answer).unwrap_or(0);
    (sent, String::from_utf8_lossy(&answer[..n]).into_owned())
}

/// True when the exporter closed `s` (end of stream or reset), checked without
/// waiting.
fn closed_by_peer(s: &TcpStream) -> bool {
    s.set_nonblocking(true).unwrap();
    let mut byte = [0u8; 64];
    match s.peek(&mut byte) {
        Ok(0) => true,
        Ok(_) => false, // an answer (503) waits: closed after it
        Err(e) if e.kind() == ErrorKind::WouldBlock => false,
        Err(_) => true,
    }
}

/// A normal scrape passes promtool; returns its body.
fn checked_scrape(port: u16, dir: &Path, during: &str) -> String {
    let body = scrape(port).unwrap_or_else(|| panic!("no scrape during {during}"));
    let (ok, lint) = promtool(&["check", "metrics"], &body, dir);
    assert!(
        ok && lint.trim().is_empty(),
        "promtool during {during}: {lint}"
    );
    body
}

#[test]
fn hostile_http_clients_get_431_or_are_closed_within_bounded_memory_and_threads() {
    // The attacker holds thousands of sockets.
    raise_open_file_limit();
    // The limits are the defaults: max_connections 64, max_header_bytes 8192,
    // request_timeout_s 10.
    let (port, site) = exporter_site(
        "exporter-hostile",
        "[[camera]]\nid = \"cam01\"\nsource = \"unused.avi\"\n",
    );
    let mut exporter = site.spawn("isochron-exporter", &[]);
    eventually(Duration::from_secs(30), || scrape(port)).expect("a first scrape");
    let pid = exporter.pid();
    std::thread::sleep(Duration::from_millis(500));
    let (rss0, threads0) = rss_and_threads(pid).unwrap();
    let peaks = Peaks::watch(pid);
    let dir = site.dir.path();

    // 1. Four clients each try 400 MiB of request headers.
    let started = Instant::now();
    let attackers: Vec<_> = (0..4)
        .map(|_| {
            named_thread("attacker", move || {
                huge_head(port, 400 << 20, Duration::from_secs(60))
            })
        })
        .collect();
    checked_scrape(port, dir, "the huge request heads");
    let huge: Vec<(u64, String)> = attackers.into_iter().map(|a| a.join().unwrap()).collect();
    let huge_s = started.elapsed().as_secs_f64();
    // One head just over the limit, sent whole before reading: 431.
    let (_, just_over) = huge_head(port, 16 << 10, Duration::from_secs(10));

    // 2. 3 000 idle connections that never send a byte.
    let started = Instant::now();
    let mut idle = Vec::new();
    let mut not_connected = 0;
    for _ in 0..3000 {
        match TcpStream::connect_timeout(&([127, 0, 0, 1], port).into(), Duration::from_secs(1)) {
            Ok(s) => idle.push(s),
            Err(_) => not_connected += 1,
        }
    }
    let opened_s = started.elapsed().as_secs_f64();
    checked_scrape(port, dir, "3 000 idle connections");
    // The exporter evicts the oldest idle connection for each new one past its
    // limit: wait (10 s at most) until all but the last 64 are seen closed.
    let evicted = 3000 - not_connected - 64 - 2;
    let closed = || idle.iter().filter(|s| closed_by_peer(s)).count();
    let closed_idle = eventually(Duration::from_secs(10), || {
        let n = closed();
        (n >= evicted).then_some(n)
    })
    .unwrap_or_else(closed);
    let (rss_idle, threads_idle) = rss_and_threads(pid).unwrap();
    drop(idle);

    // 3. Slowloris: 100 clients sending their request head one byte a second.
    let started = Instant::now();
    let mut slow: Vec<TcpStream> = (0..100)
        .filter_map(|_| TcpStream::connect(("127.0.0.1", port)).ok())
        .collect();
    for s in &mut slow {
        let _ = s.write_all(b"GET /metrics HTTP/1.1\r\nHost: localhost\r\nX-Slow: ");
    }
    let mut slow_closed_s = None;
    while started.elapsed() < Duration::from_secs(20) {
        std::thread::sleep(Duration::from_secs(1));
        for s in &mut slow {
            s.set_nonblocking(false).unwrap();
            let _ = s.write(b"a");
        }
        if slow.iter().all(closed_by_peer) {
            slow_closed_s = Some(started.elapsed().as_secs_f64());
            break;
        }
        if started.elapsed() > Duration::from_secs(3) && started.elapsed() < Duration::from_secs(5)
        {
            checked_scrape(port, dir, "slowloris");
        }
    }
    drop(slow);

    let (rss_peak, threads_peak) = peaks.stop();
    let after = checked_scrape(port, dir, "after the attack");
    let refused = |reason: &str| {
        value(
            &after,
            "isochron_exporter_http_refused_total",
            &format!("reason=\"{reason}\""),
        )
        .unwrap_or(0.0)
    };
    println!(
        "exporter under attack: VmRSS {} MiB before, peak {} MiB (+{} MiB), with 3 000 idle connections {} MiB; \
         threads {threads0} before, peak {threads_peak}, with 3 000 idle connections {threads_idle}; \
         4 × 400 MiB heads: the exporter took {:?} MiB in {huge_s:.1} s; {} idle connections opened in {opened_s:.1} s \
         ({not_connected} not), {closed_idle} closed by the exporter; slowloris closed after {slow_closed_s:?} s; \
         refused: header_size {}, evicted {}, busy {}, timeout {}",
        rss0 >> 10,
        rss_peak >> 10,
        rss_peak.saturating_sub(rss0) >> 10,
        rss_idle >> 10,
        huge.iter().map(|(n, _)| n >> 20).collect::<Vec<_>>(),
        3000 - not_connected,
        refused("header_size"),
        refused("evicted"),
        refused("busy"),
        refused("timeout"),
    );

    assert!(
        just_over.starts_with("HTTP/1.1 431"),
        "a 16 KiB head: {just_over:?}"
    );
    for (sent, answer) in &huge {
        // The head limit (8 KiB) plus what the sockets' buffers hold.
        assert!(*sent < 64 << 20, "{sent} bytes taken before the close");
        assert!(
            answer.is_empty() || answer.starts_with("HTTP/1.1 431"),
            "{answer:?}"
        );
    }
    assert!(refused("header_size") >= 5.0, "{after}");
    assert!(
        closed_idle >= evicted,
        "only {closed_idle} idle connections closed"
    );
    assert!(refused("evicted") >= 2900.0, "{after}");
    assert!(slow_closed_s.is_some(), "slowloris connections still open");
    // One HTTP thread whatever the clients do; memory: 64 connections × 8 KiB
    // heads and hyper's per-connection state, with a margin for the allocator.
    assert!(
        threads_peak <= threads0 + 1,
        "threads {threads0} → {threads_peak}"
    );
    assert!(
        rss_peak.saturating_sub(rss0) < 32 << 10,
        "VmRSS {rss0} KiB → {rss_peak} KiB"
    );
    assert!(
        exporter.wait(Duration::ZERO).is_none(),
        "{}",
        exporter.stderr()
    );
}
