//! `[[camera]]`: the cameras, their sources, masks, zones and floor points.

use std::fmt;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::{Invalid, check_at_least, check_polygon, check_range};
use isochron_wire::{PixelFormat, is_valid_camera_id};

/// The earliest `start` of a file source: 1971-01-01T00:00:00Z, UTC ns (a capture
/// time must be after 1970, and a replay may begin a little before its start).
const START_MIN_NS: i64 = 31_536_000 * 1_000_000_000;
/// The latest `start`: 2200-01-01T00:00:00Z, UTC ns, well before i64 nanoseconds
/// overflow in 2262 however long the file plays.
const START_MAX_NS: i64 = 7_258_118_400 * 1_000_000_000;

/// Parses the `start` of a file source (the capture time of its first frame):
/// UTC ns, or what was expected (as `Invalid::found` and `isochron replay
/// --start` say it).
pub fn parse_start(start: &str) -> Result<i64, &'static str> {
    let ns = crate::clock::parse_rfc3339(start)
        .map_err(|_| "an RFC 3339 time such as \"2026-03-02T07:00:00Z\"")?;
    if !(START_MIN_NS..=START_MAX_NS).contains(&ns) {
        return Err(
            "a time from 1971-01-01 to 2200-01-01 (capture times are nanoseconds after 1970 that must not overflow)",
        );
    }
    Ok(ns)
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

/// Which side of a counting line is "in" (`[[camera.line]].in`), seen walking
/// along the line from its first point to its last.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LineSide {
    /// The walker's left.
    Left,
    /// The walker's right.
    Right,
}

/// A counting line of a camera's view, whose crossings the people census
/// counts in and out (`[[camera.line]]`; checked at load, not counted yet).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LineConfig {
    /// Line name (at most 32 bytes), unique per camera.
    pub name: String,
    /// The line in frame pixels at the analysis size: 2 or more points, inside
    /// the frame.
    pub points: Vec<[f64; 2]>,
    /// Which side is `in`, walking from the first point to the last: `left` or
    /// `right`.
    #[serde(rename = "in")]
    pub in_side: LineSide,
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
    /// Capture time of a file's first frame (RFC 3339, 1971 to 2200); default: when
    /// capture starts.
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
    /// File sources only: the frame the first pass starts at (its index in the
    /// file, or with `preload_frames` in the preloaded frames); a loop starts again
    /// from frame 0. Cameras replaying one file at different points do not move in
    /// lockstep. Default 0.
    #[serde(default)]
    pub start_frame: u64,
    /// First reconnect delay after a live source drops out, seconds; one that
    /// was streaming is retried this often for its first minute down. Default 0.5.
    #[serde(default = "default_reconnect_initial_s")]
    pub reconnect_initial_s: f64,
    /// Longest reconnect delay (the backoff doubles up to it), seconds. Default 30.
    #[serde(default = "default_reconnect_max_s")]
    pub reconnect_max_s: f64,
    /// Network cameras (`rtsp://`): how the video travels, `"tcp"` (inside the
    /// RTSP connection: no loss, passes firewalls and NAT) or `"udp"` (RTP
    /// packets: lower latency, lost packets are lost). Default `"tcp"`.
    #[serde(default)]
    pub transport: Transport,
    /// Network cameras: seconds without a frame before the camera counts as
    /// stalled and is reconnected (never less than two of its frame intervals).
    /// Default 5.
    #[serde(default = "default_network_timeout_s")]
    pub read_timeout_s: f64,
    /// Network cameras: seconds opening may take (connecting, the RTSP
    /// handshake, the first frames) before the attempt counts as timed out.
    /// Default 5.
    #[serde(default = "default_network_timeout_s")]
    pub connect_timeout_s: f64,
    /// Regions that never matter (polygons in frame pixels); their blocks report no
    /// motion.
    #[serde(default)]
    pub mask: Vec<Polygon>,
    /// Zones for events; default one zone `"all"` covering the whole view.
    #[serde(default, rename = "zone")]
    pub zones: Vec<ZoneConfig>,
    /// Counting lines of the people census: crossings in and out per track.
    /// Checked at load; the gate does not count them yet. Default: none.
    #[serde(default, rename = "line")]
    pub lines: Vec<LineConfig>,
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
fn default_network_timeout_s() -> f64 {
    5.0
}

