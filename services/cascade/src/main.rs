//! isochron-cascade: config → store → node → `motion` in, `activity` out → the stage
//! runtime, filtering motion into 1-Hz activity and the long-term store.

use std::process::ExitCode;

use clap::Parser;
use isochron_cascade::stage::CascadeStage;
use isochron_shared::service::{CameraArgs, run_cameras};
use isochron_shared::stage;
use isochron_shared::topology::StageKind;

/// Filters one camera's motion stream into 1-Hz activity and the long-term store.
#[derive(Parser)]
#[command(version)]
struct Args {
    #[command(flatten)]
    service: CameraArgs,
}

fn main() -> ExitCode {
    let args = Args::parse();
    run_cameras(StageKind::Cascade, &args.service, |ctx| {
        let camera = ctx.camera();
        let (mut cascade, motion) = CascadeStage::open(&ctx.ipc, &ctx.config, camera)?;
        stage::run(&ctx.ipc, &camera.id, &mut cascade, &motion)
    })
}
