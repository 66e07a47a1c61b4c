//! The motion stage allocates nothing per frame: once a detector exists, processing
//! frame pairs (moving, still, masked, a brightness step, an illumination change)
//! must not touch the heap. Runs without the test harness so that nothing else
//! allocates concurrently.

// A test without the harness (clippy's allow-unwrap-in-tests sees no #[test]): an
// unwrap fails it with the error, as in any test.
#![allow(clippy::unwrap_used, reason = "a test: a failure panics")]

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

use isochron_motion::detector::{MotionDetector, MotionParams};
use isochron_motion::kernel::{Geometry, Implementation};
use isochron_wire::BlockMotion;

/// The system allocator, counting allocations.
struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

// SAFETY: forwards to the system allocator unchanged.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn main() {
    // The counter sees allocations at all.
    let probe = ALLOCATIONS.load(Ordering::Relaxed);
    std::hint::black_box(vec![1u8; 8]);
    assert!(ALLOCATIONS.load(Ordering::Relaxed) > probe);

    let (w, h) = (200, 150);
    let geom = Geometry::new(w, h, 16).unwrap();
    let texture = |shift: usize, gain: f32| -> Vec<u8> {
        (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                let inside =
                    (40.0..120.0).contains(&(x - shift as f32)) && (30.0..110.0).contains(&y);
                let v = if inside {
                    120.0 + 60.0 * ((x - shift as f32) * 0.4).sin() * (y * 0.3).cos()
                } else {
                    70.0 + 20.0 * (x * 0.07).sin() + 20.0 * (y * 0.05).cos()
                };
                (v * gain).min(255.0) as u8
            })
            .collect::<Vec<u8>>()
    };
    let frames = [
        texture(0, 1.0),
        texture(3, 1.0),
        texture(3, 1.0),
        texture(6, 1.0),
        texture(6, 1.0)
            .iter()
            .map(|&v| v.saturating_add(30))
            .collect(),
        texture(6, 1.6),
    ];
    let mask = vec![vec![[0.0, 0.0], [64.0, 0.0], [64.0, 64.0], [0.0, 64.0]]];
    for imp in Implementation::available() {
        let mut detector =
            MotionDetector::with_implementation(geom, MotionParams::default(), imp, &mask);
        let mut blocks = vec![BlockMotion::default(); geom.blocks()];
        detector
            .process(&frames[0], &frames[1], 0, &mut blocks)
            .unwrap(); // warm-up
        let before = ALLOCATIONS.load(Ordering::Relaxed);
        let mut moving = 0;
        for _ in 0..3 {
            for (i, pair) in frames.windows(2).enumerate() {
                // Ten frames a second: the appearance is measured on some.
                moving += detector
                    .process(
                        &pair[0],
                        &pair[1],
                        (i as i64 + 1) * 100_000_000,
                        &mut blocks,
                    )
                    .unwrap()
                    .moving_blocks;
            }
        }
        let allocations = ALLOCATIONS.load(Ordering::Relaxed) - before;
        assert!(moving > 0, "the frames move");
        assert_eq!(
            allocations,
            0,
            "{}: {allocations} allocations in 15 frames",
            imp.name()
        );
        println!("{}: no allocation per frame", imp.name());
    }
}
