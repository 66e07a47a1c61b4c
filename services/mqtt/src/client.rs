//! The MQTT client: one thread that owns the connection to the broker (rumqttc's
//! event loop on a current-thread tokio runtime), takes messages from the
//! [`Outbox`] and publishes them with QoS 1.
//!
//! * A message leaves the outbox only while connected, at most [`WINDOW`] at a
//!   time; it counts as sent when the broker's PUBACK for it arrives.
//! * When the connection fails, every message not yet acknowledged goes back to
//!   the front of the outbox (sent again after the reconnection: at least once)
//!   and the client reconnects with a backoff doubling from 0.5 s to
//!   `reconnect_max_s`. One warning per outage.
//! * A broker that refuses the sink (bad user name or password, not authorized)
//!   or a failed TLS handshake is one error line naming the broker and the
//!   reason, logged again only when the reason changes (e.g. a broker that
//!   accepted the sink refuses it after a restart); every refusal and TLS
//!   failure is counted, and the sink retries with the same backoff.
//! * Each connection publishes "online" (retained) on the status topic; the last
//!   will, which the broker publishes if the sink vanishes, is "offline"
//!   (retained). A clean stop publishes "offline" itself, then disconnects.
//! * At a stop it flushes for up to [`FLUSH`]; what is still queued then is
//!   counted as dropped.
//!
//! Sessions are clean (`clean_session`): after a reconnection rumqttc forgets the
//! unacknowledged publishes, and the outbox sends them again.
//!
//! The thread is the only owner of rumqttc's `EventLoop`, so it feeds requests
//! straight into the loop's `pending` queue rather than through rumqttc's `Client`
//! channel: the order in which it hands messages over is the order of the
//! `Outgoing::Publish(pkid)` events, which matches each message to its packet id.
//! While connected it waits on the event loop, a wake-up from the stage
//! (`tokio::sync::Notify`) or a 100 ms tick; while connecting it lets the attempt
//! run to its end (3 s timeout). So every message is either acknowledged or counted
//! as dropped: `messages = sent + queue_dropped + queued (+ in flight)`.
//!
//! Why rumqttc: an MQTT 3.1.1 client in Rust with QoS 1, last will, keep-alive and
//! reconnection by polling, maintained (bytebeamio) and widely used; its async
//! runtime is tokio, already in the workspace's tree (through the view), so it adds
//! few crates (`flume`, `fixedbitset`, `tokio-stream`). paho-mqtt would link the C
//! library, and a hand-written MQTT client would be more to keep right. TLS is
//! rumqttc's `use-rustls-no-provider` feature with rustls's `ring` provider chosen
//! by us: ring builds with the C compiler already needed, where the default
//! aws-lc-rs would need cmake and a much longer build.

use std::collections::VecDeque;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use parking_lot::{Mutex, MutexGuard};
use rumqttc::{
    ConnectReturnCode, ConnectionError, Disconnect, Event, EventLoop, Incoming, LastWill,
    MqttOptions, Outgoing, Publish, QoS, Request, TlsConfiguration, Transport,
};

use crate::login::Login;
use crate::outbox::{MAX_PACKET_BYTES, Message, Outbox};

/// Messages handed to the connection and not yet acknowledged, at most.
pub const WINDOW: usize = 32;
/// How long a stopping sink keeps publishing what is queued.
pub const FLUSH: Duration = Duration::from_secs(3);
/// First wait before reconnecting.
const BACKOFF_MIN: Duration = Duration::from_millis(500);
/// Longest wait for the TCP connection and the CONNACK, seconds.
const CONNECT_TIMEOUT_S: u64 = 3;

/// What the stage and the client share.
#[derive(Debug)]
pub struct Shared {
    outbox: Mutex<Outbox>,
    wake: tokio::sync::Notify,
    stopping: AtomicBool,
    connected: AtomicBool,
    reconnects: AtomicU64,
    refused: AtomicU64,
    tls_failures: AtomicU64,
}

