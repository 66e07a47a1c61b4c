//! Unit tests of the cascade state machine (no shared memory).
#![allow(
    clippy::too_many_lines,
    reason = "a test is one scenario, read top to bottom"
)]

use super::*;
use crate::filters::Counted;
use fastrand::Rng as Lcg;
use isochron_config::clock::{Cycle, parse_rfc3339};
use isochron_store::{Store, StoreMeta, store_path};
use isochron_wire::{FLAG_END_OF_STREAM, Preamble, Stream};

const CAM: &str = "cam01";

fn camera() -> CameraId {
    CameraId::new(CAM).unwrap()
}

fn grid(w: u32, h: u32) -> BlockGrid {
    BlockGrid::new(w * 16, h * 16, 16)
}

/// The default parameters with the paper's daily cycle, as `utc()` counts t*.
fn params() -> Params {
    Params {
        rules: isochron_store::Rules::defaults(Cycle::Daily),
        ..Params::default()
    }
}

fn utc() -> SiteClock {
    SiteClock::new("UTC", Cycle::Daily).unwrap()
}

/// Builds motion samples like the motion service does.
struct Feed {
    grid: BlockGrid,
    sequence: u64,
    source_index: u64,
}

impl Feed {
    fn new(grid: BlockGrid) -> Self {
        Feed {
            grid,
            sequence: 0,
            source_index: 0,
        }
    }

    fn header(&mut self, t_ns: i64, blocks: usize) -> MotionHeader {
        let mut preamble =
            Preamble::new::<BlockMotion>(Stream::Motion, camera(), self.sequence, blocks);
        preamble.capture_time_ns = t_ns;
        preamble.origin_wall_ns = t_ns;
        self.sequence += 1;
        let h = MotionHeader {
            preamble,
            frame_width: self.grid.frame_width,
            frame_height: self.grid.frame_height,
            block_px: self.grid.block_px,
            grid_w: self.grid.grid_w(),
            grid_h: self.grid.grid_h(),
            changed_fraction: 0.0,
            source_index: self.source_index,
        };
        self.source_index += 1;
        h
    }

    fn end(&mut self, t_ns: i64) -> MotionHeader {
        let mut h = self.header(t_ns, 0);
        h.preamble.flags = FLAG_END_OF_STREAM;
        h
    }
}

fn still(density: f32) -> BlockMotion {
    BlockMotion {
        density,
        ..Default::default()
    }
}

fn moving(density: f32, ux: f32, uy: f32) -> BlockMotion {
    BlockMotion {
        density,
        dx: density * ux,
        dy: density * uy,
        ..Default::default()
    }
}

/// A completed second with a copy of its blocks.
#[derive(Debug, Clone, PartialEq)]
struct Out {
    second: SecondOut,
    blocks: Vec<BlockActivity>,
}

fn push<B: FilterBank>(
    c: &mut Cascade<B>,
    h: &MotionHeader,
    blocks: &[BlockMotion],
    model: &mut dyn LongTerm,
    outs: &mut Vec<Out>,
) {
    if let Some(second) = c.push(h, blocks, model).expect("push") {
        outs.push(Out {
            second,
            blocks: c.activity().to_vec(),
        });
    }
}

/// Feeds `seconds` seconds at `fps` starting at `start_ns`, blocks from `f(frame time
/// in s since start, frame)`.
#[allow(
    clippy::too_many_arguments,
    reason = "a test driver: every knob of a run"
)]
fn run<B: FilterBank>(
    c: &mut Cascade<B>,
    feed: &mut Feed,
    model: &mut dyn LongTerm,
    start_ns: i64,
    seconds: f64,
    fps: f64,
    mut f: impl FnMut(f64, &mut [BlockMotion]),
    outs: &mut Vec<Out>,
) -> i64 {
    let k = feed.grid.len();
    let frames = (seconds * fps).round() as i64;
    let mut blocks = vec![BlockMotion::default(); k];
    let mut t_ns = start_ns;
    for i in 0..frames {
        t_ns = start_ns + (i as f64 * 1e9 / fps) as i64;
        blocks.fill(BlockMotion::default());
        f(i as f64 / fps, &mut blocks);
        let h = feed.header(t_ns, k);
        push(c, &h, &blocks, model, outs);
    }
    t_ns + (1e9 / fps) as i64
}

