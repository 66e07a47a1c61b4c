//! ROS 2 output over DDS, in pure Rust (`ros2-client` on RustDDS): no ROS install.
//!
//! * `<topic>`: `nav_msgs/msg/OccupancyGrid`, reliable, transient-local, keep last 1
//!   — what `map_server` offers, so a late joiner (a Nav2 costmap started after the
//!   bridge) gets the current grid at once;
//! * `<topic>_updates` (or `costmap.updates_topic`): `map_msgs/msg/OccupancyGridUpdate`,
//!   reliable, volatile, keep last 10 — deltas relative to the last full grid, which
//!   is what Nav2's StaticLayer subscribes to with `subscribe_to_updates: true`;
//! * `costmap.people_topic`: `geometry_msgs/msg/PoseArray`, reliable, volatile, keep
//!   last 10 — the people the detector confirmed, one message per detected frame,
//!   stamped with its capture time;
//! * `costmap.markers_topic`: `visualization_msgs/msg/MarkerArray`, reliable,
//!   transient-local, keep last 1 — camera footprints, zones, path segments and
//!   routes for rviz2 / Foxglove, latched;
//! * `costmap.people_markers_topic`: `visualization_msgs/msg/MarkerArray`,
//!   reliable, volatile, keep last 10 — the confirmed people of a camera drawn
//!   ([`crate::people`]), one message per detected frame;
//! * `costmap.speed_filter_info_topic`: `nav2_msgs/msg/CostmapFilterInfo` and
//!   `costmap.speed_mask_topic`: its mask `nav_msgs/msg/OccupancyGrid`, both
//!   reliable, transient-local, keep last 1 — what Nav2's SpeedFilter reads;
//! * `costmap.forecast_topic`: `nav_msgs/msg/OccupancyGrid`, reliable,
//!   transient-local, keep last 1 — the cost expected `forecast_ahead_min` ahead;
//! * `costmap.plan_offline_service`, `costmap.plan_now_service`: the services
//!   `isochron_msgs/srv/PlanOffline` and `PlanNow` (ros/isochron_msgs) on
//!   `rq/<name>Request` and `rr/<name>Reply`, in the request/reply layouts of
//!   rmw_cyclonedds and rmw_fastrtps ([`crate::plan_dds`]).
//!
//! The DDS participant joins `costmap.ros_domain_id` (else `$ROS_DOMAIN_ID`, else 0)
//! and uses the network interfaces of `costmap.dds_interfaces` (else all; only
//! loopback when `ROS_LOCALHOST_ONLY=1` or `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`):
//! RustDDS announces only their addresses and multicasts only on them, but binds
//! its sockets to 0.0.0.0 regardless (hard-coded in 0.15) — a hard limit is the
//! unit's `IPAddressAllow=`/`IPAddressDeny=` or a firewall (docs/security.md).
//!
//! With `costmap.security_dir` the participant runs DDS Security (SROS2) with the
//! bridge's enclave, as the link does: only robots of the site's keystore whose
//! permissions allow it read the topics and call the services, and no other
//! participant can write on the bridge's topics or answer its services.

use std::net::IpAddr;
use std::time::Duration;

use ros2_client::dds::{DEFAULT_PUBLISHER_QOS, Publisher};
use ros2_client::qos::Durability;
use ros2_client::{Name, NodeName};
use rustdds::dds::qos::HasQoSPolicy;
use rustdds::{QosPolicies, Topic, TopicDescription, policy};

use isochron_dds::{DdsError, RosNode, keep_last};

use isochron_planning::query::{PlanKind, PlanRequest, PlanResponse};
use isochron_runtime::stage::Context;

use isochron_ros2::msgs::{CostmapFilterInfo, MarkerArray, OccupancyGrid, OccupancyGridUpdate, PoseArray};
use crate::plan_dds::{PlanCounts, PlanServices};
use crate::zenoh_out::{Names, ZenohOutput, put};

