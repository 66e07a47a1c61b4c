//! How the detector bench scores a detector: on PETS09 against its MOT15 boxes,
//! and on a hand-labelled scene (Pose2Sim's `Demo_SinglePerson` or Sports2D's
//! demo, held out, or Pose2Sim's `Demo_MultiPerson`, the tuning scene) searched
//! as the gate searches.

use std::path::Path;
use std::time::{Duration, Instant};

use isochron_config::{DetectorConfig, MotionConfig};
use isochron_gate::detector::{Detector, Region};
use isochron_gate::gate::crop_region;
use isochron_motion::detector::MotionDetector;
use isochron_motion::eval::GroundTruth;
use isochron_wire::BlockMotion;
use isochron_wire::Detection;
use isochron_wire::geometry::BlockGrid;
use opencv::core::Mat;
use opencv::prelude::*;
use opencv::{imgproc, videoio};

use crate::Error;

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

/// Decoded grey frames, their width and height, and the video's frame rate
/// (frames/s, rounded; at least 1).
type Grey = (Vec<Vec<u8>>, u32, u32, usize);

/// Grey frames of `video` at the indices `wanted` (sorted).
fn grey_frames(video: &Path, wanted: &[usize]) -> Result<Grey, Error> {
    let name = video.to_str().ok_or("a UTF-8 path")?;
    let mut cap = videoio::VideoCapture::from_file(name, videoio::CAP_ANY)?;
    if !cap.is_opened()? {
        return Err(format!(
            "{} cannot be opened: run `cargo xtask setup --all` (it fetches the bench's scenes)",
            video.display()
        )
        .into());
    }
    let fps = (cap.get(videoio::CAP_PROP_FPS)?.round() as usize).max(1);
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
    Ok((out, w, h, fps))
}

/// Scores on PETS09: precision, recall, ms per frame.
pub(crate) struct Pets {
    pub(crate) precision: f64,
    pub(crate) recall: f64,
    pub(crate) ms: f64,
}

pub(crate) fn score_pets(detector: &mut Detector, root: &Path, step: usize) -> Result<Pets, Error> {
    let gt = GroundTruth::parse_mot(&std::fs::read_to_string(
        root.join("tests/data/pets09-s2l1-gt.txt"),
    )?)?;
    let wanted: Vec<usize> = (0..795).step_by(step).collect();
    let (frames, w, h, _) = grey_frames(&root.join("data/vtest.avi"), &wanted)?;
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

/// What a labelled box holds.
#[derive(Clone, Copy, PartialEq)]
enum Kind {
    /// A person: a detection should match it.
    Person,
    /// Nobody: a detection there is a false alarm.
    Empty,
    /// Someone too little seen to ask for (far away, mostly out of frame, lost
    /// in glare): a detection matching no person whose centre lies in it counts
    /// neither way, and missing it is no miss (as PETS09's flag 0).
    Ignore,
}

/// One row of the labels: camera, frame (None: every labelled frame), kind, box.
struct Label {
    camera: String,
    frame: Option<usize>,
    kind: Kind,
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
        let kind = match f.get(2) {
            Some(&"person") => Kind::Person,
            Some(&"empty") => Kind::Empty,
            Some(&"ignore") => Kind::Ignore,
            _ => return Err(bad().into()),
        };
        if f.len() != 7 {
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
            kind,
            at: (num(3)?, num(4)?, num(5)?, num(6)?),
        });
    }
    Ok(out)
}

/// Scores on a labelled lab scene.
#[derive(Default)]
pub(crate) struct Scene {
    pub(crate) frames: usize,
    pub(crate) frames_found: usize,
    /// Frames where a detection's centre lies in a labelled person.
    pub(crate) frames_hit: usize,
    pub(crate) people: usize,
    pub(crate) people_found: usize,
    pub(crate) detections: usize,
    pub(crate) false_detections: usize,
    pub(crate) iou_sum: f64,
    pub(crate) empty: usize,
    pub(crate) empty_alarms: usize,
    pub(crate) time: Duration,
    /// Sum over the frames of the share of the frame searched.
    pub(crate) searched: f64,
}

