//! The stage runtime: the one event loop every service runs.
//!
//! A service implements [`Stage`] in its library crate — its inputs, what it does
//! when they have samples ([`Stage::on_wake`]), on every tick ([`Stage::on_tick`])
//! and when it stops ([`Stage::on_stop`]) — and its `main` hands it to [`run`].
//! The runtime does the I/O around it, the same way for every stage:
//!
//! * it creates the one iceoryx2 WaitSet of the loop, attaches the stage's inputs
//!   and an interval for its timer, and wakes the stage with the inputs that
//!   notified ([`Woken`]);
//! * an [`Input`] checks every sample's header (magic, version, stream, camera,
//!   payload size), counts it, counts sequence gaps as drops, and rejects a
//!   malformed sample with a rate-limited warning instead of passing it on; a
//!   reader that shows only the present takes the newest sample
//!   ([`Input::latest`]) and the ones it skipped count as its drops;
//! * an [`Output`] is a publisher sized for the largest payload so far (re-created
//!   when a payload needs more room), numbers its samples and forwards end of
//!   stream ([`Output::end_of_stream`]);
//! * [`Health`] reports and the systemd watchdog tick on every pass;
//! * one rule for failures: a WaitSet that cannot wait or a sample that cannot be
//!   sent ends the process as unavailable (its supervisor restarts it); a sample
//!   that cannot be received is warned about (rate-limited) and the loop goes on.
//!
//! Inputs and outputs also exist in memory ([`Input::memory`], [`Output::memory`]):
//! [`step`] then drives a stage without shared memory, which is how its unit tests
//! run.
//!
//! One pass of [`run`]'s loop: wait (up to `min(timer, 250 ms)`, or not at all if
//! the last pass left samples); drain the wake-ups, then [`Stage::on_wake`] with
//! the inputs that notified (after a full batch every input counts as woken);
//! [`Stage::on_tick`]; then [`Health::tick`] (watchdog, and a status report every
//! 5 s). An input yields at most 256 samples per pass; the rest are taken on the
//! next pass without waiting, so health and stop requests are never starved. On
//! stop, [`Stage::on_stop`] runs (after taking what is queued, if the stage asks
//! with [`Stage::take_inputs_on_stop`]) and a final report is published;
//! [`Stage::finished`] ends the loop as a stop request does (how a recording ends
//! by itself). A [`Notified`] input is one the stage reads by itself: the costmap
//! bridge's `<prefix>/plan` server, for which the runtime only wakes the stage
//! when a client notifies the plan's event service (un-notified requests are
//! found on the next pass). [`Output::send_in_place`] loans shared memory and
//! lets the stage write the payload there (motion writes its blocks this way,
//! zero-copy); a failed loan or writer is [`SendError::Skipped`] (that sample is
//! lost and counted, the stage goes on), while [`SendError::Failed`] ends the
//! process. `drives_the_motion_stage_through_the_runtime_without_shared_memory` in
//! `services/motion/src/stage.rs` is the model of a stage's unit test: frames, a
//! foreign camera's sample and a sequence gap in, then the motion samples, the end
//! of stream, and the received/rejected/dropped/sent counters checked.

use std::cell::{Cell, RefCell};
use std::collections::{HashMap, VecDeque};
use std::fmt::Debug;
use std::mem::MaybeUninit;
use std::rc::Rc;
use std::time::{Duration, Instant};

use iceoryx2::prelude::*;

use crate::health::{Health, notify_ready};
use crate::ipc::{Ipc, Ipc2, IpcError, ReceivedSample, StreamPublisher, StreamSubscriber};
use crate::ipc::{StreamType, stop_requested_by};
use crate::topology::StageKind;
use isochron_exit::Fatal;
use isochron_wire::{CameraId, FLAG_END_OF_STREAM, Preamble, StreamHeader};

/// The longest the loop sleeps when nothing arrives: health reports and the
/// watchdog tick at least this often.
pub const IDLE_TICK: Duration = Duration::from_millis(250);
/// Samples one input yields per wake before the loop ticks (health, stop) again;
/// the rest are taken on the next pass, without waiting.
const BATCH: u32 = 256;
/// Warnings of one kind issued at once before rate limiting starts.
const WARN_BURST: u64 = 10;
/// Then at most one warning of a kind per this interval (the rest are counted).
const WARN_EVERY: Duration = Duration::from_secs(5);

