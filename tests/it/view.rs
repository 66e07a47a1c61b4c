//! Looking at what isochron sees: the calibration overlay of `isochron costmap
//! check --overlay`, drawn on a real frame of vtest.avi with the demo site's
//! calibration.

use std::path::Path;
use std::time::Duration;

use isochron_tests::{TestSite, repo_root, vtest};
use serde_json::Value;

/// config/demo.toml without its `[site]` section (the test site has its own), the
/// video at its absolute path; `edit` may change the text.
fn demo_site(name: &str, edit: impl Fn(String) -> String) -> TestSite {
    let text = std::fs::read_to_string(repo_root().join("config/demo.toml")).unwrap();
    let body = &text[text.find("[[camera]]").expect("demo has a camera")..];
    let body = body.replace(
        "source = \"../data/vtest.avi\"",
        &format!("source = \"{}\"", vtest().display()),
    );
    TestSite::new(name, &edit(body))
}

/// Width and height from a PNG's IHDR chunk.
fn png_size(path: &Path) -> (u32, u32) {
    let bytes = std::fs::read(path).unwrap();
    assert_eq!(
        &bytes[..8],
        b"\x89PNG\r\n\x1a\n",
        "{} is a PNG",
        path.display()
    );
    assert_eq!(&bytes[12..16], b"IHDR");
    let be = |b: &[u8]| u32::from_be_bytes(b.try_into().unwrap());
    (be(&bytes[16..20]), be(&bytes[20..24]))
}

fn check(site: &TestSite, extra: &[&str]) -> (Option<i32>, Value, String) {
    let config = site.config_path().display().to_string();
    let mut args = vec!["costmap", "check", "--config", &config, "--camera", "cam01"];
    args.extend_from_slice(extra);
    args.push("--json");
    let done = site.isochron(&args, Duration::from_secs(60));
    let json = serde_json::from_str(&done.stdout)
        .unwrap_or_else(|e| panic!("{e}: not JSON:\n{}\nstderr:\n{}", done.stdout, done.stderr));
    (done.status.code(), json, done.stderr)
}

#[test]
fn overlay_of_the_demo_camera_has_the_frame_size_and_the_known_error() {
    let site = demo_site("overlay", |b| b);
    let out = site.path("overlay.png");
    let (code, json, stderr) = check(&site, &["--overlay", out.to_str().unwrap()]);
    assert_eq!(code, Some(0), "{stderr}");
    // vtest.avi is 768×576, and the demo sets no analysis size.
    assert_eq!(png_size(&out), (768, 576));
    let cam = &json["cameras"][0];
    assert_eq!(cam["frame_px"], serde_json::json!([768, 576]));
    let points = cam["points"].as_array().unwrap();
    assert_eq!(points.len(), 12);
    // The calibration's known error: the lens distortion a homography cannot model
    // leaves about 0.1 m (config/demo.toml), a pixel or two in the image.
    let rms_m = cam["rms_m"].as_f64().unwrap();
    let rms_px = cam["rms_px"].as_f64().unwrap();
    assert!((0.03..0.15).contains(&rms_m), "RMS {rms_m} m");
    assert!((0.5..3.0).contains(&rms_px), "RMS {rms_px} px");
    let per_point =
        |key: &str| -> Vec<f64> { points.iter().map(|p| p[key].as_f64().unwrap()).collect() };
    let residual_m = per_point("residual_m");
    let mean_sq = residual_m.iter().map(|r| r * r).sum::<f64>() / 12.0;
    assert!((mean_sq.sqrt() - rms_m).abs() < 1e-9);
    assert!(residual_m.iter().all(|&r| r < 0.15), "{residual_m:?}");
    assert!(per_point("residual_px").iter().all(|&r| r < 3.0));
    // Leaving a point out costs accuracy at it, but not much in a good set.
    let loo = cam["loo_rms_m"].as_f64().unwrap();
    assert!(loo > rms_m && loo < 0.3, "leave-one-out {loo} m");
    assert!(points.iter().all(|p| p["flagged"] == false));

    // The overlay itself is an image OpenCV reads back as a frame to draw on.
    let again = site.path("again.png");
    let (code, _, stderr) = check(
        &site,
        &[
            "--overlay",
            again.to_str().unwrap(),
            "--frame",
            out.to_str().unwrap(),
        ],
    );
    assert_eq!(code, Some(0), "{stderr}");
    assert_eq!(png_size(&again), (768, 576));
}

