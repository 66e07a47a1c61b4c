//! isochron-costmap: config → node → `activity` + `detections` of every camera in,
//! ROS 2 `OccupancyGrid` (+ updates) out, `<prefix>/plan` served → the stage
//! runtime. Runs once per site (`isochron up` starts it without `--camera`).

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use isochron_costmap::stage::CostmapStage;
use isochron_shared::service::{finish, start};
use isochron_shared::stage;
use isochron_shared::topology::StageKind;

/// Publishes block activity on the robots' map as a ROS 2 OccupancyGrid, writes
/// snapshots, and answers planning requests.
#[derive(Parser)]
#[command(version)]
struct Args {
    /// Site configuration file.
    #[arg(long)]
    config: PathBuf,
}

fn main() -> ExitCode {
    let args = Args::parse();
    let result = start(StageKind::Costmap, &args.config).and_then(|ctx| {
        let (mut costmap, inputs) = CostmapStage::open(&ctx.ipc, &ctx.config)?;
        stage::run(&ctx.ipc, "", &mut costmap, &inputs)
    });
    finish(StageKind::Costmap, result)
}
