//! isochron-costmap as a separate process, fed synthetic activity by this test over
//! iceoryx2, read back by an independent ROS 2 subscriber (Eclipse Cyclone DDS from
//! Python, `tests/ros2/costmap_listener.py`), and asked for plans and snapshots by
//! the `isochron` CLI.
//!
//! DDS stays on this machine (loopback only, unicast discovery) and every test uses
//! its own DDS domain, derived from the process id, so parallel runs never meet.
//! The Python interpreter is the venv `cargo xtask setup` makes under
//! `target/ros2-venv` (or `$ISOCHRON_ROS2_PYTHON`).

use std::path::PathBuf;
use std::sync::atomic::{AtomicU16, Ordering};
use std::time::{Duration, Instant};

use isochron_config::clock::{Cycle, NS_PER_S, parse_rfc3339, wall_now_ns};
use isochron_runtime::ipc::{Activity, Detections, Ipc, StreamPublisher};
use isochron_store::{Store, StoreMeta, store_path};
use isochron_tests::{NetnsPair, Proc, TestSite, bin, json_list, repo_root, venv_python};
use isochron_wire::geometry::BlockGrid;
use isochron_wire::{
    ActivityHeader, BlockActivity, CameraId, Detection, DetectionHeader, DetectorModel, Keypoint,
    Preamble, Stream,
};
use serde_json::Value;

/// The frame: 320×240 in 16-px blocks (20×15).
const FRAME: (u32, u32, u32) = (320, 240, 16);
const BLOCKS: usize = 20 * 15;

/// The camera's view of the floor, floor → image (homogeneous), with perspective:
/// `u = (80x + 10y + 20) / (0.05y + 1)`, `v = (400 − 60y) / (0.05y + 1)`.
/// The test knows it; the bridge only gets point pairs from it.
pub(crate) fn floor_to_image(p: [f64; 2]) -> [f64; 2] {
    let w = 0.05 * p[1] + 1.0;
    [
        (80.0 * p[0] + 10.0 * p[1] + 20.0) / w,
        (400.0 - 60.0 * p[1]) / w,
    ]
}

/// The grid: 60×60 cells of 0.1 m from (-1, 1.5).
pub(crate) const GRID: (f64, f64, f64, u32, u32) = (-1.0, 1.5, 0.1, 60, 60);

/// Block (10, 7) is the synthetic activity source: pixels x 160..176, y 112..128.
pub(crate) const HOT_BLOCK: usize = 7 * 20 + 10;
/// Its in-place activity and the cost that gives with `cost_scale = 0.05`.
pub(crate) const HOT_S1: f32 = 0.03;
const HOT_COST: i64 = 60;

static NEXT_DOMAIN: AtomicU16 = AtomicU16::new(0);

/// A DDS domain no other test process uses at the same time: derived from the pid,
/// plus a counter for the tests of this process.
pub(crate) fn dds_domain() -> u16 {
    let n = NEXT_DOMAIN.fetch_add(1, Ordering::Relaxed);
    1 + ((std::process::id() as u16)
        .wrapping_mul(7)
        .wrapping_add(n * 101))
        % 230
}

/// The Python of the venv with `cyclonedds`; fails with what to do when missing.
pub(crate) fn python() -> PathBuf {
    venv_python("cyclonedds.domain")
}

/// A pair of network namespaces for a test with the Python peer (checked first),
/// named after this process and a fresh DDS domain (`subnet` keeps concurrent
/// tests apart); `None` where they cannot be made (the test is then skipped).
pub(crate) fn netns_pair(subnet: u8) -> Option<NetnsPair> {
    python();
    let tag = format!("{}{}", std::process::id() % 100_000, dds_domain());
    NetnsPair::new(&tag, subnet)
}

/// The camera table, with floor points taken from [`floor_to_image`] at 5 floor
/// positions (so the bridge fits by least squares).
/// [`camera_toml`] with the camera's `width` and `height` (the test sources'
/// [`FRAME`]): a box that imports it over a link without DDS Security must
/// configure its grid (`link.security_dir` absent).
pub(crate) fn sized_camera_toml() -> String {
    camera_toml().replacen(
        "source = \"unused.avi\"\n",
        &format!(
            "source = \"unused.avi\"\nwidth = {}\nheight = {}\n",
            FRAME.0, FRAME.1
        ),
        1,
    )
}

pub(crate) fn camera_toml() -> String {
    let floor = [[0.0, 2.5], [3.5, 2.5], [4.0, 6.0], [-0.5, 6.0], [1.5, 4.0]];
    let pairs: Vec<String> = floor
        .iter()
        .map(|f| {
            let i = floor_to_image(*f);
            format!(
                "  {{ image_px = [{:.9}, {:.9}], floor_m = [{}, {}] }},",
                i[0], i[1], f[0], f[1]
            )
        })
        .collect();
    format!(
        "[[camera]]\nid = \"cam01\"\nsource = \"unused.avi\"\nfloor_points = [\n{}\n]\n",
        pairs.join("\n")
    )
}

pub(crate) fn costmap_toml(domain: u16, extra: &str) -> String {
    let (x, y, res, w, h) = GRID;
    format!(
        r#"
[costmap]
origin_x_m = {x}
origin_y_m = {y}
resolution_m = {res}
width_cells = {w}
height_cells = {h}
frame_id = "test_map"
topic = "/isochron_test/activity_costmap"
publish_hz = 4
full_every_s = 2
ros_domain_id = {domain}
dds_interfaces = ["127.0.0.1"]
cost_scale = 0.05
weight_long_term = 0.0
stale_s = 120
{extra}
"#
    )
}

/// A site with the test camera and `[costmap]` (`extra` added) on DDS domain `domain`.
pub(crate) fn costmap_site(name: &str, domain: u16, extra: &str) -> TestSite {
    TestSite::new(
        name,
        &format!("{}{}", camera_toml(), costmap_toml(domain, extra)),
    )
}

