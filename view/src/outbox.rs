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

use std::collections::VecDeque;
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

/// The queue of one client, bounded in bytes; shared by the task that fills it
/// and the one that writes it to the socket.
pub struct Outbox<T> {
    state: Mutex<State<T>>,
    ready: Notify,
}

struct State<T> {
    budget: usize,
    /// Items, their size in bytes, and whether they may be dropped.
    queue: VecDeque<(T, usize, bool)>,
    queued_bytes: usize,
    drops: Drops,
    /// Since when it has been over its budget without taking anything.
    stalled_since: Option<Instant>,
    ever_over: bool,
}

impl<T> Outbox<T> {
    /// An empty outbox of `budget` bytes.
    pub fn new(budget: usize) -> Outbox<T> {
        Outbox {
            state: Mutex::new(State {
                budget,
                queue: VecDeque::new(),
                queued_bytes: 0,
                drops: Drops::default(),
                stalled_since: None,
                ever_over: false,
            }),
            ready: Notify::new(),
        }
    }

    /// Queues `item` of `bytes` bytes at `now`; `droppable` for message data,
    /// which may be dropped when the budget is exceeded (control messages never
    /// are).
    pub fn push(&self, item: T, bytes: usize, droppable: bool, now: Instant) -> Pushed {
        let mut s = self.state.lock();
        let mut dropped = 0;
        let mut over = false;
        if s.queued_bytes + bytes > s.budget {
            over = true;
            if droppable {
                // The oldest message data first, until the new one fits.
                let mut k = 0;
                while s.queued_bytes + bytes > s.budget && k < s.queue.len() {
                    if s.queue[k].2 {
                        let (_, size, _) = s.queue.remove(k).expect("k < len");
                        s.queued_bytes -= size;
                        s.drops.messages += 1;
                        s.drops.bytes += size as u64;
                        dropped += 1;
                    } else {
                        k += 1;
                    }
                }
            }
        }
        s.queue.push_back((item, bytes, droppable));
        s.queued_bytes += bytes;
        let first_time_over = over && !s.ever_over;
        if over {
            s.ever_over = true;
            s.stalled_since.get_or_insert(now);
        }
        drop(s);
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
        let (item, size, _) = s.queue.pop_front()?;
        s.queued_bytes -= size;
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
