//! Per-client fair queueing of planning requests: no I/O, decisions out.
//!
//! Each client (what its transport says sent a request: on DDS its writer, the
//! one identity a client cannot choose per request; on Zenoh the GID of its
//! attachment) has a lane of its own, bounded by `per_client`; all lanes
//! together hold at most `capacity`. Requests are taken round robin across the
//! clients that have one ready, so a client flooding the service fills only its
//! own lane and waits its turn like any other: a client with one request
//! outstanding has it answered within one round.
//!
//! When every lane together is full, a newcomer takes the place of the newest
//! request of the longest lane if that lane is longer than the newcomer's
//! (longest-queue drop): a few flooding writers cannot lock a polite client out
//! by filling `capacity` between them.
//!
//! Every lane counts what it accepted, answered and dropped; lanes are kept
//! while idle so that their counts last, and idle ones are forgotten once
//! [`MAX_LANES`] clients have been seen.

use std::collections::{HashMap, VecDeque};
use std::hash::Hash;

/// Clients whose counts are kept; beyond, the idle ones are forgotten.
pub const MAX_LANES: usize = 1024;

/// What one client's lane did since it was (last) seen first.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct LaneCounts {
    /// Requests queued.
    pub accepted: u64,
    /// Requests taken out to be answered.
    pub taken: u64,
    /// Requests dropped: refused when pushed or displaced later.
    pub dropped: u64,
}

/// What [`FairQueue::push`] did with a request.
#[derive(Debug, PartialEq, Eq)]
pub enum Pushed<K, T> {
    /// Queued.
    Queued,
    /// Queued in place of the newest request of `client`, whose lane was the
    /// longest while every lane together was full; that request is dropped.
    Displaced {
        /// The client whose request was dropped.
        client: K,
        /// The dropped request.
        request: T,
    },
    /// Dropped: the client already has `per_client` requests queued.
    ClientFull,
    /// Dropped: every lane together is full and none is longer than the
    /// client's.
    Full,
}

/// One client's requests and counts.
#[derive(Debug)]
struct Lane<T> {
    queue: VecDeque<T>,
    counts: LaneCounts,
}

impl<T> Default for Lane<T> {
    fn default() -> Self {
        Lane {
            queue: VecDeque::new(),
            counts: LaneCounts::default(),
        }
    }
}

/// Requests of type `T` from clients `K`, queued per client and taken round robin.
#[derive(Debug)]
pub struct FairQueue<K, T> {
    lanes: HashMap<K, Lane<T>>,
    /// The clients with requests queued, in the order they are served.
    ring: VecDeque<K>,
    per_client: usize,
    capacity: usize,
    len: usize,
}

impl<K: Clone + Eq + Hash, T> FairQueue<K, T> {
    /// An empty queue: at most `per_client` requests of one client, `capacity`
    /// of all (each at least 1).
    pub fn new(per_client: usize, capacity: usize) -> Self {
        FairQueue {
            lanes: HashMap::new(),
            ring: VecDeque::new(),
            per_client: per_client.max(1),
            capacity: capacity.max(1),
            len: 0,
        }
    }

    /// Queues `request` of `client`, or says why not (or whose request it displaced).
    pub fn push(&mut self, client: K, request: T) -> Pushed<K, T> {
        if self.lanes.len() >= MAX_LANES && !self.lanes.contains_key(&client) {
            self.lanes.retain(|_, lane| !lane.queue.is_empty());
        }
        let mine = self.lanes.get(&client).map_or(0, |l| l.queue.len());
        if mine >= self.per_client {
            self.lane(&client).counts.dropped += 1;
            return Pushed::ClientFull;
        }
        let mut pushed = Pushed::Queued;
        if self.len >= self.capacity {
            let longest = self.longest().filter(|(_, n)| *n > mine);
            let Some((victim, _)) = longest else {
                self.lane(&client).counts.dropped += 1;
                return Pushed::Full;
            };
            let lane = self.lane(&victim);
            let Some(request) = lane.queue.pop_back() else {
                // `longest` names a lane with more requests than `mine` ≥ 0.
                return Pushed::Full;
            };
            lane.counts.dropped += 1;
            self.len -= 1;
            pushed = Pushed::Displaced {
                client: victim,
                request,
            };
        }
        let lane = self.lane(&client);
        lane.queue.push_back(request);
        lane.counts.accepted += 1;
        if lane.queue.len() == 1 {
            self.ring.push_back(client);
        }
        self.len += 1;
        pushed
    }

    /// The next request to answer: the oldest of the next client in the round
    /// whose oldest request is `ready` (clients that are not are passed over and
    /// keep their turn order). `None` if no client has one ready.
    pub fn next(&mut self, mut ready: impl FnMut(&K, &T) -> bool) -> Option<(K, T)> {
        for _ in 0..self.ring.len() {
            let client = self.ring.pop_front()?;
            let Some(lane) = self.lanes.get_mut(&client) else {
                continue;
            };
            let Some(head) = lane.queue.front() else {
                continue;
            };
            if !ready(&client, head) {
                self.ring.push_back(client);
                continue;
            }
            let request = lane.queue.pop_front()?;
            lane.counts.taken += 1;
            self.len -= 1;
            if !lane.queue.is_empty() {
                self.ring.push_back(client.clone());
            }
            return Some((client, request));
        }
        None
    }

    /// Requests queued, of every client.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True if no request is queued.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Clients with requests queued.
    pub fn clients(&self) -> usize {
        self.ring.len()
    }

    /// The counts of `client`'s lane, if it is known.
    pub fn counts(&self, client: &K) -> Option<LaneCounts> {
        self.lanes.get(client).map(|l| l.counts)
    }

    /// The most requests one client may have queued.
    pub fn per_client(&self) -> usize {
        self.per_client
    }

