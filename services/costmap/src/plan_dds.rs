//! The planning services over ROS 2: `isochron_msgs/srv/PlanOffline` and `PlanNow`
//! (ros/isochron_msgs) on the topics ROS 2 gives a service `/s`, `rq/sRequest` and
//! `rr/sReply`, answered with what answers `<prefix>/plan` over iceoryx2.
//!
//! ROS 2 middlewares carry a request's identity in two ways on the same topics, and
//! both are served:
//!
//! * **rmw_cyclonedds**: a 16-byte header before the request's fields, the client's
//!   id (8 bytes) and sequence number (8 bytes), echoed before the reply's fields;
//! * **rmw_fastrtps** (the default RMW of Humble and Jazzy): the bare request,
//!   written with a *related sample identity* (inline QoS, PID 0x800f or 0x0083)
//!   naming the client's reply reader; the reply carries the related sample
//!   identity (that reader, the request's RTPS sequence number) and no header
//!   (rmw_fastrtps_shared_cpp `rmw_request.cpp`, `rmw_response.cpp`).
//!
//! A request with a related sample identity is in the Fast DDS layout, one without
//! in Cyclone's. A reply waits (at most [`REPLY_WAIT`]) until the client's reply
//! reader is matched with the reply writer, as rmw_fastrtps's server does: a
//! client that sends at once after discovery would otherwise miss it.
//!
//! Requests are decoded by the CDR rules ([`crate::msgs::CdrString`]): a string's
//! length counts its NUL, and a string without one is malformed (not cut short).
//! A malformed
//! request gets `STATUS_BAD_REQUEST` (1) with the reason and is counted as
//! rejected; one that cannot be answered (no identity) is counted only. Each
//! service queues at most [`QUEUE`] requests and answers at most
//! [`ANSWERS_PER_PASS`] per pass of the bridge's loop: a flood beyond that is
//! dropped and counted, as are the requests DDS overwrote in the reader's history
//! before the bridge took them (gaps in each client's sequence numbers).

use std::collections::{HashMap, HashSet, VecDeque};
use std::time::{Duration, Instant};

use byteorder::{BigEndian, LittleEndian};
use ros2_client::dds::DEFAULT_PUBLISHER_QOS;
use ros2_client::{Name, NodeName};
use rustdds::bytes::Bytes;
use rustdds::no_key::{
    DataWriter, Decode, DefaultDecoder, DeserializerAdapter, SerializerAdapter, SimpleDataReader,
};
use rustdds::serialization::{from_bytes, to_vec};
use rustdds::{
    DataWriterStatus, DomainParticipant, GUID, QosPolicies, RepresentationIdentifier,
    SampleIdentity, SequenceNumber, StatusEvented, Timestamp, TopicKind, WriteOptionsBuilder,
    policy,
};
use serde::Serialize;
use serde::de::DeserializeOwned;

use isochron_dds::keep_last;
use isochron_planning::plan_service::{offline_plan_of, ranking_of};
use isochron_planning::query::{
    PLAN_FLAG_INFINITE, PLAN_MAX_ROUTES, PLAN_NAME_LEN, PlanKind, PlanRequest, PlanResponse,
    PlanStatus,
};
use isochron_runtime::stage::Context;

use crate::msgs::{
    CostPoint, PlanNowRequest, PlanNowResponse, PlanOfflineRequest, PlanOfflineResponse, RouteCost,
    Window as WindowMsg,
};

/// Requests DDS keeps for a service between two passes of the bridge's loop (at
/// least 4 a second): a flood of 1 000 requests a second fits.
const REQUEST_HISTORY: i32 = 256;
/// Requests a service holds for an answer; more are dropped and counted.
pub const QUEUE: usize = 64;
/// Requests a service answers per pass of the loop.
pub const ANSWERS_PER_PASS: usize = 16;
/// Replies the reply writer keeps until their clients acknowledge them.
const REPLY_HISTORY: i32 = 256;
/// Longest a reply waits for its client's reply reader to be matched.
pub const REPLY_WAIT: Duration = Duration::from_secs(2);
/// Largest request body decoded: a `PlanNow` of 16 names of 32 bytes is < 700.
const MAX_REQUEST_BYTES: usize = 4096;
/// Clients whose sequence numbers are followed; more start the table afresh.
const MAX_CLIENTS: usize = 1024;
/// How long `write` waits for room in a reliable send window.
const MAX_BLOCKING: Duration = Duration::from_millis(50);
/// rmw_cyclonedds's request header: client id and sequence number, 8 bytes each.
const CYCLONE_HEADER: usize = 16;

