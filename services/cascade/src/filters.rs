//! The temporal filters of the cascade (see docs/ARCHITECTURE.md, section 'Filters'),
//! per block of a motion frame.
//!
//! Names follow the paper so that a reader can hold the code against its equations:
//! `f_l1` is the high-pass F_L1 at frame rate giving `M_L1`, `f_s1` the in-place
//! low-pass F_S1 giving `M_S1`, the band-pass F_S2 gives `M_S2`, `f_l2` the
//! isochronal low-pass F_L2 giving `M_L2` at minute of the day `t_star`.
//!
//! Every filter but one is a first-order IIR (exponential moving average)
//! `b'(t) = α·b'(t-1) + (1-α)·b(t)`, with α derived from the 10 %-decay duration T and
//! the sample rate r: `α = 0.1^(1/(r·T))` ([`alpha`]). The exception is the 1-s FIR
//! of F_S2, which is the mean over the frames of one second.
//!
//! Semantics (decided for isochron; the paper leaves them open):
//!
//! * **F_L1, per frame and block**: `b = α_L1·b + (1−α_L1)·M`, then
//!   `M_L1 = max(0, M − b)` — a *rectified* high-pass: always-on motion (leaves, a
//!   flashing light) sits at its own average and is removed; a person passing is a
//!   pulse far above the average and passes almost whole. The flow vector is scaled
//!   by the fraction of density that passes, `M_L1 / M`. The baseline starts with a
//!   bias-corrected warm-up: the weight of a new frame is `max(1−α, 1/(n+1))` after
//!   `n` frames ([`warmup_weight`]), so a cold camera learns its always-on level in
//!   seconds instead of half an hour.
//! * **Per second**: `m_sec`, the mean of `M_L1` over the frames of the second, is the
//!   1-s FIR. `S2 = max(0, m_sec − S1_prev)` (the band-pass, rectified: a negative
//!   part is activity *leaving*), then `S1 = α_S1·S1_prev + (1−α_S1)·m_sec`. The S1
//!   vector is the EMA of the per-second mean vector; the S2 vector is the per-second
//!   mean vector × `S2 / m_sec`.
//! * **Per minute of the cycle t***: the mean of `M_L1` over the minute updates F_L2
//!   of the rows of t* — an exponentially weighted mean and variance with α_L2,
//!   bias-corrected while a row has few samples ([`f_l2`]); which rows, and how the
//!   forecast is read from them, is the store's `isochronal` module.
//!
//! The cascade ([`CascadeBank`]) feeds each filter from the one before it: one 1-s
//! FIR serves both short-term outputs, one F_S1 serves the in-place output and the
//! low end of the band-pass, and the minute means are built from the second sums.
//! The non-cascade reference ([`NonCascadeBank`], the paper's table "Computational
//! costs of non-cascade versus cascade filter") runs the five filters separately, each
//! from `M_L1`: in-place (its own 1-s decimation and F_S1), band-pass (its own 1-s FIR
//! and its own low-pass at T_S1, kept separately), and the long-term minute mean. Both
//! give the same outputs and report their state ([`FilterBank::state_bytes`]).
//!
//! Both banks compute in a number type `T` ([`Real`]): `f32` in the service, and
//! [`Counted`] — an `f32` that counts every addition, multiplication, division and
//! max it takes part in — when a benchmark or test counts the operations of each.
//! The count comes from the very code that runs, not from counters kept beside it.

use std::cell::Cell;
use std::fmt::Debug;
use std::ops::{Add, AddAssign, Div, Mul, MulAssign, Sub};

use isochron_wire::{BlockActivity, BlockMotion};

/// The number type the filters compute in: `f32`, or [`Counted`] to count the
/// operations. State is kept in `T` too (a `Counted` is an `f32` in memory).
pub trait Real:
    Copy
    + Default
    + PartialEq
    + Debug
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + AddAssign
    + MulAssign
{
    /// The value `v` (a conversion, not an operation).
    fn of(v: f32) -> Self;
    /// The value as `f32` (a conversion, not an operation).
    fn get(self) -> f32;
    /// The larger of the two.
    fn max(self, other: Self) -> Self;
}

impl Real for f32 {
    #[inline(always)]
    fn of(v: f32) -> Self {
        v
    }
    #[inline(always)]
    fn get(self) -> f32 {
        self
    }
    #[inline(always)]
    fn max(self, other: Self) -> Self {
        f32::max(self, other)
    }
}

