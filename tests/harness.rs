//! Harness for the multi-process tests: finds the built binaries and the sample
//! video, gives each test its own site (directory, config, iceoryx2 prefix), and
//! runs service processes that are killed when the test ends.
//!
//! Binaries must be built first (`cargo xtask test` does it; by hand:
//! `cargo build --workspace --bins`).

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::mpsc::{Receiver, channel};
use std::time::{Duration, Instant};

use isochron_shared::config::{Config, LoadedConfig};
use isochron_shared::ipc::Ipc;
use isochron_shared::names::ServiceNames;

/// The directory holding the built binaries (`target/<profile>`).
pub fn bin_dir() -> PathBuf {
    if let Some(dir) = std::env::var_os("ISOCHRON_BIN_DIR") {
        return PathBuf::from(dir);
    }
    // target/<profile>/deps/<test-binary>
    let exe = std::env::current_exe().expect("test binary path");
    exe.parent()
        .and_then(Path::parent)
        .expect("target/<profile>")
        .to_path_buf()
}

/// Path of binary `name`, which must have been built.
pub fn bin(name: &str) -> PathBuf {
    let path = bin_dir().join(name);
    assert!(
        path.is_file(),
        "{} is not built: run `cargo build --workspace --bins` (or `cargo xtask test`)",
        path.display()
    );
    path
}

/// The repository root.
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("repo root")
        .to_path_buf()
}

/// The PETS 2009 sample video (`data/vtest.avi`, fetched by `cargo xtask setup`).
pub fn vtest() -> PathBuf {
    let path = std::env::var_os("ISOCHRON_VTEST")
        .map(PathBuf::from)
        .unwrap_or_else(|| repo_root().join("data/vtest.avi"));
    assert!(
        path.is_file(),
        "{} is missing: run `cargo xtask setup` to fetch it",
        path.display()
    );
    path
}

/// Frames in vtest.avi.
pub const VTEST_FRAMES: u64 = 795;

static NEXT_SITE: AtomicU32 = AtomicU32::new(0);

/// A private site for one test: a temp directory with `site.toml`, and an iceoryx2
/// prefix no other test uses.
pub struct TestSite {
    /// The directory (removed when the site is dropped).
    pub dir: tempfile::TempDir,
    /// The service prefix.
    pub prefix: String,
}

impl TestSite {
    /// A site whose config is `[site]` (prefix and state dir filled in) followed by
    /// `body` (cameras and sections).
    pub fn new(name: &str, body: &str) -> TestSite {
        let dir = tempfile::Builder::new()
            .prefix(&format!("isochron-{name}-"))
            .tempdir()
            .expect("temp dir");
        let prefix = format!(
            "t{}-{}-{name}",
            std::process::id(),
            NEXT_SITE.fetch_add(1, Ordering::Relaxed)
        );
        let site = TestSite { dir, prefix };
        site.write_config(body);
        site
    }

    /// Rewrites `site.toml` with `body`.
    pub fn write_config(&self, body: &str) {
        let text = format!(
            "[site]\nname = \"test\"\nservice_prefix = \"{}\"\nstate_dir = \"state\"\n\n{body}",
            self.prefix
        );
        std::fs::write(self.config_path(), text).expect("write config");
    }

    /// The config file.
    pub fn config_path(&self) -> PathBuf {
        self.dir.path().join("site.toml")
    }

    /// A path inside the site directory.
    pub fn path(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }

    /// The loaded config.
    pub fn config(&self) -> LoadedConfig {
        Config::load(&self.config_path()).expect("test config is valid")
    }

    /// An iceoryx2 node of this test process on the site's services.
    pub fn ipc(&self, name: &str) -> Ipc {
        let config = self.config();
        Ipc::new(
            &format!("test-{name}"),
            ServiceNames::new(&self.prefix),
            config.config.ipc.clone(),
        )
        .expect("iceoryx2 node")
    }

    /// Starts a service binary with `--config site.toml` and `args`.
    pub fn spawn(&self, binary: &str, args: &[&str]) -> Proc {
        let mut all = vec![
            "--config".to_string(),
            self.config_path().display().to_string(),
        ];
        all.extend(args.iter().map(|s| s.to_string()));
        Proc::spawn(&bin(binary), &all)
    }

    /// Runs `isochron <args>` to completion (with a timeout) and returns it.
    pub fn isochron(&self, args: &[&str], timeout: Duration) -> Finished {
        let mut proc = Proc::spawn(&bin("isochron"), args);
        let status = proc.wait(timeout).unwrap_or_else(|| {
            panic!(
                "isochron {args:?} did not finish in {timeout:?}\nstdout:\n{}\nstderr:\n{}",
                proc.stdout(),
                proc.stderr()
            )
        });
        Finished {
            status,
            stdout: proc.stdout(),
            stderr: proc.stderr(),
        }
    }
}

