//! Parsing, validation and error locations, end to end.

use super::*;

const GOOD: &str = r#"
[site]
name = "test"
time_zone = "Europe/Berlin"

[[camera]]
id = "cam01"
source = "video.avi"
fps = 10

[[camera]]
id = "cam02"
source = "rtsp://127.0.0.1/stream"
"#;

fn parse(text: &str) -> Result<Config, ConfigError> {
    Config::parse(text, Path::new("site.toml"))
}

/// The error of [`GOOD`] with its `fps = 10` line replaced by `line`.
fn fps_line(line: &str) -> ConfigError {
    parse(&GOOD.replace("fps = 10", line)).unwrap_err()
}

#[test]
fn good_config_parses_with_defaults() {
    let c = parse(GOOD).unwrap();
    assert_eq!(c.site.time_zone, "Europe/Berlin");
    assert_eq!(c.site.service_prefix, "isochron");
    assert_eq!(c.cameras.len(), 2);
    assert_eq!(c.cameras[0].speed, Speed::Factor(1.0));
    assert_eq!(c.ipc.max_subscribers, 5);
    assert_eq!(
        c.cameras[1].source_kind(Path::new("/etc")),
        SourceKind::Url("rtsp://127.0.0.1/stream".into())
    );
    assert_eq!(
        c.cameras[0].source_kind(Path::new("/etc")),
        SourceKind::File("/etc/video.avi".into())
    );
}

#[test]
fn relative_paths_become_absolute_against_the_config_file() {
    let text = format!(
        "{GOOD}\n[gate.detector]\nmodel = \"models/yolo.onnx\"\n\n[costmap]\nmap_yaml = \"/maps/floor.yaml\"\nsnapshot_dir = \"snaps\"\n"
    );
    let loaded = LoadedConfig {
        config: parse(&text).unwrap(),
        path: PathBuf::from("/etc/isochron/site.toml"),
    };
    let c = loaded.with_absolute_paths();
    let etc = Path::new("/etc/isochron");
    assert_eq!(c.cameras[0].source, "/etc/isochron/video.avi");
    assert_eq!(c.cameras[1].source, "rtsp://127.0.0.1/stream");
    assert_eq!(c.gate.detector.model, Some(etc.join("models/yolo.onnx")));
    assert_eq!(c.costmap.map_yaml, Some(PathBuf::from("/maps/floor.yaml")));
    assert_eq!(c.costmap.snapshot_dir, Some(etc.join("snaps")));
    assert_eq!(c.site.state_dir, PathBuf::from("/var/lib/isochron"));
}

#[test]
fn syntax_error_names_the_line() {
    let err = parse("[site]\nname = \"x\"\ntime_zone = = 3\n").unwrap_err();
    assert_eq!(err.line, Some(3), "{err}");
    assert!(err.to_string().starts_with("site.toml:3:"), "{err}");
}

#[test]
fn wrong_type_names_line_and_key() {
    let err = fps_line("fps = \"fast\"");
    assert_eq!(err.key.as_deref(), Some("camera[0].fps"), "{err}");
    assert_eq!(err.line, Some(9), "{err}");
    assert!(err.message.contains("expected"), "{err}");
}

#[test]
fn unknown_key_is_rejected_with_its_line() {
    let err = fps_line("fsp = 10");
    assert_eq!(err.line, Some(9), "{err}");
    assert!(err.message.contains("fsp"), "{err}");
}

#[test]
fn invalid_values_name_line_key_and_expectation() {
    let err = fps_line("fps = -3");
    assert_eq!(err.key.as_deref(), Some("camera[0].fps"));
    assert_eq!(err.line, Some(9));
    assert!(err.message.contains("expected a number"), "{err}");

    let text = GOOD.replace("Europe/Berlin", "Mars/Olympus");
    let err = parse(&text).unwrap_err();
    assert_eq!(err.key.as_deref(), Some("site.time_zone"));
    assert_eq!(err.line, Some(4));

    let text = GOOD.replace("id = \"cam02\"", "id = \"cam01\"");
    let err = parse(&text).unwrap_err();
    assert_eq!(err.key.as_deref(), Some("camera[1].id"));
    assert_eq!(err.line, Some(12));
    assert!(err.message.contains("used twice"));
}

