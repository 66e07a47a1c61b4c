//! `isochron plan graph --from NODE --to NODE`: for each departure of a window the
//! cheapest path over the route graph (`costmap.route_graph`) when each edge costs
//! what the forecast expects when the robot reaches it, asked of the running
//! isochron-costmap over `<prefix>/plan`; the best departure windows with their
//! nodes, edges and costs, and the shortest path leaving now beside them.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::bail;
use isochron_config::clock::{MINUTES_PER_DAY, format_t_star};
use isochron_planning::plan_service::PlanClient;
use isochron_planning::query::{PlanGraphPath, PlanRequest, PlanResponse, PlanStatus};
use isochron_runtime::ipc::Ipc;
use serde_json::{Value, json};

use super::{check_day, cost_json, hhmm, window};
use crate::common::load_config;
use crate::values;

#[derive(clap::Args)]
pub(crate) struct GraphArgs {
    /// Site configuration (default: $ISOCHRON_CONFIG or /etc/isochron/isochron.toml).
    #[arg(long)]
    config: Option<PathBuf>,
    /// The start node (a nav2_route node id of costmap.route_graph).
    #[arg(long)]
    from: u16,
    /// The goal node.
    #[arg(long)]
    to: u16,
    /// Only departures between these times of day, `HH:MM HH:MM` (end exclusive;
    /// `24:00` is midnight; an end before the start wraps past midnight).
    #[arg(long, num_args = 2, value_names = ["FROM", "TO"], value_parser = values::time_of_day_or_24)]
    between: Option<Vec<u32>>,
    /// Minutes between departures: `5m`, `15`, `1h`.
    #[arg(long, default_value = "5m", value_parser = values::step)]
    step: u32,
    /// Weekly stores: the day (`mon` .. `sun`); default today.
    #[arg(long, value_parser = values::weekday)]
    day: Option<u32>,
    /// One JSON object instead of text.
    #[arg(long)]
    json: bool,
    /// How long to wait for isochron-costmap's answer, seconds.
    #[arg(long, default_value = "10", value_parser = values::positive_seconds)]
    timeout: Duration,
}

/// Asks the bridge and prints its answer.
pub(crate) fn run(args: GraphArgs) -> anyhow::Result<ExitCode> {
    let loaded = load_config(args.config.clone())?;
    let (start, end) = window(args.between.as_deref())?;
    let step = args.step;
    check_day(args.day, &loaded)?;
    // 7: today, as the bridge's clock says.
    let weekday = args.day.unwrap_or(7);
    let mut request = PlanRequest::graph(args.from, args.to);
    request.start_minute = start;
    request.end_minute = end;
    request.step_min = step;
    request.weekday = weekday;
    let ipc = Ipc::of_site(
        &format!("isochron-plan-{}", std::process::id()),
        &loaded.config,
    )?;
    let client = PlanClient::new(&ipc)?;
    let response = client.request(request, args.timeout.max(Duration::from_millis(100)))?;
    match response.validate()? {
        PlanStatus::Ok => {}
        status => bail!(
            "isochron-costmap could not plan ({status:?}): {}",
            response.message()
        ),
    }
    if args.json {
        println!("{}", graph_json(&args, &response));
    } else {
        print_graph(&args, &response);
    }
    Ok(ExitCode::SUCCESS)
}

/// A path as JSON.
fn path_json(p: &PlanGraphPath) -> Value {
    json!({
        "departure": hhmm(p.departure_minute),
        "departure_minute": p.departure_minute,
        "nodes": p.node_ids(),
        "edges": p.edge_ids(),
        "cost": cost_json(p.cost as f64),
        "activity_cost": cost_json(p.activity_cost as f64),
        "length_m": cost_json(p.length_m as f64),
        "duration_s": cost_json(p.duration_s as f64),
        "unknown_edges": p.unknown_edges,
    })
}

/// The answer as one JSON object.
fn graph_json(args: &GraphArgs, r: &PlanResponse) -> Value {
    let windows = (r.window_count as usize).min(r.windows.len());
    let step = r.curve_step_min.max(1);
    let curve_len = (r.curve_len as usize).min(r.curve.len());
    json!({
        "from": args.from,
        "to": args.to,
        "step_min": step,
        "windows": r.windows[..windows].iter().zip(&r.graph_windows).map(|(w, p)| json!({
            "start": hhmm(w.start_minute % MINUTES_PER_DAY),
            "end": hhmm(if w.end_minute == MINUTES_PER_DAY { w.end_minute } else { w.end_minute % MINUTES_PER_DAY }),
            "start_minute": w.start_minute,
            "end_minute": w.end_minute,
            "cost": cost_json(w.cost as f64),
            "path": path_json(p),
        })).collect::<Vec<_>>(),
        "best": path_json(&r.graph_best),
        "baseline": path_json(&r.graph_baseline),
        "curve": r.curve[..curve_len].iter().enumerate().map(|(k, c)| {
            let minute = (r.curve_start_minute + k as u32 * step) % MINUTES_PER_DAY;
            json!({"time": hhmm(minute), "minute": minute, "cost": cost_json(*c as f64)})
        }).collect::<Vec<_>>(),
    })
}

/// A path in one line: departure, cost, nodes and edges.
fn path_line(p: &PlanGraphPath) -> String {
    let ids = |v: &[u16]| v.iter().map(u16::to_string).collect::<Vec<_>>().join(" → ");
    format!(
        "leave {}  cost {:.1} (activity {:.1}), {:.0} m, {:.0} s; nodes {}; edges {}",
        format_t_star(p.departure_minute),
        p.cost,
        p.activity_cost,
        p.length_m,
        p.duration_s,
        ids(p.node_ids()),
        ids(p.edge_ids())
    )
}

fn print_graph(args: &GraphArgs, r: &PlanResponse) {
    println!("route graph, node {} to node {}:", args.from, args.to);
    println!("best:      {}", path_line(&r.graph_best));
    println!(
        "baseline:  {} (the shortest path, leaving now)",
        path_line(&r.graph_baseline)
    );
    println!("cheapest departure windows:");
    let windows = (r.window_count as usize).min(r.windows.len());
    for (w, p) in r.windows[..windows].iter().zip(&r.graph_windows) {
        println!(
            "  {}–{}  mean cost {:.1}; {}",
            hhmm(w.start_minute % MINUTES_PER_DAY),
            hhmm(w.end_minute.min(MINUTES_PER_DAY)),
            w.cost,
            path_line(p)
        );
    }
}
