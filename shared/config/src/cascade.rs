//! `[cascade]`: the cascade of temporal filters and the long-term model.

use serde::{Deserialize, Serialize};

use super::{Invalid, check_positive, check_range};

/// `[cascade]`: the cascade of temporal filters (docs/ARCHITECTURE.md, "Filters"). Filters are
/// configured by their 10 %-decay duration T and rate r; α = 0.1^(1/(r·T)).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CascadeConfig {
    /// T of F_L1, the high-pass at frame rate, seconds. Default 1800 (30 min).
    pub t_l1_s: f64,
    /// T of F_L2, the isochronal low-pass, in samples of a bin: days for the
    /// daily cycle and the day-type profiles, weeks for the weekly cycle. Default 10.
    pub t_l2_days: f64,
    /// T of F_L2 for the weekday profiles of the `"day_types"` cycle, in weeks.
    /// Default 5.
    pub t_l2_weeks: f64,
    /// With `"day_types"`: how many weeks of a weekday's own data weigh as much as
    /// its day type's profile in the forecast (weight of the weekday `n / (n + this)`,
    /// `n` its weeks, at most its EMA's length). Default 2.
    pub weekday_prior_weeks: f64,
    /// With `"day_types"`: the site's rest days (`"mon"` .. `"sun"`); the other days
    /// are workdays. Default `["sat", "sun"]`.
    pub rest_days: Vec<String>,
    /// With `"day_types"`: the site's holidays, `"YYYY-MM-DD"` in local time. A
    /// holiday learns and is forecast as a rest day, and teaches its weekday
    /// nothing. Default none.
    pub holidays: Vec<String>,
    /// T of F_S1, the in-place low-pass at 1 Hz, seconds. Default 20.
    pub t_s1_s: f64,
    /// Frame rate r for F_L1 (frames/s); default: measured from header timestamps.
    pub frame_rate: Option<f64>,
    /// Isochronal cycle: `"day_types"` (default: workdays and rest days that learn
    /// in days, refined per weekday as weeks accumulate), `"daily"` (the paper's:
    /// every day alike) or `"weekly"` (each weekday alone).
    pub cycle: crate::clock::Cycle,
    /// A minute updates F_L2 only if it got at least this fraction of the frames
    /// expected at rate r (gaps teach nothing). Default 0.8.
    pub min_coverage: f64,
    /// Days of data a minute bin needs before the long-term model counts as warm.
    /// Default 3.
    pub warm_days: u32,
}

impl Default for CascadeConfig {
    fn default() -> Self {
        CascadeConfig {
            t_l1_s: 1800.0,
            t_l2_days: 10.0,
            t_l2_weeks: 5.0,
            weekday_prior_weeks: 2.0,
            rest_days: vec!["sat".into(), "sun".into()],
            holidays: Vec::new(),
            t_s1_s: 20.0,
            frame_rate: None,
            cycle: crate::clock::Cycle::DayTypes,
            min_coverage: 0.8,
            warm_days: 3,
        }
    }
}

impl CascadeConfig {
    /// Checks the `cascade.*` keys.
    pub(super) fn validate(&self) -> Result<(), Invalid> {
        check_positive("cascade.t_l1_s", self.t_l1_s)?;
        check_positive("cascade.t_l2_days", self.t_l2_days)?;
        check_positive("cascade.t_l2_weeks", self.t_l2_weeks)?;
        check_range(
            "cascade.weekday_prior_weeks",
            self.weekday_prior_weeks,
            0.0,
            1000.0,
        )?;
        self.rest_day_flags()?;
        self.holiday_dates()?;
        check_positive("cascade.t_s1_s", self.t_s1_s)?;
        if let Some(r) = self.frame_rate {
            check_range("cascade.frame_rate", r, 0.01, 1000.0)?;
        }
        check_range("cascade.min_coverage", self.min_coverage, 0.0, 1.0)
    }

    /// `rest_days` as flags, Monday first.
    pub fn rest_day_flags(&self) -> Result<[bool; 7], Invalid> {
        let mut flags = [false; 7];
        for (i, day) in self.rest_days.iter().enumerate() {
            let Some(d) = DAY_NAMES.iter().position(|n| n.eq_ignore_ascii_case(day)) else {
                return Err(Invalid::found(
                    format!("cascade.rest_days[{i}]"),
                    "a day, one of \"mon\" .. \"sun\"",
                    day,
                ));
            };
            flags[d] = true;
        }
        if flags.iter().all(|&f| f) {
            return Err(Invalid::new(
                "cascade.rest_days",
                "expected at most six rest days: a week with no workday has no workday profile",
            ));
        }
        Ok(flags)
    }

    /// `holidays` as dates, sorted.
    pub fn holiday_dates(&self) -> Result<Vec<jiff::civil::Date>, Invalid> {
        let mut dates = self
            .holidays
            .iter()
            .enumerate()
            .map(|(i, s)| {
                s.parse::<jiff::civil::Date>().map_err(|_| {
                    Invalid::found(format!("cascade.holidays[{i}]"), "a date YYYY-MM-DD", s)
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        dates.sort();
        Ok(dates)
    }
}

/// Day names as `rest_days` spells them, Monday first.
pub const DAY_NAMES: [&str; 7] = ["mon", "tue", "wed", "thu", "fri", "sat", "sun"];
