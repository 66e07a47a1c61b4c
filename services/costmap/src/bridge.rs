//! The bridge's state between samples: per camera its floor mapping, footprint on
//! the grid, latest activity and the people the detector confirmed; and from them
//! the cost map. No shared memory here — `main.rs` feeds it, tests drive it
//! directly.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use isochron_config::clock::NS_PER_S;
use isochron_config::{LoadedConfig, Polygon};
use isochron_planning::cost::{CostParams, Layer, compose};
use isochron_planning::grid::MapGrid;
use isochron_planning::homography::{Homography, HomographyError};
use isochron_planning::planner::LiveCamera;
use isochron_planning::raster::Footprint;
use isochron_runtime::stage::Context;
use isochron_wire::geometry::BlockGrid;
use isochron_wire::{
    ActivityHeader, BlockActivity, CameraId, Detection, DetectionHeader, KnownGrid, WireError,
};

/// Class id of a person in [`Detection::class`].
pub const PERSON: u32 = 0;

/// A person the detector confirmed.
#[derive(Debug, Clone, Copy)]
pub struct Confirmed {
    /// Capture time of the detected frame, UTC ns.
    pub seen_ns: i64,
    /// The feet (the box's bottom centre), frame pixels.
    pub feet_px: [f32; 2],
    /// The feet on the floor, map metres.
    pub floor_m: [f64; 2],
    /// The detection as the gate sent it (model, score, keypoints).
    pub detection: Detection,
}

/// A camera's latest activity sample.
#[derive(Debug, Clone)]
pub struct Latest {
    /// Its header.
    pub header: ActivityHeader,
    /// Its blocks.
    pub blocks: Vec<BlockActivity>,
    /// When it arrived (wall clock of this process).
    pub arrived: Instant,
}

/// What the bridge knows of one camera.
#[derive(Debug, Clone)]
pub struct CameraState {
    /// Camera id.
    pub id: String,
    /// The id as it travels in headers.
    pub camera_id: CameraId,
    /// Image → floor, if the camera has floor points.
    pub homography: Option<Homography>,
    /// RMS error of the homography at its own points, metres.
    pub homography_rms_m: f64,
    /// Masked regions (frame pixels).
    pub masks: Vec<Polygon>,
    /// Its block grid: from the config (width, height, `motion.block_px`), or
    /// pinned by its first activity sample.
    pub known: KnownGrid,
    /// The footprint of its current block grid on the map grid.
    pub footprint: Option<Footprint>,
    /// The latest activity.
    pub latest: Option<Latest>,
    /// Confirmed people, oldest first.
    pub confirmed: VecDeque<Confirmed>,
}

/// The cost map bridge's state.
#[derive(Debug, Clone)]
pub struct Bridge {
    /// The map grid, if configured.
    pub grid: Option<MapGrid>,
    /// The cost function.
    pub params: CostParams,
    /// The cameras, in config order.
    pub cameras: Vec<CameraState>,
    stale: Duration,
    confirm_hold_ns: i64,
}

/// A camera the bridge cannot work with; the message names its config key.
#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    /// Its floor points give no floor mapping.
    #[error("camera[{index}].floor_points ({camera}): {source}")]
    FloorPoints {
        /// Position in the config's camera list.
        index: usize,
        /// Camera id.
        camera: String,
        /// Why the mapping failed.
        source: HomographyError,
    },
    /// Its id cannot travel in a header.
    #[error("camera[{index}].id: invalid")]
    CameraId {
        /// Position in the config's camera list.
        index: usize,
    },
}

impl isochron_exit::Classify for BridgeError {
    fn exit_code(&self) -> i32 {
        isochron_exit::CONFIG
    }
}

/// Most confirmations kept per camera.
const MAX_CONFIRMED: usize = 1024;

