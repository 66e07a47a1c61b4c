//! The messages between base stations: `isochron_msgs/msg/Activity`, `Event`,
//! `Detections` and `Status` (ros/isochron_msgs/msg). Each is the box that sent
//! it, the iceoryx2 header exactly as `shared/src/wire.rs` lays it out, and the
//! payload: the wire types themselves derive serde, so this file adds no layout
//! of its own and the crossing loses nothing (sequence, capture and origin times
//! included). Serialised in field order they are the CDR every ROS 2 middleware
//! reads (`ros2 topic echo` with the package built).

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use isochron_shared::ipc::{Activity, Detections, Events, StreamType};
use isochron_shared::wire::{CameraId, StageStatus, StreamHeader, WireError};

/// How a stream crosses: what DDS keeps and what the link's own queues keep.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Delivery {
    /// Best effort, keep last 1: only the newest sample is worth sending, a lost
    /// one is replaced by the next (activity, 1 Hz; status).
    Latest,
    /// Reliable, keep last `link.queue_messages`, with a bounded queue on each
    /// side that drops the oldest and counts it (events, detections: each
    /// record matters, but never at the cost of blocking a producer).
    Queued,
}

/// A stream that crosses between boxes: its topic suffix, ROS 2 message type
/// and delivery.
pub trait LinkStream:
    StreamType<
        Header: Serialize + DeserializeOwned,
        Element: Serialize + DeserializeOwned + PartialEq,
    > + 'static
{
    /// Topic `<namespace>/<camera>/<SUFFIX>`; also the stream's short name in
    /// the link's status detail.
    const SUFFIX: &'static str;
    /// `isochron_msgs/msg/<MSG>`.
    const MSG: &'static str;
    /// How it crosses.
    const DELIVERY: Delivery;
}

impl LinkStream for Activity {
    const SUFFIX: &'static str = "activity";
    const MSG: &'static str = "Activity";
    const DELIVERY: Delivery = Delivery::Latest;
}

impl LinkStream for Events {
    const SUFFIX: &'static str = "events";
    const MSG: &'static str = "Event";
    const DELIVERY: Delivery = Delivery::Queued;
}

impl LinkStream for Detections {
    const SUFFIX: &'static str = "detections";
    const MSG: &'static str = "Detections";
    const DELIVERY: Delivery = Delivery::Queued;
}

/// One sample of stream `S` as it crosses: `Activity`, `Event` or `Detections`.
#[derive(Serialize, Deserialize)]
#[serde(bound = "")]
pub struct Message<S: LinkStream> {
    /// The base station that sent it.
    pub box_id: String,
    /// The iceoryx2 header, as the exporting box's stage wrote it.
    pub header: S::Header,
    /// The payload: blocks, block indices or detections.
    pub payload: Vec<S::Element>,
}

impl<S: LinkStream> Clone for Message<S> {
    fn clone(&self) -> Self {
        Message {
            box_id: self.box_id.clone(),
            header: self.header,
            payload: self.payload.clone(),
        }
    }
}

impl<S: LinkStream> Message<S> {
    /// The message of a (valid) sample sent by box `box_id`.
    pub fn from_sample(box_id: &str, header: &S::Header, payload: &[S::Element]) -> Self {
        Message {
            box_id: box_id.to_string(),
            header: *header,
            payload: payload.to_vec(),
        }
    }

    /// Checks the message as any received sample is checked: a message of
    /// another camera, or whose sizes disagree, is an error.
    pub fn validate(&self, camera: &CameraId) -> Result<(), WireError> {
        self.header.validate(camera, self.payload.len())
    }
}

/// `isochron_msgs/msg/Status`: one stage's latest [`StageStatus`] of an
/// exported camera.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Status {
    /// The base station that sent it.
    pub box_id: String,
    /// The stage's status as it published it on the exporting box.
    pub status: StageStatus,
}

/// Bytes of a message's serialised payload (little-endian CDR, without the
/// 4-byte encapsulation header and RTPS framing).
pub fn cdr_len<M: Serialize>(msg: &M) -> usize {
    cdr_encoding::to_vec::<_, byteorder::LittleEndian>(msg).map_or(0, |v| v.len())
}

#[cfg(test)]
mod tests {
    use super::*;
    use isochron_shared::wire::{
        ActivityHeader, BlockActivity, Detection, DetectionHeader, EventHeader, Preamble, Stream,
        to_fixed,
    };

    fn cam() -> CameraId {
        CameraId::new("cam01").unwrap()
    }

    fn round_trip<M: Serialize + DeserializeOwned>(msg: &M) -> M {
        let bytes = cdr_encoding::to_vec::<_, byteorder::LittleEndian>(msg).unwrap();
        assert_eq!(cdr_len(msg), bytes.len());
        cdr_encoding::from_bytes::<M, byteorder::LittleEndian>(&bytes)
            .unwrap()
            .0
    }

