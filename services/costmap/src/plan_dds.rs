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
//! Requests are decoded by the CDR rules ([`isochron_ros2::msgs::CdrString`]): a string's
//! length counts its NUL, and a string without one is malformed (not cut short).
//! A malformed
//! request gets `STATUS_BAD_REQUEST` (1) with the reason and is counted as
//! rejected; one that cannot be answered (no identity) is counted only.
//!
//! Requests are queued per client, the DDS writer that sent them, and answered
//! round robin across clients ([`isochron_ros2::fair`]): each client may have [`PER_CLIENT`]
//! requests queued, all together [`QUEUE`], and each service answers at most
//! [`ANSWERS_PER_PASS`] per pass of the bridge's loop, [`CLIENT_ANSWERS_PER_PASS`]
//! of one client. A flood beyond its
//! client's share is dropped and counted, as are the requests DDS overwrote in
//! the reader's history before the bridge took them (gaps in each client's
//! sequence numbers); a client with one request outstanding is answered within
//! one round, whatever another client sends. The writer, not the client id of
//! rmw_cyclonedds's header nor the reader named by rmw_fastrtps's related sample
//! identity, is the client: those are the request's bytes, a new one per
//! request if its sender likes.

use std::collections::{HashMap, HashSet};
use std::time::{Duration, Instant};

use ros2_client::dds::DEFAULT_PUBLISHER_QOS;
use ros2_client::{Name, NodeName};
use rustdds::no_key::{DataWriter, SimpleDataReader};
use rustdds::{
    DataWriterStatus, DomainParticipant, GUID, QosPolicies, SequenceNumber, StatusEvented,
    Timestamp, TopicKind, WriteOptionsBuilder, policy,
};

use isochron_dds::keep_last;
use isochron_planning::query::{PlanKind, PlanRequest, PlanResponse, PlanStatus};
use isochron_runtime::stage::Context;

/// Requests DDS keeps for a service between two passes of the bridge's loop (at
/// least 4 a second): a flood of 1 000 requests a second fits.
const REQUEST_HISTORY: i32 = 256;
/// Requests a service holds for an answer, of all clients together; past it a
/// newcomer displaces the newest request of the longest lane, if that is longer
/// than the newcomer's ([`isochron_ros2::fair`]).
pub const QUEUE: usize = 64;
/// Requests one client (DDS writer) may have queued; more are dropped and
/// counted. A ROS 2 client waits for each answer: it has one or two queued.
pub const PER_CLIENT: usize = 8;
/// Requests a service answers per pass of the loop.
pub const ANSWERS_PER_PASS: usize = 16;
/// Requests of one client a service answers per pass of the loop: what a flood
/// costs the planner, and the burst of replies every client's reply reader
/// receives (ROS 2 clients share the reply topic, and keep the last 10), stay
/// small.
pub const CLIENT_ANSWERS_PER_PASS: usize = 2;
/// Replies the reply writer keeps until their clients acknowledge them.
const REPLY_HISTORY: i32 = 256;
/// Longest a reply waits for its client's reply reader to be matched.
pub const REPLY_WAIT: Duration = Duration::from_secs(2);
/// Clients whose sequence numbers are followed; more start the table afresh.
const MAX_CLIENTS: usize = 1024;
/// How long `write` waits for room in a reliable send window.
const MAX_BLOCKING: Duration = Duration::from_millis(50);
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
    /// Requests dropped: beyond their client's share of the queue, or
    /// overwritten in DDS before the bridge took them.
    pub dropped: u64,
}

