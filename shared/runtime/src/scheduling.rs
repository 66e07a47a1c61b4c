//! Where a stage's threads stand in the CPU queue. Decoding is the bulk of a
//! camera box's CPU and never in a hurry (a late frame is only late); the
//! analysis stages wake for each frame and must run soon after it arrives. So
//! capture runs `SCHED_BATCH` at `site.capture_nice`, the others as started.
//! Set on the main thread before any other starts; threads inherit it.

use isochron_config::SiteConfig;

use crate::topology::StageKind;

/// The policy and nice value `stage` runs at under `site`: `None` leaves the
/// process as it was started (the analysis stages, or capture with
/// `capture_nice = 0`).
pub fn policy(stage: StageKind, site: &SiteConfig) -> Option<i32> {
    (stage == StageKind::Capture && site.capture_nice > 0).then_some(site.capture_nice)
}

/// Applies [`policy`] to the calling thread (and so to the threads it starts
/// after). Lowering one's own priority needs no privilege; a failure is logged
/// and the stage runs on as started.
pub fn apply(stage: StageKind, site: &SiteConfig) {
    let Some(nice) = policy(stage, site) else {
        return;
    };
    let param = libc::sched_param { sched_priority: 0 };
    // SAFETY: plain system calls on the calling thread with a valid parameter.
    let batch = unsafe { libc::sched_setscheduler(0, libc::SCHED_BATCH, &param) };
    if batch != 0 {
        let err = std::io::Error::last_os_error();
        tracing::warn!("capture stays at the normal scheduling policy: SCHED_BATCH: {err}");
    }
    // SAFETY: as above; `who` 0 is the calling thread on Linux.
    let reniced = unsafe { libc::setpriority(libc::PRIO_PROCESS, 0, nice) };
    if reniced != 0 {
        let err = std::io::Error::last_os_error();
        tracing::warn!("capture stays at its nice value: setpriority({nice}): {err}");
    } else {
        tracing::debug!("capture runs SCHED_BATCH at nice {nice}, behind the analysis stages");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_capture_yields_and_zero_turns_it_off() {
        let mut site = SiteConfig::default();
        assert_eq!(policy(StageKind::Capture, &site), Some(5));
        assert_eq!(policy(StageKind::Motion, &site), None);
        assert_eq!(policy(StageKind::Gate, &site), None);
        site.capture_nice = 0;
        assert_eq!(policy(StageKind::Capture, &site), None);
    }

    #[test]
    fn the_calling_thread_runs_batch_at_the_nice_value() {
        // On a thread of its own, so the test harness keeps its priority.
        std::thread::Builder::new()
            .name("capture-like".into())
            .spawn(|| {
                apply(StageKind::Capture, &SiteConfig::default());
                // SAFETY: reads the calling thread's policy.
                let policy = unsafe { libc::sched_getscheduler(0) };
                assert_eq!(policy, libc::SCHED_BATCH);
                // SAFETY: reads the calling thread's nice value.
                let nice = unsafe { libc::getpriority(libc::PRIO_PROCESS, 0) };
                assert!(nice >= 5, "nice {nice}");
            })
            .unwrap()
            .join()
            .unwrap();
    }
}
