//! The live view: the site's channels over the Foxglove WebSocket protocol, for
//! any client that speaks it, at a bounded cost per client.
//!
//! The `foxglove` crate's server implements the protocol, but accepts only the
//! subprotocol names `foxglove.sdk.v1` and `foxglove.sdk.v1.1`, and queues up to
//! 1 024 messages per client whatever their size. So it listens on an ephemeral
//! loopback port, and the view's own address is a front door:
//!
//! * it negotiates the subprotocol: `foxglove.sdk.v1.1`, `foxglove.sdk.v1`, or
//!   `foxglove.websocket.v1`, the name of the same protocol that
//!   `@foxglove/ws-protocol`'s `FoxgloveClient` (Lichtblick, older Foxglove
//!   Studio) asks for (preferred in that order); anything else gets HTTP 400;
//! * it connects to the crate's server for the client, with the crate's name for
//!   what was agreed (`foxglove.websocket.v1` is `foxglove.sdk.v1`: the same
//!   messages), and relays messages both ways unchanged;
//! * it reads the crate's side as fast as it comes, into the client's
//!   [`Outbox`], bounded in bytes (`view.client_budget_mib`): message data is
//!   dropped oldest first when the client reads more slowly than the site
//!   publishes, and a client over its budget that takes nothing for
//!   `view.client_stall_s` is disconnected (its socket reset, so that the
//!   kernel lets go of what it held for it). Warnings are rate-limited and never
//!   carry a payload.
//!
//! The group never waits for a client: the crate's server hands messages to the
//! relay, which never waits for the client.
//!
//! Why a front door rather than the crate's server alone: the crate's server
//! (0.30.3, `src/websocket/handshake.rs`) answers any other subprotocol with HTTP
//! 400, has no option for other names and no way to hand it an accepted
//! connection, and never disconnects a client that reads nothing (the
//! stalled-client test, run against the crate's server alone, saw the view grow by
//! 351 MiB in 21 s on a 1 MiB-per-message grid). The price: every message crosses
//! loopback once more (one extra WebSocket per client; measured with one client
//! taking 1 MiB cost maps at ~14 Hz: the view used 8.1–9.0 % of a core through the
//! relay, 8.4 % with the crate's server alone), and the internal port is reachable
//! by local processes, which would meet the crate's own 1 024-message backlog there
//! (never from the network, whatever `view.listen` says). A server of our own on
//! the crate's `Context` (its `Sink` trait is public but hidden, "until Sink is
//! public") would have saved the hop at the cost of re-implementing the protocol on
//! an unstable API; a byte-level proxy that only rewrote the header could not bound
//! bytes without parsing frames anyway.

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use foxglove::{Context, WebSocketServer, WebSocketServerHandle};
use futures_util::{SinkExt, StreamExt};
use isochron_config::ViewConfig;
use isochron_runtime::stage::Warnings;
use parking_lot::Mutex;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::watch;
use tokio_tungstenite::WebSocketStream;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::handshake::server::{ErrorResponse, Request, Response};
use tokio_tungstenite::tungstenite::http::{HeaderValue, StatusCode};
use tokio_tungstenite::tungstenite::protocol::WebSocketConfig;
use tokio_tungstenite::tungstenite::{self, Message};

use crate::outbox::{Drops, Outbox};

/// The subprotocols a client may ask for, in the order the view prefers them,
/// each with the name the `foxglove` crate's server speaks it under.
pub const SUBPROTOCOLS: [(&str, &str); 3] = [
    ("foxglove.sdk.v1.1", "foxglove.sdk.v1.1"),
    ("foxglove.sdk.v1", "foxglove.sdk.v1"),
    ("foxglove.websocket.v1", "foxglove.sdk.v1"),
];

/// Opcode of a binary server message that carries message data (the only kind
/// that may be dropped).
const MESSAGE_DATA: u8 = 0x01;

