//! SROS2 on the robots' side: the costmap bridge with DDS Security
//! (`costmap.security_dir`, an enclave of `isochron keystore bridge`) and a
//! secured robot the project did not write — the Fast DDS client of
//! `tests/ros2/fastdds/` (Debian's Fast DDS 2.9 and its built-in PKI-DH,
//! Access-Permissions and AES-GCM-GMAC plugins) with a robot enclave of the same
//! keystore (`isochron keystore robot`) — against an unauthenticated Cyclone DDS
//! participant in the bridge's place (`tests/ros2/robot_spoofer.py`: a forged
//! `OccupancyGrid` on the grid topic, spoofed `plan_now` replies) and a robot
//! whose certificates come from another keystore.

use std::path::Path;
use std::time::Duration;

use isochron_tests::{Proc, TestSite, repo_root};
use serde_json::Value;

use crate::costmap::{HALVES, costmap_site, dds_domain, python, start_bridge, write_store};
use crate::hostile::keystore;
use crate::nav2::fastdds_requester;

/// The bridge's grid topic in [`crate::costmap::costmap_toml`].
const TOPIC: &str = "/isochron_test/activity_costmap";

/// What one run of the Fast DDS robot printed: its JSON lines.
struct Robot {
    lines: Vec<Value>,
    stderr: String,
}

impl Robot {
    /// Runs the Fast DDS client on `domain` (with `enclave`'s DDS Security if
    /// given): it reads the grid topic, asks `plan_now` for route via-west, and
    /// reads on for 3 s after the answer.
    fn run(domain: u16, enclave: Option<&Path>, timeout_s: u32) -> Robot {
        let mut args = vec![
            "--domain".to_string(),
            domain.to_string(),
            "--service".into(),
            "/isochron/plan_now".into(),
            "--timeout".into(),
            timeout_s.to_string(),
            "--watch".into(),
            TOPIC.into(),
            "--linger".into(),
            "3".into(),
        ];
        if let Some(dir) = enclave {
            args.extend(["--security".to_string(), dir.display().to_string()]);
        }
        args.extend(["now".to_string(), "via-west".into()]);
        let done = Proc::spawn(&fastdds_requester(), &args)
            .finish(Duration::from_secs(timeout_s as u64 + 30));
        let lines = done
            .stdout
            .lines()
            .map(|l| {
                serde_json::from_str(l)
                    .unwrap_or_else(|e| panic!("plan_requester: {e}: {l}\n{}", done.stderr))
            })
            .collect();
        Robot {
            lines,
            stderr: done.stderr,
        }
    }

    /// The lines of `kind`.
    fn of(&self, kind: &str) -> Vec<&Value> {
        self.lines.iter().filter(|l| l["kind"] == kind).collect()
    }

    /// Everything it printed, for a failure message.
    fn dump(&self) -> String {
        let lines: Vec<String> = self.lines.iter().map(Value::to_string).collect();
        format!("{}\n-----\n{}", lines.join("\n"), self.stderr)
    }
}

/// Starts the spoofer on `domain` for `seconds`.
fn spoofer(domain: u16, seconds: u32) -> Proc {
    let script = repo_root().join("tests/ros2/robot_spoofer.py");
    Proc::spawn(
        &python(),
        &[
            script.display().to_string(),
            "--domain".into(),
            domain.to_string(),
            "--topic".into(),
            TOPIC.into(),
            "--seconds".into(),
            seconds.to_string(),
        ],
    )
}

