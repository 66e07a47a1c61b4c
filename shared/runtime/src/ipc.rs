//! iceoryx2 setup: one node per process, one publish-subscribe service plus one
//! event service (for wake-ups) per stream, sized deliberately.
//!
//! Every process opens a stream through [`Ipc::publisher`] or [`Ipc::subscriber`],
//! so the service attributes (which iceoryx2 requires all openers to agree on) are
//! decided here only.
//!
//! Shared memory per publisher is preallocated for
//! `max_subscribers × (buffer + borrowed) + history + loaned` samples. For frames
//! that is the dominant memory cost of a camera, so the frame buffer is small (3 by
//! default) while the small streams buffer more.
//!
//! Delivery modes:
//! * live (default): a full subscriber buffer overwrites its oldest sample, so a
//!   stalled consumer (or a `tap` left in a pager) never blocks a producer;
//! * lossless (`ipc.lossless`, used by `isochron replay --speed max`): a publisher
//!   waits for room, up to `ipc.lossless_timeout_s` per stalled subscriber, so a
//!   recording runs as fast as the slowest stage and loses nothing. A new lossless
//!   publisher wakes existing subscribers and waits 250 ms so they connect before
//!   its first sample.
//!
//! With the defaults (5 subscribers, a frame buffer of 3, 2 borrowed samples per
//! subscriber, 2 loaned per publisher, no history) a camera's frames take 27
//! frames of shared memory ([`publisher_segment_bytes`]).
//!
//! Creating a node also removes stale resources of dead processes; [`node_census`]
//! is what `isochron doctor` reports, so doctor takes the census before it creates
//! any node, removes stale resources only with `--fix`, and without it creates no
//! node at all while some exist. SIGINT and SIGTERM are seen through handlers
//! installed after iceoryx2's (chaining to them) and kept in a process-wide flag
//! ([`request_stop`], [`Ipc::should_stop`]), so every camera thread stops, and a
//! SIGCONT right after SIGTERM (systemd's stop sequence) cannot erase the request
//! as it would iceoryx2's own last-signal record.

use std::fmt::Debug;
use std::mem::MaybeUninit;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use iceoryx2::port::BackpressureAction;
use iceoryx2::port::backpressure_strategy::BackpressureStrategy;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;
use iceoryx2::sample_mut::SampleMut;
use iceoryx2::sample_mut_uninit::SampleMutUninit;
use iceoryx2::service::port_factory::PortFactory as _;
use iceoryx2::service::port_factory::event::PortFactory as PortFactoryEvent;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use iceoryx2::waitset::WaitSetRunResult;

mod error;
pub mod node_counter;

pub use error::IpcError;
use error::err;

use crate::names::ServiceNames;
use crate::topology::StageKind;
use isochron_config::{Config, IpcConfig};
use isochron_wire::{
    ActivityHeader, BlockActivity, BlockMotion, Detection, DetectionHeader, EventHeader,
    FrameHeader, MotionHeader, StageStatus, Stream, StreamHeader,
};

/// The iceoryx2 service flavour all isochron processes use: inter-process.
pub type Ipc2 = ipc::Service;

/// Samples a subscriber may hold at once. Motion holds the previous and the current
/// frame; everything else holds one.
const MAX_BORROWED: usize = 2;
/// Samples a publisher may have loaned at once.
const MAX_LOANED: usize = 2;

/// A stream's header and payload element types.
pub trait StreamType {
    /// The stream.
    const STREAM: Stream;
    /// The user header.
    type Header: StreamHeader + Debug + ZeroCopySend + 'static;
    /// One payload element.
    type Element: Debug + ZeroCopySend + Copy + 'static;
}

