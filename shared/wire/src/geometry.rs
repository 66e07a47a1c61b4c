//! Plane geometry shared by masks, zones and floor segments: polygons and the
//! block grid laid over a frame.

/// A point `[x, y]`.
pub type Point = [f64; 2];

/// True if `p` lies inside `polygon` (even-odd rule; points on an edge may go
/// either way).
pub fn point_in_polygon(p: Point, polygon: &[Point]) -> bool {
    let mut inside = false;
    let mut j = polygon.len().wrapping_sub(1);
    for i in 0..polygon.len() {
        let (a, b) = (polygon[i], polygon[j]);
        if (a[1] > p[1]) != (b[1] > p[1]) {
            let x = a[0] + (p[1] - a[1]) / (b[1] - a[1]) * (b[0] - a[0]);
            if p[0] < x {
                inside = !inside;
            }
        }
        j = i;
    }
    inside
}

/// The block grid over a frame: `block_px` squares, partial blocks at the right
/// and bottom edges. This is the one definition of how a frame splits into blocks:
/// `ceil(frame_width / block_px) × ceil(frame_height / block_px)`, row-major. Motion,
/// the cascade, the store, the gate and the costmap all describe their grid with it.
///
/// Displays as `WxH blocks of P px (FWxFH frame)`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BlockGrid {
    /// Frame width, pixels.
    pub frame_width: u32,
    /// Frame height, pixels.
    pub frame_height: u32,
    /// Block edge, pixels.
    pub block_px: u32,
}

impl BlockGrid {
    /// The grid of `block_px` blocks over a `frame_width × frame_height` frame.
    pub const fn new(frame_width: u32, frame_height: u32, block_px: u32) -> BlockGrid {
        BlockGrid {
            frame_width,
            frame_height,
            block_px,
        }
    }

    /// Blocks per row.
    pub fn grid_w(&self) -> u32 {
        self.frame_width.div_ceil(self.block_px)
    }

    /// Block rows.
    pub fn grid_h(&self) -> u32 {
        self.frame_height.div_ceil(self.block_px)
    }

    /// Number of blocks.
    pub fn len(&self) -> usize {
        self.grid_w() as usize * self.grid_h() as usize
    }

    /// True if the grid has no blocks.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Centre of block `index` (row-major) in frame pixels; edge blocks use the
    /// centre of their visible part.
    pub fn center(&self, index: usize) -> Point {
        let (bx, by) = (
            (index % self.grid_w() as usize) as u32,
            (index / self.grid_w() as usize) as u32,
        );
        let x0 = bx * self.block_px;
        let y0 = by * self.block_px;
        let x1 = (x0 + self.block_px).min(self.frame_width);
        let y1 = (y0 + self.block_px).min(self.frame_height);
        [(x0 + x1) as f64 / 2.0, (y0 + y1) as f64 / 2.0]
    }

    /// Row-major indices of the blocks whose centre lies inside `polygon`.
    pub fn blocks_in(&self, polygon: &[Point]) -> Vec<u32> {
        (0..self.len())
            .filter(|&i| point_in_polygon(self.center(i), polygon))
            .map(|i| i as u32)
            .collect()
    }
}

impl std::fmt::Display for BlockGrid {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}x{} blocks of {} px ({}x{} frame)",
            self.grid_w(),
            self.grid_h(),
            self.block_px,
            self.frame_width,
            self.frame_height
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_in_a_concave_polygon() {
        // An L shape.
        let l = [
            [0.0, 0.0],
            [10.0, 0.0],
            [10.0, 4.0],
            [4.0, 4.0],
            [4.0, 10.0],
            [0.0, 10.0],
        ];
        assert!(point_in_polygon([2.0, 8.0], &l));
        assert!(point_in_polygon([8.0, 2.0], &l));
        assert!(!point_in_polygon([8.0, 8.0], &l));
        assert!(!point_in_polygon([-1.0, 2.0], &l));
    }

    #[test]
    fn grid_covers_partial_edge_blocks() {
        let g = BlockGrid {
            frame_width: 100,
            frame_height: 40,
            block_px: 16,
        };
        assert_eq!((g.grid_w(), g.grid_h(), g.len()), (7, 3, 21));
        // Last block of the first row covers x 96..100.
        assert_eq!(g.center(6), [98.0, 8.0]);
        let left_half = [[0.0, 0.0], [50.0, 0.0], [50.0, 40.0], [0.0, 40.0]];
        // Centres at x = 8, 24, 40 are inside; 56 is not.
        assert_eq!(g.blocks_in(&left_half), vec![0, 1, 2, 7, 8, 9, 14, 15, 16]);
        assert_eq!(g.to_string(), "7x3 blocks of 16 px (100x40 frame)");
        assert_eq!(g, BlockGrid::new(100, 40, 16));
    }
}
