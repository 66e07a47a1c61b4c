//! The link's DDS side (`ros2-client` on RustDDS, as the costmap bridge): one
//! participant on `link.ros_domain_id` using the interfaces of
//! `link.dds_interfaces`, the node `/isochron/link_<box_id>`, and per camera the
//! topics `<link.namespace>/<camera>/<stream>`: `activity` best effort, keep last
//! 1 (only the newest second is worth sending; a lost one is replaced a second
//! later); `events` and `detections` reliable, keep last `link.queue_messages`;
//! `status` reliable, one report per stage. All volatile and bounded.

use std::net::IpAddr;

use ros2_client::dds::{Context, Node, Publisher, Subscription};
use ros2_client::{MessageTypeName, Name, NodeName, NodeOptions};
use rustdds::{DomainParticipantBuilder, QosPolicies, QosPolicyBuilder, TopicKind, policy};
use serde::Serialize;
use serde::de::DeserializeOwned;

use isochron_shared::topology::StageKind;

use crate::msgs::{Delivery, LinkStream, Message, Status};

/// Highest DDS domain id whose RTPS ports fit in 16 bits.
pub const MAX_DOMAIN_ID: u16 = 232;

/// Why the DDS side could not start.
#[derive(Debug, thiserror::Error)]
#[error("starting DDS on domain {domain}: {detail}")]
pub struct DdsError {
    /// The domain.
    pub domain: u16,
    /// What failed.
    pub detail: String,
}

impl isochron_shared::exit::Classify for DdsError {
    /// DDS did not start (ports, interfaces): the network side is unavailable.
    fn exit_code(&self) -> i32 {
        isochron_shared::exit::UNAVAILABLE
    }
}

/// `$ROS_DOMAIN_ID` is not a domain id.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("ROS_DOMAIN_ID={value}: expected 0 to {MAX_DOMAIN_ID}")]
pub struct DomainIdError {
    /// The variable's value.
    pub value: String,
}

