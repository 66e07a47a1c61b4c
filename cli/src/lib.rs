//! `isochron`: the command-line tool people use to run and watch a site.
//!
//! The binary's `main` calls [`main`]; [`command`] is its clap definition, from
//! which `cargo xtask docs` makes the man pages and shell completions.

mod backtest;
mod common;
mod costmap;
mod daily;
pub mod docs;
mod doctor;
mod font;
mod heatmap;
mod keystore;
mod launch;
mod overlay;
mod plan;
mod plot;
mod record;
mod replay;
mod status;
mod store;
mod synth;
mod tap;
mod up;
mod values;
mod view;

use std::process::ExitCode;

use clap::{CommandFactory, Parser, Subcommand};
use isochron_exit as exit;

/// Learn where and when people are active from fixed cameras.
#[derive(Parser)]
#[command(name = "isochron", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Start the configured services as separate processes and keep them running.
    Up(up::Args),
    /// Attach to a stream and print one line per sample.
    Tap(tap::Args),
    /// Show every service of the site: state, rates, drops, latency.
    Status(status::Args),
    /// Check config, sources, state, shared memory and services; say what to fix.
    Doctor(doctor::Args),
    /// Run the whole group on a video file and write what every stage produced.
    Replay(replay::Args),
    /// Simulate days of people through a real isochron-cascade; leaves its store.
    Synth(synth::Args),
    /// Read a camera's long-term store (export CSV, info), also while it is written.
    Store(store::Args),
    /// Plot a camera's long-term activity over the day (PNG or SVG).
    Plot(plot::Args),
    /// Plan routes and departure times around people (Cost1 off-line, Cost2 now).
    Plan(plan::Args),
    /// Snapshots of the cost map, and a check of the cameras' floor mappings.
    Costmap(costmap::Args),
    /// Show the site live in Foxglove (a Foxglove WebSocket server).
    View(view::Args),
    /// Record the site's streams into an MCAP file (opens in Foxglove).
    Record(record::Args),
    /// Make the DDS Security keystore of the site: links, costmap bridge, robots (SROS2 layout, openssl).
    Keystore(keystore::Args),
}

/// The whole `main` of the `isochron` binary.
pub fn main() -> ExitCode {
    // Output into a closed pipe (`isochron tap ... | head`) ends the process
    // quietly, as for any Unix tool, instead of a panic in println!.
    // SAFETY: called before any other thread exists.
    unsafe { libc::signal(libc::SIGPIPE, libc::SIG_DFL) };
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => return parse_error(&e),
    };
    isochron_runtime::logging::init("isochron");
    isochron_runtime::service::owner_only_files();
    let result = match cli.command {
        Command::Up(args) => up::run(args),
        Command::Tap(args) => tap::run(args),
        Command::Status(args) => status::run(args),
        Command::Doctor(args) => doctor::run(args),
        Command::Replay(args) => replay::run(args),
        Command::Synth(args) => synth::run(args),
        Command::Store(args) => store::run(args),
        Command::Plot(args) => plot::run(args),
        Command::Plan(args) => plan::run(args),
        Command::Costmap(args) => costmap::run(args),
        Command::View(args) => view::run(args),
        Command::Record(args) => record::run(args),
        Command::Keystore(args) => keystore::run(args),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("isochron: {e:#}");
            ExitCode::from(exit_code_of(&e) as u8)
        }
    }
}

/// The code a command that failed with `e` exits with: the services' table (a
/// config error is 78 here too).
pub(crate) fn exit_code_of(e: &anyhow::Error) -> i32 {
    let chain = e.chain().map(|c| c as &(dyn std::error::Error + 'static));
    exit::code_of_chain(chain, library_code)
}

/// Ends a command line clap refused. A value that is not what its flag expects
/// (`--day funday`, `--days 0`) is a usage error, 64, on one line that names the
/// flag, the value and what is expected; `--help` and `--version` print and exit
/// 0; any other (an unknown flag, a missing argument) is clap's own, 2.
fn parse_error(e: &clap::Error) -> ExitCode {
    use clap::error::ErrorKind;
    if !matches!(
        e.kind(),
        ErrorKind::ValueValidation | ErrorKind::InvalidValue
    ) {
        e.exit();
    }
    eprintln!("isochron: {}", one_line(&e.render().to_string()));
    ExitCode::from(exit::USAGE as u8)
}

/// clap's message as one line: its lines joined, without `error: ` and the
/// pointer to `--help`.
fn one_line(message: &str) -> String {
    message
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with("For more information"))
        .map(|l| l.strip_prefix("error: ").unwrap_or(l))
        .collect::<Vec<_>>()
        .join(" ")
}

/// The exit code of a library error of the chain, if it is one.
fn library_code(e: &(dyn std::error::Error + 'static)) -> Option<i32> {
    use isochron_exit::Classify;
    if let Some(e) = e.downcast_ref::<common::Coded>() {
        Some(e.code)
    } else if let Some(e) = e.downcast_ref::<isochron_config::ConfigError>() {
        Some(e.exit_code())
    } else if e.is::<isochron_config::UnknownCamera>() {
        // The command names the camera on its command line (`tap cam09`,
        // `--camera cam09`): the argument is wrong, 64, where a service, whose
        // unit names it, says 78.
        Some(isochron_exit::USAGE)
    } else if let Some(e) = e.downcast_ref::<isochron_planning::plan::PlanError>() {
        // A route or segment the command line names (`--route`, `--segment`);
        // a day the stores never learned (`--day sun`).
        use isochron_planning::plan::PlanError::{DayNotLearned, UnknownRoute, UnknownSegment};
        match e {
            UnknownRoute(..) | UnknownSegment(..) => Some(isochron_exit::USAGE),
            DayNotLearned { .. } => Some(isochron_exit::NO_INPUT),
            _ => None,
        }
    } else if let Some(e) = e.downcast_ref::<isochron_store::StoreError>() {
        Some(e.exit_code())
    } else if let Some(e) = e.downcast_ref::<isochron_wire::WireError>() {
        Some(e.exit_code())
    } else if let Some(e) = e.downcast_ref::<std::io::Error>() {
        // The disk, not the input: a full or read-only file system.
        use std::io::ErrorKind::{QuotaExceeded, ReadOnlyFilesystem, StorageFull};
        matches!(e.kind(), StorageFull | ReadOnlyFilesystem | QuotaExceeded)
            .then_some(isochron_exit::UNAVAILABLE)
    } else {
        e.downcast_ref::<isochron_runtime::ipc::IpcError>()
            .map(Classify::exit_code)
    }
}

/// The command line of `isochron`, every subcommand included.
pub fn command() -> clap::Command {
    Cli::command()
}