/// A sample's bytes as they came off the wire (after the 4-byte encapsulation
/// header) and how they are encoded.
#[derive(Debug, Clone)]
pub struct RawSample {
    bytes: Vec<u8>,
    encoding: RepresentationIdentifier,
}

/// Passes sample bytes through: the services decode them themselves.
pub struct Raw;

/// The decoder of [`Raw`].
#[derive(Clone)]
pub struct RawDecoder;

/// Never happens: raw bytes always decode.
#[derive(Debug, thiserror::Error)]
#[error("raw bytes")]
pub struct RawError;

impl DeserializerAdapter<RawSample> for Raw {
    type Error = RawError;
    type Decoded = RawSample;

    /// Plain CDR is decoded; the rest is taken in to be answered with a reason.
    fn supported_encodings() -> &'static [RepresentationIdentifier] {
        &[
            RepresentationIdentifier::CDR_LE,
            RepresentationIdentifier::CDR_BE,
            RepresentationIdentifier::CDR2_LE,
            RepresentationIdentifier::CDR2_BE,
            RepresentationIdentifier::D_CDR2_LE,
            RepresentationIdentifier::D_CDR2_BE,
            RepresentationIdentifier::PL_CDR_LE,
            RepresentationIdentifier::PL_CDR_BE,
        ]
    }

    fn transform_decoded(decoded: RawSample) -> RawSample {
        decoded
    }
}

impl DefaultDecoder<RawSample> for Raw {
    type Decoder = RawDecoder;
    const DECODER: RawDecoder = RawDecoder;
}

impl<'de> Decode<'de, RawSample> for RawDecoder {
    type Error = RawError;

    fn decode_bytes(
        self,
        input_bytes: &'de [u8],
        encoding: RepresentationIdentifier,
    ) -> Result<RawSample, RawError> {
        Ok(RawSample {
            bytes: input_bytes.to_vec(),
            encoding,
        })
    }
}

/// A reply's bytes, little-endian CDR.
pub struct RawReply(Vec<u8>);

impl SerializerAdapter<RawReply> for Raw {
    type Error = RawError;

    fn output_encoding() -> RepresentationIdentifier {
        RepresentationIdentifier::CDR_LE
    }

    fn to_bytes(value: &RawReply) -> Result<Bytes, RawError> {
        Ok(Bytes::copy_from_slice(&value.0))
    }
}

/// Decodes `body` (CDR, big- or little-endian) as a `T`.
fn cdr<T: DeserializeOwned>(body: &[u8], big_endian: bool) -> Result<T, String> {
    let decoded = if big_endian {
        from_bytes::<T, BigEndian>(body)
    } else {
        from_bytes::<T, LittleEndian>(body)
    };
    decoded.map(|(t, _)| t).map_err(|e| e.to_string())
}

/// The iceoryx2 request of a request body of `kind`, validated like one.
fn plan_request(kind: PlanKind, body: &[u8], big_endian: bool) -> Result<PlanRequest, String> {
    if body.len() > MAX_REQUEST_BYTES {
        return Err(format!(
            "a request of {} bytes; at most {MAX_REQUEST_BYTES} are read",
            body.len()
        ));
    }
    let request = match kind {
        PlanKind::Now => {
            let wire: PlanNowRequest = cdr(body, big_endian)?;
            if wire.routes.is_empty() || wire.routes.len() > PLAN_MAX_ROUTES {
                return Err(format!(
                    "expected 1 to {PLAN_MAX_ROUTES} routes, found {}",
                    wire.routes.len()
                ));
            }
            for name in &wire.routes {
                check_route_name(&name.0)?;
            }
            let names: Vec<&str> = wire.routes.iter().map(|r| r.0.as_str()).collect();
            PlanRequest::new(PlanKind::Now, &names)
        }
        _ => {
            let wire: PlanOfflineRequest = cdr(body, big_endian)?;
            check_route_name(&wire.route.0)?;
            let mut request = PlanRequest::new(PlanKind::Offline, &[&wire.route.0]);
            request.start_minute = wire.start_minute as u32;
            request.end_minute = wire.end_minute as u32;
            request.step_min = wire.step_min as u32;
            request.weekday = wire.weekday as u32;
            request
        }
    };
    request.validate().map_err(|e| e.to_string())?;
    Ok(request)
}

