//! The exporter's stage: on every tick (100 ms) it takes the latest status report
//! of every watched service into the [`Table`] that the metrics are made from at
//! each scrape. The HTTP server ([`crate::http`]) answers scrapes on its own
//! thread, within the `[exporter]` bounds.
//!
//! It watches every pipeline stage of every configured camera, and the site-wide
//! costmap, whether or not they run: a service that never reported is `up` 0.
//!
//! The exporter is not a pipeline stage (not in `StageKind::ALL`): `isochron up`
//! starts it only when the config has `[exporter]` (`launch::optional_services`),
//! and `isochron replay` goes on if it fails. `isochron status` and `doctor` show
//! its row (and the link's when `[link]` exports or imports a camera) next to the
//! pipeline's (`status::expected_stages`).

use std::net::{SocketAddr, TcpListener};
use std::sync::Arc;
use std::time::Duration;

use isochron_config::clock::wall_now_ns;
use isochron_config::{ExporterConfig, LoadedConfig};
use isochron_exit::{self as exit, Fatal};
use isochron_runtime::ipc::{Ipc, StatusSubscriber};
use isochron_runtime::service::ServiceContext;
use isochron_runtime::stage::{self, Context, Stage, Woken};
use isochron_runtime::topology::StageKind;
use prometheus_client::registry::Registry;

use crate::http::{HttpMetrics, Limits, Server};
use crate::metrics::{Service, StatusCollector, Table};

/// How often reports are read into the table.
const TICK: Duration = Duration::from_millis(100);

/// The exporter: readers of every watched service's status, and the HTTP server.
pub struct ExporterStage {
    table: Arc<Table>,
    readers: Vec<StatusSubscriber>,
    http: HttpMetrics,
    answered_reported: u64,
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
        let listener = bind(listen, &config, loaded)?;
        let services = watched(loaded);
        let mut readers = Vec::with_capacity(services.len());
        for s in &services {
            readers.push(ipc.status_subscriber(&s.camera, s.stage)?);
        }
        let table = Table::new(services, Duration::from_secs_f64(config.stale_after_s));
        let mut registry = Registry::default();
        let http = HttpMetrics::default();
        http.register(&mut registry);
        registry.register_collector(Box::new(StatusCollector::new(table.clone())));
        let limits = Limits {
            max_connections: config.max_connections,
            max_header_bytes: config.max_header_bytes,
            request_timeout: Duration::from_secs_f64(config.request_timeout_s),
        };
        let server =
            Server::start(listener, limits, Arc::new(registry), http.clone()).map_err(|e| {
                Fatal::new(
                    exit::UNAVAILABLE,
                    format!("starting the HTTP server on {listen}: {e}"),
                )
            })?;
        tracing::info!(
            "serving the metrics of {} services at http://{listen}/metrics (at most {} connections, {} B request heads, {} s per request)",
            readers.len(),
            limits.max_connections,
            limits.max_header_bytes,
            config.request_timeout_s
        );
        Ok(ExporterStage {
            table,
            readers,
            http,
            answered_reported: 0,
            server,
            listen,
        })
    }

    /// The address it listens on.
    pub fn listen(&self) -> SocketAddr {
        self.listen
    }
}

/// Listens on `listen`; a failure is one line naming the key, the address and
/// what to do.
fn bind(
    listen: SocketAddr,
    config: &ExporterConfig,
    loaded: &LoadedConfig,
) -> Result<TcpListener, Fatal> {
    TcpListener::bind(listen).map_err(|e| {
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
        if !self.server.is_running() {
            return Err(Fatal::new(
                exit::UNAVAILABLE,
                format!("the HTTP server on {} stopped", self.listen),
            ));
        }
        let answered = self.http.answered();
        for _ in self.answered_reported..answered {
            cx.health.sent(None, 0);
        }
        self.answered_reported = answered;
        Ok(())
    }

    fn on_stop(&mut self, _: &mut Context) -> Result<(), Fatal> {
        self.server.stop();
        Ok(())
    }

    fn timer(&self) -> Duration {
        TICK
    }

    fn detail(&self) -> String {
        let (up, watched) = self.table.count_up(wall_now_ns());
        format!(
            "listen={} scrapes={} up={up}/{watched} connections={} refused={}",
            self.listen,
            self.http.scrapes.get(),
            self.http.connections.get(),
            self.http.refused_total()
        )
    }
}
