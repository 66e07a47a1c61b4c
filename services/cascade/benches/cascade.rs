//! `cargo xtask bench cascade`: the cascade against the non-cascade reference on the
//! same motion stream (K = 1200 blocks, 30 fps): time per block-frame, arithmetic
//! operations per block-frame, state bytes per camera; the presence band's cost
//! (the cascade with the band against without); then the durable commit of one
//! minute to the SQLite store. Prints a table, then as its last line
//! `{"bench":"cascade","ns_per_block_frame":..,"ops_ratio":..,"state_ratio":..,"time_ratio":..,"presence_cost":..,..}`
//! (ratios are non-cascade / cascade; times are medians over the runs). The bank
//! comparison runs without the presence band, which both would share; the
//! service runs with it (`ns_per_block_frame_with_presence`).
//!
//! Operations are counted by running both banks once on
//! [`Counted`](isochron_cascade::filters::Counted), an `f32` that counts every
//! addition, multiplication, division and max it takes part in; times come from the
//! same banks on plain `f32`, the service's type. F_L2, which runs once per
//! block-minute on the minute means of either bank alike, is not in the count.
//!
//! Time covers everything the service does per sample except shared memory: header
//! and value checks, F_L1, the seconds, S1/S2 and the long-term fields, the minutes and
//! F_L2 (into a model in memory; the store's commit is measured on its own).
//!
//! The store's commits are timed in the state directory a site config names
//! (`site.state_dir`): `--config FILE` (default `config/demo.toml`, whose state
//! directory is `out/state`), or `--state-dir DIR` — on the filesystem the
//! cascade would write to, which the bench names (statfs). A commit is called
//! durable only off tmpfs and ramfs, where `fsync` reaches no disk.
//!
//! `--quick`: the same with 2 minutes of motion, one timed run each and 20 store
//! commits (a check that the bench runs; the JSON line gets `"quick":true`).

use std::hint::black_box;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use isochron_cascade::filters::{CascadeBank, Counted, FilterBank, NonCascadeBank, OpCount};
use isochron_cascade::{Cascade, LongTerm, MemoryModel, Params, SecondOut};
use isochron_config::Config;
use isochron_config::clock::{Cycle, NS_PER_S, SiteClock, parse_rfc3339};
use isochron_store::{Baseline, Bin, MinuteCommit, Store, StoreMeta, store_path};
use isochron_wire::geometry::BlockGrid;
use isochron_wire::{
    APPEARANCE_SCALE, BlockActivity, BlockMotion, CameraId, FLAG_APPEARANCE, MotionHeader,
    Preamble, Stream,
};

const GRID_W: u32 = 40;
const GRID_H: u32 = 30;
const FPS: i64 = 30;
/// Seconds of motion per run.
const SECONDS: i64 = 600;
/// Distinct frames generated (the stream cycles through them).
const DISTINCT: usize = 300;
const RUNS: usize = 9;
/// Durable commits of a minute timed.
const COMMITS: usize = 300;

/// How much one invocation runs: the full bench, or `--quick`.
#[derive(Clone, Copy)]
struct Size {
    /// Seconds of motion per run.
    seconds: i64,
    runs: usize,
    commits: usize,
}

impl Size {
    const FULL: Size = Size {
        seconds: SECONDS,
        runs: RUNS,
        commits: COMMITS,
    };
    /// Two minutes (so that minutes and F_L2 run too), one run, a few commits.
    const QUICK: Size = Size {
        seconds: 120,
        runs: 1,
        commits: 20,
    };
}

fn grid() -> BlockGrid {
    BlockGrid::new(GRID_W * 16, GRID_H * 16, 16)
}

