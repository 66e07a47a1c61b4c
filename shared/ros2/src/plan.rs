//! The planning services over ROS 2, `isochron_msgs/srv/PlanOffline`, `PlanNow`
//! and `PlanGraph` (ros/isochron_msgs), answered with what answers `<prefix>/plan` over
//! iceoryx2: one loop for every transport.
//!
//! A transport's side of a service is an [`Endpoint`]: it takes what arrived
//! (each request with its client and where its reply goes), says whether a
//! reply can go out yet, and sends one. The DDS endpoint ([`crate::dds`]) reads
//! the request layouts of rmw_cyclonedds and rmw_fastrtps, the Zenoh endpoint
//! ([`crate::zenoh`]) rmw_zenoh's; the rest is [`Service`], the same for both:
//!
//! Requests are decoded by the CDR rules ([`crate::msgs::CdrString`]): a string's
//! length counts its NUL, and a string without one is malformed (not cut short).
//! A malformed request gets `STATUS_BAD_REQUEST` (1) with the reason and is
//! counted as rejected; one that cannot be answered (no identity) is counted
//! only.
//!
//! Requests are queued per client and answered round robin across clients
//! ([`crate::fair`]): each client may have [`PER_CLIENT`] requests queued, all
//! together [`QUEUE`], and each service answers at most [`ANSWERS_PER_PASS`] per
//! pass of the bridge's loop, [`CLIENT_ANSWERS_PER_PASS`] of one client. A flood
//! beyond its client's share is dropped and counted, as are the requests the
//! transport lost before the bridge took them; a client with one request
//! outstanding is answered within one round, whatever another client sends.
//! The counts are kept per transport ([`PlanServices`]).

mod convert;

use std::collections::HashMap;
use std::fmt::Display;
use std::hash::Hash;
use std::time::Instant;

use byteorder::LittleEndian;
use rustdds::serialization::to_vec;

use isochron_planning::query::{PlanKind, PlanRequest, PlanResponse, PlanStatus};
use isochron_runtime::stage::Context;

use crate::fair::{FairQueue, Pushed};
pub use convert::{
    MAX_REQUEST_BYTES, graph_response, now_response, offline_response, plan_request,
};

/// Requests a service holds for an answer, of all clients together; past it a
/// newcomer displaces the newest request of the longest lane, if that is longer
/// than the newcomer's ([`crate::fair`]).
pub const QUEUE: usize = 64;
/// Requests one client may have queued; more are dropped and counted. A ROS 2
/// client waits for each answer: it has one or two queued.
pub const PER_CLIENT: usize = 8;
/// Requests a service answers per pass of the loop.
pub const ANSWERS_PER_PASS: usize = 16;
/// Requests of one client a service answers per pass of the loop: what a flood
/// costs the planner, and the burst of replies every client's reply reader
/// receives (ROS 2 clients share the reply topic, and keep the last 10), stay
/// small.
pub const CLIENT_ANSWERS_PER_PASS: usize = 2;

/// The totals of the planning services since the bridge started.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct PlanCounts {
    /// Requests answered (any status).
    pub answered: u64,
    /// Malformed requests: answered with `STATUS_BAD_REQUEST` when they carried an
    /// identity, else only counted.
    pub rejected: u64,
    /// Requests dropped: beyond their client's share of the queue, or lost by
    /// the transport before the bridge took them.
    pub dropped: u64,
}

impl std::ops::Add for PlanCounts {
    type Output = PlanCounts;

    fn add(self, other: PlanCounts) -> PlanCounts {
        PlanCounts {
            answered: self.answered + other.answered,
            rejected: self.rejected + other.rejected,
            dropped: self.dropped + other.dropped,
        }
    }
}

/// A request's fields: CDR in the byte order its encapsulation says.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Body {
    /// The fields.
    pub cdr: Vec<u8>,
    /// Big-endian (else little-endian).
    pub big_endian: bool,
}

/// What an [`Endpoint`] took from its transport.
#[derive(Debug)]
pub enum Taken<C, R> {
    /// A request of `client`, whose reply goes to `reply`: its fields, or why
    /// they cannot be read (answered with status 1).
    Request {
        /// Its sender: the lane it joins.
        client: C,
        /// Where its reply goes.
        reply: R,
        /// Its fields.
        body: Result<Body, String>,
    },
    /// A request that cannot be answered (its identity cannot be read), and
    /// why: counted as rejected.
    Unanswerable(String),
    /// A sample that cannot be read at all, and why: counted as rejected.
    Unreadable(String),
    /// Requests the transport lost before they were taken (of `client`, if
    /// known): counted as dropped.
    Lost {
        /// How many.
        n: u64,
        /// Whose.
        client: Option<C>,
        /// Why.
        why: &'static str,
    },
}

