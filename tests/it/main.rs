//! The multi-process integration tests, one module per area, in one test binary
//! (linking OpenCV and the services' crates once instead of once per area).
//!
//! Every test gets its own site (directory, config, iceoryx2 prefix, DDS domain),
//! so the tests of all areas run in parallel in this one process. Run one area
//! with a filter, e.g. `cargo test -p isochron-tests --test it -- capture::`.
//!
//! The areas, and the peers they meet:
//!
//! * capture, motion (scored against PETS 2009 boxes), cascade (kill -9 at random
//!   moments), gate (a small ONNX model with the YOLOv8 output layout whose boxes
//!   are known, built with the Python `onnx` package by `tests/data/yolo_constant.py`,
//!   run through the gate's OpenCV dnn path, letterbox and channels included),
//!   pipeline (`isochron replay` on vtest.avi), presence (a clip made from
//!   vtest.avi — median scene, PETS09 cut-outs walking in, standing still 30–45 s,
//!   walking out — scored on the whole group's events and recording);
//! * live_camera: capture against a real IP camera, GStreamer's RTSP server
//!   (`tests/rtsp/camera.py`, gst-rtsp-server from Debian): killed for 10 s,
//!   frozen with SIGSTOP, asked with a wrong password — recovery times, the
//!   reason in `isochron status`, one WARN per outage, no password shown;
//! * costmap: the grid read back by an independent ROS 2 peer,
//!   `tests/ros2/costmap_listener.py` (Eclipse Cyclone DDS from PyPI, in
//!   `target/ros2-venv`), on loopback and a DDS domain per test; nav2: that grid
//!   through a Python re-implementation of each Nav2 release's StaticLayer
//!   (`tests/ros2/nav2_static_layer.py`, docs/nav2.md), and the planning services
//!   called by a Fast DDS client (`tests/ros2/fastdds/`, C++ on Debian's Fast DDS
//!   2.9 with types from fastddsgen, built by `cargo xtask setup` into
//!   `target/fastdds-peer`), the Cyclone DDS client and a hostile Cyclone DDS
//!   participant (`tests/ros2/plan_attacker.py`); rclpy: real ROS 2 nodes, rclpy
//!   Jazzy and Kilted with rmw_fastrtps_cpp from PyPI (`target/rclpy-<release>`,
//!   `tests/ros2/rclpy_peer.py`), on every topic and both services, on loopback
//!   and across two network namespaces;
//! * route_server: the bridge as the client of nav2_route's `DynamicEdgesScorer`
//!   (`nav2_msgs/srv/DynamicEdges`), served by a stand-in on rclpy Jazzy and Kilted
//!   (`tests/ros2/rclpy_peer.py route-server`) and on zenoh-ros2-sdk's
//!   `ROS2ServiceServer` (`tests/zenoh/rmw_zenoh_peer.py route-server`): edges
//!   costed, closed and reopened, a restarted server told everything, a server that
//!   refuses or hangs; route_demo: the same servers fed by `isochron up` on the
//!   demo (vtest.avi and its graph) and on a presence clip where a person stands
//!   across an edge;
//! * view: the calibration overlay on vtest.avi with the demo calibration (a wrong
//!   tape mark flagged, bad input); a `replay --record` of vtest read by the
//!   Python `mcap` package; `isochron view` during a replay at speed 1 with the
//!   protocol's reference client (`@foxglove/ws-protocol` 0.8.0 under Node.js,
//!   subprotocol `foxglove.websocket.v1`: every advertised channel subscribed and
//!   decoded with the advertised protobuf schema via protobufjs) and a Python
//!   `websockets` client speaking `foxglove.sdk.v1`; raw handshakes for each name
//!   and a 400; a client that stops reading on a 1 MiB-per-message grid (the view's
//!   RSS stays within the budget plus a margin while a reading client keeps up, and
//!   the stalled one is disconnected after `view.client_stall_s`); the view as a
//!   row of `isochron status` while it runs, and not before or after; a recorder on
//!   a 5 MiB tmpfs; the heat map; `costmap snapshot --at` on a store `isochron
//!   synth` made from a profile busy 08:00–18:00 (cost where the camera sees at
//!   10:00, zero at 03:00, -1 outside, the JSON grid, `--at 25:00` exits 64 with one
//!   line; `--day` on a weekly store busy on Mondays in one half of the view and on
//!   Tuesdays in the other: each day lights its own half, an unlearned day 66 naming the learned ones,
//!   `--day funday` exits 64 with one line);
//! * operations (kill -9 under `isochron up`, SIGTERM, a hung service, a reader
//!   that never reads, a foreign publisher of malformed samples; an ignored
//!   30-minute soak), launcher, scale (several cameras per process), doctor,
//!   inputs, reliability, conventions, front_door (the `isochron` command given a
//!   wrong flag value, a missing file, an unknown camera, too few counts: the
//!   exit code of the shared table, one line naming the flag or file, no file
//!   left behind; an output that is a device, FIFO or link left as it was; a
//!   store on a read-only mount read), stopping (Ctrl-C on `replay`, SIGTERM on
//!   `synth`: 130, the group stopped, the summary and the whole minutes kept),
//!   full_disk (`synth` and `replay` on a tmpfs that fills: 69 within seconds,
//!   saying why, no empty summary), docs_commands (every `isochron …` command of README.md and docs/*.md: its
//!   subcommands and flags exist, and those that need no group are run);
//! * hostile: forged link messages from an unauthenticated Cyclone DDS participant
//!   (`tests/ros2/link_forger.py`), raw DATA_FRAG datagrams, a forged status, a
//!   stalled subscriber, two secured links in two network namespaces; RSS bounds
//!   from `/proc`; link: two boxes in two network namespaces joined by a veth pair;
//! * sros2: the bridge with DDS Security against a secured robot it did not
//!   write (the Fast DDS client with Fast DDS's built-in security plugins and a
//!   robot enclave of `isochron keystore`), an unauthenticated Cyclone DDS
//!   participant in the bridge's place (`tests/ros2/robot_spoofer.py`) and a
//!   robot of another keystore;
//! * systemd (`systemd-analyze verify` and `security`); exporter (scraped during a
//!   replay and linted by `promtool check metrics`, a killed service's
//!   `isochron_up`, a taken port; the alert rules through `promtool check rules`
//!   and `promtool test rules`; hostile clients from raw sockets — 4 × 400 MiB
//!   request heads, 3 000 idle connections, slowloris — get 431 or are closed while
//!   VmRSS and Threads from `/proc/<pid>/status` stay bounded and a normal scrape
//!   passes promtool);
//! * mqtt: a replay of vtest into a real Mosquitto restarted in the middle, read
//!   back by a rumqttc subscriber with a persistent session (in order, received +
//!   dropped = emitted); an unreachable broker, a malformed URL; Mosquitto with TLS,
//!   certificates made by openssl, a `mosquitto_passwd` file and
//!   `require_certificate`, read back by `mosquitto_sub` (events over mutual TLS,
//!   nothing in clear through a recording relay, a forged event never published, a
//!   missing client certificate, a password the broker stops accepting mid-run);
//! * package: the `.deb` made from the dev binaries, checked with `dpkg-deb
//!   --info`/`--contents`; where `CI=true`, installed with `dpkg -i`, its user,
//!   files and `--version` checked, nothing enabled, purged.

// The tests' helpers fail their test when they unwrap, as the tests themselves may
// (clippy's allow-unwrap-in-tests covers only #[test] functions); a test reads as one
// scenario from start to end, however long.
#![allow(
    clippy::unwrap_used,
    reason = "helpers of tests: a failure panics the test"
)]
#![allow(
    clippy::too_many_lines,
    reason = "a test is one scenario, read top to bottom"
)]

mod capture;
mod cascade;
mod conventions;
mod costmap;
mod detector;
mod docs_commands;
mod doctor;
mod exporter;
mod forecast;
mod front_door;
mod full_disk;
mod gate;
mod hostile;
mod inputs;
mod launcher;
mod link;
mod live_camera;
mod local_users;
mod motion;
mod mqtt;
mod nav2;
mod operations;
mod package;
mod pipeline;
mod plan_graph;
mod presence;
mod rclpy;
mod reliability;
mod route_demo;
mod route_server;
mod scale;
mod sros2;
mod stopping;
mod systemd;
mod view;
mod zenoh;