/// Declares the marker type of a stream (named as its [`Stream`] variant) and its
/// [`StreamType`].
macro_rules! stream_type {
    ($(#[$doc:meta])* $name:ident: $header:ty, $element:ty) => {
        $(#[$doc])*
        pub struct $name;
        impl StreamType for $name {
            const STREAM: Stream = Stream::$name;
            type Header = $header;
            type Element = $element;
        }
    };
}

stream_type!(
    /// `frames`: [`FrameHeader`] + bytes.
    Frames: FrameHeader, u8
);
stream_type!(
    /// `motion`: [`MotionHeader`] + [`BlockMotion`]s.
    Motion: MotionHeader, BlockMotion
);
stream_type!(
    /// `activity`: [`ActivityHeader`] + [`BlockActivity`]s.
    Activity: ActivityHeader, BlockActivity
);
stream_type!(
    /// `events`: [`EventHeader`] + block indices.
    Events: EventHeader, u32
);
stream_type!(
    /// `detections`: [`DetectionHeader`] + [`Detection`]s.
    Detections: DetectionHeader, Detection
);

type Factory<S> = PortFactory<Ipc2, [<S as StreamType>::Element], <S as StreamType>::Header>;

/// The process's iceoryx2 node and the site's naming and sizing.
pub struct Ipc {
    node: Node<Ipc2>,
    names: ServiceNames,
    config: IpcConfig,
}

/// Set once SIGINT or SIGTERM arrived: iceoryx2 reports a signal only once, to
/// whichever node or WaitSet asks first, so the answer is kept for every thread.
static STOP_REQUESTED: AtomicBool = AtomicBool::new(false);

/// Marks the process as stopping (for example when a WaitSet reported the
/// termination request): every [`Ipc::should_stop`] answers true from now on.
pub fn request_stop() {
    STOP_REQUESTED.store(true, Ordering::SeqCst);
}

/// True once SIGINT or SIGTERM arrived (or a stop was requested), without asking
/// iceoryx2: for loops that must stop on a signal but wait on nothing.
pub fn stop_signalled() -> bool {
    STOP_REQUESTED.load(Ordering::Relaxed)
}

/// Makes SIGINT and SIGTERM set the process's stop flag, once per process.
///
/// iceoryx2 remembers only the last signal that arrived, so a SIGTERM followed at
/// once by a SIGCONT (systemd's stop sequence, GNU `timeout`) would be forgotten;
/// this flag, once set, stays set. The handler only stores an atomic, which is
/// async-signal-safe, and then calls the handler installed before it.
fn watch_stop_signals() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
            // SAFETY: the action only stores to an atomic (async-signal-safe).
            let registered = unsafe { signal_hook::low_level::register(signal, request_stop) };
            if let Err(e) = registered {
                tracing::warn!("cannot watch signal {signal}: {e}; stop requests rely on iceoryx2");
            }
        }
    });
}

/// Makes this user's iceoryx2 node counter owner-only, or refuses one that other
/// users may write ([`node_counter`]).
fn guard_node_counter() -> Result<(), IpcError> {
    let prefix = iceoryx2::config::Config::global_config()
        .global
        .prefix
        .to_string();
    let dir = std::path::Path::new(node_counter::SHM_DIR);
    match node_counter::check(dir, &prefix, node_counter::euid()) {
        Ok(repaired) => {
            for file in repaired {
                tracing::info!(
                    "{} was writable by every local user (an older iceoryx2 made it so): now owner-only",
                    file.display()
                );
            }
            Ok(())
        }
        Err(unsafe_file) => Err(IpcError {
            context: "checking the node counter before creating a node".into(),
            detail: unsafe_file.to_string(),
            permanent: true,
        }),
    }
}

/// True if a WaitSet's `result` asks the process to stop (SIGINT, SIGTERM); it
/// then also makes [`Ipc::should_stop`] true in every thread of the process.
pub fn stop_requested_by(result: &WaitSetRunResult) -> bool {
    let stop = matches!(
        result,
        WaitSetRunResult::TerminationRequest | WaitSetRunResult::Interrupt
    );
    if stop {
        request_stop();
    }
    stop
}

impl Ipc {
    /// Creates the node `name` (shown by `iox2 node list`). Creating a node also
    /// removes the stale resources of dead isochron processes. iceoryx2 installs
    /// SIGINT/SIGTERM handlers; see [`Ipc::should_stop`].
    pub fn new(name: &str, names: ServiceNames, config: IpcConfig) -> Result<Self, IpcError> {
        let node_name: NodeName = name
            .try_into()
            .map_err(|e| err(format!("invalid node name '{name}'"))(&e))?;
        // iceoryx2 warns when it runs on its built-in defaults, which isochron does
        // on purpose; keep its own log to errors unless IOX2_LOG_LEVEL says otherwise.
        set_log_level_from_env_or(LogLevel::Error);
        guard_node_counter()?;
        let node = NodeBuilder::new()
            .name(&node_name)
            .create::<Ipc2>()
            .map_err(|e| err("creating the node")(&e))?;
        // iceoryx2's own signal handler is installed by its first question; ours
        // comes after it, and chains to it.
        let _ = node.wait(Duration::ZERO);
        watch_stop_signals();
        Ok(Ipc {
            node,
            names,
            config,
        })
    }

