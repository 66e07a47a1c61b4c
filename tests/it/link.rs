//! isochron-link between two base stations: two network namespaces joined by a
//! veth pair (`NetnsPair`), each box with its own iceoryx2 services (its own site
//! prefix) and DDS only over the veth.
//!
//! Box A: a source of cam01's activity — synthetic 1 Hz samples the test publishes
//! through the real iceoryx2 service, or the real capture → motion → cascade on the
//! demo video — and its link, exporting cam01. Box B: its link importing cam01, a costmap bridge
//! that has cam01's floor points, and the independent Cyclone DDS peer reading the
//! grid. Checked: the grid under cam01's footprint on B is what A's activity
//! gives; headers cross unchanged; veth down → unknown, up → back; kill -9 of A's
//! link → unknown, restarted → back; kill -9 of B's bridge or B's link, started
//! again → A's cells back within 10 s while every other process keeps its pid;
//! events and detections cross with their
//! sequence numbers, and a burst larger than the link's queue is counted as
//! dropped (A) and as a gap (B), never lost silently; on the real pipeline, A's
//! gate events reach B and B's `isochron status` lists A's stages (relayed by
//! B's link). Measured
//! (printed): bytes per second on the link and origin-to-B latency.

use std::path::Path;
use std::time::{Duration, Instant};

use isochron_config::clock::{NS_PER_S, parse_rfc3339, wall_now_ns};
use isochron_runtime::counters::{CounterId, link};
use isochron_runtime::health::status_counters;
use isochron_runtime::ipc::{Activity, Detections, Events, Ipc, StreamSubscriber};
use isochron_runtime::topology::StageKind;
use isochron_tests::{NetnsPair, Proc, TestSite, bin, eventually, repo_root};
use isochron_wire::{
    CameraId, Detection, DetectionHeader, EventHeader, Preamble, Stream, to_fixed,
};

use crate::costmap::{
    HOT_BLOCK, HOT_S1, Source, camera_toml, costmap_toml, dds_domain, expected_cells, held_grid,
    messages, netns_pair, python, sized_camera_toml,
};

const START: &str = "2026-03-02T11:00:00Z";
/// The bridge's `costmap.stale_s` on box B.
const STALE_S: u32 = 3;
/// How soon the grid must follow the link going down or up.
const FOLLOW: Duration = Duration::from_secs(5);
/// How soon after a killed link or bridge is started again camera A's cells
/// must be back in B's grid.
const RECOVER: Duration = Duration::from_secs(10);
/// The processes of the test's boxes.
const LINK_A: &str = "link A";
const LINK_B: &str = "link B";
const BRIDGE: &str = "bridge B";

/// The site of a box: `sections`, then its `[link]` (`box_id`, exporting or
/// importing cam01 as `key` says, over `addr`, without DDS Security: `insecure`;
/// `hostile.rs` runs boxes secured) ending in `extra` keys.
fn box_site(
    name: &str,
    sections: &str,
    (box_id, key, addr): (&str, &str, &str),
    domain: u16,
    extra: &str,
) -> TestSite {
    TestSite::new(
        name,
        &format!(
            "{sections}\n[link]\nbox_id = \"{box_id}\"\n{key} = [\"cam01\"]\nros_domain_id = {domain}\ndds_interfaces = [\"{addr}\"]\ninsecure = true\n{extra}"
        ),
    )
}

/// `link.queue_messages` of box A in the synthetic test: a burst of [`BURST`]
/// records cannot fit.
const QUEUE: usize = 8;
/// Events A publishes at once.
const BURST: u64 = 200;

/// The link's counter `id` of `ipc`'s site, from a report made after
/// `after_ns` (waits for one).
fn link_counter(ipc: &Ipc, id: CounterId, after_ns: i64) -> u64 {
    let reader = ipc.status_subscriber("", StageKind::Link).unwrap();
    let status = eventually(Duration::from_secs(8), || {
        reader.latest().filter(|s| s.report_wall_ns > after_ns)
    })
    .expect("a link status report");
    let counters = status_counters(&status).expect("the link's counters");
    counters.get(id) as u64
}

