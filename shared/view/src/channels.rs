//! The site as Foxglove channels: every topic, its well-known schema, and how an
//! isochron sample becomes a message. The live view and the recorder both publish
//! through [`SiteChannels`]; only the sink differs (a WebSocket server or an MCAP
//! file, attached to the same [`Context`]).
//!
//! | topic | schema | from |
//! |---|---|---|
//! | `/costmap` | `foxglove.Grid` (`cost`, int8, -1 unknown) in `costmap.frame_id` | the `activity` of every camera with floor points, composed as the bridge does (without the detections' confirmed people) |
//! | `/scene` | `foxglove.SceneUpdate` in `costmap.frame_id` | route segments and camera footprints on the floor (config), re-sent every 5 s |
//! | `/<camera>/activity` | `foxglove.Grid` (`s1`, `s2`, `lt_mean`, `present`, float32) in frame `<camera>`, cell = one block in pixels | `activity` |
//! | `/<camera>/events` | `foxglove.Log` | `events` |
//! | `/<camera>/detections` | `foxglove.ImageAnnotations` (boxes, skeletons, model and score, in the published image's pixels) | `detections` |
//! | `/<camera>/image` | `foxglove.CompressedImage` (JPEG) | `frames`, only with `view.frames = true`, at most `view.frame_rate_hz` |
//! | `/<camera>/motion` | `foxglove.Grid` (`density`, `dx`, `dy`, float32) in frame `<camera>`, cell = one block in pixels | `motion`, the newest sample at most every 0.5 s of capture time ([`MOTION_EVERY_NS`]) |
//! | `/<camera>/status/<stage>`, `/status/costmap` | `foxglove.Log` (warning when the service dropped or rejected samples since its last report) | each service's status report (every 5 s) |
//!
//! Message time (the MCAP log time) is the samples' capture time; a status report,
//! which has none, takes the newest capture time published so far (its wall time
//! before any), so it lands on the recording's timeline.

use std::collections::HashMap;
use std::sync::Arc;

use foxglove::messages::{
    Color, CompressedImage, Grid, ImageAnnotations, LinePrimitive, Log, PackedElementField, Point3,
    Pose, Quaternion, SceneEntity, SceneUpdate, TextPrimitive, Timestamp, Vector2, Vector3,
};
use foxglove::{Channel, Context};
use isochron_config::{LoadedConfig, ViewConfig};
use isochron_planning::cost::{CostParams, Layer, compose};
use isochron_planning::grid::MapGrid;
use isochron_planning::homography::Homography;
use isochron_planning::raster::Footprint;
use isochron_runtime::health::status_detail;
use isochron_runtime::topology::StageKind;
use isochron_wire::geometry::BlockGrid;
use isochron_wire::{
    ActivityHeader, ActivityKind, BlockActivity, BlockMotion, Detection, DetectionHeader,
    EventHeader, EventPhase, FrameHeader, MotionHeader, PixelFormat, StageStatus,
};

use crate::{annotations, jpeg};

/// Topic of the site's cost map.
pub const COSTMAP_TOPIC: &str = "/costmap";
/// Topic of the floor scene (segments, footprints).
pub const SCENE_TOPIC: &str = "/scene";
/// Scene updates are re-sent this often (capture time), for late joiners.
const SCENE_EVERY_NS: i64 = 5_000_000_000;
/// Motion grids are published at most this often per camera (capture time): 2 Hz.
pub const MOTION_EVERY_NS: i64 = 500_000_000;

/// The topic of a service's status: `/<camera>/status/<stage>`, or
/// `/status/<stage>` for a site-wide one.
pub fn status_topic(camera: &str, stage: StageKind) -> String {
    if camera.is_empty() {
        format!("/status/{stage}")
    } else {
        format!("/{camera}/status/{stage}")
    }
}

/// The topic of one camera's stream: `/<camera>/<what>`.
pub fn camera_topic(camera: &str, what: &str) -> String {
    format!("/{camera}/{what}")
}

