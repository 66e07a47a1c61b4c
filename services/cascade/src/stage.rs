//! The cascade stage: `motion` in, 1-Hz `activity` out, the long-term store
//! updated once per completed minute — run by the stage runtime
//! ([`isochron_runtime::stage`]).
//!
//! A store write that fails with an I/O error (a full disk) or because the store
//! became unwritable while running (a disk remounted read-only) does not end the
//! cascade: that minute is not learned, the failure is warned about (rate-limited)
//! and counted (`store_failures=` in the status detail), and the next minute tries
//! again. Permanent store errors (foreign, damaged, another grid, a store that
//! cannot be written when the cascade starts) end it with their code, which no
//! supervisor restarts. When the camera's size is configured, the
//! cascade knows the grid the config gives and rejects samples of any other grid
//! before they can create or reach the store.

use std::path::PathBuf;
use std::time::Instant;

use isochron_config::clock::{SiteClock, wall_now_ns};
use isochron_config::{CameraConfig, LoadedConfig};
use isochron_exit::{self as exit, Classify, Fatal};
use isochron_runtime::counters::{Counters, cascade};
use isochron_runtime::ipc::{Activity, Ipc, Motion};
use isochron_runtime::service::ServiceContext;
use isochron_runtime::stage::{self, Context, Input, Output, Stage};
use isochron_runtime::topology::StageKind;
use isochron_store::{Store, StoreError, StoreMeta, store_path};
use isochron_wire::geometry::BlockGrid;
use isochron_wire::{CameraId, MotionHeader};

use crate::{Cascade, Params, PushError, Reject, SecondOut, TimedStore};

/// Serves the camera of `ctx` (the `main` of isochron-cascade): opens the stage
/// and runs it until the process is asked to stop.
pub fn run(ctx: ServiceContext) -> Result<(), Fatal> {
    let camera = ctx.camera();
    let (mut cascade, motion) = CascadeStage::open(&ctx.ipc, &ctx.config, camera)?;
    isochron_runtime::stage::run(&ctx.ipc, &camera.id, &mut cascade, &motion)
}

/// Consecutive samples of another grid after which the cascade gives up: motion runs
/// with other settings for good, and the store cannot follow.
const GRID_MISMATCH_LIMIT: u32 = 30;

/// The cascade of one camera with its store and output.
pub struct CascadeStage<'ipc> {
    camera: String,
    camera_id: CameraId,
    params: Params,
    clock: SiteClock,
    cycle: isochron_config::clock::Cycle,
    path: PathBuf,
    store: Option<TimedStore>,
    resume: Option<isochron_store::Baseline>,
    cascade: Option<Cascade>,
    output: Output<'ipc, Activity>,
    grid_mismatches: u32,
    /// The grid the config implies (analysis size and `motion.block_px`), if the
    /// camera's size is set: samples of any other grid are foreign and rejected,
    /// before and after the store exists.
    expected: Option<BlockGrid>,
    /// Store writes that failed for a reason that may pass (a full or read-only
    /// disk): the minute is not learned, the service stays up and tries again.
    store_failures: u64,
}

impl<'ipc> CascadeStage<'ipc> {
    /// The stage of `camera` on `loaded`'s site, publishing through `ipc`, and its
    /// input. An existing store is checked now: a foreign or damaged file is a
    /// clear error at start-up, not after the first motion sample.
    pub fn open(
        ipc: &'ipc Ipc,
        loaded: &LoadedConfig,
        camera: &CameraConfig,
    ) -> Result<(Self, Input<Motion>), Fatal> {
        stage::one_in_one_out(ipc, &camera.id, |output| Self::new(loaded, camera, output))
    }

