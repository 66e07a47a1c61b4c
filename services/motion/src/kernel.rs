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
//!   array loops that LLVM vectorises for any target (SSE2, NEON on aarch64);
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

/// Lanes of one chunk: a 16-pixel block row, one 256-bit register of `i16`.
pub const LANES: usize = 16;

/// A motion pixel's density weight is `min(g, GRADIENT_SATURATION)`; a block's
/// density is `weight / (GRADIENT_SATURATION × pixels)`. 64 is reached by an edge of
/// 32 grey levels; stronger edges count no more than that.
pub const GRADIENT_SATURATION: u16 = 64;

/// The brightness offset is the mean over rows `y` with `y % OFFSET_ROW_STEP == 0`:
/// a sixteenth of the frame (27 600 pixels at 768×576) gives the mean to a small
/// fraction of a grey level, for a sixteenth of the summing.
pub const OFFSET_ROW_STEP: usize = 16;

/// Largest block edge the kernel accepts (keeps every per-strip lane sum inside
/// `i16`/`i32`: 128 rows × 64 < 2^15 and 8 lanes × 128 rows × 2 × 510² < 2^31).
pub const MAX_BLOCK_PX: usize = 128;

/// The block grid of a frame: `ceil(width / block_px) × ceil(height / block_px)`
/// blocks, row-major; edge blocks may be smaller.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Geometry {
    /// Frame width, pixels.
    pub width: usize,
    /// Frame height, pixels.
    pub height: usize,
    /// Block edge, pixels.
    pub block_px: usize,
    /// Blocks per row.
    pub grid_w: usize,
    /// Block rows.
    pub grid_h: usize,
}

/// A frame size or block size the kernel cannot work with.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum GeometryError {
    /// Zero width or height.
    #[error("empty frame ({width}x{height})")]
    Empty {
        /// Width.
        width: usize,
        /// Height.
        height: usize,
    },
    /// Block edge outside `1..=MAX_BLOCK_PX`.
    #[error("block size {0} px is outside 1..={MAX_BLOCK_PX}")]
    BlockSize(usize),
}

impl Geometry {
    /// The grid of `block_px` blocks over a `width × height` frame.
    pub fn new(width: usize, height: usize, block_px: usize) -> Result<Self, GeometryError> {
        if width == 0 || height == 0 {
            return Err(GeometryError::Empty { width, height });
        }
        if block_px == 0 || block_px > MAX_BLOCK_PX {
            return Err(GeometryError::BlockSize(block_px));
        }
        Ok(Geometry {
            width,
            height,
            block_px,
            grid_w: width.div_ceil(block_px),
            grid_h: height.div_ceil(block_px),
        })
    }

    /// Number of blocks.
    pub fn blocks(&self) -> usize {
        self.grid_w * self.grid_h
    }

    /// Pixels in a frame.
    pub fn pixels(&self) -> usize {
        self.width * self.height
    }

    /// Block `b`'s rectangle: `(x0, y0, width, height)` in pixels.
    pub fn block_rect(&self, b: usize) -> (usize, usize, usize, usize) {
        let (bx, by) = (b % self.grid_w, b / self.grid_w);
        let (x0, y0) = (bx * self.block_px, by * self.block_px);
        (
            x0,
            y0,
            self.block_px.min(self.width - x0),
            self.block_px.min(self.height - y0),
        )
    }

    /// Pixels in block `b`.
    pub fn block_area(&self, b: usize) -> usize {
        let (_, _, w, h) = self.block_rect(b);
        w * h
    }
}

/// Thresholds of the motion-pixel test.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Thresholds {
    /// `|It| ≥ diff` (grey levels, ≥ 1).
    pub diff: u8,
    /// `|Gx| + |Gy| ≥ gradient` (sum-image central differences).
    pub gradient: u16,
    /// `|It| ≥ ⌊g·speed / 2¹⁶⌋`: the least normal-flow speed in 1/16384 pixels per
    /// frame, at most [`MAX_SPEED`] (see [`Thresholds::speed_of`]); 0 disables the
    /// test.
    pub speed: u16,
}

/// Largest [`Thresholds::speed`]: just under 2 pixels per frame, so that the
/// product fits a signed 16-bit multiply-high.
pub const MAX_SPEED: u16 = i16::MAX as u16;