#[test]
fn start_frame_is_for_files_and_within_the_preload() {
    let c = parse(&GOOD.replace("fps = 10", "fps = 10\nstart_frame = 40")).unwrap();
    assert_eq!(c.cameras[0].start_frame, 40);
    assert_eq!(c.cameras[1].start_frame, 0);

    let text = GOOD.replace(
        "fps = 10",
        "fps = 10\npreload_frames = 40\nstart_frame = 40",
    );
    let err = parse(&text).unwrap_err();
    assert_eq!(err.key.as_deref(), Some("camera[0].start_frame"));
    assert!(err.message.contains("below preload_frames (40)"), "{err}");

    let text = format!("{GOOD}start_frame = 5\n");
    let err = parse(&text).unwrap_err();
    assert_eq!(err.key.as_deref(), Some("camera[1].start_frame"));
    assert!(err.message.contains("only for file sources"), "{err}");
}

#[test]
fn a_file_start_outside_1971_to_2200_is_refused() {
    let with =
        |start: &str| parse(&GOOD.replace("fps = 10", &format!("fps = 10\nstart = \"{start}\"")));
    assert!(with("2026-03-02T07:00:00Z").is_ok());
    for start in [
        "1969-12-31T00:00:00Z",
        "2262-01-01T00:00:00Z",
        "2201-01-01T00:00:00Z",
    ] {
        let err = with(start).unwrap_err();
        assert_eq!(err.key.as_deref(), Some("camera[0].start"), "{start}");
        assert!(
            err.message.contains("from 1971-01-01 to 2200-01-01"),
            "{err}"
        );
    }
}

#[test]
fn day_types_settings_are_checked_with_their_keys() {
    let c = parse(GOOD).unwrap();
    assert_eq!(c.cascade.cycle, crate::clock::Cycle::DayTypes);
    let text = format!("{GOOD}\n[cascade]\nrest_days = [\"fri\", \"sunday\"]\n");
    let err = parse(&text).unwrap_err();
    assert_eq!(err.key.as_deref(), Some("cascade.rest_days[1]"));
    let text = format!("{GOOD}\n[cascade]\nholidays = [\"2026-12-25\", \"25/12/2026\"]\n");
    let err = parse(&text).unwrap_err();
    assert_eq!(err.key.as_deref(), Some("cascade.holidays[1]"));
    assert!(err.message.contains("YYYY-MM-DD"), "{err}");
}

#[test]
fn missing_cameras_is_an_error() {
    let err = parse("[site]\nname = \"x\"\n").unwrap_err();
    assert_eq!(err.key.as_deref(), Some("camera"));
    assert!(err.message.contains("[[camera]]"));
}

#[test]
fn the_shipped_configs_are_valid() {
    for (name, text) in [
        (
            "config/demo.toml",
            include_str!("../../../config/demo.toml"),
        ),
        (
            "config/site.example.toml",
            include_str!("../../../config/site.example.toml"),
        ),
    ] {
        if let Err(e) = Config::parse(text, Path::new(name)) {
            panic!("{e}");
        }
    }
}

#[test]
fn speed_parses() {
    assert_eq!(Speed::parse("max"), Some(Speed::Max));
    assert_eq!(Speed::parse("2.5"), Some(Speed::Factor(2.5)));
    assert_eq!(Speed::parse("-1"), None);
    let text = GOOD.replace("fps = 10", "speed = \"max\"");
    assert_eq!(parse(&text).unwrap().cameras[0].speed, Speed::Max);
    let err = fps_line("speed = \"fast\"");
    assert_eq!(err.key.as_deref(), Some("camera[0].speed"));
}