/// A cascade with the feed of its camera, an in-memory long-term model and the
/// seconds it completed: what most tests drive.
struct Rig {
    c: Cascade,
    feed: Feed,
    model: MemoryModel,
    outs: Vec<Out>,
}

impl Rig {
    /// A default cascade on grid `g` and the UTC clock.
    fn new(g: BlockGrid) -> Self {
        Rig::with_clock(g, utc())
    }

    /// A default cascade on grid `g` and `clock`.
    fn with_clock(g: BlockGrid, clock: SiteClock) -> Self {
        Rig {
            c: Cascade::new(camera(), params(), clock, g, None),
            feed: Feed::new(g),
            model: MemoryModel::default(),
            outs: Vec::new(),
        }
    }

    /// [`push`] into this rig.
    fn push(&mut self, h: &MotionHeader, blocks: &[BlockMotion]) {
        push(&mut self.c, h, blocks, &mut self.model, &mut self.outs);
    }

    /// [`run`] on this rig.
    fn run(
        &mut self,
        start_ns: i64,
        seconds: f64,
        fps: f64,
        f: impl FnMut(f64, &mut [BlockMotion]),
    ) -> i64 {
        let (c, feed, model) = (&mut self.c, &mut self.feed, &mut self.model);
        run(c, feed, model, start_ns, seconds, fps, f, &mut self.outs)
    }
}

fn start() -> i64 {
    parse_rfc3339("2026-01-15T00:00:00Z").unwrap()
}

#[test]
fn a_constant_in_place_source_is_removed_by_f_l1_after_its_time_constant() {
    // Defaults: T_L1 = 30 min at 30 fps (α = 0.999957).
    let g = grid(2, 2);
    let mut r = Rig::new(g);
    // An hour without motion: the baseline is warm (and zero).
    let t = r.run(start(), 3600.0, 30.0, |_, _| {});
    assert!((r.c.frame_rate().unwrap() - 30.0).abs() < 1e-6);
    assert!(
        (r.c.alpha_l1() - 0.999957).abs() < 5e-7,
        "{}",
        r.c.alpha_l1()
    );
    // Then a flashing light in block 0, forever: density 0.3 on every frame.
    r.outs.clear();
    r.run(t, 3.0 * 1800.0, 30.0, |_, b| b[0] = still(0.3));
    let at = |s: usize| r.outs[s].blocks[0];
    // At first it passes almost whole and looks like someone staying there...
    assert!(at(60).s1 > 0.25, "{:?}", at(60));
    // ... after T_L1 only 10 % of it passes (M_L1 = 0.3·α^(r·T) = 0.03) ...
    let s1_t = at(1800).s1;
    assert!((s1_t - 0.03).abs() < 0.002, "S1 at T_L1: {s1_t}");
    // ... after 3·T_L1 0.1 %.
    let s1_3t = r.outs.last().unwrap().blocks[0].s1;
    assert!(s1_3t < 0.0005, "S1 at 3·T_L1: {s1_3t}");
    // The other blocks never saw anything.
    assert!(
        r.outs
            .iter()
            .all(|o| o.blocks[1].s1 == 0.0 && o.blocks[1].s2 == 0.0)
    );
}

#[test]
fn a_person_standing_still_is_in_place_and_a_person_walking_through_is_moving() {
    let g = grid(8, 1);
    let mut r = Rig::new(g);
    let fps = 10.0;
    let t = r.run(start(), 600.0, fps, |_, _| {});
    r.outs.clear();
    // A person stands in block 1 for 2 minutes (small motions: density 0.2..0.4);
    // at 100 s someone walks through blocks 3..8, half a second per block.
    r.run(t, 120.0, fps, |s, b| {
        let frame = (s * fps).round() as i64;
        b[1] = moving(0.2 + 0.05 * (frame % 5) as f32, 0.2, -0.1);
        if (100.0..102.5).contains(&s) {
            let block = 3 + ((s - 100.0) * 2.0) as usize;
            b[block] = moving(0.6, 1.0, 0.0);
        }
    });
    let last = r.outs.last().unwrap();
    let stander = last.blocks[1];
    assert!(stander.s1 > 0.2, "{stander:?}");
    assert!(stander.s2 < 0.05 * stander.s1, "{stander:?}");
    // The walker: at the second the walker is in block 4, it is moving, not in place.
    let s_walk = r
        .outs
        .iter()
        .find(|o| o.blocks[4].s2 > 0.0)
        .expect("the walker shows up");
    let w = s_walk.blocks[4];
    assert!(w.s2 > 0.25, "{w:?}");
    assert!(w.s2 > 5.0 * w.s1, "{w:?}");
    // Its direction is carried (to the right) in the moving vector.
    assert!(w.s2_dx > 0.9 * w.s2 && w.s2_dy.abs() < 1e-6, "{w:?}");
    // And the stander is never mistaken for a walker after the first seconds.
    assert!(
        r.outs[30..]
            .iter()
            .all(|o| o.blocks[1].s2 < 0.1 * o.blocks[1].s1)
    );
}

