//! Planning over the route graph across departure times: `/isochron/plan_graph`
//! (`isochron_msgs/srv/PlanGraph`) and `isochron plan graph`, on a synthetic week
//! where the straight way from node 1 to node 3 is busy on Mondays 08:30–09:30.
//!
//! The bridge is asked as a user and a robot would ask it: `isochron plan graph`
//! over iceoryx2, rclpy Jazzy and Kilted (`tests/ros2/rclpy_peer.py`), rmw_zenoh
//! (`tests/zenoh/rmw_zenoh_peer.py`), and under a flood from one Cyclone DDS
//! participant (`tests/ros2/plan_attacker.py`) while a robot polls
//! (`tests/ros2/plan_client.py`). Good requests plan around the busy hour (another
//! path, or another time, cheaper than the shortest path leaving now); malformed
//! ones (an unknown node, no path, a window out of range) get a status.

use std::process::{Command, Stdio};
use std::time::Duration;

use isochron_config::clock::Cycle;
use isochron_store::{Store, StoreMeta, store_path};
use isochron_tests::{Proc, TestSite, repo_root};
use isochron_wire::geometry::BlockGrid;
use serde_json::{Value, json};

use crate::costmap::{
    Source, camera_toml, costmap_toml, dds_domain, python, start_bridge as start_costmap,
};

/// Monday 08:45: inside the busy hour.
pub(crate) const NOW: &str = "2026-03-02T08:45:00Z";
/// Its minute of the week.
pub(crate) const NOW_T_STAR: u32 = 525;
/// The busy hour on Mondays, minutes of the day.
const BUSY: std::ops::Range<u32> = 510..570;
/// The straight way from node 1 to node 3, and the way round.
pub(crate) const STRAIGHT: [u64; 2] = [11, 12];
pub(crate) const ROUND: [u64; 3] = [13, 14, 15];

/// The route graph, nav2_route GeoJSON in the test map's frame: from node 1 to
/// node 3 straight north along x = 0.5 (edges 11, 12: 3 m) through the busy
/// zone, or round it to the east (edges 13, 14, 15: 8 m). No edge leads back.
fn graph_geojson() -> String {
    json!({"type": "FeatureCollection", "features": graph_features()}).to_string()
}

/// The features of [`graph_geojson`]: its nodes, then its edges.
pub(crate) fn graph_features() -> Vec<Value> {
    let nodes = [
        (1, 0.5, 2.8),
        (2, 0.5, 4.3),
        (3, 0.5, 5.8),
        (4, 3.0, 2.8),
        (5, 3.0, 5.8),
    ];
    let edges = [(11, 1, 2), (12, 2, 3), (13, 1, 4), (14, 4, 5), (15, 5, 3)];
    let mut features: Vec<Value> = nodes
        .iter()
        .map(|&(id, x, y)| {
            json!({"type": "Feature", "properties": {"id": id, "frame": "test_map"},
                   "geometry": {"type": "Point", "coordinates": [x, y]}})
        })
        .collect();
    features.extend(edges.iter().map(|&(id, a, b)| {
        json!({"type": "Feature", "properties": {"id": id, "startid": a, "endid": b},
               "geometry": {"type": "MultiLineString", "coordinates": []}})
    }));
    features
}

/// Whether block `b` (20 × 15 blocks of 16 px) looks at the busy zone, floor x
/// 0..1 m, y 3.8..4.8 m: its centre mapped back with the inverse of
/// [`crate::costmap::floor_to_image`].
pub(crate) fn busy_block(b: usize) -> bool {
    let (u, v) = ((b % 20) as f64 * 16.0 + 8.0, (b / 20) as f64 * 16.0 + 8.0);
    let y = (400.0 - v) / (60.0 + 0.05 * v);
    let x = (u * (0.05 * y + 1.0) - 10.0 * y - 20.0) / 80.0;
    (0.0..1.0).contains(&x) && (3.8..4.8).contains(&y)
}

/// A weekly store that learned Mondays 07:00–12:00: the busy zone at 0.2
/// (Cost 98) from 08:30 to 09:30, everything else quiet.
pub(crate) fn write_week(site: &TestSite) {
    let state_dir = site.config().state_dir();
    let meta = StoreMeta::new("cam01", BlockGrid::new(320, 240, 16), Cycle::Weekly, 0);
    let mut store = Store::open_or_create(&store_path(&state_dir, "cam01"), &meta).unwrap();
    assert!((0..300).filter(|&b| busy_block(b)).count() >= 4);
    for t in 420..720 {
        let mean: Vec<f32> = (0..300)
            .map(|b| {
                if busy_block(b) && BUSY.contains(&t) {
                    0.2
                } else {
                    0.0
                }
            })
            .collect();
        store.teach(t, 4, mean).unwrap();
    }
}

