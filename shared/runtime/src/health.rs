//! Service health: exit codes, systemd notifications (readiness, watchdog, status),
//! and the periodic one-line status every stage logs and publishes.

use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, OnceLock, Weak};
use std::time::{Duration, Instant};

use crate::counters::{Counters, fingerprint};
use crate::ipc::{Ipc, StatusPublisher};
use crate::topology::StageKind;
use isochron_config::clock::wall_now_ns;
use isochron_wire::{
    CameraId, LAYOUT_VERSION, MAGIC, STAGE_NAME_LEN, STATUS_COUNTERS, STATUS_INFO_LEN, StageStatus,
    fixed_str, to_fixed,
};
use parking_lot::Mutex;

pub use isochron_exit as exit;

/// Loops that still have to call [`notify_ready`] before the process is ready.
static READY_PENDING: AtomicUsize = AtomicUsize::new(1);

/// Sets how many loops (one per camera of a multi-camera process) must call
/// [`notify_ready`] before systemd is told the service is ready. Default 1.
pub fn expect_ready(loops: usize) {
    READY_PENDING.store(loops.max(1), Ordering::Relaxed);
}

/// Tells systemd (if it started us with `Type=notify`) that the service is ready,
/// once every loop of the process has said so (see [`expect_ready`]).
pub fn notify_ready(status: &str) {
    let before = READY_PENDING
        .fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| n.checked_sub(1))
        .unwrap_or(0);
    if before == 1 {
        let _ = sd_notify::notify(&[
            sd_notify::NotifyState::Ready,
            sd_notify::NotifyState::Status(status),
        ]);
    }
}

/// Heartbeats (ms since [`epoch`]) of the loops of this process, one per camera
/// thread: the watchdog is fed only while every live loop beats, so one hung
/// camera of a multi-camera process gets the process restarted.
static HEARTBEATS: Mutex<Vec<Weak<AtomicU64>>> = Mutex::new(Vec::new());

fn epoch() -> Instant {
    static EPOCH: OnceLock<Instant> = OnceLock::new();
    *EPOCH.get_or_init(Instant::now)
}

fn millis_since_epoch(now: Instant) -> u64 {
    now.duration_since(epoch()).as_millis() as u64
}

/// A new heartbeat, registered with the process's watchdog.
fn register_heartbeat(now: Instant) -> Arc<AtomicU64> {
    let beat = Arc::new(AtomicU64::new(millis_since_epoch(now)));
    let mut all = HEARTBEATS.lock();
    all.retain(|w| w.strong_count() > 0);
    all.push(Arc::downgrade(&beat));
    beat
}

/// What [`still_alive`] keeps going for the loop on its thread.
#[derive(Default)]
struct ThisLoop {
    heartbeat: Weak<AtomicU64>,
    publisher: std::rc::Weak<StatusPublisher>,
    last_connect_ms: u64,
}

thread_local! {
    /// The loop on this thread: the last [`Health`] made here.
    static THIS_LOOP: std::cell::RefCell<ThisLoop> = std::cell::RefCell::new(ThisLoop::default());
}

/// When [`still_alive`] last pinged the watchdog, ms since the epoch.
static LAST_BLOCKED_PING_MS: AtomicU64 = AtomicU64::new(0);

/// Says this thread's loop is alive from inside a call that blocks it (a
/// library's progress or interrupt callback while it connects or reads): beats
/// its heartbeat, hands its latest status report to new readers, and feeds the
/// systemd watchdog when due, as the loop's tick does. A loop waiting up to a
/// configured timeout in someone else's code is not hung, and `isochron
/// status` still sees it. Cheap enough for every callback.
pub fn still_alive() {
    let now = Instant::now();
    let now_ms = millis_since_epoch(now);
    THIS_LOOP.with(|this| {
        let mut this = this.borrow_mut();
        if let Some(beat) = this.heartbeat.upgrade() {
            beat.store(now_ms, Ordering::Relaxed);
        }
        if now_ms.saturating_sub(this.last_connect_ms) >= CONNECT_EVERY.as_millis() as u64
            && let Some(publisher) = this.publisher.upgrade()
        {
            publisher.update_connections();
            this.last_connect_ms = now_ms;
        }
    });
    static WATCHDOG_EVERY: OnceLock<Option<Duration>> = OnceLock::new();
    let Some(every) = *WATCHDOG_EVERY.get_or_init(|| sd_notify::watchdog_enabled().map(|d| d / 2))
    else {
        return;
    };
    let last = LAST_BLOCKED_PING_MS.load(Ordering::Relaxed);
    if now_ms.saturating_sub(last) >= every.as_millis() as u64 && all_loops_alive(now, every * 2) {
        let _ = sd_notify::notify(&[sd_notify::NotifyState::Watchdog]);
        LAST_BLOCKED_PING_MS.store(now_ms, Ordering::Relaxed);
    }
}