    /// Creates the node `name` on the site of `config`: its service prefix and its
    /// IPC settings.
    pub fn of_site(name: &str, config: &Config) -> Result<Self, IpcError> {
        Ipc::new(
            name,
            ServiceNames::new(&config.site.service_prefix),
            config.ipc.clone(),
        )
    }

    /// The node.
    pub fn node(&self) -> &Node<Ipc2> {
        &self.node
    }

    /// The site's service names.
    pub fn names(&self) -> &ServiceNames {
        &self.names
    }

    /// The transport settings.
    pub fn config(&self) -> &IpcConfig {
        &self.config
    }

    /// True once SIGINT or SIGTERM was received, in any thread of the process.
    pub fn should_stop(&self) -> bool {
        if STOP_REQUESTED.load(Ordering::Relaxed) {
            return true;
        }
        let stop = self.node.wait(Duration::ZERO).is_err();
        if stop {
            request_stop();
        }
        stop
    }

    fn service_name(text: &str) -> Result<ServiceName, IpcError> {
        text.try_into()
            .map_err(|e| err(format!("invalid service name '{text}'"))(&e))
    }

    fn buffer_of(&self, stream: Stream) -> usize {
        match stream {
            Stream::Frames => self.config.frame_buffer,
            _ => self.config.stream_buffer,
        }
    }

    fn open_pubsub<S: StreamType>(&self, camera: &str) -> Result<Factory<S>, IpcError> {
        let name = self.names.stream(camera, S::STREAM);
        self.node
            .service_builder(&Self::service_name(&name)?)
            .publish_subscribe::<[S::Element]>()
            .user_header::<S::Header>()
            .max_publishers(1)
            .max_subscribers(self.config.max_subscribers)
            .subscriber_max_buffer_size(self.buffer_of(S::STREAM))
            .subscriber_max_borrowed_samples(MAX_BORROWED)
            .history_size(0)
            .enable_safe_overflow(!self.config.lossless)
            .open_or_create()
            .map_err(|e| {
                err(format!(
                    "opening service '{name}' (another isochron version or other [ipc] settings may own it)"
                ))(&e)
            })
    }

    fn open_event(&self, camera: &str, stream: Stream) -> Result<PortFactoryEvent<Ipc2>, IpcError> {
        let name = self.names.stream(camera, stream);
        self.node
            .service_builder(&Self::service_name(&name)?)
            .event()
            .open_or_create()
            .map_err(|e| err(format!("opening event service '{name}'"))(&e))
    }

    /// The publisher of stream `S` of `camera`; `max_len` is the largest payload
    /// (elements) it will ever send, fixed for its lifetime.
    pub fn publisher<S: StreamType>(
        &self,
        camera: &str,
        max_len: usize,
    ) -> Result<StreamPublisher<S>, IpcError> {
        let service = self.open_pubsub::<S>(camera)?;
        let mut builder = service
            .publisher_builder()
            .initial_max_slice_len(max_len.max(1))
            .max_loaned_samples(MAX_LOANED);
        if self.config.lossless {
            let timeout = isochron_config::clock::saturating_secs(self.config.lossless_timeout_s);
            let stream = S::STREAM;
            builder = builder
                .backpressure_strategy(BackpressureStrategy::RetryUntilDelivered)
                .set_backpressure_handler(move |info: &iceoryx2::port::BackpressureInfo| {
                    if info.elapsed_time < timeout {
                        BackpressureAction::Retry
                    } else {
                        tracing::warn!(
                            %stream,
                            waited_s = info.elapsed_time.as_secs_f64(),
                            "a subscriber has not read for the lossless timeout; dropping its sample"
                        );
                        BackpressureAction::DiscardData
                    }
                });
        } else {
            builder = builder.backpressure_strategy(BackpressureStrategy::DiscardData);
        }
        let publisher = builder.create().map_err(|e| {
            err(format!(
                "creating the {} publisher of '{camera}'",
                S::STREAM
            ))(&e)
        })?;
        let notifier = self
            .open_event(camera, S::STREAM)?
            .notifier_builder()
            .create()
            .map_err(|e| err("creating a notifier")(&e))?;
        let publisher = StreamPublisher {
            publisher,
            notifier,
            service,
            sequence: 0,
        };
        if self.config.lossless && publisher.subscriber_count() > 0 {
            publisher.let_subscribers_connect()?;
        }
        Ok(publisher)
    }

