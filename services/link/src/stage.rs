//! The link's stage: exported cameras' small streams → DDS, DDS → imported
//! cameras' streams in this box's iceoryx2 services.
//!
//! * Export: every wake takes what each exported camera's `activity`, `events`
//!   and `detections` inputs hold. Activity is latest-only (an older sample still
//!   waiting is counted as dropped); events and detections go into a bounded
//!   queue per camera and stream (`link.queue_messages`) that drops its oldest
//!   message when full and counts it. A queue is sent while a reader is matched
//!   and DDS's reliable window has room; what does not fit waits for the next
//!   pass, so a write never blocks the link. Every tick also sends each stage's
//!   status when it reported anew.
//! * Import: every tick ([`POLL`]) takes what DDS received for each imported
//!   camera (DDS's keep-last history is the importing side's bounded queue) and
//!   publishes it with the remote header unchanged — sequence, capture and
//!   origin times — so the bridge, `tap`, `status` and the exporter see a local
//!   camera and measure gaps and latency end to end. A sequence gap (a record
//!   dropped on either side or lost on the way) is counted. A link that stops
//!   receiving writes nothing: the bridge's `costmap.stale_s` then turns the
//!   camera's cells unknown.
//!
//! The status detail counts per stream across cameras (`act`, `ev`, `det`,
//! `st`): `<s>_out` sent, `<s>_in` received; for events and detections also
//! `<s>_drop`, dropped on this box before sending (a full queue, or lost in
//! its iceoryx2 buffer), and `<s>_gap`, missing in the received sequences (dropped
//! on the exporting box, or lost in this box's DDS history).

use std::collections::{HashMap, VecDeque};
use std::net::IpAddr;
use std::time::{Duration, Instant};

use ros2_client::WriteError;
use ros2_client::dds::{Node, Publisher, Subscription};

use isochron_config::LoadedConfig;
use isochron_config::clock::wall_now_ns;
use isochron_exit as exit;
use isochron_runtime::ipc::{Activity, Detections, Events, Ipc, StatusPublisher, StatusSubscriber};
use isochron_runtime::service::{Fatal, open_files, raise_open_file_limit};
use isochron_runtime::stage::{Context, Input, Output, Stage, Woken};
use isochron_runtime::topology::StageKind;
use isochron_wire::geometry::BlockGrid;
use isochron_wire::{CameraId, KnownGrid, StageStatus, StreamHeader, fixed_str};

use crate::dds::LinkDds;
use crate::msgs::{Delivery, LinkStream, Message, Status, cdr_len, check_box_id, printable};

/// How often the DDS readers are polled: a message waits at most this long on
/// the importing box.
pub const POLL: Duration = Duration::from_millis(20);

/// Files a link needs besides what it holds when it starts: RustDDS's
/// participant (its sockets and event loop: about 50, counted in the site bench's
/// link), then four sockets per DDS reader and two per writer (RustDDS's poll
/// and status channels are socket pairs; it panics when it cannot make one), and
/// iceoryx2's: an imported camera's three publishers (each a port tag, the
/// service's dynamic config and its data segment) with their notifiers (a port
/// tag and the event service's dynamic config) and a status publisher per stage
/// (3 files); an exported camera's three subscribers (a port tag, the dynamic
/// config, the publisher's data segment) with their listeners (a socket, a port
/// tag, the event's dynamic config) and a status subscriber per stage (3).
struct FileBudget {
    dds_base: u64,
    per_import: u64,
    per_export: u64,
    spare: u64,
}

impl FileBudget {
    fn new() -> Self {
        let stages = camera_stages().count() as u64;
        let (reader, writer) = (4, 2);
        FileBudget {
            dds_base: 64,
            per_import: 4 * reader + 3 * (3 + 2) + 3 * stages,
            per_export: 4 * writer + 3 * (3 + 3) + 3 * stages,
            spare: 64,
        }
    }

