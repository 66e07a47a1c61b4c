//! A planning request and its reply as bytes: the raw samples RustDDS passes
//! through, the two layouts of the ROS 2 middlewares (rmw_cyclonedds's header,
//! rmw_fastrtps's related sample identity), CDR decoding and checks, and the
//! responses built from the planner's answer.

use std::time::Instant;

use byteorder::{BigEndian, LittleEndian};
use rustdds::bytes::Bytes;
use rustdds::no_key::{Decode, DefaultDecoder, DeserializerAdapter, SerializerAdapter};
use rustdds::serialization::{from_bytes, to_vec};
use rustdds::{GUID, RepresentationIdentifier, SampleIdentity, SequenceNumber};
use serde::Serialize;
use serde::de::DeserializeOwned;

use isochron_planning::plan_service::{offline_plan_of, ranking_of};
use isochron_planning::query::{
    PLAN_FLAG_INFINITE, PLAN_MAX_ROUTES, PLAN_NAME_LEN, PlanKind, PlanRequest, PlanResponse,
    PlanStatus,
};

use isochron_ros2::msgs::{
    CostPoint, PlanNowRequest, PlanNowResponse, PlanOfflineRequest, PlanOfflineResponse, RouteCost,
    Window as WindowMsg,
};

/// Largest request body decoded: a `PlanNow` of 16 names of 32 bytes is < 700.
pub(super) const MAX_REQUEST_BYTES: usize = 4096;
/// rmw_cyclonedds's request header: client id and sequence number, 8 bytes each.
const CYCLONE_HEADER: usize = 16;

/// A sample's bytes as they came off the wire (after the 4-byte encapsulation
/// header) and how they are encoded.
#[derive(Debug, Clone)]
pub struct RawSample {
    pub(super) bytes: Vec<u8>,
    pub(super) encoding: RepresentationIdentifier,
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
pub struct RawReply(pub(super) Vec<u8>);

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
pub(crate) fn plan_request(
    kind: PlanKind,
    body: &[u8],
    big_endian: bool,
) -> Result<PlanRequest, String> {
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
pub(super) enum ReplyTo {
    /// rmw_cyclonedds: the client's id and sequence number, before the fields.
    Cyclone { client: u64, sequence: i64 },
    /// rmw_fastrtps: the reply's related sample identity.
    FastDds(SampleIdentity),
}

/// One request waiting for its answer.
#[derive(Debug, Clone)]
pub(super) struct Pending {
    pub(super) reply_to: ReplyTo,
    /// The reader the reply is for (Fast DDS), else the request writer: any
    /// reader of its participant.
    pub(super) client: GUID,
    /// The request, or why it is malformed.
    pub(super) request: Result<PlanRequest, String>,
    pub(super) arrived: Instant,
}

/// Reads one request sample: who to answer and what, or why it cannot be answered.
pub(super) fn read_request(
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
pub(super) fn reply_bytes<T: Serialize>(
    reply_to: &ReplyTo,
    response: &T,
) -> Result<Vec<u8>, String> {
    let mut bytes = Vec::new();
    if let ReplyTo::Cyclone { client, sequence } = reply_to {
        bytes.extend(client.to_le_bytes());
        bytes.extend(sequence.to_le_bytes());
    }
    // The header is 16 bytes: the fields' alignment is the same after it.
    bytes.extend(to_vec::<T, LittleEndian>(response).map_err(|e| e.to_string())?);
    Ok(bytes)
}

/// A `PlanOffline` response from the planner's answer.
pub(crate) fn offline_response(r: &PlanResponse) -> PlanOfflineResponse {
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
pub(crate) fn now_response(r: &PlanResponse) -> PlanNowResponse {
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
