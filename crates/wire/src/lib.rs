//! Wire types: the fixed headers and payload elements of every isochron stream.
//!
//! Every sample on every stream carries, as its iceoryx2 user header, one of the
//! `*Header` structs below. Each starts with the same [`Preamble`]: magic, layout
//! version, stream kind, camera id, sequence number, capture time (UTC ns) and the
//! payload's element count and size. A consumer calls the header's `validate` before
//! it trusts a sample; a foreign or outdated producer then gets a clear
//! [`WireError`] instead of being misread.
//!
//! All types are `#[repr(C)]`, `Copy`, and pinned by `#[type_name]` so that every
//! process (and any foreign tool) agrees on them through iceoryx2's type check.
//!
//! The headers and elements that cross between base stations (`isochron-link`)
//! also derive serde: serialised in field order they are the CDR of the ROS 2
//! messages of the same names in `ros/isochron_msgs/msg`, which mirror this file
//! field for field (a test in `isochron-link` pins the sizes).

use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};

pub mod geometry;

isochron_exit::always_exits_with!(DATA: WireError;);

use crate::geometry::BlockGrid;

/// Magic at the start of every isochron header: the bytes `ISOC`.
pub const MAGIC: u32 = u32::from_le_bytes(*b"ISOC");

/// Version of the layout of all headers and payload elements in this file. Bump it on
/// any change to a `#[repr(C)]` type here.
pub const LAYOUT_VERSION: u16 = 3;

/// Longest camera id, in bytes.
pub const CAMERA_ID_LEN: usize = 24;

/// Largest frame side a header may describe, pixels: the limit of `camera.width`
/// and `camera.height`.
pub const MAX_FRAME_SIDE: u32 = 8192;
/// Smallest block edge a header may carry, pixels: the lower limit of `motion.block_px`.
pub const MIN_BLOCK_PX: u32 = 4;
/// Largest block edge a header may carry, pixels: the upper limit of `motion.block_px`.
pub const MAX_BLOCK_PX: u32 = 128;
/// Most blocks in a camera's grid (a 4K frame in 16-px blocks is 32 400): the
/// bound on every per-block payload (motion, activity, an event's block list), so
/// that no sample can make a receiver allocate more than 64 Ki elements.
pub const MAX_BLOCKS: usize = 1 << 16;
/// Most detections in one `detections` sample.
pub const MAX_DETECTIONS: usize = 1024;

/// Header flag: the last sample of a finite source (end of file). Carries no payload.
pub const FLAG_END_OF_STREAM: u32 = 1 << 0;
/// Header flag (motion): a global illumination change was detected and suppressed.
pub const FLAG_ILLUMINATION: u32 = 1 << 1;
/// Header flag (frames): the frame follows a source reconnect or a gap in capture.
pub const FLAG_DISCONTINUITY: u32 = 1 << 2;
/// Header flag (motion): the blocks' `luma` and `texture` were measured on this
/// frame (otherwise they are zero).
pub const FLAG_APPEARANCE: u32 = 1 << 3;

/// `BlockMotion::luma` and `texture` are in 1/`APPEARANCE_SCALE` grey levels.
pub const APPEARANCE_SCALE: u16 = 256;

/// Checks a sample's magic number and layout version, the first fields of every
/// shared-memory type.
pub fn check_layout(magic: u32, layout_version: u16) -> Result<(), WireError> {
    if magic != MAGIC {
        return Err(WireError::Magic { found: magic });
    }
    if layout_version != LAYOUT_VERSION {
        return Err(WireError::Version {
            found: layout_version,
        });
    }
    Ok(())
}

/// The streams of one camera, as named in docs/ARCHITECTURE.md, "Processes and streams".
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[repr(u16)]
pub enum Stream {
    /// Frame header + pixels, camera rate.
    Frames = 1,
    /// Motion header + one [`BlockMotion`] per block, camera rate.
    Motion = 2,
    /// Activity header + one [`BlockActivity`] per block, 1 Hz.
    Activity = 3,
    /// Event start/end records.
    Events = 4,
    /// Detector results for gated frames.
    Detections = 5,
}

impl Stream {
    /// All streams, in pipeline order.
    pub const ALL: [Stream; 5] = [
        Stream::Frames,
        Stream::Motion,
        Stream::Activity,
        Stream::Events,
        Stream::Detections,
    ];

    /// The stream's name as used in service names and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Stream::Frames => "frames",
            Stream::Motion => "motion",
            Stream::Activity => "activity",
            Stream::Events => "events",
            Stream::Detections => "detections",
        }
    }

    /// Parses a stream name (`frames`, `motion`, ...).
    pub fn from_name(name: &str) -> Option<Stream> {
        Stream::ALL.into_iter().find(|s| s.name() == name)
    }

    fn from_u16(v: u16) -> Option<Stream> {
        Stream::ALL.into_iter().find(|s| *s as u16 == v)
    }
}

impl std::fmt::Display for Stream {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A camera id as it travels in headers: ASCII, zero-padded.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend, Serialize, Deserialize)]
#[type_name("isochron::CameraId")]
#[repr(C)]
pub struct CameraId(pub [u8; CAMERA_ID_LEN]);

impl CameraId {
    /// Builds a camera id; `None` if `id` is empty, too long, or not `[A-Za-z0-9_-]`.
    pub fn new(id: &str) -> Option<CameraId> {
        if !is_valid_camera_id(id) {
            return None;
        }
        let mut bytes = [0u8; CAMERA_ID_LEN];
        bytes[..id.len()].copy_from_slice(id.as_bytes());
        Some(CameraId(bytes))
    }

    /// The id as text (lossy for bytes a foreign producer may have put there).
    pub fn as_str(&self) -> std::borrow::Cow<'_, str> {
        let end = self.0.iter().position(|&b| b == 0).unwrap_or(CAMERA_ID_LEN);
        String::from_utf8_lossy(&self.0[..end])
    }
}

/// True if `id` can name a camera: 1..=24 characters of `[A-Za-z0-9_-]`.
pub fn is_valid_camera_id(id: &str) -> bool {
    !id.is_empty()
        && id.len() <= CAMERA_ID_LEN
        && id
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
}