impl Shared {
    /// Shared state around an outbox of `capacity` messages.
    pub fn new(capacity: usize) -> Arc<Self> {
        Arc::new(Shared {
            outbox: Mutex::new(Outbox::new(capacity)),
            wake: tokio::sync::Notify::new(),
            stopping: AtomicBool::new(false),
            connected: AtomicBool::new(false),
            reconnects: AtomicU64::new(0),
            refused: AtomicU64::new(0),
            tls_failures: AtomicU64::new(0),
        })
    }

    /// The outbox.
    pub fn outbox(&self) -> MutexGuard<'_, Outbox> {
        self.outbox.lock()
    }

    /// Tells the client that messages are waiting.
    pub fn wake(&self) {
        self.wake.notify_one();
    }

    /// Asks the client to flush and stop.
    pub fn stop(&self) {
        self.stopping.store(true, Ordering::SeqCst);
        self.wake.notify_one();
    }

    /// True while connected to the broker.
    pub fn connected(&self) -> bool {
        self.connected.load(Ordering::Relaxed)
    }

    /// Reconnections after the first connection.
    pub fn reconnects(&self) -> u64 {
        self.reconnects.load(Ordering::Relaxed)
    }

    /// Connection attempts the broker refused (its CONNACK said no).
    pub fn refused(&self) -> u64 {
        self.refused.load(Ordering::Relaxed)
    }

    /// Connection attempts whose TLS handshake failed.
    pub fn tls_failures(&self) -> u64 {
        self.tls_failures.load(Ordering::Relaxed)
    }
}

/// Where and how to connect.
#[derive(Debug, Clone)]
pub struct Settings {
    /// Broker host.
    pub host: String,
    /// Broker port.
    pub port: u16,
    /// The broker as configured, for messages.
    pub url: String,
    /// Client id.
    pub client_id: String,
    /// The availability topic.
    pub status_topic: String,
    /// Keep-alive.
    pub keepalive: Duration,
    /// Longest backoff.
    pub reconnect_max: Duration,
    /// TLS (`mqtts://`), or `None` for plain TCP.
    pub tls: Option<Arc<rustls::ClientConfig>>,
    /// User name and password, if any.
    pub login: Option<Login>,
}

impl Settings {
    /// Who the sink connects as, for messages (never the password).
    fn who(&self) -> String {
        match &self.login {
            Some(l) => format!("user \"{}\"", l.username),
            None => "anonymous".into(),
        }
    }
}

/// Why the last connection attempt failed, so that each change is logged once.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Trouble {
    /// Connected, or not tried yet.
    None,
    /// No connection: the broker is down or unreachable, or went away.
    Unreachable,
    /// The broker refused the sink (its CONNACK return code).
    Refused(ConnectReturnCode),
    /// The TLS handshake failed (certificate, name, protocol).
    Tls,
}

impl Trouble {
    fn of(e: &ConnectionError) -> Self {
        match e {
            ConnectionError::ConnectionRefused(code) => Trouble::Refused(*code),
            ConnectionError::Tls(_) => Trouble::Tls,
            _ if caused_by_tls(e) => Trouble::Tls,
            _ => Trouble::Unreachable,
        }
    }
}

/// How far a stop has got: flushing until `deadline`, then the "offline" status,
/// then DISCONNECT.
#[derive(Debug, Default)]
struct Closing {
    /// When the flush gives up.
    deadline: Option<Instant>,
    offline_sent: bool,
    disconnect_sent: bool,
}

