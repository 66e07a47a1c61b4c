//! The live view: the site's channels over the Foxglove WebSocket protocol, for
//! any client that speaks it, at a bounded cost per client and in total.
//!
//! The view serves every client itself, inside its process: each client is a
//! [`Session`], a sink of the view's `foxglove` [`Context`] that encodes with the
//! crate's protocol types straight into the client's [`Outbox`]. There is no
//! internal port: nothing but the view's own address, on which
//!
//! * at most `view.max_clients` clients are served at once (counted from the
//!   accepted connection, handshake included); one more is answered HTTP 503,
//!   warned about (rate-limited) and counted (`refused_clients`);
//! * it negotiates the subprotocol: `foxglove.sdk.v1.1`, `foxglove.sdk.v1`, or
//!   `foxglove.websocket.v1`, the name of the same protocol that
//!   `@foxglove/ws-protocol`'s `FoxgloveClient` (Lichtblick, older Foxglove
//!   Studio) asks for (preferred in that order); anything else gets HTTP 400;
//! * every message for a client goes to its [`Outbox`], bounded in bytes
//!   (`view.client_budget_mib`): message data is dropped oldest first when the
//!   client reads more slowly than the site publishes;
//! * every outbox is in one [`Pool`], bounded over all clients
//!   (`view.memory_budget_mib`): over it, the clients holding the most message
//!   data lose their oldest first;
//! * a client losing messages (over either budget) that takes nothing for
//!   `view.client_stall_s` is disconnected (its socket reset, so that the kernel
//!   lets go of what it held for it). Warnings are rate-limited and never carry a
//!   payload.
//!
//! The group never waits for a client: the stage hands each message to every
//! subscribed session, which queues it and returns.
//!
//! Why not the crate's own server: it (0.30.3, `src/websocket/handshake.rs`)
//! answers any other subprotocol with HTTP 400, has no option for other names and
//! no way to hand it an accepted connection, queues up to 1 024 messages per
//! client whatever their size, never disconnects a client that reads nothing (the
//! stalled-client test, run against the crate's server alone, saw the view grow by
//! 351 MiB in 21 s on a 1 MiB-per-message grid), and has no client limit. An
//! earlier view put a front door before it and relayed each client over an
//! internal loopback port, which any local process could use past every limit,
//! unseen in the view's status. The price of the sessions: they implement the
//! part of the protocol the view offers (channels; no client publishing,
//! services or parameters) on the crate's `Sink` trait, public but hidden ("until
//! Sink is public").

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use foxglove::Context;
use futures_util::{SinkExt, StreamExt};
use isochron_config::ViewConfig;
use isochron_runtime::stage::Warnings;
use parking_lot::Mutex;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::watch;
use tokio_tungstenite::WebSocketStream;
use tokio_tungstenite::tungstenite::handshake::server::{ErrorResponse, Request, Response};
use tokio_tungstenite::tungstenite::http::{HeaderValue, StatusCode};
use tokio_tungstenite::tungstenite::protocol::WebSocketConfig;
use tokio_tungstenite::tungstenite::{self, Message};

use crate::outbox::{Drops, Outbox, Pool};
use crate::session::{Report, Session};

/// The subprotocols a client may ask for, in the order the view prefers them,
/// each with the name the `foxglove` crate knows it under.
pub const SUBPROTOCOLS: [(&str, &str); 3] = [
    ("foxglove.sdk.v1.1", "foxglove.sdk.v1.1"),
    ("foxglove.sdk.v1", "foxglove.sdk.v1"),
    ("foxglove.websocket.v1", "foxglove.sdk.v1"),
];

/// How long a client has for its WebSocket handshake.
const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);

/// How long a refused client has to send its request and take the answer.
const REFUSAL_TIMEOUT: Duration = Duration::from_secs(2);

/// Largest message a client may send (subscriptions and the like are small; the
/// view takes no client data).
const MAX_CLIENT_MESSAGE: usize = 1 << 20;

/// How long a closing handshake may take before the socket is simply dropped.
const CLOSE_TIMEOUT: Duration = Duration::from_secs(1);

