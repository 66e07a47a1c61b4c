//! `cargo xtask bench motion`: the motion kernel against OpenCV on vtest.avi.
//!
//! The decoded GRAY8 frames of `data/vtest.avi` (768×576, as capture publishes
//! them) are held in memory; every method processes the same consecutive frame pairs
//! on one thread (OpenCV is set to one thread too):
//!
//! * `isochron` — the whole motion stage per frame: brightness offset, fused kernel
//!   (runtime-dispatched: AVX2 when the CPU has it), block features, illumination
//!   check, written into a block buffer, and the block appearance for the presence
//!   band on the frames it is due (`motion.appearance_hz`, 1 Hz: every tenth frame
//!   of vtest's 10 frames/s, by their capture times);
//! * `isochron-no-appearance` — the same without the appearance: the band's cost is
//!   the ratio of the two (`appearance_cost` in the JSON line);
//! * `isochron-portable`, `isochron-scalar` — the same with the other kernels;
//! * `opencv-absdiff` — `absdiff` + `threshold` + block mean (`resize` INTER_AREA to
//!   the block grid): density only;
//! * `opencv-mog2` — `BackgroundSubtractorMOG2::apply`, default parameters;
//! * `opencv-dis` — `DISOpticalFlow` (preset FAST) `calc`;
//! * `read-floor` — a plain read (byte sum) of the same two frames: the memory floor.
//!
//! The machine may be shared, so the methods run interleaved: each *round* runs every
//! method once (the fast ones over all pairs, the slow ones over a few), and each
//! method's time is the median over the rounds, in thread CPU time (time spent
//! waiting for a core is not the method's cost). Output: a table, then as the last
//! line one JSON object
//! `{"bench":"motion","fps_per_core":..,"over_absdiff":..,"over_mog2":..,"over_dis":..,"floor_fraction":..,"appearance_cost":..}`.
//!
//! Options (after `--`): `--frames N` (pairs of the fast methods, default 200),
//! `--rounds N` (default 15), `--profile` (only our kernel, for `perf record` or
//! `valgrind --tool=callgrind`), `--quick` (every method over 20 pairs, 2 rounds: a
//! check that the bench runs; the JSON line gets `"quick":true`).

use std::hint::black_box;
use std::path::PathBuf;

use isochron_motion::detector::{MotionDetector, MotionParams};
use isochron_motion::kernel::{Geometry, Implementation};
use isochron_wire::BlockMotion;
use opencv::core::{Mat, Ptr, Size};
use opencv::prelude::*;
use opencv::{core, imgproc, video, videoio};

/// Pairs the slow methods (scalar, MOG2, DIS) process per round.
const SLOW_PAIRS: usize = 6;

/// Capture time of vtest.avi's frame `i` (10 frames/s), ns.
fn capture_ns(i: usize) -> i64 {
    i as i64 * 100_000_000
}

struct Options {
    frames: usize,
    rounds: usize,
    profile: bool,
    quick: bool,
}

fn options() -> Options {
    let args: Vec<String> = std::env::args().collect();
    let quick = args.iter().any(|a| a == "--quick");
    let mut o = Options {
        frames: if quick { 20 } else { 200 },
        rounds: if quick { 2 } else { 15 },
        profile: false,
        quick,
    };
    let mut i = 1;
    while i < args.len() {
        let value = args.get(i + 1).and_then(|v| v.parse::<usize>().ok());
        match (args[i].as_str(), value) {
            ("--frames", Some(v)) => {
                o.frames = v.max(SLOW_PAIRS + 1);
                i += 1;
            }
            ("--rounds", Some(v)) => {
                o.rounds = v.max(1);
                i += 1;
            }
            ("--profile", _) => o.profile = true,
            _ => {} // `--bench` and other cargo arguments
        }
        i += 1;
    }
    o
}

fn vtest_path() -> PathBuf {
    std::env::var_os("ISOCHRON_VTEST")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../data/vtest.avi"))
}

/// The first `n` frames of vtest.avi as GRAY8 (OpenCV's decode and conversion, as
/// capture publishes them).
fn decode(n: usize) -> opencv::Result<(usize, usize, Vec<Vec<u8>>)> {
    let path = vtest_path();
    let mut cap = videoio::VideoCapture::from_file(&path, videoio::CAP_ANY)?;
    if !cap.is_opened()? {
        panic!(
            "cannot open {} (run `cargo xtask setup` to fetch it)",
            path.display()
        );
    }
    let (mut bgr, mut gray) = (Mat::default(), Mat::default());
    let mut frames = Vec::new();
    let (mut w, mut h) = (0, 0);
    while frames.len() < n && cap.read(&mut bgr)? && !bgr.empty() {
        imgproc::cvt_color(&bgr, &mut gray, imgproc::COLOR_BGR2GRAY, 0)?;
        (w, h) = (gray.cols() as usize, gray.rows() as usize);
        frames.push(gray.data_bytes()?.to_vec());
    }
    Ok((w, h, frames))
}

/// CPU time of this thread, nanoseconds.
fn thread_cpu_ns() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes the timespec it is given.
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    ts.tv_sec as f64 * 1e9 + ts.tv_nsec as f64
}

