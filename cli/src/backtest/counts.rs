//! The count series a backtest reads: a CSV file with a header
//! `time,<series>,<series>...`, one row per interval, `time` as `YYYY-MM-DDTHH:MM` in
//! the site's local time (or RFC 3339 with an offset, turned into local time), the
//! values counts per interval (empty: missing). The interval is fixed, 1 to 60
//! minutes, and divides the hour or is the hour; rows may come in any order, and a
//! local time that appears twice (the hour a DST change repeats) adds to the first.

use std::path::Path;

use anyhow::{Context, bail};
use jiff::civil::{Date, DateTime};
use jiff::tz::TimeZone;

/// Count series on a common calendar.
#[derive(Debug, Clone, PartialEq)]
pub struct Counts {
    /// Series names, in the file's order.
    pub names: Vec<String>,
    /// The first day.
    pub first: Date,
    /// Minutes per interval.
    pub interval: u32,
    /// Per series, per day from `first`, per interval of the day: the count.
    pub values: Vec<Vec<Vec<Option<f64>>>>,
    /// Rows the file had.
    pub rows: usize,
}

/// Days of counts a backtest needs: a scored day and the same weekday a week
/// before it, from which the baselines forecast it.
pub const MIN_DAYS: usize = 8;

/// Fails, saying how many rows are needed, when `counts` (read from `path`)
/// span fewer than [`MIN_DAYS`] days: nothing could be scored.
pub fn long_enough(counts: &Counts, path: &Path) -> anyhow::Result<()> {
    let days = counts.days();
    if days >= MIN_DAYS {
        return Ok(());
    }
    bail!(
        "--counts {}: {} rows over {days} day{}; a backtest needs at least {MIN_DAYS} days of counts (each scored day is forecast from the same weekday a week before): at one row per {} minutes, at least {} rows",
        path.display(),
        counts.rows,
        if days == 1 { "" } else { "s" },
        counts.interval,
        MIN_DAYS * counts.slots()
    )
}

impl Counts {
    /// Intervals per day.
    pub fn slots(&self) -> usize {
        (1440 / self.interval) as usize
    }

    /// Days covered.
    pub fn days(&self) -> usize {
        self.values.first().map_or(0, Vec::len)
    }

    /// The date of day `d`.
    pub fn date(&self, d: usize) -> Date {
        self.first
            .checked_add(jiff::Span::new().days(d as i64))
            .unwrap_or(self.first)
    }

    /// The index of `date` (may be out of range).
    pub fn day_of(&self, date: Date) -> i64 {
        date.since(self.first)
            .map(|s| s.get_days() as i64)
            .unwrap_or(0)
    }

    /// Only the series named in `keep` (each must exist).
    pub fn only(mut self, keep: &[String]) -> anyhow::Result<Counts> {
        let mut values = Vec::new();
        for name in keep {
            let Some(i) = self.names.iter().position(|n| n == name) else {
                bail!(
                    "--series: no series '{name}' in the file (it has {})",
                    self.names.join(", ")
                );
            };
            values.push(std::mem::take(&mut self.values[i]));
        }
        self.names = keep.to_vec();
        self.values = values;
        Ok(self)
    }
}

/// Reads `path`; `tz` turns RFC 3339 times into local time.
pub fn read(path: &Path, tz: &TimeZone) -> anyhow::Result<Counts> {
    let shown = path.display();
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(true)
        .from_path(path)
        .with_context(|| format!("--counts {shown}: cannot read"))?;
    let header = reader
        .headers()
        .with_context(|| format!("{shown}: line 1: expected a header `time,<series>,...`"))?
        .clone();
    if header.get(0).map(str::trim) != Some("time") || header.len() < 2 {
        bail!(
            "{shown}: line 1: expected a header `time,<series>,...`, found `{}`",
            header.iter().collect::<Vec<_>>().join(",")
        );
    }
    let names: Vec<String> = header
        .iter()
        .skip(1)
        .map(|s| s.trim().to_string())
        .collect();
    let mut rows: Vec<(DateTime, Vec<Option<f64>>)> = Vec::new();
    for (i, record) in reader.records().enumerate() {
        let line = i + 2;
        let record = record.with_context(|| format!("{shown}: line {line}"))?;
        let time = record.get(0).unwrap_or("").trim();
        let at = parse_time(time, tz)
            .with_context(|| format!("{shown}: line {line}: column `time`: expected YYYY-MM-DDTHH:MM or an RFC 3339 time, found '{time}'"))?;
        if record.len() != names.len() + 1 {
            bail!(
                "{shown}: line {line}: {} values, the header names {} series",
                record.len().saturating_sub(1),
                names.len()
            );
        }
        let mut values = Vec::with_capacity(names.len());
        for (k, field) in record.iter().skip(1).enumerate() {
            let field = field.trim();
            if field.is_empty() {
                values.push(None);
                continue;
            }
            match field.parse::<f64>() {
                Ok(v) if v.is_finite() && v >= 0.0 => values.push(Some(v)),
                _ => bail!(
                    "{shown}: line {line}: series '{}': expected a count (a number ≥ 0, or empty for missing), found '{field}'",
                    names[k]
                ),
            }
        }
        rows.push((at, values));
    }
    if rows.len() < 2 {
        bail!(
            "{shown}: {} row{}; a backtest needs at least {MIN_DAYS} days of counts (at one row per hour, at least {} rows)",
            rows.len(),
            if rows.len() == 1 { "" } else { "s" },
            MIN_DAYS * 24
        );
    }
    let interval = interval_of(&rows).with_context(|| format!("{shown}"))?;
    let count = rows.len();
    let mut counts = on_calendar(names, rows, interval, &shown.to_string())?;
    counts.rows = count;
    Ok(counts)
}

