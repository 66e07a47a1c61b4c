//! The motion stage: `frames` in, per-block `motion` out, one sample per frame pair,
//! run by the stage runtime ([`isochron_runtime::stage`]).

use std::time::Instant;

use isochron_config::{CameraConfig, MotionConfig, Polygon};
use isochron_exit::{self as exit, Fatal};
use isochron_runtime::counters::{Counters, motion};
use isochron_runtime::ipc::{Frames, Ipc, Motion};
use isochron_runtime::service::ServiceContext;
use isochron_runtime::stage::{self, Context, Input, Output, Received, SendError, Stage};
use isochron_runtime::topology::StageKind;
use isochron_wire::{FLAG_ILLUMINATION, FrameHeader, MotionHeader, PixelFormat};

use crate::detector::MotionDetector;
use crate::pairing::{FrameInfo, Pairing, pair};

/// Serves the camera of `ctx` (the `main` of isochron-motion): opens the stage
/// and runs it until the process is asked to stop.
pub fn run(ctx: ServiceContext) -> Result<(), Fatal> {
    let camera = ctx.camera();
    let (mut motion, frames) = MotionStage::open(&ctx.ipc, camera, &ctx.config.config.motion)?;
    isochron_runtime::stage::run(&ctx.ipc, &camera.id, &mut motion, &frames)
}

/// The motion stage of one camera: the previous frame, the detector for the current
/// frame size, the output, and counters.
pub struct MotionStage<'ipc> {
    camera: String,
    config: MotionConfig,
    mask: Vec<Polygon>,
    /// The analysis size of the config, if set: frames of another size are
    /// rejected (they would change the grid and the shared memory it needs).
    size: Option<(u32, u32)>,
    /// The previous frame, still borrowed from shared memory (no copy).
    prev: Option<(FrameInfo, Received<Frames>)>,
    detector: Option<MotionDetector>,
    output: Output<'ipc, Motion>,
    illumination_frames: u64,
    suppressed_frames: u64,
    /// New runs of frames (a reconnect, a restarted capture, a new size).
    restarts: u64,
    /// The last frame started a new run (no pair yet since).
    starting_run: bool,
}

impl<'ipc> MotionStage<'ipc> {
    /// The stage of `camera`, publishing through `ipc`, and its input.
    pub fn open(
        ipc: &'ipc Ipc,
        camera: &CameraConfig,
        config: &MotionConfig,
    ) -> Result<(Self, Input<Frames>), Fatal> {
        stage::one_in_one_out(ipc, &camera.id, |output| Self::new(camera, config, output))
    }

    /// The stage of `camera` writing into `output`.
    pub fn new(
        camera: &CameraConfig,
        config: &MotionConfig,
        output: Output<'ipc, Motion>,
    ) -> Result<Self, Fatal> {
        let mut stage = MotionStage {
            camera: camera.id.clone(),
            config: config.clone(),
            mask: camera.mask.clone(),
            size: camera.width.zip(camera.height),
            prev: None,
            detector: None,
            output,
            illumination_frames: 0,
            suppressed_frames: 0,
            restarts: 0,
            starting_run: false,
        };
        tracing::info!(
            camera = %camera.id,
            "computing motion ({:?} backend, {} px blocks, thresholds diff {} gradient {} density {})",
            config.backend,
            config.block_px,
            config.diff_threshold,
            config.gradient_threshold,
            config.density_threshold
        );
        // With a configured analysis size the publisher (and detector) exist before
        // the first frame; otherwise they follow the first frame's size.
        if let (Some(w), Some(h)) = (camera.width, camera.height) {
            stage
                .prepare(w, h)
                .map_err(|e| Fatal::new(exit::CONFIG, e))?;
        }
        Ok(stage)
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
        self.output.reserve(blocks).map_err(|e| e.to_string())
    }

    /// Handles one received frame sample.
    fn on_frame(&mut self, sample: Received<Frames>, cx: &mut Context) -> Result<(), Fatal> {
        let arrived = Instant::now();
        let header: FrameHeader = *sample.header();
        if header.preamble.is_end_of_stream() {
            self.prev = None;
            self.output.end_of_stream(&header.preamble, |_| {})?;
            cx.health.sent(None, header.preamble.origin_wall_ns);
            tracing::info!(camera = %self.camera, "end of stream passed on; waiting for more frames");
            return Ok(());
        }
        if !self.accepts(&header, cx) {
            return Ok(());
        }
        let info = FrameInfo::of(&header);
        let pairing = pair(self.prev.as_ref().map(|(i, _)| i), &info);
        // A run starts with its first frame: frames flagged one after another
        // (those capture read behind a camera's live edge) are one new run.
        let starts_run = !matches!(pairing, Pairing::Pair { .. } | Pairing::First);
        if starts_run && !self.starting_run {
            self.restarts += 1;
            tracing::info!(camera = %self.camera, "new run of frames: {pairing:?}");
        }
        self.starting_run = starts_run;
        if let Err(e) = self.prepare(header.width, header.height) {
            cx.health.rejected();
            self.prev = None;
            cx.warnings.warn("size", || {
                format!("rejected frame {}: {e}", header.source_index)
            });
            return Ok(());
        }
        if pairing.is_pair() {
            self.send_motion(&sample, &header, arrived, cx)?;
        }
        // The current frame becomes the previous one; the old one is released here.
        self.prev = Some((info, sample));
        Ok(())
    }