/// The bridge's ROS 2 node: `/isochron/<NODE>`.
const NODE: &str = "costmap_bridge";

/// Grids kept for late joiners: the current one.
const GRID_DEPTH: i32 = 1;
/// Updates kept for slow readers.
const UPDATES_DEPTH: i32 = 10;
/// People messages kept for slow readers.
const PEOPLE_DEPTH: i32 = 10;
/// How long `publish` waits for a full reliable send window before it gives up.
const MAX_BLOCKING: Duration = Duration::from_millis(50);

/// Where and how the bridge talks ROS 2.
#[derive(Debug, Clone, PartialEq)]
pub struct RosSettings {
    /// DDS domain (ROS_DOMAIN_ID).
    pub domain_id: u16,
    /// Network interfaces (their addresses) DDS may use; empty: all.
    pub interfaces: Vec<IpAddr>,
    /// The grid topic, e.g. `/isochron/activity_costmap`.
    pub topic: String,
    /// The updates topic, e.g. `/isochron/activity_costmap_updates`.
    pub updates_topic: String,
    /// The people topic, e.g. `/isochron/people`.
    pub people_topic: String,
    /// The markers topic, e.g. `/isochron/markers`.
    pub markers_topic: String,
    /// The people markers topic, e.g. `/isochron/people_markers`.
    pub people_markers_topic: String,
    /// The speed filter info topic, e.g. `/isochron/speed_filter_info`.
    pub speed_filter_info_topic: String,
    /// The speed mask topic, e.g. `/isochron/speed_mask`.
    pub speed_mask_topic: String,
    /// The forecast topic, e.g. `/isochron/activity_forecast`.
    pub forecast_topic: String,
    /// The off-line planning service, e.g. `/isochron/plan_offline`.
    pub plan_offline_service: String,
    /// The real-time planning service, e.g. `/isochron/plan_now`.
    pub plan_now_service: String,
    /// The bridge's SROS2 enclave (`costmap.security_dir`): DDS Security with
    /// it, none without.
    pub enclave: Option<std::path::PathBuf>,
    /// The same topics and services on Zenoh in rmw_zenoh's format, if configured.
    pub zenoh: Option<isochron_zenoh::Settings>,
}

