//! The long-term forecast: `isochron store backtest` replays a count series through
//! the very model the cascade learns with, and scores it.

use std::fmt::Write as _;
use std::time::Duration;

use isochron_cascade::{Cascade, MemoryModel, Params};
use isochron_config::clock::{Cycle, SiteClock};
use isochron_tests::TestSite;
use isochron_wire::CameraId;
use isochron_wire::geometry::BlockGrid;

/// Days of the series, from Monday 2026-01-05; days before `SCORED` only learn.
const DAYS: usize = 35;
const SCORED: usize = 14;

/// A count with a weekly shape: busy workday hours, quiet weekends, and noise.
fn count(series: usize, day: usize, hour: usize) -> Option<f64> {
    // Missing hours early on (a camera that was down) teach nothing.
    if day == 2 && (series == 0 || hour < 12) {
        return None;
    }
    let weekend = day % 7 >= 5;
    let shape = if (8..18).contains(&hour) { 40.0 } else { 5.0 };
    let level = if weekend { 0.3 } else { 1.0 } * shape * (1.0 + series as f64);
    let noise = ((day * 31 + hour * 7 + series * 13) % 11) as f64;
    Some(level + noise)
}

#[test]
fn the_backtest_scores_the_model_the_cascade_learns() {
    let site = TestSite::new("forecast-backtest", "");
    let csv = site.path("counts.csv");
    let mut text = String::from("time,a,b\n");
    let first = jiff::civil::date(2026, 1, 5);
    for day in 0..DAYS {
        let date = first
            .checked_add(jiff::Span::new().days(day as i64))
            .unwrap();
        for hour in 0..24 {
            let cell = |s| count(s, day, hour).map_or(String::new(), |v| v.to_string());
            writeln!(text, "{date}T{hour:02}:00,{},{}", cell(0), cell(1)).unwrap();
        }
    }
    std::fs::write(&csv, text).unwrap();
    let score_from = first
        .checked_add(jiff::Span::new().days(SCORED as i64))
        .unwrap();
    let run = site.isochron(
        &[
            "store",
            "backtest",
            "--counts",
            csv.to_str().unwrap(),
            "--score-from",
            &score_from.to_string(),
            "--hours",
            "0-23",
        ],
        Duration::from_secs(60),
    );
    assert!(run.status.success(), "{}\n{}", run.stdout, run.stderr);
    let last = run.stdout.lines().last().unwrap();
    let report: serde_json::Value = serde_json::from_str(last).unwrap();
    assert!(
        report["model"]["name"]
            .as_str()
            .unwrap()
            .starts_with("day_types"),
        "{report}"
    );

    // The same series through the cascade's own learning, with the default
    // configuration (day types, UTC): forecast each hour, then learn the day.
    for (s, name) in ["a", "b"].into_iter().enumerate() {
        let clock = SiteClock::new("UTC", Cycle::DayTypes).unwrap();
        let grid = BlockGrid::new(16, 16, 16);
        let mut cascade: Cascade = Cascade::new(
            CameraId::new("cam01").unwrap(),
            Params::default(),
            clock,
            grid,
            None,
        );
        let mut model = MemoryModel::default();
        let epoch_day = first
            .since(jiff::civil::date(1970, 1, 1))
            .unwrap()
            .get_days() as i64;
        let (mut err, mut sum) = (0.0, 0.0);
        for day in 0..DAYS {
            let minute = |hour: usize| (epoch_day + day as i64) * 1440 + hour as i64 * 60;
            for hour in 0..24 {
                let forecast = cascade
                    .forecast(minute(hour), &mut model)
                    .unwrap()
                    .map_or(0.0, |b| b.mean[0].max(0.0) as f64);
                if day >= SCORED {
                    let actual = count(s, day, hour).unwrap();
                    err += (forecast - actual).abs();
                    sum += actual;
                }
            }
            for hour in 0..24 {
                if let Some(x) = count(s, day, hour) {
                    assert!(
                        cascade
                            .learn_minute(minute(hour), &[x as f32], &mut model)
                            .unwrap()
                    );
                }
            }
        }
        let cascade_nmae = err / sum;
        let backtest_nmae = report["series"][name]["model"]["nmae"].as_f64().unwrap();
        assert!(
            (cascade_nmae - backtest_nmae).abs() < 1e-9,
            "series {name}: the cascade's forecasts score {cascade_nmae}, the backtest says {backtest_nmae}"
        );
        // The weekly shape is learned: better than the paper's daily model.
        let paper = report["series"][name]["baselines"]["paper_daily_ema"]["nmae"]
            .as_f64()
            .unwrap();
        assert!(backtest_nmae < paper, "{report}");
    }
}

#[test]
fn a_malformed_count_file_is_refused_with_its_line() {
    let site = TestSite::new("forecast-bad-counts", "");
    let csv = site.path("counts.csv");
    std::fs::write(&csv, "time,a\n2026-01-05T00:00,1\n2026-01-05T01:00,lots\n").unwrap();
    let run = site.isochron(
        &["store", "backtest", "--counts", csv.to_str().unwrap()],
        Duration::from_secs(30),
    );
    assert!(!run.status.success());
    assert!(
        run.stderr.contains("line 3") && run.stderr.contains("'lots'"),
        "{}",
        run.stderr
    );
}
