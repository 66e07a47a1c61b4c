//! The guard on iceoryx2's node counter: the one shared-memory file every process
//! of an iceoryx2 domain opens to create a node
//! (`/dev/shm/<iceoryx2 prefix>…_node.<version>.global_mgmt`).
//!
//! iceoryx2 0.10 created it writable by every local user; any of them could then
//! truncate it and make every isochron process hang when it starts (the patched
//! iceoryx2 in `vendor/` creates it owner-only and gives up on a truncated one after
//! a second). A file left by an older isochron, or made by another user before the
//! site first started, is still there: [`check`] makes this user's own file
//! owner-only, and refuses to go on when a file another user owns is writable by
//! others — a clear error instead of a site any local user can freeze.

use std::os::unix::fs::{MetadataExt, PermissionsExt};
use std::path::{Path, PathBuf};

/// Where Linux keeps POSIX shared memory.
pub const SHM_DIR: &str = "/dev/shm";

/// What [`check`] found wrong and could not repair.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Unsafe {
    /// The file.
    pub file: PathBuf,
    /// Its owner.
    pub uid: u32,
    /// Its mode bits.
    pub mode: u32,
}

impl std::fmt::Display for Unsafe {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let why = if self.mode & 0o022 != 0 {
            "is writable by other users: any local user could freeze every isochron process of the site"
        } else {
            "is not this user's: iceoryx2 cannot open it, and every process of the site would fail to start (a command run as another user before the site started made it)"
        };
        write!(
            f,
            "{} (iceoryx2's node counter) belongs to uid {} (mode {:o}) and {why}; remove it as root (`rm {}`) while the site is stopped, then start the site and run its commands as one user",
            self.file.display(),
            self.uid,
            self.mode,
            self.file.display()
        )
    }
}

/// The node counters of iceoryx2 prefix `prefix` in `dir`.
pub fn files(dir: &Path, prefix: &str) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut found: Vec<PathBuf> = entries
        .filter_map(Result::ok)
        .filter(|e| {
            let name = e.file_name();
            let name = name.to_string_lossy();
            name.starts_with(prefix) && name.ends_with(".global_mgmt")
        })
        .map(|e| e.path())
        .collect();
    found.sort();
    found
}

/// Checks the node counters of `prefix` in `dir` for a process running as `euid`:
/// one of this user's that others may write is made owner-only (returned, to be
/// logged); one of another user's that others may write is an error, and so is
/// one of another user's that this user (not root) cannot open.
pub fn check(dir: &Path, prefix: &str, euid: u32) -> Result<Vec<PathBuf>, Unsafe> {
    let mut repaired = Vec::new();
    for file in files(dir, prefix) {
        let Ok(meta) = std::fs::symlink_metadata(&file) else {
            continue;
        };
        let mode = meta.mode() & 0o7777;
        if !meta.is_file() {
            continue;
        }
        if mode & 0o022 == 0 {
            if meta.uid() != euid && euid != 0 && mode & 0o006 != 0o006 {
                return Err(Unsafe {
                    file,
                    uid: meta.uid(),
                    mode,
                });
            }
            continue;
        }
        if meta.uid() == euid
            && std::fs::set_permissions(&file, std::fs::Permissions::from_mode(0o600)).is_ok()
        {
            repaired.push(file);
            continue;
        }
        return Err(Unsafe {
            file,
            uid: meta.uid(),
            mode,
        });
    }
    Ok(repaired)
}

/// The effective user id of this process.
pub fn euid() -> u32 {
    // SAFETY: geteuid has no preconditions and cannot fail.
    unsafe { libc::geteuid() }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn this_users_world_writable_counter_becomes_owner_only() {
        let dir = tempfile::tempdir().unwrap();
        let counter = dir.path().join("iox2_abc_node.0_10_0.global_mgmt");
        let other = dir.path().join("iox2_abc_other.0_10_0.service");
        for f in [&counter, &other] {
            std::fs::write(f, [0u8; 16]).unwrap();
            std::fs::set_permissions(f, std::fs::Permissions::from_mode(0o666)).unwrap();
        }
        let repaired = check(dir.path(), "iox2_", euid()).unwrap();
        assert_eq!(repaired, vec![counter.clone()]);
        let mode = std::fs::metadata(&counter).unwrap().mode() & 0o777;
        assert_eq!(mode, 0o600);
        // Another prefix, and files that are not node counters, are left alone.
        assert!(check(dir.path(), "other_", euid()).unwrap().is_empty());
        assert_eq!(std::fs::metadata(&other).unwrap().mode() & 0o777, 0o666);
    }

    #[test]
    fn another_users_writable_counter_is_refused_with_the_fix() {
        let dir = tempfile::tempdir().unwrap();
        let counter = dir.path().join("iox2_abc_node.0_10_0.global_mgmt");
        std::fs::write(&counter, [0u8; 16]).unwrap();
        std::fs::set_permissions(&counter, std::fs::Permissions::from_mode(0o666)).unwrap();
        // As if this process ran as another user than the file's owner.
        let e = check(dir.path(), "iox2_", euid().wrapping_add(1)).unwrap_err();
        assert_eq!(e.file, counter);
        assert!(e.to_string().contains("remove it as root"), "{e}");
        // Owner-only, but another user's: this one (not root) could not open it.
        std::fs::set_permissions(&counter, std::fs::Permissions::from_mode(0o600)).unwrap();
        let e = check(dir.path(), "iox2_", euid().wrapping_add(1)).unwrap_err();
        assert!(e.to_string().contains("is not this user's"), "{e}");
    }
}
