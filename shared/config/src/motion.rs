//! `[motion]`: motion features per block, and their backend.

use serde::{Deserialize, Serialize};

use super::{Invalid, check_range};

/// Motion-feature backend.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum MotionBackend {
    /// The fused, vectorised motion-flow kernel (temporal difference + normal flow).
    MotionFlow,
    /// OpenCV DIS optical flow reduced to the same block features (slower).
    Dis,
}

/// `[motion]`: motion features per block.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MotionConfig {
    /// Block edge in pixels. Default 16.
    pub block_px: u32,
    /// A pixel moves when its temporal difference (after removing the frame's mean
    /// brightness change) is at least this, grey levels. Default 15.
    pub diff_threshold: u8,
    /// ... and its spatial gradient |Gx|+|Gy| is at least this (central differences
    /// of the sum of both frames: 4 × the per-frame derivative, 0..=1020). Default 8.
    pub gradient_threshold: u16,
    /// ... and its edge moved at least this far, pixels per frame (a lower bound of
    /// the normal flow, `4·|It| / (|Gx|+|Gy|)`): strong static edges that shimmer by
    /// a fraction of a pixel (camera vibration, codec noise) do not count. 0 turns
    /// the test off. Default 0.5.
    pub min_flow_px: f32,
    /// A block counts as moving when its density is at least this. Default 0.02
    /// (with the defaults above, on PETS 2009 S2.L1: 91 % of moving people's blocks
    /// active, 99.2 % of blocks away from people quiet).
    pub density_threshold: f32,
    /// A frame is an illumination change when at least this fraction of blocks
    /// move at once with no coherent direction. Default 0.5.
    pub illumination_fraction: f32,
    /// Backend: `"motion-flow"` (default) or `"dis"`.
    pub backend: MotionBackend,
    /// Each block's appearance (mean grey level and texture, for the cascade's
    /// presence band, `[presence]`) is measured on at most this many frames per
    /// second of capture time, Hz; 0 turns it off (and with it the band). The band
    /// judges each second on the latest measurement in it. Default 1.
    pub appearance_hz: f64,
}

impl Default for MotionConfig {
    fn default() -> Self {
        MotionConfig {
            block_px: 16,
            diff_threshold: 15,
            gradient_threshold: 8,
            min_flow_px: 0.5,
            density_threshold: 0.02,
            illumination_fraction: 0.5,
            backend: MotionBackend::MotionFlow,
            appearance_hz: 1.0,
        }
    }
}

impl MotionConfig {
    /// Checks the `motion.*` keys.
    pub(super) fn validate(&self) -> Result<(), Invalid> {
        check_range("motion.block_px", self.block_px as f64, 4.0, 128.0)?;
        check_range(
            "motion.diff_threshold",
            self.diff_threshold as f64,
            1.0,
            255.0,
        )?;
        check_range(
            "motion.gradient_threshold",
            self.gradient_threshold as f64,
            0.0,
            1020.0,
        )?;
        check_range("motion.min_flow_px", self.min_flow_px as f64, 0.0, 1.99)?;
        check_range(
            "motion.density_threshold",
            self.density_threshold as f64,
            0.0,
            1.0,
        )?;
        check_range(
            "motion.illumination_fraction",
            self.illumination_fraction as f64,
            0.05,
            1.0,
        )?;
        check_range("motion.appearance_hz", self.appearance_hz, 0.0, 100.0)
    }
}
