//! The capture stage driven without shared memory: frames made in memory, the
//! memory output, and the runtime's `step` (an alarm that is due) and
//! `step_alarm` (an alarm fired as if its time had come).

use std::cell::RefCell;
use std::collections::VecDeque;
use std::rc::Rc;

use super::*;
use isochron_runtime::ipc::Frames;
use isochron_runtime::stage::{Queue, step, step_alarm};
use isochron_wire::{FLAG_DISCONTINUITY, FLAG_END_OF_STREAM, StreamHeader};

const CAMERA: &str = "cam01";
const FRAME: FrameFormat = FrameFormat {
    width: 4,
    height: 2,
    format: PixelFormat::Gray8,
};

/// `count` frames of 4×2 pixels, each filled with its index; then `after`.
struct MemorySource {
    next: u64,
    count: u64,
    /// What follows the last frame: `Ok(outcome)` or a failure.
    after: Result<ReadOutcome, ()>,
    /// The frame count a file states (0: unknown).
    stated: u64,
    fps: f64,
}

impl MemorySource {
    fn file(count: u64, stated: u64) -> Box<dyn FrameSource> {
        Box::new(MemorySource {
            next: 0,
            count,
            after: Ok(ReadOutcome::EndOfFile),
            stated,
            fps: 10.0,
        })
    }

    fn camera(count: u64) -> Box<dyn FrameSource> {
        Box::new(MemorySource {
            next: 0,
            count,
            after: Ok(ReadOutcome::Lost),
            stated: 0,
            fps: 25.0,
        })
    }
}

impl FrameSource for MemorySource {
    fn native_size(&mut self) -> Result<Option<(u32, u32)>, SourceError> {
        Ok(Some((FRAME.width, FRAME.height)))
    }

    fn stated_fps(&self) -> f64 {
        self.fps
    }

    fn next_index(&self) -> u64 {
        self.next
    }

    fn read_frame(
        &mut self,
        dst: &mut [MaybeUninit<u8>],
        _: FrameFormat,
    ) -> Result<ReadOutcome, SourceError> {
        if self.next >= self.count {
            return self
                .after
                .map_err(|()| SourceError::Unavailable("a broken frame".into()));
        }
        dst.fill(MaybeUninit::new(self.next as u8));
        self.next += 1;
        Ok(ReadOutcome::Frame)
    }

    fn completeness(&self) -> Option<InputCompleteness> {
        Some(InputCompleteness::of(self.next, self.stated))
    }
}

/// An opener that answers from `script`, then fails.
fn scripted(script: Vec<Result<Box<dyn FrameSource>, SourceError>>) -> (Opener, Rc<RefCell<u32>>) {
    let script = Rc::new(RefCell::new(VecDeque::from(script)));
    let calls = Rc::new(RefCell::new(0));
    let counted = calls.clone();
    let open: Opener = Box::new(move || {
        *counted.borrow_mut() += 1;
        script
            .borrow_mut()
            .pop_front()
            .unwrap_or_else(|| Err(SourceError::Unavailable("no more sources".into())))
    });
    (open, calls)
}

fn settings(is_file: bool, speed: Speed) -> Settings {
    Settings {
        camera: CAMERA.into(),
        is_file,
        loop_file: false,
        size: None,
        format: PixelFormat::Gray8,
        fps: None,
        speed,
        start_ns: Some(1_000_000_000),
        backoff: Backoff::new(Duration::from_millis(100), Duration::from_millis(400)),
    }
}

