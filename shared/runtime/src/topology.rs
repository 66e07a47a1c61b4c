//! The stage table: every stage declared once ([`STAGES`]), with its binary,
//! the streams it reads and writes, whether it runs per camera, when it runs,
//! its config section, its systemd unit and its counters.
//!
//! `isochron up` and `replay` start what the table says runs, `status`,
//! `doctor` and the exporter watch it, the installer and the man pages list its
//! binaries, and a test checks that every service binary has a row and every
//! row a binary and unit. Adding a stage is a crate and a row here
//! (docs/ARCHITECTURE.md, "Adding a stage").

use isochron_config::Config;
use isochron_wire::Stream;

use crate::counters::{self, CounterSpec};

/// A stage: the key of its row of [`STAGES`] (the variants are in table order).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum StageKind {
    /// Reads a camera or file, publishes `frames`.
    Capture,
    /// Per-block motion features of every frame pair.
    Motion,
    /// The cascade of temporal filters and the long-term store.
    Cascade,
    /// Zone events and the detector on gated frames.
    Gate,
    /// The site-wide cost map for robots and the planning service.
    Costmap,
    /// Serves every stage's status as Prometheus metrics (when `[exporter]`).
    Exporter,
    /// The link to the site's other base stations (when `[link]` exports or
    /// imports a camera).
    Link,
    /// Publishes zone events and detections to an MQTT broker (when `[mqtt]`).
    Mqtt,
    /// What people look at: the live Foxglove view (`isochron view`) and MCAP
    /// recordings (`isochron record`, `isochron replay --record`), run on demand
    /// by the `isochron` command; it reports its status like every stage, so
    /// `isochron status` lists it while it runs.
    View,
}

/// When a stage runs.
#[derive(Debug, Clone, Copy)]
pub enum Runs {
    /// Always: `isochron up` and `isochron replay` start it; its failure stops a
    /// replay.
    Always,
    /// When `configured(config)`: `isochron up` starts it then; `isochron replay`
    /// too if `in_replay` (and goes on if it fails).
    WhenConfigured {
        /// True if the config asks for the stage.
        configured: fn(&Config) -> bool,
        /// `isochron replay` runs it too (a replay's box-to-box link would write
        /// into a real site, so the link is not replayed).
        in_replay: bool,
    },
    /// On demand, by a command of `isochron` (the view): no service of its own.
    OnDemand,
}

/// One stage, declared once: everything the launcher, `replay`, `status`,
/// `doctor`, the exporter, the installer and the docs know about it.
#[derive(Debug)]
pub struct StageSpec {
    /// The stage.
    pub kind: StageKind,
    /// Its name, as in node names, status services and logs.
    pub name: &'static str,
    /// The binary that runs it (`isochron` for the view: its `view` and `record`
    /// commands).
    pub binary: &'static str,
    /// What the binary does, as its `--help` and man page say.
    pub about: &'static str,
    /// True for a stage that runs once per camera; false for a site-wide one.
    pub per_camera: bool,
    /// The streams it reads (of its camera, or of every camera if site-wide).
    pub consumes: &'static [Stream],
    /// The streams it publishes.
    pub produces: &'static [Stream],
    /// The config section that sets it up (`[gate]`).
    pub section: &'static str,
    /// Its systemd unit in `systemd/` (a template `@` per camera), if it has one.
    pub unit: Option<&'static str>,
    /// When it runs.
    pub runs: Runs,
    /// The counters of its status.
    pub counters: &'static [CounterSpec],
}

