//! A TensorFlow Object Detection API SSD (such as SSDLite-MobileNetV2) through
//! OpenCV's dnn: the frozen graph with the text graph [`super::text_graph`] makes
//! of it, its output the `1×1×N×7` rows of OpenCV's `DetectionOutput` layer.

use std::path::Path;

use isochron_wire::Detection;
use opencv::core::{Mat, Rect, Scalar, Size, Vector};
use opencv::dnn;
use opencv::imgproc;
use opencv::prelude::*;

use super::Letterbox;
use super::text_graph::{OUTPUT, TextGraphError, ssd_text_graph};

/// An SSD through OpenCV dnn, and its settings.
pub struct SsdDetector {
    /// The network.
    net: dnn::Net,
    /// Square input size, pixels (the 300 the SSD configurations train at).
    input_px: i32,
    /// Lowest kept person score.
    score_threshold: f32,
    /// The person class id of the network (1: the first after the background).
    person_class: f32,
    /// Side of the square tiles a large region is cut into, pixels (0: never).
    tile_px: u32,
    /// Overlap (IoU) above which the weaker of two boxes of neighbouring tiles goes.
    nms_threshold: f32,
    /// Reused buffers: the scaled crop, the letterboxed input, its colour version.
    buffers: [Mat; 3],
}

impl SsdDetector {
    /// Loads the frozen graph `pb`, making its text graph.
    pub fn load(
        pb: &Path,
        input_px: u32,
        score_threshold: f32,
        tile_px: u32,
        nms_threshold: f32,
    ) -> Result<Self, TextGraphError> {
        let (text, _classes) = ssd_text_graph(pb)?;
        let model = std::fs::read(pb).map_err(TextGraphError::Read)?;
        let net = dnn::read_net_from_tensorflow_buffer(
            &Vector::<u8>::from_slice(&model),
            &Vector::<u8>::from_slice(text.as_bytes()),
        )?;
        Ok(SsdDetector {
            net,
            input_px: input_px as i32,
            score_threshold,
            person_class: 1.0,
            tile_px,
            nms_threshold,
            buffers: Default::default(),
        })
    }

    /// People in `crop`, the part `r` of the frame; boxes in frame pixels. A crop
    /// larger than a tile is searched whole and in overlapping square tiles
    /// (small people stay large enough in the input to be found, large ones are
    /// found whole), each letterboxed into the input; overlapping boxes of the
    /// passes are suppressed (NMS at `nms_threshold`).
    pub fn detect(&mut self, crop: &Mat, r: Rect) -> opencv::Result<Vec<Detection>> {
        let tiles = tiles(r.width, r.height, self.tile_px as i32);
        if tiles.len() == 1 {
            return self.detect_one(crop, r);
        }
        // The whole region too: a person larger than a tile is cut by every tile.
        let mut found = self.detect_one(crop, r)?;
        for t in tiles {
            let part = Mat::roi(crop, t)?;
            let at = Rect::new(r.x + t.x, r.y + t.y, t.width, t.height);
            found.extend(self.detect_one(&part, at)?);
        }
        Ok(merge_passes(found, self.nms_threshold))
    }

    /// People in `crop` (one tile), the part `r` of the frame.
    fn detect_one(
        &mut self,
        crop: &impl opencv::core::ToInputArray,
        r: Rect,
    ) -> opencv::Result<Vec<Detection>> {
        let [scaled, boxed, bgr] = &mut self.buffers;
        let fit = Letterbox::fill(crop, r, self.input_px, scaled, boxed)?;
        imgproc::cvt_color(boxed, bgr, imgproc::COLOR_GRAY2BGR, 0)?;
        // The graph scales 0..255 to -1..1 itself (its `Preprocessor/mul`, `sub`).
        let blob = dnn::blob_from_image(
            &*bgr,
            1.0,
            Size::new(self.input_px, self.input_px),
            Scalar::default(),
            true,
            false,
            opencv::core::CV_32F,
        )?;
        self.net.set_input(&blob, "", 1.0, Scalar::default())?;
        let out = self.net.forward_single(OUTPUT)?;
        let rows = parse_detection_output(&out)?;
        let s = self.input_px as f32;
        let (ox, oy) = (r.x as f32, r.y as f32);
        Ok(rows
            .into_iter()
            .filter(|d| d.class == self.person_class && d.score >= self.score_threshold)
            .map(|d| {
                let (x1, y1) = (
                    (d.x1 * s - fit.pad_x) / fit.scale,
                    (d.y1 * s - fit.pad_y) / fit.scale,
                );
                let (x2, y2) = (
                    (d.x2 * s - fit.pad_x) / fit.scale,
                    (d.y2 * s - fit.pad_y) / fit.scale,
                );
                let clamp = |v: f32, len: i32| v.clamp(0.0, len as f32);
                let (x1, x2) = (clamp(x1, r.width), clamp(x2, r.width));
                let (y1, y2) = (clamp(y1, r.height), clamp(y2, r.height));
                Detection {
                    x: ox + x1,
                    y: oy + y1,
                    w: x2 - x1,
                    h: y2 - y1,
                    score: d.score,
                    class: 0,
                    ..Default::default()
                }
            })
            .filter(|d| d.w > 0.0 && d.h > 0.0)
            .collect())
    }
}

/// One row of a `DetectionOutput`: class, score and the box, normalised to the
/// input (0..1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OutputRow {
    /// Class id (0 is the background).
    pub class: f32,
    /// Score.
    pub score: f32,
    /// Left.
    pub x1: f32,
    /// Top.
    pub y1: f32,
    /// Right.
    pub x2: f32,
    /// Bottom.
    pub y2: f32,
}

/// The rows of a `1×1×N×7` `DetectionOutput` (image, class, score, x1, y1, x2, y2).
pub fn parse_detection_output(out: &Mat) -> opencv::Result<Vec<OutputRow>> {
    let shape: Vec<i32> = out.mat_size().iter().copied().collect();
    if shape.len() != 4 || shape[0] != 1 || shape[1] != 1 || shape[3] != 7 {
        return Err(opencv::Error::new(
            opencv::core::StsBadArg,
            format!("unexpected SSD output shape {shape:?}: expected 1x1xNx7"),
        ));
    }
    Ok(out
        .data_typed::<f32>()?
        .chunks_exact(7)
        .map(|r| OutputRow {
            class: r[1],
            score: r[2],
            x1: r[3],
            y1: r[4],
            x2: r[5],
            y2: r[6],
        })
        .collect())
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

    #[test]
    fn a_detection_output_of_another_shape_is_an_error() {
        let m = Mat::new_nd_with_default(&[1, 1, 3, 6], opencv::core::CV_32F, Scalar::all(0.0))
            .unwrap();
        assert!(parse_detection_output(&m).is_err());
        let mut ok =
            Mat::new_nd_with_default(&[1, 1, 2, 7], opencv::core::CV_32F, Scalar::all(0.0))
                .unwrap();
        ok.data_typed_mut::<f32>().unwrap()[..7]
            .copy_from_slice(&[0.0, 1.0, 0.9, 0.1, 0.2, 0.3, 0.4]);
        let rows = parse_detection_output(&ok).unwrap();
        assert_eq!(rows.len(), 2);
        assert_eq!((rows[0].class, rows[0].score, rows[0].x2), (1.0, 0.9, 0.3));
    }
}
