//! `isochron doctor`: it reports without changing anything, and repairs only with
//! `--fix`; it checks the detector model, the robots' map and the disk; `--json`
//! prints one object per check.
//!
//! iceoryx2 removes the stale resources of every dead node whenever any node is
//! created or dropped in its world (root path and prefix), so the stale-node test
//! runs its processes in a private world of their own
//! ([`isochron_tests::TestSite::private_iceoryx2`]): no other test can clean up
//! the node it left.

use std::time::Duration;

use isochron_tests::{Finished, Proc, TestSite, bin, eventually};

fn doctor(site: &TestSite, options: &[&str]) -> Finished {
    let config = site.config_path().display().to_string();
    let mut args = vec!["doctor", "--config", config.as_str()];
    args.extend(options);
    site.isochron(&args, Duration::from_secs(60))
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
    // Its own iceoryx2 world (root path and prefix), so that no node of another
    // test, created or dropped meanwhile, cleans the stale node up.
    let site = TestSite::with_source("doctor-stale", "", "unused.avi");
    let world = site.private_iceoryx2();
    let config = site.config_path().display().to_string();
    let run = |options: &[&str]| {
        let mut args = vec!["doctor", "--config", config.as_str()];
        args.extend(options);
        let mut p = Proc::spawn_in(&bin("isochron"), &args, Some(&world));
        p.finish(Duration::from_secs(60))
    };
    let mut motion = Proc::spawn_in(
        &bin("isochron-motion"),
        &["--config", config.as_str(), "--camera", "cam01"],
        Some(&world),
    );
    // Its first status report comes after its status service exists: a kill
    // before would leave a service half created, which no doctor can open.
    assert!(
        motion.wait_for_stderr("latency_ms=", Duration::from_secs(20)),
        "{}",
        motion.stderr()
    );
    motion.signal(libc::SIGKILL);
    motion
        .wait(Duration::from_secs(10))
        .expect("motion dies on SIGKILL");
    let node = format!("{}/motion/cam01", site.prefix);
    let reports_stale = |out: &Finished| {
        out.stdout.lines().any(|l| {
            l.starts_with("warn stale resources:")
                && l.contains(&node)
                && l.contains("--fix would remove")
        })
    };

    // Twice without --fix: the second still finds it (the first removed nothing).
    for attempt in 0..2 {
        let out = run(&[]);
        assert!(
            reports_stale(&out),
            "doctor (run {attempt}) does not report the stale {node} and what --fix would remove:\n{}\nstderr:\n{}",
            out.stdout,
            out.stderr
        );
        assert!(
            out.stdout
                .contains("services: skipped: creating a node would remove"),
            "doctor does not say it skipped the node checks:\n{}",
            out.stdout
        );
    }

    let fixed = run(&["--fix"]);
    assert!(
        fixed
            .stdout
            .lines()
            .any(|l| l.starts_with("ok   stale resources: removed") && l.contains(&node)),
        "doctor --fix does not say it removed {node}:\n{}\nstderr:\n{}",
        fixed.stdout,
        fixed.stderr
    );
    assert!(
        fixed.stdout.contains("services: 0 of"),
        "with --fix doctor checks the services:\n{}",
        fixed.stdout
    );
    let after = run(&[]);
    assert!(
        !after.stdout.contains(&node),
        "{node} is still there after doctor --fix:\n{}",
        after.stdout
    );
}

#[test]
fn a_missing_model_and_a_missing_map_image_fail_naming_the_paths() {
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

#[test]
fn sigterm_stops_doctor_on_a_huge_site_and_leaves_no_shared_memory() {
    // 3 000 cameras: doctor opens a status reader per camera and stage, which takes
    // longer than the SIGTERM comes.
    let cameras: String = (0..3000)
        .map(|i| format!("[[camera]]\nid = \"c{i:05}\"\nsource = \"synthetic\"\n\n"))
        .collect();
    let site = TestSite::new("doctor-huge", &cameras);
    let world = site.private_iceoryx2();
    let text = std::fs::read_to_string(world.join("config/iceoryx2.toml")).unwrap();
    let prefix = text
        .lines()
        .find(|l| l.starts_with("prefix"))
        .and_then(|l| l.split('"').nth(1))
        .unwrap()
        .to_string();
    let config = site.config_path().display().to_string();
    let mut p = Proc::spawn_in(
        &bin("isochron"),
        &["doctor", "--config", config.as_str()],
        Some(&world),
    );
    let ours = |prefix: &str| -> Vec<String> {
        std::fs::read_dir("/dev/shm")
            .unwrap()
            .filter_map(Result::ok)
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n.starts_with(prefix) && !n.ends_with(".global_mgmt"))
            .collect()
    };
    // SIGTERM once doctor is opening its status readers (their shared memory
    // shows), not after a fixed time that a loaded machine may not have reached.
    let opening = eventually(Duration::from_secs(60), || {
        (!ours(&prefix).is_empty()).then_some(())
    });
    assert!(
        opening.is_some(),
        "doctor opened no status reader in 60 s\n{}",
        p.stderr()
    );
    p.signal(libc::SIGTERM);
    let status = p.wait(Duration::from_secs(10));
    assert!(status.is_some(), "doctor ignores SIGTERM\n{}", p.stderr());
    assert!(p.stderr().contains("interrupted"), "{}", p.stderr());
    let left = ours(&prefix);
    assert!(
        left.is_empty(),
        "{} files left: {:?}",
        left.len(),
        &left[..left.len().min(5)]
    );
}

