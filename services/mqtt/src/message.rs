//! What the sink publishes: the topics, and the JSON of a zone event record or a
//! detections sample (the schema docs/operating.md documents). Pure: no I/O.

use isochron_config::clock::format_rfc3339;
use isochron_wire::{
    ActivityKind, Detection, DetectionHeader, EventHeader, EventPhase, KEYPOINT_NAMES,
};
use serde_json::{Value, json};

/// The topics of one site: `<prefix>/<site>/status` and, per camera,
/// `<prefix>/<site>/<camera>/events` and `.../detections`.
#[derive(Debug, Clone)]
pub struct Topics {
    base: String,
}

impl Topics {
    /// The topics under `<prefix>/<site>`.
    pub fn new(prefix: &str, site: &str) -> Self {
        Topics {
            base: format!("{prefix}/{site}"),
        }
    }

    /// The retained availability topic: "online" while the sink is connected,
    /// "offline" after it stopped or (its last will) vanished.
    pub fn status(&self) -> String {
        format!("{}/status", self.base)
    }

    /// `camera`'s zone events.
    pub fn events(&self, camera: &str) -> String {
        format!("{}/{camera}/events", self.base)
    }

    /// `camera`'s detections.
    pub fn detections(&self, camera: &str) -> String {
        format!("{}/{camera}/detections", self.base)
    }
}

/// The JSON of a zone event record (a start or an end) of `camera`, whose
/// payload lists the event's `blocks`.
pub fn event_json(camera: &str, h: &EventHeader, blocks: &[u32]) -> Value {
    let ended = h.phase == EventPhase::End as u32;
    let phase = if ended { "end" } else { "start" };
    let kind = ActivityKind::from_u32(h.kind).map_or("unknown", |k| k.name());
    json!({
        "camera": camera,
        "sequence": h.preamble.sequence,
        "event_id": h.event_id,
        "phase": phase,
        "zone": h.zone_name(),
        "kind": kind,
        "time": format_rfc3339(h.preamble.capture_time_ns),
        "start": format_rfc3339(h.start_ns),
        "end": ended.then(|| format_rfc3339(h.end_ns)),
        "duration_s": ended.then(|| (h.end_ns as f64 - h.start_ns as f64) / 1e9),
        "start_frame": h.start_frame,
        "end_frame": ended.then_some(h.end_frame),
        "peak": h.peak,
        "threshold": h.threshold,
        "blocks": blocks,
    })
}

/// Why the event record `h` cannot be a real zone event, if it cannot: it ends
/// before it starts (a negative duration), its last frame comes before its
/// first, it starts before 1970, or its activity is not a finite number. The
/// gate never makes such a record; a forged one is not published.
pub fn implausible_event(h: &EventHeader) -> Option<String> {
    if h.start_ns < 0 {
        return Some(format!("it starts before 1970 (start_ns {})", h.start_ns));
    }
    if !h.peak.is_finite() || !h.threshold.is_finite() {
        return Some(format!(
            "its activity is not finite (peak {}, threshold {})",
            h.peak, h.threshold
        ));
    }
    if h.phase == EventPhase::End as u32 {
        if h.end_ns < h.start_ns {
            return Some(format!(
                "it ends before it starts (duration {:.3} s)",
                (h.end_ns as f64 - h.start_ns as f64) / 1e9
            ));
        }
        if h.end_frame < h.start_frame {
            return Some(format!(
                "its last frame {} comes before its first {}",
                h.end_frame, h.start_frame
            ));
        }
    }
    None
}

/// The JSON of a detections sample of `camera`: the people the detector found
/// on one gated frame.
pub fn detections_json(camera: &str, h: &DetectionHeader, found: &[Detection]) -> Value {
    json!({
        "camera": camera,
        "sequence": h.preamble.sequence,
        "event_id": h.event_id,
        "frame": h.source_index,
        "time": format_rfc3339(h.preamble.capture_time_ns),
        "detector_ms": h.detector_us as f64 / 1e3,
        "searched": {"x_px": h.roi_x, "y_px": h.roi_y, "w_px": h.roi_w, "h_px": h.roi_h},
        "detections": found.iter().map(detection_json).collect::<Vec<_>>(),
    })
}

