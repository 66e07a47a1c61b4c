//! The bridge as a client of the route server: nav2_route's `DynamicEdgesScorer`
//! serves `nav2_msgs/srv/DynamicEdges` at `<costmap.route_server>/
//! <costmap.route_scorer>/adjust_edges`, and the bridge tells it which edges
//! people closed and what each edge costs. [`RouteServerLink`] is the life of
//! that link, the same on every transport; a [`Caller`] is one transport's side
//! (DDS: [`crate::dds::DdsCaller`]).
//!
//! * **waiting**: no server is seen; nothing is sent, and the bridge's grid and
//!   planning services go on as before;
//! * **up**: one call at a time, each answered within [`CALL_TIMEOUT`] or failed;
//! * **failing**: a call timed out, was answered `success = false` or could not
//!   be sent; the next goes after a backoff (from [`RETRY_FIRST`], doubling, at
//!   most [`RETRY_MAX`] apart, for as long as it fails) and says everything, as
//!   what the failed call said may be lost.
//!
//! A server seen anew (the first time, or a new endpoint: the route server
//! restarted and forgot what it was told) is told everything at once. Changes
//! that could not go out while a call was in flight make the next call say
//! everything too. A change of state is logged once (WARN for waiting and
//! failing), never a line per call.

use std::time::{Duration, Instant};

use crate::msgs::DynamicEdges;

/// How long a call waits for its answer before it counts as failed.
pub const CALL_TIMEOUT: Duration = Duration::from_secs(2);
/// The first wait after a failure.
pub const RETRY_FIRST: Duration = Duration::from_secs(1);
/// The longest wait between two tries of a failing server.
pub const RETRY_MAX: Duration = Duration::from_secs(30);

/// One transport's client of `nav2_msgs/srv/DynamicEdges`.
pub trait Caller {
    /// The server seen now, as an id of its endpoint that changes when it
    /// restarts; `None` while none is seen.
    fn server(&mut self) -> Option<u128>;
    /// Sends `request`; returns the call's id.
    fn call(&mut self, request: &DynamicEdges) -> Result<u64, String>;
    /// The answers that arrived since the last look: each call's id and
    /// `success`.
    fn answers(&mut self) -> Vec<(u64, bool)>;
}

impl Caller for Box<dyn Caller> {
    fn server(&mut self) -> Option<u128> {
        (**self).server()
    }
    fn call(&mut self, request: &DynamicEdges) -> Result<u64, String> {
        (**self).call(request)
    }
    fn answers(&mut self) -> Vec<(u64, bool)> {
        (**self).answers()
    }
}

/// A link on any transport.
pub type RouteLink = RouteServerLink<Box<dyn Caller>>;

/// Where the link stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkState {
    /// No server seen.
    Waiting,
    /// The server answers.
    Up,
    /// Calls fail; retried with a backoff.
    Failing,
}

/// What the link may send now ([`RouteServerLink::poll`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ready {
    /// Nothing: no server, a call in flight, or a backoff. What changes in the
    /// meantime must be reported with [`RouteServerLink::missed`].
    No,
    /// What changed since the last call.
    Changes,
    /// Everything the server should know (a new server, or after a failure or
    /// a missed change).
    Everything,
}

/// What the link did since the bridge started.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RouteCounts {
    /// Calls made.
    pub calls: u64,
    /// Calls that failed: not sent, not answered in time, or `success = false`.
    pub failures: u64,
    /// Edges named in calls the server took (closed, opened and adjusted).
    pub edges: u64,
    /// How long the last answer took, milliseconds.
    pub latency_ms: Option<f64>,
    /// A server answers.
    pub up: bool,
}

/// A call waiting for its answer.
#[derive(Debug, Clone, Copy)]
struct InFlight {
    id: u64,
    sent: Instant,
    edges: usize,
}

/// The bridge's link to one route server on one transport.
pub struct RouteServerLink<C> {
    caller: C,
    /// The service, as the logs name it.
    name: String,
    state: LinkState,
    server: Option<u128>,
    in_flight: Option<InFlight>,
    /// The server may lack something: the next call says everything.
    behind: bool,
    retry_at: Option<Instant>,
    backoff: Duration,
    counts: RouteCounts,
}

impl<C: Caller> RouteServerLink<C> {
    /// A link over `caller` to the service `name` (for the logs), waiting for
    /// its server.
    pub fn new(caller: C, name: impl Into<String>) -> RouteServerLink<C> {
        let name = name.into();
        tracing::info!("route server: waiting for {name} (nav2_msgs/srv/DynamicEdges)");
        RouteServerLink {
            caller,
            name,
            state: LinkState::Waiting,
            server: None,
            in_flight: None,
            behind: true,
            retry_at: None,
            backoff: RETRY_FIRST,
            counts: RouteCounts::default(),
        }
    }

