//! The bridge's topics and services, each declared once: the config key that
//! names it, its type as both transports name it, and its QoS. The DDS and Zenoh
//! sides create theirs from these declarations, and [`Names`] holds the names a
//! config gives them.
//!
//! * [`GRID`], `costmap.topic`: `nav_msgs/msg/OccupancyGrid`, latched — what
//!   `map_server` offers, so a late joiner (a Nav2 costmap started after the
//!   bridge) gets the current grid at once;
//! * [`UPDATES`], `costmap.updates_topic` (default `<topic>_updates`):
//!   `map_msgs/msg/OccupancyGridUpdate`, a stream — deltas relative to the last
//!   full grid, which is what Nav2's StaticLayer subscribes to with
//!   `subscribe_to_updates: true`;
//! * [`PEOPLE`], `costmap.people_topic`: `geometry_msgs/msg/PoseArray`, a stream —
//!   the people the detector confirmed, one message per detected frame, stamped
//!   with its capture time;
//! * [`MARKERS`], `costmap.markers_topic`: `visualization_msgs/msg/MarkerArray`,
//!   latched — camera footprints, zones, path segments and routes for rviz2 /
//!   Foxglove;
//! * [`PEOPLE_MARKERS`], `costmap.people_markers_topic`:
//!   `visualization_msgs/msg/MarkerArray`, a stream — the confirmed people of a
//!   camera drawn, one message per detected frame;
//! * [`SPEED_FILTER_INFO`], `costmap.speed_filter_info_topic`:
//!   `nav2_msgs/msg/CostmapFilterInfo`, and [`SPEED_MASK`],
//!   `costmap.speed_mask_topic`: its mask `nav_msgs/msg/OccupancyGrid`, both
//!   latched — what Nav2's SpeedFilter reads;
//! * [`FORECAST`], `costmap.forecast_topic`: `nav_msgs/msg/OccupancyGrid`,
//!   latched — the cost expected `forecast_ahead_min` ahead;
//! * [`PLAN_OFFLINE`], `costmap.plan_offline_service`, and [`PLAN_NOW`],
//!   `costmap.plan_now_service`: the services `isochron_msgs/srv/PlanOffline` and
//!   `PlanNow` (ros/isochron_msgs), answered by [`crate::plan`];
//! * [`PLAN_GRAPH`], `costmap.plan_graph_service`: `isochron_msgs/srv/PlanGraph`,
//!   planning over the route graph across departure times, answered there too;
//! * [`ROUTE_SERVER`], `costmap.route_server` and `costmap.route_scorer`: the
//!   route server's `nav2_msgs/srv/DynamicEdges`, which the bridge calls
//!   ([`crate::route_server`]).
//!
//! Latched is reliable, transient-local, keep last 1 ([`LATCHED`]); a stream is
//! reliable, volatile, keep last 10 ([`STREAM`]). Each type is named by its DDS
//! name and its type description hash (RIHS01, from the type's `.msg`
//! definitions: the same in Jazzy and Kilted, checked against the rclpy wheels'
//! type descriptions by `tests/it/zenoh.rs`), which rmw_zenoh puts in its key
//! expressions.

use std::collections::BTreeMap;
use std::marker::PhantomData;

use isochron_config::CostmapConfig;
use isochron_planning::query::PlanKind;
pub use isochron_zenoh::names::{Qos, RosType};

use crate::msgs::{CostmapFilterInfo, MarkerArray, OccupancyGrid, OccupancyGridUpdate, PoseArray};

/// The types the bridge sends and serves: their DDS names and type hashes.
pub mod types {
    use super::RosType;

