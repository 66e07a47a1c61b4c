//! Operating the group: faults injected into real processes.
//!
//! * kill -9 each service in turn under `isochron up`: the others keep their PIDs,
//!   the killed one is back and its output flows again, the store is undamaged;
//! * SIGTERM: a clean exit that leaves no stale iceoryx2 node;
//! * a hung service (SIGSTOP) is caught by the launcher's watchdog;
//! * a subscriber that never reads does not slow its publisher;
//! * a foreign process publishing malformed samples cannot crash a consumer;
//! * soak (ignored by default: `cargo test -p isochron-tests --test it --
//!   --ignored operations::soak`): 30 minutes at full rate, RSS and shared memory
//!   stay flat.

use std::collections::HashMap;
use std::time::{Duration, Instant};

use isochron_runtime::ipc::{Activity, Events, Frames, Ipc, Motion, StatusSubscriber};
use isochron_runtime::ipc::{StreamSubscriber, StreamType, node_census};
use isochron_runtime::topology::StageKind;
use isochron_store::{Store, store_path};
use isochron_tests::{Proc, TestSite, eventually, pid_in};
use isochron_wire::{CameraId, FrameHeader, MAGIC, PixelFormat, Preamble, Stream};

fn up(site: &TestSite, watchdog_s: &str) -> Proc {
    site.up(&["--watchdog-s", watchdog_s])
}

fn alive(pid: u32) -> bool {
    // SAFETY: signal 0 only checks that the process exists.
    unsafe { libc::kill(pid as i32, 0) == 0 }
}

/// The services `up` started, by name, with their pids (waits until all are ready).
fn started(up: &mut Proc) -> HashMap<String, u32> {
    let mut pids = HashMap::new();
    let out = eventually(Duration::from_secs(30), || {
        let text = up.stdout();
        for line in text.lines() {
            if let Some(rest) = line.strip_prefix("up: ")
                && line.contains(" started pid=")
            {
                let name = rest.split_whitespace().next().unwrap().to_string();
                pids.insert(name, pid_in(line));
            }
        }
        let ready = text.lines().filter(|l| l.ends_with(" ready")).count();
        (!pids.is_empty() && ready >= pids.len()).then_some(())
    });
    assert!(
        out.is_some(),
        "not every service became ready:\n{}",
        up.stdout()
    );
    pids
}

/// Waits for the next sample of stream `S` and returns how long that took.
fn next_sample<S: StreamType>(sub: &StreamSubscriber<S>, timeout: Duration) -> Option<Duration> {
    while sub.receive().ok().flatten().is_some() {}
    let t0 = Instant::now();
    eventually(timeout, || {
        sub.receive().ok().flatten().map(|_| t0.elapsed())
    })
}

#[test]
fn killing_each_service_in_turn_leaves_the_others_running_and_it_comes_back() {
    let site = TestSite::looping_vtest("ops-kill", "2");
    let mut up = up(&site, "10");
    let mut pids = started(&mut up);
    let ipc = site.ipc("watcher");
    let frames = ipc.subscriber::<Frames>("cam01").unwrap();
    let motion = ipc.subscriber::<Motion>("cam01").unwrap();
    let activity = ipc.subscriber::<Activity>("cam01").unwrap();
    let events = ipc.subscriber::<Events>("cam01").unwrap();
    assert!(
        next_sample(&activity, Duration::from_secs(20)).is_some(),
        "activity flows"
    );

    let order: Vec<String> = ["capture", "motion", "cascade", "gate", "costmap"]
        .iter()
        .filter_map(|stage| {
            pids.keys()
                .find(|n| n.split('/').next() == Some(stage))
                .cloned()
        })
        .collect();
    for name in order {
        let pid = pids[&name];
        // SAFETY: kill(2) on a process of this test.
        unsafe { libc::kill(pid as i32, libc::SIGKILL) };
        let killed = Instant::now();
        let line = up
            .wait_for_line(&format!("{name} restarted pid="), Duration::from_secs(10))
            .unwrap_or_else(|| panic!("{name} was not restarted:\n{}", up.stdout()));
        let new_pid = pid_in(&line);
        up.wait_for_line(&format!("{name} ready"), Duration::from_secs(10))
            .unwrap_or_else(|| panic!("{name} did not become ready again"));
        // Its own output flows again.
        let flowing = match name.split('/').next().unwrap() {
            "capture" => next_sample(&frames, Duration::from_secs(10)),
            "motion" => next_sample(&motion, Duration::from_secs(10)),
            "cascade" => next_sample(&activity, Duration::from_secs(10)),
            // A fresh gate starts the event people are in.
            "gate" => next_sample(&events, Duration::from_secs(10)),
            _ => Some(Duration::ZERO),
        };
        let gap = killed.elapsed();
        assert!(flowing.is_some(), "{name}: no output after the restart");
        // End to end: activity (capture → motion → cascade) arrives again.
        let end_to_end = next_sample(&activity, Duration::from_secs(10))
            .map(|_| killed.elapsed())
            .unwrap_or_else(|| panic!("activity stopped after killing {name}"));
        println!(
            "{name}: back (pid {pid} → {new_pid}) and flowing {:.2} s after kill -9; activity again after {:.2} s",
            gap.as_secs_f64(),
            end_to_end.as_secs_f64()
        );
        assert!(
            gap <= Duration::from_secs(2),
            "{name} took {gap:?} to come back and flow"
        );
        for (other, other_pid) in &pids {
            if *other != name {
                assert!(
                    alive(*other_pid),
                    "{other} (pid {other_pid}) died when {name} was killed"
                );
            }
        }
        pids.insert(name.clone(), new_pid);
        if name.starts_with("cascade") {
            let store = store_path(&site.config().state_dir(), "cam01");
            if store.exists() {
                let s = Store::open_read_only(&store, "cam01").expect("store opens after kill -9");
                s.verify().expect("store verifies after kill -9");
            }
        }
    }
    up.signal(libc::SIGINT);
    assert!(
        up.wait(Duration::from_secs(30))
            .is_some_and(|s| s.success())
    );
}