/// Route names a ROS 2 request may carry: at most [`PLAN_NAME_LEN`] bytes each.
fn check_route_name(name: &str) -> Result<(), String> {
    if name.is_empty() || name.len() > PLAN_NAME_LEN {
        return Err(format!(
            "route name '{name}': expected 1 to {PLAN_NAME_LEN} bytes"
        ));
    }
    Ok(())
}

/// Where a reply goes, in the layout of its request.
#[derive(Debug, Clone, Copy, PartialEq)]
enum ReplyTo {
    /// rmw_cyclonedds: the client's id and sequence number, before the fields.
    Cyclone { client: u64, sequence: i64 },
    /// rmw_fastrtps: the reply's related sample identity.
    FastDds(SampleIdentity),
}

/// One request waiting for its answer.
#[derive(Debug, Clone)]
struct Pending {
    reply_to: ReplyTo,
    /// The reader the reply is for (Fast DDS), else the request writer: any
    /// reader of its participant.
    client: GUID,
    /// The request, or why it is malformed.
    request: Result<PlanRequest, String>,
    arrived: Instant,
}

/// Reads one request sample: who to answer and what, or why it cannot be answered.
fn read_request(
    kind: PlanKind,
    writer: GUID,
    sequence: SequenceNumber,
    related: Option<SampleIdentity>,
    raw: &RawSample,
    arrived: Instant,
) -> Result<Pending, String> {
    let big_endian = match raw.encoding {
        RepresentationIdentifier::CDR_LE => Some(false),
        RepresentationIdentifier::CDR_BE => Some(true),
        _ => None,
    };
    let (reply_to, client, body) = match related {
        Some(r) => {
            // rmw_fastrtps names the client's reply reader; the sequence number is
            // the request's own.
            let known = r.writer_guid != GUID::GUID_UNKNOWN;
            let client = if known { r.writer_guid } else { writer };
            let identity = SampleIdentity {
                writer_guid: client,
                sequence_number: sequence,
            };
            (ReplyTo::FastDds(identity), client, &raw.bytes[..])
        }
        None => {
            if raw.bytes.len() < CYCLONE_HEADER {
                return Err(format!(
                    "a request of {} bytes without a related sample identity: too short for rmw_cyclonedds's {CYCLONE_HEADER}-byte header",
                    raw.bytes.len()
                ));
            }
            let Some(big_endian) = big_endian else {
                return Err(format!(
                    "a request in {:?} without a related sample identity: its header cannot be read",
                    raw.encoding
                ));
            };
            let (id, seq) = raw.bytes.split_at(8);
            let id: [u8; 8] = id.try_into().unwrap_or_default();
            let seq: [u8; 8] = seq[..8].try_into().unwrap_or_default();
            let (client_id, seq) = if big_endian {
                (u64::from_be_bytes(id), i64::from_be_bytes(seq))
            } else {
                (u64::from_le_bytes(id), i64::from_le_bytes(seq))
            };
            let reply_to = ReplyTo::Cyclone {
                client: client_id,
                sequence: seq,
            };
            (reply_to, writer, &raw.bytes[CYCLONE_HEADER..])
        }
    };
    let request = match big_endian {
        Some(be) => plan_request(kind, body, be),
        None => Err(format!(
            "a request in {:?}: expected plain CDR (XCDR1), as ROS 2 middlewares send",
            raw.encoding
        )),
    };
    Ok(Pending {
        reply_to,
        client,
        request,
        arrived,
    })
}

/// The bytes of a reply to `reply_to`: rmw_cyclonedds's header if its request had
/// one, then `response` in little-endian CDR.
fn reply_bytes<T: Serialize>(reply_to: &ReplyTo, response: &T) -> Result<Vec<u8>, String> {
    let mut bytes = Vec::new();
    if let ReplyTo::Cyclone { client, sequence } = reply_to {
        bytes.extend(client.to_le_bytes());
        bytes.extend(sequence.to_le_bytes());
    }
    // The header is 16 bytes: the fields' alignment is the same after it.
    bytes.extend(to_vec::<T, LittleEndian>(response).map_err(|e| e.to_string())?);
    Ok(bytes)
}

