//! The service's `run`: the capture stage of a configured camera, on the
//! runtime. A file is opened (and preloaded, if asked) before the loop starts,
//! so a missing or undecodable one ends the process with its permanent code at
//! once; a live camera is opened by the stage, which backs off while it cannot.

use isochron_config::clock::parse_rfc3339;
use isochron_config::{CameraConfig, SourceKind};
use isochron_exit::{self as exit, Fatal};
use isochron_runtime::service::ServiceContext;
use isochron_runtime::stage::{self, Output};

use crate::Backoff;
use crate::source::{FrameSource, PreloadedSource, VideoSource};
use crate::stage::{CaptureStage, Opener, Playback, Settings};
use crate::stream::{StreamOptions, StreamSource};

/// Reads the camera of `ctx` and publishes its frames until the file ends or the
/// process is asked to stop.
pub fn run(ctx: ServiceContext) -> Result<(), Fatal> {
    let cam = ctx.camera();
    let kind = cam.source_kind(&ctx.config.base_dir());
    let settings = settings(cam, &kind)?;
    let open: Opener = {
        let (kind, options) = (kind.clone(), stream_options(cam));
        Box::new(move || -> Result<Box<dyn FrameSource>, _> {
            match &kind {
                SourceKind::Url(url) => Ok(Box::new(StreamSource::open(
                    url,
                    &kind.to_string(),
                    &options,
                )?)),
                _ => Ok(Box::new(VideoSource::open(&kind)?)),
            }
        })
    };
    let output = Output::new(&ctx.ipc, &cam.id);
    let mut capture = if kind.is_file() {
        let mut video = VideoSource::open(&kind)?;
        let playback = Playback::of(&settings, &mut video)?;
        let first: Box<dyn FrameSource> = match cam.preload_frames {
            None => {
                video.seek(cam.start_frame)?;
                Box::new(video)
            }
            Some(n) => {
                let f = playback.frame;
                let preloaded = PreloadedSource::load(&kind, n, f.width, f.height, f.format)?
                    .start_at(cam.start_frame);
                tracing::info!(
                    "preloaded {} frames: publishing them in a loop, no decoding",
                    preloaded.len()
                );
                Box::new(preloaded)
            }
        };
        CaptureStage::playing(settings, open, first, playback, output)?
    } else {
        CaptureStage::connecting(settings, open, output)
    };
    stage::run(&ctx.ipc, &cam.id, &mut capture, &())
}

/// How a network camera is read, from the camera's config.
fn stream_options(cam: &CameraConfig) -> StreamOptions {
    StreamOptions {
        transport: cam.transport,
        connect_timeout: isochron_config::clock::saturating_secs(cam.connect_timeout_s),
        read_timeout: isochron_config::clock::saturating_secs(cam.read_timeout_s),
    }
}

/// The stage's settings from the camera's config.
fn settings(cam: &CameraConfig, kind: &SourceKind) -> Result<Settings, Fatal> {
    let start_ns = cam
        .start
        .as_deref()
        .map(|s| {
            parse_rfc3339(s).map_err(|e| {
                Fatal::with_source(exit::CONFIG, format!("camera '{}': start", cam.id), e)
            })
        })
        .transpose()?;
    Ok(Settings {
        camera: cam.id.clone(),
        is_file: kind.is_file(),
        loop_file: cam.loop_file,
        size: cam.width.zip(cam.height),
        format: cam.format(),
        fps: cam.fps,
        speed: cam.speed,
        start_ns,
        backoff: Backoff::new(
            isochron_config::clock::saturating_secs(cam.reconnect_initial_s),
            isochron_config::clock::saturating_secs(cam.reconnect_max_s),
        ),
    })
}
