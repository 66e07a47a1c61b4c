//! The gate stage: `frames` and `activity` in, `events` and `detections` out — run
//! by the stage runtime ([`isochron_runtime::stage`]). Frames go into the ring;
//! activity drives the event trackers; the detector thread runs on gated frames
//! and wakes the stage with each result (a [`Wakeup`], the stage's third input).
//!
//! The gate never waits on the runtime's thread; what it waits for, the runtime
//! does:
//!
//! * lossless (`ipc.lossless`, a replay): after an activity sample that gated
//!   detections, the gate takes no further frame or activity until their results
//!   are in (the detector's wake-ups), so the next second is judged with this
//!   second's detections known, as live with a fast enough detector, and the
//!   ring keeps the frames the jobs name; what stays queued meanwhile holds the
//!   upstream stages back (lossless delivery waits for room);
//! * at the end of the activity stream, the end of the frames stream is awaited
//!   (its samples wake the gate; an alarm ends the wait after [`END_WAIT`]),
//!   then the detections still pending (their wake-ups; an alarm after
//!   [`DRAIN_TIMEOUT`]), and only then is the end passed on.

use std::sync::Arc;
use std::time::{Duration, Instant};

use isochron_config::clock::NS_PER_S;
use isochron_config::{CameraConfig, LoadedConfig};
use isochron_exit::{self as exit, Fatal};
use isochron_runtime::counters::{Counters as StatusCounters, gate};
use isochron_runtime::ipc::{Activity, Detections, Events, Frames, Ipc};
use isochron_runtime::service::ServiceContext;
use isochron_runtime::stage::{Context, Input, Output, Received, Stage, Wakeup};
use isochron_runtime::topology::StageKind;
use isochron_wire::{
    ActivityHeader, DetectionHeader, EventHeader, EventPhase, PixelFormat, Preamble, ZONE_NAME_LEN,
    to_fixed,
};
use parking_lot::Mutex;

use crate::detector::Detector;
use crate::events::Event;
use crate::gate::{Action, Found, Gate, GateSettings};
use crate::ring::FrameRing;
use crate::worker::{DetectorSlots, Job, Outcome, Report, Worker};

/// Serves the camera of `ctx` (the `main` of isochron-gate): opens the stage
/// and runs it until the process is asked to stop.
pub fn run(ctx: ServiceContext) -> Result<(), Fatal> {
    let camera = ctx.camera();
    let (mut gate, inputs) = GateStage::open(&ctx.ipc, &ctx.config, camera)?;
    isochron_runtime::stage::run(&ctx.ipc, &camera.id, &mut gate, &inputs)
}

/// Most detections published for one frame.
const MAX_DETECTIONS: usize = 256;
/// How long the end of a stream waits for queued detections.
pub const DRAIN_TIMEOUT: Duration = Duration::from_secs(60);
/// How long the end of the activity stream waits for the end of the frames
/// (capture sends it before motion can end activity, but a full queue may hold
/// it back for a moment).
pub const END_WAIT: Duration = Duration::from_secs(2);

/// Where the gate is in its input streams.
#[derive(Debug, Clone, Copy)]
enum Phase {
    /// Taking frames and activity as they come.
    Running,
    /// The activity stream ended (`end`): waiting, until `deadline`, for the end
    /// of the frames stream.
    EndingFrames {
        end: ActivityHeader,
        deadline: Instant,
    },
    /// The events are closed: waiting, until `deadline`, for the detections
    /// still pending, then passing the end (`end`) on.
    EndingDetections { end: Preamble, deadline: Instant },
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

/// The gate of one camera: event trackers, frame intake, detector worker, outputs.
pub struct GateStage<'ipc> {
    gate: Gate,
    worker: Worker,
    detector_name: &'static str,
    lossless: bool,
    intake: FrameIntake,
    phase: Phase,
    counters: Counters,
    events: Output<'ipc, Events>,
    detections: Output<'ipc, Detections>,
}

/// The gate's inputs: frames first (they are taken before each activity sample),
/// then activity, then the detector's wake-up.
pub type GateInputs = (Input<Frames>, Input<Activity>, Wakeup);

