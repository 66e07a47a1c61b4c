//! One day of activity, per minute: a long-term profile of any cycle folded onto a
//! day, its running means and its quiet times — what `isochron plot daily` and
//! `isochron plot heatmap` draw.

use isochron_config::clock::Cycle;
use isochron_config::clock::MINUTES_PER_DAY;
use isochron_planning::profile::ProfilePoint;
use isochron_store::Rules;
use isochron_store::isochronal::DayType;

/// Which days of a model of the week a plot shows (`--day`): all of them folded
/// onto one day, one weekday, or the weekdays of one day type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DayFilter {
    /// Every day, folded (weighted by the days that taught each minute).
    All,
    /// One weekday, 0 = Monday.
    Weekday(u32),
    /// The weekdays of a day type (the site's rest days, default Saturday and Sunday).
    Type(DayType),
}

impl DayFilter {
    /// Parses `--day`: `mon` .. `sun`, `workday` or `rest` (clap's value parser
    /// of the flag).
    pub fn arg(text: &str) -> Result<DayFilter, String> {
        if let Ok(d) = crate::values::weekday(text) {
            return Ok(DayFilter::Weekday(d));
        }
        match text.trim().to_ascii_lowercase().as_str() {
            "workday" | "workdays" => Ok(DayFilter::Type(DayType::Workday)),
            "rest" | "rest-day" | "rest_day" | "weekend" => Ok(DayFilter::Type(DayType::RestDay)),
            _ => Err("expected mon .. sun, workday or rest".into()),
        }
    }

    /// Whether the profile point at minute `t_star` of `cycle` is shown (a daily
    /// model has one day: every filter shows it).
    pub fn keeps(&self, t_star: u32, cycle: Cycle, rules: &Rules) -> bool {
        let day = t_star / MINUTES_PER_DAY;
        match (*self, cycle) {
            (DayFilter::All, _) | (_, Cycle::Daily) => true,
            (DayFilter::Weekday(d), _) => day == d,
            (DayFilter::Type(kind), _) => rules.weekday_type(day) == kind,
        }
    }

    /// For a title: ", Mondays", ", workdays", or how a week is folded.
    pub fn describe(&self, cycle: Cycle) -> &'static str {
        match (*self, cycle) {
            (_, Cycle::Daily) => "",
            (DayFilter::All, _) => ", week folded onto a day",
            (DayFilter::Weekday(d), _) => [
                ", Mondays",
                ", Tuesdays",
                ", Wednesdays",
                ", Thursdays",
                ", Fridays",
                ", Saturdays",
                ", Sundays",
            ][d as usize % 7],
            (DayFilter::Type(DayType::Workday), _) => ", workdays",
            (DayFilter::Type(DayType::RestDay), _) => ", rest days",
        }
    }

    /// The points of `points` this filter shows.
    pub fn select(
        &self,
        points: &[ProfilePoint],
        cycle: Cycle,
        rules: &Rules,
    ) -> Vec<ProfilePoint> {
        points
            .iter()
            .filter(|p| self.keeps(p.t_star, cycle, rules))
            .cloned()
            .collect()
    }
}

/// One day of activity, per minute: what the plot draws.
#[derive(Debug, Clone)]
pub struct Daily {
    /// Mean per minute of the day (`None`: never learned).
    pub mean: Vec<Option<f64>>,
    /// Sigma per minute of the day.
    pub sigma: Vec<Option<f64>>,
    /// Most days any minute learned from.
    pub days: u32,
}

impl Daily {
    /// Folds a profile of any cycle onto one day.
    pub fn from_profile(points: &[ProfilePoint]) -> Daily {
        let n = MINUTES_PER_DAY as usize;
        let mut sum = vec![0.0; n];
        let mut sum_var = vec![0.0; n];
        let mut weight = vec![0u64; n];
        let mut days = 0;
        for p in points {
            if let (Some(m), Some(s)) = (p.mean, p.sigma) {
                let i = (p.t_star % MINUTES_PER_DAY) as usize;
                sum[i] += m * p.count as f64;
                sum_var[i] += s * s * p.count as f64;
                weight[i] += p.count as u64;
                days = days.max(p.count);
            }
        }
        let per = |s: &[f64]| -> Vec<Option<f64>> {
            (0..n)
                .map(|i| (weight[i] > 0).then(|| s[i] / weight[i] as f64))
                .collect()
        };
        Daily {
            mean: per(&sum),
            sigma: per(&sum_var)
                .into_iter()
                .map(|v| v.map(f64::sqrt))
                .collect(),
            days,
        }
    }

    /// Running mean of the means over `window` minutes (centred), over learned
    /// minutes only.
    pub fn smoothed(&self, window: usize) -> Vec<Option<f64>> {
        running_mean(&self.mean, window)
    }

