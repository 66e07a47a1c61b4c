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
use std::process::ExitCode;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use indicatif::{ProgressBar, ProgressStyle};
use isochron_config::clock::{NS_PER_S, format_rfc3339, parse_rfc3339, wall_now_ns};
use isochron_config::{CameraConfig, Config, IpcConfig};
use isochron_runtime::ipc::{Ipc, Motion, StreamPublisher};
use isochron_runtime::names::ServiceNames;
use isochron_store::{Store, store_path};
use isochron_wire::{
    BlockMotion, CameraId, FLAG_END_OF_STREAM, MotionHeader, Preamble, Stream, is_valid_camera_id,
};

use crate::common::{input_file, with_code};

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
    /// The long-term model's cycle: day_types (the default), daily or weekly.
    #[arg(long, default_value = "day_types", value_parser = crate::values::cycle)]
    cycle: isochron_config::clock::Cycle,
}

/// Block edge of the synthetic frames, pixels.
const BLOCK_PX: u32 = 16;
/// How often the cascade process is checked while frames flow.
const CHECK_EVERY: u64 = 256;

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    // Every argument and the profile before anything is created.
    let usage = |e| with_code(isochron_exit::USAGE, e);
    check_args(&args).map_err(usage)?;
    let (grid_w, grid_h) = parse_grid(&args.grid).map_err(usage)?;
    let start_ns = parse_start(&args.start).map_err(usage)?;
    let cycle = args.cycle;
    input_file(
        "--profile",
        &args.profile,
        "a CSV file of `minute_of_day,activity` rows",
    )?;
    let profile = Profile::load(&args.profile).map_err(|e| with_code(isochron_exit::DATA, e))?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let out = args.out.canonicalize()?;
    let config_path = write_config(&out, &args.camera, cycle)?;
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
    let motion = ipc.publisher::<Motion>(&args.camera, k)?;
    let activity = ActivityTally::start(&prefix, &args.camera)?;
    let cascade = CascadeProc::new(&config_path, &args.camera, &out.join("cascade.log"))?;
    let mut pipe = Pipe {
        motion,
        cascade,
        pb: progress_bar(args.days, args.fps),
        camera: CameraId::new(&args.camera).expect("checked"),
    };
    pipe.cascade.start(&pipe.pb)?;
    pipe.cascade.wait_subscribed(&pipe.motion, &pipe.pb)?;
    pipe.cascade.watch_status(&ipc)?;

    let total = (args.days * 86_400.0 * args.fps).round() as u64;
    let started = Instant::now();
    let (resent, sent) = send_days(
        &args,
        &mut pipe,
        &profile,
        (grid_w, grid_h),
        start_ns,
        total,
    )?;
    // Stopped early, the cascade still gets the end of stream: it stores every
    // whole minute it was sent.
    let end_ns = start_ns + (sent as f64 * 1e9 / args.fps).round() as i64;
    end_of_stream(&mut pipe, &activity, end_ns)?;
    let wall = started.elapsed();
    pipe.cascade.stop();
    let seconds = activity.stop();
    pipe.pb.finish_and_clear();

    println!(
        "synth: {} days of {} at {} fps on a {grid_w}x{grid_h} grid from {}",
        args.days,
        args.profile.display(),
        args.fps,
        format_rfc3339(start_ns)
    );
    println!(
        "synth: {sent} frames in {:.1} s ({:.0} frames/s, {:.1} simulated days per minute), {seconds} activity seconds, {} frames sent again, {} cascade restarts",
        wall.as_secs_f64(),
        sent as f64 / wall.as_secs_f64().max(1e-9),
        sent as f64 / total as f64 * args.days / wall.as_secs_f64().max(1e-9) * 60.0,
        resent,
        pipe.cascade.starts - 1
    );
    print_store(&store_path(&out, &args.camera), &args.camera)?;
    if sent < total {
        return Err(isochron_exit::Fatal::new(
            isochron_exit::INTERRUPTED,
            format!(
                "synth: interrupted (SIGINT or SIGTERM) after {sent} of {total} frames, until {}: the store keeps every whole minute sent",
                format_rfc3339(end_ns)
            ),
        )
        .into());
    }
    Ok(ExitCode::SUCCESS)
}

