//! isochron-motion: config → node → `frames` in, `motion` out → the stage runtime,
//! computing per-block motion features of every frame pair.

use std::process::ExitCode;

use isochron_motion::stage;
use isochron_runtime::service::main_per_camera;
use isochron_runtime::topology::StageKind;

fn main() -> ExitCode {
    main_per_camera(StageKind::Motion, stage::run)
}