/// A service's work, driven by the runtime.
pub trait Stage {
    /// The stage's inputs: an [`Input`], a tuple (of 2, 3 or 5) or `Vec` of them,
    /// or any [`Inputs`].
    type Inputs: Inputs;

    /// Which stage this is (its health reports and logs say so).
    const KIND: StageKind;

    /// Inputs in `woken` have samples (or may have: a pass after a full batch wakes
    /// every input). Take them with [`Input::next`] until `None`.
    fn on_wake(
        &mut self,
        inputs: &Self::Inputs,
        woken: &Woken,
        cx: &mut Context,
    ) -> Result<(), Fatal>;

    /// Called on every pass after [`Stage::on_wake`], and at least every
    /// [`Stage::timer`] (or [`IDLE_TICK`]): timers, periodic output.
    fn on_tick(&mut self, _cx: &mut Context) -> Result<(), Fatal> {
        Ok(())
    }

    /// Called once when the process is asked to stop, before the final report.
    fn on_stop(&mut self, _cx: &mut Context) -> Result<(), Fatal> {
        Ok(())
    }

    /// True for a sink that must not lose what already arrived: when the process
    /// is asked to stop, its inputs are woken once more (what is queued for it is
    /// taken) before [`Stage::on_stop`]. Default false: the rest stop at once.
    fn take_inputs_on_stop(&self) -> bool {
        false
    }

    /// True once the stage has done its work (a recording that reached its end):
    /// the loop then ends as on a stop request (inputs taken once more if
    /// [`Stage::take_inputs_on_stop`], [`Stage::on_stop`], the final report).
    /// Asked before every pass. Default false: a service runs until it is stopped.
    fn finished(&self) -> bool {
        false
    }

    /// A period at which [`Stage::on_tick`] must run (default [`IDLE_TICK`]; it
    /// also runs on every other pass, and at least every [`IDLE_TICK`]).
    fn timer(&self) -> Duration {
        IDLE_TICK
    }

    /// Stage-specific counters for the status line (`key=value ...`).
    fn detail(&self) -> String;
}

/// What a stage's callbacks get besides its inputs: its health and its warnings.
pub struct Context {
    /// Counters, reports and the watchdog.
    pub health: Health,
    /// Rate-limited warnings.
    pub warnings: Warnings,
}

impl Context {
    /// The context of `kind` for `camera` ("" for a site-wide stage), publishing
    /// its status through `ipc` if given.
    pub fn new(kind: StageKind, camera: &str, ipc: Option<&Ipc>) -> Self {
        Context {
            health: Health::new(kind, camera, ipc),
            warnings: Warnings::default(),
        }
    }
}

/// Runs `stage` until the process is asked to stop (SIGINT, SIGTERM) or the stage
/// fails: the one event loop of every service.
pub fn run<S: Stage>(
    ipc: &Ipc,
    camera: &str,
    stage: &mut S,
    inputs: &S::Inputs,
) -> Result<(), Fatal> {
    let waitset = WaitSetBuilder::new()
        .create::<Ipc2>()
        .map_err(|e| ipc_error("creating the WaitSet", e))?;
    let attachables = inputs.attachables();
    let mut guards = Vec::with_capacity(attachables.len());
    for a in &attachables {
        guards.push(
            waitset
                .attach_notification(*a)
                .map_err(|e| ipc_error("attaching an input to the WaitSet", e))?,
        );
    }
    let timer = stage.timer();
    let _timer = waitset
        .attach_interval(timer)
        .map_err(|e| ipc_error("attaching the timer to the WaitSet", e))?;
    let idle = timer.min(IDLE_TICK);
    let mut cx = Context::new(S::KIND, camera, Some(ipc));
    notify_ready(&format!("{} {camera}", S::KIND));

    let mut more = false;
    while !ipc.should_stop() && !stage.finished() {
        let mut woken = Woken::default();
        // After a full batch, samples are still waiting: look again at once.
        let wait = if more { Duration::ZERO } else { idle };
        let result = waitset
            .wait_and_process_once_with_timeout(
                |id| {
                    for (k, g) in guards.iter().enumerate() {
                        if id.has_event_from(g) {
                            woken.set(k);
                        }
                    }
                    CallbackProgression::Continue
                },
                wait,
            )
            .map_err(|e| ipc_error("waiting on the WaitSet", e))?;
        if stop_requested_by(&result) {
            break;
        }
        if more {
            woken = Woken::all();
        }
        inputs.drain_wakeups();
        stage.on_wake(inputs, &woken, &mut cx)?;
        more = inputs.take_batch_full();
        stage.on_tick(&mut cx)?;
        cx.health.tick(|| stage.detail());
    }
    if stage.take_inputs_on_stop() {
        inputs.drain_wakeups();
        stage.on_wake(inputs, &Woken::all(), &mut cx)?;
    }
    stage.on_stop(&mut cx)?;
    cx.health.report(stage.detail());
    Ok(())
}