    /// Files needed by a link of `imports` and `exports` cameras, on top of `open`.
    fn need(&self, open: u64, imports: usize, exports: usize) -> u64 {
        open + self.dds_base
            + imports as u64 * self.per_import
            + exports as u64 * self.per_export
            + self.spare
    }
}

/// Checks, before joining DDS, that the process may open the files the link
/// will need (after raising its soft limit to its hard one); else fails with one
/// line naming the limit to set and the value.
fn check_open_files(imports: usize, exports: usize) -> Result<(), Fatal> {
    let (Some(limit), Some(open)) = (raise_open_file_limit(), open_files()) else {
        return Ok(());
    };
    let budget = FileBudget::new();
    let need = budget.need(open, imports, exports);
    if need > limit {
        return Err(Fatal::new(
            exit::CONFIG,
            format!(
                "importing {imports} and exporting {exports} cameras needs about {need} open files \
                 ({} per imported camera: DDS readers' sockets and iceoryx2 ports) but this process \
                 may open {limit}: raise LimitNOFILE= of isochron-link.service (or `ulimit -n` where \
                 it is started by hand) to at least {need}",
                budget.per_import
            ),
        ));
    }
    tracing::info!(open, need, limit, "open files");
    Ok(())
}

/// This box's DDS Security enclave (`link.security_dir`, relative to the config
/// file), checked to hold its files. Without one the link runs unauthenticated,
/// which it refuses on an interface other than loopback unless `link.insecure`
/// says so.
fn enclave(loaded: &LoadedConfig) -> Result<Option<std::path::PathBuf>, Fatal> {
    let link = &loaded.config.link;
    let Some(dir) = &link.security_dir else {
        if link.leaves_the_box() && !link.insecure {
            return Err(Fatal::new(
                exit::CONFIG,
                format!(
                    "{}: the link would run without DDS Security on {}: any participant on that \
                     network could write into this site. Set link.security_dir to this box's \
                     enclave (`isochron keystore enclave`), or link.insecure = true to accept that",
                    loaded.path.display(),
                    if link.dds_interfaces.is_empty() {
                        "every interface".to_string()
                    } else {
                        format!("[{}]", link.dds_interfaces.join(", "))
                    }
                ),
            ));
        }
        if link.leaves_the_box() {
            tracing::warn!(
                "link.insecure: DDS Security is off; any participant on the network can write into this site"
            );
        }
        return Ok(None);
    };
    let dir = loaded.base_dir().join(dir);
    if let Some(missing) = isochron_dds::missing_enclave_file(&dir) {
        return Err(Fatal::new(
            exit::CONFIG,
            format!(
                "{}: link.security_dir: {} is missing (an enclave made by `isochron keystore enclave` holds {})",
                loaded.path.display(),
                missing.display(),
                isochron_dds::ENCLAVE_FILES.join(", ")
            ),
        ));
    }
    tracing::info!(enclave = %dir.display(), "DDS Security on");
    Ok(Some(dir))
}

/// The block grid this box's config gives camera `id` (its `[[camera]]` width
/// and height with `motion.block_px`), if it does.
fn configured_grid(loaded: &LoadedConfig, id: &str) -> Option<BlockGrid> {
    let config = &loaded.config;
    let camera = config.cameras.iter().find(|c| c.id == id)?;
    let (w, h) = camera.width.zip(camera.height)?;
    Some(BlockGrid::new(w, h, config.motion.block_px))
}

/// The stages whose status crosses with a camera.
fn camera_stages() -> impl Iterator<Item = StageKind> {
    StageKind::ALL.into_iter().filter(|s| s.per_camera())
}

/// What one stream of one camera did.
#[derive(Debug, Default, Clone, Copy)]
struct Counts {
    /// Messages sent (export) or written into iceoryx2 (import).
    messages: u64,
    /// Bytes of CDR sent.
    bytes: u64,
    /// Dropped before sending: a full queue, a newer activity, a gap upstream.
    dropped: u64,
    /// Missing in the received sequence.
    gaps: u64,
    /// Failed writes.
    errors: u64,
}

