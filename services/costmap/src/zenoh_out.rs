//! The bridge's topics and planning services on Zenoh, in rmw_zenoh's format
//! (`[costmap.zenoh]`, off by default), beside DDS: a robot whose ROS 2
//! middleware is rmw_zenoh sees the same seven topics, with the same QoS, and
//! calls the same two services.
//!
//! Samples are the DDS samples' CDR ([`isochron_ros2::msgs`]); each type is named by its
//! DDS name and its type description hash (RIHS01, from the type's `.msg`
//! definitions: the same in Jazzy and Kilted, checked against the rclpy wheels'
//! type descriptions by `tests/it/zenoh.rs`). Requests are queued per client
//! (the GID in the request's attachment) and answered round robin, as the DDS
//! services are ([`isochron_ros2::fair`]).

use std::collections::HashMap;

use byteorder::LittleEndian;
use rustdds::serialization::to_vec;
use serde::Serialize;

use isochron_planning::query::{PlanKind, PlanRequest, PlanResponse};
use isochron_runtime::stage::Context;
use isochron_zenoh::names::{GID_LEN, Qos, RosType};
use isochron_zenoh::{Request, RosPublisher, RosService, RosZenoh, Settings, ZenohError};

use isochron_ros2::fair::{FairQueue, Pushed};
use crate::plan_dds::{
    ANSWERS_PER_PASS, CLIENT_ANSWERS_PER_PASS, PER_CLIENT, PlanCounts, QUEUE, now_response,
    offline_response, plan_request, respond,
};

/// The types the bridge sends and serves, as rmw_zenoh names them.
pub mod types {
    use super::RosType;

    /// `nav_msgs/msg/OccupancyGrid`.
    pub const OCCUPANCY_GRID: RosType = RosType {
        dds_name: "nav_msgs::msg::dds_::OccupancyGrid_",
        hash: "RIHS01_8d348150c12913a31ee0ec170fbf25089e4745d17035792a1ba94d6f0bc0cfc7",
    };
    /// `map_msgs/msg/OccupancyGridUpdate`.
    pub const OCCUPANCY_GRID_UPDATE: RosType = RosType {
        dds_name: "map_msgs::msg::dds_::OccupancyGridUpdate_",
        hash: "RIHS01_c4095b0be2e4363f8978a1570e0293ee093436f1e1c61d99b48502ac317025e8",
    };
    /// `geometry_msgs/msg/PoseArray`.
    pub const POSE_ARRAY: RosType = RosType {
        dds_name: "geometry_msgs::msg::dds_::PoseArray_",
        hash: "RIHS01_af0cc36d190e104d546d168d6b39df04fa4b4ccecf59cb4c9ed328d3d5004aa0",
    };
    /// `visualization_msgs/msg/MarkerArray`.
    pub const MARKER_ARRAY: RosType = RosType {
        dds_name: "visualization_msgs::msg::dds_::MarkerArray_",
        hash: "RIHS01_86cb8800b6fb05b5eff1abd7a56f62a5641d3ae9a1c29e78e67e704f1d067dcf",
    };
    /// `nav2_msgs/msg/CostmapFilterInfo`.
    pub const COSTMAP_FILTER_INFO: RosType = RosType {
        dds_name: "nav2_msgs::msg::dds_::CostmapFilterInfo_",
        hash: "RIHS01_61ce391bf7690f76a331c01c9d5ce8ca71e6c99273b9fb75e48380f05c6dfdc8",
    };
    /// `isochron_msgs/srv/PlanNow`.
    pub const PLAN_NOW: RosType = RosType {
        dds_name: "isochron_msgs::srv::dds_::PlanNow_",
        hash: "RIHS01_dff9c18dbd331fcfcc5d0425b6b3c55111f50283aa00584e7731f029156e68fc",
    };
    /// `isochron_msgs/srv/PlanOffline`.
    pub const PLAN_OFFLINE: RosType = RosType {
        dds_name: "isochron_msgs::srv::dds_::PlanOffline_",
        hash: "RIHS01_842684142b8532e0527d5fa42b630f3dc55e6d5740de27bf6655d97b6d9538a1",
    };
}

/// Requests a service's Zenoh queryable holds between two passes of the loop.
const INBOX: usize = 256;

/// Latched: reliable, transient-local, keep last 1 (the grid, markers, speed
/// filter and forecast, as on DDS).
const LATCHED: Qos = Qos {
    reliable: true,
    transient_local: true,
    depth: 1,
};
/// A stream: reliable, volatile, keep last 10 (updates, people and their
/// markers, as on DDS).
const STREAM: Qos = Qos {
    reliable: true,
    transient_local: false,
    depth: 10,
};

