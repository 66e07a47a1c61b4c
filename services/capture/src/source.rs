//! Video sources through OpenCV: files, V4L2 devices, GStreamer pipelines
//! (network cameras are [`crate::stream`]'s).
//!
//! [`VideoSource::read_into`] has OpenCV decode the next frame into a buffer of its
//! own, then converts it (colour, then size) or copies it into a caller's buffer —
//! the loaned shared-memory sample: one write into shared memory per frame, where
//! every consumer reads it in place.
//!
//! The capture stage reads any [`FrameSource`]: a decoder ([`VideoSource`]),
//! frames preloaded into memory ([`PreloadedSource`]), or frames a test made.

use std::mem::MaybeUninit;
use std::path::PathBuf;
use std::sync::Arc;

use parking_lot::Mutex;

use isochron_config::SourceKind;

use crate::down::DownReason;
use isochron_runtime::health::InputCompleteness;
use isochron_wire::PixelFormat;
use opencv::core::{Mat, Size};
use opencv::prelude::*;
use opencv::{imgproc, videoio};

/// Why a source could not be opened or read.
#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    /// The file does not exist.
    #[error("video file {0} does not exist")]
    Missing(PathBuf),
    /// The file exists but no OpenCV backend can decode it.
    #[error(
        "cannot decode video file {0}: it is corrupt or in a format the installed OpenCV backends (FFmpeg, GStreamer) cannot read"
    )]
    Undecodable(PathBuf),
    /// A live source could not be opened (yet); the source as shown, its
    /// credentials masked.
    #[error("cannot open {0}")]
    Unavailable(String),
    /// A network camera is down: the URL as shown (credentials masked), why,
    /// and FFmpeg's words for it.
    #[error("{what}: {reason} ({detail})")]
    Down {
        /// The camera's URL, credentials masked.
        what: String,
        /// Why.
        reason: DownReason,
        /// What FFmpeg said.
        detail: String,
    },
    /// OpenCV failed.
    #[error("OpenCV: {0}")]
    OpenCv(#[from] opencv::Error),
    /// A buffer that does not hold one frame (a bug).
    #[error("a buffer of {got} bytes cannot hold a frame of {expected} bytes")]
    FrameBuffer {
        /// The frame's size.
        expected: usize,
        /// The buffer's size.
        got: usize,
    },
}

impl SourceError {
    /// Why the source is down, as status and `/metrics` show it.
    pub fn reason(&self) -> DownReason {
        match self {
            SourceError::Down { reason, .. } => *reason,
            SourceError::Missing(_) => DownReason::NotFound,
            SourceError::Undecodable(_) => DownReason::BadStream,
            _ => DownReason::Other,
        }
    }
}

impl isochron_exit::Classify for SourceError {
    /// A missing or undecodable file is permanent; a camera may come back.
    fn exit_code(&self) -> i32 {
        use isochron_exit as exit;
        match self {
            SourceError::Missing(_) => exit::NO_INPUT,
            SourceError::Undecodable(_) => exit::DATA,
            SourceError::FrameBuffer { .. } => exit::SOFTWARE,
            _ => exit::UNAVAILABLE,
        }
    }
}

/// What a read produced.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReadOutcome {
    /// A frame was written into the buffer.
    Frame,
    /// A file source has no more frames.
    EndOfFile,
    /// A live source stopped delivering.
    Lost,
}

/// The size and pixel format of the frames capture publishes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameFormat {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Pixel layout.
    pub format: PixelFormat,
}

impl FrameFormat {
    /// Bytes of one frame (packed rows).
    pub fn bytes(&self) -> usize {
        self.width as usize * self.height as usize * self.format.channels()
    }

    /// Bytes of one row.
    pub fn stride(&self) -> u32 {
        self.width * self.format.channels() as u32
    }

    /// `Ok` if `dst` holds exactly one frame.
    pub(crate) fn check(&self, dst: &[MaybeUninit<u8>]) -> Result<(), SourceError> {
        if dst.len() == self.bytes() {
            Ok(())
        } else {
            Err(SourceError::FrameBuffer {
                expected: self.bytes(),
                got: dst.len(),
            })
        }
    }
}

/// Where the capture stage's frames come from.
pub trait FrameSource {
    /// Width and height the source decodes to, if it says.
    fn native_size(&mut self) -> Result<Option<(u32, u32)>, SourceError> {
        Ok(None)
    }

    /// Frame rate the source states (0 if unknown).
    fn stated_fps(&self) -> f64 {
        0.0
    }

    /// Source index of the frame the next read returns.
    fn next_index(&self) -> u64;

    /// Reads the next frame into `dst`, which holds one frame of `frame`. On
    /// [`ReadOutcome::Frame`] every byte of `dst` has been written.
    fn read_frame(
        &mut self,
        dst: &mut [MaybeUninit<u8>],
        frame: FrameFormat,
    ) -> Result<ReadOutcome, SourceError>;