/// A busy scene: people walking across (about 6 % of the blocks move), a flickering
/// light, sensor noise.
fn frames() -> Vec<Vec<BlockMotion>> {
    let k = (GRID_W * GRID_H) as usize;
    let mut x: u64 = 0x2545_F491_4F6C_DD1D;
    let mut rnd = move || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        (x >> 11) as f32 / (1u64 << 53) as f32
    };
    let people: Vec<(f32, f32, f32, f32)> = (0..12)
        .map(|_| (rnd() * 40.0, rnd() * 30.0, rnd() - 0.5, rnd() - 0.5))
        .collect();
    // The floor's appearance: a smooth gradient with some texture; people are
    // brighter and more textured.
    let floor = |k: usize| BlockMotion {
        luma: ((60 + (k % 40) * 3) as u16) * APPEARANCE_SCALE,
        texture: ((2 + k % 5) as u16) * APPEARANCE_SCALE,
        ..BlockMotion::default()
    };
    (0..DISTINCT)
        .map(|f| {
            let mut b: Vec<BlockMotion> = (0..k).map(floor).collect();
            for (i, p) in people.iter().enumerate() {
                let t = f as f32 * 0.1 + i as f32;
                let (px, py) = (
                    (p.0 + p.2 * t * 8.0).rem_euclid(40.0),
                    (p.1 + p.3 * t * 8.0).rem_euclid(30.0),
                );
                for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1), (0, -1)] {
                    let (bx, by) = (px as i32 + dx, py as i32 + dy);
                    if (0..40).contains(&bx) && (0..30).contains(&by) {
                        let d = 0.4 + 0.3 * rnd();
                        b[(by * 40 + bx) as usize] = BlockMotion {
                            density: d,
                            dx: d * p.2,
                            dy: d * p.3,
                            direction: 0,
                            luma: 220 * APPEARANCE_SCALE,
                            texture: 12 * APPEARANCE_SCALE,
                            ..BlockMotion::default()
                        };
                    }
                }
            }
            for v in b.iter_mut().take(40) {
                v.density = v.density.max(if f % 2 == 0 { 0.3 } else { 0.1 });
            }
            for v in b.iter_mut() {
                if rnd() < 0.02 {
                    v.density = (v.density + 0.05 * rnd()).min(1.0);
                }
            }
            b
        })
        .collect()
}

fn header(camera: CameraId, start: i64, i: i64) -> MotionHeader {
    let k = (GRID_W * GRID_H) as usize;
    let mut preamble = Preamble::new::<BlockMotion>(Stream::Motion, camera, i as u64, k);
    preamble.capture_time_ns = start + i * NS_PER_S / FPS;
    // The motion stage measures the appearance once a second.
    if i % FPS == 0 {
        preamble.flags = FLAG_APPEARANCE;
    }
    let g = grid();
    MotionHeader {
        preamble,
        frame_width: g.frame_width,
        frame_height: g.frame_height,
        block_px: g.block_px,
        grid_w: g.grid_w(),
        grid_h: g.grid_h(),
        changed_fraction: 0.0,
        source_index: i as u64,
    }
}

struct RunResult {
    elapsed: Duration,
    filters: u32,
    state_bytes: usize,
    outputs: Vec<(SecondOut, Vec<BlockActivity>)>,
}

/// One run over `seconds` of the stream, with or without the presence band; keeps
/// the outputs if `keep`.
fn run<B: FilterBank>(
    frames: &[Vec<BlockMotion>],
    seconds: i64,
    presence: bool,
    keep: bool,
) -> RunResult {
    let camera = CameraId::new("bench").expect("a valid camera id");
    let clock = SiteClock::new("UTC", Cycle::Daily).expect("UTC is a time zone");
    let start = parse_rfc3339("2026-03-02T08:00:00Z").expect("a valid RFC 3339 time");
    let mut params = Params::default();
    params.presence.enabled = presence;
    let mut cascade: Cascade<B> = Cascade::new(camera, params, clock, grid(), None);
    let mut model = MemoryModel::default();
    let headers: Vec<MotionHeader> = (0..seconds * FPS)
        .map(|i| header(camera, start, i))
        .collect();
    let mut outputs = Vec::new();
    let t0 = Instant::now();
    for (i, h) in headers.iter().enumerate() {
        let out = cascade
            .push(
                h,
                &frames[i % frames.len()],
                &mut model as &mut dyn LongTerm,
            )
            .expect("valid stream");
        if let Some(second) = out {
            if keep {
                outputs.push((second, cascade.activity().to_vec()));
            }
            black_box(cascade.activity());
        }
    }
    let elapsed = t0.elapsed();
    RunResult {
        elapsed,
        filters: B::FILTERS,
        state_bytes: cascade.state_bytes(),
        outputs,
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    }
}