/// The names the bridge's node publishes and serves (those of its DDS output).
#[derive(Debug, Clone, Copy)]
pub struct Names<'a> {
    /// The grid topic.
    pub grid: &'a str,
    /// The updates topic.
    pub updates: &'a str,
    /// The people topic.
    pub people: &'a str,
    /// The markers topic.
    pub markers: &'a str,
    /// The people markers topic.
    pub people_markers: &'a str,
    /// The speed filter info topic.
    pub speed_filter_info: &'a str,
    /// The speed mask topic.
    pub speed_mask: &'a str,
    /// The forecast topic.
    pub forecast: &'a str,
    /// The off-line planning service.
    pub plan_offline: &'a str,
    /// The real-time planning service.
    pub plan_now: &'a str,
}

/// One planning service on Zenoh and its queue.
struct Service {
    kind: PlanKind,
    name: String,
    service: RosService,
    queue: FairQueue<[u8; GID_LEN], Request>,
    /// Requests the queryable had dropped when last looked at.
    inbox_dropped: u64,
}

/// The bridge's node on Zenoh.
pub struct ZenohOutput {
    pub(crate) grid: RosPublisher,
    pub(crate) updates: RosPublisher,
    pub(crate) people: RosPublisher,
    pub(crate) markers: RosPublisher,
    pub(crate) people_markers: RosPublisher,
    pub(crate) filter_info: RosPublisher,
    pub(crate) mask: RosPublisher,
    pub(crate) forecast: RosPublisher,
    services: [Service; 2],
    _node: RosZenoh,
}

impl ZenohOutput {
    /// Opens the session of `zenoh` and declares the node `/isochron/<node>` with
    /// the publishers and services of `names`.
    pub fn start(zenoh: &Settings, names: &Names, node: &str) -> Result<Self, ZenohError> {
        let z = RosZenoh::open(zenoh, "/isochron", node)?;
        use types::*;
        let service = |name: &str, ty: &RosType, kind| -> Result<Service, ZenohError> {
            Ok(Service {
                kind,
                name: name.to_string(),
                service: z.service(name, ty, INBOX)?,
                queue: FairQueue::new(PER_CLIENT, QUEUE),
                inbox_dropped: 0,
            })
        };
        let services = [
            service(names.plan_offline, &PLAN_OFFLINE, PlanKind::Offline)?,
            service(names.plan_now, &PLAN_NOW, PlanKind::Now)?,
        ];
        Ok(ZenohOutput {
            grid: z.publisher(names.grid, &OCCUPANCY_GRID, LATCHED)?,
            updates: z.publisher(names.updates, &OCCUPANCY_GRID_UPDATE, STREAM)?,
            people: z.publisher(names.people, &POSE_ARRAY, STREAM)?,
            markers: z.publisher(names.markers, &MARKER_ARRAY, LATCHED)?,
            people_markers: z.publisher(names.people_markers, &MARKER_ARRAY, STREAM)?,
            filter_info: z.publisher(names.speed_filter_info, &COSTMAP_FILTER_INFO, LATCHED)?,
            mask: z.publisher(names.speed_mask, &OCCUPANCY_GRID, LATCHED)?,
            forecast: z.publisher(names.forecast, &OCCUPANCY_GRID, LATCHED)?,
            services,
            _node: z,
        })
    }

    /// Answers the due requests of both services with `answer`; returns how many.
    /// Malformed requests get `STATUS_BAD_REQUEST` and are counted rejected;
    /// requests beyond their client's share, or beyond the queryable's inbox, are
    /// dropped and counted. Never blocks.
    pub fn serve(
        &mut self,
        cx: &mut Context,
        counts: &mut PlanCounts,
        answer: &mut impl FnMut(PlanKind, &PlanRequest) -> PlanResponse,
    ) -> usize {
        self.services
            .iter_mut()
            .map(|s| {
                s.intake(cx, counts);
                s.answer(cx, counts, answer)
            })
            .sum()
    }
}

/// Publishes `message` on `publisher`; what went wrong if it failed.
pub(crate) fn put<T: Serialize>(publisher: &RosPublisher, message: &T) -> Result<(), String> {
    let cdr = to_vec::<T, LittleEndian>(message).map_err(|e| format!("Zenoh: encoding: {e}"))?;
    publisher.put(&cdr).map_err(|e| e.to_string())
}

