//! The pipeline's shape, spelled once: which stages exist, the binary of each, the
//! streams each consumes and produces, and whether it runs per camera.
//!
//! The launcher (`isochron up`), `isochron replay`, health reports and node names
//! take their stage names from here instead of string literals.

use isochron_wire::Stream;

/// One service of the process group.
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
    /// Serves every stage's status as Prometheus metrics (site-wide, optional:
    /// not a pipeline stage, so not in [`StageKind::ALL`]).
    Exporter,
    /// The link to the site's other base stations (`isochron-link`): optional,
    /// started by its own unit, so it is not in [`StageKind::ALL`] (the stages
    /// `isochron up` starts).
    Link,
    /// Publishes zone events and detections to an MQTT broker (`isochron-mqtt`;
    /// site-wide, optional: started when `[mqtt]` is configured, so not in
    /// [`StageKind::ALL`]).
    Mqtt,
    /// What people look at: the live Foxglove view (`isochron view`) and MCAP
    /// recordings (`isochron record`, `isochron replay --record`). Site-wide, run
    /// on demand by the `isochron` command (no binary of its own, so neither in
    /// [`StageKind::ALL`] nor in [`StageKind::EVERY`]); it reports its status like
    /// every stage, so `isochron status` lists it while it runs.
    View,
}

impl StageKind {
    /// Every stage, in pipeline order (upstream first).
    pub const ALL: [StageKind; 5] = [
        StageKind::Capture,
        StageKind::Motion,
        StageKind::Cascade,
        StageKind::Gate,
        StageKind::Costmap,
    ];

    /// Every stage with a binary of its own: [`StageKind::ALL`], then the optional
    /// site-wide exporter, link and MQTT sink.
    pub const EVERY: [StageKind; 8] = [
        StageKind::Capture,
        StageKind::Motion,
        StageKind::Cascade,
        StageKind::Gate,
        StageKind::Costmap,
        StageKind::Exporter,
        StageKind::Link,
        StageKind::Mqtt,
    ];

    /// The stage's name, as in node names, status services and logs.
    pub fn name(self) -> &'static str {
        match self {
            StageKind::Capture => "capture",
            StageKind::Motion => "motion",
            StageKind::Cascade => "cascade",
            StageKind::Gate => "gate",
            StageKind::Costmap => "costmap",
            StageKind::Exporter => "exporter",
            StageKind::Link => "link",
            StageKind::Mqtt => "mqtt",
            StageKind::View => "view",
        }
    }

    /// The stage named `name`, if any.
    pub fn from_name(name: &str) -> Option<StageKind> {
        StageKind::EVERY
            .into_iter()
            .chain([StageKind::View])
            .find(|s| s.name() == name)
    }

    /// The binary that runs the stage (`isochron` for the view: its `view` and
    /// `record` commands).
    pub fn binary(self) -> &'static str {
        match self {
            StageKind::Capture => "isochron-capture",
            StageKind::Motion => "isochron-motion",
            StageKind::Cascade => "isochron-cascade",
            StageKind::Gate => "isochron-gate",
            StageKind::Costmap => "isochron-costmap",
            StageKind::Exporter => "isochron-exporter",
            StageKind::Link => "isochron-link",
            StageKind::Mqtt => "isochron-mqtt",
            StageKind::View => "isochron",
        }
    }

    /// What the stage's binary does, as its `--help` and man page say.
    pub fn about(self) -> &'static str {
        match self {
            StageKind::Capture => {
                "Reads one camera or video file and publishes its frames on `<prefix>/<camera>/frames`"
            }
            StageKind::Motion => {
                "Reads a camera's `frames` and publishes per-block motion on `<prefix>/<camera>/motion`"
            }
            StageKind::Cascade => {
                "Filters one camera's motion stream into 1-Hz activity and the long-term store"
            }
            StageKind::Gate => {
                "Raises events from a camera's activity and runs the detector on gated frames"
            }
            StageKind::Costmap => {
                "Publishes block activity on the robots' map as a ROS 2 OccupancyGrid, writes \
                 snapshots, and answers planning requests"
            }
            StageKind::Exporter => {
                "Serves every isochron service's status as Prometheus metrics at /metrics"
            }
            StageKind::Link => {
                "Carries the activity of this box's exported cameras to the site's other base \
                 stations over ROS 2 DDS, and writes the imported cameras' activity into this \
                 box's services as if local"
            }
            StageKind::Mqtt => "Publishes zone events and detections as JSON to an MQTT broker",
            StageKind::View => {
                "Shows the site live in Foxglove (`isochron view`) or records it into an MCAP \
                 file (`isochron record`)"
            }
        }
    }

    /// The streams the stage reads (of its camera, or of every camera if site-wide).
    pub fn consumes(self) -> &'static [Stream] {
        match self {
            StageKind::Capture => &[],
            StageKind::Motion => &[Stream::Frames],
            StageKind::Cascade => &[Stream::Motion],
            StageKind::Gate => &[Stream::Frames, Stream::Activity],
            StageKind::Costmap => &[Stream::Activity, Stream::Detections],
            StageKind::Exporter => &[],
            StageKind::Link => &[Stream::Activity, Stream::Events, Stream::Detections],
            StageKind::Mqtt => &[Stream::Events, Stream::Detections],
            StageKind::View => &Stream::ALL,
        }
    }

    /// The streams the stage publishes.
    pub fn produces(self) -> &'static [Stream] {
        match self {
            StageKind::Capture => &[Stream::Frames],
            StageKind::Motion => &[Stream::Motion],
            StageKind::Cascade => &[Stream::Activity],
            StageKind::Gate => &[Stream::Events, Stream::Detections],
            StageKind::Costmap | StageKind::Exporter | StageKind::Mqtt | StageKind::View => &[],
            StageKind::Link => &[Stream::Activity, Stream::Events, Stream::Detections],
        }
    }

    /// The stream whose end of stream says the stage has finished a recording, if
    /// the stage passes one on.
    pub fn end_stream(self) -> Option<Stream> {
        self.produces().first().copied()
    }

    /// True for stages that run once per camera; false for the site-wide costmap,
    /// exporter, link, MQTT sink and view.
    pub fn per_camera(self) -> bool {
        !matches!(
            self,
            StageKind::Costmap
                | StageKind::Exporter
                | StageKind::Link
                | StageKind::Mqtt
                | StageKind::View
        )
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
    fn every_consumed_stream_is_produced_upstream() {
        for (i, stage) in StageKind::ALL.iter().enumerate() {
            for stream in stage.consumes() {
                assert!(
                    StageKind::ALL[..i]
                        .iter()
                        .any(|up| up.produces().contains(stream)),
                    "{stage} reads {stream}, which no stage before it produces"
                );
            }
        }
    }

    #[test]
    fn names_round_trip() {
        for stage in StageKind::EVERY {
            assert_eq!(StageKind::from_name(stage.name()), Some(stage));
            assert_eq!(stage.binary(), format!("isochron-{stage}"));
        }
        assert_eq!(StageKind::from_name("view"), Some(StageKind::View));
        assert!(!StageKind::View.per_camera());
        assert_eq!(StageKind::from_name("nope"), None);
    }
}
