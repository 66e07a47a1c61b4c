//! isochron-exporter: config → node → every stage's status in, `/metrics` over
//! HTTP out → the stage runtime. Runs once per site.

use std::process::ExitCode;

use isochron_exporter::stage;
use isochron_runtime::service::main_site_wide;
use isochron_runtime::topology::StageKind;

fn main() -> ExitCode {
    main_site_wide(StageKind::Exporter, stage::run)
}
