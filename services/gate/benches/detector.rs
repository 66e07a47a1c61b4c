//! Detector benchmark: the people detectors the gate can run, scored against
//! labels no detector made, on two real scenes, side by side.
//!
//! * **PETS09** (`data/vtest.avi`, 768×576, outdoor, people 50×100 px, the MOT15
//!   boxes of `tests/data/pets09-s2l1-gt.txt`): precision and recall at IoU ≥ 0.5
//!   against the people to consider (MOT flag 1; a detection of a flag-0 person
//!   counts neither way), every [`PETS_STEP`]th frame, the whole frame searched.
//!   The SSD's settings (`ssd_tile_px`, `ssd_score_threshold`) were chosen on these
//!   frames.
//! * **Pose2Sim** (`target/detector-scenes/pose2sim/cam0N.mp4`, 1088×1920, indoor
//!   lab, a man walking and turning his back, a woman standing at the back; labels
//!   by hand in `tests/data/pose2sim-labels.csv`), measured only, never tuned on:
//!   people-frame recall (a labelled frame where a detection matches a labelled
//!   person at IoU ≥ 0.5), person recall, precision (a detection matching no
//!   person is false), the mean IoU of matched boxes, and false alarms in the
//!   labelled empty regions (each searched as the gate searches a crop).
//!
//! Both detectors run with the default `[gate.detector]` settings: the installed
//! network (`cargo xtask setup` puts it in `target/detector/`) and HOG.
//!
//! Run: `cargo xtask bench detector`. `--quick`: every 200th PETS09 frame and
//! frame 0 of each Pose2Sim camera, a check that the bench runs (`"quick":true`
//! in the JSON line). It says whether the installed network meets the targets:
//! recall at least HOG's at precision ≥ 0.85 on PETS09; on Pose2Sim people-frame
//! recall ≥ 0.80 and false alarms on ≤ 0.05 of the empty regions.
//!
//! `--trial st=S,tp=T[,crop]`: the network alone on Pose2Sim with those settings
//! (`ssd_score_threshold`, `ssd_tile_px`; `crop`: searched as the gate does, else
//! the whole frame), for trying settings.

use std::path::Path;
use std::time::{Duration, Instant};

use isochron_config::{DetectorConfig, MotionConfig};
use isochron_gate::detector::{
    Detector, INSTALLED_MOVENET, INSTALLED_NETWORK, INSTALLED_NETWORKS, Region,
};
use isochron_gate::gate::crop_region;
use isochron_motion::detector::MotionDetector;
use isochron_motion::eval::GroundTruth;
use isochron_tests::repo_root;
use isochron_wire::BlockMotion;
use isochron_wire::Detection;
use isochron_wire::geometry::BlockGrid;
use opencv::core::Mat;
use opencv::prelude::*;
use opencv::{imgproc, videoio};

/// What went wrong, for the bench's exit message.
type Error = Box<dyn std::error::Error>;

/// PETS09 frames scored: every this many.
const PETS_STEP: usize = 20;
/// With `--quick`.
const QUICK_PETS_STEP: usize = 200;

/// A box: left, top, width, height (pixels).
type Boxed = (f64, f64, f64, f64);

fn iou(a: Boxed, b: Boxed) -> f64 {
    let ix = ((a.0 + a.2).min(b.0 + b.2) - a.0.max(b.0)).max(0.0);
    let iy = ((a.1 + a.3).min(b.1 + b.3) - a.1.max(b.1)).max(0.0);
    let inter = ix * iy;
    inter / (a.2 * a.3 + b.2 * b.3 - inter)
}

fn boxed(d: &Detection) -> Boxed {
    (d.x as f64, d.y as f64, d.w as f64, d.h as f64)
}

/// Greedy matching at IoU ≥ 0.5, strongest detection first: for each detection the
/// labelled box it matched (index) and the IoU, or None.
fn matches(dets: &[Detection], labels: &[Boxed]) -> Vec<Option<(usize, f64)>> {
    let mut order: Vec<usize> = (0..dets.len()).collect();
    order.sort_by(|&a, &b| dets[b].score.total_cmp(&dets[a].score));
    let mut used = vec![false; labels.len()];
    let mut out = vec![None; dets.len()];
    for i in order {
        let best = (0..labels.len())
            .filter(|&j| !used[j])
            .map(|j| (j, iou(boxed(&dets[i]), labels[j])))
            .filter(|&(_, v)| v >= 0.5)
            .max_by(|a, b| a.1.total_cmp(&b.1));
        if let Some((j, v)) = best {
            used[j] = true;
            out[i] = Some((j, v));
        }
    }
    out
}

