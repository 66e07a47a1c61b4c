//! The stage runtime: the one event loop every service runs.
//!
//! A service implements [`Stage`] in its library crate — its inputs, what it does
//! when they have samples ([`Stage::on_wake`]), when a time it asked for has come
//! ([`Stage::on_alarm`]), on every tick ([`Stage::on_tick`]) and when it stops
//! ([`Stage::on_stop`]) — and its `main` hands it to [`run`]. The runtime does
//! the I/O and the waiting around it, the same way for every stage:
//!
//! * it creates the one iceoryx2 WaitSet of the loop, attaches the stage's inputs,
//!   and wakes the stage when one of them notified (the stage takes what every
//!   input holds: taking from an empty input costs one atomic load);
//! * **timers** are the WaitSet's timeout, so no thread sleeps and nothing polls:
//!   the wait ends at the stage's alarm ([`Context::alarm_at`],
//!   [`Context::alarm_in`]: then [`Stage::on_alarm`] runs; one alarm per stage,
//!   a new one replaces the one pending) or when its tick is due
//!   ([`Stage::timer`], at most [`IDLE_TICK`] after the last pass: every pass
//!   ticks, so a busy loop gets no extra wake-up). A stage never sleeps: what it
//!   waits for is a time (an alarm), a sample (an input) or another thread's
//!   result (a [`Wakeup`]);
//! * **source stages** have no input (`type Inputs = ()`): they produce on their
//!   alarms. Capture is one — a file's frame rate, a camera's reconnect backoff
//!   and the retry of a loan are its alarms; decoding a frame is its work;
//! * an [`Input`] checks every sample's header (magic, version, stream, camera,
//!   payload size), counts it, counts sequence gaps as drops, and rejects a
//!   malformed sample with a rate-limited warning instead of passing it on; a
//!   reader that shows only the present takes the newest sample
//!   ([`Input::latest`]) and the ones it skipped count as its drops;
//! * a [`Wakeup`] is an input another thread of the process wakes ([`Waker`]):
//!   the gate's detector thread wakes the gate with each result;
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
//! run, and [`step_alarm`] fires its alarm as if its time had come.
//!
//! One pass of [`run`]'s loop: wait (until the alarm, at most `min(timer,
//! 250 ms)` after the last pass, or not at all if the last pass left samples);
//! drain the wake-ups, then [`Stage::on_wake`] with the inputs that notified
//! (after a full batch every input counts as woken); [`Stage::on_alarm`] if it
//! is due; [`Stage::on_tick`]; then the watchdog, and a status report every 5 s.
//! An input yields at most 256 samples per pass; the rest are taken on the next
//! pass without waiting, so health and stop requests are never starved. On
//! stop, [`Stage::on_stop`] runs (after taking what is queued, if the stage asks
//! with [`Stage::take_inputs_on_stop`]) and a final report is published;
//! [`Stage::finished`] ends the loop as a stop request does (how a recording ends
//! by itself). A [`Notified`] input is one the stage reads by itself: the costmap
//! bridge's `<prefix>/plan` server, for which the runtime only wakes the stage
//! when a client notifies the plan's event service (un-notified requests are
//! found on the next pass). [`Output::send_in_place`] loans shared memory and
//! lets the stage write the payload there (motion writes its blocks this way,
//! zero-copy); a failed loan ([`SendError::NoLoan`]) or writer
//! ([`SendError::Write`]) loses that sample (counted) and the stage goes on,
//! while [`SendError::Failed`] ends the process.
//! `drives_the_motion_stage_through_the_runtime_without_shared_memory` in
//! `services/motion/src/stage.rs` is the model of a stage's unit test: frames, a
//! foreign camera's sample and a sequence gap in, then the motion samples, the end
//! of stream, and the received/rejected/dropped/sent counters checked.

mod input;
mod memory;
mod output;
mod wakeup;
mod warnings;

use std::fmt::{Debug, Display};
use std::time::{Duration, Instant};

use iceoryx2::prelude::*;

