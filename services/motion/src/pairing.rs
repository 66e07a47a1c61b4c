//! Which consecutive frames form a pair the kernel may difference.
//!
//! A motion sample compares the current frame with the one before it, so it is only
//! meaningful when both come from one continuous run of one source at one size. The
//! first frame, a frame flagged `FLAG_DISCONTINUITY` (capture reconnected), a
//! sequence number that does not increase (the publisher restarted) and a change of
//! frame size all start a new run: no motion sample, the frame is only remembered.

use isochron_wire::{FLAG_DISCONTINUITY, FrameHeader};

/// What the service needs to know about a frame to pair it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameInfo {
    /// Publisher sequence number.
    pub sequence: u64,
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// `FLAG_*` bits.
    pub flags: u32,
}

impl FrameInfo {
    /// The pairing-relevant fields of a (validated) frame header.
    pub fn of(header: &FrameHeader) -> Self {
        FrameInfo {
            sequence: header.preamble.sequence,
            width: header.width,
            height: header.height,
            flags: header.preamble.flags,
        }
    }
}

/// How the current frame relates to the remembered previous one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pairing {
    /// Continuous: compute motion between the two.
    Pair {
        /// Frames lost in between (sequence gap), 0 normally.
        skipped: u64,
    },
    /// No previous frame (start, or after end of stream).
    First,
    /// Capture flagged a gap (reconnect).
    Discontinuity,
    /// The sequence did not increase: the publisher restarted.
    Restarted {
        /// Previous sequence.
        from: u64,
        /// Current sequence.
        to: u64,
    },
    /// The frame size changed.
    Resized {
        /// Previous size.
        from: (u32, u32),
        /// Current size.
        to: (u32, u32),
    },
}

impl Pairing {
    /// True if motion is computed for this frame.
    pub fn is_pair(&self) -> bool {
        matches!(self, Pairing::Pair { .. })
    }
}

/// Decides whether `cur` pairs with `prev`.
pub fn pair(prev: Option<&FrameInfo>, cur: &FrameInfo) -> Pairing {
    let Some(prev) = prev else {
        return Pairing::First;
    };
    if cur.flags & FLAG_DISCONTINUITY != 0 {
        return Pairing::Discontinuity;
    }
    if cur.sequence <= prev.sequence {
        return Pairing::Restarted {
            from: prev.sequence,
            to: cur.sequence,
        };
    }
    if (cur.width, cur.height) != (prev.width, prev.height) {
        return Pairing::Resized {
            from: (prev.width, prev.height),
            to: (cur.width, cur.height),
        };
    }
    Pairing::Pair {
        skipped: cur.sequence - prev.sequence - 1,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn f(sequence: u64) -> FrameInfo {
        FrameInfo {
            sequence,
            width: 64,
            height: 48,
            flags: 0,
        }
    }

    #[test]
    fn consecutive_frames_pair() {
        assert_eq!(pair(Some(&f(4)), &f(5)), Pairing::Pair { skipped: 0 });
        assert_eq!(pair(Some(&f(4)), &f(7)), Pairing::Pair { skipped: 2 });
        assert!(pair(Some(&f(4)), &f(5)).is_pair());
    }

    #[test]
    fn runs_restart_on_first_discontinuity_restart_and_resize() {
        assert_eq!(pair(None, &f(0)), Pairing::First);
        let gap = FrameInfo {
            flags: FLAG_DISCONTINUITY,
            ..f(5)
        };
        assert_eq!(pair(Some(&f(4)), &gap), Pairing::Discontinuity);
        assert_eq!(
            pair(Some(&f(400)), &f(0)),
            Pairing::Restarted { from: 400, to: 0 }
        );
        assert_eq!(
            pair(Some(&f(4)), &f(4)),
            Pairing::Restarted { from: 4, to: 4 }
        );
        let big = FrameInfo {
            width: 640,
            height: 480,
            ..f(5)
        };
        assert_eq!(
            pair(Some(&f(4)), &big),
            Pairing::Resized {
                from: (64, 48),
                to: (640, 480)
            }
        );
        assert!(!pair(None, &f(0)).is_pair());
    }
}
