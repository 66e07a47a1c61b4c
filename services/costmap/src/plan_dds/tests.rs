use byteorder::LittleEndian;
use rustdds::serialization::{from_bytes, to_vec};
use rustdds::{RepresentationIdentifier, SampleIdentity};

use super::request::{MAX_REQUEST_BYTES, plan_request};
use super::*;
use isochron_ros2::msgs::{CdrString, PlanNowResponse};

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
    let err = plan_request(PlanKind::Offline, &offline_body(b"dock", false), false).unwrap_err();
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
