//! The band-buffered kernel (steps 1–3 of the module documentation), generic over
//! its vectorised row and strip routines ([`Simd`]), and the portable routines:
//! plain array loops the compiler vectorises for the target.

use super::reference::offset_of;
use super::{
    BlockSums, GRADIENT_SATURATION, Geometry, LANES, MAX_SPEED, OFFSET_ROW_STEP, Thresholds,
};

/// Buffers of the band-buffered implementations: the pre-test of every band (row
/// of blocks) and the `It` and `S` windows of one block.
#[derive(Debug, Clone)]
pub(super) struct Bands {
    /// Per band and frame column, the largest `|C − P|` over the band's rows
    /// (`grid_h × width`).
    diff_max: Vec<u8>,
    /// `block_px + 2` rows of `S` around the block: row 0 is the frame row above it,
    /// row `r + 1` is block row `r`. Row layout: `s[0] = S(x0 − 1)`,
    /// `s[i + 1] = S(x0 + i)`, `s[bw + 1] = S(x0 + bw)` (coordinates clamped to the
    /// frame), then padding for the last 16-lane loads.
    pub(super) s: Vec<i16>,
    pub(super) s_stride: usize,
    /// `block_px` rows of the block's `It` (offset subtracted), padded to whole
    /// chunks.
    pub(super) it: Vec<i16>,
    pub(super) it_stride: usize,
}

impl Bands {
    pub(super) fn new(geom: &Geometry) -> Self {
        // A strip at local column x < bw ≤ block_px loads s[x .. x + 18) and
        // it[x .. x + 16).
        let s_stride = (geom.block_px + 2 + LANES).next_multiple_of(LANES);
        let it_stride = (geom.block_px + LANES).next_multiple_of(LANES);
        Bands {
            diff_max: vec![0; geom.grid_h * geom.width],
            s: vec![0; s_stride * (geom.block_px + 2)],
            s_stride,
            it: vec![0; it_stride * geom.block_px],
            it_stride,
        }
    }

    /// Steps 1 and 2 over the whole frame, band by band as the frames lie in
    /// memory, with `K`'s routines; returns the brightness offset.
    #[inline(always)]
    unsafe fn pretest<K: Simd>(&mut self, prev: &[u8], cur: &[u8], geom: &Geometry) -> i16 {
        let w = geom.width;
        let (mut sum_p, mut sum_c, mut n) = (0u64, 0u64, 0usize);
        for (by, dmax) in self.diff_max.chunks_exact_mut(w).enumerate() {
            let y0 = by * geom.block_px;
            let y1 = (y0 + geom.block_px).min(geom.height);
            let band = y0 * w..y1 * w;
            // SAFETY: forwarded from the caller (K's CPU features).
            unsafe { K::pretest_band(&prev[band.clone()], &cur[band], w, dmax) };
            // The offset's rows of this band, still in L1.
            for y in (y0.next_multiple_of(OFFSET_ROW_STEP)..y1).step_by(OFFSET_ROW_STEP) {
                let row = y * w..(y + 1) * w;
                // SAFETY: forwarded from the caller (K's CPU features).
                let (sp, sc) = unsafe { K::row_sums(&prev[row.clone()], &cur[row]) };
                sum_p += sp;
                sum_c += sc;
                n += w;
            }
        }
        offset_of(sum_p, sum_c, n)
    }

    /// True if a column of `x .. x + lanes` of band `by` changed by at least `least`.
    #[inline(always)]
    fn columns_changed(&self, width: usize, by: usize, x: usize, lanes: usize, least: u8) -> bool {
        let dmax = &self.diff_max[by * width..(by + 1) * width];
        dmax[x..x + lanes].iter().fold(0u8, |m, &v| m.max(v)) >= least
    }

