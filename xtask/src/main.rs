//! Developer tasks: `cargo xtask <setup|demo|test|bench NAME|docs|install|deb>`.
//!
//! * `setup`: installs the system packages isochron builds and tests with
//!   (Debian/Ubuntu, [`PACKAGES`]) if they are missing, fetches the sample
//!   video (PETS 2009 `vtest.avi`, from Debian's opencv-doc package) into `data/`,
//!   and installs the test peers: Python packages into `target/ros2-venv`, npm
//!   packages into `target/node-peers`, and the Fast DDS test client;
//! * `demo`: setup, release build, `isochron replay` on the sample video with
//!   `config/demo.toml`, and a report of what every stage did;
//! * `test`: setup, format and lint checks, build, every test, then every benchmark
//!   in quick mode (dev profile), each checked for its closing JSON line;
//! * `bench NAME`: setup and one benchmark (motion, cascade, gate, ipc, group);
//!   `bench NAME --quick`: the same code with few iterations, in the dev profile (no
//!   release build), checked for its closing JSON line as `test` does;
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

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

use anyhow::{Context, bail};

mod config_ref;

/// System packages: OpenCV and the bindings' clang; iproute2 (`ip`, `ss`) for the
/// network-namespace and DDS socket tests; `prometheus` for promtool, which checks
/// the exporter's output and the alert rules; `mosquitto`, the broker the MQTT
/// sink's test publishes to (and `mosquitto_passwd`), `mosquitto-clients`, whose
/// `mosquitto_sub` reads the sink's messages back over TLS, and `openssl`, which
/// makes that test's certificates and which `isochron keystore` runs; `dpkg-dev`
/// for `dpkg-shlibdeps`, which gives the package's `Depends` (`cargo xtask deb`);
/// eProsima Fast DDS, its IDL compiler and g++ for the Fast DDS client of the
/// planning services' test ([`fastdds_peer`]); `libssl-dev` for RustDDS's DDS
/// Security (the link's authentication and encryption).
const PACKAGES: [&str; 13] = [
    "libopencv-dev",
    "clang",
    "libclang-dev",
    "iproute2",
    "prometheus",
    "mosquitto",
    "mosquitto-clients",
    "openssl",
    "dpkg-dev",
    "libfastrtps-dev",
    "fastddsgen",
    "g++",
    "libssl-dev",
];

