//! Configuration: one TOML file describes a site (its cameras and every stage).
//!
//! [`Config::load`] parses and validates; every error names the file, the line, the
//! key, and what was expected, e.g.
//! `config/site.toml:12: camera[0].fps: expected a number > 0, found -3`.
//! Each key is documented on its field with its default; units are in the names
//! (`_s`, `_px`, `_days`).

use std::fmt;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::names::is_valid_prefix;
use crate::wire::{PixelFormat, is_valid_camera_id};

/// A configuration error located in its file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub struct ConfigError {
    /// The file.
    pub file: PathBuf,
    /// 1-based line, when known.
    pub line: Option<usize>,
    /// Dotted key path (`camera[0].fps`), when known.
    pub key: Option<String>,
    /// What is wrong and what was expected.
    pub message: String,
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file.display())?;
        if let Some(line) = self.line {
            write!(f, ":{line}")?;
        }
        if let Some(key) = &self.key {
            write!(f, ": key `{key}`")?;
        }
        write!(f, ": {}", self.message)
    }
}

/// A semantic error found by validation, before it is located in the file.
#[derive(Debug, Clone, PartialEq)]
pub struct Invalid {
    /// Dotted key path, e.g. `camera[0].fps`.
    pub key: String,
    /// What is wrong and what was expected.
    pub message: String,
}

impl Invalid {
    /// An error at `key`.
    pub fn new(key: impl Into<String>, message: impl Into<String>) -> Self {
        Invalid {
            key: key.into(),
            message: message.into(),
        }
    }
}

/// The whole configuration of one site.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    /// Site-wide settings.
    pub site: SiteConfig,
    /// Shared-memory transport settings.
    pub ipc: IpcConfig,
    /// The cameras (`[[camera]]` tables); at least one.
    #[serde(rename = "camera")]
    pub cameras: Vec<CameraConfig>,
    /// The motion stage.
    pub motion: MotionConfig,
    /// The cascade filter and long-term store.
    pub cascade: CascadeConfig,
    /// The event gate and its detector.
    pub gate: GateConfig,
    /// The cost map on the robots' floor, its ROS 2 output, and path planning.
    pub costmap: CostmapConfig,
}

/// `[gate]`: events from short-term activity, and the detector they gate.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GateConfig {
    /// An event starts when a zone's S1 or S2 sum exceeds the long-term mean plus
    /// this many standard deviations (once the model is warm). Default 3.
    pub k_sigma: f32,
    /// Threshold on a zone's activity sum while the long-term model is cold (fewer
    /// than `cascade.warm_days` days at this t*). Default 0.5.
    pub floor: f32,
    /// Lowest threshold once the model is warm (a quiet night has sigma ≈ 0).
    /// Default 0.2.
    pub min_threshold: f32,
    /// In-place activity counts a block only where its own S1 is at least this
    /// (density): a place with lasting activity. People walking by leave each
    /// block a small, decaying S1 tail that, summed over a zone, would otherwise
    /// look like in-place activity. Default 0.05.
    pub in_place_block_min: f32,
    /// An event ends after its activity stayed below the threshold this long,
    /// seconds. Default 3.
    pub hold_s: f64,
    /// Frames the detector runs on per event (the first when the event starts, then
    /// one per later second). Default 1.
    pub detect_per_event: u32,
    /// Instead: one detection every this many seconds while an event lasts.
    pub detect_every_s: Option<f64>,
    /// Recent frames kept for the detector: the last frame of each of the latest
    /// this many seconds (a detection looks at the last frame of a second). Default 8.
    pub ring_frames: usize,
    /// The detector.
    pub detector: DetectorConfig,
}

impl Default for GateConfig {
    fn default() -> Self {
        GateConfig {
            k_sigma: 3.0,
            floor: 0.5,
            min_threshold: 0.2,
            in_place_block_min: 0.05,
            hold_s: 3.0,
            detect_per_event: 1,
            detect_every_s: None,
            ring_frames: 8,
            detector: DetectorConfig::default(),
        }
    }
}

/// `[gate.detector]`: OpenCV's HOG people detector (default, needs no download),
/// or an ONNX model through OpenCV's dnn module when `model` is set.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DetectorConfig {
    /// ONNX model file (a YOLOv5/YOLOv8 export; see the README); relative to the
    /// config file. Default: none (HOG).
    pub model: Option<PathBuf>,
    /// Square input size of the ONNX model, pixels. Default 640.
    pub input_px: u32,
    /// Lowest score of a kept detection (ONNX: class score; HOG: SVM margin).
    /// Default 0.4 (ONNX) — HOG uses `hog_hit_threshold`.
    pub score_threshold: f32,
    /// Overlap (IoU) above which the weaker of two boxes is suppressed. Default 0.45.
    pub nms_threshold: f32,
    /// HOG: upscale frames by this factor first (its window finds people ≥ ~100 px
    /// tall). Default 1.0.
    pub hog_upscale: f64,
    /// HOG: SVM hit threshold. Default 0.
    pub hog_hit_threshold: f64,
    /// Detection jobs that may wait for the worker; more are dropped and counted.
    /// Default 2.
    pub queue: usize,
    /// Detections that run at once on the site, all cameras and gate processes
    /// together; a job that finds every one busy is dropped and counted (a
    /// lossless replay waits instead). Default 1.
    pub concurrent: usize,
}

impl Default for DetectorConfig {
    fn default() -> Self {
        DetectorConfig {
            model: None,
            input_px: 640,
            score_threshold: 0.4,
            nms_threshold: 0.45,
            hog_upscale: 1.0,
            hog_hit_threshold: 0.0,
            queue: 2,
            concurrent: 1,
        }
    }
}

/// Motion-feature backend.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum MotionBackend {
    /// The fused, vectorised motion-flow kernel (temporal difference + normal flow).
    MotionFlow,
    /// OpenCV DIS optical flow reduced to the same block features (slower).
    Dis,
}

/// `[motion]`: motion features per block.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MotionConfig {
    /// Block edge in pixels. Default 16.
    pub block_px: u32,
    /// A pixel moves when its temporal difference (after removing the frame's mean
    /// brightness change) is at least this, grey levels. Default 15.
    pub diff_threshold: u8,
    /// ... and its spatial gradient |Gx|+|Gy| is at least this (central differences
    /// of the sum of both frames: 4 × the per-frame derivative, 0..=1020). Default 8.
    pub gradient_threshold: u16,
    /// ... and its edge moved at least this far, pixels per frame (a lower bound of
    /// the normal flow, `4·|It| / (|Gx|+|Gy|)`): strong static edges that shimmer by
    /// a fraction of a pixel (camera vibration, codec noise) do not count. 0 turns
    /// the test off. Default 0.5.
    pub min_flow_px: f32,
    /// A block counts as moving when its density is at least this. Default 0.02
    /// (with the defaults above, on PETS 2009 S2.L1: 91 % of moving people's blocks
    /// active, 99.2 % of blocks away from people quiet).
    pub density_threshold: f32,
    /// A frame is an illumination change when at least this fraction of blocks
    /// move at once with no coherent direction. Default 0.5.
    pub illumination_fraction: f32,
    /// Backend: `"motion-flow"` (default) or `"dis"`.
    pub backend: MotionBackend,
}

