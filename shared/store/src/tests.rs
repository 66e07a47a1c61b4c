use super::*;
use isochron_exit::Classify;

/// Commits one minute, which must succeed.
fn commit(store: &mut Store, minute: i64, bin: Option<&Bin>, baseline: Option<&Baseline>) {
    store
        .commit_minute(&MinuteCommit {
            minute,
            bins: bin.map(std::slice::from_ref).unwrap_or_default(),
            baseline,
        })
        .unwrap();
}

fn meta(camera: &str) -> StoreMeta {
    StoreMeta::new(
        camera,
        BlockGrid::new(64, 48, 16),
        Cycle::Daily,
        1_700_000_000_000_000_000,
    )
}

fn bin(t_star: u32, count: u32, base: f32) -> Bin {
    Bin {
        t_star,
        count,
        last_minute: 29_000_000 + t_star as i64,
        mean: (0..12).map(|k| base + k as f32).collect(),
        var: (0..12).map(|k| 0.5 * k as f32).collect(),
    }
}

fn baseline() -> Baseline {
    Baseline {
        capture_ns: 42,
        frames: 1000,
        frame_rate: 29.97,
        level: vec![0.25; 12],
    }
}

#[test]
fn round_trip_bins_baseline_progress() {
    let dir = tempfile::tempdir().unwrap();
    let path = store_path(dir.path(), "cam01");
    assert_eq!(path.file_name().unwrap(), "cam01.isochron.sqlite");
    let mut store = Store::open_or_create(&path, &meta("cam01")).unwrap();
    assert_eq!(store.read_bin(10).unwrap(), None);
    let b10 = bin(10, 1, 0.5);
    let b20 = bin(20, 3, 1.5);
    let bl = baseline();
    commit(&mut store, 100, Some(&b10), Some(&bl));
    commit(&mut store, 101, Some(&b20), None);
    commit(&mut store, 102, None, None);
    drop(store);

    let reader = Store::open_read_only(&path, "cam01").unwrap();
    assert_eq!(reader.meta(), &meta("cam01"));
    assert_eq!(reader.read_bin(10).unwrap(), Some(b10.clone()));
    assert_eq!(reader.read_bin(20).unwrap(), Some(b20.clone()));
    let model = reader.read_model().unwrap();
    assert_eq!(model.bins.len(), 1440);
    assert_eq!(model.learned().count(), 2);
    assert_eq!(model.bin(20).as_deref(), Some(&b20));
    assert_eq!(reader.read_baseline().unwrap(), Some(bl));
    assert_eq!(
        reader.progress().unwrap(),
        Progress {
            last_minute: Some(102),
            committed: 2,
            skipped: 1
        }
    );
    let report = reader.verify().unwrap();
    assert_eq!(report.bins, 2);
    assert!(report.baseline);
    assert!((b20.sigma(2) - 1.0).abs() < 1e-6);
    // Reopening for writing keeps everything; writing read-only is refused.
    let w = Store::open_writer(&path, "cam01", Cycle::Daily).unwrap();
    assert_eq!(w.read_bin(10).unwrap(), Some(b10));
    let mut reader = reader;
    assert!(matches!(
        reader.commit_minute(&MinuteCommit {
            minute: 1,
            bins: &[],
            baseline: None
        }),
        Err(StoreError::ReadOnly { .. })
    ));
}

#[test]
fn readers_see_commits_while_the_writer_is_open() {
    let dir = tempfile::tempdir().unwrap();
    let path = store_path(dir.path(), "cam01");
    let mut writer = Store::open_or_create(&path, &meta("cam01")).unwrap();
    let reader = Store::open_read_only(&path, "cam01").unwrap();
    for minute in 0..5u32 {
        let b = bin(minute, minute + 1, minute as f32);
        commit(&mut writer, minute as i64, Some(&b), None);
        assert_eq!(reader.read_bin(minute).unwrap(), Some(b));
        assert_eq!(reader.progress().unwrap().last_minute, Some(minute as i64));
    }
}