/// A weekly site with the test camera, the route graph and the synthetic week;
/// `extra` goes into `[costmap]`, `tail` after it.
fn graph_site(name: &str, domain: u16, extra: &str, tail: &str) -> TestSite {
    let costmap = costmap_toml(domain, &format!("route_graph = \"graph.geojson\"\n{extra}"));
    let site = TestSite::new(
        name,
        &format!(
            "{}{costmap}\n[cascade]\ncycle = \"weekly\"\n{tail}",
            camera_toml()
        ),
    );
    std::fs::write(site.path("graph.geojson"), graph_geojson()).unwrap();
    write_week(&site);
    site
}

/// Starts the bridge of `site` and makes its "now" Monday 08:45 (the newest
/// activity's time).
fn start_bridge(site: &TestSite) -> (isochron_runtime::ipc::Ipc, Source, Proc) {
    let (ipc, mut source, bridge) = start_costmap(site, NOW);
    for _ in 0..3 {
        source.send(&[], NOW_T_STAR);
        std::thread::sleep(Duration::from_millis(100));
    }
    (ipc, source, bridge)
}

/// The ids of a JSON list.
fn ids(v: &Value) -> Vec<u64> {
    v.as_array()
        .unwrap_or_else(|| panic!("not a list: {v}"))
        .iter()
        .map(|x| x.as_u64().unwrap())
        .collect()
}

/// Checks a good answer for Monday 08:00–11:00 (`best` and `baseline` paths
/// with `nodes`, `edges`, `cost`, `departure_minute`): the baseline goes
/// straight into the crowd; the best goes another way or at another time, and
/// costs less.
fn check_morning(best: &Value, baseline: &Value, what: &str) {
    assert_eq!(ids(&baseline["edges"]), STRAIGHT, "{what}: {baseline}");
    assert_eq!(ids(&baseline["nodes"]), [1, 2, 3], "{what}: {baseline}");
    let baseline_cost = baseline["cost"].as_f64().unwrap();
    assert!(baseline_cost > 50.0, "{what}: into the crowd: {baseline}");
    let best_cost = best["cost"].as_f64().unwrap();
    assert!(best_cost < baseline_cost, "{what}: {best} vs {baseline}");
    let departure = best["departure_minute"].as_u64().unwrap() as u32;
    assert!(
        ids(&best["edges"]) != STRAIGHT || !BUSY.contains(&departure),
        "{what}: another way or another time: {best}"
    );
    assert_eq!(ids(&best["nodes"]).first(), Some(&1), "{what}: {best}");
    assert_eq!(ids(&best["nodes"]).last(), Some(&3), "{what}: {best}");
}

/// Checks a good answer for Monday 08:30–09:15, busy throughout: the way round.
fn check_busy(best: &Value, baseline: &Value, what: &str) {
    assert_eq!(ids(&best["edges"]), ROUND, "{what}: {best}");
    assert_eq!(ids(&best["nodes"]), [1, 4, 5, 3], "{what}: {best}");
    let cost = best["cost"].as_f64().unwrap();
    assert!((cost - 8.0).abs() < 0.1, "{what}: 8 m, quiet: {best}");
    assert!(cost < baseline["cost"].as_f64().unwrap(), "{what}");
}

