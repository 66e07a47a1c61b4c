//! isochron-costmap against what Nav2 robots run, with peers it did not write:
//!
//! * the grid received over DDS by the independent Cyclone DDS subscriber
//!   (`tests/ros2/costmap_listener.py`), read by a re-implementation of each Nav2
//!   release's StaticLayer (`tests/ros2/nav2_static_layer.py`, from the C++
//!   source of Humble, Jazzy, Kilted, Lyrical and Rolling) with the parameters of
//!   the shipped snippet `config/nav2-activity-layer.yaml`;
//! * the planning services called by an Eclipse Fast DDS client built from
//!   `tests/ros2/fastdds/` (rmw_fastrtps's request/reply layout; `cargo xtask
//!   setup` builds it) and by the Cyclone DDS client `tests/ros2/plan_client.py`
//!   (rmw_cyclonedds's layout), and attacked by `tests/ros2/plan_attacker.py`;
//! * the bridge's start-up warning when its grid is not the robots' map.

use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use isochron_config::clock::parse_rfc3339;
use isochron_runtime::ipc::Detections;
use isochron_tests::{TestSite, repo_root, setup_file};
use serde_json::{Value, json};

use crate::costmap::{
    HALVES, HOT_BLOCK, assert_plan_errors, assert_plan_status, costmap_site, dds_domain, held_grid,
    listener_with, messages, plan_reply, python, ros_plan, same_cost, send_person, start_bridge,
    wait_until, write_store,
};

/// Nav2 releases the StaticLayer model covers.
const RELEASES: [&str; 5] = ["humble", "jazzy", "kilted", "lyrical", "rolling"];
/// The two costmaps of the snippet.
const COSTMAPS: [&str; 2] = ["global_costmap", "local_costmap"];

/// The grid a Cyclone DDS subscriber holds once cells at `busy` (the cap) and
/// unseen cells (-1) are in it: busy activity on three blocks and a confirmed
/// person, with `extra` in `[costmap]`.
fn received_grid(name: &str, extra: &str, busy: i64) -> Value {
    python();
    let domain = dds_domain();
    let site = costmap_site(name, domain, &format!("confirm_hold_s = 3600\n{extra}"));
    let (ipc, mut source, costmap) = start_bridge(&site, "2026-03-02T11:00:00Z");
    let mut people = ipc.publisher::<Detections>("cam01", 8).unwrap();
    let mut peer = listener_with(domain, 60, &["--updates".to_string()]);
    let capture_ns = parse_rfc3339("2026-03-02T11:00:00.5Z").unwrap();
    // s1 0.5 at cost_scale 0.05: 1000, far above any cap.
    let hot = [
        (HOT_BLOCK, 0.5),
        (HOT_BLOCK + 1, 0.5),
        (HOT_BLOCK - 20, 0.03),
    ];
    wait_until(
        &format!("a grid with cells at {busy} and unseen cells"),
        &mut peer,
        &costmap,
        || {
            source.send(&hot, 660);
            send_person(&mut people, [3.0, 6.0], capture_ns);
        },
        Duration::from_secs(60),
        |msgs| {
            held_grid(msgs).is_some_and(|g| {
                g.contains(&busy)
                    && g.contains(&-1)
                    && g.iter().filter(|&&c| c == busy).count() > 20
            })
        },
    );
    let msgs = messages(&mut peer);
    let grid = held_grid(&msgs).unwrap();
    let full = msgs.iter().rev().find(|m| m["kind"] == "grid").unwrap();
    assert!(
        grid.iter().all(|&c| (-1..=busy).contains(&c)),
        "a cell outside -1..={busy}"
    );
    json!({"width": full["width"], "height": full["height"], "data": grid})
}

