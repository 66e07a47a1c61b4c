//! isochron-link: config → node → exported cameras' `activity` out to DDS, imported
//! cameras' activity from DDS into local iceoryx2 services → the stage runtime.
//! Runs once per box, started by its own unit (`systemd/isochron-link.service`).

use std::process::ExitCode;

use isochron_link::stage::LinkStage;
use isochron_runtime::service::main_site_wide;
use isochron_runtime::stage;
use isochron_runtime::topology::StageKind;

fn main() -> ExitCode {
    main_site_wide(StageKind::Link, |ctx| {
        let (mut link, inputs) = LinkStage::open(&ctx.ipc, &ctx.config)?;
        stage::run(&ctx.ipc, "", &mut link, &inputs)
    })
}