/// The highest sequence number taken from each request writer: a jump is requests
/// DDS overwrote in the reader's history before they were taken.
#[derive(Debug, Default)]
struct Gaps {
    last: HashMap<GUID, i64>,
}

impl Gaps {
    /// Records `sequence` from `writer`; returns how many were skipped since the
    /// last one (none before a writer's first sample: those were not sent here).
    fn seen(&mut self, writer: GUID, sequence: SequenceNumber) -> u64 {
        let sequence = i64::from(sequence);
        if self.last.len() >= MAX_CLIENTS && !self.last.contains_key(&writer) {
            self.last.clear();
        }
        match self.last.insert(writer, sequence) {
            Some(last) if sequence > last + 1 => (sequence - last - 1) as u64,
            _ => 0,
        }
    }
}

/// The totals of the planning services since the bridge started.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct PlanCounts {
    /// Requests answered (any status).
    pub answered: u64,
    /// Malformed requests: answered with `STATUS_BAD_REQUEST` when they carried an
    /// identity, else only counted.
    pub rejected: u64,
    /// Requests dropped: beyond a full queue, or overwritten in DDS before the
    /// bridge took them.
    pub dropped: u64,
}

/// One service: its reader and writer, queue and bookkeeping.
struct Service {
    kind: PlanKind,
    name: String,
    reader: SimpleDataReader<RawSample, Raw>,
    writer: DataWriter<RawReply, Raw>,
    queue: VecDeque<Pending>,
    gaps: Gaps,
    /// Readers matched with the reply writer.
    matched: HashSet<GUID>,
}

/// Both planning services of the bridge.
pub struct PlanServices {
    offline: Service,
    now: Service,
    counts: PlanCounts,
}

/// Why the services could not be created.
#[derive(Debug, thiserror::Error)]
#[error("creating the service {name}: {detail}")]
pub struct ServiceError {
    /// The service name.
    pub name: String,
    /// What DDS said.
    pub detail: String,
}

impl PlanServices {
    /// Creates `offline` (`PlanOffline`) and `now` (`PlanNow`) on `participant` for
    /// the node `node` (names relative to its namespace).
    pub fn start(
        participant: &DomainParticipant,
        node: &NodeName,
        offline: &Name,
        now: &Name,
    ) -> Result<PlanServices, ServiceError> {
        Ok(PlanServices {
            offline: Service::start(participant, node, offline, PlanKind::Offline, "PlanOffline")?,
            now: Service::start(participant, node, now, PlanKind::Now, "PlanNow")?,
            counts: PlanCounts::default(),
        })
    }

    /// Takes the requests DDS holds, queues them, answers what is due with
    /// `answer` (at most [`ANSWERS_PER_PASS`] per service); returns how many were
    /// answered. Rejected and dropped requests are counted here and in `cx`'s
    /// health, with rate-limited warnings. Never blocks for long: a reply write
    /// waits at most 50 ms for room.
    pub fn serve(
        &mut self,
        cx: &mut Context,
        mut answer: impl FnMut(PlanKind, &PlanRequest) -> PlanResponse,
    ) -> usize {
        let mut n = 0;
        for service in [&mut self.offline, &mut self.now] {
            service.intake(cx, &mut self.counts);
            n += service.answer(cx, &mut self.counts, &mut answer);
        }
        n
    }

    /// The totals so far.
    pub fn counts(&self) -> PlanCounts {
        self.counts
    }
}

