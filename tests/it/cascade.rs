//! isochron-cascade as a separate process: fed by this test or by `isochron synth`,
//! killed at random moments, restarted, and read through its store.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use fastrand::Rng as Lcg;
use isochron_config::Config;
use isochron_config::clock::{Cycle, NS_PER_S, parse_rfc3339};
use isochron_runtime::ipc::{Activity, Ipc, Motion, StreamPublisher};
use isochron_runtime::names::ServiceNames;
use isochron_store::{Store, StoreMeta, store_path};
use isochron_tests::{Proc, TestSite, bin, eventually, named_thread, read_samples, vtest};
use isochron_wire::geometry::BlockGrid;
use isochron_wire::{
    ActivityHeader, BlockMotion, CameraId, FLAG_END_OF_STREAM, MotionHeader, Preamble, Stream,
};
use parking_lot::Mutex;

/// The office hallway of the paper's figure (the profile the docs' `synth`
/// commands use): activity from 6 am, a lull at lunch, the busiest time at
/// 4:30 pm, quiet after 9 pm.
const OFFICE: &str = include_str!("../../config/profiles/office.csv");

/// The profile at `minute` (fractional), linear between rows, as synth reads it.
fn office_at(minute: f64) -> f64 {
    let rows: Vec<(f64, f64)> = OFFICE
        .lines()
        .skip(1)
        .map(|l| {
            let (a, b) = l.split_once(',').unwrap();
            (a.parse().unwrap(), b.parse().unwrap())
        })
        .collect();
    let i = rows.partition_point(|r| r.0 <= minute);
    let (a, b) = if i == 0 || i == rows.len() {
        (rows[rows.len() - 1], rows[0])
    } else {
        (rows[i - 1], rows[i])
    };
    let span = (b.0 - a.0).rem_euclid(1440.0);
    a.1 + (minute - a.0).rem_euclid(1440.0) / span * (b.1 - a.1)
}

/// Runs `isochron args` to completion and returns its stdout; panics with its output
/// if it fails.
fn isochron(site: &TestSite, args: &[impl AsRef<str>], timeout: Duration) -> String {
    let args: Vec<&str> = args.iter().map(AsRef::as_ref).collect();
    let done = site.isochron(&args, timeout);
    assert!(
        done.status.success(),
        "isochron {args:?} failed ({}):\nstdout:\n{}\nstderr:\n{}",
        done.status,
        done.stdout,
        done.stderr
    );
    done.stdout
}

/// A site with the [`OFFICE`] profile in `office.csv`, and the directory synth
/// writes into (`run/`).
fn office_site(name: &str) -> (TestSite, PathBuf) {
    let site = TestSite::new(name, "");
    std::fs::write(site.path("office.csv"), OFFICE).unwrap();
    let out = site.path("run");
    (site, out)
}

/// The arguments of `isochron synth` of cam01 on the office profile of `site`
/// into `out`: `days` at `fps` on a `grid` of blocks, then `options`.
fn synth_args(
    site: &TestSite,
    out: &Path,
    (days, fps, grid): (&str, &str, &str),
    options: &[&str],
) -> Vec<String> {
    let profile = site.path("office.csv").display().to_string();
    let out = out.display().to_string();
    let args = ["synth", "--camera", "cam01", "--profile", &profile];
    args.into_iter()
        .chain(["--days", days, "--out", &out, "--fps", fps, "--grid", grid])
        // The office's profile is one day: the paper's daily model recovers it.
        .chain(["--cycle", "daily"])
        .chain(options.iter().copied())
        .map(str::to_string)
        .collect()
}

/// Runs `isochron <command> --store <store> --camera cam01 <options>`; returns its
/// stdout.
fn store_command(site: &TestSite, command: &[&str], store: &Path, options: &[&str]) -> String {
    let store = store.display().to_string();
    let args: Vec<&str> = command
        .iter()
        .copied()
        .chain(["--store", &store, "--camera", "cam01"])
        .chain(options.iter().copied())
        .collect();
    isochron(site, &args, Duration::from_secs(60))
}

/// Parses `minute_of_day,mean,sigma,count` rows.
fn parse_export(csv: &str) -> Vec<(u32, Option<f64>, Option<f64>, u32)> {
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some("minute_of_day,mean,sigma,count"));
    lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            assert_eq!(f.len(), 4, "{l}");
            (
                f[0].parse().unwrap(),
                f[1].parse().ok(),
                f[2].parse().ok(),
                f[3].parse().unwrap(),
            )
        })
        .collect()
}

