//! The planner of a site: the segments and routes of its config, the cameras'
//! floor mappings, and their long-term stores, read-only (also while the cascade
//! writes them). Both the `isochron plan` command and the bridge's planning
//! service answer through it.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use isochron_config::clock::{Cycle, MINUTES_PER_DAY};
use isochron_config::{CostmapConfig, DAY_NAMES, LoadedConfig, RouteConfig};
use isochron_store::{Model, Store, StoreError, store_path};
use isochron_wire::BlockActivity;
use isochron_wire::geometry::BlockGrid;

use crate::cost::{CostParams, Layer, compose};
use crate::grid::MapGrid;
use crate::homography::Homography;
use crate::plan::{
    CameraGeometry, DayRange, OfflinePlan, PlanError, RouteNow, SegmentBlocks, SegmentProfile,
    plan_now, plan_offline, resolve_segment, route_profiles, segment_now, store_block_grid,
};
use crate::profile::{ProfilePoint, daily_profile};
use crate::raster::Footprint;

mod graph;

/// A camera's latest live activity.
#[derive(Debug, Clone, Copy)]
pub struct LiveCamera<'a> {
    /// Its block grid.
    pub blocks: BlockGrid,
    /// Activity per block.
    pub activity: &'a [BlockActivity],
}

/// A camera's long-term mean activity per block at one t*, on its store's block
/// grid.
pub type LongTermBin = (BlockGrid, Vec<f32>);

/// A segment's long-term activity per bin of the cycle.
#[derive(Debug, Clone, PartialEq)]
pub struct SegmentDaily {
    /// `M_p(t*)` and `M'_p`.
    pub profile: SegmentProfile,
    /// Per bin: `M_p(t*)` again, the day-to-day spread (root mean square of the
    /// block sigmas) and the days (cycles) that taught it (the most over the
    /// segment's cameras).
    pub points: Vec<ProfilePoint>,
}

/// A camera's long-term model as last read.
struct Cached {
    model: Model,
    last_minute: Option<i64>,
    checked: Instant,
}

/// Plans for one site.
pub struct Planner {
    config: CostmapConfig,
    cycle: Cycle,
    /// The long-term model's rules (rest days, holidays, weights) forecasts are read
    /// with.
    rules: isochron_store::Rules,
    cameras: Vec<CameraGeometry>,
    state_dir: PathBuf,
    params: CostParams,
    models: Vec<Option<Cached>>,
    /// How long a read model is trusted before the store is checked for news.
    pub refresh_every: Duration,
}

impl Planner {
    /// The planner of `loaded`; fails if a camera's floor points do not define a
    /// homography.
    pub fn new(loaded: &LoadedConfig) -> Result<Planner, PlanError> {
        let config = &loaded.config;
        let mut cameras = Vec::new();
        for (i, cam) in config.cameras.iter().enumerate() {
            let homography = Homography::of_camera(cam)
                .map_err(|e| {
                    PlanError::Config(format!("camera[{i}].floor_points ({}): {e}", cam.id))
                })?
                .map(|(h, _)| h);
            cameras.push(CameraGeometry {
                config: cam.clone(),
                homography,
                blocks: None,
            });
        }
        Ok(Planner {
            config: config.costmap.clone(),
            cycle: config.cascade.cycle,
            rules: isochron_store::Rules::of(&config.cascade),
            models: cameras.iter().map(|_| None).collect(),
            cameras,
            state_dir: loaded.state_dir(),
            params: CostParams::from_config(&config.costmap),
            refresh_every: Duration::ZERO,
        })
    }

    /// The cost function in use.
    pub fn params(&self) -> &CostParams {
        &self.params
    }

    /// The isochronal cycle of the site.
    pub fn cycle(&self) -> Cycle {
        self.cycle
    }

    /// The route named `name`.
    pub fn route(&self, name: &str) -> Result<&RouteConfig, PlanError> {
        self.config.route(name).ok_or_else(|| {
            PlanError::UnknownRoute(
                name.to_string(),
                listed(self.config.routes.iter().map(|r| r.name.as_str())),
            )
        })
    }

