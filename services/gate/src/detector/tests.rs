//! Unit tests of the detector: the search region, the letterbox, YOLO output parsing.

use super::*;

fn mat3(shape: [i32; 3], values: &[f32]) -> Mat {
    let mut m = Mat::new_nd_with_default(&shape, opencv::core::CV_32F, Scalar::all(0.0)).unwrap();
    m.data_typed_mut::<f32>().unwrap().copy_from_slice(values);
    m
}

#[test]
fn parses_yolov8_layout() {
    // Rows cx, cy, w, h, person, other class; 8 candidates (real exports have
    // far more candidates than rows, which is how the layouts are told apart).
    let n = 8;
    let mut v = vec![0.0f32; 6 * n];
    for i in 0..n {
        v[i] = 100.0 + i as f32; // cx
        v[n + i] = 50.0; // cy
        v[2 * n + i] = 20.0; // w
        v[3 * n + i] = 40.0; // h
    }
    v[4 * n] = 0.9; // candidate 0: a person
    v[4 * n + 1] = 0.3; // candidate 1: too weak
    v[5 * n + 2] = 0.95; // candidate 2: another class
    let found = parse_yolo(&mat3([1, 6, n as i32], &v), 0.5).unwrap();
    assert_eq!(found.len(), 1);
    assert_eq!(
        (found[0].cx, found[0].cy, found[0].score),
        (100.0, 50.0, 0.9)
    );
}

#[test]
fn parses_yolov5_layout_with_objectness() {
    // 8 candidates of cx, cy, w, h, objectness, person, other.
    let mut v = vec![0.0f32; 8 * 7];
    v[..7].copy_from_slice(&[10.0, 20.0, 4.0, 8.0, 0.9, 0.8, 0.1]);
    v[7..14].copy_from_slice(&[30.0, 40.0, 4.0, 8.0, 0.2, 0.9, 0.0]);
    let found = parse_yolo(&mat3([1, 8, 7], &v), 0.5).unwrap();
    assert_eq!(found.len(), 1);
    assert!((found[0].score - 0.72).abs() < 1e-6);
}

#[test]
fn overlapping_boxes_are_suppressed_and_scaled_to_the_frame() {
    let c = |cx, score| Candidate {
        cx,
        cy: 300.0,
        w: 20.0,
        h: 40.0,
        score,
    };
    // A 1280x640 frame in a 640 input: scale 0.5, 160 px of padding above.
    let fit = Letterbox::new(1280, 640, 640);
    assert_eq!(
        (fit.scale, fit.width, fit.height, fit.pad_x, fit.pad_y),
        (0.5, 640, 320, 0.0, 160.0)
    );
    let kept = non_max_suppression(
        vec![c(100.0, 0.9), c(102.0, 0.8), c(300.0, 0.7)],
        0.5,
        0.45,
        &fit,
    )
    .unwrap();
    assert_eq!(kept.len(), 2);
    assert_eq!((kept[0].x, kept[0].w), (180.0, 40.0));
    assert_eq!((kept[0].y, kept[0].h), (240.0, 80.0), "(280 - 160) / 0.5");
}

#[test]
fn a_search_rect_is_the_region_in_the_frame_at_least_the_window() {
    let r = |x, y, w, h| Region { x, y, w, h };
    let rect = |region, min| {
        let r = search_rect(region, 768, 576, min);
        (r.x, r.y, r.width, r.height)
    };
    assert_eq!(rect(Region::WHOLE, (43, 86)), (0, 0, 768, 576));
    assert_eq!(rect(r(100, 50, 200, 300), (43, 86)), (100, 50, 200, 300));
    // Clamped to the frame.
    assert_eq!(rect(r(700, 500, 200, 300), (43, 86)), (700, 490, 68, 86));
    // Grown around the centre to the window.
    assert_eq!(rect(r(100, 100, 10, 20), (43, 86)), (83, 67, 43, 86));
    assert_eq!(rect(r(0, 0, 10, 20), (43, 86)), (0, 0, 43, 86));
    // A region off the frame searches its nearest corner.
    assert_eq!(rect(r(900, 900, 10, 10), (43, 86)), (725, 490, 43, 86));
}

/// Frame `n` of `data/vtest.avi`, GRAY8, with its size.
fn vtest_frame(n: usize) -> (Vec<u8>, u32, u32) {
    use opencv::videoio;
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/vtest.avi");
    let mut cap =
        videoio::VideoCapture::from_file(path.to_str().unwrap(), videoio::CAP_ANY).unwrap();
    let (mut bgr, mut gray) = (Mat::default(), Mat::default());
    for _ in 0..=n {
        assert!(cap.read(&mut bgr).unwrap(), "vtest.avi");
    }
    imgproc::cvt_color(&bgr, &mut gray, imgproc::COLOR_BGR2GRAY, 0).unwrap();
    let (w, h) = (gray.cols() as u32, gray.rows() as u32);
    (gray.data_bytes().unwrap().to_vec(), w, h)
}

#[test]
fn hog_on_a_crop_finds_the_people_of_the_whole_frame_in_frame_pixels() {
    let (pixels, w, h) = vtest_frame(100);
    let mut hog = Detector::from_config(&DetectorConfig::default(), Path::new(".")).unwrap();
    let whole = hog.detect(&pixels, w, h, Region::WHOLE).unwrap();
    let best = whole
        .iter()
        .max_by(|a, b| a.score.total_cmp(&b.score))
        .expect("HOG finds someone on frame 100 of vtest.avi");
    // A crop around them, 64 px more on each side, off the frame's origin.
    let margin = 64.0;
    let x0 = (best.x - margin).max(0.0) as u32;
    let y0 = (best.y - margin).max(0.0) as u32;
    let region = Region {
        x: x0,
        y: y0,
        w: ((best.x + best.w + margin) as u32).min(w) - x0,
        h: ((best.y + best.h + margin) as u32).min(h) - y0,
    };
    let cropped = hog.detect(&pixels, w, h, region).unwrap();
    let iou = |a: &Detection, b: &Detection| {
        let ix = (a.x + a.w).min(b.x + b.w) - a.x.max(b.x);
        let iy = (a.y + a.h).min(b.y + b.h) - a.y.max(b.y);
        let i = ix.max(0.0) * iy.max(0.0);
        i / (a.w * a.h + b.w * b.h - i)
    };
    let same = cropped.iter().map(|d| iou(d, best)).fold(0.0, f32::max);
    assert!(
        same >= 0.7,
        "best overlap {same:.2} with {best:?} in {region:?}: {cropped:?}"
    );
}

#[test]
fn a_missing_model_is_a_clear_error() {
    let config = DetectorConfig {
        model: Some("nope.onnx".into()),
        ..DetectorConfig::default()
    };
    let err = Detector::from_config(&config, Path::new("/tmp"))
        .err()
        .unwrap()
        .to_string();
    assert!(err.contains("/tmp/nope.onnx does not exist"), "{err}");
}