impl Service {
    /// Moves what the queryable received into the per-client queue.
    fn intake(&mut self, cx: &mut Context, counts: &mut PlanCounts) {
        let inbox_dropped = self.service.dropped();
        if inbox_dropped > self.inbox_dropped {
            let n = inbox_dropped - self.inbox_dropped;
            self.inbox_dropped = inbox_dropped;
            self.dropped(cx, counts, n, "the Zenoh inbox was full");
        }
        while let Some(request) = self.service.take() {
            let Some(attachment) = request.attachment else {
                // rmw_zenoh's clients always attach one: without it a reply
                // could not be matched to its request.
                counts.rejected += 1;
                cx.health.rejected();
                let name = &self.name;
                cx.warnings.warn("zenoh plan request unanswerable", || {
                    format!("{name} (Zenoh): a request without rmw_zenoh's attachment")
                });
                continue;
            };
            match self.queue.push(attachment.gid, request) {
                Pushed::Queued => {}
                Pushed::ClientFull => self.dropped(cx, counts, 1, "its client's queue is full"),
                Pushed::Full => self.dropped(cx, counts, 1, "the queue is full"),
                Pushed::Displaced { .. } => {
                    self.dropped(cx, counts, 1, "displaced by another client's");
                }
            }
        }
    }

    fn dropped(&self, cx: &mut Context, counts: &mut PlanCounts, n: u64, why: &str) {
        counts.dropped += n;
        cx.health.dropped(n);
        let name = &self.name;
        cx.warnings.warn("zenoh plan request dropped", || {
            format!(
                "{name} (Zenoh): {n} request(s) dropped, {why} ({PER_CLIENT} per client, {QUEUE} in all, round robin; {} dropped in all so far)",
                counts.dropped
            )
        });
    }

    /// Answers what is due, round robin, at most [`ANSWERS_PER_PASS`] and
    /// [`CLIENT_ANSWERS_PER_PASS`] of one client.
    fn answer(
        &mut self,
        cx: &mut Context,
        counts: &mut PlanCounts,
        answer: &mut impl FnMut(PlanKind, &PlanRequest) -> PlanResponse,
    ) -> usize {
        let mut this_pass: HashMap<[u8; GID_LEN], usize> = HashMap::new();
        let mut ready = |client: &[u8; GID_LEN], _: &Request| {
            let n = this_pass.entry(*client).or_default();
            *n += 1;
            *n <= CLIENT_ANSWERS_PER_PASS
        };
        let mut answered = 0;
        while answered < ANSWERS_PER_PASS
            && let Some((_, request)) = self.queue.next(&mut ready)
        {
            let read = read(self.kind, &request.payload());
            let name = format!("{} (Zenoh)", self.name);
            let response = respond(
                (self.kind, &name),
                read.as_ref().map_err(String::as_str),
                (cx, counts),
                answer,
            );
            let cdr = match self.kind {
                PlanKind::Now => to_vec::<_, LittleEndian>(&now_response(&response)),
                _ => to_vec::<_, LittleEndian>(&offline_response(&response)),
            };
            let sent = cdr
                .map_err(|e| e.to_string())
                .and_then(|cdr| self.service.reply(request, &cdr).map_err(|e| e.to_string()));
            if let Err(e) = sent {
                let name = &self.name;
                cx.warnings.warn("zenoh plan reply failed", || {
                    format!("{name} (Zenoh): a reply could not be sent: {e}")
                });
            }
            counts.answered += 1;
            answered += 1;
        }
        answered
    }
}

/// The planning request in `payload`: the encapsulation header, then the fields in
/// plain CDR of its byte order.
fn read(kind: PlanKind, payload: &[u8]) -> Result<PlanRequest, String> {
    let Some((header, body)) = payload.split_first_chunk::<4>() else {
        return Err(format!(
            "a request of {} bytes: shorter than its encapsulation header",
            payload.len()
        ));
    };
    match header[..2] {
        [0x00, 0x01] => plan_request(kind, body, false),
        [0x00, 0x00] => plan_request(kind, body, true),
        _ => Err(format!(
            "a request encoded as {:02x}{:02x}: expected plain CDR (XCDR1), as rmw_zenoh sends",
            header[0], header[1]
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requests_need_their_encapsulation_header() {
        assert!(
            read(PlanKind::Now, &[0, 1])
                .unwrap_err()
                .contains("shorter")
        );
        let err = read(PlanKind::Now, &[0, 7, 0, 0, 1, 2, 3, 4]).unwrap_err();
        assert!(err.contains("expected plain CDR"), "{err}");
    }
}