/// Why the server did not start.
#[derive(Debug, thiserror::Error)]
pub enum LiveError {
    /// The address cannot be listened on (in use, not local, no permission).
    #[error("--listen {addr}: {error}")]
    Bind {
        /// The address.
        addr: SocketAddr,
        /// Why.
        error: std::io::Error,
    },
    /// The server's threads could not be made.
    #[error("starting the Foxglove server on {addr}: {error}")]
    Runtime {
        /// The address.
        addr: SocketAddr,
        /// Why.
        error: std::io::Error,
    },
}

/// What clients may cost the view.
#[derive(Debug, Clone, Copy)]
pub struct ClientLimits {
    /// Bytes queued for one client at most (`view.client_budget_mib`).
    pub budget_bytes: usize,
    /// Bytes queued for every client together at most
    /// (`view.memory_budget_mib`).
    pub memory_budget_bytes: usize,
    /// Clients served at once at most (`view.max_clients`).
    pub max_clients: usize,
    /// Disconnected when losing messages and taking nothing this long
    /// (`view.client_stall_s`).
    pub stall: Duration,
}

impl ClientLimits {
    /// The limits `view` configures.
    pub fn of(view: &ViewConfig) -> ClientLimits {
        ClientLimits {
            budget_bytes: view.client_budget_bytes(),
            memory_budget_bytes: view.memory_budget_bytes(),
            max_clients: view.max_clients as usize,
            stall: isochron_config::clock::saturating_secs(view.client_stall_s),
        }
    }
}

/// Counters over every client, for the view's status.
#[derive(Debug, Default)]
pub struct ClientStats {
    /// Clients served now (from the accepted connection, handshake included).
    pub connected: AtomicUsize,
    /// Clients refused so far, because `view.max_clients` were served.
    pub refused: AtomicU64,
    /// Messages dropped for slow clients so far.
    pub dropped: AtomicU64,
    /// Clients disconnected for stalling so far.
    pub stalled: AtomicU64,
}

/// The running live view: the listener, the clients, and the threads they run on.
pub struct LiveServer {
    runtime: tokio::runtime::Runtime,
    stop: watch::Sender<bool>,
    stats: Arc<ClientStats>,
    pool: Arc<Pool<Message>>,
}

impl LiveServer {
    /// Counters over every client.
    pub fn stats(&self) -> &ClientStats {
        &self.stats
    }

    /// Bytes queued for every client now.
    pub fn queued_bytes(&self) -> usize {
        self.pool.queued_bytes()
    }

    /// Stops accepting, closes every client, and stops the threads (waiting at
    /// most a second for them).
    pub fn stop(self) {
        let _ = self.stop.send(true);
        self.runtime.shutdown_timeout(CLOSE_TIMEOUT);
    }
}

/// Starts the live view for `ctx`'s channels on `addr`, named `name` in
/// `serverInfo`, its clients held to `limits`.
pub fn serve(
    ctx: &Arc<Context>,
    addr: SocketAddr,
    name: &str,
    limits: ClientLimits,
) -> Result<LiveServer, LiveError> {
    let listener = std::net::TcpListener::bind(addr)
        .and_then(|l| l.set_nonblocking(true).map(|()| l))
        .map_err(|error| LiveError::Bind { addr, error })?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("isochron-view-ws")
        .enable_all()
        .build()
        .map_err(|error| LiveError::Runtime { addr, error })?;
    let listener = {
        let _guard = runtime.enter();
        TcpListener::from_std(listener).map_err(|error| LiveError::Bind { addr, error })?
    };
    let (stop, stopped) = watch::channel(false);
    let stats = Arc::new(ClientStats::default());
    let pool = Pool::new(limits.memory_budget_bytes);
    let door = FrontDoor {
        ctx: ctx.clone(),
        name: name.into(),
        limits,
        stats: stats.clone(),
        pool: pool.clone(),
        warnings: Arc::new(Mutex::new(Warnings::default())),
        stopped,
    };
    runtime.spawn(door.accept(listener));
    Ok(LiveServer {
        runtime,
        stop,
        stats,
        pool,
    })
}

