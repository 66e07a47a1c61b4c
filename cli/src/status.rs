//! `isochron status`: one table of the whole group, from the status every service
//! publishes (rates, drops, latencies), whoever started it (systemd or `up`).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use isochron_config::LoadedConfig;
use isochron_config::clock::wall_now_ns;
use isochron_runtime::health::{status_counters, status_detail};
use isochron_runtime::ipc::Ipc;
use isochron_runtime::topology::StageKind;
use isochron_wire::{StageStatus, fixed_str};
use serde_json::json;

use crate::common::load_config;
use crate::launch::installed;

/// Show the status of every service of the site. Exits with 0 when every
/// service runs, 3 when some does not.
#[derive(clap::Args)]
pub struct Args {
    /// Site configuration (default: $ISOCHRON_CONFIG or /etc/isochron/isochron.toml).
    #[arg(long)]
    config: Option<PathBuf>,
    /// One JSON object per service instead of a table.
    #[arg(long)]
    json: bool,
}

/// A report older than this many report periods (5 s) means the service is gone.
const STALE_AFTER_S: f64 = 15.0;

/// One row: a service and what it last reported.
pub struct Row {
    /// The stage.
    pub stage: StageKind,
    /// Camera id ("" for site-wide stages).
    pub camera: String,
    /// The last report, if any.
    pub status: Option<StageStatus>,
}

impl Row {
    /// Seconds since the last report.
    pub fn age_s(&self) -> Option<f64> {
        self.status
            .map(|s| (wall_now_ns() - s.report_wall_ns) as f64 / 1e9)
    }

    /// "running", "stale" or "not running".
    pub fn state(&self) -> &'static str {
        match self.age_s() {
            None => "not running",
            Some(age) if age > STALE_AFTER_S => "stale",
            Some(_) => "running",
        }
    }
}

/// How long `collect` waits for the stages' reports.
const STATUS_WAIT: Duration = Duration::from_millis(1000);

/// The stages whose status the site should publish: those `isochron up` starts
/// for `config` ([`StageKind::started`]) whose binaries are installed.
pub fn expected_stages(config: &LoadedConfig) -> Vec<StageKind> {
    installed(StageKind::started(&config.config))
        .into_iter()
        .map(|(stage, _)| stage)
        .collect()
}

/// Reads the last status of every expected stage ([`expected_stages`]) of every
/// camera of `config`, and of the view while one runs.
pub fn collect(ipc: &Ipc, config: &LoadedConfig) -> anyhow::Result<Vec<Row>> {
    let mut readers = Vec::new();
    // A view or recorder (`isochron view`, `record`) has a row while it runs.
    let view = (ipc.status_publishers("", StageKind::View) > 0).then_some(StageKind::View);
    let services = StageKind::services_of(expected_stages(config).into_iter(), &config.config);
    for (stage, camera) in services.into_iter().chain(view.map(|v| (v, String::new()))) {
        // A site of thousands of cameras takes a while: SIGTERM or SIGINT stops
        // here, and the readers made so far are dropped (their shared memory
        // with them).
        if isochron_runtime::ipc::stop_signalled() {
            anyhow::bail!(
                "interrupted (SIGTERM or SIGINT) after {} of the status readers",
                readers.len()
            );
        }
        let reader = ipc.status_subscriber(&camera, stage)?;
        readers.push((stage, camera, reader));
    }
    // A running stage hands its last report to a new reader on its next tick
    // (within 250 ms); wait a little longer, or until every stage has answered.
    let mut latest: Vec<Option<StageStatus>> = vec![None; readers.len()];
    let deadline = Instant::now() + STATUS_WAIT;
    loop {
        for ((_, _, reader), last) in readers.iter().zip(latest.iter_mut()) {
            if let Some(s) = reader.latest().filter(|s| s.validate().is_ok()) {
                *last = Some(s);
            }
        }
        if latest.iter().all(Option::is_some) || Instant::now() >= deadline || ipc.should_stop() {
            break;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    Ok(readers
        .into_iter()
        .zip(latest)
        .map(|((stage, camera, _), status)| Row {
            stage,
            camera,
            status,
        })
        .collect())
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let loaded = load_config(args.config)?;
    let ipc = Ipc::of_site("isochron-status", &loaded.config)?;
    let rows = collect(&ipc, &loaded)?;
    if args.json {
        for row in &rows {
            let mut o =
                json!({"stage": row.stage.name(), "camera": row.camera, "state": row.state()});
            if let Some(s) = &row.status {
                o["pid"] = json!(s.pid);
                o["age_s"] = json!(row.age_s());
                o["uptime_s"] = json!((s.report_wall_ns - s.started_wall_ns) as f64 / 1e9);
                o["received"] = json!(s.received);
                o["sent"] = json!(s.sent);
                o["dropped"] = json!(s.dropped);
                o["rejected"] = json!(s.rejected);
                o["rate_in"] = json!(s.rate_in);
                o["rate_out"] = json!(s.rate_out);
                o["stage_latency_ms"] = json!(s.stage_latency_ms);
                o["e2e_latency_p50_ms"] = json!(s.e2e_latency_p50_ms);
                o["e2e_latency_p99_ms"] = json!(s.e2e_latency_p99_ms);
                o["detail"] = json!(status_detail(s));
                o["info"] = json!(fixed_str(&s.info));
                if let Some(c) = status_counters(s) {
                    let counters: serde_json::Map<String, serde_json::Value> = c
                        .iter()
                        .map(|(spec, v)| (spec.name.into(), json!(v)))
                        .collect();
                    o["counters"] = counters.into();
                }
            }
            println!("{o}");
        }
    } else {
        println!(
            "{:<8} {:<10} {:<12} {:>7} {:>9} {:>9} {:>8} {:>8} {:>9} {:>13}  DETAIL",
            "STAGE",
            "CAMERA",
            "STATE",
            "PID",
            "IN/s",
            "OUT/s",
            "DROPPED",
            "REJECTED",
            "LAT ms",
            "E2E p50/p99"
        );
        for row in &rows {
            let camera = if row.camera.is_empty() {
                "-"
            } else {
                row.camera.as_str()
            };
            match &row.status {
                None => println!("{:<8} {:<10} {:<12}", row.stage.name(), camera, row.state()),
                Some(s) => println!(
                    "{:<8} {:<10} {:<12} {:>7} {:>9.1} {:>9.1} {:>8} {:>8} {:>9.2} {:>6.1}/{:<6.1}  {}",
                    row.stage.name(),
                    camera,
                    row.state(),
                    s.pid,
                    s.rate_in,
                    s.rate_out,
                    s.dropped,
                    s.rejected,
                    s.stage_latency_ms,
                    s.e2e_latency_p50_ms,
                    s.e2e_latency_p99_ms,
                    status_detail(s)
                ),
            }
        }
    }
    let all_running = rows.iter().all(|r| r.state() == "running");
    Ok(if all_running {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(isochron_exit::NOT_RUNNING as u8)
    })
}
