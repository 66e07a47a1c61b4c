//! What the view draws on a camera's image: the detections of one frame as
//! `foxglove.ImageAnnotations` — each box, its skeleton where the model gave
//! keypoints (MoveNet), and its model and score.

use foxglove::messages::{
    Color, ImageAnnotations, Point2, PointsAnnotation, TextAnnotation, Timestamp,
};
use isochron_wire::Detection;

/// The annotations of `dets`, found in the frame captured at `stamp`, in the
/// pixels of the published image (`f` frame pixels each).
pub fn detections(dets: &[Detection], f: f64, stamp: Timestamp) -> ImageAnnotations {
    let color = Color {
        r: 1.0,
        g: 0.2,
        b: 0.2,
        a: 1.0,
    };
    let bone_color = Color {
        r: 0.1,
        g: 1.0,
        b: 0.4,
        a: 1.0,
    };
    let mut points = Vec::new();
    let mut texts = Vec::new();
    for d in dets {
        let (x0, y0) = (d.x as f64 / f, d.y as f64 / f);
        let (x1, y1) = (x0 + d.w as f64 / f, y0 + d.h as f64 / f);
        points.push(PointsAnnotation {
            timestamp: Some(stamp),
            r#type: foxglove::messages::points_annotation::Type::LineLoop as i32,
            points: [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
                .map(|(x, y)| Point2 { x, y })
                .to_vec(),
            outline_color: Some(color),
            thickness: 2.0,
            ..Default::default()
        });
        let bones: Vec<Point2> = d
            .bones()
            .flat_map(|(a, b)| [a, b])
            .map(|k| Point2 {
                x: k.x as f64 / f,
                y: k.y as f64 / f,
            })
            .collect();
        if !bones.is_empty() {
            points.push(PointsAnnotation {
                timestamp: Some(stamp),
                r#type: foxglove::messages::points_annotation::Type::LineList as i32,
                points: bones,
                outline_color: Some(bone_color),
                thickness: 2.0,
                ..Default::default()
            });
        }
        texts.push(TextAnnotation {
            timestamp: Some(stamp),
            position: Some(Point2 { x: x0, y: y0 }),
            text: format!("{} {:.2}", d.model().name(), d.score),
            font_size: 12.0,
            text_color: Some(color),
            ..Default::default()
        });
    }
    ImageAnnotations {
        timestamp: Some(stamp),
        points,
        texts,
        ..Default::default()
    }
}