/// Picks the subprotocol from the `Sec-WebSocket-Protocol` values a client
/// offered (each a comma-separated list): the first of [`SUBPROTOCOLS`] among
/// them, the names compared exactly, or `None`.
pub fn negotiate(offered: &[&str]) -> Option<(&'static str, &'static str)> {
    SUBPROTOCOLS.into_iter().find(|(name, _)| {
        offered
            .iter()
            .flat_map(|v| v.split(','))
            .any(|o| o.trim() == *name)
    })
}

/// The view's listening side: admits clients and serves each one a [`Session`].
#[derive(Clone)]
struct FrontDoor {
    ctx: Arc<Context>,
    /// The server's name in `serverInfo`.
    name: Arc<str>,
    limits: ClientLimits,
    stats: Arc<ClientStats>,
    pool: Arc<Pool<Message>>,
    /// Rate-limited warnings, shared by every client.
    warnings: Arc<Mutex<Warnings>>,
    stopped: watch::Receiver<bool>,
}

/// How a client's connection ended.
enum End {
    /// The client closed the connection (or it broke).
    ClientLeft,
    /// The view is stopping.
    ServerClosed,
    /// Losing messages, the client took nothing for this long.
    Stalled(Duration),
}

/// A client's place among `view.max_clients`, given back when dropped.
struct Slot(Arc<ClientStats>);

impl Drop for Slot {
    fn drop(&mut self) {
        self.0.connected.fetch_sub(1, Ordering::Relaxed);
    }
}

/// What sessions report, into the view's counters and warnings.
struct Reporter {
    stats: Arc<ClientStats>,
    warnings: Arc<Mutex<Warnings>>,
    budget_mib: f64,
}

impl Report for Reporter {
    fn dropped(&self, dropped: usize) {
        self.stats
            .dropped
            .fetch_add(dropped as u64, Ordering::Relaxed);
    }

    fn first_time_over(&self, peer: SocketAddr) {
        let mib = self.budget_mib;
        self.warnings.lock().warn("slow", || {
            format!(
                "view: client {peer} reads more slowly than the site publishes: dropping its oldest messages (over view.client_budget_mib = {mib})"
            )
        });
    }
}

impl FrontDoor {
    fn warn(&self, kind: &'static str, message: impl FnOnce() -> String) {
        self.warnings.lock().warn(kind, message);
    }

    /// Accepts clients until the view stops.
    async fn accept(self, listener: TcpListener) {
        let mut stopped = self.stopped.clone();
        loop {
            tokio::select! {
                _ = stopped.changed() => return,
                accepted = listener.accept() => match accepted {
                    Ok((stream, peer)) => match self.admit() {
                        Some(slot) => {
                            tokio::spawn(self.clone().client(stream, peer, slot));
                        }
                        None => {
                            tokio::spawn(self.clone().refuse(stream, peer));
                        }
                    },
                    Err(error) => {
                        // Out of file descriptors, most likely: wait a little.
                        self.warn("accept", || format!("view: accepting a client: {error}"));
                        tokio::time::sleep(Duration::from_millis(100)).await;
                    }
                },
            }
        }
    }

    /// A slot for one more client, unless `view.max_clients` are served.
    fn admit(&self) -> Option<Slot> {
        let max = self.limits.max_clients;
        self.stats
            .connected
            .fetch_update(Ordering::Relaxed, Ordering::Relaxed, |n| {
                (n < max).then_some(n + 1)
            })
            .ok()
            .map(|_| Slot(self.stats.clone()))
    }

    /// Answers a client beyond `view.max_clients` with HTTP 503, and counts it.
    async fn refuse(self, stream: TcpStream, peer: SocketAddr) {
        let n = self.stats.refused.fetch_add(1, Ordering::Relaxed) + 1;
        let max = self.limits.max_clients;
        self.warn("refused", || {
            format!(
                "view: client {peer} refused (HTTP 503): {max} clients already (view.max_clients); {n} refused so far"
            )
        });
        #[allow(clippy::result_large_err, reason = "tungstenite's callback type")]
        let busy = |_: &Request, _: Response| -> Result<Response, ErrorResponse> {
            let mut response = ErrorResponse::new(Some(format!(
                "the view serves at most {max} clients (view.max_clients)"
            )));
            *response.status_mut() = StatusCode::SERVICE_UNAVAILABLE;
            Err(response)
        };
        let answer = tokio_tungstenite::accept_hdr_async(stream, busy);
        let _ = tokio::time::timeout(REFUSAL_TIMEOUT, answer).await;
    }

