//! isochron-motion: config → node → `frames` subscriber + `motion` publisher →
//! WaitSet loop computing per-block motion features of every frame pair.

use std::process::ExitCode;
use std::time::{Duration, Instant};

use clap::Parser;
use iceoryx2::prelude::*;
use isochron_motion::detector::{FrameReport, MotionDetector};
use isochron_motion::pairing::{FrameInfo, Pairing, pair};
use isochron_shared::config::{CameraConfig, MotionConfig};
use isochron_shared::health::{Health, exit, notify_ready};
use isochron_shared::ipc::{
    Frames, Ipc, Ipc2, Motion, ReceivedSample, StreamPublisher, stop_requested_by,
};
use isochron_shared::service::{CameraArgs, Fatal, ServiceContext, run_cameras};
use isochron_shared::wire::{
    BlockMotion, CameraId, FLAG_END_OF_STREAM, FLAG_ILLUMINATION, FrameHeader, MotionHeader,
    PixelFormat, Preamble, Stream,
};

/// Reads a camera's `frames` and publishes per-block motion on `<prefix>/<camera>/motion`.
#[derive(Parser)]
#[command(version)]
struct Args {
    #[command(flatten)]
    service: CameraArgs,
}

/// Longest wait for a frame before the loop feeds the watchdog and reports anyway.
const IDLE_TICK: Duration = Duration::from_millis(250);

/// Warnings issued before rate limiting starts.
const WARN_BURST: u64 = 10;
/// Then at most one warning per this interval (the rest are counted).
const WARN_EVERY: Duration = Duration::from_secs(5);

fn main() -> ExitCode {
    let args = Args::parse();
    run_cameras("motion", &args.service, run)
}

fn run(ctx: ServiceContext) -> Result<(), Fatal> {
    let cam = ctx.camera().clone();
    let frames = ctx
        .ipc
        .subscriber::<Frames>(&cam.id)
        .map_err(|e| Fatal::new(exit::UNAVAILABLE, e.to_string()))?;
    let mut stage = Stage::new(&ctx.ipc, &cam, ctx.config.config.motion.clone())?;
    let waitset = WaitSetBuilder::new()
        .create::<Ipc2>()
        .map_err(|e| Fatal::new(exit::UNAVAILABLE, format!("creating the WaitSet: {e:?}")))?;
    let _attached = waitset.attach_notification(&frames).map_err(|e| {
        Fatal::new(
            exit::UNAVAILABLE,
            format!("attaching to the WaitSet: {e:?}"),
        )
    })?;
    let mut health = Health::new("motion", &cam.id, Some(&ctx.ipc));
    tracing::info!(
        camera = %cam.id,
        "computing motion ({:?} backend, {} px blocks, thresholds diff {} gradient {} density {})",
        stage.config.backend,
        stage.config.block_px,
        stage.config.diff_threshold,
        stage.config.gradient_threshold,
        stage.config.density_threshold
    );
    notify_ready(&format!("motion {}", cam.id));

    while !ctx.ipc.should_stop() {
        let woke = waitset
            .wait_and_process_once_with_timeout(|_| CallbackProgression::Continue, IDLE_TICK)
            .map_err(|e| Fatal::new(exit::UNAVAILABLE, format!("waiting for frames: {e:?}")))?;
        if stop_requested_by(&woke) {
            break;
        }
        // Drain first, then receive: a frame arriving in between wakes the next wait.
        frames.drain_wakeups();
        loop {
            let sample = match frames.receive() {
                Ok(Some(sample)) => sample,
                Ok(None) => break,
                Err(e) => {
                    stage.warn.warn(|| e.to_string());
                    break;
                }
            };
            stage.on_frame(sample, &mut health)?;
        }
        health.tick(|| stage.detail());
    }
    health.report(stage.detail());
    Ok(())
}

/// The motion stage of one camera: the previous frame, the detector for the current
/// frame size, the publisher, and counters.
struct Stage<'ipc> {
    ipc: &'ipc Ipc,
    camera: String,
    camera_id: CameraId,
    config: MotionConfig,
    mask: Vec<isochron_shared::config::Polygon>,
    /// The previous frame, still borrowed from shared memory (no copy).
    prev: Option<(FrameInfo, ReceivedSample<Frames>)>,
    detector: Option<MotionDetector>,
    /// The publisher and the most blocks it can send.
    publisher: Option<(StreamPublisher<Motion>, usize)>,
    warn: RateLimit,
    illumination_frames: u64,
    suppressed_frames: u64,
    restarts: u64,
}

