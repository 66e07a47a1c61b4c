//! What a newcomer meets first: the `isochron` command given a wrong value, a
//! file that is not there, a camera that is not configured, too little data.
//! Each ends at once with one line that names the flag or file and what was
//! expected, the exit code of the shared table (docs/operating.md, "Exit codes"),
//! and no output file left behind.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use isochron_tests::{Finished, TestSite, repo_root, vtest};
use serde_json::Value;

/// Every file and directory under `dir`.
/// The files under `dir`, but SQLite's own `-wal` and `-shm` beside a store it
/// opened (they are the store's, not an output of the command).
fn files_under(dir: &Path) -> BTreeSet<PathBuf> {
    let mut found = BTreeSet::new();
    let mut todo = vec![dir.to_path_buf()];
    while let Some(d) = todo.pop() {
        for entry in std::fs::read_dir(&d).into_iter().flatten().flatten() {
            let path = entry.path();
            if path.is_dir() {
                todo.push(path.clone());
            }
            let name = path.to_string_lossy();
            if !name.ends_with("-wal") && !name.ends_with("-shm") {
                found.insert(path);
            }
        }
    }
    found
}

/// Runs `isochron args` on `site` (`{config}` and `{dir}` in an argument stand
/// for the site's config file and directory), which must fail with `code` and
/// one line of stderr containing each of `words`, and leave no new file in the
/// site's directory.
fn fails(site: &TestSite, args: &[&str], code: i32, words: &[&str]) -> Finished {
    let config = site.config_path().display().to_string();
    let dir = site.dir.path().display().to_string();
    let args: Vec<String> = args
        .iter()
        .map(|a| a.replace("{config}", &config).replace("{dir}", &dir))
        .collect();
    let before = files_under(site.dir.path());
    let done = site.isochron(&args, Duration::from_secs(60));
    assert_eq!(
        done.status.code(),
        Some(code),
        "isochron {args:?}\nstdout:\n{}\nstderr:\n{}",
        done.stdout,
        done.stderr
    );
    // One line of isochron's own (a decoder library may say more before it).
    assert_eq!(
        done.stderr
            .lines()
            .filter(|l| l.starts_with("isochron"))
            .count(),
        1,
        "isochron {args:?}: one line\n{}",
        done.stderr
    );
    for word in words {
        assert!(
            done.stderr.contains(word),
            "isochron {args:?}: no '{word}' in\n{}",
            done.stderr
        );
    }
    assert!(!done.stderr.contains("panicked"), "{}", done.stderr);
    let after = files_under(site.dir.path());
    let left: Vec<&PathBuf> = after.difference(&before).collect();
    assert!(left.is_empty(), "isochron {args:?} left {left:?}");
    done
}

/// A site with config/demo.toml's camera (cam01 on vtest.avi, with its floor
/// points), cost map and routes (`north`, `south`).
fn site(name: &str) -> TestSite {
    TestSite::new(name, &demo_body())
}

