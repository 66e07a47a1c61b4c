//! Samples in process memory: what a memory [`Input`](super::Input) or
//! [`Output`](super::Output) holds, so tests drive a stage without shared memory.

use std::cell::RefCell;
use std::collections::VecDeque;
use std::rc::Rc;

use crate::ipc::StreamType;

/// A header and payload in process memory.
pub struct Owned<S: StreamType> {
    /// The header.
    pub header: S::Header,
    /// The payload.
    pub payload: Vec<S::Element>,
}

/// A queue of samples shared between a test and a memory [`Input`](super::Input) or [`Output`](super::Output).
pub type Queue<S> = Rc<RefCell<VecDeque<Owned<S>>>>;
