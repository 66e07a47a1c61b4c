//! The route server fed live: the bridge calls `nav2_msgs/srv/DynamicEdges` at
//! `route_server/DynamicEdgesScorer/adjust_edges`, as nav2_route's
//! `DynamicEdgesScorer` serves it, on the synthetic week of `plan_graph.rs` (the
//! straight way from node 1 to node 3 busy on Mondays 08:30–09:30).
//!
//! The server is a real rclpy node (Jazzy and Kilted, rmw_fastrtps_cpp:
//! `tests/ros2/rclpy_peer.py route-server`) that keeps what it is told as the
//! scorer does, on loopback and (Jazzy) on another host: two network namespaces,
//! SUBNET discovery. It hears first within seconds, only ids of the graph and never
//! the edge that is not `overridable`; the busy way costs more than the way
//! round; edges close while people stand across them and reopen after; a
//! restarted server is told everything; one that refuses or never answers
//! costs the grid nothing.

use std::collections::{BTreeMap, BTreeSet};
use std::time::{Duration, Instant};

use isochron_tests::{NetnsPair, Proc, TestSite, bin, repo_root};
use serde_json::{Value, json};

use crate::costmap::{Source, camera_toml, costmap_toml, dds_domain, start_bridge};
use crate::plan_graph::{NOW, NOW_T_STAR, ROUND, STRAIGHT, busy_block, graph_features, write_week};
use crate::rclpy::rclpy_python;

/// The graph's edges the bridge may name (edge 16 is not `overridable`).
const MANAGED: [u64; 5] = [11, 12, 13, 14, 15];
/// `plan_graph.rs`'s graph and an edge from node 2 to node 4 that the route
/// server may not override (a fixed cost of 5).
fn graph_geojson() -> String {
    let mut features = graph_features();
    features.push(json!({"type": "Feature",
                         "properties": {"id": 16, "startid": 2, "endid": 4,
                                        "overridable": false, "cost": 5.0},
                         "geometry": {"type": "MultiLineString", "coordinates": []}}));
    json!({"type": "FeatureCollection", "features": features}).to_string()
}

/// The weekly test site with the graph: edges scored every half second, closed
/// after a second of being blocked; `tail` after `[cascade]`; for two network
/// namespaces the bridge on every interface (`dds_interfaces` unset).
fn route_site(name: &str, domain: u16, tail: &str, netns: bool) -> TestSite {
    let extra = "route_graph = \"graph.geojson\"\nroute_update_s = 0.5\nroute_close_after_s = 1\n";
    let mut toml = format!(
        "{}{}\n[cascade]\ncycle = \"weekly\"\n{tail}",
        camera_toml(),
        costmap_toml(domain, extra)
    );
    if netns {
        toml = toml.replace("dds_interfaces = [\"127.0.0.1\"]\n", "");
    }
    let site = TestSite::new(name, &toml);
    std::fs::write(site.path("graph.geojson"), graph_geojson()).unwrap();
    write_week(&site);
    site
}

/// A route server of rclpy `release` on `domain` answering as `answer` says
/// (`ok`, `refuse`, `never`), once it is ready; in the second namespace of
/// `netns` (SUBNET discovery), if any.
fn route_server(release: &str, domain: u16, answer: &str, netns: Option<&NetnsPair>) -> Proc {
    spawn_route_server(release, domain, &["--answer", answer], netns)
}

/// A route server of rclpy `release` on `domain` with `options` (those of
/// `rclpy_peer.py route-server`), once it is ready; in the second namespace of
/// `netns` (SUBNET discovery), if any.
pub(crate) fn spawn_route_server(
    release: &str,
    domain: u16,
    options: &[&str],
    netns: Option<&NetnsPair>,
) -> Proc {
    let script = repo_root().join("tests/ros2/rclpy_peer.py");
    let domain = domain.to_string();
    let mut args = vec![script.to_str().unwrap(), "--domain", &domain];
    if netns.is_some() {
        args.push("--subnet");
    }
    args.extend(["route-server", "--timeout", "180"]);
    args.extend(options);
    let python = rclpy_python(release);
    let mut server = match netns {
        Some(pair) => pair.spawn(1, &python, &args),
        None => Proc::spawn(&python, &args),
    };
    assert!(
        server
            .wait_for_line("\"ready\"", Duration::from_secs(60))
            .is_some(),
        "the rclpy route server did not start: {}",
        server.stderr()
    );
    server
}

/// The requests the server took so far.
pub(crate) fn requests(server: &mut Proc) -> Vec<Value> {
    server
        .stdout()
        .lines()
        .filter_map(|l| serde_json::from_str::<Value>(l).ok())
        .filter(|m| m["kind"] == "adjust_edges")
        .collect()
}

/// Every edge id a request names.
pub(crate) fn named(request: &Value) -> BTreeSet<u64> {
    let ids = |key: &str| -> Vec<u64> {
        request[key]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_u64().unwrap())
            .collect()
    };
    let adjusted = request["adjust"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p[0].as_u64().unwrap());
    ids("closed")
        .into_iter()
        .chain(ids("opened"))
        .chain(adjusted)
        .collect()
}

