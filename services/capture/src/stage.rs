//! The capture stage: a camera or file in, `frames` out. It has no input stream,
//! so it paces itself (file clock, reconnect backoff) instead of waiting on a
//! WaitSet; stop requests end its sleeps early.

use std::time::{Duration, Instant};

use isochron_config::clock::{format_rfc3339, parse_rfc3339, wall_now_ns};
use isochron_config::{SourceKind, Speed};
use isochron_exit::{self as exit, Fatal};
use isochron_runtime::health::{Health, InputCompleteness, notify_ready};
use isochron_runtime::ipc::{Frames, Ipc, StreamPublisher};
use isochron_runtime::service::ServiceContext;
use isochron_runtime::topology::StageKind;
use isochron_wire::{
    CameraId, FLAG_DISCONTINUITY, FLAG_END_OF_STREAM, FrameHeader, Preamble, Stream,
};

use crate::source::{PreloadedSource, ReadOutcome, SourceError, VideoSource};
use crate::{Backoff, Pacer, Rescale, Stamper, rescale};

/// Reads the camera of `ctx` and publishes its frames until the file ends or the
/// process is asked to stop.
pub fn run(ctx: ServiceContext) -> Result<(), Fatal> {
    let cam = ctx.camera().clone();
    let kind = cam.source_kind(&ctx.config.base_dir());
    let mut backoff = Backoff::new(
        Duration::from_secs_f64(cam.reconnect_initial_s),
        Duration::from_secs_f64(cam.reconnect_max_s),
    );
    let mut health = Health::new(StageKind::Capture, &cam.id, Some(&ctx.ipc));
    if !kind.is_file() {
        // A camera may be unreachable for long: the service is up (its status says
        // so) and feeds the watchdog while it backs off, instead of being killed
        // as a service that never started.
        notify_ready(&format!("capturing {}", cam.id));
    }
    let mut waiting = || health.tick(|| "source unavailable".into());
    let Some(mut source) = open_source(&kind, &mut backoff, &ctx.ipc, &mut waiting)? else {
        return Ok(());
    };

    let native = source.native_size()?;
    let (width, height) = match (cam.width, cam.height) {
        (Some(w), Some(h)) => (w, h),
        _ => native.ok_or_else(|| {
            Fatal::new(
                exit::CONFIG,
                format!(
                    "camera '{}': the source does not report its frame size; set width and height in the config",
                    cam.id
                ),
            )
        })?,
    };
    if let Some(native) = native {
        match rescale(&cam.id, native, (width, height)) {
            Rescale::None => {}
            Rescale::SameAspect(line) => tracing::info!("{line}"),
            Rescale::Stretched(line) => tracing::warn!("{line}"),
        }
    }
    let format = cam.format();
    let frame_bytes = width as usize * height as usize * format.channels();
    let camera_id = CameraId::new(&cam.id).expect("validated camera id");

    let is_file = kind.is_file();
    let fps = cam.fps.unwrap_or_else(|| source.stated_fps());
    let mut source = match cam.preload_frames {
        None => {
            source.seek(cam.start_frame)?;
            Source::Video(source)
        }
        Some(n) => {
            let preloaded =
                PreloadedSource::load(&kind, n, width, height, format)?.start_at(cam.start_frame);
            tracing::info!(
                "preloaded {} frames: publishing them in a loop, no decoding",
                preloaded.len()
            );
            Source::Preloaded(preloaded)
        }
    };
    if is_file && (fps.is_nan() || fps <= 0.0) {
        return Err(Fatal::new(
            exit::CONFIG,
            format!(
                "camera '{}': the file states no frame rate; set fps in the config",
                cam.id
            ),
        ));
    }
    let stamper = if is_file {
        let start_ns = match &cam.start {
            Some(s) => parse_rfc3339(s).expect("validated start time"),
            None => wall_now_ns(),
        };
        Stamper::File { start_ns, fps }
    } else {
        Stamper::Wall
    };
    let pacer = Pacer::new(
        fps.max(1.0),
        match cam.speed {
            Speed::Max => None,
            Speed::Factor(f) => Some(f),
        },
    );

    let mut publisher = ctx.ipc.publisher::<Frames>(&cam.id, frame_bytes)?;
    tracing::info!(
        camera = %cam.id,
        source = %cam.source,
        "publishing {width}x{height} {format:?} frames at {fps:.2} fps (speed {}, {})",
        cam.speed,
        match &stamper {
            Stamper::File { start_ns, .. } => format!("file clock from {}", format_rfc3339(*start_ns)),
            Stamper::Wall => "wall clock".into(),
        }
    );
    if kind.is_file() {
        notify_ready(&format!("capturing {}", cam.id));
    }

    let mut index: u64 = 0; // frames published: the file clock's tick
    let mut flags = 0u32;
    let mut reconnects = 0u64;
    let mut loops = 0u64;
    let detail = |reconnects: u64, loops: u64, fps_src: f64| {
        format!("reconnects={reconnects} loops={loops} source_fps={fps_src:.2}")
    };
    while !ctx.ipc.should_stop() {
        health.tick(|| detail(reconnects, loops, fps));
        if is_file {
            let wait = pacer.wait_for(index);
            if !wait.is_zero() {
                sleep_unless_stopped(&ctx.ipc, wait, &mut || {});
                continue;
            }
        }
        let mut sample = match publisher.loan(frame_bytes) {
            Ok(s) => s,
            Err(e) => {
                // Every sample is held by subscribers: drop this frame, don't block.
                tracing::debug!("frame dropped: {e}");
                health.dropped(1);
                std::thread::sleep(Duration::from_millis(5));
                continue;
            }
        };
        let source_index = source.next_index();
        // SAFETY: the loan holds exactly `frame_bytes` bytes.
        let outcome = unsafe {
            source.read_into(
                sample.payload_mut().as_mut_ptr().cast(),
                width,
                height,
                format,
            )
        };
        match outcome {
            Ok(ReadOutcome::Frame) => {
                health.read_one();
                let capture_time_ns = stamper.stamp(index);
                let mut preamble = Preamble::new::<u8>(
                    Stream::Frames,
                    camera_id,
                    publisher.next_sequence(),
                    frame_bytes,
                );
                preamble.capture_time_ns = capture_time_ns;
                preamble.origin_wall_ns = wall_now_ns();
                preamble.flags = std::mem::take(&mut flags);
                *sample.user_header_mut() = FrameHeader {
                    preamble,
                    width,
                    height,
                    stride: width * format.channels() as u32,
                    pixel_format: format as u32,
                    source_index,
                };
                // SAFETY: read_into wrote every byte of the frame.
                let sample = unsafe { sample.assume_init() };
                publisher.send(sample)?;
                health.sent(None, preamble.origin_wall_ns);
                index += 1;
            }
            Ok(ReadOutcome::EndOfFile) => {
                drop(sample);
                let input = source.check_complete();
                if cam.loop_file {
                    loops += 1;
                    source = Source::Video(VideoSource::open(&kind)?);
                    continue;
                }
                // The final status (with the input's completeness) before the end of
                // stream: a reader that sees the end (replay) has the status too.
                health.report(final_detail(detail(reconnects, loops, fps), input));
                send_end_of_stream(&mut publisher, camera_id, stamper.stamp(index))?;
                tracing::info!("end of file after {index} frames; end of stream signalled");
                return Ok(());
            }
            Ok(ReadOutcome::Lost) | Err(_) if !is_file => {
                drop(sample);
                if let Err(e) = outcome {
                    tracing::warn!("camera '{}' failed: {e}", cam.id);
                }
                tracing::warn!(
                    "camera '{}' stopped delivering frames; reconnecting",
                    cam.id
                );
                backoff.reset();
                let mut keep_alive = || health.tick(|| "source unavailable".into());
                match open_source(&kind, &mut backoff, &ctx.ipc, &mut keep_alive)? {
                    Some(s) => source = Source::Video(s),
                    None => break,
                }
                reconnects += 1;
                flags |= FLAG_DISCONTINUITY;
            }
            Ok(ReadOutcome::Lost) => unreachable!("file sources end, they are not lost"),
            Err(e) => {
                // A file that breaks mid-way: publish what was decodable, then end.
                drop(sample);
                tracing::warn!("decoding failed after {} frames: {e}", source.next_index());
                let input = source.check_complete();
                health.report(final_detail(detail(reconnects, loops, fps), input));
                send_end_of_stream(&mut publisher, camera_id, stamper.stamp(index))?;
                return Ok(());
            }
        }
    }
    health.report(detail(reconnects, loops, fps));
    Ok(())
}

