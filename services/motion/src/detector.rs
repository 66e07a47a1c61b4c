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
mod tests;
