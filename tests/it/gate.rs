//! isochron-gate as a separate process, fed frames and activity by this test over
//! iceoryx2, watched through its `events` and `detections` streams.

use std::time::{Duration, Instant};

use isochron_config::clock::NS_PER_S;
use isochron_runtime::ipc::{
    Activity, Detections, Events, Frames, Ipc, StreamPublisher, StreamSubscriber,
};
use isochron_tests::{Proc, TestSite, clock_ticks_per_s, cpu_ticks, eventually};
use isochron_wire::{
    ActivityHeader, BlockActivity, CameraId, EventPhase, FLAG_END_OF_STREAM, FrameHeader,
    PixelFormat, Preamble, Stream,
};

const BLOCK_PX: u32 = 16;

/// Publishes frames and activity the way capture and the cascade would.
struct Feeder {
    frames: StreamPublisher<Frames>,
    activity: StreamPublisher<Activity>,
    camera: CameraId,
    width: u32,
    height: u32,
    pixels: Vec<u8>,
    frame_index: u64,
}

impl Feeder {
    fn new(ipc: &Ipc, width: u32, height: u32) -> Self {
        let grid = (width.div_ceil(BLOCK_PX) * height.div_ceil(BLOCK_PX)) as usize;
        // A textured frame, so the detector has something to look at.
        let pixels = (0..width * height)
            .map(|i| (((i % width) * 7) ^ ((i / width) * 13)) as u8)
            .collect();
        Feeder {
            frames: ipc
                .publisher::<Frames>("cam01", (width * height) as usize)
                .unwrap(),
            activity: ipc.publisher::<Activity>("cam01", grid).unwrap(),
            camera: CameraId::new("cam01").unwrap(),
            width,
            height,
            pixels,
            frame_index: 0,
        }
    }

    fn grid(&self) -> (u32, u32) {
        (
            self.width.div_ceil(BLOCK_PX),
            self.height.div_ceil(BLOCK_PX),
        )
    }

    /// Ten frames of second `s`, then its activity sample: block 5's moving
    /// activity is `s2`.
    fn second(&mut self, s: i64, s2: f32) {
        let first = self.frame_index;
        for k in 0..10 {
            let mut preamble = Preamble::new::<u8>(
                Stream::Frames,
                self.camera,
                self.frames.next_sequence(),
                self.pixels.len(),
            );
            preamble.capture_time_ns = s * NS_PER_S + k * NS_PER_S / 10;
            let header = FrameHeader {
                preamble,
                width: self.width,
                height: self.height,
                stride: self.width,
                pixel_format: PixelFormat::Gray8 as u32,
                source_index: self.frame_index,
            };
            self.frames.send_copy(header, &self.pixels).unwrap();
            self.frame_index += 1;
        }
        let (gw, gh) = self.grid();
        let mut blocks = vec![BlockActivity::default(); (gw * gh) as usize];
        blocks[5].s2 = s2;
        let header = self.activity_header((s + 1) * NS_PER_S, blocks.len(), 0);
        let header = ActivityHeader {
            first_source_index: first,
            last_source_index: self.frame_index - 1,
            ..header
        };
        self.activity.send_copy(header, &blocks).unwrap();
    }

    fn activity_header(&mut self, time_ns: i64, blocks: usize, flags: u32) -> ActivityHeader {
        let (gw, gh) = self.grid();
        let mut preamble = Preamble::new::<BlockActivity>(
            Stream::Activity,
            self.camera,
            self.activity.next_sequence(),
            blocks,
        );
        preamble.capture_time_ns = time_ns;
        preamble.flags = flags;
        ActivityHeader {
            preamble,
            grid_w: gw,
            grid_h: gh,
            block_px: BLOCK_PX,
            frame_width: self.width,
            frame_height: self.height,
            frames: 10,
            frame_rate: 10.0,
            ..Default::default()
        }
    }

    fn end_of_stream(&mut self, time_ns: i64) {
        let header = self.activity_header(time_ns, 0, FLAG_END_OF_STREAM);
        self.activity.send_copy(header, &[]).unwrap();
    }