/// One pass of the loop without shared memory: every input is woken, then the
/// tick. For tests with [`Input::memory`] and [`Output::memory`].
pub fn step<S: Stage>(stage: &mut S, inputs: &S::Inputs, cx: &mut Context) -> Result<(), Fatal> {
    loop {
        stage.on_wake(inputs, &Woken::all(), cx)?;
        if !inputs.take_batch_full() {
            break;
        }
    }
    stage.on_tick(cx)
}

fn ipc_error(context: &str, e: impl Debug) -> IpcError {
    IpcError {
        context: context.into(),
        detail: format!("{e:?}"),
    }
}

/// Which inputs notified, by their position in [`Inputs::attachables`].
#[derive(Debug, Clone, Default)]
pub struct Woken {
    bits: u128,
    all: bool,
}

impl Woken {
    /// Every input.
    pub fn all() -> Self {
        Woken { bits: 0, all: true }
    }

    fn set(&mut self, k: usize) {
        if k < 128 {
            self.bits |= 1 << k;
        } else {
            self.all = true;
        }
    }

    /// True if input `k` notified.
    pub fn contains(&self, k: usize) -> bool {
        self.all || (k < 128 && self.bits & (1 << k) != 0)
    }
}

/// Something the WaitSet can wake on: a subscriber's listener, a server.
pub trait Attachable: FileDescriptorBased + Debug {}
impl<T: FileDescriptorBased + Debug> Attachable for T {}
impl SynchronousMultiplexing for dyn Attachable + '_ {}

/// A stage's set of inputs.
pub trait Inputs {
    /// What the WaitSet wakes on, in a fixed order (the positions [`Woken`] names).
    fn attachables(&self) -> Vec<&dyn Attachable>;
    /// Consumes the pending wake-up notifications (before samples are taken, so a
    /// sample arriving meanwhile wakes the next wait).
    fn drain_wakeups(&self) {}
    /// True if some input stopped at a full batch this pass (and resets that).
    fn take_batch_full(&self) -> bool {
        false
    }
}

impl Inputs for () {
    fn attachables(&self) -> Vec<&dyn Attachable> {
        Vec::new()
    }
}

impl<S: StreamType> Inputs for Input<S> {
    fn attachables(&self) -> Vec<&dyn Attachable> {
        match &self.port {
            InputPort::Shared(s) => vec![&**s as &dyn Attachable],
            InputPort::Memory(_) => Vec::new(),
        }
    }
    fn drain_wakeups(&self) {
        if let InputPort::Shared(s) = &self.port {
            s.drain_wakeups();
        }
    }
    fn take_batch_full(&self) -> bool {
        self.batch_full.replace(false)
    }
}

impl<I: Inputs> Inputs for Vec<I> {
    fn attachables(&self) -> Vec<&dyn Attachable> {
        self.iter().flat_map(Inputs::attachables).collect()
    }
    fn drain_wakeups(&self) {
        self.iter().for_each(Inputs::drain_wakeups);
    }
    fn take_batch_full(&self) -> bool {
        self.iter().fold(false, |any, i| i.take_batch_full() | any)
    }
}

