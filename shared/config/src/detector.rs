//! Which people detector the gate will load, decided from its configuration and
//! the files installed beside the binaries: one rule, read by the gate when it
//! starts and by `isochron doctor` when it checks a site, so that both name the
//! same detector.
//!
//! The rule: `gate.detector.model` if set (relative to the config file), else,
//! with `gate.detector.installed`, the first of [`INSTALLED_NETWORKS`] found in
//! the first of [`installed_dirs`] that has one, else OpenCV's HOG.

use std::path::{Path, PathBuf};

use crate::DetectorConfig;

/// The file name of the SSD `cargo xtask setup --all` installs.
pub const INSTALLED_SSD: &str = "ssdlite-person.pb";

/// The file name of the MoveNet `cargo xtask setup` installs (ONNX Runtime's
/// [`RUNTIME_LIBRARY`] beside it).
pub const INSTALLED_MOVENET: &str = "movenet-multipose.onnx";

/// ONNX Runtime's library, which MoveNet runs with: beside the model, else in
/// the installed directories.
pub const RUNTIME_LIBRARY: &str = "libonnxruntime.so";

/// The installed networks, first found first (chosen by `cargo xtask bench
/// detector`).
pub const INSTALLED_NETWORKS: [&str; 2] = [INSTALLED_MOVENET, INSTALLED_SSD];

/// What kind of network a model file is, by its name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ModelKind {
    /// MoveNet MultiPose in ONNX, run by ONNX Runtime.
    MoveNet,
    /// A TensorFlow Object Detection API SSD frozen graph, run by OpenCV's dnn.
    Ssd,
    /// A YOLOv5/YOLOv8 ONNX export, run by OpenCV's dnn.
    Yolo,
}

impl ModelKind {
    /// The kind of `path`: an `.onnx` whose name starts with `movenet` is
    /// MoveNet, a `.pb` an SSD, anything else a YOLO export.
    pub fn of(path: &Path) -> ModelKind {
        if is_movenet(path) {
            ModelKind::MoveNet
        } else if path.extension().is_some_and(|e| e == "pb") {
            ModelKind::Ssd
        } else {
            ModelKind::Yolo
        }
    }
}

/// The detector the gate will run.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DetectorChoice {
    /// A network from `path` (which must exist, or the gate stops with exit 78).
    Model {
        /// The model file.
        path: PathBuf,
        /// Its kind.
        kind: ModelKind,
        /// Whether it is the installed network rather than a configured one.
        installed: bool,
    },
    /// OpenCV's HOG people detector, and why.
    Hog {
        /// Why no network runs.
        why: String,
    },
}

impl DetectorConfig {
    /// The detector the gate runs with this configuration; `base_dir` resolves a
    /// relative `model`.
    pub fn choice(&self, base_dir: &Path) -> DetectorChoice {
        let (path, installed) = match &self.model {
            Some(model) if model.is_absolute() => (Some(model.clone()), false),
            Some(model) => (Some(base_dir.join(model)), false),
            None if self.installed => (installed_network(), true),
            None => (None, false),
        };
        match path {
            Some(path) => DetectorChoice::Model {
                kind: ModelKind::of(&path),
                path,
                installed,
            },
            None if self.installed => DetectorChoice::Hog {
                why: format!(
                    "no network installed (`cargo xtask setup` installs {INSTALLED_MOVENET}; looked in {})",
                    installed_dirs()
                        .iter()
                        .map(|d| d.display().to_string())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            },
            None => DetectorChoice::Hog {
                why: "gate.detector.installed = false".to_string(),
            },
        }
    }
}

/// Where the installed network is looked for, in order: `detector/` in the
/// directory above the running binary's (`target/detector/` for a checkout's
/// `target/debug/` or `target/release/`), and `share/isochron/detector/` there
/// (`/usr/share/...` for binaries in `/usr/bin`). The gate and `isochron` are
/// installed side by side, so both look in the same places.
pub fn installed_dirs() -> Vec<PathBuf> {
    let Some(prefix) = std::env::current_exe()
        .ok()
        .and_then(|exe| exe.parent()?.parent().map(Path::to_path_buf))
    else {
        return Vec::new();
    };
    vec![
        prefix.join("detector"),
        prefix.join("share/isochron/detector"),
    ]
}

/// The installed network, if there is one: the first of [`INSTALLED_NETWORKS`]
/// in the first of [`installed_dirs`] that has one.
pub fn installed_network() -> Option<PathBuf> {
    installed_dirs().into_iter().find_map(|d| {
        INSTALLED_NETWORKS
            .iter()
            .map(|n| d.join(n))
            .find(|p| p.is_file())
    })
}

/// True if `path` names a MoveNet model (an `.onnx` whose name starts with
/// `movenet`).
pub fn is_movenet(path: &Path) -> bool {
    path.extension().is_some_and(|e| e == "onnx")
        && path.file_name().is_some_and(|n| {
            n.to_string_lossy()
                .to_ascii_lowercase()
                .starts_with("movenet")
        })
}

/// ONNX Runtime's library for `model`: beside it, else in the installed
/// directories.
pub fn runtime_library(model: &Path) -> Option<PathBuf> {
    model
        .parent()
        .map(Path::to_path_buf)
        .into_iter()
        .chain(installed_dirs())
        .map(|d| d.join(RUNTIME_LIBRARY))
        .find(|p| p.is_file())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kinds_by_name() {
        assert_eq!(
            ModelKind::of(Path::new("a/MoveNet-x.onnx")),
            ModelKind::MoveNet
        );
        assert_eq!(
            ModelKind::of(Path::new("ssdlite-person.pb")),
            ModelKind::Ssd
        );
        assert_eq!(ModelKind::of(Path::new("yolov8n.onnx")), ModelKind::Yolo);
    }

    #[test]
    fn a_configured_model_wins_and_installed_false_means_hog() {
        let config = DetectorConfig {
            model: Some("m/yolo.onnx".into()),
            ..DetectorConfig::default()
        };
        assert_eq!(
            config.choice(Path::new("/etc/isochron")),
            DetectorChoice::Model {
                path: "/etc/isochron/m/yolo.onnx".into(),
                kind: ModelKind::Yolo,
                installed: false
            }
        );
        let config = DetectorConfig {
            installed: false,
            ..DetectorConfig::default()
        };
        assert!(
            matches!(config.choice(Path::new("/")), DetectorChoice::Hog { why } if why.contains("installed = false"))
        );
    }
}