/// Arithmetic operations counted by [`Counted`] on this thread.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct OpCount {
    /// Additions and subtractions.
    pub add: u64,
    /// Multiplications.
    pub mul: u64,
    /// Divisions.
    pub div: u64,
    /// Maxima (the rectifications and guards).
    pub max: u64,
}

impl OpCount {
    /// All operations.
    pub fn total(&self) -> u64 {
        self.add + self.mul + self.div + self.max
    }
}

thread_local! {
    static COUNTS: Cell<OpCount> = const { Cell::new(OpCount { add: 0, mul: 0, div: 0, max: 0 }) };
}

/// An `f32` that counts the operations it takes part in, per thread: run a bank as
/// `CascadeBank<Counted>`, then read [`Counted::take`].
#[derive(Debug, Clone, Copy, Default, PartialEq)]
#[repr(transparent)]
pub struct Counted(pub f32);

impl Counted {
    /// The operations counted on this thread since the last call; starts again from 0.
    pub fn take() -> OpCount {
        COUNTS.with(|c| c.take())
    }
}

/// The kinds of operation [`Counted`] tells apart.
#[derive(Clone, Copy)]
enum Op {
    Add,
    Mul,
    Div,
    Max,
}

/// Counts one operation of kind `op` on this thread.
#[inline(always)]
fn tally(op: Op) {
    COUNTS.with(|c| {
        let mut n = c.get();
        match op {
            Op::Add => n.add += 1,
            Op::Mul => n.mul += 1,
            Op::Div => n.div += 1,
            Op::Max => n.max += 1,
        }
        c.set(n);
    });
}

impl Add for Counted {
    type Output = Counted;
    fn add(self, o: Counted) -> Counted {
        tally(Op::Add);
        Counted(self.0 + o.0)
    }
}

impl Sub for Counted {
    type Output = Counted;
    fn sub(self, o: Counted) -> Counted {
        tally(Op::Add);
        Counted(self.0 - o.0)
    }
}

impl Mul for Counted {
    type Output = Counted;
    fn mul(self, o: Counted) -> Counted {
        tally(Op::Mul);
        Counted(self.0 * o.0)
    }
}

impl Div for Counted {
    type Output = Counted;
    fn div(self, o: Counted) -> Counted {
        tally(Op::Div);
        Counted(self.0 / o.0)
    }
}

impl AddAssign for Counted {
    fn add_assign(&mut self, o: Counted) {
        *self = *self + o;
    }
}

impl MulAssign for Counted {
    fn mul_assign(&mut self, o: Counted) {
        *self = *self * o;
    }
}

impl Real for Counted {
    fn of(v: f32) -> Self {
        Counted(v)
    }
    fn get(self) -> f32 {
        self.0
    }
    fn max(self, o: Self) -> Self {
        tally(Op::Max);
        Counted(self.0.max(o.0))
    }
}

/// α of a first-order IIR whose output decays to 10 % in `t_decay` (in the unit of
/// time whose sample rate is `rate`): `α = 0.1^(1/(r·T))`.
///
/// F_L1: T = 1800 s at 30 fps → 0.999957; F_L2: T = 10 days at 1/day → 0.794;
/// F_S1: T = 20 s at 1 Hz → 0.891 (the corrected table in docs/ARCHITECTURE.md,
/// section 'Filters'; the paper prints the first two swapped).
pub fn alpha(t_decay: f64, rate: f64) -> f64 {
    let n = rate * t_decay;
    if !(n.is_finite() && n > 0.0) {
        return 0.0;
    }
    0.1f64.powf(1.0 / n)
}

/// The warm-up weight of a bias-corrected EMA, shared with F_L2 in the store.
pub use isochron_store::isochronal::warmup_weight;

/// F_L1 on one block: updates the baseline `b` with weight `w` (`1 − α_L1`, or the
/// warm-up weight) and returns `M_L1 = max(0, M − b)`.
#[inline(always)]
pub fn f_l1<T: Real>(b: &mut T, m: T, w: T) -> T {
    *b += w * (m - *b);
    (m - *b).max(T::of(0.0))
}

/// F_L1 on one block's motion `b` with baseline `level` and weight `w`: `M_L1` and
/// the flow vector scaled by the [pass fraction](pass_fraction).
#[inline(always)]
fn f_l1_block<T: Real>(level: &mut T, b: &BlockMotion, w: T) -> (T, T, T) {
    let m = T::of(b.density);
    let m_l1 = f_l1(level, m, w);
    let frac = pass_fraction(m, m_l1);
    (m_l1, T::of(b.dx) * frac, T::of(b.dy) * frac)
}

