//! The sink's TLS client configuration (rustls, ring provider) from `[mqtt]`'s
//! files: the CA certificates the broker's certificate must chain to, and the
//! optional client certificate and key for brokers that require one (mutual
//! TLS). Read once at start; every problem names its key and file.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use isochron_config::{Invalid, MqttConfig};
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer};
use rustls::{ClientConfig, RootCertStore};

/// The rustls configuration of an `mqtts://` broker, or `None` for `mqtt://`.
/// Relative paths are resolved against `base` (the config file's directory).
pub fn client_config(
    config: &MqttConfig,
    base: &Path,
) -> Result<Option<Arc<ClientConfig>>, Invalid> {
    let Some(ca_file) = &config.ca_file else {
        return Ok(None);
    };
    let ca_path = resolve(base, ca_file);
    let cas = certificates("mqtt.ca_file", &ca_path)?;
    let mut roots = RootCertStore::empty();
    let (added, ignored) = roots.add_parsable_certificates(cas);
    if added == 0 {
        return Err(Invalid::new(
            "mqtt.ca_file",
            format!(
                "expected at least one valid CA certificate in {} ({ignored} could not be used)",
                ca_path.display()
            ),
        ));
    }
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let builder = ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .map_err(|e| Invalid::new("mqtt.broker", format!("TLS setup failed: {e}")))?
        .with_root_certificates(roots);
    let tls = match (&config.client_cert_file, &config.client_key_file) {
        (Some(cert_file), Some(key_file)) => {
            let cert_path = resolve(base, cert_file);
            let chain = certificates("mqtt.client_cert_file", &cert_path)?;
            let key_path = resolve(base, key_file);
            let key = PrivateKeyDer::from_pem_file(&key_path).map_err(|e| {
                Invalid::new(
                    "mqtt.client_key_file",
                    format!(
                        "expected a PEM private key (PKCS#8, PKCS#1 or SEC1) in {}: {}",
                        key_path.display(),
                        pem_error(&e)
                    ),
                )
            })?;
            warn_if_readable_by_others("mqtt.client_key_file", &key_path);
            builder.with_client_auth_cert(chain, key).map_err(|e| {
                Invalid::new(
                    "mqtt.client_key_file",
                    format!("expected the private key of {}: {e}", cert_path.display()),
                )
            })?
        }
        _ => builder.with_no_client_auth(),
    };
    Ok(Some(Arc::new(tls)))
}

/// `path`, relative to `base` unless absolute.
pub fn resolve(base: &Path, path: &Path) -> PathBuf {
    if path.is_absolute() {
        path.to_path_buf()
    } else {
        base.join(path)
    }
}

/// The PEM certificates in `path`, at least one.
fn certificates(key: &str, path: &Path) -> Result<Vec<CertificateDer<'static>>, Invalid> {
    let bad = |why: String| {
        Invalid::new(
            key,
            format!(
                "expected a PEM file of certificates, {}: {why}",
                path.display()
            ),
        )
    };
    let certs = CertificateDer::pem_file_iter(path)
        .map_err(|e| bad(pem_error(&e)))?
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| bad(pem_error(&e)))?;
    if certs.is_empty() {
        return Err(bad("it has no CERTIFICATE section".into()));
    }
    Ok(certs)
}

/// A PEM error in words (an I/O error as the OS says it).
fn pem_error(e: &rustls::pki_types::pem::Error) -> String {
    use rustls::pki_types::pem::Error;
    match e {
        Error::Io(io) => io.to_string(),
        Error::NoItemsFound => "no item of that kind found".into(),
        other => format!("{other:?}"),
    }
}

/// Warns when the secret in `path` can be read by users other than its owner.
pub fn warn_if_readable_by_others(key: &str, path: &Path) {
    use std::os::unix::fs::PermissionsExt;
    if let Ok(meta) = std::fs::metadata(path)
        && meta.permissions().mode() & 0o077 != 0
    {
        tracing::warn!(
            "{key}: {} can be read by other users (mode {:o}): chmod 600 it",
            path.display(),
            meta.permissions().mode() & 0o777
        );
    }
}
