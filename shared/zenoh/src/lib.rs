//! ROS 2 over Zenoh in rmw_zenoh's format, for robots whose middleware is
//! rmw_zenoh (Jazzy and later) and so see no DDS topic.
//!
//! One Zenoh session is one ROS 2 node ([`RosZenoh`]): it announces itself and
//! each of its publishers and services with liveliness tokens (the ROS graph of
//! `ros2 topic list`), publishes CDR samples with rmw_zenoh's attachment on the
//! data key expressions ([`RosPublisher`], an advanced publisher with a cache for
//! transient-local topics, which rmw_zenoh's late-joining subscribers query), and
//! answers service requests, Zenoh queries, in the order the caller takes them
//! ([`RosService`]), and calls other nodes' services ([`RosClient`]: a query
//! per call, the servers followed by their liveliness tokens). The names and
//! bytes are in [`names`].
//!
//! Off unless configured; a session listens on loopback and connects to the
//! router rmw_zenoh expects at `tcp/localhost:7447` unless told otherwise, and a
//! Zenoh configuration file can add TLS, user/password authentication and access
//! control.

pub mod names;

use std::collections::{BTreeSet, VecDeque};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicI64, AtomicU32, Ordering};
use std::time::{SystemTime, UNIX_EPOCH};

use parking_lot::Mutex;
use zenoh::Wait;
use zenoh::liveliness::LivelinessToken;
use zenoh::qos::{CongestionControl, Reliability};
use zenoh::query::{ConsolidationMode, Query, QueryTarget, Queryable};
use zenoh::sample::{Sample, SampleKind};
use zenoh_ext::{AdvancedPublisher, AdvancedPublisherBuilderExt, CacheConfig, MissDetectionConfig};

use names::{Attachment, EntityKind, GID_LEN, NodeInfo, Qos, RosType};

/// The encapsulation header of little-endian plain CDR, before a sample's fields.
pub const CDR_LE_HEADER: [u8; 4] = [0x00, 0x01, 0x00, 0x00];
/// How often a reliable transient-local publisher's subscribers are told its last
/// sequence number (rmw_zenoh's `SAMPLE_MISS_DETECTION_HEARTBEAT_PERIOD`).
const HEARTBEAT: std::time::Duration = std::time::Duration::from_millis(500);

/// Whether the session routes for others (a peer) or goes through a router.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Mode {
    /// A Zenoh peer, as rmw_zenoh's nodes are: connects to the router for
    /// discovery and to other peers directly.
    #[default]
    Peer,
    /// A Zenoh client: everything through the router it connects to.
    Client,
}

/// Where and how the session talks Zenoh.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Settings {
    /// ROS domain: the first part of every key expression.
    pub domain: u16,
    /// Peer or client.
    pub mode: Mode,
    /// Endpoints to connect to, e.g. `tcp/localhost:7447` (rmw_zenoh's router).
    pub connect: Vec<String>,
    /// Endpoints to listen on, e.g. `tcp/127.0.0.1:0`; empty: none.
    pub listen: Vec<String>,
    /// A Zenoh configuration file (JSON5) read first: TLS, authentication,
    /// access control. `mode`, `connect` and `listen` are then set over it.
    pub config_file: Option<PathBuf>,
}

/// Why Zenoh output could not start or a sample could not go out.
#[derive(Debug, thiserror::Error)]
pub enum ZenohError {
    /// The configuration (file or a setting) is not one Zenoh takes.
    #[error("Zenoh configuration: {0}")]
    Config(String),
    /// The session or one of its entities could not be opened or declared.
    #[error("Zenoh: {0}")]
    Session(String),
}

impl isochron_exit::Classify for ZenohError {
    /// A configuration Zenoh refuses is permanent; a session that could not open
    /// (a port in use, a router that refused) may open later.
    fn exit_code(&self) -> i32 {
        match self {
            ZenohError::Config(_) => isochron_exit::CONFIG,
            ZenohError::Session(_) => isochron_exit::UNAVAILABLE,
        }
    }
}

