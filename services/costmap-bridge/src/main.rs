//! isochron-costmap: config → node → `activity` + `detections` of every camera in,
//! ROS 2 `OccupancyGrid` (+ updates) out, `<prefix>/plan` served → loop.
//! Runs once per site (`isochron up` starts it without `--camera`).

use std::hash::{Hash, Hasher};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use clap::Parser;
use iceoryx2::prelude::*;
use isochron_costmap::bridge::Bridge;
use isochron_costmap::delta::{DeltaTracker, Output};
use isochron_costmap::msgs::{
    Header, MapMetaData, OccupancyGrid, OccupancyGridUpdate, Point, Pose, Quaternion, Time,
};
use isochron_costmap::ros::{RosOutput, RosSettings, domain_id, interfaces, limit_dds_logging};
use isochron_costmap::snapshot::{self, FloorPlan, Snapshot};
use isochron_planning::grid::MapGrid;
use isochron_planning::plan::{DayRange, PlanError};
use isochron_planning::plan_service::{PlanServer, answer_now, answer_offline};
use isochron_planning::planner::Planner;
use isochron_planning::query::{PlanKind, PlanRequest, PlanResponse, PlanStatus};
use isochron_shared::clock::{Cycle, SiteClock, format_rfc3339, timestamp, wall_now_ns};
use isochron_shared::config::LoadedConfig;
use isochron_shared::health::{Health, exit, notify_ready};
use isochron_shared::ipc::{Activity, Detections, IpcError, stop_requested_by};
use isochron_shared::service::{Fatal, ServiceContext, finish, start};

/// The longest the loop sleeps: plan requests from clients that do not notify are
/// answered within this, and the watchdog is fed.
const MAX_WAIT: Duration = Duration::from_millis(250);
/// How long a read long-term model is trusted before the store is checked again.
const STORE_REFRESH: Duration = Duration::from_secs(60);

/// Publishes block activity on the robots' map as a ROS 2 OccupancyGrid, writes
/// snapshots, and answers planning requests.
#[derive(Parser)]
#[command(version)]
struct Args {
    /// Site configuration file.
    #[arg(long)]
    config: PathBuf,
}

fn main() -> ExitCode {
    let args = Args::parse();
    let result = start("costmap", &args.config, None).and_then(run);
    finish("costmap", result)
}

/// Counters for the status line.
#[derive(Default)]
struct Counters {
    grids: u64,
    updates: u64,
    publish_errors: u64,
    plans: u64,
    snapshots: u64,
    confirmed: u64,
}

/// The ROS 2 side: the output and what was sent.
struct Ros {
    output: RosOutput,
    tracker: DeltaTracker,
    geometry: u64,
    frame_id: String,
}

