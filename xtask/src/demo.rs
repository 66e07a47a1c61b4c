//! `cargo xtask demo`: the whole group on the sample video, what it produced, and
//! pictures of it.

use std::path::Path;
use std::process::Command;

use anyhow::Context;

use crate::{cargo, run};

/// The binaries `isochron replay` starts for `config/demo.toml` (the stages
/// `StageKind::replayed` gives: no exporter, MQTT sink or link is configured),
/// and `isochron` itself. Built in the dev profile, as `cargo xtask test` builds
/// them, so that a later `test` compiles no dependency again.
const DEMO_PACKAGES: [&str; 6] = [
    "isochron-cli",
    "isochron-capture",
    "isochron-motion",
    "isochron-cascade",
    "isochron-gate",
    "isochron-costmap",
];

/// The demo's camera and the time of day and weekday its recording starts
/// (`config/demo.toml`: 2009-03-02 11:00 UTC, a Monday, in Europe/London).
const CAMERA: &str = "cam01";
const AT: &str = "11:00";
const DAY: &str = "mon";

/// A build of the binaries the replay runs, `isochron replay` of
/// `data/vtest.avi` with `config/demo.toml` into `out/demo`, the report, and the
/// pictures.
pub(crate) fn demo(root: &Path) -> anyhow::Result<()> {
    let mut build = cargo();
    build.args(["build", "--bins"]);
    for package in DEMO_PACKAGES {
        build.args(["-p", package]);
    }
    run(&mut build)?;
    let out = root.join("out/demo");
    let _ = std::fs::remove_dir_all(&out);
    let isochron = root.join("target/debug/isochron");
    run(Command::new(&isochron).args([
        "replay",
        "data/vtest.avi",
        "--out",
        "out/demo",
        "--config",
        "config/demo.toml",
    ]))?;
    report(&out)?;
    pictures(&isochron, &out)
}

/// Draws what the demo saw and learned, and names the files: the calibration
/// overlay on the video's first frame, the cost map the long-term model expects
/// at the recording's time, and the camera's activity over the day.
fn pictures(isochron: &Path, out: &Path) -> anyhow::Result<()> {
    let config = out.join("config.toml");
    let store = out.join("state");
    let (overlay, costmap, heatmap) = (
        out.join("calibration.png"),
        out.join("costmap.png"),
        out.join("activity.png"),
    );
    let quiet = |cmd: &mut Command| -> anyhow::Result<()> {
        let shown = format!("{cmd:?}");
        let done = cmd.output().with_context(|| format!("starting {shown}"))?;
        if !done.status.success() {
            anyhow::bail!(
                "{shown} failed ({}): {}",
                done.status,
                String::from_utf8_lossy(&done.stderr).trim()
            );
        }
        Ok(())
    };
    quiet(
        Command::new(isochron)
            .args(["costmap", "check", "--camera", CAMERA])
            .arg("--config")
            .arg(&config)
            .arg("--overlay")
            .arg(&overlay)
            .args(["--frame", "data/vtest.avi"]),
    )?;
    quiet(
        Command::new(isochron)
            .args(["costmap", "snapshot", "--at", AT, "--day", DAY])
            .arg("--config")
            .arg(&config)
            .arg("--out")
            .arg(&costmap),
    )?;
    quiet(
        Command::new(isochron)
            .args(["plot", "heatmap", "--camera", CAMERA])
            .arg("--store")
            .arg(&store)
            .arg("--out")
            .arg(&heatmap),
    )?;
    println!("pictures:");
    println!(
        "  {}  the camera's floor mapping and block grid on its first frame",
        overlay.display()
    );
    println!(
        "  {}  the cost map the learned model expects on a {DAY} at {AT}",
        costmap.display()
    );
    println!(
        "  {}  where (blocks) and when (minute of the day) the view was active",
        heatmap.display()
    );
    Ok(())
}

/// Prints what the replay produced; the last line is the demo's summary line.
fn report(out: &Path) -> anyhow::Result<()> {
    let summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.join("summary.json")).context("reading summary.json")?,
    )?;
    let count = |k: &str| summary["counts"][k].as_u64().unwrap_or(0);
    println!();
    println!(
        "replayed {} frames in {:.1} s ({:.0} frames/s)",
        count("frames"),
        summary["wall_time_s"].as_f64().unwrap_or(0.0),
        summary["frames_per_s"].as_f64().unwrap_or(0.0)
    );
    let events = std::fs::read_to_string(out.join("events.jsonl")).unwrap_or_default();
    for line in events.lines().take(10) {
        let e: serde_json::Value = serde_json::from_str(line)?;
        println!(
            "event {} {} {} {} → {} (frames {}..{}) peak {:.3}",
            e["event_id"],
            e["zone"],
            e["kind"],
            e["start"],
            e["end"],
            e["start_frame"],
            e["end_frame"],
            e["peak"].as_f64().unwrap_or(0.0)
        );
    }
    let gate = &summary["gate"];
    if let (Some(seen), Some(detected)) = (
        gate["frames_seen"].as_u64(),
        gate["frames_detected"].as_u64(),
    ) && seen > 0
    {
        println!(
            "gate: detector ran on {detected} of {seen} frames ({:.1} %), {:.0} ms of detector time",
            100.0 * detected as f64 / seen as f64,
            gate["detector_total_ms"].as_f64().unwrap_or(0.0)
        );
    }
    println!("outputs in {}", out.display());
    println!(
        "demo: frames={} motion={} activity={} events={} detections={}",
        count("frames"),
        count("motion"),
        count("activity"),
        count("events"),
        count("detections")
    );
    Ok(())
}
