//! `[costmap]`: the cost map on the robots' floor, its ROS 2 output, snapshots,
//! and path planning (its segments and routes are in `segments.rs`).

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::segments::{validate_routes, validate_segments};
use super::{
    CameraConfig, Invalid, RouteConfig, SegmentConfig, ZenohConfig, check_dds, check_positive,
    check_range, is_valid_ros_topic,
};

/// `[costmap]`: block activity on the robots' map as a ROS 2 `OccupancyGrid`
/// (docs/robots.md), snapshots, and path planning on segments and routes.
///
/// The grid is configured either by `map_yaml` (a `map_server` YAML: origin and
/// resolution from it, size from its image, so the activity lines up with the
/// robots' map) or by `resolution_m`, `width_cells`, `height_cells` and the
/// `origin_*` keys. Without a grid the bridge publishes nothing to ROS 2 and only
/// answers planning requests.
///
/// Cost of a cell seen by a camera: `min(cap, round(100 · (weight_in_place·S1 +
/// weight_moving·S2 + weight_long_term·M(t*)) / cost_scale))` over the block that
/// covers it (the highest over cameras that overlap), -1 where no camera sees.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CostmapConfig {
    /// `map_server` YAML of the robots' map (relative to this file); its `origin`
    /// and `resolution` and its image's size define the grid. Default: none.
    pub map_yaml: Option<PathBuf>,
    /// Grid cell edge, metres (without `map_yaml`). Default 0.1.
    pub resolution_m: Option<f64>,
    /// Grid cells per row (without `map_yaml`).
    pub width_cells: Option<u32>,
    /// Grid rows (without `map_yaml`).
    pub height_cells: Option<u32>,
    /// x of the grid's corner (cell (0, 0)) in the map frame, metres. Default 0.
    pub origin_x_m: Option<f64>,
    /// y of the grid's corner in the map frame, metres. Default 0.
    pub origin_y_m: Option<f64>,
    /// Rotation of the grid about z, radians. Default 0. Nav2's StaticLayer ignores
    /// a map origin's yaw (the grid lands unrotated): a non-zero value is warned
    /// at load.
    pub origin_yaw_rad: Option<f64>,
    /// `header.frame_id` of the grid. Default `"map"`.
    pub frame_id: String,
    /// ROS 2 topic of the grid (`nav_msgs/msg/OccupancyGrid`, reliable,
    /// transient-local). Default `"/isochron/activity_costmap"`.
    pub topic: String,
    /// ROS 2 topic of the deltas (`map_msgs/msg/OccupancyGridUpdate`). Default
    /// `<topic>_updates`, where Nav2's StaticLayer looks for them.
    pub updates_topic: Option<String>,
    /// ROS 2 topic of the people the detector confirmed
    /// (`geometry_msgs/msg/PoseArray` in `frame_id`, stamped with the detected
    /// frame's capture time). Default `"/isochron/people"`.
    pub people_topic: String,
    /// ROS 2 topic of the camera footprints, zones, segments and routes
    /// (`visualization_msgs/msg/MarkerArray`, transient-local). Default
    /// `"/isochron/markers"`.
    pub markers_topic: String,
    /// ROS 2 topic of the confirmed people drawn (`visualization_msgs/msg/MarkerArray`,
    /// volatile): a skeleton where the model gives keypoints, else a cylinder,
    /// labelled with model and score. Default `"/isochron/people_markers"`.
    pub people_markers_topic: String,
    /// ROS 2 topic of the speed filter's `nav2_msgs/msg/CostmapFilterInfo` (type 1:
    /// speed limit in percent, base 0, multiplier 1; transient-local), for Nav2's
    /// SpeedFilter (`config/nav2-speed-filter.yaml`). Default
    /// `"/isochron/speed_filter_info"`.
    pub speed_filter_info_topic: String,
    /// ROS 2 topic of the speed mask (`nav_msgs/msg/OccupancyGrid`, the grid's
    /// geometry, transient-local): per cell the speed limit in percent of the
    /// robot's maximum, 0 meaning no limit (quiet cells and cells no camera sees).
    /// Default `"/isochron/speed_mask"`.
    pub speed_mask_topic: String,
    /// A cell whose activity cost is at least this is busy, 1 to 100. Default 30.
    pub speed_busy_from_cost: u8,
    /// ... and crowded from this cost, 1 to 100 (at least `speed_busy_from_cost`).
    /// Default 70.
    pub speed_crowded_from_cost: u8,
    /// Speed limit in quiet cells, percent (100: no limit). Default 100.
    pub speed_quiet_percent: u8,
    /// Speed limit in busy cells, percent. Default 50.
    pub speed_busy_percent: u8,
    /// Speed limit in crowded cells, percent. Default 25.
    pub speed_crowded_percent: u8,
    /// ROS 2 topic of the forecast (`nav_msgs/msg/OccupancyGrid`, the grid's
    /// geometry, transient-local): per cell the cost the long-term model expects
    /// `forecast_ahead_min` from now, `Cost(M(t* + Δ))` as planning costs a
    /// segment; -1 where no camera with a long-term store sees or its model never
    /// learned that minute. Stamped with the forecast time. Default
    /// `"/isochron/activity_forecast"`.
    pub forecast_topic: String,
    /// How far ahead the forecast looks, minutes (1 to 1440). Default 15.
    pub forecast_ahead_min: u32,
    /// The forecast is recomputed and republished this often, seconds. Default 60.
    pub forecast_every_s: f64,
    /// ROS 2 service `isochron_msgs/srv/PlanOffline` (`isochron plan offline`
    /// over ROS 2; ros/isochron_msgs). Default `"/isochron/plan_offline"`.
    pub plan_offline_service: String,
    /// ROS 2 service `isochron_msgs/srv/PlanNow` (`isochron plan now` over ROS 2).
    /// Default `"/isochron/plan_now"`.
    pub plan_now_service: String,
    /// ROS 2 service `isochron_msgs/srv/PlanGraph` (`isochron plan graph` over ROS
    /// 2: routes across departure times over `route_graph`). Default
    /// `"/isochron/plan_graph"`.
    pub plan_graph_service: String,
    /// Publish rate, Hz. Default 1.
    pub publish_hz: f64,
    /// The full grid is republished at least this often, seconds, while deltas went
    /// out since the last one (so a late joiner's grid is at most this old);
    /// between, only the changed rectangle goes out. Default 10.
    pub full_every_s: f64,
    /// DDS domain (ROS_DOMAIN_ID), 0 to 232. Default: `$ROS_DOMAIN_ID`, else 0.
    pub ros_domain_id: Option<u16>,
    /// IP addresses of the network interfaces DDS announces in discovery and sends
    /// and joins multicast on, e.g. `["127.0.0.1"]`. Default: all (loopback only
    /// when `ROS_LOCALHOST_ONLY=1`). RustDDS still binds its UDP sockets to
    /// 0.0.0.0: to make loopback-only a hard limit, add `IPAddressDeny=any` and
    /// `IPAddressAllow=localhost` to the unit (docs/security.md).
    pub dds_interfaces: Vec<String>,
    /// The bridge's SROS2 enclave (DDS Security), the directory `isochron keystore
    /// bridge` makes: `identity_ca.cert.pem`, `cert.pem`, `key.pem`,
    /// `permissions_ca.cert.pem`, `governance.p7s`, `permissions.p7s`. With it only
    /// participants with a certificate of the site's keystore and permissions for
    /// the topic (robots: `isochron keystore robot`) read the grids or call the
    /// planning services, and none can publish on the bridge's topics or answer
    /// its services. Default none: the robots' topics and services are open to
    /// every participant on the network `dds_interfaces` reaches.
    pub security_dir: Option<String>,
    /// Weight of in-place activity S1 in the cost. Default 1.
    pub weight_in_place: f64,
    /// Weight of moving activity S2 in the cost. Default 1.
    pub weight_moving: f64,
    /// Weight of the long-term mean M(t*) at the current t* in the cost. Default 0.5.
    pub weight_long_term: f64,
    /// The weighted activity (density units) that costs 100. Default 0.2 (on the
    /// PETS demo: a median active cell costs about 10, the busiest 5 % reach 100);
    /// tune per site with `isochron costmap snapshot`.
    pub cost_scale: f64,
    /// Highest cost activity can give a cell, 1 to 100. Default 98: busy areas are
    /// expensive but passable on every Nav2 release — StaticLayer maps 98 to
    /// 98/100·254 = 248 (Humble to Rolling), while 99 is INSCRIBED (253, a
    /// collision for NavFn and Smac) on Rolling and Lyrical since
    /// ros-navigation/navigation2 PR #5781 (`inscribed_obstacle_cost_value`,
    /// default 99) and 100 is LETHAL everywhere (`lethal_cost_threshold`). `cap =
    /// 99` and `cap = 100` (a busy aisle is a wall: the paper's "people cost as much
    /// as walls") are allowed, with a warning at load (docs/nav2.md).
    pub cap: u8,
    /// A person the detector confirmed raises the cells within this radius of their
    /// feet, metres. Default 0.5.
    pub confirm_radius_m: f64,
    /// ... until a later detection that searched where they stood no longer finds
    /// them, or at most this long after the last frame they were detected in
    /// (capture time), seconds: a safety expiry for when the gate's re-checks
    /// (`gate.recheck_s`) stop coming. Default 15.
    pub confirm_hold_s: f64,
    /// ... to at least this cost, 0 to 100 (99 and 100 are obstacles in Nav2, as
    /// for `cap`: warned at load). Default: `cap` (98).
    pub confirm_cost: Option<u8>,
    /// A block of the presence band (something that entered and stays there,
    /// moving or not; `[presence]`) raises its cells to at least this cost, 0 to
    /// 100 (99 and 100 are obstacles in Nav2, as for `cap`: warned at load).
    /// Default: `confirm_cost`.
    pub presence_cost: Option<u8>,
    /// Publish -1 (unknown) where no camera sees. Default true: right for every
    /// costmap of `config/nav2-activity-layer.yaml` on every Nav2 release — the
    /// global costmap (`track_unknown_space: true`) reads -1 as NO_INFORMATION,
    /// which `use_maximum` skips; the local costmap (`track_unknown_space: false`,
    /// Nav2's default there) reads it as FREE_SPACE, which `max()` leaves below
    /// the obstacles. `false` publishes 0 there instead: only for a rolling costmap
    /// that tracks unknown space, whose StaticLayer on Humble to Lyrical writes
    /// `max(cost, master)` with unknown = 255 and so would wipe the obstacles
    /// wherever no camera sees (docs/nav2.md).
    pub publish_unknown: bool,
    /// A camera whose activity stopped arriving this long ago (wall clock) no
    /// longer counts as seeing: its cells turn unknown (-1), seconds. Default 10.
    pub stale_s: f64,
    /// Directory for snapshots (PGM + YAML + PNG), relative to this file. Default
    /// `<site.state_dir>/costmap`.
    pub snapshot_dir: Option<PathBuf>,
    /// Also write a snapshot this often, seconds; 0: only on request
    /// (`isochron costmap snapshot`). Default 0.
    pub snapshot_every_s: f64,
    /// Snapshots kept in `snapshot_dir`; older ones are deleted. Default 100.
    pub snapshot_keep: usize,
    /// Planning: weight of the long-term cost Cost1(t* = now) in Cost2. Default 1.
    pub w1: f64,
    /// Planning: weight of the short-term cost Σ Cost(M_p(now)) in Cost2. Default 1.
    pub w2: f64,
    /// Planning: a segment whose long-term activity never exceeded this at any t*
    /// has M'_p = 0 (people never go there) and makes every route through it
    /// infinitely expensive. Default 0 (the paper: any activity at all).
    pub min_activity: f64,
    /// The robots' route graph: a nav2_route GeoJSON file (relative to this file)
    /// whose nodes are in `frame_id`. isochron scores each edge from the cost map
    /// and the long-term model, closes and reopens edges people block, and plans
    /// over the graph across departure times. Default: none.
    pub route_graph: Option<PathBuf>,
    /// Width of an edge's corridor on the grid, metres: the cells whose centre is
    /// within half of it of the edge's line are the edge's (an edge's
    /// `metadata.width_m` wins). Default 1.2.
    pub route_edge_width_m: f64,
    /// The edges are scored and their changes sent to the route server this often,
    /// seconds. Default 1.
    pub route_update_s: f64,
    /// An edge whose corridor the presence band (cells at or above
    /// `presence_cost`) spans from side to side somewhere is closed once it has
    /// been so for this long, and reopened once it has been clear as long,
    /// seconds. Default 5.
    pub route_close_after_s: f64,
    /// An edge's cost is sent again once it moved by at least this much since it
    /// was last sent, on the edge cost scale (Cost2 of the edge: 0 to
    /// `(w1 + w2) · cap`, 0 to 196 with the defaults). Default 1.
    pub route_cost_epsilon: f64,
    /// The nav2_route route server's node name (with its namespace, if any): its
    /// edges are adjusted through `<route_server>/<route_scorer>/adjust_edges`
    /// (`nav2_msgs/srv/DynamicEdges`). Default `"route_server"`.
    pub route_server: String,
    /// The name of the route server's `nav2_route::DynamicEdgesScorer` plugin (an
    /// entry of its `edge_cost_functions`). Default `"DynamicEdgesScorer"`.
    pub route_scorer: String,
    /// The robots' speed along the graph, metres per second: planning across
    /// departure times takes an edge's cost at the time the robot reaches it, the
    /// length of the way there over this speed. Default 0.5.
    pub route_speed_mps: f64,
    /// Path segments (`[[costmap.segment]]`).
    #[serde(rename = "segment")]
    pub segments: Vec<SegmentConfig>,
    /// Routes (`[[costmap.route]]`).
    #[serde(rename = "route")]
    pub routes: Vec<RouteConfig>,
    /// `[costmap.zenoh]`: the same topics and services for robots on rmw_zenoh.
    pub zenoh: ZenohConfig,
}

