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
//! took at least 95 % of 25 fps; motion, cascade and gate dropped nothing; every
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
//! `--seconds S` (60), `--quick` (two cameras per mode, warm-up 3 s, window 10 s, 5 s
//! for decode-only: a check that the bench runs, in any profile, that fails unless
//! an event ended and the detector ran in the window; options after it override it;
//! the JSON line gets `"quick":true`). The last line printed is one JSON object.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use isochron_config::clock::wall_now_ns;
use isochron_runtime::health::quantile;
use isochron_runtime::ipc::{
    Activity, Detections, Events, Ipc, StatusSubscriber, StreamSubscriber, StreamType,
};
use isochron_runtime::topology::StageKind;
use isochron_tests::{
    Proc, TestSite, bench_args, bench_count, bench_options, bench_secs, bin, clock_ticks_per_s,
    cpu_ticks, repo_root, vtest,
};
use isochron_wire::{EventPhase, StageStatus, StreamHeader};
use opencv::core::{Mat, Size};
use opencv::prelude::*;
use opencv::videoio;

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

/// The per-camera services, in pipeline order, and the site-wide one.
const STAGES: [StageKind; 5] = StageKind::ALL;
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
[--start N] [--max N] [--warmup SECONDS] [--seconds SECONDS]";

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
    ];
    for (flag, value) in bench_args("group", USAGE, (&["--quick"], &valued), args)? {
        let value = value.unwrap_or_default();
        match flag.as_str() {
            "--quick" => o = o.quick(),
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
            _ => {
                o.seconds = bench_secs(&flag, &value, 0.0)?.max(Duration::from_secs(1));
                o.decode_only_seconds = o.seconds;
            }
        }
    }
    o.max = o.max.max(o.start);
    Ok(o)
}

/// Camera ids `cam001`, `cam002`, ….
fn camera_ids(n: usize) -> Vec<String> {
    (1..=n).map(|i| format!("cam{i:03}")).collect()
}

/// A DDS domain unlikely to collide with tests running at the same time.
fn ros_domain() -> u16 {
    1 + (std::process::id() % 229) as u16
}

/// The site config (after `[site]`) for `cameras` in `mode`, replaying the churn
/// `video`: camera *i* of N starts *i*/N of a cycle in.
///
/// The quiet part is a cut to the busy part's median, so a camera that started
/// in the busy part sees blocks differ from everything it learned, arriving with
/// the cut's motion: the presence band rightly holds them present until they are
/// absorbed. A short `absorb_s` lets the events end inside the window (what is
/// measured is the end record's latency, not how long presence held the event);
/// the band still runs on every camera, so its cost is in the figures.
fn site_body(mode: Mode, cameras: &[String], video: &Path) -> String {
    let source = serde_json::to_string(&video.display().to_string()).unwrap_or_default();
    let mut body = format!(
        "[presence]\nabsorb_s = 5.0\n\n\
         [gate.detector]\nhog_upscale = 1.5\n\n\
         [costmap]\norigin_x_m = -22.0\norigin_y_m = -18.0\nresolution_m = 0.1\n\
         width_cells = 320\nheight_cells = 300\nframe_id = \"map\"\n\
         topic = \"/isochron/bench_costmap\"\nros_domain_id = {}\n\
         dds_interfaces = [\"127.0.0.1\"]\n",
        ros_domain()
    );
    for (i, id) in cameras.iter().enumerate() {
        let start_frame = (2 * i as u64 + 1) * u64::from(CYCLE_FRAMES) / (2 * cameras.len() as u64);
        let _ = write!(
            body,
            "\n[[camera]]\nid = \"{id}\"\nsource = {source}\nfps = {FPS:.1}\nloop = true\n\
             start_frame = {start_frame}\n"
        );
        if mode == Mode::Predecoded {
            let _ = writeln!(body, "preload_frames = {CYCLE_FRAMES}");
        }
        let _ = writeln!(body, "{FLOOR_POINTS}");
    }
    body
}