/// Why ROS 2 output could not start.
#[derive(Debug, thiserror::Error)]
pub enum RosError {
    /// A topic name ROS 2 does not accept.
    #[error("invalid ROS 2 topic name '{name}': {detail}")]
    TopicName {
        /// The name.
        name: String,
        /// What is wrong.
        detail: String,
    },
    /// DDS could not be set up (ports, interfaces).
    #[error(transparent)]
    Dds(#[from] DdsError),
    /// Zenoh output could not be set up (its configuration, its session).
    #[error(transparent)]
    Zenoh(#[from] isochron_zenoh::ZenohError),
}

impl isochron_exit::Classify for RosError {
    /// DDS did not start (ports, interfaces, a name it refused): the network side
    /// is unavailable; a Zenoh configuration Zenoh refuses is permanent.
    fn exit_code(&self) -> i32 {
        match self {
            RosError::Zenoh(e) => isochron_exit::Classify::exit_code(e),
            _ => isochron_exit::UNAVAILABLE,
        }
    }
}

/// A sample could not be published (the text is what DDS said).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{detail}")]
pub struct PublishError {
    /// What DDS said.
    pub detail: String,
}

impl PublishError {
    /// What a failed write says, without the sample it carries back (a whole
    /// grid in a log line).
    fn of<M>(e: ros2_client::WriteError<M>) -> PublishError {
        PublishError {
            detail: e.to_string(),
        }
    }
}

/// Parses a topic name (`/a/b` absolute, `a/b` relative to the node's namespace `/`).
pub fn topic_name(name: &str) -> Result<Name, RosError> {
    Name::parse(name).map_err(|e| RosError::TopicName {
        name: name.to_string(),
        detail: format!("{e}"),
    })
}

/// The ROS 2 node of the bridge and its two publishers.
pub struct RosOutput {
    grid: Publisher<OccupancyGrid>,
    updates: Publisher<OccupancyGridUpdate>,
    people: Publisher<PoseArray>,
    markers: Publisher<MarkerArray>,
    people_markers: Publisher<MarkerArray>,
    filter_info: Publisher<CostmapFilterInfo>,
    mask: Publisher<OccupancyGrid>,
    forecast: Publisher<OccupancyGrid>,
    /// `isochron_msgs/srv/PlanOffline` and `PlanNow`.
    plans: PlanServices,
    /// The grid topic's DDS name (`rt/...`) and the QoS its writer offers: what
    /// RustDDS matches remote readers against.
    grid_match: (String, QosPolicies),
    /// The same on Zenoh (`[costmap.zenoh]`).
    zenoh: Option<ZenohOutput>,
    /// What the planning services did on Zenoh.
    zenoh_counts: PlanCounts,
    ros: RosNode,
}

impl RosOutput {
    /// Joins the DDS domain and creates the node `/isochron/costmap_bridge` with its
    /// publishers.
    pub fn start(settings: &RosSettings) -> Result<RosOutput, RosError> {
        let mut ros = RosNode::start(
            settings.domain_id,
            &settings.interfaces,
            NODE,
            settings.enclave.as_deref(),
        )?;

        let [
            grid_topic,
            updates_topic,
            people_topic,
            markers_topic,
            people_markers_topic,
            filter_info_topic,
            mask_topic,
            forecast_topic,
        ] = topics(&ros, settings)?;
        // RustDDS gives a writer the ROS default publisher's QoS overridden by the
        // topic's (`Publisher::create_datawriter`).
        let grid_match = (
            grid_topic.name(),
            QosPolicies::from(DEFAULT_PUBLISHER_QOS).modify_by(&grid_topic.qos()),
        );
        macro_rules! publisher {
            ($topic:expr, $what:literal) => {
                ros.node_mut()
                    .create_publisher(&$topic, None)
                    .map_err(|e| {
                        ros.error(format!(
                            concat!("creating the ", $what, " publisher: {}"),
                            e
                        ))
                    })?
            };
        }
        let grid = publisher!(grid_topic, "grid");
        let updates = publisher!(updates_topic, "updates");
        let people = publisher!(people_topic, "people");
        let markers = publisher!(markers_topic, "markers");
        let people_markers = publisher!(people_markers_topic, "people markers");
        let filter_info = publisher!(filter_info_topic, "speed filter info");
        let mask = publisher!(mask_topic, "speed mask");
        let forecast = publisher!(forecast_topic, "forecast");
        let node = NodeName::new("/isochron", NODE)
            .map_err(|e| ros.error(format!("node name {NODE}: {e}")))?;
        let plans = PlanServices::start(
            &ros.context().domain_participant(),
            &node,
            &topic_name(&settings.plan_offline_service)?,
            &topic_name(&settings.plan_now_service)?,
        )
        .map_err(|e| ros.error(e.to_string()))?;
        let zenoh = match &settings.zenoh {
            Some(z) => {
                let names = Names {
                    grid: &settings.topic,
                    updates: &settings.updates_topic,
                    people: &settings.people_topic,
                    markers: &settings.markers_topic,
                    people_markers: &settings.people_markers_topic,
                    speed_filter_info: &settings.speed_filter_info_topic,
                    speed_mask: &settings.speed_mask_topic,
                    forecast: &settings.forecast_topic,
                    plan_offline: &settings.plan_offline_service,
                    plan_now: &settings.plan_now_service,
                };
                let output = ZenohOutput::start(z, &names, NODE)?;
                tracing::info!(
                    "ROS 2 on Zenoh (rmw_zenoh's format) too: domain {}, {} to {}, listening on {}",
                    z.domain,
                    if z.mode == isochron_zenoh::Mode::Client {
                        "client"
                    } else {
                        "peer"
                    },
                    z.connect.join(", "),
                    if z.listen.is_empty() {
                        "nothing".to_string()
                    } else {
                        z.listen.join(", ")
                    }
                );
                Some(output)
            }
            None => None,
        };

        Ok(RosOutput {
            grid,
            updates,
            people,
            markers,
            people_markers,
            filter_info,
            mask,
            forecast,
            plans,
            grid_match,
            zenoh,
            zenoh_counts: PlanCounts::default(),
            ros,
        })
    }

    /// Publishes a full grid.
    pub fn publish_grid(&self, grid: OccupancyGrid) -> Result<(), PublishError> {
        let zenoh = self
            .zenoh
            .as_ref()
            .map(|z| put(&z.grid, &grid).map_err(|detail| PublishError { detail }));
        self.grid.publish(grid).map_err(PublishError::of)?;
        zenoh.unwrap_or(Ok(()))
    }

    /// Publishes a delta.
    pub fn publish_update(&self, update: OccupancyGridUpdate) -> Result<(), PublishError> {
        let zenoh = self
            .zenoh
            .as_ref()
            .map(|z| put(&z.updates, &update).map_err(|detail| PublishError { detail }));
        self.updates.publish(update).map_err(PublishError::of)?;
        zenoh.unwrap_or(Ok(()))
    }

    /// Publishes the people of one detected frame.
    pub fn publish_people(&self, people: PoseArray) -> Result<(), PublishError> {
        let zenoh = self
            .zenoh
            .as_ref()
            .map(|z| put(&z.people, &people).map_err(|detail| PublishError { detail }));
        self.people.publish(people).map_err(PublishError::of)?;
        zenoh.unwrap_or(Ok(()))
    }

    /// Publishes the people markers of one detected frame.
    pub fn publish_people_markers(&self, markers: MarkerArray) -> Result<(), PublishError> {
        let zenoh = self
            .zenoh
            .as_ref()
            .map(|z| put(&z.people_markers, &markers).map_err(|detail| PublishError { detail }));
        self.people_markers
            .publish(markers)
            .map_err(PublishError::of)?;
        zenoh.unwrap_or(Ok(()))
    }

    /// Publishes (and latches) the markers.
    pub fn publish_markers(&self, markers: MarkerArray) -> Result<(), PublishError> {
        let zenoh = self
            .zenoh
            .as_ref()
            .map(|z| put(&z.markers, &markers).map_err(|detail| PublishError { detail }));
        self.markers.publish(markers).map_err(PublishError::of)?;
        zenoh.unwrap_or(Ok(()))
    }

    /// Publishes (and latches) the speed filter's info.
    pub fn publish_filter_info(&self, info: CostmapFilterInfo) -> Result<(), PublishError> {
        let zenoh = self
            .zenoh
            .as_ref()
            .map(|z| put(&z.filter_info, &info).map_err(|detail| PublishError { detail }));
        self.filter_info.publish(info).map_err(PublishError::of)?;
        zenoh.unwrap_or(Ok(()))
    }

    /// Publishes (and latches) a speed mask.
    pub fn publish_mask(&self, mask: OccupancyGrid) -> Result<(), PublishError> {
        let zenoh = self
            .zenoh
            .as_ref()
            .map(|z| put(&z.mask, &mask).map_err(|detail| PublishError { detail }));
        self.mask.publish(mask).map_err(PublishError::of)?;
        zenoh.unwrap_or(Ok(()))
    }

    /// Publishes (and latches) a forecast grid.
    pub fn publish_forecast(&self, grid: OccupancyGrid) -> Result<(), PublishError> {
        let zenoh = self
            .zenoh
            .as_ref()
            .map(|z| put(&z.forecast, &grid).map_err(|detail| PublishError { detail }));
        self.forecast.publish(grid).map_err(PublishError::of)?;
        zenoh.unwrap_or(Ok(()))
    }

    /// Answers the requests of both planning services that are due with
    /// `answer` — the same function that answers `<prefix>/plan` over iceoryx2;
    /// returns how many were answered ([`PlanServices::serve`]: malformed requests
    /// get `STATUS_BAD_REQUEST`, floods are dropped, both counted in `cx`).
    pub fn serve_plans(
        &mut self,
        cx: &mut Context,
        mut answer: impl FnMut(PlanKind, &PlanRequest) -> PlanResponse,
    ) -> usize {
        let mut n = self.plans.serve(cx, &mut answer);
        if let Some(z) = &mut self.zenoh {
            n += z.serve(cx, &mut self.zenoh_counts, &mut answer);
        }
        n
    }

    /// What the planning services did so far.
    pub fn plan_counts(&self) -> PlanCounts {
        let (dds, z) = (self.plans.counts(), self.zenoh_counts);
        PlanCounts {
            answered: dds.answered + z.answered,
            rejected: dds.rejected + z.rejected,
            dropped: dds.dropped + z.dropped,
        }
    }

    /// Subscribers matched with the grid publisher: the remote readers DDS discovery
    /// knows on the grid topic whose requested QoS the writer offers — the rule by
    /// which RustDDS matches a discovered reader to a local writer
    /// (`Writer::update_reader_proxy`).
    ///
    /// Not `Publisher::get_subscription_count`: ros2-client 0.12 counts from a map
    /// that only gets an entry for a publisher when a first reader matches it, and
    /// logs an ERROR ("Publisher … not known to node") on every call until then —
    /// every status report of a bridge nobody listens to.
    pub fn grid_subscribers(&self) -> usize {
        let (topic, offered) = &self.grid_match;
        self.ros
            .context()
            .domain_participant()
            .discovered_readers()
            .iter()
            .filter(|r| {
                let s = &r.subscription_topic_data;
                s.topic_name == *topic && offered.compliance_failure_wrt(&s.qos()).is_none()
            })
            .count()
    }
}

/// The QoS of the bridge's topics: reliable (waiting at most [`MAX_BLOCKING`] for
/// room), `durability`, keep last `depth`, and at most `depth` samples in the
/// The output's topics, in this order: the grid, its updates, the people, the
/// markers, the people markers, the speed filter's info, the speed mask, the
/// forecast.
fn topics(ros: &RosNode, s: &RosSettings) -> Result<[Topic; 8], RosError> {
    let latched = Durability::TransientLocal;
    let volatile = Durability::Volatile;
    let specs = [
        (&s.topic, ("nav_msgs", "OccupancyGrid"), latched, GRID_DEPTH),
        (
            &s.updates_topic,
            ("map_msgs", "OccupancyGridUpdate"),
            volatile,
            UPDATES_DEPTH,
        ),
        (
            &s.people_topic,
            ("geometry_msgs", "PoseArray"),
            volatile,
            PEOPLE_DEPTH,
        ),
        (
            &s.markers_topic,
            ("visualization_msgs", "MarkerArray"),
            latched,
            GRID_DEPTH,
        ),
        (
            &s.people_markers_topic,
            ("visualization_msgs", "MarkerArray"),
            volatile,
            PEOPLE_DEPTH,
        ),
        (
            &s.speed_filter_info_topic,
            ("nav2_msgs", "CostmapFilterInfo"),
            latched,
            GRID_DEPTH,
        ),
        (
            &s.speed_mask_topic,
            ("nav_msgs", "OccupancyGrid"),
            latched,
            GRID_DEPTH,
        ),
        (
            &s.forecast_topic,
            ("nav_msgs", "OccupancyGrid"),
            latched,
            GRID_DEPTH,
        ),
    ];
    let mut made = Vec::with_capacity(specs.len());
    for (name, message_type, durability, depth) in specs {
        made.push(ros.topic(
            &topic_name(name)?,
            message_type,
            &topic_qos(durability, depth),
        )?);
    }
    Ok(made
        .try_into()
        .unwrap_or_else(|_| unreachable!("eight specs make eight topics")))
}

/// writer's cache ([`keep_last`]).
fn topic_qos(durability: Durability, depth: i32) -> QosPolicies {
    keep_last(
        policy::Reliability::Reliable {
            max_blocking_time: rustdds::Duration::from_std(MAX_BLOCKING),
        },
        match durability {
            Durability::Volatile => policy::Durability::Volatile,
            Durability::TransientLocal => policy::Durability::TransientLocal,
        },
        depth,
    )
}

/// The interfaces DDS may use: `configured`, else loopback only when ROS's own
/// variables ask for it (`ROS_LOCALHOST_ONLY=1`,
/// `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`), else all (empty).
pub fn interfaces(configured: &[IpAddr]) -> Vec<IpAddr> {
    if !configured.is_empty() {
        return configured.to_vec();
    }
    let localhost_only = std::env::var("ROS_LOCALHOST_ONLY").is_ok_and(|v| v.trim() == "1")
        || std::env::var("ROS_AUTOMATIC_DISCOVERY_RANGE")
            .is_ok_and(|v| v.trim().eq_ignore_ascii_case("LOCALHOST"));
    if localhost_only {
        vec![IpAddr::from([127, 0, 0, 1])]
    } else {
        Vec::new()
    }
}

#[cfg(test)]
mod tests {
    use rustdds::CDRSerializerAdapter;
    use rustdds::no_key::SerializerAdapter;

    use super::*;
    use isochron_ros2::msgs::{Header, MapMetaData, Point, Pose, Quaternion, Time};

    /// The CDR bytes of a tiny grid, laid out by hand from the `.msg` definitions:
    /// this is what any ROS 2 subscriber decodes.
    #[test]
    fn occupancy_grid_cdr_layout() {
        let grid = OccupancyGrid {
            header: Header {
                stamp: Time { sec: 7, nanosec: 9 },
                frame_id: "map".into(),
            },
            info: MapMetaData {
                map_load_time: Time { sec: 7, nanosec: 9 },
                resolution: 0.5,
                width: 2,
                height: 1,
                origin: Pose {
                    position: Point {
                        x: 1.0,
                        y: 2.0,
                        z: 0.0,
                    },
                    orientation: Quaternion::from_yaw(0.0),
                },
            },
            data: vec![-1, 100],
        };
        let bytes = CDRSerializerAdapter::<OccupancyGrid>::to_bytes(&grid).unwrap();
        let mut expected: Vec<u8> = Vec::new();
        expected.extend(7i32.to_le_bytes()); // header.stamp.sec @0
        expected.extend(9u32.to_le_bytes()); // nanosec @4
        expected.extend(4u32.to_le_bytes()); // frame_id length incl. NUL @8
        expected.extend(b"map\0"); // @12
        expected.extend(7i32.to_le_bytes()); // info.map_load_time @16
        expected.extend(9u32.to_le_bytes());
        expected.extend(0.5f32.to_le_bytes()); // resolution @24
        expected.extend(2u32.to_le_bytes()); // width @28
        expected.extend(1u32.to_le_bytes()); // height @32
        expected.extend([0u8; 4]); // pad to 8 for the f64s @36
        for v in [1.0f64, 2.0, 0.0, 0.0, 0.0, 0.0, 1.0] {
            expected.extend(v.to_le_bytes()); // origin @40..96
        }
        expected.extend(2u32.to_le_bytes()); // data length @96
        expected.extend([0xff, 100]); // data
        assert_eq!(bytes.as_ref(), expected.as_slice());
    }

    #[test]
    fn interfaces_prefer_the_config() {
        let lo: IpAddr = "127.0.0.1".parse().unwrap();
        assert_eq!(interfaces(&[lo]), vec![lo]);
        assert!(topic_name("/isochron/activity_costmap").is_ok());
        assert!(topic_name("/bad//name").is_err());
        assert!(topic_name("/bad name").is_err());
    }
}
