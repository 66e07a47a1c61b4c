//! `isochron-exporter`: scraped during a replay, its output passes Prometheus's
//! own `promtool check metrics` and its counters move; a killed service turns
//! its `isochron_up` to 0; a taken port is one clear line and exit 78. The
//! shipped alert rules pass `promtool check rules` and their unit tests, and the
//! dashboard asks only for metrics the exporter serves.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use isochron_tests::{Proc, TestSite, bin, eventually, free_port, repo_root, vtest};

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
fn value(text: &str, name: &str, labels: &str) -> Option<f64> {
    let prefix = format!("{name}{{{labels}}} ");
    text.lines()
        .find_map(|l| l.strip_prefix(&prefix))
        .and_then(|v| v.trim().parse().ok())
}

/// Runs `promtool args` with `stdin`: success and what it printed.
fn promtool(args: &[&str], stdin: &str, dir: &Path) -> (bool, String) {
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
