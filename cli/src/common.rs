//! What several commands share: finding the config, the shape of a group of
//! subcommands.

use std::path::PathBuf;

use anyhow::Context;
use isochron_config::{Config, LoadedConfig};

/// The config file: `--config`, else `$ISOCHRON_CONFIG`, else
/// `/etc/isochron/isochron.toml`.
pub fn config_path(arg: Option<PathBuf>) -> PathBuf {
    arg.or_else(|| std::env::var_os("ISOCHRON_CONFIG").map(PathBuf::from))
        .unwrap_or_else(|| PathBuf::from("/etc/isochron/isochron.toml"))
}

/// Loads the config named by `arg` (see [`config_path`]).
pub fn load_config(arg: Option<PathBuf>) -> anyhow::Result<LoadedConfig> {
    let path = config_path(arg);
    Config::load(&path).with_context(|| "invalid configuration")
}

/// The arguments of a command that is a group of subcommands (`isochron store
/// export`, `isochron plan now`, ...): `C` lists them.
#[derive(clap::Args)]
pub struct Subcommands<C: clap::Subcommand> {
    #[command(subcommand)]
    pub command: C,
}
