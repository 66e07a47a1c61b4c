//! isochron-capture against a real IP camera: GStreamer's RTSP server
//! (`tests/rtsp/camera.py`, gst-rtsp-server from Debian, H.264 from x264, H.265
//! from x265) killed (over TCP and UDP), frozen with SIGSTOP, restarted at another
//! size and given a wrong password; capture read through iceoryx2 and `isochron
//! status`, as a site would see it.

use std::time::{Duration, Instant};

use isochron_config::clock::wall_now_ns;
use isochron_runtime::ipc::{Frames, StreamSubscriber};
use isochron_tests::{Proc, TestSite, eventually, free_port, read_samples, repo_root};
use isochron_wire::FLAG_DISCONTINUITY;

/// GStreamer's RTSP server serving `rtsp://127.0.0.1:port/cam`, ready to answer.
fn rtsp_camera(port: u16, options: &[&str]) -> Proc {
    let script = repo_root().join("tests/rtsp/camera.py");
    let port = port.to_string();
    let mut args = vec![script.to_str().unwrap(), "--port", &port];
    args.extend(options);
    let mut camera = Proc::spawn(std::path::Path::new("/usr/bin/python3"), &args);
    assert!(
        camera
            .wait_for_line("ready rtsp://", Duration::from_secs(20))
            .is_some(),
        "the RTSP server did not start (cargo xtask setup --all installs it):\n{}",
        camera.stderr()
    );
    camera
}

/// A site whose cam01 is `url`, with `keys` added to its `[[camera]]`.
fn rtsp_site(name: &str, url: &str, keys: &str) -> TestSite {
    TestSite::new(
        name,
        &format!("[[camera]]\nid = \"cam01\"\nsource = \"{url}\"\n{keys}"),
    )
}

/// Capture's row in `isochron status --json`: its `info` and its counter `name`.
fn capture_status(site: &TestSite, name: &str) -> (String, f64) {
    let row = site.status_row("capture");
    let info = row["info"].as_str().unwrap_or_default().to_string();
    (info, row["counters"][name].as_f64().unwrap_or(f64::NAN))
}

/// Capture's `info` and counter `name` once the counter is `value` (within
/// `timeout`), else as last seen.
fn capture_status_becomes(
    site: &TestSite,
    name: &str,
    value: f64,
    timeout: Duration,
) -> (String, f64) {
    let deadline = Instant::now() + timeout;
    loop {
        let seen = capture_status(site, name);
        if seen.1 == value || Instant::now() >= deadline {
            return seen;
        }
        std::thread::sleep(Duration::from_millis(200));
    }
}

/// Waits for `count` frames of cam01, the first with the discontinuity flag if
/// `after_gap`; the time the first of them arrived.
fn frames_arrive(
    frames: &StreamSubscriber<Frames>,
    count: usize,
    after_gap: bool,
    timeout: Duration,
) -> Option<Instant> {
    let (mut seen, mut first) = (0, None);
    let ok = read_samples(frames, "cam01", timeout, |h, _| {
        if seen == 0 && after_gap && h.preamble.flags & FLAG_DISCONTINUITY == 0 {
            return true; // a frame from before the gap
        }
        first.get_or_insert_with(Instant::now);
        seen += 1;
        seen < count
    });
    ok.then_some(first).flatten()
}

