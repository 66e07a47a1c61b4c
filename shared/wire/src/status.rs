//! The `status` service of every stage: its periodic health.

use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};

use crate::fixed::fixed_bytes;
use crate::{CameraId, WireError, check_layout};

/// Longest stage name in a [`StageStatus`].
pub const STAGE_NAME_LEN: usize = 16;
/// Counter slots of a [`StageStatus`]: at most this many counters per stage
/// (their schema is the stage's row of the runtime's stage table).
pub const STATUS_COUNTERS: usize = 24;
/// Length of the free-text identity of a [`StageStatus`] (detector, broker).
pub const STATUS_INFO_LEN: usize = 96;

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
    /// Fingerprint of the stage's counter schema: a reader whose schema of this
    /// stage differs (another build) does not read the slots as its own.
    pub schema: u32,
    /// Counter slots in use.
    pub counter_count: u32,
    /// The stage's counters, in its schema's order (integers exact to 2⁵³).
    pub counters: [f64; STATUS_COUNTERS],
    /// What the stage is and talks to, as text (`detector=hog`, `broker=…`),
    /// zero-padded; never parsed.
    #[serde(with = "fixed_bytes")]
    pub info: [u8; STATUS_INFO_LEN],
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