/// The benchmarks, by bench target name (each unique in the workspace).
const BENCHES: [&str; 6] = ["ipc", "motion", "cascade", "gate", "group", "site"];

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let root = repo_root();
    std::env::set_current_dir(&root)?;
    match args.first().map(String::as_str) {
        Some("setup") => setup(&root),
        Some("demo") => {
            setup(&root)?;
            demo(&root)
        }
        Some("test") => {
            setup(&root)?;
            test()
        }
        Some("bench") => {
            let name = args.get(1).map(String::as_str).unwrap_or("");
            let Some(target) = BENCHES.iter().find(|n| **n == name) else {
                bail!("usage: cargo xtask bench <{}>", BENCHES.join("|"));
            };
            setup(&root)?;
            let extra = &args[2..];
            if extra.iter().any(|a| a == "--quick") {
                let rest: Vec<String> = extra.iter().filter(|a| *a != "--quick").cloned().collect();
                if matches!(*target, "gate" | "group" | "site") {
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
            docs(&out, false)
        }
        Some("install") => install(&root, &args[1..]),
        Some("deb") => deb(&root, &args[1..]),
        _ => bail!(
            "usage: cargo xtask <setup|demo|test|bench NAME|docs [OUT]|docs config [--check]|install [--prefix P] [--destdir D]|deb [--profile dev|release] [--no-build] [--out DIR]>"
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

fn is_root() -> bool {
    Command::new("id")
        .arg("-u")
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
        .unwrap_or(false)
}

/// `apt-get ...`, through sudo when not root.
fn apt_get(args: &[&str]) -> Command {
    let mut cmd = if is_root() {
        Command::new("apt-get")
    } else {
        let mut c = Command::new("sudo");
        c.arg("apt-get");
        c
    };
    cmd.args(args).env("DEBIAN_FRONTEND", "noninteractive");
    cmd
}

fn missing_packages() -> Vec<&'static str> {
    PACKAGES
        .into_iter()
        .filter(|p| {
            !Command::new("dpkg-query")
                .args(["-W", "-f=${Status}", p])
                .output()
                .map(|o| String::from_utf8_lossy(&o.stdout).contains("install ok installed"))
                .unwrap_or(false)
        })
        .collect()
}

fn setup(root: &Path) -> anyhow::Result<()> {
    let missing = missing_packages();
    if !missing.is_empty() {
        eprintln!("xtask: installing {}", missing.join(" "));
        run(&mut apt_get(&["update", "-qq"]))?;
        let mut args = vec!["install", "-y", "-qq", "--no-install-recommends"];
        args.extend(&missing);
        run(&mut apt_get(&args))?;
    }
    fetch_vtest(root)?;
    ros2_venv(root)?;
    node_peers(root)?;
    fastdds_peer(root)
}

/// The sources of the Fast DDS client (`tests/ros2/fastdds/`).
const FASTDDS_SOURCES: [&str; 2] = ["isochron_msgs.idl", "plan_requester.cpp"];

/// Builds `target/fastdds-peer/plan_requester`, the independent Fast DDS client of
/// the planning services (`tests/it/nav2.rs`): fastddsgen makes the C++ types of
/// `tests/ros2/fastdds/isochron_msgs.idl`, g++ links them with
/// `plan_requester.cpp` against Debian's Fast DDS. Skipped when the binary was
/// built from the same sources (a hash of them in `sources.hash`).
fn fastdds_peer(root: &Path) -> anyhow::Result<()> {
    use std::hash::{DefaultHasher, Hash, Hasher};
    let src = root.join("tests/ros2/fastdds");
    let out = root.join("target/fastdds-peer");
    let mut hasher = DefaultHasher::new();
    for name in FASTDDS_SOURCES {
        std::fs::read(src.join(name))
            .with_context(|| format!("reading {}", src.join(name).display()))?
            .hash(&mut hasher);
    }
    let hash = format!("{:016x}\n", hasher.finish());
    let (binary, stamp) = (out.join("plan_requester"), out.join("sources.hash"));
    if binary.is_file() && std::fs::read_to_string(&stamp).is_ok_and(|s| s == hash) {
        return Ok(());
    }
    let t0 = Instant::now();
    let gen_dir = out.join("gen");
    let _ = std::fs::remove_dir_all(&out);
    std::fs::create_dir_all(&gen_dir)?;
    run(Command::new("fastddsgen")
        .args(["-replace", "-d"])
        .arg(&gen_dir)
        .arg(src.join("isochron_msgs.idl")))?;
    run(Command::new("g++")
        .args(["-std=c++17", "-O1", "-w", "-I"])
        .arg(&gen_dir)
        .arg(src.join("plan_requester.cpp"))
        .arg(gen_dir.join("isochron_msgs.cxx"))
        .arg(gen_dir.join("isochron_msgsPubSubTypes.cxx"))
        .args(["-lfastrtps", "-lfastcdr", "-o"])
        .arg(&binary))?;
    std::fs::write(&stamp, hash)?;
    eprintln!(
        "xtask: built {} in {:.0} s",
        binary.display(),
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}

/// The Python package the ROS 2 interoperability test subscribes with (Eclipse
/// Cyclone DDS; this version has manylinux wheels for CPython 3.10 to 3.13, so pip
/// never builds it from source).
const CYCLONEDDS: &str = "cyclonedds==11.0.1";

/// The Python package `tests/data/yolo_constant.py` builds a small ONNX model with,
/// for the test of the gate's OpenCV dnn path (no model is downloaded).
const ONNX: &str = "onnx==1.17.0";

/// The other Python test peers: an independent MCAP reader and WebSocket client
/// for `tests/it/view.rs` (recordings and the live Foxglove view), the MCAP
/// protobuf decoder `tests/presence/band.py` reads the presence band with, and
/// PyYAML for `tests/ros2/nav2_static_layer.py` (it reads the shipped Nav2
/// snippet).
const PY_PEERS: &[(&str, &str)] = &[
    ("mcap", "1.6.0"),
    ("websockets", "17.4"),
    ("mcap-protobuf-support", "0.5.3"),
    ("PyYAML", "6.0.3"),
];

/// Makes `target/ros2-venv`, a Python venv with [`CYCLONEDDS`], for
/// `tests/it/costmap.rs` (an independent ROS 2 subscriber: no ROS install needed),
/// and [`ONNX`], for `tests/it/gate.rs`.
fn ros2_venv(root: &Path) -> anyhow::Result<()> {
    let venv = root.join("target/ros2-venv");
    let python = venv.join("bin/python3");
    let version = CYCLONEDDS.trim_start_matches("cyclonedds==");
    let ready = Command::new(&python)
        .args([
            "-c",
            &format!(
                "import importlib.metadata as m, cyclonedds.domain, onnx; assert m.version('cyclonedds') == '{version}'{}",
                PY_PEERS
                    .iter()
                    .map(|(p, v)| format!("; assert m.version('{p}') == '{v}'"))
                    .collect::<String>()
            ),
        ])
        .output()
        .is_ok_and(|o| o.status.success());
    if ready {
        return Ok(());
    }
    let has_venv = Command::new("python3")
        .args(["-c", "import venv, ensurepip"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !has_venv {
        eprintln!("xtask: installing python3 and python3-venv");
        run(&mut apt_get(&["update", "-qq"]))?;
        run(&mut apt_get(&[
            "install",
            "-y",
            "-qq",
            "--no-install-recommends",
            "python3",
            "python3-venv",
        ]))?;
    }
    eprintln!(
        "xtask: making {} with {CYCLONEDDS} and {ONNX}",
        venv.display()
    );
    let _ = std::fs::remove_dir_all(&venv);
    run(Command::new("python3").arg("-m").arg("venv").arg(&venv))?;
    let peers: Vec<String> = PY_PEERS.iter().map(|(p, v)| format!("{p}=={v}")).collect();
    run(Command::new(&python)
        .args([
            "-m",
            "pip",
            "install",
            "--quiet",
            "--only-binary=:all:",
            CYCLONEDDS,
            ONNX,
        ])
        .args(&peers))
}

/// Installs the npm test peers of `tests/it/view.rs` into `target/node-peers`:
/// `@foxglove/ws-protocol` (the reference client of the Foxglove WebSocket
/// protocol), `ws` and `protobufjs`, at the versions `tests/view/package.json` and
/// its lock pin (`npm ci`, no install scripts). Node.js comes from Debian's
/// `nodejs` package if there is none (tested with Node 20).
fn node_peers(root: &Path) -> anyhow::Result<()> {
    let dir = root.join("target/node-peers");
    let lock = std::fs::read(root.join("tests/view/package-lock.json"))
        .context("reading tests/view/package-lock.json")?;
    let stamp = dir.join("installed-lock.json");
    if std::fs::read(&stamp).is_ok_and(|installed| installed == lock) {
        return Ok(());
    }
    let runs = |tool: &str| {
        Command::new(tool)
            .arg("--version")
            .output()
            .is_ok_and(|o| o.status.success())
    };
    if !runs("node") || !runs("npm") {
        eprintln!("xtask: installing nodejs and npm");
        run(&mut apt_get(&["update", "-qq"]))?;
        run(&mut apt_get(&[
            "install",
            "-y",
            "-qq",
            "--no-install-recommends",
            "nodejs",
            "npm",
        ]))?;
    }
    eprintln!(
        "xtask: installing the npm test peers into {}",
        dir.display()
    );
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir)?;
    for file in ["package.json", "package-lock.json"] {
        std::fs::copy(root.join("tests/view").join(file), dir.join(file))
            .with_context(|| format!("copying tests/view/{file}"))?;
    }
    run(Command::new("npm")
        .args([
            "ci",
            "--ignore-scripts",
            "--no-audit",
            "--no-fund",
            "--prefix",
        ])
        .arg(&dir))?;
    std::fs::write(&stamp, lock)?;
    Ok(())
}

/// Fetches `data/vtest.avi` from Debian's opencv-doc package (downloaded, not
/// installed: only that one file is extracted).
fn fetch_vtest(root: &Path) -> anyhow::Result<()> {
    let target = root.join("data/vtest.avi");
    if target.is_file() {
        return Ok(());
    }
    std::fs::create_dir_all(root.join("data"))?;
    let work = root.join("target/opencv-doc");
    std::fs::create_dir_all(&work)?;
    eprintln!("xtask: fetching vtest.avi from Debian's opencv-doc package");
    if std::fs::read_dir(&work)?
        .filter_map(Result::ok)
        .all(|e| !e.file_name().to_string_lossy().ends_with(".deb"))
    {
        run(Command::new("apt-get")
            .args(["download", "opencv-doc"])
            .current_dir(&work))?;
    }
    let deb = std::fs::read_dir(&work)?
        .filter_map(Result::ok)
        .map(|e| e.path())
        .find(|p| p.extension().is_some_and(|e| e == "deb"))
        .context("apt-get download opencv-doc produced no .deb")?;
    let member = "./usr/share/doc/opencv-doc/examples/data/vtest.avi";
    run(Command::new("sh").arg("-c").arg(format!(
        "dpkg-deb --fsys-tarfile '{}' | tar -x -C '{}' '{member}'",
        deb.display(),
        work.display()
    )))?;
    std::fs::copy(work.join(member), &target)
        .with_context(|| format!("copying vtest.avi to {}", target.display()))?;
    eprintln!("xtask: {} ready", target.display());
    Ok(())
}

fn cargo() -> Command {
    Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()))
}

fn demo(root: &Path) -> anyhow::Result<()> {
    run(cargo().args(["build", "--release", "--workspace", "--bins"]))?;
    let out = root.join("out/demo");
    let _ = std::fs::remove_dir_all(&out);
    run(Command::new(root.join("target/release/isochron")).args([
        "replay",
        "data/vtest.avi",
        "--out",
        "out/demo",
        "--config",
        "config/demo.toml",
    ]))?;
    report(&out)
}

/// Prints what the replay produced; the last line is the demo's summary line.
fn report(out: &Path) -> anyhow::Result<()> {
    let summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.join("summary.json")).context("reading summary.json")?,
    )?;
    let count = |k: &str| summary["counts"][k].as_u64().unwrap_or(0);
    println!();
    println!(
        "replayed {} frames in {:.1} s ({:.0} frames/s)",
        count("frames"),
        summary["wall_time_s"].as_f64().unwrap_or(0.0),
        summary["frames_per_s"].as_f64().unwrap_or(0.0)
    );
    let events = std::fs::read_to_string(out.join("events.jsonl")).unwrap_or_default();
    for line in events.lines().take(10) {
        let e: serde_json::Value = serde_json::from_str(line)?;
        println!(
            "event {} {} {} {} → {} (frames {}..{}) peak {:.3}",
            e["event_id"],
            e["zone"],
            e["kind"],
            e["start"],
            e["end"],
            e["start_frame"],
            e["end_frame"],
            e["peak"].as_f64().unwrap_or(0.0)
        );
    }
    let gate = &summary["gate"];
    if let (Some(seen), Some(detected)) = (
        gate["frames_seen"].as_u64(),
        gate["frames_detected"].as_u64(),
    ) && seen > 0
    {
        println!(
            "gate: detector ran on {detected} of {seen} frames ({:.1} %), {:.0} ms of detector time",
            100.0 * detected as f64 / seen as f64,
            gate["detector_total_ms"].as_f64().unwrap_or(0.0)
        );
    }
    println!("outputs in {}", out.display());
    println!(
        "demo: frames={} motion={} activity={} events={} detections={}",
        count("frames"),
        count("motion"),
        count("activity"),
        count("events"),
        count("detections")
    );
    Ok(())
}

fn test() -> anyhow::Result<()> {
    run(cargo().args(["fmt", "--all", "--", "--check"]))?;
    config_ref::check(&repo_root(), linted_cargo()?)?;
    // Lint and build every target in one pass (clippy --all-targets, but building).
    run(linted_cargo()?.args(["test", "--workspace", "--all-targets", "--no-run"]))?;
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
fn quick_bench(mut cmd: Command, target: &str, extra: &[String]) -> anyhow::Result<()> {
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

fn bench(target: &str, extra: &[String]) -> anyhow::Result<()> {
    if matches!(target, "gate" | "group" | "site") {
        // These run the whole process group (site: the link and the bridge).
        run(cargo().args(["build", "--release", "--workspace", "--bins"]))?;
    }
    // `--workspace`, not `-p`: the dependencies keep the features of the release
    // build above, so they are not compiled again.
    run(cargo()
        .args(["bench", "--workspace", "--bench", target, "--"])
        .args(extra))
}

/// The binaries a site runs.
const BINARIES: [&str; 9] = [
    "isochron",
    "isochron-capture",
    "isochron-motion",
    "isochron-cascade",
    "isochron-gate",
    "isochron-costmap",
    "isochron-exporter",
    "isochron-link",
    "isochron-mqtt",
];

/// Writes the man pages (`isochron` and the services) and completions of
/// `isochron` into `out` (see the `isochron-docs` example of the cli crate).
fn docs(out: &Path, release: bool) -> anyhow::Result<()> {
    let mut cmd = cargo();
    cmd.args([
        "run",
        "-q",
        "-p",
        "isochron-cli",
        "--example",
        "isochron-docs",
    ]);
    if release {
        cmd.arg("--release");
    }
    run(cmd.arg("--").arg(out))
}

/// Where [`lay_out`] puts a site's files, and from where.
struct Layout<'a> {
    /// The repository.
    root: &'a Path,
    /// The built binaries (`target/<profile>`).
    bins: &'a Path,
    /// What [`docs`] wrote (`man/`, `completions/`).
    docs: &'a Path,
    /// The installation prefix: `/usr/local`, or `/usr` for the package.
    prefix: &'a Path,
    /// Everything goes under this directory (DESTDIR; the package's root).
    destdir: &'a Path,
    /// The package's way: man pages gzipped (Debian policy), binaries stripped of
    /// their debug sections (symbol names stay, for backtraces).
    packaged: bool,
}

/// Installs the binaries, systemd units, sysusers/tmpfiles entries, README,
/// example config, Grafana dashboard, alert rules, man pages and completions
/// under `destdir/prefix` (`cargo xtask install` and `cargo xtask deb`).
fn lay_out(l: &Layout) -> anyhow::Result<()> {
    let under = |p: &Path| l.destdir.join(p.strip_prefix("/").unwrap_or(p));
    let prefix = l.prefix;
    let bin = prefix.join("bin");
    let units = prefix.join("lib/systemd/system");
    let doc = prefix.join("share/doc/isochron");
    for dir in [
        &bin,
        &units,
        &prefix.join("lib/sysusers.d"),
        &prefix.join("lib/tmpfiles.d"),
        &doc.join("examples"),
    ] {
        std::fs::create_dir_all(under(dir))?;
    }
    let mut binaries = Vec::new();
    for name in BINARIES {
        let from = l.bins.join(name);
        let to = under(&bin.join(name));
        std::fs::copy(&from, &to).with_context(|| {
            format!(
                "installing {} (is it built? cargo build --workspace --bins)",
                from.display()
            )
        })?;
        binaries.push(to);
    }
    if l.packaged {
        run(Command::new("strip").arg("--strip-debug").args(&binaries))?;
    }
    // Units name /usr/bin; point them at this prefix.
    let bin_text = format!("{}/", bin.display());
    let copy_unit = |from: &Path, to: &Path| -> anyhow::Result<()> {
        let text = std::fs::read_to_string(from)?.replace("/usr/bin/", &bin_text);
        std::fs::write(to, text).with_context(|| format!("writing {}", to.display()))
    };
    for entry in std::fs::read_dir(l.root.join("systemd"))? {
        let path = entry?.path();
        let name = path.file_name().context("unit name")?.to_owned();
        if path.is_dir() {
            let target = under(&units.join(&name));
            std::fs::create_dir_all(&target)?;
            for inner in std::fs::read_dir(&path)? {
                let inner = inner?.path();
                copy_unit(
                    &inner,
                    &target.join(inner.file_name().context("drop-in name")?),
                )?;
            }
        } else if path
            .extension()
            .is_some_and(|e| e == "service" || e == "target")
        {
            copy_unit(&path, &under(&units.join(&name)))?;
        }
    }
    let copies = [
        (
            "systemd/isochron.sysusers",
            prefix.join("lib/sysusers.d/isochron.conf"),
        ),
        (
            "systemd/isochron.tmpfiles",
            prefix.join("lib/tmpfiles.d/isochron.conf"),
        ),
        ("README.md", doc.join("README.md")),
        (
            "config/site.example.toml",
            doc.join("examples/isochron.toml"),
        ),
        (
            "deploy/grafana/isochron-dashboard.json",
            doc.join("examples/isochron-dashboard.json"),
        ),
        (
            "deploy/prometheus/isochron-alerts.yml",
            doc.join("examples/isochron-alerts.yml"),
        ),
    ];
    for (from, to) in copies {
        std::fs::copy(l.root.join(from), under(&to))
            .with_context(|| format!("installing {from}"))?;
    }
    // `isochron*.1` (the command) and `isochron-*.8` (the services).
    let mut pages = Vec::new();
    for entry in std::fs::read_dir(l.docs.join("man"))? {
        let path = entry?.path();
        let section = path.extension().context("a man page's section")?;
        let dir = under(
            &prefix
                .join("share/man")
                .join(format!("man{}", section.to_string_lossy())),
        );
        std::fs::create_dir_all(&dir)?;
        let to = dir.join(path.file_name().context("file name")?);
        std::fs::copy(&path, &to)?;
        pages.push(to);
    }
    if l.packaged {
        // -n: no name or time stamp in the header, so the package is reproducible.
        run(Command::new("gzip").arg("-9nf").args(&pages))?;
    }
    let completions = l.docs.join("completions");
    for (file, dir, name) in [
        (
            "isochron.bash",
            "share/bash-completion/completions",
            "isochron",
        ),
        ("_isochron", "share/zsh/vendor-completions", "_isochron"),
        (
            "isochron.fish",
            "share/fish/vendor_completions.d",
            "isochron.fish",
        ),
    ] {
        let to = under(&prefix.join(dir));
        std::fs::create_dir_all(&to)?;
        std::fs::copy(completions.join(file), to.join(name))?;
    }
    Ok(())
}

fn install(root: &Path, args: &[String]) -> anyhow::Result<()> {
    let mut prefix = PathBuf::from("/usr/local");
    let mut destdir = PathBuf::from("/");
    let mut it = args.iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--prefix" => prefix = it.next().context("--prefix needs a path")?.into(),
            "--destdir" => destdir = it.next().context("--destdir needs a path")?.into(),
            other => bail!("install: unknown argument '{other}'"),
        }
    }
    anyhow::ensure!(prefix.is_absolute(), "--prefix must be an absolute path");
    run(cargo().args(["build", "--release", "--workspace", "--bins"]))?;
    let docs_dir = root.join("target/release/docs");
    let _ = std::fs::remove_dir_all(&docs_dir);
    docs(&docs_dir, true)?;
    lay_out(&Layout {
        root,
        bins: &root.join("target/release"),
        docs: &docs_dir,
        prefix: &prefix,
        destdir: &destdir,
        packaged: false,
    })?;
    let under = |p: &Path| destdir.join(p.strip_prefix("/").unwrap_or(p));
    let config = under(Path::new("/etc/isochron/isochron.toml"));
    if !config.exists() {
        std::fs::create_dir_all(config.parent().expect("config dir"))?;
        std::fs::copy(root.join("config/site.example.toml"), &config)?;
    }
    println!("installed under {}", under(&prefix).display());
    println!("next, as root:");
    println!(
        "  systemd-sysusers && systemd-tmpfiles --create    # the isochron user, its state dir, /tmp/iceoryx2"
    );
    println!("  $EDITOR /etc/isochron/isochron.toml              # cameras, zones, floor points");
    println!("  systemctl daemon-reload");
    print_enable_steps(&prefix.join("bin"));
    Ok(())
}