impl Thresholds {
    /// The `speed` field for a least normal-flow speed of `px` pixels per frame
    /// (0 ..< 2; larger values are clamped).
    pub fn speed_of(px: f32) -> u16 {
        (px * 16384.0).round().clamp(0.0, MAX_SPEED as f32) as u16
    }
}

/// One block's sums over its motion pixels (see the module documentation).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BlockSums {
    /// `Σ min(g, GRADIENT_SATURATION)`.
    pub weight: u32,
    /// `Σ −It·Gx`.
    pub flow_x: i64,
    /// `Σ −It·Gy`.
    pub flow_y: i64,
    /// `Σ Gx²`.
    pub gxx: i64,
    /// `Σ Gy²`.
    pub gyy: i64,
    /// `Σ Gx·Gy`.
    pub gxy: i64,
    /// `Σ It²`.
    pub it2: i64,
}

impl std::ops::AddAssign for BlockSums {
    fn add_assign(&mut self, o: BlockSums) {
        self.weight += o.weight;
        self.flow_x += o.flow_x;
        self.flow_y += o.flow_y;
        self.gxx += o.gxx;
        self.gyy += o.gyy;
        self.gxy += o.gxy;
        self.it2 += o.it2;
    }
}

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

/// The global brightness change of a frame pair: the mean of `cur − prev` over the
/// rows `y % OFFSET_ROW_STEP == 0`, rounded to an integer (half up). The
/// band-buffered implementations compute the same value in their first pass
/// ([`MotionKernel::offset`]).
///
/// # Panics
/// If a frame is shorter than `width × height`.
pub fn brightness_offset(prev: &[u8], cur: &[u8], width: usize, height: usize) -> i16 {
    let (mut sum_p, mut sum_c, mut n) = (0u64, 0u64, 0usize);
    for y in (0..height).step_by(OFFSET_ROW_STEP) {
        let row = y * width..(y + 1) * width;
        sum_p += prev[row.clone()].iter().map(|&v| v as u64).sum::<u64>();
        sum_c += cur[row].iter().map(|&v| v as u64).sum::<u64>();
        n += width;
    }
    offset_of(sum_p, sum_c, n)
}

/// `round((sum_cur − sum_prev) / pixels)`, half up.
fn offset_of(sum_prev: u64, sum_cur: u64, pixels: usize) -> i16 {
    let n = pixels.max(1) as i64;
    let diff = sum_cur as i64 - sum_prev as i64;
    (2 * diff + n).div_euclid(2 * n) as i16
}

/// The specification: per-pixel sums of every block, straight from the definition in
/// the module documentation. Blocks with `mask[b] == true` get zero sums. `mask` may
/// be empty (nothing masked).
///
/// # Panics
/// If the frames, `mask` or `out` do not match `geom`.
pub fn reference(
    prev: &[u8],
    cur: &[u8],
    geom: &Geometry,
    thresholds: Thresholds,
    offset: i16,
    mask: &[bool],
    out: &mut [BlockSums],
) {
    let (w, h) = (geom.width, geom.height);
    assert!(prev.len() >= w * h && cur.len() >= w * h, "frame too short");
    assert!(mask.is_empty() || mask.len() == geom.blocks(), "mask size");
    assert_eq!(out.len(), geom.blocks(), "output size");
    let s = |x: isize, y: isize| -> i32 {
        let x = x.clamp(0, w as isize - 1) as usize;
        let y = y.clamp(0, h as isize - 1) as usize;
        prev[y * w + x] as i32 + cur[y * w + x] as i32
    };
    for (b, sums) in out.iter_mut().enumerate() {
        *sums = BlockSums::default();
        if mask.get(b).copied().unwrap_or(false) {
            continue;
        }
        let (x0, y0, bw, bh) = geom.block_rect(b);
        for y in y0..y0 + bh {
            for x in x0..x0 + bw {
                let i = y * w + x;
                let it = cur[i] as i32 - prev[i] as i32 - offset as i32;
                let (xi, yi) = (x as isize, y as isize);
                let gx = s(xi + 1, yi) - s(xi - 1, yi);
                let gy = s(xi, yi + 1) - s(xi, yi - 1);
                let g = gx.abs() + gy.abs();
                let speed = thresholds.speed.min(MAX_SPEED) as i32;
                let least = (thresholds.diff as i32).max((g * speed) >> 16);
                if it.abs() >= least && g >= thresholds.gradient as i32 {
                    sums.weight += g.min(GRADIENT_SATURATION as i32) as u32;
                    sums.flow_x -= (it * gx) as i64;
                    sums.flow_y -= (it * gy) as i64;
                    sums.gxx += (gx * gx) as i64;
                    sums.gyy += (gy * gy) as i64;
                    sums.gxy += (gx * gy) as i64;
                    sums.it2 += (it * it) as i64;
                }
            }
        }
    }
}

