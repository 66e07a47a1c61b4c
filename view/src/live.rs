//! The live view: a Foxglove WebSocket server (protocol `foxglove.sdk.v1` — the
//! renamed `foxglove.websocket.v1`, same messages — the `foxglove` crate's server on its own tokio runtime) on the site's channels.
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
}

/// Starts the server for `ctx`'s channels on `addr`, named `name` in `serverInfo`.
pub fn serve(
    ctx: &Arc<Context>,
    addr: SocketAddr,
    name: &str,
) -> Result<WebSocketServerHandle, LiveError> {
    // The crate reports a taken port as a generic error; try it first to say so.
    drop(std::net::TcpListener::bind(addr).map_err(|error| LiveError::Bind { addr, error })?);
    WebSocketServer::new()
        .name(name)
        .bind(addr.ip().to_string(), addr.port())
        .context(ctx)
        .start_blocking()
        .map_err(|error| LiveError::Start { addr, error })
}
