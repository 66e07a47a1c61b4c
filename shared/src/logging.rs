//! Logging through `tracing`: to journald when the process's stderr is the
//! journal stream systemd connected it to, to stderr otherwise. The level comes
//! from `RUST_LOG` (default `info`).
//!
//! `JOURNAL_STREAM` alone does not say that: it is inherited by every child, also
//! by the services `isochron up` or `replay` start (from a unit, or from a shell
//! that has it) with stderr redirected to a log file. As systemd.exec(5) says,
//! the process compares the variable's `device:inode` with its stderr's.

use std::io::IsTerminal;

use tracing_subscriber::EnvFilter;
use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::util::SubscriberInitExt;

/// Installs the global subscriber for the process `name`. Safe to call once.
pub fn init(name: &str) {
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("info"));
    let registry = tracing_subscriber::registry().with(filter);
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

/// True when stderr is the stream `JOURNAL_STREAM` names.
fn stderr_is_journal() -> bool {
    let Some(value) = std::env::var_os("JOURNAL_STREAM") else {
        return false;
    };
    // SAFETY: fstat fills the zeroed struct for a descriptor we only inspect.
    let mut st: libc::stat = unsafe { std::mem::zeroed() };
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
    fn only_the_named_stream_is_the_journal() {
        assert!(names_stream("2049:123456", 2049, 123456));
        assert!(!names_stream("2049:123456", 2049, 123457));
        assert!(!names_stream("2049:123456", 2050, 123456));
        assert!(!names_stream("", 0, 0));
        assert!(!names_stream("x:y", 0, 0));
    }
}
