//! The values of the command's flags, parsed where clap reads them
//! (`#[arg(value_parser = ...)]`): a value that is not what its flag expects
//! stops the command before it does anything, with one line that names the
//! flag, the value and what is expected, and exit code 64 (`USAGE`; see
//! `parse_error` in `lib.rs`).

use std::time::Duration;

use isochron_config::Speed;
use isochron_config::clock::{Cycle, MINUTES_PER_DAY, parse_hhmm};
use isochron_wire::Stream;

/// A day of the week, `mon` .. `sun` (or longer: `monday`); Monday = 0.
pub fn weekday(text: &str) -> Result<u32, String> {
    let s = text.trim().to_ascii_lowercase();
    isochron_config::DAY_NAMES
        .iter()
        .position(|d| s.starts_with(d))
        .map(|d| d as u32)
        .ok_or_else(|| "expected a day of the week, mon .. sun".to_string())
}

/// A time of day, `HH:MM` from 00:00 to 23:59: its minute of the day.
pub fn time_of_day(text: &str) -> Result<u32, String> {
    parse_hhmm(text.trim()).ok_or_else(|| "expected a time of day HH:MM from 00:00 to 23:59".into())
}

/// A time of day that may be the end of the day, `HH:MM` from 00:00 to 24:00.
pub fn time_of_day_or_24(text: &str) -> Result<u32, String> {
    if text.trim() == "24:00" {
        return Ok(MINUTES_PER_DAY);
    }
    parse_hhmm(text.trim()).ok_or_else(|| "expected a time of day HH:MM from 00:00 to 24:00".into())
}

/// Minutes: `5m`, `5`, `1h`, `90min`, from 1 minute to a day.
pub fn step(text: &str) -> Result<u32, String> {
    let expected = || "expected minutes such as 5m, 15 or 1h (1 minute to 24h)".to_string();
    let s = text.trim();
    let (number, unit) = s.split_at(s.find(|c: char| !c.is_ascii_digit()).unwrap_or(s.len()));
    let n: u32 = number.parse().map_err(|_| expected())?;
    let minutes = match unit.trim() {
        "" | "m" | "min" | "mins" | "minutes" => Some(n),
        "h" | "hour" | "hours" => n.checked_mul(60),
        _ => None,
    };
    minutes
        .filter(|m| (1..=MINUTES_PER_DAY).contains(m))
        .ok_or_else(expected)
}

/// The longest time any flag takes in seconds: a year.
pub const MAX_SECONDS: f64 = 365.0 * 86_400.0;

/// Seconds from 0 to [`MAX_SECONDS`] (`2.5`, `0`), as a duration.
pub fn seconds(text: &str) -> Result<Duration, String> {
    seconds_in(text, 0.0, "from 0")
}

/// Seconds over 0 up to [`MAX_SECONDS`], as a duration.
pub fn positive_seconds(text: &str) -> Result<Duration, String> {
    seconds_in(text, f64::MIN_POSITIVE, "over 0")
}

fn seconds_in(text: &str, min: f64, range: &str) -> Result<Duration, String> {
    let expected = || format!("expected seconds {range} to {MAX_SECONDS} (a year)");
    let s: f64 = text.trim().parse().map_err(|_| expected())?;
    if !(s.is_finite() && (min..=MAX_SECONDS).contains(&s)) {
        return Err(expected());
    }
    Duration::try_from_secs_f64(s).map_err(|_| expected())
}

/// A playback speed: `max` or a factor of real time > 0.
pub fn speed(text: &str) -> Result<Speed, String> {
    Speed::parse(text.trim()).ok_or_else(|| "expected `max` or a number > 0 (1 = real time)".into())
}

/// A capture time for a file's first frame: RFC 3339 from 1971 to 2200, kept as
/// written (the config's `start` takes the same).
pub fn start_time(text: &str) -> Result<String, String> {
    isochron_config::parse_start(text.trim()).map_err(|expected| format!("expected {expected}"))?;
    Ok(text.trim().to_string())
}

/// A stream of a camera: `frames`, `motion`, `activity`, `events` or `detections`.
pub fn stream(text: &str) -> Result<Stream, String> {
    Stream::from_name(text.trim())
        .ok_or_else(|| "expected one of frames, motion, activity, events, detections".to_string())
}

/// An isochronal cycle: `day_types`, `daily` or `weekly`.
pub fn cycle(text: &str) -> Result<Cycle, String> {
    Cycle::from_name(text.trim()).ok_or_else(|| "expected day_types, daily or weekly".to_string())
}

/// A calendar date, `YYYY-MM-DD`.
pub fn date(text: &str) -> Result<jiff::civil::Date, String> {
    text.trim()
        .parse()
        .map_err(|_| "expected a date YYYY-MM-DD".to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_parse_or_say_what_is_expected() {
        assert_eq!(weekday("Wednesday"), Ok(2));
        assert_eq!(weekday("mon"), Ok(0));
        assert_eq!(weekday("sun"), Ok(6));
        assert!(weekday("funday").unwrap_err().contains("mon .. sun"));
        assert!(weekday("x").is_err());
        assert!(weekday("mo").is_err());
        assert_eq!(time_of_day("07:30"), Ok(450));
        assert!(time_of_day("25:00").unwrap_err().contains("HH:MM"));
        assert!(time_of_day("24:00").is_err());
        assert_eq!(time_of_day_or_24("24:00"), Ok(1440));
        assert_eq!(step("5m"), Ok(5));
        assert_eq!(step("15"), Ok(15));
        assert_eq!(step("1h"), Ok(60));
        assert_eq!(step("90min"), Ok(90));
        assert!(step("0m").is_err());
        assert!(step("25h").is_err());
        assert!(step("5s").is_err());
        assert_eq!(speed("max"), Ok(Speed::Max));
        assert_eq!(speed("2"), Ok(Speed::Factor(2.0)));
        assert!(speed("-1").unwrap_err().contains("> 0"));
        assert!(speed("0").is_err());
        assert!(start_time("2026-03-02T07:00:00Z").is_ok());
        assert!(start_time("yesterday").unwrap_err().contains("RFC 3339"));
        assert!(start_time("1960-01-01T00:00:00Z").is_err());
        assert_eq!(stream("events"), Ok(Stream::Events));
        assert!(stream("bogus").unwrap_err().contains("frames"));
        assert_eq!(cycle("weekly"), Ok(Cycle::Weekly));
        assert!(cycle("monthly").is_err());
        assert!(date("2026-01-07").is_ok());
        assert!(date("7.1.2026").is_err());
    }

    #[test]
    fn seconds_are_finite_within_a_year_or_refused_without_a_panic() {
        assert_eq!(seconds("2.5"), Ok(Duration::from_millis(2500)));
        assert_eq!(seconds("0"), Ok(Duration::ZERO));
        assert_eq!(seconds(" 31536000 "), Ok(Duration::from_secs(31_536_000)));
        assert_eq!(positive_seconds("0.1"), Ok(Duration::from_millis(100)));
        for bad in [
            "1e30", "inf", "-inf", "NaN", "-1", "31536001", "", "5s", "1e309",
        ] {
            let e = seconds(bad).unwrap_err();
            assert!(
                e.contains("expected seconds from 0 to 31536000"),
                "{bad}: {e}"
            );
        }
        for bad in ["0", "-0", "1e30"] {
            assert!(
                positive_seconds(bad).unwrap_err().contains("over 0"),
                "{bad}"
            );
        }
    }
}
