//! A planning request and its reply as DDS bytes: the raw samples RustDDS passes
//! through, and the two layouts of the ROS 2 middlewares (rmw_cyclonedds's
//! header, rmw_fastrtps's related sample identity).

use std::time::Instant;

use rustdds::bytes::Bytes;
use rustdds::no_key::{Decode, DefaultDecoder, DeserializerAdapter, SerializerAdapter};
use rustdds::{GUID, RepresentationIdentifier, SampleIdentity, SequenceNumber};

use super::Reply;
use crate::plan::Body;

/// rmw_cyclonedds's request header: client id and sequence number, 8 bytes each.
const CYCLONE_HEADER: usize = 16;

/// A sample's bytes as they came off the wire (after the 4-byte encapsulation
/// header) and how they are encoded.
#[derive(Debug, Clone)]
pub struct RawSample {
    pub(crate) bytes: Vec<u8>,
    pub(crate) encoding: RepresentationIdentifier,
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
pub struct RawReply(pub(crate) Vec<u8>);

impl SerializerAdapter<RawReply> for Raw {
    type Error = RawError;

    fn output_encoding() -> RepresentationIdentifier {
        RepresentationIdentifier::CDR_LE
    }

    fn to_bytes(value: &RawReply) -> Result<Bytes, RawError> {
        Ok(Bytes::copy_from_slice(&value.0))
    }
}

/// Where a reply goes, in the layout of its request.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum ReplyTo {
    /// rmw_cyclonedds: the client's id and sequence number, before the fields.
    Cyclone { client: u64, sequence: i64 },
    /// rmw_fastrtps: the reply's related sample identity.
    FastDds(SampleIdentity),
}

/// Reads one request sample of `writer`: where its reply goes and its fields
/// (or why they cannot be read, to be answered), or why it cannot be answered.
pub(crate) fn read_request(
    writer: GUID,
    sequence: SequenceNumber,
    related: Option<SampleIdentity>,
    raw: &RawSample,
    arrived: Instant,
) -> Result<(Reply, Result<Body, String>), String> {
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
    let body = match big_endian {
        Some(big_endian) => Ok(Body {
            cdr: body.to_vec(),
            big_endian,
        }),
        None => Err(format!(
            "a request in {:?}: expected plain CDR (XCDR1), as ROS 2 middlewares send",
            raw.encoding
        )),
    };
    let reply = Reply {
        reply_to,
        client,
        arrived,
    };
    Ok((reply, body))
}

/// The bytes of a reply to `reply_to`: rmw_cyclonedds's header if its request had
/// one, then `cdr`, the response's fields in little-endian CDR.
pub(crate) fn reply_bytes(reply_to: &ReplyTo, cdr: &[u8]) -> Vec<u8> {
    let mut bytes = Vec::with_capacity(CYCLONE_HEADER + cdr.len());
    if let ReplyTo::Cyclone { client, sequence } = reply_to {
        bytes.extend(client.to_le_bytes());
        bytes.extend(sequence.to_le_bytes());
    }
    // The header is 16 bytes: the fields' alignment is the same after it.
    bytes.extend(cdr);
    bytes
}
