//! The conventions every command shares: one exit-code table for the `isochron`
//! command and the services (`shared/exit/src/lib.rs`, docs/operating.md "Exit codes").

use std::time::Duration;

use isochron_tests::TestSite;

#[test]
fn a_config_error_is_78_in_the_command_as_in_the_services() {
    let site = TestSite::with_source("conv-config", "[motion]\nblock_px = -3", "unused.avi");
    let config = site.config_path().display().to_string();
    let status = site.isochron(&["status", "--config", &config], Duration::from_secs(30));
    assert_eq!(status.status.code(), Some(78), "{}", status.stderr);
    assert_eq!(status.stderr.lines().count(), 1, "{}", status.stderr);
    assert!(status.stderr.contains("site.toml:"), "{}", status.stderr);
    let service = site
        .spawn("isochron-motion", &["--camera", "cam01"])
        .finish(Duration::from_secs(30));
    assert_eq!(service.status.code(), Some(78), "{}", service.stderr);
}

#[test]
fn tap_timing_out_is_75_and_status_of_a_stopped_group_is_3() {
    let site = TestSite::with_source("conv-codes", "", "unused.avi");
    let tap = site.isochron(&site.tap_frames_args(1, 1), Duration::from_secs(30));
    assert_eq!(tap.status.code(), Some(75), "{}", tap.stderr);
    assert!(tap.stderr.contains("timeout after"), "{}", tap.stderr);
    let config = site.config_path().display().to_string();
    let status = site.isochron(&["status", "--config", &config], Duration::from_secs(30));
    assert_eq!(status.status.code(), Some(3), "{}", status.stdout);
    assert!(status.stdout.contains("not running"), "{}", status.stdout);
}

/// The stage table is the one place a stage is declared: every service binary
/// of the workspace has a row, every row's binary is built by a crate of the
/// workspace, and every row's systemd unit is in `systemd/`, which has no
/// service unit without a row.
#[test]
fn every_service_binary_and_unit_has_a_row_of_the_stage_table_and_every_row_both() {
    use isochron_runtime::topology::StageKind;
    let root = isochron_tests::repo_root();
    let metadata = std::process::Command::new(env!("CARGO"))
        .args([
            "metadata",
            "--no-deps",
            "--offline",
            "--format-version",
            "1",
        ])
        .current_dir(&root)
        .output()
        .expect("cargo metadata");
    assert!(
        metadata.status.success(),
        "{}",
        String::from_utf8_lossy(&metadata.stderr)
    );
    let metadata: serde_json::Value = serde_json::from_slice(&metadata.stdout).unwrap();
    let mut bins: Vec<String> = metadata["packages"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|p| p["targets"].as_array().unwrap().iter())
        .filter(|t| t["kind"].as_array().unwrap().iter().any(|k| k == "bin"))
        .map(|t| t["name"].as_str().unwrap().to_string())
        .filter(|name| name.starts_with("isochron-"))
        .collect();
    bins.sort();
    let mut rows: Vec<String> = StageKind::services()
        .map(|s| s.binary().to_string())
        .collect();
    rows.sort();
    assert_eq!(
        bins, rows,
        "service binaries of the workspace vs rows of the stage table"
    );

    let mut units: Vec<String> = std::fs::read_dir(root.join("systemd"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|name| name.ends_with(".service"))
        .collect();
    units.sort();
    let mut row_units: Vec<String> = StageKind::all()
        .filter_map(|s| s.spec().unit.map(String::from))
        .collect();
    row_units.sort();
    assert_eq!(
        units, row_units,
        "units in systemd/ vs rows of the stage table"
    );
}
