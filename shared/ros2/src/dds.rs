//! The DDS transport (`ros2-client` on RustDDS, pure Rust): the topics'
//! writers, and the planning services' endpoint on the topics ROS 2 gives a
//! service `/s`, `rq/sRequest` and `rr/sReply`.
//!
//! A topic's writer offers its [`Qos`] with a reliable send window that waits
//! at most [`MAX_BLOCKING`] for room, and keeps at most `depth` samples
//! ([`keep_last`]).
//!
//! ROS 2 middlewares carry a request's identity in two ways on the same topics, and
//! both are served (`dds/wire.rs`):
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
//! client that sends at once after discovery would otherwise miss it. A request
//! whose identity cannot be read (too short for Cyclone's header, or not plain
//! CDR without a related sample identity) is counted only.
//!
//! The client, whose lane of the fair queue a request joins ([`crate::plan`]), is
//! the DDS writer that sent it, not the client id of rmw_cyclonedds's header nor
//! the reader named by rmw_fastrtps's related sample identity: those are the
//! request's bytes, a new one per request if its sender likes. Requests DDS
//! overwrote in the reader's history before the bridge took them (gaps in each
//! writer's sequence numbers) are counted as dropped.

mod route;
pub(crate) mod wire;

use std::collections::{HashMap, HashSet};
use std::time::{Duration, Instant};

use ros2_client::dds::DEFAULT_PUBLISHER_QOS;
use rustdds::dds::qos::HasQoSPolicy;
use rustdds::no_key::{DataWriter, SimpleDataReader};
use rustdds::{
    DataWriterStatus, GUID, QosPolicies, SequenceNumber, StatusEvented, Timestamp, TopicKind,
    WriteOptionsBuilder, policy,
};
use serde::Serialize;

use isochron_dds::{RosNode, keep_last};

use crate::error::{RosError, topic_name};
use crate::plan::{Endpoint, Service, Taken, WarningKinds};
use crate::spec::{Qos, ServiceSpec, TopicSpec};
pub use route::{DdsCaller, Layout};
use wire::{Raw, RawReply, RawSample, ReplyTo, read_request, reply_bytes};

/// How long a write waits for room in a reliable send window.
pub const MAX_BLOCKING: Duration = Duration::from_millis(50);
/// Requests DDS keeps for a service between two passes of the bridge's loop (at
/// least 4 a second): a flood of 1 000 requests a second fits.
const REQUEST_HISTORY: i32 = 256;
/// Replies the reply writer keeps until their clients acknowledge them.
const REPLY_HISTORY: i32 = 256;
/// Longest a reply waits for its client's reply reader to be matched.
pub const REPLY_WAIT: Duration = Duration::from_secs(2);
/// Clients whose sequence numbers are followed; more start the table afresh.
const MAX_CLIENTS: usize = 1024;

/// The DDS QoS of `qos`: reliable (waiting at most [`MAX_BLOCKING`] for room) or
/// best effort, its durability, keep last `depth`, and at most `depth` samples in
/// the writer's cache ([`keep_last`]).
pub fn dds_qos(qos: Qos) -> QosPolicies {
    keep_last(
        if qos.reliable {
            policy::Reliability::Reliable {
                max_blocking_time: rustdds::Duration::from_std(MAX_BLOCKING),
            }
        } else {
            policy::Reliability::BestEffort
        },
        if qos.transient_local {
            policy::Durability::TransientLocal
        } else {
            policy::Durability::Volatile
        },
        i32::try_from(qos.depth).unwrap_or(i32::MAX),
    )
}

/// A writer's DDS topic name (`rt/...`) and the QoS it offers: what RustDDS
/// matches remote readers against.
#[derive(Debug, Clone)]
pub(crate) struct Offered {
    topic: String,
    qos: QosPolicies,
}

impl Offered {
    /// The remote readers DDS discovery knows on the topic whose requested QoS
    /// the writer offers — the rule by which RustDDS matches a discovered reader
    /// to a local writer (`Writer::update_reader_proxy`).
    ///
    /// Not `Publisher::get_subscription_count`: ros2-client 0.12 counts from a
    /// map that only gets an entry for a publisher when a first reader matches
    /// it, and logs an ERROR ("Publisher … not known to node") on every call
    /// until then — every status report of a bridge nobody listens to.
    pub(crate) fn readers(&self, ros: &RosNode) -> usize {
        ros.context()
            .domain_participant()
            .discovered_readers()
            .iter()
            .filter(|r| {
                let s = &r.subscription_topic_data;
                s.topic_name == self.topic && self.qos.compliance_failure_wrt(&s.qos()).is_none()
            })
            .count()
    }
}

/// The DDS writer of `spec`'s topic `name` on `ros`'s node, and what it offers.
pub(crate) fn publisher<M: Serialize>(
    ros: &mut RosNode,
    spec: &TopicSpec<M>,
    name: &str,
) -> Result<(ros2_client::Publisher<M>, Offered), RosError> {
    let topic = ros.typed_topic(&topic_name(name)?, spec.ty.dds_name, &dds_qos(spec.qos))?;
    // RustDDS gives a writer the ROS default publisher's QoS overridden by the
    // topic's (`Publisher::create_datawriter`).
    let offered = Offered {
        topic: rustdds::TopicDescription::name(&topic),
        qos: QosPolicies::from(DEFAULT_PUBLISHER_QOS).modify_by(&topic.qos()),
    };
    let publisher = ros
        .node_mut()
        .create_publisher(&topic, None)
        .map_err(|e| ros.error(format!("creating the publisher of {name}: {e}")))?;
    Ok((publisher, offered))
}

