//! Optional backend (`motion.backend = "dis"`): OpenCV's DIS optical flow
//! (`cv::DISOpticalFlow`, preset FAST), reduced to the same [`BlockSums`] as the
//! motion-flow kernel so that density, coherence, direction, masks and the
//! illumination check work unchanged.
//!
//! A pixel is a motion pixel when its flow `f` is at least [`MIN_FLOW_PX`] long and
//! its spatial gradient `g = |Gx| + |Gy|` (the kernel's sum-image gradient) reaches
//! the gradient threshold; it adds `w = min(g, GRADIENT_SATURATION)` to the weight.
//! The other sums are filled so that the kernel's formulas give the flow's own
//! statistics (fixed point, `F` = [`FLOW_SCALE`]): `b = F·Σ w·f`,
//! `T = 4·F·Σ w · I`, `Σ It² = F·Σ w·|f|² / 4`. Then the "Lucas–Kanade" displacement
//! `4·T⁻¹·b` is the weighted mean flow `Σ w·f / Σ w`, and the coherence `R²` is
//! `|Σ w·f|² / (Σ w · Σ w·|f|²)`: 1 when every pixel flows alike. DIS follows true
//! displacement rather than normal flow, at roughly 100× the cost of the kernel.

use opencv::core::{CV_32FC2, Mat, Scalar, Vec2f};
use opencv::prelude::*;
use opencv::video::DISOpticalFlow;

use crate::kernel::{BlockSums, GRADIENT_SATURATION, Geometry, Thresholds};

/// Shortest flow vector that counts as motion, pixels per frame.
pub const MIN_FLOW_PX: f32 = 0.5;

/// Fixed-point scale of flow components in [`BlockSums`] (1/256 px).
pub const FLOW_SCALE: f32 = 256.0;

/// DIS optical flow and its preallocated flow field, for one frame size.
pub struct DisFlow {
    geom: Geometry,
    dis: opencv::core::Ptr<DISOpticalFlow>,
    flow: Mat,
    sums: Vec<BlockSums>,
}

impl DisFlow {
    /// DIS (preset FAST) for `geom`.
    pub fn new(geom: Geometry) -> opencv::Result<Self> {
        let dis = DISOpticalFlow::create(opencv::video::DISOpticalFlow_PRESET_FAST)?;
        let flow = Mat::new_rows_cols_with_default(
            geom.height as i32,
            geom.width as i32,
            CV_32FC2,
            Scalar::all(0.0),
        )?;
        Ok(DisFlow {
            geom,
            dis,
            flow,
            sums: vec![BlockSums::default(); geom.blocks()],
        })
    }

    /// Block sums of the frame pair (GRAY8, `width × height` bytes each); masked
    /// blocks (`mask[b]`, if `mask` is not empty) get zero sums.
    pub fn run(
        &mut self,
        prev: &[u8],
        cur: &[u8],
        thresholds: Thresholds,
        mask: &[bool],
    ) -> opencv::Result<&[BlockSums]> {
        let g = self.geom;
        let (h, w) = (g.height as i32, g.width as i32);
        let p = Mat::new_rows_cols_with_data(h, w, prev)?;
        let c = Mat::new_rows_cols_with_data(h, w, cur)?;
        self.dis.calc(&p, &c, &mut self.flow)?;
        let flow: &[Vec2f] = self.flow.data_typed()?;
        reduce(prev, cur, flow, &g, thresholds, mask, &mut self.sums);
        Ok(&self.sums)
    }
}

/// Reduces a dense flow field to block sums (see the module documentation).
pub fn reduce(
    prev: &[u8],
    cur: &[u8],
    flow: &[Vec2f],
    g: &Geometry,
    thresholds: Thresholds,
    mask: &[bool],
    out: &mut [BlockSums],
) {
    let (w, h) = (g.width, g.height);
    out.fill(BlockSums::default());
    let s = |i: usize| prev[i] as i32 + cur[i] as i32;
    let min_sq = MIN_FLOW_PX * MIN_FLOW_PX;
    for y in 0..h {
        let (up, down) = (y.saturating_sub(1) * w, (y + 1).min(h - 1) * w);
        let row = y * w;
        let block_row = (y / g.block_px) * g.grid_w;
        for x in 0..w {
            let b = block_row + x / g.block_px;
            if mask.get(b).copied().unwrap_or(false) {
                continue;
            }
            let f = flow[row + x];
            let (fx, fy) = (f[0], f[1]);
            let length_sq = fx * fx + fy * fy;
            if length_sq.is_nan() || length_sq < min_sq {
                continue;
            }
            let gx = s(row + (x + 1).min(w - 1)) - s(row + x.saturating_sub(1));
            let gy = s(down + x) - s(up + x);
            let grad = gx.abs() + gy.abs();
            if grad < thresholds.gradient as i32 {
                continue;
            }
            let wt = grad.min(GRADIENT_SATURATION as i32);
            let o = &mut out[b];
            o.weight += wt as u32;
            let scale = wt as f32 * FLOW_SCALE;
            o.flow_x += (fx * scale).round() as i64;
            o.flow_y += (fy * scale).round() as i64;
            let t = 4 * FLOW_SCALE as i64 * wt as i64;
            o.gxx += t;
            o.gyy += t;
            o.it2 += (scale * (fx * fx + fy * fy) / 4.0).round() as i64;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uniform_flow_over_texture_is_one_coherent_direction() {
        let g = Geometry::new(32, 16, 16).unwrap();
        // A checkerboard-ish texture so every pixel has a gradient.
        let frame: Vec<u8> = (0..32 * 16)
            .map(|i| {
                if (i % 32 / 2 + i / 32 / 2) % 2 == 0 {
                    40
                } else {
                    200
                }
            })
            .collect();
        let mut flow = vec![Vec2f::from([0.0, 0.0]); 32 * 16];
        for y in 0..16 {
            for x in 0..16 {
                flow[y * 32 + x] = Vec2f::from([-2.0, 0.0]); // left half moves left
            }
        }
        let t = Thresholds {
            diff: 15,
            gradient: 8,
            speed: 0,
        };
        let mut out = vec![BlockSums::default(); 2];
        reduce(&frame, &frame, &flow, &g, t, &[], &mut out);
        assert!(out[0].weight > 0);
        assert!(out[0].flow_x < 0 && out[0].flow_y == 0);
        assert_eq!(out[1], BlockSums::default());
        // The block's fit is the flow itself, fully coherent.
        let f = crate::features::fit(&out[0]).unwrap();
        assert!((f.vx + 2.0).abs() < 1e-3 && f.vy.abs() < 1e-9, "{f:?}");
        assert!((f.coherence - 1.0).abs() < 1e-3, "{f:?}");
        // Masked: nothing.
        reduce(&frame, &frame, &flow, &g, t, &[true, false], &mut out);
        assert_eq!(out[0], BlockSums::default());
    }
}