#[test]
fn sigterm_exits_cleanly_and_leaves_no_stale_node() {
    let site = TestSite::looping_vtest("ops-term", "2");
    let mut up = up(&site, "10");
    let pids = started(&mut up);
    for (name, pid) in &pids {
        // SAFETY: kill(2) on a process of this test.
        unsafe { libc::kill(*pid as i32, libc::SIGTERM) };
        let line = up
            .wait_for_line(&format!("{name} exited with code"), Duration::from_secs(10))
            .unwrap_or_else(|| panic!("{name} did not exit on SIGTERM:\n{}", up.stdout()));
        assert!(line.contains("exited with code 0"), "{line}");
    }
    let census = node_census(false).unwrap();
    let ours = |n: &&String| n.starts_with(&format!("{}/", site.prefix));
    let stale: Vec<&String> = census.dead_left.iter().filter(ours).collect();
    assert!(stale.is_empty(), "stale nodes after SIGTERM: {stale:?}");
    let left: Vec<&String> = census.alive.iter().filter(ours).collect();
    assert!(left.is_empty(), "nodes still registered: {left:?}");
    up.signal(libc::SIGINT);
    up.wait(Duration::from_secs(20));
}

#[test]
fn a_hung_service_is_caught_by_the_watchdog() {
    let site = TestSite::looping_vtest("ops-hang", "2");
    let mut up = up(&site, "2");
    let pids = started(&mut up);
    let name = pids
        .keys()
        .find(|n| n.starts_with("motion/"))
        .unwrap()
        .clone();
    // SAFETY: kill(2) on a process of this test.
    unsafe { libc::kill(pids[&name] as i32, libc::SIGSTOP) };
    let stopped = Instant::now();
    up.wait_for_line(
        &format!("{name} watchdog: no sign of life"),
        Duration::from_secs(10),
    )
    .unwrap_or_else(|| panic!("the hang was not detected:\n{}", up.stdout()));
    println!(
        "hang detected after {:.1} s (watchdog 2 s)",
        stopped.elapsed().as_secs_f64()
    );
    up.wait_for_line(&format!("{name} restarted pid="), Duration::from_secs(10))
        .expect("the hung service is restarted");
    up.signal(libc::SIGINT);
    up.wait(Duration::from_secs(20));
}

#[test]
fn a_subscriber_that_stops_reading_does_not_slow_its_publisher() {
    // Capture at 5× real time: 50 frames/s.
    let site = TestSite::looping_vtest("ops-stall", "5");
    let ipc = site.ipc("stalled");
    let _never_read = ipc.subscriber::<Frames>("cam01").unwrap();
    let mut capture = site.spawn("isochron-capture", &["--camera", "cam01"]);
    let counter = ipc.subscriber::<Frames>("cam01").unwrap();
    eventually(Duration::from_secs(20), || {
        counter.receive().ok().flatten().map(|_| ())
    })
    .expect("frames flow");
    let t0 = Instant::now();
    let mut n = 0u32;
    while t0.elapsed() < Duration::from_secs(4) {
        counter.wait(Duration::from_millis(50));
        while counter.receive().unwrap().is_some() {
            n += 1;
        }
    }
    let rate = n as f64 / t0.elapsed().as_secs_f64();
    println!("publisher rate with a stalled subscriber: {rate:.1} frames/s (paced at 50)");
    assert!(
        rate > 45.0,
        "the stalled subscriber slowed capture to {rate:.1} frames/s"
    );
    assert!(alive(capture.pid()));
    assert!(capture.terminate(Duration::from_secs(10)).success());
}

