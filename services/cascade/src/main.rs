//! isochron-cascade: config → store → node → `motion` in, `activity` out → the stage
//! runtime, filtering motion into 1-Hz activity and the long-term store.

use std::process::ExitCode;

use isochron_cascade::stage;
use isochron_runtime::service::main_per_camera;
use isochron_runtime::topology::StageKind;

fn main() -> ExitCode {
    main_per_camera(StageKind::Cascade, stage::run)
}