/// An event record of cam01 as the gate writes it.
fn event(sequence: u64, event_id: u64) -> EventHeader {
    let mut preamble =
        Preamble::new::<u32>(Stream::Events, CameraId::new("cam01").unwrap(), sequence, 1);
    preamble.capture_time_ns = 1_000 + sequence as i64;
    preamble.origin_wall_ns = wall_now_ns();
    EventHeader {
        preamble,
        event_id,
        zone: to_fixed("all"),
        kind: 1,
        phase: 1,
        start_ns: 1_000,
        peak: 2.0,
        threshold: 1.0,
        ..Default::default()
    }
}

/// The (sequence, event id, capture time) of each event `sub` holds.
fn events_of(sub: &StreamSubscriber<Events>) -> Vec<(u64, u64, i64)> {
    let cam = CameraId::new("cam01").unwrap();
    let mut out = Vec::new();
    while let Some(sample) = sub.receive().unwrap() {
        let h = sample.user_header();
        h.validate(&cam, sample.payload().len()).unwrap();
        out.push((h.preamble.sequence, h.event_id, h.preamble.capture_time_ns));
    }
    out
}

/// Every cell of cam01's footprint is unknown (-1) in `grid`.
fn footprint_unknown(grid: &[i64], hot: &[i64]) -> bool {
    grid.iter().zip(hot).all(|(g, h)| *h == -1 || *g == -1)
}

/// A process of a test box: how the launcher or systemd starts it, and the
/// running one.
struct Service<'a> {
    name: &'static str,
    start: Box<dyn Fn() -> Proc + 'a>,
    proc: Proc,
}

/// Both boxes as a test drives them: A's source (`feed`, called at 1 Hz), the
/// Cyclone DDS peer reading B's grid and a probe on B's cam01 activity, the
/// boxes' processes (their logs come with a failure) and the veth between them.
struct Scene<'a> {
    pair: &'a NetnsPair,
    feed: Box<dyn FnMut() + 'a>,
    peer: Proc,
    /// The peer's messages before this one came from a bridge since killed.
    since: usize,
    probe: StreamSubscriber<Activity>,
    latencies_ms: Vec<f64>,
    /// The synthetic source's start: its samples' capture times are checked.
    synthetic_start_ns: Option<i64>,
    services: Vec<Service<'a>>,
}