impl std::ops::AddAssign for Counts {
    fn add_assign(&mut self, o: Counts) {
        self.messages += o.messages;
        self.bytes += o.bytes;
        self.dropped += o.dropped;
        self.gaps += o.gaps;
        self.errors += o.errors;
    }
}

/// Counts gaps in a received sequence; a sequence going backwards is a
/// restarted publisher, not a loss.
fn gap(last: &mut Option<u64>, sequence: u64) -> u64 {
    let missing = match *last {
        Some(l) if sequence > l + 1 => sequence - l - 1,
        _ => 0,
    };
    *last = Some(sequence);
    missing
}

/// One exported stream of one camera.
struct ExportLane<S: LinkStream> {
    writer: Publisher<Message<S>>,
    queue: VecDeque<Message<S>>,
    last_sequence: Option<u64>,
    counts: Counts,
}

impl<S: LinkStream> ExportLane<S> {
    fn new(dds: &mut LinkDds, camera: &str, queue: usize) -> Result<Self, Fatal> {
        Ok(ExportLane {
            writer: dds.stream::<S, _>(camera, queue, None)?,
            queue: VecDeque::new(),
            last_sequence: None,
            counts: Counts::default(),
        })
    }

    /// Moves what `input` holds into the queue (latest-only: one; queued: up to
    /// `cap`), counting what is dropped.
    fn take(&mut self, box_id: &str, input: &Input<S>, cap: usize, cx: &mut Context) {
        let cap = match S::DELIVERY {
            Delivery::Latest => 1,
            Delivery::Queued => cap,
        };
        while let Some(sample) = input.next(cx) {
            if sample.is_end_of_stream() {
                continue;
            }
            // Lost upstream (a full iceoryx2 buffer): counted by the input as
            // dropped in the health, and here per stream.
            let header = sample.header();
            self.counts.dropped += gap(&mut self.last_sequence, header.preamble().sequence);
            if self.queue.len() >= cap {
                self.queue.pop_front();
                self.counts.dropped += 1;
                cx.health.dropped(1);
            }
            self.queue
                .push_back(Message::from_sample(box_id, header, sample.payload()));
        }
    }

    /// Sends the queue: all of it while DDS takes it; a queued stream only while
    /// a reader is matched (else it waits, bounded).
    fn send(&mut self, node: &Node, camera: &str, cx: &mut Context) {
        if self.queue.is_empty()
            || (S::DELIVERY == Delivery::Queued && self.writer.get_subscription_count(node) == 0)
        {
            return;
        }
        while let Some(msg) = self.queue.pop_front() {
            let (bytes, origin) = (cdr_len(&msg) as u64, msg.header.preamble().origin_wall_ns);
            match self.writer.publish(msg) {
                Ok(()) => {
                    self.counts.messages += 1;
                    self.counts.bytes += bytes;
                    cx.health.sent(None, origin);
                }
                Err(WriteError::WouldBlock { data }) => {
                    // The reliable window is full: the rest waits for acks.
                    self.queue.push_front(data);
                    break;
                }
                Err(e) => {
                    self.counts.errors += 1;
                    let e = e.to_string();
                    cx.warnings.warn("publish", || {
                        format!("publishing {camera}'s {}: {e}", S::SUFFIX)
                    });
                }
            }
        }
    }
}

/// One exported camera: its streams and its stages' status.
struct Export {
    camera: String,
    activity: ExportLane<Activity>,
    events: ExportLane<Events>,
    detections: ExportLane<Detections>,
    status_in: Vec<(StatusSubscriber, i64)>,
    status_out: Publisher<Status>,
    status: Counts,
}

/// One imported stream of one camera.
struct ImportLane<'ipc, S: LinkStream> {
    reader: Subscription<Message<S>>,
    output: Output<'ipc, S>,
    last_sequence: Option<u64>,
    /// The camera's grid, as the config gives it or its first activity pinned it.
    known: KnownGrid,
    counts: Counts,
}