/// What to enable after installing (nothing is enabled by the install itself).
fn print_enable_steps(bin: &Path) {
    println!("  systemctl enable --now isochron.target isochron-costmap.service");
    println!(
        "  for c in cam01; do systemctl enable --now isochron-{{capture,motion,cascade,gate}}@$c; done"
    );
    println!(
        "  systemctl enable --now isochron-exporter         # optional: metrics at 127.0.0.1:9464"
    );
    println!(
        "  systemctl enable --now isochron-mqtt             # optional: events to [mqtt] broker"
    );
    println!(
        "  sudo -u isochron {}/isochron doctor               # checks it all",
        bin.display()
    );
}

/// The package's name.
const PACKAGE: &str = "isochron";

/// `postinst`: the user and directories from our own sysusers/tmpfiles entries,
/// and a daemon-reload when systemd runs. It enables and starts nothing.
const POSTINST: &str = r#"#!/bin/sh
# isochron postinst: the isochron user and its directories; enables nothing.
set -e
if [ "$1" = configure ]; then
    systemd-sysusers /usr/lib/sysusers.d/isochron.conf
    systemd-tmpfiles --create /usr/lib/tmpfiles.d/isochron.conf || true
    if [ -d /run/systemd/system ]; then
        systemctl --system daemon-reload >/dev/null || true
    fi
    echo "isochron: nothing is enabled; see /usr/share/doc/isochron/README.md (Running it on a base station)"
