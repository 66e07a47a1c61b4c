//! The criteria a run holds by: rates, drops, latencies, events and detections.

use isochron_runtime::health::quantile;
use isochron_runtime::topology::StageKind;

use crate::outcome::Run;
use crate::probe::Probe;
use crate::site::camera_ids;
use crate::status::StatusBoard;
use crate::{
    BUSY_S, FPS, MAX_DETECTION_MS, MAX_END_LAG_MS, MAX_P99_MS, MIN_RATE_SHARE, Mode, P99_GROWTH,
    P99_GROWTH_FLOOR_MS, QUIET_S,
};

/// The cameras that failed one criterion, summed up as one reason.
#[derive(Default)]
pub(crate) struct Offenders {
    pub(crate) cameras: Vec<usize>,
    /// The worst camera and its value.
    pub(crate) worst: Option<(usize, f64)>,
}

impl Offenders {
    /// Notes camera `i` with `value`; `worse(a, b)` says whether `a` is worse.
    pub(crate) fn add(&mut self, i: usize, value: f64, worse: fn(f64, f64) -> bool) {
        self.cameras.push(i);
        if self.worst.is_none_or(|(_, w)| worse(value, w)) {
            self.worst = Some((i, value));
        }
    }

    /// Notes camera `i` (no value).
    pub(crate) fn add_camera(&mut self, i: usize) {
        self.cameras.push(i);
    }

    /// "`what` on k camera(s) (worst V`unit` on camX)", if any camera failed.
    pub(crate) fn reason(&self, what: &str, unit: &str, cameras: &[String]) -> Option<String> {
        let first = *self.cameras.first()?;
        let detail = match self.worst {
            Some((i, v)) => format!("worst {v:.1}{unit} on {}", cameras[i]),
            None => format!("e.g. {}", cameras[first]),
        };
        Some(format!(
            "{what} on {} camera(s) ({detail})",
            self.cameras.len()
        ))
    }
}

/// A stage may drop at most one sample in this many it handled in the window: a
/// run fails on drops that say the stage falls behind, not on one late wake-up.
pub(crate) const DROP_BUDGET: u64 = 10_000;

/// Whether `(dropped, handled)` is over [`DROP_BUDGET`] (any drop in a window
/// shorter than the budget is over it).
fn over_budget((dropped, handled): (u64, u64)) -> bool {
    dropped > handled / DROP_BUDGET
}

/// Applies the rate and drop criteria to the status reports of the window.
pub(crate) fn evaluate_status(mut run: Run, board: &StatusBoard) -> Run {
    let cameras = camera_ids(run.cameras);
    let stages = run.mode.health_stages();
    let min_rate = FPS * MIN_RATE_SHARE;
    let lower = |a: f64, b: f64| a < b;
    let higher = |a: f64, b: f64| a > b;
    let mut silent: Vec<Offenders> = stages.iter().map(|_| Offenders::default()).collect();
    let mut slow: Vec<Offenders> = stages.iter().map(|_| Offenders::default()).collect();
    let mut dropping: Vec<Offenders> = stages.iter().map(|_| Offenders::default()).collect();
    // Per stage: samples dropped and samples handled (dropped ones included).
    let mut budget: Vec<(u64, u64)> = vec![(0, 0); stages.len()];
    // The stage whose rate is `min_fps`: motion, or capture when it runs alone.
    let paced = if run.mode == Mode::DecodeOnly {
        StageKind::Capture
    } else {
        StageKind::Motion
    };
    let (mut min_fps, mut gate_min_fps, mut drops) = (f64::INFINITY, f64::INFINITY, 0u64);
    let mut jobs = Some((0u64, 0u64));

    for (i, per_stage) in board.tracks.iter().enumerate() {
        for (s, track) in per_stage.iter().enumerate() {
            let Some(w) = track.window() else {
                silent[s].add_camera(i);
                continue;
            };
            if track.stage != StageKind::Cascade && w.rate < min_rate {
                slow[s].add(i, w.rate, lower);
            }
            if track.stage == paced {
                min_fps = min_fps.min(w.rate);
            }
            if track.stage == StageKind::Gate {
                gate_min_fps = gate_min_fps.min(w.rate);
                jobs = jobs.zip(w.jobs).map(|((a, d), (wa, wd))| (a + wa, d + wd));
            }
            if track.stage != StageKind::Capture {
                budget[s].0 += w.dropped;
                budget[s].1 += w.done + w.dropped;
                if w.dropped > 0 {
                    drops += w.dropped;
                    dropping[s].add(i, w.dropped as f64, higher);
                }
            }
        }
    }

    let all_reported = |stage: StageKind| {
        stages
            .iter()
            .position(|&s| s == stage)
            .is_none_or(|s| silent[s].cameras.is_empty())
    };
    if all_reported(paced) {
        run.min_fps = Some(min_fps);
    }
    if stages.contains(&StageKind::Gate) && all_reported(StageKind::Gate) {
        run.gate_min_fps = Some(gate_min_fps);
        run.jobs_accepted = jobs.map(|j| j.0);
        run.jobs_dropped = jobs.map(|j| j.1);
    }
    if stages.iter().all(|&s| all_reported(s)) && run.mode != Mode::DecodeOnly {
        run.drops = Some(drops);
    }
    for (s, stage) in stages.iter().enumerate() {
        let what = if *stage == StageKind::Gate {
            "took frames at"
        } else {
            "published"
        };
        let reasons = [
            silent[s].reason(
                &format!("{stage} made fewer than 2 status reports in the window"),
                "",
                &cameras,
            ),
            slow[s].reason(
                &format!("{stage} {what} below {min_rate:.2} fps"),
                " fps",
                &cameras,
            ),
            over_budget(budget[s])
                .then(|| dropping[s].reason(&format!("{stage} dropped samples"), "", &cameras))
                .flatten()
                .map(|r| {
                    format!(
                        "{r}: {} of {} (budget 1 in {DROP_BUDGET})",
                        budget[s].0, budget[s].1
                    )
                }),
        ];
        run.failures.extend(reasons.into_iter().flatten());
    }
    run
}

