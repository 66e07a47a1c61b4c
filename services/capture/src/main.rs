//! isochron-capture: config → source → node → `frames` publisher → read/publish loop.

use std::process::ExitCode;

use isochron_capture::stage;
use isochron_runtime::service::main_per_camera;
use isochron_runtime::topology::StageKind;

fn main() -> ExitCode {
    main_per_camera(StageKind::Capture, stage::run)
}