/// A method under test: runs pairs `first ..= last` (frame indices of the current
/// frame) once.
struct Method<'a> {
    name: &'static str,
    what: String,
    slow: bool,
    run: Box<dyn FnMut(usize, usize) + 'a>,
    /// Nanoseconds per frame, one entry per round.
    times: Vec<f64>,
}

impl Method<'_> {
    fn median(&self) -> f64 {
        let mut t = self.times.clone();
        t.sort_by(f64::total_cmp);
        t[t.len() / 2]
    }
}

fn main() -> opencv::Result<()> {
    let o = options();
    core::set_num_threads(1)?;
    let (w, h, frames) = decode(o.frames + 1)?;
    assert!(
        frames.len() > SLOW_PAIRS,
        "vtest.avi gave only {} frames",
        frames.len()
    );
    let pairs = frames.len() - 1;
    let geom = Geometry::new(w, h, 16).expect("vtest size");
    let params = MotionParams::default();

    if o.profile {
        profile(geom, params, &frames, o.rounds);
        return Ok(());
    }
    let frames = &frames;
    let mats: Vec<Mat> = frames
        .iter()
        .map(|f| Mat::new_rows_cols_with_data(h as i32, w as i32, f).and_then(|m| m.try_clone()))
        .collect::<opencv::Result<_>>()?;
    let mats = &mats;
    let mut methods = ours(geom, params, frames);
    methods.extend(opencv(geom, mats)?);

    eprintln!(
        "motion bench: {w}x{h} GRAY8 frames of vtest.avi, 1 thread, {} rounds; per round {pairs} pairs \
         ({SLOW_PAIRS} for {}), median thread CPU time",
        o.rounds,
        methods
            .iter()
            .filter(|m| m.slow)
            .map(|m| m.name)
            .collect::<Vec<_>>()
            .join(", ")
    );
    time_rounds(&mut methods, o.rounds, pairs);
    report(&methods, o.quick);
    Ok(())
}

/// `--profile`: only our detector, one line of CPU time per round (for `perf`).
fn profile(geom: Geometry, params: MotionParams, frames: &[Vec<u8>], rounds: usize) {
    let pairs = frames.len() - 1;
    let mut det = MotionDetector::with_implementation(geom, params, Implementation::detect(), &[]);
    let mut blocks = vec![BlockMotion::default(); geom.blocks()];
    for _ in 0..rounds {
        let start = thread_cpu_ns();
        for i in 1..=pairs {
            det.process(&frames[i - 1], &frames[i], capture_ns(i), &mut blocks)
                .expect("sizes");
        }
        println!(
            "{:.1} us/frame",
            (thread_cpu_ns() - start) / 1e3 / pairs as f64
        );
    }
}

/// The read floor and our detector, each kernel, and the best without the
/// appearance (what the presence band costs).
fn ours(geom: Geometry, params: MotionParams, frames: &[Vec<u8>]) -> Vec<Method<'_>> {
    let mut methods = Vec::new();
    methods.push(Method {
        name: "read-floor",
        what: "byte sum of both frames".into(),
        slow: false,
        run: Box::new(|first, last| {
            let mut acc = 0u64;
            for i in first..=last {
                acc += byte_sum(&frames[i - 1]) + byte_sum(&frames[i]);
            }
            black_box(acc);
        }),
        times: Vec::new(),
    });
    let without_appearance = MotionParams {
        appearance_hz: 0.0,
        ..params
    };
    let best = Implementation::detect();
    let variants = Implementation::available()
        .into_iter()
        .rev()
        .map(|imp| (imp, params))
        .chain([(best, without_appearance)]);
    for (imp, params) in variants {
        let mut det = MotionDetector::with_implementation(geom, params, imp, &[]);
        let mut blocks = vec![BlockMotion::default(); geom.blocks()];
        let appearance = params.appearance_hz > 0.0;
        methods.push(Method {
            name: match imp {
                _ if !appearance => "isochron-no-appearance",
                i if i == best => "isochron",
                Implementation::Portable => "isochron-portable",
                Implementation::Scalar => "isochron-scalar",
                Implementation::Avx2 => "isochron-avx2",
            },
            what: format!(
                "{} kernel + features + illumination check{}",
                imp.name(),
                if appearance {
                    " + appearance at 1 Hz"
                } else {
                    ""
                }
            ),
            slow: imp == Implementation::Scalar,
            run: Box::new(move |first, last| {
                for i in first..=last {
                    det.process(&frames[i - 1], &frames[i], capture_ns(i), &mut blocks)
                        .expect("frame sizes match");
                }
                black_box(&blocks);
            }),
            times: Vec::new(),
        });
    }
    methods
}

