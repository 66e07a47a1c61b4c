//! Where the cascade's long-term model lives: the [`LongTerm`] trait it commits
//! through, the SQLite store (timed, in the service), and a model in memory for
//! tests and benchmarks.

use std::collections::HashMap;
use std::time::Instant;

use isochron_runtime::health::quantile;
use isochron_store::{Baseline, Bin, MinuteCommit, Progress, Store, StoreError};

/// Where the long-term model lives: read one bin, commit one minute.
pub trait LongTerm {
    /// The model of bin `t_star`, if it has learned anything.
    fn bin(&mut self, t_star: u32) -> Result<Option<Bin>, StoreError>;
    /// Writes one completed minute atomically and durably.
    fn commit(&mut self, commit: &MinuteCommit<'_>) -> Result<(), StoreError>;
}

impl LongTerm for Store {
    fn bin(&mut self, t_star: u32) -> Result<Option<Bin>, StoreError> {
        self.read_bin(t_star)
    }

    fn commit(&mut self, commit: &MinuteCommit<'_>) -> Result<(), StoreError> {
        self.commit_minute(commit)
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
}

impl LongTerm for MemoryModel {
    fn bin(&mut self, t_star: u32) -> Result<Option<Bin>, StoreError> {
        Ok(self.bins.get(&t_star).cloned())
    }

    fn commit(&mut self, commit: &MinuteCommit<'_>) -> Result<(), StoreError> {
        if let Some(bin) = commit.bin {
            self.bins.insert(bin.t_star, bin.clone());
            self.progress.committed += 1;
        } else {
            self.progress.skipped += 1;
        }
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
    fn bin(&mut self, t_star: u32) -> Result<Option<Bin>, StoreError> {
        self.store.read_bin(t_star)
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