/// Grey frames of `video` at the indices `wanted` (sorted), with their size.
fn grey_frames(video: &Path, wanted: &[usize]) -> Result<(Vec<Vec<u8>>, u32, u32), Error> {
    let name = video.to_str().ok_or("a UTF-8 path")?;
    let mut cap = videoio::VideoCapture::from_file(name, videoio::CAP_ANY)?;
    if !cap.is_opened()? {
        return Err(format!(
            "{} cannot be opened: run `cargo xtask setup` (it fetches the bench's scenes)",
            video.display()
        )
        .into());
    }
    let (mut bgr, mut grey) = (Mat::default(), Mat::default());
    let (mut out, mut w, mut h) = (Vec::new(), 0, 0);
    let mut n = 0;
    while out.len() < wanted.len() && cap.read(&mut bgr)? && !bgr.empty() {
        if wanted.contains(&n) {
            imgproc::cvt_color(&bgr, &mut grey, imgproc::COLOR_BGR2GRAY, 0)?;
            (w, h) = (grey.cols() as u32, grey.rows() as u32);
            out.push(grey.data_bytes()?.to_vec());
        }
        n += 1;
    }
    if out.len() != wanted.len() {
        return Err(format!(
            "{}: only {} of the frames wanted",
            video.display(),
            out.len()
        )
        .into());
    }
    Ok((out, w, h))
}

/// Scores on PETS09: precision, recall, ms per frame.
struct Pets {
    precision: f64,
    recall: f64,
    ms: f64,
}

fn score_pets(detector: &mut Detector, root: &Path, step: usize) -> Result<Pets, Error> {
    let gt = GroundTruth::parse_mot(&std::fs::read_to_string(
        root.join("tests/data/pets09-s2l1-gt.txt"),
    )?)?;
    let wanted: Vec<usize> = (0..795).step_by(step).collect();
    let (frames, w, h) = grey_frames(&root.join("data/vtest.avi"), &wanted)?;
    let (mut tp, mut fp, mut found, mut people) = (0, 0, 0, 0);
    let mut time = Duration::ZERO;
    for (n, pixels) in wanted.iter().zip(&frames) {
        let t0 = Instant::now();
        let dets = detector.detect(pixels, w, h, Region::WHOLE)?;
        time += t0.elapsed();
        let boxes = gt.boxes(*n as u64);
        let labels: Vec<Boxed> = boxes
            .iter()
            .map(|b| (b.left, b.top, b.width, b.height))
            .collect();
        let mut matched = vec![false; boxes.len()];
        for m in matches(&dets, &labels) {
            match m {
                Some((j, _)) => {
                    matched[j] = true;
                    if boxes[j].flag == 1 {
                        tp += 1;
                    }
                }
                None => fp += 1,
            }
        }
        people += boxes.iter().filter(|b| b.flag == 1).count();
        found += boxes
            .iter()
            .zip(&matched)
            .filter(|(b, m)| b.flag == 1 && **m)
            .count();
    }
    Ok(Pets {
        precision: tp as f64 / (tp + fp).max(1) as f64,
        recall: found as f64 / people.max(1) as f64,
        ms: time.as_secs_f64() * 1e3 / frames.len().max(1) as f64,
    })
}

/// One row of the labels: camera, frame (None: every labelled frame), kind, box.
struct Label {
    camera: String,
    frame: Option<usize>,
    person: bool,
    at: Boxed,
}

fn read_labels(path: &Path) -> Result<Vec<Label>, Error> {
    let mut out = Vec::new();
    for (i, line) in std::fs::read_to_string(path)?.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let f: Vec<&str> = line.split(',').collect();
        let bad = || {
            format!(
                "{}:{}: expected camera,frame,kind,x,y,w,h",
                path.display(),
                i + 1
            )
        };
        if f.len() != 7 || !matches!(f[2], "person" | "empty") {
            return Err(bad().into());
        }
        let num = |k: usize| f[k].parse::<f64>().map_err(|_| bad());
        out.push(Label {
            camera: f[0].to_string(),
            frame: if f[1] == "*" {
                None
            } else {
                Some(f[1].parse().map_err(|_| bad())?)
            },
            person: f[2] == "person",
            at: (num(3)?, num(4)?, num(5)?, num(6)?),
        });
    }
    Ok(out)
}

