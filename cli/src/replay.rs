//! `isochron replay <video> --out DIR`: run the whole group on a video file under a
//! private service prefix, wait until every stage has processed all of it, and
//! write what each produced:
//!
//! * `DIR/config.toml`: the effective configuration;
//! * `DIR/summary.json`: samples per stage, wall time, the gate's counters, and
//!   `input`: the frames the file states, the frames capture read, and whether
//!   the file is truncated (then replay exits with 65, DATA, after writing
//!   everything). Capture reports these in its last status detail, published
//!   before its end of stream, which replay subscribes to;
//! * `DIR/events.jsonl`: one object per finished event;
//! * `DIR/detections.jsonl`: one object per detected frame;
//! * `DIR/logs/`: each service's log; `DIR/state/`: the long-term store;
//! * with `--record FILE.mcap`: the run as `isochron record` writes it.
//!
//! With `--speed max` (the default) delivery is lossless: every stage sees every
//! sample, and the run goes as fast as the slowest stage.
//!
//! The replay itself is a stage of the runtime ([`isochron_runtime::stage`]):
//! its inputs are its own subscribers to every produced stream, its alarms pace
//! the start-up (capture starts once every consumer has subscribed), its tick
//! watches the services and the progress. It reports no status of its own
//! (`Context::unreported`).

mod tally;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context as _, bail};
use isochron_config::{Config, LoadedConfig, Speed};
use isochron_exit::{Fatal, UsageError};
use isochron_runtime::counters::Counters;
use isochron_runtime::health::InputCompleteness;
use isochron_runtime::ipc::{Ipc, StatusSubscriber};
use isochron_runtime::stage::{self, Context, Stage};
use isochron_runtime::topology::StageKind;
use isochron_wire::{StageStatus, Stream};

use crate::launch::{ServiceSpec, State, Supervisor, group_specs, installed};
use crate::record::RecorderThread;
use tally::{Ending, ReplayInputs, Tally};

/// Run the whole group on a video file and write what every stage produced.
#[derive(clap::Args)]
pub struct Args {
    /// The video file.
    video: PathBuf,
    /// Output directory (created).
    #[arg(long)]
    out: PathBuf,
    /// Site configuration to start from; its first camera (or `--camera`) gets the
    /// video as source. Default: built-in defaults.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Which configured camera replays the video.
    #[arg(long)]
    camera: Option<String>,
    /// Capture time of the first frame (RFC 3339, such as 2026-03-02T07:00:00Z).
    /// Default: the camera's `start`, or now.
    #[arg(long, value_name = "RFC3339", value_parser = crate::values::start_time)]
    start: Option<String>,
    /// `max` (as fast as every stage keeps up, lossless) or a factor of real time > 0.
    #[arg(long, default_value = "max", value_parser = crate::values::speed)]
    speed: Speed,
    /// Give up if no stage makes progress for this many seconds.
    #[arg(long, default_value = "120", value_parser = crate::values::positive_seconds)]
    stall_timeout_s: Duration,
    /// Also record the run into this MCAP file, as `isochron record` does (opens in
    /// Foxglove; images only with `view.frames = true`).
    #[arg(long)]
    record: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let (video, speed, out) = check_args(&args)?;
    let (loaded, camera) = effective_config(&args, &video, speed, &out)?;
    let stages = installed(StageKind::replayed(&loaded.config));
    if !stages.iter().any(|(s, _)| *s == StageKind::Capture) {
        bail!(
            "{} is not installed next to this binary ({})",
            StageKind::Capture.binary(),
            crate::launch::bin_dir().display()
        );
    }
    let ipc = Ipc::of_site("isochron-replay", &loaded.config)?;
    let inputs = tally::open_inputs(&ipc, &camera, &stages)?;
    // The recorder runs on a thread of its own, woken by its own subscribers.
    let recorder = args
        .record
        .as_deref()
        .map(|path| RecorderThread::start(&loaded, path))
        .transpose()?;
    let tally = Tally::new(&camera, &inputs, &out)?;

