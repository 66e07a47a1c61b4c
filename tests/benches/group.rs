//! Group benchmark (issue 8, "how many cameras one box carries"): the whole process
//! group — capture, motion, cascade and gate per camera, one cost map bridge — on N
//! cameras replaying `data/vtest.avi` at 25 fps in real time, N raised until a stage
//! falls behind.
//!
//! Two sources, each searched on its own:
//! * **predecoded**: `preload_frames = 25`, the frames decoded once into memory and
//!   published in a loop — what the stages cost without the decoder;
//! * **decode**: every camera decodes the file itself (`loop = true`).
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
//! * stage health from the `StageStatus` reports of capture, motion and cascade
//!   (every 5 s): rates from the `sent` counters of the first report in the window
//!   and the last one, and drops;
//! * the end-to-end latency capture → activity of the window, from every camera's
//!   `activity` samples as they reach the bench (the cascade's own p99 spans its
//!   last 512 outputs: at 1 Hz, the whole run including start-up).
//!
//! A run **holds** when no process died, every camera's capture and motion published
//! at least 95 % of 25 fps, motion and cascade dropped nothing, every camera's
//! activity arrived, and its p99 latency stayed under 1 s and did not grow over the
//! window (second half's p99 at most twice the first half's, or under 200 ms).
//!
//! Run: `cargo xtask bench group [-- OPTIONS]` (it builds the release binaries first),
//! or after `cargo build --release --workspace --bins`:
//! `cargo bench -p isochron-tests --bench group -- [OPTIONS]`. Options:
//! `--mode predecoded|decode|both` (both), `--per-process P` (cameras per service
//! process, 32), `--start N` (8), `--max N` (256), `--warmup S` (30), `--seconds S`
//! (10), `--quick` (two cameras per mode, warm-up 3 s, window 5 s: a check that the
//! bench runs, in any profile; options after it override it; the JSON line gets
//! `"quick":true`). The last line printed is one JSON object.

use std::fmt::Write as _;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use isochron_shared::clock::wall_now_ns;
use isochron_shared::health::quantile;
use isochron_shared::ipc::{Activity, Ipc, StatusSubscriber, StreamSubscriber};
use isochron_shared::topology::StageKind;
use isochron_shared::wire::StageStatus;
use isochron_tests::{Proc, TestSite, bin, vtest};

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
/// Frames the predecoded source decodes once (one second of video).
const PRELOAD_FRAMES: u32 = 25;

/// The per-camera services, in pipeline order, and the site-wide one.
const STAGES: [StageKind; 5] = StageKind::ALL;
/// Index of the cost map bridge in [`STAGES`].
const COSTMAP: usize = 4;
/// The stages whose status decides whether a run holds.
const HEALTH_STAGES: [StageKind; 3] = [StageKind::Capture, StageKind::Motion, StageKind::Cascade];

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

/// The source of the cameras.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Mode {
    /// Frames decoded once, published from memory.
    Predecoded,
    /// Every camera decodes the file.
    Decode,
}

impl Mode {
    fn name(self) -> &'static str {
        match self {
            Mode::Predecoded => "predecoded",
            Mode::Decode => "decode",
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
    /// `--quick`: a short run that only checks the bench works.
    quick: bool,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            modes: vec![Mode::Predecoded, Mode::Decode],
            per_process: 32,
            start: 8,
            max: 256,
            // Every camera replays the same video, so their first events (and
            // detections) start together: let that burst pass before measuring.
            warmup: Duration::from_secs(30),
            seconds: Duration::from_secs(10),
            quick: false,
        }
    }
}

impl Options {
    /// `--quick`: both modes, two cameras (in one process per stage) each, short
    /// warm-up and window.
    fn quick(self) -> Options {
        Options {
            start: 2,
            max: 2,
            warmup: Duration::from_secs(3),
            seconds: Duration::from_secs(5),
            quick: true,
            ..self
        }
    }
}

const USAGE: &str = "usage: group [--quick] [--mode predecoded|decode|both] [--per-process P] \
[--start N] [--max N] [--warmup SECONDS] [--seconds SECONDS]";