/// Scores on the labelled scene.
#[derive(Default)]
struct Scene {
    frames: usize,
    frames_found: usize,
    /// Frames where a detection's centre lies in a labelled person.
    frames_hit: usize,
    people: usize,
    people_found: usize,
    detections: usize,
    false_detections: usize,
    iou_sum: f64,
    empty: usize,
    empty_alarms: usize,
    time: Duration,
    /// Sum over the frames of the share of the frame searched.
    searched: f64,
}

/// The gate's search region for frame `n` of `frames` (60 frames/s): around the
/// blocks the motion stage saw active in the second before it, margin 64
/// (`gate.detector.crop_margin_px`), as `gate::crop_region` makes it; the whole
/// frame when nothing moved (frame 0).
fn gate_crop(frames: &[Vec<u8>], n: usize, w: u32, h: u32) -> Result<Region, Error> {
    let config = MotionConfig::default();
    let mut motion = MotionDetector::new(&config, w as usize, h as usize, &[])?;
    let mut blocks = vec![BlockMotion::default(); motion.geometry().blocks()];
    let mut active = std::collections::BTreeSet::new();
    for i in n.saturating_sub(60).max(1)..=n {
        let t = i as i64 * 1_000_000_000 / 60;
        motion.process(&frames[i - 1], &frames[i], t, &mut blocks)?;
        for (b, m) in blocks.iter().enumerate() {
            if m.density >= config.density_threshold {
                active.insert(b as u32);
            }
        }
    }
    let active: Vec<u32> = active.into_iter().collect();
    let grid = BlockGrid::new(w, h, config.block_px);
    Ok(crop_region(
        &grid,
        &active,
        &[],
        DetectorConfig::default().crop_margin_px,
    ))
}

fn score_scene(
    detector: &mut Detector,
    root: &Path,
    quick: bool,
    crop: bool,
) -> Result<Scene, Error> {
    let labels = read_labels(&root.join("tests/data/pose2sim-labels.csv"))?;
    let mut cameras: Vec<&str> = labels.iter().map(|l| l.camera.as_str()).collect();
    cameras.sort_unstable();
    cameras.dedup();
    let mut s = Scene::default();
    for camera in cameras {
        let mut wanted: Vec<usize> = labels
            .iter()
            .filter(|l| l.camera == camera)
            .filter_map(|l| l.frame)
            .filter(|&f| !quick || f == 0)
            .collect();
        wanted.sort_unstable();
        wanted.dedup();
        let video = root.join(format!("target/detector-scenes/pose2sim/{camera}.mp4"));
        let last = wanted.last().copied().unwrap_or(0);
        let (all, w, h) = grey_frames(&video, &(0..=last).collect::<Vec<_>>())?;
        for n in &wanted {
            let pixels = &all[*n];
            let region = if crop {
                gate_crop(&all, *n, w, h)?
            } else {
                Region::WHOLE
            };
            if !region.is_whole() {
                s.searched += (region.w * region.h) as f64 / (w * h) as f64;
            } else {
                s.searched += 1.0;
            }
            let here = |l: &&Label| l.camera == camera && l.frame.is_none_or(|f| f == *n);
            let people: Vec<Boxed> = labels
                .iter()
                .filter(here)
                .filter(|l| l.person)
                .map(|l| l.at)
                .collect();
            let t0 = Instant::now();
            let dets = detector.detect(pixels, w, h, region)?;
            s.time += t0.elapsed();
            let m = matches(&dets, &people);
            if std::env::var_os("DETECTOR_BENCH_SHOW").is_some() {
                for (d, m) in dets.iter().zip(&m) {
                    println!(
                        "{camera} {n}: {:.0},{:.0},{:.0},{:.0} score {:.2} {}",
                        d.x,
                        d.y,
                        d.w,
                        d.h,
                        d.score,
                        m.map_or("false".to_string(), |(j, v)| format!(
                            "person {j} IoU {v:.2}"
                        ))
                    );
                }
            }
            s.frames += 1;
            s.frames_found += usize::from(m.iter().any(Option::is_some));
            let inside = |d: &Detection, p: &Boxed| {
                let (cx, cy) = ((d.x + d.w / 2.0) as f64, (d.y + d.h / 2.0) as f64);
                cx >= p.0 && cy >= p.1 && cx <= p.0 + p.2 && cy <= p.1 + p.3
            };
            s.frames_hit += usize::from(dets.iter().any(|d| people.iter().any(|p| inside(d, p))));
            s.people += people.len();
            s.people_found += m.iter().flatten().count();
            s.detections += dets.len();
            s.false_detections += m.iter().filter(|m| m.is_none()).count();
            s.iou_sum += m.iter().flatten().map(|(_, v)| v).sum::<f64>();
            for e in labels.iter().filter(here).filter(|l| !l.person) {
                let (x, y, ew, eh) = e.at;
                let region = Region {
                    x: x as u32,
                    y: y as u32,
                    w: ew as u32,
                    h: eh as u32,
                };
                s.empty += 1;
                s.empty_alarms += usize::from(!detector.detect(pixels, w, h, region)?.is_empty());
            }
        }
    }
    Ok(s)
}

