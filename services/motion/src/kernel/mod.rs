//! The fused motion-flow kernel: every block's integer sums from the previous and
//! the current GRAY8 frame, in one streaming pass over both frames plus one visit to
//! each block that may move.
//!
//! # Specification
//!
//! For each pixel `(x, y)` of a `width × height` frame, with `P` the previous and `C`
//! the current frame, coordinates clamped to the frame (replicated border):
//!
//! * `S = P + C` — the two-frame sum image; its gradient sees an edge both where it
//!   was and where it is, so fast motion (several pixels per frame) still pairs each
//!   changed pixel with a gradient, and the pair `(It, ∇S)` is centred in time;
//! * `Gx = S(x+1, y) − S(x−1, y)`, `Gy = S(x, y+1) − S(x, y−1)` — the spatial gradient
//!   (central differences of the sum: 4 × the mean per-frame derivative);
//! * `It = C − P − offset` — the temporal difference, minus the global brightness
//!   `offset` of the frame pair: the mean of `C − P` over every
//!   [`OFFSET_ROW_STEP`]th row, rounded ([`brightness_offset`]). It cancels a
//!   uniform illumination step before the motion-pixel test; a person covering a
//!   few percent of the view moves it by about one grey level;
//! * `g = |Gx| + |Gy|`;
//! * the pixel is a **motion pixel** when `|It| ≥ max(diff_threshold, ⌊g·K / 2¹⁶⌋)`
//!   and `g ≥ gradient_threshold`, with `K = round(min_flow_px · 2¹⁴)`. The second
//!   bound is a least normal-flow speed: `4·|It| / g` never exceeds the pixel's normal
//!   flow `|It| / |∇I|`, so a pixel passes only if its edge moved at least
//!   `min_flow_px` pixels. Strong static edges that shimmer by a fraction of a pixel
//!   (camera vibration, codec noise: `|It|` large only because `|∇I|` is) do not.
//!
//! Per block, over its motion pixels only, the kernel sums ([`BlockSums`]):
//!
//! * `weight = Σ min(g, GRADIENT_SATURATION)` — changed pixels weighted by their
//!   gradient (the density numerator);
//! * `flow_x = Σ −It·Gx`, `flow_y = Σ −It·Gy` — the normal flow `−It·∇I/|∇I|²`
//!   weighted by `|∇I|²`;
//! * `gxx = Σ Gx²`, `gyy = Σ Gy²`, `gxy = Σ Gx·Gy` — the structure tensor `T`;
//! * `it2 = Σ It²`.
//!
//! These are the normal equations of the block's motion-flow constraint
//! `It + ∇I·d = 0` (with `∇I = ∇S / 4`): the Lucas–Kanade displacement is
//! `d = 4·T⁻¹·(flow_x, flow_y)`, and the fraction of `Σ It²` it explains,
//! `R² = bᵀ·T⁻¹·b / it2` with `b = (flow_x, flow_y)`, is the block's coherence (1 when
//! every motion pixel moves the same way, near 0 for noise or a lighting change).
//! Summing the normal flows alone would point along the texture's gradients — the
//! aperture problem; [`crate::features`] turns the sums into features.
//!
//! All arithmetic is integer, so every implementation gives bit-identical sums.
//!
//! # Implementations
//!
//! * [`reference()`]: a plain per-pixel loop, the specification;
//! * [`Implementation::Portable`]: band-buffered, 16-lane chunks written as plain
//!   array loops that LLVM vectorises for the target; off x86-64 (and on x86-64
//!   without AVX2) this is the kernel that runs;
//! * [`Implementation::Avx2`] (x86_64): the same structure with explicit AVX2
//!   intrinsics — a 16-pixel block row is one 256-bit register of `i16`, the six
//!   products go through `_mm256_madd_epi16`. Chosen at run time when the CPU has it.
//!
//! The band-buffered implementations process one row of blocks (a *band*) at a time,
//! in buffers preallocated by [`MotionKernel::new`] (nothing is allocated per frame):
//!
//! 1. one pass over both frames, band by band as they lie in memory, on bytes (32
//!    pixels per AVX2 register): per band and column the largest `|C − P|`, and
//!    the sums over the offset's rows (`_mm256_sad_epu8`) that give the brightness
//!    offset;
//! 2. per block: `|C − P − offset| ≥ diff` needs `|C − P| ≥ diff − |offset|`, so a
//!    block (or a 16-column strip) whose columns never reach that has no motion
//!    pixel and is skipped without another look;
//! 3. each block that may move as vertical 16-pixel strips, accumulators in
//!    registers. Inside the frame, the AVX2 strip reads both frames directly (the
//!    three rows of `S` slide down with the strip); at the frame border, and in the
//!    portable code, the block's `It` rows and `S` rows (one extra row above and
//!    below, one extra column left and right, replicated at the border) are first
//!    built into small windows that stay in L1.
//!
//! Most of a fixed camera's view is still in most frames (on vtest.avi about 7 % of
//! the strips get past step 2), so the kernel costs little more than one read of
//! both frames plus the moving blocks.

