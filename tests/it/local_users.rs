//! Another local user against the site's shared memory (issue 34): no file of the
//! site's iceoryx2 world is writable by others, another user cannot truncate the
//! node counter every process opens, and a counter that another user made (or
//! that was truncated) stops `isochron status` at once with a clear error instead
//! of freezing it. Runs as root, as CI does; the other user is `nobody`
//! (`setpriv`).

use std::os::unix::fs::{MetadataExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use isochron_tests::{Proc, TestSite, bin};

/// `nobody`'s uid and gid.
const NOBODY: u32 = 65534;

/// The iceoryx2 shared-memory prefix of a private world (its `config/iceoryx2.toml`).
fn world_prefix(world: &Path) -> String {
    let text = std::fs::read_to_string(world.join("config/iceoryx2.toml")).unwrap();
    let line = text.lines().find(|l| l.starts_with("prefix")).unwrap();
    line.split('"').nth(1).unwrap().to_string()
}

/// The files of the world in /dev/shm.
fn shm_files(prefix: &str) -> Vec<PathBuf> {
    std::fs::read_dir("/dev/shm")
        .unwrap()
        .filter_map(Result::ok)
        .filter(|e| e.file_name().to_string_lossy().starts_with(prefix))
        .map(|e| e.path())
        .collect()
}

/// `isochron status` in the world: it must end within `limit`.
fn status(site: &TestSite, world: &Path, limit: Duration) -> (Option<i32>, String, Duration) {
    let config = site.config_path().display().to_string();
    let started = Instant::now();
    let mut p = Proc::spawn_in(
        &bin("isochron"),
        &["status", "--config", config.as_str()],
        Some(world),
    );
    let Some(status) = p.wait(limit) else {
        p.signal(libc::SIGKILL);
        panic!(
            "isochron status hangs (more than {limit:?})\n{}",
            p.stderr()
        );
    };
    (status.code(), p.stderr(), started.elapsed())
}

#[test]
fn another_local_user_cannot_freeze_the_site_through_shared_memory() {
    let site = TestSite::with_source("local-users", "", "unused.avi");
    let world = site.private_iceoryx2();
    let prefix = world_prefix(&world);

    // A process of the site creates its node: nothing it leaves is writable by others.
    let (code, stderr, _) = status(&site, &world, Duration::from_secs(30));
    assert_eq!(code, Some(3), "nothing runs: status says so\n{stderr}");
    let files = shm_files(&prefix);
    let counter = files
        .iter()
        .find(|f| f.to_string_lossy().ends_with(".global_mgmt"))
        .unwrap_or_else(|| panic!("no node counter among {files:?}"))
        .clone();
    for f in &files {
        let mode = std::fs::metadata(f).unwrap().mode() & 0o777;
        assert_eq!(mode & 0o022, 0, "{} has mode {mode:o}", f.display());
    }

    // Another user cannot truncate it.
    let size = std::fs::metadata(&counter).unwrap().len();
    let truncate = Command::new("setpriv")
        .args([
            "--reuid=65534",
            "--regid=65534",
            "--clear-groups",
            "truncate",
            "-s",
            "0",
        ])
        .arg(&counter)
        .output()
        .unwrap();
    assert!(
        !truncate.status.success(),
        "nobody truncated {}",
        counter.display()
    );
    assert_eq!(std::fs::metadata(&counter).unwrap().len(), size);

    // A counter another user made before the site started, writable by all: refused
    // at once with what to do, and not restarted (exit 78).
    std::fs::remove_file(&counter).unwrap();
    std::fs::write(&counter, vec![0u8; size as usize]).unwrap();
    std::fs::set_permissions(&counter, std::fs::Permissions::from_mode(0o666)).unwrap();
    std::os::unix::fs::chown(&counter, Some(NOBODY), Some(NOBODY)).unwrap();
    let (code, stderr, took) = status(&site, &world, Duration::from_secs(20));
    assert_eq!(code, Some(78), "{stderr}");
    assert!(stderr.contains("remove it as root"), "{stderr}");
    assert!(took < Duration::from_secs(10), "{took:?}");

    // The site's own counter, truncated: an error within seconds, not a hang.
    std::fs::remove_file(&counter).unwrap();
    std::fs::write(&counter, []).unwrap();
    std::fs::set_permissions(&counter, std::fs::Permissions::from_mode(0o600)).unwrap();
    let (code, stderr, took) = status(&site, &world, Duration::from_secs(20));
    assert_ne!(code, Some(0), "{stderr}");
    assert!(took < Duration::from_secs(10), "{took:?}\n{stderr}");

    // This user's counter left writable by all (an older iceoryx2): made owner-only.
    std::fs::remove_file(&counter).unwrap();
    let (code, _, _) = status(&site, &world, Duration::from_secs(30));
    assert_eq!(code, Some(3));
    std::fs::set_permissions(&counter, std::fs::Permissions::from_mode(0o666)).unwrap();
    let (code, stderr, _) = status(&site, &world, Duration::from_secs(30));
    assert_eq!(code, Some(3), "{stderr}");
    assert_eq!(
        std::fs::metadata(&counter).unwrap().mode() & 0o777,
        0o600,
        "{stderr}"
    );
    for f in shm_files(&prefix) {
        let _ = std::fs::remove_file(f);
    }
}