/// The commit latencies the cascade logged at end of stream.
fn commit_latency(log: &Path) -> String {
    let text = std::fs::read_to_string(log).unwrap();
    let line = text
        .lines()
        .rev()
        .find(|l| l.contains("store commit p50"))
        .unwrap_or_else(|| panic!("no commit latency in {}:\n{text}", log.display()));
    let from = &line[line.find("store commit").unwrap()..];
    from.split(';').next().unwrap_or(from).to_string()
}

#[test]
fn fourteen_simulated_days_of_an_office_are_learned() {
    let (site, out) = office_site("synth14");
    let started = Instant::now();
    let stdout = isochron(
        &site,
        &synth_args(
            &site,
            &out,
            ("14", "2", "16x12"),
            &["--arrivals-per-min", "60", "--seed", "7"],
        ),
        Duration::from_secs(900),
    );
    let wall = started.elapsed();
    assert!(stdout.contains("0 cascade restarts"), "{stdout}");
    let store = store_path(&out, "cam01");
    let s = Store::open_read_only(&store, "cam01").unwrap();
    s.verify().unwrap();
    let progress = s.progress().unwrap();
    // Lossless: every minute of every day had all its frames and taught its bin.
    assert_eq!((progress.committed, progress.skipped), (14 * 1440, 0));

    let csv = store_command(&site, &["store", "export"], &store, &[]);
    let rows = parse_export(&csv);
    assert_eq!(rows.len(), 1440);
    assert!(rows.iter().all(|r| r.3 == 14), "every bin learned 14 days");
    let learned: Vec<f64> = rows.iter().map(|r| r.1.unwrap()).collect();
    let truth: Vec<f64> = (0..1440).map(|m| office_at(m as f64 + 0.5)).collect();

    // Pearson correlation.
    let n = 1440.0;
    let (ml, mt) = (
        learned.iter().sum::<f64>() / n,
        truth.iter().sum::<f64>() / n,
    );
    let cov: f64 = learned
        .iter()
        .zip(&truth)
        .map(|(l, t)| (l - ml) * (t - mt))
        .sum();
    let vl: f64 = learned.iter().map(|l| (l - ml).powi(2)).sum();
    let vt: f64 = truth.iter().map(|t| (t - mt).powi(2)).sum();
    let correlation = cov / (vl * vt).sqrt();
    // Normalised error: the model is in density units, the profile in 0..1, so the
    // learned profile is scaled by the least-squares factor; the RMS error is then
    // normalised by the profile's range (NRMSE).
    let scale = learned.iter().zip(&truth).map(|(l, t)| l * t).sum::<f64>()
        / learned.iter().map(|l| l * l).sum::<f64>();
    let rmse = (learned
        .iter()
        .zip(&truth)
        .map(|(l, t)| (scale * l - t).powi(2))
        .sum::<f64>()
        / n)
        .sqrt();
    let range = truth.iter().cloned().fold(f64::MIN, f64::max)
        - truth.iter().cloned().fold(f64::MAX, f64::min);
    let nrmse = rmse / range;
    let latency = commit_latency(&out.join("cascade.log"));
    eprintln!(
        "14 days (2 fps, 16x12 blocks, 60 arrivals/min at activity 1) in {:.1} s: correlation {correlation:.4}, NRMSE {:.2} %, {latency}",
        wall.as_secs_f64(),
        nrmse * 100.0
    );
    assert!(correlation >= 0.95, "correlation {correlation}");
    assert!(nrmse <= 0.05, "normalised error {nrmse}");
    // Nights are empty, the busiest learned hour is the afternoon peak.
    assert!(learned[..300].iter().all(|&l| l == 0.0));
    let peak = (0..1440)
        .max_by(|&a, &b| learned[a].total_cmp(&learned[b]))
        .unwrap();
    assert!((8 * 60..18 * 60).contains(&peak), "peak at minute {peak}");

    // The same as a plot, PNG and SVG, and one block as CSV.
    for name in ["office.png", "office.svg"] {
        let image = site.path(name);
        let said = store_command(
            &site,
            &["plot", "daily"],
            &store,
            &["--out", image.to_str().unwrap()],
        );
        assert!(said.contains("quiet times of the working day: 1"), "{said}");
        assert!(std::fs::metadata(&image).unwrap().len() > 10_000);
    }
    let one = parse_export(&store_command(
        &site,
        &["store", "export"],
        &store,
        &["--block", "8,6"],
    ));
    assert!(one.iter().any(|r| r.1.unwrap() > 0.0));
    let info = store_command(&site, &["store", "info"], &store, &[]);
    assert!(
        info.contains("1440 learned") && info.contains("days/bin    14..14"),
        "{info}"
    );
    let json: serde_json::Value = serde_json::from_str(&store_command(
        &site,
        &["store", "info"],
        &store,
        &["--json"],
    ))
    .expect("store info --json is one JSON object");
    assert_eq!(json["bins_learned"], 1440, "{json}");
    assert_eq!(json["days_per_bin"]["min"], 14, "{json}");
    assert_eq!(json["check"], "ok");
    // The directory synth wrote stands for the camera's store in it.
    let dir = store.parent().unwrap();
    let from_dir = store_command(&site, &["store", "export"], dir, &["--block", "8,6"]);
    assert_eq!(parse_export(&from_dir), one);
    let dir_arg = dir.display().to_string();
    let other = site.isochron(
        &["store", "export", "--store", &dir_arg, "--camera", "cam09"],
        Duration::from_secs(60),
    );
    assert_eq!(other.status.code(), Some(66), "{}", other.stderr);
    assert!(
        other.stderr.contains("cam09.isochron.sqlite")
            && other.stderr.contains("it has cam01.isochron.sqlite")
            && other.stderr.lines().count() == 1,
        "{}",
        other.stderr
    );
}