/// Why the channels cannot be set up.
#[derive(Debug, thiserror::Error)]
pub enum ChannelError {
    /// The map grid of the config is unusable.
    #[error("{0}")]
    Grid(#[from] isochron_planning::grid::GridError),
    /// A camera's floor points define no mapping.
    #[error("camera {camera}: floor_points: {error}")]
    Floor {
        /// Camera id.
        camera: String,
        /// Why.
        error: isochron_planning::homography::HomographyError,
    },
}

/// One camera's channels and what the cost map needs of it.
struct CameraChannels {
    id: String,
    homography: Option<Homography>,
    mask: Vec<Vec<[f64; 2]>>,
    /// Built from the first activity sample's block grid.
    footprint: Option<(BlockGrid, Footprint)>,
    latest: Vec<BlockActivity>,
    activity: Channel<Grid>,
    events: Channel<Log>,
    detections: Channel<ImageAnnotations>,
    image: Option<Channel<CompressedImage>>,
    last_image_ns: Option<i64>,
    motion: Channel<Grid>,
    last_motion_ns: Option<i64>,
    /// Frame size, once known (for the published image's scale).
    frame_px: Option<(u32, u32)>,
}

/// Counts of messages published per topic.
pub type Counts = HashMap<String, u64>;

/// Every channel of a site, on one [`Context`].
pub struct SiteChannels {
    grid: Option<MapGrid>,
    params: CostParams,
    frame_id: String,
    view: ViewConfig,
    cameras: Vec<CameraChannels>,
    costmap: Option<Channel<Grid>>,
    scene: Channel<SceneUpdate>,
    last_scene_ns: Option<i64>,
    segments: Vec<(String, Vec<[f64; 2]>)>,
    /// Per service (`(camera, stage)`): its channel and last report.
    status: HashMap<(String, StageKind), (Channel<Log>, Option<StageStatus>)>,
    ctx: Arc<Context>,
    /// The newest capture time published.
    newest_ns: Option<i64>,
    counts: Counts,
}

impl SiteChannels {
    /// The channels of `loaded`'s site on `ctx` (images only if `view.frames`).
    pub fn new(loaded: &LoadedConfig, ctx: &Arc<Context>) -> Result<SiteChannels, ChannelError> {
        let config = &loaded.config;
        let grid = MapGrid::from_config(loaded)?;
        let mut cameras = Vec::new();
        for cam in &config.cameras {
            let homography = match Homography::of_camera(cam) {
                Ok(fit) => fit.map(|(h, _)| h),
                Err(error) => {
                    return Err(ChannelError::Floor {
                        camera: cam.id.clone(),
                        error,
                    });
                }
            };
            cameras.push(CameraChannels {
                id: cam.id.clone(),
                homography,
                mask: cam.mask.clone(),
                footprint: None,
                latest: Vec::new(),
                activity: ctx
                    .channel_builder(camera_topic(&cam.id, "activity"))
                    .build(),
                events: ctx.channel_builder(camera_topic(&cam.id, "events")).build(),
                detections: ctx
                    .channel_builder(camera_topic(&cam.id, "detections"))
                    .build(),
                image: config
                    .view
                    .frames
                    .then(|| ctx.channel_builder(camera_topic(&cam.id, "image")).build()),
                last_image_ns: None,
                motion: ctx.channel_builder(camera_topic(&cam.id, "motion")).build(),
                last_motion_ns: None,
                frame_px: cam.width.zip(cam.height),
            });
        }
        let costmap = (grid.is_some() && cameras.iter().any(|c| c.homography.is_some()))
            .then(|| ctx.channel_builder(COSTMAP_TOPIC).build());
        Ok(SiteChannels {
            grid,
            params: CostParams::from_config(&config.costmap),
            frame_id: config.costmap.frame_id.clone(),
            view: config.view.clone(),
            cameras,
            costmap,
            scene: ctx.channel_builder(SCENE_TOPIC).build(),
            last_scene_ns: None,
            segments: config
                .costmap
                .segments
                .iter()
                .filter_map(|s| Some((s.name.clone(), s.polygon_m.clone()?)))
                .collect(),
            status: HashMap::new(),
            ctx: ctx.clone(),
            newest_ns: None,
            counts: Counts::new(),
        })
    }

