//! Scores the motion stage on PETS 2009 S2.L1 (`data/vtest.avi` with
//! `tests/data/pets09-s2l1-gt.txt`) for a grid of `[motion]` settings: how many
//! moving people a block sees, how quiet blocks far from people stay. Used to choose
//! the `MotionConfig` defaults.
//!
//! `cargo run --release -p isochron-motion --example pets09 [-- diff,gradient,density ...]`

use std::path::PathBuf;

use isochron_config::{MotionBackend, MotionConfig};
use isochron_motion::detector::MotionDetector;
use isochron_motion::eval::{GroundTruth, Score};
use isochron_wire::BlockMotion;
use opencv::core::Mat;
use opencv::prelude::*;
use opencv::{imgproc, videoio};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let gt = GroundTruth::parse_mot(&std::fs::read_to_string(
        root.join("tests/data/pets09-s2l1-gt.txt"),
    )?)?;
    let mut cap = videoio::VideoCapture::from_file(root.join("data/vtest.avi"), videoio::CAP_ANY)?;
    let (mut bgr, mut gray) = (Mat::default(), Mat::default());
    let mut frames = Vec::new();
    while cap.read(&mut bgr)? && !bgr.empty() {
        imgproc::cvt_color(&bgr, &mut gray, imgproc::COLOR_BGR2GRAY, 0)?;
        frames.push(gray.data_bytes()?.to_vec());
    }
    let (w, h) = (gray.cols() as usize, gray.rows() as usize);

    // Settings: `diff,gradient,min_flow,density[,dis]`.
    let mut settings: Vec<MotionConfig> = std::env::args()
        .skip(1)
        .filter_map(|a| {
            let v: Vec<&str> = a.split(',').collect();
            Some(MotionConfig {
                diff_threshold: v.first()?.parse().ok()?,
                gradient_threshold: v.get(1)?.parse().ok()?,
                min_flow_px: v.get(2)?.parse().ok()?,
                density_threshold: v.get(3)?.parse().ok()?,
                backend: if v.get(4) == Some(&"dis") {
                    MotionBackend::Dis
                } else {
                    MotionBackend::MotionFlow
                },
                ..MotionConfig::default()
            })
        })
        .collect();
    if settings.is_empty() {
        for diff_threshold in [10u8, 12, 15, 20] {
            for min_flow_px in [0.0f32, 0.25, 0.5, 0.75, 1.0] {
                for density_threshold in [0.01f32, 0.02, 0.03, 0.05] {
                    settings.push(MotionConfig {
                        diff_threshold,
                        min_flow_px,
                        density_threshold,
                        ..MotionConfig::default()
                    });
                }
            }
        }
    }
    println!(
        "{} frames {w}x{h}, {} boxes\ndiff grad flow density backend  seen%  core%  quiet%  near%  active/frame  illum",
        frames.len(),
        gt.len()
    );
    for config in settings {
        let density = config.density_threshold;
        let mut det = MotionDetector::new(&config, w, h, &[])?;
        let mut blocks = vec![BlockMotion::default(); det.geometry().blocks()];
        let mut score = Score::default();
        let mut illumination = 0;
        for n in 1..frames.len() {
            let r = det.process(
                &frames[n - 1],
                &frames[n],
                n as i64 * 100_000_000,
                &mut blocks,
            )?;
            illumination += (r.flags != 0) as u32;
            score.add(&gt, n as u64, det.geometry(), &blocks, density);
        }
        println!(
            "{:>4} {:>4} {:>4} {density:>7} {:<8} {:>6.2} {:>6.1} {:>7.3} {:>6.1} {:>12.1} {illumination:>6}",
            config.diff_threshold,
            config.gradient_threshold,
            config.min_flow_px,
            if config.backend == MotionBackend::Dis {
                "dis"
            } else {
                "flow"
            },
            100.0 * score.seen_fraction(),
            100.0 * score.core_fraction(),
            100.0 * score.quiet_fraction(),
            100.0 * score.active_near_fraction(),
            score.active_blocks as f64 / score.pairs as f64,
        );
    }
    Ok(())
}
