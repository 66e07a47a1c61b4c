//! People who stop stay present, with or without the detector: clips made from
//! vtest.avi itself — the median of its frames as the empty scene, people cut out
//! of it along their PETS 2009 boxes and pasted back in (as they are, or three
//! times larger with their heads at the frame's top edge, where HOG's window cannot
//! match), walking in, standing perfectly still and walking out at known frames;
//! also a person in view from the first frame (a ghost when they leave), a box
//! left on the floor, and light that steps and ramps on the empty scene. Each clip
//! is replayed through the whole group (`isochron replay --record`) and scored from
//! the events it wrote and from the presence band and cost map of its recording,
//! read by an independent MCAP reader (`tests/presence/band.py`).

use std::path::Path;
use std::sync::OnceLock;
use std::time::Duration;

use isochron_motion::eval::{GroundTruth, PersonBox};
use isochron_tests::{TestSite, read_jsonl, repo_root, venv_python, vtest};
use opencv::core::{Mat, Size, Vec3b};
use opencv::prelude::*;
use opencv::{imgproc, videoio};
use serde_json::Value;

/// Seconds a walk in or out takes.
pub(crate) const WALK_S: f64 = 6.0;
/// Blocks of 16 px over vtest's 768×576 frame.
const GRID_W: usize = 48;
/// Block edge, pixels.
const BLOCK: i32 = 16;
/// The cost from which a cell is busy (`costmap.speed_busy_from_cost`, default).
const BUSY: i64 = 30;

/// A run of PETS09 boxes of one track: a stretch where no other box comes near it.
#[derive(Clone, Copy)]
struct Run {
    track: i64,
    first_frame: u64,
    frames: u64,
}

const RUNS: [Run; 3] = [
    Run {
        track: 10,
        first_frame: 481,
        frames: 60,
    },
    Run {
        track: 2,
        first_frame: 506,
        frames: 60,
    },
    Run {
        track: 17,
        first_frame: 174,
        frames: 60,
    },
];

/// A person cut out of a frame: the pixels inside their box that differ from the
/// empty scene, as (dx, dy, colour), and the box's size.
#[derive(Clone)]
struct Cutout {
    w: i32,
    h: i32,
    pixels: Vec<(i32, i32, Vec3b)>,
}

impl Cutout {
    /// The cut-out `scale` times larger (nearest neighbour: every source pixel
    /// becomes a square).
    fn scaled(&self, scale: i32) -> Cutout {
        let mut pixels = Vec::with_capacity(self.pixels.len() * (scale * scale) as usize);
        for &(x, y, p) in &self.pixels {
            for dy in 0..scale {
                for dx in 0..scale {
                    pixels.push((x * scale + dx, y * scale + dy, p));
                }
            }
        }
        Cutout {
            w: self.w * scale,
            h: self.h * scale,
            pixels,
        }
    }

    fn paste(&self, frame: &mut Mat, x0: i32, y0: i32) {
        for &(dx, dy, p) in &self.pixels {
            let (x, y) = (x0 + dx, y0 + dy);
            if x >= 0 && y >= 0 && x < frame.cols() && y < frame.rows() {
                *frame.at_2d_mut::<Vec3b>(y, x).unwrap() = p;
            }
        }
    }
}

/// The empty scene and the cut-outs of every run with where each box stood.
struct Scene {
    background: Mat,
    runs: Vec<Vec<(Cutout, (i32, i32))>>,
}

/// vtest.avi's frames `keep` selects, BGR, with their indices.
fn vtest_frames(keep: impl Fn(u64) -> bool) -> Vec<(u64, Mat)> {
    let mut cap =
        videoio::VideoCapture::from_file(vtest().to_str().unwrap(), videoio::CAP_ANY).unwrap();
    let (mut out, mut frame, mut n) = (Vec::new(), Mat::default(), 0u64);
    while cap.read(&mut frame).unwrap() && !frame.empty() {
        if keep(n) {
            out.push((n, frame.try_clone().unwrap()));
        }
        n += 1;
    }
    out
}

