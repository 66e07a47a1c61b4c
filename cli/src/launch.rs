//! A small service manager for the process group, doing for development, the demo
//! and tests what systemd does in production: start each service as its own
//! process, speak the `sd_notify` protocol with it (readiness, watchdog, status),
//! restart it when it fails — with backoff, and never when its exit code says that
//! restarting cannot help — and stop everything on request.

use std::collections::HashMap;
use std::ffi::OsString;
use std::os::unix::net::UnixDatagram;
use std::os::unix::process::CommandExt;
use std::os::unix::process::ExitStatusExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::Context;
use isochron_config::LoadedConfig;
use isochron_exit as exit;
use isochron_runtime::topology::StageKind;

/// Directory of the service binaries: `$ISOCHRON_BIN_DIR`, else next to this binary.
pub fn bin_dir() -> PathBuf {
    if let Some(dir) = std::env::var_os("ISOCHRON_BIN_DIR") {
        return PathBuf::from(dir);
    }
    std::env::current_exe()
        .ok()
        .and_then(|p| p.parent().map(Path::to_path_buf))
        .unwrap_or_else(|| PathBuf::from("."))
}

/// Those of `stages` whose binaries are installed, with their paths.
pub fn installed(stages: impl Iterator<Item = StageKind>) -> Vec<(StageKind, PathBuf)> {
    let dir = bin_dir();
    stages
        .map(|stage| (stage, dir.join(stage.binary())))
        .filter(|(_, path)| path.is_file())
        .collect()
}

/// One process to run.
#[derive(Debug, Clone)]
pub struct ServiceSpec {
    /// Unique name, `stage/camera` or `stage`.
    pub name: String,
    /// The stage.
    pub stage: StageKind,
    /// Program.
    pub program: PathBuf,
    /// Arguments.
    pub args: Vec<OsString>,
}

/// The services of `stages` (those installed) for `config`: a per-camera stage
/// once per `site.cameras_per_process` cameras, a site-wide one once,
/// downstream first, so consumers are up before producers.
pub fn group_specs(config: &LoadedConfig, stages: &[(StageKind, PathBuf)]) -> Vec<ServiceSpec> {
    let config_arg = OsString::from(
        config
            .path
            .canonicalize()
            .unwrap_or_else(|_| config.path.clone()),
    );
    let mut specs = Vec::new();
    for (stage, program) in stages.iter().cloned().rev() {
        if !stage.per_camera() {
            specs.push(ServiceSpec {
                name: stage.name().to_string(),
                stage,
                program,
                args: vec!["--config".into(), config_arg.clone()],
            });
            continue;
        }
        let per_process = config.config.site.cameras_per_process.max(1);
        let local: Vec<_> = config.config.local_cameras().collect();
        for cameras in local.chunks(per_process) {
            let ids = cameras
                .iter()
                .map(|c| c.id.as_str())
                .collect::<Vec<_>>()
                .join(",");
            specs.push(ServiceSpec {
                name: format!("{stage}/{ids}"),
                stage,
                program: program.clone(),
                args: vec![
                    "--config".into(),
                    config_arg.clone(),
                    "--camera".into(),
                    ids.into(),
                ],
            });
        }
    }
    specs
}

/// Where a managed service stands.
#[derive(Debug, Clone, PartialEq)]
pub enum State {
    /// Started, not yet ready.
    Starting,
    /// Ready (it said `READY=1`).
    Running,
    /// Waiting to be restarted.
    Backoff {
        /// When.
        until: Instant,
    },
    /// Exited cleanly (code 0); not restarted.
    Finished,
    /// Exited with a code that restarting cannot fix; not restarted.
    Failed {
        /// The code.
        code: i32,
    },
    /// Stopped by the supervisor.
    Stopped,
}

/// Something that happened to a service, for people and tests.
#[derive(Debug, Clone)]
pub struct Change {
    /// Service name.
    pub name: String,
    /// What happened.
    pub what: String,
}

struct Managed {
    spec: ServiceSpec,
    child: Option<Child>,
    state: State,
    started: Instant,
    restarts: u32,
    backoff: Duration,
    notify: UnixDatagram,
    notify_path: PathBuf,
    last_ping: Instant,
    status: String,
}

/// Runs a group of services.
pub struct Supervisor {
    services: Vec<Managed>,
    dir: PathBuf,
    restart: bool,
    watchdog: Duration,
    log_dir: Option<PathBuf>,
}

/// First restart delay; it doubles per quick failure up to [`MAX_BACKOFF`].
const FIRST_BACKOFF: Duration = Duration::from_millis(200);
const MAX_BACKOFF: Duration = Duration::from_secs(10);
/// A service that ran this long is healthy again: its backoff resets.
const HEALTHY_AFTER: Duration = Duration::from_secs(30);
/// How long a service may take to say it is ready.
const START_TIMEOUT: Duration = Duration::from_secs(60);

