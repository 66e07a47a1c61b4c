//! The AVX2 routines of the band-buffered kernel (x86-64 with AVX2 only, chosen at
//! run time): a 16-pixel block row is one 256-bit register of `i16`, the six
//! products go through `_mm256_madd_epi16`.

use super::portable::{Bands, Job, Portable, Simd, Strip, run_bands};
use super::{BlockSums, GRADIENT_SATURATION, LANES, MAX_SPEED, Thresholds};
use std::arch::x86_64::*;

/// Lane masks for strips narrower than 16: `VALID[n]` keeps lanes `0..n`.
static VALID: [[i16; LANES]; LANES + 1] = {
    let mut t = [[0i16; LANES]; LANES + 1];
    let mut n = 0;
    while n <= LANES {
        let mut l = 0;
        while l < n {
            t[n][l] = -1;
            l += 1;
        }
        n += 1;
    }
    t
};

/// Sum of the eight `i32` lanes.
#[target_feature(enable = "avx2")]
#[inline]
fn hsum_epi32(v: __m256i) -> i32 {
    let s = _mm_add_epi32(_mm256_castsi256_si128(v), _mm256_extracti128_si256::<1>(v));
    let s = _mm_add_epi32(s, _mm_shuffle_epi32::<0b01_00_11_10>(s));
    let s = _mm_add_epi32(s, _mm_shuffle_epi32::<0b10_11_00_01>(s));
    _mm_cvtsi128_si32(s)
}

/// `out[x] = op(p[x], c[x])` for `x < n`, 16 pixels (widened to `i16`) at a time;
/// the last chunk overlaps the one before.
///
/// # Safety
/// `LANES ≤ n` and `n` is at most the length of `p`, `c` and `out`.
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn map_pixels(
    p: &[u8],
    c: &[u8],
    out: &mut [i16],
    n: usize,
    op: impl Fn(__m256i, __m256i) -> __m256i,
) {
    let mut x = 0;
    loop {
        let at = x.min(n - LANES);
        // SAFETY: at + 16 ≤ n for every access (the caller's contract).
        unsafe {
            let a = _mm256_cvtepu8_epi16(_mm_loadu_si128(p.as_ptr().add(at).cast()));
            let b = _mm256_cvtepu8_epi16(_mm_loadu_si128(c.as_ptr().add(at).cast()));
            _mm256_storeu_si256(out.as_mut_ptr().add(at).cast(), op(a, b));
        }
        if at + LANES == n {
            break;
        }
        x += LANES;
    }
}

/// Sum of the four `u64` lanes.
#[target_feature(enable = "avx2")]
#[inline]
fn hsum_epi64(v: __m256i) -> u64 {
    let s = _mm_add_epi64(_mm256_castsi256_si128(v), _mm256_extracti128_si256::<1>(v));
    (_mm_cvtsi128_si64(s) + _mm_extract_epi64::<1>(s)) as u64
}

/// The AVX2 routines: 32 pixels per register on bytes; one block row of 16
/// pixels per `__m256i` of `i16`.
pub(super) struct Avx2;