#[test]
fn cascade_and_non_cascade_give_the_same_outputs_on_a_long_random_stream() {
    let g = grid(6, 4);
    let k = g.len();
    let params = Params {
        rules: isochron_store::Rules::of(&isochron_config::CascadeConfig {
            t_l2_days: 3.0,
            cycle: Cycle::Daily,
            ..Default::default()
        }),
        ..params()
    };
    // Both on the counting number type: the operations are counted as they run.
    let mut c: Cascade<CascadeBank<Counted>> =
        Cascade::new(camera(), params.clone(), utc(), g, None);
    let mut n: Cascade<NonCascadeBank<Counted>> = Cascade::new(camera(), params, utc(), g, None);
    let (mut ops_c, mut ops_n) = (0u64, 0u64);
    let (mut mc, mut mn) = (MemoryModel::default(), MemoryModel::default());
    let (mut oc, mut on) = (Vec::new(), Vec::new());
    let mut feed = Feed::new(g);
    let mut rng = Lcg::with_seed(42);
    let mut blocks = vec![BlockMotion::default(); k];
    let mut t;
    // Three "days" of 40 minutes each (t* repeats only if we wrap the day, so jump a
    // day ahead between them), at a jittery ~8 fps, with gaps and people.
    for day in 0..3 {
        t = start() + day * 86_400 * NS_PER_S;
        let mut people: Vec<(f64, f64, f64, f64)> = Vec::new();
        let end = t + 40 * 60 * NS_PER_S;
        while t < end {
            // A gap of 20 s now and then, a 3-minute outage once a day.
            if rng.f64() < 0.0005 {
                t += 20 * NS_PER_S;
            }
            if rng.f64() < 0.0001 {
                t += 180 * NS_PER_S;
            }
            if rng.f64() < 0.02 {
                let y = rng.f64() * 4.0;
                people.push((0.0, y, 0.3 + rng.f64(), rng.f64() - 0.5));
            }
            blocks.fill(BlockMotion::default());
            for p in &mut people {
                p.0 += p.2;
                p.1 += p.3 * 0.1;
                let (x, y) = (p.0 as usize, p.1.clamp(0.0, 3.99) as usize);
                if x < 6 {
                    blocks[y * 6 + x] = moving(0.5, 0.9, 0.1);
                }
            }
            people.retain(|p| p.0 < 6.0);
            for b in blocks.iter_mut() {
                if rng.f64() < 0.05 {
                    b.density = (b.density + rng.f64() as f32 * 0.2).min(1.0);
                }
            }
            let h = feed.header(t, k);
            Counted::take();
            push(&mut c, &h, &blocks, &mut mc, &mut oc);
            ops_c += Counted::take().total();
            push(&mut n, &h, &blocks, &mut mn, &mut on);
            ops_n += Counted::take().total();
            t += (125_000_000.0 * (0.9 + 0.2 * rng.f64())) as i64;
        }
        let h = feed.end(t);
        push(&mut c, &h, &[], &mut mc, &mut oc);
        push(&mut n, &h, &[], &mut mn, &mut on);
    }
    assert!(oc.len() > 3 * 1500, "{} seconds", oc.len());
    assert_eq!(oc.len(), on.len());
    for (a, b) in oc.iter().zip(&on) {
        assert_eq!(a.second, b.second);
        for (x, y) in a.blocks.iter().zip(&b.blocks) {
            // Short-term outputs: bit for bit.
            assert_eq!(
                (x.s1, x.s2, x.s1_dx, x.s1_dy, x.s2_dx, x.s2_dy),
                (y.s1, y.s2, y.s1_dx, y.s1_dy, y.s2_dx, y.s2_dy),
                "second {}",
                a.second.second
            );
            // Long-term: the minute sums are added in another order.
            assert!((x.lt_mean - y.lt_mean).abs() <= 1e-5 * y.lt_mean.abs().max(1e-3));
            assert!((x.lt_sigma - y.lt_sigma).abs() <= 1e-4 * y.lt_sigma.abs().max(1e-3));
        }
    }
    assert!(oc.iter().any(|o| o.blocks.iter().any(|b| b.s2 > 0.1)));
    assert!(oc.iter().any(|o| o.second.header.model_days == 2));
    assert_eq!(mc.bins.len(), mn.bins.len());
    assert!(mc.bins.len() >= 30, "{}", mc.bins.len());
    for (t_star, bc) in &mc.bins {
        let bn = &mn.bins[t_star];
        assert_eq!((bc.count, bc.last_minute), (bn.count, bn.last_minute));
        for kk in 0..k {
            assert!((bc.mean[kk] - bn.mean[kk]).abs() <= 1e-5 * bn.mean[kk].abs().max(1e-3));
        }
    }
    assert_eq!(c.stats(), n.stats());
    // The cascade does less arithmetic and keeps less state for the same outputs.
    assert!(ops_n as f64 > 1.25 * ops_c as f64, "{ops_n} vs {ops_c}");
    assert!(n.state_bytes() as f64 >= 1.5 * c.state_bytes() as f64);
}

