//! What the link checks before it joins DDS: that the process may open the files
//! it will need, and that its DDS Security enclave holds its files (or that
//! running without one is safe or accepted).

use isochron_config::LoadedConfig;
use isochron_exit as exit;
use isochron_runtime::service::{Fatal, open_files, raise_open_file_limit};

use super::camera_stages;

/// Files a link needs besides what it holds when it starts: RustDDS's
/// participant (its sockets and event loop: about 50, counted in the site bench's
/// link), then four sockets per DDS reader and two per writer (RustDDS's poll
/// and status channels are socket pairs; it panics when it cannot make one), and
/// iceoryx2's: an imported camera's three publishers (each a port tag, the
/// service's dynamic config and its data segment) with their notifiers (a port
/// tag and the event service's dynamic config) and a status publisher per stage
/// (3 files); an exported camera's three subscribers (a port tag, the dynamic
/// config, the publisher's data segment) with their listeners (a socket, a port
/// tag, the event's dynamic config) and a status subscriber per stage (3).
struct FileBudget {
    dds_base: u64,
    per_import: u64,
    per_export: u64,
    spare: u64,
}

impl FileBudget {
    fn new() -> Self {
        let stages = camera_stages().count() as u64;
        let (reader, writer) = (4, 2);
        FileBudget {
            dds_base: 64,
            per_import: 4 * reader + 3 * (3 + 2) + 3 * stages,
            per_export: 4 * writer + 3 * (3 + 3) + 3 * stages,
            spare: 64,
        }
    }

    /// Files needed by a link of `imports` and `exports` cameras, on top of `open`.
    fn need(&self, open: u64, imports: usize, exports: usize) -> u64 {
        open + self.dds_base
            + imports as u64 * self.per_import
            + exports as u64 * self.per_export
            + self.spare
    }
}

/// Checks, before joining DDS, that the process may open the files the link
/// will need (after raising its soft limit to its hard one); else fails with one
/// line naming the limit to set and the value.
pub(super) fn check_open_files(imports: usize, exports: usize) -> Result<(), Fatal> {
    let (Some(limit), Some(open)) = (raise_open_file_limit(), open_files()) else {
        return Ok(());
    };
    let budget = FileBudget::new();
    let need = budget.need(open, imports, exports);
    if need > limit {
        return Err(Fatal::new(
            exit::CONFIG,
            format!(
                "importing {imports} and exporting {exports} cameras needs about {need} open files \
                 ({} per imported camera: DDS readers' sockets and iceoryx2 ports) but this process \
                 may open {limit}: raise LimitNOFILE= of isochron-link.service (or `ulimit -n` where \
                 it is started by hand) to at least {need}",
                budget.per_import
            ),
        ));
    }
    tracing::info!(open, need, limit, "open files");
    Ok(())
}

/// This box's DDS Security enclave (`link.security_dir`, relative to the config
/// file), checked to hold its files. Without one the link runs unauthenticated,
/// which it refuses on an interface other than loopback unless `link.insecure`
/// says so.
pub(super) fn enclave(loaded: &LoadedConfig) -> Result<Option<std::path::PathBuf>, Fatal> {
    let link = &loaded.config.link;
    let Some(dir) = &link.security_dir else {
        if link.leaves_the_box() && !link.insecure {
            return Err(Fatal::new(
                exit::CONFIG,
                format!(
                    "{}: the link would run without DDS Security on {}: any participant on that \
                     network could write into this site. Set link.security_dir to this box's \
                     enclave (`isochron keystore enclave`), or link.insecure = true to accept that",
                    loaded.path.display(),
                    if link.dds_interfaces.is_empty() {
                        "every interface".to_string()
                    } else {
                        format!("[{}]", link.dds_interfaces.join(", "))
                    }
                ),
            ));
        }
        if link.leaves_the_box() {
            tracing::warn!(
                "link.insecure: DDS Security is off; any participant on the network can write into this site"
            );
        }
        return Ok(None);
    };
    let dir = loaded.base_dir().join(dir);
    if let Some(problem) =
        isochron_dds::enclave_problem(&dir, "link.security_dir", "isochron keystore enclave")
    {
        let line = format!("{}: {problem}", loaded.path.display());
        return Err(Fatal::new(exit::CONFIG, line));
    }
    tracing::info!(enclave = %dir.display(), "DDS Security on");
    Ok(Some(dir))
}
