//! `isochron store ...`: read a camera's long-term store, also while the cascade writes
//! it (SQLite WAL: readers never block the writer).
//!
//! * `isochron store export --store PATH --camera ID [--block X,Y] [--out FILE]`: the
//!   isochronal profile as CSV `minute_of_day,mean,sigma,count` (`minute_of_week` for
//!   a weekly store), one row per minute bin. Over all blocks: `mean` is the mean of
//!   the block means (the camera view's mean `M_L1` in that minute; a block mean
//!   below zero counts as 0, as everywhere profiles are taken), `sigma` the root
//!   mean square of the block sigmas (the typical day-to-day spread of one block);
//!   with `--block X,Y`, that block's own mean and sigma. `count` is the number of
//!   days (weeks) that taught the bin; bins that never learned anything have empty
//!   `mean` and `sigma` and count 0.
//! * `isochron store info --store PATH --camera ID [--json]`: what the store is
//!   about, how far it got, and a full check of its checksums.
//! * `isochron store migrate --store PATH --camera ID [--config FILE] [--cycle C]`:
//!   converts a store of an older format, or of another cycle, to this format and
//!   the site's cycle, keeping what it learned (the old file stays beside it).
//! * `isochron store backtest --counts FILE.csv ...`: replays count series through
//!   the long-term model and scores its forecasts against baselines
//!   ([`crate::backtest`]).
//!
//! `--store` is the store file, or a directory (a `state_dir`, or what `isochron
//! synth --out DIR` wrote): then `DIR/<camera>.isochron.sqlite`.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, bail};
use isochron_config::clock::{Cycle, NS_PER_S, format_rfc3339, timestamp};
use isochron_exit::{Fatal, UsageError};
use isochron_planning::profile::{ProfilePoint, daily_profile};
use isochron_store::{FILE_SUFFIX, Model, Store, StoreError};
use serde_json::json;

use crate::common::{OutFile, Subcommands};

/// Read a camera's long-term store.
pub type Args = Subcommands<Command>;

#[derive(clap::Subcommand)]
pub(crate) enum Command {
    /// Write the isochronal profile as CSV `minute_of_day,mean,sigma,count`
    /// (`minute_of_week,...` for a store of the week: weekly or day types).
    Export(ExportArgs),
    /// Show what a store holds and check all of it.
    Info(InfoArgs),
    /// Convert a store of an older format or another cycle, keeping what it learned.
    Migrate(MigrateArgs),
    /// Replay count series through the long-term model and score its forecasts.
    Backtest(crate::backtest::BacktestArgs),
}

#[derive(clap::Args)]
pub(crate) struct MigrateArgs {
    #[command(flatten)]
    store: StoreArgs,
    /// The site's config: the cycle, rest days and holidays to convert to (default
    /// the usual config file).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Another cycle than the config's: day_types, daily or weekly.
    #[arg(long, value_parser = crate::values::cycle)]
    cycle: Option<Cycle>,
}

#[derive(clap::Args)]
pub(crate) struct InfoArgs {
    #[command(flatten)]
    store: StoreArgs,
    /// One JSON object instead of lines for people.
    #[arg(long)]
    json: bool,
}

/// Which store.
#[derive(clap::Args)]
pub struct StoreArgs {
    /// The store file (`<state_dir>/<camera>.isochron.sqlite`), or the directory
    /// that holds it.
    #[arg(long)]
    pub store: PathBuf,
    /// The camera it belongs to.
    #[arg(long)]
    pub camera: String,
}

#[derive(clap::Args)]
pub(crate) struct ExportArgs {
    #[command(flatten)]
    store: StoreArgs,
    /// One block, `X,Y` (column, row from the top left), instead of all blocks.
    #[arg(long, value_name = "X,Y", value_parser = Selection::arg)]
    block: Option<Selection>,
    /// Output file; default standard output.
    #[arg(long)]
    out: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    match args.command {
        Command::Export(a) => export(a),
        Command::Info(a) => info(a),
        Command::Migrate(a) => migrate(a),
        Command::Backtest(a) => crate::backtest::run(a),
    }
}

