//! One live-view client's outbox: the messages waiting to be written to it,
//! bounded in bytes (`view.client_budget_mib`), so that a client that reads
//! slowly, or not at all, costs the view a known amount of memory.
//!
//! * Control messages (channel advertisements, status) are never dropped.
//! * Message data is: when a new message does not fit in the budget, the oldest
//!   queued message data goes first, as many as it takes (the newest is what a
//!   live view wants to show). The new message is always queued, so a message
//!   larger than the whole budget still reaches a client with nothing else
//!   queued: the outbox holds at most the budget or one message, whichever is
//!   larger, plus the control messages.
//! * A client that is over its budget (dropping) and takes nothing is stalled;
//!   [`Outbox::stalled_for`] says how long, and the server disconnects it after
//!   `view.client_stall_s`. A slow client that keeps reading only loses messages.
//! * Every client's outbox is in one [`Pool`], bounded in bytes over all clients
//!   (`view.memory_budget_mib`): when a push takes the pool over it, the oldest
//!   message data of the client holding the most message data goes first, then of
//!   the next, until the pool fits. A client that loses messages this way counts
//!   as over its budget (stalled, if it takes nothing). So the clients that read
//!   least pay for the memory, and the pool holds at most its budget plus the
//!   control messages and, per client, one message larger than what was dropped.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Weak};
use std::time::{Duration, Instant};

use parking_lot::Mutex;
use tokio::sync::Notify;

/// What [`Outbox::push`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Pushed {
    /// Older message data dropped to make room.
    pub dropped: usize,
    /// This is the first time this client went over its budget.
    pub first_time_over: bool,
}

/// The drops of one client so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Drops {
    /// Messages dropped.
    pub messages: u64,
    /// Their bytes.
    pub bytes: u64,
}

/// The outboxes of every client, bounded in bytes together.
pub struct Pool<T> {
    budget: usize,
    /// Bytes queued in every member.
    queued: AtomicUsize,
    members: Mutex<Vec<Weak<Outbox<T>>>>,
}

impl<T> Pool<T> {
    /// An empty pool of `budget` bytes.
    pub fn new(budget: usize) -> Arc<Pool<T>> {
        Arc::new(Pool {
            budget,
            queued: AtomicUsize::new(0),
            members: Mutex::new(Vec::new()),
        })
    }

    /// Bytes queued for every client now.
    pub fn queued_bytes(&self) -> usize {
        self.queued.load(Ordering::Relaxed)
    }

    /// Drops the oldest message data of the members holding the most, at `now`,
    /// until the pool fits its budget; how many messages were dropped.
    fn relieve(&self, now: Instant) -> usize {
        let mut dropped = 0;
        while self.queued_bytes() > self.budget {
            let worst = {
                let members = self.members.lock();
                members
                    .iter()
                    .filter_map(Weak::upgrade)
                    .max_by_key(|o| o.state.lock().droppable_bytes)
            };
            match worst {
                Some(outbox) if outbox.drop_oldest(now) => dropped += 1,
                // Nothing left to drop: control messages and messages being written.
                _ => break,
            }
        }
        dropped
    }
}

/// The queue of one client, bounded in bytes; shared by the task that fills it
/// and the one that writes it to the socket.
pub struct Outbox<T> {
    state: Mutex<State<T>>,
    ready: Notify,
    pool: Option<Arc<Pool<T>>>,
}

struct State<T> {
    budget: usize,
    /// Items, their size in bytes, and whether they may be dropped.
    queue: VecDeque<(T, usize, bool)>,
    queued_bytes: usize,
    /// The part of `queued_bytes` that may be dropped.
    droppable_bytes: usize,
    drops: Drops,
    /// Since when it has been over its budget without taking anything.
    stalled_since: Option<Instant>,
    ever_over: bool,
}

impl<T> Outbox<T> {
    /// An empty outbox of `budget` bytes, in no pool.
    pub fn new(budget: usize) -> Outbox<T> {
        Outbox::make(budget, None)
    }

    /// An empty outbox of `budget` bytes in `pool`.
    pub fn pooled(budget: usize, pool: &Arc<Pool<T>>) -> Arc<Outbox<T>> {
        let outbox = Arc::new(Outbox::make(budget, Some(pool.clone())));
        let mut members = pool.members.lock();
        members.retain(|m| m.strong_count() > 0);
        members.push(Arc::downgrade(&outbox));
        outbox
    }

    fn make(budget: usize, pool: Option<Arc<Pool<T>>>) -> Outbox<T> {
        Outbox {
            state: Mutex::new(State {
                budget,
                queue: VecDeque::new(),
                queued_bytes: 0,
                droppable_bytes: 0,
                drops: Drops::default(),
                stalled_since: None,
                ever_over: false,
            }),
            ready: Notify::new(),
            pool,
        }
    }