#[test]
fn a_bad_flag_value_is_64_and_names_the_flag() {
    let site = site("front-usage");
    let video = vtest().display().to_string();
    let out = site.path("out").display().to_string();
    #[rustfmt::skip]
    let table: &[(&[&str], &[&str])] = &[
        (&["plan", "offline", "--config", "{config}", "--route", "north", "--day", "funday"], &["--day", "'funday'", "mon .. sun"]),
        (&["plan", "offline", "--config", "{config}", "--route", "north", "--between", "25:00", "10:00"], &["--between", "'25:00'", "HH:MM"]),
        (&["plan", "offline", "--config", "{config}", "--route", "north", "--step", "5s"], &["--step", "'5s'"]),
        (&["tap", "cam01", "bogus", "--config", "{config}"], &["'bogus'", "frames, motion, activity, events, detections"]),
        (&["replay", &video, "--out", &out, "--speed=-1"], &["--speed", "'-1'", "> 0"]),
        (&["replay", &video, "--out", &out, "--start", "yesterday"], &["--start", "'yesterday'", "RFC 3339"]),
        (&["costmap", "snapshot", "--config", "{config}", "--at", "10:00", "--day", "funday", "--out", "{dir}/x.png"], &["--day", "'funday'"]),
        (&["costmap", "snapshot", "--config", "{config}", "--at", "25:00", "--out", "{dir}/x.png"], &["--at", "'25:00'"]),
        (&["keystore", "robot", "{dir}/keys", "r1", "--config", "{config}", "--days", "0"], &["--days", "'0'", "1..=36500"]),
        (&["store", "export", "--store", "{dir}", "--camera", "cam01", "--block", "a,b"], &["--block", "X,Y"]),
        (&["store", "backtest", "--counts", "{dir}/c.csv", "--cycle", "monthly"], &["--cycle", "daily"]),
        (&["plot", "heatmap", "--store", "{dir}", "--camera", "cam01", "--out", "{dir}/h.png", "--day", "someday"], &["--day", "workday or rest"]),
    ];
    for (args, words) in table {
        fails(&site, args, isochron_exit::USAGE, words);
    }
    // clap's other errors (an unknown flag) keep clap's code, 2.
    let done = site.isochron(&["plan", "offline", "--bogus"], Duration::from_secs(30));
    assert_eq!(done.status.code(), Some(2), "{}", done.stderr);
}

/// Every flag that takes seconds goes through one parser: a value that is not
/// finite, negative, or over a year is refused with 64 naming the flag, never
/// a panic converting it to a duration.
#[test]
fn a_duration_flag_out_of_range_is_64_and_never_a_panic() {
    let site = site("front-seconds");
    let video = vtest().display().to_string();
    let out = site.path("out").display().to_string();
    #[rustfmt::skip]
    let table: &[(&[&str], &str)] = &[
        (&["tap", "cam01", "frames", "--config", "{config}", "--timeout", "1e30"], "--timeout"),
        (&["tap", "cam01", "frames", "--config", "{config}", "--timeout", "NaN"], "--timeout"),
        (&["tap", "cam01", "frames", "--config", "{config}", "--timeout=-1"], "--timeout"),
        (&["costmap", "snapshot", "--config", "{config}", "--out", "{dir}/x.png", "--timeout", "inf"], "--timeout"),
        (&["plan", "graph", "--config", "{config}", "--from", "1", "--to", "2", "--timeout", "1e30"], "--timeout"),
        (&["plan", "now", "--config", "{config}", "--routes", "north", "--timeout", "0"], "--timeout"),
        (&["record", "--config", "{config}", "--out", "{dir}/r.mcap", "--duration", "1e30"], "--duration"),
        (&["replay", &video, "--out", &out, "--stall-timeout-s", "1e30"], "--stall-timeout-s"),
        (&["up", "--config", "{config}", "--watchdog-s", "0"], "--watchdog-s"),
        (&["up", "--config", "{config}", "--status-every-s", "NaN"], "--status-every-s"),
    ];
    for (args, flag) in table {
        fails(
            &site,
            args,
            isochron_exit::USAGE,
            &[flag, "expected seconds"],
        );
    }
}

#[test]
fn a_missing_input_file_is_66_and_names_it() {
    let site = site("front-missing");
    let out = site.path("out").display().to_string();
    #[rustfmt::skip]
    let table: &[(&[&str], &[&str])] = &[
        (&["replay", "{dir}/nonexist.avi", "--out", &out], &["the video", "nonexist.avi: no such file"]),
        (&["store", "backtest", "--counts", "{dir}/nofile.csv"], &["--counts", "nofile.csv: no such file"]),
        (&["store", "info", "--store", "{dir}/nonexist", "--camera", "cam01"], &["--store", "nonexist: no such file"]),
        (&["store", "export", "--store", "{dir}", "--camera", "cam01"], &["--store", "without a store of camera 'cam01'"]),
        (&["keystore", "robot", "{dir}/keys", "r1", "--config", "{config}"], &["ca.key.pem is missing", "keystore init"]),
    ];
    for (args, words) in table {
        fails(&site, args, isochron_exit::NO_INPUT, words);
    }
}