use crate::counters::Counters;
use crate::health::{Health, notify_ready};
use crate::ipc::{Ipc, Ipc2, IpcError, StreamType, stop_requested_by};
use crate::topology::StageKind;
use isochron_exit::Fatal;

pub use input::{Input, Received};
pub use memory::{Owned, Queue};
pub use output::{Output, SendError};
pub use wakeup::{Waker, Wakeup};
pub use warnings::Warnings;

/// The longest the loop sleeps when nothing arrives: health reports and the
/// watchdog tick at least this often.
pub const IDLE_TICK: Duration = Duration::from_millis(250);

/// A service's work, driven by the runtime.
pub trait Stage {
    /// The stage's inputs: an [`Input`], a [`Wakeup`], `()` for none (a source
    /// stage), a tuple (of 2, 3 or 5), `Vec` or `Option` of them, or any
    /// [`Inputs`].
    type Inputs: Inputs;

    /// Which stage this is (its health reports and logs say so).
    const KIND: StageKind;

    /// Called once before the loop first waits: a source stage sets its first
    /// alarm here.
    fn on_start(&mut self, _cx: &mut Context) -> Result<(), Fatal> {
        Ok(())
    }

    /// Some input has samples (or may have). Take them with [`Input::next`] until
    /// `None`.
    fn on_wake(&mut self, inputs: &Self::Inputs, cx: &mut Context) -> Result<(), Fatal>;

    /// The time of the alarm the stage set ([`Context::alarm_at`]) has come; the
    /// alarm is cleared first, so the stage sets the next one here if it wants
    /// one. Called after [`Stage::on_wake`] of the same pass.
    fn on_alarm(&mut self, _cx: &mut Context) -> Result<(), Fatal> {
        Ok(())
    }

    /// Called on every pass after [`Stage::on_wake`] (and [`Stage::on_alarm`]),
    /// and at least every [`Stage::timer`] (or [`IDLE_TICK`]): periodic output.
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

    /// The longest time between two runs of [`Stage::on_tick`] (default and at
    /// most [`IDLE_TICK`]): it runs on every pass, and the loop wakes for it when
    /// no pass came for this long.
    fn timer(&self) -> Duration {
        IDLE_TICK
    }

    /// The stage's counters now: fill `counters` (its row's schema,
    /// [`crate::counters`]) by their constants.
    fn counters(&self, counters: &mut Counters);

    /// What the stage is and talks to, as text for status lines (`detector=hog`,
    /// `broker=…`; at most 96 bytes are published). Default none.
    fn info(&self) -> String {
        String::new()
    }
}

/// What a stage's callbacks get besides its inputs: its health, its warnings and
/// its alarm.
pub struct Context {
    /// Counters, reports and the watchdog.
    pub health: Health,
    /// Rate-limited warnings.
    pub warnings: Warnings,
    /// When [`Stage::on_alarm`] is due, if the stage asked.
    alarm: Option<Instant>,
    /// False for a context whose health is neither published nor logged.
    reported: bool,
}

impl Context {
    /// The context of `kind` for `camera` ("" for a site-wide stage), publishing
    /// its status through `ipc` if given.
    pub fn new(kind: StageKind, camera: &str, ipc: Option<&Ipc>) -> Self {
        Context {
            health: Health::new(kind, camera, ipc),
            warnings: Warnings::default(),
            alarm: None,
            reported: true,
        }
    }

    /// A context whose health is neither published nor logged (it still counts
    /// and feeds the watchdog): for a command that drives a stage of its own with
    /// [`run_in`], such as `isochron replay`'s collector, which is no service.
    pub fn unreported(kind: StageKind) -> Self {
        Context {
            reported: false,
            ..Context::new(kind, "", None)
        }
    }

    /// Asks for [`Stage::on_alarm`] at `at` (at once if it has passed). Replaces
    /// the alarm pending, if any.
    pub fn alarm_at(&mut self, at: Instant) {
        self.alarm = Some(at);
    }

    /// Asks for [`Stage::on_alarm`] in `after` from now.
    pub fn alarm_in(&mut self, after: Duration) {
        self.alarm_at(Instant::now() + after);
    }

