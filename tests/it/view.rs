//! Looking at what isochron sees: the calibration overlay of `isochron costmap
//! check --overlay`, drawn on a real frame of vtest.avi with the demo site's
//! calibration; MCAP recordings read by the Python `mcap` package; the live
//! Foxglove view, with the protocol's reference client (`@foxglove/ws-protocol`
//! under Node.js) and Python `websockets` clients, one of which stops reading.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use isochron_tests::{
    Proc, TestSite, bin, eventually, free_port, named_thread, node_modules, repo_root, rss_bytes,
    venv_python, vtest,
};
use serde_json::Value;

/// config/demo.toml without its `[site]` section (the test site has its own), the
/// video at its absolute path; `edit` may change the text.
pub(crate) fn demo_site(name: &str, edit: impl Fn(String) -> String) -> TestSite {
    let text = std::fs::read_to_string(repo_root().join("config/demo.toml")).unwrap();
    let body = &text[text.find("[[camera]]").expect("demo has a camera")..];
    let body = body.replace(
        "source = \"../data/vtest.avi\"",
        &format!("source = \"{}\"", vtest().display()),
    );
    TestSite::new(name, &edit(body))
}

/// Width and height from a PNG's IHDR chunk.
fn png_size(path: &Path) -> (u32, u32) {
    let bytes = std::fs::read(path).unwrap();
    assert_eq!(
        &bytes[..8],
        b"\x89PNG\r\n\x1a\n",
        "{} is a PNG",
        path.display()
    );
    assert_eq!(&bytes[12..16], b"IHDR");
    let be = |b: &[u8]| u32::from_be_bytes(b.try_into().unwrap());
    (be(&bytes[16..20]), be(&bytes[20..24]))
}

fn check(site: &TestSite, extra: &[&str]) -> (Option<i32>, Value, String) {
    let config = site.config_path().display().to_string();
    let mut args = vec!["costmap", "check", "--config", &config, "--camera", "cam01"];
    args.extend_from_slice(extra);
    args.push("--json");
    let done = site.isochron(&args, Duration::from_secs(60));
    let json = serde_json::from_str(&done.stdout)
        .unwrap_or_else(|e| panic!("{e}: not JSON:\n{}\nstderr:\n{}", done.stdout, done.stderr));
    (done.status.code(), json, done.stderr)
}

#[test]
fn overlay_of_the_demo_camera_has_the_frame_size_and_the_known_error() {
    let site = demo_site("overlay", |b| b);
    let out = site.path("overlay.png");
    let (code, json, stderr) = check(&site, &["--overlay", out.to_str().unwrap()]);
    assert_eq!(code, Some(0), "{stderr}");
    // vtest.avi is 768×576, and the demo sets no analysis size.
    assert_eq!(png_size(&out), (768, 576));
    let cam = &json["cameras"][0];
    assert_eq!(cam["frame_px"], serde_json::json!([768, 576]));
    let points = cam["points"].as_array().unwrap();
    assert_eq!(points.len(), 12);
    // The calibration's known error: the lens distortion a homography cannot model
    // leaves about 0.1 m (config/demo.toml), a pixel or two in the image.
    let rms_m = cam["rms_m"].as_f64().unwrap();
    let rms_px = cam["rms_px"].as_f64().unwrap();
    assert!((0.03..0.15).contains(&rms_m), "RMS {rms_m} m");
    assert!((0.5..3.0).contains(&rms_px), "RMS {rms_px} px");
    let per_point =
        |key: &str| -> Vec<f64> { points.iter().map(|p| p[key].as_f64().unwrap()).collect() };
    let residual_m = per_point("residual_m");
    let mean_sq = residual_m.iter().map(|r| r * r).sum::<f64>() / 12.0;
    assert!((mean_sq.sqrt() - rms_m).abs() < 1e-9);
    assert!(residual_m.iter().all(|&r| r < 0.15), "{residual_m:?}");
    assert!(per_point("residual_px").iter().all(|&r| r < 3.0));
    // Leaving a point out costs accuracy at it, but not much in a good set.
    let loo = cam["loo_rms_m"].as_f64().unwrap();
    assert!(loo > rms_m && loo < 0.3, "leave-one-out {loo} m");
    assert!(points.iter().all(|p| p["flagged"] == false));

    // The overlay itself is an image OpenCV reads back as a frame to draw on.
    let again = site.path("again.png");
    let (code, _, stderr) = check(
        &site,
        &[
            "--overlay",
            again.to_str().unwrap(),
            "--frame",
            out.to_str().unwrap(),
        ],
    );
    assert_eq!(code, Some(0), "{stderr}");
    assert_eq!(png_size(&again), (768, 576));
}

#[test]
fn overlay_scales_the_frame_to_the_analysis_size() {
    // The analysis size is half the video's; the floor points are halved with it.
    let site = demo_site("overlay-half", |b| {
        let mut out = b.replace("loop = true", "loop = true\nwidth = 384\nheight = 288");
        for (x, y) in [(40, 180), (270, 180), (500, 180), (730, 180)]
            .into_iter()
            .chain([(40, 330), (270, 330), (500, 330), (730, 330)])
            .chain([(40, 560), (270, 560), (500, 560), (730, 560)])
        {
            out = out.replace(
                &format!("image_px = [{x}, {y}]"),
                &format!("image_px = [{}, {}]", x as f64 / 2.0, y as f64 / 2.0),
            );
        }
        out
    });
    let out = site.path("half.png");
    let (code, json, stderr) = check(&site, &["--overlay", out.to_str().unwrap()]);
    assert_eq!(code, Some(0), "{stderr}");
    assert_eq!(png_size(&out), (384, 288));
    let rms_px = json["cameras"][0]["rms_px"].as_f64().unwrap();
    assert!(
        (0.25..1.5).contains(&rms_px),
        "RMS {rms_px} px at half size"
    );
}

