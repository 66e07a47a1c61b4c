//! `isochron doctor`: checks what a site needs — config, sources, the detector
//! model and the robots' map, the state directory and its disk, shared memory,
//! iceoryx2's directory, stale resources of dead processes, running services — and
//! says what to fix.
//!
//! It changes nothing unless asked with `--fix`, which removes the stale iceoryx2
//! resources (shared memory, files) that dead processes left behind. Creating an
//! iceoryx2 node removes them too (iceoryx2 cleans dead nodes whenever a node is
//! created), so without `--fix` doctor creates no node while stale resources exist,
//! and skips the checks that need one.

use std::io::Write;
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use isochron_config::{Config, LoadedConfig, SourceKind};
use isochron_exit as exit;
use isochron_planning::grid::MapGrid;
use isochron_runtime::ipc::{Ipc, node_census, publisher_segment_bytes};
use isochron_runtime::topology::StageKind;
use isochron_store::{Store, store_path};
use isochron_wire::{BlockActivity, BlockMotion, Stream};

use crate::common::config_path;
use crate::status;

mod load_checks;
use load_checks::{check_model, check_mqtt, check_route_graph, check_warnings, check_zones};

/// Check the site's set-up and say what to fix (changes nothing without --fix).
#[derive(clap::Args)]
pub struct Args {
    /// Site configuration (default: $ISOCHRON_CONFIG or /etc/isochron/isochron.toml).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Repair what can be repaired: remove the stale iceoryx2 resources (shared
    /// memory, files) of dead processes. Without it, doctor only reports.
    #[arg(long)]
    fix: bool,
    /// Deprecated and ignored: doctor removes nothing without --fix.
    #[arg(long, hide = true)]
    keep_stale: bool,
    /// One JSON object per check and line: {"check", "status": "ok"|"warn"|"fail",
    /// "detail"}.
    #[arg(long)]
    json: bool,
}

/// Free space of the state directory's filesystem below which doctor warns.
const LOW_DISK_BYTES: u64 = 100 << 20;
/// The same as a share of the filesystem, percent.
const LOW_DISK_PERCENT: f64 = 5.0;

/// What a node-dependent check says when doctor may not create a node.
const SKIPPED_FOR_STALE: &str =
    "skipped: creating a node would remove the stale resources; run with --fix";

#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Level {
    Ok,
    Warn,
    Fail,
}

impl Level {
    fn name(self) -> &'static str {
        match self {
            Level::Ok => "ok",
            Level::Warn => "warn",
            Level::Fail => "fail",
        }
    }
}

struct Report {
    worst: Level,
    json: bool,
}

impl Report {
    fn say(&mut self, level: Level, what: &str, text: impl AsRef<str>) {
        let text = text.as_ref();
        let line = if self.json {
            /// One check, as `--json` prints it (fields in this order).
            #[derive(serde::Serialize)]
            struct Line<'a> {
                check: &'a str,
                status: &'a str,
                detail: &'a str,
            }
            serde_json::to_string(&Line {
                check: what,
                status: level.name(),
                detail: text,
            })
            .expect("strings serialize")
        } else {
            let tag = match level {
                Level::Ok => "ok  ",
                Level::Warn => "warn",
                Level::Fail => "FAIL",
            };
            format!("{tag} {what}: {text}")
        };
        // Each check is on screen as soon as it is done (a hung check shows where).
        let mut out = std::io::stdout().lock();
        let _ = writeln!(out, "{line}");
        let _ = out.flush();
        self.worst = self.worst.max(level);
    }
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let mut report = Report {
        worst: Level::Ok,
        json: args.json,
    };
    if args.keep_stale {
        tracing::warn!(
            "--keep-stale is deprecated and ignored: doctor removes nothing without --fix"
        );
    }
    // Before any node of ours exists: creating a node cleans dead ones silently.
    let may_create_node = check_stale(args.fix, &mut report);

    let path = config_path(args.config);
    let loaded = match Config::load(&path) {
        Ok(l) => l,
        Err(e) => {
            report.say(Level::Fail, "config", e.to_string());
            return Ok(ExitCode::from(isochron_exit::FAILURE as u8));
        }
    };
    let c = &loaded.config;
    report.say(
        Level::Ok,
        "config",
        format!(
            "{} ({} camera(s), site '{}', prefix '{}', time zone {})",
            path.display(),
            c.cameras.len(),
            c.site.name,
            c.site.service_prefix,
            c.site.time_zone
        ),
    );
    check_warnings(&loaded, &mut report);
    check_mqtt(&loaded, &mut report);
    check_sources(&loaded, &mut report);
    check_model(&loaded, &mut report);
    check_zones(&loaded, &mut report);
    check_map(&loaded, &mut report);
    check_route_graph(&loaded, &mut report);
    check_state_dir(&loaded.state_dir(), &mut report);
    check_disk(&loaded.state_dir(), &mut report);
    check_stores(&loaded, &mut report);
    check_shared_memory(&loaded, &mut report);
    check_iceoryx2_dir(&mut report);
    if may_create_node {
        check_services(&loaded, &mut report)?;
    } else {
        report.say(Level::Warn, "services", SKIPPED_FOR_STALE);
    }
    Ok(match report.worst {
        Level::Fail => ExitCode::from(isochron_exit::FAILURE as u8),
        _ => ExitCode::SUCCESS,
    })
}

