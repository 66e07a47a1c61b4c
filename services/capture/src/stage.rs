//! The capture stage: a camera or file in, `frames` out — a source stage of the
//! runtime ([`isochron_runtime::stage`]): it has no input and produces on its
//! alarms, so all its waiting is the runtime's:
//!
//! * a file's frame `i` is due at `t0 + i / (fps × speed)`: the alarm is set
//!   for it (`speed = "max"`, and a live camera: at once, the read blocks in
//!   OpenCV until the source delivers — that is the stage's work, not a wait);
//! * a live source that cannot be opened, or drops out, is opened again with
//!   exponential backoff ([`Backoff`]): an alarm per attempt;
//! * a frame that finds no sample to loan (subscribers hold them all) is counted
//!   as dropped and read again [`LOAN_RETRY`] later: an alarm.
//!
//! A file ends with its last status report (with how much of it was read,
//! [`InputCompleteness`]) and then an end of stream; a looped one starts again.

use std::cell::Cell;
use std::mem::MaybeUninit;
use std::time::{Duration, Instant};

use isochron_config::Speed;
use isochron_config::clock::{format_rfc3339, wall_now_ns};
use isochron_exit::{self as exit, Fatal};
use isochron_runtime::counters::{Counters, capture};
use isochron_runtime::health::InputCompleteness;
use isochron_runtime::ipc::Frames;
use isochron_runtime::stage::{self, Context, Output, SendError, Stage};
use isochron_runtime::topology::StageKind;
use isochron_wire::{FLAG_DISCONTINUITY, FrameHeader, PixelFormat, Preamble};

use crate::down::DownReason;
use crate::source::{FrameFormat, FrameSource, ReadOutcome, SourceError};
use crate::{Backoff, Pacer, Rescale, Stamper, rescale};

/// How long a frame that found no sample to loan waits before it is read again.
pub const LOAN_RETRY: Duration = Duration::from_millis(5);

/// What the config says about the camera, as the stage needs it.
#[derive(Debug, Clone)]
pub struct Settings {
    /// The camera's id.
    pub camera: String,
    /// The source is a file (it ends, is paced, and failing to open it is
    /// permanent) rather than a live camera.
    pub is_file: bool,
    /// A file starts again from its first frame when it ends (`loop`).
    pub loop_file: bool,
    /// Width and height from the config, if both are set (else the source's).
    pub size: Option<(u32, u32)>,
    /// Pixel format published.
    pub format: PixelFormat,
    /// Frame rate from the config, if set (else the one the source states).
    pub fps: Option<f64>,
    /// Playback speed of a file (`max`: as fast as the readers allow).
    pub speed: Speed,
    /// Capture time of a file's first frame, UTC ns (`None`: now).
    pub start_ns: Option<i64>,
    /// Delays between attempts to open a live source.
    pub backoff: Backoff,
}

/// Opens the camera's source: a live one (again, after it dropped out), or a
/// looped file for its next pass, from its first frame.
pub type Opener = Box<dyn FnMut() -> Result<Box<dyn FrameSource>, SourceError>>;

/// How the source is played, decided when it first opens.
#[derive(Debug, Clone)]
pub struct Playback {
    /// The frames published.
    pub frame: FrameFormat,
    /// The frame rate (configured, or the source's).
    pub fps: f64,
    stamper: Stamper,
    pacer: Pacer,
}

/// Logs what rescaling camera `camera`'s `native` frames to `target` means.
fn log_rescale(camera: &str, native: (u32, u32), target: (u32, u32)) {
    match rescale(camera, native, target) {
        Rescale::None => {}
        Rescale::SameAspect(line) => tracing::info!("{line}"),
        Rescale::Stretched(line) => tracing::warn!("{line}"),
    }
}

impl Playback {
    /// The playback of `source` as `settings` ask: the configured size (or the
    /// source's, logged if rescaled), the configured frame rate (or the file's),
    /// the file clock. Fails (with [`exit::CONFIG`]) if the size or a file's
    /// frame rate is known to neither.
    pub fn of(settings: &Settings, source: &mut dyn FrameSource) -> Result<Self, Fatal> {
        let camera = &settings.camera;
        let native = source.native_size()?;
        let (width, height) = settings.size.or(native).ok_or_else(|| {
            Fatal::new(
                exit::CONFIG,
                format!(
                    "camera '{camera}': the source does not report its frame size; set width and height in the config"
                ),
            )
        })?;
        if let Some(native) = native {
            log_rescale(camera, native, (width, height));
        }
        let fps = settings.fps.unwrap_or_else(|| source.stated_fps());
        if settings.is_file && (fps.is_nan() || fps <= 0.0) {
            return Err(Fatal::new(
                exit::CONFIG,
                format!("camera '{camera}': the file states no frame rate; set fps in the config"),
            ));
        }
        let stamper = match settings.is_file {
            true => Stamper::File {
                start_ns: settings.start_ns.unwrap_or_else(wall_now_ns),
                fps,
            },
            false => Stamper::Wall,
        };
        Ok(Playback {
            frame: FrameFormat {
                width,
                height,
                format: settings.format,
            },
            fps,
            stamper,
            pacer: Pacer::new(
                fps.max(1.0),
                match settings.speed {
                    Speed::Max => None,
                    Speed::Factor(f) => Some(f),
                },
            ),
        })
    }
}

