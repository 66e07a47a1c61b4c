//! Scoring forecasts against the counts: NMAE over the scored hours and the
//! departure-pick regret over the pick window (module doc of `backtest`).

use anyhow::{Context, bail};
use serde_json::json;

use super::{Counts, Plan};

/// The scored hours and the pick window, inclusive.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Window {
    /// Scored hours.
    pub hours: (u32, u32),
    /// Hours a departure is picked from.
    pub pick: (u32, u32),
}

impl Window {
    /// Parses `--hours` and `--pick-hours` (`FROM-TO`, hours 0–23).
    pub fn parse(hours: &str, pick: &str) -> anyhow::Result<Window> {
        Ok(Window {
            hours: range("--hours", hours)?,
            pick: range("--pick-hours", pick)?,
        })
    }
}

fn range(flag: &str, text: &str) -> anyhow::Result<(u32, u32)> {
    let parsed = text
        .split_once('-')
        .and_then(|(a, b)| Some((a.trim().parse::<u32>().ok()?, b.trim().parse::<u32>().ok()?)))
        .with_context(|| format!("{flag}: expected FROM-TO hours (e.g. 6-21), found '{text}'"))?;
    if parsed.0 > parsed.1 || parsed.1 > 23 {
        bail!("{flag}: expected FROM-TO with 0 ≤ FROM ≤ TO ≤ 23, found '{text}'");
    }
    Ok(parsed)
}

/// One model's figures on one series (or their medians).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Score {
    /// `Σ|f − a| / Σ a`; NaN when nothing was scored.
    pub nmae: f64,
    /// Mean departure-pick regret; NaN when no day could be scored.
    pub regret: f64,
    /// Intervals scored.
    pub intervals: usize,
    /// Days whose pick was scored.
    pub days: usize,
}

impl Score {
    /// The median of each figure over `scores` (NaN ones left out).
    pub fn median<'a>(scores: impl Iterator<Item = &'a Score>) -> Score {
        let scores: Vec<&Score> = scores.collect();
        Score {
            nmae: median(scores.iter().map(|s| s.nmae)),
            regret: median(scores.iter().map(|s| s.regret)),
            intervals: scores.iter().map(|s| s.intervals).sum(),
            days: scores.iter().map(|s| s.days).sum(),
        }
    }

    /// `NMAE / regret` for the table.
    pub fn cell(&self) -> String {
        format!("{:.3} / {:.3}", self.nmae, self.regret)
    }

    /// `{"nmae", "regret"}` (null where not scored).
    pub fn json(&self) -> serde_json::Value {
        let num = |v: f64| v.is_finite().then_some(v);
        json!({"nmae": num(self.nmae), "regret": num(self.regret), "intervals": self.intervals, "days": self.days})
    }
}

fn median(values: impl Iterator<Item = f64>) -> f64 {
    let mut v: Vec<f64> = values.filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    }
}

/// Scores every model's `forecasts` (per model, per day, per interval) against
/// `series`, on the intervals every model forecasts.
pub fn score_all(
    counts: &Counts,
    series: &[Vec<Option<f64>>],
    forecasts: &[Vec<Vec<Option<f64>>>],
    plan: &Plan,
) -> Vec<Score> {
    let interval = counts.interval;
    let hour_of = |s: usize| s as u32 * interval / 60;
    let last = (plan.score_to.max(-1) + 1) as usize;
    let days: Vec<usize> = (plan.score_from..last.min(series.len())).collect();
    let common =
        |d: usize, s: usize| series[d][s].is_some() && forecasts.iter().all(|m| m[d][s].is_some());
    forecasts
        .iter()
        .map(|model| {
            let (mut err, mut sum, mut intervals) = (0.0, 0.0, 0usize);
            let mut regrets = Vec::new();
            for &d in &days {
                for s in 0..counts.slots() {
                    let h = hour_of(s);
                    if h < plan.window.hours.0 || h > plan.window.hours.1 || !common(d, s) {
                        continue;
                    }
                    let (f, a) = (model[d][s].unwrap_or(0.0), series[d][s].unwrap_or(0.0));
                    err += (f - a).abs();
                    sum += a;
                    intervals += 1;
                }
                regrets.extend(regret(counts, &series[d], &model[d], plan, |s| {
                    common(d, s)
                }));
            }
            Score {
                nmae: if sum > 0.0 { err / sum } else { f64::NAN },
                regret: if regrets.is_empty() {
                    f64::NAN
                } else {
                    regrets.iter().sum::<f64>() / regrets.len() as f64
                },
                intervals,
                days: regrets.len(),
            }
        })
        .collect()
}

/// The regret of one day's pick, if every hour of the pick window is known and
/// forecast (hourly sums of the intervals).
fn regret(
    counts: &Counts,
    actual: &[Option<f64>],
    forecast: &[Option<f64>],
    plan: &Plan,
    common: impl Fn(usize) -> bool,
) -> Option<f64> {
    let per_hour = (60 / counts.interval) as usize;
    let (from, to) = plan.window.pick;
    let mut hours = Vec::new();
    for h in from..=to {
        let slots = h as usize * per_hour..(h as usize + 1) * per_hour;
        if !slots.clone().all(&common) {
            return None;
        }
        let a: f64 = slots.clone().map(|s| actual[s].unwrap_or(0.0)).sum();
        let f: f64 = slots.map(|s| forecast[s].unwrap_or(0.0)).sum();
        hours.push((f, a));
    }
    let mean = hours.iter().map(|(_, a)| a).sum::<f64>() / hours.len() as f64;
    if mean <= 0.0 {
        return None;
    }
    let lowest = hours.iter().map(|(_, a)| *a).fold(f64::INFINITY, f64::min);
    let pick = hours
        .iter()
        .min_by(|x, y| x.0.total_cmp(&y.0))
        .map(|(_, a)| *a)?;
    Some((pick - lowest) / mean)
}