#[test]
fn foreign_files_get_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    // Missing.
    let missing = dir.path().join("none.isochron.sqlite");
    let err = Store::open_read_only(&missing, "cam01").unwrap_err();
    assert!(matches!(err, StoreError::NotFound { .. }), "{err}");
    assert!(err.to_string().contains("site.state_dir"), "{err}");
    // Not SQLite.
    let text = dir.path().join("text.isochron.sqlite");
    std::fs::write(&text, "minute_of_day,mean\n1,2\n").unwrap();
    let err = Store::open_read_only(&text, "cam01").unwrap_err();
    assert!(matches!(err, StoreError::NotSqlite { .. }), "{err}");
    let msg = err.to_string();
    assert!(msg.contains("text.isochron.sqlite") && msg.contains("minute_of_day"));
    assert!(msg.contains("move it away"), "{msg}");
    let empty = dir.path().join("empty.isochron.sqlite");
    std::fs::write(&empty, "").unwrap();
    let err = Store::open_read_only(&empty, "cam01").unwrap_err();
    assert!(err.to_string().contains("empty"), "{err}");
    // Another application's SQLite database.
    let other = dir.path().join("other.sqlite");
    {
        let c = Connection::open(&other).unwrap();
        c.execute_batch("CREATE TABLE t (x); INSERT INTO t VALUES (1);")
            .unwrap();
    }
    let err = Store::open_read_only(&other, "cam01").unwrap_err();
    assert!(matches!(err, StoreError::Foreign { .. }), "{err}");
    assert!(err.to_string().contains("another application"), "{err}");
    // Another camera's store.
    let path = store_path(dir.path(), "cam02");
    Store::open_or_create(&path, &meta("cam02")).unwrap();
    let err = Store::open_read_only(&path, "cam01").unwrap_err();
    assert!(
        matches!(&err, StoreError::Camera { found, .. } if found == "cam02"),
        "{err}"
    );
    // Another grid.
    let mut wide = meta("cam02");
    wide.grid.frame_width = 80;
    let err = Store::open_or_create(&path, &wide).unwrap_err();
    assert!(matches!(err, StoreError::Grid { .. }), "{err}");
    assert!(err.to_string().contains("4x3"), "{err}");
    // Another cycle.
    let err = Store::open_writer(&path, "cam02", Cycle::Weekly).unwrap_err();
    assert!(matches!(err, StoreError::Cycle { .. }), "{err}");
    // Another format version.
    {
        let c = Connection::open(&path).unwrap();
        c.pragma_update(None, "user_version", 99).unwrap();
    }
    let err = Store::open_read_only(&path, "cam02").unwrap_err();
    assert!(
        matches!(err, StoreError::Version { found: 99, .. }),
        "{err}"
    );
    assert!(err.is_permanent());
}

#[test]
fn damaged_rows_are_detected_never_used() {
    let dir = tempfile::tempdir().unwrap();
    let path = store_path(dir.path(), "cam01");
    let mut store = Store::open_or_create(&path, &meta("cam01")).unwrap();
    let b = bin(7, 2, 0.1);
    let bl = baseline();
    commit(&mut store, 7, Some(&b), Some(&bl));
    drop(store);
    // Flip one byte of the stored mean, as a bad disk sector would.
    {
        let c = Connection::open(&path).unwrap();
        let mut mean: Vec<u8> = c
            .query_row("SELECT mean FROM bins WHERE t_star = 7", [], |r| r.get(0))
            .unwrap();
        mean[5] ^= 0x40;
        c.execute("UPDATE bins SET mean = ?1 WHERE t_star = 7", params![mean])
            .unwrap();
    }
    let reader = Store::open_read_only(&path, "cam01").unwrap();
    let err = reader.read_bin(7).unwrap_err();
    assert!(matches!(err, StoreError::Damaged { .. }), "{err}");
    assert!(err.to_string().contains("bin 7"), "{err}");
    assert!(reader.read_model().is_err());
    assert!(reader.verify().is_err());
    let err = Store::open_writer(&path, "cam01", Cycle::Daily).unwrap_err();
    assert!(
        err.to_string().contains("restore it from a backup"),
        "{err}"
    );
    drop(reader);

    // A truncated blob and a tampered meta row.
    {
        let c = Connection::open(&path).unwrap();
        c.execute("UPDATE bins SET var = x'0000' WHERE t_star = 7", [])
            .unwrap();
    }
    let reader = Store::open_read_only(&path, "cam01").unwrap();
    assert!(matches!(
        reader.read_bin(7),
        Err(StoreError::Damaged { .. })
    ));
    drop(reader);
    {
        let c = Connection::open(&path).unwrap();
        c.execute("UPDATE meta SET value = '8' WHERE key = 'grid_w'", [])
            .unwrap();
    }
    let err = Store::open_read_only(&path, "cam01").unwrap_err();
    assert!(err.to_string().contains("meta"), "{err}");
}

#[test]
fn garbage_in_the_middle_of_the_file_is_detected() {
    let dir = tempfile::tempdir().unwrap();
    let path = store_path(dir.path(), "cam01");
    let mut store = Store::open_or_create(&path, &meta("cam01")).unwrap();
    for t in 0..200 {
        let b = bin(t, 1, t as f32);
        commit(&mut store, t as i64, Some(&b), None);
    }
    drop(store); // checkpoints the WAL into the file
    let mut bytes = std::fs::read(&path).unwrap();
    assert!(bytes.len() > 8192, "{}", bytes.len());
    // Overwrite the middle of the file (past the header page) with noise.
    let mid = bytes.len() / 2;
    let mut x: u32 = 99;
    for b in &mut bytes[mid..mid + 2048] {
        x = x.wrapping_mul(1_103_515_245).wrapping_add(12345);
        *b = (x >> 16) as u8;
    }
    std::fs::write(&path, &bytes).unwrap();
    let result = Store::open_read_only(&path, "cam01").and_then(|s| s.verify());
    let err = result.unwrap_err();
    assert!(matches!(err, StoreError::Damaged { .. }), "{err}");
    assert!(err.to_string().contains(path.to_str().unwrap()), "{err}");
}