fn run(ctx: ServiceContext) -> Result<(), Fatal> {
    let loaded = &ctx.config;
    let config = &loaded.config;
    let c = &config.costmap;
    let config_error =
        |e: String| Fatal::new(exit::CONFIG, format!("{}: {e}", loaded.path.display()));
    let unavailable = |e: IpcError| Fatal::new(exit::UNAVAILABLE, e.to_string());

    let grid = MapGrid::from_config(loaded).map_err(|e| config_error(e.to_string()))?;
    let mut bridge = Bridge::new(loaded, grid).map_err(config_error)?;
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
    let floor_plan = load_floor_plan(loaded, bridge.grid.as_ref());
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

    let mut ros = match &bridge.grid {
        Some(grid) => {
            let settings = RosSettings {
                domain_id: domain_id(c.ros_domain_id).map_err(config_error)?,
                interfaces: interfaces(
                    &c.dds_interfaces
                        .iter()
                        .filter_map(|a| a.parse().ok())
                        .collect::<Vec<_>>(),
                ),
                topic: c.topic.clone(),
                updates_topic: c.updates_topic(),
            };
            limit_dds_logging();
            let output = RosOutput::start(&settings)
                .map_err(|e| Fatal::new(exit::UNAVAILABLE, e.to_string()))?;
            tracing::info!(
                "publishing a {}x{} grid of {} m on {} (+ {}), frame '{}', ROS domain {}, {}",
                grid.width,
                grid.height,
                grid.resolution,
                settings.topic,
                settings.updates_topic,
                c.frame_id,
                settings.domain_id,
                if settings.interfaces.is_empty() {
                    "all interfaces".to_string()
                } else {
                    format!("interfaces {:?}", settings.interfaces)
                }
            );
            Some(Ros {
                output,
                tracker: DeltaTracker::new(Duration::from_secs_f64(c.full_every_s)),
                geometry: geometry_key(grid),
                frame_id: c.frame_id.clone(),
            })
        }
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
        activity.push(
            ctx.ipc
                .subscriber::<Activity>(&cam.id)
                .map_err(unavailable)?,
        );
        detections.push(
            ctx.ipc
                .subscriber::<Detections>(&cam.id)
                .map_err(unavailable)?,
        );
    }
    let plan_server = PlanServer::new(&ctx.ipc).map_err(unavailable)?;
    let waitset = WaitSetBuilder::new()
        .create::<ipc::Service>()
        .map_err(|e| Fatal::new(exit::UNAVAILABLE, format!("creating a waitset: {e:?}")))?;
    let attach = |e| {
        Fatal::new(
            exit::UNAVAILABLE,
            format!("attaching to the waitset: {e:?}"),
        )
    };
    let mut guards = Vec::new();
    for s in &activity {
        guards.push(waitset.attach_notification(s).map_err(attach)?);
    }
    for s in &detections {
        guards.push(waitset.attach_notification(s).map_err(attach)?);
    }
    guards.push(waitset.attach_notification(&plan_server).map_err(attach)?);

    let mut health = Health::new("costmap", "", Some(&ctx.ipc));
    let mut counters = Counters::default();
    let mut sequences: Vec<[Option<u64>; 2]> = vec![[None; 2]; config.cameras.len()];
    let period = Duration::from_secs_f64(1.0 / c.publish_hz);
    let snapshot_every =
        (c.snapshot_every_s > 0.0).then(|| Duration::from_secs_f64(c.snapshot_every_s));
    let mut next_publish = Instant::now();
    let mut next_snapshot = snapshot_every.map(|e| Instant::now() + e);
    let mut newest_arrival: Option<(Instant, i64)> = None;
    notify_ready(&format!("cost map of {} cameras", config.cameras.len()));

    while !ctx.ipc.should_stop() {
        let now = Instant::now();
        let wait = next_publish
            .saturating_duration_since(now)
            .clamp(Duration::from_millis(1), MAX_WAIT);
        let result =
            waitset.wait_and_process_once_with_timeout(|_| CallbackProgression::Continue, wait);
        if result.as_ref().is_ok_and(stop_requested_by) {
            break;
        }

        for (k, sub) in activity.iter().enumerate() {
            sub.drain_wakeups();
            while let Some(sample) = sub.receive().map_err(unavailable)? {
                let arrived = Instant::now();
                let h = *sample.user_header();
                if let Err(e) = h.validate(&bridge.cameras[k].camera_id, sample.payload().len()) {
                    tracing::warn!(camera = %bridge.cameras[k].id, "rejected an activity sample: {e}");
                    health.rejected();
                    continue;
                }
                count_received(&mut health, &mut sequences[k][0], h.preamble.sequence);
                if h.preamble.is_end_of_stream() {
                    continue;
                }
                bridge.on_activity(k, &h, sample.payload(), arrived);
                newest_arrival = Some((arrived, h.preamble.origin_wall_ns));
            }
        }
        for (k, sub) in detections.iter().enumerate() {
            sub.drain_wakeups();
            while let Some(sample) = sub.receive().map_err(unavailable)? {
                let h = *sample.user_header();
                if let Err(e) = h.validate(&bridge.cameras[k].camera_id, sample.payload().len()) {
                    tracing::warn!(camera = %bridge.cameras[k].id, "rejected a detections sample: {e}");
                    health.rejected();
                    continue;
                }
                count_received(&mut health, &mut sequences[k][1], h.preamble.sequence);
                if !h.preamble.is_end_of_stream() {
                    counters.confirmed += bridge.on_detections(k, &h, sample.payload()) as u64;
                }
            }
        }

        let mut rejected = 0;
        let served = plan_server
            .serve(
                |kind, request| {
                    answer(
                        kind,
                        request,
                        &mut planner,
                        &bridge,
                        &clock,
                        &snapshot_dir,
                        floor_plan.as_ref(),
                        loaded,
                        &mut counters,
                    )
                },
                &mut rejected,
            )
            .map_err(unavailable)?;
        counters.plans += served as u64;
        for _ in 0..rejected {
            health.rejected();
        }

        let now = Instant::now();
        if now >= next_publish {
            next_publish += period;
            if next_publish < now {
                // Fell behind (a slow plan, a stalled DDS write): do not burst.
                next_publish = now + period;
            }
            if let (Some(ros), Some(grid)) = (&mut ros, &bridge.grid)
                && let Some(cells) = bridge.compose(now)
            {
                let stamp_ns = bridge.newest(now).map_or_else(wall_now_ns, |(t, _)| t);
                let published = publish(ros, grid, &cells, stamp_ns, now, &mut counters);
                if published {
                    let (arrived, origin) = newest_arrival.map_or((None, 0), |(a, o)| (Some(a), o));
                    health.sent(arrived, origin);
                }
            }
        }
        if let Some(at) = next_snapshot
            && now >= at
        {
            next_snapshot = snapshot_every.map(|e| now + e);
            match write_snapshot(&bridge, loaded, &snapshot_dir, floor_plan.as_ref(), now) {
                Ok(path) => {
                    counters.snapshots += 1;
                    tracing::debug!("snapshot {path}");
                }
                Err(e) => tracing::warn!("periodic snapshot failed: {e}"),
            }
        }

        health.tick(|| {
            let live = (0..bridge.cameras.len()).filter(|&k| bridge.is_live(k, Instant::now())).count();
            format!(
                "cameras_live={live}/{} grids={} updates={} ros_subscribers={} publish_errors={} plans={} snapshots={} confirmed={}",
                bridge.cameras.len(),
                counters.grids,
                counters.updates,
                ros.as_ref().map_or(0, |r| r.output.grid_subscribers()),
                counters.publish_errors,
                counters.plans,
                counters.snapshots,
                counters.confirmed
            )
        });
    }
    drop(guards);
    Ok(())
}