    /// Reads (or re-reads, when the cascade committed since) each camera's store.
    fn refresh(&mut self) -> Result<(), PlanError> {
        let now = Instant::now();
        for (k, cam) in self.cameras.iter_mut().enumerate() {
            if let Some(c) = &self.models[k]
                && now.duration_since(c.checked) < self.refresh_every
            {
                continue;
            }
            let path = store_path(&self.state_dir, &cam.config.id);
            let store = match Store::open_read_only(&path, &cam.config.id) {
                Ok(s) => s,
                Err(StoreError::NotFound { .. }) => {
                    self.models[k] = None;
                    continue;
                }
                Err(e) => return Err(PlanError::NoData(e.to_string())),
            };
            let last_minute = store
                .progress()
                .map_err(|e| PlanError::NoData(e.to_string()))?
                .last_minute;
            if let Some(c) = &mut self.models[k]
                && c.last_minute == last_minute
            {
                c.checked = now;
                continue;
            }
            let model = store
                .read_model()
                .map_err(|e| PlanError::NoData(e.to_string()))?
                .with_rules(self.rules.clone());
            cam.blocks = Some(store_block_grid(&model));
            self.models[k] = Some(Cached {
                model,
                last_minute,
                checked: now,
            });
        }
        Ok(())
    }

    /// The blocks of every segment named by `names` on the long-term block grids.
    fn long_term_segments(&self, names: &[&str]) -> Result<Vec<SegmentBlocks>, PlanError> {
        names
            .iter()
            .map(|name| {
                let seg = self.config.segment(name).ok_or_else(|| {
                    PlanError::UnknownSegment(
                        name.to_string(),
                        listed(self.config.segments.iter().map(|s| s.name.as_str())),
                    )
                })?;
                let blocks = resolve_segment(seg, &self.cameras).map_err(|e| match e {
                    PlanError::EmptySegment(_) if self.models.iter().all(Option::is_none) => {
                        self.no_store()
                    }
                    other => other,
                })?;
                // A segment needs the long-term model of at least one of its cameras.
                if blocks.blocks.iter().all(|(k, _)| self.models[*k].is_none()) {
                    return Err(self.no_store());
                }
                Ok(blocks)
            })
            .collect()
    }