#[test]
fn a_wrong_tape_mark_is_flagged() {
    // Point 5 measured 2 m off along x.
    let site = demo_site("overlay-outlier", |b| {
        b.replace("floor_m = [-12.51, -6.441]", "floor_m = [-10.51, -6.441]")
    });
    let out = site.path("outlier.png");
    let (code, json, _) = check(&site, &["--overlay", out.to_str().unwrap()]);
    assert_eq!(code, Some(1), "a point that stands out fails the check");
    let flagged: Vec<u64> = json["cameras"][0]["points"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|p| p["flagged"] == true)
        .map(|p| p["index"].as_u64().unwrap())
        .collect();
    assert_eq!(flagged, vec![5]);
    assert_eq!(
        png_size(&out),
        (768, 576),
        "the overlay is drawn all the same"
    );
    // And the text says which.
    let config = site.config_path().display().to_string();
    let done = site.isochron(
        &["costmap", "check", "--config", &config, "--camera", "cam01"],
        Duration::from_secs(60),
    );
    let line = done
        .stdout
        .lines()
        .find(|l| l.contains("far above the others"))
        .unwrap_or_else(|| panic!("no flagged point in:\n{}", done.stdout));
    assert!(line.trim_start().starts_with("#5 "), "{line}");
}

#[test]
fn bad_overlay_input_is_one_clear_line() {
    let site = demo_site("overlay-bad", |b| b);
    let config = site.config_path().display().to_string();
    let png = site.path("x.png").display().to_string();
    let not_video = site.config_path().display().to_string();
    let overlay = ["--camera", "cam01", "--overlay", png.as_str()];
    for (args, expect, code) in [
        (
            vec!["--camera", "cam09", "--overlay", &png],
            "no camera 'cam09'",
            64,
        ),
        (
            vec!["--camera", "cam01", "--overlay", "/nonexistent/dir/x.png"],
            "--overlay /nonexistent/dir/x.png: cannot write",
            1,
        ),
        (
            [&overlay[..], &["--frame", &not_video]].concat(),
            "not a video or image",
            65,
        ),
        (
            [&overlay[..], &["--frame", "/nonexistent.avi"]].concat(),
            "--frame /nonexistent.avi: no such file",
            66,
        ),
    ] {
        let mut all = vec!["costmap", "check", "--config", &config];
        all.extend(args);
        let done = site.isochron(&all, Duration::from_secs(60));
        assert_eq!(done.status.code(), Some(code), "{expect}: {}", done.stderr);
        assert!(!site.path("x.png").exists(), "{all:?} left x.png");
        let lines: Vec<&str> = done.stderr.lines().collect();
        assert_eq!(lines.len(), 1, "{all:?}: {}", done.stderr);
        assert!(lines[0].contains(expect), "{all:?}: {}", done.stderr);
    }
}

// ---------------------------------------------------------------------------
// Recordings and the live view: checked by independent Python peers (the `mcap`
// reader and a `websockets` client speaking foxglove.sdk.v1), from the venv
// `cargo xtask setup` makes.

/// The venv's Python with `mcap` and `websockets`.
fn python() -> PathBuf {
    venv_python("mcap.reader, websockets")
}

/// What the Python peer `tests/view/<script>` prints (one JSON value) when run
/// with `args`.
fn python_peer(script: &str, args: &[String]) -> Value {
    let out = std::process::Command::new(python())
        .arg(repo_root().join("tests/view").join(script))
        .args(args)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{script} {args:?} failed: {stderr}");
    serde_json::from_slice(&out.stdout).unwrap()
}

/// What `tests/view/mcap_summary.py` reads in `file`.
fn mcap_summary(file: &Path) -> Value {
    python_peer("mcap_summary.py", &[file.display().to_string()])
}

/// The channel of `topic` in a summary.
fn channel<'a>(summary: &'a Value, topic: &str) -> Option<&'a Value> {
    summary["channels"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["topic"] == topic)
}

/// The channels of every recording and view of cam01, with their schemas (besides
/// the status channels, and the image only with `view.frames = true`).
const CHANNELS: [(&str, &str); 6] = [
    ("/costmap", "foxglove.Grid"),
    ("/scene", "foxglove.SceneUpdate"),
    ("/cam01/activity", "foxglove.Grid"),
    ("/cam01/motion", "foxglove.Grid"),
    ("/cam01/events", "foxglove.Log"),
    ("/cam01/detections", "foxglove.ImageAnnotations"),
];