/// Errors unless the arguments are in range.
fn check_args(args: &Args) -> anyhow::Result<()> {
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
    Ok(())
}

/// Where the motion goes: the publisher, the cascade that takes it, the progress
/// bar, the camera.
struct Pipe {
    motion: StreamPublisher<Motion>,
    cascade: CascadeProc,
    pb: ProgressBar,
    camera: CameraId,
}

/// Sends the `total` frames of the crowd from `start_ns`; returns how many were
/// sent again and how many were sent (fewer than `total` when SIGINT or
/// SIGTERM stopped it).
fn send_days(
    args: &Args,
    pipe: &mut Pipe,
    profile: &Profile,
    (grid_w, grid_h): (u32, u32),
    start_ns: i64,
    total: u64,
) -> anyhow::Result<(u64, u64)> {
    let k = (grid_w * grid_h) as usize;
    pipe.pb.set_length(total);
    let mut synth = Synth::new(
        grid_w,
        grid_h,
        args.fps,
        args.seed,
        args.arrivals_per_min,
        args.standing,
    );
    let mut blocks = vec![BlockMotion::default(); k];
    let mut resent = 0u64;
    for i in 0..total {
        let t_ns = start_ns + (i as f64 * 1e9 / args.fps).round() as i64;
        let minute_of_day = (t_ns.rem_euclid(86_400 * NS_PER_S)) as f64 / 60e9;
        let changed = synth.frame(profile.at(minute_of_day), &mut blocks);
        let sequence = pipe.motion.next_sequence();
        let mut preamble = Preamble::new::<BlockMotion>(Stream::Motion, pipe.camera, sequence, k);
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
        resent += deliver(
            &mut pipe.motion,
            header,
            &blocks,
            &mut pipe.cascade,
            &pipe.pb,
        )?;
        if i % CHECK_EVERY == 0 {
            if isochron_runtime::ipc::stop_signalled() {
                return Ok((resent, i + 1));
            }
            pipe.cascade.check(&pipe.motion, &pipe.pb)?;
            pipe.pb.set_position(i);
            pipe.pb.set_message(sim_time(start_ns, t_ns, args.days));
        }
    }
    pipe.pb.set_position(total);
    Ok((resent, total))
}

/// Sends end of stream at `end_ns`, then waits until the cascade has stored
/// everything (its end-of-stream activity sample), sending it again to a cascade
/// that restarted before it got there.
fn end_of_stream(pipe: &mut Pipe, activity: &ActivityTally, end_ns: i64) -> anyhow::Result<()> {
    let sequence = pipe.motion.next_sequence();
    let mut preamble = Preamble::new::<BlockMotion>(Stream::Motion, pipe.camera, sequence, 0);
    preamble.capture_time_ns = end_ns;
    preamble.flags = FLAG_END_OF_STREAM;
    let eos = MotionHeader {
        preamble,
        ..Default::default()
    };
    pipe.pb
        .set_message("waiting for the cascade to store the last minute");
    let mut since = Instant::now();
    deliver(&mut pipe.motion, eos, &[], &mut pipe.cascade, &pipe.pb)?;
    while !activity.ended.load(Ordering::Acquire) {
        if pipe.cascade.check(&pipe.motion, &pipe.pb)? {
            // Restarted before it got to the end of stream: send it again.
            deliver(&mut pipe.motion, eos, &[], &mut pipe.cascade, &pipe.pb)?;
            since = Instant::now();
        }
        pipe.cascade
            .stalled(since, "did not finish after the end of stream")?;
        std::thread::sleep(Duration::from_millis(10));
    }
    Ok(())
}

/// Prints what the store at `store` of `camera` has learned.
fn print_store(store: &Path, camera: &str) -> anyhow::Result<()> {
    let s = Store::open_read_only(store, camera)?;
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
    Ok(())
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
fn write_config(
    out: &Path,
    camera: &str,
    cycle: isochron_config::clock::Cycle,
) -> anyhow::Result<PathBuf> {
    let mut config = Config::default();
    config.cascade.cycle = cycle;
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

mod cascade;
mod crowd;

use cascade::{ActivityTally, CascadeProc};
use crowd::{Profile, Synth};

#[cfg(test)]
mod tests;