    /// Messages published so far, per topic.
    pub fn counts(&self) -> &Counts {
        &self.counts
    }

    /// Index of camera `id`.
    pub fn camera_index(&self, id: &str) -> Option<usize> {
        self.cameras.iter().position(|c| c.id == id)
    }

    fn count(&mut self, topic: &str) {
        *self.counts.entry(topic.to_string()).or_default() += 1;
    }

    fn seen(&mut self, t: i64) {
        self.newest_ns = Some(self.newest_ns.map_or(t, |n| n.max(t)));
    }

    /// True if camera `k` publishes a motion grid for a sample captured at `t`
    /// (the last one at least [`MOTION_EVERY_NS`] ago).
    pub fn wants_motion(&self, k: usize, t: i64) -> bool {
        self.cameras.get(k).is_some_and(|c| {
            c.last_motion_ns
                .is_none_or(|last| t - last >= MOTION_EVERY_NS || t < last)
        })
    }

    /// A `motion` sample of camera `k` (call when [`Self::wants_motion`]): density
    /// and flow per block.
    pub fn on_motion(&mut self, k: usize, h: &MotionHeader, blocks: &[BlockMotion]) {
        let t = h.preamble.capture_time_ns;
        let Some(cam) = self.cameras.get_mut(k) else {
            return;
        };
        cam.last_motion_ns = Some(t);
        let values = blocks.iter().map(|b| [b.density, b.dx, b.dy]);
        let grid = block_grid(
            t,
            &cam.id,
            (h.grid_w, h.block_px),
            ["density", "dx", "dy"],
            values,
        );
        cam.motion.log_with_time(&grid, nanos(t));
        let topic = camera_topic(&cam.id, "motion");
        self.count(&topic);
        self.seen(t);
    }

    /// The latest status report of `stage` for `camera` ("" for a site-wide
    /// stage): published as a log line when it is a new report.
    pub fn on_status(&mut self, camera: &str, stage: StageKind, s: &StageStatus) {
        let topic = status_topic(camera, stage);
        let (channel, last) = self
            .status
            .entry((camera.to_string(), stage))
            .or_insert_with(|| (self.ctx.channel_builder(topic.as_str()).build(), None));
        if last.is_some_and(|l| l.report_wall_ns == s.report_wall_ns && l.pid == s.pid) {
            return;
        }
        // Losses since the last report of the same process are a warning.
        let (dropped, rejected) = match last {
            Some(l) if l.pid == s.pid => (
                s.dropped.saturating_sub(l.dropped),
                s.rejected.saturating_sub(l.rejected),
            ),
            _ => (s.dropped, s.rejected),
        };
        let level = if dropped > 0 || rejected > 0 {
            foxglove::messages::log::Level::Warning
        } else {
            foxglove::messages::log::Level::Info
        };
        let t = self.newest_ns.unwrap_or(s.report_wall_ns);
        let service = if camera.is_empty() {
            format!("isochron-{stage}")
        } else {
            format!("isochron-{stage}/{camera}")
        };
        channel.log_with_time(
            &Log {
                timestamp: Some(timestamp(t)),
                level: level as i32,
                message: format!(
                    "pid {}: {} (+{dropped} dropped, +{rejected} rejected); {}",
                    s.pid,
                    s.counters(),
                    status_detail(s)
                ),
                name: service,
                file: String::new(),
                line: 0,
            },
            nanos(t),
        );
        *last = Some(*s);
        self.count(&topic);
    }

