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

use isochron_config::{Config, LoadedConfig};
use isochron_runtime::ipc::{Ipc, StreamSubscriber, StreamType};
use isochron_runtime::names::ServiceNames;
use isochron_wire::{CameraId, StreamHeader};

/// The directory holding the built binaries: `$ISOCHRON_BIN_DIR`, else
/// `target/<profile>` of the test or bench that calls it.
pub fn bin_dir() -> PathBuf {
    if let Some(dir) = std::env::var_os("ISOCHRON_BIN_DIR") {
        return PathBuf::from(dir);
    }
    // target/<profile>/deps/<test or bench binary>
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

/// A file `cargo xtask setup` provides: `$var` if set, else `default` under the
/// repository root. Fails, saying to run the setup (`why` tells what for), when
/// it is missing.
pub fn setup_file(var: &str, default: &str, why: &str) -> PathBuf {
    let path = std::env::var_os(var)
        .map(PathBuf::from)
        .unwrap_or_else(|| repo_root().join(default));
    assert!(
        path.is_file(),
        "{} is missing: run `cargo xtask setup` {why}",
        path.display()
    );
    path
}

/// The PETS 2009 sample video (`data/vtest.avi`, fetched by `cargo xtask setup`).
pub fn vtest() -> PathBuf {
    setup_file("ISOCHRON_VTEST", "data/vtest.avi", "to fetch it")
}

/// A loopback TCP port nobody listens on now.
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port")
        .port()
}

/// Frames in vtest.avi.
pub const VTEST_FRAMES: u64 = 795;

