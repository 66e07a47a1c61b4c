//! Per-block appearance of a frame, for the cascade's presence band: what a block
//! *looks like*, where the motion kernel measures what *changes*.
//!
//! Per block of the current GRAY8 frame `C`, over the block's even rows (`y − y0`
//! even for a block starting at row `y0`: half the rows, which a block mean does
//! not need all of):
//!
//! * **luma** — the mean grey level, `Σ C / pixels`;
//! * **texture** — the mean absolute difference between each pixel and its right
//!   neighbour and the pixel two rows down (the next sampled row),
//!   `Σ (|C(x+1, y) − C(x, y)| + |C(x, y+2) − C(x, y)|) / (2 · pixels)` (at the
//!   frame's right and bottom edges a missing neighbour is the nearest pixel in the
//!   frame). An L1 gradient energy: a person or an object on a plain floor adds
//!   edges; a gain change scales it like the luma.
//!
//! Both are sent in 1/[`APPEARANCE_SCALE`] grey levels (`BlockMotion::luma`,
//! `BlockMotion::texture`). Appearance changes slowly, so the motion stage measures
//! it on a frame every [`AppearanceSampler`] period (`motion.appearance_hz`)
//! rather than on every frame: the cost is one more streaming read of half the
//! current frame's rows, still in cache, per period. [`Appearance::measure`] is
//! plain Rust over fixed 32-pixel chunks that LLVM vectorises (byte-wide
//! `abs_diff`, widening adds), compiled once for the baseline target and, on
//! x86-64, once more with AVX2 enabled and chosen at run time; the same code runs
//! on ARM. [`reference`] is the per-pixel specification.

use isochron_wire::{APPEARANCE_SCALE, BlockMotion};

use crate::kernel::Geometry;

/// Rows sampled: every `ROW_STEP`th row of a block, from its first.
pub const ROW_STEP: usize = 2;

/// Pixels per chunk of the row loop.
const CHUNK: usize = 32;

/// Per-column accumulators of one band (row of blocks), reused across frames.
#[derive(Debug, Clone, Default)]
pub struct Appearance {
    luma: Vec<u16>,
    texture: Vec<u16>,
    /// Adds a row with the AVX2 build of [`add_row`] (x86-64 CPUs that have it).
    avx2: bool,
}

impl Appearance {
    /// Buffers for frames of `geom`.
    pub fn new(geom: &Geometry) -> Self {
        Appearance {
            luma: vec![0; geom.width],
            texture: vec![0; geom.width],
            avx2: cfg!(target_arch = "x86_64") && avx2(),
        }
    }

    /// Measures every block of `frame` (`geom.pixels()` bytes) into `out[b].luma` and
    /// `out[b].texture`; blocks with `mask[b]` (if `mask` is not empty) get zero.
    /// Nothing else of `out` changes.
    ///
    /// # Panics
    /// If `frame`, `out` or a non-empty `mask` do not fit `geom`.
    pub fn measure(
        &mut self,
        frame: &[u8],
        geom: &Geometry,
        mask: &[bool],
        out: &mut [BlockMotion],
    ) {
        let (w, h, px) = (geom.width, geom.height, geom.block_px);
        assert_eq!(frame.len(), geom.pixels(), "frame size");
        assert_eq!(out.len(), geom.blocks(), "output blocks");
        assert!(mask.is_empty() || mask.len() == geom.blocks(), "mask size");
        self.luma.resize(w, 0);
        self.texture.resize(w, 0);
        for by in 0..geom.grid_h {
            self.luma.fill(0);
            self.texture.fill(0);
            let (y0, y1) = (by * px, ((by + 1) * px).min(h));
            // Column sums over the band's sampled rows: ≤ 64 rows × 255 (luma) and
            // 64 × 510 (texture) fit u16 (MAX_BLOCK_PX = 128).
            for y in (y0..y1).step_by(ROW_STEP) {
                let row = &frame[y * w..(y + 1) * w];
                let y2 = (y + ROW_STEP).min(h - 1);
                let below = &frame[y2 * w..(y2 + 1) * w];
                #[cfg(target_arch = "x86_64")]
                if self.avx2 {
                    // SAFETY: `avx2` is set only when the CPU has AVX2.
                    unsafe { add_row_avx2(row, below, &mut self.luma, &mut self.texture) };
                    continue;
                }
                add_row(row, below, &mut self.luma, &mut self.texture);
            }
            let rows = (y1 - y0).div_ceil(ROW_STEP);
            for bx in 0..geom.grid_w {
                let b = by * geom.grid_w + bx;
                if mask.get(b).copied().unwrap_or(false) {
                    out[b].luma = 0;
                    out[b].texture = 0;
                    continue;
                }
                let cols = bx * px..((bx + 1) * px).min(w);
                let area = (cols.len() * rows) as u64;
                let luma: u64 = self.luma[cols.clone()].iter().map(|&v| v as u64).sum();
                let texture: u64 = self.texture[cols].iter().map(|&v| v as u64).sum();
                out[b].luma = scaled(luma, area);
                out[b].texture = scaled(texture, 2 * area);
            }
        }
    }
}

