//! The exporter's HTTP server: `GET /metrics` (and a pointer to it at `/`) on
//! one thread of its own, where a current-thread tokio runtime runs hyper's
//! HTTP/1.1 for every connection. What one client can hold is bounded:
//!
//! * **connections**: at most [`Limits::max_connections`] open. At the limit, a
//!   new connection closes the oldest one that has not yet sent a complete
//!   request head (idle or slow: the cheap way to fill the slots), so a scraper
//!   is still served while thousands of idle connections arrive; when every open
//!   connection is being answered, the newcomer gets `503` and is closed;
//! * **request head**: at most [`Limits::max_header_bytes`] (request line and
//!   headers; hyper's read buffer stops there) — a larger one gets `431` and the
//!   connection is closed;
//! * **time**: a connection serves one request (no keep-alive) and must send it
//!   and take the whole answer within [`Limits::request_timeout`] (hyper's
//!   header read timeout, and one deadline around the connection), so idle,
//!   slowloris and slow-reading clients are closed;
//! * **threads**: one, whatever the number of connections.
//!
//! Each refusal is counted by reason in `isochron_exporter_http_refused_total`;
//! `isochron_exporter_http_connections` is the number open.
//!
//! Memory is about `max_connections` × (`max_header_bytes` + hyper's state + one
//! encoded scrape). A failed `accept` (out of file descriptors) pauses 100 ms,
//! warned at most once a minute; if the HTTP thread ever ended, the stage's next
//! tick exits 69 (restarted by systemd).
//!
//! Why hyper: the exporter used `tiny_http`, which has none of these bounds — no
//! head limit (4 × 400 MiB of headers grew it by 1.66 GB), a thread per connection
//! (3 000 idle connections, 2 989 threads) and no timeouts — and no hook to add
//! them (it owns the accept loop). hyper is the maintained HTTP implementation of
//! the tokio project, and has the three knobs the bounds need (`max_header_size`
//! answering 431, `header_read_timeout`, `keep_alive(false)`); tokio is already in
//! the tree (the view, the MQTT sink), so it adds hyper, hyper-util (its tokio
//! adapters), http-body(-util) and atomic-waker. A hand-written server on
//! `httparse` would be less code to compile but more to keep right.

use std::collections::VecDeque;
use std::convert::Infallible;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use bytes::Bytes;
use http_body_util::Full;
use hyper::body::Incoming;
use hyper::header::{ACCEPT, CONTENT_TYPE, HeaderValue};
use hyper::server::conn::http1;
use hyper::service::service_fn;
use hyper::{Method, Request, Response, StatusCode};
use hyper_util::rt::{TokioIo, TokioTimer};
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::registry::Registry;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::Notify;

use crate::metrics::classic_text;

/// The OpenMetrics text format `prometheus-client` writes, served to scrapers
/// that ask for it (Prometheus does).
const OPENMETRICS: &str = "application/openmetrics-text; version=1.0.0; charset=utf-8";
/// The Prometheus text format, served to every other client.
const PROMETHEUS_TEXT: &str = "text/plain; version=0.0.4; charset=utf-8";
/// What a connection beyond the limit gets, written without reading its request.
const BUSY: &[u8] = b"HTTP/1.1 503 Service Unavailable\r\ncontent-type: text/plain\r\ncontent-length: 38\r\nretry-after: 1\r\nconnection: close\r\n\r\nisochron-exporter: too many clients\r\n\r\n";
/// How long the accept loop pauses after a failed accept (e.g. out of file
/// descriptors), so that it never spins.
const ACCEPT_PAUSE: Duration = Duration::from_millis(100);
/// At most one warning about failed accepts per this long.
const ACCEPT_WARN_EVERY: Duration = Duration::from_secs(60);

/// The bounds of the server, from `[exporter]`.
#[derive(Debug, Clone, Copy)]
pub struct Limits {
    /// Connections open at once.
    pub max_connections: usize,
    /// Largest request head, bytes.
    pub max_header_bytes: usize,
    /// Time for a connection's request and answer.
    pub request_timeout: Duration,
}

/// Why a connection was refused or closed early (the `reason` label).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refusal {
    /// Over the connection limit while every open connection was being answered: 503.
    Busy,
    /// Closed at the connection limit to make room: it had not sent a complete
    /// request head.
    Evicted,
    /// A request head larger than the limit: 431.
    HeaderSize,
    /// The request or its answer took longer than the request timeout.
    Timeout,
    /// Not HTTP/1.1 that hyper could parse: 400.
    BadRequest,
}

impl Refusal {
    /// Every reason, for the counters to start at 0.
    pub const ALL: [Refusal; 5] = [
        Refusal::Busy,
        Refusal::Evicted,
        Refusal::HeaderSize,
        Refusal::Timeout,
        Refusal::BadRequest,
    ];

    /// Its label value.
    pub fn name(self) -> &'static str {
        match self {
            Refusal::Busy => "busy",
            Refusal::Evicted => "evicted",
            Refusal::HeaderSize => "header_size",
            Refusal::Timeout => "timeout",
            Refusal::BadRequest => "bad_request",
        }
    }
}