/// Runs `isochron replay` of vtest on `site` with `--record file` (and `extra`).
fn replay_recorded(site: &TestSite, file: &Path, extra: &[&str]) -> isochron_tests::Finished {
    let video = vtest().display().to_string();
    let out = site.path("replay").display().to_string();
    let config = site.config_path().display().to_string();
    let mut args = vec![
        "replay",
        &video,
        "--out",
        &out,
        "--config",
        &config,
        "--record",
        file.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    site.isochron(&args, Duration::from_secs(600))
}

#[test]
fn a_recording_of_the_demo_video_opens_in_an_independent_mcap_reader() {
    let site = demo_site("record", |b| b);
    let file = site.path("run.mcap");
    let done = replay_recorded(&site, &file, &[]);
    assert!(done.status.success(), "{}\n{}", done.stdout, done.stderr);
    let summary = mcap_summary(&file);
    assert_eq!(summary["has_summary"], true, "closed cleanly: {summary}");
    assert_eq!(summary["compression"], serde_json::json!(["lz4"]));
    assert!(summary["chunks"].as_u64().unwrap() >= 1);
    assert_eq!(summary["messages_read"], summary["message_count"]);
    for (topic, schema) in CHANNELS.into_iter().chain([
        ("/cam01/status/motion", "foxglove.Log"),
        ("/cam01/status/cascade", "foxglove.Log"),
        ("/status/costmap", "foxglove.Log"),
    ]) {
        let ch = channel(&summary, topic).unwrap_or_else(|| panic!("no {topic}: {summary}"));
        assert_eq!(ch["schema"], schema, "{ch}");
        assert_eq!(ch["schema_encoding"], "protobuf", "{ch}");
        assert_eq!(ch["message_encoding"], "protobuf", "{ch}");
        assert!(ch["count"].as_u64().unwrap() > 0, "{ch}");
        // The recorder's own count of the topic is what the reader found.
        let line = format!("  {topic}: {}", ch["count"]);
        assert!(done.stdout.contains(&line), "{line} in\n{}", done.stdout);
    }
    // vtest is ~80 s at 10 fps: an activity sample per second, a cost map each time.
    let activity = channel(&summary, "/cam01/activity").unwrap()["count"]
        .as_u64()
        .unwrap();
    assert!((70..=90).contains(&activity), "{activity} activity samples");
    assert_eq!(channel(&summary, "/costmap").unwrap()["count"], activity);
    // Motion at most 2 per second of capture time (10 fps in the file), latest
    // only: how many depends on how often the recorder looks at a fast replay.
    let motion = channel(&summary, "/cam01/motion").unwrap()["count"]
        .as_u64()
        .unwrap();
    assert!(
        (10..=2 * activity + 2).contains(&motion),
        "{motion} motion grids for {activity} seconds"
    );
    // One float32 density, dx, dy per block: 48 × 36 blocks of 16 px.
    assert!(
        channel(&summary, "/cam01/motion").unwrap()["first_message_bytes"]
            .as_u64()
            .unwrap()
            > 48 * 36 * 12
    );
    // The 320 × 300 cell grid of the demo, one int8 per cell (+ the message around it).
    assert!(
        channel(&summary, "/costmap").unwrap()["first_message_bytes"]
            .as_u64()
            .unwrap()
            > 96_000
    );
    assert!(
        channel(&summary, "/cam01/image").is_none(),
        "no images unless view.frames = true: {summary}"
    );
}

/// What `tests/view/ws_client.py` gets from `port` on `topic` (up to `want`).
fn ws_client(port: u16, topic: &str, want: u32, timeout_s: u32) -> Value {
    let url = format!("ws://127.0.0.1:{port}");
    let args = [url, topic.into(), want.to_string(), timeout_s.to_string()];
    python_peer("ws_client.py", &args)
}

/// Starts `isochron replay` of vtest on `site` at `--speed 1`; returns it once it
/// runs, with its effective config (its private prefix), which views and
/// recorders join.
fn replay_live(site: &TestSite) -> (Proc, PathBuf) {
    let video = vtest().display().to_string();
    let out = site.path("replay");
    let config = site.config_path().display().to_string();
    let mut replay = Proc::spawn(
        &bin("isochron"),
        &[
            "replay",
            &video,
            "--out",
            out.to_str().unwrap(),
            "--config",
            &config,
            "--speed",
            "1",
        ],
    );
    assert!(
        replay
            .wait_for_line("replay:", Duration::from_secs(120))
            .is_some(),
        "replay did not start: {}",
        replay.stderr()
    );
    (replay, out.join("config.toml"))
}

/// Starts `isochron view` of `config` on loopback port `port`.
/// A site of cam01 on the 1 MiB cost map grid whose `[view]` is `view_keys`, and
/// its running view on a free port.
fn big_grid_view(name: &str, view_keys: &str) -> (TestSite, u16, Proc) {
    let site = TestSite::new(
        name,
        &format!(
            "{}{BIG_GRID}\n[view]\n{view_keys}",
            crate::costmap::camera_toml()
        ),
    );
    let port = free_port();
    let mut view = spawn_view(&site.config_path(), port);
    wait_for_view(&mut view);
    (site, port, view)
}

fn spawn_view(config: &Path, port: u16) -> Proc {
    Proc::spawn(
        &bin("isochron"),
        &[
            "view",
            "--config",
            config.to_str().unwrap(),
            "--listen",
            &format!("127.0.0.1:{port}"),
        ],
    )
}

/// Waits until `view` serves.
fn wait_for_view(view: &mut Proc) {
    assert!(
        view.wait_for_line("view: Foxglove WebSocket", Duration::from_secs(30))
            .is_some(),
        "view did not start: {}",
        view.stderr()
    );
}

#[test]
fn the_live_view_serves_foxglove_clients_during_a_replay() {
    // Images on for this site; the replay's effective config (its private prefix)
    // is what the view and the recorder join.
    // Two views and a recorder join the group: room for them.
    let site = demo_site("live", |b| {
        format!("[ipc]\nmax_subscribers = 8\n\n{b}\n[view]\nframes = true\n")
    });
    let (replay, with_frames) = replay_live(&site);
    let text = std::fs::read_to_string(&with_frames).unwrap();
    assert!(text.contains("frames = true"), "{text}");
    let without = site.path("no-frames.toml");
    std::fs::write(&without, text.replace("frames = true", "frames = false")).unwrap();

    let (p1, p2) = (free_port(), free_port());
    let mut with = spawn_view(&with_frames, p1);
    let mut plain = spawn_view(&without, p2);
    for v in [&mut with, &mut plain] {
        wait_for_view(v);
    }
    // A recorder on the same group, for a few seconds, with images.
    let mcap = site.path("live.mcap");
    let mut record = Proc::spawn(
        &bin("isochron"),
        &[
            "record",
            "--config",
            with_frames.to_str().unwrap(),
            "--out",
            mcap.to_str().unwrap(),
            "--duration",
            "6",
        ],
    );

    // Without images: the cost map arrives, no image channel is advertised.
    let got = ws_client(p2, "/costmap", 3, 40);
    assert_eq!(got["subprotocol"], "foxglove.sdk.v1", "{got}");
    assert!(got["server"].is_string(), "serverInfo: {got}");
    let channels = got["channels"].as_object().unwrap();
    for (topic, schema) in CHANNELS
        .into_iter()
        .chain([("/cam01/status/gate", "foxglove.Log")])
    {
        assert_eq!(channels[topic]["schema"], schema, "{got}");
    }
    assert!(!channels.contains_key("/cam01/image"), "{got}");
    assert_eq!(got["received"], 3, "{got}");
    assert!(got["first_bytes"].as_u64().unwrap() > 96_000, "{got}");

    // With images: JPEGs at most 2 per second.
    let got = ws_client(p1, "/cam01/image", 2, 30);
    assert_eq!(
        channels_schema(&got, "/cam01/image"),
        "foxglove.CompressedImage"
    );
    assert_eq!(got["received"], 2, "{got}");

    // A second view on a taken port: one line, non-zero exit.
    let mut taken = spawn_view(&with_frames, p1);
    let status = taken.wait(Duration::from_secs(30)).expect("exits");
    assert!(!status.success());
    let err = taken.stderr();
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(
        err.contains(&format!("--listen 127.0.0.1:{p1}")) && err.contains("in use"),
        "{err}"
    );

    let finished = record.finish(Duration::from_secs(30));
    assert!(finished.status.success(), "{}", finished.stderr);
    let summary = mcap_summary(&mcap);
    let image = channel(&summary, "/cam01/image").unwrap_or_else(|| panic!("{summary}"));
    assert_eq!(image["schema"], "foxglove.CompressedImage");
    let n = image["count"].as_u64().unwrap();
    assert!(
        (4..=14).contains(&n),
        "{n} images in 6 s at most 2 per second"
    );
    drop(replay);
}

/// What `tests/view/foxglove_client.cjs` (the reference client,
/// `@foxglove/ws-protocol`'s `FoxgloveClient`, under Node.js) got from `port`
/// within `timeout_s`.
fn reference_client(port: u16, timeout_s: u32) -> Value {
    let script = repo_root().join("tests/view/foxglove_client.cjs");
    let out = std::process::Command::new("node")
        .arg(&script)
        .args([format!("ws://127.0.0.1:{port}"), timeout_s.to_string()])
        .env("NODE_PATH", node_modules())
        .output()
        .unwrap_or_else(|e| panic!("node {}: {e}", script.display()));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "foxglove_client.cjs failed: {stderr}");
    serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("{e}: {}\n{stderr}", String::from_utf8_lossy(&out.stdout)))
}

