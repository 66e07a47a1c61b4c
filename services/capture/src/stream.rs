//! Network cameras (`rtsp://`, `http://`, …) through FFmpeg's libraries, which
//! give what OpenCV hides: the transport, deadlines on opening and on every
//! read (an interrupt callback FFmpeg polls while it waits on the network), and
//! the error behind each failure, as a [`DownReason`].
//!
//! Frames the decoder marks damaged (lost packets) are not published, nor those
//! after them until the next clean key frame, which would carry the damage on:
//! they are counted ([`FrameSource::damaged_frames`]). The decoder's luma plane
//! is written straight into the caller's buffer (the loaned sample) for grey
//! frames at the decoded size, and scaled by swscale into it otherwise.

use std::mem::MaybeUninit;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use ffmpeg_next as ffmpeg;
use ffmpeg_next::format::Pixel;
use ffmpeg_next::software::scaling;
use ffmpeg_next::{Dictionary, Packet, codec, decoder, format, frame, media};
use isochron_config::Transport;
use isochron_wire::PixelFormat;

use crate::down::DownReason;
use crate::live_edge::LiveEdge;
use crate::source::{FrameFormat, FrameSource, ReadOutcome, SourceError};

/// How capture talks to a network camera (the camera's config keys).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StreamOptions {
    /// RTSP: video inside the RTSP connection (TCP) or as RTP over UDP.
    pub transport: Transport,
    /// How long opening may take: connecting, the handshake, the first frames.
    pub connect_timeout: Duration,
    /// How long a read may wait for a frame before the camera counts as stalled.
    pub read_timeout: Duration,
}

/// When FFmpeg's blocking calls give up: the interrupt callback FFmpeg polls
/// (every 100 ms or so while it waits) reports this deadline passed.
#[derive(Clone)]
struct Deadline {
    epoch: Instant,
    at_ms: Arc<AtomicU64>,
}

impl Deadline {
    fn new() -> Self {
        Deadline {
            epoch: Instant::now(),
            at_ms: Arc::new(AtomicU64::new(u64::MAX)),
        }
    }

    /// The deadline is `after` from now.
    fn set_in(&self, after: Duration) {
        let at = self.epoch.elapsed() + after;
        self.at_ms.store(at.as_millis() as u64, Ordering::Relaxed);
    }

    fn passed(&self) -> bool {
        self.epoch.elapsed().as_millis() as u64 >= self.at_ms.load(Ordering::Relaxed)
    }
}

/// What FFmpeg was doing when it failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// Connecting, the handshake, probing the stream.
    Opening,
    /// Reading frames of an open stream.
    Reading,
}

/// The reason behind FFmpeg's error `e`.
pub fn classify(e: &ffmpeg::Error, phase: Phase) -> DownReason {
    use ffmpeg::Error as E;
    match e {
        // Our deadline passed: no answer while opening, no frame while reading.
        E::Exit if phase == Phase::Opening => DownReason::TimedOut,
        E::Exit => DownReason::Stalled,
        E::HttpUnauthorized | E::HttpForbidden => DownReason::Unauthorized,
        E::HttpNotFound | E::ProtocolNotFound => DownReason::NotFound,
        E::InvalidData
        | E::DecoderNotFound
        | E::DemuxerNotFound
        | E::StreamNotFound
        | E::PatchWelcome => DownReason::BadStream,
        E::Other { errno } => match *errno {
            libc::ECONNREFUSED | libc::ECONNRESET | libc::EPIPE => DownReason::Refused,
            libc::ETIMEDOUT | libc::EHOSTUNREACH | libc::ENETUNREACH | libc::EHOSTDOWN => {
                match phase {
                    Phase::Opening => DownReason::TimedOut,
                    Phase::Reading => DownReason::Stalled,
                }
            }
            libc::ENOENT => DownReason::NotFound,
            _ => DownReason::Other,
        },
        _ => DownReason::Other,
    }
}