    /// Adds `bytes` to the pool's count (`add`), or takes them away.
    fn charge(&self, bytes: usize, add: bool) {
        if let Some(pool) = &self.pool {
            if add {
                pool.queued.fetch_add(bytes, Ordering::Relaxed);
            } else {
                pool.queued.fetch_sub(bytes, Ordering::Relaxed);
            }
        }
    }

    /// Drops the oldest queued message data at `now`, for the pool; false if
    /// there is none.
    fn drop_oldest(&self, now: Instant) -> bool {
        let mut s = self.state.lock();
        let Some(k) = s.queue.iter().position(|(_, _, droppable)| *droppable) else {
            return false;
        };
        let Some((_, size, _)) = s.queue.remove(k) else {
            return false;
        };
        s.queued_bytes -= size;
        s.droppable_bytes -= size;
        s.drops.messages += 1;
        s.drops.bytes += size as u64;
        s.ever_over = true;
        s.stalled_since.get_or_insert(now);
        drop(s);
        self.charge(size, false);
        true
    }

    /// Queues `item` of `bytes` bytes at `now`; `droppable` for message data,
    /// which may be dropped when the budget is exceeded (control messages never
    /// are).
    /// In a pool over its budget, the oldest message data of the clients holding
    /// the most goes (this one's too, if it is one of them).
    pub fn push(&self, item: T, bytes: usize, droppable: bool, now: Instant) -> Pushed {
        let mut s = self.state.lock();
        let mut dropped = 0;
        let mut freed = 0;
        let mut over = false;
        if s.queued_bytes + bytes > s.budget {
            over = true;
            if droppable {
                // The oldest message data first, until the new one fits.
                let mut k = 0;
                while s.queued_bytes + bytes > s.budget && k < s.queue.len() {
                    if s.queue[k].2 {
                        let Some((_, size, _)) = s.queue.remove(k) else {
                            break;
                        };
                        s.queued_bytes -= size;
                        s.droppable_bytes -= size;
                        s.drops.messages += 1;
                        s.drops.bytes += size as u64;
                        freed += size;
                        dropped += 1;
                    } else {
                        k += 1;
                    }
                }
            }
        }
        s.queue.push_back((item, bytes, droppable));
        s.queued_bytes += bytes;
        if droppable {
            s.droppable_bytes += bytes;
        }
        let first_time_over = over && !s.ever_over;
        if over {
            s.ever_over = true;
            s.stalled_since.get_or_insert(now);
        }
        drop(s);
        self.charge(freed, false);
        self.charge(bytes, true);
        if let Some(pool) = &self.pool {
            dropped += pool.relieve(now);
        }
        self.ready.notify_one();
        Pushed {
            dropped,
            first_time_over,
        }
    }

    /// The oldest queued item and its size, once there is one.
    pub async fn next(&self) -> (T, usize) {
        loop {
            if let Some(item) = self.try_next() {
                return item;
            }
            self.ready.notified().await;
        }
    }

    /// The oldest queued item and its size, if any.
    pub fn try_next(&self) -> Option<(T, usize)> {
        let mut s = self.state.lock();
        let (item, size, droppable) = s.queue.pop_front()?;
        s.queued_bytes -= size;
        if droppable {
            s.droppable_bytes -= size;
        }
        drop(s);
        self.charge(size, false);
        Some((item, size))
    }

    /// The client took a message: it is not stalled.
    pub fn taken(&self) {
        self.state.lock().stalled_since = None;
    }

    /// How long the client has been over its budget without taking anything, at
    /// `now` (`None` while it is not).
    pub fn stalled_for(&self, now: Instant) -> Option<Duration> {
        let since = self.state.lock().stalled_since?;
        Some(now.saturating_duration_since(since))
    }

    /// Bytes queued now.
    pub fn queued_bytes(&self) -> usize {
        self.state.lock().queued_bytes
    }

    /// What was dropped so far.
    pub fn drops(&self) -> Drops {
        self.state.lock().drops
    }
}