/// Checks that both give the same outputs: S1/S2 bit for bit, long-term within rounding.
fn same_outputs(a: &RunResult, b: &RunResult) -> Result<(), String> {
    if a.outputs.len() != b.outputs.len() {
        return Err(format!(
            "{} vs {} seconds",
            a.outputs.len(),
            b.outputs.len()
        ));
    }
    for ((sa, ba), (sb, bb)) in a.outputs.iter().zip(&b.outputs) {
        if sa != sb {
            return Err(format!("second {} differs: {sa:?} vs {sb:?}", sa.second));
        }
        for (x, y) in ba.iter().zip(bb) {
            let short = (x.s1, x.s2, x.s1_dx, x.s1_dy, x.s2_dx, x.s2_dy)
                == (y.s1, y.s2, y.s1_dx, y.s1_dy, y.s2_dx, y.s2_dy);
            let long = (x.lt_mean - y.lt_mean).abs() <= 1e-5 * y.lt_mean.abs().max(1e-3)
                && (x.lt_sigma - y.lt_sigma).abs() <= 1e-4 * y.lt_sigma.abs().max(1e-3);
            if !(short && long) {
                return Err(format!("second {}: {x:?} vs {y:?}", sa.second));
            }
        }
    }
    Ok(())
}

/// The state directory to time commits in: `--state-dir DIR`, or `site.state_dir`
/// of `--config FILE` (default: the repository's `config/demo.toml`).
fn state_dir(args: &[String]) -> Result<PathBuf, String> {
    let value = |flag: &str| {
        args.iter()
            .position(|a| a == flag)
            .map(|i| {
                args.get(i + 1)
                    .cloned()
                    .ok_or(format!("{flag} needs a value"))
            })
            .transpose()
    };
    if let Some(dir) = value("--state-dir")? {
        return Ok(PathBuf::from(dir));
    }
    let config = match value("--config")? {
        Some(c) => PathBuf::from(c),
        None => Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/demo.toml"),
    };
    let loaded = Config::load(&config).map_err(|e| e.to_string())?;
    Ok(loaded.state_dir())
}

/// The filesystem `path` is on, by name, from `statfs(2)`'s magic number.
fn filesystem_of(path: &Path) -> String {
    use std::os::unix::ffi::OsStrExt;
    let Ok(c_path) = std::ffi::CString::new(path.as_os_str().as_bytes()) else {
        return "unknown".into();
    };
    // SAFETY: statfs is plain integers, for which all-zero bytes are a valid value.
    let mut st: libc::statfs = unsafe { std::mem::zeroed() };
    // SAFETY: `c_path` is a NUL-terminated string that outlives the call and `st` a
    // writable statfs; statfs(2) reads the one and writes only the other.
    if unsafe { libc::statfs(c_path.as_ptr(), &mut st) } != 0 {
        return "unknown".into();
    }
    let magic = st.f_type as u64;
    let name = match magic {
        0xEF53 => "ext4",
        0x0102_1994 => "tmpfs",
        0x8584_58F6 => "ramfs",
        0x794C_7630 => "overlay",
        0x5846_5342 => "xfs",
        0x9123_683E => "btrfs",
        0x2FC1_2FC1 => "zfs",
        0xF2F5_2010 => "f2fs",
        0x6969 => "nfs",
        0x0102_1997 => "9p",
        0x6A65_6A63 => "virtiofs",
        0x6573_5546 => "fuse",
        _ => return format!("unknown (statfs type {magic:#x})"),
    };
    name.into()
}

/// Whether a commit's `fsync` on filesystem `fs` reaches storage that survives a
/// power cut (not on tmpfs or ramfs; on overlay, only if its upper layer does).
fn durable(fs: &str) -> bool {
    !matches!(fs, "tmpfs" | "ramfs")
}