/// Opens the source. A file that is missing or undecodable is a permanent error; a
/// live source is retried with exponential backoff until it opens or we are asked to
/// stop (`Ok(None)`). `keep_alive` runs while waiting (the watchdog must know a
/// camera that is reconnecting is not hung).
fn open_source(
    kind: &SourceKind,
    backoff: &mut Backoff,
    ipc: &Ipc,
    keep_alive: &mut dyn FnMut(),
) -> Result<Option<VideoSource>, Fatal> {
    loop {
        match VideoSource::open(kind) {
            Ok(source) => return Ok(Some(source)),
            Err(e) if kind.is_file() => return Err(e.into()),
            Err(e) => {
                let (delay, attempt) = backoff.next_delay();
                tracing::warn!(
                    "{e}; attempt {attempt} failed, retrying in {:.1} s",
                    delay.as_secs_f64()
                );
                if !sleep_unless_stopped(ipc, delay, keep_alive) {
                    return Ok(None);
                }
            }
        }
    }
}

/// Where frames come from: a decoder, or frames preloaded into memory.
enum Source {
    Video(VideoSource),
    Preloaded(PreloadedSource),
}

impl Source {
    /// Source index of the frame the next read returns.
    fn next_index(&self) -> u64 {
        match self {
            Source::Video(v) => v.position(),
            Source::Preloaded(p) => p.next_index(),
        }
    }