/// FFmpeg's global set-up, once per process: its own log is silenced (capture
/// says why a camera is down, once per change).
fn init() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        if let Err(e) = ffmpeg::init() {
            tracing::warn!("FFmpeg: {e}");
        }
        ffmpeg::util::log::set_level(ffmpeg::util::log::Level::Quiet);
    });
}

/// An open network camera.
pub struct StreamSource {
    input: format::context::Input,
    stream: usize,
    decoder: decoder::Video,
    decoded: frame::Video,
    scaler: Option<Scaler>,
    deadline: Deadline,
    read_timeout: Duration,
    fps: f64,
    /// The URL as logs show it (credentials masked).
    shown: String,
    frames_read: u64,
    damaged: u64,
    /// Damage seen: frames are held back until a clean key frame.
    recovering: bool,
    /// The video stream's time base (seconds per presentation-time unit).
    time_base: (i32, i32),
    /// When the stream opened: the clock frames are read on.
    opened: Instant,
    live_edge: LiveEdge,
    /// The frame last read was behind the live edge.
    behind: bool,
}

/// A swscale context for one conversion.
struct Scaler {
    from: (Pixel, u32, u32),
    to: FrameFormat,
    context: scaling::Context,
}

impl StreamSource {
    /// Opens `url` (shown in errors as `shown`) as `options` say.
    pub fn open(url: &str, shown: &str, options: &StreamOptions) -> Result<Self, SourceError> {
        init();
        let down = |reason, detail: String| SourceError::Down {
            what: shown.to_string(),
            reason,
            detail,
        };
        let deadline = Deadline::new();
        deadline.set_in(options.connect_timeout);
        let mut settings = Dictionary::new();
        // Opening probes the stream until it knows every parameter; the frame
        // rate comes from the stream's own description (an RTSP camera's SDP) or
        // the first frames' timing, not from 20 frames of buffered video (2 s at
        // 10 fps) that would then be published late in a burst.
        settings.set("fpsprobesize", "0");
        settings.set("analyzeduration", "1000000");
        if url.starts_with("rtsp") {
            settings.set("rtsp_transport", options.transport.as_str());
        }
        let interrupt = deadline.clone();
        let input = format::input_with_interrupt_and_dictionary(
            url,
            move || {
                // FFmpeg asks on the stage's thread, every 100 ms while it
                // waits: the loop is alive, waiting up to the deadline.
                isochron_runtime::health::still_alive();
                interrupt.passed()
            },
            settings,
        )
        .map_err(|e| match deadline.passed() {
            // Interrupted: FFmpeg's RTSP client reports a cut-off reply as
            // invalid data, not as the interruption.
            true => down(
                DownReason::TimedOut,
                format!(
                    "no answer within {:.1} s",
                    options.connect_timeout.as_secs_f64()
                ),
            ),
            false => down(classify(&e, Phase::Opening), e.to_string()),
        })?;
        let stream = input
            .streams()
            .best(media::Type::Video)
            .ok_or_else(|| down(DownReason::BadStream, "it sends no video".into()))?;
        let index = stream.index();
        let time_base = stream.time_base();
        let rate = match stream.avg_frame_rate() {
            r if r.numerator() > 0 && r.denominator() > 0 => r,
            _ => stream.rate(),
        };
        let fps = match rate.denominator() {
            0 => 0.0,
            d => f64::from(rate.numerator()) / f64::from(d),
        };
        let mut context = codec::context::Context::from_parameters(stream.parameters())
            .map_err(|e| down(DownReason::BadStream, e.to_string()))?;
        // One thread per camera: capture already runs one per camera.
        context.set_threading(codec::threading::Config::count(1));
        let decoder = context
            .decoder()
            .video()
            .map_err(|e| down(DownReason::BadStream, format!("no decoder: {e}")))?;
        let fps = if fps.is_finite() { fps.max(0.0) } else { 0.0 };
        Ok(StreamSource {
            input,
            stream: index,
            decoder,
            decoded: frame::Video::empty(),
            scaler: None,
            deadline,
            read_timeout: options.read_timeout,
            fps,
            shown: shown.to_string(),
            frames_read: 0,
            damaged: 0,
            recovering: false,
            time_base: (time_base.numerator(), time_base.denominator()),
            opened: Instant::now(),
            live_edge: LiveEdge::new(fps),
            behind: false,
        })
    }