    fn no_store(&self) -> PlanError {
        PlanError::NoData(format!(
            "no long-term store under {} for the cameras of this plan: isochron-cascade writes one per camera ({}) once it runs",
            self.state_dir.display(),
            self.cameras
                .iter()
                .map(|c| store_path(&self.state_dir, &c.config.id)
                    .display()
                    .to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ))
    }

    /// Each camera's long-term model as last read (`None`: no store).
    fn loaded_models(&self) -> Vec<Option<&Model>> {
        self.models
            .iter()
            .map(|m| m.as_ref().map(|c| &c.model))
            .collect()
    }

    /// The long-term profiles of the segments named by `names`.
    pub fn profiles(
        &mut self,
        names: &[&str],
    ) -> Result<BTreeMap<String, SegmentProfile>, PlanError> {
        self.refresh()?;
        let segments = self.long_term_segments(names)?;
        let models = self.loaded_models();
        let bins = self.cycle.bins() as usize;
        Ok(segments
            .iter()
            .map(|s| {
                (
                    s.name.clone(),
                    SegmentProfile::from_models(s, &models, bins, self.config.min_activity),
                )
            })
            .collect())
    }

    /// The off-line plan of `route` over `range`.
    pub fn offline(&mut self, route: &str, range: DayRange) -> Result<OfflinePlan, PlanError> {
        let route = self.route(route)?.clone();
        let names: Vec<&str> = route.segments.iter().map(String::as_str).collect();
        let profiles = self.profiles(&names)?;
        let ordered = route_profiles(&route, &profiles)?;
        Ok(plan_offline(&route, &ordered, range, &self.params))
    }

    /// The routes named `routes` ranked by `cost2` at isochronal time `t_star`, with
    /// the cameras' live activity (`live[k]` for camera `k`, `None` if none).
    pub fn now(
        &mut self,
        routes: &[String],
        live: &[Option<LiveCamera<'_>>],
        t_star: u32,
    ) -> Result<Vec<RouteNow>, PlanError> {
        let configs: Vec<RouteConfig> = routes
            .iter()
            .map(|r| self.route(r).cloned())
            .collect::<Result<_, _>>()?;
        let mut names: Vec<&str> = configs
            .iter()
            .flat_map(|r| r.segments.iter().map(String::as_str))
            .collect();
        names.sort_unstable();
        names.dedup();
        let profiles = self.profiles(&names)?;
        // M_p(now) on the live block grids.
        let live_cameras: Vec<CameraGeometry> = self
            .cameras
            .iter()
            .zip(live.iter().chain(std::iter::repeat(&None)))
            .map(|(c, l)| CameraGeometry {
                blocks: l.map(|l| l.blocks),
                ..c.clone()
            })
            .collect();
        let activity: Vec<Option<&[BlockActivity]>> = (0..self.cameras.len())
            .map(|k| live.get(k).copied().flatten().map(|l| l.activity))
            .collect();
        let mut now = BTreeMap::new();
        for name in &names {
            let seg = self.config.segment(name).expect("resolved above");
            let m = resolve_segment(seg, &live_cameras)
                .ok()
                .and_then(|blocks| segment_now(&blocks, &activity, &self.params));
            now.insert(name.to_string(), m);
        }
        let ordered: Vec<(&RouteConfig, Vec<&SegmentProfile>)> = configs
            .iter()
            .map(|r| route_profiles(r, &profiles).map(|p| (r, p)))
            .collect::<Result<_, _>>()?;
        Ok(plan_now(
            &ordered,
            &now,
            t_star,
            &self.params,
            self.config.w1,
            self.config.w2,
        ))
    }

    /// The long-term profile of one segment over the cycle: what
    /// `isochron plot daily --segment` draws.
    pub fn segment_daily(&mut self, name: &str) -> Result<SegmentDaily, PlanError> {
        self.refresh()?;
        let segment = self.long_term_segments(&[name])?.remove(0);
        let models = self.loaded_models();
        let points = daily_profile(&segment.model_blocks(&models), self.cycle.bins() as usize);
        Ok(SegmentDaily {
            profile: SegmentProfile::from_points(&segment.name, &points, self.config.min_activity),
            points,
        })
    }

    /// Each camera's long-term mean activity per block at isochronal time `t_star`
    /// with the block grid of its store (`None`: no store, or the bin never
    /// learned): what the cost map's forecast is drawn from.
    pub fn long_term_at(&mut self, t_star: u32) -> Result<Vec<Option<LongTermBin>>, PlanError> {
        self.refresh()?;
        Ok(self
            .models
            .iter()
            .map(|m| {
                let model = &m.as_ref()?.model;
                let bin = model.bin(t_star)?;
                Some((store_block_grid(model), bin.mean.clone()))
            })
            .collect())
    }

    /// The cost map the long-term model expects at isochronal time `t_star`: per
    /// camera the mean activity per block of its store's bin, costed as planning
    /// costs a segment (`Cost(M) = min(cap, 100 · M / cost_scale)`, the mean alone),
    /// the highest cost over cameras per cell, -1 where no camera with a learned
    /// bin sees. What the bridge publishes as its forecast and
    /// `isochron costmap snapshot --at` draws. `footprints` caches each camera's
    /// footprint on its store's block grid between calls.
    pub fn expected_costmap(
        &mut self,
        grid: &MapGrid,
        t_star: u32,
        footprints: &mut Vec<Option<Footprint>>,
    ) -> Result<Vec<i8>, PlanError> {
        let long_term = self.long_term_at(t_star)?;
        footprints.resize(self.cameras.len(), None);
        let mut blocks: Vec<(usize, Vec<BlockActivity>)> = Vec::new();
        for (k, cam) in self.cameras.iter().enumerate() {
            let (Some(h), Some(Some((block_grid, mean)))) = (&cam.homography, long_term.get(k))
            else {
                continue;
            };
            let slot = &mut footprints[k];
            if slot.as_ref().is_none_or(|f| f.blocks != *block_grid) {
                *slot = Some(Footprint::build(grid, h, *block_grid, &cam.config.mask));
            }
            let b = mean
                .iter()
                .map(|&s1| BlockActivity {
                    s1,
                    ..Default::default()
                })
                .collect();
            blocks.push((k, b));
        }
        let layers: Vec<Layer<'_>> = blocks
            .iter()
            .filter_map(|(k, b)| {
                let footprint = footprints[*k].as_ref()?;
                (b.len() == footprint.blocks.len()).then_some(Layer {
                    footprint,
                    blocks: b,
                })
            })
            .collect();
        // The mean alone, weighted 1, as planning's Cost(M_p).
        let params = CostParams {
            weight_in_place: 1.0,
            weight_moving: 0.0,
            weight_long_term: 0.0,
            ..self.params
        };
        Ok(compose(grid, &params, &layers, &[]))
    }

    /// Per camera (config order): its id, whether its long-term store exists, and
    /// whether its floor points give a mapping.
    pub fn cameras(&self) -> impl Iterator<Item = (&str, bool, bool)> {
        self.cameras
            .iter()
            .zip(&self.models)
            .map(|(c, m)| (c.config.id.as_str(), m.is_some(), c.homography.is_some()))
    }

    /// The days of the week (0 = Monday) on which some camera's long-term model
    /// has a forecast (a row learned, or, with day types, its type's row); every
    /// day for a daily model that learned anything.
    pub fn learned_days(&mut self) -> Result<Vec<u32>, PlanError> {
        self.refresh()?;
        let models = self.loaded_models();
        let day_has = |d: u32| {
            let minutes = d * MINUTES_PER_DAY..(d + 1) * MINUTES_PER_DAY;
            models
                .iter()
                .flatten()
                .any(|m| minutes.clone().any(|t| m.bin(t).is_some()))
        };
        Ok(match self.cycle {
            Cycle::Daily if day_has(0) => (0..7).collect(),
            Cycle::Daily => Vec::new(),
            Cycle::Weekly | Cycle::DayTypes => (0..7).filter(|&d| day_has(d)).collect(),
        })
    }

    /// Refuses `day` (0 = Monday) of a weekly model when the stores learned
    /// something but nothing for that day: a blank map or "no data" would look
    /// like a quiet day. Nothing learned at all is for the caller's own message.
    pub fn check_day_learned(&mut self, day: u32) -> Result<(), PlanError> {
        let learned = self.learned_days()?;
        if learned.is_empty() || learned.contains(&day) {
            return Ok(());
        }
        let name = |d: &u32| DAY_NAMES[(*d % 7) as usize];
        Err(PlanError::DayNotLearned {
            day: name(&day).to_string(),
            learned: learned.iter().map(name).collect::<Vec<_>>().join(", "),
        })
    }

    /// Where the long-term stores are looked for, and what is missing, as an error.
    pub fn missing_stores(&self) -> PlanError {
        self.no_store()
    }

    /// How many days taught the segment's cameras' bins at most (for titles).
    pub fn days(&self) -> u32 {
        self.models
            .iter()
            .flatten()
            .flat_map(|c| c.model.learned().map(|b| b.count))
            .max()
            .unwrap_or(0)
    }
}

/// `names` as a comma-separated list, for errors that say what exists.
fn listed<'a>(names: impl Iterator<Item = &'a str>) -> String {
    names.collect::<Vec<_>>().join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;
    use isochron_config::Config;
    use isochron_store::StoreMeta;

    /// A site with one camera looking straight down at a 4 m × 3 m floor
    /// (80 px per metre), a 320×240 frame in 16 px blocks (20×15), and a
    /// hand-made long-term store.
    const SITE: &str = concat!(
        "\n[site]\nstate_dir = \"state\"\n\n",
        include_str!("../tests/fixtures/floor_camera.toml"),
        include_str!("../tests/fixtures/door_zone.toml"),
        "\n",
        include_str!("../tests/fixtures/planner_costmap.toml"),
    );

    fn site(bins: impl Fn(u32) -> Option<Vec<f32>>) -> (tempfile::TempDir, LoadedConfig) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("site.toml");
        std::fs::write(&path, SITE).unwrap();
        let loaded = Config::load(&path).unwrap();
        let meta = StoreMeta::new("cam01", BlockGrid::new(320, 240, 16), Cycle::Daily, 0);
        let mut store =
            Store::open_or_create(&store_path(&loaded.state_dir(), "cam01"), &meta).unwrap();
        for t in 0..1440 {
            if let Some(mean) = bins(t) {
                store.teach(t, 10, mean).unwrap();
            }
        }
        (dir, loaded)
    }

