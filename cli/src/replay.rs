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

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use iceoryx2::prelude::*;
use isochron_config::clock::format_rfc3339;
use isochron_config::{Config, LoadedConfig, Speed};
use isochron_runtime::health::InputCompleteness;
use isochron_runtime::ipc::{
    Activity, Detections, Events, Frames, Ipc, IpcError, Motion, StreamSubscriber, StreamType,
};
use isochron_runtime::topology::StageKind;
use isochron_wire::{ActivityKind, DetectionHeader, EventPhase, Stream, fixed_str};
use serde_json::json;

use crate::launch::{ServiceSpec, State, Supervisor, group_specs, installed_stages};
use crate::record::RecorderThread;

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
    /// Capture time of the first frame (RFC 3339). Default: the camera's `start`, or now.
    #[arg(long)]
    start: Option<String>,
    /// `max` (as fast as every stage keeps up, lossless) or a factor of real time.
    #[arg(long, default_value = "max")]
    speed: String,
    /// Give up if no stage makes progress for this many seconds.
    #[arg(long, default_value_t = 120.0)]
    stall_timeout_s: f64,
    /// Also record the run into this MCAP file, as `isochron record` does (opens in
    /// Foxglove; images only with `view.frames = true`).
    #[arg(long)]
    record: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let video = args
        .video
        .canonicalize()
        .with_context(|| format!("video file {} does not exist", args.video.display()))?;
    let speed = Speed::parse(&args.speed).with_context(|| {
        format!(
            "--speed: expected `max` or a number > 0, found '{}'",
            args.speed
        )
    })?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let out = args.out.canonicalize()?;

    let (loaded, camera) = effective_config(&args, &video, speed, &out)?;
    let stages = installed_stages();
    if !stages.iter().any(|(s, _)| *s == StageKind::Capture) {
        bail!(
            "{} is not installed next to this binary ({})",
            StageKind::Capture.binary(),
            crate::launch::bin_dir().display()
        );
    }
    let ipc = Ipc::of_site("isochron-replay", &loaded.config)?;
    let subscribers = Subscribers::open(&ipc, &camera, &stages)?;
    // The recorder runs on a thread of its own, woken by its own subscribers.
    let recorder = args
        .record
        .as_deref()
        .map(|path| RecorderThread::start(&loaded, path))
        .transpose()?;
    let mut tally = Tally::new(&camera, &subscribers, &out)?;

    let specs = group_specs(&loaded);
    let mut supervisor = Supervisor::new(false, Duration::from_secs(60), Some(out.join("logs")))?;
    let started = Instant::now();
    // Consumers first; the producer only once everything downstream listens.
    let (capture, rest): (Vec<ServiceSpec>, Vec<ServiceSpec>) = specs
        .into_iter()
        .partition(|s| s.stage == StageKind::Capture);
    for spec in rest {
        supervisor.add(spec)?;
    }
    // Optional consumers (the MQTT sink) get every sample too.
    let consumers: Vec<_> = stages
        .iter()
        .cloned()
        .chain(crate::launch::optional_services(&loaded))
        .collect();
    wait_for_consumers(&ipc, &camera, &consumers, &mut supervisor)?;
    // Capture's last status says how much of the file it read (it publishes it
    // before the end of stream); subscribed before capture starts.
    let capture_status = ipc.status_subscriber(&camera, StageKind::Capture)?;
    let mut capture_detail = None;
    for spec in capture {
        supervisor.add(spec)?;
    }
    println!(
        "replay: {} → {} (speed {speed}, prefix {})",
        video.display(),
        out.display(),
        loaded.config.site.service_prefix
    );

    let waitset = WaitSetBuilder::new()
        .create::<ipc::Service>()
        .map_err(|e| anyhow::anyhow!("creating a waitset: {e:?}"))?;
    let guards = subscribers.attach(&waitset)?;
    let stall = Duration::from_secs_f64(args.stall_timeout_s);
    let mut last_progress = Instant::now();
    let mut last_total = 0;
    loop {
        let _ = waitset.wait_and_process_once_with_timeout(
            |_| CallbackProgression::Continue,
            Duration::from_millis(100),
        );
        tally.drain(&subscribers)?;
        if let Some(status) = capture_status.latest() {
            capture_detail = Some(fixed_str(&status.detail));
        }
        if tally.all_ended() {
            break;
        }
        if ipc.should_stop() {
            bail!("interrupted");
        }
        for change in supervisor.poll() {
            tracing::info!("{} {}", change.name, change.what);
        }
        if let Some((name, state)) = supervisor
            .states()
            .into_iter()
            .filter(|(name, _)| !is_optional(name))
            .find(|(_, s)| matches!(s, State::Failed { .. }))
        {
            bail!(
                "{name} failed ({state:?}) before the end of the video; see {}",
                out.join("logs").display()
            );
        }
        let total = tally.total();
        if total != last_total {
            last_total = total;
            last_progress = Instant::now();
        } else if last_progress.elapsed() > stall {
            bail!(
                "no progress for {:.0} s (counts so far: {}); see {}",
                stall.as_secs_f64(),
                tally.counts_line(),
                out.join("logs").display()
            );
        }
    }
    let wall = started.elapsed();
    drop(guards);
    supervisor.stop_all(Duration::from_secs(10));
    // What arrived is recorded, then the file closed (early, and the replay went
    // on, if the disk ran low: then the exit code is 1).
    let recording_failed = recorder
        .map(RecorderThread::finish)
        .transpose()?
        .is_some_and(|code| code != ExitCode::SUCCESS);
    let input = capture_detail
        .as_deref()
        .and_then(InputCompleteness::from_detail);
    tally.finish(&out, &video, wall, input)?;
    println!(
        "replay: {} in {:.1} s",
        tally.counts_line(),
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

/// The config the group runs with: the chosen camera replays `video`, alone, under a
/// private prefix, with its store in `out/state`.
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
            .with_context(|| format!("no camera '{id}' in the config"))?,
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
    let path = out.join("config.toml");
    std::fs::write(&path, toml::to_string_pretty(&config)?)
        .with_context(|| format!("writing {}", path.display()))?;
    // Validate exactly what the services will read.
    let loaded = Config::load(&path)?;
    Ok((loaded, id))
}

