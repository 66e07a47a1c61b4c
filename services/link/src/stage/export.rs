//! The export side: an exported camera's streams from its iceoryx2 inputs into
//! bounded queues and out to DDS, and its stages' status.

use std::collections::VecDeque;

use ros2_client::WriteError;
use ros2_client::dds::{Node, Publisher};

use isochron_runtime::ipc::{Activity, Detections, Events, Ipc, StatusSubscriber};
use isochron_runtime::service::Fatal;
use isochron_runtime::stage::{Context, Input};
use isochron_wire::StreamHeader;

use super::camera_stages;
use super::counts::{Counts, gap};
use crate::dds::LinkDds;
use crate::msgs::{Delivery, LinkStream, Message, Status, cdr_len};

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
pub(super) struct Export {
    camera: String,
    activity: ExportLane<Activity>,
    events: ExportLane<Events>,
    detections: ExportLane<Detections>,
    status_in: Vec<(StatusSubscriber, i64)>,
    status_out: Publisher<Status>,
    status: Counts,
}

/// An exported camera's inputs: its `activity`, `events` and `detections`.
pub(super) type ExportInputs = (Input<Activity>, Input<Events>, Input<Detections>);

impl Export {
    /// Opens `camera`'s DDS writers (queues of `queue` messages), its stages'
    /// status subscribers and its inputs.
    pub(super) fn open(
        ipc: &Ipc,
        dds: &mut LinkDds,
        camera: &str,
        queue: usize,
    ) -> Result<(Self, ExportInputs), Fatal> {
        let mut status_in = Vec::new();
        for stage in camera_stages() {
            status_in.push((ipc.status_subscriber(camera, stage)?, 0));
        }
        let export = Export {
            camera: camera.to_string(),
            activity: ExportLane::new(dds, camera, queue)?,
            events: ExportLane::new(dds, camera, queue)?,
            detections: ExportLane::new(dds, camera, queue)?,
            status_in,
            status_out: dds.status(camera)?,
            status: Counts::default(),
        };
        let inputs = (
            Input::open(ipc, camera)?,
            Input::open(ipc, camera)?,
            Input::open(ipc, camera)?,
        );
        Ok((export, inputs))
    }

    /// Moves what the inputs hold into the streams' queues (queued streams: up
    /// to `cap` messages each).
    pub(super) fn take(
        &mut self,
        box_id: &str,
        (activity, events, detections): (&Input<Activity>, &Input<Events>, &Input<Detections>),
        cap: usize,
        cx: &mut Context,
    ) {
        self.activity.take(box_id, activity, cap, cx);
        self.events.take(box_id, events, cap, cx);
        self.detections.take(box_id, detections, cap, cx);
    }

    /// Sends what each stream's queue holds, as far as DDS takes it.
    pub(super) fn send_queues(&mut self, node: &Node, cx: &mut Context) {
        self.activity.send(node, &self.camera, cx);
        self.events.send(node, &self.camera, cx);
        self.detections.send(node, &self.camera, cx);
    }

    /// Sends each stage's status that is newer than the last sent.
    pub(super) fn send_status(&mut self, box_id: &str, cx: &mut Context) {
        for (reader, last_ns) in &mut self.status_in {
            let Some(status) = reader.latest().filter(|s| s.report_wall_ns > *last_ns) else {
                continue;
            };
            *last_ns = status.report_wall_ns;
            let msg = Status {
                box_id: box_id.to_string(),
                status,
            };
            let bytes = cdr_len(&msg) as u64;
            match self.status_out.publish(msg) {
                Ok(()) => {
                    self.status.messages += 1;
                    self.status.bytes += bytes;
                }
                Err(err) => {
                    self.status.errors += 1;
                    cx.warnings.warn("publish", || {
                        format!("publishing {}'s status: {err}", self.camera)
                    });
                }
            }
        }
    }

    /// What each stream sent: activity, events, detections, status.
    pub(super) fn counts(&self) -> [Counts; 4] {
        [
            self.activity.counts,
            self.events.counts,
            self.detections.counts,
            self.status,
        ]
    }

    /// Logs what each stream sent over the link's `secs` of life.
    pub(super) fn log_totals(&self, secs: f64) {
        let streams = ["activity", "events", "detections", "status"];
        for (stream, c) in streams.into_iter().zip(self.counts()) {
            tracing::info!(
                "exported {} {stream}: {} messages, {} bytes of CDR ({} B/message), {:.0} B/s over {secs:.1} s, {} dropped",
                self.camera,
                c.messages,
                c.bytes,
                c.bytes / c.messages.max(1),
                c.bytes as f64 / secs,
                c.dropped
            );
        }
    }
}