macro_rules! tuple_inputs {
    ($($name:ident $k:tt),+) => {
        impl<$($name: Inputs),+> Inputs for ($($name,)+) {
            fn attachables(&self) -> Vec<&dyn Attachable> {
                let mut v = Vec::new();
                $(v.extend(self.$k.attachables());)+
                v
            }
            fn drain_wakeups(&self) {
                $(self.$k.drain_wakeups();)+
            }
            fn take_batch_full(&self) -> bool {
                false $(| self.$k.take_batch_full())+
            }
        }
    };
}
tuple_inputs!(A 0, B 1);
tuple_inputs!(A 0, B 1, C 2);
tuple_inputs!(A 0, B 1, C 2, D 3, E 4);

/// An input the stage reads (and drains the wake-ups of) by itself, such as a
/// request-response server: the runtime only wakes the stage for it.
#[derive(Debug)]
pub struct Notified<T>(pub T);

impl<T: Attachable> Inputs for Notified<T> {
    fn attachables(&self) -> Vec<&dyn Attachable> {
        vec![&self.0 as &dyn Attachable]
    }
}

/// A sample of stream `S`: in shared memory, or owned (tests).
pub enum Received<S: StreamType> {
    /// Borrowed from the publisher's shared memory until dropped.
    Shared(ReceivedSample<S>),
    /// A sample in process memory.
    Owned(Owned<S>),
}

impl<S: StreamType> Received<S> {
    /// The header.
    pub fn header(&self) -> &S::Header {
        match self {
            Received::Shared(s) => s.user_header(),
            Received::Owned(o) => &o.header,
        }
    }

    /// The payload.
    pub fn payload(&self) -> &[S::Element] {
        match self {
            Received::Shared(s) => s.payload(),
            Received::Owned(o) => &o.payload,
        }
    }

    /// True if this sample ends its stream.
    pub fn is_end_of_stream(&self) -> bool {
        self.header().preamble().is_end_of_stream()
    }
}

/// A header and payload in process memory.
pub struct Owned<S: StreamType> {
    /// The header.
    pub header: S::Header,
    /// The payload.
    pub payload: Vec<S::Element>,
}

/// A queue of samples shared between a test and a memory [`Input`] or [`Output`].
pub type Queue<S> = Rc<RefCell<VecDeque<Owned<S>>>>;

enum InputPort<S: StreamType> {
    Shared(Box<StreamSubscriber<S>>),
    Memory(Queue<S>),
}

/// The receiving end of stream `S` of one camera, for a stage: every sample it
/// yields has a valid header, and it counts what arrives, what was lost on the
/// way (sequence gaps) and what it rejected.
pub struct Input<S: StreamType> {
    port: InputPort<S>,
    camera: CameraId,
    last_sequence: Cell<Option<u64>>,
    taken: Cell<u32>,
    batch_full: Cell<bool>,
}

impl<S: StreamType> Input<S> {
    /// Subscribes to stream `S` of `camera`.
    pub fn open(ipc: &Ipc, camera: &str) -> Result<Self, IpcError> {
        let subscriber = ipc.subscriber::<S>(camera)?;
        Ok(Self::with_port(
            InputPort::Shared(Box::new(subscriber)),
            camera,
        ))
    }

    /// An input fed from memory: push samples into the returned queue.
    pub fn memory(camera: &str) -> (Self, Queue<S>) {
        let queue = Queue::<S>::default();
        (
            Self::with_port(InputPort::Memory(queue.clone()), camera),
            queue,
        )
    }

    fn with_port(port: InputPort<S>, camera: &str) -> Self {
        Input {
            port,
            camera: CameraId::new(camera).unwrap_or_default(),
            last_sequence: Cell::new(None),
            taken: Cell::new(0),
            batch_full: Cell::new(false),
        }
    }

    /// The next valid sample, or `None` when none is waiting (or this pass took a
    /// full batch: the runtime comes back at once). Malformed samples are counted
    /// as rejected and warned about, never returned.
    pub fn next(&self, cx: &mut Context) -> Option<Received<S>> {
        loop {
            if self.taken.get() >= BATCH {
                self.taken.set(0);
                self.batch_full.set(true);
                return None;
            }
            let sample = match &self.port {
                InputPort::Shared(s) => match s.receive() {
                    Ok(Some(sample)) => Received::Shared(sample),
                    Ok(None) => break,
                    Err(e) => {
                        cx.warnings.warn("receive", || e.to_string());
                        break;
                    }
                },
                InputPort::Memory(q) => match q.borrow_mut().pop_front() {
                    Some(o) => Received::Owned(o),
                    None => break,
                },
            };
            self.taken.set(self.taken.get() + 1);
            let header = sample.header();
            if let Err(e) = header.validate(&self.camera, sample.payload().len()) {
                cx.health.rejected();
                cx.warnings
                    .warn("header", || format!("rejected {} sample: {e}", S::STREAM));
                continue;
            }
            self.count(&mut cx.health, header.preamble().sequence);
            return Some(sample);
        }
        self.taken.set(0);
        None
    }

