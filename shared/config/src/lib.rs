//! Configuration: one TOML file describes a site (its cameras and every stage).
//!
//! [`Config::load`] parses and validates; every error names the file, the line, the
//! key, and what was expected, e.g.
//! `config/site.toml:12: camera[0].fps: expected a number > 0, found -3`.
//! Each key is documented on its field with its default; units are in the names
//! (`_s`, `_px`, `_days`).
//!
//! Each section is a module of its own that holds its keys and checks them; they
//! are all re-exported here.
//!
//! [`Config::validate`] calls each section's `validate` in turn. Syntax and type
//! errors are located through the TOML span and `serde_path_to_error`'s key path;
//! semantic errors ([`Invalid`]) through the key's span found with `toml_edit` (or
//! its table's, when the key is absent). Unknown keys are errors
//! (`deny_unknown_fields`). `cargo xtask docs config` makes docs/configuration.md
//! from the fields' doc comments and the real defaults (the
//! `isochron-config-defaults` example), and checks every `Default <value>` a doc
//! comment states against them.

mod camera;
mod cascade;
mod check;
pub mod clock;
mod costmap;
pub mod detector;
mod exporter;
mod gate;
mod ipc;
mod link;
mod motion;
mod mqtt;
mod presence;
pub mod redact;
mod segments;
mod site;
#[cfg(test)]
mod tests;
mod view;
mod zenoh;

isochron_exit::always_exits_with!(CONFIG: ConfigError, UnknownCamera;);

use std::fmt;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

pub use camera::{
    CameraConfig, FloorPoint, LineConfig, LineSide, Polygon, SourceKind, Speed, Transport,
    ZoneConfig, degenerate_points, parse_start,
};
pub use cascade::{CascadeConfig, DAY_NAMES};
use check::{check_at_least, check_dds, check_polygon};
pub use check::{check_positive, check_range, is_valid_ros_topic};
pub use costmap::{CostmapConfig, MAX_GRID_CELLS};
pub use exporter::ExporterConfig;
pub use gate::{DetectorConfig, GateConfig};
pub use ipc::IpcConfig;
pub use link::{DEFAULT_LINK_NAMESPACE, LinkConfig, MAX_BOX_ID_LEN, is_ros_token};
pub use motion::{MotionBackend, MotionConfig};
pub use mqtt::{Broker, DEFAULT_MQTT_PORT, DEFAULT_MQTTS_PORT, MqttConfig, is_topic_level};
pub use presence::PresenceConfig;
pub use redact::redact;
pub use segments::{PLAN_NAME_LEN, RouteConfig, SegmentConfig};
pub use site::{DEFAULT_PREFIX, SiteConfig, is_valid_prefix};
pub use view::ViewConfig;
pub use zenoh::{DEFAULT_ZENOH_LISTEN, DEFAULT_ZENOH_ROUTER, ZenohConfig};

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

    /// An error at `key` whose value `found` is not what was `expected`:
    /// `expected <expected>, found "<found>"`.
    pub fn found(key: impl Into<String>, expected: &str, found: &str) -> Self {
        Invalid::new(key, format!("expected {expected}, found \"{found}\""))
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
    /// The presence band (learned in the cascade).
    pub presence: PresenceConfig,
    /// The event gate and its detector.
    pub gate: GateConfig,
    /// The cost map on the robots' floor, its ROS 2 output, and path planning.
    pub costmap: CostmapConfig,
    /// The Prometheus exporter; absent: `isochron up` and `replay` do not start it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub exporter: Option<ExporterConfig>,
    /// The live view (`isochron view`) and recordings (`isochron record`).
    pub view: ViewConfig,
    /// The link to the site's other base stations (`isochron-link`).
    pub link: LinkConfig,
    /// The MQTT sink of zone events and detections; absent: nothing is published,
    /// and `isochron up` and `replay` do not start it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mqtt: Option<MqttConfig>,
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
    pub fn camera(&self, id: &str) -> Result<&CameraConfig, UnknownCamera> {
        self.config
            .cameras
            .iter()
            .find(|c| c.id == id)
            .ok_or_else(|| UnknownCamera {
                id: id.to_string(),
                file: self.path.clone(),
                configured: self.config.cameras.iter().map(|c| c.id.clone()).collect(),
            })
    }

    /// The config with every relative file path (detector model, map YAML, route
    /// graph, snapshot and state directories, camera files) made absolute, so that it
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
            config.costmap.route_graph.as_mut(),
            config.costmap.zenoh.config_file.as_mut(),
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

    /// Valid settings a site probably does not want (e.g. `costmap.cap = 100`),
    /// located in the file like errors: services log them at load.
    pub fn warnings(&self) -> Vec<ConfigError> {
        let text = std::fs::read_to_string(&self.path).unwrap_or_default();
        self.config
            .costmap
            .warnings()
            .into_iter()
            .map(|w| ConfigError {
                file: self.path.clone(),
                line: line_of_key(&text, &w.key),
                key: Some(w.key),
                message: w.message,
            })
            .collect()
    }

    /// `invalid`, located in the config file (the line of its key, or of its table
    /// when the key is absent).
    pub fn locate(&self, invalid: Invalid) -> ConfigError {
        let text = std::fs::read_to_string(&self.path).unwrap_or_default();
        let line = line_of_key(&text, &invalid.key)
            .or_else(|| parent_key(&invalid.key).and_then(|p| line_of_key(&text, p)));
        ConfigError {
            file: self.path.clone(),
            line,
            key: Some(invalid.key),
            message: invalid.message,
        }
    }

    /// The checked `[mqtt]` section, `None` without one. Checked here, by the MQTT
    /// sink, rather than at load: a bad broker URL stops the sink (exit 78) while
    /// the rest of the group runs.
    pub fn mqtt(&self) -> Result<Option<&MqttConfig>, ConfigError> {
        let Some(mqtt) = &self.config.mqtt else {
            return Ok(None);
        };
        mqtt.validate(&self.config.site.name)
            .map_err(|e| self.locate(e))?;
        Ok(Some(mqtt))
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

/// [`LoadedConfig::camera`] found no camera with the id asked for.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("no camera '{id}' in {} (configured: {})", .file.display(), .configured.join(", "))]
pub struct UnknownCamera {
    /// The id asked for.
    pub id: String,
    /// The config file.
    pub file: PathBuf,
    /// The ids of the configured cameras, in the file's order.
    pub configured: Vec<String>,
}

impl Config {
    /// The cameras this box runs: every `[[camera]]` but those `[link]` imports
    /// (their `[[camera]]` gives the bridge their floor; another box runs them).
    pub fn local_cameras(&self) -> impl Iterator<Item = &CameraConfig> {
        self.cameras
            .iter()
            .filter(|c| !self.link.import.contains(&c.id))
    }

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

    /// Checks values that parse but make no sense, section by section; the first
    /// error found is returned.
    pub fn validate(&self) -> Result<(), Invalid> {
        self.site.validate()?;
        self.ipc.validate()?;
        self.motion.validate()?;
        self.cascade.validate()?;
        self.presence.validate()?;
        self.gate.validate()?;
        if let Some(exporter) = &self.exporter {
            exporter.validate()?;
        }
        camera::validate_cameras(&self.cameras)?;
        self.costmap.validate(&self.cameras)?;
        self.view.validate()?;
        // `[mqtt]` is checked by the sink alone (`LoadedConfig::mqtt`): a bad broker
        // URL stops the sink, not the group.
        self.link.validate(&self.cameras)
    }
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
