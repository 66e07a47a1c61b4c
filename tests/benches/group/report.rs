//! The table, the summary and the closing JSON line.

use std::fmt::Write as _;

use crate::outcome::{Run, load_average};
use crate::{
    BUSY_S, FPS, Mode, Options, QUIET_S, STAGES, best, capacity, reported, shortfall_cause,
};

/// Formats an optional number with `decimals`, `-` when missing.
pub(crate) fn opt(v: Option<f64>, decimals: usize) -> String {
    v.map_or_else(|| "-".into(), |v| format!("{v:.decimals$}"))
}

/// The table's columns: title and width (the first is left-aligned).
pub(crate) const COLUMNS: [(&str, usize); 22] = [
    ("mode", 11),
    ("N", 4),
    ("procs", 5),
    ("capture%", 8),
    ("motion%", 7),
    ("cascade%", 8),
    ("gate%", 6),
    ("costmap%", 8),
    ("total%", 7),
    ("%/cam", 6),
    ("min fps", 7),
    ("gate fps", 8),
    ("drops", 5),
    ("p99 ms", 6),
    ("ends", 4),
    ("end p99", 7),
    ("dets", 4),
    ("det p99", 7),
    ("jobs", 4),
    ("jdrop", 5),
    ("priv MB/c", 9),
    ("held", 0),
];

/// One table line of `cells` laid out in [`COLUMNS`].
pub(crate) fn table_line(cells: &[String]) -> String {
    let mut line = String::new();
    for (i, (cell, (_, width))) in cells.iter().zip(COLUMNS).enumerate() {
        let _ = match i {
            0 => write!(line, "{cell:<width$}"),
            _ if i == COLUMNS.len() - 1 => write!(line, "  {cell}"),
            _ => write!(line, " {cell:>width$}"),
        };
    }
    line
}

pub(crate) fn print_header(opts: &Options, codec: &str) {
    println!(
        "group benchmark: {FPS} fps per camera in real time, churn video ({codec}: {BUSY_S} s of \
         vtest.avi, then {QUIET_S} s of its empty background; camera i of N starts (i + 1/2)/N of a \
         cycle in), {} camera(s) per service process, warm-up {:.0} s, window {:.0} s \
         (decode-only {:.0} s); load average (1 min) {}",
        opts.per_process,
        opts.warmup.as_secs_f64(),
        opts.seconds.as_secs_f64(),
        opts.decode_only_seconds.as_secs_f64(),
        opt(load_average(), 2),
    );
    println!(
        "CPU in % of one core. min fps: slowest camera's motion output (decode-only: \
         capture's); gate fps: slowest camera's frames taken by the gate. drops: samples \
         motion, cascade and gate lost. p99 ms: capture → activity. ends / dets: events \
         ended and detections in the window; end p99: event end lag, det p99: capture → \
         detection, ms; jobs / jdrop: detection jobs the gates accepted / dropped. priv \
         MB/c: Private_Clean+Private_Dirty of all the group's processes / N, excluding \
         shared memory."
    );
    let titles: Vec<String> = COLUMNS.iter().map(|(t, _)| t.to_string()).collect();
    println!("{}", table_line(&titles));
}

pub(crate) fn print_row(r: &Run) {
    let total = r.cpu.map(|c| c.iter().sum::<f64>());
    let held = if r.held() {
        "yes".to_string()
    } else {
        format!("no: {}", r.failures.join("; "))
    };
    let count = |v: Option<u64>| v.map_or_else(|| "-".into(), |d| d.to_string());
    let group = (r.mode != Mode::DecodeOnly).then_some(());
    let mut cells = vec![
        r.mode.name().to_string(),
        r.cameras.to_string(),
        r.processes.to_string(),
    ];
    match r.cpu {
        Some(cpu) => cells.extend(cpu.iter().map(|c| format!("{c:.1}"))),
        None => cells.extend(STAGES.map(|_| "-".to_string())),
    }
    cells.extend([
        opt(total, 1),
        opt(total.map(|t| t / r.cameras as f64), 1),
        opt(r.min_fps, 1),
        opt(r.gate_min_fps, 1),
        count(r.drops),
        opt(r.p99_ms.map(f64::from), 0),
        count(group.map(|_| r.events_ended)),
        opt(r.end_lag_p99_ms.map(f64::from), 0),
        count(group.map(|_| r.detections)),
        opt(r.detection_p99_ms.map(f64::from), 0),
        count(r.jobs_accepted),
        count(r.jobs_dropped),
        opt(r.private_mb_per_camera, 1),
        held,
    ]);
    println!("{}", table_line(&cells));
}