/// Starts the bridge of `site` with a [`Source`] of cam01's activity from `start`,
/// once the bridge reads it; the source's `Ipc` comes along to be kept open.
pub(crate) fn start_bridge(site: &TestSite, start: &str) -> (Ipc, Source, Proc) {
    let ipc = site.ipc("source");
    let source = Source::new(&ipc, start);
    let costmap = site.spawn("isochron-costmap", &[]);
    source.wait_for_subscriber(&costmap);
    (ipc, source, costmap)
}

/// The grid the bridge should publish while [`HOT_BLOCK`] is active (or not):
/// computed with the true mapping, independently of the bridge's fit.
pub(crate) fn expected_cells(hot: bool) -> Vec<i64> {
    let (x0, y0, res, w, h) = GRID;
    let mut cells = Vec::with_capacity((w * h) as usize);
    for j in 0..h {
        for i in 0..w {
            let c = [x0 + (i as f64 + 0.5) * res, y0 + (j as f64 + 0.5) * res];
            let [u, v] = floor_to_image(c);
            let value = if !(0.0..320.0).contains(&u) || !(0.0..240.0).contains(&v) {
                -1
            } else if hot && (160.0..176.0).contains(&u) && (112.0..128.0).contains(&v) {
                HOT_COST
            } else {
                0
            };
            cells.push(value);
        }
    }
    cells
}

/// Publishes synthetic activity of cam01.
pub(crate) struct Source {
    publisher: StreamPublisher<Activity>,
    start_ns: i64,
    pub(crate) seconds: i64,
}

impl Source {
    pub(crate) fn new(ipc: &Ipc, start: &str) -> Source {
        Source {
            publisher: ipc.publisher::<Activity>("cam01", BLOCKS).unwrap(),
            start_ns: parse_rfc3339(start).unwrap(),
            seconds: 0,
        }
    }

    /// One second of activity: `s1` on the blocks `hot` lists, nothing elsewhere.
    pub(crate) fn send(&mut self, hot: &[(usize, f32)], t_star: u32) {
        let mut blocks = vec![BlockActivity::default(); BLOCKS];
        for &(b, s1) in hot {
            blocks[b].s1 = s1;
        }
        let mut preamble = Preamble::new::<BlockActivity>(
            Stream::Activity,
            CameraId::new("cam01").unwrap(),
            self.publisher.next_sequence(),
            BLOCKS,
        );
        self.seconds += 1;
        preamble.capture_time_ns = self.start_ns + self.seconds * NS_PER_S;
        preamble.origin_wall_ns = wall_now_ns();
        let header = ActivityHeader {
            preamble,
            grid_w: 20,
            grid_h: 15,
            block_px: FRAME.2,
            frame_width: FRAME.0,
            frame_height: FRAME.1,
            t_star,
            model_days: 10,
            frames: 10,
            frame_rate: 10.0,
            ..Default::default()
        };
        self.publisher.send_copy(header, &blocks).unwrap();
    }