/// The server's state after its last request: closed edges, cost per edge.
pub(crate) fn state(server: &mut Proc) -> Option<(BTreeSet<u64>, BTreeMap<u64, f64>)> {
    let last = requests(server).pop()?;
    let closed = last["state"]["closed"]
        .as_array()?
        .iter()
        .filter_map(Value::as_u64)
        .collect();
    let costs = last["state"]["costs"]
        .as_object()?
        .iter()
        .filter_map(|(k, v)| Some((k.parse().ok()?, v.as_f64()?)))
        .collect();
    Some((closed, costs))
}

/// Every block of the camera at 0.2 (Cost 98, the presence cost): people
/// everywhere it sees, across every corridor in view.
fn everyone() -> Vec<(usize, f32)> {
    (0..300).map(|b| (b, 0.2)).collect()
}

/// The busy zone alone at 0.2: the straight way busy, but not spanned from
/// side to side (its corridor is wider than the zone).
fn busy_zone() -> Vec<(usize, f32)> {
    (0..300)
        .filter(|&b| busy_block(b))
        .map(|b| (b, 0.2))
        .collect()
}

/// Sends `hot` every 250 ms until `done` says so or `within` passes; how long it
/// took.
fn feed_until(
    source: &mut Source,
    hot: &[(usize, f32)],
    within: Duration,
    mut done: impl FnMut() -> bool,
) -> Option<Duration> {
    let t0 = Instant::now();
    while t0.elapsed() < within {
        source.send(hot, NOW_T_STAR);
        if done() {
            return Some(t0.elapsed());
        }
        std::thread::sleep(Duration::from_millis(250));
    }
    None
}

/// The bridge's counters in `isochron status`.
fn counters(site: &TestSite) -> Value {
    site.status_row("costmap")["counters"].clone()
}

fn counter(c: &Value, name: &str) -> f64 {
    c[name].as_f64().unwrap_or_else(|| panic!("no {name}: {c}"))
}

/// The route server of zenoh-ros2-sdk through the Zenoh router on `port`, with
/// `options` (those of `rmw_zenoh_peer.py route-server`).
pub(crate) fn zenoh_route_server(port: u16, domain: u16, options: &[&str]) -> Proc {
    let (port, domain) = (port.to_string(), domain.to_string());
    let share = crate::zenoh::message_dir().display().to_string();
    let mut args = vec![
        "route-server",
        "--router",
        &port,
        "--domain",
        &domain,
        "--messages",
        &share,
        "--timeout",
        "180",
    ];
    args.extend(options);
    let mut server = crate::zenoh::peer(&args);
    assert!(
        server
            .wait_for_line("\"ready\"", Duration::from_secs(60))
            .is_some(),
        "the zenoh-ros2-sdk route server did not start: {}",
        server.stderr()
    );
    server
}