    let specs = group_specs(&loaded, &stages);
    let mut supervisor = Supervisor::new(false, Duration::from_secs(60), Some(out.join("logs")))?;
    // The wall time counts the services' start-up too, as it always has.
    let started = Instant::now();
    // Consumers first; the producer only once everything downstream listens.
    let (capture, rest): (Vec<ServiceSpec>, Vec<ServiceSpec>) = specs
        .into_iter()
        .partition(|s| s.stage == StageKind::Capture);
    for spec in rest {
        supervisor.add(spec)?;
    }
    // Optional consumers (the MQTT sink) get every sample too.
    let consumers = stages.clone();
    let banner = format!(
        "replay: {} → {} (speed {speed}, prefix {})",
        video.display(),
        out.display(),
        loaded.config.site.service_prefix
    );
    let mut replay = ReplayStage {
        ipc: &ipc,
        camera: camera.clone(),
        logs: out.join("logs"),
        supervisor,
        phase: Phase::Starting {
            capture,
            consumers,
            deadline: Instant::now() + START_TIMEOUT,
            banner,
        },
        tally,
        capture_status: None,
        capture_last: None,
        stall: args.stall_timeout_s,
        last_total: 0,
        last_progress: Instant::now(),
        failure: None,
    };
    let mut cx = Context::unreported(StageKind::View);
    stage::run_in(&ipc, &mut replay, &inputs, &mut cx)?;
    if let Some(failure) = replay.failure.take() {
        return failed(replay, failure, false, &out, &video, started.elapsed());
    }
    if !matches!(replay.phase, Phase::Collecting) || !replay.tally.all_ended() {
        let stopped = Fatal::new(
            isochron_exit::INTERRUPTED,
            format!(
                "interrupted (SIGINT or SIGTERM): the group is stopped; {} says what arrived",
                out.join("summary.json").display()
            ),
        );
        return failed(
            replay,
            stopped.into(),
            true,
            &out,
            &video,
            started.elapsed(),
        );
    }
    finish(replay, recorder, &out, &video, started.elapsed())
}

/// The video (canonical), the speed and the output directory (absolute, not
/// yet created: [`effective_config`] makes it once the config is accepted) the
/// arguments name. A video that is missing or not a file (a directory) is
/// refused here, 66, before anything is created or started.
fn check_args(args: &Args) -> anyhow::Result<(PathBuf, Speed, PathBuf)> {
    crate::common::input_file("the video", &args.video, "a video file")?;
    let video = args
        .video
        .canonicalize()
        .with_context(|| format!("the video {}", args.video.display()))?;
    let out =
        std::path::absolute(&args.out).with_context(|| format!("--out {}", args.out.display()))?;
    if out.exists() && !out.is_dir() {
        return Err(UsageError(format!(
            "--out {}: not a directory; replay writes its files into a directory (a new one or one of its earlier runs)",
            args.out.display()
        ))
        .into());
    }
    Ok((video, args.speed, out))
}

/// After every stream ended: stop the services, close the recording, write the
/// outputs and the summary line; the exit code says whether the input or the
/// recording fell short.
fn finish(
    mut replay: ReplayStage<'_>,
    recorder: Option<RecorderThread>,
    out: &Path,
    video: &Path,
    wall: Duration,
) -> anyhow::Result<ExitCode> {
    replay.supervisor.stop_all(Duration::from_secs(10));
    // What arrived is recorded, then the file closed (early, and the replay went
    // on, if the disk ran low: then the exit code is 1).
    let recording_failed = recorder
        .map(RecorderThread::finish)
        .transpose()?
        .is_some_and(|code| code != ExitCode::SUCCESS);
    let input = replay
        .capture_last
        .as_ref()
        .and_then(InputCompleteness::from_status);
    replay
        .tally
        .finish(out, video, wall, input, Ending::Complete)?;
    println!(
        "replay: {} in {:.1} s",
        replay.tally.counts_line(),
        wall.as_secs_f64()
    );
    if let Some(input) = input.filter(|i| i.truncated) {
        eprintln!(
            "replay: {} is truncated or damaged: it ended after {} of the {} frames it states (outputs cover the frames read; exit code {})",
            video.display(),
            input.frames_read,
            input.frames_stated,
            isochron_exit::DATA
        );
        return Ok(ExitCode::from(isochron_exit::DATA as u8));
    }
    if recording_failed {
        return Ok(ExitCode::from(1));
    }
    Ok(ExitCode::SUCCESS)
}