/// The kinds of a transport's warnings, each rate-limited apart.
#[derive(Debug, Clone, Copy)]
pub struct WarningKinds {
    /// A sample that cannot be read.
    pub unreadable: &'static str,
    /// A request that cannot be answered.
    pub unanswerable: &'static str,
    /// Requests dropped.
    pub dropped: &'static str,
    /// A reply that could not be sent.
    pub reply_failed: &'static str,
}

/// A transport's end of one planning service: where its requests come from and
/// its replies go.
pub trait Endpoint {
    /// Who sent a request: the lane of the fair queue it joins.
    type Client: Clone + Eq + Hash + Display;
    /// Where a reply goes.
    type Reply;
    /// The kinds of this transport's warnings.
    const WARNINGS: WarningKinds;

    /// What arrived since the last call, oldest first. Never blocks.
    fn take(&mut self) -> Vec<Taken<Self::Client, Self::Reply>>;

    /// Catches up with the transport before the replies of a pass are chosen.
    fn refresh(&mut self) {}

    /// True if the reply to `reply` can go out `now` (else it waits its turn).
    fn due(&self, _reply: &Self::Reply, _now: Instant) -> bool {
        true
    }

    /// Sends `cdr`, a response's fields in little-endian CDR, to `reply`.
    fn reply(&self, reply: Self::Reply, cdr: &[u8]) -> Result<(), String>;
}

/// A request waiting for its answer.
struct Pending<R> {
    reply: R,
    /// The request, or why it is malformed.
    request: Result<PlanRequest, String>,
}

/// One planning service on one transport: its endpoint and its queue.
pub struct Service<E: Endpoint> {
    kind: PlanKind,
    /// Its name in log lines.
    label: String,
    endpoint: E,
    queue: FairQueue<E::Client, Pending<E::Reply>>,
}

impl<E: Endpoint> Service<E> {
    /// The service of `kind` on `endpoint`, called `label` in log lines.
    pub fn new(kind: PlanKind, label: String, endpoint: E) -> Self {
        Service {
            kind,
            label,
            endpoint,
            queue: FairQueue::new(PER_CLIENT, QUEUE),
        }
    }

    /// Moves what the endpoint took into the queue; counts and warns of what
    /// cannot be queued.
    fn intake(&mut self, cx: &mut Context, counts: &mut PlanCounts) {
        let label = &self.label;
        for taken in self.endpoint.take() {
            let (client, reply, body) = match taken {
                Taken::Request {
                    client,
                    reply,
                    body,
                } => (client, reply, body),
                Taken::Unanswerable(why) => {
                    counts.rejected += 1;
                    cx.health.rejected();
                    cx.warnings.warn(E::WARNINGS.unanswerable, || {
                        format!("{label}: a malformed request that cannot be answered: {why}")
                    });
                    continue;
                }
                Taken::Unreadable(e) => {
                    counts.rejected += 1;
                    cx.health.rejected();
                    cx.warnings.warn(E::WARNINGS.unreadable, || {
                        format!("{label}: a request that cannot be read: {e}")
                    });
                    continue;
                }
                Taken::Lost { n, client, why } => {
                    self.dropped(cx, counts, (n, client), why);
                    continue;
                }
            };
            let request = body.and_then(|b| plan_request(self.kind, &b.cdr, b.big_endian));
            let pending = Pending { reply, request };
            let (victim, why) = match self.queue.push(client.clone(), pending) {
                Pushed::Queued => continue,
                Pushed::ClientFull => (client, "its client's queue is full"),
                Pushed::Full => (client, "the queue is full"),
                Pushed::Displaced { client, .. } => (
                    client,
                    "displaced from the longest queue by another client's",
                ),
            };
            self.dropped(cx, counts, (1, Some(victim)), why);
        }
    }

    /// Counts `n` dropped requests of `client` (if known), with a rate-limited
    /// warning saying `why`.
    fn dropped(
        &self,
        cx: &mut Context,
        counts: &mut PlanCounts,
        (n, client): (u64, Option<E::Client>),
        why: &str,
    ) {
        counts.dropped += n;
        cx.health.dropped(n);
        let (label, queue, in_all) = (&self.label, &self.queue, counts.dropped);
        cx.warnings.warn(E::WARNINGS.dropped, || {
            let (whose, of_client) = match &client {
                Some(c) => {
                    let of_client = queue.counts(c).map_or(n, |l| l.dropped.max(n));
                    (
                        format!(" of client {c}"),
                        format!("{of_client} of its requests and "),
                    )
                }
                None => (String::new(), String::new()),
            };
            format!(
                "{label}: {n} request(s){whose} dropped, {why} ({PER_CLIENT} per client, {QUEUE} in all, {CLIENT_ANSWERS_PER_PASS} of a client answered per pass, round robin over {} client(s); {of_client}{in_all} in all dropped so far)",
                queue.clients(),
            )
        });
    }