/// Why a read sent no frame.
enum NotSent {
    /// The source ended (a file) or stopped delivering (a live camera).
    Ended,
    /// The source failed.
    Failed(SourceError),
}

/// The capture of one camera.
pub struct CaptureStage<'ipc> {
    settings: Settings,
    open: Opener,
    /// `None` while a live source is (re)connecting.
    source: Option<Box<dyn FrameSource>>,
    /// `None` until the source first opened.
    playback: Option<Playback>,
    output: Output<'ipc, Frames>,
    backoff: Backoff,
    /// Frames published: the file clock's tick.
    index: u64,
    /// Flags of the next frame (a discontinuity after a reconnect).
    flags: u32,
    reconnects: u64,
    /// While a live source cannot be opened: the last failure's message and the
    /// delay logged with it (a line per change of either, not per attempt).
    failing: Option<(String, Duration)>,
    /// `index` when the source last opened: a source that published nothing
    /// since is not "streaming" when it drops.
    opened_at_index: u64,
    /// Why a live source is down, once it failed (`None` while it is up).
    down: Option<DownReason>,
    /// The size the source last opened with, if it said.
    native: Option<(u32, u32)>,
    /// Damaged frames of the sources closed so far.
    damaged: u64,
    loops: u64,
    /// How much of the file was read, once it ended.
    input: Option<InputCompleteness>,
    ended: bool,
}

impl<'ipc> CaptureStage<'ipc> {
    /// A stage that opens its source on its first alarm (a live camera: it is
    /// ready and reports `source unavailable` while it backs off).
    pub fn connecting(settings: Settings, open: Opener, output: Output<'ipc, Frames>) -> Self {
        CaptureStage {
            backoff: settings.backoff.clone(),
            settings,
            open,
            source: None,
            playback: None,
            output,
            index: 0,
            flags: 0,
            reconnects: 0,
            failing: None,
            opened_at_index: 0,
            down: None,
            native: None,
            damaged: 0,
            loops: 0,
            input: None,
            ended: false,
        }
    }

    /// A stage that plays `source`, opened already (a file, decoded or
    /// preloaded), as `playback` says; its publisher is created now.
    pub fn playing(
        settings: Settings,
        open: Opener,
        source: Box<dyn FrameSource>,
        playback: Playback,
        output: Output<'ipc, Frames>,
    ) -> Result<Self, Fatal> {
        let mut stage = CaptureStage::connecting(settings, open, output);
        stage.start(source, playback)?;
        Ok(stage)
    }

    /// Plays `source`: creates the publisher for its frames and says so.
    fn start(&mut self, source: Box<dyn FrameSource>, playback: Playback) -> Result<(), Fatal> {
        self.output.reserve(playback.frame.bytes())?;
        let FrameFormat {
            width,
            height,
            format,
        } = playback.frame;
        tracing::info!(
            camera = %self.settings.camera,
            "publishing {width}x{height} {format:?} frames at {:.2} fps (speed {}, {})",
            playback.fps,
            self.settings.speed,
            match &playback.stamper {
                Stamper::File { start_ns, .. } =>
                    format!("file clock from {}", format_rfc3339(*start_ns)),
                Stamper::Wall => "wall clock".into(),
            }
        );
        self.playback = Some(playback);
        self.source = Some(source);
        Ok(())
    }

    /// Records why the source is down (`None`: up); `isochron status` shows a
    /// change at once, not at the next report.
    fn set_down(&mut self, down: Option<DownReason>, cx: &mut Context) {
        if down != self.down {
            self.down = down;
            cx.health.report_soon();
        }
    }

