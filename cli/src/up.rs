//! `isochron up --config FILE`: run the site's process group in the foreground, as
//! systemd would: restart what dies, stop everything on Ctrl-C, show status.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use isochron_runtime::ipc::Ipc;
use isochron_runtime::topology::StageKind;

use crate::common::load_config;
use crate::launch::{Supervisor, group_specs, installed};

/// Start the configured services as separate processes and keep them running.
#[derive(clap::Args)]
pub struct Args {
    /// Site configuration (default: $ISOCHRON_CONFIG or /etc/isochron/isochron.toml).
    #[arg(long)]
    config: Option<PathBuf>,
    /// A service that shows no sign of life for this long is killed and restarted.
    #[arg(long, default_value = "10", value_parser = crate::values::positive_seconds)]
    watchdog_s: Duration,
    /// Write each service's output to DIR/<service>.log instead of this terminal.
    #[arg(long)]
    log_dir: Option<PathBuf>,
    /// Print the status table this often (0 = only at exit).
    #[arg(long, default_value = "30", value_parser = crate::values::seconds)]
    status_every_s: Duration,
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let loaded = load_config(args.config)?;
    // The node is only for the SIGINT/SIGTERM handling every isochron process shares.
    let ipc = Ipc::of_site("isochron-up", &loaded.config)?;
    let stages = installed(StageKind::started(&loaded.config));
    let specs = group_specs(&loaded, &stages);
    if specs.is_empty() {
        anyhow::bail!(
            "no service binaries found in {} (build them with `cargo build`, or set ISOCHRON_BIN_DIR)",
            crate::launch::bin_dir().display()
        );
    }
    let mut supervisor = Supervisor::new(true, args.watchdog_s, args.log_dir)?;
    for spec in specs {
        let change = supervisor.add(spec)?;
        println!("up: {} {}", change.name, change.what);
    }
    let mut last_table = Instant::now();
    while !ipc.should_stop() {
        for change in supervisor.poll() {
            println!("up: {} {}", change.name, change.what);
        }
        if !args.status_every_s.is_zero() && last_table.elapsed() >= args.status_every_s {
            print!("{}", supervisor.table());
            last_table = Instant::now();
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    println!("up: stopping");
    supervisor.stop_all(Duration::from_secs(10));
    print!("{}", supervisor.table());
    Ok(ExitCode::SUCCESS)
}