/// True when every live loop of the process beat within `period` of `now`.
fn all_loops_alive(now: Instant, period: Duration) -> bool {
    let all = HEARTBEATS.lock();
    all_alive(&all, now, period)
}

/// True when every live heartbeat of `beats` is within `period` of `now`.
fn all_alive(beats: &[Weak<AtomicU64>], now: Instant, period: Duration) -> bool {
    let now_ms = millis_since_epoch(now);
    let limit = period.as_millis() as u64;
    beats
        .iter()
        .filter_map(Weak::upgrade)
        .all(|beat| now_ms.saturating_sub(beat.load(Ordering::Relaxed)) <= limit)
}

/// Tells systemd the service is stopping.
pub fn notify_stopping() {
    let _ = sd_notify::notify(&[sd_notify::NotifyState::Stopping]);
}

/// How often new status readers are connected (and handed the latest report).
const CONNECT_EVERY: Duration = Duration::from_millis(200);

/// Number of recent latencies kept for quantiles.
const LATENCY_WINDOW: usize = 512;

/// The status of `stage` of `camera` as it starts in this process: the layout's
/// magic and version, this process's id, started now, nothing counted or
/// reported yet.
pub fn starting_status(camera: CameraId, stage: StageKind) -> StageStatus {
    StageStatus {
        magic: MAGIC,
        layout_version: LAYOUT_VERSION,
        reserved: 0,
        camera,
        stage: to_fixed::<STAGE_NAME_LEN>(stage.name()),
        pid: std::process::id(),
        rate_in: 0.0,
        started_wall_ns: wall_now_ns(),
        report_wall_ns: 0,
        received: 0,
        sent: 0,
        dropped: 0,
        rejected: 0,
        rate_out: 0.0,
        stage_latency_ms: 0.0,
        e2e_latency_p50_ms: 0.0,
        e2e_latency_p99_ms: 0.0,
        schema: fingerprint(stage.counters()),
        counter_count: stage.counters().len() as u32,
        counters: [0.0; STATUS_COUNTERS],
        info: [0; STATUS_INFO_LEN],
    }
}

/// The counters of `status`, read with this build's schema of its stage; `None`
/// when the status names no stage this build knows or was written with other
/// counters (another build: see [`fingerprint`]).
pub fn status_counters(status: &StageStatus) -> Option<Counters> {
    let stage = StageKind::from_name(&fixed_str(&status.stage))?;
    let schema = stage.counters();
    (status.schema == fingerprint(schema) && status.counter_count as usize == schema.len())
        .then(|| Counters::from_slots(schema, status.counters))
}

/// The counters of `status` as `name=value` words and its info, as a status line
/// shows them (`events=3 open=1 … detector=hog`); a status of another build's
/// counters says so.
pub fn status_detail(status: &StageStatus) -> String {
    let info = fixed_str(&status.info);
    let words = match status_counters(status) {
        Some(c) => c.words(),
        None => "(counters of another isochron build)".to_string(),
    };
    if info.is_empty() {
        words
    } else if words.is_empty() {
        info
    } else {
        format!("{words} {info}")
    }
}

/// Counts a stage's work, feeds the watchdog, and every `report_every` logs one
/// status line and publishes it as a [`StageStatus`].
pub struct Health {
    stage: StageKind,
    camera: String,
    status: StageStatus,
    publisher: Option<std::rc::Rc<StatusPublisher>>,
    report_every: Duration,
    last_report: Instant,
    last_counts: (u64, u64),
    watchdog_every: Option<Duration>,
    last_watchdog: Instant,
    last_connect: Instant,
    heartbeat: Arc<AtomicU64>,
    stage_latency_ms: LatencyWindow,
    e2e_latency_ms: LatencyWindow,
    last_sequence: Option<u64>,
    /// A report was asked for at the next tick ([`Health::report_soon`]).
    report_asked: bool,
}

