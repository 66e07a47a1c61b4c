//! The motion detector of one camera: kernel (or DIS) → block features → mask →
//! illumination check, written straight into the caller's block buffer (in the
//! service: the loaned shared-memory sample).
//!
//! # Global illumination changes
//!
//! Lights switching, clouds and auto-exposure change the whole view at once. Two
//! steps keep them from being reported as activity:
//!
//! 1. **Compensation.** The mean brightness change of the frame pair
//!    ([`crate::kernel::brightness_offset`]) is subtracted from every temporal
//!    difference before the
//!    motion-pixel test, so a uniform step leaves no motion pixels, while people who
//!    move during the step are still seen.
//! 2. **Detection.** What compensation leaves (a gain change brightens bright areas
//!    more than dark ones) shows up as a large fraction of blocks changing at once
//!    with no common direction: when at least `illumination_fraction` of the unmasked
//!    blocks are above `density_threshold` and the density-weighted mean of their
//!    unit flow directions, `|Σ (dx, dy)| / Σ density`, is below
//!    [`ILLUMINATION_MAX_COHERENCE`], the frame is an illumination change and every
//!    block is zeroed. A camera shake or a crowd walking one way is coherent and
//!    stays motion.
//!
//! `FLAG_ILLUMINATION` is set in either case: when the compensated offset is at least
//! half the difference threshold (a step that would have lit up the view) and when
//! the frame was suppressed.

use std::mem::MaybeUninit;

use isochron_config::{MotionBackend, MotionConfig, Polygon};
use isochron_wire::{BlockMotion, DIRECTION_NONE, FLAG_APPEARANCE, FLAG_ILLUMINATION};

use crate::appearance::{Appearance, AppearanceSampler};
use crate::dis::DisFlow;
use crate::features::Features;
use crate::kernel::{Geometry, GeometryError, Implementation, MotionKernel, Thresholds};
use crate::mask::block_mask;

/// A frame whose changed blocks' flow agrees less than this (`|Σ (dx, dy)| /
/// Σ density` over the changed blocks) can be an illumination change.
pub const ILLUMINATION_MAX_COHERENCE: f32 = 0.25;

/// The parameters of the detector (the `[motion]` section without the backend).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionParams {
    /// Motion-pixel thresholds.
    pub thresholds: Thresholds,
    /// A block is moving when its density is at least this.
    pub density_threshold: f32,
    /// Fraction of unmasked blocks that must move for an illumination change.
    pub illumination_fraction: f32,
    /// Block appearance (for the presence band) is measured at most this often per
    /// second of capture time; 0: never.
    pub appearance_hz: f64,
}

impl MotionParams {
    /// The parameters of a `[motion]` section.
    pub fn from_config(config: &MotionConfig) -> Self {
        MotionParams {
            thresholds: Thresholds {
                diff: config.diff_threshold.max(1),
                gradient: config.gradient_threshold,
                speed: Thresholds::speed_of(config.min_flow_px),
            },
            density_threshold: config.density_threshold,
            illumination_fraction: config.illumination_fraction,
            appearance_hz: config.appearance_hz,
        }
    }
}

impl Default for MotionParams {
    fn default() -> Self {
        MotionParams::from_config(&MotionConfig::default())
    }
}