    /// The `It` and `S` windows of the block at `(x0, y0)`, `bw × rows` pixels,
    /// with `K`'s row routines.
    #[inline(always)]
    unsafe fn build_block<K: Simd>(
        &mut self,
        prev: &[u8],
        cur: &[u8],
        geom: &Geometry,
        (x0, y0): (usize, usize),
        (bw, rows): (usize, usize),
        offset: i16,
    ) {
        let (w, h) = (geom.width, geom.height);
        for r in 0..rows {
            let row = (y0 + r) * w + x0;
            let (p, c) = (&prev[row..row + bw], &cur[row..row + bw]);
            // SAFETY: forwarded from the caller (K's CPU features).
            unsafe { K::diff_row(p, c, offset, &mut self.it[r * self.it_stride..][..bw]) };
        }
        // Source columns x0 − 1 ..= x0 + bw, clamped to the frame: the in-frame part
        // is summed, the clamped ends (frame border) replicate their neighbour.
        let (first, last) = (x0.saturating_sub(1), (x0 + bw).min(w - 1));
        let at = first + 1 - x0; // window index of column `first`
        for r in 0..rows + 2 {
            let y = (y0 + r).saturating_sub(1).min(h - 1);
            let (p, c) = (
                &prev[y * w + first..=y * w + last],
                &cur[y * w + first..=y * w + last],
            );
            let s = &mut self.s[r * self.s_stride..][..bw + 2];
            // SAFETY: forwarded from the caller (K's CPU features).
            unsafe { K::sum_row(p, c, &mut s[at..at + p.len()]) };
            if at == 1 {
                s[0] = s[1];
            }
            if at + p.len() == bw + 1 {
                s[bw + 1] = s[bw];
            }
        }
    }
}

/// The vectorised routines of one implementation.
pub(super) trait Simd {
    /// Step 1 for one band of `width`-pixel rows (`p` and `c` hold the band):
    /// `dmax[x] = max over the rows of |c − p|` at column `x`.
    ///
    /// # Safety
    /// The implementation's CPU features must be present; `p` and `c` have one
    /// length, a multiple of `width`, and `dmax` has `width` elements.
    unsafe fn pretest_band(p: &[u8], c: &[u8], width: usize, dmax: &mut [u8]);

    /// The sums of one row of `p` and of `c`.
    ///
    /// # Safety
    /// The implementation's CPU features must be present; the slices have one length.
    unsafe fn row_sums(p: &[u8], c: &[u8]) -> (u64, u64);

    /// `it[x] = c[x] − p[x] − offset`.
    ///
    /// # Safety
    /// The implementation's CPU features must be present; the slices have one length.
    unsafe fn diff_row(p: &[u8], c: &[u8], offset: i16, it: &mut [i16]);

    /// `s[x] = p[x] + c[x]`.
    ///
    /// # Safety
    /// The implementation's CPU features must be present; the slices have one length.
    unsafe fn sum_row(p: &[u8], c: &[u8], s: &mut [i16]);

    /// Sums the motion pixels of strip `at` of the block windows, with the test's
    /// thresholds `th`; `FULL` when `at.lanes == 16`.
    ///
    /// # Safety
    /// The implementation's CPU features must be present; `at.x < block width`,
    /// `at.rows ≤ block_px`, `1 ≤ at.lanes ≤ 16` and `FULL == (at.lanes == 16)`.
    unsafe fn strip<const FULL: bool>(bands: &Bands, at: Strip, th: Thresholds) -> BlockSums;

    /// The same sums for the full 16-pixel strip at frame column `x`, rows
    /// `y0 .. y0 + rows`, straight from the frames (no windows), when the
    /// implementation has such a routine (`None` otherwise). Only for strips whose
    /// neighbours are all inside the frame: `1 ≤ x`, `x + 17 ≤ width`, `1 ≤ y0`,
    /// `y0 + rows < height`.
    ///
    /// # Safety
    /// The implementation's CPU features must be present; the frames are
    /// `width`-pixel rows.
    unsafe fn strip_direct(
        _prev: &[u8],
        _cur: &[u8],
        _width: usize,
        _at: (usize, usize, usize),
        _offset: i16,
        _thresholds: Thresholds,
    ) -> Option<BlockSums> {
        None
    }
}

/// A vertical strip of the block windows: `lanes` (≤ 16) columns from local column
/// `x`, over `rows` rows.
#[derive(Clone, Copy)]
pub(super) struct Strip {
    pub x: usize,
    pub rows: usize,
    pub lanes: usize,
}

/// The input of one run of the kernel: the frame pair, its grid, the thresholds and
/// the block mask (empty: none).
#[derive(Clone, Copy)]
pub(super) struct Job<'a> {
    pub prev: &'a [u8],
    pub cur: &'a [u8],
    pub geom: &'a Geometry,
    pub thresholds: Thresholds,
    pub mask: &'a [bool],
}