impl<'ipc, S: LinkStream> ImportLane<'ipc, S> {
    fn new(
        dds: &mut LinkDds,
        ipc: &'ipc Ipc,
        camera: &str,
        queue: usize,
        grid: Option<BlockGrid>,
    ) -> Result<Self, Fatal> {
        Ok(ImportLane {
            reader: dds.stream::<S, _>(camera, queue, grid.map(|g| g.len()))?,
            output: Output::new(ipc, camera),
            last_sequence: None,
            known: KnownGrid::new(grid),
            counts: Counts::default(),
        })
    }

    /// Checks a valid message's grid (activity) against the camera's known one;
    /// the first one pins it, with a warning.
    fn check_grid(&mut self, camera: &str, msg: &Message<S>) -> Result<(), String> {
        let Some(grid) =
            S::block_grid(&msg.header).filter(|_| !msg.header.preamble().is_end_of_stream())
        else {
            return Ok(());
        };
        match self.known.check(grid) {
            Ok(false) => Ok(()),
            Ok(true) => {
                tracing::warn!(
                    "{camera}: block grid {grid} pinned by the first activity from box '{}'; \
                     any other grid is refused until the link restarts (set the camera's \
                     width/height in this box's [[camera]] to fix it)",
                    msg.box_id
                );
                Ok(())
            }
            Err(e) => Err(e.to_string()),
        }
    }

    /// Publishes what DDS received (at most `limit` messages this tick).
    fn receive(
        &mut self,
        camera: &str,
        id: &CameraId,
        limit: usize,
        cx: &mut Context,
    ) -> Result<bool, Fatal> {
        let mut any = false;
        for _ in 0..limit {
            let msg = match self.reader.take() {
                Ok(Some((msg, _info))) => msg,
                Ok(None) => break,
                Err(e) => {
                    cx.health.rejected();
                    cx.warnings.warn("read", || {
                        format!("an unreadable {} message of {camera}: {e}", S::SUFFIX)
                    });
                    continue;
                }
            };
            let arrived = Instant::now();
            if let Err(e) = msg
                .validate(id)
                .map_err(|e| e.to_string())
                .and_then(|()| self.check_grid(camera, &msg))
            {
                cx.health.rejected();
                cx.warnings.warn("header", || {
                    format!(
                        "rejected {} of {camera} from box {}: {e}",
                        S::SUFFIX,
                        printable(&msg.box_id)
                    )
                });
                continue;
            }
            cx.health.read_one();
            let missing = gap(&mut self.last_sequence, msg.header.preamble().sequence);
            self.counts.gaps += missing;
            cx.health.dropped(missing);
            let origin = msg.header.preamble().origin_wall_ns;
            self.output.send_copy(msg.header, &msg.payload)?;
            self.counts.messages += 1;
            any = true;
            cx.health.sent(Some(arrived), origin);
        }
        Ok(any)
    }
}

/// One imported camera.
struct Import<'ipc> {
    camera: String,
    id: CameraId,
    activity: ImportLane<'ipc, Activity>,
    events: ImportLane<'ipc, Events>,
    detections: ImportLane<'ipc, Detections>,
    status_in: Subscription<Status>,
    status_out: HashMap<StageKind, StatusPublisher>,
    status: Counts,
    last: Option<Instant>,
}