/// Why a frame pair could not be processed.
#[derive(Debug, thiserror::Error)]
pub enum MotionError {
    /// The frame size does not fit the kernel.
    #[error(transparent)]
    Geometry(#[from] GeometryError),
    /// A frame or the output buffer has the wrong size.
    #[error("size mismatch: {0}")]
    Size(String),
    /// OpenCV failed (DIS backend).
    #[error("OpenCV DIS optical flow: {0}")]
    OpenCv(#[from] opencv::Error),
}

/// What the detector found in one frame pair, beyond the blocks.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FrameReport {
    /// `FLAG_*` bits for the motion header (`FLAG_ILLUMINATION` or 0).
    pub flags: u32,
    /// Fraction of unmasked blocks at or above the density threshold, before any
    /// suppression.
    pub changed_fraction: f32,
    /// The frame was an illumination change and all blocks were zeroed.
    pub suppressed: bool,
    /// The global brightness offset that was compensated (grey levels).
    pub offset: i16,
    /// Unmasked blocks at or above the density threshold, after suppression.
    pub moving_blocks: usize,
    /// The blocks' appearance was measured on this frame (`FLAG_APPEARANCE`).
    pub appearance: bool,
}

enum Backend {
    MotionFlow(MotionKernel),
    Dis(Box<DisFlow>),
}

/// Motion features of one camera, for one frame size.
pub struct MotionDetector {
    geom: Geometry,
    params: MotionParams,
    backend: Backend,
    mask: Vec<bool>,
    masked_blocks: usize,
    /// `0 .. blocks`, for backends that compute every block.
    all_blocks: Vec<usize>,
    appearance: Appearance,
    sampler: AppearanceSampler,
}

impl MotionDetector {
    /// A detector for `width × height` frames with the `[motion]` section `config`
    /// and the camera's mask polygons.
    pub fn new(
        config: &MotionConfig,
        width: usize,
        height: usize,
        mask: &[Polygon],
    ) -> Result<Self, MotionError> {
        let geom = Geometry::new(width, height, config.block_px as usize)?;
        let backend = match config.backend {
            MotionBackend::MotionFlow => Backend::MotionFlow(MotionKernel::best(geom)),
            MotionBackend::Dis => Backend::Dis(Box::new(DisFlow::new(geom)?)),
        };
        Ok(Self::with_backend(
            geom,
            MotionParams::from_config(config),
            backend,
            mask,
        ))
    }

    /// A motion-flow detector with an explicit kernel implementation (tests,
    /// benchmarks).
    pub fn with_implementation(
        geom: Geometry,
        params: MotionParams,
        implementation: Implementation,
        mask: &[Polygon],
    ) -> Self {
        let kernel = MotionKernel::new(geom, implementation);
        Self::with_backend(geom, params, Backend::MotionFlow(kernel), mask)
    }

    fn with_backend(
        geom: Geometry,
        params: MotionParams,
        backend: Backend,
        mask: &[Polygon],
    ) -> Self {
        let mask = block_mask(&geom, mask);
        let masked_blocks = mask.iter().filter(|&&m| m).count();
        MotionDetector {
            geom,
            params,
            backend,
            mask,
            masked_blocks,
            all_blocks: (0..geom.blocks()).collect(),
            appearance: Appearance::new(&geom),
            sampler: AppearanceSampler::new(params.appearance_hz),
        }
    }

    /// The block grid.
    pub fn geometry(&self) -> &Geometry {
        &self.geom
    }

    /// The parameters.
    pub fn params(&self) -> &MotionParams {
        &self.params
    }

    /// Blocks the camera mask removes.
    pub fn masked_blocks(&self) -> usize {
        self.masked_blocks
    }

    /// The block mask (`true` = masked), empty when nothing is masked.
    pub fn mask(&self) -> &[bool] {
        &self.mask
    }

    /// Backend name for logs: `motion-flow/avx2`, `motion-flow/portable`, `dis`.
    pub fn backend_name(&self) -> String {
        match &self.backend {
            Backend::MotionFlow(k) => format!("motion-flow/{}", k.implementation().name()),
            Backend::Dis(_) => "dis".into(),
        }
    }

    /// Computes the blocks of the frame pair into `out` (one per block, row-major);
    /// `capture_ns` is the current frame's capture time, which decides whether its
    /// appearance is measured too (at most `appearance_hz` times a second).
    pub fn process(
        &mut self,
        prev: &[u8],
        cur: &[u8],
        capture_ns: i64,
        out: &mut [BlockMotion],
    ) -> Result<FrameReport, MotionError> {
        // SAFETY: `BlockMotion` and `MaybeUninit<BlockMotion>` have the same layout, and
        // `process_uninit` only ever writes initialised values, so `out` stays valid.
        let out = unsafe {
            std::slice::from_raw_parts_mut(
                out.as_mut_ptr().cast::<MaybeUninit<BlockMotion>>(),
                out.len(),
            )
        };
        self.process_uninit(prev, cur, capture_ns, out)
    }