    /// Follows the server, takes the answers and fails a call that took too
    /// long; then says what may be sent now. Never blocks.
    pub fn poll(&mut self, now: Instant) -> Ready {
        let server = self.caller.server();
        if server != self.server {
            let restarted = self.server.is_some();
            self.server = server;
            self.in_flight = None;
            self.behind = true;
            self.retry_at = None;
            self.backoff = RETRY_FIRST;
            match server {
                None => self.enter(LinkState::Waiting, "the service is gone"),
                Some(_) if restarted => self.enter(
                    LinkState::Up,
                    "a new server (restarted?): telling it everything",
                ),
                Some(_) => self.enter(LinkState::Up, "found: telling it everything"),
            }
        }
        for (id, success) in self.caller.answers() {
            let Some(call) = self.in_flight.filter(|c| c.id == id) else {
                continue; // the late answer of a call that timed out
            };
            self.in_flight = None;
            self.counts.latency_ms = Some(now.duration_since(call.sent).as_secs_f64() * 1e3);
            if success {
                self.counts.edges += call.edges as u64;
                self.backoff = RETRY_FIRST;
                self.enter(LinkState::Up, "answering again");
            } else {
                self.fail(now, "the server answered success = false");
            }
        }
        if let Some(call) = self.in_flight
            && now.duration_since(call.sent) >= CALL_TIMEOUT
        {
            self.in_flight = None;
            self.fail(now, &format!("no answer within {CALL_TIMEOUT:?}"));
        }
        if self.server.is_none() || self.in_flight.is_some() {
            return Ready::No;
        }
        if let Some(at) = self.retry_at {
            if now < at {
                return Ready::No;
            }
            self.retry_at = None;
        }
        if self.behind {
            Ready::Everything
        } else {
            Ready::Changes
        }
    }

    /// Sends `request`, what [`poll`](Self::poll) said may go.
    pub fn send(&mut self, request: &DynamicEdges, now: Instant) {
        self.counts.calls += 1;
        match self.caller.call(request) {
            Ok(id) => {
                self.in_flight = Some(InFlight {
                    id,
                    sent: now,
                    edges: request.edges(),
                });
                self.behind = false;
            }
            Err(e) => self.fail(now, &format!("cannot send: {e}")),
        }
    }

    /// Changes happened that could not be sent ([`Ready::No`]): the next call
    /// says everything.
    pub fn missed(&mut self) {
        self.behind = true;
    }

    /// Where the link stands.
    pub fn state(&self) -> LinkState {
        self.state
    }

    /// What the link did so far.
    pub fn counts(&self) -> RouteCounts {
        RouteCounts {
            up: self.state == LinkState::Up,
            ..self.counts
        }
    }

    /// A call failed: counted, retried after the backoff, which doubles.
    fn fail(&mut self, now: Instant, why: &str) {
        self.counts.failures += 1;
        self.behind = true;
        self.retry_at = Some(now + self.backoff);
        let wait = self.backoff;
        self.backoff = (self.backoff * 2).min(RETRY_MAX);
        let why = format!(
            "{why}; retrying in {:.0} s, backing off to {:.0} s",
            wait.as_secs_f64(),
            RETRY_MAX.as_secs_f64()
        );
        self.enter(LinkState::Failing, &why);
    }

