//! `[gate]` and `[gate.detector]`: events from short-term activity, and the
//! detector they gate.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::{Invalid, check_positive, check_range};

/// `[gate]`: events from short-term activity, and the detector they gate.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GateConfig {
    /// An event starts when a zone's S1 or S2 sum exceeds the long-term mean plus
    /// this many standard deviations (once the model is warm). Default 3.
    pub k_sigma: f32,
    /// Threshold on a zone's activity sum while the long-term model is cold (fewer
    /// than `cascade.warm_days` days at this t*). Default 0.5.
    pub floor: f32,
    /// Lowest threshold once the model is warm (a quiet night has sigma ≈ 0).
    /// Default 0.2.
    pub min_threshold: f32,
    /// In-place activity counts a block only where its own S1 is at least this
    /// (density): a place with lasting activity. People walking by leave each
    /// block a small, decaying S1 tail that, summed over a zone, would otherwise
    /// look like in-place activity. Default 0.05.
    pub in_place_block_min: f32,
    /// An event ends after its activity stayed below the threshold this long,
    /// seconds. Default 3.
    pub hold_s: f64,
    /// Frames the detector runs on per event (the first when the event starts, then
    /// one per later second). Default 1.
    pub detect_per_event: u32,
    /// Instead: one detection every this many seconds while an event lasts.
    pub detect_every_s: Option<f64>,
    /// While the detector holds a person confirmed in a zone, it runs again on
    /// that zone every this many seconds; the person stays confirmed (and the
    /// zone's events open) until a run no longer finds anyone near them.
    /// Default 5.
    pub recheck_s: f64,
    /// A confirmed person on whose box no block was active (S1 or S2) for this
    /// long, seconds, is no longer confirmed, whatever the re-checks find: a
    /// person who stays shows some motion within minutes, a poster or a
    /// mannequin the detector likes never does. Default 300.
    pub confirm_still_max_s: f64,
    /// Recent frames kept for the detector: the last frame of each of the latest
    /// this many seconds (a detection looks at the last frame of a second). Default 8.
    pub ring_frames: usize,
    /// The detector.
    pub detector: DetectorConfig,
}

impl Default for GateConfig {
    fn default() -> Self {
        GateConfig {
            k_sigma: 3.0,
            floor: 0.5,
            min_threshold: 0.2,
            in_place_block_min: 0.05,
            hold_s: 3.0,
            detect_per_event: 1,
            detect_every_s: None,
            recheck_s: 5.0,
            confirm_still_max_s: 300.0,
            ring_frames: 8,
            detector: DetectorConfig::default(),
        }
    }
}

