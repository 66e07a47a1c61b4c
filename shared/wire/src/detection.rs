//! The `detections` stream: the people the gated detector found in one frame.

use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};

use crate::{CameraId, MAX_DETECTIONS, MAX_FRAME_SIDE, Preamble, Stream, WireError};

/// Keypoints per person in [`Detection::keypoints`]: COCO's 17, in
/// [`KEYPOINT_NAMES`] order.
pub const KEYPOINTS: usize = 17;

/// The names of COCO's 17 keypoints, in [`Detection::keypoints`] order.
pub const KEYPOINT_NAMES: [&str; KEYPOINTS] = [
    "nose",
    "left_eye",
    "right_eye",
    "left_ear",
    "right_ear",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
];

/// COCO's skeleton: the pairs of [`Detection::keypoints`] drawn as bones (face,
/// arms, torso, legs).
pub const SKELETON: [(usize, usize); 16] = [
    (0, 1),
    (0, 2),
    (1, 3),
    (2, 4),
    (5, 6),
    (5, 7),
    (7, 9),
    (6, 8),
    (8, 10),
    (5, 11),
    (6, 12),
    (11, 12),
    (11, 13),
    (13, 15),
    (12, 14),
    (14, 16),
];

/// Lowest keypoint score drawn as seen (the threshold MoveNet's own demos use).
pub const KEYPOINT_MIN_SCORE: f32 = 0.3;

/// One body keypoint in frame pixels; score 0: not given.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize, Deserialize)]
#[type_name("isochron::Keypoint")]
#[repr(C)]
pub struct Keypoint {
    /// Column, frame pixels.
    pub x: f32,
    /// Row, frame pixels.
    pub y: f32,
    /// The model's confidence, 0..1 (0: the model gives no such point).
    pub score: f32,
}

/// Which detector found a [`Detection`] (its `model` field).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum DetectorModel {
    /// A value this build does not know.
    Unknown = 0,
    /// OpenCV's HOG people detector.
    Hog = 1,
    /// A TensorFlow SSD (SSDLite-MobileNetV2 for people, as installed).
    Ssd = 2,
    /// MoveNet MultiPose (boxes and keypoints).
    MoveNet = 3,
    /// A YOLO ONNX model through OpenCV's dnn.
    Onnx = 4,
}

impl DetectorModel {
    /// The model a wire value names ([`DetectorModel::Unknown`] for others).
    pub fn from_wire(value: u32) -> Self {
        match value {
            1 => DetectorModel::Hog,
            2 => DetectorModel::Ssd,
            3 => DetectorModel::MoveNet,
            4 => DetectorModel::Onnx,
            _ => DetectorModel::Unknown,
        }
    }

    /// Its short name, as logs, status, MQTT and markers print it.
    pub fn name(self) -> &'static str {
        match self {
            DetectorModel::Unknown => "unknown",
            DetectorModel::Hog => "hog",
            DetectorModel::Ssd => "ssd",
            DetectorModel::MoveNet => "movenet",
            DetectorModel::Onnx => "onnx",
        }
    }
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
    /// The detector that found it: a [`DetectorModel`] as `u32` (read it with
    /// [`Detection::model`]).
    pub model: u32,
    /// The person's body keypoints where the model gives them (MoveNet), all
    /// scores 0 otherwise.
    pub keypoints: [Keypoint; KEYPOINTS],
}

impl Detection {
    /// The detector that found it.
    pub fn model(&self) -> DetectorModel {
        DetectorModel::from_wire(self.model)
    }

    /// True if the model gave keypoints (any score above 0).
    pub fn has_pose(&self) -> bool {
        self.keypoints.iter().any(|k| k.score > 0.0)
    }

    /// The bones of [`SKELETON`] whose two keypoints both score at least
    /// [`KEYPOINT_MIN_SCORE`] (and lie at finite coordinates).
    pub fn bones(&self) -> impl Iterator<Item = (Keypoint, Keypoint)> + '_ {
        let seen =
            |k: &Keypoint| k.score >= KEYPOINT_MIN_SCORE && k.x.is_finite() && k.y.is_finite();
        SKELETON
            .iter()
            .map(|&(a, b)| (self.keypoints[a], self.keypoints[b]))
            .filter(move |(a, b)| seen(a) && seen(b))
    }
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