    /// Opens the live source (or a file at start): on success reading starts
    /// at once; a live source that fails is tried again after the next backoff
    /// delay; a file that fails ends the process (permanent).
    fn connect(&mut self, cx: &mut Context) -> Result<(), Fatal> {
        match (self.open)() {
            Ok(mut source) => {
                self.opened_at_index = self.index;
                self.set_down(None, cx);
                if self.failing.take().is_some() {
                    tracing::info!(
                        "camera '{}' opened after {} failed attempts",
                        self.settings.camera,
                        self.backoff.attempts()
                    );
                }
                match &self.playback {
                    Some(playback) => {
                        // A camera reconfigured while it was away: analysis goes
                        // on at the size it started with, rescaled.
                        let size = (playback.frame.width, playback.frame.height);
                        match source.native_size() {
                            Ok(Some(native)) if Some(native) != self.native => {
                                log_rescale(&self.settings.camera, native, size);
                                self.native = Some(native);
                            }
                            _ => {}
                        }
                        self.reconnects += 1;
                        self.flags |= FLAG_DISCONTINUITY;
                        self.source = Some(source);
                    }
                    None => {
                        self.native = source.native_size().ok().flatten();
                        let playback = Playback::of(&self.settings, source.as_mut())?;
                        self.start(source, playback)?;
                    }
                }
                cx.alarm_at(Instant::now());
                Ok(())
            }
            Err(e) if self.settings.is_file => Err(e.into()),
            Err(e) => {
                self.set_down(Some(e.reason()), cx);
                let (delay, attempt) = self.backoff.next_delay(Instant::now());
                let message = e.to_string();
                let line = format!(
                    "{message}; attempt {attempt} failed, retrying in {:.1} s",
                    delay.as_secs_f64()
                );
                // A WARN when the failure is new or another, an INFO when the
                // delay grows, nothing more per attempt.
                match &self.failing {
                    Some((last, _)) if *last != message => tracing::warn!("{line}"),
                    None => tracing::warn!("{line}"),
                    Some((_, last_delay)) if *last_delay != delay => tracing::info!("{line}"),
                    Some(_) => tracing::debug!("{line}"),
                }
                self.failing = Some((message, delay));
                cx.alarm_in(delay);
                Ok(())
            }
        }
    }

    /// Reads the next frame into a loaned sample and publishes it, if it is due
    /// (else sets the alarm for when it is); then sets the alarm for the next.
    fn publish_next(&mut self, cx: &mut Context) -> Result<(), Fatal> {
        let (Some(playback), Some(source)) = (&self.playback, &mut self.source) else {
            return Ok(());
        };
        if self.settings.is_file
            && let Some(due) = playback.pacer.due(self.index)
            && due > Instant::now()
        {
            cx.alarm_at(due);
            return Ok(());
        }
        let (frame, index, flags) = (playback.frame, self.index, self.flags);
        let source_index = source.next_index();
        let mut origin_wall_ns = 0;
        // A frame read behind the live edge has no known capture time: flagged,
        // so that motion's run starts at the first frame read live.
        let behind = Cell::new(false);
        let write = |dst: &mut [MaybeUninit<u8>]| match source.read_frame(dst, frame) {
            Ok(ReadOutcome::Frame) => {
                behind.set(source.behind_live_edge());
                Ok(())
            }
            Ok(ReadOutcome::EndOfFile | ReadOutcome::Lost) => Err(NotSent::Ended),
            Err(e) => Err(NotSent::Failed(e)),
        };
        let header = |_: &(), mut preamble: Preamble| {
            preamble.capture_time_ns = playback.stamper.stamp(index);
            preamble.origin_wall_ns = wall_now_ns();
            preamble.flags = match behind.get() {
                true => flags | FLAG_DISCONTINUITY,
                false => flags,
            };
            origin_wall_ns = preamble.origin_wall_ns;
            FrameHeader {
                preamble,
                width: frame.width,
                height: frame.height,
                stride: frame.stride(),
                pixel_format: frame.format as u32,
                source_index,
            }
        };
        // SAFETY: `write` returns Ok only for ReadOutcome::Frame, when the source
        // has written every byte of the frame.
        let sent = unsafe {
            self.output
                .send_in_place(frame.bytes(), &Preamble::default(), write, header)
        };
        match sent {
            Ok(()) => {
                cx.health.read_one();
                cx.health.sent(None, origin_wall_ns);
                self.flags = 0;
                self.index += 1;
                self.next_alarm(cx);
                Ok(())
            }
            Err(SendError::NoLoan(e)) => {
                // Every sample is held by subscribers: drop this frame, don't block.
                tracing::debug!("frame dropped: {e}");
                cx.health.dropped(1);
                cx.alarm_in(LOAN_RETRY);
                Ok(())
            }
            Err(SendError::Failed(e)) => Err(e.into()),
            Err(SendError::Write(not_sent)) if self.settings.is_file => {
                self.file_ended(not_sent, cx)
            }
            Err(SendError::Write(not_sent)) => {
                self.lost(not_sent, cx);
                Ok(())
            }
        }
    }

    /// Sets the alarm for the next frame: when it is due (a paced file), else at
    /// once.
    fn next_alarm(&self, cx: &mut Context) {
        let due = self
            .playback
            .as_ref()
            .filter(|_| self.settings.is_file)
            .and_then(|p| p.pacer.due(self.index));
        cx.alarm_at(due.unwrap_or_else(Instant::now));
    }

