//! `isochron tap <camera> <stream>`: attach to a live stream as one more subscriber
//! and print one line (or JSON object) per sample.
//!
//! In live mode the tap can never slow a producer: a full tap buffer loses the tap's
//! oldest samples, not the producer's time.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::Context;
use isochron_config::clock::{format_rfc3339, format_t_star};
use isochron_runtime::ipc::{
    Activity, Detections, Events, Frames, Ipc, Motion, StreamSubscriber, StreamType,
};
use isochron_wire::{
    ActivityKind, CameraId, DIRECTION_NONE, EventPhase, FLAG_DISCONTINUITY, FLAG_END_OF_STREAM,
    FLAG_ILLUMINATION, Preamble, Stream, StreamHeader,
};
use serde_json::{Value, json};

use crate::common::load_config;

/// Print the samples of one stream of one camera as they arrive.
#[derive(clap::Args)]
pub struct Args {
    /// Camera id (a `[[camera]]` of the config).
    camera: String,
    /// Stream: frames, motion, activity, events or detections.
    #[arg(value_parser = crate::values::stream)]
    stream: Stream,
    /// Site configuration (default: $ISOCHRON_CONFIG or /etc/isochron/isochron.toml).
    #[arg(long)]
    config: Option<PathBuf>,
    /// One JSON object per line instead of text.
    #[arg(long)]
    json: bool,
    /// Exit 0 after this many samples.
    #[arg(long)]
    count: Option<u64>,
    /// Exit with 75 (try again) if no sample (or not all of `--count`) arrived
    /// within this many seconds.
    #[arg(long, value_parser = crate::values::seconds)]
    timeout: Option<Duration>,
    /// Exit 0 after the end-of-stream sample of a finite source.
    #[arg(long)]
    until_end: bool,
}

/// One decoded sample, ready to print.
struct Line {
    text: String,
    json: Value,
    end_of_stream: bool,
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let loaded = load_config(args.config.clone())?;
    let stream = args.stream;
    // A camera the config does not have (a `[[camera]]`, or one `[link]`
    // imports) never publishes: say so now (64, naming the configured
    // cameras) instead of waiting for it.
    if !loaded.config.link.import.contains(&args.camera) {
        loaded.camera(&args.camera)?;
    }
    let camera = CameraId::new(&args.camera)
        .with_context(|| format!("'{}' is not a valid camera id", args.camera))?;
    let ipc = Ipc::of_site(
        &format!("isochron-tap/{}/{}", args.camera, stream),
        &loaded.config,
    )?;
    match stream {
        Stream::Frames => tap::<Frames>(&ipc, &args, camera, describe_frame),
        Stream::Motion => tap::<Motion>(&ipc, &args, camera, describe_motion),
        Stream::Activity => tap::<Activity>(&ipc, &args, camera, describe_activity),
        Stream::Events => tap::<Events>(&ipc, &args, camera, describe_event),
        Stream::Detections => tap::<Detections>(&ipc, &args, camera, describe_detections),
    }
}

/// Turns a valid sample of stream `S`, and its [`common`] fields, into a [`Line`].
type Describe<S> =
    fn(&<S as StreamType>::Header, &[<S as StreamType>::Element], (String, Value)) -> Line;

fn tap<S: StreamType>(
    ipc: &Ipc,
    args: &Args,
    camera: CameraId,
    describe: Describe<S>,
) -> anyhow::Result<ExitCode> {
    let subscriber: StreamSubscriber<S> = ipc.subscriber(&args.camera)?;
    let started = Instant::now();
    let deadline = args.timeout.map(|t| started + t);
    let mut seen = 0u64;
    loop {
        while let Some(sample) = subscriber.receive()? {
            let (h, payload) = (sample.user_header(), sample.payload());
            match h.validate(&camera, payload.len()) {
                Ok(()) => {
                    let line = describe(h, payload, common(h.preamble()));
                    if args.json {
                        println!("{}", line.json);
                    } else {
                        println!("{}", line.text);
                    }
                    seen += 1;
                    if args.count.is_some_and(|n| seen >= n)
                        || (args.until_end && line.end_of_stream)
                    {
                        return Ok(ExitCode::SUCCESS);
                    }
                }
                Err(e) => eprintln!("isochron tap: rejected a sample: {e}"),
            }
        }
        if ipc.should_stop() {
            return Ok(ExitCode::SUCCESS);
        }
        if let Some(deadline) = deadline
            && Instant::now() >= deadline
        {
            eprintln!(
                "isochron tap: timeout after {:.1} s: {seen} samples{}",
                started.elapsed().as_secs_f64(),
                args.count.map(|n| format!(" of {n}")).unwrap_or_default()
            );
            return Ok(ExitCode::from(isochron_exit::TEMPFAIL as u8));
        }
        subscriber.wait(Duration::from_millis(100));
    }
}

