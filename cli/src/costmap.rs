//! `isochron costmap ...`: the cost map of a site.
//!
//! * `isochron costmap snapshot [--out DIR]`: asks the running isochron-costmap to
//!   write a snapshot of the current cost map (`map_server` PGM + YAML in raw mode,
//!   and a PNG picture) into its snapshot directory (`costmap.snapshot_dir`, by
//!   default `<state_dir>/costmap`), prints the files, and copies them to `DIR`.
//! * `isochron costmap check`: each camera's floor mapping — the fit's error at
//!   its own points, where the frame's corners land on the floor, and how much of
//!   the grid it covers — to set up `floor_points` and the grid.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Context, bail};
use isochron_planning::grid::MapGrid;
use isochron_planning::homography::Homography;
use isochron_planning::plan_service::PlanClient;
use isochron_planning::query::{PlanKind, PlanRequest, PlanStatus};
use isochron_planning::raster::Footprint;
use isochron_shared::geometry::BlockGrid;
use isochron_shared::ipc::Ipc;
use isochron_shared::store::{Store, store_path};

use crate::common::{Subcommands, load_config};

/// Snapshots and checks of the site's cost map.
pub type Args = Subcommands<Command>;

#[derive(clap::Subcommand)]
pub(crate) enum Command {
    /// Write a snapshot of the current cost map (PGM + YAML + PNG).
    Snapshot(SnapshotArgs),
    /// Show each camera's floor mapping and grid coverage.
    Check(CheckArgs),
}

#[derive(clap::Args)]
pub(crate) struct SnapshotArgs {
    /// Site configuration (default: $ISOCHRON_CONFIG or /etc/isochron/isochron.toml).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Also copy the files here.
    #[arg(long)]
    out: Option<PathBuf>,
    /// How long to wait for isochron-costmap, seconds.
    #[arg(long, default_value_t = 10.0)]
    timeout: f64,
}

#[derive(clap::Args)]
pub(crate) struct CheckArgs {
    /// Site configuration (default: $ISOCHRON_CONFIG or /etc/isochron/isochron.toml).
    #[arg(long)]
    config: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    match args.command {
        Command::Snapshot(a) => snapshot(a),
        Command::Check(a) => check(a),
    }
}

fn snapshot(args: SnapshotArgs) -> anyhow::Result<ExitCode> {
    let loaded = load_config(args.config)?;
    let ipc = Ipc::of_site(
        &format!("isochron-snapshot-{}", std::process::id()),
        &loaded.config,
    )?;
    let client = PlanClient::new(&ipc)?;
    let response = client.request(
        PlanRequest::new(PlanKind::Snapshot, &[]),
        Duration::from_secs_f64(args.timeout.max(0.1)),
    )?;
    if response.validate()? != PlanStatus::Ok {
        bail!("isochron-costmap wrote no snapshot: {}", response.message());
    }
    let yaml = PathBuf::from(response.message());
    let stem = yaml
        .file_stem()
        .and_then(|s| s.to_str())
        .context("isochron-costmap answered without a file name")?
        .to_string();
    let dir = yaml.parent().map(Path::to_path_buf).unwrap_or_default();
    let files: Vec<PathBuf> = ["yaml", "pgm", "png"]
        .iter()
        .map(|e| dir.join(format!("{stem}.{e}")))
        .collect();
    for f in &files {
        println!("{}", f.display());
    }
    if let Some(out) = args.out {
        std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
        for f in &files {
            let to = out.join(f.file_name().expect("a file name"));
            std::fs::copy(f, &to).with_context(|| {
                format!("copying {} (isochron-costmap runs as another user? read it from its snapshot_dir)", f.display())
            })?;
            println!("copied to {}", to.display());
        }
    }
    Ok(ExitCode::SUCCESS)
}

fn check(args: CheckArgs) -> anyhow::Result<ExitCode> {
    let loaded = load_config(args.config)?;
    let config = &loaded.config;
    let grid = MapGrid::from_config(&loaded)?;
    match &grid {
        Some(g) => println!(
            "grid: {}x{} cells of {} m, origin ({}, {}) yaw {} rad, covering x {:.2}..{:.2} m, y {:.2}..{:.2} m (yaw 0)",
            g.width,
            g.height,
            g.resolution,
            g.origin_x,
            g.origin_y,
            g.yaw,
            g.origin_x,
            g.origin_x + g.width as f64 * g.resolution,
            g.origin_y,
            g.origin_y + g.height as f64 * g.resolution
        ),
        None => println!("grid: none configured (planning only, nothing published to ROS 2)"),
    }
    let mut failed = false;
    for (i, cam) in config.cameras.iter().enumerate() {
        let (h, rms) = match Homography::of_camera(cam) {
            Ok(Some(fit)) => fit,
            Ok(None) => {
                println!("{}: no floor_points, not on the cost map", cam.id);
                continue;
            }
            Err(e) => {
                println!("{}: camera[{i}].floor_points: {e}", cam.id);
                failed = true;
                continue;
            }
        };
        println!(
            "{}: {} floor points, RMS error {:.3} m at them",
            cam.id,
            cam.floor_points.len(),
            rms
        );
        // The frame size: config, else the long-term store's.
        let size = match (cam.width, cam.height) {
            (Some(w), Some(h)) => Some((w, h, config.motion.block_px)),
            _ => Store::open_read_only(&store_path(&loaded.state_dir(), &cam.id), &cam.id)
                .ok()
                .map(|s| {
                    let g = s.meta().grid;
                    (g.frame_width, g.frame_height, g.block_px)
                }),
        };
        let Some((w, hgt, block_px)) = size else {
            println!(
                "  frame size unknown (set camera width/height, or let the cascade create its store) — coverage not computed"
            );
            continue;
        };
        for (name, p) in [
            ("top left", [0.0, 0.0]),
            ("top right", [w as f64, 0.0]),
            ("bottom right", [w as f64, hgt as f64]),
            ("bottom left", [0.0, hgt as f64]),
        ] {
            match h.apply(p) {
                Some(f) => println!(
                    "  {name} corner ({}, {}) px → ({:.2}, {:.2}) m",
                    p[0], p[1], f[0], f[1]
                ),
                None => println!(
                    "  {name} corner ({}, {}) px → beyond the horizon",
                    p[0], p[1]
                ),
            }
        }
        if let Some(g) = &grid {
            let blocks = BlockGrid::new(w, hgt, block_px);
            let fp = Footprint::build(g, &h, blocks, &cam.mask);
            println!(
                "  covers {} of {} grid cells ({:.1} %)",
                fp.seen,
                g.len(),
                100.0 * fp.seen as f64 / g.len().max(1) as f64
            );
        }
    }
    Ok(if failed {
        ExitCode::from(1)
    } else {
        ExitCode::SUCCESS
    })
}