/// What each release's StaticLayer makes of `grid` with the shipped snippet (and
/// `set` overrides), per release and costmap.
fn static_layer(grid: &Value, set: &[&str]) -> Value {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("grid.json");
    std::fs::write(&path, grid.to_string()).unwrap();
    let mut cmd = std::process::Command::new(python());
    cmd.arg(repo_root().join("tests/ros2/nav2_static_layer.py"))
        .arg("--grid")
        .arg(&path)
        .arg("--params")
        .arg(repo_root().join("config/nav2-activity-layer.yaml"));
    for s in set {
        cmd.args(["--set", s]);
    }
    let out = cmd.output().unwrap();
    assert!(
        out.status.success(),
        "nav2_static_layer.py: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

fn count(model: &Value, release: &str, costmap: &str, key: &str) -> i64 {
    model[release][costmap][key]
        .as_i64()
        .unwrap_or_else(|| panic!("{release} {costmap} {key}: {model}"))
}

/// The default cap (98) and the confirmed person's cost (the cap): no cell of the
/// received grid becomes INSCRIBED or LETHAL in any release's StaticLayer, in the
/// global or the local costmap of the snippet, and the robot's own obstacles
/// stay. The local costmap's old `track_unknown_space: true` wipes them on every
/// release: the model sees it.
#[test]
fn no_default_grid_value_is_an_obstacle_in_any_nav2_release() {
    let grid = received_grid("nav2-default", "", 98);
    let model = static_layer(&grid, &[]);
    for release in RELEASES {
        for costmap in COSTMAPS {
            assert_eq!(
                count(&model, release, costmap, "obstacles"),
                0,
                "{release} {costmap}: {model}"
            );
            assert_eq!(
                count(&model, release, costmap, "wiped"),
                0,
                "{release} {costmap}: {model}"
            );
            assert_eq!(
                count(&model, release, costmap, "unknown"),
                0,
                "{release} {costmap}: {model}"
            );
            assert_eq!(
                count(&model, release, costmap, "max_cost"),
                248,
                "98 → 98/100·254 in {release} {costmap}"
            );
        }
    }
    let tracking = static_layer(&grid, &["local_costmap.track_unknown_space=true"]);
    for release in RELEASES {
        assert!(
            count(&tracking, release, "local_costmap", "wiped") > 0,
            "{release}: a rolling costmap that tracks unknown space keeps its obstacles under -1? {tracking}"
        );
    }
}

/// An explicit `cap = 100` is LETHAL on every release; `cap = 99` is INSCRIBED on
/// Lyrical and Rolling (navigation2 PR #5781) and passable (251) before.
#[test]
fn caps_of_99_and_100_are_obstacles_where_nav2_says_so() {
    let lethal = static_layer(&received_grid("nav2-cap100", "cap = 100", 100), &[]);
    let inscribed = static_layer(&received_grid("nav2-cap99", "cap = 99", 99), &[]);
    for release in RELEASES {
        for costmap in COSTMAPS {
            assert!(
                count(&lethal, release, costmap, "lethal") > 20,
                "{release}: {lethal}"
            );
            let n = count(&inscribed, release, costmap, "inscribed");
            if matches!(release, "lyrical" | "rolling") {
                assert!(n > 20, "{release}: 99 → INSCRIBED: {inscribed}");
            } else {
                assert_eq!(n, 0, "{release}: {inscribed}");
                assert_eq!(count(&inscribed, release, costmap, "max_cost"), 251);
            }
        }
    }
}

/// A grid set by `width_cells`/`height_cells` is not the robots' map: the bridge
/// says so at start, in one line naming the grid and the fix; a grid from
/// `costmap.map_yaml` starts without it.
#[test]
fn the_bridge_warns_when_its_grid_is_not_the_robots_map() {
    let needle = "costmap.map_yaml unset";
    let domain = dds_domain();
    let site = costmap_site("nav2-keys", domain, "");
    let bridge = site.spawn("isochron-costmap", &[]);
    assert!(
        bridge.wait_for_stderr(needle, Duration::from_secs(30)),
        "{}",
        bridge.stderr()
    );
    let stderr = bridge.stderr();
    let line = stderr.lines().find(|l| l.contains(needle)).unwrap();
    assert!(
        line.contains("WARN")
            && line.contains("60x60 cells of 0.1 m from (-1, 1.5)")
            && line.contains("set costmap.map_yaml"),
        "{line}"
    );
    drop(bridge);

    // The robots' map: a 40x30 PGM of 0.05 m from (-2, -1).
    let site = TestSite::new(
        "nav2-map-yaml",
        &format!(
            "{}\n[costmap]\nmap_yaml = \"map.yaml\"\nros_domain_id = {}\ndds_interfaces = [\"127.0.0.1\"]\n",
            crate::costmap::camera_toml(),
            dds_domain()
        ),
    );
    let mut pgm = b"P5\n40 30\n255\n".to_vec();
    pgm.extend(vec![254u8; 40 * 30]);
    std::fs::write(site.path("map.pgm"), pgm).unwrap();
    std::fs::write(
        site.path("map.yaml"),
        "image: map.pgm\nresolution: 0.05\norigin: [-2.0, -1.0, 0.0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n",
    )
    .unwrap();
    let bridge = site.spawn("isochron-costmap", &[]);
    assert!(
        bridge.wait_for_stderr("publishing a 40x30 grid", Duration::from_secs(30)),
        "{}",
        bridge.stderr()
    );
    assert!(!bridge.stderr().contains(needle), "{}", bridge.stderr());
}

/// The Fast DDS requester `cargo xtask setup` builds (`tests/ros2/fastdds/`).
pub(crate) fn fastdds_requester() -> PathBuf {
    setup_file(
        "ISOCHRON_FASTDDS_REQUESTER",
        "target/fastdds-peer/plan_requester",
        "(it installs Fast DDS and fastddsgen from Debian and builds the Fast DDS client)",
    )
}

/// Calls a planning service with the Fast DDS client; its JSON line.
fn fastdds_plan(domain: u16, service: &str, args: &[&str]) -> Value {
    let client = std::process::Command::new(fastdds_requester());
    let reply = plan_reply("plan_requester", client, (domain, service, args));
    // Answered at once, not after the 2 s a reply waits for an unmatched reader.
    assert!(reply["reply_ms"].as_i64().unwrap() < 1500, "{reply}");
    reply
}

/// The same request over both layouts gets the same answer: rmw_fastrtps's (Fast
/// DDS client, request identity in the related sample identity, sent once after
/// discovery as rclcpp does) and rmw_cyclonedds's (the Python Cyclone DDS
/// client, a header in the payload).
#[test]
fn fast_dds_and_cyclone_dds_clients_get_the_same_plans() {
    let requester = fastdds_requester();
    assert!(requester.is_file());
    let domain = dds_domain();
    let routes = format!(
        "{HALVES}\n[[costmap.route]]\nname = \"via-west\"\nsegments = [\"west\"]\n\n[[costmap.route]]\nname = \"via-east\"\nsegments = [\"east\"]\n"
    );
    let site = costmap_site("nav2-services", domain, &routes);
    write_store(&site);
    let (_ipc, mut source, costmap) = start_bridge(&site, "2026-03-02T12:30:00Z");
    source.send(&[(HOT_BLOCK, 0.05)], 750);

    let now = ["now", "via-west", "via-east"];
    let fast = fastdds_plan(domain, "/isochron/plan_now", &now);
    let cyclone = ros_plan(domain, "/isochron/plan_now", &now);
    assert_plan_status(&fast, 0, "");
    assert_eq!(fast["t_star"], 750, "{fast}");
    assert_eq!(fast["t_star"], cyclone["t_star"]);
    let (f, c) = (
        fast["routes"].as_array().unwrap(),
        cyclone["routes"].as_array().unwrap(),
    );
    assert_eq!(f.len(), 2, "{fast}");
    assert_eq!(f.len(), c.len());
    for (f, c) in f.iter().zip(c) {
        assert_eq!(f["route"], c["route"], "{fast}\n{cyclone}");
        for key in ["cost2", "cost1", "short_term"] {
            assert!(same_cost(&f[key], &c[key]), "{key}: {fast}\n{cyclone}");
        }
    }

    let offline = ["offline", "via-west", "660", "840", "5"];
    let fast = fastdds_plan(domain, "/isochron/plan_offline", &offline);
    let cyclone = ros_plan(domain, "/isochron/plan_offline", &offline);
    assert_plan_status(&fast, 0, "");
    assert_eq!(fast["curve"].as_array().unwrap().len(), 36, "{fast}");
    assert_eq!(fast["windows"][0]["start_minute"], 720, "{fast}");
    for key in ["windows", "curve"] {
        let (f, c) = (
            fast[key].as_array().unwrap(),
            cyclone[key].as_array().unwrap(),
        );
        assert_eq!(f.len(), c.len(), "{key}: {fast}\n{cyclone}");
        for (f, c) in f.iter().zip(c) {
            for (k, v) in f.as_object().unwrap() {
                assert!(same_cost(v, &c[k]), "{key}.{k}: {fast}\n{cyclone}");
            }
        }
    }

    // Errors come back over Fast DDS too.
    assert_plan_errors(|service, args| fastdds_plan(domain, service, args));
    assert!(costmap.stderr().contains("plans="), "{}", costmap.stderr());
}

/// The costmap row's numbers in `isochron status --json` once they satisfy `f`.
fn status_until(site: &TestSite, what: &str, f: impl Fn(&Value) -> bool) -> Value {
    let end = Instant::now() + Duration::from_secs(30);
    loop {
        let row = site.status_row("costmap");
        if f(&row) {
            return row;
        }
        assert!(Instant::now() < end, "{what}: {row}");
        std::thread::sleep(Duration::from_millis(500));
    }
}

/// Garbage and a flood from a hostile Cyclone DDS participant: a string without
/// its NUL and an impossible route count are answered with status 1 and counted as
/// rejected, 3 bytes without a header are counted; of 1 000 requests in 3 s every
/// one is either answered or counted as dropped, and the bridge's loop goes on.
#[test]
fn malformed_plan_requests_are_answered_and_floods_are_counted() {
    python();
    let domain = dds_domain();
    let site = costmap_site("nav2-attack", domain, "");
    let (_ipc, mut source, costmap) = start_bridge(&site, "2026-03-02T11:00:00Z");
    source.send(&[], 660);
    let attacker = |args: &[&str]| -> Value {
        let out = std::process::Command::new(python())
            .arg(repo_root().join("tests/ros2/plan_attacker.py"))
            .args([
                "--domain",
                &domain.to_string(),
                "--service",
                "/isochron/plan_now",
            ])
            .args(args)
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout);
        serde_json::from_str(stdout.trim()).unwrap_or_else(|e| {
            panic!(
                "plan_attacker.py: {e}: {stdout}\n{}",
                String::from_utf8_lossy(&out.stderr)
            )
        })
    };

    let garbage = attacker(&["--wait", "5", "garbage"]);
    let no_nul = &garbage["replies"]["no_nul"];
    assert_eq!(no_nul["status"], 1, "{garbage}");
    assert!(
        no_nul["message"]
            .as_str()
            .unwrap()
            .contains("without its terminating NUL"),
        "{garbage}"
    );
    assert_eq!(garbage["replies"]["count"]["status"], 1, "{garbage}");
    let row = status_until(&site, "three rejected requests", |r| r["rejected"] == 3);
    assert_eq!(row["dropped"], 0, "{row}");
    assert!(
        costmap.wait_for_stderr("plans_rejected=3", Duration::from_secs(15)),
        "{}",
        costmap.stderr()
    );

    // The flood.
    let flood = attacker(&["--wait", "8", "flood", "1000", "3", "nowhere"]);
    let (sent, replies) = (
        flood["sent"].as_i64().unwrap(),
        flood["replies"].as_i64().unwrap(),
    );
    assert_eq!(sent, 1000);
    assert!(replies >= 16, "some are answered: {flood}");
    assert_eq!(flood["statuses"]["2"], replies, "an unknown route: {flood}");
    let row = status_until(&site, "every request answered or dropped", |r| {
        r["dropped"].as_i64().is_some_and(|d| d + replies == sent)
    });
    eprintln!("flood: {flood}\nbridge: {row}");
    assert!(row["dropped"].as_i64().unwrap() > 0, "{row}");
    assert_eq!(row["rejected"], 3, "{row}");
    assert!(
        costmap
            .stderr()
            .contains("dropped, its client's queue is full"),
        "{}",
        costmap.stderr()
    );
    // The loop went on: its status is fresh.
    assert!(row["age_s"].as_f64().unwrap() < 6.0, "{row}");
    drop(costmap);
}

/// The JSON line a peer printed on standard output.
pub(crate) fn peer_json(name: &str, out: &std::process::Output) -> Value {
    let stdout = String::from_utf8_lossy(&out.stdout);
    serde_json::from_str(stdout.trim()).unwrap_or_else(|e| {
        panic!(
            "{name}: {e}: {stdout}\n{}",
            String::from_utf8_lossy(&out.stderr)
        )
    })
}

/// One Cyclone DDS participant floods `plan_now` with 500 requests a second for
/// a route that exists (each one planned) while a robot asks every half second
/// (the Cyclone DDS client, sending each request once): at least 90 % of the
/// robot's plans come back within 1 s, and the flood is dropped and counted.
#[test]
fn a_plan_flood_from_one_participant_does_not_starve_a_robot() {
    python();
    let dds = dds_domain();
    let domain = dds.to_string();
    let routes =
        format!("{HALVES}\n[[costmap.route]]\nname = \"via-west\"\nsegments = [\"west\"]\n");
    let site = costmap_site("nav2-fair", dds, &routes);
    write_store(&site);
    let (_ipc, mut source, costmap) = start_bridge(&site, "2026-03-02T12:30:00Z");
    source.send(&[(HOT_BLOCK, 0.05)], 750);
    let service = ["--domain", &domain, "--service", "/isochron/plan_now"];

    // 10 000 requests in 20 s; the robot's 28 (14 s) start once the flood runs.
    let flood = Command::new(python())
        .arg(repo_root().join("tests/ros2/plan_attacker.py"))
        .args(service)
        .args(["--wait", "2", "flood", "10000", "20", "via-west"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_secs(4));
    let robot = Command::new(python())
        .arg(repo_root().join("tests/ros2/plan_client.py"))
        .args(service)
        .args(["--poll", "28", "--timeout", "3", "now", "via-west"])
        .output()
        .unwrap();
    let robot = peer_json("plan_client.py --poll", &robot);
    let flood = peer_json("plan_attacker.py", &flood.wait_with_output().unwrap());
    let row = site.status_row("costmap");
    eprintln!("robot: {robot}\nflood: {flood}\nbridge: {row}");

    let rate = flood["sent"].as_f64().unwrap() / flood["seconds"].as_f64().unwrap();
    assert!(rate > 450.0, "the flood was {rate:.0}/s: {flood}");
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
        "robot under a {rate:.0}/s flood: {within}/28 within 1 s, p50 {} ms, max {} ms",
        latency[14], latency[27]
    );
    assert!(within * 10 >= 28 * 9, "{within}/28 within 1 s: {robot}");
    let answered = latency.iter().filter(|l| l.is_finite()).count();
    assert_eq!(
        robot["statuses"]["0"], answered,
        "plans of a known route: {robot}"
    );
    assert!(
        row["dropped"].as_i64().unwrap() > 0,
        "the flood is dropped: {row}"
    );
    drop(costmap);
}
