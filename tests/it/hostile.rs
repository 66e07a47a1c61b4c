//! A hostile site network against the DDS services (issue 27): forged link
//! messages from an unauthenticated Eclipse Cyclone DDS participant
//! (`tests/ros2/link_forger.py`) and raw RTPS datagrams from a UDP socket, sent
//! to the real link and costmap bridge while a real exporting link feeds them.
//!
//! Each attack checks that no service exits or stops publishing (the bridge's
//! grid keeps the exporting box's activity, read by the independent Cyclone DDS
//! listener), that the forged samples never reach this box's services, that each
//! is counted as rejected, and that no process grows by more than a bound
//! (`VmRSS`). DDS stays on the loopback interface, each test on its own domains.

use std::time::{Duration, Instant};

use isochron_runtime::ipc::{Events, Ipc, StreamSubscriber};
use isochron_tests::{Proc, TestSite, repo_root, rss_bytes};
use isochron_wire::LAYOUT_VERSION;
use serde_json::Value;

use crate::costmap::{
    HOT_BLOCK, HOT_S1, Source, camera_toml, costmap_toml, dds_domain, expected_cells, held_grid,
    listener_with, messages, netns_pair, python, sized_camera_toml,
};

const START: &str = "2026-03-02T11:00:00Z";
const MIB: u64 = 1 << 20;

/// Two boxes on this machine's loopback: A exports cam01 (fed by the test),
/// B imports it into its bridge, whose grid the Cyclone DDS listener reads.
struct Lab {
    link_domain: u16,
    bridge_domain: u16,
    site_b: TestSite,
    _site_a: TestSite,
    _ipc_a: Ipc,
    source: Source,
    last_feed: Option<Instant>,
    /// A's camera sees nothing (else its hot block).
    quiet: bool,
    link_a: Proc,
    link_b: Proc,
    bridge: Proc,
    listener: Proc,
}

impl Lab {
    /// Starts both boxes; B's config starts with `b_sections`, and ends its
    /// `[costmap]` with `costmap_extra` and its `[link]` with `b_link_extra`.
    fn new(name: &str, b_sections: &str, costmap_extra: &str, b_link_extra: &str) -> Lab {
        Lab::start(name, (b_sections, costmap_extra, b_link_extra), |_| {})
    }

    /// [`Lab::new`], running `before_a(link_domain)` once B's link and bridge
    /// run and before A's link starts (so nothing of A has reached B yet).
    fn start(
        name: &str,
        (b_sections, costmap_extra, b_link_extra): (&str, &str, &str),
        before_a: impl FnOnce(u16),
    ) -> Lab {
        let (link_domain, bridge_domain) = (dds_domain(), dds_domain());
        let link = |box_id: &str, key: &str, extra: &str| {
            format!(
                "\n[link]\nbox_id = \"{box_id}\"\n{key} = [\"cam01\"]\nros_domain_id = {link_domain}\ndds_interfaces = [\"127.0.0.1\"]\n{extra}"
            )
        };
        let site_a = TestSite::new(
            &format!("{name}-a"),
            &format!("{}{}", camera_toml(), link("box_a", "export", "")),
        );
        let site_b = TestSite::new(
            &format!("{name}-b"),
            &format!(
                "{b_sections}{}{}{}",
                sized_camera_toml(),
                costmap_toml(bridge_domain, costmap_extra),
                link("box_b", "import", b_link_extra)
            ),
        );
        let ipc_a = site_a.ipc("source");
        let source = Source::new(&ipc_a, START);
        let link_b = site_b.spawn("isochron-link", &[]);
        let bridge = site_b.spawn("isochron-costmap", &[]);
        let listener = listener_with(bridge_domain, 300, &["--updates".into()]);
        before_a(link_domain);
        let link_a = site_a.spawn("isochron-link", &[]);
        source.wait_for_subscriber(&link_a);
        let mut lab = Lab {
            link_domain,
            bridge_domain,
            site_b,
            _site_a: site_a,
            _ipc_a: ipc_a,
            source,
            last_feed: None,
            quiet: false,
            link_a,
            link_b,
            bridge,
            listener,
        };
        lab.until("A's activity in B's grid", Duration::from_secs(60), |g| {
            g == expected_cells(true)
        });
        lab
    }

