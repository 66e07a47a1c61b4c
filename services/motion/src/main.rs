//! isochron-motion: config → node → `frames` in, `motion` out → the stage runtime,
//! computing per-block motion features of every frame pair.

use std::process::ExitCode;

use clap::Parser;
use isochron_motion::stage::MotionStage;
use isochron_shared::service::{CameraArgs, run_cameras};
use isochron_shared::stage;
use isochron_shared::topology::StageKind;

/// Reads a camera's `frames` and publishes per-block motion on `<prefix>/<camera>/motion`.
#[derive(Parser)]
#[command(version)]
struct Args {
    #[command(flatten)]
    service: CameraArgs,
}

fn main() -> ExitCode {
    let args = Args::parse();
    run_cameras(StageKind::Motion, &args.service, |ctx| {
        let camera = ctx.camera();
        let (mut motion, frames) = MotionStage::open(&ctx.ipc, camera, &ctx.config.config.motion)?;
        stage::run(&ctx.ipc, &camera.id, &mut motion, &frames)
    })
}
