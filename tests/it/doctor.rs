//! `isochron doctor`: it reports without changing anything, and repairs only with
//! `--fix`; it checks the detector model, the robots' map and the disk; `--json`
//! prints one object per check.
//!
//! iceoryx2 removes the stale resources of every dead node whenever any node is
//! created or dropped on the machine, so a stale node left by a `kill -9` lives
//! only until the next node of any test comes or goes. The tests of this module
//! take turns (a lock) so that they do not clean each other's; a test of another
//! module running at the same moment still can, and then the stale-node test says
//! so instead of blaming doctor.

use std::sync::Mutex;
use std::time::Duration;

use isochron_shared::ipc::{NodeCensus, node_census};
use isochron_tests::{Finished, TestSite, eventually};

/// Held by each test of this module (see the module's comment).
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

fn doctor(site: &TestSite, options: &[&str]) -> Finished {
    let config = site.config_path().display().to_string();
    let mut args = vec!["doctor", "--config", config.as_str()];
    args.extend(options);
    site.isochron(&args, Duration::from_secs(60))
}

/// The nodes of `site` (named `<prefix>/...`) in `names`.
fn ours<'a>(site: &TestSite, names: &'a [String]) -> Vec<&'a String> {
    let prefix = format!("{}/", site.prefix);
    names.iter().filter(|n| n.starts_with(&prefix)).collect()
}

fn census() -> NodeCensus {
    // Listing only (no node of ours, nothing removed).
    node_census(false).expect("iceoryx2 nodes can be listed")
}

/// The lines of `--json` output, parsed; each must be a check object.
fn json_checks(out: &Finished) -> Vec<serde_json::Value> {
    out.stdout
        .lines()
        .map(|line| {
            let v: serde_json::Value = serde_json::from_str(line)
                .unwrap_or_else(|e| panic!("not a JSON line ({e}): {line}\n{}", out.stdout));
            assert!(v["check"].is_string(), "no check name: {line}");
            assert!(
                matches!(v["status"].as_str(), Some("ok" | "warn" | "fail")),
                "bad status: {line}"
            );
            assert!(v["detail"].is_string(), "no detail: {line}");
            v
        })
        .collect()
}

#[test]
fn a_stale_node_is_only_reported_without_fix_and_removed_with_it() {
    let _turn = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let site = TestSite::with_source("doctor-stale", "", "unused.avi");
    let mut motion = site.spawn("isochron-motion", &["--camera", "cam01"]);
    let node = eventually(Duration::from_secs(20), || {
        ours(&site, &census().alive).first().map(|n| n.to_string())
    })
    .unwrap_or_else(|| panic!("motion made no node\n{}", motion.stderr()));
    motion.signal(libc::SIGKILL);
    motion
        .wait(Duration::from_secs(10))
        .expect("motion dies on SIGKILL");
    let stale = |c: &NodeCensus| ours(&site, &c.dead_left).contains(&&node);
    assert!(
        stale(&census()),
        "{node} was cleaned before doctor ran (by a node of another test); run this test alone"
    );

    let out = doctor(&site, &[]);
    let after = census();
    assert!(
        stale(&after),
        "doctor without --fix removed the stale node {node}\nstdout:\n{}\nstderr:\n{}",
        out.stdout,
        out.stderr
    );
    assert!(
        out.stdout
            .lines()
            .any(|l| l.starts_with("warn stale resources:")
                && l.contains(&node)
                && l.contains("--fix would remove")),
        "doctor does not say what --fix would remove:\n{}",
        out.stdout
    );
    assert!(
        out.stdout
            .contains("services: skipped: creating a node would remove"),
        "doctor does not say it skipped the node checks:\n{}",
        out.stdout
    );

    let fixed = doctor(&site, &["--fix"]);
    assert!(
        fixed
            .stdout
            .lines()
            .any(|l| l.starts_with("ok   stale resources: removed") && l.contains(&node)),
        "doctor --fix does not say it removed {node}:\n{}\nstderr:\n{}",
        fixed.stdout,
        fixed.stderr
    );
    let after = census();
    assert!(
        !stale(&after) && !ours(&site, &after.alive).contains(&&node),
        "{node} is still there after doctor --fix: {after:?}"
    );
    assert!(
        fixed.stdout.contains("services: 0 of"),
        "with --fix doctor checks the services:\n{}",
        fixed.stdout
    );
}

