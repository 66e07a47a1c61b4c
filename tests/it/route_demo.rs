//! The route server fed live by the whole group under `isochron up`, on video:
//!
//! * the demo site (config/demo.toml on vtest.avi, PETS 2009 S2.L1, with its graph
//!   config/demo-graph.geojson) feeding a route server of rclpy Jazzy and Kilted
//!   and of zenoh-ros2-sdk: the first request soon after the first grid, only the
//!   graph's ids, the fixed ramp and the edges out of view never named, and the
//!   edges PETS 2009's annotated people walked dearer than those none came near
//!   (the labels are the dataset's own ground positions, not isochron's);
//! * a person standing across an edge, in a clip made from vtest.avi
//!   (`presence.rs`: one of its people cut out along their PETS 2009 boxes and
//!   pasted back in on the empty scene, walking in, standing perfectly still for
//!   30 s, walking out): their edge closes under them and reopens after they left,
//!   an edge beside them never closes.

use std::collections::{BTreeMap, BTreeSet};
use std::time::{Duration, Instant};

use isochron_tests::{Proc, TestSite, eventually, repo_root};
use serde_json::Value;

use crate::costmap::dds_domain;
use crate::presence::{Actor, Clip, WALK_S};
use crate::route_server::{named, requests, spawn_route_server, state, zenoh_route_server};

/// The service road's edges out of the camera's view: never named.
const UNSEEN: [u64; 2] = [122, 123];
/// The ramp, `overridable: false` with a fixed cost: never named.
const FIXED: [u64; 2] = [126, 127];
/// vtest.avi's frame rate.
fn vtest_fps() -> f64 {
    use opencv::prelude::*;
    let video = opencv::videoio::VideoCapture::from_file(
        isochron_tests::vtest().to_str().unwrap(),
        opencv::videoio::CAP_ANY,
    )
    .unwrap();
    video.get(opencv::videoio::CAP_PROP_FPS).unwrap()
}

/// The demo's grid topic.
const TOPIC: &str = "/isochron/activity_costmap";

/// The demo site (its `[site]` the test's own) on DDS domain `domain` with the
/// demo graph, `tail` appended.
fn demo_route_site(name: &str, domain: u16, tail: &str) -> TestSite {
    let site = crate::view::demo_site(name, |body| {
        body.replace(
            "[costmap]\n",
            &format!("[costmap]\nros_domain_id = {domain}\nroute_graph = \"demo-graph.geojson\"\n"),
        ) + tail
    });
    std::fs::copy(
        repo_root().join("config/demo-graph.geojson"),
        site.path("demo-graph.geojson"),
    )
    .unwrap();
    site
}

/// The `t` of the server's first line of `kind`.
fn first_t(server: &mut Proc, kind: &str) -> Option<f64> {
    server
        .stdout()
        .lines()
        .filter_map(|l| serde_json::from_str::<Value>(l).ok())
        .find(|m| m["kind"] == kind)
        .and_then(|m| m["t"].as_f64())
}

/// Per edge id of the demo graph, the person-frames of PETS 2009's annotation
/// of vtest (`tests/data/pets09-s2l1-gt.txt`: frame, track, box, and each
/// person's position on the ground in metres, the frame the demo's map uses)
/// within the edge's corridor — half its width (`width_m`, else
/// `costmap.route_edge_width_m`'s default) of its line — in video frames
/// `0..frames`.
fn walked(frames: u64) -> BTreeMap<u64, u64> {
    let text = std::fs::read_to_string(repo_root().join("config/demo-graph.geojson")).unwrap();
    let graph: Value = serde_json::from_str(&text).unwrap();
    let default_half = isochron_config::CostmapConfig::default().route_edge_width_m / 2.0;
    let edges: Vec<(u64, [f64; 4], f64)> = graph["features"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|f| f["geometry"]["type"] == "MultiLineString")
        .map(|f| {
            let line = &f["geometry"]["coordinates"][0];
            let at = |i: usize, k: usize| line[i][k].as_f64().unwrap();
            let half = f["properties"]["metadata"]["width_m"]
                .as_f64()
                .map_or(default_half, |w| w / 2.0);
            let id = f["properties"]["id"].as_u64().unwrap();
            (id, [at(0, 0), at(0, 1), at(1, 0), at(1, 1)], half)
        })
        .collect();
    // Distance from p to the segment a–b.
    let distance = |[ax, ay, bx, by]: [f64; 4], (px, py): (f64, f64)| {
        let (dx, dy) = (bx - ax, by - ay);
        let t = (((px - ax) * dx + (py - ay) * dy) / (dx * dx + dy * dy)).clamp(0.0, 1.0);
        (px - ax - t * dx).hypot(py - ay - t * dy)
    };
    let truth = std::fs::read_to_string(repo_root().join("tests/data/pets09-s2l1-gt.txt")).unwrap();
    let mut out: BTreeMap<u64, u64> = edges.iter().map(|e| (e.0, 0)).collect();
    for line in truth.lines() {
        let v: Vec<f64> = line
            .split(',')
            .filter_map(|x| x.trim().parse().ok())
            .collect();
        // MOT frames are 1-based; columns 8 and 9 the ground position.
        if v.len() < 9 || v[0] < 1.0 || v[0] as u64 > frames {
            continue;
        }
        for (id, line, half) in &edges {
            if distance(*line, (v[7], v[8])) <= *half {
                *out.get_mut(id).unwrap() += 1;
            }
        }
    }
    out
}

