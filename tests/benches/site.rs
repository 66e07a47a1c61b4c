//! Site benchmark (issue 18, "a site of many base stations"): how many remote
//! cameras one site bridge keeps up with.
//!
//! Simulated boxes — one DDS participant each, as `isochron-link` on a base
//! station, [`PER_BOX`] cameras per box — publish synthetic activity (1 Hz per
//! camera, a [`FRAME`] camera's blocks with a moving hot spot, cameras spread
//! over the second) on loopback DDS, exactly the `isochron_msgs/msg/Activity`
//! the link sends. The site box runs the real `isochron-link` importing every
//! camera and the real `isochron-costmap` over a floor tiled with the cameras'
//! footprints. For each camera count (`--cameras`, default 48, 96, 192, 384 = 1,
//! 2, 4, 8 boxes) it waits for the link's and the bridge's first status reports
//! (their start-up), then `--warmup` seconds, then measures `--seconds`:
//!
//! * CPU of the site link, the bridge and the simulated boxes (this process),
//!   `/proc/<pid>/stat`, in % of one core;
//! * from the status reports (every 5 s): the bridge's activity intake
//!   (samples/s, its `received` counter from the report before the window to
//!   the first after it) and, from its last report, its origin → grid latency p50/p99 (a box published the
//!   sample → the bridge published a grid holding it, including the bridge's
//!   `publish_hz` wait), and the link's origin → activity-service latency;
//! * the bytes of one activity message (CDR).
//!
//! A count **holds** when no process died, the bridge took at least 95 % of the
//! cameras' samples per second and its origin → grid p99 stayed under 1 s.
//!
//! Run: `cargo xtask bench site [-- OPTIONS]` (it builds the release binaries
//! first), or `cargo bench -p isochron-tests --bench site -- [OPTIONS]` after
//! `cargo build --release --workspace --bins`. Options: `--cameras 48,96,...`,
//! `--warmup S` (6), `--seconds S` (15), `--quick` (48 cameras, 3 s + 6 s, one
//! JSON line; what `cargo xtask test` runs). The last line of every run is one
//! JSON object with `"bench": "site"`.

use std::net::IpAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use isochron_config::DEFAULT_LINK_NAMESPACE;
use isochron_config::clock::{NS_PER_S, wall_now_ns};
use isochron_link::dds::{LinkDds, Publisher};
use isochron_link::msgs::{Message, cdr_len};
use isochron_runtime::ipc::{Activity, Ipc};
use isochron_runtime::topology::StageKind;
use isochron_tests::{
    Proc, TestSite, bench_args, bench_count, bench_options, bench_secs, bin, clock_ticks_per_s,
    cpu_ticks,
};
use isochron_wire::{ActivityHeader, BlockActivity, CameraId, Preamble, StageStatus, Stream};

/// Cameras per simulated base station.
const PER_BOX: usize = 48;
/// Each camera's frame and block size: 40 × 30 blocks.
const FRAME: (u32, u32, u32) = (640, 480, 16);
/// Edge of a camera's floor footprint, metres.
const TILE_M: f64 = 4.0;

/// systemd's default hard limit of open files, up to which a service may raise
/// its soft limit (as every isochron service does).
const SYSTEMD_NOFILE: u64 = 524_288;

/// Gives this process and the processes it starts the open-file limits of a
/// systemd service (soft and hard [`SYSTEMD_NOFILE`]) where it may (as root), so
/// the count a run reaches is the site box's, not the shell's; returns the soft
/// limit in force.
fn systemd_open_file_limit() -> u64 {
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit and setrlimit only read and write `limit`.
    unsafe {
        libc::getrlimit(libc::RLIMIT_NOFILE, &mut limit);
        let want = limit.rlim_max.max(SYSTEMD_NOFILE);
        let raised = libc::rlimit {
            rlim_cur: want,
            rlim_max: want,
        };
        if libc::setrlimit(libc::RLIMIT_NOFILE, &raised) == 0 {
            limit = raised;
        }
    }
    limit.rlim_cur
}

const USAGE: &str = "usage: site [--quick] [--cameras N,N,...] [--warmup S] [--seconds S]";

struct Options {
    cameras: Vec<usize>,
    warmup: Duration,
    seconds: Duration,
}