impl Default for CostmapConfig {
    fn default() -> Self {
        CostmapConfig {
            map_yaml: None,
            resolution_m: None,
            width_cells: None,
            height_cells: None,
            origin_x_m: None,
            origin_y_m: None,
            origin_yaw_rad: None,
            frame_id: "map".into(),
            topic: "/isochron/activity_costmap".into(),
            updates_topic: None,
            people_topic: "/isochron/people".into(),
            markers_topic: "/isochron/markers".into(),
            people_markers_topic: "/isochron/people_markers".into(),
            speed_filter_info_topic: "/isochron/speed_filter_info".into(),
            speed_mask_topic: "/isochron/speed_mask".into(),
            forecast_topic: "/isochron/activity_forecast".into(),
            plan_offline_service: "/isochron/plan_offline".into(),
            plan_now_service: "/isochron/plan_now".into(),
            plan_graph_service: "/isochron/plan_graph".into(),
            forecast_ahead_min: 15,
            forecast_every_s: 60.0,
            speed_busy_from_cost: 30,
            speed_crowded_from_cost: 70,
            speed_quiet_percent: 100,
            speed_busy_percent: 50,
            speed_crowded_percent: 25,
            publish_hz: 1.0,
            full_every_s: 10.0,
            ros_domain_id: None,
            dds_interfaces: Vec::new(),
            security_dir: None,
            weight_in_place: 1.0,
            weight_moving: 1.0,
            weight_long_term: 0.5,
            cost_scale: 0.2,
            cap: 98,
            confirm_radius_m: 0.5,
            confirm_hold_s: 15.0,
            confirm_cost: None,
            presence_cost: None,
            publish_unknown: true,
            stale_s: 10.0,
            snapshot_dir: None,
            snapshot_every_s: 0.0,
            snapshot_keep: 100,
            w1: 1.0,
            w2: 1.0,
            min_activity: 0.0,
            route_graph: None,
            route_edge_width_m: 1.2,
            route_update_s: 1.0,
            route_close_after_s: 5.0,
            route_cost_epsilon: 1.0,
            route_server: "route_server".into(),
            route_scorer: "DynamicEdgesScorer".into(),
            route_speed_mps: 0.5,
            segments: Vec::new(),
            routes: Vec::new(),
            zenoh: ZenohConfig::default(),
        }
    }
}