#[test]
fn a_missing_model_and_a_missing_map_image_fail_naming_the_paths() {
    let _turn = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let site = TestSite::with_source("doctor-files", "", "video.avi");
    std::fs::write(site.path("video.avi"), b"").unwrap();
    std::fs::write(
        site.path("floor.yaml"),
        "image: floor.pgm\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\n",
    )
    .unwrap();
    site.write_config(
        "[gate.detector]\nmodel = \"models/yolo.onnx\"\n\n[costmap]\nmap_yaml = \"floor.yaml\"\n\n\
         [[camera]]\nid = \"cam01\"\nsource = \"video.avi\"\n",
    );
    let out = doctor(&site, &[]);
    assert_eq!(out.status.code(), Some(1), "{}", out.stdout);
    let model = site.path("models/yolo.onnx").display().to_string();
    let image = site.path("floor.pgm").display().to_string();
    assert!(
        out.stdout
            .lines()
            .any(|l| l.starts_with("FAIL detector model:")
                && l.contains("gate.detector.model")
                && l.contains(&model)),
        "the missing model is not reported as a failure naming {model}:\n{}",
        out.stdout
    );
    assert!(
        out.stdout.lines().any(|l| l.starts_with("FAIL map:")
            && l.contains("costmap.map_yaml")
            && l.contains(&image)),
        "the missing map image is not reported as a failure naming {image}:\n{}",
        out.stdout
    );

    // With both in place the same checks pass.
    std::fs::create_dir(site.path("models")).unwrap();
    std::fs::write(site.path("models/yolo.onnx"), b"not really onnx").unwrap();
    std::fs::write(site.path("floor.pgm"), b"P5\n4 3\n255\n............").unwrap();
    let out = doctor(&site, &[]);
    for check in ["detector model", "map"] {
        assert!(
            out.stdout
                .lines()
                .any(|l| l.starts_with(&format!("ok   {check}:"))),
            "{check} is not ok once its file exists:\n{}",
            out.stdout
        );
    }
    assert!(
        out.stdout.contains("ok   map:") && out.stdout.contains("4x3 cells"),
        "{}",
        out.stdout
    );
}

#[test]
fn json_prints_one_object_per_check_with_the_text_checks() {
    let _turn = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let site = TestSite::with_source("doctor-json", "", "missing.avi");
    let text = doctor(&site, &[]);
    let json = doctor(&site, &["--json"]);
    assert_eq!(json.status.code(), Some(1), "a missing video fails");
    assert_eq!(json.status.code(), text.status.code());
    let checks = json_checks(&json);
    let names: Vec<&str> = checks
        .iter()
        .map(|v| v["check"].as_str().unwrap())
        .collect();
    let text_names: Vec<&str> = text
        .stdout
        .lines()
        .map(|l| l[5..].split(": ").next().unwrap())
        .collect();
    assert_eq!(
        names, text_names,
        "text:\n{}\njson:\n{}",
        text.stdout, json.stdout
    );
    for check in [
        "config",
        "disk",
        "state dir",
        "detector model",
        "map",
        "services",
    ] {
        assert!(names.contains(&check), "no {check} check: {names:?}");
    }
    let camera = checks
        .iter()
        .find(|v| v["check"] == "camera cam01")
        .expect("a camera check");
    assert_eq!(camera["status"], "fail");
    assert!(
        camera["detail"]
            .as_str()
            .unwrap()
            .contains(&site.path("missing.avi").display().to_string()),
        "{camera}"
    );
    let disk = checks.iter().find(|v| v["check"] == "disk").unwrap();
    assert!(
        disk["detail"].as_str().unwrap().contains("MiB free"),
        "{disk}"
    );
}