    pub(crate) fn wait_for_subscriber(&self, costmap: &Proc) {
        let end = Instant::now() + Duration::from_secs(30);
        while self.publisher.subscriber_count() == 0 {
            assert!(
                Instant::now() < end,
                "isochron-costmap never subscribed:\n{}",
                costmap.stderr()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

/// The listener's JSON lines so far.
pub(crate) fn messages(listener: &mut Proc) -> Vec<Value> {
    listener
        .stdout()
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect()
}

pub(crate) fn data(v: &Value) -> Vec<i64> {
    json_list(&v["data"], Value::as_i64)
}

/// The grid a subscriber holds after the messages so far: the last full grid with
/// the updates since applied.
pub(crate) fn held_grid(msgs: &[Value]) -> Option<Vec<i64>> {
    let last = msgs.iter().rposition(|m| m["kind"] == "grid")?;
    let mut cells = data(&msgs[last]);
    let width = msgs[last]["width"].as_i64().unwrap();
    for m in &msgs[last + 1..] {
        if m["kind"] != "update" {
            continue;
        }
        let (x, y, w) = (
            m["x"].as_i64().unwrap(),
            m["y"].as_i64().unwrap(),
            m["width"].as_i64().unwrap(),
        );
        for (k, v) in data(m).into_iter().enumerate() {
            let (dx, dy) = (k as i64 % w, k as i64 / w);
            cells[((y + dy) * width + x + dx) as usize] = v;
        }
    }
    Some(cells)
}

fn listener(domain: u16, updates: bool, grids: u32, timeout_s: u32) -> Proc {
    let mut args = vec![];
    if updates {
        args.push("--updates".into());
    }
    if grids > 0 {
        args.push("--grids".into());
        args.push(grids.to_string());
    }
    listener_with(domain, timeout_s, &args)
}

/// The listener on the grid topic with `extra` arguments.
pub(crate) fn listener_with(domain: u16, timeout_s: u32, extra: &[String]) -> Proc {
    let script = repo_root().join("tests/ros2/costmap_listener.py");
    let mut args = vec![
        script.display().to_string(),
        "--domain".into(),
        domain.to_string(),
        "--topic".into(),
        "/isochron_test/activity_costmap".into(),
        "--timeout".into(),
        timeout_s.to_string(),
    ];
    args.extend(extra.iter().cloned());
    Proc::spawn(&python(), &args)
}

/// Calls a planning service of the bridge with the independent Cyclone DDS client
/// (`tests/ros2/plan_client.py`); its reply as JSON.
pub(crate) fn ros_plan(domain: u16, service: &str, args: &[&str]) -> Value {
    let script = repo_root().join("tests/ros2/plan_client.py");
    let mut client = std::process::Command::new(python());
    client.arg(&script);
    plan_reply("plan_client.py", client, (domain, service, args))
}

/// Runs the planning services' `client` (named `name`) with the domain, the
/// service and `args`; its reply, a JSON line of kind "reply".
pub(crate) fn plan_reply(
    name: &str,
    mut client: std::process::Command,
    (domain, service, args): (u16, &str, &[&str]),
) -> Value {
    let out = client
        .args(["--domain", &domain.to_string(), "--service", service])
        .args(args)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let reply: Value = serde_json::from_str(stdout.trim()).unwrap_or_else(|e| {
        panic!(
            "{name}: {e}: {stdout}\n{}",
            String::from_utf8_lossy(&out.stderr)
        )
    });
    assert_eq!(
        reply["kind"],
        "reply",
        "no reply from {service}: {reply}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    reply
}

/// Asserts that a client of the planning services (`plan(service, args)`) gets
/// an unknown route and a time outside the day back as a status with the reason.
pub(crate) fn assert_plan_errors(plan: impl Fn(&str, &[&str]) -> Value) {
    let unknown = plan("/isochron/plan_now", &["now", "nowhere"]);
    assert_plan_status(&unknown, 2, "via-west");
    let late = plan(
        "/isochron/plan_offline",
        &["offline", "via-west", "1500", "1440", "5"],
    );
    assert_plan_status(&late, 1, "outside the day");
}

/// Asserts a ROS 2 plan reply has `status` and a message holding `says`.
pub(crate) fn assert_plan_status(reply: &Value, status: u8, says: &str) {
    assert_eq!(reply["status"], status, "{reply}");
    assert!(reply["message"].as_str().unwrap().contains(says), "{reply}");
}

/// Costs of the CLI's JSON and the ROS 2 reply agree (f32 on the way, 3 decimals
/// in the CLI's JSON).
pub(crate) fn same_cost(cli: &Value, ros: &Value) -> bool {
    match (cli.as_f64(), ros.as_f64()) {
        (Some(a), Some(b)) => (a - b).abs() < 0.01,
        _ => cli == ros,
    }
}

/// Feeds [`HOT_BLOCK`] at `t_star` until the listener has a full grid with the hot
/// cells.
fn wait_for_hot_grid(
    what: &str,
    listener: &mut Proc,
    costmap: &Proc,
    source: &mut Source,
    t_star: u32,
    timeout: Duration,
) {
    let hot = expected_cells(true);
    wait_until(
        what,
        listener,
        costmap,
        || source.send(&[(HOT_BLOCK, HOT_S1)], t_star),
        timeout,
        |msgs| msgs.iter().any(|m| m["kind"] == "grid" && data(m) == hot),
    );
}

/// Waits until `f` holds for the listener's messages, feeding the source meanwhile.
pub(crate) fn wait_until(
    what: &str,
    listener: &mut Proc,
    costmap: &Proc,
    mut feed: impl FnMut(),
    timeout: Duration,
    mut f: impl FnMut(&[Value]) -> bool,
) {
    let end = Instant::now() + timeout;
    loop {
        feed();
        let msgs = messages(listener);
        if f(&msgs) {
            return;
        }
        assert!(
            Instant::now() < end,
            "timed out waiting for {what}; listener saw {} messages ({}):\nlistener stderr:\n{}\ncostmap stderr:\n{}",
            msgs.len(),
            msgs.iter()
                .map(|m| m["kind"].as_str().unwrap_or("?"))
                .collect::<Vec<_>>()
                .join(" "),
            listener.stderr(),
            costmap.stderr()
        );
        std::thread::sleep(Duration::from_millis(250));
    }
}

#[test]
fn a_ros2_subscriber_gets_the_grid_its_updates_and_late_joiners_the_last_grid() {
    python(); // fails early, saying what to do, without the venv
    let domain = dds_domain();
    let site = costmap_site("costmap-ros2", domain, "");
    let (_ipc, mut source, costmap) = start_bridge(&site, "2026-03-02T11:00:00Z");

    // An early subscriber, reading grids and updates.
    let mut early = listener(domain, true, 0, 90);
    let quiet = expected_cells(false);
    let hot = expected_cells(true);
    assert!(
        hot.iter().filter(|&&c| c == HOT_COST).count() >= 2,
        "the hot block covers cells"
    );
    assert!(
        quiet.iter().filter(|&&c| c == -1).count() > 100,
        "part of the grid is unseen"
    );

    // 1. No activity: the camera's view is free (0), the rest unknown (-1).
    wait_until(
        "the quiet grid",
        &mut early,
        &costmap,
        || source.send(&[], 750),
        Duration::from_secs(60),
        |msgs| held_grid(msgs).is_some_and(|g| g == quiet),
    );
    let grid = messages(&mut early)
        .into_iter()
        .rfind(|m| m["kind"] == "grid")
        .unwrap();
    assert_eq!(grid["frame_id"], "test_map");
    assert_eq!(grid["width"], 60);
    assert_eq!(grid["height"], 60);
    assert!((grid["resolution"].as_f64().unwrap() - 0.1).abs() < 1e-6);
    let origin = json_list(&grid["origin"], Value::as_f64);
    assert_eq!(origin, vec![-1.0, 1.5, 0.0, 0.0, 0.0, 0.0, 1.0]);
    // The stamp is the activity's capture time, not the wall clock.
    let start_s = parse_rfc3339("2026-03-02T11:00:00Z").unwrap() / NS_PER_S;
    let stamp = grid["stamp"][0].as_i64().unwrap();
    assert!(stamp > start_s && stamp < start_s + 600, "stamp {stamp}");

    // 2. The hot block: an update carries the change, then a full grid follows.
    wait_until(
        "an update with the hot cells",
        &mut early,
        &costmap,
        || source.send(&[(HOT_BLOCK, HOT_S1)], 750),
        Duration::from_secs(30),
        |msgs| {
            msgs.iter()
                .any(|m| m["kind"] == "update" && data(m).contains(&HOT_COST))
                && held_grid(msgs).is_some_and(|g| g == hot)
        },
    );
    wait_for_hot_grid(
        "a full grid with the hot cells",
        &mut early,
        &costmap,
        &mut source,
        750,
        Duration::from_secs(30),
    );
    let update = messages(&mut early)
        .into_iter()
        .find(|m| m["kind"] == "update" && data(m).contains(&HOT_COST))
        .unwrap();
    let area = update["width"].as_i64().unwrap() * update["height"].as_i64().unwrap();
    assert!(
        area < 60 * 60 / 2,
        "an update is the changed rectangle, not the grid: {area} cells"
    );

    // 3. A late joiner, once the source has gone quiet (the camera stays live for
    //    stale_s, so nothing new is published): transient-local gives it the last grid.
    std::thread::sleep(Duration::from_secs(1));
    let mut late = listener(domain, false, 1, 30);
    wait_until(
        "the late joiner's grid",
        &mut late,
        &costmap,
        || {},
        Duration::from_secs(30),
        |msgs| msgs.iter().any(|m| m["kind"] == "grid"),
    );
    let grids: Vec<Value> = messages(&mut late)
        .into_iter()
        .filter(|m| m["kind"] == "grid")
        .collect();
    assert_eq!(
        data(&grids[0]),
        hot,
        "the late joiner's first grid is the last one published"
    );
    assert_eq!(grids[0]["frame_id"], "test_map");
}

/// The long-term store of cam01: blocks with x < 160 px (the west half of the
/// floor, x < 2 m) are busy except 12:00-13:00; the rest is a little busy.
pub(crate) fn write_store(site: &TestSite) {
    let state_dir = site.config().state_dir();
    let meta = StoreMeta::new("cam01", BlockGrid::new(320, 240, 16), Cycle::Daily, 0);
    let mut store = Store::open_or_create(&store_path(&state_dir, "cam01"), &meta).unwrap();
    for t in (10 * 60..15 * 60).step_by(1) {
        let mean: Vec<f32> = (0..BLOCKS)
            .map(|b| {
                if b % 20 < 10 {
                    if (720..780).contains(&t) { 0.0 } else { 0.04 }
                } else {
                    0.01
                }
            })
            .collect();
        store.teach(t, 14, mean).unwrap();
    }
}

/// The forecast for 11:55 from the store of [`write_store`], computed from the
/// true mapping: west blocks 80, the rest of the view 20, -1 unseen.
pub(crate) fn expected_forecast() -> Vec<i64> {
    let (x0, y0, res, w, h) = GRID;
    let mut cells = Vec::new();
    for j in 0..h {
        for i in 0..w {
            let c = [x0 + (i as f64 + 0.5) * res, y0 + (j as f64 + 0.5) * res];
            let [u, v] = floor_to_image(c);
            cells.push(
                if !(0.0..320.0).contains(&u) || !(0.0..240.0).contains(&v) {
                    -1
                } else if u < 160.0 {
                    80
                } else {
                    20
                },
            );
        }
    }
    cells
}

/// The west and east halves of the camera's view on the floor, as cost map segments.
pub(crate) const HALVES: &str = r#"[[costmap.segment]]
name = "west"
polygon_m = [[-1, 1.5], [1.6, 1.5], [1.6, 7.5], [-1, 7.5]]

[[costmap.segment]]
name = "east"
polygon_m = [[1.6, 1.5], [5, 1.5], [5, 7.5], [1.6, 7.5]]
"#;

#[test]
fn plans_and_snapshots_are_served_by_the_running_bridge() {
    let domain = dds_domain();
    // West and east halves of the camera's view on the floor, a corridor nobody uses.
    let extra = format!(
        r#"
{HALVES}
[[costmap.segment]]
name = "corridor"
polygon_m = [[10, 10], [11, 10], [11, 11], [10, 11]]

[[costmap.route]]
name = "via-west"
segments = ["west"]

[[costmap.route]]
name = "via-east"
segments = ["east"]
"#
    );
    let site = costmap_site("costmap-plan", domain, &extra);
    write_store(&site);
    let config = site.config_path().display().to_string();

    // Off-line, from the store, without any service.
    let out = site.isochron(
        &[
            "plan",
            "offline",
            "--config",
            &config,
            "--route",
            "via-west",
            "--between",
            "11:00",
            "14:00",
            "--step",
            "5m",
            "--json",
        ],
        Duration::from_secs(60),
    );
    assert!(out.status.success(), "{}", out.stderr);
    let plan: Value = serde_json::from_str(&out.stdout).unwrap();
    assert_eq!(plan["windows"][0]["start"], "12:00", "{plan}");
    assert_eq!(plan["windows"][0]["end"], "13:00", "{plan}");
    assert_eq!(plan["curve"].as_array().unwrap().len(), 36);
    assert_eq!(plan["infinite"], false);
    let text = site.isochron(
        &[
            "plan", "offline", "--config", &config, "--route", "via-west",
        ],
        Duration::from_secs(60),
    );
    assert!(
        text.status.success() && text.stdout.contains("12:00–13:00"),
        "{}",
        text.stdout
    );

    // Now: west is quiet at 12:30 in the long term, but busy live.
    let ipc = site.ipc("source");
    let mut source = Source::new(&ipc, "2026-03-02T12:30:00Z");
    let costmap = site.spawn("isochron-costmap", &[]);
    source.wait_for_subscriber(&costmap);
    let west_blocks: Vec<(usize, f32)> = (0..BLOCKS)
        .filter(|b| b % 20 < 8)
        .map(|b| (b, 0.05))
        .collect();
    for _ in 0..3 {
        source.send(&west_blocks, 750);
        std::thread::sleep(Duration::from_millis(100));
    }
    let now = site.isochron(
        &[
            "plan",
            "now",
            "--config",
            &config,
            "--routes",
            "via-west,via-east",
            "--json",
        ],
        Duration::from_secs(60),
    );
    assert!(now.status.success(), "{}\n{}", now.stderr, costmap.stderr());
    let ranked: Value = serde_json::from_str(&now.stdout).unwrap();
    assert_eq!(ranked["t_star"], 750);
    let routes = ranked["routes"].as_array().unwrap();
    assert_eq!(routes[0]["route"], "via-east", "{ranked}");
    assert_eq!(routes[1]["route"], "via-west");
    // via-west: long-term 0 at 12:30, live activity on most of its blocks.
    assert_eq!(routes[1]["cost1"], 0.0);
    assert!(routes[1]["short_term"].as_f64().unwrap() > 50.0, "{ranked}");
    // via-east: long-term 0.01 → Cost 20, nothing live.
    assert!(
        (routes[0]["cost1"].as_f64().unwrap() - 20.0).abs() < 0.01,
        "{ranked}"
    );
    assert_eq!(routes[0]["short_term"], 0.0);
    let (c1, c2) = (
        routes[0]["cost1"].as_f64().unwrap(),
        routes[0]["cost2"].as_f64().unwrap(),
    );
    assert!(
        (c2 - (c1 + routes[0]["short_term"].as_f64().unwrap())).abs() < 0.01,
        "w1 = w2 = 1"
    );
    // The same over ROS 2, from the independent client: the same ranking.
    let ros = ros_plan(
        domain,
        "/isochron/plan_now",
        &["now", "via-west", "via-east"],
    );
    assert_plan_status(&ros, 0, "");
    assert_eq!(ros["t_star"], ranked["t_star"]);
    let ros_routes = ros["routes"].as_array().unwrap();
    assert_eq!(ros_routes.len(), routes.len());
    for (c, r) in routes.iter().zip(ros_routes) {
        assert_eq!(c["route"], r["route"], "{ranked}\n{ros}");
        for key in ["cost2", "cost1", "short_term"] {
            assert!(same_cost(&c[key], &r[key]), "{key}: {ranked}\n{ros}");
        }
        for key in ["infinite", "estimated", "no_long_term"] {
            assert_eq!(c[key], r[key], "{key}");
        }
    }
    // Off-line over ROS 2 = the CLI's plan from the store.
    let ros = ros_plan(
        domain,
        "/isochron/plan_offline",
        &["offline", "via-west", "660", "840", "5"],
    );
    assert_plan_status(&ros, 0, "");
    assert_eq!(ros["infinite"], plan["infinite"]);
    let (cw, rw) = (
        plan["windows"].as_array().unwrap(),
        ros["windows"].as_array().unwrap(),
    );
    assert_eq!(cw.len(), rw.len(), "{plan}\n{ros}");
    for (c, r) in cw.iter().zip(rw) {
        assert_eq!(c["start_minute"], r["start_minute"]);
        assert_eq!(c["end_minute"], r["end_minute"]);
        assert!(same_cost(&c["cost"], &r["cost"]), "{c} {r}");
    }
    let (cc, rc) = (
        plan["curve"].as_array().unwrap(),
        ros["curve"].as_array().unwrap(),
    );
    assert_eq!(cc.len(), rc.len());
    for (c, r) in cc.iter().zip(rc) {
        assert_eq!(c["minute"], r["minute"]);
        assert!(same_cost(&c["cost"], &r["cost"]), "{c} {r}");
    }
    // Errors come back as a status with the reason, at once.
    assert_plan_errors(|service, args| ros_plan(domain, service, args));
    let unknown = ros_plan(
        domain,
        "/isochron/plan_offline",
        &["offline", "nowhere", "0", "1440", "5"],
    );
    assert_plan_status(&unknown, 2, "");
    let long = "x".repeat(40);
    let bad = ros_plan(domain, "/isochron/plan_now", &["now", &long]);
    assert_plan_status(&bad, 1, "");

    // An unknown route is refused by the CLI with the configured names.
    let bad = site.isochron(
        &["plan", "now", "--config", &config, "--routes", "nowhere"],
        Duration::from_secs(30),
    );
    assert!(
        !bad.status.success() && bad.stderr.contains("via-west"),
        "{}",
        bad.stderr
    );

    // A snapshot on request: map_server raw PGM of the grid as published.
    let snap_dir = site.path("snapshots");
    let snap = site.isochron(
        &[
            "costmap",
            "snapshot",
            "--config",
            &config,
            "--out",
            snap_dir.to_str().unwrap(),
        ],
        Duration::from_secs(60),
    );
    assert!(
        snap.status.success(),
        "{}\n{}",
        snap.stderr,
        costmap.stderr()
    );
    let files: Vec<PathBuf> = std::fs::read_dir(&snap_dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    let find = |ext: &str| {
        files
            .iter()
            .find(|p| p.extension().is_some_and(|e| e == ext))
            .unwrap()
            .clone()
    };
    let yaml = std::fs::read_to_string(find("yaml")).unwrap();
    assert!(
        yaml.contains("mode: raw") && yaml.contains("resolution: 0.1"),
        "{yaml}"
    );
    assert!(yaml.contains("origin: [-1, 1.5, 0]"), "{yaml}");
    let pgm = std::fs::read(find("pgm")).unwrap();
    let png = std::fs::read(find("png")).unwrap();
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    // The PGM's last 3600 bytes are the cells, top row = the grid's last row.
    let pixels = &pgm[pgm.len() - 3600..];
    let cell = |i: usize, j: usize| pixels[(59 - j) * 60 + i];
    let unseen = expected_cells(false);
    for j in 0..60 {
        for i in 0..60 {
            if unseen[j * 60 + i] == -1 {
                assert_eq!(cell(i, j), 255, "cell ({i}, {j}) is not seen");
            }
        }
    }
    // West blocks (x < 128 px) are live at s1 0.05 → cost 100, capped at the
    // default 98 (never an obstacle in Nav2) where seen.
    let cells = || (0..60).flat_map(|j| (0..60).map(move |i| (i, j)));
    let busy = cells().filter(|&(i, j)| cell(i, j) == 98).count();
    assert!(busy > 100, "{busy} cells at cost 98");
    assert!(
        cells().all(|(i, j)| cell(i, j) <= 98 || cell(i, j) == 255),
        "no cell above the default cap"
    );

    // The corridor covers no block: planning through it is refused with the reason.
    std::fs::write(
        site.path("with-corridor.toml"),
        toml_with_route(&site, "corridor"),
    )
    .unwrap();
    let out = site.isochron(
        &[
            "plan",
            "offline",
            "--config",
            site.path("with-corridor.toml").to_str().unwrap(),
            "--route",
            "via-corridor",
        ],
        Duration::from_secs(60),
    );
    assert!(!out.status.success());
    assert!(out.stderr.contains("covers no block"), "{}", out.stderr);
    drop(costmap);
    assert!(bin("isochron").is_file());
}

/// The site's config with a route through `segment`.
fn toml_with_route(site: &TestSite, segment: &str) -> String {
    let mut text = std::fs::read_to_string(site.config_path()).unwrap();
    text.push_str(&format!(
        "\n[[costmap.route]]\nname = \"via-{segment}\"\nsegments = [\"{segment}\"]\n"
    ));
    text
}

/// A bridge nobody listens to logs no error on its status reports (ros2-client's
/// subscription count logged one every 5 s until a first reader matched), reports
/// `ros_subscribers=0`, and counts a ROS 2 subscriber once it joins.
#[test]
fn the_bridge_logs_no_error_and_counts_its_subscribers() {
    python();
    let domain = dds_domain();
    let site = costmap_site("costmap-quiet", domain, "");
    let (_ipc, mut source, costmap) = start_bridge(&site, "2026-03-02T11:00:00Z");
    assert!(
        costmap.wait_for_stderr("publishing a 60x60 grid", Duration::from_secs(20)),
        "{}",
        costmap.stderr()
    );

    // Two status reports and more (one every 5 s), with a live camera: until the
    // log holds two, however slow the machine (within a minute).
    let end = Instant::now() + Duration::from_secs(60);
    while costmap.stderr().matches("ros_subscribers=0").count() < 2 && Instant::now() < end {
        source.send(&[], 750);
        std::thread::sleep(Duration::from_millis(250));
    }
    let stderr = costmap.stderr();
    let errors: Vec<&str> = stderr.lines().filter(|l| l.contains("ERROR")).collect();
    assert!(errors.is_empty(), "errors logged:\n{}", errors.join("\n"));
    assert!(stderr.contains("ros_subscribers=0"), "{stderr}");

    // A subscriber of the grid topic is counted at the next report.
    let grids = listener(domain, false, 0, 60);
    let end = Instant::now() + Duration::from_secs(30);
    while !costmap.stderr().contains("ros_subscribers=1") {
        assert!(
            Instant::now() < end,
            "the subscriber was never counted:\n{}\nlistener stderr:\n{}",
            costmap.stderr(),
            grids.stderr()
        );
        source.send(&[], 750);
        std::thread::sleep(Duration::from_millis(250));
    }
    drop(grids);
    let stderr = costmap.stderr();
    let errors: Vec<&str> = stderr.lines().filter(|l| l.contains("ERROR")).collect();
    assert!(errors.is_empty(), "errors logged:\n{}", errors.join("\n"));
}

/// What the bridge binds with `dds_interfaces = ["127.0.0.1"]`, as
/// docs/security.md's "DDS sockets and interfaces" says: RustDDS 0.15 binds every socket to 0.0.0.0 (the
/// setting limits what it announces and where it multicasts, not the bind
/// address), on the RTPS ports of the domain. If this fails because the sockets
/// are now bound to 127.0.0.1, RustDDS has learnt to bind the configured
/// interfaces: update docs/security.md and docs/ARCHITECTURE.md, and make this test
/// assert that no socket is on 0.0.0.0.
#[test]
fn the_bridge_binds_the_documented_dds_sockets() {
    let Ok(probe) = std::process::Command::new("ss").arg("-V").output() else {
        eprintln!("skipped: no `ss` (package iproute2)");
        return;
    };
    assert!(probe.status.success());
    let domain = dds_domain();
    let site = costmap_site("costmap-sockets", domain, "");
    let (_ipc, _source, costmap) = start_bridge(&site, "2026-03-02T11:00:00Z");
    assert!(
        costmap.wait_for_stderr("publishing a 60x60 grid", Duration::from_secs(20)),
        "{}",
        costmap.stderr()
    );
    let owner = format!("pid={},", costmap.pid());
    let out = std::process::Command::new("ss")
        .args(["-H", "-lunp"])
        .output()
        .unwrap();
    let sockets: Vec<(String, u16)> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter(|l| l.contains(&owner))
        .filter_map(|l| {
            let local = l.split_whitespace().nth(3)?;
            let (addr, port) = local.rsplit_once(':')?;
            Some((addr.to_string(), port.parse().ok()?))
        })
        .collect();
    let base = 7400 + 250 * domain;
    for port in [base, base + 1] {
        assert!(
            sockets.iter().any(|(_, p)| *p == port),
            "no socket on the domain's multicast port {port}: {sockets:?}"
        );
    }
    assert!(
        sockets.iter().all(|(addr, _)| addr == "0.0.0.0"),
        "RustDDS binds specific addresses now (see this test's doc): {sockets:?}"
    );
}

/// The extra topics of the bridge as the peer asks for them (the defaults).
fn extra_topics() -> Vec<String> {
    [
        "--updates",
        "--people",
        "/isochron/people",
        "--markers",
        "/isochron/markers",
        "--speed-info",
        "/isochron/speed_filter_info",
        "--speed-mask",
        "/isochron/speed_mask",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect()
}

/// Publishes one detected frame of cam01 with one person whose feet are at floor
/// point `feet`, captured at `capture_ns`.
pub(crate) fn send_person(
    publisher: &mut StreamPublisher<Detections>,
    feet: [f64; 2],
    capture_ns: i64,
) {
    let [u, v] = floor_to_image(feet);
    let (x, y) = ((u - 10.0) as f32, (v - 40.0) as f32);
    let mut d = Detection {
        x,
        y,
        w: 20.0,
        h: 40.0,
        score: 1.0,
        class: 0,
        model: DetectorModel::MoveNet as u32,
        ..Default::default()
    };
    // A standing pose: shoulders, elbows, wrists, hips, knees and ankles (no face).
    for (k, (dx, dy)) in [
        (5, (6.0, 8.0)),
        (6, (14.0, 8.0)),
        (7, (5.0, 15.0)),
        (8, (15.0, 15.0)),
        (9, (5.0, 21.0)),
        (10, (15.0, 21.0)),
        (11, (7.0, 21.0)),
        (12, (13.0, 21.0)),
        (13, (7.0, 30.0)),
        (14, (13.0, 30.0)),
        (15, (7.0, 39.0)),
        (16, (13.0, 39.0)),
    ] {
        d.keypoints[k] = Keypoint {
            x: x + dx,
            y: y + dy,
            score: 0.9,
        };
    }
    let mut preamble = Preamble::new::<Detection>(
        Stream::Detections,
        CameraId::new("cam01").unwrap(),
        publisher.next_sequence(),
        1,
    );
    preamble.capture_time_ns = capture_ns;
    preamble.origin_wall_ns = wall_now_ns();
    let header = DetectionHeader {
        preamble,
        ..Default::default()
    };
    publisher.send_copy(header, &[d]).unwrap();
}

/// The newest message of `kind`.
pub(crate) fn last<'a>(msgs: &'a [Value], kind: &str) -> Option<&'a Value> {
    msgs.iter().rev().find(|m| m["kind"] == kind)
}

/// Cost 60 (busy), 98 (crowded, capped from 100) and 20 (quiet) blocks: the
/// independent Cyclone DDS peer gets a grid with no cell above 98, the speed
/// filter's info and a mask with the bands' limits, the person as a pose stamped
/// with the detected frame's capture time, and the latched markers.
#[test]
fn a_ros2_peer_gets_people_markers_and_speed_zones() {
    python();
    let domain = dds_domain();
    let extra = format!(
        r#"confirm_hold_s = 3600

{HALVES}
[[costmap.route]]
name = "west-east"
segments = ["west", "east"]
"#
    );
    let site = costmap_site("costmap-peer", domain, &extra);
    let ipc = site.ipc("source");
    let mut source = Source::new(&ipc, "2026-03-02T11:00:00Z");
    let mut people = ipc.publisher::<Detections>("cam01", 8).unwrap();
    let costmap = site.spawn("isochron-costmap", &[]);
    source.wait_for_subscriber(&costmap);
    let mut peer = listener_with(domain, 90, &extra_topics());
    // HOT_BLOCK at cost 60, the block to its right at 100 → 98, two to the left at 20.
    let hot = [
        (HOT_BLOCK, HOT_S1),
        (HOT_BLOCK + 1, 0.05),
        (HOT_BLOCK - 2, 0.01),
    ];
    let feet = [3.0, 6.0]; // image (246, 31): far from the active blocks
    let capture_ns = parse_rfc3339("2026-03-02T11:00:00.5Z").unwrap();
    let mut feed = || {
        source.send(&hot, 660);
        send_person(&mut people, feet, capture_ns);
    };
    wait_until(
        "grid, mask, filter info, people and markers",
        &mut peer,
        &costmap,
        &mut feed,
        Duration::from_secs(60),
        |msgs| {
            let busy_mask = last(msgs, "speed_mask").is_some_and(|m| data(m).contains(&25));
            let busy_grid = last(msgs, "grid").is_some_and(|m| data(m).contains(&98));
            busy_mask
                && busy_grid
                && last(msgs, "filter_info").is_some()
                && last(msgs, "people").is_some()
                && last(msgs, "markers").is_some()
        },
    );
    // No new input: the next ticks send the grid and mask of the same state.
    std::thread::sleep(Duration::from_secs(2));
    let msgs = messages(&mut peer);

    let grid = held_grid(&msgs).unwrap();
    assert!(grid.iter().all(|&c| c <= 98), "a cell above 98");
    let info = last(&msgs, "filter_info").unwrap();
    assert_eq!(info["type"], 1, "{info}");
    assert_eq!(info["filter_mask_topic"], "/isochron/speed_mask");
    assert_eq!(info["base"], 0.0);
    assert_eq!(info["multiplier"], 1.0);
    assert_eq!(info["frame_id"], "test_map");
    // The mask: per cell of the grid, the band's limit in percent; 0 = no limit.
    let mask_msg = last(&msgs, "speed_mask").unwrap();
    assert_eq!(mask_msg["width"], 60);
    assert_eq!(mask_msg["frame_id"], "test_map");
    let mask = data(mask_msg);
    assert_eq!(mask.len(), grid.len());
    for (k, (&c, &m)) in grid.iter().zip(&mask).enumerate() {
        let expected = match c {
            70.. => 25,
            30..=69 => 50,
            _ => 0,
        };
        assert_eq!(m, expected, "cell {k}: cost {c}, mask {m}");
    }
    assert!(mask.contains(&50) && mask.contains(&25) && grid.contains(&20));

    // The person: feet on the floor, in the map frame, at the capture time.
    let person = last(&msgs, "people").unwrap();
    assert_eq!(person["frame_id"], "test_map");
    assert_eq!(
        person["stamp"],
        serde_json::json!([capture_ns / NS_PER_S, capture_ns % NS_PER_S])
    );
    let poses = person["poses"].as_array().unwrap();
    assert_eq!(poses.len(), 1, "{person}");
    let (x, y) = (poses[0][0].as_f64().unwrap(), poses[0][1].as_f64().unwrap());
    assert!(
        (x - feet[0]).abs() < 0.01 && (y - feet[1]).abs() < 0.01,
        "{person}"
    );

    // The markers: cleared first, then the camera's footprint, the segments and
    // the route through their centres, with labels.
    let markers = last(&msgs, "markers").unwrap()["markers"]
        .as_array()
        .unwrap()
        .clone();
    assert_eq!(markers[0]["action"], 3, "DELETEALL first");
    let of = |ns: &str| -> Vec<&Value> { markers.iter().filter(|m| m["ns"] == ns).collect() };
    assert_eq!(of("cameras").len(), 1);
    assert!(of("cameras")[0]["points"].as_array().unwrap().len() >= 4);
    assert_eq!(of("segments").len(), 2);
    assert_eq!(of("routes").len(), 1);
    assert_eq!(of("routes")[0]["points"].as_array().unwrap().len(), 2);
    // The camera sees floor x from about -0.25 (u = 0 at y = 1.5) to 4 m.
    let xs = json_list(&of("cameras")[0]["points"], |p| p[0].as_f64());
    let max_x = xs.iter().cloned().fold(f64::MIN, f64::max);
    assert!(max_x > 3.0 && max_x < 6.0, "{xs:?}");
    let texts: Vec<&str> = markers
        .iter()
        .filter_map(|m| m["text"].as_str())
        .filter(|t| !t.is_empty())
        .collect();
    assert!(
        texts.contains(&"cam01") && texts.contains(&"west"),
        "{texts:?}"
    );
    assert!(markers.iter().skip(1).all(|m| m["frame_id"] == "test_map"));

    // No long-term store yet: planning over ROS 2 says so, it does not hang.
    let no_store = ros_plan(
        domain,
        "/isochron/plan_offline",
        &["offline", "west-east", "0", "1440", "15"],
    );
    assert_plan_status(&no_store, 3, "no long-term store");

    // A late joiner gets the latched markers, info and mask at once.
    let mut late = listener_with(domain, 30, &extra_topics());
    wait_until(
        "latched markers, filter info and mask",
        &mut late,
        &costmap,
        || {},
        Duration::from_secs(30),
        |msgs| {
            last(msgs, "markers").is_some()
                && last(msgs, "filter_info").is_some()
                && last(msgs, "speed_mask").is_some()
        },
    );
}

/// The forecast: with the long-term store of [`write_store`] and live t* = 11:40,
/// the peer gets the cost the model expects at 11:55 (west blocks 0.04 → 80,
/// the rest 0.01 → 20; -1 unseen), stamped 15 minutes after the newest activity.
#[test]
fn a_ros2_peer_gets_the_forecast_of_the_long_term_model() {
    python();
    let domain = dds_domain();
    let site = costmap_site("costmap-forecast", domain, "forecast_every_s = 1");
    write_store(&site);
    let start = "2026-03-02T11:40:00Z";
    let (_ipc, mut source, costmap) = start_bridge(&site, start);
    let mut peer = listener_with(
        domain,
        60,
        &["--forecast".into(), "/isochron/activity_forecast".into()],
    );
    // Independently: each cell's block through the true mapping.
    let expected = expected_forecast();
    let start_ns = parse_rfc3339(start).unwrap();
    // Before the first activity arrives the bridge forecasts from the wall
    // clock (no camera is live); those forecasts are not the ones asked for here,
    // and between 10:00 and 15:00 UTC the store's minutes would even match them.
    let in_site_time = |m: &Value| {
        m["kind"] == "forecast"
            && m["stamp"][0].as_i64().is_some_and(|stamp| {
                (start_ns / NS_PER_S + 15 * 60..start_ns / NS_PER_S + 3600).contains(&stamp)
            })
    };
    wait_until(
        "the forecast at 11:55",
        &mut peer,
        &costmap,
        || source.send(&[], 700),
        Duration::from_secs(40),
        |msgs| msgs.iter().any(|m| in_site_time(m) && data(m) == expected),
    );
    let msgs = messages(&mut peer);
    let forecast = msgs.iter().rev().find(|m| in_site_time(m)).unwrap();
    assert_eq!(forecast["frame_id"], "test_map");
    assert_eq!(forecast["width"], 60);
    let stamp = forecast["stamp"][0].as_i64().unwrap();
    let newest = start_ns / NS_PER_S + source.seconds;
    assert!(
        stamp > start_ns / NS_PER_S + 15 * 60 && stamp <= newest + 15 * 60,
        "stamp {stamp}, newest activity {newest}"
    );
}

/// Discovery the way robots do it: the bridge (all interfaces, `dds_interfaces`
/// unset) in one network namespace, the Cyclone DDS peer with its default
/// multicast discovery in another, joined by a veth pair with a 224.0.0.0/4 route
/// on each side. Skipped only where the kernel refuses `ip netns add` (not root),
/// never in CI.
#[test]
fn a_peer_in_another_network_namespace_discovers_the_bridge_by_multicast() {
    let Some(pair) = netns_pair(0) else {
        return;
    };
    let [bridge_ns, peer_ns] = pair.names.clone();

    let domain = dds_domain();
    let toml = format!("{}{}", camera_toml(), costmap_toml(domain, ""))
        .replace("dds_interfaces = [\"127.0.0.1\"]\n", "");
    assert!(!toml.contains("dds_interfaces"));
    let site = TestSite::new("costmap-netns", &toml);
    let ipc = site.ipc("source");
    let mut source = Source::new(&ipc, "2026-03-02T11:00:00Z");
    let config = site.config_path().display().to_string();
    let costmap_bin = bin("isochron-costmap").display().to_string();
    let costmap = Proc::spawn(
        std::path::Path::new("ip"),
        &[
            "netns",
            "exec",
            &bridge_ns,
            &costmap_bin,
            "--config",
            &config,
        ],
    );
    source.wait_for_subscriber(&costmap);
    let script = repo_root().join("tests/ros2/costmap_listener.py");
    let python = python().display().to_string();
    let mut peer = Proc::spawn(
        std::path::Path::new("ip"),
        &[
            "netns",
            "exec",
            &peer_ns,
            &python,
            &script.display().to_string(),
            "--domain",
            &domain.to_string(),
            "--topic",
            "/isochron_test/activity_costmap",
            "--multicast",
            "--timeout",
            "60",
        ],
    );
    wait_for_hot_grid(
        "the grid across the veth pair",
        &mut peer,
        &costmap,
        &mut source,
        660,
        Duration::from_secs(45),
    );
    drop(peer);
    drop(costmap);
    drop(pair);
}