    /// The decoded frame's presentation time in nanoseconds of stream time.
    fn presented_ns(&self) -> Option<i128> {
        let (num, den) = self.time_base;
        let t = self.decoded.timestamp()?;
        (num > 0 && den > 0)
            .then(|| i128::from(t) * i128::from(num) * 1_000_000_000 / i128::from(den))
    }

    fn down(&self, reason: DownReason, detail: impl Into<String>) -> SourceError {
        SourceError::Down {
            what: self.shown.clone(),
            reason,
            detail: detail.into(),
        }
    }

    /// The next frame the decoder has ready that is fit to publish, if any.
    fn ready_frame(&mut self) -> Result<bool, SourceError> {
        loop {
            match self.decoder.receive_frame(&mut self.decoded) {
                Ok(()) => {
                    let damaged = self.decoded.is_corrupt() || self.decoded.has_decode_errors();
                    if damaged {
                        self.recovering = true;
                    } else if !self.recovering || self.decoded.is_key() {
                        self.recovering = false;
                        return Ok(true);
                    }
                    self.damaged += 1;
                }
                Err(ffmpeg::Error::Other {
                    errno: libc::EAGAIN,
                }) => return Ok(false),
                Err(ffmpeg::Error::Eof) => {
                    return Err(self.down(DownReason::Other, "the camera ended the stream"));
                }
                Err(e) => return Err(self.down(DownReason::BadStream, e.to_string())),
            }
        }
    }

    /// Writes the decoded frame into `dst` as `out`.
    fn write(&mut self, dst: &mut [MaybeUninit<u8>], out: FrameFormat) -> Result<(), SourceError> {
        let (width, height) = (self.decoded.width(), self.decoded.height());
        let luma = out.format == PixelFormat::Gray8 && luma_first(self.decoded.format());
        if luma && (width, height) == (out.width, out.height) {
            let (plane, stride) = (self.decoded.data(0), self.decoded.stride(0));
            let w = width as usize;
            for (y, row) in dst.chunks_exact_mut(w).enumerate() {
                let src = &plane[y * stride..y * stride + w];
                for (d, s) in row.iter_mut().zip(src) {
                    d.write(*s);
                }
            }
        } else {
            let from = match luma {
                true => (Pixel::GRAY8, width, height),
                false => (self.decoded.format(), width, height),
            };
            self.scale(from, dst, out)?;
        }
        if out.format == PixelFormat::Gray8 && !full_range(&self.decoded) {
            // SAFETY: every byte of `dst` has been written above.
            let dst = unsafe { &mut *(dst as *mut [MaybeUninit<u8>] as *mut [u8]) };
            expand_video_range(dst);
        }
        Ok(())
    }