/// True if this x86-64 CPU has AVX2.
fn avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// [`add_row`] compiled with AVX2.
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn add_row_avx2(row: &[u8], below: &[u8], luma: &mut [u16], texture: &mut [u16]) {
    add_row(row, below, luma, texture);
}

/// Adds one row to the column sums: `luma[x] += row[x]`, `texture[x] +=
/// |row[x+1] − row[x]| + |below[x] − row[x]|` (the last column's right neighbour
/// is itself). Fixed 32-pixel chunks, so that the compiler vectorises the loop
/// without bounds checks.
#[inline(always)]
fn add_row(row: &[u8], below: &[u8], luma: &mut [u16], texture: &mut [u16]) {
    let n = row
        .len()
        .min(below.len())
        .min(luma.len())
        .min(texture.len());
    if n == 0 {
        return;
    }
    // Chunks whose right neighbours all exist: x + CHUNK < n.
    let body = (n - 1) / CHUNK * CHUNK;
    for x in (0..body).step_by(CHUNK) {
        let c: &[u8; CHUNK] = row[x..x + CHUNK].try_into().expect("chunk");
        let r: &[u8; CHUNK] = row[x + 1..x + 1 + CHUNK].try_into().expect("chunk");
        let d: &[u8; CHUNK] = below[x..x + CHUNK].try_into().expect("chunk");
        let l: &mut [u16; CHUNK] = (&mut luma[x..x + CHUNK]).try_into().expect("chunk");
        let t: &mut [u16; CHUNK] = (&mut texture[x..x + CHUNK]).try_into().expect("chunk");
        for i in 0..CHUNK {
            l[i] += c[i] as u16;
            t[i] += c[i].abs_diff(r[i]) as u16 + c[i].abs_diff(d[i]) as u16;
        }
    }
    for x in body..n {
        let c = row[x];
        let r = row[(x + 1).min(n - 1)];
        luma[x] += c as u16;
        texture[x] += c.abs_diff(r) as u16 + c.abs_diff(below[x]) as u16;
    }
}

/// `sum / count` in 1/APPEARANCE_SCALE units, rounded, saturating.
fn scaled(sum: u64, count: u64) -> u16 {
    if count == 0 {
        return 0;
    }
    let v = (sum * APPEARANCE_SCALE as u64 + count / 2) / count;
    v.min(u16::MAX as u64) as u16
}

/// The specification: per pixel of the sampled rows, clamped neighbours;
/// `(luma, texture)` per block.
pub fn reference(frame: &[u8], geom: &Geometry) -> Vec<(u16, u16)> {
    let (w, h) = (geom.width, geom.height);
    (0..geom.blocks())
        .map(|b| {
            let (x0, y0, bw, bh) = geom.block_rect(b);
            let (mut luma, mut texture) = (0u64, 0u64);
            for y in (y0..y0 + bh).step_by(ROW_STEP) {
                for x in x0..x0 + bw {
                    let c = frame[y * w + x];
                    let r = frame[y * w + (x + 1).min(w - 1)];
                    let d = frame[(y + ROW_STEP).min(h - 1) * w + x];
                    luma += c as u64;
                    texture += c.abs_diff(r) as u64 + c.abs_diff(d) as u64;
                }
            }
            let area = (bw * bh.div_ceil(ROW_STEP)) as u64;
            (scaled(luma, area), scaled(texture, 2 * area))
        })
        .collect()
}

/// Which frames get their appearance measured: the first frame of every `period`
/// of capture time (slots `floor(t / period)`), so the rate is the same at any
/// frame rate and a replay faster than real time measures the same frames.
#[derive(Debug, Clone, Copy)]
pub struct AppearanceSampler {
    period_ns: i64,
    last_slot: Option<i64>,
}