impl Health {
    /// Health of `stage` for `camera`, publishing through `ipc` if given.
    pub fn new(stage: StageKind, camera: &str, ipc: Option<&Ipc>) -> Self {
        let publisher = ipc.and_then(|ipc| match ipc.status_publisher(camera, stage) {
            Ok(p) => Some(std::rc::Rc::new(p)),
            Err(e) => {
                tracing::warn!("status will not be published: {e}");
                None
            }
        });
        let now = Instant::now();
        let heartbeat = register_heartbeat(now);
        THIS_LOOP.with(|this| {
            *this.borrow_mut() = ThisLoop {
                heartbeat: Arc::downgrade(&heartbeat),
                publisher: publisher
                    .as_ref()
                    .map_or_else(std::rc::Weak::new, std::rc::Rc::downgrade),
                last_connect_ms: 0,
            };
        });
        Health {
            stage,
            camera: camera.to_string(),
            status: starting_status(CameraId::new(camera).unwrap_or(CameraId([0; 24])), stage),
            publisher,
            report_every: Duration::from_secs(5),
            last_report: now,
            last_counts: (0, 0),
            // Ping at half the watchdog period, as systemd recommends.
            watchdog_every: sd_notify::watchdog_enabled().map(|d| d / 2),
            last_watchdog: now,
            last_connect: now,
            heartbeat,
            stage_latency_ms: LatencyWindow::default(),
            e2e_latency_ms: LatencyWindow::default(),
            last_sequence: None,
            report_asked: false,
        }
    }

    /// Sets how often a status line is logged and published (default 5 s).
    pub fn report_every(mut self, every: Duration) -> Self {
        self.report_every = every;
        self
    }

    /// True when the first report (or the next one) is due; the first is due at
    /// the first tick, so `isochron status` sees a service as soon as it runs.
    fn report_due(&self, now: Instant) -> bool {
        self.report_asked
            || self.status.report_wall_ns == 0
            || now.duration_since(self.last_report) >= self.report_every
    }

    /// Reports at the next tick rather than when the next report is due: for a
    /// change of state `isochron status` should show at once (a camera down).
    pub fn report_soon(&mut self) {
        self.report_asked = true;
    }

    /// Counts a received sample with `sequence`; a gap counts as dropped upstream.
    /// A sequence that goes backwards means the publisher restarted.
    pub fn received(&mut self, sequence: u64) {
        self.status.received += 1;
        if let Some(last) = self.last_sequence
            && sequence > last + 1
        {
            self.status.dropped += sequence - last - 1;
        }
        self.last_sequence = Some(sequence);
    }

    /// Counts a read that did not come through a stream (capture's frames).
    pub fn read_one(&mut self) {
        self.status.received += 1;
    }

    /// Counts a sample dropped by this stage.
    pub fn dropped(&mut self, n: u64) {
        self.status.dropped += n;
    }

    /// Counts a malformed sample.
    pub fn rejected(&mut self) {
        self.status.rejected += 1;
    }

    /// Counts a published sample: `arrived` is when its input arrived here,
    /// `origin_wall_ns` when capture published the frame it came from (0 if unknown).
    pub fn sent(&mut self, arrived: Option<Instant>, origin_wall_ns: i64) {
        self.status.sent += 1;
        if let Some(t) = arrived {
            self.stage_latency_ms.push(t.elapsed().as_secs_f32() * 1e3);
        }
        if origin_wall_ns > 0 {
            self.e2e_latency_ms
                .push((wall_now_ns() - origin_wall_ns) as f32 / 1e6);
        }
    }

    /// Counters so far.
    pub fn status(&self) -> &StageStatus {
        &self.status
    }

    /// Call often from the main loop: feeds the watchdog and, when due, reports.
    /// `counters` gives the stage's counters and info text.
    pub fn tick(&mut self, counters: impl FnOnce() -> (Counters, String)) {
        let now = self.keep_alive();
        if self.report_due(now) {
            let (c, info) = counters();
            self.report(&c, &info);
        }
    }

    /// All-zero counters of this health's stage, for the stage to fill.
    pub fn counters(&self) -> Counters {
        Counters::new(self.stage.counters())
    }

