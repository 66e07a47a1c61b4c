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
use super::tiling::TiledSearch;

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

    /// People in `crop`, the part `r` of the frame; boxes in frame pixels: the
    /// tiled search ([`TiledSearch`]) with one pass's boxes kept as the network gives
    /// them.
    pub fn detect(&mut self, crop: &Mat, r: Rect) -> opencv::Result<Vec<Detection>> {
        let search = TiledSearch {
            tile_px: self.tile_px,
            nms_threshold: self.nms_threshold,
            merge_single_pass: false,
        };
        search.run(crop, r, |part, at| self.detect_one(part, at))
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

#[cfg(test)]
mod tests {
    use super::*;

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