#[test]
fn unknown_camera_lists_the_configured_ones() {
    let loaded = LoadedConfig {
        config: parse(GOOD).unwrap(),
        path: PathBuf::from("/etc/isochron/site.toml"),
    };
    assert_eq!(loaded.camera("cam02").unwrap().id, "cam02");
    let err = loaded.camera("cam03").unwrap_err();
    assert_eq!(
        err.to_string(),
        "no camera 'cam03' in /etc/isochron/site.toml (configured: cam01, cam02)"
    );
}

#[test]
fn self_crossing_polygons_are_rejected_with_line_and_key() {
    let bow_tie = "[[0, 0], [100, 100], [100, 0], [0, 100]]";
    let square = "[[0, 0], [100, 0], [100, 100], [0, 100]]";
    let expect = |text: &str, key: &str, line: usize| {
        let err = parse(text).unwrap_err();
        assert_eq!(err.key.as_deref(), Some(key), "{err}");
        assert_eq!(err.line, Some(line), "{err}");
        assert!(
            err.message
                .starts_with("expected a simple polygon (no crossing edges)"),
            "{err}"
        );
        assert!(
            err.to_string()
                .starts_with(&format!("site.toml:{line}: key `{key}`")),
            "{err}"
        );
    };

    let mask = GOOD.replace(
        "fps = 10",
        &format!("fps = 10\nmask = [{square}, {bow_tie}]"),
    );
    expect(&mask, "camera[0].mask[1]", 10);
    let zone = format!("{GOOD}\n[[camera.zone]]\nname = \"door\"\npolygon = {bow_tie}\n");
    expect(&zone, "camera[1].zone[0].polygon", 17);
    let segment = format!("{GOOD}\n[[costmap.segment]]\nname = \"aisle\"\npolygon_m = {bow_tie}\n");
    expect(&segment, "costmap.segment[0].polygon_m", 17);

    // The same shapes, simple, pass (a zone and a mask need no floor points).
    parse(&mask.replace(bow_tie, square)).unwrap();
    parse(&zone.replace(bow_tie, square)).unwrap();
}

#[test]
fn lethal_cap_and_map_yaw_are_warned_with_line_and_key() {
    let c = parse(GOOD).unwrap();
    assert_eq!(
        c.costmap.cap, 98,
        "activity is never an obstacle in Nav2 by default"
    );
    assert!(c.costmap.publish_unknown);
    assert!(c.costmap.warnings().is_empty());
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("site.toml");
    std::fs::write(
        &path,
        format!("{GOOD}\n[costmap]\ncap = 100\norigin_yaw_rad = 0.5\nwidth_cells = 10\nheight_cells = 10\n"),
    )
    .unwrap();
    let loaded = Config::load(&path).unwrap();
    let warnings: Vec<String> = loaded.warnings().iter().map(|w| w.to_string()).collect();
    assert_eq!(warnings.len(), 2, "{warnings:?}");
    let line = |key: &str| {
        GOOD.lines().count()
            + 2
            + ["cap", "origin_yaw_rad"]
                .iter()
                .position(|k| *k == key)
                .unwrap()
            + 1
    };
    assert!(
        warnings[0].contains(&format!("site.toml:{}: key `costmap.cap`", line("cap")))
            && warnings[0].contains("lethal"),
        "{warnings:?}"
    );
    assert!(
        warnings[1].contains("key `costmap.origin_yaw_rad`") && warnings[1].contains("ignores"),
        "{warnings:?}"
    );
    assert!(parse(&format!("{GOOD}\n[costmap]\ncap = 101\n")).is_err());
    // 99 is INSCRIBED on Nav2 Rolling and Lyrical: warned, for cap and confirm_cost.
    let c = parse(&format!("{GOOD}\n[costmap]\ncap = 99\nconfirm_cost = 99\n")).unwrap();
    let warnings = c.costmap.warnings();
    assert_eq!(warnings.len(), 2, "{warnings:?}");
    assert!(warnings.iter().all(|w| w.message.contains("INSCRIBED")));
    assert!(
        parse(&format!("{GOOD}\n[costmap]\nconfirm_cost = 98\n"))
            .unwrap()
            .costmap
            .warnings()
            .is_empty()
    );
}