/// The best run of every mode, the capacity goals, and the cause of a shortfall.
pub(crate) fn print_summary(opts: &Options, runs: &[Run]) {
    println!();
    for &mode in &opts.modes {
        let Some(r) = best(runs, mode) else {
            println!("{}: no camera count held", mode.name());
            continue;
        };
        let cpu: f64 = r.cpu.iter().flatten().sum();
        println!(
            "{}: {} cameras held ({} processes, {cpu:.0} % of one core, {:.1} % per camera; \
             per camera {} MB private, {} MB shared memory in use of {} MB mapped; load \
             average {} at the start)",
            mode.name(),
            r.cameras,
            r.processes,
            cpu / r.cameras as f64,
            opt(r.private_mb_per_camera, 1),
            opt(r.shm_mb_per_camera, 1),
            opt(r.shm_mapped_mb_per_camera, 1),
            opt(r.load_before, 2),
        );
        if let Some(per_stage) = r.private_mb_per_stage
            && mode != Mode::DecodeOnly
        {
            let parts: Vec<String> = STAGES
                .iter()
                .zip(per_stage)
                .map(|(stage, mb)| format!("{stage} {mb:.1}"))
                .collect();
            println!("  private MB per camera by stage: {}", parts.join(", "));
        }
    }
    if let Some(r) = reported(runs) {
        println!(
            "gate ({} N={}): {} events started and {} ended, {} detections in the window; \
             event end lag p99 {} ms, detection latency p99 {} ms; detection jobs accepted \
             {}, dropped {} (site-wide detector slots busy or queue full)",
            r.mode.name(),
            r.cameras,
            r.events_started,
            r.events_ended,
            r.detections,
            opt(r.end_lag_p99_ms.map(f64::from), 0),
            opt(r.detection_p99_ms.map(f64::from), 0),
            r.jobs_accepted.map_or("-".into(), |j| j.to_string()),
            r.jobs_dropped.map_or("-".into(), |j| j.to_string()),
        );
    }
    let only = capacity(opts, runs, Mode::DecodeOnly);
    if let (Some(only), Some(decode)) = (only, capacity(opts, runs, Mode::Decode)) {
        let fraction = (only > 0).then(|| decode as f64 / only as f64);
        let met = fraction.is_some_and(|f| f >= 0.85);
        println!(
            "decode: {decode} cameras = {} of decode-only's {only} (goal ≥ 0.85: {})",
            opt(fraction, 2),
            if met { "met" } else { "not met" }
        );
        if !met && let Some(cause) = shortfall_cause(runs, Mode::Decode) {
            println!("  cause: {cause}");
        }
    }
    if let Some(pre) = capacity(opts, runs, Mode::Predecoded) {
        let met = pre >= 128;
        println!(
            "predecoded: {pre} cameras (goal ≥ 128: {})",
            if met { "met" } else { "not met" }
        );
        if !met && let Some(cause) = shortfall_cause(runs, Mode::Predecoded) {
            println!("  cause: {cause}");
        }
    }
}