/// A process that ran to completion.
#[derive(Debug)]
pub struct Finished {
    /// Exit status.
    pub status: ExitStatus,
    /// All it printed on stdout.
    pub stdout: String,
    /// All it printed on stderr.
    pub stderr: String,
}

/// A child process, killed when dropped. Its output is collected line by line.
pub struct Proc {
    child: Child,
    stdout_lines: Receiver<String>,
    stdout: Vec<String>,
    stderr_path: PathBuf,
    _stderr_dir: tempfile::TempDir,
}

impl Proc {
    /// Starts `program args`.
    pub fn spawn(program: &Path, args: &[impl AsRef<std::ffi::OsStr>]) -> Proc {
        let stderr_dir = tempfile::tempdir().expect("temp dir");
        let stderr_path = stderr_dir.path().join("stderr");
        let stderr = std::fs::File::create(&stderr_path).expect("stderr file");
        let mut child = Command::new(program)
            .args(args)
            .env("RUST_LOG", "info")
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(stderr)
            .spawn()
            .unwrap_or_else(|e| panic!("starting {}: {e}", program.display()));
        let (tx, rx) = channel();
        let out = child.stdout.take().expect("piped stdout");
        std::thread::spawn(move || {
            for line in BufReader::new(out).lines().map_while(Result::ok) {
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        Proc {
            child,
            stdout_lines: rx,
            stdout: Vec::new(),
            stderr_path,
            _stderr_dir: stderr_dir,
        }
    }

    /// Process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Waits up to `timeout` for the exit.
    pub fn wait(&mut self, timeout: Duration) -> Option<ExitStatus> {
        let end = Instant::now() + timeout;
        loop {
            if let Ok(Some(status)) = self.child.try_wait() {
                // Let the reader thread deliver the last lines.
                std::thread::sleep(Duration::from_millis(20));
                self.collect();
                return Some(status);
            }
            if Instant::now() >= end {
                return None;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    /// Sends `signal` (e.g. `libc::SIGTERM`).
    pub fn signal(&self, signal: i32) {
        // SAFETY: kill(2) on our own child.
        unsafe {
            libc::kill(self.child.id() as i32, signal);
        }
    }

    fn collect(&mut self) {
        while let Ok(line) = self.stdout_lines.try_recv() {
            self.stdout.push(line);
        }
    }

    /// Waits up to `timeout` for a stdout line containing `needle`; returns it.
    pub fn wait_for_line(&mut self, needle: &str, timeout: Duration) -> Option<String> {
        let end = Instant::now() + timeout;
        let mut checked = 0;
        loop {
            self.collect();
            if let Some(line) = self.stdout[checked..].iter().find(|l| l.contains(needle)) {
                return Some(line.clone());
            }
            checked = self.stdout.len();
            let left = end.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return None;
            }
            if let Ok(line) = self
                .stdout_lines
                .recv_timeout(left.min(Duration::from_millis(50)))
            {
                self.stdout.push(line);
            }
        }
    }

    /// Waits up to `timeout` until stderr contains `needle`.
    pub fn wait_for_stderr(&self, needle: &str, timeout: Duration) -> bool {
        let end = Instant::now() + timeout;
        loop {
            if self.stderr().contains(needle) {
                return true;
            }
            if Instant::now() >= end {
                return false;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// All stdout so far.
    pub fn stdout(&mut self) -> String {
        self.collect();
        self.stdout.join("\n")
    }

    /// All stderr so far.
    pub fn stderr(&self) -> String {
        std::fs::read_to_string(&self.stderr_path).unwrap_or_default()
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            // A clean stop first, so the process releases its iceoryx2 resources.
            self.signal(libc::SIGTERM);
            if self.wait(Duration::from_secs(5)).is_none() {
                let _ = self.child.kill();
                let _ = self.child.wait();
            }
        }
    }
}

/// Polls `f` every 20 ms until it returns `Some` or `timeout` passes.
pub fn eventually<T>(timeout: Duration, mut f: impl FnMut() -> Option<T>) -> Option<T> {
    let end = Instant::now() + timeout;
    loop {
        if let Some(v) = f() {
            return Some(v);
        }
        if Instant::now() >= end {
            return None;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// The camera section for vtest.avi at `speed`, starting at `start`.
pub fn vtest_camera(speed: &str, start: &str) -> String {
    format!(
        "[[camera]]\nid = \"cam01\"\nsource = \"{}\"\nspeed = \"{speed}\"\nstart = \"{start}\"\n",
        vtest().display()
    )
}