/// How a network camera's video travels (`[[camera]].transport`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Transport {
    /// Interleaved in the RTSP connection (TCP).
    #[default]
    Tcp,
    /// RTP over UDP.
    Udp,
}

impl Transport {
    /// The name the config and FFmpeg's `rtsp_transport` use.
    pub fn as_str(self) -> &'static str {
        match self {
            Transport::Tcp => "tcp",
            Transport::Udp => "udp",
        }
    }
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

impl fmt::Display for SourceKind {
    /// The source as logs and errors show it, credentials masked
    /// ([`crate::redact`]).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SourceKind::File(path) => write!(f, "{}", path.display()),
            SourceKind::Device(index) => write!(f, "V4L2 device {index}"),
            SourceKind::Url(url) => f.write_str(&crate::redact(url)),
            SourceKind::GStreamer(p) => write!(f, "GStreamer pipeline '{}'", crate::redact(p)),
        }
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

/// Checks the `[[camera]]` tables: at least one, ids unique, and each camera's keys.
pub(super) fn validate_cameras(cameras: &[CameraConfig]) -> Result<(), Invalid> {
    if cameras.is_empty() {
        return Err(Invalid::new(
            "camera",
            "expected at least one [[camera]] table with `id` and `source`",
        ));
    }
    for (i, cam) in cameras.iter().enumerate() {
        cam.validate(i, &cameras[..i])?;
    }
    Ok(())
}

impl CameraConfig {
    /// Checks the keys of this camera, `camera[i]`; `earlier` are the cameras
    /// before it (its id must differ from theirs).
    fn validate(&self, i: usize, earlier: &[CameraConfig]) -> Result<(), Invalid> {
        let key = |k: &str| format!("camera[{i}].{k}");
        if !is_valid_camera_id(&self.id) {
            return Err(Invalid::found(
                key("id"),
                "1 to 24 characters of letters, digits, '_' or '-'",
                &self.id,
            ));
        }
        if earlier.iter().any(|c| c.id == self.id) {
            return Err(Invalid::new(
                key("id"),
                format!("camera id \"{}\" is used twice", self.id),
            ));
        }
        if self.source.trim().is_empty() {
            return Err(Invalid::new(
                key("source"),
                "expected a file path, device, URL or gst: pipeline",
            ));
        }
        for (name, v) in [("width", self.width), ("height", self.height)] {
            if let Some(v) = v {
                check_range(&key(name), v as f64, 16.0, 8192.0)?;
            }
        }
        if self.width.is_some() != self.height.is_some() {
            return Err(Invalid::new(
                key(if self.width.is_some() {
                    "height"
                } else {
                    "width"
                }),
                "expected both width and height, or neither",
            ));
        }
        if !matches!(self.pixel_format.as_str(), "gray8" | "bgr8") {
            return Err(Invalid::found(
                key("pixel_format"),
                "\"gray8\" or \"bgr8\"",
                &self.pixel_format,
            ));
        }
        if let Some(fps) = self.fps {
            check_range(&key("fps"), fps, 0.01, 1000.0)?;
        }
        if let Some(start) = &self.start
            && let Err(expected) = parse_start(start)
        {
            return Err(Invalid::found(key("start"), expected, start));
        }
        self.validate_replay(i)?;
        self.validate_areas(i)?;
        check_floor_points(&key("floor_points"), &self.floor_points)?;
        Ok(())
    }

