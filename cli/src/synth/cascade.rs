//! The isochron-cascade under test: started, watched and restarted when it dies,
//! and its activity read back to know when it has stored everything.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, mpsc};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use indicatif::ProgressBar;
use isochron_config::IpcConfig;
use isochron_exit as exit;
use isochron_runtime::counters;
use isochron_runtime::health::status_counters;
use isochron_runtime::ipc::{Activity, Ipc, Motion, StatusSubscriber, StreamPublisher};
use isochron_runtime::names::ServiceNames;
use isochron_runtime::topology::StageKind;

/// How long the cascade may take no frame before the run fails.
const STALL: Duration = Duration::from_secs(120);

/// The cascade process, restarted when it dies.
pub(super) struct CascadeProc {
    program: PathBuf,
    config: PathBuf,
    camera: String,
    log: PathBuf,
    child: Option<Child>,
    started_at: Instant,
    pub(super) starts: u32,
    quick_failures: u32,
    /// The cascade's status, once [`CascadeProc::watch_status`] subscribed.
    status: Option<StatusSubscriber>,
}

impl CascadeProc {
    /// Errors, saying the cascade `what` and where its log is, once [`STALL`] has
    /// passed since `since`.
    pub(super) fn stalled(&self, since: Instant, what: &str) -> anyhow::Result<()> {
        if since.elapsed() > STALL {
            bail!(
                "the cascade {what} within {} s; see {}",
                STALL.as_secs(),
                self.log.display()
            );
        }
        Ok(())
    }

    pub(super) fn new(config: &Path, camera: &str, log: &Path) -> anyhow::Result<Self> {
        let program = crate::launch::bin_dir().join(StageKind::Cascade.binary());
        if !program.is_file() {
            bail!(
                "{} is not installed (build it with `cargo build --bins`, or set ISOCHRON_BIN_DIR)",
                program.display()
            );
        }
        Ok(CascadeProc {
            program,
            config: config.to_path_buf(),
            camera: camera.to_string(),
            log: log.to_path_buf(),
            child: None,
            started_at: Instant::now(),
            starts: 0,
            quick_failures: 0,
            status: None,
        })
    }

    pub(super) fn start(&mut self, pb: &ProgressBar) -> anyhow::Result<()> {
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&self.log)
            .with_context(|| format!("opening {}", self.log.display()))?;
        let mut command = Command::new(&self.program);
        command
            .arg("--config")
            .arg(&self.config)
            .arg("--camera")
            .arg(&self.camera)
            .stdin(Stdio::null())
            .stdout(log.try_clone()?)
            .stderr(log);
        // Ctrl-C stops synth, which ends the cascade after what it sent.
        crate::launch::held_by_this_process(&mut command);
        let child = command
            .spawn()
            .with_context(|| format!("starting {}", self.program.display()))?;
        let pid = child.id();
        self.child = Some(child);
        self.started_at = Instant::now();
        self.starts += 1;
        pb.suspend(|| println!("synth: cascade started pid={pid}"));
        Ok(())
    }

    /// Waits until the cascade subscribed to `motion`.
    pub(super) fn wait_subscribed(
        &mut self,
        motion: &StreamPublisher<Motion>,
        pb: &ProgressBar,
    ) -> anyhow::Result<()> {
        let deadline = Instant::now() + Duration::from_secs(60);
        while motion.subscriber_count() == 0 {
            self.check(motion, pb)?;
            if Instant::now() > deadline {
                bail!(
                    "{} did not subscribe within 60 s; see {}",
                    StageKind::Cascade.binary(),
                    self.log.display()
                );
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        Ok(())
    }

    /// Reads the cascade's status from now on, for [`CascadeProc::check`] to
    /// see its store fail.
    pub(super) fn watch_status(&mut self, ipc: &Ipc) -> anyhow::Result<()> {
        self.status = Some(ipc.status_subscriber(&self.camera, StageKind::Cascade)?);
        Ok(())
    }

    /// Errors (69) once the cascade says a store commit failed: the disk
    /// under `DIR` is full or read-only, and nothing more would be learned (the
    /// cascade only pauses learning, and synth would wait for it in vain).
    fn store_failing(&self) -> anyhow::Result<()> {
        let failed = self
            .status
            .as_ref()
            .and_then(StatusSubscriber::latest)
            .as_ref()
            .and_then(status_counters)
            .map_or(0.0, |c| c.get(counters::cascade::STORE_FAILURES));
        if failed > 0.0 {
            let dir = self.config.parent().unwrap_or(Path::new("."));
            return Err(exit::Fatal::new(
                exit::UNAVAILABLE,
                format!(
                    "the cascade cannot write its store in {} ({failed} commits failed: the disk is full or read-only); what it learned before is kept; see {}",
                    dir.display(),
                    self.log.display()
                ),
            )
            .into());
        }
        Ok(())
    }

    /// Checks the process; restarts it if it died of something a restart can fix.
    /// Returns true if it was restarted. Errors if the cascade cannot write its
    /// store.
    pub(super) fn check(
        &mut self,
        motion: &StreamPublisher<Motion>,
        pb: &ProgressBar,
    ) -> anyhow::Result<bool> {
        self.store_failing()?;
        let Some(child) = &mut self.child else {
            return Ok(false);
        };
        let Some(status) = child.try_wait()? else {
            return Ok(false);
        };
        self.child = None;
        let how = match (
            status.code(),
            std::os::unix::process::ExitStatusExt::signal(&status),
        ) {
            (Some(code), _) if exit::is_permanent(code) => {
                bail!(
                    "{} failed with exit code {code}:\n{}",
                    StageKind::Cascade.binary(),
                    log_tail(&self.log)
                );
            }
            (Some(code), _) => format!("exited with code {code}"),
            (None, Some(signal)) => format!("was killed by signal {signal}"),
            _ => "ended".to_string(),
        };
        // A process that keeps exiting by itself right after start is a crash loop;
        // one killed from outside (a crash test) is not.
        if status.code().is_some() && self.started_at.elapsed() < Duration::from_secs(1) {
            self.quick_failures += 1;
            if self.quick_failures >= 5 {
                bail!(
                    "{} keeps dying right after start ({how}):\n{}",
                    StageKind::Cascade.binary(),
                    log_tail(&self.log)
                );
            }
        } else {
            self.quick_failures = 0;
        }
        pb.suspend(|| println!("synth: cascade {how}; restarting it"));
        self.start(pb)?;
        self.wait_subscribed(motion, pb)?;
        Ok(true)
    }

    /// Stops the cascade: SIGTERM, then SIGKILL after 10 s.
    pub(super) fn stop(&mut self) {
        let Some(mut child) = self.child.take() else {
            return;
        };
        // SAFETY: kill(2) on our own child.
        unsafe {
            libc::kill(child.id() as i32, libc::SIGTERM);
        }
        let deadline = Instant::now() + Duration::from_secs(10);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        let _ = child.kill();
        let _ = child.wait();
    }
}

impl Drop for CascadeProc {
    fn drop(&mut self) {
        self.stop();
    }
}

/// The last lines of a log file.
fn log_tail(path: &Path) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let lines: Vec<&str> = text.lines().collect();
    lines[lines.len().saturating_sub(15)..].join("\n")
}