    /// For a file that ended: how much of it was read against the frame count
    /// it states. `None` for a source that does not end (live, preloaded).
    fn completeness(&self) -> Option<InputCompleteness> {
        None
    }

    /// Frames found damaged and not published since the source opened.
    fn damaged_frames(&self) -> u64 {
        0
    }

    /// True if the frame just read was buffered while the stream opened and
    /// read faster than the camera sent it ([`crate::live_edge`]): when it was
    /// captured is not known.
    fn behind_live_edge(&self) -> bool {
        false
    }
}

/// Makes OpenCV run its functions (the colour conversion, the resize) on the
/// calling thread, once per process. A capture process already runs one thread
/// per camera; OpenCV's own worker pool beside them only spun waiting for work
/// (measured: one camera's pool took a tenth of a core in a 32-camera process).
/// Also keeps OpenCV's own warnings out of the log (a line per failed open of
/// a camera that is down): capture says why, once per change of state.
fn single_threaded_opencv() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        if let Err(e) = opencv::core::set_num_threads(0) {
            tracing::warn!("OpenCV threads: {e}");
        }
        if let Err(e) = opencv::core::set_log_level_1(opencv::core::LOG_LEVEL_ERROR) {
            tracing::warn!("OpenCV log level: {e}");
        }
    });
}

/// An opened video source.
pub struct VideoSource {
    capture: videoio::VideoCapture,
    kind: SourceKind,
    decoded: Mat,
    scratch: Mat,
    /// Index in the file of the first frame read (see [`VideoSource::seek`]).
    first_frame: u64,
    frames_read: u64,
}

impl VideoSource {
    /// Opens `kind`.
    pub fn open(kind: &SourceKind) -> Result<Self, SourceError> {
        single_threaded_opencv();
        let capture = match kind {
            SourceKind::File(path) => {
                if !path.exists() {
                    return Err(SourceError::Missing(path.clone()));
                }
                let cap = videoio::VideoCapture::from_file(path.as_os_str(), videoio::CAP_ANY)?;
                if !cap.is_opened()? {
                    return Err(SourceError::Undecodable(path.clone()));
                }
                cap
            }
            SourceKind::Device(index) => {
                let cap = videoio::VideoCapture::new(*index, videoio::CAP_V4L2)?;
                if !cap.is_opened()? {
                    return Err(SourceError::Unavailable(kind.to_string()));
                }
                cap
            }
            SourceKind::Url(_) => {
                return Err(SourceError::Unavailable(format!(
                    "{kind}: network cameras are opened by StreamSource, not OpenCV"
                )));
            }
            SourceKind::GStreamer(pipeline) => {
                let cap = videoio::VideoCapture::from_file(pipeline, videoio::CAP_GSTREAMER)?;
                if !cap.is_opened()? {
                    return Err(SourceError::Unavailable(kind.to_string()));
                }
                cap
            }
        };
        let mut source = VideoSource {
            capture,
            kind: kind.clone(),
            decoded: Mat::default(),
            scratch: Mat::default(),
            first_frame: 0,
            frames_read: 0,
        };
        // A file that opens but yields no first frame is as good as corrupt.
        if let SourceKind::File(path) = kind
            && source.native_size()?.is_none()
        {
            return Err(SourceError::Undecodable(path.clone()));
        }
        Ok(source)
    }

    /// Width and height the source decodes to, if it says.
    pub fn native_size(&mut self) -> Result<Option<(u32, u32)>, SourceError> {
        let w = self.capture.get(videoio::CAP_PROP_FRAME_WIDTH)?;
        let h = self.capture.get(videoio::CAP_PROP_FRAME_HEIGHT)?;
        Ok((w >= 1.0 && h >= 1.0).then_some((w as u32, h as u32)))
    }

    /// Frame rate the source states (0 if unknown).
    pub fn stated_fps(&self) -> f64 {
        self.capture
            .get(videoio::CAP_PROP_FPS)
            .unwrap_or(0.0)
            .max(0.0)
    }

    /// Number of frames a file states it has (0 if unknown).
    pub fn stated_frame_count(&self) -> u64 {
        self.capture
            .get(videoio::CAP_PROP_FRAME_COUNT)
            .unwrap_or(0.0)
            .max(0.0) as u64
    }

    /// Frames read since the source was opened.
    pub fn frames_read(&self) -> u64 {
        self.frames_read
    }

    /// Index in the file of the next frame: where reading started plus the frames
    /// read since.
    pub fn position(&self) -> u64 {
        self.first_frame + self.frames_read
    }