/// The closing JSON line (keys in a fixed order; `null` for what was not measured).
pub(crate) fn json_line(opts: &Options, runs: &[Run], codec: &str) -> String {
    let count = |v: Option<usize>| v.map_or_else(|| "null".to_string(), |v| v.to_string());
    let count64 = |v: Option<u64>| v.map_or_else(|| "null".to_string(), |v| v.to_string());
    let number = |v: Option<f64>| v.map_or_else(|| "null".to_string(), |v| format!("{v:.1}"));
    let only = capacity(opts, runs, Mode::DecodeOnly);
    let decode = capacity(opts, runs, Mode::Decode);
    let fraction = only
        .zip(decode)
        .filter(|(o, _)| *o > 0)
        .map(|(o, d)| d as f64 / o as f64);
    let pre = best(runs, Mode::Predecoded);
    let gate = reported(runs);
    let load_max = runs
        .iter()
        .filter_map(|r| r.load_before)
        .fold(None, |m: Option<f64>, l| Some(m.map_or(l, |m| m.max(l))));
    format!(
        "{{\"bench\":\"group\",\"cameras_predecoded\":{},\"cameras_decode\":{},\
         \"decode_only_cameras\":{},\"decode_fraction\":{},\"gate_run\":{},\
         \"events_started_in_window\":{},\"events_ended_in_window\":{},\
         \"detections_in_window\":{},\"detection_jobs_accepted\":{},\
         \"detection_jobs_dropped\":{},\"event_end_lag_p99_ms\":{},\
         \"detection_latency_p99_ms\":{},\"rss_mb_per_camera\":{},\"shm_mb_per_camera\":{},\
         \"p99_latency_ms\":{},\"window_s\":{},\"codec\":{},\"load_1m_max\":{},\
         \"detector_cpu_share\":{}{}{}}}",
        count(capacity(opts, runs, Mode::Predecoded)),
        count(decode),
        count(only),
        fraction.map_or("null".into(), |f| format!("{f:.2}")),
        gate.map_or("null".into(), |r| format!(
            "\"{} N={}\"",
            r.mode.name(),
            r.cameras
        )),
        count64(gate.map(|r| r.events_started)),
        count64(gate.map(|r| r.events_ended)),
        count64(gate.map(|r| r.detections)),
        count64(gate.and_then(|r| r.jobs_accepted)),
        count64(gate.and_then(|r| r.jobs_dropped)),
        number(gate.and_then(|r| r.end_lag_p99_ms).map(f64::from)),
        number(gate.and_then(|r| r.detection_p99_ms).map(f64::from)),
        number(pre.and_then(|r| r.private_mb_per_camera)),
        number(pre.and_then(|r| r.shm_mb_per_camera)),
        number(pre.and_then(|r| r.p99_ms).map(f64::from)),
        opts.seconds.as_secs_f64(),
        serde_json::to_string(codec).unwrap_or_default(),
        number(load_max),
        opts.cpu_share
            .unwrap_or(isochron_config::DetectorConfig::default().cpu_share),
        if opts.no_detector {
            ",\"detector\":false"
        } else {
            ""
        },
        if opts.quick { ",\"quick\":true" } else { "" },
    )
}

/// A quick run checks the workload, not capacity: every group run ended an event
/// and (when `detecting`) ran the detector in its window. The reasons it did not.
pub(crate) fn quick_problems(runs: &[Run], detecting: bool) -> Vec<String> {
    runs.iter()
        .filter(|r| r.mode != Mode::DecodeOnly)
        .filter_map(|r| {
            let mut missing = Vec::new();
            if r.events_ended == 0 {
                missing.push("no event ended");
            }
            if detecting && r.detections == 0 {
                missing.push("the detector never ran");
            }
            (!missing.is_empty()).then(|| {
                format!(
                    "{} N={}: {} in the window ({})",
                    r.mode.name(),
                    r.cameras,
                    missing.join(" and "),
                    if r.held() {
                        "the run held".to_string()
                    } else {
                        r.failures.join("; ")
                    }
                )
            })
        })
        .collect()
}