impl<'ipc> GateStage<'ipc> {
    /// The gate of `camera` on `loaded`'s site, publishing through `ipc`, and its
    /// inputs.
    pub fn open(
        ipc: &'ipc Ipc,
        loaded: &LoadedConfig,
        camera: &CameraConfig,
    ) -> Result<(Self, GateInputs), Fatal> {
        let config = &loaded.config;
        let ring = Arc::new(Mutex::new(FrameRing::new(config.gate.ring_frames)));
        let detector_config = config.gate.detector.clone();
        let base_dir = loaded.base_dir();
        // Live, a busy detector loses work instead of delaying events; a lossless
        // replay detects every gated frame, at the detector's pace: an activity
        // sample gates at most one job per zone, and the gate takes nothing more
        // until they are done, so the queue holds them all.
        let lossless = config.ipc.lossless;
        let queue = if lossless {
            camera.zones.len().max(1)
        } else {
            config.gate.detector.queue
        };
        let (wakeup, waker) = Wakeup::new()
            .map_err(|e| Fatal::with_source(exit::UNAVAILABLE, "the detector's wake-up", e))?;
        let slots = DetectorSlots::of_site(
            &config.site.service_prefix,
            config.gate.detector.concurrent,
            (config.gate.detector.threads, config.gate.detector.cpu_share),
        )
        .map(Arc::new)
        .map_err(|e| Fatal::with_source(exit::UNAVAILABLE, "the detector's slots", e))?;
        let (worker, detector_name) = Worker::start(
            move || Detector::from_config(&detector_config, &base_dir),
            ring.clone(),
            queue,
            slots,
            (!lossless)
                .then(|| isochron_config::clock::saturating_secs(config.gate.detector.slot_wait_s)),
            waker,
        )?;
        let gate = Gate::new(
            GateSettings {
                gate: config.gate.clone(),
                warm_days: config.cascade.warm_days,
            },
            camera.zones.clone(),
        );
        let inputs = (
            Input::open(ipc, &camera.id)?,
            Input::open(ipc, &camera.id)?,
            wakeup,
        );
        let mut detections = Output::new(ipc, &camera.id);
        detections.reserve(MAX_DETECTIONS)?;
        let d = &config.gate.detector;
        tracing::info!(
            camera = %camera.id,
            detector = detector_name,
            "gating the {detector_name} detector on events; the site's detections use at most {:.2} cores ({} slots × {} threads × cpu_share {})",
            d.concurrent as f64 * f64::from(d.threads) * d.cpu_share,
            d.concurrent,
            d.threads,
            d.cpu_share
        );
        let stage = GateStage {
            gate,
            worker,
            detector_name,
            lossless,
            intake: FrameIntake::new(ring),
            phase: Phase::Running,
            counters: Counters::default(),
            events: Output::new(ipc, &camera.id),
            detections,
        };
        Ok((stage, inputs))
    }

    /// Handles one activity sample (frames queued before it are taken first).
    fn on_activity(&mut self, sample: Received<Activity>, cx: &mut Context) -> Result<(), Fatal> {
        let arrived = Instant::now();
        let h = *sample.header();
        if h.preamble.is_end_of_stream() {
            self.phase = Phase::EndingFrames {
                end: h,
                deadline: arrived + END_WAIT,
            };
            return Ok(());
        }
        let grid_len = (h.grid_w * h.grid_h) as usize;
        // An activity sample ends a second: its last frame may be the newest.
        self.intake.keep_newest();
        for action in self.gate.on_activity(&h, sample.payload()) {
            self.execute(&action, &h.preamble, grid_len, cx, arrived)?;
        }
        Ok(())
    }

    /// True while a lossless gate waits for its detections before it takes
    /// anything more (see the module doc).
    fn awaiting_detections(&self) -> bool {
        self.lossless && self.worker.pending() > 0
    }

    /// Takes frames, then activity samples one by one, as long as the gate is
    /// not waiting for its detections or the end of a stream.
    fn take_inputs(
        &mut self,
        (frames, activity, _): &GateInputs,
        cx: &mut Context,
    ) -> Result<(), Fatal> {
        while matches!(self.phase, Phase::Running) && !self.awaiting_detections() {
            // Frames take a shorter path than activity, but a gate that waited on
            // its detector may have left some queued: take them first, so the
            // frames a job names are in the ring.
            self.intake.drain(frames, cx, &mut self.counters);
            let Some(sample) = activity.next(cx) else {
                break;
            };
            self.on_activity(sample, cx)?;
        }
        Ok(())
    }

    /// Moves an ending stream on as far as it can now; sets the alarm for the
    /// deadline it waits for, if it waits.
    fn end_streams(&mut self, frames: &Input<Frames>, cx: &mut Context) -> Result<(), Fatal> {
        let now = Instant::now();
        if let Phase::EndingFrames { end, deadline } = self.phase {
            self.intake.drain(frames, cx, &mut self.counters);
            if !self.intake.ended && now < deadline {
                cx.alarm_at(deadline);
                return Ok(());
            }
            self.close_events(&end, cx)?;
        }
        if let Phase::EndingDetections { end, deadline } = self.phase {
            let pending = self.worker.pending();
            if pending > 0 && now < deadline {
                cx.alarm_at(deadline);
                return Ok(());
            }
            if pending > 0 {
                tracing::warn!("{pending} detections still pending at the end of the stream");
            }
            self.publish_end_of_stream(&end)?;
            self.phase = Phase::Running;
            cx.cancel_alarm();
            tracing::info!(
                "end of stream: {} events, detector ran on {} of {} frames",
                self.gate.events_started(),
                self.counters.frames_detected,
                self.counters.frames_seen
            );
        }
        Ok(())
    }

