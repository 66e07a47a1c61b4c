//! The tiled search every detector runs: a region larger than a tile is searched
//! whole and in overlapping square tiles (small people stay large enough in the
//! network's input to be found, large ones are found whole), and the passes are
//! merged into one set of people.

use isochron_wire::Detection;
use opencv::boxed_ref::BoxedRef;
use opencv::core::{Mat, Rect};

/// How a detector searches a region: its tile size and how passes merge.
#[derive(Debug, Clone, Copy)]
pub(crate) struct TiledSearch {
    /// Side of the square tiles a large region is cut into, pixels (0: never).
    pub tile_px: u32,
    /// Overlap (IoU) above which the weaker of two boxes is the same person.
    pub nms_threshold: f32,
    /// Whether one pass (a region within one tile) is merged too: MoveNet's
    /// multipose output repeats a person, the SSD's own NMS does not.
    pub merge_single_pass: bool,
}

impl TiledSearch {
    /// People in `crop`, the part `r` of the frame: `pass` run on the whole and,
    /// when the region is larger than a tile, on each tile, the passes merged.
    pub fn run(
        &self,
        crop: &Mat,
        r: Rect,
        mut pass: impl FnMut(&BoxedRef<Mat>, Rect) -> opencv::Result<Vec<Detection>>,
    ) -> opencv::Result<Vec<Detection>> {
        let tiles = tiles(r.width, r.height, self.tile_px as i32);
        // The whole region too: a person larger than a tile is cut by every tile.
        let whole = Mat::roi(crop, Rect::new(0, 0, r.width, r.height))?;
        let mut found = pass(&whole, r)?;
        if tiles.len() == 1 {
            return Ok(if self.merge_single_pass {
                merge_passes(found, self.nms_threshold)
            } else {
                found
            });
        }
        for t in tiles {
            let part = Mat::roi(crop, t)?;
            let at = Rect::new(r.x + t.x, r.y + t.y, t.width, t.height);
            found.extend(pass(&part, at)?);
        }
        Ok(merge_passes(found, self.nms_threshold))
    }
}

/// The tiles a `width × height` region is searched in besides its whole, relative
/// to it: overlapping squares of side `tile` (at least half the short side, so a
/// large region is not cut into dozens); the whole region alone when it fits in
/// one tile or `tile` is 0. (Squares of the short side as well, tried for people
/// close to the camera, found no more of them in the second scene and cost
/// precision on PETS09.)
pub fn tiles(width: i32, height: i32, tile: i32) -> Vec<Rect> {
    if tile <= 0 || (width <= tile && height <= tile) {
        return vec![Rect::new(0, 0, width, height)];
    }
    let short = width.min(height).max(1);
    level(width, height, tile.max(short / 2).min(short))
}

/// Square tiles of `side` covering a `width × height` region, overlapping by at
/// least a quarter (a person cut by one edge is whole in the next tile).
fn level(width: i32, height: i32, side: i32) -> Vec<Rect> {
    let starts = |len: i32| -> Vec<i32> {
        if len <= side {
            return vec![0];
        }
        let stride = side - side / 4;
        let n = (len - side + stride - 1) / stride + 1;
        (0..n)
            .map(|i| ((len - side) as i64 * i as i64 / (n - 1) as i64) as i32)
            .collect()
    };
    let (w, h) = (side.min(width), side.min(height));
    let mut out = Vec::new();
    for y in starts(height) {
        for x in starts(width) {
            out.push(Rect::new(x, y, w, h));
        }
    }
    out
}

/// Overlap of two detections: intersection over union, and intersection over the
/// smaller one's area.
fn overlap(a: &Detection, b: &Detection) -> (f32, f32) {
    let ix = ((a.x + a.w).min(b.x + b.w) - a.x.max(b.x)).max(0.0);
    let iy = ((a.y + a.h).min(b.y + b.h) - a.y.max(b.y)).max(0.0);
    let inter = ix * iy;
    let (aa, ab) = (a.w * a.h, b.w * b.h);
    (
        inter / (aa + ab - inter).max(f32::MIN_POSITIVE),
        inter / aa.min(ab).max(f32::MIN_POSITIVE),
    )
}

/// How much of the smaller of two boxes lies in the larger for them to be one
/// person: a tile that cuts a person finds a part of them (head and shoulders,
/// upper body) inside the box the whole-region pass or the next tile finds.
const CONTAINED: f32 = 0.6;

/// The detections of the whole region and its tiles as one set of people: the
/// strongest first, a detection that overlaps a kept one (IoU at least
/// `nms_threshold`, or most of the smaller inside the larger) is the same
/// person, and the kept box becomes the larger of the two.
pub(crate) fn merge_passes(mut found: Vec<Detection>, nms_threshold: f32) -> Vec<Detection> {
    found.sort_by(|a, b| b.score.total_cmp(&a.score));
    let mut kept: Vec<Detection> = Vec::new();
    for d in found {
        let same = kept.iter_mut().find(|k| {
            let (iou, inside) = overlap(k, &d);
            iou >= nms_threshold || inside >= CONTAINED
        });
        match same {
            Some(k) => {
                if d.w * d.h > k.w * k.h {
                    (k.x, k.y, k.w, k.h) = (d.x, d.y, d.w, d.h);
                }
            }
            None => kept.push(d),
        }
    }
    kept
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiles_cover_the_region_overlapping() {
        // PETS09 at 288: 3 × 2 tiles, a quarter or more overlap, the edges reached.
        let t = tiles(768, 576, 288);
        assert_eq!(t.len(), 12, "{t:?}");
        assert!(t.iter().all(|r| r.width == 288 && r.height == 288));
        assert_eq!(t.iter().map(|r| r.x + r.width).max(), Some(768));
        assert_eq!(t.iter().map(|r| r.y + r.height).max(), Some(576));
        // Small regions in one piece; tiles off.
        assert_eq!(tiles(200, 280, 288), vec![Rect::new(0, 0, 200, 280)]);
        assert_eq!(tiles(768, 576, 0), vec![Rect::new(0, 0, 768, 576)]);
        // A large frame is not cut into dozens: tiles of half its short side.
        let big = tiles(1088, 1920, 288);
        assert!(big.iter().all(|r| r.width == 544), "{big:?}");
        assert_eq!(big.len(), 15);
    }

    #[test]
    fn passes_merge_a_cut_person_into_the_whole_box() {
        let d = |x, y, w, h, score| Detection {
            x,
            y,
            w,
            h,
            score,
            class: 0,
            ..Default::default()
        };
        let whole = d(100.0, 100.0, 50.0, 120.0, 0.7);
        let upper_half = d(102.0, 100.0, 48.0, 60.0, 0.9);
        let other = d(300.0, 100.0, 50.0, 120.0, 0.6);
        let kept = merge_passes(vec![whole, upper_half, other], 0.45);
        assert_eq!(kept.len(), 2, "{kept:?}");
        // The strongest score, the larger box.
        assert_eq!(kept[0].score, 0.9);
        assert_eq!((kept[0].x, kept[0].h), (100.0, 120.0));
    }
}
