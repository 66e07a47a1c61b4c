//! Group benchmark (issues 8 and 13, "how many cameras one box carries"): the whole
//! process group — capture, motion, cascade and gate per camera, one cost map
//! bridge — on N cameras at 25 fps in real time, N raised until a stage falls behind.
//!
//! **Workload with churn.** Every camera replays one generated video (made once,
//! under `target/bench-data/`) whose scene alternates between busy and empty:
//! [`BUSY_S`] seconds of `data/vtest.avi` (people walking), then [`QUIET_S`] seconds
//! of a still background (the per-pixel median of vtest's frames, so nobody is in
//! it). Camera *i* of N starts at frame (*i* + ½)·cycle/N (`start_frame`), so events
//! start and end, and detections run, all through the window rather than in
//! lockstep. The video is written with vtest's own codec when OpenCV can encode it,
//! else MJPG (the header line says which).
//!
//! Three sources, each searched on its own:
//! * **decode-only**: capture alone, every camera decoding the churn video, nothing
//!   downstream — the physical floor of a camera box;
//! * **predecoded**: `preload_frames` = one cycle, decoded once per capture process
//!   and published in a loop — what the stages cost without the decoder;
//! * **decode**: the whole group, every camera decoding the video itself.
//!
//! N runs `--start`, doubling up to `--max` until a run fails, then one bisection
//! between the last good and the first bad N (if the start fails, N halves down to
//! 1). Each run starts the group under its own site (service prefix), waits
//! `--warmup` seconds, then measures `--seconds` seconds:
//!
//! * CPU of every process (`/proc/<pid>/stat` utime + stime), summed per stage, in %
//!   of one core;
//! * private memory of every process: Private_Clean + Private_Dirty of its mappings
//!   other than `/dev/shm` (`/proc/<pid>/smaps`) — not VmRSS, which counts the
//!   shared-memory segments again in every process that maps them;
//! * shared memory: the growth of the memory used by the files in `/dev/shm` since
//!   before the group started;
//! * stage health from the `StageStatus` reports of capture, motion, cascade and
//!   gate (every 5 s): rates from the `sent` counters (for the gate, from the
//!   `frames_seen` it reports) of the first report in the window and the last
//!   one, drops, and the gate's detection jobs accepted and dropped (from the
//!   last report before the window, as they are few);
//! * from the streams as they reach the bench: the end-to-end latency capture →
//!   activity; every event record (started, ended) and the **event end lag** —
//!   arrival of an end record minus the time capture published the frame whose
//!   second ended it; every detection and its latency — arrival minus the time
//!   capture published the detected frame (queue, detector, publication).
//!
//! A run **holds** when no process died; every camera's capture, motion and gate
//! took at least 95 % of 25 fps; motion, cascade and gate each dropped at most one
//! sample in [`evaluate::DROP_BUDGET`] (10 000) they handled in the window (drops are
//! counted and reported either way); every
//! camera's activity arrived, its p99 latency stayed under 1 s and did not grow over
//! the window (second half's p99 at most twice the first half's, or under 200 ms);
//! the event end lag p99 stayed under [`MAX_END_LAG_MS`] and the detection latency
//! p99 under [`MAX_DETECTION_MS`]; the detector ran in the window; and, in a window
//! of at least two cycles, every camera ended an event. Detection jobs the gate
//! drops because the site's detector slots are busy (`gate.detector.concurrent`,
//! site-wide) are reported, not held against the run: that is the configured
//! policy, not a stage falling behind. A decode-only run holds when every camera's
//! capture published at least 95 % of 25 fps.
//!
//! Run: `cargo xtask bench group [-- OPTIONS]` (it builds the release binaries first),
//! or after `cargo build --release --workspace --bins`:
//! `cargo bench -p isochron-tests --bench group -- [OPTIONS]`. Options:
//! `--mode decode-only|predecoded|decode|all` (all), `--per-process P` (cameras per
//! service process, 32), `--start N` (8), `--max N` (256), `--warmup S` (20),
//! `--seconds S` (60), `--cpu-share S` (the gates' `gate.detector.cpu_share`, else
//! the default), `--no-detector` (the gates run none: what the detector costs
//! in cameras; a run then need not detect), `--quick` (two cameras per mode, warm-up 3 s, window 10 s, 5 s
//! for decode-only: a check that the bench runs, in any profile, that fails unless
//! an event ended and the detector ran in the window; options after it override it;
//! the JSON line gets `"quick":true`). The last line printed is one JSON object.
//!
//! Modules: the workload (`site`), the running processes (`processes`), one run
//! (`measure`) with what it reads (`status`, `probe`), its result (`outcome`) and
//! criteria (`evaluate`), and the output (`report`); the search over N is here.