/// `--out` naming a device, a FIFO or a symbolic link: 64 before any work, and
/// the thing named is still what it was (writing to a temporary file and
/// renaming it would have replaced it by a regular file).
#[test]
fn an_output_that_is_a_device_fifo_or_link_is_64_and_left_as_it_was() {
    let site = site("front-out");
    let store = site.path("cam01.isochron.sqlite");
    wednesday_store(&store, "cam01", isochron_config::clock::Cycle::Daily);
    let target = site.path("kept.csv");
    std::fs::write(&target, "kept\n").unwrap();
    std::os::unix::fs::symlink(&target, site.path("link.csv")).unwrap();
    let fifo = site.path("fifo.csv");
    assert!(
        std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap()
            .success()
    );
    let export = [
        "store",
        "export",
        "--store",
        "{dir}/cam01.isochron.sqlite",
        "--camera",
        "cam01",
        "--out",
    ];
    #[rustfmt::skip]
    let table: &[(&[&str], &str)] = &[
        (&["/dev/full"], "/dev/full: a character device"),
        (&["{dir}/link.csv"], "link.csv: a symbolic link (to "),
        (&["{dir}/fifo.csv"], "fifo.csv: a FIFO"),
    ];
    for (out, said) in table {
        let args: Vec<&str> = export.iter().chain(out.iter()).copied().collect();
        fails(
            &site,
            &args,
            isochron_exit::USAGE,
            &["--out", said, "a new file's path"],
        );
    }
    fails(
        &site,
        &[
            "record",
            "--config",
            "{config}",
            "--out",
            "/dev/full",
            "--duration",
            "1",
        ],
        isochron_exit::USAGE,
        &["--out /dev/full: a character device"],
    );
    use std::os::unix::fs::FileTypeExt;
    let kind = |p: &Path| std::fs::symlink_metadata(p).unwrap().file_type();
    assert!(kind(Path::new("/dev/full")).is_char_device());
    assert!(kind(&site.path("link.csv")).is_symlink());
    assert!(kind(&fifo).is_fifo());
    assert_eq!(std::fs::read_to_string(&target).unwrap(), "kept\n");
}

/// A name the command line gives that the site does not configure is 64 for
/// every command; a config that lacks what a command needs is 78.
#[test]
fn an_unconfigured_route_or_segment_is_64_and_a_config_without_a_box_id_78() {
    let site = site("front-names");
    #[rustfmt::skip]
    let table: &[(&[&str], i32, &[&str])] = &[
        (&["plan", "offline", "--config", "{config}", "--route", "zzz"], isochron_exit::USAGE, &["--route", "no route 'zzz'", "north"]),
        (&["plan", "now", "--config", "{config}", "--routes", "zzz"], isochron_exit::USAGE, &["--routes", "no route 'zzz'", "north"]),
        (&["plot", "daily", "--config", "{config}", "--segment", "nosuch", "--out", "{dir}/d.png"], isochron_exit::USAGE, &["no segment 'nosuch'"]),
        (&["keystore", "enclave", "{dir}/keys", "--config", "{config}"], isochron_exit::CONFIG, &["link.box_id is not set"]),
    ];
    for (args, code, words) in table {
        fails(&site, args, *code, words);
    }
}

/// replay refusing its config or `--camera` creates nothing: not even `--out`.
#[test]
fn replay_refused_for_its_config_or_camera_creates_no_output_directory() {
    let site = site("front-replay-out");
    let video = vtest().display().to_string();
    std::fs::write(site.path("broken.toml"), "[site]\nname = 3\n").unwrap();
    #[rustfmt::skip]
    let table: &[(&[&str], i32, &str)] = &[
        (&["--out", "{dir}/out", "--config", "{dir}/broken.toml"], isochron_exit::CONFIG, "broken.toml"),
        (&["--out", "{dir}/out", "--config", "{dir}/none.toml"], isochron_exit::CONFIG, "none.toml"),
        (&["--out", "{dir}/out", "--config", "{config}", "--camera", "cam09"], isochron_exit::USAGE, "cam09"),
        (&["--out", "{config}"], isochron_exit::USAGE, "not a directory"),
    ];
    for (flags, code, said) in table {
        let args: Vec<&str> = ["replay", video.as_str()]
            .into_iter()
            .chain(flags.iter().copied())
            .collect();
        fails(&site, &args, *code, &[said]);
    }
}

