//! The whole group through `isochron replay`: every stage as its own process on a
//! real video, checked from the files replay writes.

use std::path::Path;

use isochron_tests::{TestSite, VTEST_FRAMES, mjpg_writer, read_jsonl, repo_root, vtest};
use opencv::core::{Mat, Rect, Scalar, Size};
use opencv::imgproc;
use opencv::prelude::*;
use serde_json::Value;

fn replay(site: &TestSite, video: &Path, out: &str) -> Value {
    let out = site.path(out);
    site.replay_ok(video, &out, "2026-03-02T07:00:00Z");
    serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap()
}

/// Person boxes (flag 1) of the PETS09 ground truth, by 0-based video frame.
fn pets_boxes() -> Vec<Vec<[f32; 4]>> {
    let text = std::fs::read_to_string(repo_root().join("tests/data/pets09-s2l1-gt.txt"))
        .expect("tests/data/pets09-s2l1-gt.txt");
    let mut frames = vec![Vec::new(); VTEST_FRAMES as usize];
    for line in text.lines() {
        let f: Vec<f32> = line.split(',').map(|v| v.trim().parse().unwrap()).collect();
        let frame = f[0] as usize - 1; // gt frames are 1-based
        if f[6] == 1.0 && frame < frames.len() {
            frames[frame].push([f[2], f[3], f[4], f[5]]);
        }
    }
    frames
}

fn iou(a: [f32; 4], b: [f32; 4]) -> f32 {
    let x0 = a[0].max(b[0]);
    let y0 = a[1].max(b[1]);
    let x1 = (a[0] + a[2]).min(b[0] + b[2]);
    let y1 = (a[1] + a[3]).min(b[1] + b[3]);
    let inter = (x1 - x0).max(0.0) * (y1 - y0).max(0.0);
    inter / (a[2] * a[3] + b[2] * b[3] - inter)
}

#[test]
fn vtest_through_all_stages_gates_the_detector_onto_people() {
    let site = TestSite::with_source(
        "pipeline-vtest",
        "[gate]\ndetect_every_s = 2.0\n\n[gate.detector]\nhog_upscale = 1.5",
        "replaced-by-replay",
    );
    let summary = replay(&site, &vtest(), "out");
    let count = |k: &str| summary["counts"][k].as_u64().unwrap();
    assert_eq!(count("frames"), VTEST_FRAMES);
    assert!((794..=795).contains(&count("motion")), "{summary}");
    assert!((79..=80).contains(&count("activity")), "{summary}");
    assert!(
        count("events") >= 1,
        "people walk in every frame: {summary}"
    );

    let detections = read_jsonl(&site.path("out/detections.jsonl"));
    assert_eq!(detections.len() as u64, count("detections"));
    let gate = &summary["gate"];
    assert_eq!(
        gate["frames_seen"].as_u64(),
        Some(VTEST_FRAMES),
        "a lossless replay: the gate's final counters saw every frame: {summary}"
    );
    assert_eq!(
        gate["frames_detected"].as_u64(),
        Some(detections.len() as u64),
        "{summary}"
    );
    let gated = detections.len();
    assert!(
        gated >= 20 && (gated as u64) < VTEST_FRAMES / 10,
        "one detection every 2 s of event: {gated} frames"
    );
    let truth = pets_boxes();
    let (mut found, mut boxes, mut correct, mut reported) = (0, 0, 0, 0);
    for d in &detections {
        let frame = d["frame"].as_u64().unwrap() as usize;
        let people: Vec<[f32; 4]> = d["detections"]
            .as_array()
            .unwrap()
            .iter()
            .map(|b| {
                let f = |k: &str| b[k].as_f64().unwrap() as f32;
                [f("x"), f("y"), f("w"), f("h")]
            })
            .collect();
        boxes += truth[frame].len();
        found += truth[frame]
            .iter()
            .filter(|t| people.iter().any(|p| iou(**t, *p) >= 0.3))
            .count();
        reported += people.len();
        correct += people
            .iter()
            .filter(|p| truth[frame].iter().any(|t| iou(*t, **p) >= 0.3))
            .count();
    }
    let recall = found as f64 / boxes.max(1) as f64;
    let precision = correct as f64 / reported.max(1) as f64;
    println!(
        "the default detector on {gated} gated frames: found {found} of {boxes} PETS09 people (hit rate {:.0} %), {correct} of {reported} detections are people ({:.0} %)",
        recall * 100.0,
        precision * 100.0
    );
    assert!(recall >= 0.6, "hit rate {recall:.2}");
    assert!(precision >= 0.5, "precision {precision:.2}");

    // Every detection names its model: the installed default, MoveNet, with 17
    // keypoints. On the people MOT15 boxed, the keypoints MoveNet is sure of lie
    // where bodies are: ankles in the lowest quarter of the labelled box, the
    // nose or eyes in its top quarter.
    let mut feet_ok = (0, 0);
    let mut head_ok = (0, 0);
    for d in &detections {
        let frame = d["frame"].as_u64().unwrap() as usize;
        for b in d["detections"].as_array().unwrap() {
            assert_eq!(b["model"], "movenet", "{b}");
            let f = |k: &str| b[k].as_f64().unwrap() as f32;
            let p = [f("x"), f("y"), f("w"), f("h")];
            let Some(t) = truth[frame].iter().find(|t| iou(**t, p) >= 0.5) else {
                continue;
            };
            let kps = b["keypoints"].as_array().expect("MoveNet keypoints");
            assert_eq!(kps.len(), 17, "{b}");
            let sure = |k: usize| {
                let v = kps[k].as_array().unwrap();
                let (y, score) = (v[1].as_f64().unwrap() as f32, v[2].as_f64().unwrap());
                (score >= 0.3).then_some((y - t[1]) / t[3])
            };
            let tally = |k: usize, range: std::ops::Range<f32>, into: &mut (usize, usize)| {
                if let Some(at) = sure(k) {
                    into.1 += 1;
                    into.0 += usize::from(range.contains(&at));
                }
            };
            tally(15, 0.75..1.1, &mut feet_ok);
            tally(16, 0.75..1.1, &mut feet_ok);
            tally(0, -0.1..0.25, &mut head_ok);
        }
    }
    let share = |(ok, n): (usize, usize)| ok as f64 / n.max(1) as f64;
    println!(
        "MoveNet keypoints on matched PETS09 people: ankles in the box's lowest quarter {}/{}, nose in its top quarter {}/{}",
        feet_ok.0, feet_ok.1, head_ok.0, head_ok.1
    );
    assert!(
        feet_ok.1 >= 10 && share(feet_ok) >= 0.8,
        "ankles {feet_ok:?}"
    );
    assert!(head_ok.1 >= 5 && share(head_ok) >= 0.8, "noses {head_ok:?}");
}

