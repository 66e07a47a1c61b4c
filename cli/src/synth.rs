//! `isochron synth --camera ID --profile CSV --days N --out DIR [--fps F] [--grid WxH]
//! [--start DATE] [--seed S]`: days of synthetic motion through a real isochron-cascade,
//! leaving its long-term store in DIR.
//!
//! People cross the view along straight lines between random points on two edges of
//! the block grid, some pausing on the way (in-place activity); their arrivals per
//! minute follow the profile CSV (`minute_of_day,activity` rows, activity in 0..1,
//! linearly interpolated between rows, around midnight too), scaled so that activity 1
//! is `--arrivals-per-min` people per minute. Time comes from the generated headers
//! (`--start`, `--fps`), so days run as fast as the cascade consumes them.
//!
//! The run writes `DIR/synth.toml` (a private service prefix, lossless delivery,
//! `site.state_dir = DIR`), starts `isochron-cascade` on it (log in
//! `DIR/cascade.log`), publishes the motion without dropping any — a frame the cascade
//! did not take is sent again — and restarts the cascade if it dies (for crash tests;
//! each start prints `cascade started pid=N`). At the end it sends end of stream,
//! waits until the cascade has filtered and stored everything (its end-of-stream
//! activity sample), stops it, and leaves the store `DIR/<camera>.isochron.sqlite`.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitCode, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, mpsc};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use indicatif::{ProgressBar, ProgressStyle};
use isochron_config::clock::{NS_PER_S, format_rfc3339, parse_rfc3339, wall_now_ns};
use isochron_config::{CameraConfig, Config, IpcConfig};
use isochron_exit as exit;
use isochron_runtime::ipc::{Activity, Ipc, Motion, StreamPublisher};
use isochron_runtime::names::ServiceNames;
use isochron_runtime::topology::StageKind;
use isochron_store::{Store, store_path};
use isochron_wire::{
    BlockMotion, CameraId, DIRECTION_NONE, FLAG_END_OF_STREAM, MotionHeader, Preamble, Stream,
    is_valid_camera_id,
};

/// Synthetic days of motion through a real isochron-cascade.
#[derive(clap::Args)]
pub struct Args {
    /// Camera id.
    #[arg(long)]
    camera: String,
    /// Activity profile: CSV rows `minute_of_day,activity` (activity 0..1).
    #[arg(long)]
    profile: PathBuf,
    /// Days to simulate (fractions allowed).
    #[arg(long)]
    days: f64,
    /// Output directory: config, cascade log and the long-term store (created).
    #[arg(long)]
    out: PathBuf,
    /// Frames per second of the synthetic camera.
    #[arg(long, default_value_t = 5.0)]
    fps: f64,
    /// Block grid, `WxH` (blocks of 16 px).
    #[arg(long, default_value = "40x30")]
    grid: String,
    /// Capture time of the first frame: a date (`2026-01-05`, midnight UTC) or an
    /// RFC 3339 time.
    #[arg(long, default_value = "2026-01-05")]
    start: String,
    /// Seed of the random people.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// People arriving per minute at activity 1.
    #[arg(long, default_value_t = 30.0)]
    arrivals_per_min: f64,
    /// Fraction of people who stop on their way for 5 to 40 s.
    #[arg(long, default_value_t = 0.1)]
    standing: f64,
}