    /// Says this loop is alive (call it also while waiting, e.g. between reconnect
    /// attempts) and feeds the systemd watchdog when due and every loop of the
    /// process is alive.
    pub fn keep_alive(&mut self) -> Instant {
        let now = Instant::now();
        // A reader that just subscribed gets the latest report now, not at the
        // next one (every `report_every`).
        if let Some(p) = &self.publisher
            && now.duration_since(self.last_connect) >= CONNECT_EVERY
        {
            p.update_connections();
            self.last_connect = now;
        }
        self.heartbeat
            .store(millis_since_epoch(now), Ordering::Relaxed);
        if let Some(every) = self.watchdog_every
            && now.duration_since(self.last_watchdog) >= every
            && all_loops_alive(now, every * 2)
        {
            let _ = sd_notify::notify(&[sd_notify::NotifyState::Watchdog]);
            self.last_watchdog = now;
        }
        now
    }

    /// Logs and publishes the status now, with the stage's `counters` and `info`.
    pub fn report(&mut self, counters: &Counters, info: &str) {
        let now = Instant::now();
        let secs = now.duration_since(self.last_report).as_secs_f32().max(1e-3);
        let s = &mut self.status;
        s.rate_in = (s.received - self.last_counts.0) as f32 / secs;
        s.rate_out = (s.sent - self.last_counts.1) as f32 / secs;
        self.last_counts = (s.received, s.sent);
        s.stage_latency_ms = self.stage_latency_ms.quantile(0.5);
        s.e2e_latency_p50_ms = self.e2e_latency_ms.quantile(0.5);
        s.e2e_latency_p99_ms = self.e2e_latency_ms.quantile(0.99);
        s.report_wall_ns = wall_now_ns();
        s.counters = counters.slots();
        s.info = to_fixed::<STATUS_INFO_LEN>(info);
        let detail = status_detail(s);
        self.last_report = now;
        self.report_asked = false;
        tracing::info!(
            stage = self.stage.name(),
            camera = %self.camera,
            "{} {detail}",
            s.counters()
        );
        let _ = sd_notify::notify(&[sd_notify::NotifyState::Status(&format!(
            "in={} out={} dropped={} {detail}",
            s.received, s.sent, s.dropped
        ))]);
        if let Some(p) = &self.publisher
            && let Err(e) = p.publish(*s)
        {
            tracing::debug!("status publish failed: {e}");
        }
    }
}

/// How much of a video file capture read, against the frame count the file
/// states. Capture puts it into its last status's counters before the end of
/// stream, where `isochron replay` reads it back.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct InputCompleteness {
    /// Frames decoded.
    pub frames_read: u64,
    /// Frames the file states it has (0 if it does not say).
    pub frames_stated: u64,
    /// The file ended well before (more than one frame) the count it states.
    pub truncated: bool,
}

impl InputCompleteness {
    /// `read` frames of a file stating `stated` (0: unknown). One frame short is
    /// not truncation: containers often state one frame more than they hold.
    pub fn of(read: u64, stated: u64) -> Self {
        InputCompleteness {
            frames_read: read,
            frames_stated: stated,
            truncated: stated > 0 && read + 1 < stated,
        }
    }

    /// Into capture's counters.
    pub fn set(&self, c: &mut Counters) {
        use crate::counters::capture;
        c.set(capture::FRAMES_READ, self.frames_read);
        c.set(capture::FRAMES_STATED, self.frames_stated);
        c.set(capture::TRUNCATED, self.truncated);
    }

    /// Read back from a capture status; `None` if it has none (a camera, or a
    /// file not ended yet).
    pub fn from_status(status: &StageStatus) -> Option<Self> {
        use crate::counters::capture;
        let c = status_counters(status)?;
        let read = c.get(capture::FRAMES_READ) as u64;
        (read > 0).then(|| InputCompleteness {
            frames_read: read,
            frames_stated: c.get(capture::FRAMES_STATED) as u64,
            truncated: c.get(capture::TRUNCATED) > 0.0,
        })
    }
}

/// The most recent 512 values (latencies), for their quantiles.
#[derive(Debug, Default)]
pub struct LatencyWindow {
    values: Vec<f32>,
    cursor: usize,
}

impl LatencyWindow {
    /// Adds `v`, replacing the oldest value once the window is full.
    pub fn push(&mut self, v: f32) {
        if self.values.len() < LATENCY_WINDOW {
            self.values.push(v);
        } else {
            self.values[self.cursor] = v;
            self.cursor = (self.cursor + 1) % LATENCY_WINDOW;
        }
    }

    /// The `q` quantile (0..=1) of the values (0 if none).
    pub fn quantile(&self, q: f64) -> f32 {
        quantile(&self.values, q)
    }
}