    /// Reads the next frame into `dst` (see [`VideoSource::read_into`]).
    ///
    /// # Safety
    /// `dst` must point to one frame of `width × height` `format`.
    unsafe fn read_into(
        &mut self,
        dst: *mut u8,
        width: u32,
        height: u32,
        format: isochron_wire::PixelFormat,
    ) -> Result<ReadOutcome, SourceError> {
        match self {
            // SAFETY: forwarded from the caller.
            Source::Video(v) => unsafe { v.read_into(dst, width, height, format) },
            // SAFETY: forwarded from the caller.
            Source::Preloaded(p) => Ok(unsafe { p.read_into(dst) }),
        }
    }

    /// How much of the file was read, compared with what it states; warns when it
    /// ended well before the frame count it states (truncated). `None` for a
    /// preloaded source (it never ends).
    fn check_complete(&self) -> Option<InputCompleteness> {
        let Source::Video(v) = self else {
            return None;
        };
        let input = InputCompleteness::of(v.position(), v.stated_frame_count());
        if input.truncated {
            tracing::warn!(
                "the file ended after {} of the {} frames it states: it is truncated or damaged",
                input.frames_read,
                input.frames_stated
            );
        }
        Some(input)
    }
}

/// Capture's last status detail: `detail`, then the input's completeness as
/// `frames_read=N frames_stated=M truncated=true|false` (see
/// [`InputCompleteness::from_detail`]).
fn final_detail(detail: String, input: Option<InputCompleteness>) -> String {
    match input {
        Some(input) => format!("{detail} {}", input.to_detail()),
        None => detail,
    }
}

fn send_end_of_stream(
    publisher: &mut StreamPublisher<Frames>,
    camera: CameraId,
    capture_time_ns: i64,
) -> Result<(), Fatal> {
    let mut preamble = Preamble::new::<u8>(Stream::Frames, camera, publisher.next_sequence(), 0);
    preamble.capture_time_ns = capture_time_ns;
    preamble.origin_wall_ns = wall_now_ns();
    preamble.flags = FLAG_END_OF_STREAM;
    let header = FrameHeader {
        preamble,
        ..Default::default()
    };
    publisher.send_copy(header, &[])?;
    Ok(())
}

/// Sleeps `total`, waking early when asked to stop and every 100 ms to run
/// `keep_alive`. Returns false if asked to stop.
fn sleep_unless_stopped(ipc: &Ipc, total: Duration, keep_alive: &mut dyn FnMut()) -> bool {
    let end = Instant::now() + total;
    loop {
        keep_alive();
        if ipc.should_stop() {
            return false;
        }
        let left = end.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return true;
        }
        std::thread::sleep(left.min(Duration::from_millis(100)));
    }
}