/// The fields every header starts with.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize, Deserialize)]
#[type_name("isochron::Preamble")]
#[repr(C)]
pub struct Preamble {
    /// Always [`MAGIC`].
    pub magic: u32,
    /// Always [`LAYOUT_VERSION`] of the producer.
    pub layout_version: u16,
    /// The [`Stream`] this sample belongs to, as `u16`.
    pub stream: u16,
    /// Camera that produced the data.
    pub camera: CameraId,
    /// Per-publisher sample counter, starting at 0, +1 per sample.
    pub sequence: u64,
    /// Capture time of the (last) frame this sample is about, UTC nanoseconds.
    pub capture_time_ns: i64,
    /// Wall-clock time (UTC ns) at which capture published the originating frame;
    /// carried through every stage to measure end-to-end latency.
    pub origin_wall_ns: i64,
    /// Number of payload elements that follow.
    pub payload_len: u32,
    /// Size of one payload element in bytes.
    pub element_size: u32,
    /// `FLAG_*` bits.
    pub flags: u32,
    /// Zero.
    pub reserved: u32,
}

impl Preamble {
    /// A preamble for `stream` of `camera` with the payload description filled in.
    pub fn new<T>(stream: Stream, camera: CameraId, sequence: u64, payload_len: usize) -> Self {
        Preamble {
            magic: MAGIC,
            layout_version: LAYOUT_VERSION,
            stream: stream as u16,
            camera,
            sequence,
            capture_time_ns: 0,
            origin_wall_ns: 0,
            payload_len: payload_len as u32,
            element_size: std::mem::size_of::<T>() as u32,
            flags: 0,
            reserved: 0,
        }
    }

    /// True if the end-of-stream flag is set.
    pub fn is_end_of_stream(&self) -> bool {
        self.flags & FLAG_END_OF_STREAM != 0
    }

    /// Checks magic, version, stream, camera and that the payload the sample really
    /// carries (`actual_len` elements of `T`) is what the header announces.
    pub fn validate<T>(
        &self,
        stream: Stream,
        camera: &CameraId,
        actual_len: usize,
    ) -> Result<(), WireError> {
        check_layout(self.magic, self.layout_version)?;
        if self.stream != stream as u16 {
            return Err(WireError::Stream {
                expected: stream,
                found: Stream::from_u16(self.stream)
                    .map(|s| s.name().to_string())
                    .unwrap_or_else(|| format!("unknown kind {}", self.stream)),
            });
        }
        if self.camera != *camera {
            return Err(WireError::Camera {
                expected: camera.as_str().into_owned(),
                found: self.camera.as_str().into_owned(),
            });
        }
        let element_size = std::mem::size_of::<T>() as u32;
        if self.element_size != element_size || self.payload_len as usize != actual_len {
            return Err(WireError::Size {
                what: "payload",
                expected: format!("{actual_len} elements of {element_size} bytes"),
                found: format!(
                    "{} elements of {} bytes",
                    self.payload_len, self.element_size
                ),
            });
        }
        Ok(())
    }

    /// [`Preamble::validate`], then, unless the sample is an end-of-stream marker
    /// (whose other header fields mean nothing), the stream's own checks `data`.
    pub fn validate_then<T>(
        &self,
        stream: Stream,
        camera: &CameraId,
        actual_len: usize,
        data: impl FnOnce() -> Result<(), WireError>,
    ) -> Result<(), WireError> {
        self.validate::<T>(stream, camera, actual_len)?;
        if self.is_end_of_stream() {
            return Ok(());
        }
        data()
    }
}

/// Why a received sample was rejected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WireError {
    /// Not an isochron sample at all.
    #[error(
        "bad magic {found:#010x} (expected {MAGIC:#010x}, \"ISOC\"): the publisher is not an isochron service"
    )]
    Magic {
        /// The magic found.
        found: u32,
    },
    /// Produced by another version of isochron.
    #[error(
        "layout version {found} (this build reads {LAYOUT_VERSION}): the publisher is another isochron version; run the same version on both ends"
    )]
    Version {
        /// The version found.
        found: u16,
    },
    /// A sample of another stream on this service.
    #[error("sample of stream '{found}' on a '{expected}' service")]
    Stream {
        /// The stream the consumer reads.
        expected: Stream,
        /// What the header says.
        found: String,
    },
    /// A sample of another camera on this camera's service.
    #[error("sample of camera '{found}' on camera '{expected}''s service")]
    Camera {
        /// Camera the consumer reads.
        expected: String,
        /// Camera in the header.
        found: String,
    },
    /// Sizes in the header do not match the sample or each other.
    #[error("{what} size mismatch: expected {expected}, found {found}")]
    Size {
        /// Which size.
        what: &'static str,
        /// What was expected.
        expected: String,
        /// What was found.
        found: String,
    },
    /// A field holds a value outside its range.
    #[error("invalid {field}: {reason}")]
    Field {
        /// The field.
        field: &'static str,
        /// Why it is invalid.
        reason: String,
    },
}