    /// Scales (and converts) the decoded frame, read as `from`, into `dst`.
    fn scale(
        &mut self,
        from: (Pixel, u32, u32),
        dst: &mut [MaybeUninit<u8>],
        out: FrameFormat,
    ) -> Result<(), SourceError> {
        if self
            .scaler
            .as_ref()
            .is_none_or(|s| s.from != from || s.to != out)
        {
            let to = match out.format {
                PixelFormat::Gray8 => Pixel::GRAY8,
                PixelFormat::Bgr8 => Pixel::BGR24,
            };
            let context = scaling::Context::get(
                from.0,
                from.1,
                from.2,
                to,
                out.width,
                out.height,
                scaling::Flags::AREA,
            )
            .map_err(|e| self.down(DownReason::BadStream, format!("cannot scale: {e}")))?;
            self.scaler = Some(Scaler {
                from,
                to: out,
                context,
            });
        }
        let Some(scaler) = self.scaler.as_mut() else {
            return Ok(());
        };
        let planes = match from.0 {
            Pixel::GRAY8 => 1,
            _ => self.decoded.planes(),
        };
        let (mut src, mut src_stride) = ([std::ptr::null(); 4], [0i32; 4]);
        for i in 0..planes.min(4) {
            src[i] = self.decoded.data(i).as_ptr();
            src_stride[i] = self.decoded.stride(i) as i32;
        }
        let mut dst_planes = [std::ptr::null_mut(); 4];
        dst_planes[0] = dst.as_mut_ptr().cast::<u8>();
        let dst_stride = [out.stride() as i32, 0, 0, 0];
        // SAFETY: the source planes and strides are the decoded frame's (of
        // `from`'s size); `dst` holds one frame of `out` (checked by the caller),
        // the size the context was made for; swscale writes every byte of it.
        let rows = unsafe {
            ffmpeg::ffi::sws_scale(
                scaler.context.as_mut_ptr(),
                src.as_ptr(),
                src_stride.as_ptr(),
                0,
                from.2 as i32,
                dst_planes.as_ptr(),
                dst_stride.as_ptr(),
            )
        };
        if rows != out.height as i32 {
            return Err(self.down(
                DownReason::BadStream,
                format!("swscale wrote {rows} of {} rows", out.height),
            ));
        }
        Ok(())
    }
}

impl FrameSource for StreamSource {
    fn native_size(&mut self) -> Result<Option<(u32, u32)>, SourceError> {
        let (w, h) = (self.decoder.width(), self.decoder.height());
        Ok((w > 0 && h > 0).then_some((w, h)))
    }

    fn stated_fps(&self) -> f64 {
        self.fps
    }

    fn next_index(&self) -> u64 {
        self.frames_read
    }

    fn read_frame(
        &mut self,
        dst: &mut [MaybeUninit<u8>],
        frame: FrameFormat,
    ) -> Result<ReadOutcome, SourceError> {
        frame.check(dst)?;
        // Never less than two frame intervals: a slow camera is not a stalled one.
        let interval = match self.fps {
            f if f > 0.0 => isochron_config::clock::saturating_secs(2.0 / f),
            _ => Duration::ZERO,
        };
        let timeout = self.read_timeout.max(interval);
        self.deadline.set_in(timeout);
        loop {
            // Once the deadline passed FFmpeg hands back what it had (a packet
            // cut short by the interruption): the camera stalled, whatever that
            // decodes to.
            if self.deadline.passed() {
                let detail = format!("no frame for {:.1} s", timeout.as_secs_f64());
                return Err(self.down(DownReason::Stalled, detail));
            }
            if self.ready_frame()? {
                let read_ns = self.opened.elapsed().as_nanos() as i128;
                self.behind = self.live_edge.behind(self.presented_ns(), read_ns);
                self.write(dst, frame)?;
                self.frames_read += 1;
                return Ok(ReadOutcome::Frame);
            }
            let mut packet = Packet::empty();
            match packet.read(&mut self.input) {
                Ok(()) if packet.stream() == self.stream => {
                    if self.decoder.send_packet(&packet).is_err() {
                        // A packet the decoder cannot take: its frame is damaged.
                        self.damaged += 1;
                        self.recovering = true;
                    }
                }
                Ok(()) => {}
                Err(ffmpeg::Error::Eof) => {
                    return Err(self.down(DownReason::Other, "the camera ended the stream"));
                }
                // Interrupted at the deadline: the next pass says stalled.
                Err(_) if self.deadline.passed() => {}
                Err(e) => return Err(self.down(classify(&e, Phase::Reading), e.to_string())),
            }
        }
    }

    fn damaged_frames(&self) -> u64 {
        self.damaged
    }

    fn behind_live_edge(&self) -> bool {
        self.behind
    }
}

/// True for pixel formats whose first plane is 8-bit luma.
fn luma_first(format: Pixel) -> bool {
    matches!(
        format,
        Pixel::YUV420P
            | Pixel::YUVJ420P
            | Pixel::YUV422P
            | Pixel::YUVJ422P
            | Pixel::YUV444P
            | Pixel::YUVJ444P
            | Pixel::YUV440P
            | Pixel::YUVJ440P
            | Pixel::YUV411P
            | Pixel::NV12
            | Pixel::NV21
            | Pixel::GRAY8
    )
}

