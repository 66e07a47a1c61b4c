//! The exporter's stage: on every tick (100 ms) it takes the latest status report
//! of every watched service into the [`Table`], then answers the HTTP requests
//! that arrived meanwhile (`tiny_http` accepts and parses them on its own
//! threads; they wait in its queue until the tick).
//!
//! It watches every pipeline stage of every configured camera, and the site-wide
//! costmap, whether or not they run: a service that never reported is `up` 0.

use std::net::{SocketAddr, TcpListener};
use std::sync::Arc;
use std::time::{Duration, Instant};

use isochron_shared::clock::wall_now_ns;
use isochron_shared::config::{ExporterConfig, LoadedConfig};
use isochron_shared::exit::{self, Fatal};
use isochron_shared::ipc::{Ipc, StatusSubscriber};
use isochron_shared::service::ServiceContext;
use isochron_shared::stage::{self, Context, Stage, Woken};
use isochron_shared::topology::StageKind;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::registry::Registry;
use tiny_http::{Header, Method, Request, Response, Server};

use crate::metrics::{Service, StatusCollector, Table, classic_text};

/// How often reports are read and requests answered: the longest a scrape waits.
const TICK: Duration = Duration::from_millis(100);

/// The OpenMetrics text format `prometheus-client` writes, served to scrapers
/// that ask for it (Prometheus does).
const OPENMETRICS: &str = "application/openmetrics-text; version=1.0.0; charset=utf-8";
/// The Prometheus text format, served to every other client.
const PROMETHEUS_TEXT: &str = "text/plain; version=0.0.4; charset=utf-8";

/// The exporter: readers of every watched service's status, the registry, and
/// the HTTP server.
pub struct ExporterStage {
    table: Arc<Table>,
    readers: Vec<StatusSubscriber>,
    registry: Registry,
    scrapes: Counter,
    server: Server,
    listen: SocketAddr,
}

/// Runs the exporter on `ctx`'s site until it is asked to stop.
pub fn run(ctx: ServiceContext) -> Result<(), Fatal> {
    let mut exporter = ExporterStage::open(&ctx.ipc, &ctx.config)?;
    stage::run(&ctx.ipc, "", &mut exporter, &())
}

/// The services of `loaded`'s site the exporter watches: every pipeline stage of
/// every camera, the site-wide ones once, and the MQTT sink when `[mqtt]` is
/// configured.
pub fn watched(loaded: &LoadedConfig) -> Vec<Service> {
    let mut services = Vec::new();
    let optional = loaded.config.mqtt.is_some().then_some(StageKind::Mqtt);
    for stage in StageKind::ALL.into_iter().chain(optional) {
        let cameras: Vec<String> = if stage.per_camera() {
            loaded.config.cameras.iter().map(|c| c.id.clone()).collect()
        } else {
            vec![String::new()]
        };
        services.extend(cameras.into_iter().map(|camera| Service {
            stage,
            camera,
            status: None,
        }));
    }
    services
}

impl ExporterStage {
    /// Subscribes to every watched service's status and listens on `[exporter]
    /// listen` (defaults without the section). An address that cannot be bound
    /// (in use, not on this machine, a privileged port) is a configuration error.
    pub fn open(ipc: &Ipc, loaded: &LoadedConfig) -> Result<Self, Fatal> {
        let config = loaded.config.exporter.clone().unwrap_or_default();
        let listen = config.listen_addr().map_err(|e| {
            Fatal::new(
                exit::CONFIG,
                format!("{}: key `{}`: {}", loaded.path.display(), e.key, e.message),
            )
        })?;
        let server = bind(listen, &config, loaded)?;
        let services = watched(loaded);
        let mut readers = Vec::with_capacity(services.len());
        for s in &services {
            readers.push(ipc.status_subscriber(&s.camera, s.stage)?);
        }
        let table = Table::new(services, Duration::from_secs_f64(config.stale_after_s));
        let mut registry = Registry::default();
        let scrapes = Counter::default();
        registry.register(
            "isochron_exporter_scrapes",
            "Scrapes of /metrics this exporter answered",
            scrapes.clone(),
        );
        registry.register_collector(Box::new(StatusCollector::new(table.clone())));
        tracing::info!(
            "serving the metrics of {} services at http://{listen}/metrics",
            readers.len()
        );
        Ok(ExporterStage {
            table,
            readers,
            registry,
            scrapes,
            server,
            listen,
        })
    }

