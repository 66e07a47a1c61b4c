//! One live-view client as a sink of the site's channels, inside the view's
//! process: the Foxglove WebSocket protocol's server side for what the view
//! offers (channels to subscribe to; no client publishing, services or
//! parameters), written straight into the client's [`Outbox`].
//!
//! The `foxglove` crate calls [`Sink`] for every channel it adds and every
//! message logged on a channel this client subscribed to; the messages are
//! encoded with the crate's own protocol types (`foxglove::ws_protocol`), as its
//! WebSocket server encodes them: `serverInfo`, `advertise` (with a schema table
//! for `foxglove.sdk.v1.1`), `unadvertise`, and binary message data. What the
//! client sends (`subscribe`, `unsubscribe`) goes through
//! [`Session::on_client_text`].
//!
//! The crate's `Sink` trait is public but hidden ("until Sink is public"): the
//! price of having no internal port for other local processes to use, and no
//! second queue (the crate's server's 1 024-message backlog) in front of the
//! budgets.

use std::collections::{HashMap, HashSet};
use std::net::SocketAddr;
use std::sync::{Arc, Weak};
use std::time::Instant;

use foxglove::ws_protocol::client::ClientMessage;
use foxglove::ws_protocol::server::advertise::advertise_channels;
use foxglove::ws_protocol::server::advertise_schema_table::SchemaTable;
use foxglove::ws_protocol::server::{MessageData, ServerInfo, Unadvertise};
use foxglove::ws_protocol::{BinaryMessage, JsonMessage};
use foxglove::{ChannelId, Context, FoxgloveError, Metadata, RawChannel, Sink, SinkId};
use parking_lot::Mutex;
use tokio_tungstenite::tungstenite::Message;

use crate::outbox::Outbox;

/// What a session reports about its pushes (drops, a client falling behind).
pub trait Report: Send + Sync {
    /// `dropped` messages were dropped to make room (this client's or, over the
    /// view's memory budget, another's).
    fn dropped(&self, dropped: usize);
    /// The client at `peer` went over its budget for the first time.
    fn first_time_over(&self, peer: SocketAddr);
}

/// The subscriptions of one client.
#[derive(Default)]
struct Subscriptions {
    /// Channels advertised to it.
    advertised: HashSet<ChannelId>,
    /// Its subscription to each channel (one at most).
    by_channel: HashMap<ChannelId, u32>,
    /// The channel of each of its subscriptions.
    by_id: HashMap<u32, ChannelId>,
}

/// One client's protocol state, a sink of the view's [`Context`].
pub struct Session {
    id: SinkId,
    ctx: Weak<Context>,
    peer: SocketAddr,
    outbox: Arc<Outbox<Message>>,
    /// For `foxglove.sdk.v1.1`: the schemas already sent (held while an
    /// advertisement is queued, so that no channel refers to a schema before it).
    schemas: Option<Mutex<SchemaTable>>,
    subs: Mutex<Subscriptions>,
    report: Arc<dyn Report>,
}

impl Session {
    /// A session for the client at `peer`, speaking `subprotocol` (the crate's
    /// name for it), queueing into `outbox`; it queues `serverInfo` for `name` at
    /// once. It receives nothing until [`Session::attach`].
    pub fn new(
        ctx: &Arc<Context>,
        name: &str,
        peer: SocketAddr,
        subprotocol: &str,
        outbox: Arc<Outbox<Message>>,
        report: Arc<dyn Report>,
    ) -> Arc<Session> {
        let info = ServerInfo::new(name).to_string();
        outbox.push(
            Message::text(info.clone()),
            info.len(),
            false,
            Instant::now(),
        );
        Arc::new(Session {
            id: SinkId::next(),
            ctx: Arc::downgrade(ctx),
            peer,
            outbox,
            schemas: (subprotocol == "foxglove.sdk.v1.1").then(Mutex::default),
            subs: Mutex::default(),
            report,
        })
    }