    /// How a file is replayed (`preload_frames`, `start_frame`) and how a source is
    /// reconnected.
    fn validate_replay(&self, i: usize) -> Result<(), Invalid> {
        let key = |k: &str| format!("camera[{i}].{k}");
        if let Some(n) = self.preload_frames {
            check_range(&key("preload_frames"), n as f64, 2.0, 100_000.0)?;
            if !self.source_kind(Path::new(".")).is_file() {
                return Err(Invalid::new(
                    key("preload_frames"),
                    "expected only for file sources (live sources cannot be preloaded)",
                ));
            }
        }
        if self.start_frame > 0 {
            if !self.source_kind(Path::new(".")).is_file() {
                return Err(Invalid::new(
                    key("start_frame"),
                    "expected only for file sources (a live source starts where it is)",
                ));
            }
            if let Some(n) = self.preload_frames
                && self.start_frame >= u64::from(n)
            {
                return Err(Invalid::new(
                    key("start_frame"),
                    format!("expected a frame below preload_frames ({n})"),
                ));
            }
        }
        check_range(
            &key("reconnect_initial_s"),
            self.reconnect_initial_s,
            1e-3,
            3600.0,
        )?;
        for (name, seconds) in [
            ("read_timeout_s", self.read_timeout_s),
            ("connect_timeout_s", self.connect_timeout_s),
        ] {
            check_range(&key(name), seconds, 0.1, 600.0)?;
        }
        if self.reconnect_max_s < self.reconnect_initial_s {
            return Err(Invalid::new(
                key("reconnect_max_s"),
                format!(
                    "expected a number >= reconnect_initial_s ({}), found {}",
                    self.reconnect_initial_s, self.reconnect_max_s
                ),
            ));
        }
        Ok(())
    }

    /// The masks and zones: simple polygons, zones with unique names.
    fn validate_areas(&self, i: usize) -> Result<(), Invalid> {
        for (j, poly) in self.mask.iter().enumerate() {
            check_polygon(&format!("camera[{i}].mask[{j}]"), poly)?;
        }
        for (j, zone) in self.zones.iter().enumerate() {
            let zkey = format!("camera[{i}].zone[{j}]");
            if zone.name.is_empty() || zone.name.len() > isochron_wire::ZONE_NAME_LEN {
                return Err(Invalid::new(
                    format!("{zkey}.name"),
                    "expected a name of 1 to 32 bytes",
                ));
            }
            if self.zones[..j].iter().any(|z| z.name == zone.name) {
                return Err(Invalid::new(
                    format!("{zkey}.name"),
                    format!("zone name \"{}\" is used twice", zone.name),
                ));
            }
            check_polygon(&format!("{zkey}.polygon"), &zone.polygon)?;
        }
        for (j, line) in self.lines.iter().enumerate() {
            let key = format!("camera[{i}].line[{j}]");
            if line.name.is_empty() || line.name.len() > isochron_wire::ZONE_NAME_LEN {
                return Err(Invalid::new(
                    format!("{key}.name"),
                    "expected a name of 1 to 32 bytes",
                ));
            }
            if self.lines[..j].iter().any(|l| l.name == line.name) {
                return Err(Invalid::new(
                    format!("{key}.name"),
                    format!("line name \"{}\" is used twice", line.name),
                ));
            }
            self.check_line_points(&format!("{key}.points"), &line.points)?;
        }
        Ok(())
    }

    /// A counting line's points: at least 2, finite, inside the frame (within
    /// `width` × `height` where they are configured), no two alike in a row.
    fn check_line_points(&self, key: &str, points: &[[f64; 2]]) -> Result<(), Invalid> {
        check_at_least(key, points.len(), 2, "a line of at least 2 [x, y] points")?;
        let (w, h) = (
            self.width.map_or(f64::INFINITY, f64::from),
            self.height.map_or(f64::INFINITY, f64::from),
        );
        if let Some(p) = points.iter().find(|p| {
            !(p[0].is_finite() && p[1].is_finite())
                || p[0] < 0.0
                || p[1] < 0.0
                || p[0] > w
                || p[1] > h
        }) {
            let frame = match (self.width, self.height) {
                (Some(w), Some(h)) => format!("the {w}x{h} frame"),
                _ => "the frame (x and y from 0)".to_string(),
            };
            return Err(Invalid::new(
                key,
                format!("expected points inside {frame}, found {p:?}"),
            ));
        }
        if points.windows(2).any(|w| w[0] == w[1]) {
            return Err(Invalid::new(key, "expected no point repeated in a row"));
        }
        Ok(())
    }
}

/// Checks a camera's floor points: none, or at least 4 finite pairs that can define
/// a homography (no duplicates, not all on a line, no three on a line when 4).
fn check_floor_points(key: &str, points: &[FloorPoint]) -> Result<(), Invalid> {
    if points.is_empty() {
        return Ok(());
    }
    check_at_least(
        key,
        points.len(),
        4,
        "at least 4 { image_px = [x, y], floor_m = [x, y] } pairs",
    )?;
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