    fn wait_for_gate(&self) {
        eventually(Duration::from_secs(20), || {
            (self.frames.subscriber_count() > 0 && self.activity.subscriber_count() > 0)
                .then_some(())
        })
        .expect("the gate subscribed to frames and activity");
    }
}

/// A site whose gate runs in live mode (a busy detector drops work) or, when
/// `lossless`, in replay mode (every gated frame is detected).
fn site(name: &str, lossless: bool, gate: &str) -> TestSite {
    TestSite::with_source(
        name,
        &format!("[ipc]\nlossless = {lossless}\nframe_buffer = 4\n\n[gate]\n{gate}"),
        "unused.avi",
    )
}

/// The gate of a site, fed by a [`Feeder`] of `width × height` frames, watched
/// through its events and detections (subscribed to before it starts).
struct Fed {
    // Dropped in this order: the gate stops first, the node goes last.
    gate: Proc,
    feeder: Feeder,
    detections: StreamSubscriber<Detections>,
    events: StreamSubscriber<Events>,
    _ipc: Ipc,
}

impl Fed {
    /// The end-of-stream header of `detections`, with the gate's counters,
    /// skipping the detections before it.
    fn detections_end(&mut self, timeout: Duration) -> isochron_wire::DetectionHeader {
        eventually(timeout, || {
            while let Some(s) = self.detections.receive().unwrap() {
                if s.user_header().preamble.is_end_of_stream() {
                    return Some(*s.user_header());
                }
            }
            None
        })
        .expect("detections end of stream")
    }
}

/// Starts the gate of `site` and waits until it subscribed to the feeder.
fn start_gate(site: &TestSite, width: u32, height: u32) -> Fed {
    let ipc = site.ipc("feeder");
    let events = ipc.subscriber::<Events>("cam01").unwrap();
    let detections = ipc.subscriber::<Detections>("cam01").unwrap();
    let feeder = Feeder::new(&ipc, width, height);
    let gate = site.spawn("isochron-gate", &["--camera", "cam01"]);
    feeder.wait_for_gate();
    Fed {
        gate,
        feeder,
        detections,
        events,
        _ipc: ipc,
    }
}

#[test]
fn events_start_and_end_with_hysteresis_and_the_detector_runs_at_start_and_when_quiet() {
    let site = site("gate-events", true, "hold_s = 2.0");
    let mut fed = start_gate(&site, 320, 240);

    // Quiet, active 5..10 s, a 1-s dip at 7 (shorter than the hold), quiet again.
    for s in 0..20 {
        let active = (5..10).contains(&s) && s != 7;
        fed.feeder.second(s, if active { 1.0 } else { 0.0 });
        std::thread::sleep(Duration::from_millis(20));
    }
    fed.feeder.end_of_stream(20 * NS_PER_S);

    let (mut records, mut dets, mut ended) = (Vec::new(), Vec::new(), (false, false));
    let deadline = Instant::now() + Duration::from_secs(60);
    while !(ended.0 && ended.1) && Instant::now() < deadline {
        fed.events.wait(Duration::from_millis(100));
        while let Some(s) = fed.events.receive().unwrap() {
            let h = *s.user_header();
            if h.preamble.is_end_of_stream() {
                ended.0 = true;
            } else {
                records.push((h, s.payload().to_vec()));
            }
        }
        while let Some(s) = fed.detections.receive().unwrap() {
            let h = *s.user_header();
            if h.preamble.is_end_of_stream() {
                ended.1 = true;
                assert_eq!(h.frames_seen, 200);
                // When the event starts, and each time its activity falls quiet
                // (the dip at 7, the end at 10): does someone stay?
                assert_eq!(h.frames_detected, 3, "{h:?}");
            } else {
                dets.push(h);
            }
        }
    }
    assert!(ended.0 && ended.1, "end of stream on events and detections");
    assert_eq!(
        records.len(),
        2,
        "one start and one end record: {records:?}"
    );
    let (start, blocks) = &records[0];
    assert_eq!(start.phase, EventPhase::Start as u32);
    assert_eq!((start.start_ns, start.start_frame), (5 * NS_PER_S, 50));
    assert_eq!(blocks, &vec![5]);
    assert_eq!(start.zone_name(), "all");
    let (end, _) = &records[1];
    assert_eq!(end.phase, EventPhase::End as u32);
    assert_eq!((end.end_ns, end.end_frame), (10 * NS_PER_S, 99));
    assert!(
        end.peak >= 1.0 && (end.threshold - 0.5).abs() < 1e-6,
        "cold: the floor"
    );
    assert_eq!(dets.len(), 3);
    assert!(dets.iter().all(|d| d.event_id == start.event_id));
    let frames: Vec<u64> = dets.iter().map(|d| d.source_index).collect();
    assert_eq!(
        frames,
        [59, 79, 109],
        "the last frame of the triggering second, then of the quiet ones"
    );
}