fi
exit 0
"#;

/// `prerm`: stops the running isochron units before their files go.
const PRERM: &str = r#"#!/bin/sh
# isochron prerm: stop the services before their binaries go.
set -e
if [ "$1" = remove ] && [ -d /run/systemd/system ]; then
    systemctl stop isochron.target 'isochron-*.service' >/dev/null 2>&1 || true
fi
exit 0
"#;

/// `postrm`: a daemon-reload after removal; on purge, the enablement links the
/// administrator made. The user and `/var/lib/isochron` (the learned activity)
/// are kept, as Debian keeps system users and data it cannot recreate.
const POSTRM: &str = r#"#!/bin/sh
# isochron postrm: forget the units; on purge, their enablement links too.
set -e
if [ "$1" = purge ]; then
    find /etc/systemd/system -path '*.wants/isochron*' -type l -delete 2>/dev/null || true
    echo "isochron: kept the isochron user and /var/lib/isochron (the learned activity)"
fi
if [ "$1" = remove ] || [ "$1" = purge ]; then
    if [ -d /run/systemd/system ]; then
        systemctl --system daemon-reload >/dev/null || true
    fi
fi
exit 0
"#;

/// `cargo xtask deb [--profile dev|release] [--no-build] [--out DIR]`: builds the
/// binaries (unless `--no-build`), lays the site out under `/usr` in a staging
/// tree ([`lay_out`]) and makes `DIR/isochron_<version>_<arch>.deb` with
/// `dpkg-deb --build` (default `DIR` = `target/deb`). Prints the package's path
/// as its last line.
fn deb(root: &Path, args: &[String]) -> anyhow::Result<()> {
    let mut profile = "release".to_string();
    let mut build = true;
    let mut out = root.join("target/deb");
    let mut it = args.iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--profile" => profile = it.next().context("--profile needs dev or release")?.clone(),
            "--no-build" => build = false,
            "--out" => out = it.next().context("--out needs a directory")?.into(),
            other => bail!("deb: unknown argument '{other}'"),
        }
    }
    let (dir, release) = match profile.as_str() {
        "release" => ("release", true),
        "dev" => ("debug", false),
        other => bail!("deb: --profile is dev or release, not '{other}'"),
    };
    if build {
        let mut cmd = cargo();
        cmd.args(["build", "--workspace", "--bins"]);
        if release {
            cmd.arg("--release");
        }
        run(&mut cmd)?;
    }
    let target = root.join("target").join(dir);
    let docs_dir = target.join("docs");
    // Without a build, the docs example is the one `cargo test` built: no cargo
    // run, which would wait for the lock a running `cargo test` holds.
    let example = target.join("examples/isochron-docs");
    if build {
        docs(&docs_dir, release)?;
    } else if example.is_file() {
        run(Command::new(&example).arg(&docs_dir))?;
    } else {
        bail!(
            "deb --no-build: {} is not built (cargo test --workspace builds it; or \
             cargo build -p isochron-cli --example isochron-docs{})",
            example.display(),
            if release { " --release" } else { "" }
        );
    }
    // dpkg-shlibdeps wants `debian/control` and the package under `debian/<name>`.
    let work = target.join("deb-work");
    let _ = std::fs::remove_dir_all(&work);
    let pkg = work.join("debian").join(PACKAGE);
    lay_out(&Layout {
        root,
        bins: &target,
        docs: &docs_dir,
        prefix: Path::new("/usr"),
        destdir: &pkg,
        packaged: true,
    })?;
    std::fs::create_dir_all(pkg.join("etc/isochron"))?;
    std::fs::write(
        pkg.join("usr/share/doc/isochron/copyright"),
        format!(
            "isochron {}\nLicense: {}\nSee the README for the project and its dependencies.\n",
            version(root)?,
            "MIT OR Apache-2.0"
        ),
    )?;
    let depends = depends(&work)?;
    let control = pkg.join("DEBIAN");
    std::fs::create_dir_all(&control)?;
    let version = version(root)?;
    let arch = output(Command::new("dpkg").arg("--print-architecture"))?;
    let maintainer = match (std::env::var("DEBFULLNAME"), std::env::var("DEBEMAIL")) {
        (Ok(name), Ok(email)) => format!("{name} <{email}>"),
        _ => "isochron developers <isochron@localhost>".to_string(),
    };
    normalize_modes(&pkg)?;
    let installed_kib = output(
        Command::new("du")
            .args(["-sk", "--apparent-size"])
            .arg(&pkg),
    )?
    .split_whitespace()
    .next()
    .unwrap_or("0")
    .to_string();
    std::fs::write(
        control.join("control"),
        format!(
            "Package: {PACKAGE}\n\
             Version: {version}\n\
             Architecture: {arch}\n\
             Maintainer: {maintainer}\n\
             Installed-Size: {installed_kib}\n\
             Depends: {depends}\n\
             Section: misc\n\
             Priority: optional\n\
             Description: people activity from fixed cameras, for robot planning\n \
             isochron learns where and when people are active from fixed cameras and\n \
             feeds robots a cost map (ROS 2). The package installs the isochron command,\n \
             the services and their systemd units, and creates the isochron user;\n \
             it enables nothing by itself.\n"
        ),
    )?;
    for (name, text) in [("postinst", POSTINST), ("prerm", PRERM), ("postrm", POSTRM)] {
        let path = control.join(name);
        std::fs::write(&path, text)?;
        set_mode(&path, 0o755)?;
    }
    std::fs::create_dir_all(&out)?;
    let file = out.join(format!("{PACKAGE}_{version}_{arch}.deb"));
    // xz (dpkg's default) for releases; a dev package (the tests') is large and
    // only needs to be quick to make.
    let compression: &[&str] = if release {
        &["-Zxz"]
    } else {
        &["-Zgzip", "-z1"]
    };
    run(Command::new("dpkg-deb")
        .arg("--root-owner-group")
        .args(compression)
        .arg("--build")
        .arg(&pkg)
        .arg(&file))?;
    let size = std::fs::metadata(&file)?.len();
    eprintln!(
        "xtask: {} ({:.1} MiB); install: apt install {}",
        file.display(),
        size as f64 / (1 << 20) as f64,
        file.display()
    );
    println!("next, as root:");
    println!(
        "  $EDITOR /etc/isochron/isochron.toml   # from /usr/share/doc/isochron/examples/isochron.toml"
    );
    print_enable_steps(Path::new("/usr/bin"));
    println!("{}", file.display());
    Ok(())
}