    /// Adds it to its context: every channel is advertised to it now, messages
    /// follow its subscriptions.
    pub fn attach(self: &Arc<Session>) {
        if let Some(ctx) = self.ctx.upgrade() {
            ctx.add_sink(self.clone());
        }
    }

    /// Takes it out of its context (the client left).
    pub fn detach(&self) {
        if let Some(ctx) = self.ctx.upgrade() {
            ctx.remove_sink(self.id);
        }
    }

    /// Queues `message` for the client; message data may be dropped.
    fn push(&self, message: Message, droppable: bool) {
        let bytes = message.len();
        let pushed = self.outbox.push(message, bytes, droppable, Instant::now());
        if pushed.dropped > 0 {
            self.report.dropped(pushed.dropped);
        }
        if pushed.first_time_over {
            self.report.first_time_over(self.peer);
        }
    }

    /// Handles a text message from the client: subscriptions; anything else is
    /// ignored (the view offers no more). Malformed messages are ignored too.
    pub fn on_client_text(&self, text: &str) {
        let Ok(message) = ClientMessage::parse_json(text) else {
            tracing::debug!(
                "view: client {}: a message that is not the protocol's",
                self.peer
            );
            return;
        };
        let Some(ctx) = self.ctx.upgrade() else {
            return;
        };
        match message {
            ClientMessage::Subscribe(subscribe) => {
                let mut added = Vec::new();
                {
                    let mut subs = self.subs.lock();
                    for s in subscribe.subscriptions {
                        let channel = ChannelId::new(s.channel_id);
                        if subs.advertised.contains(&channel)
                            && !subs.by_id.contains_key(&s.id)
                            && !subs.by_channel.contains_key(&channel)
                        {
                            subs.by_channel.insert(channel, s.id);
                            subs.by_id.insert(s.id, channel);
                            added.push(channel);
                        }
                    }
                }
                // Outside the lock: the context calls back into sinks.
                ctx.subscribe_channels(self.id, &added);
            }
            ClientMessage::Unsubscribe(unsubscribe) => {
                let mut removed = Vec::new();
                {
                    let mut subs = self.subs.lock();
                    for id in unsubscribe.subscription_ids {
                        if let Some(channel) = subs.by_id.remove(&id) {
                            subs.by_channel.remove(&channel);
                            removed.push(channel);
                        }
                    }
                }
                ctx.unsubscribe_channels(self.id, &removed);
            }
            _ => {}
        }
    }
}

impl Sink for Session {
    fn id(&self) -> SinkId {
        self.id
    }

    fn log(
        &self,
        channel: &RawChannel,
        msg: &[u8],
        metadata: &Metadata,
    ) -> Result<(), FoxgloveError> {
        let Some(subscription) = self.subs.lock().by_channel.get(&channel.id()).copied() else {
            return Ok(());
        };
        let data = MessageData::new(subscription, metadata.log_time, msg).to_bytes();
        self.push(Message::binary(data), true);
        Ok(())
    }

    fn add_channels(&self, channels: &[&Arc<RawChannel>]) -> Option<Vec<ChannelId>> {
        let message = advertise_channels(channels.iter().copied());
        if message.channels.is_empty() {
            return None;
        }
        {
            let mut subs = self.subs.lock();
            subs.advertised
                .extend(message.channels.iter().map(|c| ChannelId::new(c.id)));
        }
        match &self.schemas {
            None => self.push(Message::text(message.to_string()), false),
            Some(table) => {
                let mut table = table.lock();
                let text = table.deduplicate(&message).to_string();
                self.push(Message::text(text), false);
            }
        }
        None
    }

    fn remove_channel(&self, channel: &RawChannel) {
        let id = channel.id();
        {
            let mut subs = self.subs.lock();
            if !subs.advertised.remove(&id) {
                return;
            }
            if let Some(sub) = subs.by_channel.remove(&id) {
                subs.by_id.remove(&sub);
            }
        }
        let message = Unadvertise::new([u64::from(id)]).to_string();
        self.push(Message::text(message), false);
    }

    fn auto_subscribe(&self) -> bool {
        false
    }
}