    /// True if the frame can be processed: GRAY8, not empty, of the configured size.
    /// Otherwise it is counted as rejected, with a warning, and the pair broken.
    fn accepts(&mut self, header: &FrameHeader, cx: &mut Context) -> bool {
        if header.format() != PixelFormat::Gray8 || header.width == 0 || header.height == 0 {
            cx.health.rejected();
            self.prev = None;
            let camera = &self.camera;
            cx.warnings.warn("format", || {
                format!(
                    "rejected frame {} ({}x{} {:?}): motion needs GRAY8 frames of at least 1x1; \
                     set pixel_format = \"gray8\" for camera '{camera}'",
                    header.source_index,
                    header.width,
                    header.height,
                    header.format()
                )
            });
            return false;
        }
        if let Some((w, h)) = self.size
            && (header.width, header.height) != (w, h)
        {
            cx.health.rejected();
            self.prev = None;
            let camera = &self.camera;
            cx.warnings.warn("size", || {
                format!(
                    "rejected frame {} ({}x{}): camera '{camera}' is configured for {w}x{h} frames",
                    header.source_index, header.width, header.height
                )
            });
            return false;
        }
        true
    }

    /// Computes the motion between the previous frame and `sample` (which arrived
    /// at `arrived`) straight into a loan, and sends it.
    fn send_motion(
        &mut self,
        sample: &Received<Frames>,
        header: &FrameHeader,
        arrived: Instant,
        cx: &mut Context,
    ) -> Result<(), Fatal> {
        if let (Some((_, prev)), Some(detector)) = (&self.prev, &mut self.detector) {
            let geom = *detector.geometry();
            // SAFETY: process_uninit initialises every block when it returns Ok.
            let sent = unsafe {
                self.output.send_in_place(
                    geom.blocks(),
                    &header.preamble,
                    |blocks| {
                        detector.process_uninit(
                            prev.payload(),
                            sample.payload(),
                            header.preamble.capture_time_ns,
                            blocks,
                        )
                    },
                    |report, mut preamble| {
                        preamble.flags = report.flags;
                        MotionHeader {
                            preamble,
                            frame_width: geom.width as u32,
                            frame_height: geom.height as u32,
                            block_px: geom.block_px as u32,
                            grid_w: geom.grid_w as u32,
                            grid_h: geom.grid_h as u32,
                            changed_fraction: report.changed_fraction,
                            source_index: header.source_index,
                        }
                    },
                )
            };
            match sent {
                Ok(report) => {
                    cx.health
                        .sent(Some(arrived), header.preamble.origin_wall_ns);
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
                Err(SendError::Failed(e)) => return Err(e.into()),
                Err(e) => {
                    cx.health.dropped(1);
                    cx.warnings.warn("send", || {
                        format!("frame {}: no motion computed: {e}", header.source_index)
                    });
                }
            }
        }
        Ok(())
    }
}

impl Stage for MotionStage<'_> {
    type Inputs = Input<Frames>;
    const KIND: StageKind = StageKind::Motion;

    fn on_wake(&mut self, frames: &Input<Frames>, cx: &mut Context) -> Result<(), Fatal> {
        while let Some(sample) = frames.next(cx) {
            self.on_frame(sample, cx)?;
        }
        Ok(())
    }

    fn counters(&self, c: &mut Counters) {
        c.set(motion::ILLUMINATION, self.illumination_frames);
        c.set(motion::SUPPRESSED, self.suppressed_frames);
        c.set(motion::RESTARTS, self.restarts);
        if let Some(d) = &self.detector {
            let g = d.geometry();
            c.set(motion::MASKED_BLOCKS, d.masked_blocks());
            c.set(motion::GRID_BLOCKS, g.grid_w as u64 * g.grid_h as u64);
        }
    }

