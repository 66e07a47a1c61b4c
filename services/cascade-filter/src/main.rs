//! isochron-cascade: config → store → node → `motion` subscriber and `activity`
//! publisher → wait/receive/filter/publish loop.

use std::collections::HashMap;
use std::path::Path;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use clap::Parser;
use iceoryx2::prelude::*;
use isochron_cascade::{
    Cascade, Grid, Params, PushError, REJECT_LOG_EVERY, Reject, SecondOut, TimedStore,
};
use isochron_shared::clock::{SiteClock, wall_now_ns};
use isochron_shared::health::{Health, exit, notify_ready};
use isochron_shared::ipc::{Activity, Ipc, Motion, StreamPublisher, stop_requested_by};
use isochron_shared::service::{CameraArgs, Fatal, ServiceContext, run_cameras};
use isochron_shared::store::{Store, StoreError, StoreMeta, store_path};
use isochron_shared::topology::StageKind;
use isochron_shared::wire::{
    ActivityHeader, BlockActivity, CameraId, FLAG_END_OF_STREAM, MotionHeader, Preamble, Stream,
};

/// Filters one camera's motion stream into 1-Hz activity and the long-term store.
#[derive(Parser)]
#[command(version)]
struct Args {
    #[command(flatten)]
    service: CameraArgs,
}

/// The WaitSet wakes at least this often, so health reports and the watchdog tick.
const TICK: Duration = Duration::from_millis(500);
/// Consecutive samples of another grid after which the cascade gives up: motion runs
/// with other settings for good, and the store cannot follow.
const GRID_MISMATCH_LIMIT: u32 = 30;

fn main() -> ExitCode {
    let args = Args::parse();
    run_cameras(StageKind::Cascade, &args.service, run)
}