/// Block edge of the synthetic frames, pixels.
const BLOCK_PX: u32 = 16;
/// How long the cascade may take no frame before the run fails.
const STALL: Duration = Duration::from_secs(120);
/// How often the cascade process is checked while frames flow.
const CHECK_EVERY: u64 = 256;

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    if !is_valid_camera_id(&args.camera) {
        bail!(
            "--camera: expected 1 to 24 characters of letters, digits, '_' or '-', found '{}'",
            args.camera
        );
    }
    if !(args.fps.is_finite() && args.fps > 0.0 && args.fps <= 1000.0) {
        bail!(
            "--fps: expected a number from 0 to 1000, found {}",
            args.fps
        );
    }
    if !(args.days.is_finite() && args.days > 0.0 && args.days <= 3650.0) {
        bail!(
            "--days: expected a number from 0 to 3650, found {}",
            args.days
        );
    }
    if !(args.arrivals_per_min.is_finite() && args.arrivals_per_min >= 0.0) {
        bail!("--arrivals-per-min: expected a number >= 0");
    }
    if !(0.0..=1.0).contains(&args.standing) {
        bail!("--standing: expected a fraction from 0 to 1");
    }
    let (grid_w, grid_h) = parse_grid(&args.grid)?;
    let start_ns = parse_start(&args.start)?;
    let profile = Profile::load(&args.profile)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let out = args.out.canonicalize()?;
    let config_path = write_config(&out, &args.camera)?;
    let prefix = Config::load(&config_path)?.config.site.service_prefix;

    let k = (grid_w * grid_h) as usize;
    let ipc = Ipc::new(
        "isochron-synth",
        ServiceNames::new(&prefix),
        IpcConfig {
            lossless: true,
            // Not a drop: a frame the cascade did not take within this time is sent
            // again, after checking that the cascade is alive.
            lossless_timeout_s: 0.5,
            ..IpcConfig::default()
        },
    )?;
    let mut motion = ipc.publisher::<Motion>(&args.camera, k)?;
    let activity = ActivityTally::start(&prefix, &args.camera)?;
    let mut cascade = CascadeProc::new(&config_path, &args.camera, &out.join("cascade.log"))?;
    let pb = progress_bar(args.days, args.fps);
    cascade.start(&pb)?;
    cascade.wait_subscribed(&motion, &pb)?;

    let total = (args.days * 86_400.0 * args.fps).round() as u64;
    pb.set_length(total);
    let camera_id = CameraId::new(&args.camera).expect("checked");
    let mut synth = Synth::new(
        grid_w,
        grid_h,
        args.fps,
        args.seed,
        args.arrivals_per_min,
        args.standing,
    );
    let mut blocks = vec![BlockMotion::default(); k];
    let started = Instant::now();
    let mut resent = 0u64;
    for i in 0..total {
        let t_ns = start_ns + (i as f64 * 1e9 / args.fps).round() as i64;
        let minute_of_day = (t_ns.rem_euclid(86_400 * NS_PER_S)) as f64 / 60e9;
        let changed = synth.frame(profile.at(minute_of_day), &mut blocks);
        let mut preamble =
            Preamble::new::<BlockMotion>(Stream::Motion, camera_id, motion.next_sequence(), k);
        preamble.capture_time_ns = t_ns;
        preamble.origin_wall_ns = wall_now_ns();
        let header = MotionHeader {
            preamble,
            frame_width: grid_w * BLOCK_PX,
            frame_height: grid_h * BLOCK_PX,
            block_px: BLOCK_PX,
            grid_w,
            grid_h,
            changed_fraction: changed as f32 / k as f32,
            source_index: i,
        };
        resent += deliver(&mut motion, header, &blocks, &mut cascade, &pb)?;
        if i % CHECK_EVERY == 0 {
            cascade.check(&motion, &pb)?;
            pb.set_position(i);
            pb.set_message(sim_time(start_ns, t_ns, args.days));
        }
    }
    pb.set_position(total);

    // End of stream, then wait until the cascade has stored everything.
    let end_ns = start_ns + (total as f64 * 1e9 / args.fps).round() as i64;
    let mut preamble =
        Preamble::new::<BlockMotion>(Stream::Motion, camera_id, motion.next_sequence(), 0);
    preamble.capture_time_ns = end_ns;
    preamble.flags = FLAG_END_OF_STREAM;
    let eos = MotionHeader {
        preamble,
        ..Default::default()
    };
    pb.set_message("waiting for the cascade to store the last minute");
    let mut since = Instant::now();
    deliver(&mut motion, eos, &[], &mut cascade, &pb)?;
    while !activity.ended.load(Ordering::Acquire) {
        if cascade.check(&motion, &pb)? {
            // Restarted before it got to the end of stream: send it again.
            deliver(&mut motion, eos, &[], &mut cascade, &pb)?;
            since = Instant::now();
        }
        cascade.stalled(since, "did not finish after the end of stream")?;
        std::thread::sleep(Duration::from_millis(10));
    }
    let wall = started.elapsed();
    cascade.stop();
    let seconds = activity.stop();
    pb.finish_and_clear();

    let store = store_path(&out, &args.camera);
    println!(
        "synth: {} days of {} at {} fps on a {grid_w}x{grid_h} grid from {}",
        args.days,
        args.profile.display(),
        args.fps,
        format_rfc3339(start_ns)
    );
    println!(
        "synth: {total} frames in {:.1} s ({:.0} frames/s, {:.1} simulated days per minute), {seconds} activity seconds, {} frames sent again, {} cascade restarts",
        wall.as_secs_f64(),
        total as f64 / wall.as_secs_f64().max(1e-9),
        args.days / wall.as_secs_f64().max(1e-9) * 60.0,
        resent,
        cascade.starts - 1
    );
    let s = Store::open_read_only(&store, &args.camera)?;
    let model = s.read_model()?;
    let progress = s.progress()?;
    let (lo, hi) = model.learned().fold((u32::MAX, 0), |(lo, hi), b| {
        (lo.min(b.count), hi.max(b.count))
    });
    println!(
        "synth: store {}: {} bins learned ({}..{} days each), {} minutes learned, {} skipped",
        store.display(),
        model.learned().count(),
        if hi == 0 { 0 } else { lo },
        hi,
        progress.committed,
        progress.skipped
    );
    Ok(ExitCode::SUCCESS)
}