    /// Feeds A's camera at 1 Hz: its hot block active, or all quiet.
    fn feed(&mut self) {
        if self
            .last_feed
            .is_none_or(|t| t.elapsed() >= Duration::from_secs(1))
        {
            let hot: &[(usize, f32)] = if self.quiet {
                &[]
            } else {
                &[(HOT_BLOCK, HOT_S1)]
            };
            self.source.send(hot, 660);
            self.last_feed = Some(Instant::now());
        }
    }

    /// The grid B's listener holds now, and how many messages it has received.
    fn grid(&mut self) -> (Option<Vec<i64>>, usize) {
        let msgs = messages(&mut self.listener);
        (held_grid(&msgs), msgs.len())
    }

    /// Feeds A and reads B until `f` holds for B's grid; fails after `timeout`
    /// with the services' logs.
    fn until(&mut self, what: &str, timeout: Duration, mut f: impl FnMut(&[i64]) -> bool) {
        let begin = Instant::now();
        loop {
            self.feed();
            if self.grid().0.is_some_and(|g| f(&g)) {
                return;
            }
            assert!(
                begin.elapsed() < timeout,
                "timed out waiting for {what}\n{}",
                self.logs()
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    fn logs(&mut self) -> String {
        format!(
            "link A:\n{}\n-----\nlink B:\n{}\n-----\nbridge B:\n{}\n-----\nlistener:\n{}",
            tail(&self.link_a.stderr()),
            tail(&self.link_b.stderr()),
            tail(&self.bridge.stderr()),
            tail(&self.listener.stderr())
        )
    }

    /// Resident memory of B's link and bridge, bytes.
    fn rss(&self) -> [u64; 2] {
        [&self.link_b, &self.bridge].map(|p| rss_bytes(p.pid()).unwrap_or(0))
    }

    /// B's link and bridge grew by less than `limit_mib` since `before` (their
    /// [`Lab::rss`]), measured `what`: both printed, with the logs if not.
    fn assert_rss_within(&mut self, what: &str, before: [u64; 2], limit_mib: u64) {
        let after = self.rss();
        eprintln!(
            "MEASURED RSS {what}: link B {:.1} → {:.1} MiB, bridge B {:.1} → {:.1} MiB",
            before[0] as f64 / MIB as f64,
            after[0] as f64 / MIB as f64,
            before[1] as f64 / MIB as f64,
            after[1] as f64 / MIB as f64
        );
        for k in 0..2 {
            assert!(
                after[k] < before[k] + limit_mib * MIB,
                "grew from {} to {} bytes\n{}",
                before[k],
                after[k],
                self.logs()
            );
        }
    }

    /// Runs the forger (`--forge kind`, `seconds`) against B's link while A's
    /// feed goes on; its JSON summary.
    fn forge(&mut self, kind: &str, seconds: u32, extra: &[&str]) -> Value {
        forge(self.link_domain, (kind, seconds, extra), || self.feed())
    }

    /// B's link's status row (`isochron status --json` on B).
    fn link_row(&self) -> Value {
        self.site_b.status_row("link")
    }

    /// Every service still runs, and B's grid still follows A after `what`:
    /// known, then A's hot cell again after a second of quiet.
    fn still_serving(&mut self, what: &str) {
        for (name, p) in [
            ("link A", &mut self.link_a),
            ("link B", &mut self.link_b),
            ("bridge B", &mut self.bridge),
        ] {
            if let Some(status) = p.wait(Duration::ZERO) {
                panic!("{name} exited ({status}) after {what}:\n{}", p.stderr());
            }
        }
        // The bridge publishes what changes: A's camera goes quiet, then active.
        for (quiet, state) in [(true, "quiet"), (false, "active")] {
            self.quiet = quiet;
            let cells = expected_cells(!quiet);
            self.until(
                &format!("A's camera {state} in B's grid after {what}"),
                Duration::from_secs(20),
                |g| g == cells,
            );
        }
    }
}

/// Runs the forger (`--forge kind` for `seconds`, with `extra` arguments) on
/// `domain`, calling `meanwhile` every 100 ms until it ends; its JSON summary.
fn forge(
    domain: u16,
    (kind, seconds, extra): (&str, u32, &[&str]),
    mut meanwhile: impl FnMut(),
) -> Value {
    let mut args = vec![
        repo_root()
            .join("tests/ros2/link_forger.py")
            .display()
            .to_string(),
        "--domain".into(),
        domain.to_string(),
        "--forge".into(),
        kind.into(),
        "--layout-version".into(),
        LAYOUT_VERSION.to_string(),
        "--seconds".into(),
        seconds.to_string(),
    ];
    args.extend(extra.iter().map(|s| s.to_string()));
    let mut forger = Proc::spawn(&python(), &args);
    let end = Instant::now() + Duration::from_secs(seconds as u64 + 30);
    while forger.wait(Duration::ZERO).is_none() {
        assert!(Instant::now() < end, "the forger did not finish");
        meanwhile();
        std::thread::sleep(Duration::from_millis(100));
    }
    let out = forger.stdout();
    serde_json::from_str(out.lines().last().unwrap_or("")).unwrap_or_else(|e| {
        panic!(
            "link_forger.py --forge {kind}: {e}: {out}\n{}",
            forger.stderr()
        )
    })
}

/// On a link without DDS Security (loopback), the first sample of an imported
/// camera comes from a forger with another grid (160x128 in 16-px blocks, not
/// the camera's 320x240): it is refused, as the camera's `[[camera]]`
/// `width`/`height` give its grid (required without `link.security_dir`),
/// nothing is pinned and the real box's activity arrives after it.
#[test]
fn a_forged_first_sample_does_not_pin_an_imported_camera_grid() {
    python();
    let mut sent = Value::Null;
    let mut lab = Lab::start("first-forged", ("", "", ""), |domain| {
        sent = forge(domain, ("other-grid", 4, &[]), || {});
    });
    assert!(
        sent["matched"].as_u64() >= Some(1) && sent["count"].as_u64() >= Some(10),
        "the forger reached no reader: {sent}"
    );
    let log = lab.link_b.stderr();
    assert!(
        log.contains("rejected activity of cam01 from box \"evil\"")
            && log.contains("as camera.width/height and motion.block_px give"),
        "{log}"
    );
    let rejected = lab.link_row()["rejected"].as_u64().unwrap();
    assert!(rejected >= 1, "nothing counted as rejected");
    eprintln!(
        "MEASURED forged first sample of another grid: {} sent, link B rejected {rejected}, nothing pinned",
        sent["count"]
    );
    assert!(!log.contains("pinned"), "{log}");
    lab.still_serving("a forged first sample");
}

/// The last 60 lines of a log.
fn tail(log: &str) -> String {
    let lines: Vec<&str> = log.lines().collect();
    lines[lines.len().saturating_sub(60)..].join("\n")
}

/// The event records `sub` holds.
fn drain(sub: &StreamSubscriber<Events>) -> usize {
    let mut n = 0;
    while sub.receive().unwrap().is_some() {
        n += 1;
    }
    n
}

/// The longest line of a log, bytes.
fn longest_line(log: &str) -> usize {
    log.lines().map(str::len).max().unwrap_or(0)
}

/// Forged link messages from an unauthenticated Cyclone DDS participant: a grid
/// of 0xFFFFFFFF² blocks with one block, a 65 536² grid with no blocks (then a
/// `plan_now`), a well-formed grid other than the camera's, and event records
/// that end before they start. No service exits or stops publishing, nothing
/// forged reaches B's services, each message is counted as rejected, B's link
/// and bridge grow by less than 32 MiB, and no log line is longer than 2 KiB.
#[test]
fn forged_link_messages_never_crash_or_stall_a_service() {
    python();
    let routes = "\n[[costmap.segment]]\nname = \"all\"\npolygon_m = [[-1, 1.5], [5, 1.5], [5, 7.5], [-1, 7.5]]\n\n[[costmap.route]]\nname = \"via-all\"\nsegments = [\"all\"]\n";
    let mut lab = Lab::new("forged", "", routes, "");
    let ipc_b = lab.site_b.ipc("probe");
    let events_b = ipc_b.subscriber::<Events>("cam01").unwrap();
    let rss0 = lab.rss();
    let mut rejected = lab.link_row()["rejected"].as_u64().unwrap();
    for kind in ["huge-grid", "empty-grid", "other-grid", "events"] {
        let sent = lab.forge(kind, 4, &[]);
        assert!(
            sent["matched"].as_u64() >= Some(1) && sent["count"].as_u64() >= Some(10),
            "the forger reached no reader: {sent}"
        );
        lab.still_serving(kind);
        let now = lab.link_row()["rejected"].as_u64().unwrap();
        assert!(
            now > rejected,
            "{kind}: nothing counted as rejected ({now})"
        );
        eprintln!(
            "MEASURED forged {kind}: {} sent, link B rejected {}",
            sent["count"],
            now - rejected
        );
        rejected = now;
        if kind == "empty-grid" {
            // The bridge answers at once: no work for a grid it never admitted.
            let t = Instant::now();
            let reply = crate::costmap::ros_plan(
                lab.bridge_domain,
                "/isochron/plan_now",
                &["now", "via-all"],
            );
            eprintln!(
                "MEASURED plan_now after a forged 65536² grid: answered in {:?}: {}",
                t.elapsed(),
                reply["message"]
            );
            assert!(t.elapsed() < Duration::from_secs(15));
        }
    }
    assert_eq!(
        drain(&events_b),
        0,
        "a forged event reached B's events service"
    );
    lab.assert_rss_within("under forged messages", rss0, 32);
    let (link_log, bridge_log) = (lab.link_b.stderr(), lab.bridge.stderr());
    assert!(
        link_log.contains("rejected activity of cam01 from box \"evil\""),
        "{link_log}"
    );
    assert!(link_log.contains("end_ns"), "{link_log}");
    for (name, log) in [("link B", &link_log), ("bridge B", &bridge_log)] {
        assert!(
            longest_line(log) < 2048,
            "{name} logged a line of {} bytes",
            longest_line(log)
        );
    }
}

/// One RTPS datagram of one DATA_FRAG submessage to the SPDP reader
/// (`ENTITYID_SPDP_BUILTIN_PARTICIPANT_READER`), from a participant `prefix`
/// no one knows, claiming a sample of `sample_size` bytes: 64 bytes of its
/// first fragment of 1 KiB. 120 bytes on the wire.
fn data_frag(prefix: [u8; 12], sequence: u32, sample_size: u32) -> Vec<u8> {
    let mut d = Vec::new();
    d.extend_from_slice(b"RTPS");
    d.extend_from_slice(&[2, 3, 0x01, 0x0f]); // version 2.3, a vendor id
    d.extend_from_slice(&prefix);
    let mut body = Vec::new();
    body.extend_from_slice(&0u16.to_le_bytes()); // extraFlags
    body.extend_from_slice(&28u16.to_le_bytes()); // octetsToInlineQos
    body.extend_from_slice(&[0x00, 0x01, 0x00, 0xc7]); // readerId: SPDP reader
    body.extend_from_slice(&[0x00, 0x01, 0x00, 0xc2]); // writerId: SPDP writer
    body.extend_from_slice(&0i32.to_le_bytes()); // writerSN high
    body.extend_from_slice(&sequence.to_le_bytes()); // writerSN low
    body.extend_from_slice(&1u32.to_le_bytes()); // fragmentStartingNum
    body.extend_from_slice(&1u16.to_le_bytes()); // fragmentsInSubmessage
    body.extend_from_slice(&1024u16.to_le_bytes()); // fragmentSize
    body.extend_from_slice(&sample_size.to_le_bytes()); // sampleSize
    body.extend_from_slice(&[0x00, 0x03, 0x00, 0x00]); // PL_CDR_LE encapsulation
    body.extend_from_slice(&[0u8; 60]);
    d.push(0x16); // DATA_FRAG
    d.push(0x01); // little-endian
    d.extend_from_slice(&(body.len() as u16).to_le_bytes());
    d.extend_from_slice(&body);
    d
}

/// The unicast discovery (SPDP) ports of participants 0..8 of `domain`
/// (RTPS 9.6.1.1: 7400 + 250·domain + 10 + 2·participant).
fn spdp_ports(domain: u16) -> impl Iterator<Item = u16> {
    (0..8).map(move |p| 7400 + 250 * domain + 10 + 2 * p)
}

/// Raw RTPS DATA_FRAG datagrams from a UDP socket to every participant's SPDP
/// reader on the link's and the bridge's domains, before anything is
/// authenticated: first one datagram per port claiming a 1 GiB sample, then 32
/// from as many unknown participants claiming 0xFFFFFFF0 bytes and 1 MiB + 1.
/// Each claim above RustDDS's bound for a built-in reader (1 MiB, 4 MiB of
/// incomplete samples per reader: `vendor/rustdds`) is dropped before anything
/// is allocated: B's link and bridge grow by less than 16 MiB, keep serving, and
/// log the drops rate-limited.
#[test]
fn a_data_frag_claiming_a_huge_sample_allocates_nothing() {
    python();
    let mut lab = Lab::new("datafrag", "", "", "");
    let socket = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let ports: Vec<u16> = spdp_ports(lab.link_domain)
        .chain(spdp_ports(lab.bridge_domain))
        .collect();
    let send = |prefix: [u8; 12], sequence: u32, size: u32| {
        let datagram = data_frag(prefix, sequence, size);
        assert!(datagram.len() <= 120);
        for port in &ports {
            let _ = socket.send_to(&datagram, ("127.0.0.1", *port));
        }
    };
    let rss0 = lab.rss();
    send([0xee; 12], 1, 1 << 30);
    let t = Instant::now();
    while t.elapsed() < Duration::from_secs(3) {
        lab.feed();
        std::thread::sleep(Duration::from_millis(100));
    }
    lab.assert_rss_within("after one DATA_FRAG claiming 1 GiB", rss0, 16);
    for k in 0..32u8 {
        let mut prefix = [0xee; 12];
        prefix[11] = k;
        send(prefix, 2, 0xFFFF_FFF0);
        send(prefix, 3, (1 << 20) + 1);
    }
    lab.still_serving("DATA_FRAG datagrams");
    lab.assert_rss_within(
        "after 64 more DATA_FRAGs (0xFFFFFFF0 and 1 MiB + 1 bytes claimed)",
        rss0,
        16,
    );
    let log = lab.link_b.stderr();
    assert!(
        log.contains("exceeds the reader's max_sample_size"),
        "{}",
        tail(&log)
    );
    let drops = log.matches("max_sample_size").count();
    assert!(
        drops <= 12,
        "{drops} lines for 65 drops: not rate-limited\n{}",
        tail(&log)
    );
}

/// `isochron_up{stage, camera}` in the exporter's metrics on 127.0.0.1:`port`.
fn up(port: u16, stage: &str, camera: &str) -> Option<f64> {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(5))).ok()?;
    write!(
        s,
        "GET /metrics HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n"
    )
    .ok()?;
    let mut text = String::new();
    s.read_to_string(&mut text).ok()?;
    let prefix = format!("isochron_up{{stage=\"{stage}\",camera=\"{camera}\"}} ");
    text.lines()
        .find_map(|l| l.strip_prefix(&prefix))
        .and_then(|v| v.trim().parse().ok())
}

/// The state of `stage` of cam01 in B's `isochron status`, and its pid.
fn remote_row(site: &TestSite, stage: &str) -> (String, u64) {
    let rows = site.status_rows();
    let row = rows
        .iter()
        .find(|r| r["stage"] == stage && r["camera"] == "cam01")
        .unwrap_or_else(|| panic!("no {stage} row for cam01: {rows:?}"));
    (
        row["state"].as_str().unwrap_or("").to_string(),
        row["pid"].as_u64().unwrap_or(0),
    )
}

/// A forged status of each stage of cam01 with a report time of 2^62 and pid 1
/// (an unauthenticated Cyclone DDS participant, box "evil"): B relays it as
/// what B saw and when — the report time of its arrival, the relaying link's
/// pid — so once the forger stops, B's `isochron status` shows the stages stale
/// within 15 s and the exporter's `isochron_up` drops to 0 within its
/// `stale_after_s` (8 s), instead of "running" for 29 minutes.
#[test]
fn a_remote_status_is_live_only_while_it_arrives() {
    python();
    let port = isochron_tests::free_port();
    let exporter = format!("[exporter]\nlisten = \"127.0.0.1:{port}\"\nstale_after_s = 8\n\n");
    let mut lab = Lab::new("status", &exporter, "", "");
    let _exporter = lab.site_b.spawn("isochron-exporter", &[]);
    let sent = lab.forge("status", 4, &[]);
    assert!(sent["matched"].as_u64() >= Some(1), "{sent}");
    let stopped = Instant::now();
    let (state, pid) = remote_row(&lab.site_b, "gate");
    assert_eq!(state, "running", "the forged report arrived a moment ago");
    assert_eq!(
        pid,
        lab.link_b.pid() as u64,
        "the relaying link's pid, not the sender's"
    );
    assert!(
        isochron_tests::eventually(Duration::from_secs(10), || {
            (up(port, "gate", "cam01") == Some(1.0)).then_some(())
        })
        .is_some(),
        "the exporter never saw the relayed status"
    );
    let down = isochron_tests::eventually(Duration::from_secs(20), || {
        (up(port, "gate", "cam01") == Some(0.0)).then(|| stopped.elapsed())
    })
    .expect("isochron_up stayed 1 after the sender stopped");
    let stale = isochron_tests::eventually(Duration::from_secs(25), || {
        (remote_row(&lab.site_b, "gate").0 == "stale").then(|| stopped.elapsed())
    })
    .expect("isochron status kept the forged stage running");
    eprintln!(
        "MEASURED forged status (report time 2^62, pid 1) after its sender stopped: isochron_up 0 after {down:?}, isochron status stale after {stale:?}"
    );
    assert!(stale < Duration::from_secs(20) && down < Duration::from_secs(14));
    lab.still_serving("forged status");
}

/// Runs `isochron keystore args`, which must succeed.
pub(crate) fn keystore(args: &[&str]) {
    let mut p = Proc::spawn(
        &isochron_tests::bin("isochron"),
        &[&["keystore"], args].concat(),
    );
    let done = p.finish(Duration::from_secs(60));
    assert!(
        done.status.success(),
        "isochron keystore {args:?}: {}",
        done.stderr
    );
}

/// Two boxes in two network namespaces joined by a veth pair, their links with
/// DDS Security from one keystore made by `isochron keystore` (each box's
/// permissions: publish what it exports, read what it imports): A's activity
/// reaches B's grid. An unauthenticated Cyclone DDS participant on B's side of
/// the veth, forging activity of box "evil", detections of two people and every
/// stage's status, matches no reader: nothing of it reaches B's link, grid,
/// services or status.
#[test]
fn secured_boxes_exchange_activity_and_ignore_an_unauthenticated_participant() {
    let Some(pair) = netns_pair(3) else {
        return;
    };
    let (link_domain, bridge_domain) = (dds_domain(), dds_domain());
    let keys = tempfile::tempdir().unwrap();
    let dir = keys.path().display().to_string();
    keystore(&["init", &dir]);
    let link = |box_id: &str, key: &str, addr: &str| {
        format!(
            "\n[link]\nbox_id = \"{box_id}\"\n{key} = [\"cam01\"]\nros_domain_id = {link_domain}\ndds_interfaces = [\"{addr}\"]\nsecurity_dir = \"{dir}/enclaves/{box_id}\"\n"
        )
    };
    let site_a = TestSite::new(
        "secured-a",
        &format!(
            "{}{}",
            camera_toml(),
            link("box_a", "export", &pair.addrs[0])
        ),
    );
    let site_b = TestSite::new(
        "secured-b",
        &format!(
            "{}{}{}",
            camera_toml(),
            costmap_toml(bridge_domain, ""),
            link("box_b", "import", &pair.addrs[1])
        ),
    );
    for site in [&site_a, &site_b] {
        keystore(&[
            "enclave",
            &dir,
            "--config",
            &site.config_path().display().to_string(),
        ]);
    }
    let permissions =
        std::fs::read_to_string(keys.path().join("enclaves/box_a/permissions.xml")).unwrap();
    assert!(
        permissions.contains("<publish><topics><topic>rt/isochron/link/cam01/*</topic>"),
        "{permissions}"
    );

    let ipc_a = site_a.ipc("source");
    let mut source = Source::new(&ipc_a, START);
    let (link_bin, bridge_bin) = (
        isochron_tests::bin("isochron-link"),
        isochron_tests::bin("isochron-costmap"),
    );
    let (config_a, config_b) = (
        site_a.config_path().display().to_string(),
        site_b.config_path().display().to_string(),
    );
    let mut link_a = pair.spawn(0, &link_bin, &["--config", &config_a]);
    source.wait_for_subscriber(&link_a);
    let mut link_b = pair.spawn(1, &link_bin, &["--config", &config_b]);
    let mut bridge = pair.spawn(1, &bridge_bin, &["--config", &config_b]);
    let script = repo_root()
        .join("tests/ros2/costmap_listener.py")
        .display()
        .to_string();
    let mut listener = pair.spawn(
        1,
        &python(),
        &[
            script,
            "--domain".into(),
            bridge_domain.to_string(),
            "--topic".into(),
            "/isochron_test/activity_costmap".into(),
            "--updates".into(),
            "--timeout".into(),
            "300".into(),
        ],
    );
    let ipc_b = site_b.ipc("probe");
    let detections_b = ipc_b
        .subscriber::<isochron_runtime::ipc::Detections>("cam01")
        .unwrap();
    let hot = expected_cells(true);
    let mut last_feed: Option<Instant> = None;
    let mut follow =
        |what: &str, timeout: Duration, listener: &mut Proc, logs: &dyn Fn() -> String| {
            let begin = Instant::now();
            loop {
                if last_feed.is_none_or(|t| t.elapsed() >= Duration::from_secs(1)) {
                    source.send(&[(HOT_BLOCK, HOT_S1)], 660);
                    last_feed = Some(Instant::now());
                }
                if held_grid(&messages(listener)).is_some_and(|g| g == hot) {
                    eprintln!("{what}: after {:?}", begin.elapsed());
                    return;
                }
                assert!(
                    begin.elapsed() < timeout,
                    "timed out waiting for {what}\n{}",
                    logs()
                );
                std::thread::sleep(Duration::from_millis(100));
            }
        };
    let logs = || {
        format!(
            "link A:\n{}\n-----\nlink B:\n{}\n-----\nbridge:\n{}",
            tail(&link_a.stderr()),
            tail(&link_b.stderr()),
            tail(&bridge.stderr())
        )
    };
    follow(
        "MEASURED secured link: A's activity in B's grid",
        Duration::from_secs(90),
        &mut listener,
        &logs,
    );
    assert!(link_b.stderr().contains("DDS Security on"));

    let forger_config = format!(
        "<CycloneDDS><Domain id=\"any\"><General><Interfaces><NetworkInterface address=\"{}\"/></Interfaces><AllowMulticast>true</AllowMulticast></General></Domain></CycloneDDS>",
        pair.addrs[1]
    );
    let forger = repo_root()
        .join("tests/ros2/link_forger.py")
        .display()
        .to_string();
    let rejected0 = site_b.status_row("link")["rejected"].as_u64().unwrap();
    for kind in ["evil", "detections", "status"] {
        let mut p = pair.spawn(
            1,
            &python(),
            &[
                forger.clone(),
                "--domain".into(),
                link_domain.to_string(),
                "--forge".into(),
                kind.into(),
                "--layout-version".into(),
                LAYOUT_VERSION.to_string(),
                "--seconds".into(),
                "5".into(),
                "--config".into(),
                forger_config.clone(),
            ],
        );
        let done = p.finish(Duration::from_secs(40));
        let out: Value = serde_json::from_str(done.stdout.lines().last().unwrap_or(""))
            .unwrap_or_else(|e| panic!("link_forger.py: {e}: {}\n{}", done.stdout, done.stderr));
        eprintln!("MEASURED unauthenticated forger ({kind}) against secured links: {out}");
        assert_eq!(
            out["matched"], 0,
            "an unauthenticated participant matched a reader: {out}"
        );
        assert!(out["count"].as_u64() >= Some(10), "{out}");
        follow(
            &format!("A's activity in B's grid after the forged {kind}"),
            Duration::from_secs(20),
            &mut listener,
            &logs,
        );
    }
    assert!(
        detections_b.receive().unwrap().is_none(),
        "a forged detection reached B"
    );
    let rows = site_b.status_rows();
    for row in rows
        .iter()
        .filter(|r| r["camera"] == "cam01" && r["stage"] != "costmap")
    {
        assert_ne!(row["state"], "running", "a forged status reached B: {row}");
    }
    let link_row = rows.iter().find(|r| r["stage"] == "link").unwrap();
    assert_eq!(
        link_row["rejected"].as_u64(),
        Some(rejected0),
        "forged messages reached B's link: {link_row}"
    );
    for (name, p) in [
        ("link A", &mut link_a),
        ("link B", &mut link_b),
        ("bridge B", &mut bridge),
    ] {
        assert!(
            p.wait(Duration::ZERO).is_none(),
            "{name} exited:\n{}",
            p.stderr()
        );
    }
}

/// Without DDS Security, a link on an interface other than loopback refuses to
/// start (exit 78, one line saying what to set) unless `link.insecure = true`.
#[test]
fn a_link_off_loopback_refuses_to_run_unauthenticated() {
    let site = TestSite::new(
        "unsecured",
        &format!(
            "{}\n[link]\nbox_id = \"box_a\"\nexport = [\"cam01\"]\nros_domain_id = {}\n",
            camera_toml(),
            dds_domain()
        ),
    );
    let done = site
        .spawn("isochron-link", &[])
        .finish(Duration::from_secs(20));
    let log = done.stderr;
    assert_eq!(done.status.code(), Some(78), "{log}");
    assert!(
        log.contains("without DDS Security on every interface")
            && log.contains("link.security_dir")
            && log.contains("link.insecure = true"),
        "{log}"
    );
}

/// A stalled ROS 2 subscriber (the Cyclone DDS listener stopped with SIGSTOP:
/// it acknowledges nothing) fills the bridge's reliable send window and its
/// grid publishes fail: the bridge logs them rate-limited, each line short
/// (before: the whole grid, 325 KB a line), and publishes on (a new
/// subscriber gets its grid).
#[test]
fn a_blocked_grid_publish_logs_a_short_line() {
    python();
    let domain = dds_domain();
    let site = TestSite::new(
        "blocked",
        &format!("{}{}", camera_toml(), costmap_toml(domain, "")),
    );
    let ipc = site.ipc("source");
    let mut source = Source::new(&ipc, START);
    let bridge = site.spawn("isochron-costmap", &[]);
    source.wait_for_subscriber(&bridge);
    let mut listener = listener_with(domain, 300, &["--updates".into()]);
    let mut k = 0usize;
    let mut feed = |source: &mut Source| {
        // A different hot block every second: every publish is a change.
        k += 1;
        source.send(&[(k % 300, HOT_S1)], 660);
    };
    let begin = Instant::now();
    while messages(&mut listener).len() < 3 {
        assert!(
            begin.elapsed() < Duration::from_secs(60),
            "no grid reached the listener\n{}",
            bridge.stderr()
        );
        feed(&mut source);
        std::thread::sleep(Duration::from_millis(500));
    }
    listener.signal(libc::SIGSTOP);
    let failed = |log: &str| {
        log.lines()
            .filter(|l| l.contains("publishing") && l.contains("failed"))
            .count()
    };
    let begin = Instant::now();
    while failed(&bridge.stderr()) == 0 && begin.elapsed() < Duration::from_secs(60) {
        feed(&mut source);
        std::thread::sleep(Duration::from_millis(250));
    }
    let t = Instant::now();
    while t.elapsed() < Duration::from_secs(15) {
        feed(&mut source);
        std::thread::sleep(Duration::from_millis(250));
    }
    listener.signal(libc::SIGCONT);
    let log = bridge.stderr();
    let lines = failed(&log);
    eprintln!(
        "MEASURED stalled subscriber: {lines} publish-failure lines in {:?}, the longest log line {} bytes",
        begin.elapsed(),
        longest_line(&log)
    );
    assert!(
        lines >= 1,
        "the stalled subscriber never blocked a publish:\n{}",
        tail(&log)
    );
    assert!(
        lines <= 14,
        "{lines} lines: not rate-limited\n{}",
        tail(&log)
    );
    assert!(
        longest_line(&log) < 2048,
        "a log line of {} bytes",
        longest_line(&log)
    );
    // The bridge publishes on: a new subscriber gets grids.
    let mut fresh = listener_with(domain, 60, &[]);
    let t = Instant::now();
    while messages(&mut fresh).is_empty() {
        assert!(
            t.elapsed() < Duration::from_secs(30),
            "the bridge published nothing after the stall\n{}",
            tail(&bridge.stderr())
        );
        feed(&mut source);
        std::thread::sleep(Duration::from_millis(250));
    }
}