fn flags(preamble: &Preamble) -> String {
    let mut names = Vec::new();
    if preamble.flags & FLAG_END_OF_STREAM != 0 {
        names.push("end");
    }
    if preamble.flags & FLAG_ILLUMINATION != 0 {
        names.push("illumination");
    }
    if preamble.flags & FLAG_DISCONTINUITY != 0 {
        names.push("discontinuity");
    }
    names.join(",")
}

/// The fields every line starts with.
fn common(p: &Preamble) -> (String, Value) {
    let text = format!(
        "{} {} seq={} t={}{}",
        p.camera.as_str(),
        Stream::ALL
            .iter()
            .find(|s| **s as u16 == p.stream)
            .map(|s| s.name())
            .unwrap_or("?"),
        p.sequence,
        format_rfc3339(p.capture_time_ns),
        if p.flags != 0 {
            format!(" flags={}", flags(p))
        } else {
            String::new()
        }
    );
    let json = json!({
        "camera": p.camera.as_str(),
        "sequence": p.sequence,
        "capture_time": format_rfc3339(p.capture_time_ns),
        "capture_time_ns": p.capture_time_ns,
        "flags": flags(p),
    });
    (text, json)
}

fn merge(mut base: Value, extra: Value) -> Value {
    if let (Some(b), Some(e)) = (base.as_object_mut(), extra.as_object()) {
        for (k, v) in e {
            b.insert(k.clone(), v.clone());
        }
    }
    base
}

fn describe_frame(
    h: &isochron_wire::FrameHeader,
    pixels: &[u8],
    (text, json): (String, Value),
) -> Line {
    let mean = if pixels.is_empty() {
        0.0
    } else {
        pixels.iter().map(|&p| p as u64).sum::<u64>() as f64 / pixels.len() as f64
    };
    let checksum = crc32(pixels);
    Line {
        text: format!(
            "{text} index={} {}x{} {:?} mean={mean:.1} crc32={checksum:08x}",
            h.source_index,
            h.width,
            h.height,
            h.format()
        ),
        json: merge(
            json,
            json!({"source_index": h.source_index, "width": h.width, "height": h.height,
                   "pixel_format": format!("{:?}", h.format()), "mean": mean, "crc32": checksum}),
        ),
        end_of_stream: h.preamble.is_end_of_stream(),
    }
}

/// CRC-32 (IEEE) of the pixels, the same checksum tests compute on OpenCV's decode.
pub fn crc32(bytes: &[u8]) -> u32 {
    let mut h = crc32fast::Hasher::new();
    h.update(bytes);
    h.finalize()
}

fn describe_motion(
    h: &isochron_wire::MotionHeader,
    blocks: &[isochron_wire::BlockMotion],
    (text, json): (String, Value),
) -> Line {
    let moving = blocks.iter().filter(|b| b.density > 0.0).count();
    let directed = blocks
        .iter()
        .filter(|b| b.direction != DIRECTION_NONE)
        .count();
    let total: f32 = blocks.iter().map(|b| b.density).sum();
    let max = blocks.iter().map(|b| b.density).fold(0.0f32, f32::max);
    Line {
        text: format!(
            "{text} index={} grid={}x{} moving={moving} directed={directed} density_sum={total:.3} max={max:.3} changed={:.2}",
            h.source_index, h.grid_w, h.grid_h, h.changed_fraction
        ),
        json: merge(
            json,
            json!({"source_index": h.source_index, "grid_w": h.grid_w, "grid_h": h.grid_h,
                   "moving_blocks": moving, "directed_blocks": directed, "density_sum": total,
                   "density_max": max, "changed_fraction": h.changed_fraction}),
        ),
        end_of_stream: h.preamble.is_end_of_stream(),
    }
}