/// OpenCV's ways of finding motion, on the same frames as `Mat`s.
fn opencv(geom: Geometry, mats: &[Mat]) -> opencv::Result<Vec<Method<'_>>> {
    let mut methods = Vec::new();
    let grid = Size::new(geom.grid_w as i32, geom.grid_h as i32);
    let (mut diff, mut mask, mut means) = (Mat::default(), Mat::default(), Mat::default());
    methods.push(Method {
        name: "opencv-absdiff",
        what: "absdiff + threshold + INTER_AREA block mean (density only)".into(),
        slow: false,
        run: Box::new(move |first, last| {
            for i in first..=last {
                core::absdiff(&mats[i - 1], &mats[i], &mut diff).expect("absdiff");
                imgproc::threshold(&diff, &mut mask, 15.0, 255.0, imgproc::THRESH_BINARY)
                    .expect("threshold");
                imgproc::resize(&mask, &mut means, grid, 0.0, 0.0, imgproc::INTER_AREA)
                    .expect("resize");
            }
            black_box(&means);
        }),
        times: Vec::new(),
    });
    let mut mog2: Ptr<video::BackgroundSubtractorMOG2> =
        video::create_background_subtractor_mog2_def()?;
    let mut foreground = Mat::default();
    // Learn a background first so that every timed frame is a steady-state update.
    for m in mats.iter().take(20) {
        BackgroundSubtractorTrait::apply(&mut mog2, m, &mut foreground, -1.0)?;
    }
    methods.push(Method {
        name: "opencv-mog2",
        what: "BackgroundSubtractorMOG2::apply, defaults".into(),
        slow: true,
        run: Box::new(move |first, last| {
            for mat in &mats[first..=last] {
                BackgroundSubtractorTrait::apply(&mut mog2, mat, &mut foreground, -1.0)
                    .expect("MOG2");
            }
            black_box(&foreground);
        }),
        times: Vec::new(),
    });
    let mut dis = video::DISOpticalFlow::create(video::DISOpticalFlow_PRESET_FAST)?;
    let mut flow = Mat::default();
    methods.push(Method {
        name: "opencv-dis",
        what: "DISOpticalFlow preset FAST, calc".into(),
        slow: true,
        run: Box::new(move |first, last| {
            for i in first..=last {
                dis.calc(&mats[i - 1], &mats[i], &mut flow).expect("DIS");
            }
            black_box(&flow);
        }),
        times: Vec::new(),
    });
    Ok(methods)
}

/// Times every method `rounds` times, after one round of warm-up.
fn time_rounds(methods: &mut [Method<'_>], rounds: usize, pairs: usize) {
    // Round 0 warms up (page faults, lazy initialisation) and is not counted.
    for round in 0..=rounds {
        for m in methods.iter_mut() {
            let (first, last) = if m.slow {
                // A different window each round, cycling through the frames.
                let first = 1 + (round * SLOW_PAIRS) % (pairs - SLOW_PAIRS + 1);
                (first, first + SLOW_PAIRS - 1)
            } else {
                (1, pairs)
            };
            let start = thread_cpu_ns();
            (m.run)(first, last);
            let ns = (thread_cpu_ns() - start) / (last - first + 1) as f64;
            if round > 0 {
                m.times.push(ns);
            }
        }
    }
}

/// The table, and the closing JSON line.
fn report(methods: &[Method<'_>], quick: bool) {
    let ns = |name: &str| {
        methods
            .iter()
            .find(|m| m.name == name)
            .map(Method::median)
            .expect("method ran")
    };
    let ours = ns("isochron");
    eprintln!(
        "motion bench: the appearance for the presence band adds {:.1} % to the stage's time per frame",
        (ours / ns("isochron-no-appearance") - 1.0) * 100.0
    );
    println!(
        "{:<18} {:>10} {:>10} {:>9}  what",
        "method", "us/frame", "frames/s", "vs ours"
    );
    for m in methods {
        let t = m.median();
        println!(
            "{:<18} {:>10.1} {:>10.0} {:>8.2}x  {}",
            m.name,
            t / 1e3,
            1e9 / t,
            t / ours,
            m.what
        );
    }
    let mut json = serde_json::json!({
        "bench": "motion",
        "fps_per_core": round(1e9 / ours, 0),
        "over_absdiff": round(ns("opencv-absdiff") / ours, 2),
        "over_mog2": round(ns("opencv-mog2") / ours, 1),
        "over_dis": round(ns("opencv-dis") / ours, 1),
        "floor_fraction": round(ns("read-floor") / ours, 3),
        "appearance_cost": round(ours / ns("isochron-no-appearance") - 1.0, 3),
    });
    if quick {
        json["quick"] = true.into();
    }
    println!("{json}");
}

fn round(v: f64, digits: i32) -> f64 {
    let k = 10f64.powi(digits);
    (v * k).round() / k
}

/// Sum of all bytes: a plain streaming read, vectorised (AVX2 when the CPU has it,
/// like the kernel).
fn byte_sum(bytes: &[u8]) -> u64 {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2.
        return unsafe { byte_sum_avx2(bytes) };
    }
    byte_sum_impl(bytes)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn byte_sum_avx2(bytes: &[u8]) -> u64 {
    byte_sum_impl(bytes)
}

#[inline(always)]
fn byte_sum_impl(bytes: &[u8]) -> u64 {
    bytes
        .chunks(4096)
        .map(|c| c.iter().map(|&b| b as u32).sum::<u32>() as u64)
        .sum()
}
