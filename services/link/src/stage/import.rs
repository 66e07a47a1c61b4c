//! The import side: an imported camera's streams from DDS, validated, into this
//! box's iceoryx2 services with the remote header unchanged, and its remote
//! stages' status as this box saw it.

use std::collections::HashMap;
use std::time::{Duration, Instant};

use ros2_client::dds::Subscription;

use isochron_config::LoadedConfig;
use isochron_config::clock::wall_now_ns;
use isochron_runtime::ipc::{Activity, Detections, Events, Ipc, StatusPublisher};
use isochron_runtime::service::Fatal;
use isochron_runtime::stage::{Context, Output};
use isochron_runtime::topology::StageKind;
use isochron_wire::geometry::BlockGrid;
use isochron_wire::{CameraId, KnownGrid, StageStatus, StreamHeader, fixed_str};

use super::counts::{Counts, gap};
use crate::dds::LinkDds;
use crate::msgs::{LinkStream, Message, Status, check_box_id, printable};

/// The block grid this box's config gives camera `id` (its `[[camera]]` width
/// and height with `motion.block_px`), if it does.
fn configured_grid(loaded: &LoadedConfig, id: &str) -> Option<BlockGrid> {
    let config = &loaded.config;
    let camera = config.cameras.iter().find(|c| c.id == id)?;
    let (w, h) = camera.width.zip(camera.height)?;
    Some(BlockGrid::new(w, h, config.motion.block_px))
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
    ) -> Result<(), Fatal> {
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
            cx.health.sent(Some(arrived), origin);
        }
        Ok(())
    }
}

/// One imported camera.
pub(super) struct Import<'ipc> {
    camera: String,
    id: CameraId,
    activity: ImportLane<'ipc, Activity>,
    events: ImportLane<'ipc, Events>,
    detections: ImportLane<'ipc, Detections>,
    status_in: Subscription<Status>,
    status_out: HashMap<StageKind, StatusPublisher>,
    status: Counts,
    /// When a valid message of this camera last arrived.
    heard: Option<Instant>,
}

impl<'ipc> Import<'ipc> {
    /// Opens `camera`'s DDS readers (histories of `queue` messages, bounded by
    /// the grid this box's config gives it) and its outputs.
    pub(super) fn open(
        ipc: &'ipc Ipc,
        dds: &mut LinkDds,
        loaded: &LoadedConfig,
        camera: &str,
        queue: usize,
    ) -> Result<Self, Fatal> {
        let grid = configured_grid(loaded, camera);
        Ok(Import {
            camera: camera.to_string(),
            id: CameraId::new(camera).unwrap_or_default(),
            activity: ImportLane::new(dds, ipc, camera, queue, grid)?,
            events: ImportLane::new(dds, ipc, camera, queue, grid)?,
            detections: ImportLane::new(dds, ipc, camera, queue, grid)?,
            status_in: dds.status(camera)?,
            status_out: HashMap::new(),
            status: Counts::default(),
            heard: None,
        })
    }

    /// Publishes what DDS received for this camera (at most `limit` messages
    /// per stream) and its remote stages' status.
    pub(super) fn receive(
        &mut self,
        ipc: &Ipc,
        limit: usize,
        cx: &mut Context,
    ) -> Result<(), Fatal> {
        let before = self.messages();
        let (camera, id) = (&self.camera, &self.id);
        self.activity.receive(camera, id, limit, cx)?;
        self.events.receive(camera, id, limit, cx)?;
        self.detections.receive(camera, id, limit, cx)?;
        self.receive_status(ipc, cx);
        if self.messages() > before {
            self.heard = Some(Instant::now());
        }
        Ok(())
    }

    fn messages(&self) -> u64 {
        self.counts().iter().map(|c| c.messages).sum()
    }

    /// True if a valid message of this camera arrived within `within` of `now`:
    /// its box is alive and reaches this one.
    pub(super) fn live(&self, now: Instant, within: Duration) -> bool {
        self.heard
            .is_some_and(|t| now.saturating_duration_since(t) <= within)
    }

    /// What each stream received: activity, events, detections, status.
    pub(super) fn counts(&self) -> [Counts; 4] {
        [
            self.activity.counts,
            self.events.counts,
            self.detections.counts,
            self.status,
        ]
    }

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

#[cfg(test)]
mod tests {
    use super::*;
    use isochron_runtime::health::starting_status;

    #[test]
    fn a_relayed_status_is_as_fresh_as_its_arrival_and_owned_by_the_link() {
        let forged = StageStatus {
            pid: 1,
            rate_in: 1.0,
            started_wall_ns: 1,
            report_wall_ns: 1 << 62,
            ..starting_status(CameraId::new("cam01").unwrap(), StageKind::Gate)
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