/// A writer of requests: the client whose lane a request joins.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Writer(pub GUID);

impl std::fmt::Display for Writer {
    /// The writer's participant.
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        write!(f, "{:?}", self.0.prefix)
    }
}

/// Where a reply goes: the layout of its request, the reader it is for, and
/// when the request arrived.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reply {
    /// The request's layout and identity.
    pub(crate) reply_to: ReplyTo,
    /// The reader the reply is for (Fast DDS), else the request writer: any
    /// reader of its participant.
    pub(crate) client: GUID,
    /// When the request was taken.
    pub(crate) arrived: Instant,
}

/// One planning service on DDS: its request reader and reply writer.
pub struct DdsService {
    reader: SimpleDataReader<RawSample, Raw>,
    writer: DataWriter<RawReply, Raw>,
    gaps: Gaps,
    /// Readers matched with the reply writer.
    matched: HashSet<GUID>,
}

impl DdsService {
    /// The service `spec` named `name` on `ros`'s participant (names relative to
    /// its node's namespace).
    pub(crate) fn start(
        ros: &RosNode,
        spec: &ServiceSpec,
        name: &str,
    ) -> Result<Service<DdsService>, RosError> {
        let parsed = topic_name(name)?;
        let fail = |e: String| ros.error(format!("creating the service {parsed}: {e}"));
        let participant = ros.context().domain_participant();
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
                    parsed.to_dds_name(prefix, ros.name(), suffix),
                    format!("{}{part}_", spec.ty.dds_name),
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
        let endpoint = DdsService {
            reader,
            writer,
            gaps: Gaps::default(),
            matched: HashSet::new(),
        };
        Ok(Service::new(spec.kind, parsed.to_string(), endpoint))
    }
}

impl Endpoint for DdsService {
    type Client = Writer;
    type Reply = Reply;
    const WARNINGS: WarningKinds = WarningKinds {
        unreadable: "plan request unreadable",
        unanswerable: "plan request unanswerable",
        dropped: "plan request dropped",
        reply_failed: "plan reply failed",
    };

    /// What the reader holds, at most `REQUEST_HISTORY` samples.
    fn take(&mut self) -> Vec<Taken<Writer, Reply>> {
        self.reader.drain_read_notifications();
        let arrived = Instant::now();
        let mut taken = Vec::new();
        for _ in 0..REQUEST_HISTORY {
            let sample = match self.reader.try_take_one() {
                Ok(Some(sample)) => sample,
                Ok(None) => break,
                Err(e) => {
                    taken.push(Taken::Unreadable(e.to_string()));
                    continue;
                }
            };
            let writer = sample.writer_guid;
            let skipped = self.gaps.seen(writer, sample.sequence_number);
            if skipped > 0 {
                taken.push(Taken::Lost {
                    n: skipped,
                    client: Some(Writer(writer)),
                    why: "overwritten in DDS before it was taken",
                });
            }
            let related = sample.related_sample_identity();
            let read = read_request(
                writer,
                sample.sequence_number,
                related,
                &sample.sample,
                arrived,
            );
            taken.push(match read {
                Err(why) => Taken::Unanswerable(why),
                Ok((reply, body)) => Taken::Request {
                    client: Writer(writer),
                    reply,
                    body,
                },
            });
        }
        taken
    }

    /// Follows which readers the reply writer is matched with (every pass, so
    /// that the writer's status queue never fills up).
    fn refresh(&mut self) {
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

    /// Once its client's reader is matched, or it waited [`REPLY_WAIT`].
    fn due(&self, reply: &Reply, now: Instant) -> bool {
        client_matched(&self.matched, reply) || now.duration_since(reply.arrived) >= REPLY_WAIT
    }

    /// Writes the reply in its request's layout.
    fn reply(&self, reply: Reply, cdr: &[u8]) -> Result<(), String> {
        let bytes = reply_bytes(&reply.reply_to, cdr);
        let mut options = WriteOptionsBuilder::new().source_timestamp(Timestamp::now());
        if let ReplyTo::FastDds(identity) = reply.reply_to {
            options = options.related_sample_identity(identity);
        }
        self.writer
            .write_with_options(RawReply(bytes), options.build())
            .map(drop)
            .map_err(|e| e.forget_data().to_string())
    }
}

/// True if the reply would reach its client: the reader it names (Fast DDS), or a
/// reader of its writer's participant, is `matched`.
fn client_matched(matched: &HashSet<GUID>, reply: &Reply) -> bool {
    if reply.client.entity_id.entity_kind.is_reader() {
        matched.contains(&reply.client)
    } else {
        matched.iter().any(|r| r.prefix == reply.client.prefix)
    }
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

#[cfg(test)]
mod tests;