/// With SROS2 on, the secured Fast DDS robot gets the bridge's grid and its
/// `plan_now` answer, and nothing of the unauthenticated spoofer that writes a
/// forged grid and spoofed replies on the same topics meanwhile; a robot with
/// another keystore's certificates gets nothing. The control: an open robot
/// (no security) on the same domain gets the spoofer's grid and replies, and
/// nothing of the secured bridge.
#[test]
#[ignore = "races in RustDDS's security plugins: on a fresh 2-core CI run (2026-12-07) the secured bridge logged `I need my lock!! … ros2-spinner has it` every 100 ms and never subscribed to its iceoryx2 input within 30 s; passes on other runs. Run with --ignored until the lock is fixed (issue 58)"]
fn a_secured_bridge_reaches_only_robots_of_its_keystore() {
    python();
    fastdds_requester();
    let domain = dds_domain();
    let keys = tempfile::tempdir().unwrap();
    let other = tempfile::tempdir().unwrap();
    let dir = keys.path().display().to_string();
    let routes = format!(
        "security_dir = \"{dir}/enclaves/costmap\"\n{HALVES}\n[[costmap.route]]\nname = \"via-west\"\nsegments = [\"west\"]\n"
    );
    let site: TestSite = costmap_site("sros2", domain, &routes);
    let config = site.config_path().display().to_string();
    keystore(&["init", &dir]);
    keystore(&["bridge", &dir, "--config", &config]);
    keystore(&["robot", &dir, "robot1", "--config", &config]);
    let other_dir = other.path().display().to_string();
    keystore(&["init", &other_dir]);
    keystore(&["robot", &other_dir, "robot1", "--config", &config]);
    let bridge_permissions =
        std::fs::read_to_string(keys.path().join("enclaves/costmap/permissions.xml")).unwrap();
    let robot_permissions =
        std::fs::read_to_string(keys.path().join("enclaves/robots/robot1/permissions.xml"))
            .unwrap();
    assert!(
        bridge_permissions.contains(&format!("<topic>rt{TOPIC}</topic>"))
            && bridge_permissions.contains("<topic>rr/isochron/plan_nowReply</topic>"),
        "{bridge_permissions}"
    );
    let publish = &robot_permissions[robot_permissions.find("<publish>").unwrap()
        ..robot_permissions.find("</publish>").unwrap()];
    assert!(
        publish.contains("rq/isochron/plan_nowRequest") && !publish.contains(TOPIC),
        "{robot_permissions}"
    );

    write_store(&site);
    let (_ipc, mut source, mut bridge) = start_bridge(&site, "2026-03-02T12:30:00Z");
    source.send(&[(crate::costmap::HOT_BLOCK, 0.05)], 750);
    assert!(
        bridge.wait_for_stderr("DDS Security on", Duration::from_secs(20)),
        "{}",
        bridge.stderr()
    );
    // Long enough for all three robots on a loaded machine; stopped at the end.
    let mut spoof = spoofer(domain, 300);

    let robot = Robot::run(
        domain,
        Some(&keys.path().join("enclaves/robots/robot1")),
        30,
    );
    let grids = robot.of("grid");
    let reply = robot.of("reply");
    eprintln!(
        "MEASURED secured robot: {} grids ({} forged), reply {}, {} other replies",
        grids.len(),
        grids.iter().filter(|g| g["frame_id"] == "forged").count(),
        reply.first().map_or("none".into(), |r| r.to_string()),
        robot.of("other_reply").len()
    );
    assert!(
        !grids.is_empty()
            && grids
                .iter()
                .all(|g| g["frame_id"] == "test_map" && g["width"] == 60),
        "{}",
        robot.dump()
    );
    assert_eq!(reply.len(), 1, "{}", robot.dump());
    assert_eq!(reply[0]["status"], 0, "{}", robot.dump());
    assert_eq!(
        reply[0]["routes"][0]["route"],
        "via-west",
        "{}",
        robot.dump()
    );
    assert!(robot.of("other_reply").is_empty(), "{}", robot.dump());

    // Certificates of another keystore: not authenticated, nothing matches.
    let stranger = Robot::run(
        domain,
        Some(&other.path().join("enclaves/robots/robot1")),
        8,
    );
    assert_eq!(
        stranger.lines.last().map(|l| l["kind"].clone()),
        Some("unavailable".into()),
        "{}",
        stranger.dump()
    );
    assert!(
        stranger.of("grid").is_empty() && stranger.of("other_reply").is_empty(),
        "{}",
        stranger.dump()
    );

    // The control: an open robot meets the spoofer, not the secured bridge.
    let open = Robot::run(domain, None, 8);
    let forged = open.of("grid");
    eprintln!(
        "MEASURED open robot: {} grids (all forged: {}), {} spoofed replies, {}",
        forged.len(),
        forged.iter().all(|g| g["frame_id"] == "forged"),
        open.of("other_reply").len(),
        open.lines.last().map_or(String::new(), Value::to_string)
    );
    assert!(
        !forged.is_empty() && forged.iter().all(|g| g["frame_id"] == "forged"),
        "{}",
        open.dump()
    );
    assert!(!open.of("other_reply").is_empty(), "{}", open.dump());
    // Never the secured bridge's answer (under load the robot may still be
    // printing the spoofer's when its time is up, before its last line).
    assert!(open.of("reply").is_empty(), "{}", open.dump());
    spoof.terminate(Duration::from_secs(10));
    assert!(bridge.wait(Duration::ZERO).is_none(), "{}", bridge.stderr());
}

/// Without `costmap.security_dir` the bridge says at start that the robots'
/// topics and services are open.
#[test]
fn an_open_bridge_says_so_at_start() {
    let site = costmap_site("sros2-open", dds_domain(), "");
    let (_ipc, _source, bridge) = start_bridge(&site, "2026-03-02T12:30:00Z");
    assert!(
        bridge.wait_for_stderr("DDS Security off", Duration::from_secs(20)),
        "{}",
        bridge.stderr()
    );
    let stderr = bridge.stderr();
    let line = stderr
        .lines()
        .find(|l| l.contains("DDS Security off"))
        .unwrap();
    assert!(
        line.contains("open") && line.contains("costmap.security_dir"),
        "{line}"
    );
}

/// A `costmap.security_dir` without the enclave's files stops the bridge at
/// start (exit 78) with one line naming the key and the missing file.
#[test]
fn a_bridge_enclave_without_its_files_is_a_config_error() {
    let empty = tempfile::tempdir().unwrap();
    let site = costmap_site(
        "sros2-missing",
        dds_domain(),
        &format!("security_dir = \"{}\"\n", empty.path().display()),
    );
    let done = site
        .spawn("isochron-costmap", &[])
        .finish(Duration::from_secs(30));
    assert_eq!(done.status.code(), Some(78), "{}", done.stderr);
    assert!(
        done.stderr.contains("costmap.security_dir")
            && done.stderr.contains("identity_ca.cert.pem is missing"),
        "{}",
        done.stderr
    );
}