#[test]
fn minutes_teach_their_bin_only_with_enough_frames_and_t_star_is_local() {
    let g = grid(2, 1);
    let clock = SiteClock::new("Europe/Berlin", Cycle::Daily).unwrap();
    let mut r = Rig::with_clock(g, clock);
    // 07:30-07:40 UTC (08:30 in Berlin in January) on three days, 4 fps, a person in
    // block 0 for one second every 10 s. On day 2 the camera is off 07:33:00-07:35:00
    // and again 07:37:30-07:38:00, so minute 07:37 has half its frames. (A camera that
    // runs at half its rate for a while is not a gap: r follows it.)
    let day0 = parse_rfc3339("2026-01-15T07:30:00Z").unwrap();
    for day in 0..3i64 {
        let t0 = day0 + day * 86_400 * NS_PER_S;
        for i in 0..(600 * 4) {
            let s = i as f64 / 4.0;
            if day == 1 && (180.0..300.0).contains(&s) {
                continue;
            }
            if day == 1 && (450.0..480.0).contains(&s) {
                continue;
            }
            let blocks = if (s as i64) % 10 == 0 {
                [still(0.5), still(0.0)]
            } else {
                [still(0.0), still(0.0)]
            };
            let h = r.feed.header(t0 + i * NS_PER_S / 4, 2);
            r.push(&h, &blocks);
        }
        let h = r.feed.end(t0 + 600 * NS_PER_S);
        r.push(&h, &[]);
    }
    let berlin = 8 * 60 + 30;
    assert_eq!(r.outs[0].second.header.t_star, berlin);
    assert_eq!(r.model.bins.len(), 10);
    for m in 0..10u32 {
        let expected = if (3..5).contains(&m) || m == 7 { 2 } else { 3 };
        assert_eq!(r.model.bins[&(berlin + m)].count, expected, "minute {m}");
    }
    // Minute 7 of day 2 had 50 % of its frames: below min_coverage = 0.8.
    assert_eq!(r.c.stats().minutes_sparse, 1);
    // The model the activity reports is the one of its t*.
    let day3 = &r.outs[r.outs.len() - 10];
    assert_eq!(day3.second.header.model_days, 2);
    assert!(day3.blocks[0].lt_mean > 0.0);
    assert_eq!(
        r.model.progress.last_minute,
        Some(day0 / 60 / NS_PER_S + 2 * 1440 + 9)
    );
}

#[test]
fn data_delivered_twice_never_counts_twice() {
    let g = grid(2, 1);
    let mut r = Rig::new(g);
    let pulse = |s: f64, b: &mut [BlockMotion]| {
        if (s as i64) % 7 == 0 {
            b[1] = still(0.4);
        }
    };
    r.run(start(), 300.0, 5.0, pulse);
    // The same five minutes again: time goes back 5 minutes, a new timeline starts
    // (and finishes minute 4 of the first pass); the replay teaches nothing.
    r.run(start(), 300.0, 5.0, pulse);
    let h = r.feed.end(start() + 300 * NS_PER_S);
    r.push(&h, &[]);
    assert_eq!(r.c.stats().timelines, 2);
    assert_eq!(r.c.stats().minutes_learned, 5);
    assert_eq!(r.c.stats().minutes_repeated, 5, "{:?}", r.c.stats());
    assert_eq!(r.model.bins.len(), 5);
    for (t_star, bin) in &r.model.bins {
        assert_eq!(bin.count, 1);
        assert_eq!(bin.last_minute, start() / 60 / NS_PER_S + *t_star as i64);
    }
}