    /// A subscriber of stream `S` of `camera`.
    pub fn subscriber<S: StreamType>(&self, camera: &str) -> Result<StreamSubscriber<S>, IpcError> {
        let service = self.open_pubsub::<S>(camera)?;
        let subscriber = service.subscriber_builder().create().map_err(|e| {
            err(format!(
                "creating the {} subscriber of '{camera}'",
                S::STREAM
            ))(&e)
        })?;
        let listener = self
            .open_event(camera, S::STREAM)?
            .listener_builder()
            .create()
            .map_err(|e| err("creating a listener")(&e))?;
        Ok(StreamSubscriber {
            subscriber,
            listener,
            service,
        })
    }

    /// Number of subscribers currently connected to stream `stream` of `camera`,
    /// or `None` if the service does not exist.
    pub fn subscriber_count(&self, camera: &str, stream: Stream) -> Option<usize> {
        macro_rules! count {
            ($s:ty) => {
                self.open_pubsub::<$s>(camera)
                    .ok()
                    .map(|f| f.dynamic_config().number_of_subscribers())
            };
        }
        match stream {
            Stream::Frames => count!(Frames),
            Stream::Motion => count!(Motion),
            Stream::Activity => count!(Activity),
            Stream::Events => count!(Events),
            Stream::Detections => count!(Detections),
        }
    }
}

impl Ipc {
    fn open_status(&self, camera: &str, stage: StageKind) -> Result<StatusFactory, IpcError> {
        let name = self.names.status(camera, stage);
        self.node
            .service_builder(&Self::service_name(&name)?)
            .publish_subscribe::<StageStatus>()
            .max_publishers(1)
            .max_subscribers(16)
            .history_size(1)
            .subscriber_max_buffer_size(1)
            .subscriber_max_borrowed_samples(1)
            .enable_safe_overflow(true)
            .open_or_create()
            .map_err(|e| err(format!("opening status service '{name}'"))(&e))
    }

    /// The publisher of `stage`'s status for `camera`.
    pub fn status_publisher(
        &self,
        camera: &str,
        stage: StageKind,
    ) -> Result<StatusPublisher, IpcError> {
        let publisher = self
            .open_status(camera, stage)?
            .publisher_builder()
            .create()
            .map_err(|e| err(format!("creating the status publisher of {stage}/{camera}"))(&e))?;
        Ok(StatusPublisher { publisher })
    }

    /// How many processes publish `stage`'s status for `camera` now (0 or 1): whether
    /// a stage run on demand, such as the view, is running.
    pub fn status_publishers(&self, camera: &str, stage: StageKind) -> usize {
        self.open_status(camera, stage)
            .map_or(0, |f| f.dynamic_config().number_of_publishers())
    }

    /// A reader of `stage`'s status for `camera` (the latest report arrives at once
    /// if the stage runs).
    pub fn status_subscriber(
        &self,
        camera: &str,
        stage: StageKind,
    ) -> Result<StatusSubscriber, IpcError> {
        let subscriber = self
            .open_status(camera, stage)?
            .subscriber_builder()
            .create()
            .map_err(|e| {
                err(format!(
                    "creating the status subscriber of {stage}/{camera}"
                ))(&e)
            })?;
        Ok(StatusSubscriber { subscriber })
    }
}

/// Reads a stage's [`StageStatus`] reports.
pub struct StatusSubscriber {
    subscriber: Subscriber<Ipc2, StageStatus, ()>,
}

impl StatusSubscriber {
    /// The newest report received so far, if any.
    pub fn latest(&self) -> Option<StageStatus> {
        let mut last = None;
        while let Ok(Some(sample)) = self.subscriber.receive() {
            last = Some(*sample.payload());
        }
        last
    }
}

type StatusFactory = PortFactory<Ipc2, StageStatus, ()>;