/// After a stage failed (or nothing moved, or a signal stopped it:
/// `interrupted`): stop the services, write `summary.json` with what arrived
/// and why the replay stopped (`failure`), and end with the failure — the
/// stage's exit code and reason (see [`stage_failure`]), or 130.
fn failed(
    mut replay: ReplayStage<'_>,
    failure: anyhow::Error,
    interrupted: bool,
    out: &Path,
    video: &Path,
    wall: Duration,
) -> anyhow::Result<ExitCode> {
    replay.supervisor.stop_all(Duration::from_secs(10));
    let input = replay
        .capture_last
        .as_ref()
        .and_then(InputCompleteness::from_status);
    let reason = format!("{failure:#}");
    let ending = match interrupted {
        true => Ending::Interrupted(&reason),
        false => Ending::Failed(&reason),
    };
    if let Err(e) = replay.tally.finish(out, video, wall, input, ending) {
        tracing::warn!("{e:#}");
    }
    Err(failure)
}

/// The failure of service `name` in `state` (`when`: "during start-up", "before
/// the end of the video"): it ends the replay with the service's exit code
/// (65 for a video capture cannot decode), and says why, from the last error
/// its log (`logs/<name>.log`) has.
fn stage_failure(logs: &Path, name: &str, state: &State, when: &str) -> anyhow::Error {
    let log = logs.join(format!("{}.log", name.replace('/', "-")));
    let (code, how) = match state {
        State::Failed { code } if *code > 0 => (*code, format!("exited with {code}")),
        State::Failed { .. } => (isochron_exit::FAILURE, "was killed".to_string()),
        _ => (isochron_exit::FAILURE, "stopped".to_string()),
    };
    let reason = last_error(&log).map_or_else(String::new, |r| format!(": {r}"));
    Fatal::new(
        code,
        format!("{name} {how} {when}{reason} (its log: {})", log.display()),
    )
    .into()
}

/// The message of the last `ERROR` line of the log at `path` (a service's
/// fatal error, which it logs as it ends), without its time and span.
fn last_error(path: &Path) -> Option<String> {
    let text = std::fs::read(path).ok()?;
    let tail = &text[text.len().saturating_sub(64 * 1024)..];
    let text = String::from_utf8_lossy(tail);
    let line = text.lines().rev().find(|l| l.contains(" ERROR "))?;
    let message = line.split_once(" ERROR ")?.1.trim();
    // `camera{camera=cam01}: ...`: the span says what the message says again.
    let message = match message.split_once("}: ") {
        Some((span, rest)) if !span.contains(' ') => rest,
        _ => message,
    };
    Some(message.to_string())
}