    /// The newest valid sample waiting, the older ones skipped: for a reader that
    /// shows only the present (the view's frames and motion). Every sample taken is
    /// checked and counted as [`Input::next`] does; a valid one skipped for a newer
    /// one counts as dropped by this stage. `None` when no valid sample waits. A
    /// full batch is skipped down to its newest sample, and the runtime comes back
    /// at once for the rest.
    pub fn latest(&self, cx: &mut Context) -> Option<Received<S>> {
        let mut newest = None;
        while let Some(sample) = self.next(cx) {
            if newest.replace(sample).is_some() {
                cx.health.dropped(1);
            }
        }
        newest
    }

    /// Counts a received sample; a gap in the sequence counts as dropped upstream,
    /// a sequence going backwards is a restarted publisher (not a loss).
    fn count(&self, health: &mut Health, sequence: u64) {
        health.read_one();
        if let Some(last) = self.last_sequence.get()
            && sequence > last + 1
        {
            health.dropped(sequence - last - 1);
        }
        self.last_sequence.set(Some(sequence));
    }
}

/// How a per-camera stage with one input and one output starts: the input of
/// `camera`'s upstream stream `I`, and the stage `make` builds on the output of
/// stream `O`.
pub fn one_in_one_out<'ipc, I: StreamType, O: StreamType, T>(
    ipc: &'ipc Ipc,
    camera: &str,
    make: impl FnOnce(Output<'ipc, O>) -> Result<T, Fatal>,
) -> Result<(T, Input<I>), Fatal> {
    let input = Input::open(ipc, camera)?;
    Ok((make(Output::new(ipc, camera))?, input))
}

enum OutputPort<'ipc, S: StreamType> {
    Shared {
        ipc: &'ipc Ipc,
        publisher: Option<Box<(StreamPublisher<S>, usize)>>,
    },
    Memory {
        queue: Queue<S>,
        sequence: u64,
    },
}

/// The publishing end of stream `S` of one camera, for a stage: sized for the
/// largest payload so far, numbering its samples.
pub struct Output<'ipc, S: StreamType> {
    port: OutputPort<'ipc, S>,
    camera: CameraId,
    camera_name: String,
}

impl<'ipc, S: StreamType> Output<'ipc, S> {
    /// The output of stream `S` of `camera`; the publisher is created by the first
    /// [`Output::reserve`] or send.
    pub fn new(ipc: &'ipc Ipc, camera: &str) -> Self {
        Output {
            port: OutputPort::Shared {
                ipc,
                publisher: None,
            },
            camera: CameraId::new(camera).unwrap_or_default(),
            camera_name: camera.to_string(),
        }
    }

    /// An output into memory: what is sent lands in the returned queue.
    pub fn memory(camera: &str) -> (Self, Queue<S>) {
        let queue = Queue::<S>::default();
        let output = Output {
            port: OutputPort::Memory {
                queue: queue.clone(),
                sequence: 0,
            },
            camera: CameraId::new(camera).unwrap_or_default(),
            camera_name: camera.to_string(),
        };
        (output, queue)
    }

    /// Makes sure a payload of `len` elements fits: creates the publisher, or
    /// re-creates it bigger (subscribers then see a new run, sequence from 0).
    pub fn reserve(&mut self, len: usize) -> Result<(), IpcError> {
        let OutputPort::Shared { ipc, publisher } = &mut self.port else {
            return Ok(());
        };
        if publisher.as_deref().is_some_and(|(_, cap)| *cap >= len) {
            return Ok(());
        }
        // One publisher per service: the old one must go first.
        if publisher.take().is_some() {
            tracing::info!(
                camera = %self.camera_name,
                "{} samples grew to {len} elements: new publisher",
                S::STREAM
            );
        }
        *publisher = Some(Box::new((ipc.publisher::<S>(&self.camera_name, len)?, len)));
        Ok(())
    }