/// Sends one sample until the cascade has taken it; returns how often it was sent
/// again. A frame not taken means the cascade is stalled, restarting or dead: it is
/// checked (and restarted) before the frame goes out again.
fn deliver(
    motion: &mut StreamPublisher<Motion>,
    header: MotionHeader,
    blocks: &[BlockMotion],
    cascade: &mut CascadeProc,
    pb: &ProgressBar,
) -> anyhow::Result<u64> {
    let mut again = 0;
    let since = Instant::now();
    loop {
        let delivered = motion.send_copy(header, blocks)?;
        if delivered > 0 {
            return Ok(again);
        }
        again += 1;
        cascade.check(motion, pb)?;
        cascade.stalled(since, "took no frame")?;
        std::thread::sleep(Duration::from_millis(2));
    }
}

fn progress_bar(days: f64, fps: f64) -> ProgressBar {
    let pb = ProgressBar::new(0);
    pb.set_style(
        ProgressStyle::with_template(
            "{spinner} {elapsed_precise} [{bar:30}] {percent:>3}% {msg} ({per_sec}, eta {eta})",
        )
        .expect("valid template")
        .progress_chars("=> "),
    );
    pb.set_message(format!("{days} days at {fps} fps"));
    pb.enable_steady_tick(Duration::from_millis(200));
    pb
}

/// `day 3/14 08:42` for the progress bar.
fn sim_time(start_ns: i64, t_ns: i64, days: f64) -> String {
    let elapsed = (t_ns - start_ns).max(0);
    let day = elapsed / (86_400 * NS_PER_S) + 1;
    let minute = t_ns.rem_euclid(86_400 * NS_PER_S) / (60 * NS_PER_S);
    format!(
        "day {day}/{} {:02}:{:02}",
        days.ceil() as i64,
        minute / 60,
        minute % 60
    )
}

/// `WxH` → (W, H).
fn parse_grid(text: &str) -> anyhow::Result<(u32, u32)> {
    let parsed = text
        .split_once(['x', 'X'])
        .and_then(|(w, h)| Some((w.trim().parse::<u32>().ok()?, h.trim().parse::<u32>().ok()?)));
    match parsed {
        Some((w, h)) if (1..=512).contains(&w) && (1..=512).contains(&h) => Ok((w, h)),
        _ => {
            bail!("--grid: expected WxH with 1 to 512 blocks each way (e.g. 40x30), found '{text}'")
        }
    }
}