impl CostmapConfig {
    /// True if a grid is configured (`map_yaml` or `width_cells`).
    pub fn has_grid(&self) -> bool {
        self.map_yaml.is_some() || self.width_cells.is_some()
    }

    /// The floor polygons (metres) of the segments that have one, as drawn on maps.
    pub fn segment_polygons(&self) -> Vec<&[[f64; 2]]> {
        self.segments
            .iter()
            .filter_map(|s| s.polygon_m.as_deref())
            .collect()
    }

    /// The updates topic: `updates_topic`, else `<topic>_updates`.
    pub fn updates_topic(&self) -> String {
        self.updates_topic
            .clone()
            .unwrap_or_else(|| format!("{}_updates", self.topic))
    }

    /// The cost a confirmed person gives: `confirm_cost`, else `cap`.
    pub fn confirm_cost(&self) -> u8 {
        self.confirm_cost.unwrap_or(self.cap)
    }

    /// The least cost of a present block's cells: `presence_cost`, else
    /// [`CostmapConfig::confirm_cost`].
    pub fn presence_cost(&self) -> u8 {
        self.presence_cost.unwrap_or_else(|| self.confirm_cost())
    }

    /// The speed mask value of a cell of activity cost `cost` (-1: unseen): the
    /// band's limit in percent, 0 (no limit) for 100 % and unseen cells — Nav2's
    /// SpeedFilter reads 0 as "no limit" and logs an error on -1.
    pub fn speed_mask_value(&self, cost: i8) -> i8 {
        let percent = if cost < 0 {
            100
        } else if cost as u8 >= self.speed_crowded_from_cost {
            self.speed_crowded_percent
        } else if cost as u8 >= self.speed_busy_from_cost {
            self.speed_busy_percent
        } else {
            self.speed_quiet_percent
        };
        if percent >= 100 { 0 } else { percent as i8 }
    }

