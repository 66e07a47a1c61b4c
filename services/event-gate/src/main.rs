//! isochron-gate: config → node → `frames` + `activity` in, `events` + `detections`
//! out → loop. Frames go into the ring; activity drives the event trackers; the
//! detector thread runs on the gated frames.

use std::process::ExitCode;
use std::sync::Arc;
use std::time::{Duration, Instant};

use clap::Parser;
use iceoryx2::prelude::*;
use isochron_gate::detector::Detector;
use isochron_gate::gate::{Action, Gate, GateSettings};
use isochron_gate::ring::FrameRing;
use isochron_gate::worker::{DetectorSlots, Outcome, Report, Worker};
use isochron_shared::clock::NS_PER_S;
use isochron_shared::health::{Health, exit, notify_ready};
use isochron_shared::ipc::{
    Activity, Detections, Events, Frames, Ipc, ReceivedSample, StreamPublisher, StreamSubscriber,
    stop_requested_by,
};
use isochron_shared::service::{CameraArgs, Fatal, ServiceContext, run_cameras};
use isochron_shared::topology::StageKind;
use isochron_shared::wire::{
    CameraId, DetectionHeader, EventHeader, EventPhase, FLAG_END_OF_STREAM, PixelFormat, Preamble,
    Stream, ZONE_NAME_LEN, to_fixed,
};
use parking_lot::Mutex;

/// Most detections published for one frame.
const MAX_DETECTIONS: usize = 256;
/// How long the end of a stream waits for queued detections.
const DRAIN_TIMEOUT: Duration = Duration::from_secs(60);

/// Raises events from a camera's activity and runs the detector on gated frames.
#[derive(Parser)]
#[command(version)]
struct Args {
    #[command(flatten)]
    service: CameraArgs,
}

fn main() -> ExitCode {
    let args = Args::parse();
    run_cameras(StageKind::Gate, &args.service, run)
}

/// Counters of the hybrid scheme.
#[derive(Default)]
struct Counters {
    frames_seen: u64,
    frames_detected: u64,
    detector_total_us: u64,
    frames_gone: u64,
    detector_busy: u64,
    detector_errors: u64,
}

impl Counters {
    /// Accepted jobs that never ran: their frame left the ring, or every detector
    /// slot of the process was busy.
    fn jobs_lost(&self) -> u64 {
        self.frames_gone + self.detector_busy
    }
}

/// The output side: event and detection publishers.
struct Outputs<'a> {
    ipc: &'a Ipc,
    camera: String,
    camera_id: CameraId,
    events: Option<(StreamPublisher<Events>, usize)>,
    detections: StreamPublisher<Detections>,
}

impl Outputs<'_> {
    fn publish_event(
        &mut self,
        phase: EventPhase,
        zone: &str,
        event: &isochron_gate::events::Event,
        now_ns: i64,
        origin_wall_ns: i64,
        grid_len: usize,
    ) -> Result<(), Fatal> {
        // The publisher is sized for the grid, which the first activity sample tells.
        if self.events.as_ref().is_none_or(|(_, len)| *len != grid_len) {
            self.events = None;
            let p = self
                .ipc
                .publisher::<Events>(&self.camera, grid_len)
                .map_err(|e| Fatal::new(exit::UNAVAILABLE, e.to_string()))?;
            self.events = Some((p, grid_len));
        }
        let (publisher, _) = self.events.as_mut().expect("events publisher");
        let mut preamble = Preamble::new::<u32>(
            Stream::Events,
            self.camera_id,
            publisher.next_sequence(),
            event.blocks.len(),
        );
        preamble.capture_time_ns = now_ns;
        preamble.origin_wall_ns = origin_wall_ns;
        let ended = phase == EventPhase::End;
        let header = EventHeader {
            preamble,
            event_id: event.id,
            zone: to_fixed::<ZONE_NAME_LEN>(zone),
            kind: event.kind as u32,
            phase: phase as u32,
            start_ns: event.start_ns,
            end_ns: if ended { event.end_ns } else { 0 },
            start_frame: event.start_frame,
            end_frame: if ended { event.end_frame } else { 0 },
            peak: event.peak,
            threshold: event.threshold,
        };
        publisher
            .send_copy(header, &event.blocks)
            .map(|_| ())
            .map_err(|e| Fatal::new(exit::UNAVAILABLE, e.to_string()))
    }

    fn publish_detections(&mut self, o: &Outcome, c: &Counters, dropped: u64) -> Result<(), Fatal> {
        let n = o.detections.len().min(MAX_DETECTIONS);
        let mut preamble = Preamble::new::<isochron_shared::wire::Detection>(
            Stream::Detections,
            self.camera_id,
            self.detections.next_sequence(),
            n,
        );
        preamble.capture_time_ns = o.capture_time_ns;
        let header = DetectionHeader {
            preamble,
            event_id: o.event_id,
            source_index: o.source_index,
            detector_us: o.detector_us,
            frames_seen: c.frames_seen,
            frames_detected: c.frames_detected,
            jobs_dropped: dropped,
            detector_total_us: c.detector_total_us,
        };
        self.detections
            .send_copy(header, &o.detections[..n])
            .map(|_| ())
            .map_err(|e| Fatal::new(exit::UNAVAILABLE, e.to_string()))
    }

    fn publish_end_of_stream(
        &mut self,
        time_ns: i64,
        c: &Counters,
        dropped: u64,
    ) -> Result<(), Fatal> {
        let fail = |e: isochron_shared::ipc::IpcError| Fatal::new(exit::UNAVAILABLE, e.to_string());
        let mut preamble = Preamble::new::<isochron_shared::wire::Detection>(
            Stream::Detections,
            self.camera_id,
            self.detections.next_sequence(),
            0,
        );
        preamble.capture_time_ns = time_ns;
        preamble.flags = FLAG_END_OF_STREAM;
        let header = DetectionHeader {
            preamble,
            frames_seen: c.frames_seen,
            frames_detected: c.frames_detected,
            jobs_dropped: dropped,
            detector_total_us: c.detector_total_us,
            ..Default::default()
        };
        self.detections.send_copy(header, &[]).map_err(fail)?;
        if self.events.is_none() {
            let p = self
                .ipc
                .publisher::<Events>(&self.camera, 1)
                .map_err(fail)?;
            self.events = Some((p, 1));
        }
        let (events, _) = self.events.as_mut().expect("events publisher");
        let mut preamble =
            Preamble::new::<u32>(Stream::Events, self.camera_id, events.next_sequence(), 0);
        preamble.capture_time_ns = time_ns;
        preamble.flags = FLAG_END_OF_STREAM;
        events
            .send_copy(
                EventHeader {
                    preamble,
                    ..Default::default()
                },
                &[],
            )
            .map(|_| ())
            .map_err(fail)
    }
}

