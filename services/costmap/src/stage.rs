//! The cost-map stage: `activity` and `detections` of every camera in, the ROS 2
//! `OccupancyGrid` (+ updates) out, snapshots, and `<prefix>/plan` answered — run
//! by the stage runtime ([`isochron_runtime::stage`]). Runs once per site.

use std::net::IpAddr;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use isochron_config::LoadedConfig;
use isochron_config::clock::{NS_PER_S, SiteClock, wall_now_ns};
use isochron_dds::{domain_id, limit_dds_logging};
use isochron_exit::{self as exit, Fatal};
use isochron_planning::grid::MapGrid;
use isochron_planning::plan_service::PlanServer;
use isochron_planning::planner::Planner;
use isochron_planning::route_graph::RouteGraph;
use isochron_planning::snapshot;
use isochron_ros2::msgs::{CostmapFilterInfo, Header, RosDuration, Time};
use isochron_ros2::spec::{GRID, Names, SPEED_MASK, UPDATES};
use isochron_ros2::{RosOutput, RosSettings, interfaces};
use isochron_runtime::counters::{Counters as StatusCounters, costmap};
use isochron_runtime::ipc::{Activity, Detections, Ipc};
use isochron_runtime::stage::{Context, Input, Notified, Stage};
use isochron_runtime::topology::StageKind;

use crate::bridge::{Bridge, count_non_finite};
use crate::delta::DeltaTracker;
use crate::markers::{marker_key, site_markers};
use crate::planning::Planning;
use crate::publish::{
    Counters, Ros, geometry_key, occupancy_grid, publish, publish_people, unknown_as_free,
};
use crate::route_feed::{self, RouteFeed, Sight};

/// How long a read long-term model is trusted before the store is checked again.
const STORE_REFRESH: Duration = Duration::from_secs(60);
/// The longest a ROS 2 planning request waits for the loop's next pass: DDS
/// wakes no pass, so with the services on the loop ticks at least this often
/// (a flood of 1 000 requests a second is then 100 a pass, well within the
/// reader's history).
const PLAN_TICK: Duration = Duration::from_millis(100);

/// The cost-map stage's inputs: every camera's activity, every camera's
/// detections, and planning requests.
pub type CostmapInputs = (
    Vec<Input<Activity>>,
    Vec<Input<Detections>>,
    Notified<PlanServer>,
);

/// The site's cost map: the bridge from blocks to floor cells, the ROS 2 output,
/// the planner, snapshots.
pub struct CostmapStage {
    bridge: Bridge,
    planning: Planning,
    ros: Option<Ros>,
    counters: Counters,
    period: Duration,
    snapshot_every: Option<Duration>,
    next_publish: Instant,
    next_snapshot: Option<Instant>,
    newest_arrival: Option<(Instant, i64)>,
    /// The route server fed live (a route graph and ROS 2).
    route_feed: Option<RouteFeed>,
}

