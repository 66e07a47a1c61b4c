//! isochron-cascade: the per-camera cascade state machine, testable without shared
//! memory.
//!
//! [`Cascade`] takes motion samples ([`Cascade::push`]) and produces, once per
//! completed second of capture time, the activity of every block: in-place S1, moving
//! S2, their flow vectors, and the long-term mean and sigma at the current t*
//! ([`SecondOut`] + [`Cascade::activity`]). Once per completed minute it updates the
//! long-term model of that minute's bin t* through a [`LongTerm`] model — the SQLite
//! store in the service, [`MemoryModel`] in tests and benchmarks — in one atomic
//! commit.
//!
//! The filter math is [`filters`] (semantics documented there); this
//! crate does the bookkeeping around it, all from header timestamps, never the wall
//! clock:
//!
//! * **seconds** are `floor(capture_ns / 1 s)`; a second completes when the first
//!   frame of a later second arrives (or at end of stream). Seconds without frames
//!   publish nothing; S1 decays over them as over seconds of no motion.
//! * **frame rate** r is measured from the header timestamps (median frame interval)
//!   unless `cascade.frame_rate` is set; α of F_L1 is recomputed when r moves by more
//!   than 2 %.
//! * **minutes** are whole UTC minutes; t* is the minute's minute of the day (or week)
//!   in the site's time zone, and the long-term model's rules
//!   ([`isochron_store::isochronal`]) say which rows of the store it teaches (one, or
//!   its weekday's and its day type's) and how the long-term mean and sigma at t*
//!   are read from them. A minute teaches only if it got at least
//!   `min_coverage × r × 60` frames (a camera that was off teaches nothing: a day
//!   without data leaves the model as it was), and only if the store never completed
//!   it before (data delivered twice never counts twice; a minute earlier than what
//!   the store learned last but never seen — a clock corrected after running ahead —
//!   learns, with one warning per timeline). Every completed minute is one commit:
//!   the rows it taught, the F_L1 baseline, the progress.
//! * **time going backwards** by up to 2 s rejects the frame (out of order); by more,
//!   it starts a new timeline (a replay of an older recording): the partial second
//!   and minute are finished, the short-term state is reset, the long-term model and
//!   the F_L1 baseline are kept. End of stream does the same.
//! * **resuming**: a stored F_L1 baseline is taken up if the first frame comes at most
//!   T_L1 after it; an older one is dropped (the scene may have changed).

pub mod filters;
mod long_term;
pub mod presence;
pub mod stage;

use crate::filters::{CascadeBank, FilterBank, RateEstimator, SecondInput, alpha, warmup_weight};
use crate::presence::{Presence, PresenceParams, PresenceStats};
use isochron_config::clock::{NS_PER_S, SiteClock};
use isochron_config::{CascadeConfig, Config};
use isochron_store::isochronal::Rows;
use isochron_store::{Baseline, Bin, MinuteCommit, Rules, StoreError};
use isochron_wire::geometry::BlockGrid;
use isochron_wire::{
    ActivityHeader, BlockActivity, BlockMotion, CameraId, MotionHeader, WireError,
};

pub use crate::filters::NonCascadeBank;
pub use crate::long_term::{LongTerm, MemoryModel, TimedStore};

/// A backward time step up to this is an out-of-order frame (rejected); a larger one
/// starts a new timeline.
pub const RESYNC_BACKWARDS_NS: i64 = 2 * NS_PER_S;
/// r must move by more than this fraction before α of F_L1 is recomputed.
const RATE_CHANGE: f64 = 0.02;
/// Largest density (and flow component) accepted; the wire says 0..=1.
const MAX_DENSITY: f32 = 1.001;

/// The filter parameters, from `[cascade]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Params {
    /// T of F_L1, seconds.
    pub t_l1_s: f64,
    /// How the long-term model learns and forecasts (F_L2, its rows and day types).
    pub rules: Rules,
    /// T of F_S1, seconds.
    pub t_s1_s: f64,
    /// Fixed frame rate r; `None`: measured.
    pub frame_rate: Option<f64>,
    /// Fraction of a minute's expected frames it needs to teach F_L2.
    pub min_coverage: f64,
    /// The presence band.
    pub presence: PresenceParams,
}