/// Publishes a stage's [`StageStatus`] (the latest is kept for late readers).
pub struct StatusPublisher {
    publisher: Publisher<Ipc2, StageStatus, ()>,
}

impl StatusPublisher {
    /// Hands the latest report to readers that subscribed since the last call
    /// (iceoryx2 connects a new subscriber, and delivers the history, only when
    /// the publisher updates its connections).
    pub fn update_connections(&self) {
        use iceoryx2::port::update_connections::UpdateConnections;
        let _ = self.publisher.update_connections();
    }

    /// Publishes `status`.
    pub fn publish(&self, status: StageStatus) -> Result<(), IpcError> {
        self.publisher
            .send_copy(status)
            .map(|_| ())
            .map_err(|e| err("publishing a status")(&e))
    }
}

/// The iceoryx2 nodes of this machine, as `isochron doctor` reports them.
#[derive(Debug, Default, Clone)]
pub struct NodeCensus {
    /// Names of nodes whose process is alive.
    pub alive: Vec<String>,
    /// Nodes of dead processes whose stale resources were removed.
    pub dead_removed: Vec<String>,
    /// Nodes of dead processes that could not be cleaned (permissions).
    pub dead_left: Vec<String>,
    /// Nodes this user may not inspect (another user's).
    pub inaccessible: usize,
}

/// Lists the iceoryx2 nodes and, if `remove_dead`, removes the resources dead
/// processes left behind (a crash or `kill -9` leaves shared memory and files).
/// Run it before creating a node: creating one cleans dead nodes silently.
pub fn node_census(remove_dead: bool) -> Result<NodeCensus, IpcError> {
    use iceoryx2::node::NodeView;
    set_log_level_from_env_or(LogLevel::Error);
    let mut census = NodeCensus::default();
    let name_of = |d: Option<&iceoryx2::node::NodeDetails>| {
        d.map(|d| d.name().to_string())
            .unwrap_or_else(|| "(unnamed)".into())
    };
    Node::<Ipc2>::list(iceoryx2::config::Config::global_config(), |state| {
        match state {
            NodeState::Alive(view) => census.alive.push(name_of(view.details().as_ref())),
            NodeState::Dead(view) => {
                let name = name_of(view.details().as_ref());
                if remove_dead
                    && view
                        .blocking_remove_stale_resources(Duration::from_secs(1))
                        .is_ok()
                {
                    census.dead_removed.push(name);
                } else {
                    census.dead_left.push(name);
                }
            }
            NodeState::Inaccessible(_) | NodeState::Undefined(_) => census.inaccessible += 1,
        }
        CallbackProgression::Continue
    })
    .map_err(|e| err("listing iceoryx2 nodes")(&e))?;
    Ok(census)
}

/// Shared memory a publisher of `payload_bytes` per sample preallocates under
/// `config`: `max_subscribers × (buffer + borrowed) + loaned` samples (history is 0).
pub fn publisher_segment_bytes(config: &IpcConfig, stream: Stream, payload_bytes: usize) -> usize {
    let buffer = match stream {
        Stream::Frames => config.frame_buffer,
        _ => config.stream_buffer,
    };
    let samples = config.max_subscribers * (buffer + MAX_BORROWED) + MAX_LOANED;
    samples * payload_bytes
}

/// The publishing end of a stream: sends samples and wakes subscribers.
pub struct StreamPublisher<S: StreamType> {
    publisher: Publisher<Ipc2, [S::Element], S::Header>,
    notifier: Notifier<Ipc2>,
    service: Factory<S>,
    sequence: u64,
}

/// A loaned, not yet initialised sample of stream `S`.
pub type LoanedSample<S> =
    SampleMutUninit<Ipc2, [MaybeUninit<<S as StreamType>::Element>], <S as StreamType>::Header>;

/// An initialised sample of stream `S`, ready to send.
pub type ReadySample<S> = SampleMut<Ipc2, [<S as StreamType>::Element], <S as StreamType>::Header>;

/// A received sample of stream `S`.
pub type ReceivedSample<S> = Sample<Ipc2, [<S as StreamType>::Element], <S as StreamType>::Header>;

