//! Reliability under an operator's hands: a stop that no signal order can defeat,
//! a camera that is unreachable at start, status that a new reader gets at once,
//! a camera's password in no output.

use std::time::{Duration, Instant};

use isochron_tests::{Proc, TestSite, eventually, vtest};

/// A service in a state, and the log line that says it got there.
struct Case {
    name: &'static str,
    binary: &'static str,
    args: Vec<&'static str>,
    ready: &'static str,
}

/// SIGTERM followed at once by SIGCONT (systemd's stop sequence, GNU `timeout`):
/// every service in every state ends within 2 s, 20 times each.
#[test]
fn sigterm_then_sigcont_stops_every_service_in_every_state_within_2s() {
    let site = TestSite::new(
        "sigcont",
        &format!(
            "[[camera]]\nid = \"idle\"\nsource = \"never-opened.avi\"\n\n\
             [[camera]]\nid = \"gone\"\nsource = \"rtsp://127.0.0.1:9/none\"\n\
             reconnect_initial_s = 0.5\nreconnect_max_s = 4\n\n\
             [[camera]]\nid = \"busy\"\nsource = \"{}\"\nspeed = 1\nloop = true\n",
            vtest().display()
        ),
    );
    // (what, binary, camera, the log line that says it got there)
    let cases = [
        (
            "capture reconnecting",
            "isochron-capture",
            Some("gone"),
            "retrying in",
        ),
        (
            "capture busy",
            "isochron-capture",
            Some("busy"),
            "publishing",
        ),
        (
            "motion idle",
            "isochron-motion",
            Some("idle"),
            "computing motion",
        ),
        (
            "cascade idle",
            "isochron-cascade",
            Some("idle"),
            "filtering motion",
        ),
        ("gate idle", "isochron-gate", Some("idle"), "gating the"),
        ("costmap idle", "isochron-costmap", None, "planning only"),
    ]
    .map(|(name, binary, camera, ready)| Case {
        name,
        binary,
        args: camera.map_or(Vec::new(), |c| vec!["--camera", c]),
        ready,
    });
    std::thread::scope(|scope| {
        for case in &cases {
            let site = &site;
            scope.spawn(move || {
                for attempt in 0..20 {
                    let mut proc = site.spawn(case.binary, &case.args);
                    assert!(
                        proc.wait_for_stderr(case.ready, Duration::from_secs(20)),
                        "{}: never reached '{}':\n{}",
                        case.name,
                        case.ready,
                        proc.stderr()
                    );
                    let took = stop_with_sigcont(&mut proc);
                    assert!(
                        took.is_some_and(|t| t <= Duration::from_secs(2)),
                        "{} (attempt {attempt}): SIGTERM + SIGCONT did not stop it within 2 s ({took:?}):\n{}",
                        case.name,
                        proc.stderr()
                    );
                }
            });
        }
    });
}

/// Sends SIGTERM then SIGCONT at once; how long the process took to exit.
fn stop_with_sigcont(proc: &mut Proc) -> Option<Duration> {
    let start = Instant::now();
    proc.signal(libc::SIGTERM);
    proc.signal(libc::SIGCONT);
    proc.wait(Duration::from_secs(5)).map(|_| start.elapsed())
}

/// `isochron status` right after a service started reports it running (it used to
/// wait 200 ms for a report published every 5 s).
#[test]
fn status_right_after_start_reports_the_service_running() {
    let site = TestSite::with_source("status-now", "", "never-opened.avi");
    for _ in 0..5 {
        let mut motion = site.spawn("isochron-motion", &["--camera", "cam01"]);
        assert!(
            motion.wait_for_stderr("computing motion", Duration::from_secs(20)),
            "{}",
            motion.stderr()
        );
        // Past the first report (sent at the first tick), so only a late-joiner
        // delivery can answer.
        std::thread::sleep(Duration::from_millis(500));
        let motion_row = site.status_row("motion");
        assert_eq!(motion_row["state"], "running", "{motion_row}");
        motion.terminate(Duration::from_secs(10));
    }
}

/// A camera that cannot be reached at start: capture says it is ready, keeps
/// feeding the watchdog and backs off up to its configured maximum, instead of
/// being killed as a service that never started.
#[test]
fn an_unreachable_camera_at_start_keeps_capture_alive_and_backing_off() {
    let site = TestSite::new(
        "unreachable",
        "[[camera]]\nid = \"cam01\"\nsource = \"rtsp://127.0.0.1:9/none\"\n\
         reconnect_initial_s = 0.25\nreconnect_max_s = 2\n",
    );
    let mut up = site.up(&["--watchdog-s", "3"]);
    let ready = eventually(Duration::from_secs(15), || {
        up.stdout()
            .contains("up: capture/cam01 ready")
            .then_some(())
    });
    assert!(
        ready.is_some(),
        "capture never said it is ready:\n{}",
        up.stdout()
    );
    // Several watchdog periods of backing off.
    std::thread::sleep(Duration::from_secs(12));
    let out = up.stdout();
    assert!(
        !out.contains("capture/cam01 watchdog"),
        "capture was killed by the watchdog while backing off:\n{out}"
    );
    let log = std::fs::read_to_string(site.path("logs/capture-cam01.log")).unwrap_or_default();
    assert!(
        log.contains("retrying in 2.0 s"),
        "backoff never reached its maximum:\n{log}"
    );
    assert!(
        !log.contains("retrying in 4.0 s"),
        "backoff passed its maximum:\n{log}"
    );
    up.terminate(Duration::from_secs(20));
}

