//! The live view: a Foxglove WebSocket server (protocol `foxglove.websocket.v1`,
//! the `foxglove` crate's server on its own tokio runtime) on the site's channels.
//! A client subscribes to the topics it wants; the server sends only those, and a
//! client that cannot keep up loses messages from its own backlog — the group never
//! waits for it.

use std::net::SocketAddr;
use std::sync::Arc;

use foxglove::{Context, WebSocketServer, WebSocketServerHandle};

/// Why the server did not start.
#[derive(Debug, thiserror::Error)]
pub enum LiveError {
    /// The address cannot be listened on (in use, not local, no permission).
    #[error("--listen {addr}: {source}")]
    Bind {
        /// The address.
        addr: SocketAddr,
        /// Why.
        source: std::io::Error,
    },
    /// The server failed to start.
    #[error("starting the Foxglove server on {addr}: {source}")]
    Start {
        /// The address.
        addr: SocketAddr,
        /// Why.
        source: foxglove::FoxgloveError,
    },
}

/// Starts the server for `ctx`'s channels on `addr`, named `name` in `serverInfo`.
pub fn serve(
    ctx: &Arc<Context>,
    addr: SocketAddr,
    name: &str,
) -> Result<WebSocketServerHandle, LiveError> {
    // The crate reports a taken port as a generic error; try it first to say so.
    drop(std::net::TcpListener::bind(addr).map_err(|source| LiveError::Bind { addr, source })?);
    WebSocketServer::new()
        .name(name)
        .bind(addr.ip().to_string(), addr.port())
        .context(ctx)
        .start_blocking()
        .map_err(|source| LiveError::Start { addr, source })
}