/// The scene, made once per test process (two passes over vtest.avi).
fn scene() -> &'static Scene {
    static SCENE: OnceLock<Scene> = OnceLock::new();
    SCENE.get_or_init(|| {
        // The per-pixel median of every 16th frame: the scene without the people
        // who walk through it.
        let sample = vtest_frames(|n| n % 16 == 0);
        let planes: Vec<&[u8]> = sample
            .iter()
            .map(|(_, f)| f.data_bytes().unwrap())
            .collect();
        let mut background = sample[0].1.try_clone().unwrap();
        let mut values = vec![0u8; planes.len()];
        for (i, px) in background.data_bytes_mut().unwrap().iter_mut().enumerate() {
            for (v, f) in values.iter_mut().zip(&planes) {
                *v = f[i];
            }
            values.sort_unstable();
            *px = values[values.len() / 2];
        }
        let gt = GroundTruth::parse_mot(
            &std::fs::read_to_string(repo_root().join("tests/data/pets09-s2l1-gt.txt")).unwrap(),
        )
        .unwrap();
        let wanted = |n: u64| {
            RUNS.iter()
                .any(|r| (r.first_frame..r.first_frame + r.frames).contains(&n))
        };
        let frames = vtest_frames(wanted);
        let runs = RUNS
            .iter()
            .map(|r| {
                let cuts: Vec<(Cutout, (i32, i32))> = frames
                    .iter()
                    .filter(|(n, _)| (r.first_frame..r.first_frame + r.frames).contains(n))
                    .filter_map(|(n, f)| {
                        let b = gt.boxes(*n).iter().find(|b| b.id == r.track)?;
                        Some((
                            cut(f, &background, b),
                            (b.left.round() as i32, b.top.round() as i32),
                        ))
                    })
                    .collect();
                assert!(cuts.len() > 10, "track {} has no run of boxes", r.track);
                cuts
            })
            .collect();
        Scene { background, runs }
    })
}

fn cut(frame: &Mat, background: &Mat, b: &PersonBox) -> Cutout {
    let (x0, y0) = (b.left.round() as i32, b.top.round() as i32);
    let (w, h) = (b.width.round() as i32, b.height.round() as i32);
    let mut pixels = Vec::new();
    for dy in 0..h {
        for dx in 0..w {
            let (x, y) = (x0 + dx, y0 + dy);
            if x < 0 || y < 0 || x >= frame.cols() || y >= frame.rows() {
                continue;
            }
            let p = *frame.at_2d::<Vec3b>(y, x).unwrap();
            let q = *background.at_2d::<Vec3b>(y, x).unwrap();
            let diff: i32 = (0..3).map(|c| (p[c] as i32 - q[c] as i32).abs()).sum();
            if diff > 40 {
                pixels.push((dx, dy, p));
            }
        }
    }
    Cutout { w, h, pixels }
}

/// One person of a clip: a run's cut-outs, `scale` times larger, standing with
/// the top-left of their box at `place` (default: the run's middle box) from
/// `stand_from_s` (walking in from the nearer side edge in the `WALK_S` before,
/// or standing there from the first frame with `from_start`) to `stand_until_s`,
/// then walking out.
#[derive(Clone, Copy)]
pub(crate) struct Actor {
    run: usize,
    scale: i32,
    place: Option<(i32, i32)>,
    from_start: bool,
    stand_from_s: f64,
    stand_until_s: f64,
}

impl Actor {
    pub(crate) const fn standing(run: usize, stand_from_s: f64, stand_until_s: f64) -> Actor {
        Actor {
            run,
            scale: 1,
            place: None,
            from_start: false,
            stand_from_s,
            stand_until_s,
        }
    }
}

/// Three people one after the other, standing 45, 40 and 30 s.
const STANDING: [Actor; 3] = [
    Actor::standing(0, 12.0, 57.0),
    Actor::standing(1, 81.0, 121.0),
    Actor::standing(2, 144.0, 174.0),
];