    /// A preamble for the next sample of `len` elements (numbered), with the
    /// capture and origin times of `from` (the input it came from).
    pub fn preamble(&mut self, len: usize, from: &Preamble) -> Preamble {
        let sequence = match &mut self.port {
            OutputPort::Shared { publisher, .. } => publisher
                .as_deref_mut()
                .map_or(0, |(p, _)| p.next_sequence()),
            OutputPort::Memory { sequence, .. } => {
                *sequence += 1;
                *sequence - 1
            }
        };
        let mut p = Preamble::new::<S::Element>(S::STREAM, self.camera, sequence, len);
        p.capture_time_ns = from.capture_time_ns;
        p.origin_wall_ns = from.origin_wall_ns;
        p
    }

    /// Sends `header` (whose preamble came from [`Output::preamble`]) and a copy
    /// of `payload`.
    pub fn send_copy(&mut self, header: S::Header, payload: &[S::Element]) -> Result<(), IpcError> {
        self.reserve(payload.len())?;
        match &mut self.port {
            OutputPort::Shared { publisher, .. } => {
                let (p, _) = publisher.as_deref().expect("reserved");
                p.send_copy(header, payload).map(|_| ())
            }
            OutputPort::Memory { queue, .. } => {
                queue.borrow_mut().push_back(Owned {
                    header,
                    payload: payload.to_vec(),
                });
                Ok(())
            }
        }
    }

    /// Writes a payload of `len` elements in place (straight into shared memory)
    /// with `write`, then sends it with the header `header` makes from what `write`
    /// returned and the next preamble (times from `from`). Nothing is sent, and no
    /// sequence number used, if no sample can be loaned or `write` fails
    /// ([`SendError::Skipped`]).
    ///
    /// # Safety
    /// When `write` returns `Ok`, it must have initialised every element.
    pub unsafe fn send_in_place<T, E: std::fmt::Display>(
        &mut self,
        len: usize,
        from: &Preamble,
        write: impl FnOnce(&mut [MaybeUninit<S::Element>]) -> Result<T, E>,
        header: impl FnOnce(&T, Preamble) -> S::Header,
    ) -> Result<T, SendError> {
        self.reserve(len).map_err(SendError::Failed)?;
        if let OutputPort::Shared { publisher, .. } = &self.port {
            let (p, _) = publisher.as_deref().expect("reserved");
            // Every sample held by subscribers: this one is lost (and said so).
            let mut sample = p
                .loan(len)
                .map_err(|e| SendError::Skipped(format!("no sample to loan: {e}")))?;
            let out = write(sample.payload_mut()).map_err(|e| SendError::Skipped(e.to_string()))?;
            *sample.user_header_mut() = header(&out, self.preamble(len, from));
            // SAFETY: `write` returned Ok, so it initialised every element.
            let sample = unsafe { sample.assume_init() };
            if let OutputPort::Shared { publisher, .. } = &self.port {
                let (p, _) = publisher.as_deref().expect("reserved");
                p.send(sample).map_err(SendError::Failed)?;
            }
            return Ok(out);
        }
        let mut payload: Vec<MaybeUninit<S::Element>> = Vec::with_capacity(len);
        payload.resize_with(len, MaybeUninit::uninit);
        let out = write(&mut payload).map_err(|e| SendError::Skipped(e.to_string()))?;
        let h = header(&out, self.preamble(len, from));
        // SAFETY: `write` returned Ok, so every element is initialised.
        let payload = payload
            .into_iter()
            .map(|e| unsafe { e.assume_init() })
            .collect();
        if let OutputPort::Memory { queue, .. } = &self.port {
            queue.borrow_mut().push_back(Owned { header: h, payload });
        }
        Ok(out)
    }

    /// Passes an end of stream on: an empty sample flagged end of stream, with the
    /// times of `from` (the upstream end), after `fill` completed its header.
    pub fn end_of_stream(
        &mut self,
        from: &Preamble,
        fill: impl FnOnce(&mut S::Header),
    ) -> Result<(), IpcError> {
        self.reserve(1)?;
        let mut header = S::Header::default();
        *header.preamble_mut() = self.preamble(0, from);
        header.preamble_mut().flags = FLAG_END_OF_STREAM;
        fill(&mut header);
        self.send_copy(header, &[])
    }

