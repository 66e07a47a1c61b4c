//! `isochron up`: the group under the launcher survives a killed service.

use std::time::{Duration, Instant};

use isochron_tests::{TestSite, named_thread, pid_in};

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

/// Binds a stand-in journal at journald's socket when none exists (as root), so
/// that a process logging to "the journal" really can, and drains it until the
/// returned guard is dropped. With a real journald, nothing is done.
struct StandInJournal {
    path: Option<std::path::PathBuf>,
    made_dir: bool,
}

impl StandInJournal {
    fn bind() -> StandInJournal {
        let path = std::path::Path::new("/run/systemd/journal/socket");
        let none = StandInJournal {
            path: None,
            made_dir: false,
        };
        let made_dir = !path.parent().unwrap().exists();
        if path.exists() || std::fs::create_dir_all(path.parent().unwrap()).is_err() {
            return none;
        }
        let Ok(socket) = std::os::unix::net::UnixDatagram::bind(path) else {
            return none;
        };
        named_thread("notify-socket", move || {
            let mut buf = vec![0u8; 1 << 16];
            while socket.recv(&mut buf).is_ok() {}
        });
        StandInJournal {
            path: Some(path.to_path_buf()),
            made_dir,
        }
    }
}

impl Drop for StandInJournal {
    fn drop(&mut self) {
        if let Some(path) = &self.path {
            let _ = std::fs::remove_file(path);
            if self.made_dir {
                let _ = std::fs::remove_dir(path.parent().unwrap());
            }
        }
    }
}

/// A launcher started from a unit has `JOURNAL_STREAM` naming its own stderr; the
/// services it starts inherit the variable but write to their log files, which
/// must not stay empty (systemd.exec(5): compare stderr's device:inode).
#[test]
fn services_under_a_journal_parent_still_write_their_log_files() {
    use std::os::unix::fs::MetadataExt;

    let _journal = StandInJournal::bind();
    let site = TestSite::looping_vtest("journal", "2");
    let logs = site.path("logs");
    let stderr = std::fs::File::create(site.path("up.stderr")).unwrap();
    let meta = stderr.metadata().unwrap();
    let mut up = std::process::Command::new(isochron_tests::bin("isochron"))
        .args(["up", "--config", site.config_path().to_str().unwrap()])
        .args(["--status-every-s", "0", "--log-dir", logs.to_str().unwrap()])
        .env("JOURNAL_STREAM", format!("{}:{}", meta.dev(), meta.ino()))
        .env("RUST_LOG", "info")
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::null())
        .stderr(stderr)
        .spawn()
        .unwrap();
    let log = logs.join("capture-cam01.log");
    let written = isochron_tests::eventually(Duration::from_secs(60), || {
        std::fs::read_to_string(&log)
            .ok()
            .filter(|t| t.contains("in="))
    });
    // SAFETY: kill(2) on our own child.
    unsafe { libc::kill(up.id() as i32, libc::SIGINT) };
    let _ = up.wait();
    assert!(
        written.is_some(),
        "{} has no status line: {:?}",
        log.display(),
        std::fs::read_to_string(&log)
    );
}