/// A `YYYY-MM-DDTHH:MM[:SS]` local time, or an RFC 3339 time in `tz`.
fn parse_time(text: &str, tz: &TimeZone) -> anyhow::Result<DateTime> {
    if let Ok(ts) = text.parse::<jiff::Timestamp>() {
        return Ok(ts.to_zoned(tz.clone()).datetime());
    }
    Ok(text.parse::<DateTime>()?)
}

/// The interval: the most common step between consecutive distinct times.
fn interval_of(rows: &[(DateTime, Vec<Option<f64>>)]) -> anyhow::Result<u32> {
    let mut times: Vec<DateTime> = rows.iter().map(|(t, _)| *t).collect();
    times.sort_unstable();
    times.dedup();
    let mut steps = std::collections::BTreeMap::<i64, usize>::new();
    for pair in times.windows(2) {
        let minutes = pair[1].duration_since(pair[0]).as_secs().div_euclid(60);
        if minutes > 0 {
            *steps.entry(minutes).or_default() += 1;
        }
    }
    // The most common step; of equally common ones, the shortest.
    let Some((&step, _)) = steps
        .iter()
        .max_by_key(|(step, n)| (**n, std::cmp::Reverse(**step)))
    else {
        bail!("every row has the same time");
    };
    if !(1..=60).contains(&step) || 60 % step != 0 {
        bail!(
            "the rows are {step} minutes apart; expected a fixed interval of 1 to 60 minutes that divides the hour"
        );
    }
    Ok(step as u32)
}

fn on_calendar(
    names: Vec<String>,
    rows: Vec<(DateTime, Vec<Option<f64>>)>,
    interval: u32,
    shown: &str,
) -> anyhow::Result<Counts> {
    let first = rows
        .iter()
        .map(|(t, _)| t.date())
        .min()
        .unwrap_or(rows[0].0.date());
    let last = rows.iter().map(|(t, _)| t.date()).max().unwrap_or(first);
    let days = last
        .since(first)
        .map(|s| s.get_days() as usize)
        .unwrap_or(0)
        + 1;
    let slots = (1440 / interval) as usize;
    let mut values = vec![vec![vec![None; slots]; days]; names.len()];
    for (i, (at, row)) in rows.into_iter().enumerate() {
        let day = at.date().since(first).map(|s| s.get_days()).unwrap_or(-1);
        if day < 0 {
            bail!(
                "{shown}: line {}: time {at} comes before the first row",
                i + 2
            );
        }
        let minute = at.hour() as u32 * 60 + at.minute() as u32;
        let slot = (minute / interval) as usize;
        for (s, v) in row.into_iter().enumerate() {
            if let Some(v) = v {
                let cell = &mut values[s][day as usize][slot];
                *cell = Some(cell.unwrap_or(0.0) + v);
            }
        }
    }
    Ok(Counts {
        names,
        first,
        interval,
        values,
        rows: 0,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(text: &str) -> (tempfile::TempDir, std::path::PathBuf) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("counts.csv");
        std::fs::write(&path, text).unwrap();
        (dir, path)
    }

    #[test]
    fn hourly_counts_land_on_their_day_and_hour() {
        let (_d, path) = write(
            "time,a,b\n2026-03-02T06:00,1,\n2026-03-02T07:00,2,5\n2026-03-03T06:00,3,4\n2026-03-03T06:00,1,\n",
        );
        let c = read(&path, &TimeZone::UTC).unwrap();
        assert_eq!((c.interval, c.slots(), c.days()), (60, 24, 2));
        assert_eq!(c.values[0][0][6], Some(1.0));
        assert_eq!(c.values[1][0][6], None);
        // A repeated local hour adds to the first.
        assert_eq!(c.values[0][1][6], Some(4.0));
    }

    #[test]
    fn fewer_than_eight_days_are_too_short_and_say_how_many_rows() {
        let (_d, path) = write("time,a\n2026-03-02T06:00,1\n2026-03-02T07:00,2\n");
        let c = read(&path, &TimeZone::UTC).unwrap();
        assert_eq!(c.rows, 2);
        let e = format!("{:#}", long_enough(&c, &path).unwrap_err());
        assert!(
            e.contains("2 rows over 1 day;") && e.contains("at least 192 rows"),
            "{e}"
        );
        let (_d, path) =
            write("time,a\n2026-03-02T06:00,1\n2026-03-09T06:00,2\n2026-03-09T07:00,2\n");
        let c = read(&path, &TimeZone::UTC).unwrap();
        assert!(long_enough(&c, &path).is_ok());
    }

    #[test]
    fn bad_input_names_the_line_and_what_was_expected() {
        let (_d, path) = write("time,a\n2026-03-02T06:00,1\n2026-03-02T07:00,-3\n");
        let e = format!("{:#}", read(&path, &TimeZone::UTC).unwrap_err());
        assert!(e.contains("line 3") && e.contains("'-3'"), "{e}");
        let (_d, path) = write("time,a\nyesterday,1\n2026-03-02T07:00,1\n");
        let e = format!("{:#}", read(&path, &TimeZone::UTC).unwrap_err());
        assert!(
            e.contains("line 2") && e.contains("YYYY-MM-DDTHH:MM"),
            "{e}"
        );
        let (_d, path) = write("when,a\n2026-03-02T06:00,1\n");
        let e = format!("{:#}", read(&path, &TimeZone::UTC).unwrap_err());
        assert!(e.contains("line 1"), "{e}");
        let (_d, path) = write("time,a\n2026-03-02T06:00,1\n2026-03-02T06:07,1\n");
        let e = format!("{:#}", read(&path, &TimeZone::UTC).unwrap_err());
        assert!(e.contains("7 minutes"), "{e}");
    }
}