/// Counts a received sample and the samples lost before it (per camera and stream;
/// a sequence going backwards is a restarted producer, not a loss).
fn count_received(health: &mut Health, last: &mut Option<u64>, sequence: u64) {
    health.read_one();
    if let Some(l) = *last
        && sequence > l + 1
    {
        health.dropped(sequence - l - 1);
    }
    *last = Some(sequence);
}

/// A hash of what makes two grids incompatible (size, resolution, origin).
fn geometry_key(grid: &MapGrid) -> u64 {
    let mut h = std::collections::hash_map::DefaultHasher::new();
    (grid.width, grid.height).hash(&mut h);
    for v in [grid.resolution, grid.origin_x, grid.origin_y, grid.yaw] {
        v.to_bits().hash(&mut h);
    }
    h.finish()
}

/// Publishes what the tracker decides; true if something went out.
fn publish(
    ros: &mut Ros,
    grid: &MapGrid,
    cells: &[i8],
    stamp_ns: i64,
    now: Instant,
    counters: &mut Counters,
) -> bool {
    let header = Header {
        stamp: Time::from_utc_ns(stamp_ns),
        frame_id: ros.frame_id.clone(),
    };
    let result = match ros.tracker.next(cells, grid.width, ros.geometry, now) {
        Output::Nothing => return false,
        Output::Full => {
            counters.grids += 1;
            ros.output.publish_grid(OccupancyGrid {
                header: header.clone(),
                info: MapMetaData {
                    map_load_time: header.stamp,
                    resolution: grid.resolution as f32,
                    width: grid.width,
                    height: grid.height,
                    origin: Pose {
                        position: Point {
                            x: grid.origin_x,
                            y: grid.origin_y,
                            z: 0.0,
                        },
                        orientation: Quaternion::from_yaw(grid.yaw),
                    },
                },
                data: cells.to_vec(),
            })
        }
        Output::Update {
            x,
            y,
            width,
            height,
            data,
        } => {
            counters.updates += 1;
            ros.output.publish_update(OccupancyGridUpdate {
                header,
                x: x as i32,
                y: y as i32,
                width,
                height,
                data,
            })
        }
    };
    if let Err(e) = result {
        counters.publish_errors += 1;
        // Subscribers must not miss a delta: the next tick sends the full grid.
        ros.tracker.reset();
        tracing::warn!("publishing to ROS 2 failed: {e}");
        return false;
    }
    true
}

/// The map_yaml image as the snapshot's floor plan, if any.
fn load_floor_plan(loaded: &LoadedConfig, grid: Option<&MapGrid>) -> Option<FloorPlan> {
    let yaml = loaded.config.costmap.map_yaml.as_ref()?;
    let yaml = if yaml.is_absolute() {
        yaml.clone()
    } else {
        loaded.base_dir().join(yaml)
    };
    let text = std::fs::read_to_string(&yaml).ok()?;
    let image = text
        .lines()
        .find_map(|l| l.trim().strip_prefix("image:"))
        .map(|s| s.trim().trim_matches(['"', '\'']).to_string())?;
    let image = yaml
        .parent()
        .unwrap_or(std::path::Path::new("."))
        .join(image);
    match FloorPlan::load(&image) {
        Ok(plan) if grid.is_some_and(|g| g.width == plan.width && g.height == plan.height) => {
            Some(plan)
        }
        Ok(_) => None,
        Err(e) => {
            tracing::warn!("the floor plan is left out of pictures: {e}");
            None
        }
    }
}

