//! The long-term (isochronal) model's rules: which rows of the store a local minute
//! teaches, how a row learns (F_L2), and how the forecast for a minute is read from
//! its rows. The cascade learns through these rules and `isochron store backtest`
//! replays count series through the same ones, so a backtest scores exactly the
//! model the cascade runs.
//!
//! * **daily** (the paper's): one row per minute of the day; every day teaches it.
//! * **weekly**: one row per minute of the week; each weekday learns alone (one
//!   sample per row per week: weeks to converge).
//! * **day types** (the default): a minute teaches two rows, its weekday's (as
//!   weekly) and its day type's — workday or rest day (the configured rest days and
//!   holidays) — which learns from every day of that type and so converges in days.
//!   The forecast blends them: the weekday row weighs `n / (n + K)`, `n` the weeks
//!   it has learned (at most its EMA's length `1 / (1 − α)`), `K` =
//!   `cascade.weekday_prior_weeks`; the day type's row the rest. A holiday teaches
//!   and is forecast from the rest-day row alone.
//!
//! F_L2 is a bias-corrected EMA of the minute's mean per block, with its variance:
//! [`f_l2`] with the weight [`warmup_weight`].

use std::borrow::Cow;

use isochron_config::CascadeConfig;
use isochron_config::clock::{Cycle, MINUTES_PER_DAY, MINUTES_PER_WEEK};
use jiff::civil::Date;

use crate::Bin;

/// The weight of a new sample in a bias-corrected EMA that has seen `n` samples:
/// `max(1 − α, 1/(n+1))`. The first sample gets weight 1, the first few are averaged
/// equally, and from `n ≈ 1/(1−α)` on the filter is the plain EMA.
pub fn warmup_weight(one_minus_alpha: f64, n: u64) -> f64 {
    one_minus_alpha.max(1.0 / (n as f64 + 1.0))
}

/// F_L2 on one block: updates the long-term `mean` and `var` with the minute mean
/// `x` at weight `w` (use [`warmup_weight`] with `1 − α_L2` and the row's count):
/// West's incremental EMA of mean and variance.
pub fn f_l2(mean: &mut f32, var: &mut f32, x: f32, w: f32) {
    let d = x - *mean;
    let inc = w * d;
    *mean += inc;
    *var = ((1.0 - w) * (*var + d * inc)).max(0.0);
}

/// α of an EMA with 10 %-decay duration `t` samples: `0.1^(1/t)`.
fn alpha(t: f64) -> f64 {
    if t.is_finite() && t > 0.0 {
        0.1f64.powf(1.0 / t)
    } else {
        0.0
    }
}

/// The rows of the store one local minute teaches and is forecast from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Rows {
    /// t*: the minute of the cycle (what the activity header and consumers name).
    pub t_star: u32,
    /// The cycle's own row (the weekday's with day types); none on a holiday.
    pub cycle: Option<u32>,
    /// The day type's row (day types only).
    pub day_type: Option<u32>,
}

impl Rows {
    /// The rows, cycle's first.
    pub fn iter(&self) -> impl Iterator<Item = u32> + use<> {
        self.cycle.into_iter().chain(self.day_type)
    }
}

/// The day types of the `day_types` cycle, in the order of their rows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DayType {
    /// A day that is not a rest day.
    Workday,
    /// A configured rest day or holiday.
    RestDay,
}

impl DayType {
    /// Both, in row order.
    pub const ALL: [DayType; 2] = [DayType::Workday, DayType::RestDay];

    /// The name people read.
    pub fn name(self) -> &'static str {
        match self {
            DayType::Workday => "workday",
            DayType::RestDay => "rest day",
        }
    }

    /// Its first row in a `day_types` store.
    pub fn first_row(self) -> u32 {
        MINUTES_PER_WEEK + self as u32 * MINUTES_PER_DAY
    }
}

/// How a site's long-term model learns and forecasts (from `[cascade]`).
#[derive(Debug, Clone, PartialEq)]
pub struct Rules {
    cycle: Cycle,
    /// `1 − α` of the cycle's rows (daily, weekly) and of the day-type rows.
    one_minus_alpha: f64,
    /// `1 − α` of the weekday rows of day types.
    one_minus_alpha_weekday: f64,
    weekday_prior: f64,
    rest: [bool; 7],
    holidays: Vec<Date>,
}

impl Rules {
    /// The rules of a site's `[cascade]` (validated: invalid rest days or holidays
    /// are left out).
    pub fn of(c: &CascadeConfig) -> Rules {
        Rules {
            cycle: c.cycle,
            one_minus_alpha: 1.0 - alpha(c.t_l2_days),
            one_minus_alpha_weekday: 1.0 - alpha(c.t_l2_weeks),
            weekday_prior: c.weekday_prior_weeks.max(0.0),
            rest: c
                .rest_day_flags()
                .unwrap_or([false, false, false, false, false, true, true]),
            holidays: c.holiday_dates().unwrap_or_default(),
        }
    }