#[test]
fn bad_samples_are_rejected_and_change_nothing() {
    let g = grid(3, 2);
    let k = g.len();
    let mut good: Cascade = Cascade::new(camera(), params(), utc(), g, None);
    let mut tested: Cascade = Cascade::new(camera(), params(), utc(), g, None);
    let (mut mg, mut mt) = (MemoryModel::default(), MemoryModel::default());
    let (mut og, mut ot) = (Vec::new(), Vec::new());
    let mut feed = Feed::new(g);
    let mut t = start();
    let blocks: Vec<BlockMotion> = (0..k).map(|i| still(0.1 * i as f32)).collect();
    let expect_reject = |c: &mut Cascade,
                         m: &mut MemoryModel,
                         h: &MotionHeader,
                         b: &[BlockMotion]| match c.push(h, b, m) {
        Err(PushError::Reject(r)) => r,
        other => panic!("expected a rejection, got {other:?}"),
    };
    for i in 0..200 {
        let h = feed.header(t, k);
        push(&mut good, &h, &blocks, &mut mg, &mut og);
        push(&mut tested, &h, &blocks, &mut mt, &mut ot);
        if i % 20 == 5 {
            // NaN, negative, > 1, infinite flow.
            for bad in [
                still(f32::NAN),
                still(-0.1),
                still(1.5),
                BlockMotion {
                    density: 0.5,
                    dx: f32::INFINITY,
                    ..Default::default()
                },
            ] {
                let mut b = blocks.clone();
                b[4] = bad;
                let r = expect_reject(&mut tested, &mut mt, &feed.header(t + 1, k), &b);
                assert!(matches!(r, Reject::Value { block: 4, .. }), "{r}");
            }
            // Another camera, a short payload, another grid, no time, going back.
            let mut h = feed.header(t + 1, k);
            h.preamble.camera = CameraId::new("cam02").unwrap();
            assert!(matches!(
                expect_reject(&mut tested, &mut mt, &h, &blocks),
                Reject::Wire(WireError::Camera { .. })
            ));
            let h = feed.header(t + 1, k);
            assert!(matches!(
                expect_reject(&mut tested, &mut mt, &h, &blocks[..k - 1]),
                Reject::Wire(_)
            ));
            let mut h = feed.header(t + 1, k);
            h.block_px = 32;
            h.frame_width *= 2;
            h.frame_height *= 2;
            let r = expect_reject(&mut tested, &mut mt, &h, &blocks);
            assert!(matches!(r, Reject::Grid { .. }), "{r}");
            assert!(r.to_string().contains("3x2 blocks of 16 px"), "{r}");
            let h = feed.header(0, k);
            assert!(matches!(
                expect_reject(&mut tested, &mut mt, &h, &blocks),
                Reject::Time(0)
            ));
            let h = feed.header(t - NS_PER_S, k);
            assert!(matches!(
                expect_reject(&mut tested, &mut mt, &h, &blocks),
                Reject::Backwards { .. }
            ));
        }
        t += NS_PER_S / 10;
    }
    assert!(og.len() >= 19);
    assert_eq!(og, ot);
    assert_eq!(good.stats(), tested.stats());
}

#[test]
fn the_frame_rate_is_measured_from_headers_unless_configured() {
    let g = grid(1, 1);
    let mut r = Rig::new(g);
    r.run(start(), 10.0, 25.0, |_, _| {});
    let rate = r.c.frame_rate().unwrap();
    assert!((rate - 25.0).abs() < 0.01, "{rate}");
    assert!((r.c.alpha_l1() - alpha(1800.0, 25.0)).abs() < 1e-12);
    assert!((r.outs.last().unwrap().second.header.frame_rate - 25.0).abs() < 0.01);
    assert_eq!(r.outs.last().unwrap().second.header.frames, 25);
    // The camera switches to 10 fps: α follows.
    r.run(start() + 10 * NS_PER_S, 10.0, 10.0, |_, _| {});
    assert!((r.c.frame_rate().unwrap() - 10.0).abs() < 0.01);
    assert!((r.c.alpha_l1() - alpha(1800.0, 10.0)).abs() < 1e-12);

    let fixed = Params {
        frame_rate: Some(30.0),
        ..params()
    };
    r.c = Cascade::new(camera(), fixed, utc(), g, None);
    r.run(start() + 100 * NS_PER_S, 5.0, 12.5, |_, _| {});
    assert_eq!(r.c.frame_rate(), Some(30.0));
}

