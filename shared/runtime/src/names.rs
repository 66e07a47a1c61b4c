//! iceoryx2 service names: the only place they are spelled.
//!
//! Every stream of a camera is `<prefix>/<camera>/<stream>`; the prefix defaults to
//! `isochron` and is set per site in the config (`site.service_prefix`), so that
//! tests and replays run side by side without ever meeting.

use crate::topology::StageKind;
pub use isochron_config::{DEFAULT_PREFIX, is_valid_prefix};
use isochron_wire::Stream;

/// Service names under one prefix.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ServiceNames {
    prefix: String,
}

impl ServiceNames {
    /// Names under `prefix` (no trailing slash).
    pub fn new(prefix: impl Into<String>) -> Self {
        ServiceNames {
            prefix: prefix.into(),
        }
    }

    /// The prefix.
    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    /// `<prefix>/<camera>/<stream>`: the publish-subscribe service and, under the same
    /// name, the event service that wakes its subscribers.
    pub fn stream(&self, camera: &str, stream: Stream) -> String {
        format!("{}/{camera}/{}", self.prefix, stream.name())
    }

    /// `<prefix>/<camera>/status/<stage>`: the periodic status of one stage; for a
    /// site-wide stage (empty `camera`), `<prefix>/status/<stage>`.
    pub fn status(&self, camera: &str, stage: StageKind) -> String {
        if camera.is_empty() {
            format!("{}/status/{stage}", self.prefix)
        } else {
            format!("{}/{camera}/status/{stage}", self.prefix)
        }
    }

    /// `<prefix>/plan`: the request-response planning service.
    pub fn plan(&self) -> String {
        format!("{}/plan", self.prefix)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::topology::StageKind;

    #[test]
    fn names_follow_the_design() {
        let n = ServiceNames::new(DEFAULT_PREFIX);
        assert_eq!(n.stream("cam01", Stream::Frames), "isochron/cam01/frames");
        assert_eq!(
            n.stream("cam01", Stream::Activity),
            "isochron/cam01/activity"
        );
        assert_eq!(
            n.status("cam01", StageKind::Motion),
            "isochron/cam01/status/motion"
        );
        assert_eq!(n.status("", StageKind::Costmap), "isochron/status/costmap");
        let t = ServiceNames::new("test-42");
        assert_eq!(t.stream("c", Stream::Events), "test-42/c/events");
    }

    #[test]
    fn prefixes() {
        assert!(is_valid_prefix("isochron"));
        assert!(is_valid_prefix("t/replay-1"));
        assert!(!is_valid_prefix(""));
        assert!(!is_valid_prefix("/abs"));
        assert!(!is_valid_prefix("a b"));
    }
}
