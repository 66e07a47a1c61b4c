//! Long commands stopped as a user stops them: Ctrl-C (SIGINT) or SIGTERM ends
//! `replay` and `synth` with 130 within seconds, their group stopped, and what
//! they had done kept and said (`summary.json` with `"interrupted": true`; the
//! store's whole minutes).

use std::time::{Duration, Instant};

use isochron_store::{Store, store_path};
use isochron_tests::{Proc, TestSite, bin, vtest};
use serde_json::Value;

/// Sends `signal` to `proc` and waits for it to end: its exit code, how long.
fn stopped_by(proc: &mut Proc, signal: i32) -> (Option<i32>, Duration) {
    let sent = Instant::now();
    proc.signal(signal);
    let status = proc
        .wait(Duration::from_secs(40))
        .unwrap_or_else(|| panic!("still running 40 s after the signal:\n{}", proc.stderr()));
    (status.code(), sent.elapsed())
}

#[test]
fn ctrl_c_on_replay_stops_its_group_and_writes_the_summary() {
    let site = TestSite::new("stop-replay", "");
    let out = site.path("out");
    let (video, out_arg) = (vtest().display().to_string(), out.display().to_string());
    let mut replay = Proc::spawn(
        &bin("isochron"),
        &["replay", &video, "--out", &out_arg, "--speed", "1"],
    );
    assert!(
        replay
            .wait_for_line("replay: ", Duration::from_secs(90))
            .is_some(),
        "the replay did not start:\n{}",
        replay.stderr()
    );
    std::thread::sleep(Duration::from_secs(5));
    let (code, took) = stopped_by(&mut replay, libc::SIGINT);
    let stderr = replay.stderr();
    assert_eq!(code, Some(isochron_exit::INTERRUPTED), "{stderr}");
    assert!(took < Duration::from_secs(15), "took {took:?}");
    assert!(
        stderr.contains("interrupted (SIGINT or SIGTERM)"),
        "{stderr}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
    let summary: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["interrupted"], true, "{summary}");
    assert!(
        summary["counts"]["frames"].as_u64().unwrap() > 0,
        "{summary}"
    );
    // Every line written is whole.
    for name in ["events.jsonl", "detections.jsonl"] {
        let text = std::fs::read_to_string(out.join(name)).unwrap_or_default();
        for line in text.lines() {
            serde_json::from_str::<Value>(line).unwrap_or_else(|e| panic!("{name}: {e}: {line}"));
        }
    }
}

#[test]
fn sigterm_on_synth_ends_the_cascade_and_keeps_the_whole_minutes() {
    let site = TestSite::new("stop-synth", "");
    let out = site.path("run");
    let args = isochron_tests::office_synth_args(&out, "365", "2");
    let mut synth = Proc::spawn(&bin("isochron"), &args);
    assert!(
        synth
            .wait_for_line("cascade started", Duration::from_secs(60))
            .is_some(),
        "synth did not start:\n{}",
        synth.stderr()
    );
    std::thread::sleep(Duration::from_secs(5));
    let (code, took) = stopped_by(&mut synth, libc::SIGTERM);
    let (stdout, stderr) = (synth.stdout(), synth.stderr());
    assert_eq!(code, Some(isochron_exit::INTERRUPTED), "{stdout}\n{stderr}");
    assert!(took < Duration::from_secs(15), "took {took:?}");
    assert!(stderr.contains("synth: interrupted"), "{stderr}");
    assert!(!stdout.contains("restarting"), "{stdout}");
    assert!(stdout.contains("synth: store"), "{stdout}");
    let store = Store::open_read_only(&store_path(&out, "cam01"), "cam01").unwrap();
    let progress = store.progress().unwrap();
    assert!(progress.committed > 10, "{progress:?}");
    // The cascade it started ended with it.
    let cascades = std::process::Command::new("pgrep")
        .args([
            "-f",
            &format!("isochron-cascade --config {}", out.display()),
        ])
        .output()
        .unwrap();
    assert!(cascades.stdout.is_empty(), "a cascade is left running");
}
