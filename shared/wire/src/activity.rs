//! The `activity` stream: per block, once a second, the short-term activity and the
//! long-term model at t*.

use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};

use crate::blocks::{block_header, validate_blocks};
use crate::geometry::BlockGrid;
use crate::{CameraId, Preamble, Stream, WireError};

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