    /// The address it listens on.
    pub fn listen(&self) -> SocketAddr {
        self.listen
    }

    /// Answers one request: the metrics at `/metrics`, a pointer to them at `/`.
    fn answer(&mut self, request: Request, cx: &mut Context) {
        let arrived = Instant::now();
        let path = request.url().split('?').next().unwrap_or("");
        let response = match (request.method(), path) {
            (Method::Get, "/metrics") => {
                self.scrapes.inc();
                let openmetrics = request.headers().iter().any(|h| {
                    h.field.equiv("Accept")
                        && h.value.as_str().contains("application/openmetrics-text")
                });
                let mut body = String::new();
                match prometheus_client::encoding::text::encode(&mut body, &self.registry) {
                    Ok(()) if openmetrics => text(200, body, OPENMETRICS),
                    Ok(()) => text(200, classic_text(&body), PROMETHEUS_TEXT),
                    Err(e) => text(
                        500,
                        format!("encoding the metrics failed: {e}\n"),
                        "text/plain",
                    ),
                }
            }
            (Method::Get, "/") => text(
                200,
                "isochron-exporter: the metrics are at /metrics\n".into(),
                "text/plain; charset=utf-8",
            ),
            (Method::Get, _) => text(404, "not found: try /metrics\n".into(), "text/plain"),
            _ => text(405, "only GET\n".into(), "text/plain"),
        };
        if let Err(e) = request.respond(response) {
            cx.warnings
                .warn("respond", || format!("answering a scrape failed: {e}"));
        }
        cx.health.sent(Some(arrived), 0);
    }
}

/// A text response with `status` and `content_type`.
fn text(status: u16, body: String, content_type: &str) -> Response<std::io::Cursor<Vec<u8>>> {
    let header = Header::from_bytes("Content-Type", content_type).expect("a valid header");
    Response::from_string(body)
        .with_status_code(status)
        .with_header(header)
}

/// Listens on `listen`; a failure is one line naming the key, the address and
/// what to do.
fn bind(
    listen: SocketAddr,
    config: &ExporterConfig,
    loaded: &LoadedConfig,
) -> Result<Server, Fatal> {
    let listener = TcpListener::bind(listen).map_err(|e| {
        let hint = match e.kind() {
            std::io::ErrorKind::AddrInUse => {
                "; another process listens there: stop it, or choose another port"
            }
            std::io::ErrorKind::AddrNotAvailable => "; expected an address of this machine",
            std::io::ErrorKind::PermissionDenied => "; ports below 1024 need privileges: use 9464",
            _ => "",
        };
        Fatal::new(
            exit::CONFIG,
            format!(
                "{}: key `exporter.listen`: cannot listen on {}: {e}{hint}",
                loaded.path.display(),
                config.listen
            ),
        )
    })?;
    Server::from_listener(listener, None).map_err(|e| {
        Fatal::new(
            exit::UNAVAILABLE,
            format!("starting the HTTP server on {listen}: {e}"),
        )
    })
}

impl Stage for ExporterStage {
    type Inputs = ();
    const KIND: StageKind = StageKind::Exporter;

    fn on_wake(&mut self, _: &(), _: &Woken, _: &mut Context) -> Result<(), Fatal> {
        Ok(())
    }

    fn on_tick(&mut self, cx: &mut Context) -> Result<(), Fatal> {
        for (k, reader) in self.readers.iter().enumerate() {
            if let Some(status) = reader.latest() {
                if status.validate().is_ok() {
                    cx.health.read_one();
                    self.table.update(k, status);
                } else {
                    cx.health.rejected();
                }
            }
        }
        while let Ok(Some(request)) = self.server.try_recv() {
            self.answer(request, cx);
        }
        Ok(())
    }

    fn timer(&self) -> Duration {
        TICK
    }

    fn detail(&self) -> String {
        let (up, watched) = self.table.count_up(wall_now_ns());
        format!(
            "listen={} scrapes={} up={up}/{watched}",
            self.listen,
            self.scrapes.get()
        )
    }
}