    /// The stage of `camera` writing into `output`.
    pub fn new(
        loaded: &LoadedConfig,
        camera: &CameraConfig,
        mut output: Output<'ipc, Activity>,
    ) -> Result<Self, Fatal> {
        let config = &loaded.config;
        let clock = SiteClock::new(&config.site.time_zone, config.cascade.cycle)
            .map_err(|e| Fatal::new(exit::CONFIG, format!("site.time_zone: {e}")))?;
        let params = Params::of(config);
        let path = store_path(&loaded.state_dir(), &camera.id);
        let store = if path.exists() {
            let s = Store::open_writer(&path, &camera.id, config.cascade.cycle)?;
            let p = s.progress()?;
            tracing::info!(
                "long-term store {}: {} grid, {} minutes learned, {} skipped",
                path.display(),
                s.meta().grid(),
                p.committed,
                p.skipped
            );
            output.reserve(s.meta().blocks())?;
            Some(TimedStore::new(s))
        } else {
            tracing::info!(
                "no long-term store yet; {} is created when motion arrives",
                path.display()
            );
            None
        };
        let resume = match &store {
            Some(s) => s.store.read_baseline()?,
            None => None,
        };
        tracing::info!(
            camera = %camera.id,
            "filtering motion: T_L1 = {} s, T_S1 = {} s, T_L2 = {} days{}, r = {}, cycle {}, min coverage {}",
            params.t_l1_s,
            params.t_s1_s,
            config.cascade.t_l2_days,
            if config.cascade.cycle == isochron_config::clock::Cycle::DayTypes {
                format!(
                    " (weekdays {} weeks, K {})",
                    config.cascade.t_l2_weeks, config.cascade.weekday_prior_weeks
                )
            } else {
                String::new()
            },
            params
                .frame_rate
                .map_or("measured".to_string(), |r| format!("{r} frames/s")),
            config.cascade.cycle.name(),
            params.min_coverage
        );
        Ok(CascadeStage {
            camera: camera.id.clone(),
            camera_id: CameraId::new(&camera.id).unwrap_or_default(),
            params,
            clock,
            cycle: config.cascade.cycle,
            path,
            store,
            resume,
            cascade: None,
            output,
            grid_mismatches: 0,
            expected: camera
                .width
                .zip(camera.height)
                .map(|(w, h)| BlockGrid::new(w, h, config.motion.block_px)),
            store_failures: 0,
        })
    }

    /// The first data sample fixes the grid: store, publisher and cascade.
    fn start(&mut self, header: &MotionHeader) -> Result<(), Fatal> {
        let grid = header.block_grid();
        let store = match self.store.take() {
            Some(s) => {
                s.store.check_grid(&grid)?;
                s
            }
            None => {
                let meta = StoreMeta::new(self.camera.clone(), grid, self.cycle, wall_now_ns());
                let store = Store::open_or_create(&self.path, &meta)?;
                tracing::info!(
                    "created the long-term store {} ({grid})",
                    self.path.display()
                );
                TimedStore::new(store)
            }
        };
        self.store = Some(store);
        self.output.reserve(grid.len())?;
        self.cascade = Some(Cascade::new(
            self.camera_id,
            self.params.clone(),
            self.clock.clone(),
            grid,
            self.resume.take(),
        ));
        Ok(())
    }