/// `isochron up` on `site`, once capture says it is ready: the process and when.
fn up_until_capture_ready(site: &TestSite, label: &str) -> (Proc, Instant) {
    let mut up = site.up(&[]);
    let started = eventually(Duration::from_secs(60), || {
        up.stdout()
            .contains("up: capture/cam01 ready")
            .then(Instant::now)
    })
    .unwrap_or_else(|| panic!("{label}: capture never ready:\n{}", up.stdout()));
    (up, started)
}

/// `isochron up` on the demo site feeding `server` (started with its first-grid
/// note on), `label` naming it in what the test prints.
fn demo_fed_live(label: &str, site: &TestSite, mut server: Proc) {
    let (mut up, started) = up_until_capture_ready(site, label);
    // 1. The first request, after the first grid the server heard. The group
    //    starts the detector and replays from the first frame: a minute at most.
    let times = eventually(Duration::from_secs(120), || {
        let grid = first_t(&mut server, "first_grid")?;
        let request = first_t(&mut server, "adjust_edges")?;
        Some((grid, request))
    });
    let (grid, request) = times.unwrap_or_else(|| {
        panic!(
            "{label}: no grid or no request:\n{}\n{}\nup:\n{}\ncostmap log:\n{}",
            server.stdout(),
            server.stderr(),
            up.stdout(),
            std::fs::read_to_string(site.path("logs/costmap.log")).unwrap_or_default()
        )
    });
    // Bound (the issue's): an update period (1 s in the demo) and the bridge's
    // discovery of the server, which runs beside its first grid.
    eprintln!(
        "route server on the demo ({label}): first request {:.2} s after the first grid",
        request - grid
    );
    assert!(request - grid < 3.0, "{label}: {grid} s, {request} s");

    // 2. Half a minute of PETS 2009: the mean cost of each edge the server
    //    holds, sampled each second.
    let watch = Instant::now();
    let mut sums: BTreeMap<u64, f64> = BTreeMap::new();
    let mut seconds = 0;
    while watch.elapsed() < Duration::from_secs(30) {
        std::thread::sleep(Duration::from_secs(1));
        let Some((_, costs)) = state(&mut server) else {
            continue;
        };
        seconds += 1;
        for (edge, cost) in costs {
            *sums.entry(edge).or_insert(0.0) += cost;
        }
    }
    let mean: BTreeMap<u64, f64> = sums.iter().map(|(e, s)| (*e, s / seconds as f64)).collect();
    // The video has played since capture was ready (at its frame rate).
    let frames = (started.elapsed().as_secs_f64() * vtest_fps()) as u64;
    let walked = walked(frames);
    let heard = requests(&mut server);
    let ids: BTreeSet<u64> = heard.iter().flat_map(named).collect();
    let graph: BTreeSet<u64> = (100..=127).collect();
    assert!(state(&mut server).is_some(), "{label}: a request");
    eprintln!(
        "route server on the demo ({label}): {} requests naming {ids:?}",
        heard.len()
    );
    let expected: BTreeSet<u64> = graph
        .difference(&UNSEEN.into_iter().chain(FIXED).collect())
        .copied()
        .collect();
    assert_eq!(
        ids, expected,
        "{label}: every managed edge in view, no other"
    );
    // The edges annotated people walked most (the top quarter by person-frames)
    // against those none came near, among those the server holds a cost of.
    let mut by_walked: Vec<(u64, u64)> = walked
        .iter()
        .filter(|(e, _)| mean.contains_key(e))
        .map(|(e, n)| (*e, *n))
        .collect();
    by_walked.sort_by_key(|&(e, n)| (std::cmp::Reverse(n), e));
    let busy: Vec<u64> = by_walked[..by_walked.len() / 4]
        .iter()
        .map(|p| p.0)
        .collect();
    let quiet: Vec<u64> = by_walked.iter().filter(|p| p.1 == 0).map(|p| p.0).collect();
    let cost_of =
        |edges: &[u64]| edges.iter().map(|e| mean[e]).sum::<f64>() / edges.len().max(1) as f64;
    let (busy_cost, quiet_cost) = (cost_of(&busy), cost_of(&quiet));
    eprintln!(
        "route server on the demo ({label}): over {seconds} s and {frames} frames, edges walked most {busy:?} cost {busy_cost:.1} on average, edges nobody came near {quiet:?} {quiet_cost:.1}; per edge (mean cost, person-frames): {}",
        by_walked
            .iter()
            .map(|(e, n)| format!("{e}: {:.1} {n}", mean[e]))
            .collect::<Vec<_>>()
            .join(", ")
    );
    assert!(seconds >= 20, "{label}: {seconds} seconds of costs");
    assert!(
        !busy.is_empty() && !quiet.is_empty(),
        "{label}: {by_walked:?}"
    );
    // Bound: measured 1.9 to 2.0 times on this 2-core machine. A quiet edge is
    // not free: the cost map spreads each moving block's image area over the
    // floor behind the person from the camera's view (108 and 109, which no
    // annotated person came near, lie behind the crossing).
    assert!(
        busy_cost > 1.5 * quiet_cost,
        "{label}: walked {busy_cost:.1}, not {quiet_cost:.1}"
    );
    let status = up.terminate(Duration::from_secs(30));
    assert!(
        status.success(),
        "{label}: isochron up: {status:?}\n{}",
        up.stdout()
    );
    server.terminate(Duration::from_secs(20));
}

