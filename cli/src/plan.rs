//! `isochron plan`: when and which way a robot should go, from the paper's costs.
//!
//! * `isochron plan offline --route NAME [--between HH:MM HH:MM] [--step 5m] [--day DAY] [--json]`:
//!   Cost1 of the route over the day from the long-term stores (read here, also
//!   while the cascade writes them) — the cheapest departure windows, then the cost
//!   curve. Infinite when a segment of the route never saw activity (M'_p = 0).
//! * `isochron plan now --routes A,B,... [--json]`: Cost2 = w1·Cost1(t* = now) +
//!   w2·Σ Cost(M_p(now)) of each route, ranked, asked of the running
//!   isochron-costmap (it has the live activity) over `<prefix>/plan`.
//! * `isochron plan graph --from NODE --to NODE [--between ..] [--step ..] [--day ..] [--json]`:
//!   over the route graph, for each departure the cheapest path on the forecast,
//!   the best departure windows and the shortest path leaving now, asked of the
//!   running isochron-costmap ([`graph`]).

mod graph;

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::bail;
use isochron_config::LoadedConfig;
use isochron_config::clock::{Cycle, MINUTES_PER_DAY, SiteClock, format_t_star, wall_now_ns};
use isochron_exit::UsageError;
use isochron_planning::plan::{DayRange, OfflinePlan, RouteNow};
use isochron_planning::plan_service::{PlanClient, ranking_of};
use isochron_planning::planner::Planner;
use isochron_planning::query::{PLAN_MAX_ROUTES, PlanKind, PlanRequest, PlanStatus};
use isochron_runtime::ipc::Ipc;
use serde_json::json;

use crate::common::{Subcommands, load_config};
use crate::values;

/// Plan routes and departure times around people.
pub type Args = Subcommands<Command>;

#[derive(clap::Subcommand)]
pub(crate) enum Command {
    /// When is a route cheapest? Cost1 over the day from the long-term stores.
    Offline(OfflineArgs),
    /// Which route is cheapest now? Cost2, from the running isochron-costmap.
    Now(NowArgs),
    /// Which way through the route graph, and when? From the running isochron-costmap.
    Graph(graph::GraphArgs),
}

#[derive(clap::Args)]
pub(crate) struct OfflineArgs {
    /// Site configuration (default: $ISOCHRON_CONFIG or /etc/isochron/isochron.toml).
    #[arg(long)]
    config: Option<PathBuf>,
    /// The route (a [[costmap.route]] name).
    #[arg(long)]
    route: String,
    /// Only departures between these times of day, `HH:MM HH:MM` (end exclusive;
    /// `24:00` is midnight; an end before the start wraps past midnight).
    #[arg(long, num_args = 2, value_names = ["FROM", "TO"], value_parser = values::time_of_day_or_24)]
    between: Option<Vec<u32>>,
    /// Minutes between curve points: `5m`, `15`, `1h`. Each point is the mean Cost1
    /// over its step.
    #[arg(long, default_value = "5m", value_parser = values::step)]
    step: u32,
    /// Weekly stores: the day (`mon` .. `sun`); default today.
    #[arg(long, value_parser = values::weekday)]
    day: Option<u32>,
    /// One JSON object instead of text.
    #[arg(long)]
    json: bool,
}

#[derive(clap::Args)]
pub(crate) struct NowArgs {
    /// Site configuration (default: $ISOCHRON_CONFIG or /etc/isochron/isochron.toml).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Routes to rank, comma-separated ([[costmap.route]] names).
    #[arg(long, value_delimiter = ',', required = true)]
    routes: Vec<String>,
    /// One JSON object instead of text.
    #[arg(long)]
    json: bool,
    /// How long to wait for isochron-costmap's answer, seconds.
    #[arg(long, default_value = "5", value_parser = values::positive_seconds)]
    timeout: Duration,
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    match args.command {
        Command::Offline(a) => offline(a),
        Command::Now(a) => now(a),
        Command::Graph(a) => graph::run(a),
    }
}

/// `--between`: the first minute and the end minute (exclusive) of the
/// departures.
fn window(between: Option<&[u32]>) -> anyhow::Result<(u32, u32)> {
    match between {
        None | Some([]) | Some([_]) => Ok((0, MINUTES_PER_DAY)),
        Some([start, end, ..]) => {
            if *start == MINUTES_PER_DAY {
                bail!(UsageError(
                    "--between: FROM is a time of day from 00:00 to 23:59, found '24:00'".into()
                ));
            }
            Ok((*start, if *end == 0 { MINUTES_PER_DAY } else { *end }))
        }
    }
}

