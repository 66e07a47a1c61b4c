//! isochron-mqtt: config → node → every camera's events and detections in, JSON
//! to the MQTT broker out → the stage runtime. Runs once per site, when `[mqtt]`
//! is configured.

use std::process::ExitCode;

use isochron_mqtt::stage;
use isochron_runtime::service::main_site_wide;
use isochron_runtime::topology::StageKind;

fn main() -> ExitCode {
    main_site_wide(StageKind::Mqtt, stage::run)
}
