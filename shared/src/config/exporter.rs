//! `[exporter]`: the Prometheus exporter (`isochron-exporter`).

use std::net::SocketAddr;

use serde::{Deserialize, Serialize};

use super::{Invalid, check_range};

/// `[exporter]`: where `isochron-exporter` serves every stage's status as
/// Prometheus/OpenMetrics metrics (`GET /metrics`). The section's presence also
/// makes `isochron up` and `isochron replay` start the exporter with the group;
/// under systemd it runs when its unit is enabled, with these values (or the
/// defaults, without the section).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ExporterConfig {
    /// Address and port to listen on. Default `"127.0.0.1:9464"` (this machine
    /// only); set e.g. `"0.0.0.0:9464"` for a Prometheus on another host.
    pub listen: String,
    /// A service whose last status report is older than this counts as down
    /// (`isochron_up` 0). Services report every 5 s. Default 15.
    pub stale_after_s: f64,
}

impl Default for ExporterConfig {
    fn default() -> Self {
        ExporterConfig {
            listen: "127.0.0.1:9464".into(),
            stale_after_s: 15.0,
        }
    }
}

impl ExporterConfig {
    /// The listen address (validated by [`ExporterConfig::validate`]).
    pub fn listen_addr(&self) -> Result<SocketAddr, Invalid> {
        self.listen.parse().map_err(|_| {
            Invalid::found(
                "exporter.listen",
                "an IP address and port such as \"127.0.0.1:9464\"",
                &self.listen,
            )
        })
    }

    /// Checks the `exporter.*` keys.
    pub(super) fn validate(&self) -> Result<(), Invalid> {
        self.listen_addr()?;
        // Below the 5 s report period every service would flap.
        check_range("exporter.stale_after_s", self.stale_after_s, 6.0, 3600.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn listen_must_be_an_address_and_port() {
        assert!(ExporterConfig::default().validate().is_ok());
        for bad in ["localhost:9464", "127.0.0.1", "127.0.0.1:99999", ""] {
            let c = ExporterConfig {
                listen: bad.into(),
                ..Default::default()
            };
            let e = c.validate().unwrap_err();
            assert_eq!(e.key, "exporter.listen");
            assert!(e.message.contains(bad), "{}", e.message);
        }
        let c = ExporterConfig {
            stale_after_s: 2.0,
            ..Default::default()
        };
        assert_eq!(c.validate().unwrap_err().key, "exporter.stale_after_s");
    }
}