impl Default for MotionConfig {
    fn default() -> Self {
        MotionConfig {
            block_px: 16,
            diff_threshold: 15,
            gradient_threshold: 8,
            min_flow_px: 0.5,
            density_threshold: 0.02,
            illumination_fraction: 0.5,
            backend: MotionBackend::MotionFlow,
        }
    }
}

/// `[cascade]`: the cascade of temporal filters (DESIGN.md section 3). Filters are
/// configured by their 10 %-decay duration T and rate r; α = 0.1^(1/(r·T)).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CascadeConfig {
    /// T of F_L1, the high-pass at frame rate, seconds. Default 1800 (30 min).
    pub t_l1_s: f64,
    /// T of F_L2, the isochronal low-pass, in cycles (days). Default 10.
    pub t_l2_days: f64,
    /// T of F_S1, the in-place low-pass at 1 Hz, seconds. Default 20.
    pub t_s1_s: f64,
    /// Frame rate r for F_L1 (frames/s); default: measured from header timestamps.
    pub frame_rate: Option<f64>,
    /// Isochronal cycle: `"daily"` (default) or `"weekly"`.
    pub cycle: crate::clock::Cycle,
    /// A minute updates F_L2 only if it got at least this fraction of the frames
    /// expected at rate r (gaps teach nothing). Default 0.8.
    pub min_coverage: f64,
    /// Days of data a minute bin needs before the long-term model counts as warm.
    /// Default 3.
    pub warm_days: u32,
}

impl Default for CascadeConfig {
    fn default() -> Self {
        CascadeConfig {
            t_l1_s: 1800.0,
            t_l2_days: 10.0,
            t_s1_s: 20.0,
            frame_rate: None,
            cycle: crate::clock::Cycle::Daily,
            min_coverage: 0.8,
            warm_days: 3,
        }
    }
}

/// `[site]`: settings for the whole site.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SiteConfig {
    /// Name for people and logs. Default `"site"`.
    pub name: String,
    /// IANA time zone of the site, used for isochronal time t*. Default `"UTC"`.
    pub time_zone: String,
    /// Start of every iceoryx2 service name. Default `"isochron"`.
    pub service_prefix: String,
    /// Directory for state (the long-term store). Default `"/var/lib/isochron"`;
    /// relative paths are relative to the config file.
    pub state_dir: PathBuf,
    /// Cameras one process of a per-camera stage serves, when `isochron up` starts
    /// the group (each camera on its own thread; see the README's "Scale"). Default
    /// 1: one process per camera and stage.
    pub cameras_per_process: usize,
}

impl Default for SiteConfig {
    fn default() -> Self {
        SiteConfig {
            name: "site".into(),
            time_zone: "UTC".into(),
            service_prefix: crate::names::DEFAULT_PREFIX.into(),
            state_dir: PathBuf::from("/var/lib/isochron"),
            cameras_per_process: 1,
        }
    }
}

/// `[ipc]`: how streams use shared memory. Every process of a site must use the same
/// values (they are part of each iceoryx2 service's identity).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IpcConfig {
    /// Most subscribers per stream (consumers + taps). Default 5.
    pub max_subscribers: usize,
    /// Frames a `frames` subscriber may have queued. Default 3.
    pub frame_buffer: usize,
    /// Samples a subscriber of the small streams may have queued. Default 16.
    pub stream_buffer: usize,
    /// Lossless delivery: a publisher waits for slow subscribers instead of
    /// overwriting their oldest sample. Default `false` (live: never block a
    /// producer); `isochron replay --speed max` turns it on.
    pub lossless: bool,
    /// In lossless mode, how long a publisher waits for a stalled subscriber before
    /// it drops that subscriber's sample and logs it. Default 10.
    pub lossless_timeout_s: f64,
}

impl Default for IpcConfig {
    fn default() -> Self {
        IpcConfig {
            max_subscribers: 5,
            frame_buffer: 3,
            stream_buffer: 16,
            lossless: false,
            lossless_timeout_s: 10.0,
        }
    }
}

/// Playback speed of a file source.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Speed {
    /// As fast as consumers keep up, without dropping a frame.
    Max,
    /// A multiple of the file's frame rate (1 = real time).
    Factor(f64),
}

impl Speed {
    /// Parses `max` or a positive number.
    pub fn parse(s: &str) -> Option<Speed> {
        if s.eq_ignore_ascii_case("max") {
            return Some(Speed::Max);
        }
        s.parse::<f64>()
            .ok()
            .filter(|f| f.is_finite() && *f > 0.0)
            .map(Speed::Factor)
    }
}

impl fmt::Display for Speed {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Speed::Max => f.write_str("max"),
            Speed::Factor(x) => write!(f, "{x}"),
        }
    }
}

impl Serialize for Speed {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            Speed::Max => s.serialize_str("max"),
            Speed::Factor(x) => s.serialize_f64(*x),
        }
    }
}

impl<'de> Deserialize<'de> for Speed {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Raw {
            Number(f64),
            Text(String),
        }
        let bad = || serde::de::Error::custom("expected \"max\" or a number > 0");
        match Raw::deserialize(d)? {
            Raw::Number(x) if x.is_finite() && x > 0.0 => Ok(Speed::Factor(x)),
            Raw::Number(_) => Err(bad()),
            Raw::Text(s) => Speed::parse(&s).ok_or_else(bad),
        }
    }
}

/// A polygon in frame pixel coordinates (analysis size), as `[[x, y], ...]`.
pub type Polygon = Vec<[f64; 2]>;

/// A named region of a camera's view.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ZoneConfig {
    /// Zone name (at most 32 bytes), unique per camera.
    pub name: String,
    /// Outline in frame pixels, at least 3 points.
    pub polygon: Polygon,
}

