//! The ROS 2 side that isochron's DDS services share — the costmap bridge
//! (`shared/ros2`) and the link (`services/link/src/dds.rs`) —
//! on `ros2-client` over RustDDS (pure Rust, no ROS install):
//!
//! * [`domain_id`]: the DDS domain, from the config, else `$ROS_DOMAIN_ID`, else 0;
//! * [`limit_dds_logging`]: RustDDS's own log held to `$ISOCHRON_DDS_LOG`;
//! * [`RosNode`]: one participant on a domain, announcing and multicasting only on
//!   the given interfaces, one node `/isochron/<name>`, and the spinner thread that
//!   keeps the node in the ROS graph;
//! * [`RosNode::topic`], [`RosNode::typed_topic`]: the DDS topic (`rt/…`) of a
//!   ROS 2 topic and message type;
//! * [`keep_last`]: the QoS of a bounded topic, whose depth also bounds the
//!   writer's cache; [`bounded`]: the largest sample a reader reassembles.

use std::net::IpAddr;
use std::path::Path;

use ros2_client::dds::{Context, Node};
use ros2_client::{MessageTypeName, Name, NodeName, NodeOptions};
use rustdds::{DomainParticipantBuilder, QosPolicies, QosPolicyBuilder, Topic, TopicKind, policy};

/// Highest DDS domain id whose RTPS ports fit in 16 bits.
pub const MAX_DOMAIN_ID: u16 = 232;

/// DDS could not be set up or refused an entity (ports, interfaces, a name).
#[derive(Debug, thiserror::Error)]
#[error("starting DDS on domain {domain}: {detail}")]
pub struct DdsError {
    /// The domain.
    pub domain: u16,
    /// What failed.
    pub detail: String,
}

impl isochron_exit::Classify for DdsError {
    /// DDS did not start (ports, interfaces): the network side is unavailable.
    fn exit_code(&self) -> i32 {
        isochron_exit::UNAVAILABLE
    }
}

/// `$ROS_DOMAIN_ID` is not a domain id.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("ROS_DOMAIN_ID={value}: expected 0 to {MAX_DOMAIN_ID}")]
pub struct DomainIdError {
    /// The variable's value.
    pub value: String,
}

impl isochron_exit::Classify for DomainIdError {
    fn exit_code(&self) -> i32 {
        isochron_exit::CONFIG
    }
}

/// The domain: `configured`, else `$ROS_DOMAIN_ID`, else 0.
pub fn domain_id(configured: Option<u16>) -> Result<u16, DomainIdError> {
    if let Some(d) = configured {
        return Ok(d);
    }
    match std::env::var("ROS_DOMAIN_ID") {
        Ok(v) if !v.trim().is_empty() => v
            .trim()
            .parse::<u16>()
            .ok()
            .filter(|d| *d <= MAX_DOMAIN_ID)
            .ok_or(DomainIdError { value: v }),
        _ => Ok(0),
    }
}

/// Limits what RustDDS and ros2-client log (through the `log` facade) to
/// `$ISOCHRON_DDS_LOG` (`off`, `error`, `warn`, `info`, `debug`, `trace`; default
/// `error`): they report routine discovery events as warnings many times a second.
/// Call after the process's logging is set up.
pub fn limit_dds_logging() {
    let level = std::env::var("ISOCHRON_DDS_LOG")
        .ok()
        .and_then(|v| v.trim().parse::<log::LevelFilter>().ok())
        .unwrap_or(log::LevelFilter::Error);
    log::set_max_level(level);
}

/// A process's DDS participant and its ROS 2 node.
pub struct RosNode {
    node: Node,
    name: NodeName,
    domain: u16,
    context: Context,
    _spinner: Option<std::thread::JoinHandle<()>>,
}

impl RosNode {
    /// Joins `domain` on `interfaces` (empty: all; RustDDS announces and
    /// multicasts only on them, but binds its sockets to 0.0.0.0 regardless) as
    /// the node `/isochron/<name>`, without rosout or parameter services, and
    /// starts its spinner. With `enclave` (see [`ENCLAVE_FILES`]) the participant
    /// runs DDS Security: it authenticates every remote participant against the
    /// identity CA, checks their permissions per topic and protects what the
    /// governance says.
    pub fn start(
        domain: u16,
        interfaces: &[IpAddr],
        name: &str,
        enclave: Option<&Path>,
    ) -> Result<RosNode, DdsError> {
        let dds = |detail: String| DdsError { domain, detail };
        let mut builder = DomainParticipantBuilder::new(domain);
        if !interfaces.is_empty() {
            builder = builder.with_only_networks(interfaces.iter().copied());
        }
        if let Some(dir) = enclave {
            builder = secure(builder, dir).map_err(dds)?;
        }
        let participant = builder.build().map_err(|e| dds(format!("{e}")))?;
        let context =
            Context::from_domain_participant(participant).map_err(|e| dds(format!("{e}")))?;
        let node_name =
            NodeName::new("/isochron", name).map_err(|e| dds(format!("node name {name}: {e}")))?;
        let mut node = context
            .new_node(
                node_name.clone(),
                NodeOptions::new()
                    .enable_rosout(false)
                    .start_parameter_services(false),
            )
            .map_err(|e| dds(format!("creating the node: {e}")))?;
        // The spinner keeps the node visible in the ROS graph (`ros2 node list`) and
        // answers its discovery traffic; it ends when the node is dropped.
        let spinner = match node.spinner() {
            Ok(spinner) => std::thread::Builder::new()
                .name("ros2-spinner".into())
                .spawn(move || {
                    let _ = futures::executor::block_on(spinner.spin());
                })
                .ok(),
            Err(e) => {
                tracing::warn!("ROS 2 spinner not started: {e}");
                None
            }
        };
        Ok(RosNode {
            node,
            name: node_name,
            domain,
            context,
            _spinner: spinner,
        })
    }