impl Service {
    fn start(
        participant: &DomainParticipant,
        node: &NodeName,
        name: &Name,
        kind: PlanKind,
        type_name: &str,
    ) -> Result<Service, ServiceError> {
        let fail = |detail: String| ServiceError {
            name: name.to_string(),
            detail,
        };
        let reliable = policy::Reliability::Reliable {
            max_blocking_time: rustdds::Duration::from_std(MAX_BLOCKING),
        };
        let request_qos = keep_last(reliable, policy::Durability::Volatile, REQUEST_HISTORY);
        let reply_qos = keep_last(reliable, policy::Durability::Volatile, REPLY_HISTORY);
        // rosidl's names: `rq/<name>Request` of `<pkg>::srv::dds_::<Type>_Request_`,
        // `rr/<name>Reply` of `..._Response_`.
        let topic = |(prefix, suffix, part): (&str, &str, &str), qos: &QosPolicies| {
            participant
                .create_topic(
                    name.to_dds_name(prefix, node, suffix),
                    format!("isochron_msgs::srv::dds_::{type_name}_{part}_"),
                    qos,
                    TopicKind::NoKey,
                )
                .map_err(|e| fail(format!("{e}")))
        };
        let request_topic = topic(("rq", "Request", "Request"), &request_qos)?;
        let reply_topic = topic(("rr", "Reply", "Response"), &reply_qos)?;
        let subscriber = participant
            .create_subscriber(&QosPolicies::default())
            .map_err(|e| fail(format!("{e}")))?;
        let publisher = participant
            .create_publisher(&QosPolicies::from(DEFAULT_PUBLISHER_QOS))
            .map_err(|e| fail(format!("{e}")))?;
        let reader = subscriber
            .create_simple_datareader_no_key::<RawSample, Raw>(&request_topic, Some(request_qos))
            .map_err(|e| fail(format!("{e}")))?;
        let writer = publisher
            .create_datawriter_no_key::<RawReply, Raw>(&reply_topic, Some(reply_qos))
            .map_err(|e| fail(format!("{e}")))?;
        Ok(Service {
            kind,
            name: name.to_string(),
            reader,
            writer,
            queue: VecDeque::new(),
            gaps: Gaps::default(),
            matched: HashSet::new(),
        })
    }

    /// Takes what DDS holds into the queue.
    fn intake(&mut self, cx: &mut Context, counts: &mut PlanCounts) {
        self.reader.drain_read_notifications();
        let arrived = Instant::now();
        for _ in 0..REQUEST_HISTORY {
            let sample = match self.reader.try_take_one() {
                Ok(Some(sample)) => sample,
                Ok(None) => break,
                Err(e) => {
                    counts.rejected += 1;
                    cx.health.rejected();
                    let name = &self.name;
                    cx.warnings.warn("plan request unreadable", || {
                        format!("{name}: a request that cannot be read: {e}")
                    });
                    continue;
                }
            };
            let skipped = self.gaps.seen(sample.writer_guid, sample.sequence_number);
            if skipped > 0 {
                self.dropped(
                    cx,
                    counts,
                    skipped,
                    "overwritten in DDS before it was taken",
                );
            }
            let related = sample.related_sample_identity();
            let pending = read_request(
                self.kind,
                sample.writer_guid,
                sample.sequence_number,
                related,
                &sample.sample,
                arrived,
            );
            match pending {
                Err(why) => {
                    counts.rejected += 1;
                    cx.health.rejected();
                    let name = &self.name;
                    cx.warnings.warn("plan request unanswerable", || {
                        format!("{name}: a malformed request that cannot be answered: {why}")
                    });
                }
                Ok(_) if self.queue.len() >= QUEUE => {
                    self.dropped(cx, counts, 1, "the queue is full");
                }
                Ok(pending) => self.queue.push_back(pending),
            }
        }
    }

    /// Counts `n` dropped requests, with a rate-limited warning saying `why`.
    fn dropped(&self, cx: &mut Context, counts: &mut PlanCounts, n: u64, why: &str) {
        counts.dropped += n;
        cx.health.dropped(n);
        let name = &self.name;
        cx.warnings.warn("plan request dropped", || {
            format!(
                "{name}: {n} request(s) dropped, {why} ({QUEUE} queued, {ANSWERS_PER_PASS} answered per pass; {} dropped so far)",
                counts.dropped
            )
        });
    }

    /// Answers the queue's due requests; returns how many.
    fn answer(
        &mut self,
        cx: &mut Context,
        counts: &mut PlanCounts,
        answer: &mut impl FnMut(PlanKind, &PlanRequest) -> PlanResponse,
    ) -> usize {
        // Every pass, so that the writer's status queue never fills up.
        self.update_matched();
        if self.queue.is_empty() {
            return 0;
        }
        let now = Instant::now();
        let mut waiting = VecDeque::new();
        let mut n = 0;
        while n < ANSWERS_PER_PASS
            && let Some(pending) = self.queue.pop_front()
        {
            if !self.client_matched(&pending) && now.duration_since(pending.arrived) < REPLY_WAIT {
                waiting.push_back(pending);
                continue;
            }
            let response = match &pending.request {
                Ok(request) => answer(self.kind, request),
                Err(why) => {
                    counts.rejected += 1;
                    cx.health.rejected();
                    let name = &self.name;
                    cx.warnings.warn("plan request malformed", || {
                        format!("{name}: a malformed request, answered with status 1: {why}")
                    });
                    PlanResponse::new(self.kind as u32, PlanStatus::BadRequest, why)
                }
            };
            self.reply(cx, &pending, &response);
            counts.answered += 1;
            n += 1;
        }
        waiting.append(&mut self.queue);
        self.queue = waiting;
        n
    }

