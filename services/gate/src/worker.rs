//! The detector runs on its own thread, fed through a short queue: when the queue
//! is full a new job is dropped and counted, so a slow detector never delays the
//! activity path (events are published as activity arrives, whatever the detector
//! is doing). The detectors of all cameras of a site share a few slots
//! ([`DetectorSlots`]), each busy at most a configured share of the time, so that
//! the costly detector's CPU stays bounded however many cameras and gate
//! processes the site runs.

use std::fs::{File, TryLockError};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TryRecvError, TrySendError, sync_channel};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use isochron_runtime::stage::Waker;
use isochron_wire::Detection;
use parking_lot::Mutex;

use crate::detector::{Detector, DetectorError, Region};
use crate::ring::{FrameRing, StoredFrame};

/// A request to run the detector on the latest frame at or before `time_ns`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Job {
    /// Per-gate job number: the gate hears back about every job under it.
    pub id: u64,
    /// The event that gated it.
    pub event_id: u64,
    /// Capture time of the frame to detect on (the latest at or before it).
    pub time_ns: i64,
    /// Where in the frame to search.
    pub region: Region,
    /// Wall clock (UTC ns) at which capture published that frame (the activity
    /// sample's `origin_wall_ns`): carried into the detections, for their latency.
    pub origin_wall_ns: i64,
}

/// A finished detection.
#[derive(Debug, Clone, PartialEq)]
pub struct Outcome {
    /// The job.
    pub job_id: u64,
    /// Where the detector searched.
    pub region: Region,
    /// The event that gated it.
    pub event_id: u64,
    /// Capture time of the detected frame.
    pub capture_time_ns: i64,
    /// The job's `origin_wall_ns`.
    pub origin_wall_ns: i64,
    /// Source index of the detected frame.
    pub source_index: u64,
    /// People found.
    pub detections: Vec<Detection>,
    /// Detector time.
    pub detector_us: u64,
}

/// The detections that may run at once on a site, shared by the detector threads
/// of all its gate processes: `limit` lock files, one held (`flock`) per running
/// detection. The kernel drops the lock of a process that dies, so a crash never
/// leaks a slot. After each detection its slot stays taken for a rest in
/// proportion ([`DetectorSlots::rest_after`]), so that a slot's detections use
/// at most `cpu_share` of `threads` cores whoever holds it.
pub struct DetectorSlots {
    files: Vec<PathBuf>,
    cpu_share: f64,
    threads: u32,
}

/// What a detection cost its slot.
#[derive(Debug, Clone, Copy)]
pub struct Busy {
    /// Wall-clock time.
    pub wall: Duration,
    /// CPU time of the detecting thread.
    pub thread_cpu: Duration,
}