/// Buffers of the band-buffered implementations: the pre-test of every band (row
/// of blocks) and the `It` and `S` windows of one block.
#[derive(Debug, Clone)]
struct Bands {
    /// Per band and frame column, the largest `|C − P|` over the band's rows
    /// (`grid_h × width`).
    diff_max: Vec<u8>,
    /// `block_px + 2` rows of `S` around the block: row 0 is the frame row above it,
    /// row `r + 1` is block row `r`. Row layout: `s[0] = S(x0 − 1)`,
    /// `s[i + 1] = S(x0 + i)`, `s[bw + 1] = S(x0 + bw)` (coordinates clamped to the
    /// frame), then padding for the last 16-lane loads.
    s: Vec<i16>,
    s_stride: usize,
    /// `block_px` rows of the block's `It` (offset subtracted), padded to whole
    /// chunks.
    it: Vec<i16>,
    it_stride: usize,
}

impl Bands {
    fn new(geom: &Geometry) -> Self {
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
trait Simd {
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

    /// Sums the motion pixels of the `lanes`-wide (≤ 16) vertical strip at local
    /// column `x` of the block windows over `rows` rows; `FULL` when `lanes == 16`.
    ///
    /// # Safety
    /// The implementation's CPU features must be present; `x < block width`,
    /// `rows ≤ block_px`, `1 ≤ lanes ≤ 16` and `FULL == (lanes == 16)`.
    unsafe fn strip<const FULL: bool>(
        bands: &Bands,
        x: usize,
        rows: usize,
        lanes: usize,
        thresholds: Thresholds,
    ) -> BlockSums;

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

/// Runs the band-buffered kernel with routines `K` over the whole frame; returns
/// the brightness offset it used. Writes the sums of the blocks it computes and
/// pushes their indices to `active`; `out` must be all zero before.
///
/// # Safety
/// `K`'s CPU features must be present; the frames, `mask` and `out` must match
/// `geom` (checked by [`MotionKernel::run`]).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn run_bands<K: Simd>(
    bands: &mut Bands,
    prev: &[u8],
    cur: &[u8],
    geom: &Geometry,
    thresholds: Thresholds,
    mask: &[bool],
    out: &mut [BlockSums],
    active: &mut Vec<usize>,
) -> i16 {
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
                // SAFETY (all three calls): forwarded from the caller; the strip lies in
                // the block (sx < width, rows ≤ bp), FULL matches, `inner` as required.
                let direct = if inner {
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
                            unsafe { bands.build_block::<K>(prev, cur, geom, at, size, offset) };
                            built = true;
                        }
                        unsafe {
                            if lanes == LANES {
                                K::strip::<true>(bands, sx, rows, lanes, thresholds)
                            } else {
                                K::strip::<false>(bands, sx, rows, lanes, thresholds)
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
struct Portable;

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
    unsafe fn strip<const FULL: bool>(
        bands: &Bands,
        x: usize,
        rows: usize,
        lanes: usize,
        thresholds: Thresholds,
    ) -> BlockSums {
        let (ss, is) = (bands.s_stride, bands.it_stride);
        let dt = thresholds.diff as i16;
        // g ≤ 1020, so clamping keeps `g ≥ gt` exact.
        let gt = thresholds.gradient.min(i16::MAX as u16) as i16;
        let gsat = GRADIENT_SATURATION as i16;
        let k = thresholds.speed.min(MAX_SPEED) as u32;
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

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::{BlockSums, GRADIENT_SATURATION, LANES, MAX_SPEED, Simd, Thresholds};
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
                return unsafe { super::Portable::diff_row(p, c, offset, it) };
            }
            let off = _mm256_set1_epi16(offset);
            // Chunks of 16; the last one overlaps the one before (n ≥ 16).
            let mut x = 0;
            loop {
                let at = x.min(n - LANES);
                // SAFETY: AVX2 is present (caller); at + 16 ≤ n for every access.
                unsafe {
                    let a = _mm256_cvtepu8_epi16(_mm_loadu_si128(p.as_ptr().add(at).cast()));
                    let b = _mm256_cvtepu8_epi16(_mm_loadu_si128(c.as_ptr().add(at).cast()));
                    let t = _mm256_sub_epi16(_mm256_sub_epi16(b, a), off);
                    _mm256_storeu_si256(it.as_mut_ptr().add(at).cast(), t);
                }
                if at + LANES == n {
                    break;
                }
                x += LANES;
            }
        }

        #[inline]
        #[target_feature(enable = "avx2")]
        unsafe fn sum_row(p: &[u8], c: &[u8], s: &mut [i16]) {
            let n = p.len().min(c.len()).min(s.len());
            if n < LANES {
                // SAFETY: the portable routine needs no CPU feature.
                return unsafe { super::Portable::sum_row(p, c, s) };
            }
            let mut x = 0;
            loop {
                let at = x.min(n - LANES);
                // SAFETY: AVX2 is present (caller); at + 16 ≤ n for every access.
                unsafe {
                    let a = _mm256_cvtepu8_epi16(_mm_loadu_si128(p.as_ptr().add(at).cast()));
                    let b = _mm256_cvtepu8_epi16(_mm_loadu_si128(c.as_ptr().add(at).cast()));
                    _mm256_storeu_si256(s.as_mut_ptr().add(at).cast(), _mm256_add_epi16(a, b));
                }
                if at + LANES == n {
                    break;
                }
                x += LANES;
            }
        }

        #[inline]
        #[target_feature(enable = "avx2")]
        unsafe fn strip<const FULL: bool>(
            bands: &super::Bands,
            x: usize,
            rows: usize,
            lanes: usize,
            thresholds: Thresholds,
        ) -> BlockSums {
            let (ss, is) = (bands.s_stride, bands.it_stride);
            // Every load below stays inside the padded buffers (see Bands::new).
            debug_assert!((rows + 1) * ss + x + LANES + 2 <= bands.s.len());
            debug_assert!((rows.max(1) - 1) * is + x + LANES <= bands.it.len());
            let s = bands.s.as_ptr();
            let it = bands.it.as_ptr();
            // SAFETY: the caller guarantees AVX2; all loads are unaligned loads inside
            // the buffers (asserted above).
            unsafe {
                let mut acc = Acc::new(thresholds, lanes);
                for r in 0..rows {
                    let mid = s.add((r + 1) * ss + x);
                    let left = _mm256_loadu_si256(mid.cast());
                    let right = _mm256_loadu_si256(mid.add(2).cast());
                    let up = _mm256_loadu_si256(s.add(r * ss + x + 1).cast());
                    let down = _mm256_loadu_si256(s.add((r + 2) * ss + x + 1).cast());
                    let t = _mm256_loadu_si256(it.add(r * is + x).cast());
                    acc.add_row::<FULL>(
                        t,
                        _mm256_sub_epi16(right, left),
                        _mm256_sub_epi16(down, up),
                    );
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
                    acc.add_row::<true>(
                        t,
                        _mm256_sub_epi16(right, left),
                        _mm256_sub_epi16(down, up),
                    );
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
    #[allow(clippy::too_many_arguments)]
    pub(super) unsafe fn run(
        bands: &mut super::Bands,
        prev: &[u8],
        cur: &[u8],
        geom: &super::Geometry,
        thresholds: Thresholds,
        mask: &[bool],
        out: &mut [BlockSums],
        active: &mut Vec<usize>,
    ) -> i16 {
        // SAFETY: AVX2 is present (this function's contract).
        unsafe { super::run_bands::<Avx2>(bands, prev, cur, geom, thresholds, mask, out, active) }
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
        let active = &mut self.active;
        self.offset = match self.implementation {
            Implementation::Scalar => {
                let offset = brightness_offset(prev, cur, g.width, g.height);
                reference(prev, cur, g, thresholds, offset, mask, &mut self.sums);
                let unmasked = |&b: &usize| !mask.get(b).copied().unwrap_or(false);
                active.extend((0..g.blocks()).filter(unmasked));
                offset
            }
            // SAFETY: the portable routines need no CPU feature; sizes checked above.
            Implementation::Portable => unsafe {
                run_bands::<Portable>(
                    &mut self.bands,
                    prev,
                    cur,
                    g,
                    thresholds,
                    mask,
                    &mut self.sums,
                    active,
                )
            },
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `new` checked that the CPU has AVX2; sizes checked above.
            Implementation::Avx2 => unsafe {
                avx2::run(
                    &mut self.bands,
                    prev,
                    cur,
                    g,
                    thresholds,
                    mask,
                    &mut self.sums,
                    active,
                )
            },
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

    fn noise(seed: u64, n: usize) -> Vec<u8> {
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
    fn geometry_covers_partial_edge_blocks() {
        let g = Geometry::new(100, 33, 16).unwrap();
        assert_eq!((g.grid_w, g.grid_h), (7, 3));
        assert_eq!(g.block_rect(6), (96, 0, 4, 16));
        assert_eq!(g.block_rect(20), (96, 32, 4, 1));
        assert_eq!(g.block_area(20), 4);
        let total: usize = (0..g.blocks()).map(|b| g.block_area(b)).sum();
        assert_eq!(total, 100 * 33);
        assert!(Geometry::new(0, 10, 16).is_err());
        assert!(Geometry::new(10, 10, 0).is_err());
        assert!(Geometry::new(10, 10, MAX_BLOCK_PX + 1).is_err());
    }

    #[test]
    fn reference_sums_one_hand_computed_pixel() {
        // 3×3 frame, one block. Only the centre changes, by +20; the sum image has a
        // horizontal ramp so the centre has Gx = S(2,1) − S(0,1).
        let prev = [0, 10, 20, 0, 10, 20, 0, 10, 20];
        let mut cur = prev;
        cur[4] += 20;
        let g = Geometry::new(3, 3, 16).unwrap();
        let t = Thresholds {
            diff: 15,
            gradient: 0,
            speed: 0,
        };
        let mut out = [BlockSums::default()];
        reference(&prev, &cur, &g, t, 0, &[], &mut out);
        // Centre: It = 20, Gx = (20+20) − (0+0) = 40, Gy = 0 (S(1,2) − S(1,0) = 20 − 20).
        // Its neighbours changed by 0 (not motion pixels).
        assert_eq!(
            out[0],
            BlockSums {
                weight: 40,
                flow_x: -20 * 40,
                flow_y: 0,
                gxx: 40 * 40,
                gyy: 0,
                gxy: 0,
                it2: 20 * 20,
            }
        );
        // The offset is subtracted before the test: 20 − 10 = 10 < 15.
        reference(&prev, &cur, &g, t, 10, &[], &mut out);
        assert_eq!(out[0], BlockSums::default());
        // A gradient threshold above 40 removes the pixel.
        let t = Thresholds {
            diff: 15,
            gradient: 41,
            speed: 0,
        };
        reference(&prev, &cur, &g, t, 0, &[], &mut out);
        assert_eq!(out[0], BlockSums::default());
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

    #[test]
    fn brightness_offset_is_the_rounded_mean_change() {
        let (w, h) = (40, 30);
        let prev: Vec<u8> = noise(6, w * h).iter().map(|&v| v % 200).collect();
        let up: Vec<u8> = prev.iter().map(|&v| v + 12).collect();
        assert_eq!(brightness_offset(&prev, &up, w, h), 12);
        assert_eq!(brightness_offset(&up, &prev, w, h), -12);
        assert_eq!(brightness_offset(&prev, &prev, w, h), 0);
        // Half a level rounds up; below half rounds down (over the sampled rows).
        let brighten = |n: usize| {
            let mut f = prev.clone();
            for y in (0..h).step_by(OFFSET_ROW_STEP) {
                f[y * w..y * w + n].iter_mut().for_each(|v| *v += 1);
            }
            f
        };
        assert_eq!(brightness_offset(&prev, &brighten(w / 2), w, h), 1);
        assert_eq!(brightness_offset(&prev, &brighten(w / 2 - 1), w, h), 0);
        // Rows between the sampled ones do not count.
        let mut unsampled = prev.clone();
        unsampled[w..2 * w].iter_mut().for_each(|v| *v += 50);
        assert_eq!(brightness_offset(&prev, &unsampled, w, h), 0);
        // The kernels compute the same offset in their first pass.
        let geom = Geometry::new(w, h, 16).unwrap();
        for imp in Implementation::available() {
            let mut k = MotionKernel::new(geom, imp);
            k.run(
                &prev,
                &up,
                Thresholds {
                    diff: 15,
                    gradient: 8,
                    speed: 0,
                },
                &[],
            );
            assert_eq!(k.offset(), 12, "{}", imp.name());
        }
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