    /// Serves one client from its TCP connection to its end.
    async fn client(self, stream: TcpStream, peer: SocketAddr, _slot: Slot) {
        let _ = stream.set_nodelay(true);
        let Some((outer, offered, spoken)) = self.handshake(stream, peer).await else {
            return;
        };
        tracing::info!("view: client {peer} connected ({offered})");
        let (end, drops) = self.serve_client(outer, spoken, peer).await;
        let budget_mib = self.limits.budget_bytes as f64 / (1u64 << 20) as f64;
        match end {
            End::Stalled(took) => {
                self.stats.stalled.fetch_add(1, Ordering::Relaxed);
                self.warn("stalled", || {
                    format!(
                        "view: client {peer} disconnected: over its budget (view.client_budget_mib = {budget_mib}, view.memory_budget_mib for all) and taking nothing for {:.0} s; {} messages ({} bytes) dropped for it",
                        took.as_secs_f64(),
                        drops.messages,
                        drops.bytes
                    )
                });
            }
            End::ClientLeft | End::ServerClosed => {
                tracing::info!(
                    "view: client {peer} left; {} messages ({} bytes) dropped for it",
                    drops.messages,
                    drops.bytes
                );
            }
        }
    }

    /// The WebSocket handshake: the connection, and the subprotocol agreed (its
    /// name, the crate's name for it); `None` (warned) if it failed.
    async fn handshake(
        &self,
        stream: TcpStream,
        peer: SocketAddr,
    ) -> Option<(WebSocketStream<TcpStream>, &'static str, &'static str)> {
        let mut agreed = None;
        let config = WebSocketConfig::default()
            .read_buffer_size(16 << 10)
            .max_message_size(Some(MAX_CLIENT_MESSAGE))
            .max_frame_size(Some(MAX_CLIENT_MESSAGE));
        // The error type is tungstenite's, for the callback it takes.
        #[allow(clippy::result_large_err, reason = "tungstenite's callback type")]
        let choose = |request: &Request, mut response: Response| {
            let offered: Vec<&str> = request
                .headers()
                .get_all("sec-websocket-protocol")
                .iter()
                .filter_map(|v| v.to_str().ok())
                .collect();
            match negotiate(&offered) {
                Some(pair) => {
                    response
                        .headers_mut()
                        .insert("sec-websocket-protocol", HeaderValue::from_static(pair.0));
                    agreed = Some(pair);
                    Ok(response)
                }
                None => Err(refusal()),
            }
        };
        let handshake =
            tokio_tungstenite::accept_hdr_async_with_config(stream, choose, Some(config));
        match tokio::time::timeout(HANDSHAKE_TIMEOUT, handshake).await {
            Ok(Ok(ws)) => agreed.map(|(offered, spoken)| (ws, offered, spoken)),
            Ok(Err(tungstenite::Error::Http(_))) => {
                // Only the subprotocol callback answers with an HTTP error.
                self.warn("handshake", || {
                    format!(
                        "view: client {peer} refused (HTTP 400): it offers none of the subprotocols {}",
                        subprotocol_names()
                    )
                });
                None
            }
            Ok(Err(error)) => {
                self.warn("handshake", || {
                    format!("view: client {peer} refused: WebSocket handshake failed: {error}")
                });
                None
            }
            Err(_) => {
                self.warn("handshake", || {
                    format!("view: client {peer} refused: no WebSocket handshake within {HANDSHAKE_TIMEOUT:?}")
                });
                None
            }
        }
    }

