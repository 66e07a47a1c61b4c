//! The exporter's stage: on every tick (100 ms) it takes the latest status report
//! of every watched service into the [`Table`] that the metrics are made from at
//! each scrape. The HTTP server ([`crate::http`]) answers scrapes on its own
//! thread, within the `[exporter]` bounds.
//!
//! It watches every service `isochron up` runs for the config (the stage table's
//! `StageKind::started`), and the stages of the cameras `[link]` imports,
//! whether or not they run: a service that never reported is `up` 0.

use std::net::{SocketAddr, TcpListener};
use std::sync::Arc;
use std::time::Duration;

use isochron_config::clock::wall_now_ns;
use isochron_config::{ExporterConfig, LoadedConfig};
use isochron_exit::{self as exit, Fatal};
use isochron_runtime::counters::{Counters, exporter};
use isochron_runtime::ipc::{Ipc, StatusSubscriber};
use isochron_runtime::service::ServiceContext;
use isochron_runtime::stage::{self, Context, Stage};
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

/// The services of `loaded`'s site the exporter watches: every service `isochron
/// up` runs for it, and the stages of the cameras `[link]` imports (their remote
/// status, as the link relays it: their liveness is the remote box's).
pub fn watched(loaded: &LoadedConfig) -> Vec<Service> {
    let config = &loaded.config;
    StageKind::services_of(StageKind::started(config), config)
        .into_iter()
        .map(|(stage, camera)| Service {
            stage,
            camera,
            status: None,
        })
        .collect()
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
        let table = Table::new(
            services,
            isochron_config::clock::saturating_secs(config.stale_after_s),
        );
        let mut registry = Registry::default();
        let http = HttpMetrics::default();
        http.register(&mut registry);
        registry.register_collector(Box::new(StatusCollector::new(table.clone())));
        let limits = Limits {
            max_connections: config.max_connections,
            max_header_bytes: config.max_header_bytes,
            request_timeout: isochron_config::clock::saturating_secs(config.request_timeout_s),
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

    fn on_wake(&mut self, _: &(), _: &mut Context) -> Result<(), Fatal> {
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

    fn counters(&self, c: &mut Counters) {
        let (up, watched) = self.table.count_up(wall_now_ns());
        c.set(exporter::SCRAPES, self.http.scrapes.get());
        c.set(exporter::UP, up);
        c.set(exporter::WATCHED, watched);
        c.set(exporter::CONNECTIONS, self.http.connections.get());
        c.set(exporter::REFUSED, self.http.refused_total());
    }

    fn info(&self) -> String {
        format!("listen={}", self.listen)
    }
}