    /// Before the first read of a file: starts reading at frame `frame` (0-based).
    pub fn seek(&mut self, frame: u64) -> Result<(), SourceError> {
        if frame > 0 {
            self.capture
                .set(videoio::CAP_PROP_POS_FRAMES, frame as f64)?;
        }
        self.first_frame = frame;
        Ok(())
    }

    /// The source kind.
    pub fn kind(&self) -> &SourceKind {
        &self.kind
    }

    /// Decodes the next frame into `dst` (`width × height` pixels of `format`,
    /// packed rows), resizing and converting as needed.
    ///
    /// # Safety
    /// `dst` must point to `width * height * format.channels()` writable bytes.
    /// On [`ReadOutcome::Frame`] every one of them has been written.
    pub unsafe fn read_into(
        &mut self,
        dst: *mut u8,
        width: u32,
        height: u32,
        format: PixelFormat,
    ) -> Result<ReadOutcome, SourceError> {
        let ok = self.capture.read(&mut self.decoded).unwrap_or(false);
        if !ok || self.decoded.empty() {
            return Ok(if self.kind.is_file() {
                ReadOutcome::EndOfFile
            } else {
                ReadOutcome::Lost
            });
        }
        self.frames_read += 1;
        let typ = match format {
            PixelFormat::Gray8 => opencv::core::CV_8UC1,
            PixelFormat::Bgr8 => opencv::core::CV_8UC3,
        };
        let step = width as usize * format.channels();
        // SAFETY: the caller guarantees `dst` covers height * step bytes; the Mat
        // does not outlive this call.
        let mut out = unsafe {
            Mat::new_rows_cols_with_data_unsafe(height as i32, width as i32, typ, dst.cast(), step)?
        };
        let size = Size::new(width as i32, height as i32);
        let same_size = self.decoded.size()? == size;
        let channels = self.decoded.channels();
        match (format, channels, same_size) {
            (PixelFormat::Gray8, 1, true) | (PixelFormat::Bgr8, 3, true) => {
                self.decoded.copy_to(&mut out)?;
            }
            (PixelFormat::Gray8, 1, false) | (PixelFormat::Bgr8, 3, false) => {
                imgproc::resize(&self.decoded, &mut out, size, 0.0, 0.0, imgproc::INTER_AREA)?;
            }
            (_, _, true) => {
                imgproc::cvt_color(&self.decoded, &mut out, conversion(channels, format), 0)?;
            }
            (_, _, false) => {
                // Convert at the source size (one channel for gray), then shrink
                // into the sample.
                imgproc::cvt_color(
                    &self.decoded,
                    &mut self.scratch,
                    conversion(channels, format),
                    0,
                )?;
                imgproc::resize(&self.scratch, &mut out, size, 0.0, 0.0, imgproc::INTER_AREA)?;
            }
        }
        // OpenCV reallocates an output whose size or type does not fit instead of
        // failing; make sure it wrote where we asked.
        if out.data() != dst.cast_const() {
            return Err(SourceError::OpenCv(opencv::Error::new(
                opencv::core::StsInternal,
                "OpenCV reallocated the output frame instead of writing into shared memory",
            )));
        }
        Ok(ReadOutcome::Frame)
    }
}

impl FrameSource for VideoSource {
    fn native_size(&mut self) -> Result<Option<(u32, u32)>, SourceError> {
        VideoSource::native_size(self)
    }

    fn stated_fps(&self) -> f64 {
        VideoSource::stated_fps(self)
    }

    fn next_index(&self) -> u64 {
        self.position()
    }

    fn read_frame(
        &mut self,
        dst: &mut [MaybeUninit<u8>],
        frame: FrameFormat,
    ) -> Result<ReadOutcome, SourceError> {
        frame.check(dst)?;
        // SAFETY: `dst` holds exactly width × height × channels bytes (checked
        // above), and `MaybeUninit<u8>` has the layout of `u8`.
        unsafe {
            self.read_into(
                dst.as_mut_ptr().cast(),
                frame.width,
                frame.height,
                frame.format,
            )
        }
    }

    fn completeness(&self) -> Option<InputCompleteness> {
        self.kind
            .is_file()
            .then(|| InputCompleteness::of(self.position(), self.stated_frame_count()))
    }
}

/// The colour conversion from `channels` decoded channels to `format`.
fn conversion(channels: i32, format: PixelFormat) -> i32 {
    match (channels, format) {
        (3, PixelFormat::Gray8) => imgproc::COLOR_BGR2GRAY,
        (4, PixelFormat::Gray8) => imgproc::COLOR_BGRA2GRAY,
        (1, PixelFormat::Bgr8) => imgproc::COLOR_GRAY2BGR,
        (4, PixelFormat::Bgr8) => imgproc::COLOR_BGRA2BGR,
        _ => imgproc::COLOR_BGR2GRAY,
    }
}