/// Every stage, in [`StageKind`] order: the pipeline (upstream first), then the
/// optional site-wide services, then the view.
pub const STAGES: [StageSpec; 9] = [
    StageSpec {
        kind: StageKind::Capture,
        name: "capture",
        binary: "isochron-capture",
        about: "Reads one camera or video file and publishes its frames on `<prefix>/<camera>/frames`",
        per_camera: true,
        consumes: &[],
        produces: &[Stream::Frames],
        section: "[[camera]]",
        unit: Some("isochron-capture@.service"),
        runs: Runs::Always,
        counters: counters::capture::SCHEMA,
    },
    StageSpec {
        kind: StageKind::Motion,
        name: "motion",
        binary: "isochron-motion",
        about: "Reads a camera's `frames` and publishes per-block motion on `<prefix>/<camera>/motion`",
        per_camera: true,
        consumes: &[Stream::Frames],
        produces: &[Stream::Motion],
        section: "[motion]",
        unit: Some("isochron-motion@.service"),
        runs: Runs::Always,
        counters: counters::motion::SCHEMA,
    },
    StageSpec {
        kind: StageKind::Cascade,
        name: "cascade",
        binary: "isochron-cascade",
        about: "Filters one camera's motion stream into 1-Hz activity and the long-term store",
        per_camera: true,
        consumes: &[Stream::Motion],
        produces: &[Stream::Activity],
        section: "[cascade]",
        unit: Some("isochron-cascade@.service"),
        runs: Runs::Always,
        counters: counters::cascade::SCHEMA,
    },
    StageSpec {
        kind: StageKind::Gate,
        name: "gate",
        binary: "isochron-gate",
        about: "Raises events from a camera's activity and runs the detector on gated frames",
        per_camera: true,
        consumes: &[Stream::Frames, Stream::Activity],
        produces: &[Stream::Events, Stream::Detections],
        section: "[gate]",
        unit: Some("isochron-gate@.service"),
        runs: Runs::Always,
        counters: counters::gate::SCHEMA,
    },
    StageSpec {
        kind: StageKind::Costmap,
        name: "costmap",
        binary: "isochron-costmap",
        about: "Publishes block activity on the robots' map as a ROS 2 OccupancyGrid, writes \
                snapshots, and answers planning requests",
        per_camera: false,
        consumes: &[Stream::Activity, Stream::Detections],
        produces: &[],
        section: "[costmap]",
        unit: Some("isochron-costmap.service"),
        runs: Runs::Always,
        counters: counters::costmap::SCHEMA,
    },
    StageSpec {
        kind: StageKind::Exporter,
        name: "exporter",
        binary: "isochron-exporter",
        about: "Serves every isochron service's status as Prometheus metrics at /metrics",
        per_camera: false,
        consumes: &[],
        produces: &[],
        section: "[exporter]",
        unit: Some("isochron-exporter.service"),
        runs: Runs::WhenConfigured {
            configured: |c| c.exporter.is_some(),
            in_replay: true,
        },
        counters: counters::exporter::SCHEMA,
    },
    StageSpec {
        kind: StageKind::Link,
        name: "link",
        binary: "isochron-link",
        about: "Carries the activity of this box's exported cameras to the site's other base \
                stations over ROS 2 DDS, and writes the imported cameras' activity into this \
                box's services as if local",
        per_camera: false,
        consumes: &[Stream::Activity, Stream::Events, Stream::Detections],
        produces: &[Stream::Activity, Stream::Events, Stream::Detections],
        section: "[link]",
        unit: Some("isochron-link.service"),
        runs: Runs::WhenConfigured {
            configured: |c| c.link.is_enabled(),
            in_replay: false,
        },
        counters: counters::link::SCHEMA,
    },
    StageSpec {
        kind: StageKind::Mqtt,
        name: "mqtt",
        binary: "isochron-mqtt",
        about: "Publishes zone events and detections as JSON to an MQTT broker",
        per_camera: false,
        consumes: &[Stream::Events, Stream::Detections],
        produces: &[],
        section: "[mqtt]",
        unit: Some("isochron-mqtt.service"),
        runs: Runs::WhenConfigured {
            configured: |c| c.mqtt.is_some(),
            in_replay: true,
        },
        counters: counters::mqtt::SCHEMA,
    },
    StageSpec {
        kind: StageKind::View,
        name: "view",
        binary: "isochron",
        about: "Shows the site live in Foxglove (`isochron view`) or records it into an MCAP \
                file (`isochron record`)",
        per_camera: false,
        consumes: &Stream::ALL,
        produces: &[],
        section: "[view]",
        unit: None,
        runs: Runs::OnDemand,
        counters: counters::view::SCHEMA,
    },
];

impl StageKind {
    /// Every stage, in table order.
    pub fn all() -> impl Iterator<Item = StageKind> {
        STAGES.iter().map(|s| s.kind)
    }

    /// The pipeline: the stages that always run, in order (upstream first).
    pub fn pipeline() -> impl Iterator<Item = StageKind> {
        STAGES
            .iter()
            .filter(|s| matches!(s.runs, Runs::Always))
            .map(|s| s.kind)
    }

    /// The stages with a service binary of their own (all but the view).
    pub fn services() -> impl Iterator<Item = StageKind> {
        STAGES
            .iter()
            .filter(|s| !matches!(s.runs, Runs::OnDemand))
            .map(|s| s.kind)
    }