    /// `nav_msgs/msg/OccupancyGrid`.
    pub const OCCUPANCY_GRID: RosType = RosType {
        dds_name: "nav_msgs::msg::dds_::OccupancyGrid_",
        hash: "RIHS01_8d348150c12913a31ee0ec170fbf25089e4745d17035792a1ba94d6f0bc0cfc7",
    };
    /// `map_msgs/msg/OccupancyGridUpdate`.
    pub const OCCUPANCY_GRID_UPDATE: RosType = RosType {
        dds_name: "map_msgs::msg::dds_::OccupancyGridUpdate_",
        hash: "RIHS01_c4095b0be2e4363f8978a1570e0293ee093436f1e1c61d99b48502ac317025e8",
    };
    /// `geometry_msgs/msg/PoseArray`.
    pub const POSE_ARRAY: RosType = RosType {
        dds_name: "geometry_msgs::msg::dds_::PoseArray_",
        hash: "RIHS01_af0cc36d190e104d546d168d6b39df04fa4b4ccecf59cb4c9ed328d3d5004aa0",
    };
    /// `visualization_msgs/msg/MarkerArray`.
    pub const MARKER_ARRAY: RosType = RosType {
        dds_name: "visualization_msgs::msg::dds_::MarkerArray_",
        hash: "RIHS01_86cb8800b6fb05b5eff1abd7a56f62a5641d3ae9a1c29e78e67e704f1d067dcf",
    };
    /// `nav2_msgs/msg/CostmapFilterInfo`.
    pub const COSTMAP_FILTER_INFO: RosType = RosType {
        dds_name: "nav2_msgs::msg::dds_::CostmapFilterInfo_",
        hash: "RIHS01_61ce391bf7690f76a331c01c9d5ce8ca71e6c99273b9fb75e48380f05c6dfdc8",
    };
    /// `isochron_msgs/srv/PlanNow` (a service: without `Request_`/`Response_`).
    pub const PLAN_NOW: RosType = RosType {
        dds_name: "isochron_msgs::srv::dds_::PlanNow_",
        hash: "RIHS01_dff9c18dbd331fcfcc5d0425b6b3c55111f50283aa00584e7731f029156e68fc",
    };
    /// `isochron_msgs/srv/PlanOffline`.
    pub const PLAN_OFFLINE: RosType = RosType {
        dds_name: "isochron_msgs::srv::dds_::PlanOffline_",
        hash: "RIHS01_842684142b8532e0527d5fa42b630f3dc55e6d5740de27bf6655d97b6d9538a1",
    };
    /// `isochron_msgs/srv/PlanGraph`.
    pub const PLAN_GRAPH: RosType = RosType {
        dds_name: "isochron_msgs::srv::dds_::PlanGraph_",
        hash: "RIHS01_41dbd95ce2038c3547018753409eba9311f518df44b472b616fb5bc626fe8316",
    };
    /// `nav2_msgs/srv/DynamicEdges` (the route server's; the bridge calls it).
    pub const DYNAMIC_EDGES: RosType = RosType {
        dds_name: "nav2_msgs::srv::dds_::DynamicEdges_",
        hash: "RIHS01_857b6e430a2aa89345e2b8bddc0a4956c425d526218ae43e636577de465da316",
    };
}

/// Latched: reliable, transient-local, keep last 1 (the grid, the markers, the
/// speed filter and the forecast).
pub const LATCHED: Qos = Qos {
    reliable: true,
    transient_local: true,
    depth: 1,
};

/// A stream: reliable, volatile, keep last 10 (the updates, the people and their
/// markers).
pub const STREAM: Qos = Qos {
    reliable: true,
    transient_local: false,
    depth: 10,
};

/// Where a topic's or a service's name comes from: a key of the config.
#[derive(Debug, Clone, Copy)]
pub struct ConfigKey {
    /// The key, e.g. `costmap.people_topic`.
    pub key: &'static str,
    /// Its value in a config.
    pub value: fn(&CostmapConfig) -> String,
}

/// A topic of the bridge, whose messages are `M`s.
#[derive(Debug)]
pub struct TopicSpec<M> {
    /// The key that names it.
    pub config: ConfigKey,
    /// Its type.
    pub ty: RosType,
    /// Its QoS, the same on both transports.
    pub qos: Qos,
    message: PhantomData<fn(M)>,
}

