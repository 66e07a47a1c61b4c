//! The route server's `DynamicEdges` service called over DDS: a request writer
//! on `rq/<name>Request` and a reply reader on `rr/<name>Reply`, in the layout of
//! the server's middleware ([`Layout`]).
//!
//! The server is the reader matched last with the request writer whose
//! participant also has a reply writer; a new one (another GUID) is a restarted
//! server, even before the old one's lease has run out. Its layout follows its vendor, which Fast DDS writes in the
//! first two bytes of every GUID prefix (eProsima's vendor id, 0x01 0x0f):
//! rmw_fastrtps's related sample identity for Fast DDS, rmw_cyclonedds's 16-byte
//! header for any other.

use std::collections::HashSet;

use rustdds::no_key::{DataWriter, SimpleDataReader};
use rustdds::{
    DataWriterStatus, GUID, QosPolicies, RTPSEntity, RepresentationIdentifier, SampleIdentity,
    SequenceNumber, StatusEvented, Timestamp, TopicKind, WriteOptionsBuilder, policy,
};

use isochron_dds::{RosNode, keep_last};
use ros2_client::dds::DEFAULT_PUBLISHER_QOS;

use super::MAX_BLOCKING;
use super::wire::{Raw, RawReply, RawSample};
use crate::error::{RosError, topic_name};
use crate::msgs::DynamicEdges;
use crate::route_server::Caller;
use crate::spec::RosType;

/// Requests and replies DDS keeps (rmw's default for services: keep last 10).
const HISTORY: i32 = 10;
/// eProsima's RTPS vendor id, the first two bytes of a Fast DDS GUID prefix.
const FAST_DDS_VENDOR: [u8; 2] = [0x01, 0x0f];

/// How a server's middleware carries a request's identity.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layout {
    /// rmw_fastrtps: the bare request, with a related sample identity naming the
    /// client's reply reader; the reply's names the request.
    FastDds,
    /// rmw_cyclonedds: the client's id and the call's sequence number before
    /// the fields, echoed before the reply's.
    Cyclone,
}

impl Layout {
    /// The layout of the middleware whose endpoint is `guid`.
    pub fn of(guid: GUID) -> Layout {
        if guid.prefix.as_ref()[..2] == FAST_DDS_VENDOR {
            Layout::FastDds
        } else {
            Layout::Cyclone
        }
    }
}

/// The bridge's DDS client of one `DynamicEdges` service.
pub struct DdsCaller {
    writer: DataWriter<RawReply, Raw>,
    reader: SimpleDataReader<RawSample, Raw>,
    participant: rustdds::DomainParticipant,
    reply_topic: String,
    /// Readers matched with the request writer, the newest last.
    matched: Vec<GUID>,
    /// The server's request reader and its layout, while one is seen.
    server: Option<(GUID, Layout)>,
    /// rmw_cyclonedds's client id: the request writer's GUID, folded.
    client_id: u64,
    /// The last sequence number of the Cyclone layout.
    sequence: i64,
}

impl DdsCaller {
    /// The client of the service `name` of type `ty` on `ros`'s participant; a
    /// relative name is in the root namespace, where the route server's node
    /// (not the bridge's) resolves it.
    pub fn start(ros: &RosNode, name: &str, ty: &RosType) -> Result<DdsCaller, RosError> {
        let absolute = if name.starts_with('/') {
            name.to_string()
        } else {
            format!("/{name}")
        };
        let parsed = topic_name(&absolute)?;
        let fail = |e: String| ros.error(format!("creating the client of {parsed}: {e}"));
        let participant = ros.context().domain_participant();
        let reliable = policy::Reliability::Reliable {
            max_blocking_time: rustdds::Duration::from_std(MAX_BLOCKING),
        };
        let qos = keep_last(reliable, policy::Durability::Volatile, HISTORY);
        let topic = |(prefix, suffix, part): (&str, &str, &str)| {
            participant
                .create_topic(
                    parsed.to_dds_name(prefix, ros.name(), suffix),
                    format!("{}{part}_", ty.dds_name),
                    &qos,
                    TopicKind::NoKey,
                )
                .map_err(|e| fail(format!("{e}")))
        };
        let request_topic = topic(("rq", "Request", "Request"))?;
        let reply_topic = topic(("rr", "Reply", "Response"))?;
        let publisher = participant
            .create_publisher(&QosPolicies::from(DEFAULT_PUBLISHER_QOS))
            .map_err(|e| fail(format!("{e}")))?;
        let subscriber = participant
            .create_subscriber(&QosPolicies::default())
            .map_err(|e| fail(format!("{e}")))?;
        let writer = publisher
            .create_datawriter_no_key::<RawReply, Raw>(&request_topic, Some(qos.clone()))
            .map_err(|e| fail(format!("{e}")))?;
        let reader = subscriber
            .create_simple_datareader_no_key::<RawSample, Raw>(&reply_topic, Some(qos))
            .map_err(|e| fail(format!("{e}")))?;
        let guid = writer.guid().to_bytes();
        let client_id = u64::from_le_bytes(guid[..8].try_into().unwrap_or_default())
            ^ u64::from_le_bytes(guid[8..].try_into().unwrap_or_default());
        Ok(DdsCaller {
            writer,
            reader,
            participant: participant.clone(),
            reply_topic: rustdds::TopicDescription::name(&reply_topic),
            matched: Vec::new(),
            server: None,
            client_id,
            sequence: 0,
        })
    }