/// A running detection's slot, given back when dropped (closing the file unlocks).
pub struct Slot(#[allow(dead_code, reason = "held for its lock, never read")] File);

impl DetectorSlots {
    /// How often a job that waits for a slot tries again.
    const RETRY: Duration = Duration::from_millis(5);

    /// The slots of the site whose services run under `service_prefix`: lock files
    /// in `/dev/shm` (shared memory the services may write anyway), or the
    /// temporary directory where there is none. Each runs one detection at a time
    /// on `threads` threads, busy at most `cpu_share` of the time.
    pub fn of_site(
        service_prefix: &str,
        limit: usize,
        (threads, cpu_share): (u32, f64),
    ) -> std::io::Result<Self> {
        let shm = Path::new("/dev/shm");
        let dir = if shm.is_dir() {
            shm.to_path_buf()
        } else {
            std::env::temp_dir()
        };
        let name: String = service_prefix
            .chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() || "-_.".contains(c) {
                    c
                } else {
                    '_'
                }
            })
            .collect();
        Self::in_dir(
            &dir,
            &format!("{name}.detector-slot"),
            limit,
            (threads, cpu_share),
        )
    }

    /// `limit` slots as files `<dir>/<stem>.<n>`, created if missing.
    pub fn in_dir(
        dir: &Path,
        stem: &str,
        limit: usize,
        (threads, cpu_share): (u32, f64),
    ) -> std::io::Result<Self> {
        let files: Vec<PathBuf> = (0..limit.max(1))
            .map(|n| dir.join(format!("{stem}.{n}")))
            .collect();
        for file in &files {
            File::options()
                .create(true)
                .truncate(false)
                .write(true)
                .open(file)
                .map_err(|e| {
                    std::io::Error::new(e.kind(), format!("detector slot {}: {e}", file.display()))
                })?;
        }
        Ok(DetectorSlots {
            files,
            cpu_share: cpu_share.clamp(0.01, 1.0),
            threads: threads.max(1),
        })
    }

    /// How long a slot stays taken after a detection that cost it `busy`, so that
    /// its detections use at most `cpu_share` of its `threads` cores (nothing at
    /// 1). One thread detects on the worker's own: its CPU time is the cost, and
    /// a detection slowed by a busy box does not lengthen the rest. More threads
    /// work beside it, so the cost is the wall-clock time.
    pub fn rest_after(&self, busy: Busy) -> Duration {
        if self.cpu_share >= 1.0 {
            return Duration::ZERO;
        }
        let cost = if self.threads == 1 {
            busy.thread_cpu
        } else {
            busy.wall
        };
        cost.mul_f64(1.0 / self.cpu_share - 1.0)
    }

    /// A free slot, waiting for one up to `patience` (`None`: as long as it takes);
    /// `None` if every slot stayed taken.
    pub fn acquire(&self, patience: Option<Duration>) -> Option<Slot> {
        let deadline = patience.map(|p| Instant::now() + p);
        loop {
            for path in &self.files {
                // A fresh open per try: a lock belongs to one open file, so two
                // threads of one process exclude each other as processes do.
                let file = match File::open(path) {
                    Ok(f) => f,
                    Err(e) => {
                        tracing::warn!("detector slot {}: {e}", path.display());
                        continue;
                    }
                };
                match file.try_lock() {
                    Ok(()) => return Some(Slot(file)),
                    Err(TryLockError::WouldBlock) => {}
                    Err(TryLockError::Error(e)) => {
                        tracing::warn!("locking detector slot {}: {e}", path.display());
                    }
                }
            }
            if deadline.is_some_and(|d| Instant::now() >= d) {
                return None;
            }
            std::thread::sleep(Self::RETRY);
        }
    }
}

/// What the worker thread sends back.
#[derive(Debug)]
pub enum Report {
    /// A detection ran.
    Done(Outcome),
    /// Every detector slot of the process was busy: the job was dropped.
    Busy(Job),
    /// The job's frame was no longer in the ring.
    FrameGone(Job),
    /// The detector failed on a frame.
    Failed(Job, String),
}

/// Handle to the detector thread.
pub struct Worker {
    jobs: Option<SyncSender<Job>>,
    /// Set when the worker is dropped: queued jobs are abandoned.
    closed: Arc<AtomicBool>,
    reports: Receiver<Report>,
    thread: Option<JoinHandle<()>>,
    /// Jobs accepted.
    pub submitted: u64,
    /// Jobs dropped because the queue was full.
    pub dropped: u64,
    /// Reports received.
    pub completed: u64,
}

