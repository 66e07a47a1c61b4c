//! `--sweep`: the MoveNet score threshold (`gate.detector.movenet_score_threshold`)
//! chosen by a stated rule on the tuning scene (Pose2Sim's `Demo_MultiPerson`) and
//! PETS09, never on a held-out scene (`Demo_SinglePerson`, Sports2D's demo).
//!
//! MoveNet runs at each of [`THRESHOLDS`] on the tuning scene, searched as the
//! gate searches (crops around motion), and on PETS09 (whole frames). The rule
//! ([`pick`]): the lowest threshold whose tuning-scene false alarms are on at
//! most [`MAX_EMPTY_ALARMS`] of the empty regions and whose PETS09 precision is
//! at least [`MIN_PETS_PRECISION`]: the lowest such threshold keeps the most
//! recall.

use std::path::Path;

use isochron_config::DetectorConfig;
use isochron_gate::detector::{Detector, INSTALLED_MOVENET};

use crate::Error;
use crate::score::{LabScene, Pets, Scene, ratio, score_pets, score_scene, share};

/// The thresholds tried.
pub(crate) const THRESHOLDS: [f32; 7] = [0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.5];
/// At most this share of the tuning scene's empty regions may hold a detection.
pub(crate) const MAX_EMPTY_ALARMS: f64 = 0.05;
/// At least this PETS09 precision.
pub(crate) const MIN_PETS_PRECISION: f64 = 0.85;

/// The rule: of `rows` (threshold, PETS09, tuning scene), the lowest threshold
/// with the tuning scene's empty-region false alarms ≤ [`MAX_EMPTY_ALARMS`] and
/// PETS09 precision ≥ [`MIN_PETS_PRECISION`]; None when no threshold passes.
pub(crate) fn pick(rows: &[(f32, Pets, Scene)]) -> Option<f32> {
    rows.iter()
        .filter(|(_, p, s)| {
            ratio(s.empty_alarms, s.empty) <= MAX_EMPTY_ALARMS && p.precision >= MIN_PETS_PRECISION
        })
        .map(|(t, _, _)| *t)
        .min_by(f32::total_cmp)
}

/// Runs the sweep on `tuning` (loaded with the gate's crops) and PETS09 (every
/// `step`th frame), prints a row per threshold, the rule's pick and a JSON line.
pub(crate) fn run_sweep(
    root: &Path,
    tuning: &LabScene,
    quick: bool,
    step: usize,
) -> Result<(), Error> {
    let mut rows = Vec::new();
    for threshold in THRESHOLDS {
        let config = DetectorConfig {
            model: Some(root.join("target/detector").join(INSTALLED_MOVENET)),
            movenet_score_threshold: threshold,
            ..Default::default()
        };
        let mut detector = Detector::from_config(&config, root)?;
        let scene = score_scene(&mut detector, tuning)?;
        let pets = score_pets(&mut detector, root, step)?;
        rows.push((threshold, pets, scene));
    }
    println!(
        "MoveNet score threshold sweep: tuning scene Pose2Sim Demo_MultiPerson hand labels \
         (searched as the gate does), PETS09 every {step}th frame of vtest.avi; IoU >= 0.5"
    );
    println!(
        "{:>9} | {:>12} {:>13} {:>9} {:>12} {:>8} | {:>9} {:>6} {:>8}",
        "threshold",
        "frame recall",
        "person recall",
        "precision",
        "empty alarms",
        "ms/frame",
        "precision",
        "recall",
        "ms/frame"
    );
    for (t, p, s) in &rows {
        println!(
            "{:>9.2} | {:>12} {:>13} {:>9.3} {:>12} {:>8.0} | {:>9.3} {:>6.3} {:>8.0}",
            t,
            share(s.frames_found, s.frames),
            share(s.people_found, s.people),
            1.0 - ratio(s.false_detections, s.detections),
            share(s.empty_alarms, s.empty),
            s.time.as_secs_f64() * 1e3 / s.frames.max(1) as f64,
            p.precision,
            p.recall,
            p.ms
        );
    }
    let chosen = pick(&rows);
    let default = DetectorConfig::default().movenet_score_threshold;
    if quick {
        println!(
            "quick: frame 0 of each camera and every {step}th PETS09 frame, not the measurement"
        );
    }
    match chosen {
        Some(t) => println!(
            "rule (lowest threshold with tuning-scene empty alarms <= {MAX_EMPTY_ALARMS} and \
             PETS09 precision >= {MIN_PETS_PRECISION}): {t}; the default is {default}{}",
            if t == default {
                ""
            } else {
                ": NOT the rule's pick"
            }
        ),
        None => println!("rule: no threshold passes; the default is {default}"),
    }
    let json: Vec<String> = rows
        .iter()
        .map(|(t, p, s)| {
            format!(
                "{{\"threshold\":{t},\"frame_recall\":{:.3},\"person_recall\":{:.3},\"empty_alarms\":{:.3},\"pets_precision\":{:.3},\"pets_recall\":{:.3}}}",
                ratio(s.frames_found, s.frames),
                ratio(s.people_found, s.people),
                ratio(s.empty_alarms, s.empty),
                p.precision,
                p.recall
            )
        })
        .collect();
    println!(
        "{{\"bench\":\"detector\",\"sweep\":[{}],\"pick\":{},\"default\":{default}{}}}",
        json.join(","),
        chosen.map_or("null".to_string(), |t| t.to_string()),
        if quick { ",\"quick\":true" } else { "" }
    );
    Ok(())
}