    /// Block index → is it in the west half (x < 160 px ↔ x < 2 m)?
    fn west(b: usize) -> bool {
        b % 20 < 10
    }

    #[test]
    fn offline_finds_the_quiet_hour_from_the_store() {
        // The west half is busy except 12:00-13:00; the east half always a little.
        let (_dir, loaded) = site(|t| {
            Some(
                (0..300)
                    .map(|b| {
                        if west(b) {
                            if (720..780).contains(&t) { 0.0 } else { 0.05 }
                        } else {
                            0.01
                        }
                    })
                    .collect(),
            )
        });
        let mut planner = Planner::new(&loaded).unwrap();
        let plan = planner.offline("through", DayRange::whole_day(5)).unwrap();
        assert_eq!(plan.windows[0].start, 720);
        assert_eq!(plan.windows[0].end, 780);
        assert!(
            (plan.windows[0].cost - 10.0).abs() < 1e-4,
            "{:?}",
            plan.windows[0]
        );
        assert!((plan.curve[0].cost - 60.0).abs() < 1e-4);
        let err = planner
            .offline("nowhere", DayRange::whole_day(5))
            .unwrap_err();
        assert!(err.to_string().contains("through, via-door"), "{err}");
    }

    #[test]
    fn a_segment_never_visited_makes_its_routes_infinite() {
        // Only the east half ever moves.
        let (_dir, loaded) =
            site(|_| Some((0..300).map(|b| if west(b) { 0.0 } else { 0.02 }).collect()));
        let mut planner = Planner::new(&loaded).unwrap();
        let plan = planner.offline("through", DayRange::whole_day(60)).unwrap();
        assert_eq!(plan.never_active, vec!["west".to_string()]);
        assert!(plan.curve.iter().all(|p| p.cost.is_infinite()));
        let ranked = planner
            .now(&["through".into(), "via-door".into()], &[], 600)
            .unwrap();
        assert!(ranked.iter().all(|r| r.infinite));
    }