impl<M> TopicSpec<M> {
    /// The topic named by `config`, of `ty` with `qos`.
    pub const fn new(config: ConfigKey, ty: RosType, qos: Qos) -> Self {
        TopicSpec {
            config,
            ty,
            qos,
            message: PhantomData,
        }
    }
}

/// A planning service of the bridge.
#[derive(Debug, Clone, Copy)]
pub struct ServiceSpec {
    /// The key that names it.
    pub config: ConfigKey,
    /// What it plans.
    pub kind: PlanKind,
    /// Its type.
    pub ty: RosType,
}

/// The cost map.
pub const GRID: TopicSpec<OccupancyGrid> = TopicSpec::new(
    ConfigKey {
        key: "costmap.topic",
        value: |c| c.topic.clone(),
    },
    types::OCCUPANCY_GRID,
    LATCHED,
);

/// The cost map's changed rectangles.
pub const UPDATES: TopicSpec<OccupancyGridUpdate> = TopicSpec::new(
    ConfigKey {
        key: "costmap.updates_topic",
        value: CostmapConfig::updates_topic,
    },
    types::OCCUPANCY_GRID_UPDATE,
    STREAM,
);

/// The confirmed people.
pub const PEOPLE: TopicSpec<PoseArray> = TopicSpec::new(
    ConfigKey {
        key: "costmap.people_topic",
        value: |c| c.people_topic.clone(),
    },
    types::POSE_ARRAY,
    STREAM,
);

/// The site's markers.
pub const MARKERS: TopicSpec<MarkerArray> = TopicSpec::new(
    ConfigKey {
        key: "costmap.markers_topic",
        value: |c| c.markers_topic.clone(),
    },
    types::MARKER_ARRAY,
    LATCHED,
);

/// The confirmed people drawn.
pub const PEOPLE_MARKERS: TopicSpec<MarkerArray> = TopicSpec::new(
    ConfigKey {
        key: "costmap.people_markers_topic",
        value: |c| c.people_markers_topic.clone(),
    },
    types::MARKER_ARRAY,
    STREAM,
);

/// The speed filter's info.
pub const SPEED_FILTER_INFO: TopicSpec<CostmapFilterInfo> = TopicSpec::new(
    ConfigKey {
        key: "costmap.speed_filter_info_topic",
        value: |c| c.speed_filter_info_topic.clone(),
    },
    types::COSTMAP_FILTER_INFO,
    LATCHED,
);

/// The speed filter's mask.
pub const SPEED_MASK: TopicSpec<OccupancyGrid> = TopicSpec::new(
    ConfigKey {
        key: "costmap.speed_mask_topic",
        value: |c| c.speed_mask_topic.clone(),
    },
    types::OCCUPANCY_GRID,
    LATCHED,
);

/// The forecast cost map.
pub const FORECAST: TopicSpec<OccupancyGrid> = TopicSpec::new(
    ConfigKey {
        key: "costmap.forecast_topic",
        value: |c| c.forecast_topic.clone(),
    },
    types::OCCUPANCY_GRID,
    LATCHED,
);

/// The off-line planning service.
pub const PLAN_OFFLINE: ServiceSpec = ServiceSpec {
    config: ConfigKey {
        key: "costmap.plan_offline_service",
        value: |c| c.plan_offline_service.clone(),
    },
    kind: PlanKind::Offline,
    ty: types::PLAN_OFFLINE,
};

/// The real-time planning service.
pub const PLAN_NOW: ServiceSpec = ServiceSpec {
    config: ConfigKey {
        key: "costmap.plan_now_service",
        value: |c| c.plan_now_service.clone(),
    },
    kind: PlanKind::Now,
    ty: types::PLAN_NOW,
};

/// The planning service over the route graph.
pub const PLAN_GRAPH: ServiceSpec = ServiceSpec {
    config: ConfigKey {
        key: "costmap.plan_graph_service",
        value: |c| c.plan_graph_service.clone(),
    },
    kind: PlanKind::Graph,
    ty: types::PLAN_GRAPH,
};