    /// The most requests all clients together may have queued.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// The client with the most requests queued (the first in the round of those
    /// with as many) and how many.
    fn longest(&self) -> Option<(K, usize)> {
        let mut best: Option<(&K, usize)> = None;
        for client in &self.ring {
            let n = self.lanes.get(client).map_or(0, |l| l.queue.len());
            if best.is_none_or(|(_, m)| n > m) {
                best = Some((client, n));
            }
        }
        best.map(|(k, n)| (k.clone(), n))
    }

    /// `client`'s lane, made if it is new.
    fn lane(&mut self, client: &K) -> &mut Lane<T> {
        self.lanes.entry(client.clone()).or_default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn all<K: Clone + Eq + Hash, T>(q: &mut FairQueue<K, T>) -> Vec<(K, T)> {
        std::iter::from_fn(|| q.next(|_, _| true)).collect()
    }

    #[test]
    fn one_client_is_first_in_first_out() {
        let mut q = FairQueue::new(4, 16);
        for k in 0..3 {
            assert_eq!(q.push('a', k), Pushed::Queued);
        }
        assert_eq!((q.len(), q.clients()), (3, 1));
        assert_eq!(all(&mut q), [('a', 0), ('a', 1), ('a', 2)]);
        assert!(q.is_empty());
        assert_eq!(q.clients(), 0);
    }

    #[test]
    fn clients_are_served_round_robin() {
        let mut q = FairQueue::new(8, 64);
        for k in 0..5 {
            q.push('f', k);
        }
        q.push('a', 100);
        q.push('b', 200);
        q.push('a', 101);
        let order: Vec<char> = all(&mut q).into_iter().map(|(c, _)| c).collect();
        assert_eq!(order, ['f', 'a', 'b', 'f', 'a', 'f', 'f', 'f']);
    }

    #[test]
    fn a_flooding_client_fills_only_its_own_lane() {
        let mut q = FairQueue::new(8, 64);
        let mut refused = 0;
        for k in 0..500 {
            if q.push("flood", k) == Pushed::ClientFull {
                refused += 1;
            }
        }
        assert_eq!((refused, q.len()), (492, 8));
        assert_eq!(q.push("robot", 1), Pushed::Queued);
        // The robot's request is the second one out.
        assert_eq!(q.next(|_, _| true), Some(("flood", 0)));
        assert_eq!(q.next(|_, _| true), Some(("robot", 1)));
        let flood = q.counts(&"flood").unwrap();
        assert_eq!(
            flood,
            LaneCounts {
                accepted: 8,
                taken: 1,
                dropped: 492
            }
        );
        let robot = q.counts(&"robot").unwrap();
        assert_eq!((robot.accepted, robot.taken, robot.dropped), (1, 1, 0));
    }

    #[test]
    fn when_all_lanes_are_full_the_longest_gives_way() {
        let mut q = FairQueue::new(6, 8);
        for k in 0..6 {
            q.push('f', k);
        }
        for k in 0..2 {
            q.push('g', 10 + k);
        }
        // Full: the newcomer displaces f's newest.
        assert_eq!(
            q.push('r', 20),
            Pushed::Displaced {
                client: 'f',
                request: 5
            }
        );
        assert_eq!(q.len(), 8);
        // g (2) and r (1) get in while f is longer than them.
        assert!(matches!(
            q.push('r', 21),
            Pushed::Displaced { client: 'f', .. }
        ));
        assert!(matches!(
            q.push('g', 12),
            Pushed::Displaced { client: 'f', .. }
        ));
        // Now f has 3, g 3, r 2: r still may; then g (3, as long as any) may not.
        assert!(matches!(
            q.push('r', 22),
            Pushed::Displaced { client: 'f', .. }
        ));
        assert_eq!(q.push('g', 13), Pushed::Full);
        assert_eq!(q.counts(&'f').unwrap().dropped, 4);
        assert_eq!(q.counts(&'g').unwrap().dropped, 1);
        assert_eq!(q.len(), 8);
    }

    #[test]
    fn clients_not_ready_are_passed_over_and_keep_their_requests() {
        let mut q = FairQueue::new(4, 16);
        q.push("deaf", 1);
        q.push("deaf", 2);
        q.push("robot", 3);
        let hearing = |c: &&str, _: &i32| *c != "deaf";
        assert_eq!(q.next(hearing), Some(("robot", 3)));
        assert_eq!(q.next(hearing), None);
        assert_eq!(q.len(), 2);
        // Later (its reader matched, or the wait is over) they are answered.
        assert_eq!(all(&mut q), [("deaf", 1), ("deaf", 2)]);
    }

    #[test]
    fn idle_lanes_are_forgotten_past_the_bound() {
        let mut q = FairQueue::new(2, 4);
        q.push(usize::MAX, 0);
        for client in 0..MAX_LANES {
            q.push(client, 0);
            q.next(|c, _| *c == client);
        }
        // The busy lane stays with its counts; idle ones went.
        assert_eq!(q.counts(&usize::MAX).unwrap().accepted, 1);
        assert!(q.lanes.len() <= MAX_LANES);
        assert!(q.counts(&0).is_none());
        assert_eq!(q.len(), 1);
    }

    #[test]
    fn bounds_are_at_least_one() {
        let mut q = FairQueue::new(0, 0);
        assert_eq!((q.per_client(), q.capacity()), (1, 1));
        assert_eq!(q.push('a', 1), Pushed::Queued);
        assert_eq!(q.push('a', 2), Pushed::ClientFull);
        assert_eq!(
            q.push('b', 3),
            Pushed::Displaced {
                client: 'a',
                request: 1
            }
        );
        assert_eq!(q.push('b', 4), Pushed::ClientFull);
    }
}