/// A camera URL's password — in its user info and as a query parameter — appears
/// in no output while capture cannot reach it: `isochron up`'s and every
/// service's log, `isochron status`, `doctor`, `tap` and the exporter's
/// `/metrics`; the logs show it masked.
#[test]
fn a_camera_password_appears_in_no_output() {
    const SECRET: &str = "s3cret-Pa55";
    let port = isochron_tests::free_port();
    let site = TestSite::new(
        "redact",
        &format!(
            "[exporter]\nlisten = \"127.0.0.1:{port}\"\n\n\
             [[camera]]\nid = \"cam01\"\n\
             source = \"rtsp://admin:{SECRET}@127.0.0.1:9/live?user=admin&password={SECRET}\"\n\
             reconnect_initial_s = 0.25\nreconnect_max_s = 1\n"
        ),
    );
    let mut up = site.up(&[]);
    let mut exporter = site.spawn("isochron-exporter", &[]);
    let capture_log = site.path("logs/capture-cam01.log");
    let tried = eventually(Duration::from_secs(30), || {
        let log = std::fs::read_to_string(&capture_log).ok()?;
        (log.matches("retrying in").count() >= 2).then_some(log)
    });
    let log = tried.unwrap_or_else(|| panic!("capture never retried:\n{}", up.stdout()));
    assert!(
        log.contains("rtsp://admin:***@127.0.0.1:9/live?user=admin&password=***"),
        "the source masked in the log:\n{log}"
    );
    let config = site.config_path().display().to_string();
    let mut outputs = vec![("capture log".to_string(), log)];
    for args in [
        vec!["status", "--config", &config],
        vec!["status", "--config", &config, "--json"],
        vec!["doctor", "--config", &config],
        vec![
            "tap",
            "cam01",
            "frames",
            "--config",
            &config,
            "--count",
            "1",
            "--timeout",
            "2",
        ],
    ] {
        let done = site.isochron(&args, Duration::from_secs(60));
        outputs.push((
            format!("isochron {args:?}"),
            format!("{}\n{}", done.stdout, done.stderr),
        ));
    }
    let metrics = eventually(Duration::from_secs(30), || {
        let mut stream = std::net::TcpStream::connect(("127.0.0.1", port)).ok()?;
        use std::io::{Read, Write};
        stream
            .write_all(b"GET /metrics HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
            .ok()?;
        let mut page = String::new();
        stream.read_to_string(&mut page).ok()?;
        page.contains("isochron_up").then_some(page)
    });
    outputs.push(("/metrics".into(), metrics.expect("a scrape of /metrics")));
    up.terminate(Duration::from_secs(20));
    exporter.terminate(Duration::from_secs(20));
    outputs.push((
        "isochron up".into(),
        format!("{}\n{}", up.stdout(), up.stderr()),
    ));
    outputs.push(("exporter".into(), exporter.stderr()));
    for entry in std::fs::read_dir(site.path("logs")).unwrap() {
        let path = entry.unwrap().path();
        outputs.push((
            path.display().to_string(),
            std::fs::read_to_string(&path).unwrap(),
        ));
    }
    for (what, text) in &outputs {
        assert!(!text.contains(SECRET), "the password in {what}:\n{text}");
    }
    eprintln!(
        "the password in none of {} outputs ({} bytes)",
        outputs.len(),
        outputs.iter().map(|o| o.1.len()).sum::<usize>()
    );
}

/// `kill -9` of `isochron up` takes its services with it (they used to run on as
/// orphans that nothing restarts or stops).
#[test]
fn killing_up_with_sigkill_stops_its_services() {
    let site = TestSite::looping_vtest("orphans", "1");
    let mut up = site.up(&[]);
    let pids = eventually(Duration::from_secs(30), || {
        let out = up.stdout();
        let pids: Vec<u32> = out
            .lines()
            .filter(|l| l.starts_with("up: ") && l.contains(" started pid="))
            .map(isochron_tests::pid_in)
            .collect();
        let ready = out.lines().filter(|l| l.ends_with(" ready")).count();
        (pids.len() == 5 && ready >= 5).then_some(pids)
    })
    .unwrap_or_else(|| panic!("the group did not start:\n{}", up.stdout()));
    up.signal(libc::SIGKILL);
    let gone = eventually(Duration::from_secs(10), || {
        pids.iter()
            // SAFETY: signal 0 sends nothing: kill(2) only checks that `pid` exists.
            .all(|&pid| unsafe { libc::kill(pid as i32, 0) } != 0)
            .then_some(())
    });
    assert!(
        gone.is_some(),
        "services outlived their supervisor: {pids:?}"
    );
}

/// Output into a closed pipe ends the CLI quietly (it used to panic, exit 101).
#[test]
fn a_closed_pipe_ends_tap_quietly() {
    let site = TestSite::looping_vtest("epipe", "1");
    let mut capture = site.spawn("isochron-capture", &["--camera", "cam01"]);
    assert!(
        capture.wait_for_stderr("publishing", Duration::from_secs(20)),
        "{}",
        capture.stderr()
    );
    let script = format!(
        "'{}' tap cam01 frames --config '{}' --timeout 20 | head -n 1 >/dev/null; exit ${{PIPESTATUS[0]}}",
        isochron_tests::bin("isochron").display(),
        site.config_path().display()
    );
    let out = std::process::Command::new("bash")
        .args(["-c", &script])
        .output()
        .expect("bash");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_ne!(out.status.code(), Some(101), "{stderr}");
    capture.terminate(Duration::from_secs(10));
}
