//! The conventions every command shares: one exit-code table for the `isochron`
//! command and the services (`crates/exit/src/lib.rs`, docs/operating.md "Exit codes").

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
