//! isochron-motion as a separate process: fed by isochron-capture on vtest.avi (and
//! scored against the PETS 2009 person boxes), and fed by this test with foreign,
//! malformed and discontinuous frames.

use std::time::{Duration, Instant};

use isochron_config::MotionConfig;
use isochron_config::clock::{NS_PER_S, parse_rfc3339};
use isochron_motion::eval::{GroundTruth, Score};
use isochron_motion::kernel::Geometry;
use isochron_runtime::ipc::{Frames, Motion, StreamPublisher};
use isochron_tests::{TestSite, VTEST_FRAMES, eventually, read_samples, repo_root};
use isochron_wire::{
    BlockMotion, CameraId, DIRECTION_NONE, FLAG_DISCONTINUITY, FLAG_END_OF_STREAM, FrameHeader,
    MAGIC, MotionHeader, PixelFormat, Preamble, Stream,
};

const START: &str = "2026-03-02T07:00:00Z";

fn cam() -> CameraId {
    CameraId::new("cam01").unwrap()
}

/// A received motion sample.
struct Received {
    header: MotionHeader,
    blocks: Vec<BlockMotion>,
}

/// Reads motion samples until end of stream (inclusive) or `timeout`.
fn read_until_end_of_stream(
    motion: &isochron_runtime::ipc::StreamSubscriber<Motion>,
    timeout: Duration,
) -> (Vec<Received>, bool) {
    let mut out = Vec::new();
    let ended = read_samples(motion, "cam01", timeout, |&header, blocks| {
        out.push(Received {
            header,
            blocks: blocks.to_vec(),
        });
        !header.preamble.is_end_of_stream()
    });
    (out, ended)
}

#[test]
fn capture_to_motion_on_vtest_delivers_every_pair_and_sees_the_people() {
    // Subscribed before the producers start: lossless delivery counts from here.
    let (site, ipc, motion) = TestSite::lossless_vtest::<Motion>("motion-vtest", START);
    let mut motion_proc = site.spawn("isochron-motion", &["--camera", "cam01"]);
    eventually(Duration::from_secs(20), || {
        (ipc.subscriber_count("cam01", Stream::Frames)? >= 1).then_some(())
    })
    .unwrap_or_else(|| {
        panic!(
            "motion never subscribed to frames\n{}",
            motion_proc.stderr()
        )
    });
    let mut capture = site.spawn("isochron-capture", &["--camera", "cam01"]);

    let (samples, ended) = read_until_end_of_stream(&motion, Duration::from_secs(180));
    assert!(
        ended,
        "no end of stream after {} motion samples\n{}",
        samples.len(),
        motion_proc.stderr()
    );
    let (eos, samples) = samples.split_last().unwrap();
    assert_eq!(
        eos.header.preamble.flags & FLAG_END_OF_STREAM,
        FLAG_END_OF_STREAM
    );
    assert!(eos.blocks.is_empty());
    // The first frame has no predecessor: 794 pairs from 795 frames.
    let n = samples.len() as u64;
    assert!(
        n == VTEST_FRAMES - 1 || n == VTEST_FRAMES,
        "{n} motion samples from {VTEST_FRAMES} frames"
    );
    let start_ns = parse_rfc3339(START).unwrap();
    let config = MotionConfig::default();
    let geom = Geometry::new(768, 576, config.block_px as usize).unwrap();
    for (i, s) in samples.iter().enumerate() {
        let h = &s.header;
        assert_eq!(h.preamble.sequence, i as u64, "own contiguous sequence");
        let frame = h.source_index;
        assert_eq!(
            frame,
            i as u64 + VTEST_FRAMES - n,
            "one sample per frame pair"
        );
        assert_eq!(
            h.preamble.capture_time_ns,
            start_ns + frame as i64 * NS_PER_S / 10,
            "sample {i}: the capture time of its frame"
        );
        assert!(h.preamble.origin_wall_ns > 0);
        assert_eq!(
            (
                h.frame_width,
                h.frame_height,
                h.block_px,
                h.grid_w,
                h.grid_h
            ),
            (768, 576, 16, 48, 36)
        );
        for b in &s.blocks {
            assert!((0.0..=1.0).contains(&b.density), "{b:?}");
            assert!(b.dx.hypot(b.dy) <= b.density + 1e-6, "{b:?}");
            assert!(b.direction < 8 || b.direction == DIRECTION_NONE);
        }
    }
    assert_eq!(eos.header.preamble.sequence, n);

    // PETS 2009 S2.L1: moving people are seen, blocks far from people are quiet.
    let gt = GroundTruth::parse_mot(
        &std::fs::read_to_string(repo_root().join("tests/data/pets09-s2l1-gt.txt")).unwrap(),
    )
    .unwrap();
    let mut score = Score::default();
    for s in samples {
        score.add(
            &gt,
            s.header.source_index,
            &geom,
            &s.blocks,
            config.density_threshold,
        );
    }
    eprintln!(
        "PETS09 S2.L1: {} moving people in {} pairs, seen {:.2} %, core blocks active {:.1} %, \
         far blocks quiet {:.2} %, active blocks near people {:.1} %",
        score.moving,
        score.pairs,
        100.0 * score.seen_fraction(),
        100.0 * score.core_fraction(),
        100.0 * score.quiet_fraction(),
        100.0 * score.active_near_fraction()
    );
    assert!(score.moving > 3000, "{score:?}");
    assert!(score.seen_fraction() >= 0.99, "{score:?}");
    assert!(score.core_fraction() >= 0.85, "{score:?}");
    assert!(score.quiet_fraction() >= 0.99, "{score:?}");
    assert!(score.active_near_fraction() >= 0.8, "{score:?}");
    let moving_directions = samples
        .iter()
        .flat_map(|s| &s.blocks)
        .filter(|b| b.density >= config.density_threshold && b.direction != DIRECTION_NONE)
        .count();
    assert!(
        moving_directions > 10_000,
        "{moving_directions} labelled blocks"
    );

    // Capture ends with the file; motion passes the end on and keeps running.
    let status = capture
        .wait(Duration::from_secs(10))
        .expect("capture exits");
    assert!(status.success(), "{}", capture.stderr());
    std::thread::sleep(Duration::from_millis(300));
    assert!(
        motion_proc.wait(Duration::ZERO).is_none(),
        "motion must keep running after end of stream\n{}",
        motion_proc.stderr()
    );
    let status = motion_proc.terminate(Duration::from_secs(5));
    assert!(status.success(), "{}", motion_proc.stderr());
    assert!(!motion_proc.stderr().contains("panicked"));
}

