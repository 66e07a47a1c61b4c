//! What each stream of each camera did: the counts behind the status detail and
//! the stop summary.

/// What one stream of one camera did.
#[derive(Debug, Default, Clone, Copy)]
pub(super) struct Counts {
    /// Messages sent (export) or written into iceoryx2 (import).
    pub(super) messages: u64,
    /// Bytes of CDR sent.
    pub(super) bytes: u64,
    /// Dropped before sending: a full queue, a newer activity, a gap upstream.
    pub(super) dropped: u64,
    /// Missing in the received sequence.
    pub(super) gaps: u64,
    /// Failed writes.
    pub(super) errors: u64,
}

impl std::ops::AddAssign for Counts {
    fn add_assign(&mut self, o: Counts) {
        self.messages += o.messages;
        self.bytes += o.bytes;
        self.dropped += o.dropped;
        self.gaps += o.gaps;
        self.errors += o.errors;
    }
}

/// Counts gaps in a received sequence; a sequence going backwards is a
/// restarted publisher, not a loss.
pub(super) fn gap(last: &mut Option<u64>, sequence: u64) -> u64 {
    let missing = match *last {
        Some(l) if sequence > l + 1 => sequence - l - 1,
        _ => 0,
    };
    *last = Some(sequence);
    missing
}