/// The server's own metrics, registered in the exporter's registry.
#[derive(Debug, Clone, Default)]
pub struct HttpMetrics {
    /// Scrapes of `/metrics` answered.
    pub scrapes: Counter,
    /// Connections refused or closed early, by reason.
    pub refused: Family<[(&'static str, &'static str); 1], Counter>,
    /// Connections open now.
    pub connections: Gauge,
    /// Requests answered (any path), for the stage's `sent`.
    answered: Arc<AtomicU64>,
}

impl HttpMetrics {
    /// Registers the metrics in `registry` (every refusal reason at 0).
    pub fn register(&self, registry: &mut Registry) {
        registry.register(
            "isochron_exporter_scrapes",
            "Scrapes of /metrics this exporter answered",
            self.scrapes.clone(),
        );
        for r in Refusal::ALL {
            let _ = self.refused.get_or_create(&[("reason", r.name())]);
        }
        registry.register(
            "isochron_exporter_http_refused",
            "HTTP connections the exporter refused or closed early, by reason: busy (503 at the connection limit), evicted (closed at the limit before sending a request), header_size (431), timeout, bad_request (400)",
            self.refused.clone(),
        );
        registry.register(
            "isochron_exporter_http_connections",
            "HTTP connections open now",
            self.connections.clone(),
        );
    }

    /// Counts a refusal.
    pub fn refuse(&self, why: Refusal) {
        self.refused.get_or_create(&[("reason", why.name())]).inc();
    }

    /// Refusals so far, all reasons.
    pub fn refused_total(&self) -> u64 {
        Refusal::ALL
            .into_iter()
            .map(|r| self.refused.get_or_create(&[("reason", r.name())]).get())
            .sum()
    }

    /// Requests answered so far.
    pub fn answered(&self) -> u64 {
        self.answered.load(Ordering::Relaxed)
    }
}

/// The running server: its thread and how to stop it.
pub struct Server {
    stop: Arc<Notify>,
    thread: Option<JoinHandle<()>>,
}

impl Server {
    /// Serves `registry` on `listener` (already bound) within `limits`, on a
    /// thread of its own.
    pub fn start(
        listener: std::net::TcpListener,
        limits: Limits,
        registry: Arc<Registry>,
        metrics: HttpMetrics,
    ) -> std::io::Result<Server> {
        listener.set_nonblocking(true)?;
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()?;
        let stop = Arc::new(Notify::new());
        let stopped = stop.clone();
        let thread = std::thread::Builder::new()
            .name("exporter-http".into())
            .spawn(move || {
                runtime.block_on(async move {
                    match TcpListener::from_std(listener) {
                        Ok(listener) => {
                            let app = Arc::new(App { registry, metrics });
                            tokio::select! {
                                _ = accept_loop(listener, limits, app) => {}
                                _ = stopped.notified() => {}
                            }
                        }
                        Err(e) => tracing::error!("the HTTP server cannot use its socket: {e}"),
                    }
                });
            })?;
        Ok(Server {
            stop,
            thread: Some(thread),
        })
    }

    /// False once its thread has ended (it only ends when stopped, or if it
    /// panicked).
    pub fn is_running(&self) -> bool {
        self.thread.as_ref().is_some_and(|t| !t.is_finished())
    }

    /// Stops serving: open connections are closed.
    pub fn stop(&mut self) {
        self.stop.notify_one();
        if let Some(t) = self.thread.take()
            && t.join().is_err()
        {
            tracing::error!("the exporter's HTTP thread panicked");
        }
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.stop();
    }
}

/// What a connection's state is, seen by the accept loop.
#[derive(Debug, Default)]
struct Slot {
    /// A complete request head arrived: it is being answered.
    answering: AtomicBool,
    /// Asked to close to make room.
    evicted: AtomicBool,
    /// The connection ended.
    done: AtomicBool,
    wake: Notify,
}

impl Slot {
    fn evict(&self) {
        self.evicted.store(true, Ordering::Relaxed);
        self.wake.notify_one();
    }
}

/// Marks its slot done and counts the connection closed, however its task ends.
struct Open {
    slot: Arc<Slot>,
    metrics: HttpMetrics,
}

impl Drop for Open {
    fn drop(&mut self) {
        self.slot.done.store(true, Ordering::Relaxed);
        self.metrics.connections.dec();
    }
}