#[test]
fn a_slow_detector_does_not_delay_events() {
    // HOG on an upscaled 1080p frame takes seconds; events come every second.
    // Live mode: the detector may drop work, events may never wait for it.
    let site = site(
        "gate-slow",
        false,
        // The whole frame at OpenCV's fine scale step: a slow search.
        "hold_s = 0.0\n\n[gate.detector]\nhog_upscale = 2.0\nhog_scale_step = 1.05\ncrop = false\nqueue = 1",
    );
    let mut fed = start_gate(&site, 1920, 1080);

    let mut worst = Duration::ZERO;
    let mut records = 0;
    for s in 0..16 {
        // On at even seconds, off at odd ones: a start, then an end, every 2 s.
        let sent = Instant::now();
        fed.feeder.second(s, if s % 2 == 0 { 1.0 } else { 0.0 });
        let got = eventually(Duration::from_secs(5), || {
            fed.events.receive().unwrap().map(|_| ())
        });
        assert!(got.is_some(), "no event record for second {s}");
        records += 1;
        worst = worst.max(sent.elapsed());
    }
    println!("slowest event record: {worst:?}");
    assert_eq!(records, 16);
    assert!(
        worst < Duration::from_millis(1500),
        "events waited for the detector: {worst:?}"
    );

    fed.feeder.end_of_stream(16 * NS_PER_S);
    let eos = fed.detections_end(Duration::from_secs(120));
    println!(
        "detected {} frames, dropped {} jobs, detector {} ms",
        eos.frames_detected,
        eos.jobs_dropped,
        eos.detector_total_us / 1000
    );
    assert!(
        eos.jobs_dropped > 0,
        "a busy detector drops work instead of queueing it"
    );
    assert!(eos.frames_detected >= 1 && eos.frames_detected < 8);
}

/// What the gate did in `seconds` of live feeding with `share` of a core for its
/// detector: its process's CPU seconds and the wall-clock seconds of the
/// feeding, and the end of stream's counters.
fn fed_with_share(name: &str, share: f64) -> (f64, f64, isochron_wire::DetectionHeader) {
    // HOG on whole 1080p frames: a good part of a second of one core each; a
    // detection job every other second of activity (events start and end by
    // turns), eight seconds of activity fed per second.
    let site = site(
        name,
        false,
        &format!(
            "hold_s = 0.0\n\n[gate.detector]\ninstalled = false\ncrop = false\n\
             cpu_share = {share}"
        ),
    );
    let mut fed = start_gate(&site, 1920, 1080);
    let pid = fed.gate.pid();
    let (t0, c0) = (Instant::now(), cpu_ticks(pid).expect("the gate's CPU time"));
    let seconds = 64;
    for s in 0..seconds {
        fed.feeder.second(s, if s % 2 == 0 { 1.0 } else { 0.0 });
        std::thread::sleep(Duration::from_millis(125));
    }
    let ticks = cpu_ticks(pid).expect("the gate's CPU time") - c0;
    let wall = t0.elapsed().as_secs_f64();
    fed.feeder.end_of_stream(seconds * NS_PER_S);
    let eos = fed.detections_end(Duration::from_secs(60));
    (ticks as f64 / clock_ticks_per_s(), wall, eos)
}