    /// The default rules of `cycle`.
    pub fn defaults(cycle: Cycle) -> Rules {
        Rules::of(&CascadeConfig {
            cycle,
            ..CascadeConfig::default()
        })
    }

    /// The cycle.
    pub fn cycle(&self) -> Cycle {
        self.cycle
    }

    /// The day type of a local date.
    pub fn day_type(&self, date: Date) -> DayType {
        let weekday = date.weekday().to_monday_zero_offset() as usize;
        if self.rest[weekday] || self.holidays.binary_search(&date).is_ok() {
            DayType::RestDay
        } else {
            DayType::Workday
        }
    }

    /// The day type of a weekday (0 = Monday), holidays aside.
    pub fn weekday_type(&self, weekday: u32) -> DayType {
        if self.rest[(weekday % 7) as usize] {
            DayType::RestDay
        } else {
            DayType::Workday
        }
    }

    /// The rows of `minute_of_day` on the local `date`.
    pub fn rows(&self, date: Date, minute_of_day: u32) -> Rows {
        let minute = minute_of_day % MINUTES_PER_DAY;
        let weekday = date.weekday().to_monday_zero_offset() as u32;
        match self.cycle {
            Cycle::Daily => Rows {
                t_star: minute,
                cycle: Some(minute),
                day_type: None,
            },
            Cycle::Weekly => {
                let t = weekday * MINUTES_PER_DAY + minute;
                Rows {
                    t_star: t,
                    cycle: Some(t),
                    day_type: None,
                }
            }
            Cycle::DayTypes => {
                let t = weekday * MINUTES_PER_DAY + minute;
                let holiday = self.holidays.binary_search(&date).is_ok();
                Rows {
                    t_star: t,
                    cycle: (!holiday).then_some(t),
                    day_type: Some(self.day_type(date).first_row() + minute),
                }
            }
        }
    }

    /// The rows of minute `t_star` of the cycle on a day that is no holiday.
    pub fn rows_of_t_star(&self, t_star: u32) -> Rows {
        let t = t_star % self.cycle.bins();
        let minute = t % MINUTES_PER_DAY;
        Rows {
            t_star: t,
            cycle: Some(t),
            day_type: (self.cycle == Cycle::DayTypes)
                .then(|| self.weekday_type(t / MINUTES_PER_DAY).first_row() + minute),
        }
    }

    /// `1 − α` of `row`.
    fn one_minus_alpha_of(&self, row: u32) -> f64 {
        if self.cycle == Cycle::DayTypes && row < MINUTES_PER_WEEK {
            self.one_minus_alpha_weekday
        } else {
            self.one_minus_alpha
        }
    }

    /// Teaches `row` (a bin of this cycle's store) the minute means `x`, one per
    /// block, of absolute minute `minute` (minutes since the Unix epoch).
    pub fn learn(&self, row: &mut Bin, x: &[f32], minute: i64) {
        let w = warmup_weight(self.one_minus_alpha_of(row.t_star), row.count as u64) as f32;
        for ((mean, var), &x) in row.mean.iter_mut().zip(row.var.iter_mut()).zip(x) {
            f_l2(mean, var, x, w);
        }
        row.count = row.count.saturating_add(1);
        row.last_minute = minute;
    }

    /// The forecast of `rows` from the rows' bins as the store holds them (`None`
    /// or a count of 0: never taught): a bin at `rows.t_star` whose count is the days
    /// (weeks) behind it. `None` when nothing has been learned.
    pub fn forecast<'a>(
        &self,
        rows: Rows,
        cycle: Option<&'a Bin>,
        day_type: Option<&'a Bin>,
    ) -> Option<Cow<'a, Bin>> {
        let taught = |b: Option<&'a Bin>| b.filter(|b| b.count > 0);
        let at = |mut b: Bin| {
            b.t_star = rows.t_star;
            Cow::Owned(b)
        };
        match (taught(cycle), taught(day_type)) {
            (None, None) => None,
            (Some(c), None) if c.t_star == rows.t_star => Some(Cow::Borrowed(c)),
            (Some(only), None) | (None, Some(only)) => Some(at(only.clone())),
            (Some(c), Some(d)) => {
                let n = (c.count as f64).min(1.0 / self.one_minus_alpha_weekday.max(1e-9));
                let w = if self.weekday_prior > 0.0 {
                    n / (n + self.weekday_prior)
                } else {
                    1.0
                };
                Some(at(mix(&[(c, w), (d, 1.0 - w)], d.count.max(c.count))))
            }
        }
    }
}

