//! Bad inputs an operator meets: a truncated video, a video of another size than
//! the camera's configured one.

use std::path::{Path, PathBuf};
use std::time::Duration;

use isochron_tests::{Finished, TestSite, VTEST_FRAMES, vtest};
use serde_json::Value;

const START: &str = "2026-03-02T07:00:00Z";

/// The first 40 % of vtest.avi's bytes: a file that states 795 frames and ends
/// early.
fn write_truncated_vtest(site: &TestSite, name: &str) -> PathBuf {
    let bytes = std::fs::read(vtest()).unwrap();
    let path = site.path(name);
    std::fs::write(&path, &bytes[..bytes.len() * 2 / 5]).unwrap();
    path
}

/// Runs `isochron replay video --out site/out` on `site`'s config.
fn replay(site: &TestSite, video: &Path) -> Finished {
    site.replay(video, &site.path("out"), START)
}

fn summary(site: &TestSite) -> Value {
    serde_json::from_str(&std::fs::read_to_string(site.path("out/summary.json")).unwrap()).unwrap()
}

#[test]
fn replay_of_a_truncated_file_writes_everything_flags_it_and_exits_65() {
    let site = TestSite::with_source("inputs-cut", "", "replaced-by-replay");
    let video = write_truncated_vtest(&site, "cut.avi");
    let out = site.path("out");
    let run = replay(&site, &video);
    assert_eq!(
        run.status.code(),
        Some(isochron_exit::DATA),
        "stdout:\n{}\nstderr:\n{}",
        run.stdout,
        run.stderr
    );
    let flagged = lines_with(&run.stderr, "is truncated or damaged");
    assert_eq!(flagged.len(), 1, "{}", run.stderr);
    assert!(
        flagged[0].contains("of the 795 frames it states"),
        "{}",
        flagged[0]
    );
    assert!(!run.stderr.contains("panicked"), "{}", run.stderr);

    // Every output is written, covering the frames that were read.
    let summary = summary(&site);
    let frames = summary["counts"]["frames"].as_u64().unwrap();
    assert!(frames > 100 && frames < VTEST_FRAMES, "{summary}");
    let input = &summary["input"];
    assert_eq!(input["truncated"], Value::Bool(true), "{summary}");
    assert_eq!(
        input["frames_stated"].as_u64(),
        Some(VTEST_FRAMES),
        "{summary}"
    );
    assert_eq!(input["frames_read"].as_u64(), Some(frames), "{summary}");
    for file in ["events.jsonl", "detections.jsonl", "config.toml"] {
        assert!(out.join(file).exists(), "{file} missing");
    }
    assert!(frames > 0 && summary["counts"]["motion"].as_u64().unwrap() > 0);
}

#[test]
fn replay_of_a_complete_file_says_it_is_complete_and_exits_0() {
    let site = TestSite::with_source("inputs-whole", "", "replaced-by-replay");
    let run = replay(&site, &vtest());
    assert!(run.status.success(), "{}", run.stderr);
    assert!(!run.stderr.contains("truncated"), "{}", run.stderr);
    let summary = summary(&site);
    assert_eq!(
        summary["input"],
        serde_json::json!({
            "frames_stated": VTEST_FRAMES,
            "frames_read": VTEST_FRAMES,
            "truncated": false,
        }),
        "{summary}"
    );
    // What the group wrote is its user's only (umask 0077, as under the units).
    use std::os::unix::fs::PermissionsExt;
    let store = site.path("out/state/cam01.isochron.sqlite");
    for file in [site.path("out/summary.json"), store] {
        let mode = std::fs::metadata(&file)
            .unwrap_or_else(|e| panic!("{}: {e}", file.display()))
            .permissions()
            .mode();
        assert_eq!(mode & 0o077, 0, "{} is {mode:o}", file.display());
    }
}

/// Runs capture on `site`'s cam01 to the end of its file: its stderr.
fn capture_stderr(site: &TestSite) -> String {
    let done = site
        .spawn("isochron-capture", &["--camera", "cam01"])
        .finish(Duration::from_secs(120));
    assert!(done.status.success(), "{}", done.stderr);
    done.stderr
}

#[test]
fn a_source_of_another_aspect_ratio_is_warned_about_once() {
    let site = TestSite::new("inputs-size", "");
    let cut = write_truncated_vtest(&site, "cut.avi");
    let camera = |w: u32, h: u32| {
        format!(
            "[[camera]]\nid = \"cam01\"\nsource = \"{}\"\nspeed = \"max\"\nwidth = {w}\nheight = {h}\n",
            cut.display()
        )
    };

    site.write_config(&camera(640, 360));
    let stderr = capture_stderr(&site);
    let warned = lines_with(&stderr, "rescaled to the configured");
    assert_eq!(warned.len(), 1, "{stderr}");
    assert!(warned[0].contains("WARN"), "{}", warned[0]);
    assert!(
        warned[0].contains(
            "camera 'cam01': the source is 768x576, rescaled to the configured 640x360 (aspect ratio changes by 33.3 %)"
        ),
        "{}",
        warned[0]
    );

    // Half the size, same aspect ratio: an info line, no warning.
    site.write_config(&camera(384, 288));
    let stderr = capture_stderr(&site);
    let told = lines_with(
        &stderr,
        "rescaled to the configured 384x288 (same aspect ratio)",
    );
    assert_eq!(told.len(), 1, "{stderr}");
    assert!(told[0].contains("INFO"), "{}", told[0]);

    // The configured size is the source's: nothing said.
    site.write_config(&camera(768, 576));
    let stderr = capture_stderr(&site);
    assert!(!stderr.contains("rescaled"), "{stderr}");
}

/// The lines of `text` that contain `needle`.
fn lines_with<'a>(text: &'a str, needle: &str) -> Vec<&'a str> {
    text.lines().filter(|l| l.contains(needle)).collect()
}