/// `--trial SPEC`: one network alone on the second scene (or on PETS09 with
/// `pets`) with the settings of `SPEC`.
fn run_trial(spec: &str, root: &Path, quick: bool, step: usize) -> Result<(), Error> {
    let movenet = spec.split(',').any(|kv| kv == "net=movenet");
    let file = if movenet {
        INSTALLED_MOVENET
    } else {
        INSTALLED_NETWORK
    };
    let mut config = DetectorConfig {
        model: Some(root.join("target/detector").join(file)),
        ..Default::default()
    };
    for kv in spec.split(',').filter(|s| !s.is_empty()) {
        match kv.split_once('=') {
            _ if kv == "crop" || kv == "pets" => {}
            Some(("net", "movenet" | "ssd")) => {}
            Some(("st", v)) if movenet => config.movenet_score_threshold = v.parse()?,
            Some(("tp", v)) if movenet => config.movenet_tile_px = v.parse()?,
            Some(("ip", v)) if movenet => config.movenet_input_px = v.parse()?,
            Some(("st", v)) => config.ssd_score_threshold = v.parse()?,
            Some(("tp", v)) => config.ssd_tile_px = v.parse()?,
            Some(("threads", v)) => config.threads = v.parse()?,
            _ => return Err(format!("--trial: unknown setting {kv}").into()),
        }
    }
    let mut detector = Detector::from_config(&config, root)?;
    if spec.split(',').any(|kv| kv == "pets") {
        let p = score_pets(&mut detector, root, step)?;
        println!(
            "{spec} PETS09 every {step}th frame: precision {:.3} recall {:.3} {:.0} ms/frame",
            p.precision, p.recall, p.ms
        );
        return Ok(());
    }
    let crop = spec.contains("crop");
    let spec = spec.replace("crop", "");
    let s = score_scene(&mut detector, root, quick, crop)?;
    println!(
        "{spec} crop={crop}: frame recall {}/{} (centre in a person {}) person recall {}/{} false {}/{} mean IoU {:.2} empty alarms {}/{} {:.0} ms/frame, searched {:.2}",
        s.frames_found,
        s.frames,
        s.frames_hit,
        s.people_found,
        s.people,
        s.false_detections,
        s.detections,
        s.iou_sum / s.people_found.max(1) as f64,
        s.empty_alarms,
        s.empty,
        s.time.as_secs_f64() * 1e3 / s.frames.max(1) as f64,
        s.searched / s.frames.max(1) as f64
    );
    Ok(())
}

