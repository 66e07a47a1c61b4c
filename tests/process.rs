//! The service processes a test runs: started, read line by line, waited for,
//! signalled, killed when dropped; and the waiting a test does around them.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::mpsc::{Receiver, channel};
use std::time::{Duration, Instant};

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
    program: PathBuf,
    child: Child,
    stdout_lines: Receiver<String>,
    stdout: Vec<String>,
    stderr_path: PathBuf,
    _stderr_dir: tempfile::TempDir,
}

impl Proc {
    /// Starts `program args`.
    pub fn spawn(program: &Path, args: &[impl AsRef<std::ffi::OsStr>]) -> Proc {
        Proc::spawn_in(program, args, None)
    }

    /// Starts `program args` in the working directory `dir` (if given).
    pub fn spawn_in(
        program: &Path,
        args: &[impl AsRef<std::ffi::OsStr>],
        dir: Option<&Path>,
    ) -> Proc {
        let stderr_dir = tempfile::tempdir().expect("temp dir");
        let stderr_path = stderr_dir.path().join("stderr");
        let stderr = std::fs::File::create(&stderr_path).expect("stderr file");
        let mut command = Command::new(program);
        if let Some(dir) = dir {
            command.current_dir(dir);
        }
        let mut child = command
            .args(args)
            .env("RUST_LOG", "info")
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(stderr)
            .spawn()
            .unwrap_or_else(|e| panic!("starting {}: {e}", program.display()));
        let (tx, rx) = channel();
        let out = child.stdout.take().expect("piped stdout");
        named_thread("stdout-lines", move || {
            for line in BufReader::new(out).lines().map_while(Result::ok) {
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        Proc {
            program: program.to_path_buf(),
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

    /// Waits up to `timeout` for the exit, which must come, and returns it.
    pub fn finish(&mut self, timeout: Duration) -> Finished {
        let status = self.wait(timeout).unwrap_or_else(|| {
            panic!(
                "{} did not exit in {timeout:?}\nstderr:\n{}",
                self.program.display(),
                self.stderr()
            )
        });
        Finished {
            status,
            stdout: self.stdout(),
            stderr: self.stderr(),
        }
    }

    /// Sends SIGTERM and waits up to `timeout` for the exit, which must come.
    pub fn terminate(&mut self, timeout: Duration) -> ExitStatus {
        self.signal(libc::SIGTERM);
        self.wait(timeout).unwrap_or_else(|| {
            panic!(
                "{} did not stop on SIGTERM in {timeout:?}\nstderr:\n{}",
                self.program.display(),
                self.stderr()
            )
        })
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

/// Runs `f` on a new thread named `name`: a panic in it, and a debugger, say which.
pub fn named_thread<T: Send + 'static>(
    name: &str,
    f: impl FnOnce() -> T + Send + 'static,
) -> std::thread::JoinHandle<T> {
    std::thread::Builder::new()
        .name(name.to_string())
        .spawn(f)
        .unwrap_or_else(|e| panic!("spawning thread {name}: {e}"))
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

/// The pid in a launcher line such as `up: capture/cam01 started pid=123`.
pub fn pid_in(line: &str) -> u32 {
    line.rsplit("pid=")
        .next()
        .and_then(|s| s.split_whitespace().next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no pid in '{line}'"))
}