/// The Zenoh configuration of `settings`.
pub fn config(settings: &Settings) -> Result<zenoh::Config, ZenohError> {
    let mut config = match &settings.config_file {
        Some(path) => zenoh::Config::from_file(path)
            .map_err(|e| ZenohError::Config(format!("{}: {e}", path.display())))?,
        None => zenoh::Config::default(),
    };
    let json = |list: &[String]| {
        let quoted: Vec<String> = list.iter().map(|e| format!("{e:?}")).collect();
        format!("[{}]", quoted.join(","))
    };
    let mode = match settings.mode {
        Mode::Peer => "\"peer\"",
        Mode::Client => "\"client\"",
    };
    let mut set = |key: &str, value: String| {
        config
            .insert_json5(key, &value)
            .map_err(|e| ZenohError::Config(format!("{key} = {value}: {e}")))
    };
    set("mode", mode.to_string())?;
    set("connect/endpoints", json(&settings.connect))?;
    set("listen/endpoints", json(&settings.listen))?;
    // Discovery goes through the router, as rmw_zenoh's default session
    // configuration has it: no multicast on the site's network.
    set("scouting/multicast/enabled", "false".to_string())?;
    Ok(config)
}

/// A ROS 2 node on a Zenoh session.
pub struct RosZenoh {
    session: zenoh::Session,
    node: NodeInfo,
    next_id: AtomicU32,
    _token: LivelinessToken,
}

fn session_error(what: &str) -> impl Fn(zenoh::Error) -> ZenohError + '_ {
    move |e| ZenohError::Session(format!("{what}: {e}"))
}

fn now_ns() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as i64)
}

impl RosZenoh {
    /// Opens the session of `settings` and announces the node `namespace`/`name`.
    pub fn open(settings: &Settings, namespace: &str, name: &str) -> Result<RosZenoh, ZenohError> {
        let session = zenoh::open(config(settings)?)
            .wait()
            .map_err(session_error("opening the session"))?;
        let node = NodeInfo {
            domain: settings.domain,
            zid: session.zid().to_string(),
            node_id: 0,
            namespace: namespace.to_string(),
            name: name.to_string(),
            enclave: "/".to_string(),
        };
        let token = session
            .liveliness()
            .declare_token(names::liveliness_keyexpr(&node, None))
            .wait()
            .map_err(session_error("announcing the node"))?;
        Ok(RosZenoh {
            session,
            node,
            next_id: AtomicU32::new(1),
            _token: token,
        })
    }

    /// The session's Zenoh id.
    pub fn zid(&self) -> &str {
        &self.node.zid
    }

    /// A publisher of `ty` on `topic` with `qos`.
    pub fn publisher(
        &self,
        topic: &str,
        ty: &RosType,
        qos: Qos,
    ) -> Result<RosPublisher, ZenohError> {
        let id = self.next_id.fetch_add(1, Ordering::Relaxed);
        let token_key = names::liveliness_keyexpr(
            &self.node,
            Some((id, EntityKind::Publisher, topic, ty, qos)),
        );
        let key = names::data_keyexpr(self.node.domain, topic, ty);
        let what = format!("declaring the publisher of {topic}");
        let mut builder = self
            .session
            .declare_publisher(key)
            .congestion_control(CongestionControl::Drop)
            .reliability(if qos.reliable {
                Reliability::Reliable
            } else {
                Reliability::BestEffort
            })
            .advanced();
        if qos.transient_local {
            builder = builder
                .publisher_detection()
                .cache(CacheConfig::default().max_samples(qos.depth.max(1)));
            if qos.reliable {
                builder = builder.sample_miss_detection(
                    MissDetectionConfig::default().sporadic_heartbeat(HEARTBEAT),
                );
            }
        }
        let publisher = builder.wait().map_err(session_error(&what))?;
        let token = self
            .session
            .liveliness()
            .declare_token(token_key.clone())
            .wait()
            .map_err(session_error(&what))?;
        Ok(RosPublisher {
            publisher,
            gid: names::gid(&token_key),
            sequence: AtomicI64::new(1),
            _token: token,
        })
    }

    /// A service of `ty` named `name` whose requests wait, at most `capacity` of
    /// them (more are dropped and counted), until [`RosService::take`] takes them.
    pub fn service(
        &self,
        name: &str,
        ty: &RosType,
        capacity: usize,
    ) -> Result<RosService, ZenohError> {
        let id = self.next_id.fetch_add(1, Ordering::Relaxed);
        let token_key = names::liveliness_keyexpr(
            &self.node,
            Some((id, EntityKind::Service, name, ty, Qos::SERVICES)),
        );
        let key = names::data_keyexpr(self.node.domain, name, ty);
        let what = format!("declaring the service {name}");
        let inbox = Arc::new(Mutex::new(Inbox::default()));
        let sink = Arc::clone(&inbox);
        let queryable = self
            .session
            .declare_queryable(key)
            .complete(true)
            .callback(move |query| sink.lock().push(query, capacity))
            .wait()
            .map_err(session_error(&what))?;
        let token = self
            .session
            .liveliness()
            .declare_token(token_key)
            .wait()
            .map_err(session_error(&what))?;
        Ok(RosService {
            inbox,
            _queryable: queryable,
            _token: token,
        })
    }
}