impl Params {
    /// The parameters of a site's `[cascade]`, `[presence]` and `[motion]`.
    pub fn of(config: &Config) -> Self {
        let c: &CascadeConfig = &config.cascade;
        let p = &config.presence;
        Params {
            t_l1_s: c.t_l1_s,
            rules: Rules::of(c),
            t_s1_s: c.t_s1_s,
            frame_rate: c.frame_rate,
            min_coverage: c.min_coverage,
            presence: PresenceParams {
                enabled: p.enabled && config.motion.appearance_hz > 0.0,
                absorb_s: p.absorb_s,
                luma_change: p.luma_change as f32,
                texture_change: p.texture_change as f32,
                moving_density: config.motion.density_threshold,
            },
        }
    }
}

impl Default for Params {
    fn default() -> Self {
        Params::of(&Config::default())
    }
}

/// Why a motion sample was rejected (it is counted and skipped; the cascade goes on).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Reject {
    /// The header does not describe the sample (foreign producer, other version...).
    #[error("{0}")]
    Wire(#[from] WireError),
    /// The block grid differs from the one this cascade runs on.
    #[error(
        "the sample has {found}, this cascade runs on {expected} (was motion restarted with other settings?)"
    )]
    Grid {
        /// The cascade's grid.
        expected: BlockGrid,
        /// The sample's grid.
        found: BlockGrid,
    },
    /// A block holds a value outside its range (NaN, negative or > 1 density).
    #[error("block {block}: {what}")]
    Value {
        /// Row-major block index.
        block: usize,
        /// What is wrong.
        what: String,
    },
    /// Capture time is not plausible.
    #[error("capture time {0} ns is not a time after 1970")]
    Time(i64),
    /// The frame is older than the previous one (by at most the resync limit).
    #[error(
        "capture time went back by {:.3} s (out-of-order frame)",
        *by_ns as f64 / 1e9
    )]
    Backwards {
        /// How far back.
        by_ns: i64,
    },
}

/// What can go wrong when pushing a sample.
#[derive(Debug, thiserror::Error)]
pub enum PushError {
    /// The sample was rejected; nothing changed.
    #[error("rejected motion sample: {0}")]
    Reject(#[from] Reject),
    /// The long-term store failed; the service cannot go on safely.
    #[error("{0}")]
    Store(#[from] StoreError),
}

/// One completed second: its activity header (camera and sequence left for the
/// publisher; the blocks are [`Cascade::activity`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SecondOut {
    /// The second: `floor(capture_ns / 1 s)`.
    pub second: i64,
    /// The header: t*, model days, frames and source indices of the second, the
    /// frame rate in use (0 while unknown), and the `origin_wall_ns` of its last
    /// frame (for end-to-end latency).
    pub header: ActivityHeader,
}

/// Counters of a cascade.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Stats {
    /// Frames accepted.
    pub frames: u64,
    /// Seconds completed (activity samples produced).
    pub seconds: u64,
    /// Minutes that taught their bin.
    pub minutes_learned: u64,
    /// Minutes with too few frames.
    pub minutes_sparse: u64,
    /// Minutes their bin had already learned from (data delivered twice).
    pub minutes_repeated: u64,
    /// New timelines started (large backward jumps, end of stream).
    pub timelines: u64,
}

#[derive(Debug, Clone, Copy)]
struct SecondState {
    index: i64,
    frames: u32,
    first_source: u64,
    last_source: u64,
    origin_wall_ns: i64,
}

#[derive(Debug, Clone)]
struct MinuteState {
    index: i64,
    rows: Rows,
    frames: u32,
    /// The stored bins of `rows` (cycle's, day type's).
    stored: [Option<Bin>; 2],
    /// The long-term forecast for the minute, read from them.
    forecast: Option<Bin>,
}

