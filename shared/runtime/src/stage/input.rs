//! A stage's inputs: a stream's receiving end that checks and counts every
//! sample it yields, in shared memory or (tests) in process memory.

use std::cell::Cell;

use super::memory::{Owned, Queue};
use super::{Attachable, Context, Inputs};
use crate::health::Health;
use crate::ipc::{Ipc, IpcError, ReceivedSample, StreamSubscriber, StreamType};
use isochron_wire::{CameraId, StreamHeader};

/// Samples one input yields per wake before the loop ticks (health, stop) again;
/// the rest are taken on the next pass, without waiting.
const BATCH: u32 = 256;

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ipc::Detections;
    use crate::topology::StageKind;
    use isochron_wire::{Detection, DetectionHeader, Preamble, Stream};

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