/// A box pushed in from the left edge over 3 s, from `arrive_s`, to stay at
/// `rect` (x, y, w, h).
#[derive(Clone, Copy)]
struct Prop {
    arrive_s: f64,
    rect: PxBox,
}

/// A clip: its length and frame rate, its people, its props, and the light (a
/// gain on every pixel, by time).
pub(crate) struct Clip {
    length_s: f64,
    fps: f64,
    actors: Vec<Actor>,
    props: Vec<Prop>,
    light: fn(f64) -> f64,
}

/// A box in frame pixels: x, y, width, height.
type PxBox = (i32, i32, i32, i32);

/// Where things were in each frame: whether someone was in view, and each actor's
/// box while standing.
pub(crate) struct Truth {
    present: Vec<bool>,
    pub(crate) standing: Vec<Vec<Option<PxBox>>>,
}

impl Clip {
    pub(crate) fn people(length_s: f64, actors: &[Actor]) -> Clip {
        Clip {
            length_s,
            fps: 10.0,
            actors: actors.to_vec(),
            props: Vec::new(),
            light: |_| 1.0,
        }
    }

    /// Writes the clip to `path` (MJPG) and says where things were.
    pub(crate) fn write(&self, path: &Path) -> Truth {
        let scene = scene();
        let bg = &scene.background;
        let (fw, fh) = (bg.cols(), bg.rows());
        let mut writer = videoio::VideoWriter::new(
            path.to_str().unwrap(),
            videoio::VideoWriter::fourcc('M', 'J', 'P', 'G').unwrap(),
            self.fps,
            Size::new(fw, fh),
            true,
        )
        .unwrap();
        assert!(writer.is_opened().unwrap(), "OpenCV cannot write MJPG");
        let runs: Vec<Vec<(Cutout, (i32, i32))>> = self
            .actors
            .iter()
            .map(|a| {
                scene.runs[a.run]
                    .iter()
                    .map(|(c, p)| (c.scaled(a.scale), *p))
                    .collect()
            })
            .collect();
        let n = (self.length_s * self.fps) as usize;
        let mut truth = Truth {
            present: vec![false; n],
            standing: vec![vec![None; self.actors.len()]; n],
        };
        for i in 0..n {
            let t = i as f64 / self.fps;
            let mut frame = bg.try_clone().unwrap();
            for p in &self.props {
                draw_box(&mut frame, p, t);
            }
            for (k, (a, cuts)) in self.actors.iter().zip(&runs).enumerate() {
                let still = &cuts[cuts.len() / 2].0;
                let (px, py) = a.place.unwrap_or(cuts[cuts.len() / 2].1);
                let arrive = if a.from_start {
                    f64::NEG_INFINITY
                } else {
                    a.stand_from_s - WALK_S
                };
                let leave = a.stand_until_s + WALK_S;
                if t < arrive || t >= leave {
                    continue;
                }
                // Walk from the nearer side edge to the place, stand, walk back.
                let side = if px + still.w / 2 < fw / 2 {
                    -still.w
                } else {
                    fw
                };
                let progress = if t < a.stand_from_s {
                    (t - arrive) / WALK_S
                } else if t < a.stand_until_s {
                    1.0
                } else {
                    1.0 - (t - a.stand_until_s) / WALK_S
                };
                let x = side + ((px - side) as f64 * progress).round() as i32;
                let cutout = if progress < 1.0 {
                    &cuts[i % cuts.len()].0 // walking: the track's own steps
                } else {
                    truth.standing[i][k] = Some((x, py, still.w, still.h));
                    still // standing perfectly still
                };
                cutout.paste(&mut frame, x, py);
                truth.present[i] |= x + cutout.w > 0 && x < fw;
            }
            let gain = (self.light)(t);
            if gain != 1.0 {
                for v in frame.data_bytes_mut().unwrap() {
                    *v = (*v as f64 * gain).round().min(255.0) as u8;
                }
            }
            writer.write(&frame).unwrap();
        }
        writer.release().unwrap();
        truth
    }
}