    /// Handles one motion sample.
    fn on_motion(
        &mut self,
        header: &MotionHeader,
        blocks: &[isochron_wire::BlockMotion],
        cx: &mut Context,
    ) -> Result<(), Fatal> {
        let arrived = Instant::now();
        let end = header.preamble.is_end_of_stream();
        if let Some(expected) = self.expected
            && !end
            && header.block_grid() != expected
        {
            // Never let a foreign or misconfigured producer shape the store.
            cx.health.rejected();
            cx.warnings.warn("grid", || {
                format!(
                    "rejected motion sample: its grid is {}, the config gives {expected}",
                    header.block_grid()
                )
            });
            return Ok(());
        }
        if self.cascade.is_none() && !end {
            match self.start(header) {
                Ok(()) => {}
                Err(e) if !exit::is_permanent(e.code) => {
                    // The store cannot be created now (disk full, read-only):
                    // try again with a later sample.
                    self.store_failed(e, cx);
                    return Ok(());
                }
                Err(e) => return Err(e),
            }
        }
        let (Some(c), Some(s)) = (self.cascade.as_mut(), self.store.as_mut()) else {
            // End of stream before any data: pass it on.
            self.output.end_of_stream(&header.preamble, |_| {})?;
            return Ok(());
        };
        let mut failed = None;
        match c.push(header, blocks, s) {
            Ok(done) => {
                self.grid_mismatches = 0;
                if let Some(second) = done {
                    publish_second(&mut self.output, &second, c, cx, arrived);
                }
            }
            Err(PushError::Reject(r)) => {
                cx.health.rejected();
                cx.warnings
                    .warn(reject_kind(&r), || format!("rejected motion sample: {r}"));
                if matches!(r, Reject::Grid { .. }) && self.expected.is_none() {
                    self.grid_mismatches += 1;
                    if self.grid_mismatches >= GRID_MISMATCH_LIMIT {
                        return Err(Fatal::new(
                            exit::CONFIG,
                            format!(
                                "{r}; {GRID_MISMATCH_LIMIT} samples in a row: the long-term store {} is for {}; restart the cascade after moving the store away to start a new model, or restore the motion settings",
                                self.path.display(),
                                c.grid()
                            ),
                        ));
                    }
                }
                return Ok(());
            }
            // A store that became unwritable while running (a disk remounted
            // read-only) may become writable again: pause learning, keep the
            // activity flowing. One that cannot be written at start-up ends it.
            Err(PushError::Store(e))
                if e.is_permanent() && !matches!(e, StoreError::NotWritable { .. }) =>
            {
                return Err(e.into());
            }
            // A failed commit (a full disk) pauses learning; an end of stream
            // is still passed on, or everything downstream would wait for it.
            Err(PushError::Store(e)) => failed = Some(e),
        }
        if end {
            let grid = *c.grid();
            self.output.end_of_stream(&header.preamble, |h| {
                h.grid_w = grid.grid_w();
                h.grid_h = grid.grid_h();
                h.block_px = grid.block_px;
                h.frame_width = grid.frame_width;
                h.frame_height = grid.frame_height;
            })?;
            let stats = c.stats();
            let (p50, p99) = s.latency_ms();
            tracing::info!(
                "end of stream: {} frames, {} seconds, minutes learned {} / too sparse {} / repeated {}; store commit p50 {p50:.2} ms, p99 {p99:.2} ms; waiting for more",
                stats.frames,
                stats.seconds,
                stats.minutes_learned,
                stats.minutes_sparse,
                stats.minutes_repeated
            );
        }
        if let Some(e) = failed {
            self.store_failed(e.into(), cx);
        }
        Ok(())
    }
}

impl CascadeStage<'_> {
    /// A store write failed for a reason that may pass: say so (rate-limited),
    /// count it, and go on; the next minute tries again.
    fn store_failed(&mut self, e: Fatal, cx: &mut Context) {
        self.store_failures += 1;
        cx.health.dropped(1);
        cx.warnings.warn("store", || {
            format!(
                "the long-term store cannot be written ({}): this minute is not learned; \
                 trying again at the next one",
                e.chain()
            )
        });
    }
}

/// Publishes one completed second. A failed send drops the sample (counted).
fn publish_second(
    output: &mut Output<Activity>,
    second: &SecondOut,
    cascade: &Cascade,
    cx: &mut Context,
    arrived: Instant,
) {
    let blocks = cascade.activity();
    let mut header = second.header;
    header.preamble = output.preamble(blocks.len(), &header.preamble);
    match output.send_copy(header, blocks) {
        Ok(()) => cx
            .health
            .sent(Some(arrived), header.preamble.origin_wall_ns),
        Err(e) => {
            tracing::warn!("activity sample dropped: {e}");
            cx.health.dropped(1);
        }
    }
}

/// The kind of a reject, for rate-limited warnings.
fn reject_kind(r: &Reject) -> &'static str {
    match r {
        Reject::Wire(_) => "header",
        Reject::Grid { .. } => "grid",
        Reject::Value { .. } => "value",
        Reject::Time(_) => "time",
        Reject::Backwards { .. } => "backwards",
    }
}

