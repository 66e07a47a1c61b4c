//! Gate benchmark: the paper's hybrid scheme on vtest.avi, in one run.
//!
//! * **detect all**: the detector (as configured in `config/demo.toml`: the
//!   network `cargo xtask setup` installed, HOG without one, as the gate picks) on
//!   every frame, one thread — what a detector-only pipeline costs;
//! * **hybrid**: the whole process group (`isochron replay`, release build) with the
//!   detector gated by events — frames/s of the group and frames detected.
//!
//! Beside the frames/s ratio, the power proxy: CPU seconds per frame of the
//! detector on every frame (this process's CPU time over the timed frames) against
//! those of the whole hybrid group (the CPU time of every process of the replay,
//! `getrusage(RUSAGE_CHILDREN)` once it has ended, over the frames it read).
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

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use isochron_config::Config;
use isochron_gate::detector::{Detector, INSTALLED_NETWORKS, Region};
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

/// What went wrong, for the bench's exit message.
type Error = Box<dyn std::error::Error>;

/// Writes `frames` (BGR) to an MJPG clip at `path`.
fn write_clip(path: &Path, frames: &[Mat], fps: f64) -> Result<(), Error> {
    let size = Size::new(frames[0].cols(), frames[0].rows());
    let mut writer = mjpg_writer(path, fps, size);
    for f in frames {
        writer.write(f)?;
    }
    writer.release()?;
    Ok(())
}

/// The frames of the video the bench reads, grey, and their size.
struct Frames {
    /// Grey frames, `w × h` bytes each.
    grey: Vec<Vec<u8>>,
    /// Frame width, pixels.
    w: u32,
    /// Frame height, pixels.
    h: u32,
}

/// Decodes `video` (its first [`QUICK_CLIP_FRAMES`] frames if `quick`, which it then
/// also writes, BGR, to `out/clip.avi`: the returned path is the video the group
/// replays).
fn read_frames(video: &Path, out: &Path, quick: bool) -> Result<(Frames, PathBuf), Error> {
    let name = video.to_str().ok_or("a UTF-8 video path")?;
    let mut cap = videoio::VideoCapture::from_file(name, videoio::CAP_ANY)?;
    let (mut bgr, mut gray) = (Mat::default(), Mat::default());
    let mut grey = Vec::new();
    let mut clip = Vec::new();
    // The size is taken while reading: after the last read the Mat is empty (0x0).
    let (mut w, mut h) = (0, 0);
    while (!quick || grey.len() < QUICK_CLIP_FRAMES) && cap.read(&mut bgr)? && !bgr.empty() {
        imgproc::cvt_color(&bgr, &mut gray, imgproc::COLOR_BGR2GRAY, 0)?;
        (w, h) = (gray.cols() as u32, gray.rows() as u32);
        grey.push(gray.data_bytes()?.to_vec());
        if quick {
            clip.push(bgr.try_clone()?);
        }
    }
    assert!(!grey.is_empty(), "no frames in {}", video.display());
    if !quick {
        return Ok((Frames { grey, w, h }, video.to_path_buf()));
    }
    std::fs::create_dir_all(out)?;
    let path = out.join("clip.avi");
    let fps = cap.get(videoio::CAP_PROP_FPS)?;
    write_clip(&path, &clip, if fps > 0.0 { fps } else { 25.0 })?;
    Ok((Frames { grey, w, h }, path))
}

/// CPU seconds (user + system) of this process (`RUSAGE_SELF`) or of its
/// children that ended and were waited for (`RUSAGE_CHILDREN`).
fn cpu_seconds(who: libc::c_int) -> f64 {
    // SAFETY: `getrusage` writes one `rusage` into the zeroed value it is given.
    let usage = unsafe {
        let mut usage: libc::rusage = std::mem::zeroed();
        libc::getrusage(who, &mut usage);
        usage
    };
    let s = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    s(usage.ru_utime) + s(usage.ru_stime)
}

/// The detector on an even sample of `sample` frames: frames/s, frames timed,
/// people found, and CPU seconds per frame.
fn detect_all(
    detector: &mut Detector,
    frames: &Frames,
    sample: usize,
) -> Result<(f64, usize, usize, f64), Error> {
    let step = (frames.grey.len() / sample).max(1);
    let cpu0 = cpu_seconds(libc::RUSAGE_SELF);
    let t0 = Instant::now();
    let mut people = 0;
    let mut timed = 0;
    for f in frames.grey.iter().step_by(step) {
        people += detector.detect(f, frames.w, frames.h, Region::WHOLE)?.len();
        timed += 1;
    }
    let cpu = (cpu_seconds(libc::RUSAGE_SELF) - cpu0) / timed.max(1) as f64;
    Ok((
        timed as f64 / t0.elapsed().as_secs_f64(),
        timed,
        people,
        cpu,
    ))
}

/// What the group's `summary.json` says of a replay.
struct Hybrid {
    /// Frames the group read.
    frames: u64,
    /// The group's frames per second.
    fps: f64,
    /// Frames the gated detector ran on.
    detected: u64,
    /// CPU seconds of every process of the group.
    cpu_s: f64,
}