fn run(ctx: ServiceContext) -> Result<(), Fatal> {
    let cam = ctx.camera().clone();
    let config = &ctx.config.config;
    let camera_id = CameraId::new(&cam.id).expect("validated camera id");
    let unavailable =
        |e: isochron_shared::ipc::IpcError| Fatal::new(exit::UNAVAILABLE, e.to_string());

    let ring = Arc::new(Mutex::new(FrameRing::new(config.gate.ring_frames)));
    let detector_config = config.gate.detector.clone();
    let base_dir = ctx.config.base_dir();
    // Live, a busy detector loses work instead of delaying events; a lossless
    // replay detects every gated frame, at the detector's pace.
    let lossless = config.ipc.lossless;
    let queue = if lossless {
        0
    } else {
        config.gate.detector.queue
    };
    let slots =
        DetectorSlots::of_site(&config.site.service_prefix, config.gate.detector.concurrent)
            .map(Arc::new)
            .map_err(|e| Fatal::new(exit::UNAVAILABLE, e.to_string()))?;
    let (mut worker, detector_name) = Worker::start(
        move || Detector::from_config(&detector_config, &base_dir),
        ring.clone(),
        queue,
        slots,
        lossless,
    )
    .map_err(|e| Fatal::new(exit::CONFIG, e))?;
    let mut gate = Gate::new(
        GateSettings {
            gate: config.gate.clone(),
            warm_days: config.cascade.warm_days,
        },
        cam.zones.clone(),
    );

    let frames = ctx.ipc.subscriber::<Frames>(&cam.id).map_err(unavailable)?;
    let activity = ctx
        .ipc
        .subscriber::<Activity>(&cam.id)
        .map_err(unavailable)?;
    let mut outputs = Outputs {
        ipc: &ctx.ipc,
        camera: cam.id.clone(),
        camera_id,
        events: None,
        detections: ctx
            .ipc
            .publisher::<Detections>(&cam.id, MAX_DETECTIONS)
            .map_err(unavailable)?,
    };
    let waitset = WaitSetBuilder::new()
        .create::<ipc::Service>()
        .map_err(|e| Fatal::new(exit::UNAVAILABLE, format!("creating a waitset: {e:?}")))?;
    let attach = |e| {
        Fatal::new(
            exit::UNAVAILABLE,
            format!("attaching to the waitset: {e:?}"),
        )
    };
    let _frames_guard = waitset.attach_notification(&frames).map_err(attach)?;
    let _activity_guard = waitset.attach_notification(&activity).map_err(attach)?;

    let mut health = Health::new("gate", &cam.id, Some(&ctx.ipc));
    let mut counters = Counters::default();
    let mut intake = FrameIntake::new(camera_id, ring.clone());
    tracing::info!(camera = %cam.id, detector = detector_name, "gating the {detector_name} detector on events");
    notify_ready(&format!("gating {}", cam.id));

    while !ctx.ipc.should_stop() {
        let result = waitset.wait_and_process_once_with_timeout(
            |_| CallbackProgression::Continue,
            Duration::from_millis(100),
        );
        if result.as_ref().is_ok_and(stop_requested_by) {
            break;
        }

        frames.drain_wakeups();
        intake.drain(&frames, &mut health, &mut counters)?;

        activity.drain_wakeups();
        while let Some(sample) = activity.receive().map_err(unavailable)? {
            // Frames take a shorter path than activity, but a gate that waited on
            // its detector may have left some queued: take them first, so the
            // frames a job names are in the ring.
            intake.drain(&frames, &mut health, &mut counters)?;
            let arrived = Instant::now();
            let h = *sample.user_header();
            if let Err(e) = h.validate(&camera_id, sample.payload().len()) {
                tracing::warn!("rejected an activity sample: {e}");
                health.rejected();
                continue;
            }
            health.received(h.preamble.sequence);
            let grid_len = (h.grid_w * h.grid_h) as usize;
            if h.preamble.is_end_of_stream() {
                intake.finish(&frames, &mut health, &mut counters)?;
                for action in gate.finish() {
                    execute(
                        &action,
                        &mut outputs,
                        &mut worker,
                        lossless,
                        h.preamble.capture_time_ns,
                        0,
                        grid_len.max(1),
                        &mut health,
                        arrived,
                    )?;
                }
                drain_detector(&mut worker, &mut counters, &mut outputs, DRAIN_TIMEOUT)?;
                let dropped = worker.dropped + counters.jobs_lost();
                outputs.publish_end_of_stream(h.preamble.capture_time_ns, &counters, dropped)?;
                tracing::info!(
                    "end of stream: {} events, detector ran on {} of {} frames",
                    gate.events_started(),
                    counters.frames_detected,
                    counters.frames_seen
                );
                continue;
            }
            // An activity sample ends a second: its last frame may be the newest.
            intake.keep_newest();
            for action in gate.on_activity(&h, sample.payload()) {
                execute(
                    &action,
                    &mut outputs,
                    &mut worker,
                    lossless,
                    h.preamble.capture_time_ns,
                    h.preamble.origin_wall_ns,
                    grid_len,
                    &mut health,
                    arrived,
                )?;
            }
        }

        for report in worker.reports() {
            handle_report(report, &mut counters, &mut outputs, worker.dropped)?;
        }
        health.tick(|| {
            format!(
                "detector={detector_name} events={} open={} frames_seen={} detected={} detector_ms={} jobs_dropped={}",
                gate.events_started(),
                gate.open_events(),
                counters.frames_seen,
                counters.frames_detected,
                counters.detector_total_us / 1000,
                worker.dropped + counters.jobs_lost()
            )
        });
    }
    Ok(())
}