fn migrate(args: MigrateArgs) -> anyhow::Result<ExitCode> {
    let loaded = crate::common::load_config(args.config)?;
    let mut cascade = loaded.config.cascade;
    if let Some(cycle) = args.cycle {
        cascade.cycle = cycle;
    }
    let path = resolve(&args.store.store, &args.store.camera)?;
    let done = isochron_store::migrate::migrate(
        &path,
        &args.store.camera,
        &isochron_store::Rules::of(&cascade),
    )?;
    match &done.backup {
        None => println!(
            "store: {} is already format {} with the {} cycle: nothing to do",
            path.display(),
            isochron_store::FORMAT_VERSION,
            done.to_cycle.name()
        ),
        Some(backup) => println!(
            "store: {} converted from format {} ({}) to format {} ({}), {} rows; the old file is {}",
            path.display(),
            done.from_version,
            done.from_cycle.name(),
            isochron_store::FORMAT_VERSION,
            done.to_cycle.name(),
            done.rows,
            backup.display()
        ),
    }
    Ok(ExitCode::SUCCESS)
}

/// Which blocks a profile is taken over. A later `--segment NAME` (a floor polygon
/// mapped to blocks) becomes one more variant.
#[derive(Debug, Clone, PartialEq)]
pub enum Selection {
    /// Every block of the view.
    All,
    /// One block, (column, row).
    Block(u32, u32),
}

impl Selection {
    /// Parses `--block X,Y` (clap's value parser of the flag).
    pub fn arg(text: &str) -> Result<Selection, String> {
        text.split_once(',')
            .and_then(|(x, y)| Some((x.trim().parse().ok()?, y.trim().parse().ok()?)))
            .map(|(x, y)| Selection::Block(x, y))
            .ok_or_else(|| "expected X,Y (column,row from the top left, from 0)".into())
    }

    /// The row-major block indices of the selection on a `grid_w` × `grid_h` grid.
    pub fn blocks(&self, grid_w: u32, grid_h: u32) -> anyhow::Result<Vec<u32>> {
        match *self {
            Selection::All => Ok((0..grid_w * grid_h).collect()),
            Selection::Block(x, y) => {
                if x >= grid_w || y >= grid_h {
                    bail!(UsageError(format!(
                        "--block {x},{y} is outside the store's {grid_w}x{grid_h} grid (columns 0..{grid_w}, rows 0..{grid_h})"
                    )));
                }
                Ok(vec![y * grid_w + x])
            }
        }
    }

    /// For people: "all 1200 blocks" or "block 3,4".
    pub fn describe(&self, grid_w: u32, grid_h: u32) -> String {
        match self {
            Selection::All => format!("all {} blocks", grid_w * grid_h),
            Selection::Block(x, y) => format!("block {x},{y}"),
        }
    }
}

/// The isochronal profile of `selection`: one point per bin of the cycle.
pub fn profile(model: &Model, selection: &Selection) -> anyhow::Result<Vec<ProfilePoint>> {
    let blocks = selection.blocks(model.meta.grid.grid_w(), model.meta.grid.grid_h())?;
    Ok(daily_profile(
        &[(model, &blocks)],
        model.meta.bins() as usize,
    ))
}

/// Opens the store `--store PATH` names read-only; `path` may be the directory
/// holding it (see [`resolve`]). The store is the command's input: one that is
/// not there ends it with 66 (`NO_INPUT`), the store of another camera than
/// `--camera` with 64 (`USAGE`: the two flags disagree) — where the services, to
/// which the config names the store, say 69 and 78.
pub fn open(path: &Path, camera: &str) -> anyhow::Result<Store> {
    let path = resolve(path, camera)?;
    Store::open_read_only(&path, camera).map_err(|e| match &e {
        StoreError::NotFound { .. } => crate::common::with_code(isochron_exit::NO_INPUT, e.into()),
        StoreError::Camera { found, .. } => {
            let message = format!(
                "--store {} holds the long-term model of camera '{found}', not of --camera {camera}",
                path.display()
            );
            Fatal::with_source(isochron_exit::USAGE, message, e).into()
        }
        _ => e.into(),
    })
}

