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
//! * `bridge DIR --config site.toml`: the enclave of that box's costmap bridge
//!   (`DIR/enclaves/<box_id>_costmap`, or `costmap` without a `link.box_id`; the
//!   directory `costmap.security_dir` names): publish its grid, updates, people,
//!   markers, people markers, speed filter, mask and forecast topics (`rt/<topic>`), read its
//!   planning services' requests (`rq/<service>Request`) and write their replies
//!   (`rr/<service>Reply`), on `costmap.ros_domain_id`.
//! * `robot DIR NAME --config site.toml`: the enclave of robot NAME
//!   (`DIR/enclaves/robots/NAME`, subject `CN=NAME,O=isochron`), for its ROS 2
//!   node (`ROS_SECURITY_ENCLAVE`-style, the same six files): read the bridge's
//!   topics and the services' replies, write their requests; nothing else of the
//!   bridge's — a robot cannot publish a grid or answer a plan.
//!
//! One CA and one governance serve the links and the robots: a box, a bridge or
//! a robot of another keystore is not authenticated, and each is held to its
//! own permissions.

use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};

use anyhow::{Context, bail};

use crate::common::{Subcommands, load_config};

/// The longest validity `--days` gives a certificate: the CA's own (100 years).
/// Zero days would make a certificate that has expired when it is made.
const MAX_DAYS: i64 = 36500;