/// One service: its reader and writer, queue and bookkeeping.
struct Service {
    kind: PlanKind,
    name: String,
    reader: SimpleDataReader<RawSample, Raw>,
    writer: DataWriter<RawReply, Raw>,
    /// Requests waiting for an answer, per request writer.
    queue: FairQueue<GUID, Pending>,
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
            queue: FairQueue::new(PER_CLIENT, QUEUE),
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
            let writer = sample.writer_guid;
            let skipped = self.gaps.seen(writer, sample.sequence_number);
            if skipped > 0 {
                self.dropped(
                    cx,
                    counts,
                    (skipped, writer),
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
                Ok(pending) => match self.queue.push(writer, pending) {
                    Pushed::Queued => {}
                    Pushed::ClientFull => {
                        let why = "its client's queue is full";
                        self.dropped(cx, counts, (1, writer), why);
                    }
                    Pushed::Full => self.dropped(cx, counts, (1, writer), "the queue is full"),
                    Pushed::Displaced { client, .. } => {
                        let why = "displaced from the longest queue by another client's";
                        self.dropped(cx, counts, (1, client), why);
                    }
                },
            }
        }
    }

    /// Counts `n` dropped requests of `client`, with a rate-limited warning
    /// saying `why`.
    fn dropped(
        &self,
        cx: &mut Context,
        counts: &mut PlanCounts,
        (n, client): (u64, GUID),
        why: &str,
    ) {
        counts.dropped += n;
        cx.health.dropped(n);
        let (name, queue) = (&self.name, &self.queue);
        let of_client = queue.counts(&client).map_or(n, |c| c.dropped.max(n));
        cx.warnings.warn("plan request dropped", || {
            format!(
                "{name}: {n} request(s) of client {:?} dropped, {why} ({PER_CLIENT} per client, {QUEUE} in all, {CLIENT_ANSWERS_PER_PASS} of a client answered per pass, round robin over {} client(s); {of_client} of its requests and {} in all dropped so far)",
                client.prefix,
                queue.clients(),
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
        let now = Instant::now();
        let matched = &self.matched;
        let mut this_pass: HashMap<GUID, usize> = HashMap::new();
        // A reply is sent once its client's reader is matched, or waited enough;
        // at most CLIENT_ANSWERS_PER_PASS to a client.
        let mut ready = |writer: &GUID, pending: &Pending| {
            let n = this_pass.entry(*writer).or_default();
            let due = *n < CLIENT_ANSWERS_PER_PASS
                && (client_matched(matched, pending)
                    || now.duration_since(pending.arrived) >= REPLY_WAIT);
            *n += usize::from(due);
            due
        };
        let mut due = Vec::new();
        while due.len() < ANSWERS_PER_PASS
            && let Some((_, pending)) = self.queue.next(&mut ready)
        {
            due.push(pending);
        }
        for pending in &due {
            let request = pending.request.as_ref().map_err(String::as_str);
            let response = respond((self.kind, &self.name), request, (cx, counts), answer);
            self.reply(cx, pending, &response);
            counts.answered += 1;
        }
        due.len()
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

/// The response of the service `name` of `kind` to `request`: `answer`'s, or for a
/// malformed request (`Err(why)`) status 1 with the reason, counted as rejected
/// in `counts` and `cx` with a rate-limited warning.
pub(crate) fn respond(
    (kind, name): (PlanKind, &str),
    request: Result<&PlanRequest, &str>,
    (cx, counts): (&mut Context, &mut PlanCounts),
    answer: &mut impl FnMut(PlanKind, &PlanRequest) -> PlanResponse,
) -> PlanResponse {
    match request {
        Ok(request) => answer(kind, request),
        Err(why) => {
            counts.rejected += 1;
            cx.health.rejected();
            cx.warnings.warn("plan request malformed", || {
                format!("{name}: a malformed request, answered with status 1: {why}")
            });
            PlanResponse::new(kind as u32, PlanStatus::BadRequest, why)
        }
    }
}

/// True if the reply to `pending` would reach its client: the reader it names
/// (Fast DDS), or a reader of its writer's participant, is `matched`.
fn client_matched(matched: &HashSet<GUID>, pending: &Pending) -> bool {
    if pending.client.entity_id.entity_kind.is_reader() {
        matched.contains(&pending.client)
    } else {
        matched.iter().any(|r| r.prefix == pending.client.prefix)
    }
}

mod request;

use isochron_ros2::fair::{FairQueue, Pushed};

use request::{Pending, Raw, RawReply, RawSample, ReplyTo, read_request, reply_bytes};
pub(crate) use request::{now_response, offline_response, plan_request};

#[cfg(test)]
mod tests;
