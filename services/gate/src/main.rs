//! isochron-gate: config → node → `frames` + `activity` in, `events` + `detections`
//! out → the stage runtime. Frames go into the ring; activity drives the event
//! trackers; the detector thread runs on the gated frames.

use std::process::ExitCode;

use clap::Parser;
use isochron_gate::stage::GateStage;
use isochron_shared::service::{CameraArgs, run_cameras};
use isochron_shared::stage;
use isochron_shared::topology::StageKind;

/// Raises events from a camera's activity and runs the detector on gated frames.
#[derive(Parser)]
#[command(version)]
struct Args {
    #[command(flatten)]
    service: CameraArgs,
}

fn main() -> ExitCode {
    let args = Args::parse();
    run_cameras(StageKind::Gate, &args.service, |ctx| {
        let camera = ctx.camera();
        let (mut gate, inputs) = GateStage::open(&ctx.ipc, &ctx.config, camera)?;
        stage::run(&ctx.ipc, &camera.id, &mut gate, &inputs)
    })
}