/// A cardboard box: brown, a darker rim and a strip of tape, pushed in from the
/// left edge over 3 s from `arrive_s`.
fn draw_box(frame: &mut Mat, p: &Prop, t: f64) {
    if t < p.arrive_s {
        return;
    }
    let (x, y, w, h) = p.rect;
    let progress = ((t - p.arrive_s) / 3.0).min(1.0);
    let x = -w + ((x + w) as f64 * progress).round() as i32;
    let rect = opencv::core::Rect::new(x, y, w, h);
    let colour = |b, g, r| opencv::core::Scalar::new(b, g, r, 0.0);
    imgproc::rectangle(
        frame,
        rect,
        colour(60.0, 110.0, 160.0),
        -1,
        imgproc::LINE_8,
        0,
    )
    .unwrap();
    imgproc::rectangle(frame, rect, colour(30.0, 60.0, 90.0), 4, imgproc::LINE_8, 0).unwrap();
    let tape = opencv::core::Rect::new(x, y + h / 2 - 5, w, 10);
    imgproc::rectangle(
        frame,
        tape,
        colour(200.0, 200.0, 190.0),
        -1,
        imgproc::LINE_8,
        0,
    )
    .unwrap();
}

/// The camera of the clips: vtest's view as a floor of 1 cm per pixel, a cost
/// map cell per block (cell (i, j) is block column i, row 35 − j).
pub(crate) const CAMERA: &str = r#"[[camera]]
id = "cam01"
source = "replaced-by-replay"
floor_points = [
  { image_px = [0, 0], floor_m = [0, 5.76] },
  { image_px = [768, 0], floor_m = [7.68, 5.76] },
  { image_px = [768, 576], floor_m = [7.68, 0] },
  { image_px = [0, 576], floor_m = [0, 0] },
]

[costmap]
resolution_m = 0.16
width_cells = 48
height_cells = 36
origin_x_m = 0.0
origin_y_m = 0.0
"#;

/// What a replay of a clip produced.
struct Replayed {
    events: Vec<Value>,
    /// Per second of the recording: its time (ns), the present blocks, the cost of
    /// the asked cells.
    seconds: Vec<(i64, Vec<usize>, Vec<i64>)>,
    start_ns: i64,
}

/// Replays `video` on `site`, recording; reads back the events, and the band and
/// the cost at `cells` from the recording.
fn replay_on(site: &TestSite, video: &Path, cells: &[(usize, usize)]) -> Replayed {
    let out = site.path("out");
    let record = site.path("run.mcap");
    let start = "2026-03-02T07:00:00Z";
    let config = site.config_path().display().to_string();
    let done = site.isochron(
        &[
            "replay",
            video.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--config",
            &config,
            "--start",
            start,
            "--record",
            record.to_str().unwrap(),
        ],
        Duration::from_secs(900),
    );
    assert!(
        done.status.success(),
        "replay failed\n{}\n{}",
        done.stdout,
        done.stderr
    );
    let args: Vec<String> = [record.display().to_string(), "cam01".to_string()]
        .into_iter()
        .chain(cells.iter().map(|(i, j)| format!("{i},{j}")))
        .collect();
    let band = std::process::Command::new(venv_python("mcap_protobuf"))
        .arg(repo_root().join("tests/presence/band.py"))
        .args(&args)
        .output()
        .unwrap();
    assert!(
        band.status.success(),
        "band.py: {}",
        String::from_utf8_lossy(&band.stderr)
    );
    let seconds = String::from_utf8_lossy(&band.stdout)
        .lines()
        .map(|l| {
            let v: Value = serde_json::from_str(l).unwrap();
            let list = |k: &str| -> Vec<i64> {
                v[k].as_array()
                    .unwrap()
                    .iter()
                    .map(|x| x.as_i64().unwrap())
                    .collect()
            };
            (
                v["t"].as_i64().unwrap(),
                list("present").into_iter().map(|k| k as usize).collect(),
                list("costs"),
            )
        })
        .collect();
    Replayed {
        events: read_jsonl(&out.join("events.jsonl")),
        seconds,
        start_ns: isochron_config::clock::parse_rfc3339(start).unwrap(),
    }
}

