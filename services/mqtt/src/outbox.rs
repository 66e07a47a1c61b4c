//! The bounded queue between the stage (which reads the gate's streams and must
//! never wait) and the MQTT client (which waits for the broker): when full, the
//! oldest message is dropped and counted. Every message pushed ends up either
//! acknowledged by the broker or counted as dropped; none disappears silently.

use std::collections::VecDeque;
use std::time::Instant;

/// One message to publish (QoS 1).
#[derive(Debug, Clone)]
pub struct Message {
    /// Its topic.
    pub topic: String,
    /// Its JSON.
    pub payload: Vec<u8>,
    /// When the sink took it from the gate's stream.
    pub arrived: Instant,
    /// When capture published the frame it is about (wall ns; 0 unknown).
    pub origin_wall_ns: i64,
}

/// The largest MQTT packet the sink sends, bytes (rumqttc refuses larger ones
/// and closes the connection; its default is 10 KiB, less than the detections
/// of a few people with keypoints).
pub const MAX_PACKET_BYTES: usize = 1 << 20;

/// Bytes of `m`'s QoS 1 PUBLISH packet: fixed header (at most 5), the topic's
/// length and bytes, the packet id, the payload.
pub fn packet_len(m: &Message) -> usize {
    5 + 2 + m.topic.len() + 2 + m.payload.len()
}

/// The queue and what became of the messages that left it.
#[derive(Debug)]
pub struct Outbox {
    queue: VecDeque<Message>,
    capacity: usize,
    dropped: u64,
    acked: Vec<Message>,
}

impl Outbox {
    /// An empty outbox holding at most `capacity` (≥ 1) messages.
    pub fn new(capacity: usize) -> Self {
        Outbox {
            queue: VecDeque::new(),
            capacity: capacity.max(1),
            dropped: 0,
            acked: Vec::new(),
        }
    }

    /// Queues `m`; a full queue drops its oldest message first. A message whose
    /// packet would be larger than [`MAX_PACKET_BYTES`] is dropped and counted
    /// instead (returns false): no connection could carry it.
    pub fn push(&mut self, m: Message) -> bool {
        if packet_len(&m) > MAX_PACKET_BYTES {
            self.dropped += 1;
            return false;
        }
        self.queue.push_back(m);
        self.trim();
        true
    }

    /// The oldest message, to hand to the client.
    pub fn pop(&mut self) -> Option<Message> {
        self.queue.pop_front()
    }

    /// Puts messages handed to the client but not acknowledged back at the front,
    /// in their order (they are sent again: at least once). If that overfills the
    /// queue, the oldest are dropped.
    pub fn requeue(&mut self, unacked: impl DoubleEndedIterator<Item = Message>) {
        for m in unacked.rev() {
            self.queue.push_front(m);
        }
        self.trim();
    }

    /// Records that the broker acknowledged `m`.
    pub fn acked(&mut self, m: Message) {
        self.acked.push(m);
    }

    /// The messages acknowledged since the last call.
    pub fn take_acked(&mut self) -> Vec<Message> {
        std::mem::take(&mut self.acked)
    }

    /// Drops every queued message (the sink stops without a broker); returns
    /// how many.
    pub fn drop_all(&mut self) -> u64 {
        let n = self.queue.len() as u64;
        self.queue.clear();
        self.dropped += n;
        n
    }

    /// Messages waiting.
    pub fn len(&self) -> usize {
        self.queue.len()
    }

    /// True when nothing waits.
    pub fn is_empty(&self) -> bool {
        self.queue.is_empty()
    }

    /// Messages dropped so far.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    fn trim(&mut self) {
        while self.queue.len() > self.capacity {
            self.queue.pop_front();
            self.dropped += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn msg(n: u8) -> Message {
        Message {
            topic: "t".into(),
            payload: vec![n],
            arrived: Instant::now(),
            origin_wall_ns: 0,
        }
    }

    fn contents(o: &mut Outbox) -> Vec<u8> {
        std::iter::from_fn(|| o.pop())
            .map(|m| m.payload[0])
            .collect()
    }

    #[test]
    fn a_full_queue_drops_the_oldest_and_counts_it() {
        let mut o = Outbox::new(3);
        for n in 0..5 {
            o.push(msg(n));
        }
        assert_eq!(o.dropped(), 2);
        assert_eq!(contents(&mut o), vec![2, 3, 4]);
    }

    #[test]
    fn unacked_messages_go_back_to_the_front_in_order() {
        let mut o = Outbox::new(4);
        o.push(msg(3));
        o.push(msg(4));
        o.requeue(vec![msg(1), msg(2)].into_iter());
        assert_eq!(o.dropped(), 0);
        assert_eq!(contents(&mut o), vec![1, 2, 3, 4]);
        // Overfilled by the requeue: the oldest go.
        o.push(msg(3));
        o.push(msg(4));
        o.push(msg(5));
        o.requeue(vec![msg(1), msg(2)].into_iter());
        assert_eq!(o.dropped(), 1);
        assert_eq!(contents(&mut o), vec![2, 3, 4, 5]);
    }

    #[test]
    fn a_message_no_packet_can_carry_is_dropped_and_counted() {
        let mut o = Outbox::new(2);
        let mut big = msg(9);
        big.payload = vec![b'x'; MAX_PACKET_BYTES];
        assert!(!o.push(big));
        assert!(o.push(msg(1)));
        assert_eq!(o.dropped(), 1);
        assert_eq!(contents(&mut o), vec![1]);
    }

    #[test]
    fn every_message_is_acked_or_dropped() {
        let mut o = Outbox::new(2);
        for n in 0..4 {
            o.push(msg(n));
        }
        let m = o.pop().unwrap();
        o.acked(m);
        assert_eq!(o.take_acked().len(), 1);
        assert_eq!(o.drop_all(), 1);
        assert_eq!(o.dropped(), 3);
        assert!(o.is_empty());
    }
}