/// A date (midnight UTC) or an RFC 3339 time → UTC ns.
fn parse_start(text: &str) -> anyhow::Result<i64> {
    // jiff also reads the date out of a full time stamp: only a bare date is a date.
    if !text.contains(['T', 't', ' '])
        && let Ok(date) = text.parse::<jiff::civil::Date>()
    {
        return Ok(date
            .to_zoned(jiff::tz::TimeZone::UTC)
            .context("--start: date out of range")?
            .timestamp()
            .as_nanosecond() as i64);
    }
    parse_rfc3339(text).map_err(|e| {
        anyhow::anyhow!(
            "--start: expected a date (2026-01-05) or an RFC 3339 time (2026-01-05T06:00:00Z), found '{text}': {e}"
        )
    })
}

/// Writes `DIR/synth.toml`: the camera, a private prefix, lossless delivery, the store
/// in DIR. Returns its path.
fn write_config(out: &Path, camera: &str) -> anyhow::Result<PathBuf> {
    let mut config = Config::default();
    config.site.name = "synth".into();
    config.site.service_prefix = format!("isochron-synth-{}", std::process::id());
    config.site.state_dir = out.to_path_buf();
    config.ipc.lossless = true;
    let cam: CameraConfig = toml::from_str(&format!("id = \"{camera}\"\nsource = \"synthetic\"\n"))
        .context("building the camera section")?;
    config.cameras = vec![cam];
    let path = out.join("synth.toml");
    std::fs::write(&path, toml::to_string_pretty(&config)?)
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(path)
}

/// The profile: activity (0..1) per minute of the day, linear between rows.
#[derive(Debug, Clone, PartialEq)]
pub struct Profile {
    rows: Vec<(f64, f64)>,
}

impl Profile {
    /// Reads `minute_of_day,activity` rows (a header line is allowed).
    pub fn load(path: &Path) -> anyhow::Result<Profile> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("--profile: cannot read {}", path.display()))?;
        Profile::parse(&text).with_context(|| format!("--profile {}", path.display()))
    }

    /// Parses CSV text.
    pub fn parse(text: &str) -> anyhow::Result<Profile> {
        let mut rows = Vec::new();
        for (i, line) in text.lines().enumerate() {
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let mut fields = line.split(',').map(str::trim);
            let (Some(a), Some(b)) = (fields.next(), fields.next()) else {
                bail!(
                    "line {}: expected `minute_of_day,activity`, found '{line}'",
                    i + 1
                );
            };
            let (Ok(minute), Ok(activity)) = (a.parse::<f64>(), b.parse::<f64>()) else {
                if rows.is_empty() && a.parse::<f64>().is_err() {
                    continue; // the header
                }
                bail!("line {}: expected two numbers, found '{line}'", i + 1);
            };
            if !(0.0..1440.0).contains(&minute) {
                bail!("line {}: minute_of_day {minute} is outside 0..1440", i + 1);
            }
            if !(0.0..=1.0).contains(&activity) {
                bail!("line {}: activity {activity} is outside 0..1", i + 1);
            }
            rows.push((minute, activity));
        }
        if rows.is_empty() {
            bail!("no `minute_of_day,activity` rows");
        }
        rows.sort_by(|a, b| a.0.total_cmp(&b.0));
        rows.dedup_by(|a, b| a.0 == b.0);
        Ok(Profile { rows })
    }

    /// Activity at `minute` of the day (fractional), interpolated linearly between the
    /// rows, across midnight too.
    pub fn at(&self, minute: f64) -> f64 {
        let rows = &self.rows;
        let m = minute.rem_euclid(1440.0);
        let after = rows.partition_point(|r| r.0 <= m);
        let (a, b) = match after {
            0 => (rows[rows.len() - 1], rows[0]),
            n if n == rows.len() => (rows[n - 1], rows[0]),
            n => (rows[n - 1], rows[n]),
        };
        let span = (b.0 - a.0).rem_euclid(1440.0);
        if span == 0.0 {
            return a.1;
        }
        let f = (m - a.0).rem_euclid(1440.0) / span;
        a.1 + f * (b.1 - a.1)
    }
}

/// SplitMix64: a small, good, seedable generator.
struct Rng(u64);

impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    fn f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.f64()
    }

    /// Poisson-distributed count with mean `lambda` (small).
    fn poisson(&mut self, lambda: f64) -> u32 {
        if lambda <= 0.0 {
            return 0;
        }
        let (mut k, mut p) = (0u32, (-lambda).exp());
        let mut s = p;
        let u = self.f64();
        while u > s && k < 1000 {
            k += 1;
            p *= lambda / k as f64;
            s += p;
        }
        k
    }
}

/// One synthetic person.
struct Person {
    x: f64,
    y: f64,
    /// Unit direction.
    ux: f64,
    uy: f64,
    /// Blocks per frame.
    step: f64,
    /// Density while walking.
    density: f32,
    /// Steps left until the pause (if any), then frames of pause left.
    steps_to_pause: Option<u32>,
    pause_frames: u32,
}

/// The synthetic scene: people crossing the block grid.
struct Synth {
    w: u32,
    h: u32,
    fps: f64,
    rng: Rng,
    arrivals_per_min: f64,
    standing: f64,
    people: Vec<Person>,
}

impl Synth {
    fn new(w: u32, h: u32, fps: f64, seed: u64, arrivals_per_min: f64, standing: f64) -> Self {
        Synth {
            w,
            h,
            fps,
            rng: Rng(seed ^ 0x6A09_E667_F3BC_C908),
            arrivals_per_min,
            standing,
            people: Vec::new(),
        }
    }

    /// A point on edge `e` (0 top, 1 right, 2 bottom, 3 left), in block units.
    fn edge_point(&mut self, e: u32) -> (f64, f64) {
        let (w, h) = (self.w as f64, self.h as f64);
        let u = self.rng.f64();
        match e {
            0 => (u * w, 0.0),
            1 => (w - 1e-6, u * h),
            2 => (u * w, h - 1e-6),
            _ => (0.0, u * h),
        }
    }

    fn spawn(&mut self) {
        let from = (self.rng.f64() * 4.0) as u32 % 4;
        let to = (from + 1 + (self.rng.f64() * 3.0) as u32 % 3) % 4;
        let (x0, y0) = self.edge_point(from);
        let (x1, y1) = self.edge_point(to);
        let (dx, dy) = (x1 - x0, y1 - y0);
        let len = (dx * dx + dy * dy).sqrt().max(1e-3);
        let speed = self.rng.range(1.5, 4.0); // blocks per second
        let step = speed / self.fps;
        let steps_to_pause = (self.rng.f64() < self.standing)
            .then(|| (len * self.rng.range(0.3, 0.7) / step) as u32);
        let pause_frames = (self.rng.range(5.0, 40.0) * self.fps) as u32;
        self.people.push(Person {
            x: x0,
            y: y0,
            ux: dx / len,
            uy: dy / len,
            step,
            density: self.rng.range(0.35, 0.7) as f32,
            steps_to_pause,
            pause_frames,
        });
    }

    /// Fills one frame: new arrivals at `activity` (0..1), everyone moves one frame.
    /// Returns the number of blocks with motion.
    fn frame(&mut self, activity: f64, blocks: &mut [BlockMotion]) -> usize {
        blocks.fill(BlockMotion::default());
        let lambda = self.arrivals_per_min * activity / (60.0 * self.fps);
        for _ in 0..self.rng.poisson(lambda) {
            self.spawn();
        }
        let (w, h) = (self.w, self.h);
        let mut people = std::mem::take(&mut self.people);
        let mut changed = 0;
        people.retain_mut(|p| {
            let pausing = match &mut p.steps_to_pause {
                Some(0) if p.pause_frames > 0 => {
                    p.pause_frames -= 1;
                    true
                }
                Some(n) if *n > 0 => {
                    *n -= 1;
                    false
                }
                _ => false,
            };
            if !pausing {
                p.x += p.ux * p.step;
                p.y += p.uy * p.step;
            }
            if p.x < 0.0 || p.y < 0.0 || p.x >= w as f64 || p.y >= h as f64 {
                return false;
            }
            let (bx, by) = (p.x as u32, p.y as u32);
            let (d, ux, uy) = if pausing {
                // Someone standing moves a little, in no particular direction.
                let d = self.rng.range(0.12, 0.28) as f32;
                let a = self.rng.f64() * std::f64::consts::TAU;
                (d, a.cos() * 0.3, a.sin() * 0.3)
            } else {
                (p.density, p.ux * 0.9, p.uy * 0.9)
            };
            changed += mark(blocks, w, bx, by, d, ux, uy);
            if by > 0 {
                // The upper body, one block up.
                changed += mark(blocks, w, bx, by - 1, 0.6 * d, ux, uy);
            }
            true
        });
        self.people = people;
        changed
    }
}