use std::path::Path;
use std::time::Duration;

use isochron_runtime::topology::StageKind;
use isochron_tests::{bench_args, bench_count, bench_options, bench_secs, bin};

mod evaluate;
mod measure;
mod outcome;
mod probe;
mod processes;
mod report;
mod site;
mod status;

use measure::run_group;
use outcome::Run;
use processes::{catch_interrupts, interrupted};
use report::{json_line, print_header, print_row, print_summary, quick_problems};
use site::churn_video;

/// Frame rate of every camera.
const FPS: f64 = 25.0;
/// A camera keeps up when it publishes at least this share of [`FPS`].
const MIN_RATE_SHARE: f64 = 0.95;
/// Highest acceptable p99 end-to-end latency, capture → activity.
const MAX_P99_MS: f32 = 1000.0;
/// The p99 latency "grows" when the second half of the window's exceeds the first
/// half's by this factor…
const P99_GROWTH: f32 = 2.0;
/// … and is above this (small latencies are noisy).
const P99_GROWTH_FLOOR_MS: f32 = 200.0;
/// How often the stages publish their status (`Health`'s default).
const STATUS_PERIOD: Duration = Duration::from_secs(5);
/// How often the bench polls status reports and checks for dead processes.
const POLL: Duration = Duration::from_millis(250);
/// How often the bench reads the activity streams (its latency reads at most this
/// much more than the cascade's own).
const PROBE_POLL: Duration = Duration::from_millis(25);
/// How long the group gets to stop after SIGTERM before the rest is killed.
const STOP_TIMEOUT: Duration = Duration::from_secs(30);
/// Seconds of people (vtest's first frames) at the start of each cycle of the
/// churn video.
const BUSY_S: u32 = 6;
/// Seconds of the still, empty background after them: longer than the gate's
/// `hold_s` (3 s) plus the decay of the activity, so that events end.
const QUIET_S: u32 = 10;
/// Frames of one cycle of the churn video (the whole file).
const CYCLE_FRAMES: u32 = (BUSY_S + QUIET_S) * FPS as u32;
/// Frames of vtest whose per-pixel median makes the empty background (spread over
/// the whole file, so everyone who walks through is elsewhere in most of them).
const BACKGROUND_SAMPLES: usize = 53;
/// Highest acceptable p99 event end lag (arrival of the end record minus the
/// publication of the frame that ended it).
const MAX_END_LAG_MS: f32 = 1000.0;
/// Highest acceptable p99 detection latency (arrival minus the publication of the
/// detected frame): the detector queue (`gate.detector.queue` = 2) plus the
/// running job may hold three HOG runs of a few hundred ms each.
const MAX_DETECTION_MS: f32 = 4000.0;

/// The per-camera services, in pipeline order, and the site-wide one: the
/// stage table's pipeline (checked at start), as an array for the tables below.
const STAGES: [StageKind; 5] = [
    StageKind::Capture,
    StageKind::Motion,
    StageKind::Cascade,
    StageKind::Gate,
    StageKind::Costmap,
];
/// Index of the cost map bridge in [`STAGES`].
const COSTMAP: usize = 4;

/// The demo camera's floor points (`config/demo.toml`): every camera gets them, so
/// every camera is on the cost map (all over the same floor).
const FLOOR_POINTS: &str = r#"floor_points = [
  { image_px = [40, 180], floor_m = [-4.01, 9.318] },
  { image_px = [270, 180], floor_m = [-1.405, 2.018] },
  { image_px = [500, 180], floor_m = [1.059, -4.401] },
  { image_px = [730, 180], floor_m = [3.513, -10.351] },
  { image_px = [40, 330], floor_m = [-14.543, -2.353] },
  { image_px = [270, 330], floor_m = [-12.51, -6.441] },
  { image_px = [500, 330], floor_m = [-10.641, -10.269] },
  { image_px = [730, 330], floor_m = [-8.866, -13.971] },
  { image_px = [40, 560], floor_m = [-20.724, -9.153] },
  { image_px = [270, 560], floor_m = [-19.277, -11.588] },
  { image_px = [500, 560], floor_m = [-17.953, -13.958] },
  { image_px = [730, 560], floor_m = [-16.72, -16.312] },
]"#;

