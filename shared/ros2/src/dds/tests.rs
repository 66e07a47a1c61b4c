use std::time::Instant;

use byteorder::LittleEndian;
use rustdds::serialization::{from_bytes, to_vec};
use rustdds::{RepresentationIdentifier, SampleIdentity};

use super::wire::{RawSample, ReplyTo, read_request, reply_bytes};
use super::*;
use crate::msgs::PlanNowResponse;
use crate::plan::{Body, plan_request};
use isochron_planning::query::PlanKind;

/// A GUID whose last byte (the entity kind) is `kind`: 0x03 a writer, 0x04 a
/// reader (no key), under the participant `prefix`.
fn guid(prefix: u8, kind: u8) -> GUID {
    let mut b = [prefix; 16];
    b[12..].copy_from_slice(&[0, 0, 1, kind]);
    GUID::from_bytes(b)
}

/// `PlanOffline` request fields laid out by hand (little-endian): the route
/// with its NUL, 600, 720, 30, 7.
fn offline_body(route: &[u8], nul: bool) -> Vec<u8> {
    let mut b = Vec::new();
    b.extend((route.len() as u32 + u32::from(nul)).to_le_bytes());
    b.extend(route);
    if nul {
        b.push(0);
    }
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

/// The planner's request of a body read from DDS.
fn decoded(body: &Result<Body, String>) -> Result<(), String> {
    let body = body.as_ref().map_err(Clone::clone)?;
    plan_request(PlanKind::Offline, &body.cdr, body.big_endian).map(drop)
}

#[test]
fn the_layout_comes_from_the_related_sample_identity() {
    let writer = guid(7, 0x03);
    let at = Instant::now();
    // rmw_cyclonedds: the header, then the fields.
    let mut bytes = 0x1122_3344_5566_7788u64.to_le_bytes().to_vec();
    bytes.extend(42i64.to_le_bytes());
    bytes.extend(offline_body(b"dock", true));
    let (reply, body) =
        read_request(writer, SequenceNumber::from(5), None, &raw(bytes), at).unwrap();
    assert_eq!(
        reply.reply_to,
        ReplyTo::Cyclone {
            client: 0x1122_3344_5566_7788,
            sequence: 42
        }
    );
    assert_eq!(reply.client, writer);
    assert_eq!(body.as_ref().unwrap().cdr, offline_body(b"dock", true));
    assert!(decoded(&body).is_ok(), "{body:?}");

    // rmw_fastrtps: the bare fields; the reply names the client's reader and
    // the request's sequence number.
    let reader = guid(7, 0x04);
    let related = SampleIdentity {
        writer_guid: reader,
        sequence_number: SequenceNumber::UNKNOWN,
    };
    let (reply, body) = read_request(
        writer,
        SequenceNumber::from(5),
        Some(related),
        &raw(offline_body(b"dock", true)),
        at,
    )
    .unwrap();
    assert_eq!(
        reply.reply_to,
        ReplyTo::FastDds(SampleIdentity {
            writer_guid: reader,
            sequence_number: SequenceNumber::from(5)
        })
    );
    assert_eq!(reply.client, reader);
    assert!(decoded(&body).is_ok());

    // A malformed body with an identity is answered; without one it cannot be.
    let (_, body) = read_request(
        writer,
        SequenceNumber::from(6),
        Some(related),
        &raw(offline_body(b"dock", false)),
        at,
    )
    .unwrap();
    assert!(decoded(&body).is_err());
    let short = read_request(
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
    let (_, body) =
        read_request(writer, SequenceNumber::from(8), Some(related), &xcdr2, at).unwrap();
    assert!(body.unwrap_err().contains("XCDR1"));
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
        &body,
    );
    assert_eq!(&cyclone[..8], &9u64.to_le_bytes());
    assert_eq!(&cyclone[8..16], &(-2i64).to_le_bytes());
    assert_eq!(&cyclone[16..], &body[..]);
    let fast = reply_bytes(
        &ReplyTo::FastDds(SampleIdentity {
            writer_guid: guid(1, 4),
            sequence_number: SequenceNumber::from(3),
        }),
        &body,
    );
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

#[test]
fn topics_keep_their_qos() {
    use rustdds::policy::{Durability, History, Reliability};
    let latched = dds_qos(crate::spec::LATCHED);
    assert!(matches!(
        latched.reliability(),
        Some(Reliability::Reliable { .. })
    ));
    assert_eq!(latched.durability(), Some(Durability::TransientLocal));
    assert_eq!(latched.history(), Some(History::KeepLast { depth: 1 }));
    let stream = dds_qos(crate::spec::STREAM);
    assert_eq!(stream.durability(), Some(Durability::Volatile));
    assert_eq!(stream.history(), Some(History::KeepLast { depth: 10 }));
    assert_eq!(stream.resource_limits().map(|r| r.max_samples), Some(10));
}