    /// An `activity` sample of camera `k`: its grid, and the cost map anew.
    pub fn on_activity(&mut self, k: usize, h: &ActivityHeader, blocks: &[BlockActivity]) {
        let t = h.preamble.capture_time_ns;
        let Some(cam) = self.cameras.get_mut(k) else {
            return;
        };
        cam.frame_px = Some((h.frame_width, h.frame_height));
        cam.latest.clear();
        cam.latest.extend_from_slice(blocks);
        let values = blocks.iter().map(|b| [b.s1, b.s2, b.lt_mean, b.present]);
        let fields = ["s1", "s2", "lt_mean", "present"];
        let grid = block_grid(t, &cam.id, (h.grid_w, h.block_px), fields, values);
        cam.activity.log_with_time(&grid, nanos(t));
        let topic = camera_topic(&cam.id, "activity");
        let blocks_grid = BlockGrid::new(h.frame_width, h.frame_height, h.block_px);
        if let (Some(g), Some(hom)) = (&self.grid, &cam.homography)
            && cam
                .footprint
                .as_ref()
                .is_none_or(|(b, _)| *b != blocks_grid)
        {
            cam.footprint = Some((
                blocks_grid,
                Footprint::build(g, hom, blocks_grid, &cam.mask),
            ));
        }
        self.count(&topic);
        self.seen(t);
        self.publish_costmap(t);
        self.publish_scene(t);
    }

    fn publish_costmap(&mut self, t: i64) {
        let (Some(g), Some(channel)) = (&self.grid, &self.costmap) else {
            return;
        };
        let layers: Vec<Layer> = self
            .cameras
            .iter()
            .filter_map(|c| {
                let (_, fp) = c.footprint.as_ref()?;
                (!c.latest.is_empty()).then_some(Layer {
                    footprint: fp,
                    blocks: &c.latest,
                })
            })
            .collect();
        let cells = compose(g, &self.params, &layers, &[]);
        let (s, c) = (g.yaw / 2.0).sin_cos();
        channel.log_with_time(
            &Grid {
                timestamp: Some(timestamp(t)),
                frame_id: self.frame_id.clone(),
                pose: Some(Pose {
                    position: Some(Vector3 {
                        x: g.origin_x,
                        y: g.origin_y,
                        z: 0.0,
                    }),
                    orientation: Some(Quaternion {
                        x: 0.0,
                        y: 0.0,
                        z: s,
                        w: c,
                    }),
                }),
                column_count: g.width,
                cell_size: Some(Vector2 {
                    x: g.resolution,
                    y: g.resolution,
                }),
                row_stride: g.width,
                cell_stride: 1,
                fields: vec![PackedElementField {
                    name: "cost".into(),
                    offset: 0,
                    r#type: foxglove::messages::packed_element_field::NumericType::Int8 as i32,
                }],
                data: cells.iter().map(|&v| v as u8).collect::<Vec<u8>>().into(),
            },
            nanos(t),
        );
        self.count(COSTMAP_TOPIC);
    }

    /// The floor scene (segments, footprints), at most every 5 s of capture time.
    fn publish_scene(&mut self, t: i64) {
        if self
            .last_scene_ns
            .is_some_and(|last| (0..SCENE_EVERY_NS).contains(&(t - last)))
        {
            return;
        }
        self.last_scene_ns = Some(t);
        let mut entities = Vec::new();
        for (name, polygon) in &self.segments {
            entities.push(floor_entity(
                &self.frame_id,
                t,
                &format!("segment/{name}"),
                polygon,
                Color {
                    r: 0.3,
                    g: 1.0,
                    b: 0.3,
                    a: 1.0,
                },
                name,
            ));
        }
        for cam in &self.cameras {
            let (Some((blocks, _)), Some(h)) = (&cam.footprint, &cam.homography) else {
                continue;
            };
            let outline = view_outline(h, blocks.frame_width, blocks.frame_height, &self.grid);
            if outline.len() >= 3 {
                entities.push(floor_entity(
                    &self.frame_id,
                    t,
                    &format!("footprint/{}", cam.id),
                    &outline,
                    Color {
                        r: 0.0,
                        g: 0.9,
                        b: 1.0,
                        a: 1.0,
                    },
                    &cam.id,
                ));
            }
        }
        self.scene.log_with_time(
            &SceneUpdate {
                deletions: Vec::new(),
                entities,
            },
            nanos(t),
        );
        self.count(SCENE_TOPIC);
    }