/// The cascade of one camera: filters, timing, and long-term updates.
pub struct Cascade<B: FilterBank = CascadeBank> {
    camera: CameraId,
    params: Params,
    clock: SiteClock,
    grid: BlockGrid,
    bank: B,
    rate: RateEstimator,
    rate_in_use: Option<f64>,
    l1_one_minus_alpha: f64,
    l1_frames: u64,
    alpha_s1: f32,
    /// Whether this timeline has warned of a minute before the latest learned one.
    warned_earlier: bool,
    resume: Option<Baseline>,
    last_capture_ns: Option<i64>,
    last_second_done: Option<i64>,
    second: Option<SecondState>,
    minute: Option<MinuteState>,
    minute_means: Vec<f32>,
    presence: Presence,
    out: Vec<BlockActivity>,
    stats: Stats,
}

impl<B: FilterBank> Cascade<B> {
    /// A cascade for `camera` on `grid`. `resume` is the stored F_L1 baseline, taken up
    /// at the first frame if it is recent enough.
    pub fn new(
        camera: CameraId,
        params: Params,
        clock: SiteClock,
        grid: BlockGrid,
        resume: Option<Baseline>,
    ) -> Self {
        let k = grid.len();
        let rate_in_use = params.frame_rate;
        let presence = params.presence;
        let l1_one_minus_alpha = rate_in_use.map_or(0.0, |r| 1.0 - alpha(params.t_l1_s, r));
        Cascade {
            camera,
            alpha_s1: alpha(params.t_s1_s, 1.0) as f32,
            warned_earlier: false,
            params,
            clock,
            grid,
            bank: B::new(k),
            rate: RateEstimator::default(),
            rate_in_use,
            l1_one_minus_alpha,
            l1_frames: 0,
            resume: resume.filter(|b| b.level.len() == k),
            last_capture_ns: None,
            last_second_done: None,
            second: None,
            minute: None,
            minute_means: vec![0.0; k],
            presence: Presence::new(presence, grid.grid_w() as usize, grid.grid_h() as usize),
            out: vec![BlockActivity::default(); k],
            stats: Stats::default(),
        }
    }

    /// The grid this cascade runs on.
    pub fn grid(&self) -> &BlockGrid {
        &self.grid
    }

    /// The blocks of the last completed second (valid after [`Cascade::push`] or
    /// [`Cascade::end_of_stream`] returned a [`SecondOut`]).
    pub fn activity(&self) -> &[BlockActivity] {
        &self.out
    }

    /// Counters.
    pub fn stats(&self) -> Stats {
        self.stats
    }

    /// Counters of the presence band.
    pub fn presence_stats(&self) -> PresenceStats {
        self.presence.stats()
    }

    /// Bytes of per-block filter state.
    pub fn state_bytes(&self) -> usize {
        self.bank.state_bytes()
    }

    /// The frame rate r in use, if known.
    pub fn frame_rate(&self) -> Option<f64> {
        self.rate_in_use
    }

    /// α of F_L1 in use (for the rate in use).
    pub fn alpha_l1(&self) -> f64 {
        1.0 - self.l1_one_minus_alpha
    }

    /// The F_L1 baseline per block.
    pub fn baseline(&self) -> Vec<f32> {
        self.bank.baseline()
    }

    /// Frames the F_L1 baseline has seen.
    pub fn baseline_frames(&self) -> u64 {
        self.l1_frames
    }