    fn info(&self) -> String {
        match &self.detector {
            Some(d) => format!(
                "backend={} grid={}x{}",
                d.backend_name(),
                d.geometry().grid_w,
                d.geometry().grid_h
            ),
            None => format!("backend={:?} grid=-", self.config.backend),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    use isochron_config::Config;
    use isochron_runtime::stage::{Owned, Queue, step};
    use isochron_wire::{CameraId, FLAG_END_OF_STREAM, Preamble, Stream};

    fn frame(sequence: u64, index: u64, fill: impl Fn(usize, usize) -> u8) -> Owned<Frames> {
        let (w, h) = (128usize, 64usize);
        let payload: Vec<u8> = (0..w * h).map(|i| fill(i % w, i / w)).collect();
        let mut preamble = Preamble::new::<u8>(
            Stream::Frames,
            CameraId::new("cam01").unwrap(),
            sequence,
            payload.len(),
        );
        preamble.capture_time_ns = 1_000_000_000 + index as i64 * 100_000_000;
        Owned {
            header: FrameHeader {
                preamble,
                width: w as u32,
                height: h as u32,
                stride: w as u32,
                pixel_format: PixelFormat::Gray8 as u32,
                source_index: index,
            },
            payload,
        }
    }

    /// A bright square on a textured background, at column `x`.
    fn square_at(x: usize) -> impl Fn(usize, usize) -> u8 {
        move |c, r| {
            if (x..x + 12).contains(&c) && (20..32).contains(&r) {
                230
            } else {
                ((c * 7 + r * 13) % 40) as u8
            }
        }
    }

    /// A motion stage of a 128x64 camera on memory queues.
    struct Rig {
        stage: MotionStage<'static>,
        sent: Queue<Motion>,
        frames: Input<Frames>,
        queue: Queue<Frames>,
        cx: Context,
    }

    impl Rig {
        /// Queues the frames and runs the stage on them.
        fn run(&mut self, frames: impl IntoIterator<Item = Owned<Frames>>) {
            self.queue.borrow_mut().extend(frames);
            step(&mut self.stage, &self.frames, &mut self.cx).unwrap();
        }
    }

    fn rig() -> Rig {
        let config = Config::parse(
            "[[camera]]\nid = \"cam01\"\nsource = \"walk.avi\"\nwidth = 128\nheight = 64\n",
            Path::new("site.toml"),
        )
        .unwrap();
        let (output, sent) = Output::memory("cam01");
        let stage = MotionStage::new(&config.cameras[0], &config.motion, output).unwrap();
        let (frames, queue) = Input::memory("cam01");
        let cx = Context::new(StageKind::Motion, "cam01", None);
        Rig {
            stage,
            sent,
            frames,
            queue,
            cx,
        }
    }

    #[test]
    fn drives_the_motion_stage_through_the_runtime_without_shared_memory() {
        let mut rig = rig();
        // A foreign sample (another camera) is rejected, not computed.
        let mut foreign = frame(2, 2, square_at(18));
        foreign.header.preamble.camera = CameraId::new("cam02").unwrap();
        let mut end = frame(5, 5, |_, _| 0);
        end.header.preamble.flags = FLAG_END_OF_STREAM;
        end.payload.clear();
        end.header.preamble.payload_len = 0;
        // Sequences 2 (the foreign sample) and 3 never arrive: a gap of two.
        rig.run([
            frame(0, 0, square_at(10)),
            frame(1, 1, square_at(14)),
            foreign,
            frame(4, 4, square_at(22)),
            end,
        ]);

        let sent = rig.sent.borrow();
        // Frames 0→1 and 1→4 pair (the gap does not break a run); then the end.
        assert_eq!(sent.len(), 3, "two motion samples and the end of stream");
        for (k, (motion, index)) in sent.iter().zip([1, 4]).enumerate() {
            assert_eq!(motion.header.preamble.sequence, k as u64);
            assert_eq!((motion.header.grid_w, motion.header.grid_h), (8, 4));
            assert_eq!(motion.payload.len(), 32);
            assert!(motion.payload.iter().any(|b| b.density > 0.0));
            assert_eq!(motion.header.source_index, index);
        }
        let end = &sent[2];
        assert!(end.header.preamble.is_end_of_stream());
        assert_eq!(end.header.preamble.sequence, 2);
        assert_eq!(end.header.preamble.capture_time_ns, 1_500_000_000);

        let status = rig.cx.health.status();
        assert_eq!(status.received, 4);
        assert_eq!(status.rejected, 1);
        assert_eq!(
            status.dropped, 2,
            "the sequence gap 1 → 4 (the foreign sample is not counted)"
        );
        assert_eq!(status.sent, 3);
    }

    #[test]
    fn frames_of_another_size_than_configured_are_rejected_and_change_nothing() {
        let mut rig = rig();
        // A 1x1 frame from a misconfigured or foreign producer of this camera.
        let mut tiny = frame(1, 1, |_, _| 0);
        tiny.header.width = 1;
        tiny.header.height = 1;
        tiny.header.stride = 1;
        tiny.payload.truncate(1);
        tiny.header.preamble.payload_len = 1;
        rig.run([
            frame(0, 0, square_at(10)),
            tiny,
            frame(2, 2, square_at(14)),
            frame(3, 3, square_at(18)),
        ]);
        assert_eq!(rig.cx.health.status().rejected, 1);
        let sent = rig.sent.borrow();
        // The grid stays 8x4: frame 0 pairs with nothing (the odd frame broke the
        // run), frames 2 → 3 pair.
        assert_eq!(sent.len(), 1);
        assert_eq!((sent[0].header.grid_w, sent[0].header.grid_h), (8, 4));
        assert_eq!(sent[0].header.source_index, 3);
        assert!(rig.stage.info().contains("grid=8x4"));
    }
}