/// What runs, and the source of the cameras.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Mode {
    /// Capture alone, every camera decoding the file.
    DecodeOnly,
    /// The group; frames decoded once, published from memory.
    Predecoded,
    /// The group; every camera decodes the file.
    Decode,
}

impl Mode {
    const ALL: [Mode; 3] = [Mode::DecodeOnly, Mode::Predecoded, Mode::Decode];

    fn name(self) -> &'static str {
        match self {
            Mode::DecodeOnly => "decode-only",
            Mode::Predecoded => "predecoded",
            Mode::Decode => "decode",
        }
    }

    /// Indices in [`STAGES`] of the processes it runs.
    fn stages(self) -> &'static [usize] {
        match self {
            Mode::DecodeOnly => &[0],
            _ => &[0, 1, 2, 3, 4],
        }
    }

    /// The stages whose status reports decide whether a run holds.
    fn health_stages(self) -> &'static [StageKind] {
        match self {
            Mode::DecodeOnly => &[StageKind::Capture],
            _ => &[
                StageKind::Capture,
                StageKind::Motion,
                StageKind::Cascade,
                StageKind::Gate,
            ],
        }
    }
}

/// Command-line options.
#[derive(Debug, Clone)]
struct Options {
    modes: Vec<Mode>,
    per_process: usize,
    start: usize,
    max: usize,
    warmup: Duration,
    seconds: Duration,
    /// The window of decode-only runs (only capture's rate is measured).
    decode_only_seconds: Duration,
    /// `--quick`: a short run that only checks the bench works.
    quick: bool,
    /// `--cpu-share`: the site's `gate.detector.cpu_share` (else the default).
    cpu_share: Option<f64>,
    /// `--no-detector`: `gate.detector.enabled = false`, to see what the
    /// detector costs in cameras.
    no_detector: bool,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            modes: Mode::ALL.to_vec(),
            per_process: 32,
            start: 8,
            max: 256,
            // Start-up: processes, iceoryx2 services, preloads, the first second of
            // activity.
            warmup: Duration::from_secs(20),
            // Several churn cycles: every camera starts and ends events in it.
            seconds: Duration::from_secs(60),
            decode_only_seconds: Duration::from_secs(60),
            quick: false,
            cpu_share: None,
            no_detector: false,
        }
    }
}

impl Options {
    /// `--quick`: every mode, two cameras (in one process per stage) each, short
    /// warm-up and window. The two cameras are half a cycle apart: one starts 4 s
    /// into its busy part and ends an event about 6 s after capture starts; the
    /// other starts 4 s before its busy part and starts an event (and runs the
    /// detector) about 5 s after — both inside the window (3–13 s), with seconds to
    /// spare for a slow start.
    fn quick(self) -> Options {
        Options {
            start: 2,
            max: 2,
            warmup: Duration::from_secs(3),
            seconds: Duration::from_secs(10),
            decode_only_seconds: Duration::from_secs(5),
            quick: true,
            ..self
        }
    }

    /// The measurement window of `mode`.
    fn window(&self, mode: Mode) -> Duration {
        match mode {
            Mode::DecodeOnly => self.decode_only_seconds,
            _ => self.seconds,
        }
    }
}

const USAGE: &str = "usage: group [--quick] [--mode decode-only|predecoded|decode|all] [--per-process P] \
[--start N] [--max N] [--warmup SECONDS] [--seconds SECONDS] [--cpu-share S] [--no-detector]";

/// Parses the options; unknown flags (cargo passes `--bench`) are ignored.
fn parse_args(args: impl IntoIterator<Item = String>) -> Result<Options, String> {
    let mut o = Options::default();
    let valued = [
        "--mode",
        "--per-process",
        "--start",
        "--max",
        "--warmup",
        "--seconds",
        "--cpu-share",
    ];
    for (flag, value) in bench_args(
        "group",
        USAGE,
        (&["--quick", "--no-detector"], &valued),
        args,
    )? {
        let value = value.unwrap_or_default();
        match flag.as_str() {
            "--quick" => o = o.quick(),
            "--no-detector" => o.no_detector = true,
            "--mode" => {
                o.modes = match value.as_str() {
                    "all" => Mode::ALL.to_vec(),
                    name => match Mode::ALL.into_iter().find(|m| m.name() == name) {
                        Some(m) => vec![m],
                        None => {
                            return Err(format!(
                                "--mode: expected decode-only, predecoded, decode or all, found '{value}'"
                            ));
                        }
                    },
                }
            }
            "--per-process" => o.per_process = bench_count(&flag, &value)?,
            "--start" => o.start = bench_count(&flag, &value)?,
            "--max" => o.max = bench_count(&flag, &value)?,
            "--warmup" => o.warmup = bench_secs(&flag, &value, 0.0)?,
            "--cpu-share" => {
                let share = value
                    .parse::<f64>()
                    .ok()
                    .filter(|s| (0.01..=1.0).contains(s));
                o.cpu_share = Some(share.ok_or_else(|| {
                    format!("--cpu-share: expected a number from 0.01 to 1, found '{value}'")
                })?);
            }
            _ => {
                o.seconds = bench_secs(&flag, &value, 0.0)?.max(Duration::from_secs(1));
                o.decode_only_seconds = o.seconds;
            }
        }
    }
    o.max = o.max.max(o.start);
    Ok(o)
}

