//! Which people detector the gate runs, as a user starts it: the network `cargo
//! xtask setup` installed beside the binaries, HOG where none is installed, and a
//! clear configuration error (exit 78, the file named) for a model file that is
//! missing or broken, configured or installed. The detectors' quality is the
//! detector bench's (`cargo xtask bench detector`).

use std::path::{Path, PathBuf};
use std::time::Duration;

use isochron_tests::{Proc, TestSite, bin, eventually, repo_root};

/// The exit code of a configuration error (sysexits' EX_CONFIG).
const EX_CONFIG: i32 = 78;

/// A copy of the gate binary in `dir/bin/`, so that the network it looks for is
/// `dir/detector/ssdlite-person.pb` (installations put the binaries in `bin/`
/// and the network in `detector/` or `share/isochron/detector/` above it).
fn gate_in(dir: &Path) -> PathBuf {
    let bin_dir = dir.join("bin");
    std::fs::create_dir_all(&bin_dir).unwrap();
    let gate = bin_dir.join("isochron-gate");
    std::fs::copy(bin("isochron-gate"), &gate).expect("copying isochron-gate");
    gate
}

/// Starts `gate` on `site`'s cam01.
fn start(site: &TestSite, gate: &Path) -> Proc {
    let config = site.config_path().display().to_string();
    Proc::spawn(gate, &["--config", config.as_str(), "--camera", "cam01"])
}

/// Waits until the gate's stderr holds `text`; its stderr.
fn said(gate: &Proc, text: &str) -> String {
    eventually(Duration::from_secs(60), || {
        let err = gate.stderr();
        err.contains(text).then_some(err)
    })
    .unwrap_or_else(|| panic!("the gate never said {text:?}; it said:\n{}", gate.stderr()))
}

#[test]
fn the_gate_names_its_detector_hog_without_a_network_and_the_installed_one_with_it() {
    let dir = tempfile::tempdir().unwrap();
    let gate = gate_in(dir.path());
    let site = TestSite::with_source("detector-installed", "", "unused.avi");

    // Nothing installed beside this copy: HOG, and the line says why and where.
    let hog = start(&site, &gate);
    let err = said(&hog, "people detector: HOG");
    assert!(
        err.contains("no network installed") && err.contains(&dir.path().display().to_string()),
        "{err}"
    );
    drop(hog);

    // The network setup installed: the SSD, its file named.
    let installed = repo_root().join("target/detector/ssdlite-person.pb");
    assert!(
        installed.is_file(),
        "{} is missing: run `cargo xtask setup`",
        installed.display()
    );
    let detector_dir = dir.path().join("detector");
    std::fs::create_dir_all(&detector_dir).unwrap();
    let network = detector_dir.join("ssdlite-person.pb");
    std::fs::copy(&installed, &network).unwrap();
    let ssd = start(&site, &gate);
    let err = said(&ssd, "people detector: TensorFlow SSD");
    assert!(err.contains(&network.display().to_string()), "{err}");
    drop(ssd);

    // MoveNet and ONNX Runtime installed too: MoveNet, the default, its file and
    // the library named.
    for file in ["movenet-multipose.onnx", "libonnxruntime.so"] {
        let installed = repo_root().join("target/detector").join(file);
        std::fs::copy(&installed, detector_dir.join(file))
            .unwrap_or_else(|e| panic!("{}: {e}: run `cargo xtask setup`", installed.display()));
    }
    let movenet = start(&site, &gate);
    let err = said(&movenet, "people detector: MoveNet MultiPose");
    assert!(
        err.contains(
            &detector_dir
                .join("movenet-multipose.onnx")
                .display()
                .to_string()
        ) && err.contains("libonnxruntime.so")
            && err.contains("1 thread(s)"),
        "{err}"
    );
    drop(movenet);

    // `installed = false`: HOG although a network is there.
    let hog_site = TestSite::with_source(
        "detector-hog",
        "[gate.detector]\ninstalled = false",
        "unused.avi",
    );
    let hog = start(&hog_site, &gate);
    said(&hog, "gate.detector.installed = false");
}

#[test]
fn a_broken_network_stops_the_gate_with_a_config_error_naming_the_file() {
    // Installed but broken (a cut download, another file): no silent HOG.
    let dir = tempfile::tempdir().unwrap();
    let gate = gate_in(dir.path());
    let detector_dir = dir.path().join("detector");
    std::fs::create_dir_all(&detector_dir).unwrap();
    let network = detector_dir.join("ssdlite-person.pb");
    std::fs::write(&network, b"not a TensorFlow graph").unwrap();
    let site = TestSite::with_source("detector-broken", "", "unused.avi");
    let done = start(&site, &gate).finish(Duration::from_secs(60));
    assert_eq!(done.status.code(), Some(EX_CONFIG), "{}", done.stderr);
    assert!(
        done.stderr.contains(&network.display().to_string())
            && done.stderr.contains("cargo xtask setup"),
        "{}",
        done.stderr
    );
    assert!(!done.stderr.contains("panicked"), "{}", done.stderr);

    // MoveNet installed but broken (the SSD beside it is not run instead), with
    // the real library, without any, and with a broken one.
    let movenet = detector_dir.join("movenet-multipose.onnx");
    let library = detector_dir.join("libonnxruntime.so");
    std::fs::write(&movenet, b"not an ONNX model").unwrap();
    let real_library = repo_root().join("target/detector/libonnxruntime.so");
    for (case, lib) in [
        (
            "broken model",
            Some(std::fs::read(&real_library).expect("run `cargo xtask setup`")),
        ),
        ("no library", None),
        ("broken library", Some(b"not a library".to_vec())),
    ] {
        match lib {
            Some(bytes) => std::fs::write(&library, bytes).unwrap(),
            None => {
                let _ = std::fs::remove_file(&library);
            }
        }
        // The copy's installed dirs are `dir/detector` and
        // `dir/share/isochron/detector` only: no other library is found.
        let done = start(&site, &gate).finish(Duration::from_secs(60));
        assert_eq!(
            done.status.code(),
            Some(EX_CONFIG),
            "{case}: {}",
            done.stderr
        );
        assert!(
            done.stderr.contains(&movenet.display().to_string())
                && done.stderr.contains("cargo xtask setup"),
            "{case}: {}",
            done.stderr
        );
        assert!(!done.stderr.contains("panicked"), "{case}: {}", done.stderr);
    }
    std::fs::remove_file(&movenet).unwrap();

    // Configured: a truncated copy of the real network, and a missing file.
    let installed = repo_root().join("target/detector/ssdlite-person.pb");
    let bytes = std::fs::read(&installed).expect("the installed network: run `cargo xtask setup`");
    let cut = dir.path().join("cut.pb");
    std::fs::write(&cut, &bytes[..bytes.len() / 3]).unwrap();
    for (name, model) in [
        ("detector-cut", cut.clone()),
        ("detector-missing", dir.path().join("missing.pb")),
    ] {
        let site = TestSite::with_source(
            name,
            &format!("[gate.detector]\nmodel = \"{}\"", model.display()),
            "unused.avi",
        );
        let (code, stderr) = site.exit_of("isochron-gate", Duration::from_secs(60));
        assert_eq!(code, Some(EX_CONFIG), "{name}: {stderr}");
        assert!(
            stderr.contains(&model.display().to_string()),
            "{name}: {stderr}"
        );
        assert!(!stderr.contains("panicked"), "{name}: {stderr}");
    }
}