    /// Up to `max` quiet times of the working day `[start, end)` (minutes): the lowest
    /// local minima of the 30-minute running mean, at least 90 minutes apart, inside
    /// the busy part of the day (where the activity is at least 10 % of its peak).
    pub fn quiet_times(&self, start: u32, end: u32, max: usize) -> Vec<u32> {
        let smooth = self.smoothed(31);
        let peak = smooth.iter().flatten().cloned().fold(0.0, f64::max);
        if peak <= 0.0 {
            return Vec::new();
        }
        let busy: Vec<u32> = (start..end.min(MINUTES_PER_DAY))
            .filter(|&m| smooth[m as usize].is_some_and(|v| v >= 0.1 * peak))
            .collect();
        let (Some(&first), Some(&last)) = (busy.first(), busy.last()) else {
            return Vec::new();
        };
        let value = |m: u32| smooth[m as usize];
        let mut minima: Vec<(f64, u32)> = (first + 30..last.saturating_sub(30))
            .filter_map(|m| {
                let v = value(m)?;
                let around = (m - 30..=m + 30).filter_map(value);
                around
                    .clone()
                    .all(|u| v <= u)
                    .then_some((v, m))
                    .filter(|_| around.fold(0.0, f64::max) > v * 1.05)
            })
            .collect();
        minima.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut chosen: Vec<u32> = Vec::new();
        for (_, m) in minima {
            if chosen.iter().all(|&c| c.abs_diff(m) >= 90) {
                chosen.push(m);
            }
            if chosen.len() == max {
                break;
            }
        }
        chosen.sort_unstable();
        chosen
    }
}

/// Running mean over `window` minutes (centred, around midnight too) of the present
/// values; `None` where the value itself is absent.
pub(crate) fn running_mean(values: &[Option<f64>], window: usize) -> Vec<Option<f64>> {
    let n = values.len() as isize;
    let half = (window / 2) as isize;
    (0..n)
        .map(|i| {
            let (mut s, mut c) = (0.0, 0);
            for j in i - half..=i + half {
                if let Some(v) = values[j.rem_euclid(n) as usize] {
                    s += v;
                    c += 1;
                }
            }
            (c > 0 && values[i as usize].is_some()).then(|| s / c as f64)
        })
        .collect()
}

/// Runs of consecutive learned minutes, as index ranges.
pub(crate) fn runs(values: &[Option<f64>]) -> Vec<std::ops::Range<usize>> {
    let mut out = Vec::new();
    let mut start = None;
    for (i, v) in values.iter().enumerate() {
        match (v.is_some(), start) {
            (true, None) => start = Some(i),
            (false, Some(s)) => {
                out.push(s..i);
                start = None;
            }
            _ => {}
        }
    }
    if let Some(s) = start {
        out.push(s..values.len());
    }
    out
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    #[test]
    fn a_day_filter_picks_a_weekday_or_the_days_of_a_type() {
        let rules = Rules::defaults(Cycle::DayTypes);
        let points: Vec<ProfilePoint> = (0..7 * MINUTES_PER_DAY)
            .map(|t| ProfilePoint {
                t_star: t,
                mean: Some(f64::from(t / MINUTES_PER_DAY)),
                sigma: Some(0.0),
                count: 1,
            })
            .collect();
        let tuesday = DayFilter::arg("Tue").unwrap();
        let picked = tuesday.select(&points, Cycle::DayTypes, &rules);
        assert_eq!(picked.len(), 1440);
        assert_eq!(Daily::from_profile(&picked).mean[0], Some(1.0));
        let rest = DayFilter::arg("rest").unwrap();
        // Saturday (5) and Sunday (6), folded.
        let daily = Daily::from_profile(&rest.select(&points, Cycle::DayTypes, &rules));
        assert_eq!(daily.mean[0], Some(5.5));
        assert_eq!(rest.describe(Cycle::DayTypes), ", rest days");
        // A daily model has one day: every filter shows it.
        assert_eq!(
            tuesday.select(&points[..1440], Cycle::Daily, &rules).len(),
            1440
        );
        assert!(DayFilter::arg("someday").is_err());
    }

    /// An office day: busy 08:00–12:00 and 13:30–17:00, a lull at 12:45.
    pub(crate) fn office() -> Daily {
        // Busy 08:00-12:00 and 13:30-17:00, a lull at 12:45, nothing at night.
        let mean: Vec<Option<f64>> = (0..1440)
            .map(|m| {
                let h = m as f64 / 60.0;
                let v = if (8.0..12.0).contains(&h) || (13.5..17.0).contains(&h) {
                    1.0
                } else if (12.0..13.5).contains(&h) {
                    0.3 + 0.7 * ((h - 12.75).abs() / 0.75)
                } else if (7.0..8.0).contains(&h) || (17.0..19.0).contains(&h) {
                    0.2
                } else {
                    0.0
                };
                Some(v)
            })
            .collect();
        Daily {
            sigma: vec![Some(0.1); 1440],
            mean,
            days: 14,
        }
    }

    #[test]
    fn quiet_times_find_the_lunch_lull() {
        let q = office().quiet_times(6 * 60, 21 * 60, 3);
        assert!(q.iter().any(|&m| (755..=775).contains(&m)), "{q:?}");
        assert!(q.iter().all(|&m| (7 * 60..19 * 60).contains(&m)), "{q:?}");
        let empty = Daily {
            mean: vec![None; 1440],
            sigma: vec![None; 1440],
            days: 0,
        };
        assert!(empty.quiet_times(0, 1440, 3).is_empty());
    }

    #[test]
    fn weekly_profiles_fold_onto_a_day_weighted_by_count() {
        let points = vec![
            ProfilePoint {
                t_star: 10,
                mean: Some(1.0),
                sigma: Some(0.0),
                count: 3,
            },
            ProfilePoint {
                t_star: 1440 + 10,
                mean: Some(2.0),
                sigma: Some(0.0),
                count: 1,
            },
        ];
        let d = Daily::from_profile(&points);
        assert_eq!(d.mean[10], Some(1.25));
        assert_eq!(d.mean[11], None);
        assert_eq!(d.days, 3);
        assert_eq!(runs(&d.mean), vec![10..11]);
    }
}
