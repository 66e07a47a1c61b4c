//! The people the detector confirmed, and where they and a zone's activity lie on
//! the block grid: the blocks under a box, the block under a point, the region a
//! detection job searches.

use isochron_wire::Detection;
use isochron_wire::geometry::BlockGrid;

use crate::detector::Region;

/// A person the detector confirmed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Person {
    /// The latest box, frame pixels: x, y, w, h.
    pub bbox: [f32; 4],
    /// Capture time of the last frame the detector found them in, UTC ns.
    pub seen_ns: i64,
    /// End of the last second in which a block under their box was active, UTC ns.
    pub active_ns: i64,
}

impl Person {
    /// The centre of their box, frame pixels.
    pub(crate) fn centre(&self) -> (f32, f32) {
        (
            self.bbox[0] + self.bbox[2] / 2.0,
            self.bbox[1] + self.bbox[3] / 2.0,
        )
    }

    /// True if `d` is near enough to be the same person: centres within half
    /// the taller box's height.
    pub(crate) fn near(&self, d: &Detection) -> bool {
        let (cx, cy) = self.centre();
        let (dx, dy) = (d.x + d.w / 2.0 - cx, d.y + d.h / 2.0 - cy);
        let reach = 0.5 * self.bbox[3].max(d.h);
        dx * dx + dy * dy <= reach * reach
    }
}

/// The region to search around `active` blocks and confirmed `people`, `margin`
/// pixels more on each side, clamped to the frame; the whole frame when there
/// is nothing to search around or the crop would cover it all.
pub fn crop_region(grid: &BlockGrid, active: &[u32], people: &[Person], margin: u32) -> Region {
    let (w, px) = (grid.grid_w(), grid.block_px);
    let blocks = active.iter().map(|&i| {
        let (x, y) = ((i % w) * px, (i / w) * px);
        [x, y, x + px, y + px]
    });
    let boxes = people.iter().map(|p| {
        let [x, y, bw, bh] = p.bbox;
        [
            x.max(0.0) as u32,
            y.max(0.0) as u32,
            (x + bw).max(0.0).ceil() as u32,
            (y + bh).max(0.0).ceil() as u32,
        ]
    });
    let Some([x0, y0, x1, y1]) = blocks.chain(boxes).reduce(|a, b| {
        [
            a[0].min(b[0]),
            a[1].min(b[1]),
            a[2].max(b[2]),
            a[3].max(b[3]),
        ]
    }) else {
        return Region::WHOLE;
    };
    let (fw, fh) = (grid.frame_width, grid.frame_height);
    let (x0, y0) = (x0.saturating_sub(margin), y0.saturating_sub(margin));
    let (x1, y1) = (
        x1.saturating_add(margin).min(fw),
        y1.saturating_add(margin).min(fh),
    );
    if x0 >= x1 || y0 >= y1 || (x0 == 0 && y0 == 0 && x1 == fw && y1 == fh) {
        return Region::WHOLE;
    }
    Region {
        x: x0,
        y: y0,
        w: x1 - x0,
        h: y1 - y0,
    }
}

/// The blocks (row-major indices) a frame box `[x, y, w, h]` overlaps.
pub(crate) fn blocks_under(grid: &BlockGrid, bbox: &[f32; 4]) -> impl Iterator<Item = u32> + use<> {
    let (gw, gh, px) = (grid.grid_w(), grid.grid_h(), grid.block_px as f32);
    let [x, y, w, h] = *bbox;
    let col = move |v: f32, n: u32| ((v / px).floor().max(0.0) as u32).min(n);
    let (c0, c1) = (col(x, gw), col((x + w - 0.01).max(x), gw - 1) + 1);
    let (r0, r1) = (col(y, gh), col((y + h - 0.01).max(y), gh - 1) + 1);
    (r0..r1).flat_map(move |r| (c0..c1).map(move |c| r * gw + c))
}

/// The block (row-major index) under the frame point `(x, y)`, if inside.
pub(crate) fn block_at(grid: &BlockGrid, x: f32, y: f32) -> Option<u32> {
    // Feet on the bottom edge belong to the last row.
    let (x, y) = (x.floor(), y.floor().min(grid.frame_height as f32 - 1.0));
    if x < 0.0 || y < 0.0 || x >= grid.frame_width as f32 {
        return None;
    }
    let (bx, by) = (x as u32 / grid.block_px, y as u32 / grid.block_px);
    Some(by * grid.grid_w() + bx)
}

/// True if the box `d` overlaps one of `blocks`.
pub(crate) fn overlaps_blocks(grid: &BlockGrid, blocks: &[u32], d: &Detection) -> bool {
    let (w, px) = (grid.grid_w(), grid.block_px as f32);
    blocks.iter().any(|&i| {
        let (x0, y0) = ((i % w) as f32 * px, (i / w) as f32 * px);
        d.x < x0 + px && d.x + d.w > x0 && d.y < y0 + px && d.y + d.h > y0
    })
}