/// Sites made by this process so far: with the pid, a prefix no other test of any
/// test process uses (the tests of every area run in parallel in one process).
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

    /// A site with `sections` (such as `[ipc]`; empty for none) and one camera,
    /// cam01, of which only the `source` is set: a file the test makes, or one that
    /// is never opened (the test publishes cam01's streams itself, or replay
    /// replaces it).
    pub fn with_source(name: &str, sections: &str, source: &str) -> TestSite {
        let sections = if sections.is_empty() {
            String::new()
        } else {
            format!("{sections}\n\n")
        };
        TestSite::new(
            name,
            &format!("{sections}[[camera]]\nid = \"cam01\"\nsource = \"{source}\"\n"),
        )
    }

    /// A site replaying vtest.avi as cam01 in a loop at `speed`.
    pub fn looping_vtest(name: &str, speed: &str) -> TestSite {
        TestSite::new(
            name,
            &format!(
                "[[camera]]\nid = \"cam01\"\nsource = \"{}\"\nspeed = {speed}\nloop = true\n",
                vtest().display()
            ),
        )
    }

    /// A site replaying vtest.avi as cam01 at full speed from `start`, losslessly,
    /// with a subscriber of cam01's stream `S` made before any producer starts, so
    /// that it gets every sample (and the `Ipc` it came from, to keep).
    pub fn lossless_vtest<S: StreamType>(
        name: &str,
        start: &str,
    ) -> (TestSite, Ipc, StreamSubscriber<S>) {
        let site = TestSite::new(
            name,
            &format!("[ipc]\nlossless = true\n\n{}", vtest_camera("max", start)),
        );
        let ipc = site.ipc("subscriber");
        let subscriber = ipc
            .subscriber::<S>("cam01")
            .expect("a subscriber on the test site");
        (site, ipc, subscriber)
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

    /// A private iceoryx2 world for processes started in the returned directory:
    /// iceoryx2 reads `config/iceoryx2.toml` from the working directory, and this
    /// one gives them their own root path and shared-memory prefix. No process of
    /// another test sees (or cleans up) their nodes.
    pub fn private_iceoryx2(&self) -> PathBuf {
        let dir = self.path("iox2");
        std::fs::create_dir_all(dir.join("config")).expect("iceoryx2 config dir");
        let root = self.path("iox2/root/");
        std::fs::create_dir_all(&root).expect("iceoryx2 root");
        let tag = NEXT_SITE.fetch_add(1, Ordering::Relaxed);
        std::fs::write(
            dir.join("config/iceoryx2.toml"),
            format!(
                "[global]\nroot-path = \"{}/\"\nprefix = \"t{}x{tag}_\"\n",
                root.display().to_string().trim_end_matches('/'),
                std::process::id()
            ),
        )
        .expect("iceoryx2 config");
        dir
    }

    /// Runs service `binary` for cam01 until it exits, which it must do within
    /// `timeout`: its exit code and stderr.
    pub fn exit_of(&self, binary: &str, timeout: Duration) -> (Option<i32>, String) {
        let done = self.spawn(binary, &["--camera", "cam01"]).finish(timeout);
        (done.status.code(), done.stderr)
    }

    /// Runs `isochron replay video --out DIR --config site.toml --start START` to
    /// completion (10 minutes at most).
    pub fn replay(&self, video: &Path, out: &Path, start: &str) -> Finished {
        self.isochron(
            &[
                "replay",
                video.to_str().expect("a UTF-8 video path"),
                "--out",
                out.to_str().expect("a UTF-8 output path"),
                "--config",
                self.config_path().to_str().expect("a UTF-8 site directory"),
                "--start",
                start,
            ],
            Duration::from_secs(600),
        )
    }

    /// [`TestSite::replay`], which must succeed (else the test fails with its
    /// output and where the logs are).
    pub fn replay_ok(&self, video: &Path, out: &Path, start: &str) -> Finished {
        let run = self.replay(video, out, start);
        assert!(
            run.status.success(),
            "replay failed\nstdout:\n{}\nstderr:\n{}\nlogs: {}",
            run.stdout,
            run.stderr,
            out.join("logs").display()
        );
        run
    }

    /// Runs `isochron <args>` to completion (with a timeout) and returns it.
    pub fn isochron(&self, args: &[impl AsRef<str>], timeout: Duration) -> Finished {
        let args: Vec<&str> = args.iter().map(AsRef::as_ref).collect();
        let mut proc = Proc::spawn(&bin("isochron"), &args);
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

    /// The rows of `isochron status --json` on this site: one JSON object per
    /// service (`stage`, `camera`, `state`, `pid`, …).
    pub fn status_rows(&self) -> Vec<serde_json::Value> {
        let config = self.config_path().display().to_string();
        let status = self.isochron(
            &["status", "--config", &config, "--json"],
            Duration::from_secs(20),
        );
        status
            .stdout
            .lines()
            .filter_map(|l| serde_json::from_str(l).ok())
            .collect()
    }

    /// The row of `stage` in [`TestSite::status_rows`] (the test fails without one).
    pub fn status_row(&self, stage: &str) -> serde_json::Value {
        let rows = self.status_rows();
        rows.iter()
            .find(|o| o["stage"] == stage)
            .cloned()
            .unwrap_or_else(|| panic!("no {stage} row in the status: {rows:?}"))
    }

    /// The arguments of `isochron tap cam01 frames` on this site: print `count`
    /// frames, give up after `timeout_s`.
    pub fn tap_frames_args(&self, count: u32, timeout_s: u32) -> Vec<String> {
        let config = self.config_path().display().to_string();
        let (count, timeout_s) = (count.to_string(), timeout_s.to_string());
        ["tap", "cam01", "frames", "--config", &config]
            .into_iter()
            .chain(["--count", &count, "--timeout", &timeout_s])
            .map(str::to_string)
            .collect()
    }

    /// Starts `isochron up` on this site (no periodic status, logs in `logs/`),
    /// with `options` (such as `--watchdog-s`).
    pub fn up(&self, options: &[&str]) -> Proc {
        let config = self.config_path().display().to_string();
        let logs = self.path("logs").display().to_string();
        let mut args = vec!["up", "--config", &config, "--status-every-s", "0"];
        args.extend(options);
        args.extend(["--log-dir", &logs]);
        Proc::spawn(&bin("isochron"), &args)
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

/// Reads the samples of `subscriber`, each validated as one of `camera`, and hands
/// them to `each` until it returns `false` (then `true`) or `timeout` passes
/// (then `false`).
pub fn read_samples<S: StreamType>(
    subscriber: &StreamSubscriber<S>,
    camera: &str,
    timeout: Duration,
    mut each: impl FnMut(&S::Header, &[S::Element]) -> bool,
) -> bool {
    let camera = CameraId::new(camera).unwrap_or_else(|| panic!("not a camera id: {camera:?}"));
    let deadline = Instant::now() + timeout;
    while Instant::now() < deadline {
        subscriber.wait(Duration::from_millis(50));
        while let Some(sample) = subscriber.receive().expect("receiving from the subscriber") {
            let header = sample.user_header();
            header
                .validate(&camera, sample.payload().len())
                .unwrap_or_else(|e| panic!("a {} sample: {e}", S::STREAM));
            if !each(header, sample.payload()) {
                return true;
            }
        }
    }
    false
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

/// An OpenCV writer of a colour MJPG video at `path`.
pub fn mjpg_writer(
    path: &Path,
    fps: f64,
    size: opencv::core::Size,
) -> opencv::videoio::VideoWriter {
    use opencv::prelude::*;
    use opencv::videoio::VideoWriter;
    let writer = VideoWriter::new(
        path.to_str().expect("a UTF-8 video path"),
        VideoWriter::fourcc('M', 'J', 'P', 'G').expect("the MJPG fourcc"),
        fps,
        size,
        true,
    )
    .unwrap_or_else(|e| panic!("an MJPG writer at {}: {e}", path.display()));
    assert!(
        writer.is_opened().unwrap_or(false),
        "OpenCV cannot write MJPG"
    );
    writer
}

/// The JSON lines of the file at `path` (none if it is missing).
pub fn read_jsonl(path: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(path)
        .unwrap_or_default()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{}: {e}: {l}", path.display())))
        .collect()
}

/// The items of the JSON array `v`, each read by `item` (which must succeed: the
/// test expects that shape).
pub fn json_list<T>(
    v: &serde_json::Value,
    item: impl Fn(&serde_json::Value) -> Option<T>,
) -> Vec<T> {
    let items = v
        .as_array()
        .unwrap_or_else(|| panic!("expected a JSON array: {v}"));
    items
        .iter()
        .map(|x| item(x).unwrap_or_else(|| panic!("unexpected item {x} in {v}")))
        .collect()
}

/// The Python of the test venv (`target/ros2-venv`, made by `cargo xtask setup`),
/// checked to import `modules` (a Python import list); fails saying what to do.
pub fn venv_python(modules: &str) -> PathBuf {
    let path = setup_file(
        "ISOCHRON_ROS2_PYTHON",
        "target/ros2-venv/bin/python3",
        &format!("(it makes a Python venv with the test peers' packages: {modules})"),
    );
    let ok = Command::new(&path)
        .args(["-c", &format!("import {modules}")])
        .status()
        .is_ok_and(|s| s.success());
    assert!(
        ok,
        "{} cannot import {modules}: run `cargo xtask setup` again",
        path.display()
    );
    path
}

/// The `node_modules` of the npm test peers (`target/node-peers`, which `cargo
/// xtask setup` installs from `tests/view/package.json`), for `NODE_PATH`; fails
/// saying what to do when they are missing.
pub fn node_modules() -> PathBuf {
    let package = setup_file(
        "ISOCHRON_NODE_PEERS",
        "target/node-peers/node_modules/@foxglove/ws-protocol/package.json",
        "(it installs the npm test peers: @foxglove/ws-protocol, ws, protobufjs)",
    );
    package
        .ancestors()
        .nth(3)
        .expect("node_modules/@foxglove/ws-protocol/package.json")
        .to_path_buf()
}

/// The resident set size of process `pid` (`VmRSS` in `/proc/<pid>/status`),
/// bytes; `None` once it has gone.
pub fn rss_bytes(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let kb: u64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))?
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    Some(kb * 1024)
}

/// The camera section for vtest.avi at `speed`, starting at `start`.
pub fn vtest_camera(speed: &str, start: &str) -> String {
    format!(
        "[[camera]]\nid = \"cam01\"\nsource = \"{}\"\nspeed = \"{speed}\"\nstart = \"{start}\"\n",
        vtest().display()
    )
}

/// The pid in a launcher line such as `up: capture/cam01 started pid=123`.
pub fn pid_in(line: &str) -> u32 {
    line.rsplit("pid=")
        .next()
        .and_then(|s| s.split_whitespace().next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no pid in '{line}'"))
}

/// Runs `ip args`; its status and stderr.
pub fn ip(args: &[&str]) -> (bool, String) {
    match Command::new("ip").args(args).output() {
        Ok(o) => (
            o.status.success(),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        ),
        Err(e) => (false, e.to_string()),
    }
}

/// Two network namespaces joined by a veth pair — `10.77.<subnet>.1/24` in the
/// first, `.2/24` in the second, loopback up and a 224.0.0.0/4 route on each side
/// for DDS multicast discovery — deleted on drop.
pub struct NetnsPair {
    /// The namespaces.
    pub names: [String; 2],
    /// Their veth ends, in the same order.
    pub veths: [String; 2],
    /// Their addresses, in the same order.
    pub addrs: [String; 2],
}

impl NetnsPair {
    /// Makes the pair, named after `tag` (unique per test; short: interface names
    /// have at most 15 bytes). `None` where the kernel refuses `ip netns add` (not
    /// root), which is an error in CI (which runs as root).
    pub fn new(tag: &str, subnet: u8) -> Option<NetnsPair> {
        let names = [format!("isoa{tag}"), format!("isob{tag}")];
        let (ok, err) = ip(&["netns", "add", &names[0]]);
        if !ok {
            assert!(
                std::env::var("CI").is_err(),
                "`ip netns add` failed in CI (which runs as root): {err}"
            );
            eprintln!("skipped: `ip netns add` failed (needs root and iproute2): {err}");
            return None;
        }
        let pair = NetnsPair {
            veths: [format!("va{tag}"), format!("vb{tag}")],
            addrs: [format!("10.77.{subnet}.1"), format!("10.77.{subnet}.2")],
            names,
        };
        let [a, b] = &pair.names;
        let [va, vb] = &pair.veths;
        let mut steps: Vec<Vec<String>> = vec![
            vec!["netns".into(), "add".into(), b.clone()],
            vec![
                "link", "add", va, "netns", a, "type", "veth", "peer", "name", vb, "netns", b,
            ]
            .into_iter()
            .map(String::from)
            .collect(),
        ];
        for k in 0..2 {
            let (ns, veth) = (&pair.names[k], &pair.veths[k]);
            let addr = format!("{}/24", pair.addrs[k]);
            for step in [
                vec!["-n", ns, "addr", "add", &addr, "dev", veth],
                vec!["-n", ns, "link", "set", veth, "up"],
                vec!["-n", ns, "link", "set", "lo", "up"],
                vec!["-n", ns, "route", "add", "224.0.0.0/4", "dev", veth],
            ] {
                steps.push(step.into_iter().map(String::from).collect());
            }
        }
        for step in &steps {
            let args: Vec<&str> = step.iter().map(String::as_str).collect();
            let (ok, err) = ip(&args);
            assert!(ok, "ip {}: {err}", args.join(" "));
        }
        Some(pair)
    }

    /// Sets namespace `k`'s veth end up or down (both ends' carrier follows).
    pub fn set_link(&self, k: usize, up: bool) {
        let state = if up { "up" } else { "down" };
        let (ok, err) = ip(&["-n", &self.names[k], "link", "set", &self.veths[k], state]);
        assert!(ok, "setting {} {state}: {err}", self.veths[k]);
    }

    /// Bytes namespace `k`'s veth end has sent so far.
    pub fn tx_bytes(&self, k: usize) -> u64 {
        let out = Command::new("ip")
            .args(["netns", "exec", &self.names[k], "cat"])
            .arg(format!(
                "/sys/class/net/{}/statistics/tx_bytes",
                self.veths[k]
            ))
            .output()
            .expect("ip netns exec");
        String::from_utf8_lossy(&out.stdout)
            .trim()
            .parse()
            .unwrap_or(0)
    }

    /// `program args` started inside namespace `k`.
    pub fn spawn(&self, k: usize, program: &Path, args: &[impl AsRef<str>]) -> Proc {
        let mut all = vec![
            "netns".to_string(),
            "exec".into(),
            self.names[k].clone(),
            program.display().to_string(),
        ];
        all.extend(args.iter().map(|a| a.as_ref().to_string()));
        Proc::spawn(Path::new("ip"), &all)
    }
}

impl Drop for NetnsPair {
    fn drop(&mut self) {
        for n in &self.names {
            ip(&["netns", "del", n]);
        }
    }
}

/// utime + stime of process `pid`, in clock ticks.
pub fn cpu_ticks(pid: u32) -> Option<u64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // The command (field 2) may hold spaces: count fields after its ')'.
    let rest = &stat[stat.rfind(')')? + 1..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    // Fields from 3 (state) on: utime is field 14, stime 15.
    let utime: u64 = fields.get(11)?.parse().ok()?;
    let stime: u64 = fields.get(12)?.parse().ok()?;
    Some(utime + stime)
}

/// Clock ticks per second.
pub fn clock_ticks_per_s() -> f64 {
    // SAFETY: sysconf has no preconditions.
    let ticks = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    if ticks > 0 { ticks as f64 } else { 100.0 }
}

/// Reads a benchmark's command line into `(flag, value)` pairs in order: the
/// `valued` flags take a value (`--flag V` or `--flag=V`), the `bare` ones none
/// (`None`). `--help` or `-h` gives `usage` as the error, as does a missing
/// value; other arguments are ignored with a note naming `bench` (silently for
/// the `--bench` cargo passes).
pub fn bench_args(
    bench: &str,
    usage: &str,
    (bare, valued): (&[&str], &[&str]),
    args: impl IntoIterator<Item = String>,
) -> Result<Vec<(String, Option<String>)>, String> {
    let mut out = Vec::new();
    let mut args = args.into_iter();
    while let Some(arg) = args.next() {
        let (flag, inline) = match arg.split_once('=') {
            Some((f, v)) => (f.to_string(), Some(v.to_string())),
            None => (arg.clone(), None),
        };
        if flag == "--help" || flag == "-h" {
            return Err(usage.into());
        }
        if bare.contains(&flag.as_str()) {
            out.push((flag, None));
        } else if valued.contains(&flag.as_str()) {
            let value = inline
                .or_else(|| args.next())
                .ok_or_else(|| format!("{flag} needs a value\n{usage}"))?;
            out.push((flag, Some(value)));
        } else if flag != "--bench" {
            eprintln!("{bench}: ignoring unknown argument '{arg}'");
        }
    }
    Ok(out)
}

/// A benchmark's options, which `parse` reads from its command line (after the
/// program's name); on an error (or `--help`) prints it and exits with 2.
pub fn bench_options<T>(
    parse: impl FnOnce(std::iter::Skip<std::env::Args>) -> Result<T, String>,
) -> T {
    parse(std::env::args().skip(1)).unwrap_or_else(|e| {
        eprintln!("{e}");
        std::process::exit(2);
    })
}

/// The seconds (at least `min`) a benchmark option `flag` gives.
pub fn bench_secs(flag: &str, value: &str, min: f64) -> Result<Duration, String> {
    value
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite() && *v >= min)
        .map(Duration::from_secs_f64)
        .ok_or_else(|| format!("{flag}: expected seconds ≥ {min}, found '{value}'"))
}

/// The count (at least 1) a benchmark option `flag` gives.
pub fn bench_count(flag: &str, value: &str) -> Result<usize, String> {
    value
        .parse::<usize>()
        .ok()
        .filter(|v| *v >= 1)
        .ok_or_else(|| format!("{flag}: expected a whole number ≥ 1, found '{value}'"))
}