/// The planning services, in the order each transport creates and serves them.
pub const SERVICES: [ServiceSpec; 3] = [PLAN_OFFLINE, PLAN_NOW, PLAN_GRAPH];

/// A service the bridge calls: where its name comes from and its type.
#[derive(Debug, Clone, Copy)]
pub struct ClientSpec {
    /// The key that names it.
    pub config: ConfigKey,
    /// Its type.
    pub ty: RosType,
}

/// The route server's `DynamicEdgesScorer`, told which edges people closed and
/// what each costs ([`crate::route_server`]).
pub const ROUTE_SERVER: ClientSpec = ClientSpec {
    config: ConfigKey {
        key: "costmap.route_server",
        value: CostmapConfig::route_adjust_edges_service,
    },
    ty: types::DYNAMIC_EDGES,
};

/// Every key that names a topic or a service: what [`Names`] holds.
const KEYS: [ConfigKey; 12] = [
    GRID.config,
    UPDATES.config,
    PEOPLE.config,
    MARKERS.config,
    PEOPLE_MARKERS.config,
    SPEED_FILTER_INFO.config,
    SPEED_MASK.config,
    FORECAST.config,
    PLAN_OFFLINE.config,
    PLAN_NOW.config,
    PLAN_GRAPH.config,
    ROUTE_SERVER.config,
];

/// The names of the bridge's topics and services, by the keys that give them.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Names(BTreeMap<&'static str, String>);

impl Names {
    /// The names `costmap` gives.
    pub fn from_config(costmap: &CostmapConfig) -> Names {
        Names::with(|key| (key.value)(costmap))
    }

    /// The names `name` gives each key.
    pub fn with(mut name: impl FnMut(&ConfigKey) -> String) -> Names {
        Names(KEYS.iter().map(|key| (key.key, name(key))).collect())
    }

    /// The name of what `config` names.
    pub fn of(&self, config: &ConfigKey) -> &str {
        self.0
            .get(config.key)
            .map(String::as_str)
            .expect("every key that names a topic or a service is in KEYS")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_topic_and_service_has_its_configured_name() {
        let names = Names::from_config(&CostmapConfig::default());
        let keys = [
            GRID.config,
            UPDATES.config,
            PEOPLE.config,
            MARKERS.config,
            PEOPLE_MARKERS.config,
            SPEED_FILTER_INFO.config,
            SPEED_MASK.config,
            FORECAST.config,
            PLAN_OFFLINE.config,
            PLAN_NOW.config,
            PLAN_GRAPH.config,
        ];
        for key in keys {
            assert!(names.of(&key).starts_with("/isochron/"), "{}", key.key);
        }
        assert_eq!(names.of(&GRID.config), "/isochron/activity_costmap");
        assert_eq!(
            names.of(&UPDATES.config),
            "/isochron/activity_costmap_updates"
        );
        assert_eq!(names.of(&PLAN_NOW.config), "/isochron/plan_now");
        assert_eq!(names.of(&PLAN_GRAPH.config), "/isochron/plan_graph");
        assert_eq!(
            names.of(&ROUTE_SERVER.config),
            "route_server/DynamicEdgesScorer/adjust_edges"
        );
    }

    /// The DDS type names are those `ros2-client` gives `<package>/msg/<Type>`.
    #[test]
    fn dds_names_are_rosidls() {
        let types = [
            types::OCCUPANCY_GRID,
            types::OCCUPANCY_GRID_UPDATE,
            types::POSE_ARRAY,
            types::MARKER_ARRAY,
            types::COSTMAP_FILTER_INFO,
        ];
        for ty in types {
            let (package, rest) = ty.dds_name.split_once("::msg::dds_::").unwrap();
            let name = rest.strip_suffix('_').unwrap();
            assert_eq!(
                ros2_client::MessageTypeName::new(package, name).dds_msg_type(),
                ty.dds_name
            );
        }
    }
}
