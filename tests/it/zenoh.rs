//! isochron-costmap's Zenoh output (`[costmap.zenoh]`) against a robot on
//! rmw_zenoh from PyPI (`tests/zenoh/rmw_zenoh_peer.py` in `target/zenoh-peer`):
//! a Zenoh router (eclipse-zenoh in router mode, on a port of this test's own, as
//! `rmw_zenohd` is on 7447), zenoh-ros2-sdk — a third-party implementation of
//! rmw_zenoh's format, which computes each type's hash from the `.msg` files of
//! the rclpy Jazzy venv — subscribing to every topic and calling both planning
//! services, eclipse-zenoh checking each sample's key expression, attachment and
//! encapsulation and the graph's liveliness tokens, and a late joiner that is
//! what rmw_zenoh's transient-local subscription is (an advanced subscriber
//! detecting the publisher and querying its cache).

use std::path::PathBuf;
use std::time::Duration;

use isochron_config::clock::{NS_PER_S, parse_rfc3339};
use isochron_runtime::ipc::Detections;
use isochron_tests::{Proc, free_port, json_list, repo_root, setup_file};
use serde_json::{Value, json};

use crate::costmap::{
    data, dds_domain, held_grid, last, messages, send_person, wait_until, write_store,
};
use crate::rclpy::{T_STAR, TOPIC, site, start_bridge};

/// The grid type's hash as the bridge names it (`isochron_ros2::spec::types`).
const GRID_HASH: &str = "RIHS01_8d348150c12913a31ee0ec170fbf25089e4745d17035792a1ba94d6f0bc0cfc7";

/// The Python of `target/zenoh-peer`.
fn zenoh_python() -> PathBuf {
    setup_file(
        "ISOCHRON_ZENOH_PEER",
        "target/zenoh-peer/bin/python3",
        "(it makes target/zenoh-peer: zenoh-ros2-sdk and eclipse-zenoh from PyPI)",
    )
}

/// The `.msg`/`.srv` files the SDK reads: the rclpy Jazzy venv's `share/`.
pub(crate) fn message_dir() -> PathBuf {
    let srv = setup_file(
        "ISOCHRON_RCLPY_JAZZY_PLAN_NOW",
        "target/rclpy-jazzy/share/isochron_msgs/srv/PlanNow.srv",
        "(it makes target/rclpy-jazzy with the message packages)",
    );
    srv.ancestors()
        .nth(3)
        .expect("<share>/isochron_msgs/srv/PlanNow.srv")
        .to_path_buf()
}

