//! `[presence]`: the presence band — blocks where something that entered with
//! motion stays, moving or not (the cascade's `presence` module).

use serde::{Deserialize, Serialize};

use super::{Invalid, check_range};

/// `[presence]`: the presence band, learned in the cascade from the block
/// appearance the motion stage measures (`motion.appearance_hz`).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PresenceConfig {
    /// Compute the band. Default true. Off, a person who stops fades from the map
    /// and from events with their in-place activity S1 (tens of seconds), unless
    /// the detector confirms them.
    pub enabled: bool,
    /// A present region (8-connected present blocks) in which nothing moved for
    /// this long becomes background — an object left there, or a person who stood
    /// perfectly still that long — seconds. Default 120.
    pub absorb_s: f64,
    /// A block differs from its learned empty appearance when its mean grey level
    /// differs by at least this many grey levels (after the global light change is
    /// taken out, and by at least 6 % of its level). Default 6.
    pub luma_change: f64,
    /// ... or its texture (mean absolute difference of neighbouring pixels) by at
    /// least this many grey levels (and 30 % of its texture). Default 2.
    pub texture_change: f64,
}

impl Default for PresenceConfig {
    fn default() -> Self {
        PresenceConfig {
            enabled: true,
            absorb_s: 120.0,
            luma_change: 6.0,
            texture_change: 2.0,
        }
    }
}

impl PresenceConfig {
    /// Checks the `presence.*` keys.
    pub(super) fn validate(&self) -> Result<(), Invalid> {
        check_range("presence.absorb_s", self.absorb_s, 5.0, 86_400.0)?;
        check_range("presence.luma_change", self.luma_change, 1.0, 128.0)?;
        check_range("presence.texture_change", self.texture_change, 0.25, 64.0)
    }
}
