//! Developer tasks: `cargo xtask <command>`; [`COMMANDS`] is the list, each with
//! its usage and what it does (`cargo xtask help` prints it). In short: `setup`
//! installs what building and running needs, `setup --all` the test peers and
//! benchmark data as well ([`setup`]); `demo` replays the sample video through
//! the group and draws what it learned ([`demo`]); `test` is what CI runs
//! ([`ci`]); `bench NAME` one benchmark ([`ci::BENCHES`]); `structure` and
//! `deps` the source and dependency rules ([`structure`], [`deps`]); `docs`
//! the man pages, completions and the configuration reference ([`install`],
//! [`config_ref`]); `install` and `deb` the installed files ([`install`], [`deb`]).

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

/// One `cargo xtask` command: its name, its arguments, what it does, and the
/// function that runs it (with the repository root and the arguments after the
/// name).
struct Task {
    name: &'static str,
    usage: &'static str,
    about: &'static str,
    run: fn(&Path, &[String]) -> anyhow::Result<()>,
}

/// Every command, declared once: `main` dispatches on it, `help` prints it.
const COMMANDS: [Task; 10] = [
    Task {
        name: "setup",
        usage: "[--all | detector]",
        about: "install what building and running needs: the system packages (OpenCV, clang, libssl), the sample video data/vtest.avi, the MoveNet detector; --all: also the test peers (Python, npm, rclpy, Zenoh, Fast DDS), the SSD and the benchmarks' scenes and counts; detector: the detectors and scenes alone",
        run: |root, args| match args.first().map(String::as_str) {
            Some("detector") => detector_model::setup(root),
            Some("--all") => setup::setup_all(root),
            None => setup::setup(root),
            Some(other) => bail!("setup: unknown argument '{other}' (expected --all or detector)"),
        },
    },
    Task {
        name: "demo",
        usage: "",
        about: "setup, a build of the binaries the replay runs, `isochron replay` of data/vtest.avi with config/demo.toml into out/demo, and its pictures",
        run: |root, _| {
            setup::setup(root)?;
            demo::demo(root)
        },
    },
    Task {
        name: "test",
        usage: "",
        about: "setup --all, then format, structure, configuration reference, lints, every test and every benchmark in quick mode (what CI runs)",
        run: |root, _| {
            setup::setup_all(root)?;
            ci::test(root)
        },
    },
    Task {
        name: "bench",
        usage: "NAME [--quick] [ARGS]",
        about: "setup --all and one benchmark (release build; --quick: few iterations in the dev profile, checked for its closing JSON line)",
        run: run_bench,
    },
    Task {
        name: "structure",
        usage: "",
        about: "no source file over 700 lines but tests, no module cycles",
        run: |root, _| structure::check(root),
    },
    Task {
        name: "deps",
        usage: "",
        about: "the dependency policy (licences, sources, duplicate versions), offline",
        run: |root, _| deps::check(root),
    },
    Task {
        name: "docs",
        usage: "[OUT] | config [--check]",
        about: "man pages and shell completions into OUT (default target/docs); config: docs/configuration.md from the config structs (--check: fail if stale)",
        run: |root, args| {
            if args.first().is_some_and(|a| a == "config") {
                return config_ref::run(root, cargo(), &args[1..]);
            }
            let out = args
                .first()
                .map_or_else(|| root.join("target/docs"), PathBuf::from);
            install::docs(&out, false)
        },
    },
    Task {
        name: "install",
        usage: "[--prefix P] [--destdir D]",
        about: "release build, then binaries, systemd units, sysusers/tmpfiles, an example config, man pages and completions under D/P (default P = /usr/local)",
        run: |root, args| install::install(root, args),
    },
    Task {
        name: "deb",
        usage: "[--profile dev|release] [--no-build] [--out DIR]",
        about: "the same files under /usr as a Debian package (default target/deb)",
        run: |root, args| deb::deb(root, args),
    },
    Task {
        name: "help",
        usage: "",
        about: "this list",
        run: |_, _| {
            println!("{}", help());
            Ok(())
        },
    },
];

/// Every command with its usage and what it does.
fn help() -> String {
    let mut text = String::from("usage: cargo xtask <command>\n");
    for task in &COMMANDS {
        text.push_str(&format!(
            "\n  {} {}\n      {}\n",
            task.name, task.usage, task.about
        ));
    }
    text
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let root = repo_root();
    std::env::set_current_dir(&root)?;
    let name = args.first().map(String::as_str).unwrap_or("");
    let Some(task) = COMMANDS.iter().find(|t| t.name == name) else {
        bail!("unknown command '{name}'\n{}", help());
    };
    (task.run)(&root, &args[1..])
}

/// `bench NAME [--quick] [ARGS]`.
fn run_bench(root: &Path, args: &[String]) -> anyhow::Result<()> {
    let name = args.first().map(String::as_str).unwrap_or("");
    let Some(target) = BENCHES.iter().find(|n| **n == name) else {
        bail!("usage: cargo xtask bench <{}>", BENCHES.join("|"));
    };
    setup::setup_all(root)?;
    let extra = &args[1..];
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