#[test]
fn speed_bands_give_nav2_mask_values() {
    let c = parse(GOOD).unwrap().costmap;
    // Unseen and quiet: 0 = no limit (Nav2 logs an error on -1).
    assert_eq!(c.speed_mask_value(-1), 0);
    assert_eq!(c.speed_mask_value(29), 0);
    assert_eq!(c.speed_mask_value(30), 50);
    assert_eq!(c.speed_mask_value(69), 50);
    assert_eq!(c.speed_mask_value(70), 25);
    assert_eq!(c.speed_mask_value(99), 25);
    let err = parse(&format!(
        "{GOOD}\n[costmap]\nspeed_busy_from_cost = 50\nspeed_crowded_from_cost = 40\n"
    ))
    .unwrap_err();
    assert_eq!(err.key.as_deref(), Some("costmap.speed_crowded_from_cost"));
}

#[test]
fn view_is_off_and_on_loopback_by_default_and_checked() {
    let c = parse(GOOD).unwrap();
    assert!(!c.view.frames, "no pixel leaves the box by default");
    assert_eq!(c.view.listen, "127.0.0.1:8765");
    let on = parse(&format!(
        "{GOOD}\n[view]\nframes = true\nframe_rate_hz = 1\n"
    ))
    .unwrap();
    assert!(on.view.frames);
    assert_eq!(on.view.frame_rate_hz, 1.0);
    let err = parse(&format!("{GOOD}\n[view]\nlisten = \"localhost\"\n")).unwrap_err();
    let line = GOOD.lines().count() + 3;
    assert!(
        err.to_string().starts_with(&format!(
            "site.toml:{line}: key `view.listen`: expected an IP address and port"
        )),
        "{err}"
    );
    let err = parse(&format!("{GOOD}\n[view]\nframe_rate_hz = 0\n")).unwrap_err();
    assert!(err.to_string().contains("view.frame_rate_hz"), "{err}");
    // A slow client may cost the view 4 MiB, and is dropped after 10 s stalled.
    assert_eq!(c.view.client_budget_bytes(), 4 << 20);
    assert_eq!(c.view.client_stall_s, 10.0);
    let err = parse(&format!("{GOOD}\n[view]\nclient_budget_mib = 0\n")).unwrap_err();
    assert_eq!(err.key.as_deref(), Some("view.client_budget_mib"), "{err}");
    let err = parse(&format!("{GOOD}\n[view]\nclient_stall_s = 0.5\n")).unwrap_err();
    assert_eq!(err.key.as_deref(), Some("view.client_stall_s"), "{err}");
    // 32 clients at most, 128 MiB for all of them together.
    assert_eq!(c.view.max_clients, 32);
    assert_eq!(c.view.memory_budget_bytes(), 128 << 20);
    let err = parse(&format!("{GOOD}\n[view]\nmax_clients = 0\n")).unwrap_err();
    assert_eq!(err.key.as_deref(), Some("view.max_clients"), "{err}");
    let err = parse(&format!("{GOOD}\n[view]\nmemory_budget_mib = 0.5\n")).unwrap_err();
    assert_eq!(err.key.as_deref(), Some("view.memory_budget_mib"), "{err}");
}