impl isochron_shared::exit::Classify for DomainIdError {
    fn exit_code(&self) -> i32 {
        isochron_shared::exit::CONFIG
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

/// The link's DDS participant and node.
pub struct LinkDds {
    node: Node,
    node_name: NodeName,
    namespace: String,
    domain: u16,
    context: Context,
    _spinner: Option<std::thread::JoinHandle<()>>,
}

impl LinkDds {
    /// Joins `domain` on `interfaces` (empty: all) as node `/isochron/link_<box_id>`;
    /// topics go under `namespace`.
    pub fn start(
        domain: u16,
        interfaces: &[IpAddr],
        box_id: &str,
        namespace: &str,
    ) -> Result<LinkDds, DdsError> {
        let dds = |detail: String| DdsError { domain, detail };
        // RustDDS's own log is noisy at info; errors only unless ISOCHRON_DDS_LOG says.
        let level = std::env::var("ISOCHRON_DDS_LOG")
            .ok()
            .and_then(|v| v.trim().parse::<log::LevelFilter>().ok())
            .unwrap_or(log::LevelFilter::Error);
        log::set_max_level(level);
        let mut builder = DomainParticipantBuilder::new(domain);
        if !interfaces.is_empty() {
            builder = builder.with_only_networks(interfaces.iter().copied());
        }
        let participant = builder.build().map_err(|e| dds(format!("{e:?}")))?;
        let context =
            Context::from_domain_participant(participant).map_err(|e| dds(format!("{e:?}")))?;
        let base = if box_id.is_empty() {
            "link".to_string()
        } else {
            format!("link_{box_id}")
        };
        let node_name = NodeName::new("/isochron", &base)
            .map_err(|e| dds(format!("node name {base}: {e:?}")))?;
        let mut node = context
            .new_node(
                node_name.clone(),
                NodeOptions::new()
                    .enable_rosout(false)
                    .start_parameter_services(false),
            )
            .map_err(|e| dds(format!("creating the node: {e:?}")))?;
        // The spinner answers discovery and keeps the node in the ROS graph.
        let spinner = match node.spinner() {
            Ok(spinner) => std::thread::Builder::new()
                .name("ros2-spinner".into())
                .spawn(move || {
                    let _ = futures::executor::block_on(spinner.spin());
                })
                .ok(),
            Err(e) => {
                tracing::warn!("ROS 2 spinner not started: {e:?}");
                None
            }
        };
        Ok(LinkDds {
            node,
            node_name,
            namespace: namespace.to_string(),
            domain,
            context,
            _spinner: spinner,
        })
    }

    /// `<namespace>/<camera>/<suffix>`.
    pub fn topic_name(&self, camera: &str, suffix: &str) -> String {
        format!("{}/{camera}/{suffix}", self.namespace)
    }

    /// The node, for the publishers' matched-subscription counts.
    pub fn node(&self) -> &Node {
        &self.node
    }

    fn topic(
        &self,
        camera: &str,
        suffix: &str,
        msg: &str,
        qos: &QosPolicies,
    ) -> Result<rustdds::Topic, DdsError> {
        let name = self.topic_name(camera, suffix);
        let dds = |detail: String| DdsError {
            domain: self.domain,
            detail,
        };
        let parsed = Name::parse(&name).map_err(|e| dds(format!("topic {name}: {e:?}")))?;
        self.context
            .domain_participant()
            .create_topic(
                parsed.to_dds_name("rt", &self.node_name, ""),
                MessageTypeName::new("isochron_msgs", msg).dds_msg_type(),
                qos,
                TopicKind::NoKey,
            )
            .map_err(|e| dds(format!("creating topic {name}: {e:?}")))
    }

    fn writer<M: Serialize>(
        &mut self,
        camera: &str,
        (suffix, msg): (&str, &str),
        qos: QosPolicies,
    ) -> Result<Publisher<M>, DdsError> {
        let topic = self.topic(camera, suffix, msg, &qos)?;
        patiently(|| self.node.create_publisher(&topic, None))
            .map_err(|e| self.error(format!("creating the {suffix} writer of {camera}: {e:?}")))
    }

    fn reader<M: DeserializeOwned + 'static>(
        &mut self,
        camera: &str,
        (suffix, msg): (&str, &str),
        qos: QosPolicies,
    ) -> Result<Subscription<M>, DdsError> {
        let topic = self.topic(camera, suffix, msg, &qos)?;
        patiently(|| self.node.create_subscription(&topic, None))
            .map_err(|e| self.error(format!("creating the {suffix} reader of {camera}: {e:?}")))
    }

    /// A writer of stream `S` of `camera`; `queue` is the depth of a queued
    /// stream's DDS history.
    pub fn publisher<S: LinkStream>(
        &mut self,
        camera: &str,
        queue: usize,
    ) -> Result<Publisher<Message<S>>, DdsError> {
        self.writer(camera, (S::SUFFIX, S::MSG), qos(S::DELIVERY, queue))
    }

    /// A reader of stream `S` of `camera`.
    pub fn subscription<S: LinkStream>(
        &mut self,
        camera: &str,
        queue: usize,
    ) -> Result<Subscription<Message<S>>, DdsError> {
        self.reader(camera, (S::SUFFIX, S::MSG), qos(S::DELIVERY, queue))
    }

    /// The writer of `camera`'s stages' status.
    pub fn status_publisher(&mut self, camera: &str) -> Result<Publisher<Status>, DdsError> {
        self.writer(camera, STATUS, status_qos())
    }

    /// The reader of `camera`'s stages' status.
    pub fn status_subscription(&mut self, camera: &str) -> Result<Subscription<Status>, DdsError> {
        self.reader(camera, STATUS, status_qos())
    }

    fn error(&self, detail: String) -> DdsError {
        DdsError {
            domain: self.domain,
            detail,
        }
    }
}

/// Creates a DDS entity, waiting while RustDDS's event loop catches up: it takes
/// new readers and writers through bounded channels (100 readers, 10 writers),
/// which a link of a few hundred cameras fills at start ("sending on a full
/// channel"). Gives up after 5 s.
fn patiently<T, E: std::fmt::Debug>(mut create: impl FnMut() -> Result<T, E>) -> Result<T, E> {
    let end = std::time::Instant::now() + std::time::Duration::from_secs(5);
    loop {
        match create() {
            Err(e)
                if format!("{e:?}").contains("full channel") && std::time::Instant::now() < end =>
            {
                std::thread::sleep(std::time::Duration::from_millis(10));
            }
            result => return result,
        }
    }
}

/// Topic suffix and message type of the status of a camera's stages.
const STATUS: (&str, &str) = ("status", "Status");

/// The QoS of a stream: latest-only is best effort, keep last 1; queued is
/// reliable, keep last `queue`, at most `queue` unacknowledged samples, and a
/// write into a full window fails at once (the link's own queue keeps the
/// sample: a write never blocks the link).
fn qos(delivery: Delivery, queue: usize) -> QosPolicies {
    let depth = match delivery {
        Delivery::Latest => 1,
        Delivery::Queued => queue.max(1) as i32,
    };
    let reliability = match delivery {
        Delivery::Latest => policy::Reliability::BestEffort,
        Delivery::Queued => policy::Reliability::Reliable {
            max_blocking_time: rustdds::Duration::ZERO,
        },
    };
    QosPolicyBuilder::new()
        .reliability(reliability)
        .durability(policy::Durability::Volatile)
        .history(policy::History::KeepLast { depth })
        .resource_limits(policy::ResourceLimits {
            max_samples: depth,
            max_instances: 1,
            max_samples_per_instance: depth,
        })
        .build()
}

/// Status: reliable and keep last one report per stage of a camera, so the
/// reports of a camera's stages, sent together every few seconds, all arrive
/// (latest-only per stage).
fn status_qos() -> QosPolicies {
    qos(Delivery::Queued, StageKind::ALL.len())
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