impl CostmapStage {
    /// The cost map of `loaded`'s site and its inputs (every configured camera).
    pub fn open(ipc: &Ipc, loaded: &LoadedConfig) -> Result<(Self, CostmapInputs), Fatal> {
        let config = &loaded.config;
        let c = &config.costmap;
        let config_error =
            |e: String| Fatal::new(exit::CONFIG, format!("{}: {e}", loaded.path.display()));

        for warning in loaded.warnings() {
            tracing::warn!("{warning}");
        }
        let grid = MapGrid::from_config(loaded).map_err(|e| config_error(e.to_string()))?;
        if let Some(warning) = grid.as_ref().and_then(|g| nav2_geometry_warning(loaded, g)) {
            tracing::warn!("{warning}");
        }
        let bridge =
            Bridge::new(loaded, grid).map_err(|e| Fatal::from(e).context(loaded.path.display()))?;
        let mut planner = Planner::new(loaded).map_err(|e| config_error(e.to_string()))?;
        planner.refresh_every = STORE_REFRESH;
        let clock = SiteClock::new(&config.site.time_zone, config.cascade.cycle)
            .map_err(|e| config_error(format!("site.time_zone: {e}")))?;
        for cam in &bridge.cameras {
            match &cam.homography {
                Some(_) => {
                    tracing::info!(camera = %cam.id, "floor mapping fitted, RMS error {:.3} m at its points", cam.homography_rms_m)
                }
                None => {
                    tracing::info!(camera = %cam.id, "no floor_points: the camera is not on the cost map")
                }
            }
        }
        let floor_plan = snapshot::floor_plan_of(loaded, bridge.grid.as_ref());
        let route_graph =
            RouteGraph::from_config(loaded).map_err(|e| config_error(e.to_string()))?;
        let snapshot_dir = c
            .snapshot_dir
            .as_ref()
            .map(|d| {
                if d.is_absolute() {
                    d.clone()
                } else {
                    loaded.base_dir().join(d)
                }
            })
            .unwrap_or_else(|| loaded.state_dir().join("costmap"));

        let ros = match &bridge.grid {
            Some(grid) => Some(ros_output(loaded, grid, route_graph.is_some())?),
            None => {
                tracing::warn!(
                    "no [costmap] grid (map_yaml or width_cells/height_cells): nothing is published to ROS 2; planning only"
                );
                None
            }
        };

        let mut activity = Vec::new();
        let mut detections = Vec::new();
        for cam in &config.cameras {
            activity.push(Input::open(ipc, &cam.id)?);
            detections.push(Input::open(ipc, &cam.id)?);
        }
        let inputs = (activity, detections, Notified(PlanServer::new(ipc)?));
        let snapshot_every = (c.snapshot_every_s > 0.0)
            .then(|| isochron_config::clock::saturating_secs(c.snapshot_every_s));
        let now = Instant::now();
        let route_feed = match (&route_graph, &ros) {
            (Some(graph), Some(_)) => Some(RouteFeed::new(graph.clone(), c, now)),
            _ => None,
        };
        let stage = CostmapStage {
            bridge,
            planning: Planning {
                loaded: loaded.clone(),
                planner,
                clock,
                floor_plan,
                snapshot_dir,
                route_graph,
            },
            ros,
            counters: Counters::default(),
            period: isochron_config::clock::saturating_secs(1.0 / c.publish_hz),
            snapshot_every,
            next_publish: now,
            next_snapshot: snapshot_every.map(|e| now + e),
            newest_arrival: None,
            route_feed,
        };
        Ok((stage, inputs))
    }
}

impl CostmapStage {
    /// Publishes the speed mask if it changed, and the grid (full or an update).
    fn publish_grid(&mut self, cx: &mut Context, now: Instant) {
        if let (Some(ros), Some(grid)) = (&mut self.ros, &self.bridge.grid)
            && let Some(mut cells) = self.bridge.compose(now)
        {
            let stamp_ns = self.bridge.newest(now).map_or_else(wall_now_ns, |(t, _)| t);
            let c = &self.planning.loaded.config.costmap;
            let mask: Vec<i8> = cells.iter().map(|&v| c.speed_mask_value(v)).collect();
            if ros.mask_sent.as_ref() != Some(&mask) {
                let message = occupancy_grid(grid, &ros.frame_id, stamp_ns, mask.clone());
                let result = ros.output.speed_mask.publish(message);
                if self
                    .counters
                    .published("the speed mask", result, |c| &mut c.masks)
                {
                    ros.mask_sent = Some(mask);
                }
            }
            if !ros.publish_unknown {
                unknown_as_free(&mut cells);
            }
            if publish(ros, grid, &cells, stamp_ns, now, &mut self.counters) {
                let (arrived, origin) =
                    self.newest_arrival.map_or((None, 0), |(a, o)| (Some(a), o));
                cx.health.sent(arrived, origin);
            }
        }
    }