/// True if the frame's luma spans 0–255 (JPEG range) rather than 16–235.
fn full_range(frame: &frame::Video) -> bool {
    use ffmpeg::util::color::Range;
    match frame.color_range() {
        Range::JPEG => true,
        Range::MPEG => false,
        _ => matches!(
            frame.format(),
            Pixel::YUVJ420P | Pixel::YUVJ422P | Pixel::YUVJ444P | Pixel::YUVJ440P
        ),
    }
}

/// Stretches video-range luma (16–235) to 0–255 in place, as a conversion
/// through RGB to grey would: grey frames look alike whatever the camera's range.
fn expand_video_range(pixels: &mut [u8]) {
    static TABLE: std::sync::OnceLock<[u8; 256]> = std::sync::OnceLock::new();
    let table = TABLE.get_or_init(|| {
        std::array::from_fn(|v| {
            let full = (v as f64 - 16.0) * 255.0 / 219.0;
            full.round().clamp(0.0, 255.0) as u8
        })
    });
    for p in pixels {
        *p = table[*p as usize];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_map_to_reasons_by_phase() {
        use ffmpeg::Error as E;
        let cases = [
            (E::Exit, Phase::Opening, DownReason::TimedOut),
            (E::Exit, Phase::Reading, DownReason::Stalled),
            (
                E::HttpUnauthorized,
                Phase::Opening,
                DownReason::Unauthorized,
            ),
            (E::HttpNotFound, Phase::Opening, DownReason::NotFound),
            (E::InvalidData, Phase::Reading, DownReason::BadStream),
            (
                E::Other {
                    errno: libc::ECONNREFUSED,
                },
                Phase::Opening,
                DownReason::Refused,
            ),
            (
                E::Other {
                    errno: libc::ETIMEDOUT,
                },
                Phase::Reading,
                DownReason::Stalled,
            ),
            (
                E::Other { errno: libc::EIO },
                Phase::Opening,
                DownReason::Other,
            ),
        ];
        for (e, phase, reason) in cases {
            assert_eq!(classify(&e, phase), reason, "{e:?} while {phase:?}");
        }
    }

    #[test]
    fn video_range_luma_is_stretched_to_full_range() {
        let mut px = [0, 16, 126, 235, 255];
        expand_video_range(&mut px);
        assert_eq!(px, [0, 0, 128, 255, 255]);
    }

    #[test]
    fn a_port_nobody_listens_on_is_refused_at_once() {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let options = StreamOptions {
            transport: Transport::Tcp,
            connect_timeout: Duration::from_secs(5),
            read_timeout: Duration::from_secs(5),
        };
        let url = format!("rtsp://user:secret@127.0.0.1:{port}/cam");
        let started = Instant::now();
        let Err(e) = StreamSource::open(&url, "rtsp://user:***@…", &options) else {
            panic!("opened a port nobody listens on");
        };
        assert_eq!(e.reason(), DownReason::Refused, "{e}");
        assert!(started.elapsed() < Duration::from_secs(2));
        assert!(!e.to_string().contains("secret"), "{e}");
    }

    #[test]
    fn a_host_that_never_answers_times_out_at_the_connect_deadline() {
        // A listener that accepts (the kernel does) but never says a word.
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let port = listener.local_addr().unwrap().port();
        let options = StreamOptions {
            transport: Transport::Tcp,
            connect_timeout: Duration::from_millis(700),
            read_timeout: Duration::from_secs(5),
        };
        let started = Instant::now();
        let Err(e) = StreamSource::open(&format!("rtsp://127.0.0.1:{port}/cam"), "cam", &options)
        else {
            panic!("opened a silent server");
        };
        let took = started.elapsed();
        assert_eq!(e.reason(), DownReason::TimedOut, "{e}");
        assert!(
            (Duration::from_millis(600)..Duration::from_millis(2000)).contains(&took),
            "gave up after {took:?}"
        );
    }
}
