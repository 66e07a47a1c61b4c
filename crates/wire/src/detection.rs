//! The `detections` stream: the people the gated detector found in one frame.

use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};

use crate::{CameraId, MAX_DETECTIONS, MAX_FRAME_SIDE, Preamble, Stream, WireError};

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
