//! `isochron store backtest --counts FILE.csv`: how well the long-term model would
//! have forecast a site, before it is deployed.
//!
//! Each count series ([`counts`]) is replayed day by day through the long-term
//! model's own rules (`isochron_store::isochronal`, the code the cascade learns
//! with): every day is first forecast from the days before it, then learned. Each
//! interval is one sample of the bin of its first minute, as a cascade that saw that
//! count in every minute of the interval would learn it. Beside the configured
//! model it runs the baselines a site would otherwise use — the same interval one
//! week earlier, the mean of the same weekday's interval over the last 4 weeks, and
//! the paper's model (one daily cycle, T_L2 = 10 days) — and scores all of them on
//! the same intervals: those whose count is known and that every one of them
//! forecasts.
//!
//! * **NMAE** `Σ|forecast − actual| / Σ actual` over the scored hours of the scored
//!   days;
//! * **departure-pick regret**: each day, the hour of the pick window with the lowest
//!   forecast is picked; regret = (actual at the pick − the day's lowest actual in
//!   the window) / the window's mean actual, averaged over days: what a robot
//!   scheduler that trusts the forecast loses.
//!
//! Figures per series, then the median over series; the last line is one JSON
//! object (`{"model": {..}, "baselines": {..}, "series": {..}}`).

mod counts;
mod score;

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::bail;
use isochron_config::CascadeConfig;
use isochron_config::clock::Cycle;
use isochron_exit::{DATA, USAGE, UsageError};
use isochron_store::{Bin, Model, Rules, StoreMeta};
use isochron_wire::geometry::BlockGrid;
use jiff::civil::Date;
use serde_json::json;

use crate::common::with_code;
use crate::values;
pub use counts::Counts;
use score::{Score, Window};

/// The baselines, by the name the JSON line gives them.
pub const BASELINES: [&str; 3] = ["same_hour_last_week", "mean_4_weeks", "paper_daily_ema"];

/// Options of `isochron store backtest`.
#[derive(clap::Args)]
pub struct BacktestArgs {
    /// The count series: CSV with a header `time,<series>,...`, `time` as
    /// YYYY-MM-DDTHH:MM local time (or RFC 3339), counts per interval (1–60 min),
    /// empty = missing.
    #[arg(long)]
    counts: PathBuf,
    /// The site's config: the model of its `[cascade]` (cycle, T_L2, rest days,
    /// holidays) and its time zone. Default: the default configuration, UTC.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Another cycle than the config's: day_types, daily or weekly.
    #[arg(long, value_parser = values::cycle)]
    cycle: Option<Cycle>,
    /// Only these series (comma-separated names).
    #[arg(long)]
    series: Option<String>,
    /// Learning begins on this day (YYYY-MM-DD; default the first day of the file):
    /// a cold start.
    #[arg(long, value_name = "YYYY-MM-DD", value_parser = values::date)]
    learn_from: Option<Date>,
    /// The first scored day (default: the first day learning begins on).
    #[arg(long, value_name = "YYYY-MM-DD", value_parser = values::date)]
    score_from: Option<Date>,
    /// The last scored day (default: the file's last day).
    #[arg(long, value_name = "YYYY-MM-DD", value_parser = values::date)]
    score_to: Option<Date>,
    /// Scored hours of the day, `FROM-TO` inclusive.
    #[arg(long, default_value = "6-21")]
    hours: String,
    /// Hours a departure is picked from, `FROM-TO` inclusive.
    #[arg(long, default_value = "8-18")]
    pick_hours: String,
}