/// Refuses `--day` on a site whose model is of one day.
fn check_day(day: Option<u32>, loaded: &LoadedConfig) -> anyhow::Result<()> {
    if day.is_some() && loaded.config.cascade.cycle == Cycle::Daily {
        bail!(UsageError(
            "--day is for a model of the week (cascade.cycle = \"day_types\" or \"weekly\"); this site has cascade.cycle = \"daily\"".into()
        ));
    }
    Ok(())
}

/// The range of an off-line plan from the arguments.
fn day_range(args: &OfflineArgs, loaded: &LoadedConfig) -> anyhow::Result<DayRange> {
    let (start, end) = window(args.between.as_deref())?;
    check_day(args.day, loaded)?;
    let cycle_offset = match loaded.config.cascade.cycle {
        Cycle::Daily => 0,
        Cycle::Weekly | Cycle::DayTypes => {
            let day = match args.day {
                Some(d) => d,
                None => {
                    let clock = SiteClock::new(&loaded.config.site.time_zone, Cycle::Weekly)?;
                    clock.t_star(wall_now_ns()) / MINUTES_PER_DAY
                }
            };
            day * MINUTES_PER_DAY
        }
    };
    Ok(DayRange {
        start,
        end,
        step: args.step,
        cycle_offset,
    })
}

/// Refuses (64) a route `flag` names that is not a `[[costmap.route]]` of the
/// site, naming those that are.
fn configured_route(flag: &str, name: &str, loaded: &LoadedConfig) -> Result<(), UsageError> {
    if loaded.config.costmap.route(name).is_some() {
        return Ok(());
    }
    let known: Vec<&str> = loaded
        .config
        .costmap
        .routes
        .iter()
        .map(|r| r.name.as_str())
        .collect();
    Err(UsageError(format!(
        "{flag}: no route '{name}' in [[costmap.route]] (configured: {})",
        known.join(", ")
    )))
}

fn offline(args: OfflineArgs) -> anyhow::Result<ExitCode> {
    let loaded = load_config(args.config.clone())?;
    configured_route("--route", &args.route, &loaded)?;
    let range = day_range(&args, &loaded)?;
    let mut planner = Planner::new(&loaded)?;
    if loaded.config.cascade.cycle != Cycle::Daily {
        planner.check_day_learned(range.cycle_offset / MINUTES_PER_DAY)?;
    }
    let plan = planner.offline(&args.route, range)?;
    let segments = planner.route(&args.route)?.segments.clone();
    if args.json {
        println!("{}", offline_json(&plan, &segments));
    } else {
        print_offline(&plan, &segments, planner.days());
    }
    Ok(ExitCode::SUCCESS)
}

/// A cost as JSON: a number, `"inf"`, or null (no data).
fn cost_json(c: f64) -> serde_json::Value {
    if c.is_infinite() {
        json!("inf")
    } else if c.is_nan() {
        serde_json::Value::Null
    } else {
        json!((c * 1000.0).round() / 1000.0)
    }
}

fn hhmm(minute: u32) -> String {
    if minute == MINUTES_PER_DAY {
        "24:00".into()
    } else {
        format_t_star(minute % MINUTES_PER_DAY)
    }
}

/// The off-line plan as one JSON object.
pub fn offline_json(plan: &OfflinePlan, segments: &[String]) -> serde_json::Value {
    json!({
        "route": plan.route,
        "segments": segments,
        "between": [hhmm(plan.range.start), hhmm(plan.range.end)],
        "step_min": plan.range.step,
        "infinite": !plan.never_active.is_empty(),
        "never_active": plan.never_active,
        "windows": plan.windows.iter().map(|w| json!({
            "start": hhmm(w.start % MINUTES_PER_DAY),
            "end": hhmm(if w.end == MINUTES_PER_DAY { w.end } else { w.end % MINUTES_PER_DAY }),
            "start_minute": w.start,
            "end_minute": w.end,
            "cost": cost_json(w.cost),
        })).collect::<Vec<_>>(),
        "best": plan.best.iter().map(|p| json!({"time": hhmm(p.minute), "minute": p.minute, "cost": cost_json(p.cost)})).collect::<Vec<_>>(),
        "curve": plan.curve.iter().map(|p| json!({"time": hhmm(p.minute), "minute": p.minute, "cost": cost_json(p.cost)})).collect::<Vec<_>>(),
    })
}