impl<'ipc> Stage<'ipc> {
    fn new(ipc: &'ipc Ipc, cam: &CameraConfig, config: MotionConfig) -> Result<Self, Fatal> {
        let mut stage = Stage {
            ipc,
            camera: cam.id.clone(),
            camera_id: CameraId::new(&cam.id).expect("validated camera id"),
            config,
            mask: cam.mask.clone(),
            prev: None,
            detector: None,
            publisher: None,
            warn: RateLimit::default(),
            illumination_frames: 0,
            suppressed_frames: 0,
            restarts: 0,
        };
        // With a configured analysis size the publisher (and detector) exist before
        // the first frame; otherwise they follow the first frame's size.
        if let (Some(w), Some(h)) = (cam.width, cam.height) {
            stage
                .prepare(w, h)
                .map_err(|e| Fatal::new(exit::CONFIG, e))?;
        }
        Ok(stage)
    }

    /// Status detail for the health report.
    fn detail(&self) -> String {
        let (backend, grid, masked) = match &self.detector {
            Some(d) => (
                d.backend_name(),
                format!("{}x{}", d.geometry().grid_w, d.geometry().grid_h),
                d.masked_blocks(),
            ),
            None => (format!("{:?}", self.config.backend), "-".into(), 0),
        };
        format!(
            "illumination={} suppressed={} masked_blocks={masked} backend={backend} grid={grid} restarts={}",
            self.illumination_frames, self.suppressed_frames, self.restarts
        )
    }

    /// Makes the detector and publisher fit `width × height` frames (allocates only
    /// when the size changes).
    fn prepare(&mut self, width: u32, height: u32) -> Result<(), String> {
        let fits = self.detector.as_ref().is_some_and(|d| {
            (d.geometry().width, d.geometry().height) == (width as usize, height as usize)
        });
        if !fits {
            let detector =
                MotionDetector::new(&self.config, width as usize, height as usize, &self.mask)
                    .map_err(|e| {
                        format!("camera '{}': {width}x{height} frames: {e}", self.camera)
                    })?;
            tracing::info!(
                camera = %self.camera,
                "{width}x{height} frames: {}x{} blocks of {} px, {} masked, {}",
                detector.geometry().grid_w,
                detector.geometry().grid_h,
                self.config.block_px,
                detector.masked_blocks(),
                detector.backend_name()
            );
            self.detector = Some(detector);
        }
        let blocks = self.detector.as_ref().map_or(1, |d| d.geometry().blocks());
        self.ensure_publisher(blocks).map_err(|e| e.message)
    }

    /// Creates the publisher, or re-creates it when it cannot send `blocks` blocks
    /// (the frames grew: a new grid, so consumers see a new run, sequence from 0).
    fn ensure_publisher(&mut self, blocks: usize) -> Result<(), Fatal> {
        if self
            .publisher
            .as_ref()
            .is_some_and(|(_, cap)| *cap >= blocks)
        {
            return Ok(());
        }
        // One publisher per service: the old one must go first.
        if self.publisher.take().is_some() {
            tracing::info!(camera = %self.camera, "frames grew to {blocks} blocks: new motion publisher");
        }
        let publisher = self
            .ipc
            .publisher::<Motion>(&self.camera, blocks)
            .map_err(|e| Fatal::new(exit::UNAVAILABLE, e.to_string()))?;
        self.publisher = Some((publisher, blocks));
        Ok(())
    }

    /// Handles one received frame sample.
    fn on_frame(
        &mut self,
        sample: ReceivedSample<Frames>,
        health: &mut Health,
    ) -> Result<(), Fatal> {
        let arrived = Instant::now();
        let header: FrameHeader = *sample.user_header();
        health.received(header.preamble.sequence);
        if let Err(e) = header.validate(&self.camera_id, sample.payload().len()) {
            health.rejected();
            self.warn.warn(|| format!("rejected a frame sample: {e}"));
            return Ok(());
        }
        if header.preamble.is_end_of_stream() {
            self.prev = None;
            return self.send_end_of_stream(&header, health);
        }
        if header.format() != PixelFormat::Gray8 || header.width == 0 || header.height == 0 {
            health.rejected();
            self.prev = None;
            let camera = self.camera.clone();
            self.warn.warn(|| {
                format!(
                    "rejected frame {} ({}x{} {:?}): motion needs GRAY8 frames of at least 1x1; \
                     set pixel_format = \"gray8\" for camera '{camera}'",
                    header.source_index,
                    header.width,
                    header.height,
                    header.format()
                )
            });
            return Ok(());
        }
        let info = FrameInfo::of(&header);
        let pairing = pair(self.prev.as_ref().map(|(i, _)| i), &info);
        match pairing {
            Pairing::Pair { .. } => {}
            Pairing::First => {}
            other => {
                self.restarts += 1;
                tracing::info!(camera = %self.camera, "new run of frames: {other:?}");
            }
        }
        if let Err(e) = self.prepare(header.width, header.height) {
            health.rejected();
            self.prev = None;
            self.warn
                .warn(|| format!("rejected frame {}: {e}", header.source_index));
            return Ok(());
        }
        if pairing.is_pair()
            && let (Some((_, prev)), Some(detector), Some((publisher, _))) =
                (&self.prev, &mut self.detector, &mut self.publisher)
        {
            match send_motion(
                detector,
                publisher,
                self.camera_id,
                prev.payload(),
                &sample,
                &header,
            ) {
                Ok(report) => {
                    health.sent(Some(arrived), header.preamble.origin_wall_ns);
                    if report.flags & FLAG_ILLUMINATION != 0 {
                        self.illumination_frames += 1;
                    }
                    if report.suppressed {
                        self.suppressed_frames += 1;
                        tracing::debug!(
                            camera = %self.camera,
                            "frame {}: illumination change suppressed ({:.0} % of blocks changed)",
                            header.source_index,
                            report.changed_fraction * 100.0
                        );
                    }
                }
                Err(SendError::Fatal(fatal)) => return Err(fatal),
                Err(SendError::Skipped(e)) => {
                    health.dropped(1);
                    self.warn
                        .warn(|| format!("frame {}: no motion computed: {e}", header.source_index));
                }
            }
        }
        // The current frame becomes the previous one; the old one is released here.
        self.prev = Some((info, sample));
        Ok(())
    }