    /// Follows which readers the request writer is matched with (every pass, so
    /// that the writer's status queue never fills up).
    fn refresh(&mut self) {
        while let Some(status) = self.writer.try_recv_status() {
            if let DataWriterStatus::PublicationMatched {
                current, reader, ..
            } = status
            {
                self.matched.retain(|r| *r != reader);
                if current.count_change() > 0 {
                    self.matched.push(reader);
                }
            }
        }
    }
}

impl Caller for DdsCaller {
    /// The newest matched request reader whose participant also has a writer of
    /// the reply topic.
    fn server(&mut self) -> Option<u128> {
        self.refresh();
        let repliers: HashSet<_> = self
            .participant
            .discovered_writers()
            .into_iter()
            .filter(|w| w.publication_topic_data.topic_name == self.reply_topic)
            .map(|w| w.publication_topic_data.key.prefix)
            .collect();
        let server = self
            .matched
            .iter()
            .rev()
            .find(|r| repliers.contains(&r.prefix))
            .copied();
        self.server = server.map(|g| (g, Layout::of(g)));
        server.map(|g| u128::from_be_bytes(g.to_bytes()))
    }

    fn call(&mut self, request: &DynamicEdges) -> Result<u64, String> {
        let (_, layout) = self.server.ok_or("no server")?;
        let cdr = rustdds::serialization::to_vec::<_, byteorder::LittleEndian>(request)
            .map_err(|e| format!("encoding: {e}"))?;
        let mut options = WriteOptionsBuilder::new().source_timestamp(Timestamp::now());
        let bytes = match layout {
            Layout::FastDds => {
                options = options.related_sample_identity(SampleIdentity {
                    writer_guid: self.reader.guid(),
                    sequence_number: SequenceNumber::UNKNOWN,
                });
                cdr
            }
            Layout::Cyclone => {
                self.sequence += 1;
                let mut bytes = Vec::with_capacity(16 + cdr.len());
                bytes.extend(self.client_id.to_le_bytes());
                bytes.extend(self.sequence.to_le_bytes());
                bytes.extend(cdr);
                bytes
            }
        };
        let written = self
            .writer
            .write_with_options(RawReply(bytes), options.build())
            .map_err(|e| e.forget_data().to_string())?;
        Ok(match layout {
            Layout::FastDds => i64::from(written.sequence_number) as u64,
            Layout::Cyclone => self.sequence as u64,
        })
    }

    /// Replies to this client: by their related sample identity (Fast DDS, which
    /// names the reply reader or the request writer) or their header (Cyclone).
    fn answers(&mut self) -> Vec<(u64, bool)> {
        self.reader.drain_read_notifications();
        let (reader, writer) = (self.reader.guid(), self.writer.guid());
        let mut answers = Vec::new();
        while let Ok(Some(sample)) = self.reader.try_take_one() {
            let raw = &sample.sample;
            let little = match raw.encoding {
                RepresentationIdentifier::CDR_LE => true,
                RepresentationIdentifier::CDR_BE => false,
                _ => continue,
            };
            let answer = match sample.related_sample_identity() {
                Some(r) if r.writer_guid == reader || r.writer_guid == writer => raw
                    .bytes
                    .first()
                    .map(|&success| (i64::from(r.sequence_number) as u64, success != 0)),
                Some(_) => None,
                None => cyclone_answer(&raw.bytes, little, self.client_id),
            };
            answers.extend(answer);
        }
        answers
    }
}

/// A reply in rmw_cyclonedds's layout for client `client_id`: its sequence
/// number and `success` (the first byte of the fields, a CDR `bool`).
fn cyclone_answer(bytes: &[u8], little: bool, client_id: u64) -> Option<(u64, bool)> {
    let header: [u8; 16] = bytes.get(..16)?.try_into().ok()?;
    let (id, seq) = header.split_at(8);
    let (id, seq) = (id.try_into().ok()?, seq.try_into().ok()?);
    let (id, seq) = if little {
        (u64::from_le_bytes(id), i64::from_le_bytes(seq))
    } else {
        (u64::from_be_bytes(id), i64::from_be_bytes(seq))
    };
    let success = *bytes.get(16)?;
    (id == client_id).then_some((seq as u64, success != 0))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_layout_follows_the_vendor_in_the_guid_prefix() {
        let guid = |first: [u8; 2]| {
            let mut bytes = [7u8; 16];
            bytes[..2].copy_from_slice(&first);
            GUID::from_bytes(bytes)
        };
        assert_eq!(Layout::of(guid([0x01, 0x0f])), Layout::FastDds);
        assert_eq!(Layout::of(guid([0x01, 0x10])), Layout::Cyclone);
        assert_eq!(Layout::of(guid([0xab, 0xcd])), Layout::Cyclone);
    }

    #[test]
    fn cyclone_replies_are_matched_by_their_header() {
        let mut reply = Vec::new();
        reply.extend(42u64.to_le_bytes());
        reply.extend(3i64.to_le_bytes());
        reply.push(1);
        assert_eq!(cyclone_answer(&reply, true, 42), Some((3, true)));
        assert_eq!(cyclone_answer(&reply, true, 41), None, "another client's");
        assert_eq!(cyclone_answer(&reply[..16], true, 42), None, "no fields");
        reply[16] = 0;
        assert_eq!(cyclone_answer(&reply, true, 42), Some((3, false)));
    }
}
