//! `[view]`: what `isochron view` (live, Foxglove WebSocket) and `isochron record`
//! (MCAP files) show of the site.

use std::net::SocketAddr;

use serde::{Deserialize, Serialize};

use super::{Invalid, check_range};

/// `[view]`: the live view and recordings.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ViewConfig {
    /// Publish the cameras' images (downscaled JPEG) in the live view and in
    /// recordings. Default `false`: no pixel leaves the box unless the site says so.
    pub frames: bool,
    /// Most images per second per camera, when `frames` is on. Default 2.
    pub frame_rate_hz: f64,
    /// Longest side of a published image, pixels (larger frames are scaled down by
    /// a whole factor). Default 640.
    pub frame_max_px: u32,
    /// JPEG quality of published images, 1..=100. Default 75.
    pub jpeg_quality: u8,
    /// Address `isochron view` listens on. Default `"127.0.0.1:8765"`, loopback: a
    /// non-loopback address is the site's explicit choice.
    pub listen: String,
    /// Bytes the live view may hold for one client that reads more slowly than the
    /// site publishes, MiB. Past it the client's oldest messages are dropped (and
    /// counted); a message larger than the whole budget still goes to a client
    /// with nothing else queued. Default 4.
    pub client_budget_mib: f64,
    /// A client over its budget that takes nothing for this long is disconnected,
    /// seconds. Default 10.
    pub client_stall_s: f64,
    /// Most clients the live view serves at once; one more is refused (HTTP 503,
    /// a warning, counted as `refused_clients` in the view's status). Default 32.
    pub max_clients: u32,
    /// Bytes the live view may hold for all its clients together, MiB. Past it the
    /// oldest messages of the clients holding the most are dropped first (and
    /// counted), and a client that takes nothing while it loses messages is
    /// disconnected after `client_stall_s`. Default 128.
    pub memory_budget_mib: f64,
}

impl Default for ViewConfig {
    fn default() -> Self {
        ViewConfig {
            frames: false,
            frame_rate_hz: 2.0,
            frame_max_px: 640,
            jpeg_quality: 75,
            listen: "127.0.0.1:8765".into(),
            client_budget_mib: 4.0,
            client_stall_s: 10.0,
            max_clients: 32,
            memory_budget_mib: 128.0,
        }
    }
}

impl ViewConfig {
    /// Checks the `view.*` keys.
    pub(super) fn validate(&self) -> Result<(), Invalid> {
        check_range("view.frame_rate_hz", self.frame_rate_hz, 0.01, 30.0)?;
        check_range("view.frame_max_px", self.frame_max_px as f64, 16.0, 8192.0)?;
        check_range("view.jpeg_quality", self.jpeg_quality as f64, 1.0, 100.0)?;
        check_range(
            "view.client_budget_mib",
            self.client_budget_mib,
            0.0625,
            1024.0,
        )?;
        check_range("view.client_stall_s", self.client_stall_s, 1.0, 3600.0)?;
        check_range("view.max_clients", self.max_clients as f64, 1.0, 4096.0)?;
        check_range(
            "view.memory_budget_mib",
            self.memory_budget_mib,
            1.0,
            65536.0,
        )?;
        if self.listen.parse::<SocketAddr>().is_err() {
            return Err(Invalid::found(
                "view.listen",
                "an IP address and port such as \"127.0.0.1:8765\"",
                &self.listen,
            ));
        }
        Ok(())
    }

    /// [`ViewConfig::client_budget_mib`] in bytes.
    pub fn client_budget_bytes(&self) -> usize {
        (self.client_budget_mib * (1u64 << 20) as f64) as usize
    }

    /// [`ViewConfig::memory_budget_mib`] in bytes.
    pub fn memory_budget_bytes(&self) -> usize {
        (self.memory_budget_mib * (1u64 << 20) as f64) as usize
    }
}