/// Writes a snapshot of the current cost map; returns the YAML's path.
fn write_snapshot(
    bridge: &Bridge,
    loaded: &LoadedConfig,
    dir: &std::path::Path,
    floor_plan: Option<&FloorPlan>,
    now: Instant,
) -> Result<String, String> {
    let grid = bridge
        .grid
        .as_ref()
        .ok_or("no [costmap] grid is configured (map_yaml or width_cells/height_cells)")?;
    let cells = bridge.compose(now).ok_or("no grid")?;
    let stamp_ns = bridge.newest(now).map_or_else(wall_now_ns, |(t, _)| t);
    let ts = timestamp(stamp_ns);
    let stem = format!(
        "activity-{}{:03}Z",
        ts.strftime("%Y%m%dT%H%M%S."),
        ts.subsec_millisecond()
    );
    let coverage = bridge.coverage();
    let polygons: Vec<&[[f64; 2]]> = loaded
        .config
        .costmap
        .segments
        .iter()
        .filter_map(|s| s.polygon_m.as_deref())
        .collect();
    let stamp = format_rfc3339(stamp_ns);
    let files = snapshot::write(
        dir,
        &stem,
        &Snapshot {
            grid,
            cells: &cells,
            floor_plan,
            coverage: &coverage,
            segments: &polygons,
            stamp: &stamp,
        },
    )?;
    snapshot::prune(dir, "activity-", loaded.config.costmap.snapshot_keep)?;
    Ok(files.yaml.display().to_string())
}

/// Answers one planning request.
#[allow(clippy::too_many_arguments)]
fn answer(
    kind: PlanKind,
    request: &PlanRequest,
    planner: &mut Planner,
    bridge: &Bridge,
    clock: &SiteClock,
    snapshot_dir: &std::path::Path,
    floor_plan: Option<&FloorPlan>,
    loaded: &LoadedConfig,
    counters: &mut Counters,
) -> PlanResponse {
    let now = Instant::now();
    let failed =
        |status: PlanStatus, message: String| PlanResponse::new(kind as u32, status, &message);
    let status_of = |e: &PlanError| match e {
        PlanError::UnknownRoute(..) => PlanStatus::UnknownRoute,
        PlanError::NoData(_) | PlanError::EmptySegment(_) => PlanStatus::NoData,
        _ => PlanStatus::Failed,
    };
    // "Now" is the time of the newest activity (header time), else the wall clock.
    let now_ns = bridge.newest(now).map_or_else(wall_now_ns, |(t, _)| t);
    match kind {
        PlanKind::Offline => {
            let route = request.route_names().remove(0);
            let cycle_offset = match planner.cycle() {
                Cycle::Daily => 0,
                Cycle::Weekly => {
                    let day = if request.weekday == 7 {
                        clock.t_star(now_ns) / 1440
                    } else {
                        request.weekday
                    };
                    day * 1440
                }
            };
            let range = DayRange {
                start: request.start_minute,
                end: request.end_minute,
                step: request.step_min,
                cycle_offset,
            };
            match planner.offline(&route, range) {
                Ok(plan) => answer_offline(&plan),
                Err(e) => failed(status_of(&e), e.to_string()),
            }
        }
        PlanKind::Now => {
            let t_star = bridge
                .newest(now)
                .map_or_else(|| clock.t_star(now_ns), |(_, t)| t);
            let live = bridge.live(now);
            match planner.now(&request.route_names(), &live, t_star) {
                Ok(ranked) => answer_now(&ranked, t_star),
                Err(e) => failed(status_of(&e), e.to_string()),
            }
        }
        PlanKind::Snapshot => match write_snapshot(bridge, loaded, snapshot_dir, floor_plan, now) {
            Ok(path) => {
                counters.snapshots += 1;
                tracing::info!("snapshot written: {path}");
                PlanResponse::new(kind as u32, PlanStatus::Ok, &path)
            }
            Err(e) if bridge.grid.is_none() => failed(PlanStatus::NoData, e),
            Err(e) => failed(PlanStatus::Failed, e),
        },
    }
}
