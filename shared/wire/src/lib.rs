//! Wire types: the fixed headers and payload elements of every isochron stream.
//!
//! Every sample on every stream carries, as its iceoryx2 user header, one of the
//! `*Header` structs of this crate. Each starts with the same [`Preamble`]: magic, layout
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
//! messages of the same names in `ros/isochron_msgs/msg`, which mirror this crate
//! field for field (a test in `isochron-link` pins the sizes).
//!
//! One module per stream (`frame`, `motion`, `activity`, `event`, `detection`,
//! `status`), their numbers and names (`stream`), the `preamble` they share, the
//! grid checks of the per-block streams (`blocks`), [`geometry`] and the
//! zero-padded text fields (`fixed`); every type is re-exported at the crate root.

mod activity;
mod blocks;
mod detection;
mod error;
mod event;
mod fixed;
mod frame;
pub mod geometry;
mod motion;
mod preamble;
mod status;
mod stream;
#[cfg(test)]
mod tests;

pub use activity::{ActivityHeader, BlockActivity};
pub use blocks::{KnownGrid, check_block_grid};
pub use detection::{
    Detection, DetectionHeader, DetectorModel, KEYPOINT_MIN_SCORE, KEYPOINT_NAMES, KEYPOINTS,
    Keypoint, SKELETON,
};
pub use error::WireError;
pub use event::{ActivityKind, EventHeader, EventPhase, ZONE_NAME_LEN};
pub use fixed::{fixed_str, to_fixed};
pub use frame::{FrameHeader, PixelFormat};
pub use motion::{BlockMotion, DIRECTION_NONE, MotionHeader};
pub use preamble::{CameraId, Preamble, check_layout, is_valid_camera_id};
pub use status::{STAGE_NAME_LEN, STATUS_COUNTERS, STATUS_INFO_LEN, StageStatus};
pub use stream::Stream;

isochron_exit::always_exits_with!(DATA: WireError;);

/// Magic at the start of every isochron header: the bytes `ISOC`.
pub const MAGIC: u32 = u32::from_le_bytes(*b"ISOC");

/// Version of the layout of all headers and payload elements in this crate. Bump it on
/// any change to one of its `#[repr(C)]` types.
pub const LAYOUT_VERSION: u16 = 5;

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

/// Longest route or segment name, bytes: the limit on `[[costmap.route]]` and
/// `[[costmap.segment]]` names, so that they fit the planning queries of
/// `isochron-planning`.
pub const PLAN_NAME_LEN: usize = 32;
