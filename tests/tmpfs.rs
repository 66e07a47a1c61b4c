//! A small tmpfs a test mounts (a disk that fills, read-only media), unmounted
//! when dropped.

use std::path::{Path, PathBuf};
use std::process::Command;

/// A tmpfs mounted on a directory of the test's, until dropped.
pub struct Tmpfs(PathBuf);

impl Tmpfs {
    /// Mounts a tmpfs of `size` (`2m`, `300k`) on `dir` (created). `None` where
    /// this user cannot mount (not root), which is a failure under `CI` (CI runs
    /// as root); the test then skips, saying so.
    pub fn mount(dir: &Path, size: &str) -> Option<Tmpfs> {
        std::fs::create_dir_all(dir).expect("the mount point");
        let mounted = Command::new("mount")
            .args([
                "-t",
                "tmpfs",
                "-o",
                &format!("size={size}"),
                "isochron-test",
            ])
            .arg(dir)
            .status()
            .is_ok_and(|s| s.success());
        if !mounted {
            assert!(
                std::env::var_os("CI").is_none(),
                "CI runs as root and must be able to mount a tmpfs"
            );
            eprintln!("skipped: cannot mount a tmpfs here (not root)");
        }
        mounted.then(|| Tmpfs(dir.to_path_buf()))
    }

    /// Makes it read-only (a write-protected card); true if it now is.
    pub fn remount_read_only(&self) -> bool {
        Command::new("mount")
            .args(["-o", "remount,ro"])
            .arg(&self.0)
            .status()
            .is_ok_and(|s| s.success())
    }
}

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg("-l").arg(&self.0).status();
    }
}
