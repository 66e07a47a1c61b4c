//! The gate's HOG detector scored on PETS 2009 S2.L1 (`data/vtest.avi` with
//! `tests/data/pets09-s2l1-gt.txt`) at the analysis size (768×576): precision and
//! recall at IoU ≥ 0.5 against the people to consider (MOT flag 1; a detection of
//! a flag-0 person counts neither way), and the detector's time per frame, for a
//! sweep of the `[gate.detector]` HOG settings. Used to choose the defaults.
//!
//! A crop (`c=MARGIN`) searches, as the gate does, only around the blocks the
//! motion stage (its own kernel, default `[motion]` settings) saw active in the
//! second before the frame, `MARGIN` pixels more on each side
//! (`isochron_gate::gate::crop_region`); people who stand still are outside it
//! unless someone moves near them (the gate adds its confirmed people's boxes).
//!
//! `cargo run -p isochron-gate --example hog_pets09 [-- STEP [SETTINGS ...]]`
//! (every STEP-th frame, default 40). SETTINGS: comma-separated `key=value` over
//! the defaults, e.g. `u=1.5,t=0.3,s=8,k=1.05,g=2,c=64`: u upscale, t hit
//! threshold, s window stride, k scale step, g grouping threshold (0: NMS at
//! `nms_threshold` instead), c crop margin (no `c`: the whole frame). Without
//! SETTINGS, a sweep that changes one setting at a time.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::time::Instant;

use isochron_config::{DetectorConfig, MotionConfig};
use isochron_gate::detector::{Detector, Region};
use isochron_gate::gate::crop_region;
use isochron_motion::detector::MotionDetector;
use isochron_motion::eval::{GroundTruth, PersonBox};
use isochron_wire::geometry::BlockGrid;
use isochron_wire::{BlockMotion, Detection};
use opencv::core::Mat;
use opencv::prelude::*;
use opencv::{imgproc, videoio};

fn iou(d: &Detection, b: &PersonBox) -> f64 {
    let (ax0, ay0, ax1, ay1) = (
        d.x as f64,
        d.y as f64,
        (d.x + d.w) as f64,
        (d.y + d.h) as f64,
    );
    let (bx0, by0, bx1, by1) = (b.left, b.top, b.left + b.width, b.top + b.height);
    let inter = (ax1.min(bx1) - ax0.max(bx0)).max(0.0) * (ay1.min(by1) - ay0.max(by0)).max(0.0);
    inter / ((ax1 - ax0) * (ay1 - ay0) + b.width * b.height - inter)
}

/// One setting of the sweep: the detector and the crop margin (None: whole frame).
#[derive(Clone)]
struct Setting {
    config: DetectorConfig,
    crop: Option<u32>,
}

impl Setting {
    /// Parses `key=value,...` over the defaults.
    fn parse(spec: &str) -> Option<Setting> {
        let mut s = Setting::base();
        for kv in spec.split(',') {
            let (k, v) = kv.split_once('=')?;
            let c = &mut s.config;
            match k {
                "u" => c.hog_upscale = v.parse().ok()?,
                "t" => c.hog_hit_threshold = v.parse().ok()?,
                "s" => c.hog_win_stride_px = v.parse().ok()?,
                "k" => c.hog_scale_step = v.parse().ok()?,
                "g" => c.hog_group_threshold = v.parse().ok()?,
                "c" => s.crop = Some(v.parse().ok()?),
                "m" => c.model = Some(v.into()),
                "st" => c.ssd_score_threshold = v.parse().ok()?,
                "si" => c.ssd_input_px = v.parse().ok()?,
                "tp" => c.ssd_tile_px = v.parse().ok()?,
                _ => return None,
            }
        }
        Some(s)
    }

    /// The detector defaults, on the whole frame.
    fn base() -> Setting {
        Setting {
            config: DetectorConfig::default(),
            crop: None,
        }
    }

    fn label(&self) -> String {
        let c = &self.config;
        if let Some(m) = &c.model {
            return format!(
                "{} st={} si={} tp={} {}",
                m.file_name().unwrap_or_default().to_string_lossy(),
                c.ssd_score_threshold,
                c.ssd_input_px,
                c.ssd_tile_px,
                self.crop
                    .map_or("whole".to_string(), |m| format!("crop={m}"))
            );
        }
        format!(
            "u={} t={} s={} k={} g={} {}",
            c.hog_upscale,
            c.hog_hit_threshold,
            c.hog_win_stride_px,
            c.hog_scale_step,
            c.hog_group_threshold,
            self.crop
                .map_or("whole".to_string(), |m| format!("crop={m}"))
        )
    }
}

/// A sampled frame: its index, pixels, and the blocks active in the second before it.
struct Sample {
    n: u64,
    pixels: Vec<u8>,
    active: Vec<u32>,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let gt = GroundTruth::parse_mot(&std::fs::read_to_string(
        root.join("tests/data/pets09-s2l1-gt.txt"),
    )?)?;
    let mut args = std::env::args().skip(1);
    let step: u64 = args.next().and_then(|s| s.parse().ok()).unwrap_or(40);
    let mut settings: Vec<Setting> = args.filter_map(|a| Setting::parse(&a)).collect();
    if settings.is_empty() {
        settings = default_settings();
    }