#[test]
fn overlay_scales_the_frame_to_the_analysis_size() {
    // The analysis size is half the video's; the floor points are halved with it.
    let site = demo_site("overlay-half", |b| {
        let mut out = b.replace("loop = true", "loop = true\nwidth = 384\nheight = 288");
        for (x, y) in [(40, 180), (270, 180), (500, 180), (730, 180)]
            .into_iter()
            .chain([(40, 330), (270, 330), (500, 330), (730, 330)])
            .chain([(40, 560), (270, 560), (500, 560), (730, 560)])
        {
            out = out.replace(
                &format!("image_px = [{x}, {y}]"),
                &format!("image_px = [{}, {}]", x as f64 / 2.0, y as f64 / 2.0),
            );
        }
        out
    });
    let out = site.path("half.png");
    let (code, json, stderr) = check(&site, &["--overlay", out.to_str().unwrap()]);
    assert_eq!(code, Some(0), "{stderr}");
    assert_eq!(png_size(&out), (384, 288));
    let rms_px = json["cameras"][0]["rms_px"].as_f64().unwrap();
    assert!(
        (0.25..1.5).contains(&rms_px),
        "RMS {rms_px} px at half size"
    );
}

#[test]
fn a_wrong_tape_mark_is_flagged() {
    // Point 5 measured 2 m off along x.
    let site = demo_site("overlay-outlier", |b| {
        b.replace("floor_m = [-12.51, -6.441]", "floor_m = [-10.51, -6.441]")
    });
    let out = site.path("outlier.png");
    let (code, json, _) = check(&site, &["--overlay", out.to_str().unwrap()]);
    assert_eq!(code, Some(1), "a point that stands out fails the check");
    let flagged: Vec<u64> = json["cameras"][0]["points"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|p| p["flagged"] == true)
        .map(|p| p["index"].as_u64().unwrap())
        .collect();
    assert_eq!(flagged, vec![5]);
    assert_eq!(
        png_size(&out),
        (768, 576),
        "the overlay is drawn all the same"
    );
    // And the text says which.
    let config = site.config_path().display().to_string();
    let done = site.isochron(
        &["costmap", "check", "--config", &config, "--camera", "cam01"],
        Duration::from_secs(60),
    );
    let line = done
        .stdout
        .lines()
        .find(|l| l.contains("far above the others"))
        .unwrap_or_else(|| panic!("no flagged point in:\n{}", done.stdout));
    assert!(line.trim_start().starts_with("#5 "), "{line}");
}

#[test]
fn bad_overlay_input_is_one_clear_line() {
    let site = demo_site("overlay-bad", |b| b);
    let config = site.config_path().display().to_string();
    let png = site.path("x.png").display().to_string();
    let not_video = site.config_path().display().to_string();
    for (args, expect) in [
        (
            vec!["--camera", "cam09", "--overlay", &png],
            "no camera 'cam09'",
        ),
        (
            vec!["--camera", "cam01", "--overlay", "/nonexistent/dir/x.png"],
            "--overlay /nonexistent/dir/x.png: cannot write",
        ),
        (
            vec![
                "--camera",
                "cam01",
                "--overlay",
                &png,
                "--frame",
                &not_video,
            ],
            "not a video or image",
        ),
        (
            vec![
                "--camera",
                "cam01",
                "--overlay",
                &png,
                "--frame",
                "/nonexistent.avi",
            ],
            "--frame /nonexistent.avi: no such file",
        ),
    ] {
        let mut all = vec!["costmap", "check", "--config", &config];
        all.extend(args);
        let done = site.isochron(&all, Duration::from_secs(60));
        assert_eq!(done.status.code(), Some(1), "{all:?}: {}", done.stderr);
        let lines: Vec<&str> = done.stderr.lines().collect();
        assert_eq!(lines.len(), 1, "{all:?}: {}", done.stderr);
        assert!(lines[0].contains(expect), "{all:?}: {}", done.stderr);
    }
}