fn run(ctx: ServiceContext) -> Result<(), Fatal> {
    let cam = ctx.camera().clone();
    let config = &ctx.config.config;
    let camera_id = CameraId::new(&cam.id).expect("validated camera id");
    let clock = SiteClock::new(&config.site.time_zone, config.cascade.cycle)
        .map_err(|e| Fatal::new(exit::CONFIG, format!("site.time_zone: {e}")))?;
    let params = Params::from(&config.cascade);
    let path = store_path(&ctx.config.state_dir(), &cam.id);

    // An existing store is checked now: a foreign or damaged file is a clear error at
    // start-up, not after the first motion sample.
    let mut store = if path.exists() {
        let s = Store::open_writer(&path, &cam.id, config.cascade.cycle).map_err(store_fatal)?;
        let p = s.progress().map_err(store_fatal)?;
        tracing::info!(
            "long-term store {}: {} grid, {} minutes learned, {} skipped",
            path.display(),
            s.meta().grid(),
            p.committed,
            p.skipped
        );
        Some(TimedStore::new(s))
    } else {
        tracing::info!(
            "no long-term store yet; {} is created when motion arrives",
            path.display()
        );
        None
    };
    let resume = match &store {
        Some(s) => s.store.read_baseline().map_err(store_fatal)?,
        None => None,
    };

    let subscriber = ctx
        .ipc
        .subscriber::<Motion>(&cam.id)
        .map_err(|e| Fatal::new(exit::UNAVAILABLE, e.to_string()))?;
    let waitset = WaitSetBuilder::new()
        .create::<ipc::Service>()
        .map_err(|e| Fatal::new(exit::UNAVAILABLE, format!("creating a waitset: {e:?}")))?;
    let _guard = waitset.attach_notification(&subscriber).map_err(|e| {
        Fatal::new(
            exit::UNAVAILABLE,
            format!("attaching to the waitset: {e:?}"),
        )
    })?;
    let mut out = Output {
        ipc: &ctx.ipc,
        camera: cam.id.clone(),
        camera_id,
        publisher: None,
        publisher_len: 0,
    };
    if let Some(s) = &store {
        out.ensure(s.store.meta().blocks())?;
    }
    let mut health = Health::new("cascade", &cam.id, Some(&ctx.ipc));
    tracing::info!(
        camera = %cam.id,
        "filtering motion: T_L1 = {} s, T_S1 = {} s, T_L2 = {} days, r = {}, cycle {:?}, min coverage {}",
        params.t_l1_s,
        params.t_s1_s,
        params.t_l2_days,
        params
            .frame_rate
            .map_or("measured".to_string(), |r| format!("{r} frames/s")),
        config.cascade.cycle,
        params.min_coverage
    );
    notify_ready(&format!("cascade {}", cam.id));

    let mut cascade: Option<Cascade> = None;
    let mut resume = resume;
    let mut rejects = RejectLog::default();
    let mut grid_mismatches = 0u32;
    let mut received_since_tick = 0u32;
    'outer: loop {
        match waitset.wait_and_process_once_with_timeout(|_| CallbackProgression::Continue, TICK) {
            Ok(result) if stop_requested_by(&result) => break,
            Ok(_) => {}
            Err(e) => {
                return Err(Fatal::new(
                    exit::UNAVAILABLE,
                    format!("waiting for motion: {e:?}"),
                ));
            }
        }
        if ctx.ipc.should_stop() {
            break;
        }
        subscriber.drain_wakeups();
        loop {
            let sample = match subscriber.receive() {
                Ok(Some(s)) => s,
                Ok(None) => break,
                Err(e) => return Err(Fatal::new(exit::UNAVAILABLE, e.to_string())),
            };
            let arrived = Instant::now();
            let header: MotionHeader = *sample.user_header();
            let blocks = sample.payload();
            health.received(header.preamble.sequence);
            let end = header.preamble.is_end_of_stream();

            // The first data sample fixes the grid: store, publisher and cascade.
            if cascade.is_none() && !end {
                if let Err(e) = header.validate(&camera_id, blocks.len()) {
                    health.rejected();
                    rejects.log(&Reject::Wire(e));
                    continue;
                }
                let grid = Grid::of(&header);
                let s = match store.take() {
                    Some(s) => {
                        s.store
                            .check_grid(grid.grid_w, grid.grid_h)
                            .map_err(store_fatal)?;
                        s
                    }
                    None => TimedStore::new(create_store(&path, &cam.id, &grid, &ctx)?),
                };
                store = Some(s);
                out.ensure(grid.blocks())?;
                cascade = Some(Cascade::new(
                    camera_id,
                    params.clone(),
                    clock.clone(),
                    grid,
                    resume.take(),
                ));
            }

            let (Some(c), Some(s)) = (cascade.as_mut(), store.as_mut()) else {
                // End of stream before any data: pass it on.
                out.end_of_stream(&header, None)?;
                continue;
            };
            match c.push(&header, blocks, s) {
                Ok(done) => {
                    grid_mismatches = 0;
                    if let Some(second) = done {
                        out.second(&second, c.grid(), c.activity(), &mut health, arrived);
                    }
                }
                Err(PushError::Reject(r)) => {
                    health.rejected();
                    rejects.log(&r);
                    if matches!(r, Reject::Grid { .. }) {
                        grid_mismatches += 1;
                        if grid_mismatches >= GRID_MISMATCH_LIMIT {
                            return Err(Fatal::new(
                                exit::CONFIG,
                                format!(
                                    "{r}; {GRID_MISMATCH_LIMIT} samples in a row: the long-term store {} is for {}; restart the cascade after moving the store away to start a new model, or restore the motion settings",
                                    path.display(),
                                    c.grid()
                                ),
                            ));
                        }
                    }
                    continue;
                }
                Err(PushError::Store(e)) => return Err(store_fatal(e)),
            }
            if end {
                let stats = c.stats();
                out.end_of_stream(&header, Some(c.grid()))?;
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
            received_since_tick += 1;
            if received_since_tick >= 256 {
                received_since_tick = 0;
                health.tick(|| detail(cascade.as_ref(), store.as_ref()));
                if ctx.ipc.should_stop() {
                    break 'outer;
                }
            }
        }
        health.tick(|| detail(cascade.as_ref(), store.as_ref()));
    }
    // The minute in progress is not complete: it is not learned (a crash would lose it
    // the same way).
    health.report(detail(cascade.as_ref(), store.as_ref()));
    Ok(())
}

fn detail(cascade: Option<&Cascade>, store: Option<&TimedStore>) -> String {
    let mut s = String::new();
    if let Some(c) = cascade {
        let st = c.stats();
        s += &format!(
            "seconds={} learned={} sparse={} repeated={} r={:.2}",
            st.seconds,
            st.minutes_learned,
            st.minutes_sparse,
            st.minutes_repeated,
            c.frame_rate().unwrap_or(0.0)
        );
    }
    if let Some(t) = store {
        let (p50, p99) = t.latency_ms();
        s += &format!(" commits={} commit_ms={p50:.2}/{p99:.2}", t.commits);
    }
    s
}

/// Creates the store for `grid` (its directory too).
fn create_store(
    path: &Path,
    camera: &str,
    grid: &Grid,
    ctx: &ServiceContext,
) -> Result<Store, Fatal> {
    let meta = StoreMeta {
        camera: camera.to_string(),
        grid_w: grid.grid_w,
        grid_h: grid.grid_h,
        block_px: grid.block_px,
        frame_width: grid.frame_width,
        frame_height: grid.frame_height,
        cycle: ctx.config.config.cascade.cycle,
        created_ns: wall_now_ns(),
    };
    let store = Store::open_or_create(path, &meta).map_err(store_fatal)?;
    tracing::info!("created the long-term store {} ({grid})", path.display());
    Ok(store)
}

