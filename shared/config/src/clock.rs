//! Time: capture time (UTC nanoseconds) and isochronal time t*.
//!
//! Services never read the wall clock for filtering: chronological time t is a
//! frame's capture time from its header, and isochronal time t* is that instant's
//! minute of the day (or of the week) in the site's time zone. A recording replayed
//! faster than real time therefore builds the same model as the live camera would.

use jiff::tz::TimeZone;
use jiff::{Timestamp, Zoned};

/// Nanoseconds per second.
pub const NS_PER_S: i64 = 1_000_000_000;
/// Minutes in a day: the number of isochronal bins of the daily cycle.
pub const MINUTES_PER_DAY: u32 = 1440;
/// Minutes in a week: the number of isochronal bins of the weekly cycle.
pub const MINUTES_PER_WEEK: u32 = 7 * MINUTES_PER_DAY;

/// The isochronal cycle: how the long-term model divides time.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Cycle {
    /// 1440 minute bins; every day is alike (the paper's model).
    Daily,
    /// 7 × 1440 minute bins, Monday 00:00 first; each weekday learns alone.
    Weekly,
    /// A week, Monday 00:00 first, learned as day types — workdays and rest days
    /// (weekends, holidays), 1440 bins each, that converge in days — refined per
    /// weekday as weeks accumulate (`isochron_store::isochronal`).
    DayTypes,
}

impl Cycle {
    /// Number of minute bins in one cycle: what t* counts.
    pub fn bins(self) -> u32 {
        self.days() * MINUTES_PER_DAY
    }

    /// Days in one cycle: 1 (daily) or 7.
    pub fn days(self) -> u32 {
        match self {
            Cycle::Daily => 1,
            Cycle::Weekly | Cycle::DayTypes => 7,
        }
    }

    /// Rows the long-term store keeps: the cycle's bins, and for day types also the
    /// two day-type profiles (workday, rest day) after them.
    pub fn rows(self) -> u32 {
        match self {
            Cycle::Daily | Cycle::Weekly => self.bins(),
            Cycle::DayTypes => MINUTES_PER_WEEK + 2 * MINUTES_PER_DAY,
        }
    }

    /// The name configuration files and stores use.
    pub fn name(self) -> &'static str {
        match self {
            Cycle::Daily => "daily",
            Cycle::Weekly => "weekly",
            Cycle::DayTypes => "day_types",
        }
    }

    /// The cycle of a [`Cycle::name`].
    pub fn from_name(name: &str) -> Option<Cycle> {
        [Cycle::Daily, Cycle::Weekly, Cycle::DayTypes]
            .into_iter()
            .find(|c| c.name() == name)
    }
}

/// Converts capture times to isochronal time in one time zone.
#[derive(Debug, Clone)]
pub struct SiteClock {
    tz: TimeZone,
    cycle: Cycle,
}

impl SiteClock {
    /// A clock for the IANA time zone `tz` (e.g. `Europe/Berlin`).
    pub fn new(tz: &str, cycle: Cycle) -> Result<Self, jiff::Error> {
        Ok(SiteClock {
            tz: TimeZone::get(tz)?,
            cycle,
        })
    }

    /// The cycle.
    pub fn cycle(&self) -> Cycle {
        self.cycle
    }

    /// Local time of a UTC nanosecond instant.
    pub fn local(&self, utc_ns: i64) -> Zoned {
        timestamp(utc_ns).to_zoned(self.tz.clone())
    }

    /// Isochronal time t*: the minute of the cycle of `utc_ns`, local time
    /// (daily: 0..1440; weekly and day types: 0..10080, Monday 00:00 = 0).
    pub fn t_star(&self, utc_ns: i64) -> u32 {
        let local = self.local(utc_ns);
        let minute = local.hour() as u32 * 60 + local.minute() as u32;
        match self.cycle {
            Cycle::Daily => minute,
            Cycle::Weekly | Cycle::DayTypes => {
                let weekday = local.weekday().to_monday_zero_offset() as u32;
                weekday * MINUTES_PER_DAY + minute
            }
        }
    }

    /// The local calendar date and minute of the day of `utc_ns`.
    pub fn local_date_minute(&self, utc_ns: i64) -> (jiff::civil::Date, u32) {
        let local = self.local(utc_ns);
        (
            local.date(),
            local.hour() as u32 * 60 + local.minute() as u32,
        )
    }

    /// A number that changes exactly when the local minute changes: the minute
    /// index since the Unix epoch, in local time. Used to detect minute boundaries
    /// (robust to DST jumps, which change t* but not this order).
    pub fn minute_index(&self, utc_ns: i64) -> i64 {
        utc_ns.div_euclid(60 * NS_PER_S)
    }

    /// Local calendar day number of `utc_ns` (days since 1970-01-01, local).
    pub fn local_day(&self, utc_ns: i64) -> i64 {
        let local = self.local(utc_ns);
        let date = local.date();
        date.since(jiff::civil::date(1970, 1, 1))
            .map(|span| span.get_days() as i64)
            .unwrap_or(0)
    }
}

/// A UTC nanosecond instant as a [`Timestamp`] (saturating outside jiff's range).
pub fn timestamp(utc_ns: i64) -> Timestamp {
    Timestamp::from_nanosecond(utc_ns as i128).unwrap_or(if utc_ns < 0 {
        Timestamp::MIN
    } else {
        Timestamp::MAX
    })
}

