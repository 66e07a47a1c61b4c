//! A wake-up another thread of the process gives a stage: the runtime waits on
//! it with the stage's inputs, so a stage that hands work to a thread of its own
//! (the gate's detector) hears of the results as they come, without polling.
//!
//! It is a pair of connected Unix datagram sockets: the [`Waker`] (any thread)
//! sends one byte, the [`Wakeup`] (an input of the stage) is what the WaitSet
//! watches; the runtime reads the bytes back before the stage's
//! [`Stage::on_wake`](super::Stage::on_wake). A wake-up costs a `send` and the
//! wake of the loop: give one per result, not per item of work.

use std::os::fd::AsRawFd;
use std::os::unix::net::UnixDatagram;
use std::sync::Arc;

use iceoryx2::prelude::*;

use super::{Attachable, Inputs};

/// The end of a wake-up the runtime waits on: one of a stage's [`Inputs`].
pub struct Wakeup {
    socket: UnixDatagram,
    /// The socket's descriptor as iceoryx2 sees it (not owning: `socket` closes it).
    fd: FileDescriptor,
}

/// The end of a wake-up another thread holds: [`Waker::wake`] wakes the stage.
/// Cheap to clone; waking a stage that has ended does nothing.
#[derive(Clone)]
pub struct Waker {
    socket: Arc<UnixDatagram>,
}

impl Wakeup {
    /// A new wake-up: the input for the stage and the waker for the thread.
    pub fn new() -> std::io::Result<(Wakeup, Waker)> {
        let (watched, sender) = UnixDatagram::pair()?;
        watched.set_nonblocking(true)?;
        sender.set_nonblocking(true)?;
        let fd = FileDescriptor::non_owning_new(watched.as_raw_fd())
            .ok_or_else(|| std::io::Error::other("the wake-up socket's descriptor is not valid"))?;
        Ok((
            Wakeup {
                socket: watched,
                fd,
            },
            Waker {
                socket: Arc::new(sender),
            },
        ))
    }

    /// Takes the pending wake-ups; true if there were any.
    pub fn take(&self) -> bool {
        let mut byte = [0u8; 1];
        let mut any = false;
        while self.socket.recv(&mut byte).is_ok() {
            any = true;
        }
        any
    }
}

impl Waker {
    /// Wakes the stage (once, however often it is called before the stage runs).
    pub fn wake(&self) {
        // A full socket (WouldBlock) already wakes the stage; a closed one has
        // no stage left to wake: neither is an error.
        let _ = self.socket.send(&[1]);
    }
}

impl std::fmt::Debug for Wakeup {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Wakeup({:?})", self.socket)
    }
}

impl FileDescriptorBased for Wakeup {
    fn file_descriptor(&self) -> &FileDescriptor {
        &self.fd
    }
}

impl Inputs for Wakeup {
    fn attachables(&self) -> Vec<&dyn Attachable> {
        vec![self as &dyn Attachable]
    }
    fn drain_wakeups(&self) {
        self.take();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_wake_from_another_thread_is_taken_once() {
        let (wakeup, waker) = Wakeup::new().expect("a socket pair");
        assert!(!wakeup.take(), "nothing yet");
        let thread = std::thread::Builder::new()
            .name("waker".into())
            .spawn({
                let waker = waker.clone();
                move || {
                    for _ in 0..3 {
                        waker.wake();
                    }
                }
            })
            .expect("a thread");
        thread.join().expect("the waking thread");
        assert!(wakeup.take());
        assert!(!wakeup.take(), "taken");
        drop(wakeup);
        waker.wake(); // no stage any more: nothing happens
    }
}