    /// Publishes the forecast when it is due: the cost map the long-term model
    /// expects `costmap.forecast_ahead_min` from now.
    fn publish_forecast(&mut self, cx: &mut Context, now: Instant) {
        if let (Some(ros), Some(grid)) = (&mut self.ros, &self.bridge.grid)
            && now >= ros.next_forecast
        {
            let c = &self.planning.loaded.config.costmap;
            ros.next_forecast = now + isochron_config::clock::saturating_secs(c.forecast_every_s);
            let now_ns = self.bridge.newest(now).map_or_else(wall_now_ns, |(t, _)| t);
            let t_star = self
                .bridge
                .newest(now)
                .map_or_else(|| self.planning.clock.t_star(now_ns), |(_, t)| t);
            let ahead = (t_star + c.forecast_ahead_min) % self.planning.planner.cycle().bins();
            let expected =
                self.planning
                    .planner
                    .expected_costmap(grid, ahead, &mut ros.forecast_footprints);
            match expected {
                Ok(cells) => {
                    let at_ns = now_ns + c.forecast_ahead_min as i64 * 60 * NS_PER_S;
                    let message = occupancy_grid(grid, &ros.frame_id, at_ns, cells);
                    let result = ros.output.forecast.publish(message);
                    self.counters
                        .published("the forecast", result, |c| &mut c.forecasts);
                }
                Err(e) => cx.warnings.warn("forecast", || {
                    format!("no forecast: the long-term store cannot be read: {e}")
                }),
            }
        }
    }

    /// Publishes the site's markers when what they show changed.
    fn publish_markers(&mut self) {
        if let Some(ros) = &mut self.ros {
            let key = marker_key(&self.planning.loaded, &self.bridge);
            if ros.markers_sent.as_ref() != Some(&key) {
                let header = Header {
                    stamp: Time::from_utc_ns(wall_now_ns()),
                    frame_id: ros.frame_id.clone(),
                };
                let markers = site_markers(&self.planning.loaded, &self.bridge, &header);
                let result = ros.output.markers.publish(markers);
                if self
                    .counters
                    .published("the markers", result, |c| &mut c.markers)
                {
                    ros.markers_sent = Some(key);
                }
            }
        }
    }

    /// Tells the route server what changed on the graph's edges, when due.
    fn feed_route(&mut self, cx: &mut Context, now: Instant) {
        let (Some(feed), Some(ros), Some(grid)) =
            (&mut self.route_feed, &mut self.ros, &self.bridge.grid)
        else {
            return;
        };
        let bridge = &self.bridge;
        let footprints: Vec<_> = bridge
            .cameras
            .iter()
            .map(|c| c.footprint.as_ref())
            .collect();
        let now_ns = wall_now_ns();
        let t_star = bridge
            .newest(now)
            .map_or_else(|| self.planning.clock.t_star(now_ns), |(_, t)| t);
        let warning = feed.tick(
            &mut ros.output.route_links,
            &Sight {
                grid,
                footprints: &footprints,
            },
            &mut self.planning.planner,
            || bridge.compose(now),
            t_star,
            now,
        );
        if let Some(warning) = warning {
            cx.warnings.warn("route", || warning);
        }
    }

    /// Answers the planning requests that came over ROS 2.
    fn serve_ros_plans(&mut self, cx: &mut Context) {
        let Some(ros) = &mut self.ros else {
            return;
        };
        let served = ros.output.serve_plans(cx, |kind, request| {
            self.planning
                .answer(kind, request, &self.bridge, &mut self.counters.snapshots)
        });
        self.counters.plans += served as u64;
    }
}

impl Stage for CostmapStage {
    type Inputs = CostmapInputs;
    const KIND: StageKind = StageKind::Costmap;

