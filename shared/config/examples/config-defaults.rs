//! `isochron-config-defaults`: prints, as one JSON object, the configuration a
//! site gets from a file that sets only what has no default (no checks run,
//! so the required `mqtt.broker` stays empty) — one camera (`id`,
//! `source`), and empty `[exporter]` and `[mqtt]` sections — so that every
//! key's value is the one serde's defaults give. `cargo xtask docs config` reads it
//! to write the Default column of docs/configuration.md.

use std::process::ExitCode;

use isochron_config::Config;

/// The least a site file says: everything else comes from the defaults.
const MINIMAL: &str = r#"
[[camera]]
id = "cam01"
source = "video.avi"

[exporter]

[mqtt]
"#;

fn main() -> ExitCode {
    let config: Config = match toml::from_str(MINIMAL) {
        Ok(config) => config,
        Err(e) => {
            eprintln!("isochron-config-defaults: the minimal site file does not parse: {e}");
            return ExitCode::FAILURE;
        }
    };
    // serde_json's writer prints an f32 by its shortest form (0.02, not
    // 0.019999999552965164), which a `serde_json::Value` would not keep.
    match serde_json::to_string_pretty(&config) {
        Ok(json) => {
            println!("{json}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("isochron-config-defaults: cannot serialise the defaults: {e}");
            ExitCode::FAILURE
        }
    }
}