/// Puts motion `d` with direction (ux, uy) (|u| <= 1) into block (x, y), keeping the
/// stronger of two overlapping people. Returns 1 if the block was still.
fn mark(blocks: &mut [BlockMotion], w: u32, x: u32, y: u32, d: f32, ux: f64, uy: f64) -> usize {
    let b = &mut blocks[(y * w + x) as usize];
    let was_still = b.density == 0.0;
    if d > b.density {
        let (dx, dy) = (d * ux as f32, d * uy as f32);
        b.density = d;
        b.dx = dx;
        b.dy = dy;
        b.direction = direction_label(dx, dy);
    }
    was_still as usize
}

/// 8-way label of a flow vector (0 = right, counter-clockwise on screen, y down).
fn direction_label(dx: f32, dy: f32) -> u8 {
    if dx.hypot(dy) < 1e-3 {
        return DIRECTION_NONE;
    }
    let angle = (-dy).atan2(dx).to_degrees();
    ((angle / 45.0).round() as i32).rem_euclid(8) as u8
}

/// The cascade process, restarted when it dies.
struct CascadeProc {
    program: PathBuf,
    config: PathBuf,
    camera: String,
    log: PathBuf,
    child: Option<Child>,
    started_at: Instant,
    starts: u32,
    quick_failures: u32,
}

impl CascadeProc {
    /// Errors, saying the cascade `what` and where its log is, once [`STALL`] has
    /// passed since `since`.
    fn stalled(&self, since: Instant, what: &str) -> anyhow::Result<()> {
        if since.elapsed() > STALL {
            bail!(
                "the cascade {what} within {} s; see {}",
                STALL.as_secs(),
                self.log.display()
            );
        }
        Ok(())
    }

    fn new(config: &Path, camera: &str, log: &Path) -> anyhow::Result<Self> {
        let program = crate::launch::bin_dir().join(StageKind::Cascade.binary());
        if !program.is_file() {
            bail!(
                "{} is not installed (build it with `cargo build --bins`, or set ISOCHRON_BIN_DIR)",
                program.display()
            );
        }
        Ok(CascadeProc {
            program,
            config: config.to_path_buf(),
            camera: camera.to_string(),
            log: log.to_path_buf(),
            child: None,
            started_at: Instant::now(),
            starts: 0,
            quick_failures: 0,
        })
    }