/// Declares a `#[repr(u32)]` enum as a header field carries it, with `from_u32`,
/// which parses that `u32` (`None` for a value no variant has).
#[macro_export]
macro_rules! u32_enum {
    (
        $(#[$meta:meta])*
        $vis:vis enum $name:ident {
            $($(#[$variant_meta:meta])* $variant:ident = $value:literal,)*
        }
    ) => {
        $(#[$meta])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq)]
        #[repr(u32)]
        $vis enum $name {
            $($(#[$variant_meta])* $variant = $value,)*
        }

        impl $name {
            /// Parses the `u32` this enum is sent as.
            pub fn from_u32(v: u32) -> Option<$name> {
                match v {
                    $($value => Some($name::$variant),)*
                    _ => None,
                }
            }

            /// Parses header field `field`, or says that its value is unknown.
            pub fn from_field(
                v: u32,
                field: &'static str,
            ) -> Result<$name, $crate::WireError> {
                $name::from_u32(v).ok_or_else(|| $crate::WireError::Field {
                    field,
                    reason: format!("unknown value {v}"),
                })
            }
        }
    };
}

u32_enum! {
    /// Pixel layout of a frame.
    pub enum PixelFormat {
        /// One byte per pixel, luminance.
        Gray8 = 1,
        /// Three bytes per pixel, blue-green-red (OpenCV's order).
        Bgr8 = 2,
    }
}

impl PixelFormat {
    /// Bytes per pixel.
    pub fn channels(self) -> usize {
        match self {
            PixelFormat::Gray8 => 1,
            PixelFormat::Bgr8 => 3,
        }
    }
}

/// Header of a `frames` sample; the payload is `height * stride` bytes of pixels.
#[derive(Debug, Clone, Copy, Default, ZeroCopySend)]
#[type_name("isochron::FrameHeader")]
#[repr(C)]
pub struct FrameHeader {
    /// Common fields.
    pub preamble: Preamble,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Bytes per row (`width * channels`; rows are packed).
    pub stride: u32,
    /// A [`PixelFormat`] as `u32`.
    pub pixel_format: u32,
    /// Index of the frame in its source (0-based; for files, the frame number in the
    /// file, restarting when a file loops).
    pub source_index: u64,
}

impl FrameHeader {
    /// Validates the header against the sample's real payload length (bytes).
    pub fn validate(&self, camera: &CameraId, payload_bytes: usize) -> Result<(), WireError> {
        self.preamble
            .validate_then::<u8>(Stream::Frames, camera, payload_bytes, || {
                let format = PixelFormat::from_field(self.pixel_format, "pixel_format")?;
                check_side("width", self.width)?;
                check_side("height", self.height)?;
                let expected = self.width as usize * format.channels();
                if self.stride as usize != expected {
                    return Err(WireError::Size {
                        what: "row stride",
                        expected: expected.to_string(),
                        found: self.stride.to_string(),
                    });
                }
                let bytes = self.stride as usize * self.height as usize;
                if bytes != payload_bytes {
                    return Err(WireError::Size {
                        what: "frame",
                        expected: format!(
                            "{}x{}x{} = {bytes} bytes",
                            self.width,
                            self.height,
                            format.channels()
                        ),
                        found: format!("{payload_bytes} bytes"),
                    });
                }
                Ok(())
            })
    }

    /// The pixel format (valid after [`FrameHeader::validate`]).
    pub fn format(&self) -> PixelFormat {
        PixelFormat::from_u32(self.pixel_format).unwrap_or(PixelFormat::Gray8)
    }
}

/// Direction label meaning "no coherent direction".
pub const DIRECTION_NONE: u8 = 255;

/// Motion features of one block (computed by `isochron-motion`; its `features`
/// module has the details). A still or masked block is all zero with
/// `direction = DIRECTION_NONE`.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("isochron::BlockMotion")]
#[repr(C)]
pub struct BlockMotion {
    /// How much moves: motion pixels weighted by their gradient (`min(|Gx|+|Gy|, 64)`
    /// each), normalised to the block, 0..=1.
    pub density: f32,
    /// Flow vector, x (right): `density * coherence * unit direction`, where the
    /// direction is the block's fitted displacement and the coherence (0..=1) the
    /// fraction of the block's temporal change that one displacement explains. Short
    /// when little moves or the block's pixels disagree. Filter it as a vector (an
    /// average of angles is wrong at the wrap-around).
    pub dx: f32,
    /// Flow vector, y (down); see `dx`.
    pub dy: f32,
    /// 8-way direction label of (dx, dy), 0 = right, counter-clockwise on screen in
    /// steps of 45° (2 = up, 4 = left, 6 = down), or [`DIRECTION_NONE`] (density
    /// below `motion.density_threshold`, or coherence below 0.2).
    pub direction: u8,
    /// Zero.
    pub reserved: [u8; 3],
    /// Appearance of the block in the current frame (with [`FLAG_APPEARANCE`],
    /// else 0): its mean grey level, in 1/[`APPEARANCE_SCALE`] grey levels.
    pub luma: u16,
    /// ... and its texture: the mean absolute difference of each pixel to its
    /// right and lower neighbours, in 1/[`APPEARANCE_SCALE`] grey levels.
    pub texture: u16,
}

/// Header of a `motion` sample; the payload is `grid_w * grid_h` [`BlockMotion`]s,
/// row-major, one sample per pair of consecutive frames (none for the first frame
/// of a run). `preamble.capture_time_ns` and `origin_wall_ns` are the current
/// frame's. Flags: [`FLAG_END_OF_STREAM`] (the frames ended; no payload),
/// [`FLAG_ILLUMINATION`] (a global brightness step of at least half the difference
/// threshold was compensated, or a lighting change was detected and every block
/// zeroed) and [`FLAG_APPEARANCE`] (the blocks' appearance was measured).
#[derive(Debug, Clone, Copy, Default, ZeroCopySend)]
#[type_name("isochron::MotionHeader")]
#[repr(C)]
pub struct MotionHeader {
    /// Common fields.
    pub preamble: Preamble,
    /// Frame width the blocks cover.
    pub frame_width: u32,
    /// Frame height the blocks cover.
    pub frame_height: u32,
    /// Block edge in pixels (edge blocks may be smaller).
    pub block_px: u32,
    /// Blocks per row.
    pub grid_w: u32,
    /// Block rows.
    pub grid_h: u32,
    /// Fraction of unmasked blocks whose density was at or above threshold, before
    /// any illumination suppression.
    pub changed_fraction: f32,
    /// Source frame index of the current frame.
    pub source_index: u64,
}

/// Checks a frame side (`field`) a header carries: 1 to [`MAX_FRAME_SIDE`] pixels.
fn check_side(field: &'static str, px: u32) -> Result<(), WireError> {
    if px == 0 || px > MAX_FRAME_SIDE {
        return Err(WireError::Field {
            field,
            reason: format!("{px} px: expected 1 to {MAX_FRAME_SIDE}"),
        });
    }
    Ok(())
}

/// Checks the block grid a header describes — frame size, block edge, and the
/// grid size derived from them — against the bounds of this file, with no
/// arithmetic that can overflow: the grid's number of blocks (at most
/// [`MAX_BLOCKS`]).
pub fn check_block_grid(
    [frame_width, frame_height, block_px, grid_w, grid_h]: [u32; 5],
) -> Result<usize, WireError> {
    check_side("frame_width", frame_width)?;
    check_side("frame_height", frame_height)?;
    if !(MIN_BLOCK_PX..=MAX_BLOCK_PX).contains(&block_px) {
        return Err(WireError::Field {
            field: "block_px",
            reason: format!("{block_px}: expected {MIN_BLOCK_PX} to {MAX_BLOCK_PX}"),
        });
    }
    let derived = BlockGrid::new(frame_width, frame_height, block_px);
    let (w, h) = (derived.grid_w(), derived.grid_h());
    if (w, h) != (grid_w, grid_h) {
        return Err(WireError::Size {
            what: "block grid",
            expected: format!("{w}x{h} blocks for {frame_width}x{frame_height} px / {block_px}"),
            found: format!("{grid_w}x{grid_h}"),
        });
    }
    // Both sides are at most MAX_FRAME_SIDE / MIN_BLOCK_PX: the product fits.
    let blocks = w as usize * h as usize;
    if blocks > MAX_BLOCKS {
        return Err(WireError::Size {
            what: "block grid",
            expected: format!(
                "at most {MAX_BLOCKS} blocks (a larger motion.block_px or a smaller camera.width/height)"
            ),
            found: format!("{w}x{h} = {blocks} blocks"),
        });
    }
    Ok(blocks)
}

/// The checks the headers of one `E` per block (motion, activity) share: the
/// preamble, the block grid against the frame size ([`check_block_grid`]), and a
/// payload of one element per block (`what` names it in errors).
fn validate_blocks<E>(
    preamble: &Preamble,
    stream: Stream,
    what: &'static str,
    camera: &CameraId,
    blocks: usize,
    grid: [u32; 5],
) -> Result<(), WireError> {
    preamble.validate::<E>(stream, camera, blocks)?;
    if preamble.is_end_of_stream() {
        return Ok(());
    }
    let expected = check_block_grid(grid)?;
    if expected != blocks {
        return Err(WireError::Size {
            what,
            expected: format!("{expected} blocks"),
            found: format!("{blocks} blocks"),
        });
    }
    Ok(())
}

/// What a receiver knows of a camera's block grid: the one its config gives
/// (`camera.width`/`height` with `motion.block_px`), or else the grid of the first
/// valid sample, pinned for the life of the process. A sample of any other grid
/// is refused ([`KnownGrid::check`]): a forged or foreign sample cannot make the
/// receiver rebuild what it derives from the grid (footprints, buffers).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct KnownGrid {
    grid: Option<BlockGrid>,
    configured: bool,
}

impl KnownGrid {
    /// The grid of a camera whose config gives it (`Some`), or one to be pinned
    /// by its first sample (`None`).
    pub fn new(configured: Option<BlockGrid>) -> KnownGrid {
        KnownGrid {
            grid: configured,
            configured: configured.is_some(),
        }
    }

    /// The grid, once known.
    pub fn grid(&self) -> Option<BlockGrid> {
        self.grid
    }

    /// Checks the grid of a valid sample: `Ok(false)` if it is the known one,
    /// `Ok(true)` if it was unknown and is pinned now (the caller warns, once),
    /// an error naming both grids if it is another.
    pub fn check(&mut self, grid: BlockGrid) -> Result<bool, WireError> {
        match self.grid {
            Some(known) if known == grid => Ok(false),
            Some(known) => Err(WireError::Size {
                what: "block grid",
                expected: if self.configured {
                    format!("{known}, as camera.width/height and motion.block_px give")
                } else {
                    format!(
                        "{known}, pinned by this camera's first sample (set camera.width/height to fix it, restart to pin again)"
                    )
                },
                found: grid.to_string(),
            }),
            None => {
                self.grid = Some(grid);
                Ok(true)
            }
        }
    }
}

/// Activity of one block over the last second, and the long-term model at t*.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize, Deserialize)]
#[type_name("isochron::BlockActivity")]
#[repr(C)]
pub struct BlockActivity {
    /// Short-term in-place activity (F_S1 output), density units.
    pub s1: f32,
    /// Short-term moving activity (band-pass F_S2 output, rectified).
    pub s2: f32,
    /// In-place flow vector, x.
    pub s1_dx: f32,
    /// In-place flow vector, y.
    pub s1_dy: f32,
    /// Moving flow vector, x.
    pub s2_dx: f32,
    /// Moving flow vector, y.
    pub s2_dy: f32,
    /// Long-term (isochronal) mean of M_L1 at the current t*.
    pub lt_mean: f32,
    /// Long-term standard deviation at the current t*.
    pub lt_sigma: f32,
    /// Presence band: 1 while something that entered with motion stays in the
    /// block (it differs from the block's learned empty appearance), else 0. See
    /// the cascade's `presence` module.
    pub present: f32,
}

/// Header of an `activity` sample (1 Hz); payload `grid_w * grid_h` [`BlockActivity`].
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize, Deserialize)]
#[type_name("isochron::ActivityHeader")]
#[repr(C)]
pub struct ActivityHeader {
    /// Common fields; `capture_time_ns` is the end of the second this sample covers.
    pub preamble: Preamble,
    /// Blocks per row.
    pub grid_w: u32,
    /// Block rows.
    pub grid_h: u32,
    /// Block edge in pixels.
    pub block_px: u32,
    /// Frame width the blocks cover.
    pub frame_width: u32,
    /// Frame height the blocks cover.
    pub frame_height: u32,
    /// Isochronal time t*: minute of the cycle (0..1440, or 0..10080 weekly).
    pub t_star: u32,
    /// Days of data the long-term model has at this t* (0 = cold).
    pub model_days: u32,
    /// Frames that went into this second.
    pub frames: u32,
    /// Source index of the first frame of this second.
    pub first_source_index: u64,
    /// Source index of the last frame of this second.
    pub last_source_index: u64,
    /// Measured frame rate r (frames/s) used by F_L1.
    pub frame_rate: f32,
    /// Zero.
    pub reserved: u32,
}

/// The grid accessor and checks of a header of one `$element` per block (motion and
/// activity): its frame size, block edge and grid size, checked by [`validate_blocks`].
macro_rules! block_header {
    ($header:ident, $element:ty, $stream:expr, $what:literal) => {
        impl $header {
            /// The block grid the header describes (its frame size and block edge; a
            /// [valid](Self::validate) header's `grid_w`/`grid_h` are derived from
            /// them).
            pub fn block_grid(&self) -> BlockGrid {
                BlockGrid::new(self.frame_width, self.frame_height, self.block_px)
            }

            /// Validates the header against the sample's real payload length (blocks).
            pub fn validate(&self, camera: &CameraId, blocks: usize) -> Result<(), WireError> {
                validate_blocks::<$element>(
                    &self.preamble,
                    $stream,
                    $what,
                    camera,
                    blocks,
                    [
                        self.frame_width,
                        self.frame_height,
                        self.block_px,
                        self.grid_w,
                        self.grid_h,
                    ],
                )
            }
        }
    };
}

block_header!(MotionHeader, BlockMotion, Stream::Motion, "motion payload");
block_header!(
    ActivityHeader,
    BlockActivity,
    Stream::Activity,
    "activity payload"
);

impl ActivityHeader {
    /// The header of camera `camera`'s activity sample `sequence` over `grid`, for the
    /// second that ends at `capture_time_ns`; the second's own fields (`t_star`,
    /// `frames`, …) are zero for the caller to set.
    pub fn new(camera: CameraId, sequence: u64, grid: BlockGrid, capture_time_ns: i64) -> Self {
        let mut preamble =
            Preamble::new::<BlockActivity>(Stream::Activity, camera, sequence, grid.len());
        preamble.capture_time_ns = capture_time_ns;
        ActivityHeader {
            preamble,
            grid_w: grid.grid_w(),
            grid_h: grid.grid_h(),
            block_px: grid.block_px,
            frame_width: grid.frame_width,
            frame_height: grid.frame_height,
            ..ActivityHeader::default()
        }
    }
}

u32_enum! {
    /// Kind of activity an event was raised on.
    pub enum ActivityKind {
        /// In-place activity (S1).
        InPlace = 1,
        /// Moving activity (S2).
        Moving = 2,
    }
}

impl ActivityKind {
    /// Name used in JSON and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            ActivityKind::InPlace => "in-place",
            ActivityKind::Moving => "moving",
        }
    }
}

u32_enum! {
    /// Phase of an event record.
    pub enum EventPhase {
        /// The event started.
        Start = 1,
        /// The event ended.
        End = 2,
    }
}

/// Longest zone name, in bytes.
pub const ZONE_NAME_LEN: usize = 32;

/// Header of an `events` sample; the payload lists the indices (row-major) of the
/// blocks involved, as `u32`.
#[derive(Debug, Clone, Copy, Default, ZeroCopySend, Serialize, Deserialize)]
#[type_name("isochron::EventHeader")]
#[repr(C)]
pub struct EventHeader {
    /// Common fields; `capture_time_ns` is the time of the record.
    pub preamble: Preamble,
    /// Event number, per camera, from 0; start and end records share it.
    pub event_id: u64,
    /// Zone name, zero-padded.
    pub zone: [u8; ZONE_NAME_LEN],
    /// An [`ActivityKind`] as `u32`.
    pub kind: u32,
    /// An [`EventPhase`] as `u32`.
    pub phase: u32,
    /// Start time, UTC ns.
    pub start_ns: i64,
    /// End time, UTC ns (0 in a start record).
    pub end_ns: i64,
    /// Source index of the first frame of the event.
    pub start_frame: u64,
    /// Source index of the last frame of the event (0 in a start record).
    pub end_frame: u64,
    /// Highest zone activity seen so far.
    pub peak: f32,
    /// Threshold the activity crossed.
    pub threshold: f32,
}

impl EventHeader {
    /// Validates the header against the sample's real payload length.
    pub fn validate(&self, camera: &CameraId, blocks: usize) -> Result<(), WireError> {
        self.preamble
            .validate_then::<u32>(Stream::Events, camera, blocks, || {
                ActivityKind::from_field(self.kind, "kind")?;
                let phase = EventPhase::from_field(self.phase, "phase")?;
                if blocks > MAX_BLOCKS {
                    return Err(WireError::Size {
                        what: "event block list",
                        expected: format!("at most {MAX_BLOCKS} blocks"),
                        found: format!("{blocks} blocks"),
                    });
                }
                if self.start_ns < 0 {
                    return Err(WireError::Field {
                        field: "start_ns",
                        reason: format!("{}: expected a time at or after 1970", self.start_ns),
                    });
                }
                let end_ok = match phase {
                    EventPhase::Start => self.end_ns == 0,
                    EventPhase::End => self.end_ns >= self.start_ns,
                };
                if !end_ok {
                    return Err(WireError::Field {
                        field: "end_ns",
                        reason: format!(
                            "{} in a {} record starting at {}: expected 0 in a start record, not before start_ns in an end record",
                            self.end_ns,
                            if phase == EventPhase::Start { "start" } else { "end" },
                            self.start_ns
                        ),
                    });
                }
                for (field, v) in [("peak", self.peak), ("threshold", self.threshold)] {
                    if !v.is_finite() {
                        return Err(WireError::Field {
                            field,
                            reason: format!("{v}: expected a finite number"),
                        });
                    }
                }
                Ok(())
            })
    }

    /// The zone name as text.
    pub fn zone_name(&self) -> String {
        fixed_str(&self.zone)
    }
}

/// Copies `s` into a zero-padded fixed buffer, truncating at a char boundary.
pub fn to_fixed<const N: usize>(s: &str) -> [u8; N] {
    let mut out = [0u8; N];
    let mut end = s.len().min(N);
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    out[..end].copy_from_slice(&s.as_bytes()[..end]);
    out
}

/// Reads a zero-padded fixed buffer as text.
pub fn fixed_str(bytes: &[u8]) -> String {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    String::from_utf8_lossy(&bytes[..end]).into_owned()
}

/// One detected object (a person) in frame pixel coordinates.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize, Deserialize)]
#[type_name("isochron::Detection")]
#[repr(C)]
pub struct Detection {
    /// Left edge.
    pub x: f32,
    /// Top edge.
    pub y: f32,
    /// Width.
    pub w: f32,
    /// Height.
    pub h: f32,
    /// Detector confidence (HOG: SVM margin; DNN: class score).
    pub score: f32,
    /// Class id (0 = person).
    pub class: u32,
}

/// Header of a `detections` sample; payload is the [`Detection`]s of one frame.
#[derive(Debug, Clone, Copy, Default, ZeroCopySend, Serialize, Deserialize)]
#[type_name("isochron::DetectionHeader")]
#[repr(C)]
pub struct DetectionHeader {
    /// Common fields; `capture_time_ns` is the detected frame's capture time.
    pub preamble: Preamble,
    /// Event that gated this frame.
    pub event_id: u64,
    /// Source index of the detected frame.
    pub source_index: u64,
    /// Time the detector took, microseconds.
    pub detector_us: u64,
    /// Frames the gate has seen so far.
    pub frames_seen: u64,
    /// Frames the detector ran on so far (this one included).
    pub frames_detected: u64,
    /// Detection jobs dropped so far because the detector was busy.
    pub jobs_dropped: u64,
    /// Total detector time so far, microseconds.
    pub detector_total_us: u64,
    /// The region of the frame the detector searched (frame pixels): a person
    /// confirmed earlier whose feet lie inside it and who is not among this
    /// sample's detections is gone. Width 0: the whole frame.
    pub roi_x: u32,
    /// Top of the searched region.
    pub roi_y: u32,
    /// Width of the searched region; 0 means the whole frame.
    pub roi_w: u32,
    /// Height of the searched region.
    pub roi_h: u32,
}

impl DetectionHeader {
    /// True if the frame point `(x, y)` lies in the searched region.
    pub fn searched(&self, x: f32, y: f32) -> bool {
        self.roi_w == 0
            || (x >= self.roi_x as f32
                && y >= self.roi_y as f32
                && x <= self.roi_x.saturating_add(self.roi_w) as f32
                && y <= self.roi_y.saturating_add(self.roi_h) as f32)
    }

    /// Validates the header against the sample's real payload length: at most
    /// [`MAX_DETECTIONS`], a searched region inside the largest frame.
    pub fn validate(&self, camera: &CameraId, detections: usize) -> Result<(), WireError> {
        self.preamble
            .validate_then::<Detection>(Stream::Detections, camera, detections, || {
                if detections > MAX_DETECTIONS {
                    return Err(WireError::Size {
                        what: "detections",
                        expected: format!("at most {MAX_DETECTIONS}"),
                        found: detections.to_string(),
                    });
                }
                let (x1, y1) = (
                    self.roi_x as u64 + self.roi_w as u64,
                    self.roi_y as u64 + self.roi_h as u64,
                );
                if x1 > MAX_FRAME_SIDE as u64 || y1 > MAX_FRAME_SIDE as u64 {
                    return Err(WireError::Field {
                        field: "roi",
                        reason: format!(
                            "{}x{} at ({}, {}): expected inside {MAX_FRAME_SIDE}x{MAX_FRAME_SIDE} px",
                            self.roi_w, self.roi_h, self.roi_x, self.roi_y
                        ),
                    });
                }
                Ok(())
            })
    }
}

/// What every stream header has: a [`Preamble`] first, and a check against the
/// payload it arrived with. The stage runtime validates, counts and forwards end of
/// stream through it, whatever the stream.
pub trait StreamHeader: Copy + Default {
    /// The preamble.
    fn preamble(&self) -> &Preamble;
    /// The preamble, to fill in.
    fn preamble_mut(&mut self) -> &mut Preamble;
    /// Checks the header against `camera` and the real payload length.
    fn validate(&self, camera: &CameraId, payload_len: usize) -> Result<(), WireError>;
}

macro_rules! stream_header {
    ($($header:ty),*) => {$(
        impl StreamHeader for $header {
            fn preamble(&self) -> &Preamble {
                &self.preamble
            }
            fn preamble_mut(&mut self) -> &mut Preamble {
                &mut self.preamble
            }
            fn validate(&self, camera: &CameraId, payload_len: usize) -> Result<(), WireError> {
                <$header>::validate(self, camera, payload_len)
            }
        }
    )*};
}
stream_header!(
    FrameHeader,
    MotionHeader,
    ActivityHeader,
    EventHeader,
    DetectionHeader
);

/// Longest stage name in a [`StageStatus`].
pub const STAGE_NAME_LEN: usize = 16;
/// Length of the free-text detail of a [`StageStatus`].
pub const STATUS_DETAIL_LEN: usize = 160;

/// Periodic health of one stage of one camera, published on
/// `<prefix>/<camera>/status/<stage>` (history 1, so `isochron status` sees the
/// latest at once).
#[derive(Debug, Clone, Copy, ZeroCopySend, Serialize, Deserialize)]
#[type_name("isochron::StageStatus")]
#[repr(C)]
pub struct StageStatus {
    /// Always [`MAGIC`].
    pub magic: u32,
    /// Always [`LAYOUT_VERSION`].
    pub layout_version: u16,
    /// Zero.
    pub reserved: u16,
    /// Camera.
    pub camera: CameraId,
    /// Stage name (`capture`, `motion`, ...), zero-padded.
    pub stage: [u8; STAGE_NAME_LEN],
    /// Process id.
    pub pid: u32,
    /// Samples per second received over the last report period.
    pub rate_in: f32,
    /// Wall clock (UTC ns) of the process start.
    pub started_wall_ns: i64,
    /// Wall clock (UTC ns) of this report.
    pub report_wall_ns: i64,
    /// Samples received (or frames read, for capture).
    pub received: u64,
    /// Samples published.
    pub sent: u64,
    /// Samples lost upstream (sequence gaps) or dropped here.
    pub dropped: u64,
    /// Samples rejected as malformed.
    pub rejected: u64,
    /// Samples per second published over the last report period.
    pub rate_out: f32,
    /// Median time from a sample's arrival to this stage's output, ms.
    pub stage_latency_ms: f32,
    /// Median end-to-end latency, capture publish → this stage's output, ms.
    pub e2e_latency_p50_ms: f32,
    /// 99th percentile of the end-to-end latency, ms.
    pub e2e_latency_p99_ms: f32,
    /// Stage-specific counters as text (`detected=3 detector_ms=410`).
    #[serde(with = "fixed_bytes")]
    pub detail: [u8; STATUS_DETAIL_LEN],
}

/// Serde for byte arrays longer than serde's own (32): a tuple of `N` bytes,
/// which CDR writes as a fixed array (`uint8[N]`) with no length.
mod fixed_bytes {
    use serde::de::{Error, SeqAccess, Visitor};
    use serde::ser::SerializeTuple;
    use serde::{Deserializer, Serializer};

    pub fn serialize<S: Serializer, const N: usize>(
        bytes: &[u8; N],
        serializer: S,
    ) -> Result<S::Ok, S::Error> {
        let mut tuple = serializer.serialize_tuple(N)?;
        for b in bytes {
            tuple.serialize_element(b)?;
        }
        tuple.end()
    }

    pub fn deserialize<'de, D: Deserializer<'de>, const N: usize>(
        deserializer: D,
    ) -> Result<[u8; N], D::Error> {
        struct Bytes<const N: usize>;
        impl<'de, const N: usize> Visitor<'de> for Bytes<N> {
            type Value = [u8; N];
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                write!(f, "{N} bytes")
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<[u8; N], A::Error> {
                let mut out = [0u8; N];
                for (k, b) in out.iter_mut().enumerate() {
                    *b = seq
                        .next_element()?
                        .ok_or_else(|| A::Error::invalid_length(k, &self))?;
                }
                Ok(out)
            }
        }
        deserializer.deserialize_tuple(N, Bytes::<N>)
    }
}

impl StageStatus {
    /// Checks magic and version.
    pub fn validate(&self) -> Result<(), WireError> {
        check_layout(self.magic, self.layout_version)
    }

    /// The counters and latencies as one line of `key=value` words, for logs
    /// (`in=250 (25.0/s) out=250 (25.0/s) dropped=0 rejected=0 latency_ms=0.12
    /// e2e_ms(p50/p99)=1.0/2.1`).
    pub fn counters(&self) -> String {
        format!(
            "in={} ({:.1}/s) out={} ({:.1}/s) dropped={} rejected={} latency_ms={:.2} e2e_ms(p50/p99)={:.1}/{:.1}",
            self.received,
            self.rate_in,
            self.sent,
            self.rate_out,
            self.dropped,
            self.rejected,
            self.stage_latency_ms,
            self.e2e_latency_p50_ms,
            self.e2e_latency_p99_ms,
        )
    }
}

/// Longest route or segment name, bytes: the limit on `[[costmap.route]]` and
/// `[[costmap.segment]]` names, so that they fit the planning queries of
/// `isochron-planning`.
pub const PLAN_NAME_LEN: usize = 32;

#[cfg(test)]
mod tests {
    use super::*;

    fn cam() -> CameraId {
        CameraId::new("cam01").unwrap()
    }

    fn frame_header(w: u32, h: u32) -> FrameHeader {
        let mut preamble = Preamble::new::<u8>(Stream::Frames, cam(), 0, (w * h) as usize);
        preamble.capture_time_ns = 1;
        FrameHeader {
            preamble,
            width: w,
            height: h,
            stride: w,
            pixel_format: PixelFormat::Gray8 as u32,
            source_index: 0,
        }
    }

    #[test]
    fn camera_ids() {
        assert_eq!(CameraId::new("cam-01_a").unwrap().as_str(), "cam-01_a");
        assert!(CameraId::new("").is_none());
        assert!(CameraId::new("has space").is_none());
        assert!(CameraId::new(&"x".repeat(25)).is_none());
        assert!(CameraId::new(&"x".repeat(24)).is_some());
    }

    #[test]
    fn good_frame_header_validates() {
        assert_eq!(frame_header(64, 48).validate(&cam(), 64 * 48), Ok(()));
    }

    #[test]
    fn wrong_magic_version_stream_camera_size_are_rejected() {
        let mut h = frame_header(64, 48);
        h.preamble.magic = 0xdead_beef;
        let err = h.validate(&cam(), 64 * 48).unwrap_err();
        assert!(matches!(err, WireError::Magic { .. }));
        assert!(err.to_string().contains("not an isochron service"));

        let mut h = frame_header(64, 48);
        h.preamble.layout_version = 99;
        assert!(matches!(
            h.validate(&cam(), 64 * 48),
            Err(WireError::Version { found: 99 })
        ));

        let mut h = frame_header(64, 48);
        h.preamble.stream = Stream::Motion as u16;
        assert!(matches!(
            h.validate(&cam(), 64 * 48),
            Err(WireError::Stream { .. })
        ));

        let h = frame_header(64, 48);
        let other = CameraId::new("cam02").unwrap();
        assert!(matches!(
            h.validate(&other, 64 * 48),
            Err(WireError::Camera { .. })
        ));

        // The header announces fewer bytes than the sample carries.
        let h = frame_header(64, 48);
        assert!(matches!(
            h.validate(&cam(), 64 * 48 + 1),
            Err(WireError::Size { .. })
        ));

        // Internally inconsistent: width*height does not fit the payload.
        let mut h = frame_header(64, 48);
        h.height = 50;
        let err = h.validate(&cam(), 64 * 48).unwrap_err();
        assert!(err.to_string().contains("frame size mismatch"), "{err}");
    }

    #[test]
    fn motion_grid_must_follow_frame_size() {
        let mut preamble = Preamble::new::<BlockMotion>(Stream::Motion, cam(), 0, 48 * 36);
        preamble.capture_time_ns = 1;
        let mut h = MotionHeader {
            preamble,
            frame_width: 768,
            frame_height: 576,
            block_px: 16,
            grid_w: 48,
            grid_h: 36,
            changed_fraction: 0.0,
            source_index: 0,
        };
        assert_eq!(h.validate(&cam(), 48 * 36), Ok(()));
        h.grid_w = 47;
        assert!(h.validate(&cam(), 48 * 36).is_err());
    }

    #[test]
    fn end_of_stream_needs_no_payload() {
        let mut h = frame_header(64, 48);
        h.preamble.payload_len = 0;
        h.preamble.flags = FLAG_END_OF_STREAM;
        assert_eq!(h.validate(&cam(), 0), Ok(()));
    }

    #[test]
    fn a_grid_whose_product_wraps_in_u32_is_refused() {
        // 0xFFFFFFFF² wraps to 1 in u32 and 65 536² to 0: neither may pass as a
        // grid of 1 or 0 blocks.
        let wrapping = [
            [u32::MAX, u32::MAX, 1, u32::MAX, u32::MAX],
            [65_536 * 16, 65_536 * 16, 16, 65_536, 65_536],
        ];
        for (grid, blocks) in wrapping.into_iter().zip([1, 0]) {
            let mut p = Preamble::new::<BlockActivity>(Stream::Activity, cam(), 0, blocks);
            p.capture_time_ns = 1;
            let h = ActivityHeader {
                preamble: p,
                frame_width: grid[0],
                frame_height: grid[1],
                block_px: grid[2],
                grid_w: grid[3],
                grid_h: grid[4],
                ..Default::default()
            };
            let err = h.validate(&cam(), blocks).unwrap_err();
            assert!(err.to_string().contains("frame_width"), "{err}");
        }
        // The largest grid the bounds allow, and one block more.
        assert_eq!(check_block_grid([4096, 4096, 16, 256, 256]), Ok(MAX_BLOCKS));
        let err = check_block_grid([4096, 4112, 16, 256, 257]).unwrap_err();
        assert!(err.to_string().contains("at most 65536 blocks"), "{err}");
    }

    #[test]
    fn a_known_grid_refuses_another() {
        let (a, b) = (BlockGrid::new(320, 240, 16), BlockGrid::new(640, 480, 16));
        let mut pinned = KnownGrid::new(None);
        assert_eq!(pinned.check(a), Ok(true));
        assert_eq!(pinned.check(a), Ok(false));
        let err = pinned.check(b).unwrap_err().to_string();
        assert!(
            err.contains("pinned by this camera's first sample"),
            "{err}"
        );
        let mut configured = KnownGrid::new(Some(b));
        assert_eq!(configured.check(b), Ok(false));
        let err = configured.check(a).unwrap_err().to_string();
        assert!(err.contains("camera.width/height"), "{err}");
    }

    fn event_header(phase: EventPhase, start_ns: i64, end_ns: i64) -> EventHeader {
        let mut preamble = Preamble::new::<u32>(Stream::Events, cam(), 0, 1);
        preamble.capture_time_ns = 1;
        EventHeader {
            preamble,
            kind: ActivityKind::Moving as u32,
            phase: phase as u32,
            start_ns,
            end_ns,
            ..Default::default()
        }
    }

    #[test]
    fn an_event_that_ends_before_it_starts_is_refused() {
        assert_eq!(
            event_header(EventPhase::End, 10, 20).validate(&cam(), 1),
            Ok(())
        );
        assert_eq!(
            event_header(EventPhase::Start, 10, 0).validate(&cam(), 1),
            Ok(())
        );
        for (phase, start, end) in [
            (EventPhase::End, 20, 10),
            (EventPhase::Start, 10, 5),
            (EventPhase::End, -5, 10),
        ] {
            let err = event_header(phase, start, end).validate(&cam(), 1);
            assert!(matches!(err, Err(WireError::Field { .. })), "{err:?}");
        }
        let mut nan = event_header(EventPhase::End, 10, 20);
        nan.peak = f32::NAN;
        assert!(nan.validate(&cam(), 1).is_err());
    }

    #[test]
    fn a_detection_region_past_the_largest_frame_is_refused() {
        let mut h = DetectionHeader {
            preamble: Preamble::new::<Detection>(Stream::Detections, cam(), 0, 1),
            roi_x: u32::MAX,
            roi_w: 1,
            roi_h: 1,
            ..Default::default()
        };
        assert!(h.validate(&cam(), 1).is_err());
        assert!(!h.searched(0.0, 0.0), "no overflow");
        (h.roi_x, h.roi_w) = (100, 50);
        assert_eq!(h.validate(&cam(), 1), Ok(()));
        h.preamble.payload_len = MAX_DETECTIONS as u32 + 1;
        assert!(h.validate(&cam(), MAX_DETECTIONS + 1).is_err());
    }

    /// A header of type `H` read from arbitrary bytes, as a foreign producer could
    /// lay it out (every field of these types takes any bit pattern).
    fn from_bytes<H: Copy>(bytes: &[u8]) -> H {
        assert!(bytes.len() >= std::mem::size_of::<H>());
        // SAFETY: the headers are `repr(C)` of integers, floats and byte arrays,
        // for which every bit pattern is a value; the read is unaligned-safe.
        unsafe { std::ptr::read_unaligned(bytes.as_ptr().cast::<H>()) }
    }

    /// Sizes as a forger picks them: the edges of every range, and anything.
    fn size() -> impl proptest::strategy::Strategy<Value = u32> {
        use proptest::prelude::*;
        prop_oneof![
            Just(0u32),
            Just(1),
            Just(MAX_FRAME_SIDE),
            Just(MAX_FRAME_SIDE + 1),
            Just(65_536),
            Just(u32::MAX),
            0u32..=300,
            any::<u32>(),
        ]
    }

    mod properties {
        use super::*;
        use proptest::prelude::*;

        proptest! {
            #![proptest_config(ProptestConfig::with_cases(2000))]

            /// Any grid a header claims: validation never panics, and what it
            /// accepts is a grid of at most MAX_BLOCKS blocks that the payload
            /// matches, whose block count the grid itself computes without overflow.
            #[test]
            fn block_headers_accept_only_bounded_consistent_grids(
                fw in size(), fh in size(), px in size(), gw in size(), gh in size(),
                blocks in prop_oneof![Just(0usize), Just(1), 0usize..=70_000],
            ) {
                let mut p = Preamble::new::<BlockActivity>(Stream::Activity, cam(), 0, blocks);
                p.capture_time_ns = 1;
                let h = ActivityHeader {
                    preamble: p,
                    frame_width: fw,
                    frame_height: fh,
                    block_px: px,
                    grid_w: gw,
                    grid_h: gh,
                    ..Default::default()
                };
                if h.validate(&cam(), blocks).is_ok() {
                    let grid = h.block_grid();
                    prop_assert!(grid.len() <= MAX_BLOCKS);
                    prop_assert_eq!(grid.len(), blocks);
                    prop_assert_eq!((grid.grid_w(), grid.grid_h()), (gw, gh));
                }
                let mut m = MotionHeader {
                    preamble: Preamble::new::<BlockMotion>(Stream::Motion, cam(), 0, blocks),
                    frame_width: fw,
                    frame_height: fh,
                    block_px: px,
                    grid_w: gw,
                    grid_h: gh,
                    changed_fraction: 0.0,
                    source_index: 0,
                };
                m.preamble.capture_time_ns = 1;
                if m.validate(&cam(), blocks).is_ok() {
                    prop_assert!(m.block_grid().len() == blocks && blocks <= MAX_BLOCKS);
                }
            }

            /// Headers of arbitrary bytes (a foreign or hostile producer) with the
            /// right magic, version and camera: validation never panics; an
            /// accepted one is consistent with its payload.
            #[test]
            fn arbitrary_headers_never_panic(
                bytes in proptest::collection::vec(any::<u8>(), 512),
                len in prop_oneof![Just(0usize), Just(1), 0usize..=100_000],
                stream in 1u16..=5,
            ) {
                let fix = |p: &mut Preamble| {
                    p.magic = MAGIC;
                    p.layout_version = LAYOUT_VERSION;
                    p.stream = stream;
                    p.camera = cam();
                    p.payload_len = len as u32;
                };
                let mut a: ActivityHeader = from_bytes(&bytes);
                fix(&mut a.preamble);
                a.preamble.element_size = std::mem::size_of::<BlockActivity>() as u32;
                if a.validate(&cam(), len).is_ok() && !a.preamble.is_end_of_stream() {
                    prop_assert_eq!(a.block_grid().len(), len);
                }
                let mut m: MotionHeader = from_bytes(&bytes);
                fix(&mut m.preamble);
                m.preamble.element_size = std::mem::size_of::<BlockMotion>() as u32;
                if m.validate(&cam(), len).is_ok() && !m.preamble.is_end_of_stream() {
                    prop_assert_eq!(m.block_grid().len(), len);
                }
                let mut e: EventHeader = from_bytes(&bytes);
                fix(&mut e.preamble);
                e.preamble.element_size = 4;
                if e.validate(&cam(), len).is_ok() && !e.preamble.is_end_of_stream() {
                    prop_assert!(len <= MAX_BLOCKS);
                    prop_assert!(e.phase != EventPhase::End as u32 || e.end_ns >= e.start_ns);
                }
                let mut d: DetectionHeader = from_bytes(&bytes);
                fix(&mut d.preamble);
                d.preamble.element_size = std::mem::size_of::<Detection>() as u32;
                if d.validate(&cam(), len).is_ok() && !d.preamble.is_end_of_stream() {
                    prop_assert!(len <= MAX_DETECTIONS);
                }
                d.searched(f32::MAX, f32::MIN);
                let mut f: FrameHeader = from_bytes(&bytes);
                fix(&mut f.preamble);
                f.preamble.element_size = 1;
                if f.validate(&cam(), len).is_ok() && !f.preamble.is_end_of_stream() {
                    prop_assert_eq!(f.stride as usize * f.height as usize, len);
                }
            }
        }
    }

    #[test]
    fn fixed_strings_round_trip() {
        let z: [u8; ZONE_NAME_LEN] = to_fixed("entrance");
        assert_eq!(fixed_str(&z), "entrance");
        let long: [u8; 4] = to_fixed("héllo");
        assert_eq!(fixed_str(&long), "hél");
        // Never cut a character in half.
        let cut: [u8; 2] = to_fixed("hé");
        assert_eq!(fixed_str(&cut), "h");
    }
}