fn parse_args(args: impl IntoIterator<Item = String>) -> Result<Options, String> {
    let mut o = Options {
        cameras: vec![48, 96, 192, 384],
        warmup: Duration::from_secs(6),
        seconds: Duration::from_secs(15),
    };
    let valued = ["--cameras", "--warmup", "--seconds"];
    for (flag, value) in bench_args("site", USAGE, (&["--quick"], &valued), args)? {
        let value = value.unwrap_or_default();
        match flag.as_str() {
            "--quick" => {
                o.cameras = vec![48];
                o.warmup = Duration::from_secs(3);
                o.seconds = Duration::from_secs(6);
            }
            "--cameras" => {
                o.cameras = value
                    .split(',')
                    .map(|v| bench_count(&flag, v.trim()).ok())
                    .collect::<Option<Vec<_>>>()
                    .ok_or_else(|| {
                        format!("--cameras: expected counts ≥ 1 such as 48,96, found '{value}'")
                    })?
            }
            "--warmup" => o.warmup = bench_secs(&flag, &value, 1.0)?,
            _ => o.seconds = bench_secs(&flag, &value, 1.0)?,
        }
    }
    Ok(o)
}

/// Camera `k` of box `b`.
fn camera_id(b: usize, k: usize) -> String {
    format!("b{b}_c{k:02}")
}

/// The site box's config: every camera on its own floor tile, the bridge's
/// grid over all tiles, the link importing every camera.
fn site_body(cameras: &[String], link_domain: u16, bridge_domain: u16) -> String {
    let cols = (cameras.len() as f64).sqrt().ceil() as usize;
    let rows = cameras.len().div_ceil(cols);
    let (w, h, _) = FRAME;
    let depth = TILE_M * h as f64 / w as f64;
    let mut body = String::new();
    for (i, id) in cameras.iter().enumerate() {
        let (x, y) = ((i % cols) as f64 * TILE_M, (i / cols) as f64 * TILE_M);
        let p = |u: u32, v: u32| {
            format!(
                "  {{ image_px = [{u}, {v}], floor_m = [{}, {}] }},\n",
                x + TILE_M * u as f64 / w as f64,
                y + depth * v as f64 / h as f64
            )
        };
        body += &format!(
            "[[camera]]\nid = \"{id}\"\nsource = \"remote\"\nwidth = {w}\nheight = {h}\nfloor_points = [\n{}{}{}{}{}]\n\n",
            p(0, 0),
            p(w, 0),
            p(w, h),
            p(0, h),
            p(w / 2, h / 2)
        );
    }
    let imports: Vec<String> = cameras.iter().map(|c| format!("\"{c}\"")).collect();
    body += &format!(
        "[costmap]\norigin_x_m = 0.0\norigin_y_m = 0.0\nresolution_m = 0.5\n\
         width_cells = {}\nheight_cells = {}\nframe_id = \"map\"\n\
         topic = \"/isochron/bench_site_costmap\"\nros_domain_id = {bridge_domain}\n\
         dds_interfaces = [\"127.0.0.1\"]\npublish_hz = 4\nstale_s = 10\n\n\
         [link]\nbox_id = \"site\"\nimport = [{}]\nros_domain_id = {link_domain}\n\
         dds_interfaces = [\"127.0.0.1\"]\n",
        (cols as f64 * TILE_M / 0.5).ceil(),
        (rows as f64 * TILE_M / 0.5).ceil(),
        imports.join(", ")
    );
    body
}

/// One second of camera `id`'s activity: a hot block that moves every second.
fn activity(box_id: &str, id: &str, second: u64, start_ns: i64) -> Message<Activity> {
    let (w, h, px) = FRAME;
    let blocks = ((w / px) * (h / px)) as usize;
    let mut payload = vec![BlockActivity::default(); blocks];
    payload[(second as usize * 37 + id.len()) % blocks].s1 = 2.0;
    let mut preamble = Preamble::new::<BlockActivity>(
        Stream::Activity,
        CameraId::new(id).unwrap_or_default(),
        second,
        blocks,
    );
    preamble.capture_time_ns = start_ns + (second as i64 + 1) * NS_PER_S;
    preamble.origin_wall_ns = wall_now_ns();
    let header = ActivityHeader {
        preamble,
        grid_w: w / px,
        grid_h: h / px,
        block_px: px,
        frame_width: w,
        frame_height: h,
        t_star: 660,
        frames: 25,
        frame_rate: 25.0,
        ..Default::default()
    };
    Message {
        box_id: box_id.to_string(),
        header,
        payload,
    }
}