    /// A live source stopped delivering: reconnects, first at once; if it had
    /// published frames since it opened, then every `reconnect_initial_s` for
    /// [`crate::FAST_RETRY_WINDOW`], then backing off.
    fn lost(&mut self, not_sent: NotSent, cx: &mut Context) {
        let camera = &self.settings.camera;
        let reason = match not_sent {
            NotSent::Failed(e) => {
                tracing::warn!("camera '{camera}' stopped delivering frames: {e}; reconnecting");
                e.reason()
            }
            NotSent::Ended => {
                tracing::warn!("camera '{camera}' stopped delivering frames; reconnecting");
                DownReason::Other
            }
        };
        self.set_down(Some(reason), cx);
        self.damaged += self.source.take().map_or(0, |s| s.damaged_frames());
        // Streaming before it dropped: retried fast. One that drops as soon as
        // it opens goes on backing off.
        if self.index > self.opened_at_index {
            self.backoff.dropped(Instant::now());
        }
        cx.alarm_at(Instant::now());
    }

    /// A file ended (or broke mid-way: what was decodable is published): starts
    /// it again if looped, else ends the stream.
    fn file_ended(&mut self, not_sent: NotSent, cx: &mut Context) -> Result<(), Fatal> {
        let input = self.source.as_ref().and_then(|s| s.completeness());
        if let Some(input) = input.filter(|i| i.truncated) {
            tracing::warn!(
                "the file ended after {} of the {} frames it states: it is truncated or damaged",
                input.frames_read,
                input.frames_stated
            );
        }
        match not_sent {
            NotSent::Failed(e) => tracing::warn!(
                "decoding failed after {} frames: {e}",
                self.source.as_ref().map_or(0, |s| s.next_index())
            ),
            NotSent::Ended if self.settings.loop_file => {
                self.loops += 1;
                self.source = Some((self.open)()?);
                cx.alarm_at(Instant::now());
                return Ok(());
            }
            NotSent::Ended => {}
        }
        self.end_of_stream(input, cx)
    }

    /// Reports the final status (with `input`, how much of the file was read)
    /// and then sends the end of stream: a reader that sees the end (replay) has
    /// the status too.
    fn end_of_stream(
        &mut self,
        input: Option<InputCompleteness>,
        cx: &mut Context,
    ) -> Result<(), Fatal> {
        self.input = input;
        self.ended = true;
        cx.cancel_alarm();
        let (counters, info) = stage::counters_of(self);
        cx.health.report(&counters, &info);
        let capture_time_ns = self
            .playback
            .as_ref()
            .map_or_else(wall_now_ns, |p| p.stamper.stamp(self.index));
        let from = Preamble {
            capture_time_ns,
            origin_wall_ns: wall_now_ns(),
            ..Preamble::default()
        };
        self.output.end_of_stream(&from, |_| {})?;
        tracing::info!(
            "end of file after {} frames; end of stream signalled",
            self.index
        );
        Ok(())
    }
}

impl Stage for CaptureStage<'_> {
    type Inputs = ();
    const KIND: StageKind = StageKind::Capture;

    fn on_start(&mut self, cx: &mut Context) -> Result<(), Fatal> {
        cx.alarm_at(Instant::now());
        Ok(())
    }

    fn on_wake(&mut self, _: &(), _: &mut Context) -> Result<(), Fatal> {
        Ok(())
    }

    fn on_alarm(&mut self, cx: &mut Context) -> Result<(), Fatal> {
        match (self.ended, self.source.is_some()) {
            (true, _) => Ok(()),
            (false, true) => self.publish_next(cx),
            (false, false) => self.connect(cx),
        }
    }

    fn finished(&self) -> bool {
        self.ended
    }

    fn counters(&self, c: &mut Counters) {
        let fps = self.playback.as_ref().map_or(0.0, |p| p.fps);
        c.set(capture::RECONNECTS, self.reconnects);
        c.set(capture::LOOPS, self.loops);
        c.set(capture::SOURCE_FPS, fps);
        c.set(capture::SOURCE_UP, self.source.is_some());
        let damaged = self.source.as_ref().map_or(0, |s| s.damaged_frames());
        c.set(capture::DAMAGED, self.damaged + damaged);
        for reason in DownReason::ALL {
            c.set(reason.counter(), self.down == Some(reason));
        }
        if let Some(input) = self.input {
            input.set(c);
        }
    }

    fn info(&self) -> String {
        if self.source.is_none() && !self.ended {
            match self.down {
                Some(reason) => format!("source down: {reason}"),
                None => "source unavailable".into(),
            }
        } else {
            String::new()
        }
    }
}

#[cfg(test)]
mod tests;
