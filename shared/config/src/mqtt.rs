//! `[mqtt]`: the MQTT sink (`isochron-mqtt`), which publishes zone events and
//! detections to a broker. Absent: nothing is published (nothing leaves the box).

use std::net::IpAddr;
use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::{Invalid, check_range};

/// The broker port when an `mqtt://` URL names none (MQTT over plain TCP).
pub const DEFAULT_MQTT_PORT: u16 = 1883;
/// The broker port when an `mqtts://` URL names none (MQTT over TLS).
pub const DEFAULT_MQTTS_PORT: u16 = 8883;

/// `[mqtt]`: where and how `isochron-mqtt` publishes. The section's presence makes
/// `isochron up` and `isochron replay` start the sink with the group; under
/// systemd it runs when its unit is enabled.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MqttConfig {
    /// The broker, `mqtt://host[:port]` (plain TCP, port default 1883) or
    /// `mqtts://host[:port]` (TLS, port default 8883; needs `ca_file`). Required.
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
    /// to this), also after the broker refused the sink. Default 30.
    pub reconnect_max_s: f64,
    /// `mqtts://` only: PEM file of the CA certificate(s) the broker's certificate
    /// must chain to (for a broker with a public certificate, the system's
    /// `/etc/ssl/certs/ca-certificates.crt`). Relative paths are relative to the
    /// config file. Required with `mqtts://`.
    pub ca_file: Option<PathBuf>,
    /// `mqtts://` only: PEM certificate the sink presents to a broker that
    /// requires client certificates (mutual TLS); needs `client_key_file`.
    pub client_cert_file: Option<PathBuf>,
    /// `mqtts://` only: PEM private key (PKCS#8, PKCS#1 or SEC1) of
    /// `client_cert_file`.
    pub client_key_file: Option<PathBuf>,
    /// User name the sink connects with. Default: none (anonymous).
    pub username: Option<String>,
    /// File whose first line is the password (e.g. a systemd credential,
    /// `/run/credentials/isochron-mqtt.service/mqtt-password`). Needs `username`.
    pub password_file: Option<PathBuf>,
    /// Environment variable holding the password, instead of `password_file`.
    /// Needs `username`.
    pub password_env: Option<String>,
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
            ca_file: None,
            client_cert_file: None,
            client_key_file: None,
            username: None,
            password_file: None,
            password_env: None,
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
    /// The broker's host, port and transport, from [`MqttConfig::broker`].
    pub fn broker_addr(&self) -> Result<Broker, Invalid> {
        let bad = |why: &str| {
            Invalid::new(
                "mqtt.broker",
                format!(
                    "expected a broker URL such as \"mqtt://127.0.0.1:1883\" or \"mqtts://broker.lan:8883\"{why}, found \"{}\"",
                    self.broker
                ),
            )
        };
        let (rest, tls) = if let Some(rest) = self.broker.strip_prefix("mqtts://") {
            (rest, true)
        } else if let Some(rest) = self.broker.strip_prefix("mqtt://") {
            (rest, false)
        } else {
            return Err(bad(""));
        };
        let rest = rest.strip_suffix('/').unwrap_or(rest);
        let default_port = if tls {
            DEFAULT_MQTTS_PORT
        } else {
            DEFAULT_MQTT_PORT
        };
        let (host, port) = match rest.rsplit_once(':') {
            // An IPv6 address in brackets has colons of its own.
            Some((h, p)) if !p.contains(']') => {
                let port: u16 = p.parse().map_err(|_| bad(" (port 1 to 65535)"))?;
                (h, port)
            }
            _ => (rest, default_port),
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
        Ok(Broker {
            host: host.to_string(),
            port,
            tls,
        })
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
    /// level. Files are only named here; the sink reads them when it starts.
    pub fn validate(&self, site_name: &str) -> Result<(), Invalid> {
        let broker = self.broker_addr()?;
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
        check_range("mqtt.reconnect_max_s", self.reconnect_max_s, 0.5, 3600.0)?;
        self.validate_security(&broker)
    }

    /// Checks the TLS and credential keys against the broker's transport.
    fn validate_security(&self, broker: &Broker) -> Result<(), Invalid> {
        let tls_keys = [
            ("mqtt.ca_file", &self.ca_file),
            ("mqtt.client_cert_file", &self.client_cert_file),
            ("mqtt.client_key_file", &self.client_key_file),
        ];
        for (key, value) in tls_keys {
            if value.as_ref().is_some_and(|p| p.as_os_str().is_empty()) {
                return Err(Invalid::new(key, "expected a file path, found \"\""));
            }
            if value.is_some() && !broker.tls {
                return Err(Invalid::new(
                    key,
                    format!(
                        "expected an mqtts:// broker for TLS settings, found \"{}\"",
                        self.broker
                    ),
                ));
            }
        }
        if broker.tls && self.ca_file.is_none() {
            return Err(Invalid::new(
                "mqtt.ca_file",
                "expected the PEM file of the CA that signed the broker's certificate (mqtts:// needs it; for a public CA: \"/etc/ssl/certs/ca-certificates.crt\")",
            ));
        }
        match (&self.client_cert_file, &self.client_key_file) {
            (Some(_), None) => {
                return Err(Invalid::new(
                    "mqtt.client_key_file",
                    "expected the private key of mqtt.client_cert_file (both or neither)",
                ));
            }
            (None, Some(_)) => {
                return Err(Invalid::new(
                    "mqtt.client_cert_file",
                    "expected the certificate of mqtt.client_key_file (both or neither)",
                ));
            }
            _ => {}
        }
        if let Some(user) = &self.username
            && (user.is_empty() || user.len() > 65535 || user.contains('\0'))
        {
            return Err(Invalid::found(
                "mqtt.username",
                "a non-empty user name",
                user,
            ));
        }
        let password_key = match (&self.password_file, &self.password_env) {
            (Some(_), Some(_)) => {
                return Err(Invalid::new(
                    "mqtt.password_env",
                    "expected one of mqtt.password_file and mqtt.password_env, found both",
                ));
            }
            (Some(_), None) => Some("mqtt.password_file"),
            (None, Some(var)) => {
                let name_ok = !var.is_empty()
                    && !var.starts_with(|c: char| c.is_ascii_digit())
                    && var.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'_');
                if !name_ok {
                    return Err(Invalid::found(
                        "mqtt.password_env",
                        "the name of an environment variable such as \"ISOCHRON_MQTT_PASSWORD\"",
                        var,
                    ));
                }
                Some("mqtt.password_env")
            }
            (None, None) => None,
        };
        if let Some(key) = password_key {
            if self.username.is_none() {
                return Err(Invalid::new(
                    "mqtt.username",
                    format!("expected the user name that {key} is the password of"),
                ));
            }
            if !broker.tls && !broker.is_loopback() {
                return Err(Invalid::new(
                    key,
                    format!(
                        "expected an mqtts:// broker: a password to \"{}\" would cross the network in clear",
                        self.broker
                    ),
                ));
            }
        }
        Ok(())
    }
}