/// Commits of one minute (a bin of K blocks and the baseline) to a store in a
/// fresh directory under `state_dir` (WAL, `synchronous = FULL`): (p50, p99) in ms.
fn commit_latency(commits: usize, state_dir: &Path) -> Result<(f64, f64), String> {
    let dir = state_dir.join(format!("isochron-bench-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let path = store_path(&dir, "bench");
    let k = (GRID_W * GRID_H) as usize;
    let meta = StoreMeta::new("bench", grid(), Cycle::Daily, 0);
    let mut store = Store::open_or_create(&path, &meta).expect("bench store");
    let baseline = Baseline {
        capture_ns: 0,
        frames: 1,
        frame_rate: 30.0,
        level: vec![0.01; k],
    };
    let mut ms = Vec::with_capacity(commits);
    for m in 0..commits {
        let bin = Bin {
            t_star: (m % 1440) as u32,
            count: 1,
            last_minute: m as i64,
            mean: vec![0.02; k],
            var: vec![0.001; k],
        };
        let t = Instant::now();
        store
            .commit_minute(&MinuteCommit {
                minute: m as i64,
                bins: std::slice::from_ref(&bin),
                baseline: Some(&baseline),
            })
            .expect("commit");
        ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    drop(store);
    let _ = std::fs::remove_dir_all(&dir);
    let p99 = {
        let mut v = ms.clone();
        v.sort_by(|a, b| a.total_cmp(b));
        v[((v.len() - 1) as f64 * 0.99).round() as usize]
    };
    Ok((median(ms), p99))
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let quick = args.iter().any(|a| a == "--quick");
    let state_dir = match state_dir(&args) {
        Ok(d) => d,
        Err(e) => {
            eprintln!("cascade bench: {e}");
            std::process::exit(2);
        }
    };
    let size = if quick { Size::QUICK } else { Size::FULL };
    let Size {
        seconds: run_seconds,
        runs,
        commits,
    } = size;
    let frames = frames();
    let block_frames = (run_seconds * FPS) as f64 * (GRID_W * GRID_H) as f64;
    // Count the operations (each bank on the counting type), and check the outputs:
    // the two banks agree, and the counting type computes what f32 does.
    Counted::take();
    let c = run::<CascadeBank<Counted>>(&frames, run_seconds, false, true);
    let ops_c = Counted::take();
    let n = run::<NonCascadeBank<Counted>>(&frames, run_seconds, false, true);
    let ops_n = Counted::take();
    let plain = run::<CascadeBank>(&frames, run_seconds, false, true);
    let present = run::<CascadeBank>(&frames, run_seconds, true, true);
    let present_blocks: f64 = present
        .outputs
        .iter()
        .map(|(_, b)| b.iter().filter(|b| b.present > 0.5).count() as f64)
        .sum::<f64>()
        / present.outputs.len().max(1) as f64;
    check_outputs(&c, &n, &plain);
    let seconds = c.outputs.len();
    let (tc, tn, tp) = timed(&frames, run_seconds, runs, block_frames);
    let (ns_c, ns_n, ns_p) = (median(tc.clone()), median(tn.clone()), median(tp));
    let presence_cost = ns_p / ns_c - 1.0;
    let k = (GRID_W * GRID_H) as f64;
    let (commit_p50, commit_p99) = match commit_latency(commits, &state_dir) {
        Ok(t) => t,
        Err(e) => {
            eprintln!("cascade bench: store commits in the state directory: {e}");
            std::process::exit(1);
        }
    };
    let state_dir = std::fs::canonicalize(&state_dir).unwrap_or(state_dir);
    let fs = filesystem_of(&state_dir);
    let is_durable = durable(&fs);
    let ops_ratio = ops_n.total() as f64 / ops_c.total() as f64;
    let state_ratio = n.state_bytes as f64 / c.state_bytes as f64;
    let time_ratio = ns_n / ns_c;

    println!(
        "cascade vs non-cascade: K = {} blocks ({GRID_W}x{GRID_H}), {FPS} fps, {run_seconds} s of motion per run ({} seconds, {} minutes), median of {runs} runs",
        k as u32,
        seconds,
        run_seconds / 60
    );
    print_times((ns_c, &tc), (ns_n, &tn));
    print_counts((&c, &ops_c), (&n, &ops_n), block_frames);
    println!(
        "{:<34} {:>12}",
        "outputs", "identical (S1, S2 and vectors bit for bit; long-term within float rounding)"
    );
    println!(
        "non-cascade / cascade: {time_ratio:.2}x the time for {ops_ratio:.2}x the arithmetic \
         (operations counted on the counting type, F_L2 excluded; times on f32)"
    );
    println!(
        "presence band: {ns_p:.3} ns per block-frame with it, {:+.1} % on the cascade \
         (appearance on every 30th frame, {present_blocks:.1} blocks present per second on average)",
        presence_cost * 100.0
    );
    println!(
        "{:<34} p50 {commit_p50:.3} ms, p99 {commit_p99:.3} ms ({commits} commits of {} blocks, WAL, synchronous=FULL, in {} on {fs}{})",
        if is_durable {
            "store: durable commit of a minute"
        } else {
            "store: commit of a minute"
        },
        k as u32,
        state_dir.display(),
        if is_durable {
            ""
        } else {
            ": memory, not durable"
        }
    );
    println!(
        "{{\"bench\":\"cascade\",\"ns_per_block_frame\":{ns_c:.3},\"ops_ratio\":{ops_ratio:.3},\"state_ratio\":{state_ratio:.3},\"time_ratio\":{time_ratio:.3},\"presence_cost\":{presence_cost:.3},\"ns_per_block_frame_with_presence\":{ns_p:.3},\"commit_p50_ms\":{commit_p50:.3},\"commit_p99_ms\":{commit_p99:.3},\"commit_fs\":\"{fs}\",\"commit_durable\":{is_durable}{}}}",
        if quick { ",\"quick\":true" } else { "" }
    );
}

/// Exits with the reason unless the two banks agree and the counting type computes
/// what f32 does.
fn check_outputs(c: &RunResult, n: &RunResult, plain: &RunResult) {
    for (what, result) in [
        ("cascade and non-cascade outputs differ", same_outputs(c, n)),
        (
            "the cascade's outputs differ on f32 and on the counting type",
            same_outputs(plain, c),
        ),
    ] {
        if let Err(e) = result {
            eprintln!("{what}: {e}");
            std::process::exit(1);
        }
    }
}

/// Nanoseconds per block-frame of each run: the cascade, the non-cascade, the
/// cascade with the presence band.
fn timed(
    frames: &[Vec<BlockMotion>],
    run_seconds: i64,
    runs: usize,
    block_frames: f64,
) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let (mut tc, mut tn, mut tp) = (Vec::new(), Vec::new(), Vec::new());
    // Alternate, so that a noisy neighbour hurts all alike.
    for _ in 0..runs {
        let elapsed = |r: RunResult| r.elapsed.as_secs_f64() * 1e9 / block_frames;
        tc.push(elapsed(run::<CascadeBank>(
            frames,
            run_seconds,
            false,
            false,
        )));
        tn.push(elapsed(run::<NonCascadeBank>(
            frames,
            run_seconds,
            false,
            false,
        )));
        tp.push(elapsed(run::<CascadeBank>(
            frames,
            run_seconds,
            true,
            false,
        )));
    }
    (tc, tn, tp)
}

/// The table's rows of what is counted: operations, filters, state.
fn print_counts(
    (c, ops_c): (&RunResult, &OpCount),
    (n, ops_n): (&RunResult, &OpCount),
    block_frames: f64,
) {
    let per_block_frame = |n: u64| n as f64 / block_frames;
    let k = f64::from(GRID_W * GRID_H);
    let ops_row = |what: &str, of: fn(&OpCount) -> u64| {
        let (a, b) = (of(ops_c), of(ops_n));
        println!(
            "{:<34} {:>12.3} {:>12.3} {:>12.2}",
            what,
            per_block_frame(a),
            per_block_frame(b),
            b as f64 / a.max(1) as f64
        );
    };
    ops_row("arithmetic ops per block-frame", OpCount::total);
    ops_row("  additions and subtractions", |o| o.add);
    ops_row("  multiplications", |o| o.mul);
    ops_row("  divisions", |o| o.div);
    ops_row("  maxima", |o| o.max);
    println!(
        "{:<34} {:>12} {:>12} {:>12.2}",
        "filters (paper's count)",
        c.filters,
        n.filters,
        n.filters as f64 / c.filters as f64
    );
    println!(
        "{:<34} {:>12} {:>12} {:>12.2}",
        "state bytes per camera",
        c.state_bytes,
        n.state_bytes,
        n.state_bytes as f64 / c.state_bytes as f64
    );
    println!(
        "{:<34} {:>12.2} {:>12.2}",
        "state, motion frames (12 B/block)",
        c.state_bytes as f64 / (k * 12.0),
        n.state_bytes as f64 / (k * 12.0)
    );
}

/// The table's head and its rows of time: median and best of the runs.
fn print_times((ns_c, tc): (f64, &[f64]), (ns_n, tn): (f64, &[f64])) {
    let time_ratio = ns_n / ns_c;
    let (min_c, min_n) = (
        tc.iter().cloned().fold(f64::MAX, f64::min),
        tn.iter().cloned().fold(f64::MAX, f64::min),
    );
    println!(
        "{:<34} {:>12} {:>12} {:>12}",
        "", "cascade", "non-cascade", "non/cascade"
    );
    println!(
        "{:<34} {:>12.3} {:>12.3} {:>12.2}",
        "ns per block-frame (median)", ns_c, ns_n, time_ratio
    );
    println!(
        "{:<34} {:>12.3} {:>12.3} {:>12.2}",
        "ns per block-frame (best)",
        min_c,
        min_n,
        min_n / min_c
    );
}