/// Raises N for `mode` until a run fails, bisects once, and returns every run.
fn search(opts: &Options, mode: Mode, video: &Path) -> Vec<Run> {
    let mut runs = Vec::new();
    let mut once = |n: usize| {
        if interrupted() {
            return false;
        }
        let run = run_group(opts, mode, n, video);
        print_row(&run);
        let held = run.held();
        runs.push(run);
        held
    };
    let (mut good, mut bad) = (None::<usize>, None::<usize>);
    let mut n = opts.start;
    loop {
        if once(n) {
            good = Some(n);
            if n >= opts.max {
                break;
            }
            n = (n * 2).min(opts.max);
        } else {
            bad = Some(n);
            break;
        }
    }
    // Nothing held at the start: halve down to 1.
    while good.is_none() && n > 1 {
        n /= 2;
        if once(n) {
            good = Some(n);
        } else {
            bad = Some(n);
        }
    }
    if let (Some(g), Some(b)) = (good, bad)
        && b - g > 1
    {
        let mid = g + (b - g) / 2;
        once(mid);
    }
    runs
}

/// The held run of `mode` with the most cameras.
fn best(runs: &[Run], mode: Mode) -> Option<&Run> {
    runs.iter()
        .filter(|r| r.mode == mode && r.held())
        .max_by_key(|r| r.cameras)
}

/// Cameras the best run of `mode` held (0 if none), if `mode` ran.
fn capacity(opts: &Options, runs: &[Run], mode: Mode) -> Option<usize> {
    opts.modes
        .contains(&mode)
        .then(|| best(runs, mode).map_or(0, |r| r.cameras))
}

/// The run whose gate figures the summary and the JSON line give: the largest held
/// predecoded run, else the largest held decode run, else the last group run.
fn reported(runs: &[Run]) -> Option<&Run> {
    best(runs, Mode::Predecoded)
        .or_else(|| best(runs, Mode::Decode))
        .or_else(|| runs.iter().rev().find(|r| r.mode != Mode::DecodeOnly))
}

/// Why `mode` held no more cameras: the failures of its smallest failed run above
/// the best held one.
fn shortfall_cause(runs: &[Run], mode: Mode) -> Option<String> {
    let held = best(runs, mode).map_or(0, |r| r.cameras);
    let failed = runs
        .iter()
        .filter(|r| r.mode == mode && !r.held() && r.cameras > held)
        .min_by_key(|r| r.cameras)?;
    Some(format!(
        "at N={}: {}",
        failed.cameras,
        failed.failures.join("; ")
    ))
}

fn main() {
    let opts = bench_options(parse_args);
    assert_eq!(
        STAGES.to_vec(),
        StageKind::pipeline().collect::<Vec<_>>(),
        "STAGES is the stage table's pipeline"
    );
    // Fail early, with what to do, when something is missing.
    for stage in STAGES {
        bin(&format!("isochron-{stage}"));
    }
    let (video, codec) = match churn_video() {
        Ok(v) => v,
        Err(e) => {
            eprintln!("group: {e}");
            std::process::exit(1);
        }
    };
    // Hundreds of iceoryx2 services in the bench and in the processes it starts
    // (children inherit the limit).
    isochron_runtime::service::raise_open_file_limit();
    catch_interrupts();

    print_header(&opts, &codec);
    let mut runs = Vec::new();
    for &mode in &opts.modes {
        runs.extend(search(&opts, mode, &video));
    }
    if interrupted() {
        println!("\ninterrupted: the results are incomplete");
    }
    print_summary(&opts, &runs);
    println!("{}", json_line(&opts, &runs, &codec));
    if opts.quick {
        let problems = quick_problems(&runs, !opts.no_detector);
        if !problems.is_empty() {
            eprintln!("group (quick): {}", problems.join("; "));
            std::process::exit(1);
        }
    }
}