/// `[[camera]]`: one fixed camera.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraConfig {
    /// Camera id: 1..=24 characters of `[A-Za-z0-9_-]`, unique on the site.
    pub id: String,
    /// Video source: a file path (relative to the config file), a V4L2 device
    /// (`/dev/video0` or `v4l2:0`), an `rtsp://`/`http://`/`https://` URL, or a
    /// GStreamer pipeline ending in `appsink` (`gst:...`).
    pub source: String,
    /// Analysis width in pixels; default: the source's width.
    #[serde(default)]
    pub width: Option<u32>,
    /// Analysis height in pixels; default: the source's height.
    #[serde(default)]
    pub height: Option<u32>,
    /// Published pixel format, `"gray8"` (default) or `"bgr8"`.
    #[serde(default = "default_pixel_format")]
    pub pixel_format: String,
    /// Frame rate of a file source, overriding what the container states.
    #[serde(default)]
    pub fps: Option<f64>,
    /// Capture time of a file's first frame (RFC 3339); default: when capture starts.
    #[serde(default)]
    pub start: Option<String>,
    /// Playback speed of a file source: `"max"` or a factor. Default 1 (real time).
    #[serde(default = "default_speed")]
    pub speed: Speed,
    /// Play a file source again from the start when it ends. Default `false`.
    #[serde(default, rename = "loop")]
    pub loop_file: bool,
    /// File sources only: decode the first this many frames once into memory and
    /// publish them in a loop, with proper timestamps — a source that costs no
    /// decoding, to measure the stages apart from the decoder. Cameras of one
    /// capture process with the same file share the decoded frames.
    #[serde(default)]
    pub preload_frames: Option<u32>,
    /// First reconnect delay after a live source drops out, seconds. Default 0.5.
    #[serde(default = "default_reconnect_initial_s")]
    pub reconnect_initial_s: f64,
    /// Longest reconnect delay (the backoff doubles up to it), seconds. Default 30.
    #[serde(default = "default_reconnect_max_s")]
    pub reconnect_max_s: f64,
    /// Regions that never matter (polygons in frame pixels); their blocks report no
    /// motion.
    #[serde(default)]
    pub mask: Vec<Polygon>,
    /// Zones for events; default one zone `"all"` covering the whole view.
    #[serde(default, rename = "zone")]
    pub zones: Vec<ZoneConfig>,
    /// Where the view lies on the floor: at least 4 pairs of an image point and the
    /// same point on the floor, `{ image_px = [x, y], floor_m = [x, y] }`; the cost
    /// map bridge fits a homography to them (least squares for more than 4). Image
    /// points are frame pixels at the analysis size (like masks and zones), floor
    /// points metres in the robots' map frame. No two points alike and no three on
    /// a line (for exactly 4). Default: none — the camera is not on the cost map.
    #[serde(default)]
    pub floor_points: Vec<FloorPoint>,
}

/// One image ↔ floor correspondence of a camera (`[[camera]].floor_points`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FloorPoint {
    /// The point in the image, `[x, y]`, frame pixels at the analysis size.
    pub image_px: [f64; 2],
    /// The same point on the floor, `[x, y]`, metres in the robots' map frame.
    pub floor_m: [f64; 2],
}

/// `[costmap]`: block activity on the robots' map as a ROS 2 `OccupancyGrid`
/// (DESIGN.md section 5), snapshots, and path planning on segments and routes.
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
    /// Rotation of the grid about z, radians. Default 0.
    pub origin_yaw_rad: Option<f64>,
    /// `header.frame_id` of the grid. Default `"map"`.
    pub frame_id: String,
    /// ROS 2 topic of the grid (`nav_msgs/msg/OccupancyGrid`, reliable,
    /// transient-local). Default `"/isochron/activity_costmap"`.
    pub topic: String,
    /// ROS 2 topic of the deltas (`map_msgs/msg/OccupancyGridUpdate`). Default
    /// `<topic>_updates`, where Nav2's StaticLayer looks for them.
    pub updates_topic: Option<String>,
    /// Publish rate, Hz. Default 1.
    pub publish_hz: f64,
    /// The full grid is republished at least this often, seconds, while deltas went
    /// out since the last one (so a late joiner's grid is at most this old);
    /// between, only the changed rectangle goes out. Default 10.
    pub full_every_s: f64,
    /// DDS domain (ROS_DOMAIN_ID), 0 to 232. Default: `$ROS_DOMAIN_ID`, else 0.
    pub ros_domain_id: Option<u16>,
    /// IP addresses of the network interfaces DDS may use, e.g. `["127.0.0.1"]` to
    /// stay on this machine. Default: all (loopback only when `ROS_LOCALHOST_ONLY=1`).
    pub dds_interfaces: Vec<String>,
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
    /// Highest cost activity can give a cell, 1 to 100 (Nav2 reads 100 as lethal,
    /// the paper's "people cost as much as walls"; lower it to make busy areas
    /// expensive but passable). Default 100.
    pub cap: u8,
    /// A person the detector confirmed raises the cells within this radius of their
    /// feet, metres. Default 0.5.
    pub confirm_radius_m: f64,
    /// ... for this long after the detected frame (capture time), seconds. Default 5.
    pub confirm_hold_s: f64,
    /// ... to at least this cost, 0 to 100. Default: `cap`.
    pub confirm_cost: Option<u8>,
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
    /// Path segments (`[[costmap.segment]]`).
    #[serde(rename = "segment")]
    pub segments: Vec<SegmentConfig>,
    /// Routes (`[[costmap.route]]`).
    #[serde(rename = "route")]
    pub routes: Vec<RouteConfig>,
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
            publish_hz: 1.0,
            full_every_s: 10.0,
            ros_domain_id: None,
            dds_interfaces: Vec::new(),
            weight_in_place: 1.0,
            weight_moving: 1.0,
            weight_long_term: 0.5,
            cost_scale: 0.2,
            cap: 100,
            confirm_radius_m: 0.5,
            confirm_hold_s: 5.0,
            confirm_cost: None,
            stale_s: 10.0,
            snapshot_dir: None,
            snapshot_every_s: 0.0,
            snapshot_keep: 100,
            w1: 1.0,
            w2: 1.0,
            min_activity: 0.0,
            segments: Vec::new(),
            routes: Vec::new(),
        }
    }
}

impl CostmapConfig {
    /// True if a grid is configured (`map_yaml` or `width_cells`).
    pub fn has_grid(&self) -> bool {
        self.map_yaml.is_some() || self.width_cells.is_some()
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

    /// The segment named `name`.
    pub fn segment(&self, name: &str) -> Option<&SegmentConfig> {
        self.segments.iter().find(|s| s.name == name)
    }

    /// The route named `name`.
    pub fn route(&self, name: &str) -> Option<&RouteConfig> {
        self.routes.iter().find(|r| r.name == name)
    }
}

/// `[[costmap.segment]]`: a path segment p — a floor polygon, or a camera's zone.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SegmentConfig {
    /// Name (1 to 32 bytes), unique.
    pub name: String,
    /// Outline on the floor, `[[x, y], ...]`, metres in the map frame (at least 3
    /// points); its blocks are those of every camera whose centre lands inside.
    #[serde(default)]
    pub polygon_m: Option<Vec<[f64; 2]>>,
    /// Instead of `polygon_m`: a camera ...
    #[serde(default)]
    pub camera: Option<String>,
    /// ... and one of its zones (`"all"` for a camera without zones).
    #[serde(default)]
    pub zone: Option<String>,
}