impl Replayed {
    /// The frames of each event (start, end).
    fn spans(&self) -> Vec<(usize, usize)> {
        self.events
            .iter()
            .map(|e| {
                (
                    e["start_frame"].as_u64().unwrap() as usize,
                    e["end_frame"].as_u64().unwrap() as usize,
                )
            })
            .collect()
    }

    /// The second of the clip (0 = its first) that recording second `t` ended.
    fn clip_second(&self, t: i64) -> f64 {
        (t - self.start_ns) as f64 / 1e9
    }

    /// The seconds (clip time of their end) and present blocks of the recording.
    fn band(&self) -> impl Iterator<Item = (f64, &[usize], &[i64])> {
        self.seconds
            .iter()
            .map(|(t, p, c)| (self.clip_second(*t), p.as_slice(), c.as_slice()))
    }
}

/// Scores events against who was there: the share of person-present frames
/// inside an event, the share of event frames with someone present, and the
/// events no one was present for.
fn score(events: &[(usize, usize)], present: &[bool]) -> (f64, f64, usize) {
    let in_event = |f: usize| events.iter().any(|&(a, b)| a <= f && f <= b);
    let present_frames = present.iter().filter(|&&p| p).count();
    let covered = (0..present.len())
        .filter(|&f| present[f] && in_event(f))
        .count();
    let event_frames: Vec<usize> = (0..present.len()).filter(|&f| in_event(f)).collect();
    let precision = event_frames.iter().filter(|&&f| present[f]).count() as f64
        / event_frames.len().max(1) as f64;
    let false_events = events
        .iter()
        .filter(|&&(a, b)| !(a..=b.min(present.len() - 1)).any(|f| present[f]))
        .count();
    (
        covered as f64 / present_frames.max(1) as f64,
        precision,
        false_events,
    )
}

/// The blocks under a box (x, y, w, h) whose centre lies inside it.
fn blocks_under((x, y, w, h): PxBox) -> Vec<usize> {
    let mut out = Vec::new();
    for by in 0..36 {
        for bx in 0..GRID_W as i32 {
            let (cx, cy) = (bx * BLOCK + BLOCK / 2, by * BLOCK + BLOCK / 2);
            if cx >= x && cx < x + w && cy >= y && cy < y + h {
                out.push((by * GRID_W as i32 + bx) as usize);
            }
        }
    }
    out
}

/// The cost map cell of the block under frame point (x, y) (see [`CAMERA`]).
fn cell_at(x: i32, y: i32) -> (usize, usize) {
    ((x / BLOCK) as usize, (35 - y / BLOCK) as usize)
}

/// The seconds of the recording (clip time of their end) that lie wholly inside
/// actor `k`'s stand.
fn stand_seconds(clip: &Clip, k: usize) -> (f64, f64) {
    let a = &clip.actors[k];
    let from = if a.from_start { 0.0 } else { a.stand_from_s };
    (from + 1.0, a.stand_until_s)
}

fn print_events(name: &str, run: &Replayed) {
    println!(
        "{name}: events {:?}",
        run.events
            .iter()
            .map(|e| (
                e["kind"].as_str().unwrap().to_string(),
                e["start_frame"].as_u64().unwrap(),
                e["end_frame"].as_u64().unwrap()
            ))
            .collect::<Vec<_>>()
    );
}

/// The standing clip's actors' feet cells: the block under the middle of their
/// lower body (90 % of the box's height).
fn feet(truth: &Truth, k: usize) -> PxBox {
    truth
        .standing
        .iter()
        .find_map(|s| s[k])
        .expect("the actor stands")
}