#[test]
fn meta_describes_the_block_grid() {
    let m = meta("cam01");
    assert_eq!(m.grid, BlockGrid::new(64, 48, 16));
    assert_eq!((m.grid(), m.blocks()), ("4x3".to_string(), 12));
}

#[test]
fn weekly_stores_have_a_week_of_bins() {
    let dir = tempfile::tempdir().unwrap();
    let path = store_path(dir.path(), "cam01");
    let mut m = meta("cam01");
    m.cycle = Cycle::Weekly;
    let mut store = Store::open_or_create(&path, &m).unwrap();
    let b = bin(10_000, 1, 0.0);
    commit(&mut store, 1, Some(&b), None);
    let model = store.read_model().unwrap();
    assert_eq!(model.bins.len(), 10_080);
    assert_eq!(model.bin(10_000).as_deref(), Some(&b));
    // A bin outside the cycle is refused.
    let bad = bin(10_080, 1, 0.0);
    assert!(
        store
            .commit_minute(&MinuteCommit {
                minute: 2,
                bins: std::slice::from_ref(&bad),
                baseline: None
            })
            .is_err()
    );
}

/// A store of format 1 as isochron wrote it before day types: `meta`'s cycle, no
/// spans table, `user_version` 1.
fn format_1_store(path: &std::path::Path, cycle: Cycle, bins: &[Bin]) {
    let mut m = meta("cam01");
    m.cycle = cycle;
    let mut store = Store::open_or_create(path, &m).unwrap();
    for (i, b) in bins.iter().enumerate() {
        commit(&mut store, 1000 + i as i64, Some(b), None);
    }
    drop(store);
    let conn = rusqlite::Connection::open(path).unwrap();
    conn.execute_batch("DROP TABLE spans; PRAGMA user_version = 1;")
        .unwrap();
}

#[test]
fn a_format_1_store_is_refused_with_the_command_that_converts_it() {
    let dir = tempfile::tempdir().unwrap();
    let path = store_path(dir.path(), "cam01");
    format_1_store(&path, Cycle::Daily, &[bin(10, 4, 0.5)]);
    let e = Store::open_writer(&path, "cam01", Cycle::DayTypes).unwrap_err();
    assert!(matches!(e, StoreError::Version { found: 1, .. }));
    assert!(e.to_string().contains("isochron store migrate"), "{e}");
}

#[test]
fn migrating_keeps_what_was_learned() {
    let dir = tempfile::tempdir().unwrap();
    // A daily model becomes both day types' profiles.
    let path = store_path(dir.path(), "cam01");
    format_1_store(&path, Cycle::Daily, &[bin(10, 4, 0.5)]);
    let rules = crate::Rules::defaults(Cycle::DayTypes);
    let done = crate::migrate::migrate(&path, "cam01", &rules).unwrap();
    assert_eq!((done.from_version, done.to_cycle), (1, Cycle::DayTypes));
    assert!(done.backup.as_ref().unwrap().exists());
    let store = Store::open_writer(&path, "cam01", Cycle::DayTypes).unwrap();
    let model = store.read_model().unwrap();
    assert_eq!(model.learned().count(), 2);
    // Monday and Sunday 00:10 both read the daily minute 10.
    for t in [10, 6 * 1440 + 10] {
        let f = model.bin(t).unwrap();
        assert_eq!((f.t_star, f.count, f.mean[0]), (t, 4, 0.5));
    }
    // The minutes it learned stay learned: replaying them teaches nothing twice.
    assert!(store.spans().contains(29_000_010));
    drop(store);
    // Converting again does nothing.
    let again = crate::migrate::migrate(&path, "cam01", &rules).unwrap();
    assert!(again.backup.is_none());

    // A weekly model keeps its weekdays; each day type is the mix of its days.
    let path = store_path(dir.path(), "cam02");
    let mut weekly = Vec::new();
    for d in 0..7u32 {
        let mut b = bin(d * 1440 + 10, 2, if d < 5 { 1.0 } else { 0.2 });
        b.mean = vec![if d < 5 { 1.0 } else { 0.2 }; 12];
        weekly.push(b);
    }
    let mut m = meta("cam02");
    m.cycle = Cycle::Weekly;
    Store::open_or_create(&path, &m).unwrap();
    let mut store = Store::open_writer(&path, "cam02", Cycle::Weekly).unwrap();
    for (i, b) in weekly.iter().enumerate() {
        commit(&mut store, 5000 + i as i64, Some(b), None);
    }
    drop(store);
    let done = crate::migrate::migrate(&path, "cam02", &rules).unwrap();
    assert_eq!((done.from_version, done.rows), (2, 9));
    let model = Store::open_read_only(&path, "cam02")
        .unwrap()
        .read_model()
        .unwrap();
    let workday = model.row(7 * 1440 + 10).unwrap();
    let rest = model.row(8 * 1440 + 10).unwrap();
    assert_eq!((workday.count, workday.mean[0]), (10, 1.0));
    assert_eq!((rest.count, rest.mean[0]), (4, 0.2));
    assert_eq!(model.row(3 * 1440 + 10).unwrap().mean[0], 1.0);
}
