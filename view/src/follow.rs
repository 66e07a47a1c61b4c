//! The view's and recorder's side of the group: one more subscriber of each
//! camera's streams, which takes what is there and never waits for anything, so it
//! cannot slow a producer (on a live site delivery is lossy: a reader that falls
//! behind loses its own oldest samples). Images are taken latest-first and at most
//! `view.frame_rate_hz`; frames are not subscribed to at all unless
//! `view.frames = true`. Motion is taken latest-first too, at most 2 per second
//! ([`crate::channels::MOTION_EVERY_NS`]); each service's status is read as
//! `isochron status` reads it (the newest report, history 1).

use std::time::Duration;

use isochron_shared::config::LoadedConfig;
use isochron_shared::ipc::{
    Activity, Detections, Events, Frames, Ipc, IpcError, Motion, ReceivedSample, StatusSubscriber,
    StreamSubscriber, StreamType,
};
use isochron_shared::topology::StageKind;
use isochron_shared::wire::{CameraId, Stream, StreamHeader};

use crate::channels::SiteChannels;

/// Which streams to follow (the cost map and scene come with `activity`; `status`
/// is not a stream but every service's status service).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Streams {
    /// `activity`: the cameras' activity grids, the cost map, the scene.
    pub activity: bool,
    /// `events`: log lines.
    pub events: bool,
    /// `detections`: image annotations.
    pub detections: bool,
    /// `frames`: images (only with `view.frames = true`).
    pub frames: bool,
    /// `motion`: the motion blocks, at most 2 Hz.
    pub motion: bool,
    /// `status`: every service's status reports.
    pub status: bool,
}

impl Streams {
    /// Every stream the config allows.
    pub fn all(loaded: &LoadedConfig) -> Streams {
        Streams {
            activity: true,
            events: true,
            detections: true,
            frames: loaded.config.view.frames,
            motion: true,
            status: true,
        }
    }

    /// A comma-separated list of `activity`, `events`, `detections`, `frames`.
    pub fn parse(list: &str, loaded: &LoadedConfig) -> Result<Streams, String> {
        let mut s = Streams {
            activity: false,
            events: false,
            detections: false,
            frames: false,
            motion: false,
            status: false,
        };
        for name in list.split(',').map(str::trim).filter(|n| !n.is_empty()) {
            if name == "status" {
                s.status = true;
                continue;
            }
            match Stream::from_name(name) {
                Some(Stream::Motion) => s.motion = true,
                Some(Stream::Activity) => s.activity = true,
                Some(Stream::Events) => s.events = true,
                Some(Stream::Detections) => s.detections = true,
                Some(Stream::Frames) if loaded.config.view.frames => s.frames = true,
                Some(Stream::Frames) => {
                    return Err(format!(
                        "--streams frames: images are off for this site (set view.frames = true in {})",
                        loaded.path.display()
                    ));
                }
                _ => {
                    return Err(format!(
                        "--streams: unknown stream '{name}': expected activity, motion, events, detections, status or frames"
                    ));
                }
            }
        }
        Ok(s)
    }
}

struct CameraSubscribers {
    k: usize,
    camera: CameraId,
    activity: Option<StreamSubscriber<Activity>>,
    events: Option<StreamSubscriber<Events>>,
    detections: Option<StreamSubscriber<Detections>>,
    frames: Option<StreamSubscriber<Frames>>,
    motion: Option<StreamSubscriber<Motion>>,
    ended: bool,
}

/// The subscribers of every camera.
pub struct Follower {
    cameras: Vec<CameraSubscribers>,
    /// Every service's status reader: camera ("" site-wide), stage.
    status: Vec<(String, StageKind, StatusSubscriber)>,
    /// Samples taken and published.
    pub samples: u64,
    /// Samples whose header did not check out (skipped).
    pub rejected: u64,
}