#[test]
fn people_who_stand_still_stay_present_with_the_detector_off() {
    let site = TestSite::new(
        "presence-off",
        &format!("{CAMERA}\n[gate.detector]\nenabled = false\n"),
    );
    let video = site.path("standing.avi");
    let clip = Clip::people(190.0, &STANDING);
    let truth = clip.write(&video);
    let boxes: Vec<_> = (0..clip.actors.len()).map(|k| feet(&truth, k)).collect();
    let cells: Vec<(usize, usize)> = boxes
        .iter()
        .map(|&(x, y, w, h)| cell_at(x + w / 2, y + h * 9 / 10))
        .collect();
    let run = replay_on(&site, &video, &cells);
    print_events("standing, detector off", &run);
    let (coverage, precision, false_events) = score(&run.spans(), &truth.present);
    println!(
        "presence (detector off): {:.1} % of person-present frames inside events, event precision {precision:.3}, {} events, {false_events} false",
        coverage * 100.0,
        run.events.len()
    );
    assert!(coverage >= 0.9, "covered {coverage:.3}");
    assert!(precision >= 0.8, "event precision {precision:.3}");
    assert_eq!(false_events, 0, "false events");
    // While each stands: most of the blocks under them present, and the cost map
    // cell under their lower body at least busy, every second.
    for (k, b) in boxes.iter().enumerate() {
        let under = blocks_under(*b);
        let (from, until) = stand_seconds(&clip, k);
        let mut seconds = 0;
        for (t, present, costs) in run.band() {
            if t < from || t > until {
                continue;
            }
            seconds += 1;
            let hit = under.iter().filter(|b| present.contains(b)).count();
            assert!(
                hit * 2 >= under.len(),
                "actor {k} at {t:.0} s: {hit} of {} blocks under them present",
                under.len()
            );
            assert!(
                costs[k] >= BUSY,
                "actor {k} at {t:.0} s: cost {} under them",
                costs[k]
            );
        }
        assert!(
            seconds as f64 >= until - from - 2.0,
            "{seconds} seconds of actor {k}"
        );
    }
}

#[test]
fn people_who_stand_still_stay_present_and_no_event_is_false() {
    let site = TestSite::new("presence", CAMERA);
    let video = site.path("standing.avi");
    let truth = Clip::people(190.0, &STANDING).write(&video);
    let run = replay_on(&site, &video, &[]);
    let detections = read_jsonl(&site.path("out").join("detections.jsonl"));
    print_events("standing, detector on", &run);
    let (coverage, precision, false_events) = score(&run.spans(), &truth.present);
    println!(
        "presence (detector on): {:.1} % inside events, event precision {precision:.3}, {} events, {false_events} false, {} detections",
        coverage * 100.0,
        run.events.len(),
        detections.len()
    );
    assert!(coverage >= 0.9, "covered {coverage:.3}");
    assert!(precision >= 0.8, "event precision {precision:.3}");
    assert_eq!(false_events, 0, "false events");
}

#[test]
fn people_whose_heads_touch_the_frame_edge_stay_present() {
    // Two people four times the size of vtest's, heads at the top edge (about
    // 300 px tall, most of the detector's search crop), standing 16 and 17 s: the
    // default configuration, detector on.
    let tall = |run, x, from, until| Actor {
        scale: 4,
        place: Some((x, 0)),
        ..Actor::standing(run, from, until)
    };
    let clip = Clip::people(70.0, &[tall(0, 100, 10.0, 26.0), tall(2, 450, 38.0, 55.0)]);
    let site = TestSite::new("presence-tall", CAMERA);
    let video = site.path("tall.avi");
    let truth = clip.write(&video);
    let boxes: Vec<_> = (0..2).map(|k| feet(&truth, k)).collect();
    let cells: Vec<(usize, usize)> = boxes
        .iter()
        .map(|&(x, y, w, h)| cell_at(x + w / 2, (y + h * 9 / 10).min(575)))
        .collect();
    let run = replay_on(&site, &video, &cells);
    let detections = read_jsonl(&site.path("out").join("detections.jsonl"));
    print_events("tall people", &run);
    let (coverage, precision, false_events) = score(&run.spans(), &truth.present);
    println!(
        "presence (heads at the edge, {}x{} px people): {:.1} % inside events, event precision {precision:.3}, {false_events} false, {} detections found {} people",
        boxes[0].2,
        boxes[0].3,
        coverage * 100.0,
        detections.len(),
        detections
            .iter()
            .map(|d| d["detections"].as_array().map_or(0, Vec::len))
            .sum::<usize>()
    );
    assert!(coverage >= 0.9, "covered {coverage:.3}");
    assert!(precision >= 0.8, "event precision {precision:.3}");
    assert_eq!(false_events, 0, "false events");
    for k in 0..2 {
        let (from, until) = stand_seconds(&clip, k);
        for (t, _, costs) in run.band() {
            if (from..=until).contains(&t) {
                assert!(
                    costs[k] >= BUSY,
                    "person {k} at {t:.0} s: cost {}",
                    costs[k]
                );
            }
        }
    }
}