/// Follows a synth run from outside: the cascade's pid (from synth's output) and its
/// activity (through iceoryx2, like any consumer).
struct Observer {
    latest_second: Arc<AtomicI64>,
    seconds: Arc<AtomicU64>,
    days_seen: Arc<Mutex<Vec<(i64, u32)>>>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Observer {
    fn start(config: &Path) -> Observer {
        let prefix = Config::load(config).unwrap().config.site.service_prefix;
        let latest_second = Arc::new(AtomicI64::new(i64::MIN));
        let seconds = Arc::new(AtomicU64::new(0));
        let days_seen = Arc::new(Mutex::new(Vec::new()));
        let stop = Arc::new(AtomicBool::new(false));
        let (l, s, d, st) = (
            latest_second.clone(),
            seconds.clone(),
            days_seen.clone(),
            stop.clone(),
        );
        let config = config.to_path_buf();
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let thread = named_thread("observer", move || {
            let loaded = Config::load(&config).unwrap();
            let ipc = Ipc::new(
                "test-observer",
                ServiceNames::new(&prefix),
                loaded.config.ipc.clone(),
            )
            .unwrap();
            let sub = ipc.subscriber::<Activity>("cam01").unwrap();
            ready_tx.send(()).unwrap();
            let camera = CameraId::new("cam01").unwrap();
            while !st.load(Ordering::Acquire) {
                sub.wait(Duration::from_millis(20));
                sub.drain_wakeups();
                while let Ok(Some(sample)) = sub.receive() {
                    let h: &ActivityHeader = sample.user_header();
                    h.validate(&camera, sample.payload().len()).unwrap();
                    if h.preamble.is_end_of_stream() {
                        continue;
                    }
                    let second = h.preamble.capture_time_ns / NS_PER_S - 1;
                    l.fetch_max(second, Ordering::AcqRel);
                    s.fetch_add(1, Ordering::Relaxed);
                    if second % 60 == 30 {
                        d.lock().push((second, h.model_days));
                    }
                }
            }
        });
        ready_rx.recv_timeout(Duration::from_secs(30)).unwrap();
        Observer {
            latest_second,
            seconds,
            days_seen,
            stop,
            thread: Some(thread),
        }
    }
}

impl Drop for Observer {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The pid of the cascade synth started last, from its output.
fn cascade_pid(synth: &mut Proc, not: Option<u32>, timeout: Duration) -> Option<u32> {
    eventually(timeout, || {
        let out = synth.stdout();
        let pid: u32 = out
            .lines()
            .rev()
            .find_map(|l| l.strip_prefix("synth: cascade started pid="))?
            .trim()
            .parse()
            .ok()?;
        (Some(pid) != not).then_some(pid)
    })
}

#[test]
fn killing_the_cascade_at_random_moments_loses_at_most_the_minute_in_progress() {
    const KILLS: usize = 15;
    let (site, out) = office_site("kill");
    let mut synth = Proc::spawn(
        &bin("isochron"),
        &synth_args(
            &site,
            &out,
            ("4", "2", "16x12"),
            &["--start", "2026-03-02T06:00:00Z"],
        ),
    );
    let mut pid = cascade_pid(&mut synth, None, Duration::from_secs(60))
        .unwrap_or_else(|| panic!("synth did not start the cascade:\n{}", synth.stderr()));
    let observer = Observer::start(&out.join("synth.toml"));
    let store = store_path(&out, "cam01");
    let seed = std::process::id() as u64;
    let mut rng = Lcg::with_seed(seed);
    let mut kills = 0;
    let mut worst_lag = 0;
    // Activity seen when the current cascade process was started, and how many
    // restarted processes produced activity (each of those must have resumed).
    let mut seconds_at_start = 0;
    let mut productive_restarts = 0;
    let produced = |since: u64| observer.seconds.load(Ordering::Acquire) > since + 1;
    while kills < KILLS {
        // Every fourth kill hits a process that may still be starting (opening and
        // checking the store); the others one that has filtered a while.
        let starting = kills % 4 == 3;
        if !starting {
            eventually(Duration::from_secs(120), || {
                produced(seconds_at_start).then_some(())
            })
            .unwrap_or_else(|| panic!("the cascade produces nothing:\n{}", synth.stderr()));
        }
        let wait = if starting {
            0.3 * rng.f64()
        } else {
            0.2 + 1.3 * rng.f64()
        };
        std::thread::sleep(isochron_config::clock::saturating_secs(wait));
        if synth.wait(Duration::ZERO).is_some() {
            break; // the run ended before all kills
        }
        if !store.exists() || observer.seconds.load(Ordering::Relaxed) == 0 {
            continue;
        }
        // What was durable and what was seen before the kill.
        let before = Store::open_read_only(&store, "cam01")
            .unwrap()
            .read_model()
            .unwrap();
        let seen = observer.latest_second.load(Ordering::Acquire);
        // SAFETY: kill(2) with SIGKILL on the cascade, a process of this test's synth.
        let rc = unsafe { libc::kill(pid as i32, libc::SIGKILL) };
        assert_eq!(rc, 0, "kill {pid}");
        if kills > 0 && produced(seconds_at_start) {
            productive_restarts += 1;
        }
        kills += 1;

        // The store opens and validates at once, while the process is dead.
        let after = Store::open_read_only(&store, "cam01")
            .unwrap_or_else(|e| panic!("kill {kills}: the store does not open: {e}"));
        let report = after
            .verify()
            .unwrap_or_else(|e| panic!("kill {kills}: the store does not validate: {e}"));
        let model = after.read_model().unwrap();
        // Nothing that was committed was lost...
        for (b, a) in before.bins.iter().zip(&model.bins) {
            if let Some(b) = b {
                let a = a.as_ref().expect("a learned bin disappeared");
                assert!(a.count >= b.count && a.last_minute >= b.last_minute);
            }
        }
        // ... and every minute before the one of the last activity seen is durable.
        let last_minute = report.progress.last_minute.expect("minutes were committed");
        let seen_minute = seen.div_euclid(60);
        assert!(
            last_minute >= seen_minute - 1,
            "kill {kills}: activity of minute {seen_minute} was seen, but the store ends at minute {last_minute}"
        );
        worst_lag = worst_lag.max(seen_minute - last_minute);
        drop(after);
        pid = cascade_pid(&mut synth, Some(pid), Duration::from_secs(60)).unwrap_or_else(|| {
            panic!(
                "kill {kills}: synth did not restart the cascade:\n{}\n{}",
                synth.stdout(),
                synth.stderr()
            )
        });
        // (The new process subscribes only after synth announced it.)
        seconds_at_start = observer.seconds.load(Ordering::Acquire);
    }
    let status = synth
        .wait(Duration::from_secs(600))
        .expect("synth finishes after the kills");
    assert!(
        status.success(),
        "synth failed:\n{}\n{}",
        synth.stdout(),
        synth.stderr()
    );
    let stdout = synth.stdout();
    assert!(
        kills >= 10,
        "only {kills} kills happened before the run ended"
    );
    assert!(
        stdout.contains(&format!("{kills} cascade restarts")),
        "{stdout}"
    );

    // After the run: valid, and the restarts resumed (baseline and model).
    let s = Store::open_read_only(&store, "cam01").unwrap();
    let report = s.verify().unwrap();
    let progress = report.progress;
    let model = s.read_model().unwrap();
    let log = std::fs::read_to_string(out.join("cascade.log")).unwrap();
    let resumed = log
        .matches("resumed the F_L1 baseline from the store")
        .count();
    // Every restarted process that filtered anything resumed the baseline: those
    // killed while running, and the last one, which ran to the end.
    if kills > 0 && produced(seconds_at_start) {
        productive_restarts += 1;
    }
    assert!(
        resumed >= productive_restarts && productive_restarts >= kills / 2,
        "{resumed} resumes, {productive_restarts} restarted processes that filtered, {kills} kills"
    );
    // Four days from 06:00: most bins learned 4 days despite the kills.
    let fours = model.learned().filter(|b| b.count == 4).count();
    assert!(fours > 1300, "{fours} bins with 4 days");
    assert!(progress.committed > 4 * 1440 - 100, "{progress:?}");
    // The model the cascade reported after the first day comes from the store: the
    // bins of day 1 were seen as known on days 2..4, whatever restarts happened.
    let start_s = parse_rfc3339("2026-03-02T06:00:00Z").unwrap() / NS_PER_S;
    let days = observer.days_seen.lock().clone();
    let later: Vec<_> = days
        .iter()
        .filter(|(s, _)| *s >= start_s + 86_400)
        .collect();
    assert!(later.len() > 1000, "{}", later.len());
    // (A bin whose day-1 minute was lost to a kill still has 0 days on day 2.)
    let known = later.iter().filter(|(_, d)| *d >= 1).count();
    assert!(
        known as f64 >= 0.95 * later.len() as f64,
        "only {known} of {} samples after day 1 knew their bin's past days",
        later.len()
    );
    eprintln!(
        "{kills} kills -9 (seed {seed}): store valid after every kill, at most {worst_lag} minute(s) between the last activity seen and the last durable minute; {resumed} resumes ({productive_restarts} restarted processes filtered); {} bins learned 4 days; {}",
        fours,
        commit_latency(&out.join("cascade.log"))
    );
}

#[test]
fn a_restarted_cascade_resumes_from_the_store() {
    let (site, out) = office_site("resume");
    let synth = |start: &str, seed: &str| {
        isochron(
            &site,
            &synth_args(
                &site,
                &out,
                ("1", "1", "8x6"),
                &["--start", start, "--seed", seed],
            ),
            Duration::from_secs(300),
        )
    };
    synth("2026-03-02", "1");
    let store = store_path(&out, "cam01");
    let day1 = Store::open_read_only(&store, "cam01")
        .unwrap()
        .read_model()
        .unwrap();
    assert!(day1.learned().all(|b| b.count == 1));
    assert_eq!(day1.learned().count(), 1440);
    // A new cascade process (and a new synth) the next day: same store, it goes on.
    synth("2026-03-03", "2");
    let day2 = Store::open_read_only(&store, "cam01")
        .unwrap()
        .read_model()
        .unwrap();
    assert_eq!(day2.learned().count(), 1440);
    assert!(
        day2.learned().all(|b| b.count == 2),
        "the second day added to the first"
    );
    let log = std::fs::read_to_string(out.join("cascade.log")).unwrap();
    assert!(
        log.contains("resumed the F_L1 baseline from the store"),
        "{log}"
    );
    // A busy minute's model moved towards the second day, not replaced by it.
    let b = day2.bin(16 * 60 + 30).unwrap();
    let a = day1.bin(16 * 60 + 30).unwrap();
    assert!(b.mean != a.mean && b.var.iter().any(|&v| v > 0.0));
}

/// Starts the cascade of `site`, fed by this test on `publisher` (cam01's motion,
/// made first so that the test may subscribe before the cascade starts), and
/// waits until it subscribed.
fn start_fed_cascade(site: &TestSite, publisher: &StreamPublisher<Motion>) -> (Proc, MotionFeed) {
    let cascade = site.spawn("isochron-cascade", &["--camera", "cam01"]);
    eventually(Duration::from_secs(30), || {
        (publisher.subscriber_count() > 0).then_some(())
    })
    .unwrap_or_else(|| panic!("the cascade did not subscribe:\n{}", cascade.stderr()));
    let feed = MotionFeed {
        sequence: 0,
        camera: CameraId::new("cam01").unwrap(),
    };
    (cascade, feed)
}

/// Motion published by this test.
struct MotionFeed {
    sequence: u64,
    camera: CameraId,
}

impl MotionFeed {
    fn header(&mut self, t_ns: i64, blocks: usize, flags: u32) -> MotionHeader {
        let mut preamble =
            Preamble::new::<BlockMotion>(Stream::Motion, self.camera, self.sequence, blocks);
        self.sequence += 1;
        preamble.capture_time_ns = t_ns;
        preamble.flags = flags;
        MotionHeader {
            preamble,
            frame_width: 64,
            frame_height: 32,
            block_px: 16,
            grid_w: 4,
            grid_h: 2,
            changed_fraction: 0.0,
            source_index: self.sequence - 1,
        }
    }
}

#[test]
fn the_service_filters_shared_memory_rejects_bad_samples_and_passes_end_of_stream() {
    let site = TestSite::with_source("cascade-svc", "[ipc]\nlossless = true", "unused.avi");
    let ipc = site.ipc("feeder");
    let publisher = ipc.publisher::<Motion>("cam01", 8).unwrap();
    let activity = ipc.subscriber::<Activity>("cam01").unwrap();
    let (mut cascade, mut feed) = start_fed_cascade(&site, &publisher);
    let t0 = parse_rfc3339("2026-03-02T08:00:00Z").unwrap();
    let walker = |i: i64| -> Vec<BlockMotion> {
        let mut b = vec![BlockMotion::default(); 8];
        let x = (i / 5 % 4) as usize;
        b[4 + x] = BlockMotion {
            density: 0.6,
            dx: 0.5,
            dy: 0.0,
            ..Default::default()
        };
        b
    };
    // 5.5 s at 10 fps, with a NaN sample and a truncated one in the middle.
    for i in 0..55i64 {
        let t = t0 + i * NS_PER_S / 10;
        if i == 20 {
            let mut bad = walker(i);
            bad[0].density = f32::NAN;
            publisher.send_copy(feed.header(t, 8, 0), &bad).unwrap();
            publisher
                .send_copy(feed.header(t, 8, 0), &walker(i)[..7])
                .unwrap();
        }
        publisher
            .send_copy(feed.header(t, 8, 0), &walker(i))
            .unwrap();
    }
    publisher
        .send_copy(
            feed.header(t0 + 55 * NS_PER_S / 10, 0, FLAG_END_OF_STREAM),
            &[],
        )
        .unwrap();

    let mut seconds = Vec::new();
    let ended = read_samples(&activity, "cam01", Duration::from_secs(30), |h, blocks| {
        let more = !h.preamble.is_end_of_stream();
        if more {
            seconds.push((*h, blocks.to_vec()));
        }
        more
    });
    assert!(
        ended,
        "no end of stream; got {} seconds:\n{}",
        seconds.len(),
        cascade.stderr()
    );
    // Five whole seconds and the half second flushed at the end of stream.
    let frames: Vec<u32> = seconds.iter().map(|(h, _)| h.frames).collect();
    assert_eq!(frames, vec![10, 10, 10, 10, 10, 5]);
    for (i, (h, _)) in seconds.iter().enumerate() {
        assert_eq!(h.preamble.sequence, i as u64);
        assert_eq!(h.preamble.capture_time_ns, t0 + (i as i64 + 1) * NS_PER_S);
        assert_eq!(h.t_star, 8 * 60);
        assert_eq!((h.grid_w, h.grid_h), (4, 2));
        assert_eq!(
            h.first_source_index,
            10 * i as u64 + if i >= 2 { 2 } else { 0 }
        );
    }
    assert!((seconds[4].0.frame_rate - 10.0).abs() < 0.01);
    // The walker moves along the bottom row: moving activity, to the right.
    // (A fresh cascade's F_L1 is still warming up: the baseline is the running mean.)
    assert!(
        seconds
            .iter()
            .any(|(_, b)| b[5].s2 > 0.1 && b[5].s2_dx > 0.0)
    );
    assert!(
        seconds
            .iter()
            .all(|(_, b)| b[0].s1 == 0.0 && b[0].s2 == 0.0)
    );
    // Still running after the end of stream, and it said what it rejected.
    std::thread::sleep(Duration::from_millis(200));
    assert!(
        cascade.wait(Duration::ZERO).is_none(),
        "{}",
        cascade.stderr()
    );
    let stderr = cascade.stderr();
    assert!(
        stderr.contains("rejected motion sample: block 0"),
        "{stderr}"
    );
    assert!(stderr.contains("payload size mismatch"), "{stderr}");
    let status = cascade.terminate(Duration::from_secs(10));
    assert!(status.success(), "{}", cascade.stderr());
    assert!(!cascade.stderr().contains("panicked"));
    // The store of the half minute exists (nothing learned: too few frames).
    let s = Store::open_read_only(&site.path("state/cam01.isochron.sqlite"), "cam01").unwrap();
    let p = s.progress().unwrap();
    assert_eq!((p.committed, p.skipped), (0, 1));
}

/// Makes an empty store of `camera` whose model has blocks of 16 px over a
/// `width × height` frame.
fn write_store_for(path: &Path, camera: &str, (width, height): (u32, u32)) {
    let meta = StoreMeta::new(
        camera,
        BlockGrid::new(width, height, 16),
        Cycle::DayTypes,
        0,
    );
    Store::open_or_create(path, &meta).unwrap();
}

#[test]
fn foreign_or_damaged_stores_stop_the_service_with_a_clear_error() {
    let site = TestSite::with_source("cascade-foreign", "", "unused.avi");
    let state: PathBuf = site.path("state");
    std::fs::create_dir_all(&state).unwrap();
    let store = state.join("cam01.isochron.sqlite");
    let run = |site: &TestSite| site.exit_of("isochron-cascade", Duration::from_secs(30));

    std::fs::write(&store, "this is not a database at all").unwrap();
    let (code, stderr) = run(&site);
    assert_eq!(code, Some(65), "{stderr}");
    assert!(
        stderr.contains("cam01.isochron.sqlite is not an isochron store"),
        "{stderr}"
    );
    assert!(stderr.contains("move it away"), "{stderr}");

    std::fs::remove_file(&store).unwrap();
    write_store_for(&store, "cam02", (64, 32));
    let (code, stderr) = run(&site);
    assert_eq!(code, Some(78), "{stderr}");
    assert!(
        stderr.contains("holds the long-term model of camera 'cam02'"),
        "{stderr}"
    );

    std::fs::remove_file(&store).unwrap();
    write_store_for(&store, "cam01", (64, 32));
    {
        let bad = MinuteDamage::new(&store);
        bad.apply();
    }
    let (code, stderr) = run(&site);
    assert_eq!(code, Some(65), "{stderr}");
    assert!(stderr.contains("is damaged"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");

    // A store the cascade cannot write (here immutable, as a read-only mount or
    // another owner would make it): permanent, so no supervisor restarts it.
    std::fs::remove_file(&store).unwrap();
    write_store_for(&store, "cam01", (64, 32));
    let immutable = std::process::Command::new("chattr")
        .arg("+i")
        .arg(&store)
        .status()
        .is_ok_and(|s| s.success());
    if immutable {
        let (code, stderr) = run(&site);
        let _ = std::process::Command::new("chattr")
            .arg("-i")
            .arg(&store)
            .status();
        assert_eq!(code, Some(78), "{stderr}");
        assert!(stderr.contains("cannot be written"), "{stderr}");
    } else {
        eprintln!("chattr +i is not supported here: the read-only store case is not checked");
    }

    // A good store of another grid: the cascade starts, and stops at the first motion
    // sample, which shows that motion now runs with other settings.
    std::fs::remove_file(&store).unwrap();
    write_store_for(&store, "cam01", (80, 80));
    let ipc = site.ipc("feeder");
    let publisher = ipc.publisher::<Motion>("cam01", 8).unwrap();
    let (mut cascade, mut feed) = start_fed_cascade(&site, &publisher);
    let t0 = parse_rfc3339("2026-03-02T08:00:00Z").unwrap();
    publisher
        .send_copy(feed.header(t0, 8, 0), &[BlockMotion::default(); 8])
        .unwrap();
    let status = cascade
        .wait(Duration::from_secs(30))
        .expect("the cascade exits");
    let stderr = cascade.stderr();
    assert_eq!(status.code(), Some(78), "{stderr}");
    assert!(
        stderr.contains("holds a model for a 5x5 block grid"),
        "{stderr}"
    );
    assert!(stderr.contains("4x2 blocks"), "{stderr}");
}

/// Writes a learned bin and then garbles the file under it, as a bad disk would.
struct MinuteDamage<'a> {
    path: &'a Path,
}

impl<'a> MinuteDamage<'a> {
    fn new(path: &'a Path) -> Self {
        MinuteDamage { path }
    }

    fn apply(&self) {
        let mut s = Store::open_writer(self.path, "cam01", Cycle::DayTypes).unwrap();
        for t in 0..300u32 {
            s.teach(t, 1, vec![0.1; 8]).unwrap();
        }
        drop(s);
        let mut bytes = std::fs::read(self.path).unwrap();
        let mid = bytes.len() / 2;
        for (i, b) in bytes[mid..mid + 1024].iter_mut().enumerate() {
            *b = (i as u8).wrapping_mul(37) ^ 0x5a;
        }
        std::fs::write(self.path, bytes).unwrap();
    }
}

/// A full disk: the cascade stays up, says so, and learns again once space
/// returns, with every minute committed before intact. The state directory is a
/// 2 MB tmpfs the test mounts (root only; CI runs as root).
#[test]
fn a_full_disk_pauses_learning_and_it_resumes_when_space_returns() {
    let site = TestSite::with_source("cascade-full", "[ipc]\nlossless = true", "unused.avi");
    let state = site.path("state");
    let Some(_disk) = isochron_tests::Tmpfs::mount(&state, "2m") else {
        return;
    };
    let store = store_path(&state, "cam01");
    let ipc = site.ipc("feeder");
    let publisher = ipc.publisher::<Motion>("cam01", 8).unwrap();
    let (mut cascade, mut feed) = start_fed_cascade(&site, &publisher);
    let t0 = parse_rfc3339("2026-03-02T08:00:00Z").unwrap();
    let mut frame = 0i64;
    // `minutes` minutes at 10 fps (whole minutes: each completes at the next).
    let mut feed_minutes = |minutes: i64| {
        for _ in 0..minutes * 600 {
            let t = t0 + frame * NS_PER_S / 10;
            publisher
                .send_copy(feed.header(t, 8, 0), &[BlockMotion::default(); 8])
                .unwrap();
            frame += 1;
        }
    };
    let written = |store: &Path| {
        Store::open_read_only(store, "cam01")
            .and_then(|s| s.progress())
            .map(|p| p.committed + p.skipped)
            .unwrap_or(0)
    };
    feed_minutes(3);
    let before = eventually(Duration::from_secs(30), || {
        let n = written(&store);
        (n >= 2).then_some(n)
    })
    .unwrap_or_else(|| panic!("no minute committed:\n{}", cascade.stderr()));

    // Fill the disk.
    let filler = state.join("filler");
    {
        use std::io::Write;
        let mut f = std::fs::File::create(&filler).unwrap();
        let chunk = vec![0u8; 64 * 1024];
        while f.write_all(&chunk).is_ok() {}
        let _ = f.sync_all();
    }
    feed_minutes(3);
    assert!(
        cascade.wait_for_stderr("cannot be written", Duration::from_secs(30)),
        "the cascade did not say the store is full:\n{}",
        cascade.stderr()
    );
    assert!(
        cascade.wait(Duration::from_millis(500)).is_none(),
        "the cascade ended on a full disk:\n{}",
        cascade.stderr()
    );

    // Space returns: learning resumes, and what was committed is intact.
    std::fs::remove_file(&filler).unwrap();
    feed_minutes(3);
    let after = eventually(Duration::from_secs(30), || {
        let n = written(&store);
        (n > before).then_some(n)
    });
    assert!(
        after.is_some(),
        "learning did not resume once space returned:\n{}",
        cascade.stderr()
    );
    Store::open_read_only(&store, "cam01")
        .unwrap()
        .verify()
        .unwrap_or_else(|e| panic!("the store is damaged: {e}"));
    cascade.terminate(Duration::from_secs(10));
}

#[test]
fn a_store_that_saw_a_time_years_ahead_keeps_learning_with_one_warning() {
    // The first replay stamps 2099 into the state directory; the second, the
    // correct 2009, must still learn (it learned nothing before the store kept
    // spans: "learned 0 / repeated 1").
    let site = TestSite::with_source("cascade-clock-jump", "", "replaced-by-replay");
    let out = site.path("out");
    site.replay_ok(&vtest(), &out, "2099-06-01T10:00:00Z");
    let store = out.join("state/cam01.isochron.sqlite");
    let learned = || {
        Store::open_read_only(&store, "cam01")
            .unwrap()
            .progress()
            .unwrap()
            .committed
    };
    let ahead = learned();
    assert!(ahead >= 1, "the first replay learned {ahead} minutes");
    site.replay_ok(&vtest(), &out, "2009-06-01T10:00:00Z");
    assert!(learned() > ahead, "the corrected clock learned nothing");
    let log: String = std::fs::read_dir(out.join("logs"))
        .unwrap()
        .filter_map(Result::ok)
        .filter(|e| e.file_name().to_string_lossy().contains("cascade"))
        .map(|e| std::fs::read_to_string(e.path()).unwrap())
        .collect();
    assert_eq!(
        log.matches("the latest minute the long-term store completed")
            .count(),
        1,
        "{log}"
    );
    // The same recording at the same time again teaches nothing twice.
    let before = learned();
    site.replay_ok(&vtest(), &out, "2009-06-01T10:00:00Z");
    assert_eq!(learned(), before);
}
