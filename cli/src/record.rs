//! `isochron record --config site.toml --out FILE.mcap [--streams ...]
//! [--duration S]`: the site's channels (as `isochron view` shows them) into an MCAP
//! file that opens in Foxglove. Ends on Ctrl-C, after `--duration`, when every
//! camera's file source has ended, or when the disk runs low (the file is then
//! closed cleanly and the exit code is 1). The recorder is the view's stage
//! ([`isochron_view::stage`]) with an MCAP sink; `isochron replay --record` runs
//! the same stage on a thread of its own ([`RecorderThread`]).

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::Context as _;
use isochron_config::LoadedConfig;
use isochron_runtime::ipc::Ipc;
use isochron_view::Context;
use isochron_view::channels::SiteChannels;
use isochron_view::follow::{Streams, ViewInputs};
use isochron_view::record::{RESERVE_BYTES, Recording};
use isochron_view::stage::{Sink, Summary, Until, ViewStage};

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
    #[arg(long, value_parser = crate::values::positive_seconds)]
    duration: Option<Duration>,
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let loaded = load_config(args.config)?;
    let streams = streams_of(args.streams.as_deref(), &loaded)?;
    let ipc = Ipc::of_site(
        &format!("isochron-record-{}", std::process::id()),
        &loaded.config,
    )?;
    let until = Until {
        deadline: args.duration.map(|d| Instant::now() + d),
        stop: None,
        sources_end: true,
    };
    let (mut stage, inputs) = open_recorder(&ipc, &loaded, &args.out, streams, until)?;
    isochron_runtime::stage::run(&ipc, "", &mut stage, &inputs)?;
    Ok(report(stage.finish()?))
}

/// The `--streams` selection, or every stream the config allows.
pub fn streams_of(list: Option<&str>, loaded: &LoadedConfig) -> anyhow::Result<Streams> {
    match list {
        Some(list) => Streams::parse(list, loaded)
            .map_err(|e| isochron_exit::UsageError(format!("--streams: {e}")).into()),
        None => Ok(Streams::all(loaded)),
    }
}

/// A recorder of `streams` into `out` (created now): the view's stage with an
/// MCAP sink, and its inputs.
fn open_recorder(
    ipc: &Ipc,
    loaded: &LoadedConfig,
    out: &Path,
    streams: Streams,
    until: Until,
) -> anyhow::Result<(ViewStage, ViewInputs)> {
    let ctx = Context::new();
    let channels = SiteChannels::new(loaded, &ctx)?;
    crate::common::output_target("--out", out)?;
    let recording = Recording::create(out, &ctx)?;
    let sink = Sink::Record(recording);
    Ok(ViewStage::open(
        ipc, loaded, channels, sink, streams, until,
    )?)
}

/// Says what a finished recording holds; exit code 1 if the disk ran low.
fn report(summary: Summary) -> ExitCode {
    let total: u64 = summary.counts.iter().map(|(_, n)| n).sum();
    let (path, bytes) = summary.file.unwrap_or_default();
    println!(
        "record: {} written: {total} messages on {} channels, {bytes} bytes",
        path.display(),
        summary.counts.len()
    );
    for (topic, n) in &summary.counts {
        println!("  {topic}: {n}");
    }
    if summary.rejected > 0 {
        eprintln!(
            "isochron record: skipped {} malformed samples",
            summary.rejected
        );
    }
    if summary.disk_low {
        eprintln!(
            "isochron record: less than {} MiB left on the disk of {}: recording closed early (the file is complete and readable)",
            RESERVE_BYTES >> 20,
            path.display()
        );
        return ExitCode::from(1);
    }
    ExitCode::SUCCESS
}

/// A recorder on a thread of its own, for `isochron replay --record`: the same
/// stage as `isochron record`, woken by its own inputs (so it never waits for the
/// replay's loop, and a lossless replay never waits for it), with the runtime's
/// stop handling. It ends when [`RecorderThread::finish`] says so (or dropped,
/// or on Ctrl-C), or by itself when the disk runs low; the file is closed cleanly
/// in every case.
pub struct RecorderThread {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<anyhow::Result<ExitCode>>>,
}

impl RecorderThread {
    /// Starts recording `loaded`'s site into `out`; returns once the recorder has
    /// subscribed (or failed to).
    pub fn start(loaded: &LoadedConfig, out: &Path) -> anyhow::Result<RecorderThread> {
        let stop = Arc::new(AtomicBool::new(false));
        let until = Until {
            stop: Some(stop.clone()),
            ..Until::default()
        };
        let (loaded, out) = (loaded.clone(), out.to_path_buf());
        let (ready, started) = std::sync::mpsc::channel();
        // The node and the subscribers belong to the thread that reads them.
        let thread = std::thread::Builder::new()
            .name("record".into())
            .spawn(move || {
                let opened = Ipc::of_site("isochron-replay-record", &loaded.config)
                    .map_err(anyhow::Error::from)
                    .and_then(|ipc| {
                        let streams = streams_of(None, &loaded)?;
                        let recorder = open_recorder(&ipc, &loaded, &out, streams, until)?;
                        Ok((ipc, recorder))
                    });
                let (ipc, (mut stage, inputs)) = match opened {
                    Ok(o) => {
                        let _ = ready.send(Ok(()));
                        o
                    }
                    Err(e) => {
                        let _ = ready.send(Err(e));
                        return Ok(ExitCode::SUCCESS);
                    }
                };
                isochron_runtime::stage::run(&ipc, "", &mut stage, &inputs)?;
                Ok(report(stage.finish()?))
            })
            .context("starting the recorder thread")?;
        started
            .recv()
            .context("the recorder thread ended before it started")??;
        Ok(RecorderThread {
            stop,
            thread: Some(thread),
        })
    }

    /// Ends the recording (after what already arrived) and closes the file; the
    /// exit code of `isochron record` (1 if the disk ran low).
    pub fn finish(mut self) -> anyhow::Result<ExitCode> {
        self.stop.store(true, Ordering::Relaxed);
        match self.thread.take().map(JoinHandle::join) {
            Some(Ok(result)) => result,
            Some(Err(_)) => anyhow::bail!("the recorder thread panicked"),
            None => Ok(ExitCode::SUCCESS),
        }
    }
}

impl Drop for RecorderThread {
    /// A replay that fails still closes its recording.
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}