/// `[[costmap.route]]`: a route, the ordered path segments a robot passes.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RouteConfig {
    /// Name (1 to 32 bytes), unique.
    pub name: String,
    /// Segment names, in the order the robot passes them (at least one).
    pub segments: Vec<String>,
}

fn default_pixel_format() -> String {
    "gray8".into()
}
fn default_speed() -> Speed {
    Speed::Factor(1.0)
}
fn default_reconnect_initial_s() -> f64 {
    0.5
}
fn default_reconnect_max_s() -> f64 {
    30.0
}

/// What kind of source a camera's `source` names.
#[derive(Debug, Clone, PartialEq)]
pub enum SourceKind {
    /// A video file.
    File(PathBuf),
    /// A V4L2 device index.
    Device(i32),
    /// A network URL (RTSP/HTTP).
    Url(String),
    /// A GStreamer pipeline.
    GStreamer(String),
}

impl SourceKind {
    /// True for sources that run out (files).
    pub fn is_file(&self) -> bool {
        matches!(self, SourceKind::File(_))
    }
}

impl CameraConfig {
    /// Classifies `source`; relative file paths are resolved against `base_dir`.
    pub fn source_kind(&self, base_dir: &Path) -> SourceKind {
        let s = self.source.trim();
        if let Some(pipeline) = s.strip_prefix("gst:") {
            return SourceKind::GStreamer(pipeline.trim().to_string());
        }
        if let Some(index) = s.strip_prefix("v4l2:")
            && let Ok(i) = index.parse()
        {
            return SourceKind::Device(i);
        }
        if let Some(index) = s.strip_prefix("/dev/video")
            && let Ok(i) = index.parse()
        {
            return SourceKind::Device(i);
        }
        if [
            "rtsp://", "rtsps://", "http://", "https://", "udp://", "tcp://",
        ]
        .iter()
        .any(|p| s.starts_with(p))
        {
            return SourceKind::Url(s.to_string());
        }
        let path = PathBuf::from(s);
        SourceKind::File(if path.is_absolute() {
            path
        } else {
            base_dir.join(path)
        })
    }

    /// The configured pixel format (valid after validation).
    pub fn format(&self) -> PixelFormat {
        if self.pixel_format == "bgr8" {
            PixelFormat::Bgr8
        } else {
            PixelFormat::Gray8
        }
    }

    /// Zones, with the default whole-view zone when none are configured.
    pub fn zones_or_default(&self, width: u32, height: u32) -> Vec<ZoneConfig> {
        if !self.zones.is_empty() {
            return self.zones.clone();
        }
        let (w, h) = (width as f64, height as f64);
        vec![ZoneConfig {
            name: "all".into(),
            polygon: vec![[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]],
        }]
    }
}

/// A loaded configuration and where it came from.
#[derive(Debug, Clone)]
pub struct LoadedConfig {
    /// The validated configuration.
    pub config: Config,
    /// The file it was read from.
    pub path: PathBuf,
}

impl LoadedConfig {
    /// Directory relative paths in the config are resolved against.
    pub fn base_dir(&self) -> PathBuf {
        self.path
            .parent()
            .map(Path::to_path_buf)
            .unwrap_or_else(|| PathBuf::from("."))
    }

    /// The camera with `id`, or an error listing the configured ones.
    pub fn camera(&self, id: &str) -> Result<&CameraConfig, String> {
        self.config
            .cameras
            .iter()
            .find(|c| c.id == id)
            .ok_or_else(|| {
                let ids: Vec<_> = self.config.cameras.iter().map(|c| c.id.as_str()).collect();
                format!(
                    "no camera '{id}' in {} (configured: {})",
                    self.path.display(),
                    ids.join(", ")
                )
            })
    }

    /// The config with every relative file path (detector model, map YAML,
    /// snapshot and state directories, camera files) made absolute, so that it
    /// means the same when written elsewhere (as `isochron replay` does).
    pub fn with_absolute_paths(&self) -> Config {
        let base = self.base_dir();
        let absolute = |p: &mut PathBuf| {
            if p.is_relative() {
                *p = base.join(&*p);
            }
        };
        let mut config = self.config.clone();
        absolute(&mut config.site.state_dir);
        for path in [
            config.gate.detector.model.as_mut(),
            config.costmap.map_yaml.as_mut(),
            config.costmap.snapshot_dir.as_mut(),
        ]
        .into_iter()
        .flatten()
        {
            absolute(path);
        }
        for camera in &mut config.cameras {
            if let SourceKind::File(path) = camera.source_kind(&base) {
                camera.source = path.to_string_lossy().into_owned();
            }
        }
        config
    }

    /// `site.state_dir`, resolved against the config file's directory.
    pub fn state_dir(&self) -> PathBuf {
        let dir = &self.config.site.state_dir;
        if dir.is_absolute() {
            dir.clone()
        } else {
            self.base_dir().join(dir)
        }
    }
}

