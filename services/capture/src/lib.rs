//! isochron-capture: reads a camera or a video file and publishes its frames.
//!
//! * [`source`]: OpenCV sources (files, V4L2, GStreamer), decoding straight
//!   into shared memory;
//! * [`stream`]: network cameras through FFmpeg's libraries: transport,
//!   deadlines, damaged frames held back, luma straight into shared memory;
//! * [`down`]: why a live camera is down ([`down::DownReason`]);
//! * [`Stamper`]: capture times — the wall clock for live sources, `start + i/fps`
//!   for files so recordings replay on a simulated clock;
//! * [`Pacer`]: real-time (or `speed`×) pacing of file playback;
//! * [`Backoff`]: exponential reconnect delays for sources that drop out;
//! * [`stage`]: the capture stage (source → `frames`), a source stage of the
//!   runtime: pacing, reconnect backoff and loan retries are its alarms;
//! * [`camera`]: the service's `run`: the stage of a configured camera.

pub mod camera;
pub mod down;
pub mod live_edge;
pub mod source;
pub mod stage;
pub mod stream;

use std::time::{Duration, Instant};

use isochron_config::clock::{NS_PER_S, wall_now_ns};

/// Assigns capture times to frames.
#[derive(Debug, Clone)]
pub enum Stamper {
    /// Live sources: the UTC wall clock when the frame was read.
    Wall,
    /// File sources: `start_ns + index / fps`.
    File {
        /// Capture time of frame 0.
        start_ns: i64,
        /// Frames per second of the recording.
        fps: f64,
    },
}

impl Stamper {
    /// Capture time of the frame with overall `index` (counting across loops).
    pub fn stamp(&self, index: u64) -> i64 {
        match self {
            Stamper::Wall => wall_now_ns(),
            Stamper::File { start_ns, fps } => {
                start_ns + ((index as f64) * (NS_PER_S as f64) / fps).round() as i64
            }
        }
    }
}

/// Paces file playback: frame `i` is due at `t0 + i / (fps × speed)`.
#[derive(Debug, Clone)]
pub struct Pacer {
    t0: Instant,
    period: Option<Duration>,
}

impl Pacer {
    /// A pacer for `fps` at `speed` (`None` = as fast as possible).
    pub fn new(fps: f64, speed: Option<f64>) -> Self {
        Pacer {
            t0: Instant::now(),
            period: speed.map(|s| isochron_config::clock::saturating_secs(1.0 / (fps * s))),
        }
    }

    /// When frame `index` is due: `t0 + index / (fps × speed)`; `None` unpaced
    /// (every frame is due at once).
    pub fn due(&self, index: u64) -> Option<Instant> {
        self.period.map(|p| self.t0 + p.mul_f64(index as f64))
    }

    /// How long to wait before frame `index` is due (zero if late or unpaced).
    pub fn wait_for(&self, index: u64) -> Duration {
        self.due(index).map_or(Duration::ZERO, |due| {
            due.saturating_duration_since(Instant::now())
        })
    }
}

/// How long after a streaming camera dropped it is retried every `initial`
/// before the delays start doubling: most outages (a camera rebooting, a switch
/// port flapping, an RTSP server restarted) end within it.
pub const FAST_RETRY_WINDOW: Duration = Duration::from_secs(60);

/// Reconnect delays: `initial`, doubling, capped at `max`; reset on success.
/// After a camera that was streaming dropped ([`Backoff::dropped`]) the delays
/// stay at `initial` for [`FAST_RETRY_WINDOW`] first.
#[derive(Debug, Clone)]
pub struct Backoff {
    initial: Duration,
    max: Duration,
    next: Duration,
    attempts: u32,
    fast_until: Option<Instant>,
}

impl Backoff {
    /// A backoff from `initial` up to `max`.
    pub fn new(initial: Duration, max: Duration) -> Self {
        Backoff {
            initial,
            max,
            next: initial,
            attempts: 0,
            fast_until: None,
        }
    }

    /// The delay before the next attempt after one that failed at `now`, and
    /// the failed attempt's number (1-based).
    pub fn next_delay(&mut self, now: Instant) -> (Duration, u32) {
        self.attempts += 1;
        if self.fast_until.is_some_and(|until| now < until) {
            return (self.initial, self.attempts);
        }
        let delay = self.next;
        self.next = (self.next * 2).min(self.max);
        (delay, self.attempts)
    }

    /// Failed attempts since the last success.
    pub fn attempts(&self) -> u32 {
        self.attempts
    }

    /// Back to the initial delay after a success.
    pub fn reset(&mut self) {
        self.next = self.initial;
        self.attempts = 0;
        self.fast_until = None;
    }

    /// A camera that was streaming dropped at `now`: retried every `initial`
    /// for [`FAST_RETRY_WINDOW`], then backing off as from the start.
    pub fn dropped(&mut self, now: Instant) {
        self.reset();
        self.fast_until = Some(now + FAST_RETRY_WINDOW);
    }
}