    /// Follows which readers the reply writer is matched with.
    fn update_matched(&mut self) {
        while let Some(status) = self.writer.try_recv_status() {
            if let DataWriterStatus::PublicationMatched {
                current, reader, ..
            } = status
            {
                if current.count_change() > 0 {
                    self.matched.insert(reader);
                } else if current.count_change() < 0 {
                    self.matched.remove(&reader);
                }
            }
        }
    }

    /// True if the reply to `pending` would reach its client: the reader it names
    /// (Fast DDS), or a reader of its writer's participant, is matched.
    fn client_matched(&self, pending: &Pending) -> bool {
        if pending.client.entity_id.entity_kind.is_reader() {
            self.matched.contains(&pending.client)
        } else {
            self.matched
                .iter()
                .any(|r| r.prefix == pending.client.prefix)
        }
    }

    /// Sends the reply to `pending`.
    fn reply(&self, cx: &mut Context, pending: &Pending, response: &PlanResponse) {
        let bytes = match self.kind {
            PlanKind::Now => reply_bytes(&pending.reply_to, &now_response(response)),
            _ => reply_bytes(&pending.reply_to, &offline_response(response)),
        };
        let bytes = match bytes {
            Ok(b) => b,
            Err(e) => {
                tracing::warn!("{}: a reply could not be encoded: {e}", self.name);
                return;
            }
        };
        let mut options = WriteOptionsBuilder::new().source_timestamp(Timestamp::now());
        if let ReplyTo::FastDds(identity) = pending.reply_to {
            options = options.related_sample_identity(identity);
        }
        if let Err(e) = self
            .writer
            .write_with_options(RawReply(bytes), options.build())
        {
            let (name, e) = (&self.name, e.forget_data());
            cx.warnings.warn("plan reply failed", || {
                format!("{name}: a reply could not be sent: {e}")
            });
        }
    }
}

/// A `PlanOffline` response from the planner's answer.
fn offline_response(r: &PlanResponse) -> PlanOfflineResponse {
    if r.status != PlanStatus::Ok as u32 {
        return PlanOfflineResponse {
            status: r.status as u8,
            message: r.message(),
            windows: Vec::new(),
            curve: Vec::new(),
            infinite: false,
        };
    }
    let plan = offline_plan_of(r);
    PlanOfflineResponse {
        status: r.status as u8,
        message: r.message(),
        windows: plan
            .windows
            .iter()
            .map(|w| WindowMsg {
                start_minute: w.start as u16,
                end_minute: w.end as u16,
                cost: w.cost,
            })
            .collect(),
        curve: plan
            .curve
            .iter()
            .map(|p| CostPoint {
                minute: p.minute as u16,
                cost: p.cost,
            })
            .collect(),
        infinite: r.route_count > 0 && r.routes[0].flags & PLAN_FLAG_INFINITE != 0,
    }
}