/// The fraction of a block's density that passes F_L1 (`M_L1 / M`, 0 without motion),
/// by which its flow vector is scaled.
#[inline(always)]
pub fn pass_fraction<T: Real>(m: T, m_l1: T) -> T {
    // M_L1 <= M always, and M_L1 = 0 when M = 0, so the guard only avoids 0/0.
    m_l1 / m.max(T::of(f32::MIN_POSITIVE))
}

/// One step of a first-order low-pass (EMA): `y = α·y + (1−α)·x`.
#[inline(always)]
pub fn ema<T: Real>(y: &mut T, x: T, alpha: T) {
    *y = alpha * *y + (T::of(1.0) - alpha) * x;
}

/// Decays filter states by `g` (`gap_decay`: seconds that had no frames).
#[inline(always)]
fn decay<T: Real, const N: usize>(g: T, states: [&mut T; N]) {
    for v in states {
        *v *= g;
    }
}

/// Writes one block's activity: `s1` (F_S1's output and vector, as held) and the
/// band-pass output `s2` with the vector `v` scaled by its pass fraction `frac`.
#[inline(always)]
fn write_activity<T: Real>(o: &mut BlockActivity, s1: [T; 3], s2: T, [vx, vy]: [T; 2], frac: T) {
    o.s1 = s1[0].get();
    o.s1_dx = s1[1].get();
    o.s1_dy = s1[2].get();
    o.s2 = s2.get();
    o.s2_dx = (vx * frac).get();
    o.s2_dy = (vy * frac).get();
}

/// F_S1 and the low end of the band-pass on one block, once per second: returns
/// `S2 = max(0, m_sec − S1_prev)` and updates `s1` to `α·S1_prev + (1−α)·m_sec`.
#[inline(always)]
pub fn f_s1<T: Real>(s1: &mut T, m_sec: T, alpha_s1: T) -> T {
    let s2 = (m_sec - *s1).max(T::of(0.0));
    ema(s1, m_sec, alpha_s1);
    s2
}

/// F_L2 on one block of a row of the long-term model: an exponentially weighted mean
/// and variance, updated with weight `w` (use [`warmup_weight`] with `1 − α_L2` and
/// the row's count): `d = x − mean; mean += w·d; var = (1 − w)·(var + w·d²)`. With
/// `w = 1/n` this is exactly the running mean and population variance of the first
/// `n` samples. It lives with the model's rules in the store
/// ([`isochron_store::isochronal`]), which the backtest runs too.
pub use isochron_store::isochronal::f_l2;

/// What a completed second produced, for the bookkeeping around a bank.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SecondInput {
    /// Frames in the second (> 0).
    pub frames: u32,
    /// `α_S1^g` for the `g` seconds without frames before this one (1 without a gap):
    /// S1 decays over a gap as over seconds of no motion.
    pub gap_decay: f32,
    /// α of F_S1.
    pub alpha_s1: f32,
}

impl SecondInput {
    /// `(1 / frames, α of F_S1, the gap decay unless it is 1)` in the banks' number
    /// type.
    fn factors<T: Real>(&self) -> (T, T, Option<T>) {
        let inv = T::of(1.0 / self.frames.max(1) as f32);
        let gap = (self.gap_decay != 1.0).then(|| T::of(self.gap_decay));
        (inv, T::of(self.alpha_s1), gap)
    }
}

/// The per-block filter state of one camera, cascade or not.
pub trait FilterBank {
    /// Distinct filters the bank runs, F_L2 (which follows either) included: the
    /// paper's "multiples of motion frame filter operations" — 4 for the cascade, 5
    /// for the non-cascade.
    const FILTERS: u32;

    /// A bank for `blocks` blocks, all state zero.
    fn new(blocks: usize) -> Self
    where
        Self: Sized;

    /// Number of blocks.
    fn blocks(&self) -> usize;

    /// One frame: F_L1 with weight `w_l1`, and the per-frame accumulations.
    fn frame(&mut self, motion: &[BlockMotion], w_l1: f32);

    /// One completed second: F_S1 and the band-pass, written to `out`'s `s1`, `s2` and
    /// vector fields (the long-term fields are left alone).
    fn second(&mut self, input: SecondInput, out: &mut [BlockActivity]);