/// Runs the whole group (`isochron replay`) on `video` into `out`.
fn run_hybrid(video: &Path, out: &Path, config_path: &Path) -> Result<Hybrid, Error> {
    let isochron = bin_dir().join("isochron");
    assert!(
        isochron.is_file(),
        "{} is not built: build the binaries of this profile first (`cargo xtask bench gate` \
         builds the release ones; `cargo build --workspace --bins` the dev ones)",
        isochron.display()
    );
    let cpu0 = cpu_seconds(libc::RUSAGE_CHILDREN);
    let status = Command::new(&isochron)
        .arg("replay")
        .arg(video)
        .arg("--out")
        .arg(out)
        .arg("--config")
        .arg(config_path)
        .status()
        .expect("isochron replay");
    assert!(
        status.success(),
        "replay failed; see {}",
        out.join("logs").display()
    );
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json"))?)?;
    Ok(Hybrid {
        frames: summary["counts"]["frames"]
            .as_u64()
            .ok_or("summary: counts.frames")?,
        fps: summary["frames_per_s"]
            .as_f64()
            .ok_or("summary: frames_per_s")?,
        detected: summary["gate"]["frames_detected"].as_u64().unwrap_or(0),
        cpu_s: cpu_seconds(libc::RUSAGE_CHILDREN) - cpu0,
    })
}

/// The events of `out/events.jsonl` (none if it is missing).
fn read_events(out: &Path) -> Result<Vec<serde_json::Value>, Error> {
    let text = std::fs::read_to_string(out.join("events.jsonl")).unwrap_or_default();
    Ok(text
        .lines()
        .map(serde_json::from_str)
        .collect::<Result<_, _>>()?)
}

/// The person-present frames of PETS09's ground truth (0-based, below `total` if
/// `quick`) and how many of them lie outside every event (each event extended by 10
/// frames): missed people.
fn missed_frames(
    root: &Path,
    events: &[serde_json::Value],
    total: usize,
    quick: bool,
) -> Result<(usize, usize), Error> {
    let mut spans = Vec::with_capacity(events.len());
    for e in events {
        let start = e["start_frame"]
            .as_u64()
            .ok_or("an event without start_frame")?;
        let end = e["end_frame"]
            .as_u64()
            .ok_or("an event without end_frame")?;
        spans.push((start, end + 10));
    }
    let covered = |frame: u64| spans.iter().any(|&(s, e)| s <= frame && frame <= e);
    let gt =
        std::fs::read_to_string(root.join("tests/data/pets09-s2l1-gt.txt")).unwrap_or_default();
    let mut present = Vec::new();
    for l in gt.lines() {
        let f: Vec<&str> = l.split(',').collect();
        if f.get(6) == Some(&"1") {
            let frame = f[0].parse::<u64>()? - 1;
            if !quick || frame < total as u64 {
                present.push(frame);
            }
        }
    }
    present.sort_unstable();
    present.dedup();
    let missed = present.iter().filter(|&&f| !covered(f)).count();
    Ok((present.len(), missed))
}

fn main() -> Result<(), Error> {
    let quick = std::env::args().any(|a| a == "--quick");
    let root = repo_root();
    let config_path = root.join("config/demo.toml");
    let config = Config::load(&config_path).expect("config/demo.toml");
    let out = root.join(if quick {
        "target/bench-gate-quick"
    } else {
        "target/bench-gate"
    });
    let _ = std::fs::remove_dir_all(&out);

    // Detect all: decode every frame, time the detector on an even sample of them.
    let (frames, video) = read_frames(&root.join("data/vtest.avi"), &out, quick)?;
    let (w, h, total) = (frames.w, frames.h, frames.grey.len());
    // The network the group's gate finds beside its binaries (this bench's own
    // binary lies deeper, in `deps/`).
    let mut detector_config = config.config.gate.detector.clone();
    let installed = bin_dir().parent().and_then(|target| {
        INSTALLED_NETWORKS
            .iter()
            .map(|n| target.join("detector").join(n))
            .find(|p| p.is_file())
    });
    if detector_config.model.is_none()
        && detector_config.installed
        && let Some(network) = installed.filter(|p| p.is_file())
    {
        detector_config.model = Some(network);
    }
    let mut detector = Detector::from_config(&detector_config, &config.base_dir())?;
    let sample = if quick {
        QUICK_DETECT_ALL_FRAMES
    } else {
        DETECT_ALL_FRAMES
    };
    let (detect_all_fps, timed, people, detect_cpu_per_frame) =
        detect_all(&mut detector, &frames, sample)?;

    // Hybrid: the whole group on the whole video (the clip with `--quick`).
    let hybrid = run_hybrid(&video, &out, &config_path)?;
    let (hybrid_fps, detected) = (hybrid.fps, hybrid.detected);
    let detected_fraction = detected as f64 / hybrid.frames.max(1) as f64;
    // The quick run checks that every stage still works, the gated detector too.
    assert!(
        !quick || detected > 0,
        "quick run: the group's detector ran on no frame; see {}",
        out.join("logs").display()
    );

    // Person-present frames outside every event would be missed people.
    let events = read_events(&out)?;
    let (present, missed) = missed_frames(&root, &events, total, quick)?;

    let speedup = hybrid_fps / detect_all_fps;
    let hybrid_cpu_per_frame = hybrid.cpu_s / hybrid.frames.max(1) as f64;
    let cpu_ratio = detect_cpu_per_frame / hybrid_cpu_per_frame.max(1e-9);
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
        "CPU per frame: detector on every frame {:.1} ms, hybrid group {:.2} ms (all processes): {cpu_ratio:.1}× less CPU (the paper's power proxy: 6.5× less power)",
        detect_cpu_per_frame * 1e3,
        hybrid_cpu_per_frame * 1e3
    );
    println!(
        "person-present frames outside any event: {missed} of {present} (missed intervals: {})",
        if missed == 0 { "none" } else { "SOME" }
    );
    println!(
        "{{\"bench\":\"gate\",\"detect_all_fps\":{detect_all_fps:.2},\"hybrid_fps\":{hybrid_fps:.1},\"speedup\":{speedup:.1},\"cpu_ratio\":{cpu_ratio:.1},\"detected_fraction\":{detected_fraction:.4}{}}}",
        if quick { ",\"quick\":true" } else { "" }
    );
    Ok(())
}
