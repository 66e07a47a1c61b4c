//! The user name and password the sink connects with, from `[mqtt]`: the
//! password is read once from `password_file` (its first line) or the
//! environment variable `password_env`, and is never printed — its `Debug` and
//! `Display` say `<redacted>`.

use std::fmt;
use std::path::Path;

use isochron_config::{Invalid, MqttConfig};

use crate::tls::{resolve, warn_if_readable_by_others};

/// A password that does not print.
#[derive(Clone, PartialEq, Eq)]
pub struct Password(String);

impl Password {
    /// The password itself, for the CONNECT packet only.
    pub fn expose(&self) -> &str {
        &self.0
    }
}

impl fmt::Debug for Password {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("<redacted>")
    }
}

impl fmt::Display for Password {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("<redacted>")
    }
}

/// A user name and its password, if any.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Login {
    /// The user name.
    pub username: String,
    /// The password (MQTT allows a user name alone).
    pub password: Option<Password>,
}

/// The login of `config`, `None` when it names no user. Relative paths are
/// resolved against `base` (the config file's directory).
pub fn login(config: &MqttConfig, base: &Path) -> Result<Option<Login>, Invalid> {
    let Some(username) = &config.username else {
        return Ok(None);
    };
    let password = if let Some(file) = &config.password_file {
        let path = resolve(base, file);
        let text = std::fs::read_to_string(&path).map_err(|e| {
            Invalid::new(
                "mqtt.password_file",
                format!(
                    "expected a readable file whose first line is the password, {}: {e}",
                    path.display()
                ),
            )
        })?;
        warn_if_readable_by_others("mqtt.password_file", &path);
        let first = text.lines().next().unwrap_or("");
        if first.is_empty() {
            return Err(Invalid::new(
                "mqtt.password_file",
                format!(
                    "expected the password on the first line of {}, found an empty line",
                    path.display()
                ),
            ));
        }
        Some(Password(first.to_string()))
    } else if let Some(var) = &config.password_env {
        match std::env::var(var) {
            Ok(p) if !p.is_empty() => Some(Password(p)),
            _ => {
                return Err(Invalid::new(
                    "mqtt.password_env",
                    format!(
                        "expected the password in the environment variable {var}, which is not set or empty"
                    ),
                ));
            }
        }
    } else {
        None
    };
    Ok(Some(Login {
        username: username.clone(),
        password,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_password_comes_from_the_first_line_and_never_prints() {
        let dir = std::env::temp_dir().join(format!("isochron-login-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("pw"), "s3cret-word\nignored\n").unwrap();
        let config = MqttConfig {
            username: Some("isochron".into()),
            password_file: Some("pw".into()),
            ..Default::default()
        };
        let login = login(&config, &dir).unwrap().unwrap();
        assert_eq!(login.password.as_ref().unwrap().expose(), "s3cret-word");
        let shown = format!("{login:?} {}", login.password.as_ref().unwrap());
        assert!(!shown.contains("s3cret"), "{shown}");
        assert!(shown.contains("<redacted>"), "{shown}");

        std::fs::write(dir.join("pw"), "\n").unwrap();
        let e = super::login(&config, &dir).unwrap_err();
        assert_eq!(e.key, "mqtt.password_file");
        let missing = MqttConfig {
            password_file: Some("nope".into()),
            ..config.clone()
        };
        let e = super::login(&missing, &dir).unwrap_err();
        assert!(e.message.contains("nope"), "{}", e.message);
        let env = MqttConfig {
            password_file: None,
            password_env: Some("ISOCHRON_TEST_UNSET_PASSWORD".into()),
            ..config
        };
        let e = super::login(&env, &dir).unwrap_err();
        assert_eq!(e.key, "mqtt.password_env");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