fn describe_activity(
    h: &isochron_wire::ActivityHeader,
    blocks: &[isochron_wire::BlockActivity],
    (text, json): (String, Value),
) -> Line {
    let s1: f32 = blocks.iter().map(|b| b.s1).sum();
    let s2: f32 = blocks.iter().map(|b| b.s2).sum();
    let lt: f32 = blocks.iter().map(|b| b.lt_mean).sum();
    Line {
        text: format!(
            "{text} t*={} frames={} [{}..{}] s1_sum={s1:.3} s2_sum={s2:.3} lt_mean_sum={lt:.3} model_days={} r={:.2}",
            format_t_star(h.t_star),
            h.frames,
            h.first_source_index,
            h.last_source_index,
            h.model_days,
            h.frame_rate
        ),
        json: merge(
            json,
            json!({"t_star": h.t_star, "frames": h.frames, "first_source_index": h.first_source_index,
                   "last_source_index": h.last_source_index, "s1_sum": s1, "s2_sum": s2,
                   "lt_mean_sum": lt, "model_days": h.model_days, "frame_rate": h.frame_rate}),
        ),
        end_of_stream: h.preamble.is_end_of_stream(),
    }
}

fn describe_event(
    h: &isochron_wire::EventHeader,
    blocks: &[u32],
    (text, json): (String, Value),
) -> Line {
    if h.preamble.is_end_of_stream() {
        return Line {
            text,
            json,
            end_of_stream: true,
        };
    }
    let phase = if h.phase == EventPhase::Start as u32 {
        "start"
    } else {
        "end"
    };
    let kind = ActivityKind::from_u32(h.kind)
        .map(|k| k.name())
        .unwrap_or("?");
    Line {
        text: format!(
            "{text} event={} {phase} zone={} kind={kind} start={} end={} frames={}..{} peak={:.3} threshold={:.3} blocks={}",
            h.event_id,
            h.zone_name(),
            format_rfc3339(h.start_ns),
            if h.end_ns != 0 {
                format_rfc3339(h.end_ns)
            } else {
                "-".into()
            },
            h.start_frame,
            h.end_frame,
            h.peak,
            h.threshold,
            blocks.len()
        ),
        json: merge(
            json,
            json!({"event_id": h.event_id, "phase": phase, "zone": h.zone_name(), "kind": kind,
                   "start": format_rfc3339(h.start_ns), "end": (h.end_ns != 0).then(|| format_rfc3339(h.end_ns)),
                   "start_frame": h.start_frame, "end_frame": h.end_frame, "peak": h.peak,
                   "threshold": h.threshold, "blocks": blocks}),
        ),
        end_of_stream: false,
    }
}

/// One detection as `tap --json` and `replay`'s `detections.jsonl` write it: its
/// box (frame pixels), score, class, model and, where the model gave them,
/// `keypoints` (COCO's 17 as `[x, y, score]`; absent otherwise).
pub(crate) fn detection_json(d: &isochron_wire::Detection) -> Value {
    let mut out = json!({"x": d.x, "y": d.y, "w": d.w, "h": d.h, "score": d.score,
        "class": d.class, "model": d.model().name()});
    if d.has_pose() {
        out["keypoints"] = d
            .keypoints
            .iter()
            .map(|k| json!([k.x, k.y, k.score]))
            .collect();
    }
    out
}

fn describe_detections(
    h: &isochron_wire::DetectionHeader,
    dets: &[isochron_wire::Detection],
    (text, json): (String, Value),
) -> Line {
    let saved = if h.frames_seen > 0 {
        1.0 - h.frames_detected as f64 / h.frames_seen as f64
    } else {
        0.0
    };
    Line {
        text: format!(
            "{text} event={} index={} people={} model={} detector_ms={:.1} seen={} detected={} dropped_jobs={} saved={:.1}%",
            h.event_id,
            h.source_index,
            dets.len(),
            dets.first().map_or("-", |d| d.model().name()),
            h.detector_us as f64 / 1e3,
            h.frames_seen,
            h.frames_detected,
            h.jobs_dropped,
            saved * 100.0
        ),
        json: merge(
            json,
            json!({"event_id": h.event_id, "source_index": h.source_index,
                   "detections": dets.iter().map(detection_json).collect::<Vec<_>>(),
                   "detector_ms": h.detector_us as f64 / 1e3, "frames_seen": h.frames_seen,
                   "frames_detected": h.frames_detected, "jobs_dropped": h.jobs_dropped,
                   "detector_total_ms": h.detector_total_us as f64 / 1e3}),
        ),
        end_of_stream: h.preamble.is_end_of_stream(),
    }
}