/// Reads the cascade's activity in a thread of its own (with its own iceoryx2 node),
/// so the cascade never waits for the synth in lossless mode.
pub(super) struct ActivityTally {
    pub(super) ended: Arc<AtomicBool>,
    seconds: Arc<AtomicU64>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl ActivityTally {
    pub(super) fn start(prefix: &str, camera: &str) -> anyhow::Result<ActivityTally> {
        let ended = Arc::new(AtomicBool::new(false));
        let seconds = Arc::new(AtomicU64::new(0));
        let stop = Arc::new(AtomicBool::new(false));
        let (ready_tx, ready_rx) = mpsc::channel::<anyhow::Result<()>>();
        let (prefix, camera) = (prefix.to_string(), camera.to_string());
        let (e, s, st) = (ended.clone(), seconds.clone(), stop.clone());
        let thread = std::thread::Builder::new().name("activity-tally".into());
        let thread = thread.spawn(move || {
            let opened = Ipc::new(
                "isochron-synth-activity",
                ServiceNames::new(&prefix),
                IpcConfig {
                    lossless: true,
                    ..IpcConfig::default()
                },
            )
            .map_err(anyhow::Error::from)
            .and_then(|ipc| {
                let sub = ipc.subscriber::<Activity>(&camera)?;
                Ok((ipc, sub))
            });
            let (_ipc, sub) = match opened {
                Ok(x) => {
                    let _ = ready_tx.send(Ok(()));
                    x
                }
                Err(err) => {
                    let _ = ready_tx.send(Err(err));
                    return;
                }
            };
            while !st.load(Ordering::Acquire) {
                sub.wait(Duration::from_millis(50));
                sub.drain_wakeups();
                while let Ok(Some(sample)) = sub.receive() {
                    if sample.user_header().preamble.is_end_of_stream() {
                        e.store(true, Ordering::Release);
                    } else {
                        s.fetch_add(1, Ordering::Relaxed);
                    }
                }
            }
        })?;
        ready_rx
            .recv()
            .context("the activity reader thread died")??;
        Ok(ActivityTally {
            ended,
            seconds,
            stop,
            thread: Some(thread),
        })
    }

    /// Stops the reader; returns the number of activity seconds seen.
    pub(super) fn stop(mut self) -> u64 {
        self.stop.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        self.seconds.load(Ordering::Relaxed)
    }
}

impl Drop for ActivityTally {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
