//! One process per stage serving several cameras (`--camera a,b,c`): every camera
//! keeps its own node and streams, and one camera that fails for good does not
//! take the others down.

use std::time::{Duration, Instant};

use isochron_runtime::health::exit;
use isochron_runtime::ipc::{Motion, StreamSubscriber, node_census};
use isochron_tests::{TestSite, VTEST_FRAMES, eventually, vtest};
use isochron_wire::{CameraId, Stream};

const START: &str = "2026-03-02T07:00:00Z";

/// Motion samples per camera until each camera's end of stream (exclusive),
/// checked against the camera they claim to be from. Reads all cameras at once: a
/// lossless publisher waits for the slowest reader.
fn count_until_end(cameras: &[(&str, StreamSubscriber<Motion>)], timeout: Duration) -> Vec<u64> {
    let deadline = Instant::now() + timeout;
    let mut counts = vec![0u64; cameras.len()];
    let mut ended = vec![false; cameras.len()];
    while ended.contains(&false) {
        assert!(
            Instant::now() < deadline,
            "no end of stream on every camera: {counts:?} samples, ended {ended:?}"
        );
        std::thread::sleep(Duration::from_millis(20));
        for (i, (camera, motion)) in cameras.iter().enumerate() {
            let id = CameraId::new(camera).unwrap();
            while let Some(sample) = motion.receive().unwrap() {
                let header = *sample.user_header();
                header
                    .validate(&id, sample.payload().len())
                    .unwrap_or_else(|e| panic!("{camera} sample {}: {e}", counts[i]));
                if header.preamble.is_end_of_stream() {
                    ended[i] = true;
                } else {
                    counts[i] += 1;
                }
            }
        }
    }
    counts
}

#[test]
fn one_process_per_stage_serves_several_cameras_and_a_broken_one_stops_alone() {
    let camera = |id: &str, source: &str| {
        format!(
            "[[camera]]\nid = \"{id}\"\nsource = \"{source}\"\nspeed = \"max\"\nstart = \"{START}\"\n\n"
        )
    };
    let video = vtest().display().to_string();
    let site = TestSite::new(
        "scale-multi",
        &format!(
            "[ipc]\nlossless = true\n\n{}{}{}",
            camera("cam01", &video),
            camera("cam02", &video),
            camera("cam03", "missing.avi"),
        ),
    );
    let ipc = site.ipc("subscriber");
    let subscribers: Vec<_> = ["cam01", "cam02"]
        .into_iter()
        .map(|cam| (cam, ipc.subscriber::<Motion>(cam).unwrap()))
        .collect();
    let motion = site.spawn("isochron-motion", &["--camera", "cam01,cam02"]);
    eventually(Duration::from_secs(20), || {
        let both = ipc.subscriber_count("cam01", Stream::Frames)? >= 1
            && ipc.subscriber_count("cam02", Stream::Frames)? >= 1;
        both.then_some(())
    })
    .unwrap_or_else(|| {
        panic!(
            "motion never subscribed to both cameras\n{}",
            motion.stderr()
        )
    });
    let census = node_census(false).unwrap();
    for cam in ["cam01", "cam02"] {
        let name = format!("{}/motion/{cam}", site.prefix);
        assert!(
            census.alive.contains(&name),
            "each camera has its own node: {name} not in {:?}",
            census.alive
        );
    }

    // cam03's file is missing: that camera stops, the other two run to the end.
    let mut capture = site.spawn("isochron-capture", &["--camera", "cam01,cam02,cam03"]);
    let counts = count_until_end(&subscribers, Duration::from_secs(240));
    for (cam, n) in ["cam01", "cam02"].into_iter().zip(counts) {
        println!("{cam}: {n} motion samples from {VTEST_FRAMES} frames");
        // Every camera runs to its end of stream, and lossless: every frame pair
        // gives a sample. A camera cut short by its neighbour fails.
        assert!(
            (VTEST_FRAMES - 1..=VTEST_FRAMES).contains(&n),
            "{cam}: {n} motion samples from {VTEST_FRAMES} frames\ncapture:\n{}\nmotion:\n{}",
            capture.stderr(),
            motion.stderr()
        );
    }
    let done = capture.finish(Duration::from_secs(30));
    assert_eq!(
        done.status.code(),
        Some(exit::NO_INPUT),
        "the missing file decides the exit code\n{}",
        done.stderr
    );
    assert!(
        done.stderr.contains("missing.avi"),
        "the error names the file\n{}",
        done.stderr
    );
}

#[test]
fn sigterm_stops_every_camera_of_a_multi_camera_process_at_once() {
    let video = vtest().display().to_string();
    let cameras: String = ["cam01", "cam02", "cam03"]
        .iter()
        .map(|id| format!("[[camera]]\nid = \"{id}\"\nsource = \"{video}\"\nloop = true\n\n"))
        .collect();
    let site = TestSite::new("scale-term", &cameras);
    let list = ["--camera", "cam01,cam02,cam03"];
    let mut procs: Vec<_> = [
        "isochron-gate",
        "isochron-cascade",
        "isochron-motion",
        "isochron-capture",
    ]
    .into_iter()
    .map(|binary| (binary, site.spawn(binary, &list)))
    .collect();
    let ours = |names: &[String]| -> usize {
        names
            .iter()
            .filter(|n| n.starts_with(&format!("{}/", site.prefix)))
            .count()
    };
    eventually(Duration::from_secs(30), || {
        (ours(&node_census(false).ok()?.alive) == 12).then_some(())
    })
    .expect("a node per camera and stage");
    std::thread::sleep(Duration::from_secs(1)); // frames flowing

    for (binary, proc) in &mut procs {
        proc.signal(libc::SIGTERM);
        let asked = Instant::now();
        let status = proc
            .wait(Duration::from_secs(15))
            .unwrap_or_else(|| panic!("{binary} did not stop on SIGTERM\n{}", proc.stderr()));
        println!("{binary}: stopped in {:?}", asked.elapsed());
        assert_eq!(status.code(), Some(0), "{binary}\n{}", proc.stderr());
        // At most the detections in progress finish first (a second or two on a
        // loaded machine), never every queued one: well inside systemd's stop timeout.
        assert!(
            asked.elapsed() < Duration::from_secs(5),
            "{binary}: every camera thread stops at once, took {:?}",
            asked.elapsed()
        );
    }
    let census = node_census(false).unwrap();
    assert_eq!(ours(&census.alive), 0, "nodes left: {:?}", census.alive);
    assert_eq!(ours(&census.dead_left), 0, "stale: {:?}", census.dead_left);
}
