//! One run: the group started on N cameras, warmed up, watched over the window,
//! measured and evaluated.

use std::path::Path;
use std::time::{Duration, Instant};

use isochron_config::clock::wall_now_ns;
use isochron_tests::{TestSite, clock_ticks_per_s};

use crate::evaluate::{evaluate_gate, evaluate_latency, evaluate_status};
use crate::outcome::{Run, process_count};
use crate::probe::Probe;
use crate::processes::{Group, ShmUsage, interrupted};
use crate::site::{camera_ids, site_body};
use crate::status::StatusBoard;
use crate::{Mode, Options, POLL, PROBE_POLL, STATUS_PERIOD};

/// Runs the group on `n` cameras in `mode`, replaying `video`, and measures it.
pub(crate) fn run_group(opts: &Options, mode: Mode, n: usize, video: &Path) -> Run {
    let cameras = camera_ids(n);
    let run = Run::new(mode, n, process_count(mode, n, opts.per_process));
    let site = TestSite::new(
        &format!("group-{}-{n}", mode.name()),
        &site_body(mode, &cameras, video, (opts.cpu_share, opts.no_detector)),
    );
    remove_stale_nodes();
    let ipc = site.ipc("bench");
    let shm_before = ShmUsage::now();
    let opened = StatusBoard::open(&ipc, &cameras, mode.health_stages()).and_then(|board| {
        let probe = if mode == Mode::DecodeOnly {
            Probe::default()
        } else {
            Probe::open(&ipc, &cameras)?
        };
        Ok((board, probe))
    });
    let (mut board, mut probe) = match opened {
        Ok(o) => o,
        Err(e) => return run.fail(e),
    };
    eprintln!(
        "group: {} N={n}: starting {} processes",
        mode.name(),
        run.processes
    );
    let mut group = Group::spawn(&site, mode, &cameras, opts.per_process);
    let mut watch = Watch {
        group: &mut group,
        board: &mut board,
        probe: &mut probe,
    };
    let run = measure(opts, run, &mut watch, shm_before);
    group.stop();
    drop(probe);
    drop(board);
    drop(ipc);
    drop(site);
    // Let the nodes' shared memory go before the next run.
    std::thread::sleep(Duration::from_secs(1));
    remove_stale_nodes();
    run
}

/// Removes what iceoryx2 nodes of dead processes left in shared memory (a killed
/// process cannot clean up), so that the next run's baseline is clean.
pub(crate) fn remove_stale_nodes() {
    match isochron_runtime::ipc::node_census(true) {
        Ok(census) if !census.dead_removed.is_empty() => eprintln!(
            "group: removed the stale resources of {} dead iceoryx2 node(s)",
            census.dead_removed.len()
        ),
        Ok(_) => {}
        Err(e) => eprintln!("group: {e}"),
    }
}

/// What the bench keeps an eye on while the group runs.
pub(crate) struct Watch<'a> {
    pub(crate) group: &'a mut Group,
    pub(crate) board: &'a mut StatusBoard,
    pub(crate) probe: &'a mut Probe,
}

/// What [`Watch::until`] takes in while it waits.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Intake {
    /// Status reports made from this wall-clock time (ns) on count.
    pub(crate) reports_since_ns: i64,
    /// Stream samples are recorded (else only drained).
    pub(crate) record: bool,
}

impl Intake {
    /// Warm-up: nothing counts.
    pub(crate) const NOTHING: Intake = Intake {
        reports_since_ns: i64::MAX,
        record: false,
    };
}

impl Watch<'_> {
    /// Waits until `until`, reading the streams every [`PROBE_POLL`] and, every
    /// [`POLL`], the status reports and whether a process died.
    pub(crate) fn until(&mut self, until: Instant, intake: Intake) -> Result<(), String> {
        let mut next_check = Instant::now();
        loop {
            if interrupted() {
                return Err("interrupted".into());
            }
            self.probe.poll(intake.record);
            let now = Instant::now();
            if now >= next_check {
                self.board.poll(intake.reports_since_ns);
                if let Some(dead) = self.group.dead() {
                    return Err(dead);
                }
                next_check = now + POLL;
            }
            let left = until.saturating_duration_since(now);
            if left.is_zero() {
                return Ok(());
            }
            std::thread::sleep(left.min(PROBE_POLL));
        }
    }
}

/// Warm-up, measurement window, evaluation.
pub(crate) fn measure(
    opts: &Options,
    mut run: Run,
    watch: &mut Watch,
    shm_before: ShmUsage,
) -> Run {
    if let Err(dead) = watch.until(Instant::now() + opts.warmup, Intake::NOTHING) {
        return run.fail(format!("during warm-up: {dead}"));
    }

    let window_start_ns = wall_now_ns();
    let in_window = Intake {
        reports_since_ns: window_start_ns,
        record: true,
    };
    let t0 = Instant::now();
    let cpu0 = watch.group.cpu_ticks();
    if let Err(dead) = watch.until(t0 + opts.window(run.mode), in_window) {
        return run.fail(dead);
    }
    let cpu1 = watch.group.cpu_ticks();
    let elapsed = t0.elapsed().as_secs_f64();
    let window = (window_start_ns, wall_now_ns());
    let private = watch.group.private_bytes();
    let shm = ShmUsage::now().since(shm_before);

    let per_cpu_s = 100.0 / (clock_ticks_per_s() * elapsed);
    let mut cpu = [0.0; 5];
    for ((m, a), b) in watch.group.members.iter().zip(&cpu0).zip(&cpu1) {
        if let (Some(a), Some(b)) = (a, b) {
            cpu[m.stage] += b.saturating_sub(*a) as f64 * per_cpu_s;
        }
    }
    run.cpu = Some(cpu);
    let mb_per_camera = |bytes: u64| bytes as f64 / 1e6 / run.cameras as f64;
    run.private_mb_per_camera = Some(mb_per_camera(private.iter().sum()));
    run.private_mb_per_stage = Some(private.map(mb_per_camera));
    run.shm_mb_per_camera = Some(mb_per_camera(shm.used));
    run.shm_mapped_mb_per_camera = Some(mb_per_camera(shm.mapped));

    // A window shorter than the report period may hold one report per stage: wait
    // (up to a period) for the next.
    let extra = Instant::now() + STATUS_PERIOD + Duration::from_secs(1);
    let after_window = Intake {
        record: false,
        ..in_window
    };
    while !watch.board.complete() && Instant::now() < extra {
        if let Err(dead) = watch.until(Instant::now() + POLL, after_window) {
            return run.fail(dead);
        }
    }
    let run = evaluate_status(run, watch.board);
    if run.mode == Mode::DecodeOnly {
        return run;
    }
    let window_s = window.1.saturating_sub(window.0) as f64 / 1e9;
    let run = evaluate_latency(run, watch.probe, window);
    evaluate_gate(run, watch.probe, window_s, !opts.no_detector)
}
