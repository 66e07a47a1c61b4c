//! What a store holds: its meta, the bins of the model, the F_L1 baseline and the
//! cascade's progress.

use std::borrow::Cow;

use isochron_config::clock::Cycle;
use isochron_wire::geometry::BlockGrid;
use jiff::civil::Date;

use crate::Bin;
use crate::isochronal::Rules;

/// What a store is about; fixed when it is created.
///
/// The `meta` table stores the grid's frame size and block edge, and for readers of
/// the file the model's size `grid_w × grid_h` (every blob has that many values),
/// which must agree with them.
#[derive(Debug, Clone, PartialEq)]
pub struct StoreMeta {
    /// Camera id.
    pub camera: String,
    /// The block grid of the model.
    pub grid: BlockGrid,
    /// The isochronal cycle: the number of bins.
    pub cycle: Cycle,
    /// Wall-clock time of creation, UTC ns.
    pub created_ns: i64,
}

impl StoreMeta {
    /// The meta of a new store of `camera` on `grid`.
    pub fn new(camera: impl Into<String>, grid: BlockGrid, cycle: Cycle, created_ns: i64) -> Self {
        StoreMeta {
            camera: camera.into(),
            grid,
            cycle,
            created_ns,
        }
    }

    /// Number of blocks per bin.
    pub fn blocks(&self) -> usize {
        self.grid.len()
    }

    /// Number of minute bins of the cycle: what t* counts.
    pub fn bins(&self) -> u32 {
        self.cycle.bins()
    }

    /// Number of rows the store keeps ([`Cycle::rows`]).
    pub fn rows(&self) -> u32 {
        self.cycle.rows()
    }

    /// `WxH`.
    pub fn grid(&self) -> String {
        format!("{}x{}", self.grid.grid_w(), self.grid.grid_h())
    }
}

/// The F_L1 baseline of a camera at a point in (capture) time.
#[derive(Debug, Clone, PartialEq)]
pub struct Baseline {
    /// Capture time of the last frame that went into it, UTC ns.
    pub capture_ns: i64,
    /// Frames it has seen (drives the bias-corrected warm-up).
    pub frames: u64,
    /// Frame rate r in use, frames/s.
    pub frame_rate: f64,
    /// Baseline density per block.
    pub level: Vec<f32>,
}

/// How far the cascade has got.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Progress {
    /// The last completed minute (minutes since the Unix epoch), if any.
    pub last_minute: Option<i64>,
    /// Minutes that updated a bin.
    pub committed: u64,
    /// Minutes completed without enough frames (or already learned), not learned.
    pub skipped: u64,
}

/// One completed minute, written atomically by [`Store::commit_minute`].
#[derive(Debug, Clone, Copy)]
pub struct MinuteCommit<'a> {
    /// The minute (minutes since the Unix epoch).
    pub minute: i64,
    /// The new state of the rows the minute taught; empty if it was skipped.
    pub bins: &'a [Bin],
    /// The F_L1 baseline at the end of the minute.
    pub baseline: Option<&'a Baseline>,
}

/// The whole long-term model of a camera: the store's rows, and the rules that read
/// forecasts from them.
#[derive(Debug, Clone, PartialEq)]
pub struct Model {
    /// What the store is about.
    pub meta: StoreMeta,
    /// One entry per row of the store (`None`: never taught).
    pub bins: Vec<Option<Bin>>,
    /// How forecasts are read from the rows: the cycle's defaults until
    /// [`Model::with_rules`] gives the site's.
    pub rules: Rules,
}

impl Model {
    /// The model of `meta` that has learned `bins` (each at its row, which must be
    /// inside the store) and nothing else: a known model without a store.
    pub fn with_bins(meta: StoreMeta, bins: impl IntoIterator<Item = Bin>) -> Model {
        let mut all = vec![None; meta.rows() as usize];
        for bin in bins {
            let t = bin.t_star as usize;
            if t < all.len() {
                all[t] = Some(bin);
            }
        }
        Model {
            rules: Rules::defaults(meta.cycle),
            meta,
            bins: all,
        }
    }

    /// The same model read with the site's `rules` (rest days, holidays, weights);
    /// rules of another cycle are ignored.
    pub fn with_rules(mut self, rules: Rules) -> Model {
        if rules.cycle() == self.meta.cycle {
            self.rules = rules;
        }
        self
    }

    /// Row `row` of the store, if it has learned anything.
    pub fn row(&self, row: u32) -> Option<&Bin> {
        self.bins.get(row as usize).and_then(Option::as_ref)
    }

    /// The forecast at minute `t_star` of the cycle (taken modulo the cycle: a daily
    /// model serves every day of a week) on a day that is no holiday, if anything
    /// was learned for it.
    pub fn bin(&self, t_star: u32) -> Option<Cow<'_, Bin>> {
        let rows = self.rules.rows_of_t_star(t_star % self.meta.bins().max(1));
        self.forecast(rows)
    }

    /// The forecast for `minute_of_day` on the local `date` (holidays included).
    pub fn bin_on(&self, date: Date, minute_of_day: u32) -> Option<Cow<'_, Bin>> {
        self.forecast(self.rules.rows(date, minute_of_day))
    }

    fn forecast(&self, rows: crate::isochronal::Rows) -> Option<Cow<'_, Bin>> {
        let get = |r: Option<u32>| r.and_then(|r| self.row(r));
        self.rules
            .forecast(rows, get(rows.cycle), get(rows.day_type))
    }

    /// Rows that have learned anything.
    pub fn learned(&self) -> impl Iterator<Item = &Bin> {
        self.bins.iter().flatten()
    }
}

/// What [`Store::verify`] checked.
#[derive(Debug, Clone, PartialEq)]
pub struct VerifyReport {
    /// Bin rows checked.
    pub bins: usize,
    /// Whether a baseline row is present (and valid).
    pub baseline: bool,
    /// The progress.
    pub progress: Progress,
}
