//! Harness for the multi-process tests: finds the built binaries and the sample
//! video, gives each test its own site (directory, config, iceoryx2 prefix), and
//! runs service processes that are killed when the test ends.
//!
//! Beside it: the processes a test runs (`process`), network namespaces
//! (`netns`), the reference peers (`peers`) and what the benchmarks share
//! (`bench`), all re-exported here.
//!
//! Binaries must be built first (`cargo xtask test` does it; by hand:
//! `cargo build --workspace --bins`).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

use isochron_config::{Config, LoadedConfig};
use isochron_runtime::ipc::{Ipc, StreamSubscriber, StreamType};
use isochron_runtime::names::ServiceNames;
use isochron_wire::{CameraId, StreamHeader};

mod bench;
mod netns;
mod peers;
mod process;
mod tmpfs;

pub use bench::{
    bench_args, bench_count, bench_options, bench_secs, clock_ticks_per_s, cpu_ticks, rss_bytes,
};
pub use netns::{NetnsPair, ip};
pub use peers::{node_modules, venv_python};
pub use process::{Finished, Proc, eventually, named_thread, pid_in};
pub use tmpfs::Tmpfs;

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

/// A file `cargo xtask setup --all` provides: `$var` if set, else `default` under the
/// repository root. Fails, saying to run the setup (`why` tells what for), when
/// it is missing.
pub fn setup_file(var: &str, default: &str, why: &str) -> PathBuf {
    let path = std::env::var_os(var)
        .map(PathBuf::from)
        .unwrap_or_else(|| repo_root().join(default));
    assert!(
        path.is_file(),
        "{} is missing: run `cargo xtask setup --all` {why}",
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

/// The camera section for vtest.avi at `speed`, starting at `start`.
pub fn vtest_camera(speed: &str, start: &str) -> String {
    format!(
        "[[camera]]\nid = \"cam01\"\nsource = \"{}\"\nspeed = \"{speed}\"\nstart = \"{start}\"\n",
        vtest().display()
    )
}

/// `isochron synth` of cam01 on the office profile the docs use
/// (`config/profiles/office.csv`) for `days` days into `out`, at 1 fps on 16x12
/// blocks (`fps` overrides the rate).
pub fn office_synth_args(out: &Path, days: &str, fps: &str) -> Vec<String> {
    let profile = repo_root().join("config/profiles/office.csv");
    let (profile, out) = (profile.display().to_string(), out.display().to_string());
    [
        "synth",
        "--camera",
        "cam01",
        "--profile",
        &profile,
        "--days",
        days,
        "--out",
        &out,
        "--fps",
        fps,
        "--grid",
        "16x12",
    ]
    .map(str::to_string)
    .to_vec()
}