impl Follower {
    /// Subscribes to `streams` of every camera of the site.
    pub fn open(
        ipc: &Ipc,
        loaded: &LoadedConfig,
        channels: &SiteChannels,
        streams: Streams,
    ) -> Result<Follower, IpcError> {
        let mut cameras = Vec::new();
        for cam in &loaded.config.cameras {
            let (Some(k), Some(camera)) = (channels.camera_index(&cam.id), CameraId::new(&cam.id))
            else {
                continue;
            };
            cameras.push(CameraSubscribers {
                k,
                camera,
                activity: streams
                    .activity
                    .then(|| ipc.subscriber(&cam.id))
                    .transpose()?,
                events: streams
                    .events
                    .then(|| ipc.subscriber(&cam.id))
                    .transpose()?,
                detections: streams
                    .detections
                    .then(|| ipc.subscriber(&cam.id))
                    .transpose()?,
                frames: (streams.frames && loaded.config.view.frames)
                    .then(|| ipc.subscriber(&cam.id))
                    .transpose()?,
                motion: streams
                    .motion
                    .then(|| ipc.subscriber(&cam.id))
                    .transpose()?,
                ended: false,
            });
        }
        let mut status = Vec::new();
        if streams.status {
            for stage in StageKind::ALL {
                if stage.per_camera() {
                    for cam in &loaded.config.cameras {
                        status.push((
                            cam.id.clone(),
                            stage,
                            ipc.status_subscriber(&cam.id, stage)?,
                        ));
                    }
                } else {
                    status.push((String::new(), stage, ipc.status_subscriber("", stage)?));
                }
            }
        }
        Ok(Follower {
            cameras,
            status,
            samples: 0,
            rejected: 0,
        })
    }

    /// Takes every waiting sample and publishes it on `channels`; returns how many.
    pub fn poll(&mut self, channels: &mut SiteChannels) -> Result<u64, IpcError> {
        let before = self.samples;
        for c in &mut self.cameras {
            // Latest first: of what waits, only the newest frame can be shown, and
            // only the newest motion is published (at most 2 Hz).
            if let Some(s) = newest(&c.frames, &c.camera, &mut self.rejected)? {
                self.samples += 1;
                let h = s.user_header();
                if channels.wants_frame(c.k, h.preamble.capture_time_ns) {
                    channels.on_frame(c.k, h, s.payload());
                }
            }
            if let Some(s) = newest(&c.motion, &c.camera, &mut self.rejected)? {
                self.samples += 1;
                let h = s.user_header();
                if channels.wants_motion(c.k, h.preamble.capture_time_ns) {
                    channels.on_motion(c.k, h, s.payload());
                }
            }
            if let Some(sub) = &c.activity {
                while let Some(s) = sub.receive()? {
                    let h = s.user_header();
                    if h.validate(&c.camera, s.payload().len()).is_err() {
                        self.rejected += 1;
                    } else if h.preamble.is_end_of_stream() {
                        c.ended = true;
                    } else {
                        self.samples += 1;
                        channels.on_activity(c.k, h, s.payload());
                    }
                }
            }
            if let Some(sub) = &c.events {
                while let Some(s) = sub.receive()? {
                    let h = s.user_header();
                    if h.validate(&c.camera, s.payload().len()).is_err() {
                        self.rejected += 1;
                    } else if !h.preamble.is_end_of_stream() {
                        self.samples += 1;
                        channels.on_event(c.k, h, s.payload());
                    }
                }
            }
            if let Some(sub) = &c.detections {
                while let Some(s) = sub.receive()? {
                    let h = s.user_header();
                    if h.validate(&c.camera, s.payload().len()).is_err() {
                        self.rejected += 1;
                    } else if !h.preamble.is_end_of_stream() {
                        self.samples += 1;
                        channels.on_detections(c.k, h, s.payload());
                    }
                }
            }
        }
        for (camera, stage, reader) in &self.status {
            if let Some(report) = reader.latest() {
                if report.validate().is_ok() {
                    channels.on_status(camera, *stage, &report);
                } else {
                    self.rejected += 1;
                }
            }
        }
        Ok(self.samples - before)
    }

    /// True once every followed camera's activity has ended (a file source ran
    /// out); never without `activity`.
    pub fn all_ended(&self) -> bool {
        !self.cameras.is_empty() && self.cameras.iter().all(|c| c.activity.is_some() && c.ended)
    }

    /// Sleeps until a followed stream may have news, at most `timeout`.
    pub fn wait(&self, timeout: Duration) {
        match self.cameras.first().and_then(|c| c.activity.as_ref()) {
            Some(sub) => sub.wait(timeout),
            None => std::thread::sleep(timeout),
        }
    }
}

/// The newest sample waiting on `sub` (if subscribed), the older ones skipped; `None`
/// when nothing waits, or the newest is the end of stream or malformed (counted in
/// `rejected`).
fn newest<S: StreamType>(
    sub: &Option<StreamSubscriber<S>>,
    camera: &CameraId,
    rejected: &mut u64,
) -> Result<Option<ReceivedSample<S>>, IpcError> {
    let Some(sub) = sub else { return Ok(None) };
    let mut newest = None;
    while let Some(sample) = sub.receive()? {
        newest = Some(sample);
    }
    Ok(newest.filter(|s| {
        let h = s.user_header();
        if h.validate(camera, s.payload().len()).is_err() {
            *rejected += 1;
            return false;
        }
        !h.preamble().is_end_of_stream()
    }))
}
