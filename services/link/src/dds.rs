//! The link's DDS side (`ros2-client` on RustDDS, as the costmap bridge): one
//! participant on `link.ros_domain_id` using the interfaces of
//! `link.dds_interfaces`, the node `/isochron/link_<box_id>`, and per camera the
//! topic `<link.namespace>/<camera>/activity` of `isochron_msgs/msg/Activity`:
//! best effort, volatile, keep last 1 — only the newest second of a camera is
//! worth sending, and a lost one is replaced a second later (latest-only, bounded).

use std::net::IpAddr;

use ros2_client::dds::{Context, Node, Publisher, Subscription};
use ros2_client::{MessageTypeName, Name, NodeName, NodeOptions};
use rustdds::{DomainParticipantBuilder, QosPolicyBuilder, TopicKind, policy};

use crate::msgs::Activity;

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

    /// `<namespace>/<camera>/activity`.
    pub fn activity_topic_name(&self, camera: &str) -> String {
        format!("{}/{camera}/activity", self.namespace)
    }

    fn activity_topic(&self, camera: &str) -> Result<rustdds::Topic, DdsError> {
        let name = self.activity_topic_name(camera);
        let dds = |detail: String| DdsError {
            domain: self.domain,
            detail,
        };
        let parsed = Name::parse(&name).map_err(|e| dds(format!("topic {name}: {e:?}")))?;
        let qos = QosPolicyBuilder::new()
            .reliability(policy::Reliability::BestEffort)
            .durability(policy::Durability::Volatile)
            .history(policy::History::KeepLast { depth: 1 })
            .resource_limits(policy::ResourceLimits {
                max_samples: 1,
                max_instances: 1,
                max_samples_per_instance: 1,
            })
            .build();
        self.context
            .domain_participant()
            .create_topic(
                parsed.to_dds_name("rt", &self.node_name, ""),
                MessageTypeName::new("isochron_msgs", "Activity").dds_msg_type(),
                &qos,
                TopicKind::NoKey,
            )
            .map_err(|e| dds(format!("creating topic {name}: {e:?}")))
    }

    /// A writer of `camera`'s activity.
    pub fn publisher(&mut self, camera: &str) -> Result<Publisher<Activity>, DdsError> {
        let topic = self.activity_topic(camera)?;
        self.node
            .create_publisher(&topic, None)
            .map_err(|e| DdsError {
                domain: self.domain,
                detail: format!("creating the publisher of {camera}: {e:?}"),
            })
    }

    /// A reader of `camera`'s activity.
    pub fn subscription(&mut self, camera: &str) -> Result<Subscription<Activity>, DdsError> {
        let topic = self.activity_topic(camera)?;
        self.node
            .create_subscription(&topic, None)
            .map_err(|e| DdsError {
                domain: self.domain,
                detail: format!("creating the subscription of {camera}: {e:?}"),
            })
    }
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
