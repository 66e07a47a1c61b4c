//! Rasterisation: which block of a camera covers each cell of the map grid.
//!
//! A block is a rectangle of the image; the homography maps it to a quadrilateral on
//! the floor (its *footprint*). A cell belongs to the block whose footprint contains
//! the cell's centre — found exactly by mapping the centre back into the image with
//! the inverse homography and reading off the block there, so neighbouring
//! footprints never overlap or leave gaps. Cells behind the camera or beyond the
//! horizon, outside the frame, or in a masked block are not seen by the camera.

use isochron_config::Polygon;
use isochron_wire::geometry::BlockGrid;

use crate::grid::MapGrid;
use crate::homography::Homography;

/// Marks a cell the camera does not see in [`Footprint::cell_block`].
pub const NOT_SEEN: u32 = u32::MAX;

/// The cells of the map grid a camera's blocks cover.
#[derive(Debug, Clone, PartialEq)]
pub struct Footprint {
    /// The block grid it was made for.
    pub blocks: BlockGrid,
    /// Per cell (row-major), the index of the covering block, or [`NOT_SEEN`].
    pub cell_block: Vec<u32>,
    /// Number of cells seen.
    pub seen: usize,
}

impl Footprint {
    /// The footprint of `blocks` seen through `image_to_floor` on `grid`; blocks
    /// whose centre is inside a `masks` polygon (frame pixels) count as not seen.
    pub fn build(
        grid: &MapGrid,
        image_to_floor: &Homography,
        blocks: BlockGrid,
        masks: &[Polygon],
    ) -> Footprint {
        let mut cell_block = vec![NOT_SEEN; grid.len()];
        let mut seen = 0;
        let Some(floor_to_image) = image_to_floor.inverse() else {
            return Footprint {
                blocks,
                cell_block,
                seen,
            };
        };
        let mut masked = vec![false; blocks.len()];
        for mask in masks {
            for b in blocks.blocks_in(mask) {
                masked[b as usize] = true;
            }
        }
        let (fw, fh) = (blocks.frame_width as f64, blocks.frame_height as f64);
        let grid_w = blocks.grid_w();
        for j in 0..grid.height {
            for i in 0..grid.width {
                let Some([u, v]) = floor_to_image.apply(grid.cell_center(i, j)) else {
                    continue;
                };
                if !(u >= 0.0 && v >= 0.0 && u < fw && v < fh) {
                    continue;
                }
                let b = (v as u32 / blocks.block_px) * grid_w + u as u32 / blocks.block_px;
                if masked[b as usize] {
                    continue;
                }
                cell_block[grid.index(i, j)] = b;
                seen += 1;
            }
        }
        Footprint {
            blocks,
            cell_block,
            seen,
        }
    }

    /// The cells covered by block `b`.
    pub fn cells_of(&self, b: u32) -> Vec<usize> {
        self.cell_block
            .iter()
            .enumerate()
            .filter(|(_, cb)| **cb == b)
            .map(|(k, _)| k)
            .collect()
    }
}

/// The floor position of each block's centre (`None` beyond the horizon).
pub fn block_floor_centers(
    image_to_floor: &Homography,
    blocks: &BlockGrid,
) -> Vec<Option<[f64; 2]>> {
    (0..blocks.len())
        .map(|b| image_to_floor.apply(blocks.center(b)))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A floor-to-image mapping with perspective: image = G · floor.
    fn g() -> Homography {
        Homography {
            m: [[80.0, 10.0, 20.0], [0.0, -60.0, 400.0], [0.0, 0.05, 1.0]],
        }
    }

    fn setup() -> (MapGrid, Homography, BlockGrid) {
        let grid = MapGrid {
            origin_x: -1.0,
            origin_y: -1.0,
            yaw: 0.0,
            resolution: 0.1,
            width: 80,
            height: 80,
        };
        let blocks = BlockGrid {
            frame_width: 320,
            frame_height: 240,
            block_px: 16,
        };
        (grid, g().inverse().unwrap(), blocks)
    }

    #[test]
    fn a_block_lands_on_the_cells_that_see_it() {
        let (grid, h, blocks) = setup();
        let fp = Footprint::build(&grid, &h, blocks, &[]);
        let b = 7 * blocks.grid_w() + 10; // block (10, 7): x 160..176, y 112..128
        let cells = fp.cells_of(b);
        assert!(!cells.is_empty());
        // Independently: cells whose centre the floor-to-image mapping G puts inside
        // the block's pixel rectangle.
        let mut expected = Vec::new();
        for j in 0..grid.height {
            for i in 0..grid.width {
                let c = grid.cell_center(i, j);
                let [x, y, w] =
                    [0, 1, 2].map(|r| g().m[r][0] * c[0] + g().m[r][1] * c[1] + g().m[r][2]);
                let (u, v) = (x / w, y / w);
                if (160.0..176.0).contains(&u) && (112.0..128.0).contains(&v) {
                    expected.push(grid.index(i, j));
                }
            }
        }
        assert_eq!(cells, expected);
        // The footprint is on the floor where the block's centre maps.
        let centre = h.apply(blocks.center(b as usize)).unwrap();
        let (ci, cj) = grid.cell_of(centre).unwrap();
        assert!(cells.contains(&grid.index(ci, cj)));
    }

    #[test]
    fn unseen_and_masked_cells_are_not_seen() {
        let (grid, h, blocks) = setup();
        let fp = Footprint::build(&grid, &h, blocks, &[]);
        // Every seen cell maps inside the frame; the grid is larger than the view.
        assert!(fp.seen > 0 && fp.seen < grid.len());
        let mask = vec![[0.0, 0.0], [320.0, 0.0], [320.0, 112.0], [0.0, 112.0]];
        let masked = Footprint::build(&grid, &h, blocks, &[mask]);
        assert!(masked.seen < fp.seen);
        // No masked block (top half of the image) covers any cell.
        assert!(
            masked
                .cell_block
                .iter()
                .all(|&b| b == NOT_SEEN || b >= 7 * blocks.grid_w())
        );
    }
}