#[test]
fn link_sections_are_checked_with_line_and_key() {
    let link = |body: &str| parse(&format!("{GOOD}\n[link]\n{body}\n"));
    let c = link("box_id = \"box_a\"\nexport = [\"cam01\"]\nimport = [\"cam07\"]\nros_domain_id = 7\ndds_interfaces = [\"10.0.0.5\"]\nsecurity_dir = \"enclave\"").unwrap();
    assert_eq!(c.link.export, ["cam01"]);
    assert_eq!(c.link.namespace(), DEFAULT_LINK_NAMESPACE);
    assert!(!parse(GOOD).unwrap().link.is_enabled());

    let err = link("box_id = \"box_a\"\nexport = [\"cam01\", \"cam09\"]").unwrap_err();
    assert_eq!(err.key.as_deref(), Some("link.export[1]"));
    assert_eq!(err.line, Some(17));
    assert!(err.message.contains("[[camera]] id"), "{err}");

    let err = link("export = [\"cam01\"]").unwrap_err();
    assert_eq!(err.key.as_deref(), Some("link.box_id"));

    let err = link("import = [\"cam-7\"]").unwrap_err();
    assert_eq!(err.key.as_deref(), Some("link.import[0]"));
    assert!(err.message.contains("ROS 2 name token"), "{err}");

    let err = link("box_id = \"a\"\nexport = [\"cam01\"]\nimport = [\"cam01\"]").unwrap_err();
    assert_eq!(err.key.as_deref(), Some("link.export[0]"));

    let err = link("dds_interfaces = [\"eth0\"]").unwrap_err();
    assert_eq!(err.key.as_deref(), Some("link.dds_interfaces[0]"));
    assert!(err.message.contains("IP address"), "{err}");

    let err = link("namespace = \"isochron/link\"").unwrap_err();
    assert_eq!(err.key.as_deref(), Some("link.namespace"));

    assert_eq!(parse(GOOD).unwrap().link.queue_messages(), 64);
    let err = link("queue_messages = 0").unwrap_err();
    assert_eq!(err.key.as_deref(), Some("link.queue_messages"));
}

#[test]
fn an_unauthenticated_link_needs_the_grid_of_each_imported_camera() {
    // Without DDS Security an imported camera's grid is configured, never pinned
    // by the first (possibly forged) sample.
    let err = parse(&format!("{GOOD}\n[link]\nimport = [\"cam07\"]\n")).unwrap_err();
    assert_eq!(err.key.as_deref(), Some("link.import[0]"), "{err}");
    assert!(
        err.message.contains("\"cam07\"") && err.message.contains("width and height"),
        "{err}"
    );
    let err = parse(&format!(
        "{GOOD}\n[link]\nimport = [\"cam02\"]\ninsecure = true\n"
    ))
    .unwrap_err();
    assert_eq!(err.key.as_deref(), Some("camera[1].width"), "{err}");
    assert!(
        err.message.contains("imported camera \"cam02\"")
            && err.message.contains("link.security_dir"),
        "{err}"
    );
    let sized = GOOD.replace(
        "source = \"rtsp://127.0.0.1/stream\"",
        "source = \"rtsp://127.0.0.1/stream\"\nwidth = 640\nheight = 480",
    );
    let c = parse(&format!("{sized}\n[link]\nimport = [\"cam02\"]\n")).unwrap();
    assert_eq!(c.link.import, ["cam02"]);
    // With an enclave the first authenticated sample may pin it.
    parse(&format!(
        "{GOOD}\n[link]\nimport = [\"cam02\"]\nsecurity_dir = \"enclave\"\n"
    ))
    .unwrap();
}

#[test]
fn the_bridge_enclave_is_a_directory_when_given() {
    let c = parse(&format!(
        "{GOOD}\n[costmap]\nsecurity_dir = \"keys/enclaves/costmap\"\n"
    ))
    .unwrap();
    assert_eq!(
        c.costmap.security_dir.as_deref(),
        Some("keys/enclaves/costmap")
    );
    assert_eq!(parse(GOOD).unwrap().costmap.security_dir, None);
    let err = parse(&format!("{GOOD}\n[costmap]\nsecurity_dir = \" \"\n")).unwrap_err();
    assert_eq!(err.key.as_deref(), Some("costmap.security_dir"), "{err}");
    assert!(err.message.contains("isochron keystore bridge"), "{err}");
}

