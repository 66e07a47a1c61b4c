//! `isochron record --config site.toml --out FILE.mcap [--streams ...]
//! [--duration S]`: the site's channels (as `isochron view` shows them) into an MCAP
//! file that opens in Foxglove. Ends on Ctrl-C, after `--duration`, when every
//! camera's file source has ended, or when the disk runs low (the file is then
//! closed cleanly and the exit code is 1).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::Context as _;
use isochron_shared::config::LoadedConfig;
use isochron_shared::ipc::Ipc;
use isochron_view::Context;
use isochron_view::channels::SiteChannels;
use isochron_view::follow::{Follower, Streams};
use isochron_view::record::{RESERVE_BYTES, Recording};

use crate::common::load_config;

/// Record the site's streams into an MCAP file (opens in Foxglove).
#[derive(clap::Args)]
pub struct Args {
    /// Site configuration (default: $ISOCHRON_CONFIG or /etc/isochron/isochron.toml).
    #[arg(long)]
    config: Option<PathBuf>,
    /// The MCAP file to write (replaced if it exists).
    #[arg(long)]
    out: PathBuf,
    /// Streams to record, comma-separated: activity (with the cost map and the
    /// floor scene), motion (at most 2 per second), events, detections, status
    /// (every service's reports), frames (only with `view.frames = true`).
    /// Default: all the config allows.
    #[arg(long)]
    streams: Option<String>,
    /// Stop after this many seconds.
    #[arg(long)]
    duration: Option<f64>,
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let loaded = load_config(args.config)?;
    let streams = streams_of(args.streams.as_deref(), &loaded)?;
    if let Some(d) = args.duration
        && !(d.is_finite() && d > 0.0)
    {
        anyhow::bail!("--duration: expected a number of seconds > 0, found {d}");
    }
    let ipc = Ipc::of_site(
        &format!("isochron-record-{}", std::process::id()),
        &loaded.config,
    )?;
    let mut recorder = Recorder::start(&ipc, &loaded, &args.out, streams)?;
    let deadline = args
        .duration
        .map(|d| Instant::now() + Duration::from_secs_f64(d));
    loop {
        if recorder.poll()? {
            break;
        }
        if ipc.should_stop()
            || deadline.is_some_and(|d| Instant::now() >= d)
            || recorder.follower.all_ended()
        {
            break;
        }
        recorder.follower.wait(Duration::from_millis(100));
    }
    recorder.finish()
}

/// The `--streams` selection, or every stream the config allows.
pub fn streams_of(list: Option<&str>, loaded: &LoadedConfig) -> anyhow::Result<Streams> {
    match list {
        Some(list) => Streams::parse(list, loaded).map_err(anyhow::Error::msg),
        None => Ok(Streams::all(loaded)),
    }
}

/// A recording in progress: the subscribers, the channels and the file.
pub struct Recorder {
    /// The subscribers.
    pub follower: Follower,
    channels: SiteChannels,
    recording: Recording,
    disk_low: bool,
    // Keeps the channels' context alive as long as the recording.
    _ctx: std::sync::Arc<Context>,
}

impl Recorder {
    /// Subscribes to `streams` and opens `out`.
    pub fn start(
        ipc: &Ipc,
        loaded: &LoadedConfig,
        out: &std::path::Path,
        streams: Streams,
    ) -> anyhow::Result<Recorder> {
        let ctx = Context::new();
        let channels = SiteChannels::new(loaded, &ctx)?;
        let recording = Recording::create(out, &ctx)?;
        let follower = Follower::open(ipc, loaded, &channels, streams)?;
        Ok(Recorder {
            follower,
            channels,
            recording,
            disk_low: false,
            _ctx: ctx,
        })
    }

    /// Records what waits; true when the disk runs low and the recording must end.
    pub fn poll(&mut self) -> anyhow::Result<bool> {
        self.follower
            .poll(&mut self.channels)
            .context("reading the streams")?;
        if self.recording.disk_low() {
            self.disk_low = true;
        }
        Ok(self.disk_low)
    }

    /// Closes the file and reports; exit code 1 if the disk ran low.
    pub fn finish(self) -> anyhow::Result<ExitCode> {
        let path = self.recording.path().to_path_buf();
        let mut counts: Vec<(String, u64)> = self
            .channels
            .counts()
            .iter()
            .map(|(t, n)| (t.clone(), *n))
            .collect();
        counts.sort();
        let bytes = self.recording.close()?;
        let total: u64 = counts.iter().map(|(_, n)| n).sum();
        println!(
            "record: {} written: {total} messages on {} channels, {bytes} bytes",
            path.display(),
            counts.len()
        );
        for (topic, n) in &counts {
            println!("  {topic}: {n}");
        }
        if self.follower.rejected > 0 {
            eprintln!(
                "isochron record: skipped {} malformed samples",
                self.follower.rejected
            );
        }
        if self.disk_low {
            eprintln!(
                "isochron record: less than {} MiB left on the disk of {}: recording closed early (the file is complete and readable)",
                RESERVE_BYTES >> 20,
                path.display()
            );
            return Ok(ExitCode::from(1));
        }
        Ok(ExitCode::SUCCESS)
    }
}
