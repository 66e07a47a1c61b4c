//! Every stage's counters, declared once: the schema of the numbers a stage
//! publishes in its [`StageStatus`](isochron_wire::StageStatus) slots.
//!
//! Each stage's module names its counters ([`CounterId`] constants, in slot
//! order) and lists their [`CounterSpec`]s in `SCHEMA`; its row of the stage
//! table ([`crate::topology`]) points at that schema. A stage fills the slots
//! with [`Counters::set`] by constant, the status line and `isochron status`
//! print them as `name=value` words, and the exporter makes one metric of each
//! from the same spec: a counter's name is spelled here and nowhere else.

use isochron_wire::STATUS_COUNTERS;

/// A total that only grows (until its service restarts), or a value that goes
/// up and down.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CounterKind {
    /// A total that only grows (until its service restarts).
    Counter,
    /// A value that goes up and down.
    Gauge,
}

/// The unit of a slot's value.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Unit {
    /// A number of things.
    Count,
    /// Milliseconds; the metric is in seconds.
    Millis,
    /// Per second.
    PerSecond,
    /// 1 or 0.
    Flag,
}

/// One counter of a stage's status.
#[derive(Debug, Clone, Copy)]
pub struct CounterSpec {
    /// Its key in status lines and `isochron status` (`reconnects`).
    pub name: &'static str,
    /// Counter or gauge.
    pub kind: CounterKind,
    /// The unit of the slot's value.
    pub unit: Unit,
    /// The Prometheus metric made of it (a counter gets `_total` when encoded);
    /// empty for one shown in status lines only (the exporter's own HTTP
    /// counters, which it serves as metrics of their own).
    pub metric: &'static str,
    /// The metric's help text.
    pub help: &'static str,
}

impl CounterSpec {
    /// `value` (in [`CounterSpec::unit`]) in the metric's unit: milliseconds
    /// become seconds.
    pub fn metric_value(&self, value: f64) -> f64 {
        match self.unit {
            Unit::Millis => value * 1e-3,
            _ => value,
        }
    }

    /// `value` as the status line writes it.
    fn format(&self, value: f64) -> String {
        match self.unit {
            Unit::Count | Unit::Flag => format!("{}", value.round() as i64),
            Unit::Millis | Unit::PerSecond => format!("{value:.2}"),
        }
    }
}

/// The slot of a counter in its stage's schema.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CounterId(pub usize);

/// A fingerprint of `schema` (names, kinds, units, order): a status whose
/// fingerprint differs was written by a build with other counters, and its slots
/// are not read as this build's.
pub const fn fingerprint(schema: &[CounterSpec]) -> u32 {
    // FNV-1a over the names, kinds and units.
    let mut h: u32 = 0x811c_9dc5;
    let mut i = 0;
    while i < schema.len() {
        let name = schema[i].name.as_bytes();
        let mut j = 0;
        while j < name.len() {
            h = (h ^ name[j] as u32).wrapping_mul(0x0100_0193);
            j += 1;
        }
        let tag = (schema[i].kind as u32) << 4 | schema[i].unit as u32;
        h = (h ^ tag).wrapping_mul(0x0100_0193);
        i += 1;
    }
    h
}

/// The values of one stage's counters, filled by the stage at each report.
#[derive(Debug, Clone)]
pub struct Counters {
    schema: &'static [CounterSpec],
    values: [f64; STATUS_COUNTERS],
}

impl Counters {
    /// All zero, for `schema`.
    pub fn new(schema: &'static [CounterSpec]) -> Self {
        Counters {
            schema,
            values: [0.0; STATUS_COUNTERS],
        }
    }

    /// Sets counter `id` to `value`.
    pub fn set(&mut self, id: CounterId, value: impl Into<SlotValue>) {
        if let Some(slot) = self.values.get_mut(id.0) {
            *slot = value.into().0;
        }
    }

    /// The value of counter `id`.
    pub fn get(&self, id: CounterId) -> f64 {
        self.values.get(id.0).copied().unwrap_or(0.0)
    }

    /// The slots, as the status carries them.
    pub fn slots(&self) -> [f64; STATUS_COUNTERS] {
        self.values
    }

    /// The schema's counters read from `slots` (a status's).
    pub fn from_slots(schema: &'static [CounterSpec], slots: [f64; STATUS_COUNTERS]) -> Self {
        Counters {
            schema,
            values: slots,
        }
    }

