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
//! The status counts per stream across cameras (`act`, `ev`, `det`, `st`):
//! `<s>_out` sent, `<s>_in` received; for events and detections also
//! `<s>_drop`, dropped on this box before sending (a full queue, or lost in
//! its iceoryx2 buffer), and `<s>_gap`, missing in the received sequences (dropped
//! on the exporting box, or lost in this box's DDS history); `imports_live`, the
//! imported cameras heard from within [`LIVE_WITHIN`]. Each imported camera's
//! remote stages report as local ones (their liveness is their arrival here).

use std::net::IpAddr;
use std::time::{Duration, Instant};

use isochron_config::LoadedConfig;
use isochron_runtime::counters::{Counters, link};
use isochron_runtime::ipc::{Activity, Detections, Events, Ipc};
use isochron_runtime::service::Fatal;
use isochron_runtime::stage::{Context, Input, Stage};
use isochron_runtime::topology::StageKind;

use crate::dds::LinkDds;

mod checks;
mod counts;
mod export;
mod import;

use counts::Counts;
use export::Export;
use import::Import;
pub use import::seen_here;

/// How often the DDS readers are polled: a message waits at most this long on
/// the importing box.
pub const POLL: Duration = Duration::from_millis(20);

/// The stages whose status crosses with a camera.
fn camera_stages() -> impl Iterator<Item = StageKind> {
    StageKind::pipeline().filter(|s| s.per_camera())
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
        let enclave = checks::enclave(loaded)?;
        checks::check_open_files(link.import.len(), link.export.len())?;
        let mut dds = LinkDds::start(
            domain,
            &interfaces,
            (&link.box_id, enclave.as_deref()),
            link.namespace(),
        )?;
        let mut exports = Vec::new();
        let mut inputs: LinkInputs = Default::default();
        for camera in &link.export {
            let (export, (activity, events, detections)) =
                Export::open(ipc, &mut dds, camera, queue)?;
            exports.push(export);
            inputs.0.push(activity);
            inputs.1.push(events);
            inputs.2.push(detections);
        }
        let imports = link
            .import
            .iter()
            .map(|camera| Import::open(ipc, &mut dds, loaded, camera, queue))
            .collect::<Result<Vec<_>, _>>()?;
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
            e.send_queues(node, cx);
        }
    }

    /// Totals per stream over the exports and the imports.
    fn totals(&self) -> ([Counts; 4], [Counts; 4]) {
        let (mut out, mut inc) = ([Counts::default(); 4], [Counts::default(); 4]);
        for e in &self.exports {
            for (total, c) in out.iter_mut().zip(e.counts()) {
                *total += c;
            }
        }
        for i in &self.imports {
            for (total, c) in inc.iter_mut().zip(i.counts()) {
                *total += c;
            }
        }
        (out, inc)
    }
}

/// An imported camera is live while a message of it arrived this recently
/// (its box reports every stage's status every 5 s, activity every second).
pub const LIVE_WITHIN: Duration = Duration::from_secs(15);

impl Stage for LinkStage<'_> {
    type Inputs = LinkInputs;
    const KIND: StageKind = StageKind::Link;

    fn on_wake(&mut self, inputs: &Self::Inputs, cx: &mut Context) -> Result<(), Fatal> {
        let (activity, events, detections) = inputs;
        for (k, e) in self.exports.iter_mut().enumerate() {
            let inputs = (&activity[k], &events[k], &detections[k]);
            e.take(&self.box_id, inputs, self.queue, cx);
        }
        self.send_queues(cx);
        Ok(())
    }

    fn on_tick(&mut self, cx: &mut Context) -> Result<(), Fatal> {
        // Queues that waited for a reader or for acknowledgements.
        self.send_queues(cx);
        for e in &mut self.exports {
            e.send_status(&self.box_id, cx);
        }
        // A tick takes at most what DDS keeps: a full history's worth.
        let limit = self.queue.max(16);
        for import in &mut self.imports {
            import.receive(self.ipc, limit, cx)?;
        }
        Ok(())
    }

    fn on_stop(&mut self, _cx: &mut Context) -> Result<(), Fatal> {
        let secs = self.started.elapsed().as_secs_f64().max(1e-3);
        for e in &self.exports {
            e.log_totals(secs);
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

    fn counters(&self, c: &mut Counters) {
        let (out, inc) = self.totals();
        let [act, ev, det, st] = out;
        c.set(link::ACT_OUT, act.messages);
        c.set(link::EV_OUT, ev.messages);
        c.set(link::EV_DROP, ev.dropped);
        c.set(link::DET_OUT, det.messages);
        c.set(link::DET_DROP, det.dropped);
        c.set(link::ST_OUT, st.messages);
        let [act, ev, det, st] = inc;
        c.set(link::ACT_IN, act.messages);
        c.set(link::EV_IN, ev.messages);
        c.set(link::EV_GAP, ev.gaps);
        c.set(link::DET_IN, det.messages);
        c.set(link::DET_GAP, det.gaps);
        c.set(link::ST_IN, st.messages);
        c.set(link::ERRORS, out.iter().map(|c| c.errors).sum::<u64>());
        let now = Instant::now();
        c.set(link::IMPORTS, self.imports.len());
        let live = self.imports.iter().filter(|i| i.live(now, LIVE_WITHIN));
        c.set(link::IMPORTS_LIVE, live.count());
    }

    fn info(&self) -> String {
        format!("box={}", self.box_id)
    }
}
