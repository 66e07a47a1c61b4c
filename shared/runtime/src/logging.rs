//! Logging through `tracing`: to journald when the process's stderr is the
//! journal stream systemd connected it to, to stderr otherwise. The level comes
//! from `RUST_LOG` (default `info`).
//!
//! The records of the libraries that log through the `log` facade (RustDDS and
//! ros2-client report each malformed datagram) are rate-limited per module
//! ([`LibraryLogLimit`]): a flood of forged packets cannot flood the journal.
//!
//! `JOURNAL_STREAM` alone does not say that: it is inherited by every child, also
//! by the services `isochron up` or `replay` start (from a unit, or from a shell
//! that has it) with stderr redirected to a log file. As systemd.exec(5) says,
//! the process compares the variable's `device:inode` with its stderr's.

use std::collections::HashMap;
use std::io::IsTerminal;
use std::time::{Duration, Instant};

use parking_lot::Mutex;
use tracing::field::{Field, Visit};
use tracing_subscriber::EnvFilter;
use tracing_subscriber::layer::{Context, Layer, SubscriberExt};
use tracing_subscriber::util::SubscriberInitExt;

/// Installs the global subscriber for the process `name`. Safe to call once.
pub fn init(name: &str) {
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("info"));
    let registry = tracing_subscriber::registry()
        .with(filter)
        .with(LibraryLogLimit::default());
    if stderr_is_journal()
        && let Ok(journald) = tracing_journald::layer()
    {
        let _ = registry
            .with(journald.with_syslog_identifier(name.to_string()))
            .try_init();
        return;
    }
    let _ = registry
        .with(
            tracing_subscriber::fmt::layer()
                .with_writer(std::io::stderr)
                .with_ansi(std::io::stderr().is_terminal())
                .with_target(false),
        )
        .try_init();
}

/// Records of one library module let through at once before the limit holds.
const LOG_BURST: u32 = 10;
/// Then at most one record of that module per this period.
const LOG_EVERY: Duration = Duration::from_secs(10);

/// Rate-limits the records that reach `tracing` through the `log` facade, per
/// module (their `log.target`): the first [`LOG_BURST`], then one per
/// [`LOG_EVERY`], preceded by a count of the ones held back.
#[derive(Default)]
pub struct LibraryLogLimit {
    modules: Mutex<HashMap<String, Held>>,
}

#[derive(Default)]
struct Held {
    issued: u32,
    last: Option<Instant>,
    held_back: u64,
}

impl LibraryLogLimit {
    /// True if a record of `module` may pass now; the number held back since the
    /// last one that passed, if any.
    fn admit(&self, module: &str, now: Instant) -> (bool, u64) {
        let mut modules = self.modules.lock();
        let held = modules.entry(module.to_string()).or_default();
        if held.issued >= LOG_BURST && held.last.is_some_and(|t| now - t < LOG_EVERY) {
            held.held_back += 1;
            return (false, 0);
        }
        held.issued = held.issued.saturating_add(1);
        held.last = Some(now);
        (true, std::mem::take(&mut held.held_back))
    }
}

/// The `log.target` field of a record that came through the `log` facade.
#[derive(Default)]
struct LogTarget(String);

impl Visit for LogTarget {
    fn record_str(&mut self, field: &Field, value: &str) {
        if field.name() == "log.target" {
            self.0 = value.to_string();
        }
    }
    fn record_debug(&mut self, _: &Field, _: &dyn std::fmt::Debug) {}
}

impl<S: tracing::Subscriber> Layer<S> for LibraryLogLimit {
    fn event_enabled(&self, event: &tracing::Event<'_>, _: Context<'_, S>) -> bool {
        // tracing-log gives every record of the `log` facade the target "log".
        if event.metadata().target() != "log" {
            return true;
        }
        let mut module = LogTarget::default();
        event.record(&mut module);
        let (pass, held_back) = self.admit(&module.0, Instant::now());
        if pass && held_back > 0 {
            tracing::warn!("{held_back} log records of {} held back", module.0);
        }
        pass
    }
}

/// True when stderr is the stream `JOURNAL_STREAM` names.
fn stderr_is_journal() -> bool {
    let Some(value) = std::env::var_os("JOURNAL_STREAM") else {
        return false;
    };
    // SAFETY: stat is plain integers, for which all-zero bytes are a valid value.
    let mut st: libc::stat = unsafe { std::mem::zeroed() };
    // SAFETY: `st` is a writable stat and fstat(2) writes only it; any descriptor
    // number is safe to pass (a closed one is an error, EBADF).
    if unsafe { libc::fstat(libc::STDERR_FILENO, &mut st) } != 0 {
        return false;
    }
    names_stream(&value.to_string_lossy(), st.st_dev, st.st_ino)
}

/// True when `journal_stream` (`JOURNAL_STREAM`, `device:inode` in decimal) is
/// `dev`:`ino`.
fn names_stream(journal_stream: &str, dev: u64, ino: u64) -> bool {
    journal_stream
        .split_once(':')
        .and_then(|(d, i)| Some((d.parse::<u64>().ok()?, i.parse::<u64>().ok()?)))
        == Some((dev, ino))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_flood_of_library_records_is_held_back_and_counted() {
        let limit = LibraryLogLimit::default();
        let t0 = Instant::now();
        let passed = (0..1000)
            .filter(|_| limit.admit("rustdds::rtps::reader", t0).0)
            .count();
        assert_eq!(passed, LOG_BURST as usize);
        // Another module has its own budget.
        assert!(limit.admit("ros2_client::node", t0).0);
        // After the period one passes, with the count of those held back.
        assert_eq!(
            limit.admit("rustdds::rtps::reader", t0 + LOG_EVERY),
            (true, 990)
        );
        assert!(!limit.admit("rustdds::rtps::reader", t0 + LOG_EVERY).0);
    }

    #[test]
    fn only_the_named_stream_is_the_journal() {
        assert!(names_stream("2049:123456", 2049, 123456));
        assert!(!names_stream("2049:123456", 2049, 123457));
        assert!(!names_stream("2049:123456", 2050, 123456));
        assert!(!names_stream("", 0, 0));
        assert!(!names_stream("x:y", 0, 0));
    }
}