fn print_offline(plan: &OfflinePlan, segments: &[String], days: u32) {
    println!(
        "route {}: {} ({} day{} of long-term data)",
        plan.route,
        segments.join(" → "),
        days,
        if days == 1 { "" } else { "s" }
    );
    if !plan.never_active.is_empty() {
        println!(
            "Cost1 is infinite all day: no activity was ever seen on segment{} {} (M'_p = 0: people never go there, so neither should the robot)",
            if plan.never_active.len() == 1 {
                ""
            } else {
                "s"
            },
            plan.never_active.join(", ")
        );
        return;
    }
    if plan.windows.is_empty() {
        println!(
            "no long-term data in {}–{} yet: nothing to plan on",
            hhmm(plan.range.start),
            hhmm(plan.range.end)
        );
        return;
    }
    println!("cheapest departures (Cost1 within 5 % of the day's range above the minimum):");
    for w in &plan.windows {
        let end = if w.end == MINUTES_PER_DAY {
            w.end
        } else {
            w.end % MINUTES_PER_DAY
        };
        println!(
            "  {}–{}  cost {:.1}",
            hhmm(w.start % MINUTES_PER_DAY),
            hhmm(end),
            w.cost
        );
    }
    let max = plan
        .curve
        .iter()
        .map(|p| p.cost)
        .filter(|c| c.is_finite())
        .fold(0.0f64, f64::max);
    println!(
        "cost curve (Cost1, mean over each {} min):",
        plan.range.step
    );
    for p in &plan.curve {
        if p.cost.is_nan() {
            println!("  {}      —  (no long-term data)", hhmm(p.minute));
        } else {
            let bar = if max > 0.0 {
                (p.cost / max * 40.0).round() as usize
            } else {
                0
            };
            println!("  {}  {:>6.1}  {}", hhmm(p.minute), p.cost, "█".repeat(bar));
        }
    }
}

fn now(args: NowArgs) -> anyhow::Result<ExitCode> {
    let loaded = load_config(args.config.clone())?;
    for r in &args.routes {
        configured_route("--routes", r, &loaded)?;
    }
    if args.routes.len() > PLAN_MAX_ROUTES {
        bail!(UsageError(format!(
            "--routes: at most {PLAN_MAX_ROUTES} routes at once"
        )));
    }
    let ipc = Ipc::of_site(
        &format!("isochron-plan-{}", std::process::id()),
        &loaded.config,
    )?;
    let client = PlanClient::new(&ipc)?;
    let names: Vec<&str> = args.routes.iter().map(String::as_str).collect();
    let response = client.request(
        PlanRequest::new(PlanKind::Now, &names),
        args.timeout.max(Duration::from_millis(100)),
    )?;
    match response.validate()? {
        PlanStatus::Ok => {}
        status => bail!(
            "isochron-costmap could not plan ({status:?}): {}",
            response.message()
        ),
    }
    let ranked = ranking_of(&response);
    if args.json {
        println!("{}", now_json(&ranked, response.t_star, &loaded));
    } else {
        print_now(&ranked, response.t_star, &loaded);
    }
    Ok(ExitCode::SUCCESS)
}

/// The ranking as one JSON object.
pub fn now_json(ranked: &[RouteNow], t_star: u32, loaded: &LoadedConfig) -> serde_json::Value {
    json!({
        "t_star": t_star,
        "time": format_t_star(t_star),
        "w1": loaded.config.costmap.w1,
        "w2": loaded.config.costmap.w2,
        "routes": ranked.iter().enumerate().map(|(i, r)| json!({
            "rank": i + 1,
            "route": r.name,
            "cost2": cost_json(r.cost2),
            "cost1": cost_json(r.cost1),
            "short_term": cost_json(r.short_term),
            "infinite": r.infinite,
            "estimated": r.estimated,
            "no_long_term": r.no_long_term,
        })).collect::<Vec<_>>(),
    })
}

fn print_now(ranked: &[RouteNow], t_star: u32, loaded: &LoadedConfig) {
    let c = &loaded.config.costmap;
    println!(
        "routes at t* = {} (Cost2 = {}·Cost1 + {}·short-term):",
        format_t_star(t_star),
        c.w1,
        c.w2
    );
    println!(
        "{:<5} {:<24} {:>9} {:>9} {:>11}  NOTE",
        "RANK", "ROUTE", "COST2", "COST1", "SHORT-TERM"
    );
    for (i, r) in ranked.iter().enumerate() {
        let mut notes = Vec::new();
        if r.infinite {
            notes.push("a segment never saw activity");
        }
        if r.estimated {
            notes.push("no live activity for a segment: long-term stood in");
        }
        if r.no_long_term {
            notes.push("no long-term data at this t*");
        }
        let num = |v: f64| {
            if v.is_finite() {
                format!("{v:.1}")
            } else {
                "inf".to_string()
            }
        };
        println!(
            "{:<5} {:<24} {:>9} {:>9} {:>11}  {}",
            i + 1,
            r.name,
            num(r.cost2),
            num(r.cost1),
            num(r.short_term),
            notes.join("; ")
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hours_print_with_the_end_of_the_day() {
        assert_eq!(hhmm(1440), "24:00");
        assert_eq!(hhmm(750), "12:30");
    }
}