/// The gate's search region for frame `n` of `frames` (`fps` frames/s): around
/// the blocks the motion stage saw active in the second before it, margin 64
/// (`gate.detector.crop_margin_px`), as `gate::crop_region` makes it; the whole
/// frame when nothing moved (frame 0).
fn gate_crop(frames: &[Vec<u8>], n: usize, w: u32, h: u32, fps: usize) -> Result<Region, Error> {
    let config = MotionConfig::default();
    let mut motion = MotionDetector::new(&config, w as usize, h as usize, &[])?;
    let mut blocks = vec![BlockMotion::default(); motion.geometry().blocks()];
    let mut active = std::collections::BTreeSet::new();
    for i in n.saturating_sub(fps).max(1)..=n {
        let t = i as i64 * 1_000_000_000 / fps as i64;
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

/// One labelled frame of a scene, decoded, with the region searched.
struct Frame {
    camera: String,
    n: usize,
    w: u32,
    h: u32,
    pixels: Vec<u8>,
    region: Region,
}

/// A scene's labels and labelled frames, decoded once (and each frame's search
/// region found once) for every detector scored on it.
pub(crate) struct LabScene {
    labels: Vec<Label>,
    frames: Vec<Frame>,
}

/// Loads the scene labelled in `labels` (rows `camera,frame,kind,x,y,w,h`) whose
/// videos are `videos/<camera>.mp4`: every labelled frame (with `quick`, frame 0
/// only), searched around motion as the gate does (`crop`) or whole.
pub(crate) fn load_scene(
    labels: &Path,
    videos: &Path,
    quick: bool,
    crop: bool,
) -> Result<LabScene, Error> {
    let labels = read_labels(labels)?;
    let mut cameras: Vec<&str> = labels.iter().map(|l| l.camera.as_str()).collect();
    cameras.sort_unstable();
    cameras.dedup();
    let mut frames = Vec::new();
    for camera in cameras {
        let mut wanted: Vec<usize> = labels
            .iter()
            .filter(|l| l.camera == camera)
            .filter_map(|l| l.frame)
            .filter(|&f| !quick || f == 0)
            .collect();
        wanted.sort_unstable();
        wanted.dedup();
        let video = videos.join(format!("{camera}.mp4"));
        let last = wanted.last().copied().unwrap_or(0);
        let (mut all, w, h, fps) = grey_frames(&video, &(0..=last).collect::<Vec<_>>())?;
        let mut regions = Vec::new();
        for &n in &wanted {
            regions.push(if crop {
                gate_crop(&all, n, w, h, fps)?
            } else {
                Region::WHOLE
            });
        }
        for (&n, region) in wanted.iter().zip(regions) {
            frames.push(Frame {
                camera: camera.to_string(),
                n,
                w,
                h,
                pixels: std::mem::take(&mut all[n]),
                region,
            });
        }
    }
    Ok(LabScene { labels, frames })
}

/// Scores `detector` on `scene`: each frame in its region, each labelled empty
/// region searched alone. A detection that matches no person but has its centre
/// in an `ignore` box is left out (neither a detection nor a false one).
pub(crate) fn score_scene(detector: &mut Detector, scene: &LabScene) -> Result<Scene, Error> {
    let mut s = Scene::default();
    // Each detection and each alarm printed, to see what a score is made of.
    let show = std::env::var_os("DETECTOR_BENCH_SHOW").is_some();
    for f in &scene.frames {
        let (camera, n, w, h, pixels) = (&f.camera, f.n, f.w, f.h, &f.pixels);
        s.searched += if f.region.is_whole() {
            1.0
        } else {
            (f.region.w * f.region.h) as f64 / (w * h) as f64
        };
        let here = |l: &&Label| l.camera == *camera && l.frame.is_none_or(|f| f == n);
        let boxes = |kind: Kind| -> Vec<Boxed> {
            scene
                .labels
                .iter()
                .filter(here)
                .filter(|l| l.kind == kind)
                .map(|l| l.at)
                .collect()
        };
        let (people, ignored) = (boxes(Kind::Person), boxes(Kind::Ignore));
        let t0 = Instant::now();
        let dets = detector.detect(pixels, w, h, f.region)?;
        s.time += t0.elapsed();
        let inside = |d: &Detection, p: &Boxed| {
            let (cx, cy) = ((d.x + d.w / 2.0) as f64, (d.y + d.h / 2.0) as f64);
            cx >= p.0 && cy >= p.1 && cx <= p.0 + p.2 && cy <= p.1 + p.3
        };
        let m = matches(&dets, &people);
        // The detections that count: those matching a person, and those in no
        // `ignore` box.
        let (dets, m): (Vec<Detection>, Vec<Option<(usize, f64)>>) = dets
            .into_iter()
            .zip(m)
            .filter(|(d, m)| {
                let kept = m.is_some() || !ignored.iter().any(|p| inside(d, p));
                if show && !kept {
                    println!(
                        "{camera} {n}: {:.0},{:.0},{:.0},{:.0} score {:.2} in an ignore box",
                        d.x, d.y, d.w, d.h, d.score
                    );
                }
                kept
            })
            .unzip();
        if show {
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
        s.frames_hit += usize::from(dets.iter().any(|d| people.iter().any(|p| inside(d, p))));
        s.people += people.len();
        s.people_found += m.iter().flatten().count();
        s.detections += dets.len();
        s.false_detections += m.iter().filter(|m| m.is_none()).count();
        s.iou_sum += m.iter().flatten().map(|(_, v)| v).sum::<f64>();
        for e in scene
            .labels
            .iter()
            .filter(here)
            .filter(|l| l.kind == Kind::Empty)
        {
            let (x, y, ew, eh) = e.at;
            let region = Region {
                x: x as u32,
                y: y as u32,
                w: ew as u32,
                h: eh as u32,
            };
            let alarms = detector.detect(pixels, w, h, region)?;
            if show && !alarms.is_empty() {
                let best = alarms.iter().map(|d| d.score).fold(0.0, f32::max);
                println!(
                    "{camera} {n}: empty region {x:.0},{y:.0},{ew:.0},{eh:.0}: {} detections, best score {best:.2}",
                    alarms.len()
                );
            }
            s.empty += 1;
            s.empty_alarms += usize::from(!alarms.is_empty());
        }
    }
    Ok(s)
}

pub(crate) fn ratio(a: usize, b: usize) -> f64 {
    a as f64 / b.max(1) as f64
}

/// `n` of `of` as a table cell: "0.97 29/30".
pub(crate) fn share(n: usize, of: usize) -> String {
    format!("{:.2} {n}/{of}", ratio(n, of))
}