    /// The alarm pending, if any.
    pub fn alarm(&self) -> Option<Instant> {
        self.alarm
    }

    /// Clears the alarm pending.
    pub fn cancel_alarm(&mut self) {
        self.alarm = None;
    }

    /// Clears the alarm and returns true if it is due at `now`.
    fn take_due_alarm(&mut self, now: Instant) -> bool {
        let due = self.alarm.is_some_and(|at| at <= now);
        if due {
            self.alarm = None;
        }
        due
    }

    /// How long the loop may wait at `now`: until the alarm, at most `limit`.
    fn wait_at(&self, now: Instant, limit: Duration) -> Duration {
        self.alarm
            .map_or(limit, |at| at.saturating_duration_since(now).min(limit))
    }

    /// The health's share of a pass: the watchdog, and `stage`'s report when due.
    fn tick<S: Stage>(&mut self, stage: &S) {
        if self.reported {
            self.health.tick(|| counters_of(stage));
        } else {
            self.health.keep_alive();
        }
    }
}

/// Runs `stage` until the process is asked to stop (SIGINT, SIGTERM), the stage
/// has finished or it fails: the one event loop of every service. Its status is
/// published and logged as `stage.KIND` of `camera`, and systemd is told it is
/// ready once the loop starts.
pub fn run<S: Stage>(
    ipc: &Ipc,
    camera: &str,
    stage: &mut S,
    inputs: &S::Inputs,
) -> Result<(), Fatal> {
    let mut cx = Context::new(S::KIND, camera, Some(ipc));
    let ready = format!("{} {camera}", S::KIND);
    drive(ipc, stage, inputs, &mut cx, Some(&ready))
}

/// Runs `stage` as [`run`] does, in a context the caller made (such as
/// [`Context::unreported`]) and without telling systemd anything: for a command
/// that drives a stage of its own.
pub fn run_in<S: Stage>(
    ipc: &Ipc,
    stage: &mut S,
    inputs: &S::Inputs,
    cx: &mut Context,
) -> Result<(), Fatal> {
    drive(ipc, stage, inputs, cx, None)
}

/// The loop of [`run`] and [`run_in`]; `ready` is the status systemd gets once
/// it starts (`None`: systemd is not told).
fn drive<S: Stage>(
    ipc: &Ipc,
    stage: &mut S,
    inputs: &S::Inputs,
    cx: &mut Context,
    ready: Option<&str>,
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
    // A source stage has no input: the WaitSet gets a wake-up no one wakes, as
    // a WaitSet with nothing attached cannot wait (its waits are all timeouts).
    let idle_wakeup = match attachables.is_empty() {
        true => Some(Wakeup::new().map_err(|e| {
            Fatal::with_source(isochron_exit::UNAVAILABLE, "creating the loop's wake-up", e)
        })?),
        false => None,
    };
    let _idle_guard = match &idle_wakeup {
        Some((wakeup, _)) => Some(
            waitset
                .attach_notification(wakeup as &dyn Attachable)
                .map_err(|e| ipc_error("attaching the loop's wake-up to the WaitSet", e))?,
        ),
        None => None,
    };
    let idle = stage.timer().min(IDLE_TICK);
    if let Some(status) = ready {
        notify_ready(status);
    }
    stage.on_start(cx)?;

    let mut more = false;
    // The tick is due `idle` after the last pass: a pass for an input or an
    // alarm ticks too, so the timer adds no wake-up to a busy loop.
    let mut last_pass = Instant::now();
    while !ipc.should_stop() && !stage.finished() {
        let now = Instant::now();
        // After a full batch, samples are still waiting: look again at once.
        let wait = if more {
            Duration::ZERO
        } else {
            cx.wait_at(now, (last_pass + idle).saturating_duration_since(now))
        };
        let result = waitset
            .wait_and_process_once_with_timeout(|_| CallbackProgression::Continue, wait)
            .map_err(|e| ipc_error("waiting on the WaitSet", e))?;
        if stop_requested_by(&result) {
            break;
        }
        last_pass = Instant::now();
        more = pass(stage, inputs, cx)?;
    }
    if stage.take_inputs_on_stop() {
        inputs.drain_wakeups();
        stage.on_wake(inputs, cx)?;
    }
    stage.on_stop(cx)?;
    if cx.reported {
        let (counters, info) = counters_of(stage);
        cx.health.report(&counters, &info);
    }
    Ok(())
}

