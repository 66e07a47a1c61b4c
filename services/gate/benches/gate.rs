//! Gate benchmark: the paper's hybrid scheme on vtest.avi, in one run.
//!
//! * **detect all**: the detector (HOG, as configured in `config/demo.toml`) on
//!   every frame, one thread — what a detector-only pipeline costs;
//! * **hybrid**: the whole process group (`isochron replay`, release build) with the
//!   detector gated by events — frames/s of the group and frames detected.
//!
//! Also checks that gating missed no person-present interval: every PETS09 frame
//! with people in it must lie inside an event.
//!
//! Run: `cargo xtask bench gate` (it builds the release binaries first).

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use isochron_gate::detector::Detector;
use isochron_shared::config::Config;
use opencv::prelude::*;
use opencv::{imgproc, videoio};

/// Frames the detect-all pass times (every n-th of the video: HOG is slow).
const DETECT_ALL_FRAMES: usize = 80;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .canonicalize()
        .unwrap()
}

fn main() {
    let root = repo();
    let video = root.join("data/vtest.avi");
    let config_path = root.join("config/demo.toml");
    let config = Config::load(&config_path).expect("config/demo.toml");

    // Detect all: decode every frame, time the detector on an even sample of them.
    let mut cap =
        videoio::VideoCapture::from_file(video.to_str().unwrap(), videoio::CAP_ANY).unwrap();
    let (mut bgr, mut gray) = (Mat::default(), Mat::default());
    let mut frames = Vec::new();
    // The size is taken while reading: after the last read the Mat is empty (0x0).
    let (mut w, mut h) = (0, 0);
    while cap.read(&mut bgr).unwrap() && !bgr.empty() {
        imgproc::cvt_color(&bgr, &mut gray, imgproc::COLOR_BGR2GRAY, 0).unwrap();
        (w, h) = (gray.cols() as u32, gray.rows() as u32);
        frames.push(gray.data_bytes().unwrap().to_vec());
    }
    let total = frames.len();
    let mut detector =
        Detector::from_config(&config.config.gate.detector, &config.base_dir()).unwrap();
    let step = (total / DETECT_ALL_FRAMES).max(1);
    let t0 = Instant::now();
    let mut people = 0;
    let mut timed = 0;
    for f in frames.iter().step_by(step) {
        people += detector.detect(f, w, h).unwrap().len();
        timed += 1;
    }
    let detect_all_fps = timed as f64 / t0.elapsed().as_secs_f64();

    // Hybrid: the whole group on the whole video.
    let out = root.join("target/bench-gate");
    let _ = std::fs::remove_dir_all(&out);
    let isochron = root.join("target/release/isochron");
    assert!(
        isochron.is_file(),
        "build the release binaries first (cargo xtask bench gate does)"
    );
    let status = Command::new(&isochron)
        .args([
            "replay",
            video.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--config",
        ])
        .arg(&config_path)
        .status()
        .expect("isochron replay");
    assert!(
        status.success(),
        "replay failed; see {}",
        out.join("logs").display()
    );
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let group_frames = summary["counts"]["frames"].as_u64().unwrap();
    let hybrid_fps = summary["frames_per_s"].as_f64().unwrap();
    let detected = summary["gate"]["frames_detected"].as_u64().unwrap_or(0);
    let detected_fraction = detected as f64 / group_frames.max(1) as f64;

    // Person-present frames outside every event would be missed people.
    let events: Vec<serde_json::Value> = std::fs::read_to_string(out.join("events.jsonl"))
        .unwrap_or_default()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let covered = |frame: u64| {
        events.iter().any(|e| {
            e["start_frame"].as_u64().unwrap() <= frame
                && frame <= e["end_frame"].as_u64().unwrap() + 10
        })
    };
    let gt =
        std::fs::read_to_string(root.join("tests/data/pets09-s2l1-gt.txt")).unwrap_or_default();
    let mut present: Vec<u64> = gt
        .lines()
        .filter_map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (f.get(6) == Some(&"1")).then(|| f[0].parse::<u64>().unwrap() - 1)
        })
        .collect();
    present.sort_unstable();
    present.dedup();
    let missed = present.iter().filter(|&&f| !covered(f)).count();

    let speedup = hybrid_fps / detect_all_fps;
    println!(
        "gate benchmark on vtest.avi ({w}x{h}, {total} frames), detector: {}",
        detector.name()
    );
    println!("{:<34} {:>12} {:>16}", "", "frames/s", "frames detected");
    println!(
        "{:<34} {:>12.1} {:>16}",
        format!("detector on every frame ({timed} timed)"),
        detect_all_fps,
        total
    );
    println!(
        "{:<34} {:>12.1} {:>16}",
        "hybrid group (5 processes)", hybrid_fps, detected
    );
    println!(
        "speedup {speedup:.1}×, detector on {:.2} % of frames, {} events, {people} people found in the timed frames",
        detected_fraction * 100.0,
        events.len()
    );
    println!(
        "person-present frames outside any event: {missed} of {} (missed intervals: {})",
        present.len(),
        if missed == 0 { "none" } else { "SOME" }
    );
    println!(
        "{{\"bench\":\"gate\",\"detect_all_fps\":{detect_all_fps:.2},\"hybrid_fps\":{hybrid_fps:.1},\"speedup\":{speedup:.1},\"detected_fraction\":{detected_fraction:.4}}}"
    );
}
