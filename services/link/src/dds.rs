//! The link's DDS side (`ros2-client` on RustDDS, as the costmap bridge): one
//! participant on `link.ros_domain_id` using the interfaces of
//! `link.dds_interfaces`, the node `/isochron/link_<box_id>`, and per camera the
//! topics `<link.namespace>/<camera>/<stream>`: `activity` best effort, keep last
//! 1 (only the newest second is worth sending; a lost one is replaced a second
//! later); `events` and `detections` reliable, keep last `link.queue_messages`;
//! `status` reliable, one report per stage. All volatile and bounded.

use std::net::IpAddr;
use std::path::Path;

use ros2_client::dds::Node;
/// The writer and reader types [`LinkDds`] makes.
pub use ros2_client::dds::{Publisher, Subscription};
use ros2_client::{CreateError, CreateResult, Name};
use rustdds::{QosPolicies, policy};
use serde::Serialize;
use serde::de::DeserializeOwned;

use isochron_dds::{DdsError, RosNode, bounded, keep_last};
use isochron_runtime::topology::StageKind;

use crate::msgs::{Delivery, LinkStream, Message, Status};

/// The link's DDS participant and node.
pub struct LinkDds {
    ros: RosNode,
    namespace: String,
}

impl LinkDds {
    /// Joins `domain` on `interfaces` (empty: all) as node `/isochron/link_<box_id>`,
    /// with DDS Security from `enclave` if given; topics go under `namespace`.
    pub fn start(
        domain: u16,
        interfaces: &[IpAddr],
        (box_id, enclave): (&str, Option<&Path>),
        namespace: &str,
    ) -> Result<LinkDds, DdsError> {
        isochron_dds::limit_dds_logging();
        let name = if box_id.is_empty() {
            "link".to_string()
        } else {
            format!("link_{box_id}")
        };
        Ok(LinkDds {
            ros: RosNode::start(domain, interfaces, &name, enclave)?,
            namespace: namespace.to_string(),
        })
    }

    /// `<namespace>/<camera>/<suffix>`.
    pub fn topic_name(&self, camera: &str, suffix: &str) -> String {
        format!("{}/{camera}/{suffix}", self.namespace)
    }

    /// The node, for the publishers' matched-subscription counts.
    pub fn node(&self) -> &Node {
        self.ros.node()
    }

    /// The `suffix` topic of `camera` (message `isochron_msgs/msg/<msg>`) and an
    /// endpoint on it: a writer or a reader, as the caller asks.
    fn endpoint<M, E: Endpoint<M>>(
        &mut self,
        camera: &str,
        (suffix, msg): (&str, &str),
        qos: QosPolicies,
    ) -> Result<E, DdsError> {
        let name = self.topic_name(camera, suffix);
        let parsed =
            Name::parse(&name).map_err(|e| self.ros.error(format!("topic {name}: {e}")))?;
        let topic = self.ros.topic(&parsed, ("isochron_msgs", msg), &qos)?;
        patiently(|| E::create(self.ros.node_mut(), &topic)).map_err(|e| {
            self.ros.error(format!(
                "creating the {suffix} {} of {camera}: {e}",
                E::WHAT
            ))
        })
    }

    /// A writer or a reader (as the caller's type says: [`Publisher`] or
    /// [`Subscription`]) of stream `S` of `camera`; `queue` is the depth of a
    /// queued stream's DDS history. A reader reassembles no message larger than
    /// the stream's largest for a camera of `blocks` blocks (if known, else of
    /// the largest grid the wire allows).
    pub fn stream<S: LinkStream, E: Endpoint<Message<S>>>(
        &mut self,
        camera: &str,
        queue: usize,
        blocks: Option<usize>,
    ) -> Result<E, DdsError> {
        let qos = bounded(qos(S::DELIVERY, queue), Message::<S>::max_cdr_len(blocks));
        self.endpoint(camera, (S::SUFFIX, S::MSG), qos)
    }

    /// The writer or the reader of `camera`'s stages' status.
    pub fn status<E: Endpoint<Status>>(&mut self, camera: &str) -> Result<E, DdsError> {
        self.endpoint(camera, STATUS, bounded(status_qos(), Status::max_cdr_len()))
    }
}

/// A DDS endpoint of the link for messages `M`: a writer or a reader.
pub trait Endpoint<M>: Sized {
    /// What it is called in errors.
    const WHAT: &'static str;
    /// Creates it on `topic`.
    fn create(node: &mut Node, topic: &rustdds::Topic) -> CreateResult<Self>;
}

impl<M: Serialize> Endpoint<M> for Publisher<M> {
    const WHAT: &'static str = "writer";
    fn create(node: &mut Node, topic: &rustdds::Topic) -> CreateResult<Self> {
        node.create_publisher(topic, None)
    }
}

impl<M: DeserializeOwned + 'static> Endpoint<M> for Subscription<M> {
    const WHAT: &'static str = "reader";
    fn create(node: &mut Node, topic: &rustdds::Topic) -> CreateResult<Self> {
        node.create_subscription(topic, None)
    }
}

/// Creates a DDS entity, waiting while RustDDS's event loop catches up: it takes
/// new readers through a bounded channel (100 readers), which a link of a few
/// hundred cameras fills at start (then creating one is out of resources, as our
/// RustDDS patch `vendor/rustdds-full-reader-channel.patch` reports it). Gives
/// up after 5 s.
fn patiently<T>(mut create: impl FnMut() -> CreateResult<T>) -> CreateResult<T> {
    let end = std::time::Instant::now() + std::time::Duration::from_secs(5);
    loop {
        match create() {
            Err(CreateError::OutOfResources { .. }) if std::time::Instant::now() < end => {
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
    keep_last(reliability, policy::Durability::Volatile, depth)
}

/// Status: reliable and keep last one report per stage of a camera, so the
/// reports of a camera's stages, sent together every few seconds, all arrive
/// (latest-only per stage).
fn status_qos() -> QosPolicies {
    qos(Delivery::Queued, StageKind::pipeline().count())
}