impl<T> Drop for Outbox<T> {
    /// What it still holds leaves the pool with it.
    fn drop(&mut self) {
        let queued = self.state.get_mut().queued_bytes;
        self.charge(queued, false);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn drain(o: &Outbox<&'static str>) -> Vec<&'static str> {
        std::iter::from_fn(|| o.try_next().map(|(m, _)| m)).collect()
    }

    #[test]
    fn within_the_budget_everything_is_kept_in_order() {
        let o = Outbox::new(100);
        let now = Instant::now();
        for (m, n) in [("a", 40), ("b", 30), ("c", 30)] {
            let p = o.push(m, n, true, now);
            assert_eq!(p.dropped, 0);
            assert!(!p.first_time_over);
        }
        assert_eq!(o.queued_bytes(), 100);
        assert_eq!(o.stalled_for(now), None);
        assert_eq!(drain(&o), ["a", "b", "c"]);
        assert_eq!(o.queued_bytes(), 0);
        assert_eq!(o.drops(), Drops::default());
    }

    #[test]
    fn the_oldest_message_data_goes_first_and_control_stays() {
        let o = Outbox::new(100);
        let now = Instant::now();
        o.push("advertise", 10, false, now);
        o.push("d1", 40, true, now);
        o.push("d2", 40, true, now);
        // 90 queued; 30 more needs 20 freed: d1 goes, the advertisement stays.
        let p = o.push("d3", 30, true, now);
        assert_eq!(p.dropped, 1);
        assert!(p.first_time_over);
        assert_eq!(
            o.drops(),
            Drops {
                messages: 1,
                bytes: 40
            }
        );
        // Over again (reported as not the first time): 80 queued, 60 more needs
        // 40 freed, which d2 gives.
        let p = o.push("d4", 60, true, now);
        assert_eq!(p.dropped, 1);
        assert!(!p.first_time_over);
        assert_eq!(drain(&o), ["advertise", "d3", "d4"]);
        assert_eq!(
            o.drops(),
            Drops {
                messages: 2,
                bytes: 80
            }
        );
    }

    #[test]
    fn a_message_larger_than_the_budget_still_goes_alone() {
        let o = Outbox::new(100);
        let now = Instant::now();
        o.push("small", 50, true, now);
        let p = o.push("huge", 500, true, now);
        assert_eq!(p.dropped, 1);
        assert_eq!(o.queued_bytes(), 500);
        // The next one replaces it.
        o.push("huge2", 500, true, now);
        assert_eq!(drain(&o), ["huge2"]);
    }

    #[test]
    fn control_messages_are_never_dropped_but_count_as_over() {
        let o = Outbox::new(100);
        let now = Instant::now();
        o.push("d", 60, true, now);
        let p = o.push("advertise", 60, false, now);
        assert_eq!(p.dropped, 0);
        assert!(p.first_time_over);
        assert_eq!(o.stalled_for(now), Some(Duration::ZERO));
        assert_eq!(drain(&o), ["d", "advertise"]);
    }

    #[test]
    fn a_client_over_its_budget_is_stalled_until_it_takes_something() {
        let o = Outbox::new(100);
        let t0 = Instant::now();
        o.push("a", 80, true, t0);
        assert_eq!(o.stalled_for(t0), None);
        o.push("b", 80, true, t0);
        let later = t0 + Duration::from_secs(7);
        o.push("c", 80, true, later);
        // Stalled since the first drop, not the last.
        assert_eq!(o.stalled_for(later), Some(Duration::from_secs(7)));
        o.taken();
        assert_eq!(o.stalled_for(later), None);
        o.push("d", 80, true, later);
        assert_eq!(
            o.stalled_for(later + Duration::from_secs(1)),
            Some(Duration::from_secs(1))
        );
    }

    #[test]
    fn a_pool_over_its_budget_drops_from_the_client_holding_the_most() {
        let pool = Pool::new(100);
        let now = Instant::now();
        let (reader, stalled) = (Outbox::pooled(80, &pool), Outbox::pooled(80, &pool));
        stalled.push("s1", 30, true, now);
        stalled.push("s2", 30, true, now);
        reader.push("control", 10, false, now);
        reader.push("r1", 20, true, now);
        assert_eq!(pool.queued_bytes(), 90);
        assert_eq!(stalled.stalled_for(now), None);
        // 20 more is 110: the stalled client's oldest goes, not the reader's.
        let p = reader.push("r2", 20, true, now);
        assert_eq!(p.dropped, 1);
        assert_eq!(pool.queued_bytes(), 80);
        assert_eq!(drain(&stalled), ["s2"]);
        assert_eq!(stalled.drops().messages, 1);
        assert_eq!(stalled.stalled_for(now), Some(Duration::ZERO));
        assert_eq!(drain(&reader), ["control", "r1", "r2"]);
        assert_eq!(pool.queued_bytes(), 0);
        // What an outbox holds leaves the pool with it.
        stalled.push("s3", 40, true, now);
        drop(stalled);
        assert_eq!(pool.queued_bytes(), 0);
        // Control messages are never dropped, even over the pool's budget.
        reader.push("big control", 150, false, now);
        assert_eq!(pool.queued_bytes(), 150);
    }

    #[test]
    fn next_waits_for_a_push() {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        let o = std::sync::Arc::new(Outbox::new(10));
        let got = rt.block_on(async {
            let reader = tokio::spawn({
                let o = o.clone();
                async move { o.next().await }
            });
            tokio::task::yield_now().await;
            o.push("x", 3, true, Instant::now());
            reader.await.unwrap()
        });
        assert_eq!(got, ("x", 3));
    }
}