/// A `PlanNow` response from the planner's answer.
fn now_response(r: &PlanResponse) -> PlanNowResponse {
    let ok = r.status == PlanStatus::Ok as u32;
    PlanNowResponse {
        status: r.status as u8,
        message: r.message(),
        t_star: if ok { r.t_star as u16 } else { 0 },
        routes: if ok {
            ranking_of(r)
                .into_iter()
                .map(|x| RouteCost {
                    route: x.name,
                    cost2: x.cost2,
                    cost1: x.cost1,
                    short_term: x.short_term,
                    infinite: x.infinite,
                    estimated: x.estimated,
                    no_long_term: x.no_long_term,
                })
                .collect()
        } else {
            Vec::new()
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::CdrString;

    /// A GUID whose last byte (the entity kind) is `kind`: 0x03 a writer, 0x04 a
    /// reader (no key), under the participant `prefix`.
    fn guid(prefix: u8, kind: u8) -> GUID {
        let mut b = [prefix; 16];
        b[12..].copy_from_slice(&[0, 0, 1, kind]);
        GUID::from_bytes(b)
    }

    /// A little-endian CDR string: length with the NUL, bytes, NUL.
    fn cdr_str(out: &mut Vec<u8>, s: &[u8], nul: bool) {
        while !out.len().is_multiple_of(4) {
            out.push(0);
        }
        let len = s.len() + nul as usize;
        out.extend((len as u32).to_le_bytes());
        out.extend(s);
        if nul {
            out.push(0);
        }
    }

    /// `PlanOffline` request fields laid out by hand (little-endian).
    fn offline_body(route: &[u8], nul: bool) -> Vec<u8> {
        let mut b = Vec::new();
        cdr_str(&mut b, route, nul);
        while !b.len().is_multiple_of(2) {
            b.push(0);
        }
        for v in [600u16, 720, 30] {
            b.extend(v.to_le_bytes());
        }
        b.push(7);
        b
    }

    fn raw(bytes: Vec<u8>) -> RawSample {
        RawSample {
            bytes,
            encoding: RepresentationIdentifier::CDR_LE,
        }
    }

    #[test]
    fn strings_follow_the_cdr_rules() {
        assert_eq!(
            CdrString::from_wire(b"dock\0"),
            Ok(CdrString("dock".into()))
        );
        assert_eq!(CdrString::from_wire(b"\0"), Ok(CdrString(String::new())));
        let no_nul = CdrString::from_wire(b"dock").unwrap_err();
        assert!(no_nul.contains("without its terminating NUL"), "{no_nul}");
        assert!(CdrString::from_wire(b"").is_err());
        assert!(CdrString::from_wire(b"do\0ck\0").is_err());
        assert!(CdrString::from_wire(b"\xff\xfe\0").is_err());

        let ok = plan_request(PlanKind::Offline, &offline_body(b"dock", true), false).unwrap();
        assert_eq!(ok.route_names(), vec!["dock".to_string()]);
        assert_eq!(
            (ok.start_minute, ok.end_minute, ok.step_min, ok.weekday),
            (600, 720, 30, 7)
        );
        // Without its NUL the name is not "doc": the request is malformed.
        let err =
            plan_request(PlanKind::Offline, &offline_body(b"dock", false), false).unwrap_err();
        assert!(err.contains("without its terminating NUL"), "{err}");
    }

    #[test]
    fn plan_now_requests_are_read_in_either_byte_order() {
        let mut le = Vec::new();
        le.extend(2u32.to_le_bytes());
        cdr_str(&mut le, b"a", true);
        cdr_str(&mut le, b"bc", true);
        let r = plan_request(PlanKind::Now, &le, false).unwrap();
        assert_eq!(r.route_names(), vec!["a".to_string(), "bc".to_string()]);
        let mut be = Vec::new();
        be.extend(1u32.to_be_bytes());
        be.extend(3u32.to_be_bytes());
        be.extend(b"xy\0");
        let r = plan_request(PlanKind::Now, &be, true).unwrap();
        assert_eq!(r.route_names(), vec!["xy".to_string()]);
        // A count far beyond the bytes ends at the bytes, as an error.
        let mut huge = Vec::new();
        huge.extend(u32::MAX.to_le_bytes());
        cdr_str(&mut huge, b"a", true);
        assert!(plan_request(PlanKind::Now, &huge, false).is_err());
        let none = 0u32.to_le_bytes().to_vec();
        let err = plan_request(PlanKind::Now, &none, false).unwrap_err();
        assert!(err.contains("expected 1 to 16 routes"), "{err}");
        let long = vec![b'x'; 33];
        let mut b = 1u32.to_le_bytes().to_vec();
        cdr_str(&mut b, &long, true);
        assert!(plan_request(PlanKind::Now, &b, false).is_err());
        assert!(plan_request(PlanKind::Now, &vec![0; MAX_REQUEST_BYTES + 1], false).is_err());
    }

    #[test]
    fn the_layout_comes_from_the_related_sample_identity() {
        let writer = guid(7, 0x03);
        let at = Instant::now();
        // rmw_cyclonedds: the header, then the fields.
        let mut bytes = 0x1122_3344_5566_7788u64.to_le_bytes().to_vec();
        bytes.extend(42i64.to_le_bytes());
        bytes.extend(offline_body(b"dock", true));
        let p = read_request(
            PlanKind::Offline,
            writer,
            SequenceNumber::from(5),
            None,
            &raw(bytes),
            at,
        )
        .unwrap();
        assert_eq!(
            p.reply_to,
            ReplyTo::Cyclone {
                client: 0x1122_3344_5566_7788,
                sequence: 42
            }
        );
        assert_eq!(p.client, writer);
        assert!(p.request.is_ok(), "{:?}", p.request);

        // rmw_fastrtps: the bare fields; the reply names the client's reader and
        // the request's sequence number.
        let reader = guid(7, 0x04);
        let related = SampleIdentity {
            writer_guid: reader,
            sequence_number: SequenceNumber::UNKNOWN,
        };
        let p = read_request(
            PlanKind::Offline,
            writer,
            SequenceNumber::from(5),
            Some(related),
            &raw(offline_body(b"dock", true)),
            at,
        )
        .unwrap();
        assert_eq!(
            p.reply_to,
            ReplyTo::FastDds(SampleIdentity {
                writer_guid: reader,
                sequence_number: SequenceNumber::from(5)
            })
        );
        assert_eq!(p.client, reader);
        assert!(p.request.is_ok());

        // A malformed body with an identity is answered; without one it cannot be.
        let p = read_request(
            PlanKind::Offline,
            writer,
            SequenceNumber::from(6),
            Some(related),
            &raw(offline_body(b"dock", false)),
            at,
        )
        .unwrap();
        assert!(p.request.is_err());
        let short = read_request(
            PlanKind::Offline,
            writer,
            SequenceNumber::from(7),
            None,
            &raw(vec![1, 2, 3]),
            at,
        );
        assert!(short.unwrap_err().contains("too short"));
        let xcdr2 = RawSample {
            bytes: offline_body(b"dock", true),
            encoding: RepresentationIdentifier::CDR2_LE,
        };
        let p = read_request(
            PlanKind::Offline,
            writer,
            SequenceNumber::from(8),
            Some(related),
            &xcdr2,
            at,
        )
        .unwrap();
        assert!(p.request.unwrap_err().contains("XCDR1"));
    }

    #[test]
    fn replies_carry_the_header_of_their_layout() {
        let response = PlanNowResponse {
            status: 1,
            message: "why".into(),
            t_star: 0,
            routes: Vec::new(),
        };
        let body = to_vec::<_, LittleEndian>(&response).unwrap();
        let cyclone = reply_bytes(
            &ReplyTo::Cyclone {
                client: 9,
                sequence: -2,
            },
            &response,
        )
        .unwrap();
        assert_eq!(&cyclone[..8], &9u64.to_le_bytes());
        assert_eq!(&cyclone[8..16], &(-2i64).to_le_bytes());
        assert_eq!(&cyclone[16..], &body[..]);
        let fast = reply_bytes(
            &ReplyTo::FastDds(SampleIdentity {
                writer_guid: guid(1, 4),
                sequence_number: SequenceNumber::from(3),
            }),
            &response,
        )
        .unwrap();
        assert_eq!(fast, body);
        let (back, _) = from_bytes::<PlanNowResponse, LittleEndian>(&fast).unwrap();
        assert_eq!(back, response);
    }

    #[test]
    fn gaps_in_a_clients_sequence_numbers_are_counted() {
        let mut gaps = Gaps::default();
        let (a, b) = (guid(1, 3), guid(2, 3));
        assert_eq!(gaps.seen(a, SequenceNumber::from(10)), 0, "first from a");
        assert_eq!(gaps.seen(a, SequenceNumber::from(11)), 0);
        assert_eq!(gaps.seen(a, SequenceNumber::from(15)), 3);
        assert_eq!(gaps.seen(b, SequenceNumber::from(1)), 0);
        assert_eq!(gaps.seen(a, SequenceNumber::from(16)), 0);
        for k in 0..2 * MAX_CLIENTS as u32 {
            let mut bytes = [0; 16];
            bytes[..4].copy_from_slice(&k.to_le_bytes());
            gaps.seen(GUID::from_bytes(bytes), SequenceNumber::from(1));
        }
        assert!(gaps.last.len() <= MAX_CLIENTS);
    }
}