    /// The end of the activity stream `end` (the frames taken, or waited for
    /// long enough): closes the open events; the end waits for the detections.
    fn close_events(&mut self, end: &ActivityHeader, cx: &mut Context) -> Result<(), Fatal> {
        if !self.intake.ended {
            tracing::warn!("the activity stream ended before the frames stream did");
        }
        self.intake.keep_newest();
        let from = Preamble {
            capture_time_ns: end.preamble.capture_time_ns,
            ..Preamble::default()
        };
        let grid_len = ((end.grid_w * end.grid_h) as usize).max(1);
        let arrived = Instant::now();
        for action in self.gate.finish() {
            self.execute(&action, &from, grid_len, cx, arrived)?;
        }
        self.phase = Phase::EndingDetections {
            end: end.preamble,
            deadline: arrived + DRAIN_TIMEOUT,
        };
        Ok(())
    }

    /// Carries out one action of the gate.
    fn execute(
        &mut self,
        action: &Action,
        from: &Preamble,
        grid_len: usize,
        cx: &mut Context,
        arrived: Instant,
    ) -> Result<(), Fatal> {
        match action {
            Action::Event { phase, zone, event } => {
                self.publish_event(*phase, zone, event, from, grid_len)?;
                cx.health.sent(Some(arrived), from.origin_wall_ns);
                if *phase == EventPhase::Start {
                    tracing::info!(event = event.id, zone = %zone, kind = event.kind.name(), "event started");
                }
            }
            Action::Detect(job) => {
                if !self.worker.submit(*job) {
                    tracing::debug!(event = job.event_id, "detector busy: detection dropped");
                    self.gate.on_detections(job.id, job.region, None);
                }
            }
        }
        Ok(())
    }

    fn publish_event(
        &mut self,
        phase: EventPhase,
        zone: &str,
        event: &Event,
        from: &Preamble,
        grid_len: usize,
    ) -> Result<(), Fatal> {
        // The publisher is sized for the grid, which the first activity sample tells.
        self.events.reserve(grid_len)?;
        let ended = phase == EventPhase::End;
        let header = EventHeader {
            preamble: self.events.preamble(event.blocks.len(), from),
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
        Ok(self.events.send_copy(header, &event.blocks)?)
    }

    /// Jobs dropped so far: refused by a busy worker, or lost after acceptance.
    fn jobs_dropped(&self) -> u64 {
        self.worker.dropped + self.counters.jobs_lost()
    }

    /// Publishes a finished detection, or counts a job that did not run; either
    /// way the gate hears how its job went.
    fn handle_report(&mut self, report: Report) -> Result<(), Fatal> {
        let c = &mut self.counters;
        let job = match report {
            Report::Done(outcome) => {
                c.frames_detected += 1;
                c.detector_total_us += outcome.detector_us;
                let found = Found {
                    capture_time_ns: outcome.capture_time_ns,
                    source_index: outcome.source_index,
                    detections: &outcome.detections,
                };
                self.gate
                    .on_detections(outcome.job_id, outcome.region, Some(found));
                return self.publish_detections(&outcome);
            }
            Report::FrameGone(job) => not_run(
                job,
                &mut c.frames_gone,
                "the gated frame left the ring before the detector got to it",
            ),
            Report::Busy(job) => not_run(
                job,
                &mut c.detector_busy,
                "every detector slot of the process was busy: detection dropped",
            ),
            Report::Failed(job, e) => {
                c.detector_errors += 1;
                tracing::warn!(event = job.event_id, "detector failed: {e}");
                job
            }
        };
        self.gate.on_detections(job.id, job.region, None);
        Ok(())
    }

    fn publish_detections(&mut self, o: &Outcome) -> Result<(), Fatal> {
        let n = o.detections.len().min(MAX_DETECTIONS);
        let from = Preamble {
            capture_time_ns: o.capture_time_ns,
            origin_wall_ns: o.origin_wall_ns,
            ..Preamble::default()
        };
        let header = DetectionHeader {
            preamble: self.detections.preamble(n, &from),
            event_id: o.event_id,
            source_index: o.source_index,
            detector_us: o.detector_us,
            roi_x: o.region.x,
            roi_y: o.region.y,
            roi_w: o.region.w,
            roi_h: o.region.h,
            ..self.totals()
        };
        Ok(self.detections.send_copy(header, &o.detections[..n])?)
    }

    /// A detections header carrying the running totals.
    fn totals(&self) -> DetectionHeader {
        DetectionHeader {
            frames_seen: self.counters.frames_seen,
            frames_detected: self.counters.frames_detected,
            jobs_dropped: self.jobs_dropped(),
            detector_total_us: self.counters.detector_total_us,
            ..DetectionHeader::default()
        }
    }

    /// Passes the end of stream on, detections (with the final totals) first.
    fn publish_end_of_stream(&mut self, from: &Preamble) -> Result<(), Fatal> {
        let from = Preamble {
            capture_time_ns: from.capture_time_ns,
            ..Preamble::default()
        };
        let totals = self.totals();
        self.detections.end_of_stream(&from, |h| {
            *h = DetectionHeader {
                preamble: h.preamble,
                ..totals
            }
        })?;
        self.events.end_of_stream(&from, |_| {})?;
        Ok(())
    }
}

/// Counts a detection job that did not run (`why`, at debug level) and hands it back.
fn not_run(job: Job, counter: &mut u64, why: &str) -> Job {
    *counter += 1;
    tracing::debug!(event = job.event_id, "{why}");
    job
}

impl Stage for GateStage<'_> {
    type Inputs = GateInputs;
    const KIND: StageKind = StageKind::Gate;