#[test]
fn a_directory_given_as_the_video_is_refused_before_anything_starts() {
    let site = site("front-dir");
    let dir = site.path("frames");
    std::fs::create_dir(&dir).unwrap();
    let out = site.path("out").display().to_string();
    let started = Instant::now();
    let done = fails(
        &site,
        &["replay", dir.to_str().unwrap(), "--out", &out],
        isochron_exit::NO_INPUT,
        &["the video", "frames: a directory", "expected a video file"],
    );
    // Nothing started: no service, no log, no output directory (checked by
    // `fails`), and no wait for a group.
    assert!(!done.stdout.contains("replay:"), "{}", done.stdout);
    assert!(started.elapsed() < Duration::from_secs(20));
}

#[test]
fn replay_of_an_empty_video_passes_on_capture_s_failure_and_writes_its_summary() {
    let site = site("front-empty");
    let video = site.path("empty.avi");
    std::fs::write(&video, b"").unwrap();
    let out = site.path("out");
    let config = site.config_path();
    let done = site.isochron(
        &[
            "replay",
            video.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--config",
            config.to_str().unwrap(),
        ],
        Duration::from_secs(300),
    );
    assert_eq!(
        done.status.code(),
        Some(isochron_exit::DATA),
        "stdout:\n{}\nstderr:\n{}",
        done.stdout,
        done.stderr
    );
    let line = done
        .stderr
        .lines()
        .find(|l| l.starts_with("isochron: "))
        .unwrap_or_else(|| panic!("no error line in\n{}", done.stderr));
    // The stage, its exit code, its reason (from its log) and where the log is.
    for word in [
        "capture/cam01 exited with 65",
        "empty.avi",
        "logs/capture-cam01.log",
    ] {
        assert!(line.contains(word), "no '{word}' in {line}");
    }
    assert!(!line.contains("Failed {"), "{line}");
    let summary: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let failure = summary["failure"].as_str().unwrap_or_default();
    assert!(
        failure.contains("capture/cam01 exited with 65"),
        "{summary}"
    );
    assert_eq!(summary["counts"]["frames"], 0, "{summary}");
}

#[test]
fn the_overlay_is_a_png_and_never_a_partial_file() {
    let site = site("front-overlay");
    // Not a .png: refused before anything is written.
    fails(
        &site,
        &[
            "costmap",
            "check",
            "--config",
            "{config}",
            "--camera",
            "cam01",
            "--overlay",
            "{dir}/x.jpg",
        ],
        isochron_exit::USAGE,
        &["--overlay", "x.jpg", "expected a .png file name"],
    );
    // A frame that is missing (66) or no picture (65): neither x.png nor a
    // temporary file is left.
    fails(
        &site,
        &[
            "costmap",
            "check",
            "--config",
            "{config}",
            "--camera",
            "cam01",
            "--overlay",
            "{dir}/x.png",
            "--frame",
            "{dir}/nofile.png",
        ],
        isochron_exit::NO_INPUT,
        &["--frame", "nofile.png: no such file"],
    );
    std::fs::write(site.path("noise.png"), b"not a picture at all").unwrap();
    fails(
        &site,
        &[
            "costmap",
            "check",
            "--config",
            "{config}",
            "--camera",
            "cam01",
            "--overlay",
            "{dir}/x.png",
            "--frame",
            "{dir}/noise.png",
        ],
        isochron_exit::DATA,
        &["noise.png", "not a video or image"],
    );
    // A good one is written whole, as a PNG.
    let out = site.path("good.png");
    let config = site.config_path().display().to_string();
    let done = site.isochron(
        &[
            "costmap",
            "check",
            "--config",
            &config,
            "--camera",
            "cam01",
            "--overlay",
            out.to_str().unwrap(),
        ],
        Duration::from_secs(60),
    );
    assert_eq!(done.status.code(), Some(0), "{}", done.stderr);
    let bytes = std::fs::read(&out).unwrap();
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
    let strays: Vec<PathBuf> = files_under(site.dir.path())
        .into_iter()
        .filter(|p| p.file_name().unwrap().to_string_lossy().starts_with('.'))
        .collect();
    assert!(strays.is_empty(), "{strays:?}");
}

