//! `isochron costmap ...`: the cost map of a site.
//!
//! * `isochron costmap snapshot [--out DIR]`: asks the running isochron-costmap to
//!   write a snapshot of the current cost map (`map_server` PGM + YAML in raw mode,
//!   and a PNG picture) into its snapshot directory (`costmap.snapshot_dir`, by
//!   default `<state_dir>/costmap`), prints the files, and copies them to `DIR`.
//! * `isochron costmap snapshot --at HH:MM [--day mon..sun] --out FILE.png
//!   [--json]`: the cost map the long-term model expects at that time of day (and
//!   weekday, on a weekly store), drawn from the long-term stores by
//!   `Planner::expected_costmap` — the bridge's forecast — with the bridge's
//!   snapshot writer (`isochron_planning::snapshot`): FILE.png, and FILE.pgm +
//!   FILE.yaml beside it. Needs no running service.
//! * `isochron costmap check [--camera ID] [--overlay OUT.png [--frame FILE]]
//!   [--json]`: each camera's floor mapping — the fit's error at each of its own
//!   points in metres and pixels, the leave-one-out error (at a point, of the fit
//!   to the others), the point that stands out, where the frame's corners land on
//!   the floor, and how much of the grid it covers — to set up `floor_points` and
//!   the grid; with `--overlay`, all of it drawn on a frame of the camera
//!   ([`crate::overlay`]). Exits 1 when a camera's floor points define no mapping
//!   or a point stands out.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use isochron_config::clock::{Cycle, MINUTES_PER_DAY, SiteClock, format_t_star, wall_now_ns};
use isochron_config::{CameraConfig, DAY_NAMES as DAYS, LoadedConfig, SourceKind};
use isochron_exit::UsageError;
use isochron_planning::calibration::Calibration;
use isochron_planning::grid::MapGrid;
use isochron_planning::plan_service::PlanClient;
use isochron_planning::planner::Planner;
use isochron_planning::query::{PlanKind, PlanRequest, PlanStatus};
use isochron_planning::raster::Footprint;
use isochron_planning::snapshot::{self, Snapshot};
use isochron_runtime::ipc::Ipc;
use isochron_store::{Store, store_path};
use isochron_wire::geometry::BlockGrid;

use crate::common::{OutFile, Subcommands, load_config, with_code};
use crate::overlay::{self, FloorPolygon, Frame, Scene};

/// Snapshots and checks of the site's cost map.
pub type Args = Subcommands<Command>;

#[derive(clap::Subcommand)]
pub(crate) enum Command {
    /// Write a snapshot of the current cost map (PGM + YAML + PNG).
    Snapshot(SnapshotArgs),
    /// Show each camera's floor mapping, its residuals and grid coverage; draw an overlay.
    Check(CheckArgs),
}

#[derive(clap::Args)]
pub(crate) struct SnapshotArgs {
    /// Site configuration (default: $ISOCHRON_CONFIG or /etc/isochron/isochron.toml).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Without --at: also copy the running bridge's files into this directory.
    /// With --at: the picture to write, FILE.png (FILE.pgm and FILE.yaml, the
    /// `map_server` pair, beside it).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Draw the cost map the long-term model expects at this time of day, HH:MM in
    /// the site's time zone, from the long-term stores (no running service needed).
    #[arg(long, value_name = "HH:MM", value_parser = crate::values::time_of_day)]
    at: Option<u32>,
    /// With --at, for a weekly store (cascade.cycle = "weekly"): the day, mon .. sun
    /// (default today). A daily store has one model for every day: the day is
    /// noted on stderr and that model drawn.
    #[arg(long, requires = "at", value_parser = crate::values::weekday)]
    day: Option<u32>,
    /// With --at: print the grid and its cells as one JSON object.
    #[arg(long, requires = "at")]
    json: bool,
    /// How long to wait for isochron-costmap, seconds.
    #[arg(long, default_value = "10", value_parser = crate::values::positive_seconds)]
    timeout: Duration,
}

