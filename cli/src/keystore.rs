//! `isochron keystore`: the DDS Security keystore of a site's links, in the
//! layout of an SROS2 keystore, made with the `openssl` command (the steps are
//! the ones docs/many-boxes.md, "DDS Security and the keystore", lists for
//! doing it by hand).
//!
//! * `init DIR`: the site's certificate authority (one CA signs identities and
//!   permissions, as SROS2 does: `DIR/private/ca.key.pem`, which stays with the
//!   site's administrator, and `DIR/public/ca.cert.pem`) and the signed domain
//!   governance (`DIR/enclaves/governance.p7s`): no unauthenticated
//!   participants, access control on joining and on every topic, discovery,
//!   liveliness, metadata and data encrypted.
//! * `enclave DIR --config site.toml`: the enclave of the box that config
//!   describes (`DIR/enclaves/<link.box_id>/`, the directory `link.security_dir`
//!   names): its private key and certificate (subject `CN=<box_id>,O=isochron`),
//!   the CA certificate as identity and permissions CA, the governance, and its
//!   signed permissions: publish the topics of the cameras it exports, subscribe
//!   to those of the cameras it imports, on its domain, nothing else.

use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};

use anyhow::{Context, bail};

use crate::common::{Subcommands, load_config};

/// Make the DDS Security keystore of the site's links (an SROS2-style layout).
pub type Args = Subcommands<KeystoreCommand>;

/// `isochron keystore` subcommands.
#[derive(clap::Subcommand)]
pub enum KeystoreCommand {
    /// Make the site's certificate authority and signed domain governance in DIR.
    Init {
        /// The keystore directory (created).
        dir: PathBuf,
    },
    /// Make the enclave of the box a config describes: its key, certificate and
    /// signed permissions (publish its exported cameras, subscribe its imported ones).
    Enclave {
        /// The keystore directory (made by `isochron keystore init`).
        dir: PathBuf,
        /// The box's site configuration (default: $ISOCHRON_CONFIG or
        /// /etc/isochron/isochron.toml).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Days the box's certificate and permissions are valid.
        #[arg(long, default_value_t = 3650)]
        days: u32,
    },
}