/// The churn video (see the module doc): made from vtest on first use, kept in
/// `target/bench-data/`. Returns its path and the codec it was written with.
fn churn_video() -> Result<(PathBuf, String), String> {
    let dir = repo_root().join("target/bench-data");
    let path = dir.join(format!("churn-busy{BUSY_S}s-quiet{QUIET_S}s.avi"));
    let codec_of = |path: &Path| -> Result<String, String> {
        let cap = videoio::VideoCapture::from_file(path.display().to_string(), videoio::CAP_ANY)
            .map_err(|e| format!("{}: {e}", path.display()))?;
        let fourcc = cap.get(videoio::CAP_PROP_FOURCC).unwrap_or(0.0) as u32;
        Ok(fourcc_name(fourcc))
    };
    if path.exists() {
        return Ok((path.clone(), codec_of(&path)?));
    }
    std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let t0 = Instant::now();
    let source = vtest();
    let err = |e: opencv::Error| format!("making the churn video from {}: {e}", source.display());
    let mut cap = videoio::VideoCapture::from_file(source.display().to_string(), videoio::CAP_ANY)
        .map_err(err)?;
    let fourcc = cap.get(videoio::CAP_PROP_FOURCC).map_err(err)? as i32;
    let mut frames: Vec<Mat> = Vec::new();
    let mut frame = Mat::default();
    while cap.read(&mut frame).map_err(err)? && !frame.empty() {
        frames.push(frame.try_clone().map_err(err)?);
    }
    let busy = (BUSY_S * FPS as u32) as usize;
    if frames.len() < busy.max(BACKGROUND_SAMPLES) {
        return Err(format!(
            "{}: {} frames, the churn video needs {}",
            source.display(),
            frames.len(),
            busy.max(BACKGROUND_SAMPLES)
        ));
    }
    let background = median_frame(&frames, BACKGROUND_SAMPLES).map_err(err)?;
    let size: Size = frames[0].size().map_err(err)?;
    let partial = dir.join(format!("churn-partial-{}.avi", std::process::id()));
    // vtest's codec if this OpenCV can write it, else Motion JPEG (always built in).
    let mjpg = videoio::VideoWriter::fourcc('M', 'J', 'P', 'G').map_err(err)?;
    let mut writer = None;
    for code in [fourcc, mjpg] {
        let w = videoio::VideoWriter::new(partial.display().to_string(), code, FPS, size, true)
            .map_err(err)?;
        if w.is_opened().map_err(err)? {
            writer = Some(w);
            break;
        }
    }
    let mut writer = writer.ok_or_else(|| format!("OpenCV cannot write {}", partial.display()))?;
    for f in &frames[..busy] {
        writer.write(f).map_err(err)?;
    }
    for _ in 0..QUIET_S * FPS as u32 {
        writer.write(&background).map_err(err)?;
    }
    writer.release().map_err(err)?;
    std::fs::rename(&partial, &path).map_err(|e| format!("{}: {e}", path.display()))?;
    let codec = codec_of(&path)?;
    eprintln!(
        "group: made {} ({codec}, {CYCLE_FRAMES} frames) in {:.1} s",
        path.display(),
        t0.elapsed().as_secs_f64()
    );
    Ok((path, codec))
}

/// A fourcc code as its four characters.
fn fourcc_name(code: u32) -> String {
    code.to_le_bytes()
        .iter()
        .map(|&b| if b.is_ascii_graphic() { b as char } else { '?' })
        .collect()
}

/// The per-pixel (per-byte) median of `samples` frames spread evenly over `frames`.
fn median_frame(frames: &[Mat], samples: usize) -> opencv::Result<Mat> {
    let picked: Vec<&[u8]> = (0..samples)
        .map(|k| frames[k * frames.len() / samples].data_bytes())
        .collect::<opencv::Result<_>>()?;
    let mut out = frames[0].try_clone()?;
    let bytes = out.data_bytes_mut()?;
    let mut column = Vec::with_capacity(samples);
    for (i, byte) in bytes.iter_mut().enumerate() {
        column.clear();
        column.extend(picked.iter().map(|f| f[i]));
        let mid = column.len() / 2;
        *byte = *column.select_nth_unstable(mid).1;
    }
    Ok(out)
}

/// One service process of the group.
struct Member {
    /// Index in [`STAGES`].
    stage: usize,
    /// Its cameras, comma-separated (empty for the bridge).
    cameras: String,
    proc: Proc,
}

impl Member {
    fn describe(&self) -> String {
        if self.cameras.is_empty() {
            STAGES[self.stage].binary().to_string()
        } else {
            format!("{} --camera {}", STAGES[self.stage].binary(), self.cameras)
        }
    }
}

/// The running group: every service process of one site.
struct Group {
    members: Vec<Member>,
}

impl Group {
    /// Starts the bridge, then for each per-camera stage from the last to capture
    /// (consumers before producers) one process per `per_process` cameras — of
    /// the stages `mode` runs.
    fn spawn(site: &TestSite, mode: Mode, cameras: &[String], per_process: usize) -> Group {
        let mut members = Vec::new();
        if mode.stages().contains(&COSTMAP) {
            members.push(Member {
                stage: COSTMAP,
                cameras: String::new(),
                proc: site.spawn("isochron-costmap", &[]),
            });
        }
        for stage in (0..COSTMAP).rev().filter(|s| mode.stages().contains(s)) {
            for chunk in cameras.chunks(per_process) {
                let list = chunk.join(",");
                let binary = STAGES[stage].binary();
                let proc = site.spawn(binary, &["--camera", &list]);
                members.push(Member {
                    stage,
                    cameras: list,
                    proc,
                });
            }
        }
        Group { members }
    }

    /// Why the group is broken, if a process exited.
    fn dead(&mut self) -> Option<String> {
        let mut dead = Vec::new();
        for m in &mut self.members {
            if let Some(status) = m.proc.wait(Duration::ZERO) {
                let stderr = m.proc.stderr();
                let last = stderr.lines().rev().find(|l| !l.trim().is_empty());
                dead.push(format!(
                    "{} exited ({status}){}",
                    m.describe(),
                    last.map(|l| format!(": {}", l.trim())).unwrap_or_default()
                ));
            }
        }
        if dead.is_empty() {
            return None;
        }
        let more = dead.len() - 1;
        let mut reason = dead.swap_remove(0);
        if more > 0 {
            let _ = write!(reason, " (and {more} more processes)");
        }
        Some(reason)
    }

    /// CPU time so far of every process, in clock ticks (`None` once it is gone).
    fn cpu_ticks(&self) -> Vec<Option<u64>> {
        self.members
            .iter()
            .map(|m| cpu_ticks(m.proc.pid()))
            .collect()
    }