/// A GRAY8 frame of `w × h`: a smooth static background with a textured 16×16
/// square at x = 8 + `shift` (only the square moves when `shift` changes).
fn texture(w: u32, h: u32, shift: u32) -> Vec<u8> {
    (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f32, (i / w) as f32);
            let sx = x - 8.0 - shift as f32;
            if (0.0..16.0).contains(&sx) && (8.0..24.0).contains(&y) {
                (140.0 + 80.0 * (sx * 0.9).sin() * (y * 0.7).cos()) as u8
            } else {
                (60.0 + 20.0 * (x * 0.05).sin() + 20.0 * (y * 0.07).cos()) as u8
            }
        })
        .collect()
}

struct Feeder {
    publisher: StreamPublisher<Frames>,
}

impl Feeder {
    fn header(&mut self, seq: u64, w: u32, h: u32, format: PixelFormat, index: u64) -> FrameHeader {
        let bytes = (w * h) as usize * format.channels();
        let mut preamble = Preamble::new::<u8>(Stream::Frames, cam(), seq, bytes);
        preamble.capture_time_ns = 1_000 + seq as i64;
        preamble.origin_wall_ns = isochron_config::clock::wall_now_ns();
        FrameHeader {
            preamble,
            width: w,
            height: h,
            stride: w * format.channels() as u32,
            pixel_format: format as u32,
            source_index: index,
        }
    }

    fn send(&mut self, header: FrameHeader, pixels: &[u8]) {
        self.publisher.send_copy(header, pixels).unwrap();
    }

    fn gray(&mut self, seq: u64, w: u32, h: u32, shift: u32, index: u64) {
        let header = self.header(seq, w, h, PixelFormat::Gray8, index);
        self.send(header, &texture(w, h, shift));
    }
}

