//! What every service binary does first: logging, config, camera, iceoryx2 node —
//! each failure mapped to a clear message and an exit code a supervisor understands.
//!
//! * [`main_per_camera`] parses `--config` and `--camera a,b,c` ([`CameraArgs`],
//!   shared by every per-camera service) and calls [`run_cameras`]: one camera on
//!   the main thread, or several on one thread each, every one with its own node
//!   `<prefix>/<stage>/<camera>`. The process is ready once every camera's loop is
//!   (`health::expect_ready`), and the systemd watchdog is fed only while every
//!   loop beats. A permanent error stops only its camera; a transient one stops the
//!   whole process so its supervisor restarts it, and a transient code wins over a
//!   permanent one as the exit code.
//! * [`main_site_wide`] (the costmap bridge, the exporter, the link, the MQTT sink)
//!   parses `--config` only, then [`start`] and [`finish`].
//! * Every service and the CLI set umask 0077 ([`owner_only_files`]: what they
//!   create is readable by their user only, as the units' `UMask=`) and raise their
//!   soft limit of open files to the hard one ([`raise_open_file_limit`]). Stop
//!   requests (SIGINT, SIGTERM) are a process-wide flag ([`crate::ipc`]) that every
//!   loop checks at least every tick.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use crate::ipc::Ipc;
use crate::topology::StageKind;
use isochron_config::{CameraConfig, Config, LoadedConfig};
use isochron_exit as exit;

pub use isochron_exit::Fatal;

/// The started service: its config, its camera (if per-camera) and its node.
pub struct ServiceContext {
    /// The loaded config.
    pub config: LoadedConfig,
    /// The camera this process serves, for per-camera services.
    pub camera: Option<CameraConfig>,
    /// The process's iceoryx2 node.
    pub ipc: Ipc,
}

impl ServiceContext {
    /// The camera (per-camera services only).
    pub fn camera(&self) -> &CameraConfig {
        self.camera
            .as_ref()
            .expect("per-camera service started without a camera")
    }
}

/// Initialises logging, loads the config, finds `camera`, and creates the node
/// `<prefix>/<stage>/<camera>` (`<prefix>/<stage>` for site-wide stages), the name
/// `iox2 node list` shows.
pub fn start(stage: StageKind, config: &Path) -> Result<ServiceContext, Fatal> {
    crate::logging::init(stage.binary());
    owner_only_files();
    raise_open_file_limit();
    context(stage, load(config)?, None)
}

/// What a service does once started: serve its camera (per-camera services) or
/// its site until the process is asked to stop.
pub type Serve = fn(ServiceContext) -> Result<(), Fatal>;

/// The command line every per-camera service shares.
#[derive(Debug, clap::Args)]
pub struct CameraArgs {
    /// Site configuration file.
    #[arg(long)]
    pub config: PathBuf,
    /// Camera id (a `[[camera]]` of the config), or several separated by commas
    /// (or given again): one process then serves them all, one thread each.
    #[arg(long, value_delimiter = ',', required = true)]
    pub camera: Vec<String>,
}

/// Runs a per-camera service for each of `args.camera` and returns the exit code.
///
/// One camera runs on the main thread. Several run one thread each, every one with
/// its own node `<prefix>/<stage>/<camera>` (so `iox2 node list` and
/// `isochron status` show each camera), sharing the process: its code, its
/// libraries, and caches such as capture's preloaded frames. A camera that fails
/// for good (a missing file, a bad setting) is logged and stops while the others
/// go on; the process then exits with that code once they end. A transient failure
/// (shared memory, iceoryx2, a bug) stops the whole process, so that its
/// supervisor restarts it.
pub fn run_cameras(stage: StageKind, args: &CameraArgs, run: Serve) -> ExitCode {
    crate::logging::init(stage.binary());
    owner_only_files();
    raise_open_file_limit();
    let result = load(&args.config).and_then(|loaded| {
        crate::scheduling::apply(stage, &loaded.config.site);
        let mut chosen: Vec<CameraConfig> = Vec::new();
        for id in &args.camera {
            let cam = loaded.camera(id)?;
            if !chosen.iter().any(|c| c.id == cam.id) {
                chosen.push(cam.clone());
            }
        }
        match chosen.len() {
            0 => Err(Fatal::new(
                exit::USAGE,
                "no camera given: use --camera ID[,ID...]",
            )),
            1 => context(stage, loaded, chosen.pop()).and_then(run),
            n => {
                crate::health::expect_ready(n);
                tracing::info!("serving {n} cameras, one thread each");
                run_threads(stage, &loaded, chosen, run)
            }
        }
    });
    finish(stage, result)
}

/// The command line of a per-camera service (see [`main_per_camera`]).
#[derive(clap::Parser)]
struct PerCameraCommandLine {
    #[command(flatten)]
    service: CameraArgs,
}

/// The command line of a site-wide service (see [`main_site_wide`]).
#[derive(clap::Parser)]
struct SiteWideCommandLine {
    /// Site configuration file.
    #[arg(long)]
    config: PathBuf,
}

/// The command line of `stage`'s binary: `--config`, and `--camera` for per-camera
/// stages; `--help` says what it does ([`StageKind::about`]), `--version` prints
/// the binary's name and version. `cargo xtask docs` makes its man page from it.
pub fn command(stage: StageKind) -> clap::Command {
    use clap::CommandFactory;
    let command = if stage.per_camera() {
        PerCameraCommandLine::command()
    } else {
        SiteWideCommandLine::command()
    };
    command
        .name(stage.binary())
        .about(stage.about())
        .version(env!("CARGO_PKG_VERSION"))
}