    fn on_wake(
        &mut self,
        (activity, detections, plans): &CostmapInputs,
        cx: &mut Context,
    ) -> Result<(), Fatal> {
        for (k, input) in activity.iter().enumerate() {
            while let Some(sample) = input.next(cx) {
                let arrived = Instant::now();
                let h = *sample.header();
                if h.preamble.is_end_of_stream() {
                    continue;
                }
                if let Err(e) = self.bridge.admit(k, &h) {
                    cx.health.rejected();
                    let camera = &self.bridge.cameras[k].id;
                    cx.warnings
                        .warn("grid", || format!("rejected {camera}'s activity: {e}"));
                    continue;
                }
                let bad = self.bridge.on_activity(k, &h, sample.payload(), arrived);
                count_non_finite(cx, &self.bridge, k, "activity blocks", bad);
                self.newest_arrival = Some((arrived, h.preamble.origin_wall_ns));
            }
        }
        for (k, input) in detections.iter().enumerate() {
            while let Some(sample) = input.next(cx) {
                let h = *sample.header();
                if !h.preamble.is_end_of_stream() {
                    let (placed, bad) = self.bridge.on_detections(k, &h, sample.payload());
                    self.counters.confirmed += placed as u64;
                    if let Some(ros) = &mut self.ros {
                        publish_people(
                            ros,
                            &self.bridge,
                            k,
                            placed,
                            h.preamble.capture_time_ns,
                            &mut self.counters,
                        );
                    }
                    count_non_finite(cx, &self.bridge, k, "detection boxes", bad);
                }
            }
        }
        let mut rejected = 0;
        let served = plans.0.serve(
            |kind, request| {
                self.planning
                    .answer(kind, request, &self.bridge, &mut self.counters.snapshots)
            },
            &mut rejected,
        )?;
        self.counters.plans += served as u64;
        self.serve_ros_plans(cx);
        for _ in 0..rejected {
            cx.health.rejected();
        }
        Ok(())
    }

    fn on_tick(&mut self, cx: &mut Context) -> Result<(), Fatal> {
        self.serve_ros_plans(cx);
        let now = Instant::now();
        if now >= self.next_publish {
            self.next_publish += self.period;
            if self.next_publish < now {
                // Fell behind (a slow plan, a stalled DDS write): do not burst.
                self.next_publish = now + self.period;
            }
            self.publish_grid(cx, now);
        }
        self.publish_forecast(cx, now);
        self.publish_markers();
        self.feed_route(cx, now);
        if let Some(at) = self.next_snapshot
            && now >= at
        {
            self.next_snapshot = self.snapshot_every.map(|e| now + e);
            match self.planning.write_snapshot(&self.bridge, now) {
                Ok(path) => {
                    self.counters.snapshots += 1;
                    tracing::debug!("snapshot {path}");
                }
                Err(e) => tracing::warn!("periodic snapshot failed: {e}"),
            }
        }
        Ok(())
    }

    /// The publish period, so that the grid goes out on time; at most
    /// [`PLAN_TICK`] while the ROS 2 planning services are on.
    fn timer(&self) -> Duration {
        match self.ros {
            Some(_) => self.period.min(PLAN_TICK),
            None => self.period,
        }
    }