/// How a source of one size fits the configured analysis size.
#[derive(Debug, Clone, PartialEq)]
pub enum Rescale {
    /// The sizes are equal.
    None,
    /// Resized with the same aspect ratio (within 1 %): worth an info line.
    SameAspect(String),
    /// Resized and stretched: the aspect ratio changes by more than 1 %, which
    /// distorts every shape (masks, zones, floor points, people): worth a warning.
    Stretched(String),
}

/// What rescaling camera `camera`'s `source` size to the configured `target` size
/// (both `(width, height)`) means, with the line to log.
pub fn rescale(camera: &str, source: (u32, u32), target: (u32, u32)) -> Rescale {
    if source == target {
        return Rescale::None;
    }
    let aspect = |(w, h): (u32, u32)| w as f64 / h.max(1) as f64;
    let change = (aspect(target) / aspect(source) - 1.0) * 100.0;
    let (sw, sh) = source;
    let (tw, th) = target;
    if change.abs() > 1.0 {
        Rescale::Stretched(format!(
            "camera '{camera}': the source is {sw}x{sh}, rescaled to the configured {tw}x{th} (aspect ratio changes by {:.1} %)",
            change.abs()
        ))
    } else {
        Rescale::SameAspect(format!(
            "camera '{camera}': the source is {sw}x{sh}, rescaled to the configured {tw}x{th} (same aspect ratio)"
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn file_stamps_are_start_plus_index_over_fps() {
        let s = Stamper::File {
            start_ns: 1_000,
            fps: 10.0,
        };
        assert_eq!(s.stamp(0), 1_000);
        assert_eq!(s.stamp(1), 1_000 + NS_PER_S / 10);
        assert_eq!(s.stamp(795), 1_000 + 79_500_000_000);
        // 30000/1001 fps does not drift: stamps are computed, not accumulated.
        let ntsc = Stamper::File {
            start_ns: 0,
            fps: 30000.0 / 1001.0,
        };
        assert_eq!(ntsc.stamp(30000), 1001 * NS_PER_S);
    }

    #[test]
    fn backoff_doubles_to_the_cap_and_resets() {
        let now = Instant::now();
        let mut b = Backoff::new(Duration::from_millis(500), Duration::from_secs(3));
        let delays: Vec<_> = (0..5).map(|_| b.next_delay(now).0.as_millis()).collect();
        assert_eq!(delays, [500, 1000, 2000, 3000, 3000]);
        assert_eq!(b.next_delay(now).1, 6);
        b.reset();
        assert_eq!(b.next_delay(now), (Duration::from_millis(500), 1));
    }

    #[test]
    fn a_dropped_camera_is_retried_every_initial_delay_for_a_minute_then_backs_off() {
        let t0 = Instant::now();
        let mut b = Backoff::new(Duration::from_millis(500), Duration::from_secs(30));
        b.next_delay(t0);
        b.dropped(t0);
        let at = |s: u64| t0 + Duration::from_secs(s);
        for s in [0, 10, 30, 59] {
            assert_eq!(
                b.next_delay(at(s)).0,
                Duration::from_millis(500),
                "at {s} s"
            );
        }
        let after: Vec<_> = (0..3).map(|_| b.next_delay(at(61)).0.as_millis()).collect();
        assert_eq!(after, [500, 1000, 2000]);
        assert_eq!(b.next_delay(at(62)).1, 8);
        // A success ends the fast window.
        b.reset();
        b.next_delay(at(63));
        assert_eq!(b.next_delay(at(63)).0, Duration::from_millis(1000));
    }

    #[test]
    fn unpaced_never_waits_and_paced_waits_for_future_frames() {
        assert_eq!(Pacer::new(10.0, None).wait_for(1000), Duration::ZERO);
        let p = Pacer::new(10.0, Some(1.0));
        assert!(p.wait_for(10) > Duration::from_millis(900));
        assert_eq!(p.wait_for(0), Duration::ZERO);
    }

    #[test]
    fn a_stretching_rescale_is_told_apart_from_a_same_aspect_one() {
        assert_eq!(rescale("c", (768, 576), (768, 576)), Rescale::None);
        assert_eq!(
            rescale("c", (768, 576), (384, 288)),
            Rescale::SameAspect(
                "camera 'c': the source is 768x576, rescaled to the configured 384x288 (same aspect ratio)"
                    .into()
            )
        );
        // 1920x1080 → 1280x720 is the same 16:9; 1920x1088 (a codec's padding) is
        // within 1 %.
        assert!(matches!(
            rescale("c", (1920, 1088), (1280, 720)),
            Rescale::SameAspect(_)
        ));
        assert_eq!(
            rescale("cam01", (768, 576), (640, 360)),
            Rescale::Stretched(
                "camera 'cam01': the source is 768x576, rescaled to the configured 640x360 (aspect ratio changes by 33.3 %)"
                    .into()
            )
        );
        let Rescale::Stretched(m) = rescale("c", (640, 480), (640, 640)) else {
            panic!("4:3 to 1:1 stretches");
        };
        assert!(m.ends_with("(aspect ratio changes by 25.0 %)"), "{m}");
    }
}