fn rclpy_demo(release: &str) {
    crate::costmap::python();
    let domain = dds_domain();
    let site = demo_route_site(&format!("route-demo-{release}"), domain, "");
    let server = spawn_route_server(release, domain, &["--grid-topic", TOPIC], None);
    demo_fed_live(release, &site, server);
}

#[test]
fn the_demo_under_isochron_up_feeds_an_rclpy_jazzy_route_server() {
    rclpy_demo("jazzy");
}

#[test]
fn the_demo_under_isochron_up_feeds_an_rclpy_kilted_route_server() {
    rclpy_demo("kilted");
}

/// The same through rmw_zenoh's format: `[costmap.zenoh]` and zenoh-ros2-sdk's
/// service server, through a Zenoh router.
#[test]
fn the_demo_under_isochron_up_feeds_a_zenoh_route_server() {
    let (port, _router) = crate::zenoh::router();
    let domain = dds_domain();
    let zenoh = crate::zenoh::costmap_section(port);
    let site = demo_route_site("route-demo-zenoh", domain, &zenoh);
    let server = zenoh_route_server(port, domain, &["--grid", "--topic", TOPIC]);
    demo_fed_live("zenoh", &site, server);
}

/// Seconds the edge under the person must be blocked before it closes.
const CLOSE_AFTER_S: f64 = 2.0;

