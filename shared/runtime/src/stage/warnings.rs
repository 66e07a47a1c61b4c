//! Warnings that cannot flood the journal.

use std::collections::HashMap;
use std::time::{Duration, Instant};

/// Warnings of one kind issued at once before rate limiting starts.
const WARN_BURST: u64 = 10;
/// Then at most one warning of a kind per this interval (the rest are counted).
const WARN_EVERY: Duration = Duration::from_secs(5);

/// Warnings that cannot flood the journal: of each kind, the first
/// [`WARN_BURST`] at once, then at most one per [`WARN_EVERY`] with a count of the
/// ones held back.
#[derive(Debug, Default)]
pub struct Warnings {
    kinds: HashMap<&'static str, WarnState>,
}

#[derive(Debug, Default)]
struct WarnState {
    issued: u64,
    last: Option<Instant>,
    held_back: u64,
}

impl Warnings {
    /// Warns `message()` unless warnings of `kind` are being held back.
    pub fn warn(&mut self, kind: &'static str, message: impl FnOnce() -> String) {
        let now = Instant::now();
        let s = self.kinds.entry(kind).or_default();
        if s.issued >= WARN_BURST && s.last.is_some_and(|t| now.duration_since(t) < WARN_EVERY) {
            s.held_back += 1;
            return;
        }
        let held = std::mem::take(&mut s.held_back);
        if held > 0 {
            tracing::warn!("{} ({held} similar warnings held back)", message());
        } else {
            tracing::warn!("{}", message());
        }
        s.issued += 1;
        s.last = Some(now);
    }
}