impl AppearanceSampler {
    /// Measures at most `hz` times per second of capture time (`hz` ≤ 0: never).
    pub fn new(hz: f64) -> Self {
        AppearanceSampler {
            period_ns: if hz > 0.0 {
                (1e9 / hz).round().max(1.0) as i64
            } else {
                0
            },
            last_slot: None,
        }
    }

    /// True if the frame captured at `capture_ns` is due a measurement (each slot
    /// once; a frame of an earlier slot — time went back — starts again).
    pub fn due(&mut self, capture_ns: i64) -> bool {
        if self.period_ns == 0 {
            return false;
        }
        let slot = capture_ns.div_euclid(self.period_ns);
        if self.last_slot == Some(slot) {
            return false;
        }
        self.last_slot = Some(slot);
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn measure(frame: &[u8], geom: &Geometry) -> Vec<(u16, u16)> {
        let mut out = vec![BlockMotion::default(); geom.blocks()];
        Appearance::new(geom).measure(frame, geom, &[], &mut out);
        out.iter().map(|b| (b.luma, b.texture)).collect()
    }

    #[test]
    fn a_flat_block_has_its_grey_and_no_texture() {
        let geom = Geometry::new(40, 20, 16).unwrap(); // 3×2, partial edge blocks
        let frame = vec![100u8; geom.pixels()];
        for (luma, texture) in measure(&frame, &geom) {
            assert_eq!(luma, 100 * APPEARANCE_SCALE);
            assert_eq!(texture, 0);
        }
    }

    #[test]
    fn stripes_have_texture_and_a_gain_scales_both() {
        let geom = Geometry::new(32, 32, 16).unwrap();
        let stripes: Vec<u8> = (0..geom.pixels())
            .map(|i| if (i % 32) % 2 == 0 { 40 } else { 80 })
            .collect();
        let brighter: Vec<u8> = stripes.iter().map(|&v| v + v / 2).collect();
        let (a, b) = (measure(&stripes, &geom), measure(&brighter, &geom));
        // Horizontal neighbours differ by 40 (but the last column), vertical by 0.
        assert!((a[0].1 as f64 / APPEARANCE_SCALE as f64 - 20.0).abs() < 1e-9);
        assert_eq!(a[0].0, 60 * APPEARANCE_SCALE);
        assert_eq!(b[0].0, 90 * APPEARANCE_SCALE);
        assert_eq!(b[0].1, 30 * APPEARANCE_SCALE);
    }

    #[test]
    fn masked_blocks_are_zero() {
        let geom = Geometry::new(32, 16, 16).unwrap();
        let frame = vec![7u8; geom.pixels()];
        let mut out = vec![BlockMotion::default(); 2];
        Appearance::new(&geom).measure(&frame, &geom, &[true, false], &mut out);
        assert_eq!((out[0].luma, out[1].luma), (0, 7 * APPEARANCE_SCALE));
    }

    #[test]
    fn the_sampler_measures_once_per_period_of_capture_time() {
        let mut s = AppearanceSampler::new(2.0);
        // 10 frames/s: frames 0 and 5 of each second.
        let due: Vec<bool> = (0..12).map(|i| s.due(i * 100_000_000)).collect();
        assert_eq!(
            due,
            [
                true, false, false, false, false, true, false, false, false, false, true, false
            ]
        );
        // A replay from an earlier time starts again.
        assert!(s.due(0));
        assert!(!AppearanceSampler::new(0.0).due(0));
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        #[test]
        fn equals_the_reference(
            w in 1usize..90,
            h in 1usize..70,
            block in prop::sample::select(vec![4usize, 8, 13, 16, 32, 128]),
            seed in any::<u64>(),
        ) {
            let geom = Geometry::new(w, h, block).unwrap();
            let mut x = seed | 1;
            let frame: Vec<u8> = (0..geom.pixels())
                .map(|_| {
                    x ^= x << 13;
                    x ^= x >> 7;
                    x ^= x << 17;
                    (x >> 24) as u8
                })
                .collect();
            let expected = reference(&frame, &geom);
            prop_assert_eq!(measure(&frame, &geom), expected.clone());
            // The baseline build too (on a CPU with AVX2, `measure` took that one).
            let mut out = vec![BlockMotion::default(); geom.blocks()];
            let mut portable = Appearance { avx2: false, ..Appearance::new(&geom) };
            portable.measure(&frame, &geom, &[], &mut out);
            let got: Vec<(u16, u16)> = out.iter().map(|b| (b.luma, b.texture)).collect();
            prop_assert_eq!(got, expected);
        }
    }
}