/// A simulated base station: its link's DDS participant sending its cameras'
/// activity at 1 Hz, camera `k` at `k / PER_BOX` of each second.
fn simulated_box(b: usize, cameras: usize, domain: u16, stop: Arc<AtomicBool>) -> JoinHandle<()> {
    let name = format!("box{b}");
    let thread = std::thread::Builder::new().name(name.clone());
    let spawned = thread.spawn(move || {
        let box_id = name;
        let lo = [IpAddr::V4(std::net::Ipv4Addr::LOCALHOST)];
        let mut dds = LinkDds::start(domain, &lo, (&box_id, None), DEFAULT_LINK_NAMESPACE)
            .unwrap_or_else(|e| panic!("{box_id}: {e}"));
        let ids: Vec<String> = (0..cameras).map(|k| camera_id(b, k)).collect();
        let writers: Vec<_> = ids
            .iter()
            .map(|id| {
                dds.stream::<Activity, Publisher<_>>(id, 1, None)
                    .unwrap_or_else(|e| panic!("{box_id}: a writer for {id}: {e}"))
            })
            .collect();
        let (t0, start_ns) = (Instant::now(), wall_now_ns());
        for second in 0u64.. {
            for (k, (id, writer)) in ids.iter().zip(&writers).enumerate() {
                let at = isochron_config::clock::saturating_secs(
                    second as f64 + k as f64 / PER_BOX as f64,
                );
                if let Some(wait) = at.checked_sub(t0.elapsed()) {
                    std::thread::sleep(wait);
                }
                if stop.load(Ordering::Relaxed) {
                    return;
                }
                let _ = writer.publish(activity(&box_id, id, second, start_ns));
            }
        }
    });
    spawned.expect("a thread for a simulated box")
}

/// The result for one camera count.
struct Run {
    cameras: usize,
    boxes: usize,
    link_start_s: f64,
    bridge_start_s: f64,
    link_cpu: f64,
    bridge_cpu: f64,
    boxes_cpu: f64,
    bridge_rate_in: f64,
    link_rate_out: f64,
    grid_p50_ms: f64,
    grid_p99_ms: f64,
    link_p50_ms: f64,
    link_p99_ms: f64,
    held: bool,
    reason: String,
}