/// Parses an RFC 3339 time (`2026-03-02T07:00:00Z`, offsets allowed) to UTC ns.
pub fn parse_rfc3339(s: &str) -> Result<i64, jiff::Error> {
    let ts: Timestamp = s.parse()?;
    Ok(ts.as_nanosecond() as i64)
}

/// Formats UTC ns as RFC 3339 in UTC with millisecond precision.
pub fn format_rfc3339(utc_ns: i64) -> String {
    let ts = timestamp(utc_ns);
    format!("{ts:.3}")
}

/// `seconds` as a [`Duration`], saturating where `Duration::from_secs_f64`
/// would panic: NaN, zero or less is zero, more than a `Duration` holds is
/// `Duration::MAX`. For a value already checked (a config key's range) or one
/// from a peer or a file (a camera's stated frame rate turned into an
/// interval); a flag a person types is refused instead
/// (`cli/src/values.rs`).
pub fn saturating_secs(seconds: f64) -> std::time::Duration {
    match std::time::Duration::try_from_secs_f64(seconds) {
        Ok(d) => d,
        Err(_) if seconds > 0.0 => std::time::Duration::MAX,
        Err(_) => std::time::Duration::ZERO,
    }
}

/// The wall clock now, UTC ns. Only live sources and latency measurements use it.
pub fn wall_now_ns() -> i64 {
    Timestamp::now().as_nanosecond() as i64
}

/// Formats a t* minute as `HH:MM` (weekly: `Mon HH:MM`).
pub fn format_t_star(t_star: u32) -> String {
    let day = t_star / MINUTES_PER_DAY;
    let minute = t_star % MINUTES_PER_DAY;
    let hhmm = format!("{:02}:{:02}", minute / 60, minute % 60);
    if day == 0 && t_star < MINUTES_PER_DAY {
        hhmm
    } else {
        const DAYS: [&str; 7] = ["Mon", "Tue", "Wed", "Thu", "Fri", "Sat", "Sun"];
        format!("{} {hhmm}", DAYS[(day % 7) as usize])
    }
}

/// Parses `HH:MM` to a minute of the day.
pub fn parse_hhmm(s: &str) -> Option<u32> {
    let (h, m) = s.split_once(':')?;
    let (h, m): (u32, u32) = (h.parse().ok()?, m.parse().ok()?);
    (h < 24 && m < 60).then_some(h * 60 + m)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seconds_saturate_instead_of_panicking() {
        use std::time::Duration;
        assert_eq!(saturating_secs(1.5), Duration::from_millis(1500));
        for zero in [0.0, -1.0, f64::NAN, f64::NEG_INFINITY] {
            assert_eq!(saturating_secs(zero), Duration::ZERO, "{zero}");
        }
        for huge in [1e30, f64::INFINITY, 2.0 / 1e-300] {
            assert_eq!(saturating_secs(huge), Duration::MAX, "{huge}");
        }
    }

    #[test]
    fn t_star_is_local_minute_of_day() {
        let clock = SiteClock::new("Europe/Berlin", Cycle::Daily).unwrap();
        // 2026-01-15 07:30 UTC is 08:30 in Berlin (CET, +1).
        let ns = parse_rfc3339("2026-01-15T07:30:00Z").unwrap();
        assert_eq!(clock.t_star(ns), 8 * 60 + 30);
        // 2026-07-15 07:30 UTC is 09:30 in Berlin (CEST, +2).
        let ns = parse_rfc3339("2026-07-15T07:30:59.9Z").unwrap();
        assert_eq!(clock.t_star(ns), 9 * 60 + 30);
        let utc = SiteClock::new("UTC", Cycle::Daily).unwrap();
        assert_eq!(utc.t_star(ns), 7 * 60 + 30);
    }

    #[test]
    fn weekly_t_star_starts_monday() {
        let clock = SiteClock::new("UTC", Cycle::Weekly).unwrap();
        // 2026-01-12 is a Monday.
        let monday = parse_rfc3339("2026-01-12T00:01:00Z").unwrap();
        assert_eq!(clock.t_star(monday), 1);
        let sunday = parse_rfc3339("2026-01-18T23:59:00Z").unwrap();
        assert_eq!(clock.t_star(sunday), MINUTES_PER_WEEK - 1);
        assert_eq!(format_t_star(MINUTES_PER_WEEK - 1), "Sun 23:59");
    }

    #[test]
    fn rfc3339_round_trip() {
        let ns = parse_rfc3339("2026-03-02T07:00:00.250+01:00").unwrap();
        assert_eq!(format_rfc3339(ns), "2026-03-02T06:00:00.250Z");
        assert!(parse_rfc3339("yesterday").is_err());
    }

    #[test]
    fn local_days_count_in_local_time() {
        let clock = SiteClock::new("America/New_York", Cycle::Daily).unwrap();
        // 03:00 UTC on Jan 2 is still Jan 1 in New York.
        let a = parse_rfc3339("2026-01-02T03:00:00Z").unwrap();
        let b = parse_rfc3339("2026-01-02T06:00:00Z").unwrap();
        assert_eq!(clock.local_day(a) + 1, clock.local_day(b));
    }

    #[test]
    fn hhmm() {
        assert_eq!(parse_hhmm("14:30"), Some(870));
        assert_eq!(parse_hhmm("24:00"), None);
        assert_eq!(format_t_star(870), "14:30");
    }
}