    /// Serves the client at `peer` over `ws` in `subprotocol` until it leaves,
    /// stalls, or the view stops.
    async fn serve_client(
        &self,
        ws: WebSocketStream<TcpStream>,
        subprotocol: &'static str,
        peer: SocketAddr,
    ) -> (End, Drops) {
        let outbox = Outbox::pooled(self.limits.budget_bytes, &self.pool);
        let report = Arc::new(Reporter {
            stats: self.stats.clone(),
            warnings: self.warnings.clone(),
            budget_mib: self.limits.budget_bytes as f64 / (1u64 << 20) as f64,
        });
        let session = Session::new(
            &self.ctx,
            &self.name,
            peer,
            subprotocol,
            outbox.clone(),
            report,
        );
        session.attach();
        let (mut to_client, mut from_client) = ws.split();
        let end = {
            // The outbox goes to the client as fast as it takes it.
            let write = async {
                loop {
                    let (msg, _) = outbox.next().await;
                    if to_client.send(msg).await.is_err() {
                        return End::ClientLeft;
                    }
                    outbox.taken();
                }
            };
            // What the client sends (subscriptions) goes to its session.
            let read = async {
                while let Some(Ok(msg)) = from_client.next().await {
                    match msg {
                        Message::Text(text) => session.on_client_text(text.as_str()),
                        Message::Close(_) => break,
                        Message::Binary(_) | Message::Ping(_) | Message::Pong(_) => {}
                        Message::Frame(_) => {}
                    }
                }
                End::ClientLeft
            };
            let stall = self.limits.stall;
            let watchdog = async {
                let mut tick = tokio::time::interval(stall.min(Duration::from_secs(1)));
                loop {
                    tick.tick().await;
                    if let Some(took) = outbox.stalled_for(Instant::now())
                        && took >= stall
                    {
                        return End::Stalled(took);
                    }
                }
            };
            let mut stopped = self.stopped.clone();
            let stopping = async {
                let _ = stopped.wait_for(|s| *s).await;
                End::ServerClosed
            };
            tokio::select! {
                end = write => end,
                end = read => end,
                end = watchdog => end,
                end = stopping => end,
            }
        };
        session.detach();
        let drops = outbox.drops();
        match end {
            End::Stalled(_) => {
                // Nothing more can reach it: reset the connection, so that the
                // kernel drops what it still holds for it too.
                if let Ok(ws) = to_client.reunite(from_client) {
                    let _ = ws.get_ref().set_zero_linger();
                }
            }
            End::ServerClosed => {
                // Whatever is queued, then the close, if the client takes them soon.
                let flush = async {
                    while let Some((msg, _)) = outbox.try_next() {
                        to_client.feed(msg).await?;
                    }
                    to_client.close().await
                };
                let _ = tokio::time::timeout(CLOSE_TIMEOUT, flush).await;
            }
            End::ClientLeft => {
                let _ = tokio::time::timeout(CLOSE_TIMEOUT, to_client.close()).await;
            }
        }
        (end, drops)
    }
}

/// The names of [`SUBPROTOCOLS`], comma-separated.
fn subprotocol_names() -> String {
    let names: Vec<&str> = SUBPROTOCOLS.iter().map(|(n, _)| *n).collect();
    names.join(", ")
}

/// The answer to a client that offered none of [`SUBPROTOCOLS`].
fn refusal() -> ErrorResponse {
    let mut response = ErrorResponse::new(Some(format!(
        "expected a Sec-WebSocket-Protocol header offering {}",
        subprotocol_names()
    )));
    *response.status_mut() = StatusCode::BAD_REQUEST;
    response
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_name_of_the_protocol_is_accepted_newest_first() {
        assert_eq!(
            negotiate(&["foxglove.websocket.v1"]),
            Some(("foxglove.websocket.v1", "foxglove.sdk.v1"))
        );
        assert_eq!(
            negotiate(&["foxglove.sdk.v1"]),
            Some(("foxglove.sdk.v1", "foxglove.sdk.v1"))
        );
        // Offered in one header or several, in any order: the newest wins.
        assert_eq!(
            negotiate(&["foxglove.websocket.v1, foxglove.sdk.v1.1"]),
            Some(("foxglove.sdk.v1.1", "foxglove.sdk.v1.1"))
        );
        assert_eq!(
            negotiate(&["foxglove.websocket.v1", "foxglove.sdk.v1"]),
            Some(("foxglove.sdk.v1", "foxglove.sdk.v1"))
        );
        // Exact names only.
        assert_eq!(negotiate(&["foxglove.websocket"]), None);
        assert_eq!(negotiate(&["foxglove.sdk.v2", "x"]), None);
        assert_eq!(negotiate(&[]), None);
    }
}
