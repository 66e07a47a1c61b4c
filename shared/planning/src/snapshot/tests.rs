use super::*;

fn grid() -> MapGrid {
    MapGrid {
        origin_x: -1.0,
        origin_y: 2.0,
        yaw: 0.0,
        resolution: 0.5,
        width: 3,
        height: 2,
    }
}

#[test]
fn pgm_round_trips_through_map_server_raw_mode() {
    // Row 0 (at the origin) = [0, 50, -1]; row 1 = [100, 7, 0].
    let cells = [0i8, 50, -1, 100, 7, 0];
    let bytes = pgm_bytes(&grid(), &cells);
    let h = pgm_header(&bytes).unwrap();
    assert_eq!((h.width, h.height, h.max), (3, 2, 255));
    let px = &bytes[h.data_offset..];
    // Top image row is the grid's last row.
    assert_eq!(px, &[100, 7, 0, 0, 50, 255]);
    // Read back the way map_server does in raw mode.
    let mut back = vec![0i8; 6];
    for y in 0..2 {
        for x in 0..3 {
            let v = px[y * 3 + x];
            back[3 * (2 - y - 1) + x] = if v <= 100 { v as i8 } else { -1 };
        }
    }
    assert_eq!(back, cells);
    let yaml = map_yaml(&grid(), "a.pgm", "t");
    assert!(
        yaml.contains("mode: raw") && yaml.contains("origin: [-1, 2, 0]"),
        "{yaml}"
    );
    assert!(yaml.contains("resolution: 0.5"));
}

#[test]
fn snapshot_files_are_written_and_pruned() {
    let dir = tempfile::tempdir().unwrap();
    let cells = [0i8, 50, -1, 100, 7, 0];
    let cover: Vec<u32> = vec![0, 0, NOT_SEEN, 1, 1, 1];
    let seg: &[[f64; 2]] = &[[-1.0, 2.0], [0.0, 2.0], [0.0, 3.0]];
    let s = Snapshot {
        grid: &grid(),
        cells: &cells,
        floor_plan: None,
        coverage: &[&cover],
        camera_ids: &["cam01"],
        segments: &[seg],
        zones: &[vec![[-1.0, 2.0], [0.0, 2.0], [0.0, 3.0]]],
        caption: "expected cost at 08:30",
        stamp: "2026-03-02T07:00:00Z",
    };
    for stem in ["activity-1", "activity-2", "activity-3"] {
        let files = write(dir.path(), stem, &s).unwrap();
        assert!(files.yaml.is_file() && files.pgm.is_file());
        let png = std::fs::read(&files.png).unwrap();
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    }
    // The map_server YAML loads as a grid of the same geometry.
    let g = MapGrid::from_map_yaml(&dir.path().join("activity-3.yaml")).unwrap();
    assert_eq!(g, grid());
    assert_eq!(prune(dir.path(), "activity-", 2).unwrap(), 1);
    assert!(!dir.path().join("activity-1.yaml").exists());
    assert!(dir.path().join("activity-3.pgm").exists());
    // No temporary files are left behind.
    assert!(
        std::fs::read_dir(dir.path()).unwrap().all(|e| !e
            .unwrap()
            .file_name()
            .to_string_lossy()
            .contains(".tmp-"))
    );
}

#[test]
fn floor_plans_load_from_pgm_and_png() {
    let dir = tempfile::tempdir().unwrap();
    let pgm = dir.path().join("f.pgm");
    std::fs::write(&pgm, b"P5\n2 1\n255\n\x00\xff").unwrap();
    let p = FloorPlan::load(&pgm).unwrap();
    assert_eq!((p.width, p.height, p.grey.clone()), (2, 1, vec![0, 255]));
    let png_path = dir.path().join("f.png");
    let mut out = Vec::new();
    {
        let mut e = png::Encoder::new(&mut out, 2, 1);
        e.set_color(png::ColorType::Rgb);
        e.set_depth(png::BitDepth::Eight);
        e.write_header()
            .unwrap()
            .write_image_data(&[0, 0, 0, 30, 60, 90])
            .unwrap();
    }
    std::fs::write(&png_path, out).unwrap();
    let p = FloorPlan::load(&png_path).unwrap();
    assert_eq!(p.grey, vec![0, 60]);
}

#[test]
fn a_long_caption_wraps_at_spaces_and_is_never_cut() {
    let caption = "demo: expected cost at Sun 16:30 (3 days learned)";
    let lines = wrapped(caption, 20);
    assert_eq!(
        lines,
        ["demo: expected cost", "at Sun 16:30 (3 days", "learned)"]
    );
    assert_eq!(lines.join(" "), caption);
    assert!(wrapped("", 20).is_empty());
    assert_eq!(wrapped("abcdef", 4), ["abcd"]);
}