/// The `q` quantile (0..=1) of `values` (0 if empty).
pub fn quantile(values: &[f32], q: f64) -> f32 {
    if values.is_empty() {
        return 0.0;
    }
    let mut v = values.to_vec();
    v.sort_by(|a, b| a.total_cmp(b));
    let i = ((v.len() - 1) as f64 * q).round() as usize;
    v[i.min(v.len() - 1)]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::topology::StageKind;

    #[test]
    fn sequence_gaps_count_as_dropped() {
        let mut h = Health::new(StageKind::Motion, "cam01", None);
        for s in [0, 1, 2, 5, 6] {
            h.received(s);
        }
        assert_eq!(h.status().received, 5);
        assert_eq!(h.status().dropped, 2);
        // A restarted publisher starts again at 0: not a gap.
        h.received(0);
        assert_eq!(h.status().dropped, 2);
    }

    #[test]
    fn the_watchdog_is_fed_only_while_every_loop_beats() {
        let start = Instant::now();
        let beat = || Arc::new(AtomicU64::new(millis_since_epoch(start)));
        let (a, b) = (beat(), beat());
        let beats = [Arc::downgrade(&a), Arc::downgrade(&b)];
        let period = Duration::from_secs(5);
        assert!(all_alive(&beats, start, period));
        let later = start + Duration::from_secs(10);
        assert!(!all_alive(&beats, later, period));
        a.store(millis_since_epoch(later), Ordering::Relaxed);
        assert!(!all_alive(&beats, later, period), "b hangs");
        drop(b); // b's loop ended normally: it no longer counts
        assert!(all_alive(&beats, later, period));
    }

    #[test]
    fn input_completeness_travels_in_a_status() {
        let cut = InputCompleteness::of(318, 795);
        assert!(cut.truncated);
        assert!(
            !InputCompleteness::of(794, 795).truncated,
            "one short is fine"
        );
        assert!(!InputCompleteness::of(795, 795).truncated);
        assert!(!InputCompleteness::of(12, 0).truncated, "unknown count");
        let mut h = Health::new(StageKind::Capture, "cam01", None);
        let mut c = h.counters();
        assert_eq!(InputCompleteness::from_status(h.status()), None);
        cut.set(&mut c);
        h.report(&c, "");
        assert_eq!(InputCompleteness::from_status(h.status()), Some(cut));
        assert!(
            status_detail(h.status()).contains("frames_read=318 frames_stated=795 truncated=1")
        );
    }

    #[test]
    fn counters_longer_than_the_old_160_byte_detail_arrive_whole() {
        use crate::counters::costmap;
        let mut h = Health::new(StageKind::Costmap, "", None);
        let mut c = h.counters();
        for (k, spec) in StageKind::Costmap.counters().iter().enumerate() {
            c.set(crate::counters::CounterId(k), 1_000_000_000u64 + k as u64);
            assert!(!spec.name.is_empty());
        }
        h.report(&c, "");
        let words = status_detail(h.status());
        assert!(words.len() > 160, "{} bytes: {words}", words.len());
        let back = status_counters(h.status()).unwrap();
        assert_eq!(
            back.get(costmap::ROUTE_SERVER_UP),
            1_000_000_021.0,
            "the last one, whole"
        );
        assert!(words.ends_with("route_server_up=1000000021"), "{words}");
    }

    #[test]
    fn a_status_of_other_counters_is_not_read_as_ours() {
        let mut h = Health::new(StageKind::Gate, "cam01", None);
        let mut c = h.counters();
        c.set(crate::counters::gate::EVENTS, 7u64);
        h.report(&c, "detector=hog");
        let mut s = *h.status();
        assert_eq!(
            status_counters(&s)
                .unwrap()
                .get(crate::counters::gate::EVENTS),
            7.0
        );
        assert!(status_detail(&s).ends_with("detector=hog"));
        s.schema ^= 1;
        assert!(status_counters(&s).is_none());
        assert!(status_detail(&s).contains("another isochron build"));
    }

    #[test]
    fn quantiles() {
        let v: Vec<f32> = (1..=100).map(|x| x as f32).collect();
        assert_eq!(quantile(&v, 0.5), 51.0);
        assert_eq!(quantile(&v, 0.99), 99.0);
        assert_eq!(quantile(&[], 0.5), 0.0);
    }
}