impl Bridge {
    /// The bridge of `loaded`: `grid` (see [`MapGrid::from_config`]), the cameras'
    /// homographies (an error names the camera's `floor_points` key).
    pub fn new(loaded: &LoadedConfig, grid: Option<MapGrid>) -> Result<Bridge, BridgeError> {
        let config = &loaded.config;
        let mut cameras = Vec::new();
        for (i, cam) in config.cameras.iter().enumerate() {
            let fitted = Homography::of_camera(cam).map_err(|source| BridgeError::FloorPoints {
                index: i,
                camera: cam.id.clone(),
                source,
            })?;
            cameras.push(CameraState {
                id: cam.id.clone(),
                camera_id: CameraId::new(&cam.id).ok_or(BridgeError::CameraId { index: i })?,
                homography: fitted.map(|(h, _)| h),
                homography_rms_m: fitted.map_or(0.0, |(_, rms)| rms),
                masks: cam.mask.clone(),
                known: KnownGrid::new(
                    cam.width
                        .zip(cam.height)
                        .map(|(w, h)| BlockGrid::new(w, h, config.motion.block_px)),
                ),
                footprint: None,
                latest: None,
                confirmed: VecDeque::new(),
            });
        }
        let c = &config.costmap;
        Ok(Bridge {
            grid,
            params: CostParams::from_config(c),
            cameras,
            stale: isochron_config::clock::saturating_secs(c.stale_s),
            confirm_hold_ns: (c.confirm_hold_s * NS_PER_S as f64) as i64,
        })
    }

    /// Admits camera `k`'s activity sample (validated by the caller) if its grid
    /// is the camera's known one ([`KnownGrid`]): the first sample of a camera
    /// whose config gives no size pins it, with a warning. Nothing is built for
    /// a grid before it is admitted.
    pub fn admit(&mut self, k: usize, header: &ActivityHeader) -> Result<(), WireError> {
        let Some(cam) = self.cameras.get_mut(k) else {
            return Ok(());
        };
        let grid = header.block_grid();
        if cam.known.check(grid)? {
            tracing::warn!(
                camera = %cam.id,
                "block grid {grid} pinned by the camera's first activity sample: any other grid \
                 is refused until the bridge restarts (set the camera's width and height in the \
                 config to fix it)"
            );
        }
        Ok(())
    }

    /// Takes camera `k`'s activity sample (validated by the caller). A block with
    /// a NaN or infinite value is kept with those values read as 0; returns how
    /// many blocks had one (for the caller to count as rejected, see
    /// [`count_non_finite`]).
    pub fn on_activity(
        &mut self,
        k: usize,
        header: &ActivityHeader,
        blocks: &[BlockActivity],
        now: Instant,
    ) -> usize {
        let Some(cam) = self.cameras.get_mut(k) else {
            return 0;
        };
        let block_grid = header.block_grid();
        if let (Some(grid), Some(h)) = (&self.grid, &cam.homography)
            && cam
                .footprint
                .as_ref()
                .is_none_or(|f| f.blocks != block_grid)
        {
            let footprint = Footprint::build(grid, h, block_grid, &cam.masks);
            tracing::info!(
                camera = %cam.id,
                "{}x{} blocks of {} px cover {} of the grid's {} cells",
                block_grid.grid_w(),
                block_grid.grid_h(),
                block_grid.block_px,
                footprint.seen,
                grid.len()
            );
            if footprint.seen == 0 {
                tracing::warn!(
                    camera = %cam.id,
                    "the camera sees no cell of the grid: check its floor_points and the [costmap] grid"
                );
            }
            cam.footprint = Some(footprint);
        }
        let latest = cam.latest.get_or_insert_with(|| Latest {
            header: *header,
            blocks: Vec::new(),
            arrived: now,
        });
        latest.header = *header;
        latest.blocks.clear();
        latest.blocks.extend_from_slice(blocks);
        let non_finite = latest
            .blocks
            .iter_mut()
            .map(sanitise)
            .filter(|&bad| bad)
            .count();
        latest.arrived = now;
        let horizon = header.preamble.capture_time_ns - self.confirm_hold_ns;
        while cam.confirmed.front().is_some_and(|c| c.seen_ns < horizon) {
            cam.confirmed.pop_front();
        }
        non_finite
    }