/// The status line and `Sec-WebSocket-Protocol` of the view's answer to a
/// WebSocket handshake offering `protocols`.
fn handshake(port: u16, protocols: &str) -> (String, Option<String>) {
    use std::io::{Read, Write};
    let mut tcp = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
    tcp.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    write!(
        tcp,
        "GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: {protocols}\r\n\r\n"
    )
    .unwrap();
    let mut head = Vec::new();
    let mut byte = [0u8];
    while !head.ends_with(b"\r\n\r\n") && tcp.read(&mut byte).unwrap() == 1 {
        head.push(byte[0]);
    }
    let head = String::from_utf8_lossy(&head).to_string();
    let status = head.lines().next().unwrap_or_default().to_string();
    let protocol = head.lines().find_map(|l| {
        let (k, v) = l.split_once(':')?;
        k.eq_ignore_ascii_case("sec-websocket-protocol")
            .then(|| v.trim().to_string())
    });
    (status, protocol)
}

#[test]
fn the_reference_foxglove_client_decodes_every_channel_of_the_live_view() {
    // Images on, so that every schema the view has is advertised.
    let site = demo_site("live-reference", |b| {
        format!("[ipc]\nmax_subscribers = 8\n\n{b}\n[view]\nframes = true\n")
    });
    let (replay, config) = replay_live(&site);
    let port = free_port();
    let mut view = spawn_view(&config, port);
    wait_for_view(&mut view);

    let got = reference_client(port, 150);
    let log = view.stderr();
    assert_eq!(got["opened"], true, "handshake: {got}\n{log}");
    assert_eq!(got["subprotocol"], "foxglove.websocket.v1", "{got}");
    assert_eq!(got["server"], "test", "serverInfo: {got}");
    assert_eq!(got["errors"], serde_json::json!([]), "{got}");
    assert_eq!(
        got["missing"],
        serde_json::json!([]),
        "a channel gave nothing: {got}"
    );
    let channels = got["channels"].as_object().unwrap();
    for (topic, schema) in CHANNELS.into_iter().chain([
        ("/cam01/image", "foxglove.CompressedImage"),
        ("/cam01/status/motion", "foxglove.Log"),
        ("/cam01/status/gate", "foxglove.Log"),
        ("/status/costmap", "foxglove.Log"),
    ]) {
        let ch = &channels
            .get(topic)
            .unwrap_or_else(|| panic!("{topic} not advertised: {got}"));
        assert_eq!(ch["schema"], schema, "{topic}: {ch}");
        assert_eq!(ch["schema_encoding"], "protobuf", "{topic}: {ch}");
        assert!(ch["decoded"].as_u64() > Some(0), "{topic}: {ch}");
    }
    // What the messages say, decoded with the advertised schemas: the demo's
    // 320 × 300 cost grid of int8 cells, per-block grids of 48 × 36 blocks.
    let first = |topic: &str| &channels[topic]["first"];
    let costmap = first("/costmap");
    assert_eq!(
        (
            &costmap["columns"],
            &costmap["rows"],
            &costmap["cell_stride"]
        ),
        (&320.into(), &300.into(), &1.into()),
        "{costmap}"
    );
    assert_eq!(costmap["fields"], serde_json::json!(["cost"]), "{costmap}");
    assert_eq!(costmap["frame_id"], "map", "{costmap}");
    let activity = first("/cam01/activity");
    assert_eq!(
        activity["fields"],
        serde_json::json!(["s1", "s2", "lt_mean", "present"]),
        "{activity}"
    );
    assert_eq!(
        (&activity["columns"], &activity["rows"]),
        (&48.into(), &36.into())
    );
    assert_eq!(
        first("/cam01/motion")["fields"],
        serde_json::json!(["density", "dx", "dy"])
    );
    assert_eq!(first("/cam01/image")["format"], "jpeg");
    assert!(first("/scene")["entities"].as_u64() > Some(0), "{got}");

    // Every name of the protocol is accepted, the newest preferred; anything else
    // is a 400 that names them.
    for (offered, status, agreed) in [
        (
            "foxglove.websocket.v1",
            "101",
            Some("foxglove.websocket.v1"),
        ),
        ("foxglove.sdk.v1", "101", Some("foxglove.sdk.v1")),
        (
            "foxglove.websocket.v1, foxglove.sdk.v1.1",
            "101",
            Some("foxglove.sdk.v1.1"),
        ),
        ("chat", "400", None),
    ] {
        let (line, protocol) = handshake(port, offered);
        assert!(line.contains(status), "{offered}: {line}");
        assert_eq!(protocol.as_deref(), agreed, "{offered}: {line}");
    }
    assert!(
        view.wait_for_stderr(
            "refused (HTTP 400): it offers none of the subprotocols",
            Duration::from_secs(5)
        ),
        "{}",
        view.stderr()
    );
    drop(replay);
}

/// A 1024 × 1024 cell grid (1 MiB per cost map) over the costmap tests' camera.
const BIG_GRID: &str = r#"
[costmap]
origin_x_m = -1.0
origin_y_m = 1.5
resolution_m = 0.005
width_cells = 1024
height_cells = 1024
frame_id = "test_map"
cost_scale = 0.05
weight_long_term = 0.0
"#;

