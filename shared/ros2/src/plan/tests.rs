use std::cell::RefCell;

use isochron_planning::query::{PlanGraphPath, PlanStatus};
use isochron_runtime::topology::StageKind;

use super::*;
use crate::msgs::{CdrString, PlanNowResponse};

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

/// `PlanNow` request fields of `routes` (little-endian).
fn now_body(routes: &[&[u8]]) -> Vec<u8> {
    let mut b = (routes.len() as u32).to_le_bytes().to_vec();
    for r in routes {
        cdr_str(&mut b, r, true);
    }
    b
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
    let le = now_body(&[b"a", b"bc"]);
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

/// `PlanGraph` request fields laid out by hand: from, to, start, end, step (uint16)
/// and the weekday (uint8), little-endian or big-endian.
fn graph_body(fields: [u16; 5], weekday: u8, big_endian: bool) -> Vec<u8> {
    let mut b = Vec::new();
    for v in fields {
        b.extend(if big_endian {
            v.to_be_bytes()
        } else {
            v.to_le_bytes()
        });
    }
    b.push(weekday);
    b
}

#[test]
fn plan_graph_requests_and_responses_convert() {
    for big_endian in [false, true] {
        let body = graph_body([1, 3, 480, 660, 15], 0, big_endian);
        let r = plan_request(PlanKind::Graph, &body, big_endian).unwrap();
        assert_eq!(
            (
                r.from_node,
                r.to_node,
                r.start_minute,
                r.end_minute,
                r.step_min
            ),
            (1, 3, 480, 660, 15)
        );
        assert_eq!((r.weekday, r.route_count), (0, 0));
    }
    let err = plan_request(
        PlanKind::Graph,
        &graph_body([1, 3, 2000, 660, 15], 0, false),
        false,
    )
    .unwrap_err();
    assert!(err.contains("outside the day"), "{err}");
    assert!(
        plan_request(
            PlanKind::Graph,
            &graph_body([1, 3, 0, 60, 5], 9, false),
            false
        )
        .is_err()
    );
    assert!(plan_request(PlanKind::Graph, &[1, 0, 3], false).is_err());

    let mut answer = PlanResponse::new(PlanKind::Graph as u32, PlanStatus::Ok, "");
    answer.curve_start_minute = 480;
    answer.curve_step_min = 15;
    answer.curve_len = 2;
    answer.curve[..2].copy_from_slice(&[3.0, 8.0]);
    answer.window_count = 1;
    answer.windows[0].start_minute = 480;
    answer.windows[0].end_minute = 495;
    answer.windows[0].cost = 3.0;
    let mut path = PlanGraphPath::EMPTY;
    path.departure_minute = 480;
    path.node_count = 3;
    path.edge_count = 2;
    path.nodes[..3].copy_from_slice(&[1, 2, 3]);
    path.edges[..2].copy_from_slice(&[11, 12]);
    path.cost = 3.0;
    answer.graph_windows[0] = path;
    answer.graph_best = path;
    answer.graph_baseline = PlanGraphPath {
        cost: 199.0,
        ..path
    };
    let msg = graph_response(&answer);
    assert_eq!(msg.status, 0);
    assert_eq!(msg.curve.len(), 2);
    assert_eq!((msg.curve[1].minute, msg.curve[1].cost), (495, 8.0));
    assert_eq!(msg.windows.len(), 1);
    assert_eq!(msg.window_paths.len(), 1);
    assert_eq!(msg.best.nodes, [1, 2, 3]);
    assert_eq!(msg.best.edges, [11, 12]);
    assert_eq!(msg.baseline.cost, 199.0);
    // Anything but OK carries the status and the message alone.
    let failed = PlanResponse::new(PlanKind::Graph as u32, PlanStatus::NoPath, "no way");
    let msg = graph_response(&failed);
    assert_eq!((msg.status, msg.message.as_str()), (6, "no way"));
    assert!(msg.windows.is_empty() && msg.best.nodes.is_empty());
}

/// A transport in memory: what it will hand over, and the replies sent.
#[derive(Default)]
struct Fake {
    arriving: Vec<Taken<char, u32>>,
    /// Replies not due yet.
    held: Vec<u32>,
    sent: RefCell<Vec<(u32, PlanNowResponse)>>,
}

impl Endpoint for Fake {
    type Client = char;
    type Reply = u32;
    const WARNINGS: WarningKinds = WarningKinds {
        unreadable: "fake unreadable",
        unanswerable: "fake unanswerable",
        dropped: "fake dropped",
        reply_failed: "fake reply failed",
    };

    fn take(&mut self) -> Vec<Taken<char, u32>> {
        std::mem::take(&mut self.arriving)
    }

    fn due(&self, reply: &u32, _: Instant) -> bool {
        !self.held.contains(reply)
    }

    fn reply(&self, reply: u32, cdr: &[u8]) -> Result<(), String> {
        let (response, _) =
            rustdds::serialization::from_bytes::<PlanNowResponse, LittleEndian>(cdr)
                .map_err(|e| e.to_string())?;
        self.sent.borrow_mut().push((reply, response));
        Ok(())
    }
}

fn request(client: char, reply: u32) -> Taken<char, u32> {
    Taken::Request {
        client,
        reply,
        body: Ok(Body {
            cdr: now_body(&[b"west"]),
            big_endian: false,
        }),
    }
}

/// Serves `fake`'s `PlanNow` once; the replies it sent in order, and the counts.
fn serve_once(services: &mut PlanServices<Fake>, cx: &mut Context) -> (usize, Vec<(u32, u8)>) {
    let mut answer = |kind: PlanKind, _: &PlanRequest| {
        PlanResponse::new(kind as u32, PlanStatus::UnknownRoute, "no such route")
    };
    let n = services.serve(cx, &mut answer);
    let sent = services.services[0]
        .endpoint
        .sent
        .take()
        .into_iter()
        .map(|(reply, response)| (reply, response.status))
        .collect();
    (n, sent)
}

#[test]
fn one_loop_answers_round_robin_and_counts_what_it_cannot() {
    let mut cx = Context::new(StageKind::Costmap, "", None);
    let mut fake = Fake::default();
    for k in 0..5 {
        fake.arriving.push(request('f', k));
    }
    fake.arriving.push(request('r', 100));
    fake.arriving.push(Taken::Request {
        client: 'm',
        reply: 200,
        body: Err("a request in CDR2_LE".into()),
    });
    fake.arriving
        .push(Taken::Unanswerable("no identity".into()));
    fake.arriving.push(Taken::Lost {
        n: 3,
        client: None,
        why: "overwritten",
    });
    let mut services = PlanServices::new(vec![Service::new(
        PlanKind::Now,
        "/isochron/plan_now".into(),
        fake,
    )]);
    let (n, sent) = serve_once(&mut services, &mut cx);
    // Two of the flooding client per pass, the others in their turn, the
    // malformed one with status 1.
    assert_eq!(n, 4);
    let unknown = PlanStatus::UnknownRoute as u8;
    let bad = PlanStatus::BadRequest as u8;
    assert_eq!(
        sent,
        [(0, unknown), (100, unknown), (200, bad), (1, unknown)]
    );
    assert_eq!(
        services.counts(),
        PlanCounts {
            answered: 4,
            rejected: 2,
            dropped: 3
        }
    );
    let (n, sent) = serve_once(&mut services, &mut cx);
    assert_eq!((n, sent), (2, vec![(2, unknown), (3, unknown)]));
}

#[test]
fn a_client_beyond_its_share_is_dropped_and_replies_wait_until_due() {
    let mut cx = Context::new(StageKind::Costmap, "", None);
    let mut fake = Fake::default();
    for k in 0..(PER_CLIENT as u32 + 3) {
        fake.arriving.push(request('f', k));
    }
    fake.held = vec![0];
    let mut services = PlanServices::new(vec![Service::new(
        PlanKind::Now,
        "/isochron/plan_now".into(),
        fake,
    )]);
    let (n, sent) = serve_once(&mut services, &mut cx);
    // The client's head is not due: nothing of it goes out.
    assert_eq!((n, sent.len()), (0, 0));
    assert_eq!(services.counts().dropped, 3);
    services.services[0].endpoint.held.clear();
    let (n, sent) = serve_once(&mut services, &mut cx);
    assert_eq!(n, CLIENT_ANSWERS_PER_PASS);
    assert_eq!(sent[0].0, 0);
}