/// A malformed frames sample: wrong magic, or a header that lies about its size.
fn send_garbage(publisher: &mut isochron_runtime::ipc::StreamPublisher<Frames>, n: u64) {
    let camera = CameraId::new("cam01").unwrap();
    let pixels = vec![9u8; 64 * 48];
    for i in 0..n {
        let mut preamble = Preamble::new::<u8>(
            Stream::Frames,
            camera,
            publisher.next_sequence(),
            pixels.len(),
        );
        preamble.capture_time_ns = i as i64 * 100_000_000;
        let mut h = FrameHeader {
            preamble,
            width: 64,
            height: 48,
            stride: 64,
            pixel_format: PixelFormat::Gray8 as u32,
            source_index: i,
        };
        match i % 3 {
            0 => h.preamble.magic = !MAGIC,
            1 => h.height = 4000,
            _ => h.preamble.layout_version = 77,
        }
        publisher.send_copy(h, &pixels).unwrap();
    }
}

#[test]
fn a_foreign_publisher_of_malformed_samples_does_not_crash_consumers() {
    let site = TestSite::with_source("ops-foreign", "", "unused.avi");
    let ipc = site.ipc("foreign");
    let mut publisher = ipc.publisher::<Frames>("cam01", 64 * 48).unwrap();
    let mut motion = site.spawn("isochron-motion", &["--camera", "cam01"]);
    let mut gate = site.spawn("isochron-gate", &["--camera", "cam01"]);
    eventually(Duration::from_secs(20), || {
        (publisher.subscriber_count() >= 2).then_some(())
    })
    .expect("motion and gate subscribed");
    send_garbage(&mut publisher, 30);
    for (name, proc) in [
        (StageKind::Motion, &mut motion),
        (StageKind::Gate, &mut gate),
    ] {
        assert!(
            proc.wait_for_stderr("rejected", Duration::from_secs(10)),
            "{name} logged no rejection:\n{}",
            proc.stderr()
        );
        let status = status_of(&ipc, name);
        assert!(alive(proc.pid()), "{name} died on malformed input");
        assert!(!proc.stderr().contains("panicked"), "{name} panicked");
        println!(
            "{name}: rejected {} malformed samples",
            status.map_or(0, |s| s.rejected)
        );
    }
}

fn status_of(ipc: &Ipc, stage: StageKind) -> Option<isochron_wire::StageStatus> {
    let sub: StatusSubscriber = ipc.status_subscriber("cam01", stage).ok()?;
    eventually(Duration::from_secs(8), || {
        sub.latest().filter(|s| s.rejected > 0)
    })
}

/// RSS of a process, kB.
fn rss_kb(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmRSS:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|v| v.parse().ok())
        })
        .unwrap_or(0)
}

/// Bytes of shared memory in /dev/shm.
fn shm_bytes() -> u64 {
    std::fs::read_dir("/dev/shm")
        .map(|d| {
            d.filter_map(Result::ok)
                .filter_map(|e| e.metadata().ok())
                .map(|m| std::os::unix::fs::MetadataExt::blocks(&m) * 512)
                .sum()
        })
        .unwrap_or(0)
}

#[test]
#[ignore = "30 minutes; run with --ignored soak"]
fn soak() {
    let minutes: u64 = std::env::var("ISOCHRON_SOAK_MINUTES")
        .ok()
        .and_then(|m| m.parse().ok())
        .unwrap_or(30);
    let site = TestSite::looping_vtest("ops-soak", "\"max\"");
    let mut up = up(&site, "10");
    let pids = started(&mut up);
    // Warm-up: allocations settle, shared memory is touched.
    std::thread::sleep(Duration::from_secs(120));
    let rss0: HashMap<&String, u64> = pids.iter().map(|(n, p)| (n, rss_kb(*p))).collect();
    let shm0 = shm_bytes();
    std::thread::sleep(Duration::from_secs(minutes * 60));
    println!(
        "{:<16} {:>10} {:>10} {:>8}",
        "service", "RSS0 kB", "RSS kB", "growth"
    );
    let mut worst: f64 = 0.0;
    for (name, pid) in &pids {
        assert!(alive(*pid), "{name} died during the soak");
        let (a, b) = (rss0[name], rss_kb(*pid));
        let growth = (b as f64 - a as f64) / a as f64;
        worst = worst.max(growth);
        println!("{name:<16} {a:>10} {b:>10} {:>7.2}%", growth * 100.0);
    }
    let shm1 = shm_bytes();
    println!(
        "shared memory: {:.1} MiB → {:.1} MiB",
        shm0 as f64 / 1048576.0,
        shm1 as f64 / 1048576.0
    );
    assert!(worst < 0.01, "RSS grew {:.2} %", worst * 100.0);
    assert!(shm1 <= shm0, "shared memory grew");
    assert!(
        !up.stdout().contains("restarted"),
        "a service restarted during the soak"
    );
    up.signal(libc::SIGINT);
    up.wait(Duration::from_secs(30));
}
