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
    /// Connections open at once, at most. At the limit a new connection closes
    /// the one that has waited longest without sending a complete request; if
    /// every open connection is being answered, the new one gets 503. Default 64.
    pub max_connections: usize,
    /// Largest request head (request line and headers), bytes; a larger one is
    /// answered 431 and the connection closed. Default 8192.
    pub max_header_bytes: usize,
    /// A connection must send its request and take the whole answer within this;
    /// else it is closed (a connection serves one request). Default 10 (the
    /// default `scrape_timeout` of Prometheus).
    pub request_timeout_s: f64,
}

impl Default for ExporterConfig {
    fn default() -> Self {
        ExporterConfig {
            listen: "127.0.0.1:9464".into(),
            stale_after_s: 15.0,
            max_connections: 64,
            max_header_bytes: 8192,
            request_timeout_s: 10.0,
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
        check_range("exporter.stale_after_s", self.stale_after_s, 6.0, 3600.0)?;
        check_range(
            "exporter.max_connections",
            self.max_connections as f64,
            1.0,
            4096.0,
        )?;
        check_range(
            "exporter.max_header_bytes",
            self.max_header_bytes as f64,
            1024.0,
            1_048_576.0,
        )?;
        check_range(
            "exporter.request_timeout_s",
            self.request_timeout_s,
            0.5,
            300.0,
        )
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
        for (c, key) in [
            (
                ExporterConfig {
                    max_connections: 0,
                    ..Default::default()
                },
                "exporter.max_connections",
            ),
            (
                ExporterConfig {
                    max_header_bytes: 100,
                    ..Default::default()
                },
                "exporter.max_header_bytes",
            ),
            (
                ExporterConfig {
                    request_timeout_s: f64::NAN,
                    ..Default::default()
                },
                "exporter.request_timeout_s",
            ),
        ] {
            let e = c.validate().unwrap_err();
            assert_eq!(e.key, key);
            assert!(e.message.starts_with("expected a number from"), "{e:?}");
        }
    }
}