/// A stage playing the memory file `source`, and its output queue.
fn playing(
    settings: Settings,
    source: Box<dyn FrameSource>,
    open: Opener,
    output: (Output<'static, Frames>, Queue<Frames>),
) -> (CaptureStage<'static>, Queue<Frames>, Context) {
    let mut source = source;
    let playback = Playback::of(&settings, source.as_mut()).expect("a playback");
    let stage = CaptureStage::playing(settings, open, source, playback, output.0).expect("a stage");
    let mut cx = Context::new(StageKind::Capture, CAMERA, None);
    let mut stage = stage;
    stage.on_start(&mut cx).expect("started");
    (stage, output.1, cx)
}

/// Runs `stage` on its alarms, fired when due (the test waits for them), until
/// it finishes or `passes` ran.
fn run_due(stage: &mut CaptureStage<'_>, cx: &mut Context, passes: usize) {
    for _ in 0..passes {
        if stage.finished() {
            return;
        }
        if let Some(at) = cx.alarm() {
            std::thread::sleep(at.saturating_duration_since(Instant::now()));
        }
        step(stage, &(), cx).expect("a pass");
    }
}

/// (source index, first pixel, flags but end of stream, end of stream) of every
/// sample sent.
fn sent(queue: &Queue<Frames>) -> Vec<(u64, u8, u32, bool)> {
    queue
        .borrow()
        .iter()
        .map(|o| {
            let p = o.header.preamble();
            let pixel = o.payload.first().copied().unwrap_or(0);
            let flags = p.flags & !FLAG_END_OF_STREAM;
            (o.header.source_index, pixel, flags, p.is_end_of_stream())
        })
        .collect()
}

#[test]
fn a_file_is_paced_by_alarms_at_its_frame_rate_on_the_file_clock() {
    let mut s = settings(true, Speed::Factor(1.0));
    s.fps = Some(50.0); // one frame per 20 ms
    let (open, _) = scripted(vec![]);
    let (mut stage, queue, mut cx) =
        playing(s, MemorySource::file(5, 5), open, Output::memory(CAMERA));
    let t0 = Instant::now();
    step(&mut stage, &(), &mut cx).unwrap();
    assert_eq!(queue.borrow().len(), 1, "frame 0 is due at once");
    let next = cx.alarm().expect("an alarm for frame 1");
    let ahead = next.saturating_duration_since(t0);
    assert!(
        ahead > Duration::from_millis(10) && ahead <= Duration::from_millis(20),
        "frame 1 is due 20 ms after the start: {ahead:?}"
    );
    // Fired early (a wake for another reason), the alarm publishes nothing and
    // is set again for the same time.
    assert_eq!(step_alarm(&mut stage, &mut cx).unwrap(), Some(next));
    assert_eq!(queue.borrow().len(), 1);
    assert_eq!(cx.alarm(), Some(next));
    run_due(&mut stage, &mut cx, 20);
    assert!(stage.finished());
    assert!(
        t0.elapsed() >= Duration::from_millis(80),
        "{:?}",
        t0.elapsed()
    );
    let frames = queue.borrow();
    assert_eq!(frames.len(), 6, "five frames and the end of stream");
    for (i, f) in frames.iter().take(5).enumerate() {
        let p = f.header.preamble();
        assert_eq!(p.sequence, i as u64);
        assert_eq!(p.capture_time_ns, 1_000_000_000 + i as i64 * 20_000_000);
        assert_eq!(f.payload, vec![i as u8; 8]);
        assert_eq!(
            (f.header.width, f.header.height, f.header.stride),
            (4, 2, 4)
        );
    }
    let end = frames[5].header.preamble();
    assert!(end.is_end_of_stream());
    assert_eq!(end.capture_time_ns, 1_000_000_000 + 5 * 20_000_000);
    assert_eq!(cx.alarm(), None, "nothing left to wait for");
}

#[test]
fn at_speed_max_every_frame_is_due_at_once_and_the_end_reports_the_file() {
    let (open, _) = scripted(vec![]);
    let (mut stage, queue, mut cx) = playing(
        settings(true, Speed::Max),
        MemorySource::file(3, 3),
        open,
        Output::memory(CAMERA),
    );
    for _ in 0..4 {
        let at = cx.alarm().expect("an alarm");
        assert!(at <= Instant::now(), "due at once");
        step(&mut stage, &(), &mut cx).unwrap();
    }
    assert!(stage.finished());
    assert_eq!(
        sent(&queue),
        [
            (0, 0, 0, false),
            (1, 1, 0, false),
            (2, 2, 0, false),
            (0, 0, 0, true)
        ]
    );
    let words = words(&stage);
    assert!(
        words.starts_with("reconnects=0 loops=0 source_fps=10.00"),
        "{words}"
    );
    assert!(
        words.contains("frames_read=3 frames_stated=3 truncated=0 "),
        "{words}"
    );
    assert_eq!(cx.health.status().sent, 3);
    assert_ne!(
        cx.health.status().report_wall_ns,
        0,
        "reported before the end"
    );
}

#[test]
fn a_truncated_file_publishes_what_it_has_and_says_so_before_its_end() {
    let (open, _) = scripted(vec![]);
    let (mut stage, queue, mut cx) = playing(
        settings(true, Speed::Max),
        MemorySource::file(4, 10),
        open,
        Output::memory(CAMERA),
    );
    run_due(&mut stage, &mut cx, 10);
    assert!(stage.finished());
    assert_eq!(queue.borrow().len(), 5);
    assert!(words(&stage).contains("frames_read=4 frames_stated=10 truncated=1 "));

    // A file that breaks mid-way: what was decodable, then the end.
    let broken = Box::new(MemorySource {
        after: Err(()),
        ..MemorySource {
            next: 0,
            count: 2,
            after: Ok(ReadOutcome::EndOfFile),
            stated: 10,
            fps: 10.0,
        }
    });
    let (open, _) = scripted(vec![]);
    let (mut stage, queue, mut cx) = playing(
        settings(true, Speed::Max),
        broken,
        open,
        Output::memory(CAMERA),
    );
    run_due(&mut stage, &mut cx, 10);
    assert!(stage.finished());
    assert_eq!(sent(&queue).last(), Some(&(0, 0, 0, true)));
    assert_eq!(queue.borrow().len(), 3);
}

#[test]
fn a_looped_file_starts_again_from_its_first_frame_on_the_same_clock() {
    let mut s = settings(true, Speed::Max);
    s.loop_file = true;
    let (open, calls) = scripted(vec![Ok(MemorySource::file(2, 2))]);
    let (mut stage, queue, mut cx) =
        playing(s, MemorySource::file(2, 2), open, Output::memory(CAMERA));
    run_due(&mut stage, &mut cx, 5);
    assert!(!stage.finished());
    assert_eq!(*calls.borrow(), 1, "reopened once");
    let frames = queue.borrow();
    let indices: Vec<u64> = frames.iter().map(|f| f.header.source_index).collect();
    assert_eq!(indices, [0, 1, 0, 1]);
    let times: Vec<i64> = frames
        .iter()
        .map(|f| f.header.preamble().capture_time_ns)
        .collect();
    assert_eq!(
        times,
        [0, 1, 2, 3].map(|i| 1_000_000_000 + i * 100_000_000),
        "the file clock goes on"
    );
    assert!(words(&stage).starts_with("reconnects=0 loops=1"));
}

#[test]
fn a_frame_without_a_sample_to_loan_is_dropped_and_read_again_after_a_retry_alarm() {
    let (open, _) = scripted(vec![]);
    let (mut stage, queue, mut cx) = playing(
        settings(true, Speed::Max),
        MemorySource::file(4, 4),
        open,
        Output::memory_bounded(CAMERA, 2),
    );
    step(&mut stage, &(), &mut cx).unwrap();
    step(&mut stage, &(), &mut cx).unwrap();
    assert_eq!(queue.borrow().len(), 2);
    let before = Instant::now();
    step(&mut stage, &(), &mut cx).unwrap();
    assert_eq!(queue.borrow().len(), 2, "subscribers hold both samples");
    assert_eq!(cx.health.status().dropped, 1);
    let retry = cx.alarm().expect("a retry alarm");
    assert!(retry >= before + LOAN_RETRY, "not at once: no busy loop");
    assert!(retry <= Instant::now() + LOAN_RETRY);
    // The reader lets one go: the same frame (not the next) is published.
    queue.borrow_mut().pop_front();
    step_alarm(&mut stage, &mut cx).unwrap();
    assert_eq!(sent(&queue), [(1, 1, 0, false), (2, 2, 0, false)]);
}

#[test]
fn a_camera_is_reconnected_with_backoff_alarms_and_marks_the_discontinuity() {
    let unavailable = || Err(SourceError::Unavailable("rtsp://cam".into()));
    let (open, calls) = scripted(vec![
        unavailable(),
        unavailable(),
        unavailable(),
        Ok(MemorySource::camera(2)),
        unavailable(),
        Ok(MemorySource::camera(1)),
    ]);
    let (output, queue) = Output::memory(CAMERA);
    let mut stage = CaptureStage::connecting(settings(false, Speed::Max), open, output);
    let mut cx = Context::new(StageKind::Capture, CAMERA, None);
    stage.on_start(&mut cx).unwrap();
    assert_eq!(stage.info(), "source unavailable");
    assert!(words(&stage).contains("source_up=0"));
    let mut delays = Vec::new();
    step(&mut stage, &(), &mut cx).unwrap();
    for _ in 0..3 {
        let at = cx.alarm().expect("the next attempt");
        delays.push((at - Instant::now()).as_millis().div_ceil(100) * 100);
        step_alarm(&mut stage, &mut cx).unwrap();
    }
    assert_eq!(
        delays,
        [100, 200, 400],
        "each a runtime alarm, doubling to the cap"
    );
    assert_eq!(*calls.borrow(), 4);
    // Connected: its frames are due at once (the read blocks in the source).
    run_due(&mut stage, &mut cx, 3);
    assert_eq!(queue.borrow().len(), 2);
    assert_eq!(stage.info(), "source down: other", "lost after two frames");
    // The backoff starts again from its first delay.
    step(&mut stage, &(), &mut cx).unwrap();
    let at = cx.alarm().expect("a retry");
    assert!(at - Instant::now() <= Duration::from_millis(100));
    step_alarm(&mut stage, &mut cx).unwrap();
    run_due(&mut stage, &mut cx, 1);
    assert_eq!(
        sent(&queue),
        [
            (0, 0, 0, false),
            (1, 1, 0, false),
            (0, 0, FLAG_DISCONTINUITY, false)
        ]
    );
    assert!(words(&stage).starts_with("reconnects=1 loops=0 source_fps=25.00 source_up=1"));
    assert!(!stage.finished(), "a camera never ends");
}

#[test]
fn a_source_of_unknown_size_without_a_configured_one_is_a_config_error() {
    struct Sizeless;
    impl FrameSource for Sizeless {
        fn next_index(&self) -> u64 {
            0
        }
        fn read_frame(
            &mut self,
            _: &mut [MaybeUninit<u8>],
            _: FrameFormat,
        ) -> Result<ReadOutcome, SourceError> {
            Ok(ReadOutcome::Lost)
        }
    }
    let (open, _) = scripted(vec![Ok(Box::new(Sizeless))]);
    let (output, _) = Output::memory(CAMERA);
    let mut stage = CaptureStage::connecting(settings(false, Speed::Max), open, output);
    let mut cx = Context::new(StageKind::Capture, CAMERA, None);
    stage.on_start(&mut cx).unwrap();
    let err = step(&mut stage, &(), &mut cx).expect_err("no size");
    assert_eq!(err.code, exit::CONFIG);
    assert!(err.to_string().contains("set width and height"), "{err}");

    // A file that states no frame rate, with none configured.
    let mut s = settings(true, Speed::Max);
    s.size = Some((4, 2));
    let mut nofps = MemorySource {
        next: 0,
        count: 1,
        after: Ok(ReadOutcome::EndOfFile),
        stated: 1,
        fps: 0.0,
    };
    let err = Playback::of(&s, &mut nofps).expect_err("no frame rate");
    assert_eq!(err.code, exit::CONFIG);
    assert!(err.to_string().contains("set fps"), "{err}");
}

/// The stage's counters as a status line shows them.
fn words(stage: &CaptureStage) -> String {
    isochron_runtime::stage::counters_of(stage).0.words()
}

#[test]
fn why_a_camera_is_down_shows_in_status_until_it_opens() {
    let down = |reason| {
        Err(SourceError::Down {
            what: "rtsp://cam".into(),
            reason,
            detail: "test".into(),
        })
    };
    let (open, _) = scripted(vec![
        down(DownReason::Refused),
        down(DownReason::Unauthorized),
        Ok(MemorySource::camera(2)),
    ]);
    let (output, _queue) = Output::memory(CAMERA);
    let mut stage = CaptureStage::connecting(settings(false, Speed::Max), open, output);
    let mut cx = Context::new(StageKind::Capture, CAMERA, None);
    stage.on_start(&mut cx).unwrap();
    step(&mut stage, &(), &mut cx).unwrap();
    assert_eq!(stage.info(), "source down: refused");
    let status = words(&stage);
    assert!(status.contains("down_refused=1"), "{status}");
    assert!(status.contains("down_unauthorized=0"), "{status}");
    step_alarm(&mut stage, &mut cx).unwrap();
    assert_eq!(stage.info(), "source down: unauthorized");
    let status = words(&stage);
    assert!(status.contains("down_refused=0 "), "{status}");
    assert!(status.contains("down_unauthorized=1"), "{status}");
    step_alarm(&mut stage, &mut cx).unwrap();
    assert_eq!(stage.info(), "");
    let status = words(&stage);
    assert!(status.contains("source_up=1"), "{status}");
    for reason in DownReason::ALL {
        assert!(status.contains(&format!("down_{reason}=0")), "{status}");
    }
}