    /// Pushes one motion sample. Returns the second it completed, if any (its blocks
    /// are [`Cascade::activity`]). An end-of-stream sample is
    /// [`Cascade::end_of_stream`]. A rejected sample changes nothing.
    pub fn push(
        &mut self,
        header: &MotionHeader,
        blocks: &[BlockMotion],
        model: &mut dyn LongTerm,
    ) -> Result<Option<SecondOut>, PushError> {
        header
            .validate(&self.camera, blocks.len())
            .map_err(Reject::from)?;
        if header.preamble.is_end_of_stream() {
            return Ok(self.end_of_stream(model)?);
        }
        // A valid header's grid_w/grid_h are the ones its frame size and block edge
        // give, so its BlockGrid describes it completely.
        let found = header.block_grid();
        if found != self.grid {
            return Err(Reject::Grid {
                expected: self.grid,
                found,
            }
            .into());
        }
        check_values(blocks)?;
        let t = header.preamble.capture_time_ns;
        if t <= 0 {
            return Err(Reject::Time(t).into());
        }
        let mut done = None;
        if let Some(last) = self.last_capture_ns
            && t < last
        {
            if last - t <= RESYNC_BACKWARDS_NS {
                return Err(Reject::Backwards { by_ns: last - t }.into());
            }
            tracing::info!(
                "capture time jumped back by {:.1} s: a new timeline starts (short-term state reset, long-term model kept)",
                (last - t) as f64 / 1e9
            );
            done = self.end_timeline(model)?;
        }
        if let Some(b) = self.resume.take() {
            self.take_up(b, t);
        }

        let second = t.div_euclid(NS_PER_S);
        if let Some(s) = self.second
            && s.index != second
        {
            done = Some(self.finish_second(s));
            self.second = None;
        }
        let minute = second.div_euclid(60);
        if let Some(m) = &self.minute
            && m.index != minute
        {
            let m = self.minute.take().expect("checked");
            self.finish_minute(m, model)?;
        }
        if self.minute.is_none() {
            self.minute = Some(self.start_minute(minute, model)?);
        }
        let s = self.second.get_or_insert(SecondState {
            index: second,
            frames: 0,
            first_source: header.source_index,
            last_source: header.source_index,
            origin_wall_ns: 0,
        });
        s.frames += 1;
        s.last_source = header.source_index;
        s.origin_wall_ns = header.preamble.origin_wall_ns;
        if let Some(m) = &mut self.minute {
            m.frames += 1;
        }

        self.update_rate(t);
        let w = warmup_weight(self.l1_one_minus_alpha, self.l1_frames) as f32;
        self.bank.frame(blocks, w);
        self.presence.frame(header.preamble.flags, blocks);
        self.l1_frames += 1;
        self.last_capture_ns = Some(t);
        self.stats.frames += 1;
        Ok(done)
    }

    /// The stream ended: finishes the partial second (returned, if it had frames) and
    /// the partial minute (it teaches its bin if it has enough frames), then resets the
    /// short-term state for whatever comes next.
    pub fn end_of_stream(
        &mut self,
        model: &mut dyn LongTerm,
    ) -> Result<Option<SecondOut>, StoreError> {
        self.end_timeline(model)
    }

    fn end_timeline(&mut self, model: &mut dyn LongTerm) -> Result<Option<SecondOut>, StoreError> {
        let done = self.second.take().map(|s| self.finish_second(s));
        if let Some(m) = self.minute.take() {
            self.finish_minute(m, model)?;
        }
        self.bank.reset_short_term();
        self.presence.reset();
        self.rate.reset();
        self.last_capture_ns = None;
        self.last_second_done = None;
        self.warned_earlier = false;
        self.stats.timelines += 1;
        Ok(done)
    }

    /// The state of absolute minute `minute` as it starts: its rows, their stored
    /// bins and the forecast read from them.
    fn start_minute(
        &self,
        minute: i64,
        model: &mut dyn LongTerm,
    ) -> Result<MinuteState, StoreError> {
        let (date, minute_of_day) = self
            .clock
            .local_date_minute(minute.saturating_mul(60 * NS_PER_S));
        let rows = self.params.rules.rows(date, minute_of_day);
        let read = |r: Option<u32>, model: &mut dyn LongTerm| r.map(|r| model.bin(r)).transpose();
        let stored = [
            read(rows.cycle, model)?.flatten(),
            read(rows.day_type, model)?.flatten(),
        ];
        let forecast = self
            .params
            .rules
            .forecast(rows, stored[0].as_ref(), stored[1].as_ref())
            .map(std::borrow::Cow::into_owned);
        Ok(MinuteState {
            index: minute,
            rows,
            frames: 0,
            stored,
            forecast,
        })
    }

