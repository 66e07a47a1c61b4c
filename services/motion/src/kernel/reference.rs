//! The scalar reference: the brightness offset and every block's sums straight
//! from the specification, one pixel at a time.

use super::{BlockSums, GRADIENT_SATURATION, Geometry, MAX_SPEED, OFFSET_ROW_STEP, Thresholds};

/// The global brightness change of a frame pair: the mean of `cur − prev` over the
/// rows `y % OFFSET_ROW_STEP == 0`, rounded to an integer (half up). The
/// band-buffered implementations compute the same value in their first pass
/// ([`MotionKernel::offset`](super::MotionKernel::offset)).
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
pub(super) fn offset_of(sum_prev: u64, sum_cur: u64, pixels: usize) -> i16 {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernel::tests::noise;
    use crate::kernel::{Implementation, MotionKernel};

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
}
