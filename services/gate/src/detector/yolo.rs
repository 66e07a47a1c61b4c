//! A YOLOv5/YOLOv8 ONNX export through OpenCV's dnn: the letterboxed frame in,
//! person candidates out, overlapping ones suppressed.

use isochron_wire::Detection;
use opencv::core::{Mat, Rect, Scalar, Size, Vector};
use opencv::prelude::*;
use opencv::{dnn, imgproc};

use super::Letterbox;

/// A YOLO ONNX model through OpenCV dnn, and its settings.
pub struct OnnxDetector {
    /// The network.
    pub net: dnn::Net,
    /// Square input size.
    pub input_px: i32,
    /// Input channels (1 or 3).
    pub channels: u32,
    /// Lowest kept class score.
    pub score_threshold: f32,
    /// NMS overlap threshold.
    pub nms_threshold: f32,
    /// Reused buffers: the scaled frame, the letterboxed input, its colour version.
    pub buffers: [Mat; 3],
}

impl OnnxDetector {
    /// People in `crop`, the part `r` of the frame; boxes in frame pixels.
    pub(super) fn detect(&mut self, crop: &Mat, r: Rect) -> opencv::Result<Vec<Detection>> {
        let (ox, oy) = (r.x as f32, r.y as f32);
        let [scaled, boxed, bgr] = &mut self.buffers;
        let fit = Letterbox::fill(crop, r, self.input_px, scaled, boxed)?;
        let input = if self.channels == 3 {
            imgproc::cvt_color(boxed, bgr, imgproc::COLOR_GRAY2BGR, 0)?;
            &*bgr
        } else {
            &*boxed
        };
        let blob = dnn::blob_from_image(
            input,
            1.0 / 255.0,
            Size::new(self.input_px, self.input_px),
            Scalar::default(),
            self.channels == 3,
            false,
            opencv::core::CV_32F,
        )?;
        self.net.set_input(&blob, "", 1.0, Scalar::default())?;
        let out = self.net.forward_single("")?;
        let candidates = parse_yolo(&out, self.score_threshold)?;
        let mut found =
            non_max_suppression(candidates, self.score_threshold, self.nms_threshold, &fit)?;
        for d in &mut found {
            d.x += ox;
            d.y += oy;
        }
        Ok(found)
    }
}

/// A person box in model input pixels (centre, size) with its score.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Candidate {
    /// Centre x.
    pub cx: f32,
    /// Centre y.
    pub cy: f32,
    /// Width.
    pub w: f32,
    /// Height.
    pub h: f32,
    /// Person score.
    pub score: f32,
}

/// Reads person candidates from a YOLOv8 (`1×(4+C)×N`) or YOLOv5 (`1×N×(5+C)`)
/// output.
pub fn parse_yolo(out: &Mat, score_threshold: f32) -> opencv::Result<Vec<Candidate>> {
    let dims = out.mat_size();
    let shape: Vec<i32> = dims.iter().copied().collect();
    let data = out.data_typed::<f32>()?;
    let bad = || {
        opencv::Error::new(
            opencv::core::StsBadArg,
            format!("unexpected YOLO output shape {shape:?}: expected 1x(4+C)xN or 1xNx(5+C)"),
        )
    };
    if shape.len() != 3 || shape[0] != 1 {
        return Err(bad());
    }
    let (a, b) = (shape[1] as usize, shape[2] as usize);
    let mut found = Vec::new();
    if a < b {
        // YOLOv8: a = 4 + C rows of b candidates.
        if a < 5 {
            return Err(bad());
        }
        for i in 0..b {
            let score = data[4 * b + i];
            if score >= score_threshold {
                found.push(Candidate {
                    cx: data[i],
                    cy: data[b + i],
                    w: data[2 * b + i],
                    h: data[3 * b + i],
                    score,
                });
            }
        }
    } else {
        // YOLOv5: a candidates of b = 5 + C values.
        if b < 6 {
            return Err(bad());
        }
        for row in data.chunks_exact(b) {
            let score = row[4] * row[5];
            if score >= score_threshold {
                found.push(Candidate {
                    cx: row[0],
                    cy: row[1],
                    w: row[2],
                    h: row[3],
                    score,
                });
            }
        }
    }
    Ok(found)
}

/// Non-maximum suppression, then from input to frame pixels.
pub(super) fn non_max_suppression(
    candidates: Vec<Candidate>,
    score_threshold: f32,
    nms_threshold: f32,
    fit: &Letterbox,
) -> opencv::Result<Vec<Detection>> {
    let boxes: Vector<Rect> = candidates
        .iter()
        .map(|c| {
            Rect::new(
                (c.cx - c.w / 2.0) as i32,
                (c.cy - c.h / 2.0) as i32,
                c.w as i32,
                c.h as i32,
            )
        })
        .collect();
    let scores: Vector<f32> = candidates.iter().map(|c| c.score).collect();
    let mut keep = Vector::<i32>::new();
    dnn::nms_boxes(
        &boxes,
        &scores,
        score_threshold,
        nms_threshold,
        &mut keep,
        1.0,
        0,
    )?;
    Ok(keep
        .iter()
        .map(|i| fit.to_frame(&candidates[i as usize]))
        .collect())
}