#[test]
fn zenoh_output_is_off_by_default_and_its_keys_are_checked() {
    let c = parse(GOOD).unwrap();
    assert!(!c.costmap.zenoh.enabled);
    assert_eq!(
        c.costmap.zenoh.connect,
        vec![DEFAULT_ZENOH_ROUTER.to_string()]
    );
    assert_eq!(
        c.costmap.zenoh.listen,
        vec![DEFAULT_ZENOH_LISTEN.to_string()]
    );
    let zenoh = |body: &str| parse(&format!("{GOOD}\n[costmap.zenoh]\nenabled = true\n{body}"));
    assert!(zenoh("mode = \"client\"\nconnect = [\"tls/10.0.0.5:7447\"]\n").is_ok());
    let err = zenoh("mode = \"router\"\n").unwrap_err();
    assert_eq!(err.key.as_deref(), Some("costmap.zenoh.mode"));
    assert!(err.message.contains("\"peer\" or \"client\""), "{err}");
    let err = zenoh("listen = [\"tcp/127.0.0.1:0\", \"udp/10.0.0.5:7447\"]\n").unwrap_err();
    assert_eq!(err.key.as_deref(), Some("costmap.zenoh.listen[1]"));
    let err = zenoh("connect = [\"localhost\"]\n").unwrap_err();
    assert_eq!(err.key.as_deref(), Some("costmap.zenoh.connect[0]"));
    let err = zenoh("mode = \"client\"\nconnect = []\n").unwrap_err();
    assert_eq!(err.key.as_deref(), Some("costmap.zenoh.connect"));
    let err = zenoh("routers = 1\n").unwrap_err();
    assert!(err.message.contains("routers"), "{err}");
}

#[test]
fn route_graph_keys_default_and_are_checked_with_line_and_key() {
    let c = parse(GOOD).unwrap().costmap;
    assert_eq!(c.route_graph, None);
    assert_eq!(c.route_edge_width_m, 1.2);
    assert_eq!(c.route_update_s, 1.0);
    assert_eq!(c.route_close_after_s, 5.0);
    assert_eq!(c.route_cost_epsilon, 1.0);
    assert_eq!(c.route_speed_mps, 0.5);
    assert_eq!(
        c.route_adjust_edges_service(),
        "route_server/DynamicEdgesScorer/adjust_edges"
    );
    let c = parse(&format!(
        "{GOOD}\n[costmap]\nroute_graph = \"graphs/site.geojson\"\nroute_server = \"/robot1/route_server\"\nroute_scorer = \"People\"\n"
    ))
    .unwrap()
    .costmap;
    assert_eq!(c.route_graph, Some(PathBuf::from("graphs/site.geojson")));
    assert_eq!(
        c.route_adjust_edges_service(),
        "/robot1/route_server/People/adjust_edges"
    );
    // Bad values name their key and line (each is on line 16, below [costmap]).
    for (body, key, wrong) in [
        ("route_edge_width_m = 0", "costmap.route_edge_width_m", "0"),
        ("route_update_s = 0.01", "costmap.route_update_s", "0.01"),
        (
            "route_close_after_s = -1",
            "costmap.route_close_after_s",
            "-1",
        ),
        (
            "route_cost_epsilon = -0.5",
            "costmap.route_cost_epsilon",
            "-0.5",
        ),
        ("route_speed_mps = 0", "costmap.route_speed_mps", "0"),
        (
            "route_server = \"route server\"",
            "costmap.route_server",
            "route server",
        ),
        ("route_scorer = \"a/b\"", "costmap.route_scorer", "a/b"),
        ("route_graph = \"\"", "costmap.route_graph", ""),
    ] {
        let err = parse(&format!("{GOOD}\n[costmap]\n{body}\n")).unwrap_err();
        assert_eq!(err.key.as_deref(), Some(key), "{body}: {err}");
        assert_eq!(err.line, Some(16), "{body}: {err}");
        assert!(err.to_string().contains(wrong), "{body}: {err}");
    }
    // The graph's path is relative to the config file.
    let loaded = LoadedConfig {
        config: parse(&format!(
            "{GOOD}\n[costmap]\nroute_graph = \"site.geojson\"\n"
        ))
        .unwrap(),
        path: PathBuf::from("/etc/isochron/site.toml"),
    };
    assert_eq!(
        loaded.with_absolute_paths().costmap.route_graph,
        Some(PathBuf::from("/etc/isochron/site.geojson"))
    );
}

