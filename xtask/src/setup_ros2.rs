//! `cargo xtask setup --all`'s real ROS 2 test peers: rclpy Jazzy and rclpy Kilted, each
//! with rmw_fastrtps_cpp, from third-party manylinux wheels on PyPI, one venv per
//! release (`target/rclpy-jazzy`, `target/rclpy-kilted`; the wheels of both
//! releases share distribution names such as `ros-rclpy`), and the message
//! packages those wheels lack generated into each venv with the wheels' own
//! rosidl and ament_cmake ([`MSG_PACKAGES`]).
//!
//! Each venv is a ROS 2 install prefix (`share/<pkg>/cmake`, `lib/`); the wheels'
//! `ros_wheels_bootstrapper` puts its `lib/` on `LD_LIBRARY_PATH` when Python
//! starts, so the packages built into the same prefix load without sourcing
//! anything. The wheels' CMake exports name the Python of the machine that built
//! them (`/opt/python/cp311-cp311/...`): [`rewrite_builder_paths`] points them at
//! this venv's Python headers and NumPy before anything is generated.
//!
//! Fast when nothing changed: `wheels.stamp` (a hash of the pinned list) skips
//! pip, `msgs.stamp` (that and a hash of the message sources) skips the build.

use std::hash::{DefaultHasher, Hash, Hasher};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{Context, bail};

use crate::output;

/// Installs Debian packages (`setup`'s apt-get).
type AptInstall = fn(&[&str]) -> anyhow::Result<()>;

/// The ROS 2 releases of the rclpy peers; `tests/ros2/rclpy/<release>.txt` pins
/// every distribution of its venv.
pub(crate) const RELEASES: [&str; 2] = ["jazzy", "kilted"];

/// The message packages generated into each venv, in build order: `map_msgs`
/// (ros-planning/navigation_msgs 2.4.0, verbatim: no wheel carries it), the one
/// message of `nav2_msgs` the bridge publishes (no wheel either), and
/// isochron's own services from `ros/`.
const MSG_PACKAGES: [(&str, &str); 3] = [
    ("map_msgs", "tests/ros2/rclpy/map_msgs"),
    ("nav2_msgs", "tests/ros2/rclpy/nav2_msgs"),
    ("isochron_msgs", "ros/isochron_msgs"),
];

/// The generated packages' CMake build type: none, so no optimisation — the
/// typesupport code of a test peer needs none, and building it takes a quarter
/// of the time `Release` does (isochron_msgs on 2 cores: 35 s against 140 s).
/// Part of `msgs.stamp`: a change rebuilds them.
const BUILD_TYPE: &str = "-DCMAKE_BUILD_TYPE=";

/// What a venv must import once it is ready.
const READY: &str = "import rclpy, nav_msgs.msg, geometry_msgs.msg, visualization_msgs.msg, \
                     map_msgs.msg, nav2_msgs.msg, isochron_msgs.srv";

/// Makes (or checks) the venv of every release in [`RELEASES`]; `apt_install`
/// brings cmake (and Debian's Python headers) when they are missing.
pub(crate) fn rclpy_venvs(root: &Path, apt_install: AptInstall) -> anyhow::Result<()> {
    for release in RELEASES {
        rclpy_venv(root, release, apt_install)?;
    }
    Ok(())
}