mod portable;
mod reference;
mod spec;

#[cfg(target_arch = "x86_64")]
mod avx2;

pub use reference::{brightness_offset, reference};
pub use spec::{
    BlockSums, GRADIENT_SATURATION, Geometry, GeometryError, LANES, MAX_BLOCK_PX, MAX_SPEED,
    OFFSET_ROW_STEP, Thresholds,
};

use portable::{Bands, Job, Portable, run_bands};

/// Which code computes the sums.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Implementation {
    /// [`reference()`]: per-pixel, clamped coordinates. The specification; slow.
    Scalar,
    /// Band-buffered 16-lane chunks in plain Rust, vectorised by the compiler.
    Portable,
    /// Band-buffered, explicit AVX2 intrinsics (x86_64 with AVX2 only).
    Avx2,
}

impl Implementation {
    /// The fastest implementation this CPU runs.
    pub fn detect() -> Implementation {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            return Implementation::Avx2;
        }
        Implementation::Portable
    }

    /// Every implementation this CPU runs, slowest first.
    pub fn available() -> Vec<Implementation> {
        let mut v = vec![Implementation::Scalar, Implementation::Portable];
        if Implementation::detect() == Implementation::Avx2 {
            v.push(Implementation::Avx2);
        }
        v
    }

    /// Name for logs and tables.
    pub fn name(self) -> &'static str {
        match self {
            Implementation::Scalar => "scalar",
            Implementation::Portable => "portable",
            Implementation::Avx2 => "avx2",
        }
    }
}

/// The motion kernel with its preallocated buffers, for one frame size.
#[derive(Debug, Clone)]
pub struct MotionKernel {
    geom: Geometry,
    implementation: Implementation,
    bands: Bands,
    sums: Vec<BlockSums>,
    /// Blocks whose sums the last run computed; all others are zero.
    active: Vec<usize>,
    offset: i16,
}

impl MotionKernel {
    /// A kernel for `geom` using `implementation`.
    ///
    /// # Panics
    /// If `implementation` is [`Implementation::Avx2`] and the CPU lacks AVX2.
    pub fn new(geom: Geometry, implementation: Implementation) -> Self {
        assert!(
            implementation != Implementation::Avx2
                || Implementation::detect() == Implementation::Avx2,
            "this CPU has no AVX2"
        );
        MotionKernel {
            geom,
            implementation,
            bands: Bands::new(&geom),
            sums: vec![BlockSums::default(); geom.blocks()],
            active: Vec::with_capacity(geom.blocks()),
            offset: 0,
        }
    }

    /// A kernel for `geom` using the fastest implementation of this CPU.
    pub fn best(geom: Geometry) -> Self {
        MotionKernel::new(geom, Implementation::detect())
    }

    /// The grid.
    pub fn geometry(&self) -> &Geometry {
        &self.geom
    }

    /// The implementation in use.
    pub fn implementation(&self) -> Implementation {
        self.implementation
    }