    /// `name=value` words of every counter, for status lines and `isochron
    /// status` (`reconnects=0 loops=1 source_fps=25.00`).
    pub fn words(&self) -> String {
        self.schema
            .iter()
            .zip(self.values)
            .map(|(spec, v)| format!("{}={}", spec.name, spec.format(v)))
            .collect::<Vec<_>>()
            .join(" ")
    }

    /// `(spec, value)` of every counter.
    pub fn iter(&self) -> impl Iterator<Item = (&'static CounterSpec, f64)> + '_ {
        self.schema.iter().zip(self.values)
    }
}

/// What a counter slot takes: integers and floats, as `f64` (exact to 2⁵³).
#[derive(Debug, Clone, Copy)]
pub struct SlotValue(f64);

macro_rules! into_f64 {
    ($($t:ty),*) => {$(
        impl From<$t> for SlotValue {
            fn from(v: $t) -> Self {
                SlotValue(v as f64)
            }
        }
    )*};
}
into_f64!(u64, u32, usize, i64, f32, f64);

impl From<bool> for SlotValue {
    fn from(v: bool) -> Self {
        SlotValue(if v { 1.0 } else { 0.0 })
    }
}

/// Declares one stage's counters: a [`CounterId`] constant per counter (in slot
/// order) and their `SCHEMA`.
macro_rules! schema {
    ($(#[$doc:meta])* $module:ident {
        $($id:ident = $name:literal, $kind:ident, $unit:ident, $metric:literal, $help:literal;)*
    }) => {
        $(#[$doc])*
        pub mod $module {
            use super::{CounterId, CounterKind, CounterSpec, Unit};
            schema!(@ids 0usize; $($id, $help;)*);
            /// The counters, in slot order.
            pub const SCHEMA: &[CounterSpec] = &[$(CounterSpec {
                name: $name,
                kind: CounterKind::$kind,
                unit: Unit::$unit,
                metric: $metric,
                help: $help,
            }),*];
        }
    };
    (@ids $n:expr; $id:ident, $help:literal; $($rest:tt)*) => {
        #[doc = $help]
        pub const $id: CounterId = CounterId($n);
        schema!(@ids $n + 1usize; $($rest)*);
    };
    (@ids $n:expr;) => {};
}

schema! {
    /// `isochron-capture`.
    capture {
        RECONNECTS = "reconnects", Counter, Count, "isochron_capture_reconnects",
            "Times capture reopened its camera or file after a failure.";
        LOOPS = "loops", Counter, Count, "isochron_capture_loops",
            "Times capture started its file again from the beginning (camera.loop_file).";
        SOURCE_FPS = "source_fps", Gauge, PerSecond, "isochron_capture_source_fps",
            "Frame rate the camera or file states.";
        SOURCE_UP = "source_up", Gauge, Flag, "isochron_capture_source_up",
            "1 while capture has its camera or file open.";
        FRAMES_READ = "frames_read", Gauge, Count, "isochron_capture_file_frames_read",
            "Frames read from a file that ended (0 before its end).";
        FRAMES_STATED = "frames_stated", Gauge, Count, "isochron_capture_file_frames_stated",
            "Frames a file that ended states it holds (0 if it does not say).";
        TRUNCATED = "truncated", Gauge, Flag, "isochron_capture_file_truncated",
            "1 when a file ended well before the frame count it states.";
        DAMAGED = "damaged_frames", Counter, Count, "isochron_capture_damaged_frames",
            "Frames of a network camera the decoder found damaged (lost packets), and those after them until the next clean key frame: not published.";
        DOWN_REFUSED = "down_refused", Gauge, Flag, "isochron_capture_down_refused",
            "1 while the camera is down because nothing accepts the connection (the camera, its server or its port is off).";
        DOWN_TIMED_OUT = "down_timed_out", Gauge, Flag, "isochron_capture_down_timed_out",
            "1 while the camera is down because it does not answer within camera.connect_timeout_s (unplugged, unreachable, overloaded).";
        DOWN_UNAUTHORIZED = "down_unauthorized", Gauge, Flag, "isochron_capture_down_unauthorized",
            "1 while the camera is down because it refuses the credentials in the URL.";
        DOWN_NOT_FOUND = "down_not_found", Gauge, Flag, "isochron_capture_down_not_found",
            "1 while the camera is down because it has no stream at the URL's path (or the host name is unknown, or the device does not exist).";
        DOWN_STALLED = "down_stalled", Gauge, Flag, "isochron_capture_down_stalled",
            "1 while the camera is down because it sent no frame for camera.read_timeout_s.";
        DOWN_BAD_STREAM = "down_bad_stream", Gauge, Flag, "isochron_capture_down_bad_stream",
            "1 while the camera is down because what it sends cannot be decoded (no video, an unknown codec, garbage).";
        DOWN_OTHER = "down_other", Gauge, Flag, "isochron_capture_down_other",
            "1 while the camera is down for another reason (the log's WARN says which).";
    }
}

schema! {
    /// `isochron-motion`.
    motion {
        ILLUMINATION = "illumination", Counter, Count, "isochron_motion_illumination_frames",
            "Frames whose change was a global light change, not motion.";
        SUPPRESSED = "suppressed", Counter, Count, "isochron_motion_suppressed_frames",
            "Frames whose motion was suppressed (light changes, camera shake).";
        MASKED_BLOCKS = "masked_blocks", Gauge, Count, "isochron_motion_masked_blocks",
            "Blocks of the grid the camera's mask leaves out.";
        GRID_BLOCKS = "grid_blocks", Gauge, Count, "isochron_motion_grid_blocks",
            "Blocks of the camera's grid (0 before the first frame).";
        RESTARTS = "restarts", Counter, Count, "isochron_motion_restarts",
            "Times motion restarted its detector (a new frame size or stream).";
    }
}

schema! {
    /// `isochron-cascade`.
    cascade {
        SECONDS = "seconds", Counter, Count, "isochron_cascade_seconds",
            "Seconds of activity the cascade published.";
        LEARNED = "learned", Counter, Count, "isochron_cascade_learned",
            "Minutes the long-term model learned.";
        SPARSE = "sparse", Counter, Count, "isochron_cascade_sparse",
            "Minutes with too few frames to teach the long-term model.";
        REPEATED = "repeated", Counter, Count, "isochron_cascade_repeated",
            "Minutes the store had already learned (a replay): not taught again.";
        FRAME_RATE = "r", Gauge, PerSecond, "isochron_cascade_frame_rate",
            "Frame rate of the camera's motion stream.";
        PRESENT = "present", Gauge, Count, "isochron_presence_blocks",
            "Blocks where someone is present now (moved, then stayed).";
        ABSORBED = "absorbed", Counter, Count, "isochron_presence_absorbed",
            "Regions absorbed into the background after presence.absorb_s.";
        GHOSTS = "ghosts", Counter, Count, "isochron_presence_ghosts",
            "Ghosts (someone in the background who left) relearned.";
        COMMITS = "commits", Counter, Count, "isochron_store_commits",
            "Commits to the long-term store.";
        COMMIT_P50 = "commit_ms_p50", Gauge, Millis, "isochron_store_commit_latency_p50_seconds",
            "Median time of a store commit (recent commits).";
        COMMIT_P99 = "commit_ms_p99", Gauge, Millis, "isochron_store_commit_latency_p99_seconds",
            "99th percentile time of a store commit (recent commits).";
        STORE_FAILURES = "store_failures", Counter, Count, "isochron_store_failures",
            "Store commits that failed.";
    }
}

schema! {
    /// `isochron-gate`.
    gate {
        EVENTS = "events", Counter, Count, "isochron_gate_events",
            "Zone events the gate started.";
        OPEN = "open", Gauge, Count, "isochron_gate_open_events",
            "Zone events open now.";
        CONFIRMED = "confirmed", Counter, Count, "isochron_gate_confirmed",
            "Zone events the detector confirmed.";
        FRAMES_SEEN = "frames_seen", Counter, Count, "isochron_gate_frames",
            "Frames the gate saw.";
        DETECTED = "detected", Counter, Count, "isochron_detector_frames",
            "Frames the detector finished.";
        DETECTOR_MS = "detector_ms", Counter, Millis, "isochron_detector_busy_seconds",
            "Time the detector spent detecting.";
        JOBS = "jobs", Counter, Count, "isochron_detector_jobs",
            "Detection jobs handed to the detector.";
        JOBS_DROPPED = "jobs_dropped", Counter, Count, "isochron_detector_jobs_dropped",
            "Detection jobs dropped because the detector was busy.";
    }
}

schema! {
    /// `isochron-costmap`.
    costmap {
        CAMERAS_LIVE = "cameras_live", Gauge, Count, "isochron_costmap_cameras_live",
            "Cameras whose activity reached the cost map recently.";
        CAMERAS = "cameras", Gauge, Count, "isochron_costmap_cameras",
            "Cameras on the cost map.";
        GRIDS = "grids", Counter, Count, "isochron_costmap_grids",
            "Whole cost maps published.";
        UPDATES = "updates", Counter, Count, "isochron_costmap_updates",
            "Cost map updates published.";
        ROS_SUBSCRIBERS = "ros_subscribers", Gauge, Count, "isochron_ros_subscribers",
            "ROS 2 subscribers of the cost map topic.";
        PUBLISH_ERRORS = "publish_errors", Counter, Count, "isochron_ros_publish_errors",
            "Cost map publications to ROS 2 that failed.";
        PLANS = "plans", Counter, Count, "isochron_plans",
            "Planning requests answered.";
        PLANS_REJECTED = "plans_rejected", Counter, Count, "isochron_plans_rejected",
            "Planning requests rejected as malformed.";
        PLANS_DROPPED = "plans_dropped", Counter, Count, "isochron_plans_dropped",
            "Planning requests dropped: a client's or the total queue was full.";
        SNAPSHOTS = "snapshots", Counter, Count, "isochron_costmap_snapshots",
            "Cost map snapshots written.";
        CONFIRMED = "confirmed", Counter, Count, "isochron_costmap_confirmed_people",
            "People the detector confirmed that the cost map placed.";
        PEOPLE_MSGS = "people_msgs", Counter, Count, "isochron_costmap_people_messages",
            "People messages published.";
        MARKERS = "markers", Counter, Count, "isochron_costmap_marker_messages",
            "Marker messages published.";
        PEOPLE_MARKERS = "people_markers", Counter, Count,
            "isochron_costmap_people_marker_messages",
            "People marker messages published.";
        SPEED_MASKS = "speed_masks", Counter, Count, "isochron_costmap_speed_masks",
            "Speed filter masks published.";
        FORECASTS = "forecasts", Counter, Count, "isochron_costmap_forecasts",
            "Forecast grids published.";
        ROUTE_CALLS = "route_calls", Counter, Count, "isochron_route_server_calls",
            "Calls to the route server's DynamicEdgesScorer.";
        ROUTE_FAILURES = "route_failures", Counter, Count, "isochron_route_server_failures",
            "Calls to the route server that failed: not sent, not answered in time, or refused.";
        ROUTE_EDGES = "route_edges", Counter, Count, "isochron_route_server_edges",
            "Edges closed, opened or adjusted in calls the route server took.";
        ROUTE_CLOSED = "route_closed", Gauge, Count, "isochron_route_server_closed_edges",
            "Route graph edges closed now (people stand across them).";
        ROUTE_LATENCY = "route_latency_ms", Gauge, Millis, "isochron_route_server_answer_seconds",
            "How long the route server's last answer took.";
        ROUTE_SERVER_UP = "route_server_up", Gauge, Flag, "isochron_route_server_up",
            "1 while the route server answers.";
    }
}

schema! {
    /// `isochron-exporter`.
    exporter {
        SCRAPES = "scrapes", Counter, Count, "",
            "Scrapes the exporter answered.";
        UP = "up", Gauge, Count, "isochron_exporter_services_up",
            "Watched services that are up.";
        WATCHED = "watched", Gauge, Count, "isochron_exporter_services_watched",
            "Services the exporter watches.";
        CONNECTIONS = "connections", Gauge, Count, "",
            "Connections open now.";
        REFUSED = "refused", Counter, Count, "",
            "Connections or requests the exporter refused (over its limits).";
    }
}

schema! {
    /// `isochron-link`. `act`, `ev`, `det`, `st`: the activity, events,
    /// detections and status streams, summed over the cameras.
    link {
        ACT_OUT = "act_out", Counter, Count, "isochron_link_activity_sent",
            "Activity messages the link sent to other boxes.";
        EV_OUT = "ev_out", Counter, Count, "isochron_link_events_sent",
            "Event messages the link sent to other boxes.";
        EV_DROP = "ev_drop", Counter, Count, "isochron_link_events_dropped",
            "Event messages dropped on this box before sending (a full queue).";
        DET_OUT = "det_out", Counter, Count, "isochron_link_detections_sent",
            "Detection messages the link sent to other boxes.";
        DET_DROP = "det_drop", Counter, Count, "isochron_link_detections_dropped",
            "Detection messages dropped on this box before sending (a full queue).";
        ST_OUT = "st_out", Counter, Count, "isochron_link_status_sent",
            "Status messages the link sent to other boxes.";
        ACT_IN = "act_in", Counter, Count, "isochron_link_activity_received",
            "Activity messages the link received from other boxes.";
        EV_IN = "ev_in", Counter, Count, "isochron_link_events_received",
            "Event messages the link received from other boxes.";
        EV_GAP = "ev_gap", Counter, Count, "isochron_link_events_missing",
            "Event messages missing in the received sequences.";
        DET_IN = "det_in", Counter, Count, "isochron_link_detections_received",
            "Detection messages the link received from other boxes.";
        DET_GAP = "det_gap", Counter, Count, "isochron_link_detections_missing",
            "Detection messages missing in the received sequences.";
        ST_IN = "st_in", Counter, Count, "isochron_link_status_received",
            "Status messages the link received from other boxes.";
        ERRORS = "err", Counter, Count, "isochron_link_write_errors",
            "DDS writes that failed.";
        IMPORTS = "imports", Gauge, Count, "isochron_link_imports",
            "Remote cameras the link imports.";
        IMPORTS_LIVE = "imports_live", Gauge, Count, "isochron_link_imports_live",
            "Imported cameras whose box was heard from within link's stale time.";
    }
}

schema! {
    /// `isochron-mqtt`.
    mqtt {
        CONNECTED = "connected", Gauge, Flag, "isochron_mqtt_connected",
            "1 while the MQTT sink is connected to its broker.";
        MESSAGES = "messages", Counter, Count, "isochron_mqtt_messages",
            "Messages (zone events, detections) the MQTT sink queued for the broker.";
        QUEUED = "queued", Gauge, Count, "isochron_mqtt_queued",
            "Messages waiting for the broker.";
        QUEUE_DROPPED = "queue_dropped", Counter, Count, "isochron_mqtt_queue_dropped",
            "Messages dropped because the queue to the broker was full.";
        RECONNECTS = "reconnects", Counter, Count, "isochron_mqtt_reconnects",
            "Times the MQTT sink connected to its broker again.";
        REFUSED = "refused", Counter, Count, "isochron_mqtt_refused",
            "Connection attempts the MQTT broker refused (bad user name or password, not authorized).";
        TLS_FAILURES = "tls_failures", Counter, Count, "isochron_mqtt_tls_failures",
            "Connection attempts to the MQTT broker whose TLS handshake failed.";
        EVENTS_REJECTED = "events_rejected", Counter, Count, "isochron_mqtt_events_rejected",
            "Zone event records the MQTT sink rejected as impossible (ending before they start) and did not publish.";
        ACK_P50 = "ack_ms_p50", Gauge, Millis, "isochron_mqtt_ack_latency_p50_seconds",
            "Median time from the sink receiving a gate's sample to the broker's acknowledgement (recent messages).";
        ACK_P99 = "ack_ms_p99", Gauge, Millis, "isochron_mqtt_ack_latency_p99_seconds",
            "99th percentile time from the sink receiving a gate's sample to the broker's acknowledgement (recent messages).";
    }
}

schema! {
    /// The view and recorder (`isochron view`, `record`, `replay --record`).
    view {
        PUBLISHED = "published", Counter, Count, "isochron_view_published",
            "Messages the view or recorder wrote.";
        TOPICS = "topics", Gauge, Count, "isochron_view_topics",
            "Topics (channels) the view or recorder has.";
        CLIENTS = "clients", Gauge, Count, "isochron_view_clients",
            "Foxglove clients connected to the live view.";
        REFUSED_CLIENTS = "refused_clients", Counter, Count, "isochron_view_refused_clients",
            "Clients refused (over view.max_clients).";
        CLIENT_DROPS = "client_drops", Counter, Count, "isochron_view_client_drops",
            "Messages dropped for clients that read too slowly.";
        STALLED_CLIENTS = "stalled_clients", Counter, Count, "isochron_view_stalled_clients",
            "Clients disconnected for not reading.";
        QUEUED_BYTES = "queued_bytes", Gauge, Count, "isochron_view_queued_bytes",
            "Bytes queued for the live view's clients.";
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slots_hold_integers_exactly_and_print_as_words() {
        let mut c = Counters::new(gate::SCHEMA);
        c.set(gate::EVENTS, u64::MAX >> 11);
        c.set(gate::DETECTOR_MS, 12.345f64);
        assert_eq!(c.get(gate::EVENTS), (u64::MAX >> 11) as f64);
        let words = c.words();
        assert!(words.starts_with(&format!("events={} open=0", u64::MAX >> 11)));
        assert!(words.contains("detector_ms=12.35"));
        assert_eq!(gate::SCHEMA[gate::DETECTED.0].name, "detected");
    }

    #[test]
    fn fingerprints_tell_schemas_apart() {
        assert_ne!(fingerprint(gate::SCHEMA), fingerprint(costmap::SCHEMA));
        assert_ne!(fingerprint(gate::SCHEMA), fingerprint(&gate::SCHEMA[1..]));
        assert_eq!(fingerprint(gate::SCHEMA), fingerprint(gate::SCHEMA));
    }
}