/// The mixture of `parts` (bin, weight; weights summing to 1): per block the
/// weighted mean, and the variance of the mixture (within plus between).
pub fn mix(parts: &[(&Bin, f64)], count: u32) -> Bin {
    let blocks = parts.first().map_or(0, |(b, _)| b.mean.len());
    let mut out = Bin::empty(parts.first().map_or(0, |(b, _)| b.t_star), blocks);
    let total: f64 = parts.iter().map(|(_, w)| w).sum();
    if total <= 0.0 {
        return out;
    }
    for k in 0..blocks {
        let mean: f64 = parts.iter().map(|(b, w)| w * b.mean[k] as f64).sum::<f64>() / total;
        let var: f64 = parts
            .iter()
            .map(|(b, w)| {
                let d = b.mean[k] as f64 - mean;
                w * (b.var[k] as f64 + d * d)
            })
            .sum::<f64>()
            / total;
        out.mean[k] = mean as f32;
        out.var[k] = var as f32;
    }
    out.count = count;
    out.last_minute = parts
        .iter()
        .map(|(b, _)| b.last_minute)
        .max()
        .unwrap_or(i64::MIN);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bin(t: u32, count: u32, mean: f32, var: f32) -> Bin {
        Bin {
            t_star: t,
            count,
            last_minute: 0,
            mean: vec![mean],
            var: vec![var],
        }
    }

    #[test]
    fn day_types_teach_the_weekday_and_its_type() {
        let rules = Rules::defaults(Cycle::DayTypes);
        let monday = jiff::civil::date(2026, 3, 2);
        let rows = rules.rows(monday, 7 * 60);
        assert_eq!(rows.t_star, 420);
        assert_eq!(rows.cycle, Some(420));
        assert_eq!(rows.day_type, Some(MINUTES_PER_WEEK + 420));
        let sunday = jiff::civil::date(2026, 3, 8);
        let rows = rules.rows(sunday, 0);
        assert_eq!(rows.cycle, Some(6 * MINUTES_PER_DAY));
        assert_eq!(rows.day_type, Some(MINUTES_PER_WEEK + MINUTES_PER_DAY));
        assert_eq!(rules.rows_of_t_star(6 * MINUTES_PER_DAY), rows);
    }

    #[test]
    fn a_holiday_is_a_rest_day_that_teaches_its_weekday_nothing() {
        let config = CascadeConfig {
            holidays: vec!["2026-12-25".into()],
            ..CascadeConfig::default()
        };
        let rules = Rules::of(&config);
        let friday = jiff::civil::date(2026, 12, 25);
        let rows = rules.rows(friday, 60);
        assert_eq!(rows.cycle, None);
        assert_eq!(rows.day_type, Some(DayType::RestDay.first_row() + 60));
        assert_eq!(rows.iter().count(), 1);
    }

    #[test]
    fn the_forecast_leans_on_the_weekday_as_its_weeks_accumulate() {
        let rules = Rules::defaults(Cycle::DayTypes);
        let rows = rules.rows_of_t_star(420);
        let day = bin(MINUTES_PER_WEEK + 420, 10, 1.0, 0.0);
        let f = |n| {
            let weekday = bin(420, n, 3.0, 0.0);
            rules
                .forecast(rows, Some(&weekday), Some(&day))
                .map(|b| b.mean[0])
                .unwrap()
        };
        // K = 2: one week weighs 1/3, two weeks 1/2; capped at the EMA's length.
        assert!((f(1) - (1.0 + 2.0 / 3.0)).abs() < 1e-5);
        assert!((f(2) - 2.0).abs() < 1e-5);
        assert_eq!(f(50), f(100));
        let only_day = rules.forecast(rows, None, Some(&day)).unwrap();
        assert_eq!((only_day.t_star, only_day.mean[0]), (420, 1.0));
        assert!(rules.forecast(rows, None, None).is_none());
    }

    #[test]
    fn a_mixture_has_the_spread_between_its_parts() {
        let a = bin(0, 1, 0.0, 1.0);
        let b = bin(0, 1, 2.0, 1.0);
        let m = mix(&[(&a, 0.5), (&b, 0.5)], 2);
        assert_eq!((m.mean[0], m.var[0], m.count), (1.0, 2.0, 2));
    }

    #[test]
    fn f_l2_is_mean_and_population_variance_during_warm_up() {
        let (mut mean, mut var) = (0.0f32, 0.0f32);
        for (n, x) in [1.0f32, 3.0, 5.0].into_iter().enumerate() {
            f_l2(&mut mean, &mut var, x, warmup_weight(0.2, n as u64) as f32);
        }
        assert!((mean - 3.0).abs() < 1e-6);
        assert!((var - 8.0 / 3.0).abs() < 1e-5);
    }
}
