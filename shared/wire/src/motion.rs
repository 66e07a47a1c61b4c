//! The `motion` stream: per block, how much moves and where to, per frame pair.

use iceoryx2::prelude::ZeroCopySend;

use crate::blocks::{block_header, validate_blocks};
use crate::geometry::BlockGrid;
use crate::{CameraId, Preamble, Stream, WireError};

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

block_header!(MotionHeader, BlockMotion, Stream::Motion, "motion payload");