impl Config {
    /// Reads, parses and validates a config file.
    pub fn load(path: &Path) -> Result<LoadedConfig, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|e| ConfigError {
            file: path.to_path_buf(),
            line: None,
            key: None,
            message: format!("cannot read the config file: {e}"),
        })?;
        let config = Config::parse(&text, path)?;
        Ok(LoadedConfig {
            config,
            path: path.to_path_buf(),
        })
    }

    /// Parses and validates TOML text; `path` is only used in errors.
    pub fn parse(text: &str, path: &Path) -> Result<Config, ConfigError> {
        let located = |line: Option<usize>, key: Option<String>, message: String| ConfigError {
            file: path.to_path_buf(),
            line,
            key,
            message,
        };
        let deserializer = toml::Deserializer::parse(text).map_err(|e| {
            located(
                e.span().map(|s| line_at(text, s.start)),
                None,
                e.message().to_string(),
            )
        })?;
        let config: Config = serde_path_to_error::deserialize(deserializer).map_err(|e| {
            let key = e.path().to_string();
            let inner = e.into_inner();
            let line = inner
                .span()
                .map(|s| line_at(text, s.start))
                .or_else(|| line_of_key(text, &key));
            let key = (key != ".").then_some(key);
            located(line, key, inner.message().to_string())
        })?;
        if let Err(invalid) = config.validate() {
            let line = line_of_key(text, &invalid.key).or_else(|| {
                // The key is absent (a default was invalid or a required section is
                // missing): point at its table instead.
                parent_key(&invalid.key).and_then(|p| line_of_key(text, p))
            });
            return Err(located(line, Some(invalid.key), invalid.message));
        }
        Ok(config)
    }

    /// Checks values that parse but make no sense.
    pub fn validate(&self) -> Result<(), Invalid> {
        let site = &self.site;
        if jiff::tz::TimeZone::get(&site.time_zone).is_err() {
            return Err(Invalid::new(
                "site.time_zone",
                format!(
                    "expected an IANA time zone such as \"Europe/Berlin\" or \"UTC\", found \"{}\"",
                    site.time_zone
                ),
            ));
        }
        if !is_valid_prefix(&site.service_prefix) {
            return Err(Invalid::new(
                "site.service_prefix",
                format!(
                    "expected letters, digits, '_', '-', '.', '/' (not at either end), found \"{}\"",
                    site.service_prefix
                ),
            ));
        }
        check_range(
            "site.cameras_per_process",
            site.cameras_per_process as f64,
            1.0,
            1024.0,
        )?;
        let ipc = &self.ipc;
        check_range("ipc.max_subscribers", ipc.max_subscribers as f64, 1.0, 64.0)?;
        check_range("ipc.frame_buffer", ipc.frame_buffer as f64, 1.0, 64.0)?;
        check_range("ipc.stream_buffer", ipc.stream_buffer as f64, 1.0, 1024.0)?;
        check_positive("ipc.lossless_timeout_s", ipc.lossless_timeout_s)?;

        let m = &self.motion;
        check_range("motion.block_px", m.block_px as f64, 4.0, 128.0)?;
        check_range("motion.diff_threshold", m.diff_threshold as f64, 1.0, 255.0)?;
        check_range(
            "motion.gradient_threshold",
            m.gradient_threshold as f64,
            0.0,
            1020.0,
        )?;
        check_range("motion.min_flow_px", m.min_flow_px as f64, 0.0, 1.99)?;
        check_range(
            "motion.density_threshold",
            m.density_threshold as f64,
            0.0,
            1.0,
        )?;
        check_range(
            "motion.illumination_fraction",
            m.illumination_fraction as f64,
            0.05,
            1.0,
        )?;

        let c = &self.cascade;
        check_positive("cascade.t_l1_s", c.t_l1_s)?;
        check_positive("cascade.t_l2_days", c.t_l2_days)?;
        check_positive("cascade.t_s1_s", c.t_s1_s)?;
        if let Some(r) = c.frame_rate {
            check_range("cascade.frame_rate", r, 0.01, 1000.0)?;
        }
        check_range("cascade.min_coverage", c.min_coverage, 0.0, 1.0)?;

        let g = &self.gate;
        check_range("gate.k_sigma", g.k_sigma as f64, 0.0, 100.0)?;
        check_positive("gate.floor", g.floor as f64)?;
        check_positive("gate.min_threshold", g.min_threshold as f64)?;
        check_range(
            "gate.in_place_block_min",
            g.in_place_block_min as f64,
            0.0,
            1.0,
        )?;
        check_range("gate.hold_s", g.hold_s, 0.0, 3600.0)?;
        check_range("gate.detect_per_event", g.detect_per_event as f64, 0.0, 1e6)?;
        if let Some(every) = g.detect_every_s {
            check_positive("gate.detect_every_s", every)?;
        }
        check_range("gate.ring_frames", g.ring_frames as f64, 1.0, 4096.0)?;
        let d = &g.detector;
        check_range("gate.detector.input_px", d.input_px as f64, 32.0, 4096.0)?;
        check_range(
            "gate.detector.score_threshold",
            d.score_threshold as f64,
            0.0,
            1.0,
        )?;
        check_range(
            "gate.detector.nms_threshold",
            d.nms_threshold as f64,
            0.0,
            1.0,
        )?;
        check_range("gate.detector.hog_upscale", d.hog_upscale, 0.25, 4.0)?;
        check_range("gate.detector.queue", d.queue as f64, 1.0, 64.0)?;
        check_range("gate.detector.concurrent", d.concurrent as f64, 1.0, 64.0)?;

        if self.cameras.is_empty() {
            return Err(Invalid::new(
                "camera",
                "expected at least one [[camera]] table with `id` and `source`",
            ));
        }
        for (i, cam) in self.cameras.iter().enumerate() {
            let key = |k: &str| format!("camera[{i}].{k}");
            if !is_valid_camera_id(&cam.id) {
                return Err(Invalid::new(
                    key("id"),
                    format!(
                        "expected 1 to 24 characters of letters, digits, '_' or '-', found \"{}\"",
                        cam.id
                    ),
                ));
            }
            if self.cameras[..i].iter().any(|c| c.id == cam.id) {
                return Err(Invalid::new(
                    key("id"),
                    format!("camera id \"{}\" is used twice", cam.id),
                ));
            }
            if cam.source.trim().is_empty() {
                return Err(Invalid::new(
                    key("source"),
                    "expected a file path, device, URL or gst: pipeline",
                ));
            }
            for (name, v) in [("width", cam.width), ("height", cam.height)] {
                if let Some(v) = v {
                    check_range(&key(name), v as f64, 16.0, 8192.0)?;
                }
            }
            if cam.width.is_some() != cam.height.is_some() {
                return Err(Invalid::new(
                    key(if cam.width.is_some() {
                        "height"
                    } else {
                        "width"
                    }),
                    "expected both width and height, or neither",
                ));
            }
            if !matches!(cam.pixel_format.as_str(), "gray8" | "bgr8") {
                return Err(Invalid::new(
                    key("pixel_format"),
                    format!(
                        "expected \"gray8\" or \"bgr8\", found \"{}\"",
                        cam.pixel_format
                    ),
                ));
            }
            if let Some(fps) = cam.fps {
                check_range(&key("fps"), fps, 0.01, 1000.0)?;
            }
            if let Some(start) = &cam.start
                && crate::clock::parse_rfc3339(start).is_err()
            {
                return Err(Invalid::new(
                    key("start"),
                    format!(
                        "expected an RFC 3339 time such as \"2026-03-02T07:00:00Z\", found \"{start}\""
                    ),
                ));
            }
            if let Some(n) = cam.preload_frames {
                check_range(&key("preload_frames"), n as f64, 2.0, 100_000.0)?;
                if !cam.source_kind(Path::new(".")).is_file() {
                    return Err(Invalid::new(
                        key("preload_frames"),
                        "expected only for file sources (live sources cannot be preloaded)",
                    ));
                }
            }
            check_range(
                &key("reconnect_initial_s"),
                cam.reconnect_initial_s,
                1e-3,
                3600.0,
            )?;
            if cam.reconnect_max_s < cam.reconnect_initial_s {
                return Err(Invalid::new(
                    key("reconnect_max_s"),
                    format!(
                        "expected a number >= reconnect_initial_s ({}), found {}",
                        cam.reconnect_initial_s, cam.reconnect_max_s
                    ),
                ));
            }
            for (j, poly) in cam.mask.iter().enumerate() {
                check_polygon(&format!("camera[{i}].mask[{j}]"), poly)?;
            }
            for (j, zone) in cam.zones.iter().enumerate() {
                let zkey = format!("camera[{i}].zone[{j}]");
                if zone.name.is_empty() || zone.name.len() > crate::wire::ZONE_NAME_LEN {
                    return Err(Invalid::new(
                        format!("{zkey}.name"),
                        "expected a name of 1 to 32 bytes",
                    ));
                }
                if cam.zones[..j].iter().any(|z| z.name == zone.name) {
                    return Err(Invalid::new(
                        format!("{zkey}.name"),
                        format!("zone name \"{}\" is used twice", zone.name),
                    ));
                }
                check_polygon(&format!("{zkey}.polygon"), &zone.polygon)?;
            }
            check_floor_points(&key("floor_points"), &cam.floor_points)?;
        }
        validate_costmap(self)?;
        Ok(())
    }
}