pub fn run(args: BacktestArgs) -> anyhow::Result<ExitCode> {
    let (cascade, tz) = match &args.config {
        Some(path) => {
            let loaded = crate::common::load_config(Some(path.clone()))?;
            let tz = jiff::tz::TimeZone::get(&loaded.config.site.time_zone)?;
            (loaded.config.cascade, tz)
        }
        None => (CascadeConfig::default(), jiff::tz::TimeZone::UTC),
    };
    let mut cascade = cascade;
    if let Some(cycle) = args.cycle {
        cascade.cycle = cycle;
    }
    let window = Window::parse(&args.hours, &args.pick_hours).map_err(|e| with_code(USAGE, e))?;
    crate::common::input_file("--counts", &args.counts, "a CSV file of counts")?;
    let mut counts = counts::read(&args.counts, &tz).map_err(|e| with_code(DATA, e))?;
    counts::long_enough(&counts, &args.counts).map_err(|e| with_code(DATA, e))?;
    if let Some(list) = &args.series {
        let keep: Vec<String> = list.split(',').map(|s| s.trim().to_string()).collect();
        counts = counts.only(&keep).map_err(|e| with_code(USAGE, e))?;
    }
    let learn_from = args.learn_from.unwrap_or(counts.first);
    let score_from = args.score_from.unwrap_or(learn_from);
    let plan = Plan {
        learn_from: counts.day_of(learn_from).max(0) as usize,
        score_from: counts.day_of(score_from).max(0) as usize,
        score_to: args
            .score_to
            .map_or(counts.days() as i64 - 1, |d| counts.day_of(d))
            .min(counts.days() as i64 - 1),
        window,
    };
    if plan.score_to < plan.score_from as i64 {
        bail!(UsageError(
            "--learn-from, --score-from, --score-to: no day to score: the scored range is empty or outside the file".into()
        ));
    }
    let rules = Rules::of(&cascade);
    let name = model_name(&cascade);
    let report = backtest(&counts, &rules, &plan);
    if report.iter().flatten().all(|s| s.intervals == 0) {
        return Err(with_code(
            DATA,
            anyhow::anyhow!(
                "--counts {}: no interval could be scored: none of the scored hours (--hours {}) has a count on a day that has one a week earlier (the baselines forecast from it)",
                args.counts.display(),
                args.hours
            ),
        ));
    }
    print_report(&name, &counts, &report);
    Ok(ExitCode::SUCCESS)
}

/// Which days learn and which are scored, and the hours scored.
#[derive(Debug, Clone)]
pub struct Plan {
    /// The first day learned (index into the counts' days).
    pub learn_from: usize,
    /// The first day scored.
    pub score_from: usize,
    /// The last day scored (inclusive).
    pub score_to: i64,
    /// The scored hours and the pick window.
    pub window: Window,
}

/// The scores of one series: the model's, then each baseline's.
pub type SeriesScores = Vec<Score>;

/// The long-term model of one count series, learned and read through the store's
/// rules: a one-block model whose rows are the store's.
pub struct SeriesModel {
    model: Model,
}

impl SeriesModel {
    /// An empty model of `rules`.
    pub fn new(rules: &Rules) -> SeriesModel {
        let meta = StoreMeta::new("backtest", BlockGrid::new(16, 16, 16), rules.cycle(), 0);
        SeriesModel {
            model: Model::with_bins(meta, []).with_rules(rules.clone()),
        }
    }

    /// The forecast for `minute_of_day` on `date`.
    pub fn forecast(&self, date: Date, minute_of_day: u32) -> Option<f64> {
        self.model
            .bin_on(date, minute_of_day)
            .map(|b| b.mean[0].max(0.0) as f64)
    }

    /// Learns `x` at `minute_of_day` on `date`.
    pub fn learn(&mut self, date: Date, minute_of_day: u32, x: f64) {
        let rows = self.model.rules.rows(date, minute_of_day);
        let day = date
            .since(jiff::civil::date(1970, 1, 1))
            .map(|s| s.get_days() as i64)
            .unwrap_or(0);
        let minute = day * 1440 + minute_of_day as i64;
        for row in rows.iter() {
            let slot = &mut self.model.bins[row as usize];
            let bin = slot.get_or_insert_with(|| Bin::empty(row, 1));
            self.model.rules.learn(bin, &[x as f32], minute);
        }
    }
}

/// Replays every series; per series the scores of the model and the baselines.
pub fn backtest(counts: &Counts, rules: &Rules, plan: &Plan) -> Vec<SeriesScores> {
    counts
        .values
        .iter()
        .map(|series| {
            let forecasts = forecasts(counts, series, rules, plan);
            score::score_all(counts, series, &forecasts, plan)
        })
        .collect()
}