/// Runs `isochron keystore`.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    match args.command {
        KeystoreCommand::Init { dir } => init(&dir)?,
        KeystoreCommand::Enclave { dir, config, days } => {
            let loaded = load_config(config)?;
            let link = &loaded.config.link;
            if link.box_id.is_empty() {
                bail!(
                    "{}: link.box_id is not set: the enclave is named after the box",
                    loaded.path.display()
                );
            }
            let domain = link.ros_domain_id.map_or_else(env_domain, Ok)?;
            let enclave = enclave(
                &dir,
                &Grant {
                    box_id: &link.box_id,
                    domain,
                    namespace: link.namespace(),
                    export: &link.export,
                    import: &link.import,
                },
                days,
            )?;
            println!("{}", enclave.display());
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// The domain the link joins when its config names none: `$ROS_DOMAIN_ID`, else 0.
fn env_domain() -> anyhow::Result<u16> {
    match std::env::var("ROS_DOMAIN_ID") {
        Ok(v) if !v.trim().is_empty() => v
            .trim()
            .parse()
            .with_context(|| format!("ROS_DOMAIN_ID={v}: expected a domain id")),
        _ => Ok(0),
    }
}

/// Runs `openssl args`, failing with what it printed.
fn openssl(args: &[&str]) -> anyhow::Result<()> {
    let out = Command::new("openssl")
        .args(args)
        .output()
        .context("running `openssl` (Debian package openssl)")?;
    if !out.status.success() {
        bail!(
            "openssl {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        );
    }
    Ok(())
}

fn path(p: &Path) -> anyhow::Result<&str> {
    p.to_str()
        .with_context(|| format!("{}: not a UTF-8 path", p.display()))
}

/// The organisation of every subject the keystore makes.
const ORGANISATION: &str = "isochron";

/// `isochron keystore init DIR`.
fn init(dir: &Path) -> anyhow::Result<()> {
    let (key, cert) = (
        dir.join("private/ca.key.pem"),
        dir.join("public/ca.cert.pem"),
    );
    if key.exists() {
        bail!("{} exists: this keystore has its CA already", key.display());
    }
    for sub in ["private", "public", "enclaves"] {
        std::fs::create_dir_all(dir.join(sub))
            .with_context(|| format!("creating {}", dir.join(sub).display()))?;
    }
    openssl(&[
        "req",
        "-x509",
        "-newkey",
        "ec",
        "-pkeyopt",
        "ec_paramgen_curve:prime256v1",
        "-nodes",
        "-keyout",
        path(&key)?,
        "-out",
        path(&cert)?,
        "-days",
        "36500",
        "-subj",
        &format!("/O={ORGANISATION}/CN=isochron site CA"),
    ])?;
    let xml = dir.join("enclaves/governance.xml");
    std::fs::write(&xml, governance()).with_context(|| format!("writing {}", xml.display()))?;
    sign(dir, &xml, &dir.join("enclaves/governance.p7s"))?;
    println!("{}", dir.display());
    Ok(())
}

/// Signs `xml` into S/MIME `out` with the keystore's CA.
fn sign(dir: &Path, xml: &Path, out: &Path) -> anyhow::Result<()> {
    openssl(&[
        "smime",
        "-sign",
        "-text",
        "-in",
        path(xml)?,
        "-out",
        path(out)?,
        "-signer",
        path(&dir.join("public/ca.cert.pem"))?,
        "-inkey",
        path(&dir.join("private/ca.key.pem"))?,
    ])
}

/// The domain governance: on every domain, only authenticated participants
/// that the permissions let join; every topic's readers and writers checked
/// against the permissions; discovery, liveliness, RTPS messages and every
/// submessage (the data with it) encrypted with origin authentication. The
/// payload is not encrypted a second time on its own (`data_protection_kind`
/// NONE): RustDDS 0.15 encrypts each fragment of a large sample separately and
/// its readers then refuse the fragments (longer than the fragment size).
fn governance() -> String {
    let protect = "ENCRYPT_WITH_ORIGIN_AUTHENTICATION";
    format!(
        r#"<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-SECURITY/20170901/omg_shared_ca_governance.xsd">
  <domain_access_rules>
    <domain_rule>
      <domains><id_range><min>0</min><max>232</max></id_range></domains>
      <allow_unauthenticated_participants>false</allow_unauthenticated_participants>
      <enable_join_access_control>true</enable_join_access_control>
      <discovery_protection_kind>{protect}</discovery_protection_kind>
      <liveliness_protection_kind>{protect}</liveliness_protection_kind>
      <rtps_protection_kind>{protect}</rtps_protection_kind>
      <topic_access_rules>
        <topic_rule>
          <topic_expression>*</topic_expression>
          <enable_discovery_protection>true</enable_discovery_protection>
          <enable_liveliness_protection>true</enable_liveliness_protection>
          <enable_read_access_control>true</enable_read_access_control>
          <enable_write_access_control>true</enable_write_access_control>
          <metadata_protection_kind>{protect}</metadata_protection_kind>
          <data_protection_kind>NONE</data_protection_kind>
        </topic_rule>
      </topic_access_rules>
    </domain_rule>
  </domain_access_rules>
</dds>
"#
    )
}

/// What one box may do on the link.
pub struct Grant<'a> {
    /// `link.box_id`: the subject's common name.
    pub box_id: &'a str,
    /// The DDS domain.
    pub domain: u16,
    /// `link.namespace`.
    pub namespace: &'a str,
    /// Cameras whose topics it publishes.
    pub export: &'a [String],
    /// Cameras whose topics it reads.
    pub import: &'a [String],
}

/// The topics every ROS 2 node (ros2-client) creates: the graph
/// (`ros_discovery_info`), parameter events, rosout and the clock.
const ROS_GRAPH_TOPICS: [&str; 4] = [
    "ros_discovery_info",
    "rt/parameter_events",
    "rt/rosout",
    "rt/clock",
];

/// The DDS topic names of a box's cameras, `rt<namespace>/<camera>/*`, and the
/// ROS 2 graph's topics.
fn topics(namespace: &str, cameras: &[String]) -> String {
    cameras
        .iter()
        .map(|c| format!("rt{namespace}/{c}/*"))
        .chain(ROS_GRAPH_TOPICS.map(String::from))
        .map(|t| format!("<topic>{t}</topic>"))
        .collect()
}

/// The permissions document of `grant`, valid for `days` from now.
fn permissions(grant: &Grant, days: u32) -> String {
    let now = jiff::Timestamp::now();
    let until = now + jiff::SignedDuration::from_hours(24 * days as i64);
    let fmt = |t: jiff::Timestamp| t.strftime("%Y-%m-%dT%H:%M:%S").to_string();
    format!(
        r#"<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-Security/20170901/omg_shared_ca_permissions.xsd">
  <permissions>
    <grant name="{box}">
      <subject_name>CN={box},O={ORGANISATION}</subject_name>
      <validity><not_before>{from}</not_before><not_after>{until}</not_after></validity>
      <allow_rule>
        <domains><id>{domain}</id></domains>
        <publish><topics>{publish}</topics></publish>
        <subscribe><topics>{subscribe}</topics></subscribe>
      </allow_rule>
      <default>DENY</default>
    </grant>
  </permissions>
</dds>
"#,
        box = grant.box_id,
        from = fmt(now - jiff::SignedDuration::from_hours(1)),
        until = fmt(until),
        domain = grant.domain,
        publish = topics(grant.namespace, grant.export),
        subscribe = topics(grant.namespace, grant.import),
    )
}

/// Makes `DIR/enclaves/<box_id>/` for `grant`; returns it.
pub fn enclave(dir: &Path, grant: &Grant, days: u32) -> anyhow::Result<PathBuf> {
    let ca_key = dir.join("private/ca.key.pem");
    let ca_cert = dir.join("public/ca.cert.pem");
    let governance = dir.join("enclaves/governance.p7s");
    for f in [&ca_key, &ca_cert, &governance] {
        if !f.is_file() {
            bail!(
                "{} is missing: make the keystore with `isochron keystore init {}`",
                f.display(),
                dir.display()
            );
        }
    }
    let out = dir.join("enclaves").join(grant.box_id);
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    for name in ["identity_ca.cert.pem", "permissions_ca.cert.pem"] {
        std::fs::copy(&ca_cert, out.join(name))
            .with_context(|| format!("copying the CA certificate into {}", out.display()))?;
    }
    std::fs::copy(&governance, out.join("governance.p7s"))
        .with_context(|| format!("copying the governance into {}", out.display()))?;
    let request = out.join("cert.csr.pem");
    openssl(&[
        "req",
        "-newkey",
        "ec",
        "-pkeyopt",
        "ec_paramgen_curve:prime256v1",
        "-nodes",
        "-keyout",
        path(&out.join("key.pem"))?,
        "-out",
        path(&request)?,
        "-subj",
        &format!("/O={ORGANISATION}/CN={}", grant.box_id),
    ])?;
    let serial = format!(
        "{}",
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(1, |d| d.as_nanos() as u64)
    );
    openssl(&[
        "x509",
        "-req",
        "-in",
        path(&request)?,
        "-CA",
        path(&ca_cert)?,
        "-CAkey",
        path(&ca_key)?,
        "-set_serial",
        &serial,
        "-days",
        &days.to_string(),
        "-out",
        path(&out.join("cert.pem"))?,
    ])?;
    let _ = std::fs::remove_file(&request);
    let xml = out.join("permissions.xml");
    std::fs::write(&xml, permissions(grant, days))
        .with_context(|| format!("writing {}", xml.display()))?;
    sign(dir, &xml, &out.join("permissions.p7s"))?;
    Ok(out)
}