    fn counters(&self, c: &mut StatusCounters) {
        let now = Instant::now();
        let bridge = &self.bridge;
        let live = (0..bridge.cameras.len())
            .filter(|&k| bridge.is_live(k, now))
            .count();
        let plans = self
            .ros
            .as_ref()
            .map(|r| r.output.plan_counts())
            .unwrap_or_default();
        let n = &self.counters;
        c.set(costmap::CAMERAS_LIVE, live);
        c.set(costmap::CAMERAS, bridge.cameras.len());
        c.set(costmap::GRIDS, n.grids);
        c.set(costmap::UPDATES, n.updates);
        let subscribers = self.ros.as_ref().map_or(0, |r| r.output.grid_subscribers());
        c.set(costmap::ROS_SUBSCRIBERS, subscribers as u64);
        c.set(costmap::PUBLISH_ERRORS, n.publish_errors);
        c.set(costmap::PLANS, n.plans);
        c.set(costmap::PLANS_REJECTED, plans.rejected);
        c.set(costmap::PLANS_DROPPED, plans.dropped);
        c.set(costmap::SNAPSHOTS, n.snapshots);
        c.set(costmap::CONFIRMED, n.confirmed);
        c.set(costmap::PEOPLE_MSGS, n.people);
        c.set(costmap::MARKERS, n.markers);
        c.set(costmap::PEOPLE_MARKERS, n.people_markers);
        c.set(costmap::SPEED_MASKS, n.masks);
        c.set(costmap::FORECASTS, n.forecasts);
        let route = self
            .ros
            .as_ref()
            .map(|r| route_feed::total(&r.output.route_links))
            .unwrap_or_default();
        c.set(costmap::ROUTE_CALLS, route.calls);
        c.set(costmap::ROUTE_FAILURES, route.failures);
        c.set(costmap::ROUTE_EDGES, route.edges);
        let closed = self.route_feed.as_ref().map_or(0, RouteFeed::closed);
        c.set(costmap::ROUTE_CLOSED, closed);
        c.set(costmap::ROUTE_LATENCY, route.latency_ms.unwrap_or(0.0));
        c.set(costmap::ROUTE_SERVER_UP, u64::from(route.up));
    }
}

/// The ROS 2 output of the cost map on `grid`: the participant, its topics and
/// services, the speed filter's info (sent once, latched).
fn ros_output(loaded: &LoadedConfig, grid: &MapGrid, route_server: bool) -> Result<Ros, Fatal> {
    let c = &loaded.config.costmap;
    let domain =
        domain_id(c.ros_domain_id).map_err(|e| Fatal::from(e).context(loaded.path.display()))?;
    let settings = RosSettings {
        domain_id: domain,
        interfaces: interfaces(
            &c.dds_interfaces
                .iter()
                .filter_map(|a| a.parse().ok())
                .collect::<Vec<_>>(),
        ),
        names: Names::from_config(c),
        enclave: None,
        zenoh: c.zenoh.enabled.then(|| isochron_zenoh::Settings {
            domain,
            mode: if c.zenoh.mode == "client" {
                isochron_zenoh::Mode::Client
            } else {
                isochron_zenoh::Mode::Peer
            },
            connect: c.zenoh.connect.clone(),
            listen: c.zenoh.listen.clone(),
            config_file: c
                .zenoh
                .config_file
                .as_ref()
                .map(|p| loaded.base_dir().join(p)),
        }),
        route_server,
    };
    let settings = RosSettings {
        enclave: enclave(loaded, &settings.interfaces)?,
        ..settings
    };
    limit_dds_logging();
    let output = RosOutput::start(&settings)?;
    // The speed filter's info never changes: sent once, latched.
    if let Err(e) = output.speed_filter_info.publish(CostmapFilterInfo {
        header: Header {
            stamp: Time::from_utc_ns(wall_now_ns()),
            frame_id: c.frame_id.clone(),
        },
        kind: CostmapFilterInfo::SPEED_LIMIT_PERCENT,
        filter_mask_topic: settings.names.of(&SPEED_MASK.config).to_string(),
        base: 0.0,
        multiplier: 1.0,
    }) {
        tracing::warn!("publishing the speed filter info failed: {e}");
    }
    tracing::info!(
        "publishing a {}x{} grid of {} m on {} (+ {}), frame '{}', ROS domain {}, {}",
        grid.width,
        grid.height,
        grid.resolution,
        settings.names.of(&GRID.config),
        settings.names.of(&UPDATES.config),
        c.frame_id,
        settings.domain_id,
        if settings.interfaces.is_empty() {
            "all interfaces".to_string()
        } else {
            format!("interfaces {:?}", settings.interfaces)
        }
    );
    Ok(Ros {
        output,
        tracker: DeltaTracker::new(isochron_config::clock::saturating_secs(c.full_every_s)),
        geometry: geometry_key(grid),
        frame_id: c.frame_id.clone(),
        publish_unknown: c.publish_unknown,
        markers_sent: None,
        people_markers_sent: Vec::new(),
        people_lifetime: RosDuration::from_secs_f64(c.confirm_hold_s),
        mask_sent: None,
        next_forecast: Instant::now(),
        forecast_footprints: Vec::new(),
    })
}