    /// Private memory of the processes of each stage ([`STAGES`]), bytes.
    fn private_bytes(&self) -> [u64; 5] {
        let mut per_stage = [0; 5];
        for m in &self.members {
            per_stage[m.stage] += private_bytes(m.proc.pid()).unwrap_or(0);
        }
        per_stage
    }

    /// Stops every process: SIGTERM to all at once, up to [`STOP_TIMEOUT`] for them
    /// to clean up, SIGKILL for the rest. Says so when stopping was slow.
    fn stop(mut self) {
        let t0 = Instant::now();
        for m in &self.members {
            m.proc.signal(libc::SIGTERM);
        }
        // Exit time of each member, polled together so the slowest is known.
        let mut stopped: Vec<Option<Duration>> = vec![None; self.members.len()];
        while stopped.iter().any(Option::is_none) && t0.elapsed() < STOP_TIMEOUT {
            for (m, t) in self.members.iter_mut().zip(&mut stopped) {
                if t.is_none() && m.proc.wait(Duration::ZERO).is_some() {
                    *t = Some(t0.elapsed());
                }
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        let mut killed = Vec::new();
        for (m, t) in self.members.iter_mut().zip(&stopped) {
            if t.is_none() {
                m.proc.signal(libc::SIGKILL);
                let _ = m.proc.wait(Duration::from_secs(2));
                killed.push(m.describe());
            }
        }
        if let Some(first) = killed.first() {
            eprintln!(
                "group: {} of {} processes had not stopped {:.0} s after SIGTERM and were killed, e.g. {first}",
                killed.len(),
                self.members.len(),
                STOP_TIMEOUT.as_secs_f64(),
            );
        } else if let Some((m, t)) = self
            .members
            .iter()
            .zip(&stopped)
            .filter_map(|(m, t)| Some((m, (*t)?)))
            .max_by_key(|(_, t)| *t)
            && t > Duration::from_secs(5)
        {
            eprintln!(
                "group: the processes took up to {:.1} s to stop after SIGTERM (slowest: {})",
                t.as_secs_f64(),
                m.describe()
            );
        }
    }
}

/// Private_Clean + Private_Dirty of every mapping of `pid` except `/dev/shm` files
/// (those are counted once, in [`ShmUsage`]), bytes.
fn private_bytes(pid: u32) -> Option<u64> {
    let smaps = std::fs::read_to_string(format!("/proc/{pid}/smaps")).ok()?;
    let mut total_kb = 0u64;
    let mut in_shm = false;
    for line in smaps.lines() {
        let mut words = line.split_whitespace();
        let Some(first) = words.next() else { continue };
        if !first.ends_with(':') {
            // A mapping's header: `start-end perms offset dev inode [path]`.
            in_shm = line.contains(" /dev/shm/");
            continue;
        }
        if !in_shm && (first == "Private_Clean:" || first == "Private_Dirty:") {
            total_kb += words
                .next()
                .and_then(|v| v.parse::<u64>().ok())
                .unwrap_or(0);
        }
    }
    Some(total_kb * 1024)
}

/// What the files in `/dev/shm` take, bytes.
#[derive(Debug, Clone, Copy, Default)]
struct ShmUsage {
    /// Memory actually in use (allocated pages).
    used: u64,
    /// The files' sizes: what is mapped, the most they can come to use.
    mapped: u64,
}

impl ShmUsage {
    /// The usage now.
    fn now() -> ShmUsage {
        fn walk(dir: &Path, total: &mut ShmUsage) {
            use std::os::unix::fs::MetadataExt;
            let Ok(entries) = std::fs::read_dir(dir) else {
                return;
            };
            for entry in entries.flatten() {
                match entry.metadata() {
                    Ok(m) if m.is_dir() => walk(&entry.path(), total),
                    Ok(m) => {
                        total.used += m.blocks() * 512;
                        total.mapped += m.size();
                    }
                    Err(_) => {}
                }
            }
        }
        let mut total = ShmUsage::default();
        walk(Path::new("/dev/shm"), &mut total);
        total
    }

    /// The growth since `before`.
    fn since(self, before: ShmUsage) -> ShmUsage {
        ShmUsage {
            used: self.used.saturating_sub(before.used),
            mapped: self.mapped.saturating_sub(before.mapped),
        }
    }
}

/// Set by SIGINT or SIGTERM: the bench stops the running group and finishes.
static INTERRUPTED: AtomicBool = AtomicBool::new(false);

extern "C" fn on_interrupt(_signal: libc::c_int) {
    INTERRUPTED.store(true, Ordering::Relaxed);
}

/// Catches SIGINT and SIGTERM, so that an interrupted bench still stops its
/// processes (they are not killed with it).
fn catch_interrupts() {
    for signal in [libc::SIGINT, libc::SIGTERM] {
        // SAFETY: the handler only stores to an atomic.
        unsafe {
            libc::signal(signal, on_interrupt as *const () as libc::sighandler_t);
        }
    }
}

fn interrupted() -> bool {
    INTERRUPTED.load(Ordering::Relaxed)
}

/// The status reports of one stage of one camera within the measurement window.
struct Track {
    stage: StageKind,
    subscriber: StatusSubscriber,
    /// The newest report made before the window's start.
    before: Option<StageStatus>,
    /// The first report made at or after the window's start.
    first: Option<StageStatus>,
    /// The newest report.
    last: Option<StageStatus>,
}

impl Track {
    /// Both ends of the window, if the stage reported twice in it.
    fn span(&self) -> Option<(&StageStatus, &StageStatus)> {
        match (&self.first, &self.last) {
            (Some(a), Some(b)) if b.report_wall_ns > a.report_wall_ns => Some((a, b)),
            _ => None,
        }
    }
}

/// The status reports of a mode's health stages for every camera.
struct StatusBoard {
    /// Per camera, per health stage.
    tracks: Vec<Vec<Track>>,
}

impl StatusBoard {
    fn open(ipc: &Ipc, cameras: &[String], stages: &[StageKind]) -> Result<StatusBoard, String> {
        let mut tracks = Vec::with_capacity(cameras.len());
        for camera in cameras {
            let mut per_stage = Vec::with_capacity(stages.len());
            for &stage in stages {
                let subscriber = ipc
                    .status_subscriber(camera, stage)
                    .map_err(|e| format!("status of {stage}/{camera}: {e}"))?;
                per_stage.push(Track {
                    stage,
                    subscriber,
                    before: None,
                    first: None,
                    last: None,
                });
            }
            tracks.push(per_stage);
        }
        Ok(StatusBoard { tracks })
    }

    /// Takes the new reports; those made before `since_ns` (wall clock) are ignored.
    fn poll(&mut self, since_ns: i64) {
        for track in self.tracks.iter_mut().flatten() {
            if let Some(report) = track.subscriber.latest()
                && report.validate().is_ok()
            {
                if report.report_wall_ns < since_ns {
                    track.before = Some(report);
                } else {
                    track.first.get_or_insert(report);
                    track.last = Some(report);
                }
            }
        }
    }

    /// True when every stage of every camera reported twice in the window.
    fn complete(&self) -> bool {
        self.tracks.iter().flatten().all(|t| t.span().is_some())
    }
}

/// What one run at N cameras measured.
#[derive(Debug, Clone)]
struct Run {
    mode: Mode,
    cameras: usize,
    processes: usize,
    /// CPU per stage ([`STAGES`]), % of one core.
    cpu: Option<[f64; 5]>,
    /// Lowest capture rate (decode-only) or motion rate of any camera, frames/s.
    min_fps: Option<f64>,
    /// Lowest rate of frames the gate took of any camera, frames/s.
    gate_min_fps: Option<f64>,
    /// Samples motion, cascade and gate dropped in the window.
    drops: Option<u64>,
    /// p99 latency capture → activity over all cameras in the window, ms.
    p99_ms: Option<f32>,
    /// Events started and ended in the window, all cameras.
    events_started: u64,
    events_ended: u64,
    /// p99 event end lag in the window, ms.
    end_lag_p99_ms: Option<f32>,
    /// Detections published in the window, all cameras.
    detections: u64,
    /// p99 detection latency (capture publication → detections arrival), ms.
    detection_p99_ms: Option<f32>,
    /// Detection jobs the gates accepted and dropped, all cameras: from their last
    /// status report before the window to their last in it.
    jobs_accepted: Option<u64>,
    jobs_dropped: Option<u64>,
    /// Private memory of the group per camera, MB.
    private_mb_per_camera: Option<f64>,
    /// Private memory per stage ([`STAGES`]) per camera, MB.
    private_mb_per_stage: Option<[f64; 5]>,
    /// Growth of the memory in use in `/dev/shm` per camera, MB.
    shm_mb_per_camera: Option<f64>,
    /// Growth of the size of the files in `/dev/shm` per camera, MB.
    shm_mapped_mb_per_camera: Option<f64>,
    /// Load average (1 min) when the run started.
    load_before: Option<f64>,
    /// Why it did not hold (empty: it held).
    failures: Vec<String>,
}

impl Run {
    fn new(mode: Mode, cameras: usize, processes: usize) -> Run {
        Run {
            mode,
            cameras,
            processes,
            cpu: None,
            min_fps: None,
            gate_min_fps: None,
            drops: None,
            p99_ms: None,
            events_started: 0,
            events_ended: 0,
            end_lag_p99_ms: None,
            detections: 0,
            detection_p99_ms: None,
            jobs_accepted: None,
            jobs_dropped: None,
            private_mb_per_camera: None,
            private_mb_per_stage: None,
            shm_mb_per_camera: None,
            shm_mapped_mb_per_camera: None,
            load_before: load_average(),
            failures: Vec::new(),
        }
    }

    fn held(&self) -> bool {
        self.failures.is_empty()
    }

    fn fail(mut self, reason: String) -> Run {
        self.failures.push(reason);
        self
    }
}

/// The 1-minute load average (`/proc/loadavg`).
fn load_average() -> Option<f64> {
    std::fs::read_to_string("/proc/loadavg")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// Processes the group has for `n` cameras, `per_process` per process, in `mode`.
fn process_count(mode: Mode, n: usize, per_process: usize) -> usize {
    let per_camera = mode.stages().iter().filter(|&&s| s != COSTMAP).count();
    let site_wide = usize::from(mode.stages().contains(&COSTMAP));
    per_camera * n.div_ceil(per_process) + site_wide
}

/// Runs the group on `n` cameras in `mode`, replaying `video`, and measures it.
fn run_group(opts: &Options, mode: Mode, n: usize, video: &Path) -> Run {
    let cameras = camera_ids(n);
    let run = Run::new(mode, n, process_count(mode, n, opts.per_process));
    let site = TestSite::new(
        &format!("group-{}-{n}", mode.name()),
        &site_body(mode, &cameras, video),
    );
    remove_stale_nodes();
    let ipc = site.ipc("bench");
    let shm_before = ShmUsage::now();
    let opened = StatusBoard::open(&ipc, &cameras, mode.health_stages()).and_then(|board| {
        let probe = if mode == Mode::DecodeOnly {
            Probe::default()
        } else {
            Probe::open(&ipc, &cameras)?
        };
        Ok((board, probe))
    });
    let (mut board, mut probe) = match opened {
        Ok(o) => o,
        Err(e) => return run.fail(e),
    };
    eprintln!(
        "group: {} N={n}: starting {} processes",
        mode.name(),
        run.processes
    );
    let mut group = Group::spawn(&site, mode, &cameras, opts.per_process);
    let mut watch = Watch {
        group: &mut group,
        board: &mut board,
        probe: &mut probe,
    };
    let run = measure(opts, run, &mut watch, shm_before);
    group.stop();
    drop(probe);
    drop(board);
    drop(ipc);
    drop(site);
    // Let the nodes' shared memory go before the next run.
    std::thread::sleep(Duration::from_secs(1));
    remove_stale_nodes();
    run
}

/// Removes what iceoryx2 nodes of dead processes left in shared memory (a killed
/// process cannot clean up), so that the next run's baseline is clean.
fn remove_stale_nodes() {
    match isochron_runtime::ipc::node_census(true) {
        Ok(census) if !census.dead_removed.is_empty() => eprintln!(
            "group: removed the stale resources of {} dead iceoryx2 node(s)",
            census.dead_removed.len()
        ),
        Ok(_) => {}
        Err(e) => eprintln!("group: {e}"),
    }
}

/// What the bench keeps an eye on while the group runs.
struct Watch<'a> {
    group: &'a mut Group,
    board: &'a mut StatusBoard,
    probe: &'a mut Probe,
}

/// What [`Watch::until`] takes in while it waits.
#[derive(Debug, Clone, Copy)]
struct Intake {
    /// Status reports made from this wall-clock time (ns) on count.
    reports_since_ns: i64,
    /// Stream samples are recorded (else only drained).
    record: bool,
}

impl Intake {
    /// Warm-up: nothing counts.
    const NOTHING: Intake = Intake {
        reports_since_ns: i64::MAX,
        record: false,
    };
}

impl Watch<'_> {
    /// Waits until `until`, reading the streams every [`PROBE_POLL`] and, every
    /// [`POLL`], the status reports and whether a process died.
    fn until(&mut self, until: Instant, intake: Intake) -> Result<(), String> {
        let mut next_check = Instant::now();
        loop {
            if interrupted() {
                return Err("interrupted".into());
            }
            self.probe.poll(intake.record);
            let now = Instant::now();
            if now >= next_check {
                self.board.poll(intake.reports_since_ns);
                if let Some(dead) = self.group.dead() {
                    return Err(dead);
                }
                next_check = now + POLL;
            }
            let left = until.saturating_duration_since(now);
            if left.is_zero() {
                return Ok(());
            }
            std::thread::sleep(left.min(PROBE_POLL));
        }
    }
}

/// Warm-up, measurement window, evaluation.
fn measure(opts: &Options, mut run: Run, watch: &mut Watch, shm_before: ShmUsage) -> Run {
    if let Err(dead) = watch.until(Instant::now() + opts.warmup, Intake::NOTHING) {
        return run.fail(format!("during warm-up: {dead}"));
    }

    let window_start_ns = wall_now_ns();
    let in_window = Intake {
        reports_since_ns: window_start_ns,
        record: true,
    };
    let t0 = Instant::now();
    let cpu0 = watch.group.cpu_ticks();
    if let Err(dead) = watch.until(t0 + opts.window(run.mode), in_window) {
        return run.fail(dead);
    }
    let cpu1 = watch.group.cpu_ticks();
    let elapsed = t0.elapsed().as_secs_f64();
    let window = (window_start_ns, wall_now_ns());
    let private = watch.group.private_bytes();
    let shm = ShmUsage::now().since(shm_before);

    let per_cpu_s = 100.0 / (clock_ticks_per_s() * elapsed);
    let mut cpu = [0.0; 5];
    for ((m, a), b) in watch.group.members.iter().zip(&cpu0).zip(&cpu1) {
        if let (Some(a), Some(b)) = (a, b) {
            cpu[m.stage] += b.saturating_sub(*a) as f64 * per_cpu_s;
        }
    }
    run.cpu = Some(cpu);
    let mb_per_camera = |bytes: u64| bytes as f64 / 1e6 / run.cameras as f64;
    run.private_mb_per_camera = Some(mb_per_camera(private.iter().sum()));
    run.private_mb_per_stage = Some(private.map(mb_per_camera));
    run.shm_mb_per_camera = Some(mb_per_camera(shm.used));
    run.shm_mapped_mb_per_camera = Some(mb_per_camera(shm.mapped));

    // A window shorter than the report period may hold one report per stage: wait
    // (up to a period) for the next.
    let extra = Instant::now() + STATUS_PERIOD + Duration::from_secs(1);
    let after_window = Intake {
        record: false,
        ..in_window
    };
    while !watch.board.complete() && Instant::now() < extra {
        if let Err(dead) = watch.until(Instant::now() + POLL, after_window) {
            return run.fail(dead);
        }
    }
    let run = evaluate_status(run, watch.board);
    if run.mode == Mode::DecodeOnly {
        return run;
    }
    let window_s = window.1.saturating_sub(window.0) as f64 / 1e9;
    let run = evaluate_latency(run, watch.probe, window);
    evaluate_gate(run, watch.probe, window_s)
}

/// What the bench reads from the streams of every camera as they arrive (every
/// [`PROBE_POLL`]): activity (for the capture → activity latency), event records
/// and detections.
#[derive(Default)]
struct Probe {
    activity: Vec<StreamSubscriber<Activity>>,
    events: Vec<StreamSubscriber<Events>>,
    detections: Vec<StreamSubscriber<Detections>>,
    /// Arrival (wall clock, ns), camera and latency (ms) of each activity sample in
    /// the window.
    samples: Vec<(i64, usize, f32)>,
    /// Per camera: events started and ended in the window.
    started: Vec<u64>,
    ended: Vec<u64>,
    /// End lag of each end record in the window, ms.
    end_lags_ms: Vec<f32>,
    /// Per camera: detections in the window.
    detected: Vec<u64>,
    /// Latency of each detection in the window, ms.
    detection_ms: Vec<f32>,
}

impl Probe {
    fn open(ipc: &Ipc, cameras: &[String]) -> Result<Probe, String> {
        fn each<S: isochron_runtime::ipc::StreamType>(
            ipc: &Ipc,
            cameras: &[String],
        ) -> Result<Vec<StreamSubscriber<S>>, String> {
            cameras
                .iter()
                .map(|camera| {
                    ipc.subscriber::<S>(camera)
                        .map_err(|e| format!("{} of {camera}: {e}", S::STREAM))
                })
                .collect()
        }
        Ok(Probe {
            activity: each(ipc, cameras)?,
            events: each(ipc, cameras)?,
            detections: each(ipc, cameras)?,
            started: vec![0; cameras.len()],
            ended: vec![0; cameras.len()],
            detected: vec![0; cameras.len()],
            ..Probe::default()
        })
    }