    /// The segment named `name`.
    pub fn segment(&self, name: &str) -> Option<&SegmentConfig> {
        self.segments.iter().find(|s| s.name == name)
    }

    /// The route named `name`.
    pub fn route(&self, name: &str) -> Option<&RouteConfig> {
        self.routes.iter().find(|r| r.name == name)
    }
}

/// Most cells of a grid: 1 MB per `OccupancyGrid` message.
pub const MAX_GRID_CELLS: u64 = 1 << 20;

impl CostmapConfig {
    /// Checks the `costmap.*` keys, and its segments and routes against `cameras`.
    pub(super) fn validate(&self, cameras: &[CameraConfig]) -> Result<(), Invalid> {
        self.validate_grid()?;
        self.validate_ros()?;
        self.validate_costs()?;
        self.validate_route_graph()?;
        validate_segments(&self.segments, cameras)?;
        validate_routes(&self.routes, &self.segments)?;
        self.zenoh.validate()
    }

    /// The grid: from `map_yaml`, or all of its own keys, or none.
    fn validate_grid(&self) -> Result<(), Invalid> {
        if self.map_yaml.is_some() {
            for (name, given) in [
                ("resolution_m", self.resolution_m.is_some()),
                ("width_cells", self.width_cells.is_some()),
                ("height_cells", self.height_cells.is_some()),
                ("origin_x_m", self.origin_x_m.is_some()),
                ("origin_y_m", self.origin_y_m.is_some()),
                ("origin_yaw_rad", self.origin_yaw_rad.is_some()),
            ] {
                if given {
                    return Err(Invalid::new(
                        format!("costmap.{name}"),
                        "the grid comes from costmap.map_yaml: set either map_yaml or the grid keys, not both",
                    ));
                }
            }
        } else if self.width_cells.is_some() || self.height_cells.is_some() {
            let key = if self.width_cells.is_none() {
                "costmap.width_cells"
            } else {
                "costmap.height_cells"
            };
            let (w, h) = (
                self.width_cells.unwrap_or(0),
                self.height_cells.unwrap_or(0),
            );
            if self.width_cells.is_none() || self.height_cells.is_none() {
                return Err(Invalid::new(
                    key,
                    "expected both width_cells and height_cells",
                ));
            }
            check_range("costmap.width_cells", w as f64, 1.0, 10_000.0)?;
            check_range("costmap.height_cells", h as f64, 1.0, 10_000.0)?;
            if w as u64 * h as u64 > MAX_GRID_CELLS {
                return Err(Invalid::new(
                    "costmap.width_cells",
                    format!(
                        "a {w}x{h} grid has {} cells; at most {MAX_GRID_CELLS} (1 MB per grid message) are allowed: use a coarser resolution_m or a smaller area",
                        w as u64 * h as u64
                    ),
                ));
            }
        } else if self.resolution_m.is_some()
            || self.origin_x_m.is_some()
            || self.origin_y_m.is_some()
        {
            return Err(Invalid::new(
                "costmap.width_cells",
                "expected width_cells and height_cells with the other grid keys (or map_yaml)",
            ));
        }
        if let Some(r) = self.resolution_m {
            check_range("costmap.resolution_m", r, 0.001, 100.0)?;
        }
        for (name, v) in [
            ("origin_x_m", self.origin_x_m),
            ("origin_y_m", self.origin_y_m),
            ("origin_yaw_rad", self.origin_yaw_rad),
        ] {
            if let Some(v) = v {
                check_range(&format!("costmap.{name}"), v, -1e6, 1e6)?;
            }
        }
        Ok(())
    }