#[derive(clap::Args)]
pub(crate) struct CheckArgs {
    /// Site configuration (default: $ISOCHRON_CONFIG or /etc/isochron/isochron.toml).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Only this camera.
    #[arg(long)]
    camera: Option<String>,
    /// Draw the calibration overlay of `--camera` into this PNG (a `.png` file
    /// name; written whole or not at all): block grid, masks, zones, the floor grid
    /// (1 m) and route segments through the homography, and every calibration
    /// point with its residual.
    #[arg(long, requires = "camera", value_name = "OUT.png")]
    overlay: Option<PathBuf>,
    /// The picture for the overlay: a video (its first frame) or an image. Default:
    /// the camera's source, if it is a file.
    #[arg(long, requires = "overlay")]
    frame: Option<PathBuf>,
    /// Print the findings as JSON.
    #[arg(long)]
    json: bool,
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    match args.command {
        Command::Snapshot(a) => snapshot(a),
        Command::Check(a) => check(a),
    }
}

fn snapshot(args: SnapshotArgs) -> anyhow::Result<ExitCode> {
    if let Some(at) = args.at {
        return expected_snapshot(args, at);
    }
    let loaded = load_config(args.config)?;
    let ipc = Ipc::of_site(
        &format!("isochron-snapshot-{}", std::process::id()),
        &loaded.config,
    )?;
    let client = PlanClient::new(&ipc)?;
    let response = client.request(
        PlanRequest::new(PlanKind::Snapshot, &[]),
        args.timeout.max(Duration::from_millis(100)),
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

/// `costmap snapshot --at`: the cost map the long-term model expects.
fn expected_snapshot(args: SnapshotArgs, minute: u32) -> anyhow::Result<ExitCode> {
    let (out, stem) = png_out(args.out.as_deref())?;
    let day = args.day;
    let loaded = load_config(args.config)?;
    let started = Instant::now();
    let (day, note) = cycle_day(&loaded, day)?;
    if let Some(note) = &note {
        eprintln!("isochron: {note}");
    }
    let t_star = day.unwrap_or(0) * MINUTES_PER_DAY + minute;
    let e = expected(&loaded, t_star, day)?;
    let when = match day {
        Some(d) => format!("{} {}", DAYS[d as usize], format_t_star(minute)),
        None => format_t_star(minute),
    };
    let caption = format!(
        "{}: expected cost at {when} ({} days learned)",
        loaded.config.site.name, e.days
    );
    let floor_plan = snapshot::floor_plan_of(&loaded, Some(&e.grid));
    let dir = match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let coverage: Vec<&[u32]> = e
        .footprints
        .iter()
        .flatten()
        .map(|f| f.cell_block.as_slice())
        .collect();
    let camera_ids: Vec<&str> = e
        .footprints
        .iter()
        .zip(&e.cameras)
        .filter(|(f, _)| f.is_some())
        .map(|(_, c)| c.0.as_str())
        .collect();
    let segments: Vec<&[[f64; 2]]> = loaded.config.costmap.segment_polygons();
    let files = snapshot::write(
        &dir,
        &stem,
        &Snapshot {
            grid: &e.grid,
            cells: &e.cells,
            floor_plan: floor_plan.as_ref(),
            coverage: &coverage,
            camera_ids: &camera_ids,
            segments: &segments,
            zones: &snapshot::floor_zones(&loaded.config.cameras),
            caption: &caption,
            stamp: &format!("{when} (t* {t_star}), expected by the long-term model"),
        },
    )
    .with_context(|| format!("--out {}", out.display()))?;
    let render_ms = started.elapsed().as_secs_f64() * 1e3;
    if args.json {
        let cycle = loaded.config.cascade.cycle.name();
        let at = (format_t_star(minute), day.map(|d| DAYS[d as usize]), cycle);
        println!("{}", expected_json(&e, at, note, &files, render_ms));
    } else {
        print_expected(&e, &when, &files, render_ms);
    }
    Ok(ExitCode::SUCCESS)
}

/// `--out FILE.png` of `costmap snapshot --at`, and its stem.
fn png_out(out: Option<&Path>) -> anyhow::Result<(PathBuf, String)> {
    let out = out.ok_or_else(|| UsageError("--at needs --out FILE.png".into()))?;
    let stem = out
        .file_stem()
        .and_then(|s| s.to_str())
        .filter(|_| out.extension().is_some_and(|e| e == "png"))
        .ok_or_else(|| {
            UsageError(format!(
                "--out: expected a .png file name, found '{}'",
                out.display()
            ))
        })?
        .to_string();
    Ok((out.to_path_buf(), stem))
}

/// The day of the week to draw (`None` for a daily cycle: one model for every
/// day), and a note when `--day` means nothing for this site. Without `--day`, a
/// weekly cycle draws today.
fn cycle_day(
    loaded: &LoadedConfig,
    day: Option<u32>,
) -> anyhow::Result<(Option<u32>, Option<String>)> {
    Ok(match (loaded.config.cascade.cycle, day) {
        (Cycle::Daily, None) => (None, None),
        (Cycle::Daily, Some(d)) => (
            None,
            Some(format!(
                "--day {}: this site learns one daily cycle (cascade.cycle = \"daily\"), the same model for every day; drawing it (a map per weekday needs cascade.cycle = \"weekly\" and weeks of data)",
                DAYS[d as usize]
            )),
        ),
        (Cycle::Weekly | Cycle::DayTypes, Some(d)) => (Some(d), None),
        (Cycle::Weekly | Cycle::DayTypes, None) => {
            let clock = SiteClock::new(&loaded.config.site.time_zone, Cycle::Weekly)?;
            (Some(clock.t_star(wall_now_ns()) / MINUTES_PER_DAY), None)
        }
    })
}

/// The cost map the long-term model expects at `t_star`, and what went into it.
struct Expected {
    grid: MapGrid,
    /// Its cells (0..=100, -1 unseen).
    cells: Vec<i8>,
    /// Each camera's footprint on the grid (`None`: not on the floor, or no store).
    footprints: Vec<Option<Footprint>>,
    /// Each camera: id, has a store, has floor points.
    cameras: Vec<(String, bool, bool)>,
    /// Each camera: its model learned anything at `t_star`.
    learned: Vec<bool>,
    /// Days the model has learned.
    days: u32,
    /// The minute of the cycle drawn.
    t_star: u32,
}

/// What the site's long-term stores expect at `t_star` (of `day`, for a
/// weekly model); an error when no camera has a store, or a weekly model
/// learned nothing on `day`.
fn expected(loaded: &LoadedConfig, t_star: u32, day: Option<u32>) -> anyhow::Result<Expected> {
    let grid = MapGrid::from_config(loaded)?.context(
        "no [costmap] grid is configured (map_yaml, or width_cells and height_cells): nothing to draw",
    )?;
    let mut planner = Planner::new(loaded)?;
    if let Some(day) = day {
        planner.check_day_learned(day)?;
    }
    let mut footprints = Vec::new();
    let cells = planner.expected_costmap(&grid, t_star, &mut footprints)?;
    let learned: Vec<bool> = planner
        .long_term_at(t_star)?
        .iter()
        .map(Option::is_some)
        .collect();
    let cameras: Vec<(String, bool, bool)> = planner
        .cameras()
        .map(|(id, store, floor)| (id.to_string(), store, floor))
        .collect();
    if !cameras.iter().any(|c| c.1) {
        return Err(planner.missing_stores().into());
    }
    Ok(Expected {
        grid,
        cells,
        footprints,
        cameras,
        learned,
        days: planner.days(),
        t_star,
    })
}

/// `costmap snapshot --at --json`: the grid, its cells and the files as one
/// object; `at` is the time of day, the day and the cycle.
fn expected_json(
    e: &Expected,
    (at, day, cycle): (String, Option<&str>, &str),
    note: Option<String>,
    files: &snapshot::SnapshotFiles,
    render_ms: f64,
) -> serde_json::Value {
    let (grid, cells) = (&e.grid, &e.cells);
    let rows: Vec<&[i8]> = cells.chunks((grid.width as usize).max(1)).collect();
    serde_json::json!({
        "at": at,
        "day": day,
        "t_star": e.t_star,
        "cycle": cycle,
        "note": note,
        "grid": {
            "width_cells": grid.width,
            "height_cells": grid.height,
            "resolution_m": grid.resolution,
            "origin_m": [grid.origin_x, grid.origin_y],
            "yaw_rad": grid.yaw,
        },
        "cameras": e.cameras.iter().zip(&e.learned).map(|((id, store, floor), learned)| serde_json::json!({
            "id": id, "store": store, "floor_points": floor, "learned_at_t_star": learned,
        })).collect::<Vec<_>>(),
        "cells_seen": cells.iter().filter(|&&c| c >= 0).count(),
        "cells_above_zero": cells.iter().filter(|&&c| c > 0).count(),
        "highest_cost": cells.iter().copied().max().unwrap_or(-1),
        "cells": rows,
        "files": { "png": files.png, "pgm": files.pgm, "yaml": files.yaml },
        "render_ms": (render_ms * 10.0).round() / 10.0,
    })
}

/// `costmap snapshot --at`: what was drawn, camera by camera, and the files.
fn print_expected(e: &Expected, when: &str, files: &snapshot::SnapshotFiles, render_ms: f64) {
    let cells = &e.cells;
    let seen = cells.iter().filter(|&&c| c >= 0).count();
    let busy = cells.iter().filter(|&&c| c > 0).count();
    let highest = cells.iter().copied().max().unwrap_or(-1);
    println!(
        "snapshot: expected cost at {when}: {seen} of {} cells seen, {busy} above 0, highest {highest} (rows from the origin, -1 = no camera with a learned model sees)",
        cells.len()
    );
    for ((id, store, floor), learned) in e.cameras.iter().zip(&e.learned) {
        let state = match (store, floor, learned) {
            (false, _, _) => "no long-term store",
            (_, false, _) => "no floor_points, not on the map",
            (_, _, false) => "nothing learned at this time",
            _ => "drawn",
        };
        println!("  {id}: {state}");
    }
    println!(
        "wrote {}, {}, {} in {render_ms:.0} ms",
        files.png.display(),
        files.pgm.display(),
        files.yaml.display()
    );
}

fn check(args: CheckArgs) -> anyhow::Result<ExitCode> {
    let loaded = load_config(args.config)?;
    let config = &loaded.config;
    let grid = MapGrid::from_config(&loaded)?;
    let cameras: Vec<&CameraConfig> = match &args.camera {
        Some(id) => vec![loaded.camera(id)?],
        None => config.cameras.iter().collect(),
    };
    // The overlay's paths first: a bad one fails before anything is printed.
    let overlay = match (&args.overlay, cameras.first()) {
        (Some(out), Some(cam)) => Some(overlay_input(&loaded, cam, out, args.frame.as_deref())?),
        _ => None,
    };
    let frame = overlay.as_ref().map(|(_, frame)| frame);
    let reports: Vec<CameraCheck> = cameras
        .iter()
        .map(|cam| {
            let index = config
                .cameras
                .iter()
                .position(|c| c.id == cam.id)
                .unwrap_or_default();
            check_camera(&loaded, grid.as_ref(), index, cam, frame)
        })
        .collect();
    if let (Some((out, frame)), Some(cam), Some(report)) =
        (overlay, cameras.first(), reports.first())
    {
        let segments: Vec<FloorPolygon> = config
            .costmap
            .segments
            .iter()
            .filter_map(|s| {
                Some(FloorPolygon {
                    name: s.name.clone(),
                    polygon_m: s.polygon_m.clone()?,
                })
            })
            .collect();
        let zones = cam.zones_or_default(frame.width, frame.height);
        let scene = Scene {
            camera: &cam.id,
            block_px: config.motion.block_px,
            masks: &cam.mask,
            zones: &zones,
            calibration: report.calibration.as_ref(),
            floor_extent: report
                .calibration
                .as_ref()
                .map(|c| overlay::floor_extent(grid.as_ref(), c)),
            segments: &segments,
        };
        overlay::draw(out.path(), &frame, &scene)?;
        out.commit()?;
    }
    let failed = reports.iter().any(|r| {
        r.error.is_some()
            || r.calibration
                .iter()
                .flat_map(|c| &c.points)
                .any(|p| p.flagged)
    });
    if args.json {
        let json = serde_json::json!({
            "grid": grid.as_ref().map(|g| serde_json::json!({
                "width_cells": g.width,
                "height_cells": g.height,
                "resolution_m": g.resolution,
                "origin_m": [g.origin_x, g.origin_y],
                "yaw_rad": g.yaw,
            })),
            "cameras": reports,
            "overlay": args.overlay,
        });
        println!("{}", serde_json::to_string_pretty(&json)?);
    } else {
        print_text(grid.as_ref(), &reports);
        if let Some(out) = &args.overlay {
            println!("overlay: {} written", out.display());
        }
    }
    Ok(if failed {
        ExitCode::from(1)
    } else {
        ExitCode::SUCCESS
    })
}

/// The overlay's output (a `.png`, written beside it and renamed into place when
/// drawn) and the frame to draw on: `--frame`, else the camera's file source.
fn overlay_input(
    loaded: &LoadedConfig,
    cam: &CameraConfig,
    out: &Path,
    frame: Option<&Path>,
) -> anyhow::Result<(OutFile, Frame)> {
    if !out
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("png"))
    {
        bail!(UsageError(format!(
            "--overlay {}: expected a .png file name (the overlay is a PNG)",
            out.display()
        )));
    }
    let file = OutFile::create("--overlay", out)?;
    let (flag, path) = match frame {
        Some(p) => ("--frame", p.to_path_buf()),
        None => match cam.source_kind(&loaded.base_dir()) {
            SourceKind::File(p) => ("camera source", p),
            _ => bail!(UsageError(format!(
                "camera {}'s source is not a file: give --frame VIDEO_OR_IMAGE",
                cam.id
            ))),
        },
    };
    crate::common::input_file(flag, &path, "a video or an image")?;
    let size = cam.width.zip(cam.height);
    let frame = Frame::read(&path, size).map_err(|e| with_code(isochron_exit::DATA, e))?;
    Ok((file, frame))
}

/// What `costmap check` found about one camera.
#[derive(serde::Serialize)]
struct CameraCheck {
    id: String,
    /// Why the floor points do not define a mapping (`camera[i].floor_points: ...`).
    error: Option<String>,
    #[serde(flatten)]
    calibration: Option<Calibration>,
    /// Analysis frame size, if known.
    frame_px: Option<[u32; 2]>,
    /// Where the frame's corners land on the floor (`None`: beyond the horizon).
    corners: Vec<Corner>,
    /// Grid cells the camera covers, and their share of the grid.
    covered_cells: Option<usize>,
    covered_percent: Option<f64>,
}

#[derive(serde::Serialize)]
struct Corner {
    name: &'static str,
    image_px: [f64; 2],
    floor_m: Option<[f64; 2]>,
}

fn check_camera(
    loaded: &LoadedConfig,
    grid: Option<&MapGrid>,
    i: usize,
    cam: &CameraConfig,
    frame: Option<&Frame>,
) -> CameraCheck {
    let mut report = CameraCheck {
        id: cam.id.clone(),
        error: None,
        calibration: None,
        frame_px: None,
        corners: Vec::new(),
        covered_cells: None,
        covered_percent: None,
    };
    if cam.floor_points.is_empty() {
        return report;
    }
    let image: Vec<[f64; 2]> = cam.floor_points.iter().map(|p| p.image_px).collect();
    let floor: Vec<[f64; 2]> = cam.floor_points.iter().map(|p| p.floor_m).collect();
    let cal = match Calibration::analyse(&image, &floor) {
        Ok(c) => c,
        Err(e) => {
            report.error = Some(format!("camera[{i}].floor_points: {e}"));
            return report;
        }
    };
    let h = cal.homography;
    report.calibration = Some(cal);
    // The frame size: config, else the frame drawn on, else the long-term store's.
    let config = &loaded.config;
    let size = match (cam.width, cam.height, frame) {
        (Some(w), Some(h), _) => Some((w, h, config.motion.block_px)),
        (_, _, Some(f)) => Some((f.width, f.height, config.motion.block_px)),
        _ => Store::open_read_only(&store_path(&loaded.state_dir(), &cam.id), &cam.id)
            .ok()
            .map(|s| {
                let g = s.meta().grid;
                (g.frame_width, g.frame_height, g.block_px)
            }),
    };
    let Some((w, hgt, block_px)) = size else {
        return report;
    };
    report.frame_px = Some([w, hgt]);
    for (name, p) in [
        ("top left", [0.0, 0.0]),
        ("top right", [w as f64, 0.0]),
        ("bottom right", [w as f64, hgt as f64]),
        ("bottom left", [0.0, hgt as f64]),
    ] {
        report.corners.push(Corner {
            name,
            image_px: p,
            floor_m: h.apply(p),
        });
    }
    if let Some(g) = grid {
        let blocks = BlockGrid::new(w, hgt, block_px);
        let fp = Footprint::build(g, &h, blocks, &cam.mask);
        report.covered_cells = Some(fp.seen);
        report.covered_percent = Some(100.0 * fp.seen as f64 / g.len().max(1) as f64);
    }
    report
}

fn print_text(grid: Option<&MapGrid>, reports: &[CameraCheck]) {
    match grid {
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
    for r in reports {
        if let Some(e) = &r.error {
            println!("{}: {e}", r.id);
            continue;
        }
        let Some(c) = &r.calibration else {
            println!("{}: no floor_points, not on the cost map", r.id);
            continue;
        };
        println!(
            "{}: {} floor points, RMS error {:.3} m at them ({:.2} px in the image)",
            r.id,
            c.points.len(),
            c.rms_m,
            c.rms_px
        );
        match (c.loo_rms_m, c.loo_rms_px) {
            (Some(m), Some(px)) => println!(
                "  leave-one-out: RMS {m:.3} m ({px:.2} px) at a point the fit did not see"
            ),
            _ => println!("  leave-one-out: needs 5 or more points"),
        }
        println!(
            "  point  image px          floor m               residual m   px   leave-one-out m   px"
        );
        for p in &c.points {
            let loo =
                |v: Option<f64>, prec: usize| v.map_or("-".to_string(), |v| format!("{v:.prec$}"));
            println!(
                "  #{:<4} ({:>6.1}, {:>6.1})  ({:>8.3}, {:>8.3})  {:>10.3} {:>6.2} {:>12} {:>6}{}",
                p.index,
                p.image_px[0],
                p.image_px[1],
                p.floor_m[0],
                p.floor_m[1],
                p.residual_m,
                p.residual_px,
                loo(p.loo_m, 3),
                loo(p.loo_px, 2),
                if p.flagged {
                    "  <- far above the others: check this tape mark"
                } else {
                    ""
                }
            );
        }
        let Some([w, h]) = r.frame_px else {
            println!(
                "  frame size unknown (set camera width/height, or let the cascade create its store) — coverage not computed"
            );
            continue;
        };
        for corner in &r.corners {
            let p = corner.image_px;
            match corner.floor_m {
                Some(f) => println!(
                    "  {} corner ({}, {}) px → ({:.2}, {:.2}) m",
                    corner.name, p[0], p[1], f[0], f[1]
                ),
                None => println!(
                    "  {} corner ({}, {}) px → beyond the horizon",
                    corner.name, p[0], p[1]
                ),
            }
        }
        if let (Some(n), Some(pct), Some(g)) = (r.covered_cells, r.covered_percent, grid) {
            println!(
                "  covers {n} of {} grid cells ({pct:.1} %) of the {w}x{h} px view",
                g.len()
            );
        }
    }
}