    /// Takes every waiting sample; records them if `record`.
    fn poll(&mut self, record: bool) {
        let ms_since = |origin: i64| (wall_now_ns() - origin) as f32 / 1e6;
        for (camera, subscriber) in self.activity.iter().enumerate() {
            subscriber.drain_wakeups();
            while let Ok(Some(sample)) = subscriber.receive() {
                let now = wall_now_ns();
                let origin = sample.user_header().preamble.origin_wall_ns;
                if record && origin > 0 {
                    self.samples
                        .push((now, camera, (now - origin) as f32 / 1e6));
                }
            }
        }
        drain(
            &self.events,
            record,
            |camera, h| match EventPhase::from_u32(h.phase) {
                Some(EventPhase::Start) => self.started[camera] += 1,
                Some(EventPhase::End) => {
                    self.ended[camera] += 1;
                    if h.preamble.origin_wall_ns > 0 {
                        self.end_lags_ms.push(ms_since(h.preamble.origin_wall_ns));
                    }
                }
                None => {}
            },
        );
        drain(&self.detections, record, |camera, h| {
            self.detected[camera] += 1;
            if h.preamble.origin_wall_ns > 0 {
                self.detection_ms.push(ms_since(h.preamble.origin_wall_ns));
            }
        });
    }
}

/// Takes every waiting sample of the cameras' `subscribers`; if `record`, passes
/// the header of each data sample (not end-of-stream) with its camera to `f`.
fn drain<S: StreamType>(
    subscribers: &[StreamSubscriber<S>],
    record: bool,
    mut f: impl FnMut(usize, &S::Header),
) {
    for (camera, subscriber) in subscribers.iter().enumerate() {
        subscriber.drain_wakeups();
        while let Ok(Some(sample)) = subscriber.receive() {
            let h = sample.user_header();
            if record && !h.preamble().is_end_of_stream() {
                f(camera, h);
            }
        }
    }
}

/// What two status reports of one stage of one camera say about the window.
struct Window {
    /// Samples published per second (for the gate: frames taken per second).
    rate: f64,
    /// Samples dropped (here or upstream).
    dropped: u64,
    /// The gate's detection jobs accepted and dropped.
    jobs: Option<(u64, u64)>,
}

/// The number after `key=` in a status report's detail text.
fn detail_value(status: &StageStatus, key: &str) -> Option<u64> {
    let end = status
        .detail
        .iter()
        .position(|&b| b == 0)
        .unwrap_or(status.detail.len());
    let text = std::str::from_utf8(&status.detail[..end]).ok()?;
    text.split_whitespace()
        .find_map(|kv| kv.strip_prefix(key)?.strip_prefix('=')?.parse().ok())
}

impl Track {
    /// The window between the first and the last report, if there were two.
    fn window(&self) -> Option<Window> {
        let (a, b) = self.span()?;
        let seconds = (b.report_wall_ns - a.report_wall_ns) as f64 / 1e9;
        let between = |x: &StageStatus, key: &str| {
            Some(detail_value(b, key)?.saturating_sub(detail_value(x, key)?))
        };
        let done = if self.stage == StageKind::Gate {
            between(a, "frames_seen").unwrap_or(0)
        } else {
            b.sent.saturating_sub(a.sent)
        };
        // Counters of what is rare next to the report period (detection jobs)
        // span the whole window: from the last report before it.
        let from = self.before.as_ref().unwrap_or(a);
        Some(Window {
            rate: done as f64 / seconds,
            dropped: b.dropped.saturating_sub(a.dropped),
            jobs: between(from, "jobs").zip(between(from, "jobs_dropped")),
        })
    }
}

/// The cameras that failed one criterion, summed up as one reason.
#[derive(Default)]
struct Offenders {
    cameras: Vec<usize>,
    /// The worst camera and its value.
    worst: Option<(usize, f64)>,
}

impl Offenders {
    /// Notes camera `i` with `value`; `worse(a, b)` says whether `a` is worse.
    fn add(&mut self, i: usize, value: f64, worse: fn(f64, f64) -> bool) {
        self.cameras.push(i);
        if self.worst.is_none_or(|(_, w)| worse(value, w)) {
            self.worst = Some((i, value));
        }
    }

