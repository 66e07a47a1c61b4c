//! `isochron up`: the group under the launcher survives a killed service.

use std::time::{Duration, Instant};

use isochron_tests::{TestSite, pid_in};

fn tap_frames(site: &TestSite, count: u32, timeout_s: u32) -> bool {
    let out = site.isochron(
        &site.tap_frames_args(count, timeout_s),
        Duration::from_secs(timeout_s as u64 + 20),
    );
    out.status.success() && out.stdout.lines().count() == count as usize
}

#[test]
fn up_restarts_a_killed_capture_and_frames_flow_again() {
    let site = TestSite::looping_vtest("up", "2");
    let mut up = site.up(&[]);
    let started = up
        .wait_for_line("up: capture/cam01 started pid=", Duration::from_secs(20))
        .expect("capture started");
    let pid = pid_in(&started);
    assert!(tap_frames(&site, 3, 20), "frames flow under up");

    // SAFETY: kill(2) on a process of this test.
    unsafe { libc::kill(pid as i32, libc::SIGKILL) };
    let killed_at = Instant::now();
    up.wait_for_line("capture/cam01 killed by signal 9", Duration::from_secs(10))
        .expect("up notices the kill");
    let restarted = up
        .wait_for_line("capture/cam01 restarted pid=", Duration::from_secs(10))
        .expect("up restarts capture");
    assert_ne!(pid_in(&restarted), pid);
    assert!(
        tap_frames(&site, 3, 20),
        "frames flow again after the restart"
    );
    println!(
        "frames flowed again {:.2} s after the kill",
        killed_at.elapsed().as_secs_f64()
    );

    up.signal(libc::SIGINT);
    let status = up
        .wait(Duration::from_secs(20))
        .expect("up stops on Ctrl-C");
    assert!(status.success(), "{}", up.stderr());
    assert!(up.stdout().contains("up: stopping"));
}