/// Frames decoded once into memory (already at the analysis size and format),
/// handed out in a loop: a source that costs no decoding.
pub struct PreloadedSource {
    frames: Arc<Vec<Vec<u8>>>,
    next: usize,
    fps: f64,
}

/// What a preload is made of: the same key means the same frames.
type PreloadKey = (SourceKind, u32, u32, u32, PixelFormat);

/// A preload kept for the other cameras of this process.
struct Preload {
    key: PreloadKey,
    frames: Arc<Vec<Vec<u8>>>,
    fps: f64,
}

/// Preloads of this process, shared by the cameras that read the same file at
/// the same size (a multi-camera capture process decodes each file once).
static PRELOADS: Mutex<Vec<Preload>> = Mutex::new(Vec::new());

impl PreloadedSource {
    /// The first `count` frames of `kind` (a file), converted to `width × height`
    /// `format`: decoded now, or shared with a camera of this process that
    /// preloaded the same.
    pub fn load(
        kind: &SourceKind,
        count: u32,
        width: u32,
        height: u32,
        format: PixelFormat,
    ) -> Result<Self, SourceError> {
        let key = (kind.clone(), count, width, height, format);
        // Held while decoding, so two cameras never decode the same file twice.
        let mut preloads = PRELOADS.lock();
        if let Some(p) = preloads.iter().find(|p| p.key == key) {
            return Ok(PreloadedSource {
                frames: p.frames.clone(),
                next: 0,
                fps: p.fps,
            });
        }
        let source = Self::decode(&key)?;
        preloads.push(Preload {
            key,
            frames: source.frames.clone(),
            fps: source.fps,
        });
        Ok(source)
    }

    /// Decodes what `key` names: `count` frames of `kind` as `width × height` `format`.
    fn decode(key: &PreloadKey) -> Result<Self, SourceError> {
        let (kind, count, width, height, format) = (&key.0, key.1, key.2, key.3, key.4);
        let mut video = VideoSource::open(kind)?;
        let fps = video.stated_fps();
        let bytes = width as usize * height as usize * format.channels();
        let mut frames = Vec::with_capacity(count as usize);
        while frames.len() < count as usize {
            let mut frame = vec![0u8; bytes];
            // SAFETY: `frame` holds exactly the bytes of one frame.
            match unsafe { video.read_into(frame.as_mut_ptr(), width, height, format)? } {
                ReadOutcome::Frame => frames.push(frame),
                _ => break,
            }
        }
        if frames.len() < 2 {
            let SourceKind::File(path) = kind else {
                return Err(SourceError::Unavailable(
                    "a live source cannot be preloaded".into(),
                ));
            };
            return Err(SourceError::Undecodable(path.clone()));
        }
        Ok(PreloadedSource {
            frames: Arc::new(frames),
            next: 0,
            fps,
        })
    }

    /// Frames in memory.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// True if nothing was loaded (never: loading needs two frames).
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Frame rate the file states.
    pub fn stated_fps(&self) -> f64 {
        self.fps
    }

    /// Starts the loop at frame `frame` of the preload (wrapping).
    pub fn start_at(mut self, frame: u64) -> Self {
        self.next = (frame % self.frames.len() as u64) as usize;
        self
    }

    /// Index the next frame will have in the preload.
    pub fn next_index(&self) -> u64 {
        self.next as u64
    }

    /// Copies the next frame (looping) into `dst`.
    ///
    /// # Safety
    /// `dst` must point to one frame's bytes.
    pub unsafe fn read_into(&mut self, dst: *mut u8) -> ReadOutcome {
        let frame = &self.frames[self.next];
        // SAFETY: the caller guarantees `dst` holds one frame of this size.
        unsafe { std::ptr::copy_nonoverlapping(frame.as_ptr(), dst, frame.len()) };
        self.next = (self.next + 1) % self.frames.len();
        ReadOutcome::Frame
    }
}

impl FrameSource for PreloadedSource {
    fn stated_fps(&self) -> f64 {
        self.fps
    }

    fn next_index(&self) -> u64 {
        PreloadedSource::next_index(self)
    }

    fn read_frame(
        &mut self,
        dst: &mut [MaybeUninit<u8>],
        frame: FrameFormat,
    ) -> Result<ReadOutcome, SourceError> {
        frame.check(dst)?;
        let stored = self.frames[self.next].len();
        if stored != dst.len() {
            return Err(SourceError::FrameBuffer {
                expected: stored,
                got: dst.len(),
            });
        }
        // SAFETY: `dst` holds exactly the bytes of one preloaded frame (checked
        // above), and `MaybeUninit<u8>` has the layout of `u8`.
        Ok(unsafe { self.read_into(dst.as_mut_ptr().cast()) })
    }
}
