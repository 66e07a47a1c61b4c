//! Why a live camera is down: one reason per failure, shown in the log, in
//! `isochron status` and as one `/metrics` gauge per reason.

use std::fmt;

use isochron_runtime::counters::{CounterId, capture};

/// Why a live camera delivers no frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DownReason {
    /// Nothing accepts the connection: the camera, its server or its port is off.
    Refused,
    /// No answer within `connect_timeout_s`: unplugged, unreachable, overloaded.
    TimedOut,
    /// The camera refuses the URL's credentials.
    Unauthorized,
    /// No stream at the URL's path, an unknown host name, a missing device.
    NotFound,
    /// Open, but no frame for `read_timeout_s`.
    Stalled,
    /// What the camera sends cannot be decoded.
    BadStream,
    /// Anything else (the WARN line says what).
    Other,
}

impl DownReason {
    /// Every reason, in the order of their gauges.
    pub const ALL: [DownReason; 7] = [
        DownReason::Refused,
        DownReason::TimedOut,
        DownReason::Unauthorized,
        DownReason::NotFound,
        DownReason::Stalled,
        DownReason::BadStream,
        DownReason::Other,
    ];

    /// The word status lines and the docs use.
    pub fn as_str(self) -> &'static str {
        match self {
            DownReason::Refused => "refused",
            DownReason::TimedOut => "timed_out",
            DownReason::Unauthorized => "unauthorized",
            DownReason::NotFound => "not_found",
            DownReason::Stalled => "stalled",
            DownReason::BadStream => "bad_stream",
            DownReason::Other => "other",
        }
    }

    /// The gauge that is 1 while the camera is down for this reason.
    pub fn counter(self) -> CounterId {
        match self {
            DownReason::Refused => capture::DOWN_REFUSED,
            DownReason::TimedOut => capture::DOWN_TIMED_OUT,
            DownReason::Unauthorized => capture::DOWN_UNAUTHORIZED,
            DownReason::NotFound => capture::DOWN_NOT_FOUND,
            DownReason::Stalled => capture::DOWN_STALLED,
            DownReason::BadStream => capture::DOWN_BAD_STREAM,
            DownReason::Other => capture::DOWN_OTHER,
        }
    }
}

impl fmt::Display for DownReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use isochron_runtime::counters::capture::SCHEMA;

    #[test]
    fn each_reason_has_its_own_gauge_named_after_it() {
        for reason in DownReason::ALL {
            let spec = SCHEMA[reason.counter().0];
            assert_eq!(spec.name, format!("down_{reason}"));
        }
    }
}