    /// Moves to `state`, saying so if it is a change.
    fn enter(&mut self, state: LinkState, why: &str) {
        if state == self.state {
            return;
        }
        self.state = state;
        let name = &self.name;
        match state {
            LinkState::Up => tracing::info!("route server: {name} up: {why}"),
            LinkState::Waiting => tracing::warn!("route server: waiting for {name}: {why}"),
            LinkState::Failing => tracing::warn!("route server: calls to {name} fail: {why}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use std::cell::RefCell;
    use std::collections::VecDeque;
    use std::rc::Rc;

    use super::*;
    use crate::msgs::EdgeCost;

    /// A caller whose server, answers and sends the test controls.
    #[derive(Default)]
    struct Fake {
        server: Option<u128>,
        sent: Vec<DynamicEdges>,
        answers: VecDeque<(u64, bool)>,
        refuse: bool,
    }

    #[derive(Clone, Default)]
    struct Shared(Rc<RefCell<Fake>>);

    impl Caller for Shared {
        fn server(&mut self) -> Option<u128> {
            self.0.borrow().server
        }
        fn call(&mut self, request: &DynamicEdges) -> Result<u64, String> {
            let mut f = self.0.borrow_mut();
            if f.refuse {
                return Err("no room".into());
            }
            f.sent.push(request.clone());
            Ok(f.sent.len() as u64)
        }
        fn answers(&mut self) -> Vec<(u64, bool)> {
            self.0.borrow_mut().answers.drain(..).collect()
        }
    }

    fn request(edges: &[u16]) -> DynamicEdges {
        DynamicEdges {
            adjust_edges: edges
                .iter()
                .map(|&edgeid| EdgeCost { edgeid, cost: 1.0 })
                .collect(),
            ..DynamicEdges::default()
        }
    }

    fn link() -> (Shared, RouteServerLink<Shared>) {
        let fake = Shared::default();
        (
            fake.clone(),
            RouteServerLink::new(fake, "route_server/S/adjust_edges"),
        )
    }

    #[test]
    fn nothing_goes_until_a_server_is_seen_and_then_everything() {
        let (fake, mut link) = link();
        let t0 = Instant::now();
        assert_eq!(link.poll(t0), Ready::No);
        assert_eq!(link.state(), LinkState::Waiting);
        fake.0.borrow_mut().server = Some(7);
        assert_eq!(link.poll(t0), Ready::Everything);
        assert_eq!(link.state(), LinkState::Up);
        link.send(&request(&[1, 2]), t0);
        // One call at a time.
        assert_eq!(link.poll(t0), Ready::No);
        fake.0.borrow_mut().answers.push_back((1, true));
        let t1 = t0 + Duration::from_millis(30);
        assert_eq!(link.poll(t1), Ready::Changes);
        let counts = link.counts();
        assert_eq!((counts.calls, counts.failures, counts.edges), (1, 0, 2));
        assert!((counts.latency_ms.unwrap() - 30.0).abs() < 1e-6);
        assert!(counts.up);
    }

    #[test]
    fn a_timeout_or_a_refusal_fails_backs_off_and_then_says_everything() {
        let (fake, mut link) = link();
        fake.0.borrow_mut().server = Some(7);
        let t0 = Instant::now();
        assert_eq!(link.poll(t0), Ready::Everything);
        link.send(&request(&[1]), t0);
        // No answer: failed at the timeout, retried after RETRY_FIRST.
        let t1 = t0 + CALL_TIMEOUT;
        assert_eq!(link.poll(t1), Ready::No);
        assert_eq!(link.state(), LinkState::Failing);
        assert_eq!(link.poll(t1 + RETRY_FIRST), Ready::Everything);
        link.send(&request(&[1]), t1 + RETRY_FIRST);
        // Refused: the backoff doubles.
        fake.0.borrow_mut().answers.push_back((2, false));
        let t2 = t1 + RETRY_FIRST + Duration::from_millis(5);
        assert_eq!(link.poll(t2), Ready::No);
        assert_eq!(link.poll(t2 + RETRY_FIRST), Ready::No);
        assert_eq!(link.poll(t2 + 2 * RETRY_FIRST), Ready::Everything);
        // Not sent at all: a failure too.
        fake.0.borrow_mut().refuse = true;
        link.send(&request(&[1]), t2 + 2 * RETRY_FIRST);
        let counts = link.counts();
        assert_eq!((counts.calls, counts.failures, counts.edges), (3, 3, 0));
        assert!(!counts.up);
        // The late answer of the call that timed out is ignored.
        fake.0.borrow_mut().answers.push_back((1, true));
        assert_eq!(link.poll(t2 + 2 * RETRY_FIRST), Ready::No);
        assert_eq!(link.state(), LinkState::Failing);
    }

    #[test]
    fn the_backoff_stops_growing_at_its_cap() {
        let (fake, mut link) = link();
        fake.0.borrow_mut().server = Some(7);
        fake.0.borrow_mut().refuse = true;
        let mut now = Instant::now();
        let mut waits = Vec::new();
        for _ in 0..8 {
            let mut wait = Duration::ZERO;
            while link.poll(now + wait) != Ready::Everything {
                wait += Duration::from_millis(500);
            }
            waits.push(wait.as_secs());
            now += wait;
            link.send(&request(&[1]), now);
        }
        assert_eq!(waits, [0, 1, 2, 4, 8, 16, 30, 30]);
    }

    #[test]
    fn a_restarted_server_is_told_everything_and_a_missed_change_too() {
        let (fake, mut link) = link();
        fake.0.borrow_mut().server = Some(7);
        let t0 = Instant::now();
        assert_eq!(link.poll(t0), Ready::Everything);
        link.send(&request(&[1]), t0);
        fake.0.borrow_mut().answers.push_back((1, true));
        assert_eq!(link.poll(t0), Ready::Changes);
        // A change while a call is in flight: the next call says everything.
        link.send(&request(&[1]), t0);
        link.missed();
        fake.0.borrow_mut().answers.push_back((2, true));
        assert_eq!(link.poll(t0), Ready::Everything);
        link.send(&request(&[1]), t0);
        fake.0.borrow_mut().answers.push_back((3, true));
        assert_eq!(link.poll(t0), Ready::Changes);
        // The server goes, and comes back as a new endpoint.
        fake.0.borrow_mut().server = None;
        assert_eq!(link.poll(t0), Ready::No);
        assert_eq!(link.state(), LinkState::Waiting);
        fake.0.borrow_mut().server = Some(8);
        assert_eq!(link.poll(t0), Ready::Everything);
        link.send(&request(&[1]), t0);
        fake.0.borrow_mut().answers.push_back((4, true));
        assert_eq!(link.poll(t0), Ready::Changes);
        // Replaced without a gap: everything again, the call in flight forgotten.
        link.send(&request(&[1]), t0);
        fake.0.borrow_mut().server = Some(9);
        assert_eq!(link.poll(t0), Ready::Everything);
        assert_eq!(link.counts().failures, 0);
    }
}