impl Simd for Avx2 {
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn pretest_band(p: &[u8], c: &[u8], width: usize, dmax: &mut [u8]) {
        let rows = p.len().min(c.len()) / width;
        let body = width - width % 32;
        dmax.fill(0);
        // Row by row, as the frames lie in memory (the hardware prefetcher
        // streams them; walking columns down the band, or two rows at once,
        // measured slower); the band's maxima stay in L1.
        for r in 0..rows {
            let (p, c) = (
                &p[r * width..(r + 1) * width],
                &c[r * width..(r + 1) * width],
            );
            let mut x = 0;
            while x < body {
                // SAFETY: AVX2 is present (caller); x + 32 ≤ body ≤ width, the
                // length of p, c and dmax.
                unsafe {
                    let a = _mm256_loadu_si256(p.as_ptr().add(x).cast());
                    let b = _mm256_loadu_si256(c.as_ptr().add(x).cast());
                    let d = _mm256_sub_epi8(_mm256_max_epu8(a, b), _mm256_min_epu8(a, b));
                    let m = dmax.as_mut_ptr().add(x).cast::<__m256i>();
                    _mm256_storeu_si256(m, _mm256_max_epu8(_mm256_loadu_si256(m), d));
                }
                x += 32;
            }
            for ((m, &a), &b) in dmax[body..].iter_mut().zip(&p[body..]).zip(&c[body..]) {
                *m = (*m).max(a.abs_diff(b));
            }
        }
    }

    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn row_sums(p: &[u8], c: &[u8]) -> (u64, u64) {
        let n = p.len().min(c.len());
        let body = n - n % 32;
        let zero = _mm256_setzero_si256();
        let (mut sp, mut sc) = (zero, zero);
        let mut x = 0;
        while x < body {
            // SAFETY: AVX2 is present (caller); x + 32 ≤ body ≤ n.
            unsafe {
                let a = _mm256_loadu_si256(p.as_ptr().add(x).cast());
                let b = _mm256_loadu_si256(c.as_ptr().add(x).cast());
                sp = _mm256_add_epi64(sp, _mm256_sad_epu8(a, zero));
                sc = _mm256_add_epi64(sc, _mm256_sad_epu8(b, zero));
            }
            x += 32;
        }
        let tail = |f: &[u8]| f[body..n].iter().map(|&v| v as u64).sum::<u64>();
        (hsum_epi64(sp) + tail(p), hsum_epi64(sc) + tail(c))
    }

    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn diff_row(p: &[u8], c: &[u8], offset: i16, it: &mut [i16]) {
        let n = p.len().min(c.len()).min(it.len());
        if n < LANES {
            // SAFETY: the portable routine needs no CPU feature.
            return unsafe { Portable::diff_row(p, c, offset, it) };
        }
        let off = _mm256_set1_epi16(offset);
        // SAFETY: AVX2 is present (caller); 16 ≤ n ≤ every length.
        unsafe {
            map_pixels(p, c, it, n, |a, b| {
                _mm256_sub_epi16(_mm256_sub_epi16(b, a), off)
            })
        }
    }

    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn sum_row(p: &[u8], c: &[u8], s: &mut [i16]) {
        let n = p.len().min(c.len()).min(s.len());
        if n < LANES {
            // SAFETY: the portable routine needs no CPU feature.
            return unsafe { Portable::sum_row(p, c, s) };
        }
        // SAFETY: AVX2 is present (caller); 16 ≤ n ≤ every length.
        unsafe { map_pixels(p, c, s, n, |a, b| _mm256_add_epi16(a, b)) }
    }

    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn strip<const FULL: bool>(bands: &Bands, at: Strip, th: Thresholds) -> BlockSums {
        let Strip { x, rows, lanes } = at;
        let (ss, is) = (bands.s_stride, bands.it_stride);
        // Every load below stays inside the padded buffers (see Bands::new).
        debug_assert!((rows + 1) * ss + x + LANES + 2 <= bands.s.len());
        debug_assert!((rows.max(1) - 1) * is + x + LANES <= bands.it.len());
        let s = bands.s.as_ptr();
        let it = bands.it.as_ptr();
        // SAFETY: the caller guarantees AVX2; all loads are unaligned loads inside
        // the buffers (asserted above).
        unsafe {
            let mut acc = Acc::new(th, lanes);
            for r in 0..rows {
                let mid = s.add((r + 1) * ss + x);
                let left = _mm256_loadu_si256(mid.cast());
                let right = _mm256_loadu_si256(mid.add(2).cast());
                let up = _mm256_loadu_si256(s.add(r * ss + x + 1).cast());
                let down = _mm256_loadu_si256(s.add((r + 2) * ss + x + 1).cast());
                let t = _mm256_loadu_si256(it.add(r * is + x).cast());
                acc.add_row::<FULL>(t, _mm256_sub_epi16(right, left), _mm256_sub_epi16(down, up));
            }
            acc.finish()
        }
    }

    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn strip_direct(
        prev: &[u8],
        cur: &[u8],
        width: usize,
        (x, y0, rows): (usize, usize, usize),
        offset: i16,
        thresholds: Thresholds,
    ) -> Option<BlockSums> {
        // Rows y0 − 1 ..= y0 + rows and columns x − 1 ..= x + 16 are read.
        assert!(x >= 1 && x + LANES < width && y0 >= 1);
        assert!((y0 + rows + 1) * width <= prev.len().min(cur.len()));
        let (p, c) = (prev.as_ptr(), cur.as_ptr());
        // SAFETY: AVX2 is present (caller); every 16-byte load starts at row
        // y0 − 1 ..= y0 + rows, column x − 1 ..= x + 1 (asserted above).
        unsafe {
            let at = |y: usize, dx: usize| y * width + x + dx - 1;
            let ld =
                |f: *const u8, i: usize| _mm256_cvtepu8_epi16(_mm_loadu_si128(f.add(i).cast()));
            let off = _mm256_set1_epi16(offset);
            let mut acc = Acc::new(thresholds, LANES);
            let mut up = _mm256_add_epi16(ld(p, at(y0 - 1, 1)), ld(c, at(y0 - 1, 1)));
            let (mut pm, mut cm) = (ld(p, at(y0, 1)), ld(c, at(y0, 1)));
            for y in y0..y0 + rows {
                let (pd, cd) = (ld(p, at(y + 1, 1)), ld(c, at(y + 1, 1)));
                let down = _mm256_add_epi16(pd, cd);
                let left = _mm256_add_epi16(ld(p, at(y, 0)), ld(c, at(y, 0)));
                let right = _mm256_add_epi16(ld(p, at(y, 2)), ld(c, at(y, 2)));
                let t = _mm256_sub_epi16(_mm256_sub_epi16(cm, pm), off);
                acc.add_row::<true>(t, _mm256_sub_epi16(right, left), _mm256_sub_epi16(down, up));
                up = _mm256_add_epi16(pm, cm);
                (pm, cm) = (pd, cd);
            }
            Some(acc.finish())
        }
    }
}