#[test]
fn a_network_camera_transport_and_timeouts_default_and_are_checked() {
    let c = parse(GOOD).unwrap();
    let cam = &c.cameras[1];
    assert_eq!(cam.transport, Transport::Tcp);
    assert_eq!((cam.read_timeout_s, cam.connect_timeout_s), (5.0, 5.0));

    let c = parse(&format!("{GOOD}transport = \"udp\"\nread_timeout_s = 2\n")).unwrap();
    assert_eq!(c.cameras[1].transport, Transport::Udp);
    assert_eq!(c.cameras[1].read_timeout_s, 2.0);

    let err = parse(&format!("{GOOD}transport = \"quic\"\n")).unwrap_err();
    assert_eq!(err.key.as_deref(), Some("camera[1].transport"), "{err}");
    assert_eq!(err.line, Some(14), "{err}");
    assert!(err.message.contains("tcp"), "{err}");

    for line in ["read_timeout_s = 0", "connect_timeout_s = 1e9"] {
        let err = parse(&format!("{GOOD}{line}\n")).unwrap_err();
        let key = line.split(' ').next().unwrap();
        assert_eq!(err.key, Some(format!("camera[1].{key}")), "{err}");
        assert_eq!(err.line, Some(14), "{err}");
    }
}

#[test]
fn counting_lines_are_parsed_and_bad_ones_refused_naming_the_key() {
    let camera =
        "id = \"cam02\"\nsource = \"rtsp://127.0.0.1/stream\"\nwidth = 640\nheight = 480\n";
    let with = |lines: &str| {
        GOOD.replace(
            "id = \"cam02\"\nsource = \"rtsp://127.0.0.1/stream\"\n",
            &format!("{camera}{lines}"),
        )
    };
    let good =
        "[[camera.line]]\nname = \"door\"\npoints = [[10, 200], [300, 200]]\nin = \"left\"\n";
    let c = parse(&with(good)).unwrap();
    assert_eq!(c.cameras[1].lines[0].in_side, LineSide::Left);
    assert_eq!(
        c.cameras[1].lines[0].points,
        [[10.0, 200.0], [300.0, 200.0]]
    );
    for (lines, key, said) in [
        (
            "[[camera.line]]\nname = \"a\"\npoints = [[1, 2]]\nin = \"left\"\n",
            "camera[1].line[0].points",
            "at least 2",
        ),
        (
            &format!("{good}{good}"),
            "camera[1].line[1].name",
            "used twice",
        ),
        (
            "[[camera.line]]\nname = \"a\"\npoints = [[1, 2], [700, 2]]\nin = \"left\"\n",
            "camera[1].line[0].points",
            "inside the 640x480 frame",
        ),
        (
            "[[camera.line]]\nname = \"a\"\npoints = [[1, 2], [-1, 2]]\nin = \"left\"\n",
            "camera[1].line[0].points",
            "inside",
        ),
    ] {
        let err = parse(&with(lines)).unwrap_err();
        assert_eq!(err.key.as_deref(), Some(key), "{err}");
        assert!(err.message.contains(said), "{err}");
        assert!(err.line.is_some(), "{err}");
    }
    let err = parse(&with(
        "[[camera.line]]\nname = \"a\"\npoints = [[1, 2], [3, 4]]\nin = \"up\"\n",
    ))
    .unwrap_err();
    assert!(err.to_string().contains("in"), "{err}");
}
