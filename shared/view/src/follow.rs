//! What the view and the recorder follow: one more subscriber of each camera's
//! streams, as stage inputs ([`Input`]: every sample checked and counted), which
//! take what is there and never wait for anything, so they cannot slow a producer
//! (on a live site delivery is lossy: a reader that falls behind loses its own
//! oldest samples). Frames are not subscribed to at all unless
//! `view.frames = true`. Each pipeline service's status is read as
//! `isochron status` reads it (the newest report, history 1).

use isochron_config::LoadedConfig;
use isochron_runtime::ipc::{
    Activity, Detections, Events, Frames, Ipc, IpcError, Motion, StatusSubscriber, StreamType,
};
use isochron_runtime::stage::Input;
use isochron_runtime::topology::StageKind;
use isochron_wire::Stream;

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

/// The view's inputs: per followed stream, one input per camera in the config's
/// order (none when the stream is not followed), so an input's position is its
/// camera's index in [`crate::channels::SiteChannels`].
pub type ViewInputs = (
    Vec<Input<Activity>>,
    Vec<Input<Events>>,
    Vec<Input<Detections>>,
    Vec<Input<Frames>>,
    Vec<Input<Motion>>,
);

/// A service's status reader: camera ("" site-wide), stage, reader.
pub type StatusReader = (String, StageKind, StatusSubscriber);

/// Subscribes to `streams` of every camera of the site (frames only with
/// `view.frames = true`).
pub fn open_inputs(
    ipc: &Ipc,
    loaded: &LoadedConfig,
    streams: Streams,
) -> Result<ViewInputs, IpcError> {
    fn of_every_camera<S: StreamType>(
        ipc: &Ipc,
        loaded: &LoadedConfig,
        followed: bool,
    ) -> Result<Vec<Input<S>>, IpcError> {
        if !followed {
            return Ok(Vec::new());
        }
        let cameras = &loaded.config.cameras;
        cameras.iter().map(|c| Input::open(ipc, &c.id)).collect()
    }
    Ok((
        of_every_camera(ipc, loaded, streams.activity)?,
        of_every_camera(ipc, loaded, streams.events)?,
        of_every_camera(ipc, loaded, streams.detections)?,
        of_every_camera(ipc, loaded, streams.frames && loaded.config.view.frames)?,
        of_every_camera(ipc, loaded, streams.motion)?,
    ))
}

/// Readers of the status of every service `isochron up` runs for the config
/// and of the imported cameras' stages ([`StageKind::services_of`]), if
/// `streams.status`.
pub fn status_readers(
    ipc: &Ipc,
    loaded: &LoadedConfig,
    streams: Streams,
) -> Result<Vec<StatusReader>, IpcError> {
    let mut readers = Vec::new();
    if !streams.status {
        return Ok(readers);
    }
    let config = &loaded.config;
    for (stage, camera) in StageKind::services_of(StageKind::started(config), config) {
        let reader = ipc.status_subscriber(&camera, stage)?;
        readers.push((camera, stage, reader));
    }
    Ok(readers)
}