/// True when a rustls error is in `e`'s chain: with TLS 1.3 a broker that
/// rejects the client's certificate says so in an alert the sink reads only
/// after the handshake, as an I/O error of the MQTT read.
fn caused_by_tls(e: &ConnectionError) -> bool {
    let mut cause: Option<&(dyn std::error::Error + 'static)> = Some(e);
    while let Some(err) = cause {
        let inner = err
            .downcast_ref::<std::io::Error>()
            .and_then(|io| io.get_ref())
            .map(|inner| inner as &(dyn std::error::Error + 'static));
        if err.is::<rustls::Error>() || inner.is_some_and(|i| i.is::<rustls::Error>()) {
            return true;
        }
        cause = err.source();
    }
    false
}

/// A broker's refusal in words, with what to check.
fn refusal_reason(code: ConnectReturnCode) -> &'static str {
    match code {
        ConnectReturnCode::BadUserNamePassword => {
            "bad user name or password (check mqtt.username and the password against the broker's password file)"
        }
        ConnectReturnCode::NotAuthorized => {
            "not authorized (check mqtt.username, the password, and the broker's password file and ACL)"
        }
        ConnectReturnCode::BadClientId => "client id rejected (check mqtt.client_id)",
        ConnectReturnCode::ServiceUnavailable => "service unavailable",
        ConnectReturnCode::RefusedProtocolVersion => "MQTT 3.1.1 not accepted",
        ConnectReturnCode::Success => "no reason given",
    }
}

/// Starts the client thread.
pub fn spawn(
    settings: Settings,
    shared: Arc<Shared>,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    std::thread::Builder::new()
        .name("mqtt-client".into())
        .spawn(move || {
            let runtime = match tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()
            {
                Ok(r) => r,
                Err(e) => {
                    tracing::error!("cannot start the MQTT client's runtime: {e}");
                    return;
                }
            };
            runtime.block_on(Client::new(settings, shared).run());
        })
}

/// A message handed to the connection: `None` is the status ("online" /
/// "offline"), which is not counted.
struct InFlight {
    message: Option<Message>,
    pkid: Option<u16>,
}

struct Client {
    settings: Settings,
    shared: Arc<Shared>,
    eventloop: EventLoop,
    inflight: VecDeque<InFlight>,
    connected: bool,
    ever_connected: bool,
    trouble: Trouble,
    /// Refusals and TLS failures since the last connection.
    failed_since: u64,
}

impl Client {
    fn new(settings: Settings, shared: Arc<Shared>) -> Self {
        let mut options = MqttOptions::new(&settings.client_id, &settings.host, settings.port);
        options
            .set_keep_alive(settings.keepalive)
            .set_clean_session(true)
            .set_inflight(WINDOW as u16 * 2)
            // Incoming: acknowledgements only; outgoing: up to the outbox's bound.
            .set_max_packet_size(10 * 1024, MAX_PACKET_BYTES)
            .set_last_will(LastWill::new(
                &settings.status_topic,
                "offline",
                QoS::AtLeastOnce,
                true,
            ));
        if let Some(tls) = &settings.tls {
            options.set_transport(Transport::tls_with_config(TlsConfiguration::Rustls(
                tls.clone(),
            )));
        }
        if let Some(login) = &settings.login {
            let password = login.password.as_ref().map_or("", |p| p.expose());
            options.set_credentials(login.username.clone(), password);
        }
        let mut eventloop = EventLoop::new(options, 1);
        let mut network = eventloop.network_options();
        network.set_connection_timeout(CONNECT_TIMEOUT_S);
        eventloop.set_network_options(network);
        Client {
            settings,
            shared,
            eventloop,
            inflight: VecDeque::new(),
            connected: false,
            ever_connected: false,
            trouble: Trouble::None,
            failed_since: 0,
        }
    }

    fn stopping(&self) -> bool {
        self.shared.stopping.load(Ordering::SeqCst)
    }

    /// Publishes `payload` on `topic` (QoS 1): `message` is the queued message it
    /// carries, `None` for the status.
    fn publish(&mut self, topic: &str, payload: &[u8], retain: bool, message: Option<Message>) {
        let mut p = Publish::new(topic, QoS::AtLeastOnce, payload.to_vec());
        p.retain = retain;
        // Straight into the event loop's queue (this thread owns it): its
        // requests go out in this order, which matches them to their packet ids.
        self.eventloop.pending.push_back(Request::Publish(p));
        self.inflight.push_back(InFlight {
            message,
            pkid: None,
        });
    }

    /// Hands queued messages to the connection, up to the window.
    fn hand_over(&mut self) {
        while self.inflight.len() < WINDOW {
            let Some(m) = self.shared.outbox().pop() else {
                break;
            };
            let (topic, payload) = (m.topic.clone(), m.payload.clone());
            self.publish(&topic, &payload, false, Some(m));
        }
    }

    fn messages_in_flight(&self) -> usize {
        self.inflight.iter().filter(|f| f.message.is_some()).count()
    }

    /// The connection is gone: unacknowledged messages go back to the outbox.
    fn lost(&mut self) {
        self.connected = false;
        self.shared.connected.store(false, Ordering::Relaxed);
        let unacked: Vec<Message> = self.inflight.drain(..).filter_map(|f| f.message).collect();
        self.shared.outbox().requeue(unacked.into_iter());
        self.eventloop.pending.clear();
    }

    async fn run(mut self) {
        let mut backoff = BACKOFF_MIN;
        let mut closing = Closing::default();
        loop {
            if self.stopping() && closing.deadline.is_none() {
                closing.deadline = Some(Instant::now() + FLUSH);
            }
            if let Some(d) = closing.deadline {
                if !self.connected || Instant::now() >= d {
                    break;
                }
                self.close_step(&mut closing);
            }
            if self.connected && !closing.offline_sent {
                self.hand_over();
            }
            let event = if self.connected {
                // Woken by new messages or a stop; the event loop's future is
                // safe to drop while connected (reads and acks are buffered).
                let tick = tokio::time::sleep(Duration::from_millis(100));
                tokio::select! {
                    event = self.eventloop.poll() => Some(event),
                    _ = self.shared.wake.notified() => None,
                    _ = tick => None,
                }
            } else {
                // Connecting runs to its end (success, refusal or timeout).
                Some(self.eventloop.poll().await)
            };
            match event {
                None => {}
                Some(Ok(Event::Incoming(Incoming::ConnAck(_)))) => {
                    backoff = BACKOFF_MIN;
                    self.on_connected();
                }
                Some(Ok(Event::Outgoing(Outgoing::Publish(pkid)))) => {
                    if let Some(f) = self.inflight.iter_mut().find(|f| f.pkid.is_none()) {
                        f.pkid = Some(pkid);
                    }
                }
                Some(Ok(Event::Incoming(Incoming::PubAck(ack)))) => {
                    let at = self.inflight.iter().position(|f| f.pkid == Some(ack.pkid));
                    if let Some(f) = at.and_then(|i| self.inflight.remove(i))
                        && let Some(m) = f.message
                    {
                        self.shared.outbox().acked(m);
                    }
                }
                Some(Ok(Event::Outgoing(Outgoing::Disconnect))) => break,
                Some(Ok(_)) => {}
                Some(Err(e)) => {
                    let was_connected = self.connected;
                    self.lost();
                    if closing.deadline.is_some() || self.stopping() {
                        break;
                    }
                    self.failed(&e, was_connected);
                    self.sleep(backoff).await;
                    backoff = (backoff * 2).min(self.settings.reconnect_max);
                }
            }
        }
        self.lost();
        self.shared.connected.store(false, Ordering::Relaxed);
        let lost = self.shared.outbox().drop_all();
        if lost > 0 {
            tracing::warn!(
                "{lost} messages were not delivered to {} before the stop: counted as dropped",
                self.settings.url
            );
        }
    }

    /// One step of a stop while connected: once everything is delivered, the
    /// retained "offline" status, then (once that is acknowledged) DISCONNECT.
    fn close_step(&mut self, closing: &mut Closing) {
        let drained = self.shared.outbox().is_empty() && self.messages_in_flight() == 0;
        if drained && !closing.offline_sent {
            let topic = self.settings.status_topic.clone();
            self.publish(&topic, b"offline", true, None);
            closing.offline_sent = true;
        }
        if closing.offline_sent && self.inflight.is_empty() && !closing.disconnect_sent {
            self.eventloop
                .pending
                .push_back(Request::Disconnect(Disconnect));
            closing.disconnect_sent = true;
        }
    }

    /// The broker accepted the connection: counted, logged, the retained "online"
    /// status published.
    fn on_connected(&mut self) {
        self.connected = true;
        self.shared.connected.store(true, Ordering::Relaxed);
        if self.ever_connected {
            self.shared.reconnects.fetch_add(1, Ordering::Relaxed);
        }
        let queued = self.shared.outbox().len();
        let after = match self.failed_since {
            0 => String::new(),
            n => format!(", after {n} refused or failed attempts"),
        };
        tracing::info!(
            "connected to the MQTT broker {} as {}{} ({queued} messages queued{after})",
            self.settings.url,
            self.settings.who(),
            if self.settings.tls.is_some() {
                " over TLS"
            } else {
                ""
            },
        );
        self.ever_connected = true;
        self.trouble = Trouble::None;
        self.failed_since = 0;
        let topic = self.settings.status_topic.clone();
        self.publish(&topic, b"online", true, None);
    }

    /// Counts and logs a failed connection: each change of reason once (an
    /// error for a refusal or a TLS failure, a warning for an unreachable or
    /// lost broker), the repeats at debug level.
    fn failed(&mut self, e: &ConnectionError, was_connected: bool) {
        let trouble = Trouble::of(e);
        let url = &self.settings.url;
        let retry = format!(
            "retrying every {:.0} s at most; holding new messages meanwhile (the oldest dropped when the queue is full)",
            self.settings.reconnect_max.as_secs_f64()
        );
        let changed = trouble != self.trouble || was_connected;
        self.trouble = trouble;
        match trouble {
            Trouble::Refused(code) => {
                self.shared.refused.fetch_add(1, Ordering::Relaxed);
                self.failed_since += 1;
                if changed {
                    let before = if self.ever_connected {
                        " — it accepted the sink before: the broker's users, passwords or ACL changed"
                    } else {
                        ""
                    };
                    tracing::error!(
                        "the MQTT broker {url} refused the sink ({}, client id \"{}\"): {}{before}; {retry}",
                        self.settings.who(),
                        self.settings.client_id,
                        refusal_reason(code)
                    );
                    return;
                }
            }
            Trouble::Tls => {
                self.shared.tls_failures.fetch_add(1, Ordering::Relaxed);
                self.failed_since += 1;
                if changed {
                    tracing::error!(
                        "TLS with the MQTT broker {url} failed: {e} (check mqtt.ca_file, that the broker's certificate names \"{}\", and the client certificate if the broker requires one); {retry}",
                        self.settings.host
                    );
                    return;
                }
            }
            Trouble::Unreachable | Trouble::None => {
                if was_connected {
                    tracing::warn!("lost the MQTT broker {url}: {e}; reconnecting; {retry}");
                    return;
                }
                if changed {
                    tracing::warn!("cannot reach the MQTT broker {url}: {e}; {retry}");
                    return;
                }
            }
        }
        tracing::debug!("MQTT broker {url}: {e}");
    }

    /// Waits `d`, or less if the sink is asked to stop.
    async fn sleep(&self, d: Duration) {
        let end = Instant::now() + d;
        while !self.stopping() {
            let left = end.saturating_duration_since(Instant::now());
            if left.is_zero() {
                break;
            }
            tokio::time::sleep(left.min(Duration::from_millis(50))).await;
        }
    }
}
