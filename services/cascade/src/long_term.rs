//! Where the cascade's long-term model lives: the [`LongTerm`] trait it commits
//! through, the SQLite store (timed, in the service), and a model in memory for
//! tests and benchmarks.

use std::collections::HashMap;
use std::time::Instant;

use isochron_runtime::health::quantile;
use isochron_store::{Baseline, Bin, MinuteCommit, Progress, Spans, Store, StoreError};

/// Where the long-term model lives: read one row, commit one minute, and which
/// minutes it completed.
pub trait LongTerm {
    /// Row `row` of the model, if it has learned anything.
    fn bin(&mut self, row: u32) -> Result<Option<Bin>, StoreError>;
    /// Writes one completed minute atomically and durably.
    fn commit(&mut self, commit: &MinuteCommit<'_>) -> Result<(), StoreError>;
    /// Whether absolute minute `minute` was completed before (delivered twice).
    fn completed(&self, minute: i64) -> bool;
    /// The latest minute completed.
    fn latest(&self) -> Option<i64>;
}

impl LongTerm for Store {
    fn bin(&mut self, row: u32) -> Result<Option<Bin>, StoreError> {
        self.read_bin(row)
    }

    fn commit(&mut self, commit: &MinuteCommit<'_>) -> Result<(), StoreError> {
        self.commit_minute(commit)
    }

    fn completed(&self, minute: i64) -> bool {
        self.spans().contains(minute)
    }

    fn latest(&self) -> Option<i64> {
        self.spans().latest()
    }
}

/// The long-term model in memory, for tests and benchmarks.
#[derive(Debug, Clone, Default)]
pub struct MemoryModel {
    /// Bins that learned anything.
    pub bins: HashMap<u32, Bin>,
    /// The last baseline committed.
    pub baseline: Option<Baseline>,
    /// Progress as a store would keep it.
    pub progress: Progress,
    /// The completed minutes.
    pub spans: Spans,
}

impl LongTerm for MemoryModel {
    fn bin(&mut self, row: u32) -> Result<Option<Bin>, StoreError> {
        Ok(self.bins.get(&row).cloned())
    }

    fn commit(&mut self, commit: &MinuteCommit<'_>) -> Result<(), StoreError> {
        for bin in commit.bins {
            self.bins.insert(bin.t_star, bin.clone());
        }
        if commit.bins.is_empty() {
            self.progress.skipped += 1;
        } else {
            self.progress.committed += 1;
        }
        self.spans.add(commit.minute);
        if let Some(b) = commit.baseline {
            self.baseline = Some(b.clone());
        }
        self.progress.last_minute = Some(
            self.progress
                .last_minute
                .map_or(commit.minute, |m| m.max(commit.minute)),
        );
        Ok(())
    }

    fn completed(&self, minute: i64) -> bool {
        self.spans.contains(minute)
    }

    fn latest(&self) -> Option<i64> {
        self.spans.latest()
    }
}

/// Commit latencies of a [`Store`], measured.
pub struct TimedStore {
    /// The store.
    pub store: Store,
    latencies_ms: Vec<f32>,
    cursor: usize,
    /// Commits so far.
    pub commits: u64,
}

impl TimedStore {
    /// Wraps `store`.
    pub fn new(store: Store) -> Self {
        TimedStore {
            store,
            latencies_ms: Vec::new(),
            cursor: 0,
            commits: 0,
        }
    }

    /// Median and 99th percentile of the recent commit latencies, ms.
    pub fn latency_ms(&self) -> (f32, f32) {
        (
            quantile(&self.latencies_ms, 0.5),
            quantile(&self.latencies_ms, 0.99),
        )
    }
}

impl LongTerm for TimedStore {
    fn bin(&mut self, row: u32) -> Result<Option<Bin>, StoreError> {
        self.store.read_bin(row)
    }

    fn completed(&self, minute: i64) -> bool {
        LongTerm::completed(&self.store, minute)
    }

    fn latest(&self) -> Option<i64> {
        LongTerm::latest(&self.store)
    }

    fn commit(&mut self, commit: &MinuteCommit<'_>) -> Result<(), StoreError> {
        let start = Instant::now();
        let result = self.store.commit_minute(commit);
        let ms = start.elapsed().as_secs_f32() * 1e3;
        if self.latencies_ms.len() < 1024 {
            self.latencies_ms.push(ms);
        } else {
            self.latencies_ms[self.cursor] = ms;
            self.cursor = (self.cursor + 1) % 1024;
        }
        self.commits += 1;
        result
    }
}
