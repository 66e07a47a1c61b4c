//! Per-camera masks: polygons in frame pixels (`camera.mask`) turned once into a
//! block mask. A block is masked when at least half of its pixels (by pixel centre,
//! even-odd rule, union over the polygons) lie inside a mask polygon; masked blocks
//! are never computed and always report zero motion.

use isochron_config::Polygon;

use crate::kernel::Geometry;

/// The block mask of `polygons` over `geom`: `true` for masked blocks. Empty when
/// there are no polygons (nothing masked).
pub fn block_mask(geom: &Geometry, polygons: &[Polygon]) -> Vec<bool> {
    if polygons.is_empty() {
        return Vec::new();
    }
    let mut covered = vec![0usize; geom.blocks()];
    let mut spans: Vec<(f64, f64)> = Vec::new();
    let mut crossings: Vec<f64> = Vec::new();
    for y in 0..geom.height {
        let yc = y as f64 + 0.5;
        spans.clear();
        for poly in polygons {
            crossings.clear();
            for (i, a) in poly.iter().enumerate() {
                let b = poly[(i + 1) % poly.len()];
                // Half-open in y so a vertex on the scan line counts once.
                if (a[1] <= yc) != (b[1] <= yc) {
                    let t = (yc - a[1]) / (b[1] - a[1]);
                    crossings.push(a[0] + t * (b[0] - a[0]));
                }
            }
            crossings.sort_by(f64::total_cmp);
            spans.extend(crossings.chunks_exact(2).map(|c| (c[0], c[1])));
        }
        spans.sort_by(|a, b| a.0.total_cmp(&b.0));
        // Merge overlapping spans (union of the polygons), then count pixel centres.
        let mut merged: Option<(f64, f64)> = None;
        for &(a, b) in spans
            .iter()
            .chain(std::iter::once(&(f64::INFINITY, f64::INFINITY)))
        {
            match merged {
                Some((ma, mb)) if a <= mb => merged = Some((ma, mb.max(b))),
                Some(span) => {
                    add_span(geom, y, span, &mut covered);
                    merged = Some((a, b));
                }
                None => merged = Some((a, b)),
            }
        }
    }
    covered
        .iter()
        .enumerate()
        .map(|(b, &n)| 2 * n >= geom.block_area(b))
        .collect()
}

/// Adds the pixels of row `y` whose centres lie in `[a, b)` to their blocks' counts.
fn add_span(geom: &Geometry, y: usize, (a, b): (f64, f64), covered: &mut [usize]) {
    if !a.is_finite() && !b.is_finite() {
        return;
    }
    // Pixel x is inside when a ≤ x + 0.5 < b.
    let first = (a - 0.5).ceil().max(0.0);
    let end = (b - 0.5).ceil().min(geom.width as f64);
    if end <= first {
        return;
    }
    let (first, end) = (first as usize, end as usize);
    let row = (y / geom.block_px) * geom.grid_w;
    let mut x = first;
    while x < end {
        let bx = x / geom.block_px;
        let next = ((bx + 1) * geom.block_px).min(end);
        covered[row + bx] += next - x;
        x = next;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rect(x0: f64, y0: f64, x1: f64, y1: f64) -> Polygon {
        vec![[x0, y0], [x1, y0], [x1, y1], [x0, y1]]
    }

    #[test]
    fn no_polygons_masks_nothing() {
        let g = Geometry::new(64, 48, 16).unwrap();
        assert!(block_mask(&g, &[]).is_empty());
    }

    #[test]
    fn rectangle_masks_exactly_the_blocks_it_covers() {
        let g = Geometry::new(64, 48, 16).unwrap(); // 4×3 blocks
        let m = block_mask(&g, &[rect(16.0, 0.0, 48.0, 16.0)]);
        let expected: Vec<bool> = (0..12).map(|b| b == 1 || b == 2).collect();
        assert_eq!(m, expected);
    }

    #[test]
    fn half_covered_blocks_are_masked_less_than_half_are_not() {
        let g = Geometry::new(64, 16, 16).unwrap();
        // Block 0 half covered (8 of 16 columns), block 1 covered 7 columns.
        let m = block_mask(
            &g,
            &[rect(0.0, 0.0, 8.0, 16.0), rect(16.0, 0.0, 23.0, 16.0)],
        );
        assert_eq!(m, vec![true, false, false, false]);
    }

    #[test]
    fn triangle_and_overlapping_polygons_union() {
        let g = Geometry::new(32, 32, 16).unwrap();
        // Lower-left triangle: block 2 (bottom-left) fully, blocks 0 and 3 half,
        // block 1 (top-right) not at all.
        let tri: Polygon = vec![[0.0, 0.0], [32.0, 32.0], [0.0, 32.0]];
        let m = block_mask(&g, &[tri]);
        assert!(m[2] && !m[1]);
        // Two overlapping rectangles covering the right half count once.
        let m = block_mask(
            &g,
            &[rect(16.0, 0.0, 32.0, 20.0), rect(16.0, 10.0, 32.0, 32.0)],
        );
        assert_eq!(m, vec![false, true, false, true]);
    }

    #[test]
    fn polygon_outside_the_frame_is_clipped() {
        let g = Geometry::new(40, 20, 16).unwrap(); // 3×2, edge blocks 8×16, 16×4, 8×4
        let m = block_mask(&g, &[rect(30.0, -100.0, 1000.0, 1000.0)]);
        assert_eq!(m, vec![false, false, true, false, false, true]);
    }
}