/// Parses the process's command line as `stage`'s binary (see [`command`]).
fn parse_command_line<P: clap::Parser>(stage: StageKind) -> P {
    let mut matches = command(stage).get_matches();
    P::from_arg_matches_mut(&mut matches).unwrap_or_else(|e| e.format(&mut command(stage)).exit())
}

/// The whole `main` of a per-camera service: parses `--config` and `--camera`
/// (see [`command`]) and runs `run` for each camera (see [`run_cameras`]).
pub fn main_per_camera(stage: StageKind, run: Serve) -> ExitCode {
    let args: PerCameraCommandLine = parse_command_line(stage);
    run_cameras(stage, &args.service, run)
}

/// The whole `main` of a site-wide service: parses `--config` (see [`command`]),
/// starts (see [`start`]), runs `run` and returns the exit code.
pub fn main_site_wide(stage: StageKind, run: Serve) -> ExitCode {
    let args: SiteWideCommandLine = parse_command_line(stage);
    finish(stage, start(stage, &args.config).and_then(run))
}

/// Runs `run` for every camera on its own thread; see [`run_cameras`].
fn run_threads(
    stage: StageKind,
    loaded: &LoadedConfig,
    cameras: Vec<CameraConfig>,
    run: Serve,
) -> Result<(), Fatal> {
    let threads: Vec<_> = cameras
        .into_iter()
        .map(|cam| {
            let loaded = loaded.clone();
            let id = cam.id.clone();
            let thread = std::thread::Builder::new()
                .name(format!("{stage}-{id}"))
                .spawn(move || {
                    let _span = tracing::info_span!("camera", camera = %cam.id).entered();
                    let result = context(stage, loaded, Some(cam)).and_then(run);
                    match &result {
                        Err(f) if exit::is_permanent(f.code) => {
                            tracing::error!("this camera stops: {f:#}");
                        }
                        Err(f) => {
                            tracing::error!("{f:#}; stopping the process");
                            crate::ipc::request_stop();
                        }
                        Ok(()) => {}
                    }
                    result
                });
            (id, thread)
        })
        .collect();
    let mut first_failure: Option<Fatal> = None;
    for (id, thread) in threads {
        let result = match thread {
            Ok(handle) => handle.join().unwrap_or_else(|_| {
                crate::ipc::request_stop();
                Err(Fatal::new(
                    exit::SOFTWARE,
                    format!("the thread of camera '{id}' panicked"),
                ))
            }),
            Err(e) => {
                crate::ipc::request_stop();
                Err(Fatal::new(
                    exit::UNAVAILABLE,
                    format!("starting the thread of camera '{id}': {e}"),
                ))
            }
        };
        if let Err(f) = result {
            // A transient failure decides the exit code: it asks for a restart.
            let replace = match &first_failure {
                None => true,
                Some(prev) => exit::is_permanent(prev.code) && !exit::is_permanent(f.code),
            };
            if replace {
                first_failure = Some(f.context(format!("camera '{id}'")));
            }
        }
    }
    first_failure.map_or(Ok(()), Err)
}

fn load(config: &Path) -> Result<LoadedConfig, Fatal> {
    Ok(Config::load(config)?)
}

/// The node of `stage` (for `camera`, if per-camera) on `loaded`'s site.
fn context(
    stage: StageKind,
    loaded: LoadedConfig,
    camera: Option<CameraConfig>,
) -> Result<ServiceContext, Fatal> {
    let prefix = &loaded.config.site.service_prefix;
    let node_name = match &camera {
        Some(c) => format!("{prefix}/{stage}/{}", c.id),
        None => format!("{prefix}/{stage}"),
    };
    let ipc = Ipc::of_site(&node_name, &loaded.config)?;
    Ok(ServiceContext {
        config: loaded,
        camera,
        ipc,
    })
}

/// Logs the outcome of `main`'s work and turns it into the process exit code.
pub fn finish(stage: StageKind, result: Result<(), Fatal>) -> ExitCode {
    crate::health::notify_stopping();
    match result {
        Ok(()) => {
            tracing::info!("{} stopped", stage.binary());
            ExitCode::SUCCESS
        }
        Err(fatal) => {
            // The whole chain: what failed and every cause under it.
            tracing::error!("{fatal:#}");
            ExitCode::from(fatal.code as u8)
        }
    }
}

/// Files and sockets the process creates are readable by its user only (what the
/// units' `UMask=0077` does), also when it is started by hand or by `isochron up`:
/// stores, logs, lock files and snapshots are the site's data.
pub fn owner_only_files() {
    // SAFETY: umask only sets the process's file-mode creation mask.
    unsafe { libc::umask(0o077) };
}

/// Raises the process's soft limit of open files to its hard limit and returns
/// the limit now in force (`None` where it cannot be read). Every iceoryx2 port
/// holds a few files (its port tag, the service's dynamic config, its data
/// segment) and every RustDDS reader four sockets, so a process serving many
/// cameras needs more than the soft limit a shell or systemd gives by default
/// (1 024), while their hard limit (systemd: 524 288) is ample.
pub fn raise_open_file_limit() -> Option<u64> {
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit and setrlimit only read and write `limit`.
    unsafe {
        if libc::getrlimit(libc::RLIMIT_NOFILE, &mut limit) != 0 {
            return None;
        }
        if limit.rlim_cur < limit.rlim_max {
            let raised = libc::rlimit {
                rlim_cur: limit.rlim_max,
                rlim_max: limit.rlim_max,
            };
            if libc::setrlimit(libc::RLIMIT_NOFILE, &raised) == 0 {
                limit = raised;
            }
        }
    }
    Some(limit.rlim_cur)
}

/// How many files (and sockets) the process holds open now (`None` where
/// `/proc/self/fd` cannot be read).
pub fn open_files() -> Option<u64> {
    Some(std::fs::read_dir("/proc/self/fd").ok()?.count() as u64)
}