/// Per model (the configured one, then the baselines), per day, per interval: the
/// forecast made before the day was learned.
fn forecasts(
    counts: &Counts,
    series: &[Vec<Option<f64>>],
    rules: &Rules,
    plan: &Plan,
) -> Vec<Vec<Vec<Option<f64>>>> {
    let slots = counts.slots();
    let interval = counts.interval;
    let mut model = SeriesModel::new(rules);
    let mut paper = SeriesModel::new(&Rules::of(&CascadeConfig {
        cycle: Cycle::Daily,
        t_l2_days: 10.0,
        ..CascadeConfig::default()
    }));
    let last = plan.score_to.max(0) as usize;
    let mut out = vec![vec![vec![None; slots]; last + 1]; 1 + BASELINES.len()];
    for d in plan.learn_from..=last.min(series.len().saturating_sub(1)) {
        let date = counts.date(d);
        let earlier = |weeks: usize| {
            d.checked_sub(7 * weeks)
                .filter(|&e| e >= plan.learn_from)
                .map(|e| &series[e])
        };
        for s in 0..slots {
            let minute = s as u32 * interval;
            out[0][d][s] = model.forecast(date, minute);
            out[1][d][s] = earlier(1).and_then(|e| e[s]);
            let past: Vec<f64> = (1..=4)
                .filter_map(|w| earlier(w).and_then(|e| e[s]))
                .collect();
            out[2][d][s] = (!past.is_empty()).then(|| past.iter().sum::<f64>() / past.len() as f64);
            out[3][d][s] = paper.forecast(date, minute);
        }
        for (s, v) in series[d].iter().enumerate() {
            if let Some(x) = *v {
                let minute = s as u32 * interval;
                model.learn(date, minute, x);
                paper.learn(date, minute, x);
            }
        }
    }
    out
}

/// The configured model as the report names it.
fn model_name(c: &CascadeConfig) -> String {
    match c.cycle {
        Cycle::DayTypes => format!(
            "day_types (T_L2 {} days, weekdays {} weeks, K {})",
            c.t_l2_days, c.t_l2_weeks, c.weekday_prior_weeks
        ),
        Cycle::Daily => format!("daily (T_L2 {} days)", c.t_l2_days),
        Cycle::Weekly => format!("weekly (T_L2 {} weeks)", c.t_l2_days),
    }
}

fn print_report(name: &str, counts: &Counts, report: &[SeriesScores]) {
    let labels: Vec<&str> = std::iter::once("model").chain(BASELINES).collect();
    println!("backtest: {name}, {} series", counts.names.len());
    println!(
        "{:<40} {}",
        "series",
        labels
            .iter()
            .map(|l| format!("{l:>24}"))
            .collect::<String>()
    );
    let mut per_series = serde_json::Map::new();
    for (series, scores) in counts.names.iter().zip(report) {
        let cells: String = scores.iter().map(|s| format!("{:>24}", s.cell())).collect();
        println!("{series:<40} {cells}");
        per_series.insert(series.clone(), entry(scores));
    }
    let medians: Vec<Score> = (0..labels.len())
        .map(|i| Score::median(report.iter().filter_map(|s| s.get(i))))
        .collect();
    println!(
        "{:<40} {}",
        "median over series (NMAE / regret)",
        medians
            .iter()
            .map(|s| format!("{:>24}", s.cell()))
            .collect::<String>()
    );
    let mut top = entry(&medians);
    if let Some(m) = top.get_mut("model").and_then(|m| m.as_object_mut()) {
        m.insert("name".into(), json!(name));
    }
    top["series"] = serde_json::Value::Object(per_series);
    println!("{top}");
}

/// `{"model": {..}, "baselines": {NAME: {..}}}` of one row of scores.
fn entry(scores: &[Score]) -> serde_json::Value {
    let mut baselines = serde_json::Map::new();
    for (name, s) in BASELINES.iter().zip(scores.iter().skip(1)) {
        baselines.insert((*name).to_string(), s.json());
    }
    json!({
        "model": scores.first().map(Score::json),
        "baselines": baselines,
    })
}