/// Lists the iceoryx2 nodes of dead processes and, with `fix`, removes their
/// resources. Returns whether doctor may create a node of its own: not while stale
/// resources are there and `fix` was not given (creating one would remove them).
fn check_stale(fix: bool, report: &mut Report) -> bool {
    let census = match node_census(fix) {
        Ok(census) => census,
        Err(e) => {
            report.say(
                Level::Warn,
                "stale resources",
                format!("cannot list iceoryx2 nodes: {e}"),
            );
            // Nothing is known to be stale; a node of ours removes nothing we saw.
            return true;
        }
    };
    if !census.dead_removed.is_empty() {
        report.say(
            Level::Ok,
            "stale resources",
            format!(
                "removed those of {} dead process(es): {}",
                census.dead_removed.len(),
                census.dead_removed.join(", ")
            ),
        );
    }
    if !census.dead_left.is_empty() {
        let dead = census.dead_left.join(", ");
        let (level, message) = if fix {
            (
                Level::Fail,
                format!(
                    "could not remove those of dead node(s) {dead}: run isochron doctor --fix as the user that ran them"
                ),
            )
        } else {
            (
                Level::Warn,
                format!(
                    "{} dead process(es) left iceoryx2 resources (shared memory, files): {dead}; isochron doctor --fix would remove them",
                    census.dead_left.len()
                ),
            )
        };
        report.say(level, "stale resources", message);
    } else if census.dead_removed.is_empty() {
        report.say(
            Level::Ok,
            "stale resources",
            "none (no dead iceoryx2 nodes)",
        );
    }
    if census.inaccessible > 0 {
        report.say(
            Level::Warn,
            "iceoryx2 nodes",
            format!(
                "{} node(s) of another user are not visible to this user; run doctor as the services' user (isochron)",
                census.inaccessible
            ),
        );
    }
    fix || census.dead_left.is_empty()
}

/// Which of the site's services run (needs a node of doctor's own).
fn check_services(loaded: &LoadedConfig, report: &mut Report) -> anyhow::Result<()> {
    let c = &loaded.config;
    let ipc = Ipc::of_site("isochron-doctor", c)?;
    let rows = status::collect(&ipc, loaded)?;
    let running = rows.iter().filter(|r| r.state() == "running").count();
    let missing: Vec<String> = rows
        .iter()
        .filter(|r| r.state() != "running")
        .map(|r| {
            let who = if r.camera.is_empty() {
                r.stage.name().to_string()
            } else {
                format!("{}@{}", r.stage.name(), r.camera)
            };
            format!("{who} {}", r.state())
        })
        .collect();
    if missing.is_empty() {
        report.say(Level::Ok, "services", format!("all {running} running"));
    } else {
        report.say(
            Level::Warn,
            "services",
            format!(
                "{running} of {} running; {} (start them: systemctl start isochron.target, or isochron up)",
                rows.len(),
                missing.join(", ")
            ),
        );
    }
    Ok(())
}

/// `path` of the config, resolved against the config file's directory.
fn resolve(loaded: &LoadedConfig, path: &Path) -> PathBuf {
    if path.is_absolute() {
        path.to_path_buf()
    } else {
        loaded.base_dir().join(path)
    }
}

