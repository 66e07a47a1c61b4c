//! `[link]`: which cameras' small streams this box sends to the site's other base
//! stations over ROS 2 DDS, and which remote cameras it receives (`isochron-link`).
//!
//! Nothing leaves the box unless `export` names it; nothing is received unless
//! `import` names it.

use serde::{Deserialize, Serialize};

use super::{CameraConfig, Invalid, check_dds, check_range};

/// `[link]`: the box-to-box link.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LinkConfig {
    /// This base station's name on the site (letters, digits, `_`), carried in
    /// every message it sends. Required when `export` is not empty.
    pub box_id: String,
    /// Cameras of this box (`[[camera]]` ids) whose activity is sent. Default none.
    pub export: Vec<String>,
    /// Remote cameras whose activity is received and published into this box's
    /// iceoryx2 services as if local. Without `security_dir` each needs a
    /// `[[camera]]` with its `width` and `height` (the size it is analysed at on
    /// its box): the camera's grid is then configured, never taken from the first,
    /// unauthenticated sample. Default none.
    pub import: Vec<String>,
    /// DDS domain (`ROS_DOMAIN_ID`) of the link; default `$ROS_DOMAIN_ID`, else 0.
    pub ros_domain_id: Option<u16>,
    /// IP addresses of the network interfaces DDS may use (e.g. the site network's
    /// `["10.0.0.5"]`); default all.
    pub dds_interfaces: Vec<String>,
    /// ROS 2 namespace of the link's topics: `<namespace>/<camera>/activity`.
    /// Default `/isochron/link`.
    pub namespace: Option<String>,
    /// Events and detections (records, not latest-only): messages each side of
    /// the link holds per camera and stream when the other side or the network
    /// is slow or away (the DDS history depth and each side's queue). When a
    /// queue is full its oldest message is dropped and counted in the link's
    /// status. Default 64.
    pub queue_messages: Option<usize>,
    /// This box's DDS Security enclave: the directory `isochron keystore enclave`
    /// makes (an SROS2 enclave: `identity_ca.cert.pem`, `cert.pem`, `key.pem`,
    /// `permissions_ca.cert.pem`, `governance.p7s`, `permissions.p7s`). With it
    /// the link authenticates every box, checks its permissions per topic and
    /// encrypts. Default none.
    pub security_dir: Option<String>,
    /// Run without DDS Security on interfaces other than loopback (every box on
    /// the network can then write into this site). Default false: without
    /// `security_dir`, the link refuses to start unless `dds_interfaces` are
    /// all loopback.
    pub insecure: bool,
}

/// Longest `link.box_id`, bytes.
pub const MAX_BOX_ID_LEN: usize = 64;

/// The default `link.queue_messages`.
pub const DEFAULT_QUEUE_MESSAGES: usize = 64;

/// The default topic namespace.
pub const DEFAULT_LINK_NAMESPACE: &str = "/isochron/link";

/// True if `name` can be one token of a ROS 2 name: letters, digits and `_`, not
/// starting with a digit.
pub fn is_ros_token(name: &str) -> bool {
    name.bytes().next().is_some_and(|b| !b.is_ascii_digit())
        && name.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'_')
}

impl LinkConfig {
    /// The namespace of the link's topics.
    pub fn namespace(&self) -> &str {
        self.namespace.as_deref().unwrap_or(DEFAULT_LINK_NAMESPACE)
    }

    /// Messages of each queued stream a side holds (`link.queue_messages`).
    pub fn queue_messages(&self) -> usize {
        self.queue_messages.unwrap_or(DEFAULT_QUEUE_MESSAGES)
    }

    /// True if DDS may use an interface other than loopback (`dds_interfaces`
    /// empty means all of them).
    pub fn leaves_the_box(&self) -> bool {
        self.dds_interfaces.is_empty()
            || self.dds_interfaces.iter().any(|a| {
                a.parse::<std::net::IpAddr>()
                    .is_ok_and(|ip| !ip.is_loopback())
            })
    }

    /// True if the link has anything to do.
    pub fn is_enabled(&self) -> bool {
        !self.export.is_empty() || !self.import.is_empty()
    }

