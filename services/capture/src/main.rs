//! isochron-capture: config → node → source → the capture stage (source → `frames`)
//! on the runtime.

use std::process::ExitCode;

use isochron_capture::camera;
use isochron_runtime::service::main_per_camera;
use isochron_runtime::topology::StageKind;

fn main() -> ExitCode {
    main_per_camera(StageKind::Capture, camera::run)
}