/// The robots' map, if one is configured: the YAML reads, names its image, the
/// image exists, and together they make a grid.
fn check_map(loaded: &LoadedConfig, report: &mut Report) {
    const WHAT: &str = "map";
    let Some(yaml) = &loaded.config.costmap.map_yaml else {
        report.say(Level::Ok, WHAT, "costmap.map_yaml not set");
        return;
    };
    let yaml = resolve(loaded, yaml);
    let config = loaded.path.display();
    let text = match std::fs::read_to_string(&yaml) {
        Ok(text) => text,
        Err(e) => {
            let problem = if e.kind() == std::io::ErrorKind::NotFound {
                "does not exist".to_string()
            } else {
                format!("cannot be read: {e}")
            };
            report.say(
                Level::Fail,
                WHAT,
                format!(
                    "costmap.map_yaml: {} {problem}: put the map_server YAML there or fix costmap.map_yaml in {config}",
                    yaml.display()
                ),
            );
            return;
        }
    };
    let Some(image) = text
        .lines()
        .find_map(|l| l.trim().strip_prefix("image:"))
        .map(|s| s.trim().trim_matches(['"', '\'']))
        .filter(|s| !s.is_empty())
    else {
        report.say(
            Level::Fail,
            WHAT,
            format!(
                "costmap.map_yaml: {} names no image: a map_server YAML has `image: <file>` (with resolution and origin)",
                yaml.display()
            ),
        );
        return;
    };
    let image = yaml.parent().unwrap_or(Path::new(".")).join(image);
    if !image.is_file() {
        report.say(
            Level::Fail,
            WHAT,
            format!(
                "costmap.map_yaml: image {} (named by {}) does not exist: put the map image there or fix `image:` in the YAML",
                image.display(),
                yaml.display()
            ),
        );
        return;
    }
    match MapGrid::from_config(loaded) {
        Ok(Some(g)) => report.say(
            Level::Ok,
            WHAT,
            format!(
                "{} with {}: {}x{} cells of {} m",
                yaml.display(),
                image.display(),
                g.width,
                g.height,
                g.resolution
            ),
        ),
        Ok(None) => {}
        Err(e) => report.say(Level::Fail, WHAT, e.to_string()),
    }
}

fn check_sources(loaded: &LoadedConfig, report: &mut Report) {
    for cam in &loaded.config.cameras {
        let what = format!("camera {}", cam.id);
        match cam.source_kind(&loaded.base_dir()) {
            SourceKind::File(p) if p.is_file() => {
                report.say(Level::Ok, &what, format!("file {}", p.display()))
            }
            SourceKind::File(p) => report.say(
                Level::Fail,
                &what,
                format!(
                    "{} does not exist ({} exits with code {})",
                    p.display(),
                    StageKind::Capture,
                    exit::NO_INPUT
                ),
            ),
            SourceKind::Device(i) => {
                let dev = PathBuf::from(format!("/dev/video{i}"));
                if dev.exists() {
                    report.say(Level::Ok, &what, format!("V4L2 device {}", dev.display()));
                } else {
                    report.say(
                        Level::Warn,
                        &what,
                        format!(
                            "{} does not exist now; capture retries with backoff until it appears",
                            dev.display()
                        ),
                    );
                }
            }
            kind @ SourceKind::Url(_) => {
                report.say(Level::Ok, &what, format!("{kind} (network: not probed)"))
            }
            kind @ SourceKind::GStreamer(_) => report.say(Level::Ok, &what, kind.to_string()),
        }
    }
}