    /// The completed minute: the mean of `M_L1` per block over its `frames` frames
    /// into `out`; resets the minute accumulation.
    fn minute_mean(&mut self, frames: u32, out: &mut [f32]);

    /// Forgets the short-term state (S1, partial second and minute), keeping the F_L1
    /// baseline: a new timeline starts.
    fn reset_short_term(&mut self);

    /// The F_L1 baseline per block.
    fn baseline(&self) -> Vec<f32>;

    /// Sets the F_L1 baseline (resuming from a store).
    fn set_baseline(&mut self, level: &[f32]);

    /// Bytes of per-block filter state this bank keeps (the long-term model, which
    /// both need alike, excluded).
    fn state_bytes(&self) -> usize;
}

/// The [`FilterBank`] methods that only manage a bank's state, alike for both banks:
/// `$bank` holds the F_L1 baseline `level` and the short-term vectors `$state`
/// (which include the minute sums `min_m`), one value per block each.
macro_rules! bank_state {
    ($bank:ident: $($state:ident),+) => {
        fn new(blocks: usize) -> Self {
            let z = || vec![T::default(); blocks];
            $bank {
                level: z(),
                $($state: z(),)+
            }
        }

        fn blocks(&self) -> usize {
            self.level.len()
        }

        fn minute_mean(&mut self, frames: u32, out: &mut [f32]) {
            take_minute_mean(&mut self.min_m, frames, out);
        }

        fn reset_short_term(&mut self) {
            zero([$(&mut self.$state),+]);
        }

        fn baseline(&self) -> Vec<f32> {
            self.level.iter().map(|v| v.get()).collect()
        }

        fn set_baseline(&mut self, level: &[f32]) {
            copy_baseline(&mut self.level, level);
        }

        fn state_bytes(&self) -> usize {
            state_bytes(&[&self.level, $(&self.$state),+])
        }
    };
}

/// The cascade: F_L1 → one 1-s FIR → F_S1 (in-place) and, sharing F_S1, the rectified
/// band-pass (moving); the minute mean is accumulated from the second sums.
///
/// State per block: the F_L1 baseline; the second's sums (density, dx, dy); S1 and its
/// vector; the minute sum.
#[derive(Debug, Clone)]
pub struct CascadeBank<T: Real = f32> {
    level: Vec<T>,
    sec_m: Vec<T>,
    sec_dx: Vec<T>,
    sec_dy: Vec<T>,
    s1: Vec<T>,
    s1_dx: Vec<T>,
    s1_dy: Vec<T>,
    min_m: Vec<T>,
}

impl<T: Real> FilterBank for CascadeBank<T> {
    const FILTERS: u32 = 4;

    bank_state!(CascadeBank: sec_m, sec_dx, sec_dy, s1, s1_dx, s1_dy, min_m);

    fn frame(&mut self, motion: &[BlockMotion], w_l1: f32) {
        let n = self.level.len().min(motion.len());
        let w = T::of(w_l1);
        let [level, sm, sx, sy] = prefixes(
            n,
            [
                &mut self.level,
                &mut self.sec_m,
                &mut self.sec_dx,
                &mut self.sec_dy,
            ],
        );
        for (k, b) in motion[..n].iter().enumerate() {
            let (m_l1, vx, vy) = f_l1_block(&mut level[k], b, w);
            sm[k] += m_l1;
            sx[k] += vx;
            sy[k] += vy;
        }
    }

    fn second(&mut self, input: SecondInput, out: &mut [BlockActivity]) {
        let n = self.level.len().min(out.len());
        let (inv, a, gap) = input.factors();
        for (k, o) in out[..n].iter_mut().enumerate() {
            let m_sec = self.sec_m[k] * inv;
            let (vx, vy) = (self.sec_dx[k] * inv, self.sec_dy[k] * inv);
            // The minute mean is built from the seconds: one add per block-second.
            self.min_m[k] += self.sec_m[k];
            if let Some(g) = gap {
                decay(g, [&mut self.s1[k], &mut self.s1_dx[k], &mut self.s1_dy[k]]);
            }
            let s2 = f_s1(&mut self.s1[k], m_sec, a);
            ema(&mut self.s1_dx[k], vx, a);
            ema(&mut self.s1_dy[k], vy, a);
            let frac = pass_fraction(m_sec, s2);
            let s1 = [self.s1[k], self.s1_dx[k], self.s1_dy[k]];
            write_activity(o, s1, s2, [vx, vy], frac);
            self.sec_m[k] = T::default();
            self.sec_dx[k] = T::default();
            self.sec_dy[k] = T::default();
        }
    }
}