/// One detection: its box, score, class and model, and its keypoints where the
/// model gave them (MoveNet), each named as COCO names it.
fn detection_json(d: &Detection) -> Value {
    let mut out = json!({
        "x_px": d.x, "y_px": d.y, "w_px": d.w, "h_px": d.h, "score": d.score, "class": d.class,
        "model": d.model().name(),
    });
    if d.has_pose() {
        out["keypoints"] = KEYPOINT_NAMES
            .iter()
            .zip(&d.keypoints)
            .map(|(name, k)| json!({"name": name, "x_px": k.x, "y_px": k.y, "score": k.score}))
            .collect();
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use isochron_wire::{CameraId, Preamble, Stream, ZONE_NAME_LEN, to_fixed};

    #[test]
    fn topics() {
        let t = Topics::new("isochron", "depot");
        assert_eq!(t.status(), "isochron/depot/status");
        assert_eq!(t.events("cam01"), "isochron/depot/cam01/events");
        assert_eq!(t.detections("cam01"), "isochron/depot/cam01/detections");
    }

    #[test]
    fn an_end_record_has_its_end_and_duration() {
        let camera = CameraId::new("cam01").unwrap();
        let mut h = EventHeader {
            preamble: Preamble::new::<u32>(Stream::Events, camera, 7, 2),
            event_id: 3,
            zone: to_fixed::<ZONE_NAME_LEN>("door"),
            kind: ActivityKind::Moving as u32,
            phase: EventPhase::Start as u32,
            start_ns: 1_000_000_000,
            start_frame: 10,
            peak: 0.5,
            threshold: 0.25,
            ..Default::default()
        };
        let start = event_json("cam01", &h, &[4, 5]);
        assert_eq!(start["phase"], "start");
        assert_eq!(start["kind"], "moving");
        assert_eq!(start["sequence"], 7);
        assert!(start["end"].is_null() && start["duration_s"].is_null());
        h.phase = EventPhase::End as u32;
        h.end_ns = 3_500_000_000;
        h.end_frame = 35;
        let end = event_json("cam01", &h, &[4, 5]);
        assert_eq!(end["phase"], "end");
        assert_eq!(end["duration_s"], 2.5);
        assert_eq!(end["end"], "1970-01-01T00:00:03.500Z");
        assert_eq!(end["blocks"], json!([4, 5]));
    }

    #[test]
    fn an_event_that_ends_before_it_starts_is_implausible() {
        let mut h = EventHeader {
            phase: EventPhase::End as u32,
            start_ns: 5_000_000_000,
            end_ns: 7_000_000_000,
            start_frame: 10,
            end_frame: 30,
            peak: 0.5,
            threshold: 0.25,
            ..Default::default()
        };
        assert_eq!(implausible_event(&h), None);
        h.end_ns = 4_000_000_000;
        let why = implausible_event(&h).unwrap();
        assert!(
            why.contains("ends before it starts (duration -1.000 s)"),
            "{why}"
        );
        h.end_ns = i64::MIN;
        assert!(implausible_event(&h).is_some());
        h.end_ns = 7_000_000_000;
        h.end_frame = 3;
        assert!(implausible_event(&h).unwrap().contains("last frame 3"));
        h.end_frame = 30;
        h.peak = f32::NAN;
        assert!(implausible_event(&h).is_some());
        // A start record has no end yet.
        let start = EventHeader {
            phase: EventPhase::Start as u32,
            start_ns: 5_000_000_000,
            start_frame: 10,
            ..Default::default()
        };
        assert_eq!(implausible_event(&start), None);
        let before_1970 = EventHeader {
            start_ns: -1,
            ..start
        };
        assert!(implausible_event(&before_1970).is_some());
    }

    #[test]
    fn detections_carry_boxes_in_pixels() {
        let h = DetectionHeader {
            event_id: 3,
            source_index: 99,
            detector_us: 12_500,
            ..Default::default()
        };
        let d = Detection {
            x: 1.0,
            y: 2.0,
            w: 30.0,
            h: 60.0,
            score: 0.9,
            class: 0,
            ..Default::default()
        };
        let mut posed = Detection {
            model: isochron_wire::DetectorModel::MoveNet as u32,
            ..d
        };
        posed.keypoints[15] = isochron_wire::Keypoint {
            x: 5.0,
            y: 60.0,
            score: 0.75,
        };
        let v = detections_json("cam01", &h, &[d, posed]);
        assert_eq!(v["frame"], 99);
        assert_eq!(v["detector_ms"], 12.5);
        assert_eq!(v["detections"][0]["w_px"], 30.0);
        assert_eq!(v["detections"][0]["model"], "unknown");
        assert!(v["detections"][0].get("keypoints").is_none());
        let posed = &v["detections"][1];
        assert_eq!(posed["model"], "movenet");
        assert_eq!(posed["keypoints"].as_array().unwrap().len(), 17);
        assert_eq!(posed["keypoints"][15]["name"], "left_ankle");
        assert_eq!(posed["keypoints"][15]["score"], 0.75);
    }
}