    fn take_up(&mut self, b: Baseline, first_ns: i64) {
        let age_s = (first_ns - b.capture_ns) as f64 / 1e9;
        if (0.0..=self.params.t_l1_s).contains(&age_s) {
            self.bank.set_baseline(&b.level);
            self.l1_frames = b.frames;
            if self.params.frame_rate.is_none() && b.frame_rate > 0.0 {
                self.set_rate(b.frame_rate);
            }
            tracing::info!(
                "resumed the F_L1 baseline from the store ({} frames, r = {:.2}/s, {:.1} s old)",
                b.frames,
                b.frame_rate,
                age_s
            );
        } else {
            tracing::info!(
                "not resuming the stored F_L1 baseline: it is {age_s:.0} s from the first frame (more than T_L1 = {} s, or in its future)",
                self.params.t_l1_s
            );
        }
    }

    fn update_rate(&mut self, t: i64) {
        let measured = self.rate.push(t);
        if self.params.frame_rate.is_some() {
            return;
        }
        if let Some(r) = measured
            && self
                .rate_in_use
                .is_none_or(|u| (r / u - 1.0).abs() > RATE_CHANGE)
        {
            if let Some(u) = self.rate_in_use {
                tracing::info!("frame rate changed from {u:.2} to {r:.2} frames/s");
            }
            self.set_rate(r);
        }
    }

    fn set_rate(&mut self, r: f64) {
        self.rate_in_use = Some(r);
        self.l1_one_minus_alpha = 1.0 - alpha(self.params.t_l1_s, r);
    }

    fn finish_second(&mut self, s: SecondState) -> SecondOut {
        let gap = self
            .last_second_done
            .map_or(0, |last| (s.index - last - 1).max(0));
        let gap_decay = if gap == 0 {
            1.0
        } else if gap > 100_000 {
            0.0
        } else {
            self.alpha_s1.powi(gap as i32)
        };
        self.bank.second(
            SecondInput {
                frames: s.frames,
                gap_decay,
                alpha_s1: self.alpha_s1,
            },
            &mut self.out,
        );
        self.presence.second(s.index, &mut self.out);
        let (t_star, bin) = match &self.minute {
            Some(m) => (m.rows.t_star, m.forecast.as_ref()),
            None => {
                let (date, minute) = self.clock.local_date_minute(s.index * NS_PER_S);
                (self.params.rules.rows(date, minute).t_star, None)
            }
        };
        match bin {
            Some(bin) => {
                for (k, o) in self.out.iter_mut().enumerate() {
                    o.lt_mean = bin.mean[k];
                    o.lt_sigma = bin.sigma(k);
                }
            }
            None => {
                for o in &mut self.out {
                    o.lt_mean = 0.0;
                    o.lt_sigma = 0.0;
                }
            }
        }
        self.last_second_done = Some(s.index);
        self.stats.seconds += 1;
        let end_ns = (s.index + 1).saturating_mul(NS_PER_S);
        let mut header = ActivityHeader {
            t_star,
            model_days: bin.map_or(0, |b| b.count),
            frames: s.frames,
            first_source_index: s.first_source,
            last_source_index: s.last_source,
            frame_rate: self.rate_in_use.unwrap_or(0.0) as f32,
            ..ActivityHeader::new(CameraId::default(), 0, self.grid, end_ns)
        };
        header.preamble.origin_wall_ns = s.origin_wall_ns;
        SecondOut {
            second: s.index,
            header,
        }
    }

    /// The long-term forecast for absolute minute `minute` (minutes since the Unix
    /// epoch): the bin whose mean and sigma the activity of that minute carries.
    pub fn forecast(
        &self,
        minute: i64,
        model: &mut dyn LongTerm,
    ) -> Result<Option<Bin>, StoreError> {
        Ok(self.start_minute(minute, model)?.forecast)
    }