/// The non-cascade reference: the same outputs from five separate filters, each fed
/// from `M_L1` rather than from the filter before it.
///
/// * in-place: its own 1-s decimating mean, then its own F_S1 (a low-pass);
/// * moving: the band-pass as two filters of its own — a 1-s FIR (F_S2) and a
///   low-pass at T_S1 whose output it subtracts (the high-pass end) — kept separately
///   from the in-place F_S1 although it holds the same values;
/// * long-term: its own per-minute mean of `M_L1`, accumulated per frame.
///
/// Written with the same care as the cascade: the same loops over re-sliced state
/// (no bounds checks in the per-frame loop), each filter computing only its own output.
#[derive(Debug, Clone)]
pub struct NonCascadeBank<T: Real = f32> {
    level: Vec<T>,
    // In-place path: decimating mean and F_S1.
    ip_m: Vec<T>,
    ip_dx: Vec<T>,
    ip_dy: Vec<T>,
    s1: Vec<T>,
    s1_dx: Vec<T>,
    s1_dy: Vec<T>,
    // Band-pass path: FIR (F_S2) and its own low-pass at T_S1.
    bp_m: Vec<T>,
    bp_dx: Vec<T>,
    bp_dy: Vec<T>,
    bp_low: Vec<T>,
    // Long-term path: minute mean.
    min_m: Vec<T>,
}

impl<T: Real> FilterBank for NonCascadeBank<T> {
    const FILTERS: u32 = 5;

    bank_state!(NonCascadeBank: ip_m, ip_dx, ip_dy, s1, s1_dx, s1_dy, bp_m, bp_dx, bp_dy, bp_low, min_m);

    fn frame(&mut self, motion: &[BlockMotion], w_l1: f32) {
        let n = self.level.len().min(motion.len());
        let w = T::of(w_l1);
        let [level, ip_m, ip_dx, ip_dy, bp_m, bp_dx, bp_dy, min_m] = prefixes(
            n,
            [
                &mut self.level,
                &mut self.ip_m,
                &mut self.ip_dx,
                &mut self.ip_dy,
                &mut self.bp_m,
                &mut self.bp_dx,
                &mut self.bp_dy,
                &mut self.min_m,
            ],
        );
        for (k, b) in motion[..n].iter().enumerate() {
            let (m_l1, vx, vy) = f_l1_block(&mut level[k], b, w);
            // In-place path.
            ip_m[k] += m_l1;
            ip_dx[k] += vx;
            ip_dy[k] += vy;
            // Band-pass path.
            bp_m[k] += m_l1;
            bp_dx[k] += vx;
            bp_dy[k] += vy;
            // Long-term path.
            min_m[k] += m_l1;
        }
    }

    fn second(&mut self, input: SecondInput, out: &mut [BlockActivity]) {
        let n = self.level.len().min(out.len());
        let (inv, a, gap) = input.factors();
        for (k, o) in out[..n].iter_mut().enumerate() {
            if let Some(g) = gap {
                decay(
                    g,
                    [
                        &mut self.s1[k],
                        &mut self.s1_dx[k],
                        &mut self.s1_dy[k],
                        &mut self.bp_low[k],
                    ],
                );
            }
            // In-place: F_S1, a low-pass, on the decimated M_L1.
            let ip = self.ip_m[k] * inv;
            let (ix, iy) = (self.ip_dx[k] * inv, self.ip_dy[k] * inv);
            ema(&mut self.s1[k], ip, a);
            ema(&mut self.s1_dx[k], ix, a);
            ema(&mut self.s1_dy[k], iy, a);
            // Moving: the FIR's mean minus the band-pass's own low-pass (its previous
            // output), rectified; then that low-pass steps.
            let fir = self.bp_m[k] * inv;
            let (fx, fy) = (self.bp_dx[k] * inv, self.bp_dy[k] * inv);
            let s2 = (fir - self.bp_low[k]).max(T::of(0.0));
            ema(&mut self.bp_low[k], fir, a);
            let frac = pass_fraction(fir, s2);
            let s1 = [self.s1[k], self.s1_dx[k], self.s1_dy[k]];
            write_activity(o, s1, s2, [fx, fy], frac);
            self.ip_m[k] = T::default();
            self.ip_dx[k] = T::default();
            self.ip_dy[k] = T::default();
            self.bp_m[k] = T::default();
            self.bp_dx[k] = T::default();
            self.bp_dy[k] = T::default();
        }
    }
}