impl RosZenoh {
    /// A client of the service `name` (absolute) of `ty`, announced as rmw_zenoh
    /// announces one; its calls time out after `timeout`.
    pub fn client(
        &self,
        name: &str,
        ty: &RosType,
        timeout: std::time::Duration,
    ) -> Result<RosClient, ZenohError> {
        let id = self.next_id.fetch_add(1, Ordering::Relaxed);
        let token_key = names::liveliness_keyexpr(
            &self.node,
            Some((id, EntityKind::Client, name, ty, Qos::SERVICES)),
        );
        let what = format!("declaring the client of {name}");
        let servers = Arc::new(Mutex::new(BTreeSet::new()));
        let seen = Arc::clone(&servers);
        let subscriber = self
            .session
            .liveliness()
            .declare_subscriber(names::servers_keyexpr(self.node.domain, name, ty))
            .history(true)
            .callback(move |sample: Sample| {
                let key = sample.key_expr().as_str().to_string();
                let mut seen = seen.lock();
                match sample.kind() {
                    SampleKind::Put => seen.insert(key),
                    SampleKind::Delete => seen.remove(&key),
                };
            })
            .wait()
            .map_err(session_error(&what))?;
        let token = self
            .session
            .liveliness()
            .declare_token(token_key.clone())
            .wait()
            .map_err(session_error(&what))?;
        Ok(RosClient {
            session: self.session.clone(),
            key: names::data_keyexpr(self.node.domain, name, ty),
            gid: names::gid(&token_key),
            timeout,
            sequence: 0,
            servers,
            replies: Arc::new(Mutex::new(VecDeque::new())),
            _servers: subscriber,
            _token: token,
        })
    }
}

/// A ROS 2 service client on Zenoh: each call a query with rmw_zenoh's
/// attachment, its replies kept until taken.
pub struct RosClient {
    session: zenoh::Session,
    key: String,
    gid: [u8; GID_LEN],
    timeout: std::time::Duration,
    sequence: i64,
    /// The liveliness tokens of the service's servers alive now.
    servers: Arc<Mutex<BTreeSet<String>>>,
    /// Replies not yet taken.
    replies: Arc<Mutex<Replies>>,
    _servers: zenoh::pubsub::Subscriber<()>,
    _token: LivelinessToken,
}

/// A client's replies not yet taken: each call's sequence number and the
/// reply's CDR fields.
type Replies = VecDeque<(i64, Vec<u8>)>;

/// Replies a client keeps until they are taken; more are dropped.
const CLIENT_REPLIES: usize = 64;

impl RosClient {
    /// The token of the first server alive (by key), if one is.
    pub fn server(&self) -> Option<String> {
        self.servers.lock().first().cloned()
    }

    /// Calls the service with `cdr` (little-endian CDR fields, the encapsulation
    /// header is added); returns the call's sequence number.
    pub fn call(&mut self, cdr: &[u8]) -> Result<i64, ZenohError> {
        self.sequence += 1;
        let sequence = self.sequence;
        let mut payload = Vec::with_capacity(CDR_LE_HEADER.len() + cdr.len());
        payload.extend(CDR_LE_HEADER);
        payload.extend(cdr);
        let attachment = Attachment {
            sequence,
            timestamp_ns: now_ns(),
            gid: self.gid,
        };
        let replies = Arc::clone(&self.replies);
        self.session
            .get(&self.key)
            .payload(payload)
            .attachment(attachment.to_bytes())
            .target(QueryTarget::AllComplete)
            .consolidation(ConsolidationMode::None)
            .timeout(self.timeout)
            .callback(move |reply| {
                let Ok(sample) = reply.result() else {
                    return;
                };
                let Some(a) = sample
                    .attachment()
                    .and_then(|a| Attachment::from_bytes(&a.to_bytes()))
                else {
                    return;
                };
                let bytes = sample.payload().to_bytes();
                let mut replies = replies.lock();
                if replies.len() < CLIENT_REPLIES {
                    let fields = bytes.get(CDR_LE_HEADER.len()..).unwrap_or_default();
                    replies.push_back((a.sequence, fields.to_vec()));
                }
            })
            .wait()
            .map_err(|e| ZenohError::Session(format!("calling: {e}")))?;
        Ok(sequence)
    }