#[test]
fn a_client_that_stops_reading_costs_the_view_its_budget_and_is_disconnected() {
    use crate::costmap::{HOT_BLOCK, HOT_S1, Source};
    const BUDGET_MIB: u64 = 2;
    const STALL_S: u64 = 6;
    let (site, port, view) = big_grid_view(
        "live-budget",
        &format!("client_budget_mib = {BUDGET_MIB}\nclient_stall_s = {STALL_S}\n"),
    );
    // The test is cam01's cascade: activity as fast as the view composes cost
    // maps of it, each one 1 MiB to every client that subscribed to /costmap.
    let ipc = site.ipc("source");
    let mut source = Source::new(&ipc, "2024-05-06T10:00:00Z");
    source.wait_for_subscriber(&view);
    let hot = [(HOT_BLOCK, HOT_S1)];
    let publish_for = |source: &mut Source, d: Duration, rss: &mut Vec<u64>| {
        let end = Instant::now() + d;
        while Instant::now() < end {
            source.send(&hot, 600);
            rss.push(rss_bytes(view.pid()).unwrap_or(0));
            std::thread::sleep(Duration::from_millis(50));
        }
    };
    // A client that reads, for the whole test.
    let reader = named_thread("ws-reader", move || {
        ws_client(port, "/costmap", 1_000_000, 30)
    });
    let mut rss = Vec::new();
    publish_for(&mut source, Duration::from_secs(4), &mut rss);
    let baseline = *rss[rss.len() / 2..].iter().max().unwrap();

    // One that subscribes to everything and stops reading.
    let python = python();
    let script = repo_root().join("tests/view/stalled_client.py");
    let url = format!("ws://127.0.0.1:{port}");
    // The script watches its socket, reading nothing, until the view closes it:
    // a generous deadline, as a loaded machine may be slow to notice.
    let stall_arg = (STALL_S + 40).to_string();
    let mut stalled = Proc::spawn(&python, &[script.to_str().unwrap(), &url, &stall_arg]);
    let line = stalled
        .wait_for_line("local_port", Duration::from_secs(30))
        .unwrap_or_else(|| panic!("the stalled client did not subscribe: {}", stalled.stderr()));
    let hello: Value = serde_json::from_str(&line).unwrap();
    assert!(
        hello["subscribed"]
            .as_array()
            .unwrap()
            .contains(&"/costmap".into()),
        "{hello}"
    );
    let gone = format!(
        "view: client 127.0.0.1:{} disconnected: over its budget",
        hello["local_port"]
    );
    let mut during = Vec::new();
    let subscribed = Instant::now();
    while !view.stderr().contains(&gone) && subscribed.elapsed() < Duration::from_secs(STALL_S + 15)
    {
        publish_for(&mut source, Duration::from_millis(500), &mut during);
    }
    let took = subscribed.elapsed();
    let log = view.stderr();
    // Unbounded, the backlog would grow by 1 MiB per cost map (~20 a second) for
    // the whole stall. Bounded: the budget, the message being written and the one
    // being read, plus what the allocator keeps.
    let peak = *during.iter().max().unwrap();
    let grown = peak.saturating_sub(baseline);
    let bound = (BUDGET_MIB + 16) << 20;
    eprintln!(
        "view RSS: {} MiB before the stalled client, {} MiB at most in the {took:?} after it subscribed ({} samples)",
        baseline >> 20,
        peak >> 20,
        during.len()
    );
    assert!(
        log.contains(&gone),
        "never disconnected in {took:?}:\n{log}"
    );
    assert!(
        took >= Duration::from_secs(STALL_S - 1),
        "disconnected after {took:?}, before view.client_stall_s = {STALL_S}"
    );
    assert!(
        grown < bound,
        "the view grew by {} MiB for a stalled client (bound {} MiB)",
        grown >> 20,
        bound >> 20
    );
    assert!(
        log.contains("reads more slowly than the site publishes"),
        "{log}"
    );
    // Its connection is gone, not just quiet.
    let end: Value = serde_json::from_str(
        &stalled
            .wait_for_line("closed", Duration::from_secs(STALL_S + 70))
            .unwrap_or_else(|| panic!("{}", stalled.stderr())),
    )
    .unwrap();
    eprintln!("the stalled client: {end}");
    assert_eq!(end["closed"], true, "{end}");

    // The reading client got cost maps all along.
    publish_for(&mut source, Duration::from_secs(1), &mut during);
    let got = reader.join().unwrap();
    assert!(got["received"].as_u64() > Some(40), "{got}");
    assert!(got["first_bytes"].as_u64() > Some(1 << 20), "{got}");
    // And the view's status counts what happened.
    let row = site
        .status_rows()
        .into_iter()
        .find(|r| r["stage"] == "view")
        .unwrap_or_else(|| panic!("no view row"));
    let detail = row["detail"].as_str().unwrap();
    assert!(detail.contains("stalled_clients=1"), "{detail}");
    assert!(!detail.contains("client_drops=0 "), "{detail}");
}

/// Publishes cam01's frames at the analysis size, one a second of capture time
/// (so that the view, at most 2 images a second, makes a JPEG of each).
struct FrameSource {
    publisher: isochron_runtime::ipc::StreamPublisher<isochron_runtime::ipc::Frames>,
    sent: u64,
}

impl FrameSource {
    const SIZE: (u32, u32) = (320, 240);

    fn new(ipc: &isochron_runtime::ipc::Ipc) -> FrameSource {
        let bytes = (Self::SIZE.0 * Self::SIZE.1) as usize;
        FrameSource {
            publisher: ipc.publisher("cam01", bytes).unwrap(),
            sent: 0,
        }
    }

    fn send(&mut self) {
        use isochron_wire::{CameraId, FrameHeader, PixelFormat, Preamble, Stream};
        let (w, h) = Self::SIZE;
        let k = self.sent;
        // A texture that moves, so that no two JPEGs are alike.
        let pixels: Vec<u8> = (0..w * h)
            .map(|i| ((i % w) as u64 * 7 + (i / w) as u64 * 13 + k * 29) as u8 ^ (i as u8))
            .collect();
        let cam = CameraId::new("cam01").unwrap();
        let mut preamble = Preamble::new::<u8>(Stream::Frames, cam, k, pixels.len());
        preamble.capture_time_ns = 1_714_989_600_000_000_000 + k as i64 * 1_000_000_000;
        preamble.origin_wall_ns = isochron_config::clock::wall_now_ns();
        let header = FrameHeader {
            preamble,
            width: w,
            height: h,
            stride: w,
            pixel_format: PixelFormat::Gray8 as u32,
            source_index: k,
        };
        self.publisher.send_copy(header, &pixels).unwrap();
        self.sent += 1;
    }
}