    /// As [`MotionDetector::process`], into possibly uninitialised memory (a loaned
    /// sample). On `Ok`, every element of `out` is initialised.
    pub fn process_uninit(
        &mut self,
        prev: &[u8],
        cur: &[u8],
        capture_ns: i64,
        out: &mut [MaybeUninit<BlockMotion>],
    ) -> Result<FrameReport, MotionError> {
        let g = self.geom;
        if prev.len() != g.pixels() || cur.len() != g.pixels() {
            return Err(MotionError::Size(format!(
                "frames of {} and {} bytes, expected {}x{} = {}",
                prev.len(),
                cur.len(),
                g.width,
                g.height,
                g.pixels()
            )));
        }
        if out.len() != g.blocks() {
            return Err(MotionError::Size(format!(
                "{} output blocks, expected {}",
                out.len(),
                g.blocks()
            )));
        }
        let p = self.params;
        let still = BlockMotion {
            direction: DIRECTION_NONE,
            ..BlockMotion::default()
        };
        for o in out.iter_mut() {
            o.write(still); // most blocks of most frames
        }
        let all: &[usize] = &self.all_blocks;
        let (offset, sums, active) = match &mut self.backend {
            Backend::MotionFlow(kernel) => {
                kernel.run(prev, cur, p.thresholds, &self.mask);
                (kernel.offset(), kernel.sums(), kernel.active())
            }
            Backend::Dis(dis) => (0, dis.run(prev, cur, p.thresholds, &self.mask)?, all),
        };

        let mut changed = 0usize;
        let (mut sum_dx, mut sum_dy, mut sum_density) = (0f64, 0f64, 0f64);
        for &b in active {
            let s = &sums[b];
            if s.weight == 0 {
                continue;
            }
            let block = Features::from_sums(s, g.block_area(b)).to_block(p.density_threshold);
            if block.density >= p.density_threshold {
                changed += 1;
                sum_dx += block.dx as f64;
                sum_dy += block.dy as f64;
                sum_density += block.density as f64;
            }
            out[b].write(block);
        }
        let unmasked = g.blocks() - self.masked_blocks;
        let changed_fraction = if unmasked == 0 {
            0.0
        } else {
            changed as f32 / unmasked as f32
        };
        let agreement = if sum_density > 0.0 {
            ((sum_dx * sum_dx + sum_dy * sum_dy).sqrt() / sum_density) as f32
        } else {
            0.0
        };
        let suppressed = changed > 0
            && changed_fraction >= p.illumination_fraction
            && agreement < ILLUMINATION_MAX_COHERENCE;
        if suppressed {
            for o in out.iter_mut() {
                o.write(still);
            }
        }
        let stepped = 2 * offset.unsigned_abs() as u32 >= p.thresholds.diff as u32;
        let appearance = self.sampler.due(capture_ns);
        if appearance {
            // SAFETY: every element of `out` was written above (`still` first), and
            // `MaybeUninit<BlockMotion>` has the layout of `BlockMotion`.
            let blocks = unsafe {
                std::slice::from_raw_parts_mut(out.as_mut_ptr().cast::<BlockMotion>(), out.len())
            };
            self.appearance.measure(cur, &g, &self.mask, blocks);
        }
        let mut flags = if suppressed || stepped {
            FLAG_ILLUMINATION
        } else {
            0
        };
        if appearance {
            flags |= FLAG_APPEARANCE;
        }
        Ok(FrameReport {
            flags,
            changed_fraction,
            suppressed,
            offset,
            moving_blocks: if suppressed { 0 } else { changed },
            appearance,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use isochron_wire::FLAG_ILLUMINATION;

    /// A smooth random texture, isotropic at block scale: a sum of 8 sinusoids
    /// (wavelengths 12–28 px) with random orientations and phases, values in
    /// 20..=230. (A texture with a single orientation per block would leave only the
    /// normal flow knowable — the aperture problem — which is not what this tests.)
    struct Texture {
        waves: Vec<(f64, f64, f64)>,
    }

    impl Texture {
        fn new(seed: u64) -> Self {
            let mut x = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
            let mut next = move || {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                (x >> 11) as f64 / (1u64 << 53) as f64
            };
            let waves = (0..8)
                .map(|i| {
                    // Spread the orientations over the half circle, jittered.
                    let angle = (i as f64 + next()) * std::f64::consts::PI / 8.0;
                    let k = std::f64::consts::TAU / (12.0 + 16.0 * next());
                    (
                        k * angle.cos(),
                        k * angle.sin(),
                        next() * std::f64::consts::TAU,
                    )
                })
                .collect();
            Texture { waves }
        }

        fn at(&self, x: f64, y: f64) -> u8 {
            let v: f64 = self
                .waves
                .iter()
                .map(|(kx, ky, p)| (kx * x + ky * y + p).sin())
                .sum();
            (125.0 + 30.0 * v).clamp(20.0, 230.0) as u8
        }
    }

    /// A frame of `w × h`: the background texture, with a square of `side` px at
    /// (`sx`, `sy`) carrying its own texture (attached to the square).
    fn scene(
        w: usize,
        h: usize,
        bg: &Texture,
        square: Option<(&Texture, f64, f64, f64)>,
    ) -> Vec<u8> {
        let mut f = vec![0u8; w * h];
        for y in 0..h {
            for x in 0..w {
                let (xf, yf) = (x as f64, y as f64);
                f[y * w + x] = match square {
                    Some((t, sx, sy, side))
                        if xf >= sx && xf < sx + side && yf >= sy && yf < sy + side =>
                    {
                        t.at(xf - sx, yf - sy).saturating_add(20)
                    }
                    _ => bg.at(xf, yf) / 2,
                };
            }
        }
        f
    }

    /// A detector per kernel, motion only (the appearance has its own test).
    fn detector(w: usize, h: usize, mask: &[Polygon]) -> Vec<MotionDetector> {
        let geom = Geometry::new(w, h, 16).unwrap();
        let params = MotionParams {
            appearance_hz: 0.0,
            ..MotionParams::default()
        };
        Implementation::available()
            .into_iter()
            .map(|imp| MotionDetector::with_implementation(geom, params, imp, mask))
            .collect()
    }

    #[test]
    fn the_appearance_is_measured_when_due_and_flagged() {
        let (w, h) = (64, 32);
        let geom = Geometry::new(w, h, 16).unwrap();
        let params = MotionParams {
            appearance_hz: 2.0,
            ..MotionParams::default()
        };
        let mut d = MotionDetector::with_implementation(
            geom,
            params,
            Implementation::Portable,
            &[vec![[0.0, 0.0], [16.0, 0.0], [16.0, 16.0], [0.0, 16.0]]],
        );
        let frame = vec![90u8; w * h];
        let mut out = vec![BlockMotion::default(); geom.blocks()];
        // 2 Hz: the first frame of each half second of capture time.
        let flags: Vec<u32> = [0, 100, 400, 500, 600]
            .iter()
            .map(|ms| {
                let report = d.process(&frame, &frame, ms * 1_000_000, &mut out).unwrap();
                assert_eq!(report.appearance, report.flags & FLAG_APPEARANCE != 0);
                if report.appearance {
                    // The masked block is zero, the others their grey level.
                    assert_eq!(out[0].luma, 0);
                    assert!(
                        out[1..]
                            .iter()
                            .all(|b| b.luma == 90 * 256 && b.texture == 0)
                    );
                } else {
                    assert!(out.iter().all(|b| b.luma == 0));
                }
                report.flags
            })
            .collect();
        assert_eq!(flags, [FLAG_APPEARANCE, 0, 0, FLAG_APPEARANCE, 0]);
    }

    fn run(d: &mut MotionDetector, prev: &[u8], cur: &[u8]) -> (FrameReport, Vec<BlockMotion>) {
        let mut out = vec![BlockMotion::default(); d.geometry().blocks()];
        let report = d.process(prev, cur, 0, &mut out).unwrap();
        (report, out)
    }

    /// Blocks wholly inside the square in both frames; blocks not within 2 px of it
    /// in either frame.
    fn classify(
        geom: &Geometry,
        a: (f64, f64),
        b: (f64, f64),
        side: f64,
    ) -> (Vec<usize>, Vec<usize>) {
        let (mut inside, mut outside) = (Vec::new(), Vec::new());
        for blk in 0..geom.blocks() {
            let (x0, y0, bw, bh) = geom.block_rect(blk);
            let (x0, y0, x1, y1) = (x0 as f64, y0 as f64, (x0 + bw) as f64, (y0 + bh) as f64);
            let within =
                |(sx, sy): (f64, f64)| x0 >= sx && y0 >= sy && x1 <= sx + side && y1 <= sy + side;
            let near = |(sx, sy): (f64, f64)| {
                x1 > sx - 2.0 && x0 < sx + side + 2.0 && y1 > sy - 2.0 && y0 < sy + side + 2.0
            };
            if within(a) && within(b) {
                inside.push(blk);
            } else if !near(a) && !near(b) {
                outside.push(blk);
            }
        }
        (inside, outside)
    }

    #[test]
    fn textured_square_moving_in_each_direction_gives_that_direction() {
        let (w, h, side) = (160, 128, 64.0);
        let bg = Texture::new(1);
        let fg = Texture::new(2);
        for mut d in detector(w, h, &[]) {
            for dir in 0..8u8 {
                for speed in [2.0, 3.0, 4.0] {
                    let (ux, uy) = crate::features::label_vector(dir).unwrap();
                    let (ux, uy) = (ux.round() as f64, uy.round() as f64);
                    let a = (48.0, 32.0);
                    let b = (a.0 + ux * speed, a.1 + uy * speed);
                    let prev = scene(w, h, &bg, Some((&fg, a.0, a.1, side)));
                    let cur = scene(w, h, &bg, Some((&fg, b.0, b.1, side)));
                    let (report, blocks) = run(&mut d, &prev, &cur);
                    let (inside, outside) = classify(d.geometry(), a, b, side);
                    assert!(inside.len() >= 4, "{inside:?}");
                    let name = d.backend_name();
                    let mut exact = 0;
                    for &blk in &inside {
                        let m = blocks[blk];
                        assert!(m.density >= d.params().density_threshold, "{name}: {m:?}");
                        // Blocks with few motion pixels may see only one edge of the
                        // texture; then their label is the edge's normal, within 45°.
                        let near = [dir, (dir + 1) % 8, (dir + 7) % 8];
                        assert!(
                            m.direction == dir || (m.density < 0.1 && near.contains(&m.direction)),
                            "{name}: direction {dir} speed {speed}: block {blk} {m:?}"
                        );
                        exact += (m.direction == dir) as usize;
                    }
                    assert!(
                        exact * 10 >= inside.len() * 9,
                        "{name}: {exact} of {}",
                        inside.len()
                    );
                    for &blk in &outside {
                        assert_eq!(blocks[blk].density, 0.0, "{name}: block {blk} moved");
                        assert_eq!(blocks[blk].direction, DIRECTION_NONE);
                    }
                    assert!(!report.suppressed);
                    assert_eq!(report.flags, 0);
                }
            }
        }
    }

    #[test]
    fn global_brightness_step_is_compensated_and_flagged() {
        let (w, h) = (160, 128);
        let bg = Texture::new(3);
        let fg = Texture::new(4);
        for mut d in detector(w, h, &[]) {
            let prev = scene(w, h, &bg, None);
            let cur: Vec<u8> = prev.iter().map(|&v| v + 40).collect();
            let (report, blocks) = run(&mut d, &prev, &cur);
            assert_eq!(report.offset, 40);
            assert_eq!(report.flags, FLAG_ILLUMINATION);
            assert!(
                blocks.iter().all(|b| b.density == 0.0),
                "{}",
                d.backend_name()
            );

            // A person moving during the step is still seen, and only there.
            let prev = scene(w, h, &bg, Some((&fg, 48.0, 32.0, 48.0)));
            let cur: Vec<u8> = scene(w, h, &bg, Some((&fg, 51.0, 32.0, 48.0)))
                .iter()
                .map(|&v| v.saturating_add(40))
                .collect();
            let (report, blocks) = run(&mut d, &prev, &cur);
            assert_eq!(report.flags, FLAG_ILLUMINATION);
            assert!(!report.suppressed);
            let (inside, outside) = classify(d.geometry(), (48.0, 32.0), (51.0, 32.0), 48.0);
            assert!(inside.iter().all(|&b| blocks[b].direction == 0));
            assert!(outside.iter().all(|&b| blocks[b].density == 0.0));
        }
    }

    #[test]
    fn gain_change_is_detected_and_suppressed() {
        // Auto-exposure: everything 50 % brighter. The offset removes the mean;
        // what is left changes most blocks in no common direction.
        let (w, h) = (160, 128);
        let bg = Texture::new(5);
        for mut d in detector(w, h, &[]) {
            let prev = scene(w, h, &bg, None);
            let cur: Vec<u8> = prev.iter().map(|&v| (v as f32 * 1.5) as u8).collect();
            let (report, blocks) = run(&mut d, &prev, &cur);
            assert!(report.changed_fraction >= 0.5, "{report:?}");
            assert!(report.suppressed, "{report:?}");
            assert_eq!(report.flags, FLAG_ILLUMINATION);
            assert_eq!(report.moving_blocks, 0);
            assert!(
                blocks
                    .iter()
                    .all(|b| b.density == 0.0 && b.direction == DIRECTION_NONE)
            );
        }
    }

    #[test]
    fn coherent_whole_view_motion_is_not_an_illumination_change() {
        // The camera shakes 2 px to the right: every block moves, all the same way.
        let (w, h) = (160, 128);
        let bg = Texture::new(6);
        for mut d in detector(w, h, &[]) {
            let frame = |dx: f64| -> Vec<u8> {
                (0..w * h)
                    .map(|i| bg.at((i % w) as f64 - dx, (i / w) as f64))
                    .collect()
            };
            let (report, blocks) = run(&mut d, &frame(0.0), &frame(2.0));
            assert!(report.changed_fraction > 0.8, "{report:?}");
            assert!(!report.suppressed, "{report:?}");
            let right = blocks.iter().filter(|b| b.direction == 0).count();
            assert!(
                right * 10 >= blocks.len() * 9,
                "{right} of {}",
                blocks.len()
            );
            // The rest are edges (aperture: only the normal flow) — never opposite.
            assert!(
                blocks
                    .iter()
                    .all(|b| matches!(b.direction, 7 | 0 | 1 | DIRECTION_NONE))
            );
        }
    }

    #[test]
    fn masked_region_never_reports_motion() {
        let (w, h) = (160, 128);
        let bg = Texture::new(7);
        let fg = Texture::new(8);
        // Mask the left half; a square moves across the middle.
        let mask = vec![vec![[0.0, 0.0], [80.0, 0.0], [80.0, 128.0], [0.0, 128.0]]];
        for mut d in detector(w, h, &mask) {
            assert_eq!(d.masked_blocks(), 5 * 8);
            let prev = scene(w, h, &bg, Some((&fg, 40.0, 40.0, 80.0)));
            let cur = scene(w, h, &bg, Some((&fg, 43.0, 40.0, 80.0)));
            let (report, blocks) = run(&mut d, &prev, &cur);
            for (b, blk) in blocks.iter().enumerate() {
                let masked = b % 10 < 5;
                if masked {
                    assert_eq!(
                        *blk,
                        BlockMotion {
                            direction: DIRECTION_NONE,
                            ..Default::default()
                        }
                    );
                }
            }
            // The unmasked half of the square moves.
            assert!(
                blocks
                    .iter()
                    .enumerate()
                    .any(|(b, m)| b % 10 >= 5 && m.direction == 0)
            );
            assert!(report.moving_blocks > 0);
        }
    }

    #[test]
    fn shimmering_static_edge_is_not_motion_but_a_moving_one_is() {
        // A high-contrast vertical edge (40 → 240 over ~3 px). Shifted by 0.3 px it
        // changes pixels by up to ~25 grey levels: above the difference threshold,
        // but its normal flow is below min_flow_px. Shifted by 2 px it moves.
        let (w, h) = (64, 32);
        let edge = |shift: f64| -> Vec<u8> {
            (0..w * h)
                .map(|i| {
                    let x = (i % w) as f64 - 32.0 - shift;
                    (140.0 + 100.0 * (x / 1.5).tanh()).round() as u8
                })
                .collect()
        };
        let geom = Geometry::new(w, h, 16).unwrap();
        let with = MotionParams::default();
        let without = MotionParams {
            thresholds: Thresholds {
                speed: 0,
                ..with.thresholds
            },
            ..with
        };
        for imp in Implementation::available() {
            let mut d = MotionDetector::with_implementation(geom, with, imp, &[]);
            let mut plain = MotionDetector::with_implementation(geom, without, imp, &[]);
            let (_, shimmer) = run(&mut d, &edge(0.0), &edge(0.3));
            let (_, shimmer_plain) = run(&mut plain, &edge(0.0), &edge(0.3));
            assert!(
                shimmer.iter().all(|b| b.density == 0.0),
                "{}: {shimmer:?}",
                d.backend_name()
            );
            assert!(
                shimmer_plain.iter().any(|b| b.density > 0.0),
                "the test needs |It| ≥ diff"
            );
            let (_, moved) = run(&mut d, &edge(0.0), &edge(2.0));
            assert!(
                moved.iter().any(|b| b.density >= 0.02 && b.direction == 0),
                "{moved:?}"
            );
        }
    }

    #[test]
    fn wrong_sizes_are_errors_not_panics() {
        let mut d = detector(32, 32, &[]).remove(0);
        let f = vec![0u8; 32 * 32];
        let mut out = vec![BlockMotion::default(); 4];
        assert!(d.process(&f, &f[..100], 0, &mut out).is_err());
        let mut short = vec![BlockMotion::default(); 3];
        assert!(d.process(&f, &f, 0, &mut short).is_err());
        assert!(d.process(&f, &f, 0, &mut out).is_ok());
    }

    #[test]
    fn dis_backend_sees_the_moving_square() {
        let (w, h, side) = (160, 128, 64.0);
        let bg = Texture::new(9);
        let fg = Texture::new(10);
        let config = MotionConfig {
            backend: MotionBackend::Dis,
            ..MotionConfig::default()
        };
        let mut d = MotionDetector::new(&config, w, h, &[]).unwrap();
        assert_eq!(d.backend_name(), "dis");
        let a = (48.0, 32.0);
        let b = (51.0, 32.0);
        let prev = scene(w, h, &bg, Some((&fg, a.0, a.1, side)));
        let cur = scene(w, h, &bg, Some((&fg, b.0, b.1, side)));
        let (_, blocks) = run(&mut d, &prev, &cur);
        let (inside, outside) = classify(d.geometry(), a, b, side);
        let right = inside.iter().filter(|&&b| blocks[b].direction == 0).count();
        assert!(right * 4 >= inside.len() * 3, "{right} of {}", inside.len());
        let quiet = outside
            .iter()
            .filter(|&&b| blocks[b].density < 0.02)
            .count();
        assert!(
            quiet * 10 >= outside.len() * 9,
            "{quiet} of {}",
            outside.len()
        );
    }
}
