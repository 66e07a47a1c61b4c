//! The `[costmap]` section and camera `floor_points` of the site config: defaults,
//! errors that name the key, and a round trip through TOML (as `isochron replay`
//! rewrites the config).

use std::path::Path;

use isochron_config::{Config, ConfigError};
use isochron_planning::grid::MapGrid;

/// One camera looking straight down at a 4 m × 3 m floor, with a zone.
const CAMERA: &str = concat!(
    "\n",
    include_str!("fixtures/floor_camera.toml"),
    include_str!("fixtures/door_zone.toml"),
);

fn parse(text: &str) -> Result<Config, ConfigError> {
    Config::parse(text, Path::new("site.toml"))
}

fn error(extra: &str) -> ConfigError {
    parse(&format!("{CAMERA}{extra}")).expect_err("invalid config accepted")
}

#[test]
fn defaults_need_no_costmap_section() {
    let c = parse(CAMERA).unwrap();
    let m = &c.costmap;
    assert!(!m.has_grid());
    assert_eq!(m.publish_hz, 1.0);
    assert_eq!(
        m.cap, 98,
        "never an obstacle in any Nav2 release by default"
    );
    assert_eq!(m.frame_id, "map");
    assert_eq!(m.topic, "/isochron/activity_costmap");
    assert_eq!(m.updates_topic(), "/isochron/activity_costmap_updates");
    assert_eq!(m.confirm_cost(), 98);
    assert_eq!((m.w1, m.w2), (1.0, 1.0));
    assert_eq!(c.cameras[0].floor_points.len(), 4);
}

#[test]
fn errors_name_the_key_and_the_line() {
    // Extra config, the key its error names, words the message holds ("": any).
    for (extra, key, says) in [
        ("[costmap]\nwidth_cells = 10\n", "costmap.height_cells", ""),
        (
            "[costmap]\nwidth_cells = 2000\nheight_cells = 2000\n",
            "costmap.width_cells",
            "1 MB",
        ),
        (
            "[costmap]\nmap_yaml = \"m.yaml\"\nresolution_m = 0.1\n",
            "costmap.resolution_m",
            "not both",
        ),
        ("[costmap]\ncap = 0\n", "costmap.cap", ""),
        ("[costmap]\ntopic = \"/bad topic\"\n", "costmap.topic", ""),
        (
            "[costmap]\ndds_interfaces = [\"eth0\"]\n",
            "costmap.dds_interfaces[0]",
            "IP address",
        ),
        (
            "[costmap]\nros_domain_id = 240\n",
            "costmap.ros_domain_id",
            "",
        ),
        ("[costmap]\ncost_scale = 0\n", "costmap.cost_scale", ""),
    ] {
        let e = error(extra);
        assert_eq!(e.key.as_deref(), Some(key), "{e}");
        assert!(e.message.contains(says), "{e}");
    }
    // The line of the offending key.
    let e = error("[costmap]\npublish_hz = 0\n");
    let line = format!("{CAMERA}[costmap]\n").lines().count() + 1;
    assert_eq!(e.line, Some(line), "{e}");
}

#[test]
fn floor_points_must_define_a_homography() {
    let three = CAMERA.replace("  { image_px = [0, 240], floor_m = [0, 0] },\n", "");
    let e = parse(&three).unwrap_err();
    assert_eq!(e.key.as_deref(), Some("camera[0].floor_points"));
    assert!(e.message.contains("at least 4"), "{e}");
    let collinear = CAMERA.replace("image_px = [320, 240]", "image_px = [160, 0]");
    let e = parse(&collinear).unwrap_err();
    assert_eq!(e.key.as_deref(), Some("camera[0].floor_points"));
    assert!(
        e.message.contains("image_px points") && e.message.contains("on one line"),
        "{e}"
    );
    let duplicate = CAMERA.replace("floor_m = [4, 0]", "floor_m = [0, 3]");
    let e = parse(&duplicate).unwrap_err();
    assert!(
        e.message.contains("floor_m points") && e.message.contains("the same"),
        "{e}"
    );
}

