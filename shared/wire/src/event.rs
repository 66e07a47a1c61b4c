//! The `events` stream: the start and end of activity in a zone.

use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};

use crate::fixed::fixed_str;
use crate::{CameraId, MAX_BLOCKS, Preamble, Stream, WireError, u32_enum};

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
