//! A stage's outputs: a stream's publishing end, sized for the largest payload
//! so far and numbering its samples, in shared memory or (tests) in process
//! memory.

use std::fmt::Display;
use std::mem::MaybeUninit;

use super::memory::{Owned, Queue};
use crate::ipc::{Ipc, IpcError, StreamPublisher, StreamType};
use isochron_wire::{CameraId, FLAG_END_OF_STREAM, Preamble, StreamHeader};

enum OutputPort<'ipc, S: StreamType> {
    Shared {
        ipc: &'ipc Ipc,
        publisher: Option<Box<(StreamPublisher<S>, usize)>>,
    },
    Memory {
        queue: Queue<S>,
        sequence: u64,
        /// Samples the queue holds at most; a loan fails while it is full, as
        /// in shared memory when subscribers hold every sample.
        capacity: usize,
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
        Self::memory_bounded(camera, usize::MAX)
    }

    /// An output into memory that holds at most `capacity` samples: while the
    /// returned queue is that full, [`Output::send_in_place`] finds no sample to
    /// loan ([`SendError::NoLoan`]), as when subscribers hold every sample.
    pub fn memory_bounded(camera: &str, capacity: usize) -> (Self, Queue<S>) {
        let queue = Queue::<S>::default();
        let output = Output {
            port: OutputPort::Memory {
                queue: queue.clone(),
                sequence: 0,
                capacity,
            },
            camera: CameraId::new(camera).unwrap_or_default(),
            camera_name: camera.to_string(),
        };
        (output, queue)
    }

    /// Makes sure a payload of `len` elements fits: creates the publisher, or
    /// re-creates it bigger (subscribers then see a new run, sequence from 0).
    pub fn reserve(&mut self, len: usize) -> Result<(), IpcError> {
        self.publisher(len).map(|_| ())
    }

    /// The shared-memory publisher, reserved for `len` elements; `None` in memory.
    fn publisher(&mut self, len: usize) -> Result<Option<&StreamPublisher<S>>, IpcError> {
        let OutputPort::Shared { ipc, publisher } = &mut self.port else {
            return Ok(None);
        };
        if publisher.as_deref().is_none_or(|(_, cap)| *cap < len) {
            // One publisher per service: the old one must go first.
            if publisher.take().is_some() {
                tracing::info!(
                    camera = %self.camera_name,
                    "{} samples grew to {len} elements: new publisher",
                    S::STREAM
                );
            }
            *publisher = Some(Box::new((ipc.publisher::<S>(&self.camera_name, len)?, len)));
        }
        Ok(publisher.as_deref().map(|(p, _)| p))
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
        if let Some(p) = self.publisher(payload.len())? {
            return p.send_copy(header, payload).map(|_| ());
        }
        if let OutputPort::Memory { queue, .. } = &self.port {
            queue.borrow_mut().push_back(Owned {
                header,
                payload: payload.to_vec(),
            });
        }
        Ok(())
    }

    /// Writes a payload of `len` elements in place (straight into shared memory)
    /// with `write`, then sends it with the header `header` makes from what `write`
    /// returned and the next preamble (times from `from`). Nothing is sent, and no
    /// sequence number used, if no sample can be loaned ([`SendError::NoLoan`])
    /// or `write` fails ([`SendError::Write`], with its error).
    ///
    /// # Safety
    /// When `write` returns `Ok`, it must have initialised every element.
    pub unsafe fn send_in_place<T, E>(
        &mut self,
        len: usize,
        from: &Preamble,
        write: impl FnOnce(&mut [MaybeUninit<S::Element>]) -> Result<T, E>,
        header: impl FnOnce(&T, Preamble) -> S::Header,
    ) -> Result<T, SendError<E>> {
        if let Some(p) = self.publisher(len).map_err(SendError::Failed)? {
            // Every sample held by subscribers: this one is lost (and said so).
            let mut sample = p.loan(len).map_err(SendError::NoLoan)?;
            let out = write(sample.payload_mut()).map_err(SendError::Write)?;
            *sample.user_header_mut() = header(&out, self.preamble(len, from));
            // SAFETY: `write` returned Ok, so it initialised every element.
            let sample = unsafe { sample.assume_init() };
            if let Some(p) = self.publisher(len).map_err(SendError::Failed)? {
                p.send(sample).map_err(SendError::Failed)?;
            }
            return Ok(out);
        }
        if let OutputPort::Memory {
            queue, capacity, ..
        } = &self.port
            && queue.borrow().len() >= *capacity
        {
            return Err(SendError::NoLoan(IpcError {
                context: format!("loaning a {} sample of {len} elements", S::STREAM),
                detail: format!("the {capacity} samples of the memory output are all held"),
                permanent: false,
            }));
        }
        let mut payload: Vec<MaybeUninit<S::Element>> = Vec::with_capacity(len);
        payload.resize_with(len, MaybeUninit::uninit);
        let out = write(&mut payload).map_err(SendError::Write)?;
        let h = header(&out, self.preamble(len, from));
        let payload = payload
            .into_iter()
            // SAFETY: `write` returned Ok, so every element is initialised.
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
pub enum SendError<E> {
    /// No sample could be loaned: subscribers hold every one. This sample is
    /// lost, or the stage tries again later; it goes on either way.
    NoLoan(IpcError),
    /// The writer failed with this error: nothing was sent; the stage goes on.
    Write(E),
    /// Shared memory failed: the process should stop.
    Failed(IpcError),
}

impl<E: Display> Display for SendError<E> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SendError::NoLoan(e) => write!(f, "no sample to loan: {e}"),
            SendError::Write(e) => write!(f, "{e}"),
            SendError::Failed(e) => write!(f, "{e}"),
        }
    }
}

impl<E: std::error::Error + 'static> std::error::Error for SendError<E> {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            SendError::NoLoan(e) | SendError::Failed(e) => Some(e),
            SendError::Write(e) => e.source(),
        }
    }
}
