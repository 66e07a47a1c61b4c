//! Commands on a full disk (a tmpfs a few hundred kB large): they end within
//! seconds with 69 and say why, leave no empty or half-written file, and the
//! cascade passes its end of stream on though its last minute could not be
//! stored.

use std::time::{Duration, Instant};

use isochron_tests::{Proc, TestSite, Tmpfs, bin, vtest};

/// Runs `isochron args` to its end (within `timeout`): its exit code, stderr,
/// and how long it took.
fn run(args: &[&str], timeout: Duration) -> (Option<i32>, String, Duration) {
    let started = Instant::now();
    let mut proc = Proc::spawn(&bin("isochron"), args);
    let status = proc.wait(timeout).unwrap_or_else(|| {
        panic!(
            "isochron {args:?} still running after {timeout:?}:\n{}",
            proc.stderr()
        )
    });
    (status.code(), proc.stderr(), started.elapsed())
}

#[test]
fn synth_on_a_full_disk_is_69_within_seconds_saying_why() {
    let site = TestSite::new("full-synth", "");
    let Some(_disk) = Tmpfs::mount(&site.path("disk"), "300k") else {
        return;
    };
    let args = isochron_tests::office_synth_args(&site.path("disk/run"), "3", "1");
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let (code, stderr, took) = run(&args, Duration::from_secs(90));
    eprintln!(
        "synth on a full disk ended with {code:?} after {:.1} s",
        took.as_secs_f64()
    );
    assert_eq!(code, Some(isochron_exit::UNAVAILABLE), "{stderr}");
    assert!(stderr.contains("cannot write its store"), "{stderr}");
    assert!(took < Duration::from_secs(60), "took {took:?}");
}

#[test]
fn replay_on_a_full_disk_is_69_and_leaves_no_empty_summary() {
    let site = TestSite::new("full-replay", "");
    let Some(_disk) = Tmpfs::mount(&site.path("disk"), "200k") else {
        return;
    };
    let out = site.path("disk/run");
    let (video, out_arg) = (vtest().display().to_string(), out.display().to_string());
    let (code, stderr, took) = run(
        &["replay", &video, "--out", &out_arg],
        Duration::from_secs(110),
    );
    eprintln!(
        "replay on a full disk ended with {code:?} after {:.1} s",
        took.as_secs_f64()
    );
    assert_eq!(code, Some(isochron_exit::UNAVAILABLE), "{stderr}");
    assert!(stderr.contains("No space left on device"), "{stderr}");
    assert!(took < Duration::from_secs(100), "took {took:?}");
    if let Ok(text) = std::fs::read_to_string(out.join("summary.json")) {
        serde_json::from_str::<serde_json::Value>(&text).expect("a whole summary.json");
    }
    // No temporary file of the summary is left.
    let left: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .filter_map(Result::ok)
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(".summary.json"))
        .collect();
    assert!(left.is_empty(), "{left:?}");
}