fn rclpy_venv(root: &Path, release: &str, apt_install: AptInstall) -> anyhow::Result<()> {
    let venv = root.join(format!("target/rclpy-{release}"));
    let python = venv.join("bin/python3");
    let pins_path = root.join(format!("tests/ros2/rclpy/{release}.txt"));
    let pins =
        std::fs::read(&pins_path).with_context(|| format!("reading {}", pins_path.display()))?;
    let wheels = stamp_of(&[&pins]);
    let mut sources = vec![pins.clone(), BUILD_TYPE.as_bytes().to_vec()];
    for (_, dir) in MSG_PACKAGES {
        sources.extend(files_of(&root.join(dir))?);
    }
    let msgs = stamp_of(&sources.iter().map(Vec::as_slice).collect::<Vec<_>>());
    let (wheels_stamp, msgs_stamp) = (venv.join("wheels.stamp"), venv.join("msgs.stamp"));
    let current = |path: &Path, want: &str| {
        python.is_file() && std::fs::read_to_string(path).is_ok_and(|s| s == want)
    };
    if current(&msgs_stamp, &msgs) {
        return Ok(());
    }
    let t0 = Instant::now();
    if !current(&wheels_stamp, &wheels) {
        eprintln!(
            "xtask: making {} (rclpy {release} and rosidl from PyPI, pinned in {})",
            venv.display(),
            pins_path.display()
        );
        let _ = std::fs::remove_dir_all(&venv);
        quiet(
            Command::new("python3").arg("-m").arg("venv").arg(&venv),
            &root.join(format!("target/rclpy-build/{release}/venv.log")),
        )?;
        // Every distribution is pinned; --no-deps keeps pip from adding any
        // other. empy is published as source only, so binaries are preferred,
        // not required.
        quiet(
            Command::new(&python)
                .args(["-m", "pip", "install", "--no-deps", "--prefer-binary", "-r"])
                .arg(&pins_path),
            &venv.join("pip.log"),
        )?;
        rewrite_builder_paths(&venv, &python, apt_install)?;
        std::fs::write(&wheels_stamp, &wheels)?;
    }
    if !has_cmake() {
        apt_install(&["cmake"])?;
    }
    let _ = std::fs::remove_file(&msgs_stamp);
    for (name, dir) in MSG_PACKAGES {
        build_msgs(root, &venv, release, name, &root.join(dir))?;
    }
    quiet(
        Command::new(&python).args(["-c", READY]),
        &venv.join("ready.log"),
    )?;
    std::fs::write(&msgs_stamp, &msgs)?;
    eprintln!(
        "xtask: {} ready in {:.0} s",
        venv.display(),
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Makes (or checks) `target/zenoh-peer`: the robot on rmw_zenoh of
/// `tests/it/zenoh.rs`, zenoh-ros2-sdk and eclipse-zenoh from PyPI with every
/// distribution pinned in `tests/zenoh/requirements.txt` (33 MB of wheels, no
/// build). Its `.msg` and `.srv` files come from the Jazzy venv's `share/`.
pub(crate) fn zenoh_peer(root: &Path) -> anyhow::Result<()> {
    let venv = root.join("target/zenoh-peer");
    let python = venv.join("bin/python3");
    let pins_path = root.join("tests/zenoh/requirements.txt");
    let pins =
        std::fs::read(&pins_path).with_context(|| format!("reading {}", pins_path.display()))?;
    let stamp = venv.join("wheels.stamp");
    let want = stamp_of(&[&pins]);
    if python.is_file() && std::fs::read_to_string(&stamp).is_ok_and(|s| s == want) {
        return Ok(());
    }
    eprintln!(
        "xtask: making {} (zenoh-ros2-sdk and eclipse-zenoh from PyPI, pinned in {})",
        venv.display(),
        pins_path.display()
    );
    let _ = std::fs::remove_dir_all(&venv);
    quiet(
        Command::new("python3").arg("-m").arg("venv").arg(&venv),
        &root.join("target/zenoh-peer.venv.log"),
    )?;
    quiet(
        Command::new(&python)
            .args([
                "-m",
                "pip",
                "install",
                "--no-deps",
                "--only-binary=:all:",
                "-r",
            ])
            .arg(&pins_path),
        &venv.join("pip.log"),
    )?;
    quiet(
        Command::new(&python).args(["-c", "import zenoh, zenoh.ext, zenoh_ros2_sdk"]),
        &venv.join("ready.log"),
    )?;
    std::fs::write(&stamp, want)?;
    Ok(())
}

/// A hex hash of `parts`, in order.
fn stamp_of(parts: &[&[u8]]) -> String {
    let mut hasher = DefaultHasher::new();
    for p in parts {
        p.hash(&mut hasher);
    }
    format!("{:016x}\n", hasher.finish())
}

/// The relative paths and contents of the files under `dir`, sorted by path.
fn files_of(dir: &Path) -> anyhow::Result<Vec<Vec<u8>>> {
    let mut paths = Vec::new();
    let mut todo = vec![dir.to_path_buf()];
    while let Some(d) = todo.pop() {
        for entry in std::fs::read_dir(&d).with_context(|| format!("reading {}", d.display()))? {
            let path = entry?.path();
            if path.is_dir() {
                todo.push(path);
            } else {
                paths.push(path);
            }
        }
    }
    paths.sort();
    let mut out = Vec::new();
    for path in paths {
        let rel = path.strip_prefix(dir).unwrap_or(&path);
        out.push(rel.display().to_string().into_bytes());
        out.push(std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?);
    }
    Ok(out)
}

fn has_cmake() -> bool {
    Command::new("cmake")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success())
}

/// Runs `cmd` with its output in `log`; on failure, fails with the log's tail.
fn quiet(cmd: &mut Command, log: &Path) -> anyhow::Result<()> {
    let shown = format!("{cmd:?}");
    eprintln!("xtask: {shown}");
    if let Some(dir) = log.parent() {
        std::fs::create_dir_all(dir)?;
    }
    let file = std::fs::File::create(log).with_context(|| format!("creating {}", log.display()))?;
    let status = cmd
        .stdout(file.try_clone()?)
        .stderr(file)
        .status()
        .with_context(|| format!("starting {shown}"))?;
    if !status.success() {
        let text = std::fs::read_to_string(log).unwrap_or_default();
        let lines: Vec<&str> = text.lines().collect();
        let tail = lines[lines.len().saturating_sub(30)..].join("\n");
        bail!(
            "{shown} failed ({status}); the end of {}:\n{tail}",
            log.display()
        );
    }
    Ok(())
}

/// Points the wheels' CMake exports at this venv: the include directories of
/// their Python typesupport targets name the wheel builder's interpreter
/// (`/opt/python/cpXY-cpXY/include/pythonX.Y` and its NumPy), which CMake refuses
/// when they do not exist.
fn rewrite_builder_paths(
    venv: &Path,
    python: &Path,
    apt_install: AptInstall,
) -> anyhow::Result<()> {
    let paths = output(Command::new(python).args([
        "-c",
        "import sysconfig, numpy; print(sysconfig.get_paths()['include']); print(numpy.get_include())",
    ]))?;
    let mut lines = paths.lines();
    let (Some(include), Some(numpy)) = (lines.next(), lines.next()) else {
        bail!("{} did not name its include directories", python.display());
    };
    if !Path::new(include).join("Python.h").is_file() {
        // Debian's python3 keeps its headers in python3-dev.
        apt_install(&["python3-dev"])?;
        if !Path::new(include).join("Python.h").is_file() {
            bail!(
                "{include}/Python.h is missing: the message packages' Python bindings need the \
                 headers of the Python that made {} (install its development package)",
                venv.display()
            );
        }
    }
    let share = venv.join("share");
    for package in
        std::fs::read_dir(&share).with_context(|| format!("reading {}", share.display()))?
    {
        let cmake = package?.path().join("cmake");
        let Ok(files) = std::fs::read_dir(&cmake) else {
            continue;
        };
        for file in files {
            let path = file?.path();
            if path.extension().is_none_or(|e| e != "cmake") {
                continue;
            }
            let text = std::fs::read_to_string(&path)
                .with_context(|| format!("reading {}", path.display()))?;
            if let Some(new) = builder_paths_replaced(&text, include, numpy) {
                std::fs::write(&path, new)
                    .with_context(|| format!("writing {}", path.display()))?;
            }
        }
    }
    Ok(())
}

/// The wheel builder's interpreter prefix in the exports.
const BUILDER_PYTHON: &str = "/opt/python/";

/// `text` with every path under [`BUILDER_PYTHON`] replaced: a NumPy include
/// directory by `numpy`, a Python include directory by `include`; `None` if
/// there is none.
fn builder_paths_replaced(text: &str, include: &str, numpy: &str) -> Option<String> {
    if !text.contains(BUILDER_PYTHON) {
        return None;
    }
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while let Some(at) = rest.find(BUILDER_PYTHON) {
        out.push_str(&rest[..at]);
        let tail = &rest[at..];
        let end = tail
            .find(|c: char| c == '"' || c == ';' || c == ')' || c.is_whitespace())
            .unwrap_or(tail.len());
        let path = &tail[..end];
        if path.contains("/site-packages/numpy/") {
            out.push_str(numpy);
        } else if path.contains("/include/python") {
            out.push_str(include);
        } else {
            out.push_str(path);
        }
        rest = &tail[end..];
    }
    out.push_str(rest);
    Some(out)
}

/// Generates the message package `name` from `src` with the venv's rosidl and
/// installs it into the venv; the build tree is `target/rclpy-build/<release>/`.
fn build_msgs(
    root: &Path,
    venv: &Path,
    release: &str,
    name: &str,
    src: &Path,
) -> anyhow::Result<()> {
    let build: PathBuf = root.join(format!("target/rclpy-build/{release}/{name}"));
    let _ = std::fs::remove_dir_all(&build);
    std::fs::create_dir_all(&build)?;
    let jobs = std::thread::available_parallelism().map_or(2, |n| n.get());
    let env = |cmd: &mut Command| {
        cmd.env("CMAKE_PREFIX_PATH", venv)
            .env("AMENT_PREFIX_PATH", venv)
            .env_remove("CMAKE_INSTALL_PREFIX");
    };
    let mut configure = Command::new("cmake");
    configure
        .arg("-S")
        .arg(src)
        .arg("-B")
        .arg(&build)
        .arg(format!("-DCMAKE_INSTALL_PREFIX={}", venv.display()))
        .arg(format!(
            "-DPython3_EXECUTABLE={}",
            venv.join("bin/python3").display()
        ))
        .args(["-DBUILD_TESTING=OFF", BUILD_TYPE]);
    env(&mut configure);
    quiet(&mut configure, &build.join("configure.log"))?;
    let mut make = Command::new("cmake");
    make.arg("--build")
        .arg(&build)
        .args(["--parallel", &jobs.to_string()]);
    env(&mut make);
    quiet(&mut make, &build.join("build.log"))?;
    let mut install = Command::new("cmake");
    install.arg("--install").arg(&build);
    env(&mut install);
    quiet(&mut install, &build.join("install.log"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_builders_python_paths_are_replaced() {
        let text = r#"INTERFACE_INCLUDE_DIRECTORIES "/opt/python/cp311-cp311/include/python3.11;/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include""#;
        let new = builder_paths_replaced(text, "/py/include", "/venv/numpy/include").unwrap();
        assert_eq!(
            new,
            r#"INTERFACE_INCLUDE_DIRECTORIES "/py/include;/venv/numpy/include""#
        );
        assert_eq!(builder_paths_replaced("set(x 1)", "/a", "/b"), None);
    }
}