impl Import<'_> {
    /// Writes the remote stages' status into this box's status services, as
    /// this box saw it ([`seen_here`]).
    fn receive_status(&mut self, ipc: &Ipc, cx: &mut Context) {
        while let Ok(Some((msg, _))) = self.status_in.take() {
            let stage =
                StageKind::from_name(&fixed_str(&msg.status.stage)).filter(|k| k.per_camera());
            let valid = msg.status.validate().is_ok()
                && msg.status.camera == self.id
                && check_box_id(&msg.box_id).is_ok();
            let Some(stage) = stage.filter(|_| valid) else {
                cx.health.rejected();
                cx.warnings.warn("status", || {
                    format!(
                        "rejected a status of {} from box {}: not a stage status of this camera",
                        self.camera,
                        printable(&msg.box_id)
                    )
                });
                continue;
            };
            let s = seen_here(msg.status, wall_now_ns());
            self.status.messages += 1;
            if !self.status_out.contains_key(&stage) {
                match ipc.status_publisher(&self.camera, stage) {
                    Ok(p) => {
                        self.status_out.insert(stage, p);
                    }
                    Err(e) => {
                        cx.warnings.warn("status", || e.to_string());
                        continue;
                    }
                }
            }
            if let Err(e) = self.status_out[&stage].publish(s) {
                cx.warnings.warn("status", || e.to_string());
            }
        }
        // A reader (`isochron status`) that came since gets the latest at once.
        self.status_out
            .values()
            .for_each(StatusPublisher::update_connections);
    }
}

/// A remote stage's status as this box relays it: its liveness is what this
/// box saw and when, never the sender's clock or process id. The report time
/// becomes the time it arrived here (`now_ns`); the start time keeps the uptime
/// the sender reported (within 0 ..= `now_ns`); the process id becomes the
/// link's own, the local process whose death ends the relay (a remote pid means
/// nothing here: `kill(pid, 0)` of a forged pid 1 always succeeds). A sender
/// that stops is stale here `STALE_AFTER_S` after its last report arrived,
/// whatever times it wrote.
pub fn seen_here(mut status: StageStatus, now_ns: i64) -> StageStatus {
    let uptime_ns = status
        .report_wall_ns
        .saturating_sub(status.started_wall_ns)
        .clamp(0, now_ns.max(0));
    status.report_wall_ns = now_ns;
    status.started_wall_ns = now_ns - uptime_ns;
    status.pid = std::process::id();
    status
}

/// The inputs of the exported cameras, in `link.export` order.
pub type LinkInputs = (
    Vec<Input<Activity>>,
    Vec<Input<Events>>,
    Vec<Input<Detections>>,
);

/// The link of one box.
pub struct LinkStage<'ipc> {
    ipc: &'ipc Ipc,
    box_id: String,
    queue: usize,
    exports: Vec<Export>,
    imports: Vec<Import<'ipc>>,
    started: Instant,
    dds: LinkDds,
}

impl<'ipc> LinkStage<'ipc> {
    /// Joins DDS as `[link]` says and opens the exported cameras' inputs (in
    /// `link.export` order).
    pub fn open(ipc: &'ipc Ipc, loaded: &LoadedConfig) -> Result<(Self, LinkInputs), Fatal> {
        let link = &loaded.config.link;
        if !link.is_enabled() {
            tracing::warn!(
                "[link] exports and imports no camera: nothing to do (see link.export, link.import)"
            );
        }
        let domain = isochron_dds::domain_id(link.ros_domain_id)?;
        let interfaces: Vec<IpAddr> = link
            .dds_interfaces
            .iter()
            .filter_map(|a| a.parse().ok())
            .collect();
        let queue = link.queue_messages();
        let enclave = enclave(loaded)?;
        check_open_files(link.import.len(), link.export.len())?;
        let mut dds = LinkDds::start(
            domain,
            &interfaces,
            (&link.box_id, enclave.as_deref()),
            link.namespace(),
        )?;
        let mut exports = Vec::new();
        let mut inputs: LinkInputs = Default::default();
        for camera in &link.export {
            let mut status_in = Vec::new();
            for stage in camera_stages() {
                status_in.push((ipc.status_subscriber(camera, stage)?, 0));
            }
            exports.push(Export {
                camera: camera.clone(),
                activity: ExportLane::new(&mut dds, camera, queue)?,
                events: ExportLane::new(&mut dds, camera, queue)?,
                detections: ExportLane::new(&mut dds, camera, queue)?,
                status_in,
                status_out: dds.status(camera)?,
                status: Counts::default(),
            });
            inputs.0.push(Input::open(ipc, camera)?);
            inputs.1.push(Input::open(ipc, camera)?);
            inputs.2.push(Input::open(ipc, camera)?);
        }
        let mut imports = Vec::new();
        for camera in &link.import {
            let grid = configured_grid(loaded, camera);
            imports.push(Import {
                camera: camera.clone(),
                id: CameraId::new(camera).unwrap_or_default(),
                activity: ImportLane::new(&mut dds, ipc, camera, queue, grid)?,
                events: ImportLane::new(&mut dds, ipc, camera, queue, grid)?,
                detections: ImportLane::new(&mut dds, ipc, camera, queue, grid)?,
                status_in: dds.status(camera)?,
                status_out: HashMap::new(),
                status: Counts::default(),
                last: None,
            });
        }
        tracing::info!(
            box_id = %link.box_id,
            domain,
            queue_messages = queue,
            "link up: exports [{}] imports [{}] under {}",
            link.export.join(", "),
            link.import.join(", "),
            link.namespace()
        );
        Ok((
            LinkStage {
                ipc,
                box_id: link.box_id.clone(),
                queue,
                exports,
                imports,
                started: Instant::now(),
                dds,
            },
            inputs,
        ))
    }