/// A person standing across an edge of a graph on the presence clips' floor
/// (vtest's view, 1 cm a pixel): `isochron up` plays the clip in real time; the
/// edge under them closes within `route_close_after_s` + 2 s of their stopping
/// and reopens after they walked out; the edge 2 m beside them never closes.
/// The server of `start_server` on DDS domain `domain`, `site_tail` appended to
/// the site's config.
fn a_person_standing_closes_their_edge(
    label: &str,
    domain: u16,
    site_tail: &str,
    start_server: &dyn Fn() -> Proc,
) {
    // One person (PETS 2009 track 10) walks in over 6 s, stands 15–45 s, walks out.
    let (stand_from, stand_until, length) = (15.0, 45.0, 75.0);
    let clip = Clip::people(length, &[Actor::standing(0, stand_from, stand_until)]);
    let dir = tempfile::tempdir().unwrap();
    let video = dir.path().join("standing.avi");
    let truth = clip.write(&video);
    let (x, y, w, h) = truth
        .standing
        .iter()
        .find_map(|s| s[0])
        .expect("the actor stands");
    // Floor metres of a frame point (the clips' camera: y up from the bottom).
    let floor = |px: f64, py: f64| (px / 100.0, (576.0 - py) / 100.0);
    let (cx, cy) = floor(f64::from(x + w / 2), f64::from(y + h / 2));
    let beside = if cy > 2.88 { cy - 2.0 } else { cy + 2.0 };
    let (left, right) = ((cx - 1.5).max(0.3), (cx + 1.5).min(7.4));
    let node = |id: u64, x: f64, y: f64| {
        serde_json::json!({"type": "Feature", "properties": {"id": id},
                           "geometry": {"type": "Point", "coordinates": [x, y]}})
    };
    let edge = |id: u64, from: u64, to: u64| {
        serde_json::json!({"type": "Feature", "properties": {"id": id, "startid": from, "endid": to},
                           "geometry": {"type": "MultiLineString", "coordinates": []}})
    };
    // Edge 10 runs through the person's middle, 11 beside them.
    let graph = serde_json::json!({"type": "FeatureCollection", "features": [
        node(1, left, cy), node(2, right, cy), node(3, left, beside), node(4, right, beside),
        edge(10, 1, 2), edge(11, 3, 4),
    ]});
    let config = crate::presence::CAMERA.replace(
        "source = \"replaced-by-replay\"",
        &format!("source = \"{}\"\nloop = false", video.display()),
    );
    let site = TestSite::new(
        &format!("route-standing-{label}"),
        &format!(
            "{config}ros_domain_id = {domain}\ndds_interfaces = [\"127.0.0.1\"]\n\
             route_graph = \"graph.geojson\"\nroute_update_s = 0.5\n\
             route_close_after_s = {CLOSE_AFTER_S}\nroute_edge_width_m = 0.48\n{site_tail}"
        ),
    );
    std::fs::write(site.path("graph.geojson"), graph.to_string()).unwrap();
    let mut server = start_server();
    let server_t0 = Instant::now();
    let (mut up, started) = up_until_capture_ready(&site, label);
    // Clip seconds of the server's clock.
    let offset = started.duration_since(server_t0).as_secs_f64();
    let clip_s = |t: f64| t - offset;

    // Watch the server until the clip ends: when edge 10 closed and reopened.
    let deadline = isochron_config::clock::saturating_secs(length + 10.0);
    let (mut closed_at, mut reopened_at) = (None, None);
    while started.elapsed() < deadline && reopened_at.is_none() {
        std::thread::sleep(Duration::from_millis(250));
        for r in requests(&mut server) {
            let t = clip_s(r["t"].as_f64().unwrap());
            let has = |key: &str| r[key].as_array().unwrap().iter().any(|v| v == 10);
            assert!(
                !r["closed"].as_array().unwrap().iter().any(|v| v == 11),
                "{label}: the edge beside the person closed at {t:.1} s: {r}"
            );
            if has("closed") && closed_at.is_none() {
                closed_at = Some(t);
            }
            if has("opened") && closed_at.is_some() && reopened_at.is_none() && t > stand_until {
                reopened_at = Some(t);
            }
        }
    }
    let log = std::fs::read_to_string(site.path("logs/costmap.log")).unwrap_or_default();
    let closed_at = closed_at.unwrap_or_else(|| {
        panic!(
            "{label}: edge 10 never closed:\n{}\ncostmap log:\n{log}",
            server.stdout()
        )
    });
    eprintln!(
        "a person standing ({label}): they stood from {stand_from} s to {stand_until} s of the clip; their edge closed at {closed_at:.1} s, reopened at {}",
        reopened_at.map_or("never".into(), |t| format!("{t:.1} s"))
    );
    // Bounds: they reach the edge walking in (from stand_from − WALK_S); it closes
    // route_close_after_s after it is spanned, plus 2 s (the issue's) for the
    // update period, the grid's and the test's polling.
    assert!(
        closed_at > stand_from - WALK_S && closed_at < stand_from + CLOSE_AFTER_S + 2.0,
        "{label}: closed at {closed_at:.1} s"
    );
    // After they leave: out of the corridor within the walk out, the presence
    // band clears, and route_close_after_s of clear corridor; 10 s of margin.
    let reopened_at =
        reopened_at.unwrap_or_else(|| panic!("{label}: never reopened:\n{}", server.stdout()));
    assert!(
        reopened_at < stand_until + WALK_S + CLOSE_AFTER_S + 10.0,
        "{label}: reopened at {reopened_at:.1} s"
    );
    let (closed, _) = state(&mut server).unwrap();
    assert!(closed.is_empty(), "{label}: {closed:?}");
    up.terminate(Duration::from_secs(30));
    server.terminate(Duration::from_secs(20));
}

#[test]
fn a_person_standing_closes_the_edge_under_them_for_an_rclpy_route_server() {
    crate::costmap::python();
    let domain = dds_domain();
    a_person_standing_closes_their_edge("jazzy", domain, "", &|| {
        spawn_route_server("jazzy", domain, &[], None)
    });
}

#[test]
fn a_person_standing_closes_the_edge_under_them_for_a_zenoh_route_server() {
    let (port, _router) = crate::zenoh::router();
    let domain = dds_domain();
    let zenoh = crate::zenoh::costmap_section(port);
    a_person_standing_closes_their_edge("zenoh", domain, &zenoh, &|| {
        zenoh_route_server(port, domain, &[])
    });
}
