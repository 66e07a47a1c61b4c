//! `[site]`: settings for the whole site.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::{Invalid, check_range};

/// `[site]`: settings for the whole site.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SiteConfig {
    /// Name for people and logs. Default `"site"`.
    pub name: String,
    /// IANA time zone of the site, used for isochronal time t*. Default `"UTC"`.
    pub time_zone: String,
    /// Start of every iceoryx2 service name. Default `"isochron"`.
    pub service_prefix: String,
    /// Directory for state (the long-term store). Default `"/var/lib/isochron"`;
    /// relative paths are relative to the config file.
    pub state_dir: PathBuf,
    /// Cameras one process of a per-camera stage serves, when `isochron up` starts
    /// the group (each camera on its own thread; see docs/benchmarks.md, "Scale"). Default
    /// 1: one process per camera and stage.
    pub cameras_per_process: usize,
    /// How far capture yields the CPU to the analysis stages: capture runs
    /// `SCHED_BATCH` at this nice value (0..=19), so a frame's motion, cascade
    /// and gate work is not queued behind decoders. 0 runs capture as the other
    /// stages run. Default 5.
    pub capture_nice: i32,
}

impl Default for SiteConfig {
    fn default() -> Self {
        SiteConfig {
            name: "site".into(),
            time_zone: "UTC".into(),
            service_prefix: DEFAULT_PREFIX.into(),
            state_dir: PathBuf::from("/var/lib/isochron"),
            cameras_per_process: 1,
            capture_nice: 5,
        }
    }
}

impl SiteConfig {
    /// Checks the `site.*` keys.
    pub(super) fn validate(&self) -> Result<(), Invalid> {
        if jiff::tz::TimeZone::get(&self.time_zone).is_err() {
            return Err(Invalid::found(
                "site.time_zone",
                "an IANA time zone such as \"Europe/Berlin\" or \"UTC\"",
                &self.time_zone,
            ));
        }
        if !is_valid_prefix(&self.service_prefix) {
            return Err(Invalid::found(
                "site.service_prefix",
                "letters, digits, '_', '-', '.', '/' (not at either end)",
                &self.service_prefix,
            ));
        }
        check_range(
            "site.cameras_per_process",
            self.cameras_per_process as f64,
            1.0,
            1024.0,
        )?;
        check_range("site.capture_nice", self.capture_nice as f64, 0.0, 19.0)
    }
}

/// The default service prefix.
pub const DEFAULT_PREFIX: &str = "isochron";

/// True if `prefix` can start a service name: non-empty, no leading or trailing `/`,
/// and only `[A-Za-z0-9_./-]`.
pub fn is_valid_prefix(prefix: &str) -> bool {
    !prefix.is_empty()
        && !prefix.starts_with('/')
        && !prefix.ends_with('/')
        && prefix
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'_' | b'-' | b'.' | b'/'))
}