    /// The frame, the topics and services, the publish rate, DDS.
    fn validate_ros(&self) -> Result<(), Invalid> {
        if self.frame_id.trim().is_empty() {
            return Err(Invalid::new(
                "costmap.frame_id",
                "expected a frame name such as \"map\"",
            ));
        }
        for (key, topic) in [
            ("costmap.topic", Some(&self.topic)),
            ("costmap.updates_topic", self.updates_topic.as_ref()),
            ("costmap.people_topic", Some(&self.people_topic)),
            ("costmap.markers_topic", Some(&self.markers_topic)),
            (
                "costmap.people_markers_topic",
                Some(&self.people_markers_topic),
            ),
            (
                "costmap.speed_filter_info_topic",
                Some(&self.speed_filter_info_topic),
            ),
            ("costmap.speed_mask_topic", Some(&self.speed_mask_topic)),
            ("costmap.forecast_topic", Some(&self.forecast_topic)),
            (
                "costmap.plan_offline_service",
                Some(&self.plan_offline_service),
            ),
            ("costmap.plan_now_service", Some(&self.plan_now_service)),
            ("costmap.plan_graph_service", Some(&self.plan_graph_service)),
        ] {
            if let Some(topic) = topic
                && !is_valid_ros_topic(topic)
            {
                return Err(Invalid::found(
                    key,
                    "a ROS 2 topic name such as \"/isochron/activity_costmap\" (letters, digits, '_', '/')",
                    topic,
                ));
            }
        }
        check_range("costmap.publish_hz", self.publish_hz, 0.01, 100.0)?;
        check_range("costmap.full_every_s", self.full_every_s, 0.0, 86_400.0)?;
        check_dds(
            "costmap",
            self.ros_domain_id,
            &self.dds_interfaces,
            "127.0.0.1",
        )?;
        if self
            .security_dir
            .as_deref()
            .is_some_and(|d| d.trim().is_empty())
        {
            return Err(Invalid::new(
                "costmap.security_dir",
                "expected the directory of the bridge's enclave (isochron keystore bridge)",
            ));
        }
        Ok(())
    }