#[test]
fn many_stalled_clients_cost_the_view_its_memory_budget_and_the_rest_are_refused() {
    use crate::costmap::{HOT_BLOCK, HOT_S1, Source};
    const CLIENTS: u64 = 150;
    // view.max_clients and view.memory_budget_mib at their defaults (32, 128 MiB);
    // each client may hold 16 MiB, so 32 of them could hold 512 MiB but for the
    // view's memory budget.
    const MAX_CLIENTS: u64 = 32;
    const STALL_S: u64 = 8;
    let (site, port, view) = big_grid_view(
        "live-many",
        &format!("frames = true\nclient_budget_mib = 16\nclient_stall_s = {STALL_S}\n"),
    );
    // Cost maps of 1 MiB as fast as the view composes them, and images.
    let ipc = site.ipc("source");
    let mut source = Source::new(&ipc, "2024-05-06T10:00:00Z");
    let mut frames = FrameSource::new(&ipc);
    source.wait_for_subscriber(&view);
    let hot = [(HOT_BLOCK, HOT_S1)];
    let mut publish_for = |d: Duration, rss: &mut Vec<u64>| {
        let end = Instant::now() + d;
        while Instant::now() < end {
            source.send(&hot, 600);
            frames.send();
            rss.push(rss_bytes(view.pid()).unwrap_or(0));
            std::thread::sleep(Duration::from_millis(50));
        }
    };
    let mut rss = Vec::new();
    publish_for(Duration::from_secs(3), &mut rss);
    let baseline = *rss[rss.len() / 2..].iter().max().unwrap();

    // 150 clients that subscribe to everything and never read.
    let script = repo_root().join("tests/view/stalled_clients.py");
    let url = format!("ws://127.0.0.1:{port}");
    // The script watches the sockets, reading nothing, until the view has closed
    // every subscribed one: the deadline is generous (a loaded machine is slow to
    // notice), and only an open client at the deadline fails.
    let (n, deadline_arg) = (CLIENTS.to_string(), (STALL_S + 60).to_string());
    let mut clients = Proc::spawn(
        &python(),
        &[script.to_str().unwrap(), &url, &n, &deadline_arg],
    );
    let started = Instant::now();
    let mut during = Vec::new();
    let mut line = |clients: &mut Proc, needle: &str, within: Duration, during: &mut Vec<u64>| {
        let end = Instant::now() + within;
        loop {
            if let Some(line) = clients.wait_for_line(needle, Duration::ZERO) {
                return serde_json::from_str::<Value>(&line).unwrap();
            }
            assert!(Instant::now() < end, "no {needle}: {}", clients.stderr());
            publish_for(Duration::from_millis(500), during);
        }
    };
    let hello = line(
        &mut clients,
        "subscribed",
        Duration::from_secs(30),
        &mut during,
    );
    assert_eq!(
        hello["subscribed"],
        MAX_CLIENTS,
        "{hello}\n{}",
        view.stderr()
    );
    assert_eq!(hello["refused"]["503"], CLIENTS - MAX_CLIENTS, "{hello}");
    assert_eq!(hello["failed"], serde_json::json!([]), "{hello}");
    let end = line(
        &mut clients,
        "closed",
        Duration::from_secs(STALL_S + 90),
        &mut during,
    );
    let took = started.elapsed();
    let log = view.stderr();
    let peak = *during.iter().max().unwrap();
    let grown = peak.saturating_sub(baseline);
    eprintln!(
        "view RSS: {} MiB before {CLIENTS} stalled clients, {} MiB at most in the {took:?} after ({} samples); {end}",
        baseline >> 20,
        peak >> 20,
        during.len()
    );
    // Every subscribed client was disconnected for stalling, none left open (and
    // the view's own count agrees, below).
    assert_eq!(end["closed"], MAX_CLIENTS, "{end}\n{log}");
    assert!(
        grown <= 256 << 20,
        "the view grew by {} MiB for {CLIENTS} stalled clients (bound 256 MiB)",
        grown >> 20
    );
    assert!(log.contains("refused (HTTP 503)"), "{log}");
    assert!(log.contains("(view.max_clients)"), "{log}");
    assert!(log.contains("disconnected: over its budget"), "{log}");
    // The view's status counts them all.
    let want = [
        format!("refused_clients={}", CLIENTS - MAX_CLIENTS),
        format!("stalled_clients={MAX_CLIENTS}"),
        " clients=0 ".to_string(),
    ];
    let detail = eventually(Duration::from_secs(15), || {
        let row = site
            .status_rows()
            .into_iter()
            .find(|r| r["stage"] == "view")?;
        let detail = row["detail"].as_str()?.to_string();
        want.iter()
            .all(|w| detail.contains(w.as_str()))
            .then_some(detail)
    });
    assert!(
        detail.is_some(),
        "view status never said {want:?}: {:?}",
        site.status_rows()
    );
}

fn channels_schema(got: &Value, topic: &str) -> String {
    got["channels"][topic]["schema"]
        .as_str()
        .unwrap_or_else(|| panic!("{topic} not advertised: {got}"))
        .to_string()
}

/// The row of the view in `isochron status --json` of `config`, if it has one.
fn view_row(site: &TestSite, config: &Path) -> Option<Value> {
    let config = config.to_str().unwrap();
    let done = site.isochron(
        &["status", "--config", config, "--json"],
        Duration::from_secs(30),
    );
    let rows: Vec<Value> = done
        .stdout
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect();
    assert!(rows.iter().any(|r| r["stage"] == "gate"), "{}", done.stdout);
    rows.into_iter().find(|r| r["stage"] == "view")
}

#[test]
fn a_running_view_is_a_row_of_isochron_status() {
    let site = demo_site("view-status", |b| b);
    let (replay, config) = replay_live(&site);
    assert_eq!(view_row(&site, &config), None, "no view runs yet");

    let mut view = spawn_view(&config, free_port());
    wait_for_view(&mut view);
    // The first report comes at the view's first tick, the next 5 s later with
    // what it took from the streams.
    let row = eventually(Duration::from_secs(30), || {
        view_row(&site, &config).filter(|r| r["received"].as_u64() > Some(0))
    })
    .unwrap_or_else(|| panic!("no view row with samples: {}", view.stderr()));
    assert_eq!(row["state"], "running", "{row}");
    assert_eq!(row["camera"], "", "site-wide: {row}");
    assert_eq!(row["pid"], view.pid(), "{row}");
    assert!(row["dropped"].is_u64() && row["rejected"] == 0, "{row}");
    assert_eq!(row["info"], "sink=live", "{row}");
    assert!(row["counters"]["published"].as_f64() > Some(0.0), "{row}");
    let detail = row["detail"].as_str().unwrap();
    assert!(
        detail.starts_with("published=") && detail.ends_with(" sink=live"),
        "{row}"
    );
    assert!(row["sent"].as_u64() > Some(0), "it published: {row}");

    // Stopped, it has no row any more.
    assert!(view.terminate(Duration::from_secs(10)).success());
    assert_eq!(view_row(&site, &config), None, "the view stopped");
    drop(replay);
}