/// `stage`'s counters and info now.
pub fn counters_of<S: Stage>(stage: &S) -> (Counters, String) {
    let mut counters = Counters::new(S::KIND.counters());
    stage.counters(&mut counters);
    (counters, stage.info())
}

/// One pass of the loop after its wait: the inputs, the alarm if it is due, the
/// tick. Returns true if an input stopped at a full batch.
fn pass<S: Stage>(stage: &mut S, inputs: &S::Inputs, cx: &mut Context) -> Result<bool, Fatal> {
    inputs.drain_wakeups();
    stage.on_wake(inputs, cx)?;
    let more = inputs.take_batch_full();
    if cx.take_due_alarm(Instant::now()) {
        stage.on_alarm(cx)?;
    }
    stage.on_tick(cx)?;
    cx.tick(stage);
    Ok(more)
}

/// One pass of the loop without shared memory: every input is woken (until no
/// full batch is left), the alarm fires if it is due, then the tick. For tests
/// with [`Input::memory`] and [`Output::memory`].
pub fn step<S: Stage>(stage: &mut S, inputs: &S::Inputs, cx: &mut Context) -> Result<(), Fatal> {
    loop {
        stage.on_wake(inputs, cx)?;
        if !inputs.take_batch_full() {
            break;
        }
    }
    if cx.take_due_alarm(Instant::now()) {
        stage.on_alarm(cx)?;
    }
    stage.on_tick(cx)
}

/// For tests: fires the stage's alarm as if its time had come (without waiting
/// for it), then the tick. Returns the time the alarm was set for; `None` (and
/// nothing runs) if the stage set none.
pub fn step_alarm<S: Stage>(stage: &mut S, cx: &mut Context) -> Result<Option<Instant>, Fatal> {
    let Some(at) = cx.alarm.take() else {
        return Ok(None);
    };
    stage.on_alarm(cx)?;
    stage.on_tick(cx)?;
    Ok(Some(at))
}

fn ipc_error(context: &str, e: impl Display) -> IpcError {
    IpcError {
        context: context.into(),
        detail: e.to_string(),
        permanent: false,
    }
}

/// Something the WaitSet can wake on: a subscriber's listener, a server.
pub trait Attachable: FileDescriptorBased + Debug {}
impl<T: FileDescriptorBased + Debug> Attachable for T {}
impl SynchronousMultiplexing for dyn Attachable + '_ {}

/// A stage's set of inputs.
pub trait Inputs {
    /// What the WaitSet wakes on.
    fn attachables(&self) -> Vec<&dyn Attachable>;
    /// Consumes the pending wake-up notifications (before samples are taken, so a
    /// sample arriving meanwhile wakes the next wait).
    fn drain_wakeups(&self) {}
    /// True if some input stopped at a full batch this pass (and resets that).
    fn take_batch_full(&self) -> bool {
        false
    }
}

/// No input: a source stage, which produces on its alarms.
impl Inputs for () {
    fn attachables(&self) -> Vec<&dyn Attachable> {
        Vec::new()
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

/// An input that may be absent (a stream no installed stage produces).
impl<I: Inputs> Inputs for Option<I> {
    fn attachables(&self) -> Vec<&dyn Attachable> {
        self.as_ref().map_or_else(Vec::new, Inputs::attachables)
    }
    fn drain_wakeups(&self) {
        if let Some(i) = self {
            i.drain_wakeups();
        }
    }
    fn take_batch_full(&self) -> bool {
        self.as_ref().is_some_and(Inputs::take_batch_full)
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

#[cfg(test)]
mod tests;