    /// Answers the queue's due requests with `answer`, round robin, at most
    /// [`ANSWERS_PER_PASS`] and [`CLIENT_ANSWERS_PER_PASS`] of one client;
    /// returns how many.
    fn answer(
        &mut self,
        cx: &mut Context,
        counts: &mut PlanCounts,
        answer: &mut dyn FnMut(PlanKind, &PlanRequest) -> PlanResponse,
    ) -> usize {
        self.endpoint.refresh();
        let now = Instant::now();
        let endpoint = &self.endpoint;
        let mut this_pass: HashMap<E::Client, usize> = HashMap::new();
        let mut ready = |client: &E::Client, pending: &Pending<E::Reply>| {
            let n = this_pass.entry(client.clone()).or_default();
            let due = *n < CLIENT_ANSWERS_PER_PASS && endpoint.due(&pending.reply, now);
            *n += usize::from(due);
            due
        };
        let mut due = Vec::new();
        while due.len() < ANSWERS_PER_PASS
            && let Some((_, pending)) = self.queue.next(&mut ready)
        {
            due.push(pending);
        }
        let answered = due.len();
        for pending in due {
            let request = pending.request.as_ref().map_err(String::as_str);
            let response = respond((self.kind, &self.label), request, (cx, counts), answer);
            self.reply(cx, pending.reply, &response);
            counts.answered += 1;
        }
        answered
    }

    /// Sends `response` to `reply`.
    fn reply(&self, cx: &mut Context, reply: E::Reply, response: &PlanResponse) {
        let cdr = match self.kind {
            PlanKind::Now => to_vec::<_, LittleEndian>(&now_response(response)),
            PlanKind::Graph => to_vec::<_, LittleEndian>(&graph_response(response)),
            _ => to_vec::<_, LittleEndian>(&offline_response(response)),
        };
        let cdr = match cdr {
            Ok(cdr) => cdr,
            Err(e) => {
                tracing::warn!("{}: a reply could not be encoded: {e}", self.label);
                return;
            }
        };
        if let Err(e) = self.endpoint.reply(reply, &cdr) {
            let label = &self.label;
            cx.warnings.warn(E::WARNINGS.reply_failed, || {
                format!("{label}: a reply could not be sent: {e}")
            });
        }
    }
}

/// The response of the service `label` of `kind` to `request`: `answer`'s, or for
/// a malformed request (`Err(why)`) status 1 with the reason, counted as rejected
/// in `counts` and `cx` with a rate-limited warning.
fn respond(
    (kind, label): (PlanKind, &str),
    request: Result<&PlanRequest, &str>,
    (cx, counts): (&mut Context, &mut PlanCounts),
    answer: &mut dyn FnMut(PlanKind, &PlanRequest) -> PlanResponse,
) -> PlanResponse {
    match request {
        Ok(request) => answer(kind, request),
        Err(why) => {
            counts.rejected += 1;
            cx.health.rejected();
            cx.warnings.warn("plan request malformed", || {
                format!("{label}: a malformed request, answered with status 1: {why}")
            });
            PlanResponse::new(kind as u32, PlanStatus::BadRequest, why)
        }
    }
}

/// One transport's planning services, as the output serves them.
pub trait Serve {
    /// Takes what the transport holds, queues it, answers what is due with
    /// `answer` (at most [`ANSWERS_PER_PASS`] per service); returns how many
    /// were answered. Rejected and dropped requests are counted here and in
    /// `cx`'s health, with rate-limited warnings. Never blocks for long.
    fn serve(
        &mut self,
        cx: &mut Context,
        answer: &mut dyn FnMut(PlanKind, &PlanRequest) -> PlanResponse,
    ) -> usize;

    /// The totals so far.
    fn counts(&self) -> PlanCounts;
}

/// The planning services of one transport and their totals.
pub struct PlanServices<E: Endpoint> {
    services: Vec<Service<E>>,
    counts: PlanCounts,
}

impl<E: Endpoint> PlanServices<E> {
    /// `services`, served in this order.
    pub fn new(services: Vec<Service<E>>) -> Self {
        PlanServices {
            services,
            counts: PlanCounts::default(),
        }
    }
}

impl<E: Endpoint> Serve for PlanServices<E> {
    fn serve(
        &mut self,
        cx: &mut Context,
        answer: &mut dyn FnMut(PlanKind, &PlanRequest) -> PlanResponse,
    ) -> usize {
        let mut n = 0;
        for service in &mut self.services {
            service.intake(cx, &mut self.counts);
            n += service.answer(cx, &mut self.counts, answer);
        }
        n
    }

    fn counts(&self) -> PlanCounts {
        self.counts
    }
}

#[cfg(test)]
mod tests;