/// The seven per-lane accumulators of a strip and the test's constants.
struct Acc {
    valid: __m256i,
    dt: __m256i,
    k: __m256i,
    gt1: __m256i,
    gsat: __m256i,
    w: __m256i,
    x: __m256i,
    y: __m256i,
    xx: __m256i,
    yy: __m256i,
    xy: __m256i,
    tt: __m256i,
}

impl Acc {
    #[inline]
    #[target_feature(enable = "avx2")]
    fn new(thresholds: Thresholds, lanes: usize) -> Acc {
        let zero = _mm256_setzero_si256();
        // SAFETY: VALID[n] is 16 i16 = 32 bytes.
        let valid = unsafe { _mm256_loadu_si256(VALID[lanes.min(LANES)].as_ptr().cast()) };
        Acc {
            valid,
            dt: _mm256_set1_epi16(thresholds.diff as i16),
            k: _mm256_set1_epi16(thresholds.speed.min(MAX_SPEED) as i16),
            gt1: _mm256_set1_epi16(thresholds.gradient.min(i16::MAX as u16) as i16 - 1),
            gsat: _mm256_set1_epi16(GRADIENT_SATURATION as i16),
            w: zero,
            x: zero,
            y: zero,
            xx: zero,
            yy: zero,
            xy: zero,
            tt: zero,
        }
    }

    /// The motion-pixel test and the sums for one row of 16 pixels.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn add_row<const FULL: bool>(&mut self, t: __m256i, gx: __m256i, gy: __m256i) {
        let g = _mm256_add_epi16(_mm256_abs_epi16(gx), _mm256_abs_epi16(gy));
        // |It| ≥ max(diff, g·K >> 16), i.e. not (least > |It|). g ≥ 0 and
        // k ≤ i16::MAX: the signed multiply-high is the unsigned one (which LLVM
        // would widen to 32 bits).
        let least = _mm256_max_epi16(_mm256_mulhi_epi16(g, self.k), self.dt);
        let mut m = _mm256_andnot_si256(
            _mm256_cmpgt_epi16(least, _mm256_abs_epi16(t)),
            _mm256_cmpgt_epi16(g, self.gt1),
        );
        if !FULL {
            m = _mm256_and_si256(m, self.valid);
        }
        let w = _mm256_and_si256(_mm256_min_epi16(g, self.gsat), m);
        self.w = _mm256_add_epi16(self.w, w);
        let gxm = _mm256_and_si256(gx, m);
        let gym = _mm256_and_si256(gy, m);
        let tm = _mm256_and_si256(t, m);
        self.x = _mm256_add_epi32(self.x, _mm256_madd_epi16(t, gxm));
        self.y = _mm256_add_epi32(self.y, _mm256_madd_epi16(t, gym));
        self.xx = _mm256_add_epi32(self.xx, _mm256_madd_epi16(gxm, gx));
        self.yy = _mm256_add_epi32(self.yy, _mm256_madd_epi16(gym, gy));
        self.xy = _mm256_add_epi32(self.xy, _mm256_madd_epi16(gxm, gy));
        self.tt = _mm256_add_epi32(self.tt, _mm256_madd_epi16(tm, t));
    }

    /// The block sums (lane sums; the flow sign of the specification).
    #[inline]
    #[target_feature(enable = "avx2")]
    fn finish(&self) -> BlockSums {
        let weight = hsum_epi32(_mm256_madd_epi16(self.w, _mm256_set1_epi16(1)));
        BlockSums {
            weight: weight as u32,
            flow_x: -(hsum_epi32(self.x) as i64),
            flow_y: -(hsum_epi32(self.y) as i64),
            gxx: hsum_epi32(self.xx) as i64,
            gyy: hsum_epi32(self.yy) as i64,
            gxy: hsum_epi32(self.xy) as i64,
            it2: hsum_epi32(self.tt) as i64,
        }
    }
}

/// The whole frame with AVX2 code generation (the block builds are compiled for
/// AVX2 too, by inlining). Returns the brightness offset.
///
/// # Safety
/// The CPU must have AVX2; the arguments must match `geom`.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn run(
    bands: &mut Bands,
    job: Job<'_>,
    out: &mut [BlockSums],
    active: &mut Vec<usize>,
) -> i16 {
    // SAFETY: AVX2 is present (this function's contract).
    unsafe { run_bands::<Avx2>(bands, job, out, active) }
}