/// `[gate.detector]`: the people detector. By default the network `cargo xtask
/// setup` installed (SSDLite-MobileNetV2, a TensorFlow SSD, through OpenCV's dnn
/// module), OpenCV's HOG where none is installed; or the model file `model`
/// names (a TensorFlow SSD `.pb` or a YOLO `.onnx`).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DetectorConfig {
    /// Run the detector at all. Default true. `false`: events and presence come
    /// from activity and the presence band alone (no boxes, no confirmed people).
    pub enabled: bool,
    /// Model file, relative to the config file: MoveNet MultiPose in ONNX (a
    /// `.onnx` whose name starts with `movenet`, ONNX Runtime's library beside it
    /// or installed), a TensorFlow Object Detection API SSD frozen graph (`.pb`,
    /// e.g. SSDLite-MobileNetV2) or a YOLOv5/YOLOv8 ONNX export (any other name;
    /// docs/pipeline.md). A file that is missing or cannot
    /// be loaded stops the gate (exit 78). Default: none (the installed network,
    /// see `installed`).
    pub model: Option<PathBuf>,
    /// Without `model`: run the network `cargo xtask setup` installed, in
    /// `detector/` in the directory above the binaries' (`target/` in a
    /// checkout) or `share/isochron/detector/` beside it: MoveNet
    /// (`movenet-multipose.onnx` with `libonnxruntime.so`) if it is there, else
    /// the SSD (`ssdlite-person.pb`), else OpenCV's HOG (the gate logs which
    /// runs). `false`: HOG. Default true.
    pub installed: bool,
    /// Square input size of the ONNX model, pixels. Frames are letterboxed into
    /// it (scaled to fit, aspect kept, padded with grey 114). Default 640.
    pub input_px: u32,
    /// Channels the ONNX model's input has: 3 (the frame as RGB, grey frames
    /// replicated) or 1 (grey). Default 3.
    pub input_channels: u32,
    /// Square input size of a TensorFlow SSD (`model` ending in `.pb`), pixels:
    /// the search region is letterboxed into it. Default 300 (what SSDLite trains at).
    pub ssd_input_px: u32,
    /// Lowest person score a TensorFlow SSD detection is kept at. Default 0.5
    /// (measured on PETS09, docs/benchmarks.md).
    pub ssd_score_threshold: f32,
    /// A TensorFlow SSD searches a region larger than this, pixels, in
    /// overlapping square tiles of this side (people stay large enough in its
    /// input); 0: the region in one piece. Default 288 (measured on PETS09:
    /// people 50×100 px in a 768×576 frame are found at 288, not in one piece).
    pub ssd_tile_px: u32,
    /// Square input side of MoveNet MultiPose (the installed
    /// `movenet-multipose.onnx`, or a `model` whose file name starts with
    /// `movenet`), pixels, a multiple of 32: the search region is letterboxed
    /// into it. Default 256 (what it was trained at).
    pub movenet_input_px: u32,
    /// Lowest person score a MoveNet detection is kept at. Default 0.25, chosen
    /// by a stated rule on the tuning scene (Pose2Sim's `Demo_MultiPerson`) and
    /// PETS09, never on the held-out lab scene: the lowest of 0.15–0.5 with false
    /// alarms on at most 5 % of the tuning scene's empty regions (3 of 65) and
    /// PETS09 precision at least 0.85 (0.970; `cargo xtask bench detector
    /// --sweep`, docs/benchmarks.md).
    pub movenet_score_threshold: f32,
    /// MoveNet searches a region larger than this, pixels, whole and in
    /// overlapping square tiles of this side (as the SSD does); 0: whole only.
    /// Default 288 (chosen on PETS09).
    pub movenet_tile_px: u32,
    /// Lowest score of a kept detection (ONNX: class score; HOG: SVM margin).
    /// Default 0.4 (ONNX) — HOG uses `hog_hit_threshold`.
    pub score_threshold: f32,
    /// Overlap (IoU) above which the weaker of two boxes is suppressed. Default 0.45.
    pub nms_threshold: f32,
    /// HOG: upscale frames by this factor first (its window finds people ≥ ~100 px
    /// tall). Default 1.5 (measured on PETS09, docs/benchmarks.md).
    pub hog_upscale: f64,
    /// HOG: SVM hit threshold. Default 0.
    pub hog_hit_threshold: f64,
    /// HOG: window stride, pixels of the upscaled frame (a multiple of 8, the
    /// cell size). Default 8.
    pub hog_win_stride_px: u32,
    /// HOG: factor between the scales of the image pyramid. Default 1.2
    /// (measured on PETS09: 1.05, OpenCV's default, is 2.5× slower and no better).
    pub hog_scale_step: f64,
    /// HOG: boxes are grouped with OpenCV's `groupRectangles`, keeping groups of
    /// more than this many boxes; 0 keeps every box and suppresses overlaps with
    /// `nms_threshold` instead. Default 2.
    pub hog_group_threshold: u32,
    /// Search only a crop of the frame: around the blocks active in the detected
    /// second and the people confirmed there, `crop_margin_px` more on each side
    /// (the whole frame when nothing is active). Default true.
    pub crop: bool,
    /// Margin around the active blocks of a crop, frame pixels. Default 64.
    pub crop_margin_px: u32,
    /// Detection jobs that may wait for the worker; more are dropped and counted.
    /// Default 2.
    pub queue: usize,
    /// Detections that run at once on the site, all cameras and gate processes
    /// together. Default 1.
    pub concurrent: usize,
    /// Threads OpenCV may use for one detection (it sets them process-wide, for
    /// the gate's OpenCV work). With `concurrent` and `cpu_share` this bounds the
    /// detector's share of the box: at most `concurrent × threads × cpu_share`
    /// cores. Default 1.
    pub threads: u32,
    /// Share of its `threads` cores each of the `concurrent` slots may spend
    /// detecting, 0.01–1: after a detection that cost *d* seconds (the detecting
    /// thread's CPU time with one thread, else the wall-clock time) the slot stays
    /// taken *d* × (1 / `cpu_share` − 1) more, and jobs that cannot get a slot
    /// meanwhile are dropped and counted as busy. Default 1 (back to back).
    pub cpu_share: f64,
    /// How long a job waits for one of the `concurrent` slots before it is dropped
    /// and counted, seconds (a lossless replay waits as long as it takes). The
    /// waiting is on the detector's thread: activity and events never wait.
    /// Cameras whose seconds end together all ask at once; waiting spreads their
    /// jobs over the second instead of always serving the first to ask.
    /// Default 1.
    pub slot_wait_s: f64,
}

impl Default for DetectorConfig {
    fn default() -> Self {
        DetectorConfig {
            enabled: true,
            model: None,
            installed: true,
            input_px: 640,
            input_channels: 3,
            ssd_input_px: 300,
            ssd_score_threshold: 0.5,
            ssd_tile_px: 288,
            movenet_input_px: 256,
            movenet_score_threshold: 0.25,
            movenet_tile_px: 288,
            score_threshold: 0.4,
            nms_threshold: 0.45,
            hog_upscale: 1.5,
            hog_hit_threshold: 0.0,
            hog_win_stride_px: 8,
            hog_scale_step: 1.2,
            hog_group_threshold: 2,
            crop: true,
            crop_margin_px: 64,
            queue: 2,
            concurrent: 1,
            threads: 1,
            cpu_share: 1.0,
            slot_wait_s: 1.0,
        }
    }
}