async fn accept_loop(listener: TcpListener, limits: Limits, app: Arc<App>) {
    // Open connections in the order they arrived.
    let mut slots: VecDeque<Arc<Slot>> = VecDeque::new();
    let mut last_warning: Option<Instant> = None;
    loop {
        let stream = match listener.accept().await {
            Ok((stream, _)) => stream,
            Err(e) => {
                if last_warning.is_none_or(|t| t.elapsed() >= ACCEPT_WARN_EVERY) {
                    tracing::warn!(
                        "accepting an HTTP connection failed: {e} ({} open); pausing {} ms",
                        slots.len(),
                        ACCEPT_PAUSE.as_millis()
                    );
                    last_warning = Some(Instant::now());
                }
                tokio::time::sleep(ACCEPT_PAUSE).await;
                continue;
            }
        };
        slots.retain(|s| !s.done.load(Ordering::Relaxed));
        let live = slots
            .iter()
            .filter(|s| !s.evicted.load(Ordering::Relaxed))
            .count();
        if live >= limits.max_connections {
            let waiting = slots.iter().find(|s| {
                !s.answering.load(Ordering::Relaxed) && !s.evicted.load(Ordering::Relaxed)
            });
            match waiting {
                Some(oldest) => {
                    oldest.evict();
                    app.metrics.refuse(Refusal::Evicted);
                    // Let it close before the next connection is accepted.
                    tokio::task::yield_now().await;
                }
                None => {
                    // A fresh socket's send buffer is empty: this never blocks.
                    let _ = stream.try_write(BUSY);
                    app.metrics.refuse(Refusal::Busy);
                    continue;
                }
            }
        }
        let slot = Arc::new(Slot::default());
        slots.push_back(slot.clone());
        app.metrics.connections.inc();
        let open = Open {
            slot,
            metrics: app.metrics.clone(),
        };
        tokio::spawn(serve(stream, open, limits, app.clone()));
    }
}

/// Serves one connection (one request) until it ends, times out or is evicted.
async fn serve(stream: TcpStream, open: Open, limits: Limits, app: Arc<App>) {
    let slot = open.slot.clone();
    let service = service_fn(|request: Request<Incoming>| {
        slot.answering.store(true, Ordering::Relaxed);
        let response = app.answer(&request);
        async move { Ok::<_, Infallible>(response) }
    });
    let connection = http1::Builder::new()
        .keep_alive(false)
        .max_header_size(limits.max_header_bytes)
        .max_buf_size(limits.max_header_bytes.max(8192))
        .timer(TokioTimer::new())
        .header_read_timeout(limits.request_timeout)
        .serve_connection(TokioIo::new(stream), service);
    let outcome = tokio::select! {
        r = connection => Some(r),
        _ = open.slot.wake.notified() => None, // evicted, counted by the accept loop
        _ = tokio::time::sleep(limits.request_timeout) => {
            app.metrics.refuse(Refusal::Timeout);
            None
        }
    };
    if let Some(Err(e)) = outcome {
        if e.is_parse_too_large() {
            app.metrics.refuse(Refusal::HeaderSize);
        } else if e.is_timeout() {
            app.metrics.refuse(Refusal::Timeout);
        } else if e.is_parse() {
            app.metrics.refuse(Refusal::BadRequest);
        }
        // Anything else is the client going away: not a refusal.
    }
}

/// What the connections share: the registry to encode and the metrics to count.
struct App {
    registry: Arc<Registry>,
    metrics: HttpMetrics,
}

impl App {
    /// The answer to `request`: the metrics at `/metrics`, a pointer to them at `/`.
    fn answer(&self, request: &Request<Incoming>) -> Response<Full<Bytes>> {
        let response = match (request.method(), request.uri().path()) {
            (&Method::GET, "/metrics") => {
                self.metrics.scrapes.inc();
                let openmetrics = request.headers().get_all(ACCEPT).iter().any(|v| {
                    v.to_str()
                        .is_ok_and(|v| v.contains("application/openmetrics-text"))
                });
                let mut body = String::new();
                match prometheus_client::encoding::text::encode(&mut body, &self.registry) {
                    Ok(()) if openmetrics => text(StatusCode::OK, body, OPENMETRICS),
                    Ok(()) => text(StatusCode::OK, classic_text(&body), PROMETHEUS_TEXT),
                    Err(e) => text(
                        StatusCode::INTERNAL_SERVER_ERROR,
                        format!("encoding the metrics failed: {e}\n"),
                        "text/plain",
                    ),
                }
            }
            (&Method::GET, "/") => text(
                StatusCode::OK,
                "isochron-exporter: the metrics are at /metrics\n".into(),
                "text/plain; charset=utf-8",
            ),
            (&Method::GET, _) => text(
                StatusCode::NOT_FOUND,
                "not found: try /metrics\n".into(),
                "text/plain",
            ),
            _ => text(
                StatusCode::METHOD_NOT_ALLOWED,
                "only GET\n".into(),
                "text/plain",
            ),
        };
        self.metrics.answered.fetch_add(1, Ordering::Relaxed);
        response
    }
}

/// A text response with `status` and `content_type`.
fn text(status: StatusCode, body: String, content_type: &'static str) -> Response<Full<Bytes>> {
    let mut response = Response::new(Full::new(Bytes::from(body)));
    *response.status_mut() = status;
    response
        .headers_mut()
        .insert(CONTENT_TYPE, HeaderValue::from_static(content_type));
    response
}