/// Frames per second of the synthetic video.
const FPS: f64 = 10.0;
/// When the object is in view: (start s, end s).
const INTERVALS: [(f64, f64); 3] = [(15.3, 25.3), (50.6, 56.6), (80.2, 95.2)];
const LENGTH_S: f64 = 110.0;

/// An empty textured scene, 320×240 at [`FPS`] for `length_s`, with a textured
/// object walking through it during `intervals` (start s, end s), written as MJPG.
pub(crate) fn write_empty_scene_video(path: &Path, length_s: f64, intervals: &[(f64, f64)]) {
    let (w, h) = (320, 240);
    let mut writer = mjpg_writer(path, FPS, Size::new(w, h));
    // Background: smooth noise, so edges exist everywhere but nothing moves.
    let mut noise =
        Mat::new_rows_cols_with_default(h, w, opencv::core::CV_8UC3, Scalar::all(0.0)).unwrap();
    opencv::core::randu(&mut noise, &Scalar::all(60.0), &Scalar::all(200.0)).unwrap();
    let mut background = Mat::default();
    imgproc::gaussian_blur(
        &noise,
        &mut background,
        Size::new(5, 5),
        1.5,
        1.5,
        opencv::core::BORDER_DEFAULT,
    )
    .unwrap();
    // The object: a 24×56 striped figure.
    let frames = (length_s * FPS) as i32;
    for i in 0..frames {
        let t = i as f64 / FPS;
        let mut frame = background.clone();
        if let Some((start, end)) = intervals.iter().find(|(s, e)| t >= *s && t < *e) {
            let progress = (t - start) / (end - start);
            let x = (10.0 + progress * (w as f64 - 44.0)) as i32;
            let y = 90 + ((t * 3.0).sin() * 20.0) as i32;
            for stripe in 0..7 {
                let shade = if stripe % 2 == 0 { 20.0 } else { 235.0 };
                imgproc::rectangle(
                    &mut frame,
                    Rect::new(x, y + stripe * 8, 24, 8),
                    Scalar::all(shade),
                    -1,
                    imgproc::LINE_8,
                    0,
                )
                .unwrap();
            }
        }
        writer.write(&frame).unwrap();
    }
    writer.release().unwrap();
}

#[test]
fn an_empty_scene_raises_one_event_per_interval_of_motion_and_none_elsewhere() {
    let site = TestSite::with_source("pipeline-empty", "", "replaced-by-replay");
    let video = site.path("scene.avi");
    write_empty_scene_video(&video, LENGTH_S, &INTERVALS);
    let summary = replay(&site, &video, "out");
    assert_eq!(
        summary["counts"]["frames"].as_u64().unwrap(),
        (LENGTH_S * FPS) as u64
    );
    let events = read_jsonl(&site.path("out/events.jsonl"));
    let start = isochron_config::clock::parse_rfc3339("2026-03-02T07:00:00Z").unwrap();
    let seconds = |v: &Value| {
        (isochron_config::clock::parse_rfc3339(v.as_str().unwrap()).unwrap() - start) as f64 / 1e9
    };
    println!(
        "events: {:?}",
        events
            .iter()
            .map(|e| (
                e["kind"].as_str().unwrap().to_string(),
                seconds(&e["start"]),
                seconds(&e["end"])
            ))
            .collect::<Vec<_>>()
    );
    for (i, (from, to)) in INTERVALS.iter().enumerate() {
        let inside: Vec<&Value> = events
            .iter()
            .filter(|e| seconds(&e["start"]) < to + 1.5 && seconds(&e["end"]) > from - 1.5)
            .collect();
        assert_eq!(inside.len(), 1, "interval {i} ({from}..{to} s): {inside:?}");
        let latency = seconds(&inside[0]["start"]) - from;
        println!("interval {i}: event starts {latency:+.2} s from the object's entry");
        assert!(
            latency.abs() <= 1.5,
            "interval {i}: start latency {latency:.2} s"
        );
        assert_eq!(inside[0]["kind"], "moving");
        let frame = inside[0]["start_frame"].as_u64().unwrap() as f64 / FPS;
        assert!(
            (frame - seconds(&inside[0]["start"])).abs() < 0.15,
            "start_frame matches start"
        );
    }
    assert_eq!(
        events.len(),
        INTERVALS.len(),
        "no events outside the intervals"
    );
}