/// The newest status report of site-wide `stage` made after `after_ns` (waits
/// up to `wait` for one).
fn status_after(ipc: &Ipc, stage: StageKind, after_ns: i64, wait: Duration) -> Option<StageStatus> {
    let reader = ipc.status_subscriber("", stage).ok()?;
    let end = Instant::now() + wait;
    while Instant::now() < end {
        if let Some(s) = reader.latest().filter(|s| s.report_wall_ns > after_ns) {
            return Some(s);
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    None
}

/// Counter `count` per second between two reports.
fn per_s(
    a: Option<StageStatus>,
    b: Option<StageStatus>,
    count: impl Fn(&StageStatus) -> u64,
) -> f64 {
    match (a, b) {
        (Some(a), Some(b)) if b.report_wall_ns > a.report_wall_ns => {
            (count(&b) - count(&a)) as f64 * 1e9 / (b.report_wall_ns - a.report_wall_ns) as f64
        }
        _ => 0.0,
    }
}

fn run(n: usize, opts: &Options, domains: (u16, u16)) -> Run {
    let boxes = n.div_ceil(PER_BOX);
    let per_box = |b: usize| PER_BOX.min(n - b * PER_BOX);
    let cameras: Vec<String> = (0..boxes)
        .flat_map(|b| (0..per_box(b)).map(move |k| camera_id(b, k)))
        .collect();
    let site = TestSite::new("bench-site", &site_body(&cameras, domains.0, domains.1));
    let config = site.config_path().display().to_string();
    let mut link = Proc::spawn(&bin("isochron-link"), &["--config", &config]);
    let mut bridge = Proc::spawn(&bin("isochron-costmap"), &["--config", &config]);
    let ipc = site.ipc("bench");
    let stop = Arc::new(AtomicBool::new(false));
    let sources: Vec<_> = (0..boxes)
        .map(|b| simulated_box(b, per_box(b), domains.0, stop.clone()))
        .collect();
    // The link creates four DDS readers per camera, the bridge opens two inputs
    // per camera, before their first reports.
    let spawned = (Instant::now(), wall_now_ns());
    let up = Duration::from_secs(120);
    let reports = ipc.status_subscriber("", StageKind::Link).ok();
    let link_up = loop {
        let report = reports
            .as_ref()
            .and_then(|r| r.latest())
            .filter(|s| s.report_wall_ns > spawned.1);
        if report.is_some() || link.wait(Duration::ZERO).is_some() || spawned.0.elapsed() > up {
            break report;
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    if link_up.is_none() {
        eprintln!("site: the link did not report within {up:?}, or died");
    }
    let link_start_s = spawned.0.elapsed().as_secs_f64();
    if status_after(&ipc, StageKind::Costmap, spawned.1, up).is_none() {
        eprintln!("site: the bridge did not report within {up:?}");
    }
    let bridge_start_s = spawned.0.elapsed().as_secs_f64();
    std::thread::sleep(opts.warmup);
    // The bridge's counters at the window's start (its latest report).
    let wait = Duration::from_secs(7);
    let first = status_after(&ipc, StageKind::Costmap, 0, wait);
    let first_link = status_after(&ipc, StageKind::Link, 0, wait);
    let ticks = || {
        [
            cpu_ticks(link.pid()),
            cpu_ticks(bridge.pid()),
            cpu_ticks(std::process::id()),
        ]
    };
    let (before, t0) = (ticks(), Instant::now());
    let window_ns = wall_now_ns();
    std::thread::sleep(opts.seconds);
    let (after, secs) = (ticks(), t0.elapsed().as_secs_f64());
    let pct = |k: usize| match (before[k], after[k]) {
        (Some(a), Some(b)) => 100.0 * (b - a) as f64 / clock_ticks_per_s() / secs,
        _ => f64::NAN,
    };
    let bridge_status = status_after(&ipc, StageKind::Costmap, window_ns, wait);
    let link_status = status_after(&ipc, StageKind::Link, window_ns, wait);
    stop.store(true, Ordering::Relaxed);
    for s in sources {
        let _ = s.join();
    }
    let mut r = Run {
        cameras: n,
        boxes,
        link_start_s,
        bridge_start_s,
        link_cpu: pct(0),
        bridge_cpu: pct(1),
        boxes_cpu: pct(2),
        // Samples per second between the report before the window and the
        // first one after it.
        bridge_rate_in: per_s(first, bridge_status, |s| s.received),
        link_rate_out: per_s(first_link, link_status, |s| s.sent),
        grid_p50_ms: bridge_status.map_or(f64::NAN, |s| s.e2e_latency_p50_ms as f64),
        grid_p99_ms: bridge_status.map_or(f64::NAN, |s| s.e2e_latency_p99_ms as f64),
        link_p50_ms: link_status.map_or(f64::NAN, |s| s.e2e_latency_p50_ms as f64),
        link_p99_ms: link_status.map_or(f64::NAN, |s| s.e2e_latency_p99_ms as f64),
        held: true,
        reason: String::new(),
    };
    judge(&mut r, n, &mut link, &mut bridge);
    r
}

/// Whether the run held (both processes alive, the bridge took every camera's
/// samples, the grid's p99 under a second), and both processes stopped; their
/// last log lines where it did not hold.
fn judge(r: &mut Run, n: usize, link: &mut Proc, bridge: &mut Proc) {
    let dead: Vec<String> = [("link", &mut *link), ("bridge", &mut *bridge)]
        .into_iter()
        .filter_map(|(name, p)| {
            p.wait(Duration::ZERO)
                .map(|st| format!("{name} died ({st})"))
        })
        .collect();
    let mut fail = |why: String| {
        if r.held {
            r.held = false;
            r.reason = why;
        }
    };
    if !dead.is_empty() {
        fail(dead.join(", "));
    }
    if r.bridge_rate_in < 0.95 * n as f64 {
        fail(format!(
            "bridge took {:.0} of {n} samples/s",
            r.bridge_rate_in
        ));
    }
    if r.grid_p99_ms.is_nan() || r.grid_p99_ms >= 1000.0 {
        fail(format!("origin → grid p99 {:.0} ms", r.grid_p99_ms));
    }
    for (name, p) in [("link", &mut *link), ("bridge", &mut *bridge)] {
        if !r.held {
            let log = p.stderr();
            let tail: Vec<&str> = log.lines().rev().take(6).collect();
            eprintln!("site: {n} cameras, {name}'s last log lines (newest first):");
            tail.iter().for_each(|l| eprintln!("  {l}"));
        }
        // Not `terminate`: a process that does not stop is a result, not a
        // reason to lose the others (dropping it kills it).
        if p.wait(Duration::ZERO).is_none() {
            p.signal(libc::SIGTERM);
            if p.wait(Duration::from_secs(20)).is_none() {
                eprintln!("site: {n} cameras: the {name} did not stop within 20 s of SIGTERM");
            }
        }
    }
}

fn main() {
    let opts = bench_options(parse_args);
    let msg_bytes = cdr_len(&activity("box0", &camera_id(0, 0), 0, 0));
    let open_files = systemd_open_file_limit();
    let domain = 1 + (std::process::id() % 228) as u16;
    println!(
        "site bench: {PER_BOX} cameras per box, {}×{} px cameras ({} B of CDR per activity message, 1 Hz), warmup {:?}, window {:?}, open files ≤ {open_files}",
        FRAME.0, FRAME.1, msg_bytes, opts.warmup, opts.seconds
    );
    println!(
        "{:>7} {:>5} {:>8} {:>9} {:>9} {:>9} {:>9} {:>10} {:>9} {:>15} {:>15}  RESULT",
        "CAMERAS",
        "BOXES",
        "LINK UP",
        "BRIDGE UP",
        "LINK CPU",
        "BRIDGE",
        "BOXES",
        "LINK OUT/s",
        "IN/s",
        "GRID p50/p99",
        "LINK p50/p99"
    );
    let mut runs = Vec::new();
    for &n in &opts.cameras {
        let r = run(n, &opts, (domain, domain + 1));
        println!(
            "{:>7} {:>5} {:>7.1}s {:>8.1}s {:>8.0}% {:>8.0}% {:>8.0}% {:>10.1} {:>9.1} {:>7.0}/{:<4.0} ms {:>7.0}/{:<4.0} ms  {}",
            r.cameras,
            r.boxes,
            r.link_start_s,
            r.bridge_start_s,
            r.link_cpu,
            r.bridge_cpu,
            r.boxes_cpu,
            r.link_rate_out,
            r.bridge_rate_in,
            r.grid_p50_ms,
            r.grid_p99_ms,
            r.link_p50_ms,
            r.link_p99_ms,
            if r.held {
                "holds".to_string()
            } else {
                format!("falls behind: {}", r.reason)
            }
        );
        runs.push(r);
    }
    let json: Vec<serde_json::Value> = runs
        .iter()
        .map(|r| {
            let num = |v: f64| {
                if v.is_finite() {
                    serde_json::json!((v * 10.0).round() / 10.0)
                } else {
                    serde_json::Value::Null
                }
            };
            serde_json::json!({
                "cameras": r.cameras, "boxes": r.boxes, "link_start_s": num(r.link_start_s), "bridge_start_s": num(r.bridge_start_s),
                "link_cpu_pct": num(r.link_cpu), "bridge_cpu_pct": num(r.bridge_cpu),
                "boxes_cpu_pct": num(r.boxes_cpu), "bridge_in_per_s": num(r.bridge_rate_in), "link_out_per_s": num(r.link_rate_out),
                "grid_p50_ms": num(r.grid_p50_ms), "grid_p99_ms": num(r.grid_p99_ms),
                "link_p50_ms": num(r.link_p50_ms), "link_p99_ms": num(r.link_p99_ms),
                "held": r.held, "reason": r.reason,
            })
        })
        .collect();
    let limit = runs.iter().filter(|r| r.held).map(|r| r.cameras).max();
    println!(
        "{}",
        serde_json::json!({
            "bench": "site", "activity_message_bytes": msg_bytes,
            "per_box": PER_BOX, "runs": json, "largest_held": limit,
        })
    );
    // Nothing reaching the bridge is a broken bench, not a measurement.
    if let Some(r) = runs.iter().find(|r| r.bridge_rate_in <= 0.0) {
        eprintln!(
            "site: no activity reached the bridge at {} cameras: {}",
            r.cameras, r.reason
        );
        std::process::exit(1);
    }
}