/// The workspace version (`[workspace.package] version` of the root Cargo.toml).
fn version(root: &Path) -> anyhow::Result<String> {
    let text = std::fs::read_to_string(root.join("Cargo.toml"))?;
    let mut in_package = false;
    for line in text.lines() {
        let line = line.trim();
        if line.starts_with('[') {
            in_package = line == "[workspace.package]";
        } else if in_package && let Some(v) = line.strip_prefix("version") {
            let v = v
                .trim_start()
                .trim_start_matches('=')
                .trim()
                .trim_matches('"');
            return Ok(v.to_string());
        }
    }
    bail!("Cargo.toml: no version in [workspace.package]")
}

/// The runtime libraries the binaries link, as Debian dependencies: from
/// `dpkg-shlibdeps` (package dpkg-dev) when it is installed, else OpenCV's
/// runtime packages by name, and what the postinst runs (systemd-sysusers).
fn depends(work: &Path) -> anyhow::Result<String> {
    let sysusers = "systemd | systemd-standalone-sysusers";
    let has_shlibdeps = Command::new("dpkg-shlibdeps")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    if !has_shlibdeps {
        eprintln!("xtask: dpkg-shlibdeps missing (package dpkg-dev): naming OpenCV's libraries");
        return Ok(format!(
            "libopencv-core406t64 | libopencv-core406, \
             libopencv-imgproc406t64 | libopencv-imgproc406, \
             libopencv-videoio406t64 | libopencv-videoio406, \
             libopencv-video406t64 | libopencv-video406, \
             libopencv-objdetect406t64 | libopencv-objdetect406, \
             libopencv-dnn406t64 | libopencv-dnn406, libssl3t64 | libssl3, libc6, libgcc-s1, \
             libstdc++6, {sysusers}"
        ));
    }
    std::fs::write(
        work.join("debian/control"),
        format!("Source: {PACKAGE}\n\nPackage: {PACKAGE}\nArchitecture: any\n"),
    )?;
    let mut cmd = Command::new("dpkg-shlibdeps");
    cmd.arg("-O").current_dir(work);
    for name in BINARIES {
        cmd.arg(format!("-edebian/{PACKAGE}/usr/bin/{name}"));
    }
    let line = output(&mut cmd)?;
    let shlibs = line
        .lines()
        .find_map(|l| l.strip_prefix("shlibs:Depends="))
        .with_context(|| format!("dpkg-shlibdeps printed no shlibs:Depends: {line}"))?;
    Ok(format!("{shlibs}, {sysusers}"))
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

fn set_mode(path: &Path, mode: u32) -> anyhow::Result<()> {
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(mode))
        .with_context(|| format!("chmod {mode:o} {}", path.display()))
}

/// Directories 0755, files 0644, the binaries 0755: whatever the umask and the
/// checkout's modes were.
fn normalize_modes(dir: &Path) -> anyhow::Result<()> {
    set_mode(dir, 0o755)?;
    for entry in std::fs::read_dir(dir)? {
        let path = entry?.path();
        if path.is_dir() {
            normalize_modes(&path)?;
        } else {
            let executable = path.parent().is_some_and(|p| p.ends_with("usr/bin"));
            set_mode(&path, if executable { 0o755 } else { 0o644 })?;
        }
    }
    Ok(())
}