    #[test]
    fn now_uses_live_activity_and_ranks() {
        // Long-term: everything equally a little busy.
        let (_dir, loaded) = site(|_| Some(vec![0.01; 300]));
        let mut planner = Planner::new(&loaded).unwrap();
        // Live: the door zone (blocks x < 4, y < 4) is crowded.
        let blocks = BlockGrid {
            frame_width: 320,
            frame_height: 240,
            block_px: 16,
        };
        let activity: Vec<BlockActivity> = (0..300)
            .map(|b| BlockActivity {
                s1: if b % 20 < 4 && b / 20 < 4 { 0.2 } else { 0.0 },
                ..Default::default()
            })
            .collect();
        let live = [Some(LiveCamera {
            blocks,
            activity: &activity,
        })];
        let ranked = planner
            .now(&["via-door".into(), "through".into()], &live, 600)
            .unwrap();
        let names: Vec<&str> = ranked.iter().map(|r| r.name.as_str()).collect();
        assert_eq!(names, ["through", "via-door"]);
        // through: long-term 10 + 10, short-term: west has 16 of 150 blocks at 0.2.
        let west_now = 16.0 * 0.2 / 150.0;
        assert!(
            (ranked[0].short_term - 100.0 * west_now / 0.1).abs() < 1e-3,
            "{:?}",
            ranked[0]
        );
        assert!((ranked[0].cost1 - 20.0).abs() < 1e-3);
        // via-door: door is all crowded → capped at the default cap, 98.
        assert!((ranked[1].short_term - (98.0 + 100.0 * west_now / 0.1)).abs() < 1e-3);
        assert!(!ranked[0].estimated);
    }

