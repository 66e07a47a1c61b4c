//! The checks `isochron doctor` makes with the services' own load-time code: the
//! settings they warn about, the MQTT broker the sink would refuse, the people
//! detector the gate would load, and the route graph the bridge would feed the
//! route server.

use isochron_config::LoadedConfig;
use isochron_exit as exit;
use isochron_planning::route_graph::RouteGraph;

use super::{Level, Report};

/// The settings the services accept but warn about at load (e.g. a lethal
/// `costmap.cap`): the same list the services log ([`LoadedConfig::warnings`]).
pub(super) fn check_warnings(loaded: &LoadedConfig, report: &mut Report) {
    for warning in loaded.warnings() {
        report.say(Level::Warn, "config", warning.to_string());
    }
}

/// `[mqtt]`, if configured: its section and broker address as the MQTT sink
/// reads them at start ([`LoadedConfig::mqtt`], `MqttConfig::broker_addr`); a
/// refusal there stops the sink with exit 78.
pub(super) fn check_mqtt(loaded: &LoadedConfig, report: &mut Report) {
    const WHAT: &str = "mqtt";
    let config = match loaded.mqtt() {
        Ok(None) => return,
        Ok(Some(config)) => config,
        Err(e) => {
            report.say(
                Level::Fail,
                WHAT,
                format!("{e} (isochron-mqtt exits with code {})", exit::CONFIG),
            );
            return;
        }
    };
    match config.broker_addr() {
        Ok(broker) => report.say(
            Level::Ok,
            WHAT,
            format!("broker {}:{} ({})", broker.host, broker.port, config.broker),
        ),
        Err(e) => report.say(
            Level::Fail,
            WHAT,
            format!(
                "{} (isochron-mqtt exits with code {})",
                loaded.locate(e),
                exit::CONFIG
            ),
        ),
    }
}

/// The people detector the gate will load, by the gate's own rule
/// ([`isochron_config::detector`]): its name and file, and that the file (and
/// MoveNet's ONNX Runtime library) is there and readable.
pub(super) fn check_model(loaded: &LoadedConfig, report: &mut Report) {
    use isochron_config::detector::{DetectorChoice, ModelKind, RUNTIME_LIBRARY, runtime_library};
    const WHAT: &str = "detector model";
    let (path, kind, installed) = match loaded.config.gate.detector.choice(&loaded.base_dir()) {
        DetectorChoice::Hog { why } => {
            report.say(Level::Ok, WHAT, format!("HOG (OpenCV's people SVM): {why}"));
            return;
        }
        DetectorChoice::Model {
            path,
            kind,
            installed,
        } => (path, kind, installed),
    };
    let name = match kind {
        ModelKind::MoveNet => "MoveNet MultiPose (ONNX Runtime)",
        ModelKind::Ssd => "TensorFlow SSD (OpenCV dnn)",
        ModelKind::Yolo => "YOLO ONNX (OpenCV dnn)",
    };
    let whence = if installed {
        "the installed network"
    } else {
        "gate.detector.model"
    };
    let config = loaded.path.display();
    let problem = match std::fs::metadata(&path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => "does not exist".to_string(),
        Err(e) => format!("cannot be read: {e}"),
        Ok(m) if !m.is_file() => "is not a file".to_string(),
        Ok(m) => match std::fs::File::open(&path) {
            Err(e) => format!("is not readable by this user: {e}"),
            Ok(_) if kind == ModelKind::MoveNet && runtime_library(&path).is_none() => {
                format!("has no ONNX Runtime library ({RUNTIME_LIBRARY}) beside it or installed")
            }
            Ok(_) => {
                report.say(
                    Level::Ok,
                    WHAT,
                    format!(
                        "{name}, {whence}: {} ({:.1} MiB)",
                        path.display(),
                        m.len() as f64 / (1 << 20) as f64
                    ),
                );
                return;
            }
        },
    };
    report.say(
        Level::Fail,
        WHAT,
        format!(
            "{name}, {whence}: {} {problem}: the gate would stop (exit 78); put the model there (readable by the services' user), fix gate.detector.model in {config}, or set gate.detector.installed = false for HOG",
            path.display()
        ),
    );
}

/// `costmap.route_graph`, if configured: the graph as the bridge loads it
/// ([`RouteGraph::from_config`]; a refusal stops the bridge with exit 78) and
/// what the bridge will tell the route server.
pub(super) fn check_route_graph(loaded: &LoadedConfig, report: &mut Report) {
    const WHAT: &str = "route graph";
    let c = &loaded.config.costmap;
    match RouteGraph::from_config(loaded) {
        Ok(None) => {}
        Ok(Some(graph)) => {
            let edges = graph.edges();
            let fixed = edges.iter().filter(|e| !e.overridable).count();
            report.say(
                Level::Ok,
                WHAT,
                format!(
                    "{} nodes, {} edges ({fixed} not overridable, never named): every {} s the                      bridge tells {} (nav2_msgs/srv/DynamicEdges) each seen edge's cost, and                      closes an edge people stand across for {} s",
                    graph.nodes().len(),
                    edges.len(),
                    c.route_update_s,
                    c.route_adjust_edges_service(),
                    c.route_close_after_s
                ),
            );
        }
        Err(e) => report.say(
            Level::Fail,
            WHAT,
            format!("{e} (isochron-costmap exits with code {})", exit::CONFIG),
        ),
    }
}

/// Each camera's `[[camera.zone]]`s on the block grid the gate will see (the
/// configured analysis size, else a video file's size): a zone that covers no
/// block centre never raises events, which the gate only warns about once it
/// runs. A camera whose size is known only once it streams is not checked.
pub(super) fn check_zones(loaded: &LoadedConfig, report: &mut Report) {
    use isochron_config::SourceKind;
    use isochron_wire::geometry::BlockGrid;
    let block_px = loaded.config.motion.block_px;
    for cam in loaded.config.cameras.iter().filter(|c| !c.zones.is_empty()) {
        let size =
            cam.width
                .zip(cam.height)
                .or_else(|| match cam.source_kind(&loaded.base_dir()) {
                    SourceKind::File(p) => crate::overlay::Frame::read(&p, None)
                        .ok()
                        .map(|f| (f.width, f.height)),
                    _ => None,
                });
        let Some((w, h)) = size else { continue };
        let grid = BlockGrid::new(w, h, block_px);
        let what = format!("zones {}", cam.id);
        let empty: Vec<&str> = cam
            .zones
            .iter()
            .filter(|z| grid.blocks_in(&z.polygon).is_empty())
            .map(|z| z.name.as_str())
            .collect();
        if empty.is_empty() {
            report.say(
                Level::Ok,
                &what,
                format!(
                    "{} zones on the {w}x{h} frame's {}x{} blocks",
                    cam.zones.len(),
                    grid.grid_w(),
                    grid.grid_h()
                ),
            );
        } else {
            report.say(
                Level::Warn,
                &what,
                format!(
                    "{} cover no block centre of the {w}x{h} frame's {}x{} grid: they will never raise events (outside the frame, or too small; zones are in frame pixels)",
                    empty.join(", "),
                    grid.grid_w(),
                    grid.grid_h()
                ),
            );
        }
    }
}