/// Longest segment or route name, in bytes (the planning service's fixed width).
pub const PLAN_NAME_LEN: usize = crate::wire::PLAN_NAME_LEN;

/// Checks a camera's floor points: none, or at least 4 finite pairs that can define
/// a homography (no duplicates, not all on a line, no three on a line when 4).
fn check_floor_points(key: &str, points: &[FloorPoint]) -> Result<(), Invalid> {
    if points.is_empty() {
        return Ok(());
    }
    if points.len() < 4 {
        return Err(Invalid::new(
            key,
            format!(
                "expected at least 4 {{ image_px = [x, y], floor_m = [x, y] }} pairs, found {}",
                points.len()
            ),
        ));
    }
    for (side, pick) in [
        (
            "image_px",
            (|p: &FloorPoint| p.image_px) as fn(&FloorPoint) -> [f64; 2],
        ),
        ("floor_m", |p: &FloorPoint| p.floor_m),
    ] {
        let pts: Vec<[f64; 2]> = points.iter().map(pick).collect();
        if pts.iter().flatten().any(|v| !v.is_finite()) {
            return Err(Invalid::new(
                key,
                format!("expected finite {side} coordinates"),
            ));
        }
        if let Some(reason) = degenerate_points(&pts) {
            return Err(Invalid::new(
                key,
                format!("the {side} points cannot define a homography: {reason}"),
            ));
        }
    }
    Ok(())
}

/// Why `pts` (at least 4) cannot be one side of a homography, if they cannot:
/// two points alike, all on one line, or (for exactly 4) three on one line.
pub fn degenerate_points(pts: &[[f64; 2]]) -> Option<String> {
    let extent = pts
        .iter()
        .flat_map(|a| pts.iter().map(move |b| (a[0] - b[0]).hypot(a[1] - b[1])))
        .fold(0.0, f64::max);
    if extent == 0.0 {
        return Some("all points are the same".into());
    }
    let eps = 1e-9 * extent;
    for i in 0..pts.len() {
        for j in i + 1..pts.len() {
            if (pts[i][0] - pts[j][0]).hypot(pts[i][1] - pts[j][1]) <= eps {
                return Some(format!(
                    "points {} and {} are the same ({:?})",
                    i + 1,
                    j + 1,
                    pts[i]
                ));
            }
        }
    }
    // |cross| / extent² is twice a triangle's area relative to the set's size.
    let collinear = |a: [f64; 2], b: [f64; 2], c: [f64; 2]| {
        let cross = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
        cross.abs() <= 1e-6 * extent * extent
    };
    if pts.len() == 4 {
        for (i, j, k) in [(0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3)] {
            if collinear(pts[i], pts[j], pts[k]) {
                return Some(format!(
                    "points {}, {} and {} are on one line",
                    i + 1,
                    j + 1,
                    k + 1
                ));
            }
        }
    }
    // The two points farthest apart span the line any other point would be on.
    let (a, b) = pts
        .iter()
        .flat_map(|a| pts.iter().map(move |b| (*a, *b)))
        .max_by(|x, y| {
            let d = |(a, b): &([f64; 2], [f64; 2])| (a[0] - b[0]).hypot(a[1] - b[1]);
            d(x).total_cmp(&d(y))
        })
        .expect("at least two points");
    if pts.iter().all(|&c| collinear(a, b, c)) {
        return Some("all points are on one line".into());
    }
    None
}