/// The camera (`codec`, over `transport`) killed for 10 s and started again:
/// `refused` in status meanwhile, in one WARN; frames within 3 s of its return.
fn outage_recovers(name: &str, transport: &str, codec: &str) {
    let port = free_port();
    let url = format!("rtsp://127.0.0.1:{port}/cam");
    let camera_options = ["--codec", codec];
    let mut camera = rtsp_camera(port, &camera_options);
    let site = rtsp_site(name, &url, &format!("transport = \"{transport}\"\n"));
    let ipc = site.ipc("reader");
    let frames = ipc.subscriber::<Frames>("cam01").unwrap();
    let mut capture = site.spawn("isochron-capture", &["--camera", "cam01"]);
    assert!(
        frames_arrive(&frames, 20, false, Duration::from_secs(30)).is_some(),
        "no frames from the camera:\n{}",
        capture.stderr()
    );

    camera.signal(libc::SIGKILL);
    camera.wait(Duration::from_secs(5));
    let down = Instant::now();
    let refused = eventually(Duration::from_secs(8), || {
        (capture_status(&site, "down_refused").1 == 1.0).then(Instant::now)
    });
    let (info, _) = capture_status(&site, "down_refused");
    assert!(refused.is_some(), "status while the camera is off: {info}");
    assert_eq!(info, "source down: refused");
    std::thread::sleep(Duration::from_secs(10).saturating_sub(down.elapsed()));

    let restarted = Instant::now();
    let _camera = rtsp_camera(port, &camera_options);
    let back = frames_arrive(&frames, 5, true, Duration::from_secs(20))
        .unwrap_or_else(|| panic!("no frames after the camera returned:\n{}", capture.stderr()));
    let recovery = back - restarted;
    eprintln!(
        "{codec} over {transport}: refused shown {:.2} s after the kill; frames again {:.2} s after the server started",
        (refused.unwrap() - down).as_secs_f64(),
        recovery.as_secs_f64()
    );
    assert!(
        recovery < Duration::from_secs(3),
        "recovered after {recovery:?}"
    );
    let up = capture_status_becomes(&site, "source_up", 1.0, Duration::from_secs(3));
    assert_eq!(up, (String::new(), 1.0));
    assert_eq!(capture_status(&site, "reconnects").1, 1.0);

    let log = capture.stderr();
    let warns: Vec<&str> = log.lines().filter(|l| l.contains("WARN")).collect();
    let refusals = warns.iter().filter(|l| l.contains("refused")).count();
    assert_eq!(refusals, 1, "one WARN saying refused:\n{log}");
    assert!(
        warns.len() <= 2,
        "a WARN when it dropped, one when refused:\n{log}"
    );
    assert!(
        capture.terminate(Duration::from_secs(10)).success(),
        "{log}"
    );
}

#[test]
fn an_rtsp_camera_killed_for_10_s_streams_again_within_3_s_of_its_return() {
    outage_recovers("rtsp-outage", "tcp", "h264");
}

#[test]
fn an_rtsp_camera_over_udp_killed_for_10_s_streams_again_within_3_s() {
    outage_recovers("rtsp-outage-udp", "udp", "h264");
}

#[test]
fn an_h265_rtsp_camera_killed_for_10_s_streams_again_within_3_s() {
    outage_recovers("rtsp-outage-h265", "tcp", "h265");
}

#[test]
fn a_camera_that_returns_at_1280x720_is_analysed_at_the_configured_size() {
    let port = free_port();
    let url = format!("rtsp://127.0.0.1:{port}/cam");
    let mut camera = rtsp_camera(port, &["--size", "768x576"]);
    let site = rtsp_site("rtsp-resize", &url, "width = 768\nheight = 576\n");
    let ipc = site.ipc("reader");
    let frames = ipc.subscriber::<Frames>("cam01").unwrap();
    let mut capture = site.spawn("isochron-capture", &["--camera", "cam01"]);
    let mut sizes = Vec::new();
    let first = read_samples(&frames, "cam01", Duration::from_secs(30), |h, pixels| {
        sizes.push((h.width, h.height, pixels.len()));
        sizes.len() < 5
    });
    assert!(first, "no frames from the camera:\n{}", capture.stderr());

    camera.signal(libc::SIGKILL);
    camera.wait(Duration::from_secs(5));
    let _camera = rtsp_camera(port, &["--size", "1280x720"]);
    let after = frames_arrive(&frames, 1, true, Duration::from_secs(20));
    assert!(
        after.is_some(),
        "no frames after the switch:\n{}",
        capture.stderr()
    );
    let resumed = read_samples(&frames, "cam01", Duration::from_secs(10), |h, pixels| {
        sizes.push((h.width, h.height, pixels.len()));
        sizes.len() < 10
    });
    assert!(
        resumed,
        "frames stopped after the switch:\n{}",
        capture.stderr()
    );
    assert!(
        sizes.iter().all(|&s| s == (768, 576, 768 * 576)),
        "every frame at the first size: {sizes:?}"
    );
    let log = capture.stderr();
    assert!(
        log.contains("the source is 1280x720, rescaled to the configured 768x576"),
        "the switch is logged:\n{log}"
    );
    let up = capture_status_becomes(&site, "source_up", 1.0, Duration::from_secs(3));
    assert_eq!(up.1, 1.0);
    assert!(
        capture.terminate(Duration::from_secs(10)).success(),
        "{log}"
    );
}