/// A store failure as an exit: foreign, damaged or mismatched files are permanent
/// (restarting cannot help), I/O errors may pass.
fn store_fatal(e: StoreError) -> Fatal {
    let code = match &e {
        StoreError::Damaged { .. } | StoreError::NotSqlite { .. } => exit::DATA,
        StoreError::Foreign { .. }
        | StoreError::Version { .. }
        | StoreError::Camera { .. }
        | StoreError::Grid { .. }
        | StoreError::Cycle { .. } => exit::CONFIG,
        StoreError::Io { .. } | StoreError::NotFound { .. } | StoreError::ReadOnly { .. } => {
            exit::UNAVAILABLE
        }
    };
    Fatal::new(code, e.to_string())
}

/// The `activity` publisher, created once the number of blocks is known.
struct Output<'a> {
    ipc: &'a Ipc,
    camera: String,
    camera_id: CameraId,
    publisher: Option<StreamPublisher<Activity>>,
    publisher_len: usize,
}

impl Output<'_> {
    /// Makes sure the publisher can send `len` blocks.
    fn ensure(&mut self, len: usize) -> Result<&mut StreamPublisher<Activity>, Fatal> {
        if self.publisher.is_none() || self.publisher_len < len {
            self.publisher = None;
            let p = self
                .ipc
                .publisher::<Activity>(&self.camera, len)
                .map_err(|e| Fatal::new(exit::UNAVAILABLE, e.to_string()))?;
            self.publisher = Some(p);
            self.publisher_len = len;
        }
        Ok(self.publisher.as_mut().expect("just created"))
    }

    /// Publishes one completed second. A failed loan drops the sample (counted).
    fn second(
        &mut self,
        second: &SecondOut,
        grid: &Grid,
        blocks: &[BlockActivity],
        health: &mut Health,
        arrived: Instant,
    ) {
        let camera_id = self.camera_id;
        let Ok(publisher) = self.ensure(blocks.len()) else {
            health.dropped(1);
            return;
        };
        let header = second.header(camera_id, grid, publisher.next_sequence());
        let sent = publisher.loan(blocks.len()).and_then(|mut sample| {
            *sample.user_header_mut() = header;
            publisher.send(sample.write_from_slice(blocks))
        });
        match sent {
            Ok(_) => health.sent(Some(arrived), second.origin_wall_ns),
            Err(e) => {
                tracing::warn!("activity sample dropped: {e}");
                health.dropped(1);
            }
        }
    }

    /// Publishes end of stream after `motion`'s end-of-stream sample.
    fn end_of_stream(&mut self, motion: &MotionHeader, grid: Option<&Grid>) -> Result<(), Fatal> {
        let camera_id = self.camera_id;
        let len = grid.map_or(1, Grid::blocks);
        let publisher = self.ensure(len)?;
        let mut preamble = Preamble::new::<BlockActivity>(
            Stream::Activity,
            camera_id,
            publisher.next_sequence(),
            0,
        );
        preamble.capture_time_ns = motion.preamble.capture_time_ns;
        preamble.origin_wall_ns = motion.preamble.origin_wall_ns;
        preamble.flags = FLAG_END_OF_STREAM;
        let mut header = ActivityHeader {
            preamble,
            ..Default::default()
        };
        if let Some(g) = grid {
            header.grid_w = g.grid_w;
            header.grid_h = g.grid_h;
            header.block_px = g.block_px;
            header.frame_width = g.frame_width;
            header.frame_height = g.frame_height;
        }
        publisher
            .send_copy(header, &[])
            .map(|_| ())
            .map_err(|e| Fatal::new(exit::UNAVAILABLE, e.to_string()))
    }
}

/// Logs rejected samples: the first of each kind at once, then at most one line per
/// kind every [`REJECT_LOG_EVERY`], with the number suppressed.
#[derive(Default)]
struct RejectLog {
    kinds: HashMap<&'static str, (Instant, u64)>,
}

impl RejectLog {
    fn log(&mut self, r: &Reject) {
        let kind = match r {
            Reject::Wire(_) => "header",
            Reject::Grid { .. } => "grid",
            Reject::Value { .. } => "value",
            Reject::Time(_) => "time",
            Reject::Backwards { .. } => "backwards",
        };
        let now = Instant::now();
        match self.kinds.get_mut(kind) {
            Some((last, suppressed)) if now.duration_since(*last) < REJECT_LOG_EVERY => {
                *suppressed += 1;
            }
            Some((last, suppressed)) => {
                tracing::warn!(
                    "rejected motion sample: {r} ({} more like it since the last report)",
                    *suppressed
                );
                *last = now;
                *suppressed = 0;
            }
            None => {
                tracing::warn!("rejected motion sample: {r}");
                self.kinds.insert(kind, (now, 0));
            }
        }
    }
}
