//! The messages between base stations: `isochron_msgs/msg/Activity`, `Event`,
//! `Detections` and `Status` (ros/isochron_msgs/msg). Each is the box that sent
//! it, the iceoryx2 header exactly as `shared/wire/src/lib.rs` lays it out, and the
//! payload: the wire types themselves derive serde, so this file adds no layout
//! of its own and the crossing loses nothing (sequence, capture and origin times
//! included). Serialised in field order they are the CDR every ROS 2 middleware
//! reads (`ros2 topic echo` with the package built).

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use isochron_config::{MAX_BOX_ID_LEN, is_ros_token};
use isochron_runtime::health::starting_status;
use isochron_runtime::ipc::{Activity, Detections, Events, StreamType};
use isochron_runtime::topology::StageKind;
use isochron_wire::geometry::BlockGrid;
use isochron_wire::{CameraId, MAX_BLOCKS, MAX_DETECTIONS, StageStatus, StreamHeader, WireError};

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
        Element: Serialize + DeserializeOwned + PartialEq + Default,
    > + 'static
{
    /// Topic `<namespace>/<camera>/<SUFFIX>`; also the stream's short name in
    /// the link's status detail.
    const SUFFIX: &'static str;
    /// `isochron_msgs/msg/<MSG>`.
    const MSG: &'static str;
    /// How it crosses.
    const DELIVERY: Delivery;

    /// Most payload elements a message of a camera of `blocks` blocks (if
    /// known) can carry.
    fn max_elements(blocks: Option<usize>) -> usize;

    /// The block grid a header describes (activity), to check against what
    /// the receiver knows of the camera.
    fn block_grid(_header: &Self::Header) -> Option<BlockGrid> {
        None
    }
}

impl LinkStream for Activity {
    const SUFFIX: &'static str = "activity";
    const MSG: &'static str = "Activity";
    const DELIVERY: Delivery = Delivery::Latest;
    fn max_elements(blocks: Option<usize>) -> usize {
        blocks.unwrap_or(MAX_BLOCKS)
    }
    fn block_grid(header: &Self::Header) -> Option<BlockGrid> {
        Some(header.block_grid())
    }
}

impl LinkStream for Events {
    const SUFFIX: &'static str = "events";
    const MSG: &'static str = "Event";
    const DELIVERY: Delivery = Delivery::Queued;
    fn max_elements(blocks: Option<usize>) -> usize {
        blocks.unwrap_or(MAX_BLOCKS)
    }
}

impl LinkStream for Detections {
    const SUFFIX: &'static str = "detections";
    const MSG: &'static str = "Detections";
    const DELIVERY: Delivery = Delivery::Queued;
    fn max_elements(_blocks: Option<usize>) -> usize {
        MAX_DETECTIONS
    }
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
    /// another camera, or whose sizes disagree, is an error, and so is a box id
    /// that no config accepts.
    pub fn validate(&self, camera: &CameraId) -> Result<(), WireError> {
        check_box_id(&self.box_id)?;
        self.header.validate(camera, self.payload.len())
    }

    /// Bytes of the CDR of the largest message of stream `S` of a camera of
    /// `blocks` blocks (if known): the largest sample its topic carries, which
    /// bounds what DDS reassembles for the reader.
    pub fn max_cdr_len(blocks: Option<usize>) -> usize {
        let header = cdr_len(&Message::<S> {
            box_id: "b".repeat(MAX_BOX_ID_LEN),
            header: S::Header::default(),
            payload: Vec::new(),
        });
        let element = cdr_len(&S::Element::default());
        // The CDR encapsulation header and alignment padding before the elements.
        4 + header + 8 + S::max_elements(blocks) * element
    }
}

/// Checks a received message's `box_id`: a `link.box_id` as the config accepts it.
pub fn check_box_id(box_id: &str) -> Result<(), WireError> {
    if box_id.len() > MAX_BOX_ID_LEN || !is_ros_token(box_id) {
        return Err(WireError::Field {
            field: "box_id",
            reason: format!(
                "{}: expected 1 to {MAX_BOX_ID_LEN} letters, digits and '_'",
                printable(box_id)
            ),
        });
    }
    Ok(())
}