    fn send_queues(&mut self, cx: &mut Context) {
        let node = self.dds.node();
        for e in &mut self.exports {
            e.activity.send(node, &e.camera, cx);
            e.events.send(node, &e.camera, cx);
            e.detections.send(node, &e.camera, cx);
        }
    }

    /// Sends each exported stage's status that is newer than the last sent.
    fn send_status(&mut self, cx: &mut Context) {
        for e in &mut self.exports {
            for (reader, last_ns) in &mut e.status_in {
                let Some(status) = reader.latest().filter(|s| s.report_wall_ns > *last_ns) else {
                    continue;
                };
                *last_ns = status.report_wall_ns;
                let msg = Status {
                    box_id: self.box_id.clone(),
                    status,
                };
                let bytes = cdr_len(&msg) as u64;
                match e.status_out.publish(msg) {
                    Ok(()) => {
                        e.status.messages += 1;
                        e.status.bytes += bytes;
                    }
                    Err(err) => {
                        e.status.errors += 1;
                        cx.warnings.warn("publish", || {
                            format!("publishing {}'s status: {err}", e.camera)
                        });
                    }
                }
            }
        }
    }

    /// Totals per stream over the exports and the imports.
    fn totals(&self) -> ([Counts; 4], [Counts; 4]) {
        let (mut out, mut inc) = ([Counts::default(); 4], [Counts::default(); 4]);
        for e in &self.exports {
            out[0] += e.activity.counts;
            out[1] += e.events.counts;
            out[2] += e.detections.counts;
            out[3] += e.status;
        }
        for i in &self.imports {
            inc[0] += i.activity.counts;
            inc[1] += i.events.counts;
            inc[2] += i.detections.counts;
            inc[3] += i.status;
        }
        (out, inc)
    }
}

/// Short names of the streams in the status detail.
const SHORT: [&str; 4] = ["act", "ev", "det", "st"];
/// The queued streams among them (whose drops and gaps the detail shows).
const QUEUED: [usize; 2] = [1, 2];