impl Worker {
    /// Starts the thread; `make` builds the detector on it (OpenCV objects stay on
    /// the thread that made them). Fails if the detector cannot be built. With a
    /// `queue` of 0 a job is handed over only when the detector takes it, so the
    /// frame it names is copied out of the ring before anything can replace it.
    /// A job runs only in a free slot of `slots`; it waits for one up to
    /// `slot_wait` (`None`, lossless replays: as long as it takes), then is dropped.
    /// Each report wakes the stage through `waker`.
    pub fn start(
        make: impl FnOnce() -> Result<Detector, DetectorError> + Send + 'static,
        ring: Arc<Mutex<FrameRing>>,
        queue: usize,
        slots: Arc<DetectorSlots>,
        slot_wait: Option<Duration>,
        waker: Waker,
    ) -> Result<(Worker, &'static str), DetectorError> {
        let (jobs_tx, jobs_rx) = sync_channel::<Job>(queue);
        let (reports_tx, reports_rx) = sync_channel::<Report>(1024);
        let (ready_tx, ready_rx) = sync_channel::<Result<&'static str, DetectorError>>(1);
        let closed = Arc::new(AtomicBool::new(false));
        let closing = closed.clone();
        let thread = std::thread::Builder::new()
            .name("detector".into())
            .spawn(move || {
                let mut detector = match make() {
                    Ok(d) => {
                        let _ = ready_tx.send(Ok(d.name()));
                        d
                    }
                    Err(e) => {
                        let _ = ready_tx.send(Err(e));
                        return;
                    }
                };
                let mut frame = StoredFrame::default();
                while let Ok(job) = jobs_rx.recv() {
                    if closing.load(Ordering::Relaxed) {
                        break; // stopping: what is still queued is abandoned
                    }
                    let Some(_slot) = slots.acquire(slot_wait) else {
                        if reports_tx.send(Report::Busy(job)).is_err() {
                            break;
                        }
                        waker.wake();
                        continue;
                    };
                    let found = ring.lock().copy_latest_at(job.time_ns, &mut frame);
                    let (t0, cpu0) = (Instant::now(), thread_cpu_time());
                    let report = if !found {
                        Report::FrameGone(job)
                    } else {
                        match detector.detect(&frame.pixels, frame.width, frame.height, job.region)
                        {
                            Ok(detections) => Report::Done(Outcome {
                                job_id: job.id,
                                region: job.region,
                                event_id: job.event_id,
                                capture_time_ns: frame.capture_time_ns,
                                origin_wall_ns: job.origin_wall_ns,
                                source_index: frame.source_index,
                                detections,
                                detector_us: t0.elapsed().as_micros() as u64,
                            }),
                            Err(e) => Report::Failed(job, e.to_string()),
                        }
                    };
                    let busy = Busy {
                        wall: t0.elapsed(),
                        thread_cpu: thread_cpu_time().saturating_sub(cpu0),
                    };
                    if reports_tx.send(report).is_err() {
                        break;
                    }
                    waker.wake();
                    // The slot rests before it is given back (`_slot` drops here).
                    rest(slots.rest_after(busy), &closing);
                }
            })
            .map_err(DetectorError::Thread)?;
        let name = ready_rx.recv().map_err(|_| DetectorError::ThreadDied)??;
        Ok((
            Worker {
                jobs: Some(jobs_tx),
                closed,
                reports: reports_rx,
                thread: Some(thread),
                submitted: 0,
                dropped: 0,
                completed: 0,
            },
            name,
        ))
    }

    /// Queues a job; drops (and counts) it if the detector is busy and the queue
    /// is full. Never blocks.
    pub fn submit(&mut self, job: Job) -> bool {
        let Some(jobs) = &self.jobs else { return false };
        match jobs.try_send(job) {
            Ok(()) => {
                self.submitted += 1;
                true
            }
            Err(TrySendError::Full(_)) | Err(TrySendError::Disconnected(_)) => {
                self.dropped += 1;
                false
            }
        }
    }

    /// Reports that arrived, without waiting.
    pub fn reports(&mut self) -> Vec<Report> {
        let mut out = Vec::new();
        loop {
            match self.reports.try_recv() {
                Ok(r) => {
                    self.completed += 1;
                    out.push(r);
                }
                Err(TryRecvError::Empty) | Err(TryRecvError::Disconnected) => return out,
            }
        }
    }

    /// Jobs queued or running.
    pub fn pending(&self) -> u64 {
        self.submitted - self.completed
    }
}

/// CPU time the calling thread has used (zero if the clock cannot be read).
fn thread_cpu_time() -> Duration {
    let mut t = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `t` is a valid timespec for the call to write.
    if unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut t) } != 0 {
        return Duration::ZERO;
    }
    Duration::new(
        t.tv_sec.max(0) as u64,
        t.tv_nsec.clamp(0, 999_999_999) as u32,
    )
}

