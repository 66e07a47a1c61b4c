//! The specification's constants and types: the block grid, the thresholds of the
//! motion-pixel test and a block's sums (the definition is in the
//! [`kernel`](super) module documentation).

use isochron_wire::geometry::BlockGrid;

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

/// The block grid of a frame as the kernel uses it: a [`BlockGrid`] (the one
/// definition of how a frame splits into blocks, `ceil(width / block_px) ×
/// ceil(height / block_px)`, row-major, edge blocks may be smaller) that the kernel
/// can work with, with its sizes cached as `usize` for the hot loops.
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
    /// A side longer than a frame header can describe (`u32`).
    #[error("frame {width}x{height} is larger than {} px a side", u32::MAX)]
    TooLarge {
        /// Width.
        width: usize,
        /// Height.
        height: usize,
    },
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
        let (Ok(w), Ok(h)) = (u32::try_from(width), u32::try_from(height)) else {
            return Err(GeometryError::TooLarge { width, height });
        };
        Self::of(BlockGrid::new(w, h, block_px as u32))
    }

    /// The kernel's geometry of `grid`, if the kernel can work with it (non-empty
    /// frame, block edge in `1..=MAX_BLOCK_PX`).
    pub fn of(grid: BlockGrid) -> Result<Self, GeometryError> {
        let (width, height, block_px) = (
            grid.frame_width as usize,
            grid.frame_height as usize,
            grid.block_px as usize,
        );
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
            grid_w: grid.grid_w() as usize,
            grid_h: grid.grid_h() as usize,
        })
    }

    /// The block grid this geometry covers.
    pub fn block_grid(&self) -> BlockGrid {
        BlockGrid::new(self.width as u32, self.height as u32, self.block_px as u32)
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

/// One block's sums over its motion pixels (see the [`kernel`](super) module
/// documentation).
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

#[cfg(test)]
mod tests {
    use super::*;

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
        assert_eq!(g.block_grid(), BlockGrid::new(100, 33, 16));
        assert_eq!(Geometry::of(g.block_grid()), Ok(g));
        assert!(Geometry::of(BlockGrid::new(10, 10, 0)).is_err());
    }
}
