//! The checks of headers that describe a block grid (motion, activity): the frame
//! size, the block edge and the grid derived from them, within the bounds of this
//! crate; the grid a receiver pins per camera.

use crate::geometry::BlockGrid;
use crate::{
    CameraId, MAX_BLOCK_PX, MAX_BLOCKS, MAX_FRAME_SIDE, MIN_BLOCK_PX, Preamble, Stream, WireError,
};

/// Checks a frame side (`field`) a header carries: 1 to [`MAX_FRAME_SIDE`] pixels.
pub(crate) fn check_side(field: &'static str, px: u32) -> Result<(), WireError> {
    if px == 0 || px > MAX_FRAME_SIDE {
        return Err(WireError::Field {
            field,
            reason: format!("{px} px: expected 1 to {MAX_FRAME_SIDE}"),
        });
    }
    Ok(())
}

/// Checks the block grid a header describes — frame size, block edge, and the
/// grid size derived from them — against the bounds of this crate, with no
/// arithmetic that can overflow: the grid's number of blocks (at most
/// [`MAX_BLOCKS`]).
pub fn check_block_grid(
    [frame_width, frame_height, block_px, grid_w, grid_h]: [u32; 5],
) -> Result<usize, WireError> {
    check_side("frame_width", frame_width)?;
    check_side("frame_height", frame_height)?;
    if !(MIN_BLOCK_PX..=MAX_BLOCK_PX).contains(&block_px) {
        return Err(WireError::Field {
            field: "block_px",
            reason: format!("{block_px}: expected {MIN_BLOCK_PX} to {MAX_BLOCK_PX}"),
        });
    }
    let derived = BlockGrid::new(frame_width, frame_height, block_px);
    let (w, h) = (derived.grid_w(), derived.grid_h());
    if (w, h) != (grid_w, grid_h) {
        return Err(WireError::Size {
            what: "block grid",
            expected: format!("{w}x{h} blocks for {frame_width}x{frame_height} px / {block_px}"),
            found: format!("{grid_w}x{grid_h}"),
        });
    }
    // Both sides are at most MAX_FRAME_SIDE / MIN_BLOCK_PX: the product fits.
    let blocks = w as usize * h as usize;
    if blocks > MAX_BLOCKS {
        return Err(WireError::Size {
            what: "block grid",
            expected: format!(
                "at most {MAX_BLOCKS} blocks (a larger motion.block_px or a smaller camera.width/height)"
            ),
            found: format!("{w}x{h} = {blocks} blocks"),
        });
    }
    Ok(blocks)
}

/// The checks the headers of one `E` per block (motion, activity) share: the
/// preamble, the block grid against the frame size ([`check_block_grid`]), and a
/// payload of one element per block (`what` names it in errors).
pub(crate) fn validate_blocks<E>(
    preamble: &Preamble,
    stream: Stream,
    what: &'static str,
    camera: &CameraId,
    blocks: usize,
    grid: [u32; 5],
) -> Result<(), WireError> {
    preamble.validate::<E>(stream, camera, blocks)?;
    if preamble.is_end_of_stream() {
        return Ok(());
    }
    let expected = check_block_grid(grid)?;
    if expected != blocks {
        return Err(WireError::Size {
            what,
            expected: format!("{expected} blocks"),
            found: format!("{blocks} blocks"),
        });
    }
    Ok(())
}

/// What a receiver knows of a camera's block grid: the one its config gives
/// (`camera.width`/`height` with `motion.block_px`), or else the grid of the first
/// valid sample, pinned for the life of the process. A sample of any other grid
/// is refused ([`KnownGrid::check`]): a forged or foreign sample cannot make the
/// receiver rebuild what it derives from the grid (footprints, buffers).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct KnownGrid {
    grid: Option<BlockGrid>,
    configured: bool,
}

impl KnownGrid {
    /// The grid of a camera whose config gives it (`Some`), or one to be pinned
    /// by its first sample (`None`).
    pub fn new(configured: Option<BlockGrid>) -> KnownGrid {
        KnownGrid {
            grid: configured,
            configured: configured.is_some(),
        }
    }

    /// The grid, once known.
    pub fn grid(&self) -> Option<BlockGrid> {
        self.grid
    }

    /// Checks the grid of a valid sample: `Ok(false)` if it is the known one,
    /// `Ok(true)` if it was unknown and is pinned now (the caller warns, once),
    /// an error naming both grids if it is another.
    pub fn check(&mut self, grid: BlockGrid) -> Result<bool, WireError> {
        match self.grid {
            Some(known) if known == grid => Ok(false),
            Some(known) => Err(WireError::Size {
                what: "block grid",
                expected: if self.configured {
                    format!("{known}, as camera.width/height and motion.block_px give")
                } else {
                    format!(
                        "{known}, pinned by this camera's first sample (set camera.width/height to fix it, restart to pin again)"
                    )
                },
                found: grid.to_string(),
            }),
            None => {
                self.grid = Some(grid);
                Ok(true)
            }
        }
    }
}

/// The grid accessor and checks of a header of one `$element` per block (motion and
/// activity): its frame size, block edge and grid size, checked by [`validate_blocks`].
macro_rules! block_header {
    ($header:ident, $element:ty, $stream:expr, $what:literal) => {
        impl $header {
            /// The block grid the header describes (its frame size and block edge; a
            /// [valid](Self::validate) header's `grid_w`/`grid_h` are derived from
            /// them).
            pub fn block_grid(&self) -> BlockGrid {
                BlockGrid::new(self.frame_width, self.frame_height, self.block_px)
            }

            /// Validates the header against the sample's real payload length (blocks).
            pub fn validate(&self, camera: &CameraId, blocks: usize) -> Result<(), WireError> {
                validate_blocks::<$element>(
                    &self.preamble,
                    $stream,
                    $what,
                    camera,
                    blocks,
                    [
                        self.frame_width,
                        self.frame_height,
                        self.block_px,
                        self.grid_w,
                        self.grid_h,
                    ],
                )
            }
        }
    };
}
pub(crate) use block_header;