#[test]
fn a_recorder_whose_disk_fills_closes_the_file_cleanly() {
    // A 5 MiB file system: the recorder stops at 4 MiB free, with ~1 MiB written.
    let site = demo_site("record-full", |b| format!("{b}\n[view]\nframes = true\n"));
    let mnt = site.path("small");
    let Some(_disk) = isochron_tests::Tmpfs::mount(&mnt, "5m") else {
        return;
    };
    let file = mnt.join("run.mcap");
    let done = replay_recorded(&site, &file, &[]);
    assert_eq!(
        done.status.code(),
        Some(1),
        "{}\n{}",
        done.stdout,
        done.stderr
    );
    assert!(
        done.stderr
            .contains("recording closed early (the file is complete and readable)"),
        "{}",
        done.stderr
    );
    // The replay itself finished: its summary is there.
    assert!(site.path("replay/summary.json").is_file());
    let summary = mcap_summary(&file);
    assert_eq!(summary["has_summary"], true, "{summary}");
    assert_eq!(summary["messages_read"], summary["message_count"]);
    assert!(summary["messages_read"].as_u64().unwrap() > 0);
    let size = std::fs::metadata(&file).unwrap().len();
    assert!(
        size < 2 << 20,
        "{size} bytes on a 5 MiB disk with 4 MiB reserve"
    );
}

// ---------------------------------------------------------------------------
// Heat maps of the long-term store.

/// A store of `camera` (320×240 in 16-px blocks): the top half of the view busy
/// from 08:00 to 18:00 (0.04), the bottom half a little (0.01), nights unlearned.
fn heat_store(path: &Path, camera: &str) {
    use isochron_config::clock::Cycle;
    use isochron_store::{Store, StoreMeta};
    use isochron_wire::geometry::BlockGrid;
    let meta = StoreMeta::new(camera, BlockGrid::new(320, 240, 16), Cycle::Daily, 0);
    let mut store = Store::open_or_create(path, &meta).unwrap();
    for t in 6 * 60..20 * 60 {
        let busy = (8 * 60..18 * 60).contains(&t);
        let mean = (0..300)
            .map(|b| if b < 150 && busy { 0.04 } else { 0.01 })
            .collect();
        store.teach(t, 7, mean).unwrap();
    }
}

#[test]
fn a_heat_map_draws_blocks_by_minute_of_day() {
    let site = TestSite::new("heatmap", "");
    let store = site.path("cam01.isochron.sqlite");
    heat_store(&store, "cam01");
    let out = site.path("heat.png");
    let store_arg = store.display().to_string();
    let plot = |camera: &str, out: &str| {
        site.isochron(
            &[
                "plot", "heatmap", "--store", &store_arg, "--camera", camera, "--out", out,
            ],
            Duration::from_secs(60),
        )
    };
    let done = plot("cam01", out.to_str().unwrap());
    assert!(done.status.success(), "{}", done.stderr);
    // 300 blocks in 300 rows of 1 px... scaled to 1 px each; 720 two-minute columns.
    assert!(
        done.stdout.contains("300 rows × 1440 minutes"),
        "{}",
        done.stdout
    );
    assert!(
        done.stdout.contains("colour scale 0..0.0400"),
        "{}",
        done.stdout
    );
    let (w, h) = png_size(&out);
    assert_eq!((w, h), (80 + 720 + 110, 50 + 300 + 50));

    // A store of another camera (the flags disagree), and an output that is not
    // a PNG: one line each, the usage exit code.
    for (camera, out, expect) in [
        (
            "cam02",
            out.to_str().unwrap(),
            "camera 'cam01', not of --camera cam02",
        ),
        ("cam01", "/tmp/heat.svg", "expected a .png file name"),
    ] {
        let done = plot(camera, out);
        assert_eq!(done.status.code(), Some(64), "{expect}: {}", done.stderr);
        assert_eq!(done.stderr.lines().count(), 1, "{}", done.stderr);
        assert!(done.stderr.contains(expect), "{}", done.stderr);
    }
}

/// `isochron costmap snapshot --config site.toml ARGS --out OUT --json` of `site`.
fn snapshot(site: &TestSite, args: &[&str], out: &str) -> isochron_tests::Finished {
    let config = site.config_path().display().to_string();
    let mut all = vec!["costmap", "snapshot", "--config", &config];
    all.extend_from_slice(args);
    all.extend(["--out", out, "--json"]);
    site.isochron(&all, Duration::from_secs(60))
}

/// The JSON and the cells (rows of cost) of a snapshot with `args` that must
/// succeed; the picture and the map_server pair beside it are checked too.
fn snapshot_cells(site: &TestSite, args: &[&str]) -> (Value, Vec<Vec<i64>>) {
    let name: String = args
        .concat()
        .chars()
        .filter(char::is_ascii_alphanumeric)
        .collect();
    let out = site.path(&format!("{name}.png"));
    let done = snapshot(site, args, out.to_str().unwrap());
    assert!(done.status.success(), "{}", done.stderr);
    let json: Value = serde_json::from_str(&done.stdout).unwrap();
    let rows = json["cells"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| {
            r.as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_i64().unwrap())
                .collect()
        })
        .collect();
    assert!(png_size(&out).0 >= 800, "{}", out.display());
    assert!(out.with_extension("pgm").is_file() && out.with_extension("yaml").is_file());
    (json, rows)
}

/// The floor camera of planning's tests (320×240 looking straight down at a
/// 4 m × 3 m floor), a 5 cm grid with a margin no camera sees, one segment.
const SNAPSHOT_SITE: &str = r#"[[camera]]
id = "cam01"
source = "video.avi"
floor_points = [
  { image_px = [0, 0], floor_m = [0, 3] },
  { image_px = [320, 0], floor_m = [4, 3] },
  { image_px = [320, 240], floor_m = [4, 0] },
  { image_px = [0, 240], floor_m = [0, 0] },
]

[costmap]
resolution_m = 0.05
width_cells = 100
height_cells = 80
origin_x_m = -0.5
origin_y_m = -0.5
cost_scale = 0.02
segment = [{ name = "west", polygon_m = [[0.2, 0.2], [1.8, 0.2], [1.8, 2.8], [0.2, 2.8]] }]
"#;