/// The config the group runs with: the chosen camera replays `video`, alone, under a
/// private prefix, with its store in `out/state`; written into `out`, created
/// here once the site's config and `--camera` are accepted.
fn effective_config(
    args: &Args,
    video: &Path,
    speed: Speed,
    out: &Path,
) -> anyhow::Result<(LoadedConfig, String)> {
    let mut config = match &args.config {
        Some(path) => crate::common::load_config(Some(path.clone()))?.with_absolute_paths(),
        None => Config::default(),
    };
    let mut camera = match &args.camera {
        Some(id) => config
            .cameras
            .iter()
            .find(|c| &c.id == id)
            .cloned()
            .ok_or_else(|| {
                UsageError(format!(
                    "--camera: no camera '{id}' in the config (configured: {})",
                    config
                        .cameras
                        .iter()
                        .map(|c| c.id.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ))
            })?,
        None => config.cameras.first().cloned().unwrap_or_else(|| {
            toml::from_str(
                r#"id = "replay"
source = """#,
            )
            .expect("minimal camera")
        }),
    };
    camera.source = video.to_string_lossy().into_owned();
    camera.speed = speed;
    camera.loop_file = false;
    if let Some(start) = &args.start {
        camera.start = Some(start.clone());
    }
    let id = camera.id.clone();
    config.cameras = vec![camera];
    config.site.service_prefix = format!("isochron-replay-{}", std::process::id());
    config.site.state_dir = out.join("state");
    config.ipc.lossless = speed == Speed::Max;
    // Inputs accepted: the first thing created.
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let path = out.join("config.toml");
    std::fs::write(&path, toml::to_string_pretty(&config)?)
        .with_context(|| format!("writing {}", path.display()))?;
    // Validate exactly what the services will read.
    let loaded = Config::load(&path)?;
    Ok((loaded, id))
}

/// True for the service `name` (`stage` or `stage/cameras`) of an optional stage
/// (the exporter, the MQTT sink): its failure is logged (in `DIR/logs`) but does
/// not stop the replay.
fn is_optional(name: &str) -> bool {
    let stage = name.split('/').next().and_then(StageKind::from_name);
    stage.is_some_and(StageKind::optional)
}

/// How long the services may take to subscribe to their inputs.
const START_TIMEOUT: Duration = Duration::from_secs(60);
/// How often the replay looks whether the services have subscribed yet
/// (iceoryx2 says nothing when a subscriber connects).
const START_CHECK: Duration = Duration::from_millis(20);
/// How often the services' states and the progress are looked at.
const SUPERVISE_EVERY: Duration = Duration::from_millis(100);

/// Where the replay is.
enum Phase {
    /// The consumers are starting: capture (`capture`) starts once every one of
    /// `consumers` has subscribed to its inputs, before `deadline`; `banner` is
    /// printed then.
    Starting {
        capture: Vec<ServiceSpec>,
        consumers: Vec<(StageKind, PathBuf)>,
        deadline: Instant,
        banner: String,
    },
    /// Capture runs: what every stage produces is collected.
    Collecting,
}

/// The replay as a stage of the runtime: it starts the group (capture last),
/// collects what every stage produces (its inputs), and has finished once
/// every stream has ended — or a stage failed, or nothing moved for the stall
/// timeout (`failure`).
struct ReplayStage<'ipc> {
    ipc: &'ipc Ipc,
    camera: String,
    logs: PathBuf,
    supervisor: Supervisor,
    phase: Phase,
    tally: Tally,
    /// Capture's last status says how much of the file it read (it publishes
    /// it before the end of stream); subscribed before capture starts.
    capture_status: Option<StatusSubscriber>,
    capture_last: Option<StageStatus>,
    stall: Duration,
    last_total: u64,
    last_progress: Instant,
    /// Why the replay stopped before every stream ended.
    failure: Option<anyhow::Error>,
}

impl ReplayStage<'_> {
    /// While starting: starts capture once every consumer listens.
    fn start_capture(&mut self, cx: &mut Context) -> anyhow::Result<()> {
        let Phase::Starting {
            capture,
            consumers,
            deadline,
            banner,
        } = &mut self.phase
        else {
            return Ok(());
        };
        let missing = missing_consumers(self.ipc, &self.camera, consumers, &mut self.supervisor)
            .map_err(|(name, state)| stage_failure(&self.logs, &name, &state, "during start-up"))?;
        if !missing.is_empty() {
            if Instant::now() > *deadline {
                bail!(
                    "services did not subscribe in time ({})",
                    missing.join(", ")
                );
            }
            cx.alarm_in(START_CHECK);
            return Ok(());
        }
        self.capture_status = Some(
            self.ipc
                .status_subscriber(&self.camera, StageKind::Capture)?,
        );
        for spec in std::mem::take(capture) {
            self.supervisor.add(spec)?;
        }
        println!("{banner}");
        self.phase = Phase::Collecting;
        self.last_progress = Instant::now();
        Ok(())
    }

    /// While collecting: the services' changes, a failed one, no progress.
    fn supervise(&mut self) -> anyhow::Result<()> {
        if let Some(status) = self.capture_status.as_ref().and_then(|s| s.latest()) {
            self.capture_last = Some(status);
        }
        if !matches!(self.phase, Phase::Collecting) || self.tally.all_ended() {
            return Ok(());
        }
        for change in self.supervisor.poll() {
            tracing::info!("{} {}", change.name, change.what);
        }
        if let Some((name, state)) = self
            .supervisor
            .states()
            .into_iter()
            .filter(|(name, _)| !is_optional(name))
            .find(|(_, s)| matches!(s, State::Failed { .. }))
        {
            return Err(stage_failure(
                &self.logs,
                &name,
                &state,
                "before the end of the video",
            ));
        }
        let total = self.tally.total();
        if total != self.last_total {
            self.last_total = total;
            self.last_progress = Instant::now();
        } else if self.last_progress.elapsed() > self.stall {
            bail!(
                "no progress for {:.0} s (counts so far: {}); see {}",
                self.stall.as_secs_f64(),
                self.tally.counts_line(),
                self.logs.display()
            );
        }
        Ok(())
    }

    /// Ends the replay with `result`'s failure, if it failed (the loop ends
    /// as [`Stage::finished`] then says; `run` returns the error, chain and all).
    fn settle(&mut self, result: anyhow::Result<()>) -> Result<(), Fatal> {
        if let Err(e) = result {
            self.failure.get_or_insert(e);
        }
        Ok(())
    }
}

impl Stage for ReplayStage<'_> {
    type Inputs = ReplayInputs;
    // Unreported (`Context::unreported`): no status line names it.
    const KIND: StageKind = StageKind::View;

    fn on_start(&mut self, cx: &mut Context) -> Result<(), Fatal> {
        cx.alarm_at(Instant::now());
        Ok(())
    }

    fn on_wake(&mut self, inputs: &ReplayInputs, cx: &mut Context) -> Result<(), Fatal> {
        let taken = self.tally.take(inputs, cx);
        self.settle(taken)
    }

    fn on_alarm(&mut self, cx: &mut Context) -> Result<(), Fatal> {
        let started = self.start_capture(cx);
        self.settle(started)
    }

    fn on_tick(&mut self, _cx: &mut Context) -> Result<(), Fatal> {
        let supervised = self.supervise();
        self.settle(supervised)
    }

    fn finished(&self) -> bool {
        self.failure.is_some() || self.tally.all_ended()
    }

    fn timer(&self) -> Duration {
        SUPERVISE_EVERY
    }

    fn counters(&self, _: &mut Counters) {}
}

/// The streams of `camera` that some consumer of `stages` has not subscribed to
/// yet (each stream also has the replay's own subscriber), as `stream: have/n`;
/// an optional consumer that stopped (a bad `[mqtt]` broker URL) is not waited
/// for. Fails with the name and state of a required service that stopped.
fn missing_consumers(
    ipc: &Ipc,
    camera: &str,
    stages: &[(StageKind, PathBuf)],
    supervisor: &mut Supervisor,
) -> Result<Vec<String>, (String, State)> {
    supervisor.poll();
    let states = supervisor.states();
    let stopped = |stage: StageKind| {
        is_optional(stage.name())
            && states.iter().any(|(name, s)| {
                name == stage.name() && matches!(s, State::Failed { .. } | State::Finished)
            })
    };
    let mut expected: BTreeMap<Stream, usize> = BTreeMap::new();
    for (stage, _) in stages.iter().filter(|(s, _)| !stopped(*s)) {
        for input in stage.consumes() {
            *expected.entry(*input).or_insert(1) += 1;
        }
    }
    if let Some((name, state)) = states
        .iter()
        .filter(|(name, _)| !is_optional(name))
        .find(|(_, s)| matches!(s, State::Failed { .. } | State::Finished))
    {
        return Err((name.clone(), state.clone()));
    }
    Ok(expected
        .iter()
        .filter_map(|(stream, n)| {
            let have = ipc.subscriber_count(camera, *stream).unwrap_or(0);
            (have < *n).then(|| format!("{stream}: {have}/{n}"))
        })
        .collect())
}