#[test]
fn a_ghost_of_someone_there_from_the_first_frame_clears_within_10_s() {
    // Someone stands still from the first frame (learned as background) for 25 s,
    // then walks out: the floor they uncover differs from what was learned.
    let clip = Clip::people(
        60.0,
        &[Actor {
            from_start: true,
            ..Actor::standing(0, 0.0, 25.0)
        }],
    );
    let site = TestSite::new(
        "presence-ghost",
        &format!("{CAMERA}\n[gate.detector]\nenabled = false\n"),
    );
    let video = site.path("ghost.avi");
    let truth = clip.write(&video);
    let place = blocks_under(feet(&truth, 0));
    let run = replay_on(&site, &video, &[]);
    print_events("ghost", &run);
    // The last second any block where they stood is present.
    let last = run
        .band()
        .filter(|(_, p, _)| p.iter().any(|b| place.contains(b)))
        .map(|(t, _, _)| t)
        .fold(f64::NEG_INFINITY, f64::max);
    // They start walking at 25 s and are off their place within ~2 s.
    println!("ghost: their place last present at {last:.0} s (walked off at 25 s)");
    assert!(last <= 25.0 + 10.0, "the ghost stayed until {last:.0} s");
    // Nothing is present once they are gone, and no event outlives them by much.
    let late: Vec<_> = run
        .band()
        .filter(|(t, p, _)| *t > 45.0 && !p.is_empty())
        .map(|(t, p, _)| (t, p.len()))
        .collect();
    assert!(late.is_empty(), "present after they left: {late:?}");
    let gone_frame = ((25.0 + WALK_S + 10.0) * clip.fps) as usize;
    assert!(
        run.spans().iter().all(|&(_, end)| end <= gone_frame),
        "an event lasted past {gone_frame}: {:?}",
        run.spans()
    );
}

#[test]
fn a_box_left_on_the_floor_is_absorbed_after_absorb_s() {
    let absorb_s = 30.0;
    let rect = (300, 380, 120, 90);
    let clip = Clip {
        props: vec![Prop {
            arrive_s: 10.0,
            rect,
        }],
        ..Clip::people(70.0, &[])
    };
    let site = TestSite::new(
        "presence-box",
        &format!(
            "{CAMERA}\n[presence]\nabsorb_s = {absorb_s}\n\n[gate.detector]\nenabled = false\n"
        ),
    );
    let video = site.path("box.avi");
    clip.write(&video);
    let under = blocks_under(rect);
    let run = replay_on(
        &site,
        &video,
        &[cell_at(rect.0 + rect.2 / 2, rect.1 + rect.3 / 2)],
    );
    print_events("box", &run);
    let present_at = |t: f64| {
        run.band()
            .filter(|(s, _, _)| (*s - t).abs() < 0.5)
            .map(|(_, p, _)| under.iter().filter(|b| p.contains(b)).count())
            .next()
            .unwrap_or(0)
    };
    // It stops at 13 s: present (and costly) from then ...
    for t in [15.0, 25.0, 35.0] {
        assert!(
            present_at(t) * 2 >= under.len(),
            "at {t} s only {} of {} blocks under the box present",
            present_at(t),
            under.len()
        );
    }
    // ... until nothing moved there for absorb_s: background within absorb_s + 5 s.
    let absorbed = 13.0 + absorb_s + 5.0;
    for (t, p, _) in run.band() {
        if t >= absorbed {
            assert!(p.is_empty(), "at {t:.0} s still present: {p:?}");
        }
    }
    println!(
        "box: present blocks at 15 s {}, at 40 s {}, at {absorbed} s {}",
        present_at(15.0),
        present_at(40.0),
        present_at(absorbed)
    );
}