    /// Computes every block's sums for the frame pair, with the frame's brightness
    /// offset subtracted from `It` (see [`brightness_offset`]; read it back with
    /// [`MotionKernel::offset`]); blocks with `mask[b]` (if `mask` is not empty) get
    /// zero sums.
    ///
    /// # Panics
    /// If a frame is not `width × height` bytes or `mask` has the wrong length.
    pub fn run(
        &mut self,
        prev: &[u8],
        cur: &[u8],
        thresholds: Thresholds,
        mask: &[bool],
    ) -> &[BlockSums] {
        let g = &self.geom;
        assert!(
            prev.len() == g.pixels() && cur.len() == g.pixels(),
            "frames of {} and {} bytes for a {}x{} kernel",
            prev.len(),
            cur.len(),
            g.width,
            g.height
        );
        assert!(mask.is_empty() || mask.len() == g.blocks(), "mask size");
        let thresholds = Thresholds {
            diff: thresholds.diff.max(1),
            ..thresholds
        };
        // Only the blocks computed last time can be non-zero.
        for &b in &self.active {
            self.sums[b] = BlockSums::default();
        }
        self.active.clear();
        let (bands, sums, active) = (&mut self.bands, &mut self.sums, &mut self.active);
        let job = Job {
            prev,
            cur,
            geom: g,
            thresholds,
            mask,
        };
        self.offset = match self.implementation {
            Implementation::Scalar => {
                let offset = brightness_offset(prev, cur, g.width, g.height);
                reference(prev, cur, g, thresholds, offset, mask, sums);
                let unmasked = |&b: &usize| !mask.get(b).copied().unwrap_or(false);
                active.extend((0..g.blocks()).filter(unmasked));
                offset
            }
            // SAFETY: the portable routines need no CPU feature; sizes checked above.
            Implementation::Portable => unsafe { run_bands::<Portable>(bands, job, sums, active) },
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `new` checked that the CPU has AVX2; sizes checked above.
            Implementation::Avx2 => unsafe { avx2::run(bands, job, sums, active) },
            #[cfg(not(target_arch = "x86_64"))]
            Implementation::Avx2 => unreachable!("AVX2 kernel on a non-x86 target"),
        };
        &self.sums
    }

    /// The brightness offset the last [`MotionKernel::run`] subtracted.
    pub fn offset(&self) -> i16 {
        self.offset
    }

    /// The sums of the last [`MotionKernel::run`].
    pub fn sums(&self) -> &[BlockSums] {
        &self.sums
    }

