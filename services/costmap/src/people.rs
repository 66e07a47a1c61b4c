//! The people a camera's detector confirmed, as robots and people see them:
//! their feet as a `geometry_msgs/PoseArray` (`costmap.people_topic`) and, for
//! rviz2 / Foxglove, a `visualization_msgs/MarkerArray`
//! (`costmap.people_markers_topic`): each person's skeleton where the model gave
//! keypoints (MoveNet), a cylinder of the box's height otherwise, and a label
//! with the model's name and score.
//!
//! A skeleton stands upright at the person's feet, in the vertical plane facing
//! the camera: a keypoint's offset from the feet in image pixels becomes metres
//! at the scale of the floor under the feet along the image's rows (the box's
//! width mapped to the floor, divided by its width in pixels), which at the
//! person's distance from the camera is also the scale upright. It shows the
//! pose the camera saw, not a measured 3-D pose.

use isochron_planning::homography::Homography;
use isochron_ros2::msgs::{
    ColorRGBA, Header, Marker, Point, Pose, PoseArray, Quaternion, RosDuration, Vector3,
};
use isochron_wire::{Detection, Keypoint};

use crate::bridge::Confirmed;

/// Bone width, metres.
const BONE_M: f64 = 0.04;
/// Diameter of the cylinder of a person without keypoints, metres.
const BODY_M: f64 = 0.4;
/// Label height, metres.
const TEXT_M: f64 = 0.25;
/// A drawn person's height is kept within this, metres (a box cut by the frame's
/// edge or a tilted view's scale would draw a giant).
const HEIGHT_RANGE_M: (f64, f64) = (0.3, 2.5);
/// Markers per person: the body (skeleton or cylinder) and the label.
const MARKERS_PER_PERSON: usize = 2;

/// The newest `placed` people of a camera as poses at their feet (orientation:
/// none estimated, identity).
pub fn poses(confirmed: &[Confirmed], header: Header) -> PoseArray {
    PoseArray {
        header,
        poses: confirmed
            .iter()
            .map(|c| Pose {
                position: Point {
                    x: c.floor_m[0],
                    y: c.floor_m[1],
                    z: 0.0,
                },
                orientation: Quaternion::from_yaw(0.0),
            })
            .collect(),
    }
}

/// The markers of a camera's `confirmed` people in namespace `people/<camera>`,
/// each shown for `lifetime`; ids from `confirmed.len()` up to `shown_before`
/// (the count of the camera's last markers) are deleted.
pub fn markers(
    camera: &str,
    homography: &Homography,
    confirmed: &[Confirmed],
    shown_before: usize,
    header: &Header,
    lifetime: RosDuration,
) -> Vec<Marker> {
    let ns = format!("people/{camera}");
    let mut out = Vec::new();
    for (i, c) in confirmed.iter().enumerate() {
        let d = &c.detection;
        let Some(scale) = Scale::at_feet(homography, d, c.floor_m) else {
            continue;
        };
        let id = (MARKERS_PER_PERSON * i) as i32;
        let marker = |kind, color, points| Marker {
            header: header.clone(),
            ns: ns.clone(),
            id,
            kind,
            action: Marker::ADD,
            lifetime,
            color,
            points,
            ..Default::default()
        };
        let body = if d.has_pose() {
            Marker {
                scale: Vector3 {
                    x: BONE_M,
                    ..Default::default()
                },
                ..marker(Marker::LINE_LIST, rgba(0.1, 1.0, 0.4), skeleton(d, &scale))
            }
        } else {
            let height = scale.height(d.h);
            Marker {
                pose: Pose {
                    position: scale.point(0.0, height / 2.0),
                    ..Default::default()
                },
                scale: Vector3 {
                    x: BODY_M,
                    y: BODY_M,
                    z: height,
                },
                ..marker(Marker::CYLINDER, rgba(1.0, 0.5, 0.1), Vec::new())
            }
        };
        out.push(body);
        out.push(Marker {
            id: id + 1,
            kind: Marker::TEXT_VIEW_FACING,
            pose: Pose {
                position: scale.point(0.0, scale.height(d.h) + TEXT_M),
                ..Default::default()
            },
            scale: Vector3 {
                z: TEXT_M,
                ..Default::default()
            },
            color: rgba(1.0, 1.0, 1.0),
            text: format!("{} {:.2}", d.model().name(), d.score),
            ..out[out.len() - 1].clone()
        });
    }
    let drawn = MARKERS_PER_PERSON * confirmed.len();
    for id in drawn..shown_before.max(drawn) {
        out.push(Marker {
            header: header.clone(),
            ns: ns.clone(),
            id: id as i32,
            action: Marker::DELETE,
            ..Default::default()
        });
    }
    out
}

/// Image pixels around a person's feet → map metres, upright in the plane facing
/// the camera.
struct Scale {
    /// The feet, image pixels.
    feet_px: [f64; 2],
    /// The feet on the floor, metres.
    feet_m: [f64; 2],
    /// Metres per pixel.
    m_per_px: f64,
    /// The floor direction of the image's rows at the feet (unit).
    along: [f64; 2],
}