/// Runs the band-buffered kernel with routines `K` over the whole frame; returns
/// the brightness offset it used. Writes the sums of the blocks it computes and
/// pushes their indices to `active`; `out` must be all zero before.
///
/// # Safety
/// `K`'s CPU features must be present; the job's frames and mask, and `out`, must
/// match its `geom` (checked by [`MotionKernel::run`](super::MotionKernel::run)).
#[inline(always)]
pub(super) unsafe fn run_bands<K: Simd>(
    bands: &mut Bands,
    job: Job<'_>,
    out: &mut [BlockSums],
    active: &mut Vec<usize>,
) -> i16 {
    let Job {
        prev,
        cur,
        geom,
        thresholds,
        mask,
    } = job;
    // SAFETY: forwarded from the caller.
    let offset = unsafe { bands.pretest::<K>(prev, cur, geom) };
    let bp = geom.block_px;
    // |C − P − offset| ≥ diff implies |C − P| ≥ diff − |offset|: a pixel that fails
    // this cannot be a motion pixel, so columns that never reach it are skipped.
    let least = (thresholds.diff as i32 - offset.unsigned_abs() as i32).clamp(0, 255) as u8;
    for by in 0..geom.grid_h {
        let y0 = by * bp;
        let rows = bp.min(geom.height - y0);
        let row_mask = mask.get(by * geom.grid_w..(by + 1) * geom.grid_w);
        if row_mask.is_some_and(|m| m.iter().all(|&b| b)) {
            continue;
        }
        for bx in 0..geom.grid_w {
            let b = by * geom.grid_w + bx;
            let x0 = bx * bp;
            let width = bp.min(geom.width - x0);
            if row_mask.is_some_and(|m| m[bx])
                || !bands.columns_changed(geom.width, by, x0, width, least)
            {
                continue; // masked or still
            }
            let inner_rows = y0 >= 1 && y0 + rows < geom.height;
            let mut built = false;
            let mut sums = BlockSums::default();
            for sx in (0..width).step_by(LANES) {
                let (x, lanes) = (x0 + sx, LANES.min(width - sx));
                if width > LANES && !bands.columns_changed(geom.width, by, x, lanes, least) {
                    continue;
                }
                let inner = inner_rows && lanes == LANES && x >= 1 && x + LANES < geom.width;
                let direct = if inner {
                    // SAFETY: K's CPU features are the caller's promise; the frames are
                    // `geom.width`-pixel rows (the caller's promise) and `inner` holds
                    // the strip's neighbours inside the frame, as strip_direct requires.
                    unsafe {
                        K::strip_direct(prev, cur, geom.width, (x, y0, rows), offset, thresholds)
                    }
                } else {
                    None
                };
                sums += match direct {
                    Some(s) => s,
                    None => {
                        if !built {
                            let (at, size) = ((x0, y0), (width, rows));
                            // SAFETY: K's CPU features are the caller's promise; the
                            // block (x0, y0, width × rows) lies in the frame by the
                            // clamps to geom.width and geom.height above.
                            unsafe { bands.build_block::<K>(prev, cur, geom, at, size, offset) };
                            built = true;
                        }
                        // SAFETY: K's CPU features are the caller's promise;
                        // sx < width, rows ≤ block_px, 1 ≤ lanes ≤ LANES (16), and
                        // FULL is chosen by `lanes == LANES`, as strip requires.
                        unsafe {
                            let at = Strip { x: sx, rows, lanes };
                            if lanes == LANES {
                                K::strip::<true>(bands, at, thresholds)
                            } else {
                                K::strip::<false>(bands, at, thresholds)
                            }
                        }
                    }
                };
            }
            out[b] = sums;
            active.push(b);
        }
    }
    offset
}

/// The portable routines: plain array loops the compiler vectorises.
pub(super) struct Portable;

impl Simd for Portable {
    #[inline(always)]
    unsafe fn pretest_band(p: &[u8], c: &[u8], width: usize, dmax: &mut [u8]) {
        dmax.fill(0);
        for (p, c) in p.chunks_exact(width).zip(c.chunks_exact(width)) {
            for ((m, &a), &b) in dmax.iter_mut().zip(p).zip(c) {
                *m = (*m).max(a.max(b) - a.min(b));
            }
        }
    }