    /// Takes camera `k`'s detections (validated by the caller): each person's feet
    /// (the bottom centre of their box) on the floor. They replace the camera's
    /// earlier confirmations in the region the detector searched (a person it no
    /// longer finds there is gone). Returns how many were placed,
    /// and how many boxes (of any class) were ignored for a NaN or infinite
    /// coordinate (for the caller to count as rejected, see [`count_non_finite`]).
    pub fn on_detections(
        &mut self,
        k: usize,
        header: &DetectionHeader,
        detections: &[Detection],
    ) -> (usize, usize) {
        let finite = |d: &&Detection| {
            d.x.is_finite() && d.y.is_finite() && d.w.is_finite() && d.h.is_finite()
        };
        let non_finite = detections.len() - detections.iter().filter(finite).count();
        let Some(cam) = self.cameras.get_mut(k) else {
            return (0, non_finite);
        };
        let Some(h) = &cam.homography else {
            return (0, non_finite);
        };
        let t = header.preamble.capture_time_ns;
        cam.confirmed
            .retain(|c| c.seen_ns > t || !header.searched(c.feet_px[0], c.feet_px[1]));
        let mut placed = 0;
        for d in detections
            .iter()
            .filter(finite)
            .filter(|d| d.class == PERSON)
        {
            let feet = [d.x + d.w / 2.0, d.y + d.h];
            if let Some(p) = h.apply([feet[0] as f64, feet[1] as f64]) {
                cam.confirmed.push_back(Confirmed {
                    seen_ns: t,
                    feet_px: feet,
                    floor_m: p,
                    detection: *d,
                });
                placed += 1;
            }
        }
        while cam.confirmed.len() > MAX_CONFIRMED {
            cam.confirmed.pop_front();
        }
        (placed, non_finite)
    }

    /// True if camera `k`'s activity arrived within `stale_s`.
    pub fn is_live(&self, k: usize, now: Instant) -> bool {
        self.cameras
            .get(k)
            .and_then(|c| c.latest.as_ref())
            .is_some_and(|l| now.saturating_duration_since(l.arrived) < self.stale)
    }

    /// The cost map now, if a grid is configured.
    pub fn compose(&self, now: Instant) -> Option<Vec<i8>> {
        let grid = self.grid.as_ref()?;
        let mut layers = Vec::new();
        let mut confirmed = Vec::new();
        for (k, cam) in self.cameras.iter().enumerate() {
            if !self.is_live(k, now) {
                continue;
            }
            let (Some(footprint), Some(latest)) = (&cam.footprint, &cam.latest) else {
                continue;
            };
            if latest.blocks.len() != footprint.blocks.len() {
                continue;
            }
            layers.push(Layer {
                footprint,
                blocks: &latest.blocks,
            });
            let since = latest.header.preamble.capture_time_ns - self.confirm_hold_ns;
            confirmed.extend(
                cam.confirmed
                    .iter()
                    .filter(|c| c.seen_ns >= since)
                    .map(|c| c.floor_m),
            );
        }
        Some(compose(grid, &self.params, &layers, &confirmed))
    }

    /// The live cameras' latest activity, for real-time planning.
    pub fn live(&self, now: Instant) -> Vec<Option<LiveCamera<'_>>> {
        self.cameras
            .iter()
            .enumerate()
            .map(|(k, cam)| {
                let latest = cam.latest.as_ref().filter(|_| self.is_live(k, now))?;
                Some(LiveCamera {
                    blocks: latest.header.block_grid(),
                    activity: &latest.blocks,
                })
            })
            .collect()
    }

    /// The newest live sample: its capture time (UTC ns) and t*.
    pub fn newest(&self, now: Instant) -> Option<(i64, u32)> {
        self.cameras
            .iter()
            .enumerate()
            .filter(|(k, _)| self.is_live(*k, now))
            .filter_map(|(_, c)| c.latest.as_ref())
            .map(|l| (l.header.preamble.capture_time_ns, l.header.t_star))
            .max_by_key(|(t, _)| *t)
    }

    /// The footprints of the cameras, for pictures.
    pub fn coverage(&self) -> Vec<&[u32]> {
        self.cameras
            .iter()
            .filter_map(|c| c.footprint.as_ref().map(|f| f.cell_block.as_slice()))
            .collect()
    }
}

/// Sets the NaN or infinite values of `b` to 0; true if there were any.
fn sanitise(b: &mut BlockActivity) -> bool {
    let mut any = false;
    for v in [
        &mut b.s1,
        &mut b.s2,
        &mut b.s1_dx,
        &mut b.s1_dy,
        &mut b.s2_dx,
        &mut b.s2_dy,
        &mut b.lt_mean,
        &mut b.lt_sigma,
        &mut b.present,
    ] {
        if !v.is_finite() {
            *v = 0.0;
            any = true;
        }
    }
    any
}