/// The bridge's SROS2 enclave (`costmap.security_dir`, relative to the config
/// file), checked to hold its files. Says at start whether the robots' side is
/// secured: without an enclave its topics and services are open to every
/// participant the `interfaces` reach (a warning unless they are all loopback).
fn enclave(loaded: &LoadedConfig, interfaces: &[IpAddr]) -> Result<Option<PathBuf>, Fatal> {
    let Some(dir) = &loaded.config.costmap.security_dir else {
        let local = !interfaces.is_empty() && interfaces.iter().all(IpAddr::is_loopback);
        let line = format!(
            "DDS Security off: the robots' topics and planning services are open (unauthenticated) \
             on {}: any participant there can read the grids, publish on their topics and answer \
             plan requests. Set costmap.security_dir to the bridge's enclave (`isochron keystore \
             bridge`) to secure them",
            if local { "loopback" } else { "the network" }
        );
        if local {
            tracing::info!("{line}");
        } else {
            tracing::warn!("{line}");
        }
        return Ok(None);
    };
    let dir = loaded.base_dir().join(dir);
    if let Some(problem) =
        isochron_dds::enclave_problem(&dir, "costmap.security_dir", "isochron keystore bridge")
    {
        let line = format!("{}: {problem}", loaded.path.display());
        return Err(Fatal::new(exit::CONFIG, line));
    }
    tracing::info!(
        enclave = %dir.display(),
        "DDS Security on: the robots' topics and planning services are secured (SROS2): only \
         participants of the site's keystore read the grids and call the services, as their \
         permissions allow; no other can publish on the topics or answer the services"
    );
    Ok(Some(dir))
}

/// Why Nav2 may not take the grid as the robots' map, if it may not: a StaticLayer
/// of a global (not rolling) costmap resizes the whole costmap to a map of another
/// size, resolution or origin, and the robots' own map is gone. The grid has the
/// robots' map's geometry only when it comes from their `map_server` YAML
/// (`costmap.map_yaml`), and Nav2 ignores that YAML's origin yaw.
pub fn nav2_geometry_warning(loaded: &LoadedConfig, grid: &MapGrid) -> Option<String> {
    let geometry = |g: &MapGrid| {
        format!(
            "{}x{} cells of {} m from ({}, {})",
            g.width, g.height, g.resolution, g.origin_x, g.origin_y
        )
    };
    match &loaded.config.costmap.map_yaml {
        None => Some(format!(
            "{}: costmap: the grid ({}) is set by width_cells/height_cells, and the robots' map is unknown to the bridge (costmap.map_yaml unset): a Nav2 global costmap whose map has another geometry resizes to this grid and loses the robots' map; set costmap.map_yaml to the robots' map_server YAML (a rolling local costmap alone takes any geometry)",
            loaded.path.display(),
            geometry(grid)
        )),
        Some(yaml) if grid.yaw != 0.0 => Some(format!(
            "{}: costmap.map_yaml {}: the grid ({}, yaw {} rad) is rotated, but Nav2 places a map unrotated ({}, yaw 0), so the activity lands off its cells; rotate the map frame instead (a static transform) and give the map origin yaw 0",
            loaded.path.display(),
            yaml.display(),
            geometry(grid),
            grid.yaw,
            geometry(grid)
        )),
        Some(_) => None,
    }
}