impl<'a> Scene<'a> {
    /// Starts the Cyclone DDS peer in B's namespace (reading the bridge's grid on
    /// `domain` for up to `timeout_s`) and the probe on B's cam01 activity.
    fn new(
        pair: &'a NetnsPair,
        (ipc_b, domain, timeout_s): (&Ipc, u16, u32),
        synthetic_start_ns: Option<i64>,
        feed: Box<dyn FnMut() + 'a>,
    ) -> Scene<'a> {
        let script = repo_root().join("tests/ros2/costmap_listener.py");
        let peer = pair.spawn(
            1,
            &python(),
            &[
                script.display().to_string(),
                "--domain".into(),
                domain.to_string(),
                "--topic".into(),
                "/isochron_test/activity_costmap".into(),
                "--updates".into(),
                "--timeout".into(),
                timeout_s.to_string(),
            ],
        );
        Scene {
            pair,
            feed,
            peer,
            since: 0,
            probe: ipc_b.subscriber::<Activity>("cam01").unwrap(),
            latencies_ms: Vec::new(),
            synthetic_start_ns,
            services: Vec::new(),
        }
    }

    /// Adds `name`, running as `proc` (started by `start`, which starts it again).
    fn adopt(&mut self, name: &'static str, start: impl Fn() -> Proc + 'a, proc: Proc) {
        self.services.push(Service {
            name,
            start: Box::new(start),
            proc,
        });
    }

    /// Starts `name` with `start`.
    fn add(&mut self, name: &'static str, start: impl Fn() -> Proc + 'a) {
        let proc = start();
        self.adopt(name, start, proc);
    }

    fn service(&mut self, name: &str) -> &mut Service<'a> {
        self.services
            .iter_mut()
            .find(|s| s.name == name)
            .unwrap_or_else(|| panic!("no process {name}"))
    }

    /// The process `name`.
    fn proc(&mut self, name: &str) -> &mut Proc {
        &mut self.service(name).proc
    }

    /// The running processes' names and ids.
    fn pids(&mut self) -> Vec<(&'static str, u32)> {
        self.services
            .iter_mut()
            .filter_map(|s| {
                s.proc
                    .wait(Duration::ZERO)
                    .is_none()
                    .then(|| (s.name, s.proc.pid()))
            })
            .collect()
    }

    /// `kill -9` of `name`, and its end; the other running processes and their ids.
    fn kill(&mut self, name: &str) -> Vec<(&'static str, u32)> {
        let others = self
            .pids()
            .into_iter()
            .filter(|(n, _)| *n != name)
            .collect();
        let proc = self.proc(name);
        proc.signal(libc::SIGKILL);
        assert!(
            proc.wait(Duration::from_secs(5)).is_some(),
            "{name} outlived SIGKILL"
        );
        others
    }

    /// Starts `name` again, as the launcher or systemd would.
    fn restart(&mut self, name: &str) {
        let service = self.service(name);
        service.proc = (service.start)();
    }

    /// The grid the peer holds now.
    fn grid(&mut self) -> Option<Vec<i64>> {
        held_grid(messages(&mut self.peer).get(self.since..)?)
    }

    /// Ignores what the peer received so far, and in the next 300 ms (from a
    /// bridge that was killed).
    fn forget_grids(&mut self) {
        std::thread::sleep(Duration::from_millis(300));
        self.since = messages(&mut self.peer).len();
    }

    /// Reads what B's link wrote into B's cam01 activity service: the header as
    /// A's source wrote it, and the latency from its origin.
    fn probe(&mut self) {
        let cam = CameraId::new("cam01").unwrap();
        while let Some(sample) = self.probe.receive().unwrap() {
            let h = sample.user_header();
            h.validate(&cam, sample.payload().len()).unwrap();
            let p = &h.preamble;
            if let Some(start_ns) = self.synthetic_start_ns {
                assert_eq!(
                    p.capture_time_ns,
                    start_ns + (p.sequence as i64 + 1) * NS_PER_S,
                    "sequence and capture time cross together"
                );
                assert_eq!(sample.payload()[HOT_BLOCK].s1, HOT_S1);
            }
            self.latencies_ms
                .push((wall_now_ns() - p.origin_wall_ns) as f64 / 1e6);
        }
    }

    /// Feeds A at 1 Hz and reads B until `f` holds for the peer's grid; prints
    /// and returns how long that took. Fails after `timeout`, with every log.
    fn until(
        &mut self,
        what: &str,
        timeout: Duration,
        mut f: impl FnMut(&[i64]) -> bool,
    ) -> Duration {
        let begin = Instant::now();
        let mut last_sent: Option<Instant> = None;
        loop {
            if last_sent.is_none_or(|t| t.elapsed() >= Duration::from_secs(1)) {
                (self.feed)();
                last_sent = Some(Instant::now());
            }
            self.probe();
            if self.grid().is_some_and(|g| f(&g)) {
                eprintln!("{what}: after {:?}", begin.elapsed());
                return begin.elapsed();
            }
            if begin.elapsed() > timeout {
                let logs: Vec<String> = self
                    .services
                    .iter()
                    .map(|s| format!("{}:\n{}", s.name, s.proc.stderr()))
                    .collect();
                panic!(
                    "timed out ({timeout:?}) waiting for {what}\npeer stderr:\n{}\nprocess logs:\n{}",
                    self.peer.stderr(),
                    logs.join("\n-----\n")
                );
            }
            // Wakes as soon as B's link writes a sample: the latency is measured on arrival.
            self.probe.wait(Duration::from_millis(100));
        }
    }

    /// Follows 10 s of steady state and prints the bytes per second on A's veth
    /// (all traffic) and the origin → B activity-service latency (p50, p99).
    fn steady_state(&mut self, label: &str) {
        self.latencies_ms.clear();
        let tx0 = self.pair.tx_bytes(0);
        let t0 = Instant::now();
        let steady = self.until("10 s of steady state", Duration::from_secs(20), |_| {
            t0.elapsed() >= Duration::from_secs(10)
        });
        let veth_bps = (self.pair.tx_bytes(0) - tx0) as f64 / steady.as_secs_f64();
        let mut lat = self.latencies_ms.clone();
        lat.sort_by(f64::total_cmp);
        assert!(
            lat.len() >= 8,
            "only {} samples reached B in 10 s",
            lat.len()
        );
        eprintln!(
            "MEASURED {label}: veth A→B {veth_bps:.0} B/s (all traffic, 1 camera); origin → B's activity service over {} samples: p50 {:.1} ms, p99 {:.1} ms",
            lat.len(),
            percentile(&lat, 0.5),
            percentile(&lat, 0.99)
        );
    }

    /// Waits for B's grid to be `back` (A's cells known: a wait without feeding,
    /// such as for a status report, lets them go stale), sets the veth down
    /// until it is `unknown`, then up until it is `back` again.
    fn veth_down_and_up(
        &mut self,
        label: &str,
        unknown: impl FnMut(&[i64]) -> bool,
        back: impl FnMut(&[i64]) -> bool + Copy,
    ) {
        self.until(
            &format!("{label}: A's cells before the veth goes down"),
            FOLLOW,
            back,
        );
        self.pair.set_link(0, false);
        self.until(&format!("{label}: veth down → unknown"), FOLLOW, unknown);
        self.pair.set_link(0, true);
        self.until(&format!("{label}: veth up → back"), FOLLOW, back);
    }

    /// Starts the killed `name` again, as the launcher or systemd would: camera
    /// A's cells are `back` within [`RECOVER`], and the `others` running at the
    /// kill still run with the same pids.
    fn recovers(
        &mut self,
        name: &str,
        others: &[(&'static str, u32)],
        back: impl FnMut(&[i64]) -> bool,
    ) {
        self.restart(name);
        self.until(
            &format!("MEASURED {name} restarted → A's activity in B's grid"),
            RECOVER,
            back,
        );
        let mut still = self.pids();
        still.retain(|(n, _)| *n != name);
        assert_eq!(still, others, "the other processes run on, untouched");
    }
}

/// A's event and detection reach B unchanged; then a burst of [`BURST`] events:
/// A's link drops what does not fit its queue of [`QUEUE`] and counts it
/// (`ev_drop`); B counts every missing sequence number (`ev_gap`); what B got
/// and what it counts as missing are the whole burst.
fn records_cross_and_a_burst_is_counted(ipc_a: &Ipc, ipc_b: &Ipc, scene: &mut Scene) {
    let events_a = ipc_a.publisher::<Events>("cam01", 1).unwrap();
    let detections_a = ipc_a.publisher::<Detections>("cam01", 1).unwrap();
    let events_b = ipc_b.subscriber::<Events>("cam01").unwrap();
    let detections_b = ipc_b.subscriber::<Detections>("cam01").unwrap();
    let first = event(0, 7);
    events_a.send_copy(first, &[3]).unwrap();
    let mut det = DetectionHeader {
        preamble: Preamble::new::<Detection>(
            Stream::Detections,
            CameraId::new("cam01").unwrap(),
            0,
            1,
        ),
        event_id: 7,
        source_index: 42,
        ..Default::default()
    };
    det.preamble.capture_time_ns = 1_234;
    let person = Detection {
        x: 10.0,
        y: 20.0,
        w: 30.0,
        h: 60.0,
        score: 0.9,
        class: 0,
        ..Default::default()
    };
    detections_a.send_copy(det, &[person]).unwrap();
    let (mut got, mut got_det) = (Vec::new(), None);
    scene.until(
        "A's event and detection on B",
        Duration::from_secs(20),
        |_| {
            got.extend(events_of(&events_b));
            if let Some(s) = detections_b.receive().unwrap() {
                got_det = Some((*s.user_header(), s.payload().to_vec()));
            }
            !got.is_empty() && got_det.is_some()
        },
    );
    assert_eq!(got, [(0, 7, first.preamble.capture_time_ns)]);
    let (h, people) = got_det.unwrap();
    assert_eq!(
        (
            h.preamble.sequence,
            h.event_id,
            h.source_index,
            h.preamble.capture_time_ns
        ),
        (0, 7, 42, 1_234)
    );
    assert_eq!(people, [person]);

    // The burst: sequences 1..=BURST, sent as fast as iceoryx2 takes them.
    for seq in 1..=BURST {
        events_a.send_copy(event(seq, 100 + seq), &[3]).unwrap();
    }
    let mut burst = Vec::new();
    let t = scene.until(
        "the burst's last event on B",
        Duration::from_secs(20),
        |_| {
            burst.extend(events_of(&events_b));
            burst.last().is_some_and(|e| e.0 == BURST)
        },
    );
    let done_ns = wall_now_ns();
    for (seq, id, capture) in &burst {
        assert_eq!((*id, *capture), (100 + seq, 1_000 + *seq as i64));
    }
    assert!(burst.windows(2).all(|w| w[0].0 < w[1].0), "in order, once");
    let dropped_a = link_counter(ipc_a, link::EV_DROP, done_ns);
    let gaps_b = link_counter(ipc_b, link::EV_GAP, done_ns);
    eprintln!(
        "MEASURED burst of {BURST} events (queue {QUEUE}): {} reached B in {t:?}; A's link dropped {dropped_a}, B counts {gaps_b} missing",
        burst.len()
    );
    assert!(
        dropped_a > 0,
        "the burst did not fit the queue: drops are counted"
    );
    assert_eq!(
        burst.len() as u64 + gaps_b,
        BURST,
        "every event reached B or is counted as missing"
    );
    assert!(dropped_a <= gaps_b, "what A dropped B counts as missing");
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

#[test]
fn activity_crosses_boxes_and_goes_unknown_while_the_link_is_down() {
    let Some(pair) = netns_pair(1) else {
        return;
    };
    let (link_domain, bridge_domain) = (dds_domain(), dds_domain());
    let site_a = box_site(
        "link-a",
        &camera_toml(),
        ("box_a", "export", &pair.addrs[0]),
        link_domain,
        &format!("queue_messages = {QUEUE}\n"),
    );
    let costmap =
        costmap_toml(bridge_domain, "").replace("stale_s = 120", &format!("stale_s = {STALE_S}"));
    // B's services buffer a whole burst, so the test's reader loses nothing.
    let site_b = box_site(
        "link-b",
        &format!(
            "[ipc]\nstream_buffer = 256\n\n{}{costmap}",
            sized_camera_toml()
        ),
        ("box_b", "import", &pair.addrs[1]),
        link_domain,
        "",
    );
    let (link_bin, bridge_bin) = (bin("isochron-link"), bin("isochron-costmap"));
    let config_a = site_a.config_path().display().to_string();
    let config_b = site_b.config_path().display().to_string();
    let start_link_a = || pair.spawn(0, &link_bin, &["--config", &config_a]);

    let ipc_a = site_a.ipc("source");
    let mut source = Source::new(&ipc_a, START);
    let link_a = start_link_a();
    source.wait_for_subscriber(&link_a);
    let ipc_b = site_b.ipc("probe");
    let mut scene = Scene::new(
        &pair,
        (&ipc_b, bridge_domain, 240),
        Some(parse_rfc3339(START).unwrap()),
        Box::new(|| source.send(&[(HOT_BLOCK, HOT_S1)], 660)),
    );
    scene.adopt(LINK_A, start_link_a, link_a);
    scene.add(LINK_B, || {
        pair.spawn(1, &link_bin, &["--config", &config_b])
    });
    scene.add(BRIDGE, || {
        pair.spawn(1, &bridge_bin, &["--config", &config_b])
    });
    let hot = expected_cells(true);
    let (unknown, back) = (|g: &[i64]| footprint_unknown(g, &hot), |g: &[i64]| g == hot);

    // 1. A's activity reaches B's grid.
    scene.until(
        "first grid with A's activity on B",
        Duration::from_secs(60),
        back,
    );

    // 2. Steady state: bytes on the veth and latency over 10 s.
    scene.steady_state("synthetic activity");

    // 3. Events and detections cross with their headers; a burst larger than
    //    A's queue is counted, never lost silently.
    records_cross_and_a_burst_is_counted(&ipc_a, &ipc_b, &mut scene);

    // 4. The veth goes down: B's cells of cam01 turn unknown; up: they come back.
    scene.veth_down_and_up("synthetic activity", unknown, back);

    // 5. kill -9 A's link: unknown; restarted: back, without touching B.
    let others = scene.kill(LINK_A);
    scene.until("link A killed → unknown", FOLLOW, unknown);
    scene.recovers(LINK_A, &others, back);
    let t0 = Instant::now();
    scene.until(
        "5 s more from the restarted link",
        Duration::from_secs(10),
        |_| t0.elapsed() >= Duration::from_secs(5),
    );

    // 6. kill -9 B's bridge, started again: A's cells in the new bridge's grid,
    //    nothing else restarted.
    let others = scene.kill(BRIDGE);
    scene.forget_grids();
    scene.recovers(BRIDGE, &others, back);

    // 7. kill -9 B's link: unknown; started again: back, nothing else restarted.
    let others = scene.kill(LINK_B);
    scene.until("link B killed → unknown", FOLLOW, unknown);
    scene.recovers(LINK_B, &others, back);

    // The link's own count of what it sent.
    let link_a = scene.proc(LINK_A);
    link_a.terminate(Duration::from_secs(10));
    let log = link_a.stderr();
    let line = log
        .lines()
        .find(|l| l.contains("exported cam01 activity:"))
        .unwrap_or_else(|| panic!("no export summary in A's log:\n{log}"));
    eprintln!("MEASURED {line}");
}

/// The demo camera (vtest.avi at `--speed 1`, looping, with its real floor points)
/// and a coarse grid over the floor it sees.
fn demo_camera_and_grid(bridge_domain: u16) -> String {
    let demo = std::fs::read_to_string(repo_root().join("config/demo.toml")).unwrap();
    let floor = &demo[demo.find("floor_points = [").unwrap()..];
    let floor = &floor[..floor.find("\n]\n").unwrap() + 3];
    format!(
        r#"[[camera]]
id = "cam01"
source = "{}"
width = 768
height = 576
speed = 1
loop = true
start = "2009-03-02T11:00:00Z"
{floor}
[costmap]
origin_x_m = -22.0
origin_y_m = -18.0
resolution_m = 0.5
width_cells = 64
height_cells = 60
frame_id = "test_map"
topic = "/isochron_test/activity_costmap"
publish_hz = 4
full_every_s = 2
ros_domain_id = {bridge_domain}
dds_interfaces = ["127.0.0.1"]
stale_s = {STALE_S}
"#,
        isochron_tests::vtest().display()
    )
}

/// Box A runs the real capture → motion → cascade on the demo video at
/// `--speed 1` (a 768×576 camera: 1 728 blocks, ≈ 55 kB per message, which DDS
/// fragments); box B's grid gets known cells under its footprint, and loses
/// them while the veth is down.
#[test]
fn the_real_pipeline_on_one_box_feeds_the_bridge_on_another() {
    python();
    let Some(pair) = netns_pair(2) else {
        return;
    };
    let (link_domain, bridge_domain) = (dds_domain(), dds_domain());
    let camera_and_grid = demo_camera_and_grid(bridge_domain);
    let camera = &camera_and_grid[..camera_and_grid.find("[costmap]").unwrap()];
    let a = ("box_a", "export", pair.addrs[0].as_str());
    let site_a = box_site("link-pipe-a", camera, a, link_domain, "");
    let b = ("box_b", "import", pair.addrs[1].as_str());
    let site_b = box_site("link-pipe-b", &camera_and_grid, b, link_domain, "");
    let (link_bin, bridge_bin) = (bin("isochron-link"), bin("isochron-costmap"));
    let config_a = site_a.config_path().display().to_string();
    let config_b = site_b.config_path().display().to_string();
    // Box A's pipeline: shared memory only, so it needs no network namespace.
    let ipc_a = site_a.ipc("probe");
    let ipc_b = site_b.ipc("probe");
    let events_a = ipc_a.subscriber::<Events>("cam01").unwrap();
    let events_b = ipc_b.subscriber::<Events>("cam01").unwrap();
    let mut scene = Scene::new(&pair, (&ipc_b, bridge_domain, 120), None, Box::new(|| {}));
    let stages = ["capture", "motion", "cascade", "gate"];
    for stage in stages {
        let site_a = &site_a;
        scene.add(stage, move || {
            site_a.spawn(&format!("isochron-{stage}"), &["--camera", "cam01"])
        });
    }
    scene.add(LINK_A, || {
        pair.spawn(0, &link_bin, &["--config", &config_a])
    });
    scene.add(LINK_B, || {
        pair.spawn(1, &link_bin, &["--config", &config_b])
    });
    scene.add(BRIDGE, || {
        pair.spawn(1, &bridge_bin, &["--config", &config_b])
    });
    let known = |g: &[i64]| g.iter().filter(|&&c| c != -1).count();
    scene.until(
        "first known cells under the demo camera on B",
        Duration::from_secs(60),
        |g| known(g) > 100,
    );
    scene.steady_state("real pipeline");

    // A's gate events reach B with their sequence numbers and times.
    let (mut on_a, mut on_b) = (Vec::new(), Vec::new());
    scene.until("A's gate events on B", Duration::from_secs(30), |_| {
        on_a.extend(events_of(&events_a));
        on_b.extend(events_of(&events_b));
        !on_b.is_empty() && on_b.iter().all(|e| on_a.contains(e))
    });
    eprintln!(
        "{} gate events on A, {} on B: {on_b:?}",
        on_a.len(),
        on_b.len()
    );

    // B's `isochron status` lists A's stages of cam01 as running, as B's link
    // relays them: live while reports arrive, under the link's process id.
    let link_b = scene.proc(LINK_B).pid();
    let status = site_b.isochron(
        &["status", "--json", "--config", &config_b],
        Duration::from_secs(20),
    );
    for stage in stages {
        let row = status
            .stdout
            .lines()
            .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
            .find(|o| o["stage"] == *stage && o["camera"] == "cam01")
            .unwrap_or_else(|| panic!("no {stage} row in B's status:\n{}", status.stdout));
        assert_eq!(row["state"], "running", "{row}");
        assert_eq!(row["pid"], link_b, "{row}");
    }

    scene.veth_down_and_up("real pipeline", |g| known(g) == 0, |g| known(g) > 100);
    let link_a = scene.proc(LINK_A);
    link_a.terminate(Duration::from_secs(10));
    for line in link_a
        .stderr()
        .lines()
        .filter(|l| l.contains("exported cam01"))
    {
        eprintln!("MEASURED real pipeline: {line}");
    }
}

/// A link whose open-file limit cannot hold what its imports need refuses to
/// start, before joining DDS, with one line naming the limit and the value
/// (`prlimit` sets a hard limit of 300: 20 imported cameras need more).
#[test]
fn a_link_without_enough_open_files_says_which_limit_to_raise() {
    let ids: Vec<String> = (0..20).map(|k| format!("remote{k:02}")).collect();
    let imports: Vec<String> = ids.iter().map(|id| format!("\"{id}\"")).collect();
    // Without DDS Security each imported camera's grid is configured.
    let remote: String = ids
        .iter()
        .map(|id| {
            format!("[[camera]]\nid = \"{id}\"\nsource = \"remote\"\nwidth = 320\nheight = 240\n\n")
        })
        .collect();
    let site = TestSite::new(
        "link-files",
        &format!(
            "{}{remote}\n[link]\nbox_id = \"site\"\nimport = [{}]\nros_domain_id = {}\ndds_interfaces = [\"127.0.0.1\"]\n",
            camera_toml(),
            imports.join(", "),
            dds_domain()
        ),
    );
    let config = site.config_path().display().to_string();
    let link = bin("isochron-link").display().to_string();
    let mut proc = Proc::spawn(
        std::path::Path::new("prlimit"),
        &["--nofile=300:300", &link, "--config", &config],
    );
    let done = proc.finish(Duration::from_secs(20));
    assert_eq!(done.status.code(), Some(78), "{}", done.stderr);
    let line = done
        .stderr
        .lines()
        .find(|l| l.contains("open files"))
        .unwrap_or_else(|| panic!("no open-files line:\n{}", done.stderr));
    assert!(
        line.contains("importing 20 and exporting 0 cameras")
            && line.contains("may open 300")
            && line.contains("raise LimitNOFILE= of isochron-link.service"),
        "{line}"
    );
}

/// With `[link]` configured, `isochron up` runs the link, and the exporter
/// serves the link's counters and the remote box's liveness: the imported
/// camera live, and its remote stage (relayed) up — both going down when the
/// exporting box's link stops. promtool checks the page.
#[test]
fn up_runs_a_configured_link_and_the_exporter_serves_its_counters_and_remote_liveness() {
    let Some(pair) = netns_pair(4) else {
        return;
    };
    let (link_domain, bridge_domain) = (dds_domain(), dds_domain());
    let site_a = box_site(
        "link-up-a",
        &camera_toml(),
        ("box_a", "export", &pair.addrs[0]),
        link_domain,
        "",
    );
    let port = isochron_tests::free_port();
    let site_b = box_site(
        "link-up-b",
        &format!(
            "[exporter]\nlisten = \"127.0.0.1:{port}\"\nstale_after_s = 6\n\n{}{}",
            sized_camera_toml(),
            costmap_toml(bridge_domain, "")
        ),
        ("box_b", "import", &pair.addrs[1]),
        link_domain,
        "",
    );
    let config_a = site_a.config_path().display().to_string();
    let config_b = site_b.config_path().display().to_string();
    let ipc_a = site_a.ipc("source");
    let mut source = Source::new(&ipc_a, START);
    let capture_a = ipc_a.status_publisher("cam01", StageKind::Capture).unwrap();
    let mut link_a = pair.spawn(0, &bin("isochron-link"), &["--config", &config_a]);
    source.wait_for_subscriber(&link_a);
    // B runs no camera of its own: cam01 is imported, so `up` starts the
    // bridge, the exporter and the link only.
    let mut up_b = pair.spawn(1, &bin("isochron"), &["up", "--config", &config_b]);
    let scrape = || {
        let url = format!("http://127.0.0.1:{port}/metrics");
        let mut curl = pair.spawn(
            1,
            Path::new("/usr/bin/curl"),
            &["-sf", "--max-time", "3", &url],
        );
        // The page ends in a newline, which the process output loses.
        curl.finish(Duration::from_secs(10))
            .stdout
            .trim_end()
            .to_string()
            + "\n"
    };
    let link = "stage=\"link\",camera=\"\"";
    let remote = "stage=\"capture\",camera=\"cam01\"";
    let mut page = String::new();
    let started = Instant::now();
    let live = eventually(Duration::from_secs(60), || {
        source.send(&[(HOT_BLOCK, HOT_S1)], 660);
        let status = isochron_runtime::health::starting_status(
            isochron_wire::CameraId::new("cam01").unwrap(),
            StageKind::Capture,
        );
        let _ = capture_a.publish(isochron_wire::StageStatus {
            report_wall_ns: wall_now_ns(),
            ..status
        });
        capture_a.update_connections();
        std::thread::sleep(Duration::from_millis(500));
        page = scrape();
        let value = |name: &str, labels: &str| crate::exporter::value(&page, name, labels);
        (value("isochron_up", link) == Some(1.0)
            && value("isochron_link_imports_live", link) == Some(1.0)
            && value("isochron_link_activity_received_total", link).is_some_and(|n| n > 0.0)
            && value("isochron_up", remote) == Some(1.0))
        .then_some(())
    });
    assert!(
        live.is_some(),
        "B's metrics after {:?}:\n{page}\nup:\n{}",
        started.elapsed(),
        up_b.stderr()
    );
    let (ok, lint) = crate::exporter::promtool(&["check", "metrics"], &page, site_b.dir.path());
    assert!(ok && lint.trim().is_empty(), "promtool: {lint}\n{page}");

    // A's link stops: the remote stage goes down at the exporter's stale time,
    // the import at the link's LIVE_WITHIN.
    link_a.terminate(Duration::from_secs(10));
    let down = eventually(Duration::from_secs(40), || {
        std::thread::sleep(Duration::from_millis(500));
        page = scrape();
        let value = |name: &str, labels: &str| crate::exporter::value(&page, name, labels);
        (value("isochron_up", remote) == Some(0.0)
            && value("isochron_link_imports_live", link) == Some(0.0)
            && value("isochron_link_imports", link) == Some(1.0))
        .then_some(())
    });
    assert!(
        down.is_some(),
        "B's metrics after A's link stopped:\n{page}"
    );
    up_b.terminate(Duration::from_secs(20));
}