impl Stage for LinkStage<'_> {
    type Inputs = LinkInputs;
    const KIND: StageKind = StageKind::Link;

    fn on_wake(
        &mut self,
        inputs: &Self::Inputs,
        _woken: &Woken,
        cx: &mut Context,
    ) -> Result<(), Fatal> {
        let (activity, events, detections) = inputs;
        for (k, e) in self.exports.iter_mut().enumerate() {
            e.activity.take(&self.box_id, &activity[k], self.queue, cx);
            e.events.take(&self.box_id, &events[k], self.queue, cx);
            e.detections
                .take(&self.box_id, &detections[k], self.queue, cx);
        }
        self.send_queues(cx);
        Ok(())
    }

    fn on_tick(&mut self, cx: &mut Context) -> Result<(), Fatal> {
        // Queues that waited for a reader or for acknowledgements.
        self.send_queues(cx);
        self.send_status(cx);
        // A tick takes at most what DDS keeps: a full history's worth.
        let limit = self.queue.max(16);
        for import in &mut self.imports {
            let (camera, id) = (&import.camera, &import.id);
            let mut any = import.activity.receive(camera, id, limit, cx)?;
            any |= import.events.receive(camera, id, limit, cx)?;
            any |= import.detections.receive(camera, id, limit, cx)?;
            if any {
                import.last = Some(Instant::now());
            }
            import.receive_status(self.ipc, cx);
        }
        Ok(())
    }

    fn on_stop(&mut self, _cx: &mut Context) -> Result<(), Fatal> {
        let secs = self.started.elapsed().as_secs_f64().max(1e-3);
        for e in &self.exports {
            let lanes = [
                ("activity", e.activity.counts),
                ("events", e.events.counts),
                ("detections", e.detections.counts),
                ("status", e.status),
            ];
            for (stream, c) in lanes {
                tracing::info!(
                    "exported {} {stream}: {} messages, {} bytes of CDR ({} B/message), {:.0} B/s over {secs:.1} s, {} dropped",
                    e.camera,
                    c.messages,
                    c.bytes,
                    c.bytes / c.messages.max(1),
                    c.bytes as f64 / secs,
                    c.dropped
                );
            }
        }
        Ok(())
    }

    fn timer(&self) -> Duration {
        if self.imports.is_empty() && self.exports.is_empty() {
            isochron_runtime::stage::IDLE_TICK
        } else {
            POLL
        }
    }

    fn detail(&self) -> String {
        // Kept short: a status detail holds 160 bytes.
        let (out, inc) = self.totals();
        let mut d = format!("box={}", self.box_id);
        if !self.exports.is_empty() {
            for (k, (name, c)) in SHORT.iter().zip(out).enumerate() {
                d += &format!(" {name}_out={}", c.messages);
                if QUEUED.contains(&k) {
                    d += &format!(" {name}_drop={}", c.dropped);
                }
            }
        }
        if !self.imports.is_empty() {
            for (k, (name, c)) in SHORT.iter().zip(inc).enumerate() {
                d += &format!(" {name}_in={}", c.messages);
                if QUEUED.contains(&k) {
                    d += &format!(" {name}_gap={}", c.gaps);
                }
            }
        }
        let errors: u64 = out.iter().map(|c| c.errors).sum();
        if errors > 0 {
            d += &format!(" err={errors}");
        }
        d
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use isochron_wire::{LAYOUT_VERSION, MAGIC, STATUS_DETAIL_LEN};

    #[test]
    fn a_relayed_status_is_as_fresh_as_its_arrival_and_owned_by_the_link() {
        let forged = StageStatus {
            magic: MAGIC,
            layout_version: LAYOUT_VERSION,
            reserved: 0,
            camera: CameraId::new("cam01").unwrap(),
            stage: isochron_wire::to_fixed("gate"),
            pid: 1,
            rate_in: 1.0,
            started_wall_ns: 1,
            report_wall_ns: 1 << 62,
            received: 0,
            sent: 0,
            dropped: 0,
            rejected: 0,
            rate_out: 0.0,
            stage_latency_ms: 0.0,
            e2e_latency_p50_ms: 0.0,
            e2e_latency_p99_ms: 0.0,
            detail: [0; STATUS_DETAIL_LEN],
        };
        let now = 1_800_000_000_000_000_000;
        let s = seen_here(forged, now);
        assert_eq!(s.report_wall_ns, now);
        assert_eq!(s.pid, std::process::id());
        // An absurd uptime is clamped: the start is never before 1970.
        assert_eq!(s.started_wall_ns, 0);
        let mut honest = forged;
        (honest.started_wall_ns, honest.report_wall_ns) = (1_000, 61_000_000_000);
        assert_eq!(seen_here(honest, now).started_wall_ns, now - 60_999_999_000);
    }
}
