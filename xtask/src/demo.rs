//! `cargo xtask demo`: the whole group on the sample video, and what it produced.

use std::path::Path;
use std::process::Command;

use anyhow::Context;

use crate::{cargo, run};

/// Release build, `isochron replay` of `data/vtest.avi` with `config/demo.toml`
/// into `out/demo`, and the report.
pub(crate) fn demo(root: &Path) -> anyhow::Result<()> {
    run(cargo().args(["build", "--release", "--workspace", "--bins"]))?;
    let out = root.join("out/demo");
    let _ = std::fs::remove_dir_all(&out);
    run(Command::new(root.join("target/release/isochron")).args([
        "replay",
        "data/vtest.avi",
        "--out",
        "out/demo",
        "--config",
        "config/demo.toml",
    ]))?;
    report(&out)
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
