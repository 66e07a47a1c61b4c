//! The stages' status reports within the measurement window.

use isochron_runtime::counters::{CounterId, gate};
use isochron_runtime::health::status_counters;
use isochron_runtime::ipc::{Ipc, StatusSubscriber};
use isochron_runtime::topology::StageKind;
use isochron_wire::StageStatus;

use crate::probe::Window;

/// The status reports of one stage of one camera within the measurement window.
pub(crate) struct Track {
    pub(crate) stage: StageKind,
    pub(crate) subscriber: StatusSubscriber,
    /// The newest report made before the window's start.
    pub(crate) before: Option<StageStatus>,
    /// The first report made at or after the window's start.
    pub(crate) first: Option<StageStatus>,
    /// The newest report.
    pub(crate) last: Option<StageStatus>,
}

impl Track {
    /// Both ends of the window, if the stage reported twice in it.
    pub(crate) fn span(&self) -> Option<(&StageStatus, &StageStatus)> {
        match (&self.first, &self.last) {
            (Some(a), Some(b)) if b.report_wall_ns > a.report_wall_ns => Some((a, b)),
            _ => None,
        }
    }
}

/// The status reports of a mode's health stages for every camera.
pub(crate) struct StatusBoard {
    /// Per camera, per health stage.
    pub(crate) tracks: Vec<Vec<Track>>,
}

impl StatusBoard {
    pub(crate) fn open(
        ipc: &Ipc,
        cameras: &[String],
        stages: &[StageKind],
    ) -> Result<StatusBoard, String> {
        let mut tracks = Vec::with_capacity(cameras.len());
        for camera in cameras {
            let mut per_stage = Vec::with_capacity(stages.len());
            for &stage in stages {
                let subscriber = ipc
                    .status_subscriber(camera, stage)
                    .map_err(|e| format!("status of {stage}/{camera}: {e}"))?;
                per_stage.push(Track {
                    stage,
                    subscriber,
                    before: None,
                    first: None,
                    last: None,
                });
            }
            tracks.push(per_stage);
        }
        Ok(StatusBoard { tracks })
    }

    /// Takes the new reports; those made before `since_ns` (wall clock) are ignored.
    pub(crate) fn poll(&mut self, since_ns: i64) {
        for track in self.tracks.iter_mut().flatten() {
            if let Some(report) = track.subscriber.latest()
                && report.validate().is_ok()
            {
                if report.report_wall_ns < since_ns {
                    track.before = Some(report);
                } else {
                    track.first.get_or_insert(report);
                    track.last = Some(report);
                }
            }
        }
    }

    /// True when every stage of every camera reported twice in the window.
    pub(crate) fn complete(&self) -> bool {
        self.tracks.iter().flatten().all(|t| t.span().is_some())
    }
}

/// Counter `id` of a status report (`None` if it was written with other counters).
pub(crate) fn counter(status: &StageStatus, id: CounterId) -> Option<u64> {
    status_counters(status).map(|c| c.get(id) as u64)
}

impl Track {
    /// The window between the first and the last report, if there were two.
    pub(crate) fn window(&self) -> Option<Window> {
        let (a, b) = self.span()?;
        let seconds = (b.report_wall_ns - a.report_wall_ns) as f64 / 1e9;
        let between =
            |x: &StageStatus, id: CounterId| Some(counter(b, id)?.saturating_sub(counter(x, id)?));
        let done = if self.stage == StageKind::Gate {
            between(a, gate::FRAMES_SEEN).unwrap_or(0)
        } else {
            b.sent.saturating_sub(a.sent)
        };
        // Counters of what is rare next to the report period (detection jobs)
        // span the whole window: from the last report before it.
        let from = self.before.as_ref().unwrap_or(a);
        Some(Window {
            rate: done as f64 / seconds,
            done,
            dropped: b.dropped.saturating_sub(a.dropped),
            jobs: between(from, gate::JOBS).zip(between(from, gate::JOBS_DROPPED)),
        })
    }
}