/// The scores of each detector, one row each.
fn print_table(rows: &[(&str, Pets, Scene)], step: usize) {
    println!(
        "people detectors, default settings; PETS09 every {step}th frame of vtest.avi (tuned on), \
         Pose2Sim Demo_SinglePerson hand labels (measured only); IoU >= 0.5"
    );
    println!(
        "{:<20} | {:>9} {:>6} {:>8} | {:>12} {:>13} {:>9} {:>8} {:>12} {:>8}",
        "detector",
        "precision",
        "recall",
        "ms/frame",
        "frame recall",
        "person recall",
        "precision",
        "mean IoU",
        "empty alarms",
        "ms/frame"
    );
    for (label, p, s) in rows {
        println!(
            "{:<20} | {:>9.3} {:>6.3} {:>8.0} | {:>12} {:>13} {:>9.3} {:>8.2} {:>12} {:>8.0}",
            label,
            p.precision,
            p.recall,
            p.ms,
            format!(
                "{:.2} {}/{}",
                ratio(s.frames_found, s.frames),
                s.frames_found,
                s.frames
            ),
            format!(
                "{:.2} {}/{}",
                ratio(s.people_found, s.people),
                s.people_found,
                s.people
            ),
            1.0 - ratio(s.false_detections, s.detections),
            s.iou_sum / s.people_found.max(1) as f64,
            format!(
                "{:.2} {}/{}",
                ratio(s.empty_alarms, s.empty),
                s.empty_alarms,
                s.empty
            ),
            s.time.as_secs_f64() * 1e3 / s.frames.max(1) as f64
        );
    }
}

fn ratio(a: usize, b: usize) -> f64 {
    a as f64 / b.max(1) as f64
}

fn main() -> Result<(), Error> {
    let quick = std::env::args().any(|a| a == "--quick");
    // The second scene alone, the network alone, its settings as `key=value`
    // pairs (st, tp): for trying settings; the targets are not checked.
    let trial: Option<String> = std::env::args().skip_while(|a| a != "--trial").nth(1);
    let root = repo_root();
    let dir = root.join("target/detector");
    if let Some(missing) = INSTALLED_NETWORKS
        .iter()
        .map(|n| dir.join(n))
        .find(|p| !p.is_file())
    {
        return Err(format!(
            "no installed network ({}): run `cargo xtask setup`",
            missing.display()
        )
        .into());
    }
    let step = if quick { QUICK_PETS_STEP } else { PETS_STEP };
    let mut rows = Vec::new();
    if let Some(spec) = &trial {
        return run_trial(spec, &root, quick, step);
    }
    // The gate's default first (the first installed network it finds).
    for (label, config) in [
        (
            "movenet (default)",
            DetectorConfig {
                model: Some(dir.join(INSTALLED_MOVENET)),
                ..Default::default()
            },
        ),
        (
            "ssdlite",
            DetectorConfig {
                model: Some(dir.join(INSTALLED_NETWORK)),
                ..Default::default()
            },
        ),
        (
            "hog",
            DetectorConfig {
                installed: false,
                ..Default::default()
            },
        ),
    ] {
        let mut detector = Detector::from_config(&config, &root)?;
        let pets = score_pets(&mut detector, &root, step)?;
        let scene = score_scene(&mut detector, &root, quick, true)?;
        rows.push((label, pets, scene));
    }
    print_table(&rows, step);
    let (net, ssd, hog) = (&rows[0], &rows[1], &rows[2]);
    let met_pets = net.1.recall >= hog.1.recall && net.1.precision >= 0.85;
    let frame_recall = ratio(net.2.frames_found, net.2.frames);
    let empty_alarms = ratio(net.2.empty_alarms, net.2.empty);
    let met_scene = frame_recall >= 0.80 && empty_alarms <= 0.05;
    println!(
        "targets: PETS09 recall >= HOG's at precision >= 0.85: {}; Pose2Sim frame recall >= 0.80 \
         with empty alarms <= 0.05: {}",
        if met_pets { "met" } else { "NOT met" },
        if met_scene { "met" } else { "NOT met" }
    );
    println!(
        "{{\"bench\":\"detector\",\"pets_precision\":{:.3},\"pets_recall\":{:.3},\"hog_pets_precision\":{:.3},\"hog_pets_recall\":{:.3},\"scene_frame_recall\":{frame_recall:.3},\"scene_empty_alarms\":{empty_alarms:.3},\"ssd_pets_precision\":{:.3},\"ssd_pets_recall\":{:.3},\"ssd_scene_frame_recall\":{:.3},\"ssd_scene_empty_alarms\":{:.3},\"hog_scene_frame_recall\":{:.3}{}}}",
        net.1.precision,
        net.1.recall,
        hog.1.precision,
        hog.1.recall,
        ssd.1.precision,
        ssd.1.recall,
        ratio(ssd.2.frames_found, ssd.2.frames),
        ratio(ssd.2.empty_alarms, ssd.2.empty),
        ratio(hog.2.frames_found, hog.2.frames),
        if quick { ",\"quick\":true" } else { "" }
    );
    Ok(())
}
