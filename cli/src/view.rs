//! `isochron view --config site.toml [--listen ADDR]`: the site live in Foxglove —
//! a Foxglove WebSocket server (subprotocol `foxglove.websocket.v1` or its new
//! names `foxglove.sdk.v1[.1]`, each client held to `view.client_budget_mib`, all
//! of them to `view.memory_budget_mib`, at most `view.max_clients` at once) with
//! the same channels as
//! `isochron record` ([`isochron_view::channels`]). Listens on `view.listen`
//! (default 127.0.0.1:8765, loopback) unless `--listen` says otherwise. Open
//! Foxglove, "Open connection", `ws://127.0.0.1:8765`. It runs as a stage on the
//! stage runtime ([`isochron_view::stage`]) until Ctrl-C or SIGTERM, and reports
//! its status (`isochron status` lists it as `view`).

use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::bail;
use isochron_runtime::ipc::Ipc;
use isochron_view::Context;
use isochron_view::channels::SiteChannels;
use isochron_view::follow::Streams;
use isochron_view::stage::{Sink, Until, ViewStage};

use crate::common::load_config;

/// Show the site live in Foxglove (WebSocket server).
#[derive(clap::Args)]
pub struct Args {
    /// Site configuration (default: $ISOCHRON_CONFIG or /etc/isochron/isochron.toml).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Address and port to listen on (default: `view.listen`, 127.0.0.1:8765). A
    /// non-loopback address makes the view reachable from the network.
    #[arg(long)]
    listen: Option<String>,
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let loaded = load_config(args.config)?;
    let listen = args.listen.as_deref().unwrap_or(&loaded.config.view.listen);
    let Ok(addr) = listen.parse::<SocketAddr>() else {
        bail!(isochron_exit::UsageError(format!(
            "--listen: expected an IP address and port such as 127.0.0.1:8765, found '{listen}'"
        )));
    };
    let ctx = Context::new();
    let channels = SiteChannels::new(&loaded, &ctx)?;
    // The port first: a taken one fails before joining the group.
    let limits = isochron_view::live::ClientLimits::of(&loaded.config.view);
    let server = isochron_view::live::serve(&ctx, addr, &loaded.config.site.name, limits)?;
    let ipc = Ipc::of_site(
        &format!("isochron-view-{}", std::process::id()),
        &loaded.config,
    )?;
    let (mut stage, inputs) = ViewStage::open(
        &ipc,
        &loaded,
        channels,
        Sink::Live(server),
        Streams::all(&loaded),
        Until::default(),
    )?;
    println!(
        "view: Foxglove WebSocket on ws://{addr} (images {}; at most {} clients, {} MiB for all of them)",
        if loaded.config.view.frames {
            "on"
        } else {
            "off: view.frames = false"
        },
        limits.max_clients,
        loaded.config.view.memory_budget_mib
    );
    if !addr.ip().is_loopback() {
        eprintln!("isochron view: listening on {addr}, reachable from the network");
    }
    // Until Ctrl-C or SIGTERM.
    isochron_runtime::stage::run(&ipc, "", &mut stage, &inputs)?;
    stage.finish()?;
    Ok(ExitCode::SUCCESS)
}