/// Takes the `frames` stream into the detector's ring.
///
/// A detection job names the end of a second, so the detector only ever looks
/// at the last frame of a second: the newest frame stays in shared memory and
/// is copied into the ring only once it is known to be its second's last (a
/// later second's frame arrived, or an activity sample did). One copy per
/// second instead of one per frame.
struct FrameIntake {
    camera_id: CameraId,
    ring: Arc<Mutex<FrameRing>>,
    last_sequence: Option<u64>,
    newest: Option<ReceivedSample<Frames>>,
    ended: bool,
}

impl FrameIntake {
    /// How long the end of the activity stream waits for the end of the frames.
    const END_WAIT: Duration = Duration::from_secs(2);

    /// Intake of `camera_id`'s frames into `ring`.
    fn new(camera_id: CameraId, ring: Arc<Mutex<FrameRing>>) -> Self {
        FrameIntake {
            camera_id,
            ring,
            last_sequence: None,
            newest: None,
            ended: false,
        }
    }

    /// Takes every frame queued now.
    fn drain(
        &mut self,
        frames: &StreamSubscriber<Frames>,
        health: &mut Health,
        counters: &mut Counters,
    ) -> Result<(), Fatal> {
        let unavailable =
            |e: isochron_shared::ipc::IpcError| Fatal::new(exit::UNAVAILABLE, e.to_string());
        while let Some(sample) = frames.receive().map_err(unavailable)? {
            let h = sample.user_header();
            if let Err(e) = h.validate(&self.camera_id, sample.payload().len()) {
                tracing::warn!("rejected a frames sample: {e}");
                health.rejected();
                continue;
            }
            if h.preamble.is_end_of_stream() {
                self.ended = true;
                continue;
            }
            self.ended = false;
            if h.format() != PixelFormat::Gray8 {
                tracing::warn!(
                    "rejected a {:?} frame: the gate reads GRAY8 frames",
                    h.format()
                );
                health.rejected();
                continue;
            }
            if let Some(last) = self.last_sequence
                && h.preamble.sequence > last + 1
            {
                // Frames lost on the way (live mode overwrote them).
                health.dropped(h.preamble.sequence - last - 1);
            }
            self.last_sequence = Some(h.preamble.sequence);
            counters.frames_seen += 1;
            let second = h.preamble.capture_time_ns.div_euclid(NS_PER_S);
            if let Some(held) = self.newest.take()
                && held
                    .user_header()
                    .preamble
                    .capture_time_ns
                    .div_euclid(NS_PER_S)
                    != second
            {
                self.keep(&held); // the last frame of its second
            }
            self.newest = Some(sample);
        }
        Ok(())
    }

