//! The recent frames, copied out of shared memory as they arrive, so the detector
//! worker can run on the frame an event was raised on even a second later. Shared
//! between the main loop (writer) and the worker (reader) behind a `parking_lot`
//! mutex; the worker holds it only to copy one frame out.

/// One stored frame.
#[derive(Debug, Clone, Default)]
pub struct StoredFrame {
    /// Capture time, UTC ns.
    pub capture_time_ns: i64,
    /// Source index.
    pub source_index: u64,
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// GRAY8 pixels, packed rows.
    pub pixels: Vec<u8>,
}

/// A fixed ring of frames; slot buffers are reused, so a steady stream allocates
/// nothing.
#[derive(Debug)]
pub struct FrameRing {
    slots: Vec<StoredFrame>,
    filled: usize,
    next: usize,
}

impl FrameRing {
    /// A ring of `capacity` frames.
    pub fn new(capacity: usize) -> Self {
        FrameRing {
            slots: vec![StoredFrame::default(); capacity.max(1)],
            filled: 0,
            next: 0,
        }
    }

    /// Stores a frame, replacing the oldest.
    pub fn push(
        &mut self,
        capture_time_ns: i64,
        source_index: u64,
        width: u32,
        height: u32,
        pixels: &[u8],
    ) {
        let slot = &mut self.slots[self.next];
        slot.capture_time_ns = capture_time_ns;
        slot.source_index = source_index;
        slot.width = width;
        slot.height = height;
        slot.pixels.clear();
        slot.pixels.extend_from_slice(pixels);
        self.next = (self.next + 1) % self.slots.len();
        self.filled = (self.filled + 1).min(self.slots.len());
    }

    /// The latest frame captured at or before `time_ns`.
    pub fn latest_at(&self, time_ns: i64) -> Option<&StoredFrame> {
        self.stored()
            .filter(|f| f.capture_time_ns <= time_ns)
            .max_by_key(|f| f.capture_time_ns)
    }

    /// Copies the latest frame at or before `time_ns` into `out` (reusing its
    /// buffer); false if the ring has no such frame (it was overwritten).
    pub fn copy_latest_at(&self, time_ns: i64, out: &mut StoredFrame) -> bool {
        match self.latest_at(time_ns) {
            Some(f) => {
                out.capture_time_ns = f.capture_time_ns;
                out.source_index = f.source_index;
                out.width = f.width;
                out.height = f.height;
                out.pixels.clear();
                out.pixels.extend_from_slice(&f.pixels);
                true
            }
            None => false,
        }
    }

    fn stored(&self) -> impl Iterator<Item = &StoredFrame> {
        self.slots[..self.filled].iter()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_the_latest_frame_not_after_a_time_and_forgets_the_oldest() {
        let mut ring = FrameRing::new(3);
        for i in 0..5u64 {
            ring.push(i as i64 * 100, i, 2, 1, &[i as u8, 0]);
        }
        // Frames 2, 3, 4 remain.
        assert_eq!(ring.latest_at(350).unwrap().source_index, 3);
        assert_eq!(ring.latest_at(10_000).unwrap().source_index, 4);
        assert!(ring.latest_at(150).is_none(), "frame 1 was overwritten");
        let mut out = StoredFrame::default();
        assert!(ring.copy_latest_at(200, &mut out));
        assert_eq!(
            (out.source_index, out.pixels.as_slice()),
            (2, &[2u8, 0][..])
        );
    }
}