    fn start(&mut self, pb: &ProgressBar) -> anyhow::Result<()> {
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&self.log)
            .with_context(|| format!("opening {}", self.log.display()))?;
        let child = Command::new(&self.program)
            .arg("--config")
            .arg(&self.config)
            .arg("--camera")
            .arg(&self.camera)
            .stdin(Stdio::null())
            .stdout(log.try_clone()?)
            .stderr(log)
            .spawn()
            .with_context(|| format!("starting {}", self.program.display()))?;
        let pid = child.id();
        self.child = Some(child);
        self.started_at = Instant::now();
        self.starts += 1;
        pb.suspend(|| println!("synth: cascade started pid={pid}"));
        Ok(())
    }

    /// Waits until the cascade subscribed to `motion`.
    fn wait_subscribed(
        &mut self,
        motion: &StreamPublisher<Motion>,
        pb: &ProgressBar,
    ) -> anyhow::Result<()> {
        let deadline = Instant::now() + Duration::from_secs(60);
        while motion.subscriber_count() == 0 {
            self.check(motion, pb)?;
            if Instant::now() > deadline {
                bail!(
                    "{} did not subscribe within 60 s; see {}",
                    StageKind::Cascade.binary(),
                    self.log.display()
                );
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        Ok(())
    }

    /// Checks the process; restarts it if it died of something a restart can fix.
    /// Returns true if it was restarted.
    fn check(
        &mut self,
        motion: &StreamPublisher<Motion>,
        pb: &ProgressBar,
    ) -> anyhow::Result<bool> {
        let Some(child) = &mut self.child else {
            return Ok(false);
        };
        let Some(status) = child.try_wait()? else {
            return Ok(false);
        };
        self.child = None;
        let how = match (
            status.code(),
            std::os::unix::process::ExitStatusExt::signal(&status),
        ) {
            (Some(code), _) if exit::is_permanent(code) => {
                bail!(
                    "{} failed with exit code {code}:\n{}",
                    StageKind::Cascade.binary(),
                    log_tail(&self.log)
                );
            }
            (Some(code), _) => format!("exited with code {code}"),
            (None, Some(signal)) => format!("was killed by signal {signal}"),
            _ => "ended".to_string(),
        };
        // A process that keeps exiting by itself right after start is a crash loop;
        // one killed from outside (a crash test) is not.
        if status.code().is_some() && self.started_at.elapsed() < Duration::from_secs(1) {
            self.quick_failures += 1;
            if self.quick_failures >= 5 {
                bail!(
                    "{} keeps dying right after start ({how}):\n{}",
                    StageKind::Cascade.binary(),
                    log_tail(&self.log)
                );
            }
        } else {
            self.quick_failures = 0;
        }
        pb.suspend(|| println!("synth: cascade {how}; restarting it"));
        self.start(pb)?;
        self.wait_subscribed(motion, pb)?;
        Ok(true)
    }

    /// Stops the cascade: SIGTERM, then SIGKILL after 10 s.
    fn stop(&mut self) {
        let Some(mut child) = self.child.take() else {
            return;
        };
        // SAFETY: kill(2) on our own child.
        unsafe {
            libc::kill(child.id() as i32, libc::SIGTERM);
        }
        let deadline = Instant::now() + Duration::from_secs(10);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        let _ = child.kill();
        let _ = child.wait();
    }
}

impl Drop for CascadeProc {
    fn drop(&mut self) {
        self.stop();
    }
}

/// The last lines of a log file.
fn log_tail(path: &Path) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let lines: Vec<&str> = text.lines().collect();
    lines[lines.len().saturating_sub(15)..].join("\n")
}