    /// Notes camera `i` (no value).
    fn add_camera(&mut self, i: usize) {
        self.cameras.push(i);
    }

    /// "`what` on k camera(s) (worst V`unit` on camX)", if any camera failed.
    fn reason(&self, what: &str, unit: &str, cameras: &[String]) -> Option<String> {
        let first = *self.cameras.first()?;
        let detail = match self.worst {
            Some((i, v)) => format!("worst {v:.1}{unit} on {}", cameras[i]),
            None => format!("e.g. {}", cameras[first]),
        };
        Some(format!(
            "{what} on {} camera(s) ({detail})",
            self.cameras.len()
        ))
    }
}

/// Applies the rate and drop criteria to the status reports of the window.
fn evaluate_status(mut run: Run, board: &StatusBoard) -> Run {
    let cameras = camera_ids(run.cameras);
    let stages = run.mode.health_stages();
    let min_rate = FPS * MIN_RATE_SHARE;
    let lower = |a: f64, b: f64| a < b;
    let higher = |a: f64, b: f64| a > b;
    let mut silent: Vec<Offenders> = stages.iter().map(|_| Offenders::default()).collect();
    let mut slow: Vec<Offenders> = stages.iter().map(|_| Offenders::default()).collect();
    let mut dropping: Vec<Offenders> = stages.iter().map(|_| Offenders::default()).collect();
    // The stage whose rate is `min_fps`: motion, or capture when it runs alone.
    let paced = if run.mode == Mode::DecodeOnly {
        StageKind::Capture
    } else {
        StageKind::Motion
    };
    let (mut min_fps, mut gate_min_fps, mut drops) = (f64::INFINITY, f64::INFINITY, 0u64);
    let mut jobs = Some((0u64, 0u64));

    for (i, per_stage) in board.tracks.iter().enumerate() {
        for (s, track) in per_stage.iter().enumerate() {
            let Some(w) = track.window() else {
                silent[s].add_camera(i);
                continue;
            };
            if track.stage != StageKind::Cascade && w.rate < min_rate {
                slow[s].add(i, w.rate, lower);
            }
            if track.stage == paced {
                min_fps = min_fps.min(w.rate);
            }
            if track.stage == StageKind::Gate {
                gate_min_fps = gate_min_fps.min(w.rate);
                jobs = jobs.zip(w.jobs).map(|((a, d), (wa, wd))| (a + wa, d + wd));
            }
            if track.stage != StageKind::Capture && w.dropped > 0 {
                drops += w.dropped;
                dropping[s].add(i, w.dropped as f64, higher);
            }
        }
    }

    let all_reported = |stage: StageKind| {
        stages
            .iter()
            .position(|&s| s == stage)
            .is_none_or(|s| silent[s].cameras.is_empty())
    };
    if all_reported(paced) {
        run.min_fps = Some(min_fps);
    }
    if stages.contains(&StageKind::Gate) && all_reported(StageKind::Gate) {
        run.gate_min_fps = Some(gate_min_fps);
        run.jobs_accepted = jobs.map(|j| j.0);
        run.jobs_dropped = jobs.map(|j| j.1);
    }
    if stages.iter().all(|&s| all_reported(s)) && run.mode != Mode::DecodeOnly {
        run.drops = Some(drops);
    }
    for (s, stage) in stages.iter().enumerate() {
        let what = if *stage == StageKind::Gate {
            "took frames at"
        } else {
            "published"
        };
        let reasons = [
            silent[s].reason(
                &format!("{stage} made fewer than 2 status reports in the window"),
                "",
                &cameras,
            ),
            slow[s].reason(
                &format!("{stage} {what} below {min_rate:.2} fps"),
                " fps",
                &cameras,
            ),
            dropping[s].reason(&format!("{stage} dropped samples"), "", &cameras),
        ];
        run.failures.extend(reasons.into_iter().flatten());
    }
    run
}

/// Applies the latency criteria to the activity samples of `window` (wall-clock ns):
/// every camera delivered activity, the p99 is under [`MAX_P99_MS`], and the second
/// half's p99 is not more than [`P99_GROWTH`] times the first half's.
fn evaluate_latency(mut run: Run, probe: &Probe, window: (i64, i64)) -> Run {
    let cameras = camera_ids(run.cameras);
    let p99 = |half: Option<bool>| {
        let mid = window.0 + (window.1 - window.0) / 2;
        let values: Vec<f32> = probe
            .samples
            .iter()
            .filter(|(t, _, _)| half.is_none_or(|second| (*t >= mid) == second))
            .map(|(_, _, ms)| *ms)
            .collect();
        (!values.is_empty()).then(|| quantile(&values, 0.99))
    };

    let mut received = vec![0usize; run.cameras];
    let mut worst: Option<(usize, f32)> = None;
    for &(_, camera, ms) in &probe.samples {
        received[camera] += 1;
        if worst.is_none_or(|(_, w)| ms > w) {
            worst = Some((camera, ms));
        }
    }
    let mut silent = Offenders::default();
    for (i, _) in received.iter().enumerate().filter(|(_, n)| **n == 0) {
        silent.add_camera(i);
    }
    run.failures
        .extend(silent.reason("no activity arrived in the window", "", &cameras));

    run.p99_ms = p99(None);
    if let (Some(p), Some((camera, max))) = (run.p99_ms, worst)
        && p >= MAX_P99_MS
    {
        run.failures.push(format!(
            "capture→activity p99 {p:.0} ms ≥ {MAX_P99_MS:.0} ms (worst {max:.0} ms on {})",
            cameras[camera]
        ));
    }
    if let (Some(first), Some(second)) = (p99(Some(false)), p99(Some(true)))
        && second > P99_GROWTH * first
        && second > P99_GROWTH_FLOOR_MS
    {
        run.failures.push(format!(
            "capture→activity p99 grew from {first:.0} ms (first half) to {second:.0} ms (second half)"
        ));
    }
    run
}

/// Applies the gate's criteria to the event records and detections of a window of
/// `window_s` seconds: end lag and detection latency bounded, the detector ran, and
/// (in a window of two cycles or more) every camera ended an event.
fn evaluate_gate(mut run: Run, probe: &Probe, window_s: f64) -> Run {
    let cameras = camera_ids(run.cameras);
    run.events_started = probe.started.iter().sum();
    run.events_ended = probe.ended.iter().sum();
    run.detections = probe.detected.iter().sum();
    let p99 = |v: &[f32]| (!v.is_empty()).then(|| quantile(v, 0.99));
    run.end_lag_p99_ms = p99(&probe.end_lags_ms);
    run.detection_p99_ms = p99(&probe.detection_ms);
    if let Some(p) = run.end_lag_p99_ms
        && p >= MAX_END_LAG_MS
    {
        run.failures.push(format!(
            "event end lag p99 {p:.0} ms ≥ {MAX_END_LAG_MS:.0} ms"
        ));
    }
    if let Some(p) = run.detection_p99_ms
        && p >= MAX_DETECTION_MS
    {
        run.failures.push(format!(
            "detection latency p99 {p:.0} ms ≥ {MAX_DETECTION_MS:.0} ms"
        ));
    }
    if run.events_started > 0 && run.detections == 0 {
        run.failures
            .push("events started but the detector never ran in the window".into());
    }
    let cycle_s = f64::from(BUSY_S + QUIET_S);
    if window_s >= 2.0 * cycle_s {
        let mut idle = Offenders::default();
        for (i, _) in probe.ended.iter().enumerate().filter(|(_, n)| **n == 0) {
            idle.add_camera(i);
        }
        run.failures.extend(idle.reason(
            &format!("no event ended in a window of {window_s:.0} s"),
            "",
            &cameras,
        ));
    }
    run
}

/// Formats an optional number with `decimals`, `-` when missing.
fn opt(v: Option<f64>, decimals: usize) -> String {
    v.map_or_else(|| "-".into(), |v| format!("{v:.decimals$}"))
}

/// The table's columns: title and width (the first is left-aligned).
const COLUMNS: [(&str, usize); 22] = [
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
fn table_line(cells: &[String]) -> String {
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

fn print_header(opts: &Options, codec: &str) {
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

fn print_row(r: &Run) {
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

/// The best run of every mode, the capacity goals, and the cause of a shortfall.
fn print_summary(opts: &Options, runs: &[Run]) {
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
fn json_line(opts: &Options, runs: &[Run], codec: &str) -> String {
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
         \"p99_latency_ms\":{},\"window_s\":{},\"codec\":{},\"load_1m_max\":{}{}}}",
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
        if opts.quick { ",\"quick\":true" } else { "" },
    )
}

/// A quick run checks the workload, not capacity: every group run ended an event
/// and ran the detector in its window. The reasons it did not.
fn quick_problems(runs: &[Run]) -> Vec<String> {
    runs.iter()
        .filter(|r| r.mode != Mode::DecodeOnly)
        .filter_map(|r| {
            let mut missing = Vec::new();
            if r.events_ended == 0 {
                missing.push("no event ended");
            }
            if r.detections == 0 {
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

fn main() {
    let opts = bench_options(parse_args);
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
        let problems = quick_problems(&runs);
        if !problems.is_empty() {
            eprintln!("group (quick): {}", problems.join("; "));
            std::process::exit(1);
        }
    }
}
