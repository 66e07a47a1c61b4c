//! isochron-costmap: config → node → `activity` + `detections` of every camera in,
//! ROS 2 `OccupancyGrid` (+ updates) out, `<prefix>/plan` served → the stage
//! runtime. Runs once per site (`isochron up` starts it without `--camera`).

use std::process::ExitCode;

use isochron_costmap::stage::CostmapStage;
use isochron_runtime::service::main_site_wide;
use isochron_runtime::stage;
use isochron_runtime::topology::StageKind;

fn main() -> ExitCode {
    main_site_wide(StageKind::Costmap, |ctx| {
        let (mut costmap, inputs) = CostmapStage::open(&ctx.ipc, &ctx.config)?;
        stage::run(&ctx.ipc, "", &mut costmap, &inputs)
    })
}