/// A received name for a log line: at most 64 characters, escaped.
pub fn printable(name: &str) -> String {
    let head: String = name.chars().take(64).collect();
    if head.len() < name.len() {
        format!("{head:?}… ({} bytes)", name.len())
    } else {
        format!("{head:?}")
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

impl Status {
    /// Bytes of the CDR of the largest `Status` (the longest box id).
    pub fn max_cdr_len() -> usize {
        4 + cdr_len(&Status {
            box_id: "b".repeat(MAX_BOX_ID_LEN),
            status: starting_status(CameraId::default(), StageKind::Link),
        })
    }
}

/// Bytes of a message's serialised payload (little-endian CDR, without the
/// 4-byte encapsulation header and RTPS framing).
pub fn cdr_len<M: Serialize>(msg: &M) -> usize {
    cdr_encoding::to_vec::<_, byteorder::LittleEndian>(msg).map_or(0, |v| v.len())
}

#[cfg(test)]
mod tests {
    use super::*;
    use isochron_wire::{
        ActivityHeader, BlockActivity, Detection, DetectionHeader, DetectorModel, EventHeader,
        Preamble, Stream, to_fixed,
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
        person.model = DetectorModel::MoveNet as u32;
        person.keypoints[16].score = 0.5;
        let back = crossed::<Detections>(&det, &[person]);
        assert_eq!((back.header.roi_w, back.payload), (20, vec![person]));
        // Detection.msg: 5 float32, 2 uint32, then Keypoint[17] of 3 float32 each.
        assert_eq!(cdr_len(&person), 7 * 4 + 17 * 12);

        let mut status = StageStatus {
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
            ..starting_status(cam(), StageKind::Gate)
        };
        status.info[..5].copy_from_slice(b"a=1 b");
        status.counters[3] = 42.0;
        let back = round_trip(&Status {
            box_id: "box_a".into(),
            status,
        })
        .status;
        back.validate().unwrap();
        assert_eq!((back.info, back.counters), (status.info, status.counters));
        assert_eq!((back.dropped, back.e2e_latency_p99_ms), (5, 10.0));
    }

    #[test]
    fn a_message_of_a_forged_box_or_grid_is_refused() {
        let mut msg = activity();
        msg.box_id = "x".repeat(1 << 20);
        let err = msg.validate(&cam()).unwrap_err().to_string();
        assert!(err.contains("(1048576 bytes)") && err.len() < 300, "{err}");
        msg.box_id = "evil box".into();
        assert!(msg.validate(&cam()).is_err());
        // 0xFFFFFFFF² blocks with one block: refused, never multiplied out.
        let mut msg = activity();
        let h = &mut msg.header;
        (
            h.grid_w,
            h.grid_h,
            h.frame_width,
            h.frame_height,
            h.block_px,
        ) = (u32::MAX, u32::MAX, u32::MAX, u32::MAX, 1);
        h.preamble.payload_len = 1;
        msg.payload.truncate(1);
        assert!(msg.validate(&cam()).is_err());
    }

    #[test]
    fn the_largest_message_bounds_what_dds_reassembles() {
        let msg = activity();
        // A message of a 6-block camera fits the bound of a 6-block camera.
        assert!(cdr_len(&msg) + 4 <= Message::<Activity>::max_cdr_len(Some(6)));
        assert!(Message::<Activity>::max_cdr_len(Some(6)) < 512);
        assert!(
            Message::<Activity>::max_cdr_len(None)
                >= isochron_wire::MAX_BLOCKS * std::mem::size_of::<BlockActivity>()
        );
        assert!(Status::max_cdr_len() < 512);
    }

    mod properties {
        use super::*;
        use proptest::prelude::*;

        /// Decodes `bytes` as a message of `S` and checks it as the link does:
        /// never a panic, and what passes is consistent.
        fn decode<S: LinkStream>(bytes: &[u8]) -> Option<Message<S>> {
            let (msg, _) =
                cdr_encoding::from_bytes::<Message<S>, byteorder::LittleEndian>(bytes).ok()?;
            msg.validate(&cam()).ok()?;
            Some(msg)
        }

        proptest! {
            #![proptest_config(ProptestConfig::with_cases(1000))]

            /// Arbitrary bytes, and a real message's bytes with some of them
            /// changed (forged sizes, lengths, grids): decoding and validation
            /// never panic and never allocate for a length the bytes do not hold.
            #[test]
            fn forged_messages_decode_or_fail_cleanly(
                noise in proptest::collection::vec(any::<u8>(), 0..600),
                flips in proptest::collection::vec((any::<usize>(), any::<u8>()), 1..12),
            ) {
                prop_assert!(decode::<Activity>(&noise).is_none_or(|m| m.payload.len() <= 600));
                let _ = decode::<Events>(&noise);
                let _ = decode::<Detections>(&noise);
                let _ = cdr_encoding::from_bytes::<Status, byteorder::LittleEndian>(&noise);
                let mut bytes =
                    cdr_encoding::to_vec::<_, byteorder::LittleEndian>(&activity()).unwrap();
                for (at, value) in flips {
                    let k = at % bytes.len();
                    bytes[k] = value;
                }
                if let Some(m) = decode::<Activity>(&bytes)
                    .filter(|m| !m.header.preamble.is_end_of_stream())
                {
                    prop_assert_eq!(m.header.block_grid().len(), m.payload.len());
                    prop_assert!(m.payload.len() <= isochron_wire::MAX_BLOCKS);
                }
            }
        }
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