#[test]
fn end_of_stream_flushes_the_partial_second_and_a_covered_partial_minute() {
    let g = grid(1, 1);
    let mut r = Rig::new(g);
    // 59.5 s at 10 fps: the last second has 5 frames, the minute 595 of 600.
    let t = r.run(start(), 59.5, 10.0, |_, b| b[0] = still(0.2));
    assert_eq!(r.outs.len(), 59);
    assert!(r.model.bins.is_empty());
    let h = r.feed.end(t);
    let last =
        r.c.push(&h, &[], &mut r.model)
            .unwrap()
            .expect("partial second");
    assert_eq!(
        (last.second, last.header.frames),
        (r.outs[58].second.second + 1, 5)
    );
    assert_eq!(r.model.bins.len(), 1);
    assert_eq!(r.model.bins[&0].count, 1);
    // Nothing left to flush.
    assert_eq!(r.c.push(&r.feed.end(t), &[], &mut r.model).unwrap(), None);
}

#[test]
fn activity_headers_validate_and_carry_the_second() {
    let g = grid(4, 3);
    let mut r = Rig::new(g);
    r.run(start(), 2.0, 30.0, |_, _| {});
    let out = r.outs[0].second;
    let h = out.header;
    h.validate(&CameraId::default(), 12).unwrap();
    assert_eq!(out.second, start() / NS_PER_S);
    assert_eq!(h.preamble.capture_time_ns, start() + NS_PER_S);
    assert_eq!(h.preamble.origin_wall_ns, start() + 29 * NS_PER_S / 30);
    assert_eq!((h.grid_w, h.grid_h, h.frames, h.model_days), (4, 3, 30, 0));
    assert_eq!((h.first_source_index, h.last_source_index), (0, 29));
    assert!((h.frame_rate - 30.0).abs() < 0.01);
}