/// The type description hash rosidl generated for `ty` (`nav_msgs/msg/OccupancyGrid`)
/// in the rclpy venv of `release`: `share/<ty>.json`.
fn rosidl_hash(release: &str, ty: &str) -> String {
    let path = repo_root().join(format!("target/rclpy-{release}/share/{ty}.json"));
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let description: Value = serde_json::from_str(&text).unwrap();
    description["type_hashes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|h| h["type_name"] == ty)
        .and_then(|h| h["hash_string"].as_str())
        .unwrap_or_else(|| panic!("no hash of {ty} in {}", path.display()))
        .to_string()
}

/// The peer script with `args`.
pub(crate) fn peer(args: &[&str]) -> Proc {
    let script = repo_root().join("tests/zenoh/rmw_zenoh_peer.py");
    let mut all = vec![script.display().to_string()];
    all.extend(args.iter().map(|a| a.to_string()));
    Proc::spawn(&zenoh_python(), &all)
}

/// A Zenoh router (eclipse-zenoh's, in router mode) on a free loopback port, once
/// it listens: its port and process.
pub(crate) fn router() -> (u16, Proc) {
    let port = free_port();
    let mut router = peer(&["router", "--listen", &format!("tcp/127.0.0.1:{port}")]);
    assert!(
        router
            .wait_for_line("\"router\"", Duration::from_secs(20))
            .is_some(),
        "the Zenoh router did not start: {}",
        router.stderr()
    );
    (port, router)
}

/// The site's `[costmap.zenoh]`: on, through the router on `port`.
pub(crate) fn costmap_section(port: u16) -> String {
    format!("\n[costmap.zenoh]\nenabled = true\nconnect = [\"tcp/127.0.0.1:{port}\"]\n")
}

/// The JSON lines of a finished peer.
pub(crate) fn lines(stdout: &str) -> Vec<Value> {
    stdout
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect()
}

#[test]
fn an_rmw_zenoh_robot_gets_every_topic_a_late_grid_and_plans() {
    let share = message_dir();
    let (port, router) = router();
    let domain = dds_domain();
    let site = site("zenoh", domain, false);
    // The body after the `[site]` table TestSite writes.
    let toml = std::fs::read_to_string(site.config_path()).unwrap();
    let body = &toml[toml.find("\n\n").unwrap() + 2..];
    site.write_config(&format!("{body}{}", costmap_section(port)));
    write_store(&site);
    let (ipc, mut source, bridge) = start_bridge(&site, None);
    assert!(
        bridge.wait_for_stderr("ROS 2 on Zenoh", Duration::from_secs(20)),
        "no Zenoh start-up line: {}",
        bridge.stderr()
    );
    let mut people = ipc.publisher::<Detections>("cam01", 8).unwrap();
    let (port_s, domain_s, share_s) = (
        port.to_string(),
        domain.to_string(),
        share.display().to_string(),
    );
    let common = [
        "--router",
        &port_s,
        "--domain",
        &domain_s,
        "--messages",
        &share_s,
    ];
    let mut args = vec!["listen", "--topic", TOPIC, "--timeout", "30"];
    args.extend(common);
    let mut node = peer(&args);
    assert!(
        node.wait_for_line("\"ready\"", Duration::from_secs(30))
            .is_some(),
        "the SDK's node did not start: {}",
        node.stderr()
    );
    // Its subscriptions reach the bridge through the router: the full grid the
    // first activity brings (the next is an hour away) must find them there.
    // Nothing the test can see tells when the router has passed them on, so this
    // is a stated bound: on loopback it takes milliseconds; 3 s leaves room for
    // a machine loaded by a parallel build.
    std::thread::sleep(Duration::from_secs(3));

    let hot = [(crate::costmap::HOT_BLOCK, crate::costmap::HOT_S1)];
    let feet = [3.0, 6.0];
    let capture_ns = parse_rfc3339("2026-03-02T11:40:00.5Z").unwrap();
    wait_until(
        "every topic through zenoh-ros2-sdk",
        &mut node,
        &bridge,
        || {
            source.send(&hot, T_STAR);
            send_person(&mut people, feet, capture_ns);
        },
        Duration::from_secs(40),
        |msgs| {
            held_grid(msgs).is_some_and(|g| g.contains(&60) && g.contains(&98))
                && ["people", "markers", "speed_mask", "forecast"]
                    .iter()
                    .all(|k| last(msgs, k).is_some())
        },
    );
    let msgs = messages(&mut node);
    let grid = last(&msgs, "grid").unwrap();
    assert_eq!(grid["frame_id"], "test_map");
    assert_eq!(
        (grid["width"].as_i64(), grid["height"].as_i64()),
        (Some(60), Some(60))
    );
    assert!(
        held_grid(&msgs)
            .unwrap()
            .iter()
            .all(|&c| (-1..=98).contains(&c))
    );
    let person = last(&msgs, "people").unwrap();
    assert_eq!(
        person["stamp"],
        json!([capture_ns / NS_PER_S, capture_ns % NS_PER_S])
    );
    let poses = json_list(&person["poses"], |p| Some((p[0].as_f64()?, p[1].as_f64()?)));
    assert!(
        (poses[0].0 - feet[0]).abs() < 0.01 && (poses[0].1 - feet[1]).abs() < 0.01,
        "{person}"
    );
    assert_eq!(data(last(&msgs, "speed_mask").unwrap()).len(), 3600);

    // The bytes, as eclipse-zenoh sees them: each topic on its data key (domain,
    // name, DDS type, type hash), plain little-endian CDR, rmw_zenoh's attachment
    // with a 16-byte GID and sequence numbers counting up per publisher.
    let raw: Vec<&Value> = msgs.iter().filter(|m| m["kind"] == "raw").collect();
    let grid_key = format!(
        "{domain}/{}/nav_msgs::msg::dds_::OccupancyGrid_/{GRID_HASH}",
        TOPIC.trim_start_matches('/')
    );
    // (Samples published every second or on every feed: the grid and markers are
    // published at start and on a change, maybe before this subscriber was
    // routed; the late joiner below checks the grid's key.)
    let forecast_key = format!(
        "{domain}/isochron/activity_forecast/nav_msgs::msg::dds_::OccupancyGrid_/{GRID_HASH}"
    );
    for (key, what) in [
        (forecast_key.clone(), "forecast"),
        (
            format!(
                "{domain}/isochron/people/geometry_msgs::msg::dds_::PoseArray_/RIHS01_af0cc36d190e104d546d168d6b39df04fa4b4ccecf59cb4c9ed328d3d5004aa0"
            ),
            "people",
        ),
    ] {
        let sample = raw
            .iter()
            .find(|m| m["key"] == key.as_str())
            .unwrap_or_else(|| panic!("no {what} on {key}: {raw:?}"));
        assert_eq!(sample["encapsulation"], "00010000", "{sample}");
        assert_eq!(sample["attachment_len"], 33, "{sample}");
        assert_eq!(sample["gid_len"], 16, "{sample}");
        assert!(sample["seq"].as_i64().unwrap() >= 1, "{sample}");
        let age_s = (now_ns() - sample["timestamp_ns"].as_i64().unwrap()) as f64 / 1e9;
        assert!(
            (0.0..120.0).contains(&age_s),
            "source timestamp {age_s} s old: {sample}"
        );
    }
    let forecast_seqs: Vec<i64> = raw
        .iter()
        .filter(|m| m["key"] == forecast_key.as_str())
        .filter_map(|m| m["seq"].as_i64())
        .collect();
    assert!(
        !forecast_seqs.is_empty() && forecast_seqs.windows(2).all(|w| w[1] > w[0]),
        "{forecast_seqs:?}"
    );

    // A late joiner as rmw_zenoh's transient-local subscription: the grid comes
    // from the publisher's cache at once (the next full grid is an hour away).
    let mut args = vec![
        "late",
        "--topic",
        TOPIC,
        "--hash",
        GRID_HASH,
        "--timeout",
        "10",
    ];
    args.extend(common);
    let late = peer(&args).finish(Duration::from_secs(30));
    let late = lines(&late.stdout);

    let got = late
        .iter()
        .find(|m| m["kind"] == "late_grid")
        .unwrap_or_else(|| panic!("the late joiner got no grid: {late:?}"));
    assert_eq!(got["key"], grid_key.as_str(), "{got}");
    assert_eq!(got["encapsulation"], "00010000", "{got}");
    assert!(got["after_s"].as_f64().unwrap() < 3.0, "{got}");
    assert!(got["bytes"].as_u64().unwrap() > 3600, "{got}");
    // Every type's hash on the wire is the one rosidl generates, in Jazzy and in
    // Kilted (the services' are checked by the SDK's queries reaching them).
    let mut on_wire: Vec<String> = raw
        .iter()
        .filter_map(|m| m["key"].as_str().map(String::from))
        .collect();
    on_wire.extend(
        late.iter()
            .filter_map(|m| m["key"].as_str().map(String::from)),
    );
    for key in &on_wire {
        let parts: Vec<&str> = key.rsplitn(3, '/').collect();
        let (hash, dds) = (parts[0], parts[1]);
        let ty = dds.replace("::dds_::", "/").replace("::", "/");
        let ty = ty.trim_end_matches('_');
        for release in ["jazzy", "kilted"] {
            assert_eq!(hash, rosidl_hash(release, ty), "{key} ({release})");
        }
    }
    assert!(
        on_wire.iter().any(|k| k.contains("CostmapFilterInfo_")),
        "{on_wire:?}"
    );
    // The speed filter's info, published once when the bridge started.
    let info = late
        .iter()
        .find(|m| m["kind"] == "late_filter_info")
        .unwrap_or_else(|| panic!("the late joiner got no speed filter info: {late:?}"));
    assert_eq!(info["encapsulation"], "00010000", "{info}");
    assert!(
        info["text"]
            .as_str()
            .unwrap()
            .contains("/isochron/speed_mask"),
        "{info}"
    );

    // Both planning services, through the SDK's service client (a Zenoh query
    // with rmw_zenoh's attachment): good requests, a malformed one, an unknown
    // route.
    let calls = json!([
        {"service": "/isochron/plan_now", "request": {"routes": ["via-west", "via-east"]}},
        {"service": "/isochron/plan_offline", "request": {"route": "via-west",
         "start_minute": 660, "end_minute": 840, "step_min": 5, "weekday": 7}},
        {"service": "/isochron/plan_now", "request": {"routes": ["x".repeat(40)]}},
        {"service": "/isochron/plan_now", "request": {"routes": ["nowhere"]}},
    ])
    .to_string();
    let mut args = vec!["plan", &calls];
    args.extend(common);
    let done = peer(&args).finish(Duration::from_secs(60));
    let replies = lines(&done.stdout);
    assert_eq!(replies.len(), 4, "{replies:?}\n{}", done.stderr);
    assert!(
        replies.iter().all(|r| r["kind"] == "reply"),
        "{replies:?}\n{}",
        done.stderr
    );
    assert_eq!(
        (replies[0]["status"].as_u64(), replies[0]["t_star"].as_u64()),
        (Some(0), Some(u64::from(T_STAR))),
        "{}",
        replies[0]
    );
    let routes: Vec<&str> = replies[0]["routes"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|r| r[0].as_str())
        .collect();
    assert_eq!(routes.len(), 2, "{}", replies[0]);
    assert_eq!(replies[1]["status"], 0, "{}", replies[1]);
    assert_eq!(
        replies[1]["windows"][0][0], 720,
        "quiet 12:00-13:00: {}",
        replies[1]
    );
    assert_eq!(replies[2]["status"], 1, "{}", replies[2]);
    assert_eq!(replies[3]["status"], 2, "{}", replies[3]);
    for r in &replies {
        assert!(r["s"].as_f64().unwrap() < 2.0, "{r}");
    }

    // The graph: the node, eight publishers and three services, each with the
    // type hash and QoS rmw_zenoh's tokens carry.
    let done = node.finish(Duration::from_secs(60));
    let tokens: Vec<String> = lines(&done.stdout)
        .iter()
        .find(|m| m["kind"] == "tokens")
        .map(|m| json_list(&m["tokens"], |t| t.as_str().map(String::from)))
        .unwrap_or_else(|| panic!("no tokens: {}", done.stdout));
    let ours: Vec<&String> = tokens
        .iter()
        .filter(|t| t.contains("/%isochron/costmap_bridge"))
        .collect();
    let kind = |k: &str| {
        ours.iter()
            .filter(|t| t.contains(&format!("/{k}/")))
            .count()
    };
    assert_eq!((kind("NN"), kind("MP"), kind("SS")), (1, 8, 3), "{ours:?}");
    // Each service's type hash in its token is the one rosidl generates from
    // ros/isochron_msgs, in Jazzy and in Kilted.
    let mut services = Vec::new();
    for token in ours.iter().filter(|t| t.contains("/SS/")) {
        let parts: Vec<&str> = token.split('/').collect();
        let at = parts
            .iter()
            .position(|p| p.contains("::srv::dds_::"))
            .unwrap_or_else(|| panic!("no service type in {token}"));
        let ty = parts[at].replace("::dds_::", "/").replace("::", "/");
        let ty = ty.trim_end_matches('_').to_string();
        for release in ["jazzy", "kilted"] {
            assert_eq!(
                parts[at + 1],
                rosidl_hash(release, &ty),
                "{token} ({release})"
            );
        }
        services.push(ty);
    }
    services.sort();
    assert_eq!(
        services,
        [
            "isochron_msgs/srv/PlanGraph",
            "isochron_msgs/srv/PlanNow",
            "isochron_msgs/srv/PlanOffline"
        ],
        "{ours:?}"
    );
    assert!(
        ours.iter().any(|t| t.ends_with(&format!(
            "/%isochron_test%activity_costmap/nav_msgs::msg::dds_::OccupancyGrid_/{GRID_HASH}/:1:,1:,:,:,,"
        ))),
        "the grid's token: {ours:?}"
    );
    assert!(
        bridge.wait_for_stderr("plans_rejected=1", Duration::from_secs(15)),
        "the malformed request counted: {}",
        bridge.stderr()
    );
    drop(router);
}

fn now_ns() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos() as i64
}

/// A Zenoh configuration file that is missing stops the bridge with the
/// configuration's exit code (78, not restarted) and a line naming the file.
#[test]
fn a_missing_zenoh_configuration_file_is_a_configuration_error() {
    let site = site("zenoh-config", dds_domain(), false);
    let toml = std::fs::read_to_string(site.config_path()).unwrap();
    let body = &toml[toml.find("\n\n").unwrap() + 2..];
    site.write_config(&format!(
        "{body}\n[costmap.zenoh]\nenabled = true\nconfig_file = \"no-such-zenoh.json5\"\n"
    ));
    let done = site
        .spawn("isochron-costmap", &[])
        .finish(Duration::from_secs(30));
    assert_eq!(done.status.code(), Some(78), "{}", done.stderr);
    assert!(
        done.stderr.contains("no-such-zenoh.json5"),
        "{}",
        done.stderr
    );
}