/// Checks `[costmap]`, its segments and routes against the cameras.
fn validate_costmap(config: &Config) -> Result<(), Invalid> {
    let c = &config.costmap;
    if c.map_yaml.is_some() {
        for (name, given) in [
            ("resolution_m", c.resolution_m.is_some()),
            ("width_cells", c.width_cells.is_some()),
            ("height_cells", c.height_cells.is_some()),
            ("origin_x_m", c.origin_x_m.is_some()),
            ("origin_y_m", c.origin_y_m.is_some()),
            ("origin_yaw_rad", c.origin_yaw_rad.is_some()),
        ] {
            if given {
                return Err(Invalid::new(
                    format!("costmap.{name}"),
                    "the grid comes from costmap.map_yaml: set either map_yaml or the grid keys, not both",
                ));
            }
        }
    } else if c.width_cells.is_some() || c.height_cells.is_some() {
        let key = if c.width_cells.is_none() {
            "costmap.width_cells"
        } else {
            "costmap.height_cells"
        };
        let (w, h) = (c.width_cells.unwrap_or(0), c.height_cells.unwrap_or(0));
        if c.width_cells.is_none() || c.height_cells.is_none() {
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
    } else if c.resolution_m.is_some() || c.origin_x_m.is_some() || c.origin_y_m.is_some() {
        return Err(Invalid::new(
            "costmap.width_cells",
            "expected width_cells and height_cells with the other grid keys (or map_yaml)",
        ));
    }
    if let Some(r) = c.resolution_m {
        check_range("costmap.resolution_m", r, 0.001, 100.0)?;
    }
    for (name, v) in [
        ("origin_x_m", c.origin_x_m),
        ("origin_y_m", c.origin_y_m),
        ("origin_yaw_rad", c.origin_yaw_rad),
    ] {
        if let Some(v) = v {
            check_range(&format!("costmap.{name}"), v, -1e6, 1e6)?;
        }
    }
    if c.frame_id.trim().is_empty() {
        return Err(Invalid::new(
            "costmap.frame_id",
            "expected a frame name such as \"map\"",
        ));
    }
    for (key, topic) in [
        ("costmap.topic", Some(&c.topic)),
        ("costmap.updates_topic", c.updates_topic.as_ref()),
    ] {
        if let Some(topic) = topic
            && !is_valid_ros_topic(topic)
        {
            return Err(Invalid::new(
                key,
                format!(
                    "expected a ROS 2 topic name such as \"/isochron/activity_costmap\" (letters, digits, '_', '/'), found \"{topic}\""
                ),
            ));
        }
    }
    check_range("costmap.publish_hz", c.publish_hz, 0.01, 100.0)?;
    check_range("costmap.full_every_s", c.full_every_s, 0.0, 86_400.0)?;
    if let Some(d) = c.ros_domain_id {
        check_range("costmap.ros_domain_id", d as f64, 0.0, 232.0)?;
    }
    for (i, addr) in c.dds_interfaces.iter().enumerate() {
        if addr.parse::<std::net::IpAddr>().is_err() {
            return Err(Invalid::new(
                format!("costmap.dds_interfaces[{i}]"),
                format!(
                    "expected the IP address of a network interface such as \"127.0.0.1\", found \"{addr}\""
                ),
            ));
        }
    }
    for (name, v) in [
        ("weight_in_place", c.weight_in_place),
        ("weight_moving", c.weight_moving),
        ("weight_long_term", c.weight_long_term),
        ("w1", c.w1),
        ("w2", c.w2),
        ("min_activity", c.min_activity),
    ] {
        check_range(&format!("costmap.{name}"), v, 0.0, 1e6)?;
    }
    check_positive("costmap.cost_scale", c.cost_scale)?;
    check_range("costmap.cap", c.cap as f64, 1.0, 100.0)?;
    check_range("costmap.confirm_radius_m", c.confirm_radius_m, 0.0, 100.0)?;
    check_range("costmap.confirm_hold_s", c.confirm_hold_s, 0.0, 3600.0)?;
    if let Some(v) = c.confirm_cost {
        check_range("costmap.confirm_cost", v as f64, 0.0, 100.0)?;
    }
    check_positive("costmap.stale_s", c.stale_s)?;
    check_range("costmap.snapshot_every_s", c.snapshot_every_s, 0.0, 1e7)?;
    check_range("costmap.snapshot_keep", c.snapshot_keep as f64, 1.0, 1e6)?;

    let located = config
        .cameras
        .iter()
        .any(|cam| !cam.floor_points.is_empty());
    for (i, seg) in c.segments.iter().enumerate() {
        let key = |k: &str| format!("costmap.segment[{i}].{k}");
        if seg.name.is_empty() || seg.name.len() > PLAN_NAME_LEN || seg.name.contains(',') {
            return Err(Invalid::new(
                key("name"),
                "expected a name of 1 to 32 bytes without ','",
            ));
        }
        if c.segments[..i].iter().any(|s| s.name == seg.name) {
            return Err(Invalid::new(
                key("name"),
                format!("segment name \"{}\" is used twice", seg.name),
            ));
        }
        match (&seg.polygon_m, &seg.camera, &seg.zone) {
            (Some(poly), None, None) => {
                check_polygon(&key("polygon_m"), poly)?;
                if !located {
                    return Err(Invalid::new(
                        key("polygon_m"),
                        "a floor polygon needs cameras on the floor: give at least one [[camera]] floor_points",
                    ));
                }
            }
            (None, Some(camera), Some(zone)) => {
                let Some(cam) = config.cameras.iter().find(|cam| &cam.id == camera) else {
                    return Err(Invalid::new(
                        key("camera"),
                        format!("no [[camera]] with id \"{camera}\""),
                    ));
                };
                let known = if cam.zones.is_empty() {
                    zone == "all"
                } else {
                    cam.zones.iter().any(|z| &z.name == zone)
                };
                if !known {
                    return Err(Invalid::new(
                        key("zone"),
                        format!("camera \"{camera}\" has no zone \"{zone}\""),
                    ));
                }
            }
            _ => {
                return Err(Invalid::new(
                    key("name"),
                    "expected either polygon_m, or camera and zone",
                ));
            }
        }
    }
    for (i, route) in c.routes.iter().enumerate() {
        let key = |k: &str| format!("costmap.route[{i}].{k}");
        if route.name.is_empty() || route.name.len() > PLAN_NAME_LEN || route.name.contains(',') {
            return Err(Invalid::new(
                key("name"),
                "expected a name of 1 to 32 bytes without ','",
            ));
        }
        if c.routes[..i].iter().any(|r| r.name == route.name) {
            return Err(Invalid::new(
                key("name"),
                format!("route name \"{}\" is used twice", route.name),
            ));
        }
        if route.segments.is_empty() {
            return Err(Invalid::new(
                key("segments"),
                "expected at least one segment name",
            ));
        }
        for (j, name) in route.segments.iter().enumerate() {
            if c.segment(name).is_none() {
                return Err(Invalid::new(
                    format!("costmap.route[{i}].segments[{j}]"),
                    format!("no [[costmap.segment]] named \"{name}\""),
                ));
            }
        }
    }
    Ok(())
}

/// Most cells of a grid: 1 MB per `OccupancyGrid` message.
pub const MAX_GRID_CELLS: u64 = 1 << 20;

/// True if `topic` is a ROS 2 topic name this bridge can publish on: `/`-separated
/// tokens of letters, digits and `_`, each starting with a letter or `_`.
pub fn is_valid_ros_topic(topic: &str) -> bool {
    let rest = topic.strip_prefix('/').unwrap_or(topic);
    !rest.is_empty()
        && rest.split('/').all(|tok| {
            !tok.is_empty()
                && !tok.contains("__")
                && tok.starts_with(|c: char| c.is_ascii_alphabetic() || c == '_')
                && tok.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
        })
}

/// Errors unless `lo <= v <= hi`.
pub fn check_range(key: &str, v: f64, lo: f64, hi: f64) -> Result<(), Invalid> {
    if v.is_finite() && v >= lo && v <= hi {
        Ok(())
    } else {
        Err(Invalid::new(
            key,
            format!("expected a number from {lo} to {hi}, found {v}"),
        ))
    }
}

/// Errors unless `v > 0`.
pub fn check_positive(key: &str, v: f64) -> Result<(), Invalid> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(Invalid::new(
            key,
            format!("expected a number > 0, found {v}"),
        ))
    }
}

fn check_polygon(key: &str, poly: &Polygon) -> Result<(), Invalid> {
    if poly.len() < 3 {
        return Err(Invalid::new(
            key,
            format!(
                "expected a polygon of at least 3 [x, y] points, found {}",
                poly.len()
            ),
        ));
    }
    if poly.iter().flatten().any(|v| !v.is_finite()) {
        return Err(Invalid::new(key, "expected finite coordinates"));
    }
    Ok(())
}

/// 1-based line of byte `offset` in `text`.
fn line_at(text: &str, offset: usize) -> usize {
    text.as_bytes()[..offset.min(text.len())]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
}

/// `a.b[2].c` → `a.b[2]`; `a` → `None`.
fn parent_key(key: &str) -> Option<&str> {
    let cut = key.rfind(['.', '['])?;
    Some(&key[..cut])
}