/// True for the service `name` of an optional stage (the exporter, the MQTT
/// sink): its failure is logged (in `DIR/logs`) but does not stop the replay.
fn is_optional(name: &str) -> bool {
    name == StageKind::Exporter.name() || name == StageKind::Mqtt.name()
}

/// Waits until every installed consumer has subscribed to its inputs (each stream
/// also has the replay's own subscriber); an optional one that stopped (a bad
/// `[mqtt]` broker URL) is not waited for.
fn wait_for_consumers(
    ipc: &Ipc,
    camera: &str,
    stages: &[(StageKind, PathBuf)],
    supervisor: &mut Supervisor,
) -> anyhow::Result<()> {
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
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
        let missing: Vec<String> = expected
            .iter()
            .filter_map(|(stream, n)| {
                let have = ipc.subscriber_count(camera, *stream).unwrap_or(0);
                (have < *n).then(|| format!("{stream}: {have}/{n}"))
            })
            .collect();
        if missing.is_empty() {
            return Ok(());
        }
        if let Some((name, state)) = supervisor
            .states()
            .into_iter()
            .filter(|(name, _)| !is_optional(name))
            .find(|(_, s)| matches!(s, State::Failed { .. } | State::Finished))
        {
            bail!("{name} stopped during start-up ({state:?}); see its log");
        }
        if Instant::now() > deadline {
            bail!(
                "services did not subscribe in time ({})",
                missing.join(", ")
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// The replay's own subscribers, one per produced stream.
struct Subscribers {
    frames: StreamSubscriber<Frames>,
    motion: Option<StreamSubscriber<Motion>>,
    activity: Option<StreamSubscriber<Activity>>,
    events: Option<StreamSubscriber<Events>>,
    detections: Option<StreamSubscriber<Detections>>,
}

impl Subscribers {
    fn open(ipc: &Ipc, camera: &str, stages: &[(StageKind, PathBuf)]) -> anyhow::Result<Self> {
        let has = |stream: Stream| {
            stages
                .iter()
                .any(|(stage, _)| stage.produces().contains(&stream))
        };
        fn subscriber_if<S: StreamType>(
            ipc: &Ipc,
            camera: &str,
            wanted: bool,
        ) -> Result<Option<StreamSubscriber<S>>, IpcError> {
            wanted.then(|| ipc.subscriber(camera)).transpose()
        }
        Ok(Subscribers {
            frames: ipc.subscriber(camera)?,
            motion: subscriber_if(ipc, camera, has(Stream::Motion))?,
            activity: subscriber_if(ipc, camera, has(Stream::Activity))?,
            events: subscriber_if(ipc, camera, has(Stream::Events))?,
            detections: subscriber_if(ipc, camera, has(Stream::Detections))?,
        })
    }

    fn attach<'w>(
        &'w self,
        waitset: &'w WaitSet<ipc::Service>,
    ) -> anyhow::Result<Vec<WaitSetGuard<'w, 'w, ipc::Service>>> {
        let mut attachments: Vec<&dyn SynchronousMultiplexingDebug> = vec![&self.frames];
        if let Some(s) = &self.motion {
            attachments.push(s);
        }
        if let Some(s) = &self.activity {
            attachments.push(s);
        }
        if let Some(s) = &self.events {
            attachments.push(s);
        }
        if let Some(s) = &self.detections {
            attachments.push(s);
        }
        attachments
            .into_iter()
            .map(|a| {
                waitset
                    .attach_notification(a)
                    .map_err(|e| anyhow::anyhow!("attaching to the waitset: {e:?}"))
            })
            .collect()
    }
}

/// What a WaitSet can wait on.
trait SynchronousMultiplexingDebug: SynchronousMultiplexing + std::fmt::Debug {}
impl<T: SynchronousMultiplexing + std::fmt::Debug> SynchronousMultiplexingDebug for T {}

/// Samples seen per stream, and the files written from them.
struct Tally {
    camera: String,
    counts: BTreeMap<Stream, u64>,
    ended: BTreeMap<Stream, bool>,
    events_out: BufWriter<File>,
    detections_out: BufWriter<File>,
    finished_events: u64,
    gate: serde_json::Value,
}

/// The hybrid scheme's counters as a detections header states them.
fn gate_summary(h: &DetectionHeader) -> serde_json::Value {
    json!({
        "frames_seen": h.frames_seen,
        "frames_detected": h.frames_detected,
        "jobs_dropped": h.jobs_dropped,
        "detector_total_ms": h.detector_total_us as f64 / 1e3,
    })
}

/// Receives every pending sample of `subscriber`; calls `each` for data samples.
/// Returns (data samples, saw end of stream).
fn drain_one<S: StreamType>(
    subscriber: &StreamSubscriber<S>,
    mut end: impl FnMut(&S::Header) -> bool,
    mut each: impl FnMut(&S::Header, &[S::Element]) -> anyhow::Result<()>,
) -> anyhow::Result<(u64, bool)> {
    subscriber.drain_wakeups();
    let (mut n, mut ended) = (0, false);
    while let Some(sample) = subscriber.receive()? {
        if end(sample.user_header()) {
            ended = true;
        } else {
            n += 1;
            each(sample.user_header(), sample.payload())?;
        }
    }
    Ok((n, ended))
}

impl Tally {
    fn new(camera: &str, subs: &Subscribers, out: &Path) -> anyhow::Result<Self> {
        let create = |name: &str| -> anyhow::Result<BufWriter<File>> {
            let path = out.join(name);
            Ok(BufWriter::new(
                File::create(&path).with_context(|| format!("creating {}", path.display()))?,
            ))
        };
        let mut ended = BTreeMap::new();
        ended.insert(Stream::Frames, false);
        for (stream, present) in [
            (Stream::Motion, subs.motion.is_some()),
            (Stream::Activity, subs.activity.is_some()),
            (Stream::Events, subs.events.is_some()),
            (Stream::Detections, subs.detections.is_some()),
        ] {
            if present {
                ended.insert(stream, false);
            }
        }
        Ok(Tally {
            camera: camera.to_string(),
            counts: Stream::ALL.iter().map(|s| (*s, 0)).collect(),
            ended,
            events_out: create("events.jsonl")?,
            detections_out: create("detections.jsonl")?,
            finished_events: 0,
            gate: json!({}),
        })
    }

    fn add(&mut self, stream: Stream, (n, ended): (u64, bool)) {
        *self.counts.entry(stream).or_default() += n;
        if ended {
            self.ended.insert(stream, true);
        }
    }

    /// Reads everything that arrived.
    fn drain(&mut self, subs: &Subscribers) -> anyhow::Result<()> {
        let r = drain_one(
            &subs.frames,
            |h| h.preamble.is_end_of_stream(),
            |_, _| Ok(()),
        )?;
        self.add(Stream::Frames, r);
        if let Some(s) = &subs.motion {
            let r = drain_one(s, |h| h.preamble.is_end_of_stream(), |_, _| Ok(()))?;
            self.add(Stream::Motion, r);
        }
        if let Some(s) = &subs.activity {
            let r = drain_one(s, |h| h.preamble.is_end_of_stream(), |_, _| Ok(()))?;
            self.add(Stream::Activity, r);
        }
        if let Some(s) = &subs.events {
            let camera = &self.camera;
            let out = &mut self.events_out;
            let finished = &mut self.finished_events;
            let r = drain_one(
                s,
                |h| h.preamble.is_end_of_stream(),
                |h, blocks| {
                    if h.phase != EventPhase::End as u32 {
                        return Ok(());
                    }
                    *finished += 1;
                    let line = json!({
                        "camera": camera,
                        "event_id": h.event_id,
                        "zone": h.zone_name(),
                        "kind": ActivityKind::from_u32(h.kind).map(|k| k.name()).unwrap_or("?"),
                        "start": format_rfc3339(h.start_ns),
                        "end": format_rfc3339(h.end_ns),
                        "start_frame": h.start_frame,
                        "end_frame": h.end_frame,
                        "peak": h.peak,
                        "threshold": h.threshold,
                        "blocks": blocks,
                    });
                    writeln!(out, "{line}")?;
                    Ok(())
                },
            )?;
            self.add(Stream::Events, r);
        }
        if let Some(s) = &subs.detections {
            let camera = &self.camera;
            let out = &mut self.detections_out;
            let (mut final_counters, mut last_counters) = (None, None);
            let r = drain_one(
                s,
                |h| {
                    // The end of stream carries the gate's final counters.
                    let end = h.preamble.is_end_of_stream();
                    if end {
                        final_counters = Some(gate_summary(h));
                    }
                    end
                },
                |h, dets| {
                    let line = json!({
                        "camera": camera,
                        "event_id": h.event_id,
                        "frame": h.source_index,
                        "capture_time": format_rfc3339(h.preamble.capture_time_ns),
                        "detector_ms": h.detector_us as f64 / 1e3,
                        "searched": [h.roi_x, h.roi_y, h.roi_w, h.roi_h],
                        "detections": dets.iter().map(|d| json!({
                            "x": d.x, "y": d.y, "w": d.w, "h": d.h, "score": d.score, "class": d.class
                        })).collect::<Vec<_>>(),
                    });
                    writeln!(out, "{line}")?;
                    last_counters = Some(gate_summary(h));
                    Ok(())
                },
            )?;
            if let Some(summary) = final_counters.or(last_counters) {
                self.gate = summary;
            }
            self.add(Stream::Detections, r);
        }
        Ok(())
    }

    fn all_ended(&self) -> bool {
        self.ended.values().all(|e| *e)
    }

    /// Counts per stream, with events counted as finished events.
    fn counts(&self) -> Vec<(&'static str, u64)> {
        Stream::ALL
            .iter()
            .map(|s| {
                let n = if *s == Stream::Events {
                    self.finished_events
                } else {
                    self.counts[s]
                };
                (s.name(), n)
            })
            .collect()
    }

    fn total(&self) -> u64 {
        self.counts.values().sum()
    }

    fn counts_line(&self) -> String {
        self.counts()
            .iter()
            .map(|(k, v)| format!("{k}={v}"))
            .collect::<Vec<_>>()
            .join(" ")
    }

    /// Writes `summary.json`; `input` is capture's account of the file (see
    /// [`InputCompleteness`]), if it gave one.
    fn finish(
        &mut self,
        out: &Path,
        video: &Path,
        wall: Duration,
        input: Option<InputCompleteness>,
    ) -> anyhow::Result<()> {
        self.events_out.flush()?;
        self.detections_out.flush()?;
        let counts: serde_json::Map<String, serde_json::Value> = self
            .counts()
            .into_iter()
            .map(|(k, v)| (k.to_string(), json!(v)))
            .collect();
        let frames = self.counts[&Stream::Frames];
        let summary = json!({
            "video": video,
            "camera": self.camera,
            "counts": counts,
            "wall_time_s": wall.as_secs_f64(),
            "frames_per_s": frames as f64 / wall.as_secs_f64().max(1e-9),
            "gate": self.gate,
            "input": match input {
                Some(i) => json!({
                    "frames_stated": (i.frames_stated > 0).then_some(i.frames_stated),
                    "frames_read": i.frames_read,
                    "truncated": i.truncated,
                }),
                // Capture said nothing (it did not end on the file): unknown.
                None => json!({
                    "frames_stated": null,
                    "frames_read": frames,
                    "truncated": null,
                }),
            },
        });
        let path = out.join("summary.json");
        std::fs::write(&path, serde_json::to_string_pretty(&summary)? + "\n")
            .with_context(|| format!("writing {}", path.display()))?;
        Ok(())
    }
}