#[test]
fn a_snapshot_at_a_time_of_day_draws_what_the_long_term_model_expects() {
    let site = TestSite::new("snapshot-at", SNAPSHOT_SITE);
    // One simulated day through the real cascade: people only from 08:00 to 18:00.
    std::fs::write(
        site.path("busy.csv"),
        "0,0\n479,0\n480,1\n1079,1\n1080,0\n1439,0\n",
    )
    .unwrap();
    let (profile, state) = (site.path("busy.csv"), site.path("state"));
    let (profile, state) = (profile.to_str().unwrap(), state.to_str().unwrap());
    let synth = [
        ["synth", "--camera", "cam01", "--days", "1"].as_slice(),
        &["--profile", profile, "--out", state],
        &["--fps", "1", "--grid", "20x15", "--cycle", "daily"],
    ];
    let done = site.isochron(&synth.concat(), Duration::from_secs(120));
    assert!(done.status.success(), "{}", done.stderr);
    let snapshot_at = |at: &str, out: &str| snapshot(&site, &["--at", at], out);
    let cells_of = |at: &str| snapshot_cells(&site, &["--at", at]);
    // Cell (i, j) is at x = -0.5 + 0.05 (i + 0.5) m: the camera sees 0..4 × 0..3 m.
    let in_view = |i: usize, j: usize| (11..89).contains(&i) && (11..69).contains(&j);
    let (busy, rows) = cells_of("10:00");
    assert_eq!(busy["grid"]["width_cells"], 100, "{busy}");
    assert_eq!((rows.len(), rows[0].len()), (80, 100));
    let mut lit = 0;
    for (j, row) in rows.iter().enumerate() {
        for (i, &c) in row.iter().enumerate() {
            if in_view(i, j) {
                assert!((0..=99).contains(&c), "({i}, {j}) = {c}");
                lit += (c > 0) as usize;
            } else if !(10..=89).contains(&i) || !(10..=69).contains(&j) {
                assert_eq!(c, -1, "({i}, {j}) is outside the camera's view");
            }
        }
    }
    assert!(lit > 2000, "{lit} cells with cost at 10:00");
    let above_zero = rows.iter().flatten().filter(|&&c| c > 0).count();
    assert_eq!(busy["cells_above_zero"], above_zero, "{busy}");
    let (quiet, rows) = cells_of("03:00");
    assert_eq!(quiet["cells_above_zero"], 0, "nobody at 03:00");
    assert!(rows.iter().flatten().all(|&c| c <= 0));
    assert_eq!(quiet["cells_seen"], busy["cells_seen"]);

    // Bad --at: one line, the usage exit code (shared/exit/src/lib.rs).
    let out = site.path("bad.png");
    let done = snapshot_at("25:00", out.to_str().unwrap());
    assert_usage_error(
        &done,
        "invalid value '25:00' for '--at <HH:MM>': expected a time of day HH:MM",
    );
}

/// A usage error: exit 64 (shared/exit/src/lib.rs) and one line that says `expect`.
fn assert_usage_error(done: &isochron_tests::Finished, expect: &str) {
    assert_eq!(done.status.code(), Some(64), "{}", done.stderr);
    assert_eq!(done.stderr.lines().count(), 1, "{}", done.stderr);
    assert!(done.stderr.contains(expect), "{}", done.stderr);
}

#[test]
fn a_snapshot_of_a_weekly_store_draws_the_day_asked_for() {
    use isochron_config::clock::Cycle;
    use isochron_store::{Store, StoreMeta, store_path};
    use isochron_wire::geometry::BlockGrid;
    let site = TestSite::new(
        "snapshot-day",
        &format!("[cascade]\ncycle = \"weekly\"\n\n{SNAPSHOT_SITE}"),
    );
    // A weekly store (one model per weekday) written as the cascade writes it:
    // from 09:00 to 11:00 people on Mondays in the west half of the view (blocks
    // with x < 160 px: x < 2 m on the floor), on Tuesdays in the east half.
    let meta = StoreMeta::new("cam01", BlockGrid::new(320, 240, 16), Cycle::Weekly, 0);
    let path = store_path(&site.config().state_dir(), "cam01");
    let mut store = Store::open_or_create(&path, &meta).unwrap();
    for (day, west) in [(0, true), (1, false)] {
        for minute in 9 * 60..11 * 60 {
            let mean = (0..300)
                .map(|b| if (b % 20 < 10) == west { 0.04 } else { 0.0 })
                .collect();
            store.teach(day * 1440 + minute, 7, mean).unwrap();
        }
    }
    drop(store);

    // Cell i is at x = -0.5 + 0.05 (i + 0.5) m: i < 50 is west of x = 2 m.
    let lit = |rows: &[Vec<i64>], west: bool| -> usize {
        let side = |i: usize| if west { i < 45 } else { i >= 55 };
        rows.iter()
            .flat_map(|r| r.iter().enumerate())
            .filter(|(i, c)| side(*i) && **c > 0)
            .count()
    };
    for (day, t_star, west) in [("mon", 600, true), ("tue", 1440 + 600, false)] {
        let (json, rows) = snapshot_cells(&site, &["--at", "10:00", "--day", day]);
        assert_eq!(json["cycle"], "weekly", "{day}");
        assert_eq!(json["day"], day);
        assert_eq!(json["t_star"], t_star, "{day}");
        assert!(
            lit(&rows, west) > 1500,
            "{day}: {} cells lit",
            lit(&rows, west)
        );
        assert_eq!(lit(&rows, !west), 0, "{day}: the other half is quiet");
    }
    // A day the store never learned: said, 66, and no picture (a blank map
    // would look like a quiet day).
    let out = site.path("wed.png");
    let done = snapshot(
        &site,
        &["--at", "10:00", "--day", "wednesday"],
        out.to_str().unwrap(),
    );
    assert_eq!(
        done.status.code(),
        Some(isochron_exit::NO_INPUT),
        "{}",
        done.stderr
    );
    assert!(
        done.stderr.contains("nothing learned for wed") && done.stderr.contains("learned mon, tue"),
        "{}",
        done.stderr
    );
    assert!(!out.exists());

    // A bad --day: one line, the usage exit code.
    let out = site.path("bad-day.png").display().to_string();
    let done = snapshot(&site, &["--at", "10:00", "--day", "funday"], &out);
    assert_usage_error(
        &done,
        "invalid value 'funday' for '--day <DAY>': expected a day of the week, mon .. sun",
    );
}
