//! Which frames of a network camera were read behind the live edge.
//!
//! Opening a stream, FFmpeg reads up to a second of it to learn its parameters
//! and hands those packets back first: their frames are read a few milliseconds
//! apart, though the camera sent them a frame interval apart. Their capture time
//! is not known (capture stamps a frame when it reads it), so they must not start
//! a run that motion differences: capture flags them `FLAG_DISCONTINUITY`, and
//! motion's run starts at the first frame read live.
//!
//! A frame's offset is when it was read minus its presentation time. A frame
//! cannot be read before it was sent, so the smallest offset seen is the
//! stream's clock plus the shortest delay; a frame whose offset undercuts every
//! earlier one by more than half a frame interval was read faster than the
//! camera sent it: it was buffered. Late frames (a network hiccup) have larger
//! offsets, and a camera clock that drifts moves the offset by far less than
//! half an interval per frame, so neither is flagged.

use std::time::Duration;

/// Never less than this: jitter of a fast camera is not a buffered frame.
const MIN_TOLERANCE: Duration = Duration::from_millis(10);

/// Tracks the smallest read-minus-presentation offset of one open stream.
#[derive(Debug, Clone)]
pub struct LiveEdge {
    tolerance_ns: i128,
    min_offset_ns: Option<i128>,
}

impl LiveEdge {
    /// For a stream stating `fps` frames a second (0: unknown).
    pub fn new(fps: f64) -> Self {
        let half_interval = match fps {
            f if f.is_finite() && f > 0.0 => {
                isochron_config::clock::saturating_secs((0.5 / f).min(60.0))
            }
            _ => Duration::ZERO,
        };
        LiveEdge {
            tolerance_ns: half_interval.max(MIN_TOLERANCE).as_nanos() as i128,
            min_offset_ns: None,
        }
    }

    /// True if the frame presented at `pts_ns` (stream time) and read at
    /// `read_ns` (a monotonic clock) was read behind the live edge. A frame
    /// without a presentation time is taken as live.
    pub fn behind(&mut self, pts_ns: Option<i128>, read_ns: i128) -> bool {
        let Some(pts_ns) = pts_ns else {
            return false;
        };
        let offset = read_ns - pts_ns;
        match self.min_offset_ns {
            Some(min) if offset >= min => false,
            Some(min) => {
                self.min_offset_ns = Some(offset);
                min - offset > self.tolerance_ns
            }
            None => {
                self.min_offset_ns = Some(offset);
                false
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: i128 = 1_000_000;

    /// Feeds (pts ms, read ms) pairs; returns which were behind.
    fn run(fps: f64, frames: &[(i128, i128)]) -> Vec<bool> {
        let mut edge = LiveEdge::new(fps);
        frames
            .iter()
            .map(|&(pts, read)| edge.behind(Some(pts * MS), read * MS))
            .collect()
    }

    #[test]
    fn the_second_buffered_while_opening_is_behind_and_live_frames_are_not() {
        // Ten frames at 10 fps read 3 ms apart at 1000 ms, then live ones.
        let mut frames: Vec<(i128, i128)> = (0..10).map(|i| (i * 100, 1000 + i * 3)).collect();
        frames.extend((10..20).map(|i| (i * 100, 1000 + (i - 9) * 100 + 5)));
        let behind = run(10.0, &frames);
        // The first frame cannot be judged (capture flags a newly opened
        // stream's first frame itself); the other nine were buffered.
        assert_eq!(
            &behind[..10],
            &[false, true, true, true, true, true, true, true, true, true]
        );
        assert!(behind[10..].iter().all(|b| !b), "{behind:?}");
    }

    #[test]
    fn jitter_late_frames_and_a_drifting_clock_are_live() {
        // 25 fps: reads jitter by up to 15 ms, one frame comes 400 ms late and
        // the ones queued behind it arrive together, and the camera's clock
        // runs 0.1 % fast.
        let frames: Vec<(i128, i128)> = (0..200)
            .map(|i| {
                let pts = i * 40;
                let jitter = (i * 7919) % 16;
                let late = if (50..60).contains(&i) {
                    400 - (i - 50) * 40
                } else {
                    0
                };
                (pts, 20 + pts - pts / 1000 + jitter + late)
            })
            .collect();
        assert!(run(25.0, &frames).iter().all(|b| !b));
    }

    #[test]
    fn a_frame_without_a_presentation_time_is_live() {
        let mut edge = LiveEdge::new(10.0);
        assert!(!edge.behind(Some(0), 1000 * MS));
        assert!(!edge.behind(None, 1001 * MS));
        assert!(edge.behind(Some(500 * MS), 1002 * MS));
    }

    #[test]
    fn an_unknown_or_absurd_rate_still_judges_with_the_floor() {
        for fps in [0.0, f64::NAN, f64::INFINITY, -3.0] {
            let behind = run(fps, &[(0, 1000), (100, 1001), (200, 1100)]);
            assert_eq!(behind, [false, true, false], "fps {fps}");
        }
    }
}