    fn send_end_of_stream(
        &mut self,
        header: &FrameHeader,
        health: &mut Health,
    ) -> Result<(), Fatal> {
        self.ensure_publisher(1)?;
        let (publisher, _) = self.publisher.as_mut().expect("publisher just ensured");
        let mut preamble = Preamble::new::<BlockMotion>(
            Stream::Motion,
            self.camera_id,
            publisher.next_sequence(),
            0,
        );
        preamble.capture_time_ns = header.preamble.capture_time_ns;
        preamble.origin_wall_ns = header.preamble.origin_wall_ns;
        preamble.flags = FLAG_END_OF_STREAM;
        let motion = MotionHeader {
            preamble,
            ..Default::default()
        };
        publisher
            .send_copy(motion, &[])
            .map_err(|e| Fatal::new(exit::UNAVAILABLE, e.to_string()))?;
        health.sent(None, header.preamble.origin_wall_ns);
        tracing::info!(camera = %self.camera, "end of stream passed on; waiting for more frames");
        Ok(())
    }
}

/// Why no motion sample was sent for a frame pair.
enum SendError {
    /// The detector failed on this pair (the service goes on).
    Skipped(String),
    /// Shared memory failed.
    Fatal(Fatal),
}

/// Computes the motion of `prev → cur` straight into a loaned sample and publishes
/// it.
fn send_motion(
    detector: &mut MotionDetector,
    publisher: &mut StreamPublisher<Motion>,
    camera: CameraId,
    prev: &[u8],
    cur: &ReceivedSample<Frames>,
    header: &FrameHeader,
) -> Result<FrameReport, SendError> {
    let geom = *detector.geometry();
    // Every sample held by subscribers: this pair's motion is lost (and said so).
    let mut sample = publisher
        .loan(geom.blocks())
        .map_err(|e| SendError::Skipped(format!("no motion sample to loan: {e}")))?;
    let report = detector
        .process_uninit(prev, cur.payload(), sample.payload_mut())
        .map_err(|e| SendError::Skipped(e.to_string()))?;
    let mut preamble = Preamble::new::<BlockMotion>(
        Stream::Motion,
        camera,
        publisher.next_sequence(),
        geom.blocks(),
    );
    preamble.capture_time_ns = header.preamble.capture_time_ns;
    preamble.origin_wall_ns = header.preamble.origin_wall_ns;
    preamble.flags = report.flags;
    *sample.user_header_mut() = MotionHeader {
        preamble,
        frame_width: geom.width as u32,
        frame_height: geom.height as u32,
        block_px: geom.block_px as u32,
        grid_w: geom.grid_w as u32,
        grid_h: geom.grid_h as u32,
        changed_fraction: report.changed_fraction,
        source_index: header.source_index,
    };
    // SAFETY: process_uninit returned Ok, so it initialised every block.
    let sample = unsafe { sample.assume_init() };
    publisher
        .send(sample)
        .map_err(|e| SendError::Fatal(Fatal::new(exit::UNAVAILABLE, e.to_string())))?;
    Ok(report)
}

/// Warnings: the first [`WARN_BURST`] at once, then at most one per [`WARN_EVERY`]
/// with a count of the ones held back (a flood of bad samples must not flood the
/// journal).
#[derive(Default)]
struct RateLimit {
    issued: u64,
    last: Option<Instant>,
    held_back: u64,
}

impl RateLimit {
    fn warn(&mut self, message: impl FnOnce() -> String) {
        let now = Instant::now();
        if self.issued >= WARN_BURST
            && self
                .last
                .is_some_and(|t| now.duration_since(t) < WARN_EVERY)
        {
            self.held_back += 1;
            return;
        }
        let held = std::mem::take(&mut self.held_back);
        if held > 0 {
            tracing::warn!("{} ({held} similar warnings held back)", message());
        } else {
            tracing::warn!("{}", message());
        }
        self.issued += 1;
        self.last = Some(now);
    }
}
