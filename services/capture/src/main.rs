//! isochron-capture: config → source → node → `frames` publisher → read/publish loop.

use std::process::ExitCode;

use clap::Parser;
use isochron_capture::stage;
use isochron_shared::service::{CameraArgs, run_cameras};
use isochron_shared::topology::StageKind;

/// Reads one camera or video file and publishes its frames on `<prefix>/<camera>/frames`.
#[derive(Parser)]
#[command(version)]
struct Args {
    #[command(flatten)]
    service: CameraArgs,
}

fn main() -> ExitCode {
    let args = Args::parse();
    run_cameras(StageKind::Capture, &args.service, stage::run)
}