/// Sleeps `length`, or less if the worker is closed meanwhile.
fn rest(length: Duration, closed: &AtomicBool) {
    const STEP: Duration = Duration::from_millis(20);
    let end = Instant::now() + length;
    loop {
        let now = Instant::now();
        if now >= end || closed.load(Ordering::Relaxed) {
            return;
        }
        std::thread::sleep((end - now).min(STEP));
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        // The thread ends after its current job; queued jobs are abandoned (a
        // process with many cameras must stop in time, not run them all first).
        self.closed.store(true, Ordering::Relaxed);
        self.jobs = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A ring holding one textured `w × h` frame, at time 0, and its pixels.
    fn ring_with_frame(w: u32, h: u32) -> (Arc<Mutex<FrameRing>>, Vec<u8>) {
        let pixels: Vec<u8> = (0..w * h).map(|i| ((i % w) ^ (i / w)) as u8).collect();
        let ring = Arc::new(Mutex::new(FrameRing::new(1)));
        ring.lock().push(0, 0, w, h, &pixels);
        (ring, pixels)
    }

    /// A worker running HOG with `config` (no network is installed under `.`),
    /// waiting for a slot as long as it takes.
    fn hog_worker(
        config: isochron_config::DetectorConfig,
        ring: Arc<Mutex<FrameRing>>,
        queue: usize,
        slots: Arc<DetectorSlots>,
    ) -> Worker {
        let (_wakeup, waker) = isochron_runtime::stage::Wakeup::new().expect("a wake-up");
        let make = move || Detector::from_config(&config, std::path::Path::new("."));
        Worker::start(make, ring, queue, slots, None, waker)
            .expect("HOG detector")
            .0
    }

    /// A detection job on the whole of the frame at time 0.
    const WHOLE_FRAME_JOB: Job = Job {
        id: 0,
        event_id: 1,
        time_ns: 0,
        region: Region::WHOLE,
        origin_wall_ns: 0,
    };

    /// Slots in the temporary directory, private to one test.
    fn test_slots(test: &str, limit: usize) -> DetectorSlots {
        let stem = format!("isochron-{}-{test}", std::process::id());
        DetectorSlots::in_dir(&std::env::temp_dir(), &stem, limit, (1, 1.0)).expect("slot files")
    }

    #[test]
    fn detector_slots_bound_what_runs_at_once() {
        let slots = test_slots("bound", 2);
        let a = slots.acquire(Some(Duration::ZERO)).expect("first slot");
        let _b = slots.acquire(Some(Duration::ZERO)).expect("second slot");
        assert!(
            slots.acquire(Some(Duration::ZERO)).is_none(),
            "both slots busy: dropped"
        );
        drop(a);
        assert!(
            slots.acquire(Some(Duration::ZERO)).is_some(),
            "a freed slot is reused"
        );
    }

    #[test]
    fn the_site_shares_its_slots_and_a_dead_holder_frees_its_own() {
        let slots = test_slots("site", 1);
        // Another process holds the only slot, with flock(2) as a gate does.
        let mut holder = std::process::Command::new("python3")
            .args([
                "-c",
                "import fcntl, sys, time\nf = open(sys.argv[1])\nfcntl.flock(f, fcntl.LOCK_EX)\ntime.sleep(30)",
            ])
            .arg(&slots.files[0])
            .spawn()
            .expect("python3");
        let deadline = Instant::now() + Duration::from_secs(10);
        while slots.acquire(Some(Duration::ZERO)).is_some() {
            assert!(Instant::now() < deadline, "the other process never locked");
            std::thread::sleep(Duration::from_millis(10));
        }
        assert!(
            test_slots("site", 1)
                .acquire(Some(Duration::ZERO))
                .is_none(),
            "a second gate of the site sees the slot taken"
        );
        holder.kill().unwrap();
        holder.wait().unwrap();
        assert!(
            slots.acquire(Some(Duration::ZERO)).is_some(),
            "the kernel released the dead holder's lock"
        );
    }

    #[test]
    fn a_dropped_worker_abandons_its_queued_jobs() {
        // A full-HD frame: each HOG run takes a good fraction of a second.
        let (w, h) = (1920u32, 1080u32);
        let (ring, pixels) = ring_with_frame(w, h);
        let slots = Arc::new(test_slots("abandon", 1));
        let held = slots.acquire(Some(Duration::ZERO)).expect("the only slot");
        // At upscale 1: a shorter test, and the point is the same.
        let config = isochron_config::DetectorConfig {
            hog_upscale: 1.0,
            ..Default::default()
        };
        let again = config.clone();
        let mut worker = hog_worker(config, ring, 8, slots.clone());
        // The first job waits for the slot; eight more wait in the queue.
        assert!(worker.submit(WHOLE_FRAME_JOB));
        std::thread::sleep(Duration::from_millis(50));
        for _ in 0..8 {
            assert!(worker.submit(WHOLE_FRAME_JOB));
        }
        let t0 = Instant::now();
        let one_run = std::thread::scope(|scope| {
            scope.spawn(move || {
                std::thread::sleep(Duration::from_millis(100));
                drop(held);
            });
            drop(worker);
            t0.elapsed()
        });
        // The job that had the slot runs; the eight queued ones do not.
        let per_run = {
            let mut d = Detector::from_config(&again, std::path::Path::new(".")).unwrap();
            let t = Instant::now();
            d.detect(&pixels, w, h, Region::WHOLE).unwrap();
            t.elapsed()
        };
        assert!(
            one_run < Duration::from_millis(100) + per_run * 4,
            "stopping took {one_run:?}; one detection takes {per_run:?}"
        );
    }

    #[test]
    fn a_slot_rests_in_proportion_to_its_detections() {
        let stem = format!("isochron-{}-rest", std::process::id());
        let dir = std::env::temp_dir();
        let quarter = DetectorSlots::in_dir(&dir, &stem, 1, (1, 0.25)).expect("slot files");
        let busy = Busy {
            wall: Duration::from_millis(500),
            thread_cpu: Duration::from_millis(100),
        };
        assert_eq!(
            quarter.rest_after(busy),
            Duration::from_millis(300),
            "one thread: its CPU time"
        );
        let two_threads = DetectorSlots::in_dir(&dir, &stem, 1, (2, 0.25)).expect("slot files");
        assert_eq!(
            two_threads.rest_after(busy),
            Duration::from_millis(1500),
            "more: wall time"
        );
        assert_eq!(test_slots("whole", 1).rest_after(busy), Duration::ZERO);

        // A worker detects once, then keeps the site's only slot for its rest.
        let (ring, _) = ring_with_frame(640, 480);
        let mut worker = hog_worker(Default::default(), ring, 1, Arc::new(quarter));
        assert!(worker.submit(WHOLE_FRAME_JOB));
        let deadline = Instant::now() + Duration::from_secs(30);
        let busy = loop {
            if let Some(Report::Done(outcome)) = worker.reports().pop() {
                break Duration::from_micros(outcome.detector_us);
            }
            assert!(Instant::now() < deadline, "no detection");
            std::thread::sleep(Duration::from_millis(1));
        };
        let done = Instant::now();
        let other = DetectorSlots::in_dir(&dir, &stem, 1, (1, 1.0)).expect("slot files");
        assert!(
            other.acquire(Some(Duration::ZERO)).is_none(),
            "the slot rests after a detection of {busy:?}"
        );
        assert!(other.acquire(Some(Duration::from_secs(30))).is_some());
        let rested = done.elapsed();
        // Three times the detection's CPU time, which is at most its wall time.
        assert!(
            rested < busy * 3 + Duration::from_secs(1),
            "rested {rested:?} after a detection of {busy:?}"
        );
    }

    #[test]
    fn a_waiting_job_gets_the_next_free_slot() {
        let slots = Arc::new(test_slots("wait", 1));
        let held = slots.acquire(Some(Duration::ZERO)).expect("slot");
        let waiter = {
            let slots = slots.clone();
            let waiter = std::thread::Builder::new().name("waiter".into());
            waiter.spawn(move || slots.acquire(None).is_some()).unwrap()
        };
        std::thread::sleep(Duration::from_millis(50));
        assert!(!waiter.is_finished(), "it waits while the slot is taken");
        drop(held);
        assert!(waiter.join().unwrap());
    }
}