    /// An `events` sample of camera `k`, as a log line.
    pub fn on_event(&mut self, k: usize, h: &EventHeader, blocks: &[u32]) {
        let Some(cam) = self.cameras.get(k) else {
            return;
        };
        let t = h.preamble.capture_time_ns;
        let phase = if h.phase == EventPhase::Start as u32 {
            "start"
        } else {
            "end"
        };
        let kind = ActivityKind::from_u32(h.kind).map_or("?", |k| k.name());
        cam.events.log_with_time(
            &Log {
                timestamp: Some(timestamp(t)),
                level: foxglove::messages::log::Level::Info as i32,
                message: format!(
                    "event {} {phase}: zone {} {kind}, peak {:.3} over threshold {:.3}, {} blocks",
                    h.event_id,
                    h.zone_name(),
                    h.peak,
                    h.threshold,
                    blocks.len()
                ),
                name: format!("isochron-gate/{}", cam.id),
                file: String::new(),
                line: 0,
            },
            nanos(t),
        );
        let topic = camera_topic(&cam.id, "events");
        self.count(&topic);
    }

    /// A `detections` sample of camera `k`: boxes, skeletons (where the model
    /// gave keypoints), model names and scores on the image.
    pub fn on_detections(&mut self, k: usize, h: &DetectionHeader, dets: &[Detection]) {
        let Some(cam) = self.cameras.get(k) else {
            return;
        };
        let t = h.preamble.capture_time_ns;
        let f = cam.frame_px.map_or(1, |(w, hgt)| {
            jpeg::scale_factor(w, hgt, self.view.frame_max_px)
        }) as f64;
        cam.detections
            .log_with_time(&annotations::detections(dets, f, timestamp(t)), nanos(t));
        let topic = camera_topic(&cam.id, "detections");
        self.count(&topic);
    }

    /// True if camera `k` publishes an image for a frame captured at `t` (images on,
    /// and the last one at least 1 / `frame_rate_hz` ago).
    pub fn wants_frame(&self, k: usize, t: i64) -> bool {
        let every = (1e9 / self.view.frame_rate_hz) as i64;
        self.cameras.get(k).is_some_and(|c| {
            c.image.is_some()
                && c.last_image_ns
                    .is_none_or(|last| t - last >= every || t < last)
        })
    }

