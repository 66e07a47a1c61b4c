//! `cargo xtask test` and `cargo xtask bench`: what CI runs — format, lints (clippy
//! with warnings denied while building), the structure rules, every test, every
//! benchmark in quick mode.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

use anyhow::{Context, bail};

use crate::{cargo, run};

/// The benchmarks, by bench target name (each unique in the workspace): ipc,
/// motion, cascade, gate, detector (the people detectors scored on labelled
/// real scenes), group, site, and forecast (the long-term model's backtest on
/// real pedestrian counts).
pub(crate) const BENCHES: [&str; 8] = [
    "ipc", "motion", "cascade", "gate", "detector", "group", "site", "forecast",
];

/// The checks and tests CI runs, in order.
pub(crate) fn test(root: &Path) -> anyhow::Result<()> {
    run(cargo().args(["fmt", "--all", "--", "--check"]))?;
    crate::structure::check(root)?;
    crate::config_ref::check(root, linted_cargo()?)?;
    // Lint and build every target in one pass (clippy --all-targets, but building).
    run(linted_cargo()?.args(["test", "--workspace", "--all-targets", "--no-run"]))?;
    // After the build: every crate is downloaded, so `cargo metadata` runs offline.
    crate::deps::check(root)?;
    run(linted_cargo()?.args(["build", "--workspace", "--bins"]))?;
    run(linted_cargo()?.args(["test", "--workspace"]))?;
    // Every benchmark in quick mode, so that none can rot.
    let mut times = Vec::new();
    for name in BENCHES {
        let t0 = Instant::now();
        quick_bench(linted_cargo()?, name, &[])?;
        times.push(format!("{name} {:.0} s", t0.elapsed().as_secs_f64()));
    }
    eprintln!(
        "xtask: every benchmark ran in quick mode ({})",
        times.join(", ")
    );
    Ok(())
}

/// `cargo` with clippy's driver as the compiler of the workspace's own crates, all
/// warnings denied: what `cargo clippy -- -D warnings` does, but building as well as
/// linting, so that no crate is compiled twice (once checked for clippy, once built
/// for the tests). Dependencies are built by plain rustc, as with `cargo clippy`.
/// Incremental compilation is off where `CI` is set: a clean build is faster without.
fn linted_cargo() -> anyhow::Result<Command> {
    let rustc = std::env::var("RUSTC").unwrap_or_else(|_| "rustc".into());
    let sysroot = Command::new(&rustc)
        .args(["--print", "sysroot"])
        .output()
        .with_context(|| format!("running {rustc} --print sysroot"))?;
    let driver =
        PathBuf::from(String::from_utf8_lossy(&sysroot.stdout).trim()).join("bin/clippy-driver");
    if !driver.exists() {
        bail!(
            "{} not found: install clippy (`rustup component add clippy`)",
            driver.display()
        );
    }
    let mut cmd = cargo();
    cmd.env("RUSTC_WORKSPACE_WRAPPER", driver).env(
        "CLIPPY_ARGS",
        "-D__CLIPPY_HACKERY__warnings__CLIPPY_HACKERY__",
    );
    if std::env::var_os("CI").is_some() {
        cmd.env("CARGO_INCREMENTAL", "0");
    }
    Ok(cmd)
}

/// Runs benchmark `target` in quick mode in the dev profile (`cmd`, a `cargo`
/// command, with `test --workspace --bench`: the `harness = false` binary, run with
/// the arguments after `--`; `--workspace` rather than `-p`, so that dependencies keep
/// the workspace's unified features and nothing is compiled again), its output shown
/// as it comes, and fails unless the last line of its output that names
/// `"bench"` is a JSON object of this benchmark.
pub(crate) fn quick_bench(mut cmd: Command, target: &str, extra: &[String]) -> anyhow::Result<()> {
    cmd.args(["test", "--workspace", "--bench", target, "--", "--quick"])
        .args(extra)
        .stdout(Stdio::piped());
    let shown = format!("{cmd:?}");
    eprintln!("xtask: {shown}");
    let mut child = cmd.spawn().with_context(|| format!("starting {shown}"))?;
    let stdout = child.stdout.take().context("bench stdout")?;
    let mut last = None;
    for line in BufReader::new(stdout).lines() {
        let line = line.with_context(|| format!("reading the output of {shown}"))?;
        println!("{line}");
        if line.contains("\"bench\"") {
            last = Some(line);
        }
    }
    let status = child.wait()?;
    if !status.success() {
        bail!("benchmark {target} (quick) failed ({status}): {shown}");
    }
    let Some(line) = last else {
        bail!("benchmark {target} (quick) printed no JSON line with \"bench\": {shown}");
    };
    let json: serde_json::Value = serde_json::from_str(line.trim()).with_context(|| {
        format!("benchmark {target} (quick): its last \"bench\" line is not valid JSON: {line}")
    })?;
    if json["bench"] != target {
        bail!("benchmark {target} (quick): its JSON line names another bench: {line}");
    }
    Ok(())
}

/// Whether benchmark `target` runs the workspace's binaries, which must be built
/// first.
pub(crate) fn needs_bins(target: &str) -> bool {
    matches!(target, "gate" | "group" | "site" | "forecast")
}

/// Runs benchmark `target` with `cargo bench` (release profile), `extra` its options.
pub(crate) fn bench(target: &str, extra: &[String]) -> anyhow::Result<()> {
    if needs_bins(target) {
        // These run the whole process group (site: the link and the bridge;
        // forecast: `isochron store backtest`).
        run(cargo().args(["build", "--release", "--workspace", "--bins"]))?;
    }
    // `--workspace`, not `-p`: the dependencies keep the features of the release
    // build above, so they are not compiled again.
    run(cargo()
        .args(["bench", "--workspace", "--bench", target, "--"])
        .args(extra))
}
