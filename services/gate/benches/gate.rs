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
//! Run: `cargo xtask bench gate` (it builds the release binaries first). The
//! binaries are those of the profile the bench was built in (`target/<profile>`, or
//! `$ISOCHRON_BIN_DIR`).
//!
//! `--quick`: the same on the first [`QUICK_CLIP_FRAMES`] frames of vtest.avi (written
//! to a short MJPG clip the group replays), the detector timed on
//! [`QUICK_DETECT_ALL_FRAMES`] of them: a check that the bench runs; the JSON line
//! gets `"quick":true`.

use std::path::Path;
use std::process::Command;
use std::time::Instant;

use isochron_config::Config;
use isochron_gate::detector::Detector;
use isochron_gate::worker::Region;
use isochron_tests::{bin_dir, mjpg_writer, repo_root};
use opencv::core::Size;
use opencv::prelude::*;
use opencv::{imgproc, videoio};

/// Frames the detect-all pass times (every n-th of the video: HOG is slow).
const DETECT_ALL_FRAMES: usize = 80;
/// Frames of vtest.avi in the `--quick` clip (people walk in all of them).
const QUICK_CLIP_FRAMES: usize = 150;
/// Frames the detect-all pass times with `--quick`.
const QUICK_DETECT_ALL_FRAMES: usize = 4;

/// Writes `frames` (BGR) to an MJPG clip at `path`.
fn write_clip(path: &Path, frames: &[Mat], fps: f64) {
    let size = Size::new(frames[0].cols(), frames[0].rows());
    let mut writer = mjpg_writer(path, fps, size);
    for f in frames {
        writer.write(f).unwrap();
    }
    writer.release().unwrap();
}

fn main() {
    let quick = std::env::args().any(|a| a == "--quick");
    let root = repo_root();
    let mut video = root.join("data/vtest.avi");
    let config_path = root.join("config/demo.toml");
    let config = Config::load(&config_path).expect("config/demo.toml");
    let out = root.join(if quick {
        "target/bench-gate-quick"
    } else {
        "target/bench-gate"
    });
    let _ = std::fs::remove_dir_all(&out);

    // Detect all: decode every frame, time the detector on an even sample of them.
    let mut cap =
        videoio::VideoCapture::from_file(video.to_str().unwrap(), videoio::CAP_ANY).unwrap();
    let (mut bgr, mut gray) = (Mat::default(), Mat::default());
    let mut frames = Vec::new();
    let mut clip = Vec::new();
    // The size is taken while reading: after the last read the Mat is empty (0x0).
    let (mut w, mut h) = (0, 0);
    while (!quick || frames.len() < QUICK_CLIP_FRAMES)
        && cap.read(&mut bgr).unwrap()
        && !bgr.empty()
    {
        imgproc::cvt_color(&bgr, &mut gray, imgproc::COLOR_BGR2GRAY, 0).unwrap();
        (w, h) = (gray.cols() as u32, gray.rows() as u32);
        frames.push(gray.data_bytes().unwrap().to_vec());
        if quick {
            clip.push(bgr.try_clone().unwrap());
        }
    }
    let total = frames.len();
    assert!(total > 0, "no frames in {}", video.display());
    if quick {
        std::fs::create_dir_all(&out).unwrap();
        let path = out.join("clip.avi");
        let fps = cap.get(videoio::CAP_PROP_FPS).unwrap();
        write_clip(&path, &clip, if fps > 0.0 { fps } else { 25.0 });
        video = path;
    }
    let mut detector =
        Detector::from_config(&config.config.gate.detector, &config.base_dir()).unwrap();
    let sample = if quick {
        QUICK_DETECT_ALL_FRAMES
    } else {
        DETECT_ALL_FRAMES
    };
    let step = (total / sample).max(1);
    let t0 = Instant::now();
    let mut people = 0;
    let mut timed = 0;
    for f in frames.iter().step_by(step) {
        people += detector.detect(f, w, h, Region::WHOLE).unwrap().len();
        timed += 1;
    }
    let detect_all_fps = timed as f64 / t0.elapsed().as_secs_f64();

    // Hybrid: the whole group on the whole video (the clip with `--quick`).
    let isochron = bin_dir().join("isochron");
    assert!(
        isochron.is_file(),
        "{} is not built: build the binaries of this profile first (`cargo xtask bench gate` \
         builds the release ones; `cargo build --workspace --bins` the dev ones)",
        isochron.display()
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
    // The quick run checks that every stage still works, the gated detector too.
    assert!(
        !quick || detected > 0,
        "quick run: the group's detector ran on no frame; see {}",
        out.join("logs").display()
    );

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
        .filter(|&f| !quick || f < total as u64)
        .collect();
    present.sort_unstable();
    present.dedup();
    let missed = present.iter().filter(|&&f| !covered(f)).count();

    let speedup = hybrid_fps / detect_all_fps;
    println!(
        "gate benchmark on {}vtest.avi ({w}x{h}, {total} frames), detector: {}",
        if quick { "the start of " } else { "" },
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
        "{{\"bench\":\"gate\",\"detect_all_fps\":{detect_all_fps:.2},\"hybrid_fps\":{hybrid_fps:.1},\"speedup\":{speedup:.1},\"detected_fraction\":{detected_fraction:.4}{}}}",
        if quick { ",\"quick\":true" } else { "" }
    );
}