    /// A sample of stream `S` of box_a after the crossing, checked as received.
    fn crossed<S: LinkStream>(header: &S::Header, payload: &[S::Element]) -> Message<S> {
        let back = round_trip(&Message::<S>::from_sample("box_a", header, payload));
        back.validate(&cam()).unwrap();
        back
    }

    fn activity() -> Message<Activity> {
        let mut p = Preamble::new::<BlockActivity>(Stream::Activity, cam(), 41, 6);
        p.capture_time_ns = 1_700_000_000_123_456_789;
        p.origin_wall_ns = 1_700_000_000_200_000_000;
        let h = ActivityHeader {
            preamble: p,
            grid_w: 3,
            grid_h: 2,
            block_px: 16,
            frame_width: 48,
            frame_height: 32,
            t_star: 660,
            model_days: 3,
            frames: 10,
            first_source_index: 100,
            last_source_index: 109,
            frame_rate: 10.0,
            reserved: 0,
        };
        let blocks: Vec<BlockActivity> = (0..6)
            .map(|k| BlockActivity {
                s1: k as f32,
                s2: 0.5,
                lt_sigma: 0.25,
                ..Default::default()
            })
            .collect();
        Message::from_sample("box_a", &h, &blocks)
    }

    #[test]
    fn activity_crosses_unchanged() {
        let msg = activity();
        let back = round_trip(&msg);
        back.validate(&cam()).unwrap();
        assert_eq!(back.payload, msg.payload);
        let (p, q) = (&back.header.preamble, &msg.header.preamble);
        assert_eq!(p.sequence, 41);
        assert_eq!(p.capture_time_ns, q.capture_time_ns);
        assert_eq!(p.origin_wall_ns, q.origin_wall_ns);
        assert_eq!(
            (back.header.t_star, back.header.last_source_index),
            (660, 109)
        );
        // The CDR of the `.msg` files: "box_a" (4 + 6 B, padded to 12), the
        // preamble (76 B: a 24-byte camera, aligned 64-bit fields), the activity
        // fields (56 B), the blocks' count and 6 blocks of 36 B.
        assert_eq!(cdr_len(&msg), 12 + 76 + 56 + 4 + 6 * 36);
    }

    #[test]
    fn events_detections_and_status_cross_unchanged() {
        let mut p = Preamble::new::<u32>(Stream::Events, cam(), 7, 2);
        p.capture_time_ns = 5;
        let ev = EventHeader {
            preamble: p,
            event_id: 3,
            zone: to_fixed("door"),
            kind: 1,
            phase: 2,
            start_ns: 1,
            end_ns: 5,
            start_frame: 10,
            end_frame: 50,
            peak: 2.5,
            threshold: 1.0,
        };
        let back = crossed::<Events>(&ev, &[4, 9]);
        assert_eq!(back.header.zone_name(), "door");
        assert_eq!(
            (back.header.preamble.sequence, back.payload),
            (7, vec![4, 9])
        );

        let p = Preamble::new::<Detection>(Stream::Detections, cam(), 9, 1);
        let det = DetectionHeader {
            preamble: p,
            event_id: 3,
            roi_w: 20,
            ..Default::default()
        };
        let mut person = Detection::default();
        (person.x, person.w, person.score) = (1.0, 4.0, 0.9);
        let back = crossed::<Detections>(&det, &[person]);
        assert_eq!((back.header.roi_w, back.payload), (20, vec![person]));

        let mut status = StageStatus {
            magic: isochron_shared::wire::MAGIC,
            layout_version: isochron_shared::wire::LAYOUT_VERSION,
            reserved: 0,
            camera: cam(),
            stage: to_fixed("gate"),
            pid: 12,
            rate_in: 1.0,
            started_wall_ns: 1,
            report_wall_ns: 2,
            received: 3,
            sent: 4,
            dropped: 5,
            rejected: 6,
            rate_out: 7.0,
            stage_latency_ms: 8.0,
            e2e_latency_p50_ms: 9.0,
            e2e_latency_p99_ms: 10.0,
            detail: [0; isochron_shared::wire::STATUS_DETAIL_LEN],
        };
        status.detail[..5].copy_from_slice(b"a=1 b");
        let back = round_trip(&Status {
            box_id: "box_a".into(),
            status,
        })
        .status;
        back.validate().unwrap();
        assert_eq!(back.detail, status.detail);
        assert_eq!((back.dropped, back.e2e_latency_p99_ms), (5, 10.0));
    }

    #[test]
    fn a_message_of_another_camera_or_size_is_refused() {
        let msg = activity();
        assert!(msg.validate(&CameraId::new("cam02").unwrap()).is_err());
        let mut short = msg.clone();
        short.payload.pop();
        assert!(short.validate(&cam()).is_err());
    }
}