impl GateConfig {
    /// Checks the `gate.*` keys, then `gate.detector.*`.
    pub(super) fn validate(&self) -> Result<(), Invalid> {
        check_range("gate.k_sigma", self.k_sigma as f64, 0.0, 100.0)?;
        check_positive("gate.floor", self.floor as f64)?;
        check_positive("gate.min_threshold", self.min_threshold as f64)?;
        check_range(
            "gate.in_place_block_min",
            self.in_place_block_min as f64,
            0.0,
            1.0,
        )?;
        check_range("gate.hold_s", self.hold_s, 0.0, 3600.0)?;
        check_range(
            "gate.detect_per_event",
            self.detect_per_event as f64,
            0.0,
            1e6,
        )?;
        if let Some(every) = self.detect_every_s {
            check_positive("gate.detect_every_s", every)?;
        }
        check_range("gate.recheck_s", self.recheck_s, 0.1, 3600.0)?;
        check_range(
            "gate.confirm_still_max_s",
            self.confirm_still_max_s,
            1.0,
            86400.0,
        )?;
        check_range("gate.ring_frames", self.ring_frames as f64, 1.0, 4096.0)?;
        self.detector.validate()
    }
}

impl DetectorConfig {
    /// Checks the `gate.detector.movenet_*` keys.
    fn validate_movenet(&self) -> Result<(), Invalid> {
        if !self.movenet_input_px.is_multiple_of(32)
            || !(64..=1024).contains(&self.movenet_input_px)
        {
            return Err(Invalid::new(
                "gate.detector.movenet_input_px",
                format!(
                    "expected a multiple of 32 from 64 to 1024, found {}",
                    self.movenet_input_px
                ),
            ));
        }
        check_range(
            "gate.detector.movenet_score_threshold",
            self.movenet_score_threshold as f64,
            0.0,
            1.0,
        )?;
        if self.movenet_tile_px != 0 && self.movenet_tile_px < 64 {
            return Err(Invalid::new(
                "gate.detector.movenet_tile_px",
                format!(
                    "expected 0 (no tiles) or at least 64, found {}",
                    self.movenet_tile_px
                ),
            ));
        }
        Ok(())
    }

    /// Checks the `gate.detector.*` keys.
    fn validate(&self) -> Result<(), Invalid> {
        check_range("gate.detector.input_px", self.input_px as f64, 32.0, 4096.0)?;
        check_range(
            "gate.detector.ssd_input_px",
            self.ssd_input_px as f64,
            64.0,
            2048.0,
        )?;
        check_range(
            "gate.detector.ssd_score_threshold",
            self.ssd_score_threshold as f64,
            0.0,
            1.0,
        )?;
        if self.ssd_tile_px != 0 && self.ssd_tile_px < 64 {
            return Err(Invalid::new(
                "gate.detector.ssd_tile_px",
                format!(
                    "expected 0 (no tiles) or at least 64, found {}",
                    self.ssd_tile_px
                ),
            ));
        }
        self.validate_movenet()?;
        if !matches!(self.input_channels, 1 | 3) {
            return Err(Invalid::new(
                "gate.detector.input_channels",
                format!("expected 1 or 3, found {}", self.input_channels),
            ));
        }
        check_range(
            "gate.detector.score_threshold",
            self.score_threshold as f64,
            0.0,
            1.0,
        )?;
        check_range(
            "gate.detector.nms_threshold",
            self.nms_threshold as f64,
            0.0,
            1.0,
        )?;
        check_range("gate.detector.hog_upscale", self.hog_upscale, 0.25, 4.0)?;
        if self.hog_win_stride_px == 0 || !self.hog_win_stride_px.is_multiple_of(8) {
            return Err(Invalid::new(
                "gate.detector.hog_win_stride_px",
                format!(
                    "expected a positive multiple of 8 (the HOG cell), found {}",
                    self.hog_win_stride_px
                ),
            ));
        }
        check_range(
            "gate.detector.hog_scale_step",
            self.hog_scale_step,
            1.01,
            2.0,
        )?;
        check_range(
            "gate.detector.hog_group_threshold",
            self.hog_group_threshold as f64,
            0.0,
            100.0,
        )?;
        check_range(
            "gate.detector.crop_margin_px",
            self.crop_margin_px as f64,
            0.0,
            4096.0,
        )?;
        check_range("gate.detector.queue", self.queue as f64, 1.0, 64.0)?;
        check_range(
            "gate.detector.concurrent",
            self.concurrent as f64,
            1.0,
            64.0,
        )?;
        check_range("gate.detector.threads", self.threads as f64, 1.0, 256.0)?;
        check_range("gate.detector.cpu_share", self.cpu_share, 0.01, 1.0)?;
        check_range("gate.detector.slot_wait_s", self.slot_wait_s, 0.0, 60.0)
    }
}