/// Parses the options; unknown flags (cargo passes `--bench`) are ignored.
fn parse_args(args: impl IntoIterator<Item = String>) -> Result<Options, String> {
    let mut o = Options::default();
    let mut args = args.into_iter();
    while let Some(arg) = args.next() {
        let (flag, inline) = match arg.split_once('=') {
            Some((f, v)) => (f.to_string(), Some(v.to_string())),
            None => (arg.clone(), None),
        };
        let known = [
            "--mode",
            "--per-process",
            "--start",
            "--max",
            "--warmup",
            "--seconds",
        ];
        if flag == "--help" || flag == "-h" {
            return Err(USAGE.into());
        }
        if flag == "--quick" {
            o = o.quick();
            continue;
        }
        if !known.contains(&flag.as_str()) {
            if flag != "--bench" {
                eprintln!("group: ignoring unknown argument '{arg}'");
            }
            continue;
        }
        let value = inline
            .or_else(|| args.next())
            .ok_or_else(|| format!("{flag} needs a value\n{USAGE}"))?;
        let count = || -> Result<usize, String> {
            value
                .parse::<usize>()
                .ok()
                .filter(|v| *v >= 1)
                .ok_or_else(|| format!("{flag}: expected a whole number ≥ 1, found '{value}'"))
        };
        let secs = || -> Result<Duration, String> {
            value
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite() && *v >= 0.0)
                .map(Duration::from_secs_f64)
                .ok_or_else(|| format!("{flag}: expected seconds ≥ 0, found '{value}'"))
        };
        match flag.as_str() {
            "--mode" => {
                o.modes = match value.as_str() {
                    "predecoded" => vec![Mode::Predecoded],
                    "decode" => vec![Mode::Decode],
                    "both" => vec![Mode::Predecoded, Mode::Decode],
                    _ => {
                        return Err(format!(
                            "--mode: expected predecoded, decode or both, found '{value}'"
                        ));
                    }
                }
            }
            "--per-process" => o.per_process = count()?,
            "--start" => o.start = count()?,
            "--max" => o.max = count()?,
            "--warmup" => o.warmup = secs()?,
            "--seconds" => o.seconds = secs()?.max(Duration::from_secs(1)),
            _ => unreachable!("checked against `known`"),
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

/// The site config (after `[site]`) for `cameras` in `mode`.
fn site_body(mode: Mode, cameras: &[String], video: &Path) -> String {
    let source = serde_json::to_string(&video.display().to_string()).unwrap_or_default();
    let mut body = format!(
        "[gate.detector]\nhog_upscale = 1.5\n\n\
         [costmap]\norigin_x_m = -22.0\norigin_y_m = -18.0\nresolution_m = 0.1\n\
         width_cells = 320\nheight_cells = 300\nframe_id = \"map\"\n\
         topic = \"/isochron/bench_costmap\"\nros_domain_id = {}\n\
         dds_interfaces = [\"127.0.0.1\"]\n",
        ros_domain()
    );
    for id in cameras {
        let _ = write!(
            body,
            "\n[[camera]]\nid = \"{id}\"\nsource = {source}\nfps = {FPS:.1}\nloop = true\n"
        );
        if mode == Mode::Predecoded {
            let _ = writeln!(body, "preload_frames = {PRELOAD_FRAMES}");
        }
        let _ = writeln!(body, "{FLOOR_POINTS}");
    }
    body
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
    /// (consumers before producers) one process per `per_process` cameras.
    fn spawn(site: &TestSite, cameras: &[String], per_process: usize) -> Group {
        let mut members = vec![Member {
            stage: COSTMAP,
            cameras: String::new(),
            proc: site.spawn("isochron-costmap", &[]),
        }];
        for stage in (0..COSTMAP).rev() {
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

/// utime + stime of process `pid`, in clock ticks.
fn cpu_ticks(pid: u32) -> Option<u64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // The command (field 2) may hold spaces: count fields after its ')'.
    let rest = &stat[stat.rfind(')')? + 1..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    // Fields from 3 (state) on: utime is field 14, stime 15.
    let utime: u64 = fields.get(11)?.parse().ok()?;
    let stime: u64 = fields.get(12)?.parse().ok()?;
    Some(utime + stime)
}

/// Clock ticks per second.
fn clock_ticks_per_s() -> f64 {
    // SAFETY: sysconf has no preconditions.
    let ticks = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    if ticks > 0 { ticks as f64 } else { 100.0 }
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

/// Raises the soft limit of open files to the hard one: hundreds of iceoryx2
/// services in the bench and in processes serving many cameras (children inherit).
fn raise_open_file_limit() {
    // SAFETY: getrlimit/setrlimit on a valid struct.
    unsafe {
        let mut lim = libc::rlimit {
            rlim_cur: 0,
            rlim_max: 0,
        };
        if libc::getrlimit(libc::RLIMIT_NOFILE, &mut lim) == 0 && lim.rlim_cur < lim.rlim_max {
            lim.rlim_cur = lim.rlim_max;
            libc::setrlimit(libc::RLIMIT_NOFILE, &lim);
        }
    }
}

/// The status reports of one stage of one camera within the measurement window.
struct Track {
    subscriber: StatusSubscriber,
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

/// The status reports of [`HEALTH_STAGES`] for every camera.
struct StatusBoard {
    /// Per camera, per health stage.
    tracks: Vec<Vec<Track>>,
}

impl StatusBoard {
    fn open(ipc: &Ipc, cameras: &[String]) -> Result<StatusBoard, String> {
        let mut tracks = Vec::with_capacity(cameras.len());
        for camera in cameras {
            let mut per_stage = Vec::with_capacity(HEALTH_STAGES.len());
            for stage in HEALTH_STAGES {
                let subscriber = ipc
                    .status_subscriber(camera, stage)
                    .map_err(|e| format!("status of {stage}/{camera}: {e}"))?;
                per_stage.push(Track {
                    subscriber,
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
                && report.report_wall_ns >= since_ns
            {
                track.first.get_or_insert(report);
                track.last = Some(report);
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
    /// Lowest motion rate of any camera, frames/s.
    min_fps: Option<f64>,
    /// Samples motion and cascade dropped in the window.
    drops: Option<u64>,
    /// p99 latency capture → activity over all cameras in the window, ms.
    p99_ms: Option<f32>,
    /// Private memory of the group per camera, MB.
    private_mb_per_camera: Option<f64>,
    /// Private memory per stage ([`STAGES`]) per camera, MB.
    private_mb_per_stage: Option<[f64; 5]>,
    /// Growth of the memory in use in `/dev/shm` per camera, MB.
    shm_mb_per_camera: Option<f64>,
    /// Growth of the size of the files in `/dev/shm` per camera, MB.
    shm_mapped_mb_per_camera: Option<f64>,
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
            drops: None,
            p99_ms: None,
            private_mb_per_camera: None,
            private_mb_per_stage: None,
            shm_mb_per_camera: None,
            shm_mapped_mb_per_camera: None,
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

/// Processes the group has for `n` cameras, `per_process` per process.
fn process_count(n: usize, per_process: usize) -> usize {
    4 * n.div_ceil(per_process) + 1
}

/// Runs the group on `n` cameras in `mode` and measures it.
fn run_group(opts: &Options, mode: Mode, n: usize) -> Run {
    let cameras = camera_ids(n);
    let run = Run::new(mode, n, process_count(n, opts.per_process));
    let video = vtest();
    let site = TestSite::new(
        &format!("group-{}-{n}", mode.name()),
        &site_body(mode, &cameras, &video),
    );
    remove_stale_nodes();
    let ipc = site.ipc("bench");
    let shm_before = ShmUsage::now();
    let opened = StatusBoard::open(&ipc, &cameras)
        .and_then(|board| Ok((board, LatencyProbe::open(&ipc, &cameras)?)));
    let (mut board, mut probe) = match opened {
        Ok(o) => o,
        Err(e) => return run.fail(e),
    };
    eprintln!(
        "group: {} N={n}: starting {} processes",
        mode.name(),
        run.processes
    );
    let mut group = Group::spawn(&site, &cameras, opts.per_process);
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
    match isochron_shared::ipc::node_census(true) {
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
    probe: &'a mut LatencyProbe,
}

/// What [`Watch::until`] takes in while it waits.
#[derive(Debug, Clone, Copy)]
struct Intake {
    /// Status reports made from this wall-clock time (ns) on count.
    reports_since_ns: i64,
    /// Activity latencies are recorded (else only drained).
    latencies: bool,
}

impl Intake {
    /// Warm-up: nothing counts.
    const NOTHING: Intake = Intake {
        reports_since_ns: i64::MAX,
        latencies: false,
    };
}

impl Watch<'_> {
    /// Waits until `until`, reading the activity streams every [`PROBE_POLL`] and,
    /// every [`POLL`], the status reports and whether a process died.
    fn until(&mut self, until: Instant, intake: Intake) -> Result<(), String> {
        let mut next_check = Instant::now();
        loop {
            if interrupted() {
                return Err("interrupted".into());
            }
            self.probe.poll(intake.latencies);
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
        latencies: true,
    };
    let t0 = Instant::now();
    let cpu0 = watch.group.cpu_ticks();
    if let Err(dead) = watch.until(t0 + opts.seconds, in_window) {
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
        latencies: false,
        ..in_window
    };
    while !watch.board.complete() && Instant::now() < extra {
        if let Err(dead) = watch.until(Instant::now() + POLL, after_window) {
            return run.fail(dead);
        }
    }
    let run = evaluate_status(run, watch.board);
    evaluate_latency(run, watch.probe, window)
}

/// The capture → activity latency as the bench sees it: every camera's `activity`
/// samples as they arrive here (read every [`PROBE_POLL`]), minus the time capture
/// published the last frame of the second they cover. The cascade's own status has
/// this latency too, but over its last 512 outputs — at 1 Hz, the whole run with
/// its start-up — so the bench measures the window itself.
struct LatencyProbe {
    subscribers: Vec<StreamSubscriber<Activity>>,
    /// Arrival (wall clock, ns), camera and latency (ms) of each sample in the window.
    samples: Vec<(i64, usize, f32)>,
}

impl LatencyProbe {
    fn open(ipc: &Ipc, cameras: &[String]) -> Result<LatencyProbe, String> {
        let subscribers = cameras
            .iter()
            .map(|camera| {
                ipc.subscriber::<Activity>(camera)
                    .map_err(|e| format!("activity of {camera}: {e}"))
            })
            .collect::<Result<_, _>>()?;
        Ok(LatencyProbe {
            subscribers,
            samples: Vec::new(),
        })
    }

    /// Takes every waiting sample; records their latencies if `record`.
    fn poll(&mut self, record: bool) {
        for (camera, subscriber) in self.subscribers.iter().enumerate() {
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
    }
}

/// Indices in [`HEALTH_STAGES`].
const CAPTURE: usize = 0;
const MOTION: usize = 1;
const CASCADE: usize = 2;

/// What two status reports of one stage of one camera say about the window.
struct Window {
    /// Samples published per second.
    rate: f64,
    /// Samples dropped (here or upstream).
    dropped: u64,
}

impl Track {
    /// The window between the first and the last report, if there were two.
    fn window(&self) -> Option<Window> {
        let (a, b) = self.span()?;
        let seconds = (b.report_wall_ns - a.report_wall_ns) as f64 / 1e9;
        Some(Window {
            rate: b.sent.saturating_sub(a.sent) as f64 / seconds,
            dropped: b.dropped.saturating_sub(a.dropped),
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
    let min_rate = FPS * MIN_RATE_SHARE;
    let lower = |a: f64, b: f64| a < b;
    let higher = |a: f64, b: f64| a > b;
    let mut silent: [Offenders; 3] = Default::default();
    let mut slow: [Offenders; 3] = Default::default();
    let mut dropping: [Offenders; 3] = Default::default();
    let (mut min_fps, mut drops) = (f64::INFINITY, 0u64);

    for (i, per_stage) in board.tracks.iter().enumerate() {
        for (s, track) in per_stage.iter().enumerate() {
            let Some(w) = track.window() else {
                silent[s].add_camera(i);
                continue;
            };
            if s != CASCADE && w.rate < min_rate {
                slow[s].add(i, w.rate, lower);
            }
            if s == MOTION {
                min_fps = min_fps.min(w.rate);
            }
            if s != CAPTURE && w.dropped > 0 {
                drops += w.dropped;
                dropping[s].add(i, w.dropped as f64, higher);
            }
        }
    }

    if silent[MOTION].cameras.is_empty() {
        run.min_fps = Some(min_fps);
    }
    if silent[MOTION].cameras.is_empty() && silent[CASCADE].cameras.is_empty() {
        run.drops = Some(drops);
    }
    for (s, stage) in HEALTH_STAGES.iter().enumerate() {
        let reasons = [
            silent[s].reason(
                &format!("{stage} made fewer than 2 status reports in the window"),
                "",
                &cameras,
            ),
            slow[s].reason(
                &format!("{stage} below {min_rate:.2} fps"),
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
fn evaluate_latency(mut run: Run, probe: &LatencyProbe, window: (i64, i64)) -> Run {
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

/// Formats an optional number with `decimals`, `-` when missing.
fn opt(v: Option<f64>, decimals: usize) -> String {
    v.map_or_else(|| "-".into(), |v| format!("{v:.decimals$}"))
}

/// The table's columns: title and width (the first is left-aligned).
const COLUMNS: [(&str, usize); 17] = [
    ("mode", 10),
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
    ("drops", 5),
    ("p99 ms", 6),
    ("priv MB/c", 9),
    ("shm MB/c", 8),
    ("map MB/c", 8),
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

fn print_header(opts: &Options) {
    println!(
        "group benchmark: {FPS} fps per camera (vtest.avi, real time), {} camera(s) per \
         service process, warm-up {:.0} s, window {:.0} s",
        opts.per_process,
        opts.warmup.as_secs_f64(),
        opts.seconds.as_secs_f64()
    );
    println!(
        "CPU in % of one core. priv MB/c: Private_Clean+Private_Dirty of all the group's \
         processes / N, excluding shared memory. shm MB/c: growth of the memory in use in \
         /dev/shm / N; map MB/c: growth of the size of its files (what is mapped, the most \
         it can come to) / N. min fps: slowest camera's motion output."
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
        r.drops.map_or_else(|| "-".into(), |d| d.to_string()),
        opt(r.p99_ms.map(f64::from), 0),
        opt(r.private_mb_per_camera, 1),
        opt(r.shm_mb_per_camera, 1),
        opt(r.shm_mapped_mb_per_camera, 1),
        held,
    ]);
    println!("{}", table_line(&cells));
}

/// Raises N for `mode` until a run fails, bisects once, and returns every run.
fn search(opts: &Options, mode: Mode) -> Vec<Run> {
    let mut runs = Vec::new();
    let mut once = |n: usize| {
        if interrupted() {
            return false;
        }
        let run = run_group(opts, mode, n);
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

/// One line per mode: the most cameras that held, and what they took.
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
             per camera {} MB private, {} MB shared memory in use of {} MB mapped)",
            mode.name(),
            r.cameras,
            r.processes,
            cpu / r.cameras as f64,
            opt(r.private_mb_per_camera, 1),
            opt(r.shm_mb_per_camera, 1),
            opt(r.shm_mapped_mb_per_camera, 1),
        );
        if let Some(per_stage) = r.private_mb_per_stage {
            let parts: Vec<String> = STAGES
                .iter()
                .zip(per_stage)
                .map(|(stage, mb)| format!("{stage} {mb:.1}"))
                .collect();
            println!("  private MB per camera by stage: {}", parts.join(", "));
        }
    }
}

/// The held run of `mode` with the most cameras.
fn best(runs: &[Run], mode: Mode) -> Option<&Run> {
    runs.iter()
        .filter(|r| r.mode == mode && r.held())
        .max_by_key(|r| r.cameras)
}

/// The closing JSON line (keys in a fixed order; `null` for what was not measured).
fn json_line(opts: &Options, runs: &[Run]) -> String {
    let cameras = |mode: Mode| {
        if opts.modes.contains(&mode) {
            best(runs, mode).map_or(0, |r| r.cameras).to_string()
        } else {
            "null".to_string()
        }
    };
    let number = |v: Option<f64>| v.map_or_else(|| "null".to_string(), |v| format!("{v:.1}"));
    let pre = best(runs, Mode::Predecoded);
    format!(
        "{{\"bench\":\"group\",\"cameras_predecoded\":{},\"cameras_decode\":{},\"rss_mb_per_camera\":{},\"shm_mb_per_camera\":{},\"p99_latency_ms\":{}{}}}",
        cameras(Mode::Predecoded),
        cameras(Mode::Decode),
        number(pre.and_then(|r| r.private_mb_per_camera)),
        number(pre.and_then(|r| r.shm_mb_per_camera)),
        number(pre.and_then(|r| r.p99_ms).map(f64::from)),
        if opts.quick { ",\"quick\":true" } else { "" },
    )
}

fn main() {
    let opts = match parse_args(std::env::args().skip(1)) {
        Ok(o) => o,
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(2);
        }
    };
    // Fail early, with what to do, when something is missing.
    for stage in STAGES {
        bin(&format!("isochron-{stage}"));
    }
    vtest();
    raise_open_file_limit();
    catch_interrupts();

    print_header(&opts);
    let mut runs = Vec::new();
    for &mode in &opts.modes {
        runs.extend(search(&opts, mode));
    }
    if interrupted() {
        println!("\ninterrupted: the results are incomplete");
    }
    print_summary(&opts, &runs);
    println!("{}", json_line(&opts, &runs));
}