    fn on_wake(&mut self, inputs: &GateInputs, cx: &mut Context) -> Result<(), Fatal> {
        // The detector's results (its wake-up is the third input).
        for report in self.worker.reports() {
            self.handle_report(report)?;
        }
        loop {
            self.take_inputs(inputs, cx)?;
            let ending = !matches!(self.phase, Phase::Running);
            self.end_streams(&inputs.0, cx)?;
            // An end passed on just now: activity that came since is taken next.
            if !(ending && matches!(self.phase, Phase::Running)) {
                return Ok(());
            }
        }
    }

    fn counters(&self, c: &mut StatusCounters) {
        c.set(gate::EVENTS, self.gate.events_started());
        c.set(gate::OPEN, self.gate.open_events());
        c.set(gate::CONFIRMED, self.gate.confirmed());
        c.set(gate::FRAMES_SEEN, self.counters.frames_seen);
        c.set(gate::DETECTED, self.counters.frames_detected);
        c.set(
            gate::DETECTOR_MS,
            self.counters.detector_total_us as f64 / 1e3,
        );
        c.set(gate::JOBS, self.worker.submitted);
        c.set(gate::JOBS_DROPPED, self.jobs_dropped());
    }

    fn info(&self) -> String {
        format!("detector={}", self.detector_name)
    }
}

/// Takes the `frames` stream into the detector's ring.
///
/// A detection job names the end of a second, so the detector only ever looks
/// at the last frame of a second: the newest frame stays in shared memory and
/// is copied into the ring only once it is known to be its second's last (a
/// later second's frame arrived, or an activity sample did). One copy per
/// second instead of one per frame.
struct FrameIntake {
    ring: Arc<Mutex<FrameRing>>,
    newest: Option<Received<Frames>>,
    ended: bool,
}

impl FrameIntake {
    /// Intake into `ring`.
    fn new(ring: Arc<Mutex<FrameRing>>) -> Self {
        FrameIntake {
            ring,
            newest: None,
            ended: false,
        }
    }

    /// Takes every frame queued now.
    fn drain(&mut self, frames: &Input<Frames>, cx: &mut Context, counters: &mut Counters) {
        // A full batch leaves frames queued: take them all, the ring needs them.
        loop {
            let mut took = false;
            while let Some(sample) = frames.next(cx) {
                took = true;
                self.take(sample, cx, counters);
            }
            if !took {
                break;
            }
        }
    }

    fn take(&mut self, sample: Received<Frames>, cx: &mut Context, counters: &mut Counters) {
        let h = *sample.header();
        if h.preamble.is_end_of_stream() {
            self.ended = true;
            return;
        }
        self.ended = false;
        if h.format() != PixelFormat::Gray8 {
            cx.health.rejected();
            cx.warnings.warn("format", || {
                format!(
                    "rejected a {:?} frame: the gate reads GRAY8 frames",
                    h.format()
                )
            });
            return;
        }
        counters.frames_seen += 1;
        let second = h.preamble.capture_time_ns.div_euclid(NS_PER_S);
        if let Some(held) = self.newest.take()
            && held.header().preamble.capture_time_ns.div_euclid(NS_PER_S) != second
        {
            self.keep(&held); // the last frame of its second
        }
        self.newest = Some(sample);
    }

    /// Copies the newest frame into the ring: it is the last of its second.
    fn keep_newest(&mut self) {
        if let Some(held) = self.newest.take() {
            self.keep(&held);
        }
    }

    /// Copies a frame into the ring the detector reads.
    fn keep(&self, sample: &Received<Frames>) {
        let h = sample.header();
        self.ring.lock().push(
            h.preamble.capture_time_ns,
            h.source_index,
            h.width,
            h.height,
            sample.payload(),
        );
    }
}