impl Supervisor {
    /// A supervisor that restarts failed services if `restart`, and treats a service
    /// that has not pinged its watchdog for `watchdog` as hung. Service output goes
    /// to `log_dir/<name>.log` if given, else is inherited.
    pub fn new(
        restart: bool,
        watchdog: Duration,
        log_dir: Option<PathBuf>,
    ) -> anyhow::Result<Self> {
        let dir = std::env::temp_dir().join(format!("isochron-supervisor-{}", std::process::id()));
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        if let Some(log_dir) = &log_dir {
            std::fs::create_dir_all(log_dir)
                .with_context(|| format!("creating {}", log_dir.display()))?;
        }
        Ok(Supervisor {
            services: Vec::new(),
            dir,
            restart,
            watchdog,
            log_dir,
        })
    }

    /// Adds and starts a service.
    pub fn add(&mut self, spec: ServiceSpec) -> anyhow::Result<Change> {
        let notify_path = self
            .dir
            .join(format!("{}.notify", spec.name.replace('/', "-")));
        let _ = std::fs::remove_file(&notify_path);
        let notify = UnixDatagram::bind(&notify_path)
            .with_context(|| format!("binding {}", notify_path.display()))?;
        notify.set_nonblocking(true)?;
        let mut managed = Managed {
            spec,
            child: None,
            state: State::Starting,
            started: Instant::now(),
            restarts: 0,
            backoff: FIRST_BACKOFF,
            notify,
            notify_path,
            last_ping: Instant::now(),
            status: String::new(),
        };
        spawn(&mut managed, self.watchdog, self.log_dir.as_deref())?;
        let change = Change {
            name: managed.spec.name.clone(),
            what: format!("started pid={}", managed.pid().unwrap_or(0)),
        };
        self.services.push(managed);
        Ok(change)
    }

    /// Reaps exits, reads notifications, enforces watchdogs, restarts what is due.
    pub fn poll(&mut self) -> Vec<Change> {
        let mut changes = Vec::new();
        let now = Instant::now();
        for i in 0..self.services.len() {
            let m = &mut self.services[i];
            read_notifications(m, now, &mut changes);
            // Exits.
            if let Some(child) = &mut m.child
                && let Ok(Some(status)) = child.try_wait()
            {
                m.child = None;
                let code = status.code();
                let signal = status.signal();
                let what = match (code, signal) {
                    (Some(c), _) => format!("exited with code {c}"),
                    (None, Some(s)) => format!("killed by signal {s}"),
                    _ => "exited".into(),
                };
                m.state = match code {
                    Some(0) => State::Finished,
                    Some(c) if exit::is_permanent(c) => State::Failed { code: c },
                    _ if self.restart => {
                        if now.duration_since(m.started) >= HEALTHY_AFTER {
                            m.backoff = FIRST_BACKOFF;
                        }
                        let until = now + m.backoff;
                        m.backoff = (m.backoff * 2).min(MAX_BACKOFF);
                        State::Backoff { until }
                    }
                    Some(c) => State::Failed { code: c },
                    None => State::Failed { code: -1 },
                };
                let tail = match &m.state {
                    State::Backoff { until } => format!(
                        "; restarting in {:.1} s",
                        until.duration_since(now).as_secs_f64()
                    ),
                    State::Failed { code } if exit::is_permanent(*code) => {
                        "; not restarting: the error is permanent (see its log)".into()
                    }
                    _ => String::new(),
                };
                changes.push(Change {
                    name: m.spec.name.clone(),
                    what: format!("{what}{tail}"),
                });
            }
            // Hangs: no watchdog ping (after ready) or no readiness in time.
            let hung = match m.state {
                State::Running => now.duration_since(m.last_ping) > self.watchdog,
                State::Starting => now.duration_since(m.started) > START_TIMEOUT,
                _ => false,
            };
            if hung && let Some(child) = &mut m.child {
                changes.push(Change {
                    name: m.spec.name.clone(),
                    what: format!(
                        "watchdog: no sign of life for {:.1} s; killing pid {}",
                        now.duration_since(m.last_ping).as_secs_f64(),
                        child.id()
                    ),
                });
                // SIGABRT first would leave a core; a hung process gets SIGKILL.
                let _ = child.kill();
                // The exit is reaped (and the restart scheduled) on the next poll.
                m.last_ping = now;
            }
        }
        // Restarts that are due.
        for i in 0..self.services.len() {
            let m = &mut self.services[i];
            if let State::Backoff { until } = m.state
                && now >= until
            {
                m.restarts += 1;
                let what = match spawn(m, self.watchdog, self.log_dir.as_deref()) {
                    Ok(()) => format!(
                        "restarted pid={} (restart #{})",
                        m.pid().unwrap_or(0),
                        m.restarts
                    ),
                    Err(e) => {
                        m.state = State::Backoff {
                            until: now + m.backoff,
                        };
                        format!("restart failed: {e:#}")
                    }
                };
                changes.push(Change {
                    name: m.spec.name.clone(),
                    what,
                });
            }
        }
        changes
    }

    /// States by service name.
    pub fn states(&self) -> HashMap<String, State> {
        self.services
            .iter()
            .map(|m| (m.spec.name.clone(), m.state.clone()))
            .collect()
    }

    /// True while any service is still starting or running.
    pub fn any_alive(&self) -> bool {
        self.services.iter().any(|m| m.child.is_some())
    }