/// The store file `path` names: `path` itself, or for a directory
/// `path/<camera>.isochron.sqlite`. Either must exist, else 66 (`NO_INPUT`;
/// for a directory, the error lists the stores it has).
pub fn resolve(path: &Path, camera: &str) -> anyhow::Result<PathBuf> {
    let expected = format!("{camera}{FILE_SUFFIX}");
    if !path.is_dir() {
        if !path.exists() {
            bail!(Fatal::new(
                isochron_exit::NO_INPUT,
                format!(
                    "--store {}: no such file or directory; expected a store file ({expected}) or the directory that holds it",
                    path.display()
                ),
            ));
        }
        return Ok(path.to_path_buf());
    }
    let file = path.join(&expected);
    if file.is_file() {
        return Ok(file);
    }
    let mut found: Vec<String> = std::fs::read_dir(path)
        .map(|entries| {
            entries
                .filter_map(Result::ok)
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|name| name.ends_with(FILE_SUFFIX))
                .collect()
        })
        .unwrap_or_default();
    found.sort();
    bail!(Fatal::new(
        isochron_exit::NO_INPUT,
        format!(
            "--store {} is a directory without a store of camera '{camera}': expected {} ({})",
            path.display(),
            file.display(),
            if found.is_empty() {
                "it has no *.isochron.sqlite".to_string()
            } else {
                format!("it has {}", found.join(", "))
            }
        )
    ))
}

fn export(args: ExportArgs) -> anyhow::Result<ExitCode> {
    let store = open(&args.store.store, &args.store.camera)?;
    let model = store.read_model()?;
    let selection = args.block.clone().unwrap_or(Selection::All);
    let points = profile(&model, &selection)?;
    let mut text = String::with_capacity(points.len() * 32);
    text += match model.meta.cycle {
        Cycle::Daily => "minute_of_day,mean,sigma,count\n",
        Cycle::Weekly | Cycle::DayTypes => "minute_of_week,mean,sigma,count\n",
    };
    for p in &points {
        match (p.mean, p.sigma) {
            (Some(m), Some(s)) => text += &format!("{},{m},{s},{}\n", p.t_star, p.count),
            _ => text += &format!("{},,,0\n", p.t_star),
        }
    }
    match &args.out {
        Some(path) => {
            let file = OutFile::create("--out", path)?;
            std::fs::write(file.path(), text)
                .with_context(|| format!("writing {}", path.display()))?;
            file.commit()?;
        }
        None => {
            let mut out = std::io::stdout().lock();
            // A closed pipe (`| head`) is not an error worth reporting.
            let _ = out.write_all(text.as_bytes()).and_then(|_| out.flush());
        }
    }
    Ok(ExitCode::SUCCESS)
}

fn info(args: InfoArgs) -> anyhow::Result<ExitCode> {
    let store = open(&args.store.store, &args.store.camera)?;
    let meta = store.meta().clone();
    let report = store.verify()?;
    let model = store.read_model()?;
    let baseline = store.read_baseline()?;
    let (min_days, max_days) = model
        .learned()
        .map(|b| b.count)
        .fold((u32::MAX, 0), |(lo, hi), c| (lo.min(c), hi.max(c)));
    let p = report.progress;
    if args.json {
        let o = json!({
            "store": store.path(),
            "camera": meta.camera,
            "blocks": meta.grid(),
            "block_px": meta.grid.block_px,
            "frame_width": meta.grid.frame_width,
            "frame_height": meta.grid.frame_height,
            "cycle": format!("{:?}", meta.cycle).to_lowercase(),
            "bins": meta.bins(),
            "bins_learned": report.bins,
            "days_per_bin": (report.bins > 0).then(|| json!({"min": min_days, "max": max_days})),
            "created": format_rfc3339(meta.created_ns),
            "last_minute": p.last_minute.map(|m| format_rfc3339(m * 60_000_000_000)),
            "minutes_learned": p.committed,
            "minutes_skipped": p.skipped,
            "baseline": baseline.map(|b| json!({
                "capture": format_rfc3339(b.capture_ns),
                "frames": b.frames,
                "frame_rate": b.frame_rate,
            })),
            "check": "ok",
        });
        println!("{o}");
        return Ok(ExitCode::SUCCESS);
    }
    println!("store       {}", store.path().display());
    println!("camera      {}", meta.camera);
    println!(
        "grid        {} blocks of {} px ({}x{} frame)",
        meta.grid(),
        meta.grid.block_px,
        meta.grid.frame_width,
        meta.grid.frame_height
    );
    println!(
        "cycle       {:?}, {} bins, {} learned",
        meta.cycle,
        meta.bins(),
        report.bins
    );
    if report.bins > 0 {
        println!("days/bin    {min_days}..{max_days}");
    }
    println!("created     {}", format_rfc3339(meta.created_ns));
    match p.last_minute {
        Some(m) => println!(
            "progress    last minute {} ({}), {} minutes learned, {} skipped",
            format_rfc3339(m * 60_000_000_000),
            utc_minute_label(m),
            p.committed,
            p.skipped
        ),
        None => println!("progress    nothing yet"),
    }
    if let Some(b) = baseline {
        println!(
            "baseline    F_L1 at {} after {} frames, r = {:.2}/s",
            format_rfc3339(b.capture_ns),
            b.frames,
            b.frame_rate
        );
    }
    println!("check       ok (SQLite quick_check and every checksum)");
    Ok(ExitCode::SUCCESS)
}

