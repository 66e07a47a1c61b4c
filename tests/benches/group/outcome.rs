//! What one run at N cameras measured, and whether it held.

use crate::{COSTMAP, Mode};

/// What one run at N cameras measured.
#[derive(Debug, Clone)]
pub(crate) struct Run {
    pub(crate) mode: Mode,
    pub(crate) cameras: usize,
    pub(crate) processes: usize,
    /// CPU per stage ([`STAGES`]), % of one core.
    pub(crate) cpu: Option<[f64; 5]>,
    /// Lowest capture rate (decode-only) or motion rate of any camera, frames/s.
    pub(crate) min_fps: Option<f64>,
    /// Lowest rate of frames the gate took of any camera, frames/s.
    pub(crate) gate_min_fps: Option<f64>,
    /// Samples motion, cascade and gate dropped in the window.
    pub(crate) drops: Option<u64>,
    /// p99 latency capture → activity over all cameras in the window, ms.
    pub(crate) p99_ms: Option<f32>,
    /// Events started and ended in the window, all cameras.
    pub(crate) events_started: u64,
    pub(crate) events_ended: u64,
    /// p99 event end lag in the window, ms.
    pub(crate) end_lag_p99_ms: Option<f32>,
    /// Detections published in the window, all cameras.
    pub(crate) detections: u64,
    /// p99 detection latency (capture publication → detections arrival), ms.
    pub(crate) detection_p99_ms: Option<f32>,
    /// Detection jobs the gates accepted and dropped, all cameras: from their last
    /// status report before the window to their last in it.
    pub(crate) jobs_accepted: Option<u64>,
    pub(crate) jobs_dropped: Option<u64>,
    /// Private memory of the group per camera, MB.
    pub(crate) private_mb_per_camera: Option<f64>,
    /// Private memory per stage ([`STAGES`]) per camera, MB.
    pub(crate) private_mb_per_stage: Option<[f64; 5]>,
    /// Growth of the memory in use in `/dev/shm` per camera, MB.
    pub(crate) shm_mb_per_camera: Option<f64>,
    /// Growth of the size of the files in `/dev/shm` per camera, MB.
    pub(crate) shm_mapped_mb_per_camera: Option<f64>,
    /// Load average (1 min) when the run started.
    pub(crate) load_before: Option<f64>,
    /// Why it did not hold (empty: it held).
    pub(crate) failures: Vec<String>,
}

impl Run {
    pub(crate) fn new(mode: Mode, cameras: usize, processes: usize) -> Run {
        Run {
            mode,
            cameras,
            processes,
            cpu: None,
            min_fps: None,
            gate_min_fps: None,
            drops: None,
            p99_ms: None,
            events_started: 0,
            events_ended: 0,
            end_lag_p99_ms: None,
            detections: 0,
            detection_p99_ms: None,
            jobs_accepted: None,
            jobs_dropped: None,
            private_mb_per_camera: None,
            private_mb_per_stage: None,
            shm_mb_per_camera: None,
            shm_mapped_mb_per_camera: None,
            load_before: load_average(),
            failures: Vec::new(),
        }
    }

    pub(crate) fn held(&self) -> bool {
        self.failures.is_empty()
    }

    pub(crate) fn fail(mut self, reason: String) -> Run {
        self.failures.push(reason);
        self
    }
}

/// The 1-minute load average (`/proc/loadavg`).
pub(crate) fn load_average() -> Option<f64> {
    std::fs::read_to_string("/proc/loadavg")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// Processes the group has for `n` cameras, `per_process` per process, in `mode`.
pub(crate) fn process_count(mode: Mode, n: usize, per_process: usize) -> usize {
    let per_camera = mode.stages().iter().filter(|&&s| s != COSTMAP).count();
    let site_wide = usize::from(mode.stages().contains(&COSTMAP));
    per_camera * n.div_ceil(per_process) + site_wide
}