    /// Copies the newest frame into the ring: it is the last of its second.
    fn keep_newest(&mut self) {
        if let Some(held) = self.newest.take() {
            self.keep(&held);
        }
    }

    /// Copies a frame into the ring the detector reads.
    fn keep(&self, sample: &ReceivedSample<Frames>) {
        let h = sample.user_header();
        self.ring.lock().push(
            h.preamble.capture_time_ns,
            h.source_index,
            h.width,
            h.height,
            sample.payload(),
        );
    }

    /// At the end of the activity stream: takes the frames still on their way,
    /// up to the end of the frames stream (capture sends it before motion can
    /// end activity, but a full queue may hold it back for a moment).
    fn finish(
        &mut self,
        frames: &StreamSubscriber<Frames>,
        health: &mut Health,
        counters: &mut Counters,
    ) -> Result<(), Fatal> {
        let deadline = Instant::now() + Self::END_WAIT;
        loop {
            self.drain(frames, health, counters)?;
            if self.ended || Instant::now() >= deadline {
                break;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        if !self.ended {
            tracing::warn!("the activity stream ended before the frames stream did");
        }
        self.keep_newest();
        Ok(())
    }
}

/// Carries out one action of the gate.
#[allow(clippy::too_many_arguments)]
fn execute(
    action: &Action,
    outputs: &mut Outputs,
    worker: &mut Worker,
    lossless: bool,
    now_ns: i64,
    origin_wall_ns: i64,
    grid_len: usize,
    health: &mut Health,
    arrived: Instant,
) -> Result<(), Fatal> {
    match action {
        Action::Event { phase, zone, event } => {
            outputs.publish_event(*phase, zone, event, now_ns, origin_wall_ns, grid_len)?;
            health.sent(Some(arrived), origin_wall_ns);
            if *phase == EventPhase::Start {
                tracing::info!(event = event.id, zone = %zone, kind = event.kind.name(), "event started");
            }
        }
        Action::Detect(job) => {
            let queued = if lossless {
                worker.submit_wait(*job)
            } else {
                worker.submit(*job)
            };
            if !queued {
                tracing::debug!(event = job.event_id, "detector busy: detection dropped");
            }
        }
    }
    Ok(())
}

fn handle_report(
    report: Report,
    c: &mut Counters,
    outputs: &mut Outputs,
    dropped: u64,
) -> Result<(), Fatal> {
    match report {
        Report::Done(outcome) => {
            c.frames_detected += 1;
            c.detector_total_us += outcome.detector_us;
            outputs.publish_detections(&outcome, c, dropped + c.jobs_lost())?;
        }
        Report::FrameGone(job) => {
            c.frames_gone += 1;
            tracing::debug!(
                event = job.event_id,
                "the gated frame left the ring before the detector got to it"
            );
        }
        Report::Busy(job) => {
            c.detector_busy += 1;
            tracing::debug!(
                event = job.event_id,
                "every detector slot of the process was busy: detection dropped"
            );
        }
        Report::Failed(job, e) => {
            c.detector_errors += 1;
            tracing::warn!(event = job.event_id, "detector failed: {e}");
        }
    }
    Ok(())
}

/// Waits (up to `timeout`) for every queued detection and publishes the results.
fn drain_detector(
    worker: &mut Worker,
    c: &mut Counters,
    outputs: &mut Outputs,
    timeout: Duration,
) -> Result<(), Fatal> {
    let end = Instant::now() + timeout;
    while worker.pending() > 0 {
        let left = end.saturating_duration_since(Instant::now());
        if left.is_zero() {
            tracing::warn!(
                "{} detections still pending at the end of the stream",
                worker.pending()
            );
            break;
        }
        if let Some(report) = worker.wait_report(left) {
            handle_report(report, c, outputs, worker.dropped)?;
        }
    }
    Ok(())
}