    let motion_config = MotionConfig::default();
    let (samples, w, h) = sampled_frames(&root, step, &motion_config)?;
    let grid = BlockGrid::new(w, h, motion_config.block_px);
    println!(
        "HOG on {} frames of vtest.avi ({w}x{h}), every {step}th; IoU >= 0.5",
        samples.len()
    );
    println!(
        "{:<36} {:>9} {:>6} {:>9} {:>8} {:>6}",
        "setting", "precision", "recall", "found/all", "ms/frame", "area"
    );
    for setting in settings {
        let mut detector = Detector::from_config(&setting.config, &root)?;
        let (mut tp, mut fp, mut found, mut people) = (0, 0, 0, 0);
        let mut area = 0.0;
        let mut elapsed = std::time::Duration::ZERO;
        for s in &samples {
            let region = match setting.crop {
                Some(margin) => crop_region(&grid, &s.active, &[], margin),
                None => Region::WHOLE,
            };
            area += if region.is_whole() {
                1.0
            } else {
                (region.w * region.h) as f64 / (w * h) as f64
            };
            let t0 = Instant::now();
            let dets = detector.detect(&s.pixels, w, h, region)?;
            elapsed += t0.elapsed();
            let boxes = gt.boxes(s.n);
            let mut used = vec![false; boxes.len()];
            // Greedy: strongest detections first take their best free box.
            let mut order: Vec<&Detection> = dets.iter().collect();
            order.sort_by(|a, b| b.score.total_cmp(&a.score));
            for d in order {
                let best = (0..boxes.len())
                    .filter(|&i| !used[i])
                    .map(|i| (i, iou(d, &boxes[i])))
                    .filter(|&(_, v)| v >= 0.5)
                    .max_by(|a, b| a.1.total_cmp(&b.1));
                match best {
                    Some((i, _)) => {
                        used[i] = true;
                        if boxes[i].flag == 1 {
                            tp += 1;
                        }
                    }
                    None => fp += 1,
                }
            }
            people += boxes.iter().filter(|b| b.flag == 1).count();
            found += boxes
                .iter()
                .zip(&used)
                .filter(|(b, u)| b.flag == 1 && **u)
                .count();
        }
        let k = samples.len().max(1) as f64;
        println!(
            "{:<36} {:>9.3} {:>6.3} {:>9} {:>8.0} {:>6.2}",
            setting.label(),
            tp as f64 / (tp + fp).max(1) as f64,
            found as f64 / people.max(1) as f64,
            format!("{found}/{people}"),
            elapsed.as_secs_f64() * 1e3 / k,
            area / k
        );
    }
    Ok(())
}

/// The settings compared when none are given: the defaults, then one change at a time.
fn default_settings() -> Vec<Setting> {
    let mut settings = Vec::new();
    let one = |f: &dyn Fn(&mut Setting)| {
        let mut s = Setting::base();
        f(&mut s);
        s
    };
    settings.push(Setting::base());
    for u in [1.0, 1.25, 1.75, 2.0] {
        settings.push(one(&|s| s.config.hog_upscale = u));
    }
    for t in [0.3, 0.6] {
        settings.push(one(&|s| s.config.hog_hit_threshold = t));
    }
    settings.push(one(&|s| s.config.hog_win_stride_px = 16));
    for k in [1.1, 1.2] {
        settings.push(one(&|s| s.config.hog_scale_step = k));
    }
    for g in [0, 1, 3] {
        settings.push(one(&|s| s.config.hog_group_threshold = g));
    }
    for c in [32, 64, 96] {
        settings.push(one(&|s| s.crop = Some(c)));
    }
    settings
}

/// The frames of vtest.avi sampled every `step`th, with the blocks the motion stage
/// saw active in the second before each, and the frames' size.
fn sampled_frames(
    root: &Path,
    step: u64,
    motion_config: &MotionConfig,
) -> Result<(Vec<Sample>, u32, u32), Box<dyn std::error::Error>> {
    let mut cap = videoio::VideoCapture::from_file(
        root.join("data/vtest.avi")
            .to_str()
            .ok_or("a UTF-8 checkout path")?,
        videoio::CAP_ANY,
    )?;
    let fps = cap.get(videoio::CAP_PROP_FPS)?;
    let per_second = if fps > 0.0 { fps.round() as u64 } else { 10 };
    let (mut bgr, mut gray) = (Mat::default(), Mat::default());
    let mut motion = None;
    let mut blocks = Vec::new();
    let mut previous: Vec<u8> = Vec::new();
    let mut active = BTreeSet::new();
    let mut samples = Vec::new();
    let mut n = 0u64;
    while cap.read(&mut bgr)? && !bgr.empty() {
        imgproc::cvt_color(&bgr, &mut gray, imgproc::COLOR_BGR2GRAY, 0)?;
        let pixels = gray.data_bytes()?.to_vec();
        let (w, h) = (gray.cols() as usize, gray.rows() as usize);
        let det = match &mut motion {
            Some(det) => det,
            None => {
                let det = MotionDetector::new(motion_config, w, h, &[])?;
                blocks = vec![BlockMotion::default(); det.geometry().blocks()];
                motion.insert(det)
            }
        };
        // Only the pairs of the second before a sampled frame.
        let next_sample = n.div_ceil(step) * step;
        if n > 0 && next_sample - n < per_second {
            det.process(&previous, &pixels, n as i64 * 100_000_000, &mut blocks)?;
            for (i, b) in blocks.iter().enumerate() {
                if b.density >= motion_config.density_threshold {
                    active.insert(i as u32);
                }
            }
        }
        if n.is_multiple_of(step) {
            samples.push(Sample {
                n,
                pixels: pixels.clone(),
                active: std::mem::take(&mut active).into_iter().collect(),
            });
        }
        previous = pixels;
        n += 1;
    }
    Ok((samples, gray.cols() as u32, gray.rows() as u32))
}
