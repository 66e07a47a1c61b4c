//! The streams the bench reads as they arrive: activity (latency), event records
//! and detections; and what two status reports say of the window.

use isochron_config::clock::wall_now_ns;
use isochron_runtime::ipc::{Activity, Detections, Events, Ipc, StreamSubscriber, StreamType};
use isochron_wire::{EventPhase, StreamHeader};

/// What the bench reads from the streams of every camera as they arrive (every
/// [`PROBE_POLL`]): activity (for the capture → activity latency), event records
/// and detections.
#[derive(Default)]
pub(crate) struct Probe {
    pub(crate) activity: Vec<StreamSubscriber<Activity>>,
    pub(crate) events: Vec<StreamSubscriber<Events>>,
    pub(crate) detections: Vec<StreamSubscriber<Detections>>,
    /// Arrival (wall clock, ns), camera and latency (ms) of each activity sample in
    /// the window.
    pub(crate) samples: Vec<(i64, usize, f32)>,
    /// Per camera: events started and ended in the window.
    pub(crate) started: Vec<u64>,
    pub(crate) ended: Vec<u64>,
    /// End lag of each end record in the window, ms.
    pub(crate) end_lags_ms: Vec<f32>,
    /// Per camera: detections in the window.
    pub(crate) detected: Vec<u64>,
    /// Latency of each detection in the window, ms.
    pub(crate) detection_ms: Vec<f32>,
}

impl Probe {
    pub(crate) fn open(ipc: &Ipc, cameras: &[String]) -> Result<Probe, String> {
        fn each<S: isochron_runtime::ipc::StreamType>(
            ipc: &Ipc,
            cameras: &[String],
        ) -> Result<Vec<StreamSubscriber<S>>, String> {
            cameras
                .iter()
                .map(|camera| {
                    ipc.subscriber::<S>(camera)
                        .map_err(|e| format!("{} of {camera}: {e}", S::STREAM))
                })
                .collect()
        }
        Ok(Probe {
            activity: each(ipc, cameras)?,
            events: each(ipc, cameras)?,
            detections: each(ipc, cameras)?,
            started: vec![0; cameras.len()],
            ended: vec![0; cameras.len()],
            detected: vec![0; cameras.len()],
            ..Probe::default()
        })
    }

    /// Takes every waiting sample; records them if `record`.
    pub(crate) fn poll(&mut self, record: bool) {
        let ms_since = |origin: i64| (wall_now_ns() - origin) as f32 / 1e6;
        for (camera, subscriber) in self.activity.iter().enumerate() {
            subscriber.drain_wakeups();
            while let Ok(Some(sample)) = subscriber.receive() {
                let now = wall_now_ns();
                let origin = sample.user_header().preamble.origin_wall_ns;
                if record && origin > 0 {
                    self.samples
                        .push((now, camera, (now - origin) as f32 / 1e6));
                }
            }
        }
        drain(
            &self.events,
            record,
            |camera, h| match EventPhase::from_u32(h.phase) {
                Some(EventPhase::Start) => self.started[camera] += 1,
                Some(EventPhase::End) => {
                    self.ended[camera] += 1;
                    if h.preamble.origin_wall_ns > 0 {
                        self.end_lags_ms.push(ms_since(h.preamble.origin_wall_ns));
                    }
                }
                None => {}
            },
        );
        drain(&self.detections, record, |camera, h| {
            self.detected[camera] += 1;
            if h.preamble.origin_wall_ns > 0 {
                self.detection_ms.push(ms_since(h.preamble.origin_wall_ns));
            }
        });
    }
}

/// Takes every waiting sample of the cameras' `subscribers`; if `record`, passes
/// the header of each data sample (not end-of-stream) with its camera to `f`.
pub(crate) fn drain<S: StreamType>(
    subscribers: &[StreamSubscriber<S>],
    record: bool,
    mut f: impl FnMut(usize, &S::Header),
) {
    for (camera, subscriber) in subscribers.iter().enumerate() {
        subscriber.drain_wakeups();
        while let Ok(Some(sample)) = subscriber.receive() {
            let h = sample.user_header();
            if record && !h.preamble().is_end_of_stream() {
                f(camera, h);
            }
        }
    }
}

/// What two status reports of one stage of one camera say about the window.
pub(crate) struct Window {
    /// Samples published per second (for the gate: frames taken per second).
    pub(crate) rate: f64,
    /// Samples published (for the gate: frames taken) in the window.
    pub(crate) done: u64,
    /// Samples dropped (here or upstream).
    pub(crate) dropped: u64,
    /// The gate's detection jobs accepted and dropped.
    pub(crate) jobs: Option<(u64, u64)>,
}