    /// The node, for its publishers' and subscriptions' matched counts.
    pub fn node(&self) -> &Node {
        &self.node
    }

    /// The node, to create publishers, subscriptions and services on.
    pub fn node_mut(&mut self) -> &mut Node {
        &mut self.node
    }

    /// The ROS 2 context (its DDS participant).
    pub fn context(&self) -> &Context {
        &self.context
    }

    /// The domain.
    pub fn domain(&self) -> u16 {
        self.domain
    }

    /// An error of this node's DDS side.
    pub fn error(&self, detail: String) -> DdsError {
        DdsError {
            domain: self.domain,
            detail,
        }
    }

    /// The node's name, `/isochron/<name>`: what names relative to it resolve
    /// against.
    pub fn name(&self) -> &NodeName {
        &self.name
    }

    /// The DDS topic (`rt/…`) of ROS 2 topic `name` for `package/msg/type_name`
    /// with `qos`.
    pub fn topic(
        &self,
        name: &Name,
        (package, type_name): (&str, &str),
        qos: &QosPolicies,
    ) -> Result<Topic, DdsError> {
        let dds_type = MessageTypeName::new(package, type_name).dds_msg_type();
        self.typed_topic(name, &dds_type, qos)
    }

    /// The DDS topic (`rt/…`) of ROS 2 topic `name` whose DDS type name is
    /// `dds_type` (`<package>::msg::dds_::<Type>_`) with `qos`.
    pub fn typed_topic(
        &self,
        name: &Name,
        dds_type: &str,
        qos: &QosPolicies,
    ) -> Result<Topic, DdsError> {
        self.context
            .domain_participant()
            .create_topic(
                name.to_dds_name("rt", &self.name, ""),
                dds_type.to_string(),
                qos,
                TopicKind::NoKey,
            )
            .map_err(|e| self.error(format!("creating topic {name}: {e}")))
    }
}

/// `builder` with DDS Security's built-in plugins reading the enclave `dir`.
#[cfg(feature = "security")]
fn secure(
    builder: DomainParticipantBuilder,
    dir: &Path,
) -> Result<DomainParticipantBuilder, String> {
    // The keystore's private keys are not encrypted (RustDDS reads no encrypted
    // ones): the enclave's file permissions protect them.
    Ok(builder.builtin_security(
        rustdds::DomainParticipantSecurityConfigFiles::with_ros_default_names(dir, String::new()),
    ))
}

/// Without the `security` feature: an error saying so.
#[cfg(not(feature = "security"))]
fn secure(_: DomainParticipantBuilder, dir: &Path) -> Result<DomainParticipantBuilder, String> {
    Err(format!(
        "the enclave {} needs DDS Security, which this binary is built without (isochron-dds feature `security`)",
        dir.display()
    ))
}

/// The files of an SROS2 enclave that DDS Security reads.
pub const ENCLAVE_FILES: [&str; 6] = [
    "identity_ca.cert.pem",
    "cert.pem",
    "key.pem",
    "permissions_ca.cert.pem",
    "governance.p7s",
    "permissions.p7s",
];

/// The first of [`ENCLAVE_FILES`] missing from `dir`, if any.
fn missing_enclave_file(dir: &Path) -> Option<std::path::PathBuf> {
    ENCLAVE_FILES
        .iter()
        .map(|f| dir.join(f))
        .find(|p| !p.is_file())
}

/// What is wrong with the enclave `dir` that the config key `key` names, if
/// anything: the first of [`ENCLAVE_FILES`] it lacks, and the command (`made_by`)
/// that makes one.
pub fn enclave_problem(dir: &Path, key: &str, made_by: &str) -> Option<String> {
    missing_enclave_file(dir).map(|missing| {
        format!(
            "{key}: {} is missing (an enclave made by `{made_by}` holds {})",
            missing.display(),
            ENCLAVE_FILES.join(", ")
        )
    })
}

/// The QoS of a bounded topic: `reliability`, `durability`, keep last `depth`, and
/// at most `depth` samples in the writer's cache — RustDDS keeps every sample no
/// reader has acknowledged, so without the limit a writer nobody reads would pile
/// up samples, and a late joiner would receive all of them.
pub fn keep_last(
    reliability: policy::Reliability,
    durability: policy::Durability,
    depth: i32,
) -> QosPolicies {
    QosPolicyBuilder::new()
        .reliability(reliability)
        .durability(durability)
        .history(policy::History::KeepLast { depth })
        .resource_limits(policy::ResourceLimits {
            max_samples: depth,
            max_instances: 1,
            max_samples_per_instance: depth,
        })
        .build()
}

/// `qos` with a bound on what a reader reassembles: at most `bytes` per sample,
/// and 4 samples' worth of incomplete ones over all remote writers together
/// (RustDDS's `max_sample_size`, the patch in `vendor/rustdds`). A DATA_FRAG
/// claiming a larger sample — from anyone, before discovery or authentication —
/// is dropped before anything is allocated for it.
pub fn bounded(qos: QosPolicies, bytes: usize) -> QosPolicies {
    let bytes = u32::try_from(bytes).unwrap_or(u32::MAX);
    qos.modify_by(&QosPolicyBuilder::new().max_sample_size(bytes).build())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_config_decides_the_domain() {
        assert_eq!(domain_id(Some(42)), Ok(42));
        assert_eq!(
            DomainIdError {
                value: "300".into()
            }
            .to_string(),
            "ROS_DOMAIN_ID=300: expected 0 to 232"
        );
    }
}