#[test]
fn cpu_share_holds_the_detector_to_its_share_of_a_core() {
    // Back to back (the default), the detector is busy all along.
    let (_, wall, full) = fed_with_share("gate-share-full", 1.0);
    let busy = full.detector_total_us as f64 / 1e6 / wall;
    println!(
        "cpu_share 1: detecting {busy:.2} of the time, {} detections",
        full.frames_detected
    );
    assert!(busy > 0.7, "the load keeps a whole slot busy: {busy:.2}");

    // A quarter: the gate's whole process stays within a quarter of a core, but
    // for the detection under way and its own work on the frames.
    let (cpu, wall, quarter) = fed_with_share("gate-share-quarter", 0.25);
    let mean = quarter.detector_total_us as f64 / 1e6 / quarter.frames_detected.max(1) as f64;
    println!(
        "cpu_share 0.25: {cpu:.2} s of CPU in {wall:.2} s, {} detections of {mean:.2} s, {} jobs dropped",
        quarter.frames_detected, quarter.jobs_dropped
    );
    assert!(quarter.frames_detected >= 2, "{quarter:?}");
    assert!(
        quarter.jobs_dropped > 0,
        "jobs over the share are dropped: {quarter:?}"
    );
    assert!(
        cpu <= 0.25 * wall + mean + 0.1 * wall,
        "{cpu:.2} s of CPU in {wall:.2} s with a quarter of a core"
    );
}

/// The Python of the test venv with the `onnx` package (`cargo xtask setup`).
fn onnx_python() -> std::path::PathBuf {
    isochron_tests::venv_python("onnx")
}

#[test]
fn an_onnx_model_runs_through_opencv_dnn_on_the_letterboxed_frame() {
    for channels in [3, 1] {
        // A model with the YOLOv8 output layout whose boxes are known, made here.
        let dir = tempfile::tempdir().unwrap();
        let model = dir.path().join("yolo.onnx");
        let made = std::process::Command::new(onnx_python())
            .arg(isochron_tests::repo_root().join("tests/data/yolo_constant.py"))
            .arg(&model)
            .args([channels.to_string(), "64".into()])
            .status()
            .unwrap();
        assert!(made.success(), "tests/data/yolo_constant.py failed");
        let site = site(
            &format!("gate-onnx{channels}"),
            true,
            &format!(
                "[gate.detector]\nmodel = \"{}\"\ninput_px = 64\ninput_channels = {channels}\ncrop = false",
                model.display()
            ),
        );
        // 128x64 frames in a 64x64 input: scale 0.5, 16 px of grey above and below.
        let mut fed = start_gate(&site, 128, 64);
        for s in 0..4 {
            fed.feeder.second(s, if s == 1 { 1.0 } else { 0.0 });
        }
        fed.feeder.end_of_stream(4 * NS_PER_S);
        let found = eventually(Duration::from_secs(60), || {
            while let Some(s) = fed.detections.receive().unwrap() {
                if !s.user_header().preamble.is_end_of_stream() {
                    return Some(s.payload().to_vec());
                }
            }
            None
        })
        .unwrap_or_else(|| panic!("no detection; the gate said:\n{}", fed.gate.stderr()));
        // The person at (32, 32) 16x24 of the input, in frame pixels: x = (32 - 8)
        // / 0.5, y = (32 - 12 - 16) / 0.5. Stretched instead of letterboxed, y
        // would be 20 and h 24. The weak person and the other class are dropped.
        assert_eq!(found.len(), 1, "{found:?}");
        let d = found[0];
        assert_eq!((d.x, d.y, d.w, d.h, d.class), (48.0, 8.0, 32.0, 48.0, 0));
        assert_eq!(d.model(), isochron_wire::DetectorModel::Onnx);
        assert!(!d.has_pose(), "a YOLO box has no keypoints");
        // Its score is the input's mean: half frame (≈ its mean), half grey 114.
        let pixels = &fed.feeder.pixels;
        let frame_mean = pixels.iter().map(|&p| p as f64).sum::<f64>() / pixels.len() as f64;
        let expected = (frame_mean + 114.0) / 2.0 / 255.0;
        println!(
            "{channels} channel(s): score {} (expected ≈ {expected:.3})",
            d.score
        );
        assert!(
            (d.score as f64 - expected).abs() < 0.03,
            "score {} expected {expected}",
            d.score
        );
    }
}
