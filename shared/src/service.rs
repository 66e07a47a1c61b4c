//! What every service binary does first: logging, config, camera, iceoryx2 node —
//! each failure mapped to a clear message and an exit code a supervisor understands.

use std::path::Path;

use crate::config::{CameraConfig, Config, LoadedConfig};
use crate::health::exit;
use crate::ipc::Ipc;
use crate::names::ServiceNames;

/// A failure that ends the process with `code` after logging `message`.
#[derive(Debug)]
pub struct Fatal {
    /// Exit code (see [`crate::health::exit`]).
    pub code: i32,
    /// What went wrong and what to do.
    pub message: String,
}

impl Fatal {
    /// A failure with `code`.
    pub fn new(code: i32, message: impl Into<String>) -> Self {
        Fatal {
            code,
            message: message.into(),
        }
    }
}

/// The started service: its config, its camera (if per-camera) and its node.
pub struct ServiceContext {
    /// The loaded config.
    pub config: LoadedConfig,
    /// The camera this process serves, for per-camera services.
    pub camera: Option<CameraConfig>,
    /// The process's iceoryx2 node.
    pub ipc: Ipc,
}

impl ServiceContext {
    /// The camera (per-camera services only).
    pub fn camera(&self) -> &CameraConfig {
        self.camera
            .as_ref()
            .expect("per-camera service started without a camera")
    }
}

/// Initialises logging, loads the config, finds `camera`, and creates the node
/// `<prefix>/<stage>/<camera>` (`<prefix>/<stage>` for site-wide stages), the name
/// `iox2 node list` shows.
pub fn start(stage: &str, config: &Path, camera: Option<&str>) -> Result<ServiceContext, Fatal> {
    crate::logging::init(&format!("isochron-{stage}"));
    let loaded = Config::load(config).map_err(|e| Fatal::new(exit::CONFIG, e.to_string()))?;
    let camera = camera
        .map(|id| loaded.camera(id).cloned())
        .transpose()
        .map_err(|e| Fatal::new(exit::CONFIG, e))?;
    let prefix = &loaded.config.site.service_prefix;
    let node_name = match &camera {
        Some(c) => format!("{prefix}/{stage}/{}", c.id),
        None => format!("{prefix}/{stage}"),
    };
    let ipc = Ipc::new(
        &node_name,
        ServiceNames::new(&loaded.config.site.service_prefix),
        loaded.config.ipc.clone(),
    )
    .map_err(|e| Fatal::new(exit::UNAVAILABLE, e.to_string()))?;
    Ok(ServiceContext {
        config: loaded,
        camera,
        ipc,
    })
}

/// Logs the outcome of `main`'s work and turns it into the process exit code.
pub fn finish(stage: &str, result: Result<(), Fatal>) -> std::process::ExitCode {
    crate::health::notify_stopping();
    match result {
        Ok(()) => {
            tracing::info!("isochron-{stage} stopped");
            std::process::ExitCode::SUCCESS
        }
        Err(fatal) => {
            tracing::error!("{}", fatal.message);
            std::process::ExitCode::from(fatal.code as u8)
        }
    }
}
