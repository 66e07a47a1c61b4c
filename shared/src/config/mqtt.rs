//! `[mqtt]`: the MQTT sink (`isochron-mqtt`), which publishes zone events and
//! detections to a broker. Absent: nothing is published (nothing leaves the box).

use serde::{Deserialize, Serialize};

use super::{Invalid, check_range};

/// The broker port when the URL names none (MQTT over plain TCP).
pub const DEFAULT_MQTT_PORT: u16 = 1883;

/// `[mqtt]`: where and how `isochron-mqtt` publishes. The section's presence makes
/// `isochron up` and `isochron replay` start the sink with the group; under
/// systemd it runs when its unit is enabled.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MqttConfig {
    /// The broker, `mqtt://host:port` (port default 1883; plain TCP: `mqtts://`
    /// is not supported yet). Required.
    pub broker: String,
    /// The MQTT client id. Default `"isochron-<site>"`.
    pub client_id: Option<String>,
    /// First level of every topic. Default `"isochron"`.
    pub topic_prefix: String,
    /// The site's level in the topics (`<topic_prefix>/<site>/<camera>/events`).
    /// Default: `[site] name`.
    pub site: Option<String>,
    /// Messages held while the broker is slow or away; when full the oldest is
    /// dropped (and counted). Default 1000.
    pub queue_len: usize,
    /// MQTT keep-alive: the broker takes the sink for gone (and publishes its last
    /// will, "offline") after 1.5 times this without a packet. Default 30.
    pub keepalive_s: u64,
    /// Longest wait between reconnection attempts (the wait doubles from 0.5 s up
    /// to this). Default 30.
    pub reconnect_max_s: f64,
}

impl Default for MqttConfig {
    fn default() -> Self {
        MqttConfig {
            broker: String::new(),
            client_id: None,
            topic_prefix: "isochron".into(),
            site: None,
            queue_len: 1000,
            keepalive_s: 30,
            reconnect_max_s: 30.0,
        }
    }
}

/// True if `level` can be one level of an MQTT topic name: not empty, no `/`, no
/// wildcard (`+`, `#`), no NUL, no leading `$` (reserved for brokers).
pub fn is_topic_level(level: &str) -> bool {
    !level.is_empty()
        && !level.starts_with('$')
        && !level.contains(['/', '+', '#', '\0'])
        && level.len() <= 128
}

impl MqttConfig {
    /// The broker's host and port, from [`MqttConfig::broker`].
    pub fn broker_addr(&self) -> Result<(String, u16), Invalid> {
        let bad = |why: &str| {
            Invalid::new(
                "mqtt.broker",
                format!(
                    "expected a broker URL such as \"mqtt://127.0.0.1:1883\"{why}, found \"{}\"",
                    self.broker
                ),
            )
        };
        if self.broker.starts_with("mqtts://") || self.broker.starts_with("ssl://") {
            return Err(bad(" (TLS is not supported yet: use mqtt://)"));
        }
        let rest = self.broker.strip_prefix("mqtt://").ok_or_else(|| bad(""))?;
        let rest = rest.strip_suffix('/').unwrap_or(rest);
        let (host, port) = match rest.rsplit_once(':') {
            // An IPv6 address in brackets has colons of its own.
            Some((h, p)) if !p.contains(']') => {
                let port: u16 = p.parse().map_err(|_| bad(" (port 1 to 65535)"))?;
                (h, port)
            }
            _ => (rest, DEFAULT_MQTT_PORT),
        };
        let host = host
            .strip_prefix('[')
            .and_then(|h| h.strip_suffix(']'))
            .unwrap_or(host);
        let host_ok = !host.is_empty()
            && host
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || b"-.:_".contains(&b));
        if !host_ok || port == 0 {
            return Err(bad(""));
        }
        Ok((host.to_string(), port))
    }

    /// The site level of the topics: `site`, else `site_name` (`[site] name`).
    pub fn site_level<'a>(&'a self, site_name: &'a str) -> &'a str {
        self.site.as_deref().unwrap_or(site_name)
    }

    /// The client id: `client_id`, else `isochron-<site level>`.
    pub fn client_id(&self, site_name: &str) -> String {
        self.client_id
            .clone()
            .unwrap_or_else(|| format!("isochron-{}", self.site_level(site_name)))
    }

    /// Checks the `mqtt.*` keys; `site_name` is `[site] name`, the default site
    /// level.
    pub fn validate(&self, site_name: &str) -> Result<(), Invalid> {
        self.broker_addr()?;
        if !is_topic_level(&self.topic_prefix) {
            return Err(Invalid::found(
                "mqtt.topic_prefix",
                "one topic level without '/', '+', '#' or a leading '$', such as \"isochron\"",
                &self.topic_prefix,
            ));
        }
        let site = self.site_level(site_name);
        if !is_topic_level(site) {
            return Err(Invalid::found(
                "mqtt.site",
                "one topic level without '/', '+', '#' or a leading '$' (default: [site] name)",
                site,
            ));
        }
        let id = self.client_id(site_name);
        if id.is_empty() || id.len() > 65535 || id.contains('\0') {
            return Err(Invalid::found(
                "mqtt.client_id",
                "a non-empty client id",
                &id,
            ));
        }
        check_range("mqtt.queue_len", self.queue_len as f64, 1.0, 1_000_000.0)?;
        check_range("mqtt.keepalive_s", self.keepalive_s as f64, 5.0, 65535.0)?;
        check_range("mqtt.reconnect_max_s", self.reconnect_max_s, 0.5, 3600.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn with_broker(broker: &str) -> MqttConfig {
        MqttConfig {
            broker: broker.into(),
            ..Default::default()
        }
    }

    #[test]
    fn broker_urls() {
        for (url, host, port) in [
            ("mqtt://127.0.0.1:1883", "127.0.0.1", 1883),
            ("mqtt://broker.lan", "broker.lan", 1883),
            ("mqtt://broker.lan:8883/", "broker.lan", 8883),
            ("mqtt://[::1]:1884", "::1", 1884),
        ] {
            assert_eq!(
                with_broker(url).broker_addr(),
                Ok((host.to_string(), port)),
                "{url}"
            );
        }
        for bad in [
            "",
            "127.0.0.1:1883",
            "http://host:1883",
            "mqtt://",
            "mqtt://host:0",
            "mqtt://host:99999",
            "mqtt://host:port",
            "mqtt://ho st:1883",
            "mqtts://host:8883",
        ] {
            let e = with_broker(bad).validate("site").unwrap_err();
            assert_eq!(e.key, "mqtt.broker", "{bad}");
            assert!(e.message.contains(&format!("\"{bad}\"")), "{}", e.message);
        }
    }

    #[test]
    fn topic_levels_and_defaults() {
        let c = with_broker("mqtt://localhost");
        assert!(c.validate("depot").is_ok());
        assert_eq!(c.site_level("depot"), "depot");
        assert_eq!(c.client_id("depot"), "isochron-depot");
        assert_eq!(c.validate("a/b").unwrap_err().key, "mqtt.site");
        let c = MqttConfig {
            topic_prefix: "x/#".into(),
            ..with_broker("mqtt://localhost")
        };
        assert_eq!(c.validate("s").unwrap_err().key, "mqtt.topic_prefix");
        let c = MqttConfig {
            queue_len: 0,
            ..with_broker("mqtt://localhost")
        };
        assert_eq!(c.validate("s").unwrap_err().key, "mqtt.queue_len");
    }
}