/// The completed minute's mean per block, `min_m / frames`, into `out`; zeroes the
/// minute sums `min_m`.
fn take_minute_mean<T: Real>(min_m: &mut [T], frames: u32, out: &mut [f32]) {
    let inv = T::of(1.0 / frames.max(1) as f32);
    for (o, m) in out.iter_mut().zip(min_m.iter_mut()) {
        *o = (*m * inv).get();
        *m = T::default();
    }
}

/// Copies the stored baseline `from` into `level`, as far as both reach.
fn copy_baseline<T: Real>(level: &mut [T], from: &[f32]) {
    for (l, &f) in level.iter_mut().zip(from) {
        *l = T::of(f);
    }
}

/// The first `n` values of each of the per-block vectors `state` (re-sliced once, so
/// the per-frame loop has no bounds checks).
fn prefixes<T, const N: usize>(n: usize, state: [&mut Vec<T>; N]) -> [&mut [T]; N] {
    state.map(|v| &mut v[..n])
}

/// Sets every value of the per-block vectors `state` to zero.
fn zero<T: Real, const N: usize>(state: [&mut Vec<T>; N]) {
    for v in state {
        v.fill(T::default());
    }
}

/// Bytes held by the per-block vectors `state`.
fn state_bytes<T: Real>(state: &[&Vec<T>]) -> usize {
    let values = state.iter().map(|v| v.len()).sum::<usize>();
    values * std::mem::size_of::<T>()
}

/// Intervals the frame-rate estimate is the median of.
const RATE_WINDOW: usize = 32;
/// Intervals longer than this are gaps, not frame periods.
const MAX_FRAME_INTERVAL_NS: i64 = 2_000_000_000;
/// Intervals needed before there is an estimate.
const MIN_INTERVALS: usize = 4;

/// The frame rate r measured from capture times: the median of the last 32 frame
/// intervals, ignoring gaps (> 2 s) and repeated or backward timestamps, so that a
/// dropped frame or a stalled source does not move it.
#[derive(Debug, Clone)]
pub struct RateEstimator {
    intervals: [i64; RATE_WINDOW],
    len: usize,
    next: usize,
    last_ns: Option<i64>,
    since_update: usize,
    rate: Option<f64>,
}

impl Default for RateEstimator {
    fn default() -> Self {
        RateEstimator {
            intervals: [0; RATE_WINDOW],
            len: 0,
            next: 0,
            last_ns: None,
            since_update: 0,
            rate: None,
        }
    }
}

impl RateEstimator {
    /// Adds a frame's capture time; returns the current estimate (frames/s).
    pub fn push(&mut self, capture_ns: i64) -> Option<f64> {
        if let Some(last) = self.last_ns {
            let dt = capture_ns - last;
            if dt > 0 && dt <= MAX_FRAME_INTERVAL_NS {
                self.intervals[self.next] = dt;
                self.next = (self.next + 1) % RATE_WINDOW;
                self.len = (self.len + 1).min(RATE_WINDOW);
                self.since_update += 1;
                // The median moves slowly: recompute it early on, then every 16 frames.
                if self.len >= MIN_INTERVALS
                    && (self.rate.is_none() || self.len < RATE_WINDOW || self.since_update >= 16)
                {
                    let mut sorted = self.intervals;
                    let window = &mut sorted[..self.len];
                    window.sort_unstable();
                    let median = if self.len % 2 == 1 {
                        window[self.len / 2] as f64
                    } else {
                        (window[self.len / 2 - 1] + window[self.len / 2]) as f64 / 2.0
                    };
                    self.rate = Some(1e9 / median);
                    self.since_update = 0;
                }
            }
        }
        if self.last_ns.is_none_or(|last| capture_ns > last) {
            self.last_ns = Some(capture_ns);
        }
        self.rate
    }

    /// The current estimate, once a few intervals were seen.
    pub fn rate(&self) -> Option<f64> {
        self.rate
    }

    /// Forgets everything (a new timeline).
    pub fn reset(&mut self) {
        *self = RateEstimator::default();
    }
}

#[cfg(test)]
mod tests;