    /// The stages `isochron up` starts for `config`: the pipeline and the
    /// optional services it configures, in table order.
    pub fn started(config: &Config) -> impl Iterator<Item = StageKind> + '_ {
        STAGES
            .iter()
            .filter(|s| match s.runs {
                Runs::Always => true,
                Runs::WhenConfigured { configured, .. } => configured(config),
                Runs::OnDemand => false,
            })
            .map(|s| s.kind)
    }

    /// The stages `isochron replay` starts for `config` ([`StageKind::started`]
    /// but those not replayed).
    pub fn replayed(config: &Config) -> impl Iterator<Item = StageKind> + '_ {
        StageKind::started(config).filter(|k| match k.spec().runs {
            Runs::WhenConfigured { in_replay, .. } => in_replay,
            _ => true,
        })
    }

    /// The services of `stages` on `config`'s site, as `(stage, camera)`: a
    /// per-camera stage once for each camera this box runs
    /// ([`Config::local_cameras`]) and each camera `[link]` imports (the link
    /// relays their remote stages' status: their liveness is the remote box's),
    /// a site-wide one once, with camera "".
    pub fn services_of(
        stages: impl Iterator<Item = StageKind>,
        config: &Config,
    ) -> Vec<(StageKind, String)> {
        let cameras: Vec<&String> = (config.local_cameras().map(|c| &c.id))
            .chain(&config.link.import)
            .collect();
        let mut services = Vec::new();
        for stage in stages {
            if stage.per_camera() {
                services.extend(cameras.iter().map(|c| (stage, c.to_string())));
            } else {
                services.push((stage, String::new()));
            }
        }
        services
    }

    /// The stage's row of [`STAGES`].
    pub fn spec(self) -> &'static StageSpec {
        &STAGES[self as usize]
    }

    /// The stage's name, as in node names, status services and logs.
    pub fn name(self) -> &'static str {
        self.spec().name
    }

    /// The stage named `name`, if any.
    pub fn from_name(name: &str) -> Option<StageKind> {
        STAGES.iter().find(|s| s.name == name).map(|s| s.kind)
    }

    /// The binary that runs the stage.
    pub fn binary(self) -> &'static str {
        self.spec().binary
    }

    /// What the stage's binary does, as its `--help` and man page say.
    pub fn about(self) -> &'static str {
        self.spec().about
    }

    /// The streams the stage reads.
    pub fn consumes(self) -> &'static [Stream] {
        self.spec().consumes
    }

    /// The streams the stage publishes.
    pub fn produces(self) -> &'static [Stream] {
        self.spec().produces
    }

    /// The stream whose end of stream says the stage has finished a recording, if
    /// the stage passes one on.
    pub fn end_stream(self) -> Option<Stream> {
        self.produces().first().copied()
    }

    /// True for stages that run once per camera.
    pub fn per_camera(self) -> bool {
        self.spec().per_camera
    }

    /// True for a stage whose failure does not stop a replay (an optional one).
    pub fn optional(self) -> bool {
        !matches!(self.spec().runs, Runs::Always)
    }

    /// The counters of the stage's status.
    pub fn counters(self) -> &'static [CounterSpec] {
        self.spec().counters
    }
}

impl std::fmt::Display for StageKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_are_in_kind_order() {
        for (i, spec) in STAGES.iter().enumerate() {
            assert_eq!(spec.kind as usize, i, "{} is out of order", spec.name);
        }
    }

    #[test]
    fn every_consumed_stream_is_produced_upstream() {
        let pipeline: Vec<StageKind> = StageKind::pipeline().collect();
        for (i, stage) in pipeline.iter().enumerate() {
            for stream in stage.consumes() {
                assert!(
                    pipeline[..i]
                        .iter()
                        .any(|up| up.produces().contains(stream)),
                    "{stage} reads {stream}, which no stage before it produces"
                );
            }
        }
    }

    #[test]
    fn names_round_trip() {
        for stage in StageKind::services() {
            assert_eq!(StageKind::from_name(stage.name()), Some(stage));
            assert_eq!(stage.binary(), format!("isochron-{stage}"));
            let unit = stage.spec().unit.unwrap();
            assert!(unit.starts_with(stage.binary()));
            assert_eq!(unit.contains('@'), stage.per_camera());
        }
        assert_eq!(StageKind::from_name("view"), Some(StageKind::View));
        assert!(!StageKind::View.per_camera());
        assert_eq!(StageKind::from_name("nope"), None);
    }

    #[test]
    fn counter_names_and_metrics_are_unique_and_fit_a_status() {
        let mut metrics = std::collections::HashSet::new();
        for spec in &STAGES {
            assert!(spec.counters.len() <= isochron_wire::STATUS_COUNTERS);
            let mut names = std::collections::HashSet::new();
            for c in spec.counters {
                assert!(names.insert(c.name), "{}: {} twice", spec.name, c.name);
                if c.metric.is_empty() {
                    continue;
                }
                assert!(metrics.insert(c.metric), "metric {} twice", c.metric);
                assert!(c.metric.starts_with("isochron_"));
                if c.unit == counters::Unit::Millis {
                    assert!(c.metric.ends_with("_seconds"), "{}", c.metric);
                }
            }
        }
    }

    #[test]
    fn what_runs_follows_the_config() {
        let mut config = Config::default();
        let started: Vec<_> = StageKind::started(&config).collect();
        assert_eq!(started, StageKind::pipeline().collect::<Vec<_>>());
        config.link.import = vec!["far01".into()];
        config.mqtt = Some(Default::default());
        let started: Vec<_> = StageKind::started(&config).collect();
        assert!(started.contains(&StageKind::Link) && started.contains(&StageKind::Mqtt));
        let replayed: Vec<_> = StageKind::replayed(&config).collect();
        assert!(!replayed.contains(&StageKind::Link) && replayed.contains(&StageKind::Mqtt));
    }
}