impl<S: StreamType> StreamPublisher<S> {
    /// Loans shared memory for `len` payload elements. Write the payload in place,
    /// then [`StreamPublisher::send`] it.
    pub fn loan(&self, len: usize) -> Result<LoanedSample<S>, IpcError> {
        self.publisher
            .loan_slice_uninit(len)
            .map_err(|e| err(format!("loaning a {} sample of {len} elements", S::STREAM))(&e))
    }

    /// The next sequence number (0, 1, 2, ...), incremented by each call.
    pub fn next_sequence(&mut self) -> u64 {
        let s = self.sequence;
        self.sequence += 1;
        s
    }

    /// Sends a sample and wakes the subscribers. Returns the number of receivers.
    pub fn send(&self, sample: ReadySample<S>) -> Result<usize, IpcError> {
        let n = sample
            .send()
            .map_err(|e| err(format!("sending a {} sample", S::STREAM))(&e))?;
        self.wake_subscribers()?;
        Ok(n)
    }

    /// Copies `header` and `payload` into a sample and sends it (for small payloads).
    pub fn send_copy(&self, header: S::Header, payload: &[S::Element]) -> Result<usize, IpcError> {
        let mut sample = self.loan(payload.len())?;
        *sample.user_header_mut() = header;
        let sample = sample.write_from_slice(payload);
        self.send(sample)
    }

    /// Subscribers currently connected.
    pub fn subscriber_count(&self) -> usize {
        self.service.dynamic_config().number_of_subscribers()
    }

    /// How long a new lossless publisher gives existing subscribers to connect.
    const CONNECT_GRACE: Duration = Duration::from_millis(250);

    /// A new publisher is connected to a subscriber that existed before it only
    /// once that subscriber next reads; until then iceoryx2 drops what overflows
    /// its queue, even in lossless mode (to avoid a deadlock on a dead reader).
    /// So wake every subscriber (each read connects it) and give them a moment
    /// before the first sample.
    fn let_subscribers_connect(&self) -> Result<(), IpcError> {
        self.wake_subscribers()?;
        std::thread::sleep(Self::CONNECT_GRACE);
        Ok(())
    }

    /// Notifies the stream's event: every subscriber's WaitSet wakes.
    fn wake_subscribers(&self) -> Result<(), IpcError> {
        self.notifier
            .notify()
            .map(|_| ())
            .map_err(|e| err(format!("notifying {} subscribers", S::STREAM))(&e))
    }
}

/// The receiving end of a stream. Attach it to a [`WaitSet`] to wake on new samples,
/// then [`StreamSubscriber::drain_wakeups`] and [`StreamSubscriber::receive`] until
/// `None`.
pub struct StreamSubscriber<S: StreamType> {
    subscriber: Subscriber<Ipc2, [S::Element], S::Header>,
    listener: Listener<Ipc2>,
    service: Factory<S>,
}

impl<S: StreamType> Debug for StreamSubscriber<S> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "StreamSubscriber({})", S::STREAM)
    }
}

impl<S: StreamType> FileDescriptorBased for StreamSubscriber<S> {
    fn file_descriptor(&self) -> &FileDescriptor {
        self.listener.file_descriptor()
    }
}

impl<S: StreamType> SynchronousMultiplexing for StreamSubscriber<S> {}

impl<S: StreamType> StreamSubscriber<S> {
    /// Takes the next sample, if any.
    pub fn receive(&self) -> Result<Option<ReceivedSample<S>>, IpcError> {
        self.subscriber
            .receive()
            .map_err(|e| err(format!("receiving a {} sample", S::STREAM))(&e))
    }

    /// True when a sample is waiting (without taking it).
    pub fn has_samples(&self) -> Result<bool, IpcError> {
        self.subscriber
            .has_samples()
            .map_err(|e| err(format!("checking for {} samples", S::STREAM))(&e))
    }

    /// Consumes pending wake-up notifications (call after the WaitSet woke up).
    pub fn drain_wakeups(&self) {
        let _ = self.listener.try_wait(|_| {});
    }

    /// Waits up to `timeout` for a wake-up (for simple loops without a WaitSet).
    pub fn wait(&self, timeout: Duration) {
        let _ = self.listener.timed_wait(|_| {}, timeout);
    }

    /// Publishers currently connected.
    pub fn publisher_count(&self) -> usize {
        self.service.dynamic_config().number_of_publishers()
    }
}