/// config/demo.toml's camera and calibration on vtest.avi.
fn demo_body() -> String {
    let text = std::fs::read_to_string(repo_root().join("config/demo.toml")).unwrap();
    let body = &text[text.find("[[camera]]").expect("demo has a camera")..];
    body.replace(
        "source = \"../data/vtest.avi\"",
        &format!("source = \"{}\"", vtest().display()),
    )
}

#[test]
fn tap_of_a_camera_that_is_not_configured_fails_at_once_naming_the_cameras() {
    let site = site("front-tap");
    let started = Instant::now();
    fails(
        &site,
        &[
            "tap",
            "cam09",
            "frames",
            "--config",
            "{config}",
            "--timeout",
            "30",
        ],
        isochron_exit::USAGE,
        &["no camera 'cam09'", "configured: cam01"],
    );
    assert!(
        started.elapsed() < Duration::from_secs(20),
        "it did not wait for the timeout"
    );
}

/// A store of `camera` with the `cycle`, a busy morning on one day, and its last
/// minute on Wednesday 2026-01-07 07:00 UTC.
fn wednesday_store(path: &Path, camera: &str, cycle: isochron_config::clock::Cycle) {
    use isochron_store::{MinuteCommit, Store, StoreMeta};
    use isochron_wire::geometry::BlockGrid;
    let meta = StoreMeta::new(camera, BlockGrid::new(64, 48, 16), cycle, 0);
    let mut store = Store::open_or_create(path, &meta).unwrap();
    for t in 6 * 60..8 * 60 {
        store.teach(t, 1, vec![0.05; 12]).unwrap();
    }
    let minute =
        isochron_config::clock::parse_rfc3339("2026-01-07T07:00:00Z").unwrap() / 60_000_000_000;
    store
        .commit_minute(&MinuteCommit {
            minute,
            bins: &[],
            baseline: None,
        })
        .unwrap();
}

/// A store on read-only media (a tmpfs remounted read-only: a write-protected
/// card) is read by every command that only reads: info, export, plot.
#[test]
fn a_store_on_read_only_media_is_read() {
    let site = site("front-ro");
    let card = site.path("card");
    let Some(disk) = isochron_tests::Tmpfs::mount(&card, "4m") else {
        return;
    };
    let store = card.join("cam01.isochron.sqlite");
    wednesday_store(&store, "cam01", isochron_config::clock::Cycle::Daily);
    assert!(disk.remount_read_only(), "remount read-only");
    assert!(
        std::fs::write(card.join("probe"), b"").is_err(),
        "the card is read-only"
    );
    let arg = store.display().to_string();
    let plot = site.path("daily.png").display().to_string();
    for args in [
        &["store", "info", "--store", &arg, "--camera", "cam01"][..],
        &["store", "export", "--store", &arg, "--camera", "cam01"],
        &[
            "plot", "daily", "--store", &arg, "--camera", "cam01", "--out", &plot,
        ],
    ] {
        let done = site.isochron(args, Duration::from_secs(60));
        assert!(done.status.success(), "isochron {args:?}: {}", done.stderr);
        if args[1] == "export" {
            assert!(done.stdout.lines().count() > 120, "{}", done.stdout);
        }
    }
    assert!(std::fs::metadata(&plot).unwrap().len() > 1000);
}