    /// Subscribers connected now (0 in memory).
    pub fn subscriber_count(&self) -> usize {
        match &self.port {
            OutputPort::Shared { publisher, .. } => publisher
                .as_deref()
                .map_or(0, |(p, _)| p.subscriber_count()),
            OutputPort::Memory { .. } => 0,
        }
    }
}

/// Why [`Output::send_in_place`] sent nothing.
#[derive(Debug)]
pub enum SendError {
    /// This sample is lost (no loan, or the writer failed); the stage goes on.
    Skipped(String),
    /// Shared memory failed: the process should stop.
    Failed(IpcError),
}

/// Warnings that cannot flood the journal: of each kind, the first
/// [`WARN_BURST`] at once, then at most one per [`WARN_EVERY`] with a count of the
/// ones held back.
#[derive(Debug, Default)]
pub struct Warnings {
    kinds: HashMap<&'static str, WarnState>,
}

#[derive(Debug, Default)]
struct WarnState {
    issued: u64,
    last: Option<Instant>,
    held_back: u64,
}

impl Warnings {
    /// Warns `message()` unless warnings of `kind` are being held back.
    pub fn warn(&mut self, kind: &'static str, message: impl FnOnce() -> String) {
        let now = Instant::now();
        let s = self.kinds.entry(kind).or_default();
        if s.issued >= WARN_BURST && s.last.is_some_and(|t| now.duration_since(t) < WARN_EVERY) {
            s.held_back += 1;
            return;
        }
        let held = std::mem::take(&mut s.held_back);
        if held > 0 {
            tracing::warn!("{} ({held} similar warnings held back)", message());
        } else {
            tracing::warn!("{}", message());
        }
        s.issued += 1;
        s.last = Some(now);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ipc::Detections;
    use isochron_wire::{Detection, DetectionHeader, Stream};

    /// A detections sample of cam01 numbered `sequence` (of `camera` if given).
    fn sample(sequence: u64, camera: &str) -> Owned<Detections> {
        let id = CameraId::new(camera).unwrap();
        let header = DetectionHeader {
            preamble: Preamble::new::<Detection>(Stream::Detections, id, sequence, 0),
            source_index: sequence,
            ..Default::default()
        };
        Owned {
            header,
            payload: Vec::new(),
        }
    }

    #[test]
    fn latest_takes_the_newest_valid_sample_and_counts_what_it_skipped() {
        let (input, queue) = Input::<Detections>::memory("cam01");
        let mut cx = Context::new(StageKind::View, "", None);
        // 0 and 1 are skipped for 3; 2 never arrives; cam02's sample is rejected.
        queue.borrow_mut().extend([
            sample(0, "cam01"),
            sample(1, "cam01"),
            sample(3, "cam01"),
            sample(4, "cam02"),
        ]);
        let newest = input.latest(&mut cx).expect("a sample");
        assert_eq!(newest.header().source_index, 3);
        assert!(input.latest(&mut cx).is_none(), "nothing left");
        let status = cx.health.status();
        assert_eq!(status.received, 3);
        assert_eq!(status.rejected, 1);
        assert_eq!(status.dropped, 3, "two skipped here, one lost upstream");
    }

    #[test]
    fn latest_stops_at_a_full_batch_and_the_runtime_comes_back() {
        let (input, queue) = Input::<Detections>::memory("cam01");
        let mut cx = Context::new(StageKind::View, "", None);
        let n = BATCH as u64 + 10;
        queue
            .borrow_mut()
            .extend((0..n).map(|s| sample(s, "cam01")));
        let first = input.latest(&mut cx).expect("a sample");
        assert_eq!(first.header().source_index, BATCH as u64 - 1);
        assert!(input.take_batch_full(), "more waits");
        let second = input.latest(&mut cx).expect("the rest");
        assert_eq!(second.header().source_index, n - 1);
        assert!(!input.take_batch_full());
        assert_eq!(cx.health.status().dropped, n - 2);
    }
}