    /// Teaches the long-term model the per-block minute means `x` of absolute minute
    /// `minute` as a completed minute with enough frames does; a minute completed
    /// before teaches nothing (`false`). The seam a backtest is checked against.
    pub fn learn_minute(
        &mut self,
        minute: i64,
        x: &[f32],
        model: &mut dyn LongTerm,
    ) -> Result<bool, StoreError> {
        if model.completed(minute) || x.len() != self.grid.len() {
            return Ok(false);
        }
        let m = self.start_minute(minute, model)?;
        self.teach(m, x, None, model)?;
        Ok(true)
    }

    /// Teaches the rows of `m` the means `x` and commits them with `baseline`.
    fn teach(
        &mut self,
        m: MinuteState,
        x: &[f32],
        baseline: Option<&Baseline>,
        model: &mut dyn LongTerm,
    ) -> Result<(), StoreError> {
        if let Some(latest) = model.latest()
            && m.index < latest
            && !self.warned_earlier
        {
            self.warned_earlier = true;
            tracing::warn!(
                "minute {} comes before {}, the latest minute the long-term store completed, and was never delivered before: learning it (a clock corrected after running ahead, or an older recording); a minute delivered twice is still learned once",
                isochron_config::clock::format_rfc3339(m.index.saturating_mul(60 * NS_PER_S)),
                isochron_config::clock::format_rfc3339(latest.saturating_mul(60 * NS_PER_S)),
            );
        }
        let k = self.grid.len();
        let [a, b] = m.stored;
        let bins: Vec<Bin> = [(m.rows.cycle, a), (m.rows.day_type, b)]
            .into_iter()
            .filter_map(|(row, stored)| {
                let row = row?;
                let mut bin = stored.unwrap_or_else(|| Bin::empty(row, k));
                self.params.rules.learn(&mut bin, x, m.index);
                Some(bin)
            })
            .collect();
        model.commit(&MinuteCommit {
            minute: m.index,
            bins: &bins,
            baseline,
        })
    }

    fn finish_minute(
        &mut self,
        m: MinuteState,
        model: &mut dyn LongTerm,
    ) -> Result<(), StoreError> {
        self.bank.minute_mean(m.frames, &mut self.minute_means);
        let expected = self
            .rate_in_use
            .map(|r| r * 60.0 * self.params.min_coverage);
        let covered = expected.is_some_and(|e| m.frames as f64 >= e) && m.frames > 0;
        let repeated = model.completed(m.index);
        let baseline = Baseline {
            capture_ns: self.last_capture_ns.unwrap_or(0),
            frames: self.l1_frames,
            frame_rate: self.rate_in_use.unwrap_or(0.0),
            level: self.bank.baseline(),
        };
        if covered && !repeated {
            let means = std::mem::take(&mut self.minute_means);
            let taught = self.teach(m, &means, Some(&baseline), model);
            self.minute_means = means;
            taught?;
            self.stats.minutes_learned += 1;
        } else {
            model.commit(&MinuteCommit {
                minute: m.index,
                bins: &[],
                baseline: Some(&baseline),
            })?;
            if repeated {
                self.stats.minutes_repeated += 1;
            } else {
                self.stats.minutes_sparse += 1;
            }
        }
        Ok(())
    }
}

/// Rejects NaN, infinite, negative or > 1 densities and flow components.
fn check_values(blocks: &[BlockMotion]) -> Result<(), Reject> {
    let ok = |b: &BlockMotion| {
        (0.0..=MAX_DENSITY).contains(&b.density)
            && b.dx.abs() <= MAX_DENSITY
            && b.dy.abs() <= MAX_DENSITY
    };
    // One branch-free pass; the slow search only when something is wrong.
    let all_ok = blocks.iter().fold(true, |acc, b| acc & ok(b));
    if all_ok {
        return Ok(());
    }
    let (block, b) = blocks
        .iter()
        .enumerate()
        .find(|(_, b)| !ok(b))
        .expect("a bad block exists");
    Err(Reject::Value {
        block,
        what: format!(
            "density {} and flow ({}, {}) outside 0..=1",
            b.density, b.dx, b.dy
        ),
    })
}

#[cfg(test)]
mod tests;