    #[inline(always)]
    unsafe fn row_sums(p: &[u8], c: &[u8]) -> (u64, u64) {
        // A row holds at most 8192 × 255 < 2^32.
        let sum = |f: &[u8]| f.iter().map(|&v| v as u32).sum::<u32>() as u64;
        (sum(p), sum(c))
    }

    #[inline(always)]
    unsafe fn diff_row(p: &[u8], c: &[u8], offset: i16, it: &mut [i16]) {
        for ((o, &a), &b) in it.iter_mut().zip(p).zip(c) {
            *o = (b as i16).wrapping_sub(a as i16).wrapping_sub(offset);
        }
    }

    #[inline(always)]
    unsafe fn sum_row(p: &[u8], c: &[u8], s: &mut [i16]) {
        for ((o, &a), &b) in s.iter_mut().zip(p).zip(c) {
            *o = a as i16 + b as i16;
        }
    }

    #[inline(always)]
    unsafe fn strip<const FULL: bool>(bands: &Bands, at: Strip, th: Thresholds) -> BlockSums {
        let Strip { x, rows, lanes } = at;
        let (ss, is) = (bands.s_stride, bands.it_stride);
        let dt = th.diff as i16;
        // g ≤ 1020, so clamping keeps `g ≥ gt` exact.
        let gt = th.gradient.min(i16::MAX as u16) as i16;
        let gsat = GRADIENT_SATURATION as i16;
        let k = th.speed.min(MAX_SPEED) as u32;
        let mut acc_w = [0i16; LANES];
        let mut acc_x = [0i32; LANES];
        let mut acc_y = [0i32; LANES];
        let mut acc_xx = [0i32; LANES];
        let mut acc_yy = [0i32; LANES];
        let mut acc_xy = [0i32; LANES];
        let mut acc_tt = [0i32; LANES];
        for r in 0..rows {
            let mid: &[i16; LANES + 2] = bands.s[(r + 1) * ss + x..][..LANES + 2]
                .try_into()
                .expect("padded row");
            let up: &[i16; LANES] = bands.s[r * ss + x + 1..][..LANES]
                .try_into()
                .expect("padded row");
            let down: &[i16; LANES] = bands.s[(r + 2) * ss + x + 1..][..LANES]
                .try_into()
                .expect("padded row");
            let it: &[i16; LANES] = bands.it[r * is + x..][..LANES]
                .try_into()
                .expect("padded row");
            for l in 0..LANES {
                let gx = mid[l + 2].wrapping_sub(mid[l]);
                let gy = down[l].wrapping_sub(up[l]);
                let t = it[l];
                let g = gx.wrapping_abs().wrapping_add(gy.wrapping_abs());
                let valid = FULL || l < lanes;
                let least = dt.max(((g as u16 as u32 * k) >> 16) as i16);
                let m = -((valid & (t.wrapping_abs() >= least) & (g >= gt)) as i16);
                acc_w[l] = acc_w[l].wrapping_add(g.min(gsat) & m);
                let (gxm, gym, tm) = ((gx & m) as i32, (gy & m) as i32, (t & m) as i32);
                acc_x[l] = acc_x[l].wrapping_add(t as i32 * gxm);
                acc_y[l] = acc_y[l].wrapping_add(t as i32 * gym);
                acc_xx[l] = acc_xx[l].wrapping_add(gxm * gx as i32);
                acc_yy[l] = acc_yy[l].wrapping_add(gym * gy as i32);
                acc_xy[l] = acc_xy[l].wrapping_add(gxm * gy as i32);
                acc_tt[l] = acc_tt[l].wrapping_add(tm * t as i32);
            }
        }
        let sum = |a: &[i32; LANES]| a.iter().map(|&v| v as i64).sum::<i64>();
        BlockSums {
            weight: acc_w.iter().map(|&v| v as u32).sum(),
            flow_x: -sum(&acc_x),
            flow_y: -sum(&acc_y),
            gxx: sum(&acc_xx),
            gyy: sum(&acc_yy),
            gxy: sum(&acc_xy),
            it2: sum(&acc_tt),
        }
    }
}