#[test]
fn store_info_labels_the_last_minute_with_its_weekday() {
    let site = site("front-info");
    let store = site.path("cam01.isochron.sqlite");
    wednesday_store(&store, "cam01", isochron_config::clock::Cycle::Weekly);
    let arg = store.display().to_string();
    let done = site.isochron(
        &["store", "info", "--store", &arg, "--camera", "cam01"],
        Duration::from_secs(30),
    );
    assert!(done.status.success(), "{}", done.stderr);
    let line = done
        .stdout
        .lines()
        .find(|l| l.starts_with("progress"))
        .unwrap_or_else(|| panic!("no progress line in\n{}", done.stdout));
    assert!(
        line.contains("2026-01-07T07:00:00.000Z (Wed 07:00 UTC)"),
        "{line}"
    );
}

#[test]
fn store_export_says_which_header_it_writes() {
    let site = site("front-export");
    let help = site.isochron(&["store", "export", "--help"], Duration::from_secs(30));
    assert!(help.status.success(), "{}", help.stderr);
    assert!(
        help.stdout.contains("minute_of_day") && help.stdout.contains("minute_of_week"),
        "{}",
        help.stdout
    );
    let store = site.path("cam01.isochron.sqlite");
    wednesday_store(&store, "cam01", isochron_config::clock::Cycle::Weekly);
    let arg = store.display().to_string();
    let done = site.isochron(
        &["store", "export", "--store", &arg, "--camera", "cam01"],
        Duration::from_secs(30),
    );
    assert!(done.status.success(), "{}", done.stderr);
    assert_eq!(
        done.stdout.lines().next(),
        Some("minute_of_week,mean,sigma,count")
    );
}

#[test]
fn a_store_of_another_camera_is_64_naming_both() {
    let site = site("front-other");
    wednesday_store(
        &site.path("cam01.isochron.sqlite"),
        "cam02",
        isochron_config::clock::Cycle::Daily,
    );
    for command in [&["plot", "heatmap"][..], &["store", "info"]] {
        let mut args = command.to_vec();
        args.extend([
            "--store",
            "{dir}/cam01.isochron.sqlite",
            "--camera",
            "cam01",
        ]);
        if command[0] == "plot" {
            args.extend(["--out", "{dir}/heat.png"]);
        }
        fails(
            &site,
            &args,
            isochron_exit::USAGE,
            &["camera 'cam02', not of --camera cam01"],
        );
    }
}

#[test]
fn a_backtest_of_too_few_counts_is_65_and_says_how_many_rows() {
    let site = site("front-backtest");
    std::fs::write(
        site.path("short.csv"),
        "time,a\n2026-03-02T06:00,1\n2026-03-02T07:00,2\n",
    )
    .unwrap();
    fails(
        &site,
        &["store", "backtest", "--counts", "{dir}/short.csv"],
        isochron_exit::DATA,
        &[
            "short.csv",
            "2 rows over 1 day",
            "at least 8 days",
            "at least 192 rows",
        ],
    );
}

/// A model of the week that learned Monday only: asked for Sunday, the map and
/// the plan say so, 66, instead of a blank map or "no long-term data".
#[test]
fn a_day_the_stores_never_learned_is_66_naming_the_days_they_did() {
    let site = site("front-day");
    std::fs::create_dir(site.path("state")).unwrap();
    wednesday_store(
        &site.path("state/cam01.isochron.sqlite"),
        "cam01",
        isochron_config::clock::Cycle::DayTypes,
    );
    #[rustfmt::skip]
    let table: &[&[&str]] = &[
        &["costmap", "snapshot", "--config", "{config}", "--at", "07:00", "--day", "sun", "--out", "{dir}/sun.png"],
        &["plan", "offline", "--config", "{config}", "--route", "north", "--day", "sun"],
    ];
    for args in table {
        fails(
            &site,
            args,
            isochron_exit::NO_INPUT,
            &["nothing learned for sun", "learned mon"],
        );
    }
    let out = site.path("mon.png").display().to_string();
    let config = site.config_path().display().to_string();
    let monday = site.isochron(
        &[
            "costmap", "snapshot", "--config", &config, "--at", "07:00", "--day", "mon", "--out",
            &out,
        ],
        Duration::from_secs(60),
    );
    assert!(monday.status.success(), "{}", monday.stderr);
}