/// How long a client has for its WebSocket handshake.
const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);

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
    /// The server failed to start.
    #[error("starting the Foxglove server on {addr}: {error}")]
    Start {
        /// The address.
        addr: SocketAddr,
        /// Why.
        error: foxglove::FoxgloveError,
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

/// What one client may cost the view.
#[derive(Debug, Clone, Copy)]
pub struct ClientLimits {
    /// Bytes queued for it at most (`view.client_budget_mib`).
    pub budget_bytes: usize,
    /// Disconnected when over its budget and taking nothing this long
    /// (`view.client_stall_s`).
    pub stall: Duration,
}

impl ClientLimits {
    /// The limits `view` configures.
    pub fn of(view: &ViewConfig) -> ClientLimits {
        ClientLimits {
            budget_bytes: view.client_budget_bytes(),
            stall: Duration::from_secs_f64(view.client_stall_s),
        }
    }
}

/// Counters over every client, for the view's status.
#[derive(Debug, Default)]
pub struct ClientStats {
    /// Clients connected now.
    pub connected: AtomicUsize,
    /// Messages dropped for slow clients so far.
    pub dropped: AtomicU64,
    /// Clients disconnected for stalling so far.
    pub stalled: AtomicU64,
}

/// The running live view: the front door, the crate's server behind it, and the
/// threads they run on.
pub struct LiveServer {
    runtime: tokio::runtime::Runtime,
    crate_server: WebSocketServerHandle,
    stop: watch::Sender<bool>,
    stats: Arc<ClientStats>,
}

impl LiveServer {
    /// Counters over every client.
    pub fn stats(&self) -> &ClientStats {
        &self.stats
    }

    /// Stops accepting, closes every client, and stops the threads (waiting at
    /// most a second for them).
    pub fn stop(self) {
        let _ = self.stop.send(true);
        // The crate closes its side of every relay; the relays close their clients.
        self.crate_server.stop().detach_all();
        self.runtime.shutdown_timeout(CLOSE_TIMEOUT);
    }
}

/// Starts the live view for `ctx`'s channels on `addr`, named `name` in
/// `serverInfo`, each client held to `limits`.
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
    // Started inside the runtime, the crate's server runs on it.
    let crate_server = runtime
        .block_on(
            WebSocketServer::new()
                .name(name)
                .bind("127.0.0.1", 0)
                .context(ctx)
                .start(),
        )
        .map_err(|error| LiveError::Start { addr, error })?;
    let behind = SocketAddr::from(([127, 0, 0, 1], crate_server.port()));
    let listener = {
        let _guard = runtime.enter();
        TcpListener::from_std(listener).map_err(|error| LiveError::Bind { addr, error })?
    };
    let (stop, stopped) = watch::channel(false);
    let stats = Arc::new(ClientStats::default());
    let door = FrontDoor {
        behind,
        limits,
        stats: stats.clone(),
        warnings: Arc::new(Mutex::new(Warnings::default())),
    };
    runtime.spawn(door.accept(listener, stopped));
    Ok(LiveServer {
        runtime,
        crate_server,
        stop,
        stats,
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

/// The view's listening side: accepts clients and relays each to the crate's
/// server.
#[derive(Clone)]
struct FrontDoor {
    /// The crate's server.
    behind: SocketAddr,
    limits: ClientLimits,
    stats: Arc<ClientStats>,
    /// Rate-limited warnings, shared by every client.
    warnings: Arc<Mutex<Warnings>>,
}

/// How a relay ended.
enum End {
    /// The client closed the connection (or it broke).
    ClientLeft,
    /// The crate's server closed it (the view is stopping).
    ServerClosed,
    /// Over its budget, the client took nothing for this long.
    Stalled(Duration),
}

impl FrontDoor {
    fn warn(&self, kind: &'static str, message: impl FnOnce() -> String) {
        self.warnings.lock().warn(kind, message);
    }

    /// Accepts clients until `stopped`.
    async fn accept(self, listener: TcpListener, mut stopped: watch::Receiver<bool>) {
        loop {
            tokio::select! {
                _ = stopped.changed() => return,
                accepted = listener.accept() => match accepted {
                    Ok((stream, peer)) => {
                        tokio::spawn(self.clone().client(stream, peer));
                    }
                    Err(error) => {
                        // Out of file descriptors, most likely: wait a little.
                        self.warn("accept", || format!("view: accepting a client: {error}"));
                        tokio::time::sleep(Duration::from_millis(100)).await;
                    }
                },
            }
        }
    }

    /// Serves one client from its TCP connection to its end.
    async fn client(self, stream: TcpStream, peer: SocketAddr) {
        let _ = stream.set_nodelay(true);
        let mut agreed = None;
        let config = WebSocketConfig::default()
            .read_buffer_size(16 << 10)
            .max_message_size(Some(MAX_CLIENT_MESSAGE))
            .max_frame_size(Some(MAX_CLIENT_MESSAGE));
        // The error type is tungstenite's, for the callback it takes.
        #[allow(clippy::result_large_err)]
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
        let outer = match tokio::time::timeout(HANDSHAKE_TIMEOUT, handshake).await {
            Ok(Ok(ws)) => ws,
            Ok(Err(tungstenite::Error::Http(_))) => {
                // Only the subprotocol callback answers with an HTTP error.
                self.warn("handshake", || {
                    format!(
                        "view: client {peer} refused (HTTP 400): it offers none of the subprotocols {}",
                        subprotocol_names()
                    )
                });
                return;
            }
            Ok(Err(error)) => {
                self.warn("handshake", || {
                    format!("view: client {peer} refused: WebSocket handshake failed: {error}")
                });
                return;
            }
            Err(_) => {
                self.warn("handshake", || {
                    format!("view: client {peer} refused: no WebSocket handshake within {HANDSHAKE_TIMEOUT:?}")
                });
                return;
            }
        };
        let Some((offered, spoken)) = agreed else {
            return;
        };
        let inner = match connect(self.behind, spoken).await {
            Ok(ws) => ws,
            Err(error) => {
                self.warn("behind", || {
                    format!(
                        "view: client {peer} dropped: the Foxglove server behind the view: {error}"
                    )
                });
                return;
            }
        };
        tracing::info!("view: client {peer} connected ({offered})");
        self.stats.connected.fetch_add(1, Ordering::Relaxed);
        let (end, drops) = self.relay(outer, inner, peer).await;
        self.stats.connected.fetch_sub(1, Ordering::Relaxed);
        let budget_mib = self.limits.budget_bytes as f64 / (1u64 << 20) as f64;
        match end {
            End::Stalled(took) => {
                self.stats.stalled.fetch_add(1, Ordering::Relaxed);
                self.warn("stalled", || {
                    format!(
                        "view: client {peer} disconnected: over its budget (view.client_budget_mib = {budget_mib}) and taking nothing for {:.0} s; {} messages ({} bytes) dropped for it",
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

    /// Relays between a client (`outer`) and the crate's server (`inner`) until
    /// either side ends, or the client stalls.
    async fn relay(
        &self,
        outer: WebSocketStream<TcpStream>,
        inner: WebSocketStream<TcpStream>,
        peer: SocketAddr,
    ) -> (End, Drops) {
        let outbox = Outbox::new(self.limits.budget_bytes);
        let (mut to_client, mut from_client) = outer.split();
        let (mut to_server, mut from_server) = inner.split();
        let end = {
            // Everything the server sends goes to the outbox, at once.
            let down = async {
                while let Some(Ok(msg)) = from_server.next().await {
                    let (bytes, droppable) = match &msg {
                        Message::Binary(b) => (b.len(), b.first() == Some(&MESSAGE_DATA)),
                        Message::Text(t) => (t.len(), false),
                        Message::Close(_) => break,
                        Message::Ping(_) | Message::Pong(_) | Message::Frame(_) => continue,
                    };
                    let pushed = outbox.push(msg, bytes, droppable, Instant::now());
                    if pushed.dropped > 0 {
                        self.stats
                            .dropped
                            .fetch_add(pushed.dropped as u64, Ordering::Relaxed);
                    }
                    if pushed.first_time_over {
                        let mib = self.limits.budget_bytes as f64 / (1u64 << 20) as f64;
                        self.warn("slow", || {
                            format!(
                                "view: client {peer} reads more slowly than the site publishes: dropping its oldest messages (over view.client_budget_mib = {mib})"
                            )
                        });
                    }
                }
                End::ServerClosed
            };
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
            // What the client sends (subscriptions) goes to the server.
            let up = async {
                while let Some(Ok(msg)) = from_client.next().await {
                    match msg {
                        Message::Text(_) | Message::Binary(_) => {
                            if to_server.send(msg).await.is_err() {
                                return End::ServerClosed;
                            }
                        }
                        Message::Close(_) => break,
                        Message::Ping(_) | Message::Pong(_) | Message::Frame(_) => {}
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
            tokio::select! {
                end = down => end,
                end = write => end,
                end = up => end,
                end = watchdog => end,
            }
        };
        let drops = outbox.drops();
        let _ = tokio::time::timeout(CLOSE_TIMEOUT, to_server.close()).await;
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

/// Connects to the crate's server at `addr` speaking `subprotocol`.
async fn connect(
    addr: SocketAddr,
    subprotocol: &'static str,
) -> Result<WebSocketStream<TcpStream>, tungstenite::Error> {
    let tcp = TcpStream::connect(addr).await?;
    tcp.set_nodelay(true)?;
    let mut request = format!("ws://{addr}/").into_client_request()?;
    request.headers_mut().insert(
        "sec-websocket-protocol",
        HeaderValue::from_static(subprotocol),
    );
    let (ws, _) = tokio_tungstenite::client_async_with_config(request, tcp, None).await?;
    Ok(ws)
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
