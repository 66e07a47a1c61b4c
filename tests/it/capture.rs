//! isochron-capture as a separate process, read through iceoryx2 by this test.

use std::time::Duration;

use isochron_config::clock::{NS_PER_S, parse_rfc3339};
use isochron_runtime::ipc::Frames;
use isochron_tests::{Proc, TestSite, VTEST_FRAMES, bin, eventually, read_samples, vtest};
use isochron_wire::{CameraId, FrameHeader, MAGIC, Preamble, Stream};
use opencv::prelude::*;
use opencv::{imgproc, videoio};

const START: &str = "2026-03-02T07:00:00Z";

/// CRC-32 of every frame of vtest.avi as OpenCV itself decodes and greys it.
fn opencv_reference_checksums() -> Vec<u32> {
    let mut cap =
        videoio::VideoCapture::from_file(vtest().to_str().unwrap(), videoio::CAP_ANY).unwrap();
    let (mut bgr, mut gray) = (opencv::core::Mat::default(), opencv::core::Mat::default());
    let mut sums = Vec::new();
    while cap.read(&mut bgr).unwrap() && !bgr.empty() {
        imgproc::cvt_color(&bgr, &mut gray, imgproc::COLOR_BGR2GRAY, 0).unwrap();
        sums.push(crc32fast::hash(gray.data_bytes().unwrap()));
    }
    sums
}

#[test]
fn publishes_every_frame_with_file_clock_and_opencv_pixels() {
    // Subscribed before the producers start: lossless delivery counts from here.
    let (site, _ipc, frames) = TestSite::lossless_vtest::<Frames>("capture-all", START);
    let mut capture = site.spawn("isochron-capture", &["--camera", "cam01"]);

    let start_ns = parse_rfc3339(START).unwrap();
    let mut checksums = Vec::new();
    let ended = read_samples(&frames, "cam01", Duration::from_secs(120), |h, pixels| {
        if h.preamble.is_end_of_stream() {
            assert_eq!(h.preamble.sequence, checksums.len() as u64);
            return false;
        }
        let i = checksums.len() as u64;
        assert_eq!(h.preamble.sequence, i, "sequence must be contiguous");
        assert_eq!(h.source_index, i);
        assert_eq!(
            h.preamble.capture_time_ns,
            start_ns + i as i64 * NS_PER_S / 10,
            "frame {i}: capture time must be start + i/fps"
        );
        assert_eq!((h.width, h.height, h.stride), (768, 576, 768));
        checksums.push(crc32fast::hash(pixels));
        true
    });
    assert!(ended, "no end of stream after {} frames", checksums.len());
    assert_eq!(checksums.len() as u64, VTEST_FRAMES);
    let reference = opencv_reference_checksums();
    assert_eq!(reference.len() as u64, VTEST_FRAMES);
    let mismatched: Vec<usize> = (0..reference.len())
        .filter(|&i| reference[i] != checksums[i])
        .collect();
    assert!(
        mismatched.is_empty(),
        "pixels differ from OpenCV's decode at frames {mismatched:?}"
    );
    let status = capture
        .wait(Duration::from_secs(10))
        .expect("capture exits after the file");
    assert!(status.success(), "{}", capture.stderr());
}

/// The first `count` frames cam01 of `site` publishes: source index and checksum.
fn first_frames(site: &TestSite, count: usize) -> Vec<(u64, u32)> {
    let ipc = site.ipc("subscriber");
    let frames = ipc.subscriber::<Frames>("cam01").unwrap();
    let mut capture = site.spawn("isochron-capture", &["--camera", "cam01"]);
    let mut got = Vec::new();
    read_samples(&frames, "cam01", Duration::from_secs(60), |h, pixels| {
        if !h.preamble.is_end_of_stream() {
            got.push((h.source_index, crc32fast::hash(pixels)));
        }
        got.len() < count
    });
    capture.terminate(Duration::from_secs(10));
    assert_eq!(got.len(), count, "{}", capture.stderr());
    got
}