    /// Weights, costs, the speed filter, the forecast, staleness and snapshots.
    fn validate_costs(&self) -> Result<(), Invalid> {
        for (name, v) in [
            ("weight_in_place", self.weight_in_place),
            ("weight_moving", self.weight_moving),
            ("weight_long_term", self.weight_long_term),
            ("w1", self.w1),
            ("w2", self.w2),
            ("min_activity", self.min_activity),
        ] {
            check_range(&format!("costmap.{name}"), v, 0.0, 1e6)?;
        }
        check_positive("costmap.cost_scale", self.cost_scale)?;
        check_range("costmap.cap", self.cap as f64, 1.0, 100.0)?;
        check_range(
            "costmap.confirm_radius_m",
            self.confirm_radius_m,
            0.0,
            100.0,
        )?;
        check_range("costmap.confirm_hold_s", self.confirm_hold_s, 0.0, 3600.0)?;
        if let Some(v) = self.confirm_cost {
            check_range("costmap.confirm_cost", v as f64, 0.0, 100.0)?;
        }
        if let Some(v) = self.presence_cost {
            check_range("costmap.presence_cost", v as f64, 0.0, 100.0)?;
        }
        check_range(
            "costmap.speed_busy_from_cost",
            self.speed_busy_from_cost as f64,
            1.0,
            100.0,
        )?;
        check_range(
            "costmap.speed_crowded_from_cost",
            self.speed_crowded_from_cost as f64,
            self.speed_busy_from_cost as f64,
            100.0,
        )?;
        for (name, v) in [
            ("speed_quiet_percent", self.speed_quiet_percent),
            ("speed_busy_percent", self.speed_busy_percent),
            ("speed_crowded_percent", self.speed_crowded_percent),
        ] {
            check_range(&format!("costmap.{name}"), v as f64, 1.0, 100.0)?;
        }
        check_range(
            "costmap.forecast_ahead_min",
            self.forecast_ahead_min as f64,
            1.0,
            1440.0,
        )?;
        check_range(
            "costmap.forecast_every_s",
            self.forecast_every_s,
            1.0,
            86_400.0,
        )?;
        check_positive("costmap.stale_s", self.stale_s)?;
        check_range("costmap.snapshot_every_s", self.snapshot_every_s, 0.0, 1e7)?;
        check_range("costmap.snapshot_keep", self.snapshot_keep as f64, 1.0, 1e6)?;
        Ok(())
    }