#[test]
fn light_that_steps_or_ramps_raises_no_long_event_and_nothing_present() {
    // The empty scene at 2 frames/s: 60 s still, a 30 % step up, 60 s, then a
    // 10-minute ramp back down.
    let light = |t: f64| {
        if t < 60.0 {
            1.0
        } else if t < 120.0 {
            1.3
        } else {
            1.3 - 0.3 * ((t - 120.0) / 600.0).min(1.0)
        }
    };
    let clip = Clip {
        fps: 2.0,
        light,
        ..Clip::people(730.0, &[])
    };
    let site = TestSite::new("presence-light", CAMERA);
    let video = site.path("light.avi");
    clip.write(&video);
    let run = replay_on(&site, &video, &[]);
    print_events("light", &run);
    for e in &run.events {
        let frames = e["end_frame"].as_u64().unwrap() - e["start_frame"].as_u64().unwrap() + 1;
        assert!(
            frames as f64 / clip.fps <= 2.0,
            "an event of {frames} frames: {e}"
        );
    }
    let present: Vec<_> = run
        .band()
        .filter(|(_, p, _)| !p.is_empty())
        .map(|(t, p, _)| (t, p.len()))
        .collect();
    assert!(
        present.is_empty(),
        "present under a light change: {present:?}"
    );
}

#[test]
fn on_vtest_the_band_marks_where_people_are() {
    // PETS09 S2.L1 itself: people walk nearly all the time. Score each second's
    // band (judged on the appearance of the second's first frame) against the
    // MOT15 boxes of that frame.
    let site = TestSite::new("presence-vtest", CAMERA);
    let run = replay_on(&site, &vtest(), &[]);
    let gt = GroundTruth::parse_mot(
        &std::fs::read_to_string(repo_root().join("tests/data/pets09-s2l1-gt.txt")).unwrap(),
    )
    .unwrap();
    let (mut boxes, mut boxes_hit, mut present, mut near) = (0, 0, 0, 0);
    for (t, blocks, _) in run.band() {
        // The second that ended at t: its frames 10(t−1) .. 10t − 1.
        let frame = (t * 10.0).round() as u64 - 10;
        let people: Vec<&PersonBox> = gt.boxes(frame).iter().filter(|b| b.flag == 1).collect();
        let px = |b: &PersonBox| {
            (
                b.left.round() as i32,
                b.top.round() as i32,
                b.width.round() as i32,
                b.height.round() as i32,
            )
        };
        for b in &people {
            boxes += 1;
            boxes_hit += blocks_under(px(b)).iter().any(|k| blocks.contains(k)) as usize;
        }
        // Within a block of a person's box.
        let around: Vec<usize> = people
            .iter()
            .flat_map(|b| {
                let (x, y, w, h) = px(b);
                blocks_under((x - BLOCK, y - BLOCK, w + 2 * BLOCK, h + 2 * BLOCK))
            })
            .collect();
        present += blocks.len();
        near += blocks.iter().filter(|k| around.contains(k)).count();
    }
    let (hit, precise) = (
        boxes_hit as f64 / boxes.max(1) as f64,
        near as f64 / present.max(1) as f64,
    );
    println!(
        "presence on vtest: {:.1} % of {boxes} person boxes have a present block under them; \
         {:.1} % of {present} present blocks lie within a block of a person",
        hit * 100.0,
        precise * 100.0
    );
    assert!(hit >= 0.8, "{hit:.3} of person boxes");
    assert!(
        precise >= 0.65,
        "{precise:.3} of present blocks near people"
    );
}