#[test]
fn start_frame_starts_the_first_pass_there_and_a_loop_from_zero() {
    let reference = opencv_reference_checksums();
    let last = VTEST_FRAMES - 3;
    let expected: Vec<(u64, u32)> = [last, last + 1, last + 2, 0, 1]
        .iter()
        .map(|&i| (i, reference[i as usize]))
        .collect();
    let camera = |extra: &str| {
        format!(
            "[ipc]\nlossless = true\n\n{}loop = true\n{extra}",
            isochron_tests::vtest_camera("max", START)
        )
    };
    let decoding = TestSite::new(
        "capture-start-frame",
        &camera(&format!("start_frame = {last}\n")),
    );
    assert_eq!(first_frames(&decoding, 5), expected, "decoding");

    // Preloaded: the start is a frame of the preload, which loops.
    let preloaded = TestSite::new(
        "capture-start-frame-preload",
        &camera("preload_frames = 10\nstart_frame = 8\n"),
    );
    let expected: Vec<(u64, u32)> = [8u64, 9, 0, 1]
        .iter()
        .map(|&i| (i, reference[i as usize]))
        .collect();
    assert_eq!(first_frames(&preloaded, 4), expected, "preloaded");
}

/// Capture exits within `timeout` with `code`, saying `message`, without a panic.
fn assert_capture_fails(site: &TestSite, timeout: Duration, code: i32, message: &str) {
    let (exit, stderr) = site.exit_of("isochron-capture", timeout);
    assert_eq!(exit, Some(code), "{stderr}");
    assert!(stderr.contains(message), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}

#[test]
fn missing_file_is_a_clear_permanent_error() {
    let site = TestSite::with_source("missing", "", "nope.avi");
    let timeout = Duration::from_secs(20);
    assert_capture_fails(&site, timeout, 66, "nope.avi does not exist");
}

#[test]
fn corrupt_file_is_a_clear_permanent_error() {
    let site = TestSite::with_source("corrupt", "", "corrupt.avi");
    // Deterministic noise, 1 MB.
    let mut x: u32 = 12345;
    let noise: Vec<u8> = (0..1 << 20)
        .map(|_| {
            x = x.wrapping_mul(1_103_515_245).wrapping_add(12345);
            (x >> 16) as u8
        })
        .collect();
    std::fs::write(site.path("corrupt.avi"), noise).unwrap();
    let timeout = Duration::from_secs(30);
    assert_capture_fails(&site, timeout, 65, "cannot decode video file");
}

#[test]
fn truncated_file_publishes_what_it_can_then_ends() {
    let site = TestSite::new(
        "truncated",
        &format!(
            "[ipc]\nlossless = true\n\n[[camera]]\nid = \"cam01\"\nsource = \"cut.avi\"\nspeed = \"max\"\nstart = \"{START}\"\n"
        ),
    );
    let bytes = std::fs::read(vtest()).unwrap();
    std::fs::write(site.path("cut.avi"), &bytes[..bytes.len() * 2 / 5]).unwrap();
    let ipc = site.ipc("subscriber");
    let frames = ipc.subscriber::<Frames>("cam01").unwrap();
    let mut capture = site.spawn("isochron-capture", &["--camera", "cam01"]);
    let mut n = 0u64;
    let ended = read_samples(&frames, "cam01", Duration::from_secs(60), |h, _| {
        let more = !h.preamble.is_end_of_stream();
        n += more as u64;
        more
    });
    assert!(ended, "end of stream must be signalled");
    assert!(
        n > 100 && n < VTEST_FRAMES,
        "{n} frames from 40 % of the file"
    );
    let done = capture.finish(Duration::from_secs(10));
    assert!(done.status.success());
    assert!(done.stderr.contains("truncated"), "{}", done.stderr);
}

#[test]
fn unopenable_device_reconnects_with_backoff_until_stopped() {
    let site = TestSite::new(
        "device",
        "[[camera]]\nid = \"cam01\"\nsource = \"/dev/video99\"\nwidth = 640\nheight = 480\nreconnect_initial_s = 0.1\nreconnect_max_s = 0.4\n",
    );
    let mut capture = site.spawn("isochron-capture", &["--camera", "cam01"]);
    assert!(
        capture.wait_for_stderr(
            "attempt 3 failed, retrying in 0.4 s",
            Duration::from_secs(20)
        ),
        "{}",
        capture.stderr()
    );
    // A line when the failure starts (WARN) and when the delay grows (INFO),
    // none per attempt after: a second more of attempts 0.4 s apart adds none.
    std::thread::sleep(Duration::from_secs(1));
    let stderr = capture.stderr();
    for delay in [
        "attempt 1 failed, retrying in 0.1 s",
        "attempt 2 failed, retrying in 0.2 s",
    ] {
        assert!(stderr.contains(delay), "{stderr}");
    }
    assert_eq!(stderr.matches("retrying in 0.4 s").count(), 1, "{stderr}");
    let warnings = stderr.lines().filter(|l| l.contains("WARN")).count();
    assert_eq!(warnings, 1, "{stderr}");
    let status = capture.terminate(Duration::from_secs(5));
    assert!(status.success(), "{}", capture.stderr());
    assert!(!capture.stderr().contains("panicked"));
}

#[test]
fn malformed_and_invalid_config_name_line_and_key() {
    let site = TestSite::new("badconfig", "[[camera]]\nid = \"cam01\"\nsource = = 3\n");
    let (code, stderr) = site.exit_of("isochron-capture", Duration::from_secs(10));
    assert_eq!(code, Some(78), "{stderr}");
    assert!(stderr.contains("site.toml:8"), "{stderr}");

    site.write_config("[[camera]]\nid = \"cam01\"\nsource = \"x.avi\"\nfps = -1\n");
    let (code, stderr) = site.exit_of("isochron-capture", Duration::from_secs(10));
    assert_eq!(code, Some(78), "{stderr}");
    assert!(
        stderr.contains("site.toml:9: key `camera[0].fps`"),
        "{stderr}"
    );
    assert!(stderr.contains("expected a number"), "{stderr}");

    site.write_config("[[camera]]\nid = \"cam01\"\nsource = \"x.avi\"\nspeeed = 2\n");
    let (code, stderr) = site.exit_of("isochron-capture", Duration::from_secs(10));
    assert_eq!(code, Some(78), "{stderr}");
    assert!(stderr.contains("site.toml:9"), "{stderr}");
    assert!(stderr.contains("speeed"), "{stderr}");
}

#[test]
fn samples_with_wrong_magic_version_or_size_are_rejected_clearly() {
    // A buffer deep enough that the tap sees all four samples sent back to back.
    let site = TestSite::with_source("foreign", "[ipc]\nframe_buffer = 8", "unused.avi");
    let ipc = site.ipc("foreign-publisher");
    let mut publisher = ipc.publisher::<Frames>("cam01", 64 * 48).unwrap();
    let mut tap = Proc::spawn(&bin("isochron"), &site.tap_frames_args(1, 30));
    // The tap subscribes asynchronously: wait for it.
    eventually(Duration::from_secs(10), || {
        (publisher.subscriber_count() > 0).then_some(())
    })
    .expect("tap subscribed");

    let camera = CameraId::new("cam01").unwrap();
    let good = |seq: u64| {
        let mut preamble = Preamble::new::<u8>(Stream::Frames, camera, seq, 64 * 48);
        preamble.capture_time_ns = 1;
        FrameHeader {
            preamble,
            width: 64,
            height: 48,
            stride: 64,
            pixel_format: 1,
            source_index: seq,
        }
    };
    let pixels = vec![7u8; 64 * 48];
    let mut bad_magic = good(publisher.next_sequence());
    bad_magic.preamble.magic = !MAGIC;
    publisher.send_copy(bad_magic, &pixels).unwrap();
    let mut bad_version = good(publisher.next_sequence());
    bad_version.preamble.layout_version = 999;
    publisher.send_copy(bad_version, &pixels).unwrap();
    let mut bad_size = good(publisher.next_sequence());
    bad_size.height = 47;
    publisher.send_copy(bad_size, &pixels).unwrap();
    let good_one = good(publisher.next_sequence());
    publisher.send_copy(good_one, &pixels).unwrap();

    let status = tap
        .wait(Duration::from_secs(30))
        .expect("tap exits after one good sample");
    let (stdout, stderr) = (tap.stdout(), tap.stderr());
    assert!(status.success(), "{stderr}");
    assert!(stderr.contains("bad magic"), "{stderr}");
    assert!(stderr.contains("layout version 999"), "{stderr}");
    assert!(stderr.contains("frame size mismatch"), "{stderr}");
    assert_eq!(
        stdout.lines().count(),
        1,
        "only the good sample is printed: {stdout}"
    );
    assert!(
        stdout.contains("seq=3") && stdout.contains("64x48"),
        "{stdout}"
    );
}