#[test]
fn the_cli_plans_around_a_busy_corridor_over_iceoryx2() {
    let site = graph_site("graph-cli", dds_domain(), "", "");
    let (_ipc, _source, bridge) = start_bridge(&site);
    let config = site.config_path().display().to_string();
    let plan = |args: &[&str]| {
        let mut all = vec!["plan", "graph", "--config", &config];
        all.extend(args);
        site.isochron(&all, Duration::from_secs(60))
    };

    let out = plan(&[
        "--from",
        "1",
        "--to",
        "3",
        "--between",
        "08:00",
        "11:00",
        "--step",
        "15m",
        "--day",
        "mon",
        "--json",
    ]);
    assert!(out.status.success(), "{}\n{}", out.stderr, bridge.stderr());
    let answer: Value = serde_json::from_str(&out.stdout).unwrap();
    check_morning(&answer["best"], &answer["baseline"], "CLI");
    assert_eq!(answer["curve"].as_array().unwrap().len(), 12, "{answer}");
    let windows = answer["windows"].as_array().unwrap();
    assert!(!windows.is_empty(), "{answer}");
    for w in windows {
        let start = w["start_minute"].as_u64().unwrap() as u32;
        let end = w["end_minute"].as_u64().unwrap() as u32;
        assert!(end <= BUSY.start || start >= BUSY.end, "quiet: {w}");
        assert_eq!(ids(&w["path"]["edges"]), STRAIGHT, "{w}");
    }
    // Busy all through the window: the way round.
    let out = plan(&[
        "--from",
        "1",
        "--to",
        "3",
        "--between",
        "08:30",
        "09:15",
        "--step",
        "15",
        "--day",
        "mon",
        "--json",
    ]);
    assert!(out.status.success(), "{}", out.stderr);
    let answer: Value = serde_json::from_str(&out.stdout).unwrap();
    check_busy(&answer["best"], &answer["baseline"], "CLI");
    // Text, for people.
    let out = plan(&["--from", "1", "--to", "3", "--day", "mon"]);
    assert!(
        out.status.success() && out.stdout.contains("baseline") && out.stdout.contains("1 → 2"),
        "{}\n{}",
        out.stdout,
        out.stderr
    );
    // Malformed: each fails with one line saying why.
    for (args, why) in [
        (vec!["--from", "99", "--to", "3"], "UnknownNode"),
        (vec!["--from", "3", "--to", "1"], "NoPath"),
        (
            vec!["--from", "1", "--to", "3", "--between", "25:00", "26:00"],
            "--between",
        ),
        (vec!["--from", "1", "--to", "70000"], "70000"),
    ] {
        let out = plan(&args);
        assert!(!out.status.success(), "{args:?}: {}", out.stdout);
        assert!(out.stderr.contains(why), "{args:?}: {}", out.stderr);
    }
}

/// The calls every ROS 2 client makes, and what each must answer: two good
/// ones, an unknown node, no path, a window out of range, a day out of range.
fn ros_calls(service: &str) -> Vec<Value> {
    let call = |from: u16, to: u16, start: u16, end: u16, step: u16, weekday: u8| {
        json!({"service": service, "from_node": from, "to_node": to, "start_minute": start,
               "end_minute": end, "step_min": step, "weekday": weekday})
    };
    vec![
        call(1, 3, 480, 660, 15, 0),
        call(1, 3, 510, 555, 15, 0),
        call(99, 3, 480, 660, 15, 0),
        call(3, 1, 480, 660, 15, 0),
        call(1, 3, 2000, 660, 15, 0),
        call(1, 3, 480, 660, 15, 9),
    ]
}

/// The statuses [`ros_calls`] must get: OK, OK, unknown node, no path, bad
/// request twice.
const STATUSES: [u64; 6] = [0, 0, 5, 6, 1, 1];

/// rclpy of `release` calls `plan_graph`.
fn rclpy_plans(release: &str) {
    let python = crate::rclpy::rclpy_python(release);
    let domain = dds_domain();
    let site = graph_site(&format!("graph-rclpy-{release}"), domain, "", "");
    let (_ipc, _source, bridge) = start_bridge(&site);
    let peer = crate::rclpy::Peer {
        python,
        domain,
        netns: None,
    };
    let calls: Vec<Value> = ros_calls("/isochron/plan_graph");
    let lines = peer.plan(&Value::Array(calls));
    let replies: Vec<&Value> = lines.iter().filter(|l| l["kind"] == "reply").collect();
    assert_eq!(replies.len(), 6, "{lines:?}\n{}", bridge.stderr());
    for (r, status) in replies.iter().zip(STATUSES) {
        assert_eq!(r["status"], status, "{r}");
        if status != 0 {
            assert!(!r["message"].as_str().unwrap().is_empty(), "{r}");
            assert!(r["windows"].as_array().unwrap().is_empty(), "{r}");
        }
    }
    check_morning(&replies[0]["best"], &replies[0]["baseline"], release);
    check_busy(&replies[1]["best"], &replies[1]["baseline"], release);
    let paths = replies[0]["window_paths"].as_array().unwrap();
    assert_eq!(
        paths.len(),
        replies[0]["windows"].as_array().unwrap().len(),
        "{}",
        replies[0]
    );
    assert_eq!(replies[0]["curve"].as_array().unwrap().len(), 12);
    assert!(replies[2]["message"].as_str().unwrap().contains("99"));
}

#[test]
fn rclpy_jazzy_plans_over_the_graph() {
    rclpy_plans("jazzy");
}

#[test]
fn rclpy_kilted_plans_over_the_graph() {
    rclpy_plans("kilted");
}

