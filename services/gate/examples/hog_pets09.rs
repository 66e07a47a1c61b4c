//! The gate's HOG detector scored on PETS 2009 S2.L1 (`data/vtest.avi` with
//! `tests/data/pets09-s2l1-gt.txt`) at the analysis size (768×576): precision and
//! recall at IoU ≥ 0.5 against the people to consider (MOT flag 1; a detection of
//! a flag-0 person counts neither way), and the time per frame, for a grid of
//! `hog_upscale` × `hog_hit_threshold` settings. Used to choose the defaults.
//!
//! `cargo run -p isochron-gate --example hog_pets09 [-- STEP [upscale,threshold ...]]`
//! (every STEP-th frame, default 10).

use std::path::PathBuf;
use std::time::Instant;

use isochron_gate::detector::Detector;
use isochron_motion::eval::{GroundTruth, PersonBox};
use isochron_shared::config::DetectorConfig;
use isochron_shared::wire::Detection;
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

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let gt = GroundTruth::parse_mot(&std::fs::read_to_string(
        root.join("tests/data/pets09-s2l1-gt.txt"),
    )?)?;
    let mut args = std::env::args().skip(1);
    let step: usize = args.next().and_then(|s| s.parse().ok()).unwrap_or(10);
    let mut grid: Vec<(f64, f64)> = args
        .filter_map(|a| {
            let (u, t) = a.split_once(',')?;
            Some((u.parse().ok()?, t.parse().ok()?))
        })
        .collect();
    if grid.is_empty() {
        for upscale in [1.0, 1.25, 1.5, 1.75] {
            for threshold in [0.0, 0.3] {
                grid.push((upscale, threshold));
            }
        }
    }
    let mut cap = videoio::VideoCapture::from_file(
        root.join("data/vtest.avi").to_str().unwrap(),
        videoio::CAP_ANY,
    )?;
    let (mut bgr, mut gray) = (Mat::default(), Mat::default());
    let mut frames = Vec::new();
    let mut n = 0u64;
    while cap.read(&mut bgr)? && !bgr.empty() {
        if (n as usize).is_multiple_of(step) {
            imgproc::cvt_color(&bgr, &mut gray, imgproc::COLOR_BGR2GRAY, 0)?;
            frames.push((n, gray.data_bytes()?.to_vec()));
        }
        n += 1;
    }
    let (w, h) = (gray.cols() as u32, gray.rows() as u32);
    println!(
        "HOG on {} frames of vtest.avi ({w}x{h}), every {step}th; IoU >= 0.5",
        frames.len()
    );
    println!(
        "{:>8} {:>10} {:>10} {:>8} {:>10} {:>10}",
        "upscale", "threshold", "precision", "recall", "found/all", "ms/frame"
    );
    for (upscale, threshold) in grid {
        let config = DetectorConfig {
            hog_upscale: upscale,
            hog_hit_threshold: threshold,
            ..DetectorConfig::default()
        };
        let mut detector = Detector::from_config(&config, &root)?;
        let (mut tp, mut fp, mut found, mut people) = (0, 0, 0, 0);
        let t0 = Instant::now();
        for (n, pixels) in &frames {
            let dets = detector.detect(pixels, w, h)?;
            let boxes = gt.boxes(*n);
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
        let ms = t0.elapsed().as_secs_f64() * 1e3 / frames.len() as f64;
        println!(
            "{upscale:>8.2} {threshold:>10.2} {:>10.3} {:>8.3} {:>10} {ms:>10.0}",
            tp as f64 / (tp + fp).max(1) as f64,
            found as f64 / people.max(1) as f64,
            format!("{found}/{people}")
        );
    }
    Ok(())
}