#[test]
fn a_restart_resumes_the_baseline_and_the_model_from_the_store() {
    let dir = tempfile::tempdir().unwrap();
    let path = store_path(dir.path(), CAM);
    let g = grid(3, 1);
    let meta = StoreMeta::new(CAM, g, Cycle::Daily, 0);
    // Someone in block 0 one second in five.
    let pulse = |s: f64, b: &mut [BlockMotion]| {
        if (s as i64) % 5 == 0 {
            b[0] = still(0.5);
        }
    };
    let mut feed = Feed::new(g);
    let mut outs = Vec::new();
    let t_end = {
        let mut store = Store::open_or_create(&path, &meta).unwrap();
        let mut c: Cascade = Cascade::new(camera(), params(), utc(), g, None);
        let t = run(
            &mut c,
            &mut feed,
            &mut store,
            start(),
            600.0,
            10.0,
            pulse,
            &mut outs,
        );
        assert_eq!(c.baseline_frames(), 6000);
        // Killed here: minute 9 is still in progress (no frame of minute 10 yet).
        t
    };
    let mut store = Store::open_writer(&path, CAM, Cycle::Daily).unwrap();
    assert_eq!(
        store.progress().unwrap().last_minute,
        Some(start() / 60 / NS_PER_S + 8)
    );
    let resumed = store.read_baseline().unwrap().unwrap();
    // The stored baseline is the one at the end of minute 8, the last committed.
    assert_eq!(resumed.frames, 5400);
    assert!((resumed.level[0] - 0.1).abs() < 0.01, "{resumed:?}");
    assert!((resumed.frame_rate - 10.0).abs() < 1e-3);

    // Restarted 30 s later: the person's first second passes against the resumed
    // baseline (about 0.1), where a fresh cascade would take it as the baseline.
    let restart = t_end + 30 * NS_PER_S;
    let mut c: Cascade = Cascade::new(camera(), params(), utc(), g, Some(resumed));
    outs.clear();
    let t = run(
        &mut c, &mut feed, &mut store, restart, 120.0, 10.0, pulse, &mut outs,
    );
    let mut fresh: Cascade = Cascade::new(camera(), params(), utc(), g, None);
    let mut fresh_outs = Vec::new();
    run(
        &mut fresh,
        &mut feed,
        &mut MemoryModel::default(),
        restart,
        120.0,
        10.0,
        pulse,
        &mut fresh_outs,
    );
    assert!(outs[0].blocks[0].s2 > 0.35, "{:?}", outs[0].blocks[0]);
    assert!(
        fresh_outs[0].blocks[0].s2 < 0.2,
        "{:?}",
        fresh_outs[0].blocks[0]
    );
    assert_eq!(c.baseline_frames(), 5400 + 1200);

    // The next day, the model of yesterday's minutes comes from the store.
    outs.clear();
    run(
        &mut c,
        &mut feed,
        &mut store,
        start() + 86_400 * NS_PER_S,
        30.0,
        10.0,
        pulse,
        &mut outs,
    );
    assert!(t < start() + 86_400 * NS_PER_S);
    // outs[0] is the last second of yesterday's run, completed by today's first frame.
    let today = &outs[1];
    assert_eq!(
        today.second.second,
        (start() + 86_400 * NS_PER_S) / NS_PER_S
    );
    assert_eq!(today.second.header.model_days, 1);
    assert!(today.blocks[0].lt_mean > 0.03, "{:?}", today.blocks[0]);
    assert!(today.blocks[0].lt_sigma == 0.0, "one day: no spread yet");
    assert_eq!(today.blocks[1].lt_mean, 0.0);

    // A baseline older than T_L1 is not taken up.
    let old = Baseline {
        capture_ns: start(),
        frames: 99,
        frame_rate: 10.0,
        level: vec![0.5; 3],
    };
    let mut c: Cascade = Cascade::new(camera(), params(), utc(), g, Some(old));
    let mut model = MemoryModel::default();
    run(
        &mut c,
        &mut feed,
        &mut model,
        start() + 7200 * NS_PER_S,
        1.0,
        10.0,
        |_, _| {},
        &mut outs,
    );
    assert_eq!(c.baseline_frames(), 10);
}

mod never_panics {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        #[test]
        fn on_arbitrary_samples(
            samples in proptest::collection::vec(
                (any::<i64>(), any::<u32>(), any::<u32>(), any::<u32>(), any::<u32>(),
                 proptest::collection::vec(any::<f32>(), 0..40)),
                1..60)
        ) {
            let g = grid(3, 2);
            let mut c: Cascade = Cascade::new(camera(), params(), utc(), g, None);
            let mut model = MemoryModel::default();
            let mut feed = Feed::new(g);
            for (t, flags, gw, payload, sel, values) in samples {
                let blocks: Vec<BlockMotion> = values
                    .chunks(3)
                    .map(|v| BlockMotion { density: v[0], dx: *v.get(1).unwrap_or(&0.0), dy: *v.get(2).unwrap_or(&0.0), ..Default::default() })
                    .collect();
                let mut h = feed.header(t, blocks.len());
                match sel % 4 {
                    0 => h.preamble.flags = flags,
                    1 => h.grid_w = gw,
                    2 => h.preamble.payload_len = payload,
                    _ => {}
                }
                let _ = c.push(&h, &blocks, &mut model);
            }
        }
    }
}

#[test]
fn a_clock_that_ran_ahead_does_not_stop_learning_and_a_repeat_is_learned_once() {
    let g = grid(2, 2);
    let mut c: Cascade = Cascade::new(camera(), params(), utc(), g, None);
    let mut model = MemoryModel::default();
    let x = vec![0.5; g.len()];
    // 2099, then the corrected clock's 2009: both learn.
    let ahead = 4_102_444_800 / 60;
    let now = 1_243_814_400 / 60;
    assert!(c.learn_minute(ahead, &x, &mut model).unwrap());
    assert!(c.learn_minute(now, &x, &mut model).unwrap());
    assert!(c.learn_minute(now + 1, &x, &mut model).unwrap());
    // The same minute delivered again teaches nothing.
    assert!(!c.learn_minute(now, &x, &mut model).unwrap());
    let f = c.forecast(now + 7 * 1440, &mut model).unwrap().unwrap();
    // Both 00:00 minutes taught the daily row of 00:00.
    assert_eq!((f.count, f.mean[0]), (2, 0.5));
}