    #[test]
    fn segment_daily_counts_negative_means_as_zero() {
        // West drifted a little below zero (rounding), east is a little busy.
        let (_dir, loaded) = site(|t| {
            (t < 60).then(|| {
                (0..300)
                    .map(|b| if west(b) { -0.01 } else { 0.02 })
                    .collect()
            })
        });
        let mut planner = Planner::new(&loaded).unwrap();
        let west = planner.segment_daily("west").unwrap();
        // The site's cycle is a week (day types): the daily store serves every day.
        assert_eq!(west.points.len(), 7 * 1440);
        assert_eq!(west.points[6 * 1440].mean, Some(0.0));
        assert_eq!(west.points[0].mean, Some(0.0));
        assert_eq!(
            (west.points[0].sigma, west.points[0].count),
            (Some(0.0), 10)
        );
        assert_eq!((west.points[60].mean, west.points[60].count), (None, 0));
        assert_eq!(west.profile.m_p[0], Some(0.0));
        assert!(!west.profile.m_prime);
        let east = planner.segment_daily("east").unwrap();
        assert!((east.points[0].mean.unwrap() - 0.02).abs() < 1e-6);
        assert!(east.profile.m_prime);
    }

    #[test]
    fn the_expected_cost_map_is_the_costed_mean_of_the_bin() {
        // West busy (0.05 → 100 · 0.05 / 0.1 = 50) and east a little (0.01 → 10) from 08:00;
        // nothing learned before.
        let (_dir, loaded) = site(|t| {
            (t >= 480).then(|| {
                (0..300)
                    .map(|b| if west(b) { 0.05 } else { 0.01 })
                    .collect()
            })
        });
        let mut planner = Planner::new(&loaded).unwrap();
        // Half-metre cells over the camera's 4 m × 3 m, one column more (unseen).
        let grid = MapGrid {
            origin_x: 0.0,
            origin_y: 0.0,
            yaw: 0.0,
            resolution: 0.5,
            width: 9,
            height: 6,
        };
        let mut footprints = Vec::new();
        let cells = planner
            .expected_costmap(&grid, 600, &mut footprints)
            .unwrap();
        for (k, &c) in cells.iter().enumerate() {
            let want = match k % 9 {
                0..4 => 50,
                4..8 => 10,
                _ => -1,
            };
            assert_eq!(c, want, "cell {k}");
        }
        assert!(footprints[0].is_some());
        // A bin never learned: no camera with a model sees anything.
        let cells = planner
            .expected_costmap(&grid, 300, &mut footprints)
            .unwrap();
        assert!(cells.iter().all(|&c| c == -1));
        assert_eq!(
            planner.cameras().collect::<Vec<_>>(),
            [("cam01", true, true)]
        );
    }

    #[test]
    fn a_missing_store_says_where_it_was_looked_for() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("site.toml");
        std::fs::write(&path, SITE).unwrap();
        let loaded = Config::load(&path).unwrap();
        let mut planner = Planner::new(&loaded).unwrap();
        let err = planner
            .offline("through", DayRange::whole_day(5))
            .unwrap_err();
        assert!(matches!(err, PlanError::NoData(_)), "{err}");
        assert!(err.to_string().contains("cam01.isochron.sqlite"), "{err}");
    }
}