    /// Without DDS Security nothing authenticates a sample, so an imported
    /// camera's block grid must be configured (its `[[camera]]` `width` and
    /// `height`), never pinned by the first sample on the wire: a forger's first
    /// sample would otherwise fix a wrong geometry until the link restarts.
    fn check_unauthenticated_imports(&self, cameras: &[CameraConfig]) -> Result<(), Invalid> {
        for (i, id) in self.import.iter().enumerate() {
            let why = "the link runs without link.security_dir, so the grid of an imported camera is configured, not taken from unauthenticated samples";
            match cameras.iter().position(|c| &c.id == id) {
                None => {
                    return Err(Invalid::new(
                        format!("link.import[{i}]"),
                        format!(
                            "expected a [[camera]] with id \"{id}\", width and height for imported camera \"{id}\" ({why})"
                        ),
                    ));
                }
                Some(j) if cameras[j].width.is_none() || cameras[j].height.is_none() => {
                    return Err(Invalid::new(
                        format!("camera[{j}].width"),
                        format!(
                            "expected width and height of imported camera \"{id}\" (its analysis size on the box that runs it; {why})"
                        ),
                    ));
                }
                Some(_) => {}
            }
        }
        Ok(())
    }

    /// Checks the `link.*` keys against the configured cameras.
    pub(super) fn validate(&self, cameras: &[CameraConfig]) -> Result<(), Invalid> {
        if !self.box_id.is_empty()
            && (!is_ros_token(&self.box_id) || self.box_id.len() > MAX_BOX_ID_LEN)
        {
            return Err(Invalid::found(
                "link.box_id",
                "a name of up to 64 letters, digits and '_' not starting with a digit, such as \"box_a\"",
                &self.box_id,
            ));
        }
        if !self.export.is_empty() && self.box_id.is_empty() {
            return Err(Invalid::new(
                "link.box_id",
                "expected this box's name (such as \"box_a\") when link.export names cameras",
            ));
        }
        for (key, list) in [("export", &self.export), ("import", &self.import)] {
            for (i, id) in list.iter().enumerate() {
                if !is_ros_token(id) || id.len() > isochron_wire::CAMERA_ID_LEN {
                    return Err(Invalid::new(
                        format!("link.{key}[{i}]"),
                        format!(
                            "expected a camera id of 1 to {} letters, digits and '_' not starting with a digit (a ROS 2 name token), found \"{id}\"",
                            isochron_wire::CAMERA_ID_LEN
                        ),
                    ));
                }
                if list[..i].contains(id) {
                    return Err(Invalid::new(
                        format!("link.{key}[{i}]"),
                        format!("expected each camera once, found \"{id}\" again"),
                    ));
                }
            }
        }
        for (i, id) in self.export.iter().enumerate() {
            if !cameras.iter().any(|c| &c.id == id) {
                return Err(Invalid::found(
                    format!("link.export[{i}]"),
                    "a [[camera]] id of this site",
                    id,
                ));
            }
            if self.import.contains(id) {
                return Err(Invalid::new(
                    format!("link.export[{i}]"),
                    format!("camera \"{id}\" is both exported and imported: expected one"),
                ));
            }
        }
        if self.security_dir.is_none() {
            self.check_unauthenticated_imports(cameras)?;
        }
        if let Some(q) = self.queue_messages {
            check_range("link.queue_messages", q as f64, 1.0, 10_000.0)?;
        }
        check_dds("link", self.ros_domain_id, &self.dds_interfaces, "10.0.0.5")?;
        if self
            .security_dir
            .as_deref()
            .is_some_and(|d| d.trim().is_empty())
        {
            return Err(Invalid::new(
                "link.security_dir",
                "expected the directory of this box's enclave (isochron keystore enclave)",
            ));
        }
        if let Some(ns) = &self.namespace {
            let ok = ns.starts_with('/') && ns[1..].split('/').all(is_ros_token);
            if !ok {
                return Err(Invalid::found(
                    "link.namespace",
                    "an absolute ROS 2 namespace such as \"/isochron/link\"",
                    ns,
                ));
            }
        }
        Ok(())
    }
}
