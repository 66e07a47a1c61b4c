//! `isochron doctor`: checks what a site needs — config, sources, state directory,
//! shared memory, iceoryx2's directory, stale resources of dead processes, running
//! services — and says what to fix.

use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use isochron_shared::config::{Config, LoadedConfig, SourceKind};
use isochron_shared::exit;
use isochron_shared::ipc::{Ipc, node_census, publisher_segment_bytes};
use isochron_shared::store::{Store, store_path};
use isochron_shared::topology::StageKind;
use isochron_shared::wire::{BlockActivity, BlockMotion, Stream};

use crate::common::config_path;
use crate::status;

/// Check the site's set-up and say what to fix.
#[derive(clap::Args)]
pub struct Args {
    /// Site configuration (default: $ISOCHRON_CONFIG or /etc/isochron/isochron.toml).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Only report stale iceoryx2 resources of dead processes; do not remove them.
    #[arg(long)]
    keep_stale: bool,
}

#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Level {
    Ok,
    Warn,
    Fail,
}

struct Report {
    worst: Level,
}

impl Report {
    fn say(&mut self, level: Level, what: &str, text: impl AsRef<str>) {
        let tag = match level {
            Level::Ok => "ok  ",
            Level::Warn => "warn",
            Level::Fail => "FAIL",
        };
        println!("{tag} {what}: {}", text.as_ref());
        self.worst = self.worst.max(level);
    }
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let mut report = Report { worst: Level::Ok };
    // Before any node of ours exists: creating a node would clean dead ones silently.
    match node_census(!args.keep_stale) {
        Ok(census) => {
            let stale = census.dead_removed.len() + census.dead_left.len();
            if stale == 0 {
                report.say(
                    Level::Ok,
                    "stale resources",
                    "none (no dead iceoryx2 nodes)",
                );
            } else if census.dead_left.is_empty() {
                report.say(
                    Level::Ok,
                    "stale resources",
                    format!(
                        "removed those of {} dead process(es): {}",
                        census.dead_removed.len(),
                        census.dead_removed.join(", ")
                    ),
                );
            } else {
                report.say(
                    if args.keep_stale {
                        Level::Warn
                    } else {
                        Level::Fail
                    },
                    "stale resources",
                    format!(
                        "dead nodes left: {} (run without --keep-stale, as the user that ran them)",
                        census.dead_left.join(", ")
                    ),
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
        }
        Err(e) => report.say(
            Level::Warn,
            "stale resources",
            format!("cannot list iceoryx2 nodes: {e}"),
        ),
    }

    let path = config_path(args.config);
    let loaded = match Config::load(&path) {
        Ok(l) => l,
        Err(e) => {
            report.say(Level::Fail, "config", e.to_string());
            return Ok(ExitCode::from(1));
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
    check_sources(&loaded, &mut report);
    check_state_dir(&loaded.state_dir(), &mut report);
    check_stores(&loaded, &mut report);
    check_shared_memory(&loaded, &mut report);
    check_iceoryx2_dir(&mut report);

    let ipc = Ipc::of_site("isochron-doctor", c)?;
    let cameras: Vec<String> = c.cameras.iter().map(|c| c.id.clone()).collect();
    let rows = status::collect(&ipc, &cameras)?;
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
    Ok(match report.worst {
        Level::Fail => ExitCode::from(1),
        _ => ExitCode::SUCCESS,
    })
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
            SourceKind::Url(u) => {
                report.say(Level::Ok, &what, format!("{u} (network: not probed)"))
            }
            SourceKind::GStreamer(p) => {
                report.say(Level::Ok, &what, format!("GStreamer pipeline '{p}'"))
            }
        }
    }
}

fn check_state_dir(dir: &Path, report: &mut Report) {
    if !dir.exists() {
        report.say(
            Level::Warn,
            "state dir",
            format!(
                "{} does not exist yet; the cascade creates it (it must be writable by the services' user)",
                dir.display()
            ),
        );
        return;
    }
    let probe = dir.join(".isochron-doctor-probe");
    match std::fs::write(&probe, b"") {
        Ok(()) => {
            let _ = std::fs::remove_file(&probe);
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
        match Store::open_read_only(&path, &cam.id).and_then(|s| s.verify().map(|v| (s, v))) {
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
fn frame_bytes(cam: &isochron_shared::config::CameraConfig) -> (usize, bool) {
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
    let free = free_bytes("/dev/shm");
    let mib = |b: usize| b as f64 / (1 << 20) as f64;
    let mut text = format!("the group preallocates about {:.0} MiB", mib(need));
    if !guessed.is_empty() {
        text += &format!(
            " (assuming 1920x1080 for {}: set width/height to size it exactly)",
            guessed.join(", ")
        );
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

fn free_bytes(path: &str) -> Option<usize> {
    let c = std::ffi::CString::new(path).ok()?;
    // SAFETY: statvfs fills the struct for a valid path.
    let mut st: libc::statvfs = unsafe { std::mem::zeroed() };
    (unsafe { libc::statvfs(c.as_ptr(), &mut st) } == 0)
        .then(|| st.f_bavail as usize * st.f_frsize as usize)
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