/// Applies the latency criteria to the activity samples of `window` (wall-clock ns):
/// every camera delivered activity, the p99 is under [`MAX_P99_MS`], and the second
/// half's p99 is not more than [`P99_GROWTH`] times the first half's.
pub(crate) fn evaluate_latency(mut run: Run, probe: &Probe, window: (i64, i64)) -> Run {
    let cameras = camera_ids(run.cameras);
    let p99 = |half: Option<bool>| {
        let mid = window.0 + (window.1 - window.0) / 2;
        let values: Vec<f32> = probe
            .samples
            .iter()
            .filter(|(t, _, _)| half.is_none_or(|second| (*t >= mid) == second))
            .map(|(_, _, ms)| *ms)
            .collect();
        (!values.is_empty()).then(|| quantile(&values, 0.99))
    };

    let mut received = vec![0usize; run.cameras];
    let mut worst: Option<(usize, f32)> = None;
    for &(_, camera, ms) in &probe.samples {
        received[camera] += 1;
        if worst.is_none_or(|(_, w)| ms > w) {
            worst = Some((camera, ms));
        }
    }
    let mut silent = Offenders::default();
    for (i, _) in received.iter().enumerate().filter(|(_, n)| **n == 0) {
        silent.add_camera(i);
    }
    run.failures
        .extend(silent.reason("no activity arrived in the window", "", &cameras));

    run.p99_ms = p99(None);
    if let (Some(p), Some((camera, max))) = (run.p99_ms, worst)
        && p >= MAX_P99_MS
    {
        run.failures.push(format!(
            "capture→activity p99 {p:.0} ms ≥ {MAX_P99_MS:.0} ms (worst {max:.0} ms on {})",
            cameras[camera]
        ));
    }
    if let (Some(first), Some(second)) = (p99(Some(false)), p99(Some(true)))
        && second > P99_GROWTH * first
        && second > P99_GROWTH_FLOOR_MS
    {
        run.failures.push(format!(
            "capture→activity p99 grew from {first:.0} ms (first half) to {second:.0} ms (second half)"
        ));
    }
    run
}

/// Applies the gate's criteria to the event records and detections of a window of
/// `window_s` seconds: end lag and detection latency bounded, the detector ran
/// (when `detecting`), and (in a window of two cycles or more) every camera ended
/// an event.
pub(crate) fn evaluate_gate(mut run: Run, probe: &Probe, window_s: f64, detecting: bool) -> Run {
    let cameras = camera_ids(run.cameras);
    run.events_started = probe.started.iter().sum();
    run.events_ended = probe.ended.iter().sum();
    run.detections = probe.detected.iter().sum();
    let p99 = |v: &[f32]| (!v.is_empty()).then(|| quantile(v, 0.99));
    run.end_lag_p99_ms = p99(&probe.end_lags_ms);
    run.detection_p99_ms = p99(&probe.detection_ms);
    if let Some(p) = run.end_lag_p99_ms
        && p >= MAX_END_LAG_MS
    {
        run.failures.push(format!(
            "event end lag p99 {p:.0} ms ≥ {MAX_END_LAG_MS:.0} ms"
        ));
    }
    if let Some(p) = run.detection_p99_ms
        && p >= MAX_DETECTION_MS
    {
        run.failures.push(format!(
            "detection latency p99 {p:.0} ms ≥ {MAX_DETECTION_MS:.0} ms"
        ));
    }
    if detecting && run.events_started > 0 && run.detections == 0 {
        run.failures
            .push("events started but the detector never ran in the window".into());
    }
    let cycle_s = f64::from(BUSY_S + QUIET_S);
    if window_s >= 2.0 * cycle_s {
        let mut idle = Offenders::default();
        for (i, _) in probe.ended.iter().enumerate().filter(|(_, n)| **n == 0) {
            idle.add_camera(i);
        }
        run.failures.extend(idle.reason(
            &format!("no event ended in a window of {window_s:.0} s"),
            "",
            &cameras,
        ));
    }
    run
}