    /// The blocks the last [`MotionKernel::run`] computed, ascending; every other
    /// block's sums are zero (still or masked).
    pub fn active(&self) -> &[usize] {
        &self.active
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    /// Runs every available implementation and checks they all equal the reference
    /// (with the frame's brightness offset).
    fn check_all(
        prev: &[u8],
        cur: &[u8],
        geom: Geometry,
        thresholds: Thresholds,
        mask: &[bool],
    ) -> Vec<BlockSums> {
        let offset = brightness_offset(prev, cur, geom.width, geom.height);
        let mut expected = vec![BlockSums::default(); geom.blocks()];
        reference(prev, cur, &geom, thresholds, offset, mask, &mut expected);
        for imp in Implementation::available() {
            let mut k = MotionKernel::new(geom, imp);
            let got = k.run(prev, cur, thresholds, mask).to_vec();
            assert_eq!(k.offset(), offset, "{} offset", imp.name());
            if let Some(b) = (0..geom.blocks()).find(|&b| got[b] != expected[b]) {
                panic!(
                    "{} differs from the reference at block {b} of {geom:?} ({thresholds:?}, offset {offset}): {:?} vs {:?}",
                    imp.name(),
                    got[b],
                    expected[b]
                );
            }
            // A second run on the same buffers gives the same result (no stale state).
            let again = k.run(prev, cur, thresholds, mask).to_vec();
            assert_eq!(again, expected, "{} second run", imp.name());
        }
        expected
    }

    pub(super) fn noise(seed: u64, n: usize) -> Vec<u8> {
        let mut x = seed | 1;
        (0..n)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                (x >> 24) as u8
            })
            .collect()
    }

    #[test]
    fn simd_equals_scalar_on_a_full_size_frame() {
        let geom = Geometry::new(768, 576, 16).unwrap();
        let prev = noise(1, geom.pixels());
        let cur = noise(2, geom.pixels());
        let t = Thresholds {
            diff: 15,
            gradient: 8,
            speed: Thresholds::speed_of(0.5),
        };
        let sums = check_all(&prev, &cur, geom, t, &[]);
        assert!(sums.iter().all(|s| s.weight > 0), "noise moves everywhere");
    }

    #[test]
    fn extreme_values_do_not_overflow_the_lanes() {
        // Largest block, full-contrast patterns inverting, offsets from −255 to 255:
        // every lane sum at its bound.
        for block in [16, MAX_BLOCK_PX] {
            let geom = Geometry::new(2 * MAX_BLOCK_PX + 3, MAX_BLOCK_PX + 1, block).unwrap();
            let w = geom.width;
            let checker: Vec<u8> = (0..geom.pixels())
                .map(|i| {
                    if (i % w + i / w).is_multiple_of(2) {
                        0
                    } else {
                        255
                    }
                })
                .collect();
            let inverted: Vec<u8> = checker.iter().map(|&v| 255 - v).collect();
            let vertical: Vec<u8> = (0..geom.pixels())
                .map(|i| if (i % w).is_multiple_of(2) { 0 } else { 255 })
                .collect();
            let zeros = vec![0u8; geom.pixels()];
            let full = vec![255u8; geom.pixels()];
            // Mostly white with a black checker corner: offset near +255 with
            // motion pixels of |It| up to 510.
            let mut white = full.clone();
            white[..w * 8].copy_from_slice(&checker[..w * 8]);
            for gradient in [0, 1020] {
                for speed in [0, Thresholds::speed_of(0.5)] {
                    let t = Thresholds {
                        diff: 1,
                        gradient,
                        speed,
                    };
                    check_all(&checker, &inverted, geom, t, &[]);
                    check_all(&vertical, &inverted, geom, t, &[]);
                    check_all(&zeros, &vertical, geom, t, &[]);
                    check_all(&zeros, &white, geom, t, &[]);
                    check_all(&white, &zeros, geom, t, &[]);
                    check_all(&zeros, &full, geom, t, &[]);
                }
            }
        }
    }

    #[test]
    fn masked_blocks_are_zero_in_every_implementation() {
        let geom = Geometry::new(50, 40, 16).unwrap(); // 4×3
        let prev = noise(3, geom.pixels());
        let cur = noise(4, geom.pixels());
        let mask: Vec<bool> = (0..geom.blocks()).map(|b| b % 3 == 0).collect();
        let t = Thresholds {
            diff: 10,
            gradient: 0,
            speed: 0,
        };
        let sums = check_all(&prev, &cur, geom, t, &mask);
        for (b, s) in sums.iter().enumerate() {
            assert_eq!(*s == BlockSums::default(), mask[b], "block {b}");
        }
        // A whole masked band is skipped too.
        let mask: Vec<bool> = (0..geom.blocks()).map(|b| b < geom.grid_w).collect();
        check_all(&prev, &cur, geom, t, &mask);
    }

    #[test]
    fn identical_frames_have_no_motion() {
        let geom = Geometry::new(77, 51, 16).unwrap();
        let f = noise(5, geom.pixels());
        let t = Thresholds {
            diff: 1,
            gradient: 0,
            speed: 0,
        };
        let sums = check_all(&f, &f, geom, t, &[]);
        assert!(sums.iter().all(|s| *s == BlockSums::default()));
    }

    fn frames(w: usize, h: usize, seed: u64, smooth: bool) -> (Vec<u8>, Vec<u8>) {
        let a = noise(seed, w * h);
        let b = noise(seed.wrapping_mul(31).wrapping_add(7), w * h);
        if !smooth {
            return (a, b);
        }
        // Mostly static smooth content with a few changed pixels: realistic sparsity.
        let prev: Vec<u8> = (0..w * h)
            .map(|i| ((i % w) * 3 + (i / w) * 5) as u8 ^ (a[i] & 7))
            .collect();
        let cur: Vec<u8> = prev
            .iter()
            .zip(&b)
            .map(|(&p, &r)| if r > 230 { r } else { p })
            .collect();
        (prev, cur)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(96))]

        #[test]
        fn simd_equals_scalar_on_random_frames(
            w in 1usize..90,
            h in 1usize..70,
            block in prop::sample::select(vec![4usize, 8, 13, 16, 24, 32, 48]),
            seed in any::<u64>(),
            smooth in any::<bool>(),
            diff in 1u8..=60,
            gradient in 0u16..=120,
            speed in prop::sample::select(vec![0u16, 1, 4096, 8192, 16384, MAX_SPEED, u16::MAX]),
            brightness in -40i16..=40,
            mask_bits in any::<u64>(),
            masked in any::<bool>(),
        ) {
            let geom = Geometry::new(w, h, block).unwrap();
            let (prev, cur) = frames(w, h, seed, smooth);
            // A brightness change on top: the offset path and its pre-test bound.
            let cur: Vec<u8> = cur.iter().map(|&v| (v as i16 + brightness).clamp(0, 255) as u8).collect();
            let mask: Vec<bool> = if masked {
                (0..geom.blocks()).map(|b| mask_bits >> (b % 64) & 1 == 1).collect()
            } else {
                Vec::new()
            };
            check_all(&prev, &cur, geom, Thresholds { diff, gradient, speed }, &mask);
        }
    }
}