/// The weekday and time, UTC, of the minute `minute` since the Unix epoch (the
/// store's `last_minute`): `Wed 07:00 UTC`. The store keeps no time zone; the
/// bin it taught is this minute in the site's.
fn utc_minute_label(minute: i64) -> String {
    timestamp(minute.saturating_mul(60 * NS_PER_S))
        .to_zoned(jiff::tz::TimeZone::UTC)
        .strftime("%a %H:%M UTC")
        .to_string()
}

#[cfg(test)]
mod tests {
    use super::*;
    use isochron_store::{Bin, StoreMeta};
    use isochron_wire::geometry::BlockGrid;

    fn model() -> Model {
        let meta = StoreMeta::new("c", BlockGrid::new(32, 32, 16), Cycle::Daily, 0);
        let bin = Bin {
            t_star: 5,
            count: 3,
            last_minute: 0,
            mean: vec![1.0, 2.0, 3.0, 6.0],
            var: vec![1.0, 1.0, 4.0, 4.0],
        };
        Model::with_bins(meta, [bin])
    }

    #[test]
    fn profiles_aggregate_blocks_or_take_one() {
        let m = model();
        let all = profile(&m, &Selection::All).unwrap();
        assert_eq!(all.len(), 1440);
        assert_eq!(all[5].mean, Some(3.0));
        assert_eq!(all[5].sigma, Some(2.5f64.sqrt()));
        assert_eq!(all[5].count, 3);
        assert_eq!(all[4].mean, None);
        let one = profile(&m, &Selection::arg("1,1").unwrap()).unwrap();
        assert_eq!((one[5].mean, one[5].sigma), (Some(6.0), Some(2.0)));
        let err = profile(&m, &Selection::Block(2, 0)).unwrap_err();
        assert!(
            err.to_string().contains("outside the store's 2x2 grid"),
            "{err}"
        );
        assert!(Selection::arg("3").is_err());
        assert!(Selection::arg("a,b").is_err());
    }

    #[test]
    fn the_last_minute_is_labelled_with_its_own_weekday() {
        // 2026-01-07 is a Wednesday (the Unix epoch was a Thursday).
        let ns = isochron_config::clock::parse_rfc3339("2026-01-07T07:00:00Z").unwrap();
        assert_eq!(utc_minute_label(ns / 60 / NS_PER_S), "Wed 07:00 UTC");
        assert_eq!(utc_minute_label(0), "Thu 00:00 UTC");
    }

    #[test]
    fn a_directory_means_the_camera_s_store_in_it() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("cam01.isochron.sqlite");
        std::fs::write(&file, b"").unwrap();
        assert_eq!(resolve(dir.path(), "cam01").unwrap(), file);
        assert_eq!(resolve(&file, "cam01").unwrap(), file);
        let err = resolve(dir.path(), "cam02").unwrap_err().to_string();
        assert!(
            err.contains("cam02.isochron.sqlite") && err.contains("it has cam01.isochron.sqlite"),
            "{err}"
        );
    }
}