impl Stage for CascadeStage<'_> {
    type Inputs = Input<Motion>;
    const KIND: StageKind = StageKind::Cascade;

    fn on_wake(&mut self, motion: &Input<Motion>, cx: &mut Context) -> Result<(), Fatal> {
        while let Some(sample) = motion.next(cx) {
            let header = *sample.header();
            self.on_motion(&header, sample.payload(), cx)?;
        }
        Ok(())
    }

    /// The minute in progress is not complete: it is not learned (a crash would
    /// lose it the same way).
    fn counters(&self, c: &mut Counters) {
        if let Some(k) = &self.cascade {
            let st = k.stats();
            c.set(cascade::SECONDS, st.seconds);
            c.set(cascade::LEARNED, st.minutes_learned);
            c.set(cascade::SPARSE, st.minutes_sparse);
            c.set(cascade::REPEATED, st.minutes_repeated);
            c.set(cascade::FRAME_RATE, k.frame_rate().unwrap_or(0.0));
            let p = k.presence_stats();
            c.set(cascade::PRESENT, p.present);
            c.set(cascade::ABSORBED, p.absorbed);
            c.set(cascade::GHOSTS, p.ghosts);
        }
        if let Some(t) = &self.store {
            let (p50, p99) = t.latency_ms();
            c.set(cascade::COMMITS, t.commits);
            c.set(cascade::COMMIT_P50, p50);
            c.set(cascade::COMMIT_P99, p99);
        }
        c.set(cascade::STORE_FAILURES, self.store_failures);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use isochron_config::Config;
    use isochron_runtime::stage::{Owned, step};
    use isochron_wire::{BlockMotion, Preamble, Stream};

    fn motion(sequence: u64, (frame_width, frame_height): (u32, u32)) -> Owned<Motion> {
        let grid = BlockGrid::new(frame_width, frame_height, 16);
        let mut preamble = Preamble::new::<BlockMotion>(
            Stream::Motion,
            CameraId::new("cam01").unwrap(),
            sequence,
            grid.len(),
        );
        preamble.capture_time_ns = 1_700_000_000_000_000_000 + sequence as i64 * 100_000_000;
        Owned {
            header: MotionHeader {
                preamble,
                frame_width,
                frame_height,
                block_px: 16,
                grid_w: grid.grid_w(),
                grid_h: grid.grid_h(),
                changed_fraction: 0.0,
                source_index: sequence,
            },
            payload: vec![BlockMotion::default(); grid.len()],
        }
    }

    #[test]
    fn a_sample_of_another_grid_never_shapes_the_store() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("site.toml");
        std::fs::write(
            &path,
            "[site]\nstate_dir = \"state\"\n\n[[camera]]\nid = \"cam01\"\nsource = \"walk.avi\"\nwidth = 64\nheight = 32\n",
        )
        .unwrap();
        let loaded = Config::load(&path).unwrap();
        let store = store_path(&loaded.state_dir(), "cam01");
        let (output, _sent) = Output::memory("cam01");
        let mut stage = CascadeStage::new(&loaded, &loaded.config.cameras[0], output).unwrap();
        let (input, queue) = Input::memory("cam01");
        let mut cx = Context::new(StageKind::Cascade, "cam01", None);

        // Before the store exists: a 4x4 sample from a foreign producer.
        queue.borrow_mut().push_back(motion(0, (64, 64)));
        step(&mut stage, &input, &mut cx).unwrap();
        assert_eq!(cx.health.status().rejected, 1);
        assert!(!store.exists(), "a foreign sample created the store");

        // The configured grid creates it; a foreign sample after that changes nothing.
        queue.borrow_mut().push_back(motion(1, (64, 32)));
        for k in 0..40 {
            queue.borrow_mut().push_back(motion(2 + k, (64, 64)));
        }
        step(&mut stage, &input, &mut cx).unwrap();
        assert_eq!(cx.health.status().rejected, 41);
        let meta = Store::open_read_only(&store, "cam01")
            .unwrap()
            .meta()
            .clone();
        assert_eq!(meta.grid, BlockGrid::new(64, 32, 16));
        // Still running: 40 foreign samples in a row no longer end learning.
        queue.borrow_mut().push_back(motion(42, (64, 32)));
        step(&mut stage, &input, &mut cx).unwrap();
        assert_eq!(cx.health.status().rejected, 41);
    }
}