/// Reads the cascade's activity in a thread of its own (with its own iceoryx2 node),
/// so the cascade never waits for the synth in lossless mode.
struct ActivityTally {
    ended: Arc<AtomicBool>,
    seconds: Arc<AtomicU64>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl ActivityTally {
    fn start(prefix: &str, camera: &str) -> anyhow::Result<ActivityTally> {
        let ended = Arc::new(AtomicBool::new(false));
        let seconds = Arc::new(AtomicU64::new(0));
        let stop = Arc::new(AtomicBool::new(false));
        let (ready_tx, ready_rx) = mpsc::channel::<anyhow::Result<()>>();
        let (prefix, camera) = (prefix.to_string(), camera.to_string());
        let (e, s, st) = (ended.clone(), seconds.clone(), stop.clone());
        let thread = std::thread::Builder::new().name("activity-tally".into());
        let thread = thread.spawn(move || {
            let opened = Ipc::new(
                "isochron-synth-activity",
                ServiceNames::new(&prefix),
                IpcConfig {
                    lossless: true,
                    ..IpcConfig::default()
                },
            )
            .map_err(anyhow::Error::from)
            .and_then(|ipc| {
                let sub = ipc.subscriber::<Activity>(&camera)?;
                Ok((ipc, sub))
            });
            let (_ipc, sub) = match opened {
                Ok(x) => {
                    let _ = ready_tx.send(Ok(()));
                    x
                }
                Err(err) => {
                    let _ = ready_tx.send(Err(err));
                    return;
                }
            };
            while !st.load(Ordering::Acquire) {
                sub.wait(Duration::from_millis(50));
                sub.drain_wakeups();
                while let Ok(Some(sample)) = sub.receive() {
                    if sample.user_header().preamble.is_end_of_stream() {
                        e.store(true, Ordering::Release);
                    } else {
                        s.fetch_add(1, Ordering::Relaxed);
                    }
                }
            }
        })?;
        ready_rx
            .recv()
            .context("the activity reader thread died")??;
        Ok(ActivityTally {
            ended,
            seconds,
            stop,
            thread: Some(thread),
        })
    }

    /// Stops the reader; returns the number of activity seconds seen.
    fn stop(mut self) -> u64 {
        self.stop.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        self.seconds.load(Ordering::Relaxed)
    }
}

impl Drop for ActivityTally {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn profiles_parse_and_interpolate_around_midnight() {
        let p = Profile::parse("minute_of_day,activity\n0,0\n600,1\n720,0.5\n1380,0.2\n").unwrap();
        assert_eq!(p.at(0.0), 0.0);
        assert_eq!(p.at(300.0), 0.5);
        assert_eq!(p.at(600.0), 1.0);
        assert!((p.at(660.0) - 0.75).abs() < 1e-12);
        // Between 23:00 (0.2) and midnight (0).
        assert!((p.at(1410.0) - 0.1).abs() < 1e-12);
        assert!((p.at(1440.0 + 300.0) - 0.5).abs() < 1e-12);
        let one = Profile::parse("5,0.3").unwrap();
        assert_eq!(one.at(1000.0), 0.3);
        for bad in [
            "",
            "minute,activity\n",
            "0,2\n",
            "1500,0.1\n",
            "0,x\n",
            "0\n",
        ] {
            assert!(Profile::parse(bad).is_err(), "{bad:?}");
        }
        let err = Profile::parse("0,0.1\n10,1.5\n").unwrap_err();
        assert!(err.to_string().contains("line 2"), "{err}");
    }

    #[test]
    fn arguments_parse() {
        assert_eq!(parse_grid("16x12").unwrap(), (16, 12));
        assert!(parse_grid("16").is_err() && parse_grid("0x3").is_err());
        assert_eq!(
            parse_start("2026-01-05").unwrap(),
            parse_rfc3339("2026-01-05T00:00:00Z").unwrap()
        );
        assert_eq!(
            parse_start("2026-01-05T06:00:00+01:00").unwrap(),
            parse_rfc3339("2026-01-05T05:00:00Z").unwrap()
        );
        assert!(parse_start("monday").is_err());
        assert_eq!(direction_label(1.0, 0.0), 0);
        assert_eq!(direction_label(0.0, -1.0), 2);
        assert_eq!(direction_label(-1.0, 0.0), 4);
        assert_eq!(direction_label(0.0, 1.0), 6);
        assert_eq!(direction_label(0.0, 0.0), DIRECTION_NONE);
    }

    #[test]
    fn arrivals_follow_the_profile() {
        let mut s = Synth::new(16, 12, 2.0, 7, 30.0, 0.0);
        let mut blocks = vec![BlockMotion::default(); 192];
        let mut busy = 0;
        for _ in 0..(2 * 3600) {
            busy += s.frame(1.0, &mut blocks);
        }
        let mut quiet = 0;
        for _ in 0..(2 * 3600) {
            quiet += s.frame(0.25, &mut blocks);
        }
        // A quarter of the arrivals: a quarter of the motion, within noise.
        let ratio = quiet as f64 / busy as f64;
        assert!((ratio - 0.25).abs() < 0.05, "{ratio}");
        // People move in straight lines: every block with motion has a direction.
        assert!(
            blocks
                .iter()
                .all(|b| b.density == 0.0 || b.direction != DIRECTION_NONE)
        );
        let mut idle = Synth::new(16, 12, 2.0, 7, 30.0, 0.0);
        for _ in 0..100 {
            assert_eq!(idle.frame(0.0, &mut blocks), 0);
        }
        assert!(blocks.iter().all(|b| b.density == 0.0));
    }
}