#[test]
fn an_rmw_zenoh_robot_plans_over_the_graph() {
    let (port, router) = crate::zenoh::router();
    let domain = dds_domain();
    let zenoh = crate::zenoh::costmap_section(port);
    let site = graph_site("graph-zenoh", domain, "", &zenoh);
    let (_ipc, _source, bridge) = start_bridge(&site);
    assert!(
        bridge.wait_for_stderr("ROS 2 on Zenoh", Duration::from_secs(20)),
        "no Zenoh start-up line: {}",
        bridge.stderr()
    );
    let calls: Vec<Value> = ros_calls("/isochron/plan_graph")
        .into_iter()
        .map(|mut c| {
            let service = c["service"].take();
            c.as_object_mut().unwrap().remove("service");
            json!({"service": service, "request": c})
        })
        .collect();
    let calls = Value::Array(calls).to_string();
    let share = crate::zenoh::message_dir().display().to_string();
    let (port_s, domain_s) = (port.to_string(), domain.to_string());
    let done = crate::zenoh::peer(&[
        "plan",
        &calls,
        "--router",
        &port_s,
        "--domain",
        &domain_s,
        "--messages",
        &share,
    ])
    .finish(Duration::from_secs(90));
    let replies = crate::zenoh::lines(&done.stdout);
    assert_eq!(replies.len(), 6, "{replies:?}\n{}", done.stderr);
    for (r, status) in replies.iter().zip(STATUSES) {
        assert_eq!(r["kind"], "reply", "{r}\n{}", done.stderr);
        assert_eq!(r["status"], status, "{r}");
    }
    check_morning(&replies[0]["best"], &replies[0]["baseline"], "zenoh");
    check_busy(&replies[1]["best"], &replies[1]["baseline"], "zenoh");
    drop(router);
}

/// One Cyclone DDS participant floods `plan_graph` with 500 requests a second
/// while a robot asks every half second: at least 90 % of the robot's plans come
/// back within 1 s, and the flood is dropped and counted.
#[test]
fn a_plan_graph_flood_from_one_participant_does_not_starve_a_robot() {
    python();
    let dds = dds_domain();
    let domain = dds.to_string();
    let site = graph_site("graph-fair", dds, "", "");
    let (_ipc, _source, bridge) = start_bridge(&site);
    let service = ["--domain", &domain, "--service", "/isochron/plan_graph"];
    let flood = Command::new(python())
        .arg(repo_root().join("tests/ros2/plan_attacker.py"))
        .args(service)
        .args(["--wait", "2", "flood", "10000", "20", "1,3,480,660,15,0"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_secs(4));
    let robot = Command::new(python())
        .arg(repo_root().join("tests/ros2/plan_client.py"))
        .args(service)
        .args([
            "--poll",
            "28",
            "--timeout",
            "3",
            "graph",
            "1",
            "3",
            "480",
            "660",
            "15",
            "0",
        ])
        .output()
        .unwrap();
    let robot = crate::nav2::peer_json("plan_client.py --poll", &robot);
    let flood = crate::nav2::peer_json("plan_attacker.py", &flood.wait_with_output().unwrap());
    let row = site.status_row("costmap");
    eprintln!("robot: {robot}\nflood: {flood}\nbridge: {row}");

    let rate = flood["sent"].as_f64().unwrap() / flood["seconds"].as_f64().unwrap();
    assert!(rate > 450.0, "the flood was {rate:.0}/s: {flood}");
    assert!(
        flood["replies"].as_i64().unwrap() > 0,
        "the flood is answered too: {flood}"
    );
    assert_eq!(flood["statuses"]["0"], flood["replies"], "{flood}");
    let mut latency: Vec<f64> = robot["latency_ms"]
        .as_array()
        .unwrap()
        .iter()
        .map(|l| l.as_f64().unwrap_or(f64::INFINITY))
        .collect();
    assert_eq!(latency.len(), 28, "{robot}");
    latency.sort_by(f64::total_cmp);
    let within = latency.iter().filter(|&&l| l <= 1000.0).count();
    eprintln!(
        "robot under a {rate:.0}/s plan_graph flood: {within}/28 within 1 s, p50 {} ms, max {} ms",
        latency[14], latency[27]
    );
    assert!(within * 10 >= 28 * 9, "{within}/28 within 1 s: {robot}");
    let answered = latency.iter().filter(|l| l.is_finite()).count();
    assert_eq!(robot["statuses"]["0"], answered, "{robot}");
    assert!(
        row["dropped"].as_i64().unwrap() > 0,
        "the flood is dropped: {row}"
    );
    drop(bridge);
}
