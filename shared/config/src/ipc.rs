//! `[ipc]`: how streams use shared memory.

use serde::{Deserialize, Serialize};

use super::{Invalid, check_positive, check_range};

/// `[ipc]`: how streams use shared memory. Every process of a site must use the same
/// values (they are part of each iceoryx2 service's identity).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IpcConfig {
    /// Most subscribers per stream (consumers + taps). Default 5.
    pub max_subscribers: usize,
    /// Frames a `frames` subscriber may have queued. Default 3.
    pub frame_buffer: usize,
    /// Samples a subscriber of the small streams may have queued. Default 16.
    pub stream_buffer: usize,
    /// Lossless delivery: a publisher waits for slow subscribers instead of
    /// overwriting their oldest sample. Default `false` (live: never block a
    /// producer); `isochron replay --speed max` turns it on.
    pub lossless: bool,
    /// In lossless mode, how long a publisher waits for a stalled subscriber before
    /// it drops that subscriber's sample and logs it. Default 10.
    pub lossless_timeout_s: f64,
}

impl Default for IpcConfig {
    fn default() -> Self {
        IpcConfig {
            max_subscribers: 5,
            frame_buffer: 3,
            stream_buffer: 16,
            lossless: false,
            lossless_timeout_s: 10.0,
        }
    }
}

impl IpcConfig {
    /// Checks the `ipc.*` keys.
    pub(super) fn validate(&self) -> Result<(), Invalid> {
        check_range(
            "ipc.max_subscribers",
            self.max_subscribers as f64,
            1.0,
            64.0,
        )?;
        check_range("ipc.frame_buffer", self.frame_buffer as f64, 1.0, 64.0)?;
        check_range("ipc.stream_buffer", self.stream_buffer as f64, 1.0, 1024.0)?;
        check_positive("ipc.lossless_timeout_s", self.lossless_timeout_s)
    }
}