    /// A table of the services for people.
    pub fn table(&self) -> String {
        let mut out = format!(
            "{:<20} {:>8} {:>9} {:>9}  {}\n",
            "SERVICE", "PID", "STATE", "RESTARTS", "STATUS"
        );
        for m in &self.services {
            let state = match &m.state {
                State::Starting => "starting".to_string(),
                State::Running => "running".to_string(),
                State::Backoff { .. } => "backoff".to_string(),
                State::Finished => "finished".to_string(),
                State::Failed { code } => format!("failed({code})"),
                State::Stopped => "stopped".to_string(),
            };
            out += &format!(
                "{:<20} {:>8} {:>9} {:>9}  {}\n",
                m.spec.name,
                m.pid().map(|p| p.to_string()).unwrap_or_else(|| "-".into()),
                state,
                m.restarts,
                m.status
            );
        }
        out
    }

    /// Stops every service: SIGTERM, then SIGKILL after `grace`.
    pub fn stop_all(&mut self, grace: Duration) {
        for m in &mut self.services {
            if let Some(child) = &m.child {
                // SAFETY: plain kill(2) on our own child.
                unsafe {
                    libc::kill(child.id() as i32, libc::SIGTERM);
                }
            }
        }
        let deadline = Instant::now() + grace;
        while Instant::now() < deadline && self.services.iter_mut().any(|m| m.reap().is_none()) {
            std::thread::sleep(Duration::from_millis(20));
        }
        for m in &mut self.services {
            if let Some(child) = &mut m.child {
                tracing::warn!("{} did not stop within {grace:?}; killing it", m.spec.name);
                let _ = child.kill();
                let _ = child.wait();
                m.child = None;
            }
            m.state = State::Stopped;
        }
    }
}

impl Managed {
    fn pid(&self) -> Option<u32> {
        self.child.as_ref().map(Child::id)
    }

    /// Reaps the child if it exited; `Some(())` when it is gone.
    fn reap(&mut self) -> Option<()> {
        match &mut self.child {
            None => Some(()),
            Some(child) => match child.try_wait() {
                Ok(Some(_)) | Err(_) => {
                    self.child = None;
                    Some(())
                }
                Ok(None) => None,
            },
        }
    }
}

impl Drop for Supervisor {
    fn drop(&mut self) {
        if self.any_alive() {
            self.stop_all(Duration::from_secs(5));
        }
        for m in &self.services {
            let _ = std::fs::remove_file(&m.notify_path);
        }
        let _ = std::fs::remove_dir(&self.dir);
    }
}

/// Reads `m`'s notifications (READY=1, WATCHDOG=1, STATUS=...): any of them is a
/// sign of life.
fn read_notifications(m: &mut Managed, now: Instant, changes: &mut Vec<Change>) {
    let mut buf = [0u8; 4096];
    while let Ok(n) = m.notify.recv(&mut buf) {
        for line in String::from_utf8_lossy(&buf[..n]).lines() {
            match line.split_once('=') {
                Some(("READY", "1")) if m.state == State::Starting => {
                    m.state = State::Running;
                    changes.push(Change {
                        name: m.spec.name.clone(),
                        what: "ready".into(),
                    });
                }
                Some(("WATCHDOG", "1")) => m.last_ping = now,
                Some(("STATUS", s)) => m.status = s.to_string(),
                _ => {}
            }
        }
        m.last_ping = now;
    }
}

/// Starts (or restarts) `m`'s process with the notify socket and watchdog set.
fn spawn(m: &mut Managed, watchdog: Duration, log_dir: Option<&Path>) -> anyhow::Result<()> {
    let mut cmd = Command::new(&m.spec.program);
    cmd.args(&m.spec.args)
        .env("NOTIFY_SOCKET", &m.notify_path)
        .env("WATCHDOG_USEC", watchdog.as_micros().to_string())
        .env_remove("WATCHDOG_PID")
        .stdin(Stdio::null());
    held_by_this_process(&mut cmd);
    if let Some(dir) = log_dir {
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(dir.join(format!("{}.log", m.spec.name.replace('/', "-"))))?;
        cmd.stdout(log.try_clone()?).stderr(log);
    }
    let child = cmd
        .spawn()
        .with_context(|| format!("starting {}", m.spec.program.display()))?;
    m.child = Some(child);
    m.state = State::Starting;
    m.started = Instant::now();
    m.last_ping = Instant::now();
    Ok(())
}

/// Makes `cmd`'s process one this process alone stops: in a process group of
/// its own, so that Ctrl-C in the terminal reaches only the command, which
/// stops its services in order (a service that got the terminal's SIGINT
/// itself would end first, and be taken for a failure or restarted); and
/// stopped with SIGTERM if this process dies, even by SIGKILL, instead of
/// running on as an orphan nobody restarts or stops.
pub(crate) fn held_by_this_process(cmd: &mut Command) {
    cmd.process_group(0);
    // SAFETY: prctl is async-signal-safe; nothing else runs between fork and exec.
    unsafe {
        cmd.pre_exec(|| {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
}
