//! isochron-gate: config → node → `frames` + `activity` in, `events` + `detections`
//! out → the stage runtime. Frames go into the ring; activity drives the event
//! trackers; the detector thread runs on the gated frames.

use std::process::ExitCode;

use isochron_gate::stage;
use isochron_runtime::service::main_per_camera;
use isochron_runtime::topology::StageKind;

fn main() -> ExitCode {
    main_per_camera(StageKind::Gate, stage::run)
}