impl Scale {
    /// The scale at `d`'s feet: its box's bottom edge mapped to the floor. None
    /// where the edge does not map (at or beyond the horizon) or is degenerate.
    fn at_feet(h: &Homography, d: &Detection, feet_m: [f64; 2]) -> Option<Scale> {
        let bottom = (d.y + d.h) as f64;
        let left = h.apply([d.x as f64, bottom])?;
        let right = h.apply([(d.x + d.w) as f64, bottom])?;
        let (dx, dy) = (right[0] - left[0], right[1] - left[1]);
        let len = dx.hypot(dy);
        if !(len.is_finite() && len > 0.0 && d.w > 0.0) {
            return None;
        }
        Some(Scale {
            feet_px: [(d.x + d.w / 2.0) as f64, bottom],
            feet_m,
            m_per_px: len / d.w as f64,
            along: [dx / len, dy / len],
        })
    }

    /// The point `right_m` along the rows and `up_m` above the feet.
    fn point(&self, right_m: f64, up_m: f64) -> Point {
        Point {
            x: self.feet_m[0] + right_m * self.along[0],
            y: self.feet_m[1] + right_m * self.along[1],
            z: up_m,
        }
    }

    /// The image point `k` upright above the feet.
    fn keypoint(&self, k: &Keypoint) -> Point {
        self.point(
            (k.x as f64 - self.feet_px[0]) * self.m_per_px,
            (self.feet_px[1] - k.y as f64) * self.m_per_px,
        )
    }

    /// A box `h_px` tall in metres, within [`HEIGHT_RANGE_M`].
    fn height(&self, h_px: f32) -> f64 {
        (h_px as f64 * self.m_per_px).clamp(HEIGHT_RANGE_M.0, HEIGHT_RANGE_M.1)
    }
}

/// The bones of `d` ([`Detection::bones`]) as a `LINE_LIST`'s point pairs.
fn skeleton(d: &Detection, scale: &Scale) -> Vec<Point> {
    d.bones()
        .flat_map(|(a, b)| [scale.keypoint(&a), scale.keypoint(&b)])
        .collect()
}

fn rgba(r: f32, g: f32, b: f32) -> ColorRGBA {
    ColorRGBA { r, g, b, a: 1.0 }
}

#[cfg(test)]
mod tests {
    use super::*;
    use isochron_wire::{DetectorModel, KEYPOINTS};

    /// 100 image px = 1 m: image (u, v) → floor (u / 100, v / 100).
    fn flat() -> Homography {
        let image = [[0.0, 0.0], [100.0, 0.0], [0.0, 100.0], [100.0, 100.0]];
        let floor = image.map(|[u, v]| [u / 100.0, v / 100.0]);
        Homography::fit(&image, &floor).unwrap()
    }

    fn person(pose: bool) -> Confirmed {
        let mut d = Detection {
            x: 100.0,
            y: 20.0,
            w: 40.0,
            h: 170.0,
            score: 0.87,
            model: DetectorModel::MoveNet as u32,
            ..Default::default()
        };
        if pose {
            // Shoulders 140 px above the feet, hips 90: both drawn, and the bone between.
            d.keypoints[5] = Keypoint {
                x: 110.0,
                y: 50.0,
                score: 0.9,
            };
            d.keypoints[6] = Keypoint {
                x: 130.0,
                y: 50.0,
                score: 0.9,
            };
            d.keypoints[11] = Keypoint {
                x: 112.0,
                y: 100.0,
                score: 0.8,
            };
            d.keypoints[12] = Keypoint {
                x: 128.0,
                y: 100.0,
                score: 0.1,
            };
        }
        Confirmed {
            seen_ns: 0,
            feet_px: [120.0, 190.0],
            floor_m: [1.2, 1.9],
            detection: d,
        }
    }

    fn header() -> Header {
        Header {
            frame_id: "map".into(),
            ..Default::default()
        }
    }

    #[test]
    fn a_pose_stands_upright_at_the_feet_with_its_model_and_score() {
        let m = markers(
            "cam01",
            &flat(),
            &[person(true)],
            0,
            &header(),
            RosDuration {
                sec: 15,
                nanosec: 0,
            },
        );
        assert_eq!(m.len(), 2);
        let (body, label) = (&m[0], &m[1]);
        assert_eq!(
            (body.ns.as_str(), body.kind),
            ("people/cam01", Marker::LINE_LIST)
        );
        // Bones with both ends seen: shoulders–shoulders, left shoulder–left hip.
        assert_eq!(body.points.len(), 4, "{:?}", body.points);
        let shoulder = &body.points[0];
        assert!((shoulder.x - 1.1).abs() < 1e-9 && (shoulder.y - 1.9).abs() < 1e-9);
        assert!((shoulder.z - 1.4).abs() < 1e-9, "{}", shoulder.z);
        assert_eq!(label.text, "movenet 0.87");
        assert_eq!(label.kind, Marker::TEXT_VIEW_FACING);
        assert_eq!(label.lifetime.sec, 15);
        assert!(label.pose.position.z > 1.7);
        assert_eq!(KEYPOINTS, 17);
    }

    #[test]
    fn a_box_without_keypoints_is_a_cylinder_and_stale_ids_are_deleted() {
        let mut p = person(false);
        p.detection.model = DetectorModel::Hog as u32;
        let m = markers("cam01", &flat(), &[p], 6, &header(), RosDuration::default());
        assert_eq!(m[0].kind, Marker::CYLINDER);
        assert!((m[0].scale.z - 1.7).abs() < 1e-9);
        assert!((m[0].pose.position.z - 0.85).abs() < 1e-9);
        assert!(m[1].text.starts_with("hog "));
        let deleted: Vec<i32> = m
            .iter()
            .filter(|m| m.action == Marker::DELETE)
            .map(|m| m.id)
            .collect();
        assert_eq!(deleted, [2, 3, 4, 5]);
    }
}
