//! What the replay collects: its own inputs, one per produced stream, the
//! samples counted per stream, the events and detections written as JSON lines,
//! and `summary.json`.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::Context as _;
use isochron_config::clock::format_rfc3339;
use isochron_runtime::health::InputCompleteness;
use isochron_runtime::ipc::{Activity, Detections, Events, Frames, Ipc, IpcError, Motion};
use isochron_runtime::stage::{Context, Input, Received};
use isochron_runtime::topology::StageKind;
use isochron_wire::{ActivityKind, DetectionHeader, EventPhase, Stream};
use serde_json::json;

use crate::tap::detection_json;

/// The replay's inputs: every stream an installed stage produces (frames always).
pub type ReplayInputs = (
    Input<Frames>,
    Option<Input<Motion>>,
    Option<Input<Activity>>,
    Option<Input<Events>>,
    Option<Input<Detections>>,
);

/// Subscribes to each stream of `camera` that one of `stages` produces.
pub fn open_inputs(
    ipc: &Ipc,
    camera: &str,
    stages: &[(StageKind, PathBuf)],
) -> Result<ReplayInputs, IpcError> {
    let has = |stream: Stream| {
        stages
            .iter()
            .any(|(stage, _)| stage.produces().contains(&stream))
    };
    Ok((
        Input::open(ipc, camera)?,
        has(Stream::Motion)
            .then(|| Input::open(ipc, camera))
            .transpose()?,
        has(Stream::Activity)
            .then(|| Input::open(ipc, camera))
            .transpose()?,
        has(Stream::Events)
            .then(|| Input::open(ipc, camera))
            .transpose()?,
        has(Stream::Detections)
            .then(|| Input::open(ipc, camera))
            .transpose()?,
    ))
}

/// Samples seen per stream, and the files written from them.
pub struct Tally {
    camera: String,
    counts: BTreeMap<Stream, u64>,
    ended: BTreeMap<Stream, bool>,
    events_out: BufWriter<File>,
    detections_out: BufWriter<File>,
    finished_events: u64,
    gate: serde_json::Value,
}

/// The hybrid scheme's counters as a detections header states them.
fn gate_summary(h: &DetectionHeader) -> serde_json::Value {
    json!({
        "frames_seen": h.frames_seen,
        "frames_detected": h.frames_detected,
        "jobs_dropped": h.jobs_dropped,
        "detector_total_ms": h.detector_total_us as f64 / 1e3,
    })
}

/// A data sample (`Some`), or the end of its stream (`None`, noted in `ended`).
fn data<S: isochron_runtime::ipc::StreamType>(
    sample: Received<S>,
    ended: &mut bool,
) -> Option<Received<S>> {
    if sample.is_end_of_stream() {
        *ended = true;
        None
    } else {
        Some(sample)
    }
}