    /// A `frames` sample of camera `k` (call when [`Self::wants_frame`]): downscaled,
    /// JPEG. False if no image was published (images off, a frame JPEG cannot hold).
    pub fn on_frame(&mut self, k: usize, h: &FrameHeader, pixels: &[u8]) -> bool {
        let quality = self.view.jpeg_quality;
        let max_px = self.view.frame_max_px;
        let Some(cam) = self.cameras.get_mut(k) else {
            return false;
        };
        let Some(channel) = &cam.image else {
            return false;
        };
        let t = h.preamble.capture_time_ns;
        let Some(format) = PixelFormat::from_u32(h.pixel_format) else {
            return false;
        };
        let Some(data) = jpeg::encode(pixels, h.width, h.height, h.stride, format, max_px, quality)
        else {
            return false;
        };
        cam.last_image_ns = Some(t);
        cam.frame_px = Some((h.width, h.height));
        channel.log_with_time(
            &CompressedImage {
                timestamp: Some(timestamp(t)),
                frame_id: cam.id.clone(),
                data: data.into(),
                format: "jpeg".into(),
            },
            nanos(t),
        );
        let topic = camera_topic(&cam.id, "image");
        self.count(&topic);
        true
    }
}

/// A camera's per-block grid in its own frame `frame_id` (one cell per block of
/// `block_px` pixels, `grid_w` blocks a row): `N` float32 fields, `names`, per
/// block from `values`.
fn block_grid<const N: usize>(
    t: i64,
    frame_id: &str,
    (grid_w, block_px): (u32, u32),
    names: [&str; N],
    values: impl Iterator<Item = [f32; N]>,
) -> Grid {
    let data: Vec<u8> = values.flatten().flat_map(f32::to_le_bytes).collect();
    let bp = block_px as f64;
    let cell = 4 * N as u32;
    Grid {
        timestamp: Some(timestamp(t)),
        frame_id: frame_id.into(),
        pose: Some(identity()),
        column_count: grid_w,
        cell_size: Some(Vector2 { x: bp, y: bp }),
        row_stride: grid_w * cell,
        cell_stride: cell,
        fields: names
            .into_iter()
            .zip((0..).step_by(4))
            .map(|(name, offset)| PackedElementField {
                name: name.into(),
                offset,
                r#type: foxglove::messages::packed_element_field::NumericType::Float32 as i32,
            })
            .collect(),
        data: data.into(),
    }
}

fn timestamp(ns: i64) -> Timestamp {
    let ns = ns.max(0);
    Timestamp::new(
        (ns / 1_000_000_000).min(u32::MAX as i64) as u32,
        (ns % 1_000_000_000) as u32,
    )
}

fn nanos(ns: i64) -> u64 {
    ns.max(0) as u64
}

fn identity() -> Pose {
    Pose {
        position: Some(Vector3 {
            x: 0.0,
            y: 0.0,
            z: 0.0,
        }),
        orientation: Some(Quaternion {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        }),
    }
}

/// A closed floor outline with a label, as a scene entity.
fn floor_entity(
    frame_id: &str,
    t: i64,
    id: &str,
    polygon: &[[f64; 2]],
    color: Color,
    label: &str,
) -> SceneEntity {
    let n = polygon.len().max(1) as f64;
    let (cx, cy) = (
        polygon.iter().map(|p| p[0]).sum::<f64>() / n,
        polygon.iter().map(|p| p[1]).sum::<f64>() / n,
    );
    SceneEntity {
        timestamp: Some(timestamp(t)),
        frame_id: frame_id.into(),
        id: id.into(),
        lines: vec![LinePrimitive {
            r#type: foxglove::messages::line_primitive::Type::LineLoop as i32,
            pose: Some(identity()),
            thickness: 0.08,
            points: polygon
                .iter()
                .map(|p| Point3 {
                    x: p[0],
                    y: p[1],
                    z: 0.02,
                })
                .collect(),
            color: Some(color),
            ..Default::default()
        }],
        texts: vec![TextPrimitive {
            pose: Some(Pose {
                position: Some(Vector3 {
                    x: cx,
                    y: cy,
                    z: 0.3,
                }),
                orientation: identity().orientation,
            }),
            billboard: true,
            font_size: 14.0,
            scale_invariant: true,
            color: Some(color),
            text: label.into(),
        }],
        ..Default::default()
    }
}

/// The floor outline of a camera's view: its frame border mapped to the floor,
/// where it maps and lies on the map grid.
fn view_outline(h: &Homography, w: u32, hgt: u32, grid: &Option<MapGrid>) -> Vec<[f64; 2]> {
    let (w, hgt) = (w as f64, hgt as f64);
    let mut border = Vec::new();
    const STEPS: usize = 32;
    for i in 0..STEPS {
        border.push([w * i as f64 / STEPS as f64, hgt]);
    }
    for i in 0..STEPS {
        border.push([w, hgt * (1.0 - i as f64 / STEPS as f64)]);
    }
    for i in 0..STEPS {
        border.push([w * (1.0 - i as f64 / STEPS as f64), 0.0]);
    }
    for i in 0..STEPS {
        border.push([0.0, hgt * i as f64 / STEPS as f64]);
    }
    border
        .into_iter()
        .filter_map(|p| h.apply(p))
        .filter(|p| grid.as_ref().is_none_or(|g| g.cell_of(*p).is_some()))
        .collect()
}
