//! The view and the recorder as a stage on the stage runtime
//! ([`isochron_runtime::stage`]), `StageKind::View`: the runtime wakes it when a
//! followed stream has samples, checks and counts every sample, and publishes its
//! status (`<prefix>/status/view`, so `isochron status` lists it while it runs).
//!
//! * `activity`, `events` and `detections` are taken in full ([`Input::next`]);
//! * `frames` and `motion` only the newest waiting sample ([`Input::latest`]): the
//!   skipped ones count as the view's drops. An image is published at most
//!   `view.frame_rate_hz`, a motion grid at most every 0.5 s of capture time;
//! * every tick (100 ms) the pipeline services' status reports are read.
//!
//! The sink is the Foxglove WebSocket server ([`Sink::Live`]) or an MCAP file
//! ([`Sink::Record`]); both publish through the same [`SiteChannels`].
//!
//! The view is not an expected service: `isochron status` adds its row only while
//! `<prefix>/status/view` has a publisher, and the exporter does not watch it (it
//! would be "down" whenever nobody looks). There is one status publisher per
//! service: a second `view` or `record` on the same site runs but warns that its
//! status is not published.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use isochron_config::LoadedConfig;
use isochron_exit::Fatal;
use isochron_runtime::counters::{Counters, view};
use isochron_runtime::ipc::{Ipc, IpcError, StreamType};
use isochron_runtime::stage::{Context, Input, Stage};
use isochron_runtime::topology::StageKind;
use isochron_wire::StreamHeader;

use crate::channels::SiteChannels;
use crate::follow::{StatusReader, Streams, ViewInputs, open_inputs, status_readers};
use crate::live::LiveServer;
use crate::record::{RecordError, Recording};

/// How often status reports are read and the end conditions checked.
const TICK: Duration = Duration::from_millis(100);

/// Where the channels go.
pub enum Sink {
    /// The live view: a Foxglove WebSocket server.
    Live(LiveServer),
    /// A recording into an MCAP file.
    Record(Recording),
}

/// When a view or recording ends, besides a stop request (SIGINT, SIGTERM) and,
/// for a recording, a disk running low.
#[derive(Debug, Clone, Default)]
pub struct Until {
    /// At this instant (`isochron record --duration`).
    pub deadline: Option<Instant>,
    /// Once this flag is set (how `isochron replay --record` ends its recorder).
    pub stop: Option<Arc<AtomicBool>>,
    /// Once every camera's `activity` has ended (its file source ran out).
    pub sources_end: bool,
}

/// The view or recorder: the channels, the sink, the status readers.
pub struct ViewStage {
    channels: SiteChannels,
    sink: Sink,
    status: Vec<StatusReader>,
    /// Per camera: its `activity` has ended (empty without `activity`).
    ended: Vec<bool>,
    until: Until,
    disk_low: bool,
    rejected: u64,
}

/// What a view or recording did, once it has finished.
#[derive(Debug)]
pub struct Summary {
    /// Messages per topic, by topic.
    pub counts: Vec<(String, u64)>,
    /// The recording and its size in bytes (none for the live view).
    pub file: Option<(PathBuf, u64)>,
    /// Malformed samples skipped.
    pub rejected: u64,
    /// The recording was closed early because its disk ran low.
    pub disk_low: bool,
}

impl ViewStage {
    /// Follows `streams` of `loaded`'s site into `channels` and `sink` (whose
    /// context the channels are on): the stage and its inputs, for
    /// [`isochron_runtime::stage::run`].
    pub fn open(
        ipc: &Ipc,
        loaded: &LoadedConfig,
        channels: SiteChannels,
        sink: Sink,
        streams: Streams,
        until: Until,
    ) -> Result<(ViewStage, ViewInputs), IpcError> {
        let inputs = open_inputs(ipc, loaded, streams)?;
        let stage = ViewStage {
            channels,
            sink,
            status: status_readers(ipc, loaded, streams)?,
            ended: vec![false; inputs.0.len()],
            until,
            disk_low: false,
            rejected: 0,
        };
        Ok((stage, inputs))
    }

    /// Messages published so far, over every topic.
    pub fn published(&self) -> u64 {
        self.channels.counts().values().sum()
    }

    /// Stops the server or closes the recording, and says what was published.
    pub fn finish(self) -> Result<Summary, RecordError> {
        let mut counts: Vec<(String, u64)> = self
            .channels
            .counts()
            .iter()
            .map(|(t, n)| (t.clone(), *n))
            .collect();
        counts.sort();
        let file = match self.sink {
            Sink::Live(server) => {
                server.stop();
                None
            }
            Sink::Record(recording) => {
                let path = recording.path().to_path_buf();
                Some((path, recording.close()?))
            }
        };
        Ok(Summary {
            counts,
            file,
            rejected: self.rejected,
            disk_low: self.disk_low,
        })
    }