#[test]
fn an_rtsp_camera_frozen_for_10_s_is_stalled_then_streams_within_3_s_of_waking() {
    let port = free_port();
    let url = format!("rtsp://127.0.0.1:{port}/cam");
    let camera = rtsp_camera(port, &[]);
    let site = rtsp_site(
        "rtsp-stall",
        &url,
        "read_timeout_s = 2\nconnect_timeout_s = 2\n",
    );
    let ipc = site.ipc("reader");
    let frames = ipc.subscriber::<Frames>("cam01").unwrap();
    let mut capture = site.spawn("isochron-capture", &["--camera", "cam01"]);
    assert!(
        frames_arrive(&frames, 20, false, Duration::from_secs(30)).is_some(),
        "no frames from the camera:\n{}",
        capture.stderr()
    );

    camera.signal(libc::SIGSTOP);
    let frozen = Instant::now();
    // What the server had sent before it froze still arrives: the stall counts
    // from the last frame capture read (its wall-clock stamp).
    let mut last_frame_ns = wall_now_ns();
    while read_samples(&frames, "cam01", Duration::from_millis(700), |h, _| {
        last_frame_ns = h.preamble.capture_time_ns;
        false
    }) {}
    assert!(
        capture.wait_for_stderr("stalled (no frame", Duration::from_secs(3)),
        "not stalled within read_timeout_s + 1 s of the last frame:\n{}",
        capture.stderr()
    );
    let stalled = Duration::from_nanos((wall_now_ns() - last_frame_ns).max(0) as u64);
    let last_after_stop = frozen.elapsed().saturating_sub(stalled);
    std::thread::sleep(Duration::from_secs(10).saturating_sub(frozen.elapsed()));
    let (info, up) = capture_status_becomes(&site, "source_up", 0.0, Duration::from_secs(3));
    assert_eq!(up, 0.0, "{info}");
    assert!(info.starts_with("source down: "), "{info}");

    camera.signal(libc::SIGCONT);
    let woken = Instant::now();
    let back = frames_arrive(&frames, 5, true, Duration::from_secs(20))
        .unwrap_or_else(|| panic!("no frames after SIGCONT:\n{}", capture.stderr()));
    let recovery = back - woken;
    eprintln!(
        "frames for {:.2} s after SIGSTOP, stalled {:.2} s after the last; frames again {:.2} s after SIGCONT",
        last_after_stop.as_secs_f64(),
        stalled.as_secs_f64(),
        recovery.as_secs_f64()
    );
    assert!(
        stalled < Duration::from_secs(3),
        "stalled after {stalled:?}"
    );
    assert!(
        recovery < Duration::from_secs(3),
        "recovered after {recovery:?}"
    );
    assert!(capture.terminate(Duration::from_secs(10)).success());
}

#[test]
fn a_wrong_rtsp_password_is_unauthorized_backs_off_and_is_never_shown() {
    const SECRET: &str = "n0t-the-Pa55word";
    let port = free_port();
    let _camera = rtsp_camera(port, &["--user", "admin", "--password", "right-one"]);
    let url = format!("rtsp://admin:{SECRET}@127.0.0.1:{port}/cam");
    let site = rtsp_site(
        "rtsp-password",
        &url,
        "reconnect_initial_s = 0.2\nreconnect_max_s = 0.8\n",
    );
    let mut capture = site.spawn("isochron-capture", &["--camera", "cam01"]);
    assert!(
        capture.wait_for_stderr("retrying in 0.8 s", Duration::from_secs(20)),
        "the backoff does not grow to its cap:\n{}",
        capture.stderr()
    );
    let (info, unauthorized) = capture_status(&site, "down_unauthorized");
    assert_eq!(
        (info.as_str(), unauthorized),
        ("source down: unauthorized", 1.0)
    );
    let status = site.status_row("capture").to_string();
    let log = capture.stderr();
    assert!(log.contains("rtsp://admin:***@127.0.0.1"), "{log}");
    assert_eq!(
        log.lines().filter(|l| l.contains("WARN")).count(),
        1,
        "one WARN for the whole outage:\n{log}"
    );
    assert!(capture.terminate(Duration::from_secs(10)).success());
    for (what, text) in [("capture's log", capture.stderr()), ("status", status)] {
        assert!(!text.contains(SECRET), "the password in {what}:\n{text}");
    }
}