fn check_state_dir(dir: &Path, report: &mut Report) {
    if !dir.exists() {
        // The cascade creates it: in the nearest directory that exists, which
        // must be a directory this user can write.
        let mut base = dir.parent();
        while let Some(b) = base.filter(|b| !b.exists()) {
            base = b.parent();
        }
        let base = base.unwrap_or(Path::new("/"));
        let (level, said) = match () {
            _ if !base.is_dir() => (
                Level::Fail,
                format!(
                    "{} cannot be created: {} is not a directory",
                    dir.display(),
                    base.display()
                ),
            ),
            _ => match write_probe(base) {
                Ok(()) => (
                    Level::Warn,
                    format!(
                        "{} does not exist yet; the cascade creates it (it must be writable by the services' user)",
                        dir.display()
                    ),
                ),
                Err(e) => (
                    Level::Fail,
                    format!(
                        "{} cannot be created: {} is not writable by this user: {e}",
                        dir.display(),
                        base.display()
                    ),
                ),
            },
        };
        report.say(level, "state dir", said);
        return;
    }
    if !dir.is_dir() {
        report.say(
            Level::Fail,
            "state dir",
            format!("{} is not a directory", dir.display()),
        );
        return;
    }
    match write_probe(dir) {
        Ok(()) => {
            report.say(
                Level::Ok,
                "state dir",
                format!("{} is writable", dir.display()),
            );
        }
        Err(e) => report.say(
            Level::Fail,
            "state dir",
            format!("{} is not writable by this user: {e}", dir.display()),
        ),
    }
}

/// Whether this user can write in `dir`, which is only known by writing: a
/// probe file, removed at once. It changes nothing anyone relies on (no store,
/// snapshot or setting), so doctor does it also without --fix.
fn write_probe(dir: &Path) -> std::io::Result<()> {
    let probe = dir.join(format!(".isochron-doctor-probe-{}", std::process::id()));
    std::fs::write(&probe, b"")?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}

/// Free space of the filesystem holding the state directory (or, before it
/// exists, its nearest existing parent).
fn check_disk(dir: &Path, report: &mut Report) {
    const WHAT: &str = "disk";
    let dir = std::path::absolute(dir).unwrap_or_else(|_| dir.to_path_buf());
    let Some(on) = dir.ancestors().find(|p| p.exists()) else {
        report.say(
            Level::Warn,
            WHAT,
            format!("no part of {} exists", dir.display()),
        );
        return;
    };
    let Some(space) = fs_space(on) else {
        report.say(
            Level::Warn,
            WHAT,
            format!("cannot read the free space of {}", on.display()),
        );
        return;
    };
    let mib = |b: u64| b as f64 / (1 << 20) as f64;
    let percent = if space.total > 0 {
        100.0 * space.available as f64 / space.total as f64
    } else {
        0.0
    };
    let text = format!(
        "{:.0} MiB free of {:.0} MiB ({percent:.1} %) on the filesystem of {}",
        mib(space.available),
        mib(space.total),
        on.display()
    );
    if space.available < LOW_DISK_BYTES || percent < LOW_DISK_PERCENT {
        report.say(
            Level::Warn,
            WHAT,
            format!(
                "{text}: below {} MiB or {LOW_DISK_PERCENT} %; the cascade pauses learning when the disk is full: free some space",
                LOW_DISK_BYTES >> 20
            ),
        );
    } else {
        report.say(Level::Ok, WHAT, text);
    }
}

/// Each camera's long-term store opens, validates (checksums, metadata) and says how
/// much it has learned.
fn check_stores(loaded: &LoadedConfig, report: &mut Report) {
    for cam in &loaded.config.cameras {
        let what = format!("store {}", cam.id);
        let path = store_path(&loaded.state_dir(), &cam.id);
        if !path.exists() {
            report.say(
                Level::Ok,
                &what,
                format!(
                    "{} not created yet (the cascade creates it when motion arrives)",
                    path.display()
                ),
            );
            continue;
        }
        // The cascade's own checks: the camera, the cycle, every row.
        let cycle = loaded.config.cascade.cycle;
        let opened = Store::open_read_only(&path, &cam.id)
            .and_then(|s| s.check_cycle(cycle).map(|()| s))
            .and_then(|s| s.verify().map(|v| (s, v)));
        match opened {
            Ok((store, v)) => {
                let days = store
                    .read_model()
                    .map(|m| m.learned().map(|b| b.count).max().unwrap_or(0))
                    .unwrap_or(0);
                report.say(
                    Level::Ok,
                    &what,
                    format!(
                        "{}: {} grid, {} of {} bins learned (up to {days} days), {} minutes committed",
                        path.display(),
                        store.meta().grid(),
                        v.bins,
                        store.meta().bins(),
                        v.progress.committed
                    ),
                );
            }
            Err(e) => report.say(Level::Fail, &what, e.to_string()),
        }
    }
}