    /// Publishes every service's newest status report (a new one as a log line).
    fn read_status(&mut self, cx: &mut Context) {
        for (camera, stage, reader) in &self.status {
            if let Some(report) = reader.latest() {
                if report.validate().is_ok() {
                    self.channels.on_status(camera, *stage, &report);
                } else {
                    cx.health.rejected();
                }
            }
        }
    }
}

/// Takes samples of every camera's input of one stream (all of them, or only the
/// newest if `latest`) and hands each to `publish` with its camera index; one
/// that `publish` turned into a message counts as sent.
fn take<S: StreamType>(
    inputs: &[Input<S>],
    latest: bool,
    cx: &mut Context,
    mut publish: impl FnMut(usize, &S::Header, &[S::Element]) -> bool,
) {
    for (k, input) in inputs.iter().enumerate() {
        loop {
            let sample = if latest {
                input.latest(cx)
            } else {
                input.next(cx)
            };
            let Some(s) = sample else { break };
            let arrived = Instant::now();
            if publish(k, s.header(), s.payload()) {
                let origin = s.header().preamble().origin_wall_ns;
                cx.health.sent(Some(arrived), origin);
            }
            if latest {
                break;
            }
        }
    }
}

/// Runs `publish` unless `h` ends its stream; true if it ran.
fn unless_end<H: StreamHeader>(h: &H, publish: impl FnOnce()) -> bool {
    let data = !h.preamble().is_end_of_stream();
    if data {
        publish();
    }
    data
}

impl Stage for ViewStage {
    type Inputs = ViewInputs;
    const KIND: StageKind = StageKind::View;

    fn on_wake(&mut self, inputs: &ViewInputs, cx: &mut Context) -> Result<(), Fatal> {
        let (activity, events, detections, frames, motion) = inputs;
        let (channels, ended) = (&mut self.channels, &mut self.ended);
        take(frames, true, cx, |k, h, pixels| {
            let t = h.preamble.capture_time_ns;
            !h.preamble.is_end_of_stream()
                && channels.wants_frame(k, t)
                && channels.on_frame(k, h, pixels)
        });
        take(motion, true, cx, |k, h, blocks| {
            let t = h.preamble.capture_time_ns;
            channels.wants_motion(k, t) && unless_end(h, || channels.on_motion(k, h, blocks))
        });
        take(activity, false, cx, |k, h, blocks| {
            ended[k] |= h.preamble.is_end_of_stream();
            unless_end(h, || channels.on_activity(k, h, blocks))
        });
        take(events, false, cx, |k, h, blocks| {
            unless_end(h, || channels.on_event(k, h, blocks))
        });
        take(detections, false, cx, |k, h, dets| {
            unless_end(h, || channels.on_detections(k, h, dets))
        });
        Ok(())
    }

    fn on_tick(&mut self, cx: &mut Context) -> Result<(), Fatal> {
        self.read_status(cx);
        if let Sink::Record(recording) = &self.sink
            && recording.disk_low()
        {
            self.disk_low = true;
        }
        Ok(())
    }

    fn on_stop(&mut self, cx: &mut Context) -> Result<(), Fatal> {
        self.read_status(cx);
        self.rejected = cx.health.status().rejected;
        Ok(())
    }

    /// A recording takes what already arrived (unless its disk runs low).
    fn take_inputs_on_stop(&self) -> bool {
        matches!(self.sink, Sink::Record(_)) && !self.disk_low
    }

    fn finished(&self) -> bool {
        let until = &self.until;
        self.disk_low
            || until.deadline.is_some_and(|d| Instant::now() >= d)
            || until
                .stop
                .as_ref()
                .is_some_and(|s| s.load(Ordering::Relaxed))
            || (until.sources_end && !self.ended.is_empty() && self.ended.iter().all(|e| *e))
    }

    fn timer(&self) -> Duration {
        TICK
    }

    fn counters(&self, c: &mut Counters) {
        c.set(view::PUBLISHED, self.published());
        c.set(view::TOPICS, self.channels.counts().len());
        if let Sink::Live(server) = &self.sink {
            let stats = server.stats();
            c.set(view::CLIENTS, stats.connected.load(Ordering::Relaxed));
            c.set(view::REFUSED_CLIENTS, stats.refused.load(Ordering::Relaxed));
            c.set(view::CLIENT_DROPS, stats.dropped.load(Ordering::Relaxed));
            c.set(view::STALLED_CLIENTS, stats.stalled.load(Ordering::Relaxed));
            c.set(view::QUEUED_BYTES, server.queued_bytes());
        }
    }

    fn info(&self) -> String {
        match self.sink {
            Sink::Live(_) => "sink=live".into(),
            Sink::Record(_) => "sink=record".into(),
        }
    }
}
