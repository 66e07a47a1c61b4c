//! `[costmap.zenoh]`: the costmap bridge's topics and planning services also in
//! rmw_zenoh's format, for robots whose ROS 2 middleware is rmw_zenoh.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::Invalid;

/// The router rmw_zenoh's nodes connect to by default.
pub const DEFAULT_ZENOH_ROUTER: &str = "tcp/localhost:7447";
/// Where the bridge's session listens by default: loopback, any free port.
pub const DEFAULT_ZENOH_LISTEN: &str = "tcp/127.0.0.1:0";

/// `[costmap.zenoh]`: ROS 2 over Zenoh (rmw_zenoh's key expressions, attachments
/// and liveliness tokens), beside DDS. Off by default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ZenohConfig {
    /// Publish the topics and serve the planning services on Zenoh too. Default
    /// false.
    pub enabled: bool,
    /// `"peer"` (as rmw_zenoh's nodes are: discovery through the router, data
    /// directly between peers) or `"client"` (everything through the router).
    /// Default `"peer"`.
    pub mode: String,
    /// Zenoh endpoints to connect to. Default `["tcp/localhost:7447"]`, the
    /// router `ros2 run rmw_zenoh_cpp rmw_zenohd` starts.
    pub connect: Vec<String>,
    /// Zenoh endpoints to listen on (peers connect to them for data). Default
    /// `["tcp/127.0.0.1:0"]`: loopback only; a robot on another machine needs an
    /// address of the site network here (and `config_file` for TLS).
    pub listen: Vec<String>,
    /// A Zenoh configuration file (JSON5), relative to this file, read before the
    /// keys above are set over it: TLS certificates (`tls/…` endpoints),
    /// user/password authentication, access control. Default none.
    pub config_file: Option<PathBuf>,
}

impl Default for ZenohConfig {
    fn default() -> Self {
        ZenohConfig {
            enabled: false,
            mode: "peer".into(),
            connect: vec![DEFAULT_ZENOH_ROUTER.into()],
            listen: vec![DEFAULT_ZENOH_LISTEN.into()],
            config_file: None,
        }
    }
}

/// The link protocols the bridge's Zenoh is built with.
const PROTOCOLS: [&str; 2] = ["tcp/", "tls/"];

impl ZenohConfig {
    pub(super) fn validate(&self) -> Result<(), Invalid> {
        if self.mode != "peer" && self.mode != "client" {
            return Err(Invalid::found(
                "costmap.zenoh.mode",
                "\"peer\" or \"client\"",
                &self.mode,
            ));
        }
        for (key, list) in [("connect", &self.connect), ("listen", &self.listen)] {
            for (i, endpoint) in list.iter().enumerate() {
                let known = PROTOCOLS.iter().any(|p| endpoint.starts_with(p));
                let address = endpoint.split_once('/').map_or("", |(_, a)| a);
                if !known || !address.contains(':') {
                    return Err(Invalid::found(
                        format!("costmap.zenoh.{key}[{i}]"),
                        "a Zenoh endpoint such as \"tcp/localhost:7447\" or \"tls/10.0.0.5:7447\"",
                        endpoint,
                    ));
                }
            }
        }
        if self.enabled && self.mode == "client" && self.connect.is_empty() {
            return Err(Invalid::new(
                "costmap.zenoh.connect",
                "a client connects to a router: expected at least one endpoint",
            ));
        }
        Ok(())
    }
}