/// Frame size of a camera: configured, else assumed 1920×1080 (the worst case).
fn frame_bytes(cam: &isochron_config::CameraConfig) -> (usize, bool) {
    match (cam.width, cam.height) {
        (Some(w), Some(h)) => (w as usize * h as usize * cam.format().channels(), true),
        _ => (1920 * 1080 * cam.format().channels(), false),
    }
}

fn check_shared_memory(loaded: &LoadedConfig, report: &mut Report) {
    let c = &loaded.config;
    let mut need = 0usize;
    let mut guessed = Vec::new();
    for cam in &c.cameras {
        let (bytes, known) = frame_bytes(cam);
        if !known {
            guessed.push(cam.id.clone());
        }
        let (w, h) = (
            cam.width.unwrap_or(1920) as usize,
            cam.height.unwrap_or(1080) as usize,
        );
        let blocks =
            w.div_ceil(c.motion.block_px as usize) * h.div_ceil(c.motion.block_px as usize);
        need += publisher_segment_bytes(&c.ipc, Stream::Frames, bytes)
            + publisher_segment_bytes(&c.ipc, Stream::Motion, blocks * size_of::<BlockMotion>())
            + publisher_segment_bytes(
                &c.ipc,
                Stream::Activity,
                blocks * size_of::<BlockActivity>(),
            );
    }
    let free = fs_space(Path::new("/dev/shm")).map(|s| s.available as usize);
    let mib = |b: usize| b as f64 / (1 << 20) as f64;
    let mut text = format!("the group preallocates about {:.0} MiB", mib(need));
    if !guessed.is_empty() {
        let shown = if guessed.len() > 5 {
            format!("{} and {} more", guessed[..5].join(", "), guessed.len() - 5)
        } else {
            guessed.join(", ")
        };
        text += &format!(" (assuming 1920x1080 for {shown}: set width/height to size it exactly)");
    }
    match free {
        Some(free) if free < need => report.say(
            Level::Fail,
            "shared memory",
            format!("{text}, but /dev/shm has only {:.0} MiB free: enlarge it (mount -o remount,size=...)", mib(free)),
        ),
        Some(free) => report.say(
            Level::Ok,
            "shared memory",
            format!("{text}; /dev/shm has {:.0} MiB free", mib(free)),
        ),
        None => report.say(Level::Warn, "shared memory", format!("{text}; cannot read /dev/shm")),
    }
}

/// Space of a filesystem, bytes.
struct Space {
    /// Available to unprivileged users.
    available: u64,
    /// Size of the filesystem.
    total: u64,
}

/// Space of the filesystem holding `path` (statvfs).
fn fs_space(path: &Path) -> Option<Space> {
    use std::os::unix::ffi::OsStrExt;
    let c = std::ffi::CString::new(path.as_os_str().as_bytes()).ok()?;
    // SAFETY: statvfs is plain integers, for which all-zero bytes are a valid value.
    let mut st: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: `c` is a NUL-terminated string that outlives the call and `st` a
    // writable statvfs; statvfs(3) reads the one and writes only the other.
    if unsafe { libc::statvfs(c.as_ptr(), &mut st) } != 0 {
        return None;
    }
    let frsize = st.f_frsize as u64;
    Some(Space {
        available: st.f_bavail as u64 * frsize,
        total: st.f_blocks as u64 * frsize,
    })
}

fn check_iceoryx2_dir(report: &mut Report) {
    let dir = Path::new("/tmp/iceoryx2");
    match std::fs::metadata(dir) {
        Err(_) => report.say(
            Level::Ok,
            "iceoryx2 dir",
            "/tmp/iceoryx2 does not exist yet (the first service creates it; under systemd, isochron.tmpfiles does)",
        ),
        Ok(m) => {
            // SAFETY: geteuid has no preconditions.
            let me = unsafe { libc::geteuid() };
            let mode = m.mode() & 0o777;
            if m.uid() != me && me != 0 {
                report.say(
                    Level::Fail,
                    "iceoryx2 dir",
                    format!(
                        "/tmp/iceoryx2 belongs to uid {} (mode {mode:o}); iceoryx2 keeps its files owner-only, so run every isochron process as that user",
                        m.uid()
                    ),
                );
            } else {
                report.say(Level::Ok, "iceoryx2 dir", format!("/tmp/iceoryx2 mode {mode:o}, uid {}", m.uid()));
            }
        }
    }
}