    /// The route graph: its file, corridor width, timings, the route server's
    /// names and the robots' speed.
    fn validate_route_graph(&self) -> Result<(), Invalid> {
        if self
            .route_graph
            .as_ref()
            .is_some_and(|p| p.as_os_str().is_empty())
        {
            return Err(Invalid::new(
                "costmap.route_graph",
                "expected the path of a nav2_route GeoJSON graph",
            ));
        }
        check_range(
            "costmap.route_edge_width_m",
            self.route_edge_width_m,
            0.05,
            50.0,
        )?;
        check_range("costmap.route_update_s", self.route_update_s, 0.1, 3600.0)?;
        check_range(
            "costmap.route_close_after_s",
            self.route_close_after_s,
            0.0,
            3600.0,
        )?;
        check_range(
            "costmap.route_cost_epsilon",
            self.route_cost_epsilon,
            0.0,
            1000.0,
        )?;
        if !is_valid_ros_topic(&self.route_server) {
            return Err(Invalid::found(
                "costmap.route_server",
                "a ROS 2 node name such as \"route_server\" or \"/robot1/route_server\" (letters, digits, '_', '/')",
                &self.route_server,
            ));
        }
        if self.route_scorer.contains('/') || !is_valid_ros_topic(&self.route_scorer) {
            return Err(Invalid::found(
                "costmap.route_scorer",
                "the name of a DynamicEdgesScorer plugin such as \"DynamicEdgesScorer\" (letters, digits, '_')",
                &self.route_scorer,
            ));
        }
        check_range("costmap.route_speed_mps", self.route_speed_mps, 0.01, 10.0)?;
        Ok(())
    }

    /// The route server's service that adjusts, closes and reopens edges:
    /// `<route_server>/<route_scorer>/adjust_edges`.
    pub fn route_adjust_edges_service(&self) -> String {
        format!(
            "{}/{}/adjust_edges",
            self.route_server.trim_end_matches('/'),
            self.route_scorer
        )
    }
}

impl CostmapConfig {
    /// Settings that are valid but probably not what a site wants on Nav2 robots,
    /// as (key, why): logged at load by the cost map bridge.
    pub fn warnings(&self) -> Vec<Invalid> {
        let mut out = Vec::new();
        for (key, value, what) in [
            ("costmap.cap", Some(self.cap), "busy cells"),
            (
                "costmap.confirm_cost",
                self.confirm_cost,
                "the cells around a confirmed person",
            ),
        ] {
            match value {
                Some(100..) => out.push(Invalid::new(
                    key,
                    format!("100 makes {what} lethal in Nav2 (StaticLayer maps 100 to LETHAL_OBSTACLE on every release): a robot with no other way is stuck; use 98 or less unless people must block the way"),
                )),
                Some(99) => out.push(Invalid::new(
                    key,
                    format!("99 makes {what} an obstacle on Nav2 Rolling and Lyrical (StaticLayer maps 99, inscribed_obstacle_cost_value, to INSCRIBED 253 since navigation2 PR #5781; 251 on Humble to Kilted); use 98 or less for a cost every release passes"),
                )),
                _ => {}
            }
        }
        if self.origin_yaw_rad.is_some_and(|y| y != 0.0) {
            out.push(Invalid::new(
                "costmap.origin_yaw_rad",
                "Nav2 ignores a map origin's yaw: its costmaps place the grid unrotated, so activity lands in the wrong place; rotate the map frame instead (a static transform) and set 0",
            ));
        }
        out
    }
}