/// Counts `n` of camera `k`'s `what` (e.g. "activity blocks") that had NaN or
/// infinite values as rejected, and warns (rate-limited) when there were any: a
/// producer that sends them is broken, and the operator should know.
pub fn count_non_finite(cx: &mut Context, bridge: &Bridge, k: usize, what: &str, n: usize) {
    if n == 0 {
        return;
    }
    for _ in 0..n {
        cx.health.rejected();
    }
    let camera = bridge.cameras.get(k).map_or("?", |c| c.id.as_str());
    cx.warnings.warn("values", || {
        format!("camera '{camera}': {n} {what} with NaN or infinite values, ignored (counted as rejected)")
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use isochron_config::Config;
    use isochron_wire::{Preamble, Stream};

    /// The camera of the planning tests, over a 5 m × 4 m grid.
    const SITE: &str = concat!(
        "\n",
        include_str!("../../../shared/planning/tests/fixtures/floor_camera.toml"),
        r#"
[costmap]
resolution_m = 0.1
width_cells = 50
height_cells = 40
cost_scale = 0.1
weight_long_term = 0.0
confirm_radius_m = 0.15
confirm_hold_s = 2
stale_s = 5
"#
    );

    fn bridge() -> Bridge {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("site.toml");
        std::fs::write(&path, SITE).unwrap();
        let loaded = Config::load(&path).unwrap();
        let grid = MapGrid::from_config(&loaded).unwrap();
        Bridge::new(&loaded, grid).unwrap()
    }

    fn header(t_ns: i64) -> ActivityHeader {
        let mut preamble = Preamble::new::<BlockActivity>(
            Stream::Activity,
            CameraId::new("cam01").unwrap(),
            0,
            300,
        );
        preamble.capture_time_ns = t_ns;
        ActivityHeader {
            preamble,
            grid_w: 20,
            grid_h: 15,
            block_px: 16,
            frame_width: 320,
            frame_height: 240,
            t_star: 600,
            ..Default::default()
        }
    }

    #[test]
    fn activity_lands_on_its_cells_and_goes_stale() {
        let mut b = bridge();
        let t0 = Instant::now();
        // Nothing yet: all unknown.
        assert!(b.compose(t0).unwrap().iter().all(|&c| c == -1));
        // Block (10, 7): image x 160..176, y 112..128 → floor x 2.0..2.2, y 1.4..1.6.
        let mut blocks = vec![BlockActivity::default(); 300];
        blocks[7 * 20 + 10].s1 = 0.05;
        b.on_activity(0, &header(1_000 * NS_PER_S), &blocks, t0);
        let cells = b.compose(t0).unwrap();
        let grid = b.grid.unwrap();
        let hot: Vec<(u32, u32)> = (0..grid.len())
            .filter(|&k| cells[k] > 0)
            .map(|k| ((k % 50) as u32, (k / 50) as u32))
            .collect();
        assert_eq!(hot, vec![(20, 14), (21, 14), (20, 15), (21, 15)]);
        assert!(hot.iter().all(|&(i, j)| cells[grid.index(i, j)] == 50));
        // The camera sees x < 4 m, y < 3 m: cost 0 there, unknown beyond.
        assert_eq!(cells[grid.index(39, 29)], 0);
        assert_eq!(cells[grid.index(40, 29)], -1);
        assert_eq!(cells[grid.index(39, 30)], -1);
        assert_eq!(b.newest(t0), Some((1_000 * NS_PER_S, 600)));
        // Stale after 5 s without activity.
        let later = t0 + Duration::from_secs(6);
        assert!(b.compose(later).unwrap().iter().all(|&c| c == -1));
        assert!(b.live(later)[0].is_none());
    }

    /// A detections header of `n` boxes at capture time 1000 s.
    fn detections_at_1000_s(n: usize) -> DetectionHeader {
        let mut dh = DetectionHeader {
            preamble: Preamble::new::<Detection>(
                Stream::Detections,
                CameraId::new("cam01").unwrap(),
                0,
                n,
            ),
            ..Default::default()
        };
        dh.preamble.capture_time_ns = 1_000 * NS_PER_S;
        dh
    }

    /// A bridge that has seen one quiet second at capture time 1000 s (at `t0`), and
    /// those quiet blocks.
    fn quiet_bridge_at_1000_s(t0: Instant) -> (Bridge, Vec<BlockActivity>) {
        let mut b = bridge();
        let blocks = vec![BlockActivity::default(); 300];
        b.on_activity(0, &header(1_000 * NS_PER_S), &blocks, t0);
        (b, blocks)
    }

    /// A person whose feet are at image (105, 124).
    fn person_at_feet_105_124() -> Detection {
        Detection {
            x: 95.0,
            y: 60.0,
            w: 20.0,
            h: 64.0,
            score: 1.0,
            class: PERSON,
            ..Default::default()
        }
    }

    #[test]
    fn confirmed_people_raise_their_cells_for_a_while() {
        let t0 = Instant::now();
        let (mut b, blocks) = quiet_bridge_at_1000_s(t0);
        let dh = detections_at_1000_s(1);
        // Feet at image (105, 124) → floor (1.3125, 1.45): cell (13, 14).
        let person = person_at_feet_105_124();
        let chair = Detection {
            class: 56,
            ..person
        };
        assert_eq!(b.on_detections(0, &dh, &[person, chair]), (1, 0));
        let grid = b.grid.unwrap();
        let cells = b.compose(t0).unwrap();
        assert_eq!(
            cells[grid.index(13, 14)],
            98,
            "confirm_cost defaults to cap, 98"
        );
        assert_eq!(cells[grid.index(20, 20)], 0);
        // 3 s of capture time later the confirmation has expired.
        b.on_activity(0, &header(1_003 * NS_PER_S), &blocks, t0);
        assert_eq!(b.compose(t0).unwrap()[grid.index(13, 14)], 0);
    }

    #[test]
    fn a_detection_that_searched_there_and_found_nobody_ends_a_confirmation() {
        let t0 = Instant::now();
        let (mut b, _) = quiet_bridge_at_1000_s(t0);
        b.on_detections(0, &detections_at_1000_s(1), &[person_at_feet_105_124()]);
        let grid = b.grid.unwrap();
        let at_feet = |b: &Bridge| b.compose(t0).unwrap()[grid.index(13, 14)];
        assert_eq!(at_feet(&b), 98);
        // 1 s later a search of the left half finds nobody: the person's feet
        // (105, 124) are elsewhere, so they stay confirmed.
        let mut later = detections_at_1000_s(0);
        later.preamble.capture_time_ns += NS_PER_S;
        let left = DetectionHeader {
            roi_w: 50,
            roi_h: 240,
            ..later
        };
        b.on_detections(0, &left, &[]);
        assert_eq!(at_feet(&b), 98);
        // A search around them finds nobody: gone, long before `confirm_hold_s`.
        let around = DetectionHeader {
            roi_x: 80,
            roi_y: 40,
            roi_w: 60,
            roi_h: 100,
            ..later
        };
        b.on_detections(0, &around, &[]);
        assert_eq!(at_feet(&b), 0);
    }

    #[test]
    fn non_finite_activity_and_boxes_are_counted_and_read_as_zero() {
        let mut b = bridge();
        let t0 = Instant::now();
        let mut blocks = vec![BlockActivity::default(); 300];
        blocks[7 * 20 + 10].s1 = 0.05;
        blocks[0].s1 = f32::NAN;
        blocks[1].s2 = f32::INFINITY;
        blocks[2].lt_sigma = f32::NEG_INFINITY;
        assert_eq!(b.on_activity(0, &header(1_000 * NS_PER_S), &blocks, t0), 3);
        let kept = &b.cameras[0].latest.as_ref().unwrap().blocks;
        assert!(
            kept.iter()
                .all(|x| x.s1.is_finite() && x.s2.is_finite() && x.lt_sigma.is_finite())
        );
        assert_eq!(kept[7 * 20 + 10].s1, 0.05, "finite values are kept");
        let grid = b.grid.unwrap();
        assert_eq!(b.compose(t0).unwrap()[grid.index(20, 14)], 50);

        let dh = detections_at_1000_s(3);
        let person = person_at_feet_105_124();
        let nan = Detection {
            x: f32::NAN,
            ..person
        };
        let inf = Detection {
            h: f32::INFINITY,
            class: 56,
            ..person
        };
        assert_eq!(b.on_detections(0, &dh, &[person, nan, inf]), (1, 2));

        // The caller counts them as rejected.
        let mut cx = Context::new(isochron_runtime::topology::StageKind::Costmap, "", None);
        count_non_finite(&mut cx, &b, 0, "activity blocks", 3);
        count_non_finite(&mut cx, &b, 0, "detection boxes", 2);
        count_non_finite(&mut cx, &b, 0, "detection boxes", 0);
        assert_eq!(cx.health.status().rejected, 5);
    }
}