/// Make the DDS Security keystore of the site: its links, costmap bridge and robots (an SROS2-style layout).
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
        #[arg(long, default_value_t = 3650, value_parser = clap::value_parser!(u32).range(1..=MAX_DAYS))]
        days: u32,
    },
    /// Make the enclave of the costmap bridge a config describes (for
    /// `costmap.security_dir`): publish its topics, serve its planning services.
    Bridge {
        /// The keystore directory (made by `isochron keystore init`).
        dir: PathBuf,
        /// The box's site configuration (default: $ISOCHRON_CONFIG or
        /// /etc/isochron/isochron.toml).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Days the certificate and permissions are valid.
        #[arg(long, default_value_t = 3650, value_parser = clap::value_parser!(u32).range(1..=MAX_DAYS))]
        days: u32,
    },
    /// Make the enclave of a robot: read the bridge's topics (of the config's
    /// `[costmap]`), call its planning services.
    Robot {
        /// The keystore directory (made by `isochron keystore init`).
        dir: PathBuf,
        /// The robot's name (letters, digits, '_'): its certificate's common name
        /// and its enclave `DIR/enclaves/robots/NAME`.
        name: String,
        /// The site configuration whose bridge the robot uses (default:
        /// $ISOCHRON_CONFIG or /etc/isochron/isochron.toml).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Days the certificate and permissions are valid.
        #[arg(long, default_value_t = 3650, value_parser = clap::value_parser!(u32).range(1..=MAX_DAYS))]
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
                // The config lacks what this command needs: a config error, 78.
                return Err(isochron_exit::Fatal::new(
                    isochron_exit::CONFIG,
                    format!(
                        "{}: link.box_id is not set: the enclave is named after the box",
                        loaded.path.display()
                    ),
                )
                .into());
            }
            let domain = link.ros_domain_id.map_or_else(env_domain, Ok)?;
            let grant = Grant {
                subject: &link.box_id,
                domain,
                publish: link_topics(link.namespace(), &link.export),
                subscribe: link_topics(link.namespace(), &link.import),
            };
            let enclave = enclave(&dir, Path::new(&link.box_id), &grant, days)?;
            println!("{}", enclave.display());
        }
        KeystoreCommand::Bridge { dir, config, days } => {
            let loaded = load_config(config)?;
            let name = bridge_name(&loaded.config.link.box_id);
            let (topics, requests, replies) = bridge_names(&loaded.config.costmap);
            let grant = Grant {
                subject: &name,
                domain: robots_domain(&loaded)?,
                publish: with_graph(topics.into_iter().chain(replies)),
                subscribe: with_graph(requests),
            };
            let enclave = enclave(&dir, Path::new(&name), &grant, days)?;
            println!("{}", enclave.display());
        }
        KeystoreCommand::Robot {
            dir,
            name,
            config,
            days,
        } => {
            if !isochron_config::is_ros_token(&name) || name.len() > 64 {
                bail!(isochron_exit::UsageError(format!(
                    "robot name \"{name}\": expected up to 64 letters, digits and '_', not starting with a digit"
                )));
            }
            let loaded = load_config(config)?;
            let (topics, requests, replies) = bridge_names(&loaded.config.costmap);
            let grant = Grant {
                subject: &name,
                domain: robots_domain(&loaded)?,
                publish: with_graph(requests),
                subscribe: with_graph(topics.into_iter().chain(replies)),
            };
            let enclave = enclave(&dir, &Path::new("robots").join(&name), &grant, days)?;
            println!("{}", enclave.display());
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// The bridge's enclave (and subject) name: `<box_id>_costmap`, or `costmap` on a
/// site without `link.box_id`.
pub fn bridge_name(box_id: &str) -> String {
    if box_id.is_empty() {
        "costmap".to_string()
    } else {
        format!("{box_id}_costmap")
    }
}

/// The bridge's DDS names: its topics (`rt/...`), its services' request topics
/// (`rq/<service>Request`) and reply topics (`rr/<service>Reply`).
/// The DDS domain of the robots' side: `costmap.ros_domain_id`, else `$ROS_DOMAIN_ID`.
fn robots_domain(loaded: &isochron_config::LoadedConfig) -> anyhow::Result<u16> {
    loaded
        .config
        .costmap
        .ros_domain_id
        .map_or_else(env_domain, Ok)
}

fn bridge_names(c: &isochron_config::CostmapConfig) -> (Vec<String>, Vec<String>, Vec<String>) {
    let absolute = |n: &str| {
        if n.starts_with('/') {
            n.to_string()
        } else {
            format!("/{n}")
        }
    };
    let topics = [
        c.topic.clone(),
        c.updates_topic(),
        c.people_topic.clone(),
        c.markers_topic.clone(),
        c.people_markers_topic.clone(),
        c.speed_filter_info_topic.clone(),
        c.speed_mask_topic.clone(),
        c.forecast_topic.clone(),
    ]
    .iter()
    .map(|t| format!("rt{}", absolute(t)))
    .collect();
    let services = [
        &c.plan_now_service,
        &c.plan_offline_service,
        &c.plan_graph_service,
    ];
    let requests = services
        .iter()
        .map(|s| format!("rq{}Request", absolute(s)))
        .collect();
    let replies = services
        .iter()
        .map(|s| format!("rr{}Reply", absolute(s)))
        .collect();
    (topics, requests, replies)
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

/// `openssl req` with a new P-256 key into `key`, its request (or with `-x509` in
/// `extra`, its self-signed certificate) into `out`, for `subject`.
fn new_key((key, out): (&Path, &Path), subject: &str, extra: &[&str]) -> anyhow::Result<()> {
    let mut args = vec!["req"];
    args.extend(extra);
    args.extend([
        "-newkey",
        "ec",
        "-pkeyopt",
        "ec_paramgen_curve:prime256v1",
        "-nodes",
        "-keyout",
        path(key)?,
        "-out",
        path(out)?,
        "-subj",
        subject,
    ]);
    openssl(&args)
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
    new_key(
        (&key, &cert),
        &format!("/O={ORGANISATION}/CN=isochron site CA"),
        &["-x509", "-days", "36500"],
    )?;
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

/// What one participant (a box's link, a bridge, a robot) may do.
pub struct Grant<'a> {
    /// The subject's common name (`link.box_id`, the bridge's or robot's name).
    pub subject: &'a str,
    /// The DDS domain.
    pub domain: u16,
    /// DDS topic names (or `*` patterns) it may publish.
    pub publish: Vec<String>,
    /// DDS topic names (or `*` patterns) it may subscribe to.
    pub subscribe: Vec<String>,
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
fn link_topics(namespace: &str, cameras: &[String]) -> Vec<String> {
    with_graph(cameras.iter().map(|c| format!("rt{namespace}/{c}/*")))
}

/// `names` and the ROS 2 graph's topics.
fn with_graph(names: impl IntoIterator<Item = String>) -> Vec<String> {
    names
        .into_iter()
        .chain(ROS_GRAPH_TOPICS.map(String::from))
        .collect()
}

/// `<topic>` elements of `names`.
fn topics(names: &[String]) -> String {
    names
        .iter()
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
    <grant name="{subject}">
      <subject_name>CN={subject},O={ORGANISATION}</subject_name>
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
        subject = grant.subject,
        from = fmt(now - jiff::SignedDuration::from_hours(1)),
        until = fmt(until),
        domain = grant.domain,
        publish = topics(&grant.publish),
        subscribe = topics(&grant.subscribe),
    )
}

/// Makes the enclave `DIR/enclaves/<name>/` for `grant`; returns it.
pub fn enclave(dir: &Path, name: &Path, grant: &Grant, days: u32) -> anyhow::Result<PathBuf> {
    let ca_key = dir.join("private/ca.key.pem");
    let ca_cert = dir.join("public/ca.cert.pem");
    let governance = dir.join("enclaves/governance.p7s");
    for f in [&ca_key, &ca_cert, &governance] {
        if !f.is_file() {
            bail!(isochron_exit::Fatal::new(
                isochron_exit::NO_INPUT,
                format!(
                    "{} is missing: make the keystore with `isochron keystore init {}`",
                    f.display(),
                    dir.display()
                )
            ));
        }
    }
    let out = dir.join("enclaves").join(name);
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    for name in ["identity_ca.cert.pem", "permissions_ca.cert.pem"] {
        std::fs::copy(&ca_cert, out.join(name))
            .with_context(|| format!("copying the CA certificate into {}", out.display()))?;
    }
    std::fs::copy(&governance, out.join("governance.p7s"))
        .with_context(|| format!("copying the governance into {}", out.display()))?;
    let request = out.join("cert.csr.pem");
    new_key(
        (&out.join("key.pem"), &request),
        &format!("/O={ORGANISATION}/CN={}", grant.subject),
        &[],
    )?;
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