/// Doctor names the detector the gate will load, by the gate's own rule: on a
/// checkout after `cargo xtask setup`, the demo's MoveNet beside the binaries.
#[test]
fn doctor_names_the_detector_the_gate_loads() {
    let site = TestSite::with_source("doctor-detector", "", "unused.avi");
    let installed = isochron_tests::repo_root().join("target/detector/movenet-multipose.onnx");
    let out = doctor(&site, &[]);
    let line = out
        .stdout
        .lines()
        .find(|l| l[5..].starts_with("detector model:"))
        .unwrap_or_else(|| panic!("no detector line:\n{}", out.stdout));
    if installed.is_file() {
        assert!(
            line.starts_with("ok   ")
                && line.contains("MoveNet MultiPose")
                && line.contains("installed"),
            "{line}"
        );
    } else {
        assert!(line.contains("HOG"), "{line}");
    }
    site.write_config("[gate.detector]\ninstalled = false\n\n[[camera]]\nid = \"cam01\"\nsource = \"unused.avi\"\n");
    let out = doctor(&site, &[]);
    assert!(
        out.stdout
            .lines()
            .any(|l| l.starts_with("ok   detector model: HOG") && l.contains("installed = false")),
        "{}",
        out.stdout
    );
}

/// Doctor says what the services refuse or warn about at load, with their own
/// checks: a broker URL the MQTT sink refuses (it would exit 78), a cost cap the
/// bridge warns about.
#[test]
fn doctor_fails_what_the_services_refuse_and_warns_what_they_warn() {
    let site = TestSite::with_source("doctor-load-checks", "", "unused.avi");
    site.write_config(
        "[mqtt]\nbroker = \"tcp://1.2.3.4\"\n\n[costmap]\ncap = 99\n\n\
         [[camera]]\nid = \"cam01\"\nsource = \"unused.avi\"\n",
    );
    let out = doctor(&site, &[]);
    assert_eq!(out.status.code(), Some(1), "{}", out.stdout);
    assert!(
        out.stdout
            .lines()
            .any(|l| l.starts_with("FAIL mqtt:") && l.contains("mqtt.broker") && l.contains("78")),
        "{}",
        out.stdout
    );
    assert!(
        out.stdout
            .lines()
            .any(|l| l.starts_with("warn config:") && l.contains("costmap.cap")),
        "{}",
        out.stdout
    );
}

/// What the services would meet at run time, checked with their own rules: a
/// zone wholly outside the frame (the gate warns it never raises events), a
/// state directory that cannot be made (under a regular file, under /proc), a
/// store of a daily model under a `day_types` config (the cascade refuses it).
#[test]
fn doctor_checks_zones_the_state_dir_and_the_store_s_cycle_as_the_services_do() {
    let site = TestSite::new("doctor-zones", "");
    let video = isochron_tests::vtest().display().to_string();
    let camera = format!(
        "[[camera]]\nid = \"cam01\"\nsource = \"{video}\"\n\
         [[camera.zone]]\nname = \"door\"\npolygon = [[10, 10], [200, 10], [200, 200]]\n\
         [[camera.zone]]\nname = \"beyond\"\npolygon = [[5000, 5000], [6000, 5000], [6000, 6000]]\n"
    );
    let line = |out: &Finished, start: &str, words: &[&str]| {
        assert!(
            out.stdout
                .lines()
                .any(|l| l.starts_with(start) && words.iter().all(|w| l.contains(w))),
            "no '{start}' line with {words:?} in\n{}",
            out.stdout
        );
    };
    site.write_config(&camera);
    let out = doctor(&site, &[]);
    line(
        &out,
        "warn zones cam01:",
        &["beyond cover no block centre", "768x576"],
    );

    std::fs::write(site.path("a-file"), b"").unwrap();
    for state_dir in [
        site.path("a-file").join("state"),
        "/proc/isochron-state".into(),
    ] {
        let config = std::fs::read_to_string(site.config_path()).unwrap();
        let config = config.replace(
            "state_dir = \"state\"",
            &format!("state_dir = \"{}\"", state_dir.display()),
        );
        std::fs::write(site.config_path(), config).unwrap();
        let out = doctor(&site, &[]);
        assert_eq!(out.status.code(), Some(1), "{}", out.stdout);
        line(&out, "FAIL state dir:", &["cannot be created"]);
        site.write_config(&camera);
    }

    // A daily store, then the site switched to day types.
    let state = site.path("state");
    std::fs::create_dir_all(&state).unwrap();
    let meta = isochron_store::StoreMeta::new(
        "cam01",
        isochron_wire::geometry::BlockGrid::new(768, 576, 16),
        isochron_config::clock::Cycle::Daily,
        0,
    );
    drop(
        isochron_store::Store::open_or_create(&isochron_store::store_path(&state, "cam01"), &meta)
            .unwrap(),
    );
    site.write_config(&format!("[cascade]\ncycle = \"day_types\"\n\n{camera}"));
    let out = doctor(&site, &[]);
    assert_eq!(out.status.code(), Some(1), "{}", out.stdout);
    line(&out, "FAIL store cam01:", &["day_types", "daily"]);
}