/// How a replay ended, as `summary.json` says.
#[derive(Debug, Clone, Copy)]
pub enum Ending<'a> {
    /// Every stream ended.
    Complete,
    /// A stage failed or nothing moved: why.
    Failed(&'a str),
    /// SIGINT or SIGTERM stopped it: what it says.
    Interrupted(&'a str),
}

impl Tally {
    /// A tally of `camera` for `inputs`, writing its files into `out`.
    pub fn new(camera: &str, inputs: &ReplayInputs, out: &Path) -> anyhow::Result<Self> {
        let create = |name: &str| -> anyhow::Result<BufWriter<File>> {
            let path = out.join(name);
            Ok(BufWriter::new(
                File::create(&path).with_context(|| format!("creating {}", path.display()))?,
            ))
        };
        let mut ended = BTreeMap::new();
        ended.insert(Stream::Frames, false);
        for (stream, present) in [
            (Stream::Motion, inputs.1.is_some()),
            (Stream::Activity, inputs.2.is_some()),
            (Stream::Events, inputs.3.is_some()),
            (Stream::Detections, inputs.4.is_some()),
        ] {
            if present {
                ended.insert(stream, false);
            }
        }
        Ok(Tally {
            camera: camera.to_string(),
            counts: Stream::ALL.iter().map(|s| (*s, 0)).collect(),
            ended,
            events_out: create("events.jsonl")?,
            detections_out: create("detections.jsonl")?,
            finished_events: 0,
            gate: json!({}),
        })
    }

    /// Counts what arrived (and writes the events and detections).
    pub fn take(&mut self, inputs: &ReplayInputs, cx: &mut Context) -> anyhow::Result<()> {
        let (frames, motion, activity, events, detections) = inputs;
        self.count(Stream::Frames, frames, cx);
        if let Some(input) = motion {
            self.count(Stream::Motion, input, cx);
        }
        if let Some(input) = activity {
            self.count(Stream::Activity, input, cx);
        }
        if let Some(input) = events {
            self.take_events(input, cx)?;
        }
        if let Some(input) = detections {
            self.take_detections(input, cx)?;
        }
        Ok(())
    }

    /// Counts the samples of `stream` waiting on `input`.
    fn count<S: isochron_runtime::ipc::StreamType>(
        &mut self,
        stream: Stream,
        input: &Input<S>,
        cx: &mut Context,
    ) {
        let mut ended = false;
        let mut n = 0;
        while let Some(sample) = input.next(cx) {
            n += data(sample, &mut ended).is_some() as u64;
        }
        self.add(stream, n, ended);
    }

    fn add(&mut self, stream: Stream, n: u64, ended: bool) {
        *self.counts.entry(stream).or_default() += n;
        if ended {
            self.ended.insert(stream, true);
        }
    }

    /// Writes a line per finished event.
    fn take_events(&mut self, input: &Input<Events>, cx: &mut Context) -> anyhow::Result<()> {
        let (mut n, mut ended) = (0, false);
        while let Some(sample) = input.next(cx) {
            let Some(sample) = data(sample, &mut ended) else {
                continue;
            };
            n += 1;
            let h = sample.header();
            if h.phase != EventPhase::End as u32 {
                continue;
            }
            self.finished_events += 1;
            let line = json!({
                "camera": self.camera,
                "event_id": h.event_id,
                "zone": h.zone_name(),
                "kind": ActivityKind::from_u32(h.kind).map(|k| k.name()).unwrap_or("?"),
                "start": format_rfc3339(h.start_ns),
                "end": format_rfc3339(h.end_ns),
                "start_frame": h.start_frame,
                "end_frame": h.end_frame,
                "peak": h.peak,
                "threshold": h.threshold,
                "blocks": sample.payload(),
            });
            writeln!(self.events_out, "{line}")?;
        }
        self.add(Stream::Events, n, ended);
        Ok(())
    }

    /// Writes a line per detected frame; keeps the gate's counters (the end of
    /// stream carries the final ones).
    fn take_detections(
        &mut self,
        input: &Input<Detections>,
        cx: &mut Context,
    ) -> anyhow::Result<()> {
        let (mut n, mut ended) = (0, false);
        while let Some(sample) = input.next(cx) {
            let h = sample.header();
            self.gate = gate_summary(h);
            let Some(sample) = data(sample, &mut ended) else {
                continue;
            };
            n += 1;
            let h = sample.header();
            let line = json!({
                "camera": self.camera,
                "event_id": h.event_id,
                "frame": h.source_index,
                "capture_time": format_rfc3339(h.preamble.capture_time_ns),
                "detector_ms": h.detector_us as f64 / 1e3,
                "searched": [h.roi_x, h.roi_y, h.roi_w, h.roi_h],
                "detections": sample.payload().iter().map(detection_json).collect::<Vec<_>>(),
            });
            writeln!(self.detections_out, "{line}")?;
        }
        self.add(Stream::Detections, n, ended);
        Ok(())
    }

    /// True once every stream has ended.
    pub fn all_ended(&self) -> bool {
        self.ended.values().all(|e| *e)
    }

    /// Counts per stream, with events counted as finished events.
    fn counts(&self) -> Vec<(&'static str, u64)> {
        Stream::ALL
            .iter()
            .map(|s| {
                let n = if *s == Stream::Events {
                    self.finished_events
                } else {
                    self.counts.get(s).copied().unwrap_or(0)
                };
                (s.name(), n)
            })
            .collect()
    }

    /// Samples counted so far, all streams.
    pub fn total(&self) -> u64 {
        self.counts.values().sum()
    }

    /// `frames=N motion=N ...`.
    pub fn counts_line(&self) -> String {
        self.counts()
            .iter()
            .map(|(k, v)| format!("{k}={v}"))
            .collect::<Vec<_>>()
            .join(" ")
    }

    /// Writes `summary.json`; `input` is capture's account of the file (see
    /// [`InputCompleteness`]), if it gave one; `ending` how the replay ended
    /// (`"failure"`: why it stopped before every stream ended, `null` when it
    /// did not; `"interrupted"`: stopped by SIGINT or SIGTERM).
    pub fn finish(
        &mut self,
        out: &Path,
        video: &Path,
        wall: Duration,
        input: Option<InputCompleteness>,
        ending: Ending<'_>,
    ) -> anyhow::Result<()> {
        let (failure, interrupted) = match ending {
            Ending::Complete => (None, false),
            Ending::Failed(why) => (Some(why), false),
            Ending::Interrupted(why) => (Some(why), true),
        };
        self.events_out.flush()?;
        self.detections_out.flush()?;
        let counts: serde_json::Map<String, serde_json::Value> = self
            .counts()
            .into_iter()
            .map(|(k, v)| (k.to_string(), json!(v)))
            .collect();
        let frames = self.counts.get(&Stream::Frames).copied().unwrap_or(0);
        let summary = json!({
            "video": video,
            "camera": self.camera,
            "counts": counts,
            "wall_time_s": wall.as_secs_f64(),
            "frames_per_s": frames as f64 / wall.as_secs_f64().max(1e-9),
            "gate": self.gate,
            "failure": failure,
            "interrupted": interrupted,
            "input": match input {
                Some(i) => json!({
                    "frames_stated": (i.frames_stated > 0).then_some(i.frames_stated),
                    "frames_read": i.frames_read,
                    "truncated": i.truncated,
                }),
                // Capture said nothing (it did not end on the file): unknown.
                None => json!({
                    "frames_stated": null,
                    "frames_read": frames,
                    "truncated": null,
                }),
            },
        });
        // Whole or not at all: a full disk leaves no empty summary.
        let path = out.join("summary.json");
        let file = crate::common::OutFile::create("summary.json", &path)?;
        std::fs::write(file.path(), serde_json::to_string_pretty(&summary)? + "\n")
            .with_context(|| format!("writing {}", path.display()))?;
        file.commit()
    }
}