/// The route server of `start_server` (started again for step 4) fed by the
/// bridge of `site` (in the first namespace of `netns`, if any), `label` naming
/// it in what the test prints.
fn fed_live(
    label: &str,
    site: &TestSite,
    netns: Option<&NetnsPair>,
    start_server: &dyn Fn() -> Proc,
) {
    let release = label;
    let mut server = start_server();

    // 1. The first request: soon, only the graph's ids, never edge 16.
    let started = Instant::now();
    let (_ipc, mut source, bridge) = match netns {
        None => start_bridge(site, NOW),
        Some(pair) => {
            let ipc = site.ipc("source");
            let source = Source::new(&ipc, NOW);
            let config = site.config_path().display().to_string();
            let bridge = pair.spawn(0, &bin("isochron-costmap"), &["--config", &config]);
            source.wait_for_subscriber(&bridge);
            (ipc, source, bridge)
        }
    };
    let first = feed_until(&mut source, &busy_zone(), Duration::from_secs(30), || {
        !requests(&mut server).is_empty()
    });
    let first = first.unwrap_or_else(|| {
        panic!(
            "no request reached the route server:\n{}\n{}\nbridge:\n{}",
            server.stdout(),
            server.stderr(),
            bridge.stderr()
        )
    });
    // Bound: the bridge's start (its participant discovering the server's, a
    // second or two on loopback) and one update period; printed to see a near miss.
    eprintln!(
        "route server ({release}): first request {:.1} s after the bridge started ({:.1} s to the bridge's first activity)",
        started.elapsed().as_secs_f64(),
        first.as_secs_f64()
    );
    assert!(first < Duration::from_secs(10), "{first:?}");
    let heard = requests(&mut server);
    let managed: BTreeSet<u64> = MANAGED.into();
    for request in &heard {
        let ids = named(request);
        assert!(
            ids.is_subset(&managed),
            "not the graph's managed edges: {request}"
        );
    }
    assert!(
        named(&heard[0]).contains(&11) && named(&heard[0]).contains(&13),
        "the first request tells everything: {}",
        heard[0]
    );

    // 2. The busy way costs more than the way round (the busy hour in the
    //    store, the busy zone live).
    let (closed, costs) = state(&mut server).unwrap();
    assert!(closed.is_empty(), "nothing closed yet: {closed:?}");
    let straight = STRAIGHT
        .iter()
        .filter_map(|e| costs.get(e))
        .fold(0.0f64, |a, &b| a.max(b));
    let round = ROUND
        .iter()
        .filter_map(|e| costs.get(e))
        .fold(0.0f64, |a, &b| a.max(b));
    eprintln!("route server ({release}): costs {costs:?}");
    assert!(straight > round + 10.0, "{costs:?}");

    // 3. People across every corridor: edges close after route_close_after_s
    //    (1 s), and reopen as long after they leave.
    let close_s = 1.0;
    let closing = feed_until(&mut source, &everyone(), Duration::from_secs(20), || {
        state(&mut server).is_some_and(|(c, _)| !c.is_empty())
    })
    .unwrap_or_else(|| panic!("no edge closed: {}\n{}", server.stdout(), bridge.stderr()));
    let (closed, _) = state(&mut server).unwrap();
    eprintln!(
        "route server ({release}): {closed:?} closed {:.1} s after people stood across them",
        closing.as_secs_f64()
    );
    assert!(closed.is_subset(&managed), "{closed:?}");
    // Bound: route_close_after_s, an update period (0.5 s), the grid's own
    // period (0.25 s) and the test's feed (0.25 s), with a second for a loaded machine.
    assert!(closing.as_secs_f64() < close_s + 3.0, "{closing:?}");
    let reopening = feed_until(&mut source, &busy_zone(), Duration::from_secs(20), || {
        state(&mut server).is_some_and(|(c, _)| c.is_empty())
    })
    .unwrap_or_else(|| panic!("never reopened: {}", server.stdout()));
    eprintln!(
        "route server ({release}): reopened {:.1} s after they left",
        reopening.as_secs_f64()
    );

    // 4. The server restarts: the new one is told everything at once.
    server.terminate(Duration::from_secs(20));
    let mut server = start_server();
    let back = Instant::now();
    let told = feed_until(&mut source, &busy_zone(), Duration::from_secs(30), || {
        !requests(&mut server).is_empty()
    })
    .unwrap_or_else(|| panic!("the restarted server heard nothing\n{}", bridge.stderr()));
    let first = &requests(&mut server)[0];
    eprintln!(
        "route server ({release}): the restarted server told everything {:.1} s after it was ready",
        back.elapsed().as_secs_f64()
    );
    assert!(told < Duration::from_secs(10), "{told:?}");
    let opened: BTreeSet<u64> = first["opened"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(Value::as_u64)
        .collect();
    let closed: BTreeSet<u64> = first["closed"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(Value::as_u64)
        .collect();
    assert!(
        opened.union(&closed).count() >= 4 && named(first).is_subset(&managed),
        "everything, to a new server: {first}"
    );

    // 5. What the bridge counts (its status comes every 5 s: awaited).
    let t0 = Instant::now();
    let mut c = counters(site);
    while counter(&c, "route_calls") < 3.0 && t0.elapsed() < Duration::from_secs(15) {
        std::thread::sleep(Duration::from_millis(500));
        c = counters(site);
    }
    eprintln!("route server ({release}): bridge counters {c}");
    assert!(counter(&c, "route_calls") >= 3.0, "{c}");
    assert_eq!(counter(&c, "route_failures"), 0.0, "{c}");
    assert!(counter(&c, "route_edges") >= 5.0, "{c}");
    assert_eq!(counter(&c, "route_server_up"), 1.0, "{c}");
    let log = bridge.stderr();
    assert!(!log.contains("ERROR"), "{log}");
}

fn rclpy_fed_live(release: &str, netns: Option<&NetnsPair>) {
    crate::costmap::python();
    let domain = dds_domain();
    let mode = if netns.is_some() { "netns" } else { "lo" };
    let site = route_site(
        &format!("route-{release}-{mode}"),
        domain,
        "",
        netns.is_some(),
    );
    fed_live(release, &site, netns, &|| {
        route_server(release, domain, "ok", netns)
    });
}

#[test]
fn an_rclpy_jazzy_route_server_is_fed_live() {
    rclpy_fed_live("jazzy", None);
}

#[test]
fn an_rclpy_kilted_route_server_is_fed_live() {
    rclpy_fed_live("kilted", None);
}

/// The same with the route server on another host: two network namespaces
/// joined by a veth pair, default SUBNET discovery (multicast on the veth).
#[test]
fn an_rclpy_jazzy_route_server_on_another_host_is_fed_live() {
    if let Some(pair) = crate::costmap::netns_pair(12) {
        rclpy_fed_live("jazzy", Some(&pair));
    }
}

/// The same through rmw_zenoh's format: the bridge's `[costmap.zenoh]` and
/// zenoh-ros2-sdk's `ROS2ServiceServer`, through a Zenoh router.
#[test]
fn a_zenoh_route_server_is_fed_live() {
    let (port, _router) = crate::zenoh::router();
    let domain = dds_domain();
    let zenoh = crate::zenoh::costmap_section(port);
    let site = route_site("route-zenoh", domain, &zenoh, false);
    fed_live("zenoh", &site, None, &|| {
        zenoh_route_server(port, domain, &[])
    });
}