/// Where the broker is and how to reach it, from `mqtt.broker`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Broker {
    /// Host name or IP address.
    pub host: String,
    /// TCP port.
    pub port: u16,
    /// True for `mqtts://` (TLS).
    pub tls: bool,
}

impl Broker {
    /// True when the broker is on this machine (`localhost`, 127.0.0.0/8, `::1`).
    pub fn is_loopback(&self) -> bool {
        self.host == "localhost" || self.host.parse::<IpAddr>().is_ok_and(|ip| ip.is_loopback())
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
        for (url, host, port, tls) in [
            ("mqtt://127.0.0.1:1883", "127.0.0.1", 1883, false),
            ("mqtt://broker.lan", "broker.lan", 1883, false),
            ("mqtt://broker.lan:8883/", "broker.lan", 8883, false),
            ("mqtt://[::1]:1884", "::1", 1884, false),
            ("mqtts://broker.lan", "broker.lan", 8883, true),
            ("mqtts://10.0.0.7:18883", "10.0.0.7", 18883, true),
        ] {
            let expected = Broker {
                host: host.to_string(),
                port,
                tls,
            };
            assert_eq!(with_broker(url).broker_addr(), Ok(expected), "{url}");
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
            "ssl://host:8883",
            "mqtts://",
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

    #[test]
    fn tls_and_credentials_are_checked_against_the_transport() {
        let tls = |f: fn(&mut MqttConfig)| {
            let mut c = MqttConfig {
                ca_file: Some("ca.pem".into()),
                ..with_broker("mqtts://broker.lan")
            };
            f(&mut c);
            c.validate("s")
        };
        assert!(tls(|_| {}).is_ok());
        let e = tls(|c| c.ca_file = None).unwrap_err();
        assert_eq!(e.key, "mqtt.ca_file");
        assert!(e.message.contains("mqtts:// needs it"), "{}", e.message);
        let e = tls(|c| c.client_cert_file = Some("me.pem".into())).unwrap_err();
        assert_eq!(e.key, "mqtt.client_key_file");
        let e = tls(|c| c.client_key_file = Some("me.key".into())).unwrap_err();
        assert_eq!(e.key, "mqtt.client_cert_file");
        assert!(
            tls(|c| {
                c.client_cert_file = Some("me.pem".into());
                c.client_key_file = Some("me.key".into());
            })
            .is_ok()
        );
        // A password needs a user name, one source, and TLS off this machine.
        let e = tls(|c| c.password_file = Some("pw".into())).unwrap_err();
        assert_eq!(e.key, "mqtt.username");
        assert!(
            tls(|c| {
                c.username = Some("isochron".into());
                c.password_env = Some("MQTT_PW".into());
            })
            .is_ok()
        );
        let e = tls(|c| {
            c.username = Some("isochron".into());
            c.password_env = Some("2 bad".into());
        })
        .unwrap_err();
        assert_eq!(e.key, "mqtt.password_env");
        let e = tls(|c| {
            c.username = Some("isochron".into());
            c.password_env = Some("MQTT_PW".into());
            c.password_file = Some("pw".into());
        })
        .unwrap_err();
        assert!(e.message.contains("found both"), "{}", e.message);

        let plain = |broker: &str| MqttConfig {
            username: Some("isochron".into()),
            password_file: Some("pw".into()),
            ..with_broker(broker)
        };
        let e = plain("mqtt://broker.lan").validate("s").unwrap_err();
        assert_eq!(e.key, "mqtt.password_file");
        assert!(e.message.contains("in clear"), "{}", e.message);
        assert!(plain("mqtt://127.0.0.1").validate("s").is_ok());
        assert!(plain("mqtt://localhost:1884").validate("s").is_ok());
        let e = MqttConfig {
            ca_file: Some("ca.pem".into()),
            ..with_broker("mqtt://broker.lan")
        }
        .validate("s")
        .unwrap_err();
        assert_eq!(e.key, "mqtt.ca_file");
        assert!(e.message.contains("mqtts://"), "{}", e.message);
    }
}