#[test]
fn segments_and_routes_are_checked_against_each_other() {
    let e = error("[[costmap.segment]]\nname = \"a\"\ncamera = \"cam09\"\nzone = \"door\"\n");
    assert_eq!(e.key.as_deref(), Some("costmap.segment[0].camera"));
    let e = error("[[costmap.segment]]\nname = \"a\"\ncamera = \"cam01\"\nzone = \"window\"\n");
    assert_eq!(e.key.as_deref(), Some("costmap.segment[0].zone"));
    let e = error("[[costmap.segment]]\nname = \"a\"\npolygon_m = [[0, 0], [1, 0]]\n");
    assert_eq!(e.key.as_deref(), Some("costmap.segment[0].polygon_m"));
    let e = error(
        "[[costmap.segment]]\nname = \"a\"\npolygon_m = [[0, 0], [1, 0], [1, 1]]\ncamera = \"cam01\"\nzone = \"door\"\n",
    );
    assert!(
        e.message.contains("either polygon_m, or camera and zone"),
        "{e}"
    );
    let seg = "[[costmap.segment]]\nname = \"a\"\ncamera = \"cam01\"\nzone = \"door\"\n";
    let e = error(&format!(
        "{seg}[[costmap.segment]]\nname = \"a\"\ncamera = \"cam01\"\nzone = \"door\"\n"
    ));
    assert_eq!(e.key.as_deref(), Some("costmap.segment[1].name"));
    let e = error(&format!(
        "{seg}[[costmap.route]]\nname = \"r\"\nsegments = [\"a\", \"b\"]\n"
    ));
    assert_eq!(e.key.as_deref(), Some("costmap.route[0].segments[1]"));
    assert!(e.message.contains("\"b\""), "{e}");
    let e = error(&format!(
        "{seg}[[costmap.route]]\nname = \"r\"\nsegments = []\n"
    ));
    assert_eq!(e.key.as_deref(), Some("costmap.route[0].segments"));
    parse(&format!(
        "{CAMERA}{seg}[[costmap.route]]\nname = \"r\"\nsegments = [\"a\"]\n"
    ))
    .unwrap();
    // A camera without zones has the whole view as zone "all".
    let plain = CAMERA.replace(
        "[[camera.zone]]\nname = \"door\"\npolygon = [[0, 0], [64, 0], [64, 64], [0, 64]]\n",
        "",
    );
    parse(&format!(
        "{plain}[[costmap.segment]]\nname = \"a\"\ncamera = \"cam01\"\nzone = \"all\"\n"
    ))
    .unwrap();
    // Floor polygons need a camera on the floor.
    let unlocated = plain.split("floor_points").next().unwrap().to_string();
    let e = parse(&format!(
        "{unlocated}\n[[costmap.segment]]\nname = \"a\"\npolygon_m = [[0, 0], [1, 0], [1, 1]]\n"
    ))
    .unwrap_err();
    assert!(e.message.contains("floor_points"), "{e}");
}

#[test]
fn the_costmap_section_survives_a_rewrite() {
    let text = format!(
        "{CAMERA}[costmap]\norigin_x_m = -2.5\norigin_y_m = 1.0\nresolution_m = 0.05\nwidth_cells = 80\nheight_cells = 60\nros_domain_id = 7\ndds_interfaces = [\"127.0.0.1\"]\ncap = 90\n\n[[costmap.segment]]\nname = \"a\"\npolygon_m = [[0, 0], [1, 0], [1, 1]]\n\n[[costmap.route]]\nname = \"r\"\nsegments = [\"a\"]\n"
    );
    let c = parse(&text).unwrap();
    let again = parse(&toml::to_string_pretty(&c).unwrap()).unwrap();
    assert_eq!(again.costmap.width_cells, Some(80));
    assert_eq!(again.costmap.origin_x_m, Some(-2.5));
    assert_eq!(again.costmap.ros_domain_id, Some(7));
    assert_eq!(again.costmap.cap, 90);
    assert_eq!(
        again.costmap.segments[0].polygon_m,
        c.costmap.segments[0].polygon_m
    );
    assert_eq!(again.costmap.routes[0].segments, vec!["a".to_string()]);
    assert_eq!(again.cameras[0].floor_points, c.cameras[0].floor_points);
    // And the grid it describes.
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("site.toml"), &text).unwrap();
    let loaded = Config::load(&dir.path().join("site.toml")).unwrap();
    let g = MapGrid::from_config(&loaded).unwrap().unwrap();
    assert_eq!(
        (g.width, g.height, g.resolution, g.origin_x, g.origin_y),
        (80, 60, 0.05, -2.5, 1.0)
    );
}