#[test]
fn bad_samples_restarts_gaps_and_end_of_stream_are_handled() {
    let site = TestSite::with_source("motion-feed", "[ipc]\nlossless = true", "unused.avi");
    let ipc = site.ipc("feeder");
    let motion = ipc.subscriber::<Motion>("cam01").unwrap();
    let mut feeder = Feeder {
        publisher: ipc.publisher::<Frames>("cam01", 64 * 48 * 3).unwrap(),
    };
    let mut proc = site.spawn("isochron-motion", &["--camera", "cam01"]);
    eventually(Duration::from_secs(20), || {
        (feeder.publisher.subscriber_count() >= 1).then_some(())
    })
    .unwrap_or_else(|| panic!("motion never subscribed\n{}", proc.stderr()));

    // Each step: what is sent, and the source index of the motion sample it yields.
    feeder.gray(0, 64, 48, 0, 100); // first frame: nothing
    feeder.gray(1, 64, 48, 3, 101); // → M0
    let mut bad = feeder.header(2, 64, 48, PixelFormat::Gray8, 102);
    bad.preamble.magic = !MAGIC;
    feeder.send(bad, &texture(64, 48, 0)); // rejected, the previous frame stays
    feeder.gray(3, 64, 48, 0, 103); // → M1 (a gap of one sample is still a pair)
    let bgr = feeder.header(4, 64, 48, PixelFormat::Bgr8, 104);
    feeder.send(bgr, &vec![7u8; 64 * 48 * 3]); // rejected: not GRAY8; run restarts
    feeder.gray(5, 64, 48, 0, 105); // first of a run: nothing
    feeder.gray(6, 64, 48, 3, 106); // → M2
    feeder.gray(0, 64, 48, 0, 0); // publisher restarted (sequence back to 0): nothing
    feeder.gray(1, 64, 48, 3, 1); // → M3
    feeder.gray(2, 32, 32, 0, 2); // new size: nothing
    feeder.gray(3, 32, 32, 3, 3); // → M4, a 2×2 grid
    let mut gap = feeder.header(4, 32, 32, PixelFormat::Gray8, 4);
    gap.preamble.flags = FLAG_DISCONTINUITY;
    feeder.send(gap, &texture(32, 32, 0)); // capture reconnected: nothing
    feeder.gray(5, 32, 32, 3, 5); // → M5
    let mut eos = feeder.header(6, 0, 0, PixelFormat::Gray8, 6);
    eos.preamble.flags = FLAG_END_OF_STREAM;
    eos.preamble.payload_len = 0;
    feeder.send(eos, &[]); // → M6, end of stream
    feeder.gray(7, 64, 48, 0, 7); // after the end: a new run, nothing
    feeder.gray(8, 64, 48, 3, 8); // → M7: the service kept running

    let mut got: Vec<Received> = Vec::new();
    read_samples(
        &motion,
        "cam01",
        Duration::from_secs(30),
        |&header, blocks| {
            got.push(Received {
                header,
                blocks: blocks.to_vec(),
            });
            got.len() < 8
        },
    );
    let stderr = proc.stderr();
    let indices: Vec<u64> = got.iter().map(|r| r.header.source_index).collect();
    assert_eq!(
        got.len(),
        8,
        "motion samples for frames {indices:?}\n{stderr}"
    );
    let expected_frames = [101, 103, 106, 1, 3, 5];
    for (i, &frame) in expected_frames.iter().enumerate() {
        assert_eq!(got[i].header.source_index, frame, "M{i}\n{stderr}");
    }
    for (i, r) in got.iter().enumerate() {
        assert_eq!(
            r.header.preamble.sequence, i as u64,
            "contiguous motion sequence"
        );
    }
    assert_eq!(got[0].header.preamble.capture_time_ns, 1_001);
    assert_eq!((got[0].header.grid_w, got[0].header.grid_h), (4, 3));
    assert!(
        got[0].blocks.iter().any(|b| b.density > 0.0),
        "the shift moves"
    );
    assert_eq!((got[4].header.grid_w, got[4].header.grid_h), (2, 2));
    assert_eq!(got[4].blocks.len(), 4);
    assert!(got[6].header.preamble.is_end_of_stream());
    assert!(got[6].blocks.is_empty());
    assert_eq!(got[7].header.source_index, 8);

    // The frames grow: the larger grid needs a larger motion publisher, a new run
    // whose sequence starts again at 0.
    feeder.gray(9, 96, 64, 0, 9); // new size: nothing
    feeder.gray(10, 96, 64, 3, 10); // → M8, from the new publisher
    let mut grown = None;
    let deadline = Instant::now() + Duration::from_secs(30);
    while grown.is_none() && Instant::now() < deadline {
        motion.wait(Duration::from_millis(100));
        if let Some(sample) = motion.receive().unwrap() {
            let header = *sample.user_header();
            header.validate(&cam(), sample.payload().len()).unwrap();
            grown = Some(header);
        }
    }
    let grown =
        grown.unwrap_or_else(|| panic!("no motion for the grown frames\n{}", proc.stderr()));
    assert_eq!((grown.grid_w, grown.grid_h, grown.source_index), (6, 4, 10));
    assert_eq!(
        grown.preamble.sequence, 0,
        "a new publisher starts a new run"
    );

    let stderr = proc.stderr();
    assert!(stderr.contains("bad magic"), "{stderr}");
    assert!(stderr.contains("motion needs GRAY8 frames"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");

    let status = proc.terminate(Duration::from_secs(5));
    assert!(status.success(), "{}", proc.stderr());
}