/// The 1-based line where dotted key path `key` (`camera[0].fps`) is written, or of
/// the deepest part of it that exists.
pub fn line_of_key(text: &str, key: &str) -> Option<usize> {
    use toml_edit::{Item, TableLike, Value};
    let doc = toml_edit::Document::parse(text).ok()?;
    let mut table: &dyn TableLike = doc.as_item().as_table_like()?;
    let mut span = None;
    let mut segments = key.split('.').peekable();
    while let Some(segment) = segments.next() {
        let (name, indices) = segment.split_at(segment.find('[').unwrap_or(segment.len()));
        let (k, item) = table.get_key_value(name)?;
        span = k.span().or_else(|| item.span()).or(span);
        // Walk `[i]` indices: into arrays of tables or inline arrays.
        let mut next_table = item.as_table_like();
        let mut value: Option<&Value> = item.as_value();
        for index in indices.split(['[', ']']).filter(|s| !s.is_empty()) {
            let index: usize = index.parse().ok()?;
            if let Item::ArrayOfTables(a) = item
                && value.is_none()
            {
                let t = a.get(index)?;
                span = t.span().or(span);
                next_table = Some(t as &dyn TableLike);
                continue;
            }
            let v = value?.as_array()?.get(index)?;
            span = v.span().or(span);
            next_table = v.as_inline_table().map(|t| t as &dyn TableLike);
            value = Some(v);
        }
        if segments.peek().is_some() {
            table = next_table?;
        }
    }
    span.map(|s| line_at(text, s.start))
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"
[site]
name = "test"
time_zone = "Europe/Berlin"

[[camera]]
id = "cam01"
source = "video.avi"
fps = 10

[[camera]]
id = "cam02"
source = "rtsp://127.0.0.1/stream"
"#;

    fn parse(text: &str) -> Result<Config, ConfigError> {
        Config::parse(text, Path::new("site.toml"))
    }

    #[test]
    fn good_config_parses_with_defaults() {
        let c = parse(GOOD).unwrap();
        assert_eq!(c.site.time_zone, "Europe/Berlin");
        assert_eq!(c.site.service_prefix, "isochron");
        assert_eq!(c.cameras.len(), 2);
        assert_eq!(c.cameras[0].speed, Speed::Factor(1.0));
        assert_eq!(c.ipc.max_subscribers, 5);
        assert_eq!(
            c.cameras[1].source_kind(Path::new("/etc")),
            SourceKind::Url("rtsp://127.0.0.1/stream".into())
        );
        assert_eq!(
            c.cameras[0].source_kind(Path::new("/etc")),
            SourceKind::File("/etc/video.avi".into())
        );
    }

    #[test]
    fn relative_paths_become_absolute_against_the_config_file() {
        let text = format!(
            "{GOOD}\n[gate.detector]\nmodel = \"models/yolo.onnx\"\n\n[costmap]\nmap_yaml = \"/maps/floor.yaml\"\nsnapshot_dir = \"snaps\"\n"
        );
        let loaded = LoadedConfig {
            config: parse(&text).unwrap(),
            path: PathBuf::from("/etc/isochron/site.toml"),
        };
        let c = loaded.with_absolute_paths();
        let etc = Path::new("/etc/isochron");
        assert_eq!(c.cameras[0].source, "/etc/isochron/video.avi");
        assert_eq!(c.cameras[1].source, "rtsp://127.0.0.1/stream");
        assert_eq!(c.gate.detector.model, Some(etc.join("models/yolo.onnx")));
        assert_eq!(c.costmap.map_yaml, Some(PathBuf::from("/maps/floor.yaml")));
        assert_eq!(c.costmap.snapshot_dir, Some(etc.join("snaps")));
        assert_eq!(c.site.state_dir, PathBuf::from("/var/lib/isochron"));
    }

    #[test]
    fn syntax_error_names_the_line() {
        let err = parse("[site]\nname = \"x\"\ntime_zone = = 3\n").unwrap_err();
        assert_eq!(err.line, Some(3), "{err}");
        assert!(err.to_string().starts_with("site.toml:3:"), "{err}");
    }

    #[test]
    fn wrong_type_names_line_and_key() {
        let text = GOOD.replace("fps = 10", "fps = \"fast\"");
        let err = parse(&text).unwrap_err();
        assert_eq!(err.key.as_deref(), Some("camera[0].fps"), "{err}");
        assert_eq!(err.line, Some(9), "{err}");
        assert!(err.message.contains("expected"), "{err}");
    }

    #[test]
    fn unknown_key_is_rejected_with_its_line() {
        let text = GOOD.replace("fps = 10", "fsp = 10");
        let err = parse(&text).unwrap_err();
        assert_eq!(err.line, Some(9), "{err}");
        assert!(err.message.contains("fsp"), "{err}");
    }

    #[test]
    fn invalid_values_name_line_key_and_expectation() {
        let text = GOOD.replace("fps = 10", "fps = -3");
        let err = parse(&text).unwrap_err();
        assert_eq!(err.key.as_deref(), Some("camera[0].fps"));
        assert_eq!(err.line, Some(9));
        assert!(err.message.contains("expected a number"), "{err}");

        let text = GOOD.replace("Europe/Berlin", "Mars/Olympus");
        let err = parse(&text).unwrap_err();
        assert_eq!(err.key.as_deref(), Some("site.time_zone"));
        assert_eq!(err.line, Some(4));

        let text = GOOD.replace("id = \"cam02\"", "id = \"cam01\"");
        let err = parse(&text).unwrap_err();
        assert_eq!(err.key.as_deref(), Some("camera[1].id"));
        assert_eq!(err.line, Some(12));
        assert!(err.message.contains("used twice"));
    }

    #[test]
    fn missing_cameras_is_an_error() {
        let err = parse("[site]\nname = \"x\"\n").unwrap_err();
        assert_eq!(err.key.as_deref(), Some("camera"));
        assert!(err.message.contains("[[camera]]"));
    }

    #[test]
    fn the_shipped_configs_are_valid() {
        for (name, text) in [
            ("config/demo.toml", include_str!("../../../config/demo.toml")),
            (
                "config/site.example.toml",
                include_str!("../../../config/site.example.toml"),
            ),
        ] {
            if let Err(e) = Config::parse(text, Path::new(name)) {
                panic!("{e}");
            }
        }
    }

    #[test]
    fn speed_parses() {
        assert_eq!(Speed::parse("max"), Some(Speed::Max));
        assert_eq!(Speed::parse("2.5"), Some(Speed::Factor(2.5)));
        assert_eq!(Speed::parse("-1"), None);
        let text = GOOD.replace("fps = 10", "speed = \"max\"");
        assert_eq!(parse(&text).unwrap().cameras[0].speed, Speed::Max);
        let text = GOOD.replace("fps = 10", "speed = \"fast\"");
        let err = parse(&text).unwrap_err();
        assert_eq!(err.key.as_deref(), Some("camera[0].speed"));
    }
}