    /// The replies that arrived since the last look: each call's sequence
    /// number and the reply's CDR fields.
    pub fn replies(&self) -> Vec<(i64, Vec<u8>)> {
        self.replies.lock().drain(..).collect()
    }
}

/// A ROS 2 publisher on Zenoh.
pub struct RosPublisher {
    publisher: AdvancedPublisher<'static>,
    gid: [u8; GID_LEN],
    sequence: AtomicI64,
    _token: LivelinessToken,
}

impl RosPublisher {
    /// Publishes one sample: `cdr` is its fields in little-endian CDR, without the
    /// encapsulation header (added here).
    pub fn put(&self, cdr: &[u8]) -> Result<(), ZenohError> {
        let mut payload = Vec::with_capacity(CDR_LE_HEADER.len() + cdr.len());
        payload.extend(CDR_LE_HEADER);
        payload.extend(cdr);
        let attachment = Attachment {
            sequence: self.sequence.fetch_add(1, Ordering::Relaxed),
            timestamp_ns: now_ns(),
            gid: self.gid,
        };
        self.publisher
            .put(payload)
            .attachment(attachment.to_bytes())
            .wait()
            .map_err(|e| ZenohError::Session(format!("publishing: {e}")))
    }

    /// The publisher's GID.
    pub fn gid(&self) -> [u8; GID_LEN] {
        self.gid
    }
}

/// Requests received and not yet taken.
#[derive(Default)]
struct Inbox {
    queries: VecDeque<Query>,
    dropped: u64,
}

impl Inbox {
    fn push(&mut self, query: Query, capacity: usize) {
        if self.queries.len() >= capacity {
            // Dropping the query ends it: its client gets no reply and times out.
            self.dropped += 1;
            return;
        }
        self.queries.push_back(query);
    }
}

/// A service request: its client, sequence number and CDR body, or why it cannot
/// be read.
pub struct Request {
    query: Query,
    /// The client's attachment, `None` when it had none or a malformed one.
    pub attachment: Option<Attachment>,
}

impl Request {
    /// The request's payload: encapsulation header and CDR.
    pub fn payload(&self) -> Vec<u8> {
        self.query
            .payload()
            .map(|p| p.to_bytes().into_owned())
            .unwrap_or_default()
    }
}

/// A ROS 2 service on Zenoh: a queryable whose queries wait to be taken.
pub struct RosService {
    inbox: Arc<Mutex<Inbox>>,
    _queryable: Queryable<()>,
    _token: LivelinessToken,
}

impl RosService {
    /// The next request waiting, oldest first.
    pub fn take(&self) -> Option<Request> {
        let query = self.inbox.lock().queries.pop_front()?;
        let attachment = query
            .attachment()
            .and_then(|a| Attachment::from_bytes(&a.to_bytes()));
        Some(Request { query, attachment })
    }

    /// Requests dropped so far because `capacity` were waiting.
    pub fn dropped(&self) -> u64 {
        self.inbox.lock().dropped
    }

    /// Answers `request` with `cdr` (little-endian CDR fields, the encapsulation
    /// header is added) and the attachment rmw_zenoh's client matches it by: its
    /// sequence number and GID. A request without an attachment gets none back.
    pub fn reply(&self, request: Request, cdr: &[u8]) -> Result<(), ZenohError> {
        let mut payload = Vec::with_capacity(CDR_LE_HEADER.len() + cdr.len());
        payload.extend(CDR_LE_HEADER);
        payload.extend(cdr);
        let query = &request.query;
        let mut reply = query.reply(query.key_expr().clone(), payload);
        if let Some(a) = request.attachment {
            let attachment = Attachment {
                timestamp_ns: now_ns(),
                ..a
            };
            reply = reply.attachment(attachment.to_bytes());
        }
        reply
            .wait()
            .map_err(|e| ZenohError::Session(format!("replying: {e}")))
    }
}
